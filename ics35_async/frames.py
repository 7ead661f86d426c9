"""What streams publish: a line's frame, a group's merged frame, and a stream's statistics."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

from . import units


@dataclass(frozen=True)
class Frame:
    """One completed cycle.

    ``positions`` and ``timestamps`` (``time.monotonic()`` of each reply) hold the
    IDs that answered this cycle; ``failed`` the IDs tried that did not;
    ``offline`` the IDs currently out of the cycle.  ``skipped`` counts the
    frames this consumer missed since its previous one.
    """

    cycle: int
    positions: dict[int, int]
    timestamps: dict[int, float]
    failed: frozenset[int]
    offline: frozenset[int]
    started: float
    finished: float
    skipped: int = 0

    def degrees(self) -> dict[int, float]:
        """The positions of this frame in degrees, by ID (7500 counts is 0 degrees)."""
        return {i: units.position_to_degrees(p) for i, p in self.positions.items()}


@dataclass
class StreamStats:
    cycles: int = 0
    rate_hz: float = 0.0
    cycle_time_p50: float = 0.0
    cycle_time_p90: float = 0.0
    cycle_time_p99: float = 0.0
    cycle_time_max: float = 0.0
    jitter: float = 0.0  # standard deviation of the interval between cycle starts, seconds
    overruns: int = 0
    frames_dropped: int = 0  # frames no consumer looked at before the next one replaced them
    failures: dict[int, int] = field(default_factory=dict)
    offline: frozenset[int] = frozenset()


def percentile(sorted_values: Sequence[float], p: float) -> float:
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
