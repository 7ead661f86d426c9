"""The soaks' watchdog: a run that stops making progress fails with a dump, whatever it is stuck in."""

from __future__ import annotations

import asyncio
import threading
from typing import Any

import pytest

from benchmarks.soak.watchdog import Stalled, Watchdog
from ics35_async import PortLost, open_bus, protocol


class StuckDevice:
    """Answers one read, then blocks the writer until released: the event loop is stuck in ``write``."""

    def __init__(self) -> None:
        self.host: Any = None
        self.release = threading.Event()
        self.writes = 0

    def connect(self, host: Any, baudrate: int) -> None:
        self.host = host

    def disconnect(self) -> None:
        self.host = None

    def write(self, data: bytes) -> None:
        self.writes += 1
        if self.writes == 1:
            self.host.deliver(data + protocol.ReadParam(2, protocol.Param.STRETCH).encode_reply(40))
            return
        self.release.wait()


def test_a_loop_stuck_with_a_request_on_the_wire_fails_with_a_dump_of_it() -> None:
    device = StuckDevice()

    async def main() -> None:
        bus = await open_bus(device, adapter_latency=0.05)
        try:
            with Watchdog("stuck device", patience=1.0) as dog:
                dog.watch(bus)
                assert await bus.servo(2).read_stretch() == 40
                with pytest.raises(PortLost):  # the interrupted write is a lost port to the bus
                    await bus.servo(5).read_temperature()  # written, and the write never returns
        finally:
            device.release.set()
            await bus.aclose()

    with pytest.raises(Stalled) as stalled:
        asyncio.run(main())
    dump = str(stalled.value)
    assert "stuck device: no progress for 1 s" in dump
    assert '"state": "busy"' in dump and '"tx": "a5 04"' in dump  # the read on the wire, and who waits
    assert "read_temperature id=5" in dump
    assert "self.release.wait()" in dump  # where the main thread stands


def test_a_future_nobody_resolves_on_an_idle_loop_fails_with_a_dump() -> None:
    # The loop sleeps in select with no timer armed: only a signal wakes it.
    async def main() -> None:
        async with open_bus("sim://?ids=1", adapter_latency=0.05) as bus:
            with Watchdog("forgotten future", patience=0.5, progress=lambda: 0) as dog:
                dog.watch(bus)
                await bus.servo(1).read_stretch()
                await asyncio.get_running_loop().create_future()

    with pytest.raises(Stalled, match="forgotten future: no progress") as stalled:
        asyncio.run(main())
    assert "task " in str(stalled.value) and "main" in str(stalled.value)


def test_a_run_that_keeps_progressing_is_left_alone() -> None:
    async def main() -> int:
        async with open_bus("sim://?ids=1", adapter_latency=0.05) as bus:
            with Watchdog("busy", patience=0.3) as dog:
                dog.watch(bus)
                n = 0
                for _ in range(40):
                    await bus.servo(1).read_stretch()
                    await asyncio.sleep(0.02)
                    n += 1
                return n

    assert asyncio.run(main()) == 40
