"""``benchmarks/run.py --quick`` must leave the tracked benchmarks/results.json alone (issue 14, finding 14).

The script runs from a copy of ``benchmarks/`` in a temporary directory, so
that a run that does overwrite results.json spoils only the copy.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"
CHEAP_SECTION = "startup"  # the cheapest section: import and --version timings, about 2 s with --quick

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the benchmarks use a pty")


@pytest.fixture
def bench_copy(tmp_path: Path) -> Path:
    copy = tmp_path / "benchmarks"
    shutil.copytree(
        BENCHMARKS,
        copy,
        ignore=shutil.ignore_patterns("__pycache__", "soak", "results-quick.json", "results-partial.json"),
    )
    return copy


def run_script(copy: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, str(copy / "run.py"), "--sections", CHEAP_SECTION, "--runs", "1", *args],
        capture_output=True,
        text=True,
        timeout=300,
    )


def test_a_quick_run_leaves_the_tracked_results_alone(bench_copy: Path) -> None:
    tracked = (bench_copy / "results.json").read_bytes()
    done = run_script(bench_copy, "--quick")
    assert done.returncode == 0, done.stderr[-2000:]
    assert (bench_copy / "results.json").read_bytes() == tracked
    quick = json.loads((bench_copy / "results-quick.json").read_text())
    assert quick["meta"]["quick"] is True and CHEAP_SECTION in quick
    assert "results-quick.json" in done.stdout


def test_an_explicit_output_is_written_even_for_a_quick_run(bench_copy: Path, tmp_path: Path) -> None:
    out = tmp_path / "mine.json"
    done = run_script(bench_copy, "--quick", "--out", str(out))
    assert done.returncode == 0, done.stderr[-2000:]
    assert CHEAP_SECTION in json.loads(out.read_text())
    assert not (bench_copy / "results-quick.json").exists()


def test_the_quick_results_file_is_ignored_by_git() -> None:
    ignored = subprocess.run(
        ["git", "check-ignore", "-q", str(BENCHMARKS / "results-quick.json")], cwd=BENCHMARKS, check=False
    )
    assert ignored.returncode == 0


def test_a_run_of_some_sections_leaves_the_tracked_results_alone(bench_copy: Path) -> None:
    tracked = (bench_copy / "results.json").read_bytes()
    done = run_script(bench_copy)
    assert done.returncode == 0, done.stderr[-2000:]
    assert (bench_copy / "results.json").read_bytes() == tracked
    assert CHEAP_SECTION in json.loads((bench_copy / "results-partial.json").read_text())
