"""Ending a controller program with a signal: ics35_async.run, in a real process sent SIGINT or SIGTERM."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time

import pytest

PROGRAM = textwrap.dedent(
    """
    import sys
    import ics35_async
    from ics35_async import open_bus
    from ics35_async.sim import VirtualLine

    sim = VirtualLine([1, 2, 3], realtime=True)
    ON_CLOSE = sys.argv[2]

    async def main() -> None:
        async with open_bus(sim) as bus, bus.stream([1, 2, 3], rate_hz=100, on_close=ON_CLOSE) as stream:
            stream.set_targets({1: 8000, 2: 7000, 3: 7500})
            async for frame in stream:
                if frame.cycle == 5:
                    print("streaming", flush=True)

    code = ics35_async.run(main, backend=sys.argv[1])
    print("free" if all(sim.servo(i).free for i in (1, 2, 3)) else "holding", flush=True)
    sys.exit(code)
    """
)


@pytest.mark.parametrize("backend", ["asyncio", "uvloop", "trio"])
@pytest.mark.parametrize(
    ("signum", "code", "on_close", "state"),
    [(signal.SIGTERM, 143, "free", "free"), (signal.SIGINT, 130, "hold", "holding")],
    ids=["SIGTERM-free", "SIGINT-hold"],
)
def test_a_signal_ends_the_program_cleanly_with_the_servos_as_chosen(
    backend: str, signum: int, code: int, on_close: str, state: str
) -> None:
    proc = subprocess.Popen(
        [sys.executable, "-c", PROGRAM, backend, on_close],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().strip() == "streaming"
        time.sleep(0.1)
        os.kill(proc.pid, signum)
        out, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
    assert proc.returncode == code, err
    assert out.strip() == state
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err


def test_an_ics_error_is_one_line_and_exit_1() -> None:
    program = textwrap.dedent(
        """
        import sys, ics35_async
        from ics35_async import open_bus

        async def main() -> None:
            async with open_bus("sim://?ids=1", adapter_latency=0.005) as bus:
                await bus.servo(9).read_stretch()

        sys.exit(ics35_async.run(main))
        """
    )
    result = subprocess.run([sys.executable, "-c", program], capture_output=True, text=True, timeout=60)
    assert result.returncode == 1
    assert result.stderr.startswith("error: ") and "Traceback" not in result.stderr


BLOCKING_PROGRAM = textwrap.dedent(
    """
    import sys
    from ics35_async import blocking
    from ics35_async.sim import VirtualLine

    sim = VirtualLine([1, 2], realtime=True)
    try:
        with blocking.stop_on_signals(), blocking.open_bus(sim) as bus, bus.stream([1, 2], on_close="free") as s:
            s.set_targets({1: 8000, 2: 7000})
            for n, frame in enumerate(s):
                if n == 5:
                    print("streaming", flush=True)
    finally:
        print("free" if all(sim.servo(i).free for i in (1, 2)) else "holding", flush=True)
    """
)


@pytest.mark.parametrize(("signum", "code"), [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_a_blocking_program_under_stop_on_signals_ends_cleanly(signum: int, code: int) -> None:
    proc = subprocess.Popen(
        [sys.executable, "-c", BLOCKING_PROGRAM], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().strip() == "streaming"
        os.kill(proc.pid, signum)
        out, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
    assert proc.returncode == code, err
    assert out.strip() == "free"
    assert "Traceback" not in err, err


THREADS_AT_EXIT = textwrap.dedent(
    """
    import sys, threading
    import ics35_async
    from ics35_async import open_bus

    async def main() -> None:
        async with open_bus(sys.argv[2]) as bus, bus.stream([1, 2, 3]) as stream:
            for _ in range(3):
                await stream.next_frame()

    code = ics35_async.run(main, backend=sys.argv[1])
    print(sorted(t.name for t in threading.enumerate() if t is not threading.main_thread()), flush=True)
    sys.exit(code)
    """
)


@pytest.mark.parametrize("backend", ["asyncio", "uvloop", "trio"])
def test_no_thread_is_left_when_the_program_ends(backend: str) -> None:
    # A port the loop opens in a worker thread: that worker must not outlive the program's run
    # (trio keeps idle workers of its own thread cache alive for seconds).
    from ics35_async.sim.launch import serving

    with serving(["--ids", "1-3"]) as path:
        done = subprocess.run(
            [sys.executable, "-c", THREADS_AT_EXIT, backend, path], capture_output=True, text=True, timeout=60
        )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]", done.stdout
