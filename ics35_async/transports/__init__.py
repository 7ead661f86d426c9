"""Ports and transports: how bytes reach the line (serial ports, pyserial URLs, in-process devices)."""

from ..errors import (
    DirectionControlNotSupported,
    ParityNotSupported,
    PortBusy,
    PortNotFound,
    PortPermissionDenied,
    SerialPortError,
)
from .advice import adapter_advice
from .direct import DirectSerialTransport, ParityMarks
from .direction import DIRECTIONS, check_direction
from .in_process import HostSide, InProcessTransport, WireDevice, WireDeviceFactory, register_url_scheme
from .links import carries_line_settings, rate_blind_note
from .opening import TRANSPORT_KINDS, TransportKind, discard_input, open_line
from .threaded import ThreadedSerialDevice

__all__ = [
    "DIRECTIONS",
    "DirectionControlNotSupported",
    "TRANSPORT_KINDS",
    "DirectSerialTransport",
    "HostSide",
    "InProcessTransport",
    "ParityMarks",
    "ParityNotSupported",
    "PortBusy",
    "PortNotFound",
    "PortPermissionDenied",
    "SerialPortError",
    "ThreadedSerialDevice",
    "TransportKind",
    "WireDevice",
    "WireDeviceFactory",
    "adapter_advice",
    "carries_line_settings",
    "check_direction",
    "discard_input",
    "open_line",
    "rate_blind_note",
    "register_url_scheme",
]
