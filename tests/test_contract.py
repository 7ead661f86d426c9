"""One public-API contract, run on every driver and async library.

The same scenarios drive the bus through the asyncio driver (I/O callbacks),
the thread driver (the engine in an I/O thread blocking on the port) and the anyio driver
(one bus task), under asyncio (also on uvloop) and under trio, against the in-process
simulator and against the pty simulator in another process.  anyio's pytest plugin runs
each test on the case's library (``anyio_backend``); the ``bus`` fixture opens the case's bus.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import AsyncIterator, Callable, Iterator
from typing import Any, TypeVar

import anyio
import pytest

from ics35_async import (
    Bus,
    BusClosed,
    BusGroup,
    InvalidArgument,
    ReplyError,
    ReplyTimeout,
    Stream,
    open_bus,
    protocol,
)
from ics35_async.drivers import burst
from ics35_async.drivers.burst import ENV, burst_path
from ics35_async.sim import start_subprocess, stop_subprocess
from tests.conftest import SIM_LAST, every_backend, sim_notes
from tests.support.timing import FAST, GUARD, NO_TIMEOUTS, PATIENT

IDS = range(8)
T = TypeVar("T", bound=Callable[..., Any])

# (driver, async library, far end)
CASES = [
    ("asyncio", "asyncio", "sim"),
    ("anyio", "asyncio", "sim"),
    ("anyio", "trio", "sim"),
    ("asyncio", "asyncio", "pty"),
    ("asyncio", "asyncio", "pty-ordinary"),
    ("asyncio", "uvloop", "sim"),
    ("asyncio", "uvloop", "pty"),
    ("asyncio", "uvloop", "pty-ordinary"),
    ("thread", "asyncio", "pty"),
    ("thread", "asyncio", "pty-ordinary"),
    ("thread", "asyncio", "sim"),
    ("thread", "uvloop", "pty"),
    ("anyio", "trio", "pty"),
    ("anyio", "trio", "pty-ordinary"),
    ("anyio", "asyncio", "pty"),
    ("thread", "trio", "pty"),
]
every_case = pytest.mark.parametrize(
    ("driver", "anyio_backend", "far"),
    CASES,
    ids=[f"{d}-{lib}-{far}" for d, lib, far in CASES],
    indirect=["anyio_backend"],
)


@pytest.fixture(scope="module")
def pty_port() -> Iterator[str]:
    with sim_notes("test_contract") as notes:
        proc, path = start_subprocess(["--fast", "--ids", "0-7", *SIM_LAST], notes=notes)
        try:
            yield path
        finally:
            stop_subprocess(proc)


def every_reply(test: T) -> T:
    """Mark a scenario that asks only servos that are there and fails on any error: its bus waits NO_TIMEOUTS
    for a reply, not PATIENT (on a loaded machine a stream's reply came later than PATIENT's half second; its
    late bytes failed the request they landed in, typed, but the scenario needs every reply)."""
    test.every_reply = True  # type: ignore[attr-defined]
    return test


@pytest.fixture
async def bus(
    driver: str, far: str, anyio_backend_name: str, request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch
) -> AsyncIterator[Bus]:
    """The case's bus on IDs 0-7: its driver, under its library, to its far end.

    Every driver on a pty's descriptor takes the burst path where it is built ("pty" turns it on, as
    default does, and lets bursts run beside requests, which the library pauses them for, so
    that requests arrive mid-burst); "pty-ordinary" turns it off (ICS35_BURST=0).
    """
    port = request.getfixturevalue("pty_port") if far.startswith("pty") else "sim://?ids=0-7"
    if far == "pty-ordinary":
        monkeypatch.setenv(ENV, "0")
    else:
        monkeypatch.setenv(ENV, "1")
        monkeypatch.setattr(burst, "PAUSE_AFTER_REQUEST", 0.0)
    # PATIENT: on a machine loaded by parallel tests a pty server can answer 50 ms late; the few
    # timeouts the scenarios expect (an absent ID) cost their half second each.  A scenario that asks only
    # servos that are there and needs every reply waits NO_TIMEOUTS (see every_reply).
    timing = NO_TIMEOUTS if getattr(request.function, "every_reply", False) else PATIENT
    async with open_bus(port, driver=driver, **timing) as opened:
        assert opened.driver == ("anyio" if driver == "anyio" or anyio_backend_name == "trio" else driver)
        # (Under trio "thread" is the anyio driver on the thread transport: no descriptor for the helper.)
        on_thread_transport = driver == "thread" and anyio_backend_name == "trio"
        bursts = far == "pty" and burst_path()[0] and not on_thread_transport
        assert (opened._driver.burst is not None) == bursts  # type: ignore[union-attr]
        assert opened.describe()["burst_path"] == bursts
        yield opened


@every_case
async def test_every_caller_gets_its_own_reply(bus: Bus) -> None:
    got: dict[int, int] = {}

    async def ask(i: int) -> None:
        got[i] = (await bus.servo(i).read_eeprom()).servo_id

    async with anyio.create_task_group() as group:
        for i in IDS:
            group.start_soon(ask, i)
    assert got == {i: i for i in IDS}
    assert isinstance(await bus.servo(3).read_stretch(), int)
    assert 3500 <= await bus.servo(2).free() <= 11500
    assert bus.stats.total.ok >= len(IDS) + 2


@every_case
async def test_a_missing_servo_times_out_and_the_line_carries_on(bus: Bus) -> None:
    with pytest.raises(ReplyTimeout):
        await bus.servo(20).read_speed()
    assert (await bus.servo(1).read_eeprom()).servo_id == 1
    assert bus.stats.per_id[20].timeouts == 1


@every_case
async def test_a_cancelled_request_does_not_desync_the_line(bus: Bus) -> None:
    for _ in range(5):
        with anyio.move_on_after(0):
            await bus.servo(4).read_eeprom()  # cancelled at once: queued or on the wire
        assert (await bus.servo(5).read_eeprom()).servo_id == 5


# Every driver on a pty, under each library it serves (the anyio driver under trio and on asyncio).
PTY_CASES = [case for case in CASES if case[2] == "pty"]
on_every_pty_case = pytest.mark.parametrize(
    ("driver", "anyio_backend", "far"),
    PTY_CASES,
    ids=[f"{d}-{lib}-{far}" for d, lib, far in PTY_CASES],
    indirect=["anyio_backend"],
)


@on_every_pty_case
async def test_a_submitted_request_tells_done_gives_its_result_and_cancels_as_a_future_does(bus: Bus) -> None:
    stretch, speed = protocol.Param.STRETCH, protocol.Param.SPEED
    # ID 20 is silent: its read stays on the wire for the whole allowance, and the next request waits queued.
    on_wire = bus.submit(protocol.ReadParam(20, speed), retries=2)
    queued = bus.submit(protocol.ReadParam(6, stretch))
    assert not on_wire.done() and not queued.done()  # type: ignore[attr-defined]
    with pytest.raises(asyncio.InvalidStateError):
        queued.result()  # type: ignore[attr-defined]
    assert queued.cancel() is True  # type: ignore[attr-defined]
    assert queued.done() and queued.cancelled()  # type: ignore[attr-defined]
    assert queued.cancel() is False  # type: ignore[attr-defined]  # (cancelled already)
    with pytest.raises(asyncio.CancelledError):
        queued.result()  # type: ignore[attr-defined]
    with pytest.raises(asyncio.CancelledError):
        await queued
    # On the wire: it finishes there (its deadline waited out, no retry), and the line carries on in step.
    assert on_wire.cancel() is True and on_wire.done()  # type: ignore[attr-defined]
    with pytest.raises(asyncio.CancelledError):
        await on_wire
    with anyio.fail_after(GUARD):
        assert (await bus.servo(5).read_eeprom()).servo_id == 5
    assert 6 not in bus.stats.per_id  # cancelled while queued: never sent
    assert bus.stats.per_id[20].transactions == 1 and bus.stats.per_id[20].retries == 0
    # A reply already on its way when the request is cancelled is read and dropped, not taken for the next one's.
    answered = bus.submit(protocol.ReadEeprom(4))
    assert answered.cancel() is True  # type: ignore[attr-defined]
    assert await bus.servo(3).read_stretch() == await bus.servo(3).read_stretch()
    assert (await bus.servo(2).read_eeprom()).servo_id == 2
    # Done: its result, again and again, and a cancel that changes nothing.
    done = bus.submit(protocol.ReadParam(1, stretch))
    with anyio.fail_after(GUARD):
        value = await done
    assert done.done() and not done.cancelled() and done.result() == value  # type: ignore[attr-defined]
    assert done.cancel() is False and done.result() == value  # type: ignore[attr-defined]
    # Given up by its caller (a timeout around the await): cancelled, as a future awaited by a cancelled task is.
    given_up = bus.submit(protocol.ReadParam(20, speed))
    with anyio.move_on_after(0):
        await given_up
    assert given_up.cancelled()  # type: ignore[attr-defined]


@every_case
async def test_stream_frames_targets_and_offline_ids(bus: Bus) -> None:
    async with bus.stream([*IDS, 20], offline_after=2) as stream:
        stream.set_targets_degrees({i: 10.0 * i - 30 for i in IDS})
        frame = await stream.next_frame()
        # ID 20 fails offline_after times, then is out of the cycle.  (After a failure it is held
        # back until its reply could no longer come: cycles in that time do not count.)
        with anyio.fail_after(GUARD):
            while 20 not in frame.offline:
                frame = await stream.next_frame()
        assert 20 in frame.offline
        # Every present servo answers in a cycle (on a loaded machine a reply now and then outlasts
        # the stream's short wait, and its servo sits out a cycle or two: not what is tested here).
        with anyio.fail_after(GUARD):
            frame = await stream.next_frame()
            while set(frame.positions) != set(IDS):
                frame = await stream.next_frame()
        assert 20 in frame.offline
        assert all(not math.isnan(d) for d in frame.degrees().values())
    with pytest.raises(BusClosed):
        await stream.next_frame()
    assert (await bus.servo(0).read_eeprom()).servo_id == 0  # the bus outlives its stream


@every_case
@every_reply
async def test_requests_share_the_line_with_a_stream(bus: Bus) -> None:
    runner = bus._driver.burst  # type: ignore[union-attr]
    async with bus.stream(IDS) as stream:
        await stream.next_frame()
        for i in IDS:
            assert await eeprom_id_beside_a_stream(bus, i) == i
        before = (await stream.next_frame()).cycle
        assert (await stream.next_frame()).cycle > before
        if runner is not None:  # the stream's transactions really ran in the compiled helper
            with anyio.fail_after(GUARD):
                while runner.transactions == 0:  # (counted as each burst ends)
                    await stream.next_frame()
            assert runner.bursts > 0


async def eeprom_id_beside_a_stream(bus: Bus, servo_id: int) -> int:
    """The ID in servo ``servo_id``'s EEPROM, read while a stream runs.

    A stream transaction gives its reply up after twice what this line's answers take, not its full allowance
    (see ics35_async.engine.probe): on a loaded machine that reply can still come, and it fails, typed, the
    request it lands in, never passing for that one's answer.  Only then is the read asked again."""
    try:
        return (await bus.servo(servo_id).read_eeprom()).servo_id
    except ReplyTimeout:
        raise
    except ReplyError:
        assert bus.stats.total.errors >= 2  # this read's failure, and the stream's that left its reply to come
        return (await bus.servo(servo_id).read_eeprom()).servo_id


@every_case
async def test_scan_and_close(bus: Bus) -> None:
    assert await bus.scan(range(12)) == list(IDS)
    await bus.aclose()
    await bus.aclose()  # idempotent
    with pytest.raises(BusClosed):
        await bus.servo(1).read_stretch()


@every_backend
async def test_a_group_streams_two_lines_together() -> None:
    group = BusGroup.open({"left": "sim://?ids=1-3", "right": "sim://?ids=4-6"}, driver="auto", **FAST)
    async with group, group.stream({"left": [1, 2, 3], "right": [4, 5, 6]}) as stream:
        for _ in range(3):
            frame = await stream.next_frame()
        assert set(frame.positions) == {("left", i) for i in (1, 2, 3)} | {("right", i) for i in (4, 5, 6)}
        assert all(n >= 3 for n in frame.line_cycles.values())


@every_case
async def test_protocol_commands_through_request(bus: Bus) -> None:
    assert await bus.request(protocol.ReadParam(6, protocol.Param.STRETCH)) == await bus.servo(6).read_stretch()
    assert await bus.request(protocol.WriteParam(6, protocol.Param.SPEED, 77)) == 77
    assert await bus.servo(6).read_speed() == 77


async def answered_by_all(stream: Stream, ids: list[int], within: float = GUARD / 2) -> bool:
    """Whether a frame in which every one of ``ids`` answered comes within ``within`` seconds (on a loaded
    machine a stream transaction may give up after its short wait, and its servo then sits out the
    frames until its late reply can no longer come: counting frames, a stall could outlast them all)."""
    with anyio.move_on_after(within):
        while set((await stream.next_frame()).positions) != set(ids):
            pass
        return True
    return False


@every_case
async def test_a_second_stream_is_refused_at_once_and_one_started_right_after_a_close_runs(bus: Bus) -> None:
    # On the burst path the first stream's transactions run in the executor while the program acts:
    # the refusal must still reach the caller (not be deferred to where the burst stops), and a close
    # followed at once by a new stream must hand the line over.
    first = bus.stream([1, 2, 3])
    async with first:
        await first.next_frame()
        with pytest.raises(InvalidArgument, match="already runs a stream"):
            await bus.stream([4, 5]).start()
        assert await answered_by_all(first, [1, 2, 3])  # the line carries on
    for ids in ([4, 5], [1, 6], [2, 3, 7]):
        async with bus.stream(ids) as stream:
            assert await answered_by_all(stream, ids)
