"""The bus: the single owner of one half-duplex ICS line.

Any number of coroutines submit commands; the bus runs them one at a time.
For each it writes the command, consumes and checks the echo, reads exactly
the reply length of that command type, validates it with the protocol codec
and resolves the caller's future with the value or a typed error.

The engine is driven by the event loop's I/O callbacks rather than by a task
awaiting each reply: the callback that completes one transaction writes the
next one straight away, so a transaction costs no task switch and no extra
loop pass.  A small supervisor task handles what may wait (reopening a lost
port).  Because the engine, not the caller, owns each transaction, a caller
cancelled mid-transaction cannot desync the line: the engine still consumes
that reply (and drops it).

Resync: after a timeout, a partial reply, an echo mismatch, a bad reply or
stray bytes, the engine discards input and waits for the line to stay quiet
for ``quiet_time`` before the next transaction, so the late bytes of a failed
transaction are never taken as the next reply.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import enum
import logging
import time
from collections import deque
from collections.abc import Callable, Generator, Iterable, Sequence
from dataclasses import dataclass
from types import TracebackType
from typing import TYPE_CHECKING, Any, Protocol, TypeVar

from . import protocol
from .errors import (
    BadReply,
    BusClosed,
    EchoMismatch,
    IcsError,
    InvalidArgument,
    PartialReply,
    PortLost,
    ReplyDataError,
    ReplyError,
    ReplyTimeout,
    UnsafeOperation,
)
from .protocol import Command, Timing
from .stats import COUNTER_NAMES, BusStats, IdStats, LatencyHistogram
from .transport import WireDevice, discard_input, open_line
from .units import check_bool, check_ids, check_int, check_seconds

if TYPE_CHECKING:  # servo.py builds on this module; imported lazily at run time
    from .servo import Device, Servo
    from .streaming import Stream

log = logging.getLogger("ics35_async")

T = TypeVar("T")


class Priority(enum.IntEnum):
    """Request priority: lower runs first; FIFO within a level."""

    URGENT = 0  # e.g. free-all / emergency stop: before everything queued
    HIGH = 1
    NORMAL = 2
    LOW = 3


@dataclass(frozen=True)
class BusTiming:
    """Deadline and resync allowances, in seconds.

    A transaction's deadline is its wire time ((TX + reply bytes) x 11 / baud)
    plus ``turnaround`` plus ``adapter_latency`` plus, for the EEPROM write and
    the ID command, their extra allowance.
    """

    turnaround: float = 0.0005
    adapter_latency: float = 0.020  # USB adapters add 0.1-16 ms (FTDI latency timer)
    eeprom_write: float = 0.200
    id_command: float = 0.050
    quiet_time: float = 0.010  # silence required before the next transaction after a fault
    max_resync: float = 0.5  # a line that never goes quiet is used anyway after this

    def __post_init__(self) -> None:
        for name in ("turnaround", "adapter_latency", "eeprom_write", "id_command", "quiet_time", "max_resync"):
            check_seconds(name, getattr(self, name))


class BackgroundSource(Protocol):
    """Something that fills the line's idle time (the position stream).

    ``next_transaction`` returns ``(tx, reply_len, servo_id)`` or ``None`` when
    it has nothing to send now.  ``complete`` gets the receive buffer and the
    reply's offset in it (after the echo) and returns ``None`` or the error
    that made the reply invalid.  ``fail`` is told of a timeout or echo fault.
    """

    def next_transaction(self) -> tuple[bytes, int, int] | None: ...

    def complete(self, buf: bytearray, offset: int, now: float) -> ReplyError | None: ...

    def fail(self, exc: ReplyError, now: float) -> None: ...

    def bus_closed(self, exc: IcsError) -> None:
        """The bus closed for good (or lost its port with reconnect off): stop."""


class _State(enum.Enum):
    CLOSED = "closed"  # not opened yet, or closed for good
    IDLE = "idle"
    BUSY = "busy"  # a transaction is on the wire
    QUIET = "quiet"  # resyncing: waiting for silence
    LOST = "lost"  # port gone, reconnecting
    REOPENING = "reopening"  # closing and reopening on purpose (new baud rate); requests wait


class _Request:
    __slots__ = ("command", "future", "priority", "retries_left")

    is_guard = False

    def __init__(self, command: Command[Any], future: asyncio.Future[Any], priority: int, retries: int) -> None:
        self.command = command
        self.future = future
        self.priority = priority
        self.retries_left = retries


class _GuardRequest(_Request):
    """The harmless read the bus slips in after a timeout (see ``Bus._guard``)."""

    __slots__ = ()

    is_guard = True


class _Line(asyncio.Protocol):
    """Forwards the transport's callbacks to the bus."""

    def __init__(self, bus: Bus) -> None:
        self.data_received = bus._on_data  # type: ignore[method-assign]
        self._bus = bus

    def connection_lost(self, exc: Exception | None) -> None:
        self._bus._on_connection_lost(self, exc)

    def line_error(self, count: int) -> None:
        """The transport saw ``count`` bytes arrive with parity or framing errors."""
        self._bus._on_line_error(count)


_NO_ID = 32  # counter slot for the ID command, which addresses the whole line
# Delays between reopen attempts; capped well under 1 s so a returning port is found fast.
RECONNECT_BACKOFF = (0.05, 0.1, 0.2, 0.4)


def _consume_outcome(future: asyncio.Future[Any]) -> None:
    """Nobody awaits a guard read: fetch its outcome so asyncio does not warn."""
    if not future.cancelled():
        future.exception()


# The bus's clock: the default event loop's own (time.monotonic); uvloop's loop.time() is
# whole milliseconds cached per iteration, too coarse for latencies and reply timestamps.
_now = time.monotonic


class Bus:
    """One ICS line.  Create with :func:`open_bus`."""

    def __init__(
        self,
        port: str | WireDevice = "sim://",
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
        self.baudrate = protocol.check_baud(baudrate)
        self.echo = check_bool("echo", echo)
        self.transport_kind = transport
        self.timing = timing or BusTiming()
        self.retries = check_int("retries", retries, 0, 10)
        self.reconnect = check_bool("reconnect", reconnect)
        self.reconnect_backoff = tuple(check_seconds("reconnect delay", d) for d in reconnect_backoff) or (0.5,)
        self.max_requests_between = check_int("max_requests_between", max_requests_between, 1, 10_000)

        self._state = _State.CLOSED
        self._closing = False
        self._released = False
        self._reopening = False
        self._opening: asyncio.Future[None] | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._transport: asyncio.Transport | None = None
        self._line: _Line | None = None
        self._queues: list[deque[_Request]] = [deque() for _ in Priority]
        self._queued = 0
        self._source: BackgroundSource | None = None
        self._requests_in_row = 0

        # The transaction on the wire.
        self._buf = bytearray()
        self._tx = b""
        self._expect = 0
        self._echo_len = 0
        self._current: _Request | None = None  # None while a background transaction runs
        self._owner: BackgroundSource | None = None  # the source whose transaction is on the wire
        self._current_id = _NO_ID
        self._t_start = 0.0
        self._deadline = 0.0
        self._grace_given = False
        self._corrupted = False  # a byte of this transaction had a parity/framing error
        # Command byte of a transaction that timed out while its reply may still come (-1: none).
        self._suspect = -1
        self._line_errors = 0
        self._guards = 0
        self._watchdog: asyncio.TimerHandle | None = None
        self._quiet_until = 0.0
        self._resync_limit = 0.0
        self._idle_waiters: list[asyncio.Future[None]] = []
        self._supervisor: asyncio.Task[None] | None = None
        self._lost_event: asyncio.Event | None = None

        # Counters: one list per counter name, indexed by ID (slot 32: the ID command).
        self._counters: dict[str, list[int]] = {name: [0] * 33 for name in COUNTER_NAMES}
        # The hot path's counters, as direct references into _counters.
        self._n_transactions = self._counters["transactions"]
        self._n_ok = self._counters["ok"]
        self._n_bytes_tx = self._counters["bytes_tx"]
        self._n_bytes_rx = self._counters["bytes_rx"]
        self._allowances: dict[int, float] = {}  # NORMAL deadline allowance by transaction size
        self._latency = LatencyHistogram()
        self._resyncs = 0
        self._stray = 0
        self._reconnects = 0
        self._by_command: dict[str, int] = {}
        self._debug = log.isEnabledFor(logging.DEBUG)

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
        if self._state is not _State.CLOSED or self._closing:
            if self._closing:
                raise BusClosed("bus is closed")
            return self
        if self._opening is not None:  # another open() is under way: share its outcome
            await asyncio.shield(self._opening)
            if self._state is _State.CLOSED:
                raise BusClosed(f"opening {self.port} failed")
            return self
        self._loop = asyncio.get_running_loop()
        opening = self._opening = self._loop.create_future()
        try:
            await self._connect()
        finally:
            self._opening = None
            opening.set_result(None)  # waiters look at the state, not at this result
        self._lost_event = asyncio.Event()
        self._supervisor = self._loop.create_task(self._supervise(), name=f"ics35 bus {self.port}")
        return self

    async def _connect(self) -> None:
        transport, line = await open_line(
            self.port, baudrate=self.baudrate, protocol_factory=lambda: _Line(self), transport=self.transport_kind
        )
        self._transport, self._line = transport, line
        self._buf.clear()
        self._allowances.clear()  # wire times depend on the baud rate, which reopen() may change
        self._state = _State.IDLE
        log.info("opened %s at %d baud", self.port, self.baudrate)
        self._start_next()

    async def reopen(self, *, baudrate: int | None = None) -> None:
        """Close and reopen the port, optionally at a new line rate.

        For a baud-rate change: write the servos' EEPROM (``allow_baud_change=True``),
        power-cycle them, then ``await bus.reopen(baudrate=...)``.  Requests
        submitted meanwhile wait and run after the reopen.
        """
        new_baud = self.baudrate if baudrate is None else protocol.check_baud(baudrate)
        if self._closing or self._state is _State.CLOSED:
            raise BusClosed("bus is closed")
        if self._source is not None or self._reopening:
            raise InvalidArgument("stop the running stream (or the other reopen) before reopening the bus")
        self._reopening = True  # attach_source refuses from here on
        try:
            await self.wait_idle()
        finally:
            self._reopening = False
        if self._state is not _State.IDLE:
            raise PortLost(f"port {self.port} is lost; cannot reopen now")
        self._state = _State.REOPENING
        transport, self._transport, self._line = self._transport, None, None
        if transport is not None:
            transport.close()
            await asyncio.sleep(0)
        self.baudrate = new_baud
        try:
            await self._connect()
        except BaseException as exc:
            reason = f"reopening {self.port} failed: {exc}"
            self._state = _State.CLOSED
            self._closing = True
            self._fail_queued(lambda: PortLost(reason))
            raise

    @property
    def is_open(self) -> bool:
        return self._state is not _State.CLOSED and not self._closing

    async def aclose(self) -> None:
        """Fail queued requests with BusClosed, finish the one on the wire, release the port."""
        if self._released:
            return
        self._released = True  # also after a port loss, which closes the bus but leaves this to do
        self._closing = True
        self._detach_source(BusClosed("bus closed"))
        self._fail_queued(lambda: BusClosed("bus closed"))
        if self._state in (_State.BUSY, _State.QUIET):
            waiter = self._get_loop().create_future()
            self._idle_waiters.append(waiter)
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(waiter, self._transaction_allowance(200) + self.timing.max_resync + 1)
        if self._supervisor is not None:
            self._supervisor.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._supervisor
            self._supervisor = None
        self._cancel_watchdog()
        self._state = _State.CLOSED
        transport, self._transport = self._transport, None
        if transport is not None:
            transport.close()
            # Let the transport deliver connection_lost and release the fd.
            await asyncio.sleep(0)
        if self._current is not None:
            self._settle(self._current, BusClosed("bus closed"))
            self._current = None
        self._release_idle_waiters()
        log.info("closed %s", self.port)

    def _get_loop(self) -> asyncio.AbstractEventLoop:
        if self._loop is None:
            raise BusClosed("bus is not open")
        return self._loop

    # ------------------------------------------------------------------ submitting

    async def request(
        self,
        command: Command[T],
        *,
        priority: Priority = Priority.NORMAL,
        retries: int | None = None,
    ) -> T:
        """Run one command and return its parsed reply.

        ``retries`` (default: the bus's) applies only to idempotent commands.
        Raises :class:`ReplyError` subclasses, :class:`BusClosed` or
        :class:`PortLost`.
        """
        fut = self.submit(command, priority=priority, retries=retries)
        return await fut

    def submit(
        self,
        command: Command[T],
        *,
        priority: Priority = Priority.NORMAL,
        retries: int | None = None,
    ) -> asyncio.Future[T]:
        """Queue ``command`` and return the future of its result (no await needed)."""
        if not isinstance(command, Command):
            raise InvalidArgument(f"not a command: {command!r}")
        check_int("priority", priority, Priority.URGENT, Priority.LOW)
        retries = self.retries if retries is None else check_int("retries", retries, 0, 10)
        if self._closing or self._state is _State.CLOSED:
            raise BusClosed("bus is closed" if self._closing else "bus is not open (use `async with open_bus(...)`)")
        if self._state is _State.LOST:
            raise PortLost(f"port {self.port} is lost; reconnecting")
        loop = self._get_loop()
        # Re-read per request (not per stream transaction) so enabling DEBUG takes effect.
        self._debug = log.isEnabledFor(logging.DEBUG)
        fut: asyncio.Future[T] = loop.create_future()
        self._queues[priority].append(_Request(command, fut, priority, retries if command.idempotent else 0))
        self._queued += 1
        if self._state is _State.IDLE:
            self._start_next()
        return fut

    def attach_source(self, source: BackgroundSource | None) -> None:
        """Let ``source`` fill the line's idle time (one at a time); ``None`` detaches."""
        if source is not None and self._source is not None and source is not self._source:
            raise InvalidArgument("this bus already runs a stream; close it first")
        if source is not None and (self._reopening or self._state is _State.REOPENING):
            raise InvalidArgument("the bus is reopening; start the stream afterwards")
        self._source = source
        if source is not None and self._state is _State.IDLE:
            self._start_next()

    def detach_source(self, source: BackgroundSource) -> None:
        """Stop ``source`` filling the line (no-op if it is not attached)."""
        if self._source is source:
            self._source = None

    def kick(self) -> None:
        """Tell an idle bus that the background source has work again."""
        if self._state is _State.IDLE:
            self._start_next()

    async def wait_idle(self) -> None:
        """Wait until nothing is queued or on the wire."""
        while self._state in (_State.BUSY, _State.QUIET) or self._queued:
            waiter = self._get_loop().create_future()
            self._idle_waiters.append(waiter)
            await waiter

    # ------------------------------------------------------------------ the engine

    def _pop_request(self) -> _Request | None:
        if not self._queued:
            return None
        for queue in self._queues:
            while queue:
                req = queue.popleft()
                self._queued -= 1
                if not req.future.done():  # skip requests whose caller gave up
                    return req
        return None

    def _start_next(self) -> None:
        """Put the next transaction on the wire, if any.  Called only when IDLE."""
        source = self._source
        if self._queued and (source is None or self._requests_in_row < self.max_requests_between):
            req = self._pop_request()
            if req is not None:
                self._requests_in_row += 1
                cmd = req.command
                self._begin(cmd.tx, cmd.reply_len, cmd.servo_id, req, cmd.timing)
                return
        self._requests_in_row = 0
        if source is not None:
            job = source.next_transaction()
            if job is not None:
                self._owner = source
                self._begin(job[0], job[1], job[2], None, Timing.NORMAL)
                return
            if self._queued:  # the source yielded its turn but requests still wait
                self._start_next()
                return
        if self._idle_waiters and not self._queued:
            self._release_idle_waiters()

    def _transaction_allowance(self, nbytes: int, timing: Timing = Timing.NORMAL) -> float:
        t = self.timing
        allowance = protocol.wire_time(nbytes, self.baudrate) + t.turnaround + t.adapter_latency
        if timing is Timing.EEPROM_WRITE:
            allowance += t.eeprom_write
        elif timing is Timing.ID:
            allowance += t.id_command
        return allowance

    def _begin(self, tx: bytes, reply_len: int, servo_id: int | None, req: _Request | None, timing: Timing) -> None:
        if self._suspect >= 0:
            suspect, self._suspect = self._suspect, -1
            if tx[0] == suspect and servo_id is not None:
                self._guard(tx, servo_id, req)
                return
        transport = self._transport
        assert transport is not None and self._loop is not None
        self._state = _State.BUSY
        self._current = req
        self._current_id = _NO_ID if servo_id is None else servo_id
        self._tx = tx
        echo_len = len(tx) if self.echo else 0
        self._echo_len = echo_len
        self._expect = echo_len + reply_len
        self._buf.clear()
        self._grace_given = False
        self._corrupted = False
        now = _now()
        self._t_start = now
        nbytes = len(tx) + reply_len
        allowance = self._allowances.get(nbytes) if timing is Timing.NORMAL else None
        if allowance is None:
            allowance = self._transaction_allowance(nbytes, timing)
            if timing is Timing.NORMAL:
                self._allowances[nbytes] = allowance
        self._deadline = now + allowance
        self._arm()
        try:
            transport.write(tx)
        except Exception as exc:  # the port vanished under us
            self._on_connection_lost(self._line, exc)

    def _guard(self, tx: bytes, servo_id: int, req: _Request | None) -> None:
        """Put a harmless read between a timed-out command and its twin.

        A reply that missed its deadline can still arrive right after the echo
        of the next command.  If that command has the same command byte, the
        late reply has the right length and header and would be taken for the
        new answer.  A parameter read with a different reply shape goes first
        instead, so late bytes fail it, not the real request.
        """
        if req is not None:
            self._queues[req.priority].appendleft(req)
            self._queued += 1
        guard = protocol.guard_read(tx, servo_id)
        assert self._loop is not None
        future: asyncio.Future[Any] = self._loop.create_future()
        future.add_done_callback(_consume_outcome)
        self._guards += 1
        self._begin(guard.tx, guard.reply_len, servo_id, _GuardRequest(guard, future, Priority.URGENT, 0), guard.timing)

    def _arm(self) -> None:
        # One watchdog timer follows the moving deadline instead of a timer per
        # transaction: transactions normally finish long before their deadline, and
        # deadlines usually only move later.  When one moves earlier (after an EEPROM
        # write's long allowance, or a resync's short quiet time), re-arm.
        watchdog = self._watchdog
        if watchdog is not None:
            if watchdog.when() <= self._deadline:
                return
            watchdog.cancel()
        assert self._loop is not None
        self._watchdog = self._loop.call_at(self._deadline, self._on_watchdog)

    def _cancel_watchdog(self) -> None:
        if self._watchdog is not None:
            self._watchdog.cancel()
            self._watchdog = None

    def _on_watchdog(self) -> None:
        self._watchdog = None
        assert self._loop is not None
        now = _now()
        if self._state is _State.BUSY:
            if now < self._deadline:
                self._arm()
            elif not self._grace_given:
                # The loop may have stalled past the deadline with the reply already read
                # or queued behind this callback: judge it after one more I/O poll. A timer
                # (not call_soon) runs after that poll's I/O callbacks.
                self._grace_given = True
                assert self._loop is not None
                self._watchdog = self._loop.call_at(now, self._on_watchdog)
            else:
                self._on_timeout()
        elif self._state is _State.QUIET:
            if now < self._quiet_until and now < self._resync_limit:
                self._deadline = self._quiet_until
                self._arm()
            elif not self._grace_given and now < self._resync_limit:
                # As for a deadline: bytes already read but queued behind this callback
                # must extend the quiet time before the next transaction starts.
                self._grace_given = True
                assert self._loop is not None
                self._watchdog = self._loop.call_at(now, self._on_watchdog)
            else:
                if now < self._quiet_until:
                    log.warning("line on %s never went quiet; carrying on", self.port)
                self._end_resync()

    def _on_data(self, data: bytes) -> None:
        state = self._state
        if state is _State.BUSY:
            buf = self._buf
            buf += data
            if len(buf) >= self._expect:
                self._finish()
        elif state is _State.QUIET:
            self._stray += len(data)
            self._quiet_until = _now() + self.timing.quiet_time
            self._grace_given = False
        elif state is _State.IDLE:
            # Bytes on an idle line: a late reply or noise. Let it settle first.
            self._stray += len(data)
            if self._debug:
                log.debug("stray bytes on idle line: %s", data.hex(" "))
            self._resync()

    def _on_line_error(self, count: int) -> None:
        self._line_errors += count
        if self._state is _State.BUSY:
            self._corrupted = True  # the transaction fails once its bytes are all in

    def _finish(self) -> None:
        buf = self._buf
        now = _now()
        sid = self._current_id
        tx = self._tx
        if self._debug:
            log.debug("id %s tx %s rx %s", sid, tx.hex(" "), buf.hex(" "))
        # Counted now (before the next _begin reuses these fields), recorded as ok later.
        n_tx, n_rx, latency = len(tx), len(buf), now - self._t_start
        self._n_transactions[sid] += 1
        self._n_bytes_tx[sid] += n_tx
        self._n_bytes_rx[sid] += n_rx
        echo_len = self._echo_len
        if n_rx != self._expect or (echo_len and not buf.startswith(tx)) or self._corrupted:
            self._latency.add(latency)
            self._framing_error(now, sid)
            return
        req = self._current
        self._current = None
        if req is None:
            # Only the source that sent the command hears its reply (it may have been
            # detached, and another attached, while the command was on the wire).
            source = self._owner if self._owner is self._source else None
            error = source.complete(buf, echo_len, now) if source is not None else None
            if error is not None:
                self._latency.add(latency)
                self._background_failed(error, sid)
                return
            # The next command goes on the wire first; the bookkeeping can wait.
            self._state = _State.IDLE
            self._start_next()
        else:
            try:
                value = req.command.parse(bytes(buf[echo_len:]))
            except ReplyError as exc:
                self._latency.add(latency)
                self._fail_request(req, exc, sid)
                return
            name = req.command.name
            self._by_command[name] = self._by_command.get(name, 0) + 1
            if not req.future.done():
                req.future.set_result(value)
            self._state = _State.IDLE
            self._start_next()
        self._n_ok[sid] += 1
        self._latency.add(latency)

    def _framing_error(self, now: float, sid: int) -> None:
        """Extra bytes after the reply, or an echo that is not what we sent."""
        if self._corrupted:
            error = self._transaction_error(
                ReplyDataError, "a byte arrived with a parity or framing error (noise on the line?)"
            )
        elif len(self._buf) > self._expect:
            error = self._transaction_error(
                BadReply, f"{len(self._buf) - self._expect} unexpected extra byte(s) after the reply"
            )
        else:
            error = self._transaction_error(EchoMismatch, f"echo differs from the bytes sent ({self._tx.hex(' ')})")
        self._transaction_failed(error, sid, now)

    def _transaction_error(self, cls: type[ReplyError], message: str, **extra: int) -> ReplyError:
        """A ``cls`` error about the transaction on the wire, carrying every byte received."""
        req = self._current
        return cls(
            message,
            command=req.command.name if req is not None else "position",
            servo_id=None if self._current_id == _NO_ID else self._current_id,
            raw=bytes(self._buf),
            **extra,
        )

    def _transaction_failed(self, error: ReplyError, sid: int, now: float) -> None:
        """Hand a failed transaction's error to its request, or to the stream that sent it."""
        req, self._current = self._current, None
        if req is not None:
            self._fail_request(req, error, sid)
            return
        if self._owner is not None and self._owner is self._source:
            self._owner.fail(error, now)
        self._background_failed(error, sid)

    def _background_failed(self, error: ReplyError, sid: int) -> None:
        self._count_error(error, sid)
        self._resync()

    def _count_error(self, error: ReplyError, sid: int) -> None:
        if isinstance(error, ReplyTimeout):
            name = "timeouts"
        elif isinstance(error, PartialReply):
            name = "partial_replies"
        elif isinstance(error, EchoMismatch):
            name = "echo_mismatches"
        else:
            name = "bad_replies"
        self._counters[name][sid] += 1
        log.debug("%s", error)

    def _fail_request(self, req: _Request, error: ReplyError, sid: int) -> None:
        self._count_error(error, sid)
        if req.retries_left > 0 and not req.future.done() and not self._closing:
            req.retries_left -= 1
            self._counters["retries"][sid] += 1
            self._queues[req.priority].appendleft(req)
            self._queued += 1
        elif not req.future.done():
            req.future.set_exception(BusClosed("bus closed") if self._closing and req.retries_left else error)
        self._resync()

    def _on_timeout(self) -> None:
        buf = self._buf
        sid = self._current_id
        got = len(buf)
        self._n_transactions[sid] += 1
        self._n_bytes_tx[sid] += len(self._tx)
        self._n_bytes_rx[sid] += got
        echo_len = self._echo_len
        error: ReplyError
        if echo_len and buf[: min(got, echo_len)] != self._tx[: min(got, echo_len)]:
            error = self._transaction_error(EchoMismatch, "echo differs from the bytes sent")
        elif got == 0:
            error = self._transaction_error(
                ReplyTimeout, "no echo and no reply: is the adapter connected?" if echo_len else "no reply"
            )
        elif got <= echo_len:
            error = self._transaction_error(ReplyTimeout, "no reply (check ID, baud rate, power)")
        else:
            n, m = got - echo_len, self._expect - echo_len
            error = self._transaction_error(PartialReply, f"{n} of {m} reply bytes", received=n, expected=m)
        req = self._current
        if not isinstance(error, EchoMismatch) and not (req is not None and req.is_guard):
            # The command was heard: its reply may still come.  (A guard's late reply
            # always differs in shape from the command it protects, so it needs none.)
            self._suspect = self._tx[0]
        self._transaction_failed(error, sid, _now())

    def _resync(self) -> None:
        assert self._loop is not None
        self._resyncs += 1
        self._state = _State.QUIET
        now = _now()
        self._quiet_until = now + self.timing.quiet_time
        self._resync_limit = now + self.timing.max_resync
        self._buf.clear()
        self._grace_given = False
        self._deadline = self._quiet_until
        self._arm()

    def _end_resync(self) -> None:
        if self._transport is not None:
            discard_input(self._transport)
        self._state = _State.IDLE
        self._start_next()

    # ------------------------------------------------------------------ losing the port

    def _on_connection_lost(self, line: _Line | None, exc: Exception | None) -> None:
        if line is not self._line or self._state in (_State.CLOSED, _State.LOST):
            return
        self._cancel_watchdog()
        self._line = None
        transport, self._transport = self._transport, None
        if transport is not None and not transport.is_closing():
            transport.close()
        if self._closing:
            self._state = _State.CLOSED
            self._release_idle_waiters()
            return
        reason = f"port {self.port} lost: {exc}" if exc else f"port {self.port} closed"
        log.warning("%s", reason)
        req, self._current = self._current, None
        if req is not None:
            self._settle(req, PortLost(reason))
        self._fail_queued(lambda: PortLost(reason))
        if self.reconnect:
            self._state = _State.LOST
            if self._lost_event is not None:
                self._lost_event.set()
        else:
            self._state = _State.CLOSED
            self._closing = True
            self._detach_source(PortLost(reason))
        self._release_idle_waiters()

    def _detach_source(self, exc: IcsError) -> None:
        source, self._source = self._source, None
        if source is not None:
            source.bus_closed(exc)

    def _release_idle_waiters(self) -> None:
        waiters, self._idle_waiters = self._idle_waiters, []
        for w in waiters:
            if not w.done():
                w.set_result(None)

    def _settle(self, req: _Request, error: IcsError) -> None:
        if not req.future.done():
            req.future.set_exception(error)

    def _fail_queued(self, make_error: Callable[[], IcsError]) -> None:
        for queue in self._queues:
            while queue:
                self._settle(queue.popleft(), make_error())
        self._queued = 0

    async def _supervise(self) -> None:
        assert self._lost_event is not None
        while True:
            await self._lost_event.wait()
            self._lost_event.clear()
            attempt = 0
            while self._state is _State.LOST and not self._closing:
                delay = self.reconnect_backoff[min(attempt, len(self.reconnect_backoff) - 1)]
                await asyncio.sleep(delay)
                attempt += 1
                try:
                    await self._connect()
                except (OSError, IcsError) as exc:
                    log.debug("reconnect %d to %s failed: %s", attempt, self.port, exc)
                else:
                    self._reconnects += 1
                    log.info("reconnected to %s after %d attempt(s)", self.port, attempt)

    # ------------------------------------------------------------------ public conveniences

    @property
    def stats(self) -> BusStats:
        per_id: dict[int | None, IdStats] = {}
        total = IdStats()
        for slot in range(33):
            values = {name: self._counters[name][slot] for name in COUNTER_NAMES}
            if any(values.values()):
                s = IdStats(**values)
                per_id[None if slot == _NO_ID else slot] = s
                total.add(s)
        return BusStats(
            total=total,
            per_id=per_id,
            latency=self._latency.copy(),
            resyncs=self._resyncs,
            stray_bytes=self._stray,
            line_errors=self._line_errors,
            guards=self._guards,
            reconnects=self._reconnects,
            queued=self._queued,
            by_command=dict(self._by_command),
        )

    def servo(self, servo_id: int) -> Servo:
        from .servo import Servo  # servo.py builds on this module

        return Servo(self, servo_id)

    def device(self, device_id: int) -> Device:
        from .servo import Device

        return Device(self, device_id)

    def servos(self, ids: Iterable[int]) -> list[Servo]:
        return [self.servo(i) for i in check_ids("ids", ids)]

    def stream(self, ids: Iterable[int], *, rate_hz: float | None = None, **options: Any) -> Stream:
        """A position :class:`~ics35_async.streaming.Stream` over ``ids``; use as ``async with``."""
        import inspect

        from .streaming import Stream

        unknown = set(options) - (set(inspect.signature(Stream).parameters) - {"bus", "ids"})
        if unknown:
            raise InvalidArgument(f"unknown stream option(s): {', '.join(sorted(unknown))}")
        return Stream(self, ids, rate_hz=rate_hz, **options)

    async def read_id(self, *, exactly_one_device: bool = False) -> int:
        """Read the ID of the only device on the line.

        With several devices on the line every one answers at once and the
        result is garbage, so the caller must confirm there is exactly one.
        """
        if exactly_one_device is not True:
            raise UnsafeOperation(
                "read_id() needs exactly one device on the line (every device answers the ID command); "
                "pass exactly_one_device=True to confirm"
            )
        return await self.request(protocol.ReadId())

    async def write_id(self, new_id: int, *, exactly_one_device: bool = False) -> int:
        """Give the only device on the line the ID ``new_id`` (stored in its EEPROM).

        Every device on the line takes the new ID, so this is refused unless
        the caller confirms with ``exactly_one_device=True``.
        """
        command = protocol.WriteId(new_id)
        if exactly_one_device is not True:
            raise UnsafeOperation(
                "write_id() renames EVERY device on the line; disconnect all but one and pass exactly_one_device=True"
            )
        # Take the caller's word, but check it: exactly one ID may answer a harmless read,
        # and the ID read (which every device answers) must agree with it.
        found = await self.scan()
        if len(found) != 1:
            raise UnsafeOperation(
                f"{len(found)} devices answer on this line (IDs {found}); write_id() needs exactly one; "
                "nothing was written"
            )
        try:
            current = await self.request(protocol.ReadId())
        except BadReply as exc:
            raise UnsafeOperation(
                f"the ID read came back garbled ({exc.raw.hex(' ')}): more than one device is on the line; "
                "nothing was written"
            ) from exc
        if current != found[0]:
            raise UnsafeOperation(
                f"the ID read says {current} but ID {found[0]} answers: another device (at another baud "
                "rate?) may share the line; nothing was written"
            )
        return await self.request(command)

    async def scan(self, ids: Iterable[int] = range(32), *, concurrency: int = 32) -> list[int]:
        """IDs that answer a stretch read (harmless: it moves nothing).

        ``concurrency`` bounds how many probes are queued at once (the line
        still runs them one at a time), leaving room for other callers.
        """
        checked = check_ids("ids", ids)
        gate = asyncio.Semaphore(check_int("concurrency", concurrency, 1, 32))

        async def probe(i: int) -> int | None:
            async with gate:
                try:
                    await self.request(protocol.ReadParam(i, protocol.Param.STRETCH), retries=1)
                except ReplyError:
                    return None
                return i

        found = await asyncio.gather(*(probe(i) for i in checked))
        return [i for i in found if i is not None]

    def __repr__(self) -> str:
        return f"<Bus {self.port!s} {int(self.baudrate)} baud {self._state.value}>"


def open_bus(
    port: str | WireDevice = "sim://",
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
    or a :class:`~ics35_async.transport.WireDevice`.  Extra keyword
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
