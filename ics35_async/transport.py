"""Opening the line: serial ports (pyserial URLs too) and in-process devices.

The bus talks to the line through an :class:`asyncio.Protocol`; this module
gives it an :class:`asyncio.Transport` for whatever ``port`` names:

* a device path or pyserial URL (``/dev/ttyUSB0``, ``socket://``,
  ``loop://``): opened 8E1 with pyserial and driven by pyserial-asyncio-fast
  (or stock pyserial-asyncio);
* an in-process device such as the simulator, which implements
  :class:`WireDevice` and is wrapped in :class:`InProcessTransport`;
* a URL whose scheme was registered with :func:`register_url_scheme`
  (the simulator registers ``sim://``), resolved to a :class:`WireDevice`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol, runtime_checkable


class HostSide(Protocol):
    """The host end of an in-process line, as a device sees it."""

    def deliver(self, data: bytes) -> None:
        """Bytes arriving at the host (echo, replies, noise).  Thread-safe."""

    def lost(self, exc: Exception | None) -> None:
        """The line went away (``exc`` says why).  Thread-safe."""


@runtime_checkable
class WireDevice(Protocol):
    """An in-process device on the far end of the wire (e.g. the simulator).

    ``connect`` raises :class:`OSError` when the device cannot be opened
    (e.g. it is simulated as unplugged).  ``write`` is called with the host's
    bytes; the device answers by calling ``host.deliver`` now or later, from
    any thread.  ``disconnect`` detaches the host.
    """

    def connect(self, host: HostSide, baudrate: int) -> None: ...

    def write(self, data: bytes) -> None: ...

    def disconnect(self) -> None: ...


WireDeviceFactory = Callable[[str], WireDevice]
_URL_SCHEMES: dict[str, WireDeviceFactory] = {}


def register_url_scheme(scheme: str, factory: WireDeviceFactory) -> None:
    """Make ``open_line("<scheme>://...")`` build its device with ``factory(url)``."""
    _URL_SCHEMES[scheme] = factory
