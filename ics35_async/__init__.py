"""ics35_async: drive Kondo ICS 3.5 serial servos from async code.

Importing the package is cheap: the bus, streams and groups load when first
named (``from ics35_async import open_bus``), the event-loop drivers when a
line opens, and the simulator only for ``sim://`` ports or ``ics35_async.sim``.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from .eeprom import BaudRate, Eeprom, Flags
from .errors import (
    BadReply,
    BusClosed,
    ClosedByPortLoss,
    DirectionControlNotSupported,
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
    PositionReadUnsupported,
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
from .protocol import Param

if TYPE_CHECKING:
    from . import sim as sim
    from .bus import Bus, BusOptions, BusTiming, Priority, RequestHandle, State, open_bus
    from .frames import Frame, GroupFrame, LiveReadings, StreamStats
    from .group import BusGroup, GroupStream
    from .line import Line
    from .robot import Robot, RobotStream, SafetyStop, open_robot
    from .running import run
    from .servo import Device, Servo
    from .stream import LineStreamOptions, Stream, StreamOptions

__version__ = "0.1.0"  # the one place the version is written (pyproject.toml reads it)

# Loaded on first use: name -> module (relative to this package).
_LAZY = {
    "Bus": ".bus",
    "BusOptions": ".bus",
    "BusTiming": ".bus",
    "Priority": ".bus",
    "RequestHandle": ".bus",
    "State": ".bus",
    "open_bus": ".bus",
    "Frame": ".frames",
    "GroupFrame": ".frames",
    "LiveReadings": ".frames",
    "StreamStats": ".frames",
    "BusGroup": ".group",
    "GroupStream": ".group",
    "Line": ".line",
    "Device": ".servo",
    "Servo": ".servo",
    "Stream": ".stream",
    "LineStreamOptions": ".stream",
    "StreamOptions": ".stream",
    "Robot": ".robot",
    "RobotStream": ".robot",
    "SafetyStop": ".robot",
    "open_robot": ".robot",
    "run": ".running",
}


def __getattr__(name: str) -> Any:
    if name == "sim":
        return importlib.import_module(".sim", __name__)
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(module, __name__), name)
    globals()[name] = value  # once: later lookups are plain attribute reads
    return value


__all__ = [
    "BadReply",
    "BaudRate",
    "Bus",
    "BusClosed",
    "BusGroup",
    "BusOptions",
    "BusTiming",
    "ClosedByPortLoss",
    "DirectionControlNotSupported",
    "Device",
    "Frame",
    "GroupFrame",
    "GroupStream",
    "Line",
    "LineStreamOptions",
    "LiveReadings",
    "Priority",
    "RequestHandle",
    "Robot",
    "RobotStream",
    "SafetyStop",
    "Servo",
    "State",
    "Stream",
    "StreamOptions",
    "StreamStats",
    "open_bus",
    "open_robot",
    "run",
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
    "PositionReadUnsupported",
    "ReplyTimeout",
    "ReplyValueError",
    "UnsafeOperation",
    "VerifyError",
    "__version__",
]
