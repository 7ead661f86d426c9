"""How long to wait where silence is likely or costly: learnt from the answers this link has given.

A scan or an ID write's survey probes 32 IDs, most of them empty, so a
probe's usual outcome is silence and its cost is the whole wait.  The
normal allowance covers the adapter's worst case (20 ms by default); a
probe (``Timing.PROBE``) instead waits its wire time plus ``latency``:
twice the slowest answer beyond wire time seen since the port opened, plus
a millisecond, never under ``FLOOR`` and never over the normal allowance.
Until something has answered (a fresh port, a new baud rate) a probe gets
the normal allowance; a command to a servo already found silent
(``Timing.SILENT``: a closing stream's free to an offline servo) waits its
wire time plus ``FLOOR`` and a millisecond then: its silence has cost the whole
allowance already.  A stream's probe of an offline servo waits as the stream's
other transactions do (its answer brings the servo back), but no longer than
that once its stream has left with it on the wire: nobody hears its answer
then (see ``LineEngine.detach_source``).

As the stream's wait (below), a probe's is for silence after the echo: one whose echo has not come
round by then waits the normal allowance (an FTDI adapter's latency timer holds an echo and its reply
together; a servo given up on that way was taken for absent).

A probe that timed out with no reply bytes is followed by a resync of
``latency`` (plus the link's learnt extra) instead of the full quiet time.
The link's own bookkeeping still measures against the normal allowance: a
probe answered after its short wait but in time says nothing of the link.  A servo answering later
than that is not lost silently: its bytes arrive as strays (or in front of
the next echo, failing that probe), and the scan policy then probes its
silent IDs again with the normal allowance (see
:func:`ics35_async.policies.probe_ids`).

The same answers tell the engine whether a request fits in a paced stream's
slack (see ``LineEngine._start_next``): ``expected`` is what an answer usually
takes beyond its wire time, an average that leans high.

And they set the stream's wait (``stream_latency``): like a probe's, but from
the last ``RECENT`` answers instead of all, and from the ``OUTLIERS + 1``-th
slowest of them rather than the slowest, and only once ``RECENT_MIN`` answers
have been seen.  A hiccup of the host (a garbage collection, a loaded
machine) makes one answer slow, and its echo with it; taken as the norm it
would set the wait past the full allowance, and every failure would then cost
the control loop the full allowance until 256 answers had passed: minutes,
when a servo fails every time it is asked and each failure costs that much.
Twice a slow recent answer (not a median) keeps a healthy servo's failing
for being slow rare: a stream transaction that gave up early holds its servo
back, with no command, for the rest of its allowance (see
``LineEngine._hold``); a reply later than the wait fails whatever it lands in,
never passes for another answer.  It gives up early only once its echo has
come round: until then the host or the link is late, not the servo (a silent
servo still echoes), and it waits the full allowance.  A read in a paced
stream's slack waits as the stream's transactions do (see
``LineEngine._in_slack``).
"""

from __future__ import annotations

FLOOR = 0.004  # seconds: the least a probe waits beyond its wire time (a loop or VM hiccup)
FACTOR = 2.0
MARGIN = 0.001
RISE, FALL = 0.3, 0.05  # how fast the expected answer time follows slower / faster answers
RECENT = 256  # answers the stream's wait is measured from
RECENT_MIN = 8  # answers seen before the stream waits less than the full allowance
OUTLIERS = 2  # the slowest recent answers the stream's wait leaves out (host hiccups)
REFRESH = 32  # answers between two updates of the stream's wait (a pass over RECENT floats)
# The silence that ends the resync after a stream transaction that gave up early: its reply, had it
# been coming, would most likely have come by then (it waited twice what answers take), and if it
# comes later it can only fail what it lands in (see LineEngine._hold).  A millisecond lets bytes
# already on their way (one more USB frame) arrive inside the resync.
STREAM_RESYNC = 0.001


class AnswerTimes:
    """What answers on this line take beyond their wire time: the slowest, and what is usual."""

    __slots__ = ("_n", "_recent", "expected", "slowest", "stream_latency")

    def __init__(self) -> None:
        self.slowest = -1.0  # the slowest answer beyond its wire time (s); negative: none seen yet
        self.expected = -1.0  # what an answer usually takes beyond its wire time, leaning high
        self.stream_latency: float | None = None  # seconds the stream waits beyond wire time (None: full)
        self._recent: list[float] = []
        self._n = 0

    def reset(self) -> None:
        """A fresh port or baud rate: what the old one showed proves nothing."""
        self.slowest = self.expected = -1.0
        self.stream_latency = None
        self._recent.clear()
        self._n = 0

    def answered(self, beyond_wire: float) -> None:
        """A request was answered ``beyond_wire`` seconds after its bytes' wire time."""
        beyond_wire = max(0.0, beyond_wire)  # a fast simulator can beat the wire time
        if beyond_wire > self.slowest:
            self.slowest = beyond_wire
        # An average that follows slower answers quickly and faster ones slowly: it sits near the
        # high end of what answers take, and a one-off hiccup fades within a few dozen answers.
        recent = self._recent
        if len(recent) < RECENT:
            recent.append(beyond_wire)
        else:
            recent[self._n % RECENT] = beyond_wire
        self._n += 1
        if self._n % REFRESH == 0 or self._n == RECENT_MIN:
            # (RECENT_MIN answers at least: more than OUTLIERS; sorted() is one C call, where heapq.nlargest loops
            # in Python over every answer: a tenth of a burst-path stream's loop time, once every REFRESH answers)
            slow = sorted(recent)[-1 - OUTLIERS]
            self.stream_latency = max(FLOOR, FACTOR * slow + MARGIN)
        expected = self.expected
        if expected < 0:
            self.expected = beyond_wire
        else:
            self.expected = expected + (beyond_wire - expected) * (RISE if beyond_wire > expected else FALL)

    def answers_before_change(self) -> int:
        """How many more answers leave :attr:`stream_latency` as it is: the one after that many may
        recompute it (never below ``FLOOR``)."""
        n = self._n
        change = (n // REFRESH + 1) * REFRESH
        if n < RECENT_MIN:
            change = min(change, RECENT_MIN)
        return change - n

    @property
    def latency(self) -> float | None:
        """Seconds a probe waits beyond its wire time; None until something has answered."""
        if self.slowest < 0:
            return None
        return max(FLOOR, FACTOR * self.slowest + MARGIN)

    def allowance(self, normal: float, wire: float) -> float:
        """A probe's allowance: its wire time plus :attr:`latency`, never more than ``normal``."""
        latency = self.latency
        return normal if latency is None else min(normal, wire + latency)

    def silent_allowance(self, normal: float, wire: float) -> float:
        """The allowance of a command to a servo already found silent (``Timing.SILENT``): a probe's, but the
        least one (``FLOOR`` and a millisecond) until something has answered, not ``normal``.  Its reply would
        only confirm what the command did, and its silence has already cost the whole allowance: on a line where
        nothing answers (an unplugged line) waiting that once more for each such servo only delays the program's
        end."""
        latency = self.latency
        return min(normal, wire + (FLOOR + MARGIN if latency is None else latency))
