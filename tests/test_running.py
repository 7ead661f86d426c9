"""Ending a controller program with a signal: ics35_async.run, in a real process sent SIGINT, SIGTERM or SIGHUP."""

from __future__ import annotations

import asyncio
import json
import os
import re
import select
import signal
import subprocess
import sys
import textwrap
import threading
import time
from collections.abc import AsyncIterator
from typing import Any

import pytest

import ics35_async
from ics35_async import InvalidArgument
from ics35_async.extras import install_command, installed_from
from tests.support.timing import scaled

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
    [
        (signal.SIGTERM, 143, "free", "free"),
        (signal.SIGINT, 130, "hold", "holding"),
        (signal.SIGHUP, 129, "free", "free"),
    ],
    ids=["SIGTERM-free", "SIGINT-hold", "SIGHUP-free"],
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


@pytest.mark.parametrize("backend", ["asyncio", "trio"])
def test_main_s_own_exception_comes_out_as_itself(backend: str) -> None:
    # "Other exceptions propagate": the program's `except KeyError` around run() must catch its KeyError
    # (it came out wrapped in the task group's ExceptionGroup).
    async def main() -> None:
        raise KeyError("x")

    with pytest.raises(KeyError):
        ics35_async.run(main, backend=backend)  # type: ignore[arg-type]

    async def chained() -> None:
        try:
            raise KeyError("x")
        except KeyError as exc:
            raise ValueError("y") from exc

    with pytest.raises(ValueError, match="y") as raised:
        ics35_async.run(chained, backend=backend)  # type: ignore[arg-type]
    assert isinstance(raised.value.__cause__, KeyError)  # its cause, as main raised it

    async def own_group() -> None:
        raise ExceptionGroup("main's own", [KeyError("z")])

    with pytest.raises(ExceptionGroup, match="main's own"):
        ics35_async.run(own_group, backend=backend)  # type: ignore[arg-type]


def test_misuses_of_run_are_said_before_anything_runs() -> None:
    async def main() -> None:
        pass

    coroutine = main()
    with pytest.raises(InvalidArgument, match=r"run\(main\), not run\(main\(\)\)"):
        ics35_async.run(coroutine)  # type: ignore[arg-type]
    with pytest.raises(InvalidArgument, match="backend"):
        ics35_async.run(main, backend="uvlopp")  # type: ignore[arg-type]

    async def inside() -> None:
        ics35_async.run(main)

    with pytest.raises(InvalidArgument, match="inside a running event loop"):
        asyncio.run(inside())


def test_run_and_stop_on_signals_outside_the_main_thread_say_so_before_anything_runs() -> None:
    """Python hands signals to the main thread only: called from another thread (a program whose main thread runs
    a GUI), ``run``, ``blocking.run`` and ``stop_on_signals`` failed with Python's own ``RuntimeError`` or
    ``ValueError`` (``set_wakeup_fd only works in main thread``, ``signal only works in main thread``)."""
    from ics35_async import blocking

    ran: list[str] = []
    refused: list[BaseException] = []

    async def main() -> None:
        ran.append("run")

    def plain() -> None:
        ran.append("blocking.run")

    def within() -> None:
        with blocking.stop_on_signals():
            ran.append("stop_on_signals")

    def worker() -> None:
        for call in (lambda: ics35_async.run(main), lambda: blocking.run(plain), within):
            try:
                call()
            except Exception as exc:
                refused.append(exc)

    thread = threading.Thread(target=worker)
    thread.start()
    thread.join(10)
    assert ran == []
    assert [type(exc) for exc in refused] == [InvalidArgument] * 3, refused
    assert all("main thread" in str(exc) for exc in refused), refused


@pytest.mark.parametrize("backend", ["uvloop", "trio"])
def test_a_backend_not_installed_is_said_with_the_extra_that_installs_it(
    backend: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    # run(main, backend="uvloop") without uvloop was a ModuleNotFoundError's traceback (trio: anyio's LookupError
    # naming anyio's extra), from inside the run; said before anything starts, with this package's extra.
    monkeypatch.setitem(sys.modules, backend, None)  # (as if not installed: its import fails)

    async def main() -> None:
        pytest.fail("ran")

    with pytest.raises(InvalidArgument, match=rf"backend='{backend}' needs {backend}: .*\[{backend}\]") as raised:
        ics35_async.run(main, backend=backend)  # type: ignore[arg-type]
    # Said the way this copy was installed: a clone installed with `pip install -e` gets the extra from the clone
    # (the package index would fetch a second copy, if it has one at all), as `ics35 web` says it.
    assert install_command(backend, installed_from()) in str(raised.value)
    if installed_from()[0] == "editable":
        assert f"pip install 'ics35_async[{backend}]'" not in str(raised.value)


@pytest.mark.parametrize("backend", ["asyncio", "trio"])
def test_a_main_that_is_not_async_is_said_plainly(backend: str) -> None:
    # `def main()` where `async def main()` was meant: said as run()'s misuse, not as a TypeError from
    # inside the task that awaited what main returned.
    def main() -> None:
        pass

    with pytest.raises(InvalidArgument, match=r"^run\(\) takes an async function \(async def main\(\)\)"):
        ics35_async.run(main, backend=backend)  # type: ignore[arg-type]

    async def generator() -> AsyncIterator[int]:
        yield 1

    with pytest.raises(InvalidArgument, match=r"generator\(\) returned an async_generator, not an awaitable"):
        ics35_async.run(generator, backend=backend)  # type: ignore[arg-type]


def test_sys_exit_in_main_ends_the_program_with_its_code_and_no_traceback() -> None:
    program = textwrap.dedent(
        """
        import sys, ics35_async
        from ics35_async import open_bus

        async def main() -> None:
            async with open_bus("sim://?ids=1") as bus:
                await bus.servo(1).read_stretch()
                sys.exit(3)

        sys.exit(ics35_async.run(main))
        """
    )
    result = subprocess.run([sys.executable, "-c", program], capture_output=True, text=True, timeout=60)
    assert result.returncode == 3, result.stderr
    assert result.stderr == "", result.stderr


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


@pytest.mark.parametrize(("signum", "code"), [(signal.SIGTERM, 143), (signal.SIGINT, 130), (signal.SIGHUP, 129)])
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


# The blocking API inside an async main under ics35_async.run: each blocking call holds the event loop, so the
# loop's signal receiver never ran and Ctrl-C did nothing (the stream streamed on; SIGHUP at last killed it holding).
BLOCKING_IN_ASYNC_PROGRAM = textwrap.dedent(
    """
    import sys
    import ics35_async
    from ics35_async import blocking
    from ics35_async.sim import VirtualLine

    sim = VirtualLine([1, 2], realtime=True)

    async def main() -> None:
        with blocking.open_bus(sim) as bus, bus.stream([1, 2], rate_hz=50, on_close="free") as s:
            s.set_targets({1: 8000, 2: 7000})
            for n, frame in enumerate(s):
                if n == 5:
                    print("streaming", flush=True)

    code = ics35_async.run(main, backend=sys.argv[1])
    print("free" if all(sim.servo(i).free for i in (1, 2)) else "holding", flush=True)
    sys.exit(code)
    """
)


@pytest.mark.parametrize("backend", ["asyncio", "uvloop", "trio"])
@pytest.mark.parametrize(("signum", "code"), [(signal.SIGTERM, 143), (signal.SIGINT, 130), (signal.SIGHUP, 129)])
def test_a_signal_stops_a_blocking_call_made_inside_an_async_main(backend: str, signum: int, code: int) -> None:
    proc = subprocess.Popen(
        [sys.executable, "-c", BLOCKING_IN_ASYNC_PROGRAM, backend],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().strip() == "streaming"
        os.kill(proc.pid, signum)
        out, err = proc.communicate(timeout=scaled(10))
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


# A signal's exception lands between any two bytecodes of the main thread.  This program stops a
# blocking stream with SIGTERM at each of the main thread's calls and returns in turn (a profile hook
# sends the signal), from a given frame on, under stop_on_signals: each time, the program must stop
# with 143, the servos free and the bus's thread gone, and nothing may print (a lock left held hangs
# the loop thread; a Condition's lock released twice raises RuntimeError; a stop dropped inside a
# weakref callback prints "Exception ignored").  It prints the points it got wrong and how many it
# tried (it stops early once the signal would come after the whole ``with`` block).
SIGNAL_EVERYWHERE = textwrap.dedent(
    """
    import faulthandler, json, os, signal, sys, threading
    from ics35_async import blocking
    from ics35_async.sim import VirtualLine

    calls, hang_after = int(sys.argv[1]), float(sys.argv[2])
    first_frame, break_frame, then_move = map(int, sys.argv[3:6])
    faulthandler.dump_traceback_later(hang_after, exit=True)  # a hang: the stacks, then exit 1
    after = []  # a signal after stop_on_signals has handed SIGTERM back (the sweep is past the block's end)
    signal.signal(signal.SIGTERM, lambda signum, frame: after.append(signum))
    bad = []
    tried = 0
    for n in range(1, calls + 1):
        events = 0
        fired = moving = False

        def hook(frame, event, arg):
            global events, fired, fired_moving
            events += 1
            if events == n:
                sys.setprofile(None)
                fired, fired_moving = True, moving
                os.kill(os.getpid(), signal.SIGTERM)

        sim = VirtualLine([1, 2], realtime=True)
        outcome = "not stopped"
        try:
            with blocking.stop_on_signals(), blocking.open_bus(sim) as bus:
                with bus.stream([1, 2], on_close="free") as s:
                    s.set_targets({1: 8000, 2: 7000})
                    for k, frame in enumerate(s):
                        if k == first_frame:  # from this frame on, the n-th call is signalled
                            sys.setprofile(hook)
                        if k == break_frame:
                            break
                if then_move:  # the program's next command: a stop that came before it must keep it off the wire
                    moving = True
                    bus.servo(1).set_position(9000)
        except SystemExit as stop:
            outcome = f"exit {stop.code}"
        except BaseException as exc:
            outcome = repr(exc)
        sys.setprofile(None)
        if not fired or after or fired_moving:
            break  # the n-th call comes after the stream's close (and the bus's): every point before was tried
        tried = n
        if outcome == "exit 143" and not all(sim.servo(i).free for i in (1, 2)):
            outcome = "servos holding"
        left = [t.name for t in threading.enumerate() if t.name.startswith("ics35 blocking")]
        if outcome == "exit 143" and left:
            outcome = f"threads left: {left}"
        if outcome != "exit 143":
            bad.append((n, outcome))
    print(json.dumps({"bad": bad, "tried": tried}), flush=True)
    """
)


def signal_everywhere(calls: int, first_frame: int, break_frame: int, then_move: bool = False) -> dict[str, Any]:
    args = [str(calls), str(scaled(60)), str(first_frame), str(break_frame), str(int(then_move))]
    done = subprocess.run(
        [sys.executable, "-c", SIGNAL_EVERYWHERE, *args],
        capture_output=True,
        text=True,
        timeout=scaled(90),
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stderr == ""
    result: dict[str, Any] = json.loads(done.stdout)
    return result


@pytest.mark.slow
def test_a_stop_signal_at_any_point_of_a_blocking_wait_stops_the_program_cleanly() -> None:
    # From the third frame on: the calls of a stream running.
    assert signal_everywhere(150, first_frame=2, break_frame=200) == {"bad": [], "tried": 150}


@pytest.mark.slow
def test_a_stop_signal_at_any_point_of_the_closes_stops_the_program_with_servos_free() -> None:
    # From the loop's break on: the calls of the stream's close (servos freed), then the bus's (its thread
    # joined), to the end of the with block.
    result = signal_everywhere(2000, first_frame=3, break_frame=3)
    assert result["bad"] == []
    # It swept the closes to their end (how many calls they take varies with the real-time simulator).
    assert 150 < result["tried"] < 2000


@pytest.mark.slow
def test_a_stop_signal_in_a_streams_close_keeps_the_programs_next_command_off_the_wire() -> None:
    # The stream's close, then a command of the program's own: a stop that came before that command must
    # end the program before it goes out (the servo stays free), even one held until the close was over.
    result = signal_everywhere(2000, first_frame=3, break_frame=3, then_move=True)
    assert result["bad"] == []
    assert 100 < result["tried"] < 2000


def test_every_blocking_close_and_exit_is_a_close_step() -> None:
    # A close that is not one would be cut short by a stop landing as it starts (the sweeps above use
    # ``with``; a program may call close() itself).
    from ics35_async.blocking import BlockingBus, BlockingRobot, BlockingStream
    from ics35_async.running import _CLOSING

    for cls in (BlockingBus, BlockingStream, BlockingRobot):
        for name in ("close", "__exit__"):
            assert getattr(cls, name).__code__ is _CLOSING, f"{cls.__name__}.{name}"


FINALIZER_PROGRAM = textwrap.dedent(
    """
    import os, signal, sys
    from ics35_async import blocking
    from ics35_async.sim import VirtualLine

    class SignalsWhenCollected:
        def __del__(self):
            os.kill(os.getpid(), signal.SIGTERM)  # the handler's stop is raised inside __del__

    sim = VirtualLine([1, 2], realtime=True)
    try:
        with blocking.stop_on_signals(), blocking.open_bus(sim) as bus, bus.stream([1, 2], on_close="free") as s:
            for k, frame in enumerate(s):
                if k == 2:
                    SignalsWhenCollected()
                if k == 200:
                    print("not stopped", flush=True)
                    break
    finally:
        print("free" if all(sim.servo(i).free for i in (1, 2)) else "holding", flush=True)
    """
)


def test_a_stop_signal_that_lands_in_a_finalizer_still_stops_the_program() -> None:
    # Python prints and drops an exception raised in __del__; the stop must not be lost with it.
    done = subprocess.run([sys.executable, "-c", FINALIZER_PROGRAM], capture_output=True, text=True, timeout=60)
    assert (done.returncode, done.stdout.strip(), done.stderr) == (143, "free", "")


DROPPED_LAST = textwrap.dedent(
    """
    import os, signal
    from ics35_async import blocking
    from ics35_async.sim import VirtualLine

    class SignalsWhenCollected:
        def __del__(self):
            os.kill(os.getpid(), signal.SIGTERM)  # the handler's stop is raised inside __del__

    sim = VirtualLine([1], realtime=True)
    with blocking.stop_on_signals():
        with blocking.open_bus(sim, adapter_latency=0.5) as bus:  # (a loaded machine: the read must not fail)
            bus.servo(1).read_stretch()
        SignalsWhenCollected()  # after the last blocking call: no later call raises the dropped stop
        print("went on", flush=True)
    print("not stopped", flush=True)
    """
)


def test_a_stop_a_finalizer_drops_after_the_last_blocking_call_still_ends_the_program() -> None:
    done = subprocess.run([sys.executable, "-c", DROPPED_LAST], capture_output=True, text=True, timeout=scaled(60))
    assert (done.returncode, done.stdout.split(), done.stderr) == (143, ["went", "on"], "")


def test_stop_on_signals_inside_another_leaves_the_outer_one_in_charge() -> None:
    from ics35_async.blocking import stop_on_signals
    from ics35_async.running import stop_signals

    hook, handler = sys.unraisablehook, signal.getsignal(signal.SIGTERM)
    with stop_on_signals():
        with stop_on_signals():
            pass
        assert stop_signals.active  # the outer block still defers a signal during a blocking wait
        assert signal.getsignal(signal.SIGTERM) is not handler
    assert sys.unraisablehook is hook and signal.getsignal(signal.SIGTERM) is handler


def test_a_wait_woken_early_blocks_again_until_its_outcome_is_settled() -> None:
    # A stop signal wakes the main thread's wait; the wait that follows (for a call to end) must
    # block again, not find the lock free and spin until the loop thread settles the outcome.
    from ics35_async.blocking.loop_thread import Outcome

    outcome: Outcome[int] = Outcome()
    outcome.wake()
    assert outcome.wait(0.0) is False
    assert outcome.wait(0.0) is False and outcome._wake.locked()  # taken again: a timed wait would block
    outcome.set_result(7)
    assert outcome.wait(0.0) is True and outcome.result() == 7


# Ctrl-C pressed twice (or three times) in a row: a program whose close takes its time (a robot slowing to
# rest, here a pause in a finally) under run() or stop_on_signals.  The first press stops it; it prints
# "closing" as its close begins and "closed" as it ends.
SLOW_CLOSE_ASYNC = textwrap.dedent(
    """
    import sys, anyio, ics35_async
    from ics35_async import open_bus
    from ics35_async.sim import VirtualLine

    sim = VirtualLine([1, 2], realtime=True)
    PAUSE = float(sys.argv[1])

    async def main() -> None:
        async with open_bus(sim) as bus, bus.stream([1, 2], rate_hz=100, on_close="free") as stream:
            stream.set_targets({1: 8000, 2: 7000})
            try:
                async for frame in stream:
                    if frame.cycle == 5:
                        print("streaming", flush=True)
            finally:
                with anyio.CancelScope(shield=True):
                    print("closing", flush=True)
                    await anyio.sleep(PAUSE)
                    print("closed", flush=True)

    code = ics35_async.run(main)
    print("free" if all(sim.servo(i).free for i in (1, 2)) else "holding", flush=True)
    sys.exit(code)
    """
)

SLOW_CLOSE_BLOCKING = textwrap.dedent(
    """
    import sys, time
    from ics35_async import blocking
    from ics35_async.sim import VirtualLine

    sim = VirtualLine([1, 2], realtime=True)
    PAUSE = float(sys.argv[1])
    try:
        with blocking.stop_on_signals(), blocking.open_bus(sim) as bus, bus.stream([1, 2], on_close="free") as s:
            s.set_targets({1: 8000, 2: 7000})
            try:
                for n, frame in enumerate(s):
                    if n == 5:
                        print("streaming", flush=True)
            finally:
                print("closing", flush=True)
                time.sleep(PAUSE)
                print("closed", flush=True)
    finally:
        print("free" if all(sim.servo(i).free for i in (1, 2)) else "holding", flush=True)
    """
)


def press_ctrl_c(
    program: str, pause: float, gaps: list[float], wait_for_close: bool, signum: int = signal.SIGINT
) -> tuple[int, str, str]:
    """Run ``program``, then SIGINT (or ``signum``) once it streams, and again after each of ``gaps`` (seconds;
    from "closing" on, with ``wait_for_close``): its exit code, stdout and stderr."""
    proc = subprocess.Popen(
        [sys.executable, "-c", program, str(pause)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().strip() == "streaming"
        lines = ["streaming"]
        os.kill(proc.pid, signum)
        if wait_for_close:
            lines.append(proc.stdout.readline().strip())
            assert lines[-1] == "closing"
        for gap in gaps:
            time.sleep(gap)
            os.kill(proc.pid, signum)
        out, err = proc.communicate(timeout=scaled(30))
    finally:
        proc.kill()
    return proc.returncode, "\n".join([*lines, *out.split()]), err


@pytest.mark.parametrize("program", [SLOW_CLOSE_ASYNC, SLOW_CLOSE_BLOCKING], ids=["run", "stop_on_signals"])
@pytest.mark.parametrize("gap", [0.001, 0.015, 0.05])
def test_ctrl_c_twice_in_a_row_ends_the_program_as_once_does(program: str, gap: float) -> None:
    # A double press, the second 1-50 ms after the first: as the close runs or just after it ended, as
    # the program exits.  It exited by SIGINT with KeyboardInterrupt's traceback, or killed by it.
    for _ in range(3):
        code, out, err = press_ctrl_c(program, 0.0, [gap], wait_for_close=False)
        assert code == 130, err
        assert out.split()[-3:] == ["closing", "closed", "free"], out
        assert "Traceback" not in err and "KeyboardInterrupt" not in err, err


@pytest.mark.parametrize("program", [SLOW_CLOSE_ASYNC, SLOW_CLOSE_BLOCKING], ids=["run", "stop_on_signals"])
def test_a_second_ctrl_c_during_the_close_is_said_and_the_close_goes_on(program: str) -> None:
    code, out, err = press_ctrl_c(program, 1.0, [0.2], wait_for_close=True)
    assert code == 130, err
    assert out.split()[-2:] == ["closed", "free"], out
    assert err.count("\n") == 1 and "Ctrl-C again" in err and "once more" in err, err


@pytest.mark.parametrize("program", [SLOW_CLOSE_ASYNC, SLOW_CLOSE_BLOCKING], ids=["run", "stop_on_signals"])
def test_a_third_ctrl_c_during_the_close_forces_the_program_out(program: str) -> None:
    code, out, err = press_ctrl_c(program, 30.0, [0.2, 0.2], wait_for_close=True)
    assert code in (130, -signal.SIGINT), err  # (as a shell reports either: 130)
    assert "closed" not in out.split(), out
    assert "Traceback" not in err and "forced out" in err and "cut short" in err, err


@pytest.mark.parametrize("program", [SLOW_CLOSE_ASYNC, SLOW_CLOSE_BLOCKING], ids=["run", "stop_on_signals"])
def test_sighup_again_during_the_close_neither_is_said_nor_forces_out(program: str) -> None:
    # A closed terminal sends SIGHUP more than once (the kernel to the foreground group, the shell to its jobs):
    # no one pressed anything, and the servos' rest must not be cut short by the third.
    code, out, err = press_ctrl_c(program, 1.0, [0.1, 0.1, 0.1], wait_for_close=True, signum=signal.SIGHUP)
    assert code == 129, err
    assert out.split()[-2:] == ["closed", "free"], out
    assert err == "", err


def _started_ignoring_sigint() -> None:
    """As a shell without job control starts a background command (``./robot.py &`` in a script)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


@pytest.mark.parametrize(
    "program",
    [
        pytest.param([PROGRAM, "asyncio", "free"], id="run-asyncio"),
        pytest.param([PROGRAM, "uvloop", "free"], id="run-uvloop"),
        pytest.param([PROGRAM, "trio", "free"], id="run-trio"),
        pytest.param([BLOCKING_PROGRAM], id="stop_on_signals"),
    ],
)
def test_a_program_started_ignoring_sigint_keeps_ignoring_it(program: list[str]) -> None:
    # The Ctrl-C typed for the script's foreground command reaches its background jobs too: they were started
    # ignoring it so that it does not stop them, and a robot program must not start hearing it.  SIGTERM still
    # stops it as asked.
    proc = subprocess.Popen(
        [sys.executable, "-c", *program],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=_started_ignoring_sigint,
    )
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().strip() == "streaming"
        os.kill(proc.pid, signal.SIGINT)
        time.sleep(scaled(0.5))
        assert proc.poll() is None, proc.communicate()
        os.kill(proc.pid, signal.SIGTERM)
        out, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
    assert proc.returncode == 143, err
    assert out.strip() == "free"
    assert "Traceback" not in err, err


# A program under run (argv[1] "run") or blocking.run ("blocking"), its SIGHUP its own: argv[2] "own" (a handler
# of its own, as a program that reloads its configuration on SIGHUP has) or "ignored" (started under nohup).
HANGUP_KEPT = textwrap.dedent(
    """
    import os, signal, sys
    import ics35_async
    from ics35_async import blocking, open_bus
    from ics35_async.sim import VirtualLine

    sim = VirtualLine([1, 2], realtime=True)

    def reload(signum, frame):
        os.write(1, b"reloaded\\n")

    if sys.argv[2] == "own":
        signal.signal(signal.SIGHUP, reload)
    before = signal.getsignal(signal.SIGHUP)

    async def async_main() -> None:
        async with open_bus(sim) as bus, bus.stream([1, 2], rate_hz=50, on_close="free") as s:
            s.set_targets({1: 8000, 2: 7000})
            async for frame in s:
                if frame.cycle == 5:
                    print("streaming", flush=True)

    def blocking_main() -> None:
        with blocking.open_bus(sim) as bus, bus.stream([1, 2], rate_hz=50, on_close="free") as s:
            s.set_targets({1: 8000, 2: 7000})
            for frame in s:
                if frame.cycle == 5:
                    print("streaming", flush=True)

    code = ics35_async.run(async_main) if sys.argv[1] == "run" else blocking.run(blocking_main)
    print("free" if all(sim.servo(i).free for i in (1, 2)) else "holding", flush=True)
    print("kept" if signal.getsignal(signal.SIGHUP) is before else "replaced", flush=True)
    sys.exit(code)
    """
)


def _started_under_nohup() -> None:
    signal.signal(signal.SIGHUP, signal.SIG_IGN)


@pytest.mark.parametrize("runner", ["run", "blocking"])
@pytest.mark.parametrize("handler", ["own", "ignored"])
def test_a_program_s_own_or_ignored_sighup_is_left_to_it(runner: str, handler: str) -> None:
    # run() and blocking.run take SIGHUP only where it has Python's default (the process dies): a handler of the
    # program's own (a configuration reloaded) runs as before and the program goes on; under nohup it stays
    # ignored.  SIGTERM still stops the program, and the handler is still there once run() has returned.
    proc = subprocess.Popen(
        [sys.executable, "-c", HANGUP_KEPT, runner, handler],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=_started_under_nohup if handler == "ignored" else None,
    )
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().strip() == "streaming"
        os.kill(proc.pid, signal.SIGHUP)
        if handler == "own":
            assert proc.stdout.readline().strip() == "reloaded"
        time.sleep(scaled(0.5))
        assert proc.poll() is None, proc.communicate()
        os.kill(proc.pid, signal.SIGTERM)
        out, err = proc.communicate(timeout=scaled(30))
    finally:
        proc.kill()
    assert proc.returncode == 143, err
    assert out.split() == ["free", "kept"], out
    assert "Traceback" not in err, err


# A program whose stdout and stderr are a terminal, stopped by SIGHUP under run (argv[1] "run") or blocking.run
# ("blocking"): its close writes to both once the terminal is gone (hung up), then its servos' state goes to the
# file argv[2].
HANGUP_ON_A_TERMINAL = textwrap.dedent(
    """
    import sys, time
    import anyio
    import ics35_async
    from ics35_async import blocking, open_bus
    from ics35_async.sim import VirtualLine

    sim = VirtualLine([1, 2], realtime=True)

    def said_after_the_terminal_went() -> None:
        time.sleep(0.5)  # (the terminal is hung up meanwhile)
        for stream in (sys.stdout, sys.stderr):
            print("closing", file=stream, flush=True)

    async def async_main() -> None:
        async with open_bus(sim) as bus, bus.stream([1, 2], rate_hz=50, on_close="free") as s:
            s.set_targets({1: 8000, 2: 7000})
            try:
                async for frame in s:
                    if frame.cycle == 5:
                        print("streaming", flush=True)
            finally:
                with anyio.CancelScope(shield=True):
                    said_after_the_terminal_went()

    def blocking_main() -> None:
        with blocking.open_bus(sim) as bus, bus.stream([1, 2], rate_hz=50, on_close="free") as s:
            s.set_targets({1: 8000, 2: 7000})
            try:
                for frame in s:
                    if frame.cycle == 5:
                        print("streaming", flush=True)
            finally:
                said_after_the_terminal_went()

    code = ics35_async.run(async_main) if sys.argv[1] == "run" else blocking.run(blocking_main)
    with open(sys.argv[2], "w") as state:
        state.write("free" if all(sim.servo(i).free for i in (1, 2)) else "holding")
    print("stopped", flush=True)
    sys.exit(code)
    """
)


@pytest.mark.parametrize("runner", ["run", "blocking"])
def test_a_program_whose_terminal_hung_up_closes_without_a_traceback(runner: str, tmp_path: Any) -> None:
    # The terminal closed (ssh gone, the window shut): after its SIGHUP a write to it fails (EIO), and a print in
    # the program's close, or the library's own last words, would end the stop in a traceback, the close cut
    # short.  What goes to the terminal from then on is dropped instead.
    master, slave = os.openpty()
    state = tmp_path / "state"
    proc = subprocess.Popen(
        [sys.executable, "-c", HANGUP_ON_A_TERMINAL, runner, str(state)],
        stdin=subprocess.DEVNULL,
        stdout=slave,
        stderr=slave,
    )
    os.close(slave)
    try:
        seen = b""
        deadline = time.monotonic() + scaled(30)
        while b"streaming" not in seen and select.select([master], [], [], max(0, deadline - time.monotonic()))[0]:
            seen += os.read(master, 1024)
        assert b"streaming" in seen, seen
        os.kill(proc.pid, signal.SIGHUP)
        os.close(master)  # hung up: the program's writes to it fail from now on
        master = -1
        proc.wait(timeout=scaled(30))
    finally:
        if master >= 0:
            os.close(master)
        proc.kill()
    assert proc.returncode == 129
    assert state.read_text() == "free"


# A plain 50 Hz gait script under blocking.run: argv[1] what it does once its port is lost ("end": nothing,
# "catch": catches PortLost itself, "reconnect": opened with reconnect=True, returns at the first frame after
# the port came back; "alone": nothing, under blocking.stop_on_signals() alone instead of blocking.run).
# It reads its port from stdin once it has imported everything (see gait_on_a_pty).
BLOCKING_GAIT = textwrap.dedent(
    """
    import sys
    from ics35_async import PortLost, blocking

    MODE = sys.argv[1]
    STAND = {1: 7500, 2: 7500}
    print("ready", flush=True)
    PORT = input()

    def main() -> None:
        with blocking.open_bus(PORT, reconnect=MODE == "reconnect") as bus:
            stream = bus.stream(STAND, rate_hz=50, on_close="free")
            stream.set_targets(STAND)
            with stream:
                try:
                    for frame in stream:
                        if frame.cycle == 5:
                            print("streaming", flush=True)
                        if frame.resumed:
                            print("resumed", flush=True)
                            return
                        stream.set_targets(STAND, lift_holds=False)
                except PortLost:
                    if MODE != "catch":
                        raise
                    print("caught", flush=True)

    if MODE == "alone":
        with blocking.stop_on_signals():
            main()
    else:
        sys.exit(blocking.run(main))
    """
)


# BLOCKING_GAIT's "end" mode as an async program under ics35_async.run.
ASYNC_GAIT = textwrap.dedent(
    """
    import sys
    import ics35_async
    from ics35_async import open_bus

    STAND = {1: 7500, 2: 7500}
    print("ready", flush=True)
    PORT = input()

    async def main() -> None:
        async with open_bus(PORT) as bus, bus.stream(STAND, rate_hz=50, on_close="free") as stream:
            stream.set_targets(STAND)
            async for frame in stream:
                if frame.cycle == 5:
                    print("streaming", flush=True)

    sys.exit(ics35_async.run(main))
    """
)


# Under ics35_async.run, a program with a second line it only checks now and then, which goes on without that line
# once its port is lost for good (no error of it reaches the program's end).
ASIDE_LINE = textwrap.dedent(
    """
    import sys
    import anyio
    import ics35_async
    from ics35_async import open_bus

    print("ready", flush=True)
    PORT = input()

    async def main() -> None:
        async with open_bus(PORT) as aside, open_bus("sim://?ids=1") as bus:
            await aside.servo(1).read_temperature()
            with anyio.fail_after(30):
                while aside.is_open:
                    await bus.servo(1).read_temperature()
                    await anyio.sleep(0.05)
            print("gone", flush=True)

    sys.exit(ics35_async.run(main))
    """
)


# The simulator's port goes this long after it starts, once the program streams (it prints "streaming" at its fifth
# cycle): a second was not always enough for a loaded machine to open the port and run five cycles.
UNPLUG_AFTER_STREAMING = ("--unplug-after", str(scaled(2.0)))


def gait_on_a_pty(
    pty_sim: Any, mode: str, *sim_args: str, program: str = BLOCKING_GAIT
) -> subprocess.CompletedProcess[str]:
    """``program`` (BLOCKING_GAIT) in a process of its own on a pty simulator started with ``sim_args``, once the
    program has imported everything: a simulator's ``--unplug-after`` counts from its start, and a loaded machine
    can take seconds to start a Python program."""
    proc = subprocess.Popen(
        [sys.executable, "-c", program, mode],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().strip() == "ready"
        path = pty_sim("--ids", "1-2", *sim_args).path
        out, err = proc.communicate(f"{path}\n", timeout=60)
    finally:
        proc.kill()
    return subprocess.CompletedProcess(proc.args, proc.returncode, f"{path}\n{out}", err)


def test_a_blocking_program_s_lost_port_is_one_line_and_exit_1(pty_sim: Any) -> None:
    done = gait_on_a_pty(pty_sim, "end", *UNPLUG_AFTER_STREAMING, "--replug-after", "60")
    path, *said = done.stdout.split()
    assert done.returncode == 1, done.stderr
    assert said == ["streaming"]
    assert "Traceback" not in done.stderr, done.stderr
    # Said once, by run(): the library's own warning of the loss would say it a second time.
    assert done.stderr.count("\n") == 1 and done.stderr.startswith(f"error: port {path} lost: "), done.stderr


def test_a_library_error_s_traceback_under_stop_on_signals_alone_ends_at_the_program_s_call(pty_sim: Any) -> None:
    # The error is met on the bus's loop thread; the frames it went through there mean nothing to the
    # program's author, and the traceback's last of the program's own lines is the call that failed.
    done = gait_on_a_pty(pty_sim, "alone", *UNPLUG_AFTER_STREAMING, "--replug-after", "60")
    path, *said = done.stdout.split()
    assert done.returncode == 1, done.stderr
    assert said == ["streaming"]
    assert done.stderr.count("Traceback (most recent call last):") == 1, done.stderr
    assert done.stderr.startswith(f"port {path} lost: "), done.stderr  # (no run() to say it: the library's warning)
    assert done.stderr.splitlines()[-1].startswith(f"ics35_async.errors.PortLost: port {path} lost: "), done.stderr
    files = re.findall(r'^  File "([^"]+)", line \d+, in (\S+)$', done.stderr, re.MULTILINE)
    assert files[0] == ("<string>", "<module>"), done.stderr
    assert ("<string>", "main") in files, done.stderr
    below = files[files.index(("<string>", "main")) + 1 :]
    # Below the program's own call only the blocking layer's hand-over in the program's thread.
    assert below and all("ics35_async/blocking/" in file for file, _ in below), done.stderr
    assert not any(function in ("_await", "_next_frame") for _, function in below), done.stderr


def test_an_async_program_s_lost_port_is_said_once_and_exit_1(pty_sim: Any) -> None:
    done = gait_on_a_pty(pty_sim, "", *UNPLUG_AFTER_STREAMING, "--replug-after", "60", program=ASYNC_GAIT)
    path, *said = done.stdout.split()
    assert done.returncode == 1, done.stderr
    assert said == ["streaming"]
    assert done.stderr.count("\n") == 1 and done.stderr.startswith(f"error: port {path} lost: "), done.stderr


def test_a_blocking_program_catching_a_lost_port_itself_goes_on(pty_sim: Any) -> None:
    done = gait_on_a_pty(pty_sim, "catch", *UNPLUG_AFTER_STREAMING, "--replug-after", "60")
    path, *said = done.stdout.split()
    assert done.returncode == 0, done.stderr
    assert said == ["streaming", "caught"]
    assert "Traceback" not in done.stderr and "error:" not in done.stderr, done.stderr
    # Not the program's ending, so not said there: the library's warning, once, as the program ends.
    assert done.stderr.count("\n") == 1 and done.stderr.startswith(f"port {path} lost: "), done.stderr


def test_a_port_lost_for_good_that_does_not_end_the_program_is_still_said_once(pty_sim: Any) -> None:
    done = gait_on_a_pty(pty_sim, "", *UNPLUG_AFTER_STREAMING, "--replug-after", "60", program=ASIDE_LINE)
    path, *said = done.stdout.split()
    assert done.returncode == 0, done.stderr
    assert said == ["gone"]
    assert done.stderr.count("\n") == 1 and done.stderr.startswith(f"port {path} lost: "), done.stderr


def test_a_blocking_program_s_mistyped_port_is_one_line_with_its_hint() -> None:
    port = "/dev/ttyICS35-nothing-here"
    done = subprocess.run(
        [sys.executable, "-c", BLOCKING_GAIT, "end"], input=f"{port}\n", capture_output=True, text=True, timeout=60
    )
    assert done.returncode == 1, done.stderr
    assert done.stderr.count("\n") == 1 and done.stderr.startswith("error: "), done.stderr
    assert port in done.stderr and "ics35 ports" in done.stderr, done.stderr
    assert "Errno" not in done.stderr, done.stderr  # (the words only, as the ics35 commands say them)


def test_a_plain_program_hears_its_port_lost_and_back(pty_sim: Any) -> None:
    # No logging set up: Python's last-resort handler prints the library's warnings, the port lost and,
    # once reopened, back (were it logged below WARNING, the program would never hear of it).
    done = gait_on_a_pty(pty_sim, "reconnect", *UNPLUG_AFTER_STREAMING, "--replug-after", "0.3")
    path, *said = done.stdout.split()
    assert done.returncode == 0, done.stderr
    assert said == ["streaming", "resumed"]
    lines = done.stderr.splitlines()
    assert len(lines) == 2, done.stderr
    assert lines[0].startswith(f"port {path} lost: "), done.stderr
    assert lines[1].startswith(f"port {path} back: reconnected after "), done.stderr


BLOCKING_RUN_PROGRAM = textwrap.dedent(
    """
    import sys
    from ics35_async import blocking
    from ics35_async.sim import VirtualLine

    sim = VirtualLine([1, 2], realtime=True)

    def main() -> None:
        with blocking.open_bus(sim) as bus, bus.stream([1, 2], on_close="free") as s:
            s.set_targets({1: 8000, 2: 7000})
            for n, frame in enumerate(s):
                if n == 5:
                    print("streaming", flush=True)

    code = blocking.run(main)
    print("free" if all(sim.servo(i).free for i in (1, 2)) else "holding", flush=True)
    sys.exit(code)
    """
)


@pytest.mark.parametrize(("signum", "code"), [(signal.SIGTERM, 143), (signal.SIGINT, 130), (signal.SIGHUP, 129)])
def test_blocking_run_ends_on_a_signal_as_the_async_run_does(signum: int, code: int) -> None:
    proc = subprocess.Popen(
        [sys.executable, "-c", BLOCKING_RUN_PROGRAM], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().strip() == "streaming"
        os.kill(proc.pid, signum)
        out, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
    assert proc.returncode == code, err
    assert out.strip() == "free"  # run() returned its code: the program's own last words came after
    assert err == "", err


def test_blocking_run_lets_main_s_own_exceptions_and_exit_through() -> None:
    from ics35_async import blocking

    def failing() -> None:
        try:
            raise KeyError("x")
        except KeyError as exc:
            raise ValueError("y") from exc

    with pytest.raises(ValueError, match="y") as raised:
        blocking.run(failing)
    assert isinstance(raised.value.__cause__, KeyError)

    def exiting() -> None:
        with blocking.open_bus("sim://?ids=1") as bus:
            bus.servo(1).read_stretch()
            sys.exit(3)

    with pytest.raises(SystemExit) as exited:
        blocking.run(exiting)
    assert exited.value.code == 3
    assert blocking.run(lambda: None) == 0


def test_misuses_of_blocking_run_are_said_before_anything_runs() -> None:
    from ics35_async import blocking

    async def main() -> None:
        pass

    with pytest.raises(InvalidArgument, match=r"ics35_async\.run\(main\)"):
        blocking.run(main)
    coroutine = main()
    with pytest.raises(InvalidArgument, match=r"ics35_async\.run\(main\), not blocking\.run\(main\(\)\)"):
        blocking.run(coroutine)  # type: ignore[arg-type]
    with pytest.raises(InvalidArgument, match="plain function"):
        blocking.run(42)  # type: ignore[arg-type]
    # blocking.run(main()): main has run already, outside blocking.run, and gave None; "not NoneType" said only that.
    with pytest.raises(InvalidArgument, match=r"blocking\.run\(main\), not blocking\.run\(main\(\)\)"):
        blocking.run(None)  # type: ignore[arg-type]

    def plain() -> None:
        pass

    with pytest.raises(InvalidArgument, match=r"blocking\.run\(plain\)"):
        ics35_async.run(plain)  # type: ignore[arg-type]
