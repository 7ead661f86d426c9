"""Which processes hold a port open, read from Linux's ``/proc`` (elsewhere: none are found).

A port another program holds is the most common reason an open fails, and the program's name (a serial
monitor, another ``ics35``, ModemManager) is what a person needs to free it: the busy port's error names it,
and ``ics35 doctor`` reports it.
"""

from __future__ import annotations

import os
import time
from pathlib import Path


def below(root: Path, path: str) -> Path:
    """``path`` as seen below ``root`` (a test's stand-in for ``/``); a relative path is the working directory's,
    as every open takes it."""
    return root / os.path.abspath(path).lstrip("/")


def processes(root: Path) -> list[tuple[int, str]]:
    """``(pid, name)`` of the processes ``root/proc`` lists."""
    found = []
    try:
        entries = list(below(root, "/proc").iterdir())
    except OSError:
        return []
    for entry in entries:
        if not entry.name.isdigit():
            continue
        try:
            found.append((int(entry.name), (entry / "comm").read_text().strip()))
        except OSError:
            continue
    return sorted(found)


def holders(root: Path, device: str, *, own_pid: int | None = None) -> list[tuple[int, str]]:
    """The processes with ``device`` open (from their ``/proc/PID/fd`` links; only those we may read)."""
    targets = {device, os.path.realpath(device)}
    held = []
    for pid, name in processes(root):
        if pid == own_pid:
            continue
        try:
            fds = list(below(root, f"/proc/{pid}/fd").iterdir())
        except OSError:
            continue
        for fd in fds:
            try:
                if os.readlink(fd) in targets:
                    held.append((pid, name))
                    break
            except OSError:
                continue
    return held


# A busy port's error is made again at each of a reconnect's tries (ten a second): /proc is walked at most this often
# for one device, the words kept meanwhile.
HELD_BY_FOR = 2.0
_held_by_seen: dict[str, tuple[float, str | None]] = {}


def held_by(device: str) -> str | None:
    """Who else holds ``device`` open, in words (``python (process 1234)``), or None where none is found (not
    Linux, or only this process)."""
    now = time.monotonic()
    seen = _held_by_seen.get(device)
    if seen is not None and now - seen[0] < HELD_BY_FOR:
        return seen[1]
    found = holders(Path("/"), device, own_pid=os.getpid())
    words = ", ".join(f"{name} (process {pid})" for pid, name in found) or None
    _held_by_seen[device] = (now, words)
    return words
