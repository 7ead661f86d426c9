"""The line's rules as a pure state machine, and what it queues.

Nothing here does I/O or reads a clock: drivers (:mod:`ics35_async.drivers`)
move bytes and time between a :class:`LineEngine` and the world.
"""

from .counters import LineCounters
from .machine import LineEngine, State
from .requests import GuardRequest, Priority, Request, RequestQueue
from .source import BackgroundSource
from .timing import BusTiming

__all__ = [
    "BackgroundSource",
    "BusTiming",
    "GuardRequest",
    "LineCounters",
    "LineEngine",
    "Priority",
    "Request",
    "RequestQueue",
    "State",
]
