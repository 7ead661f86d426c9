"""Current and temperature reads for the live table, fitted between a stream's position cycles.

They follow the stream (``Frame.unanswered``): an ID that did not answer its
latest cycle, or that the stream has taken out of its cycle (it stopped
answering), is not read, since every read of a dead ID costs a full reply
timeout and would slow every cycle (an ID where no servo is would cost the
first cycles one a read until the stream marks it offline); the stream
probes it, and telemetry resumes when it answers.  An ID whose telemetry reads alone
keep failing is read only once per ``probe_interval`` until one answers, and shows none meanwhile (the rule of
``LiveReadings.read_failed``).
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable, Sequence

from .. import protocol
from ..bus import Bus, Priority
from ..errors import PortLost, ReplyError
from ..frames import Frame, LiveReadings
from ..protocol import Param


class Telemetry:
    """Current and temperature reads, a few servos per cycle, queued between position transactions."""

    def __init__(
        self,
        bus: Bus,
        ids: Sequence[int],
        per_cycle: int,
        *,
        probe_interval: float = 0.5,
        fail_limit: int = 3,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.bus = bus
        self.ids = list(ids)
        self.per_cycle = per_cycle
        self.probe_interval = probe_interval
        self.fail_limit = fail_limit
        self.clock = clock
        # (kept while each is the servo's own now: see LiveReadings)
        self.current: LiveReadings[int] = LiveReadings()
        self.temperature: LiveReadings[int] = LiveReadings()
        self.errors: dict[int, int] = dict.fromkeys(self.ids, 0)
        self._fail_run: dict[int, int] = dict.fromkeys(self.ids, 0)
        self._next_probe: dict[int, float] = dict.fromkeys(self.ids, 0.0)
        self._next = 0
        self._reads: set[asyncio.Future[int]] = set()  # outstanding (cancelled by stop)
        self._stopped = False

    def after_frame(self, frame: Frame) -> None:
        """Drop the readings of the servos ``frame`` has offline (see :class:`LiveReadings`), and queue the next
        round of reads, skipping the IDs the frame has unanswered."""
        self.current.follow(frame)
        self.temperature.follow(frame)
        unanswered = frame.unanswered
        # At most one round outstanding: telemetry must never starve the stream.
        if self._reads or self._stopped or not self.per_cycle or not self.ids:
            return
        now = self.clock()
        chosen: list[int] = []
        for _ in range(len(self.ids)):
            if len(chosen) >= self.per_cycle:
                break
            sid = self.ids[self._next % len(self.ids)]
            self._next += 1
            if sid in unanswered:
                continue
            if self._fail_run[sid] >= self.fail_limit:
                if now < self._next_probe[sid]:
                    continue
                self._next_probe[sid] = now + self.probe_interval
            chosen.append(sid)
        for sid in chosen:
            for param, store in ((Param.CURRENT, self.current), (Param.TEMPERATURE, self.temperature)):
                try:
                    handle = self.bus.submit(protocol.ReadParam(sid, param), priority=Priority.LOW)
                except PortLost:
                    # Lost since the frame came (reconnecting: a request fails at once): the round is skipped, the
                    # stream's frames stop until the port is back, and the rounds go on from the next one then.
                    return
                fut = asyncio.ensure_future(handle)
                self._reads.add(fut)
                fut.add_done_callback(self._done_callback(sid, store))

    def forget(self) -> None:
        """Drop the readings so far (the port lost: they are no longer the servos' now); read again from the next
        round on."""
        self.current.forget()
        self.temperature.forget()

    def stop(self) -> None:
        """No more reads; those still queued are withdrawn (one on the wire finishes there, its value dropped).
        The stream's last cycles, a free going out as a command ends, must not wait behind them: a read of a
        servo that does not answer costs its whole allowance, and its guard read as much again."""
        self._stopped = True
        for read in list(self._reads):
            read.cancel()

    def _done_callback(self, sid: int, store: LiveReadings[int]) -> Callable[[asyncio.Future[int]], None]:
        def done(fut: asyncio.Future[int]) -> None:
            self._reads.discard(fut)
            if fut.cancelled():
                return
            exc = fut.exception()
            if exc is None:
                store[sid] = fut.result()
                self._fail_run[sid] = 0
            elif isinstance(exc, ReplyError):
                self.errors[sid] = self.errors.get(sid, 0) + 1
                self._fail_run[sid] += 1
                store.read_failed(sid)  # (its reading goes at the second in a row: see LiveReadings)

        return done
