"""How long to wait where silence is likely or costly: learnt from the answers this link has given.

A scan or an ID write's survey probes 32 IDs, most of them empty, so a
probe's usual outcome is silence and its cost is the whole wait.  The
normal allowance covers the adapter's worst case (20 ms by default); a
probe (``Timing.PROBE``) instead waits its wire time plus ``latency``:
twice the slowest answer beyond wire time seen since the port opened, plus
a millisecond, never under ``FLOOR`` and never over the normal allowance.
Until something has answered (a fresh port, a new baud rate) a probe gets
the normal allowance.

A probe that timed out with no reply bytes is followed by a resync of
``latency`` (plus the link's learnt extra) instead of the full quiet time.
The link's own bookkeeping still measures against the normal allowance: a
probe answered after its short wait but in time says nothing of the link.  A servo answering later
than that is not lost silently: its bytes arrive as strays (or in front of
the next echo, failing that probe), and the scan policy then probes its
silent IDs again with the normal allowance (see
:func:`ics35_async.policies.probe_ids`).

A stream transaction waits the same way (:meth:`AnswerTimes.stream_allowance`),
so a dropped or garbled reply costs a paced stream a few milliseconds instead
of the adapter's worst case and its cycle keeps its slot: twice what that
servo's answers usually take (an average leaning high), plus a millisecond,
never under ``STREAM_FLOOR``.  A reply that comes after that short wait but
within the full allowance is taken as an answer (:meth:`AnswerTimes.late`), so
a servo that is always slower soon has a wait that covers it; one later than
the full allowance is a fault and teaches nothing.  The resync after such a
failure keeps the configured quiet time: a reply later than the short wait must
land in it (or in the guard read after it), never in a later transaction of the
same shape, where nothing could tell it from that transaction's own answer.
The same averages tell the engine whether a request fits in a paced
stream's slack (see ``LineEngine._start_next``).
"""

from __future__ import annotations

FLOOR = 0.004  # seconds: the least a probe waits beyond its wire time (a loop or VM hiccup)
STREAM_FLOOR = 0.002  # ...and a stream transaction: the stream's cycle must keep its slot
FACTOR = 2.0
MARGIN = 0.001
RISE, FALL = 0.3, 0.05  # how fast an expected answer time follows slower / faster answers
IDS = 33  # servo IDs 0..31, and the ID command's slot (counters.NO_ID)


class AnswerTimes:
    """What answers on this line take beyond their wire time: the slowest, and what is usual
    (line-wide and per servo)."""

    __slots__ = ("by_id", "expected", "slowest")

    def __init__(self) -> None:
        self.slowest = -1.0  # the slowest answer beyond its wire time (s); negative: none seen yet
        self.expected = -1.0  # what an answer usually takes beyond its wire time, leaning high
        self.by_id = [-1.0] * IDS  # the same, per servo

    def reset(self) -> None:
        """A fresh port or baud rate: what the old one showed proves nothing."""
        self.slowest = self.expected = -1.0
        self.by_id = [-1.0] * IDS

    def answered(self, beyond_wire: float, servo_id: int) -> None:
        """Servo ``servo_id`` answered ``beyond_wire`` seconds after its bytes' wire time."""
        beyond_wire = max(0.0, beyond_wire)  # a fast simulator can beat the wire time
        if beyond_wire > self.slowest:
            self.slowest = beyond_wire
        # Averages that follow slower answers quickly and faster ones slowly: they sit near the
        # high end of what answers take, and a one-off hiccup fades within a few dozen answers.
        self.expected = _follow(self.expected, beyond_wire)
        self.by_id[servo_id] = _follow(self.by_id[servo_id], beyond_wire)

    def late(self, beyond_wire: float, servo_id: int) -> None:
        """A stream transaction's reply came ``beyond_wire`` seconds after its wire time, after its
        short wait but within the full allowance (as stray bytes, or ahead of a later echo): taken
        as an answer (see the module docstring)."""
        self.answered(beyond_wire, servo_id)

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

    def stream_latency(self, servo_id: int | None = None) -> float | None:
        """Seconds a stream transaction to ``servo_id`` waits beyond its wire time (line-wide without
        an ID, or for a servo not heard yet); None until something has answered."""
        expected = self.expected if servo_id is None or self.by_id[servo_id] < 0 else self.by_id[servo_id]
        if expected < 0:
            return None
        return max(STREAM_FLOOR, FACTOR * expected + MARGIN)

    def stream_allowance(self, normal: float, wire: float, servo_id: int) -> float:
        """A stream transaction's allowance: its wire time plus :meth:`stream_latency`, at most ``normal``."""
        latency = self.stream_latency(servo_id)
        return normal if latency is None else min(normal, wire + latency)


def _follow(expected: float, answer: float) -> float:
    if expected < 0:
        return answer
    return expected + (answer - expected) * (RISE if answer > expected else FALL)
