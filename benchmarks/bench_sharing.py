"""Sharing the line: a full-rate 32-ID stream plus 16 coroutines polling current and temperature.

Against the real-time pty simulator.  Each run first measures the stream
alone (rate R0; one position transaction then takes T = 1 / (32 R0), host
latency included), then starts 16 pollers (coroutine k reads the current,
then the temperature, of servo 2k, ``POLL_HZ`` times a second, the 16
spread evenly over the period) and measures again (rate R1).  Reported:

* the pollers' latency (call to result) and wait (latency minus their own
  transaction's time, estimated as T adjusted by the wire-time difference of
  a 5-byte parameter read and a 6-byte position transaction), p50 and p99,
  in units of T;
* the line time the polls used (u = polls x their transaction time /
  elapsed) against the stream's rate loss (1 - R1 / R0): a ratio of 1 means
  the stream lost exactly the line time the polls used and nothing more.

For scale, ``stall_p99_tx``: how much longer than usual (p99 minus p50) the
stream alone waited between two frames, in units of T: the host's own
scheduling hiccups, which a poll waits through too.

A flat-out variant (every poller loops without sleeping) shows the bus's
fairness limit (``Bus.max_requests_between``) instead of typical use.

The floor, ``bare_floor``: a bare ``os.write``/``poll``/``os.read`` loop
that streams the same 32 position transactions and serves the same polls
(each due at its poller's time, sent at the next transaction boundary,
current then temperature) with no checks, no event loop and no engine.  Its
figures, in its own T, are what the pty and the host leave to any client:
a poll's wait can be no shorter than the transaction in flight as it comes,
and the host's stalls fall on polls and transactions alike.

    .venv/bin/python benchmarks/bench_sharing.py [--runs 3]
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import heapq
import json
import os
import select
import time
from typing import Any

import serial
from bench_common import (
    IDS,
    NEUTRAL,
    POSITION_BYTES,
    POSITION_TXS,
    PTY_BUS_OPTIONS,
    READ_PARAM_BYTES,
    loop_names,
    median,
    percentile,
    progress,
    pty_sim,
    run_on,
)

from ics35_async import open_bus, protocol
from ics35_async.errors import ReplyError
from ics35_async.stream import Stream

POLLERS = 16
POLL_HZ = 10.0  # each poller: current + temperature, 10 times a second (320 reads/s in all)
BAUDS = (115200, 1250000)

Figures = dict[str, Any]


Mark = tuple[int, float]  # (cycle number, perf_counter when the consumer got the frame)


async def _window(stream: Stream, duration: float, gaps: list[float] | None = None) -> tuple[Mark, Mark]:
    """First and last frame of a window of at least ``duration`` seconds.

    Timed with ``time.perf_counter`` rather than the frames' loop-time
    stamps: uvloop's ``loop.time()`` has millisecond resolution.  ``gaps``
    collects the time between consecutive frames, per cycle.
    """
    first = ((await stream.next_frame()).cycle, time.perf_counter())
    last = first
    while last[1] - first[1] < duration:
        frame = ((await stream.next_frame()).cycle, time.perf_counter())
        if gaps is not None:
            gaps.append((frame[1] - last[1]) / (frame[0] - last[0]))
        last = frame
    return first, last


def _rate(first: Mark, last: Mark) -> float:
    return (last[0] - first[0]) / (last[1] - first[1])


def measure(
    path: str, loop: str, baud: int, *, alone: float, shared: float, flat_out: bool = False, transport: str = "direct"
) -> Figures:
    async def main() -> Figures:
        loop_ = asyncio.get_running_loop()
        async with open_bus(path, baudrate=baud, transport=transport, **PTY_BUS_OPTIONS) as bus:
            async with bus.stream(IDS) as stream:
                stream.set_targets(dict.fromkeys(IDS, NEUTRAL))
                while (await stream.next_frame()).cycle < 5:  # warm-up
                    pass
                gaps: list[float] = []
                r0 = _rate(*await _window(stream, alone, gaps))
                polls: list[tuple[float, float]] = []  # (start, end) of each read
                poll_errors: list[float] = []
                period = 1 / POLL_HZ

                async def poller(k: int) -> None:
                    servo = bus.servo(2 * k)
                    start = loop_.time() + k * period / POLLERS
                    tick = 0
                    while True:
                        if not flat_out:
                            delay = start + tick * period - loop_.time()
                            tick += 1
                            if delay > 0:
                                await asyncio.sleep(delay)
                        for read in (servo.read_current, servo.read_temperature):
                            t0 = time.perf_counter()
                            try:
                                await read()
                            except ReplyError:
                                poll_errors.append(t0)
                            else:
                                polls.append((t0, time.perf_counter()))

                tasks = [asyncio.create_task(poller(k)) for k in range(POLLERS)]
                try:
                    await asyncio.sleep(2 * period)  # every poller has started
                    first, last = await _window(stream, shared)
                finally:
                    for t in tasks:
                        t.cancel()
                    for t in tasks:
                        with contextlib.suppress(asyncio.CancelledError):
                            await t
                failures = sum(stream.stats.failures.values())
            errors = bus.stats.total.errors
        r1 = _rate(first, last)
        in_window = [(a, b) for a, b in polls if first[1] <= b <= last[1]]
        t_pos = 1 / (r0 * len(IDS))
        t_read = t_pos + protocol.wire_time(READ_PARAM_BYTES - POSITION_BYTES, baud)
        elapsed = last[1] - first[1]
        used = len(in_window) * t_read / elapsed
        loss = 1 - r1 / r0
        return {
            **_figures(in_window, gaps, t_pos, baud),
            "rate_alone_cycles_per_s": r0,
            "rate_shared_cycles_per_s": r1,
            "polls_per_s": len(in_window) / elapsed,
            "line_share_used_by_polls": used,
            "stream_rate_loss": loss,
            "loss_per_line_time_used": loss / used if used else float("nan"),
            "stream_failures": failures,
            "poll_errors": len(poll_errors),
            "bus_errors": errors,
        }

    return run_on(loop, main)


def _figures(polls: list[tuple[float, float]], gaps: list[float], t_pos: float, baud: int) -> Figures:
    """A measure's figures from its polls' (call, result) times and the stream alone's gaps, in units of T."""
    t_read = t_pos + protocol.wire_time(READ_PARAM_BYTES - POSITION_BYTES, baud)
    latency = [(b - a) / t_pos for a, b in polls]
    wait = [max(0.0, (b - a - t_read) / t_pos) for a, b in polls]
    return {
        # host stalls seen by the stream alone: p99 minus p50 of the time between frames, in T
        "stall_p99_tx": (percentile(gaps, 99) - percentile(gaps, 50)) / t_pos,
        "position_tx_us": t_pos * 1e6,
        "latency_p50_tx": percentile(latency, 50),
        "latency_p99_tx": percentile(latency, 99),
        "wait_p50_tx": percentile(wait, 50),
        "wait_p99_tx": percentile(wait, 99),
    }


def bare_floor(path: str, baud: int, *, alone: float, shared: float) -> Figures:
    """The polls' wait with nothing of ours around: see the module's docstring.  Figures as :func:`measure`'s
    (those that concern its engine or its stream's rate left out)."""
    reads = [
        tuple(bytes((0xA0 | servo, param)) for param in (protocol.Param.CURRENT, protocol.Param.TEMPERATURE))
        for servo in range(0, 2 * POLLERS, 2)
    ]
    ser = serial.Serial(path, baud, parity=serial.PARITY_NONE, timeout=1)
    fd = ser.fileno()
    poller = select.poll()
    poller.register(fd, select.POLLIN)
    write, read, poll, clock = os.write, os.read, poller.poll, time.perf_counter

    def transaction(tx: bytes, expect: int) -> float:
        write(fd, tx)
        got = 0
        while got < expect:
            if not poll(1000):
                raise RuntimeError(f"the responder did not answer {tx.hex(' ')} within 1 s")
            got += len(read(fd, 64))
        return clock()

    try:
        for tx in POSITION_TXS:  # warm-up
            transaction(tx, 6)
        t0 = last = clock()
        cycles = 0
        gaps: list[float] = []
        while last - t0 < alone:
            for tx in POSITION_TXS:
                transaction(tx, 6)
            now = clock()
            gaps.append(now - last)
            last = now
            cycles += 1
        t_pos = (last - t0) / (cycles * len(IDS))
        period = 1 / POLL_HZ
        start = clock() + 2 * period / POLLERS
        due = [(start + k * period / POLLERS, k) for k in range(POLLERS)]  # the pollers' next turns
        polls: list[tuple[float, float]] = []
        end = clock() + shared
        while clock() < end:
            for tx in POSITION_TXS:
                transaction(tx, 6)
                while due[0][0] <= clock():
                    when, k = heapq.heappop(due)
                    call = when
                    for read_tx in reads[k]:
                        done = transaction(read_tx, 5)
                        polls.append((call, done))
                        call = done
                    heapq.heappush(due, (when + period, k))
    finally:
        ser.close()
    return {**_figures(polls, gaps, t_pos, baud), "polls_per_s": len(polls) / shared}


def run(runs: int = 3, alone: float = 1.5, shared: float = 2.5, bauds: tuple[int, ...] = BAUDS) -> dict[str, Any]:
    loops = loop_names()
    out: dict[str, Any] = {
        "server": "pty, real-time mode",
        "runs": runs,
        "pollers": POLLERS,
        "poll_hz_each": POLL_HZ,
        "rows": [],
    }
    for baud in bauds:
        rows: dict[tuple[str, str], list[Figures]] = {}
        with pty_sim("--realtime", "--baud", str(baud)) as path:
            for r in range(runs):
                progress(f"sharing {baud}: run {r + 1}/{runs}")
                for loop in loops:
                    rows.setdefault((loop, "paced"), []).append(measure(path, loop, baud, alone=alone, shared=shared))
                if baud == bauds[0]:
                    rows.setdefault((loops[0], "flat-out"), []).append(
                        measure(path, loops[0], baud, alone=alone / 2, shared=shared / 2, flat_out=True)
                    )
        for (loop, mode), figs in rows.items():
            out["rows"].append(
                {
                    "baud": baud,
                    "loop": loop,
                    "transport": "direct",
                    "polling": mode,
                    **{k: median([f[k] for f in figs]) for k in figs[0]},
                }
            )
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=3)
    args = parser.parse_args()
    print(json.dumps(run(args.runs), indent=2))


if __name__ == "__main__":
    main()
