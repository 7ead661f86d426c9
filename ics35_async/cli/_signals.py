"""SIGTERM and SIGHUP end a command as Ctrl-C does: servos left as Ctrl-C leaves them, work written.

A service manager (systemd, Docker, ``kill``) stops a program with SIGTERM, and closing the terminal
sends SIGHUP.  Python's default for both is to die at once: a demo's servos would keep holding their
last target and ``teach`` would lose its poses.  Each command already handles Ctrl-C: on the event
loop asyncio cancels its task, elsewhere (a question, a file being read) ``KeyboardInterrupt`` ends
the wait.  The first stop signal does the same: it cancels the command's task (see
:func:`command_task`), or raises ``KeyboardInterrupt`` when none runs.  Later ones are ignored, so
that they cannot cut short the cleanup the first began (closing a terminal often sends SIGHUP twice:
the shell to its jobs, the kernel to the foreground group); a Ctrl-C still forces.  The exit code
then says which signal it was (128 + its number; the library's :mod:`ics35_async.running` gives a
program the same for SIGTERM).
"""

from __future__ import annotations

import _thread
import asyncio
import atexit
import contextlib
import signal
import sys
import threading
import time
import weakref
from collections.abc import Iterator
from types import CodeType, FrameType
from typing import Any

from ..terminal import leave_the_terminal

_received: list[int] = []  # the stop signals received, first first
_tasks: list[asyncio.Task[Any]] = []  # the command's task on the event loop, while it runs
_questions: list[bool] = []  # a question waits for its answer, blocking the loop (see asking)
_settled: weakref.WeakSet[asyncio.Task[Any]] = weakref.WeakSet()  # see nothing_left_to_cut_short


def _stop_signals() -> list[signal.Signals]:
    return [getattr(signal, name) for name in ("SIGTERM", "SIGHUP") if hasattr(signal, name)]


def install() -> None:
    """Handle SIGTERM and SIGHUP as Ctrl-C for the rest of the process (call from the main thread).

    A signal the process was started ignoring stays ignored: ``nohup ics35 ...`` keeps running when
    its terminal closes.
    """
    for signum in _stop_signals():
        if signal.getsignal(signum) is signal.SIG_DFL:
            signal.signal(signum, _stop)
    keep_dropped_ctrl_c()
    if not _ending:
        _ending.append(atexit.register(_nothing_left_to_interrupt))


_ending: list[object] = []  # _nothing_left_to_interrupt, once registered


def _nothing_left_to_interrupt() -> None:
    """Python's last steps, the command over and its words said (registered as the command began, so run after
    the exit hooks of what it used): Ctrl-C is ignored from here.  Python puts its own handler back to the
    default as it ends, and a press in those milliseconds (typed as ``free`` printed its last servo) killed the
    process by SIGINT, the shell seeing 130 with not a word, where the command had ended with its own code."""
    from ..running import _ignore  # (here: every command starts with only the light front)

    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        _ignore(signal.SIGINT)


def keep_dropped_ctrl_c() -> None:
    """A Ctrl-C Python drops is raised again, at the main thread's next step (for the rest of the process).

    Python's handler raises ``KeyboardInterrupt`` wherever the main thread is; inside a weakref callback (one
    runs as each import lets its module lock go) or a finalizer Python prints "Exception ignored in ..." with
    a traceback and drops it, and the command went on as if the key had never been pressed.  So does this
    module's own raise for SIGTERM and SIGHUP outside the loop.  Only while Python's own handler takes Ctrl-C
    (the event loop's handler cancels the command's task instead, and handles its own drops)."""
    previous = sys.unraisablehook
    if getattr(previous, "keeps_ctrl_c", False):  # (once: main may run many times in one process)
        return

    def hook(unraisable: Any) -> None:
        if unraisable.exc_type is KeyboardInterrupt and signal.getsignal(signal.SIGINT) is signal.default_int_handler:
            # Python's handler run again, by a thread of its own once this hook has returned: run from here, the
            # handler would raise at once, in the hook, where Python drops it too.  (The thread is started bare:
            # threading's start would wait for it, and it could press while the hook still runs.)
            main = threading.main_thread().ident
            assert main is not None  # (the main thread has started)
            _thread.start_new_thread(_press_again, (main, hook.__code__))
            return
        previous(unraisable)

    hook.keeps_ctrl_c = True  # type: ignore[attr-defined]
    sys.unraisablehook = hook


@contextlib.contextmanager
def command_task(task: asyncio.Task[Any]) -> Iterator[None]:
    """While the block runs, a stop signal cancels ``task`` (the command's, on the loop) as Ctrl-C does."""
    _tasks.append(task)
    try:
        yield
    finally:
        _tasks.remove(task)


@contextlib.contextmanager
def asking() -> Iterator[None]:
    """While the block runs, a question blocks the loop waiting for its answer: a stop signal raises
    ``KeyboardInterrupt`` there, as Ctrl-C does (a cancelled task would wait for the answer)."""
    _questions.append(True)
    try:
        yield
    finally:
        _questions.pop()


def nothing_left_to_cut_short() -> None:
    """Said by the command's task once its stop has nothing a second Ctrl-C could cut short (teach, its joints
    free: its close frees free joints, and its poses are written after the loop whatever ended it): from then on
    a second press is taken for the same stop, as one just after the loop ended is, and the command ends in its
    own words; a third still forces it out (a close that hangs).  Elsewhere (play slowing to rest) the second
    press is the person's choice to cut the stop short, and forces out."""
    task = asyncio.current_task()
    if task is not None:
        _settled.add(task)


def stop_cuts_nothing(task: asyncio.Task[Any]) -> bool:
    """Whether ``task`` said :func:`nothing_left_to_cut_short`."""
    return task in _settled


def current_task() -> asyncio.Task[Any] | None:
    """The command's task on the event loop, while it runs."""
    return _tasks[-1] if _tasks else None


def _press_again(main: int, hook: CodeType) -> None:
    """Ctrl-C again for the main thread (``main``), once it has left the unraisable ``hook`` it was dropped in."""
    while (frame := sys._current_frames().get(main)) is not None and frame.f_code is hook:
        time.sleep(0.001)
    _thread.interrupt_main(signal.SIGINT)


def _stop(signum: int, frame: FrameType | None) -> None:
    _received.append(signum)
    if len(_received) > 1:
        return  # the first is being acted on (see the module's docstring)
    if signum == getattr(signal, "SIGHUP", None):
        leave_the_terminal()
    task = _tasks[-1] if _tasks else None
    # A question waiting for its answer blocks the loop: there Ctrl-C raises (see _prompt), and so do these.
    if task is not None and not task.done() and not _questions:
        # (run in the main thread between two bytecodes of the loop: cancel from the loop itself)
        task.get_loop().call_soon_threadsafe(task.cancel)
        return
    raise KeyboardInterrupt  # outside the loop, or at a question: as a Ctrl-C there


def same_stop_for_a_moment() -> None:
    """Ctrl-C has just stopped the command outside the event loop's handling (at a question, while loading):
    a second press within a moment (a double Ctrl-C) is the same stop.  Python's own handler, back by then,
    would raise it wherever the command is as it says its last words (a traceback over them) or kill the
    process as Python ends (by SIGINT, not with its exit code); the library's after-stop handler takes it
    instead, as it does after a command's stop on the loop (see ``running._AfterStop``).  Main thread only.

    The second press may land before that handler is in place, even inside the import below (on a loaded
    machine both presses come as the process gets the CPU back): its KeyboardInterrupt is caught and the step
    begun again."""
    if threading.current_thread() is not threading.main_thread():
        return
    while True:
        try:
            from ..running import _after_stop, _unwrapped  # (here: every command starts with only the light front)

            handler = signal.getsignal(signal.SIGINT)
            # (Not where it is ignored, not Python's to set, or so already.)
            if handler not in (signal.SIG_IGN, None) and _unwrapped(handler) is handler:
                _after_stop({signal.SIGINT: handler})
            return
        except KeyboardInterrupt:
            continue


def received() -> int | None:
    """The stop signal that ended the command (None: none, or only Ctrl-C)."""
    return _received[0] if _received else None


def stop_name() -> str:
    """What stopped the command, for a person: ``Ctrl-C``, ``SIGTERM`` or ``SIGHUP``."""
    signum = received()
    return "Ctrl-C" if signum is None else signal.Signals(signum).name
