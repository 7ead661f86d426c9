"""What the robot's stream publishes: one merged cycle in joint degrees."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass


@dataclass(frozen=True)
class RobotFrame:
    """One merged cycle of every line, in joint degrees.

    ``positions`` holds the joints that answered this cycle; ``targets`` every
    joint's target (``None``: free); ``failed`` the joints tried that did not
    answer; ``offline`` the joints the stream has taken out of its cycle;
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
