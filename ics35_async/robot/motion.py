"""Motion files: keyframes (poses with times) in a versioned JSON format, and playing them on a robot.

Format (version 1)::

    {
      "format": "ics35-motion",
      "version": 1,
      "name": "wave",                      (optional)
      "profile": "minjerk",                (optional: the default of every segment; or "linear")
      "keyframes": [
        {"time": 1.0, "pose": {"right_shoulder": -80, "right_elbow": 30}},
        {"time": 1.6, "pose": {"right_elbow": 60}, "profile": "linear"}
      ]
    }

``time`` is seconds from the start of the motion, strictly increasing,
above 0 and at most :data:`~.profiles.LONGEST_MOTION` (an hour): the first keyframe is reached from wherever the
robot is when the motion starts, in that keyframe's time.  ``profile`` on a keyframe shapes
the segment that ends there.  A pose names any of the robot's joints; a
joint a keyframe leaves out keeps its angle from the keyframe before, and
joints no keyframe names are not touched.  Every angle is checked against
the robot's limits before anything moves.  Every keyframe's pose is sent
exactly, in order: keyframes closer together than a cycle of the line each
take a cycle (the motion runs late rather than cutting a corner).
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .. import units
from ..errors import FileContentError, InvalidArgument
from ..user_files import UnreadableText, parse_json, read_user_text, replace_keeping_backup
from .profiles import PROFILES, KeyframeError, Trajectory, check_angles, check_profile, check_time

if TYPE_CHECKING:
    from .host import PoseChecker
    from .host import RobotHost as Robot

FORMAT = "ics35-motion"
VERSION = 1
SPEEDS = (0.05, 10.0)
"""The time scales a motion plays at (``Robot.play``'s ``speed``, ``ics35 play --speed``, the configurator's): from
twenty times slower to ten times faster.  Faster, a motion's keyframes come milliseconds apart, its joints
thrown between them at the servos' own speed; slower, a motion of a few seconds creeps for minutes."""


def check_speed(speed: object) -> float:
    """A motion's time scale (2: twice as fast), within :data:`SPEEDS`.

    Raises:
        InvalidArgument: not a number, or outside :data:`SPEEDS`.
    """
    return units.check_number("speed", speed, *SPEEDS, "times the motion's own pace (2: twice as fast)")


def check_pace(motion: Motion, speed: object) -> float:
    """``speed`` (:func:`check_speed`) for ``motion``: played faster or slower, a motion's times meet their rule
    again (a keyframe at an hour, played at half speed, comes after two; two close ones, sped up, may come at the
    same time).  ``ics35 play`` asks it before any port opens, as ``Robot.play`` does before anything moves.

    Raises:
        InvalidArgument: ``speed`` breaks its rule, or a keyframe played at it breaks a time's (the message names
            the speed and the keyframe).
    """
    rate = check_speed(speed)
    previous = 0.0
    for k, frame in enumerate(motion.keyframes):
        try:
            previous = check_time(frame.time / rate, previous)
        except KeyframeError as exc:
            raise InvalidArgument(f"at speed {rate:g}, keyframes[{k}]{exc.key}: {exc}") from None
    return rate


class MotionError(FileContentError):
    """A motion file breaks the format; the message names the file and the key (``keyframes[2].time``)."""


@dataclass(frozen=True)
class Keyframe:
    time: float
    pose: dict[str, float]
    profile: str | None = None


@dataclass(frozen=True)
class Motion:
    """Keyframes to play, held to the file format's rules (:func:`check_keyframe`) as it is built.

    Raises:
        InvalidArgument: no keyframe, or one breaking a rule (the message names it: ``keyframes[2].time``).
    """

    keyframes: tuple[Keyframe, ...]
    profile: str = "minjerk"
    name: str | None = None

    def __post_init__(self) -> None:
        if not self.keyframes:
            raise InvalidArgument("a motion needs at least one keyframe")
        check_profile(self.profile)
        previous = 0.0
        for k, frame in enumerate(self.keyframes):
            try:
                previous = check_keyframe(frame.time, frame.pose, frame.profile, previous)[0]
            except KeyframeError as exc:
                raise InvalidArgument(f"keyframes[{k}]{exc.key}: {exc}") from None

    @property
    def duration(self) -> float:
        """Seconds from the start to the last keyframe."""
        return self.keyframes[-1].time

    @property
    def joints(self) -> list[str]:
        """Every joint some keyframe names, in order of first appearance."""
        seen: dict[str, None] = {}
        for frame in self.keyframes:
            seen.update(dict.fromkeys(frame.pose))
        return list(seen)

    def to_json(self) -> dict[str, Any]:
        """The motion as the JSON document ``load_motion`` reads (format and version included)."""
        data: dict[str, Any] = {"format": FORMAT, "version": VERSION}
        if self.name is not None:
            data["name"] = self.name
        data["profile"] = self.profile
        frames = []
        for frame in self.keyframes:
            entry: dict[str, Any] = {"time": frame.time, "pose": dict(frame.pose)}
            if frame.profile is not None:
                entry["profile"] = frame.profile
            frames.append(entry)
        data["keyframes"] = frames
        return data


def check_keyframe(
    time: object, pose: object, profile: object, previous: float
) -> tuple[float, dict[str, float], str | None]:
    """A keyframe's ``time``, ``pose`` and ``profile`` checked: the one rule of a motion file's keyframes
    (:func:`parse_motion`), of a :class:`Motion` built in Python, and so of ``ics35 play``'s files and the
    configurator's uploads.  ``previous``: the time of the keyframe before (0 for the first).  The time is a
    finite number of seconds after ``previous`` and at most :data:`~.profiles.LONGEST_MOTION`; every angle a finite
    number of degrees (the robot's limits are checked against the robot: :func:`check_motion`).  The time and
    angle rules are a trajectory's segments' too (:func:`~.profiles.check_time`, :func:`~.profiles.check_angles`).

    Raises:
        KeyframeError: which part breaks which rule.
    """
    seconds = check_time(time, previous)
    angles = check_angles(pose)
    if profile is not None and profile not in PROFILES:
        raise KeyframeError(".profile", f"must be one of {', '.join(PROFILES)}, not {profile!r}")
    return seconds, angles, profile if isinstance(profile, str) else None


def load_motion(source: str | Path | Mapping[str, Any]) -> Motion:
    """Read and check a motion: ``source`` is a JSON file's path, or the same structure as a mapping.

    Raises:
        MotionError: the file cannot be read, is not JSON, or breaks a rule of the format.
        InvalidArgument: ``source`` is neither a path nor a mapping (nothing read).
    """
    if isinstance(source, Mapping):
        return parse_motion(source, "<mapping>")
    if not isinstance(source, (str, os.PathLike)):
        raise InvalidArgument(f"a motion is a Motion, a JSON file's path or a mapping, not {type(source).__name__}")
    path = Path(source)
    try:
        data = parse_json(read_user_text(source if isinstance(source, str) else path, "a motion is UTF-8 JSON"))
    except UnreadableText as exc:
        raise MotionError(str(path), "", str(exc)) from None
    except json.JSONDecodeError as exc:
        raise MotionError(str(path), "", f"not valid JSON: {exc}") from None
    return parse_motion(data, str(path))


def save_motion(motion: Motion, path: str | Path) -> Path | None:
    """Write ``motion`` to ``path`` as JSON (UTF-8, indented), whole: a file already there is kept as
    ``NAME.bak`` beside it, which this returns (``None`` when there was none).

    Raises:
        OSError: the file cannot be written (one already there is left as it was).
    """
    return replace_keeping_backup(Path(path), json.dumps(motion.to_json(), indent=2) + "\n")


def parse_motion(data: object, source: str = "<mapping>") -> Motion:
    """Check ``data``, a parsed motion (what ``json.load`` returns), and build a :class:`Motion`.

    ``source`` names where it came from in error messages.

    Raises:
        MotionError: ``data`` breaks a rule of the format (the error names the key).
    """
    if not isinstance(data, Mapping):
        raise MotionError(source, "", "a motion is a JSON object with format, version and keyframes")
    unknown = set(data) - {"format", "version", "name", "profile", "keyframes"}
    if unknown and unknown == set(data) and all(units.real_number(v) is not None for v in data.values()):
        # ({joint: degrees}: what move_to takes, given where a motion is wanted)
        raise MotionError(source, "", "this is a pose, not a motion: move_to(pose, duration) moves to a pose")
    if unknown:
        raise MotionError(source, sorted(unknown)[0], "unknown key (known: format, version, name, profile, keyframes)")
    if data.get("format") != FORMAT:
        raise MotionError(source, "format", f"must be {FORMAT!r}, got {data.get('format')!r}")
    version = data.get("version")
    if version != VERSION:
        newer = isinstance(version, int) and not isinstance(version, bool) and version > VERSION
        why = "written by a newer ics35_async" if newer else "not a version this library reads"
        raise MotionError(source, "version", f"{version!r} is {why} (it reads version {VERSION})")
    name = data.get("name")
    if name is not None and not isinstance(name, str):
        raise MotionError(source, "name", f"must be a string, not {name!r}")
    profile = data.get("profile", "minjerk")
    if profile not in PROFILES:
        raise MotionError(source, "profile", f"must be one of {', '.join(PROFILES)}, not {profile!r}")
    frames = data.get("keyframes")
    if not isinstance(frames, list) or not frames:
        raise MotionError(source, "keyframes", "must be a non-empty list of {time, pose} objects")
    keyframes: list[Keyframe] = []
    previous = 0.0
    for k, frame in enumerate(frames):
        key = f"keyframes[{k}]"
        if not isinstance(frame, Mapping):
            raise MotionError(source, key, "must be an object with time and pose")
        extra = set(frame) - {"time", "pose", "profile"}
        if extra:
            raise MotionError(source, f"{key}.{sorted(extra)[0]}", "unknown key (known: time, pose, profile)")
        try:
            previous, angles, shape = check_keyframe(
                frame.get("time"), frame.get("pose"), frame.get("profile"), previous
            )
        except KeyframeError as exc:
            raise MotionError(source, f"{key}{exc.key}", str(exc)) from None
        keyframes.append(Keyframe(previous, angles, shape))
    return Motion(tuple(keyframes), profile, name)


def check_motion(robot: PoseChecker, motion: Motion, source: str = "motion") -> None:
    """Every joint known to ``robot`` and every angle within its limits (a MotionError naming the keyframe).

    ``robot`` is a :class:`~.description.RobotDescription` or an open robot: checked against the
    description, a motion that does not fit the robot is refused before any port opens (a robot
    would otherwise start, freeing its joints, only to refuse the motion).
    """
    for k, frame in enumerate(motion.keyframes):
        try:
            robot.check_pose(frame.pose)
        except InvalidArgument as exc:
            raise MotionError(source, f"keyframes[{k}]", str(exc)) from None


async def play_motion(
    robot: Robot, motion: Motion | str | Path | Mapping[str, Any], *, speed: float = 1.0, loop: bool = False
) -> None:
    """Play ``motion`` on ``robot`` (``speed`` 2 plays twice as fast); with ``loop``, again and again until
    cancelled, each pass reaching the first keyframe from the last in the first keyframe's time.  A joint
    another command takes over is given up: the passes go on with the others, and end when none is left."""
    # A file's mistakes name the file, as load_motion's own do.
    source = str(motion) if isinstance(motion, (str, os.PathLike)) else "motion"
    if not isinstance(motion, Motion):
        motion = load_motion(motion)
    rate = check_pace(motion, speed)
    units.check_bool("loop", loop)
    check_motion(robot, motion, source)
    joints = motion.joints
    timeline = [(f.time / rate, f.pose, f.profile or motion.profile) for f in motion.keyframes]
    first = motion.keyframes[0].pose
    robot.check_ready(joints)
    if not joints:
        return
    owned = set(joints)  # a joint another command takes over is given up, for this pass and the next ones
    # A stop (or a safety trip) that comes between two passes finds no pass running to end: it ends the loop all
    # the same, rather than the next pass moving the joints after stop() has returned.
    stops = robot.stops
    while owned:
        # A joint never read starts at its first angle in the motion (nothing to interpolate from).
        start = {j: first.get(j, _first_angle(motion, j)) for j in owned}
        start.update(await robot.start_pose(owned))
        keyframes: Sequence[tuple[float, Mapping[str, float], str]] = [
            (time, {j: a for j, a in pose.items() if j in owned}, profile) for time, pose, profile in timeline
        ]
        owned &= await robot.run(
            Trajectory.through(start, keyframes), wait_on_wire=not loop, unless_stopped_since=stops
        )
        if not loop:
            return


def _first_angle(motion: Motion, joint: str) -> float:
    return next(f.pose[joint] for f in motion.keyframes if joint in f.pose)
