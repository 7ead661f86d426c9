"""The benchmark suite (``make bench``): prints a table with ratios and writes benchmarks/results.json.

Sections (each a ``bench_*.py`` module that also runs on its own):

1. host overhead over a pty, fast-mode simulator: sequential transactions
   and 32-ID stream against a raw blocking pyserial loop (bench_overhead);
2. wire efficiency against the real-time simulator at 115200, 625000 and
   1250000 bit/s (bench_wire);
3. sharing: stream plus 16 telemetry pollers (bench_sharing);
4. cost: client CPU per transaction (from 1) and memory growth over
   1,000,000 transactions (bench_memory);
5. event loops (asyncio, uvloop) x transports (direct, fast, stock): rows
   of 1 and 2;
6. a peer: rcb4's ICSServoController (bench_peer).

Every figure is a median of several runs; ratios are taken against a
baseline measured in the same run, next to the variant.  The machine is a
shared, noisy one: compare ratios, not absolute rates.  Nothing here is
asserted by the test suite.

    .venv/bin/python benchmarks/run.py [--quick] [--sections overhead,wire,...] [--runs N] [--output FILE]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import subprocess
import sys
import time
import traceback
from collections.abc import Callable
from importlib import metadata
from pathlib import Path
from typing import Any

import bench_memory
import bench_overhead
import bench_peer
import bench_sharing
import bench_wire
from bench_common import progress

HERE = Path(__file__).resolve().parent
SECTIONS = ("overhead", "wire", "sharing", "memory", "peer")

# The targets (see /work/notes/bench_readme.md for the analysis).
TARGET_STREAM_VS_RAW = 1.0
TARGET_WIRE_PCT = {115200: 97.0, 1250000: 70.0}
TARGET_P99_WAIT_TX = 3.0
TARGET_CPU_US = 25.0
TARGET_MEMORY_MIB = 2.0


def machine() -> dict[str, Any]:
    def version(dist: str) -> str | None:
        try:
            return metadata.version(dist)
        except metadata.PackageNotFoundError:
            return None

    model = ""
    with open("/proc/cpuinfo") as cpuinfo:
        for line in cpuinfo:
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=HERE, capture_output=True, text=True)
    dirty = subprocess.run(
        ["git", "status", "--porcelain", "ics35_async"], cwd=HERE.parent, capture_output=True, text=True
    )
    return {
        "date": time.strftime("%Y-%m-%d %H:%M:%S %Z"),
        "platform": platform.platform(),
        "python": platform.python_version(),
        "cpus": os.cpu_count(),
        "cpu_model": model,
        "load_average_at_start": os.getloadavg(),
        "git_commit": commit.stdout.strip() or None,
        "library_modified_since_commit": bool(dirty.stdout.strip()),
        "packages": {d: version(d) for d in ("pyserial", "pyserial-asyncio-fast", "pyserial-asyncio", "uvloop")},
    }


# ---------------------------------------------------------------------- the table


def fmt(x: float | None, spec: str = ".2f") -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "-"
    return format(x, spec)


def print_overhead(r: dict[str, Any]) -> None:
    raw = r["raw"]
    print(f"\n1+5. Host overhead over a pty, fast-mode simulator (median of {r['runs']} runs)")
    print("     ratio = our transactions/s over the raw blocking pyserial loop's, measured next to it in the same run")
    print(f"  {'variant':34} {'tx/s':>8} {'cycles/s':>9} {'CPU us/tx':>10} {'vs raw':>7}")
    print(
        f"  {'raw blocking pyserial (baseline)':34} {raw['tx_per_s']:8.0f} {raw['cycles_per_s']:9.1f} "
        f"{raw['cpu_us_per_tx']:10.1f} {1:7.2f}"
    )
    lean = r.get("lean")
    if lean:
        print(
            f"  {'lean os.write/poll/os.read (floor)':34} {lean['tx_per_s']:8.0f} {lean['cycles_per_s']:9.1f} "
            f"{lean['cpu_us_per_tx']:10.1f} {lean['vs_raw']:7.2f}"
        )
    for v in r["variants"]:
        name = f"{v['loop']}/{v['transport']}"
        seq, st = v["sequential"], v["stream"]
        print(
            f"  {'(a) sequential ' + name:34} {seq['tx_per_s']:8.0f} {'':9} {seq['cpu_us_per_tx']:10.1f} "
            f"{v['sequential_vs_raw']:7.2f}"
        )
        fails = f"  ({st['failures']:.0f} failed)" if st["failures"] else ""
        print(
            f"  {'(b) stream ' + name:34} {st['tx_per_s']:8.0f} {st['cycles_per_s']:9.1f} {st['cpu_us_per_tx']:10.1f} "
            f"{v['stream_vs_raw']:7.2f}{fails}"
        )


def print_wire(r: dict[str, Any]) -> None:
    print(f"\n2+5. Wire efficiency: 32-ID stream, real-time pty simulator (median of {r['runs']} runs)")
    print("     % of the wire limit (32 x 6 bytes x 11 bits / baud) and of wire + 100 us servo turnaround;")
    print("     overhead = what each transaction took beyond wire + turnaround; vs raw = over the raw pyserial loop")
    for b in r["bauds"]:
        print(
            f"  {b['baud']} bit/s: wire limit {b['wire_limit_cycles_per_s']:.1f} cycles/s, "
            f"with turnaround {b['wire_turnaround_limit_cycles_per_s']:.1f}"
        )
        print(
            f"    {'variant':22} {'cycles/s':>9} {'% wire':>7} {'% w+ta':>7} {'overhead us':>12} {'vs raw':>7} "
            f"{'CPU us/tx':>10}"
        )
        lean = [("lean loop (floor)", b["lean"], b["lean"]["cycles_per_s"] / b["raw"]["cycles_per_s"], None, 0)]
        rows = [("raw blocking pyserial", b["raw"], 1.0, None, 0), *lean] + [
            (f"{v['loop']}/{v['transport']}", v, v["vs_raw"], v["cpu_us_per_tx"], v["failed_transactions"])
            for v in b["variants"]
        ]
        for name, f, ratio, cpu, fails in rows:
            extra = f"  ({fails} failed)" if fails else ""
            print(
                f"    {name:22} {f['cycles_per_s']:9.1f} {f['pct_of_wire']:6.1f}% {f['pct_of_wire_turnaround']:6.1f}% "
                f"{f['host_overhead_us_per_tx']:12.0f} {ratio:7.2f} {fmt(cpu, '10.1f')}{extra}"
            )


def print_sharing(r: dict[str, Any]) -> None:
    print(
        f"\n3. Sharing: 32-ID stream + {r['pollers']} pollers (current + temperature, {r['poll_hz_each']:g} Hz each), "
        f"real-time pty, direct transport (median of {r['runs']} runs)"
    )
    print("   T = one position transaction's time (measured, stream alone); wait = latency - own transaction;")
    print("   stall = p99 - p50 of the stream's own time between frames with no pollers (host hiccups), in T;")
    print("   loss/used = stream rate loss over the share of line time the polls used (1.0 = no waste)")
    print(
        f"  {'baud':>8} {'loop':8} {'polling':9} {'T us':>6} {'polls/s':>8} {'lat p50':>8} {'lat p99':>8} "
        f"{'wait p50':>9} {'wait p99':>9} {'stall':>6} {'used':>6} {'loss':>6} {'loss/used':>9}"
    )
    for row in r["rows"]:
        print(
            f"  {row['baud']:8d} {row['loop']:8} {row['polling']:9} {row['position_tx_us']:6.0f} "
            f"{row['polls_per_s']:8.0f} {row['latency_p50_tx']:7.2f}T {row['latency_p99_tx']:7.2f}T "
            f"{row['wait_p50_tx']:8.2f}T {row['wait_p99_tx']:8.2f}T {row['stall_p99_tx']:5.1f}T "
            f"{row['line_share_used_by_polls']:6.1%} "
            f"{row['stream_rate_loss']:6.1%} {row['loss_per_line_time_used']:9.2f}"
        )


def print_memory(r: dict[str, Any]) -> None:
    print(f"\n4. Memory over {r['rows'][0]['transactions']:,} transactions ({r['device']})")
    print(
        f"  {'case':12} {'loop':8} {'seconds':>8} {'RSS start MiB':>14} {'growth MiB':>11} {'steady MiB':>11} "
        f"{'maxrss MiB':>11} {'CPU us/tx incl. sim':>20}"
    )
    for row in r["rows"]:
        print(
            f"  {row['case']:12} {row['loop']:8} {row['seconds']:8.1f} {row['rss_start_mib']:14.1f} "
            f"{row['growth_mib']:11.2f} {row['growth_after_first_tenth_mib_per_run']:11.2f} "
            f"{row['ru_maxrss_mib']:11.1f} {row['cpu_us_per_tx_incl_sim']:20.1f}"
        )


def print_peer(r: dict[str, Any]) -> None:
    print(f"\n6. Peer: {r['peer']} over the same fast-mode pty server")
    if "peer_tx_per_s" not in r:
        print(f"  {r['status']}")
        return
    print(f"  rcb4 {r['rcb4_version']} (parity: {r['parity_used']})")
    print(f"  {'':34} {'tx/s':>8} {'vs raw':>7}")
    print(f"  {'raw blocking pyserial (baseline)':34} {r['raw_tx_per_s']:8.0f} {1:7.2f}")
    print(
        f"  {'rcb4 set_angle loop':34} {r['peer_tx_per_s']:8.0f} {r['peer_vs_raw']:7.3f}   "
        f"(CPU {r['peer_cpu_us_per_tx']:.0f} us/tx)"
    )
    print(
        f"  {'ours: servo.set_position loop':34} {r['ours_sequential_tx_per_s']:8.0f}   = {r['ours_vs_peer']:.1f}x rcb4"
    )


# ---------------------------------------------------------------------- targets


def targets(results: dict[str, Any]) -> list[dict[str, Any]]:
    out: list[dict[str, Any]] = []

    def add(name: str, measured: str, target: str, met: bool | None) -> None:
        out.append({"target": name, "measured": measured, "goal": target, "met": met})

    ov = results.get("overhead")
    if isinstance(ov, dict) and "variants" in ov:
        by = {(v["loop"], v["transport"]): v for v in ov["variants"]}
        default = by.get(("asyncio", "direct"))
        best = max(ov["variants"], key=lambda v: v["stream_vs_raw"])
        if default:
            add(
                "32-ID stream vs raw pyserial loop (fast pty)",
                f"{default['stream_vs_raw']:.2f}x asyncio/direct; best {best['stream_vs_raw']:.2f}x "
                f"{best['loop']}/{best['transport']}",
                f">= {TARGET_STREAM_VS_RAW}x",
                default["stream_vs_raw"] >= TARGET_STREAM_VS_RAW,
            )
            cpu = default["stream"]["cpu_us_per_tx"]
            best_cpu = min(ov["variants"], key=lambda v: v["stream"]["cpu_us_per_tx"])
            add(
                "client CPU per position transaction (stream)",
                f"{cpu:.1f} us asyncio/direct (sequential {default['sequential']['cpu_us_per_tx']:.1f}); best "
                f"{best_cpu['stream']['cpu_us_per_tx']:.1f} us {best_cpu['loop']}/{best_cpu['transport']}; "
                f"raw pyserial {ov['raw']['cpu_us_per_tx']:.1f} us",
                f"<= {TARGET_CPU_US:g} us",
                cpu <= TARGET_CPU_US,
            )
    wire = results.get("wire")
    if isinstance(wire, dict) and "bauds" in wire:
        for b in wire["bauds"]:
            goal = TARGET_WIRE_PCT.get(b["baud"])
            if goal is None:
                continue
            by = {(v["loop"], v["transport"]): v for v in b["variants"]}
            d = by.get(("asyncio", "direct"))
            best = max(b["variants"], key=lambda v: v["cycles_per_s"])
            if d:
                add(
                    f"wire efficiency at {b['baud']} (real-time pty)",
                    f"{d['pct_of_wire']:.1f}% of wire ({d['pct_of_wire_turnaround']:.1f}% of wire+turnaround) "
                    f"asyncio/direct; best {best['pct_of_wire']:.1f}% ({best['pct_of_wire_turnaround']:.1f}%) "
                    f"{best['loop']}/{best['transport']}; raw pyserial {b['raw']['pct_of_wire']:.1f}% "
                    f"({b['raw']['pct_of_wire_turnaround']:.1f}%)",
                    f">= {goal:g}% of wire",
                    d["pct_of_wire"] >= goal,
                )
    sh = results.get("sharing")
    if isinstance(sh, dict) and "rows" in sh:
        paced = [r for r in sh["rows"] if r["polling"] == "paced"]
        if paced:
            worst = max(paced, key=lambda r: r["wait_p99_tx"])
            summary = "; ".join(f"{r['baud']} {r['loop']}: {r['wait_p99_tx']:.2f}T" for r in paced)
            add(
                "telemetry p99 wait while streaming",
                summary,
                f"<= {TARGET_P99_WAIT_TX:g} position-transaction times",
                worst["wait_p99_tx"] <= TARGET_P99_WAIT_TX,
            )
    mem = results.get("memory")
    if isinstance(mem, dict) and "rows" in mem:
        worst_mem = max(mem["rows"], key=lambda r: r["growth_mib"])
        per_1m = worst_mem["growth_mib"] * 1e6 / worst_mem["transactions"]
        add(
            "memory growth per 1M transactions",
            "; ".join(f"{r['case']} {r['loop']}: {r['growth_mib']:.2f} MiB" for r in mem["rows"]),
            f"< {TARGET_MEMORY_MIB:g} MiB",
            per_1m < TARGET_MEMORY_MIB,
        )
    return out


def print_targets(rows: list[dict[str, Any]]) -> None:
    print("\nTargets (issue 7)")
    for r in rows:
        status = {True: "MET", False: "NOT MET", None: "?"}[r["met"]]
        print(f"  [{status:7}] {r['target']}: {r['measured']}  (goal {r['goal']})")


# ---------------------------------------------------------------------- main


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="fewer, shorter runs (a smoke test; about 2 minutes)")
    parser.add_argument(
        "--sections", default=",".join(SECTIONS), help=f"comma-separated subset of {','.join(SECTIONS)}"
    )
    parser.add_argument("--runs", type=int, default=None, help="runs per figure (default 5 for overhead, 3 elsewhere)")
    parser.add_argument("--output", default=str(HERE / "results.json"), help="where to write the JSON results")
    args = parser.parse_args()
    sections = [s.strip() for s in args.sections.split(",") if s.strip()]
    unknown = set(sections) - set(SECTIONS)
    if unknown:
        parser.error(f"unknown section(s): {', '.join(sorted(unknown))}")

    quick = args.quick
    runs = args.runs
    plans: dict[str, Callable[[], dict[str, Any]]] = {
        "overhead": lambda: bench_overhead.run(runs or (2 if quick else 5), 0.3 if quick else 0.5),
        "wire": lambda: bench_wire.run(runs or (1 if quick else 3), 0.6 if quick else 1.0),
        "sharing": lambda: bench_sharing.run(runs or (1 if quick else 3), 1.0 if quick else 1.5, 1.5 if quick else 2.5),
        "memory": lambda: bench_memory.run(
            100_000 if quick else 1_000_000, loops=None if quick else ["asyncio", "uvloop"]
        ),
        "peer": lambda: bench_peer.run(runs or (1 if quick else 3), 0.5 if quick else 1.0),
    }
    results: dict[str, Any] = {"meta": {**machine(), "quick": quick, "sections": sections}}
    started = time.perf_counter()
    for name in sections:
        progress(f"section {name}")
        t0 = time.perf_counter()
        try:
            results[name] = plans[name]()
        except Exception as exc:  # keep the other sections' figures
            traceback.print_exc()
            results[name] = {"error": f"{type(exc).__name__}: {exc}"}
        results[name]["seconds"] = time.perf_counter() - t0
    results["meta"]["seconds"] = time.perf_counter() - started
    results["meta"]["load_average_at_end"] = os.getloadavg()
    results["targets"] = targets(results)

    m = results["meta"]
    local = " (+ local changes)" if m["library_modified_since_commit"] else ""
    print(
        f"\nics35_async benchmarks, {m['date']}: {m['cpu_model']}, {m['cpus']} CPUs, {m['platform']}, "
        f"Python {m['python']}, commit {m['git_commit']}{local}"
    )
    print(
        f"load average at start {m['load_average_at_start'][0]:.2f}, at end {m['load_average_at_end'][0]:.2f}; "
        "a shared, noisy machine: compare the ratios (measured side by side), not the absolute rates"
    )
    printers = {
        "overhead": print_overhead,
        "wire": print_wire,
        "sharing": print_sharing,
        "memory": print_memory,
        "peer": print_peer,
    }
    for name in sections:
        if "error" in results[name]:
            print(f"\n{name}: FAILED: {results[name]['error']}")
        else:
            printers[name](results[name])
    print_targets(results["targets"])
    Path(args.output).write_text(json.dumps(results, indent=2) + "\n")
    print(f"\nwrote {args.output} in {m['seconds']:.0f} s")
    return 1 if any("error" in results[s] for s in sections) else 0


if __name__ == "__main__":
    sys.exit(main())
