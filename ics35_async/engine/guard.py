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

A command that got nothing back at all, not even its echo (a far end that
stalls: an adapter or a bridge holding bytes, a simulator not yet scheduled),
says nothing of the line: its echo and reply may still come whole, and with
them those of any command before it that got nothing either.  Such commands are
remembered (``unheard``, in the order last sent) until a command's own echo
comes back: bytes come in order, so nothing older can still come after it.
Until then a command identical to one of them would take that one's echo and
reply for its own, and gets a guard read first, itself identical to none of
them: a guard that took a remembered twin's echo and reply for its own would
clear the commands remembered after that twin, whose bytes may still come.  So
with both of that servo's guard reads remembered, the guard is a twin of the
last command remembered if that is one of them (taking its echo and reply shows
that every older one's came first, and none remembered went after it), otherwise a
read of another servo (a late reply from this one fails it by its header; see
:func:`~ics35_async.protocol.guard_read`).  A guard read that gets no echo of its
own back either (nothing, or only bytes not its own: another servo answering
without echo) shows nothing, and counts as one of the tries of the command it
went before (see the engine), so a line that answers nothing (or nothing of its
own) still fails that command after its tries.  (On a line without echo nothing
tells a stall from a silent servo: the rule is for lines with echo.)

A command to a servo already found silent (``Timing.SILENT``: a closing
stream's free to an offline servo) goes without a guard read: its reply
would only confirm it, so a late one passing for it misleads nobody, while
the guard would wait a whole allowance.  The suspicion stays for the command
after it, and if that free times out too, its own suspicion joins the one it
went past rather than replacing it: the earlier reply may still come.
"""

from __future__ import annotations

from ..protocol import ReadParam, guard_read

UNHEARD_KEPT = 32  # commands without their echo remembered (a 32-servo stream's cycle); the oldest go first


class GuardRule:
    __slots__ = ("suspect", "unheard")

    def __init__(self) -> None:
        self.suspect: tuple[bytes, ...] = ()  # what a command may start with to fit a reply that may still come
        self.unheard: tuple[bytes, ...] = ()  # commands sent whose echo has not come back since the last that did

    def timed_out(self, tx: bytes, *, heard: bool, was_guard: bool, went_past: bool = False) -> None:
        """A transaction timed out; ``heard``: its echo was right, so a servo may still answer.  ``went_past``: it
        went without the guard read the suspicion standing would have asked for (see above), so that stays."""
        if heard:
            shape = tx[:2] if was_guard else tx[:1]  # a guard is a parameter read: header + sub-command
            self.suspect = (*self.suspect, shape) if went_past else (shape,)

    def echo_came(self, tx: bytes, came: bool) -> None:
        """A transaction that sent ``tx`` ended; ``came``: its own echo came back (first, or behind bytes
        that were already on their way), so nothing sent before it can still come after it; only its own
        bytes, if those were another command's identical ones (see above)."""
        unheard = self.unheard
        if came:
            self.unheard = (tx,) if tx in unheard else ()
        else:  # (kept in the order last sent: a guard may be a twin of the last one, see above)
            if tx in unheard:
                unheard = tuple(u for u in unheard if u != tx)
            self.unheard = (*unheard[1 - UNHEARD_KEPT :], tx) if len(unheard) >= UNHEARD_KEPT else (*unheard, tx)

    def before(self, tx: bytes, servo_id: int | None) -> ReadParam | None:
        """The guard read to send before ``tx``, if it needs one (the suspicion of a late reply lasts one
        command; that of a command whose echo never came, until an echo comes)."""
        suspect, self.suspect = self.suspect, ()
        if servo_id is not None and (tx.startswith(suspect) or tx in self.unheard):
            return guard_read(tx, servo_id, self.unheard)
        return None
