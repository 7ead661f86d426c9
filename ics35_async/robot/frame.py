"""What the robot's stream publishes: every line's newest cycle, merged, in joint degrees."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class RobotFrame:
    """Every line's newest cycle, merged, in joint degrees: one comes each time any line ends a cycle.

    ``positions`` holds the joints that answered in their line's newest cycle; ``targets`` every
    joint's target (``None``: free); ``failed`` the joints tried that did not
    answer (or held back: :attr:`not_sent`); ``offline`` the joints the stream has taken out of its cycle;
    ``time`` is ``anyio.current_time()`` when the frame arrived; ``stamps``
    the ``time.monotonic()`` of each answering joint's reply.
    """

    cycle: int
    time: float
    positions: dict[str, float]
    targets: dict[str, float | None]
    failed: frozenset[str]
    offline: frozenset[str]
    stamps: dict[str, float] = dataclasses.field(default_factory=dict)
    skipped: int = 0
    line_cycles: dict[str, int] = dataclasses.field(default_factory=dict)
    """Each line's newest cycle number: the lines that ended a cycle since the previous frame have a new one."""
    resumed: frozenset[str] = frozenset()
    """The lines whose lost port came back with this frame (opened with ``reconnect=True``): the motions
    moving their joints gave them up, and those joints are :attr:`held`."""
    held: frozenset[str] = frozenset()
    """The joints on a line that came back (or whose servo came back from offline), sent nothing until a target
    is set for them again: their servos
    may have restarted, free and elsewhere, and where they are is unknown until they answer again (an ICS
    3.6 servo's position can be read: ``robot.group[line].servo(id).read_position()``).  Decide before
    moving them; a target the program sets for one (``set_targets``, ``hold``, ``free``; not a motion's
    next step, nor ``set_targets(..., lift_holds=False)``) ends its hold.  ``Robot.held`` is the same,
    live."""
    not_sent: frozenset[str] = frozenset()
    """The joints of :attr:`failed` that were sent nothing in their line's newest cycle: held back after a failure
    while its late reply could still come, or failed by their guard read (see ``Frame.not_sent``), where the
    others' commands went out."""
    lost: frozenset[str] = frozenset()
    """The joints on a line whose port is lost now (opened with ``reconnect=True``: its bus reconnecting), until
    the frame that says it is back (:attr:`resumed`): their servos keep their last command, the motions have
    given them up, and their angles in :attr:`positions` are from the line's last cycle before the loss.  Once
    it is back, a joint that had a target is :attr:`held`."""

    def to_dict(self) -> dict[str, Any]:
        """The frame as plain JSON values, for a log or a web page: degrees rounded to 0.01, sets as sorted
        lists, a free joint's target ``None``."""
        return {
            "cycle": self.cycle,
            "time": self.time,
            "positions": {name: round(deg, 2) for name, deg in self.positions.items()},
            "targets": {name: None if deg is None else round(deg, 2) for name, deg in self.targets.items()},
            "failed": sorted(self.failed),
            "not_sent": sorted(self.not_sent),
            "offline": sorted(self.offline),
            "stamps": dict(self.stamps),
            "skipped": self.skipped,
            "line_cycles": dict(self.line_cycles),
            "resumed": sorted(self.resumed),
            "held": sorted(self.held),
            "lost": sorted(self.lost),
        }
