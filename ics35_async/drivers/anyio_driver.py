"""The anyio driver: one bus task in a task group owns the line (trio, or asyncio by choice).

The task waits for input or the engine's deadline inside a cancel scope;
anything that changes what it waits for (bytes from an in-process device, a
request that starts a transaction and so an earlier deadline) cancels that
scope so the task looks again.  Requests wait on an ``anyio.Event``.  This
costs a little more per transaction than the asyncio driver's I/O callbacks,
so asyncio programs get the asyncio driver unless they ask for this one.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Generator
from typing import Any, TypeVar

import anyio

from ..engine import LineEngine, Request, State
from ..errors import IcsError
from ..protocol import Command
from ..transports import WireDevice
from ..transports.serial_port import open_serial, posix_fd
from ..transports.threaded import ThreadedSerialDevice
from ..transports.wire_device import device_factory
from .anyio_ports import DevicePort, FdPort
from .clock import now
from .settings import LineSettings

log = logging.getLogger("ics35_async")

T = TypeVar("T")
INF = math.inf


class EventRequest(Request):
    """A request whose caller awaits an ``anyio.Event``; ``await request`` gives the value."""

    __slots__ = ("event",)

    def __init__(self, command: Command[Any], priority: int, retries: int) -> None:
        super().__init__(command, priority, retries)
        self.event = anyio.Event()

    def resolve(self, value: Any) -> None:
        super().resolve(value)
        self.event.set()

    def reject(self, error: IcsError) -> None:
        super().reject(error)
        self.event.set()

    async def wait(self) -> Any:
        try:
            await self.event.wait()
        except BaseException:
            self.cancel()  # queued: skipped; on the wire: its reply is consumed and dropped
            raise
        return self.result()

    def __await__(self) -> Generator[Any, None, Any]:
        return self.wait().__await__()


class AnyioDriver:
    """Runs one :class:`LineEngine` in a task of its own, under any anyio backend."""

    name = "anyio"

    def __init__(self, engine: LineEngine, port: str | WireDevice, settings: LineSettings) -> None:
        self.engine = engine
        self.port = port
        self.settings = settings
        self.line: FdPort | DevicePort | None = None
        self._group: Any = None
        self._scope: anyio.CancelScope | None = None
        self._waiting_until = INF  # the engine deadline the task's current wait ends at
        self._idle: list[anyio.Event] = []
        self._task_scope = anyio.CancelScope()  # the bus task's own, shielded scope (see _run_shielded)

    # ------------------------------------------------------------------ life cycle

    async def open(self) -> None:
        await self._connect()
        self._group = anyio.create_task_group()
        await self._group.__aenter__()
        # Made here, not in the task: aclose() may cancel it before the task has even started.
        self._task_scope = anyio.CancelScope(shield=True)
        self._group.start_soon(self._run_shielded, name=f"ics35 bus {self.port}")

    async def _open_port(self) -> FdPort | DevicePort:
        port = self.port
        if isinstance(port, str):
            scheme, sep, _ = port.partition("://")
            factory = device_factory(scheme) if sep else None
            if factory is None:
                ser = await anyio.to_thread.run_sync(
                    open_serial, port, self.engine.baudrate, True, self.settings.direction
                )
                if posix_fd(ser) is not None and self.settings.transport != "thread":
                    return FdPort(ser)
                port = ThreadedSerialDevice(ser)
            else:
                port = factory(port)
        line = DevicePort(port, self._wake)
        port.connect(line, self.engine.baudrate)
        return line

    async def _connect(self) -> None:
        self.line = await self._open_port()
        log.info("opened %s at %d baud (anyio)", self.port, self.engine.baudrate)
        self.pump(self.engine.connected(now()))

    async def reopen(self, baudrate: int) -> None:
        self.engine.disconnected()
        line, self.line = self.line, None
        if line is not None:
            line.close()
        self.engine.baudrate = baudrate
        await self._connect()  # a failure closes the line for good (the bus tells the engine)

    async def aclose(self) -> None:
        engine = self.engine
        engine.close()
        try:
            if engine.state is State.DRAINING:
                with anyio.move_on_after(engine.drain_bound):
                    await self.wait_idle()
        finally:
            # Even when the closing task is cancelled (Ctrl-C, a timeout around the program): the
            # bus task's group must end here, in the task that began it, or trio's nursery stack
            # is corrupted and the program dies with a traceback instead of closing.
            engine.abort()
            self._release_idle()
            try:
                if self._group is not None:
                    group, self._group = self._group, None
                    self._task_scope.cancel()
                    group.cancel_scope.cancel()
                    await group.__aexit__(None, None, None)  # no scope around it: it closes the group's own
            finally:  # even if that raised (the closing task is cancelled): the port is released
                line, self.line = self.line, None
                if line is not None:
                    line.close()

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
            line = self.line
            if line is None or engine.state is State.LOST:
                await self._reconnect()
                continue
            deadline = engine.deadline
            self._waiting_until = deadline
            wait = None if deadline == INF else anyio.current_time() + max(0.0, deadline - now())
            with anyio.CancelScope(deadline=INF if wait is None else wait) as scope:
                self._scope = scope
                await line.wait_input()
            self._scope = None
            self._waiting_until = INF
            try:
                self._step(line)
            except OSError as exc:
                self._lose(line, exc)

    def _step(self, line: FdPort | DevicePort) -> None:
        engine = self.engine
        data = line.read()
        t = now()
        if data:
            if line.bad:  # bytes the kernel marked damaged: their transaction fails once complete
                engine.line_error(line.bad)
                line.bad = 0
            self._write(engine.receive(data, t))
        elif t >= engine.deadline:
            # Nothing more has arrived by the deadline (read just now, after the wait): judge it.
            out = engine.tick(t)
            if engine.flush_input:
                engine.flush_input = False
                line.discard_input()
            self._write(out)
        if self._idle and engine.idle:
            self._release_idle()

    def _lose(self, line: FdPort | DevicePort, exc: Exception) -> None:
        if line is not self.line:
            return
        self.line = None
        line.close()
        reason = f"port {self.port} lost: {exc}"
        if self.engine.state not in (State.CLOSED, State.DRAINING):
            log.warning("%s", reason)
        self.engine.lost(reason, reconnect=self.settings.reconnect)
        self._release_idle()

    async def _reconnect(self) -> None:
        if self.engine.state is not State.LOST:
            await anyio.sleep_forever()  # closed for good: aclose() cancels this task
        backoff = self.settings.reconnect_backoff
        attempt = 0
        while self.engine.state is State.LOST:
            await anyio.sleep(backoff[min(attempt, len(backoff) - 1)])
            attempt += 1
            try:
                await self._connect()
            except (OSError, IcsError) as exc:
                log.debug("reconnect %d to %s failed: %s", attempt, self.port, exc)
            else:
                self.engine.counters.reconnects += 1

    def _wake(self) -> None:
        if self._scope is not None:
            self._scope.cancel()

    def _write(self, out: bytes | None) -> None:
        line = self.line
        if out is not None and line is not None:
            try:
                line.write(out)
            except Exception as exc:  # the port vanished, or an in-process device failed: a lost port
                self._lose(line, exc)

    # ------------------------------------------------------------------ the user's side

    def pump(self, out: bytes | None) -> None:
        """Write what an engine call from the user's side answered; re-aim the bus task's wait."""
        self._write(out)
        if self.engine.deadline < self._waiting_until:
            self._wake()

    def submit(self, command: Command[T], priority: int, retries: int) -> EventRequest:
        request = EventRequest(command, priority, retries)
        self.pump(self.engine.submit(request, now()))
        return request

    def call(self, step: Callable[[float], bytes | None]) -> None:
        """Run an engine call (given the time) and act on what it answers."""
        self.pump(step(now()))

    def notify(self, callback: Callable[[], None]) -> None:
        """Run ``callback`` now: the engine runs on the caller's loop."""
        callback()

    async def wait_idle(self) -> None:
        while not self.engine.idle and self.line is not None:
            event = anyio.Event()
            self._idle.append(event)
            await event.wait()

    def _release_idle(self) -> None:
        waiters, self._idle = self._idle, []
        for event in waiters:
            event.set()
