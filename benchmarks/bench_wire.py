"""Wire efficiency: a 32-ID stream against the real-time simulator, as a share of the wire limit.

The simulator's pty server runs in real-time mode (``--realtime --baud B``):
it delivers each echo and reply no earlier than its modelled wire time
(11 bits a byte, plus a 100 us servo turnaround before each reply), from
another process, so the pty's and both processes' latency count as they
would with a USB adapter.  The limits (spec section 11):

* wire limit: 32 x 6 bytes x 11 bits / baud per cycle (54.5 cycles/s at
  115200, 592 at 1250000);
* wire + turnaround limit: the same plus 32 x 100 us (what the simulator
  can deliver at best).

The raw blocking pyserial loop (same bytes) is measured in the same run as
the baseline, and a lean ``os.write``/``poll``/``os.read`` loop as the floor
that the pty and the simulator leave to any client.

    .venv/bin/python benchmarks/bench_wire.py [--runs 3] [--duration 1.0]
"""

from __future__ import annotations

import argparse
import json
import statistics
from typing import Any

from bench_common import IDS, SIM_TURNAROUND, TRANSPORTS, loop_names, median, progress, pty_sim, wire_cycle_time
from bench_overhead import api_stream, lean_loop, raw_loop

BAUDS = (115200, 625000, 1250000)


def describe(rate: float, baud: int) -> dict[str, float]:
    """A cycle rate as shares of the limits, and what each transaction took beyond the model."""
    modelled_tx = wire_cycle_time(baud, 1, turnaround=SIM_TURNAROUND)
    return {
        "cycles_per_s": rate,
        "pct_of_wire": 100 * rate * wire_cycle_time(baud),
        "pct_of_wire_turnaround": 100 * rate * wire_cycle_time(baud, turnaround=SIM_TURNAROUND),
        "host_overhead_us_per_tx": (1 / rate / len(IDS) - modelled_tx) * 1e6,
    }


def run(runs: int = 3, duration: float = 1.0, bauds: tuple[int, ...] = BAUDS) -> dict[str, Any]:
    loops = loop_names()
    variants = [(lp, t) for lp in loops for t in TRANSPORTS]
    out: dict[str, Any] = {
        "server": "pty, real-time mode (python -m ics35_async.sim --ids 0-31 --realtime --baud B)",
        "runs": runs,
        "turnaround_s": SIM_TURNAROUND,
        "bauds": [],
    }
    for baud in bauds:
        raw_rates: list[float] = []
        lean_rates: list[float] = []
        rates: dict[tuple[str, str], list[float]] = {v: [] for v in variants}
        ratios: dict[tuple[str, str], list[float]] = {v: [] for v in variants}
        failures: dict[tuple[str, str], int] = dict.fromkeys(variants, 0)
        cpu: dict[tuple[str, str], list[float]] = {v: [] for v in variants}
        with pty_sim("--realtime", "--baud", str(baud)) as path:
            for r in range(runs):
                progress(f"wire {baud}: run {r + 1}/{runs}")
                # raw, the variants of one loop, raw, those of the next loop, ..., raw
                raws = [raw_loop(path, duration, baud=baud)["cycles_per_s"]]
                lean_rates.append(lean_loop(path, duration, baud=baud)["cycles_per_s"])
                for loop in loops:
                    group = {v: api_stream(path, *v, duration, baud=baud) for v in variants if v[0] == loop}
                    raws.append(raw_loop(path, duration, baud=baud)["cycles_per_s"])
                    base = (raws[-2] + raws[-1]) / 2
                    for v, f in group.items():
                        rates[v].append(f["cycles_per_s"])
                        ratios[v].append(f["cycles_per_s"] / base)
                        failures[v] += f["failures"]
                        cpu[v].append(f["cpu_us_per_tx"])
                raw_rates.append(statistics.mean(raws))

        entry: dict[str, Any] = {
            "baud": baud,
            "wire_limit_cycles_per_s": 1 / wire_cycle_time(baud),
            "wire_turnaround_limit_cycles_per_s": 1 / wire_cycle_time(baud, turnaround=SIM_TURNAROUND),
            "raw": {**describe(median(raw_rates), baud), "per_run": raw_rates},
            "lean": {**describe(median(lean_rates), baud), "per_run": lean_rates},
            "variants": [],
        }
        for v in variants:
            entry["variants"].append(
                {
                    "loop": v[0],
                    "transport": v[1],
                    **describe(median(rates[v]), baud),
                    "vs_raw": median(ratios[v]),
                    "cpu_us_per_tx": median(cpu[v]),
                    "failed_transactions": failures[v],
                    "per_run": rates[v],
                }
            )
        out["bauds"].append(entry)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--duration", type=float, default=1.0)
    args = parser.parse_args()
    print(json.dumps(run(args.runs, args.duration), indent=2))


if __name__ == "__main__":
    main()
