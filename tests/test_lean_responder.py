"""The benchmarks' lean pty responder answers the way the bus expects (else the CPU figures would count failures)."""

from __future__ import annotations

import sys

import anyio
import pytest

from benchmarks.lean_responder import lean_lines
from ics35_async import BusGroup, ReplyTimeout, open_bus, protocol
from tests.support.timing import GUARD, REAL_TIME

pytestmark = [
    pytest.mark.pty,
    pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the responder needs a pty"),
]


@pytest.mark.parametrize("baud", [115200, 1250000])
async def test_every_id_answers_positions_and_parameter_reads(baud: int) -> None:
    with lean_lines(1, baud=baud) as (path,):
        async with open_bus(path, baudrate=baud, **REAL_TIME) as bus:
            assert await bus.scan() == list(range(32))
            assert await bus.servo(0).set_position(9000) == 9000  # ID 0 at 115200 keeps the header's MSB
            assert await bus.servo(0).free() == 9000  # free reads back the last target
            assert await bus.servo(5).read_speed() == 100
            # (The scan's probes wait only as long as answers have taken: on a loaded machine one can time
            # out and be asked again.  The errors counted are this request's.)
            errors = bus.stats.total.errors
            with pytest.raises(ReplyTimeout):  # what it does not know, it leaves unanswered
                await bus.request(protocol.ReadEeprom(5))
            assert bus.stats.total.errors == errors + 1
            # (The stream's wait is measured from answers: on a machine loaded by parallel tests a reply
            # can outlast it now and then; that says nothing of the responder, so its errors are not counted.)
            async with bus.stream(range(32)) as stream:
                frame = await stream.next_frame()
                for _ in range(100):
                    if not frame.failed:
                        break
                    frame = await stream.next_frame()
            assert frame.positions == {i: 9000 if i == 0 else 7500 for i in range(32)}


async def test_wire_mode_serves_several_lines_from_one_process() -> None:
    with lean_lines(3, baud=1250000, wire=True) as paths:
        group = BusGroup.open({str(k): p for k, p in enumerate(paths)}, baudrate=1250000, **REAL_TIME)
        async with group, group.stream({str(k): range(4) for k in range(3)}) as gs:
            for _ in range(3):
                frame = await gs.next_frame()
            # (A reply can outlast the stream's short wait on a loaded machine: a frame with every
            # servo of every line answering is what shows the one process serving all three.)
            with anyio.fail_after(GUARD):
                while frame.failed:
                    frame = await gs.next_frame()
    assert len(frame.positions) == 12 and not frame.failed
