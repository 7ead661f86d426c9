"""Motions never leave their envelope: every command a motion, a stop or a cancelled motion sends lies, per joint,
between the pose the motion started from and the targets it was given (and inside the joint's limits).

The commands are decoded from the simulator's transaction log, never taken from the robot's bookkeeping.
"""

from __future__ import annotations

import contextlib
import itertools
from typing import Any

import anyio
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ics35_async import Robot, open_robot, units
from ics35_async.robot import MotionStopped
from tests.support.robot_rig import JOINTS, Rig, joint_degrees, make_rig, targets_sent
from tests.support.timing import FAST, GUARD

# Degrees: a command is rounded to whole counts, so it may sit this far outside the exact interval.
HALF_COUNT = 0.5 / units.COUNTS_PER_DEGREE + 1e-9
COUNT = 1 / units.COUNTS_PER_DEGREE + 1e-9


def seq_now(rig: Rig) -> dict[str, int]:
    return {"upper": rig.upper.transactions, "lower": rig.lower.transactions}


def sent_degrees(rig: Rig, name: str, since: dict[str, int]) -> list[float]:
    spec = JOINTS[name]
    return [joint_degrees(spec, p) for p in targets_sent(rig.sim(spec["line"]), spec["id"], since[spec["line"]])]


def check_envelope(rig: Rig, since: dict[str, int], start: dict[str, float], targets: list[dict[str, float]]) -> None:
    """Every command to a joint the motion names lies between its start and its targets, and within its limits."""
    for name, spec in JOINTS.items():
        sent = sent_degrees(rig, name, since)
        # A joint the motion never names holds its start (the stream repeats its target every cycle).
        named = [pose[name] for pose in targets if name in pose] or [start[name]]
        # The nearest count within the limits: half a count from the angle, a whole one at a limit, and
        # never past the limit itself.
        low = max(min(start[name], *named) - COUNT, spec["min"] - 1e-9)
        high = min(max(start[name], *named) + COUNT, spec["max"] + 1e-9)
        outside = [d for d in sent if not low <= d <= high]
        assert not outside, (name, low, high, outside)


def run_robot(rig: Rig, body: Any) -> None:
    async def main() -> None:
        with anyio.fail_after(GUARD):
            async with open_robot(rig.description, **FAST) as robot:
                await body(robot)

    try:
        anyio.run(main)
    finally:
        rig.close()


def test_a_stop_ends_at_or_before_the_motions_target() -> None:
    """move_to shoulder -60 in 0.5 s, stop(ramp=0.3) 0.3 s in: the joint slows down and rests at -60 at most."""
    rig = make_rig()
    caught: list[BaseException] = []
    since: dict[str, int] = {}

    stop_returned: list[bool] = []
    at_rest_when_told: list[bool] = []

    async def body(robot: Robot) -> None:
        await robot.move_to({"shoulder": 0.0}, duration=0.05)
        since.update(seq_now(rig))

        async def mover() -> None:
            try:
                await robot.move_to({"shoulder": -60.0}, duration=0.5)
            except MotionStopped as exc:
                caught.append(exc)
                # Told once the joint is at rest (the ramp over), not as the stop begins: code after
                # the motion (a blocking program leaving its with block) must not cut the ramp short.
                at_rest_when_told.append(bool(stop_returned))

        async with anyio.create_task_group() as tasks:
            tasks.start_soon(mover)
            await anyio.sleep(0.3)
            await robot.stop(ramp=0.3)
            stop_returned.append(True)
        await robot.on_wire()

    run_robot(rig, body)
    sent = sent_degrees(rig, "shoulder", since)
    assert len(caught) == 1 and at_rest_when_told == [True]
    assert min(sent) >= -60.0 - HALF_COUNT, min(sent)
    # It kept going the way it went (no jump back), and came to rest.
    assert all(b <= a + HALF_COUNT for a, b in itertools.pairwise(sent)), sent


async def knee_up_until_stopped(robot: Robot) -> None:
    """The knee's 2 s linear move up to 15 degrees, which a stop cuts short (MotionStopped, as expected)."""
    with pytest.raises(MotionStopped):
        await robot.move_to({"knee": 15.0}, duration=2.0, profile="linear")


def test_a_stop_with_room_left_still_slows_down_over_its_ramp() -> None:
    """Far from its target, a stopped joint goes on for a while (not frozen) and rests short of the target."""
    rig = make_rig()
    since: dict[str, int] = {}

    async def body(robot: Robot) -> None:
        await robot.move_to({"knee": -90.0}, duration=0.05)
        since.update(seq_now(rig))
        async with anyio.create_task_group() as tasks:
            tasks.start_soon(knee_up_until_stopped, robot)
            await anyio.sleep(0.2)
            await robot.stop(ramp=0.3)
        await robot.on_wire()

    run_robot(rig, body)
    sent = sent_degrees(rig, "knee", since)
    assert sent[-1] < 15.0 - 10.0  # at about 52 degrees/s, 0.3 s of ramp covers some 8 degrees
    rest = [d for d in sent if d > sent[-1] - 10.0]
    assert len(set(rest)) > 3  # it went on moving while slowing down


def test_a_stop_ends_at_or_before_the_keyframe_its_joint_is_heading_for() -> None:
    """Stopped on its way back to a keyframe the motion turns at (-90, then -40, then -90 again), the knee comes
    to rest on -40 at most: not past it, towards the poses of the motion's other keyframes."""
    rig = make_rig()
    since: dict[str, int] = {}
    motion = {
        "format": "ics35-motion",
        "version": 1,
        "profile": "linear",
        "keyframes": [
            {"time": 0.4, "pose": {"knee": -90.0}},
            {"time": 0.8, "pose": {"knee": -40.0}},
            {"time": 1.2, "pose": {"knee": -90.0}},
        ],
    }
    at_stop: list[float] = []

    async def body(robot: Robot) -> None:
        await robot.move_to({"knee": 0.0}, duration=0.05)
        async with anyio.create_task_group() as tasks:

            async def player() -> None:
                with contextlib.suppress(MotionStopped):
                    await robot.play(motion)

            tasks.start_soon(player)
            await anyio.sleep(0.7)
            since.update(seq_now(rig))
            at_stop.append(robot.targets["knee"] or 0.0)
            await robot.stop(ramp=0.6)  # at 125 degrees/s, 0.6 s of ramp would carry it some 37 degrees
        await robot.on_wire()

    run_robot(rig, body)
    sent = sent_degrees(rig, "knee", since)
    assert -90.0 < at_stop[0] < -40.0, at_stop  # (on its way from -90 to -40 when stopped)
    assert max(sent) <= -40.0 + HALF_COUNT, (at_stop, max(sent))


def test_a_stop_taken_over_by_another_stop_returns_once_the_joints_are_at_rest() -> None:
    """Two stops (a watchdog's and a finally's): the first one's ramp, taken over by the second, is no error: it
    returns as the second does, the joints at rest, instead of raising MotionStopped into the close-out."""
    rig = make_rig()
    outcomes: dict[str, str] = {}
    since: dict[str, int] = {}

    async def body(robot: Robot) -> None:
        await robot.move_to({"knee": -90.0}, duration=0.05)
        since.update(seq_now(rig))
        async with anyio.create_task_group() as tasks:

            async def stopper(name: str, delay: float) -> None:
                await anyio.sleep(delay)
                try:
                    await robot.stop(ramp=0.4)
                except MotionStopped as exc:
                    outcomes[name] = f"MotionStopped: {exc}"
                else:
                    outcomes[name] = f"at rest at {robot.targets['knee']}"

            tasks.start_soon(knee_up_until_stopped, robot)
            tasks.start_soon(stopper, "first", 0.2)
            tasks.start_soon(stopper, "second", 0.3)
        await robot.on_wire()

    run_robot(rig, body)
    sent = sent_degrees(rig, "knee", since)
    # Both returned with the joint at rest, where the second stop's ramp left it.
    assert outcomes.keys() == {"first", "second"} and outcomes["first"] == outcomes["second"], outcomes
    assert outcomes["first"].startswith("at rest"), outcomes
    assert all(b >= a - HALF_COUNT for a, b in itertools.pairwise(sent)), sent  # no jump back


def test_a_second_stop_in_the_same_moment_as_the_first_returns_once_the_joints_are_at_rest() -> None:
    """Two stops called together (before the first one's ramp has run a step): the second takes the ramp over as
    it would later, instead of finding nothing moving and returning while the joint still slows down."""
    rig = make_rig()
    outcomes: dict[str, float | None] = {}

    async def body(robot: Robot) -> None:
        await robot.move_to({"knee": -90.0}, duration=0.05)
        async with anyio.create_task_group() as tasks:

            async def stopper(name: str) -> None:
                await robot.stop(ramp=0.4)
                outcomes[name] = robot.targets["knee"]

            tasks.start_soon(knee_up_until_stopped, robot)
            await anyio.sleep(0.2)
            tasks.start_soon(stopper, "first")
            tasks.start_soon(stopper, "second")
        await robot.on_wire()

    run_robot(rig, body)
    assert outcomes.keys() == {"first", "second"} and outcomes["first"] == outcomes["second"], outcomes


def test_a_stop_leaves_a_joint_at_rest_since_its_motion_was_cancelled() -> None:
    """A motion cancelled half way (a timeout around it), the joint at rest a while: a stop() for another motion
    does not set it moving again at the speed it had when cancelled."""
    rig = make_rig()
    since: dict[str, int] = {}
    rested: list[float] = []

    async def body(robot: Robot) -> None:
        await robot.move_to({"shoulder": 0.0, "knee": 0.0}, duration=0.05)
        with anyio.move_on_after(0.3):
            await robot.move_to({"shoulder": -80.0}, duration=1.0, profile="linear")
        await anyio.sleep(0.3)  # the shoulder holds where the motion left it
        rested.append(sent_degrees(rig, "shoulder", {"upper": 0})[-1])
        since.update(seq_now(rig))
        async with anyio.create_task_group() as tasks:

            async def knee() -> None:
                with pytest.raises(MotionStopped):
                    await robot.move_to({"knee": -60.0}, duration=1.0)

            tasks.start_soon(knee)
            await anyio.sleep(0.2)
            await robot.stop(ramp=0.3)
        await robot.on_wire()

    run_robot(rig, body)
    sent = sent_degrees(rig, "shoulder", since)
    assert -80.0 < rested[0] < -1.0, rested  # (the motion was under way when it was cancelled)
    assert sent and all(abs(d - rested[0]) <= HALF_COUNT for d in sent), (rested, sorted(set(sent)))


def test_a_stop_right_after_a_cancelled_motion_slows_its_joint_down() -> None:
    """Ctrl-C in a program that stops in its finally: the joint goes on at its speed and slows to rest."""
    rig = make_rig()
    since: dict[str, int] = {}
    at_cancel: list[float] = []

    async def body(robot: Robot) -> None:
        await robot.move_to({"knee": -90.0}, duration=0.05)
        since.update(seq_now(rig))
        with anyio.move_on_after(0.2):
            try:
                await robot.move_to({"knee": 15.0}, duration=2.0, profile="linear")
            finally:
                with anyio.CancelScope(shield=True):
                    at_cancel.append(robot.targets["knee"] or 0.0)
                    await robot.stop(ramp=0.3)
        await robot.on_wire()

    run_robot(rig, body)
    sent = sent_degrees(rig, "knee", since)
    # Slowed to rest from 52.5 degrees a second over 0.3 s: about 7.9 degrees on past the target it had at the
    # cancel (frozen there, it would go no further; kept at its speed, far more).  Judged by distance, which the
    # ramp's clock sets, not by how many cycles a loaded machine ran in it.
    assert 2.0 < sent[-1] - at_cancel[0] < 12.0, (at_cancel, sent[-5:])


angles = {name: st.floats(spec["min"], spec["max"], allow_nan=False) for name, spec in JOINTS.items()}
pose_strategy = st.fixed_dictionaries({}, optional=angles)
start_strategy = st.fixed_dictionaries(angles)


@st.composite
def motions(draw: st.DrawFn) -> list[dict[str, Any]]:
    count = draw(st.integers(1, 3))
    keyframes, time = [], 0.0
    for _ in range(count):
        time += draw(st.floats(0.03, 0.25))
        frame: dict[str, Any] = {"time": round(time, 3), "pose": draw(pose_strategy.filter(bool))}
        if draw(st.booleans()):
            frame["profile"] = draw(st.sampled_from(["minjerk", "linear"]))
        keyframes.append(frame)
    return keyframes


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    start=start_strategy,
    keyframes=motions(),
    profile=st.sampled_from(["minjerk", "linear"]),
    stop_after=st.floats(0.0, 0.6),
    ramp=st.floats(0.0, 0.8),
    how=st.sampled_from(["stop", "cancel then stop", "loop then stop"]),
)
@pytest.mark.slow
def test_no_command_leaves_the_motions_envelope(
    start: dict[str, float], keyframes: list[dict[str, Any]], profile: str, stop_after: float, ramp: float, how: str
) -> None:
    """Random motions (both profiles, reversed joints, offsets), stopped, cancelled or looped at random times."""
    rig = make_rig()
    since: dict[str, int] = {}
    data = {"format": "ics35-motion", "version": 1, "profile": profile, "keyframes": keyframes}

    async def body(robot: Robot) -> None:
        await robot.move_to(start, duration=0.05)
        since.update(seq_now(rig))
        playing = anyio.CancelScope()

        async def player() -> None:
            with playing, contextlib.suppress(MotionStopped):
                await robot.play(data, loop=how == "loop then stop")

        async with anyio.create_task_group() as tasks:
            tasks.start_soon(player)
            await anyio.sleep(stop_after)
            if how == "cancel then stop":
                playing.cancel()  # the play's task is cancelled (as Ctrl-C does): then the smooth stop
                await anyio.sleep(0)
            await robot.stop(ramp=ramp)
            playing.cancel()  # a player that had not begun when stop() came would never end
        await robot.on_wire()

    run_robot(rig, body)
    check_envelope(rig, since, start, [frame["pose"] for frame in keyframes])
