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
the lateness seen, and lowered by half after each window of transactions in
which fewer than one in ``RARE`` needed it: a slow link delays most replies,
while a servo that answers late now and then (a faulty line) must not keep
every deadline and resync longer for good.  It never exceeds ``bound``, so a
dead servo still times out within its base allowance plus ``bound``; bytes
later than ``bound`` are not learnt from at all (no allowance within the
bound would have caught them, so raising it would only slow the line).
"""

from __future__ import annotations

import math

from ..protocol.wire import echo_offset

MARGIN = 1.5  # the allowance covers half as much again as the lateness seen...
JITTER = 0.001  # ...plus a millisecond for the loop's own jitter
MAX_BEHIND = 8  # commands remembered as sent while a reply was owed
RARE = 10  # fewer than one in RARE transactions of a window needing the extra: it is halved


class LinkLatency:
    """The allowance a slow link needs (``extra``), and the owed reply that may prove it."""

    __slots__ = (
        "_header",
        "_missing",
        "_needed",
        "_unechoed",
        "_window",
        "bound",
        "extra",
        "late_replies",
        "owed",
        "owed_since",
        "window",
    )

    def __init__(self, bound: float, window: int = 100) -> None:
        self.bound = bound  # the most the engine ever adds: a dead servo must still time out in bounded time
        self.window = window
        self.extra = 0.0
        self.late_replies = 0  # times late bytes were learnt from
        self.owed_since = math.inf  # when the earliest reply still owed was due, without extra (inf: none)
        self.owed = 0  # bytes of it that may still come in the resync right after its timeout
        self._missing = 0  # bytes the owed reply lacks (0: unknown)
        self._header = -1  # its 7-bit header, when none of it came (-1: no check)
        self._unechoed: list[bytes] = []  # commands sent while a reply was owed whose echo has not come
        self._window = 0
        self._needed = 0  # transactions of this window that needed the extra

    # ------------------------------------------------------------------ evidence

    def owe(self, due: float, tx: bytes, got: int, echo_len: int, expect: int) -> None:
        """A heard transaction timed out with ``got`` of its ``expect`` bytes; its reply was due at ``due``."""
        if got or not echo_len:
            # Its echo came (or the line has none to tell): this is the reply owed now.
            self._owe(due, expect - got, tx[0] & 0x7F if got == echo_len else -1)
        elif self.owed_since == math.inf:
            self._owe(due, 0, -1)  # nothing came at all: only its echo, when it comes, will show it
            self._unechoed.append(tx)
        elif len(self._unechoed) < MAX_BEHIND:
            self._unechoed.append(tx)  # held back behind the reply owed before
        self.owed = expect - got

    def stray(self, data: bytes, now: float) -> None:
        """Bytes arrived in the resync right after a timeout (only while ``owed`` > 0)."""
        owed = self.owed - len(data)
        if owed < 0 or (self._header >= 0 and self.owed == self._missing and data[0] & 0x7F != self._header):
            self.owed = 0
            return  # more than the reply lacked, or not its header: noise, not (only) a late reply
        self.owed = owed
        self.late_by(now - self.owed_since)
        if owed == 0:
            self.in_step()  # the owed reply is complete

    def resync_over(self) -> None:
        """The resync after the timeout ended: owed bytes can only land in front of a later echo now."""
        self.owed = 0

    def in_step(self) -> None:
        """A transaction's bytes began with its own echo (or formed a valid reply): nothing is owed."""
        self.owed_since = math.inf
        self.owed = self._missing = 0
        self._unechoed.clear()

    def judge(
        self,
        buf: bytearray,
        tx: bytes,
        echo_len: int,
        expect: int,
        first_byte_at: float,
        due: float,
        unheard: tuple[bytes, ...],
    ) -> None:
        """A transaction failed while a reply was owed: did owed bytes land in front of its echo?

        Owed bytes are recognised by where they sit: this command's echo after them, the
        echo of a command that got nothing while the reply was owed (or of one still owed
        its echo: ``unheard``, see .guard), or exactly the bytes the owed reply lacked (its
        header first, if none of it came) followed by an echo.
        """
        if not echo_len or not buf:
            return  # without an echo nothing tells a late tail from this reply; no bytes, no news
        got = min(len(buf), echo_len)
        if buf[:got] == tx[:got]:
            self.in_step()
            return
        ours = echo_offset(buf, tx, 1)
        if not (
            ours > 0
            or any(echo_offset(buf, sent, 0) >= 0 for sent in (*self._unechoed, *unheard))
            or self._lacked_bytes_first(buf, tx)
        ):
            if len(self._unechoed) < MAX_BEHIND:
                self._unechoed.append(tx)  # a damaged echo, noise... or held back: its echo may show later
            return
        self.late_by(first_byte_at - self.owed_since)
        if 0 < ours <= len(buf) - echo_len:
            self.in_step()  # everything before this echo has come
        else:
            self._owe(due, 0, -1)  # this command's own bytes are still behind what came
            self._unechoed.append(tx)
            self.owed = expect

    def _owe(self, due: float, missing: int, header: int) -> None:
        self.owed_since = due
        self._missing = missing
        self._header = header
        self._unechoed.clear()

    def _lacked_bytes_first(self, buf: bytearray, tx: bytes) -> bool:
        m = self._missing
        if not m or len(buf) < m or (self._header >= 0 and buf[0] & 0x7F != self._header):
            return False
        rest = bytes(buf[m:])
        return any(sent[: len(rest)] == rest[: len(sent)] for sent in (tx, *self._unechoed))

    # ------------------------------------------------------------------ the allowance

    def late_by(self, seconds: float) -> None:
        """Bytes owed by a transaction arrived ``seconds`` after its deadline without ``extra``."""
        if seconds > self.bound:
            return  # an artefact of something else (or a link no bounded allowance can serve)
        self.late_replies += 1
        self._raise(seconds)
        self._window = 0
        self._needed = 1

    def succeeded(self, over_base: float) -> None:
        """A transaction finished ``over_base`` seconds past what it would have been allowed without ``extra``."""
        if over_base > 0:
            self._needed += 1
            self._raise(over_base)  # keep the margin as the link's lateness creeps up
        self._window += 1
        if self._window >= self.window:
            if self._needed * RARE < self.window:
                self.extra = 0.0 if self.extra < 2 * JITTER else self.extra / 2
            self._window = 0
            self._needed = 0

    def _raise(self, seconds: float) -> None:
        wanted = seconds * MARGIN + JITTER
        if wanted > self.extra:
            self.extra = min(self.bound, wanted)
