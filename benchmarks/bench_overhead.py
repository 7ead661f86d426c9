"""Host overhead: our public API against the best synchronous code, over a pty.

Three ways of doing the same bytes against the simulator's pty server
(32 servos, position 7500 to IDs 0..31 in turn; write 3 bytes, read 6):

* ``raw``: a blocking pyserial loop (``write`` then ``read(6)``), the
  baseline the issue sets;
* ``lean``: the same with bare ``os.write`` / ``poll`` / ``os.read`` and no
  checks at all: not a driver, but the floor any client of this server has;
* ``sequential``: ``await servo.set_position(7500)`` in a loop;
* ``stream``: ``bus.stream(range(32))`` with a consumer awaiting every frame,
  counting the frames' cycle numbers over a fixed time.

Each also gives the client's CPU time per transaction (``time.process_time``
of this process; the server is another process).  The same functions run
against the real-time server for the wire-efficiency figures.

    .venv/bin/python benchmarks/bench_overhead.py [--runs 3] [--duration 0.6]
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import os
import select
import statistics
import time
from typing import Any

import serial
from bench_common import (
    IDS,
    NEUTRAL,
    POSITION_TXS,
    PTY_BUS_OPTIONS,
    TRANSPORTS,
    loop_names,
    median,
    progress,
    pty_sim,
    run_on,
)

from ics35_async import open_bus

Figures = dict[str, Any]


def raw_loop(path: str, duration: float, *, baud: int = 115200) -> Figures:
    """The blocking pyserial baseline: one position transaction after the other, IDs 0..31 in turn."""
    # 8N1 and every setting in the constructor: a pty has no parity, and a
    # later re-configuration at an unchanged speed fails there (see sim.pty_port).
    ser = serial.Serial(path, baud, parity=serial.PARITY_NONE, timeout=1)
    txs = POSITION_TXS
    write, read = ser.write, ser.read
    try:
        for tx in txs:  # warm-up: one cycle
            write(tx)
            read(6)
        cycles = 0
        wall0, cpu0 = time.perf_counter(), time.process_time()
        end = wall0 + duration
        while True:
            for tx in txs:
                write(tx)
                if len(read(6)) != 6:
                    raise RuntimeError(f"the simulator did not answer {tx.hex(' ')} within 1 s")
            cycles += 1
            now = time.perf_counter()
            if now >= end:
                break
        wall, cpu = now - wall0, time.process_time() - cpu0
    finally:
        ser.close()
    n = cycles * len(txs)
    return {"tx_per_s": n / wall, "cycles_per_s": cycles / wall, "cpu_us_per_tx": cpu / n * 1e6}


def lean_loop(path: str, duration: float, *, baud: int = 115200) -> Figures:
    """The floor for any client of this server: ``os.write`` then ``poll`` + ``os.read`` until 6 bytes.

    Not a baseline we aim to beat (it skips every check a driver needs) but
    a measure of what the pty and the simulator leave to any client.
    """
    ser = serial.Serial(path, baud, parity=serial.PARITY_NONE, timeout=1)
    fd = ser.fileno()
    poller = select.poll()
    poller.register(fd, select.POLLIN)
    txs = POSITION_TXS
    write, read, poll = os.write, os.read, poller.poll
    try:
        cycles = 0
        wall0 = cpu0 = 0.0
        end = math.inf
        while True:
            for tx in txs:
                write(fd, tx)
                got = 0
                while got < 6:
                    if not poll(1000):
                        raise RuntimeError(f"the simulator did not answer {tx.hex(' ')} within 1 s")
                    got += len(read(fd, 64))
            now = time.perf_counter()
            if not wall0:  # the first cycle was the warm-up
                wall0, cpu0, end = now, time.process_time(), now + duration
                continue
            cycles += 1
            if now >= end:
                break
        wall, cpu = now - wall0, time.process_time() - cpu0
    finally:
        ser.close()
    n = cycles * len(txs)
    return {"tx_per_s": n / wall, "cycles_per_s": cycles / wall, "cpu_us_per_tx": cpu / n * 1e6}


def api_sequential(path: str, loop: str, transport: str, duration: float, *, baud: int = 115200) -> Figures:
    """``await servo.set_position(...)`` in a loop over IDs 0..31, through the public API."""

    async def measure() -> Figures:
        async with open_bus(path, baudrate=baud, transport=transport, **PTY_BUS_OPTIONS) as bus:
            servos = bus.servos(IDS)
            for s in servos + servos:  # warm-up
                await s.set_position(NEUTRAL)
            rounds = 0
            wall0, cpu0 = time.perf_counter(), time.process_time()
            end = wall0 + duration
            while True:
                for s in servos:
                    await s.set_position(NEUTRAL)
                rounds += 1
                now = time.perf_counter()
                if now >= end:
                    break
            wall, cpu = now - wall0, time.process_time() - cpu0
            n = rounds * len(servos)
            errors = bus.stats.total.errors
        return {"tx_per_s": n / wall, "cpu_us_per_tx": cpu / n * 1e6, "errors": errors}

    return run_on(loop, measure)


def api_stream(
    path: str, loop: str, transport: str, duration: float, *, baud: int = 115200, warmup_cycles: int = 5
) -> Figures:
    """A 32-ID stream with a consumer awaiting every frame; the cycle rate from the frames' cycle numbers."""

    async def measure() -> Figures:
        async with (
            open_bus(path, baudrate=baud, transport=transport, **PTY_BUS_OPTIONS) as bus,
            bus.stream(IDS) as stream,
        ):
            stream.set_targets(dict.fromkeys(IDS, NEUTRAL))
            first = await stream.next_frame()
            while first.cycle < warmup_cycles:
                first = await stream.next_frame()
            # perf_counter, not the frames' loop-time stamps: uvloop's loop.time() has 1 ms resolution
            wall0, cpu0 = time.perf_counter(), time.process_time()
            failures0 = sum(stream.stats.failures.values())
            frame = first
            while (now := time.perf_counter()) - wall0 < duration:
                frame = await stream.next_frame()
            cpu = time.process_time() - cpu0
            failures = sum(stream.stats.failures.values()) - failures0
        cycles = frame.cycle - first.cycle
        elapsed = now - wall0
        n = cycles * len(IDS)
        return {
            "cycles_per_s": cycles / elapsed,
            "tx_per_s": n / elapsed,
            "cpu_us_per_tx": cpu / n * 1e6,
            "failures": failures,
        }

    return run_on(loop, measure)


def run(runs: int = 5, duration: float = 0.6) -> dict[str, Any]:
    """Section 1 (host overhead) and 5 (loops x transports), fast-mode pty server.

    The raw baseline is measured before and after every variant; each
    variant's ratio is taken against the mean of its two neighbours, and the
    median over runs is reported.
    """
    loops = loop_names()
    variants = [(lp, t) for lp in loops for t in TRANSPORTS]
    raw_runs: list[Figures] = []
    lean_runs: list[Figures] = []
    lean_ratios: list[float] = []
    per_variant: dict[tuple[str, str], dict[str, list[Figures]]] = {
        v: {"sequential": [], "stream": []} for v in variants
    }
    ratios: dict[tuple[str, str], dict[str, list[float]]] = {v: {"sequential": [], "stream": []} for v in variants}
    with pty_sim("--fast") as path:
        for r in range(runs):
            progress(f"overhead: run {r + 1}/{runs}")
            # raw, variant, raw, variant, ..., raw: each variant against the mean of its two neighbours
            raws = [raw_loop(path, duration)]
            lean = lean_loop(path, duration)
            this_run: dict[tuple[str, str], dict[str, Figures]] = {}
            for v in variants:
                this_run[v] = {
                    "sequential": api_sequential(path, *v, duration),
                    "stream": api_stream(path, *v, duration * 1.5),
                }
                raws.append(raw_loop(path, duration))
            base_rates = [(a["tx_per_s"] + b["tx_per_s"]) / 2 for a, b in itertools.pairwise(raws)]
            raw_runs.append({k: statistics.mean(f[k] for f in raws) for k in raws[0]})
            lean_runs.append(lean)
            lean_ratios.append(lean["tx_per_s"] / raws[0]["tx_per_s"])
            for (v, figs), base in zip(this_run.items(), base_rates, strict=True):
                for kind, f in figs.items():
                    per_variant[v][kind].append(f)
                    ratios[v][kind].append(f["tx_per_s"] / base)

    def medians(runs_: list[Figures]) -> Figures:
        return {k: median([f[k] for f in runs_]) for k in runs_[0]}

    out: dict[str, Any] = {
        "server": "pty, fast mode (python -m ics35_async.sim --ids 0-31 --fast)",
        "runs": runs,
        "raw": {**medians(raw_runs), "per_run": raw_runs},
        "lean": {**medians(lean_runs), "vs_raw": median(lean_ratios), "per_run": lean_runs},
        "variants": [],
    }
    for v in variants:
        seq, stream = medians(per_variant[v]["sequential"]), medians(per_variant[v]["stream"])
        out["variants"].append(
            {
                "loop": v[0],
                "transport": v[1],
                "sequential": seq,
                "stream": stream,
                # (a)/(c): transactions/s; (b)/(c): cycles/s x 32 against the raw loop's transactions/s
                "sequential_vs_raw": median(ratios[v]["sequential"]),
                "stream_vs_raw": median(ratios[v]["stream"]),
                "sequential_vs_raw_per_run": ratios[v]["sequential"],
                "stream_vs_raw_per_run": ratios[v]["stream"],
            }
        )
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--duration", type=float, default=0.6)
    args = parser.parse_args()
    print(json.dumps(run(args.runs, args.duration), indent=2))


if __name__ == "__main__":
    main()
