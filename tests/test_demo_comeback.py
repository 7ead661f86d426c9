"""A servo that comes back to a loop setting every target each cycle (ics35 demo's wave) joins it from where it
stands, not at the loop's target: it may have restarted (free) and been turned elsewhere meanwhile."""

from __future__ import annotations

import asyncio
import itertools
import threading
import time
from collections.abc import Callable
from typing import Any

import pytest

from ics35_async import InvalidArgument, Stream, open_bus
from ics35_async.policies import BlendIn, Joining
from ics35_async.protocol import FREE
from ics35_async.sim import VirtualLine, VirtualServo
from tests.support.robot_rig import commanded
from tests.support.timing import FAST, GUARD

TURNED_TO = 11000  # +118 degrees: far from any target of a 45-degree wave (7500 +- 1333)


def drop_restart_and_come_back(sim: VirtualLine, servo_id: int, ended: threading.Event, marks: dict[str, int]) -> None:
    """Once the wave drives ``servo_id`` (well past the demo's blend-in), unplug it; once the stream probes it
    (offline), power-cycle it (free), turn it by hand to TURNED_TO and plug it back.  ``marks["back"]``: the log's
    length when it is back.  By what the command has sent, not by the clock: a loaded machine runs fewer cycles."""

    def sent(command: str, since: int = 0) -> int:
        return sum(t.servo_id == servo_id and t.command == command for t in sim.log_since(since))

    while not ended.is_set() and sent("position") < 150:
        time.sleep(0.01)
    if ended.is_set():
        return
    servo = sim.remove_servo(servo_id)
    gone = sim.transactions

    def offline() -> bool:
        # Probed with a read that moves nothing, twice in a row: a guard read (the same read, after a timeout) is
        # followed by the position command it goes before, so one such read alone may be a servo only failing
        # (not offline: back then, it would take its next target, held by nothing).
        last = [t.command for t in sim.log_since(gone) if t.servo_id == servo_id][-2:]
        return last == ["read_stretch", "read_stretch"]

    while not ended.is_set() and not offline():
        time.sleep(0.01)
    servo.power_cycle()
    servo.move_by_hand(TURNED_TO)
    marks["back"] = sim.transactions
    sim.add_device(servo)


# (a slow wave: the step bound below holds beside a loop stalled a tenth of a second on a loaded machine)
SLOW_WAVE = ("--frequency", "0.1")


def demo_beside(cli: Any, url: str, seconds: str, servos: Callable[[threading.Event], None]) -> Any:
    """``ics35 demo`` on IDs 1-3 at ``url`` for ``seconds``, ``servos`` run beside it in a thread until it ends."""
    ended = threading.Event()
    beside = threading.Thread(target=servos, args=(ended,))
    beside.start()
    try:
        return cli("--port", url, "--timeout", "0.02", "demo", "--ids", "1-3", "--seconds", seconds, *SLOW_WAVE)
    finally:
        ended.set()
        beside.join()


def test_demo_brings_a_servo_that_restarted_elsewhere_back_into_the_wave_from_where_it_stands(
    cli: Any, sim_line: Any
) -> None:
    # Servo 3 lost power mid-wave, restarted (free), was turned by hand to 11000 and answered again: demo set every
    # target every frame, which lifted the stream's hold on it, and its first command was the wave's target (near
    # 7500): a jump across its range at full speed.  It is read where it stands (the free command) and blended
    # from there into the wave.
    sim, url = sim_line([1, 2, 3], realtime=True)
    marks: dict[str, int] = {}
    result = demo_beside(cli, url, "8", lambda ended: drop_restart_and_come_back(sim, 3, ended, marks))
    assert result.code == 0, result.err
    assert "back" in marks, "servo 3 never came back"
    after = list(commanded(sim, 3, marks["back"]))
    targets = [p for p in after if p != FREE]
    assert targets, after
    # Nothing but the free command (which reads it) before its first target, and that target where it stands.
    assert after[: after.index(targets[0])] and set(after[: after.index(targets[0])]) == {FREE}, after[:20]
    assert abs(targets[0] - TURNED_TO) < 100, targets[:10]
    # Then on into the wave without a step: the blend takes the demo's ramp, over many cycles.
    steps = [abs(b - a) for a, b in itertools.pairwise(targets)]
    assert max(steps) < 800, max(steps)
    assert min(targets) < 9000, targets[-10:]  # (it did reach the wave)
    summaries = [line for line in result.out.splitlines() if line.startswith("t=")]
    assert any("servo 3 came back" in line and f"from {TURNED_TO}" in line for line in summaries), result.out


def test_demo_brings_a_servo_plugged_in_once_the_wave_runs_in_from_where_it_stands(cli: Any, sim_line: Any) -> None:
    # ID 3, silent as demo asked it, started out of the stream's cycle; plugged in once the wave ran, it answered
    # its probe and was thrown to the wave's target.
    sim, url = sim_line([1, 2], realtime=True)
    marks: dict[str, int] = {}

    def plug_in_late(ended: threading.Event) -> None:
        while not ended.is_set() and sum(t.servo_id == 1 and t.command == "position" for t in sim.log_since(0)) < 100:
            time.sleep(0.01)
        marks["in"] = sim.transactions
        sim.add_device(VirtualServo(3, position=TURNED_TO))

    result = demo_beside(cli, url, "5", plug_in_late)
    assert result.code == 0, result.err
    assert "in" in marks, "servo 3 was never plugged in"
    targets = [p for p in commanded(sim, 3, marks["in"]) if p != FREE]
    assert targets and abs(targets[0] - TURNED_TO) < 100, targets[:10]
    assert max(abs(b - a) for a, b in itertools.pairwise(targets)) < 800, targets


GOAL = 7500
BLEND = 1.0  # seconds: a stall of the loop's thread (a loaded machine) under a tenth of it leaves no step of 600


async def drive(
    stream: Stream, blend: BlendIn, frames: int, goals: dict[int, int], seen: list[dict[int, Joining]]
) -> None:
    """Set ``goals`` through ``blend`` for ``frames`` frames, keeping what it said it was bringing in each one."""
    for _ in range(frames):
        frame = await asyncio.wait_for(stream.next_frame(), GUARD)
        blend.set_targets(goals, frame)
        seen.append(blend.joining)


async def drive_until_joined(
    stream: Stream, blend: BlendIn, goals: dict[int, int], seen: list[dict[int, Joining]]
) -> None:
    """Drive until every servo of ``goals`` is in (none being read or blended) and its target sent."""
    await drive(stream, blend, 5, goals, seen)
    for _ in range(2000):
        if not blend.joining:
            await drive(stream, blend, 3, goals, seen)  # (the last targets on the wire)
            return
        await drive(stream, blend, 1, goals, seen)
    raise AssertionError(f"still joining: {blend.joining}")


def came_in_from(sim: VirtualLine, servo_id: int, since: int, where: int) -> None:
    """What ``servo_id`` was sent since ``since``: the free command (which reads it), then targets from ``where``
    to GOAL without a step."""
    sent = list(commanded(sim, servo_id, since))
    targets = [p for p in sent if p != FREE]
    assert targets and targets[-1] == GOAL, sent[-10:]
    first = sent.index(targets[0])
    assert first and set(sent[:first]) == {FREE}, sent[:10]
    assert abs(targets[0] - where) < 200, targets[:5]
    assert max(abs(b - a) for a, b in itertools.pairwise(targets)) < 600, targets


@pytest.mark.parametrize("how", ["rejoined", "resumed"])
async def test_a_servo_back_restarted_elsewhere_is_read_and_blended_in_not_thrown(how: str) -> None:
    ids = [1, 2, 3]
    sim = VirtualLine([VirtualServo(i, position=GOAL + 300 * i) for i in ids], log_size=None)
    goals = dict.fromkeys(ids, GOAL)
    seen: list[dict[int, Joining]] = []
    async with (
        open_bus(sim, reconnect=True, **FAST) as bus,
        bus.stream(ids, rate_hz=200, offline_after=2, probe_interval=0.02) as stream,
    ):
        blend = BlendIn(stream, BLEND)
        await drive_until_joined(stream, blend, goals, seen)
        for i in ids:  # (each from where it stood as the loop began)
            came_in_from(sim, i, 0, GOAL + 300 * i)
        if how == "rejoined":
            servo = sim.remove_servo(2)
            while 2 not in (await asyncio.wait_for(stream.next_frame(), GUARD)).offline:
                pass
            servo.power_cycle()
            servo.move_by_hand(TURNED_TO)
            since = sim.transactions
            sim.add_device(servo)
        else:
            sim.unplug()
            sim.power_cycle(2)
            sim.move_by_hand(2, TURNED_TO)
            since = sim.transactions
            sim.replug()
        for _ in range(2000):  # (until its probe, or the port, is answered again: held, then read)
            if 2 in blend.joining:
                break
            await drive(stream, blend, 1, goals, seen)
        await drive_until_joined(stream, blend, goals, seen)
    came_in_from(sim, 2, since, TURNED_TO)
    said = [joining[2] for joining in seen if 2 in joining and joining[2].position is not None]
    assert said and said[-1].why == how and said[-1].position == TURNED_TO and said[-1].came_back, said[-1:]


async def test_a_servo_the_loop_freed_is_blended_in_again_from_where_it_was_turned() -> None:
    sim = VirtualLine([VirtualServo(1, position=GOAL)], log_size=None)
    seen: list[dict[int, Joining]] = []
    async with open_bus(sim, **FAST) as bus, bus.stream([1], rate_hz=200) as stream:
        blend = BlendIn(stream, BLEND)
        await drive_until_joined(stream, blend, {1: GOAL}, seen)
        await drive(stream, blend, 3, {1: FREE}, seen)
        sim.move_by_hand(1, 4000)
        since = sim.transactions
        await drive(stream, blend, 3, {1: FREE}, seen)
        await drive_until_joined(stream, blend, {1: GOAL}, seen)
    came_in_from(sim, 1, since, 4000)
    assert not any(joining.came_back for frame in seen for joining in frame.values())  # (freed, not back)


async def test_a_bad_target_changes_nothing_and_a_bad_blend_time_is_refused() -> None:
    sim = VirtualLine([VirtualServo(1, position=GOAL)], log_size=None)
    async with open_bus(sim, **FAST) as bus, bus.stream([1], rate_hz=200) as stream:
        with pytest.raises(InvalidArgument, match="seconds"):
            BlendIn(stream, -1)
        blend = BlendIn(stream, BLEND)
        frame = await asyncio.wait_for(stream.next_frame(), GUARD)
        with pytest.raises(InvalidArgument):
            blend.set_targets({1: GOAL, 9: GOAL}, frame)  # (ID 9 is not in the stream)
        assert blend.joining == {} and stream.target(1) == FREE
    # A stream that frees a servo as it comes back (on_resume="free") tells the loop nothing by a hold: the loop's
    # next target would throw it from wherever it restarted.  Refused, before anything is sent.
    async with open_bus(sim, **FAST) as bus, bus.stream([1], on_resume="free") as stream:
        with pytest.raises(InvalidArgument, match="on_resume"):
            BlendIn(stream, BLEND)
