"""The unplug soak: the pty simulator's device disappears mid-stream and comes back at the same path.

With and without ``reconnect=True``.  Measures the time from the device's
return to the first new frame; counts tasks, file descriptors and threads
before and after.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import os
import random
import statistics
import subprocess
import time
from collections import Counter
from collections.abc import Awaitable, Sequence
from dataclasses import dataclass
from typing import Any

from benchmarks.bench_common import burst_setting
from ics35_async import (
    Bus,
    IcsError,
    PortLost,
    Priority,
    RequestHandle,
    open_bus,
    protocol,
)
from ics35_async.protocol import Param
from ics35_async.sim import (
    start_subprocess,
    stop_subprocess,
)
from tests.support.leaks import non_executor_threads, open_fds, other_tasks

from .common import Row, executor_row, ms
from .watchdog import under_watchdog, watched


def start_pty_server(args: Sequence[str], timeout: float = 15.0) -> tuple[subprocess.Popen[str], str]:
    """``python -m ics35_async.sim ARGS`` quietly (its notes go to /dev/null); returns it and its device path."""
    return start_subprocess(args, timeout=timeout, quiet=True)


@dataclass
class UnplugCycle:
    down_s: float  # how long the device path was gone
    resume_s: float  # device path back -> first frame with every ID answering


@dataclass
class UnplugReport:
    reconnect_cycles: list[UnplugCycle]
    resume_s_median: float
    resume_s_max: float
    reconnects_counted: int
    requests: int
    requests_ok: int
    failed_port_lost: int
    failed_other_typed: dict[str, int]
    untyped_outcomes: int
    requests_hung: int
    values_wrong: int
    no_reconnect_stream_end: str
    no_reconnect_request_error: str
    no_reconnect_pending_errors: dict[str, int]
    tasks_before: int
    tasks_after: int
    fds_before: int
    fds_after: int
    threads_before: int
    threads_after: int
    seconds: float
    burst: bool = False  # run with the burst path on (ICS35_BURST=1)
    driver: str = "asyncio"
    burst_transactions: int = 0  # of the stream's transactions, those the compiled executor ran

    @property
    def passed(self) -> bool:
        return (
            bool(self.reconnect_cycles)
            and self.resume_s_max < 1.0
            and self.untyped_outcomes == 0
            and self.requests_hung == 0
            and self.values_wrong == 0
            # Strict, unlike the short test in make test: the soak runs on a quiet machine, where no
            # reply comes later than the stream's wait (a loaded one may fail one, typed: see the test).
            and not self.failed_other_typed
            and self.no_reconnect_stream_end == "PortLost"
            and self.no_reconnect_request_error == "ClosedByPortLoss"
            and set(self.no_reconnect_pending_errors) <= {"PortLost", "ReplyTimeout"}  # silent reads time out
            and self.no_reconnect_pending_errors.get("PortLost", 0) > 0
            and self.tasks_after == self.tasks_before
            and self.fds_after == self.fds_before
            and self.threads_after == self.threads_before
        )


class _PathWatch:
    """Notes when the pty server's device path disappears and comes back (``time.monotonic()``)."""

    def __init__(self, path: str) -> None:
        self.path = path
        self.events: list[tuple[str, float]] = []
        self.task: asyncio.Task[None] | None = None

    async def run(self) -> None:
        present = True
        while True:
            exists = os.path.exists(self.path)
            if exists != present:
                present = exists
                # The clock of frame timestamps (see Bus.open).
                self.events.append(("back" if exists else "gone", time.monotonic()))
            await asyncio.sleep(0.0005)


PATIENT_ALLOWANCE = 0.25


@under_watchdog("unplug (reconnect)")
async def reconnect_session(
    down_times: Sequence[float],
    cycles_each: int,
    seed: int,
    report: dict[str, Any],
    unplug_rate: float = 0.002,
    patience: float = 6.0,
    workers: int = 3,
    driver: str = "asyncio",
) -> None:
    """reconnect=True: a stream plus ``workers`` request loops across repeated unplugs, at several down times.

    The pty server unplugs after a transaction to ID 7 with probability
    ``unplug_rate`` (its ``unplug`` fault) and plugs back in after the down time.
    Each down time gets ``patience`` seconds (plus the cycles' own time) for its
    unplugs to come: on a loaded machine fewer transactions a second means later unplugs.
    """
    loop = asyncio.get_running_loop()
    ids = list(range(8))
    for n, down in enumerate(down_times):
        proc, path = start_pty_server(
            [
                "--fast",
                "--ids",
                "0-7",
                "--faults",
                f"unplug@7:{unplug_rate}",
                "--replug-after",
                f"{down}",
                "--seed",
                str(seed + n),
            ]
        )
        watch = _PathWatch(path)
        stop = asyncio.Event()
        try:
            # The requests' allowance is a loaded machine's (0.25 s, not an adapter's 20 ms): what is
            # judged is how a request ends across an unplug, and a reply held up by the machine (a
            # timeout, then its late bytes in front of the next echo) would count as a failure here.
            async with open_bus(path, reconnect=True, adapter_latency=PATIENT_ALLOWANCE, driver=driver) as bus:
                watched(bus)
                watch.task = asyncio.create_task(watch.run())

                async def requests(k: int, bus: Bus = bus, stop: asyncio.Event = stop) -> None:
                    rng = random.Random(seed * 100 + k)
                    while not stop.is_set():
                        sid = rng.choice(ids)
                        if await tally_request(report, bus.servo(sid).read_stretch(), bus) == "port_lost":
                            await asyncio.sleep(0.01)

                stream = bus.stream(ids)
                targets = {i: 7000 + 100 * i for i in ids}
                stream.set_targets(targets)
                async with stream:
                    tasks = [asyncio.create_task(requests(k)) for k in range(workers)]
                    measured = 0  # unplugs whose resume was measured
                    backs_seen = 0  # replugs accounted for (measured, or cut short by the next unplug)
                    give_up = loop.time() + patience + cycles_each * (down + 1.5)
                    runners: dict[int, Any] = {}  # each port's burst runner (a new one after a reconnect)
                    while measured < cycles_each and loop.time() < give_up:
                        frame = await stream.next_frame()
                        runner = getattr(bus._driver, "burst", None)
                        if runner is not None:
                            runners[id(runner)] = runner
                        if frame.resumed:  # as a controller does: targets again, once it knows where it is
                            stream.set_targets(targets)
                        backs = [t for kind, t in watch.events if kind == "back"]
                        if len(backs) > backs_seen and len(frame.positions) == len(ids):
                            # The latest replug's resume: the first whole frame that started after it.
                            # An earlier replug not measured yet was cut short by the next unplug before
                            # the stream had resumed (a loaded machine's slow frames): it has no resume
                            # to measure, and the session waits for more unplugs instead.
                            gone = [t for kind, t in watch.events if kind == "gone"][len(backs) - 1]
                            back = backs[len(backs) - 1]
                            if frame.started >= back:
                                report["cycles"].append(UnplugCycle(back - gone, frame.finished - back))
                                measured += 1
                                backs_seen = len(backs)
                    stop.set()
                    await asyncio.gather(*tasks)
                    report["burst_transactions"] += sum(runner.transactions for runner in runners.values())
                report["reconnects"] += bus.stats.reconnects
                report["timeouts"] += bus.stats.total.timeouts
        finally:
            stop.set()
            if watch.task is not None:
                watch.task.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await watch.task
            stop_subprocess(proc)


@under_watchdog("unplug (no reconnect)")
async def no_reconnect_session(report: dict[str, Any], adapter_latency: float = 0.02, driver: str = "asyncio") -> None:
    """reconnect=False: the stream ends with PortLost, pending requests fail, later calls get ClosedByPortLoss.

    ``adapter_latency``: the bus's reply allowance; a reply later than that (a loaded machine) is a timeout
    and its bytes spoil the next transaction's echo."""
    proc, path = start_pty_server(["--fast", "--ids", "0-7", "--unplug-after", "1.0", "--replug-after", "0.3"])
    try:
        bus = watched(await open_bus(path, adapter_latency=adapter_latency, driver=driver))
        pending: list[RequestHandle[Any]] = []

        async def keep_requests_queued() -> None:
            # Reads nobody answers (each waits out its deadline on the wire) and ordinary reads,
            # topped up all along: whenever the port goes, some are on the wire or queued.
            with contextlib.suppress(IcsError):
                while True:
                    if sum(not f.done() for f in pending) < 6:
                        pending.append(bus.submit(protocol.ReadMemory(3, 0, 4), priority=Priority.LOW))
                        pending.append(bus.submit(protocol.ReadParam(1, Param.SPEED), priority=Priority.LOW))
                    await asyncio.sleep(0.002)

        stream = bus.stream(range(8))
        stream.set_targets({i: 7000 + 100 * i for i in range(8)})
        feeder = asyncio.create_task(keep_requests_queued())
        try:
            async with stream:
                while True:
                    await stream.next_frame()
        except IcsError as exc:
            report["stream_end"] = type(exc).__name__
        await feeder
        outcomes = await asyncio.gather(*pending, return_exceptions=True)
        report["pending"] = dict(Counter(type(o).__name__ for o in outcomes if isinstance(o, BaseException)))
        try:
            await bus.servo(1).read_stretch()
            report["request_error"] = "none"
        except IcsError as exc:
            report["request_error"] = type(exc).__name__
        await bus.aclose()
        await asyncio.sleep(0.05)
        # Counted while the bus object is alive: a task left pending by it is still referenced.
        report["tasks_after_close"] = other_tasks()
    finally:
        stop_subprocess(proc)


async def tally_request(report: dict[str, Any], read: Awaitable[int], bus: Bus, patience: float = 5.0) -> str:
    """Await a stretch read and count its outcome in ``report``; returns the key counted.

    A library error is typed, whatever its bases: ``ReplyTimeout`` is also a ``TimeoutError``,
    and is counted as the typed error it is, not as a read that hung past ``patience``.
    """
    report["requests"] += 1
    try:
        async with asyncio.timeout(patience):
            value = await read
    except PortLost:
        key = "port_lost"
    except IcsError as exc:
        report["other"][type(exc).__name__] += 1
        return "other"
    except TimeoutError:
        key = "hung"
        report.setdefault("hung_lines", []).append(bus.describe())  # what the line was doing
    except Exception:
        key = "untyped"
    else:
        key = "ok"
        if value != 30:  # factory RAM stretch: answered, but not with the servo's value
            report["wrong"] += 1
    report[key] += 1
    return key


def other_errors(counts: dict[str, int]) -> str:
    """`` (ReplyTimeout: 1)``: which typed errors other than PortLost requests met (none: empty)."""
    return f" ({', '.join(f'{name}: {n}' for name, n in sorted(counts.items()))})" if counts else ""


def new_unplug_tally() -> dict[str, Any]:
    """The counters :func:`reconnect_session` and :func:`no_reconnect_session` fill in."""
    return {
        "cycles": [],
        "requests": 0,
        "ok": 0,
        "port_lost": 0,
        "other": Counter(),
        "untyped": 0,
        "hung": 0,
        "wrong": 0,
        "reconnects": 0,
        "timeouts": 0,  # transactions the bus gave up on (a reply late on a loaded machine among them)
        "burst_transactions": 0,  # those the compiled executor ran (with ICS35_BURST=1)
    }


@under_watchdog("unplug")
async def unplug_soak(
    down_times: Sequence[float] = (0.05, 0.2, 0.5, 0.856, 1.4, 1.856, 2.4),
    cycles_each: int = 3,
    seed: int = 3,
    *,
    burst: bool = False,
    driver: str = "asyncio",
) -> UnplugReport:
    """The pty simulator's device vanishes and returns (same path), again and again.

    ``burst``: with the burst path on (``ICS35_BURST=1``), where the executor is built, and one request
    loop instead of three, so that the stream has the line most of the time.  ``driver``: the bus's.

    The down times include the worst case of the default reconnect backoff
    (0.05, 0.1, 0.2, 0.5, 1.0 s): a device that returns just after the 4th or
    5th attempt (0.85 s, 1.85 s after the loss) waits for the next one.
    """
    t0 = time.perf_counter()
    await asyncio.sleep(0)
    tasks0, fds0, threads0 = other_tasks(), open_fds(), non_executor_threads()
    report = new_unplug_tally()
    with burst_setting("1" if burst else "0", beside_requests=True):
        await reconnect_session(down_times, cycles_each, seed, report, workers=1 if burst else 3, driver=driver)
        await no_reconnect_session(report, driver=driver)
    await asyncio.sleep(0.05)  # closing transports release their fds on the next loop passes
    resume = [c.resume_s for c in report["cycles"]]
    return UnplugReport(
        reconnect_cycles=report["cycles"],
        resume_s_median=statistics.median(resume) if resume else math.nan,
        resume_s_max=max(resume, default=math.nan),
        reconnects_counted=report["reconnects"],
        requests=report["requests"],
        requests_ok=report["ok"],
        failed_port_lost=report["port_lost"],
        failed_other_typed=dict(report["other"]),
        untyped_outcomes=report["untyped"],
        requests_hung=report["hung"],
        values_wrong=report["wrong"],
        no_reconnect_stream_end=report.get("stream_end", "none"),
        no_reconnect_request_error=report.get("request_error", "none"),
        no_reconnect_pending_errors=report.get("pending", {}),
        tasks_before=tasks0,
        tasks_after=max(other_tasks(), report.get("tasks_after_close", 0)),
        fds_before=fds0,
        fds_after=open_fds(),
        threads_before=threads0,
        threads_after=non_executor_threads(),
        seconds=time.perf_counter() - t0,
        burst=burst,
        driver=driver,
        burst_transactions=report["burst_transactions"],
    )


def summarize_unplug(r: UnplugReport) -> list[Row]:
    downs = sorted({round(c.down_s, 2) for c in r.reconnect_cycles})
    rows: list[Row] = [
        (
            "unplug: stream resumes after the device returns",
            f"median {ms(r.resume_s_median)}, max {ms(r.resume_s_max)} over {len(r.reconnect_cycles)} unplugs "
            f"(down {downs[0] if downs else 0:g}-{downs[-1] if downs else 0:g} s)",
            r.resume_s_max < 1.0,
        ),
        (
            "unplug: request outcomes",
            f"{r.requests_ok:,} ok, {r.failed_port_lost:,} PortLost, {sum(r.failed_other_typed.values())} other"
            f"{other_errors(r.failed_other_typed)}, {r.untyped_outcomes} untyped, {r.requests_hung} hung, "
            f"{r.values_wrong} wrong",
            r.untyped_outcomes == 0 and r.requests_hung == 0 and r.values_wrong == 0 and not r.failed_other_typed,
        ),
        (
            "unplug: without reconnect",
            f"stream ends with {r.no_reconnect_stream_end}, pending {r.no_reconnect_pending_errors}, "
            f"later calls {r.no_reconnect_request_error}",
            r.no_reconnect_stream_end == "PortLost" and r.no_reconnect_request_error == "ClosedByPortLoss",
        ),
        (
            "unplug: leaks (tasks, fds, threads before -> after)",
            f"{r.tasks_before}->{r.tasks_after}, {r.fds_before}->{r.fds_after}, {r.threads_before}->{r.threads_after}",
            r.tasks_after == r.tasks_before and r.fds_after == r.fds_before and r.threads_after == r.threads_before,
        ),
    ]
    if not r.burst:
        return rows
    rows.insert(0, executor_row("unplug: stream transactions the compiled executor ran", r.burst_transactions))
    label = "unplug, burst path" if r.driver == "asyncio" else f"unplug, {r.driver} driver, burst path"
    return [(label + name.removeprefix("unplug"), value, ok) for name, value, ok in rows]
