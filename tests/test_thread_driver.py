"""The thread driver's own duties: waking its I/O thread, and never leaving a caller waiting on a dead thread.

The shared scenarios (requests, streams, scans, sharing, cancellation) run on
it in tests/test_contract.py; losing and reopening the port in test_bus.py and
test_stream.py.
"""

from __future__ import annotations

import asyncio

import pytest

from ics35_async import PortLost, ReplyTimeout, open_bus, protocol
from ics35_async.sim import VirtualLine, VirtualServo

FAST = {"adapter_latency": 0.02, "quiet_time": 0.002}


async def test_a_request_to_a_silent_servo_times_out_while_the_line_idles() -> None:
    # The I/O thread sleeps without a deadline on an idle line: the request must wake it, or the
    # timeout would never be judged.
    with VirtualLine([VirtualServo(1)]) as sim:
        async with open_bus(sim, driver="thread", **FAST) as bus:
            assert bus.driver == "thread"
            for _ in range(3):
                with pytest.raises(ReplyTimeout):
                    await asyncio.wait_for(bus.servo(9).read_stretch(), 5)
                assert await asyncio.wait_for(bus.servo(1).read_stretch(), 5) == sim.servo(1).stretch


class BrokenDevice:
    """A device whose write fails with an error no port raises: a bug below the engine."""

    def __init__(self) -> None:
        self.host = None

    def connect(self, host: object, baudrate: int) -> None:
        self.host = host

    def write(self, data: bytes) -> None:
        raise ValueError("not an OSError")

    def disconnect(self) -> None:
        self.host = None


async def test_a_failure_in_the_io_thread_fails_its_callers_instead_of_leaving_them_waiting() -> None:
    bus = await open_bus(BrokenDevice(), driver="thread", reconnect=True, **FAST)
    try:
        with pytest.raises(PortLost):
            await asyncio.wait_for(bus.request(protocol.ReadParam(1, protocol.Param.STRETCH)), 5)
        with pytest.raises(PortLost):
            await asyncio.wait_for(bus.request(protocol.ReadParam(1, protocol.Param.STRETCH)), 5)
    finally:
        await asyncio.wait_for(bus.aclose(), 5)
