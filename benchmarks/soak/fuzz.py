"""The fuzz soak: hypothesis draws batches of byte streams through every reply parser and the bus's framing.

Every stream goes through every command's reply parser (and the stream's
fast path), and through the bus's framing as the reply of a real
transaction on a fuzzing WireDevice double (:class:`tests.support.fuzzing.FuzzRig`).
Only typed errors, a value exactly when the bytes form a valid reply, and a
clean device answers correctly afterwards.
"""

from __future__ import annotations

import asyncio
import math
import time
from dataclasses import dataclass
from typing import Any

from tests.support.fuzzing import FuzzRig

from .common import Row
from .watchdog import Watchdog


@dataclass
class FuzzReport:
    streams: int
    parses: int
    parse_values: int
    untyped: int
    fast_path_disagrees: int
    decode_problems: int
    bus_transactions: int
    bus_values: int
    bus_errors: dict[str, int]
    bus_wrong: int
    bus_untyped: int
    loop_exceptions: int
    health_problems: list[str]
    seconds: float
    examples: list[str]

    @property
    def passed(self) -> bool:
        return not (
            self.untyped
            or self.fast_path_disagrees
            or self.decode_problems
            or self.bus_wrong
            or self.bus_untyped
            or self.loop_exceptions
            or self.health_problems
        )


def fuzz_soak(streams: int = 1_000_000, batch: int = 400, lines: int = 64, seed: int | None = 4) -> FuzzReport:
    """Hypothesis draws ``streams`` byte streams, in batches, through the parsers and the bus."""
    from hypothesis import HealthCheck, Phase, given, settings
    from hypothesis import strategies as st

    loop = asyncio.new_event_loop()
    loop_errors: list[dict[str, Any]] = []
    loop.set_exception_handler(lambda _loop, context: loop_errors.append(context))
    rig = FuzzRig(lines)
    t0 = time.perf_counter()
    try:
        with Watchdog("fuzz", progress=lambda: rig.counts.streams + rig.counts.finished, loop=loop) as dog:
            loop.run_until_complete(rig.open())
            for bus in rig.buses:
                dog.watch(bus)
            batches = max(1, math.ceil(streams / batch))

            @settings(
                max_examples=batches,
                database=None,
                deadline=None,
                derandomize=seed is not None,
                suppress_health_check=list(HealthCheck),
                phases=[Phase.generate],
            )
            @given(st.lists(st.binary(min_size=6, max_size=80), min_size=batch, max_size=batch))
            def drive(blobs: list[bytes]) -> None:
                loop.run_until_complete(rig.run(blobs))

            drive()
            problems = loop.run_until_complete(rig.health_check())
            loop.run_until_complete(rig.close())
    finally:
        loop.close()
    c = rig.counts
    return FuzzReport(
        streams=c.streams,
        parses=c.parses,
        parse_values=c.parse_values,
        untyped=c.untyped,
        fast_path_disagrees=c.fast_path_disagrees,
        decode_problems=c.decode_problems,
        bus_transactions=c.bus_transactions,
        bus_values=c.bus_values,
        bus_errors=dict(c.bus_errors),
        bus_wrong=c.bus_wrong,
        bus_untyped=c.bus_untyped,
        loop_exceptions=len(loop_errors),
        health_problems=problems,
        seconds=time.perf_counter() - t0,
        examples=c.examples + [str(e.get("message")) for e in loop_errors[:5]],
    )


def summarize_fuzz(r: FuzzReport) -> list[Row]:
    return [
        (
            "fuzz: byte streams",
            f"{r.streams:,} ({r.parses:,} parses, {r.bus_transactions:,} bus transactions, {r.seconds:.0f} s)",
            None,
        ),
        (
            "fuzz: untyped exceptions (parsers, bus, loop)",
            f"{r.untyped}, {r.bus_untyped}, {r.loop_exceptions}",
            not (r.untyped or r.bus_untyped or r.loop_exceptions),
        ),
        ("fuzz: bus conclusions differing from the bytes", f"{r.bus_wrong}", r.bus_wrong == 0),
        (
            "fuzz: stream fast path vs codec; decode_request",
            f"{r.fast_path_disagrees}; {r.decode_problems}",
            not (r.fast_path_disagrees or r.decode_problems),
        ),
        (
            "fuzz: clean device afterwards",
            "ok" if not r.health_problems else "; ".join(r.health_problems[:3]),
            not r.health_problems,
        ),
    ]
