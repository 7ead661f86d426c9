"""The benchmarks' own baselines measure what they say they measure."""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import bench_floors


def test_the_engine_alone_runs_the_stream_as_the_bus_attaches_it() -> None:
    # Attaching the Stream object itself went through its deprecated public hook names, a warning
    # per call: the "engine alone" figure measured the warnings machinery (twice the engine's cost).
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        figures = bench_floors.engine_alone(transactions=2_000)
    assert figures["transactions"] == 2_000


def test_the_telemetry_floor_serves_the_pollers_reads_between_its_transactions() -> None:
    # The lean responder drops what it does not know byte by byte: a read the floor framed wrong would go
    # unanswered (the floor raises after 1 s) rather than be counted as a poll.
    import bench_sharing
    from lean_responder import lean_lines

    with lean_lines(1, baud=1250000, wire=True) as (path,):
        figures = bench_sharing.bare_floor(path, 1250000, alone=0.2, shared=0.5)
    assert figures["polls_per_s"] > 0
    assert 0 <= figures["wait_p50_tx"] <= figures["wait_p99_tx"]
    assert figures["latency_p50_tx"] > 0
