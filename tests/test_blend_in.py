"""BlendIn is gentle: no blend runs faster than its speed limit however far the servo stands from the loop's target,
and a servo that can be read without freeing it (ICS 3.6's position read) is never freed to be read: a servo that
only missed replies on a standing robot would sag for that moment."""

from __future__ import annotations

import asyncio
import itertools
import math

import pytest

from ics35_async import InvalidArgument, Stream, open_bus, units
from ics35_async.policies import BlendIn, Joining
from ics35_async.protocol import FREE
from ics35_async.sim import VirtualLine, VirtualServo
from ics35_async.stream import WATCH
from tests.support.robot_rig import commanded
from tests.support.timing import FAST, GUARD

GOAL = 7500
FAR = 11000  # +118 degrees from GOAL


async def blend_until_joined(
    stream: Stream, blend: BlendIn, goals: dict[int, int], sent: list[tuple[float, dict[int, int]]]
) -> list[dict[int, Joining]]:
    """Set ``goals`` through ``blend`` each frame until no servo is being brought in (and a few frames more: the
    last targets on the wire); ``sent`` gets each frame's time and the targets set.  Returns what it said it was
    bringing in, frame by frame."""
    seen: list[dict[int, Joining]] = []
    done = 0
    for _ in range(5000):
        frame = await asyncio.wait_for(stream.next_frame(), GUARD)
        sent.append((frame.finished, blend.set_targets(goals, frame)))
        seen.append(blend.joining)
        done = done + 1 if not blend.joining and len(seen) > 5 else 0
        if done > 3:
            return seen
    raise AssertionError(f"still joining: {blend.joining}")


def steepest(sent: list[tuple[float, dict[int, int]]], servo_id: int) -> float:
    """The fastest the targets set for ``servo_id`` moved between two frames, in degrees per second."""
    targets = [(t, out[servo_id]) for t, out in sent if out.get(servo_id, FREE) not in (FREE, WATCH)]
    speeds = [
        # (a count each way is rounding: the targets are whole counts)
        max(0, abs(b - a) - 1) / units.COUNTS_PER_DEGREE / (t1 - t0)
        for (t0, a), (t1, b) in itertools.pairwise(targets)
        if t1 > t0
    ]
    assert speeds, targets[:5]
    return max(speeds)


@pytest.mark.parametrize("max_speed", [None, 30.0])
async def test_a_long_way_is_blended_no_faster_than_the_speed_limit(max_speed: float | None) -> None:
    # 118 degrees in the blend's 1 s: smoothstep's steepest point ran at 1.5 * 118 = 177 degrees a second, near a
    # servo's top speed.  The blend takes as long as the speed limit needs (60 degrees a second by default).
    sim = VirtualLine([VirtualServo(1, position=FAR), VirtualServo(2, position=GOAL + 150)], log_size=None)
    sent: list[tuple[float, dict[int, int]]] = []
    async with open_bus(sim, **FAST) as bus, bus.stream([1, 2], rate_hz=200) as stream:
        blend = BlendIn(stream, 1.0) if max_speed is None else BlendIn(stream, 1.0, max_speed=max_speed)
        seen = await blend_until_joined(stream, blend, {1: GOAL, 2: GOAL}, sent)
    limit = 60.0 if max_speed is None else max_speed
    assert steepest(sent, 1) <= limit, steepest(sent, 1)
    assert sent[-1][1] == {1: GOAL, 2: GOAL}
    far = [joining[1] for joining in seen if 1 in joining and joining[1].position is not None]
    degrees = (FAR - GOAL) / units.COUNTS_PER_DEGREE
    assert far and far[-1].seconds == pytest.approx(1.5 * degrees / limit), far[-1]
    # A short way takes the blend's seconds all the same: the shortest blend.
    near = [joining[2] for joining in seen if 2 in joining and joining[2].position is not None]
    assert near and near[-1].seconds == 1.0, near[-1]
    # And the smoothstep's shape: it starts and ends slowly, fastest halfway.
    moved = [out[1] for _, out in sent if out.get(1, FREE) != FREE]
    first, last = moved[1] - moved[0], moved[-1] - moved[-2] if moved[-1] != moved[-2] else 0
    assert abs(first) < 20 and abs(last) < 20, (moved[:3], moved[-3:])


@pytest.mark.parametrize("bad", [0, -5, 1e9, math.nan, math.inf, True, "fast", None])
async def test_a_bad_speed_limit_is_refused_with_its_name(bad: object) -> None:
    sim = VirtualLine([VirtualServo(1, position=GOAL)], log_size=None)
    async with open_bus(sim, **FAST) as bus, bus.stream([1], rate_hz=200) as stream:
        with pytest.raises(InvalidArgument, match=r"max_speed .*degrees per second"):
            BlendIn(stream, 1.0, max_speed=bad)  # type: ignore[arg-type]
        assert stream.target(1) == FREE  # (nothing sent for it)


def frees_sent(sim: VirtualLine, servo_id: int, since: int) -> int:
    return sum(p == FREE for p in commanded(sim, servo_id, since))


def reads_sent(sim: VirtualLine, servo_id: int, since: int) -> int:
    return sum(t.servo_id == servo_id and t.command == "read_position" for t in sim.log_since(since))


@pytest.mark.parametrize("how", ["rejoined", "resumed"])
@pytest.mark.parametrize("known", ["watched", "probed"])
async def test_an_ics36_servo_back_holding_is_read_without_freeing_it(how: str, known: str) -> None:
    # An ICS 3.6 servo that only missed replies (a loose plug: still powered, holding where the loop left it) was
    # sent the free command to be read: on a standing robot its joint sagged for that moment.  ICS 3.6's position
    # read says where it stands and leaves its torque alone.  Known as ICS 3.6 by the stream's watch at the start,
    # or by a probe of the line (Servo.has_position_read, as plan_position_stream asks).
    ids = [1, 2, 3]
    sim = VirtualLine([VirtualServo(i, position=GOAL + 200 * i, ics36=True) for i in ids], log_size=None)
    goals = dict.fromkeys(ids, GOAL)
    sent: list[tuple[float, dict[int, int]]] = []
    async with open_bus(sim, reconnect=True, **FAST) as bus:
        if known == "probed":
            assert all([await bus.servo(i).has_position_read() for i in ids])
        watch = ids if known == "watched" else []
        async with bus.stream(ids, rate_hz=200, offline_after=2, probe_interval=0.02, watch=watch) as stream:
            blend = BlendIn(stream, 0.2)
            await blend_until_joined(stream, blend, goals, sent)
            if known == "watched":  # (watched at the start: read so, never freed, from the first frame)
                assert frees_sent(sim, 2, 0) == 0
            assert sim.servo(2).target == GOAL
            if how == "rejoined":
                servo = sim.remove_servo(2)
                while 2 not in (await asyncio.wait_for(stream.next_frame(), GUARD)).offline:
                    pass
                since = sim.transactions
                sim.add_device(servo)
            else:
                sim.unplug()
                since = sim.transactions
                sim.replug()
            seen: list[dict[int, Joining]] = []
            for _ in range(2000):  # (until its probe, or the port, is answered again: held, then read)
                frame = await asyncio.wait_for(stream.next_frame(), GUARD)
                blend.set_targets(goals, frame)
                seen.append(blend.joining)
                if 2 in blend.joining:
                    break
            seen += await blend_until_joined(stream, blend, goals, sent)
    assert frees_sent(sim, 2, since) == 0, list(commanded(sim, 2, since))[:10]
    assert reads_sent(sim, 2, since) >= 1
    assert not sim.servo(2).free and sim.servo(2).target == GOAL
    said = [joining[2] for joining in seen if 2 in joining]
    assert said and said[-1].why == how and not said[-1].frees, said[-1:]


async def test_an_ics35_servo_back_is_still_read_with_the_free_command() -> None:
    # Nothing else can say where an ICS 3.5 servo stands: it is read with the free command, as before.
    ids = [1, 2]
    sim = VirtualLine([VirtualServo(i, position=GOAL) for i in ids], log_size=None)
    goals = dict.fromkeys(ids, GOAL)
    sent: list[tuple[float, dict[int, int]]] = []
    async with open_bus(sim, **FAST) as bus:
        assert not await bus.servo(2).has_position_read()
        async with bus.stream(ids, rate_hz=200, offline_after=2, probe_interval=0.02) as stream:
            blend = BlendIn(stream, 0.2)
            await blend_until_joined(stream, blend, goals, sent)
            servo = sim.remove_servo(2)
            while 2 not in (await asyncio.wait_for(stream.next_frame(), GUARD)).offline:
                pass
            servo.power_cycle()
            servo.move_by_hand(FAR)
            since = sim.transactions
            sim.add_device(servo)
            for _ in range(2000):
                frame = await asyncio.wait_for(stream.next_frame(), GUARD)
                blend.set_targets(goals, frame)
                if 2 in blend.joining:
                    break
            assert blend.joining[2].frees
            await blend_until_joined(stream, blend, goals, sent)
    assert frees_sent(sim, 2, since) >= 1 and reads_sent(sim, 2, since) == 0
    targets = [p for p in commanded(sim, 2, since) if p != FREE]
    assert abs(targets[0] - FAR) < 100 and targets[-1] == GOAL, targets[:5]


async def test_a_watched_servo_of_untold_protocol_silent_to_the_read_is_freed_to_be_read_once_offline() -> None:
    # Watched by the program (its protocol told by nobody), an ICS 3.5 servo stays silent to ICS 3.6's read: kept
    # watched, it would stay offline, never brought in.  Offline unheard, nothing else can say where it stands.
    sim = VirtualLine([VirtualServo(1, position=GOAL, ics36=True), VirtualServo(2, position=FAR)], log_size=None)
    sent: list[tuple[float, dict[int, int]]] = []
    async with (
        open_bus(sim, **FAST) as bus,
        bus.stream([1, 2], rate_hz=200, offline_after=2, probe_interval=0.02, watch=[1, 2]) as stream,
    ):
        blend = BlendIn(stream, 0.2)
        seen = await blend_until_joined(stream, blend, {1: GOAL, 2: GOAL}, sent)
    assert frees_sent(sim, 1, 0) == 0  # (the ICS 3.6 one, heard answering the read: never freed)
    assert frees_sent(sim, 2, 0) >= 1
    targets = [p for p in commanded(sim, 2, 0) if p != FREE]
    assert abs(targets[0] - FAR) < 100 and targets[-1] == GOAL, targets[:5]
    said = [joining[2] for joining in seen if 2 in joining and joining[2].position is not None]
    assert said and said[0].frees, said[:1]


async def test_a_moving_loop_target_adds_no_speed_to_a_blend() -> None:
    # The loop's target swings at up to 40 degrees a second while servo 1 comes in from 118 degrees away: blended
    # from where it stood towards a target that moves, the targets set ran at the blend's speed plus the target's
    # own (about 90 degrees a second).  No target set moves faster than the limit, and the blend still ends on the
    # loop's target, which it then follows.
    sim = VirtualLine([VirtualServo(1, position=FAR)], log_size=None)
    sent: list[tuple[float, dict[int, int]]] = []
    amplitude = 40.0 / (2 * math.pi * 0.5) * units.COUNTS_PER_DEGREE  # (0.5 Hz: at most 40 degrees a second)
    async with open_bus(sim, **FAST) as bus, bus.stream([1], rate_hz=200) as stream:
        blend = BlendIn(stream, 1.0)
        start = None
        for _ in range(5000):
            frame = await asyncio.wait_for(stream.next_frame(), GUARD)
            start = frame.finished if start is None else start
            goal = round(GOAL + amplitude * math.sin(2 * math.pi * 0.5 * (frame.finished - start)))
            sent.append((frame.finished, blend.set_targets({1: goal}, frame)))
            if not blend.joining and len(sent) > 5:
                break
        for _ in range(40):  # (and following the loop's target once joined)
            frame = await asyncio.wait_for(stream.next_frame(), GUARD)
            goal = round(GOAL + amplitude * math.sin(2 * math.pi * 0.5 * (frame.finished - start)))
            sent.append((frame.finished, blend.set_targets({1: goal}, frame)))
            assert sent[-1][1] == {1: goal}
    assert steepest(sent, 1) <= 60.0, steepest(sent, 1)
