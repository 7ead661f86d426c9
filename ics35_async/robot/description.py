"""The robot description: lines, joints and safety limits, read from TOML (or a mapping) and checked.

Every mistake is a :class:`DescriptionError` naming the file and the key
(``robot.toml: joints.left_elbow.line: ...``), raised before any port is
opened.  A joint maps to its servo as ``servo degrees = offset + (-1 if
reverse else +1) * joint degrees``.
"""

from __future__ import annotations

import difflib
import json
import math
import os
import re
import tomllib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from .. import protocol, units
from ..eeprom import FACTORY_BAUD
from ..errors import FileContentError, InvalidArgument
from ..transports.direction import DIRECTIONS
from ..transports.wire_device import check_url, is_url, opens_anew, url_scheme
from ..user_files import UnreadableText, is_device, parse_toml, read_user_text

SAFETY_ACTIONS = ("free", "hold", "stop")
SERVO_DEGREES = units.DEGREES_MAX  # the servo's travel: -135..+135 degrees
# A count is 270/8000 = 0.03375 degree exactly: an angle a servo reports has 5 decimals (plus the offset's).
COUNT_DECIMALS = 5
# The fewest position cycles per second a robot line's rate_hz may ask.  A motion goes out as one target a cycle,
# each reached at the servo's full speed: at 0.5 Hz the joints jumped between targets two seconds apart, and the
# safety watch's temperature and current reads, a few joints a cycle, came seconds late.  Every line can keep it:
# 32 servos at 115200 baud, the slowest line, cycle about 30 times a second.
MIN_LINE_RATE_HZ = 20.0
MAX_LINE_RATE_HZ = 10_000.0


class DescriptionError(FileContentError):
    """A robot description breaks a rule; ``source`` is the file (or ``<mapping>``), ``key`` the dotted key."""


@dataclass(frozen=True)
class LineSpec:
    """One ICS line: any port ``open_bus`` takes, its baud rate, and the stream's rate (None: the line's pace)."""

    name: str
    port: str
    baudrate: int = FACTORY_BAUD
    echo: bool = True
    rate_hz: float | None = None
    retries: int = 0
    direction: str = "none"  # a DIY half-duplex interface's direction control on RTS (see open_bus)


@dataclass(frozen=True)
class JointSpec:
    """One joint: which servo drives it, how its degrees map to the servo's, and its limits (joint degrees)."""

    name: str
    line: str
    id: int
    offset: float = 0.0
    reverse: bool = False
    min: float = -SERVO_DEGREES
    max: float = SERVO_DEGREES
    limits_given: bool = field(default=True, compare=False)
    """Whether the description states ``min`` or ``max`` (a file without them takes the servo's whole travel)."""

    @property
    def sign(self) -> int:
        """-1 for a reversed joint, else +1."""
        return -1 if self.reverse else 1

    def servo_degrees(self, joint_degrees: float) -> float:
        """The servo angle for an angle of this joint: ``offset + sign * joint_degrees``."""
        return self.offset + self.sign * joint_degrees

    def joint_degrees(self, servo_degrees: float) -> float:
        """The joint angle for an angle of its servo (the inverse of ``servo_degrees``)."""
        return (servo_degrees - self.offset) * self.sign

    def position(self, joint_degrees: float) -> int:
        """The servo position (counts) for ``joint_degrees``, an angle of this joint: the nearest count
        within the joint's limits (the nearest one overall may lie half a count past a limit)."""
        nearest = units.degrees_to_position(self.servo_degrees(joint_degrees))
        if self._within(nearest):
            return nearest
        for step in (-1, 1):  # one count back inside (which way depends on offset and reverse)
            if self._within(nearest + step):
                return nearest + step
        return nearest  # limits narrower than a count: nothing inside to choose

    def _within(self, position: int) -> bool:
        if not units.POSITION_MIN <= position <= units.POSITION_MAX:
            return False
        angle = self.joint_degrees(units.position_to_degrees(position))
        return self.min - 1e-9 <= angle <= self.max + 1e-9  # (float noise at a limit on a whole count)

    def degrees(self, position: int) -> float:
        """This joint's angle for a servo position (counts), to the servo's resolution.

        Rounding to :data:`COUNT_DECIMALS` drops the float noise an offset leaves (-0.004999... for
        -0.005) and changes no real reading; + 0.0 turns -0.0 into 0.0.
        """
        return round(self.joint_degrees(units.position_to_degrees(position)), COUNT_DECIMALS) + 0.0

    def clamp(self, joint_degrees: float) -> float:
        """``joint_degrees`` brought within ``[min, max]``."""
        return min(self.max, max(self.min, joint_degrees))

    def check(self, joint_degrees: object) -> float:
        """``joint_degrees`` as a float if it is a finite number within the limits, else InvalidArgument."""
        number = units.real_number(joint_degrees)
        if number is None:
            raise InvalidArgument(f"joint {self.name}: the target must be a number of degrees, not {joint_degrees!r}")
        if not self.min <= number <= self.max:
            raise InvalidArgument(
                f"joint {self.name}: {units.shown(number)} degrees is outside its limits {self.min:g}..{self.max:g}"
            )
        return number


@dataclass(frozen=True)
class SafetySpec:
    """``[safety]``: thresholds read in the line's gaps, and what crossing one does."""

    max_temperature_c: float | None = None
    max_current: int | None = None
    action: str = "free"
    continue_on_offline: bool = False
    telemetry_per_cycle: int = 2


@dataclass(frozen=True)
class RobotDescription:
    source: str
    lines: dict[str, LineSpec]
    joints: dict[str, JointSpec]
    safety: SafetySpec = field(default_factory=SafetySpec)
    name: str | None = None

    def joints_on(self, line: str) -> list[JointSpec]:
        """The joints driven by servos on ``line``, in file order."""
        return [j for j in self.joints.values() if j.line == line]

    def on_hardware(self, names: Iterable[str]) -> list[str]:
        """Of the joints ``names``, those whose line is not the built-in simulator (a serial port or a bridge to
        one): where freeing a joint at the start drops what it bears, so a program asks a person first."""
        return [n for n in names if url_scheme(self.lines[self.joints[n].line].port) != "sim"]

    def only(self, names: Iterable[object]) -> RobotDescription:
        """This robot with only the joints ``names`` (in file order) and the lines they use: a robot opened on
        it streams, reads and frees no other joint (their servos keep what they hold).

        Raises:
            InvalidArgument: an unknown joint name, or none at all.
        """
        wanted = set(self.known_joints(names))
        if not wanted:
            raise InvalidArgument("name at least one joint")
        joints = {name: spec for name, spec in self.joints.items() if name in wanted}
        used = {spec.line for spec in joints.values()}
        lines = {name: spec for name, spec in self.lines.items() if name in used}
        return replace(self, lines=lines, joints=joints)

    def known_joints(self, names: Iterable[object]) -> list[str]:
        """``names`` as a list, each one of this robot's joints.

        Raises:
            InvalidArgument: not joint names, or an unknown joint name (the message lists the robot's joints).
        """
        if not isinstance(names, Iterable):
            raise InvalidArgument(f"joints must be a joint's name or joint names, not {type(names).__name__}")
        names = list(names)
        unknown = [str(n) for n in names if n not in self.joints]
        if unknown:
            raise InvalidArgument(f"unknown joint(s): {', '.join(unknown)} (joints: {', '.join(self.joints)})")
        return [str(n) for n in names]

    def check_pose(self, pose: Mapping[str, object]) -> dict[str, float]:
        """``pose`` ``{joint: degrees}`` checked: every name one of this robot's joints, every angle a number
        within its joint's limits.  Needs no open port: a pose (or a motion's every keyframe) is checked
        before a line opens, so a typo or an angle past a limit frees and moves nothing.

        Raises:
            InvalidArgument: not a mapping, an unknown joint or an angle outside its limits.
        """
        if not isinstance(pose, Mapping):
            raise InvalidArgument(f"a pose is a mapping {{joint: degrees}}, not {type(pose).__name__}")
        self.known_joints(pose)
        return {name: self.joints[name].check(deg) for name, deg in pose.items()}


# ---------------------------------------------------------------------------------------- reading


def load_description(source: str | Path | Mapping[str, Any]) -> RobotDescription:
    """Read and check a robot description: ``source`` is a TOML file's path, or the same structure as a mapping.

    Raises:
        DescriptionError: the file cannot be read, is not TOML, or breaks a rule of the format; or ``source`` is a
            port (``"sim://arm"``, ``"/dev/ttyUSB0"``), not a file (see :func:`check_not_a_port`).
        InvalidArgument: ``source`` is neither a path nor a mapping.
    """
    if isinstance(source, Mapping):
        return parse_description(source, "<mapping>")
    if not isinstance(source, (str, Path)):
        raise InvalidArgument(f"a robot description is a TOML file's path or a mapping, not {type(source).__name__}")
    check_not_a_port(source)
    path = Path(source)
    try:
        text = read_user_text(source, "a robot file is UTF-8 TOML")
    except UnreadableText as exc:
        raise DescriptionError(str(path), "", str(exc)) from None
    try:
        data = parse_toml(text)
    except tomllib.TOMLDecodeError as exc:
        raise DescriptionError(str(path), "", f"not valid TOML: {exc}") from None
    return parse_description(data, str(path))


def check_not_a_port(source: str | os.PathLike[str], taker: str | None = None) -> None:
    """Refuse ``source``, given where a robot file goes, when it names a port and no file is there: a URL
    (``sim://arm``, which a path reads as ``sim:/arm``, a file that is not there), a device path (``/dev/ttyUSB0``
    unplugged, ``COM3``) or a device (a serial port, which has no end to read to).  The error says where a robot's
    ports go instead; ``taker`` (``"open_robot"``), when given, is named as what takes the robot file.

    Raises:
        DescriptionError: ``source`` names a port, not a file; it names ``source`` as given.
    """
    text = os.fspath(source)
    if os.path.exists(text) and not is_device(text):
        return  # (a file or a pipe there, a shell's <(...), whatever its name reads like, is what was meant)
    if is_url(text):
        scheme = url_scheme(text)
        kind = f"a {scheme}:// URL" if scheme else "a URL"
    elif is_device(text):
        kind = "a device"
    elif text.startswith("/dev/") or re.fullmatch(r"COM\d+", text, re.IGNORECASE):
        kind = "a device path"
    else:
        return
    where = f"a robot's ports go in its file, a [lines.NAME] table each: port = {json.dumps(text)}"
    if taker is None:
        raise DescriptionError(text, "", f"this looks like a port ({kind}), not a robot file: {where}")
    mapping = f'{{"lines": {{"main": {{"port": {json.dumps(text)}}}}}, "joints": {{...}}}}'
    raise DescriptionError(
        text,
        "",
        f"{taker} takes a robot file (or a mapping of the same), and this looks like a port ({kind}): {where}; "
        f"in a mapping, {mapping}",
    )


class _Reader:
    """Takes the keys of one table, each checked, and refuses the ones nobody took."""

    def __init__(self, source: str, key: str, table: object) -> None:
        self.source = source
        self.key = key
        if not isinstance(table, Mapping):
            raise self.error("", f"must be a table, not {_kind(table)}")
        self.table = table
        self.taken: set[str] = set()

    def error(self, name: str, message: str) -> DescriptionError:
        return DescriptionError(self.source, ".".join(k for k in (self.key, name) if k), message)

    def missing(self, name: str) -> DescriptionError:
        """``name`` is required and absent: a key spelt nearly like it is the likely reason."""
        near = difflib.get_close_matches(name, [str(k) for k in self.table if k != name], n=1, cutoff=0.6)
        return self.error(name, f"is required (is {near[0]!r} meant to be {name!r}?)" if near else "is required")

    def get(self, name: str) -> object:
        self.taken.add(name)
        return self.table.get(name)

    def text(self, name: str, *, required: bool = False) -> str | None:
        value = self.get(name)
        if value is None and not required:
            return None
        if not isinstance(value, str) or not value:
            if value is None:
                raise self.missing(name)
            raise self.error(name, f"must be a non-empty string, got {_toml_said(value)}")
        return value

    def number(self, name: str, low: float, high: float, *, unit: str = "", too_low: str = "") -> float | None:
        """The number ``name`` holds, in ``low..high`` (``unit`` follows the range where it is said); each refusal
        names the range and the value as the file has it, with ``too_low``, the reason for ``low``, when below it."""
        value = self.get(name)
        if value is None:
            return None
        number = units.finite_number(value)  # (a description built by a program may hold NumPy numbers)
        if number is None or not low <= number <= high:
            below = f": {too_low}" if too_low and number is not None and number < low else ""
            raise self.error(
                name, f"must be a number in {low:g}..{high:g}{unit and ' '}{unit}, got {_toml_said(value)}{below}"
            )
        return number

    def integer(self, name: str, low: int, high: int, *, required: bool = False) -> int | None:
        value = self.get(name)
        if value is None:
            if required:
                raise self.missing(name)
            return None
        number = units.whole_number(value)
        if number is None or not low <= number <= high:
            raise self.error(name, f"must be a whole number in {low}..{high}, got {_toml_said(value, whole=True)}")
        return number

    def flag(self, name: str) -> bool | None:
        value = self.get(name)
        if value is None:
            return None
        if not isinstance(value, bool):
            raise self.error(name, f"must be true or false, got {_toml_said(value)}")
        return value

    def done(self) -> None:
        unknown = [k for k in self.table if k not in self.taken]
        if unknown:
            raise self.error(str(unknown[0]), f"unknown key (known: {', '.join(sorted(self.taken))})")


def _toml_said(value: object, *, whole: bool = False) -> str:
    """``value`` as a robot file has it, for a message refusing it: in TOML's words (``true``, ``"fast"``, ``nan``,
    ``1e300``), a whole float as digits (``rate_hz = 1e9``: ``1000000000``), but as a float (``1.0``) where a
    ``whole`` number is asked (its digits alone would read as the number asked for)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)  # (a TOML basic string: the quotes and escapes are the same)
    if isinstance(value, (list, tuple)):
        return "an array"
    if isinstance(value, Mapping):
        return "a table"
    integer = units.whole_number(value)
    if integer is not None:
        return str(integer)
    number = units.real_number(value)
    if number is None:
        return type(value).__name__  # (only a description built by a program holds other things)
    if not math.isfinite(number):
        return str(number)  # nan, inf, -inf: TOML's own
    if number.is_integer() and not whole and abs(number) < 1e16:  # (past it, a float's digits are not all its own)
        return str(int(number))
    return re.sub(r"e\+?(-?)0*(?=\d)", r"e\1", repr(number))  # 1e+300 -> 1e300, 1.5e-07 -> 1.5e-7


def _kind(value: object) -> str:
    return {str: "a string", bool: "a boolean", int: "a number", float: "a number", list: "a list"}.get(
        type(value), type(value).__name__
    )


def parse_description(data: Mapping[str, Any], source: str = "<mapping>") -> RobotDescription:
    """Check ``data``, a parsed description (what ``tomllib`` returns), and build a :class:`RobotDescription`.

    ``source`` names where it came from in error messages.

    Raises:
        DescriptionError: ``data`` breaks a rule of the format (the error names the key).
    """
    top = _Reader(source, "", data)
    name = top.text("name")
    lines_table, joints_table, safety_table = top.get("lines"), top.get("joints"), top.get("safety")
    top.done()  # first: a misspelt [line.arms] is named, not the unknown line 'arms' its joints then point at
    lines = _lines(source, lines_table)
    joints = _joints(source, joints_table, lines)
    safety = _safety(source, safety_table)
    return RobotDescription(source=source, lines=lines, joints=joints, safety=safety, name=name)


def _tables(source: str, key: str, value: object) -> Mapping[str, Any]:
    if value is None:
        raise DescriptionError(source, key, f"is required: at least one [{key}.NAME] table")
    if not isinstance(value, Mapping):
        raise DescriptionError(source, key, f"must be a table of [{key}.NAME] tables, not {_kind(value)}")
    if not value:
        raise DescriptionError(source, key, f"needs at least one [{key}.NAME] table")
    return value


def _lines(source: str, value: object) -> dict[str, LineSpec]:
    lines: dict[str, LineSpec] = {}
    ports: dict[str, str] = {}
    for name, table in _tables(source, "lines", value).items():
        r = _Reader(source, f"lines.{name}", table)
        port = r.text("port", required=True)
        assert port is not None
        baud = r.integer("baudrate", 0, 10_000_000)
        if baud is not None:
            try:
                protocol.check_baud(baud)
            except InvalidArgument:
                raise r.error("baudrate", f"must be 115200, 625000 or 1250000, got {baud}") from None
        echo = r.flag("echo")
        rate = r.number(
            "rate_hz",
            MIN_LINE_RATE_HZ,
            MAX_LINE_RATE_HZ,
            unit="cycles per second",
            too_low="a motion goes out as one target a cycle, and fewer cycles would move the joints in jumps at the "
            "servos' full speed (leave rate_hz out to cycle as fast as the line allows)",
        )
        retries = r.integer("retries", 0, protocol.MAX_RETRIES)
        direction = r.text("direction")
        if direction is not None and direction not in DIRECTIONS:
            raise r.error("direction", f"must be one of {', '.join(DIRECTIONS)}, got {direction!r}")
        r.done()
        try:  # (a port the simulator refuses, told as the file is read: not at the open, after the lines before it)
            check_url(port)
        except InvalidArgument as exc:
            raise r.error("port", f"{_toml_said(port)} is refused: {exc}") from None
        if port in ports and not opens_anew(port):
            raise r.error("port", f"{port!r} is already the port of lines.{ports[port]}")
        ports[port] = name
        lines[name] = LineSpec(
            name=name,
            port=port,
            baudrate=FACTORY_BAUD if baud is None else baud,
            echo=True if echo is None else echo,
            rate_hz=rate,
            retries=0 if retries is None else retries,
            direction="none" if direction is None else direction,
        )
    return lines


def _joints(source: str, value: object, lines: Mapping[str, LineSpec]) -> dict[str, JointSpec]:
    joints: dict[str, JointSpec] = {}
    owners: dict[tuple[str, int], str] = {}
    for name, table in _tables(source, "joints", value).items():
        r = _Reader(source, f"joints.{name}", table)
        line = r.text("line", required=True)
        assert line is not None
        if line not in lines:
            raise r.error("line", f"unknown line {line!r} (lines: {', '.join(lines)})")
        sid = r.integer("id", 0, 31, required=True)
        assert sid is not None
        offset = r.number("offset", -SERVO_DEGREES, SERVO_DEGREES) or 0.0
        reverse = bool(r.flag("reverse"))
        low = r.number("min", -360, 360)
        high = r.number("max", -360, 360)
        given = low is not None or high is not None  # (else the whole travel: see JointSpec.limits_given)
        r.done()
        owner = owners.get((line, sid))
        if owner is not None:
            raise r.error("id", f"ID {sid} on line {line!r} is already joint {owner!r}")
        owners[(line, sid)] = name
        # The whole travel of the servo, in this joint's degrees: the default limits.
        ends = sorted(((e - offset) * (-1 if reverse else 1)) for e in (-SERVO_DEGREES, SERVO_DEGREES))
        low = ends[0] if low is None else low
        high = ends[1] if high is None else high
        if low > high:
            raise r.error("min", f"min ({low:g}) is greater than max ({high:g})")
        for key, limit in (("min", low), ("max", high)):
            servo = offset + (-1 if reverse else 1) * limit
            if abs(servo) > SERVO_DEGREES + 1e-9:
                raise r.error(
                    key,
                    f"{limit:g} joint degrees is {servo:g} servo degrees (offset {offset:g}"
                    f"{', reversed' if reverse else ''}), outside the servo's range -135..+135",
                )
        joints[name] = JointSpec(
            name=name, line=line, id=sid, offset=offset, reverse=reverse, min=low, max=high, limits_given=given
        )
    for line in lines:
        if not any(j.line == line for j in joints.values()):
            raise DescriptionError(source, f"lines.{line}", "no joint uses this line")
    return joints


def _safety(source: str, value: object) -> SafetySpec:
    if value is None:
        return SafetySpec()
    r = _Reader(source, "safety", value)
    temperature = r.number("max_temperature_c", 0, 150)
    current = r.integer("max_current", 1, 63)
    action = r.text("action") or "free"
    if action not in SAFETY_ACTIONS:
        raise r.error("action", f"must be one of {', '.join(SAFETY_ACTIONS)}, not {action!r}")
    on_offline = r.flag("continue_on_offline")
    per_cycle = r.integer("telemetry_per_cycle", 0, 32)
    r.done()
    per_cycle = 2 if per_cycle is None else per_cycle
    if per_cycle == 0 and (temperature is not None or current is not None):
        raise r.error("telemetry_per_cycle", "is 0, so the temperature and current limits could never be checked")
    return SafetySpec(
        max_temperature_c=temperature,
        max_current=current,
        action=action,
        continue_on_offline=bool(on_offline),
        telemetry_per_cycle=per_cycle,
    )
