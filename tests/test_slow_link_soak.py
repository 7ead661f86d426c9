"""The held-tail soak, short (``python -m benchmarks.soak --only held_tail`` runs the full one).

A mixed workload on the real-time in-process simulator; mid-run every EEPROM
reply starts reaching the host with its last 4 bytes 40 ms late (ser2net with
Nagle's algorithm).  The issue's targets: the bus recovers within 1 s, then at
least 98 % of transactions succeed, none misattributed; and once the link is
fast again the learnt allowance goes back to 0.  The recovery time is measured
on the simulator's line clock between two log entries, and the success share
by counting transactions, so a loaded machine slows the run without skewing
the figures.
"""

from __future__ import annotations

import pytest

from benchmarks.soak.held_tail import SUCCESS_TARGET, held_tail_soak

pytestmark = [pytest.mark.realtime, pytest.mark.slow]


async def test_held_tail_soak_short() -> None:
    report = await held_tail_soak(fast=150, held=400, max_decay=3_000, tail_delay=0.040, seed=3)
    assert report.misattributed == 0 and report.untyped_outcomes == 0, report.examples
    # Before the slow link starts: a loaded machine may cost a transaction or two (a real-time line).
    assert report.fast_ok_fraction >= SUCCESS_TARGET, report.requests_failed
    assert report.held_tails >= 20  # the slow link was exercised
    assert report.recovery_s <= 1.0, report
    assert report.after_recovery_ok_fraction >= SUCCESS_TARGET, report
    assert report.after_1s_ok_fraction >= SUCCESS_TARGET, report
    assert 0 < report.link_extra_ms <= 250 and report.late_replies >= 1
    assert report.decay_transactions >= 0  # back to 0 on the fast link again
