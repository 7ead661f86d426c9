"""A stalled event loop (a slow callback, a GC pause) must not fake a timeout or crash the bus.

On uvloop, ``call_at`` with a time already past returns a plain ``Handle``
without ``when()``; the bus once read it back and raised inside its timer
callback, so the next command was never written and timed out.  Run on both
loops: the default one and uvloop.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable
from typing import Any

import pytest
import uvloop

from ics35_async import open_bus, protocol
from ics35_async.drivers.core import STALL
from ics35_async.errors import ReplyTimeout
from ics35_async.sim import VirtualLine, VirtualServo

LOOPS: dict[str, Callable[[], asyncio.AbstractEventLoop]] = {
    "asyncio": asyncio.new_event_loop,
    "uvloop": uvloop.new_event_loop,
}


def run_with_errors(make_loop: Callable[[], asyncio.AbstractEventLoop], main: Callable[[], Any]) -> list[str]:
    """Run ``main()`` on a new loop; return what reached the loop's exception handler."""
    errors: list[str] = []
    loop = make_loop()
    loop.set_exception_handler(lambda _loop, ctx: errors.append(str(ctx.get("exception") or ctx["message"])))
    try:
        loop.run_until_complete(main())
    finally:
        loop.close()
    return errors


@pytest.mark.parametrize("loop_name", sorted(LOOPS))
def test_a_stalled_loop_gives_no_false_timeout_and_no_exception(loop_name: str) -> None:
    sim = VirtualLine([VirtualServo(i) for i in range(4)], log_size=None)

    async def main() -> None:
        async with open_bus(sim, adapter_latency=0.002, quiet_time=0.001) as bus:
            for _ in range(20):
                # Several requests queued, then the loop stalls well past their deadlines
                # before it polls for I/O: replies and the timer are due at the same time.
                futures = [bus.submit(protocol.ReadParam(i, protocol.Param.STRETCH)) for i in range(4)]
                time.sleep(0.02)
                values = await asyncio.wait_for(asyncio.gather(*futures), 2)
                assert values == [sim.servo(i).stretch for i in range(4)]
            assert bus.stats.total.timeouts == 0

    assert run_with_errors(LOOPS[loop_name], main) == []
    sim.close()


@pytest.mark.slow  # (stalls of seconds: a look is a second)
@pytest.mark.parametrize("loop_name", sorted(LOOPS))
def test_the_anyio_driver_takes_a_loop_stalled_again_and_again_for_a_stall_not_a_lost_wake_up(loop_name: str) -> None:
    # The anyio driver looks at its line once a second for a wake-up an exception dropped (see
    # DriverCore.check_progress): the same overdue deadline found at two looks a whole look apart.  A program that
    # stalls its loop for seconds (a synchronous load, a plot) makes the looks late, never two of them in one go.
    sim = VirtualLine([VirtualServo(i) for i in range(4)], log_size=None)
    stall = 2.5 * STALL

    async def main() -> None:
        async with open_bus(sim, driver="anyio") as bus:
            for _ in range(2):
                time.sleep(stall)  # the look due meanwhile is overdue by more than a look as the request comes
                assert await bus.servo(1).read_temperature() >= 0
                # On the wire, to an ID where nobody is: its deadline, and the looks, pass during the stall.
                read = asyncio.ensure_future(bus.servo(9).read_temperature())
                await asyncio.sleep(0)
                time.sleep(stall)
                with pytest.raises(ReplyTimeout):
                    await asyncio.wait_for(read, 5)

    assert run_with_errors(LOOPS[loop_name], main) == []
    sim.close()


class _SlowLog(logging.Handler):
    """A log handler as slow as a terminal being redrawn, or a log file on a busy SD card: it takes ``delay``
    seconds over each of the stream's warnings."""

    def __init__(self, delay: float) -> None:
        super().__init__(logging.WARNING)
        self.delay = delay
        self.told: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.told.append(record.getMessage())
        time.sleep(self.delay)


DRIVERS_ON_LOOPS = [("asyncio", "asyncio"), ("asyncio", "uvloop"), ("thread", "asyncio"), ("anyio", "asyncio")]


@pytest.mark.parametrize(("driver", "loop_name"), DRIVERS_ON_LOOPS)
def test_a_transaction_waits_its_allowance_from_when_it_was_written_however_late_that_was(
    driver: str, loop_name: str
) -> None:
    # A paced stream that falls behind warns as it plans its next cycle's first transaction: between the engine
    # answering with those bytes and the driver writing them, the program's log handler ran.  Its 30 ms were
    # counted into the transaction's allowance (the deadline came from when the engine answered), so a servo that
    # answered at once after the write was judged silent: `ics35 monitor` showed an error on a simulator.  (Its
    # servos answer 2 ms after a command: the anyio driver's own wait, a fraction of that, does not cover it.)
    sim = VirtualLine([VirtualServo(i) for i in range(4)], realtime=True, turnaround=0.002, log_size=None)
    slow = _SlowLog(0.03)
    library = logging.getLogger("ics35_async")
    library.addHandler(slow)

    async def main() -> None:
        async with open_bus(sim, driver=driver) as bus:
            async with bus.stream(range(4), rate_hz=5000) as stream:
                for _ in range(30):
                    await asyncio.wait_for(stream.next_frame(), 5)
            assert slow.told and "cannot keep rate_hz=5000" in slow.told[0], slow.told
            assert stream.stats.failures == {}, stream.stats.failures
            assert bus.stats.total.timeouts == 0

    try:
        assert run_with_errors(LOOPS[loop_name], main) == []
    finally:
        library.removeHandler(slow)
        sim.close()
