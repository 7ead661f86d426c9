"""Resident memory growth over 1,000,000 transactions, and in-process CPU cost.

Runs in a fresh child process per case so that nothing else in the
benchmark run shares its heap.  The far end is the in-process simulator in
fast mode (``VirtualLine(log_size=0)``: no transaction log), not the pty
server: a million transactions through it would take minutes, and memory
growth is a property of the client, not of the line.  The CPU figure therefore
includes the simulator's own work and is for scale only (the burst case
below answers from the lean pty responder, another process: its CPU is the
client's alone).

Cases: ``stream`` (a 32-ID stream with a consumer awaiting every frame),
``sequential`` (``await servo.set_position(...)`` in a loop) and ``stream burst``
(the same stream on the burst path: the compiled executor needs a descriptor, so
its far end is the lean pty responder, a process of its own; the case is left out
where the executor is not built).  RSS is read
from ``/proc/self/status`` (VmRSS) after a warm-up of ``WARMUP``
transactions, at 10 % of the run and at the end; ``ru_maxrss`` is reported
as well.

    .venv/bin/python benchmarks/bench_memory.py [--transactions 1000000] [--loop asyncio]
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from bench_common import (
    IDS,
    NEUTRAL,
    burst_path_built,
    burst_setting,
    executor_transactions,
    loop_names,
    run_on,
    vm_rss_kib,
)
from lean_responder import lean_lines

from ics35_async import open_bus
from ics35_async.sim import VirtualLine

WARMUP = 20_000
BURST_CASE = "stream burst"
CASES = ("stream", "sequential", BURST_CASE)


def child(case: str, transactions: int, loop: str) -> dict[str, Any]:
    if case == BURST_CASE:
        with burst_setting("1"), lean_lines(1) as (path,):
            return measure(case, path, transactions, loop)
    return measure(case, VirtualLine(IDS, log_size=0), transactions, loop)


def measure(case: str, device: Any, transactions: int, loop: str) -> dict[str, Any]:
    async def main() -> dict[str, Any]:
        async with open_bus(device, adapter_latency=0.003, quiet_time=0.001) as bus:
            marks: dict[str, int] = {}
            tenth = transactions // 10
            if case == "sequential":
                servos = bus.servos(IDS)
                for k in range(WARMUP):
                    await servos[k & 31].set_position(NEUTRAL)
                marks["start"] = vm_rss_kib()
                wall0, cpu0 = time.perf_counter(), time.process_time()
                for k in range(transactions):
                    if k == tenth:
                        marks["tenth"] = vm_rss_kib()
                    await servos[k & 31].set_position(NEUTRAL)
                done = transactions
            else:
                async with bus.stream(IDS) as stream:
                    stream.set_targets(dict.fromkeys(IDS, NEUTRAL))
                    cycles, warm = transactions // len(IDS), WARMUP // len(IDS)
                    frame = await stream.next_frame()
                    while frame.cycle < warm:
                        frame = await stream.next_frame()
                    marks["start"] = vm_rss_kib()
                    first = frame.cycle
                    wall0, cpu0 = time.perf_counter(), time.process_time()
                    while frame.cycle - first < cycles:
                        frame = await stream.next_frame()
                        if "tenth" not in marks and frame.cycle - first >= cycles // 10:
                            marks["tenth"] = vm_rss_kib()
                    done = (frame.cycle - first) * len(IDS)
            wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
            marks["end"] = vm_rss_kib()
            errors = bus.stats.total.errors
            in_executor = executor_transactions(bus)
        mib = 1 / 1024
        return {
            "case": case,
            "loop": loop,
            "transactions": done,
            "seconds": wall,
            "tx_per_s": done / wall,
            "cpu_us_per_tx_incl_sim": cpu / done * 1e6,
            "rss_start_mib": marks["start"] * mib,
            "rss_end_mib": marks["end"] * mib,
            "growth_mib": (marks["end"] - marks["start"]) * mib,
            # growth over the last 90 %, scaled to the whole run: the steady-state slope
            "growth_after_first_tenth_mib_per_run": (marks["end"] - marks["tenth"]) * mib / 0.9,
            "ru_maxrss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * mib,
            "errors": errors,
            "burst_transactions": in_executor,
        }

    return run_on(loop, main)


def run(
    transactions: int = 1_000_000, cases: tuple[str, ...] = CASES, loops: list[str] | None = None
) -> dict[str, Any]:
    rows = []
    if not burst_path_built():
        cases = tuple(c for c in cases if c != BURST_CASE)
    for loop in loops or loop_names()[:1]:
        for case in cases:
            proc = subprocess.run(
                [
                    sys.executable,
                    str(Path(__file__)),
                    "--child",
                    case,
                    "--transactions",
                    str(transactions),
                    "--loop",
                    loop,
                ],
                capture_output=True,
                text=True,
                check=True,
                timeout=600,
            )
            rows.append(json.loads(proc.stdout))
    return {
        "device": "in-process simulator, fast mode, log_size=0; the burst case: the lean pty responder "
        "(a child process per case)",
        "warmup_transactions": WARMUP,
        "rows": rows,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--transactions", type=int, default=1_000_000)
    parser.add_argument("--loop", default="asyncio")
    parser.add_argument("--child", choices=CASES, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(child(args.child, args.transactions, args.loop)))
    else:
        print(json.dumps(run(args.transactions, loops=[args.loop]), indent=2))


if __name__ == "__main__":
    main()
