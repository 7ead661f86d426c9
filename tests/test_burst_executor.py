"""The compiled burst executor (ics35_async.drivers._burst) on a real pty, against a responder thread.

The executor only moves bytes and notes times; what it must get right is where it stops: at the
end of the plan, at a late transaction, at an echo that differs from what was sent, at more bytes
than expected, after a reply not of its planned shape, at a 0xFF while the port marks parity
errors, at a boundary once woken, on a hang-up.  The engine's side (what it plans and how it judges the bytes) is in
tests/test_burst_engine.py.
"""

from __future__ import annotations

import asyncio
import itertools
import os
import select
import sys
import termios
import threading
import time
import tty
from collections.abc import Callable, Iterator
from typing import Any

import anyio
import pytest
import serial

from benchmarks.lean_responder import lean_lines
from ics35_async import open_bus, protocol
from ics35_async.drivers import burst
from ics35_async.drivers.burst import DONE, HANGUP, LATE, MARK, MISMATCH, OVERRUN, SHAPE, WOKEN, burst_path
from ics35_async.transports.tty_port import ParityMarks, enable_parity_marks
from tests.support.timing import GUARD, NO_TIMEOUTS, scaled

_burst = pytest.importorskip("ics35_async.drivers._burst", reason="the executor is not built (no C compiler?)")
pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="needs a pty")

# Each transaction's allowance where every answer is expected: the no-timeouts one (a responder thread on a
# loaded machine once answered later than 50 ms, and the burst rightly stopped there as late).
ALLOWANCE = NO_TIMEOUTS["adapter_latency"]
Reply = Callable[[int, bytes], bytes | None]  # (index of the command, its bytes) -> what goes back


def answer(k: int, tx: bytes) -> bytes | None:
    """A well-behaved servo: the echo, then the position reply."""
    return tx + bytes((tx[0] & 0x7F, 7500 >> 7, 7500 & 0x7F))


class Responder:
    """The far end of a pty: reads 3-byte commands and answers each as ``reply`` says."""

    def __init__(self, master: int, reply: Reply) -> None:
        self.master = master
        self.reply = reply
        self.commands: list[bytes] = []
        self._stop = False
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        pending = b""
        while not self._stop:
            try:
                ready, _, _ = select.select([self.master], [], [], 0.05)
                if not ready:
                    continue
                pending += os.read(self.master, 4096)
            except (OSError, ValueError):  # closed: a hang-up the test made
                return
            while len(pending) >= 3:
                tx, pending = pending[:3], pending[3:]
                out = self.reply(len(self.commands), tx)
                self.commands.append(tx)
                if out:
                    os.write(self.master, out)

    def stop(self) -> None:
        self._stop = True
        self._thread.join()


class PtyPair:
    """A raw pty: ``master, slave = pair``; :meth:`hang_up` closes the master (once: a descriptor
    number closed twice may by then be another thread's)."""

    def __init__(self) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        attrs = termios.tcgetattr(self.slave)
        attrs[3] &= ~termios.ECHO
        termios.tcsetattr(self.slave, termios.TCSANOW, attrs)
        os.set_blocking(self.slave, False)
        self._open = [self.master, self.slave]

    def __iter__(self) -> Iterator[int]:
        return iter((self.master, self.slave))

    def hang_up(self) -> None:
        self._open.remove(self.master)
        os.close(self.master)

    def close(self) -> None:
        while self._open:
            os.close(self._open.pop())


@pytest.fixture
def pty_pair() -> Iterator[PtyPair]:
    pair = PtyPair()
    yield pair
    pair.close()


def plan(n: int = 32, allowance: float = ALLOWANCE) -> list[tuple[bytes, int, int, float, bytes]]:
    """Position commands to IDs 0-31 in turn, each with the shape of the reply :func:`answer` gives."""
    txs = [protocol.position_tx(i % 32, 7500) for i in range(n)]
    return [(tx, 6, 3, allowance, protocol.position_reply_shape(tx[0] & 0x7F)) for tx in txs]


def serve(master: int, reply: Reply = answer) -> Responder:
    return Responder(master, reply)


def test_the_path_reports_itself_built_and_on_unless_turned_off(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("ICS35_BURST", "1")
    assert burst_path() == (True, burst_path()[1]) and "compiled" in burst_path()[1]
    monkeypatch.delenv("ICS35_BURST")
    assert burst_path()[0] is True  # the default where it is built
    for off in ("0", "off", "No", "false", "2"):
        monkeypatch.setenv("ICS35_BURST", off)
        assert burst_path()[0] is False and "ICS35_BURST=" in burst_path()[1]
    # Elsewhere than Linux (the helper builds on macOS and the BSDs, untried there) only when asked.
    monkeypatch.setattr(sys, "platform", "darwin")
    monkeypatch.delenv("ICS35_BURST")
    assert burst_path() == (False, "off by default on darwin, where it has not been tried (ICS35_BURST=1 turns it on)")
    monkeypatch.setenv("ICS35_BURST", "1")
    assert burst_path()[0] is True
    monkeypatch.setenv("ICS35_BURST", "0")
    assert burst_path() == (False, "off (ICS35_BURST=0; ICS35_BURST=1 turns it on)")
    # Where the helper is not built (Windows: never), no setting turns it on, and none is offered.
    monkeypatch.setattr(burst, "_burst", None)
    for setting in (None, "1", "0"):
        if setting is None:
            monkeypatch.delenv("ICS35_BURST")
        else:
            monkeypatch.setenv("ICS35_BURST", setting)
        assert burst_path()[0] is False and burst_path()[1].startswith("off, not built ("), burst_path()


def test_a_whole_plan_runs_and_every_transaction_is_timed(pty_pair: PtyPair) -> None:
    master, slave = pty_pair
    responder = serve(master)
    burst = _burst.Burst(slave)
    t0 = time.monotonic()
    status, err, records = burst.run(t0 + ALLOWANCE, plan())
    responder.stop()
    assert (status, err) == (DONE, 0)
    assert [data for data, _, _ in records] == [answer(k, tx) for k, (tx, *_) in enumerate(plan())]
    times = [t for _, first, last in records for t in (first, last)]
    assert times == sorted(times) and t0 < times[0] and times[-1] <= time.monotonic()
    assert responder.commands == [tx for tx, *_ in plan()]  # one command at a time, each after its reply
    burst.close()


def test_it_stops_at_a_silent_servo_at_its_deadline(pty_pair: PtyPair) -> None:
    master, slave = pty_pair
    responder = serve(master, lambda k, tx: tx if k == 5 else answer(k, tx))  # ID 5 only echoes
    burst = _burst.Burst(slave)
    # ID 5's silence waits out the whole allowance (ALLOWANCE: every other answer is expected).
    status, _, records = burst.run(time.monotonic() + ALLOWANCE, plan())
    ended = time.monotonic()
    responder.stop()
    assert status == LATE and len(records) == 6
    data = records[5][0]
    assert data == plan()[5][0]  # its echo came; its reply did not
    assert ended - records[4][2] >= ALLOWANCE  # it waited the whole allowance from the previous reply
    assert len(responder.commands) == 6  # nothing was sent after it


def test_it_stops_at_an_echo_that_differs(pty_pair: PtyPair) -> None:
    master, slave = pty_pair
    responder = serve(master, lambda k, tx: b"\x00" + answer(k, tx)[1:] if k == 3 else answer(k, tx))
    status, _, records = _burst.Burst(slave).run(time.monotonic() + ALLOWANCE, plan())
    responder.stop()
    assert status == MISMATCH and len(records) == 4
    assert records[3][0].startswith(b"\x00")


def test_it_stops_at_more_bytes_than_expected(pty_pair: PtyPair) -> None:
    master, slave = pty_pair
    responder = serve(master, lambda k, tx: answer(k, tx) + b"\x01\x02" if k == 2 else answer(k, tx))
    status, _, records = _burst.Burst(slave).run(time.monotonic() + ALLOWANCE, plan())
    responder.stop()
    assert status == OVERRUN and len(records) == 3 and len(records[2][0]) == 8


def test_a_marked_byte_ends_the_burst_and_comes_as_it_came(pty_pair: PtyPair) -> None:
    master, slave = pty_pair
    assert enable_parity_marks(slave)  # a genuine 0xFF now arrives doubled: FF FF
    reply = answer(0, protocol.position_tx(1, 7500))[:5] + b"\xff"
    responder = serve(master, lambda k, tx: reply if k == 1 else answer(k, tx))
    status, _, records = _burst.Burst(slave, marks=True).run(time.monotonic() + ALLOWANCE, plan())
    responder.stop()
    assert status == MARK and len(records) == 2
    assert records[1][0].endswith(b"\xff\xff")
    assert ParityMarks().decode(records[1][0]) == (reply, 0)  # the usual decoder reads it as the wire had it


def test_a_wake_stops_it_at_the_next_boundary_and_other_threads_run_meanwhile() -> None:
    # The far end in its own process, answering at the wire time of 9600 bit/s (7 ms a
    # transaction): the burst lasts long enough to wake, and no thread of ours answers.
    with lean_lines(1, baud=9600, wire=True) as (path,):
        ser = serial.Serial(path, 9600, timeout=0)
        os.set_blocking(ser.fileno(), False)
        burst = _burst.Burst(ser.fileno())
        counted = [0]
        done = threading.Event()

        def count() -> None:  # pure Python: it runs only while the burst has let go of the GIL
            while not done.is_set():
                counted[0] += 1

        counter = threading.Thread(target=count)
        counter.start()
        burst.start(time.monotonic() + 0.5, plan(64, allowance=0.5))  # a loaded machine is no fault here
        time.sleep(0.05)
        progress = counted[0]
        burst.wake()
        status, _, records = burst.wait()
        done.set()
        counter.join()
        burst.close()
        ser.close()
    # Stopped at a boundary before the plan's end, every transaction whole.  (How many went before the wake
    # depends on how soon the far end's process got a core: under load, one.)
    assert status == WOKEN and 1 <= len(records) < 64
    assert all(data == answer(k, tx) for k, ((data, _, _), (tx, *_)) in enumerate(zip(records, plan(64), strict=False)))
    assert progress > 1000  # the counting thread ran while the burst did


def _sched(tid: str) -> tuple[int, int]:
    """A thread's time slice (ns; the scheduler's own figure) and nice value, from /proc."""
    with open(f"/proc/self/task/{tid}/sched") as f:
        line = next(ln for ln in f if ln.startswith("se.slice"))
    with open(f"/proc/self/task/{tid}/stat") as f:
        nice = int(f.read().rsplit(")", 1)[1].split()[16])
    return int(line.split(":")[1]), nice


def test_the_executors_thread_asks_for_the_shortest_time_slice_and_keeps_its_nice(pty_pair: PtyPair) -> None:
    # Woken by a reply while the program's Python has the core (its loop feeding the engine, a thread of its
    # own), the executor must get the core at once, not at the end of the other thread's slice: on Linux 6.12 and
    # later a thread that asks for a short slice gets an earlier deadline, so its wake-up preempts.  The request
    # must not change its nice value (the program's, inherited: as root, a reset to 0 would raise its priority).
    master, slave = pty_pair
    responder = serve(master)
    found: dict[str, tuple[int, int]] = {}

    def run() -> None:
        os.nice(3)  # this thread only (Linux): the executor's thread is made by it
        before = set(os.listdir("/proc/self/task"))
        burst = _burst.Burst(slave)
        burst.start(time.monotonic() + ALLOWANCE, plan(8))
        result = burst.wait()
        assert result[0] == DONE and len(result[2]) == 8
        found.update({tid: _sched(tid) for tid in set(os.listdir("/proc/self/task")) - before})
        burst.close()

    thread = threading.Thread(target=run)
    thread.start()
    thread.join()
    responder.stop()
    assert len(found) == 1, found  # the executor's thread
    (slice_ns, nice), base = found.popitem()[1], _sched(str(threading.get_native_id()))[0]
    assert nice == 3
    release = tuple(int(x) for x in os.uname().release.split(".")[:2] if x.isdigit())
    if release >= (6, 12):  # (custom slices came with Linux 6.12; older kernels ignore the request)
        assert slice_ns == 100_000 < base
    else:
        assert slice_ns == base


def test_done_fd_turns_readable_when_a_started_burst_ends(pty_pair: PtyPair) -> None:
    master, slave = pty_pair
    responder = serve(master)
    burst = _burst.Burst(slave)
    for _ in range(3):  # the executor's thread serves burst after burst
        burst.start(time.monotonic() + ALLOWANCE, plan(8))
        ready, _, _ = select.select([burst.done_fd], [], [], 2)
        assert ready
        result = burst.result()
        assert result is not None and result[0] == DONE and len(result[2]) == 8
    assert burst.result is not None
    with pytest.raises(RuntimeError):
        burst.result()  # nothing started
    responder.stop()
    burst.close()


def test_a_new_burst_never_hands_back_the_last_ones_records(pty_pair: PtyPair) -> None:
    # completed() right after start() gave the previous burst's records (its bytes, its old times) until the
    # executor's thread began the new plan: a driver woken for another reason then fed the engine those as the
    # new plan's replies (the thread driver did, on any wake-up).
    master, slave = pty_pair
    responder = serve(master)
    burst = _burst.Burst(slave)
    for _ in range(100):
        burst.start(time.monotonic() + ALLOWANCE, plan(4))
        early = burst.completed(0)
        result = burst.wait()
        assert result is not None and result[0] == DONE and len(result[2]) == 4
        assert all(record in result[2] for record in early), (early, result[2])  # only this burst's records
    responder.stop()
    burst.close()


def test_a_notice_mid_burst_hands_over_what_is_final_while_the_rest_runs(pty_pair: PtyPair) -> None:
    # The loop feeds the engine a long burst in parts (see burst.feed_ahead_points): done_fd turns readable
    # once the asked-for transaction is written, the burst still runs, and completed() gives every
    # transaction before the last one written; the end's result gives the rest from where the loop is.
    master, slave = pty_pair
    gate = threading.Event()

    def held_at_10(k: int, tx: bytes) -> bytes | None:
        if k == 10:
            gate.wait(5)  # the burst is still running while the test looks
        return answer(k, tx)

    responder = serve(master, held_at_10)
    executor = _burst.Burst(slave)
    whole = plan(16)
    executor.start(time.monotonic() + ALLOWANCE, whole)
    executor.notify(6)
    ready, _, _ = select.select([executor.done_fd], [], [], 2)
    assert ready  # the notice: transaction 6 is on the wire
    deadline = time.monotonic() + 2
    while len(executor.completed(0)) < 10 and time.monotonic() < deadline:
        time.sleep(0.001)  # it runs on to the held transaction 10
    assert executor.result() is None  # (and the notice is taken: done_fd is quiet again)
    assert not select.select([executor.done_fd], [], [], 0)[0]
    early = executor.completed(0)
    assert len(early) == 10  # 10 is written and unanswered: not final, nor anything after it
    assert executor.completed(4) == early[4:]
    gate.set()
    assert select.select([executor.done_fd], [], [], 2)[0]
    result = executor.result(len(early))
    responder.stop()
    executor.close()
    assert result is not None
    status, _, rest = result
    assert status == DONE and len(rest) == 6
    records = early + rest
    assert [data for data, _, _ in records] == [answer(k, tx) for k, (tx, *_) in enumerate(whole)]
    assert all(first <= last for _, first, last in records)
    assert all(a[2] <= b[1] for a, b in itertools.pairwise(records))  # in the order they came


def test_a_notice_and_the_end_leave_done_fd_quiet_once_the_result_is_taken(pty_pair: PtyPair) -> None:
    # A notice that comes just before the burst's end, and the end's own signal: once result() hands
    # the result over, done_fd must be quiet (an event loop would otherwise call back for nothing, on
    # and on, until the next burst starts).  Also a notice asked for past the plan, which never comes.
    master, slave = pty_pair
    responder = serve(master)
    executor = _burst.Burst(slave)
    for notice in (1, 3, 7, 20):
        executor.start(time.monotonic() + ALLOWANCE, plan(8))
        executor.notify(notice)
        deadline = time.monotonic() + 2
        result = None
        while result is None and time.monotonic() < deadline:
            select.select([executor.done_fd], [], [], 0.5)
            time.sleep(0.01)  # (the burst has ended by now: both signals are written)
            result = executor.result()
        assert result is not None and result[0] == DONE and len(result[2]) == 8
        assert not select.select([executor.done_fd], [], [], 0)[0], notice
    for start in (0, 5):  # wait() from where the loop has fed
        executor.start(time.monotonic() + ALLOWANCE, plan(8))
        status, _, rest = executor.wait(start)
        assert status == DONE and len(rest) == 8 - start
        assert not select.select([executor.done_fd], [], [], 0)[0]
    responder.stop()
    executor.close()


def test_a_hang_up_ends_the_burst(pty_pair: PtyPair) -> None:
    master, slave = pty_pair

    def hang_up(k: int, tx: bytes) -> bytes | None:
        if k == 2:
            pty_pair.hang_up()
            return None
        return answer(k, tx)

    responder = serve(master, hang_up)
    status, _, records = _burst.Burst(slave).run(time.monotonic() + 1.0, plan())
    responder.stop()
    assert status == HANGUP and len(records) == 3


def test_it_stops_after_a_reply_out_of_its_shape_and_sends_nothing_more(pty_pair: PtyPair) -> None:
    # Write 4's reply has a data byte's top bit set: the echo and the length are right, the shape is not.
    def garble(k: int, tx: bytes) -> bytes | None:
        good = answer(k, tx)
        assert good is not None
        return good[:4] + bytes((good[4] | 0x80,)) + good[5:] if k == 4 else good

    master, slave = pty_pair
    responder = serve(master, garble)
    status, _, records = _burst.Burst(slave).run(time.monotonic() + ALLOWANCE, plan())
    time.sleep(0.05)  # (a command sent after it would have reached the responder by now)
    responder.stop()
    assert status == SHAPE and len(records) == 5
    assert records[4][0] == garble(4, plan()[4][0])  # handed back whole, for the engine to judge
    assert len(responder.commands) == 5  # nothing was sent after it
    # Without a shape the executor judges no reply: the same line runs the whole plan.
    responder = serve(master, garble)
    unshaped = [(*entry[:4], b"") for entry in plan()]
    status, _, records = _burst.Burst(slave).run(time.monotonic() + ALLOWANCE, unshaped)
    responder.stop()
    assert status == DONE and len(records) == 32


def test_bad_plans_are_refused_before_anything_is_written(pty_pair: PtyPair) -> None:
    _, slave = pty_pair
    burst = _burst.Burst(slave)
    tx = b"\x80\x00\x00"
    for bad in (
        [],
        [(b"", 6, 3, 0.1, b"")],  # no command
        [(tx, 6, 7, 0.1, b"")],  # more echo than expected
        [("text", 6, 3, 0.1, b"")],
        [(tx, 1)],
        [(tx, 6, 3, 0.1)],  # no shape (b"" says none)
        [(tx, 6, 3, 0.1, b"\x00\xff")],  # a shape not twice the reply's length
    ):
        with pytest.raises((ValueError, TypeError)):
            burst.run(time.monotonic() + 1, bad)
    with pytest.raises(ValueError):
        _burst.Burst(-1)
    burst.close()
    with pytest.raises(ValueError):
        burst.run(time.monotonic() + 1, plan(1))


@pytest.mark.anyio
@pytest.mark.pty
async def test_on_a_bus_no_burst_starts_while_the_program_sends_requests(monkeypatch: pytest.MonkeyPatch) -> None:
    # The library's default: a request that arrived mid-burst would wait for the burst's bytes to be
    # fed to the engine, so while requests come the stream takes the ordinary path.
    monkeypatch.setenv("ICS35_BURST", "1")
    pause = scaled(1.0)  # longer than any read here takes, even on a loaded machine
    monkeypatch.setattr(burst, "PAUSE_AFTER_REQUEST", pause)
    with lean_lines(1) as (path,):
        async with open_bus(path, **NO_TIMEOUTS) as bus, bus.stream(range(8)) as stream:
            runner = bus._driver.burst  # type: ignore[attr-defined]
            with anyio.fail_after(GUARD):
                while runner.bursts < 5:
                    await stream.next_frame()
            for _ in range(40):  # a poller, flat out for a while
                await bus.servo(3).read_current()
            during = runner.bursts
            cycle = (await stream.next_frame()).cycle
            for _ in range(40):
                await bus.servo(3).read_current()
            assert runner.bursts == during  # none started while the reads came
            assert (await stream.next_frame()).cycle > cycle  # the stream ran on meanwhile
            await anyio.sleep(pause)
            with anyio.fail_after(GUARD):
                while runner.bursts == during:  # bursts again once the requests have stopped
                    await stream.next_frame()


@pytest.mark.anyio
@pytest.mark.pty
async def test_the_pause_after_requests_outlives_a_reopened_port(monkeypatch: pytest.MonkeyPatch) -> None:
    # The port's burst runner is new after a reopen (or a reconnect); the program's requests are not.
    monkeypatch.setenv("ICS35_BURST", "1")
    monkeypatch.setattr(burst, "PAUSE_AFTER_REQUEST", 60.0)  # far longer than the test runs
    with lean_lines(1) as (path,):
        async with open_bus(path, **NO_TIMEOUTS) as bus:
            assert bus.describe()["burst_path"] is True  # (what doctor reports of a line it measured)
            await bus.servo(3).read_current()
            await bus.reopen()
            async with bus.stream(range(8)) as stream:
                for _ in range(20):
                    await stream.next_frame()
                runner = bus._driver.burst  # type: ignore[attr-defined]
                assert runner is not None and runner.bursts == 0


@pytest.mark.anyio
@pytest.mark.pty
async def test_back_to_back_bursts_keep_the_port_from_the_loops_reader(monkeypatch: pytest.MonkeyPatch) -> None:
    # A burst that ends with the next one starting at once leaves the port with the executor: handing it to
    # the loop's reader and taking it back costs two epoll_ctl calls and the selector's bookkeeping a burst.
    monkeypatch.setenv("ICS35_BURST", "1")
    with lean_lines(1) as (path,):
        async with open_bus(path, **NO_TIMEOUTS) as bus, bus.stream(range(32)) as stream:
            runner = bus._driver.burst  # type: ignore[attr-defined]
            assert runner is not None
            with anyio.fail_after(GUARD):
                while runner.bursts < 3:
                    await stream.next_frame()
            loop = asyncio.get_running_loop()
            fd = bus._driver.port.fd  # type: ignore[attr-defined]
            handed: list[int] = []
            add_reader = loop.add_reader

            def counting_add_reader(reader_fd: Any, *args: Any) -> None:
                if reader_fd == fd:
                    handed.append(runner.bursts)
                add_reader(reader_fd, *args)

            monkeypatch.setattr(loop, "add_reader", counting_add_reader)
            stops: list[int] = []  # why each burst stopped
            finish = runner.finish

            def noting_finish(*args: Any, **kwargs: Any) -> Any:
                done = finish(*args, **kwargs)
                if done[0]:
                    stops.append(runner.status)
                return done

            monkeypatch.setattr(runner, "finish", noting_finish)
            first = runner.bursts
            with anyio.fail_after(GUARD):
                while runner.bursts < first + 20:
                    await stream.next_frame()
            # A burst that stopped early (a late reply on a loaded machine, say) hands the port back: its next
            # transaction is read the ordinary way.  One that ran its plan to the end does not.
            early = sum(status != DONE for status in stops)
            assert len(handed) <= early, f"the port went back to the loop's reader {len(handed)} times; {stops=}"


@pytest.mark.anyio
@pytest.mark.pty
async def test_a_burst_stopped_for_a_close_hands_the_port_back_with_a_stream_still_on_the_line(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # What a reopen or close does to a running burst (stop it, close the executor), here with the stream
    # still on the line: the next transaction must go the ordinary way, not to the executor just closed
    # (which raised, and left the port with no reader, no timer and the engine waiting for a reply).
    monkeypatch.setenv("ICS35_BURST", "1")
    with lean_lines(1) as (path,):
        async with open_bus(path, **NO_TIMEOUTS) as bus, bus.stream(range(8)) as stream:
            driver = bus._driver  # type: ignore[attr-defined]
            with anyio.fail_after(GUARD):
                while not (driver.burst is not None and driver.burst.running):
                    await stream.next_frame()
            driver._stop_burst()
            assert driver.burst is None and driver._reading
            cycle = (await stream.next_frame()).cycle
            with anyio.fail_after(GUARD):
                while (await stream.next_frame()).cycle < cycle + 3:  # the stream goes on, the ordinary way
                    pass
