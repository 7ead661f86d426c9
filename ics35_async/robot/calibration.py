"""Calibration results written back into the robot file, comments kept where the file's shape allows.

:func:`calibrate_joint` turns what a person showed by hand (the servo angle
at the joint's neutral, and the extremes it was moved to) into ``offset``,
``min`` and ``max``.  :func:`write_calibration` edits the ``offset`` /
``min`` / ``max`` lines of each ``[joints.NAME]`` table in place, keeping
every comment and every other line; when a joint is written otherwise (an
inline table, dotted keys) it writes the file so edited beside the original
instead (``NAME.calibrated.toml``: the original with only the calibration
changed), and when the edit would not read back as intended, a complete new
file there (comments are lost in that one).  A file it
overwrites is kept as ``NAME.bak`` first, and the new content is written whole
before it replaces the old (a crash mid-write leaves the old file).
:func:`reverse_note` tells, as calibration begins, of a joint reversed both in
the file and by its servo's EEPROM REVERSE flag.
"""

from __future__ import annotations

import json
import math
import re
import shlex
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path

from .. import units
from ..eeprom import Eeprom, Flags
from ..errors import InvalidArgument
from ..user_files import replace_keeping_backup
from .description import (
    COUNT_DECIMALS,
    SERVO_DEGREES,
    JointSpec,
    LineSpec,
    RobotDescription,
    SafetySpec,
    parse_description,
)

CALIBRATED_KEYS = ("offset", "min", "max")
# Keys not added to a joint's table that lacks them when their value is this: the file reads the same without
# them.  (Not min or max: their defaults follow the offset.)
_LEFT_OUT_AT = {"offset": 0.0}
# A TOML key, bare or quoted, and a dotted path of them (``joints."left arm".min``).
_PART = r"""(?:[A-Za-z0-9_-]+|"(?:[^"\\]|\\.)*"|'[^']*')"""
_PATH = rf"{_PART}(?:\s*\.\s*{_PART})*"
_HEADER = re.compile(rf"^\s*\[\s*({_PATH})\s*\]\s*(?:#.*)?$")
_KEY = re.compile(rf"^(\s*)({_PATH})(\s*=\s*)(.*)$")
_SCALAR = re.compile(r"^([^#]*?)(\s*#.*)?$")  # a number, and the comment after it
_ITEM = re.compile(rf"^(\s*)({_PATH})(\s*=\s*)(.*?)(\s*)$", re.DOTALL)  # an inline table's key = value


MIN_RANGE_DEGREES = 5.0  # narrower, the joint was not moved through its range: limits that would lock it


class NarrowRange(InvalidArgument):
    """A joint moved over less than :data:`MIN_RANGE_DEGREES` as it was calibrated: ``joint`` (its name),
    ``span`` (the degrees it moved over)."""

    def __init__(self, joint: str, span: float) -> None:
        super().__init__(
            f"joint {joint} moved over {span:.1f} degrees only, less than the {MIN_RANGE_DEGREES:g} a range needs "
            "(was it moved to both ends of its range?)"
        )
        self.joint = joint
        self.span = span


# Calibrated limits are rounded inward to this step, so that the file reads as a person writes it.
LIMIT_STEP = 0.1
# How far past a calibrated limit a joint can read at the very end it was calibrated at: the rounding, and a count
# of the potentiometer's reading either way.  A reading within it is at the limit, not beyond it.
AT_THE_LIMIT = LIMIT_STEP + 1 / units.COUNTS_PER_DEGREE


def beyond_limits(joint: JointSpec, angle: float) -> bool:
    """Whether ``joint`` read at ``angle`` (joint degrees) stands beyond its limits by more than a joint at the end
    a calibration measured reads past them (:data:`AT_THE_LIMIT`; a hand-written limit is given the same room)."""
    return not joint.min - AT_THE_LIMIT <= angle <= joint.max + AT_THE_LIMIT


def calibrate_joint(joint: JointSpec, neutral: float, low: float, high: float) -> JointSpec:
    """``joint`` with the offset that makes ``neutral`` (servo degrees) read 0, and limits spanning
    ``low``..``high`` (servo degrees), rounded inward to 0.1 degree.

    The offset is the angle of the whole position count nearest ``neutral`` (0.03375 degree a count): a
    joint back at that count reads exactly 0, where an offset rounded coarser than a count would leave it
    reading a few hundredths off.

    Raises :class:`NarrowRange` (an InvalidArgument) when the range is narrower than
    :data:`MIN_RANGE_DEGREES`: a joint not moved by hand (Enter pressed twice) would otherwise get limits
    that forbid every motion.
    """
    offset = count_angle(neutral)
    lo, hi = calibrated_limits(joint, offset, low, high)
    if hi - lo < MIN_RANGE_DEGREES:
        raise NarrowRange(joint.name, max(0.0, high - low))
    return replace(joint, offset=offset, min=lo, max=hi)


def calibrated_limits(joint: JointSpec, offset: float, low: float, high: float) -> tuple[float, float]:
    """``min`` and ``max`` for ``joint`` given ``offset``: ``low``..``high`` (servo degrees) in its joint degrees,
    rounded inward to 0.1 degree and within the servo's travel (a range too narrow is not refused here)."""
    ends = sorted(((s - offset) * joint.sign) for s in (low, high))
    steps = 1 / LIMIT_STEP
    lo = math.ceil(round(ends[0] * steps, 6)) / steps
    hi = math.floor(round(ends[1] * steps, 6)) / steps
    # Within the servo's travel whatever the rounding did.
    bound = sorted(((e - offset) * joint.sign) for e in (-SERVO_DEGREES, SERVO_DEGREES))
    return max(lo, bound[0]), min(hi, bound[1])


def count_angle(servo_degrees: float) -> float:
    """The angle of the whole position count nearest ``servo_degrees`` (at most :data:`COUNT_DECIMALS` decimals:
    the float noise of a count's angle, 10.125000000000002 for 300 counts, dropped)."""
    counts = round(servo_degrees * units.COUNTS_PER_DEGREE)
    return round(counts / units.COUNTS_PER_DEGREE, COUNT_DECIMALS) + 0.0


def _number(value: float) -> str:
    # To the servo's resolution: an offset on a whole count has up to 5 decimals (0.03375 a count).
    text = f"{round(value, COUNT_DECIMALS):.{COUNT_DECIMALS}f}".rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


def _written_value(text: str) -> float | None:
    """The number a key's value ``text`` is (``-60.0``, ``+60``, ``1_0``), None for anything else."""
    try:
        value = tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return None
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else None


def _key_parts(path: str) -> tuple[str, ...] | None:
    """The keys of a dotted key as TOML reads them (``joints."a.b".min``: joints, a.b, min); None if it is not one."""
    try:
        node: object = tomllib.loads(f"{path} = 0")
    except tomllib.TOMLDecodeError:
        return None
    parts: list[str] = []
    while isinstance(node, dict) and len(node) == 1:
        ((key, node),) = node.items()
        parts.append(key)
    return tuple(parts)


def _bare_or_quoted(key: str) -> str:
    return key if re.fullmatch(r"[A-Za-z0-9_-]+", key) else json.dumps(key)


def _inline_items(text: str) -> tuple[list[str], int] | None:
    """The ``key = value`` items of the inline table ``text`` starts with, as written, and where its ``}`` is;
    None if it does not close on this line."""
    items: list[str] = []
    depth, quote, start, at = 0, "", 1, 1
    while at < len(text):
        char = text[at]
        if quote:
            if char == "\\" and quote == '"':
                at += 1
            elif char == quote:
                quote = ""
        elif char in "\"'":
            quote = char
        elif char in "[{":
            depth += 1
        elif char == "," and depth == 0:
            items.append(text[start:at])
            start = at + 1
        elif char in "]}":
            if depth == 0:
                items.append(text[start:at])
                return [item for item in items if item.strip()], at
            depth -= 1
        at += 1
    return None


def _edit_inline(text: str, values: dict[str, float]) -> str | None:
    """``text`` (an inline table and the rest of its line) with ``values`` set in the table, as
    :func:`edit_joint_values` sets a table's keys; None if the table does not close on this line."""
    found = _inline_items(text)
    if found is None:
        return None
    items, close = found
    values = dict(values)
    for at, item in enumerate(items):
        match = _ITEM.match(item)
        parts = _key_parts(match.group(2)) if match else None
        if match and parts is not None and len(parts) == 1 and parts[0] in values:
            value = values.pop(parts[0])
            if _written_value(match.group(4)) != value:
                lead, key, equals, _old, trail = match.groups()
                items[at] = f"{lead}{key}{equals}{_number(value)}{trail}"
    added = [f"{key} = {_number(value)}" for key, value in values.items() if _LEFT_OUT_AT.get(key) != value]
    if not items:
        return "{" + ", ".join(added) + text[close:]
    if added:  # after the last item, before the spaces that end the table ("{ a = 1 }")
        last = items[-1].rstrip()
        items[-1] = last + "".join(f", {item}" for item in added) + items[-1][len(last) :]
    return "{" + ",".join(items) + text[close:]


@dataclass(frozen=True)
class JointsEdited:
    """What :func:`edit_joint_values` made of a robot file."""

    text: str
    tables_only: bool  # every joint edited is a ``[joints.NAME]`` table (none an inline table or dotted keys)


def edit_joint_values(text: str, values: Mapping[str, Mapping[str, float]]) -> JointsEdited | None:
    """``text`` with the given keys of each joint set, however the joint is written: a ``[joints.NAME]`` table, an
    inline table (``neck = {line = "upper", id = 1}`` in ``[joints]``, or ``joints.neck = {...}``) or dotted keys
    (``hip.id = 1`` in ``[joints]``, or ``joints.hip.id = 1``); None if a joint is not found so.

    A key the joint lacks is added after its last key, in the joint's own way of writing them, but for an
    ``offset`` of 0 (the file reads the same without it); a key it has is updated, unless it already holds that
    value (its line is then left as it is written, so a diff against the old file shows only what changed).
    Every other line is kept as it is, comments too.
    """
    out: list[str] = []
    header: tuple[str, ...] | None = ()  # the table the lines are in (None: an array of tables')
    pending = {name: dict(keys) for name, keys in values.items()}
    tables: set[str] = set()
    last_at: dict[str, int] = {}  # the line after which a joint's missing keys go
    prefix: dict[str, str] = {}  # how they are written: "hip." for a joint of dotted keys in [joints]

    for line in text.splitlines(keepends=True):
        body = line.rstrip("\r\n")
        ending = line[len(body) :]
        if body.lstrip().startswith("[["):
            header = None
            out.append(line)
            continue
        if (table := _HEADER.match(body)) is not None:
            header = _key_parts(table.group(1))
            if header is not None and len(header) == 2 and header[0] == "joints" and header[1] in values:
                tables.add(header[1])
                last_at[header[1]] = len(out)
                prefix[header[1]] = ""
            out.append(line)
            continue
        key = _KEY.match(body)
        parts = _key_parts(key.group(2)) if key is not None and header is not None else None
        path = (*header, *parts) if header is not None and parts is not None else ()
        if key is None or len(path) < 2 or path[0] != "joints" or path[1] not in values:
            out.append(line)
            continue
        indent, written, equals, rest = key.groups()
        name = path[1]
        if len(path) == 2:  # the joint as an inline table
            edited = _edit_inline(rest, pending.pop(name)) if rest.startswith("{") else None
            if edited is None:
                return None
            line = f"{indent}{written}{equals}{edited}{ending}"
        else:
            if name not in tables:
                prefix[name] = indent + "".join(f"{_bare_or_quoted(part)}." for part in path[len(header or ()) : -1])
            scalar = _SCALAR.match(rest)
            if len(path) == 3 and path[2] in pending.get(name, {}) and scalar is not None:
                value = pending[name].pop(path[2])
                if _written_value(scalar.group(1)) != value:  # (one it already holds stays as written: "0.0")
                    line = f"{indent}{written}{equals}{_number(value)}{scalar.group(2) or ''}{ending}"
            last_at[name] = len(out)
        out.append(line)
    if set(last_at) | (set(values) - set(pending)) != set(values):
        return None
    for name, at in last_at.items():
        added = [
            f"{prefix[name]}{key} = {_number(value)}\n"
            for key, value in pending.get(name, {}).items()
            if _LEFT_OUT_AT.get(key) != value
        ]
        if added and not out[at].endswith("\n"):
            out[at] += "\n"
        out[at] += "".join(added)
    return JointsEdited("".join(out), tables_only=set(values) <= tables)


def dump_description(description: RobotDescription) -> str:
    """A complete TOML file for ``description`` (no comments), a key at its default left out, as a person leaves
    it out: the file stands in for one they wrote."""
    text = []
    if description.name is not None:
        text.append(f"name = {json.dumps(description.name)}\n")
    for line in description.lines.values():
        text.append(f"\n[lines.{json.dumps(line.name)}]\nport = {json.dumps(line.port)}\nbaudrate = {line.baudrate}\n")
        if not line.echo:
            text.append("echo = false\n")
        if line.rate_hz is not None:
            text.append(f"rate_hz = {_number(line.rate_hz)}\n")
        if line.retries:
            text.append(f"retries = {line.retries}\n")
        if line.direction != LineSpec.direction:
            text.append(f"direction = {json.dumps(line.direction)}\n")
    for joint in description.joints.values():
        text.append(f"\n[joints.{json.dumps(joint.name)}]\nline = {json.dumps(joint.line)}\nid = {joint.id}\n")
        if joint.offset:
            text.append(f"offset = {_number(joint.offset)}\n")
        if joint.reverse:
            text.append("reverse = true\n")
        # The limits by default: the servo's whole travel in this joint's degrees (as the file is read).
        travel = sorted((end - joint.offset) * joint.sign for end in (-SERVO_DEGREES, SERVO_DEGREES))
        for key, limit, default in (("min", joint.min, travel[0]), ("max", joint.max, travel[1])):
            if limit != default:
                text.append(f"{key} = {_number(limit)}\n")
    safety, defaults = description.safety, SafetySpec()
    kept = [
        f"action = {json.dumps(safety.action)}\n" if safety.action != defaults.action else "",
        f"max_temperature_c = {_number(safety.max_temperature_c)}\n" if safety.max_temperature_c is not None else "",
        f"max_current = {safety.max_current}\n" if safety.max_current is not None else "",
        "continue_on_offline = true\n" if safety.continue_on_offline else "",
        f"telemetry_per_cycle = {safety.telemetry_per_cycle}\n"
        if safety.telemetry_per_cycle != defaults.telemetry_per_cycle
        else "",
    ]
    if any(kept):
        text.append("\n[safety]\n" + "".join(kept))
    return "".join(text).lstrip("\n")


def _reads_back(text: str, before: str, source: str, values: Mapping[str, Mapping[str, float]]) -> bool:
    """``text`` reads as ``before`` (the robot file) with only the joints' ``values`` set (a key with the value
    :func:`edit_joint_values` leaves out left out), and as a robot file with them."""
    try:
        data, expected = tomllib.loads(text), tomllib.loads(before)
        again = parse_description(data, source)
    except (tomllib.TOMLDecodeError, ValueError):
        return False
    for name, keys in values.items():
        joint = expected.get("joints", {}).get(name)
        if not isinstance(joint, dict):  # (what the edit took for the joint was not it: inside a multi-line string)
            return False
        joint.update({key: value for key, value in keys.items() if key in joint or _LEFT_OUT_AT.get(key) != value})
    return data == expected and all(
        getattr(again.joints[name], key) == value for name, keys in values.items() for key, value in keys.items()
    )


@dataclass(frozen=True)
class CalibrationWritten:
    """Where :func:`write_calibration` put its result."""

    path: Path  # the file written: the robot file itself, or NAME.calibrated.toml beside it
    in_place: bool  # the robot file itself (False: NAME.calibrated.toml beside it, the robot file untouched)
    comments_kept: bool  # False: a complete new file, written beside the robot file
    backup: Path | None  # the previous content of ``path`` (None: there was no such file)


def write_calibration(
    path: str | Path, description: RobotDescription, joints: Mapping[str, JointSpec]
) -> CalibrationWritten:
    """Write the calibrated ``joints`` into the robot file, keeping its previous content as ``NAME.bak``; or,
    where a joint is not a ``[joints.NAME]`` table, beside it (``NAME.calibrated.toml``)."""
    target = Path(path)
    text = target.read_text(encoding="utf-8")
    bom = "\ufeff" if text.startswith("\ufeff") else ""  # (a Windows editor's byte order mark: kept as it was)
    text = text.removeprefix(bom)
    values = {name: {key: float(getattr(j, key)) for key in CALIBRATED_KEYS} for name, j in joints.items()}
    edited = edit_joint_values(text, values)
    if edited is not None and not _reads_back(edited.text, text, str(target), values):
        edited = None
    if edited is not None and edited.tables_only:
        return CalibrationWritten(target, True, True, replace_keeping_backup(target, bom + edited.text))
    beside = target.with_name(f"{target.stem}.calibrated.toml")
    if edited is not None:
        # The robot file with only the calibration changed, its comments and line endings kept: a diff against it
        # shows the calibration.  Beside it, not over it: the line edit of a [joints.NAME] table, one key a line,
        # is the only one calibrate makes in the person's own file.
        written = replace_keeping_backup(beside, bom + edited.text, like=target)
        return CalibrationWritten(beside, False, True, written)
    whole = replace(description, joints={**description.joints, **joints})
    return CalibrationWritten(beside, False, False, replace_keeping_backup(beside, dump_description(whole)))


def reverse_note(source: str, joint: JointSpec, line: LineSpec, eeprom: Eeprom) -> str | None:
    """What to check, in words, when ``joint`` is reversed both in the file and by its servo's EEPROM REVERSE flag
    (``line``: the joint's line, for the command that clears the flag); None otherwise.

    For calibration, where a joint's direction is set up: the two cancel out, so the joint turns as its servo
    would with neither, most often a mix-up of two ways of reversing it.  Not a fault: a robot calibrated
    so turns as it was calibrated, and removing either one mirrors the joint (its offset and limits with it),
    so the note says to calibrate again then; it is not said at every open, where it would be noise for a
    robot set up so on purpose."""
    if not (joint.reverse and eeprom.flags & Flags.REVERSE):
        return None
    options = ["--port", line.port]
    if line.baudrate != LineSpec.baudrate:
        options += ["--baud", str(line.baudrate)]
    if not line.echo:
        options.append("--no-echo")
    if line.direction != LineSpec.direction:
        options += ["--direction", line.direction]
    clear = shlex.join(["ics35", *options, "eeprom", "set", str(joint.id), "flags-=REVERSE"])
    return (
        f"{source}: joints.{joint.name}: reverse = true in the file, and servo ID {joint.id} on line {joint.line} "
        "has its EEPROM REVERSE flag set too: the two cancel out, so the joint turns as its servo would with "
        "neither. If it turns the way you want, nothing to do. To keep one of them, remove reverse = true from "
        f"joints.{joint.name} or, with calibrate stopped, clear the flag ({clear}); either mirrors the joint, its "
        "offset and limits with it, so calibrate it again before any motion"
    )
