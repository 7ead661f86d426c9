"""The anyio driver on a tty, under trio and anyio-on-asyncio: the compiled stream path (see
ics35_async.drivers.burst), and a write the tty could not take at once.

Its bus task waits on the burst's notices instead of the port while a burst runs; these scenarios put
the program's requests, new streams, reopens, closes and a port that vanishes in the middle of bursts.
The shared scenarios run on it in tests/test_contract.py.
"""

from __future__ import annotations

import contextlib
import os
import random
from typing import Any

import anyio
import pytest

from ics35_async import BusClosed, PortLost, ReplyError, State, open_bus
from ics35_async.drivers import burst
from ics35_async.drivers.burst import ENV, burst_path
from tests.support.terminal import write_until_refused
from tests.support.timing import FAST, GUARD, NO_TIMEOUTS, PATIENT, scaled

RUN_GUARD = scaled(120.0)  # a run this long means a reply or a frame stopped coming (4-9 s, 60+ once under stress)
# The test's own guard goes first, then the bus closes: pytest-timeout's alarm, landing in one of the loop's callbacks,
# once dropped the bus task's wake-up there (the guard and the alarm both at 120 s under load), and the task then
# outlived the test, keeping the worker's loop from closing for ever.
pytestmark = pytest.mark.timeout(RUN_GUARD + scaled(120.0))
on_trio_and_asyncio = pytest.mark.parametrize("anyio_backend", ["trio", "asyncio"], indirect=True)


@pytest.fixture(autouse=True)
def bursts_beside_requests(monkeypatch: pytest.MonkeyPatch) -> None:
    """The burst path on, and not paused after requests: the program's requests arrive mid-burst."""
    monkeypatch.setenv(ENV, "1")
    monkeypatch.setattr(burst, "PAUSE_AFTER_REQUEST", 0.0)
    assert burst_path()[0], burst_path()[1]


@on_trio_and_asyncio
async def test_a_stream_runs_in_bursts_beside_requests_that_get_their_own_replies(pty_sim: Any) -> None:
    ids = list(range(1, 9))
    path = pty_sim("--fast", "--ids", "1-8").path
    # The reads come with a pause between them, as a poller's do: the stream starts bursts in the pauses, and
    # each read arrives in one (asked again at once, a read takes the next turn the engine gives its caller,
    # and no burst starts while they last).
    async with open_bus(path, driver="anyio", **PATIENT) as bus:
        assert bus.describe()["burst_path"] is True
        runner = bus._driver.burst  # type: ignore[attr-defined]
        async with bus.stream(ids) as stream:
            targets = {i: 7000 + 100 * i for i in ids}
            stream.set_targets(targets)
            whole: list[bool] = []
            answered: list[int] = []
            beside: list[int] = []  # the bursts run by the time the reads are over

            async def frames() -> None:
                for _ in range(200):
                    frame = await stream.next_frame()
                    # (The fast simulator is where it is told at once.  A servo whose transaction failed on a
                    # loaded machine sits out the cycles until its late reply could no longer come.)
                    whole.append(all(targets[i] == p for i, p in frame.positions.items()))

            async def reads() -> None:
                for n in range(200):
                    sid = 1 + n % 8
                    with contextlib.suppress(ReplyError):
                        assert (await bus.servo(sid).read_eeprom()).servo_id == sid
                        answered.append(sid)
                    await anyio.sleep(0.001)
                beside.append(runner.bursts)

            with anyio.fail_after(RUN_GUARD):
                async with anyio.create_task_group() as group:
                    group.start_soon(frames)
                    group.start_soon(reads)
            # (A read arriving mid-burst stops it at its next boundary: bursts beside reads are short.)  One burst
            # starts in each pause between reads while the line is in step.  After a transaction that failed (on a
            # loaded machine, a reply later than its wait) the ordinary path runs until its late reply could no
            # longer come, half a second here, and a late reply that came teaches the link an allowance that bursts
            # wait out as well: the reads take about that long, so one early fault can leave no burst beside them.
            failed = bus.stats.total.transactions - bus.stats.total.ok
            said = (beside, runner.bursts, runner.transactions, bus.stats.total, bus.describe()["link_extra_s"])
            assert beside[0] > 10 or failed, said
            assert runner.transactions >= runner.bursts, said
            # From the first frame with every servo at its target on, every frame is so (a reply misattributed
            # would show another position); on a loaded machine a transaction failed in the first cycles put that
            # first frame past the fifth once (a servo sits out until its late reply could no longer come).
            first = whole.index(True) if True in whole else len(whole)
            assert first < 50 and all(whole[first:]), (first, whole, bus.stats.total)
            assert len(answered) > 100, (len(answered), bus.stats.total)


@on_trio_and_asyncio
async def test_streams_started_closed_and_cancelled_beside_requests_and_reopens_keep_every_reply_its_own(
    pty_sim: Any, caplog: pytest.LogCaptureFixture
) -> None:
    ids = list(range(1, 9))
    path = pty_sim("--fast", "--ids", "1-8").path
    rng = random.Random(1)
    wrong: list[tuple[int, int]] = []
    ran = 0
    with caplog.at_level("WARNING", logger="ics35_async"):
        async with open_bus(path, driver="anyio", **PATIENT) as bus:
            stop = False

            async def reads() -> None:
                k = 0
                while not stop:
                    sid = ids[k % 8]
                    k += 1
                    with anyio.move_on_after(rng.choice([0.0005, 0.002, 1.0])), contextlib.suppress(ReplyError):
                        got = await bus.servo(sid).read_eeprom()
                        if got.servo_id != sid:
                            wrong.append((sid, got.servo_id))
                    await anyio.lowlevel.checkpoint()

            async def streams() -> None:
                nonlocal ran, stop
                try:
                    # (30 streams, 3 reopens: an unpaced stream beside two readers always queued is owed only one
                    # transaction in max_requests_between + 1 (17), so its frames come at the readers' pace: on
                    # asyncio on a loaded machine 0.23 s a frame, and 60 streams ran past the guard)
                    for i in range(30):
                        rate, on_close = rng.choice([None, 200.0]), rng.choice(["free", "hold"])
                        stream = bus.stream(ids, rate_hz=rate, on_close=on_close)
                        await stream.start()
                        stream.set_targets({sid: 7000 + 10 * i for sid in ids})
                        for _ in range(rng.randint(1, 6)):
                            await stream.next_frame()
                        runner = bus._driver.burst  # type: ignore[attr-defined]
                        ran += runner.bursts if runner is not None else 0
                        if rng.random() < 0.3:  # a close cancelled as it sends its close-out
                            with anyio.move_on_after(rng.random() * 0.002):
                                await stream.aclose()
                        await stream.aclose()
                        if i % 10 == 9:
                            await bus.reopen()
                finally:
                    stop = True

            try:
                with anyio.fail_after(RUN_GUARD):
                    async with anyio.create_task_group() as group:
                        group.start_soon(streams)
                        group.start_soon(reads)
                        group.start_soon(reads)
            except TimeoutError:  # (slow, or stuck: what the line was doing says which)
                raise AssertionError(f"not done in {RUN_GUARD:.0f} s: {bus.describe()}") from None
            assert bus.is_open
    assert wrong == []
    assert ran > 0
    said = [r.getMessage() for r in caplog.records if "burst" in r.getMessage() or "task" in r.getMessage()]
    assert said == []


@on_trio_and_asyncio
async def test_closing_the_bus_mid_burst_feeds_the_engine_and_releases_the_port(pty_sim: Any) -> None:
    # A close (or the program's cancellation around it) while the stream's bursts run: the burst stops at
    # its next boundary, the stream's close-out goes the ordinary way, the port is free for the next open.
    path = pty_sim("--fast", "--ids", "1-8").path
    for on_close in ("hold", "free"):
        with anyio.CancelScope() as program:
            async with (
                open_bus(path, driver="anyio", **NO_TIMEOUTS) as bus,
                bus.stream(range(1, 9), on_close=on_close) as stream,
            ):
                stream.set_targets(dict.fromkeys(range(1, 9), 8000))
                runner = bus._driver.burst  # type: ignore[attr-defined]
                with anyio.fail_after(GUARD):
                    while runner.transactions == 0:
                        await stream.next_frame()
                program.cancel()  # the program cancelled mid-stream (Ctrl-C, a timeout)
                while True:
                    await stream.next_frame()
        assert runner.bursts > 0 and not runner.running
        assert bus.state is State.CLOSED
        with anyio.fail_after(GUARD):
            async with open_bus(path, driver="anyio", **NO_TIMEOUTS) as again:
                for sid in range(1, 9):
                    assert (await again.servo(sid).read_eeprom()).servo_id == sid
                assert again.stats.total.errors == 0


@on_trio_and_asyncio
async def test_a_port_lost_mid_burst_is_reconnected_and_the_stream_bursts_again(pty_sim: Any) -> None:
    # The simulator's device goes away while the stream's bursts run (the executor sees the hang-up or an
    # error), and comes back at the same path: the bus reconnects and the stream goes on in bursts.
    path = pty_sim("--fast", "--ids", "1-4", "--unplug-after", "0.5", "--replug-after", "0.3").path
    async with open_bus(path, driver="anyio", reconnect=True, **PATIENT) as bus, bus.stream(range(1, 5)) as stream:
        first = bus._driver.burst  # type: ignore[attr-defined]
        assert first is not None
        with anyio.fail_after(GUARD):
            while not (await stream.next_frame()).resumed:
                pass
            assert bus.stats.reconnects == 1
            assert first.bursts > 0 and not first.running
            again = bus._driver.burst  # type: ignore[attr-defined]
            assert again is not None and again is not first
            while again.transactions == 0:
                await stream.next_frame()
            # Every servo read again (a frame may miss one whose reply failed on a loaded machine: the next reads it).
            while set((await stream.next_frame()).positions) != {1, 2, 3, 4}:
                pass


@on_trio_and_asyncio
async def test_a_port_lost_mid_burst_without_reconnect_ends_the_stream_with_port_lost(pty_sim: Any) -> None:
    sim = pty_sim("--fast", "--ids", "1-4")
    async with open_bus(sim.path, driver="anyio", **PATIENT) as bus, bus.stream(range(1, 5)) as stream:
        runner = bus._driver.burst  # type: ignore[attr-defined]
        with anyio.fail_after(GUARD):
            while runner.transactions == 0:
                await stream.next_frame()
            sim.stop()  # the adapter pulled mid-stream
            with pytest.raises((PortLost, BusClosed)):
                while True:
                    await stream.next_frame()
        assert bus._driver.burst is None  # type: ignore[attr-defined]
        assert not runner.running


@on_trio_and_asyncio
async def test_a_port_lost_while_a_partial_write_waits_is_lost_and_reconnected_not_a_failed_bus_task() -> None:
    # The bus task finishes a write the tty could not take at once when the port turns writable: a port gone
    # meanwhile (the adapter pulled) raised out of the task, which took it for a bug of its own: the bus closed
    # for good despite reconnect=True, and aclose() raised the OSError (the asyncio driver loses the port).
    master, slave = os.openpty()
    path = os.ttyname(slave)
    os.close(slave)  # (the bus opens it by name)
    os.set_blocking(master, False)
    try:
        bus = await open_bus(path, driver="anyio", reconnect=True, reconnect_backoff=(0.05,), **FAST)
        port = bus._driver.port  # type: ignore[attr-defined]
        # Nobody reads the far end: fill the pty until it takes not one byte more.
        quiet_checks = 0
        while quiet_checks < 3:
            quiet_checks = quiet_checks + 1 if not write_until_refused(port.fd) else 0
            await anyio.sleep(0.02)
        with pytest.raises(ReplyError):
            await bus.servo(1).read_stretch()  # its command waits in the port's pending bytes
        assert port.pending
        os.close(master)  # the device goes away
        master = -1
        with anyio.fail_after(GUARD):
            while bus.state not in (State.LOST, State.CLOSED):
                await bus.state_change()
        assert bus.state is State.LOST and bus.is_open  # reconnecting
    finally:
        if master >= 0:
            os.close(master)
    await bus.aclose()  # (no error of the bus task to raise)
