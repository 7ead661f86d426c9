"""Real-time mode: nothing arrives before the wire allows, and it arrives (loose upper bounds only).

The accuracy figures themselves come from benchmarks/sim_timing.py; the upper
bounds here are generous enough not to flake on a loaded 2-core machine.
"""

from __future__ import annotations

import threading
import time

import pytest

from ics35_async.protocol import Position, ReadParam, wire_time
from ics35_async.sim import Deliverer, VirtualLine, wait_until

pytestmark = pytest.mark.realtime

LOOSE = 0.25  # seconds: only catches "never delivered" or "delivered by the wrong clock"


class TimedHost:
    def __init__(self) -> None:
        self.arrivals: list[tuple[float, bytes]] = []
        self.lock = threading.Lock()
        self.cond = threading.Condition(self.lock)
        self.lost_with: list[Exception | None] = []

    def deliver(self, data: bytes) -> None:
        stamp = time.perf_counter()
        with self.cond:
            self.arrivals.append((stamp, data))
            self.cond.notify_all()

    def lost(self, exc: Exception | None) -> None:
        with self.cond:
            self.lost_with.append(exc)
            self.cond.notify_all()

    def wait_for(self, count: int, timeout: float = 5.0) -> list[tuple[float, bytes]]:
        with self.cond:
            assert self.cond.wait_for(lambda: len(self.arrivals) >= count, timeout), self.arrivals
            out = self.arrivals[:count]
            del self.arrivals[:count]
            return out


def test_wait_until_never_returns_early() -> None:
    for delay in (0.0, 50e-6, 300e-6, 2e-3):
        deadline = time.perf_counter() + delay
        wait_until(deadline)
        after = time.perf_counter()
        assert deadline <= after < deadline + LOOSE


def test_deliverer_keeps_time_order_and_never_delivers_early() -> None:
    deliverer = Deliverer()
    got: list[tuple[float, float, bytes]] = []
    done = threading.Event()
    base = time.perf_counter() + 0.01
    plan = [(base + 0.003, b"c"), (base + 0.001, b"a"), (base + 0.002, b"b"), (base + 0.002, b"b2")]
    for when, data in plan:
        deliverer.schedule(when, data, lambda d, w=when: (got.append((w, time.perf_counter(), d)), done.set()))
    deadline = time.monotonic() + 5
    while len(got) < 4 and time.monotonic() < deadline:
        time.sleep(0.005)
    deliverer.close()
    assert [d for _, _, d in got] == [b"a", b"b", b"b2", b"c"]
    for when, arrived, _ in got:
        assert when <= arrived < when + LOOSE


def test_cancel_drops_pending_chunks() -> None:
    deliverer = Deliverer()
    got: list[bytes] = []
    deliverer.schedule(time.perf_counter() + 0.05, b"x", got.append)
    deliverer.cancel()
    time.sleep(0.1)
    deliverer.close()
    assert got == []


@pytest.mark.parametrize("baud", [115200, 625000, 1250000])
def test_echo_and_reply_arrive_no_earlier_than_the_wire(baud: int) -> None:
    bus = VirtualLine([1], baudrate=baud, realtime=True, turnaround=100e-6)
    host = TimedHost()
    bus.connect(host, baud)
    try:
        for target in (7000, 8000):
            command = Position(1, target, baudrate=baud)
            written = time.perf_counter()
            bus.write(command.tx)
            (echo_at, echo), (reply_at, reply) = host.wait_for(2)
            assert echo == command.tx and reply[0] == 0x01
            assert echo_at >= written + wire_time(3, baud)
            assert reply_at >= written + wire_time(6, baud) + 100e-6
            assert reply_at < written + LOOSE
            record = bus.log[-1]
            assert record.reply_time is not None
            assert reply_at >= bus.epoch + record.reply_time
    finally:
        bus.close()


def test_eeprom_write_reply_waits_for_the_extra_delay() -> None:
    from ics35_async.eeprom import Eeprom
    from ics35_async.protocol import WriteEeprom

    bus = VirtualLine([1], baudrate=1250000, realtime=True, eeprom_write_delay=0.03)
    host = TimedHost()
    bus.connect(host, 1250000)
    try:
        written = time.perf_counter()
        bus.write(WriteEeprom(1, Eeprom.factory(1, baud_rate=1250000)).tx)
        (_, _), (reply_at, reply) = host.wait_for(2)
        assert reply == bytes.fromhex("41 00")
        assert reply_at >= written + 0.03 + wire_time(68, 1250000)
    finally:
        bus.close()


def test_motion_follows_the_wall_clock() -> None:
    bus = VirtualLine([1], realtime=True)
    host = TimedHost()
    bus.connect(host, 115200)
    try:
        bus.write(Position(1, 11000, baudrate=115200).tx)
        host.wait_for(2)
        time.sleep(0.1)
        bus.sync()
        moved = bus.servo(1).position - 7500
        assert moved >= 12000 * 0.1 * 0.9  # 12000 counts/s at speed 127, at least 0.1 s
    finally:
        bus.close()


def test_late_reply_with_a_delay_arrives_that_much_later() -> None:
    bus = VirtualLine([1, 2], realtime=True, faults="late@1:1", late_delay=0.05)
    host = TimedHost()
    bus.connect(host, 115200)
    try:
        written = time.perf_counter()
        bus.write(ReadParam(1, 2).tx)
        bus.write(ReadParam(2, 2).tx)
        arrivals = host.wait_for(4)
        assert [d for _, d in arrivals] == [
            ReadParam(1, 2).tx,
            ReadParam(2, 2).tx,
            bytes.fromhex("22 02 7F"),
            bytes.fromhex("21 02 7F"),
        ]
        assert arrivals[3][0] >= written + 0.05
    finally:
        bus.close()


def test_unplug_fault_after_the_reply_in_realtime() -> None:
    bus = VirtualLine([1], realtime=True, faults="unplug:1", replug_after=0.05)
    host = TimedHost()
    bus.connect(host, 115200)
    try:
        bus.write(ReadParam(1, 2).tx)
        host.wait_for(2)
        with host.cond:
            assert host.cond.wait_for(lambda: host.lost_with, 5)
        deadline = time.monotonic() + 5
        while not bus.plugged:
            assert time.monotonic() < deadline
            time.sleep(0.01)
        bus.connect(TimedHost(), 115200)
    finally:
        bus.close()


def test_reconnecting_does_not_leak_delivery_threads() -> None:
    bus = VirtualLine([1], realtime=True)
    before = threading.active_count()
    for _ in range(5):
        host = TimedHost()
        bus.connect(host, 115200)
        bus.write(ReadParam(1, 2).tx)
        host.wait_for(2)
        bus.disconnect()
    assert threading.active_count() <= before
    bus.close()
