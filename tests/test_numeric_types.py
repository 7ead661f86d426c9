"""NumPy numbers wherever the API takes a number: a gait's arithmetic gives ``np.int64`` counts and
``np.float32`` angles, and they must go out exactly as the same Python numbers do.

Each call runs twice, on two fresh simulated lines: once with NumPy values, once with the Python
values they equal; the bytes on the wire (the simulator's log) and the results must be the same,
and what comes back (results, frames, a robot's targets) holds Python numbers, so that
``json.dumps`` takes it.  What is refused for a Python number is refused for its NumPy twin: a
fractional count, a bool, a NaN, a value out of range (named as a plain number).
"""

from __future__ import annotations

import json
from collections.abc import Awaitable, Callable
from typing import Any

import anyio
import numpy as np
import pytest

from ics35_async import BusGroup, InvalidArgument, open_bus, open_robot
from ics35_async.bus import Bus
from ics35_async.policies import plan_eeprom_write
from ics35_async.robot import parse_motion
from ics35_async.sim import VirtualLine
from tests.support.robot_rig import make_rig
from tests.support.timing import FAST, FAST_TIMING, GUARD

Call = Callable[[Bus, Any], Awaitable[Any]]


async def _stream_targets(bus: Bus, value: Any) -> Any:
    async with bus.stream([1, 2]) as stream:
        stream.set_targets({1: value, 2: value})
        await stream.next_frame()
        frame = await stream.next_frame()
        return frame.to_dict()


async def _stream_degrees(bus: Bus, value: Any) -> Any:
    async with bus.stream([1, 2]) as stream:
        stream.set_targets_degrees({1: value})
        stream.set_target_degrees(2, value)
        await stream.next_frame()
        frame = await stream.next_frame()
        return frame.to_dict()


async def _group_degrees(bus: Bus, value: Any) -> Any:
    async with BusGroup({"a": bus}).stream({"a": [1, 2]}) as group:
        group.set_targets_degrees({("a", 1): value, ("a", 2): value})
        await group.next_frame()
        frame = await group.next_frame()
        return {f"{line}/{servo_id}": position for (line, servo_id), position in frame.positions.items()}


async def _eeprom(bus: Bus, value: Any) -> Any:
    servo = bus.servo(1)
    image = (await servo.read_eeprom()).replace(speed=value, punch=value // 10 // 2 * 2)
    await servo.write_eeprom(image)
    return (await servo.read_eeprom()).to_dict()


async def _planned(bus: Bus, value: Any) -> Any:
    plan = await plan_eeprom_write(bus, value, {"speed": 90})
    return {"servo_id": plan.servo_id, "diff": {k: list(v) for k, v in plan.diff.items()}}


# (label, call, NumPy value, the Python value it equals)
CALLS: list[tuple[str, Call, Any, Any]] = [
    ("servo ID and set_position", lambda bus, v: bus.servo(v).set_position(7600), np.int64(1), 1),
    ("set_position int64", lambda bus, v: bus.servo(1).set_position(v), np.int64(7600), 7600),
    ("set_position uint16", lambda bus, v: bus.servo(1).set_position(v), np.uint16(8123), 8123),
    ("set_degrees float32", lambda bus, v: bus.servo(1).set_degrees(v), np.float32(10.5), 10.5),
    ("set_degrees int64", lambda bus, v: bus.servo(1).set_degrees(v), np.int64(-20), -20),
    ("set_radians float32", lambda bus, v: bus.servo(1).set_radians(v), np.float32(0.25), 0.25),
    ("write_speed", lambda bus, v: bus.servo(1).write_speed(v), np.int8(100), 100),
    ("write_stretch", lambda bus, v: bus.servo(1).write_stretch(v), np.int32(60), 60),
    ("write_current_limit", lambda bus, v: bus.servo(1).write_current_limit(v), np.uint8(40), 40),
    ("read_memory", lambda bus, v: bus.device(5).read_memory(v, v + 2), np.int64(4), 4),
    ("servos from an array", lambda bus, v: bus.servos(np.arange(1, v + 1))[1].set_position(7000), 2, 2),
    ("scan IDs from an array", lambda bus, v: bus.scan(np.arange(0, v)), np.int64(4), 4),
    ("stream targets", _stream_targets, np.int64(7700), 7700),
    ("stream targets in degrees", _stream_degrees, np.float32(-12.25), -12.25),
    ("group targets in degrees", _group_degrees, np.float32(33.5), 33.5),
    ("EEPROM fields", _eeprom, np.int64(88), 88),
    ("plan_eeprom_write", lambda bus, v: _planned(bus, v), np.int64(2), 2),
]


def _python_only(value: Any) -> None:
    """``value`` holds only Python's own numbers (and containers, strings, None): JSON takes it."""
    if isinstance(value, dict):
        for key, item in value.items():
            _python_only(key)
            _python_only(item)
    elif isinstance(value, (list, tuple)):
        for item in value:
            _python_only(item)
    else:
        assert value is None or type(value) in (int, float, bool, str, bytes), (value, type(value))


def _run(call: Call, value: Any) -> tuple[list[bytes], Any]:
    sim = VirtualLine([1, 2, 3], memory={5: bytes(range(128))}, log_size=None)

    async def main() -> Any:
        with anyio.fail_after(GUARD):
            async with open_bus(sim, timing=FAST_TIMING) as bus:
                return await call(bus, value)

    try:
        result = anyio.run(main)
        return [t.tx for t in sim.log_since(0)], result
    finally:
        sim.close()


def _comparable(result: Any) -> Any:
    """A result with the times a frame carries taken out (they differ between two runs)."""
    if isinstance(result, dict):
        return {k: _comparable(v) for k, v in result.items() if k not in ("started", "finished", "timestamps")}
    if isinstance(result, list):
        return [_comparable(v) for v in result]
    return result


@pytest.mark.parametrize(("label", "call", "numpy_value", "python_value"), CALLS, ids=[c[0] for c in CALLS])
def test_numpy_numbers_go_out_as_the_python_numbers_they_equal(
    label: str, call: Call, numpy_value: Any, python_value: Any
) -> None:
    assert numpy_value == python_value
    numpy_wire, numpy_result = _run(call, numpy_value)
    python_wire, python_result = _run(call, python_value)
    assert numpy_wire == python_wire
    assert _comparable(numpy_result) == _comparable(python_result)
    _python_only(numpy_result)
    json.dumps(numpy_result, default=lambda b: b.hex())


REFUSED: list[tuple[str, Call, Any, str]] = [
    ("a fractional count", lambda bus, v: bus.servo(1).set_position(v), np.float64(7600.5), "must be an int"),
    ("a whole float as a count", lambda bus, v: bus.servo(1).set_position(v), np.float32(7600.0), "must be an int"),
    ("a bool as a count", lambda bus, v: bus.servo(1).set_position(v), np.bool_(True), "must be an int"),
    ("a count out of range", lambda bus, v: bus.servo(1).set_position(v), np.int64(20000), "got 20000"),
    ("an ID out of range", lambda bus, v: bus.servo(v).free(), np.int16(40), "got 40"),
    ("NaN degrees", lambda bus, v: bus.servo(1).set_degrees(v), np.float32("nan"), "finite"),
    ("degrees past the travel", lambda bus, v: bus.servo(1).set_degrees(v), np.float32(200), "200 degrees is outside"),
]


@pytest.mark.parametrize(("label", "call", "value", "message"), REFUSED, ids=[c[0] for c in REFUSED])
def test_numpy_numbers_python_would_refuse_are_refused_before_the_wire(
    label: str, call: Call, value: Any, message: str
) -> None:
    with pytest.raises(InvalidArgument, match=message) as caught:
        _run(call, value)
    assert "np." not in str(caught.value), "the number is named as a plain number"


def test_a_numpy_bool_is_not_a_number() -> None:
    with pytest.raises(InvalidArgument, match="finite number"):
        _run(lambda bus, v: bus.servo(1).set_degrees(v), np.bool_(False))


def test_a_robot_takes_numpy_joint_angles_and_keeps_python_floats() -> None:
    rig = make_rig()
    pose = {"neck": np.float32(12.5), "hip": np.int64(-10), "knee": np.float64(-40.0)}
    # A motion made by a program (keyframes from an array), not read from a file.
    times = np.linspace(0.1, 0.2, 2, dtype=np.float32)
    motion = parse_motion(
        {"format": "ics35-motion", "version": 1, "keyframes": [{"time": t, "pose": {"hip": t * 10}} for t in times]}
    )
    _python_only([(frame.time, frame.pose) for frame in motion.keyframes])

    async def main() -> dict[str, Any]:
        with anyio.fail_after(GUARD):
            async with open_robot(rig.description, **FAST) as robot:
                await robot.move_to(pose, duration=np.float32(0.1))
                robot.set_targets({"elbow": np.float32(30.0)})
                await robot.play(motion, speed=np.float32(4.0))
                return dict(robot.targets)

    try:
        targets = anyio.run(main)
    finally:
        rig.close()
    assert {name: targets[name] for name in pose if name != "hip"} == {
        name: float(v) for name, v in pose.items() if name != "hip"
    }
    assert targets["elbow"] == 30.0
    assert targets["hip"] == float(np.float32(0.2) * 10)
    _python_only(targets)


def test_an_id_written_from_a_numpy_number_comes_back_as_a_python_int() -> None:
    sim = VirtualLine([1], log_size=None)

    async def main() -> Any:
        with anyio.fail_after(GUARD):
            async with open_bus(sim, timing=FAST_TIMING) as bus:
                return await bus.write_id(np.int64(5), exactly_one_device=True)

    try:
        written = anyio.run(main)
    finally:
        sim.close()
    assert written == 5 and type(written) is int


def test_a_robot_description_built_by_a_program_takes_numpy_numbers() -> None:
    rig = make_rig()
    description = dict(rig.description)
    description["joints"] = {
        name: {**spec, "id": np.int64(spec["id"]), "min": np.float32(spec.get("min", -135)), "max": np.int64(20)}
        for name, spec in rig.description["joints"].items()
        if name in ("hip", "knee")
    }
    description["lines"] = {"lower": rig.description["lines"]["lower"]}

    async def main() -> Any:
        with anyio.fail_after(GUARD):
            async with open_robot(description, **FAST) as robot:
                joints = robot.joints
                return {name: (joints[name].id, joints[name].min, joints[name].max) for name in joints}

    try:
        specs = anyio.run(main)
    finally:
        rig.close()
    assert specs == {"hip": (1, -30.0, 20.0), "knee": (2, -100.0, 20.0)}
    _python_only(specs)


def test_a_command_built_from_numpy_numbers_holds_python_ints_only() -> None:
    # The engine takes a command's lengths and IDs as ints; a compiled engine (mypyc) refuses anything else.
    from ics35_async import protocol

    commands = [
        protocol.ReadMemory(np.int64(5), np.int64(4), np.int64(6)),
        protocol.WriteMemory(np.int64(5), np.int64(4), [np.int64(1), np.int64(2)]),
        protocol.Position(np.int64(3), np.int64(7500), baudrate=np.int64(115200)),
        protocol.ReadParam(np.int64(3), protocol.Param.STRETCH),
    ]
    for command in commands:
        for name in ("servo_id", "reply_len", "address", "count"):
            value = getattr(command, name, 0)
            assert type(value) is int, (command, name, type(value))
