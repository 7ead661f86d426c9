"""`ics35 scan` and `set-id` as real processes on the pty simulator, including a line that ignores baud rates."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from ics35_async.cli import ExitCode
from ics35_async.sim import serving
from tests.support.cli_runs import run_process
from tests.support.terminal import screen_of, typed_on_a_terminal
from tests.support.timing import PATIENT_OPTION, REAL_TIME_OPTION

pytestmark = [
    pytest.mark.pty,
    pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the pty simulator needs Linux"),
]

# The timing profile's allowance for replies across a pty: a loaded machine answers later than an adapter.
LINE = [*REAL_TIME_OPTION, "--retries", "1"]
# Where the test counts replies and none may be missed: the patient allowance, long for a loaded machine, so
# only the IDs that should answer (and one that should not) are probed.
ANSWERED = [*PATIENT_OPTION, "--retries", "1"]


def ics35(port: str, *args: str) -> subprocess.CompletedProcess[str]:
    return run_process("--port", port, *args)


@pytest.fixture(scope="module")
def rate_blind_port() -> Iterator[str]:
    """Three servos at 115200 on a pty whose line runs at 115200 whatever the client sets."""
    with serving(["--ids", "2,5,17", "--fixed-baud"]) as path:
        yield path


@pytest.fixture
def lone_servo_port() -> Iterator[str]:
    with serving(["--ids", "0"]) as path:
        yield path


def test_scan_lists_each_servo_once_when_the_line_ignores_rates(rate_blind_port: str) -> None:
    # Every rate each servo answered at is counted: a late reply under load must not drop one.
    proc = ics35(rate_blind_port, *ANSWERED, "scan", "--ids", "2,5,17", "--quick", "--json")
    assert proc.returncode == 0, proc.stderr
    servos = json.loads(proc.stdout)["servos"]
    assert [(s["id"], s["baud"]) for s in servos] == [(2, 115200), (5, 115200), (17, 115200)]
    assert all(s["answered_at"] == [115200, 625000, 1250000] for s in servos)


@pytest.mark.slow
def test_set_id_refuses_several_servos_and_renumbers_a_lone_one(rate_blind_port: str, lone_servo_port: str) -> None:
    # -v: should a servo be missed, the failure shows each transaction that failed and how.
    proc = ics35(rate_blind_port, *ANSWERED, "set-id", "9", "--yes", "-v")
    assert proc.returncode == 5 and "IDs 2, 5, 17" in proc.stderr, proc.stderr

    proc = ics35(lone_servo_port, *ANSWERED, "set-id", "9", "--yes", "--json")
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout) == {"old": 0, "new": 9, "changed": True}
    proc = ics35(lone_servo_port, *ANSWERED, "scan", "--bauds", "115200", "--ids", "0,9", "--quick", "--json")
    assert [s["id"] for s in json.loads(proc.stdout)["servos"]] == [9]


def _refusing_url(scheme: str) -> str:
    """A local TCP port nobody listens on (bound, then let go): a connection there is refused."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"{scheme}://127.0.0.1:{s.getsockname()[1]}"


@pytest.mark.parametrize("scheme", ["socket", "rfc2217"])
def test_scan_of_a_port_that_never_opens_says_why_like_get_does(scheme: str) -> None:
    url = _refusing_url(scheme)
    proc = ics35(url, *LINE, "scan", "--quick")
    got = ics35(url, *LINE, "get", "1", "stretch")
    assert got.returncode == 3, got.stderr
    # Not "no servo answered ... at  baud" (exit 4) after a warning per rate: the port's own error, once.
    assert proc.returncode == 3, proc.stderr
    assert "no servo answered" not in proc.stderr and "skipped" not in proc.stderr
    assert "refused" in proc.stderr


def test_scan_with_an_empty_port_is_a_usage_error() -> None:
    proc = ics35("", "scan", "--quick")
    assert proc.returncode == 2, proc.stderr
    assert "port must not be empty" in proc.stderr and "skipped" not in proc.stderr


@pytest.mark.parametrize("command", [["scan"], ["scan", "--quick"], ["monitor"]], ids=" ".join)
def test_a_missing_port_is_said_before_any_progress_bar_is_drawn(tmp_path: Path, command: list[str]) -> None:
    # `ics35 --port /dev/ttyUSB9 scan` on a terminal drew "scanning 115200 baud ━━━ 0/96" before the port's error:
    # a scan looked begun on a port that was never opened.
    missing = tmp_path / "ttyUSB9"
    code, shown = typed_on_a_terminal(["--port", str(missing), *command], [])
    assert code == ExitCode.PORT, shown
    assert "scanning" not in shown and "━" not in shown, shown
    assert f"no serial port at '{missing}'" in " ".join(" ".join(screen_of(shown)).split()), shown
