"""What a slow link adds: the engine learns it from late bytes and forgets it when the link is fast again.

A TCP bridge with Nagle's algorithm on can hold a reply's tail for 40 ms; a
fixed allowance tuned for a USB adapter then times out every long reply and
the held tail lands in the next transaction.  The engine therefore adds
``extra`` seconds to every deadline and to the quiet time of a resync.

``extra`` is raised only by evidence that a reply was late, never by a
failure alone (a dead servo, noise, a reply cut short prove nothing).  Once
a transaction that was heard times out, its reply is *owed*, from its base
deadline on.  The evidence is the owed bytes turning up:

* in the resync right after the timeout, no more bytes than were missing
  (a held tail: :meth:`LinkLatency.stray`);
* in front of the echo of a later command, which follows them intact: a
  bridge keeps bytes in order, so a reply later than that resync comes
  before the next echo, and so do the echoes of commands sent while it was
  held back (:meth:`LinkLatency.judge`).

A transaction whose bytes start with its own echo shows the line is in step
again: nothing is owed any more.  ``extra`` is set to half as much again as
the lateness seen, and lowered by half after each window of transactions
that finished within their base allowance.  It never exceeds ``bound``, so a
dead servo still times out within its base allowance plus ``bound``; bytes
later than ``bound`` are not learnt from at all (no allowance within the
bound would have caught them, so raising it would only slow the line).
"""

from __future__ import annotations

import math

MARGIN = 1.5  # the allowance covers half as much again as the lateness seen...
JITTER = 0.001  # ...plus a millisecond for the loop's own jitter
MAX_BEHIND = 8  # commands remembered as sent while a reply was owed


class LinkLatency:
    """The allowance a slow link needs (``extra``), and the owed reply that may prove it."""

    __slots__ = ("_behind", "_needed", "_window", "bound", "extra", "late_replies", "owed", "owed_since", "window")

    def __init__(self, bound: float, window: int = 100) -> None:
        self.bound = bound  # the most the engine ever adds: a dead servo must still time out in bounded time
        self.window = window
        self.extra = 0.0
        self.late_replies = 0  # times late bytes were learnt from
        self.owed_since = math.inf  # when the earliest reply still owed was due, without extra (inf: none)
        self.owed = 0  # bytes of it that may still come in the resync right after its timeout
        self._behind: list[bytes] = []  # commands that got no byte at all while a reply was owed
        self._window = 0
        self._needed = False

    # ------------------------------------------------------------------ evidence

    def owe(self, due: float, missing: int, echoed: bool) -> None:
        """A heard transaction timed out ``missing`` bytes short; its reply was due at ``due``.

        ``echoed``: bytes of its own echo came first (or the line has no echo to tell), so this
        is the reply owed; else one owed from before still comes first.
        """
        if echoed or self.owed_since == math.inf:
            self.owed_since = due
            self._behind.clear()
        self.owed = missing

    def stray(self, count: int, now: float) -> None:
        """``count`` bytes arrived in the resync right after the timeout (only while ``owed`` > 0)."""
        owed = self.owed - count
        self.owed = owed
        if owed < 0:
            return  # more than the reply was missing: noise, not (only) a late tail
        self.late_by(now - self.owed_since)
        if owed == 0:
            self.in_step()  # the owed reply is complete

    def resync_over(self) -> None:
        """The resync after the timeout ended: owed bytes can only land in front of a later echo now."""
        self.owed = 0

    def in_step(self) -> None:
        """A transaction's bytes began with its own echo (or formed a valid reply): nothing is owed."""
        self.owed_since = math.inf
        self.owed = 0
        self._behind.clear()

    def judge(self, buf: bytearray, tx: bytes, echo_len: int, first_byte_at: float) -> None:
        """A transaction failed while a reply was owed: did that reply land in front of this echo?"""
        if not echo_len:
            return  # without an echo nothing tells a late tail from this reply
        if not buf:
            self._remember(tx)  # held back behind the owed reply, perhaps: its echo may show later
            return
        got = min(len(buf), echo_len)
        if buf[:got] == tx[:got]:
            self.in_step()
        elif any(_echo_offset(buf, sent) > 0 for sent in (tx, *self._behind)):
            self.late_by(first_byte_at - self.owed_since)
            self.in_step()
        else:
            self._remember(tx)

    def _remember(self, tx: bytes) -> None:
        if len(self._behind) < MAX_BEHIND:
            self._behind.append(tx)

    # ------------------------------------------------------------------ the allowance

    def late_by(self, seconds: float) -> None:
        """Bytes owed by a transaction arrived ``seconds`` after its deadline without ``extra``."""
        if seconds > self.bound:
            return  # an artefact of something else (or a link no bounded allowance can serve)
        self.late_replies += 1
        self._raise(seconds)
        self._window = 0
        self._needed = True

    def succeeded(self, over_base: float) -> None:
        """A transaction finished ``over_base`` seconds past what it would have been allowed without ``extra``."""
        if over_base > 0:
            self._needed = True
            self._raise(over_base)  # keep the margin as the link's lateness creeps up
        self._window += 1
        if self._window >= self.window:
            if not self._needed:
                self.extra = 0.0 if self.extra < 2 * JITTER else self.extra / 2
            self._window = 0
            self._needed = False

    def _raise(self, seconds: float) -> None:
        wanted = seconds * MARGIN + JITTER
        if wanted > self.extra:
            self.extra = min(self.bound, wanted)


def _echo_offset(buf: bytearray, tx: bytes) -> int:
    """Where, after the first byte, ``tx``'s echo starts in ``buf`` (at least its first two bytes if cut off); -1."""
    k = buf.find(tx, 1)
    if k > 0:
        return k
    n = len(buf)
    for k in range(max(1, n - len(tx) + 1), n - 1):
        if buf[k:] == tx[: n - k]:
            return k
    return -1
