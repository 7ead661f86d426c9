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
)

if TYPE_CHECKING:
    from .advice import adapter_advice
    from .direct import DirectSerialTransport, ParityMarks
    from .direction import DIRECTIONS, check_direction
    from .in_process import InProcessTransport
    from .links import carries_line_settings, rate_blind_note
    from .opening import discard_input, open_line
    from .threaded import ThreadedSerialDevice

_LAZY = {
    "adapter_advice": ".advice",
    "DirectSerialTransport": ".direct",
    "ParityMarks": ".direct",
    "DIRECTIONS": ".direction",
    "check_direction": ".direction",
    "InProcessTransport": ".in_process",
    "carries_line_settings": ".links",
    "rate_blind_note": ".links",
    "discard_input": ".opening",
    "open_line": ".opening",
    "ThreadedSerialDevice": ".threaded",
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
    "device_factory",
    "carries_line_settings",
    "check_direction",
    "discard_input",
    "open_line",
    "rate_blind_note",
    "register_url_scheme",
]
