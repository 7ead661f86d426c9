"""The chaos soak's oracle, short, on a line whose failed stream transactions hold their servos back.

The soak (``python -m benchmarks.soak --only chaos``) pairs each ID's n-th stream outcome with its n-th
position command in the simulator's log (:class:`tests.support.matcher.LogMatcher`), and then finds the
close's last sends after them.  An ID the engine *holds back* after a failure (the stream skips it while the
reply to its failed command may still come: see ``LineEngine._hold``) is listed as failed with no command on
the line; its frame says so (``Frame.not_sent``).  A matcher that paired that outcome with the ID's next command
put every outcome after it one command late: valid replies counted as rejected, values as misattributed, and at
the end outcomes with no log entry or the close's send of a target seemingly sent twice.

The soak itself runs at a 3 ms adapter allowance, below the stream's learnt wait (4 ms at least), so its stream
waits its full allowance and a failure is followed by a quiet time on the whole line, no servo held back.  Here
the allowance is 100 ms, so the stream waits its learnt, shorter wait and a failure holds its servo back for many
cycles of the 32 IDs: the pairing must come out exact all the same.
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

# An allowance far above the stream's learnt wait, even on a loaded machine (whose slow answers lengthen that wait):
# a failure holds its servo back, for longer than many cycles of the 32 IDs.
HELD_BACK = dataclasses.replace(FAST_TIMING, adapter_latency=0.100)


async def test_each_failed_stream_slot_pairs_with_its_own_command() -> None:
    sim = VirtualLine(chaos_servos(), faults="drop@5:0.5", seed=1)
    async with await open_bus(sim, retries=1, timing=HELD_BACK) as bus:
        workload = ChaosWorkload(sim, bus, seed=1, workers=0, request_pause=0.0)
        await workload.run(6_000)
        workload.finish()  # raises CheckError where the pairing is off
        counts = workload.matcher.counts
    assert counts.fault_kinds["drop"] >= 2  # ID 5's replies were dropped
    assert counts.misattributed == 0 and counts.valid_rejected == 0, counts.examples
    assert counts.held_back  # (the case in question: slots held back, failed in their frames, nothing sent)
    assert workload.sent_on_close  # the close's sends were found where they went
