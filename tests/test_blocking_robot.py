"""The blocking robot against simulated lines: opening, poses read back, typed errors before the wire, closing.

Positions are checked against the simulator's servos and its transaction log, never the robot's bookkeeping.
"""

from __future__ import annotations

import _thread
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from ics35_async import BusClosed, InvalidArgument, SafetyStop, blocking
from ics35_async.eeprom import Eeprom
from ics35_async.robot import DescriptionError, RobotWarning, Segment, Trajectory
from tests.support.robot_rig import (
    ALL_ICS36,
    JOINTS,
    ics36_humanoid,
    joint_degrees,
    joint_position,
    make_rig,
    sent_position,
    targets_sent,
)
from tests.support.timing import FAST, GUARD, NO_TIMEOUTS

HUMANOID = Path(__file__).resolve().parent.parent / "examples" / "humanoid.toml"


def test_a_script_that_never_closes_its_robot_still_exits_cleanly() -> None:
    # Closed at interpreter exit: its loop thread ends there, where Python 3.12 starts no new thread (asyncio's
    # own ending joins the loop's executor from one, and printed that refusal as a traceback).
    script = (
        f"from ics35_async import blocking\nrobot = blocking.open_robot({str(HUMANOID)!r})\nprint(len(robot.joints))"
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().isdigit()
    assert "Traceback" not in done.stderr, done.stderr


def settled_pose(robot: blocking.BlockingRobot, goal: dict[str, float]) -> dict[str, float]:
    """The pose once the simulated servos have reached ``goal`` (they move at a servo's speed; GUARD: hangs only)."""
    deadline = time.monotonic() + GUARD
    while True:
        pose = robot.read_pose()
        if all(abs(pose[n] - d) <= 0.1 for n, d in goal.items()) or time.monotonic() > deadline:
            return pose


def test_humanoid_file_opens_moves_and_reads_back(tmp_path: Path) -> None:
    before = set(threading.enumerate())
    with blocking.open_robot(ics36_humanoid(tmp_path), **NO_TIMEOUTS) as robot:
        assert robot.thread in threading.enumerate()
        pose = robot.read_pose()
        assert set(pose) == set(robot.joints)
        robot.move_to({"head_yaw": 20.0}, duration=0.1)
        assert settled_pose(robot, {"head_yaw": 20.0})["head_yaw"] == pytest.approx(20.0, abs=0.1)
        assert robot.targets["head_yaw"] == 20.0
    assert not robot.is_open
    assert set(threading.enumerate()) <= before


def test_move_free_hold_and_bad_poses_against_the_simulator() -> None:
    rig = make_rig()
    before = set(threading.enumerate())
    try:
        with blocking.open_robot(rig.description, **FAST) as robot:
            robot.move_to({"neck": 15.0, "knee": -10.0}, duration=0.05)
            pose = settled_pose(robot, {"neck": 15.0, "knee": -10.0})
            assert pose["neck"] == pytest.approx(15.0, abs=0.1)
            assert pose["knee"] == pytest.approx(-10.0, abs=0.1)
            assert rig.servo("neck").target == joint_position(JOINTS["neck"], 15.0)

            since = {"upper": rig.upper.transactions, "lower": rig.lower.transactions}
            with pytest.raises(InvalidArgument, match=r"joint hip: 31 degrees is outside its limits"):
                robot.move_to({"neck": 10.0, "hip": 31.0}, duration=0.1)
            with pytest.raises(InvalidArgument, match="outside its limits"):
                robot.set_targets({"elbow": -5.0})
            with pytest.raises(InvalidArgument, match="unknown joint"):
                robot.hold(["tail"])
            robot.read_pose()
            robot.read_pose()
            for name, spec in JOINTS.items():
                sent = targets_sent(rig.sim(spec["line"]), spec["id"], since[spec["line"]])
                # Only the held targets from before went out: nothing new from the refused calls.
                target = robot.targets[name]
                assert set(sent) <= (set() if target is None else {joint_position(spec, target)}), name

            robot.free(["neck"])
            assert rig.servo("neck").free and not rig.servo("knee").free
            assert robot.targets["neck"] is None
            robot.hold(["neck"])
            robot.on_wire(["neck"])
            assert not rig.servo("neck").free
            robot.set_targets({"hip": -12.0})
            robot.on_wire(["hip"])
            assert rig.servo("hip").target == joint_position(JOINTS["hip"], -12.0)
            assert robot.tripped == {} and robot.warnings == []
            assert set(robot.telemetry) == set(JOINTS)
            robot.stop()
        with pytest.raises(Exception, match="closed"):
            robot.read_pose()
        robot.close()  # idempotent
    finally:
        rig.close()
    assert set(threading.enumerate()) <= before


def test_a_loop_setting_targets_each_pass_ends_at_an_over_current_trip_until_reset() -> None:
    # The docs' own control loop at 200 Hz with max_current: the watch freed the overloaded knee, read it free
    # (no current: "within limits") and cleared the trip, so most passes went on and powered the knee again.
    rig = make_rig(safety={"max_current": 20, "action": "free"})
    knee = rig.servo("knee")
    try:
        with blocking.open_robot(rig.description, **FAST) as robot:
            robot.move_to({"knee": -10.0}, duration=0.05)
            knee.load = 40
            deadline = time.monotonic() + GUARD
            with pytest.raises(SafetyStop, match="joint knee"):
                while time.monotonic() < deadline:
                    robot.set_targets({"knee": -10.0, "hip": 0.0})
                    time.sleep(0.005)
            robot.on_wire()
            since = rig.lower.transactions
            for _ in range(20):  # the loop's later passes: each refused, none re-powers the knee
                with pytest.raises(SafetyStop, match="joint knee"):
                    robot.set_targets({"knee": -10.0, "hip": 0.0})
                time.sleep(0.005)
            robot.on_wire()
            assert knee.free and targets_sent(rig.lower, 2, since) == []
            knee.load = 0
            robot.reset_trip("knee")
            robot.set_targets({"knee": -10.0})
            robot.on_wire(["knee"])
            assert not knee.free and robot.tripped == {}
    finally:
        rig.close()


def test_run_says_plainly_what_it_takes_and_the_robot_carries_on() -> None:
    # robot.run(fn(...)) or a plain function: said as run()'s misuse, not as "'coroutine' object is not
    # callable" or a TypeError from inside the robot's loop; the robot is still open after it.
    rig = make_rig()
    try:
        with blocking.open_robot(rig.description, **FAST) as robot:
            coroutine = robot.async_robot.read_pose()
            with pytest.raises(InvalidArgument, match=r"robot\.run\(fn, \*args\), not robot\.run\(fn\(\*args\)\)"):
                robot.run(coroutine)  # type: ignore[call-overload]

            def plain() -> None:
                pass

            with pytest.raises(
                InvalidArgument, match=r"async function \(async def plain\(\)\): plain\(\) returned None"
            ):
                robot.run(plain)  # type: ignore[call-overload]
            assert set(robot.run(robot.async_robot.read_pose)) == set(JOINTS)
    finally:
        rig.close()


def test_run_plays_a_trajectory_as_the_async_robots_run_does() -> None:
    # A robot builder's finding: `robot.run(Trajectory([...]))`, as the async robot plays one, was refused on the
    # blocking robot ("robot.run() takes an async function, not Trajectory"), which had no other way to play it.
    rig = make_rig()
    try:
        with blocking.open_robot(rig.description, start_pose={"neck": 0.0}, **FAST) as robot:
            since = rig.upper.transactions
            trajectory = Trajectory(
                [
                    Segment(0.0, 0.1, {"neck": 0.0}, {"neck": 20.0}, "linear"),
                    Segment(0.1, 0.2, {"neck": 20.0}, {"neck": 10.0}),
                ]
            )
            assert robot.run(trajectory) == {"neck"}
            sent = targets_sent(rig.upper, JOINTS["neck"]["id"], since)
            assert sent[-1] == joint_position(JOINTS["neck"], 10.0)
            assert max(sent) == joint_position(JOINTS["neck"], 20.0)
            with pytest.raises(InvalidArgument, match="outside its limits"):
                robot.run(Trajectory([Segment(0.0, 0.1, {"neck": 10.0}, {"neck": 90.0})]))
    finally:
        rig.close()


def test_positions_and_untouched_read_as_the_async_robots_do() -> None:
    # The readings hold(), read_pose() and calibrate go by, and the ICS 3.6 joints whose torque is as found:
    # both snapshots the async robot has, which the robot pages name without saying which robot.
    rig = make_rig(ics36=(1,))  # neck and hip (ID 1 of each line) speak ICS 3.6: read at the open, not freed
    try:
        with blocking.open_robot(rig.description, **FAST) as robot:
            assert robot.untouched == {"neck", "hip"}
            positions = robot.positions
            assert set(positions) == set(JOINTS)
            for name, spec in JOINTS.items():
                assert positions[name] == pytest.approx(joint_degrees(spec, rig.servo(name).position), abs=0.1)
            robot.move_to({"neck": 15.0}, duration=0.05)
            assert robot.untouched == {"hip"}
            settled_pose(robot, {"neck": 15.0})
            positions["neck"] = 99.0  # a snapshot: the robot's own readings are not the caller's to change
            assert robot.positions["neck"] == pytest.approx(15.0, abs=0.1)
    finally:
        rig.close()


def test_unreached_names_the_joints_whose_servo_is_offline_as_the_async_robot_does() -> None:
    # The joints a view shows no target or readings for (their servo offline: sent nothing), as `ics35 play`'s live
    # table and the configurator's Robot page show them: a snapshot of the async robot's, for a program's own view.
    rig = make_rig({"continue_on_offline": True})
    try:
        with blocking.open_robot(rig.description, start_pose={"hip": 5.0}, **FAST) as robot:
            assert robot.unreached == frozenset()
            rig.lower.remove_servo(JOINTS["hip"]["id"])
            end = time.monotonic() + GUARD
            while robot.unreached != {"hip"}:
                assert time.monotonic() < end, robot.unreached
                time.sleep(0.01)
            assert robot.unreached == robot.async_robot.unreached
            assert robot.targets["hip"] == 5.0  # (what it was asked stays: its target is not sent, not gone)
    finally:
        rig.close()


def test_uncommanded_names_the_joints_only_read_and_those_offline_as_the_async_robot_does() -> None:
    # The joints no target of the program's reaches, which a view shows "-" for (not "free": nothing freed them):
    # the ICS 3.6 ones only read since the open (torque as found) and those whose servo is offline (sent nothing).
    rig = make_rig({"continue_on_offline": True}, ics36=(1,))  # neck and hip (ID 1 of each line): read, not freed
    try:
        with blocking.open_robot(rig.description, **FAST) as robot:
            assert robot.uncommanded == {"neck", "hip"}
            robot.move_to({"neck": 15.0}, duration=0.05)
            assert robot.uncommanded == {"hip"}
            rig.upper.remove_servo(JOINTS["neck"]["id"])
            end = time.monotonic() + GUARD
            while robot.uncommanded != {"neck", "hip"}:
                assert time.monotonic() < end, robot.uncommanded
                time.sleep(0.01)
            assert robot.uncommanded == robot.async_robot.uncommanded
            assert robot.targets["neck"] == 15.0  # (asked, not sent: its target stays)
    finally:
        rig.close()


def test_on_close_free_frees_every_joint() -> None:
    rig = make_rig()
    try:
        with blocking.open_robot(rig.description, on_close="free", **FAST) as robot:
            robot.move_to({"hip": 5.0}, duration=0.05)
            assert not rig.servo("hip").free
        assert all(rig.servo(name).free for name in JOINTS)
    finally:
        rig.close()


def test_a_pose_set_just_before_the_block_ends_reaches_the_servos() -> None:
    # set_targets() then the block's end: the last pose (a robot sitting down) was dropped.
    rig = make_rig(realtime=True, ics36=ALL_ICS36)
    try:
        with blocking.open_robot(rig.description, **NO_TIMEOUTS) as robot:
            robot.move_to({"hip": 5.0, "neck": 0.0}, duration=0.05)
            robot.set_targets({"hip": -20.0, "neck": 30.0})
        for name, degrees in (("hip", -20.0), ("neck", 30.0)):
            assert rig.servo(name).target == sent_position(JOINTS[name], degrees), name
    finally:
        rig.close()


def test_a_limits_warning_points_at_the_programs_line_and_is_issued_once() -> None:
    rig = make_rig()
    narrowed = rig.servo("elbow").eeprom.replace(pulse_limit_low=6000, pulse_limit_high=9000)
    assert isinstance(narrowed, Eeprom)
    rig.servo("elbow").eeprom = narrowed
    try:
        with (
            pytest.warns(RobotWarning, match=r"joints\.elbow: the file allows") as caught,
            blocking.open_robot(rig.description, **FAST) as robot,
        ):
            assert len(robot.warnings) == 1
    finally:
        rig.close()
    assert len(caught) == 1
    assert Path(caught[0].filename).name == Path(__file__).name, caught[0].filename


def test_opening_errors_are_typed_and_leave_no_thread() -> None:
    before = set(threading.enumerate())
    with pytest.raises(DescriptionError):
        blocking.open_robot({"lines": {}, "joints": {"x": {"line": "nowhere", "id": 1}}})
    with pytest.raises(InvalidArgument, match="on_close"):
        blocking.open_robot(HUMANOID, on_close="explode")
    assert set(threading.enumerate()) <= before


def test_a_misspelt_robot_option_is_named_as_open_robots_not_open_bus() -> None:
    """``onclose="free"`` was refused as an "unknown open_bus option", sending the reader to a call the
    program never made: the refusal names open_robot and the robot's own options."""
    before = set(threading.enumerate())
    with pytest.raises(InvalidArgument, match=r"unknown open_robot option\(s\): onclose \(.*on_close.*start_pose"):
        blocking.open_robot(HUMANOID, onclose="free")  # type: ignore[call-arg]
    assert set(threading.enumerate()) <= before


def test_ctrl_c_during_a_motion_cancels_it_and_closes_the_robot() -> None:
    rig = make_rig()
    before = set(threading.enumerate())
    neck = rig.servo("neck")
    start_target = neck.target

    def interrupt_once_moving() -> None:
        deadline = time.monotonic() + GUARD  # only against a hang
        while neck.target == start_target and time.monotonic() < deadline:
            time.sleep(0.005)
        _thread.interrupt_main()

    try:
        with pytest.raises(KeyboardInterrupt), blocking.open_robot(rig.description, on_close="free", **FAST) as robot:
            threading.Thread(target=interrupt_once_moving).start()
            robot.move_to({"neck": 50.0}, duration=60.0)
        assert not robot.is_open
        assert all(rig.servo(name).free for name in JOINTS)  # on_close="free" ran
        # Its calls then say what closed it (the program never touched a bus); its snapshots still read.
        with pytest.raises(BusClosed, match=r"the robot is closed: a Ctrl-C during a call closed it"):
            robot.hold()
        assert set(robot.targets) == set(JOINTS)
    finally:
        rig.close()
    time.sleep(0)  # the helper thread has ended once interrupt_main returned
    assert {t for t in set(threading.enumerate()) - before if t.name.startswith("ics35")} == set()


def test_lost_lines_and_line_change_say_a_lost_line_as_the_async_robots_do() -> None:
    # A program without an event loop had no way to hear of a line lost and back (reconnect=True) but polling
    # the frames: the blocking robot lacked lost, lost_lines and line_change().
    rig = make_rig()
    for line in rig.description["lines"].values():
        line["rate_hz"] = 200  # (paced: an unpaced line's stream still gives a frame as its port goes)
    lower = frozenset(name for name, spec in JOINTS.items() if spec["line"] == "lower")
    try:
        with blocking.open_robot(rig.description, reconnect=True, **FAST) as robot:
            robot.set_targets({"hip": 5.0})
            robot.on_wire()
            assert robot.lost == frozenset() and robot.lost_lines == frozenset()
            started = time.monotonic()
            with pytest.raises(TimeoutError, match=r"no line lost or back within 0\.1 s"):
                robot.line_change((), timeout=0.1)  # (no line lost: it waits, then gives up)
            assert time.monotonic() - started >= 0.1
            rig.lower.unplug()
            lost = robot.line_change((), timeout=GUARD)
            assert lost == frozenset({"lower"}) and robot.lost_lines == lost and robot.lost == lower
            rig.lower.replug()
            assert robot.line_change(lost, timeout=GUARD) == frozenset()
            assert robot.lost == frozenset() and robot.held == {"hip": "resumed"}
            with pytest.raises(InvalidArgument, match="no line 'middle'"):
                robot.line_change(["middle"])
            with pytest.raises(InvalidArgument, match="timeout"):
                robot.line_change((), timeout=-1.0)
            assert robot.is_open  # (a wait that timed out, or a refused one, leaves the robot as it was)
        assert robot.lost_lines == frozenset()  # (a snapshot: read after the block too)
        with pytest.raises(BusClosed):
            robot.line_change(())
    finally:
        rig.close()
