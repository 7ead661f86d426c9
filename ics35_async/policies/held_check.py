"""Telling from a position command's reply whether a servo the program holds was on its way when it came.

A position command's reply is where the servo stood as the command arrived.  A servo the program holds stands
between where it stood at the command before and that command's target (on its way there, or there, a little
off under load).  Standing well off that way, it was not holding: it restarted (a brown-out shorter than
anything that reads it, so it woke free) and was turned, or something forced it; the command just sent throws it
to the new target from there.  The configurator's jogs follow this rule: the servo is freed at once (it was free
before the command) and its motion switched off.
"""

from __future__ import annotations

from .. import units

HELD_SLACK_DEGREES = 10.0
"""Degrees a held servo may stand off its way and still be taken for holding: a joint under load sags some
degrees; a servo that restarted and was turned further than this is told."""


def off_its_way(reported: int, came_from: int, target: int, slack_degrees: float = HELD_SLACK_DEGREES) -> bool:
    """Whether ``reported`` (a position command's reply) lies more than ``slack_degrees`` off the way from
    ``came_from`` (where the servo stood at the command before) to ``target`` (that command's): see the module."""
    low, high = sorted((came_from, target))
    off = max(low - reported, reported - high, 0)
    return off > slack_degrees * units.COUNTS_PER_DEGREE
