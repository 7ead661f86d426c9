"""The engine's one state variable: where the line is in its life and in a transaction."""

from __future__ import annotations

import enum


class State(enum.Enum):
    """What the line is doing (``bus.state``; ``bus.state_change()`` waits for the next change)."""

    OFFLINE = "offline"  # no line yet, or reopening: requests wait
    IDLE = "idle"
    BUSY = "busy"  # a transaction is on the wire
    QUIET = "quiet"  # resyncing: waiting for silence
    DRAINING = "draining"  # closing: the transaction on the wire finishes, nothing new starts
    LOST = "lost"  # the port is gone and the driver is reconnecting: requests fail at once
    CLOSED = "closed"
