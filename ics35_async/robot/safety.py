"""The safety watch: temperature and current read in the line's gaps, checked against ``[safety]``.

Each line has its own watch task.  After every merged frame it reads the
temperature and current of the next ``telemetry_per_cycle`` joints of its
line (round robin), at low priority, so the reads slip in between the
stream's position transactions.  A *telemetry round* is every joint of a
line read once; a joint crossing a threshold is reported within one round, once a
second reading taken at once confirms it (a reply has no checksum: one garbled
byte can read as any value).
A joint the stream has marked offline is skipped (each read of a dead ID
costs a whole reply timeout); the robot itself watches offline joints.  So
is one whose servo has not answered since the robot opened (an unplugged
one): nothing of it is under control, and it answers nothing to read.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol

import anyio

from .. import units
from ..bus import Bus, Priority
from ..errors import IcsError, PortLost, ReplyError
from ..frames import STALE_AFTER_FAILED_READS
from ..servo import Servo
from .description import JointSpec, SafetySpec
from .frame import RobotFrame

log = logging.getLogger("ics35_async.robot")

REASONS = ("temperature", "current", "offline")


class SafetyStop(IcsError):
    """The safety watch stopped the motion: a joint got too hot, drew too much current, or went offline.

    ``joint`` names it, ``reason`` is ``"temperature"``, ``"current"`` or
    ``"offline"``, ``value`` and ``limit`` the reading and the threshold
    (``None`` for offline), ``action`` what was done (``"free"``, ``"hold"``
    or ``"stop"``, from ``[safety] action``).
    """

    def __init__(
        self,
        message: str,
        *,
        joint: str,
        reason: str,
        action: str,
        value: float | None = None,
        limit: float | None = None,
    ) -> None:
        self.joint = joint
        self.reason = reason
        self.action = action
        self.value = value
        self.limit = limit
        super().__init__(message)


class MotionStopped(IcsError):
    """A motion ended early: :meth:`Robot.stop` was called (from another task), a line it moves lost its port
    or came back after that (``reconnect=True``: the motion gave that line's joints up and went on with its
    joints on the other lines, or stopped with none left), or a joint it moves came back after going offline
    (its servo may have restarted, free and elsewhere: the motion gave it up)."""


class UnsettledReadings(IcsError):
    """Joints whose position readings kept disagreeing with one another (a broken potentiometer, a noisy line):
    a wait for a reading that agrees (``Robot.read_pose()``, a motion starting from a free joint) gave up, no
    joint moved on them.  ``readings``: ``{joint: its last readings in degrees, oldest first}``."""

    def __init__(self, message: str, *, readings: Mapping[str, Sequence[float]]) -> None:
        self.readings = {name: tuple(values) for name, values in readings.items()}
        super().__init__(message)


@dataclass
class JointTelemetry:
    """The newest temperature (approximate Celsius) and current (0..63) read from a joint's servo; ``reads`` and
    ``errors`` count the readings taken and those that failed (no reply, a garbled one), ``failed_in_row`` those
    failed since the newest one taken or its servo went offline (see :meth:`SafetyWatch.forget`;
    :attr:`Robot.telemetry <ics35_async.robot.Robot.telemetry>` shows none from
    :data:`~ics35_async.frames.STALE_AFTER_FAILED_READS` on)."""

    temperature_c: float | None = None
    current: int | None = None
    reads: int = 0
    errors: int = 0
    failed_in_row: int = 0

    @property
    def stale(self) -> bool:
        """Whether the reads of the joint's servo have failed too often in a row since its newest reading for
        that reading to pass for its now (:data:`~ics35_async.frames.STALE_AFTER_FAILED_READS`)."""
        return self.failed_in_row >= STALE_AFTER_FAILED_READS


class WatchedRobot(Protocol):
    """What the watch needs from the robot."""

    async def wait_frame(self, after: int) -> RobotFrame: ...

    def trip(self, stop: SafetyStop) -> None: ...

    def clear_trip(self, joint: str, reasons: Sequence[str]) -> None: ...

    def has_answered(self, joint: str) -> bool: ...


class SafetyWatch:
    """Reads every joint's temperature and current between stream cycles and trips the robot's safety."""

    def __init__(self, spec: SafetySpec, buses: Mapping[str, Bus], joints: Sequence[JointSpec]) -> None:
        self.spec = spec
        self.buses = dict(buses)
        self.joints = list(joints)
        self.telemetry: dict[str, JointTelemetry] = {j.name: JointTelemetry() for j in self.joints}
        self.rounds: dict[str, int] = dict.fromkeys(self.buses, 0)
        self._said_blind: set[str] = set()  # the joints whose stretch of failed reads was said (see _say_blind)
        self._blind: set[str] = set()  # those whose reads failed into a stretch, said next round if still answering

    def forget(self, joints: Iterable[str]) -> None:
        """Drop the readings of ``joints``, whose servo went offline or whose line lost its port: it may come back
        restarted, cooler or hotter, and what was read before is not its own now (``reads`` and ``errors`` stay).
        The reads that failed as it went end with it (``failed_in_row`` from 0): back, a stretch of failed reads to
        say is counted from then (they were said "did not read 20 times in a row (its servo still answers its
        position commands)" as it answered again)."""
        for name in joints:
            seen = self.telemetry.get(name)
            if seen is not None:
                seen.temperature_c = seen.current = None
                seen.failed_in_row = 0
            self._blind.discard(name)
            self._said_blind.discard(name)

    async def run(self, robot: WatchedRobot) -> None:
        if not self.spec.telemetry_per_cycle:
            return
        async with anyio.create_task_group() as group:
            for line, bus in self.buses.items():
                joints = [j for j in self.joints if j.line == line]
                if joints:
                    group.start_soon(self._watch_line, robot, line, bus, joints)

    async def _watch_line(self, robot: WatchedRobot, line: str, bus: Bus, joints: list[JointSpec]) -> None:
        servos = {j.name: Servo(bus, j.id, priority=Priority.LOW) for j in joints}
        per_cycle = min(self.spec.telemetry_per_cycle, len(joints))
        cycle, k, line_cycle = 0, 0, 0
        try:
            while True:
                frame = await robot.wait_frame(cycle)
                cycle = frame.cycle
                ran = frame.line_cycles.get(line, line_cycle + 1)  # (no line_cycles: every frame is one)
                if ran <= line_cycle:
                    continue  # another line's cycle: this line's reads follow its own pace
                line_cycle = ran
                for _ in range(per_cycle):
                    joint = joints[k]
                    k = (k + 1) % len(joints)
                    if k == 0:
                        self.rounds[line] += 1
                    if joint.name not in frame.offline and robot.has_answered(joint.name):
                        try:
                            await self._read(robot, joint, servos[joint.name], joint.name in frame.failed)
                        except PortLost:
                            # Reconnecting (reconnect=True): the line runs no cycle until it is back, and its
                            # reads go on with its cycles then.  (Without reconnect the robot's frames end
                            # with the line, and this watch with them.)
                            break
        except IcsError:
            return  # the robot's frames ended (its block, a line lost for good): the robot reports that itself

    async def _read(self, robot: WatchedRobot, joint: JointSpec, servo: Servo, position_failed: bool) -> None:
        """Read ``joint``'s temperature and current, and trip or clear its stop on them; ``position_failed``: its
        position did not answer in the frame this round follows (a cycle run after the round before's reads)."""
        seen = self.telemetry[joint.name]
        if joint.name in self._blind:
            # Its reads failed into a stretch last round: said now only if its position answered in a cycle run
            # since (the frame that round followed may be older than the servo's going); failing too, the servo
            # is gone, which the offline rule says, not a servo that still answers its position commands.
            self._blind.discard(joint.name)
            if not position_failed:
                self._said_blind.add(joint.name)
                self._say_blind(joint)
        reading = await self._reading(joint, servo, seen)
        if reading is None:
            if seen.stale and joint.name not in self._said_blind:
                self._blind.add(joint.name)  # (once a stretch: see above)
            return
        crossed = self._crossings(joint, *reading)
        confirmed: set[str] | None = None  # (the limits a second reading must cross too to trip)
        if crossed:
            # An ICS reply carries no checksum: a byte garbled on the wire reads as another value (a servo at 25 C
            # as 120 C), and one such reading would free a joint of a robot standing on it.  A crossing is read
            # once more at once, and trips only if that reading crosses the same limit: two garbled replies, one
            # in each reading, are two single readings still.
            confirmed = {stop.reason for stop in crossed}
            reading = await self._reading(joint, servo, seen)
            if reading is None:
                return  # (a stretch of failed reads begins: said from the next round on, see above)
            crossed = self._crossings(joint, *reading)
            if crossed and not confirmed & {stop.reason for stop in crossed}:
                return  # each limit crossed by one reading only: read again next round
        seen.reads += 1
        seen.failed_in_row = 0
        self._said_blind.discard(joint.name)
        self._blind.discard(joint.name)
        seen.temperature_c, seen.current = reading
        self.check(robot, joint, seen, confirmed)

    async def _reading(self, joint: JointSpec, servo: Servo, seen: JointTelemetry) -> tuple[float, int] | None:
        """The servo's temperature (Celsius) and current, or None (counted in ``seen.errors``) if a reply was
        garbled."""
        try:
            raw_temperature = await servo.read_temperature()
            raw_current = await servo.read_current()
        except ReplyError:
            seen.errors += 1
            seen.failed_in_row += 1
            return None
        return units.temperature_to_celsius(raw_temperature), units.current_from_raw(raw_current).magnitude

    def _say_blind(self, joint: JointSpec) -> None:
        """Say that the limits cannot guard ``joint`` while its readings fail: its reading is not shown any more
        (see STALE_AFTER_FAILED_READS), and a limit that nothing reads would pass for one that holds.  Not a trip:
        freeing a joint of a standing robot because a read fails would be worse than the heat it might miss."""
        spec = self.spec
        limits = [
            f"{name} {limit:g}"
            for name, limit in (("max_temperature_c", spec.max_temperature_c), ("max_current", spec.max_current))
            if limit is not None
        ]
        if not limits:
            return  # (nothing to guard: the views show "-" by themselves)
        log.warning(
            "joint %s (line %s, ID %s): its temperature and current did not read %d times in a row (its servo "
            "still answers its position commands): the safety watch cannot hold it to %s until they read again",
            joint.name,
            joint.line,
            joint.id,
            self.telemetry[joint.name].failed_in_row,
            " and ".join(limits),
        )

    def check(
        self, robot: WatchedRobot, joint: JointSpec, seen: JointTelemetry, confirmed: set[str] | None = None
    ) -> None:
        """Trip on ``seen``'s first crossing (of those whose reason is in ``confirmed``, if given), or clear the
        joint's trip when it crosses nothing."""
        crossed = [
            stop
            for stop in self._crossings(joint, seen.temperature_c, seen.current)
            if confirmed is None or stop.reason in confirmed
        ]
        if crossed:
            robot.trip(crossed[0])
        else:
            robot.clear_trip(joint.name, ("temperature", "current"))

    def _crossings(self, joint: JointSpec, temperature_c: float | None, current: int | None) -> list[SafetyStop]:
        """The stops a reading calls for, the first one to act on first (none: within every limit)."""
        spec = self.spec
        where = f"joint {joint.name} (line {joint.line}, ID {joint.id})"
        # (reason, what is seen, its limit, how the stop words it); the first crossed trips
        checks = (
            (
                "temperature",
                temperature_c,
                spec.max_temperature_c,
                "is at about {:.0f} C, over max_temperature_c {:g}",
            ),
            ("current", current, spec.max_current, "draws current {}, over max_current {}"),
        )
        return [
            SafetyStop(
                f"{where} {words.format(value, limit)}; action: {spec.action}",
                joint=joint.name,
                reason=reason,
                action=spec.action,
                value=value,
                limit=limit,
            )
            for reason, value, limit, words in checks
            if value is not None and limit is not None and value > limit
        ]
