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

The rule of a motion's times and angles lives here too (:func:`check_time`,
:func:`check_angles`): a motion file's keyframes, a :class:`Segment` built in
Python and ``Robot.move_to``'s duration all meet it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from .. import units
from ..errors import InvalidArgument

PROFILES = ("minjerk", "linear")
_ALL = (*PROFILES, "decel")
LONGEST_MOTION = 3600.0
"""Seconds: the latest a keyframe may come, the longest ``Robot.move_to`` and the latest a trajectory's segment may
end.  An hour is longer than any motion a servo robot plays in one go; a time later than that is a slip
(milliseconds written for seconds, a stray exponent), and a time such as 1e308 makes a motion that never ends while
it looks as if it runs (its joints creep too slowly to see), with the robot's motion taken until it is stopped."""


class KeyframeError(InvalidArgument):
    """A keyframe breaks a rule of the format; ``key`` is where in the keyframe (``.time``, ``.pose.neck``)."""

    def __init__(self, key: str, message: str) -> None:
        self.key = key
        super().__init__(message)


def check_time(time: object, previous: float, key: str = ".time") -> float:
    """The rule of a motion's times: ``time`` is a finite number of seconds after ``previous`` (the time
    before it: 0 for the first) and at most :data:`LONGEST_MOTION`.  Not 0: a pose reached in no time is sent
    at once, its joints thrown there at full speed.

    Raises:
        KeyframeError: which rule ``time`` breaks, at ``key``.
    """
    seconds = units.finite_number(time)
    if seconds is None:
        raise KeyframeError(key, f"must be a number of seconds, not {units.said(time)}")
    if seconds <= previous:
        why = "above 0 (the time to reach it from where the robot is)" if previous == 0 else f"after {previous:g}"
        raise KeyframeError(key, f"{seconds:g} must be {why}")
    if seconds > LONGEST_MOTION:
        raise KeyframeError(key, f"{seconds:g} must be at most {LONGEST_MOTION:g} seconds (an hour) from the start")
    return seconds


def check_angles(pose: object, key: str = ".pose") -> dict[str, float]:
    """The rule of a motion's poses: ``pose`` is a mapping ``{joint: degrees}``, every angle a finite number (a
    robot's joints and limits are checked against the robot: ``check_pose``).  The angles as floats, in a new dict.

    Raises:
        KeyframeError: which joint breaks the rule (``key`` and the joint: ``.pose.neck``).
    """
    if not isinstance(pose, Mapping):
        raise KeyframeError(key, "must be an object {joint: degrees}")
    angles = {}
    for joint, deg in pose.items():
        angle = units.finite_number(deg)
        if angle is None:
            raise KeyframeError(f"{key}.{joint}", f"must be a number of degrees, not {units.said(deg)}")
        angles[joint] = angle
    return angles


def check_duration(duration: object, name: str = "duration") -> float:
    """A move's time (``Robot.move_to``'s ``duration``): a first keyframe's time (:func:`check_time`).

    Raises:
        InvalidArgument: the rule it breaks, in the words of a keyframe's, after ``name``.
    """
    try:
        return check_time(duration, 0.0)
    except KeyframeError as exc:
        raise InvalidArgument(f"{name}: {exc}") from None


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
    """Every joint of ``start`` goes to its angle in ``end`` between ``start_time`` and ``end_time``.

    Held to a keyframe's rules as it is built (:func:`check_time`, :func:`check_angles`): ``end_time`` after
    ``start_time`` (from 0) and at most :data:`LONGEST_MOTION`, every angle a finite number, ``start`` and ``end``
    naming the same joints.  ``start`` and ``end`` are kept as copies: a mapping changed after is not played.

    Raises:
        InvalidArgument: the rule broken (``a segment's end_time: 0 must be above 0 ...``).
    """

    start_time: float
    end_time: float
    start: Mapping[str, float]
    end: Mapping[str, float]
    profile: str = "minjerk"

    def __post_init__(self) -> None:
        begins = units.finite_number(self.start_time)
        if begins is None or begins < 0:
            raise InvalidArgument(
                f"a segment's start_time: must be a number of seconds from 0, not {units.said(self.start_time)}"
            )
        try:
            ends = check_time(self.end_time, begins, ".end_time")
            start, end = check_angles(self.start, ".start"), check_angles(self.end, ".end")
        except KeyframeError as exc:
            raise InvalidArgument(f"a segment's {exc.key[1:]}: {exc}") from None
        if start.keys() != end.keys():
            raise InvalidArgument(
                f"a segment's start and end name the same joints, not {', '.join(start) or 'none'} and "
                f"{', '.join(end) or 'none'}"
            )
        if self.profile not in _ALL:
            check_profile(self.profile)
        for field, value in (("start_time", begins), ("end_time", ends), ("start", start), ("end", end)):
            object.__setattr__(self, field, value)  # (frozen: checked once, kept as checked)

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

    Each segment starts when and where the one before ends, with the same joints: a segment starting elsewhere
    would be sent at once, its joints thrown there at full speed.  The robot's joints and limits are checked when
    it is played (``Robot.run``).

    Raises:
        InvalidArgument: no segment, not a :class:`Segment`, or one not starting where the one before ends.
    """

    def __init__(self, segments: Sequence[Segment]) -> None:
        if not segments:
            raise InvalidArgument("a trajectory needs at least one segment")
        self.segments: tuple[Segment, ...] = tuple(segments)
        for k, segment in enumerate(self.segments):
            if not isinstance(segment, Segment):
                raise InvalidArgument(f"segments[{k}] must be a Segment, not {type(segment).__name__}")
            if k == 0:
                continue
            before, there = self.segments[k - 1], f"not where segments[{k - 1}] ends"
            if segment.start.keys() != before.end.keys():
                raise InvalidArgument(
                    f"segments[{k}] moves {', '.join(segment.start)}, not the joints of segments[{k - 1}] "
                    f"({', '.join(before.end)})"
                )
            if segment.start_time != before.end_time:
                raise InvalidArgument(
                    f"segments[{k}] starts at {segment.start_time:g} s, {there} ({before.end_time:g} s)"
                )
            for joint, deg in segment.start.items():
                if deg != before.end[joint]:
                    raise InvalidArgument(f"segments[{k}] starts at {joint} {deg:g}, {there} ({before.end[joint]:g})")
        self.joints = frozenset(self.segments[0].start)
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
        # (Rounded first: a joint at rest within a tenth of a millisecond needs no segment, and gets none of 0 s.)
        duration = round(2 * abs(end - angle) / abs(speed), 4)
        if duration > 0:
            start, ends = groups.setdefault(duration, ({}, {}))
            start[joint], ends[joint] = angle, end
    return [Segment(0.0, duration, start, ends, "decel") for duration, (start, ends) in groups.items()]
