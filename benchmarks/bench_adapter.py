"""The USB adapter: what an FTDI latency timer does to a 32-servo cycle, and how close the stream gets.

Three figures a cycle of 32 position transactions at 115200 bit/s:

* the wire's limit (32 x (6 bytes x 11 bits / baud + 100 us turnaround));
* the adapter-bound rate at latency timer 16 ms (FTDI's default) and 1 ms:
  the FTDI model (``ics35_async.transports.usb_timing``) driven by an ideal
  host that writes the moment a reply is whole (computed, not timed);
* the stream's measured rate against the real-time pty simulator behind that
  same model (``python -m ics35_async.sim --adapter ftdi --latency-timer N``),
  as a share of the adapter-bound rate (the goal: at least 95%), next to a
  raw blocking pyserial loop's over the same simulator in the same run (the
  baseline: what any client gets from this machine and the pty).

The adapter bound assumes the host writes its next command within the USB
frame in which a reply arrived; a host that takes longer (a loaded machine,
the pty's own latency) waits one more frame, for the raw loop and the
stream alike.

Short on purpose: at 16 ms a cycle takes half a second, so a run is a few
cycles (about 5 s in all with the 1 ms case).

    .venv/bin/python benchmarks/bench_adapter.py [--runs 1]
"""

from __future__ import annotations

import argparse
import json
import time
from typing import Any

from bench_common import IDS, NEUTRAL, median, progress, pty_sim, run_on
from bench_overhead import raw_loop

from ics35_async import open_bus
from ics35_async.transports.usb_timing import FtdiAdapter, adapter_cycle_time

BAUD = 115200
TIMERS_MS = (16, 1)
DURATION_S = {16: 2.2, 1: 1.0}  # about 4 cycles at 16 ms, 15 at 1 ms


def stream_rate(path: str, duration: float) -> dict[str, float]:
    """A 32-ID stream's cycle rate (cycles between two frames over the wall time between them)."""

    async def measure() -> dict[str, float]:
        # Default timing: its 20 ms adapter allowance is made for a 16 ms latency timer.
        async with open_bus(path, baudrate=BAUD) as bus, bus.stream(IDS) as stream:
            stream.set_targets(dict.fromkeys(IDS, NEUTRAL))
            first = await stream.next_frame()  # the first cycle also settles the timer's phase
            start = time.perf_counter()
            frame = first
            while (now := time.perf_counter()) - start < duration:
                frame = await stream.next_frame()
            failures = sum(stream.stats.failures.values())
        return {"cycles_per_s": (frame.cycle - first.cycle) / (now - start), "failures": failures}

    return run_on("asyncio", measure)


def run(runs: int = 1) -> dict[str, Any]:
    wire = 1 / adapter_cycle_time(None, servos=len(IDS), baudrate=BAUD)
    out: dict[str, Any] = {"baud": BAUD, "servos": len(IDS), "runs": runs, "wire_limit_cycles_per_s": wire, "rows": []}
    for timer in TIMERS_MS:
        bound = 1 / adapter_cycle_time(FtdiAdapter(timer), servos=len(IDS), baudrate=BAUD)
        rates: list[float] = []
        raw_rates: list[float] = []
        failures = 0.0
        server = ("--baud", str(BAUD), "--adapter", "ftdi", "--latency-timer", str(timer))
        for n in range(runs):
            progress(f"adapter: latency timer {timer} ms, run {n + 1}/{runs}")
            # A fresh simulator each: the raw loop's 8N1 open and its last bytes must not touch the stream's.
            with pty_sim(*server) as path:
                raw_rates.append(raw_loop(path, DURATION_S[timer])["cycles_per_s"])
            with pty_sim(*server) as path:
                measured = stream_rate(path, DURATION_S[timer])
            rates.append(measured["cycles_per_s"])
            failures += measured["failures"]
        rate, raw = median(rates), median(raw_rates)
        out["rows"].append(
            {
                "latency_timer_ms": timer,
                "adapter_bound_cycles_per_s": bound,
                "raw_pyserial_cycles_per_s": raw,
                "stream_cycles_per_s": rate,
                "stream_vs_bound": rate / bound,
                "raw_vs_bound": raw / bound,
                "stream_vs_raw": rate / raw,
                "failures": failures,
            }
        )
    return out


def print_table(r: dict[str, Any]) -> None:
    print(f"\n7. USB adapter: 32 servos at {r['baud']} bit/s behind the FTDI model (median of {r['runs']} runs)")
    print("   bound = the model with an ideal host (computed); raw = blocking pyserial loop, stream = ours, both")
    print("   measured against the real-time pty simulator behind the same model (goal: stream >= 95% of bound)")
    print(f"  {'':24} {'bound/s':>8} {'raw/s':>7} {'stream/s':>9} {'vs bound':>9} {'raw vs bound':>13} {'vs raw':>7}")
    print(f"  {'wire limit (no adapter)':24} {r['wire_limit_cycles_per_s']:8.1f}")
    for row in r["rows"]:
        fails = f"  ({row['failures']:.0f} failed)" if row["failures"] else ""
        name = f"latency timer {row['latency_timer_ms']} ms"
        print(
            f"  {name:24} {row['adapter_bound_cycles_per_s']:8.1f} {row['raw_pyserial_cycles_per_s']:7.1f} "
            f"{row['stream_cycles_per_s']:9.1f} {row['stream_vs_bound']:8.1%} {row['raw_vs_bound']:12.1%} "
            f"{row['stream_vs_raw']:7.2f}{fails}"
        )


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=1)
    parser.add_argument("--json", action="store_true", help="print the figures as JSON too")
    args = parser.parse_args()
    result = run(args.runs)
    print_table(result)
    if args.json:
        print(json.dumps(result, indent=2))
