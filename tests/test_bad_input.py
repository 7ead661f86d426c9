"""Bad input everywhere, and the dangerous writes.

Every public entry point (Bus, open_bus, BusTiming, Servo, Device, Stream,
BusGroup, GroupStream, Eeprom.replace) and every CLI command gets
out-of-range, wrong-type and boundary arguments.  A bad one must raise
:class:`InvalidArgument` (the CLI: a message, exit code 2, no traceback)
before a single byte reaches the line (``sim.transactions`` unchanged); a
value just inside a boundary must work.
"""

from __future__ import annotations

import asyncio
import contextlib
import io
import itertools
import math
import subprocess
import sys
from collections.abc import AsyncIterator, Awaitable, Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ics35_async import (
    BaudRate,
    Bus,
    BusGroup,
    BusTiming,
    Eeprom,
    Flags,
    InvalidArgument,
    Priority,
    ReplyTimeout,
    Servo,
    UnsafeOperation,
    blocking,
    open_bus,
    open_robot,
    protocol,
)
from ics35_async.cli import main as cli_main
from ics35_async.eeprom import EEPROM_FIELDS
from ics35_async.group import GroupStream
from ics35_async.sim import VirtualLine, VirtualServo
from ics35_async.stream import Stream
from tests.support.timing import FAST, FAST_TIMING


@dataclass
class Env:
    sim: VirtualLine
    bus: Bus
    image: Eeprom
    stream: Stream
    group: GroupStream

    @property
    def servo(self) -> Servo:
        return self.bus.servo(1)


@pytest.fixture
async def env() -> AsyncIterator[Env]:
    sim = VirtualLine([VirtualServo(1), VirtualServo(2)], memory={5: bytes(128)})
    async with open_bus(sim, timing=FAST_TIMING) as bus:
        image = await bus.servo(1).read_eeprom()
        stream = bus.stream([1, 2])  # built, not started: argument checks need no traffic
        group = BusGroup({"a": bus}).stream({"a": [1, 2]})
        yield Env(sim, bus, image, stream, group)
    sim.close()


async def outcome(call: Callable[[Env], Any], env: Env) -> Any:
    result = call(env)
    if isinstance(result, Awaitable):
        result = await result
    return result


# (label, call): every one must raise InvalidArgument and write nothing.
BAD_CALLS: list[Any] = [
    # open_bus / Bus / BusTiming
    ("open_bus port int", lambda e: open_bus(123)),  # type: ignore[arg-type]
    ("open_bus baud 9600", lambda e: open_bus(e.sim, baudrate=9600)),
    ("open_bus baud str", lambda e: open_bus(e.sim, baudrate="fast")),  # type: ignore[arg-type]
    ("open_bus retries 11", lambda e: open_bus(e.sim, retries=11)),
    ("open_bus retries -1", lambda e: open_bus(e.sim, retries=-1)),
    ("open_bus retries float", lambda e: open_bus(e.sim, retries=1.0)),  # type: ignore[arg-type]
    ("open_bus unknown option", lambda e: open_bus(e.sim, bogus=1.0)),
    ("open_bus latency nan", lambda e: open_bus(e.sim, adapter_latency=math.nan)),
    ("open_bus latency -1", lambda e: open_bus(e.sim, adapter_latency=-1)),
    ("open_bus latency 61", lambda e: open_bus(e.sim, adapter_latency=61)),
    ("open_bus latency str", lambda e: open_bus(e.sim, adapter_latency="1")),  # type: ignore[arg-type]
    ("open_bus max_requests_between 0", lambda e: open_bus(e.sim, max_requests_between=0)),
    ("open_bus transport bogus", lambda e: open_bus(VirtualLine([1]), transport="bogus").open()),
    ("open_bus empty port", lambda e: open_bus("").open()),
    ("open_bus sim url bad ids", lambda e: open_bus("sim://?ids=40").open()),
    ("open_bus sim url empty ids", lambda e: open_bus("sim://?ids=").open()),  # (was a line of no servos)
    ("BusTiming quiet -1", lambda e: BusTiming(quiet_time=-1)),
    ("BusTiming max_resync inf", lambda e: BusTiming(max_resync=math.inf)),
    ("open_bus timing str", lambda e: open_bus(e.sim, timing="x")),  # type: ignore[arg-type]
    ("open_bus backoff int", lambda e: open_bus(e.sim, reconnect_backoff=5)),  # type: ignore[arg-type]
    ("open_bus backoff str", lambda e: open_bus(e.sim, reconnect_backoff="ab")),  # type: ignore[arg-type]
    ("open_bus backoff negative", lambda e: open_bus(e.sim, reconnect_backoff=(-1,))),
    ("open_bus backoff empty", lambda e: open_bus(e.sim, reconnect_backoff=())),  # (was taken as 0.5 s, said nowhere)
    ("open_bus retries True", lambda e: open_bus(e.sim, retries=True)),
    ("open_bus latency True", lambda e: open_bus(e.sim, adapter_latency=True)),
    ("open_bus echo str", lambda e: open_bus(e.sim, echo="no")),  # type: ignore[arg-type]
    # Bus methods
    ("request not a command", lambda e: e.bus.request("a1 01")),
    ("request priority 9", lambda e: e.bus.request(protocol.ReadParam(1, 1), priority=9)),
    ("request priority -1", lambda e: e.bus.request(protocol.ReadParam(1, 1), priority=-1)),
    ("request priority float", lambda e: e.bus.request(protocol.ReadParam(1, 1), priority=2.0)),
    ("request retries 11", lambda e: e.bus.request(protocol.ReadParam(1, 1), retries=11)),
    ("submit retries str", lambda e: e.bus.submit(protocol.ReadParam(1, 1), retries="1")),
    ("request priority True", lambda e: e.bus.request(protocol.ReadParam(1, 1), priority=True)),
    ("request retries True", lambda e: e.bus.request(protocol.ReadParam(1, 1), retries=True)),
    ("servo id 32", lambda e: e.bus.servo(32)),
    ("servo id -1", lambda e: e.bus.servo(-1)),
    ("servo id str", lambda e: e.bus.servo("1")),
    ("servo id True", lambda e: e.bus.servo(True)),
    ("device id 32", lambda e: e.bus.device(32)),
    ("servos bad id", lambda e: e.bus.servos([1, 40])),
    ("scan bad id", lambda e: e.bus.scan([40])),
    ("read_id unconfirmed", lambda e: e.bus.read_id()),
    ("write_id unconfirmed", lambda e: e.bus.write_id(3)),
    ("write_id confirmed truthy", lambda e: e.bus.write_id(3, exactly_one_device="yes")),
    ("write_id 32", lambda e: e.bus.write_id(32, exactly_one_device=True)),
    ("write_id str", lambda e: e.bus.write_id("3", exactly_one_device=True)),
    ("reopen 9600", lambda e: e.bus.reopen(baudrate=9600)),
    ("servos int", lambda e: e.bus.servos(5)),
    ("scan int", lambda e: e.bus.scan(5)),
    ("scan concurrency 0", lambda e: e.bus.scan([1], concurrency=0)),
    # Servo
    ("set_position 0 (free is free())", lambda e: e.servo.set_position(0)),
    ("set_position 16384", lambda e: e.servo.set_position(16384)),
    ("set_position -1", lambda e: e.servo.set_position(-1)),
    ("set_position float", lambda e: e.servo.set_position(7500.0)),
    ("set_position str", lambda e: e.servo.set_position("7500")),
    ("set_position None", lambda e: e.servo.set_position(None)),
    ("set_degrees 400", lambda e: e.servo.set_degrees(400)),
    ("set_degrees nan", lambda e: e.servo.set_degrees(math.nan)),
    ("set_degrees inf", lambda e: e.servo.set_degrees(-math.inf)),
    ("set_degrees str", lambda e: e.servo.set_degrees("10")),
    ("set_radians 10", lambda e: e.servo.set_radians(10)),
    ("set_radians nan", lambda e: e.servo.set_radians(math.nan)),
    ("free priority 9", lambda e: e.servo.free(priority=9)),
    ("write_stretch 0", lambda e: e.servo.write_stretch(0)),
    ("write_stretch 128", lambda e: e.servo.write_stretch(128)),
    ("write_speed 0", lambda e: e.servo.write_speed(0)),
    ("write_speed True", lambda e: e.servo.write_speed(True)),
    ("write_current_limit 64", lambda e: e.servo.write_current_limit(64)),
    ("write_current_limit 0", lambda e: e.servo.write_current_limit(0)),
    ("write_temperature_limit 128", lambda e: e.servo.write_temperature_limit(128)),
    ("write_temperature_limit float", lambda e: e.servo.write_temperature_limit(80.0)),
    ("write_eeprom bytes", lambda e: e.servo.write_eeprom(e.image.to_bytes())),
    ("write_eeprom None", lambda e: e.servo.write_eeprom(None)),
    ("Servo priority 9 (at the request)", lambda e: Servo(e.bus, 1, priority=9).read_stretch()),  # type: ignore[arg-type]
    ("Servo on a non-bus", lambda e: Servo("bus", 1).read_stretch()),  # type: ignore[arg-type]
    # Device
    ("read_memory address -1", lambda e: e.bus.device(5).read_memory(-1, 1)),
    ("read_memory address 128", lambda e: e.bus.device(5).read_memory(128, 1)),
    ("read_memory count 0", lambda e: e.bus.device(5).read_memory(0, 0)),
    ("read_memory count 128", lambda e: e.bus.device(5).read_memory(0, 128)),
    ("read_memory past the end", lambda e: e.bus.device(5).read_memory(100, 29)),
    ("read_memory str", lambda e: e.bus.device(5).read_memory("0", 1)),
    ("write_memory empty", lambda e: e.bus.device(5).write_memory(0, b"")),
    ("write_memory past the end", lambda e: e.bus.device(5).write_memory(127, b"ab")),
    ("write_memory 128 bytes", lambda e: e.bus.device(5).write_memory(0, bytes(128))),
    ("write_memory str", lambda e: e.bus.device(5).write_memory(0, "ab")),
    ("write_memory int", lambda e: e.bus.device(5).write_memory(0, 3)),
    ("write_memory 256", lambda e: e.bus.device(5).write_memory(0, [256])),
    ("write_memory None", lambda e: e.bus.device(5).write_memory(0, None)),
    # Stream
    ("stream no ids", lambda e: e.bus.stream([])),
    ("stream duplicate ids", lambda e: e.bus.stream([1, 1])),
    ("stream id 32", lambda e: e.bus.stream([32])),
    ("stream rate 0", lambda e: e.bus.stream([1], rate_hz=0)),
    ("stream rate nan", lambda e: e.bus.stream([1], rate_hz=math.nan)),
    ("stream rate str", lambda e: e.bus.stream([1], rate_hz="100")),
    ("stream offline_after 0", lambda e: e.bus.stream([1], offline_after=0)),
    ("stream probe_interval 0", lambda e: e.bus.stream([1], probe_interval=0)),
    ("stream probe_interval nan", lambda e: e.bus.stream([1], probe_interval=math.nan)),
    ("set_target id not in stream", lambda e: e.stream.set_target(9, 7500)),
    ("set_target id str", lambda e: e.stream.set_target("1", 7500)),
    ("set_target id float", lambda e: e.stream.set_target(1.0, 7500)),  # (servo(1.0) is refused: so is this)
    ("set_target id True", lambda e: e.stream.set_target(True, 7500)),
    ("set_targets id float", lambda e: e.stream.set_targets({1.0: 7500})),
    ("set_targets_degrees id float", lambda e: e.stream.set_targets_degrees({2.0: 10})),
    ("stream target id True", lambda e: e.stream.target(True)),
    ("stream watch id float", lambda e: e.stream.watch([1.0])),
    ("group set_target id float", lambda e: e.group.set_target("a", 1.0, 7500)),
    ("set_target 16384", lambda e: e.stream.set_target(1, 16384)),
    ("set_target -1", lambda e: e.stream.set_target(1, -1)),
    ("set_target float", lambda e: e.stream.set_target(1, 7500.0)),
    ("set_targets one bad", lambda e: e.stream.set_targets({1: 7500, 2: 20000})),
    ("set_target_degrees nan", lambda e: e.stream.set_target_degrees(1, math.nan)),
    ("set_targets_degrees huge", lambda e: e.stream.set_targets_degrees({1: 1e308})),
    ("stream free id not in stream", lambda e: e.stream.free([9])),
    ("stream target id not in stream", lambda e: e.stream.target(9)),
    ("stream ids int", lambda e: e.bus.stream(5)),
    ("stream option bus", lambda e: e.bus.stream([1], bus=e.bus)),
    ("stream free int", lambda e: e.stream.free(5)),
    ("set_targets str", lambda e: e.stream.set_targets("abc")),
    ("set_targets None", lambda e: e.stream.set_targets(None)),
    ("stream history -1", lambda e: e.bus.stream([1], history=-1)),
    ("stream history str", lambda e: e.bus.stream([1], history="x")),
    ("stream unknown option", lambda e: e.bus.stream([1], bogus=1)),
    ("stream offline_after True", lambda e: e.bus.stream([1], offline_after=True)),
    ("stream offline duplicate id", lambda e: e.bus.stream([1, 2], offline=[1, 1])),
    ("stream offline id not in stream", lambda e: e.bus.stream([1, 2], offline=[3])),
    ("stream watch duplicate id", lambda e: e.bus.stream([1, 2], watch=[2, 2])),
    ("stream watch id not in stream", lambda e: e.bus.stream([1, 2], watch=[3])),
    # BusGroup / GroupStream
    ("group empty", lambda e: BusGroup({})),
    ("group not a bus", lambda e: BusGroup({"a": 1})),  # type: ignore[dict-item]
    ("group open bad port", lambda e: BusGroup.open({"a": 5})),  # type: ignore[dict-item]
    ("group open of a str", lambda e: BusGroup.open("sim://?ids=1")),  # type: ignore[arg-type]
    ("group open of an int", lambda e: BusGroup.open(5)),  # type: ignore[arg-type]
    ("group stream unknown line", lambda e: BusGroup({"a": e.bus}).stream({"b": [1]})),
    ("group stream bad id", lambda e: BusGroup({"a": e.bus}).stream({"a": [40]})),
    ("group stream bad rate", lambda e: BusGroup({"a": e.bus}).stream({"a": [1]}, rate_hz=-1)),
    ("group stream no lines", lambda e: BusGroup({"a": e.bus}).stream({})),
    ("group stream of no streams", lambda e: GroupStream({})),
    ("group set_target unknown line", lambda e: e.group.set_target("b", 1, 7500)),
    ("group set_target bad position", lambda e: e.group.set_target("a", 1, 0.5)),
    ("group set_targets bad position", lambda e: e.group.set_targets({("a", 1): "x"})),
    ("group of an int", lambda e: BusGroup(5)),  # type: ignore[arg-type]
    ("group stream int", lambda e: BusGroup({"a": e.bus}).stream(5)),  # type: ignore[arg-type]
    ("group set_targets bad key", lambda e: e.group.set_targets({"a": 1})),
    # Eeprom.replace
    ("eeprom calibration", lambda e: e.image.replace(calibration=bytes(22))),
    ("eeprom unknown field", lambda e: e.image.replace(colour=3)),
    ("eeprom speed 0", lambda e: e.image.replace(speed=0)),
    ("eeprom speed True", lambda e: e.image.replace(speed=True)),
    ("eeprom stretch odd", lambda e: e.image.replace(stretch_gain=61)),
    ("eeprom stretch 256", lambda e: e.image.replace(stretch_gain=256)),
    ("eeprom offset -128", lambda e: e.image.replace(user_offset=-128)),
    ("eeprom offset float", lambda e: e.image.replace(user_offset=1.0)),
    ("eeprom id 32", lambda e: e.image.replace(servo_id=32)),
    ("eeprom baud 9600", lambda e: e.image.replace(baud_rate=9600)),
    ("eeprom flags str", lambda e: e.image.replace(flags="REVERSE")),
    ("eeprom flags unused bits", lambda e: e.image.replace(flags=0x20)),
    ("eeprom flags read-only", lambda e: e.image.replace(flags=Flags.FREE)),
    ("eeprom limits crossed", lambda e: e.image.replace(pulse_limit_low=9000, pulse_limit_high=8000)),
    ("eeprom pulse limit 3499", lambda e: e.image.replace(pulse_limit_low=3499)),
]


def _label(case: Any) -> str:
    return str(case.values[0] if hasattr(case, "marks") else case[0])


@pytest.mark.parametrize(("label", "call"), BAD_CALLS, ids=[_label(c) for c in BAD_CALLS])
async def test_bad_argument_is_refused_before_the_wire(env: Env, label: str, call: Callable[[Env], Any]) -> None:
    before = env.sim.transactions
    try:
        with pytest.raises(InvalidArgument) as info:
            await outcome(call, env)
    finally:
        assert env.sim.transactions == before, f"{label}: bytes went on the line"
    assert str(info.value), "the error says what is wrong"
    assert await env.bus.servo(2).read_stretch() == 30  # and the bus is fine


@pytest.mark.parametrize("port", ["sim://?ids=1", Path("/dev/ttyUSB0")])
def test_a_group_given_a_port_for_a_bus_points_at_open_bus_and_busgroup_open(port: object) -> None:
    # BusGroup({"legs": "/dev/ttyUSB0"}): BusGroup.open takes ports, BusGroup takes buses.
    with pytest.raises(InvalidArgument, match=r"line 'legs' is a port, not a Bus: .*open_bus\(.*BusGroup\.open\("):
        BusGroup({"legs": port})  # type: ignore[dict-item]


async def test_an_async_context_manager_used_with_plain_with_says_how_to_use_it(env: Env) -> None:
    # `with bus.stream(...)` in async code (the `async` forgotten) is said as `with open_bus(...)` is:
    # how to write it, not "'Stream' object does not support the context manager protocol".
    before = env.sim.transactions
    uses = [
        (env.stream, r"`async with bus\.stream\(\.\.\.\) as stream:`"),
        (env.group, r"`async with group\.stream\(\.\.\.\) as stream:`"),
        (BusGroup({"a": env.bus}), r"`async with BusGroup\(\.\.\.\) as group:`"),
    ]
    for manager, how in uses:
        with pytest.raises(TypeError, match=how), manager:  # type: ignore[attr-defined]
            pytest.fail("entered")
    assert env.sim.transactions == before and env.bus.is_open
    assert await env.bus.servo(2).read_stretch() == 30
    robot_line = {"lines": {"m": {"port": "sim://bad-input-robot?ids=1"}}, "joints": {"j": {"line": "m", "id": 1}}}
    async with open_robot(robot_line, **FAST) as robot:
        with pytest.raises(TypeError, match=r"`async with robot\.stream\(\) as stream:`"), robot.stream():  # type: ignore[attr-defined]
            pytest.fail("entered")
        assert set(await robot.read_pose()) == {"j"}


@pytest.mark.parametrize(
    ("options", "said"),
    [
        ({"offline": [1, 1]}, "duplicate IDs in offline [1, 1]"),
        ({"offline": [2, 3]}, "offline: ID 3 is not in this stream [1, 2]"),
        ({"watch": [2, 2]}, "duplicate IDs in watch [2, 2]"),
        ({"watch": [5]}, "watch: ID 5 is not in this stream [1, 2]"),
    ],
)
async def test_a_streams_offline_and_watch_ids_are_checked_as_its_ids_are(
    env: Env, options: dict[str, list[int]], said: str
) -> None:
    # offline=[1, 1] was taken without a word (each ID listed as many times as given), and an ID the stream does
    # not carry was said as if it were the stream's own argument: the option is named, as for the stream's IDs.
    with pytest.raises(InvalidArgument) as info:
        env.bus.stream([1, 2], **options)  # type: ignore[arg-type]
    assert str(info.value) == said


async def test_a_stream_iterated_with_plain_for_says_how_to_use_it(env: Env) -> None:
    # `for frame in stream:` in async code (as the blocking API's page writes it) was "'Stream' object is not
    # iterable": how to write it is said instead, for a bus's, a group's and a robot's stream alike.
    how = r"`async for frame in stream:`"
    for stream in (env.stream, env.group):
        with pytest.raises(TypeError, match=how):
            for _ in stream:  # type: ignore[union-attr]
                pytest.fail("iterated")
    robot_line = {"lines": {"m": {"port": "sim://bad-input-robot-for?ids=1"}}, "joints": {"j": {"line": "m", "id": 1}}}
    async with open_robot(robot_line, **FAST) as robot, robot.stream() as frames:
        with pytest.raises(TypeError, match=how):
            list(frames)  # type: ignore[call-overload]
        assert set((await frames.next_frame()).positions) == {"j"}
    assert await env.bus.servo(2).read_stretch() == 30


async def _entered(block: contextlib.AbstractAsyncContextManager[Any]) -> None:
    async with block:
        pytest.fail("entered")


# Every way a program opens a line with reconnect=True, each given ``backoff``.
def _backoff_openers(backoff: Any) -> dict[str, Callable[[], Any]]:
    port = "sim://?ids=1"
    robot_line = {"lines": {"m": {"port": port}}, "joints": {"j": {"line": "m", "id": 1}}}
    options: dict[str, Any] = {"reconnect": True, "reconnect_backoff": backoff}
    return {
        "open_bus": lambda: open_bus(port, **options),
        "open_robot": lambda: _entered(open_robot(robot_line, **options)),
        "blocking.open_bus": lambda: blocking.open_bus(port, **options),
        "blocking.open_robot": lambda: blocking.open_robot(robot_line, **options),
    }


@pytest.mark.parametrize(
    "backoff", [[0], (0.05, 0), [0.0, 0.1], [-0.1], [math.inf], [math.nan], [61], ["0.1"], [True]], ids=repr
)
async def test_a_reconnect_wait_that_is_not_a_positive_finite_time_is_refused_by_every_opener(backoff: Any) -> None:
    # reconnect_backoff=[0] was taken: a lost port was then tried again and again with no wait between, a loop that
    # holds a core for as long as the port stays away.  Refused as the empty list is, naming the option.
    for opener, call in _backoff_openers(backoff).items():
        with pytest.raises(InvalidArgument, match=r"^reconnect_backoff'?s? ") as info:
            result = call()
            if isinstance(result, Awaitable):
                await result
        assert "more than 0" in str(info.value), (opener, str(info.value))


@pytest.mark.parametrize(
    ("call", "told"),
    [
        (lambda e: open_bus(e.sim, adapter_latncy=0.002), r"adapter_latncy \(did you mean adapter_latency\?\)"),
        (lambda e: open_bus(e.sim, baud=115200), r"baud \(did you mean baudrate\?\)"),
        # The ics35 commands' --timeout is open_bus's reply allowance: a program written after them says timeout=.
        (lambda e: open_bus(e.sim, timeout=0.05), r"timeout \(the reply allowance is adapter_latency"),
        (lambda e: e.bus.stream([1], on_clsoe="free"), r"on_clsoe \(did you mean on_close\?\)"),
        # (not the deprecated free_on_close, the nearer spelling: the reader is told what to write now)
        (lambda e: e.bus.stream([1], free_on_clsoe=True), r"free_on_clsoe \(did you mean on_close\?\)"),
        # (rate_hz is the stream's own argument, not one of its options: the likeliest slip is named all the same)
        (lambda e: e.bus.stream([1], rate=50), r"rate \(did you mean rate_hz\?\)"),
        (lambda e: _entered(open_robot({}, onclose="free")), r"onclose \(did you mean on_close\?\)"),
        (lambda e: VirtualLine([1], turnarond=0.0001), r"turnarond \(did you mean turnaround\?\)"),
    ],
)
async def test_a_misspelt_option_is_named_with_the_one_it_probably_meant(
    env: Env, call: Callable[[Env], Any], told: str
) -> None:
    # "unknown open_bus option(s): adapter_latncy" said what was wrong, not what to write instead.
    with pytest.raises(InvalidArgument, match=told):
        await outcome(call, env)


# (label, call, expected result or a check): values just inside a boundary work.
GOOD_CALLS: list[tuple[str, Callable[[Env], Any], Callable[[Any, Env], bool]]] = [
    ("set_position 1", lambda e: e.servo.set_position(1), lambda r, e: e.sim.servo(1).target == 3500),
    ("set_position 16383", lambda e: e.servo.set_position(16383), lambda r, e: e.sim.servo(1).target == 11500),
    ("set_degrees -135", lambda e: e.servo.set_degrees(-135), lambda r, e: e.sim.servo(1).target == 3500),
    ("write_stretch 1", lambda e: e.servo.write_stretch(1), lambda r, e: r == 1 and e.sim.servo(1).stretch == 1),
    ("write_stretch 127", lambda e: e.servo.write_stretch(127), lambda r, e: r == 127),
    ("write_current_limit 63", lambda e: e.servo.write_current_limit(63), lambda r, e: r == 63),
    ("write_temperature_limit 1", lambda e: e.servo.write_temperature_limit(1), lambda r, e: r == 1),
    ("read_memory 0..126", lambda e: e.bus.device(5).read_memory(0, 127), lambda r, e: r == bytes(127)),
    ("read_memory 127", lambda e: e.bus.device(5).read_memory(127, 1), lambda r, e: r == b"\x00"),
    (
        "write_memory 127",
        lambda e: e.bus.device(5).write_memory(127, bytes([255])),
        lambda r, e: e.sim.memory_device(5).memory[127] == 255,
    ),
    (
        "write_memory 127 bytes",
        lambda e: e.bus.device(5).write_memory(0, bytes(range(127))),
        lambda r, e: bytes(e.sim.memory_device(5).memory[:127]) == bytes(range(127)),
    ),
    (
        "request priority URGENT",
        lambda e: e.bus.request(protocol.ReadParam(1, 2), priority=Priority.URGENT),
        lambda r, e: r == 127,
    ),
    ("request retries 10", lambda e: e.bus.request(protocol.ReadParam(1, 2), retries=10), lambda r, e: r == 127),
    (
        "stream targets 0 and 16383",
        lambda e: e.stream.set_targets({1: 0, 2: 16383}),
        lambda r, e: e.stream.target(1) == 0 and e.stream.target(2) == 16383,
    ),
    ("eeprom offset -127", lambda e: e.image.replace(user_offset=-127), lambda r, e: r.user_offset == -127),
    ("eeprom stretch 254", lambda e: e.image.replace(stretch_gain=254), lambda r, e: r.stretch_gain == 254),
    ("eeprom baud str", lambda e: e.image.replace(baud_rate="625000"), lambda r, e: r.baud_rate == 625000),
    ("BusTiming zeros", lambda e: BusTiming(turnaround=0, adapter_latency=0, quiet_time=0), lambda r, e: True),
    ("BusTiming 60 s", lambda e: BusTiming(max_resync=60), lambda r, e: r.max_resync == 60),
]


@pytest.mark.parametrize(("label", "call", "check"), GOOD_CALLS, ids=[c[0] for c in GOOD_CALLS])
async def test_a_value_just_inside_a_boundary_works(
    env: Env, label: str, call: Callable[[Env], Any], check: Callable[[Any, Env], bool]
) -> None:
    result = await outcome(call, env)
    assert check(result, env), result


# --------------------------------------------------------------------------- the CLI

CLI_BAD = [
    ["move", "1", "16384"],
    ["move", "1", "-5"],
    ["move", "1", "nan", "--deg"],
    ["move", "1", "inf", "--deg"],
    ["move", "1", "7500", "--deg"],
    ["move", "x", "7500"],
    ["move", "1"],
    ["move", "1", "7500", "extra"],
    ["free"],
    ["free", "32"],
    ["free", "1,x"],
    ["free", "5-3"],
    ["get", "1"],
    ["get", "32", "speed"],
    ["get", "1.5", "speed"],
    ["set", "1", "stretch", "128"],
    ["set", "1", "stretch", "-1"],
    ["set", "1", "speed", "1.5"],
    ["set", "1", "temperature-limit", "0"],
    ["set", "1", "temperature-limit", "128"],
    ["set", "1", "speed"],
    ["set", "1", "bogus", "3"],
    ["info", "32"],
    ["info"],
    ["info", "1", "--bogus"],
    ["eeprom", "dump", "32"],
    ["eeprom", "set", "1"],
    ["eeprom", "set", "1", "user_offset=-128"],
    ["eeprom", "set", "1", "user_offset=x"],
    ["eeprom", "set", "1", "pulse_limit_low=3000"],
    ["eeprom", "set", "1", "pulse_limit_low=11000", "pulse_limit_high=5000"],
    ["eeprom", "set", "1", "calibration=0"],
    ["eeprom", "set", "1", "id=32"],
    ["eeprom", "set", "1", "=5"],
    ["eeprom", "restore", "1", "/nonexistent/backup.json"],
    ["eeprom", "restore", "32", "-"],
    ["eeprom", "restore", "1", "-"],  # stdin empty: not JSON
    ["eeprom", "bogus"],
    ["set-id"],
    ["set-id", "-1"],
    ["set-id", "x"],
    ["scan", "--ids", "32"],
    ["scan", "--bauds", "115200,x"],
    ["scan", "--timeout", "-1"],
    ["monitor", "--rate", "0"],
    ["monitor", "--seconds", "0"],
    ["monitor", "--telemetry", "33"],
    ["monitor", "x"],
    ["demo", "--ids", "40"],
    ["demo", "--amplitude", "0"],
    ["demo", "--frequency", "10"],
    ["demo", "--seconds", "0.01"],
    ["demo", "--rate", "0"],
    ["demo", "--rate", "0.5"],  # (below the 20 cycles/s a wave needs, see the test below)
    ["--baud", "9600", "scan"],
    ["--timeout", "6", "scan"],
    ["--timeout", "nan", "get", "1", "speed"],
    ["--retries", "11", "scan"],
    ["--retries", "-1", "get", "1", "speed"],
    ["--transport", "bogus", "scan"],
    ["bogus-command"],
]

_names = (f"bad-input-{n}" for n in itertools.count())


@contextlib.contextmanager
def named_line(servos: Any = (1, 2)) -> Iterator[tuple[VirtualLine, str]]:
    name = next(_names)
    sim = VirtualLine(list(servos), name=name)
    try:
        yield sim, f"sim://{name}"
    finally:
        sim.close()


def run_cli(*args: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    stdin, sys.stdin = sys.stdin, io.StringIO("")
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), pytest.raises(SystemExit) as exited:
            cli_main(list(args))
    finally:
        sys.stdin = stdin
    code = exited.value.code
    return (code if isinstance(code, int) else 1), out.getvalue(), err.getvalue()


@pytest.mark.parametrize("args", CLI_BAD, ids=[" ".join(a) for a in CLI_BAD])
def test_cli_bad_argument_exits_2_with_a_message_and_sends_nothing(args: list[str]) -> None:
    with named_line() as (sim, url):
        code, _out, err = run_cli("--port", url, *args)
        assert code == 2, err
        assert "Traceback" not in err
        assert "rror" in err or "Usage" in err, err
        assert sim.transactions == 0


@pytest.mark.parametrize("ids", ["", "40"])
def test_a_sim_url_with_a_bad_id_list_is_a_usage_error_naming_the_key(ids: str) -> None:
    # --port 'sim://?ids=' scanned a line of no servos and ended "no servo answered" after every rate's wait.
    code, out, err = run_cli("--port", f"sim://?ids={ids}", "scan")
    said = " ".join(err.split())
    assert code == 2 and "Traceback" not in err, err
    assert "sim URL: ids=" in said and "nothing was sent" in said and out == "", said


def test_demo_refuses_a_rate_that_would_move_the_wave_in_steps_and_says_which_option_slows_it() -> None:
    # demo --rate 0.5 sent a target every two seconds, each reached at the servos' full speed: the wave moved in
    # jumps, and at its default 0.5 Hz the same phase came round every cycle (the servos jumped once and stood).
    # A slow wave is --frequency's; --rate is the stream's cycles, floored as a robot file's rate_hz is.
    with named_line() as (sim, url):
        code, _out, err = run_cli("--port", url, "demo", "--ids", "1-2", "--rate", "19.9")
        assert code == 2 and "Traceback" not in err, err
        said = " ".join(err.split())
        assert "--rate" in said and "at least 20" in said and "--frequency" in said, said
        assert sim.transactions == 0
        code, _out, err = run_cli("--port", url, "demo", "--ids", "1-2", "--rate", "20", "--seconds", "0.1")
        assert code == 0, err
        assert sim.transactions > 0


@pytest.mark.parametrize(
    ("args", "check"),
    [
        (["move", "1", "1", "--force"], lambda sim: sim.servo(1).target == 3500),
        (["move", "1", "16383", "--force"], lambda sim: sim.servo(1).target == 11500),
        (["move", "2", "-135", "--deg"], lambda sim: sim.servo(2).target == 3500),
        (["set", "1", "stretch", "1"], lambda sim: sim.servo(1).stretch == 1),
        (["set", "1", "stretch", "127"], lambda sim: sim.servo(1).stretch == 127),
        (["set", "2", "current-limit", "63"], lambda sim: sim.servo(2).current_limit == 63),
        (["eeprom", "set", "1", "user_offset=-127", "--yes"], lambda sim: sim.servo(1).eeprom.user_offset == -127),
        (["free", "1-2"], lambda sim: sim.servo(1).free and sim.servo(2).free),
    ],
    ids=lambda v: " ".join(v) if isinstance(v, list) else "",
)
def test_cli_boundary_values_work(args: list[str], check: Callable[[VirtualLine], bool]) -> None:
    with named_line() as (sim, url):
        code, _out, err = run_cli("--port", url, *args)
        assert code == 0, err
        assert check(sim)


def test_cli_sim_server_refuses_bad_ids_without_serving() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "ics35_async.cli", "sim", "--ids", "40"], capture_output=True, text=True, timeout=30
    )
    assert proc.returncode != 0
    assert "Traceback" not in proc.stderr and proc.stderr.strip()


# --------------------------------------------------------------------------- dangerous writes


async def test_id_write_refused_unless_confirmed_and_when_more_than_one_device_answers() -> None:
    sim = VirtualLine([VirtualServo(1), VirtualServo(2)], log_size=None)
    async with open_bus(sim, timing=FAST_TIMING) as bus:
        for confirm in (False, None, 1, "yes"):
            with pytest.raises(UnsafeOperation):
                await bus.write_id(7, exactly_one_device=confirm)  # type: ignore[arg-type]
        assert sim.transactions == 0
        # Confirmed, but wrongly: a scan finds two devices (whatever the ID read would say
        # on a real wired-AND line), and the write is refused.
        with pytest.raises(UnsafeOperation, match="2 servos answer"):
            await bus.write_id(7, exactly_one_device=True)
        assert "write_id" not in [t.command for t in sim.log]
    assert [s.servo_id for s in sim.servos] == [1, 2]


async def test_id_write_with_exactly_one_device() -> None:
    sim = VirtualLine([VirtualServo(4)])
    async with open_bus(sim, timing=FAST_TIMING) as bus:
        assert await bus.write_id(9, exactly_one_device=True) == 9
        assert sim.servos[0].servo_id == 9 and sim.servos[0].calibration_intact
        assert await bus.read_id(exactly_one_device=True) == 9


_EDITABLE = sorted(set(EEPROM_FIELDS) - {"baud_rate", "servo_id", "flags"})


@st.composite
def eeprom_edits(draw: st.DrawFn) -> dict[str, Any]:
    """A random set of valid field changes (ranges as the EEPROM model checks them)."""
    image = Eeprom.factory(3)
    edits: dict[str, Any] = {}
    for name in draw(st.lists(st.sampled_from(_EDITABLE), unique=True, max_size=6)):
        for _ in range(50):
            value = draw(st.integers(-130, 12000))
            try:
                image.replace(**{name: value})
            except InvalidArgument:
                continue
            edits[name] = value
            break
    if draw(st.booleans()):
        edits["flags"] = draw(st.sampled_from([Flags(0), Flags.REVERSE, Flags.PWMINH, Flags.REVERSE | Flags.PWMINH]))
    return edits


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(edits=st.lists(eeprom_edits(), min_size=1, max_size=3))
def test_eeprom_writes_never_touch_the_factory_calibration(edits: list[dict[str, Any]]) -> None:
    async def run() -> None:
        sim = VirtualLine([VirtualServo(3)])
        async with open_bus(sim, timing=FAST_TIMING) as bus:
            servo = bus.servo(3)
            for change in edits:
                try:
                    image = (await servo.read_eeprom()).replace(**change)
                except InvalidArgument:
                    continue  # e.g. crossed pulse limits with the servo's current ones
                await servo.write_eeprom(image)  # verified read-back inside
                assert sim.servo(3).eeprom == image
                assert sim.servo(3).calibration_intact
            # An image with any other calibration is refused before anything is written.
            foreign = Eeprom.factory(3, calibration=bytes(22))
            writes = sim.servo(3).eeprom_writes
            with pytest.raises(UnsafeOperation):
                await servo.write_eeprom(foreign)
            assert sim.servo(3).eeprom_writes == writes and sim.servo(3).calibration_intact

    asyncio.run(run())


@pytest.mark.parametrize(
    ("field", "value", "flag"), [("baud_rate", 625000, "allow_baud_change"), ("servo_id", 9, "allow_id_change")]
)
async def test_a_dangerous_eeprom_change_needs_a_real_true(field: str, value: int, flag: str) -> None:
    sim = VirtualLine([VirtualServo(1)])
    async with open_bus(sim, timing=FAST_TIMING) as bus:
        servo = bus.servo(1)
        image = (await servo.read_eeprom()).replace(**{field: value})
        with pytest.raises(InvalidArgument):
            await servo.write_eeprom(image, **{flag: "no"})  # type: ignore[arg-type]
        assert sim.servo(1).eeprom_writes == 0


async def test_baud_change_needs_confirmation_then_the_bus_reopens_at_the_new_rate() -> None:
    sim = VirtualLine([VirtualServo(1), VirtualServo(2)])
    async with open_bus(sim, timing=FAST_TIMING) as bus:
        servo = bus.servo(1)
        image = await servo.read_eeprom()
        for rate in (625000, 1250000):
            with pytest.raises(UnsafeOperation):
                await servo.write_eeprom(image.replace(baud_rate=rate))
        assert sim.servo(1).eeprom_writes == 0
        for i in (1, 2):
            s = bus.servo(i)
            await s.write_eeprom((await s.read_eeprom()).replace(baud_rate=1250000), allow_baud_change=True)
        assert sim.servo(1).eeprom.baud_rate == BaudRate.B1250000 and sim.servo(1).calibration_intact
        sim.power_cycle()  # the servos take the new rate at power-up
        with pytest.raises(ReplyTimeout):
            await servo.read_stretch()
        async with bus.stream([1, 2]) as stream:
            with pytest.raises(InvalidArgument):  # not under a running stream
                await bus.reopen(baudrate=1250000)
            await stream.next_frame()
        await bus.reopen(baudrate=1250000)
        assert bus.baudrate == 1250000
        assert [await bus.servo(i).read_stretch() for i in (1, 2)] == [30, 30]
        async with bus.stream([1, 2]) as stream:
            frame = await stream.next_frame()
            frame = await stream.next_frame()
            assert set(frame.positions) == {1, 2}
        # And back again.
        for i in (1, 2):
            s = bus.servo(i)
            await s.write_eeprom((await s.read_eeprom()).replace(baud_rate=115200), allow_baud_change=True)
        sim.power_cycle()
        await bus.reopen(baudrate=115200)
        assert await servo.read_stretch() == 30 and sim.servo(1).calibration_intact
