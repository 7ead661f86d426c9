"""The burst path (compiled executor) against the ordinary path, blocking pyserial and the bare loop.

Rows, every one alternated with its baseline in each run, medians of the ratios:

* CPU per transaction of a 32-ID stream on the default driver and loop, burst path and
  ordinary path (``ICS35_BURST=0``), against blocking pyserial on the same lean responder
  (answers at once): the goal is at most 0.7x; the same two for the anyio driver under trio;
* the same stream against a responder holding every reply to its 1.25 Mbit/s wire time, rate
  against the bare ``os.write``/``poll``/``os.read`` loop on the same line: goal at least 1.0x;
* both of these also without feeding the engine a few transactions ahead of each burst's end (what
  that buys in rate, and costs in CPU); the first also with the engine as plain Python (``make bench``
  runs the rest with it compiled by mypyc: see ``setup.py``);
* where the burst path's CPU goes: the executor's thread, the loop's, feeding the engine;
* four such lines streamed together against one: CPU per transaction, goal at most 1.1x;
* a CPU-bound Python thread's progress while a wire-timed stream runs, against the same thread
  alone (how much of the program's time the servo line leaves it), and the stream's rate meanwhile;
  also under trio (the anyio driver);
* telemetry beside a wire-timed stream (``bench_sharing``'s 16 pollers reading current and
  temperature, 10 times a second each): their p99 wait in position-transaction times and their
  latency, on the burst path as it runs (no burst starts while requests come), with bursts
  beside the requests (what that pause avoids), on the ordinary path, and on uvloop (the goal: at most 1.5);
  and the same polls served by a bare loop between its own 32 position transactions (``bench_sharing.bare_floor``:
  what the pty and the host leave any client, in that loop's own T);
* sequential awaited ``set_position`` against raw pyserial, and the batched forms (``gather`` of
  one cycle's 32 commands; a stream) that replace it.

CPU is ``time.process_time()`` of this process (every thread, the executor's included).

    .venv/bin/python benchmarks/bench_burst.py [--runs 3] [--duration 1.0]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from bench_common import IDS, NEUTRAL, burst_setting, median, progress, run_on
from bench_cpu import BUS_OPTIONS, sequential, stream
from bench_lines import group_stream
from bench_overhead import lean_loop, raw_loop
from bench_sharing import bare_floor
from bench_sharing import measure as telemetry_beside_stream
from lean_responder import lean_lines

from ics35_async import IcsError, open_bus
from ics35_async.compiled import engine_compiled
from ics35_async.drivers import burst as burst_module
from ics35_async.drivers.burst import burst_path

Figures = dict[str, Any]
BAUD = 1_250_000


def on_path(burst: bool, fn: Callable[[], Figures]) -> Figures:
    with burst_setting("1" if burst else "0"):
        return fn()


def fed_at_end(fn: Callable[[], Figures]) -> Figures:
    """``fn()`` on the burst path with each burst fed to the engine only where a frame is complete and at
    the burst's end, not also a few transactions before it (see
    :func:`ics35_async.drivers.burst.feed_ahead_points`): what feeding ahead of the end buys."""
    before = burst_module.FEED_AHEAD_MIN
    burst_module.FEED_AHEAD_MIN = sys.maxsize
    try:
        return on_path(True, fn)
    finally:
        burst_module.FEED_AHEAD_MIN = before


SOURCE_TREE = Path(__file__).resolve().parent.parent


def plain_engine_stream(path: str, duration: float) -> Figures:
    """:func:`bench_cpu.stream` on the burst path with the engine as plain Python: in a process that imports the
    package from the source tree (which ``make`` never compiles in place; ``make bench`` runs the other rows on
    the compiled copy), what the compiled engine saves.  CPU counted inside that process, as in-process rows."""
    code = (
        "import json, sys; from bench_cpu import stream; "
        f"print(json.dumps(stream({path!r}, None, 'asyncio', {duration!r})))"
    )
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(SOURCE_TREE), str(SOURCE_TREE / "benchmarks")])}
    check = "from ics35_async.compiled import engine_compiled; assert not engine_compiled()[0]; "
    with burst_setting("1"):
        done = subprocess.run(
            [sys.executable, "-c", check + code], capture_output=True, text=True, timeout=120, env=env, check=False
        )
    if done.returncode != 0:
        raise RuntimeError(f"the plain-engine row failed: {done.stderr[-2000:]}")
    figures: Figures = json.loads(done.stdout.splitlines()[-1])
    return figures


def cpu_split(path: str, duration: float) -> Figures:
    """Where the burst path's CPU goes, per transaction of a 32-ID stream: all of it and the loop's
    thread's (:func:`bench_cpu.stream`), and what feeding the engine the bursts' bytes takes
    (``BurstRunner._feed``, ``time.thread_time()`` per record fed); the rest is the executor's thread."""
    fed = [0.0, 0]  # seconds feeding, records fed
    feed = burst_module.BurstRunner._feed

    def timed_feed(self: burst_module.BurstRunner, plan: Any, records: list[Any], *args: Any) -> bytes | None:
        t = time.thread_time()
        try:
            return feed(self, plan, records, *args)
        finally:
            fed[0] += time.thread_time() - t
            fed[1] += len(records)

    burst_module.BurstRunner._feed = timed_feed  # type: ignore[method-assign,assignment]
    try:
        figures = on_path(True, lambda: stream(path, None, "asyncio", duration))
    finally:
        burst_module.BurstRunner._feed = feed  # type: ignore[method-assign]
    return {**figures, "feed_us_per_tx": fed[0] / max(1, int(fed[1])) * 1e6}


def gathered(path: str, duration: float) -> Figures:
    """One cycle's 32 ``set_position`` commands queued together (``asyncio.gather``), cycle after cycle."""

    async def measure() -> Figures:
        async with open_bus(path, **BUS_OPTIONS) as bus:
            servos = bus.servos(IDS)
            await asyncio.gather(*(s.set_position(NEUTRAL) for s in servos), return_exceptions=True)
            n = failures = 0
            wall0, cpu0 = time.perf_counter(), time.process_time()
            while (now := time.perf_counter()) - wall0 < duration:
                got = await asyncio.gather(*(s.set_position(NEUTRAL) for s in servos), return_exceptions=True)
                failures += sum(isinstance(g, IcsError) for g in got)  # counted, not fatal (a loaded machine)
                n += len(servos)
            cpu = time.process_time() - cpu0
        return {"tx_per_s": n / (now - wall0), "cpu_us_per_tx": cpu / n * 1e6, "failures": failures}

    return run_on("asyncio", measure)


def thread_progress(path: str | None, burst: bool, duration: float, loop: str = "asyncio") -> Figures:
    """Iterations per second of a pure-Python counting thread, alone (``path`` None) or beside a stream run
    under ``loop`` (``"trio"``: the anyio driver)."""
    done = threading.Event()
    count = [0]

    def spin() -> None:
        n = 0
        while not done.is_set():
            n += 1
            if n % 4096 == 0:
                count[0] = n

    async def beside_stream() -> Figures:
        assert path is not None
        async with open_bus(path, baudrate=BAUD, **BUS_OPTIONS) as bus, bus.stream(IDS) as st:
            first = await st.next_frame()
            c0, t0 = count[0], time.perf_counter()
            frame = first
            while (now := time.perf_counter()) - t0 < duration:
                frame = await st.next_frame()
            c1 = count[0]
        wall = now - t0
        return {"spins_per_s": (c1 - c0) / wall, "stream_tx_per_s": (frame.cycle - first.cycle) * len(IDS) / wall}

    thread = threading.Thread(target=spin, daemon=True)
    thread.start()
    try:
        if path is None:
            c0, t0 = count[0], time.perf_counter()
            time.sleep(duration)
            return {"spins_per_s": (count[0] - c0) / (time.perf_counter() - t0)}
        return on_path(burst, lambda: run_on(loop, beside_stream))
    finally:
        done.set()
        thread.join()


def ratio(value: float, a: float, b: float) -> float:
    return value / ((a + b) / 2)


def run(runs: int = 3, duration: float = 1.0) -> dict[str, Any]:
    rows: dict[str, list[float]] = {}
    figures: dict[str, list[Figures]] = {}

    def note(name: str, value: float, f: Figures | None = None) -> None:
        rows.setdefault(name, []).append(value)
        if f is not None:
            figures.setdefault(name, []).append(f)

    with lean_lines(1) as (path,):
        for r in range(runs):
            progress(f"burst: run {r + 1}/{runs} (answers at once)")
            raw0 = raw_loop(path, duration)
            bursts = on_path(True, lambda: stream(path, None, "asyncio", duration))
            raw1 = raw_loop(path, duration)
            at_end = fed_at_end(lambda: stream(path, None, "asyncio", duration))
            raw1a = raw_loop(path, duration)
            plain_engine = plain_engine_stream(path, duration)
            raw1b = raw_loop(path, duration)
            plain = on_path(False, lambda: stream(path, None, "asyncio", duration))
            raw2 = raw_loop(path, duration)
            seq = sequential(path, None, "asyncio", duration)
            raw3 = raw_loop(path, duration)
            trio_bursts = on_path(True, lambda: stream(path, "anyio", "trio", duration))
            raw3a = raw_loop(path, duration)
            trio_plain = on_path(False, lambda: stream(path, "anyio", "trio", duration))
            raw3b = raw_loop(path, duration)
            gath = gathered(path, duration)
            raw4 = raw_loop(path, duration)
            floor = lean_loop(path, duration)
            raw5 = raw_loop(path, duration)
            note("cpu split", 0.0, cpu_split(path, duration))
            for name, f, a, b in (
                ("stream burst", bursts, raw0, raw1),
                ("stream burst fed at end", at_end, raw1, raw1a),
                ("stream burst plain engine", plain_engine, raw1a, raw1b),
                ("stream ordinary", plain, raw1b, raw2),
                ("sequential awaited set_position", seq, raw2, raw3),
                ("stream trio burst", trio_bursts, raw3, raw3a),
                ("stream trio ordinary", trio_plain, raw3a, raw3b),
                ("gather of one cycle's set_position", gath, raw3b, raw4),
                ("floor: os.write/poll/os.read", floor, raw4, raw5),
            ):
                note(f"cpu_vs_raw {name}", ratio(f["cpu_us_per_tx"], a["cpu_us_per_tx"], b["cpu_us_per_tx"]), f)
                note(f"rate_vs_raw {name}", ratio(f["tx_per_s"], a["tx_per_s"], b["tx_per_s"]))
            note("raw cpu_us_per_tx", (raw0["cpu_us_per_tx"] + raw5["cpu_us_per_tx"]) / 2)
    with lean_lines(4, baud=BAUD, wire=True) as paths:
        for r in range(runs):
            progress(f"burst: run {r + 1}/{runs} (wire-timed at {BAUD} bit/s)")
            bare0 = lean_loop(paths[0], duration, baud=BAUD)
            one = on_path(True, lambda: group_stream(paths[:1], None, "asyncio", BAUD, duration))
            bare1 = lean_loop(paths[0], duration, baud=BAUD)
            one_plain = on_path(False, lambda: group_stream(paths[:1], None, "asyncio", BAUD, duration))
            bare2 = lean_loop(paths[0], duration, baud=BAUD)
            one_end = fed_at_end(lambda: group_stream(paths[:1], None, "asyncio", BAUD, duration))
            bare3 = lean_loop(paths[0], duration, baud=BAUD)
            four = on_path(True, lambda: group_stream(paths, None, "asyncio", BAUD, duration))
            four_plain = on_path(False, lambda: group_stream(paths, None, "asyncio", BAUD, duration))
            for name, f, a, b in (
                ("burst", one, bare0, bare1),
                ("ordinary", one_plain, bare1, bare2),
                ("burst fed at end", one_end, bare2, bare3),
            ):
                rate = f["aggregate_cycles_per_s"] * len(IDS)
                note(f"wire rate_vs_bare {name}", ratio(rate, a["tx_per_s"], b["tx_per_s"]), f)
            note("four_vs_one cpu burst", four["cpu_us_per_tx"] / one["cpu_us_per_tx"], four)
            note("four_vs_one cpu ordinary", four_plain["cpu_us_per_tx"] / one_plain["cpu_us_per_tx"], four_plain)
            alone = thread_progress(None, True, duration)
            beside_burst = thread_progress(paths[0], True, duration)
            beside_plain = thread_progress(paths[0], False, duration)
            beside_trio_burst = thread_progress(paths[0], True, duration, "trio")
            beside_trio_plain = thread_progress(paths[0], False, duration, "trio")
            alone2 = thread_progress(None, True, duration)
            base = (alone["spins_per_s"] + alone2["spins_per_s"]) / 2
            note("thread progress beside burst", beside_burst["spins_per_s"] / base, beside_burst)
            note("thread progress beside ordinary", beside_plain["spins_per_s"] / base, beside_plain)
            note("thread progress beside trio burst", beside_trio_burst["spins_per_s"] / base, beside_trio_burst)
            note("thread progress beside trio ordinary", beside_trio_plain["spins_per_s"] / base, beside_trio_plain)
            # The burst path as it runs (no burst starts while requests come), with bursts beside the
            # requests (what that pause avoids), the ordinary path, the first on uvloop (its own order of
            # timers and I/O in a pass), and the floor; a different one first each run.
            variants = [
                ("burst", "1", False, "asyncio"),
                ("burst beside requests", "1", True, "asyncio"),
                ("ordinary", "0", False, "asyncio"),
                ("burst uvloop", "1", False, "uvloop"),
                ("floor", "", False, ""),  # the same polls served by a bare loop
            ]
            for name, setting, beside, loop in variants[r % 5 :] + variants[: r % 5]:
                if name == "floor":
                    tele = bare_floor(paths[0], BAUD, alone=duration, shared=1.5 * duration)
                else:
                    with burst_setting(setting, beside_requests=beside):
                        tele = telemetry_beside_stream(paths[0], loop, BAUD, alone=duration, shared=1.5 * duration)
                note(f"telemetry wait_p99_tx {name}", tele["wait_p99_tx"], tele)
    return {
        "path": on_path(True, lambda: {"path": burst_path()[1]})["path"],
        "engine": engine_compiled()[1],
        "runs": runs,
        "duration_s": duration,
        "medians": {name: median(values) for name, values in rows.items()},
        "per_run": rows,
        "figures": {name: fs for name, fs in figures.items()},
    }


ROWS = (
    ("stream, default driver and loop, burst path", "cpu_vs_raw stream burst", "rate_vs_raw stream burst"),
    (
        "  the same, not fed ahead of a burst's end",
        "cpu_vs_raw stream burst fed at end",
        "rate_vs_raw stream burst fed at end",
    ),
    (
        "  the same, engine as plain Python",
        "cpu_vs_raw stream burst plain engine",
        "rate_vs_raw stream burst plain engine",
    ),
    ("stream, default driver and loop, ordinary path", "cpu_vs_raw stream ordinary", "rate_vs_raw stream ordinary"),
    ("stream, anyio driver under trio, burst path", "cpu_vs_raw stream trio burst", "rate_vs_raw stream trio burst"),
    (
        "stream, anyio driver under trio, ordinary path",
        "cpu_vs_raw stream trio ordinary",
        "rate_vs_raw stream trio ordinary",
    ),
    (
        "sequential awaited set_position",
        "cpu_vs_raw sequential awaited set_position",
        "rate_vs_raw sequential awaited set_position",
    ),
    (
        "gather of one cycle's set_position",
        "cpu_vs_raw gather of one cycle's set_position",
        "rate_vs_raw gather of one cycle's set_position",
    ),
    (
        "bare os.write/poll/os.read loop",
        "cpu_vs_raw floor: os.write/poll/os.read",
        "rate_vs_raw floor: os.write/poll/os.read",
    ),
)


def print_table(r: dict[str, Any]) -> None:
    m = r["medians"]
    print(f"\nE. The burst path ({r['path']}); medians of {r['runs']} runs, ratios against baselines run alongside")
    print(f"   compiled engine: {r.get('engine', 'not recorded')}")
    raw = m["raw cpu_us_per_tx"]
    print(f"   against blocking pyserial on a lean responder that answers at once (raw: {raw:.1f} us/tx)")
    print(f"  {'row':48} {'CPU/raw':>8} {'rate/raw':>9}")
    for label, cpu_key, rate_key in ROWS:
        print(f"  {label:48} {m[cpu_key]:8.2f} {m[rate_key]:9.2f}")
    split = r["figures"]["cpu split"]
    total, loop, feeding = (
        median([f[k] for f in split]) for k in ("cpu_us_per_tx", "loop_us_per_tx", "feed_us_per_tx")
    )
    print(f"   where the burst path's CPU goes (not alternated; only the split is to be read): {total:.1f} us/tx,")
    executor = total - loop
    print(f"   the executor's thread {executor:.1f}, the loop's thread {loop:.1f} (feeding the engine {feeding:.1f})")
    print(f"   wire-timed at {BAUD} bit/s: stream rate against the bare loop on the same line")
    print(f"  {'burst path':48} {m['wire rate_vs_bare burst']:8.2f}")
    not_ahead = "  the same, not fed ahead of a burst's end"
    print(f"  {not_ahead:48} {m['wire rate_vs_bare burst fed at end']:8.2f}")
    print(f"  {'ordinary path':48} {m['wire rate_vs_bare ordinary']:8.2f}")
    print("   four lines streamed together against one: CPU per transaction")
    print(f"  {'burst path':48} {m['four_vs_one cpu burst']:8.2f}")
    print(f"  {'ordinary path':48} {m['four_vs_one cpu ordinary']:8.2f}")
    print("   a CPU-bound Python thread beside a wire-timed stream: its progress against the thread alone,")
    print("   and the stream's rate meanwhile (each burst's end waits for the GIL: sys.getswitchinterval())")
    for name in ("burst", "ordinary", "trio burst", "trio ordinary"):
        stream_rate = median([f["stream_tx_per_s"] for f in r["figures"][f"thread progress beside {name}"]])
        label = f"{name.removeprefix('trio ')} path" + (", anyio driver under trio" if name.startswith("trio") else "")
        print(f"  {label:48} {m[f'thread progress beside {name}']:8.2f}   stream {stream_rate:7.0f} tx/s")
    print("   telemetry beside a wire-timed stream (16 pollers reading current and temperature 10 times a")
    print("   second each): p99 wait in position-transaction times (goal: at most 1.5; each path's own T,")
    print("   measured with the stream alone), and a read's latency, call to result, p50 / p99")
    labels = {
        "burst": "burst path",
        "burst beside requests": "burst path, bursts beside requests",
        "ordinary": "ordinary path",
        "burst uvloop": "burst path, on uvloop",
        "floor": "bare os.write/poll/os.read loop (the floor)",
    }
    for name, label in labels.items():
        figs = r["figures"][f"telemetry wait_p99_tx {name}"]
        p50, p99 = (median([f[f"latency_{p}_tx"] * f["position_tx_us"] for f in figs]) for p in ("p50", "p99"))
        print(f"  {label:48} {m[f'telemetry wait_p99_tx {name}']:8.2f}   {p50:4.0f} / {p99:4.0f} us")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--duration", type=float, default=1.0)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    result = run(args.runs, args.duration)
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print_table(result)


if __name__ == "__main__":
    main()
