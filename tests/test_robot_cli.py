"""ics35 play / teach / calibrate in this process, on named simulated lines (hands moved from a helper thread)."""

from __future__ import annotations

import io
import itertools
import json
import os
import re
import signal
import sys
import threading
import time
import tomllib
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import anyio
import hypothesis
import pytest
from hypothesis import strategies as st
from rich.table import Table

from ics35_async import PortLost, open_robot
from ics35_async.cli import ExitCode, main
from ics35_async.cli._robot_common import lost_line_hint, other_lines_hint
from ics35_async.cli._robot_teach import TaughtTimes, capture
from ics35_async.cli._robot_view import Screen
from ics35_async.cli._settings import Settings
from ics35_async.eeprom import Flags
from ics35_async.robot import Keyframe, Motion, load_description
from ics35_async.robot.calibration import calibrate_joint, dump_description, edit_joint_values, write_calibration
from ics35_async.robot.profiles import LONGEST_MOTION
from ics35_async.sim import VirtualLine, VirtualServo
from ics35_async.units import COUNTS_PER_DEGREE
from tests.support.cli_runs import CliResult
from tests.support.robot_rig import JOINTS, Rig, commanded, joint_degrees, joint_position, make_rig, targets_sent
from tests.support.timing import FAST, GUARD, NO_TIMEOUTS_OPTION, scaled

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


@pytest.fixture
def rig(tmp_path: Path) -> Iterator[tuple[Rig, Path]]:
    """The two-line test robot, written out as a TOML file."""
    made = make_rig()
    path = tmp_path / "robot.toml"
    path.write_text(dump_description(load_description(made.description)))
    yield made, path
    made.close()


def write_motion(path: Path, *keyframes: dict[str, Any]) -> Path:
    path.write_text(json.dumps({"format": "ics35-motion", "version": 1, "keyframes": list(keyframes)}))
    return path


@pytest.mark.slow  # (its open reads each ICS 3.5 joint once more with the whole allowance, a line's in turn)
def test_play_the_example_humanoid_with_no_hardware(cli: Any) -> None:
    # Its lines are real-time simulators: the no-timeouts allowance, as for any test across a real-time boundary.
    files = (str(EXAMPLES / "humanoid.toml"), str(EXAMPLES / "wave.json"))
    result = cli(*NO_TIMEOUTS_OPTION, "play", *files, "--speed", "3")
    assert result.code == 0, result.err
    assert "play done" in result.out and "joints left holding" in result.out
    assert "right_elbow" in result.out  # the table at the end
    assert "no --port given" not in result.err


def test_the_example_files_are_valid() -> None:
    robot = load_description(EXAMPLES / "humanoid.toml")
    assert len(robot.joints) == 17 and len(robot.lines) == 2
    assert all(line.port.startswith("sim://") for line in robot.lines.values())


def test_play_with_its_two_files_swapped_says_which_comes_first(
    cli: Any, rig: tuple[Rig, Path], tmp_path: Path
) -> None:
    _, robot_file = rig
    motion = write_motion(tmp_path / "m.json", {"time": 0.2, "pose": {"neck": 20}})
    result = cli("play", str(motion), str(robot_file))
    assert result.code == 2, result.err
    assert "the robot file (ROBOT.toml) comes first, then the motion (MOTION.json)" in " ".join(result.err.split())


def test_play_leaves_the_joints_its_motion_does_not_name_as_they_are(
    cli: Any, rig: tuple[Rig, Path], tmp_path: Path
) -> None:
    # A newcomer's finding: a wrist left holding by `ics35 move`, then a motion that never names it; play freed
    # it at its start (ICS 3.5 servos are read by freeing them) and it stayed limp, while the summary said
    # "joints left holding". A standing humanoid's legs would fold under a wave of its arms.
    sims, robot_file = rig
    sims.servo("elbow").command_position(8000)  # holding, as a move left it
    sims.servo("knee").command_position(7000)
    upper, lower = sims.upper.transactions, sims.lower.transactions
    motion = write_motion(tmp_path / "m.json", {"time": 0.2, "pose": {"neck": 20, "hip": -10}})
    result = cli("play", str(robot_file), str(motion))
    assert result.code == 0, result.err
    for name, sim, since in (("elbow", sims.upper, upper), ("knee", sims.lower, lower)):
        assert not sims.servo(name).free and sims.servo(name).target in (8000, 7000), name
        spec = JOINTS[name]
        assert list(commanded(sim, spec["id"], since)) == [], name  # not a command: not even a read
    said = " ".join(result.err.split())
    assert "neither in the motion nor in --start-pose, left as they are" in said and ": shoulder, elbow, knee" in said
    assert targets_sent(sims.upper, 1, upper)[-1] == joint_position(JOINTS["neck"], 20)


def test_play_with_joints_plays_only_those_and_leaves_the_others_as_they_are(
    cli: Any, rig: tuple[Rig, Path], tmp_path: Path
) -> None:
    # A motion for both arms and the legs, played on one joint to try it out: the motion's other joints are not
    # opened (not read, so not freed; not commanded), on its line or on another.
    sims, robot_file = rig
    held = {"elbow": 8000, "hip": 7000}
    for name, position in held.items():
        sims.servo(name).command_position(position)
    marks = {"upper": sims.upper.transactions, "lower": sims.lower.transactions}
    motion = write_motion(tmp_path / "m.json", {"time": 0.2, "pose": {"neck": 20, "elbow": 30, "hip": -10}})
    result = cli("play", str(robot_file), str(motion), "--joints", "neck")
    assert result.code == 0, result.err
    for name, position in held.items():
        spec = JOINTS[name]
        assert sims.servo(name).target == position and not sims.servo(name).free, name
        assert list(commanded(sims.sim(spec["line"]), spec["id"], marks[spec["line"]])) == [], name
    assert targets_sent(sims.upper, 1, marks["upper"])[-1] == joint_position(JOINTS["neck"], 20)
    said = " ".join(result.err.split())
    assert "left as they are" in said and "elbow" in said and "hip" in said


def test_play_refuses_joints_it_does_not_know_or_the_motion_does_not_move(
    cli: Any, rig: tuple[Rig, Path], tmp_path: Path
) -> None:
    sims, robot_file = rig
    marks = (sims.upper.transactions, sims.lower.transactions)
    motion = write_motion(tmp_path / "m.json", {"time": 0.2, "pose": {"neck": 20, "hip": -10}})
    result = cli("play", str(robot_file), str(motion), "--joints", "neck,tail")
    assert result.code == 2 and "unknown joint(s): tail" in result.err, result.err
    result = cli("play", str(robot_file), str(motion), "--joints", "neck,knee")
    said = " ".join(result.err.split())
    assert result.code == 2 and "knee" in said and "not in the motion" in said and "neck, hip" in said, said
    result = cli("play", str(robot_file), str(motion), "--joints", " , ")
    assert result.code == 2 and "no joint named" in result.err, result.err
    assert (sims.upper.transactions, sims.lower.transactions) == marks  # nothing was sent


def test_play_a_motion_to_its_end_and_loop_until_the_time_is_up(
    cli: Any, rig: tuple[Rig, Path], tmp_path: Path
) -> None:
    sims, robot_file = rig
    motion = write_motion(
        tmp_path / "m.json",
        {"time": 0.1, "pose": {"neck": 30, "hip": -20}},
        {"time": 0.2, "pose": {"neck": -30, "hip": 20}},
    )
    result = cli("play", str(robot_file), str(motion), "--on-stop", "free")
    assert result.code == 0, result.err
    assert "joints left free" in result.out
    table = result.out[: result.out.index("play done after")]  # its last look says what they are left in
    assert "held" not in table and table.count(" free") >= 2, result.out
    neck = targets_sent(sims.upper, 1)
    assert neck[-1] == joint_position(JOINTS["neck"], -30)
    assert sims.servo("neck").free
    since = sims.upper.transactions
    # (--seconds counts from the command's start, the robot's open included: 2 s leaves several 0.2 s passes
    # even on a loaded machine; 1 s left one in a stress run)
    result = cli("play", str(robot_file), str(motion), "--loop", "--seconds", "2")
    assert result.code == 0, result.err
    assert "time is up" in result.err
    end = joint_position(JOINTS["neck"], -30)
    runs = targets_sent(sims.upper, 1, since)
    assert sum(1 for a, b in itertools.pairwise(runs) if b == end != a) >= 2  # reached more than once


def test_play_counts_each_lines_cycles_not_the_merged_frames(cli: Any, rig: tuple[Rig, Path], tmp_path: Path) -> None:
    # Two lines at 100 Hz each showed "cycle 210" a second in: the robot's frames (one each time either line ends
    # a cycle), read as a 200 Hz rate.  Each line's own count is shown.
    _, robot_file = rig
    motion = write_motion(tmp_path / "m.json", {"time": 1.0, "pose": {"neck": 30, "hip": -20}})
    # (--seconds counts the robot's open too: 3 s leaves a line a second to print on a loaded machine)
    result = cli("play", str(robot_file), str(motion), "--loop", "--seconds", "3")
    assert result.code == 0, result.err
    lines = [line for line in result.out.splitlines() if line.startswith("t=")]
    assert lines and all(re.search(r"cycles lower \d+, upper \d+$", line) for line in lines), result.out


def test_play_names_the_line_options_the_robot_file_decides(cli: Any, rig: tuple[Rig, Path], tmp_path: Path) -> None:
    """A robot's lines are its file's: a line option given for them is said to be unused, not dropped unsaid."""
    _, robot_file = rig
    motion = write_motion(tmp_path / "m.json", {"time": 0.1, "pose": {"neck": 10}})
    result = cli("play", str(robot_file), str(motion))
    assert result.code == 0, result.err
    assert "not used" not in result.err
    result = cli("play", str(robot_file), str(motion), "--no-echo", "--retries", "3", "--direction", "rts")
    assert result.code == 0, result.err
    note = next(line for line in result.err.splitlines() if "not used" in line)
    for option in ("--retries", "--no-echo", "--direction"):
        assert option in note, note
    assert "--port" not in note  # (not given)


def test_play_names_a_baud_rate_given_alone_as_not_used(
    cli: Any, rig: tuple[Rig, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # A robot builder's finding: `--baud 625000` alone was dropped without a word (the note named --port and --baud
    # together, and only when --port was given), and `--port` alone was said as "--port and --baud".
    _, robot_file = rig
    motion = write_motion(tmp_path / "m.json", {"time": 0.1, "pose": {"neck": 10}})

    def note(*args: str) -> str:
        result = cli(*args)
        assert result.code == 0, result.err
        return next((line for line in result.err.splitlines() if "not used" in line), "")

    # (and a value that is the option's default, given all the same: `--baud 115200` went unsaid; before the command
    # as after it)
    for given, unsaid in (
        (["--baud", "625000"], "--port"),
        (["--port", "/dev/ttyUSB7"], "--baud"),
        (["--baud", "115200"], "--port"),
        (["--retries", "1"], "--baud"),
    ):
        for said in (
            note(*given, "play", str(robot_file), str(motion)),
            note("play", str(robot_file), str(motion), *given),
        ):
            assert f"{given[0]} is not used" in said and unsaid not in said, said
    # (set by the environment: named as its variable, not as an option nobody typed)
    monkeypatch.setenv("ICS35_BAUD", "115200")
    said = note("play", str(robot_file), str(motion))
    assert "ICS35_BAUD is not used" in said and "--baud" not in said, said


def test_play_stopped_before_the_first_pass_ends_says_how_far_it_got(
    cli: Any, rig: tuple[Rig, Path], tmp_path: Path
) -> None:
    _sims, robot_file = rig
    motion = write_motion(tmp_path / "m.json", {"time": 5.0, "pose": {"neck": 30}})
    result = cli("play", str(robot_file), str(motion), "--seconds", "0.5")
    assert result.code == 0, result.err
    found = re.search(r"play time is up after [\d.]+ s: ([\d.]+) s of 5\.0 s played;", result.out)
    assert found, result.out
    assert 0.4 <= float(found[1]) <= 0.6  # the time is up at 0.5 s, whatever the smooth stop takes
    shown = [float(t) for t in re.findall(r"t= *([\d.]+)/0\.5 s", result.out)]
    assert shown and max(shown) <= 0.5  # the clock stops at the limit


def test_play_looping_stopped_mid_pass_says_the_pass_its_status_line_said(
    cli: Any, rig: tuple[Rig, Path], tmp_path: Path
) -> None:
    # A user's trial: Ctrl-C in the second pass of a --loop left the status line at "pass 2" right above a summary
    # of "1 pass": how far it got could not be told.  The summary counts the whole passes and names the one stopped
    # part-way with how far into it, as the status line shows them.  (--seconds stops it as Ctrl-C does.)
    _, robot_file = rig
    motion = write_motion(tmp_path / "m.json", {"time": 0.5, "pose": {"neck": 30}})
    result = cli("play", str(robot_file), str(motion), "--loop", "--seconds", "1.5")
    assert result.code == 0, result.err
    status = [line for line in result.out.splitlines() if line.startswith("t=")][-1]
    shown = re.search(r"motion +([\d.]+)/0\.5 s +pass (\d+) ", status)
    assert shown, result.out
    into, count = shown[1], int(shown[2])
    summary = next(line for line in result.out.splitlines() if line.startswith("play time is up after"))
    assert count >= 2, result.out  # (1.5 s leaves more than one 0.5 s pass, even on a loaded machine)
    whole = f"{count - 1} pass{'' if count == 2 else 'es'} of 0.5 s"
    part = f"pass {count} stopped as it began" if float(into) < 0.05 else f"pass {count} stopped {into} s in"
    assert f": {whole}, then {part};" in summary, result.out


def test_play_looping_stopped_in_its_first_pass_names_the_pass(cli: Any, rig: tuple[Rig, Path], tmp_path: Path) -> None:
    # Stopped in the first pass of a --loop, the status line said "pass 1" and the summary "0.5 s of 5.0 s played",
    # as if it had not been looping: later passes' summaries name the pass stopped.
    _, robot_file = rig
    motion = write_motion(tmp_path / "m.json", {"time": 5.0, "pose": {"neck": 30}})
    result = cli("play", str(robot_file), str(motion), "--loop", "--seconds", "0.5")
    assert result.code == 0, result.err
    status = [line for line in result.out.splitlines() if line.startswith("t=")][-1]
    assert re.search(r"motion +[\d.]+/5\.0 s +pass 1 ", status), result.out
    found = re.search(r"play time is up after [\d.]+ s: pass 1 of 5\.0 s stopped ([\d.]+) s in;", result.out)
    assert found, result.out
    assert 0.4 <= float(found[1]) <= 0.6


@pytest.mark.parametrize(
    ("change", "code", "phrase"),
    [
        (lambda robot, motion: (robot.write_text("[lines.a]\nport = 3\n"), motion), 2, "lines.a.port"),
        (
            lambda robot, motion: (robot, write_motion(motion, {"time": 1, "pose": {"neck": 99}})),
            2,
            "keyframes[0]: joint neck: 99 degrees is outside its limits -60..60 (nothing was sent)",
        ),
        (lambda robot, motion: (robot, motion.write_text("{}")), 2, "format: must be 'ics35-motion'"),
        (
            lambda robot, motion: (robot, write_motion(motion, {"time": 1e308, "pose": {"neck": 10}})),
            2,
            "keyframes[0].time: 1e+308 must be at most 3600 seconds (an hour) from the start (nothing was sent)",
        ),
        (lambda robot, motion: (robot.unlink(), motion), 2, "ROBOT.toml"),
    ],
)
def test_bad_files_are_usage_errors(
    cli: Any, rig: tuple[Rig, Path], tmp_path: Path, change: Callable[[Path, Path], Any], code: int, phrase: str
) -> None:
    sims, robot_file = rig
    motion = write_motion(tmp_path / "m.json", {"time": 0.1, "pose": {"neck": 10}})
    change(robot_file, motion)
    result = cli("play", str(robot_file), str(motion))
    assert result.code == code, result.err
    assert phrase in result.err
    assert targets_sent(sims.upper, 1) == []


# Not text, or text in another encoding: named in words (what is wrong, what was expected), not a codec's.
UNREADABLE = {
    "binary": (b"\x7fELF\x02\x01\x01\x00\x00\xd0\xd1", "not a text file"),
    "latin-1": ('name = "caf\xe9"\n'.encode("latin-1"), "not UTF-8 text: byte 0xe9 on line 1"),
    "utf-16": ('{"neck": 10}'.encode("utf-16"), "is UTF-16 text"),
}


@pytest.mark.parametrize("content", list(UNREADABLE), ids=list(UNREADABLE))
@pytest.mark.parametrize("which", ["ROBOT.toml", "MOTION.json", "--start-pose"])
def test_a_file_that_is_not_utf8_text_is_named_so(
    cli: Any, rig: tuple[Rig, Path], tmp_path: Path, which: str, content: str
) -> None:
    sims, robot_file = rig
    motion = write_motion(tmp_path / "m.json", {"time": 0.1, "pose": {"neck": 10}})
    bad = tmp_path / "bad.dat"
    raw, phrase = UNREADABLE[content]
    bad.write_bytes(raw)
    args = {
        "ROBOT.toml": [str(bad), str(motion)],
        "MOTION.json": [str(robot_file), str(bad)],
        "--start-pose": [str(robot_file), str(motion), "--start-pose", str(bad)],
    }[which]
    result = cli("play", *args)
    said = " ".join(result.err.split())
    assert result.code == ExitCode.USAGE, result.err
    assert phrase in said and "codec" not in said and "Traceback" not in said, said
    assert "save it as UTF-8" in said or content == "binary", said
    assert sims.upper.transactions == 0 and sims.lower.transactions == 0


@pytest.mark.parametrize("which", ["MOTION.json", "--start-pose"])
def test_json_nested_deeper_than_python_parses_is_not_json(
    cli: Any, rig: tuple[Rig, Path], tmp_path: Path, which: str
) -> None:
    sims, robot_file = rig
    motion = write_motion(tmp_path / "m.json", {"time": 0.1, "pose": {"neck": 10}})
    bad = tmp_path / "bad.json"
    bad.write_text("[" * 100_000)  # a file edited into nonsense: once a RecursionError's traceback
    args = {
        "MOTION.json": [str(robot_file), str(bad)],
        "--start-pose": [str(robot_file), str(motion), "--start-pose", str(bad)],
    }[which]
    result = cli("play", *args)
    said = " ".join(result.err.split())
    assert result.code == ExitCode.USAGE and "not valid JSON" in said and "nested too deeply" in said, said
    assert sims.upper.transactions == 0 and sims.lower.transactions == 0


@pytest.mark.parametrize(
    ("pose", "phrase"),
    [
        ({"nose": 2}, "keyframes[1]: unknown joint(s): nose"),
        ({"neck": 200}, "keyframes[1]: joint neck: 200 degrees is outside its limits -60..60"),
    ],
)
def test_a_motion_that_does_not_fit_the_robot_is_refused_before_any_port_opens(
    cli: Any, rig: tuple[Rig, Path], tmp_path: Path, pose: dict[str, float], phrase: str
) -> None:
    """A typo'd joint or an angle past its limits must not free the robot first (a standing robot falls)."""
    sims, robot_file = rig
    motion = write_motion(tmp_path / "m.json", {"time": 0.1, "pose": {"hip": 5}}, {"time": 0.2, "pose": pose})
    result = cli("play", str(robot_file), str(motion))
    assert result.code == 2, result.err
    assert phrase in result.err and "(nothing was sent)" in result.err
    assert "started free" not in result.err
    assert sims.upper.transactions == 0 and sims.lower.transactions == 0  # not even a free or a read


def test_play_refusing_a_joint_whose_servo_never_answered_is_exit_code_5_not_a_usage_error(
    cli: Any, rig: tuple[Rig, Path], tmp_path: Path
) -> None:
    # The robot refuses (UnsafeOperation) to drive it blind: nothing wrong with the command line, so not
    # exit code 2, which a script takes for a mistake in its own arguments.
    sims, robot_file = rig
    sims.sim("lower").remove_servo(2)  # the knee's servo: unplugged
    motion = write_motion(tmp_path / "m.json", {"time": 0.5, "pose": {"knee": -10, "hip": 5}})
    result = cli("play", str(robot_file), str(motion))
    assert result.code == 5, result.err
    assert "joint knee has not answered since the robot opened" in result.err
    # The robot was open by then, its ICS 3.5 joints freed to be read (the hip went limp): not "nothing was sent".
    assert sims.servo("hip").free and "nothing was sent" not in result.err, result.err
    assert "no motion was started" in " ".join(result.err.split()), result.err


def test_a_line_where_nothing_answers_gives_its_scan_and_the_baud_rate_the_file_sets(
    cli: Any, rig: tuple[Rig, Path], tmp_path: Path
) -> None:
    # A builder's first-day slip: the file's baudrate is the HS adapter's 1250000, the servos still at their
    # factory 115200. The hints said to check the wiring and that "ics35 scan" looks at every rate, without the
    # line's port to scan nor the rate the file had the line talk at.
    _, robot_file = rig
    port = load_description(robot_file).lines["upper"].port  # (a name of its own in each test)
    text = robot_file.read_text()
    assert text.count("baudrate = 115200") == 2
    robot_file.write_text(text.replace("baudrate = 115200", "baudrate = 1250000", 1))  # the upper line's
    motion = write_motion(tmp_path / "m.json", {"time": 0.1, "pose": {"neck": 10}})
    result = cli("play", str(robot_file), str(motion))
    said = " ".join(result.err.split())
    assert result.code == 4, result.err
    assert f"no joint's servo answered on line(s) upper ({port})" in said, said
    assert f"ics35 --port {port} scan tries every ID at every baud rate" in said, said
    assert "line upper talks at 1250000 baud, the robot file's baudrate" in said, said


@pytest.mark.parametrize("on_stop", ["hold", "free"])
def test_play_refused_as_it_starts_says_the_joints_it_freed_to_read_are_left_free(
    cli: Any, rig: tuple[Rig, Path], tmp_path: Path, on_stop: str
) -> None:
    # A standing robot's legs went limp to be read, then play refused: "no motion was started" alone reads as if
    # the robot were left as it stood.
    sims, robot_file = rig
    sims.sim("lower").remove_servo(2)  # the knee's servo: unplugged
    motion = write_motion(tmp_path / "m.json", {"time": 0.5, "pose": {"knee": -10, "hip": 5}})
    result = cli("play", str(robot_file), str(motion), "--on-stop", on_stop)
    assert result.code == 5, result.err
    assert sims.servo("hip").free, result.err
    said = " ".join(result.err.split())
    assert "joints left free (those it opened" in said, result.err


def captures(sims: Rig, joints: list[str], *changes: Callable[[TaughtTimes], object]) -> list[Keyframe]:
    """The poses ``teach`` keeps of its captures (Enter pressed) on a robot of ``sims``'s: one, then one more after
    each of ``changes`` (given the times taught so far)."""
    keyframes: list[Keyframe] = []

    async def main() -> None:
        async with open_robot(sims.description, **FAST) as robot:
            screen = Screen(Table, str)
            times = TaughtTimes(1.0)
            at_limits: dict[str, list[tuple[int, float, float]]] = {}
            await capture(robot, joints, times, keyframes, screen, at_limits)
            for change in changes:
                change(times)
                await capture(robot, joints, times, keyframes, screen, at_limits)

    anyio.run(main)
    return keyframes


def test_teach_goes_on_when_a_pose_is_not_captured_for_readings_that_disagree(
    rig: tuple[Rig, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    # Enter pressed while a hand still turns a joint (or a joint's readings stop agreeing after the open): that pose
    # is not captured and teaching goes on; the poses before it are kept.  The error ended teaching before.
    sims, _ = rig

    def broken_potentiometer(_: TaughtTimes) -> None:
        sims.servo("elbow").noisy = True

    keyframes = captures(sims, ["elbow", "neck"], broken_potentiometer, lambda _: None)
    assert len(keyframes) == 1
    said = " ".join(capsys.readouterr().err.split())
    assert said.count("pose not captured: joint elbow (line upper, ID 3)") == 2, said
    assert "hold the robot still and press Enter again" in said, said


def test_teach_records_a_joint_at_its_calibrated_end_at_the_limit_without_a_warning(
    rig: tuple[Rig, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    # A joint posed at the end of a calibrated range stands up to a tenth of a degree and a count past a limit
    # (calibrate rounds limits inward): teach warned "beyond its limits" at every pose that used the whole range.
    sims, _ = rig
    past = joint_position(JOINTS["hip"], 30.1)  # (the end the limit 30 was rounded from, a count further still)
    sims.servo("hip").move_by_hand(past)
    assert 30.1 < joint_degrees(JOINTS["hip"], past) <= 30.1 + 1 / COUNTS_PER_DEGREE
    keyframes = captures(sims, ["hip"])
    assert keyframes[0].pose == {"hip": 30.0}  # recorded at the limit
    said = " ".join(capsys.readouterr().err.split())
    assert "beyond its limits" not in said, said


def test_teach_says_how_far_past_its_limit_a_joint_stands_to_the_count(
    rig: tuple[Rig, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    # Further past than calibrate's rounding: said, to the count ("at 30.0, beyond its limits -30..30" said it was
    # at the limit and beyond it at once).
    sims, _ = rig
    past = joint_position(JOINTS["hip"], 30.2) + 1
    sims.servo("hip").move_by_hand(past)
    standing = joint_degrees(JOINTS["hip"], past)
    assert 30.2 < standing < 30.25
    keyframes = captures(sims, ["hip"])
    assert keyframes[0].pose == {"hip": 30.0}  # recorded at the limit
    said = " ".join(capsys.readouterr().err.split())
    assert f"joint hip is at {standing:+.5f}".rstrip("0") + ", beyond its limits -30..30" in said, said
    assert "recorded at its limit" not in said, said  # (a terminal's kept line: into a log the warning stays)


@pytest.mark.parametrize("command", ["play", "calibrate"])
def test_a_joint_whose_readings_never_agree_ends_the_command_in_one_line_not_a_hang(
    cli: Any, rig: tuple[Rig, Path], tmp_path: Path, command: str
) -> None:
    # A servo with a broken potentiometer answers, but no reading agrees with the one before: play's start and
    # calibrate's first read of the pose waited for one that does, and the command hung.  (teach: see above.)
    sims, robot_file = rig
    sims.servo("elbow").noisy = True
    if command == "play":
        motion = write_motion(tmp_path / "m.json", {"time": 0.5, "pose": {"elbow": 10, "neck": 5}})
        result = cli("play", str(robot_file), str(motion))
    else:
        result = cli("calibrate", str(robot_file), "--yes", stdin="\n\n")
    assert result.code == ExitCode.COMMUNICATION, result.err
    said = " ".join(result.err.split())
    assert "joint elbow (line upper, ID 3) last read at" in said and "Traceback" not in said, result.err
    assert "neck" not in said.split("last read at")[0], said  # (only the joint at fault is named)
    assert all(
        targets_sent(sims.sim(line), servo_id) == []
        for line, servo_id in ((s["line"], s["id"]) for s in JOINTS.values())
    )


def test_a_safety_stop_is_exit_code_7(cli: Any, tmp_path: Path) -> None:
    sims = make_rig(safety={"max_current": 20, "action": "free"})
    try:
        robot_file = tmp_path / "robot.toml"
        robot_file.write_text(dump_description(load_description(sims.description)))
        sims.servo("knee").load = 45  # a stalled knee: draws current as soon as it holds
        motion = write_motion(
            tmp_path / "m.json", {"time": 1.0, "pose": {"knee": -50}}, {"time": 2.0, "pose": {"knee": 0}}
        )
        result = cli("play", str(robot_file), str(motion))
    finally:
        sims.close()
    assert result.code == 7, result.err
    assert "safety stop: joint knee (line lower, ID 2) draws current" in result.err
    assert "hint:" in result.err


Step = tuple[str | None, Callable[[], None] | None, str]


# How many transactions a line runs after a hand's move before the test goes on ("the robot has seen it"): the
# command reads each joint once a cycle, and takes each frame on the loop that serves its in-process simulated lines,
# so a few tens of cycles are a wide margin.  No more: each costs CPU (the commands cycle as fast as the simulator
# answers), and the settling is most of what these tests' commands transact.
SETTLE_TRANSACTIONS = 60


def run_with_hands(args: list[str], steps: list[Step], sims: list[VirtualLine]) -> CliResult:
    """Run ``ics35 ARGS`` with a pipe as stdin.  For each ``(phrase, move, text)`` step a helper thread waits
    until the command has printed ``phrase`` (it has done what came before), does the hand ``move``, lets
    the robot see it (``SETTLE_TRANSACTIONS`` on every line), then types ``text``."""
    read_end, write_end = os.pipe()
    stdin = os.fdopen(read_end, "r")
    writer = os.fdopen(write_end, "w")
    errors = io.StringIO()

    def settle() -> None:
        marks = [sim.transactions for sim in sims]
        give_up = time.monotonic() + GUARD  # (a line the command did not open would be waited for for ever;
        # going on then leaves the command to show what it saw, rather than a hang in a helper thread)
        while any(sim.transactions < mark + SETTLE_TRANSACTIONS for sim, mark in zip(sims, marks, strict=True)):
            if time.monotonic() > give_up:
                return
            threading.Event().wait(0.005)

    def hands() -> None:
        for phrase, move, text in steps:
            give_up = time.monotonic() + GUARD
            while phrase is not None and phrase not in errors.getvalue():
                if time.monotonic() > give_up:  # (never said: the input ends, and the test sees what was)
                    writer.close()
                    return
                threading.Event().wait(0.005)
            settle()
            if move is not None:
                move()
                settle()
            writer.write(text)
            writer.flush()
        writer.close()

    helper = threading.Thread(target=hands, daemon=True)
    old_stdin, old_out, old_err = sys.stdin, sys.stdout, sys.stderr
    sys.stdin, sys.stdout, sys.stderr = stdin, io.StringIO(), errors
    try:
        helper.start()
        with pytest.raises(SystemExit) as exited:
            main(args)
        out, err = sys.stdout.getvalue(), errors.getvalue()  # type: ignore[attr-defined]
    finally:
        sys.stdin, sys.stdout, sys.stderr = old_stdin, old_out, old_err
        helper.join(10)
        stdin.close()
    code = exited.value.code
    return CliResult(code if isinstance(code, int) else 1, out, err)


def test_teach_captures_hand_poses_and_play_brings_them_back(
    rig: tuple[Rig, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("ICS35_PORT", raising=False)
    sims, robot_file = rig
    out_file = tmp_path / "taught.json"
    neck, hip = sims.servo("neck"), sims.servo("hip")
    first = {"neck": 25.0, "hip": -15.0}
    second = {"neck": -40.0, "hip": 22.0}

    def pose(values: dict[str, float]) -> Callable[[], None]:
        def move() -> None:
            neck.move_by_hand(joint_position(JOINTS["neck"], values["neck"]))
            hip.move_by_hand(joint_position(JOINTS["hip"], values["hip"]))

        return move

    out_file.write_text('{"hand-edited": true}\n')  # a motion of the user's, under the name reused
    result = run_with_hands(
        ["teach", str(robot_file), str(out_file), "--joints", "neck,hip"],
        [("Enter captures", pose(first), "\n"), ("pose 1 at", pose(second), "\n"), ("pose 2 at", None, "q\n")],
        [sims.upper, sims.lower],
    )
    assert result.code == 0, result.err
    assert "wrote 2 pose(s)" in result.out
    # The file it replaced is kept beside it, and the user was told before teaching began.
    assert (tmp_path / "taught.json.bak").read_text() == '{"hand-edited": true}\n'
    assert "taught.json.bak" in " ".join((result.out + result.err).split())
    assert "exists" in result.err.split("Enter captures")[0], result.err
    taught = json.loads(out_file.read_text())
    assert [k["pose"] for k in taught["keyframes"]] == [pytest.approx(first, abs=0.05), pytest.approx(second, abs=0.05)]
    # The first pose is reached in the lead time whenever it was captured; the rest keep their spacing.
    assert taught["keyframes"][0]["time"] == 1.0
    assert taught["keyframes"][1]["time"] > 1.0
    # Elsewhere by hand, then play it back: the robot ends at the second pose.
    pose({"neck": 0.0, "hip": 0.0})()
    result = run_with_hands(["play", str(robot_file), str(out_file)], [], [sims.upper, sims.lower])
    assert result.code == 0, result.err
    assert targets_sent(sims.upper, 1)[-1] == joint_position(JOINTS["neck"], taught["keyframes"][1]["pose"]["neck"])
    assert targets_sent(sims.lower, 1)[-1] == joint_position(JOINTS["hip"], taught["keyframes"][1]["pose"]["hip"])


@pytest.fixture
def calibrating(rig: tuple[Rig, Path], monkeypatch: pytest.MonkeyPatch) -> tuple[Rig, dict[str, str]]:
    """The rig's simulated lines and their ports (for CALIBRATE_FILE), with no ICS35_PORT set."""
    monkeypatch.delenv("ICS35_PORT", raising=False)
    sims, _ = rig
    return sims, {name: line["port"] for name, line in sims.description["lines"].items()}


def by_hand(sims: Rig) -> Callable[[dict[str, float]], Callable[[], None]]:
    """``at(servo_degrees)``: a step that turns the neck and hip servos by hand to those servo degrees."""

    def at(servo_degrees: dict[str, float]) -> Callable[[], None]:
        def move() -> None:
            for name in ("neck", "hip"):
                sims.servo(name).move_by_hand(7500 + round(servo_degrees[name] * 8000 / 270))

        return move

    return at


def in_counts(sims: Rig) -> Callable[[dict[str, int]], Callable[[], None]]:
    """``at(positions)``: a step that turns the neck and hip servos by hand to those positions (counts)."""

    def at(positions: dict[str, int]) -> Callable[[], None]:
        def move() -> None:
            for name in ("neck", "hip"):
                sims.servo(name).move_by_hand(positions[name])

        return move

    return at


# Neutrals a whole count off 0.1 degree: 10.125 and -0.03375 servo degrees.
NEUTRAL_COUNTS = {"neck": 7800, "hip": 7499}
TRAVEL_ENDS = ({"neck": 5500, "hip": 5500}, {"neck": 9500, "hip": 9500})


CALIBRATE_FILE = """\
# my arm
[lines.upper]
port = "{upper}"   # the left adapter

[lines.lower]
port = "{lower}"

[joints.neck]      # the head
line = "upper"
id = 1
offset = 0.0       # degrees: trimmed by calibrate
min = -60
max = 60

[joints.hip]
line = "lower"
id = 1
"""
# The same robot with the knee (servo 2 of the lower line) beside the hip.
CALIBRATE_WITH_KNEE = CALIBRATE_FILE.replace("[joints.hip]", '[joints.knee]\nline = "lower"\nid = 2\n\n[joints.hip]')


@pytest.mark.parametrize("bom", ["", "\ufeff"], ids=["utf-8", "utf-8 with a BOM"])
def test_calibrate_writes_neutral_and_range_back_keeping_comments(
    calibrating: tuple[Rig, dict[str, str]], tmp_path: Path, bom: str
) -> None:
    sims, ports = calibrating
    robot_file = tmp_path / "arm.toml"
    # From a Windows editor: CRLF, and from some (Notepad's "UTF-8 with BOM") a byte order mark first.
    written = (bom + CALIBRATE_FILE.format(**ports).replace("\n", "\r\n")).encode()
    robot_file.write_bytes(written)
    at = by_hand(sims)

    result = run_with_hands(
        ["calibrate", str(robot_file)],
        [
            ("neutral (every joint at 0)", at({"neck": 12.0, "hip": -3.0}), "\n"),  # servo degrees
            ("whole range", at({"neck": -50.0, "hip": -60.0}), ""),  # one end of each range
            (None, at({"neck": 70.0, "hip": 40.0}), "\n"),  # the other end; done
        ],
        [sims.upper, sims.lower],
    )
    assert result.code == 0, result.err
    assert "comments kept" in result.out
    assert f"kept as {robot_file}.bak" in " ".join(result.out.split())
    assert Path(f"{robot_file}.bak").read_bytes() == written  # the file as it was
    assert robot_file.read_bytes().count(b"\n") == robot_file.read_bytes().count(b"\r\n")  # its line endings kept
    assert robot_file.read_bytes().startswith(bom.encode())  # and its BOM
    text = robot_file.read_text(encoding="utf-8-sig")
    assert "# my arm" in text and "# the left adapter" in text and "# degrees: trimmed by calibrate" in text
    data = tomllib.loads(text)
    neck_values = {k: data["joints"]["neck"][k] for k in ("offset", "min", "max")}
    hip_values = {k: data["joints"]["hip"][k] for k in ("offset", "min", "max")}
    assert neck_values == pytest.approx({"offset": 12.0, "min": -62.0, "max": 58.0}, abs=0.11)
    assert hip_values == pytest.approx({"offset": -3.0, "min": -57.0, "max": 43.0}, abs=0.11)
    load_description(robot_file)  # still a valid robot file


def test_calibrate_writes_the_offset_on_a_whole_count_so_a_joint_at_its_neutral_reads_zero(
    calibrating: tuple[Rig, dict[str, str]], tmp_path: Path
) -> None:
    # A count is 270/8000 = 0.03375 degree: an offset rounded to 0.1 degree left a joint at its neutral reading
    # up to 0.05 degree (10.1 for a neutral at 10.125), however carefully it was posed.
    sims, ports = calibrating
    robot_file = tmp_path / "arm.toml"
    robot_file.write_text(CALIBRATE_FILE.format(**ports))
    neutral = NEUTRAL_COUNTS
    at = by_hand(sims)

    result = run_with_hands(
        ["calibrate", str(robot_file)],
        [
            ("neutral (every joint at 0)", in_counts(sims)(neutral), "\n"),
            ("whole range", at({"neck": -60.0, "hip": -60.0}), ""),
            (None, at({"neck": 60.0, "hip": 60.0}), "\n"),
        ],
        [sims.upper, sims.lower],
    )
    assert result.code == 0, result.err
    joints = tomllib.loads(robot_file.read_text())["joints"]
    assert {name: joints[name]["offset"] for name in neutral} == {"neck": 10.125, "hip": -0.03375}
    assert "neck: offset +10.125," in result.out and "hip: offset -0.03375," in result.out, result.out
    read_back = load_description(robot_file)
    assert {name: read_back.joints[name].degrees(position) for name, position in neutral.items()} == {
        "neck": 0.0,
        "hip": 0.0,
    }


def test_calibrate_shows_the_neutral_as_the_offset_it_writes(
    calibrating: tuple[Rig, dict[str, str]], tmp_path: Path
) -> None:
    # The live table showed the neutral to 0.1 degree (+10.1) while the file got the whole count's angle (10.125).
    sims, ports = calibrating
    robot_file = tmp_path / "arm.toml"
    robot_file.write_text(CALIBRATE_FILE.format(**ports))
    neutral = NEUTRAL_COUNTS
    at = in_counts(sims)

    result = run_with_hands(
        ["calibrate", str(robot_file)],
        [
            ("neutral (every joint at 0)", at(neutral), "\n"),
            ("whole range", at(TRAVEL_ENDS[0]), ""),
            (None, at(TRAVEL_ENDS[1]), "\n"),
        ],
        [sims.upper, sims.lower],
    )
    assert result.code == 0, result.err
    joints = tomllib.loads(robot_file.read_text())["joints"]
    # The table's last three columns: neutral, min and max (servo degrees), in the row of each joint.
    rows = {
        cells[0]: cells[-3:] for cells in map(str.split, result.out.splitlines()) if cells[:1] in (["neck"], ["hip"])
    }
    shown = {name: float(row[0]) for name, row in rows.items()}
    assert shown == {name: joints[name]["offset"] for name in neutral} == {"neck": 10.125, "hip": -0.03375}, rows


def test_calibrate_shows_the_limits_as_it_writes_them(calibrating: tuple[Rig, dict[str, str]], tmp_path: Path) -> None:
    # The live table showed the extremes in servo degrees (-67.5..+67.5) while the file got the joint's limits
    # (-77.6..57.3 for a neutral at 10.125): a person checking the table against the file found them apart.
    sims, ports = calibrating
    robot_file = tmp_path / "arm.toml"
    robot_file.write_text(CALIBRATE_FILE.format(**ports) + "reverse = true\n")  # the hip turns the other way
    neutral = NEUTRAL_COUNTS
    at = in_counts(sims)

    result = run_with_hands(
        ["calibrate", str(robot_file)],
        [
            ("neutral (every joint at 0)", at(neutral), "\n"),
            ("whole range", at(TRAVEL_ENDS[0]), ""),
            (None, at(TRAVEL_ENDS[1]), "\n"),
        ],
        [sims.upper, sims.lower],
    )
    assert result.code == 0, result.err
    joints = tomllib.loads(robot_file.read_text())["joints"]
    written = {name: [joints[name][key] for key in ("offset", "min", "max")] for name in neutral}
    assert written == {"neck": [10.125, -77.6, 57.3], "hip": [-0.03375, -67.5, 67.4]}
    # The table's last three columns, in the row of each joint.
    rows = {
        cells[0]: [float(cell) for cell in cells[-3:]]
        for cells in map(str.split, result.out.splitlines())
        if cells[:1] in (["neck"], ["hip"])
    }
    assert rows == written


def test_calibrate_shows_each_joints_position_from_the_offset_it_found(
    calibrating: tuple[Rig, dict[str, str]], tmp_path: Path
) -> None:
    # pos° came from the file's old offset, beside the new offset and the limits from it: a joint held at the end
    # of its range read 20 degrees away from the max beside it.
    sims, ports = calibrating
    robot_file = tmp_path / "arm.toml"
    old = CALIBRATE_FILE.format(**ports).replace("offset = 0.0 ", "offset = 30.0 ") + "offset = -20.0\nreverse = true\n"
    robot_file.write_text(old)
    at = in_counts(sims)

    result = run_with_hands(
        ["calibrate", str(robot_file)],
        [
            ("neutral (every joint at 0)", at(NEUTRAL_COUNTS), "\n"),
            ("whole range", at(TRAVEL_ENDS[0]), ""),
            (None, at(TRAVEL_ENDS[1]), "\n"),  # (left there: the table at the end shows each joint at that end)
        ],
        [sims.upper, sims.lower],
    )
    assert result.code == 0, result.err
    before, after = load_description(str(tmp_path / "arm.toml.bak")), load_description(robot_file)
    rows = {cells[0]: cells for cells in map(str.split, result.out.splitlines()) if cells[:1] in (["neck"], ["hip"])}
    for name, row in rows.items():
        shown = float(row[3])  # joint, line:ID, target°, pos°, ...
        found = after.joints[name].degrees(TRAVEL_ENDS[1][name])
        assert shown == pytest.approx(found, abs=0.05), (name, row)
        assert abs(shown - before.joints[name].degrees(TRAVEL_ENDS[1][name])) > 5, (name, row)  # (the file's old)
        # Where its range ended: at a limit the table shows beside it (rounded inward, within 0.1 degree).
        assert min(abs(shown - float(limit)) for limit in row[-2:]) <= 0.1 + 1e-9, (name, row)
    assert set(rows) == {"neck", "hip"}, result.out


def test_calibrate_adds_no_offset_of_zero_to_a_joint_without_one_but_updates_an_offset_there(
    calibrating: tuple[Rig, dict[str, str]], tmp_path: Path
) -> None:
    # Every joint calibrated got an offset line, "offset = 0" too in a table that had none: noise in the file.
    sims, ports = calibrating
    robot_file = tmp_path / "arm.toml"
    robot_file.write_text(CALIBRATE_FILE.format(**ports).replace("offset = 0.0 ", "offset = 4.5 "))
    at = by_hand(sims)

    result = run_with_hands(
        ["calibrate", str(robot_file)],
        [
            ("neutral (every joint at 0)", at({"neck": 0.0, "hip": 0.0}), "\n"),
            ("whole range", at({"neck": -50.0, "hip": -60.0}), ""),
            (None, at({"neck": 70.0, "hip": 40.0}), "\n"),
        ],
        [sims.upper, sims.lower],
    )
    assert result.code == 0, result.err
    text = robot_file.read_text()
    hip_table = text[text.index("[joints.hip]") :]
    assert "offset" not in hip_table, hip_table
    assert "offset = 0       # degrees: trimmed by calibrate\n" in text, text  # the neck's line, updated to 0
    joints = tomllib.loads(text)["joints"]
    assert {k: joints["hip"][k] for k in ("min", "max")} == pytest.approx({"min": -60.0, "max": 40.0}, abs=0.11)
    assert load_description(robot_file).joints["hip"].offset == 0.0


def test_calibrate_leaves_a_value_the_file_already_has_as_it_is_written(
    calibrating: tuple[Rig, dict[str, str]], tmp_path: Path
) -> None:
    # A joint calibrated where it was before had its lines rewritten all the same ("offset = 0.0" became
    # "offset = 0", "min = -60.0" became "min = -60"): a diff against the backup showed changes that were none.
    sims, ports = calibrating
    robot_file = tmp_path / "arm.toml"
    original = CALIBRATE_FILE.format(**ports).replace("min = -60\nmax = 60\n", "min = -60.0\nmax = +60  # ends\n")
    robot_file.write_text(original)
    at = by_hand(sims)

    result = run_with_hands(
        ["calibrate", str(robot_file)],
        [
            ("neutral (every joint at 0)", at({"neck": 0.0, "hip": 0.0}), "\n"),
            ("whole range", at({"neck": -60.0, "hip": -60.0}), ""),  # the neck's range as the file has it
            (None, at({"neck": 60.0, "hip": 40.0}), "\n"),
        ],
        [sims.upper, sims.lower],
    )
    assert result.code == 0, result.err
    assert "neck: offset +0.0, min -60.0, max +60.0" in result.out, result.out
    text = robot_file.read_text()
    neck_table = text[: text.index("[joints.hip]")]
    assert neck_table == original[: original.index("[joints.hip]")]
    assert text.count("offset") == 1, text  # (the hip's table gets its range only)


def test_calibrate_does_not_take_a_garbled_reading_for_an_end_of_a_range(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # ICS replies carry no checksum: a byte garbled on the wire reads as a position far from the servo's, and
    # calibrate took every reading in a frame as a place the joint was turned to: one such reading widened the
    # range written to the file by tens of degrees, limits the robot then moved its joint to.
    monkeypatch.delenv("ICS35_PORT", raising=False)
    sims = make_rig(faults="corrupt:0.03", seed=4)
    try:
        ports = {name: line["port"] for name, line in sims.description["lines"].items()}
        robot_file = tmp_path / "arm.toml"
        robot_file.write_text(CALIBRATE_FILE.format(**ports))
        at = by_hand(sims)
        result = run_with_hands(
            ["calibrate", str(robot_file)],
            [
                ("neutral (every joint at 0)", at({"neck": 12.0, "hip": -3.0}), "\n"),
                ("whole range", at({"neck": -50.0, "hip": -60.0}), ""),
                (None, at({"neck": 70.0, "hip": 40.0}), ""),
                # (once more: a turn of 120 degrees within a cycle is taken only once a later reading agrees, and
                # at 3 % garbled replies the robot's last reads before Enter were garbled in one run of 15)
                (None, None, "\n"),
            ],
            [sims.upper, sims.lower],
        )
    finally:
        sims.close()
    assert result.code == 0, result.err
    data = tomllib.loads(robot_file.read_text())
    # (a garble of a few degrees cannot be told from a joint turned by hand within a cycle: those pass)
    said = result.out + result.err
    assert {k: data["joints"]["neck"][k] for k in ("min", "max")} == pytest.approx(
        {"min": -62.0, "max": 58.0}, abs=5
    ), said
    assert {k: data["joints"]["hip"][k] for k in ("min", "max")} == pytest.approx({"min": -57.0, "max": 43.0}, abs=5), (
        said
    )


def test_calibrate_warns_when_a_calibrated_range_reaches_past_the_servos_pulse_limits(
    calibrating: tuple[Rig, dict[str, str]], tmp_path: Path
) -> None:
    # A free servo turns by hand past its EEPROM pulse limits, which bound only the positions it is sent:
    # calibrate wrote such a range without a word (only the next open warned).
    sims, ports = calibrating
    robot_file = tmp_path / "arm.toml"
    robot_file.write_text(CALIBRATE_FILE.format(**ports).replace("min = -60\nmax = 60\n", "min = -40\nmax = 40\n"))
    neck = sims.servo("neck")
    neck.eeprom = neck.eeprom.replace(pulse_limit_low=6000, pulse_limit_high=9000)  # about -50..+50 degrees
    at = by_hand(sims)

    result = run_with_hands(
        ["calibrate", str(robot_file)],
        [
            ("neutral (every joint at 0)", at({"neck": 0.0, "hip": 0.0}), "\n"),
            ("whole range", at({"neck": -45.0, "hip": -60.0}), ""),
            (None, at({"neck": 70.0, "hip": 40.0}), "\n"),
        ],
        [sims.upper, sims.lower],
    )
    assert result.code == 0, result.err
    said = " ".join(result.err.split())
    assert "joints.neck: the file allows -44.9..69.9 degrees, but servo ID 1 on line upper stops at" in said, said
    assert "-50.6..50.6 (EEPROM pulse limits 6000..9000)" in said and "joints.hip" not in said, said


def test_calibrate_warns_when_a_joint_is_reversed_both_in_the_file_and_in_its_servos_eeprom(
    calibrating: tuple[Rig, dict[str, str]], tmp_path: Path
) -> None:
    # The two reversals cancel (the joint turns as its servo would with neither): said as calibrate begins, where
    # a joint's direction is set up, with what either way out does (it mirrors the joint: calibrate again).
    sims, ports = calibrating
    robot_file = tmp_path / "arm.toml"
    robot_file.write_text(CALIBRATE_FILE.format(**ports).replace("id = 1\noffset", "id = 1\nreverse = true\noffset"))
    assert load_description(robot_file).joints["neck"].reverse
    neck = sims.servo("neck")
    neck.eeprom = neck.eeprom.replace(flags=neck.eeprom.flags | Flags.REVERSE)
    at = by_hand(sims)

    result = run_with_hands(
        ["calibrate", str(robot_file)],
        [
            ("neutral (every joint at 0)", at({"neck": 0.0, "hip": 0.0}), "\n"),
            ("whole range", at({"neck": -45.0, "hip": -60.0}), ""),
            (None, at({"neck": 45.0, "hip": 40.0}), "\n"),
        ],
        [sims.upper, sims.lower],
    )
    assert result.code == 0, result.err
    said = " ".join(result.err.split())
    assert f"{robot_file}: joints.neck: reverse = true in the file, and servo ID 1 on line upper" in said, said
    assert f"ics35 --port {ports['upper']} eeprom set 1 flags-=REVERSE" in said, said
    assert "nothing to do" in said and "calibrate it again before any motion" in said, said
    assert said.count("flags-=REVERSE") == 1 and "joints.hip" not in said, said
    assert said.index("flags-=REVERSE") < said.index("neutral"), said  # before step 1


def test_calibrate_writes_a_new_file_when_the_joints_are_inline_tables(
    calibrating: tuple[Rig, dict[str, str]], tmp_path: Path
) -> None:
    sims, ports = calibrating
    robot_file = tmp_path / "inline.toml"
    original = (
        f'lines.upper.port = "{ports["upper"]}"\n'
        'joints.neck = {line = "upper", id = 1}   # inline: cannot be edited in place\n'
    )
    robot_file.write_text(original)
    neck = sims.servo("neck")

    def swing() -> None:
        neck.move_by_hand(6000)
        settle_on(sims.upper)
        neck.move_by_hand(9000)

    result = run_with_hands(
        ["calibrate", str(robot_file), "--joints", "neck"],
        [("neutral (every joint at 0)", None, "\n"), ("whole range", swing, "\n")],
        [sims.upper],
    )
    assert result.code == 0, result.err
    assert robot_file.read_text() == original
    beside = tmp_path / "inline.calibrated.toml"
    assert "inline.calibrated.toml" in result.err
    # The robot file with the range added to the joint's inline table (6000..9000 is -50.625..+50.625 degrees).
    assert beside.read_text() == original.replace("id = 1}", "id = 1, min = -50.6, max = 50.6}")
    assert not Path(f"{robot_file}.bak").exists()  # the robot file itself was not touched


def test_calibrate_writes_beside_a_compact_robot_file_that_file_with_only_the_calibration_changed(
    calibrating: tuple[Rig, dict[str, str]], tmp_path: Path
) -> None:
    # The file written beside was a new one listing every key (offset = 0, reverse = false, ...) without the
    # comments: a diff against the robot file showed the whole file, the calibration lost in it.
    sims, ports = calibrating
    robot_file = tmp_path / "compact.toml"
    original = (
        "# my arm, written compactly\r\n"
        'name = "arm"\r\n'
        f'lines.upper.port = "{ports["upper"]}"   # the left adapter\r\n'
        f'lines.lower = {{ port = "{ports["lower"]}" }}\r\n'
        "\r\n"
        "[joints]\r\n"
        'neck = { line = "upper", id = 1, offset = 0.0 }   # the head\r\n'
        'hip.line = "lower"\r\n'
        "hip.id = 1\r\n"
        "hip.min = -80   # a stop\r\n"
        "\r\n"
        "[safety]\r\n"
        'action = "free"\r\n'
    )
    robot_file.write_bytes(original.encode())
    positions = {"neck": 7500, "hip": 7800}  # the neutral: 0 and 10.125 servo degrees

    def hands(move: Callable[[str], int]) -> Callable[[], None]:
        def turn() -> None:
            for name in ("neck", "hip"):
                sims.servo(name).move_by_hand(move(name))

        return turn

    result = run_with_hands(
        ["calibrate", str(robot_file)],
        [
            ("neutral (every joint at 0)", hands(positions.__getitem__), "\n"),
            ("whole range", hands(lambda _: 5500), ""),  # -67.5 servo degrees
            (None, hands(lambda _: 9500), "\n"),  # +67.5
        ],
        [sims.upper, sims.lower],
    )
    assert result.code == 0, result.err
    assert robot_file.read_bytes() == original.encode()
    assert not Path(f"{robot_file}.bak").exists()
    beside = tmp_path / "compact.calibrated.toml"
    assert str(beside) in " ".join(result.err.split()), result.err
    # Only the calibration: the neck's range added (its offset of 0 is there already), the hip's min changed and
    # its offset and max added (joint degrees: -67.5 - 10.125 and 67.5 - 10.125, rounded inward), the line
    # endings kept.
    expected = original.replace("offset = 0.0 }", "offset = 0.0, min = -67.5, max = 67.5 }").replace(
        "hip.min = -80   # a stop\r\n", "hip.min = -77.6   # a stop\r\nhip.offset = 10.125\r\nhip.max = 57.3\r\n"
    )
    assert beside.read_bytes() == expected.encode()


@pytest.mark.parametrize(
    ("written", "edited", "tables_only"),
    [
        (
            '[ joints . "neck" ]\nline = "upper"\n"offset" = 2   # trimmed\n',
            '[ joints . "neck" ]\nline = "upper"\n"offset" = 10.125   # trimmed\nmin = -50\nmax = 40\n',
            True,
        ),
        (
            'joints.neck = { line = "a, b}", id = 1 }\n',
            'joints.neck = { line = "a, b}", id = 1, offset = 10.125, min = -50, max = 40 }\n',
            False,
        ),
        ('[joints]\n"neck" = {min=-50,id=1}', '[joints]\n"neck" = {min=-50,id=1, offset = 10.125, max = 40}', False),
        (
            "joints.neck.id = 1   # the head\njoints.neck.max = 45",
            "joints.neck.id = 1   # the head\njoints.neck.max = 40\n"
            "joints.neck.offset = 10.125\njoints.neck.min = -50\n",
            False,
        ),
        ('[joints.head]\nline = "upper"\n', None, True),  # no joint neck: nothing to edit
    ],
    ids=["table, quoted keys", "inline", "inline in [joints]", "dotted keys", "no such joint"],
)
def test_calibration_edits_a_joint_the_way_it_is_written_and_nothing_else(
    written: str, edited: str | None, tables_only: bool
) -> None:
    done = edit_joint_values(written, {"neck": {"offset": 10.125, "min": -50.0, "max": 40.0}})
    assert (done and done.text) == edited
    assert done is None or done.tables_only == tables_only


JOINT_SHAPES = {
    "table": '[joints.neck]   # the head\nline = "upper"\nid = 1\n{keys}',
    "inline": 'joints.neck = {{ line = "upper", id = 1{inline} }}   # the head\n',
    "inline in [joints]": '[joints]\nneck = {{line = "upper", id = 1{inline}}}\n',
    "dotted": 'joints.neck.line = "upper"\njoints.neck.id = 1\n{dotted}',
    "dotted in [joints]": '[joints]\n  neck.line = "upper"   # the head\n  neck.id = 1\n{dotted_indented}',
}
OTHER_TABLES = '\n[joints.head]\nline = "upper"\nid = 2\nmin = -10\n\n[safety]\naction = "hold"\n'
TENTHS = st.integers(-1000, 1000).map(lambda tenths: tenths / 10)


@hypothesis.given(
    shape=st.sampled_from(sorted(JOINT_SHAPES)),
    there=st.dictionaries(st.sampled_from(["offset", "min", "max"]), TENTHS),
    offset=st.sampled_from([0.0, 10.125, -0.03375]) | st.integers(-2900, 2900).map(lambda n: round(n * 0.03375, 5)),
    limits=st.tuples(TENTHS, TENTHS),
)
def test_calibration_edit_changes_only_the_joints_values_whatever_its_shape(
    shape: str, there: dict[str, float], offset: float, limits: tuple[float, float]
) -> None:
    written = "# my arm\n" + JOINT_SHAPES[shape].format(
        keys="".join(f"{key} = {value}   # {key}\n" for key, value in there.items()),
        inline="".join(f", {key} = {value}" for key, value in there.items()),
        dotted="".join(f"joints.neck.{key} = {value}\n" for key, value in there.items()),
        dotted_indented="".join(f"  neck.{key} = {value}\n" for key, value in there.items()),
    )
    written += OTHER_TABLES
    values = {"offset": offset, "min": min(limits), "max": max(limits)}
    done = edit_joint_values(written, {"neck": values})
    assert done is not None and done.tables_only == (shape == "table")
    expected = tomllib.loads(written)
    neck = expected["joints"]["neck"]
    neck.update({key: value for key, value in values.items() if key in neck or key != "offset" or value != 0})
    assert tomllib.loads(done.text) == expected
    # The other joint and tables as they were, every comment kept.
    assert done.text.endswith(OTHER_TABLES)
    assert done.text.count("#") == written.count("#")


def test_calibration_of_a_robot_file_changed_meanwhile_out_of_recognition_writes_a_whole_file_beside_it(
    tmp_path: Path,
) -> None:
    # Edited during calibration, the file kept "[joints.neck]" only inside a string: the edit took that for the
    # joint's table, and checking it against the file ended in a KeyError (a traceback for the person).
    robot_file = tmp_path / "arm.toml"
    robot_file.write_text('[lines.upper]\nport = "sim://x"\n\n[joints.neck]\nline = "upper"\nid = 1\n')
    description = load_description(robot_file)
    changed = (
        'name = """\n[joints.neck]\n"""\n[lines.upper]\nport = "sim://x"\n\n[joints.head]\nline = "upper"\nid = 1\n'
    )
    robot_file.write_text(changed)
    neck = calibrate_joint(description.joints["neck"], 10.125, -50.0, 50.0)

    written = write_calibration(robot_file, description, {"neck": neck})

    assert (written.path.name, written.in_place, written.comments_kept) == ("arm.calibrated.toml", False, False)
    assert load_description(written.path).joints["neck"] == neck
    assert robot_file.read_text() == changed


def settle_on(sim: VirtualLine) -> None:
    """Let the robot see a hand move: ``SETTLE_TRANSACTIONS`` on its line."""
    mark = sim.transactions
    while sim.transactions < mark + SETTLE_TRANSACTIONS:
        threading.Event().wait(0.005)


def test_teach_with_joints_leaves_the_others_as_they_are(rig: tuple[Rig, Path], tmp_path: Path) -> None:
    # --joints neck: the other joints were opened too, and their ICS 3.5 servos freed to be read (a held arm
    # dropped while one joint was taught); now only the joints named are opened.
    sims, robot_file = rig
    held = {"elbow": 8000, "hip": 7000, "knee": 7200}
    for name, position in held.items():
        sims.servo(name).command_position(position)
    marks = {"upper": sims.upper.transactions, "lower": sims.lower.transactions}
    result = run_with_hands(
        ["teach", str(robot_file), str(tmp_path / "taught.json"), "--joints", "neck"],
        [("Enter captures", None, "\n"), ("pose 1 at", None, "q\n")],
        [sims.upper],
    )
    assert result.code == 0, result.err
    for name, position in held.items():
        spec = JOINTS[name]
        assert sims.servo(name).target == position and not sims.servo(name).free, name
        assert list(commanded(sims.sim(spec["line"]), spec["id"], marks[spec["line"]])) == [], name


@pytest.mark.skipif(os.name != "posix", reason="SIGINT to this process")
def test_calibrate_stopped_by_ctrl_c_says_nothing_was_written(
    calibrating: tuple[Rig, dict[str, str]], tmp_path: Path
) -> None:
    # Ctrl-C at step 2: it said only "interrupted", leaving the user to wonder whether the file was half changed.
    sims, ports = calibrating
    robot_file = tmp_path / "arm.toml"
    robot_file.write_text(CALIBRATE_FILE.format(**ports))

    def ctrl_c() -> None:
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(scaled(1.0))  # (taken before the end of input that follows)

    result = run_with_hands(
        ["calibrate", str(robot_file)],
        [("neutral (every joint at 0)", None, "\n"), ("whole range", ctrl_c, "")],
        [],
    )
    assert result.code == ExitCode.INTERRUPTED, result.err
    said = " ".join(result.err.split())
    assert f"interrupted: nothing written to {robot_file}" in said, said
    assert "the joints it opened are left free" in said, said
    assert robot_file.read_text() == CALIBRATE_FILE.format(**ports)
    assert all(sims.servo(name).free for name in ("neck", "hip"))


def test_calibrate_refuses_a_joint_not_moved_through_its_range(
    calibrating: tuple[Rig, dict[str, str]], tmp_path: Path
) -> None:
    """Enter twice without moving: a zero-width range would forbid every motion; nothing is written."""
    sims, ports = calibrating
    robot_file = tmp_path / "arm.toml"
    robot_file.write_text(CALIBRATE_FILE.format(**ports))
    neck, hip = sims.servo("neck"), sims.servo("hip")

    def hip_only() -> None:  # the hip swings 40 degrees, the neck moves 3
        neck.move_by_hand(7500 + round(3 * 8000 / 270))
        hip.move_by_hand(7500 - round(20 * 8000 / 270))
        settle_on(sims.lower)
        hip.move_by_hand(7500 + round(20 * 8000 / 270))

    result = run_with_hands(
        ["calibrate", str(robot_file)],
        [("neutral (every joint at 0)", None, "\n"), ("whole range", hip_only, "\n")],
        [sims.upper, sims.lower],
    )
    assert result.code == ExitCode.REFUSED, result.err
    message = " ".join(result.err.split())
    assert "joint neck moved over 3.0 degrees only, less than the 5" in message
    assert "hip" not in message.split("hint")[0]  # the hip's range was fine
    assert f"Nothing was written to {robot_file}" in message
    assert robot_file.read_text() == CALIBRATE_FILE.format(**ports)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["arm.toml", "robot.toml"]  # no backup, no side file


def test_calibrate_with_no_joint_moved_says_so_in_one_short_sentence(
    calibrating: tuple[Rig, dict[str, str]], tmp_path: Path
) -> None:
    """Enter twice, nothing moved: one sentence for the joints (it was the same sentence once per joint, 17
    times over for a humanoid, on one line)."""
    sims, ports = calibrating
    robot_file = tmp_path / "arm.toml"
    robot_file.write_text(CALIBRATE_FILE.format(**ports))
    result = run_with_hands(
        ["calibrate", str(robot_file)],
        [("neutral (every joint at 0)", None, "\n"), ("whole range", None, "\n")],
        [sims.upper, sims.lower],
    )
    assert result.code == ExitCode.REFUSED, result.err
    message = " ".join(result.err.split())
    assert "joints neck, hip moved over less than the 5 degrees a range needs" in message, message
    assert message.count("degrees") == 1, message
    assert f"Nothing was written to {robot_file}" in message
    assert robot_file.read_text() == CALIBRATE_FILE.format(**ports)


@pytest.mark.skipif(os.name != "posix", reason="SIGINT to this process")
def test_teach_keeps_its_poses_when_a_second_ctrl_c_lands_as_it_writes_them(
    rig: tuple[Rig, Path], tmp_path: Path
) -> None:
    # A double Ctrl-C: the first ends the teaching, the second came as the poses were being written (the
    # command's loop already over): KeyboardInterrupt ended the command with "aborted" and nothing written.
    # It is the same stop (a press just after it, as ics35_async.run takes one): the poses are written and
    # teach ends as at one Ctrl-C.
    _, robot_file = rig
    target = tmp_path / "taught.json"

    def second_press(frame: Any, event: str, arg: Any) -> None:
        if event == "call" and frame.f_code.co_name == "save_taught":
            sys.setprofile(None)
            os.kill(os.getpid(), signal.SIGINT)

    def first_press() -> None:
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(scaled(1.0))

    sys.setprofile(second_press)  # (the main thread's, where the command runs)
    try:
        result = run_with_hands(
            ["teach", str(robot_file), str(target), "--joints", "neck"],
            [("Enter captures", None, "\n"), ("pose 1 at", first_press, "")],
            [],
        )
    finally:
        sys.setprofile(None)
    assert result.code == ExitCode.OK, result.err
    assert "aborted" not in result.err
    assert len(json.loads(target.read_text())["keyframes"]) == 1


def test_teach_that_cannot_write_its_file_prints_the_poses_instead(
    rig: tuple[Rig, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The folder goes away while the user poses the robot: the poses are not lost with it.
    monkeypatch.delenv("ICS35_PORT", raising=False)
    sims, robot_file = rig
    folder = tmp_path / "gone"
    folder.mkdir()
    result = run_with_hands(
        ["teach", str(robot_file), str(folder / "taught.json"), "--joints", "neck"],
        [("Enter captures", None, "\n"), ("pose 1 at", folder.rmdir, "q\n")],
        [sims.upper],  # (the lower line has no joint named: it is not opened)
    )
    assert result.code == 2 and "printed above instead" in result.err, result.err
    motion = json.loads(result.out[result.out.index('{\n  "format"') :])
    assert len(motion["keyframes"]) == 1 and set(motion["keyframes"][0]["pose"]) == {"neck"}


def opened_without_probes(sims: Rig, names: list[str]) -> None:
    """Each joint's servo was read its EEPROM, then freed: the open asked none its protocol (ICS 3.6's position
    read, or that read once more at the whole reply allowance before an ICS 3.5 joint went free)."""
    for name in names:
        spec = sims.description["joints"][name]
        sent = [t.command for t in sims.sim(spec["line"]).log_since(0) if t.servo_id == spec["id"]]
        assert sent[:2] == ["read_eeprom", "free"] and "read_position" not in sent, (name, sent)


def test_teach_on_a_robot_of_both_protocols_frees_every_joint_without_probing_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # teach frees every joint it opens, and the free command reads the position on ICS 3.5 and ICS 3.6 alike:
    # the open's protocol probe was wasted, and its read once more of each ICS 3.5 servo cost a whole --timeout.
    monkeypatch.delenv("ICS35_PORT", raising=False)
    sims = make_rig(ics36=[1])  # neck (upper 1) and hip (lower 1) speak ICS 3.6
    robot_file = tmp_path / "robot.toml"
    robot_file.write_text(dump_description(load_description(sims.description)))
    out_file = tmp_path / "taught.json"
    pose = {"neck": 25.0, "shoulder": -30.0, "hip": -15.0, "knee": -40.0}

    def move() -> None:
        for name, deg in pose.items():
            sims.servo(name).move_by_hand(joint_position(JOINTS[name], deg))

    try:
        result = run_with_hands(
            ["teach", str(robot_file), str(out_file), "--joints", ",".join(pose)],
            [("Enter captures", move, "\n"), ("pose 1 at", None, "q\n")],
            [sims.upper, sims.lower],
        )
    finally:
        sims.close()
    assert result.code == 0, result.err
    taught = json.loads(out_file.read_text())
    assert [k["pose"] for k in taught["keyframes"]] == [pytest.approx(pose, abs=0.05)]
    opened_without_probes(sims, list(pose))


def test_calibrate_on_a_robot_of_both_protocols_frees_every_joint_without_probing_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("ICS35_PORT", raising=False)
    sims = make_rig(ics36=[1])  # neck and hip speak ICS 3.6, the knee ICS 3.5
    robot_file = tmp_path / "arm.toml"
    robot_file.write_text(
        CALIBRATE_WITH_KNEE.format(**{name: line["port"] for name, line in sims.description["lines"].items()})
    )

    def at(servo_degrees: dict[str, float]) -> Callable[[], None]:
        def move() -> None:
            for name, deg in servo_degrees.items():
                sims.servo(name).move_by_hand(7500 + round(deg * 8000 / 270))

        return move

    try:
        result = run_with_hands(
            ["calibrate", str(robot_file)],
            [
                ("neutral (every joint at 0)", at({"neck": 12.0, "hip": -3.0, "knee": 6.0}), "\n"),
                ("whole range", at({"neck": -50.0, "hip": -60.0, "knee": -70.0}), ""),
                (None, at({"neck": 70.0, "hip": 40.0, "knee": 30.0}), "\n"),
            ],
            [sims.upper, sims.lower],
        )
    finally:
        sims.close()
    assert result.code == 0, result.err
    joints = tomllib.loads(robot_file.read_text())["joints"]
    assert {n: joints[n]["offset"] for n in ("neck", "hip", "knee")} == pytest.approx(
        {"neck": 12.0, "hip": -3.0, "knee": 6.0}, abs=0.11
    )
    assert {n: (joints[n]["min"], joints[n]["max"]) for n in ("neck", "hip", "knee")} == {
        "neck": pytest.approx((-62.0, 58.0), abs=0.11),
        "hip": pytest.approx((-57.0, 43.0), abs=0.11),
        "knee": pytest.approx((-76.0, 24.0), abs=0.11),
    }
    opened_without_probes(sims, ["neck", "hip", "knee"])


@pytest.mark.filterwarnings("ignore:.*did not answer:ics35_async.robot.RobotWarning")
@pytest.mark.parametrize("command", ["teach", "calibrate"])
def test_teach_and_calibrate_with_a_line_where_nothing_answers_ask_that_line_once(
    cli: Any, tmp_path: Path, command: str
) -> None:
    # Two legs unplugged on their own line: teach waited each leg joint's EEPROM read, its probe and the stream's
    # first three cycles, each a whole --timeout (nothing had answered there to learn a shorter wait from).  Now
    # the line's first joint is read, one ID read asks the line, and its joints start offline.  Calibrate then read
    # each silent joint's EEPROM again (for its reverse flag and pulse limits), each read a whole --timeout and its
    # retries: at --timeout 1 a humanoid's ten leg joints kept step 1 from showing for over a minute.
    sims = make_rig()
    sims.description["joints"]["ankle"] = {"line": "lower", "id": 3}  # (no servo: the leg's third joint)
    for servo_id in (1, 2):
        sims.lower.remove_servo(servo_id)
    robot_file = tmp_path / "robot.toml"
    robot_file.write_text(dump_description(load_description(sims.description)))
    try:
        if command == "teach":
            result = cli("teach", str(robot_file), str(tmp_path / "taught.json"), "--yes", stdin="\nq\n")
        else:
            result = cli("calibrate", str(robot_file), "--yes", stdin="")
    finally:
        sims.close()
    if command == "teach":
        assert result.code == 0, result.err
        said = " ".join(result.err.split())
        assert "joints hip, knee, ankle (servo IDs 1, 2, 3 on line lower) did not answer" in said, said
    else:
        assert result.code == 5 and "nothing written" in result.err, result.err
    sent = {i: [t.command for t in sims.lower.log_since(0) if t.servo_id == i] for i in (None, 1, 2, 3)}
    assert sent[None] == ["read_id"] and sent[1][:1] == ["read_eeprom"], sent
    assert all(set(sent[i][1 if i == 1 else 0 :]) <= {"free"} for i in (1, 2, 3)), sent  # (probes, the close)


def test_teach_and_calibrate_refuse_bad_arguments(cli: Any, rig: tuple[Rig, Path], tmp_path: Path) -> None:
    _, robot_file = rig
    result = cli("teach", str(robot_file), str(tmp_path / "x.txt"))
    assert result.code == 2 and "cannot write .txt files" in result.err
    result = cli("teach", str(robot_file), str(tmp_path / "x.json"), "--joints", "neck,tail")
    assert result.code == 2 and "unknown joint(s): tail" in result.err
    result = cli("calibrate", str(robot_file), stdin="")
    assert result.code == 5 and "nothing written" in result.err
    result = cli("teach", str(robot_file), str(tmp_path / "x.json"), stdin="q\n")
    assert result.code == 5 and "no pose captured" in result.err
    assert not (tmp_path / "x.json").exists()


def test_a_directory_given_for_a_file_is_named_so(cli: Any, rig: tuple[Rig, Path], tmp_path: Path) -> None:
    # It was "no such file", for a folder the user could see was there.
    sims, robot_file = rig
    motion = write_motion(tmp_path / "m.json", {"time": 0.1, "pose": {"neck": 10}})
    folder = tmp_path / "motions"
    folder.mkdir()
    for args, placeholder in (([robot_file, folder], "MOTION.json"), ([folder, motion], "ROBOT.toml")):
        result = cli("play", *map(str, args))
        said = " ".join(result.err.split())
        assert result.code == ExitCode.USAGE, result.err
        assert f"{placeholder} {folder}: is a directory" in said and "no such file" not in said, said
    assert sims.upper.transactions == sims.lower.transactions == 0


@pytest.mark.parametrize("command", ["teach", "calibrate"])
def test_a_backup_path_that_is_a_directory_is_refused_before_the_joints_go_free(
    cli: Any, rig: tuple[Rig, Path], tmp_path: Path, command: str
) -> None:
    # The file's old content goes to NAME.bak: a folder there made the write fail only at the end, after the
    # poses were taken by hand, as "cannot write taught.json: Is a directory" (taught.json was not one).
    sims, robot_file = rig
    out_file = tmp_path / "taught.json"
    out_file.write_text("{}\n")
    target = out_file if command == "teach" else robot_file
    Path(f"{target}.bak").mkdir()
    args = [str(robot_file), str(out_file)] if command == "teach" else [str(robot_file)]
    result = cli(command, *args, stdin="\nq\n")
    said = " ".join(result.err.split())
    assert result.code == ExitCode.USAGE, result.err
    assert f"{target}.bak" in said and "is a directory" in said and "Traceback" not in said, said
    assert sims.upper.transactions == sims.lower.transactions == 0  # nothing freed, nothing read
    assert out_file.read_text() == "{}\n"


def test_calibrate_that_cannot_write_at_the_end_says_so_in_words(
    calibrating: tuple[Rig, dict[str, str]], tmp_path: Path
) -> None:
    # The backup's place taken by a folder while the joints were moved by hand: a traceback, and the values lost.
    sims, ports = calibrating
    robot_file = tmp_path / "arm.toml"
    robot_file.write_text(CALIBRATE_FILE.format(**ports))
    at = by_hand(sims)

    def then_a_folder() -> None:
        at({"neck": 70.0, "hip": 40.0})()
        Path(f"{robot_file}.bak").mkdir()

    result = run_with_hands(
        ["calibrate", str(robot_file)],
        [
            ("neutral (every joint at 0)", at({"neck": 12.0, "hip": -3.0}), "\n"),
            ("whole range", at({"neck": -50.0, "hip": -60.0}), ""),
            (None, then_a_folder, "\n"),
        ],
        [sims.upper, sims.lower],
    )
    said = " ".join(result.err.split())
    assert result.code == ExitCode.USAGE, result.err
    assert f"{robot_file}.bak, which is a directory" in said and "printed above" in said, said
    assert "neck: offset" in result.out  # the values found, not lost
    assert robot_file.read_text() == CALIBRATE_FILE.format(**ports)


def test_the_lost_line_hint_names_that_lines_port_and_what_the_others_were_left_in() -> None:
    description = load_description(
        {
            "lines": {"arms": {"port": "/dev/ttyUSB1"}, "legs": {"port": "/dev/ttyUSB10", "baudrate": 1250000}},
            "joints": {"a": {"line": "arms", "id": 1}, "l": {"line": "legs", "id": 1}},
        }
    )
    lost = PortLost("port /dev/ttyUSB10 lost: the serial port hung up (device disconnected?)")
    hint = lost_line_hint(Settings(), description, lost, "free")
    # The longest port name in the message (not USB1), at that line's baud rate (its servos hear no other).
    assert "ics35 --port /dev/ttyUSB10 --baud 1250000 free 1;" in hint
    assert hint.endswith("the other lines' joints were left free")


def test_the_lost_line_hint_frees_that_lines_servos_by_their_ids_not_every_id() -> None:
    # `free all` asks all 32 IDs: it frees the robot's servos, then ends with exit code 4 and "servo(s) 0, 5,
    # ... did not go free", each absent ID taken for a servo without power.
    description = load_description(
        {
            "lines": {"arms": {"port": "/dev/ttyUSB1"}, "legs": {"port": "/dev/ttyUSB2"}},
            "joints": {
                "a": {"line": "arms", "id": 7},
                "b": {"line": "legs", "id": 4},
                "c": {"line": "legs", "id": 2},
                "d": {"line": "legs", "id": 3},
                "e": {"line": "legs", "id": 9},
            },
        }
    )
    lost = PortLost("port /dev/ttyUSB2 lost: the serial port hung up (device disconnected?)")
    hint = lost_line_hint(Settings(), description, lost, None)
    assert hint.endswith("get: ics35 --port /dev/ttyUSB2 free 2-4,9"), hint


def swing(sims: Rig, sign: int) -> Callable[[], None]:
    """A step that turns the neck, hip and knee servos by hand to 40 servo degrees on the side of ``sign``."""

    def move() -> None:
        for name in ("neck", "hip", "knee"):
            sims.servo(name).move_by_hand(7500 + sign * round(40 * 8000 / 270))

    return move


def plug_back(sim: VirtualLine, servo: VirtualServo) -> None:
    """Plug ``servo`` back into ``sim``'s line and wait until it has been asked something (heard back only at its
    next probe, one probe interval on: a count of transactions may come first)."""
    mark = sim.transactions
    sim.add_device(servo)
    give_up = time.monotonic() + GUARD
    while not any(t.responders == (servo.servo_id,) for t in sim.log_since(mark)):
        assert time.monotonic() < give_up, f"servo {servo.servo_id}, plugged back in, was never asked"
        threading.Event().wait(0.005)


def until_offline(sims: Rig, joint: str) -> Callable[[], None]:
    """A step that unplugs ``joint``'s servo and waits until the robot has had time to take it out of its
    cycle (three settles' transactions on its line, the other servos answering)."""

    def unplug() -> None:
        spec = JOINTS[joint]
        sim = sims.sim(spec["line"])
        sim.remove_servo(spec["id"])
        for _ in range(3):
            settle_on(sim)

    return unplug


def test_play_with_a_line_lost_says_the_other_lines_joints_hold_their_last_targets(
    rig: tuple[Rig, Path], tmp_path: Path
) -> None:
    # The legs' adapter pulled mid-motion: the arms' joints stop at once where the motion had them (no ramp, not
    # thrown on to the keyframe, not freed), and the error says so, not just "left holding".
    sims, robot_file = rig
    motion = write_motion(tmp_path / "m.json", {"time": 10.0, "pose": {"neck": 50, "hip": 20}, "profile": "linear"})
    mark, start = sims.upper.transactions, sims.servo("neck").position
    result = run_with_hands(
        ["play", str(robot_file), str(motion)],
        [("started free", lambda: (time.sleep(1.0), sims.lower.unplug()), "")],
        [],  # (the upper line's cycles end with the lower line's)
    )
    assert result.code == ExitCode.COMMUNICATION, result.err
    said = " ".join(result.err.split())
    assert "the other lines' joints were left holding their last targets" in said, said
    assert "stopped there at once" in said, said
    # (the lost line's joints held the motion's targets: they stay stiff until freed, and the command that does)
    port = load_description(robot_file).lines["lower"].port
    assert "the servos on the lost line keep their last command" in said and f"ics35 --port {port} free" in said, said
    neck = sims.servo("neck")
    last = targets_sent(sims.upper, 1, mark)[-1]
    assert not neck.free and neck.target == last
    assert start < last < joint_position(JOINTS["neck"], 50)  # mid-motion


def test_teach_with_a_line_lost_names_only_the_servos_it_freed_on_that_line(
    rig: tuple[Rig, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # A robot builder's finding: `teach --joints` of one leg joint per line, the legs' adapter pulled: the
    # hint's command freed every servo of the legs' line, those teach had left as they were (holding a
    # standing robot up) included.
    monkeypatch.delenv("ICS35_PORT", raising=False)
    sims, robot_file = rig
    result = run_with_hands(
        ["teach", str(robot_file), str(tmp_path / "taught.json"), "--joints", "neck,hip"],
        # (then a second for teach to see the loss, before the end of its input would end it normally)
        [("Enter captures", None, "\n"), ("pose 1 at", lambda: (sims.lower.unplug(), time.sleep(1.0)), "")],
        [],  # (the upper line's cycles end with the lower line's)
    )
    assert result.code == ExitCode.COMMUNICATION, result.err
    said = " ".join(result.err.split())
    # (teach had freed hip, the one joint it opened there: nothing to free, no command that would free the others)
    assert "joint hip on the lost line was free when the line went: nothing holds it" in said, said
    assert "ics35 --port" not in said.partition("hint:")[2], said
    assert said.endswith("the other lines' joints were left free"), said
    assert sims.servo("neck").free  # (so they were)


@pytest.mark.parametrize("command", ["teach", "calibrate", "play"])
def test_a_robot_command_names_the_line_whose_adapter_is_missing(
    cli: Any, rig: tuple[Rig, Path], tmp_path: Path, command: str
) -> None:
    # The legs' adapter unplugged: "no serial port at '/tmp/nothing/legs'" alone did not say which line of the
    # robot file that was, nor that the other lines' joints can be opened meanwhile.
    sims, robot_file = rig
    missing = str(tmp_path / "nothing" / "lower")
    sims.description["lines"]["lower"]["port"] = missing
    robot_file.write_text(dump_description(load_description(sims.description)))
    files = {
        "teach": [str(tmp_path / "taught.json")],
        "calibrate": [],
        "play": [str(write_motion(tmp_path / "m.json", {"time": 0.2, "pose": {"neck": 20, "hip": 5}}))],
    }[command]
    result = cli(command, str(robot_file), *files, "--yes" if command != "play" else "--speed=1")
    assert result.code == ExitCode.PORT, result.err
    said = " ".join(result.err.split())
    assert f"{robot_file}: line lower: no serial port at '{missing}'" in said, said
    # (play opens the joints its motion moves: of those, the neck alone is on the upper line)
    others = "neck" if command == "play" else "neck,shoulder,elbow"
    assert f"--joints can open only the joints on the other line meanwhile: --joints {others}" in said, said


@pytest.mark.parametrize("command", ["teach", "play"])
def test_a_robot_command_whose_adapters_are_all_missing_offers_no_joints_of_another_missing_one(
    cli: Any, rig: tuple[Rig, Path], tmp_path: Path, command: str
) -> None:
    # A robot file given its adapters' names before they were plugged in: the error named the first line's missing
    # port, then offered "--joints can open only the joints on the other line meanwhile", whose port was missing
    # too (the command it made failed the same way).  The other line's port is named as missing as well instead.
    sims, robot_file = rig
    missing = {name: str(tmp_path / "nothing" / name) for name in ("upper", "lower")}
    for name, port in missing.items():
        sims.description["lines"][name]["port"] = port
    robot_file.write_text(dump_description(load_description(sims.description)))
    files = {
        "teach": [str(tmp_path / "taught.json")],
        "play": [str(write_motion(tmp_path / "m.json", {"time": 0.2, "pose": {"neck": 20, "hip": 5}}))],
    }[command]
    result = cli(command, str(robot_file), *files, "--yes" if command != "play" else "--speed=1")
    assert result.code == ExitCode.PORT, result.err
    said = " ".join(result.err.split())
    first = next(name for name in missing if f"line {name}: no serial port at '{missing[name]}'" in said)
    (other,) = set(missing) - {first}
    assert "--joints" not in said, said
    assert f"the port of line {other}, {missing[other]}, is not there either" in said, said


def test_a_line_whose_port_is_busy_names_a_missing_one_as_missing_not_missing_either(tmp_path: Path) -> None:
    # ("either" said of a line beside one whose port was there, only busy or not a serial port)
    from ics35_async.errors import PortBusy

    ports = {"arms": str(tmp_path / "arms"), "legs": str(tmp_path / "legs")}
    description = load_description(
        {
            "lines": {name: {"port": port} for name, port in ports.items()},
            "joints": {f"{name}_joint": {"line": name, "id": 1} for name in ports},
        }
    )
    busy = PortBusy(16, f"port {ports['arms']!r} is busy")
    assert other_lines_hint(description, busy) == [f"the port of line legs, {ports['legs']}, is not there"]


def test_of_three_lines_two_missing_the_joints_offered_are_the_third_lines_named_as_such(tmp_path: Path) -> None:
    # (Three lines, the arms' and the legs' adapters not plugged in: --joints offers the head's line alone, by name.)
    from ics35_async.errors import PortNotFound

    ports = {"arms": str(tmp_path / "arms"), "head": "sim://three-lines-head?ids=1", "legs": str(tmp_path / "legs")}
    description = load_description(
        {
            "lines": {name: {"port": port} for name, port in ports.items()},
            "joints": {f"{name}_joint": {"line": name, "id": 1} for name in ports},
        }
    )
    failed = PortNotFound(2, f"no serial port at {ports['arms']!r}")
    assert other_lines_hint(description, failed) == [
        f"the port of line legs, {ports['legs']}, is not there either",
        "--joints can open only the joints on line head meanwhile: --joints head_joint",
    ]


def test_a_robot_file_whose_sim_url_has_a_typo_is_a_usage_error_naming_its_line(
    cli: Any, rig: tuple[Rig, Path], tmp_path: Path
) -> None:
    # A misspelt option in a line's sim:// URL ended play with a traceback (the command reads the file's simulated
    # lines before it opens them) and exit code 1; it is refused as the file is read, naming the line's port.
    sims, robot_file = rig
    typo = "sim://robot-cli-typo?ids=1-3&realtme=1"
    good = dump_description(load_description(sims.description))
    robot_file.write_text(good.replace(json.dumps(sims.description["lines"]["lower"]["port"]), json.dumps(typo)))
    motion = write_motion(tmp_path / "m.json", {"time": 0.2, "pose": {"neck": 20, "hip": 5}})
    result = cli("play", str(robot_file), str(motion))
    assert result.code == ExitCode.USAGE, result.err
    said = " ".join(result.err.split())
    assert f"{robot_file}: lines.lower.port: \"{typo}\" is refused: sim URL: unknown option 'realtme'" in said, said
    assert "Traceback" not in result.err
    assert sims.upper.transactions == 0


def test_teach_leaves_a_joint_whose_servo_went_offline_out_of_the_pose(
    rig: tuple[Rig, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The hip's servo stops answering (a loose plug) after the first pose: its last known angle is not where
    # the hand has put it since, so a pose captured meanwhile must not record it as if it were.
    monkeypatch.delenv("ICS35_PORT", raising=False)
    sims, robot_file = rig
    out_file = tmp_path / "taught.json"
    sims.servo("hip").move_by_hand(joint_position(JOINTS["hip"], 20.0))
    result = run_with_hands(
        ["teach", str(robot_file), str(out_file), "--joints", "neck,hip,knee"],
        [("Enter captures", None, "\n"), ("pose 1 at", until_offline(sims, "hip"), "\n"), ("pose 2 at", None, "q\n")],
        [sims.upper, sims.lower],
    )
    assert result.code == 0, result.err
    taught = json.loads(out_file.read_text())
    assert taught["keyframes"][0]["pose"]["hip"] == pytest.approx(20.0, abs=0.05)
    assert set(taught["keyframes"][1]["pose"]) == {"neck", "knee"}
    hip = f"joint hip (servo ID {JOINTS['hip']['id']} on line lower)"
    assert f"{hip} does not answer (offline): left out of this pose" in " ".join(result.err.split())


def unplug_the_legs(sims: Rig) -> None:
    """Every servo of the rig's lower line (the hip's and the knee's) unplugged."""
    for name in ("hip", "knee"):
        sims.lower.remove_servo(JOINTS[name]["id"])


def test_teach_says_the_joints_gone_offline_on_a_line_in_one_warning(
    rig: tuple[Rig, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The legs' line unplugged whole after the first pose: each capture said one warning a joint (a humanoid's ten
    # legs' joints, ten lines each Enter), where the open says one a line.
    monkeypatch.delenv("ICS35_PORT", raising=False)
    sims, robot_file = rig
    out_file = tmp_path / "taught.json"

    def unplug_the_lower_line() -> None:
        unplug_the_legs(sims)
        for _ in range(2):  # (and the settling after it: as until_offline's three)
            settle_on(sims.upper)

    result = run_with_hands(
        ["teach", str(robot_file), str(out_file), "--joints", "neck,hip,knee"],
        [("Enter captures", None, "\n"), ("pose 1 at", unplug_the_lower_line, "\n"), ("pose 2 at", None, "q\n")],
        # (the upper line's cycles tell the time, not the lower's: silent, it is probed too seldom)
        [sims.upper],
    )
    assert result.code == 0, result.err
    assert set(json.loads(out_file.read_text())["keyframes"][1]["pose"]) == {"neck"}
    said = [" ".join(line.split()) for line in result.err.splitlines() if "answer" in line]
    ids = f"{JOINTS['hip']['id']}, {JOINTS['knee']['id']}"
    assert said == [
        f"warning: joints hip, knee (servo IDs {ids} on line lower) do not answer (offline): left out of this pose"
    ], result.err


def test_calibrate_does_not_take_an_offline_joints_last_angle_as_its_neutral(
    calibrating: tuple[Rig, dict[str, str]], tmp_path: Path
) -> None:
    # The hip's servo stops answering before the neutral pose: its last known angle (30 degrees off) would
    # become its offset, and every later motion of that joint would be 30 degrees off.
    sims, ports = calibrating
    robot_file = tmp_path / "arm.toml"
    robot_file.write_text(CALIBRATE_WITH_KNEE.format(**ports))
    sims.servo("hip").move_by_hand(7500 + round(30 * 8000 / 270))
    hip = sims.servo("hip")

    def back_and_swing() -> None:  # the plug is pushed back in; each joint goes through its range
        plug_back(sims.lower, hip)
        for name in ("neck", "hip", "knee"):
            sims.servo(name).move_by_hand(7500 - round(40 * 8000 / 270))
        for _ in range(3):
            settle_on(sims.lower)
        for name in ("neck", "hip", "knee"):
            sims.servo(name).move_by_hand(7500 + round(40 * 8000 / 270))

    result = run_with_hands(
        ["calibrate", str(robot_file)],
        [("neutral (every joint at 0)", until_offline(sims, "hip"), "\n"), ("whole range", back_and_swing, "\n")],
        [sims.upper, sims.lower],
    )
    assert result.code == 0, result.err
    calibrated = tomllib.loads(robot_file.read_text())
    # Not calibrated (it was written with an offset of 30).
    assert calibrated["joints"]["hip"].keys().isdisjoint({"offset", "min", "max"})
    said = " ".join(result.err.split())
    assert (
        f"joint hip (servo ID {JOINTS['hip']['id']} on line lower) does not answer (offline): no neutral taken" in said
    ), said
    # Back at step 2 it answered: the end says why it is left out (it was said "did not answer" there).
    assert "joint hip did not answer" not in said, said
    assert "joint hip had no neutral (it did not answer at step 1): not calibrated" in said, said
    # (and step 2 gave it no advice to sweep what it missed: with no neutral, nothing it does there is kept)
    assert "joint hip stopped answering:" not in said and "joint hip answers again" not in said, said
    knee = load_description(robot_file).joints["knee"]  # (an offset of 0 is not written: read as the file means it)
    assert "min" in calibrated["joints"]["knee"] and knee.offset == pytest.approx(0.0, abs=0.1)


def test_calibrate_goes_on_when_a_servo_stops_answering_during_the_ranges(
    calibrating: tuple[Rig, dict[str, str]], tmp_path: Path
) -> None:
    # The hip's plug works loose at step 2, after the neck and the knee have been through their ranges: the
    # safety stop ended the ranges' tracking, and at Enter calibrate failed (exit code 7) writing nothing, the
    # other joints' ranges lost.  The hip's range may be cut short: it alone is not calibrated.
    sims, ports = calibrating
    robot_file = tmp_path / "arm.toml"
    robot_file.write_text(CALIBRATE_WITH_KNEE.format(**ports))

    result = run_with_hands(
        ["calibrate", str(robot_file)],
        [
            ("neutral (every joint at 0)", None, "\n"),
            ("whole range", swing(sims, -1), ""),
            (None, swing(sims, 1), ""),
            (None, until_offline(sims, "hip"), "\n"),
        ],
        [sims.upper, sims.lower],
    )
    assert result.code == 0, result.err
    calibrated = tomllib.loads(robot_file.read_text())
    assert calibrated["joints"]["hip"].keys().isdisjoint({"offset", "min", "max"})
    assert "joint hip stopped answering during step 2: not calibrated" in " ".join(result.err.split())
    for name in ("neck", "knee"):
        joint = load_description(robot_file).joints[name]  # (an offset of 0 is not written: read as the file means it)
        values = {"offset": joint.offset, "min": joint.min, "max": joint.max}
        assert values == pytest.approx({"offset": 0.0, "min": -40.0, "max": 40.0}, abs=0.11), name


def test_calibrate_keeps_the_range_of_a_joint_that_stopped_answering_for_a_moment_and_says_so_at_once(
    calibrating: tuple[Rig, dict[str, str]], tmp_path: Path
) -> None:
    # A few missed replies at step 2 (a loaded machine, a plug touched): nothing said until Enter, then "joint hip
    # stopped answering during step 2: not calibrated" (for a robot of one joint, "no joint answered"),
    # the range the person had just swept lost though the joint answered before and after.  Told at once, they
    # can sweep again what it missed; its range is what was seen while it answered.
    sims, ports = calibrating
    robot_file = tmp_path / "arm.toml"
    robot_file.write_text(CALIBRATE_WITH_KNEE.format(**ports))
    hip = sims.servo("hip")

    def plugged_back() -> None:
        plug_back(sims.lower, hip)
        for _ in range(3):
            settle_on(sims.lower)

    result = run_with_hands(
        ["calibrate", str(robot_file)],
        [
            ("neutral (every joint at 0)", None, "\n"),
            ("whole range", swing(sims, -1), ""),
            (None, until_offline(sims, "hip"), ""),
            ("joint hip stopped answering", plugged_back, ""),  # (said as it happened, not at Enter)
            ("joint hip answers again", swing(sims, 1), "\n"),
        ],
        [sims.upper, sims.lower],
    )
    assert result.code == 0, result.err
    for name in ("neck", "hip", "knee"):
        joint = load_description(robot_file).joints[name]  # (an offset of 0 is not written: read as the file means it)
        values = {"offset": joint.offset, "min": joint.min, "max": joint.max}
        assert values == pytest.approx({"offset": 0.0, "min": -40.0, "max": 40.0}, abs=0.11), name
    said = " ".join(result.err.split())
    assert "joint hip stopped answering for a moment during step 2: its range is what was seen" in said, said


@pytest.mark.parametrize("on_stop", ["hold", "free"])
def test_play_says_which_joint_it_could_not_leave_as_its_summary_says(cli: Any, tmp_path: Path, on_stop: str) -> None:
    # With continue_on_offline the motion plays on without a servo that does not answer (unplugged here); the
    # summary said every joint was left holding (or free), the silent one included, which got no command.
    sims = make_rig(safety={"continue_on_offline": True})
    try:
        robot_file = tmp_path / "robot.toml"
        robot_file.write_text(dump_description(load_description(sims.description)))
        sims.lower.remove_servo(JOINTS["hip"]["id"])
        motion = write_motion(tmp_path / "m.json", {"time": 0.2, "pose": {"neck": 20, "hip": -10}})
        result = cli("play", str(robot_file), str(motion), "--on-stop", on_stop)
    finally:
        sims.close()
    assert result.code == 0, result.err
    summary = " ".join(result.out[result.out.index("play done after") :].split())
    assert f"joints left {'free' if on_stop == 'free' else 'holding'} (those it opened), but hip: its servo" in summary
    assert "does not answer (offline)" in summary
    assert "neck" not in summary


def unplug_once_answered(sim: VirtualLine, servo_id: int) -> None:
    """Unplug ``servo_id`` a moment after it first answers a position command (mid-motion: the robot has heard
    it), from a thread of its own.  (Not after its first answer of any kind: the start's read of an ICS 3.5
    servo frees it, and on a loaded machine the robot's stream may not have heard it 0.3 s later: a joint never
    heard from is refused, not tripped.)"""

    def run() -> None:
        deadline = time.monotonic() + scaled(30.0)
        while time.monotonic() < deadline:
            if any(t.servo_id == servo_id and t.reply and t.command == "position" for t in sim.log_since(0)):
                time.sleep(0.3)
                sim.remove_servo(servo_id)
                return
            time.sleep(0.01)

    threading.Thread(target=run, daemon=True).start()


def unplug_and_replug_once_answered(sim: VirtualLine, servo_id: int, away: float) -> None:
    """As :func:`unplug_once_answered`, then plug the servo back in ``away`` seconds later, powered up (free), once
    the stream has taken it offline (its position commands unanswered ``offline_after`` cycles in a row): under
    load, fewer cycles than that may have run in ``away`` seconds, and a servo back before then has not come back
    to the robot.  (Not once any read to it went unanswered: the safety watch's telemetry reads go unanswered
    the moment it is unplugged, cycles before the stream's third position command.)"""
    offline_after = 3  # (the stream's default: the robot's lines keep it)

    def probed(since: int) -> bool:
        unanswered = [t for t in sim.log_since(since) if t.servo_id == servo_id and t.command == "position"]
        return sum(not t.responders for t in unanswered) >= offline_after

    def run() -> None:
        deadline = time.monotonic() + scaled(30.0)
        while time.monotonic() < deadline:
            if any(t.servo_id == servo_id and t.reply and t.command == "position" for t in sim.log_since(0)):
                time.sleep(0.2)
                servo = sim.remove_servo(servo_id)
                since = sim.log_since(0)[-1].seq
                time.sleep(away)
                while not probed(since) and time.monotonic() < deadline:
                    time.sleep(0.01)
                servo.power_cycle()
                sim.add_device(servo)
                return
            time.sleep(0.01)

    threading.Thread(target=run, daemon=True).start()


TELEMETRY_READS = ("read_current", "read_temperature")


def once_its_telemetry_answered(sim: VirtualLine, servo_id: int, then: Callable[[], object]) -> None:
    """Call ``then`` once ``servo_id`` has answered a current read and a temperature read (the robot's telemetry),
    from a thread of its own."""

    def run() -> None:
        deadline = time.monotonic() + scaled(30.0)
        while time.monotonic() < deadline:
            answered = {t.command for t in sim.log_since(0) if t.servo_id == servo_id and t.reply}
            if {"read_current", "read_temperature"} <= answered:
                then()
                return
            time.sleep(0.01)

    threading.Thread(target=run, daemon=True).start()


def unplug_once_its_telemetry_answered(sim: VirtualLine, servo_id: int) -> None:
    """Unplug ``servo_id`` once it has answered a current read and a temperature read (the robot's telemetry)."""
    once_its_telemetry_answered(sim, servo_id, lambda: sim.remove_servo(servo_id))


def playing_on_past_offline(sims: Any, tmp_path: Path) -> tuple[Path, Path]:
    """The rig's robot file and a 2.5 s motion of neck and hip, for a play that goes on past an offline servo."""
    robot_file = tmp_path / "robot.toml"
    robot_file.write_text(dump_description(load_description(sims.description)))
    motion = write_motion(
        tmp_path / "m.json",
        {"time": 0.3, "pose": {"neck": 10, "hip": -5}},
        {"time": 2.5, "pose": {"neck": 20, "hip": -10}},
    )
    return robot_file, motion


def test_play_shows_no_target_temperature_or_current_for_a_joint_gone_offline(cli: Any, tmp_path: Path) -> None:
    # With continue_on_offline the motion plays on without a servo unplugged mid-motion: its row said "offline"
    # beside the last temperature and current read from it, shown as if they were current, and beside the
    # motion's target for it, never sent to it (the motion's end, where the servo never went).
    sims = make_rig(safety={"continue_on_offline": True})
    try:
        robot_file, motion = playing_on_past_offline(sims, tmp_path)
        unplug_once_its_telemetry_answered(sims.lower, JOINTS["hip"]["id"])
        result = cli("play", str(robot_file), str(motion))
    finally:
        sims.close()
    assert result.code == 0, result.err
    rows = {
        line.split()[0]: line.split() for line in result.out.splitlines() if line.split()[:1] in (["hip"], ["neck"])
    }
    # joint, line:ID, target°, pos°, temp, cur, state
    assert rows["hip"][-1] == "offline" and rows["hip"][-3:-1] == ["-", "-"], result.out
    assert re.fullmatch(r"\d+C", rows["neck"][-3]) and rows["neck"][-2].isdigit(), result.out  # (still read)
    assert rows["hip"][2] == "-" and rows["neck"][2] == "+20.0", result.out  # (the neck's end: sent)


def play_with_the_hips_telemetry_failing(cli: Any, tmp_path: Path, sims: Any) -> tuple[Any, Any]:
    """``ics35 play`` of a motion of neck and hip on ``sims`` (a rig), the hip's temperature and current reads
    unanswered once they have answered (its position commands answered throughout); the result and the rig."""
    try:
        robot_file, motion = playing_on_past_offline(sims, tmp_path)
        hip = sims.lower.servo(JOINTS["hip"]["id"])
        once_its_telemetry_answered(
            sims.lower, JOINTS["hip"]["id"], lambda: setattr(hip, "ignores", frozenset(TELEMETRY_READS))
        )
        return cli("play", str(robot_file), str(motion)), sims
    finally:
        sims.close()


def test_play_shows_no_temperature_or_current_for_a_joint_whose_telemetry_reads_keep_failing(
    cli: Any, tmp_path: Path
) -> None:
    # The hip's servo answered every position command, but its temperature and current reads went unanswered once
    # they had answered: its row went on showing the temperature and current read then, as if read now.
    result, sims = play_with_the_hips_telemetry_failing(cli, tmp_path, make_rig())
    assert result.code == 0, result.err
    hip = sims.lower.servo(JOINTS["hip"]["id"])
    silent = [t for t in sims.lower.log_since(0) if t.command in TELEMETRY_READS and t.servo_id == hip.servo_id]
    assert sum(not t.reply for t in silent) >= 2, silent  # (read, then failing)
    rows = {
        line.split()[0]: line.split() for line in result.out.splitlines() if line.split()[:1] in (["hip"], ["neck"])
    }
    # joint, line:ID, target°, pos°, temp, cur, state
    assert rows["hip"][-3:-1] == ["-", "-"] and rows["hip"][-1] != "offline", result.out
    assert rows["hip"][2] == "-10.0", result.out  # (its motion's end: sent, and it went there)
    assert re.fullmatch(r"\d+C", rows["neck"][-3]) and rows["neck"][-2].isdigit(), result.out  # (still read)


def test_play_says_once_that_a_guarded_joint_whose_telemetry_does_not_read_is_not_guarded(
    cli: Any, tmp_path: Path
) -> None:
    # The robot file sets max_temperature_c; the hip's temperature and current reads went unanswered mid-motion
    # while its servo answered its position commands: its row showed "-", and nothing said the limit guarded it
    # no longer (the library's warning went to a quiet logger).
    result, _ = play_with_the_hips_telemetry_failing(cli, tmp_path, make_rig(safety={"max_temperature_c": 70}))
    assert result.code == 0, result.err
    said = [line for line in result.err.splitlines() if line.startswith("warning:")]
    assert len(said) == 1, result.err  # (once for the stretch, not once a failed read)
    text = " ".join(result.err[result.err.index("warning:") :].split())
    assert "joint hip (line lower, ID" in text and "cannot hold it to max_temperature_c 70" in text, text
    assert "Traceback" not in result.err


@pytest.mark.parametrize("loop", [False, True])
def test_play_on_past_a_servo_that_came_back_ends_with_its_summary(cli: Any, tmp_path: Path, loop: bool) -> None:
    # With continue_on_offline the motion plays on without a servo unplugged mid-motion; plugged back, the motion
    # gives its joint up (it may have restarted, free and elsewhere).  play ended on the motion's MotionStopped,
    # in the library's words (exit code 1, "until a target is set again"), without its summary of the joints.
    sims = make_rig(safety={"continue_on_offline": True})
    try:
        robot_file, motion = playing_on_past_offline(sims, tmp_path)
        unplug_and_replug_once_answered(sims.lower, JOINTS["hip"]["id"], 0.5)
        result = cli("play", str(robot_file), str(motion), *(["--loop", "--seconds", "20"] if loop else []))
    finally:
        sims.close()
    assert result.code == 0, result.err
    assert "Traceback" not in result.err and "error:" not in result.err, result.err
    summary = " ".join(result.out[result.out.index("play ") :].split()[-60:])
    assert "joints left holding (those it opened), but hip: its servo came back after going offline" in summary
    assert "neck" not in summary.split("but", 1)[1], summary
    # Its row said "waiting for a target" beside the last target set before it went offline, sent no more.
    row = next(line.split() for line in result.out.splitlines() if line.split()[:2] == ["hip", "lower:1"])
    assert row[2] == "-" and " ".join(row[-4:]) == "waiting for a target", result.out
    if loop:
        # The loop ends after the pass the servo came back in: the last status line numbered a pass 2 that never
        # began, beside the closing line's "1 pass".
        shown = re.findall(r"motion .* pass (\d+) ", result.out)
        assert shown and shown[-1] == "1" and "1 pass of 2.5 s;" in summary, result.out


UNHEARD = "silent servo may not have heard it (its torque may still be on)"


@pytest.mark.parametrize(
    ("safety", "on_stop", "phrase", "free"),
    [
        (None, "hold", f'action = "free": joint hip was freed, but its {UNHEARD}; the others keep their last', {"hip"}),
        (
            {"action": "stop"},
            "hold",
            f'action = "stop": every joint it opened was freed (torque off: a standing robot falls), but joint hip\'s '
            f"{UNHEARD}; [safety]",
            {"neck", "hip"},
        ),
        (
            {"action": "free"},
            "hold",
            f'action = "free": joint hip was freed, but its {UNHEARD}; the others keep their last',
            {"hip"},
        ),
        ({"action": "hold"}, "hold", 'action = "hold": every joint it opened keeps its last target', set()),
        (
            {"action": "hold"},
            "free",
            f"the command then freed every joint it opened (--on-stop free), but joint hip's {UNHEARD}",
            {"neck", "hip"},
        ),
    ],
)
def test_a_safety_stop_says_what_the_joints_were_left_in(
    cli: Any, tmp_path: Path, safety: dict[str, Any] | None, on_stop: str, phrase: str, free: set[str]
) -> None:
    # A robot file with no [safety] table: one servo's plug works loose mid-motion and every joint goes limp (a
    # standing robot falls), while the message said only "action: stop".
    sims = make_rig(safety=safety)
    try:
        robot_file = tmp_path / "robot.toml"
        robot_file.write_text(dump_description(load_description(sims.description)))
        unplug_once_answered(sims.lower, JOINTS["hip"]["id"])  # (one never heard from is refused, not a trip)
        motion = write_motion(tmp_path / "m.json", {"time": 3.0, "pose": {"neck": 20, "hip": -10}})
        # (--start-pose: the neck holds from the first command, as a standing robot's joints would)
        result = cli("play", str(robot_file), str(motion), "--on-stop", on_stop, "--start-pose", "neck=0")
        assert result.code == 7, result.err
        said = " ".join(result.err.split())
        assert phrase in said, said
        # (each thing said once: the hint named the tripped joint twice, "joint hip was freed, but joint hip's")
        hint = next(part for part in said.split("hint: ") if part.startswith(phrase[:20]))
        assert hint.count("hip") <= 1, said
        assert sims.servo("neck").free == ("neck" in free)
        # Its row: the trip, and no temperature or current (the last ones read are not its own now).
        row = next(line.split() for line in result.out.splitlines() if line.split()[:2] == ["hip", "lower:1"])
        assert row[-2:] == ["STOP:", "offline"] and row[-4:-2] == ["-", "-"], result.out
    finally:
        sims.close()


@pytest.mark.parametrize("command", ["play", "teach", "calibrate"])
def test_each_robot_commands_help_says_the_joints_it_leaves_unopened_are_not_watched_by_the_safety(
    cli: Any, command: str
) -> None:
    # Only the docs said it: a person choosing --joints at the terminal could take the file's [safety] to watch
    # the whole robot, the legs left holding under a taught arm included.
    shown = " ".join(cli(command, "--help").out.split())
    joints = shown[shown.index("--joints") :]
    assert "not opened" in joints and "watched by the file's [safety]" in joints, shown


def test_teach_does_not_capture_a_pose_past_the_longest_motion_so_the_poses_so_far_are_kept(
    rig: tuple[Rig, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    # A keyframe later than an hour is refused as a Motion is built: a pose captured past it made the write of
    # every pose taught so far fail at the end.
    sims, _ = rig

    def an_hour_of_posing_later(times: TaughtTimes) -> None:
        assert times.first is not None
        times.first -= LONGEST_MOTION

    keyframes = captures(sims, ["neck"], an_hour_of_posing_later)
    assert len(keyframes) == 1 and Motion(tuple(keyframes)).duration == 1.0
    assert "pose not captured" in capsys.readouterr().err


def test_play_a_motion_that_moves_no_joint_is_a_usage_error(cli: Any, rig: tuple[Rig, Path], tmp_path: Path) -> None:
    # A robot builder's finding: a motion whose every pose is empty (taught with every joint's servo silent) made
    # `ics35 play` end in a traceback ("name at least one joint"), with nothing said of the file.
    sims, robot_file = rig
    marks = {"upper": sims.upper.transactions, "lower": sims.lower.transactions}
    motion = write_motion(tmp_path / "empty.json", {"time": 0.5, "pose": {}}, {"time": 1.0, "pose": {}})
    for extra in ([], ["--start-pose", "neck=0"]):
        result = cli("play", str(robot_file), str(motion), *extra)
        assert result.code == ExitCode.USAGE, result.err
        said = " ".join(result.err.split())
        assert "Traceback" not in said
        assert f"{motion}: the motion moves no joint (every keyframe's pose is empty): nothing to play" in said, said
    assert (sims.upper.transactions, sims.lower.transactions) == (marks["upper"], marks["lower"])  # nothing sent


def test_teach_does_not_capture_a_pose_no_joint_answers_in(
    rig: tuple[Rig, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # A robot builder's finding: teach of one leg's joints, the leg's servos unplugged after the first pose: each
    # Enter then captured an empty pose, and a motion of empty poses (one taught with the servos silent from the
    # start) was written, which plays nothing.  A pose with no joint in it is not captured, and teach says why.
    monkeypatch.delenv("ICS35_PORT", raising=False)
    sims, robot_file = rig
    out_file = tmp_path / "taught.json"

    def unplug_the_lower_line() -> None:
        unplug_the_legs(sims)
        # (a line where nothing answers is only probed now and then: its transactions do not tell the time)
        time.sleep(scaled(1.0))

    result = run_with_hands(
        ["teach", str(robot_file), str(out_file), "--joints", "hip,knee"],
        [("Enter captures", None, "\n"), ("pose 1 at", unplug_the_lower_line, "\n"), (None, None, "q\n")],
        [],
    )
    assert result.code == 0, result.err
    assert len(json.loads(out_file.read_text())["keyframes"]) == 1
    said = " ".join(result.err.split())
    assert "pose not captured: none of its joints answers (hip, knee): nothing to capture" in said, said


def test_play_refuses_a_speed_that_puts_a_keyframe_past_an_hour_before_the_robot_opens(
    cli: Any, rig: tuple[Rig, Path], tmp_path: Path
) -> None:
    # A robot builder's finding: `--speed 0.05` on a motion with a keyframe at 200 s (4000 s at that speed) was
    # refused only once the robot had opened, its joints freed to be read, and the error said "nothing was sent".
    sims, robot_file = rig
    sims.servo("neck").command_position(8000)  # holding, as a move left it
    marks = {"upper": sims.upper.transactions, "lower": sims.lower.transactions}
    motion = write_motion(tmp_path / "m.json", {"time": 1, "pose": {"neck": 10}}, {"time": 200, "pose": {"neck": 0}})
    result = cli("play", str(robot_file), str(motion), "--speed", "0.05")
    assert result.code == ExitCode.USAGE, result.err
    said = " ".join(result.err.split())
    assert "at speed 0.05, keyframes[1].time: 4000 must be at most 3600 seconds" in said, said
    assert (sims.upper.transactions, sims.lower.transactions) == (marks["upper"], marks["lower"])  # nothing sent
    assert not sims.servo("neck").free


@pytest.mark.parametrize("on_stop", ["hold", "free"])
def test_play_with_a_line_lost_as_the_robot_opens_says_what_the_open_left(
    cli: Any, rig: tuple[Rig, Path], tmp_path: Path, on_stop: str
) -> None:
    # A robot builder's finding: the legs' adapter pulled while `ics35 play` opened the robot said the other
    # lines' joints "were left holding their last targets (the motion stopped there at once ...)": no motion had
    # started and no joint had a target; the open had freed them to read them, as a Ctrl-C then says.
    sims, robot_file = rig
    lost = VirtualLine([1, 2], name=f"{sims.lower.name}-lost", faults="unplug:1", replug_after=60, log_size=None)
    try:
        sims.description["lines"]["lower"]["port"] = f"sim://{lost.name}"
        robot_file.write_text(dump_description(load_description(sims.description)))
        motion = write_motion(tmp_path / "m.json", {"time": 0.5, "pose": {"neck": 20, "hip": 5}})
        result = cli("play", str(robot_file), str(motion), "--on-stop", on_stop)
    finally:
        lost.close()
    assert result.code == ExitCode.COMMUNICATION, result.err
    said = " ".join(result.err.split())
    assert "lost" in said and "the motion stopped there" not in said and "last targets" not in said, said
    assert "the port was lost as the robot opened: " in said, said


def test_calibrates_table_into_a_log_is_printed_whole(cli_process: Any, tmp_path: Path) -> None:
    # `ics35 calibrate robot.toml | tee log` (or CI): the table printed at the end was fitted to 80 columns, as on a
    # terminal of 80, the joints' line:ID left out.  A log is read later, in a wider window or a file: every
    # column is in it, as monitor's.
    robot = tmp_path / "humanoid.toml"
    robot.write_text((EXAMPLES / "humanoid.toml").read_text())
    proc = cli_process("calibrate", str(robot), stdin="\n\n", columns=80)
    assert "columns left out" not in proc.stdout, proc.stdout
    lines = proc.stdout.splitlines()
    header = next(line for line in lines if line.split()[:1] == ["joint"])
    assert header.split() == ["joint", "line:ID", "target°", "pos°", "temp", "cur", "state", "offset°", "min°", "max°"]
    joints = load_description(robot).joints
    rows = {cells[0]: cells for cells in map(str.split, lines) if cells[:1] and cells[0] in joints}
    assert len(rows) == 17 and all(len(cells) == 10 for cells in rows.values()), proc.stdout
    assert rows["left_ankle_roll"][1] == "legs:10", proc.stdout
