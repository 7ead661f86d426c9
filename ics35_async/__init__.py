"""ics35_async: drive Kondo ICS 3.5 serial servos from async code.

Importing the package loads no simulator: ``sim://`` ports and the
``ics35_async.sim`` attribute import it on first use.
"""

from __future__ import annotations

import importlib
from types import ModuleType

from .bus import Bus, BusTiming, Priority, open_bus
from .eeprom import BaudRate, Eeprom, Flags
from .errors import (
    BadReply,
    BusClosed,
    EchoMismatch,
    IcsError,
    InvalidArgument,
    MalformedEeprom,
    ParityNotSupported,
    PartialReply,
    PortBusy,
    PortLost,
    PortNotFound,
    PortPermissionDenied,
    ReplyDataError,
    ReplyError,
    ReplyHeaderError,
    ReplyLengthError,
    ReplySubcommandError,
    ReplyTimeout,
    ReplyValueError,
    SerialPortError,
    UnsafeOperation,
    VerifyError,
)
from .frames import Frame, GroupFrame, StreamStats
from .group import BusGroup, GroupStream
from .protocol import Param
from .robot import Robot, RobotStream, SafetyStop, open_robot
from .servo import Device, Servo
from .stream import Stream

__version__ = "0.1.0"


def __getattr__(name: str) -> ModuleType:
    # `ics35_async.sim` without importing it first: loaded on first use, never at import.
    if name == "sim":
        return importlib.import_module(".sim", __name__)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "BadReply",
    "BaudRate",
    "Bus",
    "BusClosed",
    "BusGroup",
    "BusTiming",
    "Device",
    "Frame",
    "GroupFrame",
    "GroupStream",
    "Priority",
    "Robot",
    "RobotStream",
    "SafetyStop",
    "Servo",
    "Stream",
    "StreamStats",
    "open_bus",
    "open_robot",
    "EchoMismatch",
    "Eeprom",
    "Flags",
    "IcsError",
    "InvalidArgument",
    "MalformedEeprom",
    "Param",
    "ParityNotSupported",
    "PortBusy",
    "PortNotFound",
    "PortPermissionDenied",
    "SerialPortError",
    "PartialReply",
    "PortLost",
    "ReplyDataError",
    "ReplyError",
    "ReplyHeaderError",
    "ReplyLengthError",
    "ReplySubcommandError",
    "ReplyTimeout",
    "ReplyValueError",
    "UnsafeOperation",
    "VerifyError",
    "__version__",
]
