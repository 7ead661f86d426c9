"""Ctrl-C in a program using ics35_async.blocking: a real SIGINT to a subprocess, no mocks.

The child prints progress lines; the parent sends SIGINT at known points and
reads the child's own report (JSON) of what it saw: which call was
cancelled on the loop before the interrupt reached it, whether the bus still
worked, and which threads and file descriptors were left at the end.
"""

from __future__ import annotations

import json
import os
import select
import signal
import subprocess
import sys
import textwrap
import time
from collections.abc import Iterator
from typing import Any

import pytest

from ics35_async.sim.launch import serving

pytestmark = pytest.mark.realtime

CHILD = textwrap.dedent(
    """
    import json, os, sys, threading, traceback

    import anyio

    from ics35_async import blocking

    def fds():
        return set(os.listdir("/proc/self/fd"))

    report = {}
    events = []
    before = fds()

    async def long_call():
        print("in call", flush=True)  # from the loop thread: the main thread is waiting for this call
        try:
            await anyio.sleep(3600)
        except BaseException as exc:
            events.append(type(exc).__name__)
            raise

    try:
        with blocking.open_bus(sys.argv[1]) as bus:
            try:
                bus.run(long_call)
            except KeyboardInterrupt:
                report["ended_on_loop_before_the_interrupt"] = list(events)
                report["bus_works_after"] = bus.servo(1).free()
            with bus.stream([1, 2, 3]) as stream:
                for frame in stream:
                    if frame.cycle >= 5:
                        break
            # ID 9 is absent: it goes offline after one cycle and is probed again only in an hour,
            # so after the first frames next_frame waits until the interrupt comes.
            with bus.stream([9], offline_after=1, probe_interval=3600) as stream:
                for frame in stream:
                    if not frame.failed:
                        print("waiting", flush=True)
    except KeyboardInterrupt:
        report["interrupted_in"] = "next_frame" if "next_frame" in traceback.format_exc() else traceback.format_exc()
    report["threads"] = [t.name for t in threading.enumerate()]
    report["fds_left"] = sorted(fds() - before)
    print(json.dumps(report), flush=True)
    """
)


@pytest.fixture(params=["pty", "sim"])
def port(request: pytest.FixtureRequest) -> Iterator[str]:
    if request.param == "sim":
        yield "sim://?ids=1-3"
    else:
        with serving(["--ids", "1-3"]) as path:  # real time, as on hardware
            yield path


def read_line(proc: subprocess.Popen[str], timeout: float = 30) -> str:
    assert proc.stdout is not None
    ready, _, _ = select.select([proc.stdout], [], [], timeout)
    assert ready, "the child said nothing"
    return proc.stdout.readline().strip()


def wait_until_every_thread_sleeps(pid: int, timeout: float = 30) -> None:
    """Until every thread of ``pid`` sleeps: then the main thread is in its wait, not waiting for the GIL.

    (A thread waiting for the GIL sleeps too, but then the thread holding it runs.)
    """
    deadline = time.monotonic() + timeout
    calm = 0
    while calm < 3:
        assert time.monotonic() < deadline, "the child never went idle"
        states = []
        for task in os.listdir(f"/proc/{pid}/task"):
            with open(f"/proc/{pid}/task/{task}/stat") as stat:
                states.append(stat.read().rsplit(")", 1)[1].split()[0])
        calm = calm + 1 if all(state == "S" for state in states) else 0
        time.sleep(0.01)


def test_ctrl_c_cancels_the_waiting_call_then_closes_everything(port: str) -> None:
    proc = subprocess.Popen(
        [sys.executable, "-c", CHILD, port], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        assert read_line(proc) == "in call"
        proc.send_signal(signal.SIGINT)
        assert read_line(proc) == "waiting"
        wait_until_every_thread_sleeps(proc.pid)
        proc.send_signal(signal.SIGINT)
        report: dict[str, Any] = json.loads(read_line(proc))
        _, stderr = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, stderr
    assert "Traceback" not in stderr, stderr
    # The interrupted call had ended on the loop (cancelled) before KeyboardInterrupt reached the caller,
    # and the bus carried on.
    assert report["ended_on_loop_before_the_interrupt"] == ["CancelledError"]
    assert report["bus_works_after"] == 7500
    # The second interrupt came while the stream waited; both with-blocks closed on the way out.
    assert report["interrupted_in"] == "next_frame"
    assert report["threads"] == ["MainThread"]
    assert report["fds_left"] == []
