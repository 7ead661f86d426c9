"""Opening the line: the one :func:`open_port` every driver uses, and the kinds of port it gives.

* a device path or pty with a descriptor: a :class:`~.tty_port.TtyPort`
  (pyserial opens it 8E1, then ``os.read``/``os.write`` on its descriptor,
  parity marks decoded);
* a pyserial port without one (``loop://``, ``rfc2217://``, ``socket://``,
  Windows COM ports): a :class:`~.pyserial_port.SerialPort` read with
  blocking reads, or, for a driver that cannot block, the same behind a
  :class:`~.pyserial_port.ReaderThread` as an in-process device;
* an in-process device (the simulator, a URL scheme that maps to one, any
  :class:`~.wire_device.WireDevice`): a :class:`~.device_port.DevicePort`.

Each kind offers ``read()`` (what has arrived, ``b""`` if nothing; raises
:class:`OSError` when the port is gone -- a hang-up, never a flushed input),
``bad`` (bytes that arrived damaged since the driver last took the count),
``write(data)`` (False when part of it waits for the port: a tty's
``pending``), ``discard_input()`` (drop what arrived unread, and say how
many bytes that was) and ``close()``.  How to wait for input
is the driver's own business.
"""

from __future__ import annotations

import logging
import os

from ..errors import InvalidArgument
from .device_port import DevicePort
from .pyserial_port import SERIAL_POLL, ReaderThread, SerialPort
from .serial_port import READ_POLL, open_serial, posix_fd
from .tty_port import TtyPort
from .wire_device import TRANSPORT_KINDS, WireDevice, device_factory, port_argument, url_scheme

log = logging.getLogger("ics35_async.transports")

Port = TtyPort | SerialPort | DevicePort


def open_port(
    port: str | os.PathLike[str] | WireDevice,
    baudrate: int,
    *,
    transport: str = "auto",
    direction: str = "none",
    blocking_reads: bool = False,
) -> Port:
    """Open the line to the servos (blocking: call it from a worker thread).

    ``port`` is a device path (``/dev/ttyUSB0``), a pyserial URL
    (``socket://host:port``, ``rfc2217://host:port``, ``loop://``), a URL
    whose scheme was registered with :func:`register_url_scheme`
    (``sim://...``), or a :class:`WireDevice` object.  Serial ports open at
    8 data bits, EVEN parity, 1 stop bit.  ``transport``: ``"auto"`` or
    ``"direct"`` read a port with a descriptor on it; ``"thread"`` reads any
    serial port with blocking reads in a thread.  ``blocking_reads``: the
    caller reads a port without a descriptor itself (the thread driver);
    otherwise such a port comes behind a reader thread.  ``direction``
    (``"none"``, ``"rts"``, ``"rts-inverted"``) asks the driver of a local
    serial port to toggle RTS while sending (see :mod:`.direction`).

    Raises :class:`PortNotFound`, :class:`PortPermissionDenied`,
    :class:`PortBusy`, :class:`ParityNotSupported` or another
    :class:`SerialPortError` (all :class:`OSError`), and
    :class:`~ics35_async.errors.InvalidArgument` for bad arguments.
    """
    if transport not in TRANSPORT_KINDS:
        raise InvalidArgument(f"transport must be one of {', '.join(TRANSPORT_KINDS)}, not {transport!r}")
    if isinstance(baudrate, bool) or not isinstance(baudrate, int) or baudrate <= 0:
        raise InvalidArgument(f"baudrate must be a positive int, not {baudrate!r}")
    port = port_argument(port)
    if not isinstance(port, str):
        return _device_port(port, baudrate)
    scheme = url_scheme(port)
    factory = device_factory(scheme) if scheme else None
    if factory is not None:
        return _device_port(factory(port), baudrate)
    ser = open_serial(port, baudrate, True, direction)
    try:
        if posix_fd(ser) is not None and (transport != "thread" or blocking_reads):
            opened: Port = TtyPort(ser)
        elif transport == "direct":
            raise InvalidArgument(f"transport='direct' drives device paths only, not {port!r}")
        elif blocking_reads:
            opened = SerialPort(ser, SERIAL_POLL)
        else:
            return _device_port(ReaderThread(SerialPort(ser, READ_POLL)), baudrate)
    except BaseException:
        ser.close()
        raise
    log.debug("opened %s at %d baud (%s) as a %s port", port, baudrate, ser.parity, opened.kind)
    return opened


def _device_port(device: WireDevice, baudrate: int) -> DevicePort:
    opened = DevicePort(device)
    opened.connect(baudrate)
    return opened
