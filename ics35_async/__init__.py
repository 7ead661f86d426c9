"""ics35_async: drive Kondo ICS 3.5 serial servos from asyncio code."""

from __future__ import annotations

from . import sim as sim  # importing the simulator registers the sim:// URL scheme
from .bus import Bus, BusTiming, Priority, open_bus
from .eeprom import BaudRate, Eeprom, Flags
from .errors import (
    BadReply,
    BusClosed,
    EchoMismatch,
    IcsError,
    InvalidArgument,
    MalformedEeprom,
    PartialReply,
    PortLost,
    ReplyDataError,
    ReplyError,
    ReplyHeaderError,
    ReplyLengthError,
    ReplySubcommandError,
    ReplyTimeout,
    ReplyValueError,
    UnsafeOperation,
    VerifyError,
)
from .protocol import Param
from .servo import Device, Servo
from .streaming import BusGroup, Frame, GroupFrame, GroupStream, Stream, StreamStats
from .transport import ParityNotSupported, PortBusy, PortNotFound, PortPermissionDenied, SerialPortError

__version__ = "0.1.0"

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
    "Servo",
    "Stream",
    "StreamStats",
    "open_bus",
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
