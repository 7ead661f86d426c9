"""The same stream on the landed bus (before the engine) and on today's, in one run.

Issue 11 asks that the asyncio driver cost no more CPU per stream
transaction than the bus it replaced.  This section exports the package as
it was at ``BEFORE`` (the last commit before the engine) with ``git
archive``, then measures a 32-ID stream of free commands against the lean
responder in child processes, alternating before / after / before / after
..., each on the default asyncio loop and on uvloop.  Each child reports
its own ``time.process_time()`` over the measured stretch.

    .venv/bin/python benchmarks/bench_before_after.py [--runs 5] [--duration 1.0]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

from bench_common import median, progress
from lean_responder import lean_lines

BEFORE = "0f3cbbf"  # the landed main: Bus as one asyncio-callback class
ROOT = Path(__file__).resolve().parents[1]

CHILD = r"""
import asyncio, json, sys, time
loop_name, path, duration = sys.argv[1], sys.argv[2], float(sys.argv[3])
from ics35_async import open_bus

async def measure():
    async with open_bus(path, adapter_latency=0.010) as bus, bus.stream(range(32)) as st:
        first = await st.next_frame()
        while first.cycle < 5:
            first = await st.next_frame()
        wall0, cpu0 = time.perf_counter(), time.process_time()
        frame = first
        while time.perf_counter() - wall0 < duration:
            frame = await st.next_frame()
        cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
    n = (frame.cycle - first.cycle) * 32
    return {"cpu_us_per_tx": cpu / n * 1e6, "tx_per_s": n / wall}

if loop_name == "uvloop":
    import uvloop
    factory = uvloop.new_event_loop
else:
    factory = asyncio.new_event_loop
with asyncio.Runner(loop_factory=factory) as runner:
    print(json.dumps(runner.run(measure())))
"""


def export(rev: str, into: Path) -> Path:
    """The package as it was at ``rev``, unpacked under ``into``; returns the directory to put on sys.path."""
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", rev, "ics35_async"], capture_output=True, check=True)
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive.stdout, check=True)
    return into


def child(pythonpath: Path, loop: str, port: str, duration: float) -> dict[str, float]:
    env = {**os.environ, "PYTHONPATH": str(pythonpath)}
    out = subprocess.run(
        [sys.executable, "-c", CHILD, loop, port, str(duration)], env=env, capture_output=True, text=True, timeout=60
    )
    if out.returncode:
        raise RuntimeError(f"child failed: {out.stderr[-2000:]}")
    figures: dict[str, float] = json.loads(out.stdout)
    return figures


def run(runs: int = 5, duration: float = 1.0, before: str = BEFORE) -> dict[str, Any]:
    results: dict[str, Any] = {"before": before, "rows": {}}
    with tempfile.TemporaryDirectory() as tmp:
        old = export(before, Path(tmp))
        sides = {"before": old, "after": ROOT}
        with lean_lines(1) as (port,):
            for loop in ("asyncio", "uvloop"):
                samples: dict[str, list[dict[str, float]]] = {"before": [], "after": []}
                for k in range(runs):
                    progress(f"before/after {loop}: run {k + 1}/{runs}")
                    for side, path in sides.items():
                        samples[side].append(child(path, loop, port, duration))
                row: dict[str, Any] = {
                    side: {key: median([s[key] for s in ss]) for key in ("cpu_us_per_tx", "tx_per_s")}
                    for side, ss in samples.items()
                }
                row["cpu_after_over_before"] = row["after"]["cpu_us_per_tx"] / row["before"]["cpu_us_per_tx"]
                results["rows"][loop] = row
    return results


def print_table(r: dict[str, Any]) -> None:
    print(f"\nE. Stream CPU per transaction, landed bus ({r['before']}) vs today's asyncio driver (same run)")
    print("   32 IDs, free commands, lean responder; medians of alternating child processes")
    header = ("loop", "before us/tx", "after us/tx", "after/before", "tx/s before", "after")
    print("  {:10} {:>13} {:>12} {:>13} {:>12} {:>8}".format(*header))
    for loop, row in r["rows"].items():
        b, a = row["before"], row["after"]
        print(
            f"  {loop:10} {b['cpu_us_per_tx']:13.1f} {a['cpu_us_per_tx']:12.1f} {row['cpu_after_over_before']:13.2f}"
            f" {b['tx_per_s']:12.0f} {a['tx_per_s']:8.0f}"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--duration", type=float, default=1.0)
    parser.add_argument("--before", default=BEFORE)
    args = parser.parse_args()
    print_table(run(args.runs, args.duration, args.before))


if __name__ == "__main__":
    main()
