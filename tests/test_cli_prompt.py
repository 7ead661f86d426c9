"""Ctrl-C at a [y/N] question: the first one ends the command with exit code 130, nothing written.

A real process gets a real SIGINT while it waits on the question (no mocks):
the question is asked inside the event loop, whose own SIGINT handler used to
swallow the first Ctrl-C.
"""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
import time
from collections.abc import Iterator

import pytest

from ics35_async.sim import serving

pytestmark = [
    pytest.mark.pty,
    pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the pty simulator needs Linux"),
]

LOOPS = {
    "asyncio": "import sys; sys.modules['uvloop'] = None; from ics35_async.cli import main; main()",
    "uvloop": "from ics35_async.cli import main; main()",
}


@pytest.fixture(scope="module")
def port() -> Iterator[str]:
    with serving(["--ids", "1,2"]) as path:
        yield path


def read_until(fd: int, marker: bytes, limit: float = 30.0) -> bytes:
    """Bytes from ``fd`` up to ``marker`` (a generous limit: this waits for the process, it measures nothing)."""
    seen = b""
    end = time.monotonic() + limit
    while marker not in seen:
        ready, _, _ = select.select([fd], [], [], max(0.0, end - time.monotonic()))
        if not ready:
            raise AssertionError(f"no {marker!r} from the command; it wrote: {seen.decode(errors='replace')}")
        chunk = os.read(fd, 4096)
        if not chunk:
            raise AssertionError(f"the command ended before {marker!r}: {seen.decode(errors='replace')}")
        seen += chunk
    return seen


# demo on "hardware" (a pty) asks before moving the servos a scan found; eeprom set asks before writing.
COMMANDS = {
    "demo": ["--timeout", "0.05", "demo", "--seconds", "1"],
    "eeprom-set": ["eeprom", "set", "1", "speed=5"],
}


@pytest.mark.parametrize("command", list(COMMANDS))
@pytest.mark.parametrize("loop", list(LOOPS))
def test_first_ctrl_c_at_the_question_exits_130(port: str, loop: str, command: str) -> None:
    if loop == "uvloop":
        pytest.importorskip("uvloop")
    where = port if command == "demo" else "sim://?ids=1"
    proc = subprocess.Popen(
        [sys.executable, "-c", LOOPS[loop], "--port", where, *COMMANDS[command]],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    try:
        assert proc.stderr is not None
        before = read_until(proc.stderr.fileno(), b"[y/N]")
        proc.send_signal(signal.SIGINT)
        code = proc.wait(timeout=20)
        rest = proc.stderr.read().decode(errors="replace")
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert code == 130, rest
    assert "Traceback" not in rest
    # In the words of what the command would have done: demo moves servos, eeprom set writes.
    assert ("nothing moved" if command == "demo" else "nothing was written") in rest, rest
    if command == "demo":
        assert b"Move servo(s) 1, 2" in before
        assert "written" not in rest
