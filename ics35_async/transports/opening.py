"""Opening the line: an asyncio transport for whatever ``port`` names.

* a device path or pyserial URL (``/dev/ttyUSB0``, ``socket://``,
  ``rfc2217://``, ``loop://``): opened 8E1 with pyserial and driven by our
  :class:`~.direct.DirectSerialTransport` (device paths), pyserial-asyncio-fast
  or stock pyserial-asyncio, or a reader thread for ports without a file
  descriptor;
* an in-process device such as the simulator (a :class:`~.in_process.WireDevice`),
  wrapped in :class:`~.in_process.InProcessTransport`;
* a URL whose scheme maps to a device factory (``sim://``).

Whatever the transport, ``connection_lost(exc)`` reaches the protocol with an
:class:`OSError` when the port disappears (USB unplug, pty master closed), and
``data_received`` is never called from inside ``write()``.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable
from typing import Any, TypeVar, cast

import serial

from ..errors import InvalidArgument
from .direct import DirectSerialTransport
from .in_process import InProcessTransport
from .links import carries_line_settings
from .serial_port import TermiosError, open_serial, posix_fd
from .threaded import ThreadedSerialDevice
from .wire_device import TRANSPORT_KINDS, WireDevice, device_factory

log = logging.getLogger("ics35_async.transports")

P = TypeVar("P", bound=asyncio.Protocol)

_SerialTransportClass = Callable[[asyncio.AbstractEventLoop, asyncio.Protocol, serial.SerialBase], asyncio.Transport]


def _fast_transport_class() -> _SerialTransportClass | None:
    try:
        import serial_asyncio_fast
    except ImportError:
        return None
    return cast(_SerialTransportClass, serial_asyncio_fast.SerialTransport)


def _stock_transport_class() -> _SerialTransportClass | None:
    try:
        import serial_asyncio
    except ImportError:
        return None
    return cast(_SerialTransportClass, serial_asyncio.SerialTransport)

def _choose_kind(kind: str, ser: serial.SerialBase) -> str:
    """Resolve ``transport`` for an open port; ``"thread"`` for ports with no descriptor to wait on."""
    if kind == "thread":
        return "thread"
    fd_backed = posix_fd(ser) is not None  # a POSIX tty or pty
    has_fileno = fd_backed
    if not fd_backed:
        try:
            ser.fileno()  # socket:// has the socket's
            has_fileno = True
        except (OSError, ValueError, AttributeError):
            has_fileno = False
    if not has_fileno or (kind == "auto" and not fd_backed and not carries_line_settings(ser.port)):
        # socket:// has a descriptor, but pyserial's socket handler reports a hang-up only after the
        # 0.3 s sleep of its close, which pyserial-asyncio runs first; the reader thread tells at once.
        if has_fileno:
            return "thread"
        if kind != "auto":
            raise InvalidArgument(
                f"transport={kind!r} needs a port with a file descriptor; {ser.port!r} has none "
                "(use transport='auto', which reads it from a thread)"
            )
        return "thread"
    if kind == "direct" and not fd_backed:
        raise InvalidArgument(f"transport='direct' drives device paths only, not {ser.port!r}")
    if kind == "auto":
        if fd_backed:
            return "direct"
        return "fast" if _fast_transport_class() is not None else "stock"
    return kind


async def open_line(
    port: str | WireDevice,
    *,
    baudrate: int,
    protocol_factory: Callable[[], P],
    transport: str = "auto",
    low_latency: bool = True,
    direction: str = "none",
) -> tuple[asyncio.Transport, P]:
    """Open the line to the servos and connect ``protocol_factory()`` to it.

    ``port`` is a device path (``/dev/ttyUSB0``), a pyserial URL
    (``socket://host:port``, ``rfc2217://host:port``, ``loop://``), a URL
    whose scheme was registered with :func:`register_url_scheme`
    (``sim://...``), or a :class:`WireDevice` object.

    Serial ports open at 8 data bits, EVEN parity, 1 stop bit.  ``transport``
    picks the driver for ports with a file descriptor: ``"direct"``
    (:class:`DirectSerialTransport`, device paths only), ``"fast"``
    (pyserial-asyncio-fast), ``"stock"`` (pyserial-asyncio), or ``"auto"``:
    direct for device paths, fast (else stock) for other URLs.  Ports without
    a descriptor (``loop://``, ``rfc2217://``) are read by a thread.
    In-process devices ignore ``transport``.  ``low_latency`` asks the
    driver for ASYNC_LOW_LATENCY (sets FTDI's latency timer to 1 ms) where
    it can.  ``direction`` (``"none"``, ``"rts"``, ``"rts-inverted"``) asks the
    driver of a local serial port to toggle RTS while sending (see
    :mod:`.direction`).

    ``protocol.connection_made`` has been called when this returns.
    Raises :class:`PortNotFound`, :class:`PortPermissionDenied`,
    :class:`PortBusy`, :class:`ParityNotSupported` or another
    :class:`SerialPortError` (all :class:`OSError`), and
    :class:`~ics35_async.errors.InvalidArgument` for bad arguments.
    """
    if transport not in TRANSPORT_KINDS:
        raise InvalidArgument(f"transport must be one of {', '.join(TRANSPORT_KINDS)}, not {transport!r}")
    if isinstance(baudrate, bool) or not isinstance(baudrate, int) or baudrate <= 0:
        raise InvalidArgument(f"baudrate must be a positive int, not {baudrate!r}")
    loop = asyncio.get_running_loop()

    if not isinstance(port, str):
        if not isinstance(port, WireDevice):
            raise InvalidArgument(f"port must be a device path, a URL or a WireDevice, not {type(port).__name__}")
        return await _open_in_process(loop, port, baudrate, protocol_factory)
    scheme, sep, _ = port.partition("://")
    factory = device_factory(scheme) if sep else None
    if factory is not None:
        return await _open_in_process(loop, factory(port), baudrate, protocol_factory)
    if not port:
        raise InvalidArgument("port must not be empty")

    opening = loop.run_in_executor(None, open_serial, port, baudrate, low_latency, direction)
    try:
        ser = await opening
    except asyncio.CancelledError:
        opening.add_done_callback(lambda f: f.cancelled() or f.exception() or f.result().close())
        raise
    try:
        kind = _choose_kind(transport, ser)
        if kind == "thread":
            return await _open_in_process(
                loop, ThreadedSerialDevice(ser), baudrate, protocol_factory, extra={"serial": ser}
            )
        protocol = protocol_factory()
        line: asyncio.Transport
        if kind == "direct":
            line = DirectSerialTransport(loop, protocol, cast(serial.Serial, ser))
        else:
            cls = _fast_transport_class() if kind == "fast" else _stock_transport_class()
            if cls is None:
                cls = _stock_transport_class() if kind == "fast" else None
                if cls is None:
                    raise InvalidArgument(f"transport={kind!r} is not installed (pip install pyserial-asyncio)")
                log.debug("pyserial-asyncio-fast is not installed: using stock pyserial-asyncio")
            line = cls(loop, protocol, ser)
    except BaseException:
        ser.close()
        raise
    log.debug("opened %s at %d baud (%s) with %s", port, baudrate, ser.parity, type(line).__name__)
    await asyncio.sleep(0)  # let the transport's connection_made run
    return line, protocol


async def _open_in_process(
    loop: asyncio.AbstractEventLoop,
    device: WireDevice,
    baudrate: int,
    protocol_factory: Callable[[], P],
    *,
    extra: dict[str, Any] | None = None,
) -> tuple[asyncio.Transport, P]:
    protocol = protocol_factory()
    line = InProcessTransport(loop, protocol, device, extra=extra)
    # Scheduled before connect so that anything the device says while
    # connecting reaches the protocol after connection_made.
    made = loop.call_soon(protocol.connection_made, line)
    try:
        device.connect(line.host, baudrate)
    except BaseException:
        made.cancel()
        line._closing = True
        raise
    await asyncio.sleep(0)
    return line, protocol


# --------------------------------------------------------------------------- helpers for the bus


def discard_input(transport: asyncio.BaseTransport) -> None:
    """Drop bytes waiting in the OS input buffer of the line (resync after a fault).

    Bytes already handed to the event loop still reach ``data_received``;
    the bus ignores them by waiting for a quiet line.  Errors are swallowed:
    a port that is gone reports it through ``connection_lost``.
    """
    if transport.is_closing():
        return
    try:
        discard = getattr(transport, "discard_input", None)
        if discard is not None:
            discard()
            return
        ser = transport.get_extra_info("serial")
        if ser is not None:
            ser.reset_input_buffer()
    except (OSError, TermiosError) as exc:
        log.debug("discarding input failed: %s", exc)
