"""What a type checker tells a user of the library: the package is found from an installed copy
(outside this checkout), and misspelt options or wrong values are errors, line by line."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

SAMPLE = Path(__file__).parent / "typing_samples" / "mistakes.py"
# mypy's cache of the package between runs (its own, not the checkout's .mypy_cache): mypy reads a module
# from it only while the source is unchanged, and a run without it analyses the package again (4-5 s).
CACHE = Path(__file__).resolve().parents[1] / "build" / "mypy-cache-typing-test"


@pytest.mark.slow
def test_mypy_finds_the_package_and_flags_every_mistake(tmp_path: Path) -> None:
    program = tmp_path / "program.py"
    shutil.copy(SAMPLE, program)
    result = subprocess.run(
        [sys.executable, "-m", "mypy", "--strict", "--cache-dir", str(CACHE), "--no-error-summary", str(program)],
        cwd=tmp_path,  # not the checkout: the package must be found as installed
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert "Cannot find implementation or library stub" not in result.stdout, result.stdout
    flagged = {int(m) for m in re.findall(r"program\.py:(\d+): error", result.stdout)}
    expected = {n for n, line in enumerate(SAMPLE.read_text().splitlines(), 1) if "# MISTAKE" in line}
    assert flagged == expected, result.stdout
