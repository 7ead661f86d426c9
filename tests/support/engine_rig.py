"""A :class:`LineEngine` and a simulated line on one virtual clock: plain calls, no event loop, no wall time.

The simulator's wire model (:class:`~ics35_async.sim.model.LineModel`, real-time
mode so that its faults deliver at wire times, e.g. a held tail
``tail_delay`` late) says when each chunk reaches the host; the rig feeds the
chunks to the engine at exactly those times and calls :meth:`LineEngine.tick`
at its deadlines, as a driver would (input due before a deadline first).  Time
is a number the rig advances, so a test can assert on deadlines and lateness
exactly, whatever the machine's load.
"""

from __future__ import annotations

import heapq
from typing import Any

from ics35_async.engine import BusTiming, FlushInput, LineEngine, Request
from ics35_async.protocol import Command
from ics35_async.sim.model import LineModel

INF = float("inf")


class EngineRig:
    """Drive ``engine`` against ``line``; ``now`` is the shared clock (line clock = engine clock)."""

    def __init__(self, line: LineModel, *, echo: bool = True, timing: BusTiming | None = None) -> None:
        if not line.realtime:
            raise ValueError("the rig needs the line's real-time wire model (LineModel(realtime=True))")
        self.line = line
        self.engine = LineEngine(baudrate=line.baudrate, echo=echo, timing=timing)
        self.now = 0.0
        self._pending: list[tuple[float, int, bytes]] = []
        self._order = 0
        self.writes: list[tuple[float, bytes]] = []  # (time, bytes) of every write the engine made
        self.flushed = 0  # bytes dropped by the engine's FlushInput answers
        self._write(self.engine.connected(self.now))

    def _write(self, out: bytes | None) -> None:
        if out is None:
            return
        self.writes.append((self.now, out))
        for when, chunk in self.line.feed(out, self.now):
            self._order += 1
            heapq.heappush(self._pending, (max(when, self.now), self._order, chunk))

    def submit(self, command: Command[Any], retries: int = 0) -> Request:
        request = Request(command, retries=retries)
        self._write(self.engine.submit(request, self.now))
        return request

    def step(self) -> bool:
        """Deliver the next chunk or fire the next deadline, whichever comes first; False if neither is due."""
        engine = self.engine
        pending = self._pending
        if pending and pending[0][0] <= engine.deadline:
            when, _, chunk = heapq.heappop(pending)
            self.now = max(self.now, when)
            self._write(engine.receive(chunk, self.now))
            return True
        if engine.deadline == INF:
            return False
        self.now = max(self.now, engine.deadline)
        out = engine.tick(self.now)
        if isinstance(out, FlushInput):
            # The OS input buffer holds only what has already arrived: chunks due by now.
            out = out.then
            while pending and pending[0][0] <= self.now:
                self.flushed += len(heapq.heappop(pending)[2])
        self._write(out)
        return True

    def finish(self, request: Request, limit: int = 100_000) -> Request:
        """Run until ``request`` has an outcome."""
        for _ in range(limit):
            if request.state != "queued":
                return request
            if not self.step():
                break
        raise AssertionError(f"{request!r} never finished (engine {self.engine.state.value})")

    def idle(self, seconds: float) -> None:
        """Let ``seconds`` pass, delivering whatever comes meanwhile."""
        until = self.now + seconds
        while True:
            next_chunk = self._pending[0][0] if self._pending else INF
            if min(next_chunk, self.engine.deadline) > until:
                break
            self.step()
        self.now = until
