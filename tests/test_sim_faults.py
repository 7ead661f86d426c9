"""Fault injection: every kind, determinism by seed, per-ID rates, the spec syntax, unplug and replug."""

from __future__ import annotations

import threading

import pytest

from ics35_async.errors import InvalidArgument
from ics35_async.protocol import Position, ReadParam, WriteParam
from ics35_async.sim import FaultConfig, Transaction, VirtualLine


def pos(servo_id: int, position: int = 7500) -> bytes:
    return Position(servo_id, position, baudrate=115200).tx


def xfer(bus: VirtualLine, tx: bytes) -> bytes:
    return b"".join(chunk for _, chunk in bus.process(tx))


class Host:
    """The host end of an in-process line: collects what the device sends."""

    def __init__(self) -> None:
        self.data = bytearray()
        self.lost_with: list[Exception | None] = []
        self.gone = threading.Event()

    def deliver(self, data: bytes) -> None:
        self.data += data

    def lost(self, exc: Exception | None) -> None:
        self.lost_with.append(exc)
        self.gone.set()

    def take(self) -> bytes:
        out = bytes(self.data)
        self.data.clear()
        return out


# --------------------------------------------------------------------------- each kind


def test_drop() -> None:
    bus = VirtualLine([1, 2], faults="drop@1:1")
    assert xfer(bus, pos(1)) == pos(1)
    assert bus.log[-1].fault == "drop" and bus.log[-1].reply == b"" and bus.log[-1].clean_reply
    assert xfer(bus, pos(2)) == pos(2) + bytes.fromhex("02 3A 4C")  # other IDs unaffected
    assert bus.fault_counts["drop"] == 1


def test_truncate() -> None:
    bus = VirtualLine([1], faults="truncate:1")
    for _ in range(20):
        received = xfer(bus, pos(1))
        record = bus.log[-1]
        assert record.fault == "truncate"
        assert len(record.reply) < len(record.clean_reply)
        assert record.clean_reply.startswith(record.reply)
        assert received == pos(1) + record.reply


def test_corrupt() -> None:
    bus = VirtualLine([1], faults="corrupt:1", seed=5)
    for _ in range(20):
        received = xfer(bus, ReadParam(1, 2).tx)
        record = bus.log[-1]
        assert record.fault == "corrupt"
        diffs = [i for i, (a, b) in enumerate(zip(record.reply, record.clean_reply, strict=True)) if a != b]
        assert len(diffs) == 1
        assert record.reply[diffs[0]] & 0x80 == record.clean_reply[diffs[0]] & 0x80
        assert received == ReadParam(1, 2).tx + record.reply


def test_msb() -> None:
    bus = VirtualLine([1], faults="msb:1")
    for _ in range(10):
        xfer(bus, pos(1))
        record = bus.log[-1]
        diffs = [i for i, (a, b) in enumerate(zip(record.reply, record.clean_reply, strict=True)) if a != b]
        assert len(diffs) == 1 and diffs[0] >= 1  # a data byte, not the header
        assert record.reply[diffs[0]] == record.clean_reply[diffs[0]] | 0x80


def test_late_reply_lands_after_the_next_echo() -> None:
    bus = VirtualLine([1, 2], faults="late@1:1")
    first = xfer(bus, pos(1, 8000))
    assert first == pos(1, 8000)
    late_record = bus.log[-1]
    assert late_record.fault == "late" and late_record.reply == late_record.clean_reply
    second = xfer(bus, ReadParam(2, 2).tx)
    # The echo, then the stale reply for ID 1, then ID 2's own reply.
    assert second == ReadParam(2, 2).tx + late_record.reply + bytes.fromhex("22 02 7F")
    assert bus.log[-1].extra == late_record.reply
    assert bus.log[-1].fault is None


def test_late_reply_with_a_delay_waits_for_the_clock_in_fast_mode() -> None:
    bus = VirtualLine([1, 2], faults="late@1:1", late_delay=0.01)
    assert xfer(bus, pos(1)) == pos(1)
    assert xfer(bus, pos(2)) == pos(2) + bytes.fromhex("02 3A 4C")  # 1 ms later: not yet
    bus.advance(0.02)
    assert xfer(bus, pos(2)) == bytes.fromhex("01 3A 4C") + pos(2) + bytes.fromhex("02 3A 4C")


def test_noise_on_the_idle_line() -> None:
    bus = VirtualLine([1], faults="noise:1")
    received = xfer(bus, pos(1))
    record = bus.log[-1]
    assert record.fault == "noise"
    assert 1 <= len(record.extra) <= 3
    assert received == pos(1) + record.reply + record.extra
    assert record.reply == record.clean_reply


def test_echo_collision_garbles_the_echo_and_the_command() -> None:
    bus = VirtualLine([1], faults="collision:1")
    servo = bus.servo(1)
    received = xfer(bus, pos(1, 9000))
    record = bus.log[-1]
    assert record.fault == "echo"
    assert len(received) == 3 and received != pos(1, 9000)
    assert sum(a != b for a, b in zip(received, pos(1, 9000), strict=True)) == 1
    assert record.responders == () and servo.free  # nobody heard the command


def test_unplug_fault_disconnects_and_replugs() -> None:
    bus = VirtualLine([1], faults="unplug:1", replug_after=0.05)
    host = Host()
    replugged = threading.Event()
    bus.add_listener(lambda plugged: replugged.set() if plugged else None)
    bus.connect(host, 115200)
    bus.write(pos(1))
    assert host.take() == pos(1) + bytes.fromhex("01 3A 4C")  # the answer comes first
    assert host.gone.is_set() and isinstance(host.lost_with[0], OSError)
    assert not bus.plugged
    with pytest.raises(OSError):
        bus.connect(Host(), 115200)
    assert replugged.wait(5)
    bus.connect(Host(), 115200)
    bus.close()


# --------------------------------------------------------------------------- determinism


def _session(seed: int) -> list[Transaction]:
    bus = VirtualLine(
        [1, 2, 3],
        faults="drop:0.1,truncate:0.1,corrupt:0.1,msb:0.1,late:0.1,noise:0.1,echo:0.05",
        seed=seed,
        log_size=None,
    )
    for i in range(300):
        servo_id = 1 + i % 3
        command = pos(servo_id, 4000 + 13 * i) if i % 2 else WriteParam(servo_id, 2, 1 + i % 127).tx
        xfer(bus, command)
    return list(bus.log)


def test_same_seed_same_faults_different_seed_differs() -> None:
    first, again, other = _session(11), _session(11), _session(12)
    assert first == again
    faults = [t.fault for t in first]
    assert faults != [t.fault for t in other]
    for kind in ("drop", "truncate", "corrupt", "msb", "late", "noise", "echo"):
        assert any(f and kind in f.split("+") for f in faults), kind
    # Rates are roughly honoured (0.1 each over 300 transactions).
    drops = sum(1 for f in faults if f and "drop" in f.split("+"))
    assert 10 <= drops <= 60


def test_faults_are_per_id() -> None:
    bus = VirtualLine([1, 2, 3], faults="drop:1,drop@2:0", seed=1)
    for servo_id in (1, 2, 3):
        xfer(bus, pos(servo_id))
    assert [t.fault for t in bus.log] == ["drop", None, "drop"]


# --------------------------------------------------------------------------- the spec syntax


def test_fault_spec_parsing() -> None:
    config = FaultConfig.parse("drop:0.01, late:0.02,corrupt@3:0.5,noise@4-6:0.25,collision:0.1")
    assert config.rate("drop", 9) == 0.01
    assert config.rate("corrupt", 3) == 0.5 and config.rate("corrupt", 4) == 0.0
    assert config.rate("noise", 5) == 0.25 and config.rate("noise", 7) == 0.0
    assert config.rate("echo", None) == 0.1
    assert FaultConfig.parse(str(config)) == config
    assert not FaultConfig.parse("none") and not FaultConfig.parse("")


@pytest.mark.parametrize(
    "spec",
    [
        "explode:0.1",
        "drop",
        "drop:2",
        "drop:x",
        "drop@40:0.1",
        "drop@a:0.1",
        "drop:0.6,late:0.6",
        "late@1:0.7,drop:0.4",
    ],
)
def test_bad_fault_specs(spec: str) -> None:
    with pytest.raises(InvalidArgument):
        FaultConfig.parse(spec)


# --------------------------------------------------------------------------- unplug and replug


def test_unplug_and_replug_by_hand() -> None:
    bus = VirtualLine([1])
    host = Host()
    bus.connect(host, 115200)
    bus.write(pos(1))
    assert host.take().endswith(bytes.fromhex("01 3A 4C"))
    bus.unplug()
    assert isinstance(host.lost_with[0], OSError)
    with pytest.raises(OSError):
        bus.write(pos(1))
    with pytest.raises(OSError):
        bus.connect(host, 115200)
    bus.replug()
    bus.connect(host, 115200)
    bus.write(pos(1))
    assert host.take() == pos(1) + bytes.fromhex("01 3A 4C")
    assert bus.unplug_count == 1


def test_scheduled_unplug() -> None:
    bus = VirtualLine([1])
    events: list[bool] = []
    done = threading.Event()

    def listener(plugged: bool) -> None:
        events.append(plugged)
        if plugged:
            done.set()

    bus.add_listener(listener)
    host = Host()
    bus.connect(host, 115200)
    bus.schedule_unplug(0.01, replug_after=0.01)
    assert done.wait(5)
    assert events == [False, True] and host.gone.is_set()
    bus.close()


def test_second_connect_while_open_is_refused_and_disconnect_frees_it() -> None:
    bus = VirtualLine([1])
    bus.connect(Host(), 115200)
    with pytest.raises(OSError):
        bus.connect(Host(), 115200)
    bus.disconnect()
    bus.connect(Host(), 115200)
