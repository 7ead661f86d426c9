"""The [y/N] question before a write or a move: 'no', end of input or Ctrl-C, and nothing gets written or moved."""

from __future__ import annotations

import contextlib
import signal
import sys
import threading
from collections.abc import Iterator

from ._settings import CliError, ExitCode


@contextlib.contextmanager
def _ctrl_c_raises() -> Iterator[None]:
    """Let Ctrl-C interrupt a blocking read of the answer.

    A question asked inside the event loop would otherwise meet asyncio.Runner's
    SIGINT handler, which only cancels the main task (the read goes on waiting)
    and raises KeyboardInterrupt at the second Ctrl-C.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.getsignal(signal.SIGINT)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def ask_yes_no(question: str, nothing: str = "nothing was written") -> bool:
    """Ask on stderr, read stdin.  Ctrl-C raises a CliError with exit code 130 saying ``nothing`` happened."""
    try:
        with _ctrl_c_raises():
            return _ask(question)
    except KeyboardInterrupt:
        # Anywhere in the question (even between writing it and reading), not just in the read.
        sys.stderr.write("\n")
        raise CliError(ExitCode.INTERRUPTED, f"interrupted at the question: {nothing}") from None


def _ask(question: str) -> bool:
    while True:
        sys.stderr.write(f"{question} [y/N]: ")
        sys.stderr.flush()
        line = sys.stdin.readline()
        if not line:
            sys.stderr.write("\n")  # end of input: the prompt line got no newline from the user
            return False
        answer = line.strip().lower()
        if answer in ("y", "yes"):
            return True
        if answer in ("", "n", "no"):
            return False
        sys.stderr.write("please answer y or n\n")


def confirm(question: str, yes: bool, nothing: str = "nothing was written") -> None:
    """Go on only on 'y' (or with --yes); a 'no' or end of input is exit code 5, Ctrl-C 130, each saying
    ``nothing`` happened (in the words of what the command would have done)."""
    if yes:
        return
    if not ask_yes_no(question, nothing):
        raise CliError(ExitCode.REFUSED, f"not confirmed: {nothing}", "pass --yes to skip the question")
