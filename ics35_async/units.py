"""Unit conversions: position counts, degrees, radians, current, temperature.

7500 counts is neutral and 3500..11500 spans 270 degrees, so one degree is
8000 / 270 (about 29.63) counts.  Angles are refused outside -135..+135
degrees (the servo's whole travel): a larger angle is a unit mistake, not a
target (positions beyond 3500..11500 can still be sent as counts).  The temperature conversion is a straight
line through the reference's two points (parameter 80 at about 80 C, 25 at
about 125 C): an approximation, good for warnings, not for measurement.
"""

from __future__ import annotations

import difflib
import math
import numbers
import operator
import re
from collections.abc import Iterable, Mapping
from typing import NamedTuple

from .errors import InvalidArgument

NEUTRAL = 7500
POSITION_MIN = 1
POSITION_MAX = 16383
COUNTS_PER_DEGREE = 8000 / 270
TRAVEL_MIN = 3500  # -135 degrees
TRAVEL_MAX = 11500  # +135 degrees
DEGREES_MAX = 135.0
_ANGLE_SLACK = 1e-9  # so that +-3*pi/4 radians (135.00000000000003 degrees) still converts

_TEMP_P1, _TEMP_C1 = 80, 80.0
_TEMP_P2, _TEMP_C2 = 25, 125.0
_CELSIUS_PER_STEP = (_TEMP_C2 - _TEMP_C1) / (_TEMP_P2 - _TEMP_P1)


def whole_number(value: object) -> int | None:
    """``value`` as a Python int if it is a whole-number type (an int, a NumPy integer: any
    ``numbers.Integral``), else None.  Not a bool: True as an ID or position is always a mistake."""
    if isinstance(value, bool):
        return None
    if isinstance(value, int):
        return value  # an IntEnum or IntFlag stays itself
    if isinstance(value, numbers.Integral):
        return operator.index(value)  # np.int64(7) -> 7: what goes on and comes back holds Python's ints
    return None


def real_number(value: object) -> float | None:
    """``value`` as a Python float if it is a real-number type (int, float, NumPy's numbers: any
    ``numbers.Real``; ``np.float32`` is not a float), else None.  Not a bool.  NaN and inf pass: the
    caller says whether they are allowed; so does a number too big for a float (``10**400``: ``inf``)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        return None
    try:
        return float(value)
    except OverflowError:  # a whole number past a float's range (JSON and TOML have no limit): an infinity
        return -math.inf if operator.lt(value, 0) else math.inf


def finite_number(value: object) -> float | None:
    """``value`` as a Python float if it is a real-number type (:func:`real_number`) and finite, else None."""
    number = real_number(value)
    return number if number is not None and math.isfinite(number) else None


def said(value: object) -> str:
    """``value`` as an error message names it: a number as Python writes it (``nan``, not
    ``np.float32(nan)``), anything else as its repr."""
    number = real_number(value)
    return repr(value) if number is None else shown(number)


def said_not_whole(value: object) -> str:
    """``value`` as a message refusing it as a whole number names it: a float that is whole as a float
    (``7500.0``: ``7500`` would read as the whole number asked for), anything else as :func:`said` does."""
    number = real_number(value)
    if number is not None and number.is_integer():
        return repr(number)
    return said(value)


def check_int(name: str, value: object, low: int, high: int) -> int:
    """``value`` as an int if it is a whole number (:func:`whole_number`) in ``low..high``, else InvalidArgument."""
    number = whole_number(value)
    if number is None:
        raise InvalidArgument(f"{name} must be an int, not {type(value).__name__}")
    if not low <= number <= high:
        raise InvalidArgument(f"{name} must be in {low}..{high}, got {number}")
    return number


def check_bool(name: str, value: object) -> bool:
    """``value`` if it is a real bool: a confirmation flag must not be a truthy string."""
    if not isinstance(value, bool):
        raise InvalidArgument(f"{name} must be True or False, not {value!r}")
    return value


def check_seconds(name: str, value: object, low: float = 0.0, high: float = 60.0) -> float:
    """A finite number of seconds in ``low..high`` (not a bool)."""
    return check_number(name, value, low, high, "seconds")


def check_number(name: str, value: object, low: float, high: float, unit: str) -> float:
    """A finite number in ``low..high`` (not a bool); ``unit`` says what it counts, in its errors."""
    number = finite_number(value)
    if number is None:
        raise InvalidArgument(f"{name} must be a number of {unit}, not {said(value)}")
    if not low <= number <= high:
        raise InvalidArgument(f"{name} must be in {low}..{high} {unit}, got {shown(number)}")
    return number


def check_rate_hz(value: object) -> float | None:
    """A stream's pace: ``None`` (cycles back to back) or a finite number of cycles a second in (0, 10000]
    (not a bool: ``True`` from a JSON form is not a rate)."""
    if value is None:
        return None
    number = finite_number(value)
    if number is None or not 0 < number <= 10000:
        raise InvalidArgument(f"rate_hz must be None or a number in (0, 10000], got {said(value)}")
    return number


def check_ids(name: str, ids: object) -> list[int]:
    """A list of servo IDs 0..31 from an iterable of ints."""
    if isinstance(ids, (str, bytes)) or not isinstance(ids, Iterable):
        raise InvalidArgument(f"{name} must be an iterable of IDs 0..31, not {ids!r}")
    return [check_int("servo ID", i, 0, 31) for i in ids]


def closest_name(name: str, known: Iterable[str]) -> str | None:
    """The ``known`` name a mistyped ``name`` most likely meant, if one is close enough."""
    close = difflib.get_close_matches(name, list(known), n=1)
    return close[0] if close else None


def named_with_the_one_meant(name: str, known: Iterable[str]) -> str:
    """``name`` as an error quotes it, with the ``known`` name it is closest to, if one is close enough:
    ``strech_gain (did you mean stretch_gain?)``."""
    close = closest_name(name, known)
    return f"{name} (did you mean {close}?)" if close else name


def unknown_options(what: str, unknown: Iterable[str], known: Iterable[str], meant: Mapping[str, str] = {}) -> str:
    """What an :class:`InvalidArgument` says of keyword options ``unknown`` to ``what`` (``"open_bus"``): each
    with the ``known`` one it is closest to, or what ``meant`` says of it (an option of the ``ics35``
    commands a program passes by the same name), so the reader learns what to write, not only what not to."""
    known = sorted(known)
    told = [
        f"{name} ({meant[name]})" if name in meant else named_with_the_one_meant(name, known)
        for name in sorted(unknown)
    ]
    return f"unknown {what} option(s): {', '.join(told)}"


def plain_count(text: str) -> int | None:
    """``text`` as a whole number written in plain digits (``"12"``), else None: int() also reads ``"1_2"`` (12:
    a ``"1-2"`` mistyped), ``"+3"`` and other scripts' digits."""
    return int(text) if text.isascii() and text.isdigit() else None


def parse_ids(text: str, *, example: str | None = "3, 1-12 or 0,4,7") -> list[int]:
    """``text`` such as ``"0-31"``, ``"1,3,5-7"`` or ``"1 2 5-7"`` -> the sorted unique IDs it names (none for ``""``).

    ``example``: what the error for an item that is no ID shows how to write (None: none, for a caller that says
    its own).

    Raises:
        InvalidArgument: an item is not an ID or a range, a range runs backwards, or an ID is outside 0..31.
    """
    ids: set[int] = set()
    for part in re.split(r"[,\s]+", re.sub(r"\s*-\s*", "-", text.strip())):
        if not part:
            continue
        low_text, dash, high_text = part.partition("-")
        low = plain_count(low_text)
        high = plain_count(high_text) if dash else low
        if low is None or high is None:
            raise InvalidArgument(
                f"{part!r} is not an ID (0..31) or a range of IDs" + (f" (write e.g. {example})" if example else "")
            )
        if low > high:
            raise InvalidArgument(f"the range {part!r} runs backwards")
        if low == high:
            check_int("servo ID", low, 0, 31)  # (one ID refused in the words every other refusal of one uses)
        elif high > 31:
            raise InvalidArgument(f"the range {part!r} goes beyond 0..31")
        ids.update(range(low, high + 1))
    return sorted(ids)


def parse_id_list(text: str) -> list[int]:
    """IDs as a person types them in a box or an option: ``"1-12"``, ``"0,3 5-7"``, ``"all"`` -> the sorted unique
    IDs; InvalidArgument for anything else, or for nothing (the command line's and the configurator's rule)."""
    if text.strip().lower() in ("all", "*"):
        return list(range(32))
    ids = parse_ids(text, example=None)  # (each caller shows its own example, with `all`)
    if not ids:
        raise InvalidArgument("no IDs given")
    return ids


def position_to_degrees(position: int) -> float:
    """The angle of a position in counts (7500 = 0 degrees); InvalidArgument for anything but a whole number."""
    return (_counts(position) - NEUTRAL) / COUNTS_PER_DEGREE


def _counts(position: object) -> int:
    number = whole_number(position)
    if number is None:
        raise InvalidArgument(f"a position must be a whole number of counts, got {said_not_whole(position)}")
    return number


def shown(value: float) -> str:
    """``value`` as short as ``:g`` writes it, unless that rounds it (135.0001 is not "135" in a message
    saying it is past 135)."""
    text = f"{value:g}"
    return text if float(text) == value else repr(float(value))


def degrees_to_position(degrees: float) -> int:
    """The position for an angle in -135..+135 degrees (0 = neutral); InvalidArgument outside it."""
    number = finite_number(degrees)
    if number is None:
        raise InvalidArgument(f"degrees must be a finite number, got {said(degrees)}")
    if not abs(number) <= DEGREES_MAX + _ANGLE_SLACK:
        raise InvalidArgument(
            f"{shown(number)} degrees is outside -135..+135, the servo's travel ({TRAVEL_MIN}..{TRAVEL_MAX} counts)"
        )
    return round(NEUTRAL + number * COUNTS_PER_DEGREE)


def position_to_radians(position: int) -> float:
    return math.radians(position_to_degrees(position))


def radians_to_position(radians: float) -> int:
    """The position for an angle in -3*pi/4..+3*pi/4 radians (0 = neutral); InvalidArgument outside it."""
    number = finite_number(radians)
    if number is None:
        raise InvalidArgument(f"radians must be a finite number, got {said(radians)}")
    if not abs(math.degrees(number)) <= DEGREES_MAX + _ANGLE_SLACK:
        raise InvalidArgument(f"{shown(number)} radians is outside -3*pi/4..+3*pi/4 (-135..+135 degrees)")
    return degrees_to_position(math.degrees(number))


class Current(NamedTuple):
    """A current reading split into magnitude 0..63 and direction."""

    magnitude: int
    reverse: bool


def current_from_raw(raw: int) -> Current:
    raw = check_int("raw current", raw, 0, 127)
    return Current(raw & 0x3F, bool(raw & 0x40))


def current_to_raw(current: Current) -> int:
    return check_int("current magnitude", current.magnitude, 0, 63) | (0x40 if current.reverse else 0)


def temperature_to_celsius(parameter: int) -> float:
    """Approximate Celsius for a temperature parameter (smaller is hotter)."""
    parameter = check_int("temperature parameter", parameter, 0, 127)
    return _TEMP_C1 + (parameter - _TEMP_P1) * _CELSIUS_PER_STEP


# How a person reads a current or a temperature reading (the command line's `get` and the configurator's RAM
# table say them alike): shown bare, a reverse current of 6 (raw 70) reads as a large one, and 127 as hot.
CURRENT_NOTE = "magnitude 0..63, sign = direction"
TEMPERATURE_NOTE = "smaller is hotter"


def current_text(raw: int) -> str:
    """A raw current reading as ``+6`` / ``-6``: its magnitude, signed by its direction."""
    c = current_from_raw(raw)
    return f"{'-' if c.reverse else '+'}{c.magnitude}"


def temperature_text(parameter: int) -> str:
    """A temperature parameter with its approximate Celsius: ``70 (~80 °C)``."""
    return f"{parameter} (~{temperature_to_celsius(parameter):.0f} °C)"


def celsius_to_temperature(celsius: float) -> int:
    """The temperature parameter (1..127) closest to ``celsius``, clamped."""
    number = finite_number(celsius)
    if number is None:
        raise InvalidArgument(f"celsius must be a finite number, got {said(celsius)}")
    # Clamped before rounding: an extreme finite input overflows to inf, which round() cannot take.
    parameter = _TEMP_P1 + (number - _TEMP_C1) / _CELSIUS_PER_STEP
    return round(min(127.0, max(1.0, parameter)))


def stretch_to_eeprom(stretch: int) -> int:
    """A stretch command value (1..127) as the EEPROM stores it (2..254)."""
    return 2 * check_int("stretch", stretch, 1, 127)


def stretch_from_eeprom(value: int) -> int:
    return check_int("EEPROM stretch", value, 2, 255) // 2
