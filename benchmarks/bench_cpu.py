"""Client CPU per transaction against the lean responder: raw pyserial, the floor, and ours per driver x loop.

The far end is :mod:`lean_responder` (a tight os.read/os.write loop in its
own process), so the client's cost dominates.  Rows, 32 IDs in turn, one
position transaction (write 3 bytes, read 6) each:

* ``raw``: a blocking pyserial ``write`` / ``read(6)`` loop, the baseline;
* ``floor``: bare ``os.write`` / ``poll`` / ``os.read``, no checks: what the
  pty and the responder leave to any client;
* per event loop, its own floors (:mod:`bench_floors`): ``loop floor stream``
  (a reader callback that writes the next command: one loop pass per
  transaction) and ``loop floor sequential`` (an awaited future per
  transaction);
* for each driver x event loop: ``sequential`` (``await servo.set_position``
  in a loop) and ``stream`` (``bus.stream(range(32))``, every ID free: each
  transaction a free command that reads the position back; a consumer awaits
  every frame).

CPU is ``time.process_time()`` of this process (every thread; the responder
is another process) over the measured stretch, divided by the transactions.
Each run measures the raw loop before the first row and after every row;
each row's ratios are taken against the mean of its two neighbouring raw
measurements, and the medians over runs are reported.

    .venv/bin/python benchmarks/bench_cpu.py [--runs 3] [--duration 1.0]
"""

from __future__ import annotations

import argparse
import itertools
import json
import statistics
import time
from collections.abc import Callable
from typing import Any

import bench_floors
from bench_common import IDS, NEUTRAL, loop_names, median, progress, run_on
from bench_overhead import lean_loop, raw_loop
from lean_responder import lean_lines

from ics35_async import IcsError, open_bus

Figures = dict[str, Any]

DRIVERS: tuple[str | None, ...] = ("asyncio", "thread", "anyio")
"""The drivers to measure (``None`` would be ``open_bus``'s default, asyncio under asyncio): every row,
table and ratio in sections A and B follows from this tuple."""

BUS_OPTIONS: dict[str, Any] = {"adapter_latency": 0.010}
"""A pty has no USB latency timer; 10 ms keeps false timeouts rare on a busy machine (they are counted)."""


def bus_options(driver: str | None) -> dict[str, Any]:
    """``open_bus`` keyword arguments for one driver (no ``driver=`` at all for the default)."""
    return dict(BUS_OPTIONS) if driver is None else {**BUS_OPTIONS, "driver": driver}


def driver_name(driver: str | None) -> str:
    return driver or "default"


def sequential(path: str, driver: str | None, loop: str, duration: float) -> Figures:
    """``await servo.set_position(7500)`` over IDs 0..31 in turn; a failed transaction is counted, not fatal."""

    async def measure() -> Figures:
        async with open_bus(path, **bus_options(driver)) as bus:
            servos = bus.servos(IDS)
            for s in servos * 2:  # warm-up
                await s.set_position(NEUTRAL)
            n = failures = 0
            wall0, cpu0 = time.perf_counter(), time.process_time()
            end = wall0 + duration
            while True:
                for s in servos:
                    try:
                        await s.set_position(NEUTRAL)
                    except IcsError:
                        failures += 1
                n += len(servos)
                now = time.perf_counter()
                if now >= end:
                    break
            wall, cpu = now - wall0, time.process_time() - cpu0
        return {"tx_per_s": n / wall, "cpu_us_per_tx": cpu / n * 1e6, "failures": failures}

    return run_on(loop, measure)


def stream(path: str, driver: str | None, loop: str, duration: float, warmup_cycles: int = 5) -> Figures:
    """A 32-ID stream, every ID free (no targets), with a consumer awaiting every frame.  CPU per
    transaction: all of the process's, and the event loop's thread's alone."""

    async def measure() -> Figures:
        async with open_bus(path, **bus_options(driver)) as bus, bus.stream(IDS) as st:
            first = await st.next_frame()
            while first.cycle < warmup_cycles:
                first = await st.next_frame()
            wall0, cpu0, loop0 = time.perf_counter(), time.process_time(), time.thread_time()
            failures0 = sum(st.stats.failures.values())
            frame = first
            while (now := time.perf_counter()) - wall0 < duration:
                frame = await st.next_frame()
            cpu, loop_cpu = time.process_time() - cpu0, time.thread_time() - loop0
            failures = sum(st.stats.failures.values()) - failures0
        n = (frame.cycle - first.cycle) * len(IDS)
        wall = now - wall0
        return {
            "tx_per_s": n / wall,
            "cpu_us_per_tx": cpu / n * 1e6,
            "loop_us_per_tx": loop_cpu / n * 1e6,
            "failures": failures,
        }

    return run_on(loop, measure)


def rows_to_measure() -> list[tuple[str, Callable[[str, float], Figures]]]:
    """(row name, measure(path, duration)) for the floor and every driver x loop x kind."""
    rows: list[tuple[str, Callable[[str, float], Figures]]] = [("floor", lean_loop)]

    def on(fn: Callable[[str, str, float], Figures], loop: str) -> Callable[[str, float], Figures]:
        return lambda path, duration: fn(path, loop, duration)

    def with_driver(
        fn: Callable[[str, str | None, str, float], Figures], driver: str | None, loop: str
    ) -> Callable[[str, float], Figures]:
        return lambda path, duration: fn(path, driver, loop, duration)

    for loop in loop_names():
        rows.append((f"loop floor stream {loop}", on(bench_floors.loop_stream, loop)))
        rows.append((f"loop floor sequential {loop}", on(bench_floors.loop_sequential, loop)))
    for driver, loop in itertools.product(DRIVERS, loop_names()):
        for kind, fn in (("sequential", sequential), ("stream", stream)):
            rows.append((f"{kind} {driver_name(driver)}/{loop}", with_driver(fn, driver, loop)))
    return rows


def run(runs: int = 3, duration: float = 1.0) -> dict[str, Any]:
    """Every row ``runs`` times, interleaved with the raw baseline, against one lean responder."""
    rows = rows_to_measure()
    raw_runs: list[Figures] = []
    figures: dict[str, list[Figures]] = {name: [] for name, _ in rows}
    rate_ratio: dict[str, list[float]] = {name: [] for name, _ in rows}
    cpu_ratio: dict[str, list[float]] = {name: [] for name, _ in rows}
    engine_runs: list[Figures] = []
    with lean_lines(1) as (path,):
        for r in range(runs):
            progress(f"cpu: run {r + 1}/{runs}")
            raws = [raw_loop(path, duration)]
            for name, measure in rows:
                figures[name].append(measure(path, duration))
                raws.append(raw_loop(path, duration))
            for (name, _), (a, b) in zip(rows, itertools.pairwise(raws), strict=True):
                f = figures[name][-1]
                rate_ratio[name].append(f["tx_per_s"] / ((a["tx_per_s"] + b["tx_per_s"]) / 2))
                cpu_ratio[name].append(f["cpu_us_per_tx"] / ((a["cpu_us_per_tx"] + b["cpu_us_per_tx"]) / 2))
            raw_runs.append({k: statistics.mean(f[k] for f in raws) for k in ("tx_per_s", "cpu_us_per_tx")})
            engine_runs.append(bench_floors.engine_alone())

    def medians(runs_: list[Figures]) -> Figures:
        return {k: median([f[k] for f in runs_]) for k in runs_[0]}

    return {
        "server": "lean pty responder (benchmarks/lean_responder.py), answers at once",
        "runs": runs,
        "duration_s": duration,
        "drivers": [driver_name(d) for d in DRIVERS],
        "raw": {**medians(raw_runs), "per_run": raw_runs},
        "engine_alone": medians(engine_runs),
        "rows": [
            {
                "row": name,
                **medians(figures[name]),
                "rate_vs_raw": median(rate_ratio[name]),
                "cpu_vs_raw": median(cpu_ratio[name]),
                "rate_vs_raw_per_run": rate_ratio[name],
                "cpu_vs_raw_per_run": cpu_ratio[name],
            }
            for name, _ in rows
        ],
    }


def print_table(r: dict[str, Any]) -> None:
    raw = r["raw"]
    print(f"\nA. Client CPU per transaction against the lean responder (32 IDs, median of {r['runs']} runs)")
    print("   ratios against the raw blocking pyserial loop measured next to each row in the same run")
    print(f"  {'row':34} {'tx/s':>8} {'CPU us/tx':>10} {'rate/raw':>9} {'CPU/raw':>8}")
    print(
        f"  {'raw blocking pyserial (baseline)':34} {raw['tx_per_s']:8.0f} {raw['cpu_us_per_tx']:10.1f} "
        f"{1:9.2f} {1:8.2f}"
    )
    for row in r["rows"]:
        fails = f"  ({row['failures']:.0f} failed)" if row.get("failures") else ""
        name = "floor: os.write/poll/os.read" if row["row"] == "floor" else row["row"]
        print(
            f"  {name:34} {row['tx_per_s']:8.0f} {row['cpu_us_per_tx']:10.1f} {row['rate_vs_raw']:9.2f} "
            f"{row['cpu_vs_raw']:8.2f}{fails}"
        )
    if "engine_alone" in r:
        print_breakdown(r)


def breakdown(r: dict[str, Any]) -> list[dict[str, Any]]:
    """Where a stream transaction's CPU goes, per driver x loop: the layers under it, from this run's rows."""
    rows = {row["row"]: row for row in r["rows"]}
    floor = rows["floor"]["cpu_us_per_tx"]
    engine = r["engine_alone"]["cpu_us_per_tx"]
    out = []
    for row in r["rows"]:
        if not row["row"].startswith("stream "):
            continue
        driver, loop = row["row"][len("stream ") :].split("/")
        loop_floor = rows.get(f"loop floor stream {loop}")
        # The thread driver's hot loop is a poll loop of its own: its floor is the bare one.
        below = floor if driver == "thread" or loop_floor is None else loop_floor["cpu_us_per_tx"]
        out.append(
            {
                "row": row["row"],
                "total": row["cpu_us_per_tx"],
                "pty_and_syscalls": floor,
                "event_loop": below - floor,
                "engine_and_stream_alone": engine,
                "ours_beyond_the_floors": row["cpu_us_per_tx"] - below,
            }
        )
    return out


def print_breakdown(r: dict[str, Any]) -> None:
    print("\n   Where a stream transaction's CPU goes (us per transaction, this run's medians):")
    print("   floor = the bare os.write/poll/os.read loop (the pty and the system calls any client pays);")
    print("   loop = that event loop's own pass (its loop floor minus the floor; the thread driver has none);")
    print("   ours = everything above those floors: engine, stream, driver, run between system calls;")
    print(f"   engine alone = the engine and stream with no I/O at all: {r['engine_alone']['cpu_us_per_tx']:.1f} us")
    print(f"  {'row':26} {'total':>6} {'floor':>6} {'loop':>6} {'ours':>6}")
    for b in breakdown(r):
        print(
            f"  {b['row']:26} {b['total']:6.1f} {b['pty_and_syscalls']:6.1f} {b['event_loop']:6.1f} "
            f"{b['ours_beyond_the_floors']:6.1f}"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--duration", type=float, default=1.0)
    parser.add_argument("--json", action="store_true", help="print the figures as JSON, not the table")
    args = parser.parse_args()
    result = run(args.runs, args.duration)
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print_table(result)


if __name__ == "__main__":
    main()
