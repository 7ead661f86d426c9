"""Position streaming: one position transaction per servo per cycle, at the wire's pace.

ICS 3.5 has no broadcast, so a cycle over N servos is N position
transactions, each returning that servo's measured position.  A
:class:`Stream` plugs into its bus as the *background source*: the I/O
callback that completes one servo's reply writes the next servo's command,
so the hot path has no task switch and no future per servo.

Sharing policy: requests from other coroutines (any :class:`Servo` call) go
before the stream's next position transaction, so such a request waits for
at most the transaction already on the wire plus the requests queued ahead
of it, and the stream loses only the line time those requests use.  To keep
the stream alive under a flood, at most ``Bus.max_requests_between``
(default 16) requests run between two position transactions.

Dead IDs: an ID that fails ``offline_after`` cycles in a row is taken out of
the cycle and probed every ``probe_interval`` seconds; it rejoins as soon as
a probe answers.  Frames list the offline IDs.
"""

from __future__ import annotations

import contextlib
import dataclasses
import itertools
import math
import statistics
from collections import deque
from collections.abc import AsyncIterator, Iterable
from types import TracebackType

import anyio

from . import protocol, units
from .errors import BusClosed, IcsError, InvalidArgument, ReplyError
from .frames import Frame, StreamStats, percentile
from .line import Line
from .protocol.hot_path import position_from_reply
from .stream_targets import WATCH as WATCH  # re-exported: Stream.target() returns it
from .stream_targets import StreamTargets

INF = math.inf


# Options of Stream beyond its IDs and rate (what Bus.stream passes through).
STREAM_OPTIONS = frozenset({"offline_after", "probe_interval", "free_on_close", "history", "watch"})


class Stream(StreamTargets):
    """Streams position targets to ``ids`` and publishes a :class:`Frame` per cycle.

    Create with :meth:`Bus.stream` and use as ``async with``.  Every ID
    starts free (torque off, position still read back) until it is given a
    target: the safe start-up the reference recommends.  IDs in ``watch``
    (ICS 3.6 servos only) start *watched* instead: each cycle reads their
    position with ICS 3.6's position read, which neither moves nor frees
    them, until they are given a target (:meth:`watch` returns an ID to it).
    """

    def __init__(
        self,
        bus: Line,
        ids: Iterable[int],
        *,
        rate_hz: float | None = None,
        offline_after: int = 3,
        probe_interval: float = 0.5,
        free_on_close: bool = False,
        history: int = 2000,
        watch: Iterable[int] = (),
    ) -> None:
        id_list = units.check_ids("ids", ids)
        if not id_list:
            raise InvalidArgument("a stream needs at least one ID")
        if len(set(id_list)) != len(id_list):
            raise InvalidArgument(f"duplicate IDs in {id_list}")
        if rate_hz is not None and (
            not isinstance(rate_hz, (int, float)) or not math.isfinite(rate_hz) or not 0 < rate_hz <= 10000
        ):
            raise InvalidArgument(f"rate_hz must be None or a number in (0, 10000], got {rate_hz!r}")
        units.check_int("offline_after", offline_after, 1, 1_000_000)
        units.check_seconds("probe_interval", probe_interval, 0.001, 3600)
        units.check_int("history", history, 1, 10_000_000)
        units.check_bool("free_on_close", free_on_close)
        self.bus = bus
        self.ids: tuple[int, ...] = tuple(id_list)
        self.rate_hz = rate_hz
        self.offline_after = offline_after
        self.probe_interval = float(probe_interval)
        self.free_on_close = free_on_close
        n = len(id_list)
        self._index = {sid: k for k, sid in enumerate(id_list)}
        self._targets = [protocol.FREE] * n
        self._jobs = [(protocol.position_tx(sid, protocol.FREE), 3, sid) for sid in id_list]
        self._readers: list[protocol.ReadPosition | None] = [None] * n
        self._headers = [protocol.position_reply_header(sid, bus.baudrate) for sid in id_list]
        self._positions = [-1] * n
        self._stamps = [0.0] * n
        self._answered = [False] * n
        self._fail_run = [0] * n
        self._failures = [0] * n
        self._offline = [False] * n
        self._next_probe = [0.0] * n
        # The cycle in progress.
        self._order: list[int] = []
        self._pos = 0
        self._cur = -1
        self._cycle = 0
        self._cycle_start = 0.0
        self._t0 = 0.0
        self.wake_at = INF  # when a cycle waiting for its fixed-rate slot (or a probe) is due
        self._running = False
        self._closed = False
        self._end_error: IcsError = BusClosed("stream closed")
        # Publishing.
        self._latest: Frame | None = None
        self._new_frame: anyio.Event | None = None  # made by the first waiter, set by the next frame
        self._consumed_cycle = 0
        self._dropped = 0
        self._seen_latest = True
        # Statistics.
        self._cycle_times: deque[float] = deque(maxlen=history)
        self._starts: deque[float] = deque(maxlen=history)
        self._overruns = 0
        self._slot_checked = True
        self._first_start = 0.0
        self.watch(units.check_ids("watch", watch))

    @property
    def offline(self) -> frozenset[int]:
        return frozenset(sid for sid, off in zip(self.ids, self._offline, strict=True) if off)

    # ------------------------------------------------------------------ BackgroundSource

    def next_transaction(self, now: float) -> tuple[bytes, int, int] | None:
        if not self._running:
            return None
        if self._pos >= len(self._order) and not self._start_cycle(now):
            return None
        k = self._order[self._pos]
        self._cur = k
        return self._jobs[k]

    def complete(self, buf: bytearray, offset: int, now: float) -> ReplyError | None:
        k = self._cur
        if k < 0:
            return None  # not ours: the bus routes only our own, but stay safe
        reader = self._readers[k]
        if reader is not None:  # a watched ID: ICS 3.6's position read
            try:
                position = reader.parse(bytes(buf[offset:]))
            except ReplyError as exc:
                return exc
        else:
            position = position_from_reply(buf, offset, self._headers[k])
        if position < 0:  # let the codec name what is wrong
            try:
                command = protocol.Position(self.ids[k], self._targets[k], baudrate=self.bus.baudrate)
                position = command.parse(bytes(buf[offset:]))
            except ReplyError as exc:
                return exc  # the engine counts it, then calls fail
        self._positions[k] = position
        self._stamps[k] = now
        self._answered[k] = True
        if self._fail_run[k]:  # only fail() marks an ID offline, always after a failure
            self._fail_run[k] = 0
            self._offline[k] = False
        self._pos = pos = self._pos + 1  # _advance, inline: this runs once per transaction
        if pos >= len(self._order):
            self._publish(now)
        return None

    def fail(self, exc: ReplyError, now: float) -> None:
        k = self._cur
        if k < 0:
            return
        self._failures[k] += 1
        self._fail_run[k] += 1
        if self._fail_run[k] >= self.offline_after and not self._offline[k]:
            self._offline[k] = True
        if self._offline[k]:
            self._next_probe[k] = now + self.probe_interval
        self._advance(now)

    def _advance(self, now: float) -> None:
        self._pos += 1
        if self._pos >= len(self._order):
            self._publish(now)

    def line_closed(self, exc: IcsError) -> None:
        self._end_error = exc
        self._stop(detach=False)  # the engine has detached us already (and may hold its driver's lock)

    # ------------------------------------------------------------------ cycles

    def _start_cycle(self, now: float) -> bool:
        """Begin the next cycle if it is due; False (and ``wake_at`` set) while waiting for a slot."""
        self.wake_at = INF
        if self.rate_hz is not None and self._cycle:
            due = self._t0 + self._cycle / self.rate_hz  # start of cycle number self._cycle + 1
            if not self._slot_checked:
                # An overrun is a cycle whose own work ran past the next slot, not a
                # timer that fired late (the loop's timers have ~1 ms resolution).
                self._slot_checked = True
                if now > due:
                    self._overruns += 1
            if now < due:
                self.wake_at = due
                return False
            if now - due > 1 / self.rate_hz:
                # A whole slot missed: re-anchor instead of bursting to catch up.
                self._t0 = now - self._cycle / self.rate_hz
        if not self._cycle:
            self._t0 = now
            self._first_start = now
        self._cycle += 1
        order = []
        for k in range(len(self.ids)):
            self._answered[k] = False
            if not self._offline[k] or now >= self._next_probe[k]:
                order.append(k)
        self._order = order
        self._pos = 0
        self._cycle_start = now
        self._starts.append(now)
        if not order:
            # Everything is offline: wait for the next probe instead of spinning.
            self._publish(now)
            self.wake_at = min(self._next_probe)
            return False
        return True

    def _publish(self, now: float) -> None:
        self._slot_checked = False
        ids = self.ids
        positions: dict[int, int] = {}
        stamps: dict[int, float] = {}
        failed = []
        for k in self._order:
            if self._answered[k]:
                positions[ids[k]] = self._positions[k]
                stamps[ids[k]] = self._stamps[k]
            else:
                failed.append(ids[k])
        self._order = []
        self._pos = 0
        self._cycle_times.append(now - self._cycle_start)
        if not self._seen_latest:
            self._dropped += 1
        self._seen_latest = False
        self._latest = Frame(
            cycle=self._cycle,
            positions=positions,
            timestamps=stamps,
            failed=frozenset(failed),
            offline=self.offline,
            started=self._cycle_start,
            finished=now,
        )
        self.bus.notify(self._wake_waiters)  # this may run in a driver's I/O thread

    def _wake_waiters(self) -> None:
        event, self._new_frame = self._new_frame, None
        if event is not None:
            event.set()

    # ------------------------------------------------------------------ consuming

    async def next_frame(self) -> Frame:
        """The newest frame not yet returned; waits for one if needed.

        A slow consumer never slows the bus: it gets the latest frame, with
        ``skipped`` telling how many it missed.  Once the stream is closed
        (or its bus closed or lost), it raises, even if a frame came meanwhile.
        """
        while self._closed or self._latest is None or self._latest.cycle <= self._consumed_cycle:
            if self._closed:
                raise self._end_error
            if self._new_frame is None:
                self._new_frame = anyio.Event()
            await self._new_frame.wait()
        frame = self._latest
        skipped = frame.cycle - self._consumed_cycle - 1 if self._consumed_cycle else 0
        self._consumed_cycle = frame.cycle
        self._seen_latest = True
        return dataclasses.replace(frame, skipped=skipped) if skipped else frame

    @property
    def latest(self) -> Frame | None:
        """The newest published frame (does not mark it consumed)."""
        return self._latest

    def __aiter__(self) -> AsyncIterator[Frame]:
        return self

    async def __anext__(self) -> Frame:
        try:
            return await self.next_frame()
        except BusClosed:
            # Closing ends the iteration; losing the port (PortLost) is raised.
            raise StopAsyncIteration from None

    @property
    def stats(self) -> StreamStats:
        times = sorted(self._cycle_times)
        starts = list(self._starts)
        intervals = [b - a for a, b in itertools.pairwise(starts)]
        elapsed = (self._latest.finished - self._first_start) if self._latest else 0.0
        return StreamStats(
            cycles=self._cycle,
            rate_hz=self._latest.cycle / elapsed if self._latest and elapsed > 0 else 0.0,
            cycle_time_p50=percentile(times, 50),
            cycle_time_p90=percentile(times, 90),
            cycle_time_p99=percentile(times, 99),
            cycle_time_max=times[-1] if times else 0.0,
            jitter=statistics.pstdev(intervals) if len(intervals) > 1 else 0.0,
            overruns=self._overruns,
            frames_dropped=self._dropped,
            failures={sid: n for sid, n in zip(self.ids, self._failures, strict=True) if n},
            offline=self.offline,
        )

    # ------------------------------------------------------------------ lifetime

    async def start(self) -> Stream:
        if self._closed:
            raise BusClosed("stream closed")
        if not self.bus.is_open:
            raise BusClosed("the bus is not open (use `async with open_bus(...) as bus`)")
        if not self._running:
            self._running = True
            try:
                self.bus.attach_source(self)
            except BaseException:
                self._running = False
                raise
        return self

    async def aclose(self) -> None:
        """Stop streaming; the bus stays usable.  With ``free_on_close`` every ID goes free."""
        if self._closed:
            return
        self._stop()
        if self.free_on_close and self.bus.is_open:
            async with anyio.create_task_group() as group:
                for i in self.ids:
                    group.start_soon(self._free_quietly, i)

    async def _free_quietly(self, servo_id: int) -> None:
        with contextlib.suppress(IcsError):
            await self.bus.request(protocol.Position(servo_id, protocol.FREE, baudrate=self.bus.baudrate))

    def _stop(self, *, detach: bool = True) -> None:
        self._running = False
        self._closed = True
        self._cur = -1
        self.wake_at = INF
        if detach:
            self.bus.detach_source(self)
        self.bus.notify(self._wake_waiters)

    async def __aenter__(self) -> Stream:
        return await self.start()

    async def __aexit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        await self.aclose()
