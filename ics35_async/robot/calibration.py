"""Calibration results written back into the robot file, comments kept where the file's shape allows.

:func:`calibrate_joint` turns what a person showed by hand (the servo angle
at the joint's neutral, and the extremes it was moved to) into ``offset``,
``min`` and ``max``.  :func:`write_calibration` edits the ``offset`` /
``min`` / ``max`` lines of each ``[joints.NAME]`` table in place, keeping
every comment and every other line; when a joint is not written as such a
table (an inline table, a dotted key) or the edit would not read back as
intended, it writes a complete new file beside the original instead
(``NAME.calibrated.toml``; comments are lost there) and says so.  A file it
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
from .description import COUNT_DECIMALS, SERVO_DEGREES, JointSpec, LineSpec, RobotDescription, parse_description

CALIBRATED_KEYS = ("offset", "min", "max")
# Keys not added to a joint's table that lacks them when their value is this: the file reads the same without
# them.  (Not min or max: their defaults follow the offset.)
_LEFT_OUT_AT = {"offset": 0.0}
_HEADER = re.compile(r"^\s*\[\s*([^\[\]]+?)\s*\]\s*(#.*)?$")
_KEY = re.compile(r"^(\s*)([A-Za-z0-9_-]+)(\s*=\s*)([^#]*?)(\s*#.*)?$")


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
    ends = sorted(((s - offset) * joint.sign) for s in (low, high))
    lo = math.ceil(round(ends[0] * 10, 6)) / 10
    hi = math.floor(round(ends[1] * 10, 6)) / 10
    # Within the servo's travel whatever the rounding did.
    bound = sorted(((e - offset) * joint.sign) for e in (-SERVO_DEGREES, SERVO_DEGREES))
    lo, hi = max(lo, bound[0]), min(hi, bound[1])
    if hi - lo < MIN_RANGE_DEGREES:
        raise NarrowRange(joint.name, max(0.0, high - low))
    return replace(joint, offset=offset, min=lo, max=hi)


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


def _header_joint(header: str) -> str | None:
    parts = header.split(".", 1)
    if len(parts) != 2 or parts[0].strip() != "joints":
        return None
    name = parts[1].strip()
    if len(name) >= 2 and name[0] == name[-1] and name[0] in "\"'":
        name = name[1:-1]
    return name


def edit_joint_values(text: str, values: Mapping[str, Mapping[str, float]]) -> str | None:
    """``text`` with the given keys of each ``[joints.NAME]`` table set; None if a joint has no such table.

    A key the table lacks is added after its last key, but for an ``offset`` of 0 (the file reads the same
    without it); a key it has is updated, unless it already holds that value (its line is then left as it is
    written, so a diff against the old file shows only what changed).
    """
    lines = text.splitlines(keepends=True)
    out: list[str] = []
    current: str | None = None
    pending: dict[str, float] = {}
    last_key_at = -1
    found: set[str] = set()

    def close_table() -> None:
        # Keys the table did not have go after its last key line.
        nonlocal pending
        added = [f"{key} = {_number(value)}\n" for key, value in pending.items() if _LEFT_OUT_AT.get(key) != value]
        if added:
            at = last_key_at + 1 if last_key_at >= 0 else len(out)
            if at > 0 and not out[at - 1].endswith("\n"):
                out[at - 1] += "\n"
            out[at:at] = added
        pending = {}

    for line in lines:
        header = _HEADER.match(line)
        if header and not line.lstrip().startswith("[["):
            close_table()
            current = _header_joint(header.group(1))
            if current is not None and current in values:
                found.add(current)
                pending = dict(values[current])
                last_key_at = len(out)
            else:
                current = None
            out.append(line)
            continue
        if current is not None:
            match = _KEY.match(line.rstrip("\r\n"))
            if match and match.group(2) in pending:
                ending = line[len(line.rstrip("\r\n")) :]
                indent, key, equals, old, comment = match.groups()
                value = pending.pop(key)
                if _written_value(old) != value:  # (one it already holds stays as written: "0.0", "+60")
                    line = f"{indent}{key}{equals}{_number(value)}{comment or ''}{ending}"
            if match:
                last_key_at = len(out)
        out.append(line)
    close_table()
    if found != set(values):
        return None
    return "".join(out)


def dump_description(description: RobotDescription) -> str:
    """A complete TOML file for ``description`` (no comments)."""
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
        text.append(f"offset = {_number(joint.offset)}\nreverse = {'true' if joint.reverse else 'false'}\n")
        text.append(f"min = {_number(joint.min)}\nmax = {_number(joint.max)}\n")
    safety = description.safety
    text.append(f"\n[safety]\naction = {json.dumps(safety.action)}\n")
    if safety.max_temperature_c is not None:
        text.append(f"max_temperature_c = {_number(safety.max_temperature_c)}\n")
    if safety.max_current is not None:
        text.append(f"max_current = {safety.max_current}\n")
    text.append(f"continue_on_offline = {'true' if safety.continue_on_offline else 'false'}\n")
    text.append(f"telemetry_per_cycle = {safety.telemetry_per_cycle}\n")
    return "".join(text).lstrip("\n")


def _reads_back(text: str, source: str, joints: Mapping[str, JointSpec]) -> bool:
    try:
        again = parse_description(tomllib.loads(text), source)
    except (tomllib.TOMLDecodeError, ValueError):
        return False
    return all(again.joints.get(name) == joint for name, joint in joints.items())


@dataclass(frozen=True)
class CalibrationWritten:
    """Where :func:`write_calibration` put its result."""

    path: Path  # the file written: the robot file itself, or NAME.calibrated.toml beside it
    comments_kept: bool  # False: a complete new file, written beside the robot file
    backup: Path | None  # the previous content of ``path`` (None: there was no such file)


def write_calibration(
    path: str | Path, description: RobotDescription, joints: Mapping[str, JointSpec]
) -> CalibrationWritten:
    """Write the calibrated ``joints`` into the robot file, keeping its previous content as ``NAME.bak``."""
    target = Path(path)
    text = target.read_text(encoding="utf-8")
    bom = "\ufeff" if text.startswith("\ufeff") else ""  # (a Windows editor's byte order mark: kept as it was)
    values = {name: {key: float(getattr(j, key)) for key in CALIBRATED_KEYS} for name, j in joints.items()}
    edited = edit_joint_values(text.removeprefix(bom), values)
    if edited is not None and _reads_back(edited, str(target), joints):
        return CalibrationWritten(target, True, replace_keeping_backup(target, bom + edited))
    beside = target.with_name(f"{target.stem}.calibrated.toml")
    whole = replace(description, joints={**description.joints, **joints})
    return CalibrationWritten(beside, False, replace_keeping_backup(beside, dump_description(whole)))


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
