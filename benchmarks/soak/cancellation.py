"""The cancellation soak: random cancellations of in-flight and queued requests and of whole streams.

Then a consistency check: every servo answers correctly, the bus is idle,
nothing is queued, the counters add up, and no request that was not
cancelled got a value its bytes did not carry.

``link``: as in the chaos soak, the simulator may answer on a pty (:data:`.common.PTY`), with the
bus on the burst path (:data:`.common.PTY_BURST`).  Real time then decides whether a reply comes
within its allowance: errors beyond what the bytes call for, stray bytes (a reply that came after
its transaction gave up) and rejected valid replies are counted, not desyncs; wrong values, values
out of a servo's band, untyped outcomes and the counters adding up afterwards stay targets.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import random
import time
from collections import Counter, deque
from dataclasses import dataclass
from typing import Any

from benchmarks.bench_common import burst_setting, executor_transactions
from ics35_async import (
    Bus,
    IcsError,
    Priority,
    open_bus,
    protocol,
)
from ics35_async.protocol import Command
from ics35_async.sim import (
    VirtualLine,
)
from tests.support.matcher import LogMatcher, RequestRecord
from tests.support.oracle import band, chaos_servos, is_stream_tx
from tests.support.timing import FAST_TIMING

from .common import (
    BURST_LINKS,
    IN_PROCESS,
    Row,
    consistency_check,
    executor_row,
    link_driver,
    random_request,
    served_on_a_pty,
    stream_target,
)
from .watchdog import under_watchdog, watched

RECENT_COMMANDS = 4  # see `recent` in the soak


@dataclass
class CancelReport:
    cancellations: int
    requests_cancelled_queued: int
    requests_cancelled_in_flight: int
    streams_cancelled: int
    stream_frames_seen: int
    requests_completed: int
    requests_checked: int
    misattributed: int
    valid_replies_rejected: int
    stream_positions_out_of_band: int
    untyped_outcomes: int
    bus_errors: int
    expected_errors: int
    stray_bytes: int
    desyncs: int
    post_check: dict[str, Any]
    seconds: float
    examples: list[str]
    link: str = IN_PROCESS
    burst_transactions: int = 0  # of the streams' transactions, those the compiled executor ran

    @property
    def passed(self) -> bool:
        return self.desyncs == 0 and self.misattributed == 0 and self.untyped_outcomes == 0


@under_watchdog("cancel")
async def cancellation_soak(
    cancellations: int = 10_000,
    seed: int = 2,
    concurrency: int = 6,
    stream_share: float = 0.05,
    link: str = IN_PROCESS,
) -> CancelReport:
    """Cancel requests (queued, on the wire, between retries) and streams at random; then check for desyncs.

    The line has no faults, so every transaction's bytes are valid except
    those of the silent memory reads: any other error, a stray byte or a
    wrong value is a desync.  Requests that were not cancelled are matched
    to the log like in the chaos soak; stream frames are checked against
    the servos' disjoint position bands.
    """
    sim = VirtualLine(chaos_servos(), log_size=200_000)
    async with contextlib.AsyncExitStack() as stack:
        stack.callback(sim.close)
        if link == IN_PROCESS:
            bus = watched(await open_bus(sim, retries=1, timing=FAST_TIMING))
        else:
            path = await stack.enter_async_context(served_on_a_pty(sim))
            with burst_setting("1" if link in BURST_LINKS else "0", beside_requests=True):
                bus = watched(await open_bus(path, retries=1, timing=FAST_TIMING, driver=link_driver(link)))
        stack.push_async_callback(bus.aclose)
        report = await _cancel(sim, bus, cancellations, seed, concurrency, stream_share, link)
    return report


async def _cancel(
    sim: VirtualLine, bus: Bus, cancellations: int, seed: int, concurrency: int, stream_share: float, link: str
) -> CancelReport:
    realtime = link != IN_PROCESS
    matcher = LogMatcher(sim, is_stream_tx, range(32), track_stream=False, realtime=realtime)
    images = {i: sim.servo(i).eeprom for i in range(32)}
    loop = asyncio.get_running_loop()
    busy: set[int] = set()
    # The last few commands sent to each ID: a request never repeats one of them, so a servo's log entries split
    # into one run per request even where a request cancelled while queued never reached the line (one
    # before it and one after it may then send the same bytes) and, over a pty, its outcome came before the
    # simulator's thread logged it.
    recent: dict[int, deque[bytes]] = {i: deque(maxlen=RECENT_COMMANDS) for i in range(32)}
    tally: Counter[str] = Counter()
    out_of_band: list[str] = []
    stream_target_ids = list(range(32))
    t0 = time.perf_counter()

    def record(sid: int, cmd: Command[Any], attempts: int, outcome: BaseException | None, value: Any) -> None:
        if outcome is None:
            rec = RequestRecord(sid, cmd.tx, attempts, True, value, None, True, time.monotonic(), sim.transactions)
            tally["completed"] += 1
        else:
            typed = isinstance(outcome, (IcsError, asyncio.CancelledError, TimeoutError))
            name = "CancelledError" if isinstance(outcome, (asyncio.CancelledError, TimeoutError)) else None
            name = name or type(outcome).__name__
            rec = RequestRecord(sid, cmd.tx, attempts, False, None, name, typed, time.monotonic(), sim.transactions)
            tally["cancelled" if name == "CancelledError" else "failed"] += 1
        matcher.add_request(rec)

    async def request_victim(rng: random.Random) -> None:
        free = [i for i in range(32) if i not in busy]
        sid = rng.choice(free)
        busy.add(sid)
        try:
            cmd, call, attempts = random_request(rng, bus, sid, images[sid])
            while cmd.tx in recent[sid]:
                cmd, call, attempts = random_request(rng, bus, sid, images[sid])
            if rng.random() < 0.1:
                # A silent servo: the request waits out its deadline on the wire, cancellable all along.
                silent = protocol.ReadMemory(sid, rng.randrange(100), rng.randrange(1, 8))
                if silent.tx not in recent[sid]:
                    cmd, call, attempts = silent, functools.partial(bus.request, silent, retries=1), 2
            recent[sid].append(cmd.tx)
            style = rng.random()
            outcome: BaseException | None = None
            value: Any = None
            if style < 0.6:
                # A bare future from submit(), cancelled while queued or exactly while on the wire.
                priority = rng.choice(list(Priority))
                retries = rng.randrange(3) if cmd.idempotent else 0
                attempts = 1 + retries
                fut = bus.submit(cmd, priority=priority, retries=retries)
                if style < 0.25:
                    for _ in range(rng.randrange(3)):
                        await asyncio.sleep(0)
                else:
                    give_up = loop.time() + 0.1
                    while loop.time() < give_up:
                        log = sim.log
                        if fut.done() or (log and log[-1].tx == cmd.tx):
                            break  # written, its reply not handled yet: on the wire
                        await asyncio.sleep(0)
                fut.cancel()
                try:
                    value = await fut
                except BaseException as exc:
                    outcome = exc
            elif style < 0.85:
                # A task inside a Servo call, cancelled after it has submitted its request.
                task = asyncio.ensure_future(call())
                await asyncio.sleep(0)
                if rng.random() < 0.5:
                    for _ in range(rng.randrange(4)):
                        await asyncio.sleep(0)
                else:
                    await asyncio.sleep(rng.uniform(0, 0.004))
                task.cancel()
                try:
                    value = await task
                except BaseException as exc:
                    outcome = exc
            else:
                # A caller's own timeout.
                try:
                    async with asyncio.timeout(rng.uniform(0, 0.003)):
                        value = await call()
                except BaseException as exc:
                    outcome = exc
            record(sid, cmd, attempts, outcome, value)
        finally:
            busy.discard(sid)

    async def stream_victim(rng: random.Random) -> None:
        ids = sorted(rng.sample(stream_target_ids, rng.randrange(1, 33)))
        rate = rng.choice([None, None, 500.0, 2000.0])

        first_frame = asyncio.Event()

        async def body() -> None:
            stream = bus.stream(ids, rate_hz=rate, probe_interval=0.01)
            # Targets first: a stream starts with every ID free, and a free command looks like a request.
            stream.set_targets({i: stream_target(i, rng.randrange(100)) for i in ids})
            async with stream:
                async for frame in stream:
                    tally["frames"] += 1
                    first_frame.set()
                    for i, position in frame.positions.items():
                        low, high = band(i)
                        if not low <= position <= high:
                            out_of_band.append(f"frame {frame.cycle}: ID {i} at {position}, band {low}..{high}")

        task = asyncio.ensure_future(body())
        for _ in range(rng.randrange(3)):
            await asyncio.sleep(0)
        if rng.random() < 0.8:
            await asyncio.sleep(rng.uniform(0, 0.05))
        elif rng.random() < 0.5:
            # Some streams live until they have published: cancelling one mid-cycle is covered
            # either way, and a loaded machine must not leave every stream frameless.
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(first_frame.wait(), 2.0)
        task.cancel()
        result = await asyncio.gather(task, return_exceptions=True)
        if isinstance(result[0], asyncio.CancelledError):
            tally["streams_cancelled"] += 1
        elif result[0] is not None:
            tally["stream_errors"] += 1
            out_of_band.append(f"stream ended with {result[0]!r}")

    stream_goal = round(stream_share * cancellations)
    request_goal = cancellations - stream_goal

    async def canceller(k: int) -> None:
        rng = random.Random(seed * 7919 + k)
        while tally["cancelled"] < request_goal:
            await request_victim(rng)
            matcher.drain()
            matcher.match()

    async def stream_canceller() -> None:
        rng = random.Random(seed * 31 + 5)
        while tally["streams_cancelled"] < stream_goal:
            await stream_victim(rng)

    await asyncio.gather(stream_canceller(), *(canceller(k) for k in range(concurrency)))
    await bus.wait_idle()
    matcher.drain()
    matcher.match(final=True)
    counts = matcher.counts
    expected_errors = counts.predicted_errors
    stats = bus.stats
    bus_errors, stray = stats.total.errors, stats.stray_bytes
    queued = stats.queued
    burst_transactions = executor_transactions(bus)
    post = await consistency_check(sim, bus, realtime=realtime)
    problems = list(post["problems"])
    if bus_errors != expected_errors and not realtime:
        problems.append(f"bus counted {bus_errors} errors, the bytes on the line call for {expected_errors}")
    if stray and not realtime:
        problems.append(f"{stray} stray bytes")
    if queued:
        problems.append(f"{queued} requests still queued after wait_idle()")
    problems += out_of_band[:5]
    rejected = 0 if realtime else counts.valid_rejected
    desyncs = len(problems) + counts.misattributed + rejected + len(out_of_band)
    return CancelReport(
        cancellations=tally["cancelled"] + tally["streams_cancelled"],
        requests_cancelled_queued=counts.cancelled_queued,
        requests_cancelled_in_flight=counts.cancelled_in_flight,
        streams_cancelled=tally["streams_cancelled"],
        stream_frames_seen=tally["frames"],
        requests_completed=tally["completed"] + tally["failed"],
        requests_checked=counts.requests - counts.cancelled_queued - counts.cancelled_in_flight,
        misattributed=counts.misattributed,
        valid_replies_rejected=counts.valid_rejected,
        stream_positions_out_of_band=len(out_of_band),
        untyped_outcomes=counts.untyped_outcomes,
        bus_errors=bus_errors,
        expected_errors=expected_errors,
        stray_bytes=stray,
        desyncs=desyncs,
        post_check={**post, "problems": problems},
        seconds=time.perf_counter() - t0,
        examples=counts.examples + out_of_band[:5],
        link=link,
        burst_transactions=burst_transactions,
    )


def summarize_cancel(r: CancelReport) -> list[Row]:
    rows: list[Row] = [
        (
            "cancel: cancellations",
            f"{r.cancellations:,}: {r.requests_cancelled_queued:,} queued, "
            f"{r.requests_cancelled_in_flight:,} on the wire, {r.streams_cancelled} streams",
            None,
        ),
        ("cancel: desyncs", f"{r.desyncs}", r.desyncs == 0),
        (
            "cancel: wrong values (requests, stream frames)",
            f"{r.misattributed}, {r.stream_positions_out_of_band}",
            r.misattributed == 0 and r.stream_positions_out_of_band == 0,
        ),
    ]
    if r.link == IN_PROCESS:
        return rows
    if r.link in BURST_LINKS:
        rows.insert(1, executor_row("cancel: stream transactions the compiled executor ran", r.burst_transactions))
    rows.append(
        (
            "cancel: real time (counted, not desyncs)",
            f"{r.bus_errors - r.expected_errors} errors beyond what the bytes call for, {r.stray_bytes} stray "
            f"bytes, {r.valid_replies_rejected} valid replies rejected",
            None,
        )
    )
    return [(f"cancel over a {r.link}" + name.removeprefix("cancel"), value, ok) for name, value, ok in rows]
