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
        sys.stderr.write("interrupted\n")
        sys.exit(INTERRUPTED)
    cli_main()
