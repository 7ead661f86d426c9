"""The EEPROM write rules against the in-process simulator: plan, refuse, write, verify."""

from __future__ import annotations

import dataclasses
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

import pytest

from ics35_async import open_bus, protocol
from ics35_async.bus import Bus
from ics35_async.eeprom import BaudRate, Eeprom, Flags
from ics35_async.errors import InvalidArgument, UnsafeOperation, VerifyError
from ics35_async.policies import (
    WriteOutcome,
    check_changes,
    edit_image,
    plan_eeprom_write,
    write_eeprom_plan,
    write_eeprom_plans,
)
from ics35_async.policies.eeprom_backup import plan_restores, restore_rates
from ics35_async.sim import VirtualLine, VirtualServo
from tests.conftest import every_backend
from tests.support.sim_servos import UnpluggedAfterWrite
from tests.support.timing import FAST, NO_TIMEOUTS


@asynccontextmanager
async def line(servos: list[VirtualServo], **options: Any) -> AsyncIterator[tuple[VirtualLine, Bus]]:
    sim = VirtualLine(servos, log_size=None)
    try:
        async with open_bus(sim, **{**FAST, **options}) as bus:
            yield sim, bus
    finally:
        sim.close()


class IdAtPowerUp(VirtualServo):
    """A servo that takes a new EEPROM ID only at its next power-up (the reference leaves this open)."""

    def __init__(self, servo_id: int, **options: Any) -> None:
        self._live_id = servo_id
        super().__init__(servo_id, **options)

    @property
    def servo_id(self) -> int:
        return self._live_id

    def power_cycle(self) -> None:
        super().power_cycle()
        self._live_id = self.eeprom.servo_id


def eeprom_writes(sim: VirtualLine) -> int:
    return sum(s.eeprom_writes for s in sim.servos)


async def test_a_field_change_is_written_and_read_back() -> None:
    async with line([VirtualServo(1)]) as (sim, bus):
        plan = await plan_eeprom_write(bus, 1, {"speed": 90, "punch": 4})
        assert set(plan.diff) == {"speed", "punch"} and not plan.changes_baud and not plan.changes_id
        result = await write_eeprom_plan(bus, plan)
        assert result.written and result.acknowledged and result.verified
        assert (sim.servo(1).eeprom.speed, sim.servo(1).eeprom.punch) == (90, 4)
        assert sim.servo(1).calibration_intact
        # Read, read again right before writing, write, read back.
        assert bus.stats.total.transactions == 4


async def test_a_plan_made_around_edit_image_is_checked_before_it_is_written() -> None:
    # EepromPlan is a plain dataclass: a plan built by hand holds whatever its `after` holds.  Each field it
    # changes is checked as Eeprom.replace checks it (the reference's range), before a byte is sent.
    async with line([VirtualServo(1)]) as (sim, bus):
        planned = await plan_eeprom_write(bus, 1, {})
        plan = dataclasses.replace(planned, after=dataclasses.replace(planned.before, speed=0, punch=4))
        with pytest.raises(InvalidArgument, match=r"speed must be in 1\.\.127"):
            await write_eeprom_plan(bus, plan)
        assert eeprom_writes(sim) == 0 and sim.servo(1).eeprom == planned.before


async def test_an_image_that_already_matches_is_not_written() -> None:
    async with line([VirtualServo(1)]) as (sim, bus):
        plan = await plan_eeprom_write(bus, 1, {"speed": 127})
        result = await write_eeprom_plan(bus, plan)
        assert not result.written and eeprom_writes(sim) == 0


async def test_flag_edits_keep_the_other_flags_and_the_read_only_ones() -> None:
    servo = VirtualServo(1)
    servo.eeprom = servo.eeprom.replace(flags=Flags.PWMINH)
    servo.eeprom = Eeprom.from_bytes(servo.eeprom.to_bytes()[:15] + bytes([0x0A]) + servo.eeprom.to_bytes()[16:])
    assert servo.eeprom.flags == Flags.PWMINH | Flags.FREE  # the servo reports itself free
    async with line([servo]) as (sim, bus):
        plan = await plan_eeprom_write(bus, 1, {}, set_flags=Flags.REVERSE)
        assert plan.after.flags == Flags.PWMINH | Flags.FREE | Flags.REVERSE and plan.cleared_flags == Flags(0)
        plan = await plan_eeprom_write(bus, 1, {"flags": Flags.REVERSE})
        assert plan.after.flags == Flags.REVERSE | Flags.FREE
        assert plan.cleared_flags == Flags.PWMINH and plan.added_flags == Flags.REVERSE
        plan = await plan_eeprom_write(bus, 1, {}, clear_flags=Flags.PWMINH)
        assert plan.after.flags == Flags.FREE
        await write_eeprom_plan(bus, plan)
        assert sim.servo(1).eeprom.flags == Flags.FREE


async def test_flag_edits_keep_the_unused_bits_the_servo_has() -> None:
    servo = VirtualServo(1)
    raw = bytearray(servo.eeprom.to_bytes())
    raw[14], raw[15] = 0x6, 0x8  # bits 5-6 and PWMINH, as a servo may report them
    servo.eeprom = Eeprom.from_bytes(bytes(raw))
    async with line([servo]) as (sim, bus):
        plan = await plan_eeprom_write(bus, 1, {}, set_flags=Flags.REVERSE)
        assert int(plan.after.flags) == 0x69 and plan.added_flags == Flags.REVERSE
        await write_eeprom_plan(bus, plan)
        assert int(sim.servo(1).eeprom.flags) == 0x69
        plan = await plan_eeprom_write(bus, 1, {"flags": Flags.REVERSE})  # a replacement of the named flags
        assert int(plan.after.flags) == 0x61 and plan.cleared_flags == Flags.PWMINH
        plan = await plan_eeprom_write(bus, 1, {}, clear_flags=0x60)  # cleared when asked, to the reference's 0
        assert int(plan.after.flags) == 0x09 and plan.cleared_flags == Flags(0)  # nameless: no "flag" lost
        # A restore's saved byte without them (another servo's): they are the servo's state, kept and named.
        restore = await plan_eeprom_write(bus, 1, {"flags": Flags.PWMINH}, keep_read_only=True)
        assert int(restore.after.flags) == 0x68 and int(restore.kept_read_only) == 0x60
        assert restore.kept_note is not None and "(bit 5 on, bit 6 on)" in restore.kept_note
        assert "unused flag bits" in restore.kept_note and "read-only" not in restore.kept_note  # (not flags)
        with pytest.raises(InvalidArgument, match="unused"):
            await plan_eeprom_write(bus, 1, {"flags": 0x40})
        with pytest.raises(InvalidArgument, match="unused"):
            await plan_eeprom_write(bus, 1, {}, set_flags=0x60)


async def test_a_flags_value_naming_a_read_only_flag_is_refused_and_a_restore_keeps_the_servos() -> None:
    servo = VirtualServo(1)
    raw = bytearray(servo.eeprom.to_bytes())
    raw[14], raw[15] = 0x0, 0xA  # PWMINH, and FREE as the servo reports it
    servo.eeprom = Eeprom.from_bytes(bytes(raw))
    async with line([servo]) as (sim, bus):
        for value in (Flags.PCM | Flags.PWMINH, Flags.FREE | Flags.PWMINH):  # a change, or one as the servo has it
            with pytest.raises(InvalidArgument, match="read-only"):
                await plan_eeprom_write(bus, 1, {"flags": value})
        assert sim.transactions == 0
        # A restore: the backup's read-only flags are another moment's state; the servo's stay, and are named.
        plan = await plan_eeprom_write(bus, 1, {"flags": Flags.PCM | Flags.REVERSE}, keep_read_only=True)
        assert plan.after.flags == Flags.FREE | Flags.REVERSE and plan.kept_read_only == Flags.FREE | Flags.PCM
        assert plan.kept_note == (
            "servo 1 keeps its read-only flag(s) as it reports them (FREE on, PCM off): they report the servo's "
            "state and are not written"
        )
        same = await plan_eeprom_write(bus, 1, {"flags": Flags.FREE | Flags.PWMINH}, keep_read_only=True)
        assert not same.diff and same.kept_read_only == Flags(0) and same.kept_note is None


@pytest.mark.parametrize(
    ("changes", "flags"),
    [
        ({}, {"set_flags": Flags.FREE}),
        ({}, {"clear_flags": Flags.PCM}),
        ({"flags": Flags.FREE}, {}),
        ({}, {"set_flags": Flags.REVERSE, "clear_flags": Flags.REVERSE}),
        ({"flags": 0x20}, {}),
        ({"flags": -1}, {}),
        ({"flags": "REVERSE"}, {}),
        ({"speed": 300}, {}),
        ({"colour": 3}, {}),
        ({"baud_rate": 9600}, {}),
    ],
)
async def test_bad_changes_raise_before_the_wire(changes: dict[str, Any], flags: dict[str, Any]) -> None:
    with pytest.raises(InvalidArgument):
        check_changes(changes, **flags)
    async with line([VirtualServo(1)]) as (sim, bus):
        with pytest.raises(InvalidArgument):
            await plan_eeprom_write(bus, 1, changes, **flags)
        assert sim.transactions == 0


def test_edit_image_never_touches_calibration() -> None:
    image = Eeprom.factory(3)
    with pytest.raises(UnsafeOperation):
        edit_image(image, {"calibration": bytes(22)})
    assert edit_image(image, {"speed": 5}).calibration == image.calibration


async def test_a_baud_change_needs_permission_and_is_checked_at_both_rates() -> None:
    async with line([VirtualServo(1)]) as (sim, bus):
        plan = await plan_eeprom_write(bus, 1, {"baud_rate": 1250000})
        assert plan.changes_baud and plan.refusal()
        with pytest.raises(UnsafeOperation, match="nothing was written"):
            await write_eeprom_plan(bus, plan)
        assert eeprom_writes(sim) == 0
        result = await write_eeprom_plan(bus, plan, allow_baud_change=True)
        assert result.verified
        # The simulated servo takes the new rate at its next power-up: not at once.
        assert result.new_rate_answers is False and result.new_rate_error is None
        assert bus.baudrate == 115200  # the line is back at its own rate
        sim.power_cycle()
        await bus.reopen(baudrate=1250000)
        assert (await bus.servo(1).read_eeprom()).baud_rate == BaudRate.B1250000


async def test_a_baud_change_taken_at_once_is_verified_at_the_new_rate() -> None:
    class BaudAtOnce(VirtualServo):
        def handle(self, command: Any) -> Any:
            value = super().handle(command)
            self.baud_rate = self.eeprom.baud_rate
            return value

    async with line([BaudAtOnce(1)]) as (_, bus):
        plan = await plan_eeprom_write(bus, 1, {"baud_rate": 625000, "speed": 10})
        result = await write_eeprom_plan(bus, plan, allow_baud_change=True)
        assert result.verified and result.new_rate_answers is True
        assert bus.baudrate == 115200


async def test_an_id_change_needs_permission_and_a_free_id() -> None:
    async with line([VirtualServo(1), VirtualServo(2)]) as (sim, bus):
        taken = await plan_eeprom_write(bus, 1, {"servo_id": 2})
        assert taken.id_taken
        with pytest.raises(UnsafeOperation, match="already answers"):
            await write_eeprom_plan(bus, taken, allow_id_change=True)
        plan = await plan_eeprom_write(bus, 1, {"servo_id": 5})
        assert not plan.id_taken
        with pytest.raises(UnsafeOperation):
            await write_eeprom_plan(bus, plan)
        assert eeprom_writes(sim) == 0
        result = await write_eeprom_plan(bus, plan, allow_id_change=True)
        assert result.verified and result.answering_ids == (5,)
        assert sorted(s.servo_id for s in sim.servos) == [2, 5]


async def test_an_id_taken_at_power_up_is_reported_as_the_old_id_answering() -> None:
    async with line([IdAtPowerUp(20)]) as (sim, bus):
        plan = await plan_eeprom_write(bus, 20, {"servo_id": 21})
        result = await write_eeprom_plan(bus, plan, allow_id_change=True)
        assert result.verified and result.answering_ids == (20,)
        assert sim.servos[0].eeprom.servo_id == 21
        sim.power_cycle()
        assert sim.servos[0].servo_id == 21


async def test_a_stale_plan_is_not_written() -> None:
    async with line([VirtualServo(1)]) as (sim, bus):
        plan = await plan_eeprom_write(bus, 1, {"speed": 90})
        sim.servo(1).eeprom = sim.servo(1).eeprom.replace(punch=7)  # someone else wrote meanwhile
        with pytest.raises(UnsafeOperation, match="changed since"):
            await write_eeprom_plan(bus, plan)
        assert sim.servo(1).eeprom.speed == 127 and eeprom_writes(sim) == 0


async def test_a_write_the_servo_does_not_keep_fails_verification() -> None:
    class Forgetful(VirtualServo):
        def handle(self, command: Any) -> Any:
            before = self.eeprom
            value = super().handle(command)
            self.eeprom = before  # acknowledges, stores nothing
            return value

    async with line([Forgetful(1)]) as (_, bus):
        plan = await plan_eeprom_write(bus, 1, {"speed": 90})
        with pytest.raises(VerifyError, match="differs"):
            await write_eeprom_plan(bus, plan)


@pytest.mark.parametrize(
    ("changes", "said"),
    [
        ({"speed": 90}, "servo 1 acknowledged the EEPROM write, then did not answer its read-back (asked as ID 1)"),
        ({"servo_id": 7}, "then did not answer its read-back (asked as ID 7 and as ID 1)"),
    ],
)
async def test_a_servo_gone_after_acknowledging_a_write_is_said_written_not_verified(
    changes: dict[str, Any], said: str
) -> None:
    servo = UnpluggedAfterWrite(1)
    async with line([servo]) as (sim, bus):
        servo.line = sim
        plan = await plan_eeprom_write(bus, 1, changes)
        # Said once in sentences that end: it was "servo 1 answers as neither ID 1", with no word of what to do.
        with pytest.raises(VerifyError) as raised:
            await write_eeprom_plan(bus, plan, allow_id_change=True)
    message = str(raised.value)
    assert said in message and "written, not verified" in message, message
    assert "check its power and cable, then read it again" in message, message
    assert servo.eeprom.to_bytes() == plan.after.to_bytes()  # it did take the write: "not verified" was honest


async def test_a_batch_cancelled_mid_write_still_accounts_for_every_servo() -> None:
    """Ctrl-C while the second of three writes waits for its answer: the report says written / unknown / not
    written, then the cancellation goes on; what the servos hold agrees."""
    import asyncio

    from ics35_async.policies import ServoWriteReport, WriteOutcome, write_eeprom_plans

    sim = VirtualLine([1, 2, 3], realtime=True, eeprom_write_delay=0.1, log_size=None)
    heard: list[ServoWriteReport] = []
    try:
        # A real-time simulator answers from its delivery thread, which a loaded machine can hold for more
        # than the real-time allowance; every servo answers here: the no-timeouts allowance.
        async with open_bus(sim, adapter_latency=NO_TIMEOUTS["adapter_latency"]) as bus:
            plans = [await plan_eeprom_write(bus, i, {"speed": 40}) for i in (1, 2, 3)]
            batch = asyncio.ensure_future(write_eeprom_plans(bus, plans, on_report=heard.append))
            while sim.servo(2).eeprom_writes == 0 and not batch.done():  # servo 2 has taken the write;
                await asyncio.sleep(0.001)  # its answer is 0.1 s away
            if batch.done():
                batch.result()  # it ended before servo 2 took its write: its error is the test's failure
            batch.cancel()
            with pytest.raises(asyncio.CancelledError):
                await batch
    finally:
        sim.close()
    assert [(r.plan.servo_id, r.outcome, r.error) for r in heard] == [
        (1, WriteOutcome.VERIFIED, None),
        (2, WriteOutcome.UNKNOWN, None),
        (3, WriteOutcome.NOT_WRITTEN, None),
    ]
    assert [sim.servo(i).eeprom.speed for i in (1, 2, 3)] == [40, 40, 127]  # 2 got it: unknown was honest


async def test_restore_rates_and_plans_at_two_rates_are_written_each_at_its_own() -> None:
    fast = int(BaudRate.B1250000)
    async with line([VirtualServo(1), VirtualServo(2, baud_rate=fast), VirtualServo(3)]) as (sim, bus):
        found = await restore_rates(bus, [1, 2, 3])
        assert dict(found.rates) == {1: 115200, 2: fast, 3: 115200} and found.refusal() is None
        assert bus.baudrate == 115200  # returned to its own rate
        plans = []
        for i in (1, 2, 3):
            if bus.baudrate != found.rates[i]:
                await bus.reopen(baudrate=found.rates[i])
            plans.append(await plan_eeprom_write(bus, i, {"speed": 50}))
        assert [p.baud for p in plans] == [115200, fast, 115200]
        await bus.reopen(baudrate=fast)  # wherever the line is when the writes begin, it is left there
        reports = await write_eeprom_plans(bus, plans)
        assert [r.outcome for r in reports] == [WriteOutcome.VERIFIED] * 3
        assert bus.baudrate == fast and [s.eeprom.speed for s in sim.servos] == [50, 50, 50]
        assert [r.result.read_back.speed for r in reports if r.result and r.result.read_back] == [50, 50, 50]


async def test_an_id_at_two_rates_is_two_servos_and_refused() -> None:
    fast = int(BaudRate.B1250000)
    async with line([VirtualServo(1, baud_rate=fast), VirtualServo(2), VirtualServo(2, baud_rate=fast)]) as (_, bus):
        all_home = await restore_rates(bus, [2])
        assert dict(all_home.rates) == {2: 115200} and not all_home.looked  # nothing sent at another rate
        found = await restore_rates(bus, [1, 2])
        assert found.looked and dict(found.several) == {2: (115200, fast)}
        assert "ID 2 answers at 115,200 and 1,250,000 baud" in (found.refusal() or "")


@every_backend
async def test_a_batch_cancelled_during_its_write_at_another_rate_leaves_the_line_at_its_own() -> None:
    """Ctrl-C while servo 2's write waits for its answer at 1,250,000: the batch had reopened the line there;
    the cancellation goes on with the line back at the rate it had, on every async library."""
    import anyio

    from ics35_async.policies import ServoWriteReport

    fast = int(BaudRate.B1250000)
    sim = VirtualLine([VirtualServo(1), VirtualServo(2, baud_rate=fast)], realtime=True, eeprom_write_delay=0.1)
    heard: list[ServoWriteReport] = []
    try:
        async with open_bus(sim, adapter_latency=NO_TIMEOUTS["adapter_latency"]) as bus:
            plans = [await plan_eeprom_write(bus, 1, {"speed": 40})]
            await bus.reopen(baudrate=fast)
            plans.append(await plan_eeprom_write(bus, 2, {"speed": 40}))
            await bus.reopen(baudrate=115200)
            async with anyio.create_task_group() as group:

                async def batch() -> None:
                    await write_eeprom_plans(bus, plans, on_report=heard.append)
                    raise AssertionError("the batch ended before servo 2 took its write")

                group.start_soon(batch)
                while sim.servo(2).eeprom_writes == 0:  # servo 2 has taken the write; its answer is 0.1 s away
                    await anyio.sleep(0.001)
                assert bus.baudrate == fast  # (the write is on its way at servo 2's rate)
                group.cancel_scope.cancel()
            assert [(r.plan.servo_id, r.outcome) for r in heard] == [
                (1, WriteOutcome.VERIFIED),
                (2, WriteOutcome.UNKNOWN),
            ]
            assert bus.baudrate == 115200 and bus.is_open
            assert [s.eeprom.speed for s in sim.servos] == [40, 40]
            assert await bus.request(protocol.ReadEeprom(1)) == sim.servo(1).eeprom  # the line works at its rate
    finally:
        sim.close()


async def test_restore_rates_on_a_line_without_echo_looks_at_other_rates_when_nothing_answers() -> None:
    """Without the echo, "nothing came back" at the line's rate is what a line whose servos are all at another
    rate gives: they are looked for there.  With the echo, it means the adapter or its wiring: not looked for."""
    fast = int(BaudRate.B1250000)
    sim = VirtualLine([VirtualServo(1, baud_rate=fast), VirtualServo(2, baud_rate=fast)], echo=False, log_size=None)
    try:
        async with open_bus(sim, echo=False, **FAST) as bus:
            found = await restore_rates(bus, [1, 2])
            assert found.looked and dict(found.rates) == {1: fast, 2: fast}
            assert bus.baudrate == 115200
    finally:
        sim.close()


async def test_one_plan_made_at_another_rate_is_written_there_and_the_line_returns_to_its_own() -> None:
    fast = int(BaudRate.B1250000)
    async with line([VirtualServo(1), VirtualServo(2, baud_rate=fast)]) as (sim, bus):
        await bus.reopen(baudrate=fast)
        plan = await plan_eeprom_write(bus, 2, {"speed": 60})
        await bus.reopen(baudrate=115200)
        result = await write_eeprom_plan(bus, plan)
        assert result.verified and sim.servo(2).eeprom.speed == 60
        assert bus.baudrate == 115200  # the caller's line is at the rate it gave
        stale = await plan_eeprom_write(bus, 1, {"speed": 61})
        sim.servo(1).eeprom = sim.servo(1).eeprom.replace(speed=62)
        await bus.reopen(baudrate=fast)
        with pytest.raises(UnsafeOperation, match="changed since"):  # a failure returns the line too
            await write_eeprom_plan(bus, stale)
        assert bus.baudrate == fast


async def test_plan_restores_plans_each_servo_at_its_rate_and_returns_the_line() -> None:
    fast = int(BaudRate.B1250000)
    servos = [VirtualServo(1), VirtualServo(2, baud_rate=fast), VirtualServo(3)]
    async with line(servos) as (sim, bus):
        plans = await plan_restores(bus, {2: {"speed": 50}, 1: {"speed": 51}, 3: {"speed": 52}})
        assert [(p.servo_id, p.baud) for p in plans] == [(1, 115200), (3, 115200), (2, fast)]  # the line's rate first
        assert bus.baudrate == 115200 and eeprom_writes(sim) == 0
        reports = await write_eeprom_plans(bus, plans)
        assert [r.outcome for r in reports] == [WriteOutcome.VERIFIED] * 3
        assert [s.eeprom.speed for s in sim.servos] == [51, 50, 52] and bus.baudrate == 115200


async def test_plan_restores_refuses_an_id_at_two_rates_and_bad_fields_before_the_wire() -> None:
    fast = int(BaudRate.B1250000)
    async with line([VirtualServo(1, baud_rate=fast), VirtualServo(2), VirtualServo(2, baud_rate=fast)]) as (sim, bus):
        with pytest.raises(UnsafeOperation, match=r"ID 2 answers at 115,200 and 1,250,000 baud.*nothing was written"):
            await plan_restores(bus, {1: {"speed": 50}, 2: {"speed": 50}})
        assert bus.baudrate == 115200 and eeprom_writes(sim) == 0
        sent = bus.stats.total.transactions
        with pytest.raises(InvalidArgument):
            await plan_restores(bus, {1: {"speed": 50}, 2: {"speed": 500}})
        assert bus.stats.total.transactions == sent


@every_backend
@pytest.mark.parametrize("stint", [1, 2], ids=["scanning", "planning"])
async def test_plan_restores_cancelled_at_another_rate_returns_the_line_to_its_own(stint: int) -> None:
    """Ctrl-C while the line is at 1,250,000: its first stint there scans for the servos silent at the line's
    rate, its second reads servo 2 for its plan.  The cancellation goes on with the line back at its rate."""
    import anyio

    fast = int(BaudRate.B1250000)
    async with line([VirtualServo(1), VirtualServo(2, baud_rate=fast)]) as (sim, bus):
        async with anyio.create_task_group() as group:

            async def planning() -> None:
                await plan_restores(bus, {1: {"speed": 50}, 2: {"speed": 50}}, bauds=[115200, fast])
                raise AssertionError(f"the planning ended before stint {stint} at another rate was seen")

            group.start_soon(planning)
            for n in range(stint):
                while bus.baudrate == 115200:
                    await anyio.sleep(0)
                while n < stint - 1 and bus.baudrate == fast:
                    await anyio.sleep(0)
            group.cancel_scope.cancel()
        assert bus.baudrate == 115200 and bus.is_open
        assert await bus.request(protocol.ReadEeprom(1)) == sim.servo(1).eeprom  # the line works at its rate


@pytest.mark.parametrize("change", ["calibration", "baud_rate", "servo_id"])
async def test_servo_write_eeprom_and_a_plan_refuse_in_the_same_words(change: str) -> None:
    """The two ways to write an image (``Servo.write_eeprom`` and a plan) refuse a change of the calibration
    bytes, the rate or the ID by one rule: the same words, naming what to do instead, and nothing written."""
    async with line([VirtualServo(1), VirtualServo(2)]) as (sim, bus):
        current = await bus.servo(1).read_eeprom()
        if change == "calibration":  # another servo's bytes: a plan made by hand from its image
            foreign = await bus.servo(2).read_eeprom()
            image = dataclasses.replace(current, calibration=foreign.calibration)
            plan = dataclasses.replace(await plan_eeprom_write(bus, 1, {}), after=image)
        else:
            value = {"baud_rate": 625000, "servo_id": 7}[change]
            image = current.replace(**{change: value})
            plan = await plan_eeprom_write(bus, 1, {change: value})
        with pytest.raises(UnsafeOperation) as by_servo:
            await bus.servo(1).write_eeprom(image)
        with pytest.raises(UnsafeOperation) as by_plan:
            await write_eeprom_plan(bus, plan)
        assert str(by_servo.value) == str(by_plan.value)
        assert str(by_plan.value) == f"{plan.refusal()}; nothing was written"
        hint = {"calibration": "Eeprom.replace()", "baud_rate": "allow_baud_change", "servo_id": "allow_id_change"}
        assert hint[change] in str(by_plan.value)
        assert eeprom_writes(sim) == 0
