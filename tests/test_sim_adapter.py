"""The USB adapter model (an FTDI chip between the line and the host) and the line's tap.

The model's times are checked on the simulated clock (fast mode, or the
sans-IO model itself), so nothing here depends on how busy the machine is.
"""

from __future__ import annotations

import itertools
import os

import pytest

from ics35_async.errors import InvalidArgument
from ics35_async.protocol import BITS_PER_BYTE, ReadEeprom, ReadParam
from ics35_async.sim import VirtualLine, parse_url
from ics35_async.sim.adapter import PACKET_PAYLOAD, FtdiAdapter, adapter_cycle_time

BYTE_115200 = BITS_PER_BYTE / 115200
TEMPERATURE_1 = ReadParam(1, 4).tx


def test_an_echo_and_its_reply_wait_for_the_latency_timer_together() -> None:
    adapter = FtdiAdapter(16)
    on_wire = adapter.outbound(0.0)
    assert on_wire == pytest.approx(0.001)  # the next USB frame, even for a write at a frame start
    packets = adapter.inbound([(0.0012, b"\xa1\x04"), (0.0016, b"\x21\x04\x50")], BYTE_115200)
    assert packets == [(pytest.approx(0.016), b"\xa1\x04\x21\x04\x50")]


def test_the_timer_runs_from_the_last_packet() -> None:
    adapter = FtdiAdapter(16)
    adapter.inbound([(0.002, b"\x01")], BYTE_115200)  # a packet at 16 ms
    ((when, _),) = adapter.inbound([(0.020, b"\x02")], BYTE_115200)
    assert when == pytest.approx(0.032)  # not 20 + 16: the timer restarted at 16 ms


def test_62_bytes_make_a_packet_at_once_and_the_rest_waits_a_period_from_it() -> None:
    adapter = FtdiAdapter(16)
    reply = bytes(range(66))
    end = 0.010
    packets = adapter.inbound([(0.0012, b"\xa1\x00"), (end, reply)], BYTE_115200)
    assert [len(p) for _, p in packets] == [PACKET_PAYLOAD, 68 - PACKET_PAYLOAD]
    assert b"".join(p for _, p in packets) == b"\xa1\x00" + reply
    full_at = end - (66 - 60 - 1 + 1) * BYTE_115200  # the 62nd byte (the 60th of the reply) came in then
    assert full_at < packets[0][0] <= full_at + 0.001  # the next USB frame
    assert packets[1][0] == pytest.approx(packets[0][0] + 0.016)


def test_latency_timer_range_is_checked() -> None:
    for bad in (0, 256):
        with pytest.raises(InvalidArgument, match="latency_timer"):
            FtdiAdapter(bad)


def test_cycle_rates_of_32_servos() -> None:
    wire = 1 / adapter_cycle_time(None, servos=32, baudrate=115200)
    slow = 1 / adapter_cycle_time(FtdiAdapter(16), servos=32, baudrate=115200)
    fast = 1 / adapter_cycle_time(FtdiAdapter(1), servos=32, baudrate=115200)
    assert slow == pytest.approx(1 / (32 * 0.016))  # every transaction waits one period
    assert fast == pytest.approx(1 / (32 * 0.002))  # one frame out, one period back
    assert slow < fast < wire


def transaction_times(line: VirtualLine, count: int) -> list[float]:
    """The simulated time each of ``count`` temperature reads of servo 1 is delivered (fast mode)."""
    times = []
    for _ in range(count):
        chunks = line.process(TEMPERATURE_1)
        assert b"".join(c for _, c in chunks) == TEMPERATURE_1 + b"\x21\x04" + bytes([chunks[-1][1][-1]])
        times.append(line.now())
    return times


def test_a_line_behind_the_adapter_model_delivers_as_the_chip_does() -> None:
    with VirtualLine([1], adapter=FtdiAdapter(16)) as line:
        times = transaction_times(line, 5)
        chunks = line.process(TEMPERATURE_1)
        assert len(chunks) == 1  # echo and reply in one USB packet
    steps = [b - a for a, b in itertools.pairwise(times)]
    assert steps == [pytest.approx(0.016)] * 4


def test_the_default_line_is_unchanged() -> None:
    with VirtualLine([1]) as line:
        chunks = line.process(TEMPERATURE_1)
        assert chunks[0][1] == TEMPERATURE_1  # the echo, then the reply, at their wire times
        assert len(chunks) == 2
        assert line.now() < 0.001


def test_sim_url_adapter_options() -> None:
    _, options = parse_url("sim://?ids=1&adapter=ftdi&latency_timer=16")
    assert isinstance(options["adapter"], FtdiAdapter)
    assert options["adapter"].latency_timer_ms == 16
    assert options["realtime"] is True  # what the model adds is time the host waits
    _, options = parse_url("sim://?adapter=ftdi")
    assert options["adapter"].latency_timer_ms == 16  # FTDI's default
    _, options = parse_url("sim://?adapter=ftdi&latency_timer=1ms")
    assert options["adapter"].latency_timer_ms == 1
    _, options = parse_url("sim://?ids=1")
    assert "adapter" not in options


@pytest.mark.parametrize(
    ("query", "message"),
    [
        ("adapter=ch340", "unknown adapter model"),
        ("latency_timer=16", "needs an adapter model"),
        ("adapter=ftdi&latency_timer=0", "latency_timer must be in 1..255"),
        ("adapter=ftdi&latency_timer=x", "not an integer"),
        ("adapter=ftdi&realtime=0", "needs realtime=1"),
    ],
)
def test_sim_url_adapter_mistakes(query: str, message: str) -> None:
    with pytest.raises(InvalidArgument, match=message):
        parse_url(f"sim://?{query}")


def test_a_tap_hears_every_byte_on_the_wire_once() -> None:
    heard: list[bytes] = []
    with VirtualLine([1, 2]) as line:
        line.add_tap(heard.append)
        line.process(TEMPERATURE_1)
        line.process(ReadParam(5, 4).tx)  # nobody answers
        line.process(ReadEeprom(2).tx)
        eeprom_reply = line.log[-1].reply
    assert heard[0].startswith(TEMPERATURE_1) and len(heard[0]) == 5
    assert heard[1] == ReadParam(5, 4).tx
    assert heard[2] == ReadEeprom(2).tx + eeprom_reply and len(eeprom_reply) == 66


@pytest.mark.skipif(not hasattr(os, "openpty"), reason="ptys are POSIX")
def test_a_tap_pty_passes_the_bytes_to_a_listener(tmp_path: object) -> None:
    import serial

    from ics35_async.sim.tap import LineTap

    with VirtualLine([1]) as line:
        tap = LineTap(line)
        try:
            line.process(TEMPERATURE_1)  # nobody listens yet: lost, as on a wire
            listener = serial.Serial(str(tap.path), 115200, timeout=1)
            try:
                line.process(TEMPERATURE_1)
                got = listener.read(5)
            finally:
                listener.close()
        finally:
            tap.close()
    assert got[:2] == TEMPERATURE_1 and got[2:4] == b"\x21\x04"


def test_the_pty_server_command_line_takes_the_adapter_model() -> None:
    from ics35_async.sim.server_cli import build_device, build_parser

    parser = build_parser()
    line = build_device(parser.parse_args(["--ids", "1", "--adapter", "ftdi", "--latency-timer", "8"]))
    try:
        assert isinstance(line, VirtualLine) and line.realtime
        assert line.adapter is not None and line.adapter.latency_timer_ms == 8
    finally:
        line.close()
    plain = build_device(parser.parse_args(["--ids", "1"]))
    assert isinstance(plain, VirtualLine) and plain.adapter is None
    plain.close()
    with pytest.raises(InvalidArgument, match="cannot be used with --fast"):
        build_device(parser.parse_args(["--adapter", "ftdi", "--fast"]))
    with pytest.raises(InvalidArgument, match="needs an adapter model"):
        build_device(parser.parse_args(["--latency-timer", "1"]))
