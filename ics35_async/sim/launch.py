"""Run the pty server in a subprocess, for tests and scripts.

Needs nothing POSIX-only to import; the server it starts does
(``python -m ics35_async.sim``, :mod:`.server_cli`).
"""

from __future__ import annotations

import contextlib
import select
import signal
import subprocess
import sys
from collections.abc import Iterator, Sequence
from typing import IO


def start_subprocess(
    args: Sequence[str] = (),
    *,
    timeout: float = 15.0,
    python: str | None = None,
    quiet: bool = False,
    notes: IO[str] | None = None,
) -> tuple[subprocess.Popen[str], str]:
    """Launch the server in a subprocess; return it and the device path it printed.

    ``args`` are the server's command-line arguments (``python -m ics35_async.sim --help``);
    ``timeout``: seconds to wait for the path; ``python``: the interpreter (default: this one);
    ``quiet`` sends its notes (stderr: what it serves, and on exit how many transactions and
    any bytes no client took) to /dev/null, ``notes`` to that file instead.  Stop it with
    :func:`stop_subprocess` (or use :func:`serving`).
    """
    proc = subprocess.Popen(
        [python or sys.executable, "-m", "ics35_async.sim", *args],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=notes if notes is not None else subprocess.DEVNULL if quiet else None,
        text=True,
    )
    assert proc.stdout is not None
    ready, _, _ = select.select([proc.stdout], [], [], timeout)
    line = proc.stdout.readline() if ready else ""
    if not line.strip():
        stop_subprocess(proc)
        raise RuntimeError(
            f"the simulator did not print its device path within {timeout} s (exit code {proc.returncode})"
        )
    return proc, line.strip()


def stop_subprocess(proc: subprocess.Popen[str], timeout: float = 5.0) -> int:
    """SIGTERM the server ``proc``, wait for it (kill after ``timeout``), return its exit code."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    if proc.stdout is not None:
        proc.stdout.close()
    return proc.returncode


@contextlib.contextmanager
def serving(args: Sequence[str] = (), *, timeout: float = 15.0) -> Iterator[str]:
    """``with serving(["--ids", "1-3"]) as path:`` a server subprocess for the block.

    ``args`` and ``timeout`` are :func:`start_subprocess`'s.
    """
    proc, path = start_subprocess(args, timeout=timeout)
    try:
        yield path
    finally:
        stop_subprocess(proc)
