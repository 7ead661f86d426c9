"""Ports and transports: how bytes reach the line (serial ports, pyserial URLs, in-process devices).

The names that need asyncio or pyserial load on first use, so that importing
the library (and the bus) stays cheap.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from ..errors import (
    DirectionControlNotSupported,
    ParityNotSupported,
    PortBusy,
    PortNotFound,
    PortPermissionDenied,
    SerialPortError,
)
from .wire_device import (
    TRANSPORT_KINDS,
    HostSide,
    TransportKind,
    WireDevice,
    WireDeviceFactory,
    device_factory,
    register_url_scheme,
    url_scheme,
)

if TYPE_CHECKING:
    from .advice import adapter_advice
    from .device_port import DevicePort
    from .direction import DIRECTIONS, check_direction
    from .links import carries_line_settings, rate_blind_note, same_port
    from .opening import Port, open_port
    from .pyserial_port import ReaderThread, SerialPort
    from .tty_port import ParityMarks, TtyPort

_LAZY = {
    "adapter_advice": ".advice",
    "DevicePort": ".device_port",
    "DIRECTIONS": ".direction",
    "check_direction": ".direction",
    "carries_line_settings": ".links",
    "same_port": ".links",
    "rate_blind_note": ".links",
    "Port": ".opening",
    "open_port": ".opening",
    "ReaderThread": ".pyserial_port",
    "SerialPort": ".pyserial_port",
    "ParityMarks": ".tty_port",
    "TtyPort": ".tty_port",
}


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(module, __name__), name)


__all__ = [
    "DIRECTIONS",
    "DirectionControlNotSupported",
    "TRANSPORT_KINDS",
    "DevicePort",
    "HostSide",
    "ParityMarks",
    "ParityNotSupported",
    "PortBusy",
    "PortNotFound",
    "PortPermissionDenied",
    "Port",
    "ReaderThread",
    "SerialPort",
    "SerialPortError",
    "TtyPort",
    "TransportKind",
    "WireDevice",
    "WireDeviceFactory",
    "adapter_advice",
    "device_factory",
    "carries_line_settings",
    "same_port",
    "check_direction",
    "open_port",
    "rate_blind_note",
    "register_url_scheme",
    "url_scheme",
]
