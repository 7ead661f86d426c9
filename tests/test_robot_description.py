"""The robot description file: every rule, each mistake a clear error naming the file and key, opening nothing."""

from __future__ import annotations

import json
import math
import os
import tomllib
from dataclasses import replace
from pathlib import Path
from typing import Any

import anyio
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ics35_async import InvalidArgument, blocking, open_robot, units
from ics35_async.robot import DescriptionError, JointSpec, load_description, parse_description
from ics35_async.robot.calibration import dump_description
from ics35_async.sim import VirtualLine, open_url
from tests.support.timing import FAST

GOOD = """\
name = "arm"

[lines.main]              # one table per ICS line
port = "sim://?ids=1-3"
baudrate = 115200
rate_hz = 200

[joints.left_elbow]
line = "main"
id = 3
offset = 2.5              # degrees: the servo angle at which the joint reads 0
reverse = true
min = -90
max = 45

[joints.wrist]
line = "main"
id = 1

[safety]
max_temperature_c = 70
max_current = 30
action = "hold"
"""


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "robot.toml"
    path.write_text(text)
    return path


def test_a_good_file_reads_with_its_defaults(tmp_path: Path) -> None:
    robot = load_description(write(tmp_path, GOOD))
    assert robot.name == "arm"
    line = robot.lines["main"]
    assert (line.port, line.baudrate, line.rate_hz, line.echo) == ("sim://?ids=1-3", 115200, 200.0, True)
    elbow = robot.joints["left_elbow"]
    assert (elbow.line, elbow.id, elbow.offset, elbow.reverse, elbow.min, elbow.max) == (
        "main",
        3,
        2.5,
        True,
        -90.0,
        45.0,
    )
    # No limits given: the servo's whole travel, in the joint's degrees.
    wrist = robot.joints["wrist"]
    assert (wrist.offset, wrist.reverse, wrist.min, wrist.max) == (0.0, False, -135.0, 135.0)
    assert (robot.safety.max_temperature_c, robot.safety.max_current, robot.safety.action) == (70.0, 30, "hold")
    assert robot.safety.continue_on_offline is False


def test_a_line_rate_of_twenty_cycles_a_second_reads() -> None:
    # The fewest a motion needs (lower is refused: see MISTAKES); no rate_hz at all streams as fast as the line allows.
    lines = {"main": {"port": "sim://a", "rate_hz": 20}, "fast": {"port": "sim://b"}}
    joints = {"x": {"line": "main", "id": 1}, "y": {"line": "fast", "id": 1}}
    robot = parse_description({"lines": lines, "joints": joints})
    assert (robot.lines["main"].rate_hz, robot.lines["fast"].rate_hz) == (20.0, None)


def test_only_some_joints_keeps_their_lines_and_the_rest_of_the_robot() -> None:
    two_lines = {
        "lines": {"a": {"port": "sim://?ids=1-2"}, "b": {"port": "sim://?ids=1"}},
        "joints": {"x": {"line": "a", "id": 1}, "y": {"line": "a", "id": 2}, "z": {"line": "b", "id": 1}},
        "safety": {"action": "hold"},
    }
    robot = load_description(two_lines)
    some = robot.only(["y", "x"])
    assert list(some.joints) == ["x", "y"] and list(some.lines) == ["a"]  # (file order; line b unused)
    assert some.safety == robot.safety and some.source == robot.source and some.joints["y"] is robot.joints["y"]
    with pytest.raises(InvalidArgument, match=r"unknown joint\(s\): w \(joints: x, y, z\)"):
        robot.only(["x", "w"])
    with pytest.raises(InvalidArgument, match="at least one joint"):
        robot.only([])


@pytest.mark.parametrize("joints", [5, 2.5])
def test_joints_that_are_neither_a_name_nor_names_are_refused_in_words(joints: Any) -> None:
    # robot.free(5) and robot.hold(5) raised TypeError ("'int' object is not iterable"), not an IcsError.
    robot = load_description({"lines": {"a": {"port": "sim://?ids=1"}}, "joints": {"x": {"line": "a", "id": 1}}})
    with pytest.raises(InvalidArgument, match="joint names"):
        robot.known_joints(joints)


def test_servo_degrees_are_offset_plus_signed_joint_degrees_both_ways(tmp_path: Path) -> None:
    elbow = load_description(write(tmp_path, GOOD)).joints["left_elbow"]
    for joint in (-90.0, -12.25, 0.0, 30.0, 45.0):
        servo = elbow.servo_degrees(joint)
        assert servo == pytest.approx(2.5 - joint)
        assert elbow.joint_degrees(servo) == pytest.approx(joint)
        # Through the counts and back: within half a count (a whole one at a limit, inside it).
        back = elbow.degrees(elbow.position(joint))
        at_limit = joint in (elbow.min, elbow.max)
        assert back == pytest.approx(joint, abs=(1.0 if at_limit else 0.5) / 29.6)
        assert elbow.min <= back <= elbow.max
    with pytest.raises(InvalidArgument, match=r"45\.00001 degrees is outside its limits -90\.\.45"):
        elbow.check(45.00001)


def test_default_limits_follow_the_offset() -> None:
    robot = load_description(
        {"lines": {"m": {"port": "sim://"}}, "joints": {"j": {"line": "m", "id": 0, "offset": 35, "reverse": True}}}
    )
    assert (robot.joints["j"].min, robot.joints["j"].max) == (-100.0, 170.0)


BASE_LINES = '[lines.main]\nport = "sim://a"\n[lines.legs]\nport = "sim://b"\n'
JOINT = '[joints.knee]\nline = "legs"\nid = 2\n'

MISTAKES: list[tuple[str, str, str]] = [
    # (file text, the key the error must name, a phrase of its message)
    (
        BASE_LINES + '[joints.knee]\nline = "arms"\nid = 2\n[joints.x]\nline="main"\nid=1',
        "joints.knee.line",
        "unknown line 'arms'",
    ),
    (
        BASE_LINES + JOINT + '[joints.hip]\nline = "legs"\nid = 2\n[joints.x]\nline="main"\nid=1',
        "joints.hip.id",
        "already joint 'knee'",
    ),
    (
        BASE_LINES + JOINT + "min = 10\nmax = -10\n" + '[joints.x]\nline="main"\nid=1',
        "joints.knee.min",
        "greater than max",
    ),
    (
        BASE_LINES + JOINT + "offset = 100\nmax = 50\n" + '[joints.x]\nline="main"\nid=1',
        "joints.knee.max",
        "outside the servo's range",
    ),
    (
        BASE_LINES + JOINT + "reverse = true\noffset = -100\nmax = 50\n" + '[joints.x]\nline="main"\nid=1',
        "joints.knee.max",
        "outside the servo's range",
    ),
    (BASE_LINES + JOINT + "speed = 3\n" + '[joints.x]\nline="main"\nid=1', "joints.knee.speed", "unknown key"),
    (BASE_LINES + JOINT + "id = 40\n", "", ""),  # duplicate key: not valid TOML
    ('[lines.main]\nport = "sim://a"\nbaud = 115200\n[joints.x]\nline="main"\nid=1', "lines.main.baud", "unknown key"),
    (
        '[lines.main]\nport = "sim://a"\nbaudrate = 9600\n[joints.x]\nline="main"\nid=1',
        "lines.main.baudrate",
        "115200, 625000 or 1250000",
    ),
    ('[lines.main]\nbaudrate = 115200\n[joints.x]\nline="main"\nid=1', "lines.main.port", "is required"),
    # A motion goes out as one target a cycle: at 0.5 Hz the joints jumped from one target to the next, two seconds
    # apart, at the servos' full speed.
    (
        '[lines.main]\nport = "sim://a"\nrate_hz = 0.5\n[joints.x]\nline="main"\nid=1',
        "lines.main.rate_hz",
        "must be a number in 20..10000 cycles per second, got 0.5: a motion goes out as one target a cycle",
    ),
    ('[lines.main]\nport = "sim://a"\nrate_hz = 19.9\n[joints.x]\nline="main"\nid=1', "lines.main.rate_hz", "got 19.9"),
    (
        '[lines.main]\nport = "sim://a"\ndirection = "up"\n[joints.x]\nline="main"\nid=1',
        "lines.main.direction",
        "none, rts, rts-inverted",
    ),
    ('[lines.main]\nprot = "sim://a"\n[joints.x]\nline="main"\nid=1', "lines.main.port", "'prot' meant to be 'port'"),
    (
        '[lines.main]\nport = "sim://a"\n[lines.b]\nport = "sim://a"\n[joints.x]\nline="main"\nid=1\n'
        '[joints.y]\nline="b"\nid=1',
        "lines.b.port",
        "already the port of lines.main",
    ),
    (
        '[lines.main]\nport = "sim://a"\n[lines.spare]\nport = "sim://b"\n[joints.x]\nline="main"\nid=1',
        "lines.spare",
        "no joint uses this line",
    ),
    ('[lines.main]\nport = "sim://a"\n[joints.x]\nline="main"\nid=32', "joints.x.id", "0..31"),
    ('[lines.main]\nport = "sim://a"\n[joints.x]\nline="main"', "joints.x.id", "is required"),
    # A float that happens to be whole is named as written: "not 1" would read as nonsense.
    (
        '[lines.main]\nport = "sim://a"\n[joints.x]\nline="main"\nid=1.0',
        "joints.x.id",
        "whole number in 0..31, got 1.0",
    ),
    (
        '[lines.main]\nport = "sim://a"\n[joints.x]\nline="main"\nid=1\noffset="2"',
        "joints.x.offset",
        "must be a number",
    ),
    ('[lines.main]\nport = "sim://a"\n[joints.x]\nline="main"\nid=1\nreverse=1', "joints.x.reverse", "true or false"),
    (
        '[lines.main]\nport = "sim://a"\n[joints.x]\nline="main"\nid=1\n[safety]\naction="panic"',
        "safety.action",
        "free, hold, stop",
    ),
    (
        '[lines.main]\nport = "sim://a"\n[joints.x]\nline="main"\nid=1\n[safety]\nmax_temp=50',
        "safety.max_temp",
        "unknown key",
    ),
    (
        '[lines.main]\nport = "sim://a"\n[joints.x]\nline="main"\nid=1\n[safety]\nmax_current=80',
        "safety.max_current",
        "1..63",
    ),
    (
        '[lines.main]\nport = "sim://a"\n[joints.x]\nline="main"\nid=1\n[safety]\nmax_current=30\n'
        "telemetry_per_cycle=0",
        "safety.telemetry_per_cycle",
        "never be checked",
    ),
    ('[lines.main]\nport = "sim://a"\n[joints.x]\nline="main"\nid=1\n[servos]\n', "servos", "unknown key"),
    # A misspelt table is named as such, not as the unknown line its joints then point at.
    (
        '[lines.main]\nport = "sim://a"\n[line.arms]\nport = "sim://b"\n[joints.x]\nline="main"\nid=1\n'
        '[joints.y]\nline="arms"\nid=1',
        "line",
        "unknown key (known: joints, lines, name, safety)",
    ),
    ('[lines.main]\nport = "sim://a"\n', "joints", "is required"),
    ('joints = 3\n[lines.main]\nport = "sim://a"\n', "joints", "must be a table"),
    ("this is = not toml [", "", "not valid TOML"),
    ("a = " + "[" * 100_000, "", "not valid TOML: nested too deeply"),  # (once a RecursionError's traceback)
]


@pytest.mark.parametrize(("text", "key", "phrase"), MISTAKES, ids=[m[1] or "toml" for m in MISTAKES])
def test_each_mistake_names_the_file_and_key_and_opens_nothing(
    tmp_path: Path, text: str, key: str, phrase: str
) -> None:
    # Lines a and b exist: had anything been opened, their logs would show it.
    sims = [VirtualLine([1, 2], name=n, log_size=None) for n in ("a", "b")]
    try:
        path = write(tmp_path, text)
        with pytest.raises(DescriptionError) as caught:
            load_description(path)
        error = caught.value
        assert isinstance(error, InvalidArgument) and isinstance(error, ValueError)
        assert str(error).startswith(f"{path}: ")
        assert error.source == str(path)
        if key:
            assert error.key == key
            assert f": {key}: " in str(error)
        assert phrase in str(error)

        async def try_open() -> None:
            async with open_robot(path, **FAST):
                pytest.fail("opened a robot from a bad file")

        with pytest.raises(DescriptionError):
            anyio.run(try_open)
        assert all(sim.transactions == 0 and not sim.log for sim in sims)
    finally:
        for sim in sims:
            sim.close()


# sim:// ports the simulator refuses as it opens them: an empty ID list (ids=none is a line without servos), a
# misspelt option, an option refused only with the others (an ics36 servo not among the IDs), a log size below 0.
REFUSED_SIM_PORTS = [
    "sim://?ids=",
    "sim://?idz=1-3",
    "sim://?ids=1-2&ics36=5",
    "sim://?ids=1&tail_bytes=0",
    "sim://?log=-1",
    "sim://?ids=1&replay=motion.rec",
]


@pytest.mark.parametrize("port", REFUSED_SIM_PORTS)
def test_a_sim_port_the_simulator_refuses_is_refused_with_the_file_naming_its_key(tmp_path: Path, port: str) -> None:
    """A robot file whose line names a sim:// URL the simulator refuses was read as good (ics35 check passed it);
    open_robot refused it only as it opened the lines, after the ones before it.  It is refused as the file is read,
    in the simulator's own words, and no line is opened."""
    with pytest.raises(InvalidArgument) as at_open:
        open_url(port)
    path = write(
        tmp_path,
        f'[lines.arm]\nport = "sim://?ids=1"\n[lines.main]\nport = "{port}"\n'
        '[joints.x]\nline = "arm"\nid = 1\n[joints.y]\nline = "main"\nid = 1\n',
    )
    with pytest.raises(DescriptionError) as caught:
        load_description(path)
    assert caught.value.key == "lines.main.port"
    assert str(caught.value) == f"{path}: lines.main.port: {json.dumps(port)} is refused: {at_open.value}"

    async def try_open() -> None:
        async with open_robot(path, **FAST):
            pytest.fail("opened a robot from a bad file")

    with pytest.raises(DescriptionError):
        anyio.run(try_open)


# A user's trial: `rate_hz = 1e9` was told as "got 1e+09", `rate_hz = true` as "not True", and the allowed range only
# when too high.  Each refusal of a number names the range and shows the value as TOML writes it.
NUMBER_REFUSALS = [
    ("rate_hz = 1e9", "lines.main.rate_hz", "must be a number in 20..10000 cycles per second, got 1000000000"),
    ("rate_hz = 1000000000", "lines.main.rate_hz", "must be a number in 20..10000 cycles per second, got 1000000000"),
    ("rate_hz = 1e300", "lines.main.rate_hz", "must be a number in 20..10000 cycles per second, got 1e300"),
    ("rate_hz = true", "lines.main.rate_hz", "must be a number in 20..10000 cycles per second, got true"),
    ("rate_hz = nan", "lines.main.rate_hz", "must be a number in 20..10000 cycles per second, got nan"),
    ("rate_hz = -inf", "lines.main.rate_hz", "must be a number in 20..10000 cycles per second, got -inf"),
    ('rate_hz = "fast"', "lines.main.rate_hz", 'must be a number in 20..10000 cycles per second, got "fast"'),
    ("rate_hz = [50]", "lines.main.rate_hz", "must be a number in 20..10000 cycles per second, got an array"),
    ("rate_hz = 1.5e-7", "lines.main.rate_hz", "must be a number in 20..10000 cycles per second, got 1.5e-7: a motion"),
    ("rate_hz = 5", "lines.main.rate_hz", "must be a number in 20..10000 cycles per second, got 5: a motion"),
    ("retries = false", "lines.main.retries", "must be a whole number in 0..10, got false"),
    ("retries = 1.0", "lines.main.retries", "must be a whole number in 0..10, got 1.0"),
    ("retries = 11", "lines.main.retries", "must be a whole number in 0..10, got 11"),
    ("echo = 1", "lines.main.echo", "must be true or false, got 1"),
    ("echo = 'yes'", "lines.main.echo", 'must be true or false, got "yes"'),
    ("direction = false", "lines.main.direction", "must be a non-empty string, got false"),
]


@pytest.mark.parametrize(("line", "key", "phrase"), NUMBER_REFUSALS, ids=[r[0] for r in NUMBER_REFUSALS])
def test_a_refused_value_is_shown_as_toml_writes_it_beside_what_is_allowed(
    tmp_path: Path, line: str, key: str, phrase: str
) -> None:
    path = write(tmp_path, f'[lines.main]\nport = "sim://a"\n{line}\n[joints.x]\nline = "main"\nid = 1\n')
    with pytest.raises(DescriptionError) as caught:
        load_description(path)
    assert caught.value.key == key and f": {key}: {phrase}" in str(caught.value), caught.value


def test_a_lines_direction_control_reaches_its_bus(tmp_path: Path) -> None:
    # A robot on a board's own UART with a tri-state buffer on RTS (a DIY half-duplex interface) could not say
    # so: the robot file had no key for it, and the command line's --direction is not used by the robot
    # commands.  Its line's `direction` goes to that line's bus, which refuses it on a simulated line (it drives a
    # local serial port's RTS pin): the refusal shows it arrived.
    path = write(tmp_path, '[lines.main]\nport = "sim://dir"\ndirection = "rts"\n[joints.x]\nline="main"\nid=1')
    assert load_description(path).lines["main"].direction == "rts"

    async def try_open() -> None:
        async with open_robot(path, **FAST):
            pytest.fail("opened a simulated line with RTS direction control")

    with pytest.raises(InvalidArgument, match="RTS pin"):
        anyio.run(try_open)
    again = tmp_path / "again.toml"  # (as calibrate writes a whole file where it cannot edit one in place)
    again.write_text(dump_description(load_description(path)))
    assert load_description(again).lines["main"].direction == "rts"
    plain = tmp_path / "plain.toml"
    plain.write_text('[lines.main]\nport = "sim://dir"\n[joints.x]\nline="main"\nid=1')
    assert load_description(plain).lines["main"].direction == "none"


def test_a_whole_file_written_anew_reads_back_the_same_and_leaves_defaults_out(tmp_path: Path) -> None:
    # The complete file calibrate writes where it cannot edit a robot file listed every key at its default too
    # (offset = 0, reverse = false, the servo's whole travel as min and max, a [safety] table of defaults): noise
    # against the robot file it stands in for.
    described = load_description(write(tmp_path, GOOD))
    again = tmp_path / "again.toml"
    again.write_text(dump_description(described))
    assert replace(load_description(again), source=described.source) == described
    data = tomllib.loads(again.read_text())
    assert data["joints"] == {
        "left_elbow": {"line": "main", "id": 3, "offset": 2.5, "reverse": True, "min": -90, "max": 45},
        "wrist": {"line": "main", "id": 1},
    }
    assert data["safety"] == {"max_temperature_c": 70, "max_current": 30, "action": "hold"}
    plain = load_description(write(tmp_path, '[lines.main]\nport = "sim://x"\n[joints.x]\nline="main"\nid=1\n'))
    assert "safety" not in tomllib.loads(dump_description(plain))


def test_a_missing_file_is_a_description_error(tmp_path: Path) -> None:
    with pytest.raises(DescriptionError, match=r"nothere\.toml: no such file"):
        load_description(tmp_path / "nothere.toml")


PORTS_FOR_FILES = [
    ("sim://x", "a sim:// URL"),
    ("sim://arm?ids=1-6", "a sim:// URL"),
    ("socket://localhost:7777", "a socket:// URL"),
    ("/dev/ttyUSB-not-plugged-in", "a device path"),
]


@pytest.mark.parametrize(("port", "kind"), PORTS_FOR_FILES)
def test_open_robot_given_a_port_says_it_takes_a_robot_file_and_where_the_port_goes(port: str, kind: str) -> None:
    # open_robot("sim://x") said "sim:/x: no such file": a path's reading of the URL, as if a file were missing.
    async def attempt() -> None:
        async with open_robot(port):
            pytest.fail("opened")

    for opener in (lambda: anyio.run(attempt), lambda: blocking.open_robot(port)):
        with pytest.raises(DescriptionError) as info:
            opener()
        said = str(info.value)
        assert said.startswith(f"{port}: open_robot takes a robot file"), said
        assert f"this looks like a port ({kind})" in said and "no such file" not in said, said
        assert f'[lines.NAME] table each: port = "{port}"' in said, said  # where a robot's port goes instead
        assert f'{{"lines": {{"main": {{"port": "{port}"}}}}, "joints": ' in said, said  # or a mapping's


@pytest.mark.parametrize(("port", "kind"), PORTS_FOR_FILES)
def test_load_description_given_a_port_says_it_looks_like_one(port: str, kind: str) -> None:
    with pytest.raises(DescriptionError) as info:
        load_description(port)
    said = str(info.value)
    assert said.startswith(f"{port}: this looks like a port ({kind}), not a robot file"), said
    assert f'port = "{port}"' in said, said


def test_a_file_at_a_path_that_reads_like_a_url_is_read(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # (a path reads sim://x as sim:/x: a robot file there is what was meant, and is read)
    monkeypatch.chdir(tmp_path)
    (tmp_path / "sim:").mkdir()
    (tmp_path / "sim:" / "x").write_text('[lines.m]\nport = "sim://"\n[joints.j]\nline = "m"\nid = 1\n')
    assert set(load_description("sim://x").joints) == {"j"}


@pytest.mark.parametrize(
    "value",
    [True, math.inf, "3"],
)
def test_a_mapping_gets_the_same_checks(value: Any) -> None:
    with pytest.raises(DescriptionError, match=r"^<mapping>: joints\.j\.min: must be a number"):
        load_description({"lines": {"m": {"port": "sim://"}}, "joints": {"j": {"line": "m", "id": 1, "min": value}}})


def test_open_robot_refuses_per_line_options_and_bad_on_close() -> None:
    description = {"lines": {"m": {"port": "sim://"}}, "joints": {"j": {"line": "m", "id": 1}}}

    async def attempt(**options: Any) -> None:
        async with open_robot(description, **options):
            pytest.fail("opened")

    with pytest.raises(InvalidArgument, match="baudrate: set per line"):
        anyio.run(lambda: attempt(baudrate=115200))
    with pytest.raises(InvalidArgument, match="on_close must be one of hold, free"):
        anyio.run(lambda: attempt(on_close="drop"))
    with pytest.raises(InvalidArgument, match="unknown open_robot option"):
        anyio.run(lambda: attempt(speed=3))


@settings(max_examples=300, deadline=None)
@given(
    offset=st.floats(-30, 30, allow_nan=False),
    reverse=st.booleans(),
    low=st.floats(-100, 0, allow_nan=False),
    span=st.floats(1, 100, allow_nan=False),
    where=st.floats(0, 1),
)
def test_no_count_sent_for_an_angle_within_the_limits_is_past_them(
    offset: float, reverse: bool, low: float, span: float, where: float
) -> None:
    # "No command ever leaves a joint's limits" held only to half a count: a limit of 60 degrees went out
    # as 60.0075, the nearest count.  The count sent is now the nearest one within the limits.
    joint = JointSpec("j", "l", 1, offset=offset, reverse=reverse, min=low, max=low + span)
    for angle in (joint.min, joint.max, joint.min + where * span):
        sent = joint.joint_degrees(units.position_to_degrees(joint.position(angle)))
        assert joint.min - 1e-9 <= sent <= joint.max + 1e-9, (angle, sent)
        assert abs(sent - angle) <= 1 / units.COUNTS_PER_DEGREE + 1e-9  # still the nearest count inside


def test_a_robot_file_given_through_a_pipe_is_read_not_taken_for_a_port() -> None:
    # A shell's <(...) hands the program /dev/fd/N: a pipe, whose name starts as a device path's does.
    read_end, write_end = os.pipe()
    os.write(write_end, b'[lines.main]\nport = "sim://a"\n[joints.x]\nline = "main"\nid = 1\n')
    os.close(write_end)
    try:
        robot = load_description(f"/dev/fd/{read_end}")
    finally:
        os.close(read_end)
    assert list(robot.joints) == ["x"]
