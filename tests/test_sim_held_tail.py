"""The held-tail fault: a reply's last bytes reach the host late, as through a TCP bridge with Nagle's algorithm.

A 68-byte EEPROM reply (echo included) through ser2net with Nagle on arrives
as 64 + 4 bytes with the 4 some 40 ms later.  The simulator's ``tail`` fault
holds back a reply's last ``tail_bytes`` bytes for ``tail_delay`` seconds,
and, like a TCP stream, lets nothing that follows overtake them.  These
tests check the split, the order and that the tail is never early; no test
relies on how late it is beyond that lower bound.
"""

from __future__ import annotations

import sys
import threading
import time

import pytest

from ics35_async.errors import InvalidArgument
from ics35_async.protocol import BITS_PER_BYTE, Position, ReadEeprom, ReadParam
from ics35_async.sim import FaultConfig, VirtualLine, open_url, parse_url

EEPROM_READ = ReadEeprom(1).tx  # A1 00: a 66-byte reply


def pos(servo_id: int, position: int = 7500) -> bytes:
    return Position(servo_id, position, baudrate=115200).tx


def clean_eeprom_reply() -> bytes:
    """What servo 1 answers to the EEPROM read on a healthy line."""
    healthy = VirtualLine([1])
    return b"".join(chunk for _, chunk in healthy.process(EEPROM_READ))[len(EEPROM_READ) :]


def test_tail_is_a_reply_fault_with_an_alias() -> None:
    assert FaultConfig.parse("tail:0.5").rate("tail", 1) == 0.5
    assert FaultConfig.parse("held_tail@3:1").rate("tail", 3) == 1.0
    with pytest.raises(InvalidArgument, match="add up to"):
        FaultConfig.parse("drop:0.6,tail:0.6")


def test_model_times_the_tail_after_the_delay_and_holds_what_follows_behind_it() -> None:
    line = VirtualLine([1, 2], realtime=True, faults="tail@1:1", tail_bytes=4, tail_delay=0.04)
    reply = clean_eeprom_reply()
    chunks = line.feed(EEPROM_READ, 0.0)
    assert [c for _, c in chunks] == [EEPROM_READ, reply[:-4], reply[-4:]]
    (_, _), (head_time, _), (tail_time, _) = chunks
    byte_time = BITS_PER_BYTE / 115200
    assert tail_time == pytest.approx(head_time + 4 * byte_time + 0.04)
    record = line.log[-1]
    assert record.fault == "tail" and record.reply == reply and record.reply_time == tail_time
    # The next command, written before the tail arrived: its echo and reply queue behind the tail.
    later = line.feed(pos(2), head_time + 0.001)
    assert [c for _, c in later] == [pos(2), bytes.fromhex("02 3A 4C")]
    assert all(when >= tail_time for when, _ in later)


def test_short_replies_are_not_split() -> None:
    # A reply no longer than the tail goes out whole (a lone small segment is not held).
    line = VirtualLine([1], faults="tail:1", tail_bytes=4)
    assert b"".join(c for _, c in line.process(pos(1))) == pos(1) + bytes.fromhex("01 3A 4C")
    assert line.log[-1].fault is None


def test_fast_mode_holds_the_tail_until_the_hosts_next_write() -> None:
    line = VirtualLine([1, 2], faults="tail@1:1", tail_bytes=4)
    reply = clean_eeprom_reply()
    first = b"".join(c for _, c in line.process(EEPROM_READ))
    assert first == EEPROM_READ + reply[:-4]
    second = b"".join(c for _, c in line.process(ReadParam(2, 2).tx))
    # The tail first, then the next command's echo and reply: nothing overtakes it.
    assert second == reply[-4:] + ReadParam(2, 2).tx + bytes.fromhex("22 02 7F")
    assert line.log[-1].extra == reply[-4:] and line.log[-1].fault is None


class TimedHost:
    def __init__(self) -> None:
        self.arrivals: list[tuple[float, bytes]] = []
        self.cond = threading.Condition()

    def deliver(self, data: bytes) -> None:
        stamp = time.perf_counter()
        with self.cond:
            self.arrivals.append((stamp, data))
            self.cond.notify_all()

    def lost(self, exc: Exception | None) -> None:
        pass

    def wait_for_bytes(self, count: int, timeout: float = 10.0) -> list[tuple[float, bytes]]:
        with self.cond:
            done = self.cond.wait_for(lambda: sum(len(d) for _, d in self.arrivals) >= count, timeout)
            assert done, self.arrivals
            return list(self.arrivals)


@pytest.mark.realtime
def test_in_process_real_time_the_tail_arrives_separately_and_late() -> None:
    delay = 0.1
    line = VirtualLine([1, 2], realtime=True, faults="tail@1:1", tail_bytes=4, tail_delay=delay)
    reply = clean_eeprom_reply()
    host = TimedHost()
    line.connect(host, 115200)
    try:
        written = time.perf_counter()
        line.write(EEPROM_READ)
        line.write(pos(2))  # written at once: it must not overtake the held tail
        expected = EEPROM_READ + reply + pos(2) + bytes.fromhex("02 3A 4C")
        arrivals = host.wait_for_bytes(len(expected))
    finally:
        line.close()
    assert b"".join(d for _, d in arrivals) == expected
    # The head and the tail are separate deliveries, the tail at least `delay` after the head was due
    # (measured from the write: a busy machine may deliver the head late, never the tail early).
    stream = b"".join(d for _, d in arrivals)
    head_end = len(EEPROM_READ) + len(reply) - 4
    offsets = [0]
    for _, data in arrivals:
        offsets.append(offsets[-1] + len(data))
    assert head_end in offsets, "the head and the tail arrived in one piece"
    head_arrival = next(t for (t, _), end in zip(arrivals, offsets[1:], strict=True) if end == head_end)
    tail_arrival = next(t for (t, _), start in zip(arrivals, offsets, strict=True) if start == head_end)
    assert head_arrival < tail_arrival and tail_arrival - written >= delay
    assert stream[head_end : head_end + 4] == reply[-4:]


def test_url_and_defaults() -> None:
    _, options = parse_url("sim://?faults=tail:1&tail_bytes=2&tail_delay=40ms")
    assert options["tail_bytes"] == 2 and options["tail_delay"] == pytest.approx(0.04)
    line = open_url("sim://?faults=tail:1")
    assert isinstance(line, VirtualLine)
    assert (line.tail_bytes, line.tail_delay) == (4, pytest.approx(0.04))  # the ser2net/Nagle example
    line.close()
    for bad in ("sim://?tail_bytes=0", "sim://?tail_bytes=x", "sim://?tail_delay=-1"):
        with pytest.raises(InvalidArgument):
            open_url(bad)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="needs Linux ptys")
@pytest.mark.realtime
@pytest.mark.pty
def test_pty_server_holds_the_tail() -> None:
    import serial

    from ics35_async.sim import start_subprocess, stop_subprocess

    delay = 0.5  # long, so a client descheduled for a moment still finds the tail missing
    proc, path = start_subprocess(["--ids", "1", "--faults", "tail:1", "--tail-bytes", "4", "--tail-delay", f"{delay}"])
    try:
        with serial.Serial(path, 115200, timeout=5.0) as port:
            port.write(EEPROM_READ)
            assert port.read(2) == EEPROM_READ
            head = port.read(62)
            assert head[:2] == bytes.fromhex("21 00") and len(head) == 62
            assert port.in_waiting == 0  # the tail is held back
            tail = port.read(4)
            assert len(tail) == 4 and all(b <= 0x0F for b in head[2:] + tail)
            # Short replies are not split, and the line goes on normally.
            port.write(pos(1))
            assert port.read(6) == pos(1) + bytes.fromhex("01 3A 4C")
    finally:
        assert stop_subprocess(proc) == 0


def test_pty_server_options_reach_the_line() -> None:
    pytest.importorskip("termios")
    from ics35_async.sim.server_cli import build_device, build_parser

    device = build_device(build_parser().parse_args(["--ids", "1", "--tail-bytes", "2", "--tail-delay", "40ms"]))
    assert isinstance(device, VirtualLine)
    assert (device.tail_bytes, device.tail_delay) == (2, pytest.approx(0.04))
    device.close()
