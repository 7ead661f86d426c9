"""What a person sees on a terminal: the bytes a program wrote to a pty, played onto a screen of lines.

Only what the live views write is modelled (rich's ``Live`` redraws in place with carriage returns,
cursor-up and erase-line); colours and other control sequences are dropped.  A line printed beside a live
view by another console is overwritten by the view's next redraw, as on a real terminal: that is what
this is for.  :func:`typed_on_a_terminal` runs a command on a pty of its own, Ctrl-C typed as a person types it
(and :class:`Unread`, a terminal reading nothing for a while); :func:`write_until_refused` fills a pty nobody reads.
"""

from __future__ import annotations

import contextlib
import os
import re
import signal
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

CHECKOUT = str(Path(__file__).resolve().parents[2])  # (the folder that holds the package under test)

# (The other C0 control characters are matched alone and print nothing, as on a terminal: a Ctrl-C's raw echo, \x03,
# once ECHOCTL is off.)
_CONTROL = re.compile(
    r"\x1b\[([0-9;?]*)([A-Za-z])|\x1b[()][A-Za-z0-9]|\x1b.|\r|\n|\x08|[\x00-\x07\x0b\x0c\x0e-\x1a\x1c-\x1f]"
    r"|[^\x00-\x08\x0a-\x1f]+"
)


def screen_of(output: str, width: int | None = None) -> list[str]:
    """The lines on the screen once ``output`` has been written to a terminal (no scrolling limit).

    ``width``: the terminal's columns, wrapping as a terminal does (a character written past the last column
    starts the next line; one that fills the last column leaves the cursor there, the wrap pending until
    the next character); without it, lines never wrap."""
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
                col = col if width is None else min(col, width - 1)  # (a pending wrap ends with the move)
            elif command == "B":
                row = min(row + count, len(lines) - 1)
            elif command == "K":
                mode = match.group(1) or "0"
                lines[row] = [] if mode == "2" else lines[row][:col]
            elif command == "G":
                col = count - 1
        elif not text.startswith("\x1b") and not (len(text) == 1 and text < " " and text != "\t"):
            for part in [text] if width is None else list(text):
                if width is not None and col >= width:  # (the wrap pending at the last column)
                    row, col = row + 1, 0
                    if row == len(lines):
                        lines.append([])
                line = lines[row]
                line.extend(" " * (col - len(line)))
                line[col : col + len(part)] = list(part)
                col += len(part)
    return ["".join(line).rstrip() for line in lines]


class TerminalOutput:
    """What a program writes to its pty, read from the master side ``fd`` as it comes."""

    def __init__(self, fd: int) -> None:
        self.fd = fd
        self.written = b""

    @property
    def text(self) -> str:
        return self.written.decode(errors="replace")

    def shows(self, text: str | re.Pattern[str]) -> Callable[[], bool]:
        """A check that ``text`` has been written, or something ``text`` matches (for :meth:`read_until`)."""
        if isinstance(text, re.Pattern):
            return lambda: text.search(self.text) is not None
        return lambda: text in self.text

    def read_until(self, done: Callable[[], bool], limit: float) -> None:
        """Read until ``done()``, the program has closed the terminal, or ``limit`` seconds."""
        import select
        import time

        deadline = time.monotonic() + limit
        while not done() and time.monotonic() < deadline:
            if select.select([self.fd], [], [], 0.05)[0]:
                try:
                    chunk = os.read(self.fd, 65536)
                except OSError:  # the process has ended and closed the terminal
                    return
                if not chunk:
                    return
                self.written += chunk


@dataclass(frozen=True)
class Unread:
    """A wait in :func:`typed_on_a_terminal`'s keys during which the terminal reads nothing of what the command
    writes (a terminal behind: a loaded machine, an ssh link): the pty's buffer fills and the command's writes
    wait for room.  A Ctrl-C typed next makes the pty discard the output not read, as a terminal does."""

    seconds: float


def typed_on_a_terminal(
    args: list[str],
    keys: list[tuple[str | re.Pattern[str] | float | Unread | Callable[[], bool], bytes]],
    *,
    timeout: float = 60,
    stdout: Path | None = None,
    columns: int = 120,
    rows: int = 40,
    env: dict[str, str] | None = None,
    script: str | None = None,
    cwd: Path | None = None,
) -> tuple[int, str]:
    """``python -m ics35_async.cli ARGS`` (``python -c script ARGS`` with ``script``) with a pty as its controlling
    terminal (stdin, stdout and stderr), as
    a shell runs it: for each ``(when, key)`` it waits until ``when`` (a phrase, or a pattern) is on the screen, or for
    ``when`` seconds (an :class:`Unread`'s reading nothing), or until ``when()`` is true (e.g. a line in the
    ``stdout`` file), then types ``key`` (``b"\\x03"`` is Ctrl-C: the terminal echoes ``^C`` and sends SIGINT).
    ``stdout``: a file for stdout instead (``ics35 ... > FILE``); ``columns`` and ``rows``: the terminal's width and
    height; ``env``: more environment variables; ``cwd``: the directory it runs in (the package still this
    checkout's).  Returns the exit code and everything written to the terminal."""
    import fcntl
    import struct
    import subprocess
    import sys
    import termios
    import time

    master, slave = os.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", rows, columns, 0, 0))

    def own_terminal() -> None:
        os.setsid()
        fcntl.ioctl(0, termios.TIOCSCTTY, 0)
        signal.signal(signal.SIGINT, signal.SIG_DFL)  # (as an interactive shell starts it)

    output = None if stdout is None else stdout.open("wb")
    # (run elsewhere, `-m` would find the package installed, not this checkout's)
    here = (
        {} if cwd is None else {"PYTHONPATH": os.pathsep.join(filter(None, [CHECKOUT, os.environ.get("PYTHONPATH")]))}
    )
    proc = subprocess.Popen(
        [sys.executable, *(["-m", "ics35_async.cli"] if script is None else ["-c", script]), *args],
        stdin=slave,
        stdout=slave if output is None else output,
        stderr=slave,
        preexec_fn=own_terminal,
        env={**os.environ, "TERM": "xterm", "COLUMNS": str(columns), "LINES": str(rows), **here, **(env or {})},
        cwd=cwd,
    )
    os.close(slave)
    screen = TerminalOutput(master)
    try:
        for when, key in keys:
            if isinstance(when, (str, re.Pattern)) or callable(when):
                # (A phrase never shown fails here, not after typing the key at the end of the wait: the test then
                # judged whatever followed, and a misspelt phrase cost the whole timeout.)
                done = when if callable(when) else screen.shows(when)
                screen.read_until(done, timeout)
                assert done(), f"not shown within {timeout} s: {when!r}; the screen:\n" + "\n".join(
                    screen_of(screen.text)
                )
            elif isinstance(when, Unread):
                time.sleep(when.seconds)
            else:
                screen.read_until(lambda: False, when)
            os.write(master, key)
        screen.read_until(lambda: proc.poll() is not None, timeout)
        proc.wait(timeout)
        screen.read_until(lambda: False, 0.2)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        os.close(master)
        if output is not None:
            output.close()
    return proc.returncode, screen.text


def write_until_refused(fd: int) -> int:
    """Write to the non-blocking ``fd`` until it takes not one byte more; the bytes it took.  A pty whose far
    end nobody reads is full only once this takes nothing a few times in a row, a little apart: the kernel
    moves bytes between the pty's buffers in a worker of its own, so room can appear just after a refusal
    (on a loaded machine, late)."""
    took = 0
    for size in (4096, 1):
        with contextlib.suppress(BlockingIOError):
            while True:
                took += os.write(fd, b"x" * size)
    return took
