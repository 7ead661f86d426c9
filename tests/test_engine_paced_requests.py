"""Requests in a paced stream's slack on a faulty line, in simulated time: what a failed read costs the loop.

A program reads temperatures beside a 12-servo stream at 100 Hz (the control
loop the library promises, as docs/how-to/control-loop.md runs it), each read
fitted into the slack between two cycles.  A read whose reply is lost must not
make the stream's next cycle miss its slot.  Plain calls and simulated time
(tests.support.paced_line): no event loop, no wall clock, so the figures are
exact and repeatable.
"""

from __future__ import annotations

import pytest

from ics35_async import protocol
from ics35_async.engine import BusTiming, LineEngine
from ics35_async.errors import ReplyTimeout
from tests.support.engine_support import Recorded, Servos, Wire
from tests.support.paced_line import BAUD, IDS, PERIOD, PacedCycle, run_with_telemetry

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


@TIMINGS
@pytest.mark.parametrize("before_slot", [0.008, 0.005, 0.001])
def test_a_read_fitted_into_the_slack_whose_reply_is_lost_leaves_the_next_cycle_under_half_a_period_late(
    timing: BusTiming, before_slot: float
) -> None:
    # Asked early in the slack, in its middle, and as late as it still fits (its wire time and what answers
    # take, a millisecond before the slot): its lost reply used to cost its full allowance and a whole quiet
    # time, past the slot.
    wire, source, servos = paced_stream(timing)
    slot = source.t0 + source.cycle * PERIOD
    wire.run_until(slot - before_slot)
    cycles = len(source.late)
    servos.mute.add(len(servos.answers))  # the next write, the read's: its echo comes, no reply
    read = Recorded(protocol.ReadParam(3, protocol.Param.TEMPERATURE), wire=wire)
    wire.submit(read)
    wire.run_until(slot + 5 * PERIOD)
    assert isinstance(read.error, ReplyTimeout) and wire.writes[read.write_index][0] == slot - before_slot
    late = source.late[cycles]
    assert late < PERIOD / 2, f"the cycle after the read started {late * 1e3:.1f} ms after its slot"


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
