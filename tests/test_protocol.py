"""The sans-IO wire codec against the spec's worked examples, malformed replies and random input."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ics35_async import protocol
from ics35_async.eeprom import BaudRate, Eeprom, Flags
from ics35_async.errors import (
    BadReply,
    IcsError,
    InvalidArgument,
    MalformedEeprom,
    ReplyDataError,
    ReplyHeaderError,
    ReplyLengthError,
    ReplySubcommandError,
    ReplyValueError,
)
from ics35_async.protocol import (
    Command,
    Param,
    Position,
    ReadEeprom,
    ReadId,
    ReadMemory,
    ReadParam,
    Timing,
    WriteEeprom,
    WriteId,
    WriteMemory,
    WriteParam,
    bytes_from_nibbles,
    decode_request,
    join7,
    nibbles_from_bytes,
    position_from_reply,
    position_reply_header,
    position_reply_shape,
    position_tx,
    split7,
    wire_time,
)

BAUDS = [115200, 625000, 1250000]
BAD_IDS: list[object] = [-1, 32, True, False, 1.0, "1", None]
CALIBRATION = bytes(i & 0x0F for i in range(22))
EEPROM = Eeprom.factory(1, calibration=CALIBRATION)


def h(text: str) -> bytes:
    return bytes.fromhex(text)


def state(cmd: Command[Any]) -> dict[str, Any]:
    """Everything a command holds, read from the slots of its whole class chain."""
    out: dict[str, Any] = {"type": type(cmd)}
    for klass in type(cmd).__mro__:
        for slot in getattr(klass, "__slots__", ()):
            out[slot] = getattr(cmd, slot)
    return out


# --- section 3: position ---


@pytest.mark.parametrize("baud", BAUDS)
def test_position_example(baud: int) -> None:
    cmd = Position(1, 7500, baudrate=baud)
    assert cmd.tx == h("81 3A 4C")
    assert (cmd.echo_len, cmd.reply_len) == (3, 3)
    assert cmd.parse(h("01 3A 4C")) == 7500
    assert cmd.encode_reply(7500) == h("01 3A 4C")
    assert cmd.name == "position"
    assert cmd.idempotent and cmd.timing is Timing.NORMAL
    assert decode_request(h("81 3A 4C"), baudrate=baud) is not None


def test_position_extremes() -> None:
    assert Position(1, 16383, baudrate=115200).tx == h("81 7F 7F")
    assert Position(31, 0, baudrate=115200).tx == h("9F 00 00")
    assert Position(31, 0, baudrate=115200).name == "free"
    assert Position(1, 0, baudrate=115200).parse(h("01 3A 4C")) == 7500  # FREE still reports the angle
    assert Position(5, 7500, baudrate=1250000).parse(h("05 7F 7F")) == 16383


def test_position_to_id0_keeps_msb_only_at_115200() -> None:
    slow = Position(0, 7500, baudrate=115200)
    assert slow.tx == h("80 3A 4C")
    assert slow.encode_reply(7500) == h("80 3A 4C")
    assert slow.parse(h("80 3A 4C")) == 7500
    with pytest.raises(ReplyHeaderError):
        slow.parse(h("00 3A 4C"))
    for baud in (625000, 1250000):
        fast = Position(0, 7500, baudrate=baud)
        assert fast.encode_reply(7500) == h("00 3A 4C")
        assert fast.parse(h("00 3A 4C")) == 7500
        with pytest.raises(ReplyHeaderError):
            fast.parse(h("80 3A 4C"))
    # Only ID 0 keeps the MSB.
    assert Position(1, 7500, baudrate=115200).encode_reply(7500)[0] == 0x01
    assert position_reply_header(0, 115200) == 0x80
    assert position_reply_header(0, 625000) == 0x00
    assert position_reply_header(17, 115200) == 0x11


def test_position_fast_helpers() -> None:
    assert position_tx(1, 7500) == h("81 3A 4C")
    assert position_tx(0, 16383) == h("80 7F 7F")
    assert split7(7500) == (0x3A, 0x4C)
    assert join7(0x3A, 0x4C) == 7500


@settings(max_examples=200)
@given(st.integers(0, 31), st.sampled_from(BAUDS), st.binary(min_size=3, max_size=3), st.binary(max_size=4))
def test_position_from_reply_agrees_with_parse(servo_id: int, baud: int, reply: bytes, before: bytes) -> None:
    cmd = Position(servo_id, 7500, baudrate=baud)
    for candidate in (reply, cmd.encode_reply(reply[1] * 128 % 16384), bytes((cmd.reply_header,)) + reply[1:]):
        fast = position_from_reply(bytearray(before + candidate), len(before), cmd.reply_header)
        try:
            assert fast == cmd.parse(candidate)
        except BadReply:
            assert fast == -1


@pytest.mark.parametrize("header", [0x00, 0x01, 0x11, 0x80])
def test_a_position_replys_shape_takes_exactly_the_replies_the_hot_path_takes(header: int) -> None:
    # The burst executor compares a reply with this shape (bytes under masks) and stops where it differs;
    # the stream takes a reply through position_from_reply: the two must agree on every reply.
    shape = position_reply_shape(header)
    want, masks = shape[:3], shape[3:]
    for first in (header, header ^ 0x80, header ^ 0x01):
        for high in range(256):
            for low in (0x00, 0x4C, 0x7F, 0x80, 0xCC, 0xFF):
                reply = bytes((first, high, low))
                fits = all(b & m == w for b, m, w in zip(reply, masks, want, strict=True))
                assert fits == (position_from_reply(reply, 0, header) >= 0), reply.hex(" ")


def test_position_from_reply_cases() -> None:
    assert position_from_reply(h("FF 01 3A 4C"), 1, 0x01) == 7500
    assert position_from_reply(h("80 3A 4C"), 0, 0x80) == 7500
    assert position_from_reply(h("00 3A 4C"), 0, 0x80) == -1  # ID 0 at 115200 keeps the MSB
    assert position_from_reply(h("01 BA 4C"), 0, 0x01) == -1
    assert position_from_reply(h("01 3A CC"), 0, 0x01) == -1
    assert position_from_reply(h("01 7F 7F"), 0, 0x01) == 16383


@settings(max_examples=300)
@given(st.integers(0, 16383))
def test_split_join_round_trip(position: int) -> None:
    high, low = split7(position)
    assert 0 <= high <= 0x7F and 0 <= low <= 0x7F
    assert join7(high, low) == position
    assert position_tx(3, position) == bytes((0x83, high, low))


@settings(max_examples=150)
@given(st.integers(0, 31), st.integers(0, 16383), st.integers(0, 16383), st.sampled_from(BAUDS))
def test_position_reply_round_trip(servo_id: int, target: int, current: int, baud: int) -> None:
    cmd = Position(servo_id, target, baudrate=baud)
    assert cmd.parse(cmd.encode_reply(current)) == current


# --- section 4: parameter read ---


def test_read_stretch_example() -> None:
    cmd = ReadParam(1, Param.STRETCH)
    assert cmd.tx == h("A1 01")
    assert (cmd.echo_len, cmd.reply_len) == (2, 3)
    assert cmd.parse(h("21 01 1E")) == 30
    assert cmd.encode_reply(30) == h("21 01 1E")
    assert cmd.name == "read_stretch"


@pytest.mark.parametrize(
    ("param", "name"),
    [(1, "read_stretch"), (2, "read_speed"), (3, "read_current"), (4, "read_temperature")],
)
def test_read_each_param(param: int, name: str) -> None:
    cmd = ReadParam(7, param)
    assert cmd.tx == bytes((0xA7, param))
    assert cmd.name == name
    assert cmd.param is Param(param)
    assert cmd.parse(bytes((0x27, param, 0x7F))) == 127
    assert cmd.parse(bytes((0x27, param, 0x00))) == 0


def test_read_eeprom() -> None:
    cmd = ReadEeprom(1)
    assert cmd.tx == h("A1 00")
    assert (cmd.echo_len, cmd.reply_len) == (2, 66)
    reply = h("21 00") + EEPROM.to_bytes()
    assert cmd.parse(reply) == EEPROM
    assert cmd.encode_reply(EEPROM) == reply
    assert cmd.name == "read_eeprom"


# --- section 5: parameter write ---


def test_write_temperature_limit_example() -> None:
    cmd = WriteParam(2, Param.TEMPERATURE, 10)
    assert cmd.tx == h("C2 04 0A")
    assert (cmd.echo_len, cmd.reply_len) == (3, 3)
    assert cmd.parse(h("42 04 0A")) == 10
    assert cmd.encode_reply(10) == h("42 04 0A")
    assert cmd.name == "write_temperature_limit"


@pytest.mark.parametrize(
    ("param", "low", "high", "name"),
    [
        (Param.STRETCH, 1, 127, "write_stretch"),
        (Param.SPEED, 1, 127, "write_speed"),
        (Param.CURRENT, 1, 63, "write_current_limit"),
        (Param.TEMPERATURE, 1, 127, "write_temperature_limit"),
    ],
)
def test_write_param_ranges(param: Param, low: int, high: int, name: str) -> None:
    for value in (low, high):
        cmd = WriteParam(3, param, value)
        assert cmd.tx == bytes((0xC3, param, value))
        assert cmd.name == name
        assert cmd.parse(cmd.encode_reply(value)) == value
    bad: tuple[object, ...] = (low - 1, high + 1, True, float(low), str(low), None)
    for wrong in bad:
        with pytest.raises(InvalidArgument):
            WriteParam(3, param, wrong)  # type: ignore[arg-type]


def test_write_eeprom() -> None:
    cmd = WriteEeprom(1, EEPROM)
    assert cmd.tx == h("C1 00") + EEPROM.to_bytes()
    assert (cmd.echo_len, cmd.reply_len) == (66, 2)
    cmd.parse(h("41 00"))  # returns nothing; raises on a bad reply
    assert cmd.encode_reply(None) == h("41 00")
    assert not cmd.idempotent and cmd.timing is Timing.EEPROM_WRITE


# --- section 6: ID ---


def test_write_id_example() -> None:
    cmd = WriteId(20)
    assert cmd.tx == h("F4 01 01 01")
    assert (cmd.echo_len, cmd.reply_len) == (4, 1)
    assert cmd.parse(h("F4")) == 20
    assert cmd.encode_reply(20) == h("F4")
    assert cmd.servo_id is None and cmd.new_id == 20
    assert not cmd.idempotent and cmd.timing is Timing.ID


def test_read_id_example() -> None:
    cmd = ReadId()
    assert cmd.tx == h("FF 00 00 00")
    assert (cmd.echo_len, cmd.reply_len) == (4, 1)
    assert cmd.parse(h("F4")) == 20
    assert cmd.encode_reply(20) == h("F4")
    assert cmd.servo_id is None
    assert cmd.idempotent and cmd.timing is Timing.ID
    assert ReadId(0).tx == h("E0 00 00 00")
    for found in range(32):
        assert cmd.parse(cmd.encode_reply(found)) == found


# --- section 9: generic memory commands ---


def test_read_analog_device_example() -> None:
    cmd = ReadMemory(1, 0, 8)
    assert cmd.tx == h("A1 7F 00 08")
    assert (cmd.echo_len, cmd.reply_len) == (4, 20)
    # Channels k=1..4 hold 10-bit values: upper 2 bits at 2k-2, lower 8 at 2k-1.
    channels = [0x3FF, 0x000, 0x155, 0x2AA]
    memory = bytes(b for value in channels for b in (value >> 8, value & 0xFF))
    payload = h("00 03 0F 0F 00 00 00 00 00 01 05 05 00 02 0A 0A")
    assert len(payload) == 16
    for header in ("A1", "21"):
        reply = h(f"{header} 7F 00 08") + payload
        data = cmd.parse(reply)
        assert data == memory
        assert [(data[2 * k] << 8) | data[2 * k + 1] for k in range(4)] == channels
    assert cmd.encode_reply(memory) == h("A1 7F 00 08") + payload
    assert cmd.name == "read_memory" and cmd.servo_id == 1


def test_write_memory() -> None:
    cmd = WriteMemory(1, 4, b"\x12\xab")
    assert cmd.tx == h("C1 7F 04 02 01 02 0A 0B")
    assert (cmd.echo_len, cmd.reply_len) == (8, 4)
    cmd.parse(h("C1 7F 04 02"))  # generic replies may keep the MSB ...
    cmd.parse(h("41 7F 04 02"))  # ... or clear it
    assert cmd.encode_reply(None) == h("C1 7F 04 02")
    assert WriteMemory(1, 4, [0x12, 0xAB]).tx == cmd.tx
    assert WriteMemory(1, 4, bytearray(b"\x12\xab")).tx == cmd.tx
    assert not cmd.idempotent


def test_memory_span_edges() -> None:
    assert ReadMemory(0, 127, 1).tx == h("A0 7F 7F 01")
    assert ReadMemory(0, 1, 127).tx == h("A0 7F 01 7F")
    assert WriteMemory(31, 0, bytes(127)).reply_len == 4
    assert len(WriteMemory(31, 100, bytes(28)).tx) == 4 + 56


@settings(max_examples=150)
@given(st.binary(max_size=127))
def test_nibble_round_trip(data: bytes) -> None:
    wire = nibbles_from_bytes(data)
    assert len(wire) == 2 * len(data)
    assert all(b <= 0x0F for b in wire)
    assert bytes_from_nibbles(wire) == data


@pytest.mark.parametrize("wire", [h("01"), h("01 02 03"), h("10 00"), h("00 80")])
def test_bytes_from_nibbles_rejects(wire: bytes) -> None:
    with pytest.raises(ValueError, match="nibble"):
        bytes_from_nibbles(wire)


# --- section 11: timing ---


def test_wire_time_budget() -> None:
    assert wire_time(6, 1250000) == pytest.approx(52.8e-6)
    assert wire_time(6, 115200) == pytest.approx(573e-6, abs=1e-6)
    assert 32 * wire_time(6, 1250000) == pytest.approx(1.69e-3, abs=0.01e-3)
    assert 32 * wire_time(6, 115200) == pytest.approx(18.3e-3, abs=0.1e-3)
    assert wire_time(1, 115200) == pytest.approx(95.49e-6, abs=0.01e-6)


# --- argument checking: every encoder ---

ID_TAKING: list[Callable[[Any], object]] = [
    lambda i: Position(i, 7500, baudrate=115200),
    lambda i: ReadParam(i, Param.SPEED),
    lambda i: ReadEeprom(i),
    lambda i: WriteParam(i, Param.SPEED, 10),
    lambda i: WriteEeprom(i, EEPROM),
    lambda i: ReadId(i),
    lambda i: WriteId(i),
    lambda i: ReadMemory(i, 0, 1),
    lambda i: WriteMemory(i, 0, b"\x01"),
]


@pytest.mark.parametrize("make", ID_TAKING)
@pytest.mark.parametrize("servo_id", BAD_IDS)
def test_every_command_rejects_bad_ids(make: Callable[[Any], object], servo_id: object) -> None:
    with pytest.raises(InvalidArgument, match="servo ID"):
        make(servo_id)


@pytest.mark.parametrize("make", ID_TAKING)
def test_every_command_accepts_id_bounds(make: Callable[[Any], Command[Any]]) -> None:
    assert make(0).tx[0] & 0x1F == 0
    assert make(31).tx[0] & 0x1F == 31


@pytest.mark.parametrize("position", [-1, 16384, True, 7500.0, "7500", None])
def test_position_rejects_bad_positions(position: object) -> None:
    with pytest.raises(InvalidArgument, match="position"):
        Position(1, position, baudrate=115200)  # type: ignore[arg-type]


@pytest.mark.parametrize("baud", [9600, 0, True, 115200.5, None, "fast"])
def test_position_rejects_bad_baud(baud: object) -> None:
    with pytest.raises(InvalidArgument, match="baud"):
        Position(1, 7500, baudrate=baud)  # type: ignore[arg-type]


@pytest.mark.parametrize("param", [0, 5, -1, 0x7F, True, 1.0, "1", None])
def test_param_commands_reject_bad_subcommands(param: object) -> None:
    with pytest.raises(InvalidArgument, match="parameter"):
        ReadParam(1, param)  # type: ignore[arg-type]
    with pytest.raises(InvalidArgument, match="parameter"):
        WriteParam(1, param, 10)  # type: ignore[arg-type]


@pytest.mark.parametrize("eeprom", [None, EEPROM.to_bytes(), EEPROM.to_dict()])
def test_write_eeprom_needs_an_eeprom(eeprom: object) -> None:
    with pytest.raises(InvalidArgument, match="Eeprom"):
        WriteEeprom(1, eeprom)  # type: ignore[arg-type]


# The reference's ranges (section 7) and flag rules (section 8), for an image given to the codec itself: a value
# within its nibbles but outside them (speed 0, punch 200) went on the wire as it was.
@pytest.mark.parametrize(
    ("changes", "match"),
    [
        ({"speed": 0}, "speed must be in 1..127"),
        ({"punch": 200}, "punch must be in 0..10"),
        ({"dead_band": 15}, "dead_band must be in 0..5"),
        ({"safe_timer": 9}, "safe_timer must be in 10..255"),
        ({"servo_id": 32}, "servo_id must be in 0..31"),
        ({"stretch_gain": 61}, "stretch_gain must be even"),
        ({"user_offset": -128}, "user_offset must be in -127..127"),
        ({"pulse_limit_low": 3000}, "pulse_limit_low must be in 3500..11500"),
        ({"flags": Flags.PWMINH | 0x20}, "bits 5-6 are unused"),
        ({"pulse_limit_low": 11500, "pulse_limit_high": 3500}, "must not exceed"),
    ],
)
def test_write_eeprom_refuses_a_value_outside_the_references_range(changes: dict[str, Any], match: str) -> None:
    with pytest.raises(InvalidArgument, match=match):
        WriteEeprom(1, dataclasses.replace(EEPROM, **changes))


def test_write_eeprom_given_the_servos_image_checks_only_what_changes() -> None:
    # A servo's own value outside the ranges (an image as read) is written back as it is; a change is checked.
    held = dataclasses.replace(EEPROM, speed=0, flags=Flags(0x68))
    changed = dataclasses.replace(held, punch=3, flags=Flags(0x69))
    assert WriteEeprom(1, changed, current=held).tx == h("C1 00") + changed.to_bytes()
    with pytest.raises(InvalidArgument, match="speed"):
        WriteEeprom(1, changed)
    with pytest.raises(InvalidArgument, match="punch"):
        WriteEeprom(1, dataclasses.replace(changed, punch=11), current=held)
    with pytest.raises(InvalidArgument, match="read-only"):
        WriteEeprom(1, dataclasses.replace(changed, flags=Flags(0x6B)), current=held)
    with pytest.raises(InvalidArgument, match="Eeprom"):
        WriteEeprom(1, changed, current=held.to_bytes())  # type: ignore[arg-type]
    # The read-only flags report the servo's state: an image with them, checked alone, is not refused for them.
    assert WriteEeprom(1, dataclasses.replace(EEPROM, flags=Flags.FREE | Flags.PCM)).eeprom.flags == Flags(0x06)


def test_a_device_frames_an_eeprom_write_whatever_its_values() -> None:
    # The simulator answers a host's write of any 64 nibbles (a servo's own out-of-range value written back).
    held = dataclasses.replace(EEPROM, speed=0)
    framed = decode_request(WriteEeprom(1, held, current=held).tx, baudrate=115200)
    assert framed is not None and isinstance(framed[0], WriteEeprom) and framed[0].eeprom == held


@pytest.mark.parametrize(
    ("address", "count", "match"),
    [
        (-1, 1, "address"),
        (128, 1, "address"),
        (True, 1, "address"),
        (0.0, 1, "address"),
        ("0", 1, "address"),
        (0, 0, "count"),
        (0, 128, "count"),
        (0, -1, "count"),
        (0, True, "count"),
        (0, 1.0, "count"),
        (100, 29, "runs past"),
        (127, 2, "runs past"),
    ],
)
def test_read_memory_rejects_bad_spans(address: object, count: object, match: str) -> None:
    with pytest.raises(InvalidArgument, match=match):
        ReadMemory(1, address, count)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("address", "data", "match"),
    [
        (-1, b"\x01", "address"),
        (128, b"\x01", "address"),
        (True, b"\x01", "address"),
        (0, b"", "count"),
        (0, bytes(128), "count"),
        (100, bytes(29), "runs past"),
        (0, 5, "data must be"),
        (0, True, "data must be"),
        (0, "ab", "data must be"),
        (0, None, "data must be"),
        (0, [256], "data must be"),
        (0, [-1], "data must be"),
        (0, [1.0], "data must be"),
    ],
)
def test_write_memory_rejects_bad_arguments(address: object, data: object, match: str) -> None:
    with pytest.raises(InvalidArgument, match=match):
        WriteMemory(1, address, data)  # type: ignore[arg-type]


def test_invalid_argument_is_a_value_error() -> None:
    with pytest.raises(ValueError):
        Position(32, 7500, baudrate=115200)


# --- malformed replies: each class raises its typed error ---

# Each good reply with the value it must parse to (data chosen so that a parser reading the wrong bytes,
# or the right bytes in the wrong order, returns something else).
GOOD_PARSED: list[tuple[Command[Any], bytes, object]] = [
    (Position(1, 7500, baudrate=115200), h("01 3A 4C"), 7500),
    (Position(0, 7500, baudrate=115200), h("80 1B 58"), 3544),
    (ReadParam(1, Param.STRETCH), h("21 01 1E"), 30),
    (ReadEeprom(1), h("21 00") + EEPROM.to_bytes(), EEPROM),
    (WriteParam(2, Param.TEMPERATURE, 10), h("42 04 0A"), 10),
    (WriteEeprom(1, EEPROM), h("41 00"), None),
    (ReadId(), h("F4"), 20),
    (WriteId(20), h("F4"), 20),
    (
        ReadMemory(1, 0, 8),
        h("21 7F 00 08 00 03 0F 0F 00 00 00 00 00 01 05 05 00 02 0A 0A"),
        h("03 FF 00 00 01 55 02 AA"),
    ),
    (WriteMemory(1, 4, b"\x12\xab"), h("41 7F 04 02"), None),
]
GOOD: list[tuple[Command[Any], bytes]] = [(cmd, reply) for cmd, reply, _ in GOOD_PARSED]
GOOD_IDS = [f"{cmd.name}-{cmd.tx[:2].hex()}" for cmd, _ in GOOD]


def expect(error: type[BadReply], cmd: Command[Any], reply: bytes) -> BadReply:
    with pytest.raises(error) as info:
        cmd.parse(reply)
    exc = info.value
    assert isinstance(exc, BadReply)
    assert exc.command == cmd.name
    assert exc.servo_id == cmd.servo_id
    assert exc.raw == reply
    return exc


@pytest.mark.parametrize(("cmd", "reply", "value"), GOOD_PARSED, ids=GOOD_IDS)
def test_good_replies_parse(cmd: Command[Any], reply: bytes, value: object) -> None:
    assert cmd.parse(reply) == value


@pytest.mark.parametrize(("cmd", "reply"), GOOD, ids=GOOD_IDS)
def test_short_and_long_replies(cmd: Command[Any], reply: bytes) -> None:
    expect(ReplyLengthError, cmd, reply[:-1])
    expect(ReplyLengthError, cmd, b"")
    expect(ReplyLengthError, cmd, reply + b"\x00")
    expect(ReplyLengthError, cmd, reply + reply)


@pytest.mark.parametrize(("cmd", "reply"), GOOD, ids=GOOD_IDS)
def test_wrong_command_byte(cmd: Command[Any], reply: bytes) -> None:
    kinds = {0x00, 0x20, 0x40, 0x60, 0x80, 0xA0, 0xC0, 0xE0}
    first = reply[0]
    for kind in kinds - {first & 0xE0, (first & 0xE0) ^ 0x80}:
        expect(ReplyHeaderError, cmd, bytes((kind | (first & 0x1F),)) + reply[1:])


@pytest.mark.parametrize(("cmd", "reply"), [g for g in GOOD if g[0].servo_id is not None or isinstance(g[0], WriteId)])
def test_wrong_id(cmd: Command[Any], reply: bytes) -> None:
    for other in (0, 2, 31):
        if other != reply[0] & 0x1F:
            expect(ReplyHeaderError, cmd, bytes(((reply[0] & 0xE0) | other,)) + reply[1:])


def test_msb_rule_of_the_reply_header() -> None:
    # Servo replies clear the MSB of CMD (except ID 0 at 115200); generic replies may keep it.
    expect(ReplyHeaderError, Position(1, 7500, baudrate=115200), h("81 3A 4C"))
    expect(ReplyHeaderError, ReadParam(1, 1), h("A1 01 1E"))
    expect(ReplyHeaderError, WriteParam(2, 4, 10), h("C2 04 0A"))
    expect(ReplyHeaderError, ReadEeprom(1), h("A1 00") + EEPROM.to_bytes())
    expect(ReplyHeaderError, WriteEeprom(1, EEPROM), h("C1 00"))
    expect(ReplyHeaderError, ReadId(), h("74"))  # the ID reply keeps its MSB
    expect(ReplyHeaderError, WriteId(20), h("74"))
    expect(ReplyHeaderError, WriteId(20), h("F5"))
    assert ReadMemory(1, 0, 1).parse(h("A1 7F 00 01 0F 0F")) == b"\xff"


@pytest.mark.parametrize(
    ("cmd", "reply"),
    [
        (ReadParam(1, Param.STRETCH), h("21 02 1E")),
        (ReadParam(1, Param.STRETCH), h("21 81 1E")),
        (ReadEeprom(1), h("21 01") + EEPROM.to_bytes()),
        (WriteParam(2, Param.TEMPERATURE, 10), h("42 03 0A")),
        (WriteEeprom(1, EEPROM), h("41 04")),
        (ReadMemory(1, 0, 8), h("21 00 00 08") + bytes(16)),  # SC 0 instead of 0x7F
        (ReadMemory(1, 0, 8), h("21 7F 01 08") + bytes(16)),  # address
        (ReadMemory(1, 0, 8), h("21 7F 80 08") + bytes(16)),
        (ReadMemory(1, 2, 1), h("21 7F 02 02 00 00")),  # count (at the expected length)
        (WriteMemory(1, 4, b"\x12\xab"), h("41 7E 04 02")),
        (WriteMemory(1, 4, b"\x12\xab"), h("41 7F 05 02")),
        (WriteMemory(1, 4, b"\x12\xab"), h("41 7F 04 01")),
    ],
)
def test_wrong_subcommand(cmd: Command[Any], reply: bytes) -> None:
    expect(ReplySubcommandError, cmd, reply)


@pytest.mark.parametrize("value", [9, 11, 0, 0x7F])
def test_write_value_not_echoed(value: int) -> None:
    expect(ReplyValueError, WriteParam(2, Param.TEMPERATURE, 10), bytes((0x42, 4, value)))


@pytest.mark.parametrize(
    ("cmd", "reply"),
    [
        (Position(1, 7500, baudrate=115200), h("01 BA 4C")),
        (Position(1, 7500, baudrate=115200), h("01 3A CC")),
        (Position(0, 7500, baudrate=115200), h("80 80 00")),
        (ReadParam(1, Param.STRETCH), h("21 01 9E")),
        (WriteParam(2, Param.TEMPERATURE, 10), h("42 04 8A")),
    ],
)
def test_msb_set_in_data(cmd: Command[Any], reply: bytes) -> None:
    expect(ReplyDataError, cmd, reply)


@pytest.mark.parametrize("index", [0, 1, 14, 30, 63])
def test_non_nibble_eeprom_byte(index: int) -> None:
    image = bytearray(EEPROM.to_bytes())
    image[index] = 0x10
    exc = expect(ReplyDataError, ReadEeprom(1), h("21 00") + image)
    assert isinstance(exc.__cause__, MalformedEeprom)


UNKNOWN_CODES = [(0, b"\x05\x0b", "header"), (0, b"\x00\x00", "header"), (26, b"\x00\x05", "baud_rate")]


@pytest.mark.parametrize(("offset", "nibbles", "field"), UNKNOWN_CODES)
def test_read_eeprom_keeps_an_unknown_header_or_baud_code(offset: int, nibbles: bytes, field: str) -> None:
    image = bytearray(EEPROM.to_bytes())
    image[offset : offset + 2] = nibbles
    eeprom = ReadEeprom(1).parse(h("21 00") + image)
    assert eeprom.to_bytes() == image
    assert eeprom.unknown_codes == {field: (nibbles[0] << 4) | nibbles[1]}
    assert ReadEeprom(1).encode_reply(eeprom) == h("21 00") + image


@pytest.mark.parametrize(("offset", "nibbles", "field"), UNKNOWN_CODES)
def test_write_eeprom_refuses_an_unknown_header_or_baud_code(offset: int, nibbles: bytes, field: str) -> None:
    image = bytearray(EEPROM.to_bytes())
    image[offset : offset + 2] = nibbles
    eeprom = Eeprom.from_bytes(image)
    with pytest.raises(InvalidArgument, match="reference does not define"):
        WriteEeprom(1, eeprom)
    if field == "baud_rate":
        assert WriteEeprom(1, eeprom.replace(baud_rate=115200)).tx == h("C1 00") + EEPROM.to_bytes()


@pytest.mark.parametrize("index", range(4, 20, 5))
@pytest.mark.parametrize("value", [0x10, 0x7F, 0x80, 0xFF])
def test_non_nibble_memory_byte(index: int, value: int) -> None:
    reply = bytearray(h("21 7F 00 08") + bytes(16))
    reply[index] = value
    expect(ReplyDataError, ReadMemory(1, 0, 8), bytes(reply))


def test_reply_error_message_names_command_id_and_bytes() -> None:
    exc = expect(ReplyHeaderError, ReadParam(5, Param.SPEED), h("26 02 10"))
    assert "read_speed to ID 5" in str(exc) and "26 02 10" in str(exc)
    exc = expect(ReplyLengthError, ReadId(), b"")
    assert str(exc).startswith("read_id:") and "nothing" in str(exc)


# --- random input never escapes the typed errors ---


@st.composite
def commands(draw: st.DrawFn) -> Command[Any]:
    sid = st.integers(0, 31)
    kind = draw(st.integers(0, 8))
    if kind == 0:
        return Position(draw(sid), draw(st.integers(0, 16383)), baudrate=draw(st.sampled_from(BAUDS)))
    if kind == 1:
        return ReadParam(draw(sid), draw(st.integers(1, 4)))
    if kind == 2:
        return ReadEeprom(draw(sid))
    if kind == 3:
        param = draw(st.sampled_from(list(Param)[1:]))
        return WriteParam(draw(sid), param, draw(st.integers(1, 63 if param is Param.CURRENT else 127)))
    if kind == 4:  # any image a servo may hold, written back as read
        image = draw(eeproms())
        return WriteEeprom(draw(sid), image, current=image)
    if kind == 5:
        return ReadId(draw(sid))
    if kind == 6:
        return WriteId(draw(sid))
    address, count = draw(memory_spans())
    if kind == 7:
        return ReadMemory(draw(sid), address, count)
    return WriteMemory(draw(sid), address, draw(st.binary(min_size=count, max_size=count)))


@st.composite
def memory_spans(draw: st.DrawFn, addresses: st.SearchStrategy[int] | None = None) -> tuple[int, int]:
    """An (address, count) the generic commands accept: count 1..127 and inside the 128-byte memory."""
    address = draw(addresses if addresses is not None else st.integers(0, 127))
    return address, draw(st.integers(1, min(127, 128 - address)))


@given(memory_spans(st.just(0)) | memory_spans())
def test_memory_span_strategy_draws_only_valid_spans(span: tuple[int, int]) -> None:
    # Address 0 is where a count of 128 (one past the codec's limit) would come from.
    address, count = span
    assert ReadMemory(1, address, count).count == count


@st.composite
def eeproms(draw: st.DrawFn) -> Eeprom:
    image = bytearray(draw(st.lists(st.integers(0, 15), min_size=64, max_size=64)))
    image[0:2] = b"\x05\x0a"
    image[26:28] = (0, draw(st.sampled_from([10, 1, 0])))
    return Eeprom.from_bytes(bytes(image))


@st.composite
def replies_for(draw: st.DrawFn, cmd: Command[Any]) -> bytes:
    """Random bytes, often of the right length or one byte off a well-formed reply."""
    how = draw(st.integers(0, 2))
    if how == 0:
        return draw(st.binary(max_size=80))
    if how == 1:
        return draw(st.binary(min_size=cmd.reply_len, max_size=cmd.reply_len))
    good = bytearray(_well_formed_reply(cmd, draw))
    index = draw(st.integers(0, len(good) - 1))
    good[index] = draw(st.integers(0, 255))
    return bytes(good)


def _well_formed_reply(cmd: Command[Any], draw: Callable[[st.SearchStrategy[Any]], Any]) -> bytes:
    if isinstance(cmd, Position):
        return cmd.encode_reply(draw(st.integers(0, 16383)))
    if isinstance(cmd, ReadParam):
        return cmd.encode_reply(draw(st.integers(0, 127)))
    if isinstance(cmd, ReadEeprom):
        return cmd.encode_reply(draw(eeproms()))
    if isinstance(cmd, WriteParam):
        return cmd.encode_reply(cmd.value)
    if isinstance(cmd, ReadId):
        return cmd.encode_reply(draw(st.integers(0, 31)))
    if isinstance(cmd, WriteId):
        return cmd.encode_reply(cmd.new_id)
    if isinstance(cmd, ReadMemory):
        return cmd.encode_reply(draw(st.binary(min_size=cmd.count, max_size=cmd.count)))
    return cmd.encode_reply(None)  # WriteEeprom, WriteMemory


@settings(max_examples=400)
@given(st.data())
def test_random_replies_raise_only_typed_errors(data: st.DataObject) -> None:
    cmd = data.draw(commands())
    reply = data.draw(replies_for(cmd))
    try:
        cmd.parse(reply)
    except BadReply as exc:
        assert exc.raw == reply and exc.command == cmd.name and exc.servo_id == cmd.servo_id


@settings(max_examples=300)
@given(st.data())
def test_every_command_parses_its_own_encoded_reply(data: st.DataObject) -> None:
    cmd = data.draw(commands())
    reply = _well_formed_reply(cmd, data.draw)
    assert len(reply) == cmd.reply_len
    value = cmd.parse(reply)
    if value is not None:
        assert cmd.encode_reply(value) == reply


# --- decode_request: the device side ---


@settings(max_examples=300)
@given(commands(), st.binary(max_size=8))
def test_decode_request_round_trip(cmd: Command[Any], trailing: bytes) -> None:
    baud = cmd.baudrate if isinstance(cmd, Position) else 115200
    for buf in (cmd.tx, cmd.tx + trailing, bytearray(cmd.tx)):
        decoded = decode_request(buf, baudrate=baud)
        assert decoded is not None
        found, consumed = decoded
        assert consumed == len(cmd.tx)
        assert found is not None
        assert state(found) == state(cmd)
    # Every strict prefix asks for more bytes.
    for end in range(len(cmd.tx)):
        assert decode_request(cmd.tx[:end], baudrate=baud) is None


@st.composite
def request_buffers(draw: st.DrawFn) -> bytes:
    """Random bytes, plausible frames with random bodies, and real frames with one byte changed."""
    how = draw(st.integers(0, 2))
    if how == 0:
        return draw(st.binary(max_size=90))
    if how == 1:
        first = draw(st.integers(0x80, 0xFF))
        sc = draw(st.sampled_from([0, 1, 2, 3, 4, 5, 0x7F, 0x80]))
        body = draw(st.lists(st.one_of(st.integers(0, 0x0F), st.integers(0, 0xFF)), max_size=70))
        return bytes((first, sc, *body))
    frame = bytearray(draw(commands()).tx)
    index = draw(st.integers(0, len(frame) - 1))
    frame[index] = draw(st.integers(0, 255))
    return bytes(frame[: draw(st.integers(1, len(frame)))])


@settings(max_examples=500)
@given(request_buffers(), st.sampled_from(BAUDS), st.binary(min_size=1, max_size=4))
def test_decode_request_on_random_buffers(buf: bytes, baud: int, more: bytes) -> None:
    decoded = decode_request(buf, baudrate=baud)
    if not buf:
        assert decoded is None
        return
    if decoded is None:
        assert buf[0] & 0x80, "only a started command waits for more"
        # A byte with the MSB set starts a new command, so the wait always ends.
        assert decode_request(buf + b"\x80", baudrate=baud) is not None
        return
    found, consumed = decoded
    assert 1 <= consumed <= len(buf)
    if found is not None:
        assert found.tx == buf[:consumed]
    # The decision depends only on the frame's own bytes.
    assert _summary(decode_request(buf + more, baudrate=baud)) == _summary(decoded)


def _summary(decoded: tuple[Command[Any] | None, int] | None) -> object:
    if decoded is None:
        return None
    found, consumed = decoded
    return (None if found is None else state(found)), consumed


@pytest.mark.parametrize(
    ("buf", "expected"),
    [
        ("", None),
        ("00", (None, 1)),  # a stray data byte
        ("7F 81 3A 4C", (None, 1)),
        ("81", None),
        ("81 3A", None),
        ("81 BA 4C", (None, 1)),  # MSB in a data byte: resynchronise on it
        ("81 3A CC", (None, 1)),
        ("81 A1", (None, 1)),
        ("A1", None),
        ("A1 81", (None, 1)),
        ("A1 06", (None, 2)),  # unknown SC (05 is ICS 3.6's position read)
        ("A1 7E", (None, 2)),
        ("C1 05 00", (None, 2)),
        ("F4", None),
        ("F4 01 01", None),
        ("F4 01 81", (None, 1)),
        ("F4 01 00 01", (None, 4)),  # neither read nor write
        ("F4 00 00 01", (None, 4)),
        ("F4 00 01 01", (None, 4)),
        ("A1 7F 00", None),
        ("A1 7F 80", (None, 1)),
        ("A1 7F 00 00", (None, 4)),  # count 0
        ("A1 7F 7F 02", (None, 4)),  # runs past the memory
        ("C1 7F 00 00", (None, 4)),
        ("C1 7F 00 02 01 02 0A", None),
        ("C1 7F 00 02 01 82", (None, 1)),
        ("C1 7F 00 02 01 02 10 0B", (None, 8)),  # not a nibble
        ("C1 00 05 0A", None),
        ("C1 00 05 8A", (None, 1)),
        ("C1 04", None),
        ("C1 04 8A", (None, 1)),
        ("C1 04 00", (None, 3)),  # out of range: 0
        ("C1 03 40", (None, 3)),  # current limit 64
    ],
)
def test_decode_request_cases(buf: str, expected: tuple[None, int] | None) -> None:
    assert decode_request(h(buf), baudrate=115200) == expected


def test_decode_request_rejects_a_malformed_eeprom_write() -> None:
    image = bytearray(EEPROM.to_bytes())
    image[0:2] = b"\x05\x0b"
    assert decode_request(h("C1 00") + image + h("81 3A 4C"), baudrate=115200) == (None, 66)
    assert decode_request(h("C1 00") + EEPROM.to_bytes()[:63] + h("81 3A 4C"), baudrate=115200) == (None, 1)


def test_decode_request_examples() -> None:
    found, consumed = decode_request(h("C2 04 0A 81"), baudrate=625000) or (None, 0)
    assert isinstance(found, WriteParam) and (found.servo_id, found.param, found.value, consumed) == (2, 4, 10, 3)
    found, consumed = decode_request(h("FF 00 00 00"), baudrate=115200) or (None, 0)
    assert isinstance(found, ReadId) and consumed == 4 and found.encode_reply(20) == h("F4")
    found, consumed = decode_request(h("80 3A 4C"), baudrate=115200) or (None, 0)
    assert isinstance(found, Position) and found.encode_reply(7500) == h("80 3A 4C")
    found, consumed = decode_request(h("80 3A 4C"), baudrate=1250000) or (None, 0)
    assert isinstance(found, Position) and found.encode_reply(7500) == h("00 3A 4C")
    found, consumed = decode_request(bytearray(h("A1 7F 00 08")), baudrate=115200) or (None, 0)
    assert isinstance(found, ReadMemory) and (found.address, found.count, consumed) == (0, 8, 4)


@pytest.mark.parametrize("baud", [9600, None, True, "slow"])
def test_decode_request_rejects_a_bad_baud_rate(baud: object) -> None:
    with pytest.raises(InvalidArgument, match="baud"):
        decode_request(b"", baudrate=baud)  # type: ignore[arg-type]
    with pytest.raises(InvalidArgument, match="baud"):
        decode_request(h("A1 01"), baudrate=baud)  # type: ignore[arg-type]


# --- the base class ---


def test_base_command_is_abstract_and_repr() -> None:
    base: Command[int] = Command()
    with pytest.raises(NotImplementedError):
        base.parse(b"")
    with pytest.raises(NotImplementedError):
        base.encode_reply(0)
    assert repr(Position(1, 7500, baudrate=115200)) == "<Position position id=1 tx=81 3a 4c>"
    assert repr(ReadId()) == "<ReadId read_id id=None tx=ff 00 00 00>"


def test_baud_rate_enum_values_match_the_line() -> None:
    assert [int(b) for b in BaudRate] == BAUDS
    assert int(Flags.PWMINH) == 0x08  # the flag serial users must set (section 1)


def test_all_errors_are_ics_errors() -> None:
    for error in (ReplyLengthError, ReplyHeaderError, ReplySubcommandError, ReplyValueError, ReplyDataError):
        assert issubclass(error, BadReply) and issubclass(error, IcsError)


def test_guard_read_differs_in_reply_shape_from_the_command_it_guards() -> None:
    stretch = protocol.ReadParam(4, protocol.Param.STRETCH)
    assert protocol.guard_read(stretch.tx, 4).tx == bytes.fromhex("a4 02")  # speed, not stretch again
    for command in (
        protocol.Position(4, 7500, baudrate=115200),
        protocol.ReadParam(4, protocol.Param.SPEED),
        protocol.ReadEeprom(4),
    ):
        guard = protocol.guard_read(command.tx, 4)
        assert guard.tx == bytes.fromhex("a4 01")
        late = command.encode_reply(command.parse(command.encode_reply(_sample_value(command))))
        with pytest.raises(BadReply):  # the late reply never passes as the guard's answer
            guard.parse(late)


def test_guard_read_is_not_one_of_the_commands_whose_answer_may_still_come() -> None:
    # A guard identical to a command sent whose echo never came back would take that command's late answer for its
    # own (the engine then took the bytes after it for the next command's).
    position, stretch, speed = (
        protocol.Position(4, 7500, baudrate=115200).tx,
        bytes.fromhex("a4 01"),
        bytes.fromhex("a4 02"),
    )
    assert protocol.guard_read(position, 4, [stretch]).tx == speed
    # Both of them: a twin of the last one sent (taking its echo and reply shows that every older one's came first).
    assert protocol.guard_read(position, 4, [stretch, speed]).tx == speed
    assert protocol.guard_read(position, 4, [speed, stretch]).tx == stretch
    assert protocol.guard_read(stretch, 4, [speed]).tx == speed  # (the last; no other but stretch itself)
    # Otherwise a read of another servo (its header fails a late reply from this one): one the line talked to first.
    assert protocol.guard_read(stretch, 4, [speed, stretch]).tx == bytes.fromhex("a0 01")  # (never its own shape)
    seven = bytes.fromhex("a7 01")
    assert protocol.guard_read(position, 4, [seven, stretch, speed, position]).tx == bytes.fromhex("a7 02")
    # However many are remembered (the engine keeps 32), one is free.
    others = [bytes((0xA0 | i, p)) for i in range(32) if i != 4 for p in (1, 2)][:29]
    guard = protocol.guard_read(position, 4, [*others, stretch, speed, position]).tx
    assert guard not in others and guard[0] & 0x1F != 4


def _sample_value(command: protocol.Command[Any]) -> Any:
    if isinstance(command, protocol.ReadEeprom):
        return Eeprom.factory(4)
    return 30


# --- the package's import surface ---

# What the sans-IO engine, the bus, the simulator and the CLI import: the split into modules must not move them.
PUBLIC_NAMES = [
    "Command",
    "Timing",
    "wire_time",
    "guard_read",
    "position_tx",
    "position_reply_header",
    "position_from_reply",
    "Position",
    "ReadParam",
    "ReadEeprom",
    "WriteParam",
    "WriteEeprom",
    "ReadId",
    "WriteId",
    "ReadMemory",
    "WriteMemory",
    "check_baud",
    "check_id",
    "Param",
    "FREE",
    "POSITION_MAX",
    "MAX_ID",
    "MEMORY_SIZE",
    "BITS_PER_BYTE",
    "CMD_POSITION",
    "CMD_READ",
    "CMD_WRITE",
    "CMD_ID",
    "SC_MEMORY",
    "WRITE_RANGES",
    "decode_request",
    "join7",
    "split7",
    "nibbles_from_bytes",
    "bytes_from_nibbles",
    "BaudRate",
    "Eeprom",
    "EEPROM_SIZE",
]


@pytest.mark.parametrize("name", PUBLIC_NAMES)
def test_package_exports_every_name(name: str) -> None:
    assert name in protocol.__all__
    assert getattr(protocol, name) is not None


def test_command_interface_the_engine_uses() -> None:
    cmd: Command[Any] = ReadParam(3, Param.SPEED)
    assert (cmd.tx, cmd.reply_len, cmd.echo_len, cmd.servo_id) == (h("A3 02"), 3, 2, 3)
    assert (cmd.timing, cmd.idempotent, cmd.name) == (Timing.NORMAL, True, "read_speed")
    assert cmd.parse(h("23 02 1E")) == 30


def test_ids_are_named_in_the_singular_for_one_and_read_once_from_an_iterator() -> None:
    from ics35_async.protocol.wire import ids_named, no_servo_among

    assert ids_named(iter([3])) == "ID 3" and ids_named(i for i in (1, 2, 5)) == "IDs 1, 2, 5"
    assert ids_named(range(4, 32)) == "IDs 4-31"
    assert no_servo_among(iter([1])) == "no servo at ID 1" and no_servo_among(iter([1, 2])) == "no servo among 1, 2"
