"""The chaos soak's oracle, short, on a line whose failed stream transactions are followed by a long silence.

The soak (``python -m benchmarks.soak --only chaos``) pairs each ID's n-th stream outcome with its n-th
position command in the simulator's log (:class:`tests.support.matcher.LogMatcher`), and then finds the
close's last sends after them.  That pairing is exact only while every ID a frame lists as failed had its
command on the line in that cycle.  An ID the engine *holds back* (the stream skips it while the reply to its
failed command may still come: see ``LineEngine._hold``) is listed as failed with no command on the line; the
matcher would pair that outcome with the ID's next command, and every outcome after it one command late: valid
replies counted as rejected, values as misattributed, and at the end outcomes with no log entry or the close's
send of a target seemingly sent twice.

Here the adapter allowance is the soak's 3 ms (below the stream's learnt wait, so the stream waits its full
allowance) and ``quiet_time`` is longer than a cycle of the 32 IDs: a failure is waited out and followed by
that silence on the whole line, no ID is held back, and the pairing must come out exact.  An engine that held
such an ID back instead would make this module fail until the matcher can tell a held-back slot from a failed
transaction (a frame does not say which of its failed IDs were sent nothing).
"""

from __future__ import annotations

import dataclasses

import pytest

from benchmarks.soak.chaos import ChaosWorkload
from ics35_async import open_bus
from ics35_async.sim import VirtualLine
from tests.support.oracle import chaos_servos
from tests.support.timing import FAST_TIMING

pytestmark = pytest.mark.slow

# A quiet_time longer than a cycle of the 32 IDs (the value under test): a servo held back for it would be
# skipped by the stream's next cycle.
LONG_SILENCE = dataclasses.replace(FAST_TIMING, quiet_time=0.050)


async def test_each_failed_stream_slot_pairs_with_its_own_command() -> None:
    sim = VirtualLine(chaos_servos(), faults="drop@5:0.25", seed=1)
    async with await open_bus(sim, retries=1, timing=LONG_SILENCE) as bus:
        workload = ChaosWorkload(sim, bus, seed=1, workers=0, request_pause=0.0)
        await workload.run(1_500)
        workload.finish()  # raises CheckError where the pairing is off
        counts = workload.matcher.counts
    assert counts.fault_kinds["drop"] >= 5  # ID 5's replies were dropped
    assert counts.misattributed == 0 and counts.valid_rejected == 0, counts.examples
    assert workload.sent_on_close  # the close's sends were found where they went
