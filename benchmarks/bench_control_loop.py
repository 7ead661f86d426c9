"""The control loop: a 12-servo stream at rate_hz=100 on a 1.25 Mbit/s line, shared and imperfect.

Four scenarios, each on the in-process simulator in real time (replies held to
their wire time at 1.25 Mbit/s, servos answering after 100 us):

* clean: the stream alone (the baseline of this run);
* pollers: four coroutines reading temperatures flat out at default priority;
* faults: 5% of replies dropped, cut short, held back 30 ms or garbled (with the default
  10 ms quiet time after a fault, and with ``quiet_time=0.005``); "held back" is the
  simulator's ``late`` fault with ``late_delay=0.03``, as in the simulated-time column (its
  default, a reply held until the host's next command, ties the reply to what the host does);
* offline: one of the 12 servos missing;
* clean, pollers and faults again with the asyncio driver's deadlines on the event loop's own timers (whole
  milliseconds) instead of its timerfd (``ics35_async.drivers.fine_timer``): what the finer timer buys;
* clean on the thread driver over a pty (its I/O thread polls the tty: the simulator in its own process, as
  for the busy rows below), with its timerfd and again on ``poll``'s whole milliseconds alone;
* busy loop: two coroutines doing ~0.1 ms of Python work between yields (a web server
  under load), beside the stream on the asyncio driver and on the thread driver (each on its
  default path: the compiled one where it is built), and on the thread driver's ordinary path
  (``ICS35_BURST=0``), also with ``sys.setswitchinterval(0.0005)``: there its I/O thread needs
  the GIL after every system call, and a busy thread holds it for up to the switch interval
  (5 ms by default);
* busy thread: a Python thread computing without pause (planning, or vision in pure Python: it
  holds the GIL but for the interpreter's switch interval) beside the stream on the asyncio
  driver and on the thread driver, each on the ordinary path (``ICS35_BURST=0``: the loop's or
  the I/O thread needs the GIL at every transaction) and on the compiled path (the default where
  it is built: once a cycle); and the same two for the anyio driver under trio (its bus task).
  The busy rows use the simulator in its own process on a pty (``python -m
  ics35_async.sim``): in-process, the simulator's delivery thread would compete for the GIL too,
  and the compiled path needs a port with a descriptor.

Each prints the stream's frame rate (Hz), the p99 and largest interval
between cycle starts (ms; 10 ms is one period), how long after its slot a cycle
starts (median, ms; "-" where a missed slot moved the schedule) and, with
pollers, their reads a second.  Beside them, the same scenarios in simulated time
(tests/support/paced_line.py: the engine with no event loop and no clock),
which shows the engine's rules alone, free of this machine's load: the goals
(at least 97 Hz with pollers, 95 Hz at 5% faults, no interval over 1.5
periods with a servo offline) are checked there by tests, and shown here.

    .venv/bin/python benchmarks/bench_control_loop.py [--seconds 5]
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import itertools
import json
import statistics
import sys
import threading
import time
from collections.abc import Iterator
from typing import Any

from bench_common import burst_setting, progress

from ics35_async import Bus, BusTiming, open_bus
from ics35_async.drivers import asyncio_driver, thread_driver
from ics35_async.engine.timing import TimingOverrides
from ics35_async.sim import VirtualLine, VirtualServo
from ics35_async.sim.launch import serving
from tests.support.paced_line import IDS, intervals
from tests.support.paced_line import run as run_simulated

BAUD = 1_250_000
RATE_HZ = 100.0
FAULTS = "drop:0.0125,truncate:0.0125,late:0.0125,corrupt:0.0125"  # 5% in all
BUSY = {  # ICS35_BURST for each (None: the default, the compiled path where it is built)
    "busy loop, asyncio driver": None,
    "busy loop, thread driver": None,
    "busy loop, thread driver, ordinary path": "0",
    "busy loop, thread driver, ordinary path, switch 0.5 ms": "0",
}
BUSY_THREAD = {  # ICS35_BURST for each
    "busy thread, ordinary path": "0",
    "busy thread, compiled path": "1",
    "busy thread, thread driver, ordinary path": "0",
    "busy thread, thread driver, compiled path": "1",
    "busy thread, anyio driver under trio, ordinary path": "0",
    "busy thread, anyio driver under trio, compiled path": "1",
}
ON_A_PTY = "clean, thread driver, pty"  # (its I/O thread polls a tty: whole milliseconds but for its timerfd)
LOOP_TIMERS = {  # the scenario each runs, with the driver's deadlines on the loop's own timers or poll's milliseconds
    "clean, loop timers": "clean",
    "pollers, loop timers": "pollers",
    "faults, loop timers": "faults",
    f"{ON_A_PTY}, whole milliseconds": ON_A_PTY,
}
SCENARIOS = (
    "clean",
    "pollers",
    "faults",
    "faults, quiet 5 ms",
    "offline",
    ON_A_PTY,
    *LOOP_TIMERS,
    *BUSY,
    *BUSY_THREAD,
)
QUIET_5MS = "faults, quiet 5 ms"  # the same faults with open_bus(..., quiet_time=0.005)


@contextlib.contextmanager
def loop_timers() -> Iterator[None]:
    """The drivers without their fine timer (ics35_async.drivers.fine_timer): the asyncio driver's deadlines on
    the event loop's own timers, whole milliseconds in epoll, the thread driver's on poll's whole milliseconds
    (what they do where the system has no timerfd)."""
    drivers = (asyncio_driver, thread_driver)
    before = [getattr(driver, "open_fine_timer") for driver in drivers]  # noqa: B009 (the name each calls)
    for driver in drivers:
        setattr(driver, "open_fine_timer", lambda: None)  # noqa: B010
    try:
        yield
    finally:
        for driver, made in zip(drivers, before, strict=True):
            setattr(driver, "open_fine_timer", made)  # noqa: B010


async def measure(scenario: str, seconds: float) -> dict[str, Any]:
    if scenario in LOOP_TIMERS:
        with loop_timers():
            return await measure(LOOP_TIMERS[scenario], seconds)
    present = IDS[:-1] if scenario == "offline" else IDS
    sim = VirtualLine(
        [VirtualServo(i, baud_rate=BAUD) for i in present],
        baudrate=BAUD,
        realtime=True,
        turnaround=0.0001,
        faults=FAULTS if scenario.startswith("faults") else None,
        late_delay=0.03,
        seed=1,
    )
    timing: TimingOverrides = {"quiet_time": 0.005} if scenario == QUIET_5MS else {}
    driver = "thread" if "thread driver" in scenario else "anyio" if "under trio" in scenario else "asyncio"
    switch = sys.getswitchinterval()
    if scenario.endswith("switch 0.5 ms"):
        sys.setswitchinterval(0.0005)
    try:
        if scenario in BUSY or scenario in BUSY_THREAD or scenario == ON_A_PTY:
            setting = BUSY_THREAD.get(scenario, BUSY.get(scenario))
            path = burst_setting(setting) if setting is not None else contextlib.nullcontext()
            with serving(["--ids", f"{IDS[0]}-{IDS[-1]}", "--baud", str(BAUD)]) as pty, path:
                async with open_bus(pty, baudrate=BAUD, driver=driver) as bus:
                    return await measure_on(bus, scenario, present, seconds)
        async with open_bus(sim, baudrate=BAUD, driver=driver, **timing) as bus:
            return await measure_on(bus, scenario, present, seconds)
    finally:
        sys.setswitchinterval(switch)


async def measure_on(bus: Bus, scenario: str, present: list[int], seconds: float) -> dict[str, Any]:
    reads = work = 0
    stop = False

    async def poll(k: int) -> None:
        nonlocal reads
        servo = bus.servo(IDS[k % len(present)])
        while not stop:
            try:
                await servo.read_temperature()
                reads += 1
            except Exception:
                await asyncio.sleep(0)

    async def busy() -> None:
        nonlocal work
        while not stop:
            x = 0
            for i in range(2000):  # about 0.1 ms of Python: a request served
                x += i
            work += 1
            await asyncio.sleep(0)

    def spin() -> None:  # the busy thread: Python work without pause
        nonlocal work
        while not stop:
            x = 0
            for i in range(2000):  # about 0.1 ms of Python
                x += i
            work += 1

    async with bus.stream(IDS, rate_hz=RATE_HZ) as stream:
        stream.set_targets(dict.fromkeys(IDS, 7500))
        first = await stream.next_frame()
        tasks = [asyncio.ensure_future(poll(k)) for k in range(4 if scenario == "pollers" else 0)]
        if scenario in BUSY:
            tasks += [asyncio.ensure_future(busy()) for _ in range(2)]
        thread = threading.Thread(target=spin, daemon=True)
        if scenario in BUSY_THREAD:
            thread.start()
        try:
            starts = [first.started]
            # Where each cycle started on the slot grid (start - cycle / rate): the grid is anchored
            # at the earliest of them, as no cycle starts before its slot.
            on_grid = [first.started - first.cycle / RATE_HZ]
            missed = 0
            cycles0 = stream.stats.cycles
            t0 = time.monotonic()
            while time.monotonic() - t0 < seconds:
                frame = await stream.next_frame()
                starts.append(frame.started)
                on_grid.append(frame.started - frame.cycle / RATE_HZ)
                missed += frame.missed_slots
            # Over the wall-clock window, not the frames seen: a starved consumer sees few of them.
            cycles = stream.stats.cycles - cycles0
            elapsed = time.monotonic() - t0
        finally:  # the busy thread and coroutines end even if the stream raised: the next scenario needs the CPU
            stop = True
            if thread.is_alive():
                thread.join()
            if tasks:  # (none under trio: only the busy thread's rows run there)
                await asyncio.gather(*tasks)
    gaps = sorted(b - a for a, b in itertools.pairwise(starts))
    return {
        "rate_hz": cycles / elapsed,
        "interval_p99_ms": gaps[min(len(gaps) - 1, int(len(gaps) * 0.99))] * 1e3,
        "interval_max_ms": gaps[-1] * 1e3,
        "reads_per_s": reads / elapsed,
        "work_per_s": work / elapsed,
        "frames_seen": len(starts),
        # A missed slot moves the grid (the stream re-anchors): then there is no one grid to measure.
        "slot_lag_p50_ms": (statistics.median(on_grid) - min(on_grid)) * 1e3 if not missed else None,
    }


def measure_in_its_library(scenario: str, seconds: float) -> dict[str, Any]:
    """:func:`measure` under asyncio, or under trio for the scenarios that say so."""
    if "under trio" in scenario:
        import trio

        return trio.run(measure, scenario, seconds)
    return asyncio.run(measure(scenario, seconds))


def simulated(scenario: str) -> dict[str, Any]:
    rate = 0.05 if scenario.startswith("faults") else 0.0
    present = IDS[:-1] if scenario == "offline" else IDS
    timing = BusTiming(quiet_time=0.005) if scenario == QUIET_5MS else None
    source = run_simulated(rate, 1, present=present, seconds=10.0, timing=timing)
    gaps = sorted(intervals(source))
    return {
        "rate_hz": (len(source.starts) - 1) / (source.starts[-1] - source.starts[0]),
        "interval_p99_ms": gaps[int(len(gaps) * 0.99)] * 1e3,
        "interval_max_ms": gaps[-1] * 1e3,
    }


def run(seconds: float = 5.0) -> dict[str, Any]:
    rows = []
    for scenario in SCENARIOS:
        progress(f"control loop: {scenario}, {seconds:g} s")
        row: dict[str, Any] = {"scenario": scenario, "measured": measure_in_its_library(scenario, seconds)}
        if scenario not in ("pollers", ON_A_PTY, *LOOP_TIMERS, *BUSY, *BUSY_THREAD):  # (not simulated)
            row["simulated"] = simulated(scenario)
        rows.append(row)
    return {"servos": len(IDS), "rate_hz": RATE_HZ, "baud": BAUD, "seconds": seconds, "rows": rows}


def print_table(result: dict[str, Any]) -> None:
    print(f"\n## Control loop: {result['servos']} servos at {result['rate_hz']:g} Hz, {result['baud']} bit/s\n")
    print(
        "| scenario | rate (Hz) | interval p99 / max (ms) | start after slot, median (ms) | reads/s, loop work/s "
        "| simulated: rate, p99 / max |"
    )
    print("|---|---|---|---|---|---|")
    for row in result["rows"]:
        m = row["measured"]
        s = row.get("simulated")
        sim = f"{s['rate_hz']:.1f} Hz, {s['interval_p99_ms']:.1f} / {s['interval_max_ms']:.1f} ms" if s else "-"
        reads = f"{m['reads_per_s']:,.0f}" if row["scenario"].startswith("pollers") else "-"
        if row["scenario"] in BUSY or row["scenario"] in BUSY_THREAD:
            reads = f"{m['work_per_s']:,.0f} work/s, {m['frames_seen']} frames seen"
        lag = "-" if m["slot_lag_p50_ms"] is None else f"{m['slot_lag_p50_ms']:.2f}"
        print(
            f"| {row['scenario']} | {m['rate_hz']:.1f} | {m['interval_p99_ms']:.1f} / {m['interval_max_ms']:.1f} "
            f"| {lag} | {reads} | {sim} |"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    result = run(args.seconds)
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print_table(result)


if __name__ == "__main__":
    main()
