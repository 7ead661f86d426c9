"""Position streaming against the in-process simulator (fast mode unless stated).

The simulator's transaction log is the ground truth: every frame is checked
against what each servo actually reported on the wire, waits are measured in
transactions on the simulated line, and rates in the stream's own loop-time
bookkeeping, never by wall-clock assertions.  Servos start at distinct
positions (and get distinct RAM values where it matters) so a reply handed to
the wrong ID shows up as a wrong value.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import json
import sys
import threading
import time
from collections.abc import AsyncIterator, Awaitable, Callable, Iterable, Sequence
from typing import Any

import anyio
import pytest

from ics35_async import (
    BaudRate,
    BusClosed,
    BusGroup,
    Frame,
    GroupFrame,
    GroupStream,
    InvalidArgument,
    LiveReadings,
    Param,
    PortLost,
    Priority,
    ReplyError,
    State,
    Stream,
    open_bus,
    protocol,
    units,
)
from ics35_async.bus import Bus
from ics35_async.protocol import FREE, ReadParam, position_tx
from ics35_async.sim import PtyServer, Transaction, VirtualLine, VirtualServo
from ics35_async.stream import RATE_CHECK_CYCLES, RATE_KEPT_WINDOWS
from tests.conftest import every_backend
from tests.support.timing import FAST, GUARD, NO_TIMEOUTS, PATIENT, REAL_TIME

POSITION_COMMANDS = ("position", "free")  # the sim logs a position-0 command as "free"
STREAM_COMMANDS = (*POSITION_COMMANDS, "read_stretch")  # (an offline ID with a target is probed with a read)


def start_position(i: int) -> int:
    return 4000 + 100 * i


def make_sim(ids: Iterable[int] = range(32), **options: Any) -> VirtualLine:
    """Servos at distinct start positions with distinct RAM stretch values; an unbounded log.  The servos
    talk at the line's ``baudrate`` (default 115200)."""
    servos = []
    for i in ids:
        servo = VirtualServo(i, position=start_position(i), baud_rate=options.get("baudrate", 115200))
        servo.stretch = 40 + i
        servos.append(servo)
    options.setdefault("log_size", None)
    return VirtualLine(servos, **options)


@contextlib.asynccontextmanager
async def streaming(sim: VirtualLine, ids: Sequence[int], **options: Any) -> AsyncIterator[tuple[Bus, Stream]]:
    async with open_bus(sim, **FAST) as bus, bus.stream(ids, **options) as stream:
        yield bus, stream


async def next_frame(stream: Stream | GroupStream) -> Any:
    return await asyncio.wait_for(stream.next_frame(), GUARD)


async def frames_until(stream: Stream, done: Callable[[Frame], bool], limit: int = 5000) -> list[Frame]:
    """Frames up to and including the first one for which ``done`` holds."""
    frames = []
    for _ in range(limit):
        frame = await next_frame(stream)
        frames.append(frame)
        if done(frame):
            return frames
    raise AssertionError(f"condition not met within {limit} frames; last {frames[-1]}")


async def wait_for_sim(condition: Callable[[], bool], what: str) -> None:
    try:
        async with asyncio.timeout(GUARD):
            while not condition():
                await asyncio.sleep(0.001)
    except TimeoutError:
        raise AssertionError(f"gave up waiting for: {what}") from None


def position_log(sim: VirtualLine, since: int = 0) -> list[Transaction]:
    return [t for t in sim.log_since(since) if t.command in POSITION_COMMANDS]


def split_cycles(entries: Sequence[Transaction], ids: Sequence[int]) -> list[list[Transaction]]:
    """Cut a stream's position transactions into cycles: each cycle visits its IDs in stream order."""
    index = {sid: k for k, sid in enumerate(ids)}
    cycles: list[list[Transaction]] = []
    previous = len(ids)
    for t in entries:
        assert t.servo_id in index, t
        k = index[t.servo_id]
        if k <= previous:
            cycles.append([])
        cycles[-1].append(t)
        previous = k
    return cycles


def check_frame(frame: Frame, cycle_log: Sequence[Transaction]) -> None:
    """The frame holds exactly what the servos reported in that cycle; silent IDs are ``failed``."""
    assert frame.positions == {t.servo_id: t.value for t in cycle_log if t.reply and t.command != "read_stretch"}
    # (an ID held back after a failure is failed and was sent nothing: not_sent)
    assert frame.failed - frame.not_sent == {t.servo_id for t in cycle_log if not t.reply}, frame.cycle
    assert frame.not_sent <= frame.failed and not frame.not_sent & {t.servo_id for t in cycle_log}, frame.cycle
    assert set(frame.timestamps) == set(frame.positions)
    assert frame.started <= min(frame.timestamps.values(), default=frame.started)
    assert max(frame.timestamps.values(), default=frame.finished) <= frame.finished


def check_frames(
    frames: Iterable[Frame], sim: VirtualLine, ids: Sequence[int], since: int = 0, commands: Sequence[str] = ()
) -> None:
    """Check frames of a stream whose first cycle began at log seq ``since`` (no other position traffic;
    ``commands``: the stream's others, an offline ID's probe reads: ``STREAM_COMMANDS``)."""
    commands = commands or POSITION_COMMANDS
    cycles = split_cycles([t for t in sim.log_since(since) if t.command in commands], ids)
    for frame in frames:
        check_frame(frame, cycles[frame.cycle - 1])


def percentile(values: Sequence[int], p: int) -> int:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, max(0, -(-len(ordered) * p // 100) - 1))]


# --------------------------------------------------------------------------- 32 IDs: values, order, latest value


async def test_32_ids_frames_carry_reported_positions_and_targets_apply_in_order() -> None:
    ids = list(range(32))
    sim = make_sim(ids)
    async with streaming(sim, ids) as (_, stream):
        frames = [await next_frame(stream)]
        steps: list[tuple[int, dict[int, int]]] = []  # (first seq written after the change, targets)
        superseded = []
        for step in range(5):
            targets = {i: 5000 + 150 * i + 400 * step for i in ids}
            # Latest value: a target replaced before the next cycle never reaches the wire.
            junk = 12000 + step
            stream.set_target(1, junk)
            superseded.append(position_tx(1, junk))
            stream.set_targets(targets)
            assert stream.target(1) == targets[1]
            seq = sim.transactions  # the transaction on the wire was written before the change
            steps.append((seq, targets))
            # Wait for a whole cycle that started after the change.
            frames += await frames_until(stream, lambda f, seq=seq: (f.cycle - 1) * 32 >= seq)
        frames += [await next_frame(stream) for _ in range(3)]

    log = sim.log_since(0)
    assert all(t.command in POSITION_COMMANDS for t in log)  # no other traffic
    # Cycle k's position transactions are log entries [(k-1)*32, k*32), in ID order.
    for frame in frames:
        cycle_log = log[(frame.cycle - 1) * 32 : frame.cycle * 32]
        assert [t.servo_id for t in cycle_log] == ids
        assert frame.positions == {t.servo_id: t.value for t in cycle_log}
        assert frame.failed == frozenset() and frame.offline == frozenset()
        assert set(frame.timestamps) == set(ids)
    assert [f.cycle for f in frames] == sorted({f.cycle for f in frames})
    # The servos moved, so the check above compared changing values.
    assert len({f.positions[20] for f in frames}) > 3

    # Every ID starts free: the first cycle sends position 0 to each.
    assert [t.tx for t in log[:32]] == [position_tx(i, 0) for i in ids]
    # Targets apply in order: after each change every position command carries the new target.
    bounds = [seq for seq, _ in steps] + [len(log)]
    assert all(t.tx == position_tx(t.servo_id, 0) for t in log[: bounds[0]])
    for (seq, targets), end in zip(steps, bounds[1:], strict=True):
        chunk = log[seq:end]
        assert {t.servo_id for t in chunk} == set(ids)  # each target went out at least once
        assert all(t.tx == position_tx(t.servo_id, targets[t.servo_id]) for t in chunk)
    assert not any(t.tx in superseded for t in log)
    last_targets = steps[-1][1]
    assert all(sim.servo(i).target == last_targets[i] for i in ids)


# --------------------------------------------------------------------------- sharing the line


async def test_concurrent_telemetry_is_correct_and_waits_at_most_one_position_transaction() -> None:
    ids = list(range(32))
    sim = make_sim(ids)
    rounds = 30
    results: list[tuple[int, int, Param, int]] = []  # (sim.transactions at submission, id, param, value)
    async with streaming(sim, ids) as (bus, stream):
        stream.set_targets({i: 6000 + 60 * i for i in ids})  # moving servos draw current
        first = await next_frame(stream)

        async def poll(c: int) -> None:
            # Poller c alone talks to IDs c and c + 16, so its command bytes are its own.
            for r in range(rounds):
                sid = c if r % 2 == 0 else c + 16
                param = (Param.STRETCH, Param.CURRENT, Param.TEMPERATURE)[r % 3]
                submitted = sim.transactions
                value = await bus.request(ReadParam(sid, param))
                results.append((submitted, sid, param, value))

        await asyncio.wait_for(asyncio.gather(*(poll(c) for c in range(16))), 30)
        last = await next_frame(stream)
        assert stream.stats.failures == {}

    log = sim.log_since(0)
    waits = []
    for submitted, sid, param, value in results:
        tx = ReadParam(sid, param).tx
        own = next(t for t in log[submitted:] if t.tx == tx)
        assert value == own.value, (sid, param)
        if param is Param.STRETCH:
            assert value == 40 + sid
        waits.append(sum(t.command in POSITION_COMMANDS for t in log[submitted : own.seq]))
    assert len(results) == 16 * rounds
    # Policy: a request waits for the position transaction already on the wire (written before
    # it was submitted, so not counted here) plus at most one more when max_requests_between
    # requests ran back to back.
    assert max(waits) <= 2
    counts = {n: waits.count(n) for n in sorted(set(waits))}
    print(
        f"\ntelemetry waits in position transactions: p50={percentile(waits, 50)} "
        f"p99={percentile(waits, 99)} max={max(waits)} distribution={counts}"
    )
    # The stream kept going: at most max_requests_between requests ran between two of its transactions.
    during = log[results[0][0] : 1 + max(t.seq for t in log if t.command not in POSITION_COMMANDS)]
    requests = sum(t.command not in POSITION_COMMANDS for t in during)
    assert requests == len(results)
    assert sum(t.command in POSITION_COMMANDS for t in during) >= requests // 16 - 1
    assert last.cycle > first.cycle
    check_frames([first, last], sim, ids)


async def test_a_flood_of_requests_lets_a_position_transaction_through_every_max_requests_between() -> None:
    ids = list(range(8))
    sim = make_sim(ids)
    async with streaming(sim, ids) as (bus, stream):
        await next_frame(stream)
        submitted = sim.transactions
        futures = [bus.submit(ReadParam(i % 8, Param.STRETCH)) for i in range(3 * bus.max_requests_between + 5)]
        values = await asyncio.wait_for(asyncio.gather(*futures), GUARD)
        assert values == [40 + i % 8 for i in range(len(futures))]
        limit = bus.max_requests_between
    log = sim.log_since(submitted)
    runs, run = [], 0
    for t in log:
        if t.command in POSITION_COMMANDS:
            runs.append(run)
            run = 0
        else:
            run += 1
    runs.append(run)
    assert max(runs) == limit  # never more requests in a row, and the limit was reached
    assert sum(runs) == len(futures)


# --------------------------------------------------------------------------- dead IDs


@pytest.mark.realtime
async def test_dead_id_goes_offline_is_probed_at_a_low_rate_and_rejoins() -> None:
    ids = list(range(32))
    dead = 5
    others = set(ids) - {dead}
    sim = make_sim(ids)
    probe_interval = 0.15
    loop = asyncio.get_running_loop()
    async with streaming(sim, ids, offline_after=3, probe_interval=probe_interval) as (_, stream):
        stream.set_targets({i: 6000 + 60 * i for i in ids})
        healthy = await frames_until(stream, lambda f: f.cycle >= 2)

        seq_dead = sim.transactions
        sim.servo(dead).baud_rate = BaudRate.B625000  # the line stays at 115200: the servo goes silent

        def dead_txns(since: int) -> list[Transaction]:
            return [t for t in sim.log_since(since) if t.servo_id == dead]

        going = await frames_until(stream, lambda f: dead in f.offline)
        t_obs, seq_obs, cycle_obs = loop.time(), sim.transactions, stream.stats.cycles
        offline = await frames_until(stream, lambda f: len(dead_txns(seq_obs)) >= 2)
        t_end, seq_end, cycle_end = loop.time(), sim.transactions, stream.stats.cycles
        assert stream.offline == {dead} and stream.stats.offline == {dead}

        seq_alive = sim.transactions
        sim.servo(dead).baud_rate = BaudRate.B115200
        back = await frames_until(stream, lambda f: dead not in f.offline)
        assert back[-1].held == {dead}  # back from offline: held until its target is set again
        stream.set_target(dead, 6000 + 60 * dead)
        back += await frames_until(stream, lambda f: dead in f.positions)
        after = [await next_frame(stream) for _ in range(3)]
        stats = stream.stats

    # Every frame holds what the servos reported; the others answered in every cycle.
    check_frames(healthy + going + offline + back + after, sim, ids, commands=STREAM_COMMANDS)
    for frame in going + offline:
        assert others <= set(frame.positions)
        assert frame.failed <= {dead}
    assert stats.failures.keys() == {dead}

    # Offline after exactly offline_after consecutive cycles of silence...
    silent = [t for t in dead_txns(seq_dead) if not t.reply]
    assert silent and all(t.seq < seq_alive for t in silent)
    assert [b.seq - a.seq for a, b in itertools.pairwise(silent[:3])] == [32, 32]
    assert going[-1].offline == {dead}
    # ... then tried only at the probe rate: probes are at least probe_interval apart in loop time.
    probes = len(dead_txns(seq_obs)) - len(dead_txns(seq_end))
    assert 2 <= probes <= (t_end - t_obs) / probe_interval + 1
    assert cycle_end - cycle_obs > probes  # most cycles skip it
    assert silent[3].seq - silent[2].seq > 32  # the cycle after it went offline did not try it
    assert stats.failures[dead] == len(silent)

    # It rejoined (probed with reads, which move nothing, then held until targeted again): frames include it
    # again and nothing is offline.
    probes_sent = {t.command for t in dead_txns(seq_obs) if t.seq < seq_alive}
    assert probes_sent == {"read_stretch"}, probes_sent
    assert stats.probes == len([t for t in dead_txns(seq_dead) if t.command == "read_stretch"]) > 2
    assert back[-1].offline == frozenset() and back[-1].failed == frozenset()
    assert all(set(f.positions) == set(ids) and not f.offline for f in after)
    assert stats.offline == frozenset()


@pytest.mark.parametrize("driver", ["asyncio", "thread"])
@pytest.mark.parametrize("on_resume", ["wait", "free"])
async def test_a_servo_back_from_offline_is_not_thrown_to_its_old_target(driver: str, on_resume: str) -> None:
    # A servo browned out mid-stream (a humanoid's knee sagging under load): it went offline, restarted free
    # where the robot's weight left it, and the probe that found it again was its old position command, which
    # threw it there at full speed.  An offline ID is probed with a read that moves nothing, and comes back held
    # (no command until the program sets its target again) or free, as after a lost port.
    ids = [1, 2, 3]
    sim = make_sim(ids)
    opened = open_bus(sim, driver=driver, **FAST)
    async with opened as bus, bus.stream(ids, offline_after=2, probe_interval=0.02, on_resume=on_resume) as stream:
        old = {i: start_position(i) + 900 for i in ids}
        stream.set_targets(old)
        await frames_until(stream, lambda f: all(abs(f.positions.get(i, 0) - old[i]) < 20 for i in ids))
        knee = sim.remove_servo(2)
        await frames_until(stream, lambda f: 2 in f.offline)
        sim.add_device(knee)
        sim.power_cycle(2)  # it restarted: free, where the weight left it
        knee.move_by_hand(start_position(2))
        seq = sim.transactions
        back = (await frames_until(stream, lambda f: 2 not in f.offline))[-1]
        more = [await next_frame(stream) for _ in range(3)]
        to_knee = [t for t in sim.log_since(seq) if t.servo_id == 2]
        assert to_knee and not [t for t in to_knee if t.command == "position"], to_knee[:3]
        assert knee.position == start_position(2)  # not moved
        assert 2 not in back.failed and not back.offline
        if on_resume == "wait":
            assert all(f.held == {2} for f in [back, *more]) and stream.target(2) == old[2]
            assert all(t.command != "free" for t in to_knee)  # nor freed: a held servo gets nothing
            stream.set_target(2, start_position(2) + 50)  # the program decides again
            await frames_until(stream, lambda f: 2 in f.positions and not f.held)
            await wait_for_sim(lambda: knee.target == start_position(2) + 50, "the new target reached the knee")
        else:
            assert not back.held and stream.target(2) == FREE
            await frames_until(stream, lambda f: f.positions.get(2) == start_position(2))
        # The others carried on meanwhile.
        assert all({1, 3} <= set(f.positions) for f in more)


async def test_ids_given_offline_are_out_of_the_cycle_from_the_first() -> None:
    # A caller that has just found IDs silent (a robot's open: two unplugged legs) had each of them asked
    # offline_after cycles more, at its whole reply allowance each, before the stream marked it offline.
    # Given as offline, they are out of the cycle from the first frame: nothing is sent to them until their
    # first probe, one probe_interval after the start.
    ids = [1, 2, 3]
    sim = make_sim(ids)
    sim.remove_servo(2)
    async with streaming(sim, ids, offline=[2], probe_interval=60.0) as (_, stream):
        frames = [await next_frame(stream) for _ in range(5)]
        assert stream.offline == {2} and stream.stats.offline == {2}
    assert all(f.offline == {2} and not f.failed and set(f.positions) == {1, 3} for f in frames)
    assert [t for t in sim.log_since(0) if t.servo_id == 2] == []
    assert stream.stats.failures == {}  # (its silence was the caller's, not the stream's)


async def test_live_readings_keep_a_reading_through_one_failed_read_and_drop_it_at_the_second_in_a_row() -> None:
    # A program's own telemetry beside a stream, kept as the library's views keep theirs: servo 2 answers every
    # cycle, but its temperature reads go unanswered.  One lost reply says nothing of the servo (its reading
    # stays); two in a row, and what was read before is no longer shown as its now, until a read answers.
    sim = make_sim([1, 2])
    temperatures: LiveReadings[int] = LiveReadings()
    shown: list[int | None] = []

    async def read(frame: Frame) -> None:
        temperatures.follow(frame)
        try:
            temperatures[2] = await bus.servo(2).read_temperature()
        except ReplyError:
            temperatures.read_failed(2)
        shown.append(temperatures.get(2))

    async with streaming(sim, [1, 2]) as (bus, stream):
        await read(await next_frame(stream))
        sim.servo(2).ignores = frozenset({"read_temperature"})
        for _ in range(3):
            frame = await next_frame(stream)
            assert 2 in frame.positions and 2 not in frame.offline  # (its position answers throughout)
            await read(frame)
        sim.servo(2).ignores = frozenset()
        await read(await next_frame(stream))
        sim.servo(2).ignores = frozenset({"read_temperature"})
        await read(await next_frame(stream))  # (one failure after an answer: counted from zero again)
    first = shown[0]
    assert first is not None and shown == [first, first, None, None, first, first], shown


@pytest.mark.parametrize("target", ["free", "position"])
async def test_an_id_given_offline_that_answers_its_probe_comes_back_as_any_offline_id(target: str) -> None:
    # A servo the caller took for absent that answers after all (plugged in since, or missed): as an ID back
    # from offline, a free one is read (its free is the probe), one given a position target is held, sent
    # nothing, not thrown there.
    ids = [1, 2, 3]
    sim = make_sim(ids)
    async with streaming(sim, ids, offline=[2], probe_interval=0.02) as (_, stream):
        if target == "position":
            stream.set_target(2, start_position(2) + 900)
        back = (await frames_until(stream, lambda f: 2 not in f.offline))[-1]
        if target == "free":
            await frames_until(stream, lambda f: f.positions.get(2) == start_position(2))
        else:
            assert back.held == {2} and stream.held == {2: "rejoined"}
    sent = [t.command for t in sim.log_since(0) if t.servo_id == 2]
    assert sent and set(sent) == ({"free"} if target == "free" else {"read_stretch"}), sent
    assert sim.servo(2).position == start_position(2)  # not moved


@pytest.mark.parametrize("then", ["nothing", "free", "watch"])
async def test_hold_offline_brings_a_free_id_given_offline_back_held_unless_the_program_said_otherwise(
    then: str,
) -> None:
    # Its free, the probe and an ICS 3.5 servo's only read, dropped what a servo that had kept its power and target
    # (its replies lost) bore, for a program that asks before freeing: probed by a read, it is held, sent nothing.
    # A free or watch the program sets meanwhile is its own word: the probe follows it.
    ids = [1, 2, 3]
    sim = make_sim(ids)
    if then == "watch":  # (an ICS 3.6 servo: watched, it answers its position read)
        sim.remove_servo(2)
        sim.add_device(VirtualServo(2, position=start_position(2), ics36=True))
    sim.servo(2).command_position(start_position(2))  # (holding)
    async with streaming(sim, ids, offline=[2], hold_offline=True, probe_interval=0.02) as (_, stream):
        if then == "free":
            stream.free([2])
        elif then == "watch":
            stream.watch([2])
        back = (await frames_until(stream, lambda f: 2 not in f.offline))[-1]
        for _ in range(3):
            await next_frame(stream)
        if then == "nothing":
            assert back.held == {2} and stream.held == {2: "rejoined"} and not sim.servo(2).free
        elif then == "free":
            await frames_until(stream, lambda f: sim.servo(2).free)
        else:
            assert stream.held == {} and not sim.servo(2).free
    sent = {t.command for t in sim.log_since(0) if t.servo_id == 2}
    expected = {"nothing": {"read_stretch"}, "free": {"free"}, "watch": {"read_position"}}[then]
    assert sent == expected, sent
    with pytest.raises(InvalidArgument, match="hold_offline"):
        open_bus(sim, **FAST).stream(ids, hold_offline="yes")  # type: ignore[arg-type]


async def test_a_stalled_event_loop_does_not_fail_a_healthy_servo() -> None:
    ids = list(range(8))
    sim = make_sim(ids)
    loop = asyncio.get_running_loop()
    async with streaming(sim, ids) as (bus, stream):
        await next_frame(stream)
        # Blocking code on the loop (a slow callback, a GC pause, the OS preempting the process on a busy
        # machine): the watchdog comes due while the reply of the transaction on the wire waits in the
        # loop's ready queue.  Here: hold the loop, then let a due timer hold it again just after the
        # next transaction is written and just before the watchdog runs.
        time.sleep(0.02)
        loop.call_at(loop.time() - 1, time.sleep, 0.02)
        seq = sim.transactions
        frames = await frames_until(stream, lambda f: (f.cycle - 1) * len(ids) >= seq + len(ids))
        assert bus.stats.total.timeouts == 0
        assert stream.stats.failures == {}
    check_frames(frames, sim, ids)


# --------------------------------------------------------------------------- several lines


async def test_two_line_group_merges_frames_and_routes_targets_per_line() -> None:
    lines = {"left": list(range(12)), "right": list(range(12))}  # the same IDs on both lines
    sims = {
        "left": make_sim(range(12)),
        "right": VirtualLine([VirtualServo(i, position=10000 + 50 * i) for i in range(12)], log_size=None),
    }
    group = BusGroup({name: open_bus(sim, **FAST) for name, sim in sims.items()})
    async with group, group.stream(lines) as gstream:
        frames: list[GroupFrame] = [await next_frame(gstream)]
        changes: list[tuple[dict[str, int], dict[tuple[str, int], int]]] = []
        for step in range(3):
            targets = {("left", i): 5000 + 100 * i + 300 * step for i in range(12)}
            targets |= {("right", i): 9000 + 100 * i + 300 * step for i in range(12)}
            gstream.set_targets(targets)
            gstream.set_target("right", 3, 11000 + step)  # one more, to this line only
            targets["right", 3] = 11000 + step
            seqs = {name: sim.transactions for name, sim in sims.items()}
            changes.append((seqs, targets))
            for _ in range(50):
                frame = await next_frame(gstream)
                frames.append(frame)
                if all((frame.line_cycles[n] - 1) * 12 >= seqs[n] for n in lines):
                    break
        frames += [await next_frame(gstream) for _ in range(3)]
        with pytest.raises(InvalidArgument):
            gstream.set_target("middle", 1, 7500)
        with pytest.raises(InvalidArgument):
            gstream.set_target("left", 20, 7500)
        assert set(gstream.stats) == {"left", "right"}

    for name, sim in sims.items():
        log = position_log(sim)
        assert len(log) == sim.transactions
        for frame in frames:
            cycle = frame.line_cycles[name]
            cycle_log = log[(cycle - 1) * 12 : cycle * 12]
            assert [t.servo_id for t in cycle_log] == lines[name]
            mine = {sid: p for (line, sid), p in frame.positions.items() if line == name}
            assert mine == {t.servo_id: t.value for t in cycle_log}, (name, frame.cycle)
        # Targets went to the right line: after each change every command carries that line's target.
        bounds = [seqs[name] for seqs, _ in changes] + [len(log)]
        for (seqs, targets), end in zip(changes, bounds[1:], strict=True):
            chunk = log[seqs[name] : end]
            assert {t.servo_id for t in chunk} == set(lines[name])
            assert all(t.tx == position_tx(t.servo_id, targets[name, t.servo_id]) for t in chunk)
    assert all(set(f.positions) == {(n, i) for n in lines for i in lines[n]} for f in frames)
    assert [f.cycle for f in frames] == sorted({f.cycle for f in frames})


async def test_group_frames_end_with_the_reason_when_a_line_closes_or_loses_its_port() -> None:
    for lose in ("close", "unplug"):
        sims = [make_sim(range(4)), make_sim(range(4))]
        group = BusGroup({"a": open_bus(sims[0], **FAST), "b": open_bus(sims[1], **FAST)})
        async with group, group.stream({"a": [0, 1], "b": [2, 3]}) as gstream:
            got: list[GroupFrame] = []

            async def consume(gstream: GroupStream = gstream, got: list[GroupFrame] = got) -> None:
                async for frame in gstream:
                    got.append(frame)

            task = asyncio.create_task(consume())
            await wait_for_sim(lambda got=got: len(got) >= 2, "group frames")
            if lose == "close":
                await group["a"].aclose()
            else:
                sims[0].unplug()
            if lose == "close":
                await asyncio.wait_for(task, GUARD)  # closing ends the loop, no hang
            else:
                with pytest.raises(PortLost):  # losing the port is an error, not a quiet end
                    await asyncio.wait_for(task, GUARD)
            expected = BusClosed if lose == "close" else PortLost
            with pytest.raises(expected):
                for _ in range(3):  # a frame already merged may still come; then it ends
                    await next_frame(gstream)
            # The other line is still usable.
            assert await group["b"].servo(3).read_stretch() == 43


async def test_group_set_targets_is_all_or_nothing() -> None:
    sims = [make_sim(range(4)), make_sim(range(4))]
    group = BusGroup({"a": open_bus(sims[0], **FAST), "b": open_bus(sims[1], **FAST)})
    async with group, group.stream({"a": [0, 1], "b": [2, 3]}) as gstream:
        for bad, says in (
            ({("a", 0): 8000, ("b", 2): 20000}, "line b"),
            ({("a", 0): 8000, ("b", 0): 8000}, "line b: ID 0"),  # ID 0 streams on line a only
            ({("a", 0): 8000, ("c", 2): 8000}, "no line named 'c'"),
        ):
            with pytest.raises(InvalidArgument, match=says):
                gstream.set_targets(bad)
        with pytest.raises(InvalidArgument, match="line b: 140 degrees is outside -135"):
            gstream.set_targets_degrees({("a", 0): 10.0, ("b", 2): 140.0})  # in degrees, as one stream takes them
        with pytest.raises(InvalidArgument, match=r"unknown stream option.*on_clos"):  # not Python's TypeError
            group.stream({"a": [0]}, on_clos="free")  # type: ignore[call-arg]
        assert [gstream.streams["a"].target(0), gstream.streams["b"].target(2)] == [0, 0]
        await next_frame(gstream)
        await next_frame(gstream)
    for sim in sims:
        assert all(t.tx[1:] == b"\0\0" for t in position_log(sim))  # every ID stayed free


async def test_a_group_with_one_line_closed_still_frees_the_others_and_sets_no_target_by_halves() -> None:
    sims = [make_sim([1]), make_sim([1])]
    group = BusGroup({"a": open_bus(sims[0], **FAST), "b": open_bus(sims[1], **FAST)})
    async with group, group.stream({"a": [1], "b": [1]}) as gstream:
        gstream.set_targets({("a", 1): 8000, ("b", 1): 8000})
        await next_frame(gstream)
        await next_frame(gstream)
        await group["a"].aclose()  # one line's bus closed by the program
        with pytest.raises(BusClosed):
            gstream.set_targets({("b", 1): 7000, ("a", 1): 7000})
        assert gstream.streams["b"].target(1) == 8000  # nothing applied, line b included
        with pytest.raises(BusClosed):
            gstream.free()
        await wait_for_sim(lambda: sims[1].servo(1).free, "line b freed")


async def test_a_group_stream_takes_the_ids_it_starts_offline_per_line() -> None:
    # A group's frames name offline servos as (line, id), and a program that restarts its stream gives it
    # those: `offline=frame.offline` was refused ("servo ID must be an int, not tuple"), and a plain ID was
    # taken for every line (refused where a line had no such ID). A pair starts that one servo offline.
    sims = [make_sim([1, 2]), make_sim([1, 3])]
    sims[0].remove_servo(2)
    group = BusGroup({"a": open_bus(sims[0], **FAST), "b": open_bus(sims[1], **FAST)})
    async with group:
        with pytest.raises(InvalidArgument, match=r"offline: .*line 'c'"):
            group.stream({"a": [1, 2], "b": [1, 3]}, offline=[("c", 2)])
        with pytest.raises(InvalidArgument, match=r"offline: ID 3 is not in this stream"):
            group.stream({"a": [1, 2], "b": [1, 3]}, offline=[("a", 3)])
        async with group.stream({"a": [1, 2], "b": [1, 3]}, offline=[("a", 2)], probe_interval=60.0) as gstream:
            frames = [await next_frame(gstream) for _ in range(3)]
    assert all(f.offline == {("a", 2)} and not f.failed for f in frames), frames
    assert set(frames[-1].positions) == {("a", 1), ("b", 1), ("b", 3)}
    assert [t for t in sims[0].log_since(0) if t.servo_id == 2] == []  # never asked


async def test_a_group_stream_asked_for_a_frame_before_it_started_works_once_started() -> None:
    sims = [make_sim([1]), make_sim([1])]
    group = BusGroup({"a": open_bus(sims[0], **FAST), "b": open_bus(sims[1], **FAST)})
    async with group:
        gstream = group.stream({"a": [1], "b": [1]})
        with anyio.fail_after(GUARD), pytest.raises(InvalidArgument, match=r"async with group\.stream"):
            await gstream.next_frame()
        async with gstream:
            assert (await next_frame(gstream)).positions


async def test_a_group_stream_s_latest_merges_each_line_s_newest_frame_and_takes_none() -> None:
    sims = [make_sim([1, 2]), make_sim([1])]
    group = BusGroup({"a": open_bus(sims[0], **FAST), "b": open_bus(sims[1], **FAST)})
    async with group:
        gstream = group.stream({"a": [1, 2], "b": [1]})
        assert gstream.latest is None  # before the first frame
        async with gstream:
            await wait_for_sim(lambda: gstream.latest is not None, "a latest group frame")
            latest = gstream.latest
            assert latest is not None
            assert set(latest.positions) == {("a", 1), ("a", 2), ("b", 1)}
            assert latest.positions["a", 2] == start_position(2)
            streams = gstream.streams
            assert all(latest.line_cycles[line] <= s.latest.cycle for line, s in streams.items() if s.latest)
            # Reading it took nothing: the next frame is at least as new, on every line.
            frame = await next_frame(gstream)
            assert all(frame.line_cycles[line] >= latest.line_cycles[line] for line in streams)
            assert (latest.cycle, frame.cycle) == (0, 1)  # (a frame taken by latest would have counted one)


# --------------------------------------------------------------------------- cancelling and closing


async def test_cancelled_consumer_and_stream_closed_mid_cycle_leave_the_bus_usable() -> None:
    ids = list(range(8))
    sim = make_sim(ids)
    async with open_bus(sim, **FAST) as bus:
        stream = await bus.stream(ids).start()
        got: list[Frame] = []

        async def consume() -> None:
            async for frame in stream:
                got.append(frame)

        task = asyncio.create_task(consume())
        await wait_for_sim(lambda: len(got) >= 3, "consumer got frames")
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task
        assert task.cancelled()
        # The stream runs on regardless of its consumer.
        got.append(await next_frame(stream))

        # Close it mid-cycle, while a consumer waits for the next frame: the consumer ends.
        waiting = asyncio.create_task(consume())
        await wait_for_sim(lambda: sim.log[-1].servo_id not in (ids[-1], None), "mid-cycle")
        await stream.aclose()
        await asyncio.wait_for(waiting, GUARD)
        await bus.wait_idle()
        stopped_at = sim.transactions
        assert stopped_at % len(ids) != 0  # it really stopped inside a cycle
        await asyncio.sleep(0.02)
        assert sim.transactions == stopped_at  # nothing more is written
        with pytest.raises(BusClosed):
            for _ in range(3):  # at most the last frame is still unread
                got.append(await next_frame(stream))
        check_frames(got, sim, ids)

        # Plain requests work, and so does a new stream.
        assert await bus.servo(3).read_stretch() == 43
        assert await bus.servo(4).set_position(7000) == sim.log[-1].value
        since = sim.transactions
        async with bus.stream(ids) as again:
            frames = [await next_frame(again) for _ in range(3)]
        check_frames(frames, sim, ids, since)
        assert frames[0].cycle == 1
        assert await bus.servo(3).read_speed() == sim.servo(3).speed


async def test_closing_the_bus_ends_async_for_and_next_frame() -> None:
    sim = make_sim(range(4))
    bus = await open_bus(sim, **FAST)
    async with bus.stream([0, 1, 2, 3]) as stream:
        got: list[Frame] = []

        async def consume() -> None:
            async for frame in stream:
                got.append(frame)

        task = asyncio.create_task(consume())
        await wait_for_sim(lambda: len(got) >= 2, "consumer got frames")
        await bus.aclose()
        await asyncio.wait_for(task, GUARD)  # the loop ended, no hang and no error
        with pytest.raises(BusClosed):
            for _ in range(3):
                await next_frame(stream)
    with pytest.raises(BusClosed):
        await bus.servo(1).read_stretch()


async def test_a_stream_on_a_closed_or_unopened_bus_raises_bus_closed() -> None:
    sim = make_sim(range(4))
    bus = open_bus(sim, **FAST)
    with pytest.raises(BusClosed):
        await bus.stream([0, 1]).start()  # not opened yet
    await bus.open()
    await bus.aclose()
    with pytest.raises(BusClosed):
        async with bus.stream([0, 1]):
            pass
    assert sim.transactions == 0


async def test_a_stream_not_started_says_so_at_once_and_one_closed_refuses_targets() -> None:
    # Used without `async with`, a stream's frames waited forever; once closed, its targets went nowhere
    # in silence (a controller "commanding" a stream that had ended).
    sim = make_sim(range(4))
    async with open_bus(sim, **FAST) as bus:
        stream = bus.stream([0, 1], rate_hz=50)
        stream.set_targets({0: 8000})  # before it starts: its first cycle sends it
        for call in (stream.next_frame, stream.__anext__):
            with anyio.fail_after(GUARD), pytest.raises(InvalidArgument, match=r"async with bus\.stream"):
                await call()
        async with stream:
            assert (await next_frame(stream)).positions
        with pytest.raises(BusClosed, match="stream closed"):
            stream.set_targets({0: 7000})
        with pytest.raises(BusClosed, match="stream closed"):
            stream.set_target(1, 7000)


async def test_a_stream_started_again_after_its_block_says_a_stream_runs_once() -> None:
    # A program in phases (`async with stream:` twice) got "stream closed", as if the bus had gone.
    sim = make_sim(range(2))
    async with open_bus(sim, **FAST) as bus:
        stream = bus.stream([0, 1])
        async with stream:
            await next_frame(stream)
        with pytest.raises(BusClosed, match=r"a stream runs once; .*bus\.stream\("):
            async with stream:
                pass
        async with bus.stream([0, 1]) as again:  # and the bus is fine
            assert (await next_frame(again)).positions


@pytest.mark.parametrize("driver", ["asyncio", "thread"])
async def test_losing_the_port_without_reconnect_ends_next_frame_with_port_lost(driver: str) -> None:
    ids = [0, 1, 2, 3]
    sim = make_sim(ids)
    async with open_bus(sim, driver=driver, **FAST) as bus, bus.stream(ids) as stream:
        frames = [await next_frame(stream)]
        sim.unplug()
        with pytest.raises(PortLost):
            for _ in range(3):
                frames.append(await next_frame(stream))
        assert not bus.is_open
        with pytest.raises(BusClosed):
            await bus.servo(1).read_stretch()
    check_frames(frames, sim, ids)


@pytest.mark.parametrize("driver", ["asyncio", "thread"])
async def test_losing_the_port_with_reconnect_resumes_the_stream(driver: str) -> None:
    ids = list(range(8))
    sim = make_sim(ids)
    async with open_bus(sim, reconnect=True, driver=driver, **FAST) as bus, bus.stream(ids) as stream:
        before = await next_frame(stream)
        sim.unplug(replug_after=0.05)
        unplugged_at = sim.transactions
        # Frames of cycles that began after the port came back.
        after = await frames_until(stream, lambda f: bus.stats.reconnects >= 1 and f.started > before.finished + 0.05)
        assert after[-1].cycle > before.cycle
        more = [await next_frame(stream) for _ in range(3)]
        assert sim.transactions > unplugged_at + 3 * len(ids)
        assert bus.stats.reconnects == 1
    # The servos were free and untouched, so every answer is their start position.
    for frame in [before, after[-1], *more]:
        assert frame.positions == {i: start_position(i) for i in ids}
        assert not frame.failed and not frame.offline


async def test_an_id_offline_when_its_port_was_lost_is_still_probed_and_comes_back_held() -> None:
    # Held as the port came back while it was offline, it left the cycle and was never probed again.
    ids = [1, 2, 3]
    sim = make_sim(ids)
    async with (
        open_bus(sim, reconnect=True, **FAST) as bus,
        bus.stream(ids, offline_after=2, probe_interval=0.02) as stream,
    ):
        stream.set_targets({i: start_position(i) + 900 for i in ids})
        await frames_until(stream, lambda f: len(f.positions) == 3)
        knee = sim.remove_servo(2)
        await frames_until(stream, lambda f: 2 in f.offline)
        sim.unplug(replug_after=0.05)
        resumed = (await frames_until(stream, lambda f: f.resumed))[-1]
        assert resumed.held == {1, 3} and stream.held == {1: "resumed", 3: "resumed"}
        sim.add_device(knee)
        seq = sim.transactions
        await frames_until(stream, lambda f: 2 not in f.offline)
        assert stream.held == {1: "resumed", 2: "rejoined", 3: "resumed"}
        assert not [t for t in sim.log_since(seq) if t.command in POSITION_COMMANDS]  # nothing moved


@pytest.mark.parametrize("unit", ["counts", "degrees"])
async def test_a_loop_that_sets_every_target_each_cycle_keeps_a_hold_with_lift_holds_false(unit: str) -> None:
    # A hold may begin after the frame a loop looked at: filtering its targets by that frame's held, the loop
    # lifted the hold at once and threw the restarted servo to its target.  (In degrees, set_targets_degrees,
    # the streaming page's unit, had no lift_holds.)
    ids = [1, 2, 3]
    sim = make_sim(ids)
    async with open_bus(sim, **FAST) as bus, bus.stream(ids, offline_after=2, probe_interval=0.02) as stream:
        if unit == "counts":
            pose: dict[int, float] = {i: start_position(i) + 900 for i in ids}
            set_targets: Callable[..., None] = stream.set_targets
        else:
            pose = {i: 10.0 * i for i in ids}
            set_targets = stream.set_targets_degrees
        set_targets(pose)
        await frames_until(stream, lambda f: len(f.positions) == 3)
        knee = sim.remove_servo(2)
        await frames_until(stream, lambda f: 2 in f.offline)
        sim.add_device(knee)
        sim.power_cycle(2)
        seq = sim.transactions
        while 2 not in stream.held:
            set_targets(pose, lift_holds=False)  # the loop's every cycle
            await next_frame(stream)
        for _ in range(5):
            set_targets(pose, lift_holds=False)
            await next_frame(stream)
        assert [t for t in sim.log_since(seq) if t.servo_id == 2 and t.command == "position"] == []
        assert knee.free
        set_targets({2: pose[2]})  # the program decides: the hold is lifted
        await frames_until(stream, lambda f: 2 in f.positions)
        assert stream.held == {}


async def test_a_group_loop_in_degrees_keeps_a_hold_with_lift_holds_false() -> None:
    sim = make_sim([1, 2])
    async with (
        BusGroup({"legs": open_bus(sim, **FAST)}) as group,
        group.stream({"legs": [1, 2]}, offline_after=2, probe_interval=0.02) as stream,
    ):
        pose = {("legs", 1): 10.0, ("legs", 2): 20.0}
        stream.set_targets_degrees(pose)
        await frames_until_group(stream, lambda f: len(f.positions) == 2)
        knee = sim.remove_servo(2)
        await frames_until_group(stream, lambda f: ("legs", 2) in f.offline)
        sim.add_device(knee)
        sim.power_cycle(2)
        seq = sim.transactions
        while ("legs", 2) not in stream.held:
            stream.set_targets_degrees(pose, lift_holds=False)
            await next_frame(stream)
        for _ in range(5):
            stream.set_targets_degrees(pose, lift_holds=False)
            await next_frame(stream)
        assert [t for t in sim.log_since(seq) if t.servo_id == 2 and t.command == "position"] == []
        assert knee.free


async def frames_until_group(stream: GroupStream, done: Callable[[GroupFrame], bool], limit: int = 5000) -> None:
    for _ in range(limit):
        if done(await next_frame(stream)):
            return
    raise AssertionError(f"condition not met within {limit} frames")


async def test_the_slots_a_paced_stream_missed_while_its_port_was_lost_are_counted() -> None:
    # The control-loop page: missed_slots are "slots that passed with no cycle: your program or the line
    # stalled"; after an outage the resumed frame said 0, so a loop's log showed no gap at all.
    ids = [1, 2]
    sim = make_sim(ids)
    async with open_bus(sim, reconnect=True, **FAST) as bus, bus.stream(ids, rate_hz=100) as stream:
        stream.set_targets(dict.fromkeys(ids, 7500))
        for _ in range(3):
            before = await next_frame(stream)
        sim.unplug(replug_after=0.3)
        frames = await frames_until(stream, lambda f: f.resumed)
        resumed = frames[-1]
        gap = resumed.started - before.started  # the slots between are missed (bar the ones frames used)
        used = len(frames) - 1
        assert resumed.missed_slots + used >= int(gap * 100) - 2, (resumed.missed_slots, used, gap)
        assert stream.stats.missed_slots >= resumed.missed_slots > 0


async def test_a_group_frame_says_which_line_came_back_and_which_servos_it_holds() -> None:
    # A hexapod's gait over two lines: the right line reconnected and the gait drove its legs straight
    # back to their old targets; a group frame had no resumed or held (only each line's own frames had).
    ids = [1, 2, 3]
    left, right = make_sim(ids), make_sim(ids)
    lines = {"left": open_bus(left, reconnect=True, **FAST), "right": open_bus(right, reconnect=True, **FAST)}
    async with BusGroup(lines) as group:
        stream = group.stream({"left": ids, "right": ids})
        pose = {(line, i): 8000 for line in lines for i in ids}
        stream.set_targets(pose)
        async with stream:
            frame = await stream.next_update()
            assert frame.resumed == frozenset() and frame.held == frozenset() and frame.missed_slots == 0
            right.unplug(replug_after=0.05)
            with anyio.fail_after(GUARD):
                while not (frame := await stream.next_update()).resumed:
                    pass
            assert frame.resumed == {"right"}
            assert frame.held == {("right", i) for i in ids}
            later = await stream.next_update()
            assert later.resumed == frozenset() and later.held == frame.held  # held until targeted again
            stream.set_targets({("right", i): 8000 for i in ids})
            with anyio.fail_after(GUARD):
                while (await stream.next_update()).held:
                    pass


# --------------------------------------------------------------------------- free mode, consumers, rates


async def test_free_mode_reads_back_a_servo_turned_by_hand() -> None:
    ids = [1, 2, 3, 4]
    sim = make_sim(ids)
    async with streaming(sim, ids) as (_, stream):
        stream.set_targets(dict.fromkeys(ids, 8000))
        seq = sim.transactions
        await frames_until(stream, lambda f: (f.cycle - 1) * 4 >= seq)
        assert not any(sim.servo(i).free for i in ids)

        stream.free([3])
        assert stream.target(3) == 0
        seq = sim.transactions
        await frames_until(stream, lambda f: (f.cycle - 1) * 4 >= seq)
        assert sim.servo(3).free and not any(sim.servo(i).free for i in (1, 2, 4))
        sim.servo(3).move_by_hand(9000)
        seq = sim.transactions
        frames = await frames_until(stream, lambda f: (f.cycle - 1) * 4 >= seq)
        frames += [await next_frame(stream) for _ in range(3)]
    assert all(f.positions[3] == 9000 for f in frames[-4:])
    assert sim.servo(3).free and sim.servo(3).position == 9000
    assert all(t.tx == position_tx(3, 0) for t in position_log(sim, seq) if t.servo_id == 3)
    check_frames(frames, sim, ids)


async def test_on_close_free_frees_every_servo() -> None:
    ids = [1, 2, 3]
    sim = make_sim(ids)
    async with open_bus(sim, **FAST) as bus:
        with pytest.warns(DeprecationWarning, match="on_close='free'"):
            assert bus.stream(ids, free_on_close=True).on_close == "free"  # the old name still works
        async with bus.stream(ids, on_close="free") as stream:
            stream.set_targets(dict.fromkeys(ids, 8000))
            seq = sim.transactions
            await frames_until(stream, lambda f: (f.cycle - 1) * 3 >= seq)
            assert not any(sim.servo(i).free for i in ids)
        assert all(sim.servo(i).free for i in ids)


@pytest.mark.parametrize("offline_after", [2, 10], ids=["offline", "not-yet-offline"])
async def test_on_close_free_sends_an_id_never_heard_its_free_once_without_retries(offline_after: int) -> None:
    # An ID where no servo is (`ics35 monitor 0-9 --free` with 4-9 unplugged) failed every cycle and every probe;
    # its close-out free, retried after a guard read (retries=1, ics35's default), waited three reply allowances
    # at the end of the command, each such ID, offline or not yet (a short run, a long allowance).  Two silences
    # and no answer say nobody is there: its free goes out once.
    ids = [1, 2, 5]
    sim = make_sim([1, 2])
    async with (
        open_bus(sim, **{**FAST, "retries": 1}) as bus,
        bus.stream(ids, on_close="free", offline_after=offline_after, probe_interval=60.0) as stream,
    ):
        frames = await frames_until(stream, lambda f: 5 in f.offline or f.cycle >= 3)
        assert sum(5 in f.failed for f in frames) >= 2
        seq = sim.transactions
    sent = [(t.servo_id, t.command) for t in sim.log_since(seq)]
    assert [c for i, c in sent if i == 5] == ["free"], sent
    assert {1, 2} <= {i for i, c in sent if c == "free"} and sim.servo(1).free and sim.servo(2).free
    assert stream.targets_sent_on_close == dict.fromkeys(ids, FREE)


async def test_on_close_free_to_ids_never_heard_waits_as_long_as_the_line_answers_not_its_allowance() -> None:
    # A leg unplugged under `ics35 teach --timeout 1`: after q, each of its IDs' close-out free waited a whole
    # reply allowance, one after the other (five IDs: five seconds with nothing said).  Nobody is there: the
    # free goes out as `free all` sends it to an ID that may be empty, waiting only as long as this line's
    # servos take to answer.
    ids = [1, 5, 6, 7]
    sim = make_sim([1])
    async with open_bus(sim, **{**PATIENT, "retries": 1}) as bus:
        async with bus.stream(ids, on_close="free", offline_after=2, probe_interval=60.0) as stream:
            await frames_until(stream, lambda f: {5, 6, 7} <= f.offline)
            seq = sim.transactions
            closing = time.monotonic()
        took = time.monotonic() - closing
    assert [(t.servo_id, t.command) for t in sim.log_since(seq)] == [(i, "free") for i in ids]
    assert stream.targets_sent_on_close == dict.fromkeys(ids, FREE)
    assert took < 2 * PATIENT["adapter_latency"], took  # (three allowances before)


async def test_on_close_free_to_offline_ids_on_a_line_where_nothing_answers_waits_no_whole_allowance() -> None:
    # A robot's leg line unplugged under `ics35 teach --timeout 1`: nothing on that line had ever answered, so the
    # probe's wait had nothing to learn from and each close-out free waited the whole allowance (ten leg joints:
    # about eleven seconds after q).  The stream had already found them silent: each free still goes out (a
    # servo plugged back in executes it), its reply waited for only briefly.
    ids = [5, 6, 7]
    sim = make_sim([])
    allowance = PATIENT["adapter_latency"]
    async with open_bus(sim, **{**PATIENT, "retries": 1}) as bus:
        async with bus.stream(ids, on_close="free", offline_after=1, probe_interval=60.0) as stream:
            await frames_until(stream, lambda f: set(ids) <= f.offline)
            seq = sim.transactions
            closing = time.monotonic()
        took = time.monotonic() - closing
    assert [(t.servo_id, t.command) for t in sim.log_since(seq)] == [(i, "free") for i in ids]
    assert stream.targets_sent_on_close == dict.fromkeys(ids, FREE)  # (on the wire: unconfirmed, not unsent)
    assert took < allowance / 2, took  # (one whole allowance per ID before)


@pytest.mark.parametrize("target", ["free", "position"])
async def test_a_closing_stream_waits_out_no_probe_of_an_offline_servo(target: str) -> None:
    # A robot's leg line unplugged under `ics35 teach --timeout 1`: q came while the stream's probe of an offline
    # joint was on the wire, nothing on that line had ever answered, and the close waited that probe's whole
    # allowance, then a guard read's (the joint's free has the probe's command byte): two seconds after q.  Its
    # stream gone, nobody hears the probe's answer; each offline ID's free still goes out.
    ids = [5, 6]
    sim = make_sim([])
    allowance = PATIENT["adapter_latency"]
    async with open_bus(sim, **{**PATIENT, "retries": 1}) as bus:
        async with bus.stream(ids, on_close="free", offline_after=1, probe_interval=0.001) as stream:
            if target == "position":  # (probed with a read: another command byte than its free's)
                stream.set_targets(dict.fromkeys(ids, 7500))
            await frames_until(stream, lambda f: set(ids) <= f.offline)
            seq = sim.transactions
            await wait_for_sim(lambda: sim.transactions > seq, "a probe of an offline ID on the wire")
            probed = sim.log_since(seq)[0]
            assert probed.servo_id in ids and probed.command in STREAM_COMMANDS, probed
            closing = time.monotonic()
        took = time.monotonic() - closing
    after = [(t.servo_id, t.command) for t in sim.log_since(seq + 1)]
    assert sorted(after) == [(i, "free") for i in ids], after  # (no guard read, no retry)
    assert stream.targets_sent_on_close == dict.fromkeys(ids, FREE)
    assert took < allowance / 2, took  # (one or two allowances before)


async def test_on_close_free_to_a_servo_gone_offline_waits_no_whole_allowance() -> None:
    # A servo that answered, then stopped (its cable pulled mid-run): its close-out free went with the whole
    # allowance and the bus's retries, each after a guard read (three allowances at retries=1), as if it were
    # there.  Offline, it gets its free once, with the short wait; the servo still there keeps its whole one.
    ids = [1, 2]
    sim = make_sim(ids)
    allowance = PATIENT["adapter_latency"]
    async with open_bus(sim, **{**PATIENT, "retries": 1}) as bus:
        async with bus.stream(ids, on_close="free", offline_after=1, probe_interval=60.0) as stream:
            await frames_until(stream, lambda f: 2 in f.positions)
            sim.remove_servo(2)
            await frames_until(stream, lambda f: 2 in f.offline)
            seq = sim.transactions
            closing = time.monotonic()
        took = time.monotonic() - closing
    assert sorted((t.servo_id, t.command) for t in sim.log_since(seq)) == [(1, "free"), (2, "free")]
    assert sim.servo(1).free
    assert stream.targets_sent_on_close == dict.fromkeys(ids, FREE)
    assert took < allowance / 2, took


async def test_on_close_free_still_retries_an_id_that_failed_only_once() -> None:
    # One silence is not two: a servo whose only reply so far was lost gets the bus's retries as ever.
    ids = [1, 5]
    sim = make_sim([1])
    async with (
        open_bus(sim, **{**FAST, "retries": 1}) as bus,
        # (a cycle every 20 s: no second one before the close, however long the machine stalls)
        bus.stream(ids, on_close="free", offline_after=10, rate_hz=0.05) as stream,
    ):
        await frames_until(stream, lambda f: 5 in f.failed)
        seq = sim.transactions
    assert [t.command for t in sim.log_since(seq) if t.servo_id == 5] == ["free", "read_stretch", "free"]


@pytest.mark.parametrize("driver", ["asyncio", "anyio"])
async def test_reads_in_a_row_beside_a_stream_follow_each_other_on_the_wire(driver: str) -> None:
    # Each read after a caller's first waited a whole stream transaction: the stream's next went on the wire as
    # the previous read's reply came in, before the caller's task had its turn to ask again.
    ids = [1, 2, 3]
    sim = make_sim(ids)
    # (Every reply in time on a loaded machine, and no stream turn owed to the share rule within the 20 reads.)
    async with (
        open_bus(sim, driver=driver, max_requests_between=100, **NO_TIMEOUTS) as bus,
        bus.stream(ids) as stream,
    ):
        await stream.next_frame()
        mark = sim.transactions
        for _ in range(10):
            await bus.servo(2).read_current()
            await bus.servo(2).read_temperature()
        log = [t.command for t in sim.log_since(mark)]
    follows = [log[k - 1] for k, command in enumerate(log) if command == "read_temperature" and k]
    assert follows == ["read_current"] * 10, log


# A slow link's reply allowance (0.3 s, as over a TCP bridge): the close-out's fixed two-second bound ran out on the
# frees of the IDs that do not answer (each waits its whole allowance), and the servo queued behind them never got
# its free: it went on holding.  With the bus's retries (retries=1, as ics35's default) each silent ID's free is
# tried twice, with a guard read between: three allowances where the bound counted one.
@pytest.mark.parametrize(("absent", "retries"), [(8, 0), (3, 1)], ids=["no-retries", "retries"])
async def test_on_close_free_reaches_a_servo_queued_behind_silent_ids_on_a_slow_link(absent: int, retries: int) -> None:
    present = absent + 1
    ids = list(range(1, present + 1))
    sim = make_sim([present])
    async with open_bus(sim, **{**FAST, "adapter_latency": 0.3, "retries": retries}) as bus:
        await bus.servo(present).set_position(8000)
        assert not sim.servo(present).free
        async with bus.stream(ids, on_close="free") as stream:
            pass
    assert sim.servo(present).free
    assert stream.targets_sent_on_close == dict.fromkeys(ids, FREE)


@pytest.mark.parametrize("driver", ["asyncio", "thread", "anyio"])
async def test_targets_set_just_before_the_block_ends_are_sent_when_it_holds(driver: str) -> None:
    # A final pose set right before leaving the block (a robot sitting down) was dropped: the stream
    # stopped before its next cycle, and with on_close="hold" nothing else sent it.
    ids = list(range(1, 10))
    sim = make_sim(ids, realtime=True)  # a cycle takes wire time: the block ends before the next one
    async with open_bus(sim, driver=driver, **PATIENT) as bus:
        async with bus.stream(ids, rate_hz=100) as stream:
            stream.set_targets(dict.fromkeys(ids, 7500))
            await frames_until(stream, lambda f: f.cycle > 2)
            stream.set_targets({i: 9000 + i for i in ids})
            stream.set_target(5, FREE)
            stream.watch([6])  # (a watched ID gets no command: nothing to send)
        seq = sim.transactions
        expected = {i: 9000 + i for i in ids} | {5: None, 6: 7500}  # 5 freed; 6 watched, so left as it was
        assert {i: sim.servo(i).target for i in ids} == expected
        # Once each: nothing more goes out after the close.
        await asyncio.sleep(0.05)
        assert sim.transactions == seq


@pytest.mark.parametrize("driver", ["asyncio", "thread", "anyio"])
async def test_targets_given_before_the_stream_starts_hold_from_its_first_command(driver: str) -> None:
    # The documented way to start a stream on a standing robot: inside the block the first cycle
    # may already have freed the first IDs (a stream starts as the block begins).
    ids = [1, 2, 3]
    sim = make_sim(ids, realtime=True)
    other = make_sim(ids, realtime=True)
    async with open_bus(sim, driver=driver, **PATIENT) as bus:
        stream = bus.stream(ids, rate_hz=100)
        stream.set_targets(dict.fromkeys(ids, 8000))
        async with stream:
            await next_frame(stream)
        async with BusGroup({"a": bus, "b": open_bus(other, driver=driver, **PATIENT)}) as group:
            both = group.stream({"a": ids, "b": ids}, rate_hz=100)
            both.set_targets({(line, i): 7000 for line in "ab" for i in ids})
            async with both:
                await next_frame(both)
    for line in (sim, other):
        assert [t.servo_id for t in line.log_since(0) if t.command == "free"] == []


@pytest.mark.parametrize("close_mid_burst", [False, True])
async def test_a_target_set_during_a_burst_is_sent_at_the_close_when_its_cycle_carried_the_old_one(
    close_mid_burst: bool,
) -> None:
    # The engine's hooks driven as during a burst: the executor has already sent ID 2's planned command
    # (the old target) when the program sets ID 2's final pose; that transaction is then fed back.  The
    # close took the slot as sent (it was handed out) and the final pose was dropped.
    ids = [1, 2, 3]
    sim = make_sim(ids)
    async with open_bus(sim, **FAST) as bus:
        stream = bus.stream(ids)
        stream.set_targets(dict.fromkeys(ids, 7000))
        await stream.start()
        await bus.servo(1).read_stretch()  # (a request: the stream ran meanwhile, cycles under way)
        hooks = stream._hooks
        bus.detach_source(hooks)  # from here the test is the engine
        stream._running = True
        now = 0.0
        stream._pos = len(stream._order)  # (between cycles)
        first = hooks.next_transaction(now)
        assert first is not None and first[2] == 1
        planned = hooks.upcoming(3)  # a burst plans IDs 1, 2, 3: the executor sends them
        assert [p[0] for p in planned] == [position_tx(i, 7000) for i in ids]
        stream.set_targets({2: 9000})  # the final pose, while the burst runs
        reply = bytearray(position_tx(1, 7000) + bytes((0x01, 0x36, 0x58)))
        for sid in ids:  # the burst's records fed back, one by one
            job = hooks.next_transaction(now) if sid != 1 else first
            assert job is not None and job[2] == sid
            reply[0:3] = job[0]
            reply[3] = sid
            assert hooks.complete(reply, 3, now) is None
        if close_mid_burst:  # (a frame fed ahead of the burst's end: the program leaves its block)
            await stream.aclose()
        hooks.upcoming_done()
        await stream.aclose()
    assert stream.targets_sent_on_close == {2: 9000}


async def cancel_twice_while_it_frees(task: asyncio.Future[None], sim: VirtualLine) -> None:
    """Cancel ``task``; cancel it again once its close-out's first free is on the simulator's log (polling,
    bounded); wait for its end."""
    mark = sim.transactions
    task.cancel()
    with anyio.fail_after(GUARD):
        while not any(t.command == "free" for t in sim.log_since(mark)):
            await asyncio.sleep(0.0005)
    task.cancel()
    with contextlib.suppress(asyncio.CancelledError):
        await task


@pytest.mark.parametrize("driver", ["asyncio", "thread", "anyio"])
async def test_on_close_free_survives_a_second_cancel_while_it_frees(driver: str) -> None:
    # A second Task.cancel() (a timeout around the task, then its caller cancelling it) landed in the free
    # and cut it short: anyio's shield keeps out anyio's cancellation, not asyncio's Task.cancel().
    ids = list(range(1, 9))
    sim = make_sim(ids, realtime=True)  # the frees take wire time, so the second cancel lands among them
    async with open_bus(sim, driver=driver, **PATIENT) as bus:
        streaming = asyncio.Event()

        async def controller() -> None:
            async with bus.stream(ids, on_close="free") as stream:
                stream.set_targets(dict.fromkeys(ids, 8000))
                await frames_until(stream, lambda f: f.cycle > 2)
                streaming.set()
                await asyncio.sleep(3600)

        task = asyncio.ensure_future(controller())
        await streaming.wait()
        await cancel_twice_while_it_frees(task, sim)
        assert task.cancelled()  # the cancellation goes on once the frees are done
    assert all(sim.servo(i).free for i in ids), [i for i in ids if not sim.servo(i).free]


async def test_a_stream_still_open_when_its_bus_closes_still_frees_with_on_close_free() -> None:
    # A control task's stream outlived the program's `async with open_bus` block: the bus closed under it
    # and the servos kept holding (the free was skipped because the bus was no longer open).
    ids = [1, 2, 3]
    sim = make_sim(ids)
    async with contextlib.AsyncExitStack() as outlives:
        async with open_bus(sim, **FAST) as bus:
            stream = await outlives.enter_async_context(bus.stream(ids, on_close="free"))
            stream.set_targets(dict.fromkeys(ids, 8000))
            await frames_until(stream, lambda f: f.cycle > 2)
            assert not any(sim.servo(i).free for i in ids)
        assert all(sim.servo(i).free for i in ids), [i for i in ids if not sim.servo(i).free]


@pytest.mark.parametrize("driver", ["asyncio", "thread", "anyio"])
async def test_a_bus_closing_a_stream_that_outlived_its_block_closes_even_when_cancelled_again(driver: str) -> None:
    # A review's find: a second cancellation during the stream's close-out (run by the bus's close) came
    # out of it before the port was closed: the bus stayed open after its block, port held.
    ids = list(range(1, 9))
    sim = make_sim(ids, realtime=True)
    kept: list[Bus] = []
    started = asyncio.Event()

    async def controller() -> None:
        async with contextlib.AsyncExitStack() as outlives, open_bus(sim, driver=driver, **PATIENT) as bus:
            kept.append(bus)
            stream = await outlives.enter_async_context(bus.stream(ids, on_close="free"))
            stream.set_targets(dict.fromkeys(ids, 8000))
            await frames_until(stream, lambda f: f.cycle > 2)
            started.set()
            await asyncio.sleep(3600)

    task = asyncio.ensure_future(controller())
    await started.wait()
    await cancel_twice_while_it_frees(task, sim)
    assert not kept[0].is_open
    assert all(sim.servo(i).free for i in ids)


async def test_slow_consumer_gets_the_latest_frame_and_a_skip_count_without_slowing_the_bus() -> None:
    ids = list(range(32))
    sim = make_sim(ids)
    async with streaming(sim, ids) as (_, stream):
        frames = [await next_frame(stream)]
        for _ in range(4):
            # A consumer busy for five cycles' worth of line time (measured on the line, not the clock).
            mark = sim.transactions
            await wait_for_sim(lambda mark=mark: sim.transactions >= mark + 5 * 32, "five cycles")
            frames.append(await next_frame(stream))
        stats = stream.stats
    for prev, frame in itertools.pairwise(frames):
        assert frame.skipped == frame.cycle - prev.cycle - 1
        assert frame.skipped >= 4  # the bus kept cycling while nobody looked
    assert stats.frames_dropped >= sum(f.skipped for f in frames[1:])
    check_frames(frames, sim, ids)


@pytest.mark.realtime
async def test_fixed_rate_never_runs_faster_than_asked_and_leaves_the_line_to_requests() -> None:
    ids = [0, 1, 2, 3]
    rate = 50.0
    sim = make_sim(ids)
    async with streaming(sim, ids, rate_hz=rate) as (bus, stream):
        frames = [await next_frame(stream) for _ in range(6)]
        # Between cycles the line is free: a request goes through while the stream waits.
        assert await bus.servo(2).read_stretch() == 42
        frames += [await next_frame(stream) for _ in range(2)]
        stats = stream.stats
    first = frames[0]
    for frame in frames[1:]:
        # Scheduled from the first cycle's start (re-anchored only later, after an overrun).
        assert frame.started >= first.started + (frame.cycle - first.cycle) / rate - 1e-9
    assert frames[-1].cycle - first.cycle >= 6
    assert stats.cycle_time_p50 <= stats.cycle_time_p90 <= stats.cycle_time_p99 <= stats.cycle_time_max
    assert stats.rate_hz > 0
    check_frames(frames, sim, ids)


@pytest.mark.realtime
async def test_the_achieved_rate_is_counted_between_cycle_starts() -> None:
    # Counted as frames over the time since the first cycle began, the first frame counted as a
    # whole period already run: a 50 Hz stream said about 140 Hz after its first frame, 57 after eight.
    ids = [0, 1]
    rate = 50.0
    sim = make_sim(ids)
    async with streaming(sim, ids, rate_hz=rate) as (_, stream):
        first = await next_frame(stream)
        stats, latest = stream.stats, stream.latest
        assert latest is not None
        if latest.cycle == 1:  # (a loaded machine's loop may have let the next cycle run meanwhile)
            assert stats.rate_hz == 0.0  # one cycle: no interval to measure yet
        for _ in range(4):
            await next_frame(stream)
        stats, latest = stream.stats, stream.latest
    assert latest is not None and latest.cycle > first.cycle
    # (Counted from cycle 1's start: the same intervals when the first frame read is cycle 1; on a loaded machine
    # it may be cycle 2, whose start is one slot later on the same grid.)
    exact = 1e-6 if first.cycle == 1 else 0.1
    assert stats.rate_hz == pytest.approx((latest.cycle - first.cycle) / (latest.started - first.started), rel=exact)
    assert stats.rate_hz <= rate * (1 + 1e-6)  # cycles start on their slots, never earlier


@pytest.mark.realtime
async def test_an_impossible_rate_counts_overruns() -> None:
    ids = list(range(32))
    # Real time: 32 position transactions at 115200 take > 20 ms, a 5000 Hz period is 0.2 ms.
    sim = make_sim(ids, realtime=True)
    try:
        async with (
            open_bus(sim, **REAL_TIME) as bus,
            bus.stream(ids, rate_hz=5000) as stream,
        ):
            frames = [await next_frame(stream) for _ in range(3)]
            stats = stream.stats
    finally:
        sim.close()
    # Every ID in each frame, answered or failed: a loaded machine (a stress run's CPU burners) can hold the
    # real-time simulator's reply past a stream read's learnt wait; the cycles themselves are the point.
    assert all(set(f.positions) | f.failed == set(ids) for f in frames)
    # Every cycle after the first started more than a whole period late.
    assert stats.cycles >= 3
    assert stats.overruns == stats.cycles - 1
    assert stats.cycle_time_p50 > 32 * 6 * 11 / 115200


@pytest.mark.realtime
@pytest.mark.parametrize("nothing_to_send", ["every ID offline", "every ID held"])
async def test_a_cycle_with_nothing_to_send_is_no_overrun(
    nothing_to_send: str, caplog: pytest.LogCaptureFixture
) -> None:
    # A paced stream whose IDs were all offline (the servos' supply off, the adapter on) or all held
    # (after a port came back) counted each of its empty cycles as an overrun, its timer firing just after
    # the slot: stats.overruns grew every cycle, and the "cannot keep rate_hz" warning blamed the adapter's
    # latency timer or a busy host for cycles that started on their slots.
    present = [] if nothing_to_send == "every ID offline" else [1, 2]
    sim = make_sim(present)
    with caplog.at_level("WARNING", logger="ics35_async"):
        async with (
            open_bus(sim, reconnect=True, **FAST) as bus,
            bus.stream([1, 2], rate_hz=50, probe_interval=60) as stream,
        ):
            if nothing_to_send == "every ID held":
                stream.set_targets({1: 7500, 2: 7500})
                await frames_until(stream, lambda f: len(f.positions) == 2)
                sim.unplug(replug_after=0.05)
                await frames_until(stream, lambda f: f.held == {1, 2})
            else:
                await frames_until(stream, lambda f: f.offline == {1, 2})
            await next_frame(stream)  # (the last cycle that sent anything has been checked against its slot)
            before = stream.stats
            frames = [await next_frame(stream) for _ in range(RATE_CHECK_CYCLES + 2)]
            after = stream.stats
    assert all(not f.positions and not f.failed for f in frames)  # nothing was sent in those cycles
    assert after.overruns == before.overruns, (before.overruns, after.overruns)
    assert not [r for r in caplog.records if "rate_hz" in r.getMessage()]


def rate_warning(caplog: pytest.LogCaptureFixture) -> str:
    """The one warning of a stream that cannot keep its rate (fails if there is none, or more than one)."""
    said = [r.getMessage() for r in caplog.records if "rate_hz" in r.getMessage()]
    assert len(said) == 1, said
    return said[0]


async def rate_warning_beside(
    caplog: pytest.LogCaptureFixture,
    sim: VirtualLine,
    ids: list[int],
    rate_hz: float,
    requests: list[Callable[[Bus], Awaitable[object]]],
    **options: Any,
) -> str:
    """The rate warning of a stream of ``ids`` at ``rate_hz`` on ``sim`` while the program sends ``requests``
    (each, on the bus, over and over, its failures ignored) beside it."""

    async def over_and_over(request: Callable[[Bus], Awaitable[object]], bus: Bus) -> None:
        while True:
            with contextlib.suppress(ReplyError):
                await request(bus)

    try:
        with caplog.at_level("WARNING", logger="ics35_async"):
            async with open_bus(sim, **options) as bus, bus.stream(ids, rate_hz=rate_hz) as stream:
                tasks = [asyncio.ensure_future(over_and_over(request, bus)) for request in requests]
                try:
                    while (await next_frame(stream)).cycle < 2 * RATE_CHECK_CYCLES:
                        pass
                finally:
                    for task in tasks:
                        task.cancel()
    finally:
        sim.close()
    return rate_warning(caplog)


def write_to_unplugged_servo(bus: Bus) -> Awaitable[object]:
    # (a write: a read of a silent servo in a paced stream's slack gives up sooner and holds only that servo back)
    return bus.servo(20).write_speed(100)


def read_eeprom_of(sid: int) -> Callable[[Bus], Awaitable[object]]:
    return lambda bus: bus.servo(sid).read_eeprom()


async def test_a_rate_the_line_cannot_keep_is_told_once_in_words(caplog: pytest.LogCaptureFixture) -> None:
    # 17 servos at 115200 with rate_hz=100 ran at about 63 Hz, said only by stats.overruns: a newcomer's
    # loop then runs slow without a word.  One warning, after the first cycles, with what to change.
    ids = list(range(17))
    sim = make_sim(ids, realtime=True)
    try:
        with caplog.at_level("WARNING", logger="ics35_async"):
            async with open_bus(sim, **REAL_TIME) as bus, bus.stream(ids, rate_hz=100) as stream:
                while (await next_frame(stream)).cycle < 2 * RATE_CHECK_CYCLES:
                    pass
            async with open_bus(sim, **REAL_TIME) as bus, bus.stream(ids[:4], rate_hz=20) as stream:
                while (await next_frame(stream)).cycle < RATE_CHECK_CYCLES + 2:
                    pass  # a rate the line keeps: nothing said
    finally:
        sim.close()
    said = rate_warning(caplog)
    assert "17 IDs" in said and "rate_hz=100" in said and "115200 baud" in said, said


async def test_a_servo_gone_offline_early_is_not_blamed_for_a_rate_the_wire_cannot_keep(
    caplog: pytest.LogCaptureFixture,
) -> None:
    # 17 servos at 115200 cannot make 100 Hz whatever an 18th, absent one does: it goes offline after
    # three cycles; the warning named it as the cause and left out the wire time.
    ids = list(range(17))
    sim = make_sim(ids, realtime=True)
    try:
        with caplog.at_level("WARNING", logger="ics35_async"):
            async with open_bus(sim, **REAL_TIME) as bus, bus.stream([*ids, 30], rate_hz=100) as stream:
                while (await next_frame(stream)).cycle < RATE_CHECK_CYCLES + 2:
                    pass
    finally:
        sim.close()
    said = rate_warning(caplog)
    assert "115200 baud" in said and "did not answer" not in said, said


async def test_a_rate_lost_to_requests_for_a_silent_servo_is_told_as_such(caplog: pytest.LogCaptureFixture) -> None:
    # Six servos at 1.25 Mbit/s need 0.4 ms of a 10 ms period; a program writing to an unplugged servo over and
    # over takes a whole reply allowance and a quiet time each time.  The warning said "raise the baud rate,
    # stream fewer IDs": the stream was never the cause.
    ids = list(range(6))
    sim = make_sim(ids, realtime=True, baudrate=1250000)
    said = await rate_warning_beside(caplog, sim, ids, 100, [write_to_unplugged_servo], baudrate=1250000, **REAL_TIME)
    assert "requests" in said and "does not answer" in said, said
    assert "raise the baud rate" not in said, said


@pytest.mark.realtime
async def test_a_rate_lost_to_the_programs_eeprom_requests_is_told_as_such(caplog: pytest.LogCaptureFixture) -> None:
    # Six servos at 115200 need about half of a 150 Hz period; an EEPROM read takes more than the slack
    # left, so each goes once passed over in two slots and delays that cycle.  The warning blamed an
    # adapter's latency timer or a busy host.
    ids = list(range(6))
    sim = make_sim([*ids, 9, 10], realtime=True)
    said = await rate_warning_beside(caplog, sim, ids, 150, [read_eeprom_of(9), read_eeprom_of(10)], **REAL_TIME)
    assert "EEPROM" in said and "latency timer" not in said, said


@pytest.mark.realtime
async def test_a_rate_lost_to_several_causes_names_each(caplog: pytest.LogCaptureFixture) -> None:
    # The program writes to an unplugged servo and reads EEPROMs beside a 150 Hz stream: both cost its cycles.  The
    # warning named the first cause it checked that could account for half the late cycles and stopped there.
    ids = list(range(6))
    sim = make_sim([*ids, 9, 10], realtime=True)
    requests = [read_eeprom_of(9), read_eeprom_of(10), write_to_unplugged_servo]
    said = await rate_warning_beside(caplog, sim, ids, 150, requests, **REAL_TIME)
    assert "ID(s) 20 went unanswered" in said and "EEPROM" in said, said
    assert "latency timer" not in said and "raise the baud rate" not in said, said


async def test_a_rate_lost_to_the_streams_own_silent_servos_is_told_as_such(caplog: pytest.LogCaptureFixture) -> None:
    # Servos at 115200 streamed at 1.25 Mbit/s (a wrong baud rate): none answers, each costs its whole
    # reply allowance every cycle until it goes offline; the warning said "raise the baud rate".
    ids = list(range(4))
    sim = make_sim(ids, realtime=True)  # the servos talk at 115200, the bus at 1250000
    try:
        with caplog.at_level("WARNING", logger="ics35_async"):
            options = {**FAST, "baudrate": 1250000}  # (nothing answers: the allowance is what a cycle costs)
            async with open_bus(sim, **options) as bus, bus.stream(ids, rate_hz=100, offline_after=1000) as stream:
                while (await next_frame(stream)).cycle < 2 * RATE_CHECK_CYCLES:
                    pass
    finally:
        sim.close()
    said = rate_warning(caplog)
    assert "its ID(s) 0, 1, 2, 3 did not answer" in said and "baud rate" in said, said
    assert "raise the baud rate" not in said, said


async def test_a_rate_lost_beyond_the_wire_is_not_blamed_on_the_baud_rate(
    caplog: pytest.LogCaptureFixture,
) -> None:
    # Six servos at 1.25 Mbit/s need 0.3 ms of a 10 ms period on the wire; the cycle's time went to the
    # answers (here servos slow to answer, as behind an adapter's 16 ms latency timer; a thread computing
    # without pause, holding the GIL, does the same to the loop: a newcomer's loop at 22-38 Hz).  The warning
    # said "raise the baud rate, stream fewer IDs or ask a lower rate (or the host is busy)".
    ids = list(range(6))
    sim = make_sim(ids, realtime=True, baudrate=1250000, turnaround=0.003)
    try:
        with caplog.at_level("WARNING", logger="ics35_async"):
            async with open_bus(sim, baudrate=1250000, **REAL_TIME) as bus, bus.stream(ids, rate_hz=100) as stream:
                while (await next_frame(stream)).cycle <= RATE_CHECK_CYCLES:  # (told at the check's last cycle)
                    pass
    finally:
        sim.close()
    said = rate_warning(caplog)
    assert "only 0.3 ms of each 10.0 ms period" in said and "latency timer" in said and "GIL" in said, said
    assert said.endswith("or ask a lower rate"), said
    assert "raise the baud rate" not in said, said


@pytest.mark.realtime
async def test_a_stream_that_falls_behind_later_says_so_once_an_episode(caplog: pytest.LogCaptureFixture) -> None:
    # A stream that kept its rate through its first cycles and fell behind later (a program starting to write to
    # an unplugged servo: each request holds the line for a whole reply allowance) ran at 36 Hz of 100 with not a
    # word: the warning judged the first 20 cycles only.  It is told once an episode: again only after the
    # stream kept its rate for a while and fell behind again.
    ids = list(range(6))
    sim = make_sim(ids, realtime=True, baudrate=1250000)
    told_at: list[int] = []  # the cycle of the newest frame when each warning was seen

    def rate_warnings() -> list[str]:
        return [r.getMessage() for r in caplog.records if "rate_hz" in r.getMessage()]

    async def frames_while(stream: Stream, cycles: int) -> None:
        until = (await next_frame(stream)).cycle + cycles
        while (frame := await next_frame(stream)).cycle < until:
            if len(rate_warnings()) > len(told_at):
                told_at.append(frame.cycle)

    async def writing(bus: Bus) -> None:
        while True:
            with contextlib.suppress(ReplyError):
                await write_to_unplugged_servo(bus)

    try:
        with caplog.at_level("WARNING", logger="ics35_async"):
            async with open_bus(sim, baudrate=1250000, **REAL_TIME) as bus, bus.stream(ids, rate_hz=100) as stream:
                await frames_while(stream, 2 * RATE_CHECK_CYCLES)  # the rate kept: nothing said
                assert not told_at, rate_warnings()
                for _ in range(2):  # two episodes of falling behind, the rate kept in between
                    writer = asyncio.ensure_future(writing(bus))
                    try:
                        await frames_while(stream, 4 * RATE_CHECK_CYCLES)  # (told once, not once a window)
                    finally:
                        writer.cancel()
                    # (kept for RATE_KEPT_WINDOWS whole windows: the one the writer ended in is neither)
                    await frames_while(stream, (RATE_KEPT_WINDOWS + 5) * RATE_CHECK_CYCLES)
    finally:
        sim.close()
    said = rate_warnings()
    assert len(said) == 2 and told_at[0] > 2 * RATE_CHECK_CYCLES, (told_at, said)
    for warning in said:
        assert "stream of 6 IDs cannot keep rate_hz=100" in warning and "of its last 20 cycles" in warning, warning
        assert "ID(s) 20 went unanswered" in warning and "does not answer" in warning, warning
        assert "raise the baud rate" not in warning, warning


async def test_a_request_beside_a_stream_that_cannot_keep_its_rate_is_still_answered() -> None:
    # 32 servos at 115200 in real time: a cycle takes over 20 ms, so a 100 Hz stream is always late and
    # never leaves a slack; a request still gets the line within two cycles (the engine's rule).
    ids = list(range(32))
    sim = make_sim(ids, realtime=True)
    try:
        # Every servo answers: the no-timeouts allowance (on a loaded machine the request's reply can come
        # late from the real-time simulator; what is tested is that it gets the line at all).
        async with open_bus(sim, **NO_TIMEOUTS) as bus, bus.stream(ids, rate_hz=100) as stream:
            await next_frame(stream)
            assert await asyncio.wait_for(bus.servo(5).read_stretch(), GUARD) == 45  # its own (make_sim)
            assert stream.stats.overruns >= 1
    finally:
        sim.close()


# --------------------------------------------------------------------------- bad input


async def test_bad_input_raises_invalid_argument_and_writes_nothing() -> None:
    ids = [1, 2, 3]
    sim = make_sim(ids)
    async with open_bus(sim, **FAST) as bus:
        before = sim.transactions
        for bad_ids in ([], [1, 1], [1, 2, 1], [32], [-1], ["1"], [True]):
            with pytest.raises(InvalidArgument):
                bus.stream(bad_ids)
        for options in (
            {"rate_hz": 0},
            {"rate_hz": -5},
            {"rate_hz": float("nan")},
            {"rate_hz": float("inf")},
            {"rate_hz": "50"},
            {"offline_after": 0},
            {"probe_interval": 0},
        ):
            with pytest.raises(InvalidArgument):
                bus.stream(ids, **options)
        # A choice refused names the choices in words, as open_robot's and open_bus's do (not a tuple's repr).
        with pytest.raises(InvalidArgument, match=r"^on_close must be one of hold, free, not 'drop'$"):
            bus.stream(ids, on_close="drop")  # type: ignore[arg-type]
        with pytest.raises(InvalidArgument, match=r"^on_resume must be one of [a-z]+, [a-z]+, not 'go'$"):
            bus.stream(ids, on_resume="go")  # type: ignore[arg-type]
        with pytest.raises(InvalidArgument):
            BusGroup({})
        with pytest.raises(InvalidArgument):
            BusGroup({"a": bus}).stream({"b": [1]})
        assert sim.transactions == before

        async with bus.stream(ids, rate_hz=20) as stream:
            stream.set_targets({1: 6000, 2: 7000, 3: 8000})
            for call in (
                lambda: stream.set_target(4, 7500),  # not in the stream
                lambda: stream.set_target(1, 20000),
                lambda: stream.set_target(1, -1),
                lambda: stream.set_target(1, 7500.0),
                lambda: stream.set_target(1, True),
                lambda: stream.set_target("1", 7500),  # type: ignore[arg-type]
                lambda: stream.set_targets({1: 9000, 2: 20000}),  # all or nothing
                lambda: stream.set_targets({3: 9000, 9: 7500}),
                lambda: stream.set_targets_degrees({1: 500.0}),
                lambda: stream.free([7]),
                lambda: stream.target(9),
            ):
                written = sim.transactions
                with pytest.raises(InvalidArgument):
                    call()
                assert sim.transactions == written
            assert [stream.target(i) for i in ids] == [6000, 7000, 8000]
            stream.set_targets_degrees({1: 0.0})
            assert stream.target(1) == 7500
            with pytest.raises(InvalidArgument):
                await bus.stream([2]).start()  # one stream per bus
            seq = sim.transactions
            frames = await frames_until(stream, lambda f: (f.cycle - 1) * 3 >= seq)
        assert frames
        sent = {t.tx for t in position_log(sim, seq)}
        assert sent == {position_tx(1, 7500), position_tx(2, 7000), position_tx(3, 8000)}


@pytest.mark.realtime
async def test_a_closed_streams_last_reply_never_reaches_the_next_stream() -> None:
    """Close a stream with its command on the wire, start another: the old reply is not the new one's."""
    sim = VirtualLine([VirtualServo(i) for i in (1, 2, 3, 4)], realtime=True)
    # Every servo answers: the no-timeouts allowance (a 10 ms one once failed servo 3's first read when
    # the real-time simulator answered late beside two CPU burners, which says nothing of the old reply).
    async with open_bus(sim, **{**NO_TIMEOUTS, "quiet_time": 0.002}) as bus:
        async with bus.stream([1, 2]) as first:
            await first.next_frame()
        async with bus.stream([3, 4]) as second:
            frame = await second.next_frame()
            frame = await second.next_frame()
            assert set(frame.positions) == {3, 4} and not frame.failed
            assert second.stats.failures == {}
            assert second.stats.cycle_time_max < 1.0  # no bogus cycle from the old stream's reply


async def test_a_group_that_fails_to_start_leaves_no_line_streaming() -> None:
    sims = [make_sim(range(4)), make_sim(range(4))]
    group = BusGroup({"a": open_bus(sims[0], **FAST), "b": open_bus(sims[1], **FAST)})
    async with group:
        await group["b"].aclose()
        with pytest.raises(BusClosed):
            async with group.stream({"a": [0, 1], "b": [2, 3]}):
                pass
        async with group["a"].stream([0, 1]) as stream:  # line a is free again
            await stream.next_frame()


# --------------------------------------------------------------------------- trouble a controller can see


@pytest.mark.parametrize("driver", ["asyncio", "thread"])
@pytest.mark.parametrize("on_resume", ["wait", "free"])
async def test_a_resumed_stream_sends_no_old_target_to_servos_that_restarted(driver: str, on_resume: str) -> None:
    ids = [0, 1, 2, 3]
    sim = make_sim(ids)
    opened = open_bus(sim, reconnect=True, driver=driver, **FAST)
    async with opened as bus, bus.stream(ids, on_resume="wait" if on_resume == "wait" else "free") as stream:
        old = {i: start_position(i) + 900 for i in ids}
        stream.set_targets(old)
        await frames_until(stream, lambda f: all(abs(f.positions.get(i, 0) - old[i]) < 20 for i in ids))
        sim.unplug(replug_after=0.05)
        sim.power_cycle()  # the servos lost power too: they wake up free, where they are
        for i in ids:
            sim.servo(i).move_by_hand(start_position(i))  # ...and were moved by hand meanwhile
        seq = sim.transactions
        resumed = await frames_until(stream, lambda f: f.resumed)
        frame = resumed[-1]
        more = [await next_frame(stream) for _ in range(3)]
        commands = [t for t in sim.log_since(seq) if t.command in POSITION_COMMANDS]
        # No command after the resume moves a servo toward its old target.
        assert all(t.tx[1:] == b"\x00\x00" or t.command == "free" for t in commands), commands[:3]
        assert not any(f.resumed for f in more)
        if on_resume == "wait":
            assert frame.held == set(ids) and all(f.held == set(ids) for f in more)
            assert not commands  # nothing at all goes to a held ID
            stream.set_target(2, start_position(2) + 50)  # the program decides again: only that ID
            await frames_until(stream, lambda f: 2 in f.positions)
            assert stream.target(2) == start_position(2) + 50
        else:
            assert not frame.held
            assert frame.positions == {i: start_position(i) for i in ids}  # read back, free
            assert all(stream.target(i) == protocol.FREE for i in ids)


async def test_a_stalled_loop_shows_as_missed_slots_on_the_frame_and_in_the_stats() -> None:
    ids = [0, 1]
    sim = make_sim(ids)
    async with open_bus(sim, **FAST) as bus, bus.stream(ids, rate_hz=100) as stream:
        await frames_until(stream, lambda f: f.cycle >= 3)
        time.sleep(0.06)  # the program blocks its event loop: six slots pass with no cycle
        # (the frame of the stall's cycle: on a loaded machine a frame before it may have missed a slot of its own)
        after = await frames_until(stream, lambda f: f.missed_slots >= 3, limit=20)
        assert stream.stats.missed_slots >= after[-1].missed_slots
        assert json.loads(json.dumps(after[-1].to_dict()))["missed_slots"] == after[-1].missed_slots


async def test_switching_an_id_between_watch_and_a_target_mid_transaction_fails_nothing() -> None:
    # A program's set_targets and watch run while the stream's transaction is on the wire: the
    # reply in flight answers the command that was sent, and must be read as that command's.
    servos = [VirtualServo(i, position=start_position(i), ics36=True) for i in (1, 2)]
    sim = VirtualLine(servos, realtime=True)
    async with open_bus(sim, **FAST) as bus, bus.stream([1, 2]) as stream:
        switches = 0
        for _ in range(60):
            stream.watch([1, 2])
            await next_frame(stream)
            stream.set_targets({1: 7500, 2: 7500})
            await next_frame(stream)
            switches += 2
        # A reply read with the other command's parser is a bad reply.  On a loaded machine the real-time
        # simulator's thread can answer late: a timeout, and its late reply may then fail the next
        # transaction as a bad one.  Only those are allowed: the parser's mistake would fail many switches.
        total = bus.stats.total
        assert total.bad_replies <= total.timeouts, (total, stream.stats.failures)
        assert bus.stats.total.ok > switches


async def test_a_group_takes_targets_in_degrees_as_one_stream_does() -> None:
    sims = [make_sim(range(2)), make_sim(range(2))]
    group = BusGroup({"a": open_bus(sims[0], **FAST), "b": open_bus(sims[1], **FAST)})
    async with group, group.stream({"a": [0, 1], "b": [0, 1]}) as gstream:
        gstream.set_targets_degrees({("a", 1): 30.0, ("b", 1): -45.0})
        assert gstream.streams["a"].target(1) == round(7500 + 30.0 * 8000 / 270)
        assert gstream.streams["b"].target(1) == round(7500 - 45.0 * 8000 / 270)


@pytest.mark.parametrize("on_close", ["free", "hold"])
async def test_what_the_close_could_not_put_on_the_wire_is_not_said_sent(on_close: str) -> None:
    # The port is lost and not back when the block ends: the close's commands never go out, so the
    # servos keep holding what they held; targets_sent_on_close must not claim them (a robot's targets
    # are set from it).
    ids = [1, 2]
    sim = make_sim(ids)
    async with open_bus(sim, reconnect=True, **FAST) as bus:
        stream = bus.stream(ids, on_close=on_close)
        stream.set_targets({1: 7000, 2: 8000})
        async with stream:
            await next_frame(stream)
            stream.set_target(2, 9000)  # (a target since the last cycle: what "hold" would send)
            sim.unplug(replug_after=60.0)
            with anyio.fail_after(GUARD):
                while bus.state is not State.LOST:
                    await bus.state_change()
        assert stream.targets_sent_on_close == {}
    assert not sim.servo(1).free and not sim.servo(2).free


async def test_what_the_close_had_no_time_to_send_is_not_said_sent() -> None:
    # on_close="free" over IDs 0-3 of which 0 answers; once its free is out a program's urgent reads of a silent
    # ID take the line (requests beside the stream: its bound does not count them) until the close's bound runs
    # out with the other frees still queued: those never went out.
    sim = make_sim([0])
    async with open_bus(sim, **{**FAST, "adapter_latency": 0.1}) as bus:
        ids = list(range(4))
        stream = bus.stream(ids, on_close="free")
        reads: list[Any] = []

        async def take_the_line() -> None:
            while not any(t.servo_id == 0 and t.tx[1:3] == b"\0\0" for t in sim.log_since(mark)):
                await asyncio.sleep(0.001)
            reads.extend(bus.submit(ReadParam(20, Param.TEMPERATURE), priority=Priority.HIGH) for _ in range(40))

        async with stream:
            await next_frame(stream)
            mark = sim.transactions
            hog = asyncio.create_task(take_the_line())
        sent = stream.targets_sent_on_close
        on_wire = {t.servo_id for t in sim.log_since(mark) if t.tx[1:3] == b"\0\0"}  # the frees that went out
        await hog
        for read in reads:
            read.cancel()
    assert 0 in sent and len(sent) < len(ids), sent
    assert set(sent) <= on_wire, (sorted(sent), sorted(on_wire))


async def test_streams_and_groups_say_what_they_are_in_their_repr() -> None:
    # A program that prints its stream (a log line, a debugger) saw `<ics35_async.stream.Stream object at 0x...>`
    # beside the bus's and the servos' own reprs.
    async with open_bus(make_sim([1, 2, 3]), **FAST) as bus:
        stream = bus.stream([1, 2, 3], rate_hz=100)
        assert repr(stream).startswith("<Stream [1, 2, 3] at 100 Hz, not started, on <Bus ")
        async with stream:
            assert repr(stream).startswith("<Stream [1, 2, 3] at 100 Hz, running, on <Bus ")
        assert repr(stream).startswith("<Stream [1, 2, 3] at 100 Hz, closed, on <Bus ")
        assert repr(bus.stream([2])).startswith("<Stream [2] back to back, not started, on <Bus ")
    lines = {"left": open_bus(make_sim([1, 2]), **FAST), "right": open_bus(make_sim([1]), **FAST)}
    async with BusGroup(lines) as group:
        assert repr(group) == f"<BusGroup left={lines['left']!r}, right={lines['right']!r}>"
        async with group.stream({"left": [1, 2], "right": [1]}, rate_hz=50) as merged:
            assert repr(merged) == "<GroupStream left: [1, 2] at 50 Hz, right: [1] at 50 Hz, running>"
        assert repr(merged) == "<GroupStream left: [1, 2] at 50 Hz, right: [1] at 50 Hz, closed>"


async def test_a_group_opens_from_a_list_of_ports_as_from_a_list_of_buses() -> None:
    # BusGroup([bus, bus]) names its lines "0", "1", ...; BusGroup.open([port, port]) raised AttributeError.
    sims = [make_sim([1]), make_sim([2])]
    async with BusGroup.open(sims, **FAST) as group:
        assert list(group.buses) == ["0", "1"]
        assert await group["1"].servo(2).read_stretch() == 42


@pytest.mark.parametrize("closers", ["stream, bus", "stream, bus, bus"])
@pytest.mark.parametrize("on_close", ["free", "hold"])
async def test_the_bus_closing_while_its_stream_closes_lets_the_close_out_reach_the_servos(
    on_close: str, closers: str
) -> None:
    # The stream closed in one task (its block left, a task cancelled) while the program closed the bus in
    # another: the bus's close found the stream already detached and failed the commands its close had
    # queued, so with on_close="free" every servo kept holding and targets_sent_on_close said nothing went.
    # A second close of the bus meanwhile (a shutdown handler beside the block's end) did the same.
    ids = [1, 2, 3]
    sim = make_sim(ids)
    bus = await open_bus(sim, **FAST)
    stream = bus.stream(ids, rate_hz=50, on_close=on_close)
    stream.set_targets(dict.fromkeys(ids, 8000))
    await stream.start()
    await next_frame(stream)
    stream.set_targets(dict.fromkeys(ids, 8100))  # (a final pose: "hold" sends it as it closes)
    seq = sim.transactions
    await asyncio.gather(*({"stream": stream, "bus": bus}[name].aclose() for name in closers.split(", ")))
    sent = {t.servo_id: t.command for t in sim.log_since(seq) if t.command in POSITION_COMMANDS}
    expected = "free" if on_close == "free" else "position"
    assert sent == dict.fromkeys(ids, expected), sent
    assert stream.targets_sent_on_close == dict.fromkeys(ids, 0 if on_close == "free" else 8100)
    if on_close == "free":
        assert all(servo.free for servo in sim.devices if isinstance(servo, VirtualServo))


async def test_a_watched_id_that_goes_offline_unheard_is_said_maybe_an_ics35_servo(
    caplog: pytest.LogCaptureFixture,
) -> None:
    # watch sends the ICS 3.6 position read: an ICS 3.5 servo (most KRS servos) stays silent to it and the
    # frames only said "offline", as for a servo not there.  Said once per ID, naming both causes and the
    # way to read its position; not for an ICS 3.6 servo heard before, nor for one that went offline while
    # it had a target.
    servos = [VirtualServo(1), VirtualServo(2, ics36=True), VirtualServo(3)]
    sim = VirtualLine(servos)
    with caplog.at_level("WARNING", logger="ics35_async"):
        async with open_bus(sim, **FAST) as bus, bus.stream([1, 2, 3], offline_after=2) as stream:
            stream.watch([1, 2])
            await frames_until(stream, lambda f: 1 in f.offline and f.cycle > 20)
            sim.remove_servo(2)  # (an ICS 3.6 servo heard, then gone)
            sim.remove_servo(3)  # (a target, not a watch)
            await frames_until(stream, lambda f: {2, 3} <= f.offline)
            for _ in range(5):
                await next_frame(stream)
    said = [r.getMessage() for r in caplog.records if "ICS 3.5" in r.getMessage()]
    assert len(said) == 1, said
    assert "ID 1" in said[0] and "free" in said[0]


async def test_a_group_frame_is_plain_json_by_line_and_says_its_degrees() -> None:
    sims = [make_sim(range(3)), make_sim(range(2))]
    group = BusGroup({"a": open_bus(sims[0], **FAST), "b": open_bus(sims[1], **FAST)})
    async with group, group.stream({"a": [0, 1, 2], "b": [0, 1]}) as gstream:
        gstream.set_targets_degrees({("a", 1): 30.0, ("b", 0): -45.0})
        frame = await gstream.next_frame()
        frame = await gstream.next_frame()
    assert frame.degrees() == {key: units.position_to_degrees(p) for key, p in frame.positions.items()}
    doc = json.loads(json.dumps(frame.to_dict()))
    assert doc["positions"] == {
        line: {str(i): p for (ln, i), p in frame.positions.items() if ln == line} for line in ("a", "b")
    }
    assert doc["degrees"]["a"]["1"] == round(units.position_to_degrees(frame.positions[("a", 1)]), 2)
    assert doc["line_cycles"] == frame.line_cycles and doc["cycle"] == frame.cycle
    assert doc["failed"] == {"a": [], "b": []} and doc["resumed"] == []


class WritersRecorded:
    """The far end of a line (a simulator) that notes which thread wrote each command."""

    def __init__(self, sim: VirtualLine) -> None:
        self.sim = sim
        self.writers: set[int] = set()

    def connect(self, host: Any, baudrate: int) -> None:
        self.sim.connect(host, baudrate)

    def write(self, data: bytes) -> None:
        self.writers.add(threading.get_ident())
        self.sim.write(data)

    def disconnect(self) -> None:
        self.sim.disconnect()


@pytest.mark.parametrize("driver", ["asyncio", "anyio"])
async def test_targets_set_from_another_thread_go_on_the_wire_from_the_loops_thread(driver: str) -> None:
    # A program's vision thread sets the stream's targets.  The engine of these drivers runs on the loop's thread
    # without a lock: a stream held with nothing to send (after a lost port) put its next command on the wire
    # from the program's thread, inside the engine beside the loop's own calls.
    sim = make_sim([1, 2])
    device = WritersRecorded(sim)
    async with open_bus(device, reconnect=True, driver=driver, **FAST) as bus, bus.stream([1, 2]) as stream:
        stream.set_targets({1: 7000, 2: 8000})
        await frames_until(stream, lambda f: len(f.positions) == 2)
        sim.unplug(replug_after=0.05)
        await frames_until(stream, lambda f: f.held == {1, 2})
        device.writers.clear()
        thread = threading.Thread(target=stream.set_targets, args=({1: 7100, 2: 8100},))
        thread.start()
        thread.join()
        await frames_until(stream, lambda f: f.positions.keys() == {1, 2} and not f.held)
        assert device.writers == {threading.get_ident()}
    assert (sim.servo(1).target, sim.servo(2).target) == (7100, 8100)


async def test_the_bus_closing_waits_for_an_earlier_streams_close_out_when_another_stream_started_meanwhile() -> None:
    # The bus waited only for the stream attached last: a stream closing with its frees queued, the program's
    # next stream started meanwhile, then the bus closed under the frees (the first stream's servos left holding).
    sim = make_sim(range(1, 7))
    bus = await open_bus(sim, **FAST)
    first = bus.stream([1, 2, 3], on_close="free")
    first.set_targets(dict.fromkeys([1, 2, 3], 8000))
    await first.start()
    await next_frame(first)
    await next_frame(first)
    second = bus.stream([4, 5, 6])  # (on_close="hold": nothing left to send when it closes)
    closing = asyncio.ensure_future(first.aclose())
    await asyncio.sleep(0)  # (the first stream's frees are queued)
    await second.start()
    await asyncio.gather(closing, bus.aclose())
    assert first.targets_sent_on_close == dict.fromkeys([1, 2, 3], FREE)
    assert all(sim.servo(i).free for i in (1, 2, 3))


@every_backend
@pytest.mark.parametrize("unplugged_from", ["the program", "another thread"])
async def test_a_stream_on_an_unplugged_simulated_port_says_it_was_unplugged(unplugged_from: str) -> None:
    # The loss raced the stream's next write: a write that came first met the line already gone and said "the
    # simulated port is gone" (most often on uvloop) instead of why it went.
    from ics35_async import sim

    for attempt in range(5):
        name = f"unplug-words-{unplugged_from.replace(' ', '-')}-{attempt}"
        async with open_bus(f"sim://{name}?ids=1", **FAST) as bus:
            line = sim.named(name)
            try:
                with pytest.raises(PortLost) as lost:
                    async with bus.stream([1]) as stream:
                        async for frame in stream:
                            if frame.cycle >= 2 and line.plugged:  # (>=: a consumer slower than the line skips frames)
                                if unplugged_from == "the program":
                                    line.unplug()
                                else:
                                    threading.Thread(target=line.unplug).start()
                assert str(lost.value).endswith("the simulated port was unplugged"), str(lost.value)
            finally:
                line.close()


async def test_a_frame_tells_the_failed_ids_that_were_sent_nothing() -> None:
    # A servo whose reply the stream gave up on after its short, learnt wait is held back while that reply could
    # still come: the stream skips it, sending nothing, and the frame lists it as failed.  The frame says which
    # failed IDs were sent nothing (``not_sent``): lining frames up with the line's traffic (a recording, a log
    # of the wire) took each failed ID for a command that went out, and every later one of that ID off by one.
    ids = [1, 2, 3, 4]
    sim = make_sim(ids, faults="drop@3:0.3", seed=1)
    # (an allowance far above what the servos take, so the stream's learnt wait is the shorter: a failure holds)
    async with open_bus(sim, adapter_latency=0.05, quiet_time=0.01, retries=0) as bus:
        async with bus.stream(ids, rate_hz=200) as stream:
            frames = [await next_frame(stream) for _ in range(100)]
        held_back = bus.stats.held_back
    assert held_back and any(3 in frame.not_sent for frame in frames), held_back
    assert all(frame.not_sent <= {3} for frame in frames)
    check_frames(frames, sim, ids)
    assert frames[0].to_dict()["not_sent"] == sorted(frames[0].not_sent)


@pytest.mark.pty
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the pty simulator needs Linux")
async def test_a_frame_tells_an_id_failed_by_its_guard_read_on_a_silent_line_was_sent_nothing() -> None:
    # A line that sends nothing back, not even the echo (a simulator held up by a loaded machine, an adapter that
    # stalls): each ID's command times out unheard, and its next one gets a guard read first.  A guard read that
    # gets nothing back too counts as that command's try, and the command is not sent: its frame lists the ID as
    # failed, and must say it was sent nothing.  (Lining frames up with the log, the chaos soak's oracle took the
    # ID's next command for this one and put every later value of that ID one cycle off.)
    ids = [1, 2, 3]
    sim = make_sim(ids)
    server = PtyServer(sim)
    path = str(server.open())
    serving = threading.Thread(target=server.serve, daemon=True)
    serving.start()
    try:
        async with await open_bus(path, **FAST, retries=0) as bus:
            counters = bus._engine.counters  # (the holder reads them from its thread: ints, in place)
            # (paced, a slot of 20 ms, so that the test takes every frame: the stream keeps only the newest)
            async with bus.stream(ids, rate_hz=50, offline_after=100) as stream:
                frames = [await next_frame(stream) for _ in range(3)]
                with sim._lock:  # the server thread waits here: nothing comes back, not even the echo
                    guards = counters.guards
                    # (taking every frame meanwhile, so each cycle is checked: a cycle ends in a frame, failed or not)
                    while counters.guards < guards + 2 and len(frames) < 100:
                        frames.append(await next_frame(stream))
                    frames += [await next_frame(stream) for _ in range(2)]
                frames += [await next_frame(stream) for _ in range(20)]
    finally:
        server.stop()
        serving.join(GUARD)
        server.close()
    assert counters.guards >= guards + 2  # (what this is about: guard reads on the silent line, and after them)
    assert any(f.not_sent for f in frames), frames  # (an ID whose guard read got nothing, sent nothing)
    assert [f.cycle for f in frames] == list(range(1, len(frames) + 1))  # (every frame: each cycle is checked)
    # Each frame's commands, in the log in turn (a cycle whose IDs all went unsent has none).  Over a pty the
    # replies the held simulator logged came too late: the commands that went out are what a frame tells.
    log, seen = position_log(sim), 0
    for frame in frames:
        told = sorted(set(frame.positions) | (frame.failed - frame.not_sent))
        went, seen = log[seen : seen + len(told)], seen + len(told)
        assert [t.servo_id for t in went] == told, (frame, went)
        assert frame.positions == {t.servo_id: t.value for t in went if t.servo_id in frame.positions}, frame
