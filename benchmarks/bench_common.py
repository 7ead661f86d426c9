"""Shared pieces of the benchmark suite (``benchmarks/run.py``).

Every figure the suite reports is a ratio against a baseline measured in the
same run, or a median of several runs whose variants are interleaved, so
that the drift of a shared, noisy machine hits every variant alike.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import os
import statistics
import sys
import time
from collections.abc import Awaitable, Callable, Iterator, Sequence
from typing import Any, TypeVar

from ics35_async import protocol
from ics35_async.drivers import burst
from ics35_async.drivers.burst import ENV as BURST_ENV
from ics35_async.sim import DEFAULT_TURNAROUND, serving

T = TypeVar("T")

IDS = tuple(range(32))
NEUTRAL = 7500
POSITION_TXS = tuple(protocol.position_tx(i, NEUTRAL) for i in IDS)
POSITION_BYTES = 6  # 3 command bytes + 3 reply bytes on the wire (the echo is the command itself)
READ_PARAM_BYTES = 5  # 2 command bytes + 3 reply bytes
TRANSPORTS = ("direct", "thread")  # the tty read on its descriptor by the loop, or by a reader thread
SIM_TURNAROUND = DEFAULT_TURNAROUND

# A pty has no USB latency timer (the default 20 ms allowance is for FTDI
# adapters), but on a busy shared 2-core machine the server process can be
# descheduled for a few ms (see the figures in ics35_async.sim): 10 ms keeps
# false timeouts rare.  Failed transactions are counted in the results.
PTY_BUS_OPTIONS: dict[str, Any] = {"adapter_latency": 0.010}


def loop_names() -> list[str]:
    names = ["asyncio"]
    try:
        import uvloop  # noqa: F401
    except ImportError:
        pass
    else:
        names.append("uvloop")
    return names


def loop_factory(name: str) -> Callable[[], asyncio.AbstractEventLoop]:
    if name == "uvloop":
        import uvloop

        return uvloop.new_event_loop
    return asyncio.new_event_loop


def run_on(loop_name: str, fn: Callable[[], Awaitable[T]]) -> T:
    """Run ``fn()`` to completion on a fresh event loop of the named kind (``"trio"``: under ``trio.run``)."""

    async def main() -> T:
        return await fn()

    if loop_name == "trio":
        import trio

        return trio.run(main)

    with asyncio.Runner(loop_factory=loop_factory(loop_name)) as runner:
        return runner.run(main())


@contextlib.contextmanager
def pty_sim(*args: str) -> Iterator[str]:
    """The simulator's pty server in a subprocess (``--ids 0-31`` plus ``args``); yields the device path."""
    with serving(["--ids", "0-31", *args]) as path:
        yield path


def wire_cycle_time(baud: int, n: int = len(IDS), *, turnaround: float = 0.0) -> float:
    """Seconds one cycle of ``n`` position transactions needs on the wire (spec section 11)."""
    return n * (protocol.wire_time(POSITION_BYTES, baud) + turnaround)


def median(values: Sequence[float]) -> float:
    return statistics.median(values) if values else math.nan


def percentile(values: Sequence[float], p: float) -> float:
    """Nearest-rank percentile (``p`` in 0..100) of ``values``."""
    if not values:
        return math.nan
    ordered = sorted(values)
    k = min(len(ordered) - 1, max(0, math.ceil(len(ordered) * p / 100) - 1))
    return ordered[k]


def progress(message: str) -> None:
    print(f"  [{time.strftime('%H:%M:%S')}] {message}", file=sys.stderr, flush=True)


def vm_rss_kib() -> int:
    """Resident set size of this process now, in KiB (Linux ``/proc/self/status``)."""
    with open("/proc/self/status") as status:
        for line in status:
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    return -1


@contextlib.contextmanager
def burst_setting(value: str, *, beside_requests: bool = False) -> Iterator[None]:
    """ICS35_BURST set to ``value`` for buses opened inside ("1": the burst path, "0": the ordinary one).

    ``beside_requests``: bursts run even while the program sends requests (the library pauses them then:
    :data:`ics35_async.drivers.burst.PAUSE_AFTER_REQUEST`), so that requests arrive mid-burst: what the soaks
    put the burst path through.
    """
    before = os.environ.get(BURST_ENV)
    pause = burst.PAUSE_AFTER_REQUEST
    os.environ[BURST_ENV] = value
    if beside_requests:
        burst.PAUSE_AFTER_REQUEST = 0.0
    try:
        yield
    finally:
        burst.PAUSE_AFTER_REQUEST = pause
        if before is None:
            del os.environ[BURST_ENV]
        else:
            os.environ[BURST_ENV] = before


def executor_transactions(bus: Any) -> int:
    """How many transactions the compiled executor ran on ``bus`` (0 off the burst path)."""
    runner = getattr(bus._driver, "burst", None)
    return runner.transactions if runner is not None else 0


def burst_path_built() -> bool:
    """Whether buses opened with ``ICS35_BURST=1`` take the burst path (the executor is built here)."""
    with burst_setting("1"):
        return burst.burst_path()[0]
