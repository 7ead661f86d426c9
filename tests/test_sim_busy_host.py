"""The real-time simulator on a busy host: a servo's reply is on time even when the simulator's own thread is not.

A real servo's reply waits in the operating system's buffer from the moment it comes off the wire, whatever the
host is doing; the program reads it when it looks.  The in-process simulator delivers its chunks from a thread of
its own, which a busy program (a thread computing, a loaded machine) can hold back past the reply's allowance: the
simulated servo then looked late or silent where a real one never is (the built-in simulator showed errors under
load).  A port that looks for input now takes what is due by now from the simulator.
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Iterator

import pytest

from ics35_async import open_bus, protocol
from ics35_async.sim import Deliverer, VirtualLine, VirtualServo
from ics35_async.transports import HostSide


@pytest.fixture
def busy_program() -> Iterator[None]:
    """A thread of the program that computes without pause, taking the interpreter for 20 ms at a time: the
    simulator's delivery thread and the driver then wait for it in turn, in either order."""
    stop = threading.Event()

    def compute() -> None:
        while not stop.is_set():
            pass

    interval = sys.getswitchinterval()
    sys.setswitchinterval(0.02)
    thread = threading.Thread(target=compute, daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join()
        sys.setswitchinterval(interval)


@pytest.mark.parametrize("driver", ["asyncio", "thread", "anyio"])
async def test_replies_due_are_read_when_the_simulators_thread_is_held_back(driver: str, busy_program: None) -> None:
    sim = VirtualLine([VirtualServo(1)], realtime=True)
    # (A reply's allowance of 2 ms: the interpreter's 20 ms turns hold either thread back far longer.)
    async with open_bus(sim, driver=driver, adapter_latency=0.002, retries=0) as bus:
        for _ in range(30):
            assert await bus.submit(protocol.ReadParam(1, protocol.Param.STRETCH)) == VirtualServo(1).stretch
        stats = bus.stats
    assert stats.total.timeouts == 0
    assert stats.total.ok == 30


def test_deliver_due_hands_over_what_is_due_in_order_and_nothing_early() -> None:
    deliverer = Deliverer()
    got: list[bytes] = []
    try:
        now = time.perf_counter()
        # Held back: the thread waits for the first chunk's time; the caller looks later than all but the last.
        deliverer.schedule(now + 0.5, b"c", got.append)
        deliverer.schedule(now + 0.2, b"a", got.append)
        deliverer.schedule(now + 0.3, b"b", got.append)
        deliverer.schedule(now + 60, b"late", got.append)
        assert deliverer.deliver_due(now + 0.1) == 0 and got == []
        assert deliverer.deliver_due(now + 0.6) == 3
        assert got == [b"a", b"b", b"c"]
        assert deliverer.pending() == 1
    finally:
        deliverer.close()


class HandedOverWhenLooked:
    """A line whose answers reach the host only as it looks for input (``deliver_due``), one chunk a look, handed
    over by another thread the look waits for: as the real-time simulator's delivery thread may be handing a chunk
    over just as the driver looks (each then waits for the other's hand-over to end)."""

    def __init__(self, line: VirtualLine) -> None:
        self.line = line
        self.chunks: list[bytes] = []
        self.stuck = 0  # hand-overs that could not finish while the look waited for them
        self.host: HostSide | None = None

    def connect(self, host: HostSide, baudrate: int) -> None:
        self.host = host
        self.line.connect(self, baudrate)

    def deliver(self, data: bytes) -> None:  # (the line's answers, kept until the host looks)
        self.chunks.extend(data[i : i + 1] for i in range(len(data)))

    def lost(self, exc: Exception | None) -> None:
        assert self.host is not None
        self.host.lost(exc)

    def write(self, data: bytes) -> None:
        self.line.write(data)

    def disconnect(self) -> None:
        self.line.disconnect()

    def deliver_due(self) -> None:
        if not self.chunks or self.host is None:
            return
        hand_over = threading.Thread(target=self.host.deliver, args=(self.chunks.pop(0),))
        hand_over.start()
        hand_over.join(1.0)
        if hand_over.is_alive():  # (it finishes once the driver lets go of what it held: no join again)
            self.stuck += 1


@pytest.mark.parametrize("driver", ["thread", "asyncio", "anyio"])
async def test_a_driver_holds_nothing_a_device_handing_input_over_needs_while_it_looks(driver: str) -> None:
    device = HandedOverWhenLooked(VirtualLine([VirtualServo(1)]))
    async with open_bus(device, driver=driver, adapter_latency=0.05, retries=0) as bus:
        for _ in range(5):
            assert await bus.submit(protocol.ReadParam(1, protocol.Param.STRETCH)) == VirtualServo(1).stretch
    assert device.stuck == 0
