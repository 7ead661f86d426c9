"""What a slow link adds: the engine learns it from late bytes and forgets it when the link is fast again.

A TCP bridge with Nagle's algorithm on can hold a reply's tail for 40 ms; a
fixed allowance tuned for a USB adapter then times out every long reply and
the held tail lands in the next transaction.  The engine therefore adds
``extra`` seconds to every deadline and to the quiet time of a resync:
raised when bytes prove late (bytes of a timed-out transaction arriving
during the resync that follows it), lowered by half after a window of
transactions in which none needed it.
"""

from __future__ import annotations


class LinkLatency:
    __slots__ = ("_needed", "_window", "bound", "extra", "window")

    def __init__(self, bound: float, window: int = 100) -> None:
        self.bound = bound  # the most the engine ever adds: a dead servo must still time out in bounded time
        self.window = window
        self.extra = 0.0
        self._window = 0
        self._needed = False

    def late_by(self, seconds: float) -> None:
        """Bytes arrived ``seconds`` after the deadline they would have had without ``extra``."""
        # Half as much again as the worst seen, plus a millisecond for the loop's own jitter.
        self.extra = min(self.bound, max(self.extra, seconds * 1.5 + 0.001))
        self._window = 0
        self._needed = True

    def succeeded(self, over_base: float) -> None:
        """A transaction finished ``over_base`` seconds past what it would have been allowed without ``extra``."""
        if over_base > 0:
            self._needed = True
        self._window += 1
        if self._window >= self.window:
            if not self._needed:
                self.extra = 0.0 if self.extra < 0.001 else self.extra / 2
            self._window = 0
            self._needed = False
