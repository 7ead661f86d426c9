"""An in-process device that misbehaves: its ``write`` raises.

Whatever a device does, every request ends once with a typed error and the
program never hangs: the driver takes the raising device for a lost port
(the bus reconnects if asked to, exactly as after an unplug).  Run on every
driver and async library.
"""

from __future__ import annotations

import contextlib
import os
import select
import threading
import time
import tty
from typing import Any

import anyio
import pytest

from ics35_async import IcsError, PortLost, ReplyDataError, open_bus, protocol
from ics35_async.drivers.burst import burst_path
from ics35_async.engine.machine import BURST_LIMIT
from tests.support.fuzzing import healthy_answer
from tests.support.timing import GUARD, NO_TIMEOUTS, REAL_TIME

try:
    import termios
except ImportError:  # Windows: no ttys to check
    termios = None  # type: ignore[assignment]

CASES = [("asyncio", "asyncio"), ("thread", "asyncio"), ("anyio", "asyncio"), ("anyio", "trio")]


class BrokenDevice:
    """Answers like a healthy servo until ``broken`` is set; then its ``write`` raises."""

    def __init__(self) -> None:
        self.host: Any = None
        self.broken: Exception | None = None
        self.writes = 0

    def connect(self, host: Any, baudrate: int) -> None:
        self.host, self.baudrate = host, baudrate

    def disconnect(self) -> None:
        self.host = None

    def write(self, data: bytes) -> None:
        self.writes += 1
        if self.broken is not None:
            raise self.broken
        self.host.deliver(data + healthy_answer(data, self.baudrate, b"\x05"))


@pytest.mark.parametrize(("driver", "library"), CASES, ids=[f"{d}-{lib}" for d, lib in CASES])
@pytest.mark.parametrize("error", [IndexError("pop from an empty deque"), OSError(5, "I/O error")], ids=repr)
def test_a_device_whose_write_raises_ends_every_request_typed(driver: str, library: str, error: Exception) -> None:
    device = BrokenDevice()

    async def main() -> None:
        with anyio.fail_after(10):  # a hang is the failure this test is about
            async with open_bus(device, driver=driver, **REAL_TIME) as bus:
                assert await bus.servo(3).read_stretch() == 5
                device.broken = error
                outcomes: list[BaseException | Any] = []

                async def one(sid: int) -> None:
                    try:
                        outcomes.append(await bus.servo(sid).read_stretch())
                    except Exception as exc:  # what the caller sees, typed or not
                        outcomes.append(exc)

                async with anyio.create_task_group() as tg:
                    for sid in range(4):
                        tg.start_soon(one, sid)
                assert len(outcomes) == 4
                assert all(isinstance(o, IcsError) for o in outcomes), outcomes
                lost = [o for o in outcomes if isinstance(o, PortLost)]
                assert lost, outcomes
                assert str(error.args[-1]) in str(lost[0])
                with pytest.raises(IcsError):
                    await bus.request(protocol.ReadParam(1, protocol.Param.STRETCH))

    anyio.run(main, backend=library)


# ---------------------------------------------------------------------------- parity marks on every driver

PARITY_CASES = [("asyncio", "asyncio"), ("thread", "asyncio"), ("anyio", "asyncio"), ("anyio", "trio")]


@pytest.mark.skipif(termios is None, reason="needs POSIX ttys")
@pytest.mark.parametrize(("driver", "library"), PARITY_CASES, ids=[f"{d}-{lib}" for d, lib in PARITY_CASES])
def test_every_driver_asks_the_kernel_to_mark_parity_errors(driver: str, library: str) -> None:
    # ICS replies carry no checksum: a byte damaged on the wire is caught only if the tty marks it.
    # termios flags belong to the tty, so the slave side shows what the driver set.
    master, slave = os.openpty()
    try:

        async def main() -> None:
            async with open_bus(os.ttyname(slave), driver=driver, **REAL_TIME):
                flags = termios.tcgetattr(slave)[0]
                assert flags & termios.PARMRK and flags & termios.INPCK, (driver, library)

        anyio.run(main, backend=library)
    finally:
        os.close(master)
        os.close(slave)


class FarEnd:
    """The far end of a pty (its master side, raw), served by a thread: :meth:`answer` is what it
    does with each command.  :meth:`close` stops the thread, then closes both ends."""

    def __init__(self) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.master)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self.serve, daemon=True)
        self.thread.start()

    def serve(self) -> None:
        while not self.stop.is_set():
            if select.select([self.master], [], [], 0.05)[0]:
                self.answer(os.read(self.master, 64))

    def answer(self, data: bytes) -> None:
        raise NotImplementedError

    def close(self) -> None:
        self.stop.set()
        self.thread.join()
        os.close(self.master)
        os.close(self.slave)


class MarkingServo(FarEnd):
    """Answers every command as a healthy servo would, except that the ``damaged``-th answer comes
    with one reply byte as the kernel marks a byte received with a parity error (``FF 00 x``).  A
    pty has no wire and so no parity errors of its own; with PARMRK cleared on the tty after the
    driver opened it, the marks the port decodes are these."""

    def __init__(self, damaged: int) -> None:
        self.damaged, self.answers = damaged, 0
        super().__init__()

    def answer(self, data: bytes) -> None:
        reply = healthy_answer(data, 115200, b"\x05")
        self.answers += 1
        if self.answers == self.damaged:
            reply = reply[:1] + b"\xff\x00" + reply[1:]  # the second reply byte arrived damaged
        os.write(self.master, data + reply)


@pytest.mark.skipif(termios is None, reason="needs POSIX ttys")
@pytest.mark.parametrize(("driver", "library"), PARITY_CASES, ids=[f"{d}-{lib}" for d, lib in PARITY_CASES])
def test_on_every_driver_a_marked_byte_fails_its_transaction_and_is_counted(driver: str, library: str) -> None:
    far = MarkingServo(damaged=2)
    slave = far.slave
    try:

        async def main() -> None:
            with anyio.fail_after(10):
                # Every read is answered, by a thread of this (busy) process: the no-timeouts allowance.
                async with open_bus(os.ttyname(slave), driver=driver, **NO_TIMEOUTS) as bus:
                    attrs = termios.tcgetattr(slave)
                    assert attrs[0] & termios.PARMRK  # the driver asked for marks
                    attrs[0] &= ~termios.PARMRK  # now let the far end's marks through as they are
                    termios.tcsetattr(slave, termios.TCSANOW, attrs)
                    assert await bus.servo(3).read_stretch() == 5
                    with pytest.raises(ReplyDataError, match="parity"):
                        await bus.servo(3).read_stretch()
                    assert bus.stats.line_errors == 1
                    assert await bus.servo(3).read_stretch() == 5  # the line carries on

        anyio.run(main, backend=library)
    finally:
        far.close()


class MarkingStreamServo(FarEnd):
    """Answers a stream's position commands as healthy servos would, the ``damaged``-th with a reply byte
    marked as the kernel marks a parity error (see :class:`MarkingServo`)."""

    def __init__(self, damaged: int) -> None:
        self.damaged, self.answers = damaged, 0
        super().__init__()

    def answer(self, data: bytes) -> None:
        reply = healthy_answer(data, 115200)
        self.answers += 1
        if self.answers == self.damaged:
            reply = reply[:1] + b"\xff\x00" + reply[1:]
        os.write(self.master, data + reply)


@pytest.mark.skipif(termios is None, reason="needs POSIX ttys")
@pytest.mark.parametrize("library", ["asyncio", "trio"])
def test_a_marked_byte_in_a_streams_burst_fails_that_transaction_alone(library: str) -> None:
    # The burst path: the executor stops at the chunk holding the mark, and the runner undoes the marks of
    # that chunk alone (every other one comes as it was on the wire).  The mark comes halfway through the
    # second burst (the first ends at the engine's limit).
    far = MarkingStreamServo(damaged=BURST_LIMIT * 3 // 2)
    slave = far.slave
    try:

        async def main() -> None:
            driver = "anyio" if library == "trio" else "auto"
            with anyio.fail_after(GUARD):
                async with open_bus(os.ttyname(slave), driver=driver, **NO_TIMEOUTS) as bus:
                    attrs = termios.tcgetattr(slave)
                    attrs[0] &= ~termios.PARMRK  # the far end's marks come through as they are
                    termios.tcsetattr(slave, termios.TCSANOW, attrs)
                    runner = bus._driver.burst  # type: ignore[attr-defined]
                    if burst_path()[0]:
                        assert runner is not None
                    async with bus.stream(range(4)) as stream:
                        while far.answers < far.damaged + 100:
                            await stream.next_frame()
                        failures = dict(stream.stats.failures)
                    assert bus.stats.line_errors == 1
                    assert sum(failures.values()) == 1, failures
                    if runner is not None:
                        assert runner.bursts > 1  # (the mark came mid-burst)

        anyio.run(main, backend=library)
    finally:
        far.close()


@pytest.mark.parametrize("library", ["asyncio", "trio"])
def test_a_bus_opened_and_closed_at_once_under_the_anyio_driver_closes(library: str) -> None:
    # aclose() can come before the bus task has started: it must still end it (it hung).
    async def main() -> None:
        with anyio.fail_after(10):
            async with open_bus("sim://?ids=1", driver="anyio", **REAL_TIME):
                pass

    anyio.run(main, backend=library)


# ---------------------------------------------------------------------------- late replies at a resync's end


class LateReplies(FarEnd):
    """Echoes each command at once and sends its reply ``delays[k]`` seconds later, past the
    allowance, so that it lands in the resync that follows the timeout, at its end, or just after
    it.  Counts every byte it sends."""

    def __init__(self, delays: list[float]) -> None:
        self.delays, self.sent, self.answers = delays, 0, 0
        super().__init__()

    def answer(self, data: bytes) -> None:
        self.sent += os.write(self.master, data)
        if self.answers < len(self.delays):
            time.sleep(self.delays[self.answers])
        self.answers += 1
        self.sent += os.write(self.master, healthy_answer(data, 115200, b"\x05"))


async def _busy_neighbour() -> None:
    # Another part of the program that holds the event loop for a moment at every turn (a web
    # server, a planner): the time between the loop's look at the port and a timer's callback grows.
    while True:
        time.sleep(0.002)
        await anyio.sleep(0)


@pytest.mark.skipif(termios is None, reason="needs POSIX ttys")
@pytest.mark.parametrize(("driver", "library"), PARITY_CASES, ids=[f"{d}-{lib}" for d, lib in PARITY_CASES])
def test_a_late_reply_that_lands_as_a_resync_ends_is_counted_not_silently_dropped(driver: str, library: str) -> None:
    # A resync ends by dropping what the port still holds.  Bytes that came but were never read (the
    # loop was busy) are a late reply all the same: a scan takes a servo whose late reply left no trace
    # for absent.  Whatever the far end sent must show in the statistics: in a transaction, or as
    # stray bytes.
    # A short allowance and no learning of a slow link (which would soon wait for these replies).
    allowance, quiet = 0.004, 0.002
    # Each reply comes later by a step, from the allowance's end to well past the resync's.
    far = LateReplies([allowance + 0.0002 * k for k in range(80)])
    try:

        async def main() -> None:
            with anyio.fail_after(60):
                async with (
                    open_bus(
                        os.ttyname(far.slave),
                        driver=driver,
                        adapter_latency=allowance,
                        quiet_time=quiet,
                        link_extra_max=0.0,
                    ) as bus,
                    anyio.create_task_group() as group,
                ):
                    group.start_soon(_busy_neighbour)
                    for _ in far.delays:
                        with contextlib.suppress(IcsError):
                            await bus.request(protocol.ReadParam(3, protocol.Param.STRETCH), retries=0)

                    def counted() -> int:
                        stats = bus.stats
                        return stats.total.bytes_rx + stats.stray_bytes

                    with anyio.move_on_after(GUARD):  # the last late reply comes and is read
                        while counted() != far.sent:
                            await anyio.sleep(0.01)
                    assert counted() == far.sent, (far.sent, bus.stats)
                    group.cancel_scope.cancel()

        anyio.run(main, backend=library)
    finally:
        far.close()


@pytest.mark.skipif(termios is None, reason="needs POSIX ttys")
def test_a_scan_on_a_port_with_nothing_attached_warns_that_not_even_the_echo_came(
    caplog: pytest.LogCaptureFixture,
) -> None:
    # No servos and no adapter look alike in the list scan() returns (empty): the log says which.
    master, slave = os.openpty()  # the far end never answers, nor echoes
    try:

        async def main(echo: bool) -> list[int]:
            async with open_bus(os.ttyname(slave), echo=echo, **REAL_TIME) as bus:
                return await bus.scan([1, 2])

        with caplog.at_level("WARNING", logger="ics35_async"):
            assert anyio.run(main, True) == []
        said = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
        assert [m for m in said if "not even the echo" in m and "adapter connected" in m], said
        caplog.clear()
        with caplog.at_level("WARNING", logger="ics35_async"):
            assert anyio.run(main, False) == []  # without an echo, silence is what an empty line gives
        assert not [r for r in caplog.records if "not even the echo" in r.getMessage()]
    finally:
        os.close(master)
        os.close(slave)


def test_a_scan_that_finds_nobody_or_a_shared_id_says_why(caplog: pytest.LogCaptureFixture) -> None:
    # bus.scan() gave an empty list, and nothing else, for servos set to another baud rate and for two new servos
    # that share ID 0 (their replies collide): a program had no way to tell those from an empty line.
    from ics35_async.protocol import BaudRate
    from ics35_async.sim import VirtualLine, VirtualServo

    async def scan(line: VirtualLine) -> list[int]:
        async with open_bus(line) as bus:
            return await bus.scan()

    fast = VirtualLine([VirtualServo(i) for i in (1, 2)])
    for servo in fast.servos:
        servo.baud_rate = BaudRate.B1250000  # silent at the bus's 115200
    with caplog.at_level("WARNING", logger="ics35_async"):
        assert anyio.run(scan, fast) == []
    said = " ".join(r.getMessage() for r in caplog.records if r.levelname == "WARNING")
    assert "no servo answered at 115200" in said and "baudrate=1250000" in said and "ics35" in said, said
    caplog.clear()
    with caplog.at_level("WARNING", logger="ics35_async"):
        assert anyio.run(scan, VirtualLine([VirtualServo(0), VirtualServo(0), VirtualServo(3)])) == [3]
    said = " ".join(r.getMessage() for r in caplog.records if r.levelname == "WARNING")
    assert "ID 0" in said and "garbled" in said and "one at a time" in said, said
    caplog.clear()
    with caplog.at_level("WARNING", logger="ics35_async"):
        assert anyio.run(scan, VirtualLine([VirtualServo(3)])) == [3]  # a line that answers: nothing to say
    assert not [r for r in caplog.records if r.levelname == "WARNING"]


def test_a_scan_that_finds_nobody_on_a_line_without_echo_says_so(caplog: pytest.LogCaptureFixture) -> None:
    # A line without echo (a DIY interface: echo=False) where nothing answers gets no "not even the echo" warning,
    # which would blame the adapter for what such a line always does; no servo answering is still worth saying.
    from ics35_async.protocol import BaudRate
    from ics35_async.sim import VirtualLine, VirtualServo

    async def scan(line: VirtualLine) -> list[int]:
        async with open_bus(line, echo=False) as bus:
            return await bus.scan()

    fast = VirtualLine([VirtualServo(i) for i in (1, 2)], echo=False)
    for servo in fast.servos:
        servo.baud_rate = BaudRate.B1250000  # silent at the bus's 115200
    with caplog.at_level("WARNING", logger="ics35_async"):
        assert anyio.run(scan, fast) == []
    said = " ".join(r.getMessage() for r in caplog.records if r.levelname == "WARNING")
    assert "no servo answered at 115200" in said and "baudrate=1250000" in said, said
    assert "not even the echo" not in said, said
