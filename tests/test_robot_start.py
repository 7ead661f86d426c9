"""How a robot learns its starting pose: ICS 3.6 joints by the position read (nothing freed, nothing moved),
ICS 3.5 joints free unless the caller states their pose.  What went on the wire is read from the simulator's log."""

from __future__ import annotations

import errno
import functools
import itertools
import time
import traceback
from collections.abc import Awaitable, Callable
from typing import Any, TypeVar

import anyio
import pytest
from rich.console import Console

from ics35_async import (
    BusClosed,
    InvalidArgument,
    PortLost,
    PortNotFound,
    Robot,
    State,
    UnsafeOperation,
    open_bus,
    open_robot,
)
from ics35_async.cli._robot_view import joint_table
from ics35_async.errors import error_text
from ics35_async.protocol import FREE, ReadEeprom, ReadPosition
from ics35_async.robot import DescriptionError, Segment, Trajectory, startup
from ics35_async.sim import VirtualServo
from ics35_async.sim.virtual_servo import NO_REPLY
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
from tests.support.sim_servos import LosesPositionReplies, UnplugsWhenAsked, free_command
from tests.support.timing import FAST, GUARD, NO_TIMEOUTS, PATIENT

HALF_COUNT = 0.5 / (8000 / 270) + 1e-9


E = TypeVar("E", bound=BaseException)


def run_robot(rig: Rig, body: Any, **options: Any) -> Any:
    async def main() -> Any:
        with anyio.fail_after(GUARD):
            async with open_robot(rig.description, **{**FAST, **options}) as robot:
                return await body(robot)

    try:
        return anyio.run(main)
    finally:
        rig.close()


def torque_commands(rig: Rig, name: str) -> list[int]:
    spec = JOINTS[name]
    return list(commanded(rig.sim(spec["line"]), spec["id"]))


def test_a_standing_robot_of_ics36_servos_opens_without_freeing_or_moving_a_joint() -> None:
    rig = make_rig(ics36=[1, 2, 3])
    standing = {"neck": 20.0, "shoulder": -45.0, "elbow": 80.0, "hip": -10.0, "knee": -60.0}
    for name, deg in standing.items():
        servo = rig.servo(name)
        servo.move_by_hand(joint_position(JOINTS[name], deg))
        servo.command_position(servo.position)  # holding there, torque on: a robot standing

    async def body(robot: Robot) -> dict[str, float]:
        assert robot.start_modes == dict.fromkeys(JOINTS, "read")
        pose = await robot.read_pose()
        assert robot.targets == dict.fromkeys(JOINTS)  # nothing commanded yet
        return pose

    pose = run_robot(rig, body)
    assert pose == pytest.approx(standing, abs=HALF_COUNT)
    for name in JOINTS:
        assert torque_commands(rig, name) == [], name  # no position, no free command
        assert not rig.servo(name).free, name  # still holding


def test_a_motion_starts_from_the_pose_read() -> None:
    rig = make_rig(ics36=[1, 2, 3])
    rig.servo("knee").move_by_hand(joint_position(JOINTS["knee"], -80.0))

    async def body(robot: Robot) -> None:
        assert robot.untouched == set(JOINTS)  # torque as found, all of them
        await robot.move_to({"knee": 0.0}, duration=0.2)
        assert robot.untouched == set(JOINTS) - {"knee"}
        console = Console(record=True, width=120)
        console.print(joint_table(robot, "t", None))
        rows = {line.split()[0]: line for line in console.export_text().splitlines() if line.strip()}
        assert "as found" in rows["shoulder"] and "held" in rows["knee"]  # not "free": its torque is unknown

    run_robot(rig, body)
    sent = [joint_degrees(JOINTS["knee"], p) for p in torque_commands(rig, "knee")]
    assert sent[0] == pytest.approx(-80.0, abs=2.0)  # from where it was, not a jump from elsewhere
    assert all(-80.0 - HALF_COUNT <= d <= 0.0 + HALF_COUNT for d in sent)
    assert sent[-1] == pytest.approx(0.0, abs=HALF_COUNT)


def test_a_host_stall_before_a_motions_first_frame_does_not_skip_its_start() -> None:
    # The motion's clock starts with the first frame that carries it: a host that stalls (a loaded
    # machine, a garbage collection) between the call and that frame must not send the joint a
    # target already far along its path, a jump the servo makes at full speed.
    rig = make_rig(ics36=[1, 2, 3])
    rig.servo("knee").move_by_hand(joint_position(JOINTS["knee"], -80.0))

    async def body(robot: Robot) -> None:
        async with anyio.create_task_group() as tasks:
            tasks.start_soon(lambda: robot.move_to({"knee": 0.0}, duration=0.2))
            await anyio.sleep(0)  # the motion is planned...
            time.sleep(0.15)  # ...and the host stalls before its first frame

    run_robot(rig, body)
    sent = [joint_degrees(JOINTS["knee"], p) for p in torque_commands(rig, "knee")]
    assert sent[0] == pytest.approx(-80.0, abs=2.0)
    assert all(-80.0 - HALF_COUNT <= d <= 0.0 + HALF_COUNT for d in sent)
    assert sent[-1] == pytest.approx(0.0, abs=HALF_COUNT)


def test_ics35_joints_start_free_unless_their_pose_is_stated() -> None:
    rig = make_rig(ics36=[1])  # neck (upper 1) and hip (lower 1) speak ICS 3.6

    async def body(robot: Robot) -> None:
        await robot.read_pose()
        assert robot.start_modes == {
            "neck": "read",
            "shoulder": "stated",
            "elbow": "free",
            "hip": "read",
            "knee": "stated",
        }
        assert robot.targets["shoulder"] == 30.0 and robot.targets["elbow"] is None

    run_robot(rig, body, start_pose={"shoulder": 30.0, "knee": -5.0})
    for name, deg in (("shoulder", 30.0), ("knee", -5.0)):
        sent = torque_commands(rig, name)
        assert sent and set(sent) == {sent_position(JOINTS[name], deg)}, name  # held from the first command
    assert set(torque_commands(rig, "elbow")) == {0}  # ICS 3.5, not stated: read by freeing it
    assert torque_commands(rig, "neck") == torque_commands(rig, "hip") == []


def commands_to(rig: Rig, line: str, servo_id: int) -> list[str]:
    return [t.command for t in rig.sim(line).log_since(0) if t.servo_id == servo_id]


# What the open sends a present servo before the stream's first command: its EEPROM read, then the position-read
# probe: an ICS 3.6 servo answers it; an ICS 3.5 one stays silent twice around a parameter read it answers (the
# read the probe asks for, after the guard read a silent probe calls for).
PRESENT_ICS36 = ["read_eeprom", "read_position"]
PRESENT_ICS35 = ["read_eeprom", "read_position", "read_speed", "read_stretch", "read_position"]


@pytest.mark.filterwarnings("ignore:.*did not answer:ics35_async.robot.RobotWarning")
def test_an_absent_joint_costs_the_open_one_reply_allowance_and_the_watch_none() -> None:
    # Each read of a silent ID waits a whole allowance (an adapter's latency, --timeout): a robot with unplugged
    # legs must not wait several of them a joint.  The EEPROM read's silence and one short probe say the servo
    # is not there; the safety watch reads nothing of a servo never heard from (it has nothing to watch).
    rig = make_rig(ics36=[1])  # neck (upper 1) and hip (lower 1) speak ICS 3.6
    rig.upper.remove_servo(2)  # shoulder unplugged
    rig.lower.remove_servo(2)  # knee unplugged

    async def body(robot: Robot) -> None:
        pose = await robot.read_pose()  # (once the absent ones are offline)
        assert set(pose) == {"neck", "elbow", "hip"}
        assert robot.start_modes == {"neck": "read", "shoulder": "free", "elbow": "free", "hip": "read", "knee": "free"}
        for _ in range(3):  # a few telemetry rounds more
            await robot.wait_frame(robot.latest.cycle if robot.latest else 0)

    run_robot(rig, body, probe_interval=60.0)
    for line in ("upper", "lower"):
        # One full allowance, one short probe; then the stream starts with it offline, asking it nothing until its
        # first probe (not offline_after cycles of its whole allowance first).
        assert commands_to(rig, line, 2) == ["read_eeprom", "read_position"], line
        assert not [t for t in rig.sim(line).log_since(0) if t.command == "read_id"], line  # (others answered)
    # The servos that answer are checked as fully as ever.
    for line, servo_id, expected in (
        ("upper", 1, PRESENT_ICS36),
        ("upper", 3, PRESENT_ICS35),
        ("lower", 1, PRESENT_ICS36),
    ):
        sent = commands_to(rig, line, servo_id)
        assert sent[: len(expected)] == expected, (line, servo_id)
        assert {"read_temperature", "read_current"} <= set(sent), (line, servo_id)  # watched


@pytest.mark.filterwarnings("ignore:.*did not answer:ics35_async.robot.RobotWarning")
@pytest.mark.parametrize("check_limits", [True, False])
@pytest.mark.parametrize("start_free", [False, True])
def test_a_line_where_nothing_answers_costs_the_open_one_question_not_one_per_joint(
    check_limits: bool, start_free: bool
) -> None:
    # Two legs unplugged on their own line: each joint's EEPROM read and position probe waited a whole allowance
    # (nothing has answered there, so even a probe cannot wait less), then each was asked offline_after cycles
    # more at its whole allowance: at --timeout 1, about five seconds a joint.  After the first silence on a
    # line where nothing has answered, one ID read (which every servo on the line answers) asks them all; the
    # stream starts with them offline.
    rig = make_rig(ics36=[1])
    rig.description["joints"]["ankle"] = {"line": "lower", "id": 3}  # (no servo: the leg's third joint)
    for servo_id in (1, 2):
        rig.lower.remove_servo(servo_id)

    async def body(robot: Robot) -> None:
        assert robot.latest is not None and {"hip", "knee", "ankle"} <= robot.latest.offline  # from the first frame
        pose = await robot.read_pose()
        assert set(pose) == {"neck", "shoulder", "elbow"}
        assert [robot.start_modes[name] for name in ("hip", "knee", "ankle")] == ["free"] * 3
        if check_limits:
            assert any("hip, knee, ankle" in warning and "did not answer" in warning for warning in robot.warnings)

    run_robot(rig, body, probe_interval=60.0, check_limits=check_limits, start_free=start_free)
    first = "read_eeprom" if check_limits else "read_stretch" if start_free else "read_position"
    assert commands_to(rig, "lower", 1)[:1] == [first]
    if check_limits:  # (without it, the first joint's own probe is the whole allowance: see the docs)
        assert commands_to(rig, "lower", 1) == [first]
    assert commands_to(rig, "lower", 2) == commands_to(rig, "lower", 3) == []
    assert [t.command for t in rig.lower.log_since(0) if t.servo_id is None] == ["read_id"]
    # The line that answers is asked as fully as ever, and not with an ID read.
    assert commands_to(rig, "upper", 3)[:1] == [first]
    assert not [t for t in rig.upper.log_since(0) if t.servo_id is None]


@pytest.mark.filterwarnings("ignore:.*did not answer:ics35_async.robot.RobotWarning")
def test_a_robot_closing_free_frees_a_line_where_nothing_answers_without_waiting_an_allowance_a_joint() -> None:
    # The legs' line unplugged, the robot closed with on_close="free" (ics35 teach's q): each leg joint's free
    # waited the whole allowance for its reply, one after the other, though the open had found them all silent
    # (nothing had answered there to learn a shorter wait from).  The frees still go out, waited for briefly.
    rig = make_rig()
    rig.description["joints"]["ankle"] = {"line": "lower", "id": 3}  # (no servo: the leg's third joint)
    for servo_id in (1, 2):
        rig.lower.remove_servo(servo_id)
    legs = {"hip": 1, "knee": 2, "ankle": 3}
    allowance = PATIENT["adapter_latency"]

    async def main() -> tuple[Robot, float, int]:
        with anyio.fail_after(GUARD):
            async with open_robot(rig.description, on_close="free", probe_interval=60.0, **PATIENT) as robot:
                assert robot.latest is not None and set(legs) <= robot.latest.offline
                seq = rig.lower.transactions
                closing = time.monotonic()
            return robot, time.monotonic() - closing, seq

    try:
        robot, took, seq = anyio.run(main)
    finally:
        rig.close()
    assert [(t.servo_id, t.command) for t in rig.lower.log_since(seq)] == [(i, "free") for i in legs.values()]
    assert all(robot.targets[name] is None for name in JOINTS)  # (each was sent its free: targets say so)
    assert "joints hip, knee, ankle never answered" in robot.joints_left(), robot.joints_left()  # (still true)
    assert took < allowance / 2, took  # (three allowances before)


@pytest.mark.filterwarnings("ignore:.*did not answer:ics35_async.robot.RobotWarning")
def test_a_line_whose_first_joint_is_absent_is_asked_once_and_its_other_joints_as_fully_as_ever() -> None:
    # The ID read after the first silence: the others answer it (garbled, several at once), so the line is not
    # taken for empty and each of its joints is read and probed as before.
    rig = make_rig(ics36=[1])
    rig.lower.add_device(VirtualServo(3))
    rig.description["joints"]["ankle"] = {"line": "lower", "id": 3}
    rig.lower.remove_servo(1)  # the hip

    async def body(robot: Robot) -> None:
        assert set(await robot.read_pose()) == set(robot.joints) - {"hip"}
        assert robot.latest is not None and robot.latest.offline == {"hip"}

    run_robot(rig, body, probe_interval=60.0)
    assert [t.command for t in rig.lower.log_since(0) if t.servo_id is None] == ["read_id"]
    assert commands_to(rig, "lower", 1) == ["read_eeprom", "read_position"]
    for servo_id in (2, 3):  # (ICS 3.5 servos)
        assert commands_to(rig, "lower", servo_id)[: len(PRESENT_ICS35)] == PRESENT_ICS35, servo_id


@pytest.mark.filterwarnings("ignore:.*did not answer:ics35_async.robot.RobotWarning")
@pytest.mark.parametrize("targeted", [False, True])
def test_a_joint_absent_at_the_open_that_is_plugged_in_later_is_not_moved(targeted: bool) -> None:
    # Started offline, an absent joint is probed every probe_interval: plugged in, it is read where it stands
    # (freed, as a joint that did not answer starts), or, given a target meanwhile, held: never thrown there.
    rig = make_rig()
    knee = rig.lower.remove_servo(2)
    knee.move_by_hand(joint_position(JOINTS["knee"], -40.0))

    async def body(robot: Robot) -> None:
        await robot.read_pose()
        if targeted:
            robot.set_targets({"knee": 10.0})
        rig.lower.add_device(knee)
        while "knee" not in (robot.held if targeted else await robot.read_pose()):
            await robot.wait_frame(robot.latest.cycle if robot.latest else 0)
        if not targeted:
            assert (await robot.read_pose())["knee"] == pytest.approx(-40.0, abs=HALF_COUNT)
        else:
            assert robot.held == {"knee": "rejoined"}

    run_robot(rig, body, probe_interval=0.02)
    assert targets_sent(rig.lower, 2) == []  # never sent a position: freed or read only
    assert knee.position == joint_position(JOINTS["knee"], -40.0)


def joints_left_said(rig: Rig, **options: Any) -> dict[str, str]:
    """What ``open_robot(rig's robot, **options)``'s block says the joints were left in: before it is entered, once
    the robot has read its pose, and after its close (the rig closed afterwards)."""
    said: dict[str, str] = {}

    async def main() -> None:
        with anyio.fail_after(GUARD):
            block = open_robot(rig.description, **options, **FAST)
            said["before"] = block.joints_left()
            async with block as robot:
                await robot.read_pose()
                said["open"] = block.joints_left()
            said["closed"] = block.joints_left()

    try:
        anyio.run(main)
    finally:
        rig.close()
    return said


def test_a_stated_joint_moved_since_is_said_to_hold_its_last_target_not_its_stated_angle() -> None:
    # "joints shoulder, elbow hold their stated angles" after a move had taken them elsewhere.
    rig = make_rig()

    async def body(robot: Robot) -> tuple[str, str]:
        await robot.wait_frame(robot.latest.cycle if robot.latest else 0)
        before = robot.joints_left()
        await robot.move_to({"shoulder": 20.0}, duration=0.05)
        await robot.wait_frame(robot.latest.cycle if robot.latest else 0)
        return before, robot.joints_left()

    before, after = run_robot(rig, body, start_pose={"shoulder": 10.0, "elbow": 30.0})
    assert "joints shoulder, elbow hold their stated angles" in before, before
    assert "shoulder, elbow hold their last targets" in after and "stated" not in after, after


@pytest.mark.parametrize("on_close", ["hold", "free"])
def test_the_block_does_not_say_an_unplugged_servo_was_freed(on_close: str) -> None:
    # A leg unplugged as the robot opened: Ctrl-C then said its joints "were freed to read where they stand",
    # though no servo there heard a thing (plugged back, it would be free by powering up, not by the robot).
    rig = make_rig()
    rig.sim("lower").remove_servo(2)  # the knee
    said = joints_left_said(rig, on_close=on_close)
    for when in ("open", "closed"):
        freed = [part for part in said[when].split("; ") if "freed" in part]
        assert freed and all("knee" not in part for part in freed), said
        assert "joint knee never answered (whatever was sent to it went unheard)" in said[when], said


@pytest.mark.parametrize("on_close", ["hold", "free"])
def test_the_block_tells_what_an_open_left_each_joint_in_as_the_wire_shows(on_close: str) -> None:
    # What a program cut short as it opened (Ctrl-C) tells its person: which servos went limp, which were only read.
    rig = make_rig(ics36=[1])  # neck (upper 1) and hip (lower 1) speak ICS 3.6
    said = joints_left_said(rig, on_close=on_close, start_pose={"shoulder": 30.0})
    assert said["before"] == "no servo was sent anything (its lines were still being opened)"
    freed = sorted(name for name in JOINTS if 0 in torque_commands(rig, name))
    assert freed == (["elbow", "knee"] if on_close == "hold" else sorted(JOINTS))
    assert torque_commands(rig, "neck") == torque_commands(rig, "hip") == ([] if on_close == "hold" else [0])
    assert said["open"] == (
        "joints elbow, knee were freed to read where they stand; joint shoulder holds its stated angle; "
        "joints neck, hip were left as they were (only read)"
    )
    if on_close == "hold":
        assert said["closed"] == said["open"]
    else:  # (the shoulder: its stated angle, then the close's free)
        assert (
            said["closed"]
            == "joints elbow, knee were freed to read where they stand; joints neck, shoulder, hip were freed"
        )


@pytest.mark.filterwarnings("ignore:.*did not answer:ics35_async.robot.RobotWarning")
def test_the_block_of_a_robot_opened_with_start_free_says_every_joint_was_freed_to_be_read() -> None:
    # (ICS 3.6 joints too: Ctrl-C as teach opens must not say they were left as they were)
    rig = make_rig(ics36=[1])
    rig.sim("lower").remove_servo(2)  # the knee
    said = joints_left_said(rig, start_free=True)
    assert said["open"] == (
        "joints neck, shoulder, elbow, hip were freed to read where they stand; "
        "joint knee never answered (whatever was sent to it went unheard)"
    )


class DeafToTheFree(VirtualServo):
    """A servo that answers reads but whose reply to the free command never gets back (lost on the line)."""

    def handle(self, command: Any) -> Any:
        reply = super().handle(command)
        return NO_REPLY if free_command(command) else reply


@pytest.mark.parametrize("start_free", [False, True])
def test_a_joint_that_answered_the_opens_reads_is_not_said_never_to_have_answered(start_free: bool) -> None:
    # Opened with start_free, the open's reads are its EEPROM read: a joint whose free went unanswered (Ctrl-C before
    # its first reply) was said never to have answered, though it had.
    rig = make_rig()
    rig.lower.remove_servo(2)
    rig.lower.add_device(DeafToTheFree(2))  # the knee

    opened: list[int] = []

    async def main() -> str:
        with anyio.fail_after(GUARD):
            block = open_robot(rig.description, start_free=start_free, offline_after=1000, **FAST)
            async with block as robot:
                opened.append(rig.lower.transactions)
                await robot.wait_frame(robot.latest.cycle if robot.latest else 0)
                return block.joints_left()

    try:
        said = anyio.run(main)
    finally:
        rig.close()
    assert said == "joints neck, shoulder, elbow, hip, knee were freed to read where they stand"
    # The open waits for one more reading of each joint read in its first frame, not for a joint that never answered
    # (it waited until the knee went offline, 1,000 cycles here).
    assert opened[0] < 100, opened


@pytest.mark.parametrize(
    ("pose", "phrase"),
    [
        ({"tail": 0.0}, "unknown joint(s): tail"),
        ({"neck": 99.0}, "outside its limits"),
        ([("neck", 0.0)], "mapping"),
    ],
)
def test_a_bad_start_pose_is_refused_before_anything_is_sent(pose: Any, phrase: str) -> None:
    rig = make_rig()

    async def main() -> None:
        async with open_robot(rig.description, start_pose=pose, **FAST):
            pass

    try:
        with pytest.raises(InvalidArgument, match=phrase.replace("(", r"\(").replace(")", r"\)")):
            anyio.run(main)
        assert rig.upper.transactions == rig.lower.transactions == 0
    finally:
        rig.close()


def test_the_blocking_robot_takes_a_start_pose_and_tells_the_start_modes() -> None:
    from ics35_async import blocking

    rig = make_rig(ics36=[2, 3])
    try:
        with blocking.open_robot(rig.description, start_pose={"neck": 0.0}, **FAST) as robot:
            assert robot.start_modes == {
                "neck": "stated",
                "shoulder": "read",
                "elbow": "read",
                "hip": "free",
                "knee": "read",
            }
    finally:
        rig.close()


def test_a_robot_used_after_its_block_ended_says_it_is_closed_at_once() -> None:
    # A helper task can outlive the `async with open_robot(...)` block: every call then fails at once
    # with BusClosed (they waited forever for a frame, or set targets nothing would ever send).
    rig = make_rig(ics36=[1, 2, 3])
    wave = {"format": "ics35-motion", "version": 1, "keyframes": [{"time": 0.5, "pose": {"neck": 10}}]}

    async def main() -> None:
        with anyio.fail_after(GUARD):
            async with open_robot(rig.description, **FAST) as robot:
                robot.hold()
                await robot.wait_frame(0)
            calls: list[tuple[str, Any]] = [
                ("move_to", lambda: robot.move_to({"neck": 10}, duration=0.2)),
                ("read_pose", robot.read_pose),
                ("play", lambda: robot.play(wave)),
                ("free", robot.free),
                ("on_wire", robot.on_wire),
                ("wait_frame", lambda: robot.wait_frame(0)),
                ("stop", robot.stop),
                ("run", lambda: robot.run(Trajectory([Segment(0.0, 0.2, {"neck": 0.0}, {"neck": 5.0}, "linear")]))),
            ]
            for name, call in calls:
                with anyio.fail_after(2), pytest.raises(BusClosed, match="robot is closed"):
                    await call()
                    pytest.fail(name)
            async with robot.stream() as stream:
                with anyio.fail_after(2), pytest.raises(BusClosed, match="robot is closed"):
                    await stream.next_frame()
            with pytest.raises(BusClosed, match="robot is closed"):
                robot.hold()
            with pytest.raises(BusClosed, match="robot is closed"):
                robot.set_targets({"neck": 5})

    try:
        anyio.run(main)
    finally:
        rig.close()


def test_a_motion_still_running_when_the_block_ends_fails_with_bus_closed() -> None:
    rig = make_rig(ics36=[1, 2, 3])
    outcome: list[BaseException] = []

    async def main() -> None:
        with anyio.fail_after(GUARD):
            async with anyio.create_task_group() as tasks, open_robot(rig.description, **FAST) as robot:
                robot.hold()

                async def slow_move() -> None:
                    try:
                        await robot.move_to({"neck": 30}, duration=30.0)
                    except BusClosed as exc:
                        outcome.append(exc)

                tasks.start_soon(slow_move)
                await robot.wait_frame(robot.latest.cycle + 3 if robot.latest else 3)

    try:
        anyio.run(main)
    finally:
        rig.close()
    assert len(outcome) == 1 and "robot is closed" in str(outcome[0])


def test_a_task_commanding_a_joint_while_the_block_closes_cannot_keep_it_from_going_free() -> None:
    # on_close="free" with a controller task that outlives the block: its commands are refused from the
    # moment the block ends, so the free each line's stream sends as it closes is the last command every joint gets.
    rig = make_rig(ics36=[1, 2, 3])
    refused: list[BusClosed] = []

    async def main() -> None:
        with anyio.fail_after(GUARD):
            opening = open_robot(rig.description, on_close="free", **FAST)
            async with anyio.create_task_group() as tasks, opening as robot:
                robot.hold()

                async def controller() -> None:
                    try:
                        while True:
                            await robot.wait_frame(robot.latest.cycle if robot.latest else 0)
                            robot.set_targets({"neck": 10.0})
                    except BusClosed as exc:
                        refused.append(exc)

                tasks.start_soon(controller)
                for _ in range(5):
                    await robot.wait_frame(robot.latest.cycle if robot.latest else 0)

    try:
        anyio.run(main)
    finally:
        rig.close()
    assert refused and "robot is closed" in str(refused[0])
    assert all(rig.servo(name).free for name in JOINTS), {n: rig.servo(n).target for n in JOINTS}


@pytest.mark.parametrize("moving", [False, True])
def test_on_close_free_frees_the_other_lines_joints_when_one_line_is_lost(moving: bool) -> None:
    # A robot builder's finding: the lower line's adapter pulled, the block ended with PortLost, and the upper
    # line's joints kept holding (mid-motion targets included): the robot's own free at the close then waited
    # on its frames, which had ended with the lost line.
    rig = make_rig(ics36=[1, 2, 3], realtime=True)  # real time: the close can come before the next cycle
    tables: list[dict[str, str]] = []

    async def main() -> None:
        with anyio.fail_after(GUARD):
            async with open_robot(rig.description, on_close="free", **PATIENT) as robot:
                robot.hold()
                await robot.on_wire()
                try:
                    async with anyio.create_task_group() as tasks:
                        if moving:
                            tasks.start_soon(robot.move_to, {"neck": 30.0, "shoulder": -60.0, "hip": 20.0}, 2.0)
                        await anyio.sleep(0.2)
                        rig.lower.unplug()
                        while True:  # the robot's frames end with the lost line: PortLost
                            await robot.wait_frame(robot.latest.cycle if robot.latest else 0)
                except* PortLost:
                    # The CLI's live table names the lost line's joints only (it said LINE LOST for all).
                    console = Console(record=True, width=120)
                    console.print(joint_table(robot, "t", None, lost=True))
                    rows = {line.split()[0]: line for line in console.export_text().splitlines() if line.strip()}
                    tables.append(rows)
                    raise PortLost("the lower line") from None

    run_to_the_lost_line(rig, main)
    upper = [name for name, spec in JOINTS.items() if spec["line"] == "upper"]
    assert all(rig.servo(name).free for name in upper), {n: rig.servo(n).target for n in upper}
    for name, spec in JOINTS.items():
        assert ("LINE LOST" in tables[0][name]) == (spec["line"] == "lower"), tables[0][name]


def frees_since(rig: Rig, marks: dict[str, int]) -> dict[str, int]:
    """How many free commands each joint's servo got on the wire from ``marks`` (each line's log seq) on."""
    return {
        name: list(commanded(rig.sim(spec["line"]), spec["id"], marks[spec["line"]])).count(0)
        for name, spec in JOINTS.items()
    }


@pytest.mark.parametrize(
    ("ending", "backend"),
    [(ending, "asyncio") for ending in ("block ends", "mid-motion", "cancelled", "line came back")]
    + [("block ends", "trio"), ("cancelled", "trio")],
)
def test_on_close_free_sends_every_joint_one_free(ending: str, backend: str) -> None:
    # The robot's close-out freed every joint through the streams' cycles and each line's stream then freed
    # its servos again as it closed: every servo got its free several times (a cancelled block: free after
    # free for two seconds), wire time spent at the moment the robot is being stopped, and doubled traffic
    # in a sniff.  Every joint holds a target before the end, so each free counted is one sent for the close.
    trio = backend == "trio"
    rig = make_rig(ics36=[1, 2, 3], realtime=trio)  # (under trio the buses take their anyio driver: real time)
    marks: dict[str, int] = {}
    closed: list[Robot] = []

    async def main() -> None:
        with anyio.fail_after(GUARD), anyio.CancelScope() as scope:
            timing = NO_TIMEOUTS if trio else FAST
            opening = open_robot(rig.description, on_close="free", reconnect=ending == "line came back", **timing)
            async with anyio.create_task_group() as tasks, opening as robot:
                robot.hold()
                await robot.on_wire()
                if ending == "mid-motion":

                    async def move() -> None:
                        with pytest.raises(BusClosed):  # the block's end ends it
                            await robot.move_to({"neck": 30.0, "hip": 20.0, "knee": -50.0}, duration=30.0)

                    tasks.start_soon(move)
                    await robot.wait_frame(robot.latest.cycle + 3 if robot.latest else 3)
                if ending == "line came back":
                    rig.lower.unplug(replug_after=0.05)
                    while not (await robot.wait_frame(robot.latest.cycle if robot.latest else 0)).held:
                        pass  # the lower line is back, its joints held (sent nothing until a target is set)
                marks.update(upper=rig.upper.transactions, lower=rig.lower.transactions)
                closed.append(robot)
                if ending == "cancelled":  # as Ctrl-C does: the body cancelled, the close runs all the same
                    scope.cancel()
                    await anyio.sleep_forever()

    try:
        anyio.run(main, backend=backend)
    finally:
        rig.close()
    assert frees_since(rig, marks) == dict.fromkeys(JOINTS, 1)
    assert all(rig.servo(name).free for name in JOINTS), {n: rig.servo(n).target for n in JOINTS}
    # The closed robot's snapshot says so too.  (Under trio the lines run in real time: on a loaded machine the
    # close's time bound can run out with a free's reply still due, and the snapshot then keeps that joint's
    # target, as documented: its servo "may still hold".  The wire, checked above, shows the free went out.)
    kept = {name: target for name, target in closed[0].targets.items() if target is not None}
    assert not kept or trio, kept


def test_a_line_still_lost_at_the_close_keeps_its_joints_targets_in_the_closed_robots_snapshot() -> None:
    # on_close="free" with the lower line's port gone and not back: its free never goes out, its servos
    # hold; the closed robot's targets must say so (they said free), while the upper line's joints are free.
    rig = make_rig(ics36=[1, 2, 3])
    closed: list[Robot] = []

    async def main() -> None:
        with anyio.fail_after(GUARD):
            async with open_robot(rig.description, on_close="free", reconnect=True, **FAST) as robot:
                robot.hold()
                await robot.on_wire()
                held = dict(robot.targets)
                rig.lower.unplug(replug_after=60.0)
                lower_bus = robot.group["lower"]
                while lower_bus.state is not State.LOST:
                    await lower_bus.state_change()
                closed.append(robot)
        lower = {name for name, spec in JOINTS.items() if spec["line"] == "lower"}
        assert lower and all(held[name] is not None for name in lower)
        assert closed[0].targets == {name: held[name] if name in lower else None for name in JOINTS}

    try:
        anyio.run(main)
        assert all(rig.servo(name).free == (JOINTS[name]["line"] != "lower") for name in JOINTS)
    finally:
        rig.close()


def rig_whose_lower_line_is_pulled_at(what: Any, replug_after: float, *, ics36: bool = True) -> Rig:
    """The rig (of ICS 3.6 servos, or 3.5), its lower line pulled away (once) as the knee's servo hears ``what``."""
    rig = make_rig(ics36=[1, 2, 3] if ics36 else [])
    knee = rig.servo("knee")
    puller = UnplugsWhenAsked(JOINTS["knee"]["id"], what, replug_after=replug_after, ics36=ics36)
    rig.lower.remove_device(knee)
    rig.lower.add_device(puller)
    puller.line = rig.lower
    return rig


def lower_line_only(rig: Rig) -> Rig:
    description = rig.description
    description["lines"].pop("upper")
    description["joints"] = {name: spec for name, spec in description["joints"].items() if spec["line"] == "lower"}
    return rig


def test_a_holding_ics36_joint_whose_probe_replies_were_lost_starts_read_not_free() -> None:
    # Two position reads unanswered around an answered parameter read: the protocol probe takes the servo for
    # ICS 3.5, whose joint starts free: a standing robot's ICS 3.6 joint went limp as the robot opened.
    rig = make_rig(ics36=[1, 2, 3])
    knee = LosesPositionReplies(JOINTS["knee"]["id"], lost=2)
    rig.lower.remove_device(rig.servo("knee"))
    rig.lower.add_device(knee)
    knee.command_position(joint_position(JOINTS["knee"], -10.0))  # (holding)

    async def body(robot: Robot) -> dict[str, str]:
        return dict(robot.start_modes)

    assert run_robot(rig, body) == dict.fromkeys(JOINTS, "read")
    assert FREE not in torque_commands(rig, "knee") and not knee.free


@pytest.mark.parametrize("what", [ReadEeprom, ReadPosition], ids=["limits", "position-reads"])
def test_an_open_with_reconnect_rides_out_a_port_lost_during_its_reads(what: type) -> None:
    # A robot builder who asked for reconnect=True had the open raise PortLost when a line's port went away
    # (a USB adapter re-enumerating as the servos power up) while the open read the servos.
    rig = rig_whose_lower_line_is_pulled_at(what, replug_after=0.1)

    async def body(robot: Robot) -> tuple[dict[str, str], list[str], int]:
        return dict(robot.start_modes), list(robot.warnings), robot.group["lower"].stats.reconnects

    modes, warned, reconnects = run_robot(rig, body, reconnect=True)
    assert reconnects == 1
    assert modes == dict.fromkeys(JOINTS, "read")  # as an undisturbed open: the reads cut short were made again
    assert warned == []
    assert FREE not in torque_commands(rig, "knee")


def test_an_open_with_reconnect_whose_port_stays_away_says_it_was_lost_while_opening(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(startup, "LOST_AT_OPEN", 0.3)
    rig = rig_whose_lower_line_is_pulled_at(ReadEeprom, replug_after=60.0)

    async def body(robot: Robot) -> None:
        raise AssertionError("opened without its lower line")

    with pytest.raises(PortLost, match=r", while the robot was opening: line lower \(sim://[^)]+\) not back within "):
        run_robot(rig, body, reconnect=True)


@pytest.mark.parametrize("replug_after", [0.1, 60.0], ids=["back", "away"])
def test_an_open_with_reconnect_whose_every_line_is_lost_as_its_streams_start_waits_a_bounded_while(
    monkeypatch: pytest.MonkeyPatch, replug_after: float
) -> None:
    # The ICS 3.5 joints start free (their only position read): the line is pulled at that first free, and with
    # no line left no frame came: the open waited for ever.
    monkeypatch.setattr(startup, "LOST_AT_OPEN", 0.5)
    rig = lower_line_only(rig_whose_lower_line_is_pulled_at(free_command, replug_after, ics36=False))

    async def body(robot: Robot) -> dict[str, str]:
        return dict(robot.start_modes)

    if replug_after < startup.LOST_AT_OPEN:
        assert run_robot(rig, body, reconnect=True) == {"hip": "free", "knee": "free"}
    else:
        with pytest.raises(PortLost, match=r"every line's port was lost, while the robot was opening: line lower "):
            run_robot(rig, body, reconnect=True)


def test_an_open_without_reconnect_raises_a_port_lost_during_its_reads_at_once() -> None:
    rig = rig_whose_lower_line_is_pulled_at(ReadEeprom, replug_after=60.0)

    async def body(robot: Robot) -> None:
        raise AssertionError("opened without its lower line")

    with pytest.raises(PortLost) as lost:
        run_robot(rig, body)
    assert "while the robot was opening" not in str(lost.value)


def test_a_robot_or_bus_used_without_async_with_says_how_to_open_it() -> None:
    rig = make_rig()

    async def main() -> None:
        opener = open_robot(rig.description, **FAST)
        with pytest.raises(AttributeError, match=r"async with open_robot\(\.\.\.\) as robot.*'move_to'"):
            opener.move_to({"neck": 0.0}, duration=0.1)  # type: ignore[attr-defined]
        with (
            pytest.raises(TypeError, match=r"async with open_robot\(\.\.\.\) as robot.*blocking\.open_robot"),
            opener,  # type: ignore[attr-defined]
        ):
            pass
        with pytest.raises(TypeError, match=r"async with open_robot\(\.\.\.\) as robot"):
            await opener  # type: ignore[misc]
        bus = open_bus(f"sim://{rig.upper.name}", **FAST)
        with pytest.raises(TypeError, match=r"async with open_bus\(\.\.\.\) as bus.*blocking\.open_bus"), bus:
            pass
        async with opener as robot:  # the same opener still opens the robot: nothing was started
            await robot.move_to({"neck": 5.0}, duration=0.05)
        assert rig.upper.transactions > 0

    try:
        anyio.run(main)
    finally:
        rig.close()


@pytest.mark.parametrize("backend", ["asyncio", "trio"])
def test_a_stop_in_the_body_s_finally_runs_when_a_scope_around_the_robot_is_cancelled(backend: str) -> None:
    # run()'s Ctrl-C cancels a scope around the whole program, the robot's block included: its cycles were
    # cancelled with it, and a shielded robot.stop() in the body's finally (what the docs advise after a
    # cancellation) waited for frames that never came, for ever.  The stop must slow the joint to rest.
    trio = backend == "trio"
    rig = make_rig(realtime=trio, ics36=ALL_ICS36)
    stopped: list[bool] = []
    marks: dict[str, int] = {}
    under_way: list[float] = []  # the joint's target as the scope is cancelled

    async def main() -> None:
        with anyio.fail_after(GUARD), anyio.CancelScope() as outer:
            async with open_robot(rig.description, **(NO_TIMEOUTS if trio else FAST)) as robot:
                try:
                    async with anyio.create_task_group() as tasks:
                        # (Slow, so that the joint is still on its way when the scope is cancelled: a loaded
                        # machine stalled a 2 s move's task past its end once, and its first target was the goal.)
                        tasks.start_soon(functools.partial(robot.move_to, {"neck": 50.0}, 10.0, profile="linear"))
                        while (robot.targets["neck"] or -10.0) < -5.0:  # (the neck starts at -10 degrees)
                            await robot.wait_frame(robot.latest.cycle if robot.latest else 0)
                        marks["upper"] = rig.upper.transactions
                        under_way.append(robot.targets["neck"] or 0.0)
                        outer.cancel()  # as run() does at Ctrl-C
                        await anyio.sleep_forever()
                finally:
                    with anyio.CancelScope(shield=True), anyio.fail_after(GUARD):
                        await robot.stop(ramp=0.3)
                        stopped.append(True)

    try:
        anyio.run(main, backend=backend)
    finally:
        rig.close()
    assert stopped == [True]
    assert under_way and under_way[0] < 50.0, under_way  # (what this test is about: a joint still moving)
    sent = [joint_degrees(JOINTS["neck"], p) for p in sent_positions(rig, marks["upper"])]
    steps = [b - a for a, b in itertools.pairwise(sent)]
    assert sent and max(sent) < 50.0  # short of the target: slowed to rest, not carried on to it
    assert steps and steps[-1] <= max(steps)  # (slowing, not cut off at full speed)


def run_to_the_lost_line(rig: Rig, main: Callable[[], Awaitable[None]]) -> None:
    """Run ``main``, which ends raising the lost line's PortLost (its checks done inside), then close ``rig``."""
    try:
        with pytest.raises(PortLost):
            anyio.run(main)
    finally:
        rig.close()


def sent_positions(rig: Rig, since: int) -> list[int]:
    return [p for p in commanded(rig.upper, JOINTS["neck"]["id"], since) if p]


def test_calls_after_a_lost_line_each_raise_its_error_with_their_own_traceback() -> None:
    # The robot (and its streams) raised the one PortLost they keep at every call after the line was lost,
    # each raise adding that call's frames: the traceback a program printed named every earlier call, and a
    # loop retrying grew it without end.
    rig = make_rig()
    lengths: list[int] = []

    async def main() -> None:
        with anyio.fail_after(GUARD):
            async with open_robot(rig.description, **FAST) as robot:
                rig.lower.unplug()
                for _ in range(10):
                    for call in (robot.read_pose, functools.partial(robot.move_to, {"neck": 1.0}, 0.1)):
                        with pytest.raises(PortLost) as lost:
                            await call()
                        lengths.append(len(traceback.extract_tb(lost.value.__traceback__)))
                raise PortLost("the lower line") from None

    run_to_the_lost_line(rig, main)
    assert len(lengths) == 20 and max(lengths) <= 12, lengths


def test_after_a_lost_line_targets_that_power_a_joint_are_refused_and_freeing_still_goes_out() -> None:
    # A robot builder's control loop of set_targets() went on after one line's adapter was pulled (no
    # reconnect): the robot's frames and its safety watch had ended with the lost line, yet each pass still
    # drove the other line's joints, unwatched, and nothing told the loop; stop() returned with nothing ramped.
    rig = make_rig(safety={"max_temperature_c": 60, "action": "free"})
    refused: list[str] = []

    async def main() -> None:
        with anyio.fail_after(GUARD):
            async with open_robot(rig.description, start_pose={"neck": 0.0, "hip": 0.0}, **FAST) as robot:
                rig.lower.unplug()
                with pytest.raises(PortLost):
                    await robot.read_pose()
                since = rig.upper.log[-1].seq + 1
                for call in (
                    functools.partial(robot.set_targets, {"neck": 30.0}),
                    functools.partial(robot.set_targets, {"neck": 30.0, "shoulder": None}, allow_free=True),
                    robot.hold,
                    functools.partial(robot.stream().set_target, "neck", 30.0),
                ):
                    with pytest.raises(PortLost) as lost:
                        call()
                    refused.append(str(lost.value))
                with pytest.raises(PortLost) as lost:
                    await robot.stop()  # (no frames: nothing to ramp by)
                refused.append(str(lost.value))
                assert robot.targets["neck"] == 0.0 and robot.targets["shoulder"] is None  # nothing applied
                # Freeing is still allowed: the line left sends it (the call then says the other is lost).
                with pytest.raises(PortLost):
                    await robot.free(["neck"])
                assert robot.targets["neck"] is None
                with anyio.fail_after(GUARD):
                    while FREE not in commanded(rig.upper, JOINTS["neck"]["id"], since):
                        await anyio.sleep(0.01)
                assert targets_sent(rig.upper, JOINTS["neck"]["id"], since) == []  # never sent 30 degrees
                raise PortLost("the lower line") from None

    run_to_the_lost_line(rig, main)
    assert len(refused) == 5 and all("lost" in message for message in refused), refused


@pytest.mark.filterwarnings("ignore:.*did not answer:ics35_async.robot.RobotWarning")
@pytest.mark.parametrize("check_limits", [True, False])
def test_start_free_opens_without_protocol_probes_and_reads_every_joint_by_its_free(check_limits: bool) -> None:
    # A program that frees every joint it opens (teach, calibrate) has no use for the protocol probe: the free
    # command reads the position on ICS 3.5 and ICS 3.6 alike, and an ICS 3.5 joint's read once more cost the open
    # a whole reply allowance each.  An unplugged joint is still asked once, and starts offline.
    rig = make_rig(ics36=[1])  # neck (upper 1) and hip (lower 1) speak ICS 3.6
    rig.lower.remove_servo(2)  # knee unplugged
    where = {"neck": 20.0, "shoulder": -45.0, "elbow": 80.0, "hip": -10.0}
    for name, deg in where.items():
        rig.servo(name).move_by_hand(joint_position(JOINTS[name], deg))

    async def body(robot: Robot) -> tuple[dict[str, float], dict[str, str], frozenset[str]]:
        assert robot.latest is not None
        offline = robot.latest.offline  # (the first frame's)
        return await robot.read_pose(), dict(robot.start_modes), offline

    pose, modes, offline = run_robot(rig, body, start_free=True, check_limits=check_limits, probe_interval=60.0)
    assert pose == pytest.approx(where, abs=HALF_COUNT)
    assert modes == dict.fromkeys(JOINTS, "free")
    assert offline == {"knee"}
    first = "read_eeprom" if check_limits else "read_stretch"  # (the one read that tells a servo is there)
    for name in where:
        spec = JOINTS[name]
        sent = commands_to(rig, spec["line"], spec["id"])
        assert sent[:2] == [first, "free"], (name, sent)
        assert "read_position" not in sent, (name, sent)
    assert commands_to(rig, "lower", 2) == [first]  # one allowance, then offline: asked nothing more


def test_start_free_with_a_start_pose_holds_the_stated_joints_and_frees_the_others() -> None:
    rig = make_rig(ics36=[1])

    async def body(robot: Robot) -> dict[str, str]:
        await robot.read_pose()
        return dict(robot.start_modes)

    modes = run_robot(rig, body, start_free=True, start_pose={"knee": -5.0})
    assert modes == {**dict.fromkeys(JOINTS, "free"), "knee": "stated"}
    sent = torque_commands(rig, "knee")
    assert sent and set(sent) == {sent_position(JOINTS["knee"], -5.0)}
    assert set(torque_commands(rig, "neck")) == {FREE}  # ICS 3.6, freed all the same


@pytest.mark.parametrize("value", ["yes", 1])
def test_start_free_must_be_a_bool(value: Any) -> None:
    rig = make_rig()

    async def main() -> None:
        async with open_robot(rig.description, start_free=value, **FAST):
            pass

    try:
        with pytest.raises(InvalidArgument, match="start_free"):
            anyio.run(main)
        assert not rig.upper.log_since(0) and not rig.lower.log_since(0)
    finally:
        rig.close()


def open_refused(lower_port: str, error: type[E], **options: Any) -> tuple[E, Rig]:
    """A two-line robot whose lower line's port is ``lower_port``, opened with ``options``: the ``error`` its open
    raises (at once: no wait), and the rig, closed."""
    rig = make_rig()
    rig.description["lines"]["lower"]["port"] = lower_port

    async def main() -> None:
        with anyio.fail_after(GUARD):
            async with open_robot(rig.description, **FAST, **options):
                pass

    try:
        with pytest.raises(error) as refused:
            anyio.run(main)
    finally:
        rig.close()
    return refused.value, rig


def test_a_line_whose_port_is_missing_is_named_by_the_robots_line(tmp_path: Any) -> None:
    # A robot of two lines, one adapter unplugged: the port's own words alone ("no serial port at ...") did not say
    # which line of the robot file it was.
    missing = str(tmp_path / "nothing" / "lower")
    refused, rig = open_refused(missing, PortNotFound)
    said = error_text(refused)
    assert said.startswith("<mapping>: line lower: no serial port at "), said
    assert missing in said and refused.errno == errno.ENOENT
    assert "reconnecting" not in said  # (opened without reconnect=True: nothing to say of it)
    assert rig.upper.transactions == 0  # (the upper line, opened first, was closed without a word sent)


def test_a_line_whose_port_is_missing_with_reconnect_says_reconnecting_does_not_wait_for_it(tmp_path: Any) -> None:
    # A robot builder's finding: open_robot(..., reconnect=True) with one adapter not plugged in yet failed at once,
    # saying only "no serial port", where reconnect=True led them to expect a wait for it: it rides out a port lost
    # once its line is open (during the open too), not one missing as the robot opens.
    refused, _ = open_refused(str(tmp_path / "nothing" / "lower"), PortNotFound, reconnect=True)
    said = error_text(refused)
    assert said.startswith("<mapping>: line lower: no serial port at "), said
    assert said.endswith(
        "; reconnecting rides out a port lost once the bus is open, not one missing as it opens: plug the adapter"
        " in, then open it again"
    ), said
    assert refused.errno == errno.ENOENT
    assert refused.may_be_plugged_in  # (kept through the robot's words for its line)
    # A misnamed port (ttyUSB0 for /dev/ttyUSB0) is no adapter to plug in: its own hint only.
    misnamed, _ = open_refused("ttyUSB0", PortNotFound, reconnect=True)
    said = error_text(misnamed)
    assert "/dev/ttyUSB0" in said and "plug the adapter in" not in said and not misnamed.may_be_plugged_in, said


def test_a_line_whose_port_is_refused_as_written_is_named_by_the_robots_line() -> None:
    # A port the open refuses as written (a bridge URL without its TCP port): the port's own words alone did not
    # say which line of the robot file it was.
    refused, rig = open_refused("socket://legs-pi", InvalidArgument)
    assert str(refused).startswith("<mapping>: line lower: "), refused
    assert rig.upper.transactions == 0  # (the upper line, opened first, was closed without a word sent)


def test_a_sim_port_the_simulator_refuses_is_named_by_its_key_before_a_line_opens() -> None:
    # A misspelt sim:// option was refused only as the lines opened, the ones before it opened first; the
    # simulator's own check refuses it as the description is read, naming the key.
    refused, _ = open_refused("sim://robot-start-typo?ids=1-3&realtme=1", DescriptionError)
    assert str(refused).startswith("<mapping>: lines.lower.port: "), refused
    assert "sim URL: unknown option 'realtme'" in str(refused), refused


@pytest.mark.filterwarnings("ignore:.*did not answer:ics35_async.robot.RobotWarning")
def test_each_fault_logged_names_its_lines_port(caplog: pytest.LogCaptureFixture) -> None:
    # `ics35 -v` on a robot of two lines: "read_position to ID 1: no reply" alone could be either line's ID 1.
    rig = make_rig()
    rig.lower.remove_servo(JOINTS["hip"]["id"])
    ports = {name: line["port"] for name, line in rig.description["lines"].items()}

    async def body(robot: Robot) -> None:
        await robot.read_pose()

    with caplog.at_level("DEBUG", logger="ics35_async.faults"):
        run_robot(rig, body)
    said = [r.getMessage() for r in caplog.records if r.name == "ics35_async.faults"]
    hip = f"read_eeprom to ID {JOINTS['hip']['id']}: no reply"  # (the neck, ID 1 too, answers it: ICS 3.5 the probe)
    assert said and all(m.startswith((f"{ports['upper']}: ", f"{ports['lower']}: ")) for m in said), said
    assert [m for m in said if hip in m] and all(m.startswith(f"{ports['lower']}: ") for m in said if hip in m), said


@pytest.mark.parametrize("asks", ["function", "coroutine"])
def test_a_start_free_not_confirmed_ends_the_open_with_no_joint_freed_or_moved(asks: str) -> None:
    # ics35 play freed a standing humanoid's ICS 3.5 joints to read them before a word was said: the open asks the
    # program's confirm_start_free first, naming the joints about to start free (not an ICS 3.6 joint, read
    # without freeing, nor a stated one), and a no ends it with nothing freed or moved.
    rig = make_rig(ics36=[1])  # neck and hip speak ICS 3.6
    for name in JOINTS:
        servo = rig.servo(name)
        servo.command_position(servo.position)  # a robot standing: every servo holds
    asked: list[list[str]] = []

    def confirm(joints: list[str]) -> bool:
        asked.append(joints)
        return False

    async def confirm_later(joints: list[str]) -> bool:
        await anyio.sleep(0)
        return confirm(joints)

    async def body(robot: Robot) -> None:
        raise AssertionError("opened")

    with pytest.raises(UnsafeOperation, match="shoulder, elbow would start free") as refused:
        run_robot(
            rig, body, start_pose={"knee": 0.0}, confirm_start_free=confirm if asks == "function" else confirm_later
        )
    assert "no joint was freed or moved" in str(refused.value)
    assert asked == [["shoulder", "elbow"]]
    for name in JOINTS:
        assert torque_commands(rig, name) == [], name  # no position, no free command
        assert not rig.servo(name).free, name


@pytest.mark.parametrize("asks", [True, False], ids=["asks", "does-not-ask"])
def test_a_joint_silent_at_the_open_is_not_freed_when_it_answers_where_the_program_asks_before_freeing(
    asks: bool,
) -> None:
    # The web's question named the joints that answered; one whose servo kept its power and target while its replies
    # were lost (a loose signal wire) was freed by its probe, the free command, the moment it answered again: a
    # standing robot's knee went limp unasked.  Where the program asks (confirm_start_free), such a joint is probed
    # with a read and comes back held, sent nothing, as a joint with a target that went offline does.
    rig = make_rig()
    lower = rig.sim("lower")
    knee = lower.remove_servo(JOINTS["knee"]["id"])  # (silent at the open)
    knee.command_position(8000)  # (holding: its replies lost, not its power)

    async def frames(n: int = 1) -> None:
        for _ in range(n):
            latest = robot_of[0].latest
            await robot_of[0].wait_frame(-1 if latest is None else latest.cycle)

    robot_of: list[Robot] = []

    async def body(robot: Robot) -> tuple[dict[str, str], bool]:
        robot_of.append(robot)
        assert "knee" in robot.unreached
        lower.add_device(knee)
        with anyio.fail_after(GUARD):
            while "knee" in robot.unreached:
                await frames()
        await frames(5)  # (cycles after its return: a free command would have gone out by now)
        held, free = dict(robot.held), knee.free
        if asks:
            await robot.free(["knee"])  # (the program's decision: now it goes free)
            with anyio.fail_after(GUARD):
                while not knee.free:
                    await frames()
        return held, free

    options: dict[str, Any] = {"probe_interval": 0.02}
    if asks:
        options["confirm_start_free"] = lambda joints: True
    held, freed = run_robot(rig, body, **options)
    if asks:
        assert held.get("knee") == "rejoined" and not freed, held
    else:  # (as ever for a program that does not ask: it is read by freeing, as at an open)
        assert "knee" not in held and freed, held


def test_a_start_free_confirmed_opens_as_without_the_question_and_none_is_asked_with_nothing_to_free() -> None:
    rig = make_rig(ics36=[1])
    asked: list[list[str]] = []

    async def body(robot: Robot) -> dict[str, str]:
        return dict(robot.start_modes)

    modes = run_robot(rig, body, confirm_start_free=lambda joints: asked.append(joints) or True)
    assert asked == [["shoulder", "elbow", "knee"]]
    assert modes == {"neck": "read", "shoulder": "free", "elbow": "free", "hip": "read", "knee": "free"}
    rig = make_rig(ics36=ALL_ICS36)
    run_robot(rig, body, confirm_start_free=lambda joints: asked.append(joints) or True)
    assert len(asked) == 1  # (every joint read: nothing to free, nothing asked)
    with pytest.raises(InvalidArgument, match="confirm_start_free must be a function"):
        run_robot(make_rig(), body, confirm_start_free="yes")
