"""The 64-byte EEPROM image (spec sections 7 and 8): layout, round trips, strict updates."""

from __future__ import annotations

from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ics35_async.eeprom import (
    EEPROM_FIELDS,
    EEPROM_SIZE,
    PROTECTED_OFFSETS,
    BaudRate,
    Eeprom,
    Flags,
)
from ics35_async.errors import InvalidArgument, MalformedEeprom, UnsafeOperation

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


@pytest.mark.parametrize("header", [b"\x05\x0b", b"\x0a\x05", b"\x00\x00"])
def test_wrong_header(header: bytes) -> None:
    with pytest.raises(MalformedEeprom, match="header"):
        Eeprom.from_bytes(_image_with(0, header))


@pytest.mark.parametrize("code", [2, 9, 11, 0xFF])
def test_unknown_baud_code(code: int) -> None:
    with pytest.raises(MalformedEeprom, match="baud"):
        Eeprom.from_bytes(_image_with(26, bytes((code >> 4, code & 0x0F))))
    with pytest.raises(MalformedEeprom):
        BaudRate.from_eeprom_code(code)


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
    assert set(out) == {*SPEC_LAYOUT, "flags_names", "raw"}
    assert out["flags"] == 8 and out["flags_names"] == ["PWMINH"]
    assert out["baud_rate"] == 625000 and out["user_offset"] == -5 and out["servo_id"] == 3
    assert bytes.fromhex(out["raw"]) == eeprom.to_bytes()
    assert all(type(out[name]) is int for name in SPEC_LAYOUT)
