"""Many lines at once: 4 lines x 32 servos streamed together, wire-timed at 1.25 Mbit/s, against one line.

The far end is :mod:`lean_responder` in wire mode: one process serving
every line, each answer held back until its transaction would have ended on
the wire (6 bytes x 11 bits at the baud rate, 52.8 us at 1.25 Mbit/s), so
one line can do at most the wire limit.  Measured in one run, interleaved:

* ``raw``: a blocking pyserial loop on one line (the synchronous reference);
* ``1 line``: ``BusGroup`` with one bus, a 32-ID stream (every ID free);
* ``4 lines``: ``BusGroup`` with four buses, ``group.stream({line: ids})``.

The aggregate is the sum of every line's cycles per second (each line's own
cycle count, ``GroupFrame.line_cycles``); the ratio against one line's is the
figure the issue sets (>= 3.6x).  The client is one process: on a machine
with few cores its CPU, not the wires, bounds the aggregate.

    .venv/bin/python benchmarks/bench_lines.py [--runs 3] [--duration 1.5] [--lines 4] [--baud 1250000]
"""

from __future__ import annotations

import argparse
import json
import os
import time
from typing import Any

from bench_common import IDS, loop_names, median, progress, run_on, wire_cycle_time
from bench_cpu import DRIVERS, bus_options, driver_name
from bench_overhead import raw_loop
from lean_responder import lean_lines

from ics35_async import BusGroup

Figures = dict[str, Any]


def cpu_ticks() -> tuple[int, int]:
    """(busy, total) jiffies of every core together, from /proc/stat."""
    with open("/proc/stat") as stat:
        fields = [int(x) for x in stat.readline().split()[1:]]
    idle = fields[3] + fields[4]  # idle + iowait
    total = sum(fields[:8])  # guest time is already counted in user
    return total - idle, total


def group_stream(
    paths: list[str], driver: str | None, loop: str, baud: int, duration: float, warmup_s: float = 0.2
) -> Figures:
    """Stream 32 IDs on every path at once; cycles per second per line and in all, client CPU per transaction."""

    async def measure() -> Figures:
        ports = {str(k): p for k, p in enumerate(paths)}
        async with (
            BusGroup.open(ports, baudrate=baud, **bus_options(driver)) as group,
            group.stream(dict.fromkeys(ports, IDS)) as gs,
        ):
            t_warm = time.perf_counter() + warmup_s
            first = await gs.next_frame()
            while time.perf_counter() < t_warm:
                first = await gs.next_frame()
            wall0, cpu0, ticks0 = time.perf_counter(), time.process_time(), cpu_ticks()
            frame = first
            while (now := time.perf_counter()) - wall0 < duration:
                frame = await gs.next_frame()
            cpu = time.process_time() - cpu0
            ticks1 = cpu_ticks()
            failures = sum(sum(s.failures.values()) for s in gs.stats.values())
        wall = now - wall0
        per_line = [(frame.line_cycles[k] - first.line_cycles[k]) / wall for k in ports]
        total = sum(per_line)
        return {
            "lines": len(paths),
            "cycles_per_s_per_line": per_line,
            "aggregate_cycles_per_s": total,
            "cpu_us_per_tx": cpu / (total * wall * len(IDS)) * 1e6 if total else float("nan"),
            "failures": failures,
            # How busy the whole machine was (this client, the responder, the kernel, other tenants),
            # and this client's share of all cores: 1.0 means no core had time to spare.
            "machine_busy": (ticks1[0] - ticks0[0]) / max(1, ticks1[1] - ticks0[1]),
            "client_share": cpu / (wall * (os.cpu_count() or 1)),
        }

    return run_on(loop, measure)


def run(runs: int = 3, duration: float = 1.5, lines: int = 4, baud: int = 1250000) -> dict[str, Any]:
    """Raw on one line, then each driver x loop on one line and on ``lines`` lines, ``runs`` times."""
    variants = [(d, lp) for d in DRIVERS for lp in loop_names()]
    raw: list[float] = []
    one: dict[str, list[Figures]] = {}
    many: dict[str, list[Figures]] = {}
    with lean_lines(lines, baud=baud, wire=True) as paths:
        for r in range(runs):
            progress(f"lines: run {r + 1}/{runs}")
            raw.append(raw_loop(paths[0], duration, baud=baud)["cycles_per_s"])
            for driver, loop in variants:
                name = f"{driver_name(driver)}/{loop}"
                one.setdefault(name, []).append(group_stream(paths[:1], driver, loop, baud, duration))
                many.setdefault(name, []).append(group_stream(paths, driver, loop, baud, duration))
    rows = []
    for name in one:
        one_rate = median([f["aggregate_cycles_per_s"] for f in one[name]])
        many_rate = median([f["aggregate_cycles_per_s"] for f in many[name]])
        ratios = [
            m["aggregate_cycles_per_s"] / o["aggregate_cycles_per_s"]
            for o, m in zip(one[name], many[name], strict=True)
        ]
        rows.append(
            {
                "variant": name,
                "one_line_cycles_per_s": one_rate,
                "one_line_cpu_us_per_tx": median([f["cpu_us_per_tx"] for f in one[name]]),
                "aggregate_cycles_per_s": many_rate,
                "aggregate_cpu_us_per_tx": median([f["cpu_us_per_tx"] for f in many[name]]),
                "aggregate_vs_one_line": median(ratios),
                "machine_busy_all_lines": median([f["machine_busy"] for f in many[name]]),
                "client_share_all_lines": median([f["client_share"] for f in many[name]]),
                "aggregate_vs_one_line_per_run": ratios,
                "failures": sum(f["failures"] for f in one[name] + many[name]),
                "per_run": {"one": one[name], "many": many[name]},
            }
        )
    return {
        "server": f"lean responder, wire-timed at {baud} bit/s, one process for all lines",
        "runs": runs,
        "lines": lines,
        "baud": baud,
        "wire_limit_cycles_per_s": 1 / wire_cycle_time(baud),
        "raw_one_line_cycles_per_s": median(raw),
        "rows": rows,
    }


def print_table(r: dict[str, Any]) -> None:
    print(
        f"\nB. Many lines: {r['lines']} lines x 32 servos streamed together, wire-timed at {r['baud']} bit/s "
        f"(median of {r['runs']} runs)"
    )
    print(
        f"   wire limit {r['wire_limit_cycles_per_s']:.0f} cycles/s per line; raw blocking pyserial on one line "
        f"{r['raw_one_line_cycles_per_s']:.0f} cycles/s"
    )
    print(
        "   busy = the whole machine's CPU use while all lines ran (every core; 100 % = none to spare); "
        "client = this process's share of it"
    )
    print(
        f"  {'variant':20} {'1 line cyc/s':>12} {'CPU us/tx':>10} {'all lines cyc/s':>16} {'CPU us/tx':>10} "
        f"{'x one':>6} {'busy':>6} {'client':>7}"
    )
    for row in r["rows"]:
        fails = f"  ({row['failures']} failed)" if row["failures"] else ""
        print(
            f"  {row['variant']:20} {row['one_line_cycles_per_s']:12.0f} {row['one_line_cpu_us_per_tx']:10.1f} "
            f"{row['aggregate_cycles_per_s']:16.0f} {row['aggregate_cpu_us_per_tx']:10.1f} "
            f"{row['aggregate_vs_one_line']:6.2f} {row.get('machine_busy_all_lines', float('nan')):6.0%} "
            f"{row.get('client_share_all_lines', float('nan')):7.0%}{fails}"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--duration", type=float, default=1.5)
    parser.add_argument("--lines", type=int, default=4)
    parser.add_argument("--baud", type=int, default=1250000)
    parser.add_argument("--json", action="store_true", help="print the figures as JSON, not the table")
    args = parser.parse_args()
    result = run(args.runs, args.duration, args.lines, args.baud)
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print_table(result)


if __name__ == "__main__":
    main()
