"""The ``ics35`` console script's entry point: Ctrl-C while the command line loads ends in one line too.

A module of its own, outside the package on purpose: a console script imports its entry point's package
before any of its code runs, and ``ics35_async`` with its command line takes about 0.1 s to import, in which
Ctrl-C (a command started by mistake, stopped at once) would print a ``KeyboardInterrupt`` traceback.  This
module imports only :mod:`os` and :mod:`sys` (loaded with the interpreter), then the command line with Ctrl-C
caught; once ``main`` runs, the command line handles Ctrl-C itself.
"""

from __future__ import annotations

import os
import sys

TYPE_CHECKING = False  # (typing is not imported at run time: it is not loaded with the interpreter)
if TYPE_CHECKING:
    from typing import Any, NoReturn

# ExitCode.INTERRUPTED (128 + SIGINT): the enum is in the package whose import this guards.
INTERRUPTED = 130


def main() -> None:
    """``ics35``: the command line of :mod:`ics35_async.cli`, imported with Ctrl-C caught."""
    # Ctrl-C landing in a weakref callback (one runs as each import lets its module lock go): Python prints
    # "Exception ignored in ..." and drops the KeyboardInterrupt there, and the import goes on.  Kept, and the
    # command line stopped once loaded (as it begins, the command line raises one it drops again itself).
    dropped: list[bool] = []
    previous = sys.unraisablehook

    def keep(unraisable: Any) -> None:
        if unraisable.exc_type is KeyboardInterrupt:
            dropped.append(True)
        else:
            previous(unraisable)

    sys.unraisablehook = keep
    try:
        from ics35_async.cli import main as cli_main
    except KeyboardInterrupt:
        _interrupted()
    except RuntimeError as exc:
        # Ctrl-C landing in a class as it was made (a module's class with a cached property, a dataclass): Python
        # hands the KeyboardInterrupt on inside a RuntimeError ("Error calling __set_name__ ...").
        if not isinstance(exc.__cause__, KeyboardInterrupt):
            raise
        _interrupted()
    finally:
        sys.unraisablehook = previous
    if dropped:
        _interrupted()
    cli_main()


def _interrupted() -> NoReturn:
    _ignore_later_presses()
    # As the command line does after Ctrl-C (ics35_async.terminal.clear_echoed_ctrl_c, not importable here):
    # the terminal's echoed ^C, at the start of the line, is cleared and the message starts a line of its own.
    _clear_echoed_ctrl_c()
    sys.stderr.write("error: interrupted\n")
    sys.exit(INTERRUPTED)


def _ignore_later_presses() -> None:
    """A second press (a double Ctrl-C) is the same stop: not a traceback over "interrupted", nor a death by
    SIGINT as Python ends.  It may land before SIGINT is ignored, even inside the import below (on a loaded
    machine both presses come as the process gets the CPU back): its KeyboardInterrupt is caught and the
    step begun again."""
    while True:
        try:
            import signal

            # Blocked meanwhile, as ics35_async.running._ignore does (this module cannot import the package): one
            # arriving between Python's handler turning SIG_IGN and the kernel's was printed as "OSError: Signal 2
            # ignored due to race condition" as the process ended.
            block = getattr(signal, "pthread_sigmask", None)  # (not on Windows)
            before = block(signal.SIG_BLOCK, {signal.SIGINT}) if block is not None else None
            try:
                signal.signal(signal.SIGINT, signal.SIG_IGN)
            finally:
                if block is not None and before is not None:
                    block(signal.SIG_SETMASK, before)
            return
        except KeyboardInterrupt:
            continue


def _clear_echoed_ctrl_c() -> None:
    """The line the terminal echoed ``^C`` on cleared, on stderr or else stdout: whichever is the terminal this
    process is in the foreground of."""
    if sys.platform == "win32":
        return
    for stream in (sys.stderr, sys.stdout):
        try:
            fd = stream.fileno()
            if os.isatty(fd) and os.tcgetpgrp(fd) == os.getpgrp():
                stream.write("\r\x1b[2K")
                stream.flush()
                return
        except (AttributeError, OSError, ValueError):
            continue
