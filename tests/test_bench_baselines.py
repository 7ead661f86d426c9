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
