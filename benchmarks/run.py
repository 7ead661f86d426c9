"""The benchmark suite (``make bench``): prints one report with ratios and writes benchmarks/results.json.

Sections (each a ``bench_*.py`` module that also runs on its own):

A. cpu: client CPU per transaction and rate against a lean pty responder
   (benchmarks/lean_responder.py): raw blocking pyserial, the os.write/poll/
   os.read floor, and each driver x event loop, sequential and stream
   (bench_cpu);
B. lines: 4 lines x 32 servos streamed together, wire-timed at 1.25 Mbit/s,
   against one line (bench_lines);
C. startup: ``import ics35_async`` and ``ics35 --version`` (bench_tools);
D. scan: ``ics35 scan`` (3 rates x 32 IDs, 3 servos) and ``ics35 set-id`` on
   the real-time pty simulator (bench_tools);
1. host overhead over a pty, fast-mode simulator: sequential transactions
   and 32-ID stream against a raw blocking pyserial loop (bench_overhead);
2. wire efficiency against the real-time simulator at 115200, 625000 and
   1250000 bit/s (bench_wire);
3. sharing: stream plus 16 telemetry pollers (bench_sharing);
4. cost: memory growth over 1,000,000 transactions (bench_memory);
5. event loops (asyncio, uvloop) x transports (direct, thread): rows
   of 1 and 2;
6. a peer: rcb4's ICSServoController (bench_peer);
7. the USB adapter: 32-servo cycle rates behind the FTDI model at latency
   timer 16 and 1 ms, next to the wire's limit, and the stream's (bench_adapter);
8. the control loop: a 12-servo stream at 100 Hz on a wire-timed 1.25 Mbit/s
   line, alone, with four flat-out pollers, at 5% faults and with a servo
   offline, in real time and in simulated time (bench_control_loop);
9. the burst path (compiled executor) against the ordinary path, blocking pyserial and the
   bare loop: stream CPU and wire-timed rate, four lines, a CPU-bound thread beside a stream,
   sequential and batched requests (bench_burst);
10. the web configurator: a 32-servo stream's rate with the Live plots page
    open against none, and the server's CPU per page update (bench_web; needs
    the ``web`` extra).

The report ends with one summary table (every headline figure, its goal
met or not; bench_targets).  Every figure is a median of several runs; ratios are taken against a
baseline measured in the same run, next to the variant.  The machine is a
shared, noisy one: compare ratios, not absolute rates.  Nothing here is
asserted by the test suite.

Only a full run (every section, not ``--quick``) writes the tracked
benchmarks/results.json by default; a ``--quick`` run writes
benchmarks/results-quick.json and a run of some sections
benchmarks/results-partial.json (both ignored by git), unless ``--out`` names
a file.

    .venv/bin/python benchmarks/run.py [--quick] [--sections cpu,lines,...] [--runs N] [--out FILE]
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

import bench_adapter
import bench_burst
import bench_control_loop
import bench_cpu
import bench_lines
import bench_memory
import bench_overhead
import bench_peer
import bench_sharing
import bench_tools
import bench_web
import bench_wire
from bench_common import progress
from bench_targets import print_targets, targets

from ics35_async.drivers.burst import burst_path

HERE = Path(__file__).resolve().parent
SECTIONS = (
    "cpu",
    "lines",
    "startup",
    "scan",
    "overhead",
    "wire",
    "sharing",
    "memory",
    "peer",
    "adapter",
    "control_loop",
    "burst",
    "web",
)


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
        # The rows that do not choose a path (all but the burst section's) run the one this names.
        "compiled_stream_path": burst_path()[1],
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
        f"{'maxrss MiB':>11} {'CPU us/tx (+in-process sim)':>28}"
    )
    for row in r["rows"]:
        print(
            f"  {row['case']:12} {row['loop']:8} {row['seconds']:8.1f} {row['rss_start_mib']:14.1f} "
            f"{row['growth_mib']:11.2f} {row['growth_after_first_tenth_mib_per_run']:11.2f} "
            f"{row['ru_maxrss_mib']:11.1f} {row['cpu_us_per_tx_incl_sim']:28.1f}"
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


# ---------------------------------------------------------------------- main


def default_output(quick: bool, sections: list[str]) -> Path:
    """The tracked results.json only for a full run: a smoke test or a subset must not replace its figures."""
    if quick:
        return HERE / "results-quick.json"
    if set(sections) != set(SECTIONS):
        return HERE / "results-partial.json"
    return HERE / "results.json"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="fewer, shorter runs (a smoke test; about 2 minutes)")
    parser.add_argument(
        "--sections", default=",".join(SECTIONS), help=f"comma-separated subset of {','.join(SECTIONS)}"
    )
    parser.add_argument("--runs", type=int, default=None, help="runs per figure (default 5 for overhead, 3 elsewhere)")
    parser.add_argument(
        "--out",
        "--output",
        dest="out",
        default=None,
        help="where to write the JSON results (default: results.json for a full run, else results-quick.json "
        "or results-partial.json, both ignored by git)",
    )
    args = parser.parse_args()
    sections = [s.strip() for s in args.sections.split(",") if s.strip()]
    unknown = set(sections) - set(SECTIONS)
    if unknown:
        parser.error(f"unknown section(s): {', '.join(sorted(unknown))}")

    quick = args.quick
    runs = args.runs
    plans: dict[str, Callable[[], dict[str, Any]]] = {
        "cpu": lambda: bench_cpu.run(runs or (1 if quick else 3), 0.3 if quick else 1.0),
        "lines": lambda: bench_lines.run(runs or (1 if quick else 3), 0.6 if quick else 1.5),
        "startup": lambda: bench_tools.run(2 if quick else 5, ("imports",)),
        "scan": lambda: bench_tools.run(1 if quick else 2, ("scan", "set_id")),
        "overhead": lambda: bench_overhead.run(runs or (2 if quick else 5), 0.3 if quick else 0.5),
        "wire": lambda: bench_wire.run(runs or (1 if quick else 3), 0.6 if quick else 1.0),
        "sharing": lambda: bench_sharing.run(runs or (1 if quick else 3), 1.0 if quick else 1.5, 1.5 if quick else 2.5),
        "memory": lambda: bench_memory.run(
            100_000 if quick else 1_000_000, loops=None if quick else ["asyncio", "uvloop"]
        ),
        "peer": lambda: bench_peer.run(runs or (1 if quick else 3), 0.5 if quick else 1.0),
        "adapter": lambda: bench_adapter.run(runs or (1 if quick else 2)),
        "control_loop": lambda: bench_control_loop.run(2.0 if quick else 5.0),
        "burst": lambda: bench_burst.run(runs or (1 if quick else 3), 0.5 if quick else 1.0),
        "web": lambda: bench_web.run(1.0 if quick else 2.0, runs or (1 if quick else 4)),
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
    print(f"compiled stream path: {m.get('compiled_stream_path', 'not recorded')}")
    printers: dict[str, Callable[[dict[str, Any]], None]] = {
        "cpu": bench_cpu.print_table,
        "lines": bench_lines.print_table,
        "startup": bench_tools.print_startup,
        "scan": bench_tools.print_line_tools,
        "overhead": print_overhead,
        "wire": print_wire,
        "sharing": print_sharing,
        "memory": print_memory,
        "peer": print_peer,
        "adapter": bench_adapter.print_table,
        "control_loop": bench_control_loop.print_table,
        "burst": bench_burst.print_table,
        "web": bench_web.print_table,
    }
    for name in sections:
        if "error" in results[name]:
            print(f"\n{name}: FAILED: {results[name]['error']}")
        else:
            printers[name](results[name])
    print_targets(results["targets"])
    out = Path(args.out) if args.out else default_output(quick, sections)
    out.write_text(json.dumps(results, indent=2) + "\n")
    print(f"\nwrote {out} in {m['seconds']:.0f} s")
    return 1 if any("error" in results[s] for s in sections) else 0


if __name__ == "__main__":
    sys.exit(main())
