"""The event loop a command runs on: uvloop when it is installed, else asyncio's (``ICS35_LOOP`` chooses)."""

from __future__ import annotations

import _thread
import asyncio
import contextlib
import gc
import inspect
import logging
import os
import signal
import sys
import threading
import warnings
from collections.abc import Awaitable, Callable, Coroutine, Iterator
from types import CoroutineType, FrameType
from typing import Any, Literal, TypeGuard, TypeVar, cast

from ..running import _after_stop, _unwrapped
from ..terminal import ctrl_c_typed
from ._console import end_live_views
from ._settings import CliError, ExitCode
from ._signals import command_task, current_task, received, stop_cuts_nothing

T = TypeVar("T")
LOOPS = ("auto", "asyncio", "uvloop")
log = logging.getLogger("ics35_async")


async def _await(make: Callable[[], Awaitable[T]], started: list[asyncio.Task[T]]) -> T:
    task = asyncio.current_task()
    assert task is not None
    started.append(task)
    with command_task(task):  # (SIGTERM and SIGHUP cancel it, as Ctrl-C does)
        return await make()


def loop_factory() -> tuple[Literal["asyncio", "uvloop"], Callable[[], asyncio.AbstractEventLoop] | None]:
    """The loop ``ICS35_LOOP`` asks for (``auto``: uvloop when installed, about 25% less CPU per transaction in
    section A of ``make bench``)."""
    choice = os.environ.get("ICS35_LOOP", "").strip().lower() or "auto"
    if choice not in LOOPS:
        raise CliError(ExitCode.USAGE, f"ICS35_LOOP must be one of {', '.join(LOOPS)}, not {choice!r}")
    if choice == "asyncio":
        return "asyncio", None
    try:
        import uvloop
    except ImportError:
        if choice == "uvloop":
            missing = "ICS35_LOOP=uvloop, but uvloop is not installed"
            raise CliError(ExitCode.USAGE, missing, "pip install uvloop") from None
        return "asyncio", None
    return "uvloop", uvloop.new_event_loop


def run_loop(make: Callable[[], Awaitable[T]]) -> T:
    """``asyncio.run(make())`` on the loop :func:`loop_factory` names.

    The command's coroutine is made by ``make`` once its task runs: one made before (``run_loop(main())``) and
    never run, stopped by a Ctrl-C as the loop was being made (or ``ICS35_LOOP`` refused), was said by Python
    as the process ended, under the command's message: "coroutine ... was never awaited"."""
    name, factory = loop_factory()
    log.info("event loop: %s", name)
    started: list[asyncio.Task[T]] = []
    forced: list[asyncio.Task[T]] = []
    presses: list[int] = []
    quiet_executor_shutdown()
    loops: list[asyncio.AbstractEventLoop] = []
    awaiting: list[Coroutine[Any, Any, T]] = []  # the coroutine the runner runs, once made
    try:
        with (
            _ctrl_c(started, loops) as pressed,
            _dropping_unrun(loops, pressed),
            asyncio.Runner(loop_factory=factory) as runner,
        ):
            presses = pressed
            loops.append(runner.get_loop())
            _reports_when_forced_out(runner.get_loop(), pressed, forced)
            awaiting.append(_await(make, started))
            try:
                return runner.run(awaiting[0])
            except asyncio.CancelledError:
                if received() is None and not pressed:
                    raise
                raise KeyboardInterrupt from None  # cancelled by a stop signal: what Ctrl-C's cancel becomes
            except KeyboardInterrupt:
                if len(pressed) == 2 and started:  # (a third forces out at once: nothing more to tell then)
                    forced.append(started[0])
                raise
    except KeyboardInterrupt:
        if not forced:
            raise
        return _forced_out(forced[0])
    except RuntimeError as exc:
        # uvloop: a later press's KeyboardInterrupt, raised by a loop callback, stopped the loop inside the runner's
        # close (as it shut the executor down): the close's own error, not the command's.
        if len(presses) < 2 or "Event loop stopped before Future completed" not in str(exc):
            raise
        if not forced:
            raise KeyboardInterrupt from None
        return _forced_out(forced[0])
    finally:
        if len(presses) >= 2:  # (what the command says next, or its error, must not go through a view left running)
            end_live_views()
        # Never run (a Ctrl-C before its task was made), closed as the command's would be (see run_loop); only now,
        # the runner closed: a task made for it and never run has been cancelled, and closing it while that task
        # waited to start would fail the task.
        if awaiting and _unstarted(awaiting[0]):
            awaiting[0].close()


@contextlib.contextmanager
def _dropping_unrun(loops: list[asyncio.AbstractEventLoop], pressed: list[int]) -> Iterator[None]:
    """Once the runner has closed the loop (``loops``' one): the work it left unrun, dropped for good.

    Forced out (a later Ctrl-C cut the runner's close short), the loop closes with tasks still pending: work
    the command's stop had just started (play's slow-down, a task per joint; a group stream's next take) and
    never began, or began and never finished; and the press's KeyboardInterrupt, raised wherever the command
    then was, may have come between a coroutine's making and its first step (``retrieved(robot.stop())``),
    which the exception's traceback keeps.  The process's end collects them in whatever order it finds them,
    and each says so on the screen, below the command's message: "coroutine ... was never awaited", "Task
    was destroyed but it is pending!".  What was cut short is the message's to say: here every coroutine
    never begun is closed (nothing can run it any more), and no pending task is reported as it goes."""
    try:
        yield
    finally:
        if len(pressed) >= 2:
            for loop in loops:
                for task in asyncio.all_tasks(loop):
                    cast(Any, task)._log_destroy_pending = False  # (asyncio's own switch for that report)
            for value in gc.get_objects():  # (coroutines are tracked by the collector)
                if _unstarted(value):
                    value.close()


def _unstarted(value: object) -> TypeGuard[CoroutineType[Any, Any, Any]]:
    return inspect.iscoroutine(value) and inspect.getcoroutinestate(value) == inspect.CORO_CREATED


def quiet_executor_shutdown() -> None:
    """Forced out (a later Ctrl-C cut the runner's close short), uvloop's thread that shuts the loop's executor
    down (the one the driver opens ports in) finds the loop closed as it reports back, and Python prints that
    thread's RuntimeError as a traceback.  Nothing is lost there: that one report is dropped (asyncio's own
    loop checks first; any other thread's error is printed as before).  Installed once, for the process."""
    previous = threading.excepthook
    if getattr(previous, "quiet_executor_shutdown", False):
        return

    def hook(args: threading.ExceptHookArgs) -> None:
        name = args.thread.name if args.thread is not None else ""
        if args.exc_type is RuntimeError and "Event loop is closed" in str(args.exc_value) and "_do_shutdown" in name:
            return
        previous(args)

    hook.quiet_executor_shutdown = True  # type: ignore[attr-defined]
    threading.excepthook = hook


# The runner's words for a task its close ended.
_SHUTDOWN_REPORT = "unhandled exception during asyncio.run() shutdown"


def _reports_when_forced_out(
    loop: asyncio.AbstractEventLoop, pressed: list[int], forced: list[asyncio.Task[Any]]
) -> None:
    """What the loop reports once a second Ctrl-C has forced the command out (``pressed``, ``forced``: run_loop's).

    The runner, closing, cancels the command's task again and waits for it (its ``finally`` blocks run); what
    it then ends with the runner prints as a traceback ("unhandled exception during asyncio.run() shutdown") and
    drops.  That is the command's own account of what it left (servos that may still hold, and how to free
    them): it is kept for :func:`_forced_out` instead.  And a task that failed as a later press stopped the loop
    (play's ``retrieved(robot.stop())``, its first step taken as the runner closed, the robot closed under it)
    never had its done callback run, the one that retrieves its error: the loop's close dropped the task and
    Python printed "Task exception was never retrieved" and the error's traceback under the command's message.
    So did a task the press cut off from the task group it ran in (the robot's cycles, anyio's cancel scope
    left mid-exit: "Attempted to exit a cancel scope that isn't the current task's"), which the runner's close
    cancelled and reported as its own shutdown's.  What was cut short is the message's to say: those reports
    are dropped; every other goes to the default."""

    def handler(loop: asyncio.AbstractEventLoop, context: dict[str, Any]) -> None:
        if forced and context.get("task") is forced[0]:
            return
        message = str(context.get("message", ""))
        if len(pressed) >= 2 and (message.endswith("exception was never retrieved") or message == _SHUTDOWN_REPORT):
            return
        loop.default_exception_handler(context)

    loop.set_exception_handler(handler)


def _forced_out(task: asyncio.Task[T]) -> T:
    """A second Ctrl-C forced the command out as it stopped, and the runner's close has ended its task: the
    command's own account of what it left is raised, as an interruption; a command that finished all the same
    returns what it did; else KeyboardInterrupt."""
    if not task.done() or task.cancelled():
        raise KeyboardInterrupt
    error = task.exception()
    if error is None:
        return task.result()
    if isinstance(error, CliError):
        if error.code != ExitCode.INTERRUPTED:
            error.code, error.message = ExitCode.INTERRUPTED, f"interrupted: {error.message}"
        raise error from None
    raise KeyboardInterrupt from None  # (another failure as it was forced out: an interruption all the same)


@contextlib.contextmanager
def _ctrl_c(command: list[asyncio.Task[T]], loops: list[asyncio.AbstractEventLoop]) -> Iterator[list[int]]:
    """Ctrl-C while a command runs on the loop, as asyncio's runner takes it but for where the second raises.

    The first cancels the command's task (it stops as it does at Ctrl-C: play slows to rest).  The second
    forces it out: KeyboardInterrupt, raised by the loop between two of its callbacks.  asyncio's runner
    raises it in its signal handler, wherever the main thread is: inside a weakref callback Python prints
    it as "Exception ignored in ..." and drops it (the command goes on), inside the library it cuts a step
    in half.  A third raises it at once (a loop stuck in a call that never returns).  One within a second after
    the loop ends is taken for the same stop (see the end).  A first press once the command's task (``command``)
    is over, as the runner closes the loop, is raised once it has: inside uvloop's own step it left the loop
    running and unclosable ("Cannot close a running event loop"), and the close lets the port go cleanly.  A
    press raised at once is raised by the loop (``loops``' one) when it lands in uvloop's own step as a run of the
    loop starts or ends (see :func:`_raised_by_the_loop`).  Yields the presses."""
    pressed: list[int] = []
    after_the_command: list[bool] = []  # a first press came once the command's task was over
    same_stop: list[int] = []  # a second press taken for the first's stop (see nothing_left_to_cut_short)
    left_to_the_loop: list[bool] = []  # a press the loop is to raise, until it has
    if (
        threading.current_thread() is not threading.main_thread()
        or _unwrapped(signal.getsignal(signal.SIGINT)) is not signal.default_int_handler  # (see below)
    ):
        yield pressed  # (asyncio's runner takes it, as before, or a handler of the program's own)
        return

    def on_sigint(signum: int, frame: FrameType | None) -> None:
        pressed.append(signum)
        ctrl_c_typed()  # (what -v logs as the command stops starts a line of its own: see _settings)
        task = current_task()
        try:
            if len(pressed) == 1 and task is not None and not task.done():
                task.get_loop().call_soon_threadsafe(task.cancel)
                return
            if len(pressed) == 1 and command and command[0].done():
                after_the_command.append(True)  # (raised at the end, once the runner has closed the loop)
                return
            if len(pressed) == 2 and not same_stop and task is not None and stop_cuts_nothing(task):
                # Nothing left for it to cut short: the same stop, as one after the loop ended is.  Not counted,
                # so that the next press forces out as a second one would.
                same_stop.append(pressed.pop())
                return
            if len(pressed) == 2:
                # Forced out: a later press's KeyboardInterrupt, raised wherever the command then is, can land
                # between a coroutine's making and its first step (``await f()``), dropping it there, and
                # Python would print a "coroutine ... was never awaited" warning through a live table being torn
                # down.  (Those the exception keeps, and the tasks the closed loop leaves unrun, are closed by
                # _dropping_unrun.)
                warnings.filterwarnings("ignore", "coroutine .* was never awaited", RuntimeWarning)
            if len(pressed) == 2 and task is not None and not task.done():
                task.get_loop().call_soon_threadsafe(_interrupt)
                return
        except RuntimeError:  # the loop is closed
            pass
        if len(pressed) == 2:
            return  # the command has ended (the first press stopped it): this one is the same stop (see the end)
        if _raised_by_the_loop(loops, left_to_the_loop):
            return
        raise KeyboardInterrupt

    def on_unraisable(unraisable: Any) -> None:
        if unraisable.exc_type is KeyboardInterrupt and len(pressed) >= 2:
            # A forcing press raised where Python only prints an exception and drops it (a weakref callback, a
            # finalizer: "Exception ignored in ..." and its traceback under the table) and the close went on as
            # if it had not come: it is raised again, by the loop as the second press's is (the main thread may
            # be about to wait in it), or else at the main thread's next step.
            try:
                asyncio.get_running_loop().call_soon_threadsafe(_interrupt)
            except RuntimeError:  # (no loop running)
                _thread.interrupt_main(signal.SIGINT)
            return
        previous_unraisable(unraisable)

    previous_unraisable = sys.unraisablehook
    sys.unraisablehook = on_unraisable
    signal.signal(signal.SIGINT, on_sigint)
    try:
        yield pressed
        if after_the_command or left_to_the_loop:  # (the loop closed before it ran the press it was left)
            raise KeyboardInterrupt
    finally:
        if sys.unraisablehook is on_unraisable:
            sys.unraisablehook = previous_unraisable
        if signal.getsignal(signal.SIGINT) is on_sigint:
            if pressed:
                # A double Ctrl-C's second press landing once the loop is over would raise KeyboardInterrupt
                # wherever the command then is (making its message: a bare "interrupted" instead), or kill
                # the process as Python ends: within a moment it is the same press, as the library's run() has it.
                _after_stop({signal.SIGINT: signal.default_int_handler})
            else:
                signal.signal(signal.SIGINT, signal.default_int_handler)
        if pressed:  # (what the command says next, a report or its error, must not follow the echoed ^C)
            from ..terminal import clear_echoed_ctrl_c

            clear_echoed_ctrl_c()


def _interrupt() -> None:
    raise KeyboardInterrupt  # (a loop callback's KeyboardInterrupt leaves run_until_complete)


def _raised_by_the_loop(loops: list[asyncio.AbstractEventLoop], left: list[bool]) -> bool:
    """A press to raise at once, landing in uvloop's own step as a run of the loop starts or ends, is left to the
    loop to raise (between its callbacks) and True; else False (raised where it landed).

    uvloop marks itself running, then makes its self-pipe with Python's socket code (closing it as the run ends,
    before it unmarks itself): a KeyboardInterrupt raised in between left the loop marked running for good, and
    the runner's close failed ("Cannot close a running event loop", exit code 1).  Running, yet not the thread's
    running loop, is that window (asyncio's loop unmarks itself first).  A press left to a run that is ending is
    raised by the loop's next run (the runner's close has more) or once the loop has closed (:func:`_ctrl_c`)."""
    loop = loops[0] if loops else None
    if loop is None or not loop.is_running() or asyncio._get_running_loop() is loop:
        return False
    if not left:

        def interrupt() -> None:
            left.clear()
            raise KeyboardInterrupt

        left.append(True)
        loop.call_soon_threadsafe(interrupt)
    return True
