"""Running a controller program until it ends or is told to stop (Ctrl-C, SIGTERM, SIGHUP), servos at rest.

A robot program is stopped by Ctrl-C at a terminal, by SIGTERM from a
service manager (systemd, Docker, a supervisor) and by SIGHUP when its
terminal goes (the window closed, the ssh link dropped).  Without help,
SIGTERM and SIGHUP end the process on the spot (no ``finally``, no ``async
with`` exit: the servos keep whatever they were last told), and Ctrl-C
prints asyncio's ``KeyboardInterrupt`` traceback.  :func:`run` turns these
signals into a cancellation of ``main``: its ``async with`` blocks unwind in order (a stream
closes as its ``on_close`` says, a robot's joints hold or go free as its own
says, a bus drains and releases its port), then it returns an exit code for ``sys.exit``.  A second
signal while that unwinding runs is said with one line and the unwinding goes on
(the servos are being put to rest); a third forces the program out at once,
cutting it short.  One just after it ended (a double Ctrl-C) is taken for the
same stop: the program ends as the first one had it, with no traceback.
SIGHUP is taken only where it has its default handler (a program's own, a
configuration reloaded, is left to it; ``nohup`` leaves it ignored), and
once it has come the terminal is gone: what is written to it from then on
is dropped, not an error cutting the close short.
"""

from __future__ import annotations

import asyncio
import atexit
import contextlib
import functools
import importlib
import inspect
import logging
import os
import signal
import sys
import threading
import time
import typing
from collections.abc import AsyncIterator, Awaitable, Callable, Iterator
from types import FrameType
from typing import Any, Literal, NoReturn, Protocol, TypeVar, cast

from .errors import IcsError, InvalidArgument, error_text
from .tasks import only_error
from .terminal import ctrl_c_typed, leave_the_terminal, losses_said_at_the_end

EXIT_OK = 0
EXIT_ERROR = 1  # main raised an IcsError (printed as one line)
EXIT_SIGINT = 128 + signal.SIGINT  # 130, as a shell reports a Ctrl-C'd program
EXIT_SIGTERM = 128 + signal.SIGTERM  # 143
EXIT_SIGHUP = 128 + 1  # 129: 128 + SIGHUP's number (the name is not there on Windows)
_SIGHUP: signal.Signals | None = getattr(signal, "SIGHUP", None)
STOPPING: tuple[signal.Signals, ...] = (signal.SIGINT, signal.SIGTERM, *([] if _SIGHUP is None else [_SIGHUP]))
AFTER_STOP = 1.0  # seconds after a stop's close when another stop signal is taken for the same press

Backend = Literal["asyncio", "uvloop", "trio"]


def run(main: Callable[[], Awaitable[object]], *, backend: Backend = "asyncio") -> int:
    """Run ``main()`` until it returns, or until SIGINT (Ctrl-C), SIGTERM or SIGHUP cancels it; return an exit code.

    0 when ``main`` returned; 130 after SIGINT, 143 after SIGTERM and 129 after SIGHUP, once ``main``'s
    ``async with`` blocks have closed (streams, robots, buses, in that order); 1 when
    ``main`` raised an :class:`~ics35_async.IcsError`, printed to stderr as one line
    without a traceback.  A second signal while the blocks close is said with one line and they go on
    closing; a third forces the program out at once (by that signal), cutting the close short.  Other
    exceptions propagate (main's own, not the task group that ran it); ``sys.exit()`` in ``main`` ends the
    program with its code once everything has closed.
    SIGHUP (the terminal gone) is taken only where its handler is the default one as ``run`` starts: a handler of
    the program's own keeps it, and one ``nohup`` left ignored stays so; after it, what the program writes to
    that terminal is dropped rather than failing its close.
    ``backend``: ``"asyncio"``, ``"uvloop"`` (needs the uvloop package) or ``"trio"``.  Call it
    from the main thread, outside any event loop::

        async def main() -> None:
            async with open_bus("/dev/ttyUSB0") as bus, bus.stream(ids, rate_hz=100, on_close="free") as s:
                async for frame in s:
                    ...


        sys.exit(ics35_async.run(main))

    Raises:
        InvalidArgument: ``main`` is a coroutine (``run(main())``: pass ``main`` itself) or not callable,
            an unknown ``backend`` or one not installed (the message names the extra that installs it), an event loop
            already runs in this thread, or this is not the main thread; or ``main()`` gave nothing
            to await (``def main()`` for ``async def main()``: said once that call has returned; a program with
            no async code at all runs with :func:`run_blocking`).
    """
    import anyio

    _check_run(main, backend)
    stopping = _heard()
    received: list[int] = []
    exited: list[SystemExit] = []
    misused: list[InvalidArgument] = []  # main was a plain function: `def main()` meant as `async def main()`

    def outside(signum: int, frame: FrameType | None) -> None:
        """A stop signal while the receiver below is not open (the loop starting, or ending): one before a stop
        is the stop (main, if it has not started, never does); one after it is the same press, ignored.  Without
        it such a signal meets Python's handler (or trio's): a KeyboardInterrupt's traceback, or the program
        killed; and trio gives its receiver's signals still queued as it closes to the handler it puts back."""
        _hung_up(signum)
        if not received:
            received.append(signum)

    async def until_signal() -> None:
        if not stopping:  # (both ignored: nothing to listen for, and trio refuses a receiver of none)
            await listening(_no_signals())
            return
        receiver = anyio.open_signal_receiver(*stopping)
        signals = receiver.__enter__()
        try:
            if threading.current_thread() is threading.main_thread():
                # A blocking call of ics35_async.blocking in main holds the event loop, and so the receiver: the
                # signal's Python handler, run in the main thread whatever it waits for, hands it to that call.
                _hand_back([(signum, _after_the_loop_s(signal.getsignal(signum))) for signum in stopping])
                if received and stop_signals.signum is None:  # (one came as the loop started: the next is a press)
                    stop_signals.signum = received[0]
            await listening(signals)
        finally:
            try:
                receiver.__exit__(None, None, None)
                # asyncio's receiver puts Python's own handlers back as it closes, whatever was there before.
                _hand_back([(signum, outside) for signum in stopping])
            except KeyboardInterrupt:  # a Ctrl-C just then, on Python's handler
                outside(signal.SIGINT, None)
                _hand_back([(signum, outside) for signum in stopping])

    async def listening(signals: AsyncIterator[int]) -> None:
        async with anyio.create_task_group() as tasks:
            main_scope = anyio.CancelScope()

            async def main_then_stop() -> None:
                try:
                    with main_scope:
                        if received:  # as the loop started
                            main_scope.cancel()
                        awaitable = main()
                        if inspect.isawaitable(awaitable):
                            await awaitable
                        else:  # (raised below, as run()'s misuse: not printed as main's IcsError)
                            misused.append(not_async(main, awaitable))
                except _Stopped:  # a blocking call in main took the stop signal (see _after_the_loop_s)
                    pass
                except SystemExit as exc:  # sys.exit() in main: its code, once everything has closed
                    exited.append(exc)
                tasks.cancel_scope.cancel()  # main is done (or cancelled): stop listening

            async def listen() -> None:
                async for signum in signals:  # (a second or third press is said, or forces out, in its handler)
                    if not received:
                        received.append(int(signum))
                        stop_signals.deferred = False  # (main is cancelled: its blocking calls, closes, go on)
                        main_scope.cancel()

            tasks.start_soon(main_then_stop)
            tasks.start_soon(listen)

    options: dict[str, object] = {}
    name = backend
    if backend == "uvloop":
        import uvloop

        name, options = "asyncio", {"loop_factory": uvloop.new_event_loop}
    failure: BaseException | None = None
    before: list[tuple[int, object]] = []
    try:
        if threading.current_thread() is threading.main_thread():  # (else the receiver refuses, as it should)
            before = [(signum, _unwrapped(signal.signal(signum, outside))) for signum in stopping]
        with _run_under_way(), stop_signals.in_run():
            anyio.run(until_signal, backend=name, backend_options=options)
    except BaseException as exc:
        if _said(exc):
            return EXIT_ERROR
        # main's own exception (its own group included), not the task group that ran it: raised
        # below, out of this handler, so that its cause and context stay as main left them.
        failure = exc.exceptions[0] if isinstance(exc, BaseExceptionGroup) and len(exc.exceptions) == 1 else exc
    finally:
        if not received and stop_signals.signum is not None:  # taken by a blocking call, main ended before the loop
            received.append(stop_signals.signum)
        if received:
            _after_stop(dict(before))  # (a double press's second one may still come, as the program ends)
        else:
            _hand_back(before)
    if misused:
        raise misused[0]
    if failure is not None:
        raise failure
    if exited:
        raise exited[0]
    if not received:
        return EXIT_OK
    return _exit_code(received[0])


@contextlib.contextmanager
def _run_under_way() -> Iterator[None]:
    """The :func:`run` or :func:`run_blocking` call under way: the ports lost for good while it runs are said
    once, as it ends (see :func:`~ics35_async.terminal.said_at_the_end`)."""
    kept: list[tuple[logging.Logger, str]] = []
    ending = ""
    try:
        with losses_said_at_the_end() as kept:
            yield
    except BaseException as exc:
        error = only_error(exc)
        ending = str(error) if isinstance(error, IcsError) else ""  # (what _said then prints)
        raise
    finally:
        # Before the program's last line: a loss the ending says is not said twice, and one it does not say
        # (the program went on without that port, or caught its PortLost) is not left unsaid.
        for logger, message in kept:
            if message not in ending:
                logger.warning("%s", message)


def _said(exc: BaseException) -> bool:
    """A library error (alone in any exception groups around it) said on stderr as one line, no traceback: the
    ending of a program run by :func:`run` or :func:`run_blocking`; False (nothing said) for anything else."""
    error = only_error(exc)
    if not isinstance(error, IcsError):
        return False
    print(f"error: {error_text(error)}", file=sys.stderr)
    return True


def run_blocking(main: Callable[[], object]) -> int:
    """:func:`run` for programs without an event loop (``ics35_async.blocking.run``): call the plain function
    ``main()`` under :func:`stop_on_signals` and return an exit code, the same as :func:`run`'s.

    0 when ``main`` returned; 130 after SIGINT (Ctrl-C), 143 after SIGTERM and 129 after SIGHUP (taken as
    :func:`run` takes it), once its ``with`` blocks have closed (a stream frees or holds as its ``on_close``
    says, a bus releases its port); 1 when ``main`` raised an :class:`~ics35_async.IcsError` (a lost port, a
    mistyped one), printed to stderr as one line, with its hint, without a traceback.  Other exceptions propagate
    as ``main`` raised them, with their traceback (a bug); ``sys.exit()`` in ``main`` ends the program with its
    code.  An error ``main`` catches itself (``except PortLost``) is its own, as without ``run``.  Call it from
    the main thread::

        def main() -> None:
            with blocking.open_bus("/dev/ttyUSB0") as bus, bus.stream(ids, rate_hz=50, on_close="free") as s:
                for frame in s:
                    ...


        sys.exit(blocking.run(main))

    Raises:
        InvalidArgument: ``main`` is an async function (``ics35_async.run`` runs it), a coroutine or not
            callable, or this is not the main thread; or ``main()`` returned an awaitable (said once that call has
            returned).
    """
    _check_plain_function(main)
    if not stop_signals.active:  # (inside a stop_on_signals of the program's own, that one takes the signals)
        _check_main_thread("blocking.run()", "in another thread, call main() itself, without them")
    inside = stop_signals.active  # inside a stop_on_signals of the program's own: that one stops the program
    misused: InvalidArgument | None = None  # (raised below, as run_blocking's misuse: not printed as main's error)
    try:
        with _run_under_way(), stop_on_signals():
            returned = main()
            if inspect.isawaitable(returned):  # (a partial of an async function, say)
                if inspect.iscoroutine(returned):
                    returned.close()  # (never awaited: no warning about it on top of the error)
                misused = _not_plain(main)
    except SystemExit as exc:
        # The stop's own exit (not main's sys.exit(), which goes on as main raised it): its code, returned.
        if inside or stop_signals.signum is None or exc.code != _exit_code(stop_signals.signum):
            raise
        return _exit_code(stop_signals.signum)
    except BaseException as exc:
        if _said(exc):
            return EXIT_ERROR
        raise
    if misused is not None:
        raise misused
    return EXIT_OK


def _check_plain_function(main: object) -> None:
    """What :func:`run_blocking` refuses before it starts anything: an async function (or its coroutine), which
    :func:`run` runs, or something not callable."""
    if inspect.iscoroutine(main):
        main.close()  # (never awaited: no warning about it on top of the error)
        raise InvalidArgument(
            "blocking.run() takes a plain function; an async one runs with ics35_async.run(main), "
            "not blocking.run(main())"
        )
    if not callable(main):
        # (None, most likely what main() returned: the call in blocking.run(main()) ran it first, without run)
        raise InvalidArgument(
            f"blocking.run() takes a plain function, not {type(main).__name__}: the function itself, "
            "blocking.run(main), not blocking.run(main()), which calls main before blocking.run can start"
        )
    if inspect.iscoroutinefunction(main) or inspect.isasyncgenfunction(main):
        raise _not_plain(main)


def _not_plain(main: Callable[..., object]) -> InvalidArgument:
    name = getattr(main, "__name__", "")
    name = name if name.isidentifier() else "main"
    return InvalidArgument(
        f"blocking.run() takes a plain function: async def {name}() runs with ics35_async.run({name})"
    )


def _after_the_loop_s(handler: object) -> Callable[[int, FrameType | None], None]:
    """A stop signal's Python handler under :func:`run`: the event loop's own ``handler`` (which notes it for the
    loop's receiver), then :meth:`_StopSignals.heard_by_run`."""

    def heard(signum: int, frame: FrameType | None) -> None:
        _hung_up(signum)
        try:
            if callable(handler):
                handler(signum, frame)
        finally:
            stop_signals.heard_by_run(signum)

    return heard


def _heard() -> tuple[signal.Signals, ...]:
    """The stop signals the program takes: those it was not started ignoring.  A shell without job control
    (a script) starts a background command with SIGINT ignored, so that the Ctrl-C typed for its foreground
    command does not stop it too, and ``nohup`` has SIGHUP ignored the same way: such a signal stays ignored.
    SIGHUP is taken only from its default handler (the process dies): a program's own handler of it (a
    configuration reloaded) is the program's way of taking it, kept as it is."""
    return tuple(
        signum
        for signum in STOPPING
        if signal.getsignal(signum) is not signal.SIG_IGN
        and (signum != _SIGHUP or _unwrapped(signal.getsignal(signum)) is signal.SIG_DFL)
    )


def _hung_up(signum: int) -> None:
    """In each of the stop signals' handlers, first: after SIGHUP the terminal is gone, and a write to it (the
    program's, the library's last words) would fail and cut the close short; from then on it is dropped."""
    if signum == _SIGHUP:
        leave_the_terminal()


async def _no_signals() -> AsyncIterator[int]:
    """A receiver of no signals: waits until cancelled."""
    import anyio

    await anyio.sleep_forever()
    yield 0  # (never reached: makes this an async generator)


def _check_run(main: object, backend: str) -> None:
    """What :func:`run` refuses before it starts anything (the habits of ``asyncio.run``)."""
    check_async_function(main, "run")
    if inspect.isasyncgenfunction(main):  # (its call gives something to iterate, not to await)
        raise not_async(main, main())
    if backend not in typing.get_args(Backend):
        raise InvalidArgument(f"backend must be one of {', '.join(typing.get_args(Backend))}, not {backend!r}")
    if backend != "asyncio":  # (an extra: its absence said here, not as an import's traceback from inside the run)
        try:
            importlib.import_module(backend)
        except ImportError:
            from .extras import extra_hint  # (said the way this copy was installed: a clone's extras come from it)

            raise InvalidArgument(
                f"backend={backend!r} needs {backend}: {extra_hint(backend)} (or run on asyncio)"
            ) from None
    if _in_event_loop():
        raise InvalidArgument("run() starts its own event loop: inside a running event loop, await main() instead")
    _check_main_thread("run()", "in another thread, asyncio.run(main()) runs it, without them")


def _check_main_thread(taker: str, elsewhere: str) -> None:
    """``taker`` takes the stop signals, which Python hands to the main thread only (elsewhere ``signal.signal``
    raises ``ValueError``, an event loop's signal receiver ``RuntimeError``): said before anything runs."""
    if threading.current_thread() is not threading.main_thread():
        raise InvalidArgument(
            f"{taker} takes Ctrl-C, SIGTERM and SIGHUP, which Python hands to the main thread only: call it from the "
            f"main thread ({elsewhere})"
        )


def check_async_function(fn: object, taker: str, *, with_args: bool = False) -> None:
    """What ``taker`` (:func:`run`; ``bus.run`` and ``robot.run``, ``with_args``: they take the function's
    arguments too) refuses before anything runs: a coroutine (``run(main())``) or something not callable."""
    if inspect.iscoroutine(fn):
        fn.close()  # (never awaited: no warning about it on top of the error)
        right, wrong = ("fn, *args", "fn(*args)") if with_args else ("main", "main()")
        what = "and its arguments" if with_args else "itself"
        raise InvalidArgument(f"{taker}() takes the async function {what}: {taker}({right}), not {taker}({wrong})")
    if not callable(fn):
        raise InvalidArgument(f"{taker}() takes an async function, not {type(fn).__name__}")


def not_async(fn: Callable[..., object], returned: object, taker: str = "run()") -> InvalidArgument:
    """The misuse of ``taker`` (:func:`run`, ``BlockingBus.run``) by an ``fn`` whose call gave nothing to
    await: ``def main()`` for ``async def main()``."""
    name = getattr(fn, "__name__", "")
    kind = type(returned).__name__
    what = "None" if returned is None else f"{'an' if kind[:1] in 'aeiou' else 'a'} {kind}"
    if not name.isidentifier():  # a lambda, a partial: nothing to name
        return InvalidArgument(f"{taker} takes an async function: the function given returned {what}, not an awaitable")
    # A plain function meant as one (no async anywhere in the program) has a runner of its own.
    plain = "" if taker != "run()" or inspect.isasyncgen(returned) else f" (a plain one runs with blocking.run({name}))"
    return InvalidArgument(
        f"{taker} takes an async function (async def {name}()): {name}() returned {what}, not an awaitable{plain}"
    )


def _in_event_loop() -> bool:
    try:
        asyncio.get_running_loop()
    except RuntimeError:
        pass
    else:
        return True
    trio = sys.modules.get("trio")  # (imported by whoever runs trio)
    if trio is None:
        return False
    try:
        trio.lowlevel.current_task()
    except RuntimeError:
        return False
    return True


class _Stopped(SystemExit):
    """Raised in the main thread by a signal inside :func:`stop_on_signals` (not an error: a stop).

    A ``SystemExit`` with the signal's exit code: :func:`stop_on_signals` hands the program a plain one,
    and should a signal land in its own last steps, this one ends the program as cleanly.
    """

    def __init__(self, signum: int) -> None:
        super().__init__(_exit_code(signum))
        self.signum = signum


def _exit_code(signum: int) -> int:
    if signum == signal.SIGINT:
        return EXIT_SIGINT
    return EXIT_SIGHUP if signum == _SIGHUP else EXIT_SIGTERM


def _signal_name(signum: int) -> str:
    return "Ctrl-C" if signum == signal.SIGINT else signal.Signals(signum).name


def _say(text: str) -> None:
    """A line on stderr from a signal handler: straight to its file descriptor where it has one (the main
    thread may be inside a write to ``sys.stderr``'s buffer, which would refuse a second one)."""
    stream = sys.stderr
    if stream is None:
        return
    try:
        fd = stream.fileno()
    except (OSError, ValueError, AttributeError):
        with contextlib.suppress(Exception):
            stream.write(text)
        return
    with contextlib.suppress(OSError):
        os.write(fd, text.encode(errors="replace"))


class _Presses:
    """The stop signals after the first while its close runs: the second is said, the third forces out.

    Ignored without a word, a second Ctrl-C would look lost, and a program whose close hangs (a port gone
    mid-write) could not be stopped from its terminal."""

    def __init__(self) -> None:
        self.count = 0

    def again(self, signum: int) -> None:
        if signum == _SIGHUP:
            # No one's press: a closed terminal sends it twice or more (the kernel to the foreground group, the
            # shell to its jobs), and a third must not cut the close short; no one is there to read a line.
            return
        self.count += 1
        name = _signal_name(signum)
        if self.count == 1:
            _say(
                f"{name} again: still stopping, the servos are being put to rest "
                f"({name} once more forces out, cutting that short)\n"
            )
        else:
            _force_out(signum)


def _force_out(signum: int) -> NoReturn:
    """End the process now, by ``signum`` as a shell expects of a signal it sent (the close is cut short)."""
    _say(f"{_signal_name(signum)}: forced out; the close was cut short (each servo keeps whatever it was last sent)\n")
    with contextlib.suppress(Exception):  # (may be inside a write of its own: then what it holds is lost)
        sys.stdout.flush()
    with contextlib.suppress(OSError, ValueError, TypeError):
        signal.signal(signum, signal.SIG_DFL)
        os.kill(os.getpid(), signum)
    os._exit(_exit_code(signum))  # (where a signal to itself does not end it)


class _AfterStop:
    """A stop signal's handler for the moment a stopped program takes to end, its closes over.

    A double Ctrl-C's second press lands there: Python's own handler would print KeyboardInterrupt's
    traceback over the program's last steps, or kill it.  Within :data:`AFTER_STOP` seconds it is taken for
    the same stop and ignored; later (a program that went on after its stop) the handler that was there
    before is put back and has it."""

    def __init__(self, previous: object) -> None:
        self.previous = previous
        self.until = time.monotonic() + AFTER_STOP

    def __call__(self, signum: int, frame: FrameType | None) -> None:
        _hung_up(signum)
        if time.monotonic() < self.until:
            if signum == signal.SIGINT:
                ctrl_c_typed()  # (its ^C is echoed where the program's last words go: they clear it first)
            return
        with contextlib.suppress(TypeError, ValueError):
            signal.signal(signum, self.previous)  # type: ignore[arg-type]
        if callable(self.previous):
            self.previous(signum, frame)
        elif self.previous == signal.SIG_DFL:
            os.kill(os.getpid(), signum)


def _unwrapped(handler: object) -> object:
    """The handler an :class:`_AfterStop` stands in for (a new stop's block is its own, and gives that back)."""
    return handler.previous if isinstance(handler, _AfterStop) else handler


def _after_stop(previous: dict[int, object]) -> None:
    """Once a stop's closes are over: each stop signal's handler an :class:`_AfterStop` in front of ``previous``."""
    if threading.current_thread() is threading.main_thread():
        if not _exiting:
            _exiting.append(atexit.register(_ignore_at_exit))
        _hand_back([(signum, _AfterStop(handler)) for signum, handler in previous.items()])


_exiting: list[object] = []  # _ignore_at_exit, once registered


def _ignore_at_exit() -> None:
    """A stopped program's last steps: Python puts every handler of its own back to the default as it ends,
    and a double Ctrl-C's second press would then kill it (by SIGINT, not with its stop's exit code)."""
    for signum in STOPPING:
        with contextlib.suppress(TypeError, ValueError):
            if isinstance(signal.getsignal(signum), _AfterStop):
                _ignore(signum)


def _ignore(signum: int) -> None:
    """``signal.signal(signum, SIG_IGN)`` with the signal blocked meanwhile: one arriving between Python's
    handler turning SIG_IGN and the kernel's was reported by Python, as the program ended, as "OSError: Signal 2
    ignored due to race condition" with a traceback (a double Ctrl-C's second press).  Blocked, it waits; a
    pending signal whose action becomes SIG_IGN is dropped by the kernel."""
    block = getattr(signal, "pthread_sigmask", None)  # (not on Windows)
    if block is None:
        signal.signal(signum, signal.SIG_IGN)
        return
    before = block(signal.SIG_BLOCK, {signum})
    try:
        signal.signal(signum, signal.SIG_IGN)
    finally:
        block(signal.SIG_SETMASK, before)


class Wakeable(Protocol):
    def wake(self) -> None: ...


class _NeverWoken:
    """The wait of :meth:`_StopSignals.held`: a stop signal waits for its end, nothing wakes it."""

    def wake(self) -> None:
        pass


_NEVER_WOKEN = _NeverWoken()


class _StopSignals:
    """Where :func:`stop_on_signals` raises its stop, given what the main thread is doing.

    An exception from a signal handler lands between any two bytecodes of the
    main thread: inside a finalizer or weakref callback it is printed and
    dropped (the program would go on), and inside library code it can cut a
    step in half.  So while the main thread waits for a blocking call
    (:mod:`ics35_async.blocking.loop_thread` registers each wait), the signal
    is deferred: the wait is woken and raises the stop itself, at a point
    where nothing is half done; inside a close (a function marked
    :func:`close_step`, or anything it calls) the signal is deferred too and
    raised once the close is over.  Elsewhere, in the program's own code,
    the handler raises at once, as Ctrl-C does; if a finalizer or weakref
    callback it landed in drops it, the program's next blocking call raises it.
    """

    def __init__(self) -> None:
        self.active = False
        self.signum: int | None = None  # the first stop signal; later ones are ignored
        self.deferred = False  # a wait took the signal and owes the raise
        # The wait under way and whether it holds signals till it ends: one value, so that a handler
        # running between two stores never sees half of a change.
        self._current: tuple[Wakeable | None, bool] = (None, False)
        self.unraisablehook = sys.unraisablehook
        self.presses = _Presses()

    def start(self) -> None:
        self.active, self.signum, self.deferred = True, None, False
        self._current = (None, False)
        self.presses = _Presses()

    def handle(self, signum: int, frame: FrameType | None) -> None:
        _hung_up(signum)
        if not self.active:  # stop_on_signals is ending: noted, and raised once its handlers are given back
            self.signum = self.signum or signum
            return
        wait, holding = self._current
        if self.signum is None:
            self.signum = signum
        elif not (self.deferred and wait is None):
            self.presses.again(signum)  # while the with blocks close (servos being put to rest): said, or forced
            return
        # (else the first is still owed: a finalizer dropped it)
        if wait is None:
            if _inside_a_close(frame):  # a close begun is not cut in half: raised as it returns
                self.deferred = True
                return
            self.deferred = False
            raise _Stopped(self.signum)
        self.deferred = True
        if not holding:
            wait.wake()

    @contextlib.contextmanager
    def in_run(self) -> Iterator[None]:
        """While :func:`run` runs ``main`` (unless inside a :func:`stop_on_signals`, which then stops the program):
        blocking waits are registered, as under :func:`stop_on_signals`, for :meth:`heard_by_run`."""
        if self.active:
            yield
            return
        self.start()
        try:
            yield
        finally:
            self.active = False

    def heard_by_run(self, signum: int) -> None:
        """A stop signal under :func:`run`, after the event loop's own handler noted it for the loop's receiver.

        The first, while the main thread waits for a blocking call (the loop held by it, its receiver too), is
        that call's to raise, as :func:`stop_on_signals` has it; otherwise the loop's receiver cancels ``main``.
        A second is said, a third forces out, wherever the main thread is (a blocking close holding the loop
        could not be forced out from the loop)."""
        if not self.active:
            return
        if self.signum is not None:
            self.presses.again(signum)
            return
        # Owed to the next blocking call too: one landing between two (main's own code, the loop held all along)
        # raises it there; the loop's receiver takes it back if the loop runs first (see run's listen).
        self.signum, self.deferred = signum, True
        wait, holding = self._current
        if wait is not None and not holding:
            wait.wake()

    def waiting(self, wait: Wakeable) -> contextlib.AbstractContextManager[None]:
        """Around a blocking wait: a stop signal meanwhile wakes it (``wait.wake()``), and the wait raises it."""
        return self._around(wait, holding=False)

    def held(self) -> contextlib.AbstractContextManager[None]:
        """Around a close (or a wait that must not be cut short): a stop signal meanwhile is raised once it ends."""
        return self._around(_NEVER_WOKEN, holding=True)

    @contextlib.contextmanager
    def _around(self, wait: Wakeable, *, holding: bool) -> Iterator[None]:
        """The outermost raises, as it ends, a stop still owed."""
        if not self.active or threading.current_thread() is not threading.main_thread():
            yield  # signals run in the main thread only
            return
        outer = self._current
        self._current = (wait, holding or outer[1])
        try:
            yield
        finally:
            self._current = outer
            if outer[0] is None:
                self.take()  # a signal that came as the wait ended: raised now, not at the next call

    def take(self) -> None:
        """At a safe point of a blocking wait: raise the stop that wait owes (or one a finalizer dropped)."""
        if self.active and self.deferred and threading.current_thread() is threading.main_thread():
            self.deferred = False
            raise _Stopped(self.signum or signal.SIGTERM)

    def dropped(self, unraisable: Any) -> None:
        """``sys.unraisablehook`` meanwhile: a stop raised inside a finalizer was dropped; the next wait owes it."""
        if isinstance(unraisable.exc_value, _Stopped):
            self.deferred = True
        else:
            self.unraisablehook(unraisable)


stop_signals = _StopSignals()

F = TypeVar("F", bound=Callable[..., Any])


def close_step(function: F) -> F:
    """``function`` puts servos to rest or releases a port (a blocking stream's or bus's ``close``, its
    ``__exit__``): a stop signal landing anywhere in it, or in anything it calls, waits for its end and is
    raised as the outermost close returns.  ``held()`` alone cannot do this: a signal can land in the few
    calls before a close enters it, and the close would then never run."""

    @functools.wraps(function)
    def closing(*args: Any, **kwargs: Any) -> Any:
        try:
            return function(*args, **kwargs)
        finally:
            if not _inside_a_close(sys._getframe(1)):
                stop_signals.take()  # the outermost close is over: the stop it held is raised now

    return cast(F, closing)


def _inside_a_close(frame: FrameType | None) -> bool:
    while frame is not None:
        if frame.f_code is _CLOSING:
            return True
        frame = frame.f_back
    return False


_CLOSING = close_step(lambda: None).__code__  # the code every close runs in (close_step's wrapper)


@contextlib.contextmanager
def stop_on_signals() -> Iterator[None]:
    """For programs without an event loop: SIGINT (Ctrl-C), SIGTERM and SIGHUP end the ``with`` block like an
    exception, so the ``with`` blocks inside it close in order (a blocking stream frees or holds as its
    ``on_close`` says, a bus releases its port), then the program exits with 130, 143 or 129 and no
    traceback (``SystemExit``).  SIGHUP (the terminal gone) is taken only where its handler is the default one
    as the block starts: a handler of the program's own keeps it, ``nohup``'s ignoring stays; after it, what
    is written to that terminal is dropped rather than failing the close.  A second signal while they close
    is said with one line and they go on closing; a third forces the program out at once, cutting the close
    short (a SIGHUP again counts for neither: a closed terminal sends it more than once); one just after they
    closed (a double Ctrl-C) is taken for the same stop.  Use it around everything, in the main thread::

        with stop_on_signals(), blocking.open_bus(port) as bus, bus.stream(ids, on_close="free") as s:
            ...

    Raises:
        InvalidArgument: this is not the main thread (Python hands signals to the main thread only), outside
            another ``stop_on_signals`` block.
    """
    if stop_signals.active:  # inside another stop_on_signals: that one stops the program
        yield
        return
    _check_main_thread("stop_on_signals()", "in another thread, leave it out: the blocking calls work without it")
    previous: dict[int, object] = {}
    stop_signals.unraisablehook = sys.unraisablehook
    try:
        stop_signals.start()
        sys.unraisablehook = stop_signals.dropped
        for stopping in _heard():
            previous[stopping] = _unwrapped(signal.signal(stopping, stop_signals.handle))
        yield
        if stop_signals.deferred:  # a finalizer dropped the stop after the block's last blocking call
            raise _Stopped(stop_signals.signum or signal.SIGTERM)
    except _Stopped as stopped:
        raise SystemExit(stopped.code) from None
    finally:
        # (``deferred`` may stay set: nothing reads it while inactive, and start() clears it.)
        try:
            stop_signals.active = False  # a signal from here on is only noted (see _StopSignals.handle)
            sys.unraisablehook = stop_signals.unraisablehook
        finally:  # a stop raised above, or a handler run as another goes back, must not leave one installed
            if stop_signals.signum is None:
                _hand_back(list(previous.items()))
            else:
                _after_stop(previous)
    # The block ended without a stop raised, yet one came: as the handlers went back, or the block's own
    # code swallowed it (``except SystemExit``).  A stop asked for is a stop: raised now.
    if stop_signals.signum is not None:
        raise SystemExit(_exit_code(stop_signals.signum))


def _hand_back(handlers: list[tuple[int, object]]) -> None:
    """Each signal's handler back, even when one (``signal.signal`` runs a pending signal's new handler as it
    installs it: a Ctrl-C then raises KeyboardInterrupt) raises as it goes back."""
    if handlers:
        (signum, handler), rest = handlers[0], handlers[1:]
        try:
            signal.signal(signum, handler)  # type: ignore[arg-type]
        finally:
            _hand_back(rest)


__all__ = [
    "EXIT_ERROR",
    "EXIT_OK",
    "EXIT_SIGHUP",
    "EXIT_SIGINT",
    "EXIT_SIGTERM",
    "run",
    "run_blocking",
    "stop_on_signals",
]
