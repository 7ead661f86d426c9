"""A slow link (issue 12 item 4) through a real serial boundary: the pty simulator with a held tail.

The server holds the last 4 bytes of every EEPROM reply of servo 1 for
40 ms, as ser2net with Nagle's algorithm does.  Before the bus learnt a
link's latency, every such reply timed out and its tail spoiled the next
transaction, for good ("each request receives the previous one's bytes").
Now the first one fails and the rest of the run succeeds.  The run counts
transactions, never wall time: on a loaded machine a few extra failures
may happen, most may not.
"""

from __future__ import annotations

import sys
from typing import Any

import pytest

from ics35_async import IcsError, open_bus
from tests.support.timing import NO_TIMEOUTS

pytestmark = [
    pytest.mark.realtime,
    pytest.mark.pty,
    pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the pty simulator needs Linux"),
]

SPEEDS = {1: 11, 2: 22, 3: 33}  # a distinct value per servo: a reply handed to the wrong request shows
ROUNDS = 30


async def test_through_a_held_tail_link_the_bus_adapts_and_no_reply_goes_to_the_wrong_request(pty_sim: Any) -> None:
    path = pty_sim("--ids", "1-3", "--faults", "tail@1:1", "--tail-delay", "40ms").path
    # The speeds first, on a bus of their own with the no-timeouts allowance: each write must land (short
    # replies, never split, but a loaded machine can hold the pty's echo past the default allowance), and
    # the bus under test starts from nothing learnt.
    async with open_bus(path, retries=0, **NO_TIMEOUTS) as setup:
        for i, speed in SPEEDS.items():
            await setup.servo(i).write_speed(speed)
    async with open_bus(path, retries=0) as bus:
        servos = {i: bus.servo(i) for i in SPEEDS}
        failed: list[tuple[int, str]] = []
        wrong: list[str] = []
        n = 0
        for _ in range(ROUNDS):
            for i, action in ((1, "eeprom"), (2, "speed"), (3, "eeprom"), (1, "speed"), (2, "eeprom")):
                try:
                    if action == "eeprom":
                        image = await servos[i].read_eeprom()
                        if image.servo_id != i:
                            wrong.append(f"#{n}: EEPROM of ID {image.servo_id} for ID {i}")
                    else:
                        speed = await servos[i].read_speed()
                        if speed != SPEEDS[i]:
                            wrong.append(f"#{n}: speed {speed} for ID {i} (it has {SPEEDS[i]})")
                except IcsError as exc:
                    failed.append((n, type(exc).__name__))
                n += 1
        extra = bus.stats.link_extra
    assert wrong == []
    # The first held tail fails its read (and maybe one more); after that, at least 95% succeed.
    later = [k for k, _ in failed if k >= 5]
    assert len(later) <= 0.05 * (n - 5), failed
    assert 0 < extra <= 0.25
