"""The thread driver's own duties: waking its I/O thread, and never leaving a caller waiting on a dead thread.

The shared scenarios (requests, streams, scans, sharing, cancellation) run on
it in tests/test_contract.py; losing and reopening the port in test_bus.py and
test_stream.py.
"""

from __future__ import annotations

import asyncio
import contextlib
import random
from collections import Counter
from typing import Any

import pytest

from ics35_async import PortLost, ReplyError, ReplyTimeout, open_bus, protocol
from ics35_async.drivers import burst
from ics35_async.drivers.burst import ENV, burst_path
from ics35_async.sim import VirtualLine, VirtualServo
from tests.support.timing import FAST, NO_TIMEOUTS, PATIENT, or_describe, scaled

# A few seconds' work against a fast simulator: a run this long means a reply or a frame stopped coming
# (then the failure says what the line was doing, rather than pytest's timeout giving only the stacks).
RUN_GUARD = scaled(60.0)
pytestmark = pytest.mark.timeout(RUN_GUARD + scaled(120.0))  # (the guard first: see test_anyio_bursts.py)


async def test_a_request_to_a_silent_servo_times_out_while_the_line_idles() -> None:
    # The I/O thread sleeps without a deadline on an idle line: the request must wake it, or the
    # timeout would never be judged.
    with VirtualLine([VirtualServo(1)]) as sim:
        async with open_bus(sim, driver="thread", **FAST) as bus:
            assert bus.driver == "thread"
            for _ in range(3):
                with pytest.raises(ReplyTimeout):
                    await asyncio.wait_for(bus.servo(9).read_stretch(), 5)
                assert await asyncio.wait_for(bus.servo(1).read_stretch(), 5) == sim.servo(1).stretch


class BrokenDevice:
    """A device whose write fails with an error no port raises: a bug below the engine."""

    def __init__(self) -> None:
        self.host = None

    def connect(self, host: object, baudrate: int) -> None:
        self.host = host

    def write(self, data: bytes) -> None:
        raise ValueError("not an OSError")

    def disconnect(self) -> None:
        self.host = None


async def test_a_failure_in_the_io_thread_fails_its_callers_instead_of_leaving_them_waiting() -> None:
    bus = await open_bus(BrokenDevice(), driver="thread", reconnect=True, **FAST)
    try:
        with pytest.raises(PortLost):
            await asyncio.wait_for(bus.request(protocol.ReadParam(1, protocol.Param.STRETCH)), 5)
        with pytest.raises(PortLost):
            await asyncio.wait_for(bus.request(protocol.ReadParam(1, protocol.Param.STRETCH)), 5)
    finally:
        await asyncio.wait_for(bus.aclose(), 5)


async def test_a_caller_that_hears_its_answer_sees_it_counted(pty_sim: Any) -> None:
    # The I/O thread hands the answer to the loop while it still holds the engine: whoever
    # awaits it may look at the statistics at once, and must find the transaction counted ok.
    path = pty_sim("--fast", "--ids", "1-2").path
    async with open_bus(path, driver="thread", **NO_TIMEOUTS) as bus:
        behind = []

        async def reads() -> None:
            for n in range(1, 2001):
                await bus.servo(1 + n % 2).read_stretch()
                ok = bus.stats.total.ok
                if ok < n:
                    behind.append((n, ok))

        await or_describe(reads(), bus, RUN_GUARD)
        assert behind == []


@pytest.mark.pty
async def test_a_stream_frame_comes_with_its_transactions_counted(pty_sim: Any) -> None:
    path = pty_sim("--fast", "--ids", "1-2").path
    async with open_bus(path, driver="thread", **NO_TIMEOUTS) as bus, bus.stream([1, 2]) as stream:
        behind = []

        async def frames() -> None:
            for _ in range(1000):
                frame = await stream.next_frame()
                stats = bus.stats
                total = stats.total
                ended = total.ok + total.timeouts + total.partial_replies + total.echo_mismatches + total.bad_replies
                # (A transaction held back after a failure is skipped, not sent: counted in held_back.)
                if ended + stats.held_back < 2 * frame.cycle:
                    behind.append((frame.cycle, ended))

        await or_describe(frames(), bus, RUN_GUARD)
        assert behind == []


@pytest.mark.pty
@pytest.mark.slow
async def test_a_stream_reply_it_rejects_is_never_counted_ok(pty_sim: Any) -> None:
    # Every reply of servo 2 has a byte with its MSB set: the stream rejects it.  The engine counts
    # a stream reply before the frame it ends is published; a rejected one must not show as ok even
    # for the instant before it is taken back.  (Never taken offline: asked every cycle.)
    path = pty_sim("--fast", "--ids", "1-2", "--faults", "msb@2:1.0").path
    bus = await open_bus(path, driver="thread", **PATIENT)
    async with bus, bus.stream([1, 2], offline_after=10**6) as stream:
        seen = []

        async def frames() -> None:
            for _ in range(1000):
                frame = await stream.next_frame()
                two = bus.stats.per_id.get(2)
                if two is not None and two.ok:
                    seen.append((frame.cycle, two.ok))

        await or_describe(frames(), bus, RUN_GUARD)
        assert seen == []
        assert bus.stats.per_id[2].bad_replies > 0


@pytest.mark.pty
async def test_a_stream_on_a_tty_runs_in_bursts_beside_requests_that_get_their_own_replies(
    pty_sim: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The compiled path under the I/O thread: the stream's transactions run in the executor while the
    # program's requests arrive mid-burst (no pause after requests here); each gets its own servo's reply and
    # the stream's frames carry every ID.  (On a loaded machine a stream transaction may give up after its
    # short learnt wait and its late reply fail the next transaction: a failure, never a value for another.)
    monkeypatch.setenv(ENV, "1")
    monkeypatch.setattr(burst, "PAUSE_AFTER_REQUEST", 0.0)
    assert burst_path()[0], burst_path()[1]
    ids = list(range(1, 9))
    path = pty_sim("--fast", "--ids", "1-8").path
    async with open_bus(path, driver="thread", **PATIENT) as bus:
        assert bus.describe()["burst_path"] is True
        runner = bus._driver.burst  # type: ignore[attr-defined]
        async with bus.stream(ids) as stream:
            targets = {i: 7000 + 100 * i for i in ids}
            stream.set_targets(targets)
            seen: Counter[int] = Counter()  # frames carrying each ID's position
            wrong: list[tuple[int, int]] = []  # (ID, position) in a frame that is not that servo's
            answered: list[int] = []
            beside: list[int] = []  # the bursts run by the time the reads are over

            arrived: set[int] = set()

            async def frames() -> None:
                # (200 frames, and on until the executor has run 400 transactions: a loaded machine runs more of
                # them on the ordinary path while the reads last)
                n = 0
                while n < 200 or runner.transactions <= 400:
                    n += 1
                    frame = await stream.next_frame()
                    seen.update(frame.positions)
                    for sid, position in frame.positions.items():
                        # A servo that reached its target stays there: any other value after is another's.
                        if position == targets[sid]:
                            arrived.add(sid)
                        elif sid in arrived:
                            wrong.append((sid, position))

            async def reads() -> None:
                for n in range(200):
                    sid = 1 + n % 8
                    with contextlib.suppress(ReplyError):
                        assert (await bus.servo(sid).read_eeprom()).servo_id == sid
                        answered.append(sid)
                    await asyncio.sleep(0.001)  # (as a poller's: the stream starts bursts in the pauses)
                beside.append(runner.bursts)

            await or_describe(asyncio.gather(frames(), reads()), bus, RUN_GUARD)
            assert beside[0] > 10 and runner.transactions > 400, (beside, runner.bursts, runner.transactions)
            assert arrived == set(ids) and not wrong, (arrived, wrong)
            # Every ID's replies reach the frames (a loaded machine fails some, as the comment above says).
            assert min(seen[sid] for sid in ids) > 50 and len(answered) > 100, (seen, len(answered), bus.stats.total)


@pytest.mark.pty
async def test_streams_started_and_closed_beside_requests_feed_the_engine_only_their_own_bursts(
    pty_sim: Any, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    # The I/O thread, woken for another reason (a caller's new target or request) just as it started a burst,
    # fed the engine what the executor had not yet begun: the previous burst's records, taken for this one's
    # replies (echo mismatches on healthy servos, "burst ran on past a reply", or old replies taken as new).
    monkeypatch.setenv(ENV, "1")
    monkeypatch.setattr(burst, "PAUSE_AFTER_REQUEST", 0.0)
    ids = list(range(1, 9))
    path = pty_sim("--fast", "--ids", "1-8").path
    rng = random.Random(1)
    wrong: list[tuple[int, int]] = []
    with caplog.at_level("WARNING", logger="ics35_async"):
        async with open_bus(path, driver="thread", **PATIENT) as bus:
            stop = False

            async def reads() -> None:
                k = 0
                while not stop:
                    sid = ids[k % 8]
                    k += 1
                    with contextlib.suppress(ReplyError, asyncio.TimeoutError):
                        got = await asyncio.wait_for(bus.servo(sid).read_eeprom(), rng.choice([0.0005, 0.002, 1.0]))
                        if got.servo_id != sid:
                            wrong.append((sid, got.servo_id))

            async def streams() -> None:
                for i in range(60):
                    stream = bus.stream(ids, rate_hz=rng.choice([None, 200.0]), on_close=rng.choice(["free", "hold"]))
                    await stream.start()
                    stream.set_targets({sid: 7000 + 10 * i for sid in ids})
                    for _ in range(rng.randint(1, 6)):
                        await stream.next_frame()
                    if rng.random() < 0.3:  # a close cancelled as it sends its close-out
                        closing = asyncio.ensure_future(stream.aclose())
                        await asyncio.sleep(rng.random() * 0.002)
                        closing.cancel()
                        with contextlib.suppress(asyncio.CancelledError):
                            await closing
                    else:
                        await stream.aclose()
                    if i % 10 == 9:
                        await bus.reopen()

            readers = [asyncio.ensure_future(reads()) for _ in range(2)]
            try:
                await or_describe(streams(), bus, RUN_GUARD)
            finally:
                stop = True
                await asyncio.gather(*readers)
            assert bus.is_open
    assert wrong == []
    said = [r.getMessage() for r in caplog.records if "burst" in r.getMessage() or "I/O thread" in r.getMessage()]
    assert said == []
