"""Motion profiles and trajectories in joint space: where every joint should be at time ``t``.

A segment moves each of its joints from a start to an end angle along a
profile's shape ``k(s)``, ``s = t / duration`` in 0..1, ``k(0) = 0`` and
``k(1) = 1``, never decreasing, so a joint moves monotonically within a
segment and never leaves the interval between its two ends:

* ``minjerk``: ``10 s^3 - 15 s^4 + 6 s^5``, minimum jerk: it starts and
  ends at rest with zero acceleration (what a human reach looks like);
* ``linear``: ``s``, constant speed (starts and stops abruptly);
* ``decel`` (internal, for a smooth stop): ``2 s - s^2``, from the speed a
  joint has down to rest, covering half the distance that speed would.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from ..errors import InvalidArgument

PROFILES = ("minjerk", "linear")
_ALL = (*PROFILES, "decel")


def check_profile(profile: object) -> str:
    if profile not in PROFILES:
        raise InvalidArgument(f"profile must be one of {', '.join(PROFILES)}, not {profile!r}")
    assert isinstance(profile, str)
    return profile


def shape(profile: str, s: float) -> float:
    """How far along (0..1) a segment with this profile is at fraction ``s`` of its time."""
    s = min(1.0, max(0.0, s))
    if profile == "minjerk":
        k = s * s * s * (10.0 + s * (-15.0 + 6.0 * s))
    elif profile == "linear":
        k = s
    elif profile == "decel":
        k = s * (2.0 - s)
    else:
        raise InvalidArgument(f"unknown profile {profile!r}")
    return min(1.0, max(0.0, k))


def slope(profile: str, s: float) -> float:
    """d shape / d s: the speed as a multiple of (distance / duration)."""
    if not 0.0 <= s < 1.0:
        return 0.0  # at rest before the start and after the end
    if profile == "minjerk":
        return 30.0 * s * s * (1.0 - s) * (1.0 - s)
    if profile == "linear":
        return 1.0
    return 2.0 - 2.0 * s


@dataclass(frozen=True)
class Segment:
    """Every joint of ``start`` goes to its angle in ``end`` between ``start_time`` and ``end_time``."""

    start_time: float
    end_time: float
    start: Mapping[str, float]
    end: Mapping[str, float]
    profile: str = "minjerk"

    def fraction(self, t: float) -> float:
        """How far through the segment time ``t`` is (0 at its start, 1 at its end or after)."""
        duration = self.end_time - self.start_time
        return 1.0 if duration <= 0 else (t - self.start_time) / duration

    def pose_at(self, t: float) -> dict[str, float]:
        """The interpolated pose at time ``t``, shaped by the segment's profile."""
        s = self.fraction(t)
        if s >= 1.0:
            return dict(self.end)
        k = shape(self.profile, s)
        pose = {}
        for joint, a in self.start.items():
            b = self.end[joint]
            # Kept between the two ends whatever the float rounding does.
            pose[joint] = min(max(a + (b - a) * k, min(a, b)), max(a, b))
        return pose

    def velocity_at(self, t: float) -> dict[str, float]:
        """Degrees per second of each joint at ``t``."""
        duration = self.end_time - self.start_time
        if duration <= 0:
            return dict.fromkeys(self.start, 0.0)
        k = slope(self.profile, self.fraction(t)) / duration
        return {j: (self.end[j] - a) * k for j, a in self.start.items()}


class Trajectory:
    """``segments`` back to back; each joint moves along the current segment, then holds its last angle.

    Raises:
        InvalidArgument: no segment.
    """

    def __init__(self, segments: Sequence[Segment]) -> None:
        if not segments:
            raise InvalidArgument("a trajectory needs at least one segment")
        self.segments = list(segments)
        self.joints = frozenset(segments[0].start)
        self.duration = self.segments[-1].end_time

    @classmethod
    def through(
        cls, start: Mapping[str, float], keyframes: Sequence[tuple[float, Mapping[str, float], str]]
    ) -> Trajectory:
        """From ``start`` through ``(time, pose, profile)`` keyframes (times increasing, from 0).

        A joint a keyframe does not name keeps its angle from the keyframe before.
        """
        segments = []
        previous_time, previous = 0.0, dict(start)
        for time, pose, profile in keyframes:
            end = {**previous, **pose}
            segments.append(Segment(previous_time, time, previous, end, profile))
            previous_time, previous = time, end
        return cls(segments)

    def envelope(self) -> dict[str, tuple[float, float]]:
        """Per joint, the lowest and highest angle of any segment's ends: where the trajectory stays."""
        spans: dict[str, tuple[float, float]] = {}
        for segment in self.segments:
            for pose in (segment.start, segment.end):
                for joint, deg in pose.items():
                    low, high = spans.get(joint, (deg, deg))
                    spans[joint] = (min(low, deg), max(high, deg))
        return spans

    @property
    def final(self) -> dict[str, float]:
        """The pose the trajectory ends in."""
        return dict(self.segments[-1].end)


def stopping(moving: Mapping[str, tuple[float, float, tuple[float, float]]], ramp: float) -> list[Segment]:
    """Decelerating segments that bring ``{joint: (angle, speed, (low, high))}`` to rest, each inside its interval.

    A joint slows at the rate that would bring it to rest in ``ramp``
    seconds (``decel`` covers half the distance its initial speed would); one
    that would leave its interval (its motion's envelope) rests on its edge,
    sooner, having started at the same speed.  Joints taking as long share a segment.
    """
    groups: dict[float, tuple[dict[str, float], dict[str, float]]] = {}
    for joint, (angle, speed, (low, high)) in moving.items():
        if not speed or ramp <= 0:
            continue
        end = min(max(angle + speed * ramp / 2, low), high)
        duration = 2 * abs(end - angle) / abs(speed)
        if duration > 0:
            start, ends = groups.setdefault(round(duration, 4), ({}, {}))
            start[joint], ends[joint] = angle, end
    return [Segment(0.0, duration, start, ends, "decel") for duration, (start, ends) in groups.items()]
