"""Robots: named joints in degrees over one or more ICS lines, smooth motions, motion files, a safety watch.

* :mod:`.description`: the TOML robot description, checked key by key;
* :mod:`.profiles`: motion profiles (``minjerk``, ``linear``) and trajectories;
* :mod:`.host`: what motions and the joint-space stream need from the robot (a small protocol);
* :mod:`.frame`: what the robot's stream publishes, every line's newest cycle in joint degrees;
* :mod:`.joint_stream`: frames and targets in joint space;
* :mod:`.safety`: the temperature / current / offline watch and :class:`SafetyStop`;
* :mod:`.plans`: the running motions' bookkeeping;
* :mod:`.robot`: :class:`Robot`, streaming to every joint while it is open;
* :mod:`.startup`: :func:`open_robot`;
* :mod:`.motion`: the keyframe motion file format and playing it;
* :mod:`.calibration`: calibration results written back into the robot file, its comments kept.
"""

from __future__ import annotations

from .description import (
    DescriptionError,
    JointSpec,
    LineSpec,
    RobotDescription,
    SafetySpec,
    load_description,
    parse_description,
)
from .frame import RobotFrame
from .joint_stream import RobotStream
from .motion import Keyframe, Motion, MotionError, load_motion, parse_motion, save_motion
from .profiles import PROFILES, Segment, Trajectory
from .robot import Robot
from .safety import JointTelemetry, MotionStopped, SafetyStop, UnsettledReadings
from .startup import RobotBlock, RobotOptions, RobotWarning, check_servo_limits, open_robot

__all__ = [
    "PROFILES",
    "DescriptionError",
    "JointSpec",
    "JointTelemetry",
    "Keyframe",
    "LineSpec",
    "Motion",
    "MotionError",
    "MotionStopped",
    "Robot",
    "RobotBlock",
    "RobotDescription",
    "RobotFrame",
    "RobotOptions",
    "RobotStream",
    "RobotWarning",
    "SafetySpec",
    "SafetyStop",
    "Segment",
    "Trajectory",
    "UnsettledReadings",
    "check_servo_limits",
    "load_description",
    "load_motion",
    "open_robot",
    "parse_description",
    "parse_motion",
    "save_motion",
]
