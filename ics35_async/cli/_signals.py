"""SIGTERM and SIGHUP end a command as Ctrl-C does: servos left as Ctrl-C leaves them, work written.

A service manager (systemd, Docker, ``kill``) stops a program with SIGTERM, and closing the terminal
sends SIGHUP.  Python's default for both is to die at once: a demo's servos would keep holding their
last target and ``teach`` would lose its poses.  Each command already handles Ctrl-C (asyncio cancels
its task, or ``KeyboardInterrupt`` ends a wait), so these signals go the same way, through whatever
handles SIGINT at that moment; the exit code then says which signal it was (128 + its number).
"""

from __future__ import annotations

import contextlib
import os
import signal
import stat
import sys
from types import FrameType

_received: list[int] = []  # the stop signals received, first first


def _stop_signals() -> list[signal.Signals]:
    return [getattr(signal, name) for name in ("SIGTERM", "SIGHUP") if hasattr(signal, name)]


def install() -> None:
    """Handle SIGTERM and SIGHUP as Ctrl-C for the rest of the process (call from the main thread).

    A signal the process was started ignoring stays ignored: ``nohup ics35 ...`` keeps running when
    its terminal closes.
    """
    for signum in _stop_signals():
        if signal.getsignal(signum) is signal.SIG_DFL:
            signal.signal(signum, _like_ctrl_c)


def _like_ctrl_c(signum: int, frame: FrameType | None) -> None:
    _received.append(signum)
    if signum == getattr(signal, "SIGHUP", None):
        # The terminal is gone: a write to it would fail (EIO) and cut the cleanup short.  (Output
        # going to a file or a pipe still goes there.  A hung-up terminal may no longer pass isatty():
        # any character device is taken for one.)
        devnull = os.open(os.devnull, os.O_WRONLY)
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(OSError, ValueError):
                if stat.S_ISCHR(os.fstat(stream.fileno()).st_mode):
                    with contextlib.suppress(OSError):  # (what was buffered goes nowhere now)
                        stream.flush()
                    os.dup2(devnull, stream.fileno())
        os.close(devnull)
    handler = signal.getsignal(signal.SIGINT)
    if callable(handler):  # asyncio's while a command runs (it cancels the command's task), else Python's
        handler(signal.SIGINT, frame)
    else:  # SIGINT ignored (a background job of a non-interactive shell): this signal still stops
        raise KeyboardInterrupt


def received() -> int | None:
    """The stop signal that ended the command (None: none, or only Ctrl-C)."""
    return _received[0] if _received else None


def stop_name() -> str:
    """What stopped the command, for a person: ``Ctrl-C``, ``SIGTERM`` or ``SIGHUP``."""
    signum = received()
    return "Ctrl-C" if signum is None else signal.Signals(signum).name
