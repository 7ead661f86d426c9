"""The engine compiled by mypyc (see setup.py and ics35_async.compiled): which build runs, and that it is said.

The development tree runs the engine as plain Python (an editable install does not compile it: compiled modules
would shadow every edit); ``make test`` also runs the engine's, the burst path's and the contract suite's tests on
a compiled copy of the tree (``make pytest-compiled``, which sets ``ICS35_EXPECT_COMPILED=1``).  The wheel's
build compiles it: tests/test_wheel.py checks what the installed wheel says.
"""

from __future__ import annotations

import importlib.machinery
import os
import runpy
import subprocess
import sys
from pathlib import Path

from ics35_async.compiled import ENGINE_NAME, engine_compiled
from ics35_async.engine import link, machine

EXPECTED = os.environ.get("ICS35_EXPECT_COMPILED") == "1"
ROOT = Path(__file__).resolve().parent.parent


def _compiled(path: str | None) -> bool:
    return path is not None and path.endswith(tuple(importlib.machinery.EXTENSION_SUFFIXES))


def test_the_engine_runs_as_this_tree_was_built() -> None:
    # A compiled pass that silently ran the plain modules (a build that failed quietly) would test nothing new;
    # a development tree with compiled modules in it runs stale code after an edit.
    assert _compiled(machine.__file__) is EXPECTED, machine.__file__
    assert _compiled(link.__file__) is EXPECTED, link.__file__
    on, said = engine_compiled()
    assert on is EXPECTED
    assert said.startswith("on (") if EXPECTED else said.startswith("off (")


def test_version_with_verbose_and_doctor_say_whether_the_engine_is_compiled() -> None:
    for args in (["--version", "-v"], ["doctor"]):
        done = subprocess.run(
            [sys.executable, "-m", "ics35_async.cli", *args], capture_output=True, text=True, timeout=60
        )
        assert done.returncode == 0, done.stderr
        (said,) = [ln for ln in done.stdout.splitlines() if ln.startswith(f"{ENGINE_NAME}:")]
        assert said == f"{ENGINE_NAME}: {engine_compiled()[1]}"


def test_the_engine_type_checks_for_mypyc_as_an_isolated_build_sees_it(tmp_path: Path) -> None:
    # An isolated build (pip's default) has mypy but none of the package's dependencies: mypyc's type check of the
    # compiled modules must pass there, or the wheel quietly holds the plain engine.  (A strict check reaching
    # the anyio driver through the engine's imports did fail there, Any for anyio's types.)
    constants = runpy.run_path(str(ROOT / "setup.py"), run_name="read_constants")
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "mypy",
            *constants["MYPYC_OPTIONS"],
            "--no-site-packages",
            f"--cache-dir={tmp_path}",
            *constants["COMPILED"],
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stdout + done.stderr
