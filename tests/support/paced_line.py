"""A paced stream on a faulty line in simulated time: the engine, a stream-like source and servos, no clock.

Twelve servos at 100 Hz on a 1.25 Mbit/s line (the control loop the library
promises), replies dropped, cut short, garbled or late at a chosen rate, and
a program reading temperatures beside it.  Used by tests/test_engine_paced_faults.py,
tests/test_engine_paced_requests.py and benchmarks/bench_control_loop.py.
"""

from __future__ import annotations

import math
import random
from typing import Any

from ics35_async import protocol
from ics35_async.engine import BusTiming, LineEngine, Priority
from ics35_async.engine.source import Upcoming
from ics35_async.errors import IcsError, ReplyError, ReplyTimeout

from .engine_support import Recorded, Servos, Wire

BAUD = 1_250_000
PERIOD = 0.010
IDS = list(range(1, 13))


class PacedCycle:
    """A stream with a rate, as the engine sees it: one position transaction per ID per cycle, a
    cycle per slot (a late cycle keeps the schedule; a whole slot missed re-anchors it)."""

    def __init__(self, ids: list[int], period: float) -> None:
        self.ids = ids
        self.period = period
        self.wake_at = 0.0
        self.t0 = -1.0
        self.cycle = 0
        self.pos = len(ids)
        self.starts: list[float] = []
        self.late: list[float] = []  # how long after its slot each cycle started
        self.missed = 0  # cycles that started more than a period after their slot (the schedule re-anchored)
        self.failed = 0

    def slot_due(self, now: float) -> float | None:
        return now if self.pos < len(self.ids) or self.t0 < 0 else self.t0 + self.cycle * self.period

    def next_transaction(self, now: float) -> tuple[bytes, int, int] | None:
        if self.pos >= len(self.ids):
            if self.t0 >= 0:
                due = self.t0 + self.cycle * self.period
                if now < due:
                    self.wake_at = due
                    return None
                self.late.append(now - due)
                if now - due > self.period:
                    self.missed += 1
                    self.t0 = now - self.cycle * self.period
            else:
                self.t0 = now
            self.cycle += 1
            self.pos = 0
            self.starts.append(now)
            self.wake_at = math.inf
        sid = self.ids[self.pos]
        return protocol.position_tx(sid, 7500), 3, sid

    def complete(self, buf: bytearray, offset: int, now: float) -> ReplyError | None:
        command = protocol.Position(self.ids[self.pos], 7500, baudrate=BAUD)
        try:
            command.parse(bytes(buf[offset:]))
        except ReplyError as exc:
            return exc
        self.pos += 1
        return None

    def fail(self, exc: ReplyError, now: float, sent: bool) -> None:
        self.failed += 1
        self.pos += 1

    def skip(self, now: float) -> None:
        self.pos += 1

    def line_closed(self, exc: IcsError) -> None:
        pass

    def line_resumed(self, now: float) -> None:
        pass

    def upcoming(self, limit: int) -> list[Upcoming]:
        return [
            (
                protocol.position_tx(sid, 7500),
                3,
                sid,
                protocol.position_reply_shape(protocol.position_reply_header(sid, BAUD)),
                k == len(self.ids) - 1,  # the cycle's last: news
            )
            for k, sid in enumerate(self.ids[self.pos : self.pos + limit], start=self.pos)
        ]

    def upcoming_done(self) -> None:
        pass

    def probing_silent(self) -> bool:
        return False  # (it never takes a servo out of its cycle)


class FaultyServos(Servos):
    """Servos whose replies are dropped, cut short, garbled or late, each kind at ``rate / 4``."""

    def __init__(self, ids: list[int], rate: float, seed: int, late: float = 0.030) -> None:
        super().__init__(ids, baudrate=BAUD, turnaround=0.0001)
        self.rng = random.Random(seed)
        self.rate = rate
        self.late = late

    def deliver(self, wire: Wire, tx: bytes, reply: bytes) -> None:
        roll = self.rng.random() / self.rate * 4 if self.rate else 4.0
        at = wire.now + protocol.wire_time(len(tx) + len(reply), self.baudrate) + self.turnaround
        if roll < 1:
            return  # dropped
        if roll < 2:
            wire.schedule(at, reply[:1])  # cut short
        elif roll < 3:
            wire.schedule(at, bytes([reply[0], reply[1] ^ 0x40, reply[2]]))  # a byte garbled
        elif roll < 4:
            wire.schedule(at + self.late, reply)  # late: past even the full 20 ms allowance
        else:
            wire.schedule(at, reply)


class DroppingServos(Servos):
    """Servos that drop each reply with probability ``rate`` (its echo still comes: a servo that missed the
    command, or a reply lost on the line); ``reads_only``: only their replies to reads (the stream's come)."""

    def __init__(self, ids: list[int], rate: float, seed: int, *, reads_only: bool = False) -> None:
        super().__init__(ids, baudrate=BAUD, turnaround=0.0001)
        self.rng = random.Random(seed)
        self.rate = rate
        self.reads_only = reads_only

    def deliver(self, wire: Wire, tx: bytes, reply: bytes) -> None:
        if (self.reads_only and tx[0] & 0xE0 != protocol.CMD_READ) or self.rng.random() >= self.rate:
            super().deliver(wire, tx, reply)


class Telemetry:
    """A program reading temperatures beside the stream, one read at a time round ``ids``: the next is asked in
    the program's next turn after each ends (a coroutine awaiting each read in a loop).  A servo whose read timed
    out is left alone for ``leave_alone`` seconds, as the control-loop page's telemetry does."""

    def __init__(
        self,
        wire: Wire,
        ids: list[int],
        priority: Priority = Priority.NORMAL,
        retries: int = 0,
        leave_alone: float = 0.0,
    ) -> None:
        self.wire = wire
        self.ids = ids
        self.priority = priority
        self.retries = retries
        self.leave_alone = leave_alone
        self.alone_until = dict.fromkeys(ids, 0.0)
        self.reads: list[Recorded] = []
        self._turn = 0

    def start(self, at: float) -> None:
        self.wire.at(at, self._next)

    def _next(self) -> None:
        now = self.wire.now
        waiting = [sid for sid in self.ids if self.alone_until[sid] <= now]
        if not waiting:
            self.wire.at(min(self.alone_until.values()), self._next)
            return
        while self.alone_until[sid := self.ids[self._turn % len(self.ids)]] > now:
            self._turn += 1
        self._turn += 1
        command = protocol.ReadParam(sid, protocol.Param.TEMPERATURE)
        read = _TelemetryRead(self, command, self.priority, self.retries, wire=self.wire)
        self.reads.append(read)
        self.wire.submit(read)

    def ended(self, read: Recorded) -> None:
        if isinstance(read.error, ReplyTimeout):
            assert read.command.servo_id is not None
            self.alone_until[read.command.servo_id] = self.wire.now + self.leave_alone
        self.wire.at(self.wire.now, self._next)


class _TelemetryRead(Recorded):
    __slots__ = ("telemetry",)

    def __init__(self, telemetry: Telemetry, command: protocol.Command[Any], *args: Any, **kwargs: Any) -> None:
        super().__init__(command, *args, **kwargs)
        self.telemetry = telemetry

    def resolve(self, value: Any) -> None:
        super().resolve(value)
        self.telemetry.ended(self)  # (in the program's next turn: the engine is not called back)

    def reject(self, error: IcsError) -> None:
        super().reject(error)
        self.telemetry.ended(self)


def run_with_telemetry(
    drop: float,
    seed: int,
    timing: BusTiming,
    seconds: float = 10.0,
    *,
    retries: int = 0,
    leave_alone: float = 0.0,
    reads_only: bool = False,
) -> tuple[PacedCycle, Telemetry, DroppingServos]:
    """The paced stream and :class:`Telemetry` beside it over ``seconds`` of simulated time, each reply
    (or each reply to a read: ``reads_only``) dropped with probability ``drop``."""
    engine = LineEngine(baudrate=BAUD, timing=timing)
    assert engine.connected(0.0) is None
    servos = DroppingServos(IDS, drop, seed, reads_only=reads_only)
    wire = Wire(engine, servos)
    source = PacedCycle(IDS, PERIOD)
    wire.emit(engine.attach_source(source, 0.0))
    telemetry = Telemetry(wire, IDS, retries=retries, leave_alone=leave_alone)
    telemetry.start(0.05)
    for second in range(1, math.ceil(seconds) + 1):  # (a second at a time: its steps are many)
        wire.run_until(min(second, seconds))
    return source, telemetry, servos


def run(
    rate: float,
    seed: int,
    ids: list[int] = IDS,
    present: list[int] = IDS,
    seconds: float = 10.0,
    timing: BusTiming | None = None,
) -> PacedCycle:
    """The paced stream over ``seconds`` of simulated time; default timing: a 20 ms adapter allowance."""
    engine = LineEngine(baudrate=BAUD, timing=timing or BusTiming())
    assert engine.connected(0.0) is None
    servos = FaultyServos(present, rate, seed)
    wire = Wire(engine, servos)
    source = PacedCycle(ids, PERIOD)
    wire.emit(engine.attach_source(source, 0.0))
    wire.run_until(seconds)
    return source


def intervals(source: PacedCycle) -> list[float]:
    return [b - a for a, b in zip(source.starts, source.starts[1:], strict=False)]
