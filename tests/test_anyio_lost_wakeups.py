"""An exception raised inside one of the event loop's callbacks (a signal handler's, as pytest-timeout's alarm or a
program's own handler raising KeyboardInterrupt): no request is left unanswered, no hang, under the anyio driver and
the others.

Such an exception drops what the interrupted callback was doing: a task's wake-up (the task never runs again) or a
cancel scope's delivery (its cancellation never reaches the task).  The program here raises it, through a trace
function, exactly where a signal handler's would land: at the start of the bus task's wake-up callback or of anyio's
cancellation delivery, the Nth time.  Each run is a subprocess with a time limit: a hang fails, it never hangs the
suite.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
from typing import Any

import pytest

from tests.support.timing import scaled

PROGRAM = textwrap.dedent(
    """
    import asyncio, inspect, sys
    from ics35_async import IcsError, open_bus

    port, kind, nth, raised, driver, servo = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4], *sys.argv[5:]

    class Alarm(BaseException):  # as pytest-timeout's Failed: not an Exception, nor KeyboardInterrupt
        pass

    EXC = {"KeyboardInterrupt": KeyboardInterrupt, "Alarm": Alarm}[raised]
    seen = [0]
    bus_task = []

    def target(frame):
        if frame.f_code.co_name != "_run" or not frame.f_code.co_filename.endswith("events.py"):
            return False
        callback = getattr(frame.f_locals.get("self"), "_callback", None)
        if kind == "wakeup":  # the bus task's own step: lost, the task never runs again
            return getattr(callback, "__self__", None) is bus_task[0]
        if kind == "deliver":  # a cancel scope's delivery
            return getattr(callback, "__name__", "") == "_deliver_cancellation"
        return getattr(callback, "__name__", "") == kind  # one of the asyncio or thread driver's own callbacks

    # KeyboardInterrupt lands at the callback's start (out of the loop, as asyncio lets it); Alarm inside the
    # callback's call, where the loop catches it, says so and goes on.
    lines, first = inspect.getsourcelines(asyncio.Handle._run)
    inside = first + next(i for i, line in enumerate(lines) if "_context.run" in line)

    def raise_there(frame, event, arg):
        if EXC is KeyboardInterrupt or (event == "line" and frame.f_lineno == inside):
            sys.settrace(None)
            raise EXC("raised by a signal handler")
        return raise_there

    def tracer(frame, event, arg):
        if event == "call" and target(frame):
            seen[0] += 1
            if seen[0] == nth:
                return raise_there(frame, event, arg)
        return None

    async def read(bus, servo):
        try:
            await asyncio.wait_for(bus.servo(servo).read_temperature(), 5)
        except IcsError as exc:
            return f"failed: {type(exc).__name__}: {exc}"
        except TimeoutError:
            return "unanswered"
        return "ok"

    # (A pty's server, a process of its own, may stall longer than the default reply allowance on a loaded machine:
    # its first reads then failed unanswered, before the exception this program is about was raised.)
    LINE = {} if port.startswith("sim://") else {"adapter_latency": 0.5}

    async def main():
        async with open_bus(port, driver=driver, **LINE) as bus:
            bus_task.append(getattr(bus._driver, "_task", None))
            sys.settrace(tracer)
            try:
                for _ in range(100):
                    outcome = await read(bus, int(servo))
                    if outcome != "ok":
                        break
                print("reads:", outcome, flush=True)
            finally:
                sys.settrace(None)
                print("injected:", seen[0] >= nth, flush=True)
                print("after:", await read(bus, 2), flush=True)

    try:
        asyncio.run(main())
    except BaseException as exc:
        print("end:", type(exc).__name__, flush=True)
    else:
        print("end: returned", flush=True)
    """
)


def said(program: str, *args: str, needs: str) -> dict[str, str]:
    """What ``program`` (one of the texts here, run in a Python of its own) printed, ``key: value`` a line; a
    program that hangs, or that never printed ``needs``, fails the test with all it printed."""
    try:
        done = subprocess.run(
            [sys.executable, "-c", program, *args], capture_output=True, text=True, timeout=scaled(30.0)
        )
    except subprocess.TimeoutExpired as exc:
        pytest.fail(f"the program hung: {exc.stdout!r} {exc.stderr!r}")
    lines = dict(line.split(": ", 1) for line in done.stdout.splitlines() if ": " in line)
    assert needs in lines, (done.stdout, done.stderr)
    return lines


def run_program(port: str, kind: str, nth: int, raised: str, driver: str = "anyio", servo: int = 1) -> dict[str, str]:
    return said(PROGRAM, port, kind, str(nth), raised, driver, str(servo), needs="end")


def answered(outcome: str) -> bool:
    """A request's outcome: done, or failed with a library error saying why; never left waiting."""
    return outcome == "ok" or outcome.startswith("failed: ")


@pytest.mark.slow  # (a lost wake-up is told after two looks of a second, and the close waits for the task 1.5 s)
@pytest.mark.parametrize("nth", [1, 3])
@pytest.mark.parametrize("raised", ["KeyboardInterrupt", "Alarm"])
@pytest.mark.parametrize("kind", ["wakeup", "deliver"])
@pytest.mark.parametrize("on", ["sim", "pty"])
def test_an_exception_raised_in_a_loop_callback_leaves_no_request_waiting_and_no_hang(
    on: str, kind: str, raised: str, nth: int, pty_sim: Any
) -> None:
    port = "sim://?ids=1-4" if on == "sim" else pty_sim("--fast", "--ids", "1-4").path
    lines = run_program(port, kind, nth, raised)
    assert lines["injected"] == "True", lines
    assert answered(lines["after"]), lines
    if raised == "KeyboardInterrupt":  # out of asyncio.run, as the program's own Ctrl-C would be
        assert lines["end"] == "KeyboardInterrupt", lines
    else:  # dropped by the loop (it says so on stderr), the program goes on
        assert answered(lines["reads"]), lines
        assert lines["end"] == "returned", lines


@pytest.mark.parametrize(
    ("driver", "callback", "servo"),
    [
        ("asyncio", "_on_timer", 9),  # the timer that judges a silent servo's transaction
        ("asyncio", "_hop", 9),  # its second look
        ("asyncio", "_readable", 1),  # an in-process device's input, told once
        ("thread", "_settle", 1),  # a request's outcome, handed to the loop's thread
    ],
)
def test_a_callback_of_the_other_drivers_dropped_by_an_exception_leaves_no_request_waiting(
    driver: str, callback: str, servo: int
) -> None:
    # Servo 9 is not on the line: its reads end only when the driver's timer judges them.
    lines = run_program("sim://?ids=1-4", callback, 1, "Alarm", driver, servo)
    assert lines["injected"] == "True", lines
    assert answered(lines["reads"]), lines
    if servo != 9:  # a reply that came in time is its request's, however late the driver takes it
        assert lines["reads"] == "ok", lines
    assert answered(lines["after"]), lines
    assert lines["end"] == "returned", lines


# A trace function raising an exception where a signal handler's might land: what the programs below share.
RAISING_AT = textwrap.dedent(
    """
    import inspect, sys

    def raising_at(function, marker, exc, armed=None):
        # A trace function raising exc once, at the first line of function holding marker (while armed[0], if given).
        lines, first = inspect.getsourcelines(function)
        at = first + next(i for i, line in enumerate(lines) if marker in line)

        def raise_there(frame, event, arg):
            if event == "line" and frame.f_lineno == at and (armed is None or armed[0]):
                if armed is not None:
                    armed[0] = False
                sys.settrace(None)
                raise exc
            return raise_there

        return raise_there
    """
)


IN_THE_BUS_TASK = RAISING_AT + textwrap.dedent(
    """
    import asyncio, inspect, logging, sys, anyio
    from ics35_async import IcsError, open_bus
    from ics35_async.drivers.anyio_driver import AnyioDriver

    port, backend, where = sys.argv[1:4]
    armed = [False]
    # "driver": in the bus task's own code, just after a wait for input ended.  "anyio": as the bus task leaves one of
    # anyio's cancel scopes, its books left half done (asyncio only).
    raise_there = raising_at(
        AnyioDriver._run, "self._waiting_until = INF", KeyboardInterrupt("raised by a signal handler"), armed
    )

    def tracer(frame, event, arg):  # the bus task's loop, as it resumes
        code = frame.f_code
        if event != "call":
            return None
        if where == "driver" and code.co_name == "_run" and code.co_filename.endswith("anyio_driver.py"):
            return raise_there
        if where == "anyio" and armed[0] and code.co_name == "__exit__" and "_backends" in code.co_filename:
            if asyncio.current_task().get_name().startswith("ics35 bus"):
                armed[0] = False
                sys.settrace(None)
                raise KeyboardInterrupt("raised by a signal handler")
        return None

    class Said(logging.Handler):  # what asyncio says of the program's tasks (a task's exception never retrieved)
        def emit(self, record):
            print("asyncio:", record.getMessage().splitlines()[0], flush=True)

    logging.getLogger("asyncio").addHandler(Said())

    async def read(bus, servo):
        try:
            with anyio.fail_after(5):
                await bus.servo(servo).read_temperature()
        except IcsError as exc:
            return f"failed: {type(exc).__name__}: {exc}"
        except TimeoutError:
            return "unanswered"
        return "ok"

    async def main():
        async with open_bus(port, driver="anyio") as bus:
            sys.settrace(tracer)
            try:
                for i in range(100):
                    armed[0] = i == 20
                    outcome = await read(bus, 1)
                    if outcome != "ok":
                        break
                print("reads:", outcome, flush=True)
            finally:
                sys.settrace(None)
                with anyio.CancelScope(shield=True):
                    print("after:", await read(bus, 2), flush=True)

    try:
        anyio.run(main, backend=backend)
    except BaseException as exc:
        print("end:", type(exc).__name__, flush=True)
    else:
        print("end: returned", flush=True)
    """
)


@pytest.mark.parametrize(("backend", "where"), [("asyncio", "driver"), ("asyncio", "anyio"), ("trio", "driver")])
def test_a_keyboard_interrupt_raised_in_the_bus_task_interrupts_the_program_and_leaves_no_request_waiting(
    backend: str, where: str
) -> None:
    lines = said(IN_THE_BUS_TASK, "sim://?ids=1-4", backend, where, needs="after")
    if (
        backend == "asyncio" and where == "driver"
    ):  # out of the loop from a callback of the task's own, the line going on
        assert lines["after"] == "ok", lines
    else:  # (trio, or inside anyio's books: the task ends, and the line says what stopped it)
        assert answered(lines["after"]) and "KeyboardInterrupt" in lines["after"], lines
    assert lines.get("end") == "KeyboardInterrupt", lines  # the program is interrupted, as the signal meant
    assert "asyncio" not in lines, lines  # (said once, by the line: no traceback of the bus task's at exit)


# The exception a signal handler such as pytest-timeout's raises (not an Exception, nor KeyboardInterrupt), raised
# inside a loop callback's call, where the loop catches it, says so and goes on: what the programs below share.
ALARM_INSIDE_A_CALLBACK = RAISING_AT + textwrap.dedent(
    """
    import asyncio

    class Alarm(BaseException):
        pass

    raise_there = raising_at(asyncio.Handle._run, "_context.run", Alarm("raised by a signal handler"))
    """
)

WAIT_IDLE = ALARM_INSIDE_A_CALLBACK + textwrap.dedent(
    """
    from ics35_async import open_bus

    driver = sys.argv[1]
    armed = [False]

    def tracer(frame, event, arg):  # the callback that tells a wait_idle() the line is idle, dropped once
        if event == "call" and armed[0] and frame.f_code.co_name == "_run" and frame.f_code.co_filename.endswith(
            "events.py"
        ):
            if getattr(getattr(frame.f_locals.get("self"), "_callback", None), "__name__", "") == "set":
                armed[0] = False
                return raise_there
        return None

    async def main():
        async with open_bus("sim://?ids=1-4", driver=driver) as bus:
            sys.settrace(tracer)
            armed[0] = True
            try:
                for _ in range(20):
                    read = asyncio.ensure_future(bus.servo(1).read_temperature())
                    await asyncio.wait_for(bus.wait_idle(), 5)
                    await read
                print("idle: ok", armed[0], flush=True)
            except TimeoutError:
                print("idle: never told", flush=True)

    asyncio.run(main())
    """
)


def test_a_wait_for_an_idle_line_whose_wake_up_was_dropped_still_ends() -> None:
    lines = said(WAIT_IDLE, "thread", needs="idle")
    assert lines["idle"] == "ok False", lines  # (False: the callback was dropped)
    assert lines["idle"] != "never told", lines


# A stream's frames wait on the bus task too, with no request made: the Nth wake-up of the bus task dropped by an
# exception the loop catches (as pytest-timeout's), inside the callback's call.
A_STREAM = (
    ALARM_INSIDE_A_CALLBACK
    + """
from ics35_async import IcsError, open_bus
nth = int(sys.argv[1])
seen = [0]
bus_task = []
def tracer(frame, event, arg):
    if event == "call" and frame.f_code.co_name == "_run" and frame.f_code.co_filename.endswith("events.py"):
        cb = getattr(frame.f_locals.get("self"), "_callback", None)
        if bus_task and getattr(cb, "__self__", None) is bus_task[0]:
            seen[0] += 1
            if seen[0] == nth:
                return raise_there
    return None
async def main():
    async with open_bus("sim://?ids=1-4", driver="anyio") as bus, bus.stream([1, 2]) as stream:
        bus_task.append(bus._driver._task)
        sys.settrace(tracer)
        try:
            for _ in range(300):
                await asyncio.wait_for(stream.next_frame(), 5)
            print("frames: ok", seen[0], flush=True)
        except IcsError as exc:
            print("frames: failed:", type(exc).__name__, exc, flush=True)
        except TimeoutError:
            print("frames: unanswered", flush=True)
try:
    asyncio.run(main())
except BaseException as exc:
    print("end:", type(exc).__name__, flush=True)
"""
)


@pytest.mark.slow  # (a lost wake-up is told after two looks of a second)
def test_a_stream_whose_bus_task_lost_its_wake_up_fails_its_frames_rather_than_waiting() -> None:
    lines = said(A_STREAM, "5", needs="frames")
    assert lines["frames"].startswith("failed: PortLost"), lines


# Ctrl-C under plain asyncio.run, where a SIGINT handler of the program's own has KeyboardInterrupt come out of the
# loop (as a second Ctrl-C does under asyncio.run's own handling): asyncio.run then cancels every task, the program's
# and the bus's alike, and runs them to their ends; the program's closes must still put the servos to rest.  The
# signal is real, sent from a thread of the program's; its handler raises from a loop callback of its own, so that it
# lands where the test says (raised from the handler itself, it lands wherever the loop is, at times inside asyncio's
# or anyio's bookkeeping: see the docs).  "in-driver": it lands in the driver's own code as it takes a reply, raised
# there by a trace function.  "trio": trio.run's own Ctrl-C (a KeyboardInterrupt in the program's task).  The line
# is served in process (in-process, or on a pty by a thread of the program's) so that the program can tell how it was
# left.
CTRL_C_OUT_OF_THE_LOOP = RAISING_AT + textwrap.dedent(
    """
    import asyncio, inspect, os, signal, sys, threading, time, trio
    from ics35_async import open_bus
    from ics35_async.drivers.anyio_driver import AnyioDriver
    from ics35_async.robot import open_robot
    from ics35_async.sim import VirtualLine
    from ics35_async.sim.pty_server import PtyServer

    on, driver, closer, presses = sys.argv[1:5]
    sim = VirtualLine([1, 2, 3], realtime=True)
    port = sim
    if on == "pty":
        server = PtyServer(sim)
        port = str(server.open())
        serving = threading.Thread(target=server.serve, daemon=True)
        serving.start()

    def interrupt(signum, frame):
        def out_of_the_loop():
            raise KeyboardInterrupt

        loop.call_soon_threadsafe(out_of_the_loop)

    if presses != "trio":
        signal.signal(signal.SIGINT, interrupt)

    def press_ctrl_c():
        if presses == "in-driver":
            sys.settrace(in_the_driver)
            return

        def press():
            time.sleep(0.05)
            os.kill(os.getpid(), signal.SIGINT)

        threading.Thread(target=press).start()

    # Where the driver takes what came from the port: the asyncio driver's reader callback, the anyio driver's bus
    # task just after its wait for input ended (not inside anyio's cancel scopes, whose books that would corrupt).
    raise_there = raising_at(
        AnyioDriver._run, "self._waiting_until = INF", KeyboardInterrupt("raised by a signal handler")
    )

    def in_the_driver(frame, event, arg):
        if event != "call" or not frame.f_code.co_filename.endswith(f"{driver}_driver.py"):
            return None
        if frame.f_code.co_name == "_readable":
            sys.settrace(None)
            raise KeyboardInterrupt("raised by a signal handler")
        return raise_there if frame.f_code.co_name == "_run" else None

    async def stream():
        async with open_bus(port, driver=driver) as bus, bus.stream([1, 2, 3], rate_hz=100, on_close="free") as s:
            s.set_targets({1: 8000, 2: 7000, 3: 7500})
            async for frame in s:
                if frame.cycle == 5:
                    press_ctrl_c()

    async def robot():
        joints = {name: {"line": "main", "id": i} for i, name in enumerate("abc", 1)}
        pose = {"a": 10, "b": -10, "c": 5}
        async with open_robot(
            {"lines": {"main": {"port": port}}, "joints": joints}, driver=driver, on_close="free", start_pose=pose
        ) as robot:
            await robot.wait_frame(5)
            press_ctrl_c()
            await robot.move_to({"a": 30, "b": 20, "c": -20}, duration=30)

    async def main():
        global loop
        if presses == "trio":
            await (stream() if closer == "stream" else robot())
            return
        loop = asyncio.get_running_loop()
        try:
            await (stream() if closer == "stream" else robot())
        finally:
            print("tasks left:", len(asyncio.all_tasks()) - 1, flush=True)

    try:
        trio.run(main) if presses == "trio" else asyncio.run(main())
    except BaseException as exc:
        print("end:", type(exc).__name__, flush=True)
    print("servos:", " ".join("free" if sim.servo(i).free else "holding" for i in (1, 2, 3)), flush=True)
    if on == "pty":  # (its private folder, and the link in it, would be left in the temporary directory)
        server.stop()
        serving.join(5)
        server.close()
        print("pty folder left:", server.path.parent.exists(), flush=True)
    """
)


@pytest.mark.parametrize(
    ("on", "closer"), [("sim", "stream"), ("pty", "stream"), ("pty", "robot")], ids=["sim", "pty", "robot"]
)
@pytest.mark.parametrize("presses", ["handler", "in-driver"])
@pytest.mark.parametrize("driver", ["asyncio", "anyio"])
def test_a_keyboard_interrupt_out_of_asyncio_run_still_puts_the_servos_to_rest(
    driver: str, presses: str, on: str, closer: str
) -> None:
    lines = said(CTRL_C_OUT_OF_THE_LOOP, on, driver, closer, presses, needs="servos")
    assert lines.get("end") == "KeyboardInterrupt", lines  # the program is interrupted, as the signal meant
    assert lines["servos"] == "free free free", lines
    assert lines["tasks left"] == "0", lines  # the closed bus left no task of its own behind
    assert lines.get("pty folder left", "False") == "False", lines


@pytest.mark.parametrize(
    ("on", "closer"), [("sim", "stream"), ("pty", "stream"), ("pty", "robot")], ids=["sim", "pty", "robot"]
)
def test_ctrl_c_under_trio_puts_the_servos_to_rest(on: str, closer: str) -> None:
    lines = said(CTRL_C_OUT_OF_THE_LOOP, on, "anyio", closer, "trio", needs="servos")
    assert lines.get("end") == "KeyboardInterrupt", lines
    assert lines["servos"] == "free free free", lines
    assert lines.get("pty folder left", "False") == "False", lines
