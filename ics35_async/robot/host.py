"""What motions and the joint-space stream need from the robot: a small protocol.

:class:`~.robot.Robot` is the one the library makes; ``motion`` and
``stream`` depend on this, not on ``robot``, which builds on them.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:
    from .frame import RobotFrame
    from .profiles import Trajectory
    from .safety import SafetyStop


class PoseChecker(Protocol):
    """What checks a pose against a robot's joints: a :class:`~.description.RobotDescription` (before any
    port opens) or an open robot."""

    def check_pose(self, pose: Mapping[str, float]) -> dict[str, float]: ...


class RobotHost(PoseChecker, Protocol):
    trips: list[SafetyStop]

    @property
    def latest(self) -> RobotFrame | None: ...

    def joint_names(self, joints: Iterable[str] | None) -> list[str]: ...

    def check_ready(self, joints: Iterable[str]) -> None: ...

    async def start_pose(self, joints: Iterable[str]) -> dict[str, float]: ...

    async def wait_frame(self, after: int) -> RobotFrame: ...

    @property
    def stops(self) -> int: ...

    async def run(
        self, trajectory: Trajectory, *, wait_on_wire: bool = True, unless_stopped_since: int | None = None
    ) -> frozenset[str]: ...

    def set_targets(
        self, pose: Mapping[str, float | None], *, allow_free: bool = False, lift_holds: bool = True
    ) -> None: ...

    def hold(self, joints: Iterable[str] | None = None) -> dict[str, str]: ...
