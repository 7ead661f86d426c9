"""What streams publish: a line's frame, a group's merged frame, and a stream's statistics."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Generic, NoReturn, Self, TypeVar

from . import units
from .errors import BusClosed

F = TypeVar("F")


class FrameIterator(Generic[F]):
    """``async for frame in stream``: every frame :meth:`next_frame` returns, until the stream closes.

    Closing ends the iteration; a lost port (``PortLost``) is raised from it.
    """

    async def next_frame(self) -> F:
        """The next frame (each stream says which); raises ``BusClosed`` once the stream is closed."""
        raise NotImplementedError

    # What a program that wrote `with` where `async with` goes is told (each stream says how it is used).
    _used_with = "a stream runs in `async with ...`"
    # How a stream like this one is made, for a program starting it again (each stream says its own).
    _made_with = "the call that made it"

    def _ran_once(self) -> BusClosed:
        """What a program starting this stream again after its ``async with`` block is told: that a stream runs
        once, and how to make another (a program in phases took "stream closed" for its bus or robot gone)."""
        made = f"make a new one as this one was made ({self._made_with})"
        return BusClosed(f"stream closed: a stream runs once; for another run, {made}")

    if not TYPE_CHECKING:  # (at run time only: a type checker says `with` is wrong itself, and suggests __aenter__)

        def __enter__(self) -> NoReturn:
            raise TypeError(self._used_with)

        def __exit__(self, *exc: object) -> None:
            return None

        def __iter__(self) -> NoReturn:  # (`for`, as the blocking API's streams are iterated, in async code)
            raise TypeError(
                "a stream's frames come with `async for frame in stream:` (or `await stream.next_frame()`); in code"
                " without an event loop, a bus of `ics35_async.blocking` gives a stream for `for`"
            )

    def __aiter__(self) -> Self:
        return self

    async def __anext__(self) -> F:
        try:
            return await self.next_frame()
        except BusClosed:
            raise StopAsyncIteration from None


@dataclass(frozen=True)
class Frame:
    """One completed cycle.

    ``positions`` (0..16383) and ``timestamps`` (``time.monotonic()`` of each reply) hold the
    IDs that answered this cycle; ``failed`` the IDs in the cycle that did not (their
    transaction failed, or was held back after a failure while its late reply could still come, or its
    guard read got nothing back on a line that had answered its previous command with nothing either:
    those two, sent nothing this cycle, are in ``not_sent`` too);
    ``offline`` the IDs currently out of the cycle (an ID whose failure this cycle took it out is in
    both, in this frame).  ``skipped`` counts the
    frames this consumer missed since its previous one.

    Trouble the stream itself went through shows here too: ``missed_slots``,
    how many of a paced stream's slots passed with no cycle before this one
    (a stalled program or line, a pause, a lost port's outage); ``resumed``, True on the first frame
    after the line came back from a lost port; ``held``, the IDs that get no
    command since then, or since they came back from offline (an ID back this
    cycle is in neither ``positions`` nor ``failed``), until the program sets
    their target again (see ``Stream(on_resume=...)``).
    """

    cycle: int
    positions: dict[int, int]
    timestamps: dict[int, float]
    failed: frozenset[int]
    offline: frozenset[int]
    started: float
    finished: float
    skipped: int = 0
    missed_slots: int = 0
    resumed: bool = False
    held: frozenset[int] = frozenset()
    not_sent: frozenset[int] = frozenset()

    @property
    def unanswered(self) -> frozenset[int]:
        """The IDs that did not answer this cycle or are out of it (``failed | offline``): a read sent to one
        now would most likely wait its whole reply allowance (and its retries), so telemetry beside a stream
        (``ics35 monitor``, the configurator's Live page) leaves them to the stream until they answer it."""
        return self.failed | self.offline

    def degrees(self) -> dict[int, float]:
        """The positions of this frame in degrees, by ID (7500 counts is 0 degrees)."""
        return {i: units.position_to_degrees(p) for i, p in self.positions.items()}

    def to_dict(self) -> dict[str, Any]:
        """The frame as plain JSON values (ID keys as strings, sets as sorted lists), for a log or a web page."""
        return {
            "cycle": self.cycle,
            "positions": {str(i): p for i, p in self.positions.items()},
            "degrees": {str(i): round(d, 2) for i, d in self.degrees().items()},
            "timestamps": {str(i): t for i, t in self.timestamps.items()},
            "failed": sorted(self.failed),
            "offline": sorted(self.offline),
            "started": self.started,
            "finished": self.finished,
            "skipped": self.skipped,
            "missed_slots": self.missed_slots,
            "resumed": self.resumed,
            "held": sorted(self.held),
            "not_sent": sorted(self.not_sent),
        }


V = TypeVar("V")


STALE_AFTER_FAILED_READS = 2
"""The rule of every live view for a reading that is no longer read: a servo's reading (its temperature, its
current) is shown until this many reads of it in a row have failed, and "-" from then until one answers.

Counted in failed reads, not in seconds: each view reads its servos at its own pace (``ics35 monitor`` a few
servos a cycle, the configurator's Live page one servo every 0.1 s, a robot's safety watch a few joints a cycle),
so a round of 32 servos at 115200 baud can take seconds, and a reading a round old is that view's newest; two failed
reads are two rounds in which the servo was asked and did not answer, however long that view's rounds are.  Not
at the first: an ICS reply carries no checksum, and one reply lost or garbled on a noisy line says nothing of the
servo (a temperature blinking to "-" at each would teach its reader to overlook the "-").  At the second in a row
the reads are failing (a servo that answers its position commands but not these reads, a loose data line that
drops some replies), and what was read before them is no longer the servo's now: a motor heats by tens of degrees
in a minute of stalling.  So a reading shown is the servo's newest answer, followed by one failed read at most.
A servo the stream has taken offline, or on a lost port, shows none at once
(:meth:`LiveReadings.follow`, :meth:`LiveReadings.forget`)."""


class LiveReadings(dict[int, V]):
    """The newest reading of each of a stream's servos taken between its cycles (a current, a temperature), by ID,
    kept only while it is the servo's own now: :meth:`follow` drops those of the servos a frame has offline,
    :meth:`forget` those of every servo (the port lost), and :meth:`read_failed` one whose reads have failed
    :data:`STALE_AFTER_FAILED_READS` times in a row (its servo may answer its position commands still, but not
    these reads: what was read before is not what the servo is now).  A servo back from any of them has none until
    it is read anew: it may have restarted, hotter or cooler.  (A robot's joints follow the same rules:
    ``Robot.telemetry``.)  A view of the stream shows "-" for a servo with none: ``ics35 monitor``'s and ``demo``'s
    tables and JSON lines, the configurator's Live plots and Line page.

    A reader stores what it read (``readings[servo_id] = value``, which also counts the servo's failed reads from
    zero again) and tells each read that failed (:meth:`read_failed`); a view shows what is in it.  A program's own
    telemetry beside a stream follows the same rules so: ``temperatures[i] = await bus.servo(i).read_temperature()``,
    ``temperatures.read_failed(i)`` on a ``ReplyError``, ``temperatures.follow(frame)`` at each frame.  (Why two
    failed reads, and why reads and not seconds: ``ics35_async.frames.STALE_AFTER_FAILED_READS``.)"""

    def __init__(self) -> None:
        super().__init__()
        self._failed: dict[int, int] = {}  # failed reads in a row since each servo's newest reading

    def __setitem__(self, servo_id: int, value: V) -> None:
        super().__setitem__(servo_id, value)
        self._failed.pop(servo_id, None)

    def read_failed(self, servo_id: int) -> None:
        """A read of ``servo_id`` failed (no reply, a garbled one): at the :data:`STALE_AFTER_FAILED_READS`-th in a
        row, its reading is dropped until one answers."""
        failed = self._failed.get(servo_id, 0) + 1
        self._failed[servo_id] = failed
        if failed >= STALE_AFTER_FAILED_READS:
            self.pop(servo_id, None)

    def follow(self, frame: Frame) -> None:
        """Drop the readings of the servos ``frame`` has offline."""
        for servo_id in frame.offline:
            self.pop(servo_id, None)
            self._failed.pop(servo_id, None)

    def forget(self) -> None:
        """Drop every reading (the port lost: none is a servo's now)."""
        self.clear()
        self._failed.clear()


@dataclass
class StreamStats:
    """What a stream has done so far (:attr:`Stream.stats <ics35_async.Stream.stats>`); times in seconds.

    - ``cycles``: cycles started; ``rate_hz``: cycles per second, from the first cycle's start to the newest
      frame's cycle start (0 until two cycles have run).
    - ``cycle_time_p50`` .. ``cycle_time_max``: how long a cycle took, start to frame, over the
      last ``history`` cycles.
    - ``jitter``: standard deviation of the interval between cycle starts.
    - ``overruns``: cycles whose own work ran past the next slot (a paced stream).
    - ``missed_slots``: slots that passed with no cycle at all (the stream re-anchors rather than
      bursting to catch up), a lost port's outage included.
    - ``frames_dropped``: frames no consumer looked at before the next one replaced them.
    - ``failures``: failed transactions per ID; ``offline``: the IDs out of the cycle now.
    - ``probes``: parameter reads that probed an offline ID with a position target (answered or not); on the
      wire they look like the bus's guard reads (``BusStats.guards``).
    """

    cycles: int = 0
    rate_hz: float = 0.0
    cycle_time_p50: float = 0.0
    cycle_time_p90: float = 0.0
    cycle_time_p99: float = 0.0
    cycle_time_max: float = 0.0
    jitter: float = 0.0
    overruns: int = 0
    frames_dropped: int = 0
    failures: dict[int, int] = field(default_factory=dict)
    offline: frozenset[int] = frozenset()
    missed_slots: int = 0
    probes: int = 0


def percentile(sorted_values: Sequence[float], p: float) -> float:
    """The ``p``-th percentile (0..100) by the nearest-rank rule: a value measured, never one interpolated
    between two; 0.0 for no values."""
    if not sorted_values:
        return 0.0
    k = min(len(sorted_values) - 1, max(0, math.ceil(len(sorted_values) * p / 100) - 1))
    return sorted_values[k]


@dataclass(frozen=True)
class GroupFrame:
    """Merged frames of a :class:`~ics35_async.group.GroupStream`, keyed by ``(line, id)``."""

    cycle: int
    positions: dict[tuple[str, int], int]
    timestamps: dict[tuple[str, int], float]
    failed: frozenset[tuple[str, int]]
    offline: frozenset[tuple[str, int]]
    line_cycles: dict[str, int]
    skipped: int = 0
    line_started: dict[str, float] = field(default_factory=dict)
    """When each line's newest cycle began (``time.monotonic()``): a target set before that went out in it."""
    missed_slots: int = 0
    """Whole slots the paced lines missed since the previous frame (see :attr:`Frame.missed_slots`), together."""
    resumed: frozenset[str] = frozenset()
    """The lines whose lost port came back since the previous frame (see :attr:`Frame.resumed`): their servos may
    have restarted elsewhere; decide before moving them."""
    held: frozenset[tuple[str, int]] = frozenset()
    """The servos held after their line came back (or they came back from offline), sent nothing until their
    target is set again."""
    not_sent: frozenset[tuple[str, int]] = frozenset()
    """The servos of ``failed`` sent nothing in their line's cycle: held back after a failure while its late reply
    could still come, or failed by their guard read (see :attr:`Frame.not_sent`)."""

    def degrees(self) -> dict[tuple[str, int], float]:
        """The positions of this frame in degrees, by ``(line, id)`` (7500 counts is 0 degrees)."""
        return {key: units.position_to_degrees(p) for key, p in self.positions.items()}

    def to_dict(self) -> dict[str, Any]:
        """The frame as plain JSON values, for a log or a web page: what is keyed by ``(line, id)`` nested by
        line, then ID (as a string), every line present; sets as sorted lists."""
        lines = sorted(self.line_cycles)

        def by_line(values: Mapping[tuple[str, int], Any]) -> dict[str, dict[str, Any]]:
            nested: dict[str, dict[str, Any]] = {line: {} for line in lines}
            for (line, i), value in sorted(values.items()):
                nested.setdefault(line, {})[str(i)] = value
            return nested

        def listed(keys: frozenset[tuple[str, int]]) -> dict[str, list[int]]:
            return {line: sorted(i for ln, i in keys if ln == line) for line in lines}

        return {
            "cycle": self.cycle,
            "line_cycles": dict(self.line_cycles),
            "positions": by_line(self.positions),
            "degrees": by_line({key: round(d, 2) for key, d in self.degrees().items()}),
            "timestamps": by_line(self.timestamps),
            "failed": listed(self.failed),
            "offline": listed(self.offline),
            "line_started": dict(self.line_started),
            "skipped": self.skipped,
            "missed_slots": self.missed_slots,
            "resumed": sorted(self.resumed),
            "held": listed(self.held),
            "not_sent": listed(self.not_sent),
        }
