"""The guard read: a harmless read between a timed-out command and its twin.

A reply that missed its deadline can still arrive right after the echo of
the next command.  If that command has the same command byte (a retry, a
one-servo stream), the late reply has the right length and header and would
be taken for the new answer: no check can see it.  So after a timeout the
engine remembers the command byte, and if the next command has it, a
parameter read with a different reply shape goes first, so late bytes fail
that read, not the real request.  A guard that times out arms no further
guard: its own late reply always differs in shape from the command it
protects.
"""

from __future__ import annotations

from ..protocol import ReadParam, guard_read


class GuardRule:
    __slots__ = ("suspect",)

    def __init__(self) -> None:
        self.suspect = -1  # command byte of a timed-out command whose reply may still come

    def timed_out(self, tx: bytes, *, heard: bool, was_guard: bool) -> None:
        """A transaction timed out; ``heard``: its echo was right, so a servo may still answer."""
        if heard and not was_guard:
            self.suspect = tx[0]

    def before(self, tx: bytes, servo_id: int | None) -> ReadParam | None:
        """The guard read to send before ``tx``, if it needs one (the suspicion lasts one command)."""
        suspect, self.suspect = self.suspect, -1
        if tx[0] == suspect and servo_id is not None:
            return guard_read(tx, servo_id)
        return None
