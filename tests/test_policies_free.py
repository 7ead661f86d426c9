"""Freeing servos as a policy: "every servo" (an ID that does not answer is not there) against named IDs."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest

from ics35_async import open_bus
from ics35_async.errors import PortLost, ReplyTimeout
from ics35_async.policies import ALL_IDS, free_servos
from ics35_async.sim import VirtualLine, VirtualServo
from tests.support.sim_servos import UnplugsWhenAsked, free_command
from tests.support.timing import FAST


@pytest.fixture
def lines() -> Iterator[Any]:
    made: list[VirtualLine] = []

    def make(servos: Any) -> VirtualLine:
        sim = VirtualLine(list(servos), log_size=None)
        made.append(sim)
        return sim

    yield make
    for sim in made:
        sim.close()


async def test_every_servo_frees_those_there_and_lists_the_silent_ids_as_absent(lines: Any) -> None:
    sim = lines([1, 2, 3])
    async with open_bus(sim, **FAST) as bus:
        report = await free_servos(bus, ALL_IDS, every_servo=True)
    assert dict(report.freed) == {1: 7500, 2: 7500, 3: 7500}
    assert report.absent == (0, *range(4, 32))
    assert not report.failed and report.lost is None and report.ok
    assert all(sim.servo(i).free for i in (1, 2, 3))


async def test_named_ids_that_do_not_answer_failed(lines: Any) -> None:
    sim = lines([1, 2, 3])
    async with open_bus(sim, **FAST) as bus:
        report = await free_servos(bus, range(1, 6))
    assert sorted(report.freed) == [1, 2, 3] and report.absent == ()
    assert sorted(report.failed) == [4, 5] and not report.ok
    assert all(isinstance(e, ReplyTimeout) for e in report.failed.values())


async def test_every_servo_on_a_line_where_none_answers_failed(lines: Any) -> None:
    sim = lines([])
    async with open_bus(sim, **FAST) as bus:
        report = await free_servos(bus, ALL_IDS, every_servo=True)
    assert not report.freed and report.absent == ()
    assert sorted(report.failed) == list(ALL_IDS) and not report.ok


async def test_a_line_lost_half_way_tells_the_freed_from_the_unknown(lines: Any) -> None:
    puller = UnplugsWhenAsked(2, free_command)
    sim = lines([VirtualServo(1), puller, VirtualServo(3)])
    puller.line = sim
    async with open_bus(sim, **FAST) as bus:
        report = await free_servos(bus, ALL_IDS, every_servo=True)
    assert sorted(report.freed) == [1]
    assert isinstance(report.lost, PortLost) and not report.ok
    assert report.unknown == tuple(range(2, 32)) and report.absent == (0,)
