"""The anyio driver: one bus task in a task group owns the line (trio, or asyncio by choice).

Its way of waiting: the task waits for input (``anyio.wait_readable`` on a
tty's descriptor, or a cancel scope that an in-process device's delivery
cancels) or the engine's deadline inside a cancel scope; anything that
changes what it waits for (a request that starts a transaction and so an
earlier deadline) cancels that scope so the task looks again.  Requests wait
on an ``anyio.Event``.  This costs a little more per transaction than the
asyncio driver's I/O callbacks, so asyncio programs get the asyncio driver
unless they ask for this one.
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
from ..protocol import Command
from ..transports.device_port import DevicePort
from ..transports.opening import Port
from ..transports.tty_port import TtyPort
from ..transports.wire_device import WireDevice
from .clock import now
from .core import INF, CallerRequest, DriverCore
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
    """What a caller of the anyio driver awaits: ``await waiter`` gives the request's value."""

    __slots__ = ("event", "request")

    def __init__(self) -> None:
        self.event = anyio.Event()
        self.request: CallerRequest | None = None

    def done(self) -> bool:
        return False  # a caller that gives up cancels its request (see wait)

    async def wait(self) -> Any:
        request = self.request
        assert request is not None
        try:
            await self.event.wait()
        except BaseException:
            request.cancel()  # queued: skipped; on the wire: its reply is consumed and dropped
            raise
        return request.result()

    def __await__(self) -> Generator[Any, None, Any]:
        return self.wait().__await__()


def _set_event(request: CallerRequest) -> None:
    request.waiter.event.set()  # type: ignore[attr-defined]


class AnyioDriver(DriverCore):
    """Runs one :class:`LineEngine` in a task of its own, under any anyio backend."""

    name = "anyio"

    def __init__(self, engine: LineEngine, port: str | WireDevice, settings: LineSettings) -> None:
        super().__init__(engine, port, settings)
        self._group: Any = None
        self._scope: anyio.CancelScope | None = None
        self._task_scope = anyio.CancelScope()  # the bus task's own, shielded scope (see _run_shielded)
        self._soon = soon_threadsafe()
        self._thread = threading.get_ident()

    # ------------------------------------------------------------------ life cycle

    async def open(self) -> None:
        self._connected(await self._open())
        self._group = anyio.create_task_group()
        await self._group.__aenter__()
        # Made here, not in the task: aclose() may cancel it before the task has even started.
        self._task_scope = anyio.CancelScope(shield=True)
        self._group.start_soon(self._run_shielded, name=f"ics35 bus {self.target}")

    async def aclose(self) -> None:
        try:
            await self._drain()
        finally:
            # Even when the closing task is cancelled (Ctrl-C, a timeout around the program): the
            # bus task's group must end here, in the task that began it, or trio's nursery stack
            # is corrupted and the program dies with a traceback instead of closing.
            try:
                if self._group is not None:
                    group, self._group = self._group, None
                    self._task_scope.cancel()
                    group.cancel_scope.cancel()
                    await group.__aexit__(None, None, None)  # no scope around it: it closes the group's own
            finally:  # even if that raised (the closing task is cancelled): the port is released
                self._drop_port()

    # ------------------------------------------------------------------ the bus task

    async def _run_shielded(self) -> None:
        # Shielded from the opening task's cancellation: a program cancelled inside ``async with
        # open_bus(...)`` (Ctrl-C, SIGTERM, a timeout) still has its line while it puts its servos
        # to rest on the way out (a stream's on_close, a robot's stop); aclose() ends it.
        with self._task_scope:
            await self._run()

    async def _run(self) -> None:
        engine = self.engine
        while True:
            port = self.port
            if port is None or engine.state is State.LOST:
                if engine.state is not State.LOST:
                    await anyio.sleep_forever()  # closed for good: aclose() cancels this task
                await self._reconnect()
                continue
            deadline = engine.deadline
            self._waiting_until = deadline
            wait = INF if deadline == INF else anyio.current_time() + max(0.0, deadline - now())
            with anyio.CancelScope(deadline=wait) as scope:
                self._scope = scope
                await self._wait_input(port)
            self._scope = None
            self._waiting_until = INF
            data = self._read(port)
            if data is not None:
                self._step(port, data, now())

    async def _wait_input(self, port: Port) -> None:
        if isinstance(port, TtyPort):
            if port.pending:
                await anyio.wait_writable(port.fd)
                port.write_pending()
            await anyio.wait_readable(port.fd)
        elif isinstance(port, DevicePort) and port.has_input:
            # Already here (a fast simulator answers inside write): still let other tasks run,
            # or a line that never waits would starve its own callers.
            await anyio.lowlevel.checkpoint()
        else:
            await anyio.sleep_forever()

    # ------------------------------------------------------------------ waking the bus task

    def _watch(self, port: Port) -> None:
        if isinstance(port, DevicePort):
            port.on_input = self._input_came
        self._rewait()

    def _unwatch(self, port: Port) -> None:
        if isinstance(port, DevicePort):
            port.stop_telling()
        self._rewait()

    def _input_came(self) -> None:
        if threading.get_ident() == self._thread:
            self._rewait()
        else:
            with contextlib.suppress(RuntimeError):  # the loop has ended: nobody is left to tell
                self._soon(self._rewait)

    def _rewait(self) -> None:
        if self._scope is not None:
            self._scope.cancel()

    # ------------------------------------------------------------------ the user's side

    def _new_request(self, command: Command[Any], priority: int, retries: int) -> tuple[CallerRequest, Any]:
        waiter = EventWaiter()
        waiter.request = CallerRequest(command, priority, retries, waiter, _set_event)
        return waiter.request, waiter
