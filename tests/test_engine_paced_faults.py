"""A paced stream on a faulty line, in simulated time: what a failure costs the control loop.

Twelve servos at 100 Hz on a 1.25 Mbit/s line (the control loop the library
promises), with replies dropped, cut short, garbled or late.  A failure must
cost what the line has shown its answers take, not the adapter's worst-case
allowance, so the loop keeps its rate; an offline servo leaves no long gap.
Plain calls and simulated time (tests.support.paced_line): no event loop, no
wall clock, so the figures are exact and repeatable.
"""

from __future__ import annotations

import pytest

from ics35_async import protocol
from ics35_async.engine import BusTiming, LineEngine
from tests.support.engine_support import Servos, Wire
from tests.support.paced_line import BAUD, IDS, PERIOD, PacedCycle, intervals, run


@pytest.mark.parametrize("seed", [1, 2, 3])
@pytest.mark.parametrize(("quiet_time", "floor_hz"), [(0.005, 95), (None, 80)], ids=["quiet 5 ms", "default quiet"])
def test_at_five_percent_faults_the_loop_holds_its_rate(seed: int, quiet_time: float | None, floor_hz: float) -> None:
    # A failure costs the stream's short wait plus the resync's quiet time, which stays the configured
    # one (a late reply must land in it, never in a later transaction of the same shape): at the
    # default 10 ms the loop holds about 82 Hz; with quiet_time=0.005 it holds its 100 Hz slots.
    timing = BusTiming(quiet_time=quiet_time) if quiet_time is not None else None
    source = run(0.05, seed, timing=timing)
    rate = (len(source.starts) - 1) / (source.starts[-1] - source.starts[0])
    assert source.failed > 200  # the faults did happen
    assert rate >= floor_hz, f"{rate:.1f} Hz, {source.failed} failures"


def test_a_clean_line_holds_the_rate_exactly() -> None:
    source = run(0.0, 1, seconds=2.0)
    assert source.failed == 0
    assert max(intervals(source)) == pytest.approx(PERIOD)


def test_an_offline_servo_leaves_no_interval_above_one_and_a_half_periods() -> None:
    # The stream keeps offering ID 12's transaction (the real stream probes it every 0.5 s; here
    # every cycle, the harder case): each costs only what this line's answers take.
    source = run(0.0, 1, present=IDS[:-1], seconds=3.0)
    assert source.failed > 100
    assert max(intervals(source)) <= 1.5 * PERIOD + 1e-9, max(intervals(source))


def test_a_servo_always_slower_than_the_measured_wait_is_learnt_not_failed_forever() -> None:
    # One servo answers 6 ms late, inside the configured 20 ms allowance: after a failure or two
    # the stream's wait covers it, and its replies are taken again.
    engine = LineEngine(baudrate=BAUD, timing=BusTiming())
    assert engine.connected(0.0) is None

    class OneSlow(Servos):
        def deliver(self, wire: Wire, tx: bytes, reply: bytes) -> None:
            slow = 0.006 if tx[0] & 0x1F == 5 else 0.0
            wire.schedule(wire.now + protocol.wire_time(len(tx) + len(reply), BAUD) + 0.0001 + slow, reply)

    wire = Wire(engine, OneSlow(IDS, baudrate=BAUD))
    source = PacedCycle(IDS, PERIOD)
    wire.emit(engine.attach_source(source, 0.0))
    wire.run_until(2.0)
    assert 0 < source.failed <= 3
