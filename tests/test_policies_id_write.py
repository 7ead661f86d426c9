"""The safe ID write against the in-process simulator: proof of one device, cost, refusals."""

from __future__ import annotations

from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from typing import Any

import pytest

from ics35_async import open_bus
from ics35_async.bus import Bus
from ics35_async.errors import InvalidArgument, UnsafeOperation, VerifyError
from ics35_async.policies import Refusal, survey_for_id_write, write_lone_id
from ics35_async.sim import FaultConfig, FaultInjector, VirtualLine, VirtualServo
from tests.support.timing import FAST


@asynccontextmanager
async def line(servos: list[VirtualServo], **options: Any) -> AsyncIterator[tuple[VirtualLine, Bus]]:
    sim = VirtualLine(servos, log_size=None)
    try:
        async with open_bus(sim, **{**FAST, **options}) as bus:
            yield sim, bus
    finally:
        sim.close()


def writes(sim: VirtualLine) -> list[str]:
    return [t.command for t in sim.log if t.command in ("write_id", "write_eeprom")]


@pytest.mark.parametrize("retries", [0, 1, 3])
async def test_renumbering_one_servo_takes_at_most_40_transactions(retries: int) -> None:
    async with line([VirtualServo(0)], retries=retries) as (sim, bus):
        change = await write_lone_id(bus, 17)
        assert (change.old_id, change.new_id, change.written) == (0, 17, True)
        assert [s.servo_id for s in sim.servos] == [17]
        assert bus.stats.total.transactions <= 40
        assert bus.stats.total.transactions == sim.transactions


async def test_a_servo_that_has_the_id_already_is_not_written() -> None:
    async with line([VirtualServo(6)]) as (sim, bus):
        change = await write_lone_id(bus, 6)
        assert not change.written
        assert writes(sim) == []


@pytest.mark.parametrize(
    ("ids", "refusal"),
    [([1, 2], Refusal.SEVERAL), ([3, 3], Refusal.GARBLED), ([4, 3, 3], Refusal.GARBLED), ([], Refusal.NOBODY)],
)
async def test_anything_but_one_device_is_refused_and_nothing_written(ids: list[int], refusal: Refusal) -> None:
    async with line([VirtualServo(i) for i in ids]) as (sim, bus):
        survey = await survey_for_id_write(bus)
        assert survey.refusal is refusal and survey.lone_id is None
        assert survey.reason(9)
        with pytest.raises(UnsafeOperation, match="nothing was written"):
            await write_lone_id(bus, 9, survey=survey)
        with pytest.raises(UnsafeOperation):
            await write_lone_id(bus, 9)
        assert writes(sim) == []
        assert sorted(s.servo_id for s in sim.servos) == sorted(ids)


async def test_an_empty_line_costs_one_transaction() -> None:
    async with line([]) as (_, bus):
        survey = await survey_for_id_write(bus)
        assert survey.refusal is Refusal.NOBODY and not survey.silent
        assert bus.stats.total.transactions == 1


async def test_every_answering_id_is_named_in_the_refusal() -> None:
    # On a real wire the ID replies 0xE1 and 0xE3 can combine into a clean 0xE1: the
    # survey does not trust the ID read alone, so servo 3 is found by its own probe.
    async with line([VirtualServo(1), VirtualServo(3)]) as (_, bus):
        survey = await survey_for_id_write(bus)
        assert survey.answered == (1, 3) and survey.refusal is Refusal.SEVERAL
        assert "ALL of them ID 9" in survey.reason(9)


class NotAServo(VirtualServo):
    """A device that answers the ID read as ID 12 but no stretch read (a foreign device on the line)."""

    def handle(self, command: Any) -> Any:
        from ics35_async.protocol import ReadId
        from ics35_async.sim.virtual_servo import NO_REPLY

        return 12 if isinstance(command, ReadId) else NO_REPLY


async def test_a_device_that_only_the_id_read_sees_blocks_the_write() -> None:
    async with line([NotAServo(12)]) as (sim, bus):
        survey = await survey_for_id_write(bus)
        assert survey.refusal is Refusal.ID_READ and survey.id_read == 12
        with pytest.raises(UnsafeOperation):
            await write_lone_id(bus, 9, survey=survey)
        assert writes(sim) == []


async def test_bad_new_id_raises_before_the_wire() -> None:
    async with line([VirtualServo(0)]) as (sim, bus):
        bad: list[Callable[[], Any]] = [lambda: write_lone_id(bus, 32), lambda: write_lone_id(bus, "3")]  # type: ignore[arg-type]
        for call in bad:
            with pytest.raises(InvalidArgument):
                await call()
        assert sim.transactions == 0


# The ID command is sent once (it renames every device that hears it); when its reply goes missing the
# policy asks who answers now instead of guessing.  Fault specs: the all-ID rate applies to the ID command
# (it names no servo), the per-ID override keeps every servo's own transactions clean.
ID_COMMAND_REPLY_LOST = "drop:1,drop@0-31:0"  # the servo hears the write and takes the ID; its ack is lost
ID_COMMAND_NOT_HEARD = "echo:1,echo@0-31:0"  # a collision garbles the write: no servo hears it


def fault_the_id_command(sim: VirtualLine, spec: str) -> None:
    """From now on, the line's faults are ``spec`` (the survey before it ran on a clean line)."""
    sim.faults = FaultInjector(FaultConfig.parse(spec))


async def test_a_lost_acknowledgement_is_settled_by_asking_the_new_id() -> None:
    async with line([VirtualServo(0)]) as (sim, bus):
        survey = await survey_for_id_write(bus)
        fault_the_id_command(sim, ID_COMMAND_REPLY_LOST)
        change = await write_lone_id(bus, 17, survey=survey)
        assert (change.old_id, change.new_id, change.written) == (0, 17, True)
        assert [s.servo_id for s in sim.servos] == [17]


async def test_an_id_write_nobody_heard_says_the_id_is_unchanged() -> None:
    async with line([VirtualServo(4)]) as (sim, bus):
        survey = await survey_for_id_write(bus)
        fault_the_id_command(sim, ID_COMMAND_NOT_HEARD)
        with pytest.raises(VerifyError, match="still answers as ID 4: its ID is unchanged"):
            await write_lone_id(bus, 17, survey=survey)
        assert [s.servo_id for s in sim.servos] == [4]


async def test_an_id_write_after_which_nothing_answers_says_to_scan() -> None:
    async with line([VirtualServo(4)]) as (sim, bus):
        survey = await survey_for_id_write(bus)
        fault_the_id_command(sim, "drop:1")
        with pytest.raises(VerifyError, match="neither ID 4 nor ID 17 answers"):
            await write_lone_id(bus, 17, survey=survey)
