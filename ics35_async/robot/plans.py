"""The bookkeeping of running motions: a plan (a trajectory being played) and the replies that prove its end sent."""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import anyio

from ..errors import IcsError
from .profiles import Trajectory


class Replies:
    """Counts each joint's replies that arrived after a moment (distinct reply times seen in frames).

    A frame holds each line's newest cycle, which may have begun before that
    moment; a reply after it may still answer a command sent before it (the
    servo measures when the command reaches it), but a second one answers a
    command sent after it.
    """

    def __init__(self, joints: Iterable[str], since: float) -> None:
        self.since = since
        self.counts = dict.fromkeys(joints, 0)
        self._last: dict[str, float] = {}

    def add(self, stamps: Mapping[str, float]) -> None:
        """Count the replies among ``stamps`` (``{joint: reply time}``, a frame's or the readings a robot took)."""
        for name, stamp in stamps.items():
            if name in self.counts and stamp > self.since and stamp != self._last.get(name):
                self.counts[name] += 1
                self._last[name] = stamp

    def reached(self, replies: int, offline: Iterable[str]) -> bool:
        skip = set(offline)
        return all(n >= replies or name in skip for name, n in self.counts.items())


class Plan:
    """A trajectory being played: which joints it still drives, and how it ends."""

    def __init__(self, trajectory: Trajectory, wait_on_wire: bool) -> None:
        self.trajectory = trajectory
        # The trajectory's time zero: the first frame that carries it (not the call), so a host that
        # stalls before that frame delays the motion instead of sending a target far along its path.
        self.t0: float | None = None
        self.wait_on_wire = wait_on_wire
        self.joints = set(trajectory.joints)
        self.done = anyio.Event()
        self.error: IcsError | None = None
        self.ending: Replies | None = None  # once the final targets are set
        self.segment = 0  # the segment the last targets came from
        self.stepped: dict[str, int] = {}  # each line's cycle when the plan last set targets (see Robot._step)
        self.keyframe_at: float | None = None  # when it last set a keyframe exactly, until that surely went out
        # Why it gave up joints no other command took over (their line came back after a lost port): its
        # caller hears it at the end, since the pose was not reached.
        self.given_up: IcsError | None = None
        self.lost_lines: set[str] = set()  # the lines whose lost port took joints from it (see Robot._give_up_lost)

    @property
    def slowing_down(self) -> bool:
        """Whether this is a stop's own ramp (only ``Robot.stop`` makes ``decel`` segments)."""
        return all(segment.profile == "decel" for segment in self.trajectory.segments)

    def finish(self, error: IcsError | None = None) -> None:
        if not self.done.is_set():
            self.error = error or self.given_up
            self.done.set()
