"""The robot tests' rig: two simulated lines, a description over them, and the log read back.

The simulator's transaction log is the ground truth: every position command
the robot sent is decoded from the bytes on the wire, never taken from the
robot's own bookkeeping.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ics35_async import units
from ics35_async.protocol import FREE
from ics35_async.sim import VirtualLine, VirtualServo

_names = itertools.count()


@dataclass
class Rig:
    """Two named simulated lines ("upper": IDs 1-3, "lower": IDs 1-2) and a description using them."""

    upper: VirtualLine
    lower: VirtualLine
    description: dict[str, Any]

    def sim(self, line: str) -> VirtualLine:
        return self.upper if line == "upper" else self.lower

    def servo(self, joint: str) -> VirtualServo:
        spec = self.description["joints"][joint]
        return self.sim(spec["line"]).servo(spec["id"])

    def close(self) -> None:
        self.upper.close()
        self.lower.close()


JOINTS: dict[str, dict[str, Any]] = {
    # offset and reverse both ways, narrow and wide limits, on two lines with the same IDs.
    "neck": {"line": "upper", "id": 1, "offset": 10.0, "min": -60.0, "max": 60.0},
    "shoulder": {"line": "upper", "id": 2, "reverse": True, "min": -90.0, "max": 45.0},
    "elbow": {"line": "upper", "id": 3, "offset": -20.0, "reverse": True, "min": 0.0, "max": 110.0},
    "hip": {"line": "lower", "id": 1, "min": -30.0, "max": 30.0},
    "knee": {"line": "lower", "id": 2, "offset": 5.5, "min": -100.0, "max": 20.0},
}


# The rig's IDs, for ``make_rig(ics36=ALL_ICS36)``: every servo speaks ICS 3.6.  For a test at the NO_TIMEOUTS
# allowance that is not about ICS 3.5 joints: the open reads an ICS 3.5 joint once more with the whole allowance
# before it starts free (two seconds each, a line's joints one after the other), where an ICS 3.6 servo answers
# its position read at once.
ALL_ICS36 = (1, 2, 3)


EXAMPLE_HUMANOID = Path(__file__).resolve().parents[2] / "examples" / "humanoid.toml"


def ics36_humanoid(folder: Path) -> Path:
    """The example humanoid with every servo of its simulated lines speaking ICS 3.6 (see ``ALL_ICS36``), written
    into ``folder``: for a test at the NO_TIMEOUTS allowance that is about the robot, not its ICS 3.5 joints."""
    text = EXAMPLE_HUMANOID.read_text(encoding="utf-8")
    for ids in ("1-7", "1-10"):
        assert f"ids={ids}&" in text, f"{EXAMPLE_HUMANOID}: its lines are no longer ids={ids}"
        text = text.replace(f"ids={ids}&", f"ids={ids}&ics36={ids}&")
    path = folder / EXAMPLE_HUMANOID.name
    path.write_text(text, encoding="utf-8")
    return path


def make_rig(safety: dict[str, Any] | None = None, **line_options: Any) -> Rig:
    n = next(_names)
    line_options.setdefault("log_size", None)
    upper = VirtualLine([1, 2, 3], name=f"robot-upper-{n}", **line_options)
    lower = VirtualLine([1, 2], name=f"robot-lower-{n}", **_options_for([1, 2], line_options))
    # At its neutral the elbow's servo stands 20 degrees past the joint's lower limit (offset -20, reversed): a
    # robot refuses to move or hold a free joint so far out (it would throw it to the limit), so it starts within.
    upper.servo(3).move_by_hand(joint_position(JOINTS["elbow"], 10.0))
    description: dict[str, Any] = {
        "lines": {"upper": {"port": f"sim://robot-upper-{n}"}, "lower": {"port": f"sim://robot-lower-{n}"}},
        "joints": {name: dict(spec) for name, spec in JOINTS.items()},
    }
    if safety is not None:
        description["safety"] = safety
    return Rig(upper, lower, description)


def _options_for(ids: list[int], line_options: dict[str, Any]) -> dict[str, Any]:
    """``line_options`` with the IDs it names of servos (``ics36``, ``noisy``) cut to ``ids``: a line refuses an ID
    no servo of it is built from, and the rig's options go to both lines."""
    return {
        key: [i for i in value if i in ids] if key in ("ics36", "noisy") else value
        for key, value in line_options.items()
    }


def joint_degrees(spec: dict[str, Any], position: int) -> float:
    sign = -1 if spec.get("reverse") else 1
    return (units.position_to_degrees(position) - float(spec.get("offset", 0.0))) * sign


def joint_position(spec: dict[str, Any], degrees: float) -> int:
    sign = -1 if spec.get("reverse") else 1
    return units.degrees_to_position(spec.get("offset", 0.0) + sign * degrees)


def sent_position(spec: dict[str, Any], degrees: float) -> int:
    """The count a command for ``degrees`` goes out as: the nearest one within the joint's limits (the
    nearest overall may lie half a count past a limit)."""
    nearest = joint_position(spec, degrees)
    low, high = spec.get("min", -135.0), spec.get("max", 135.0)
    for candidate in (nearest, nearest - 1, nearest + 1):
        if low - 1e-9 <= joint_degrees(spec, candidate) <= high + 1e-9:
            return candidate
    return nearest


def commanded(sim: VirtualLine, servo_id: int, since: int = 0) -> Iterator[int]:
    """Every position target sent to ``servo_id`` (log seq >= ``since``), decoded from the wire bytes; 0 is free."""
    for t in sim.log_since(since):
        if t.command in ("position", "free") and t.servo_id == servo_id:
            yield (t.tx[1] << 7) | t.tx[2]


def targets_sent(sim: VirtualLine, servo_id: int, since: int = 0) -> list[int]:
    """The non-free position targets sent to ``servo_id``."""
    return [p for p in commanded(sim, servo_id, since) if p != FREE]
