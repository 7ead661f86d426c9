"""ics35 play's ways to stop (Ctrl-C, --seconds during --loop) never carry a joint past the motion's poses.

In this process, on named simulated lines; every command is read back from the simulator's log.
"""

from __future__ import annotations

import json
import os
import signal
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from ics35_async import units
from ics35_async.robot import load_description
from ics35_async.robot.calibration import dump_description
from tests.support.robot_rig import (
    JOINTS,
    Rig,
    commanded,
    joint_degrees,
    make_rig,
    sent_position,
    targets_sent,
)

HALF_COUNT = 0.5 / units.COUNTS_PER_DEGREE + 1e-9


@pytest.fixture
def rig(tmp_path: Path) -> Iterator[tuple[Rig, Path]]:
    made = make_rig()
    path = tmp_path / "robot.toml"
    path.write_text(dump_description(load_description(made.description)))
    yield made, path
    made.close()


def write_motion(path: Path, *keyframes: dict[str, Any]) -> Path:
    path.write_text(json.dumps({"format": "ics35-motion", "version": 1, "keyframes": list(keyframes)}))
    return path


def neutral(name: str) -> float:
    """Where a joint starts: its servo powers up free at neutral (7500)."""
    return joint_degrees(JOINTS[name], units.NEUTRAL)


def sent(rig: Rig, name: str) -> list[float]:
    spec = JOINTS[name]
    return [joint_degrees(spec, p) for p in targets_sent(rig.sim(spec["line"]), spec["id"])]


def inside(values: list[float], *ends: float) -> bool:
    return all(min(ends) - HALF_COUNT <= v <= max(ends) + HALF_COUNT for v in values)


@pytest.mark.parametrize("seconds", ["0.15", "0.3", "0.42", "0.55"])
def test_loop_stopped_by_the_clock_stays_between_the_keyframes(
    cli: Any, rig: tuple[Rig, Path], tmp_path: Path, seconds: str
) -> None:
    """--loop --seconds: the smooth stop at any point of a fast back-and-forth stays within its poses."""
    sims, robot_file = rig
    motion = write_motion(
        tmp_path / "m.json",
        {"time": 0.1, "pose": {"neck": 30, "hip": -20}},
        {"time": 0.25, "pose": {"neck": -30, "hip": 20}},
    )
    result = cli("play", str(robot_file), str(motion), "--loop", "--seconds", seconds, "--ramp", "0.3")
    assert result.code == 0, result.err
    assert "time is up" in result.err
    neck, hip = sent(sims, "neck"), sent(sims, "hip")
    assert neck and hip
    assert inside(neck, neutral("neck"), 30, -30), (min(neck), max(neck))
    assert inside(hip, neutral("hip"), -20, 20), (min(hip), max(hip))


@pytest.mark.skipif(os.name != "posix", reason="SIGINT to this process")
def test_ctrl_c_mid_motion_slows_down_short_of_the_keyframe(cli: Any, rig: tuple[Rig, Path], tmp_path: Path) -> None:
    """Ctrl-C while the joint moves fast toward its keyframe: it decelerates and rests at the keyframe at most."""
    sims, robot_file = rig
    motion = write_motion(tmp_path / "m.json", {"time": 0.5, "pose": {"neck": 55, "knee": -90}})
    done = threading.Event()

    def press_ctrl_c() -> None:
        # Once the motion has begun (the neck, free until then, gets a target), 0.25 s into it.
        while sims.servo("neck").target is None:
            if done.wait(0.005):
                return
        if not done.wait(0.25):
            os.kill(os.getpid(), signal.SIGINT)

    presser = threading.Thread(target=press_ctrl_c)
    presser.start()
    try:
        result = cli("play", str(robot_file), str(motion), "--loop", "--ramp", "0.3")
    finally:
        done.set()
        presser.join()
    assert result.code == 0, result.err
    assert "stopped by Ctrl-C: slowing to rest, then the joints hold" in result.err
    neck, knee = sent(sims, "neck"), sent(sims, "knee")
    assert inside(neck, neutral("neck"), 55), max(neck)
    assert inside(knee, neutral("knee"), -90), min(knee)


def test_start_pose_keeps_ics35_joints_holding_from_the_first_command(
    cli: Any, rig: tuple[Rig, Path], tmp_path: Path
) -> None:
    sims, robot_file = rig
    motion = write_motion(tmp_path / "m.json", {"time": 0.1, "pose": {"neck": 20}})
    pose = tmp_path / "pose.json"
    pose.write_text("\ufeff" + json.dumps({"hip": 10, "knee": -20}), encoding="utf-8")  # a BOM, as Notepad may write
    for given in ("shoulder=30,elbow=40", str(pose)):
        since = {"upper": sims.upper.transactions, "lower": sims.lower.transactions}
        result = cli("play", str(robot_file), str(motion), "--start-pose", given)
        assert result.code == 0, result.err
        stated = {"shoulder": 30.0, "elbow": 40.0} if "=" in given else {"hip": 10.0, "knee": -20.0}
        for name, deg in stated.items():
            spec = JOINTS[name]
            sent = [t for t in sims.sim(spec["line"]).log_since(since[spec["line"]]) if t.servo_id == spec["id"]]
            torque = [t for t in sent if t.command in ("position", "free")]
            assert torque and all(t.command == "position" for t in torque), name  # never freed
            first = (torque[0].tx[1] << 7) | torque[0].tx[2]
            assert first == sent_position(spec, deg), name  # holding the stated angle from the first command
        assert "started free" in result.err  # the others did, and it says so


@pytest.mark.parametrize(
    ("given", "phrase"),
    [
        # The option is named as typed: "start_pose" is the library's word for it.
        ("tail=3", "--start-pose: unknown joint(s): tail"),
        ("neck=99", "--start-pose: joint neck: 99 degrees is outside its limits"),
        ("neck=x", "joint=degrees"),
        ("/nonexistent.json", "nor a readable JSON file"),
        ("neck=10,neck=20", "neck given twice"),
        ("", "empty"),
    ],
)
def test_a_bad_start_pose_is_a_usage_error_before_anything_is_sent(
    cli: Any, rig: tuple[Rig, Path], tmp_path: Path, given: str, phrase: str
) -> None:
    sims, robot_file = rig
    motion = write_motion(tmp_path / "m.json", {"time": 0.1, "pose": {"neck": 20}})
    result = cli("play", str(robot_file), str(motion), "--start-pose", given)
    assert result.code == 2, result.err
    assert phrase in result.err
    assert sims.upper.transactions == sims.lower.transactions == 0


def test_a_motion_given_as_the_start_pose_is_named_so(cli: Any, rig: tuple[Rig, Path], tmp_path: Path) -> None:
    # The motion file given twice (or for the pose): it was "must hold a JSON object {joint: degrees}" without
    # saying which option, of a file that is one.
    sims, robot_file = rig
    motion = write_motion(tmp_path / "m.json", {"time": 0.1, "pose": {"neck": 20}})
    result = cli("play", str(robot_file), str(motion), "--start-pose", str(motion))
    said = " ".join(result.err.split())
    assert result.code == 2, result.err
    assert "--start-pose" in said and f"{motion}: is a motion" in said and "{joint: degrees}" in said, said
    assert sims.upper.transactions == sims.lower.transactions == 0


def test_play_on_an_ics36_robot_frees_nothing(cli: Any, tmp_path: Path) -> None:
    sims = make_rig(ics36=[1, 2, 3])
    robot_file = tmp_path / "robot.toml"
    robot_file.write_text(dump_description(load_description(sims.description)))
    try:
        motion = write_motion(tmp_path / "m.json", {"time": 0.1, "pose": {"neck": 20}})
        result = cli("play", str(robot_file), str(motion))
        assert result.code == 0, result.err
        assert "started free" not in result.err
        for name in JOINTS:
            spec = JOINTS[name]
            assert 0 not in commanded(sims.sim(spec["line"]), spec["id"]), name  # no free command
    finally:
        sims.close()


@pytest.mark.skipif(os.name != "posix", reason="SIGINT to this process")
@pytest.mark.parametrize("on_stop", ["hold", "free"])
def test_ctrl_c_twice_cuts_the_slow_down_short_and_says_what_the_joints_were_left_in(
    cli: Any, rig: tuple[Rig, Path], tmp_path: Path, on_stop: str
) -> None:
    """A second Ctrl-C during a long --ramp ends the command at once (the CLI's second Ctrl-C forces): the
    joints stay within the motion's poses, hold where the slow-down had them or go free as asked, and the
    error says which (it said only "interrupted")."""
    sims, robot_file = rig
    # (far from its keyframe: a slow-down never passes it, so one close to it ends before the second press)
    motion = write_motion(tmp_path / "m.json", {"time": 4.0, "pose": {"neck": 55, "knee": -90}, "profile": "linear"})
    done = threading.Event()

    def press_ctrl_c_twice() -> None:
        while sims.servo("neck").target is None:
            if done.wait(0.005):
                return
        if not done.wait(0.5):
            os.kill(os.getpid(), signal.SIGINT)
        if not done.wait(0.3):  # slowing to rest over 3 s: well inside it
            os.kill(os.getpid(), signal.SIGINT)

    presser = threading.Thread(target=press_ctrl_c_twice)
    presser.start()
    try:
        result = cli("play", str(robot_file), str(motion), "--ramp", "3", "--on-stop", on_stop)
    finally:
        done.set()
        presser.join()
    assert result.code == 130, result.err
    said = " ".join(result.err.split())
    assert "Ctrl-C again cut the slow-down short" in said, said
    neck, knee = sent(sims, "neck"), sent(sims, "knee")
    assert inside(neck, neutral("neck"), 55), max(neck)
    assert inside(knee, neutral("knee"), -90), min(knee)
    if on_stop == "free":
        assert "the joints it opened were freed" in said, said
        assert sims.servo("neck").free and sims.servo("knee").free
    else:
        assert "the joints it opened hold their last targets, where the slow-down had them" in said, said
        for name in ("neck", "knee"):
            spec = JOINTS[name]
            assert not sims.servo(name).free
            assert sims.servo(name).target == targets_sent(sims.sim(spec["line"]), spec["id"])[-1], name
