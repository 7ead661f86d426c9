"""The 64-byte EEPROM image (spec sections 7 and 8): layout, round trips, strict updates."""

from __future__ import annotations

import dataclasses
import itertools
import json
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ics35_async import open_bus
from ics35_async.cli import ExitCode, main
from ics35_async.eeprom import (
    EEPROM_FIELDS,
    EEPROM_SIZE,
    PROTECTED_OFFSETS,
    BaudRate,
    Eeprom,
    Flags,
)
from ics35_async.errors import InvalidArgument, MalformedEeprom, UnsafeOperation
from ics35_async.sim import VirtualLine, VirtualServo

# The spec's table (section 7), with its 1-based byte numbers, written out independently of the code.
SPEC_LAYOUT: dict[str, tuple[int, int]] = {
    "stretch_gain": (3, 4),
    "speed": (5, 6),
    "punch": (7, 8),
    "dead_band": (9, 10),
    "damping": (11, 12),
    "safe_timer": (13, 14),
    "flags": (15, 16),
    "pulse_limit_high": (17, 20),
    "pulse_limit_low": (21, 24),
    "baud_rate": (27, 28),
    "temperature_limit": (29, 30),
    "current_limit": (31, 32),
    "response": (51, 52),
    "user_offset": (53, 54),
    "servo_id": (57, 58),
    "stretch_1": (59, 60),
    "stretch_2": (61, 62),
    "stretch_3": (63, 64),
}
SPEC_CALIBRATION_BYTES = [*range(25, 27), *range(33, 51), *range(55, 57)]  # 1-based
SPEC_RANGES: dict[str, tuple[int, int]] = {
    "stretch_gain": (2, 254),
    "speed": (1, 127),
    "punch": (0, 10),
    "dead_band": (0, 5),
    "damping": (1, 255),
    "safe_timer": (10, 255),
    "pulse_limit_high": (3500, 11500),
    "pulse_limit_low": (3500, 11500),
    "temperature_limit": (1, 127),
    "current_limit": (1, 63),
    "response": (1, 5),
    "user_offset": (-127, 127),
    "servo_id": (0, 31),
    "stretch_1": (2, 254),
    "stretch_2": (2, 254),
    "stretch_3": (2, 254),
}
EVEN_FIELDS = {"stretch_gain", "stretch_1", "stretch_2", "stretch_3"}
CALIBRATION = bytes(i & 0x0F for i in range(22))

# Factory example image (section 7) with CALIBRATION in the protected bytes, nibble by nibble.
FACTORY_IMAGE = bytes.fromhex(
    "050a"  # 1-2 header 0x5A
    "030c"  # 3-4 stretch gain 60
    "070f"  # 5-6 speed 127
    "0001"  # 7-8 punch 1
    "0002"  # 9-10 dead band 2
    "0208"  # 11-12 damping 40
    "0f0a"  # 13-14 safe timer 250
    "0000"  # 15-16 flags 0
    "020c0e0c"  # 17-20 pulse limit high 11500 = 0x2CEC
    "000d0a0c"  # 21-24 pulse limit low 3500 = 0x0DAC
    "0001"  # 25-26 calibration
    "000a"  # 27-28 baud code 10 = 115200
    "0500"  # 29-30 temperature limit 80
    "030f"  # 31-32 current limit 63
    "02030405060708090a0b0c0d0e0f00010203"  # 33-50 calibration
    "0003"  # 51-52 response 3
    "0000"  # 53-54 user offset 0
    "0405"  # 55-56 calibration
    "0000"  # 57-58 ID 0
    "0708"  # 59-60 stretch 1 = 120
    "030c"  # 61-62 stretch 2 = 60
    "0f0e"  # 63-64 stretch 3 = 254
)

nibble_lists = st.lists(st.integers(0, 15), min_size=22, max_size=22).map(bytes)
even_stretch = st.integers(1, 127).map(lambda v: 2 * v)


def _field(name: str) -> st.SearchStrategy[int]:
    low, high = SPEC_RANGES[name]
    return even_stretch if name in EVEN_FIELDS else st.integers(low, high)


@st.composite
def valid_eeproms(draw: st.DrawFn) -> Eeprom:
    """An Eeprom built field by field from the spec's ranges."""
    values: dict[str, Any] = {name: draw(_field(name)) for name in SPEC_RANGES}
    low, high = sorted((values["pulse_limit_low"], values["pulse_limit_high"]))
    values["pulse_limit_low"], values["pulse_limit_high"] = low, high
    values["flags"] = Flags(draw(st.integers(0, 0xFF)) & ~0x60)
    values["baud_rate"] = draw(st.sampled_from(list(BaudRate)))
    values["calibration"] = draw(nibble_lists)
    return Eeprom(**values)


@st.composite
def nibble_images(draw: st.DrawFn) -> bytes:
    """Any 64 nibbles with the fixed header and a known baud code."""
    image = bytearray(draw(st.lists(st.integers(0, 15), min_size=64, max_size=64)))
    image[0:2] = b"\x05\x0a"
    image[26:28] = (0, draw(st.sampled_from([10, 1, 0])))
    return bytes(image)


def _image_with(offset: int, nibbles: bytes) -> bytes:
    image = bytearray(FACTORY_IMAGE)
    image[offset : offset + len(nibbles)] = nibbles
    return bytes(image)


# --- layout and the factory example ---


def test_layout_matches_the_spec_table() -> None:
    assert EEPROM_SIZE == 64
    assert {name: (off + 1, off + n) for name, (off, n) in EEPROM_FIELDS.items()} == SPEC_LAYOUT
    assert sorted(i + 1 for i in PROTECTED_OFFSETS) == SPEC_CALIBRATION_BYTES
    covered = sorted([0, 1, *PROTECTED_OFFSETS, *(off + i for off, n in EEPROM_FIELDS.values() for i in range(n))])
    assert covered == list(range(64)), "every byte is header, a field or calibration, exactly once"


def test_factory_image_bytes() -> None:
    eeprom = Eeprom.factory(calibration=CALIBRATION)
    assert eeprom.to_bytes() == FACTORY_IMAGE
    assert eeprom.header == 0x5A
    assert eeprom.calibration == CALIBRATION


def test_factory_image_decodes_to_the_spec_values() -> None:
    eeprom = Eeprom.from_bytes(bytearray(FACTORY_IMAGE))
    assert eeprom == Eeprom.factory(calibration=CALIBRATION)
    assert (eeprom.stretch_gain, eeprom.speed, eeprom.punch, eeprom.dead_band) == (60, 127, 1, 2)
    assert (eeprom.damping, eeprom.safe_timer, eeprom.flags) == (40, 250, Flags(0))
    assert (eeprom.pulse_limit_high, eeprom.pulse_limit_low) == (11500, 3500)
    assert eeprom.baud_rate is BaudRate.B115200
    assert (eeprom.temperature_limit, eeprom.current_limit, eeprom.response) == (80, 63, 3)
    assert (eeprom.user_offset, eeprom.servo_id) == (0, 0)
    assert (eeprom.stretch_1, eeprom.stretch_2, eeprom.stretch_3) == (120, 60, 254)


def test_factory_options() -> None:
    a = Eeprom.factory(7, baud_rate=BaudRate.B1250000)
    assert a.servo_id == 7 and a.baud_rate is BaudRate.B1250000
    assert a.to_bytes()[56:58] == b"\x00\x07"
    assert a.to_bytes()[26:28] == b"\x00\x00"
    assert Eeprom.factory(1).calibration != Eeprom.factory(2).calibration
    assert Eeprom.factory(baud_rate="625000").baud_rate is BaudRate.B625000  # type: ignore[arg-type]


@pytest.mark.parametrize("servo_id", [-1, 32, True, 1.0, "1"])
def test_factory_rejects_bad_ids(servo_id: object) -> None:
    with pytest.raises(InvalidArgument):
        Eeprom.factory(servo_id)  # type: ignore[arg-type]


@pytest.mark.parametrize("calibration", [bytes(21), bytes(23), bytes([0x10]) + bytes(21)])
def test_calibration_must_be_22_nibbles(calibration: bytes) -> None:
    with pytest.raises(MalformedEeprom, match="calibration"):
        Eeprom.factory(calibration=calibration)


@pytest.mark.parametrize(("baud", "code"), [(BaudRate.B115200, 10), (BaudRate.B625000, 1), (BaudRate.B1250000, 0)])
def test_baud_codes(baud: BaudRate, code: int) -> None:
    assert baud.eeprom_code == code
    assert BaudRate.from_eeprom_code(code) is baud
    image = _image_with(26, bytes((code >> 4, code & 0x0F)))
    assert Eeprom.from_bytes(image).baud_rate is baud


@pytest.mark.parametrize(
    ("value", "nibbles"),
    [(0, b"\x00\x00"), (1, b"\x00\x01"), (-1, b"\x0f\x0f"), (127, b"\x07\x0f"), (-127, b"\x08\x01")],
)
def test_user_offset_is_twos_complement(value: int, nibbles: bytes) -> None:
    eeprom = Eeprom.factory(calibration=CALIBRATION).replace(user_offset=value)
    assert eeprom.to_bytes()[52:54] == nibbles
    assert Eeprom.from_bytes(eeprom.to_bytes()).user_offset == value


def test_flag_bits() -> None:
    assert [int(f) for f in (Flags.REVERSE, Flags.FREE, Flags.PCM, Flags.PWMINH, Flags.ROTATION, Flags.SLAVE)] == [
        1,
        2,
        4,
        8,
        16,
        128,
    ]
    eeprom = Eeprom.from_bytes(_image_with(14, b"\x08\x09"))  # 0x89: slave, PWMINH, reverse
    assert eeprom.flags == Flags.SLAVE | Flags.PWMINH | Flags.REVERSE
    assert eeprom.to_dict()["flags_names"] == ["REVERSE", "PWMINH", "SLAVE"]


# --- round trips ---


@settings(max_examples=150)
@given(valid_eeproms())
def test_fields_to_bytes_to_fields(eeprom: Eeprom) -> None:
    image = eeprom.to_bytes()
    assert len(image) == 64
    assert all(b <= 0x0F for b in image)
    assert image[:2] == b"\x05\x0a"
    decoded = Eeprom.from_bytes(image)
    assert decoded == eeprom
    assert decoded.to_bytes() == image


@settings(max_examples=150)
@given(nibble_images())
def test_any_nibble_image_round_trips(image: bytes) -> None:
    # Decoding is lenient about ranges: a real servo's image comes back byte for byte.
    assert Eeprom.from_bytes(image).to_bytes() == image


# --- malformed images ---


@pytest.mark.parametrize("length", [0, 1, 63, 65, 66])
def test_wrong_length(length: int) -> None:
    with pytest.raises(MalformedEeprom, match="64 bytes"):
        Eeprom.from_bytes(FACTORY_IMAGE[:length] if length <= 64 else FACTORY_IMAGE + bytes(length - 64))


@settings(max_examples=100)
@given(st.integers(0, 63), st.integers(0x10, 0xFF))
def test_non_nibble_byte_anywhere(index: int, value: int) -> None:
    image = bytearray(FACTORY_IMAGE)
    image[index] = value
    with pytest.raises(MalformedEeprom, match=f"byte {index + 1} is"):
        Eeprom.from_bytes(bytes(image))


# --- codes the reference does not define: read and kept exactly, never written ---

UNKNOWN_BAUD_CODES = [0x1A, 0x0B, 2, 9, 11, 0xFF]
UNKNOWN_HEADERS = [0x5B, 0xA5, 0x00, 0xFF]


def _nibbles(value: int) -> bytes:
    return bytes((value >> 4, value & 0x0F))


@pytest.mark.parametrize("header", UNKNOWN_HEADERS)
def test_unknown_header_is_kept_and_flagged(header: int) -> None:
    image = _image_with(0, _nibbles(header))
    eeprom = Eeprom.from_bytes(image)
    assert eeprom.header == header
    assert eeprom.unknown_codes == {"header": header}
    assert eeprom.to_bytes() == image
    assert eeprom.to_dict()["unknown_codes"] == {"header": header}
    assert eeprom.baud_rate is BaudRate.B115200 and eeprom.speed == 127  # the rest decodes as usual


@pytest.mark.parametrize("code", UNKNOWN_BAUD_CODES)
def test_unknown_baud_code_is_kept_and_flagged(code: int) -> None:
    image = _image_with(26, _nibbles(code))
    eeprom = Eeprom.from_bytes(image)
    assert eeprom.baud_rate == code and not isinstance(eeprom.baud_rate, BaudRate)
    assert eeprom.baud_code == code
    assert eeprom.unknown_codes == {"baud_rate": code}
    assert eeprom.to_bytes() == image
    out = eeprom.to_dict()
    assert out["baud_rate"] == code and out["unknown_codes"] == {"baud_rate": code}
    assert bytes.fromhex(out["raw"]) == image
    with pytest.raises(MalformedEeprom):
        BaudRate.from_eeprom_code(code)  # the enum itself still knows only the three rates


def test_defined_codes_are_not_flagged() -> None:
    for baud in BaudRate:
        eeprom = Eeprom.factory(baud_rate=baud)
        assert eeprom.unknown_codes == {} and eeprom.baud_code == baud.eeprom_code
        assert eeprom.to_dict()["unknown_codes"] == {}
        eeprom.check_writable()


def test_replace_keeps_unknown_codes_and_can_set_a_defined_rate() -> None:
    eeprom = Eeprom.from_bytes(_image_with(0, _nibbles(0x5B) + FACTORY_IMAGE[2:26] + _nibbles(0x1A)))
    assert eeprom.unknown_codes == {"header": 0x5B, "baud_rate": 0x1A}
    slower = eeprom.replace(speed=10)
    assert slower.unknown_codes == eeprom.unknown_codes and slower.speed == 10
    assert slower.to_bytes()[:2] == b"\x05\x0b" and slower.to_bytes()[26:28] == b"\x01\x0a"
    fixed = eeprom.replace(baud_rate=115200)
    assert fixed.baud_rate is BaudRate.B115200 and fixed.unknown_codes == {"header": 0x5B}
    assert eeprom.diff(fixed) == {"baud_rate": (0x1A, BaudRate.B115200)}


@pytest.mark.parametrize(
    ("image", "match"),
    [
        (_image_with(26, _nibbles(0x1A)), "baud-rate code 0x1A"),
        (_image_with(0, _nibbles(0x5B)), "header 0x5B"),
    ],
    ids=["baud", "header"],
)
def test_check_writable_refuses_unknown_codes(image: bytes, match: str) -> None:
    with pytest.raises(InvalidArgument, match=match):
        Eeprom.from_bytes(image).check_writable()


def test_constructor_takes_a_baud_rate_or_a_raw_code() -> None:
    base = Eeprom.factory(calibration=CALIBRATION).__dict__
    assert Eeprom(**{**base, "baud_rate": 625000}).baud_rate is BaudRate.B625000
    assert Eeprom(**{**base, "baud_rate": 1}).baud_rate is BaudRate.B625000  # code 1
    assert Eeprom(**{**base, "baud_rate": 0x1A}).unknown_codes == {"baud_rate": 0x1A}
    for bad in (-1, 256, 9600, True, "115200", None):
        with pytest.raises(MalformedEeprom, match="baud"):
            Eeprom(**{**base, "baud_rate": bad})
    for bad in (-1, 256, True, None):
        with pytest.raises(MalformedEeprom, match="header"):
            Eeprom(**{**base, "header": bad})


@settings(max_examples=150)
@given(st.lists(st.integers(0, 15), min_size=64, max_size=64).map(bytes))
def test_every_nibble_image_reads_and_round_trips(image: bytes) -> None:
    # Whatever 64 nibbles a servo returns, they are read and written out byte for byte.
    eeprom = Eeprom.from_bytes(image)
    assert eeprom.to_bytes() == image
    assert Eeprom.from_bytes(eeprom.to_bytes()) == eeprom
    assert set(eeprom.unknown_codes) <= {"header", "baud_rate"}


def test_malformed_eeprom_is_a_value_error() -> None:
    assert issubclass(MalformedEeprom, ValueError)


# --- BaudRate.parse ---


def test_baud_parse_accepts_ints_and_strings() -> None:
    assert BaudRate.parse(115200) is BaudRate.B115200
    assert BaudRate.parse("625000") is BaudRate.B625000
    assert BaudRate.parse(BaudRate.B1250000) is BaudRate.B1250000


@pytest.mark.parametrize("value", [9600, 0, 1, 10, True, 115200.0, 115200.7, "fast", None, b"115200"])
def test_baud_parse_rejects(value: object) -> None:
    with pytest.raises(InvalidArgument, match="baud rate"):
        BaudRate.parse(value)


# --- replace(): strict about every change ---

FACTORY = Eeprom.factory(3, calibration=CALIBRATION)


@pytest.mark.parametrize("name", sorted(SPEC_RANGES))
def test_replace_accepts_each_fields_bounds(name: str) -> None:
    low, high = SPEC_RANGES[name]
    base = FACTORY
    if name == "pulse_limit_high":
        base = FACTORY.replace(pulse_limit_low=3500)
    if name == "pulse_limit_low":
        base = FACTORY.replace(pulse_limit_high=11500)
    for value in (low, high):
        updated = base.replace(**{name: value})
        assert getattr(updated, name) == value
        assert Eeprom.from_bytes(updated.to_bytes()) == updated
        assert updated.diff(base) == ({} if getattr(base, name) == value else {name: (value, getattr(base, name))})


@pytest.mark.parametrize("name", sorted(SPEC_RANGES))
def test_replace_rejects_each_fields_out_of_range_and_wrong_types(name: str) -> None:
    low, high = SPEC_RANGES[name]
    for value in (low - 1, high + 1, True, float(low), str(low), None):
        with pytest.raises(InvalidArgument):
            FACTORY.replace(**{name: value})


@pytest.mark.parametrize("name", sorted(EVEN_FIELDS))
@pytest.mark.parametrize("value", [3, 61, 253])
def test_replace_rejects_odd_stretch(name: str, value: int) -> None:
    with pytest.raises(InvalidArgument, match="even"):
        FACTORY.replace(**{name: value})


def test_replace_rejects_low_above_high() -> None:
    with pytest.raises(InvalidArgument, match="must not exceed"):
        FACTORY.replace(pulse_limit_low=8000, pulse_limit_high=7999)
    narrow = FACTORY.replace(pulse_limit_low=7000, pulse_limit_high=8000)
    with pytest.raises(InvalidArgument, match="must not exceed"):
        narrow.replace(pulse_limit_low=8001)
    with pytest.raises(InvalidArgument, match="must not exceed"):
        narrow.replace(pulse_limit_high=6999)
    assert narrow.replace(pulse_limit_low=8000).pulse_limit_low == 8000


def test_crossed_limits_read_from_a_servo_do_not_block_other_changes() -> None:
    crossed = Eeprom.from_bytes(_image_with(16, bytes.fromhex("000d0a0c020c0e0c")))  # high 3500, low 11500
    assert (crossed.pulse_limit_high, crossed.pulse_limit_low) == (3500, 11500)
    assert crossed.replace(speed=10).speed == 10
    with pytest.raises(InvalidArgument, match="must not exceed"):
        crossed.replace(pulse_limit_high=4000)
    fixed = crossed.replace(pulse_limit_high=11500, pulse_limit_low=3500)
    assert (fixed.pulse_limit_high, fixed.pulse_limit_low) == (11500, 3500)


def test_replace_baud_rate() -> None:
    assert FACTORY.replace(baud_rate=1250000).baud_rate is BaudRate.B1250000
    assert FACTORY.replace(baud_rate="625000").baud_rate is BaudRate.B625000
    for bad in (9600, 1, True, 115200.0, None):
        with pytest.raises(InvalidArgument):
            FACTORY.replace(baud_rate=bad)


def test_replace_flags() -> None:
    updated = FACTORY.replace(flags=Flags.PWMINH | Flags.REVERSE | Flags.ROTATION | Flags.SLAVE)
    assert updated.flags == Flags.PWMINH | Flags.REVERSE | Flags.ROTATION | Flags.SLAVE
    assert isinstance(updated.flags, Flags)
    assert FACTORY.replace(flags=0x08).flags == Flags.PWMINH


@pytest.mark.parametrize("bits", [0x20, 0x40, 0x60, 0x28])
def test_replace_flags_rejects_unused_bits(bits: int) -> None:
    with pytest.raises(InvalidArgument, match="unused"):
        FACTORY.replace(flags=bits)


def test_unused_flag_bits_the_image_has_stay_when_another_flag_changes() -> None:
    # A servo (or a hand-made image) may have bits 5-6 set: a change to another flag keeps them as read,
    # clearing them is allowed (the reference fixes them at 0), setting one is refused.
    reported = Eeprom.from_bytes(_image_with(14, b"\x02\x08"))  # 0x28: bit 5 and PWMINH
    assert int(reported.replace(flags=reported.flags | Flags.REVERSE).flags) == 0x29
    assert reported.replace(flags=Flags.PWMINH).flags == Flags.PWMINH
    with pytest.raises(InvalidArgument, match="unused"):
        reported.replace(flags=reported.flags | 0x40)


@pytest.mark.parametrize("value", [True, 8.0, "8", None, -1, 0x100])
def test_replace_flags_rejects_wrong_types_and_ranges(value: object) -> None:
    with pytest.raises(InvalidArgument):
        FACTORY.replace(flags=value)


def test_free_and_pcm_flags_are_read_only() -> None:
    with pytest.raises(InvalidArgument, match="read-only"):
        FACTORY.replace(flags=Flags.FREE)
    with pytest.raises(InvalidArgument, match="read-only"):
        FACTORY.replace(flags=Flags.PCM | Flags.PWMINH)
    # A servo reporting FREE|PCM: other flags may change, those two must stay as read.
    reported = Eeprom.from_bytes(_image_with(14, b"\x00\x06"))
    assert reported.flags == Flags.FREE | Flags.PCM
    kept = reported.replace(flags=Flags.FREE | Flags.PCM | Flags.PWMINH)
    assert kept.flags == Flags.FREE | Flags.PCM | Flags.PWMINH
    for dropped in (Flags.PWMINH, Flags.FREE | Flags.PWMINH, Flags.PCM):
        with pytest.raises(InvalidArgument, match="read-only"):
            reported.replace(flags=dropped)


def test_calibration_change_refused() -> None:
    with pytest.raises(UnsafeOperation, match="calibration"):
        FACTORY.replace(calibration=bytes(22))
    with pytest.raises(UnsafeOperation):
        FACTORY.replace(calibration=FACTORY.calibration)
    assert issubclass(UnsafeOperation, InvalidArgument)


def test_unknown_field_refused() -> None:
    with pytest.raises(InvalidArgument, match="unknown EEPROM field"):
        FACTORY.replace(header=0x5A)
    with pytest.raises(InvalidArgument, match="unknown EEPROM field"):
        FACTORY.replace(speed=10, colour="red")
    with pytest.raises(InvalidArgument, match=r"strech_gain \(did you mean stretch_gain\?\)"):
        FACTORY.replace(strech_gain=50)


def test_replace_with_nothing_is_equal() -> None:
    assert FACTORY.replace() == FACTORY


@settings(max_examples=150)
@given(nibble_images(), st.data())
def test_replace_never_touches_protected_bytes(image: bytes, data: st.DataObject) -> None:
    eeprom = Eeprom.from_bytes(image)
    name = data.draw(st.sampled_from(sorted(n for n in SPEC_RANGES if not n.startswith("pulse"))))
    value = data.draw(_field(name))
    updated = eeprom.replace(**{name: value})
    new_image = updated.to_bytes()
    assert all(new_image[i] == image[i] for i in PROTECTED_OFFSETS)
    assert set(updated.diff(eeprom)) <= {name}
    offset, nibbles = EEPROM_FIELDS[name]
    changed = {i for i in range(64) if new_image[i] != image[i]}
    assert changed <= set(range(offset, offset + nibbles))


# --- diff and to_dict ---


def test_diff() -> None:
    other = FACTORY.replace(speed=50, servo_id=4)
    assert FACTORY.diff(other) == {"speed": (127, 50), "servo_id": (3, 4)}
    assert FACTORY.diff(FACTORY) == {}


def test_to_dict() -> None:
    eeprom = FACTORY.replace(flags=Flags.PWMINH, user_offset=-5, baud_rate=625000)
    out = eeprom.to_dict()
    assert set(out) == {*SPEC_LAYOUT, "flags_names", "raw", "unknown_codes"}
    assert out["flags"] == 8 and out["flags_names"] == ["PWMINH"]
    assert out["baud_rate"] == 625000 and out["user_offset"] == -5 and out["servo_id"] == 3
    assert bytes.fromhex(out["raw"]) == eeprom.to_bytes()
    assert all(type(out[name]) is int for name in SPEC_LAYOUT)


# --- a servo holding an image with unknown codes: the bus, the simulator and the CLI ---

_lines = itertools.count()


def _servo_image(servo_id: int = 1, *, header: int = 0x5B, baud_code: int = 0x1A) -> bytes:
    image = bytearray(_image_with(56, _nibbles(servo_id)))
    image[0:2] = _nibbles(header)
    image[26:28] = _nibbles(baud_code)
    return bytes(image)


@pytest.fixture
def odd_servo() -> Iterator[tuple[VirtualLine, str, bytes]]:
    """A named in-process line with servo 1 holding an unknown header and baud code (it talks at 115200)."""
    image = _servo_image()
    sim = VirtualLine([VirtualServo(eeprom=Eeprom.from_bytes(image))], name=f"eeprom-odd-{next(_lines)}")
    yield sim, f"sim://{sim.name}", image
    sim.close()


def test_the_simulator_holds_an_image_with_unknown_codes() -> None:
    image = _servo_image(3, header=0x00, baud_code=0x0B)
    servo = VirtualServo(eeprom=Eeprom.from_bytes(image), baud_rate=625000)
    assert servo.eeprom.to_bytes() == image and servo.servo_id == 3
    assert servo.baud_rate is BaudRate.B625000  # the code names no rate: the servo talks at the one it was given
    servo.power_cycle()
    assert servo.baud_rate is BaudRate.B625000


async def test_the_bus_reads_such_a_servo_and_refuses_to_write_it(odd_servo: tuple[VirtualLine, str, bytes]) -> None:
    sim, _, image = odd_servo
    async with open_bus(sim) as bus:
        servo = bus.servo(1)
        eeprom = await servo.read_eeprom()
        assert eeprom.to_bytes() == image
        assert eeprom.unknown_codes == {"header": 0x5B, "baud_rate": 0x1A}
        before = sim.transactions
        with pytest.raises(InvalidArgument, match="reference does not define"):
            await servo.write_eeprom(eeprom.replace(speed=50))
        with pytest.raises(InvalidArgument, match="reference does not define"):
            await servo.write_eeprom(eeprom.replace(baud_rate=115200), allow_baud_change=True)  # the header stays
        assert sim.transactions == before  # refused before a byte went out
        assert sim.servo(1).eeprom_writes == 0 and sim.servo(1).eeprom.to_bytes() == image


class _Cli:
    def __init__(self, capsys: pytest.CaptureFixture[str]) -> None:
        self.capsys = capsys

    def __call__(self, *args: str) -> tuple[int, str, str]:
        self.capsys.readouterr()
        with pytest.raises(SystemExit) as exited:
            main(list(args))
        out, err = self.capsys.readouterr()
        assert "Traceback" not in err, err
        code = exited.value.code
        return (code if isinstance(code, int) else 1), out, err


def test_cli_info_and_dump_show_and_flag_unknown_codes(
    odd_servo: tuple[VirtualLine, str, bytes], capsys: pytest.CaptureFixture[str]
) -> None:
    _, url, image = odd_servo
    ics35 = _Cli(capsys)
    code, out, _ = ics35("--port", url, "info", "1", "--no-position")
    assert code == 0
    assert "0x1A" in out and "0x5B" in out and "unknown" in out
    code, out, _ = ics35("--port", url, "info", "1", "--json")
    assert code == 0 and json.loads(out)["eeprom"]["unknown_codes"] == {"header": 0x5B, "baud_rate": 0x1A}
    code, out, err = ics35("--port", url, "eeprom", "dump", "1")
    assert code == 0
    doc = json.loads(out)
    assert bytes.fromhex(doc["raw"]) == image  # the backup holds the image exactly
    assert doc["unknown_codes"] == {"header": 0x5B, "baud_rate": 0x1A}
    assert "unknown" in err
    code, out, _ = ics35("--port", url, "eeprom", "dump", "1", "--table")
    assert code == 0 and "0x1A" in out and "unknown" in out
    code, out, _ = ics35("--port", url, "scan", "--ids", "1", "--bauds", "115200", "--json")
    assert code == 0 and json.loads(out)["servos"][0]["eeprom"]["unknown_codes"]["baud_rate"] == 0x1A


def test_cli_refuses_to_write_an_image_with_unknown_codes(
    odd_servo: tuple[VirtualLine, str, bytes], capsys: pytest.CaptureFixture[str]
) -> None:
    sim, url, image = odd_servo
    code, _, err = _Cli(capsys)("--port", url, "eeprom", "set", "1", "speed=50", "--yes")
    assert code == ExitCode.USAGE and "reference does not define" in err and "nothing was written" in err
    assert sim.servo(1).eeprom_writes == 0 and sim.servo(1).eeprom.to_bytes() == image


@pytest.mark.parametrize("other", [5, None, b"\x00" * 64, {"speed": 1}])
def test_a_diff_with_what_is_not_an_eeprom_is_refused_in_words(other: object) -> None:
    with pytest.raises(InvalidArgument, match="Eeprom"):
        Eeprom.factory(1).diff(other)  # type: ignore[arg-type]


# A value the image cannot hold was cut to its nibbles on the way out: speed 300 went on the wire as 44,
# user offset 200 as -56, a pulse limit of 70000 as 4464.  The image refuses it when it is made.
@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("speed", 300),
        ("speed", -1),
        ("servo_id", 256),
        ("pulse_limit_high", 70000),
        ("pulse_limit_low", -3500),
        ("user_offset", 200),
        ("user_offset", -200),
        ("flags", 0x160),
        ("damping", 40.0),
        ("punch", True),
        ("dead_band", "2"),
        ("stretch_gain", None),
    ],
)
def test_an_image_refuses_a_value_its_nibbles_cannot_hold(name: str, value: object) -> None:
    with pytest.raises(MalformedEeprom, match=name):
        dataclasses.replace(FACTORY, **{name: value})
    with pytest.raises(MalformedEeprom, match=name):
        Eeprom(**{**FACTORY.__dict__, name: value})


def test_an_image_holds_every_value_its_nibbles_can() -> None:
    # Lenient as decoding is (a servo's image is shown as it is): out of the reference's range but whole.
    image = dataclasses.replace(
        FACTORY, speed=255, pulse_limit_high=0xFFFF, pulse_limit_low=0, user_offset=-128, servo_id=np.int64(40)
    )
    assert Eeprom.from_bytes(image.to_bytes()) == image
    assert type(image.servo_id) is int
    assert isinstance(dataclasses.replace(FACTORY, flags=0x09).flags, Flags)


async def test_an_image_that_cannot_be_made_never_reaches_the_wire() -> None:
    sim = VirtualLine([VirtualServo(1)], name=f"eeprom-wide-{next(_lines)}")
    try:
        async with open_bus(sim) as bus:
            servo = bus.servo(1)
            image = await servo.read_eeprom()
            before = sim.transactions
            with pytest.raises(MalformedEeprom, match="speed"):
                await servo.write_eeprom(dataclasses.replace(image, speed=300))
            assert sim.transactions == before
            assert sim.servo(1).eeprom == image and sim.servo(1).eeprom_writes == 0
    finally:
        sim.close()


# The reference's ranges (section 7) and flag rules (section 8) hold for an image written whole, as for
# replace(): a change made around replace() (dataclasses.replace, Eeprom(...)) went to the servo as it was.
@pytest.mark.parametrize(
    ("changes", "match"),
    [
        ({"speed": 0}, "speed must be in 1..127"),
        ({"punch": 200}, "punch must be in 0..10"),
        ({"stretch_gain": 61}, "stretch_gain must be even"),
        ({"user_offset": -128}, "user_offset must be in -127..127"),
        ({"flags": Flags.PWMINH | 0x20}, "bits 5-6 are unused"),
        ({"flags": Flags.FREE}, "read-only"),
        ({"pulse_limit_low": 11500, "pulse_limit_high": 3500}, "must not exceed"),
    ],
)
async def test_write_eeprom_refuses_a_change_the_reference_does_not_allow(changes: dict[str, Any], match: str) -> None:
    sim = VirtualLine([VirtualServo(1)], name=f"eeprom-range-{next(_lines)}")
    try:
        async with open_bus(sim) as bus:
            servo = bus.servo(1)
            image = await servo.read_eeprom()
            with pytest.raises(InvalidArgument, match=match):
                await servo.write_eeprom(dataclasses.replace(image, **changes))
            assert sim.servo(1).eeprom == image and sim.servo(1).eeprom_writes == 0
    finally:
        sim.close()


async def test_write_eeprom_writes_back_what_a_servo_holds_out_of_range() -> None:
    # Read, change one field, write back (the reference's way): a value the servo already holds is kept.
    odd = Eeprom.from_bytes(_image_with(4, _nibbles(0)))  # speed 0, out of 1..127
    sim = VirtualLine([VirtualServo(eeprom=odd)], name=f"eeprom-range-{next(_lines)}")
    try:
        async with open_bus(sim) as bus:
            servo = bus.servo(0)
            await servo.write_eeprom((await servo.read_eeprom()).replace(punch=3))
            assert sim.servo(0).eeprom == odd.replace(punch=3) and sim.servo(0).eeprom.speed == 0
    finally:
        sim.close()
