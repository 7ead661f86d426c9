"""ics35_async.blocking: the async API driven from plain (loop-less) code, through the simulator."""

from __future__ import annotations

import asyncio
import contextlib
import gc
import inspect
import itertools
import pydoc
import re
import subprocess
import sys
import textwrap
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from ics35_async import (
    BusClosed,
    Device,
    Eeprom,
    InvalidArgument,
    PortNotFound,
    PositionReadUnsupported,
    ReplyTimeout,
    Servo,
    Stream,
    UnsafeOperation,
    blocking,
    protocol,
)
from ics35_async.bus import Bus
from ics35_async.bus import open_bus as open_async_bus
from ics35_async.policies import plan_eeprom_write, write_eeprom_plan
from ics35_async.protocol import BaudRate
from ics35_async.sim import MemoryDevice, VirtualLine, VirtualServo
from ics35_async.sim.launch import serving
from tests.support.leaks import open_fds
from tests.support.timing import GUARD, PATIENT


def threads() -> set[threading.Thread]:
    return set(threading.enumerate())


@pytest.fixture
def no_leaks() -> Iterator[None]:
    """The test leaves no thread and no file descriptor behind."""
    gc.collect()
    before_threads, before_fds = threads(), open_fds()
    yield
    gc.collect()
    assert threads() - before_threads == set()
    assert open_fds() == before_fds


def public_coroutine_methods(cls: type) -> dict[str, inspect.Signature]:
    return {
        name: inspect.signature(member)
        for name, member in vars(cls).items()
        if not name.startswith("_") and inspect.iscoroutinefunction(member)
    }


def without_self(signature: inspect.Signature) -> inspect.Signature:
    return signature.replace(parameters=list(signature.parameters.values())[1:])


# ---------------------------------------------------------------------- same methods as the async API


def test_every_async_method_has_a_blocking_twin_with_its_signature() -> None:
    with blocking.open_bus("sim://?ids=1", echo=True) as bus:
        pairs = [
            (Servo, bus.servo(1), set()),
            (Device, bus.device(1), set()),
            (Bus, bus, {"open", "aclose", "request"}),  # open_bus and close() replace the first two
        ]
        for async_cls, twin, skipped in pairs:
            expected = public_coroutine_methods(async_cls)
            assert expected
            for name, signature in expected.items():
                if name in skipped:
                    continue
                method = getattr(twin, name, None)
                assert method is not None, f"{type(twin).__name__} has no {name}"
                assert inspect.signature(method) == without_self(signature), name
                assert method.__doc__ == getattr(async_cls, name).__doc__
        # request is written out (generic in its result); its parameters are the async one's
        assert list(inspect.signature(bus.request).parameters) == ["command", "priority", "retries"]


def test_help_on_a_blocking_class_shows_each_method_with_its_arguments() -> None:
    # help(blocking.BlockingServo) in the REPL listed "set_position(...)": its arguments were not to be seen.
    assert inspect.signature(blocking.BlockingServo.set_position) == inspect.signature(Servo.set_position)
    assert inspect.signature(blocking.BlockingBus.scan) == inspect.signature(Bus.scan)
    text = pydoc.render_doc(blocking.BlockingServo, renderer=pydoc.plaintext)  # type: ignore[attr-defined]
    assert "set_position(self, position: 'int') -> 'int'" in text
    assert "free(self, *, priority: 'Priority | None' = None) -> 'int'" in text
    line = VirtualLine([VirtualServo(1, position=8000)])
    with blocking.open_bus(line) as bus:  # called through the class, as any method can be
        assert blocking.BlockingServo.set_position(bus.servo(1), 9000) == 8000
        assert line.servo(1).target == 9000


def test_every_stream_target_method_is_there() -> None:
    names = ("set_target", "set_targets", "set_target_degrees", "set_targets_degrees", "free", "watch", "target")
    for name in names:
        assert hasattr(Stream, name) and name in vars(blocking.BlockingStream), name


# ---------------------------------------------------------------------- servos, devices, the bus


def test_servo_methods_reach_the_simulated_servo(no_leaks: None) -> None:
    line = VirtualLine([VirtualServo(1, position=8000), VirtualServo(2)])
    with blocking.open_bus(line) as bus:
        servo = bus.servo(1)
        assert servo.id == 1
        assert servo.free() == 8000
        line.servo(1).move_by_hand(9000)
        assert servo.free_and_read_degrees() == pytest.approx((9000 - 7500) / (8000 / 270), abs=0.1)
        with pytest.raises(PositionReadUnsupported):
            servo.read_position()  # an ICS 3.5 servo: nothing freed, a typed error
        assert servo.known_position_read() is False and bus.servo(2).known_position_read() is None
        servo.set_position(8500)
        assert line.servo(1).target == 8500
        servo.set_degrees(-30)
        assert line.servo(1).target == 7500 - round(30 * 8000 / 270)
        servo.write_speed(64)
        assert servo.read_speed() == 64 == line.servo(1).speed
        servo.write_stretch(50)
        assert servo.read_stretch() == 50
        assert servo.read_temperature() == line.servo(1).temperature
        assert 0 <= servo.read_current() <= 127
        eeprom = servo.read_eeprom()
        assert isinstance(eeprom, Eeprom)
        servo.write_eeprom(eeprom.replace(speed=99))
        assert line.servo(1).eeprom.speed == 99
        assert [s.id for s in bus.servos([1, 2])] == [1, 2]


def test_device_memory_through_the_blocking_bus() -> None:
    line = VirtualLine([VirtualServo(1)], memory={5: b"\x01\x02\x03"})
    with blocking.open_bus(line) as bus:
        device = bus.device(5)
        assert device.read_memory(0, 3) == b"\x01\x02\x03"
        device.write_memory(10, b"\x7f\x00")
        assert line.memory_device(5).memory[10:12] == b"\x7f\x00"
        assert isinstance(line.memory_device(5), MemoryDevice)


def test_bus_scan_request_stats_and_properties() -> None:
    with blocking.open_bus("sim://?ids=2,4,6", baudrate=115200) as bus:
        assert bus.scan(range(8)) == [2, 4, 6]
        assert bus.scan([4, 5], concurrency=1) == [4]
        assert bus.request(protocol.ReadParam(4, protocol.Param.STRETCH)) == bus.servo(4).read_stretch()
        before = bus.stats.total.transactions
        bus.servo(2).free()
        assert bus.stats.total.transactions == before + 1
        assert bus.baudrate == 115200 and bus.echo and bus.is_open
        assert bus.driver == "asyncio"
        assert isinstance(bus.async_bus, Bus)
        assert "sim://" in repr(bus)
    assert not bus.is_open


def test_errors_arrive_typed_in_the_callers_thread() -> None:
    with blocking.open_bus("sim://?ids=1") as bus:
        with pytest.raises(ReplyTimeout) as timeout:
            bus.servo(20).read_speed()
        assert timeout.value.servo_id == 20
        with pytest.raises(InvalidArgument):
            bus.servo(1).set_position(0)  # checked before anything reaches the wire
        with pytest.raises(InvalidArgument):
            bus.servo(32)
        eeprom = bus.servo(1).read_eeprom()
        with pytest.raises(UnsafeOperation):
            bus.servo(1).write_eeprom(eeprom.replace(servo_id=3))
        with pytest.raises(InvalidArgument):
            blocking.open_bus("sim://", bogus_option=1.0)
        # The bus carries on after each error.
        assert bus.servo(1).free() == 7500


def test_run_takes_async_helpers_that_want_the_async_bus() -> None:
    line = VirtualLine([VirtualServo(1)])
    with blocking.open_bus(line) as bus:
        plan = bus.run(plan_eeprom_write, bus.async_bus, 1, {"speed": 90})
        result = bus.run(write_eeprom_plan, bus.async_bus, plan)
        assert result.verified and line.servo(1).eeprom.speed == 90


def test_run_says_plainly_what_it_takes_and_sends_nothing_for_a_misuse() -> None:
    # bus.run(fn(...)) or a plain function: said as run()'s misuse (not "'coroutine' object is not callable" or
    # a TypeError from inside the loop), with no "never awaited" warning on top; the bus carries on.
    line = VirtualLine([VirtualServo(1)])
    with blocking.open_bus(line) as bus:
        coroutine = plan_eeprom_write(bus.async_bus, 1, {"speed": 90})
        with pytest.raises(InvalidArgument, match=r"bus\.run\(fn, \*args\), not bus\.run\(fn\(\*args\)\)"):
            bus.run(coroutine)  # type: ignore[arg-type]
        assert inspect.getcoroutinestate(coroutine) == inspect.CORO_CLOSED

        def plain(servo_id: int) -> int:
            return servo_id

        with pytest.raises(InvalidArgument, match=r"an async function \(async def plain\(\)\): .* returned an int"):
            bus.run(plain, 1)  # type: ignore[arg-type]
        assert line.transactions == 0
        assert bus.servo(1).free() == 7500


def test_several_threads_share_one_bus_and_each_gets_its_own_answer() -> None:
    line = VirtualLine([VirtualServo(i, position=5000 + 100 * i) for i in range(8)])
    answers: dict[int, list[int]] = {}

    def worker(servo: blocking.BlockingServo) -> None:
        answers[servo.id] = [servo.free() for _ in range(25)]

    with blocking.open_bus(line) as bus:
        workers = [threading.Thread(target=worker, args=(bus.servo(i),)) for i in range(8)]
        for t in workers:
            t.start()
        for t in workers:
            t.join()
    assert answers == {i: [5000 + 100 * i] * 25 for i in range(8)}


def test_a_blocking_call_on_the_loop_thread_is_refused_not_deadlocked() -> None:
    with blocking.open_bus("sim://?ids=1") as bus:

        async def calls_blocking_inside() -> int:
            return bus.servo(1).free()

        with pytest.raises(RuntimeError, match="own event loop thread"):
            bus.run(calls_blocking_inside)
        assert bus.servo(1).free() == 7500


# ---------------------------------------------------------------------- streams


def test_stream_targets_reach_the_servos_and_frames_come_back() -> None:
    line = VirtualLine([VirtualServo(i) for i in (1, 2, 3)])
    with blocking.open_bus(line) as bus, bus.stream([1, 2, 3]) as stream:
        assert stream.ids == (1, 2, 3) and stream.rate_hz is None
        first = stream.next_frame()
        assert set(first.positions) == {1, 2, 3}
        assert all(line.servo(i).free for i in (1, 2, 3))  # every ID starts free
        stream.set_target(1, 8000)
        stream.set_targets({2: 7000, 3: 7600})
        assert [stream.target(i) for i in (1, 2, 3)] == [8000, 7000, 7600]
        stream.next_frame()
        stream.next_frame()  # a whole cycle after the targets were set
        assert [line.servo(i).target for i in (1, 2, 3)] == [8000, 7000, 7600]
        stream.set_target_degrees(1, 10)
        stream.set_targets_degrees({2: -10})
        stream.next_frame()
        stream.next_frame()
        assert line.servo(1).target == stream.target(1) > 7500 > stream.target(2) == line.servo(2).target
        stream.free([1])
        stream.next_frame()
        stream.next_frame()
        assert line.servo(1).free and not line.servo(2).free
        stream.free()
        stream.next_frame()
        stream.next_frame()
        assert all(line.servo(i).free for i in (1, 2, 3))
        latest = stream.latest
        assert latest is not None and latest.cycle >= 10
        stats = stream.stats
        assert stats.cycles >= latest.cycle and stats.failures == {}
        assert stream.offline == frozenset()


def test_targets_given_before_a_blocking_stream_starts_hold_from_its_first_command() -> None:
    line = VirtualLine([VirtualServo(i) for i in (1, 2, 3)], log_size=None, realtime=True)
    with blocking.open_bus(line) as bus:
        stream = bus.stream([1, 2, 3], rate_hz=100)
        stream.set_targets({1: 8000, 2: 7000, 3: 7600})
        with stream:
            stream.next_frame()
    assert [t.servo_id for t in line.log_since(0) if t.command == "free"] == []
    assert [line.servo(i).target for i in (1, 2, 3)] == [8000, 7000, 7600]


def test_stream_errors_are_typed_and_a_bad_target_changes_nothing() -> None:
    with blocking.open_bus("sim://?ids=1-2") as bus, bus.stream([1, 2]) as stream:
        stream.set_targets({1: 8000, 2: 8000})
        with pytest.raises(InvalidArgument):
            stream.set_targets({1: 9000, 2: 99999})
        assert (stream.target(1), stream.target(2)) == (8000, 8000)
        with pytest.raises(InvalidArgument):
            stream.set_target(7, 8000)  # not in this stream
        with pytest.raises(InvalidArgument):
            stream.set_target_degrees(1, 200)  # beyond the servo's travel
        with pytest.raises(InvalidArgument):
            stream.next_frame(timeout=-1)
        with pytest.raises(InvalidArgument):
            bus.stream([1, 1])
        with pytest.raises(InvalidArgument):
            bus.stream([1], bogus=3)


def test_a_stream_not_started_says_so_and_a_frame_not_come_in_time_says_how_long() -> None:
    with blocking.open_bus("sim://?ids=1-2") as bus:
        stream = bus.stream([1, 2], rate_hz=2)
        with pytest.raises(InvalidArgument, match=r"with bus\.stream"):
            stream.next_frame(timeout=5)  # it waited out the timeout (or forever without one)
        with pytest.raises(InvalidArgument, match=r"with bus\.stream"):
            next(iter(stream))  # a for loop over it: not silently empty
        with stream:
            stream.next_frame()
            with pytest.raises(TimeoutError, match=r"no frame within 0\.01 s"):
                stream.next_frame(timeout=0.01)  # the next one comes half a second later


def test_iteration_takes_every_frame_in_order_and_ends_when_the_stream_closes() -> None:
    with blocking.open_bus("sim://?ids=1-4") as bus:
        stream = bus.stream(range(1, 5)).start()
        cycles = []
        for frame in stream:
            cycles.append(frame.cycle)
            if len(cycles) == 20:
                stream.close()  # the next step of the loop ends it
        assert len(cycles) == 20 and cycles == sorted(set(cycles))
        with pytest.raises(BusClosed):
            stream.next_frame()
        assert bus.servo(1).free() == 7500  # the bus stays usable


def test_closing_the_bus_from_another_thread_ends_a_waiting_iteration() -> None:
    frames: list[int] = []
    with blocking.open_bus("sim://?ids=1") as bus:
        stream = bus.stream([1]).start()

        def consume() -> None:
            frames.extend(frame.cycle for frame in stream)

        consumer = threading.Thread(target=consume)
        consumer.start()
        stream.next_frame()
    consumer.join(30)
    assert not consumer.is_alive()


def test_next_frame_timeout_raises_timeout_error() -> None:
    # ID 5 is absent: after one failed cycle it goes offline and is probed again only in an hour,
    # so after the first frames no new frame comes.
    with blocking.open_bus("sim://?ids=1") as bus:
        with bus.stream([5], offline_after=1, probe_interval=3600) as stream:
            frame = stream.next_frame()
            while frame.failed:
                frame = stream.next_frame()
            assert frame.offline == {5}
            with pytest.raises(TimeoutError):
                stream.next_frame(timeout=0.05)
            assert stream.stats.failures == {5: 1}
        assert bus.servo(1).free() == 7500


def test_on_close_free_frees_every_id() -> None:
    line = VirtualLine([VirtualServo(1), VirtualServo(2)])
    with blocking.open_bus(line) as bus:
        with bus.stream([1, 2], on_close="free") as stream:
            stream.set_targets({1: 8000, 2: 8000})
            stream.next_frame()
            stream.next_frame()
            assert not line.servo(1).free and not line.servo(2).free
        assert line.servo(1).free and line.servo(2).free


# ---------------------------------------------------------------------- opening and closing


def test_closed_bus_raises_bus_closed_and_close_is_idempotent(no_leaks: None) -> None:
    bus = blocking.open_bus("sim://?ids=1")
    servo = bus.servo(1)
    bus.close()
    bus.close()
    with pytest.raises(BusClosed):
        servo.free()
    with pytest.raises(BusClosed):
        bus.scan()
    assert bus.stats.total.transactions == 0  # statistics still read (see below)
    assert not bus.thread.is_alive()


def test_port_error_is_typed_and_leaves_no_thread(no_leaks: None) -> None:
    with pytest.raises(PortNotFound):
        blocking.open_bus("/dev/ttyUSB_no_such_port_here")


def test_bad_option_fails_before_any_thread_starts(no_leaks: None) -> None:
    with pytest.raises(InvalidArgument):
        blocking.open_bus("sim://", driver="nonsense")


def test_exception_in_the_block_closes_the_bus(no_leaks: None) -> None:
    with pytest.raises(ZeroDivisionError), blocking.open_bus("sim://?ids=1-3") as bus, bus.stream([1, 2, 3]) as stream:
        stream.next_frame()
        _ = 1 / 0
    assert not bus.is_open and not bus.thread.is_alive()


@pytest.mark.pty
def test_pty_simulator_round_trip_and_no_leaks() -> None:
    with serving(["--ids", "1-3", "--fast"]) as path:
        gc.collect()
        before_threads, before_fds = threads(), open_fds()
        for _ in range(2):  # twice: the second opening finds the port released
            with blocking.open_bus(path, **PATIENT) as bus:  # 0 and 4 silent; the others' replies may not be late
                assert bus.scan(range(5)) == [1, 2, 3]
                with bus.stream([1, 2, 3]) as stream:
                    stream.set_targets({1: 8000, 2: 7000})
                    frames = [stream.next_frame(timeout=10) for _ in range(5)]
                    # A stream gives up on a late answer early (a loaded machine can hold the simulator
                    # between echo and reply): every ID is in each frame, answered or failed, and whole
                    # frames come.
                    assert all(set(f.positions) | f.failed == {1, 2, 3} for f in frames[1:])
                    # (by time, not by a count of cycles: an ID taken offline by a stall of the loaded machine
                    # comes back at the stream's next probe of it, and 200 fast cycles could all go by first)
                    until = time.monotonic() + GUARD
                    whole = next(f for f in stream if set(f.positions) == {1, 2, 3} or time.monotonic() > until)
                    assert set(whole.positions) == {1, 2, 3}
                with pytest.raises(RuntimeError), bus.stream([1]) as stream:
                    raise RuntimeError("the program fails mid-stream")
        gc.collect()
        # No thread left that was not there before (an earlier test's idle trio worker may have ended meanwhile).
        assert threads() - before_threads == set()
        assert open_fds() == before_fds


def test_a_forgotten_bus_is_closed_at_garbage_collection(no_leaks: None) -> None:
    bus = blocking.open_bus("sim://?ids=1")
    thread = bus.thread
    assert thread.is_alive()
    with pytest.warns(ResourceWarning, match="never closed"):
        del bus
        gc.collect()
    assert not thread.is_alive()


def test_a_script_that_never_closes_its_bus_still_exits_cleanly() -> None:
    script = textwrap.dedent(
        """
        from ics35_async import blocking
        bus = blocking.open_bus("sim://?ids=1")
        stream = bus.stream([1]).start()
        stream.next_frame()
        print(bus.servo(1).read_speed())
        """
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().isdigit()
    assert "Traceback" not in done.stderr


def test_read_degrees_warns_a_blocking_program_that_it_frees_the_servo() -> None:
    """``read_degrees()`` sounds like a read but turns the torque off.  Its DeprecationWarning said so to an
    async program, at the program's line; the blocking twin issued it on the bus's loop thread, inside the
    package, where Python's default filters hide it: a script freed its servo with nothing on screen."""
    script = textwrap.dedent(
        """
        from ics35_async import blocking
        with blocking.open_bus("sim://?ids=1") as bus:
            bus.servo(1).set_position(8000)
            print(bus.servo(1).read_degrees())
        """
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert "<string>:5: DeprecationWarning: Servo.read_degrees() turns the torque off" in done.stderr
    assert done.stderr.count("DeprecationWarning") == 1, done.stderr
    with blocking.open_bus("sim://?ids=1") as bus, pytest.warns(DeprecationWarning, match="torque off") as seen:
        bus.servo(1).read_degrees()
    assert [w.filename for w in seen] == [__file__]  # once, at the program's line


# ---------------------------------------------------------------------- inside a running event loop (Jupyter)


async def test_works_from_inside_a_running_asyncio_loop() -> None:
    # A Jupyter cell runs in a thread whose asyncio loop is running: the blocking bus has its own
    # loop in its own thread, so it works (and blocks the caller's loop while each call waits).
    asyncio.get_running_loop()
    with blocking.open_bus("sim://?ids=1-2") as bus:
        assert bus.scan([1, 2, 3]) == [1, 2]
        with bus.stream([1, 2]) as stream:
            assert stream.next_frame().positions.keys() == {1, 2}


@pytest.mark.parametrize("backend", ["asyncio", "trio"])
def test_works_from_inside_an_async_main_under_anyio_or_ics35_async_run(backend: str) -> None:
    # anyio.run (and so ics35_async.run) names its library in a context variable of the caller's context: the bus's
    # loop ran the calls in that context, took itself for trio, and opening failed ("must be called from async
    # context").  The bus's loop is asyncio's whatever the caller's is.
    import anyio

    async def main() -> list[int]:
        with blocking.open_bus("sim://?ids=1-2") as bus, bus.stream([1, 2]) as stream:
            assert stream.next_frame().positions.keys() == {1, 2}
            return bus.scan([1, 2, 3])

    assert anyio.run(main, backend=backend) == [1, 2]


async def test_async_with_on_a_blocking_object_says_how_and_releases_the_port() -> None:
    # `async with blocking.open_bus(...)` in async code: said how to write it (with, or the async API), and
    # the port the blocking bus had opened is released at once: the async bus opens it next.
    asyncio.get_running_loop()
    with pytest.raises(TypeError, match=r"`with blocking\.open_bus\(\.\.\.\) as bus:`.*`async with ics35_async\."):
        async with blocking.open_bus("sim://wrong-with?ids=1"):  # type: ignore[attr-defined]
            pytest.fail("entered")
    with blocking.open_bus("sim://wrong-with?ids=1") as bus:
        with pytest.raises(TypeError, match=r"`with bus\.stream\(\.\.\.\) as stream:`"):
            async with bus.stream([1]):  # type: ignore[attr-defined]
                pytest.fail("entered")
        assert bus.servo(1).free() == 7500
    robot_line = {"lines": {"m": {"port": "sim://wrong-with?ids=1"}}, "joints": {"j": {"line": "m", "id": 1}}}
    with pytest.raises(TypeError, match=r"`with blocking\.open_robot\(\.\.\.\) as robot:`"):
        async with blocking.open_robot(robot_line):  # type: ignore[attr-defined]
            pytest.fail("entered")
    async with open_async_bus("sim://wrong-with?ids=1") as async_bus:
        assert await async_bus.servo(1).free() == 7500


def test_statistics_still_read_after_the_with_block_ends() -> None:
    # A summary printed after the block: the async objects allow it, the blocking ones said BusClosed.
    with blocking.open_bus("sim://?ids=1-2") as bus, bus.stream([1, 2]) as stream:
        for _ in range(3):
            stream.next_frame()
    assert stream.stats.cycles >= 3 and stream.offline == frozenset() and stream.target(1) == 0
    assert bus.stats.total.ok >= 6
    with pytest.raises(BusClosed):
        stream.set_target(1, 8000)  # acting on it is still refused


def test_a_blocking_stream_says_which_ids_it_holds_now() -> None:
    # The control-loop docs tell a loop to filter its targets by `stream.held` (the holds now, not a frame's):
    # the blocking stream had no `held`, so a blocking gait had only its frames' word, a cycle late.
    line = VirtualLine([VirtualServo(i) for i in (1, 2)], log_size=None)
    with blocking.open_bus(line) as bus, bus.stream([1, 2], offline_after=1, probe_interval=0.01) as stream:
        stream.set_targets({1: 7000, 2: 8000})
        assert stream.held == {}
        line.servo(2).baud_rate = BaudRate.B625000  # silent at the line's 115200
        while 2 not in stream.next_frame(timeout=5).offline:
            pass
        line.servo(2).baud_rate = BaudRate.B115200
        while 2 in stream.next_frame(timeout=5).offline:
            pass
        assert stream.held == {2: "rejoined"}
        stream.set_target(2, 8000)
        assert stream.held == {}


def test_a_blocking_stream_says_what_its_close_sent_and_how_long_a_cycle_may_take() -> None:
    # The streaming docs point a program at `stream.targets_sent_on_close` (did every joint go limp on Ctrl-C?)
    # and `stream.longest_cycle()` (how long to wait for a free to go out), and at `bus.describe()` for a log:
    # the blocking objects had none of them, and a script following those docs stopped on an AttributeError.
    line = VirtualLine([VirtualServo(i) for i in (1, 2)])
    with blocking.open_bus(line) as bus:
        assert bus.describe()["port"] == str(bus.port)
        with bus.stream([1, 2], on_close="free") as stream:
            stream.set_targets({1: 8000, 2: 7000})
            assert stream.longest_cycle() > 0
            assert stream.targets_sent_on_close == {}
            stream.next_frame()
        assert stream.targets_sent_on_close == {1: 0, 2: 0}
        assert line.servo(1).free and line.servo(2).free
    assert stream.targets_sent_on_close == {1: 0, 2: 0}  # still read for a summary after the bus's block


def test_the_module_example_starts_its_stream_with_every_servo_holding() -> None:
    # The reference page opens with the package's docstring example: it started its stream with no targets, so
    # every servo was sent the free command (a standing robot sags) and then thrown to neutral. It is run here
    # on a simulated line in place of its serial port, and stopped (its bus closed) once it has streamed a while.
    assert blocking.__doc__ is not None
    after = blocking.__doc__.split("::\n", 1)[1].splitlines()
    block = itertools.takewhile(lambda text: not text or text.startswith("    "), after)
    example = textwrap.dedent("\n".join(block))
    opening = re.search(r"open_bus\([^)]*\)", example)
    assert opening is not None
    line = VirtualLine([VirtualServo(i, position=8000) for i in range(12)], log_size=None)
    names: dict[str, object] = {"__name__": "example", "LINE": line}
    code = compile(example.replace(opening.group(0), "open_bus(LINE)"), "<ics35_async.blocking>", "exec")

    def stop_it() -> None:  # as a Ctrl-C would, from outside: the example's own loop never ends
        while sum(t.command == "position" for t in line.log) < 60:
            time.sleep(0.01)
        bus = names["bus"]
        assert isinstance(bus, blocking.BlockingBus)
        bus.close()

    stopper = threading.Thread(target=stop_it, daemon=True)
    stopper.start()
    # In the main thread: stop_on_signals() takes the signals there only.  The bus closed from outside ends the
    # example's loop with BusClosed, wherever it is (waiting for a frame, or setting targets).
    with contextlib.suppress(BusClosed):
        exec(code, names)
    stopper.join(10)
    first: dict[
        int | None, str
    ] = {}  # each servo's first command from the stream (a free to start with: the joint went limp)
    for transaction in line.log:
        if transaction.command in ("position", "free"):
            first.setdefault(transaction.servo_id, transaction.command)
    assert first == dict.fromkeys(range(12), "position")


@pytest.mark.parametrize("port", ["", None])
def test_a_forgotten_port_says_what_to_pass(port: str) -> None:
    # A script whose port came from an unset variable (os.environ.get, an empty argument) was told only that
    # the port "must not be empty" or "must be a path ... not NoneType": not what to pass, nor where to find it.
    with pytest.raises(InvalidArgument) as raised:
        blocking.open_bus(port)
    assert "/dev/ttyUSB0" in str(raised.value) and "ics35 ports" in str(raised.value) and "sim://" in str(raised.value)


def _guide_examples() -> list[str]:
    """The ```python blocks of the blocking guide, in order."""
    page = (Path(__file__).resolve().parent.parent / "docs" / "how-to" / "blocking.md").read_text()
    return re.findall(r"^```python\n(.*?)^```", page, flags=re.S | re.M)


def _drop_and_bring_back(line: VirtualLine, servo_id: int, back: threading.Event, stop: threading.Event) -> None:
    """Servo ``servo_id`` leaves the line once the stream has driven it a while (by what the line saw, not the
    clock: a loaded machine), and comes back once it has gone unanswered long enough to go offline; ``back`` is
    set once it has answered again."""

    def driven() -> int:
        return sum(t.servo_id == servo_id and t.command == "position" for t in line.log)

    while driven() < 10 and not stop.is_set():
        time.sleep(0.005)
    gone = line.remove_servo(servo_id)
    seen = len(line.log_since(0))
    while sum(t.servo_id == servo_id for t in line.log_since(0)[seen:]) < 6 and not stop.is_set():
        time.sleep(0.005)  # (offline after 3 cycles unanswered, probed since)
    seen = len(line.log_since(0))
    line.add_device(gone)
    while not any(t.servo_id == servo_id and t.responders for t in line.log_since(0)[seen:]) and not stop.is_set():
        time.sleep(0.005)
    seen = len(line.log_since(0))
    while sum(t.servo_id == 1 for t in line.log_since(0)[seen:]) < 10 and not stop.is_set():
        time.sleep(0.005)  # (ten cycles more, for the program to act on it)
    back.set()


# The engine's guard read after a probe (a stretch read) that went unanswered, another parameter's read so that a
# late reply to the probe cannot pass for it: a servo coming back between the two answers it first.
GUARD_AFTER_A_PROBE = protocol.guard_read(protocol.ReadParam(1, protocol.Param.STRETCH).tx, 1).name


def test_the_guide_s_first_loop_leaves_a_servo_that_came_back_to_the_program() -> None:
    # The guide's first example sets every target each pass.  A servo that went offline and answers again may
    # have restarted (free, where the load left it): the stream holds it, and a loop setting its target with
    # the others lifted that hold at once, throwing it to the loop's target behind the program's back.  It is
    # run here on a simulated line in place of its own, and ended once servo 3 has been back a while.
    (code, *_) = _guide_examples()
    assert '"sim://?ids=1-6"' in code and "frame.cycle >= 100" in code
    line = VirtualLine(list(range(1, 7)), realtime=True)
    back, stop = threading.Event(), threading.Event()
    names: dict[str, object] = {"__name__": "example", "LINE": line, "BACK": back}
    code = code.replace('"sim://?ids=1-6"', "LINE").replace("frame.cycle >= 100", "frame.cycle >= 100 and BACK.wait(0)")
    mover = threading.Thread(target=_drop_and_bring_back, args=(line, 3, back, stop), daemon=True)
    mover.start()
    try:
        exec(compile(code, "<docs/how-to/blocking.md>", "exec"), names)
    finally:
        stop.set()
        mover.join(10)
    log = line.log_since(0)
    last_silent = max(n for n, t in enumerate(log) if t.servo_id == 3 and not t.responders)
    after = [t.command for t in log[last_silent + 1 :] if t.servo_id == 3 and t.command != GUARD_AFTER_A_PROBE]
    assert after[:1] == ["read_stretch"], after  # probed (a read moves nothing), and it answered
    assert "position" not in after, after


def test_the_guide_s_gait_loop_leaves_a_servo_that_came_back_to_the_program_and_ends_its_helper(
    capsys: pytest.CaptureFixture[str],
) -> None:
    # The guide's gait loop: a servo back from offline (maybe restarted, free) is left held, sent nothing, out
    # of the gait (it says so once), and its helper thread, which catches IcsError to carry on, ends as the bus
    # closes.  Run on a simulated line in place of its own (no unplugged port), ended once servo 2 is back.
    code = next(code for code in _guide_examples() if "def telemetry" in code)
    line = VirtualLine(list(range(1, 7)), realtime=True)
    back, stop = threading.Event(), threading.Event()
    names: dict[str, object] = {"__name__": "example", "LINE": line, "BACK": back}
    for old, new in [
        ("blocking.open_bus(PORT, ", "blocking.open_bus(LINE, "),
        ("frame.cycle >= 150", "frame.cycle >= 150 and BACK.wait(0)"),
        ("helper.join()", "helper.join(10)"),  # (a helper spinning on BusClosed would hang the test)
        ("sys.exit(blocking.run(main))", "CODE = blocking.run(main)"),
    ]:
        assert old in code, old
        code = code.replace(old, new)
    mover = threading.Thread(target=_drop_and_bring_back, args=(line, 2, back, stop), daemon=True)
    mover.start()
    try:
        exec(compile(code, "<docs/how-to/blocking.md>", "exec"), names)
    finally:
        stop.set()
        mover.join(10)
    assert names["CODE"] == 0
    out = capsys.readouterr().out
    assert out.count("servo 2 held (rejoined): left out of the gait") == 1, out
    assert not [t for t in threading.enumerate() if "telemetry" in t.name], threading.enumerate()
    log = line.log_since(0)
    streamed = [t for t in log if t.servo_id == 2 and t.command != "read_temperature"]  # (not the helper's)
    last_silent = max(n for n, t in enumerate(streamed) if not t.responders)
    after = [t.command for t in streamed[last_silent + 1 :] if t.command != GUARD_AFTER_A_PROBE]
    assert after[:1] == ["read_stretch"] and "position" not in after, after  # probed, held: never thrown to the gait


def test_a_port_given_as_a_path_object_is_taken_as_its_path() -> None:
    # A program building the port's name with pathlib (Path("/dev/serial/by-id") / name) was told "port must be
    # a path, a URL or a WireDevice, not PosixPath".  It is opened as the path it names.
    missing = Path("/dev/ttyICS-no-such-port")
    with pytest.raises(PortNotFound):
        blocking.open_bus(missing)
    assert open_async_bus(missing).port == str(missing)
