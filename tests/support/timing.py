"""The test suite's one timing profile, scaled for slow machines by ``ICS35_TEST_TIME_SCALE``.

Every test that talks to a simulator through a bus uses :data:`FAST` (``open_bus(sim, **FAST)``) or
:data:`FAST_TIMING` (``open_bus(sim, timing=FAST_TIMING)``), the same allowances either way, or
:data:`REAL_TIME` when the reply comes from a pty or a real-time simulator, :data:`NO_TIMEOUTS` when
no reply may time out at all, or :data:`PATIENT` across a pty where some transactions time out by design.
A test that sets a timing value itself does so because that value is what it tests (a reply held past the
allowance, a real-time pace), never for speed or slack.

The allowances are how long a bus waits for a reply beyond its wire time.  Across a pty or from a
real-time simulator a reply can be late when the machine is loaded: raise ``ICS35_TEST_TIME_SCALE``
(``ICS35_TEST_TIME_SCALE=3 make test``) and every allowance and guard grows by that factor.  A test
never asserts that something was fast.  A test that counts the replies of servos that are there uses
:data:`NO_TIMEOUTS` (and asks only the IDs involved: a silent one costs a whole allowance); one that also
waits out silent IDs or failures over a pty uses :data:`PATIENT`.
:func:`or_describe` guards a wait against a hang and, if it trips, says what the line was doing.
"""

from __future__ import annotations

import asyncio
import os
import time
from collections.abc import Awaitable
from typing import TypeVar

import pytest

from ics35_async import Bus
from ics35_async.engine import BusTiming, TimingOverrides

T = TypeVar("T")


def _scale() -> float:
    text = os.environ.get("ICS35_TEST_TIME_SCALE", "1")
    try:
        value = float(text)
    except ValueError:
        value = 0.0
    if not 0.1 <= value <= 100:
        raise ValueError(f"ICS35_TEST_TIME_SCALE must be a number from 0.1 to 100, not {text!r}")
    return value


SCALE = _scale()


def scaled(seconds: float) -> float:
    """An allowance or guard of ``seconds`` on this machine."""
    return seconds * SCALE


# In process, fast mode: the simulator queues its reply on the bus's loop as the bus writes, ahead of any
# deadline, so no load makes a reply late here; the allowance is what each expected timeout costs (a scan's
# empty IDs, an offline servo): short.
FAST: TimingOverrides = {"adapter_latency": scaled(0.003), "eeprom_write": scaled(0.005), "quiet_time": 0.001}
FAST_TIMING = BusTiming(**FAST)
# Across a real-time boundary: a pty served by another process, or a real-time simulator's delivery thread,
# where the reply waits for another process or thread to be scheduled.
REAL_TIME: TimingOverrides = {**FAST, "adapter_latency": scaled(0.050)}
# For a test that expects every reply and counts them, and asks no silent ID: an allowance costs nothing when
# no reply times out, so this one is long enough for a machine that stalls both processes for a second and
# more (seen under two CPU burners beside the test workers).
NO_TIMEOUTS: TimingOverrides = {**FAST, "adapter_latency": scaled(2.0)}
# For a test across a pty that must not take a present servo's late reply for silence but also waits out
# silent IDs or failed transactions (a scan, set-id's survey, a servo that answers garbage): each of those
# costs the whole allowance, so this one is shorter than NO_TIMEOUTS.
PATIENT: TimingOverrides = {**FAST, "adapter_latency": scaled(0.5)}
GUARD = scaled(10.0)  # seconds: only against hangs, never a timing assertion
# The same allowances as ``ics35`` options, for a test that runs the CLI across a real-time boundary.
REAL_TIME_OPTION = ("--timeout", str(REAL_TIME["adapter_latency"]))
NO_TIMEOUTS_OPTION = ("--timeout", str(NO_TIMEOUTS["adapter_latency"]))
PATIENT_OPTION = ("--timeout", str(PATIENT["adapter_latency"]))


async def or_describe(awaitable: Awaitable[T], bus: Bus, seconds: float = GUARD) -> T:
    """``await awaitable``; if it takes ``seconds`` (a guard against a hang, never a timing assertion) or a
    reply never comes, fail the test with what the line was doing then (``bus.describe()``) and its counters."""
    try:
        return await asyncio.wait_for(awaitable, seconds)
    except TimeoutError as exc:  # the guard's, or a ReplyTimeout (a TimeoutError too)
        what = str(exc) or f"nothing after {seconds} s"
        # The time, on the clock a pty simulator's notes use, to find this moment in them.
        pytest.fail(f"{what}; the line: {bus.describe()}; {bus.stats.total}; at {time.monotonic():.6f}")
