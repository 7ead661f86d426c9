"""The safety watch: a simulated servo made hot, over-current or silent mid-motion stops the robot.

The simulator's log shows when the watch read what, and what the robot
sent after it tripped; nothing here depends on wall-clock timing.
"""

from __future__ import annotations

import traceback
from collections.abc import Awaitable, Callable
from typing import Any

import anyio
import pytest

from ics35_async import IcsError, InvalidArgument, Robot, SafetyStop, State, UnsafeOperation, open_robot, units
from ics35_async.protocol import Param
from ics35_async.robot import MotionStopped
from ics35_async.sim import FaultConfig, FaultInjector, VirtualLine, VirtualServo
from tests.support.robot_rig import JOINTS, Rig, commanded, make_rig, targets_sent
from tests.support.timing import FAST, GUARD

FREE = 0


def reads(sim: VirtualLine, command: str, since: int, until: int, servo_id: int | None = None) -> int:
    return sum(
        1
        for t in sim.log_since(since)
        if t.seq < until and t.command == command and (servo_id is None or t.servo_id == servo_id)
    )


def heard(sim: VirtualLine, servo_id: int, since: int) -> list[int]:
    """The position targets (log seq > ``since``) the servo at ``servo_id`` heard: it was on the line to answer."""
    return [
        (t.tx[1] << 7) | t.tx[2]
        for t in sim.log_since(since)
        if t.command == "position" and t.servo_id == servo_id and servo_id in t.responders
    ]


def first_free(sim: VirtualLine, servo_id: int, since: int) -> int:
    return next(t.seq for t in sim.log_since(since) if t.command == "free" and t.servo_id == servo_id)


async def when_moving(robot: Robot, joint: str) -> None:
    """Wait until ``joint`` is under way (its target has left where it started)."""
    async with robot.stream() as stream:
        first = (await stream.next_frame()).targets[joint]
        while (await stream.next_frame()).targets[joint] in (None, first):
            pass


async def frames_until(robot: Robot, done: Callable[[], bool]) -> None:
    """The robot's frames, one after another, until ``done()`` (the test's GUARD bounds the wait)."""
    while not done():
        await robot.wait_frame(robot.latest.cycle if robot.latest else 0)


def run_with_fault(
    rig: Rig, moves: dict[str, float], joint: str, fault: Callable[[], None], **options: Any
) -> tuple[SafetyStop | None, dict[str, int], Robot]:
    """Start a 3 s move, apply ``fault`` once ``joint`` moves; return the move's error and the log seqs then."""
    caught: list[SafetyStop] = []
    marks: dict[str, int] = {}

    async def main() -> Robot:
        with anyio.fail_after(GUARD):
            async with open_robot(rig.description, **FAST, **options) as robot:

                async def mover() -> None:
                    try:
                        await robot.move_to(moves, duration=3.0)
                    except SafetyStop as exc:
                        caught.append(exc)

                async with anyio.create_task_group() as tasks:
                    tasks.start_soon(mover)
                    await when_moving(robot, joint)
                    marks.update(upper=rig.upper.transactions, lower=rig.lower.transactions)
                    fault()
                await robot.on_wire()
                return robot

    try:
        robot = anyio.run(main)
    finally:
        rig.close()
    return (caught[0] if caught else None), marks, robot


def test_a_hot_servo_mid_motion_frees_its_joint_within_one_telemetry_round() -> None:
    rig = make_rig(safety={"max_temperature_c": 60, "action": "free"})
    neck = rig.servo("neck")

    def heat() -> None:
        neck.temperature_celsius = 70.0  # under the servo's own 80 C cut-out: only the watch can act

    stop, marks, robot = run_with_fault(rig, {"neck": 50.0, "shoulder": -60.0}, "neck", heat)
    assert isinstance(stop, SafetyStop)
    assert (stop.joint, stop.reason, stop.action, stop.limit) == ("neck", "temperature", "free", 60.0)
    assert stop.value is not None and stop.value > 60
    assert "joint neck (line upper, ID 1)" in str(stop)
    freed = first_free(rig.upper, 1, marks["upper"])
    # Within one round: the neck's very next temperature read found it (and the read at once after it confirmed
    # it), and the line's other joints were read at most once each before the free command went out.
    assert reads(rig.upper, "read_temperature", marks["upper"], freed, servo_id=1) == 2
    assert reads(rig.upper, "read_temperature", marks["upper"], freed) <= 1 + len(
        [j for j in JOINTS.values() if j["line"] == "upper"]
    )
    assert neck.free
    # Action "free": the other joints stopped where they were, torque on, and sent no new targets after.
    shoulder = targets_sent(rig.upper, 2, freed)
    assert shoulder and len(set(shoulder)) == 1 and not rig.servo("shoulder").free
    assert robot.trips == [stop]


def test_over_current_with_action_stop_frees_the_whole_robot() -> None:
    rig = make_rig(safety={"max_current": 20, "action": "stop"})
    knee = rig.servo("knee")

    def overload() -> None:
        knee.load = 40

    stop, marks, _ = run_with_fault(rig, {"knee": -80.0, "neck": 40.0}, "knee", overload)
    assert isinstance(stop, SafetyStop)
    assert (stop.joint, stop.reason, stop.action) == ("knee", "current", "stop")
    assert stop.value is not None and stop.value > 20
    for name in JOINTS:
        assert rig.servo(name).free, name
    freed = first_free(rig.lower, 2, marks["lower"])
    assert reads(rig.lower, "read_current", marks["lower"], freed, servo_id=2) == 2  # the crossing, confirmed


def test_action_hold_keeps_every_joint_at_its_last_target() -> None:
    rig = make_rig(safety={"max_temperature_c": 60, "action": "hold"})

    def heat() -> None:
        rig.servo("shoulder").temperature_celsius = 75.0

    stop, marks, robot = run_with_fault(rig, {"shoulder": -80.0, "hip": 25.0}, "shoulder", heat)
    assert isinstance(stop, SafetyStop) and stop.action == "hold"
    # The read that found it hot; from the command after it on, the shoulder's target no longer changes.
    found = next(
        t.seq for t in rig.upper.log_since(marks["upper"]) if t.command == "read_temperature" and t.servo_id == 2
    )
    after = targets_sent(rig.upper, 2, found)
    assert len(after) >= 2 and len(set(after[1:])) == 1
    for name in ("shoulder", "hip"):
        assert not rig.servo(name).free, name
    assert robot.tripped["shoulder"] is stop


def with_the_knee_unplugged(body: Callable[[Robot, Rig, VirtualServo], Awaitable[None]]) -> None:
    """``body(robot, rig, knee)`` on a robot opened (standing on its start pose) with the knee's servo unplugged
    before it opened, once its frames say the knee is offline; ``knee`` is the unplugged servo, to plug in."""
    rig = make_rig()
    knee = rig.lower.remove_servo(2)

    async def main() -> None:
        with anyio.fail_after(GUARD):
            async with open_robot(rig.description, start_pose={"hip": 10.0, "knee": 0.0}, **FAST) as robot:
                await frames_until(robot, lambda: robot.latest is not None and "knee" in robot.latest.offline)
                await body(robot, rig, knee)

    try:
        anyio.run(main)
    finally:
        rig.close()


@pytest.mark.filterwarnings("ignore::ics35_async.robot.RobotWarning")  # (the open names the silent joint)
def test_a_servo_that_never_answered_does_not_free_the_robot_and_its_joint_refuses_motions() -> None:
    # One servo unplugged before the robot opened (a loose plug, a line at the wrong rate): its joint went
    # "offline" in the first cycles and the default action, stop, freed every joint, so a robot standing on its
    # start pose went limp as it opened.  A joint that never answered was never under control: it is named at
    # open and refused by motions, and the others hold.

    async def body(robot: Robot, rig: Rig, knee: VirtualServo) -> None:
        lower = robot.latest.line_cycles["lower"]
        while robot.latest.line_cycles["lower"] < lower + 3:  # (the watch has seen it offline)
            await robot.wait_frame(robot.latest.cycle)
        assert robot.trips == [] and not rig.servo("hip").free
        assert any("knee" in w and "did not answer" in w for w in robot.warnings), robot.warnings
        with pytest.raises(UnsafeOperation, match="joint knee has not answered since the robot opened"):
            await robot.move_to({"hip": 5.0, "knee": 5.0}, duration=0.05)
        await robot.move_to({"hip": 5.0}, duration=0.05)  # the others move
        rig.lower.add_device(knee)  # plugged in: it answers (held, where it is), under the watch from then on
        while "knee" not in robot.held:
            await robot.wait_frame(robot.latest.cycle)
        robot.set_targets({"knee": 0.0})  # decided
        await robot.move_to({"knee": 5.0}, duration=0.05)
        rig.lower.remove_servo(2)  # lost after it answered: the watch stops the robot
        with pytest.raises(SafetyStop, match="joint knee"):
            while True:
                await robot.wait_frame(robot.latest.cycle)
                robot.check_ready(["knee"])

    with_the_knee_unplugged(body)


@pytest.mark.filterwarnings("ignore::ics35_async.robot.RobotWarning")  # (the open names the silent joints)
def test_a_motion_refused_for_silent_joints_names_every_one_of_them() -> None:
    # A robot's legs' line unplugged whole: a motion over both legs was refused naming only its first silent joint,
    # and the builder who plugged that one in was refused again for the next.
    rig = make_rig()
    rig.lower.remove_servo(1)
    rig.lower.remove_servo(2)

    async def main() -> None:
        with anyio.fail_after(GUARD):
            async with open_robot(rig.description, start_pose={"neck": 0.0}, **FAST) as robot:
                await frames_until(robot, lambda: robot.latest is not None and {"hip", "knee"} <= robot.latest.offline)
                with pytest.raises(UnsafeOperation) as refused:
                    await robot.move_to({"neck": 5.0, "hip": 5.0, "knee": 5.0}, duration=0.05)
                said = str(refused.value)
                assert "joints hip, knee have not answered since the robot opened" in said, said
                assert "line lower, servo IDs 1, 2" in said, said

    try:
        anyio.run(main)
    finally:
        rig.close()


@pytest.mark.filterwarnings("ignore::ics35_async.robot.RobotWarning")  # (the open names the silent joint)
def test_a_target_set_for_a_joint_that_never_answered_does_not_move_its_servo_once_plugged_in() -> None:
    # move_to refuses such a joint (it would drive it blind); set_targets takes the target, as a loop setting
    # every joint each pass needs, but the servo, plugged in later, must not be thrown there at full speed from
    # wherever it stands: it answers a read, comes back held, and moves only once the program sets it again.

    async def body(robot: Robot, rig: Rig, knee: VirtualServo) -> None:
        robot.set_targets({"hip": 10.0, "knee": -40.0})
        since = rig.lower.transactions
        rig.lower.add_device(knee)
        await frames_until(robot, lambda: "knee" in robot.held)
        lower = robot.latest.line_cycles["lower"]
        await frames_until(robot, lambda: robot.latest.line_cycles["lower"] >= lower + 3)
        assert heard(rig.lower, 2, since) == []
        robot.set_targets({"knee": -40.0})  # decided: now it goes
        await robot.on_wire(["knee"])
        assert set(heard(rig.lower, 2, since)) == {robot.joints["knee"].position(-40.0)}

    with_the_knee_unplugged(body)


def test_a_trip_between_a_stops_planning_and_its_ramps_start_is_not_undone_by_the_ramp() -> None:
    # stop() works its ramps out, then its ramp tasks start a scheduler pass later: a trip landing in between (the
    # watch's frame handled first) ended every motion but the ramps not yet running, which then drove the joint
    # the watch had just freed.  A ramp, like a motion, does not drive a tripped joint.
    rig = make_rig()

    async def main() -> None:
        with anyio.fail_after(GUARD):
            async with open_robot(rig.description, **FAST) as robot:
                await robot.move_to({"neck": 0.0}, duration=0.05)
                caught: list[BaseException] = []

                async def move() -> None:
                    try:
                        await robot.move_to({"neck": 50.0}, duration=2.0)
                    except (MotionStopped, SafetyStop) as exc:  # (stopped: by the stop, or the trip)
                        caught.append(exc)

                async def stop() -> None:
                    try:
                        await robot.stop(ramp=0.5)
                    except SafetyStop as exc:
                        caught.append(exc)

                async with anyio.create_task_group() as tasks:
                    tasks.start_soon(move)
                    await when_moving(robot, "neck")
                    tasks.start_soon(stop)
                    await anyio.sleep(0)  # stop() has planned its ramps; they have not started
                    robot.trip(SafetyStop("neck: a test's trip", joint="neck", reason="current", action="free"))
                    since = rig.upper.transactions
                await robot.on_wire()
                await frames_until(robot, lambda: rig.upper.transactions > since + 20)
                assert rig.servo("neck").free, "the ramp drove the joint the watch freed"
                assert targets_sent(rig.upper, 1, since) == []
                # The stop, and the motion it stopped, hear of the trip.
                assert len(caught) == 2 and all(isinstance(e, SafetyStop) for e in caught), caught

    try:
        anyio.run(main)
    finally:
        rig.close()


def test_an_offline_servo_stops_the_motion_unless_continue_on_offline() -> None:
    def silence(rig: Rig) -> Callable[[], None]:
        # Every reply of ID 3 (the elbow) dropped from now on: the servo has gone quiet.
        return lambda: setattr(rig.upper, "faults", FaultInjector(FaultConfig.parse("drop@3:1")))

    # By default (no [safety] action) the tripped joint is freed and the others keep their last targets: one
    # servo's plug working loose must not make a standing robot go limp (the default freed every joint).
    rig = make_rig()
    stop, _, _ = run_with_fault(rig, {"elbow": 80.0, "neck": 20.0}, "neck", silence(rig))
    assert isinstance(stop, SafetyStop)
    assert (stop.joint, stop.reason, stop.action) == ("elbow", "offline", "free")
    assert not rig.servo("neck").free  # (it was moving: it holds its last target; shoulder was never held)

    rig = make_rig(safety={"continue_on_offline": True})
    go_on = silence(rig)

    caught: list[BaseException] = []

    async def main() -> None:
        async with open_robot(rig.description, **FAST) as robot:
            async with anyio.create_task_group() as tasks:

                async def mover() -> None:
                    try:
                        await robot.move_to({"neck": 20.0, "elbow": 80.0}, duration=0.5)
                    except SafetyStop as exc:
                        caught.append(exc)

                tasks.start_soon(mover)
                await when_moving(robot, "neck")
                go_on()
            assert robot.latest is not None and "elbow" in robot.latest.offline
            assert robot.trips == []

    try:
        anyio.run(main)
    finally:
        rig.close()
    assert caught == []
    assert list(commanded(rig.upper, 1))[-1] == 7500 + round((10 + 20) * 8000 / 270)


def test_the_stream_raises_the_stop_and_a_tripped_joint_refuses_motion_until_it_cools() -> None:
    rig = make_rig(safety={"max_temperature_c": 60, "action": "free"})
    hip = rig.servo("hip")

    async def main() -> None:
        with anyio.fail_after(GUARD):
            async with open_robot(rig.description, **FAST) as robot:
                await robot.move_to({"hip": 10.0}, duration=0.05)
                async with robot.stream() as stream:
                    await stream.next_frame()
                    hip.temperature_celsius = 90.0
                    hip.temperature_limit = 1  # the servo's own cut-out out of the way
                    with pytest.raises(SafetyStop, match="joint hip"):
                        while True:
                            await stream.next_frame()
                    await stream.next_frame()  # reported once; the stream goes on
                since = rig.lower.transactions
                with pytest.raises(SafetyStop, match="joint hip"):
                    await robot.move_to({"hip": 20.0, "knee": 5.0}, duration=0.1)
                await robot.on_wire()
                assert targets_sent(rig.lower, 1, since) == [] and targets_sent(rig.lower, 2, since) == []
                await robot.move_to({"knee": 5.0}, duration=0.05)  # other joints still move
                hip.temperature_celsius = 25.0
                await frames_until(robot, lambda: "hip" not in robot.tripped)
                await robot.move_to({"hip": 20.0}, duration=0.05)
                assert robot.watch.rounds["lower"] > 0

    try:
        anyio.run(main)
    finally:
        rig.close()
    assert not hip.free and hip.target == 7500 + round(20 * 8000 / 270)


def test_targets_and_holds_naming_a_tripped_joint_are_refused_until_it_cools() -> None:
    # A program's own control loop (the blocking robot has no stream) set every joint's target each pass:
    # the next set_targets after the watch freed an overheated hip turned its torque back on, 20 ms later.
    rig = make_rig(safety={"max_temperature_c": 60, "action": "free"})
    hip = rig.servo("hip")

    async def main() -> None:
        with anyio.fail_after(GUARD):
            async with open_robot(rig.description, **FAST) as robot:
                await robot.move_to({"hip": 10.0, "knee": 0.0}, duration=0.05)
                hip.temperature_celsius = 90.0
                hip.temperature_limit = 1  # the servo's own cut-out out of the way
                while "hip" not in robot.tripped:
                    robot.set_targets({"knee": 1.0})  # a loop's pass that leaves the hip alone goes on
                    await robot.wait_frame(robot.latest.cycle if robot.latest else 0)
                await robot.on_wire()
                assert hip.free
                since = rig.lower.transactions
                for attempt in (
                    lambda: robot.set_targets({"hip": 12.0, "knee": 2.0}),
                    lambda: robot.hold(["hip", "knee"]),
                ):
                    with pytest.raises(SafetyStop, match="joint hip"):
                        attempt()
                robot.hold()  # every joint but the tripped one
                robot.set_targets({"hip": None}, allow_free=True)  # freeing is always allowed
                await robot.on_wire()
                assert targets_sent(rig.lower, 1, since) == [] and hip.free  # nothing re-powered the hip
                assert targets_sent(rig.lower, 2, since)  # the knee was held
                hip.temperature_celsius = 25.0
                await frames_until(robot, lambda: "hip" not in robot.tripped)
                robot.set_targets({"hip": 12.0})  # cooled: targets go again
                await robot.on_wire(["hip"])

    try:
        anyio.run(main)
    finally:
        rig.close()
    assert not hip.free and hip.target == 7500 + round(12 * 8000 / 270)


def test_a_freed_over_current_joint_stays_tripped_until_the_program_resets_it() -> None:
    # A free servo draws no current, so the watch's next read of the knee it had freed for over-current was
    # "back within the limits" and cleared the trip at once (about 10 ms): a control loop setting every joint
    # each pass powered the overloaded knee again at its next pass, and tripped again, over and over.
    rig = make_rig(safety={"max_current": 20, "action": "free"})
    knee = rig.servo("knee")

    async def main() -> None:
        with anyio.fail_after(GUARD):
            async with open_robot(rig.description, **FAST) as robot:
                await robot.move_to({"knee": 10.0}, duration=0.05)
                knee.load = 40  # a load it cannot carry, still there
                await frames_until(robot, lambda: "knee" in robot.tripped)
                stop = robot.tripped["knee"]
                await robot.on_wire()
                assert knee.free
                reads_before = robot.watch.telemetry["knee"].reads
                # Read three times since, free: a current of 0, "within the limits".
                await frames_until(robot, lambda: robot.watch.telemetry["knee"].reads >= reads_before + 3)
                assert robot.tripped == {"knee": stop}
                since = rig.lower.transactions
                with pytest.raises(SafetyStop, match="joint knee"):
                    robot.set_targets({"knee": 12.0, "hip": 0.0})
                await robot.on_wire()
                assert targets_sent(rig.lower, 2, since) == [], [
                    (t.seq, t.command, t.tx.hex(), t.responders) for t in rig.lower.log_since(since) if t.servo_id == 2
                ] and knee.free  # nothing re-powered the knee
                knee.load = 0  # the program dealt with the cause: its call puts the joint back in its hands
                robot.reset_trip("knee")
                assert robot.tripped == {} and robot.trips == [stop]
                robot.set_targets({"knee": 12.0})
                await robot.on_wire(["knee"])
                assert not knee.free and knee.target == robot.joints["knee"].position(12.0)
                with pytest.raises(InvalidArgument, match="ankle"):
                    robot.reset_trip("ankle")

    try:
        anyio.run(main)
    finally:
        rig.close()


def test_an_over_current_trip_with_action_hold_clears_once_the_load_is_gone() -> None:
    # With action "hold" the joint keeps its torque: a reading back within the limits is the load gone.
    rig = make_rig(safety={"max_current": 20, "action": "hold"})
    knee = rig.servo("knee")

    async def main() -> None:
        with anyio.fail_after(GUARD):
            async with open_robot(rig.description, **FAST) as robot:
                await robot.move_to({"knee": 10.0}, duration=0.05)
                knee.load = 40
                await frames_until(robot, lambda: "knee" in robot.tripped)
                assert not knee.free
                knee.load = 0
                await frames_until(robot, lambda: "knee" not in robot.tripped)
                robot.set_targets({"knee": 12.0})
                await robot.on_wire(["knee"])

    try:
        anyio.run(main)
    finally:
        rig.close()
    assert not knee.free


def test_the_watch_reads_at_each_lines_own_pace_beside_a_faster_line() -> None:
    # The robot's frames come as each line ends a cycle: the watch of a 10 Hz line read a joint at every
    # frame of the 100 Hz line too (11 reads a cycle of its own for telemetry_per_cycle=1), taking that
    # line's slack.  One read a cycle of its own line, whatever the others do.  (20 Hz beside 200 Hz here: a robot
    # file asks 20 Hz at least.)
    rig = make_rig(safety={"telemetry_per_cycle": 1})
    rig.description["lines"]["upper"]["rate_hz"] = 200
    rig.description["lines"]["lower"]["rate_hz"] = 20

    async def main() -> tuple[int, int, int]:
        with anyio.fail_after(GUARD):
            async with open_robot(rig.description, **FAST) as robot:
                first = await robot.wait_frame(0)
                mark = rig.lower.transactions
                await anyio.sleep(0.5)
                last = await robot.wait_frame(first.cycle)
                until = rig.lower.transactions
                return mark, until, last.line_cycles["lower"] - first.line_cycles["lower"]

    try:
        mark, until, cycles = anyio.run(main)
    finally:
        rig.close()
    temperatures = reads(rig.lower, "read_temperature", mark, until)
    assert temperatures <= cycles + 2, (temperatures, cycles)  # (a read each at the window's two edges)


def test_a_loop_that_catches_the_stop_at_every_pass_does_not_pile_up_its_tracebacks() -> None:
    # The robot raised the one SafetyStop it keeps for a tripped joint at every refusal, and each raise added
    # that pass's frames to its traceback: a 100 Hz loop catching it and going on grew it (and the frames it
    # keeps alive) without end, and the traceback shown named every earlier pass.
    rig = make_rig(safety={"max_temperature_c": 60, "action": "free"})
    hip = rig.servo("hip")
    lengths: list[int] = []

    async def main() -> None:
        with anyio.fail_after(GUARD):
            async with open_robot(rig.description, **FAST) as robot:
                await robot.move_to({"hip": 10.0, "knee": 0.0}, duration=0.05)
                hip.temperature_celsius = 90.0
                hip.temperature_limit = 1  # the servo's own cut-out out of the way
                await frames_until(robot, lambda: "hip" in robot.tripped)
                for _ in range(20):
                    try:
                        robot.set_targets({"hip": 12.0, "knee": 2.0})
                    except SafetyStop as stop:
                        lengths.append(len(traceback.extract_tb(stop.__traceback__)))
                    with pytest.raises(SafetyStop) as refused:
                        await robot.move_to({"hip": 0.0}, duration=0.1)
                    lengths.append(len(traceback.extract_tb(refused.value.__traceback__)))

    try:
        anyio.run(main)
    finally:
        rig.close()
    assert len(lengths) == 40 and max(lengths) <= 8, lengths


def test_the_watch_goes_on_reading_a_line_that_comes_back_after_its_port_was_lost() -> None:
    # A robot builder's finding (reconnect=True): a read of the watch's landing while the lower line was away
    # ended that line's watch for good. Back, its joints were driven again with nothing reading their
    # temperature or current: a knee at 80 C went unnoticed.
    rig = make_rig(safety={"max_temperature_c": 60, "action": "free"})

    async def main() -> None:
        with anyio.fail_after(GUARD):
            async with open_robot(rig.description, reconnect=True, start_pose={"knee": 0.0}, **FAST) as robot:
                await frames_until(robot, lambda: robot.telemetry["knee"].reads > 0)
                rig.lower.unplug()
                await frames_until(robot, lambda: robot.group["lower"].state is State.LOST)
                await frames_until(robot, lambda: robot.telemetry["neck"].reads > 10)  # (reads went on: upper)
                rig.lower.replug()
                await frames_until(robot, lambda: "knee" in robot.held)
                robot.set_targets({"knee": 0.0})  # the program decides: the knee holds again, torque on
                rig.servo("knee").temperature_celsius = 80.0
                await frames_until(robot, lambda: "knee" in robot.tripped)
                assert robot.tripped["knee"].reason == "temperature"

    try:
        anyio.run(main)
    finally:
        rig.close()
    assert rig.servo("knee").free  # action "free"


def run_standing(rig: Rig, main: Callable[[], Awaitable[Robot]]) -> Robot:
    """The robot ``main`` opened on ``rig`` (standing at its start pose), the rig closed after it."""
    try:
        return anyio.run(main)
    finally:
        rig.close()


def test_a_garbled_telemetry_reply_does_not_trip_the_watch() -> None:
    # ICS replies carry no checksum: a reply byte garbled on the wire reads as another value (a servo at 25 C as
    # over 100 C, a current of 50 at rest), and the watch tripped on that one reading, freeing joints of a robot
    # standing still.  Every simulated servo here stays cool and unloaded.
    rig = make_rig(safety={"max_temperature_c": 70, "max_current": 30, "action": "free"}, faults="corrupt:0.02")

    async def main() -> Robot:
        with anyio.fail_after(GUARD):
            async with open_robot(rig.description, **FAST, start_pose=dict.fromkeys(JOINTS, 0.0)) as robot:
                await frames_until(robot, lambda: min(robot.watch.rounds.values()) >= 100)
                return robot

    robot = run_standing(rig, main)
    assert robot.trips == []
    for line in ("upper", "lower"):
        assert [t for t in rig.sim(line).log if t.command == "free"] == []
    assert all(s.temperature_celsius < 70 and s.load == 0 for line in ("upper", "lower") for s in rig.sim(line).servos)


class ReadsOnce(VirtualServo):
    """A servo whose next telemetry reads return ``scripted``'s values in turn (as a line garbling those replies
    would), its own after them."""

    def __init__(self, servo_id: int) -> None:
        super().__init__(servo_id)
        self.scripted: dict[Param, list[int]] = {}

    def _read_param(self, param: Param) -> int:
        script = self.scripted.get(param)
        return script.pop(0) if script else super()._read_param(param)


def test_two_garbled_telemetry_replies_crossing_different_limits_do_not_trip_the_watch() -> None:
    # A crossing is read again at once and trips only if confirmed: a garbled temperature reply (over 100 C) and,
    # in the read confirming it, a garbled current reply are two single readings, each crossing once.
    rig = make_rig(safety={"max_temperature_c": 70, "max_current": 30, "action": "free"})
    neck = ReadsOnce(JOINTS["neck"]["id"])
    rig.upper.remove_servo(neck.servo_id)
    rig.upper.add_device(neck)

    async def main() -> Robot:
        with anyio.fail_after(GUARD):
            async with open_robot(rig.description, **FAST, start_pose=dict.fromkeys(JOINTS, 0.0)) as robot:
                await frames_until(robot, lambda: min(robot.watch.rounds.values()) >= 2)
                cool = units.current_to_raw(units.Current(1, False))
                neck.scripted = {
                    Param.TEMPERATURE: [units.celsius_to_temperature(120)],  # the first read: too hot
                    Param.CURRENT: [cool, units.current_to_raw(units.Current(60, False))],  # the second: too much
                }
                await frames_until(robot, lambda: not any(neck.scripted.values()))
                rounds = robot.watch.rounds["upper"]
                await frames_until(robot, lambda: robot.watch.rounds["upper"] >= rounds + 2)
                return robot

    robot = run_standing(rig, main)
    assert robot.trips == []
    assert not neck.free


def test_a_joint_gone_offline_or_on_a_lost_line_has_no_temperature_or_current_until_read_again() -> None:
    # Robot.telemetry kept the last readings of a servo unplugged (or of a line whose port was lost) as if they
    # were its own now, and once it answered again, until the watch read it anew: a view of the robot showed a
    # knee at its old 42 C that came back at 70 C.
    rig = make_rig(safety={"continue_on_offline": True})
    shown: dict[str, list[float | None]] = {"offline": [], "lost": [], "back": []}

    async def main() -> None:
        with anyio.fail_after(GUARD):
            async with open_robot(rig.description, reconnect=True, start_pose={"knee": 0.0}, **FAST) as robot:
                await frames_until(robot, lambda: robot.telemetry["knee"].temperature_c is not None)
                assert (robot.telemetry["knee"].temperature_c or 0) < 50  # (the simulator's ambient)
                knee = rig.lower.remove_servo(2)
                await frames_until(robot, lambda: "knee" in robot.unreached)
                shown["offline"].append(robot.telemetry["knee"].temperature_c)
                knee.temperature_celsius = 70.0
                rig.lower.add_device(knee)
                while "knee" not in robot.held:
                    shown["back"].append(robot.telemetry["knee"].temperature_c)
                    await robot.wait_frame(robot.latest.cycle)
                reads = robot.telemetry["knee"].reads
                while robot.telemetry["knee"].reads == reads:  # (until the watch has read it since it came back)
                    shown["back"].append(robot.telemetry["knee"].temperature_c)
                    await robot.wait_frame(robot.latest.cycle)
                assert (robot.telemetry["knee"].temperature_c or 0) > 65  # read again: its own now
                robot.set_targets({"knee": 0.0})
                await frames_until(robot, lambda: robot.telemetry["hip"].temperature_c is not None)
                rig.lower.unplug()
                await frames_until(robot, lambda: robot.group["lower"].state is State.LOST)
                shown["lost"] += [robot.telemetry[name].temperature_c for name in ("hip", "knee")]
                shown["lost"].append(robot.telemetry["hip"].current)

    try:
        anyio.run(main)
    finally:
        rig.close()
    assert shown["offline"] == [None] and shown["lost"] == [None, None, None], shown
    assert all(seen is None or seen > 65 for seen in shown["back"]), shown  # (never the 42 C from before)


def test_a_joint_on_a_line_lost_for_good_has_no_temperature_or_current() -> None:
    # Without reconnect a lost port ends its line: `ics35 play`'s last table said LINE LOST beside the
    # temperature and current read before, as if they were the servos' now.
    rig = make_rig()
    shown: list[float | int | None] = []

    async def main() -> None:
        with anyio.fail_after(GUARD):
            async with open_robot(rig.description, start_pose={"knee": 0.0}, **FAST) as robot:
                await frames_until(robot, lambda: robot.telemetry["knee"].temperature_c is not None)
                rig.lower.unplug()
                with pytest.raises(IcsError):
                    while True:
                        await robot.wait_frame(robot.latest.cycle)
                while robot.group["lower"].state not in (State.CLOSED, State.DRAINING):
                    await anyio.sleep(0.01)
                shown.extend([robot.telemetry["knee"].temperature_c, robot.telemetry["knee"].current])

    try:
        anyio.run(main)
    finally:
        rig.close()
    assert shown == [None, None], shown


def test_a_joint_whose_telemetry_reads_keep_failing_has_no_temperature_or_current_while_it_answers() -> None:
    # The knee's servo answered every position command, but its temperature and current reads went unanswered:
    # Robot.telemetry went on giving the temperature and current read before, as if read now (a view of the robot
    # showed a knee at 42 C that nothing had read for minutes).
    rig = make_rig()
    shown: list[float | int | None] = []

    async def main() -> None:
        with anyio.fail_after(GUARD):
            async with open_robot(rig.description, start_pose={"knee": 0.0}, **FAST) as robot:
                await frames_until(robot, lambda: robot.telemetry["knee"].temperature_c is not None)
                rig.lower.servo(2).ignores = frozenset({"read_temperature", "read_current"})
                errors = robot.telemetry["knee"].errors
                await frames_until(robot, lambda: robot.telemetry["knee"].errors >= errors + 2)
                assert "knee" not in robot.unreached and "knee" in robot.latest.positions  # (still answering)
                shown.extend([robot.telemetry["knee"].temperature_c, robot.telemetry["knee"].current])
                assert robot.telemetry["hip"].temperature_c is not None  # (the others read on)
                rig.lower.servo(2).ignores = frozenset()
                await frames_until(robot, lambda: robot.telemetry["knee"].temperature_c is not None)  # read again

    try:
        anyio.run(main)
    finally:
        rig.close()
    assert shown == [None, None], shown


def blind_said(caplog: pytest.LogCaptureFixture) -> list[str]:
    """The safety watch's words that it cannot hold a joint to its limits (its telemetry does not read)."""
    return [r.getMessage() for r in caplog.records if "cannot hold" in r.getMessage()]


def run_with_warnings(rig: Rig, main: Callable[[], Awaitable[None]], caplog: pytest.LogCaptureFixture) -> None:
    """``main`` run with the library's warnings captured, the rig closed after it however it ended."""
    try:
        with caplog.at_level("WARNING", logger="ics35_async"):
            anyio.run(main)
    finally:
        rig.close()


def test_a_watched_joint_whose_telemetry_cannot_be_read_is_said_once_an_episode(
    caplog: pytest.LogCaptureFixture,
) -> None:
    # A max_temperature_c guards a joint only while its temperature reads: the knee's servo answered its position
    # commands but no temperature or current read, and the watch went on without a word, as if guarding it.
    rig = make_rig({"max_temperature_c": 70, "max_current": 40})
    blind: list[int] = []

    async def main() -> None:
        with anyio.fail_after(GUARD):
            async with open_robot(rig.description, start_pose={"knee": 0.0}, **FAST) as robot:
                await frames_until(robot, lambda: robot.telemetry["knee"].temperature_c is not None)
                for _ in range(2):  # two episodes, read in between
                    rig.lower.servo(2).ignores = frozenset({"read_temperature", "read_current"})
                    until = robot.telemetry["knee"].errors + 4
                    await frames_until(robot, lambda until=until: robot.telemetry["knee"].errors >= until)
                    blind.append(len(blind_said(caplog)))
                    rig.lower.servo(2).ignores = frozenset()
                    await frames_until(robot, lambda: robot.telemetry["knee"].temperature_c is not None)

    run_with_warnings(rig, main, caplog)
    assert blind == [1, 2], (blind, blind_said(caplog))  # once an episode, not once a failed read
    for message in blind_said(caplog):
        assert "joint knee (line lower, ID 2)" in message, message
        assert "max_temperature_c 70 and max_current 40" in message and "until they read again" in message, message
    assert not [message for message in blind_said(caplog) if "hip" in message]


def test_a_watched_joint_whose_servo_stopped_answering_altogether_is_not_said_blind(
    caplog: pytest.LogCaptureFixture,
) -> None:
    # A servo unplugged mid-motion: its temperature and current reads failed twice before the stream took it
    # offline, and the watch said "its servo may still answer its position commands", pointing away from the
    # cause (the servo was gone: the offline rule says so).  Said only while its position still answers.
    rig = make_rig({"max_temperature_c": 70, "max_current": 40, "telemetry_per_cycle": 2})

    async def main() -> None:
        with anyio.fail_after(GUARD):
            # (offline only after 50 failed cycles: the reads fail twice long before)
            async with open_robot(rig.description, start_pose={"knee": 0.0}, **{**FAST, "offline_after": 50}) as robot:
                await frames_until(robot, lambda: robot.telemetry["knee"].temperature_c is not None)
                rig.lower.remove_servo(2)
                until = robot.telemetry["knee"].errors + 4
                await frames_until(robot, lambda: robot.telemetry["knee"].errors >= until)

    run_with_warnings(rig, main, caplog)
    assert not blind_said(caplog), blind_said(caplog)


def test_a_watched_joint_whose_servo_is_plugged_back_in_is_not_said_blind(caplog: pytest.LogCaptureFixture) -> None:
    # A servo unplugged until the stream took it offline, then plugged back in: as it answered again, the watch said
    # "its temperature and current did not read 3 times in a row (its servo still answers its position commands)",
    # counting the reads that failed as it went, while the views showed it reading well.
    rig = make_rig({"max_temperature_c": 70, "max_current": 40, "telemetry_per_cycle": 2})

    async def main() -> None:
        with anyio.fail_after(GUARD):
            # (offline after 20 failed cycles: its reads fail twice before, as on a line with an adapter's latency)
            async with open_robot(rig.description, start_pose={"knee": 0.0}, **{**FAST, "offline_after": 20}) as robot:
                await frames_until(robot, lambda: robot.telemetry["knee"].temperature_c is not None)
                servo = rig.lower.remove_servo(2)
                await frames_until(robot, lambda: "knee" in robot.latest.offline)
                rig.lower.add_device(servo)
                await frames_until(robot, lambda: "knee" not in robot.latest.offline)
                reads = robot.telemetry["knee"].reads
                await frames_until(robot, lambda: robot.telemetry["knee"].reads >= reads + 3)  # (read well again)

    run_with_warnings(rig, main, caplog)
    assert not blind_said(caplog), blind_said(caplog)


def test_telemetry_that_cannot_be_read_is_not_said_where_no_limit_needs_it(caplog: pytest.LogCaptureFixture) -> None:
    rig = make_rig()  # no [safety] limits: the reads only feed the views, which show "-" by themselves

    async def main() -> None:
        with anyio.fail_after(GUARD):
            async with open_robot(rig.description, start_pose={"knee": 0.0}, **FAST) as robot:
                await frames_until(robot, lambda: robot.telemetry["knee"].temperature_c is not None)
                rig.lower.servo(2).ignores = frozenset({"read_temperature", "read_current"})
                errors = robot.telemetry["knee"].errors
                await frames_until(robot, lambda: robot.telemetry["knee"].errors >= errors + 3)

    run_with_warnings(rig, main, caplog)
    assert not blind_said(caplog)
