"""The guard read: a harmless read between a timed-out command and the next command its reply would fit.

A reply that missed its deadline can still arrive right after the echo of
the next command.  If that command has the same command byte (a retry, a
one-servo stream), the late reply may have the right length and header and
be taken for the new answer: no check can see it.  So after a timeout the
engine remembers the command byte, and if the next command has it, a
parameter read with a different reply shape goes first, so late bytes fail
that read, not the real request.

A guard that times out is remembered by its whole reply shape (command byte
and sub-command) instead: the command it protects differs from it in
sub-command and goes straight on (a silent servo never loops through
guards), while another read of the guard's own shape gets a guard too, so
the guard's late reply cannot pass for its answer.

A command to a servo already found silent (``Timing.SILENT``: a closing
stream's free to an offline servo) goes without a guard read: its reply
would only confirm it, so a late one passing for it misleads nobody, while
the guard would wait a whole allowance.  The suspicion stays for the command
after it, and if that free times out too, its own suspicion joins the one it
went past rather than replacing it: the earlier reply may still come.
"""

from __future__ import annotations

from ..protocol import ReadParam, guard_read


class GuardRule:
    __slots__ = ("suspect",)

    def __init__(self) -> None:
        self.suspect: tuple[bytes, ...] = ()  # what a command may start with to fit a reply that may still come

    def timed_out(self, tx: bytes, *, heard: bool, was_guard: bool, went_past: bool = False) -> None:
        """A transaction timed out; ``heard``: its echo was right, so a servo may still answer.  ``went_past``: it
        went without the guard read the suspicion standing would have asked for (see above), so that stays."""
        if heard:
            shape = tx[:2] if was_guard else tx[:1]  # a guard is a parameter read: header + sub-command
            self.suspect = (*self.suspect, shape) if went_past else (shape,)

    def before(self, tx: bytes, servo_id: int | None) -> ReadParam | None:
        """The guard read to send before ``tx``, if it needs one (the suspicion lasts one command)."""
        suspect, self.suspect = self.suspect, ()
        if suspect and servo_id is not None and tx.startswith(suspect):
            return guard_read(tx, servo_id)
        return None
