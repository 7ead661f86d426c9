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

from ics35_async.engine import BusTiming
from tests.support.paced_line import IDS, PERIOD, intervals, run

# The goals below are not met yet: a failed stream transaction still costs its full allowance
# (20 ms by default) plus the quiet time.  A shorter, measured wait was tried and taken out: a reply
# later than it but within the full allowance could land in a later transaction to the same servo
# (found by the model test and in review).  strict=True: these fail loudly once the goal is met.
GOAL_NOT_MET = pytest.mark.xfail(strict=True, reason="a failure still costs the full allowance and the quiet time")


@GOAL_NOT_MET
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_at_five_percent_faults_the_loop_holds_95_hz(seed: int) -> None:
    source = run(0.05, seed, timing=BusTiming(quiet_time=0.005))
    rate = (len(source.starts) - 1) / (source.starts[-1] - source.starts[0])
    assert source.failed > 100  # the faults did happen
    assert rate >= 95, f"{rate:.1f} Hz, {source.failed} failures"


def test_a_clean_line_holds_the_rate_exactly() -> None:
    source = run(0.0, 1, seconds=2.0)
    assert source.failed == 0
    assert max(intervals(source)) == pytest.approx(PERIOD)


@GOAL_NOT_MET
def test_an_offline_servo_leaves_no_interval_above_one_and_a_half_periods() -> None:
    # The stream keeps offering ID 12's transaction (the real stream probes it every 0.5 s; here
    # every cycle, the harder case): each costs only what this line's answers take.
    source = run(0.0, 1, present=IDS[:-1], seconds=3.0)
    assert source.failed > 100
    assert max(intervals(source)) <= 1.5 * PERIOD + 1e-9, max(intervals(source))
