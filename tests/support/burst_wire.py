"""The burst path on the simulated wire: the compiled executor's contract in simulated time.

:class:`SimExecutor` does on a :class:`~.engine_support.Wire` what ``ics35_async.drivers._burst`` does on
a real port (write each planned command, take the bytes that arrive until its expected count or
its deadline, stop at a late, short, overlong or wrongly echoed transaction, or one answered out of
its planned shape, or at a boundary once woken); :class:`BurstWire` is the Wire with the library's
own :class:`BurstRunner` between the engine and the wire, so the same scenario can be run with
and without bursts and compared.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Iterator

from ics35_async.drivers.burst import DONE, LATE, MISMATCH, OVERRUN, SHAPE, WOKEN, BurstRunner, Record, Result
from ics35_async.engine import FlushInput, LineEngine, Output, Request
from ics35_async.engine.machine import PlannedTransaction

from .engine_support import Answer, Wire


class SimExecutor:
    """``ics35_async.drivers._burst.Burst``'s contract on a simulated wire (run by :class:`BurstWire`)."""

    done_fd = -1

    def __init__(self, wire: Wire) -> None:
        self.wire = wire
        self.woken = False
        self.plan: tuple[float, list[PlannedTransaction]] | None = None
        self._result: Result | None = None
        self._steps: Iterator[None] = iter(())
        self.records: list[Record] = []  # of the running plan, as each transaction completes
        self.ran = 0  # transactions of the running plan written
        self.notify_at = -1
        self.runs = 0
        self.notices = 0  # notify points reached (the runner then fed ahead)
        self.plan_lengths: list[int] = []  # of every plan started
        self.stops: Counter[int] = Counter()  # why each run stopped (DONE, SHAPE, ...)

    def start(self, deadline: float, plan: list[PlannedTransaction]) -> None:
        self.woken = False
        self.plan_lengths.append(len(plan))
        self.plan = (deadline, plan)
        self._result = None
        self.records = []
        self.ran = 0
        self.notify_at = -1
        self._steps = self._run()

    def notify(self, index: int) -> None:
        self.notify_at = index

    def wake(self) -> None:
        self.woken = True

    def result(self, start: int = 0) -> Result | None:
        result, self._result = self._result, None
        return None if result is None else (result[0], result[1], result[2][start:])

    def completed(self, start: int) -> list[Record]:
        return self.records[start : self.ran - 1]

    def run(self) -> bool:
        """Run the plan on until a notify point or its end: True once it has ended."""
        for _ in self._steps:
            return False
        return True

    def _run(self) -> Iterator[None]:
        assert self.plan is not None
        wire = self.wire
        deadline, plan = self.plan
        self.runs += 1
        records = self.records
        t_start = 0.0
        status = DONE
        for i, (tx, expect, echo, allowance, shape) in enumerate(plan):
            if i:
                if self.woken:
                    status = WOKEN
                    break
                deadline = t_start + allowance
            Wire.emit(wire, tx)  # the servos hear it (the base class's write: no burst inside a burst)
            self.ran = i + 1
            if 0 <= self.notify_at <= i:
                self.notify_at = -1
                self.notices += 1
                yield  # the runner feeds what is done while this one's reply comes
            buf = bytearray()
            first = last = 0.0
            stop = DONE
            while len(buf) < expect:
                got = wire.next_arrival(min(deadline, wire.end))
                if got is None:  # late (or the simulated run ends here: fed as far as it came)
                    stop = LATE
                    break
                data = got[0]
                before = len(buf)
                if not buf:
                    first = wire.now
                last = wire.now
                buf += data
                end = min(echo, len(buf))
                if before < end and buf[before:end] != tx[before:end]:
                    stop = MISMATCH
                    break
                if len(buf) > expect:
                    stop = OVERRUN
                    break
            if stop == DONE and shape:
                n = len(shape) // 2
                reply, want, masks = buf[echo:], shape[:n], shape[n:]
                if any(b & m != w for b, m, w in zip(reply, masks, want, strict=True)):
                    stop = SHAPE
            records.append((bytes(buf), first, last))
            if stop != DONE:
                status = stop
                break
            t_start = last
        self.stops[status] += 1
        self._result = (status, 0, list(records))


class BurstWire(Wire):
    """A :class:`Wire` whose driver takes the burst path: every transaction of the engine's source that
    a burst can run, the simulated executor runs and :class:`BurstRunner` feeds back."""

    def __init__(self, engine: LineEngine, answer: Answer | None = None) -> None:
        super().__init__(engine, answer)
        self.executor = SimExecutor(self)
        self.requested_at = -math.inf  # as the driver notes it (see DriverCore.submit)
        self.runner = BurstRunner(engine, self.executor, None, last_request=lambda: self.requested_at)

    def emit(self, out: Output) -> bytes | None:
        if isinstance(out, FlushInput):  # the driver drops stale input first, then runs the burst
            self.flushes += 1
            out = out.then
        runner = self.runner
        while out is not None and self.now < self.end and not runner.running and runner.start(self.now):
            done = False
            while not done:
                self.executor.run()  # to a notify point (the runner feeds ahead) or the plan's end
                done, out = runner.finish(lambda: self.now)
        return super().emit(out)

    def submit(self, request: Request) -> bytes | None:
        self.requested_at = self.now
        if self.runner.submit(request, self.now):
            return None  # queued where the burst stops
        return super().submit(request)
