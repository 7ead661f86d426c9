"""Unit conversions against the spec's reference points (sections 3, 4 and 7)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ics35_async import open_bus
from ics35_async.errors import InvalidArgument
from ics35_async.sim import VirtualLine
from ics35_async.units import (
    COUNTS_PER_DEGREE,
    NEUTRAL,
    Current,
    celsius_to_temperature,
    check_int,
    current_from_raw,
    current_to_raw,
    degrees_to_position,
    position_to_degrees,
    position_to_radians,
    radians_to_position,
    stretch_from_eeprom,
    stretch_to_eeprom,
    temperature_to_celsius,
)

BAD_NUMBERS = [None, "1", True, False, math.nan, math.inf, -math.inf, 1 + 0j]


# --- check_int ---


@pytest.mark.parametrize("value", [True, False, 1.0, "1", None, b"\x01"])
def test_check_int_rejects_non_ints(value: object) -> None:
    with pytest.raises(InvalidArgument, match="must be an int"):
        check_int("thing", value, 0, 10)


@pytest.mark.parametrize("value", [-1, 11, 10**30])
def test_check_int_rejects_out_of_range(value: int) -> None:
    with pytest.raises(InvalidArgument, match=r"thing must be in 0\.\.10"):
        check_int("thing", value, 0, 10)


def test_check_int_accepts_bounds_and_is_a_value_error() -> None:
    assert check_int("thing", 0, 0, 10) == 0
    assert check_int("thing", 10, 0, 10) == 10
    assert issubclass(InvalidArgument, ValueError)


# --- angles ---


def test_reference_angles() -> None:
    assert NEUTRAL == 7500
    assert pytest.approx(29.63, abs=0.005) == COUNTS_PER_DEGREE
    assert position_to_degrees(7500) == 0
    assert position_to_degrees(3500) == pytest.approx(-135)
    assert position_to_degrees(11500) == pytest.approx(135)
    assert degrees_to_position(0) == 7500
    assert degrees_to_position(-135) == 3500
    assert degrees_to_position(135) == 11500
    assert degrees_to_position(90.0) == 7500 + round(90 * 8000 / 270)


def test_reference_radians() -> None:
    assert position_to_radians(7500) == 0
    assert position_to_radians(11500) == pytest.approx(3 * math.pi / 4)
    assert position_to_radians(3500) == pytest.approx(-3 * math.pi / 4)
    assert radians_to_position(3 * math.pi / 4) == 11500
    assert radians_to_position(-3 * math.pi / 4) == 3500
    assert radians_to_position(0) == 7500


@settings(max_examples=200)
@given(st.integers(3500, 11500))
def test_position_degrees_radians_round_trip(position: int) -> None:
    assert degrees_to_position(position_to_degrees(position)) == position
    assert radians_to_position(position_to_radians(position)) == position


def test_degrees_range_edges() -> None:
    # Angles cover the servo's travel, 3500..11500 counts (-135..+135 degrees); beyond is a unit mistake.
    assert degrees_to_position(position_to_degrees(3500)) == 3500
    assert degrees_to_position(position_to_degrees(11500)) == 11500
    for outside in (3499, 11501, 1, 16383):
        with pytest.raises(InvalidArgument, match="outside"):
            degrees_to_position(position_to_degrees(outside))
        with pytest.raises(InvalidArgument, match="outside"):
            radians_to_position(position_to_radians(outside))
    # The value in the message is the one given, not rounded into the range it is outside of.
    with pytest.raises(InvalidArgument, match=r"^135\.0001 degrees is outside"):
        degrees_to_position(135.0001)
    with pytest.raises(InvalidArgument, match=r"^200 degrees is outside"):
        degrees_to_position(200)


@pytest.mark.parametrize("value", [1e307, -1e307, 1e300, -1e300, 1e308])
def test_huge_finite_angles_are_invalid_arguments(value: float) -> None:
    with pytest.raises(InvalidArgument):
        degrees_to_position(value)
    with pytest.raises(InvalidArgument):
        radians_to_position(value)


@pytest.mark.parametrize("value", BAD_NUMBERS)
def test_angle_conversions_reject_bad_numbers(value: object) -> None:
    with pytest.raises(InvalidArgument, match="finite number"):
        degrees_to_position(value)  # type: ignore[arg-type]
    with pytest.raises(InvalidArgument, match="finite number"):
        radians_to_position(value)  # type: ignore[arg-type]


# --- current ---


def test_current_split() -> None:
    assert current_from_raw(0) == Current(0, False)
    assert current_from_raw(63) == Current(63, False)
    assert current_from_raw(64) == Current(0, True)
    assert current_from_raw(0x45) == Current(5, True)
    assert current_from_raw(127) == Current(63, True)
    assert current_to_raw(Current(5, True)) == 0x45
    assert current_to_raw(Current(63, False)) == 63


def test_current_round_trip_over_every_raw_value() -> None:
    for raw in range(128):
        assert current_to_raw(current_from_raw(raw)) == raw


@pytest.mark.parametrize("raw", [-1, 128, True, 1.0, "1"])
def test_current_from_raw_rejects(raw: object) -> None:
    with pytest.raises(InvalidArgument):
        current_from_raw(raw)  # type: ignore[arg-type]


@pytest.mark.parametrize("magnitude", [-1, 64, True, 1.0])
def test_current_to_raw_rejects(magnitude: object) -> None:
    with pytest.raises(InvalidArgument):
        current_to_raw(Current(magnitude, False))  # type: ignore[arg-type]


# --- temperature ---


def test_temperature_reference_points() -> None:
    assert temperature_to_celsius(80) == pytest.approx(80)
    assert temperature_to_celsius(25) == pytest.approx(125)
    assert celsius_to_temperature(80) == 80
    assert celsius_to_temperature(125) == 25
    assert celsius_to_temperature(125.0) == 25


def test_smaller_parameter_is_hotter() -> None:
    readings = [temperature_to_celsius(p) for p in range(1, 128)]
    assert readings == sorted(readings, reverse=True)


@pytest.mark.parametrize(("celsius", "parameter"), [(1000, 1), (-1000, 127), (1e308, 1), (-1.7e308, 127)])
def test_celsius_to_temperature_clamps(celsius: float, parameter: int) -> None:
    assert celsius_to_temperature(celsius) == parameter


@settings(max_examples=100)
@given(st.integers(1, 127))
def test_temperature_round_trip(parameter: int) -> None:
    assert celsius_to_temperature(temperature_to_celsius(parameter)) == parameter


@pytest.mark.parametrize("value", BAD_NUMBERS)
def test_celsius_to_temperature_rejects(value: object) -> None:
    with pytest.raises(InvalidArgument, match="finite number"):
        celsius_to_temperature(value)  # type: ignore[arg-type]


@pytest.mark.parametrize("parameter", [-1, 128, True, 80.0])
def test_temperature_to_celsius_rejects(parameter: object) -> None:
    with pytest.raises(InvalidArgument):
        temperature_to_celsius(parameter)  # type: ignore[arg-type]


# --- stretch ---


def test_stretch_eeprom_scaling() -> None:
    # Spec section 4: EEPROM stores 2x the command value (2..254).
    assert stretch_to_eeprom(1) == 2
    assert stretch_to_eeprom(30) == 60
    assert stretch_to_eeprom(127) == 254
    assert stretch_from_eeprom(2) == 1
    assert stretch_from_eeprom(60) == 30
    assert stretch_from_eeprom(254) == 127
    for stretch in range(1, 128):
        assert stretch_from_eeprom(stretch_to_eeprom(stretch)) == stretch


@pytest.mark.parametrize("value", [0, 128, True, 30.0, "30"])
def test_stretch_to_eeprom_rejects(value: object) -> None:
    with pytest.raises(InvalidArgument):
        stretch_to_eeprom(value)  # type: ignore[arg-type]


@pytest.mark.parametrize("value", [0, 1, 256, True, 60.0])
def test_stretch_from_eeprom_rejects(value: object) -> None:
    with pytest.raises(InvalidArgument):
        stretch_from_eeprom(value)  # type: ignore[arg-type]


# --- angles beyond the travel, wherever degrees are taken ---


@pytest.mark.parametrize("degrees", [135.01, -136, 200, 1e6])
def test_units_refuse_degrees_beyond_135(degrees: float) -> None:
    with pytest.raises(InvalidArgument, match="135"):
        degrees_to_position(degrees)
    with pytest.raises(InvalidArgument, match="135"):
        radians_to_position(math.radians(degrees))


async def test_servo_and_stream_refuse_degrees_beyond_135() -> None:
    sim = VirtualLine([1], log_size=None)
    async with open_bus(sim) as bus:
        with pytest.raises(InvalidArgument):
            await bus.servo(1).set_degrees(200)
        with pytest.raises(InvalidArgument):
            await bus.servo(1).set_radians(math.radians(-140))
        assert sim.transactions == 0
        assert await bus.servo(1).set_degrees(135) == pytest.approx(0.0)  # reports where it was: neutral
        assert sim.servo(1).target == 11500
        async with bus.stream([1]) as stream:
            with pytest.raises(InvalidArgument):
                stream.set_target_degrees(1, 136)
            with pytest.raises(InvalidArgument):
                stream.set_targets_degrees({1: -200.0})


def test_id_lists_are_parsed_in_one_place_for_the_cli_the_simulator_and_the_configurator() -> None:
    from ics35_async.cli import _params
    from ics35_async.sim import parse_ids as sim_parse_ids
    from ics35_async.units import parse_id_list, parse_ids
    from ics35_async.web import api

    assert _params.parse_id_list is api.parse_id_list is parse_id_list  # (the ID boxes' rule: GET /api/ids)

    assert sim_parse_ids is parse_ids
    assert parse_ids("5-7, 1 3,1") == [1, 3, 5, 6, 7] and parse_ids("2 - 4") == [2, 3, 4] and parse_ids("") == []
    assert parse_id_list("all") == list(range(32)) and parse_id_list("0,31") == [0, 31]
    # (Python's int() reads "1_3" as 13, a "1-3" mistyped: a line of servo 13 for one of three)
    for bad in ("3-1", "x", "31-32", "-1", "1-", "1_3", "+3", "1-+3", "\u0663"):
        with pytest.raises(InvalidArgument):
            parse_ids(bad)
    with pytest.raises(InvalidArgument, match="no IDs"):
        parse_id_list(" ")


@pytest.mark.parametrize("value", [*BAD_NUMBERS, 7500.0, "7500"])
def test_position_conversions_refuse_what_is_not_a_whole_number_of_counts(value: object) -> None:
    with pytest.raises(InvalidArgument, match="whole number"):
        position_to_degrees(value)  # type: ignore[arg-type]
    with pytest.raises(InvalidArgument, match="whole number"):
        position_to_radians(value)  # type: ignore[arg-type]


@pytest.mark.parametrize("value", [7500.0, np.float64(7500.0)])
def test_a_whole_float_refused_as_a_position_is_named_as_a_float(value: object) -> None:
    """A message saying "got 7500" beside "must be a whole number" reads as nonsense: it shows the float."""
    with pytest.raises(InvalidArgument, match=r"whole number of counts, got 7500\.0$"):
        position_to_degrees(value)  # type: ignore[arg-type]
