"""ics35 check ROBOT.toml [MOTION.json]...: a robot file, and motions against it, checked with no port opened.

What ``play``, ``teach`` and ``calibrate`` check before they open anything (the library's
``load_description`` and ``check_motion``), on its own: for editing a robot file away from the robot, or
before the first power-up, with what the file says written out (the lines, each joint's servo and limits,
what a safety trip does).
"""

from __future__ import annotations

import os
import sys
from typing import Any, TypeVar

import click
from rich.markup import escape
from rich.table import Table

from ..robot import Motion, RobotDescription
from ..robot.description import JointSpec, SafetySpec
from ..transports.wire_device import url_scheme
from ..units import shown
from ._common import CliError, ExitCode, emit_json, ids_named, json_option, out
from ._console import printed_table, say, say_error
from ._robot_common import MOTION_FILE_PROBLEMS, MotionFileError, load_motion_file, load_robot_file

Refused = TypeVar("Refused", bound=CliError)

# The column of the joint table a terminal too narrow for it goes without: each line's IDs are named above it.
LEAVE_OUT = ("line",)
LEAVE_OUT_LAST = ("reverse",)  # (once the names are at their narrowest: see FittedTable)

# What a safety trip does, by [safety] action (see the robot-files page).
TRIP_DOES = {
    "free": "the joint that tripped goes free, the others keep their last targets",
    "hold": "every joint keeps its last target",
    "stop": "every joint goes free",
}


def _plural(count: int, word: str) -> str:
    return f"{count} {word}{'' if count == 1 else 's'}"


def _whole_travel(joint: JointSpec) -> bool:
    """Limits at the servo's whole travel because the file gives none (never calibrated?): one calibrated on a
    joint that turns the servo's whole way states them."""
    return not joint.limits_given


def safety_text(safety: SafetySpec) -> str:
    """What trips the robot's safety watch and what a trip does, in words."""
    crossings = []
    if safety.max_temperature_c is not None:
        crossings.append(f"above {shown(safety.max_temperature_c)} °C (approximate)")
    if safety.max_current is not None:
        crossings.append(f"a current reading above {safety.max_current}")
    if not safety.continue_on_offline:
        crossings.append("a servo going offline")
    if not crossings:
        return "safety: no limit set, and a motion plays on without a servo gone offline"
    return f"safety: {', or '.join(crossings)}: motions end and {TRIP_DOES[safety.action]} (action = {safety.action})"


def robot_json(description: RobotDescription) -> dict[str, Any]:
    safety = description.safety
    return {
        "file": description.source,
        "name": description.name,
        "lines": [
            {"name": line.name, "port": line.port, "baudrate": line.baudrate, "rate_hz": line.rate_hz}
            for line in description.lines.values()
        ],
        "joints": [
            {
                "name": joint.name,
                "line": joint.line,
                "id": joint.id,
                "reverse": joint.reverse,
                "offset": joint.offset,
                "min": joint.min,
                "max": joint.max,
            }
            for joint in description.joints.values()
        ],
        "safety": {
            "max_temperature_c": safety.max_temperature_c,
            "max_current": safety.max_current,
            "action": safety.action,
            "continue_on_offline": safety.continue_on_offline,
        },
        "whole_travel": [joint.name for joint in description.joints.values() if _whole_travel(joint)],
    }


def motion_json(path: str, motion: Motion | MotionFileError) -> dict[str, Any]:
    if isinstance(motion, MotionFileError):
        # (a motion not read is not known not to fit: null, not false)
        fits = False if motion.problem == "does not fit" else None
        return {"file": path, "fits": fits, "problem": motion.problem, "error": motion.message}
    return {
        "file": path,
        "fits": True,
        "keyframes": len(motion.keyframes),
        "duration_s": motion.duration,
        "joints": motion.joints,
    }


def show_robot(path: str, description: RobotDescription) -> None:
    lines, joints = description.lines, description.joints
    called = f"robot {escape(description.name)}, " if description.name else ""
    counts = f"{_plural(len(lines), 'line')}, {_plural(len(joints), 'joint')}"
    say(f"{escape(path)}: {called}{counts} (no port opened)", to=out)
    for line in lines.values():
        rate = f"{shown(line.rate_hz)} cycles/s" if line.rate_hz is not None else "as fast as the line goes"
        ids = ids_named(joint.id for joint in description.joints_on(line.name))
        # (a device path: whether it is there now, so that a mistyped one is seen before play; no port is opened.
        # Not on Windows, whose ports, COM3, are no paths.)
        device = not url_scheme(line.port) and sys.platform != "win32"
        absent = " (not there now)" if device and not os.path.exists(line.port) else ""
        say(f"  line {escape(line.name)}: {escape(line.port)}{absent} at {line.baudrate} baud, {rate}, {ids}", to=out)
    # (no value wraps: a terminal too narrow leaves the line out, then wraps the names: see FittedTable)
    table = Table(box=None, pad_edge=False)
    for heading in ("joint", "line", "ID", "reverse"):
        table.add_column(heading, no_wrap=True)
    for heading in ("offset°", "min°", "max°"):  # (numbers to the right: their rows end where the table does)
        table.add_column(heading, justify="right", no_wrap=True)
    for joint in joints.values():
        table.add_row(
            escape(joint.name),
            escape(joint.line),
            str(joint.id),
            "reversed" if joint.reverse else "",
            shown(joint.offset),
            shown(joint.min),
            shown(joint.max),
        )
    out.print(printed_table(table, LEAVE_OUT, indent=2, last=LEAVE_OUT_LAST))
    whole = [joint.name for joint in joints.values() if _whole_travel(joint)]
    if whole:
        say(
            f"  {escape(', '.join(whole))}: {'its limits are' if len(whole) == 1 else 'their limits are each'} the "
            "servo's whole travel (no min or max in the file: ics35 calibrate finds a joint's own)",
            to=out,
        )
    say(f"  {safety_text(description.safety)}", to=out)


@click.command()
@click.argument("robot_file", metavar="ROBOT.toml")
@click.argument("motion_files", metavar="[MOTION.json]...", nargs=-1)
@json_option
def check(robot_file: str, motion_files: tuple[str, ...], as_json: bool) -> int:
    """Check a robot file, and motions against it, with no port opened.

    \b
    ics35 check robot.toml                 its lines, joints, limits and safety, written out
    ics35 check robot.toml wave.json ...   and each motion: its joints known, every angle within limits

    What play, teach and calibrate check before they open anything; a file that breaks a rule is named with
    its key (exit code 2), then each motion refused: not found, not readable, not a motion file, or not fitting
    the robot.
    """
    try:
        description = load_robot_file(robot_file)
    except CliError as exc:
        error = _said_of_check(exc)
        if as_json:  # (the motions are not checked against a robot file that breaks a rule)
            emit_json({"robot": None, "error": error.message, "motions": []})
        raise error from None
    # Every motion, each on its own: checking the motions taught before a calibration wants each one's verdict.
    checked: list[tuple[str, Motion | MotionFileError]] = []
    for path in motion_files:
        try:
            checked.append((path, load_motion_file(path, description)))
        except MotionFileError as exc:
            checked.append((path, _said_of_check(exc)))
    refused = [error.problem for _, error in checked if isinstance(error, MotionFileError)]
    if as_json:
        emit_json({"robot": robot_json(description), "motions": [motion_json(p, m) for p, m in checked]})
    else:
        show_robot(robot_file, description)
        for path, motion in checked:
            if isinstance(motion, MotionFileError):
                if len(checked) > 1:  # (one alone is said last, as the verdict)
                    say_error(motion)
                continue
            moves = ", ".join(motion.joints)
            say(
                f"{escape(path)}: {_plural(len(motion.keyframes), 'keyframe')}, {shown(motion.duration)} s, "
                f"moves {escape(moves)}: fits the robot",
                to=out,
            )
    if not refused:
        return 0
    only = checked[0][1]
    if len(checked) == 1 and isinstance(only, MotionFileError):
        raise only  # its own error is the verdict: "1 of 1 motion was not found" would say it again
    raise CliError(
        ExitCode.USAGE, f"{len(refused)} of {_plural(len(checked), 'motion')}{_refused_text(refused, robot_file)}"
    )


# What is wrong with the motions check refused, by MotionFileError.problem: said of one, of several.
_PROBLEM_SAID = {
    "not found": ("was not found", "were not found"),
    "not readable": ("is not readable", "are not readable"),
    "not a motion file": ("is not a motion file", "are not motion files"),
    "does not fit": ("does not fit {robot}", "do not fit {robot}"),
}


def _refused_text(problems: list[str], robot_file: str) -> str:
    """What follows "2 of 5 motions" in check's closing error: " do not fit arm.toml" when all of them share a
    problem, else ": 1 was not found and 1 does not fit arm.toml", a count for each."""
    counts = {problem: problems.count(problem) for problem in MOTION_FILE_PROBLEMS if problem in problems}
    said = [
        f"{count} {_PROBLEM_SAID[problem][count != 1].format(robot=robot_file)}" for problem, count in counts.items()
    ]
    if len(said) == 1:
        return " " + said[0].split(" ", 1)[1]
    return ": " + ", ".join(said[:-1]) + f" and {said[-1]}"


def _said_of_check(error: Refused) -> Refused:
    """``error`` of a file check, said for ``check``: the loaders, shared with the commands that send once their
    files are read, end it with "(nothing was sent)", and check never sends anything."""
    error.message = error.message.removesuffix(" (nothing was sent)")
    return error


COMMANDS = [check]
