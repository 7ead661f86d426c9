"""sim:// URLs: parsing, defaults, named lines, and the in-process port opened from a URL."""

from __future__ import annotations

import itertools
import pathlib
import threading
import time
from typing import Any

import anyio
import pytest

from ics35_async import open_bus, units
from ics35_async.eeprom import BaudRate
from ics35_async.errors import InvalidArgument, PortBusy
from ics35_async.protocol import Position, ReadParam
from ics35_async.sim import FaultConfig, ReplayDevice, VirtualLine, VirtualServo, named, open_url, parse_url
from ics35_async.sim import url as sim_url
from ics35_async.sim.virtual_servo import NOISY_JUMP
from ics35_async.transports import DevicePort, WireDevice, open_port


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


async def test_a_noisy_servos_readings_jump_either_side_of_where_it_is_and_never_agree() -> None:
    # A broken potentiometer: what a robot must not take as where the joint is, nor wait on for ever.
    try:
        async with open_bus("sim://noisy-url?ids=1-2&noisy=2", adapter_latency=0.003) as bus:
            line = named("noisy-url")
            assert line.servo(2).noisy and not line.servo(1).noisy
            clean = [await bus.servo(1).free() for _ in range(4)]
            noisy = [await bus.servo(2).free() for _ in range(4)]
        at = line.servo(2).position
        assert clean == [line.servo(1).position] * 4
        assert all(abs(p - at) <= NOISY_JUMP for p in noisy) and len(set(noisy)) == len(noisy), noisy
    finally:
        line.close()


@pytest.mark.parametrize("every", [1, 2, 3, 4, 7, 11, 25])
def test_a_noisy_servos_readings_disagree_however_many_a_reader_skips(every: int) -> None:
    # A reader at its own pace (a robot takes each line's newest cycle) sees every few reports: no two of those agree
    # either, or the readings, far from where the servo is, would be taken as where it is.
    from ics35_async.robot.robot import TURN_SLACK, TURN_STEP

    servo = VirtualServo(2, noisy=True)
    reports = [servo.handle(Position(2, 0, baudrate=115200)) for _ in range(12 * every)][::every]
    apart = [abs(b - a) / units.COUNTS_PER_DEGREE for a, b in itertools.pairwise(reports)]
    assert min(apart) > TURN_STEP + TURN_SLACK, (reports, apart)
    assert all(abs(p - servo.position) <= NOISY_JUMP for p in reports), reports


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
        "sim://?noisy=40",
    ],
)
def test_bad_urls(url: str) -> None:
    with pytest.raises(InvalidArgument):
        parse_url(url)


@pytest.mark.parametrize("ids", ["", ",", " ", "%20,%20"])
def test_an_id_list_naming_no_servo_is_refused_naming_the_key_and_what_it_takes(ids: str) -> None:
    """``sim://?ids=`` (a script's unset variable) opened a line without servos, silently: every command then
    timed out.  An empty line is asked for in words, ``ids=none``."""
    with pytest.raises(InvalidArgument) as info:
        parse_url(f"sim://?ids={ids}")
    said = str(info.value)
    assert said.startswith("sim URL: ids="), said
    assert "0-31" in said and "none" in said, said
    assert parse_url("sim://?ids=none")[1]["servos"] == []


@pytest.mark.parametrize(
    ("query", "key"),
    [
        ("unplug_after=0.1&replug_after=inf", "replug_after"),
        ("unplug_after=0.1&replug_after=nan", "replug_after"),
        ("unplug_after=inf", "unplug_after"),
        ("unplug_after=nan", "unplug_after"),
        ("unplug_after=0.1&replug_after=1e12", "replug_after"),
        ("turnaround=inf", "turnaround"),
        ("late_delay=nan&faults=late:1", "late_delay"),
        ("tail_delay=inf&faults=tail:1", "tail_delay"),
        ("eeprom_delay=nan", "eeprom_delay"),
    ],
)
async def test_a_duration_no_timer_can_wait_is_refused_as_the_bus_opens(query: str, key: str) -> None:
    """``replug_after=inf`` (a port that never comes back, as a user says it) went to a timer thread that died with
    an ``OverflowError`` traceback once the port was pulled, and ``nan`` replugged at once: each such duration is
    refused, naming its key, before anything is opened."""
    with pytest.raises(InvalidArgument, match=f"^{key} "):
        async with open_bus(f"sim://?ids=1&realtime=1&{query}"):
            pass


@pytest.mark.parametrize("option", ["unplug_after", "replug_after", "turnaround", "tail_delay"])
@pytest.mark.parametrize("value", [float("inf"), float("nan")])
def test_a_line_built_in_python_refuses_a_duration_no_timer_can_wait(option: str, value: float) -> None:
    with pytest.raises(InvalidArgument, match=f"^{option} "):
        VirtualLine([1], **{option: value})


@pytest.mark.parametrize("url", ["sim://?ids=1-2&noisy=3", "sim://?ids=1-2&ics36=0"])
def test_an_ics36_or_noisy_id_outside_the_urls_ids_is_refused(url: str) -> None:
    with pytest.raises(InvalidArgument, match="no servo of this line is built from ID"):
        open_url(url)


def test_a_log_size_below_zero_is_refused_in_words() -> None:
    """``log=-1`` was passed on to the log's deque, which raised a bare ValueError ("maxlen must be
    non-negative"), naming neither the option nor what it takes."""
    with pytest.raises(InvalidArgument, match=r"^log_size must be a whole number of transactions >= 0"):
        VirtualLine([1], log_size=-1)


@pytest.mark.parametrize("value", ["-1", "-20", "abc", "1.5", "every"])
def test_a_urls_log_not_a_size_is_refused_naming_the_urls_own_option(value: str) -> None:
    # The URL's refusal named log_size, the Python argument, which the user never typed; a word other than all
    # was "not an integer", as if all were not taken.
    for refuse in (lambda: parse_url(f"sim://?log={value}"), lambda: open_url(f"sim://?log={value}")):
        with pytest.raises(InvalidArgument) as refused:
            refuse()
        said = str(refused.value)
        assert said.startswith(f"sim URL: log={value!r}: "), said
        assert "log_size" not in said and ">= 0" in said and "all" in said, said


def test_the_cli_names_the_urls_log_option(cli: Any) -> None:
    result = cli("--port", "sim://?log=-1", "get", "1", "stretch")
    assert result.code == 2, result.err
    assert "log='-1'" in result.err and "log_size" not in result.err, result.err


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


def test_a_named_line_asked_for_with_other_options_is_refused_while_it_runs() -> None:
    # The same name with other servos (a typo, or a test that reused a name) would silently get the
    # first line's servos: refused in words.  The same options, or none, find it.
    line = open_url("sim://arm?ids=1-3&baud=625000")
    try:
        assert open_url("sim://arm?baud=625000&ids=1-3") is line  # (the keys in any order)
        assert open_url("sim://arm") is line
        with pytest.raises(InvalidArgument, match="sim://arm is open already with other options"):
            open_url("sim://arm?ids=5")
    finally:
        line.close()


def test_a_named_line_open_on_one_bus_is_busy_for_a_second_one_in_words() -> None:
    # A bare OSError ("the simulated port is already open") came out with a traceback, unlike a busy tty.
    async def main() -> None:
        async with open_bus("sim://twice?ids=1-2"):
            with pytest.raises(PortBusy, match="sim://twice is already open: a simulated line takes one bus"):
                await open_bus("sim://twice").open()
        async with open_bus("sim://twice") as again:  # closed, the name still finds the same servos
            assert await again.servo(2).free() == 7500

    try:
        anyio.run(main)
    finally:
        named("twice").close()


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


class Collect:
    """The host end as a driver holds it: the DevicePort open_port gives, read when it says so."""

    def __init__(self, url: str, baudrate: int) -> None:
        port = open_port(url, baudrate)
        assert isinstance(port, DevicePort)
        self.port = port
        self.data = bytearray()
        self.arrived = threading.Event()
        port.on_input = self.arrived.set

    def write(self, data: bytes) -> None:
        self.port.write(data)

    def expect(self, count: int) -> bytes:
        deadline = time.monotonic() + 5
        while len(self.data) < count:
            assert time.monotonic() < deadline, bytes(self.data)
            self.arrived.wait(0.05)
            self.arrived.clear()
            self.data += self.port.read()
        out = bytes(self.data[:count])
        del self.data[:count]
        return out


def test_open_port_with_a_sim_url_talks_to_the_simulator() -> None:
    line = Collect("sim://url-e2e?ids=1-3", 115200)
    bus = named("url-e2e")
    try:
        command = Position(2, 8000, baudrate=115200)
        line.write(command.tx)
        received = line.expect(6)
        assert received[:3] == command.tx
        assert command.parse(received[3:]) == 7500
        assert bus.log[-1].servo_id == 2
        bus.unplug()
        with pytest.raises(OSError):
            line.expect(1)
    finally:
        line.port.close()
        bus.close()


def test_host_baud_sets_the_line_rate_in_process() -> None:
    line = Collect("sim://baud-e2e?ids=1&baud=625000", 115200)
    bus = named("baud-e2e")
    try:
        line.write(ReadParam(1, 2).tx)
        assert line.expect(2) == ReadParam(1, 2).tx
        time.sleep(0.01)
        assert line.port.read() == b""  # servos at 625000 do not hear a 115200 host
    finally:
        line.port.close()
    line = Collect("sim://baud-e2e", 625000)
    try:
        line.write(ReadParam(1, 2).tx)
        assert line.expect(5)[2:] == bytes.fromhex("21 02 7F")
    finally:
        line.port.close()
        bus.close()


def test_realtime_line_through_open_port() -> None:
    line = Collect("sim://rt-e2e?ids=1&baud=1250000&realtime=1", 1250000)
    bus = named("rt-e2e")
    try:
        for target in (7000, 8000, 9000):
            command = Position(1, target, baudrate=1250000)
            line.write(command.tx)
            received = line.expect(6)
            assert received[:3] == command.tx and received[3] == 0x01
        assert bus.transactions == 3
    finally:
        line.port.close()
        bus.close()


def test_ids_none_is_a_line_without_servos_as_ics35_sim_takes_it() -> None:
    # `ics35 sim --ids none` served an empty line; `sim://?ids=none` was refused as "not an ID".
    assert parse_url("sim://?ids=none")[1]["servos"] == []
    assert parse_url("sim://?ids=None")[1]["servos"] == []
    line = open_url("sim://?ids=none")
    assert isinstance(line, VirtualLine) and not line.servos
    line.close()


@pytest.mark.parametrize("url", ["SIM://?ids=1-3", "Sim://?ids=1-3"])
async def test_a_url_scheme_in_capitals_opens_the_same_port(url: str) -> None:
    # URL schemes are case-insensitive (RFC 3986): SIM:// was refused as "protocol 'sim' not known".
    async with open_bus(url) as bus:
        assert await bus.scan(range(5)) == [1, 2, 3]


def test_the_cli_takes_a_url_scheme_in_capitals_for_the_simulator_it_names(cli: Any) -> None:
    lower = cli("--port", "sim://?ids=1-3", "scan", "--quick")
    upper = cli("--port", "SIM://?ids=1-3", "scan", "--quick")
    assert lower.code == 0
    assert (upper.code, upper.out, upper.err) == (0, lower.out.replace("sim://", "SIM://"), lower.err)
    # What the CLI does for the simulator (no serial port to listen on) it does for SIM:// as for sim://.
    refused = [cli("--port", port, "sniff") for port in ("sim://", "SIM://")]
    assert refused[0].code != 0 and "listens on a serial port" in refused[0].err
    assert (refused[1].code, refused[1].err) == (refused[0].code, refused[0].err)


@pytest.mark.parametrize(
    "url", ["sim://", "sim:///?ids=5", "SIM://?ids=1-2", "sim://arm", "sim://arm/?ids=1", "sim:///arm"]
)
def test_a_robot_file_shares_a_sim_port_between_lines_only_when_each_opening_is_a_line_of_its_own(url: str) -> None:
    """A robot file refuses two lines on one port unless opening it twice gives two lines: the simulator's
    rule for an unnamed URL, which the robot layer reads from the transports, not a copy of its own."""
    from ics35_async.robot.description import DescriptionError, load_description

    first, second = open_url(url), open_url(url)
    try:
        own = first is not second
    finally:
        for line in {id(first): first, id(second): second}.values():
            assert isinstance(line, VirtualLine)
            line.close()
    joints = {"x": {"line": "a", "id": 1}, "y": {"line": "b", "id": 1}}
    description = {"lines": {"a": {"port": url}, "b": {"port": url}}, "joints": joints}
    if own:
        assert load_description(description)
    else:
        with pytest.raises(DescriptionError, match=r"already the port of lines\.a"):
            load_description(description)
