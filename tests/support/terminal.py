"""What a person sees on a terminal: the bytes a program wrote to a pty, played onto a screen of lines.

Only what the live views write is modelled (rich's ``Live`` redraws in place with carriage returns,
cursor-up and erase-line); colours and other control sequences are dropped.  A line printed beside a live
view by another console is overwritten by the view's next redraw, as on a real terminal: that is what
this is for.
"""

from __future__ import annotations

import re

_CONTROL = re.compile(r"\x1b\[([0-9;?]*)([A-Za-z])|\x1b[()][A-Za-z0-9]|\x1b.|\r|\n|\x08|[^\x1b\r\n\x08]+")


def screen_of(output: str) -> list[str]:
    """The lines on the screen once ``output`` has been written to a terminal (no scrolling limit)."""
    lines: list[list[str]] = [[]]
    row = col = 0
    for match in _CONTROL.finditer(output):
        text = match.group(0)
        if text == "\n":
            row += 1
            if row == len(lines):
                lines.append([])
        elif text == "\r":
            col = 0
        elif text == "\x08":
            col = max(col - 1, 0)
        elif match.group(2) is not None:
            count = int(match.group(1) or "1") if match.group(1).isdigit() else 1
            command = match.group(2)
            if command == "A":
                row = max(row - count, 0)
            elif command == "B":
                row = min(row + count, len(lines) - 1)
            elif command == "K":
                mode = match.group(1) or "0"
                lines[row] = [] if mode == "2" else lines[row][:col]
            elif command == "G":
                col = count - 1
        elif not text.startswith("\x1b"):
            line = lines[row]
            line.extend(" " * (col - len(line)))
            line[col : col + len(text)] = list(text)
            col += len(text)
    return ["".join(line).rstrip() for line in lines]
