"""Robot motions against two simulated lines: limits, exact ends, monotonic segments, the joint mapping.

Every check reads the position commands back from the simulator's log.
"""

from __future__ import annotations

import itertools
import json
import math
import sys
import warnings
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

import anyio
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from rich.console import Console

from ics35_async import BusClosed, InvalidArgument, PortLost, Robot, State, UnsafeOperation, open_robot, units
from ics35_async.cli._robot_view import joint_table
from ics35_async.eeprom import Eeprom, Flags
from ics35_async.robot import (
    Keyframe,
    Motion,
    MotionStopped,
    RobotFrame,
    RobotWarning,
    Segment,
    Trajectory,
    UnsettledReadings,
)
from ics35_async.robot.profiles import LONGEST_MOTION, check_duration
from ics35_async.robot.robot import LIMIT_SLACK
from ics35_async.sim import FaultConfig, FaultInjector, VirtualLine, VirtualServo
from tests.support.robot_rig import (
    ALL_ICS36,
    JOINTS,
    Rig,
    commanded,
    joint_degrees,
    joint_position,
    make_rig,
    sent_position,
    targets_sent,
)
from tests.support.timing import FAST, GUARD, NO_TIMEOUTS, scaled

HALF_COUNT = 0.5 / units.COUNTS_PER_DEGREE  # degrees: the rounding to whole counts


def run_robot(rig: Rig, body: Callable[[Robot], Awaitable[Any]], **options: Any) -> Any:
    async def main() -> Any:
        # (Twice the guard: the open alone reads each joint taken for ICS 3.5 once more at the whole allowance,
        # two seconds each at NO_TIMEOUTS, before the body's moves.)
        with anyio.fail_after(2 * GUARD):
            async with open_robot(rig.description, **{**FAST, **options}) as robot:
                return await body(robot)

    try:
        return anyio.run(main)
    finally:
        rig.close()


def seq_now(rig: Rig) -> dict[str, int]:
    return {"upper": rig.upper.transactions, "lower": rig.lower.transactions}


async def settled_pose(robot: Robot, expected: dict[str, float]) -> dict[str, float]:
    """The pose once the named joints are there: move_to returns once its end is on the wire, and a
    simulated servo a busy machine left behind the motion still has to get there at its own speed.
    A few reads until it has, or 2 s; the caller's checks then fail on what was read last."""
    for _ in range(100):
        pose = await robot.read_pose()
        if all(pose[name] == pytest.approx(deg, abs=0.1) for name, deg in expected.items()):
            break
        await anyio.sleep(0.02)
    return pose


def check_segment(rig: Rig, since: dict[str, int], start: dict[str, float], goal: dict[str, float]) -> None:
    """Every command within limits, monotonic from start toward goal, the last one exactly the goal."""
    for name, spec in JOINTS.items():
        sent = targets_sent(rig.sim(spec["line"]), spec["id"], since[spec["line"]])
        low = sent_position(spec, spec["min"])
        high = sent_position(spec, spec["max"])
        assert all(min(low, high) <= p <= max(low, high) for p in sent), (name, sent)
        if name not in goal:
            continue
        assert sent, name
        assert sent[-1] == sent_position(spec, goal[name]), name
        ahead = sent_position(spec, goal[name]) >= sent_position(spec, start[name])
        steps = list(itertools.pairwise(sent))
        assert all((b >= a) if ahead else (b <= a) for a, b in steps), (name, sent)


pose_strategy = st.fixed_dictionaries(
    {},
    optional={name: st.floats(spec["min"], spec["max"], allow_nan=False) for name, spec in JOINTS.items()},
)


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    first=pose_strategy,
    second=pose_strategy,
    durations=st.tuples(st.floats(0.0, 0.25, exclude_min=True), st.floats(0.0, 0.25, exclude_min=True)),
    profiles=st.tuples(st.sampled_from(["minjerk", "linear"]), st.sampled_from(["minjerk", "linear"])),
)
def test_move_to_stays_within_limits_ends_exactly_and_moves_monotonically(
    first: dict[str, float], second: dict[str, float], durations: tuple[float, float], profiles: tuple[str, str]
) -> None:
    rig = make_rig()

    async def body(robot: Robot) -> None:
        for pose, duration, profile in zip((first, second), durations, profiles, strict=True):
            start = {**await robot.start_pose(pose)}
            since = seq_now(rig)
            await robot.move_to(pose, duration=duration, profile=profile)
            check_segment(rig, since, start, pose)
            await robot.read_pose()
            for name, deg in robot.targets.items():
                if deg is not None:
                    assert robot.joints[name].min <= deg <= robot.joints[name].max

    run_robot(rig, body)


@pytest.mark.parametrize("profile", ["minjerk", "linear"])
def test_read_pose_after_move_to_is_the_pose_and_unnamed_joints_hold_still(profile: str) -> None:
    # Real time: the simulated servos move at their speed in wall-clock time, as the motion is timed.
    rig = make_rig(realtime=True, ics36=ALL_ICS36)
    goal = {"neck": 33.3, "shoulder": -71.0, "elbow": 88.8, "knee": -45.5}

    async def body(robot: Robot) -> None:
        await robot.move_to({"hip": 12.5}, duration=0.1)
        since = seq_now(rig)
        await robot.move_to(goal, duration=0.3, profile=profile)
        expected = {**goal, "hip": 12.5}
        pose = await settled_pose(robot, expected)
        for name, deg in expected.items():
            assert pose[name] == pytest.approx(deg, abs=0.1), name
        # hip was not named: every command it got meanwhile is its old target.
        assert set(targets_sent(rig.lower, 1, since["lower"])) == {joint_position(JOINTS["hip"], 12.5)}

    run_robot(rig, body, **NO_TIMEOUTS)


def test_a_motion_on_one_line_keeps_its_lines_pace_beside_a_slower_line() -> None:
    # A robot builder's finding: the robot stepped its motions on frames merged from every line, so a
    # line at 10 Hz (or one slowed by a silent servo) made a 100 Hz line's motion a staircase of 10 steps
    # a second.  Counted against the lines' own cycles in the same span: no wall-clock figure.  (20 Hz
    # beside 200 Hz here: a robot file asks 20 Hz at least.)

    def moved() -> tuple[list[int], int]:
        """The fast line's targets to the neck, one a cycle of its own, and the slow line's cycles meanwhile."""
        rig = make_rig()
        rig.description["lines"]["upper"]["rate_hz"] = 200
        rig.description["lines"]["lower"]["rate_hz"] = 20

        async def body(robot: Robot) -> dict[str, int]:
            robot.hold()
            await robot.on_wire()
            before = seq_now(rig)
            await robot.move_to({"neck": 40.0}, duration=0.6)
            return before

        before = run_robot(rig, body)
        return targets_sent(rig.upper, 1, before["upper"]), len(list(commanded(rig.lower, 1, before["lower"])))

    # Only a run whose fast line ran at least twice the slow one's cycles can tell the two apart: a loaded machine
    # (a suite's load on a slow hour) held it to the slow one's pace, 17 cycles to 16.  Run again until one does.
    for _ in range(5):
        sent, slow_cycles = moved()
        if len(sent) >= 2 * slow_cycles:
            break
    else:
        raise AssertionError(
            f"in 5 runs the machine never let the fast line run twice the slow one's cycles: "
            f"{len(sent)} to {slow_cycles} in the last"
        )
    moving = sent[: sent.index(sent[-1]) + 1]  # its cycles until the motion's end was sent
    steps = sum(a != b for a, b in itertools.pairwise(moving))
    # Stepped on the slow line's frames, the fast line sends each target for several of its cycles in a row: one
    # new target in 10 of its cycles here on a quiet machine.  At its own pace a new one nearly every cycle (a
    # few repeat where the motion eases in and out by less than a count a cycle, or where late cycles came in a
    # row).
    assert steps >= 0.6 * (len(moving) - 1), (steps, len(moving), slow_cycles)


def test_the_joint_mapping_against_the_servos_positions_both_ways() -> None:
    rig = make_rig(realtime=True, ics36=ALL_ICS36)

    async def body(robot: Robot) -> None:
        # Joint -> servo: where the simulated servos end up.
        goal = {"neck": 20.0, "shoulder": 30.0, "elbow": 50.0}
        await robot.move_to(goal, duration=0.5)
        pose = await settled_pose(robot, goal)
        rig.upper.sync()
        for name, deg in goal.items():
            spec = JOINTS[name]
            expected = spec.get("offset", 0.0) + (-1 if spec.get("reverse") else 1) * deg
            assert units.position_to_degrees(rig.servo(name).target or 0) == pytest.approx(expected, abs=HALF_COUNT)
            assert units.position_to_degrees(rig.servo(name).position) == pytest.approx(expected, abs=0.1)
            assert pose[name] == pytest.approx(deg, abs=0.1)
        # Servo -> joint: a free servo turned by hand reads back in joint degrees.
        rig.servo("knee").move_by_hand(9000)
        rig.servo("hip").move_by_hand(6500)
        pose = await robot.read_pose()
        assert pose["knee"] == pytest.approx(joint_degrees(JOINTS["knee"], 9000))
        assert pose["hip"] == pytest.approx(units.position_to_degrees(6500))
        assert pose["knee"] == pytest.approx(units.position_to_degrees(9000) - 5.5)

    run_robot(rig, body, **NO_TIMEOUTS)


@pytest.mark.parametrize(
    ("pose", "message"),
    [
        ({"neck": 10.0, "hip": 31.0}, r"joint hip: 31 degrees is outside its limits -30\.\.30"),
        ({"neck": 10.0, "elbow": -0.5}, r"joint elbow: -0\.5 degrees is outside"),
        ({"neck": 10.0, "tail": 0.0}, r"unknown joint\(s\): tail"),
        ({"neck": math.nan}, r"outside its limits"),
        ({"neck": "10"}, r"must be a number of degrees"),
    ],
)
def test_a_bad_target_raises_before_anything_is_sent(pose: dict[str, Any], message: str) -> None:
    rig = make_rig()

    async def body(robot: Robot) -> None:
        since = seq_now(rig)
        with pytest.raises(InvalidArgument, match=message):
            await robot.move_to(pose, duration=0.1)
        await robot.read_pose()
        await robot.read_pose()
        for name, spec in JOINTS.items():
            assert targets_sent(rig.sim(spec["line"]), spec["id"], since[spec["line"]]) == [], name
        with pytest.raises(InvalidArgument, match="duration: -1 must be above 0"):
            await robot.move_to({"neck": 1.0}, duration=-1)
        with pytest.raises(InvalidArgument, match="profile must be one of minjerk, linear"):
            await robot.move_to({"neck": 1.0}, duration=1, profile="cubic")

    run_robot(rig, body)


# Trajectories built in Python, each from the neck's start angle: what each broke, and the words that say so.
BAD_TRAJECTORIES: dict[str, tuple[Callable[[float], list[Segment]], str]] = {
    # A time of 0 threw the joint to its end at full speed; a negative one too.
    "zero time": (lambda a: [Segment(0.0, 0.0, {"neck": a}, {"neck": 50.0})], r"end_time: 0 must be above 0"),
    "negative time": (lambda a: [Segment(0.0, -1.0, {"neck": a}, {"neck": 50.0})], r"end_time: -1 must be above 0"),
    # NaN, an infinity or 1e308: the motion never ended (the joint held its start, the robot's motion taken).
    "nan time": (lambda a: [Segment(0.0, math.nan, {"neck": a}, {"neck": 50.0})], r"end_time: must be a number of s"),
    "inf time": (lambda a: [Segment(0.0, math.inf, {"neck": a}, {"neck": 50.0})], r"end_time: must be a number of s"),
    "1e308 time": (lambda a: [Segment(0.0, 1e308, {"neck": a}, {"neck": 50.0})], r"end_time: 1e\+308 must be at most"),
    "nan start": (lambda a: [Segment(math.nan, 1.0, {"neck": a}, {"neck": 50.0})], r"start_time: must be a number"),
    "later than before": (
        lambda a: [Segment(0.0, 0.2, {"neck": a}, {"neck": 5.0}), Segment(0.3, 0.1, {"neck": 5.0}, {"neck": 9.0})],
        r"end_time: 0\.1 must be after 0\.3",
    ),
    # A NaN angle threw the joint to its lower limit at full speed, an infinite one to both limits in turn.
    "nan angle": (lambda a: [Segment(0.0, 0.3, {"neck": a}, {"neck": math.nan})], r"end\.neck: must be a number of d"),
    "inf angle": (lambda a: [Segment(0.0, 0.3, {"neck": math.inf}, {"neck": a})], r"start\.neck: must be a number"),
    # An unknown joint, or an end without a joint of its start, ended the robot with a KeyError.
    "unknown joint": (
        lambda a: [Segment(0.0, 0.3, {"neck": a, "tail": 0.0}, {"neck": 20.0, "tail": 5.0})],
        r"segments\[0\]\.start: unknown joint\(s\): tail",
    ),
    "end without a joint": (lambda a: [Segment(0.0, 0.3, {"neck": a}, {})], r"start and end name the same joints"),
    # An unknown profile ended the robot (raised in its frames' pump).
    "unknown profile": (lambda a: [Segment(0.0, 0.3, {"neck": a}, {"neck": 5.0}, "cubic")], r"profile must be one"),
    # The stop's own profile: stop() took such a run for its ramp, to take over rather than to stop.
    "the stop's profile": (
        lambda a: [Segment(0.0, 0.3, {"neck": a}, {"neck": 5.0}, "decel")],
        r"segments\[0\]: profile 'decel' is Robot\.stop's own ramp; a trajectory's segments are minjerk or linear",
    ),
    # An angle past a limit was sent as the limit instead of refused.
    "past a limit": (
        lambda a: [Segment(0.0, 0.3, {"neck": a}, {"neck": 120.0})],
        r"segments\[0\]\.end: joint neck: 120 degrees is outside its limits -60\.\.60",
    ),
    # Segments not back to back: the second one's start was sent at full speed, or its joint held for nothing.
    "a jump between segments": (
        lambda a: [Segment(0.0, 0.2, {"neck": a}, {"neck": 0.0}), Segment(0.2, 0.4, {"neck": -55.0}, {"neck": -50.0})],
        r"segments\[1\] starts at neck -55, not where segments\[0\] ends \(0\)",
    ),
    "a gap between segments": (
        lambda a: [Segment(0.0, 0.2, {"neck": a}, {"neck": 0.0}), Segment(0.5, 0.7, {"neck": 0.0}, {"neck": 9.0})],
        r"segments\[1\] starts at 0\.5 s, not where segments\[0\] ends \(0\.2 s\)",
    ),
    # A first segment starting away from the joint: its start was sent at once, the joint thrown there.
    "starting away from the joint": (
        lambda a: [Segment(0.0, 0.3, {"neck": a + 30.0}, {"neck": a + 35.0})],
        r"segments\[0\] starts neck at 20 degrees, not where a motion of it starts \(-10",
    ),
    "other joints later": (
        lambda a: [Segment(0.0, 0.2, {"neck": a}, {"neck": 0.0}), Segment(0.2, 0.4, {"hip": 0.0}, {"hip": 9.0})],
        r"segments\[1\] moves hip, not the joints of segments\[0\] \(neck\)",
    ),
}


@pytest.mark.parametrize("case", list(BAD_TRAJECTORIES))
def test_a_trajectory_built_in_python_is_held_to_the_motion_rules_before_anything_is_sent(case: str) -> None:
    """A Trajectory of Segments given to Robot.run meets a keyframe's rules and the robot's limits, refused
    (InvalidArgument) before any command goes out; the robot goes on moving after."""
    build, message = BAD_TRAJECTORIES[case]
    rig = make_rig()

    async def body(robot: Robot) -> None:
        start = (await robot.read_pose())["neck"]
        since = seq_now(rig)
        with pytest.raises(InvalidArgument, match=message):
            await robot.run(Trajectory(build(start)))
        await robot.read_pose()
        await robot.read_pose()
        for name, spec in JOINTS.items():
            assert targets_sent(rig.sim(spec["line"]), spec["id"], since[spec["line"]]) == [], name
        await robot.move_to({"neck": 5.0}, duration=0.05)
        assert (await settled_pose(robot, {"neck": 5.0}))["neck"] == pytest.approx(5.0, abs=0.1)

    run_robot(rig, body)


def test_a_trajectory_from_where_its_joints_start_plays_to_its_end() -> None:
    """Built from start_pose(), or within LIMIT_SLACK of it (a reading a count off), a trajectory plays through."""
    rig = make_rig()

    async def body(robot: Robot) -> None:
        start = await robot.start_pose(["neck", "hip"])
        near = {"neck": start["neck"] + LIMIT_SLACK / 2, "hip": start["hip"]}
        middle = {"neck": 20.0, "hip": -10.0}
        since = seq_now(rig)
        await robot.run(
            Trajectory([Segment(0.0, 0.1, near, middle), Segment(0.1, 0.2, middle, {"neck": 25.0, "hip": -5.0})])
        )
        for name, goal in (("neck", 25.0), ("hip", -5.0)):
            spec = JOINTS[name]
            assert targets_sent(rig.sim(spec["line"]), spec["id"], since[spec["line"]])[-1] == sent_position(spec, goal)

    run_robot(rig, body)


def test_a_segment_keyframe_and_move_to_say_the_same_rule_in_the_same_words() -> None:
    """One rule of a motion's times and angles: a Segment, a Keyframe of a Motion and move_to's duration."""
    for seconds in (0.0, -1.0, math.nan, math.inf, 1e308, LONGEST_MOTION * 2):
        with pytest.raises(InvalidArgument) as by_keyframe:
            Motion((Keyframe(seconds, {"neck": 5.0}),))
        with pytest.raises(InvalidArgument) as by_segment:
            Segment(0.0, seconds, {"neck": 0.0}, {"neck": 5.0})
        with pytest.raises(InvalidArgument) as by_duration:
            check_duration(seconds)
        rule = str(by_keyframe.value).split(": ", 1)[1]
        assert str(by_segment.value).endswith(f"end_time: {rule}"), (by_segment.value, rule)
        assert str(by_duration.value) == f"duration: {rule}", (by_duration.value, rule)
    for angle in (math.nan, math.inf, "5"):
        with pytest.raises(InvalidArgument) as by_keyframe:
            Motion((Keyframe(1.0, {"neck": angle}),))  # type: ignore[dict-item]
        with pytest.raises(InvalidArgument) as by_segment:
            Segment(0.0, 1.0, {"neck": 0.0}, {"neck": angle})  # type: ignore[dict-item]
        rule = str(by_keyframe.value).split(": ", 1)[1]
        assert str(by_segment.value).endswith(f"end.neck: {rule}"), (by_segment.value, rule)
    assert check_duration(LONGEST_MOTION) == LONGEST_MOTION


def test_move_to_in_no_time_is_refused_before_anything_is_sent() -> None:
    """A move in 0 s threw the joints to the pose at full speed: refused, as a keyframe at 0 s is."""
    rig = make_rig()

    async def body(robot: Robot) -> None:
        since = seq_now(rig)
        for duration in (0, 0.0, LONGEST_MOTION + 1):
            with pytest.raises(InvalidArgument, match=r"^duration: "):
                await robot.move_to({"neck": 50.0}, duration=duration)
        await robot.read_pose()
        await robot.read_pose()
        assert targets_sent(rig.upper, JOINTS["neck"]["id"], since["upper"]) == []

    run_robot(rig, body)


def test_a_pose_set_just_before_the_block_ends_reaches_the_servos() -> None:
    # set_targets() then the block's end (on_close="hold"): the last pose was dropped.
    rig = make_rig(realtime=True, ics36=ALL_ICS36)

    async def body(robot: Robot) -> None:
        await robot.move_to({"hip": 5.0, "neck": 0.0}, duration=0.05)
        robot.set_targets({"hip": -20.0, "neck": 30.0})

    run_robot(rig, body, **NO_TIMEOUTS)
    for name, degrees in (("hip", -20.0), ("neck", 30.0)):
        assert rig.servo(name).target == sent_position(JOINTS[name], degrees), name


def test_a_motion_gives_up_the_joints_of_a_line_that_comes_back_and_they_wait_for_a_target() -> None:
    # A robot line reconnected mid-motion and the motion drove its joints on from where the plan was
    # (a servo that restarted meanwhile would be thrown there); the robot's frames did not say so, and
    # a stop, a hold or a read_pose then used what was known before the loss.
    rig = make_rig()

    async def body(robot: Robot) -> None:
        await robot.move_to({"hip": 0.0, "neck": 0.0}, duration=0.05)
        outcome: list[BaseException] = []

        async def move() -> None:
            try:
                await robot.move_to({"hip": 20.0, "neck": 30.0}, duration=1.0)
            except MotionStopped as exc:
                outcome.append(exc)

        async with anyio.create_task_group() as group:
            group.start_soon(move)
            await robot.wait_frame((await robot.wait_frame(0)).cycle + 3)
            rig.lower.unplug(replug_after=0.05)
            with anyio.fail_after(GUARD):
                while not (frame := await robot.wait_frame(robot.latest.cycle if robot.latest else 0)).held:
                    pass
            assert frame.held == {"hip"}, frame.held  # (knee was free: a free joint carries on free)
            since = rig.lower.transactions
        # The motion went on with neck, to its end, and then said it had given hip up (as the line was lost, or as
        # it came back when the robot saw no frame in between).
        said = str(outcome[0]) if outcome else ""
        assert said.startswith("line lower") and "sent nothing until a target is set again" in said, outcome
        assert targets_sent(rig.upper, 1)[-1] == sent_position(JOINTS["neck"], 30.0)
        await robot.stop()  # nothing to ramp for hip: it stays held
        robot.hold(["hip"])  # where it is is unknown: nothing to hold it at
        with pytest.raises(UnsafeOperation, match="hip is held since line lower came back"):
            await robot.move_to({"hip": -20.0}, duration=0.1)  # it would start from the target it had
        pose = await robot.read_pose()  # (it waited for hip's replies, which never come)
        assert "hip" not in pose and "neck" in pose
        assert targets_sent(rig.lower, 1, since) == []  # hip: no command since it came back
        robot.set_targets({"hip": 5.0})
        await robot.on_wire(["hip"])
        assert targets_sent(rig.lower, 1, since)[-1] == sent_position(JOINTS["hip"], 5.0)
        assert "hip" not in (await robot.wait_frame(robot.latest.cycle if robot.latest else 0)).held
        await robot.move_to({"hip": 0.0}, duration=0.05)  # a target set: motions may move it again

    run_robot(rig, body, reconnect=True)


def test_a_motion_goes_on_with_the_other_lines_joints_while_one_line_is_lost_and_never_throws_them() -> None:
    # A robot builder's finding (a hexapod on two lines, reconnect=True): one line's adapter pulled mid-stride
    # froze the other line's joints too (the motion waited for a cycle of every line it moves), and when the
    # line came back they jumped to where the motion was by then: 35 degrees in one command.
    rig = make_rig(realtime=True, ics36=ALL_ICS36)
    outage: dict[str, int] = {}

    async def body(robot: Robot) -> None:
        await robot.move_to({"neck": 0.0, "hip": 0.0}, duration=0.05)
        await robot.on_wire()
        outage["start"] = rig.upper.transactions
        outcome: list[BaseException] = []

        async def unplug_for_a_while() -> None:
            await anyio.sleep(0.2)
            outage["from"] = rig.upper.transactions
            rig.lower.unplug()
            await anyio.sleep(0.5)
            while rig.upper.transactions < outage["from"] + 90:  # (a machine that stalled us: 30 cycles at least)
                await anyio.sleep(0.01)
            outage["to"] = rig.upper.transactions
            rig.lower.replug()

        async with anyio.create_task_group() as group:
            group.start_soon(unplug_for_a_while)
            try:
                await robot.move_to({"neck": 50.0, "hip": 20.0}, duration=1.0, profile="linear")
            except MotionStopped as exc:
                outcome.append(exc)
        said = str(outcome[0]) if outcome else ""  # (hip was given up, neck driven on)
        assert said.startswith("line lower lost its port") and "went on with its joints on the other lines" in said, (
            said
        )

    run_robot(rig, body, reconnect=True, **NO_TIMEOUTS)
    # (a log entry's seq is the line's transaction count when it went out)
    neck = [
        (t.seq, t.time, joint_degrees(JOINTS["neck"], (t.tx[1] << 7) | t.tx[2]))
        for t in rig.upper.log_since(outage["start"])
        if t.command == "position" and t.servo_id == JOINTS["neck"]["id"]
    ]
    during = [deg for seq, _, deg in neck if outage["from"] <= seq < outage["to"]]
    assert during and during[-1] - during[0] > 5.0, during  # it went on while the lower line was away (not 0)
    # 50 degrees a second: each new target at most that far on from the one before, by the time since that one
    # first went out (a busy machine's stall lets the motion's clock run on as much, the stream sending the
    # last target meanwhile), and a slack of 0.3 s: a stall between a target worked out and its command on the
    # wire is not in the wire's times (a loaded machine's 0.1 s made a command 5 degrees on from one 14 ms
    # before; `make test`'s own load once 0.24 s, 11.8 degrees in 10 ms).  Never half a second's worth at once,
    # as when it drove on after the lost line came back.
    changes = [(t, deg) for k, (_, t, deg) in enumerate(neck) if k == 0 or deg != neck[k - 1][2]]
    for (t1, d1), (t2, d2) in itertools.pairwise(changes):
        assert d2 - d1 <= 50.0 * (t2 - t1 + 0.3) + 1.0, (d1, d2, t2 - t1)
    assert neck[-1][2] == pytest.approx(50.0, abs=HALF_COUNT)


def test_read_pose_and_on_wire_do_not_wait_for_a_line_whose_port_is_lost() -> None:
    # A robot builder's finding (reconnect=True): with one line's adapter pulled, read_pose() waited for that
    # line's replies for as long as it stayed away, so the other line's pose could not be read at all.
    rig = make_rig()
    rig.servo("neck").move_by_hand(joint_position(JOINTS["neck"], 12.0))

    async def body(robot: Robot) -> None:
        before = await robot.read_pose()
        rig.lower.unplug()
        with anyio.fail_after(GUARD):
            while robot.group["lower"].state is not State.LOST:
                await robot.wait_frame(robot.latest.cycle if robot.latest else 0)
        rig.servo("neck").move_by_hand(joint_position(JOINTS["neck"], 20.0))
        with anyio.fail_after(GUARD):  # (it waited for ever)
            pose = await robot.read_pose()
            await robot.on_wire()
        assert pose["neck"] == pytest.approx(20.0, abs=HALF_COUNT)  # read after the call
        assert pose["hip"] == before["hip"]  # its last known angle, as an offline joint's

    run_robot(rig, body, reconnect=True)


def test_hold_says_which_joints_it_left_out_because_their_line_is_lost_or_came_back() -> None:
    # A robot builder's finding (reconnect=True): hold() left a lost line's joints out saying "its newest reading is
    # not confirmed", as if a joint were turning fast, and once the line was back, "held since its servo answered
    # again", as if a servo had gone offline; neither said the line, nor what would get them held.
    rig = make_rig()

    async def body(robot: Robot) -> None:
        await robot.read_pose()
        assert robot.hold() == {}
        await robot.on_wire()
        rig.lower.unplug()
        with anyio.fail_after(GUARD):
            while robot.group["lower"].state is not State.LOST:
                await anyio.sleep(0.01)
            await robot.wait_frame(robot.latest.cycle if robot.latest else 0)  # (a frame with lower lost)
        left = robot.hold()
        assert set(left) == {"hip", "knee"}, left  # the upper line's joints were held
        for why in left.values():
            assert why.startswith("its line lower is lost (its port reconnecting)"), why
        rig.lower.replug()
        with anyio.fail_after(GUARD):
            while not (await robot.wait_frame(robot.latest.cycle if robot.latest else 0)).resumed:
                pass
        since = rig.lower.transactions
        left = robot.hold()
        assert set(left) == {"hip", "knee"}, left
        for why in left.values():
            assert why.startswith("held since line lower came back after its port was lost"), why
            assert "set its target" in why and "free it" in why, why
        await robot.on_wire(["neck"])
        assert targets_sent(rig.lower, 1, since) == [] and targets_sent(rig.lower, 2, since) == []

    run_robot(rig, body, reconnect=True)


def test_set_targets_refuses_a_target_for_a_joint_on_a_lost_line_naming_it_and_its_line() -> None:
    # A robot builder's finding (reconnect=True): set_targets({"neck": 5, "hip": 10}) with the hip's line lost took
    # both, robot.targets showed hip at 10, and hip's target never went out (its line came back with it held).
    rig = make_rig()

    async def body(robot: Robot) -> None:
        await robot.read_pose()
        robot.set_targets({"neck": 0.0, "hip": 0.0})
        await robot.on_wire()
        rig.lower.unplug()
        with anyio.fail_after(GUARD):
            while robot.group["lower"].state is not State.LOST:
                await anyio.sleep(0.01)
        since = rig.upper.transactions
        with pytest.raises(PortLost, match=r"joint hip \(line lower, ID 1\).*line lower.*lost.*nothing was applied"):
            robot.set_targets({"neck": 5.0, "hip": 10.0})
        with pytest.raises(PortLost, match="joint hip"):
            robot.stream().set_target("hip", 10.0)
        assert robot.targets["neck"] == 0.0 and robot.targets["hip"] == 0.0  # nothing applied
        await robot.on_wire(["neck"])
        assert set(targets_sent(rig.upper, 1, since)) == {sent_position(JOINTS["neck"], 0.0)}
        # A loop that sets every joint each pass goes on with the others: the frames' lost name the joints left.
        robot.set_targets({"neck": 5.0, "hip": 10.0}, lift_holds=False)
        await robot.on_wire(["neck"])
        assert targets_sent(rig.upper, 1, since)[-1] == sent_position(JOINTS["neck"], 5.0)
        assert robot.latest is not None and "hip" in robot.latest.lost
        robot.set_targets({"knee": None}, allow_free=True)  # (freeing goes out as the line comes back)
        rig.lower.replug()
        with anyio.fail_after(GUARD):
            while not (await robot.wait_frame(robot.latest.cycle)).resumed:
                pass
        assert robot.held == {"hip": "resumed"}  # (sent nothing: it may have restarted elsewhere)
        since = rig.lower.transactions
        robot.set_targets({"hip": 10.0})
        await robot.on_wire(["hip"])
        assert targets_sent(rig.lower, 1, since)[-1] == sent_position(JOINTS["hip"], 10.0)

    run_robot(rig, body, reconnect=True)


def paced_rig() -> Rig:
    """The rig with both lines paced (200 Hz): an unpaced line's stream still gives a frame as its port goes."""
    rig = make_rig()
    for line in rig.description["lines"].values():
        line["rate_hz"] = 200
    return rig


async def lose_every_line(rig: Rig, robot: Robot) -> None:
    """Both lines' adapters pulled (``reconnect=True``): returns once both buses know it."""
    rig.upper.unplug()
    rig.lower.unplug()
    with anyio.fail_after(GUARD):
        while any(bus.state is not State.LOST for bus in robot.group.buses.values()):
            await anyio.sleep(0.01)


def test_free_on_wire_and_read_pose_do_not_wait_when_every_line_is_lost() -> None:
    # With every line's port lost no frame comes (there is no line left to run a cycle): free() waited for one
    # for as long as the lines stayed away (the configurator's Free all hung on a one-line robot).  The free is
    # each joint's target, sent once its line is back.
    rig = paced_rig()

    async def body(robot: Robot) -> None:
        robot.set_targets({"neck": 10.0, "hip": 5.0})
        await robot.on_wire()
        await lose_every_line(rig, robot)
        with anyio.fail_after(GUARD):  # (it waited for ever)
            await robot.free()
            await robot.on_wire(["neck"])
            pose = await robot.read_pose()
        assert set(pose) == set(JOINTS)  # their last known angles
        assert set(robot.targets.values()) == {None}
        rig.upper.replug()
        rig.lower.replug()
        with anyio.fail_after(GUARD):
            while not (all(s.free for s in rig.upper.servos) and all(s.free for s in rig.lower.servos)):
                await anyio.sleep(0.01)

    run_robot(rig, body, reconnect=True)


@pytest.mark.parametrize("lost", [("upper", "lower"), ("lower",)], ids=["every-line", "one-line"])
def test_a_stop_right_after_a_cancelled_motion_has_nothing_to_ramp_on_a_lost_line(lost: tuple[str, ...]) -> None:
    # A motion cancelled (Ctrl-C, the configurator's Stop) leaves its joints coasting for two cycles, at the speed
    # they had, for a smooth stop() right after.  A line lost then, the stop ramped its joints down on cycles the
    # line could not run: with every line lost it waited for as long as they stayed away; with one, it raised
    # MotionStopped for joints no motion drove any more.  Their servos keep their last command.
    rig = paced_rig()

    async def body(robot: Robot) -> None:
        with anyio.move_on_after(0.3):  # (a move of 5 s: cancelled on its way)
            await robot.move_to({"neck": 40.0, "hip": 20.0}, duration=5.0)
        for name in lost:  # (at once: within the two cycles the joints coast for)
            getattr(rig, name).unplug()
        with anyio.fail_after(GUARD):
            while any(robot.group.buses[name].state is not State.LOST for name in lost):
                await anyio.sleep(0.01)
        with anyio.fail_after(GUARD):  # (it waited for ever, every line lost)
            await robot.stop()
        for name in lost:
            getattr(rig, name).replug()

    run_robot(rig, body, reconnect=True)


def test_a_motion_started_once_every_line_is_lost_ends_with_motion_stopped_not_a_wait() -> None:
    # Started after the loss (a program's next move, the configurator's), the motion was given nothing up: with
    # no line left to run a cycle, no frame came to step it, and it waited for as long as the lines stayed away.
    rig = paced_rig()

    async def body(robot: Robot) -> None:
        await robot.read_pose()
        await lose_every_line(rig, robot)
        # (it waited for ever; its words say it stopped, with no line to go on with)
        stopped = "lines lower, upper lost their ports: the motion stopped"
        with anyio.fail_after(GUARD), pytest.raises(MotionStopped, match=stopped):
            await robot.move_to({"neck": 10.0, "hip": 5.0}, duration=0.5)
        rig.upper.replug()
        rig.lower.replug()

    run_robot(rig, body, reconnect=True)


def test_a_motion_whose_every_line_is_lost_ends_with_motion_stopped_not_a_wait() -> None:
    # One line lost among others gives its joints up at the next frame; with every line lost no frame came, and
    # the motion waited for as long as the lines stayed away (then went on, its joints held by their lines).
    rig = paced_rig()

    async def body(robot: Robot) -> None:
        ended: list[BaseException] = []

        async def move() -> None:
            try:
                await robot.move_to({"neck": 20.0, "hip": 10.0}, duration=5.0)
            except MotionStopped as exc:
                ended.append(exc)

        async with anyio.create_task_group() as tasks:
            tasks.start_soon(move)
            with anyio.fail_after(GUARD):
                while robot.targets.get("neck") is None:  # (the motion under way)
                    await anyio.sleep(0.01)
            rig.upper.unplug()
            rig.lower.unplug()
        said = str(ended[0]) if ended else ""  # (not "went on with" joints elsewhere: there were none)
        assert said.startswith("lines lower, upper lost their ports: the motion stopped"), ended

    run_robot(rig, body, reconnect=True)


def test_frames_name_the_joints_on_a_line_whose_port_is_lost_until_it_is_back() -> None:
    # With one line's adapter pulled (reconnect=True) the robot's frames went on with the other line's cycles,
    # and a lost line's joints were neither offline nor held in them: a program had to ask each line's bus.
    rig = make_rig()
    lower = {name for name, spec in JOINTS.items() if spec["line"] == "lower"}

    async def body(robot: Robot) -> None:
        frame = await robot.wait_frame(0)
        assert frame.lost == frozenset() and frame.to_dict()["lost"] == []
        rig.lower.unplug()
        with anyio.fail_after(GUARD):
            while not frame.lost:
                frame = await robot.wait_frame(frame.cycle)
        assert frame.lost == lower and sorted(lower) == frame.to_dict()["lost"]
        rig.lower.replug()
        with anyio.fail_after(GUARD):
            while "lower" not in frame.resumed:
                assert frame.lost == lower  # (until the frame that says the line is back)
                frame = await robot.wait_frame(frame.cycle)
        assert frame.lost == frozenset()  # back (free joints answer again; one with a target is held)
        with anyio.fail_after(GUARD):
            while not lower <= frame.positions.keys():
                frame = await robot.wait_frame(frame.cycle)

    run_robot(rig, body, reconnect=True)


def test_a_joint_back_from_offline_is_given_up_by_its_motion_and_waits_for_a_target() -> None:
    # A servo browned out under a robot that carries on past offline joints ([safety] continue_on_offline):
    # it restarted free where the load left it, and the probe that found it again threw it to the motion's
    # target.  It comes back held: the motion gives it up and nothing moves it until a target is set.
    rig = make_rig(safety={"continue_on_offline": True})

    async def body(robot: Robot) -> None:
        await robot.move_to({"elbow": 30.0, "neck": 0.0}, duration=0.05)
        outcome: list[BaseException] = []

        async def move() -> None:
            try:
                await robot.move_to({"elbow": 80.0, "neck": 30.0}, duration=1.0)
            except MotionStopped as exc:
                outcome.append(exc)

        async with anyio.create_task_group() as group:
            group.start_soon(move)
            await robot.wait_frame((await robot.wait_frame(0)).cycle + 3)
            elbow = rig.upper.remove_servo(3)
            with anyio.fail_after(GUARD):
                while "elbow" not in (await robot.wait_frame(robot.latest.cycle if robot.latest else 0)).offline:
                    pass
            rig.upper.add_device(elbow)
            rig.upper.power_cycle(3)  # restarted: free, where the load left it
            since = rig.upper.transactions
            with anyio.fail_after(GUARD):
                while not (frame := await robot.wait_frame(robot.latest.cycle if robot.latest else 0)).held:
                    pass
            assert frame.held == {"elbow"} and not frame.offline, frame
            # The CLI's table (ics35 play): the elbow is not "held" at its target, it waits for one.
            console = Console(record=True, width=120)
            console.print(joint_table(robot, "t", None))
            rows = {line.split()[0]: line for line in console.export_text().splitlines() if line.strip()}
            assert "waiting for a target" in rows["elbow"] and "held" in rows["neck"], rows
        assert outcome and "elbow came back after going offline" in str(outcome[0]), outcome
        assert targets_sent(rig.upper, 1)[-1] == sent_position(JOINTS["neck"], 30.0)  # neck went on to its end
        assert targets_sent(rig.upper, 3, since) == [] and elbow.free  # nothing moved the elbow
        with pytest.raises(UnsafeOperation, match="elbow is held since it came back after going offline"):
            await robot.move_to({"elbow": 40.0}, duration=0.1)
        robot.set_targets({"elbow": 40.0})
        await robot.on_wire(["elbow"])
        assert targets_sent(rig.upper, 3, since)[-1] == sent_position(JOINTS["elbow"], 40.0)
        await robot.move_to({"elbow": 50.0}, duration=0.05)  # a target set: motions may move it again

    run_robot(rig, body, offline_after=2, probe_interval=0.02)


def test_hold_and_a_loops_targets_leave_a_joint_held_by_its_stream_before_the_robot_saw_the_frame() -> None:
    # hold() sent a servo back from offline the position it had before it fell silent (the robot had not
    # yet seen the frame that held it), throwing a restarted servo back there.
    rig = make_rig(safety={"continue_on_offline": True})

    async def body(robot: Robot) -> None:
        await robot.move_to({"elbow": 30.0, "neck": 0.0}, duration=0.05)
        await robot.read_pose()
        elbow = rig.upper.remove_servo(3)
        with anyio.fail_after(GUARD):
            while "elbow" not in (await robot.wait_frame(robot.latest.cycle if robot.latest else 0)).offline:
                pass
        rig.upper.add_device(elbow)
        rig.upper.power_cycle(3)  # restarted free, where the load left it
        elbow.move_by_hand(sent_position(JOINTS["elbow"], 90.0))
        since = rig.upper.transactions
        with anyio.fail_after(GUARD):
            while "elbow" not in robot.held:
                await anyio.sleep(0)
        assert robot.held == {"elbow": "rejoined"}
        robot.hold()  # every joint where it is: not the elbow, whose position is unknown
        robot.set_targets({"elbow": 40.0, "neck": 5.0}, lift_holds=False)  # a loop's pass
        await anyio.sleep(0.1)
        assert targets_sent(rig.upper, 3, since) == [] and elbow.free
        assert targets_sent(rig.upper, 1, since)[-1] == sent_position(JOINTS["neck"], 5.0)
        robot.set_targets({"elbow": 40.0})  # decided
        await robot.on_wire(["elbow"])
        assert targets_sent(rig.upper, 3, since)[-1] == sent_position(JOINTS["elbow"], 40.0) and robot.held == {}

    run_robot(rig, body, offline_after=2, probe_interval=0.02)


def test_free_hold_and_the_joint_space_stream() -> None:
    rig = make_rig()

    async def body(robot: Robot) -> None:
        await robot.move_to({"neck": 15.0, "knee": -10.0}, duration=0.05)
        await robot.free(["neck"])
        assert rig.servo("neck").free and not rig.servo("knee").free
        rig.servo("neck").move_by_hand(joint_position(JOINTS["neck"], -25.0))
        await robot.read_pose()
        robot.hold(["neck"])
        async with robot.stream() as stream:
            frame = await stream.next_frame()
            assert set(frame.positions) <= set(JOINTS) and frame.targets["neck"] == pytest.approx(-25.0, abs=HALF_COUNT)
            assert rig.servo("neck").target == joint_position(JOINTS["neck"], -25.0)
            stream.set_targets({"hip": -12.0})
            with pytest.raises(InvalidArgument, match="outside its limits"):
                stream.set_target("hip", 40.0)
            await robot.on_wire(["hip"])
            assert rig.servo("hip").target == joint_position(JOINTS["hip"], -12.0)
            frame = await stream.next_frame()
            assert frame.targets["hip"] == -12.0
            stream.free()
            await robot.on_wire()
            assert all(rig.servo(name).free for name in JOINTS)
        await robot.free()

    run_robot(rig, body)


def test_a_robot_stream_started_again_after_its_block_says_a_stream_runs_once() -> None:
    # A program in phases (`async with stream:` twice on one robot stream) was let in, and its frames then ended at
    # once (`async for` ran no turn) or raised "robot stream closed": as a bus's stream, it is told to make another.
    rig = make_rig()

    async def body(robot: Robot) -> None:
        stream = robot.stream()
        async with stream:
            await stream.next_frame()
        with pytest.raises(BusClosed, match=r"a stream runs once; .*robot\.stream\(\)"):
            async with stream:
                pass
        with pytest.raises(BusClosed, match=r"a stream runs once; .*robot\.stream\(\)"):
            await stream.next_frame()
        async with robot.stream() as again:  # and the robot streams on
            assert (await again.next_frame()).positions

    run_robot(rig, body)


def test_a_free_joint_standing_past_its_limit_is_not_thrown_to_the_limit_by_a_motion_or_a_hold() -> None:
    # A free joint turned by hand past its limit (knee: max 20 degrees, at 61) started a motion from the limit:
    # the first command was the limit, which the servo reached at full speed (a 2 s move_to moved it 41 degrees
    # in a tenth of a second), and hold() (the configurator's "enable motion") did the same.  A motion naming it
    # is refused, hold() leaves it free and says so; within the limits' slack it is held and moved as ever.
    rig = make_rig()
    knee = rig.servo("knee")
    knee.move_by_hand(joint_position(JOINTS["knee"], 61.0))

    async def body(robot: Robot) -> None:
        pose = await robot.read_pose()
        assert pose["knee"] == pytest.approx(61.0, abs=0.1) and knee.free
        since = seq_now(rig)
        with pytest.raises(UnsafeOperation, match=r"joint knee stands at 61\.0 degrees, past its limit 20"):
            await robot.move_to({"knee": 0.0, "hip": 5.0}, duration=1.0)
        with pytest.raises(UnsafeOperation, match="joint knee stands at 61"):
            await robot.play(
                {"format": "ics35-motion", "version": 1, "keyframes": [{"time": 0.5, "pose": {"knee": 0}}]}
            )
        left = robot.hold()
        assert set(left) == {"knee"} and "past its limit 20" in left["knee"], left
        await robot.on_wire()
        assert targets_sent(rig.lower, JOINTS["knee"]["id"], since["lower"]) == [] and knee.free
        assert not rig.servo("hip").free  # the others hold
        knee.move_by_hand(joint_position(JOINTS["knee"], 21.5))  # within the slack: read noise at a limit
        await robot.read_pose()
        assert robot.hold(["knee"]) == {}
        await robot.move_to({"knee": 0.0}, duration=0.1)
        assert knee.target == sent_position(JOINTS["knee"], 0.0)

    run_robot(rig, body)


def test_hold_during_a_motion_stops_its_joints_where_they_were_sent_not_back_where_they_were_last_read() -> None:
    # hold() mid-motion held a moving joint where it was last read, which lags its target (the servo is on its
    # way): the joint stepped back, against its motion (6.3 degrees in a 0.5 s move of 90).  A joint a motion
    # drives holds at the target last sent; one at rest, or free, where it was read, as ever.
    rig = make_rig()

    async def body(robot: Robot) -> None:
        await robot.move_to({"neck": 0.0}, duration=0.05)
        since = seq_now(rig)
        async with anyio.create_task_group() as tasks:
            tasks.start_soon(robot.move_to, {"neck": 50.0}, 1.0)
            while (robot.targets["neck"] or 0.0) < 20.0:
                await robot.wait_frame(robot.latest.cycle if robot.latest else 0)
            before = robot.targets["neck"]
            assert before is not None
            assert robot.hold(["neck"]) == {}
            assert robot.targets["neck"] == before
        await robot.on_wire(["neck"])
        spec = JOINTS["neck"]
        sent = [joint_degrees(spec, p) for p in targets_sent(rig.upper, spec["id"], since["upper"])]
        assert sent and all(b >= a - HALF_COUNT for a, b in itertools.pairwise(sent)), sent  # never back
        assert sent[-1] == pytest.approx(before, abs=HALF_COUNT)

    run_robot(rig, body)


def test_limits_wider_than_the_servos_eeprom_warn_at_open() -> None:
    rig = make_rig()
    narrowed = rig.servo("elbow").eeprom.replace(pulse_limit_low=6000, pulse_limit_high=9000)
    assert isinstance(narrowed, Eeprom)
    rig.servo("elbow").eeprom = narrowed

    async def body(robot: Robot) -> list[str]:
        return list(robot.warnings)

    with pytest.warns(RobotWarning, match=r"<mapping>: joints\.elbow: the file allows 0\.\.110 degrees") as caught:
        found = run_robot(rig, body)
    assert len(found) == 1 and len(caught) == 1
    assert "EEPROM pulse limits 6000..9000" in found[0]
    # The warning points at the program that opened the robot, not into the library or contextlib.
    assert Path(caught[0].filename).name == Path(__file__).name, caught[0].filename


def test_joints_whose_servos_do_not_answer_are_named_in_one_warning_a_line() -> None:
    # A hexapod line with nothing answering printed a warning block per joint (nine, each with its
    # source line): one a line, naming the joints, says the same.
    rig = make_rig()
    for servo_id in (1, 2, 3):
        rig.upper.servo(servo_id).ignores = frozenset({"read_eeprom"})

    async def body(robot: Robot) -> list[str]:
        return list(robot.warnings)

    with pytest.warns(RobotWarning) as caught:
        found = run_robot(rig, body)
    assert len(found) == 1 and len(caught) == 1, found
    assert "joints neck, shoulder, elbow (servo IDs 1, 2, 3 on line upper) did not answer" in found[0], found
    assert "limits not checked" in found[0]


def test_a_joint_reversed_both_in_the_file_and_in_its_servos_eeprom_is_no_warning_at_open() -> None:
    # The two reversals cancel, which calibrate points out (tests/test_robot_cli.py); a robot calibrated so
    # turns as calibrated, and a warning at every open would be noise whose advice mirrors the joint.
    rig = make_rig()
    elbow = rig.servo("elbow")  # reverse = true in the file
    elbow.eeprom = elbow.eeprom.replace(flags=elbow.eeprom.flags | Flags.REVERSE)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RobotWarning)
        assert run_robot(rig, lambda robot: _warnings(robot)) == []


def test_no_warning_when_the_servos_allow_the_limits() -> None:
    rig = make_rig()
    with warnings.catch_warnings():
        warnings.simplefilter("error", RobotWarning)
        assert run_robot(rig, lambda robot: _warnings(robot)) == []


async def _warnings(robot: Robot) -> list[str]:
    return robot.warnings


def test_move_to_under_trio() -> None:
    rig = make_rig(realtime=True, ics36=ALL_ICS36)

    async def main() -> dict[str, float]:
        async with open_robot(rig.description, **NO_TIMEOUTS) as robot:  # the buses pick their anyio driver
            await robot.move_to({"neck": -30.0, "hip": 20.0}, duration=0.3)
            # The simulated servos turn at their own speed in real time: on a loaded machine they may still
            # be on their way when the motion's last target has gone out.
            with anyio.move_on_after(GUARD):
                while abs((pose := await robot.read_pose())["neck"] + 30.0) > 0.1 or abs(pose["hip"] - 20.0) > 0.1:
                    pass
            return pose

    try:
        pose = anyio.run(main, backend="trio")
    finally:
        rig.close()
    assert pose["neck"] == pytest.approx(-30.0, abs=0.1) and pose["hip"] == pytest.approx(20.0, abs=0.1)


def test_move_to_never_ends_early_and_returns_within_three_frames_of_its_end() -> None:
    rig = make_rig()

    async def body(robot: Robot) -> None:
        frames = []
        done = anyio.Event()

        async def watch() -> None:
            async with robot.stream() as stream:
                while not done.is_set():
                    frames.append(await stream.next_frame())

        async with anyio.create_task_group() as tasks:
            tasks.start_soon(watch)
            await robot.read_pose()
            began = anyio.current_time()
            await robot.move_to({"knee": 15.0}, duration=0.2)
            returned = robot.latest
            done.set()
        assert returned is not None
        final = [f for f in frames if f.targets["knee"] == 15.0]
        assert final and final[0].time - began >= 0.2
        # The frame that set the final target; then two replies from each line prove it sent
        # (a merged frame may carry a line's cycle that began before): at most three frames.
        assert returned.cycle - final[0].cycle <= 3
        moving = [f for f in frames if f.cycle < final[0].cycle and f.targets["knee"] is not None]
        assert len(moving) >= 2  # interpolated, not a jump

    run_robot(rig, body)
    assert list(commanded(rig.lower, 2))[-1] == joint_position(JOINTS["knee"], 15.0)


def test_stop_slows_a_running_motion_to_rest_without_turning_back() -> None:
    rig = make_rig()
    caught: list[BaseException] = []

    async def body(robot: Robot) -> None:
        async def mover() -> None:
            try:
                await robot.move_to({"neck": 55.0, "knee": -90.0}, duration=2.0, profile="linear")
            except MotionStopped as exc:
                caught.append(exc)

        async with anyio.create_task_group() as tasks:
            tasks.start_soon(mover)
            async with robot.stream() as stream:
                while (await stream.next_frame()).targets["neck"] in (None, -10.0):
                    pass
            since = seq_now(rig)
            await robot.stop(0.2)
        await robot.on_wire()
        for name in ("neck", "knee"):
            spec = JOINTS[name]
            sent = targets_sent(rig.sim(spec["line"]), spec["id"], since[spec["line"]])
            forward = joint_position(spec, -90.0 if name == "knee" else 55.0) > sent[0]
            steps = list(itertools.pairwise(sent))
            # On in the direction it was going, slowing down, never back; then at rest.
            assert all((b >= a) if forward else (b <= a) for a, b in steps), (name, sent)
            # It went on moving: not frozen at once.  (Not counted in distinct targets: the ramp follows the clock,
            # so a machine that stalls the loop for most of the 0.2 s sends its rest two or three cycles in.)
            assert sent[-1] != sent[0], (name, sent)
            assert sent[-1] != joint_position(spec, -90.0 if name == "knee" else 55.0)
            assert robot.targets[name] == pytest.approx(joint_degrees(spec, sent[-1]), abs=HALF_COUNT)

    run_robot(rig, body)
    assert len(caught) == 1


def test_a_robot_frame_is_plain_json_for_a_log_or_a_web_page() -> None:
    # A robot serving a web page had frame.to_dict() on one line's stream but not on the robot's frame.
    rig = make_rig()

    async def body(robot: Robot) -> None:
        await robot.move_to({"hip": 12.5, "neck": -20.0}, duration=0.05)
        frame = await robot.wait_frame((await robot.wait_frame(0)).cycle + 1)
        doc = json.loads(json.dumps(frame.to_dict()))
        assert doc["cycle"] == frame.cycle and doc["line_cycles"] == frame.line_cycles
        assert doc["positions"] == {name: round(deg, 2) for name, deg in frame.positions.items()}
        assert doc["targets"]["hip"] == pytest.approx(12.5, abs=0.01) and doc["targets"]["knee"] is None
        assert doc["held"] == sorted(frame.held) and doc["offline"] == sorted(frame.offline)

    run_robot(rig, body)


# (Whether a failure holds its servo back depends on the stream's learnt wait, which the real answers' times set: in
# the parallel pass's load it reached the allowance in every run of a make test now and then.)
@pytest.mark.realtime
def test_a_robot_frame_tells_the_failed_joints_that_were_sent_nothing() -> None:
    # A stream's frame says which failed IDs were sent nothing (held back while a late reply could still come);
    # the robot's frame merged them into `failed` and dropped the difference: lining robot frames up with the
    # line's traffic took each such joint for a command that went out.

    def frames_of_a_robot_losing_elbow_replies() -> list[RobotFrame]:
        rig = make_rig()
        rig.description["lines"]["upper"]["retries"] = 0
        frames: list[RobotFrame] = []

        async def body(robot: Robot) -> None:
            rig.upper.faults = FaultInjector(FaultConfig.parse("drop@3:0.3"), seed=1)  # (the elbow's, once open)
            cycle = (await robot.wait_frame(0)).cycle
            # (150 of the upper line's cycles: robot frames come at the faster line's pace, and the upper line's
            # failed telemetry reads each wait their allowance, so 150 frames held as few as 4 of its cycles)
            while not any(f.not_sent for f in frames) and (not frames or frames[-1].line_cycles["upper"] < 150):
                frames.append(await robot.wait_frame(cycle + 1))
                cycle = frames[-1].cycle

        # (An allowance far above what the servos take, so the stream's learnt wait is the shorter and a failure
        # holds its servo back; the elbow kept from going offline, which trips the robot and frees it.)
        run_robot(rig, body, adapter_latency=0.05, quiet_time=0.01, offline_after=1000)
        return frames

    # A loaded machine's learnt wait can reach the allowance (a suite's load on a slow hour), and a failure then
    # waits out a quiet time instead, holding nothing back: run again until a slot was held back, up to 4 runs.
    for _ in range(4):
        frames = frames_of_a_robot_losing_elbow_replies()
        if any(f.not_sent for f in frames):
            break
    assert any(f.not_sent == {"elbow"} for f in frames), (len(frames), sum("elbow" in f.failed for f in frames))
    assert all(f.not_sent <= f.failed for f in frames)
    shown = next(f for f in frames if f.not_sent)
    assert json.loads(json.dumps(shown.to_dict()))["not_sent"] == ["elbow"]


def test_robot_lost_names_the_joints_on_a_lost_line_as_of_now() -> None:
    # (What the configurator's Free all names as not reached: a frame's `lost` is as of its cycle, and with every
    # line lost no frame comes.)
    rig = make_rig()
    upper = {name for name, spec in JOINTS.items() if spec["line"] == "upper"}

    async def body(robot: Robot) -> None:
        assert robot.lost == frozenset()
        rig.upper.unplug()
        rig.lower.unplug()
        with anyio.fail_after(GUARD):
            while robot.lost != set(JOINTS):
                await anyio.sleep(0.01)
        rig.lower.replug()
        with anyio.fail_after(GUARD):  # (the lower line back: in a frame whose `resumed` names it)
            while robot.lost != upper:
                await anyio.sleep(0.01)

    run_robot(rig, body, reconnect=True)


def test_line_change_returns_as_a_line_is_lost_and_as_it_is_back_with_its_joints() -> None:
    # What the configurator's Robot page waits for to stop the robot, and Reconnect for the line to be back.
    rig = paced_rig()
    lower = {name for name, spec in JOINTS.items() if spec["line"] == "lower"}

    async def body(robot: Robot) -> None:
        robot.set_targets({"hip": 5.0})
        await robot.on_wire()
        seen: list[tuple[frozenset[str], frozenset[str], frozenset[str]]] = []

        async def watch() -> None:
            lost = await robot.line_change(())
            seen.append((lost, robot.lost, frozenset(robot.held)))
            lost = await robot.line_change(lost)
            seen.append((lost, robot.lost, frozenset(robot.held)))

        async with anyio.create_task_group() as tasks:
            tasks.start_soon(watch)
            await anyio.sleep(0.1)
            assert not seen  # (no line lost yet: it waits)
            rig.lower.unplug()
            with anyio.fail_after(GUARD):
                while not seen:
                    await anyio.sleep(0.01)
            assert seen[0] == (frozenset({"lower"}), lower, frozenset()), seen
            assert robot.lost_lines == frozenset({"lower"})
            await anyio.sleep(0.1)
            assert len(seen) == 1  # (still lost: it waits)
            rig.lower.replug()
        # Back as the robot counts it: at the frame that says so, its joint with a target held from then on.
        assert seen[1] == (frozenset(), frozenset(), frozenset({"hip"})), seen
        assert robot.lost_lines == frozenset() and robot.held == {"hip": "resumed"}

    run_robot(rig, body, reconnect=True)


def test_line_change_returns_with_every_line_lost_when_no_frame_comes_and_at_once_when_they_differ() -> None:
    rig = paced_rig()

    async def body(robot: Robot) -> None:
        await lose_every_line(rig, robot)
        with anyio.fail_after(GUARD):  # (already others than none: at once)
            assert await robot.line_change(()) == frozenset({"upper", "lower"})
            assert await robot.line_change("upper") == frozenset({"upper", "lower"})
        rig.upper.replug()
        with anyio.fail_after(GUARD):  # (the default: the lines lost as it is called)
            assert await robot.line_change() == frozenset({"lower"})
        with pytest.raises(InvalidArgument, match="no line 'middle'"):
            await robot.line_change(["lower", "middle"])
        for bad in (5, [["lower"]], None.__class__):  # (not line names: a typed error, not a TypeError)
            with pytest.raises(InvalidArgument, match="lost must be"):
                await robot.line_change(bad)  # type: ignore[arg-type]
        rig.lower.replug()
        return robot

    robot = run_robot(rig, body, reconnect=True)
    with pytest.raises(BusClosed):  # (the block has ended: nothing to wait for)
        anyio.run(robot.line_change)


def test_line_change_waiting_as_the_robots_block_ends_raises_bus_closed() -> None:
    rig = paced_rig()
    raised: list[BaseException] = []

    async def watch(robot: Robot) -> None:
        try:
            await robot.line_change(())
        except BusClosed as exc:
            raised.append(exc)

    async def main() -> None:
        with anyio.fail_after(GUARD):
            # (the watcher outlives the robot's block: the task group waits for it once the robot is closed)
            async with (
                anyio.create_task_group() as tasks,
                open_robot(rig.description, **{**FAST, "reconnect": True}) as robot,
            ):
                tasks.start_soon(watch, robot)
                await anyio.sleep(0.05)

    try:
        anyio.run(main)
    finally:
        rig.close()
    assert raised and "closed" in str(raised[0]), raised


@pytest.mark.pty
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the pty simulator needs Linux")
def test_line_change_over_a_pty_whose_port_goes_away_and_comes_back(pty_sim: Any) -> None:
    # A one-line robot over a real serial boundary: with its only line lost no frame comes, so the loss is told
    # by the line's bus alone; back, by the frame whose `resumed` names the line.
    # (unplugged once the robot is open: its opening reads take a fraction of that, its servos ICS 3.6: an ICS 3.5
    # joint's open waits a whole allowance for a second position read before it starts free)
    server = pty_sim(
        "--fast", "--ids", "1-2", "--ics36", "1-2", "--unplug-after", str(scaled(3.0)), "--replug-after", "0.5"
    )
    description = {
        "lines": {"main": {"port": server.path}},
        "joints": {"a": {"line": "main", "id": 1}, "b": {"line": "main", "id": 2}},
    }

    async def main() -> None:
        with anyio.fail_after(GUARD):
            async with open_robot(description, **{**NO_TIMEOUTS, "reconnect": True}) as robot:
                robot.set_targets({"a": 10.0})
                lost = await robot.line_change(())
                assert lost == frozenset({"main"}) and robot.lost == frozenset({"a", "b"})
                assert await robot.line_change(lost) == frozenset()
                assert robot.lost == frozenset() and robot.held == {"a": "resumed"}
                assert robot.group["main"].stats.reconnects >= 1

    anyio.run(main)


NOT_A_GARBLE = 10.0  # degrees: a move of a free joint no servo turned by hand makes within a few milliseconds


def run_on_garbled_lines(main: Callable[[], Awaitable[None]], *lines: VirtualLine) -> None:
    """Run ``main`` (a robot on ``lines``, some garbling replies), then close the lines."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RobotWarning)  # (an EEPROM read garbled at the open)
            anyio.run(main)
    finally:
        for line in lines:
            line.close()


@pytest.mark.parametrize(("rate_hz", "rounds", "seed"), [(None, 60, 1), (25, 30, 3)], ids=["back-to-back", "25-hz"])
def test_a_garbled_position_reply_does_not_throw_a_free_joint_when_it_is_held(
    rate_hz: float | None, rounds: int, seed: int
) -> None:
    # ICS replies carry no checksum: a byte garbled on the wire reads as another position, 100 degrees from where
    # the servo stands, and hold() (a motion from a free joint alike) took that one reading as where to hold it:
    # the servo was thrown there at full speed.  The free servos here stand still, so each hold must be where it
    # is, but for a garble of a few degrees, which no check can tell from a servo turned by hand within a cycle.
    # On a slow line (25 Hz, or a busy host) two readings 40 ms apart were taken as agreeing within 40 degrees
    # (what a servo turns at the agreement's 1000 degrees a second): a garble of 35 degrees passed; no reading
    # agrees past a step of a few degrees, and a joint whose newest reading did not agree is left free by hold().
    name = f"garbled-holds-{seed}"
    line = VirtualLine([1, 2, 3, 4], name=name, faults="corrupt:0.05", seed=seed, log_size=None)
    main_line: dict[str, Any] = {"port": f"sim://{name}"} | ({} if rate_hz is None else {"rate_hz": rate_hz})
    description = {
        "lines": {"main": main_line},
        "joints": {f"j{i}": {"line": "main", "id": i} for i in range(1, 5)},  # the servo's whole range
    }
    jumps: list[tuple[int, float, float]] = []
    left: list[int] = []  # each round's count of joints hold() left free

    async def main() -> None:
        with anyio.fail_after(2 * GUARD):
            async with open_robot(description, **FAST) as robot:  # ICS 3.5: every joint starts free
                for _ in range(rounds):
                    await robot.wait_frame(robot.latest.cycle + 2 if robot.latest else 0)
                    where = {s.servo_id: units.position_to_degrees(s.position) for s in line.servos}
                    since = line.transactions
                    left.append(len(robot.hold()))
                    await robot.on_wire()
                    for servo_id, at in where.items():
                        sent = targets_sent(line, servo_id, since)
                        if sent and abs(units.position_to_degrees(sent[0]) - at) > NOT_A_GARBLE:
                            jumps.append((servo_id, at, units.position_to_degrees(sent[0])))
                    await robot.free()

    run_on_garbled_lines(main, line)
    assert jumps == []
    assert sum(left) < len(left)  # (most joints are held in most rounds: the rule leaves free only the unsettled)


def test_a_move_from_a_free_joint_just_turned_far_starts_where_it_now_is() -> None:
    # A free joint turned 90 degrees within a cycle (by hand, or a limb falling) reads far from the reading before:
    # not taken as where it is (a garble reads so too) until the next reading agrees.  A motion starting right
    # then began at the reading before the turn: its first target threw the joint 90 degrees back.
    line = VirtualLine([1], name="turned-then-moved", log_size=None)
    description = {"lines": {"main": {"port": "sim://turned-then-moved"}}, "joints": {"j1": {"line": "main", "id": 1}}}
    turned = units.degrees_to_position(90.0)
    first: list[float] = []

    async def main() -> None:
        with anyio.fail_after(2 * GUARD):
            async with open_robot(description, **FAST) as robot:  # ICS 3.5: it starts free
                await robot.read_pose()
                line.move_by_hand(1, turned)
                frame = robot.latest
                while frame is None or abs(frame.positions.get("j1", 0.0) - 90.0) > 1.0:  # its first turned reading
                    frame = await robot.wait_frame(frame.cycle + 1 if frame else 0)
                since = line.transactions
                await robot.move_to({"j1": 100.0}, duration=0.2)
                first.append(units.position_to_degrees(targets_sent(line, 1, since)[0]))

    run_on_garbled_lines(main, line)
    assert abs(first[0] - 90.0) < NOT_A_GARBLE, first


def test_a_garbled_position_reply_seen_again_in_the_next_frame_is_still_left_out() -> None:
    # A robot on two lines: each frame carries every line's newest cycle, so a line's garbled reading comes again,
    # with the same reply time, in the frame the other line's cycle brings.  Seen twice, it agreed with itself and
    # was taken as where its joint stands (Robot.positions, what hold() holds a free joint at).  The free servos
    # here stand still: each joint's position is where its servo is, but for a garble of a few degrees.
    line = VirtualLine([1, 2, 3, 4], name="garbled-of-two", faults="corrupt:0.05", seed=1, log_size=None)
    clean = VirtualLine([1], name="clean-of-two", log_size=None)
    description = {
        "lines": {"main": {"port": "sim://garbled-of-two"}, "other": {"port": "sim://clean-of-two"}},
        "joints": {
            **{f"j{i}": {"line": "main", "id": i} for i in range(1, 5)},  # the servo's whole range
            "other": {"line": "other", "id": 1},
        },
    }
    wrong: list[tuple[str, float, float]] = []

    async def main() -> None:
        with anyio.fail_after(2 * GUARD):
            async with open_robot(description, **FAST) as robot:  # ICS 3.5: every joint starts free
                await robot.read_pose()
                for _ in range(300):
                    await robot.wait_frame(robot.latest.cycle + 1 if robot.latest else 0)
                    taken = robot.positions
                    for servo in line.servos:
                        name, at = f"j{servo.servo_id}", units.position_to_degrees(servo.position)
                        if name in taken and abs(taken[name] - at) > NOT_A_GARBLE:
                            wrong.append((name, at, taken[name]))

    run_on_garbled_lines(main, line, clean)
    assert wrong == []


def test_read_pose_and_a_motion_from_a_joint_whose_readings_never_agree_raise_instead_of_waiting_for_ever() -> None:
    # A servo with a broken potentiometer answers every cycle, but no reading agrees with the one before: read_pose()
    # and a motion starting from the free joint waited for one that does, and the program hung.  They give up once
    # no turn explains the readings, naming the joint and its readings, and nothing is sent that moves a joint.
    line = VirtualLine([VirtualServo(1), VirtualServo(2, noisy=True)], name="never-agrees", log_size=None)
    description = {
        "lines": {"main": {"port": "sim://never-agrees"}},
        "joints": {"good": {"line": "main", "id": 1}, "broken": {"line": "main", "id": 2}},
    }

    async def main() -> None:
        with anyio.fail_after(2 * GUARD):
            async with open_robot(description, **FAST) as robot:  # ICS 3.5: both start free
                with pytest.raises(UnsettledReadings, match="broken") as caught:
                    await robot.read_pose()
                assert "good" not in str(caught.value) and set(caught.value.readings) == {"broken"}
                assert len(set(caught.value.readings["broken"])) > 1  # (its readings, as they came)
                since = line.transactions
                with pytest.raises(UnsettledReadings, match="broken"):
                    await robot.move_to({"good": 20.0, "broken": 20.0}, duration=0.1)
                await robot.on_wire()
                assert targets_sent(line, 1, since) == targets_sent(line, 2, since) == []
                assert robot.targets == {"good": None, "broken": None}

    run_on_garbled_lines(main, line)


def test_a_joint_whose_readings_never_agree_is_given_up_by_a_robot_that_takes_every_few_cycles() -> None:
    # A robot at its own pace takes each line's newest cycle, not every cycle: two readings it compares may be a few
    # reports apart.  The simulator's broken potentiometer must not agree with itself there either, or its readings,
    # far from where it is, were taken as where the joint is (read_pose() gave them, a motion started from them).
    line = VirtualLine([VirtualServo(1), VirtualServo(2, noisy=True)], name="never-agrees-paced", log_size=None)
    description = {
        "lines": {"main": {"port": "sim://never-agrees-paced"}},
        "joints": {"good": {"line": "main", "id": 1}, "broken": {"line": "main", "id": 2}},
    }

    async def main() -> None:
        with anyio.fail_after(2 * GUARD):
            async with open_robot(description) as robot:  # (its default pace: not every cycle of the line)
                with pytest.raises(UnsettledReadings, match="broken"):
                    await robot.read_pose()

    run_on_garbled_lines(main, line)


def test_a_joints_first_reading_at_the_open_is_not_where_hold_holds_it() -> None:
    # A joint's first reading has none before it to agree with, and was taken as it came: a garbled one (here a servo
    # whose readings jump) was where hold() right after the open held it, throwing the servo there at full speed.
    line = VirtualLine([VirtualServo(1), VirtualServo(2, noisy=True)], name="first-at-open", log_size=None)
    description = {
        "lines": {"main": {"port": "sim://first-at-open", "rate_hz": 25}},
        "joints": {"good": {"line": "main", "id": 1}, "broken": {"line": "main", "id": 2}},
    }

    async def main() -> None:
        with anyio.fail_after(2 * GUARD):
            async with open_robot(description, **FAST) as robot:  # ICS 3.5: both start free, read once
                since = line.transactions
                left = robot.hold()
                await robot.on_wire()
                assert "broken" in left and targets_sent(line, 2, since) == [], left
                await robot.fresh_replies(["good"], 2, agreed=True)  # (the good joint once read: held where it is)
                assert robot.hold() == {"broken": left["broken"]}

    run_on_garbled_lines(main, line)


def test_a_joints_first_reading_once_its_servo_answers_again_is_not_held_or_moved_from() -> None:
    # A servo that did not answer the open (unplugged) starts offline; plugged in, its first reading was taken as it
    # came, with none before it to agree with: a garbled one (here a servo whose readings jump) was where hold() held
    # it and where a motion started from.  It waits for the next reading to agree, as any free joint's does.
    line = VirtualLine([VirtualServo(1), VirtualServo(2, noisy=True)], name="first-after-offline", log_size=None)
    description = {
        "lines": {"main": {"port": "sim://first-after-offline", "rate_hz": 25}},
        "joints": {"good": {"line": "main", "id": 1}, "broken": {"line": "main", "id": 2}},
    }
    unplugged = line.remove_servo(2)

    async def main() -> None:
        with anyio.fail_after(2 * GUARD):
            async with open_robot(description, **FAST, probe_interval=0.01) as robot:
                await robot.read_pose()  # (the broken joint left out: it has not answered)
                line.add_device(unplugged)
                frame = await robot.wait_frame(0)
                while "broken" not in frame.positions:
                    frame = await robot.wait_frame(frame.cycle)
                since = line.transactions
                left = robot.hold(["broken"])
                await robot.on_wire()
                assert "broken" in left and targets_sent(line, 2, since) == [], left
                with pytest.raises(UnsettledReadings, match="broken"):
                    await robot.move_to({"broken": 10.0}, duration=0.1)
                await robot.on_wire()
                assert targets_sent(line, 2, since) == [] and unplugged.free

    run_on_garbled_lines(main, line)


def test_a_joint_target_of_none_without_allow_free_names_allow_free() -> None:
    rig = make_rig()

    async def body(robot: Robot) -> str:
        with pytest.raises(InvalidArgument) as caught:
            robot.set_targets({"neck": None})
        return str(caught.value)

    said = run_robot(rig, body)
    assert "allow_free=True" in said and "neck" in said, said
