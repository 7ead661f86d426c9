"""An asyncio event loop in a background thread, and blocking calls into it.

Every blocking call is one hop: the caller's thread hands a function to the
loop thread (``call_soon_threadsafe``) and waits for its result on an
:class:`Outcome`.  Whatever the function raises is raised in the caller's
thread, as it was, so typed errors stay typed (a library error without the
loop thread's frames, see :meth:`Outcome.result`).

This is what anyio's ``BlockingPortal`` does, minus its task group and
cancel scopes: a portal call measured about 400 us on the development
machine, this one 60-100 us, and a control loop makes two per frame.

Ctrl-C: Python raises ``KeyboardInterrupt`` in the main thread, which is the
caller waiting in :meth:`LoopThread.call`.  The call is then cancelled on the
loop, and the interrupt goes on only once the call has ended there, so
nothing it started still runs behind the caller's back.  Closing
(:meth:`LoopThread.call_to_end`, :meth:`LoopThread.stop`) holds a further
Ctrl-C until it is done, so an impatient second Ctrl-C still leaves the
port released and the thread gone.

Signals: a signal handler's exception (Ctrl-C's ``KeyboardInterrupt``,
:func:`~ics35_async.blocking.stop_on_signals`' stop) is raised in the main
thread between any two bytecodes.  ``concurrent.futures.Future`` and
``threading.Event`` wait on a ``threading.Condition``, which such an
exception can leave holding its lock (the loop thread then hangs settling
the call) or releasing one it no longer holds (``RuntimeError``).  An
:class:`Outcome` is waited on with one bare lock acquire, which a signal
interrupts cleanly, and is read from plain attributes.  Under
``stop_on_signals`` a stop signal during a wait wakes it, and the wait raises
the stop itself (see :class:`ics35_async.running._StopSignals`).
"""

from __future__ import annotations

import asyncio
import contextlib
import contextvars
import inspect
import threading
from collections.abc import Awaitable, Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Generic, ParamSpec, TypeVar, cast

import anyio

from ..errors import BusClosed, IcsError
from ..running import not_async, stop_signals
from ..tasks import again

P = ParamSpec("P")
T = TypeVar("T")

# How often a waiting caller checks that the loop thread is still alive (it never dies
# on its own; this only turns a broken invariant into BusClosed instead of a hang).
_ALIVE_CHECK = 0.5


class Outcome(Generic[T]):
    """A result or exception handed from the loop thread to a waiting thread, safe to wait on in a signal's path.

    The loop thread settles it once (:meth:`set_result`, :meth:`set_exception`);
    the waiting thread only reads ``done`` and acquires ``_wake``, a lock held
    from birth until the outcome is settled.
    """

    __slots__ = ("_exception", "_result", "_wake", "done")

    def __init__(self) -> None:
        self.done = False
        self._result: T | None = None
        self._exception: BaseException | None = None
        self._wake = threading.Lock()
        self._wake.acquire()

    def set_result(self, result: T) -> None:
        self._result = result
        self._settle()

    def set_exception(self, exception: BaseException) -> None:
        self._exception = exception
        self._settle()

    def _settle(self) -> None:
        if not self.done:
            self.done = True  # before the release: a waiter that wakes sees it
            _release(self._wake)

    def wake(self) -> None:
        """End a wait in progress early (a stop signal's handler, in the waiting thread)."""
        _release(self._wake)

    def wait(self, timeout: float) -> bool:
        """True once settled; waits at most ``timeout`` seconds for it (less if woken)."""
        if not self.done and self._wake.acquire(timeout=timeout) and self.done:
            # Settled: free again for any later wait.  Woken early instead (a stop signal), the lock
            # stays taken, so that a later wait blocks until the outcome is settled.  A signal between
            # the acquire and this release leaves it held: harmless, ``done`` is read first.
            _release(self._wake)
        return self.done

    def result(self) -> T:
        """The result, or the exception raised (call once settled).

        A library error comes without the frames it went through on the loop thread: they are the bus's
        inner workings, meaningless to the program whose call it fails, and its traceback ends at that call.
        Anything else (a bug) keeps them: they say where it happened."""
        if isinstance(self._exception, IcsError):
            raise again(self._exception)
        if self._exception is not None:
            raise self._exception
        return cast(T, self._result)


def _release(lock: threading.Lock) -> None:
    # The settling thread, a waker and the waiter may each release the wake lock once.
    with contextlib.suppress(RuntimeError):
        lock.release()


class _Call(Generic[T]):
    """One coroutine call on the loop: its outcome for the caller, its task for cancelling."""

    __slots__ = ("ended", "outcome", "task")

    def __init__(self) -> None:
        self.outcome: Outcome[T] = Outcome()
        self.ended: Outcome[None] = Outcome()  # the task has finished, whatever the outcome says
        self.task: asyncio.Task[T] | None = None

    def settle(self, task: asyncio.Task[T]) -> None:
        if task.cancelled():
            self.outcome.set_exception(BusClosed("bus closed while the call was waiting"))
        elif (exc := task.exception()) is not None:
            self.outcome.set_exception(exc)
        else:
            self.outcome.set_result(task.result())
        self.ended.set_result(None)

    def spawn(self, fn: Callable[..., Awaitable[T]], args: tuple[Any, ...], kwargs: dict[str, Any]) -> None:
        """Start the call's task (on the loop; ``fn`` is called there, not in the caller's thread)."""
        self.task = asyncio.create_task(_await(fn, args, kwargs))
        self.task.add_done_callback(self.settle)

    def cancel(self) -> None:
        # Callbacks run in the order they were scheduled: a spawn scheduled before us has run.
        if self.task is None:
            self.ended.set_result(None)  # never scheduled (Ctrl-C came first): nothing runs
        else:
            self.task.cancel()


async def _await(fn: Callable[..., Awaitable[T]], args: tuple[Any, ...], kwargs: dict[str, Any]) -> T:
    return await fn(*args, **kwargs)


async def awaited(taker: str, fn: Callable[P, Awaitable[T]], /, *args: P.args, **kwargs: P.kwargs) -> T:
    """``fn(*args, **kwargs)`` awaited for ``taker`` (``bus.run``), or :class:`InvalidArgument` if it gave
    nothing to await: a plain ``def``, whose result awaited would raise a TypeError from inside the loop."""
    result = fn(*args, **kwargs)
    if not inspect.isawaitable(result):
        raise not_async(fn, result, f"{taker}()")
    return await result


async def within(
    timeout: float | None, what: str, fn: Callable[P, Awaitable[T]], /, *args: P.args, **kwargs: P.kwargs
) -> T:
    """``fn(*args, **kwargs)`` awaited for at most ``timeout`` seconds (``None``: for as long as it takes): a
    blocking wait that gives up raises ``TimeoutError("no WHAT within T s")`` in the caller's thread."""
    try:
        with anyio.fail_after(timeout):
            return await fn(*args, **kwargs)
    except TimeoutError:
        if timeout is None:
            raise  # (the awaited call's own: a ReplyTimeout is a TimeoutError too)
        raise TimeoutError(f"no {what} within {timeout:g} s") from None


class LoopThread:
    """A daemon thread running an asyncio event loop, with blocking calls into it.

    A daemon thread, so that a program that forgets to close its bus still
    exits; :class:`~ics35_async.blocking.BlockingBus` closes the bus at exit.
    """

    def __init__(self, name: str, what: str = "bus") -> None:
        started: Outcome[asyncio.AbstractEventLoop] = Outcome()
        self._stop: asyncio.Event | None = None
        self._closed = False
        self.what = what  # what a call finds closed: "bus", "robot"
        self.closed_because = ""  # why it closed, when not by the program's close() (said with BusClosed)
        self._thread = threading.Thread(target=self._main, args=(started,), name=name, daemon=True)
        self._thread.start()
        try:
            self._loop = _result_holding_interrupts(started, self._thread)
        except BaseException:  # Ctrl-C or a stop signal while the thread started: end it before going on
            _wait_holding_interrupts(started, self._thread)
            self._loop = started.result()
            self.stop()
            raise

    def _main(self, started: Outcome[asyncio.AbstractEventLoop]) -> None:
        async def serve() -> None:
            self._stop = asyncio.Event()
            started.set_result(asyncio.get_running_loop())
            await self._stop.wait()

        # asyncio.run's ending (cancel what is left, the executor shut down, the loop closed), but for the executor:
        # asyncio joins it from a new thread, and Python 3.12 refuses to start one at interpreter exit, which is
        # where a bus the program never closed is closed.  Its workers (ports opened: idle by now) are joined here.
        executor = ThreadPoolExecutor(thread_name_prefix=self._thread.name)
        loop = asyncio.new_event_loop()
        loop.set_default_executor(executor)
        try:
            loop.run_until_complete(serve())
            left = asyncio.all_tasks(loop)
            for task in left:
                task.cancel()
            if left:
                loop.run_until_complete(asyncio.gather(*left, return_exceptions=True))
            loop.run_until_complete(loop.shutdown_asyncgens())
        finally:
            executor.shutdown(wait=True)
            loop.close()

    @property
    def thread(self) -> threading.Thread:
        return self._thread

    @property
    def is_running(self) -> bool:
        return not self._closed and self._thread.is_alive()

    # ------------------------------------------------------------------ calls

    def call(self, fn: Callable[P, Awaitable[T]], /, *args: P.args, **kwargs: P.kwargs) -> T:
        """Await ``fn(*args, **kwargs)`` on the loop; a Ctrl-C meanwhile cancels it there first."""
        self._check_caller()
        stop_signals.take()  # a stop owed (held by a close, dropped by a finalizer) ends it before this goes out
        call: _Call[T] = _Call()
        try:
            self._schedule(call.spawn, fn, args, kwargs)
            return _result(call.outcome, self._thread)
        except BaseException:
            if not call.outcome.done:  # our wait was interrupted (Ctrl-C), not the call: end it first
                with contextlib.suppress(BusClosed):  # closed meanwhile: the loop cancels it itself
                    self._schedule(call.cancel)
                _wait_holding_interrupts(call.ended, self._thread)
            raise

    def call_to_end(self, fn: Callable[P, Awaitable[T]], /, *args: P.args, **kwargs: P.kwargs) -> T:
        """Like :meth:`call`, but a Ctrl-C does not cancel: it is raised once ``fn`` has finished."""
        self._check_caller()
        call: _Call[T] = _Call()
        with stop_signals.held():  # a stop signal from here on waits for the end
            self._schedule(call.spawn, fn, args, kwargs)
            return _result_holding_interrupts(call.outcome, self._thread)

    def call_sync(self, fn: Callable[P, T], /, *args: P.args, **kwargs: P.kwargs) -> T:
        """Run the plain function ``fn(*args, **kwargs)`` on the loop thread, where the bus's objects live."""
        outcome: Outcome[T] = Outcome()

        def run() -> None:
            try:
                outcome.set_result(fn(*args, **kwargs))
            except BaseException as exc:  # whatever it is, the caller's thread gets it
                outcome.set_exception(exc)

        self._check_caller()
        stop_signals.take()  # (as in call)
        self._schedule(run)
        try:
            return _result(outcome, self._thread)
        except BaseException:
            if not outcome.done:  # interrupted: a plain function ends at once, let it
                _wait_holding_interrupts(outcome, self._thread)
            raise

    def read(self, fn: Callable[P, T], /, *args: P.args, **kwargs: P.kwargs) -> T:
        """A read of state (statistics, the latest frame): :meth:`call_sync` while the loop thread runs;
        once it has ended, here (nothing else touches the objects any more), so what a program prints
        after its ``with`` block still reads, as the async objects allow."""
        if self._closed and not self._thread.is_alive():
            return fn(*args, **kwargs)
        return self.call_sync(fn, *args, **kwargs)

    def _check_caller(self) -> None:
        if self._closed:
            raise self._closed_error()
        if threading.current_thread() is self._thread:
            raise RuntimeError(
                "a blocking call cannot run on the bus's own event loop thread (it would wait for itself); "
                "use the async API there (bus.async_bus)"
            )

    def _schedule(self, callback: Callable[..., object], *args: object) -> None:
        try:
            # In a context of its own, not the caller's: anyio.run (so ics35_async.run) names its library (trio) in
            # a context variable there, and the call's task, on this asyncio loop, took it for its own.
            self._loop.call_soon_threadsafe(callback, *args, context=contextvars.Context())
        except RuntimeError:  # the loop is closed
            raise self._closed_error() from None

    def _closed_error(self) -> BusClosed:
        because = f": {self.closed_because}" if self.closed_because else ""
        return BusClosed(f"the {self.what} is closed{because}")

    # ------------------------------------------------------------------ stopping

    def stop(self) -> None:
        """End the loop (cancelling anything still running on it) and join the thread (idempotent)."""
        if self._closed:
            return
        if threading.current_thread() is self._thread:
            raise RuntimeError("the bus cannot be closed from its own event loop thread; use the async API there")
        self._closed = True
        stop = self._stop
        if stop is not None:
            with contextlib.suppress(RuntimeError):  # RuntimeError: the loop has already ended
                self._loop.call_soon_threadsafe(stop.set)
        thread = self._thread

        def joined() -> bool:
            if thread.is_alive():  # (never started: nothing to join)
                thread.join()
            return True

        _hold_interrupts_until(joined)  # a close is not cut in half


def _result(outcome: Outcome[T], thread: threading.Thread) -> T:
    """The outcome's result, or BusClosed if the loop thread ends first (never expected: a safety net)."""
    # A stop signal wakes the wait and is raised here; one that comes as it ends, by ``waiting`` itself.
    with stop_signals.waiting(outcome):
        while not outcome.wait(_ALIVE_CHECK):
            stop_signals.take()
            if not thread.is_alive() and not outcome.done:
                raise BusClosed("the bus's event loop thread has ended")
    return outcome.result()


def _hold_interrupts_until(done: Callable[[], bool]) -> None:
    """Call ``done()`` until it says True; a KeyboardInterrupt or a stop signal meanwhile is raised after."""
    interrupted: KeyboardInterrupt | None = None
    with stop_signals.held():
        while True:
            try:
                if done():
                    break
            except KeyboardInterrupt as exc:
                interrupted = exc
    if interrupted is not None:
        raise interrupted


def _wait_holding_interrupts(outcome: Outcome[Any], thread: threading.Thread) -> None:
    """Wait until ``outcome`` is settled (or the loop thread ends); a KeyboardInterrupt or a stop signal
    meanwhile is raised after."""
    _hold_interrupts_until(lambda: outcome.wait(_ALIVE_CHECK) or not thread.is_alive())


def _result_holding_interrupts(outcome: Outcome[T], thread: threading.Thread) -> T:
    """The outcome's result; a KeyboardInterrupt or a stop signal meanwhile is raised once it is settled."""
    _wait_holding_interrupts(outcome, thread)
    return _result(outcome, thread)
