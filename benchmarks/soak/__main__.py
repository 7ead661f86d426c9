"""Run the reliability soaks and print one table: ``python -m benchmarks.soak`` (``make soak``).

    .venv/bin/python -m benchmarks.soak             # every part at full size
    .venv/bin/python -m benchmarks.soak --quick     # every part, small (about a minute)
    .venv/bin/python -m benchmarks.soak --only chaos,fuzz --transactions 200000 --seed 3

Prints one markdown table (check, result, target met) and exits 1 if a
target is missed; ``--json FILE`` keeps every figure (``make soak`` writes
benchmarks/soak_results.json).  The full run takes about 20 minutes on two
cores.  One module per part, registered in :data:`PARTS`.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import os
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from typing import Any

from ics35_async.compiled import engine_compiled

from . import cancellation, chaos, fuzz, held_tail, unplug
from .common import PTY, PTY_BURST, PTY_BURST_ANYIO, PTY_BURST_THREAD, Row, markdown


@dataclass
class PathReports:
    """A soak's reports on the ordinary path and on the burst path: the asyncio driver's, the anyio driver's
    (on asyncio) and, where the soak runs there, the thread driver's."""

    ordinary: Any
    burst: Any
    anyio_burst: Any
    thread_burst: Any = None

    @property
    def seconds(self) -> float:
        reports = (self.ordinary, self.burst, self.anyio_burst, self.thread_burst)
        return float(sum(r.seconds for r in reports if r is not None))


Part = Callable[[argparse.Namespace, Callable[[str], None]], tuple[Any, list[Row]]]
"""One soak: (the parsed options, a progress printer) -> (its report, a dataclass; its table rows)."""


def run_chaos(args: argparse.Namespace, say: Callable[[str], None]) -> tuple[Any, list[Row]]:
    transactions = args.transactions or (50_000 if args.quick else 1_000_000)
    report = asyncio.run(chaos.chaos_soak(transactions, args.fault_rate, args.seed, progress=say))
    return report, chaos.summarize_chaos(report)


def run_chaos_pty(args: argparse.Namespace, say: Callable[[str], None]) -> tuple[Any, list[Row]]:
    """The chaos soak over a pty, on the ordinary path and then on the burst path, the asyncio driver's and the
    anyio driver's (one report each).  Not under the thread driver: its stream runs beside the program's loop,
    which then takes the latest frame and skips some, and this soak's oracle pairs every cycle on the wire with
    a frame taken (it sets aside only the skipped cycles of a burst fed at once, which have every ID: see
    ``LogMatcher.add_frame``).

    On the burst path with one request worker instead of four: the stream then has the line most of
    the time, so most transactions run in the executor (with four, about 1 %).
    """
    transactions = args.pty_transactions or (10_000 if args.quick else 100_000)
    reports: list[chaos.ChaosReport] = []
    rows: list[Row] = []
    for link, workers in ((PTY, 4), (PTY_BURST, 1), (PTY_BURST_ANYIO, 1)):
        baseline = max(2_000, transactions // 10)
        soak = chaos.chaos_soak(transactions, args.fault_rate, args.seed, baseline, workers, progress=say, link=link)
        reports.append(asyncio.run(soak))
        rows += chaos.summarize_chaos(reports[-1])
    return PathReports(*reports), rows


def run_cancel(args: argparse.Namespace, say: Callable[[str], None]) -> tuple[Any, list[Row]]:
    cancellations = args.cancellations or (1_000 if args.quick else 10_000)
    say(f"cancel: {cancellations} cancellations")
    report = asyncio.run(cancellation.cancellation_soak(cancellations, args.seed + 1))
    return report, cancellation.summarize_cancel(report)


def run_cancel_pty(args: argparse.Namespace, say: Callable[[str], None]) -> tuple[Any, list[Row]]:
    """The cancellation soak over a pty: on the ordinary path, then on the burst path (the asyncio driver's, the
    anyio driver's, then the thread driver's) with one request canceller and half the cancellations streams
    (with six cancellers the line is never free for a burst)."""
    cancellations = 500 if args.quick else 2_000
    reports: list[cancellation.CancelReport] = []
    rows: list[Row] = []
    on_bursts = {"concurrency": 1, "stream_share": 0.5}
    shapes: tuple[tuple[str, dict[str, Any]], ...] = (
        (PTY, {}),
        (PTY_BURST, on_bursts),
        (PTY_BURST_ANYIO, on_bursts),
        (PTY_BURST_THREAD, on_bursts),
    )
    for link, shape in shapes:
        say(f"cancel over a {link}: {cancellations} cancellations")
        soak = cancellation.cancellation_soak(cancellations, args.seed + 1, link=link, **shape)
        reports.append(asyncio.run(soak))
        rows += cancellation.summarize_cancel(reports[-1])
    return PathReports(*reports), rows


def run_unplug(args: argparse.Namespace, say: Callable[[str], None]) -> tuple[Any, list[Row]]:
    """The unplug soak on the ordinary path, then on the burst path, the asyncio driver's, the anyio driver's (on
    asyncio) and the thread driver's (one report each)."""
    reports: list[unplug.UnplugReport] = []
    rows: list[Row] = []
    for burst, driver in ((False, "asyncio"), (True, "asyncio"), (True, "anyio"), (True, "thread")):
        path = f", burst path{'' if driver == 'asyncio' else f', {driver} driver'}" if burst else ""
        say(f"unplug: pty simulator, device unplugged and replugged{path}")
        sizes: dict[str, Any] = {"down_times": (0.05, 1.0), "cycles_each": 1} if args.quick else {}
        reports.append(asyncio.run(unplug.unplug_soak(seed=args.seed + 2, burst=burst, driver=driver, **sizes)))
        rows += unplug.summarize_unplug(reports[-1])
    return PathReports(*reports), rows


def run_fuzz(args: argparse.Namespace, say: Callable[[str], None]) -> tuple[Any, list[Row]]:
    streams = args.fuzz_streams or (20_000 if args.quick else 1_000_000)
    say(f"fuzz: {streams} byte streams")
    report = fuzz.fuzz_soak(streams, seed=args.seed + 3)
    return report, fuzz.summarize_fuzz(report)


def run_held_tail(args: argparse.Namespace, say: Callable[[str], None]) -> tuple[Any, list[Row]]:
    held = args.held_tail_transactions or (400 if args.quick else 10_000)
    report = asyncio.run(held_tail.held_tail_runs(held, fast=max(200, held // 10), seed=args.seed + 4, progress=say))
    return report, held_tail.summarize_runs(report)


PARTS: dict[str, Part] = {
    "chaos": run_chaos,
    "chaos_pty": run_chaos_pty,
    "cancel": run_cancel,
    "cancel_pty": run_cancel_pty,
    "unplug": run_unplug,
    "fuzz": run_fuzz,
    "held_tail": run_held_tail,
}
"""Every soak, in the order ``make soak`` runs them; a new soak is a module plus one entry here."""


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--quick", action="store_true", help="small sizes (about a minute in all)")
    parser.add_argument("--only", default=",".join(PARTS), help=f"comma-separated parts: {', '.join(PARTS)}")
    parser.add_argument("--transactions", type=int, default=None, help="chaos: transactions (default 1,000,000)")
    parser.add_argument(
        "--pty-transactions", type=int, default=None, help="chaos_pty: transactions on each path (default 100,000)"
    )
    parser.add_argument("--fault-rate", type=float, default=0.02, help="chaos: share of faulted transactions")
    parser.add_argument("--cancellations", type=int, default=None, help="cancel: cancellations (default 10,000)")
    parser.add_argument("--fuzz-streams", type=int, default=None, help="fuzz: byte streams (default 1,000,000)")
    parser.add_argument(
        "--held-tail-transactions", type=int, default=None, help="held_tail: transactions on the slow link, per run"
    )
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--json", default=None, help="also write every figure to this JSON file")
    args = parser.parse_args(argv)
    # Port losses and resyncs are the point here: the library's warnings about them are expected.
    logging.getLogger("ics35_async").setLevel(logging.ERROR)
    parts = [p.strip() for p in args.only.split(",") if p.strip()]
    unknown = set(parts) - set(PARTS)
    if unknown:
        parser.error(f"unknown part(s): {', '.join(sorted(unknown))}")

    def say(text: str) -> None:
        print(text, file=sys.stderr, flush=True)

    rows: list[Row] = []
    figures: dict[str, Any] = {
        "python": sys.version.split()[0],
        "cpus": os.cpu_count(),
        "engine": engine_compiled()[1],  # (make soak runs on the compiled copy: see the Makefile)
    }
    started = time.perf_counter()
    for name in parts:
        report, part_rows = PARTS[name](args, say)
        figures[name] = asdict(report)
        rows += part_rows
        say(f"{name}: {report.seconds:.0f} s")
    figures["seconds"] = time.perf_counter() - started
    print(markdown(rows))
    print(f"\n{figures['seconds']:.0f} s in all, Python {figures['python']}, {figures['cpus']} CPUs")
    print(f"compiled engine: {figures['engine']}")
    for part in parts:
        examples = figures.get(part, {}).get("examples")
        if examples:
            print(f"\n{part} examples:\n  " + "\n  ".join(examples))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(figures, f, indent=1, default=str)
    failed = [name for name, _value, ok in rows if ok is False]
    if failed:
        print(f"\nFAILED: {', '.join(failed)}")
        return 1
    print("\nevery target met")
    return 0


if __name__ == "__main__":
    sys.exit(main())
