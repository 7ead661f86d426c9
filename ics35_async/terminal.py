"""The terminal a command runs on: whether the process runs in the background of it, the ``^C`` it echoes, what
it keeps of the command's last words at Ctrl-C, what is written once it is gone (hung up), and who tells it a
port lost for good (the run that ends the program, once, or the library's warning at once).

The command line and the simulator's server share these rules; the console script's entry module
(``_ics35_async_entry``) keeps a copy of the second, since it runs before the package can be imported.
"""

from __future__ import annotations

import atexit
import contextlib
import io
import os
import signal
import stat
import sys
import threading
import time
from collections.abc import Iterator
from typing import IO, TYPE_CHECKING

if TYPE_CHECKING:
    import logging

try:
    import termios  # (here, not in keep_last_words: that runs in a signal handler, which must not import)
except ImportError:  # (Windows: no terminal settings of this kind)
    termios = None  # type: ignore[assignment]

ERASE_LINE = "\r\x1b[2K"  # back to the line's start, then the whole line cleared (VT100, every terminal today)

_echoed: list[bool] = []  # a Ctrl-C was typed and its echoed ^C not cleared yet (see ctrl_c_typed)


def fitted_lines(text: str, stream: IO[str] | None) -> str:
    """``text`` as written to ``stream``: on a terminal, each line wrapped at words to its width (a terminal cuts
    a line mid-word), further lines under the first's indent; a word wider than that is broken where it must (a
    path); into a pipe or a file, as it is (a log keeps its lines whole).  The command line's rich consoles wrap
    their own lines so (see ``cli._console``); this is for the plain ones (the simulator's server and console)."""
    try:
        if stream is None or not stream.isatty():
            return text
        width = os.get_terminal_size(stream.fileno()).columns
    except (OSError, ValueError, AttributeError):  # (closed, or not a file: a test's StringIO)
        return text
    import textwrap  # (only on a terminal: the command line's start pays for no more than it uses)

    lines = []
    for line in text.split("\n"):
        indent = line[: len(line) - len(line.lstrip())]
        lines.extend(textwrap.wrap(line, max(width, 1), subsequent_indent=indent, break_on_hyphens=False) or [""])
    return "\n".join(lines)


def in_background_of_terminal(fd: int = 0) -> bool:
    """Whether ``fd`` is this process's controlling terminal and the process is in a background process
    group of it (started with ``&``): reading it would stop the process (SIGTTIN), and all it serves with it."""
    if not os.isatty(fd):
        return False
    try:
        return os.tcgetpgrp(fd) != os.getpgrp()
    except OSError:
        return False  # a terminal, but not this process's controlling one: reading it never stops the process


def in_foreground_of_terminal(stream: IO[str]) -> bool:
    """Whether ``stream`` writes to this process's controlling terminal and the process is in its foreground
    process group: where a Ctrl-C typed there came from, and the terminal echoed ``^C``."""
    if sys.platform == "win32":
        return False  # (the console echoes no ^C there)
    try:
        fd = stream.fileno()
        return os.isatty(fd) and os.tcgetpgrp(fd) == os.getpgrp()
    except (AttributeError, OSError, ValueError):  # no descriptor (a test's capture), or not the controlling one
        return False


class _WholeWrites(io.TextIOWrapper):
    """Text written at once, all of it (see :func:`whole_writes`)."""

    def write(self, text: str) -> int:
        written = super().write(text)
        self.flush()
        return written


def whole_writes(stream: IO[str]) -> IO[str]:
    """``stream``, or where Python runs unbuffered (``-u``, ``PYTHONUNBUFFERED``: many container images set it) a
    stream on the same descriptor that writes all it is given, at once as the unbuffered one does.

    Unbuffered, Python hands text straight to the descriptor and drops what a write cut short did not take: a
    write waiting for a terminal that reads behind (a loaded machine, an ssh link) is cut short by a signal (a
    Ctrl-C), so a live view's redraw lost its rest, and the next, moving up by the view's height from a line it
    never reached, overwrote the lines above the view.  Buffered, the rest is written after the signal's handler
    (or at the next write, should the handler raise)."""
    if not isinstance(stream, io.TextIOWrapper) or not isinstance(stream.buffer, io.FileIO):
        return stream  # (buffered already, or not a file: a test's capture)
    raw = io.FileIO(stream.fileno(), "w", closefd=False)  # (the descriptor stays open when this one goes)
    return _WholeWrites(
        io.BufferedWriter(raw),
        encoding=stream.encoding,
        errors=stream.errors,
        line_buffering=stream.line_buffering,
        write_through=True,
    )


def clear_echoed_ctrl_c(*, newline_on_stderr: bool = False) -> None:
    """After Ctrl-C, before anything more is written: the terminal echoed ``^C`` where the cursor was, and what
    comes next would follow it on that line (``^Cerror: interrupted``).

    The cursor is at the start of a line there (every line written ends with its newline), so that line is
    cleared: the ``^C`` goes and the next words start a line of their own.  Only on the terminal the process is
    in the foreground of (stderr's, else stdout's): a signal sent to a background process (``kill -INT``) echoes
    nothing, and the line where the cursor is then is the shell's, with what the person is typing; a file or a
    pipe gets nothing (not even where a setting such as ``FORCE_COLOR`` makes the output look like a terminal's).
    ``newline_on_stderr``: a newline was written to stderr since the press (click's, as it takes a
    KeyboardInterrupt): on that terminal the ``^C`` is on the line above, cleared too.
    """
    _echoed.clear()
    keep_last_words()
    for stream in (sys.stderr, sys.stdout):
        if in_foreground_of_terminal(stream):
            above = newline_on_stderr and stream is sys.stderr
            stream.write(ERASE_LINE + ("\x1b[1A" + ERASE_LINE if above else ""))
            stream.flush()
            return


def ctrl_c_typed() -> None:
    """Note a Ctrl-C (from its signal handler: nothing is written there): :func:`clear_after_ctrl_c` clears its
    echoed ``^C`` before the next thing written, unless :func:`clear_echoed_ctrl_c` has by then.  What the
    program says as it stops is kept from a later press (see :func:`keep_last_words`)."""
    if not _echoed:
        _echoed.append(True)
    keep_last_words()


_kept: list[int] = []  # the terminal's descriptor once its settings were changed here
_set: list[int] = [0, 0]  # the local-mode bits turned on here, and those turned off (to put back)
_last_words_kept: list[bool] = []  # keep_last_words has acted


def keep_output_at_ctrl_c(stream: IO[str]) -> None:
    """A live view is about to redraw in place on ``stream``: the terminal it writes to (the process in its
    foreground) is set to keep its output at Ctrl-C until the process ends (POSIX's NOFLSH; see
    :func:`keep_last_words` for when the setting is put back).

    A terminal discards what the program wrote and it has not shown yet at each Ctrl-C: a terminal behind (a
    loaded machine, an ssh link, a busy tmux) lost the rest of a redraw, so the cursor was not where the view
    left it, and the view's next redraw, moving up by its height from there, overwrote the lines above it (a
    warning, the command's title).  No way of drawing can tell where the terminal's cursor is once it has
    discarded an unknown part of the output: a cursor saved on the terminal (ESC 7) is lost with the rest, and
    one saved before the view scrolls the screen is no longer where the view starts.  Kept, every redraw arrives
    whole.  Nothing on a terminal the process runs in the background of, in a file or a pipe, or on Windows."""
    if termios is not None:
        _change_local_modes((stream,), on=termios.NOFLSH, off=0)


def keep_last_words() -> None:
    """Once a Ctrl-C has stopped the program: a later press must not take what it says as it ends off the screen.

    At each Ctrl-C a terminal discards what the program wrote and it has not shown yet (POSIX's default, the
    NOFLSH flag unset): a double Ctrl-C's second press, landing as the program said what it left ("the joints
    it opened are left free"), took those lines away, a few lines in every hundred written under it.  So the
    terminal the process is in the foreground of is set to keep its output at Ctrl-C (its input is kept too:
    the program reads none as it stops) until the process ends, when its own setting is put back a tenth of a
    second later (see ``_LAST_WORDS_SHOWN``).  It also echoes no more ``^C`` meanwhile (ECHOCTL off): a later
    press's, echoed between the first one's clearing and the last words, came in front of them ("^Cwrote 1
    pose(s)"); the press itself still interrupts.  Where a live view had the output kept already
    (:func:`keep_output_at_ctrl_c`), the press that stopped the program found it so and the terminal kept what
    had been typed ahead too: that is discarded now, as the press would have (a half-typed line is not left to
    the shell).  Nothing on a terminal the process runs in the background of (changing its settings would stop
    the process), in a file or a pipe, or on Windows."""
    if _last_words_kept or termios is None:
        return
    _last_words_kept.append(True)
    kept_before = _kept[0] if _kept and _set[0] & termios.NOFLSH else None
    echoctl = getattr(termios, "ECHOCTL", 0)  # (POSIX leaves it out; Linux, macOS and the BSDs have it)
    _change_local_modes((sys.stderr, sys.stdout), on=termios.NOFLSH, off=echoctl)
    if kept_before is not None:
        with contextlib.suppress(termios.error, OSError):
            termios.tcflush(kept_before, termios.TCIFLUSH)


def _change_local_modes(streams: tuple[IO[str], ...], *, on: int, off: int) -> None:
    """The local-mode bits ``on`` turned on and ``off`` turned off on the terminal changed here before, else on that
    of the first of ``streams`` the process is in the foreground of; what was changed is put back as the process
    ends (:func:`_put_back_setting`), a bit already so left as the terminal had it."""
    foreground = (stream.fileno() for stream in streams if in_foreground_of_terminal(stream))
    fd = _kept[0] if _kept else next(foreground, -1)
    with contextlib.suppress(termios.error, OSError):
        if fd < 0 or os.tcgetpgrp(fd) != os.getpgrp():
            return  # (in the background now: changing the settings would stop the process)
        attrs = termios.tcgetattr(fd)
        turned_on, turned_off = on & ~attrs[3], off & attrs[3]
        if not turned_on and not turned_off:
            return
        attrs[3] = (attrs[3] | turned_on) & ~turned_off
        termios.tcsetattr(fd, termios.TCSANOW, attrs)
        if not _kept:
            _kept.append(fd)
            atexit.register(_put_back_setting, fd)
        _set[0] |= turned_on
        _set[1] |= turned_off


# How long the terminal keeps its output at Ctrl-C once the process has said its last words: what was written and
# the terminal has not read yet (a loaded machine, an ssh link) would be discarded by a press landing just after
# the setting is put back.  The last words' bytes cannot be seen leaving a pty from the process's side.
_LAST_WORDS_SHOWN = 0.1


def _put_back_setting(fd: int) -> None:
    """The terminal's own setting put back (output flushed at Ctrl-C, ``^C`` echoed), as the process ends (unless
    it is no longer the foreground's: a background process changing it would be stopped).  A later press's
    ``^C``, where the terminal still echoed one below the last words, is cleared first: the shell's prompt would
    follow it ("^C$ "), the process having ended with its exit code.  A press from here on is the same stop: it
    is ignored (one landing in the wait raised KeyboardInterrupt out of it, with its traceback, and the terminal was
    left keeping its output at Ctrl-C and not echoing ``^C`` for every command after)."""
    with contextlib.suppress(ValueError):  # (atexit runs this in the main thread: only there can it be set)
        signal.signal(signal.SIGINT, signal.SIG_IGN)
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
