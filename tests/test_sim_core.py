"""The simulated line's core: spec examples byte for byte, the servo model, the ID command, timing, the log."""

from __future__ import annotations

import pytest

from ics35_async.eeprom import BaudRate, Eeprom, Flags
from ics35_async.errors import InvalidArgument
from ics35_async.protocol import (
    Position,
    ReadEeprom,
    ReadMemory,
    ReadParam,
    WriteEeprom,
    WriteMemory,
    WriteParam,
    nibbles_from_bytes,
    wire_time,
)
from ics35_async.sim import MemoryDevice, VirtualLine, VirtualServo, garble
from ics35_async.sim.virtual_servo import MAX_RATE


def xfer(bus: VirtualLine, tx: bytes | str) -> bytes:
    """Everything the host receives for ``tx`` (fast mode delivers at once)."""
    data = bytes.fromhex(tx) if isinstance(tx, str) else tx
    return b"".join(chunk for _, chunk in bus.process(data))


def h(text: str) -> bytes:
    return bytes.fromhex(text)


# --------------------------------------------------------------------------- spec worked examples


def test_spec_position_example() -> None:
    bus = VirtualLine([1])
    assert xfer(bus, "81 3A 4C") == h("81 3A 4C 01 3A 4C")


def test_spec_read_stretch_example() -> None:
    bus = VirtualLine([1])
    assert xfer(bus, "A1 01") == h("A1 01 21 01 1E")


def test_spec_write_temperature_limit_example() -> None:
    bus = VirtualLine([2])
    assert xfer(bus, "C2 04 0A") == h("C2 04 0A 42 04 0A")
    assert bus.servo(2).temperature_limit == 10


@pytest.mark.parametrize(
    ("offset", "nibbles", "ram", "held"),
    [
        (4, b"\x00\x00", "speed", 1),  # speed 0: the servo moved at rate 0 (a division by zero)
        (2, b"\x00\x01", "stretch", 1),  # stretch gain 1: RAM stretch 0 (an error at power-up)
        (2, b"\x00\x00", "stretch", 1),
        (4, b"\x0c\x08", "speed", 127),  # speed 200: a RAM value whose reply would have its MSB set
        (30, b"\x00\x00", "current_limit", 1),
        (30, b"\x06\x04", "current_limit", 63),
        (28, b"\x00\x00", "temperature_limit", 1),
    ],
    ids=[
        "speed-0",
        "stretch-gain-1",
        "stretch-gain-0",
        "speed-200",
        "current-limit-0",
        "current-limit-100",
        "t-limit-0",
    ],
)
def test_an_eeprom_value_out_of_the_references_range_loads_into_ram_within_it(
    offset: int, nibbles: bytes, ram: str, held: int
) -> None:
    # The simulator stores any EEPROM image the wire brings (what a real servo does with one out of range is not
    # documented), and its RAM loads from it at power-up: held to the range the RAM holds (sections 4-5), so
    # the servo goes on answering and moving.
    bus = VirtualLine([1])
    image = bytearray(bus.servo(1).eeprom.to_bytes())
    image[offset : offset + 2] = nibbles
    assert xfer(bus, b"\xc1\x00" + bytes(image))[-2:] == h("41 00")
    bus.power_cycle()
    servo = bus.servo(1)
    assert getattr(servo, ram) == held
    servo.load = 70  # more than any current limit lets through
    assert xfer(bus, "81 3E 40")[3:4] == h("01")  # position 8000: it takes the command and answers
    bus.advance(0.5)  # moving there
    assert xfer(bus, "A1 03")[2:4] == h("21 03") and xfer(bus, "A1 02")[4] == servo.speed <= 127


def test_spec_id_examples_on_a_single_servo_line() -> None:
    bus = VirtualLine([7])
    assert xfer(bus, "F4 01 01 01") == h("F4 01 01 01 F4")
    assert xfer(bus, "FF 00 00 00") == h("FF 00 00 00 F4")
    assert bus.servo(20).servo_id == 20
    with pytest.raises(KeyError):
        bus.servo(7)


def test_position_reply_from_id0_at_115200_keeps_its_msb() -> None:
    assert xfer(VirtualLine([0]), "80 3A 4C") == h("80 3A 4C 80 3A 4C")
    assert xfer(VirtualLine([0], baudrate=625000), "80 3A 4C") == h("80 3A 4C 00 3A 4C")
    assert xfer(VirtualLine([1]), "81 3A 4C")[3] == 0x01


def test_spec_generic_read_example_four_analog_channels() -> None:
    # Channel k's upper 2 bits and lower 8 bits at addresses 2k-2 and 2k-1.
    channels = [0x3FF, 0x000, 0x155, 0x2AA]
    memory = bytes(b for value in channels for b in (value >> 8, value & 0xFF))
    bus = VirtualLine([], memory={1: memory})
    received = xfer(bus, "A1 7F 00 08")
    assert received[:4] == h("A1 7F 00 08")
    reply = received[4:]
    assert len(reply) == 4 + 16
    assert reply[:4] in (h("A1 7F 00 08"), h("21 7F 00 08"))
    assert reply[4:] == h("00 03 0F 0F 00 00 00 00 00 01 05 05 00 02 0A 0A")


def test_generic_write_then_read() -> None:
    bus = VirtualLine([], memory=[MemoryDevice(9)])
    write = WriteMemory(9, 10, b"\x12\xab")
    received = xfer(bus, write.tx)
    assert received == write.tx + write.encode_reply(None)
    assert bus.memory_device(9).memory[10:12] == b"\x12\xab"
    read = ReadMemory(9, 10, 2)
    reply = xfer(bus, read.tx)[len(read.tx) :]
    assert read.parse(reply) == b"\x12\xab"


def test_servos_ignore_generic_commands_and_memory_devices_ignore_servo_commands() -> None:
    bus = VirtualLine([3], memory={4: b""})
    assert xfer(bus, ReadMemory(3, 0, 1).tx) == ReadMemory(3, 0, 1).tx
    assert xfer(bus, Position(4, 7500, baudrate=115200).tx) == Position(4, 7500, baudrate=115200).tx


# --------------------------------------------------------------------------- framing


def test_only_the_addressed_servo_answers() -> None:
    bus = VirtualLine()
    command = ReadParam(17, 2)
    received = xfer(bus, command.tx)
    assert received[:2] == command.tx
    assert command.parse(received[2:]) == 127
    assert bus.log[-1].responders == (17,)


def test_unknown_subcommand_gets_echo_only_and_is_logged() -> None:
    bus = VirtualLine([1])
    assert xfer(bus, "A1 06") == h("A1 06")
    assert bus.log[-1].command == "unknown"
    assert bus.log[-1].reply == b""


def test_ics35_servo_echoes_the_ics36_position_read_only_and_an_ics36_one_answers() -> None:
    bus = VirtualLine([1, 2], ics36=[2])
    assert xfer(bus, "A1 05") == h("A1 05")
    assert (bus.log[-1].command, bus.log[-1].reply) == ("read_position", b"")
    bus.servo(2).move_by_hand(9000)
    assert xfer(bus, "A2 05") == h("A2 05") + bytes((0x22, 0x05, 9000 >> 7, 9000 & 0x7F))
    assert bus.servo(2).free  # the read changed nothing


@pytest.mark.parametrize("option", ["ics36", "noisy"])
def test_an_ics36_or_noisy_id_with_no_servo_built_from_it_is_refused(option: str) -> None:
    # (a typo, or an ID left out of the servos, would otherwise give an ICS 3.5 or steady servo without a word)
    said = rf"no servo of this line is built from IDs 5, 9 given in {option} \(built from IDs: 1, 2, 3\)"
    with pytest.raises(InvalidArgument, match=said):
        VirtualLine([1, 2, 3], **{option: [2, 5, 9]})
    with pytest.raises(InvalidArgument, match=rf"built from ID 4 given in {option} \(built from IDs: 1\)"):
        VirtualLine([VirtualServo(4), 1], **{option: [4]})  # (an object keeps its own)
    assert VirtualLine(None, **{option: [31]}).servo(31) is not None  # (None: 0-31)


def test_absent_id_gets_echo_only() -> None:
    bus = VirtualLine([1, 2])
    assert xfer(bus, "83 3A 4C") == h("83 3A 4C")
    assert bus.log[-1].responders == ()


def test_command_split_across_writes_is_reassembled() -> None:
    bus = VirtualLine([1])
    assert xfer(bus, "81") == h("81")
    assert xfer(bus, "3A") == h("3A")
    assert xfer(bus, "4C") == h("4C 01 3A 4C")
    assert bus.log[-1].tx == h("81 3A 4C")
    assert bus.log[-1].echo == h("4C")


def test_two_commands_in_one_write_are_both_answered_in_order() -> None:
    bus = VirtualLine([1, 2])
    assert xfer(bus, "A1 02 A2 02") == h("A1 02 21 02 7F A2 02 22 02 7F")


def test_stray_bytes_before_a_command_are_echoed_and_skipped() -> None:
    bus = VirtualLine([1])
    assert xfer(bus, "05 06 81 3A 4C") == h("05 06 81 3A 4C 01 3A 4C")
    assert [t.command for t in list(bus.log)[-2:]] == ["unknown", "position"]
    assert bus.log[-2].tx == h("05 06")


def test_echo_off() -> None:
    bus = VirtualLine([1], echo=False)
    assert xfer(bus, "81 3A 4C") == h("01 3A 4C")
    assert xfer(bus, "83 3A 4C") == b""


def test_eeprom_write_answer_and_persistence() -> None:
    bus = VirtualLine([1])
    image = Eeprom.factory(1).replace(speed=90, punch=5)
    command = WriteEeprom(1, image)
    assert len(command.tx) == 66
    assert xfer(bus, command.tx) == command.tx + h("41 00")
    read = ReadEeprom(1)
    assert read.parse(xfer(bus, read.tx)[2:]) == image
    assert bus.servo(1).eeprom_writes == 1


def test_malformed_eeprom_write_is_ignored() -> None:
    bus = VirtualLine([1])
    bad = bytearray(WriteEeprom(1, Eeprom.factory(1)).tx)
    bad[2] = 0x00  # header nibble 0x5A -> 0x0A
    assert xfer(bus, bytes(bad)) == bytes(bad)
    assert bus.servo(1).eeprom_writes == 0


# --------------------------------------------------------------------------- the servo model


def test_factory_images_are_the_spec_example_with_distinct_calibration() -> None:
    bus = VirtualLine()
    images = [bus.servo(i).eeprom for i in range(32)]
    assert all(img.servo_id == i and img.baud_rate == BaudRate.B115200 for i, img in enumerate(images))
    assert images[5].stretch_gain == 60 and images[5].speed == 127 and images[5].pulse_limit_high == 11500
    assert len({img.calibration for img in images}) == 32


def test_motion_toward_target_at_the_speed_derived_rate() -> None:
    bus = VirtualLine([1])
    servo = bus.servo(1)
    xfer(bus, Position(1, 9500, baudrate=115200).tx)
    start = bus.log[-1].time  # the servo starts when it has heard the command
    bus.advance(0.05)
    travelled = servo.position - 7500
    assert travelled == pytest.approx(MAX_RATE * (bus.now() - start), abs=2)
    assert servo.moving
    bus.advance(1.0)
    assert servo.position == 9500 and not servo.moving
    # The servo reports where it is, not where it is going.
    reply = xfer(bus, Position(1, 7500, baudrate=115200).tx)[3:]
    assert Position(1, 7500, baudrate=115200).parse(reply) == 9500


def test_speed_parameter_slows_motion() -> None:
    bus = VirtualLine([1, 2])
    xfer(bus, WriteParam(2, 2, 32).tx)  # speed 32 of 127
    xfer(bus, Position(1, 9000, baudrate=115200).tx)
    xfer(bus, Position(2, 9000, baudrate=115200).tx)
    bus.advance(0.05)
    fast = bus.servo(1).position - 7500
    slow = bus.servo(2).position - 7500
    assert slow == pytest.approx(fast * 32 / 127, rel=0.05)


def test_targets_are_clamped_to_the_pulse_limits() -> None:
    bus = VirtualLine([1])
    servo = bus.servo(1)
    xfer(bus, Position(1, 16000, baudrate=115200).tx)
    assert servo.target == 11500
    xfer(bus, WriteEeprom(1, servo.eeprom.replace(pulse_limit_low=6000)).tx)
    xfer(bus, Position(1, 100, baudrate=115200).tx)
    assert servo.target == 6000


def test_reverse_flag_mirrors_the_shaft_not_the_host_view() -> None:
    bus = VirtualLine([1])
    servo = bus.servo(1)
    xfer(bus, WriteEeprom(1, servo.eeprom.replace(flags=Flags.REVERSE | Flags.PWMINH)).tx)
    xfer(bus, Position(1, 9000, baudrate=115200).tx)
    bus.advance(1)
    assert servo.position == 9000
    assert servo.shaft_position == 6000
    normal = VirtualLine([1])
    xfer(normal, Position(1, 9000, baudrate=115200).tx)
    normal.advance(1)
    assert normal.servo(1).shaft_position == 9000


def test_free_leaves_the_servo_where_it_is_and_lets_it_be_moved_by_hand() -> None:
    bus = VirtualLine([1])
    servo = bus.servo(1)
    xfer(bus, Position(1, 8000, baudrate=115200).tx)
    bus.advance(1)
    free = Position(1, 0, baudrate=115200)
    assert free.parse(xfer(bus, free.tx)[3:]) == 8000
    assert servo.free
    bus.advance(1)
    servo.move_by_hand(5000)
    bus.advance(1)
    assert free.parse(xfer(bus, free.tx)[3:]) == 5000
    assert bus.log[-1].value == 5000
    # With torque on, a hand-moved servo goes back to its target.
    xfer(bus, Position(1, 5000, baudrate=115200).tx)
    servo.move_by_hand(6000)
    bus.advance(1)
    assert servo.position == 5000


def test_ram_parameters_versus_eeprom_and_power_cycle() -> None:
    bus = VirtualLine([3])
    servo = bus.servo(3)
    for param, value in ((1, 20), (2, 50), (3, 30), (4, 60)):
        command = WriteParam(3, param, value)
        assert command.parse(xfer(bus, command.tx)[3:]) == value
    assert ReadParam(3, 1).parse(xfer(bus, ReadParam(3, 1).tx)[2:]) == 20
    assert ReadParam(3, 2).parse(xfer(bus, ReadParam(3, 2).tx)[2:]) == 50
    assert (servo.current_limit, servo.temperature_limit) == (30, 60)
    image = ReadEeprom(3).parse(xfer(bus, ReadEeprom(3).tx)[2:])
    assert (image.stretch_gain, image.speed, image.current_limit, image.temperature_limit) == (60, 127, 63, 80)

    # An EEPROM write persists but RAM keeps its values until power-up.
    xfer(bus, WriteEeprom(3, image.replace(speed=40, stretch_gain=100)).tx)
    assert ReadParam(3, 2).parse(xfer(bus, ReadParam(3, 2).tx)[2:]) == 50
    bus.power_cycle()
    assert ReadParam(3, 2).parse(xfer(bus, ReadParam(3, 2).tx)[2:]) == 40
    assert ReadParam(3, 1).parse(xfer(bus, ReadParam(3, 1).tx)[2:]) == 50
    assert (servo.current_limit, servo.temperature_limit) == (63, 80)
    assert servo.free  # powers up without torque


def test_baud_mismatch_answers_nothing() -> None:
    fast_servo = VirtualServo(1, baud_rate=1250000)
    bus = VirtualLine([fast_servo, VirtualServo(2)])
    assert xfer(bus, "81 3A 4C") == h("81 3A 4C")
    assert xfer(bus, "A2 02") == h("A2 02 22 02 7F")
    bus.baudrate = 1250000  # as a host reopening the line at 1.25 Mbit/s does
    assert xfer(bus, "81 3A 4C") == h("81 3A 4C 01 3A 4C")
    assert xfer(bus, "A2 02") == h("A2 02")


def test_line_at_a_non_ics_rate_only_echoes() -> None:
    bus = VirtualLine([1])
    bus.baudrate = 9600
    assert xfer(bus, "81 3A 4C") == h("81 3A 4C")


def test_eeprom_baud_change_takes_effect_at_power_up() -> None:
    bus = VirtualLine([1])
    servo = bus.servo(1)
    xfer(bus, WriteEeprom(1, servo.eeprom.replace(baud_rate=625000)).tx)
    assert xfer(bus, "A1 02") == h("A1 02 21 02 7F")
    bus.power_cycle()
    assert xfer(bus, "A1 02") == h("A1 02")
    bus.baudrate = 625000
    assert xfer(bus, "A1 02") == h("A1 02 21 02 7F")


def test_calibration_written_back_differently_is_detectable() -> None:
    bus = VirtualLine([1])
    servo = bus.servo(1)
    assert servo.calibration_intact
    image = servo.eeprom
    damaged = Eeprom(**{**image.__dict__, "calibration": bytes(len(image.calibration))})
    xfer(bus, WriteEeprom(1, damaged).tx)
    assert not servo.calibration_intact


def test_current_rises_with_motion_and_load() -> None:
    bus = VirtualLine([1])
    servo = bus.servo(1)
    read = ReadParam(1, 3)

    def current() -> int:
        return read.parse(xfer(bus, read.tx)[2:])

    assert current() == 0  # free
    xfer(bus, Position(1, 7500, baudrate=115200).tx)
    holding = current()
    xfer(bus, Position(1, 11000, baudrate=115200).tx)
    moving = current()
    assert moving > holding >= 1
    assert not moving & 0x40  # toward larger positions: forward
    bus.advance(1)
    xfer(bus, Position(1, 4000, baudrate=115200).tx)
    assert current() & 0x40  # moving back: the direction bit
    bus.advance(1)
    servo.load = 30
    assert current() == holding + 30
    servo.load = -30
    assert current() == (holding + 30) | 0x40
    xfer(bus, WriteParam(1, 3, 10).tx)
    assert current() & 0x3F == 10  # capped by the current limit


def test_temperature_follows_current_slowly_and_overheating_drops_torque() -> None:
    bus = VirtualLine([1])
    servo = bus.servo(1)
    read = ReadParam(1, 4)

    def temperature() -> int:
        return read.parse(xfer(bus, read.tx)[2:])

    cold = temperature()
    xfer(bus, Position(1, 7500, baudrate=115200).tx)
    servo.load = 40
    bus.advance(1)
    after_1s = temperature()
    bus.advance(60)
    after_1min = temperature()
    assert cold >= after_1s > after_1min  # smaller is hotter, and it takes time
    assert cold - after_1s < after_1s - after_1min
    bus.advance(600)
    assert servo.free  # hotter than the limit (80): the servo drops its torque
    assert temperature() < servo.temperature_limit
    servo.load = 0
    bus.advance(3600)
    assert temperature() > 100  # cooled down again


# --------------------------------------------------------------------------- the ID command


def test_id_read_with_several_servos_is_garbled() -> None:
    bus = VirtualLine([3, 5])
    received = xfer(bus, "FF 00 00 00")
    assert received[:4] == h("FF 00 00 00")
    assert received[4:] == bytes([0xE3 & 0xE5, 0x00])
    record = bus.log[-1]
    assert record.responders == (3, 5) and record.value is None
    assert garble([h("E3"), h("E5")]) == received[4:]


def test_id_write_renames_every_servo_on_the_line() -> None:
    bus = VirtualLine([3, 5, 9])
    received = xfer(bus, "EA 01 01 01")
    assert received[4:] != h("EA")  # three devices answering at once
    assert sorted(s.servo_id for s in bus.servos) == [10, 10, 10]
    assert all(s.eeprom.servo_id == 10 for s in bus.servos)
    # Now a position command to ID 10 has three answers too.
    assert xfer(bus, "8A 3A 4C")[3:] == garble([h("0A 3A 4C")] * 3)


def test_id_command_ignores_servos_at_another_baud() -> None:
    bus = VirtualLine([VirtualServo(3), VirtualServo(5, baud_rate=625000)])
    assert xfer(bus, "FF 00 00 00") == h("FF 00 00 00 E3")
    assert xfer(bus, "E1 01 01 01") == h("E1 01 01 01 E1")
    assert sorted(s.servo_id for s in bus.servos) == [1, 5]


# --------------------------------------------------------------------------- timing and the log


def test_fast_mode_clock_advances_by_the_wire_time() -> None:
    for baud in (115200, 625000, 1250000):
        bus = VirtualLine([1], baudrate=baud, turnaround=50e-6)
        (echo_at, echo), (reply_at, reply) = bus.process(Position(1, 7500, baudrate=baud).tx)
        assert (echo, reply) == (Position(1, 7500, baudrate=baud).tx, bytes.fromhex("01 3A 4C"))
        assert echo_at == pytest.approx(wire_time(3, baud))
        assert reply_at == pytest.approx(wire_time(6, baud) + 50e-6)
        assert bus.now() == pytest.approx(reply_at)
    # The spec's figure: a position transaction is 573 us of wire at 115200.
    assert wire_time(6, 115200) == pytest.approx(573e-6, abs=1e-6)


def test_eeprom_write_answers_after_the_configured_delay() -> None:
    bus = VirtualLine([1], eeprom_write_delay=0.05, turnaround=0.0)
    command = WriteEeprom(1, Eeprom.factory(1))
    (_, _), (reply_at, _) = bus.process(command.tx)
    assert reply_at == pytest.approx(wire_time(66 + 2, 115200) + 0.05)


def test_log_records_every_transaction_and_stays_bounded() -> None:
    bus = VirtualLine([1, 2], log_size=5)
    for i in range(12):
        xfer(bus, Position(1 + i % 2, 7000 + i, baudrate=115200).tx)
    assert bus.transactions == 12
    assert [t.seq for t in bus.log] == list(range(7, 12))
    last = bus.log[-1]
    assert (last.servo_id, last.command, last.tx) == (2, "position", Position(2, 7011, baudrate=115200).tx)
    assert last.reply == last.clean_reply and last.fault is None
    assert last.reply_time is not None and last.reply_time > last.time
    assert [t.seq for t in bus.log_since(10)] == [10, 11]
    silent = VirtualLine([1], log_size=0)
    xfer(silent, Position(1, 7000, baudrate=115200).tx)
    assert silent.transactions == 1 and list(silent.log) == []


def test_log_value_is_what_the_servo_reported() -> None:
    bus = VirtualLine([4])
    bus.servo(4).move_by_hand(6123)
    xfer(bus, Position(4, 0, baudrate=115200).tx)
    assert bus.log[-1].value == 6123
    xfer(bus, ReadEeprom(4).tx)
    assert bus.log[-1].value == bus.servo(4).eeprom


def test_constructor_validation() -> None:
    with pytest.raises(InvalidArgument):
        VirtualLine(baudrate=9600)
    with pytest.raises(InvalidArgument):
        VirtualLine(turnaround=-1)
    with pytest.raises(InvalidArgument):
        VirtualLine(faults="explode:0.5")
    with pytest.raises(InvalidArgument):
        VirtualServo(1, position=0)


def test_nibble_layout_of_memory_replies_uses_the_codec() -> None:
    bus = VirtualLine([], memory={2: bytes(range(128))})
    reply = xfer(bus, ReadMemory(2, 100, 3).tx)[4:]
    assert reply[4:] == nibbles_from_bytes(bytes([100, 101, 102]))
