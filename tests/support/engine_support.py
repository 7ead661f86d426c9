"""Plain-call helpers for the engine's own tests: a simulated wire, servos that answer it, a fake stream.

No event loop and no real clock: :class:`Wire` keeps a simulated time and the
bytes in flight, and drives a :class:`LineEngine` exactly as a driver must
(input that arrived before a deadline is fed before the deadline's tick; what
the engine returns is written at once).
"""

from __future__ import annotations

import heapq
import itertools
import math
from collections.abc import Callable, Iterable
from typing import Any

from ics35_async import protocol
from ics35_async.engine import FlushInput, LineEngine, Output, Request
from ics35_async.engine.source import Upcoming
from ics35_async.errors import IcsError, ReplyError
from ics35_async.protocol import Param, Position, ReadParam

BAUD = 115200
TURNAROUND = 0.0002  # the simulated servos' own turnaround, well inside the engine's allowance


def ready_engine(echo: bool = True, **options: Any) -> LineEngine:
    """An engine with its port open (IDLE) at time 0."""
    engine = LineEngine(baudrate=options.pop("baudrate", BAUD), echo=echo, **options)
    assert engine.connected(0.0) is None
    return engine


def wire_time(nbytes: int) -> float:
    return protocol.wire_time(nbytes, BAUD)


def read(sid: int, param: Param = Param.SPEED) -> ReadParam:
    return ReadParam(sid, param)


def position(sid: int, pos: int = 7500) -> Position:
    return Position(sid, pos, baudrate=BAUD)


class Recorded(Request):
    """A request that counts how often the engine hands it an outcome.

    With a ``wire``, it also notes the write its outcome came from (the last
    write before the engine resolved or rejected it: one transaction at a
    time) and how many arrivals the wire had delivered by then.
    """

    __slots__ = ("calls", "end_mark", "wire", "write_index")

    def __init__(
        self, command: protocol.Command[Any], priority: int = 2, retries: int = 0, wire: Wire | None = None
    ) -> None:
        super().__init__(command, priority, retries)
        self.calls = 0
        self.wire = wire
        self.write_index = -1
        self.end_mark = -1

    def _ended(self) -> None:
        self.calls += 1
        if self.state == "queued" and self.wire is not None:
            self.write_index = len(self.wire.writes) - 1
            self.end_mark = len(self.wire.delivered)

    def resolve(self, value: Any) -> None:
        self._ended()
        super().resolve(value)

    def reject(self, error: IcsError) -> None:
        self._ended()
        super().reject(error)


def misattributed(req: Recorded, servos: Servos) -> str | None:
    """Why ``req``'s value is not the reply to its own write (None when it is)."""
    assert req.wire is not None and req.state == "done"
    k = req.write_index
    tx = req.wire.writes[k][1]
    if tx != req.command.tx:
        return f"{req!r} resolved while write {k} ({tx.hex(' ')}) was on the wire"
    if req.value != servos.answers[k]:
        return f"{req!r} got {req.value}, but write {k} was answered {servos.answers[k]}"
    return None


Answer = Callable[["Wire", bytes], None]


class Wire:
    """Simulated time and the bytes in flight around one engine."""

    def __init__(self, engine: LineEngine, answer: Answer | None = None) -> None:
        self.engine = engine
        self.answer = answer
        self.now = 0.0
        self.writes: list[tuple[float, bytes]] = []
        self.flushes = 0  # FlushInput answers (resyncs ended)
        self.marks: list[int] = []  # per write: how many arrivals had been delivered before it
        self.delivered: list[object] = []  # the tag of each arrival delivered, in order
        self._arrivals: list[tuple[float, int, bytes, int, object]] = []  # (time, order, bytes, parity errors, tag)
        self._calls: list[tuple[float, int, Callable[[], object]]] = []  # what the program does, when
        self.end = -math.inf  # where the run in progress stops (none yet)
        self._order = itertools.count()
        self.on_write: Callable[[], None] | None = None  # called as each write goes out

    # -- what the world does

    def schedule(self, at: float, data: bytes, parity_errors: int = 0, tag: object = None) -> None:
        """Bytes that reach the host's port at ``at`` (with ``parity_errors`` of them marked).

        ``tag`` says whose bytes they are (e.g. the number of the write they answer).
        """
        heapq.heappush(self._arrivals, (at, next(self._order), data, parity_errors, tag))

    def at(self, when: float, call: Callable[[], object]) -> None:
        """The program does ``call()`` at ``when`` (before bytes that arrive at the same time)."""
        heapq.heappush(self._calls, (when, next(self._order), call))

    def _run_calls(self, until: float) -> None:
        while self._calls and self._calls[0][0] <= until:
            when, _, call = heapq.heappop(self._calls)
            self.now = max(self.now, when)
            call()

    def next_arrival(self, limit: float) -> tuple[bytes, int] | None:
        """The next bytes to arrive by ``limit`` (the program's calls due by then run first), or None
        with the time moved on to ``limit``: what a burst executor waiting on the port sees."""
        arrival = self._arrivals[0][0] if self._arrivals else math.inf
        self._run_calls(min(arrival, limit))
        if arrival > limit:
            self.now = max(self.now, limit)
            return None
        at, _, data, errors, tag = heapq.heappop(self._arrivals)
        self.now = max(self.now, at)
        self.delivered.append(tag)
        return data, errors

    def clear_in_flight(self) -> None:
        """The port is gone: bytes still on their way to it are lost with it."""
        self._arrivals.clear()

    @property
    def in_flight(self) -> bool:
        return bool(self._arrivals)

    # -- what the driver does

    def emit(self, out: Output) -> bytes | None:
        if isinstance(out, FlushInput):  # nothing waits in a simulated OS buffer: only counted
            self.flushes += 1
            out = out.then
        if out is not None:
            if self.on_write is not None:
                self.on_write()
            self.writes.append((self.now, out))
            self.marks.append(len(self.delivered))
            if self.answer is not None:
                self.answer(self, out)
        return out

    def submit(self, request: Request) -> bytes | None:
        return self.emit(self.engine.submit(request, self.now))

    def run_until(self, end: float, *, max_steps: int = 100_000) -> None:
        """Deliver arrivals and deadlines in time order up to ``end`` (arrivals first on a tie)."""
        engine = self.engine
        self.end = end
        for _ in range(max_steps):
            arrival = self._arrivals[0][0] if self._arrivals else math.inf
            deadline = engine.deadline
            if self._calls and self._calls[0][0] <= min(arrival, deadline, end):
                self._run_calls(self._calls[0][0])
                continue
            if min(arrival, deadline) > end:
                break
            if arrival <= deadline:
                at, _, data, errors, tag = heapq.heappop(self._arrivals)
                self.now = max(self.now, at)
                self.delivered.append(tag)
                if errors:
                    engine.line_error(errors)
                self.emit(engine.receive(data, self.now))
            else:
                self.now = max(self.now, deadline)
                before = (engine.state, engine.deadline)
                self.emit(engine.tick(self.now))
                if (engine.state, engine.deadline) == before and engine.deadline <= self.now:
                    raise AssertionError(f"tick({self.now}) left the engine {before}: it would spin")
        else:
            raise AssertionError("the engine never settled")
        self.now = max(self.now, end)

    def run_for(self, seconds: float) -> None:
        self.run_until(self.now + seconds)

    def settle(self, limit: float = 60.0) -> None:
        """Run until the engine has nothing on the wire, nothing resyncing and nothing queued, and nothing is
        due to arrive or be done."""
        end = self.now + limit
        while not self.engine.idle or self._arrivals or self._calls:
            nxt = min(
                self.engine.deadline,
                self._arrivals[0][0] if self._arrivals else math.inf,
                self._calls[0][0] if self._calls else math.inf,
            )
            if nxt > end:
                raise AssertionError(f"not idle after {limit} s: {self.engine.state}")
            self.run_until(nxt)

    def sent(self) -> list[bytes]:
        return [tx for _, tx in self.writes]


class Servos:
    """Well-behaved servos on the wire: the echo (when the line has one), then a reply per command.

    Every answer carries a fresh value (position replies 1..16383, parameter
    reads 1..127), so a reply taken for the wrong request shows.
    ``answers[k]`` is the value sent for write ``k`` (``None``: no reply);
    the writes numbered in ``mute`` get their echo but no reply, those in ``damaged`` a reply of the
    right length whose last byte has its MSB set (a reply the codec refuses by its bytes alone).
    """

    def __init__(
        self, ids: Iterable[int], echo: bool = True, turnaround: float = TURNAROUND, baudrate: int = BAUD
    ) -> None:
        self.ids = set(ids)
        self.echo = echo
        self.turnaround = turnaround
        self.baudrate = baudrate
        self.answers: list[Any] = []
        self.mute: set[int] = set()
        self.damaged: set[int] = set()
        self._serial = itertools.count(1)

    def value_for(self, command: protocol.Command[Any]) -> Any:
        n = next(self._serial)
        if isinstance(command, Position | protocol.ReadPosition):  # (ICS 3.6 servos, these)
            return n % protocol.POSITION_MAX + 1
        if isinstance(command, ReadParam):
            return n % 127 + 1
        if isinstance(command, protocol.WriteParam):
            return command.value
        return None

    def reply_for(self, tx: bytes) -> tuple[bytes | None, Any]:
        framed = protocol.decode_request(tx, baudrate=self.baudrate)
        command = framed[0] if framed is not None else None
        if command is None or command.servo_id not in self.ids:
            return None, None
        value = self.value_for(command)
        return command.encode_reply(value), value

    def __call__(self, wire: Wire, tx: bytes) -> None:
        t = wire.now
        if self.echo:
            wire.schedule(t + protocol.wire_time(len(tx), self.baudrate), tx, tag=len(self.answers))
        reply, value = self.reply_for(tx) if len(self.answers) not in self.mute else (None, None)
        if reply is not None and len(self.answers) in self.damaged:
            reply = reply[:-1] + bytes((reply[-1] | 0x80,))
        self.answers.append(value)
        if reply is not None:
            self.deliver(wire, tx, reply)

    def deliver(self, wire: Wire, tx: bytes, reply: bytes) -> None:
        at = wire.now + protocol.wire_time(len(tx) + len(reply), self.baudrate) + self.turnaround
        wire.schedule(at, reply, tag=len(self.answers) - 1)


class FakeSource:
    """A stream-like background source: position commands round the ``ids``, re-offering a job until told.

    It offers jobs only while ``active``, and with a ``period``, one per
    period (as a fixed-rate stream does); with nothing to send it waits for
    ``wake_at``.  ``paced``: it tells the engine its slots (``slot_due``), as a
    stream with a rate does, so requests must fit between them.  Replies are
    judged with the codec.
    """

    def __init__(
        self, ids: Iterable[int], *, wake_at: float = math.inf, period: float = 0.0, paced: bool = False
    ) -> None:
        self.ids = list(ids)
        self.active = True
        self.wake_at = wake_at
        self.period = period
        self.paced = paced
        self.started: list[tuple[float, float]] = []  # paced: (slot, when its transaction began)
        self.resumed: list[float] = []  # when the line came back after a loss
        self.k = 0
        self.asked = 0
        self.offered: list[bytes] = []
        self.values: list[tuple[int, int]] = []
        self.failures: list[ReplyError] = []
        self.skipped = 0
        self.closed: IcsError | None = None
        self.on_value: Callable[[int, int], None] | None = None

    def command(self) -> Position:
        return position(self.ids[self.k % len(self.ids)], 0)  # free: reads the position, moves nothing

    def slot_due(self, now: float) -> float | None:
        return self.wake_at if self.paced and self.active else None

    def next_transaction(self, now: float) -> tuple[bytes, int, int] | None:
        self.asked += 1
        if not self.active:
            return None
        if self.period:
            if now < self.wake_at:
                return None
            self.started.append((self.wake_at, now))
            self.wake_at = (self.wake_at if self.paced else now) + self.period
        command = self.command()
        self.offered.append(command.tx)
        assert command.servo_id is not None
        return command.tx, command.reply_len, command.servo_id

    def complete(self, buf: bytearray, offset: int, now: float) -> ReplyError | None:
        command = self.command()
        try:
            value = command.parse(bytes(buf[offset:]))
        except ReplyError as exc:
            return exc  # the engine calls fail
        assert command.servo_id is not None
        self.values.append((command.servo_id, value))
        if self.on_value is not None:
            self.on_value(command.servo_id, value)
        self.k += 1
        return None

    def fail(self, exc: ReplyError, now: float, sent: bool) -> None:
        self.failures.append(exc)
        self.k += 1

    def skip(self, now: float) -> None:
        self.skipped += 1
        self.k += 1

    def line_closed(self, exc: IcsError) -> None:
        self.closed = exc

    def line_resumed(self, now: float) -> None:
        self.resumed.append(now)

    def upcoming(self, limit: int) -> list[Upcoming]:
        """The one on the wire and the rest of this round of the IDs (none with a period: each
        transaction waits for its own)."""
        if self.period or not self.active:
            return []
        n = len(self.ids)
        jobs: list[Upcoming] = []
        for k in range(self.k, min((self.k // n + 1) * n, self.k + limit)):
            command = position(self.ids[k % n], 0)
            assert command.servo_id is not None
            shape = protocol.position_reply_shape(command.reply_header)
            jobs.append((command.tx, command.reply_len, command.servo_id, shape, k % n == n - 1))
        return jobs

    def upcoming_done(self) -> None:
        pass

    def probing_silent(self) -> bool:
        return False  # (it never takes a servo out of its cycle)


class StalledOnce(Servos):
    """Write ``stalled`` comes round ``delay`` seconds late, its echo and reply together: the host or the
    link stalled (a loaded machine, a pty server not yet scheduled), not the servo."""

    def __init__(self, ids: list[int], stalled: int, delay: float) -> None:
        super().__init__(ids)
        self.stalled = stalled
        self.delay = delay

    def __call__(self, wire: Wire, tx: bytes) -> None:
        if len(self.answers) != self.stalled:
            super().__call__(wire, tx)
            return
        reply, value = self.reply_for(tx)
        self.answers.append(value)
        assert reply is not None
        at = wire.now + protocol.wire_time(len(tx) + len(reply), self.baudrate) + self.turnaround + self.delay
        wire.schedule(at, tx + reply, tag=len(self.answers) - 1)


class StalledPipe(Servos):
    """A far end that stops reading from ``start`` to ``end`` (a pty simulator not scheduled, an adapter or a
    bridge holding bytes): each write meanwhile is answered at ``end``, echo and reply together, in the order
    written, each after the one before, as bytes through a pipe come.  Nothing is lost: everything comes late."""

    def __init__(self, ids: Iterable[int], start: float, end: float) -> None:
        super().__init__(ids)
        self.start, self.end = start, end
        self._free_at = 0.0  # when the far end has answered everything written so far

    def __call__(self, wire: Wire, tx: bytes) -> None:
        reply, value = self.reply_for(tx)
        self.answers.append(value)
        begin = self.end if self.start <= wire.now < self.end else wire.now
        self._free_at = at = (
            max(begin, self._free_at)
            + self.turnaround
            + protocol.wire_time(len(tx) + (len(reply) if reply is not None else 0), self.baudrate)
        )
        wire.schedule(at, tx + (reply or b""), tag=len(self.answers) - 1)
