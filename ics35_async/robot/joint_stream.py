"""The robot's stream in joint space: frames keyed by joint name in degrees, targets set by name."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Mapping
from types import TracebackType
from typing import TYPE_CHECKING

from ..frames import FrameIterator
from .frame import RobotFrame

if TYPE_CHECKING:
    from .host import RobotHost as Robot


class RobotStream(FrameIterator[RobotFrame]):
    """A view of the robot's stream: ``async for frame in robot.stream()`` and ``set_targets({joint: deg})``.

    The robot streams all the time it is open; this view hands out its frames
    (the newest one not seen yet) and raises :class:`SafetyStop` when the
    safety watch trips after the view was opened.
    """

    _used_with = "a robot's stream runs in `async with robot.stream() as stream:`"
    _made_with = "robot.stream()"

    def __init__(self, robot: Robot) -> None:
        self.robot = robot
        self._cycle = robot.latest.cycle if robot.latest is not None else 0
        self._trips = len(robot.trips)
        self._closed = False

    async def next_frame(self) -> RobotFrame:
        """The newest frame in joint degrees not yet returned; waits for one.

        Raises:
            BusClosed: the stream or the robot was closed.
            SafetyStop: the safety watch stopped the robot.
        """
        if self._closed:
            raise self._ran_once()
        frame = await self.robot.wait_frame(self._cycle)
        skipped = frame.cycle - self._cycle - 1 if self._cycle else 0
        self._cycle = frame.cycle
        if len(self.robot.trips) > self._trips:
            self._trips = len(self.robot.trips)
            raise self.robot.trips[-1]
        return dataclasses.replace(frame, skipped=skipped) if skipped > 0 else frame

    def set_target(self, joint: str, degrees: float) -> None:
        """Latest-value target for one joint, in joint degrees.

        Raises:
            InvalidArgument: an unknown joint or an angle outside its limits.
            SafetyStop: a joint the safety watch tripped (see ``Robot.set_targets``).
            BusClosed: the robot was closed (its ``async with`` block has ended).
            PortLost: a line was lost (without ``reconnect``), or, with it, the joint's line is lost now: nothing
                applied (see ``Robot.set_targets``).
        """
        self.robot.set_targets({joint: degrees})

    def set_targets(self, pose: Mapping[str, float], *, lift_holds: bool = True) -> None:
        """Targets ``pose`` ``{joint: degrees}``, all checked (names, limits) before any is applied;
        ``lift_holds``: as for ``Robot.set_targets`` (a loop setting every joint each frame passes False).

        Raises:
            InvalidArgument: an unknown joint or an angle outside its limits (nothing applied).
            SafetyStop: a joint the safety watch tripped (see ``Robot.set_targets``).
            BusClosed: the robot was closed (its ``async with`` block has ended).
            PortLost: a line was lost (without ``reconnect``), or, with it, an angle for a joint on a line lost now
                and ``lift_holds`` true: nothing applied (see ``Robot.set_targets``).
        """
        self.robot.set_targets(pose, lift_holds=lift_holds)

    def free(self, joints: Iterable[str] | None = None) -> None:
        """Free ``joints`` (default: all): torque off, positions still read back.

        Raises:
            InvalidArgument: an unknown joint.
            BusClosed: the robot was closed (its ``async with`` block has ended).
        """
        self.robot.set_targets(dict.fromkeys(self.robot.joint_names(joints)), allow_free=True)

    def hold(self, joints: Iterable[str] | None = None) -> dict[str, str]:
        """Hold ``joints`` (default: all but the tripped ones) where they are, torque on; returns those left out
        and why (see ``Robot.hold``).

        Raises:
            InvalidArgument: an unknown joint.
            SafetyStop: a joint the safety watch tripped (see ``Robot.hold``).
            BusClosed: the robot was closed (its ``async with`` block has ended).
            PortLost: a line was lost (without ``reconnect``): nothing applied (see ``Robot.set_targets``).
        """
        return self.robot.hold(joints)

    async def aclose(self) -> None:
        """Stop taking frames from this stream; the robot keeps streaming."""
        self._closed = True

    async def __aenter__(self) -> RobotStream:
        if self._closed:  # (a program in phases: the second `async with stream:` needs a new one)
            raise self._ran_once()
        return self

    async def __aexit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        await self.aclose()
