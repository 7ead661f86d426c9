"""A paced stream on a faulty line in simulated time: the engine, a stream-like source and servos, no clock.

Twelve servos at 100 Hz on a 1.25 Mbit/s line (the control loop the library
promises), replies dropped, cut short, garbled or late at a chosen rate.  Used
by tests/test_engine_paced_faults.py and benchmarks/bench_control_loop.py.
"""

from __future__ import annotations

import math
import random

from ics35_async import protocol
from ics35_async.engine import BusTiming, LineEngine
from ics35_async.engine.source import Upcoming
from ics35_async.errors import IcsError, ReplyError

from .engine_support import Servos, Wire

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
                if now - due > self.period:
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

    def fail(self, exc: ReplyError, now: float) -> None:
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
