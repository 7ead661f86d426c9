"""Requests in a paced stream's slack on a faulty line, in simulated time: what a failed read costs the loop.

A program reads temperatures beside a 12-servo stream at 100 Hz (the control
loop the library promises, as docs/how-to/control-loop.md runs it), each read
fitted into the slack between two cycles.  A read whose reply is lost must not
make the stream's next cycle miss its slot.  Plain calls and simulated time
(tests.support.paced_line): no event loop, no wall clock, so the figures are
exact and repeatable.
"""

from __future__ import annotations

from typing import Any

import pytest

from ics35_async import protocol
from ics35_async.engine import BusTiming, LineEngine, Priority
from ics35_async.engine.probe import FLOOR as STREAM_WAIT_FLOOR
from ics35_async.engine.probe import STREAM_RESYNC
from ics35_async.errors import ReplyTimeout
from tests.support.engine_support import BAUD as BAUD_115200
from tests.support.engine_support import FakeSource, Recorded, Servos, Wire, misattributed, ready_engine
from tests.support.paced_line import BAUD, IDS, PERIOD, DroppingServos, PacedCycle, Telemetry, run_with_telemetry

ADAPTER_3MS = BusTiming(adapter_latency=0.003)  # the control-loop page's line (an adapter's latency timer at 1 ms)
TIMINGS = pytest.mark.parametrize("timing", [ADAPTER_3MS, BusTiming()], ids=["adapter 3 ms", "adapter 20 ms"])


def paced_stream(timing: BusTiming) -> tuple[Wire, PacedCycle, Servos]:
    """The stream alone for half a second: this line's answers are learnt."""
    engine = LineEngine(baudrate=BAUD, timing=timing)
    assert engine.connected(0.0) is None
    servos = Servos(IDS, baudrate=BAUD, turnaround=0.0001)
    wire = Wire(engine, servos)
    source = PacedCycle(IDS, PERIOD)
    wire.emit(engine.attach_source(source, 0.0))
    wire.run_until(0.5)
    return wire, source, servos


def lost_read_in_the_slack(timing: BusTiming, before_slot: float) -> float:
    """A read asked ``before_slot`` seconds before a paced stream's slot, its echo coming and no reply: how late the
    cycle after it started (the read checked to have gone at once and failed with ReplyTimeout)."""
    wire, source, servos = paced_stream(timing)
    slot = source.t0 + source.cycle * PERIOD
    wire.run_until(slot - before_slot)
    cycles = len(source.late)
    servos.mute.add(len(servos.answers))  # the next write, the read's: its echo comes, no reply
    read = Recorded(protocol.ReadParam(3, protocol.Param.TEMPERATURE), wire=wire)
    wire.submit(read)
    wire.run_until(slot + 5 * PERIOD)
    assert isinstance(read.error, ReplyTimeout) and wire.writes[read.write_index][0] == slot - before_slot
    return source.late[cycles]


@TIMINGS
@pytest.mark.parametrize("before_slot", [0.008, 0.005, 0.001])
def test_a_read_fitted_into_the_slack_whose_reply_is_lost_leaves_the_next_cycle_under_half_a_period_late(
    timing: BusTiming, before_slot: float
) -> None:
    # Asked early in the slack, in its middle, and as late as it still fits (its wire time and what answers
    # take, a millisecond before the slot): its lost reply used to cost its full allowance and a whole quiet
    # time, past the slot.
    late = lost_read_in_the_slack(timing, before_slot)
    assert late < PERIOD / 2, f"the cycle after the read started {late * 1e3:.1f} ms after its slot"


@TIMINGS
@pytest.mark.parametrize("before_slot", [0.003, 0.002, 0.001])
def test_a_read_fitted_into_the_slack_whose_reply_is_lost_gives_up_at_the_slot(
    timing: BusTiming, before_slot: float
) -> None:
    # It fitted with a margin over what this line's answers take, so by the slot its reply is overdue: waiting
    # on (its allowance, or the stream's learnt wait) would only start the cycle later, by what that wait has
    # left.  Given up at the slot, the cycle waits only for the stream's short resync.
    late = lost_read_in_the_slack(timing, before_slot)
    assert late <= STREAM_RESYNC + 1e-9, f"the cycle after the read started {late * 1e3:.2f} ms after its slot"


def test_a_read_that_did_not_fit_the_slack_waits_its_whole_wait() -> None:
    # A stream whose cycles run past their slots leaves no slack: a read goes only once passed over in two
    # slots, delaying a cycle by design; the overdue slot is no reason to give up on it sooner.
    engine = LineEngine(baudrate=BAUD, timing=ADAPTER_3MS)
    assert engine.connected(0.0) is None
    servos = DroppingServos(IDS, 1.0, seed=1, reads_only=True)  # every read's reply lost, the stream's all come
    wire = Wire(engine, servos)
    source = PacedCycle(IDS, 0.002)  # twelve transactions take longer than that
    wire.emit(engine.attach_source(source, 0.0))
    wire.run_until(0.3)
    read = Recorded(protocol.ReadParam(3, protocol.Param.TEMPERATURE), wire=wire)
    wire.submit(read)
    wire.run_until(0.4)
    assert isinstance(read.error, ReplyTimeout)
    t_sent, tx = wire.writes[read.write_index]
    waited = wire.writes[read.write_index + 1][0] - t_sent
    nbytes = len(tx) + read.command.reply_len
    allowance = engine.timing.allowance(nbytes, engine.baudrate)
    assert waited >= min(allowance, protocol.wire_time(nbytes, BAUD) + STREAM_WAIT_FLOOR) - 1e-9


@TIMINGS
@pytest.mark.parametrize("seed", [1, 2])
def test_reads_in_the_slack_whose_replies_are_lost_cost_the_stream_no_slot(timing: BusTiming, seed: int) -> None:
    # 2 % of the reads' replies dropped (the stream's all come: its own failures are the stream's tests'),
    # the reads going on round the servos, each one that timed out left alone for a second as the page's
    # telemetry does.
    source, telemetry, _ = run_with_telemetry(0.02, seed, timing, seconds=10.0, reads_only=True, leave_alone=1.0)
    lost = sum(isinstance(read.error, ReplyTimeout) for read in telemetry.reads)
    assert lost > 100 and len(telemetry.reads) > 5000  # the reads went on, and their faults did happen
    assert source.missed == 0, f"{source.missed} slots missed, latest start {max(source.late) * 1e3:.1f} ms late"


# ---------------------------------------------------------------- what the short wait must never do


class LateReply(Servos):
    """Servos that answer the first write of ``tx`` at or after ``after`` ``delay`` seconds late (``late_write``:
    its number); each answer otherwise fresh, so a reply taken for another's shows."""

    def __init__(self, ids: list[int], *, echo: bool, tx: bytes, after: float, delay: float) -> None:
        super().__init__(ids, echo=echo)
        self.tx, self.after, self.delay = tx, after, delay
        self.late_write: int | None = None

    def deliver(self, wire: Wire, tx: bytes, reply: bytes) -> None:
        k = len(self.answers) - 1
        at = wire.now + protocol.wire_time(len(tx) + len(reply), self.baudrate) + self.turnaround
        if self.late_write is None and tx == self.tx and wire.now >= self.after:
            self.late_write = k
            at += self.delay
        wire.schedule(at, reply, tag=k)


def beside_a_paced_stream(servos: Servos, echo: bool = True) -> tuple[Wire, FakeSource, list[tuple[int, int]]]:
    """A paced stream round servos 1 and 2 (one transaction a 4 ms slot), its answers learnt by 0.2 s; ``taken``
    lists (write, value) for each value it took."""
    engine = ready_engine(echo)
    wire = Wire(engine, servos)
    source = FakeSource([1, 2], wake_at=0.0, period=0.004, paced=True)
    taken: list[tuple[int, int]] = []
    source.on_value = lambda sid, value: taken.append((len(wire.writes) - 1, value))
    wire.emit(engine.attach_source(source, 0.0))
    wire.run_until(0.2)
    return wire, source, taken


@pytest.mark.parametrize("echo", [True, False], ids=["echo", "no echo"])
@pytest.mark.parametrize("delay", [0.003, 0.008, 0.015, 0.025, 0.030, 0.0305, 0.031, 0.0315, 0.04])
def test_a_held_reads_late_reply_is_never_taken_for_another_answer(echo: bool, delay: float) -> None:
    # Reads round servos 1-3 with a retry each, beside the stream; one read of servo 2 is answered late: within
    # its hold (its full allowance and a quiet time, about 31 ms here), just around the hold's end, and after it.
    # Wherever that reply lands (the stream's transactions, other reads, its own retry, a guard read), it must
    # fail what it lands in or be dropped, never be taken for another answer.
    servos = LateReply(
        [1, 2, 3], echo=echo, tx=protocol.ReadParam(2, protocol.Param.TEMPERATURE).tx, after=0.3, delay=delay
    )
    wire, _, taken = beside_a_paced_stream(servos, echo)
    telemetry = Telemetry(wire, [1, 2, 3], retries=1)
    telemetry.start(wire.now)
    wire.run_until(0.6)
    late = servos.late_write
    assert late is not None  # the scene happened
    wrong = [(k, v, servos.answers[k]) for k, v in taken if v != servos.answers[k]]
    assert not wrong, f"stream: (write, value taken, value that write was answered) {wrong}"
    problems = [problem for read in telemetry.reads if read.state == "done" if (problem := misattributed(read, servos))]
    assert not problems, problems
    assert len(taken) > 100 and sum(read.state == "done" for read in telemetry.reads) > 100  # the line went on


def test_a_held_reads_retry_waits_for_the_hold_while_the_stream_goes_on() -> None:
    servos = Servos([1, 2, 3])
    wire, source, taken = beside_a_paced_stream(servos)
    engine = wire.engine
    wire.run_until(source.wake_at + 0.001)  # in the slack after the slot's transaction
    first = len(servos.answers)
    servos.mute.add(first)  # the read's first attempt: its echo comes, no reply
    read = Recorded(protocol.ReadParam(3, protocol.Param.TEMPERATURE), retries=1, wire=wire)
    wire.submit(read)
    assert engine.deadline < wire.now + engine.timing.allowance(5, engine.baudrate)  # the learnt wait, not all
    streamed = len(taken)
    wire.run_until(wire.now + 0.1)
    assert read.state == "done" and misattributed(read, servos) is None
    t_first, tx = wire.writes[first]
    retry = next(k for k in range(first + 1, len(wire.writes)) if wire.writes[k][1] == tx)
    hold = engine.timing.allowance(5, engine.baudrate) + engine.timing.quiet_time
    assert wire.writes[retry][0] >= t_first + hold - 1e-9
    assert any(first < k < retry for k, _ in taken[streamed:])  # the stream went on meanwhile


def lost_reply_beside_a_paced_stream(
    command: protocol.Command[Any], priority: Priority = Priority.NORMAL, paced: bool = True
) -> tuple[Wire, Recorded, float]:
    """``command``, its reply lost, asked in the slack of a paced stream (or beside an unpaced one) whose answers
    are learnt; returns the wire, the request and the deadline it got."""
    servos = Servos([1, 2, 3])
    wire, source, _ = beside_a_paced_stream(servos)
    source.paced = paced
    wire.run_until(source.wake_at + 0.001)  # in the slack after the slot's transaction
    servos.mute.add(len(servos.answers))
    request = Recorded(command, priority, wire=wire)
    assert wire.submit(request) == command.tx  # at once
    deadline = wire.engine.deadline
    wire.run_until(wire.now + 0.1)
    assert isinstance(request.error, ReplyTimeout)
    return wire, request, deadline


@pytest.mark.parametrize(
    ("command", "priority", "paced"),
    [
        (protocol.ReadParam(3, protocol.Param.TEMPERATURE), Priority.URGENT, True),
        (protocol.ReadParam(3, protocol.Param.TEMPERATURE), Priority.NORMAL, False),
        (protocol.WriteParam(3, protocol.Param.SPEED, 100), Priority.NORMAL, True),
        (protocol.Position(3, 7500, baudrate=BAUD_115200), Priority.NORMAL, True),
        (protocol.SecondLookRead(3), Priority.NORMAL, True),
    ],
    ids=["urgent read", "read beside an unpaced stream", "write", "position", "a scan's second look"],
)
def test_other_requests_wait_their_whole_allowance_and_a_quiet_time(
    command: protocol.Command[Any], priority: Priority, paced: bool
) -> None:
    # Only a read below URGENT in a paced stream's slack waits less: an URGENT request takes the line whatever
    # the slot, an unpaced stream has no slot to keep, a command that changes something is not given up on
    # sooner, and a read whose silence is an answer waits its whole allowance by its nature.
    wire, request, deadline = lost_reply_beside_a_paced_stream(command, priority, paced)
    engine = wire.engine
    t, tx = wire.writes[request.write_index]
    assert deadline == pytest.approx(t + engine.timing.allowance(len(tx) + command.reply_len, engine.baudrate))
    assert wire.writes[request.write_index + 1][0] >= deadline + engine.timing.quiet_time - 1e-9
