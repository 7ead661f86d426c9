"""An asyncio event loop in a background thread, and blocking calls into it.

Every blocking call is one hop: the caller's thread hands a function to the
loop thread (``call_soon_threadsafe``) and waits for its result on a
:class:`concurrent.futures.Future`.  Whatever the function raises is raised
in the caller's thread, as it was, so typed errors stay typed.

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
"""

from __future__ import annotations

import asyncio
import contextlib
import threading
from collections.abc import Awaitable, Callable
from concurrent import futures
from concurrent.futures import Future
from typing import Any, Generic, ParamSpec, TypeVar

from ..errors import BusClosed

P = ParamSpec("P")
T = TypeVar("T")

# How often a waiting caller checks that the loop thread is still alive (it never dies
# on its own; this only turns a broken invariant into BusClosed instead of a hang).
_ALIVE_CHECK = 0.5


class _Call(Generic[T]):
    """One coroutine call on the loop: its result for the caller, its task for cancelling."""

    __slots__ = ("ended", "future", "task")

    def __init__(self) -> None:
        self.future: Future[T] = Future()
        self.ended = threading.Event()  # the task has finished, whatever the future says
        self.task: asyncio.Task[T] | None = None

    def settle(self, task: asyncio.Task[T]) -> None:
        if task.cancelled():
            self.future.set_exception(BusClosed("bus closed while the call was waiting"))
        elif (exc := task.exception()) is not None:
            self.future.set_exception(exc)
        else:
            self.future.set_result(task.result())
        self.ended.set()

    def spawn(self, fn: Callable[..., Awaitable[T]], args: tuple[Any, ...], kwargs: dict[str, Any]) -> None:
        """Start the call's task (on the loop; ``fn`` is called there, not in the caller's thread)."""
        self.task = asyncio.create_task(_await(fn, args, kwargs))
        self.task.add_done_callback(self.settle)

    def cancel(self) -> None:
        # Callbacks run in the order they were scheduled: a spawn scheduled before us has run.
        if self.task is None:
            self.ended.set()  # never scheduled (Ctrl-C came first): nothing runs
        else:
            self.task.cancel()


async def _await(fn: Callable[..., Awaitable[T]], args: tuple[Any, ...], kwargs: dict[str, Any]) -> T:
    return await fn(*args, **kwargs)


class LoopThread:
    """A daemon thread running an asyncio event loop, with blocking calls into it.

    A daemon thread, so that a program that forgets to close its bus still
    exits; :class:`~ics35_async.blocking.BlockingBus` closes the bus at exit.
    """

    def __init__(self, name: str) -> None:
        started: Future[asyncio.AbstractEventLoop] = Future()
        self._stop: asyncio.Event | None = None
        self._closed = False
        self._thread = threading.Thread(target=self._main, args=(started,), name=name, daemon=True)
        self._thread.start()
        try:
            self._loop = _result_holding_interrupts(started, self._thread)
        except KeyboardInterrupt:  # Ctrl-C while the thread started: end it before going on
            self._loop = started.result()
            self.stop()
            raise

    def _main(self, started: Future[asyncio.AbstractEventLoop]) -> None:
        async def serve() -> None:
            self._stop = asyncio.Event()
            started.set_result(asyncio.get_running_loop())
            await self._stop.wait()

        # asyncio.run ends by cancelling what is left, shutting the executor down and closing the loop.
        asyncio.run(serve())

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
        call: _Call[T] = _Call()
        try:
            self._schedule(call.spawn, fn, args, kwargs)
            return _result(call.future, self._thread)
        except BaseException:
            if not call.future.done():  # our wait was interrupted (Ctrl-C), not the call: end it first
                with contextlib.suppress(BusClosed):  # closed meanwhile: the loop cancels it itself
                    self._schedule(call.cancel)
                _wait_holding_interrupts(call.ended, self._thread)
            raise

    def call_to_end(self, fn: Callable[P, Awaitable[T]], /, *args: P.args, **kwargs: P.kwargs) -> T:
        """Like :meth:`call`, but a Ctrl-C does not cancel: it is raised once ``fn`` has finished."""
        self._check_caller()
        call: _Call[T] = _Call()
        self._schedule(call.spawn, fn, args, kwargs)
        return _result_holding_interrupts(call.future, self._thread)

    def call_sync(self, fn: Callable[P, T], /, *args: P.args, **kwargs: P.kwargs) -> T:
        """Run the plain function ``fn(*args, **kwargs)`` on the loop thread, where the bus's objects live."""
        future: Future[T] = Future()

        def run() -> None:
            if future.set_running_or_notify_cancel():
                try:
                    future.set_result(fn(*args, **kwargs))
                except BaseException as exc:  # whatever it is, the caller's thread gets it
                    future.set_exception(exc)

        self._check_caller()
        self._schedule(run)
        try:
            return _result(future, self._thread)
        except BaseException:
            if not future.cancel():  # it has begun: a plain function ends at once
                _wait_holding_interrupts(future, self._thread)
            raise

    def _check_caller(self) -> None:
        if self._closed:
            raise BusClosed("bus is closed")
        if threading.current_thread() is self._thread:
            raise RuntimeError(
                "a blocking call cannot run on the bus's own event loop thread (it would wait for itself); "
                "use the async API there (bus.async_bus)"
            )

    def _schedule(self, callback: Callable[..., object], *args: object) -> None:
        try:
            self._loop.call_soon_threadsafe(callback, *args)
        except RuntimeError:  # the loop is closed
            raise BusClosed("bus is closed") from None

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
        interrupted: KeyboardInterrupt | None = None
        while self._thread.is_alive():
            try:
                self._thread.join()
            except KeyboardInterrupt as exc:
                interrupted = exc
        if interrupted is not None:
            raise interrupted


def _done_within(waitable: Future[T] | threading.Event, timeout: float) -> bool:
    if isinstance(waitable, threading.Event):
        return waitable.wait(timeout)
    try:
        waitable.exception(timeout)  # returns the call's own exception; raises only if it is not done
    except TimeoutError:
        return False
    except futures.CancelledError:
        pass
    return True


def _result(future: Future[T], thread: threading.Thread) -> T:
    """``future.result()``, or BusClosed if the loop thread ends first (never expected: a safety net)."""
    while not _done_within(future, _ALIVE_CHECK):
        if not thread.is_alive() and not future.done():
            raise BusClosed("the bus's event loop thread has ended")
    return future.result()


def _wait_holding_interrupts(waitable: Future[T] | threading.Event, thread: threading.Thread) -> None:
    """Wait until ``waitable`` is done (or the loop thread ends); a KeyboardInterrupt meanwhile is raised after."""
    interrupted: KeyboardInterrupt | None = None
    while True:
        try:
            if _done_within(waitable, _ALIVE_CHECK) or not thread.is_alive():
                break
        except KeyboardInterrupt as exc:
            interrupted = exc
    if interrupted is not None:
        raise interrupted


def _result_holding_interrupts(future: Future[T], thread: threading.Thread) -> T:
    """``future.result()``; a KeyboardInterrupt meanwhile is raised once the future is done."""
    _wait_holding_interrupts(future, thread)
    return _result(future, thread)
