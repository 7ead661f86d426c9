"""Freeing servos as a policy: "every servo" (an ID that does not answer is not there) against named IDs."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest

from ics35_async import open_bus
from ics35_async.errors import PortLost, ReplyError, ReplyTimeout
from ics35_async.policies import ALL_IDS, free_servos
from ics35_async.sim import VirtualLine, VirtualServo
from ics35_async.sim.virtual_servo import NO_REPLY
from tests.support.sim_servos import UnplugsWhenAsked, free_command
from tests.support.timing import FAST, or_describe, scaled


@pytest.fixture
def lines() -> Iterator[Any]:
    made: list[VirtualLine] = []

    def make(servos: Any, **options: Any) -> VirtualLine:
        sim = VirtualLine(list(servos), log_size=None, **options)
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


def frees(sim: VirtualLine) -> list[int]:
    """The IDs the free command went to, in the order it went on the wire."""
    return [t.servo_id for t in sim.log if t.command == "free"]


async def test_every_servo_asks_each_id_once_without_the_buses_retries(lines: Any) -> None:
    # A robot that misbehaves must go limp at once: servo 20 is not to wait while each empty ID below it
    # uses up the bus's retries.  Each ID is asked once; only the last, silent, once more (nothing
    # after it would catch a late answer), as a scan's probes are.
    sim = lines([1, 7, 20])
    async with open_bus(sim, retries=2, **FAST) as bus:
        report = await free_servos(bus, ALL_IDS, every_servo=True)
        assert bus.stats.total.retries == 0
    assert dict(report.freed) == {1: 7500, 7: 7500, 20: 7500} and not report.failed
    assert report.absent == tuple(i for i in ALL_IDS if i not in (1, 7, 20))
    sent = [(t.command, t.servo_id) for t in sim.log]
    assert sent[: sent.index(("free", 20)) + 1] == [("free", i) for i in range(21)]
    assert frees(sim) == [*ALL_IDS, 31]


async def test_every_servo_waits_for_a_silent_id_only_as_long_as_answers_take(lines: Any) -> None:
    # An allowance of 5 s (a slow bridge's, set by hand): the empty IDs after servo 0 answered wait what
    # its answer took, not 5 s each (18 of them, twice with a retry: minutes, past the guard).
    sim = lines([0, 7, 20])
    async with open_bus(sim, adapter_latency=5.0, retries=1, quiet_time=0.001) as bus:
        report = await or_describe(free_servos(bus, range(21), every_servo=True), bus, scaled(60))
    assert sorted(report.freed) == [0, 7, 20] and not report.failed
    assert report.absent == tuple(i for i in range(21) if i not in (0, 7, 20))


@pytest.mark.parametrize("ids", [range(8), range(21)], ids=["freed before others", "freed last"])
async def test_every_servo_frees_a_servo_slower_than_the_short_wait_not_calls_it_absent(lines: Any, ids: range) -> None:
    # Servo 7 answers 12 ms late: within the normal allowance (100 ms, which a loaded machine cannot
    # exceed), past the short wait (about 5 ms once servo 1 answered at once).
    sim = lines([1, 7], faults="late@7:1.0", late_delay=0.012, realtime=True)
    async with open_bus(sim, adapter_latency=0.100, quiet_time=0.030) as bus:
        report = await free_servos(bus, ids, every_servo=True)
    assert sorted(report.freed) == [1, 7] and not report.failed
    assert report.absent == tuple(i for i in ids if i not in (1, 7))


async def test_every_servo_on_a_line_where_every_servo_answers_late(lines: Any) -> None:
    # A bridge: every answer takes 30 ms more than the wire.  Before anything answered the free waits
    # the normal allowance; from then on what answers have taken.
    sim = lines([1, 7, 20], turnaround=0.030, realtime=True)
    async with open_bus(sim, adapter_latency=0.150, quiet_time=0.030) as bus:
        report = await free_servos(bus, ALL_IDS, every_servo=True)
    assert sorted(report.freed) == [1, 7, 20] and not report.failed
    assert report.absent == tuple(i for i in ALL_IDS if i not in (1, 7, 20))


async def test_every_servo_fails_an_id_that_answers_garbled_rather_than_calling_it_absent(lines: Any) -> None:
    sim = lines([VirtualServo(1), VirtualServo(7), VirtualServo(7), VirtualServo(20)])  # two sharing ID 7
    async with open_bus(sim, **FAST) as bus:
        report = await free_servos(bus, ALL_IDS, every_servo=True)
    assert sorted(report.freed) == [1, 20]
    assert list(report.failed) == [7] and not isinstance(report.failed[7], ReplyTimeout)
    assert 7 not in report.absent and not report.ok
    assert frees(sim).count(7) == 2  # once more after the line settled: noise would answer then


@pytest.mark.parametrize("seed", range(6))
async def test_every_servo_frees_a_servo_whose_first_answer_was_garbled(lines: Any, seed: int) -> None:
    sim = lines([1, 7, 20], faults="msb@7:0.5", seed=seed)
    async with open_bus(sim, **FAST) as bus:
        report = await free_servos(bus, ALL_IDS, every_servo=True)
    answers_of_7 = [t for t in sim.log if t.command == "free" and t.servo_id == 7]
    assert (7 in report.freed) == (answers_of_7[-1].fault is None)
    assert (7 in report.failed) == (answers_of_7[-1].fault is not None)
    assert isinstance(report.failed.get(7), ReplyError | None) and 7 not in report.absent


async def test_named_ids_keep_the_full_allowance_and_the_buses_retries(lines: Any) -> None:
    # A servo the caller named and that is slow must not be called absent: no short wait, and retries.
    sim = lines([1, 7], faults="late@7:1.0", late_delay=0.012, realtime=True)
    async with open_bus(sim, adapter_latency=0.100, quiet_time=0.030, retries=2) as bus:
        report = await free_servos(bus, [1, 5, 7])
    assert sorted(report.freed) == [1, 7] and list(report.failed) == [5]
    assert frees(sim).count(5) == 3


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


class SilentThenUnplugs(UnplugsWhenAsked):
    """Silent to its first free (an empty ID, as far as a short wait can tell); the line is pulled away as
    its second free comes."""

    def __init__(self, servo_id: int) -> None:
        super().__init__(servo_id, free_command)
        self.frees = 0

    def handle(self, command: Any) -> Any:
        if free_command(command):
            self.frees += 1
            if self.frees == 1:
                return NO_REPLY
        return super().handle(command)


async def test_a_line_lost_as_a_silent_id_is_freed_again_leaves_that_id_unknown(lines: Any) -> None:
    # The last ID, silent, is freed again with the normal allowance; the line is lost on the way: that free
    # was pending (free or still holding), not an empty ID.
    puller = SilentThenUnplugs(31)
    sim = lines([VirtualServo(1), puller])
    puller.line = sim
    async with open_bus(sim, **FAST) as bus:
        report = await free_servos(bus, ALL_IDS, every_servo=True)
    assert sorted(report.freed) == [1] and puller.frees == 2
    assert isinstance(report.lost, PortLost) and not report.ok
    assert report.unknown == (31,) and report.absent == (0, *range(2, 31))
