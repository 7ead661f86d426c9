"""The terminal a command runs on: whether the process runs in the background of it, the ``^C`` it echoes, what
it keeps of the command's last words at Ctrl-C, what is written once it is gone (hung up), and who tells it a
port lost for good (the run that ends the program, once, or the library's warning at once).

The command line and the simulator's server share these rules; the console script's entry module
(``_ics35_async_entry``) keeps a copy of the second, since it runs before the package can be imported.
"""

from __future__ import annotations

import atexit
import contextlib
import os
import stat
import sys
import threading
import time
from collections.abc import Iterator
from typing import TYPE_CHECKING, TextIO

if TYPE_CHECKING:
    import logging

try:
    import termios  # (here, not in keep_last_words: that runs in a signal handler, which must not import)
except ImportError:  # (Windows: no terminal settings of this kind)
    termios = None  # type: ignore[assignment]

ERASE_LINE = "\r\x1b[2K"  # back to the line's start, then the whole line cleared (VT100, every terminal today)

_echoed: list[bool] = []  # a Ctrl-C was typed and its echoed ^C not cleared yet (see ctrl_c_typed)


def in_background_of_terminal(fd: int = 0) -> bool:
    """Whether ``fd`` is this process's controlling terminal and the process is in a background process
    group of it (started with ``&``): reading it would stop the process (SIGTTIN), and all it serves with it."""
    if not os.isatty(fd):
        return False
    try:
        return os.tcgetpgrp(fd) != os.getpgrp()
    except OSError:
        return False  # a terminal, but not this process's controlling one: reading it never stops the process


def in_foreground_of_terminal(stream: TextIO) -> bool:
    """Whether ``stream`` writes to this process's controlling terminal and the process is in its foreground
    process group: where a Ctrl-C typed there came from, and the terminal echoed ``^C``."""
    if sys.platform == "win32":
        return False  # (the console echoes no ^C there)
    try:
        fd = stream.fileno()
        return os.isatty(fd) and os.tcgetpgrp(fd) == os.getpgrp()
    except (AttributeError, OSError, ValueError):  # no descriptor (a test's capture), or not the controlling one
        return False


def clear_echoed_ctrl_c() -> None:
    """After Ctrl-C, before anything more is written: the terminal echoed ``^C`` where the cursor was, and what
    comes next would follow it on that line (``^Cerror: interrupted``).

    The cursor is at the start of a line there (every line written ends with its newline), so that line is
    cleared: the ``^C`` goes and the next words start a line of their own.  Only on the terminal the process is
    in the foreground of (stderr's, else stdout's): a signal sent to a background process (``kill -INT``) echoes
    nothing, and the line where the cursor is then is the shell's, with what the person is typing; a file or a
    pipe gets nothing (not even where a setting such as ``FORCE_COLOR`` makes the output look like a terminal's).
    """
    _echoed.clear()
    keep_last_words()
    for stream in (sys.stderr, sys.stdout):
        if in_foreground_of_terminal(stream):
            stream.write(ERASE_LINE)
            stream.flush()
            return


def ctrl_c_typed() -> None:
    """Note a Ctrl-C (from its signal handler: nothing is written there): :func:`clear_after_ctrl_c` clears its
    echoed ``^C`` before the next thing written, unless :func:`clear_echoed_ctrl_c` has by then.  What the
    program says as it stops is kept from a later press (see :func:`keep_last_words`)."""
    if not _echoed:
        _echoed.append(True)
    keep_last_words()


_kept: list[int] = []  # the terminal's descriptor once keep_last_words has acted (-1: nothing to put back)
_set: list[int] = []  # the local-mode bits keep_last_words turned on, and those it turned off (to put back)


def keep_last_words() -> None:
    """Once a Ctrl-C has stopped the program: a later press must not take what it says as it ends off the screen.

    At each Ctrl-C a terminal discards what the program wrote and it has not shown yet (POSIX's default, the
    NOFLSH flag unset): a double Ctrl-C's second press, landing as the program said what it left ("the joints
    it opened are left free"), took those lines away, a few lines in every hundred written under it.  So the
    terminal the process is in the foreground of is set to keep its output at Ctrl-C (its input is kept too:
    the program reads none as it stops) until the process ends, when its own setting is put back a tenth of a
    second later (see ``_LAST_WORDS_SHOWN``).  It also echoes no more ``^C`` meanwhile (ECHOCTL off): a later
    press's, echoed between the first one's clearing and the last words, came in front of them ("^Cwrote 1
    pose(s)"); the press itself still interrupts.  Nothing on a terminal the process runs in the background of
    (changing its settings would stop the process), in a file or a pipe, or on Windows."""
    if _kept or termios is None:
        return
    echoctl = getattr(termios, "ECHOCTL", 0)  # (POSIX leaves it out; Linux, macOS and the BSDs have it)
    for stream in (sys.stderr, sys.stdout):
        if in_foreground_of_terminal(stream):
            fd = stream.fileno()
            try:
                attrs = termios.tcgetattr(fd)
                on, off = ~attrs[3] & termios.NOFLSH, attrs[3] & echoctl
                if not on and not off:
                    break  # (already so: nothing to put back)
                attrs[3] = (attrs[3] | on) & ~off
                termios.tcsetattr(fd, termios.TCSANOW, attrs)
            except (termios.error, OSError):
                break
            _kept.append(fd)
            _set[:] = [on, off]
            atexit.register(_put_back_setting, fd)
            return
    _kept.append(-1)


# How long the terminal keeps its output at Ctrl-C once the process has said its last words: what was written and
# the terminal has not read yet (a loaded machine, an ssh link) would be discarded by a press landing just after
# the setting is put back.  The last words' bytes cannot be seen leaving a pty from the process's side.
_LAST_WORDS_SHOWN = 0.1


def _put_back_setting(fd: int) -> None:
    """The terminal's own setting put back (output flushed at Ctrl-C, ``^C`` echoed), as the process ends (unless
    it is no longer the foreground's: a background process changing it would be stopped).  A later press's
    ``^C``, where the terminal still echoed one below the last words, is cleared first: the shell's prompt would
    follow it ("^C$ "), the process having ended with its exit code."""
    with contextlib.suppress(termios.error, OSError):
        if os.tcgetpgrp(fd) == os.getpgrp():
            time.sleep(_LAST_WORDS_SHOWN)
            clear_after_ctrl_c()
            on, off = _set
            attrs = termios.tcgetattr(fd)
            attrs[3] = (attrs[3] & ~on) | off
            termios.tcsetattr(fd, termios.TCSANOW, attrs)


def clear_after_ctrl_c() -> None:
    """Before a line written while the command may still be stopping (a log record): the ``^C`` a Ctrl-C noted
    by :func:`ctrl_c_typed` left, cleared once (see :func:`clear_echoed_ctrl_c`)."""
    if _echoed:
        clear_echoed_ctrl_c()


def leave_the_terminal() -> None:
    """The terminal is gone (SIGHUP: a window closed, an ssh link dropped): a write to it would fail (EIO) and cut
    the program's cleanup short, so what is written from now on goes to /dev/null instead.  Output to a file or a
    pipe still goes there.  (A hung-up terminal may no longer pass isatty(): any character device is taken for
    one.  Nothing is flushed: called from a signal handler, the main thread may be inside a write to it.)"""
    with contextlib.suppress(OSError):
        devnull = os.open(os.devnull, os.O_WRONLY)
        try:
            for stream in (sys.stdout, sys.stderr):
                with contextlib.suppress(OSError, ValueError, AttributeError):  # (None, or no descriptor)
                    fd = stream.fileno()
                    if stat.S_ISCHR(os.fstat(fd).st_mode):
                        os.dup2(devnull, fd)
        finally:
            os.close(devnull)


# Ports lost for good while run() or run_blocking() runs a program (None: no run under way).  The run fills
# and says them; the drivers' core, which hears of a loss, asks said_at_the_end: here, below the drivers, so
# that they need not import the runner of programs.
_losses: list[tuple[logging.Logger, str]] | None = None
_losses_lock = threading.Lock()  # (a driver may tell its loss from a thread of its own)


def said_at_the_end(logger: logging.Logger, message: str) -> bool:
    """A port lost for good (no ``reconnect``), told by the library's ``logger``: while :func:`run` or
    :func:`run_blocking` runs the program, ``message`` is logged at INFO now and True is returned; the run says it
    once, as the program ends: as its last line when the PortLost ends it, else as a warning then.  So the
    person at the terminal reads the loss once, not as the library's warning and again as the program's end,
    and never not at all.  False (nothing logged) without a run under way: the caller warns."""
    with _losses_lock:
        if _losses is None:
            return False
        _losses.append((logger, message))
    logger.info("%s", message)
    return True


@contextlib.contextmanager
def losses_said_at_the_end() -> Iterator[list[tuple[logging.Logger, str]]]:
    """While it lasts, :func:`said_at_the_end` keeps each loss (logger, message) in the list it gives, for the
    run to say as the program ends; a run inside another keeps its own, and the outer one's are kept again after."""
    global _losses
    with _losses_lock:
        outer, _losses = _losses, []
        kept = _losses
    try:
        yield kept
    finally:
        with _losses_lock:
            _losses = outer
