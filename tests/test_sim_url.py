"""sim:// URLs: parsing, defaults, named lines, and the in-process transport opened from a URL."""

from __future__ import annotations

import asyncio
import pathlib

import pytest

from ics35_async.eeprom import BaudRate
from ics35_async.errors import InvalidArgument
from ics35_async.protocol import Position, ReadParam
from ics35_async.sim import FaultConfig, ReplayDevice, VirtualLine, named, open_url, parse_url
from ics35_async.sim import url as sim_url
from ics35_async.transports import WireDevice, open_line


def test_bare_url_is_32_servos_at_115200_in_fast_mode() -> None:
    bus = open_url("sim://")
    assert isinstance(bus, VirtualLine)
    assert sorted(s.servo_id for s in bus.servos) == list(range(32))
    assert bus.baudrate == 115200 and not bus.realtime and bus.echo
    assert all(s.baud_rate == BaudRate.B115200 for s in bus.servos)
    assert not bus.faults.config


def test_full_query() -> None:
    name, options = parse_url(
        "sim://?ids=1,3,5-7&baud=1250000&realtime=1&seed=3&faults=drop:0.01,late@3:0.5"
        "&echo=0&turnaround=80us&eeprom_delay=5ms&late_delay=0.1&memory=20-21&log=all"
        "&unplug_after=2s&replug_after=0.5&follow_baud=0"
    )
    assert name is None
    assert options["servos"] == [1, 3, 5, 6, 7]
    assert options["baudrate"] == 1250000
    assert options["realtime"] is True and options["echo"] is False and options["follow_host_baud"] is False
    assert options["seed"] == 3
    assert options["faults"] == FaultConfig.parse("drop:0.01,late@3:0.5")
    assert options["turnaround"] == pytest.approx(80e-6)
    assert options["eeprom_write_delay"] == pytest.approx(5e-3)
    assert options["late_delay"] == pytest.approx(0.1)
    assert options["unplug_after"] == pytest.approx(2.0) and options["replug_after"] == pytest.approx(0.5)
    assert options["memory"] == {20: b"", 21: b""}
    assert options["log_size"] is None
    bus = VirtualLine(**options)
    assert bus.servo(5).baud_rate == 1250000
    assert bus.memory_device(21).memory == bytearray(128)
    bus.close()


@pytest.mark.parametrize(
    "url",
    [
        "serial:///dev/ttyUSB0",
        "sim://?ids=0-40",
        "sim://?baud=9600",
        "sim://?realtime=maybe",
        "sim://?seed=x",
        "sim://?faults=boom:1",
        "sim://?turnaround=-1",
        "sim://?colour=red",
        "sim://?ids=1&ids=2",
    ],
)
def test_bad_urls(url: str) -> None:
    with pytest.raises(InvalidArgument):
        parse_url(url)


def test_named_line_is_shared_until_closed() -> None:
    bus = open_url("sim://robot?ids=1-2")
    assert isinstance(bus, VirtualLine)
    try:
        assert open_url("sim://robot") is bus
        assert named("robot") is bus
    finally:
        bus.close()
    with pytest.raises(KeyError):
        named("robot")
    fresh = open_url("sim://robot?ids=4")
    assert isinstance(fresh, VirtualLine) and fresh is not bus
    fresh.close()


def test_line_built_in_python_is_reachable_by_name() -> None:
    with VirtualLine([9], name="from-python") as bus:
        assert open_url("sim://from-python?ids=0-31") is bus


def test_replay_url(tmp_path: object) -> None:
    import pathlib

    path = pathlib.Path(str(tmp_path)) / "session.txt"
    path.write_text("0.0 81 3a 4c -> 81 3a 4c | 01 3a 4c\n")
    device = open_url(f"sim://?replay={path}")
    assert isinstance(device, ReplayDevice) and device.remaining == 1
    with pytest.raises(InvalidArgument, match="replay= takes no other options"):
        open_url(f"sim://?replay={path}&ids=1")


@pytest.mark.parametrize("query", ["", "?ids=1&realtime=1", "?replay=REC"])
def test_open_url_is_the_one_way_from_a_url_to_a_wire_device(query: str, tmp_path: pathlib.Path) -> None:
    # What the core's scheme map points at: ics35_async.sim.url.open_url (re-exported as sim.open_url).
    assert sim_url.open_url is open_url
    recording = tmp_path / "r.txt"
    recording.write_text("# nothing recorded\n")
    device = sim_url.open_url("sim://" + query.replace("REC", str(recording)))
    assert isinstance(device, WireDevice)
    device.close()  # type: ignore[attr-defined]


class Collect(asyncio.Protocol):
    def __init__(self) -> None:
        self.data = bytearray()
        self.arrived = asyncio.Event()
        self.lost: list[Exception | None] = []

    def data_received(self, data: bytes) -> None:
        self.data += data
        self.arrived.set()

    def connection_lost(self, exc: Exception | None) -> None:
        self.lost.append(exc)

    async def expect(self, count: int) -> bytes:
        while len(self.data) < count:
            self.arrived.clear()
            await asyncio.wait_for(self.arrived.wait(), 5)
        out = bytes(self.data[:count])
        del self.data[:count]
        return out


async def test_open_line_with_a_sim_url_talks_to_the_simulator() -> None:
    transport, protocol = await open_line("sim://url-e2e?ids=1-3", baudrate=115200, protocol_factory=Collect)
    bus = named("url-e2e")
    try:
        command = Position(2, 8000, baudrate=115200)
        transport.write(command.tx)
        received = await protocol.expect(6)
        assert received[:3] == command.tx
        assert command.parse(received[3:]) == 7500
        assert bus.log[-1].servo_id == 2
        bus.unplug()
        await asyncio.sleep(0.01)
        assert protocol.lost and isinstance(protocol.lost[0], OSError)
    finally:
        transport.close()
        bus.close()


async def test_host_baud_sets_the_line_rate_in_process() -> None:
    transport, protocol = await open_line("sim://baud-e2e?ids=1&baud=625000", baudrate=115200, protocol_factory=Collect)
    bus = named("baud-e2e")
    try:
        transport.write(ReadParam(1, 2).tx)
        assert await protocol.expect(2) == ReadParam(1, 2).tx
        await asyncio.sleep(0.01)
        assert protocol.data == b""  # servos at 625000 do not hear a 115200 host
    finally:
        transport.close()
    transport, protocol = await open_line("sim://baud-e2e", baudrate=625000, protocol_factory=Collect)
    try:
        transport.write(ReadParam(1, 2).tx)
        assert (await protocol.expect(5))[2:] == bytes.fromhex("21 02 7F")
    finally:
        transport.close()
        bus.close()


async def test_realtime_line_through_open_line() -> None:
    transport, protocol = await open_line(
        "sim://rt-e2e?ids=1&baud=1250000&realtime=1", baudrate=1250000, protocol_factory=Collect
    )
    bus = named("rt-e2e")
    try:
        for target in (7000, 8000, 9000):
            command = Position(1, target, baudrate=1250000)
            transport.write(command.tx)
            received = await protocol.expect(6)
            assert received[:3] == command.tx and received[3] == 0x01
        assert bus.transactions == 3
    finally:
        transport.close()
        bus.close()
