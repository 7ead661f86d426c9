"""The bus: the public face of one ICS line.

A :class:`Bus` checks options, opens and closes the port, reconnects after a
loss, and hands requests and the stream to a
:class:`~ics35_async.engine.LineEngine` (every transaction rule) through a
driver that moves bytes and time between the engine and the event loop
(:mod:`ics35_async.drivers`).  Servos, streams and groups build on it.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import logging
from collections.abc import Generator, Iterable, Sequence
from types import TracebackType
from typing import TYPE_CHECKING, Any, TypeVar

from . import protocol
from .drivers.asyncio_line import AsyncioLine, FutureRequest, now
from .engine import BackgroundSource, BusTiming, LineEngine, Priority, State
from .errors import BusClosed, IcsError, InvalidArgument, PortLost
from .protocol import Command
from .stats import BusStats
from .transports import WireDevice, discard_input, open_line
from .units import check_bool, check_ids, check_int, check_seconds

if TYPE_CHECKING:
    from .servo import Device, Servo
    from .streaming import Stream

log = logging.getLogger("ics35_async")

T = TypeVar("T")

# Delays between reopen attempts; capped well under 1 s so a returning port is found fast.
RECONNECT_BACKOFF = (0.05, 0.1, 0.2, 0.4)


class Bus:
    """One ICS line.  Create with :func:`open_bus`."""

    def __init__(
        self,
        port: str | WireDevice,
        *,
        baudrate: int = 115200,
        echo: bool = True,
        transport: str = "auto",
        timing: BusTiming | None = None,
        retries: int = 0,
        reconnect: bool = False,
        reconnect_backoff: Sequence[float] = RECONNECT_BACKOFF,
        max_requests_between: int = 16,
    ) -> None:
        if not isinstance(port, (str, WireDevice)):
            raise InvalidArgument(f"port must be a path, a URL or a WireDevice, not {type(port).__name__}")
        if timing is not None and not isinstance(timing, BusTiming):
            raise InvalidArgument(f"timing must be a BusTiming, not {type(timing).__name__}")
        if isinstance(reconnect_backoff, (str, bytes)) or not isinstance(reconnect_backoff, Iterable):
            raise InvalidArgument(f"reconnect_backoff must be a sequence of seconds, not {reconnect_backoff!r}")
        self.port = port
        self.echo = check_bool("echo", echo)
        self.transport_kind = transport
        self.retries = check_int("retries", retries, 0, 10)
        self.reconnect = check_bool("reconnect", reconnect)
        self.reconnect_backoff = tuple(check_seconds("reconnect delay", d) for d in reconnect_backoff) or (0.5,)
        self.max_requests_between = check_int("max_requests_between", max_requests_between, 1, 10_000)
        self._engine = LineEngine(
            baudrate=protocol.check_baud(baudrate),
            echo=self.echo,
            timing=timing or BusTiming(),
            max_requests_between=self.max_requests_between,
        )
        self._loop: asyncio.AbstractEventLoop | None = None
        self._line: AsyncioLine | None = None
        self._opening: asyncio.Future[None] | None = None
        self._reopening: asyncio.Future[None] | None = None
        self._supervisor: asyncio.Task[None] | None = None
        self._lost_event: asyncio.Event | None = None

    @property
    def baudrate(self) -> int:
        return self._engine.baudrate

    @property
    def timing(self) -> BusTiming:
        return self._engine.timing

    @property
    def state(self) -> State:
        """The engine's state (``State.IDLE``, ``BUSY``, ``QUIET``, ``LOST``, ``CLOSED``...)."""
        return self._engine.state

    # ------------------------------------------------------------------ opening / closing

    def __await__(self) -> Generator[Any, None, Bus]:
        return self.open().__await__()

    async def __aenter__(self) -> Bus:
        return await self.open()

    async def __aexit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        await self.aclose()

    async def open(self) -> Bus:
        """Open the line (idempotent)."""
        if self._engine.state is State.CLOSED or self._engine.state is State.DRAINING:
            raise BusClosed("bus is closed")
        if self._loop is not None and self._opening is None:
            return self
        if self._opening is not None:  # another open() is under way: share its outcome
            await asyncio.shield(self._opening)
            if self._line is None:
                raise BusClosed(f"opening {self.port} failed")
            return self
        self._loop = asyncio.get_running_loop()
        opening = self._opening = self._loop.create_future()
        try:
            await self._connect()
        except BaseException:
            self._loop = None
            raise
        finally:
            self._opening = None
            opening.set_result(None)  # waiters look at the line, not at this result
        self._lost_event = asyncio.Event()
        self._supervisor = self._loop.create_task(self._supervise(), name=f"ics35 bus {self.port}")
        return self

    async def _connect(self) -> None:
        loop = self._loop
        assert loop is not None
        _, line = await open_line(
            self.port,
            baudrate=self.baudrate,
            protocol_factory=lambda: AsyncioLine(self._engine, loop, self._on_connection_lost, discard_input),
            transport=self.transport_kind,
        )
        self._line = line
        self._engine.debug = log.isEnabledFor(logging.DEBUG)
        log.info("opened %s at %d baud", self.port, self.baudrate)
        line.pump(self._engine.connected(now()))

    async def reopen(self, *, baudrate: int | None = None) -> None:
        """Close and reopen the port, optionally at a new line rate.

        For a baud-rate change: write the servos' EEPROM (``allow_baud_change=True``),
        power-cycle them, then ``await bus.reopen(baudrate=...)``.  Requests
        submitted meanwhile wait and run after the reopen.
        """
        new_baud = self.baudrate if baudrate is None else protocol.check_baud(baudrate)
        if not self.is_open:
            raise BusClosed("bus is closed")
        if self._engine._source is not None or self._reopening is not None:
            raise InvalidArgument("stop the running stream (or the other reopen) before reopening the bus")
        self._reopening = self._get_loop().create_future()  # attach_source refuses from here on
        try:
            await self.wait_idle()
            if self._engine.state is not State.IDLE:
                raise PortLost(f"port {self.port} is lost; cannot reopen now")
            self._engine.disconnected()
            line, self._line = self._line, None
            if line is not None:
                line.cancel_timer()
                if line.transport is not None:
                    line.transport.close()
                await asyncio.sleep(0)
            self._engine.baudrate = new_baud
            try:
                await self._connect()
            except BaseException as exc:
                self._engine.lost(f"reopening {self.port} failed: {exc}", reconnect=False)
                raise
        finally:
            self._reopening.set_result(None)
            self._reopening = None

    @property
    def is_open(self) -> bool:
        return self._loop is not None and self._engine.state not in (State.CLOSED, State.DRAINING)

    async def aclose(self) -> None:
        """Fail queued requests with BusClosed, finish the one on the wire, release the port."""
        engine = self._engine
        if engine.state is State.CLOSED and self._line is None and self._supervisor is None:
            return
        engine.close()
        line = self._line
        if engine.state is State.DRAINING and line is not None:
            waiter = self._get_loop().create_future()
            line.idle_waiters.append(waiter)
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(waiter, engine.timing.allowance(200, self.baudrate) + 1)
        engine.abort()
        if self._supervisor is not None:
            self._supervisor.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._supervisor
            self._supervisor = None
        self._line = None
        if line is not None:
            line.cancel_timer()
            line.release_idle_waiters()
            if line.transport is not None and not line.transport.is_closing():
                line.transport.close()
                await asyncio.sleep(0)  # let the transport deliver connection_lost and release the fd
        log.info("closed %s", self.port)

    def _get_loop(self) -> asyncio.AbstractEventLoop:
        if self._loop is None:
            raise BusClosed("bus is not open")
        return self._loop

    # ------------------------------------------------------------------ losing the port

    def _on_connection_lost(self, line: AsyncioLine, exc: Exception | None) -> None:
        if line is not self._line:
            return
        self._line = None
        if line.transport is not None and not line.transport.is_closing():
            line.transport.close()
        engine = self._engine
        reason = f"port {self.port} lost: {exc}" if exc else f"port {self.port} closed"
        if engine.state not in (State.CLOSED, State.DRAINING):
            log.warning("%s", reason)
        engine.lost(reason, reconnect=self.reconnect)
        line.release_idle_waiters()
        if engine.state is State.LOST and self._lost_event is not None:
            self._lost_event.set()

    async def _supervise(self) -> None:
        assert self._lost_event is not None
        while True:
            await self._lost_event.wait()
            self._lost_event.clear()
            attempt = 0
            while self._engine.state is State.LOST:
                delay = self.reconnect_backoff[min(attempt, len(self.reconnect_backoff) - 1)]
                await asyncio.sleep(delay)
                attempt += 1
                try:
                    await self._connect()
                except (OSError, IcsError) as exc:
                    log.debug("reconnect %d to %s failed: %s", attempt, self.port, exc)
                else:
                    self._engine.counters.reconnects += 1
                    log.info("reconnected to %s after %d attempt(s)", self.port, attempt)

    # ------------------------------------------------------------------ submitting

    async def request(
        self, command: Command[T], *, priority: Priority = Priority.NORMAL, retries: int | None = None
    ) -> T:
        """Run one command and return its parsed reply.

        ``retries`` (default: the bus's) applies only to idempotent commands.
        Raises :class:`ReplyError` subclasses, :class:`BusClosed` or
        :class:`PortLost`.
        """
        return await self.submit(command, priority=priority, retries=retries)

    def submit(
        self, command: Command[T], *, priority: Priority = Priority.NORMAL, retries: int | None = None
    ) -> asyncio.Future[T]:
        """Queue ``command`` and return the future of its result (no await needed)."""
        if not isinstance(command, Command):
            raise InvalidArgument(f"not a command: {command!r}")
        check_int("priority", priority, Priority.URGENT, Priority.LOW)
        retries = self.retries if retries is None else check_int("retries", retries, 0, 10)
        loop = self._loop
        if loop is None:
            if self._engine.state is State.CLOSED:
                raise BusClosed("bus is closed")
            raise BusClosed("bus is not open (use `async with open_bus(...)`)")
        engine = self._engine
        # Re-read per request (not per stream transaction) so enabling DEBUG takes effect.
        engine.debug = log.isEnabledFor(logging.DEBUG)
        fut: asyncio.Future[T] = loop.create_future()
        out = engine.submit(FutureRequest(command, fut, priority, retries), now())
        if out is not None and self._line is not None:
            self._line.pump(out)
        return fut

    def attach_source(self, source: BackgroundSource | None) -> None:
        """Let ``source`` fill the line's idle time (one at a time); ``None`` detaches."""
        if source is None:
            if self._engine._source is not None:
                self._engine.detach_source(self._engine._source)
            return
        if self._reopening is not None or self._engine.state is State.OFFLINE:
            raise InvalidArgument("the bus is reopening; start the stream afterwards")
        out = self._engine.attach_source(source, now())
        if self._line is not None:
            self._line.pump(out)

    def detach_source(self, source: BackgroundSource) -> None:
        """Stop ``source`` filling the line (no-op if it is not attached)."""
        self._engine.detach_source(source)

    def kick(self) -> None:
        """Tell an idle bus that the background source has work again."""
        line = self._line
        if line is not None:
            line.pump(self._engine.kick(now()))

    async def wait_idle(self) -> None:
        """Wait until nothing is queued or on the wire."""
        while not self._engine.idle and self._line is not None:
            waiter = self._get_loop().create_future()
            self._line.idle_waiters.append(waiter)
            await waiter

    # ------------------------------------------------------------------ public conveniences

    @property
    def stats(self) -> BusStats:
        return self._engine.counters.snapshot(queued=self._engine.queue.count)

    def servo(self, servo_id: int) -> Servo:
        from .servo import Servo

        return Servo(self, servo_id)

    def device(self, device_id: int) -> Device:
        from .servo import Device

        return Device(self, device_id)

    def servos(self, ids: Iterable[int]) -> list[Servo]:
        return [self.servo(i) for i in check_ids("ids", ids)]

    def stream(self, ids: Iterable[int], *, rate_hz: float | None = None, **options: Any) -> Stream:
        """A position :class:`~ics35_async.streaming.Stream` over ``ids``; use as ``async with``."""
        from .streaming import STREAM_OPTIONS, Stream

        unknown = set(options) - STREAM_OPTIONS
        if unknown:
            raise InvalidArgument(f"unknown stream option(s): {', '.join(sorted(unknown))}")
        return Stream(self, ids, rate_hz=rate_hz, **options)

    async def read_id(self, *, exactly_one_device: bool = False) -> int:
        """Read the ID of the only device on the line (every device answers: confirm there is one)."""
        from .bus_ids import read_id

        return await read_id(self, exactly_one_device=exactly_one_device)

    async def write_id(self, new_id: int, *, exactly_one_device: bool = False) -> int:
        """Give the only device on the line the ID ``new_id`` (refused unless exactly one device answers)."""
        from .bus_ids import write_id

        return await write_id(self, new_id, exactly_one_device=exactly_one_device)

    async def scan(self, ids: Iterable[int] = range(32), *, concurrency: int = 32) -> list[int]:
        """IDs that answer a stretch read (harmless: it moves nothing)."""
        from .bus_ids import scan

        return await scan(self, ids, concurrency=concurrency)

    def __repr__(self) -> str:
        return f"<Bus {self.port!s} {int(self.baudrate)} baud {self._engine.state.value}>"


def open_bus(
    port: str | WireDevice,
    *,
    baudrate: int = 115200,
    echo: bool = True,
    transport: str = "auto",
    timing: BusTiming | None = None,
    retries: int = 0,
    reconnect: bool = False,
    reconnect_backoff: Sequence[float] = RECONNECT_BACKOFF,
    max_requests_between: int = 16,
    **timing_overrides: float,
) -> Bus:
    """A :class:`Bus` on ``port``: use ``async with open_bus(...) as bus`` or ``bus = await open_bus(...)``.

    ``port`` is a serial device path, a pyserial URL (``socket://``,
    ``rfc2217://``, ``loop://``), ``sim://?...`` for the built-in simulator,
    or a :class:`~ics35_async.transports.WireDevice`.  Extra keyword
    arguments set :class:`BusTiming` fields (e.g. ``adapter_latency=0.002``).
    """
    if timing_overrides:
        unknown = set(timing_overrides) - set(BusTiming.__dataclass_fields__)
        if unknown:
            raise InvalidArgument(f"unknown open_bus option(s): {', '.join(sorted(unknown))}")
        timing = dataclasses.replace(timing or BusTiming(), **timing_overrides)
    return Bus(
        port,
        baudrate=baudrate,
        echo=echo,
        transport=transport,
        timing=timing,
        retries=retries,
        reconnect=reconnect,
        reconnect_backoff=reconnect_backoff,
        max_requests_between=max_requests_between,
    )


__all__ = ["BackgroundSource", "Bus", "BusTiming", "Priority", "open_bus"]
