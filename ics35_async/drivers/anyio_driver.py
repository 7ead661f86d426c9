"""The anyio driver: one bus task of its own owns the line (trio, or asyncio by choice).

Its way of waiting: the task waits for input (``anyio.wait_readable`` on a
tty's descriptor, or a cancel scope that an in-process device's delivery
cancels) or the engine's deadline inside a cancel scope; anything that
changes what it waits for (a request that starts a transaction and so an
earlier deadline) cancels that scope so the task looks again.  Requests wait
on an ``anyio.Event``.  This costs a little more per transaction than the
asyncio driver's I/O callbacks, so asyncio programs get the asyncio driver
unless they ask for this one.

On a tty where the compiled helper is built, a stream's transactions run in
bursts as under the other drivers (see .burst): while one runs, the bus task
waits on the burst's notices (``done_fd``), never on the port, which the
executor's thread reads meanwhile, and with no deadline (the executor keeps
them).  Only the bus task starts a burst: a caller's task that puts the
stream's transaction on the wire writes it the ordinary way, as the bus task
may be about to read the port (the stream's next transaction, put on the wire
by the bus task, starts the burst).  A burst stopped from a caller's task (a
close, a reopen, a stream attached) ends the bus task's wait on its notices.
"""

from __future__ import annotations

import asyncio
import contextlib
import threading
from collections.abc import Callable, Generator
from typing import Any

import anyio
import anyio.lowlevel

from ..engine import LineEngine, State
from ..errors import error_text
from ..protocol import Command
from ..transports.device_port import DevicePort
from ..transports.opening import Port
from ..transports.tty_port import TtyPort
from ..transports.wire_device import WireDevice
from .burst import BurstRunner, open_runner
from .clock import now
from .core import INF, STALL, CallerRequest, DriverCore, outlive_the_program
from .settings import LineSettings


def soon_threadsafe() -> Callable[[Callable[[], None]], None]:
    """A function that runs a callback on the running event loop's thread, callable from any thread."""
    try:
        loop = asyncio.get_running_loop()
    except RuntimeError:  # not asyncio: trio (the only other backend anyio has)
        import trio

        token = trio.lowlevel.current_trio_token()

        def trio_soon(callback: Callable[[], None]) -> None:
            token.run_sync_soon(callback)

        return trio_soon

    def asyncio_soon(callback: Callable[[], None]) -> None:
        loop.call_soon_threadsafe(callback)

    return asyncio_soon


class EventWaiter:
    """What ``submit`` hands a caller under the anyio driver: awaiting it gives the request's value.

    It answers as the asyncio future the other drivers hand out does, so that a program's (or a soak's)
    code that cancels or polls its requests runs on every driver: ``done()``, ``cancelled()``, ``cancel()``,
    ``result()`` and ``exception()``, with asyncio's ``CancelledError`` and ``InvalidStateError`` (under trio
    too: there is no other exception for a request cancelled outside any cancel scope).  Not thread-safe,
    as a future is not: its methods are for the bus's own event loop."""

    __slots__ = ("_cancelled", "_check", "event", "request")

    def __init__(self, check: Callable[[float], float] | None) -> None:
        self.event = anyio.Event()  # set once the outcome is in, or the request is cancelled
        self.request: CallerRequest | None = None
        self._cancelled = False
        self._check = check  # the driver's check_progress, for the wait to call (None: the driver's timer does)

    def done(self) -> bool:
        return self.event.is_set()

    def cancelled(self) -> bool:
        return self._cancelled

    def cancel(self) -> bool:
        """Give up on the request; False if it is done already.  Queued, it is skipped; on the wire, it
        finishes there (its reply, if one comes, is read and dropped; it is not retried), so the line
        stays in step."""
        if self.event.is_set():
            return False
        assert self.request is not None
        self._cancelled = True
        self.request.cancel()
        self.event.set()  # (awaiting it raises CancelledError, as for a cancelled future)
        return True

    def result(self) -> Any:
        """The value; raises the request's error, ``CancelledError`` once cancelled, ``InvalidStateError`` before
        the outcome."""
        if self._cancelled:
            raise asyncio.CancelledError
        if not self.event.is_set():
            raise asyncio.InvalidStateError("Result is not set.")
        assert self.request is not None
        return self.request.result()

    def exception(self) -> BaseException | None:
        """The request's error (``None`` once done without one); raises as :meth:`result` when cancelled or
        not done."""
        if self._cancelled:
            raise asyncio.CancelledError
        if not self.event.is_set():
            raise asyncio.InvalidStateError("Exception is not set.")
        assert self.request is not None
        return self.request.error

    async def wait(self) -> Any:
        suspect = INF
        try:
            if self._check is None:
                await self.event.wait()
            while not self.event.is_set():
                # Under trio in looks of STALL seconds, not one wait: the bus task's own wake-up may be lost (see
                # check_progress).  (Under asyncio, a cancel scope a request costs as much as the rest of it: there,
                # one timer of the driver's looks.)
                with anyio.move_on_after(STALL):
                    await self.event.wait()
                if not self.event.is_set():
                    assert self._check is not None
                    suspect = self._check(suspect)
        except BaseException:
            self.cancel()  # the caller gave up (a timeout, a cancelled task): as its future would be
            raise
        return self.result()

    def __await__(self) -> Generator[Any, None, Any]:
        return self.wait().__await__()


def _set_event(request: CallerRequest) -> None:
    request.waiter.event.set()  # type: ignore[attr-defined]


class AnyioDriver(DriverCore):
    """Runs one :class:`LineEngine` in a task of its own, under any anyio backend."""

    name = "anyio"

    def __init__(self, engine: LineEngine, port: str | WireDevice, settings: LineSettings) -> None:
        super().__init__(engine, port, settings)
        self._scope: anyio.CancelScope | None = None
        self._task_scope = anyio.CancelScope()  # the bus task's own (see open)
        self._task_ended: anyio.Event | None = None
        self._task_error: BaseException | None = None
        self._task: Any = None  # the asyncio task (kept referenced), when the backend is asyncio
        self._soon = soon_threadsafe()
        self._in_bus_task = False  # the bus task acts on the engine's answer now: it may start a burst
        self._turn_at = -INF  # when the bus task last began a turn of its loop (see check_progress)
        self._look_timer: asyncio.TimerHandle | None = None  # under asyncio: the next look (see _look_soon)
        self._suspect = INF  # the overdue deadline its previous look found

    # ------------------------------------------------------------------ life cycle

    async def open(self) -> None:
        """Open the port and start the bus task: a task of no caller's, a system task under trio.

        Not a task group's child: a group entered here belongs to the cancel scopes around this call
        (``with trio.fail_after(2): bus = await open_bus(...)``) and must end in this task, which
        broke trio (and anyio on asyncio) as soon as the bus outlived that scope or another task
        closed it.  Detached, the line also outlives the program's own cancellation (Ctrl-C, a
        timeout) while it puts its servos to rest on the way out (a stream's on_close, a robot's
        stop); :meth:`aclose` ends it, and under trio the run's end does, for a bus never closed.
        On asyncio, whose run's end cancels every task at once (after a KeyboardInterrupt out of
        the loop), it runs on until the program's tasks have ended (see outlive_the_program).
        """
        self._connected(await self._open())
        # Made here, not in the task: aclose() may cancel it before the task has even started.
        self._task_scope = anyio.CancelScope()
        self._task_ended = anyio.Event()
        name = f"ics35 bus {self.target}"
        try:
            loop = asyncio.get_running_loop()
        except RuntimeError:  # not asyncio: trio (the only other backend anyio has)
            import trio

            trio.lowlevel.spawn_system_task(self._run_task, name=name)
        else:
            # (Its error retrieved: how it ended is said by the line, its warning and its callers' errors; asyncio would
            # print a KeyboardInterrupt that ended it again, with the task's traceback, as the program exits.)
            self._task = loop.create_task(self._run_task(), name=name)
            self._task.add_done_callback(lambda task: None if task.cancelled() else task.exception())
            self._look_soon()

    async def aclose(self) -> None:
        try:
            await self._drain()
        finally:
            try:
                self._task_scope.cancel()
                if self._task_ended is not None:
                    # At once (nothing in the task outlasts its scope), and before the port closes under
                    # its wait for input; shielded, since the closer may itself be cancelled.
                    with anyio.CancelScope(shield=True):
                        with anyio.move_on_after(1.0):
                            await self._task_ended.wait()
                        if not self._task_ended.is_set():
                            await self._end_stuck_task()
            finally:  # even if the closing task is cancelled meanwhile: the port is released
                self._drop_port()
                if self._look_timer is not None:
                    self._look_timer.cancel()
                    self._look_timer = None
        error, self._task_error = self._task_error, None
        if error is not None:
            raise error

    async def _end_stuck_task(self) -> None:
        """The bus task outlived its scope's cancellation: an exception raised inside an event loop callback (by a
        signal handler) dropped its wake-up.  Left as it is, asyncio.run() would wait for it for ever as it ends."""
        task = self._task
        if task is None:  # (trio: its run's end cancels the system task as it can)
            return
        task.cancel()  # a scope's delivery lost, the task still waits on a future: a plain cancellation ends it
        with anyio.move_on_after(0.5):
            await self._task_ended.wait()  # type: ignore[union-attr]
        if not task.done():
            # Its own wake-up lost, the task never runs again and no cancellation reaches it: marked cancelled as
            # a plain future is (Task.cancel only asks its next step to raise), so that nothing waits for it.
            asyncio.Future.cancel(task)

    # ------------------------------------------------------------------ the bus task

    async def _run_task(self) -> None:
        assert self._task_ended is not None
        try:
            await self._run_in_scope()
        except Exception as exc:  # a bug: told at aclose(); out of a system task it would kill trio
            self._task_error = exc
            # Every caller waiting hears it (PortLost), none waits forever, with or without a port.
            if self.port is not None:
                self._lose(self.port, exc, reconnect=False)
            else:
                self.engine.lost(f"the bus task for {self.target} failed: {error_text(exc)}", reconnect=False)
                self._release_idle()
        except BaseException as exc:
            # Not aclose()'s cancellation (its scope ends the task quietly): the run's end cancelling every task
            # (asyncio.run's, after a KeyboardInterrupt out of the loop: here once the program's tasks have ended), or
            # an exception a signal handler raised in the task (on asyncio, a KeyboardInterrupt or SystemExit only
            # inside asyncio's or anyio's code, or as the bus closes: see outlive_the_program).  No task runs the line
            # any more: its callers hear so instead of waiting for ever.
            cancelled = isinstance(exc, anyio.get_cancelled_exc_class())
            self._fail_line(f"the bus task for {self.target} ended: {type(exc).__name__}", warn=not cancelled)
            if cancelled or self._task is not None:
                raise  # (on asyncio, a KeyboardInterrupt or SystemExit goes on out of the loop, as the signal meant)
            # Out of a trio system task it would crash the run (TrioInternalError): the program hears it at aclose().
            self._task_error = exc
        finally:
            self._task_ended.set()

    async def _run_in_scope(self) -> None:
        try:
            with self._task_scope:
                if self._task is None:  # (trio: a system task, cancelled only as the run ends, after the program)
                    await self._run()
                else:
                    await outlive_the_program(self._run, self._task_scope)
        except RuntimeError as exc:
            interrupt = exc.__context__
            if not isinstance(interrupt, (KeyboardInterrupt, SystemExit)):
                raise
            # Raised by a signal handler inside anyio's cancel scopes, it left their books half done, and the task
            # scope refuses its exit (RuntimeError): the interrupt ended the task, not a bug nor the port.
            raise interrupt from None

    async def _run(self) -> None:
        engine = self.engine
        while True:
            self._turn_at = now()
            port = self.port
            if port is None or engine.state is State.LOST:
                if engine.state is State.LOST:
                    await self._reconnect()
                    continue
                # No port: closed for good (aclose() cancels this task), or a reopen's port opening in
                # a thread, whose _connected() ends this wait (_watch -> _rewait) as any new wait does.
                with anyio.CancelScope() as scope:
                    self._scope = scope
                    await anyio.sleep_forever()
                self._scope = None
                continue
            burst = self.burst
            if burst is not None and burst.running:
                await self._wait_burst(burst)
                continue
            deadline = engine.deadline
            self._waiting_until = deadline
            wait = INF if deadline == INF else anyio.current_time() + max(0.0, deadline - now())
            with anyio.CancelScope(deadline=wait) as scope:
                self._scope = scope
                await self._wait_input(port)
            self._scope = None
            self._waiting_until = INF
            if self.bursting or port is not self.port:
                continue  # (not this wait's port to read any more: the executor's, or gone)
            data = self._read(port)
            if data is not None:
                self._in_bus_task = True
                try:
                    self._step(port, data, now())
                finally:
                    self._in_bus_task = False

    async def _wait_burst(self, burst: BurstRunner) -> None:
        """Wait for the running ``burst``'s notice (a point to feed ahead, or its end) and feed the engine.

        No deadline: the executor keeps them.  A wait ended by ``_rewait`` (the runner closing under a port
        that is lost, closed or reopened, or a burst stopped by a caller's task) feeds nothing: the burst's
        records are taken only once it told (before, the executor may not have begun them)."""
        told = False
        with anyio.CancelScope() as scope:
            self._scope = scope
            await anyio.wait_readable(burst.done_fd)
            told = True
        self._scope = None
        if told and burst is self.burst and burst.running:
            self._in_bus_task = True
            try:
                self._burst_done(burst)
            finally:
                self._in_bus_task = False

    async def _wait_input(self, port: Port) -> None:
        if isinstance(port, TtyPort):
            if port.pending:
                await anyio.wait_writable(port.fd)
                try:
                    port.write_pending()
                except OSError as exc:  # the port went away (a pulled adapter): lost, not a bug of this task
                    self._lose(port, exc)
                    return
            await anyio.wait_readable(port.fd)
        elif isinstance(port, DevicePort) and port.has_input:
            # Already here (a fast simulator answers inside write): still let other tasks run,
            # or a line that never waits would starve its own callers.
            await anyio.lowlevel.checkpoint()
        else:
            await anyio.sleep_forever()

    # ------------------------------------------------------------------ waking the bus task

    def _watch(self, port: Port) -> None:
        if isinstance(port, TtyPort):
            self.burst = open_runner(
                self.engine, port.fd, port.decode_marks, port.in_between, lambda: self.requested_at
            )
        elif isinstance(port, DevicePort):
            port.on_input = self._input_came
        self._rewait()

    def _unwatch(self, port: Port) -> None:
        self._close_burst()
        if isinstance(port, DevicePort):
            port.stop_telling()
        self._rewait()

    def _input_came(self) -> None:
        if threading.get_ident() == self._home_thread:
            self._rewait()
        else:
            with contextlib.suppress(RuntimeError):  # the loop has ended: nobody is left to tell
                self._soon(self._rewait)

    def _turned_since(self, t: float) -> bool:
        return self._turn_at >= t or self._task_ended is None or self._task_ended.is_set()

    def _rewait(self) -> None:
        if self._scope is not None:
            self._scope.cancel()

    def _soon_at_home(self, callback: Callable[[], None]) -> None:
        self._soon(callback)

    # ------------------------------------------------------------------ the burst path

    def _start_burst(self, burst: BurstRunner) -> bool:
        # Only from the bus task, between its waits (see the module docstring).
        return self._in_bus_task and isinstance(self.port, TtyPort) and burst.start(now())

    def _burst_over(self, port: Port | None) -> None:
        self._rewait()  # (from a caller's task: the bus task waits on the burst's notices; the port is its own again)

    def _burst_closing(self, burst: BurstRunner) -> None:
        # The bus task's wait on its notices ends first: under trio at once (its descriptor is no longer watched
        # once this returns), under asyncio as the task next runs (the loop drops a closed one).
        self._rewait()

    # ------------------------------------------------------------------ the user's side

    def _look_soon(self) -> None:
        """Under asyncio: one timer looks at the line every STALL seconds while the bus is open (see check_progress):
        for its requests, and for its stream, whose frames wait on the bus task too."""
        loop = asyncio.get_running_loop()
        timer = self._look_timer
        if timer is not None:
            if timer.when() > loop.time() - STALL:
                return  # armed
            # Due a whole look ago: dropped, or late behind a loop the program stalled, to run with the next.  Two
            # chains of looks would look twice in one go after a stall, and take the stall for a lost wake-up.
            timer.cancel()
        self._look_timer = loop.call_later(STALL, self._look)

    def _look(self) -> None:
        self._look_timer = None
        self._suspect = self.check_progress(self._suspect)
        if self.engine.state is not State.CLOSED:
            self._look_soon()

    def _new_request(self, command: Command[Any], priority: int, retries: int) -> tuple[CallerRequest, Any]:
        on_asyncio = self._task is not None
        if on_asyncio:
            self._look_soon()
        waiter = EventWaiter(None if on_asyncio else self.check_progress)
        waiter.request = CallerRequest(command, priority, retries, waiter, _set_event)
        return waiter.request, waiter
