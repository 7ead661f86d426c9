"""``--start-pose`` (``ics35 play``, ``ics35 web --robot``): where the robot stands, so its joints hold
there from the first command instead of going limp (ICS 3.5 servos are read by freeing them).

Its own module: ``ics35 web`` declares the option without importing the robot's modules.
"""

from __future__ import annotations

import json
from pathlib import Path

import click

from ..user_files import UnreadableText, parse_json, read_user_text

start_pose_option = click.option(
    "--start-pose",
    "start_pose_text",
    metavar="POSE",
    default=None,
    help="Where the robot is now (joint=deg,... or a JSON file): those joints hold it from the first "
    "command instead of going limp (ICS 3.5 servos are read by freeing them).",
)


def parse_start_pose(text: str | None) -> dict[str, float] | None:
    """``joint=deg,joint=deg`` or a JSON file ``{joint: degrees}`` (the joints' names and limits are checked
    when the robot opens, before any port is)."""
    if text is None:
        return None
    if not text.strip():
        raise click.BadParameter("is empty: give joint=degrees,... or a JSON file", param_hint="--start-pose")
    if "=" not in text:
        try:
            data = parse_json(read_user_text(text, "a start pose is UTF-8 JSON"))
        except (UnreadableText, json.JSONDecodeError) as exc:
            # A file that is there: what is wrong with it (not which of the two forms it was taken for).
            if not Path(text).exists():
                why = f"neither joint=degrees,... nor a readable JSON file {{joint: degrees}} ({exc})"
            elif isinstance(exc, json.JSONDecodeError):
                why = f"not valid JSON ({exc}); a start pose is {{joint: degrees}}"
            else:
                why = str(exc)
            raise click.BadParameter(f"{text}: {why}", param_hint="--start-pose") from None
        from ..robot.motion import FORMAT as MOTION_FORMAT  # (here: `ics35 web` imports this module up front)

        if isinstance(data, dict) and ("keyframes" in data or data.get("format") == MOTION_FORMAT):
            # (the motion given twice, or for the pose: its keyframes are where it goes, not where it starts)
            raise click.BadParameter(
                f"{text}: is a motion, not a pose: a start pose is where the robot stands now, "
                "a JSON object {joint: degrees} or joint=degrees,...",
                param_hint="--start-pose",
            )
        if not isinstance(data, dict) or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in data.values()
        ):
            raise click.BadParameter(f"{text}: must hold a JSON object {{joint: degrees}}", param_hint="--start-pose")
        return {str(k): float(v) for k, v in data.items()}
    pose = {}
    for item in text.split(","):
        joint, _, deg = item.partition("=")
        if joint.strip() in pose:  # two angles for one joint: a typo for another joint, likely
            raise click.BadParameter(f"{joint.strip()} given twice", param_hint="--start-pose")
        try:
            pose[joint.strip()] = float(deg)
        except ValueError:
            raise click.BadParameter(
                f"{item!r} is not joint=degrees (e.g. knee=30,hip=-10)", param_hint="--start-pose"
            ) from None
    return pose
