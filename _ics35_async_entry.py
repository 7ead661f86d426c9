"""The ``ics35`` console script's entry point: Ctrl-C while the command line loads ends in one line too.

A module of its own, outside the package on purpose: a console script imports its entry point's package
before any of its code runs, and ``ics35_async`` with its command line takes about 0.1 s to import, in which
Ctrl-C (a command started by mistake, stopped at once) would print a ``KeyboardInterrupt`` traceback.  This
module imports only :mod:`sys`, then the command line with Ctrl-C caught; once ``main`` runs, the command
line handles Ctrl-C itself.
"""

from __future__ import annotations

import sys

# ExitCode.INTERRUPTED (128 + SIGINT): the enum is in the package whose import this guards.
INTERRUPTED = 130


def main() -> None:
    """``ics35``: the command line of :mod:`ics35_async.cli`, imported with Ctrl-C caught."""
    try:
        from ics35_async.cli import main as cli_main
    except KeyboardInterrupt:
        # As the command line does after Ctrl-C (cli._console.off_the_ctrl_c_line): the terminal's echoed ^C,
        # at the start of the line, is cleared, and the message starts a line of its own.
        clear = "\r\x1b[2K" if sys.stderr.isatty() and sys.platform != "win32" else ""
        sys.stderr.write(f"{clear}interrupted\n")
        sys.exit(INTERRUPTED)
    cli_main()
