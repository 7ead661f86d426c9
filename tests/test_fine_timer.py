"""Deadlines to the microsecond: the Linux ``timerfd`` the asyncio driver arms for the engine's deadlines.

The timer itself on a real ``timerfd`` (it fires once per deadline, never before it, and a deadline moved or
cancelled forgets an expiry not yet read), then the drivers: which of them fire their deadlines on it, that a
deadline there is still judged (a silent servo's reply given up on, a paced stream's slots), and that a closed
bus leaves no descriptor behind.
"""

from __future__ import annotations

import os
import select
import sys
import time
from typing import Any

import pytest

from ics35_async import ReplyTimeout, open_bus
from ics35_async.drivers.fine_timer import FineTimer, open_fine_timer
from ics35_async.protocol import Param, ReadParam
from tests.support.timing import FAST, GUARD

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="a timerfd is Linux's")


def fine_timer() -> FineTimer:
    timer = open_fine_timer()
    assert timer is not None, "no timerfd on this Linux"
    return timer


def readable(timer: FineTimer, within: float) -> bool:
    return bool(select.select([timer.fd], [], [], within)[0])


def test_a_deadline_passed_fires_at_once_and_once() -> None:
    timer = fine_timer()
    try:
        timer.arm(time.monotonic() - 1.0)
        assert readable(timer, GUARD)
        assert timer.fired()
        assert not readable(timer, 0.05)
        assert not timer.fired()
    finally:
        timer.close()


@pytest.mark.parametrize("delay", [0.0003, 0.002, 0.02])
def test_a_deadline_never_fires_before_its_time(delay: float) -> None:
    timer = fine_timer()
    try:
        deadline = time.monotonic() + delay
        timer.arm(deadline)
        assert readable(timer, GUARD)
        assert time.monotonic() >= deadline  # (the drivers' clock, time.monotonic, is the timer's)
        assert timer.fired()
    finally:
        timer.close()


def test_a_deadline_moved_later_forgets_the_expiry_of_the_one_before() -> None:
    timer = fine_timer()
    try:
        timer.arm(time.monotonic() - 1.0)  # expired, not yet read
        timer.arm(time.monotonic() + 60.0)
        assert not readable(timer, 0.05)
        assert not timer.fired()
    finally:
        timer.close()


@pytest.mark.parametrize("expired", [False, True], ids=["pending", "expired"])
def test_a_cancelled_deadline_never_fires(expired: bool) -> None:
    timer = fine_timer()
    try:
        timer.arm(time.monotonic() + (-1.0 if expired else 0.01))
        timer.cancel()
        assert not readable(timer, 0.05)
        assert not timer.fired()
    finally:
        timer.close()


def open_descriptors() -> set[str]:
    return set(os.listdir("/proc/self/fd"))


@pytest.mark.parametrize(
    ("anyio_backend", "driver", "fine"),
    [
        ("asyncio", "asyncio", True),
        ("uvloop", "asyncio", True),
        ("asyncio", "thread", False),
        ("trio", "anyio", False),
    ],
    indirect=["anyio_backend"],
)
async def test_the_asyncio_driver_judges_its_deadlines_on_it(anyio_backend: Any, driver: str, fine: bool) -> None:
    before = open_descriptors()
    async with open_bus("sim://?ids=1", driver=driver, **FAST) as bus:
        assert bus.describe()["fine_deadlines"] is fine
        with pytest.raises(ReplyTimeout):  # no servo at ID 2: its reply given up on at the deadline
            # (one try: a retry goes behind a guard read, whose echo a loaded simulator can send after the guard's
            # deadline, ahead of the retry's own: an EchoMismatch, the line's rule, not this test's subject)
            await bus.request(ReadParam(2, Param.TEMPERATURE), retries=0)
        async with bus.stream([1], rate_hz=200) as stream:  # its cycles start at slots, deadlines 5 ms apart
            first = (await stream.next_frame()).cycle
            while (await stream.next_frame()).cycle < first + 5:
                pass
        assert await bus.servo(1).read_temperature() > 0
    assert open_descriptors() <= before  # the timer's descriptor closed with the bus


@pytest.mark.pty
@pytest.mark.parametrize(
    ("anyio_backend", "driver", "fine"),
    [("asyncio", "asyncio", True), ("asyncio", "thread", True), ("trio", "anyio", False)],
    indirect=["anyio_backend"],
)
async def test_the_drivers_on_a_tty_judge_their_deadlines_on_it(
    anyio_backend: Any, driver: str, fine: bool, pty_sim: Any
) -> None:
    # The thread driver's I/O thread polls a tty: poll counts whole milliseconds, so its deadlines (a reply given
    # up on, a paced stream's slot) came up to a millisecond late, as the event loops' timers do.
    path = pty_sim("--ids", "1").path
    before = open_descriptors()
    # (A retry: on a loaded machine the simulator's process can answer a stream's command after its deadline and
    # the resync's quiet time, so the late reply lands ahead of the next read's echo, a typed error that a retry
    # after the resync recovers from; the test is about deadlines, not about the simulator's punctuality.)
    async with open_bus(path, driver=driver, retries=1, **FAST) as bus:
        assert bus.describe()["fine_deadlines"] is fine
        with pytest.raises(ReplyTimeout):  # no servo at ID 2: its reply given up on at the deadline
            # (one try: a retry goes behind a guard read, whose echo a loaded simulator can send after the guard's
            # deadline, ahead of the retry's own: an EchoMismatch, the line's rule, not this test's subject)
            await bus.request(ReadParam(2, Param.TEMPERATURE), retries=0)
        async with bus.stream([1], rate_hz=200) as stream:
            first = (await stream.next_frame()).cycle
            while (await stream.next_frame()).cycle < first + 5:
                pass
        assert await bus.servo(1).read_temperature() > 0
    assert open_descriptors() <= before
