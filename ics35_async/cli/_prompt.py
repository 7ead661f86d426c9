"""The [y/N] question before a write or a move: 'no', end of input or Ctrl-C, and nothing gets written or moved."""

from __future__ import annotations

import contextlib
import io
import os
import select
import signal
import sys
import threading
from collections.abc import Iterator

from . import _signals
from ._console import question_text
from ._settings import CliError, ExitCode


@contextlib.contextmanager
def _ctrl_c_raises() -> Iterator[None]:
    """Let Ctrl-C interrupt a blocking read of the answer.

    A question asked inside the event loop would otherwise meet asyncio.Runner's
    SIGINT handler, which only cancels the main task (the read goes on waiting)
    and raises KeyboardInterrupt at the second Ctrl-C (SIGTERM and SIGHUP raise
    there too: see _signals.asking).  A command started with
    SIGINT ignored (a script's background job: the Ctrl-C typed for the
    script's foreground command is not for it) keeps ignoring it.
    """
    previous = signal.getsignal(signal.SIGINT)
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    with _signals.asking():  # (SIGTERM and SIGHUP raise there too)
        if previous is signal.SIG_IGN:
            yield
            return
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
        _signals.same_stop_for_a_moment()
        sys.stderr.write("\n")
        raise CliError(ExitCode.INTERRUPTED, f"interrupted at the question: {nothing}") from None


def _ask(question: str) -> bool:
    while True:
        sys.stderr.write(question_text(question, "[y/N]:"))
        sys.stderr.flush()
        line = _read_line()
        if not line:
            sys.stderr.write("\n")  # end of input: the prompt line got no newline from the user
            return False
        answer = line.strip().lower()
        if answer in ("y", "yes"):
            return True
        if answer in ("", "n", "no"):
            return False
        sys.stderr.write("please answer y or n\n")


# How often a wait for the answer looks up (the longest a Ctrl-C can go unnoticed).
_CTRL_C_CHECK = 0.2


def _read_line() -> str:
    """One line of stdin ("" at its end), ended at once by a Ctrl-C however it lands.

    A blocking ``readline()`` misses a Ctrl-C that lands after Python's last signal
    check and before the read begins: the handler only notes it, and the read waits
    on. So, where stdin is a descriptor select() can watch (not on Windows), the
    wait wakes every moment to let a noted Ctrl-C raise, and the line is read a byte
    at a time so nothing past it is taken from stdin.
    """
    if sys.stdin is None:  # no stdin at all (its descriptor closed, pythonw): as at its end
        return ""
    try:
        fd = sys.stdin.fileno()
    except (ValueError, io.UnsupportedOperation):  # closed, or not on a descriptor (a test's StringIO)
        fd = -1
    if fd < 0 or sys.platform == "win32":
        return sys.stdin.readline()
    line = bytearray()
    while not line.endswith(b"\n"):
        if not select.select([fd], [], [], _CTRL_C_CHECK)[0]:
            continue
        byte = os.read(fd, 1)
        if not byte:
            break
        line += byte
    return line.decode(sys.stdin.encoding or "utf-8", errors="replace")


def confirm(question: str, yes: bool, nothing: str = "nothing was written") -> None:
    """Go on only on 'y' (or with --yes); a 'no' or end of input is exit code 5, Ctrl-C 130, each saying
    ``nothing`` happened (in the words of what the command would have done)."""
    if yes:
        return
    if not ask_yes_no(question, nothing):
        raise CliError(ExitCode.REFUSED, f"not confirmed: {nothing}", "pass --yes to skip the question")
