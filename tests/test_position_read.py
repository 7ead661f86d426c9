"""ICS 3.6's position read: the codec, the simulator's ICS 3.6 servos, Servo.read_position and its detection,
and the stream's watched IDs.  What went on the wire is read back from the simulator's log."""

from __future__ import annotations

import functools
from collections.abc import Awaitable, Callable
from typing import Any

import anyio
import pytest

from ics35_async import PositionReadUnsupported, ReplyTimeout, open_bus, protocol, units
from ics35_async.errors import ReplyHeaderError, ReplyLengthError, ReplySubcommandError
from ics35_async.policies.scan import probe_ids
from ics35_async.sim import VirtualLine, VirtualServo, parse_url
from ics35_async.stream import WATCH
from tests.support.sim_servos import LosesPositionReplies, LosesStretchReplies
from tests.support.timing import GUARD

TORQUE_COMMANDS = {"position", "free"}


def fault_lines(caplog: pytest.LogCaptureFixture) -> list[str]:
    """The fault log's lines, each checked to name its port (a simulator here) and given without it."""
    said = [r.getMessage() for r in caplog.records if r.name == "ics35_async.faults"]
    assert all(m.startswith("<VirtualLine ") and ">: " in m for m in said), said
    return [m.partition(">: ")[2] for m in said]


def run(sim: VirtualLine, body: Callable[[Any], Awaitable[Any]]) -> Any:
    return run_with(sim, body)


def run_with(sim: VirtualLine, body: Callable[[Any], Awaitable[Any]], **options: Any) -> Any:
    async def main() -> Any:
        with anyio.fail_after(GUARD):
            async with open_bus(sim, **options) as bus:
                return await body(bus)

    try:
        return anyio.run(main)
    finally:
        sim.close()


def commands(sim: VirtualLine, servo_id: int) -> list[str]:
    return [t.command for t in sim.log_since(0) if t.servo_id == servo_id]


# ---------------------------------------------------------------- codec


def test_the_read_is_two_bytes_and_its_reply_four() -> None:
    command = protocol.ReadPosition(3)
    assert command.tx == bytes((0xA3, 0x05)) and command.reply_len == 4
    assert command.encode_reply(9000) == bytes((0x23, 0x05, 9000 >> 7, 9000 & 0x7F))
    assert command.parse(bytes((0x23, 0x05, 0x46, 0x2C))) == (0x46 << 7) | 0x2C
    decoded = protocol.decode_request(bytes((0xA3, 0x05)), baudrate=115200)
    assert decoded is not None and isinstance(decoded[0], protocol.ReadPosition) and decoded[1] == 2
    assert protocol.ProbeReadPosition(3).tx == command.tx
    assert protocol.ProbeReadPosition(3).timing is protocol.Timing.PROBE


@pytest.mark.parametrize(
    ("reply", "error"),
    [
        (bytes((0x23, 0x05, 0x46)), ReplyLengthError),
        (bytes((0x24, 0x05, 0x46, 0x2C)), ReplyHeaderError),
        (bytes((0x23, 0x01, 0x46, 0x2C)), ReplySubcommandError),
    ],
)
def test_a_wrong_reply_is_named(reply: bytes, error: type[Exception]) -> None:
    with pytest.raises(error):
        protocol.ReadPosition(3).parse(reply)


# ---------------------------------------------------------------- the simulator


def test_ics36_is_a_per_id_option_and_ics35_the_default() -> None:
    _name, options = parse_url("sim://?ids=1-4&ics36=2,4")
    sim = VirtualLine(**options, log_size=None)
    assert [s.ics36 for s in sim.servos] == [False, True, False, True]
    assert not VirtualLine([1]).servo(1).ics36
    with pytest.raises(Exception, match="ics36"):
        parse_url("sim://?ics36=x")
    sim.close()


# ---------------------------------------------------------------- Servo.read_position


def test_an_ics36_servo_reports_its_position_and_keeps_its_torque() -> None:
    sim = VirtualLine([1], ics36=[1], log_size=None)

    async def body(bus: Any) -> list[float]:
        servo = bus.servo(1)
        await servo.set_position(9000)
        held = sim.servo(1).target
        seq = sim.transactions
        got = [await servo.read_position(), await servo.read_position(), await servo.read_position_degrees()]
        assert sim.servo(1).target == held == 9000  # still holding its target: not freed, not moved
        reads = list(sim.log_since(seq))
        assert {t.command for t in reads} == {"read_position"}
        # What the servo answered on the wire, each time (it is still on its way to 9000).
        assert got == [reads[0].value, reads[1].value, units.position_to_degrees(reads[2].value)]
        return got

    run(sim, body)


def test_an_ics35_servo_raises_a_typed_error_and_is_probed_once() -> None:
    sim = VirtualLine([1], log_size=None)

    async def body(bus: Any) -> None:
        servo = bus.servo(1)
        assert await servo.has_position_read() is False
        for _ in range(2):
            with pytest.raises(PositionReadUnsupported, match=r"servo 1 speaks ICS 3\.5") as caught:
                await servo.read_position()
            assert caught.value.servo_id == 1
        assert bus.servo(1).known_position_read() is False  # remembered for the line, not the object

    run(sim, body)
    sent = commands(sim, 1)
    assert not TORQUE_COMMANDS & set(sent), sent  # nothing freed or moved it
    assert sent.count("read_position") == 2  # two silences decide it, once


def test_after_the_callers_own_silent_read_one_silent_probe_says_no_servo_and_an_answer_still_counts() -> None:
    # silent_before: the caller's full-allowance read just went unanswered (a robot's EEPROM read at open).
    sim = VirtualLine([1], ics36=[1], log_size=None)

    async def body(bus: Any) -> None:
        with pytest.raises(ReplyTimeout):
            await bus.servo(5).has_position_read(silent_before=True)
        assert bus.servo(5).known_position_read() is None  # nothing remembered: asked again next time
        assert await bus.servo(1).has_position_read(silent_before=True) is True  # its reply was only lost

    run(sim, body)
    assert commands(sim, 5) == ["read_position"]  # no parameter read, nor the guard read before it
    assert commands(sim, 1) == ["read_position"]


def test_the_fault_log_tells_a_probes_silence_from_a_servo_that_should_have_answered(
    caplog: pytest.LogCaptureFixture,
) -> None:
    # `ics35 -v` shows this log: a healthy ICS 3.5 servo's silence to the probe is not a wiring fault.
    sim = VirtualLine([1], log_size=None)

    async def body(bus: Any) -> None:
        assert await bus.servo(1).has_position_read() is False
        with pytest.raises(ReplyTimeout):
            await bus.servo(9).read_stretch()

    with caplog.at_level("DEBUG", logger="ics35_async.faults"):
        run(sim, body)
    said = fault_lines(caplog)
    probes = [m for m in said if m.startswith("read_position to ID 1")]
    assert probes and all("probe" in m and "check ID" not in m for m in probes), said
    assert any(m.startswith("read_stretch to ID 9") and "check ID, baud rate, power" in m for m in said), said


def test_a_scans_empty_ids_are_not_logged_as_wiring_faults(caplog: pytest.LogCaptureFixture) -> None:
    # Its probes, the second look with the full allowance and the guard read before it: each silence
    # is what a scan expects of an empty ID.
    sim = VirtualLine([1], log_size=None)

    async def body(bus: Any) -> None:
        assert await bus.scan([1, 9]) == [1]

    with caplog.at_level("DEBUG", logger="ics35_async.faults"):
        run(sim, body)
    said = fault_lines(caplog)
    assert said and not [m for m in said if "check ID" in m], said


def test_a_scans_id_read_on_a_silent_line_is_not_logged_as_a_wiring_fault(caplog: pytest.LogCaptureFixture) -> None:
    # A scan of many IDs first asks the whole line with an ID read: silence there (a rate no servo
    # speaks, a line being searched) is what a scan expects too.
    sim = VirtualLine([], log_size=None)

    async def body(bus: Any) -> None:
        assert (await probe_ids(bus, range(32))).nobody  # as `ics35 scan` asks at each rate

    with caplog.at_level("DEBUG", logger="ics35_async.faults"):
        run(sim, body)
    said = fault_lines(caplog)
    assert [m for m in said if m.startswith("read_id")] and not [m for m in said if "check ID" in m], said


def test_an_absent_id_is_not_taken_for_an_ics35_servo() -> None:
    sim = VirtualLine([1], ics36=[1], log_size=None)

    async def body(bus: Any) -> None:
        with pytest.raises(ReplyTimeout):
            await bus.servo(7).read_position()
        assert bus.servo(7).known_position_read() is None  # probed again next time
        assert await bus.servo(1).has_position_read() is True

    run(sim, body)


def test_one_lost_reply_does_not_make_an_ics36_servo_look_like_ics35() -> None:
    """A reply dropped on a noisy line: the probe asks again before it decides."""
    for seed in range(6):
        sim = VirtualLine([1], ics36=[1], faults="drop:0.3", seed=seed, log_size=None)

        async def body(bus: Any) -> bool | None:
            try:
                return bool(await bus.servo(1).has_position_read())
            except ReplyTimeout:
                return None  # silent to everything this time: undecided, never "ICS 3.5"

        assert run(sim, body) in (True, None), seed


def test_read_degrees_is_deprecated_and_says_it_frees() -> None:
    sim = VirtualLine([1], log_size=None)

    async def body(bus: Any) -> float:
        with pytest.warns(DeprecationWarning, match="free_and_read_degrees"):
            return float(await bus.servo(1).read_degrees())

    assert run(sim, body) == pytest.approx(0.0, abs=0.1)
    assert commands(sim, 1) == ["free"]


# ---------------------------------------------------------------- the stream's watched IDs


def test_a_watched_id_is_read_without_a_target_until_it_gets_one() -> None:
    sim = VirtualLine([1, 2], ics36=[1, 2], log_size=None)
    sim.servo(2).move_by_hand(8123)

    async def body(bus: Any) -> None:
        await bus.servo(1).set_position(7000)
        async with bus.stream([1, 2], watch=[1, 2]) as stream:
            for _ in range(3):
                frame = await stream.next_frame()
            assert frame.positions[2] == 8123 and not frame.failed
            assert stream.target(1) == WATCH
            assert sim.servo(1).target == 7000 and sim.servo(2).free  # each as it was
            seq = sim.transactions
            stream.set_target(2, 9000)
            for _ in range(3):
                await stream.next_frame()
            assert "position" in {t.command for t in sim.log_since(seq) if t.servo_id == 2}

    run(sim, body)
    assert not TORQUE_COMMANDS & set(commands(sim, 1)[1:])  # after its own set_position: reads only


# ---------------------------------------------------------------- the policies info and monitor follow


async def planned_and_streamed(bus: Any, frames: int) -> Any:
    """The plan of IDs 1, 2 and 5 where ICS 3.5 servos may be freed, then ``frames`` of a stream of it."""
    from ics35_async import policies

    plan = await policies.plan_position_stream(bus, [1, 2, 5], free_ics35=True)
    async with bus.stream(plan.streamed, **plan.stream_options()) as stream:
        for _ in range(frames):
            await stream.next_frame()
    return plan


def test_a_stream_with_the_plans_options_has_its_silent_ids_offline_from_the_first_frame() -> None:
    # The plan names the IDs silent to its probes; a stream of it asked each of them offline_after cycles more, at
    # its whole reply allowance each, before taking it out of the cycle (`monitor 0-17` with two legs unplugged).
    from ics35_async import policies

    sim = VirtualLine([1, 2], ics36=[2], log_size=None)

    async def body(bus: Any) -> Any:
        plan = await policies.plan_position_stream(bus, [1, 2, 5], free_ics35=True)
        start = sim.transactions
        async with bus.stream(plan.streamed, probe_interval=60.0, **plan.stream_options()) as stream:
            frames = [await stream.next_frame() for _ in range(5)]
        return plan, start, frames

    plan, start, frames = run(sim, body)
    assert plan.silent == [5] and plan.stream_options() == {"watch": [2, 5], "offline": [5]}
    assert all(f.offline == {5} and not f.failed and set(f.positions) == {1, 2} for f in frames), frames
    assert [t.command for t in sim.log_since(start) if t.servo_id == 5] == []  # (first probed a minute on)


def test_the_stream_plan_frees_ics35_servos_only_when_asked_and_sends_no_torque_command() -> None:
    from ics35_async import policies

    sim = VirtualLine([1, 2], ics36=[2], log_size=None)

    async def body(bus: Any) -> tuple[Any, Any, Any]:
        safe = await policies.plan_position_stream(bus, [1, 2, 5])
        limp = await policies.plan_position_stream(bus, [1, 2, 5], free_ics35=True)
        reading = await policies.read_position_without_freeing(bus.servo(1))
        return safe, limp, reading

    safe, limp, reading = run(sim, body)
    # ID 5 is silent to everything: watched (a read never frees), even where the caller allows freeing ICS 3.5
    # servos: it may be a servo whose replies are lost, and the free command would still reach it.
    assert (safe.watch, safe.free, list(safe.left_out)) == ([2, 5], [], [1])
    assert "free command" in safe.left_out[1]
    assert (limp.watch, limp.free, limp.left_out, limp.streamed) == ([2, 5], [1], {}, [1, 2, 5])
    assert safe.silent == limp.silent == [5]  # (a caller holding 5 at a target cannot tell it still holds)
    assert (reading.position, reading.how, reading.protocol) == (None, None, "ICS 3.5")
    assert not TORQUE_COMMANDS & {t.command for t in sim.log_since(0)}


def test_the_stream_plan_finds_a_servo_silent_that_answered_before_its_protocol_is_remembered_from() -> None:
    # Each servo's protocol is probed once per line and remembered; a plan made later probed nothing, so a
    # servo held at a target that had since lost its supply (it restarts free, elsewhere) was not named
    # silent, and a caller streaming it that target threw it there.
    from ics35_async import policies

    sim = VirtualLine([1, 2, 3], ics36=[2], log_size=None)

    async def body(bus: Any) -> Any:
        await policies.plan_position_stream(bus, [1, 2, 3])  # (both protocols known from here on)
        sim.remove_servo(1)
        sim.remove_servo(2)
        return await policies.plan_position_stream(bus, [1, 2, 3], free_ics35=True)

    plan = run(sim, body)
    assert plan.silent == [1, 2] and plan.streamed == [1, 2, 3]
    # Each still read as its protocol says: the ICS 3.6 servo (2) watched, never freed, once it answers again.
    assert (plan.watch, plan.free) == ([2], [1, 3])
    assert not TORQUE_COMMANDS & {t.command for t in sim.log_since(0)}


def test_an_absent_id_costs_the_stream_plan_two_short_probes_and_the_servos_there_are_told_apart_as_ever() -> None:
    # Each wait of a full allowance (an adapter's latency, --timeout) at an ID nobody answers delays the command's
    # first cycle: `monitor 0-17` with two legs unplugged.  The plan asks every ID as a scan probes (a short wait,
    # no retry), and a silent one once more with a short position-read probe: no parameter read with its retries,
    # nor the guard read before each.
    from ics35_async import policies

    sim = VirtualLine([1, 2, 6], ics36=[2], log_size=None)

    async def body(bus: Any) -> Any:
        return await policies.plan_position_stream(bus, range(1, 9), free_ics35=True)

    plan = run_with(sim, body, retries=1)  # (the command line's --retries)
    assert (plan.watch, plan.free, plan.silent) == ([2, 3, 4, 5, 7, 8], [1, 6], [3, 4, 5, 7, 8])
    for absent in (3, 4, 5, 7):
        assert commands(sim, absent) == ["read_stretch", "read_position"], absent
    # The last ID's short wait has nothing after it to catch a late reply: the scan's second look (after its guard).
    assert commands(sim, 8) == ["read_stretch", "read_speed", "read_stretch", "read_position"]
    # The servos that answer: ICS 3.6 by its position read; ICS 3.5 silent to it twice around a parameter read,
    # then, as it is to be freed, once more with the whole allowance (behind a guard read).
    assert commands(sim, 2) == ["read_stretch", "read_position"]
    ics35 = ["read_stretch", "read_position", "read_speed", "read_stretch", "read_position"]
    assert commands(sim, 1) == commands(sim, 6) == [*ics35, "read_stretch", "read_position"]
    assert not TORQUE_COMMANDS & {t.command for t in sim.log_since(0)}


def test_on_a_line_where_nothing_answers_the_stream_plan_asks_each_id_once_and_the_line_once() -> None:
    # `monitor 1-4 --timeout 1` on a line where nothing answers: until something has answered, every probe waits the
    # whole allowance, and each silent ID's position-read probe more waited it once again (ten seconds before the
    # first cycle).  Where no ID answered, one ID read (which every device at the line's rate answers) says whether
    # anyone is there: nobody, and no ID is asked again; a device there, and each silent ID is, as before.
    from ics35_async import policies

    def plan_of(sim: VirtualLine) -> Any:
        return run_with(sim, lambda bus: policies.plan_position_stream(bus, range(1, 5), free_ics35=True), retries=1)

    empty = VirtualLine([], log_size=None)
    plan = plan_of(empty)
    assert (plan.watch, plan.free, plan.silent) == ([1, 2, 3, 4], [], [1, 2, 3, 4])
    for absent in (1, 2, 3):
        assert commands(empty, absent) == ["read_stretch"], absent
    assert commands(empty, 4) == ["read_stretch", "read_speed", "read_stretch"]  # (the scan's second look)
    assert [t.command for t in empty.log_since(0) if t.servo_id is None] == ["read_id"]

    # A servo whose reply to the scan's probe was lost answers the ID read: it is asked again and told apart.
    lossy = VirtualLine([LosesStretchReplies(2, lost=1, ics36=True)], log_size=None)
    plan = plan_of(lossy)
    assert (plan.watch, plan.free, plan.silent) == ([1, 2, 3, 4], [], [1, 3, 4]), plan
    assert commands(lossy, 2) == ["read_stretch", "read_position"]
    assert commands(lossy, 3) == ["read_stretch", "read_position"]
    assert not TORQUE_COMMANDS & {t.command for t in lossy.log_since(0)}


def test_a_known_ics35_servo_gone_silent_is_still_left_out_of_a_plan_that_may_not_free() -> None:
    from ics35_async import policies

    sim = VirtualLine([1, 2], ics36=[2], log_size=None)

    async def body(bus: Any) -> Any:
        await policies.plan_position_stream(bus, [1, 2])
        sim.remove_servo(1)
        return await policies.plan_position_stream(bus, [1, 2])

    plan = run(sim, body)
    assert (plan.watch, plan.free, list(plan.left_out), plan.silent) == ([2], [], [1], [1])


def test_a_holding_ics36_servo_whose_replies_are_lost_is_watched_never_freed_by_a_plan_that_may_free() -> None:
    # A lossy line (or replies late past a short wait: a TCP bridge, an FTDI latency timer): the servo may be silent
    # to the plan's short probes, or answer one and lose the replies that tell its protocol.  Freed on that, a
    # standing robot's joint went limp though only ICS 3.5 servos were to be freed (the free command reaches a
    # servo whose reply is lost).

    undecided = 0
    for seed in range(12):
        sim = VirtualLine([1, 2], ics36=[1], faults="drop@1:0.5", seed=seed, log_size=None)
        sim.servo(1).command_position(9000)  # holding: a joint of a standing robot
        plan = run(sim, functools.partial(planned_and_streamed, frames=6))
        undecided += 1 in plan.silent
        assert 1 in plan.watch and 1 not in plan.free, (seed, plan)
        assert commands(sim, 1).count("free") == 0 and sim.servo(1).target == 9000, seed
        assert 2 in plan.free and 5 in plan.watch, (seed, plan)  # the ICS 3.5 servo freed as asked; nobody at 5
    assert undecided  # (the seeds do make the probes miss the servo)


def test_an_ics36_servo_that_lost_its_probes_replies_is_read_not_freed_where_ics35_servos_may_be_freed() -> None:
    # Two position reads unanswered around an answered parameter read: the probe takes the servo for ICS 3.5.
    # Where that frees it (monitor --free, the Live plots tick, info --free, Hold here), a holding joint went limp.
    from ics35_async import policies

    sim = VirtualLine([LosesPositionReplies(1, lost=2), VirtualServo(2)], log_size=None)
    sim.servo(1).command_position(9000)
    plan = run(sim, functools.partial(planned_and_streamed, frames=3))
    assert (plan.watch, plan.free) == ([1, 5], [2])
    assert "free" not in commands(sim, 1) and sim.servo(1).target == 9000
    assert commands(sim, 2).count("free") >= 1  # the ICS 3.5 servo, as asked

    one = VirtualLine([LosesPositionReplies(1, lost=2)], log_size=None)
    one.servo(1).move_by_hand(9000)
    one.servo(1).command_position(9000)  # (holding where it stands)

    async def read(bus: Any) -> Any:
        return await policies.read_position_without_freeing(bus.servo(1), free_ics35=True)

    reading = run(one, read)
    assert (reading.position, reading.how, reading.protocol) == (9000, "read", "ICS 3.6")
    assert "free" not in commands(one, 1) and one.servo(1).target == 9000


def test_a_servo_read_once_more_is_known_for_ics36_on_its_line_from_then_on() -> None:
    # Its answer to the read once more told the line's memory nothing: it still said ICS 3.5, and a later
    # read without freeing (the configurator's joints after Hold here, a plot without the tick) named the servo
    # ICS 3.5 and left it out, or asked it once more at every free.
    from ics35_async import policies

    sim = VirtualLine([LosesPositionReplies(1, lost=2)], log_size=None)
    sim.servo(1).move_by_hand(9000)

    async def body(bus: Any) -> Any:
        servo = bus.servo(1)
        first = await policies.read_position_without_freeing(servo, free_ics35=True)
        return first, servo.known_position_read(), await policies.read_position_without_freeing(servo)

    first, known, then = run(sim, body)
    assert (first.how, first.protocol) == ("read", "ICS 3.6")
    assert known is True
    assert (then.position, then.how, then.protocol) == (9000, "read", "ICS 3.6")
    assert "free" not in commands(sim, 1)
