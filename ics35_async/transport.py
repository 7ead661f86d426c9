"""Opening the line: serial ports (pyserial URLs too) and in-process devices.

The bus talks to the line through an :class:`asyncio.Protocol`; this module
gives it an :class:`asyncio.Transport` for whatever ``port`` names:

* a device path or pyserial URL (``/dev/ttyUSB0``, ``socket://``,
  ``rfc2217://``, ``loop://``): opened 8E1 with pyserial and driven by
  pyserial-asyncio-fast (or stock pyserial-asyncio, or our own
  :class:`DirectSerialTransport`);
* an in-process device such as the simulator, which implements
  :class:`WireDevice` and is wrapped in :class:`InProcessTransport`;
* a URL whose scheme was registered with :func:`register_url_scheme`
  (the simulator registers ``sim://``), resolved to a :class:`WireDevice`.

Whatever the transport, ``connection_lost(exc)`` reaches the protocol with an
:class:`OSError` when the port disappears (USB unplug, pty master closed), and
``data_received`` is never called from inside ``write()``.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import logging
import os
import sys
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any, Final, Literal, Protocol, TypeVar, cast, get_args, runtime_checkable

import serial

from .errors import IcsError, InvalidArgument

if sys.platform != "win32":
    import termios

__all__ = [
    "TRANSPORT_KINDS",
    "DirectSerialTransport",
    "HostSide",
    "InProcessTransport",
    "ParityNotSupported",
    "PortBusy",
    "PortNotFound",
    "PortPermissionDenied",
    "SerialPortError",
    "TransportKind",
    "WireDevice",
    "WireDeviceFactory",
    "adapter_advice",
    "discard_input",
    "open_line",
    "register_url_scheme",
]

log = logging.getLogger(__name__)

P = TypeVar("P", bound=asyncio.Protocol)
TransportKind = Literal["auto", "fast", "stock", "direct"]
TRANSPORT_KINDS: Final[tuple[str, ...]] = get_args(TransportKind)


# --------------------------------------------------------------------------- errors


class SerialPortError(IcsError, OSError):
    """The serial port could not be opened or set up as the ICS line needs.

    Also an :class:`OSError`, so code that already handles I/O errors keeps
    working; ``errno`` is set when the system gave one.
    """


class PortNotFound(SerialPortError, FileNotFoundError):
    """No device exists at that path."""


class PortPermissionDenied(SerialPortError, PermissionError):
    """The device exists but this user may not open it."""


class PortBusy(SerialPortError):
    """Another program (or another line in this one) holds the port."""


class ParityNotSupported(SerialPortError):
    """The driver silently refused EVEN parity, which ICS 3.5 requires."""


# --------------------------------------------------------------------------- in-process lines


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

    A device may also offer ``discard_input()``, which :func:`discard_input`
    calls; it is optional.
    """

    def connect(self, host: HostSide, baudrate: int) -> None: ...

    def write(self, data: bytes) -> None: ...

    def disconnect(self) -> None: ...


WireDeviceFactory = Callable[[str], WireDevice]
_URL_SCHEMES: dict[str, WireDeviceFactory] = {}


def register_url_scheme(scheme: str, factory: WireDeviceFactory) -> None:
    """Make ``open_line("<scheme>://...")`` build its device with ``factory(url)``."""
    _URL_SCHEMES[scheme] = factory


class _Host:
    """The :class:`HostSide` handed to a device; forwards to its transport."""

    __slots__ = ("_transport",)

    def __init__(self, transport: InProcessTransport) -> None:
        self._transport = transport

    def deliver(self, data: bytes) -> None:
        self._transport._schedule(self._transport._data_received, data)

    def lost(self, exc: Exception | None) -> None:
        self._transport._schedule(self._transport._device_lost, exc)


class InProcessTransport(asyncio.Transport):
    """An asyncio transport whose far end is a :class:`WireDevice` in this process.

    ``write`` hands the bytes straight to ``device.write``.  The device's
    answers always reach ``protocol.data_received`` through the event loop,
    never synchronously: the bus writes from inside ``data_received``, and a
    device answering inside ``write`` would otherwise re-enter it.

    Create it on the event loop's thread.  It is on the hot path of every
    in-process transaction, hence the plain attribute juggling.
    """

    def __init__(
        self,
        loop: asyncio.AbstractEventLoop,
        protocol: asyncio.Protocol,
        device: WireDevice,
        *,
        extra: dict[str, Any] | None = None,
    ) -> None:
        super().__init__({"device": device, **(extra or {})})
        self._loop = loop
        self._protocol = protocol
        self._device = device
        self._loop_thread = threading.get_ident()
        self._closing = False
        self._lost_reported = False
        self._paused: list[bytes] | None = None
        self.host: HostSide = _Host(self)

    # -- called by the device, from any thread

    def _schedule(self, callback: Callable[[Any], None], arg: Any) -> None:
        if threading.get_ident() == self._loop_thread:
            self._loop.call_soon(callback, arg)
            return
        with contextlib.suppress(RuntimeError):  # a closed loop: nobody is left to tell
            self._loop.call_soon_threadsafe(callback, arg)

    # -- run on the loop

    def _data_received(self, data: bytes) -> None:
        if self._closing:
            return
        if type(data) is not bytes:
            data = bytes(data)
        if self._paused is not None:
            self._paused.append(data)
            return
        self._protocol.data_received(data)

    def _device_lost(self, exc: Exception | None) -> None:
        self._closing = True
        self._report_lost(exc)

    def _report_lost(self, exc: Exception | None) -> None:
        if not self._lost_reported:
            self._lost_reported = True
            self._protocol.connection_lost(exc)

    # -- asyncio.Transport

    def write(self, data: bytes | bytearray | memoryview) -> None:
        if self._closing:
            return
        try:
            self._device.write(data if type(data) is bytes else bytes(data))
        except OSError as exc:
            self._closing = True
            self._loop.call_soon(self._report_lost, exc)

    def is_closing(self) -> bool:
        return self._closing

    def close(self) -> None:
        if self._closing:
            return
        self._closing = True
        try:
            self._device.disconnect()
        except Exception:
            log.debug("device %r failed to disconnect", self._device, exc_info=True)
        self._loop.call_soon(self._report_lost, None)

    def abort(self) -> None:
        self.close()

    def get_write_buffer_size(self) -> int:
        return 0

    def set_write_buffer_limits(self, high: int | None = None, low: int | None = None) -> None:
        pass  # writes never queue here

    def can_write_eof(self) -> bool:
        return False

    def pause_reading(self) -> None:
        if self._paused is None:
            self._paused = []

    def resume_reading(self) -> None:
        held, self._paused = self._paused, None
        for data in held or ():
            self._loop.call_soon(self._data_received, data)

    def is_reading(self) -> bool:
        return self._paused is None and not self._closing

    def get_protocol(self) -> asyncio.BaseProtocol:
        return self._protocol

    def set_protocol(self, protocol: asyncio.BaseProtocol) -> None:
        self._protocol = cast(asyncio.Protocol, protocol)

    def discard_input(self) -> None:
        """Ask the device to drop what it has not delivered yet, if it can."""
        discard = getattr(self._device, "discard_input", None)
        if discard is not None:
            discard()


class _ThreadedSerialDevice:
    """A pyserial port without a file descriptor (``loop://``, ``rfc2217://``).

    The event loop cannot wait on such a port, so a reader thread blocks in
    ``read`` and hands the bytes over like any in-process device would.
    """

    _POLL = 0.05  # how long the reader thread blocks before checking for shutdown

    def __init__(self, ser: serial.SerialBase) -> None:
        self._serial = ser
        self._host: HostSide | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def connect(self, host: HostSide, baudrate: int) -> None:
        self._host = host
        # write_timeout=0 makes loop:// refuse every write; these ports buffer.
        self._serial.write_timeout = None
        self._serial.timeout = self._POLL
        self._thread = threading.Thread(target=self._read_loop, name=f"ics35-reader {self._serial.port}", daemon=True)
        self._thread.start()

    def _read_loop(self) -> None:
        ser, host = self._serial, self._host
        assert host is not None
        try:
            while not self._stop.is_set():
                data = ser.read(ser.in_waiting or 1)
                if data and not self._stop.is_set():
                    host.deliver(data)
        except Exception as exc:
            if not self._stop.is_set():
                host.lost(exc if isinstance(exc, OSError) else OSError(errno.EIO, f"serial read failed: {exc}"))

    def write(self, data: bytes) -> None:
        try:
            self._serial.write(data)
        except serial.SerialException:
            raise
        except Exception as exc:
            raise OSError(errno.EIO, f"serial write failed: {exc}") from exc

    def discard_input(self) -> None:
        self._serial.reset_input_buffer()

    def disconnect(self) -> None:
        self._stop.set()
        cancel_read = getattr(self._serial, "cancel_read", None)
        if cancel_read is not None:
            with contextlib.suppress(Exception):
                cancel_read()  # wakes the reader now rather than after its poll timeout
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=1.0)
        self._serial.close()


# --------------------------------------------------------------------------- our own POSIX transport


class ParityMarks:
    """Undo the kernel's PARMRK marking of received bytes.

    With INPCK and PARMRK set (and IGNPAR, ISTRIP clear), Linux passes a
    byte that arrived with a parity or framing error as ``FF 00 x`` and a
    genuine ``FF`` as ``FF FF``.  :meth:`decode` returns the bytes as they
    were on the wire and how many of them were marked bad; a mark split
    across two reads is completed by the next call.
    """

    __slots__ = ("_pending",)

    def __init__(self) -> None:
        self._pending = b""

    def decode(self, data: bytes) -> tuple[bytes, int]:
        if self._pending:
            data = self._pending + data
            self._pending = b""
        elif 0xFF not in data:
            return data, 0
        out = bytearray()
        errors = 0
        i, n = 0, len(data)
        while i < n:
            j = data.find(b"\xff", i)
            if j < 0:
                out += data[i:]
                break
            out += data[i:j]
            if j + 1 >= n:
                self._pending = data[j:]
                break
            if data[j + 1] == 0xFF:
                out.append(0xFF)
                i = j + 2
            elif data[j + 1] == 0x00:
                if j + 2 >= n:
                    self._pending = data[j:]
                    break
                out.append(data[j + 2])
                errors += 1
                i = j + 3
            else:  # not a mark (PARMRK off after all): keep it as it came
                out.append(0xFF)
                i = j + 1
        return bytes(out), errors


def _enable_parity_marks(fd: int) -> bool:
    """Ask the kernel to mark bytes received with parity/framing errors; True if set."""
    try:
        attrs = termios.tcgetattr(fd)
        attrs[0] |= termios.INPCK | termios.PARMRK
        attrs[0] &= ~(termios.IGNPAR | termios.ISTRIP)
        termios.tcsetattr(fd, termios.TCSANOW, attrs)
        return bool(termios.tcgetattr(fd)[0] & termios.PARMRK)
    except termios.error:
        log.debug("could not enable parity-error marks on fd %d", fd, exc_info=True)
        return False


class DirectSerialTransport(asyncio.Transport):
    """A minimal POSIX transport on the file descriptor of an open pyserial port.

    pyserial opens and configures the port; after that, reading is one
    ``os.read`` per readiness event and ``write`` calls ``os.write`` at once,
    skipping pyserial's per-call ``select`` and timeout bookkeeping.  Only for
    ports that are real file descriptors (device paths, ptys).
    """

    max_read_size = 4096

    def __init__(self, loop: asyncio.AbstractEventLoop, protocol: asyncio.Protocol, ser: serial.Serial) -> None:
        super().__init__({"serial": ser})
        self._loop = loop
        self._protocol = protocol
        self._serial: serial.Serial | None = ser
        self._fd: int = ser.fileno()
        # pyserial opens O_NONBLOCK; rely on it being so, since with VMIN=0 a
        # blocking read of an empty tty returns 0 bytes, which means hangup here.
        os.set_blocking(self._fd, False)
        # pyserial turns input parity checking off; we want corrupted bytes reported
        # (ICS has no checksum), so the kernel marks them and we unmark them here.
        self._marks: ParityMarks | None = ParityMarks() if _enable_parity_marks(self._fd) else None
        self._line_error = getattr(protocol, "line_error", None)
        self._buffer = bytearray()
        self._closing = False
        self._finish_scheduled = False
        self._reading = False
        self._writing = False
        self._high_water = 64 * 1024
        self._low_water = 16 * 1024
        self._protocol_paused = False
        loop.call_soon(protocol.connection_made, self)
        loop.call_soon(self._start_reading)

    @property
    def serial(self) -> serial.Serial | None:
        return self._serial

    # -- reading

    def _start_reading(self) -> None:
        if not self._reading and not self._closing:
            self._loop.add_reader(self._fd, self._read_ready)
            self._reading = True

    def _stop_reading(self) -> None:
        if self._reading:
            self._loop.remove_reader(self._fd)
            self._reading = False

    def _read_ready(self) -> None:
        try:
            data = os.read(self._fd, self.max_read_size)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as exc:
            self._abort(exc)
            return
        if data:
            marks = self._marks
            if marks is not None:
                data, errors = marks.decode(data)
                if errors and self._line_error is not None:
                    self._line_error(errors)
                if not data:
                    return
            self._protocol.data_received(data)
        else:
            # A tty reads 0 bytes only once the device is gone (hangup).
            self._abort(OSError(errno.EIO, "the serial port hung up (device disconnected?)"))

    # -- writing

    def write(self, data: bytes | bytearray | memoryview) -> None:
        if self._closing:
            return
        if self._buffer:
            self._buffer += data
            self._maybe_pause_protocol()
            return
        try:
            n = os.write(self._fd, data)
        except (BlockingIOError, InterruptedError):
            n = 0
        except OSError as exc:
            self._abort(exc)
            return
        if n == len(data):
            return
        self._buffer += memoryview(data)[n:]
        self._loop.add_writer(self._fd, self._write_ready)
        self._writing = True
        self._maybe_pause_protocol()

    def _write_ready(self) -> None:
        try:
            n = os.write(self._fd, self._buffer)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as exc:
            self._abort(exc)
            return
        del self._buffer[:n]
        if not self._buffer:
            self._loop.remove_writer(self._fd)
            self._writing = False
            if self._closing:
                self._schedule_finish(None)
        self._maybe_resume_protocol()

    def _maybe_pause_protocol(self) -> None:
        if not self._protocol_paused and len(self._buffer) > self._high_water:
            self._protocol_paused = True
            self._protocol.pause_writing()

    def _maybe_resume_protocol(self) -> None:
        if self._protocol_paused and len(self._buffer) <= self._low_water:
            self._protocol_paused = False
            self._protocol.resume_writing()

    def get_write_buffer_size(self) -> int:
        return len(self._buffer)

    def get_write_buffer_limits(self) -> tuple[int, int]:
        return self._low_water, self._high_water

    def set_write_buffer_limits(self, high: int | None = None, low: int | None = None) -> None:
        if high is None:
            high = 64 * 1024 if low is None else 4 * low
        if low is None:
            low = high // 4
        if not high >= low >= 0:
            raise ValueError(f"high ({high!r}) must be >= low ({low!r}) must be >= 0")
        self._high_water, self._low_water = high, low
        self._maybe_pause_protocol()

    def can_write_eof(self) -> bool:
        return False

    # -- life cycle

    def is_closing(self) -> bool:
        return self._closing

    def is_reading(self) -> bool:
        return self._reading

    def pause_reading(self) -> None:
        self._stop_reading()

    def resume_reading(self) -> None:
        self._start_reading()

    def get_protocol(self) -> asyncio.BaseProtocol:
        return self._protocol

    def set_protocol(self, protocol: asyncio.BaseProtocol) -> None:
        self._protocol = cast(asyncio.Protocol, protocol)

    def close(self) -> None:
        """Stop reading; finish writing what is buffered; then release the port."""
        if self._closing:
            return
        self._closing = True
        self._stop_reading()
        if not self._buffer:
            self._schedule_finish(None)

    def abort(self) -> None:
        self._abort(None)

    def _abort(self, exc: Exception | None) -> None:
        self._closing = True
        self._stop_reading()
        if self._writing:
            self._loop.remove_writer(self._fd)
            self._writing = False
        self._buffer.clear()
        self._schedule_finish(exc)

    def _schedule_finish(self, exc: Exception | None) -> None:
        if not self._finish_scheduled:
            self._finish_scheduled = True
            self._loop.call_soon(self._finish, exc)

    def _finish(self, exc: Exception | None) -> None:
        ser, self._serial = self._serial, None
        if ser is None:
            return
        try:
            ser.close()
        except OSError:
            log.debug("closing %s failed", ser.port, exc_info=True)
        self._protocol.connection_lost(exc)

    def discard_input(self) -> None:
        """Drop what sits in the OS input buffer."""
        if self._serial is not None:
            termios.tcflush(self._fd, termios.TCIFLUSH)


# --------------------------------------------------------------------------- opening


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


def _is_pty(fd: int) -> bool:
    """Whether ``fd`` is the slave side of a pseudo-terminal."""
    if sys.platform.startswith("linux"):
        # 136-143: UNIX98 pty slaves (/dev/pts/N); 3: legacy BSD-style slaves.
        major = os.major(os.fstat(fd).st_rdev)
        return 136 <= major <= 143 or major == 3
    try:
        return os.ttyname(fd).startswith("/dev/pts/")
    except OSError:
        return False


def _is_pty_path(path: str) -> bool:
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOCTTY | os.O_NONBLOCK)
    except OSError:
        return False
    try:
        return _is_pty(fd)
    finally:
        os.close(fd)


def _translate_open_error(port: str, exc: Exception) -> Exception:
    """Turn what pyserial raised into an error that says what to do."""
    code = getattr(exc, "errno", None)
    if code == errno.ENOENT:
        return PortNotFound(
            code,
            f"no serial port at {port!r}: check the cable/adapter is plugged in and the name "
            "(ls /dev/ttyUSB* /dev/ttyACM* /dev/serial/by-id/)",
        )
    if code in (errno.EACCES, errno.EPERM):
        return PortPermissionDenied(
            code,
            f"permission denied opening {port!r}: add your user to the group owning the port "
            "(usually 'dialout': sudo usermod -aG dialout $USER, then log in again)",
        )
    if code in (errno.EBUSY, errno.EAGAIN, errno.EWOULDBLOCK):
        return PortBusy(code, f"{port!r} is in use by another program (or already open in this one)")
    if code in (errno.ENXIO, errno.ENODEV):
        return SerialPortError(code, f"{port!r} exists but no device answers behind it (unplugged?)")
    if code is None and "Inappropriate ioctl" in str(exc):
        return SerialPortError(errno.ENOTTY, f"{port!r} is not a serial port")
    return SerialPortError(code if code is not None else errno.EIO, f"cannot open {port!r}: {exc}")


_PYSERIAL_SCHEMES = ("alt", "cp2110", "hwgrep", "loop", "rfc2217", "socket", "spy")


def _open_serial(port: str, baudrate: int, low_latency: bool) -> serial.SerialBase:
    """Open ``port`` 8E1 with pyserial (blocking; run it in an executor)."""
    is_device_path = "://" not in port
    settings: dict[str, Any] = {
        "baudrate": baudrate,
        "bytesize": serial.EIGHTBITS,
        "parity": serial.PARITY_EVEN,
        "stopbits": serial.STOPBITS_ONE,
        "timeout": 0,
        "write_timeout": 0,
    }
    if is_device_path:
        settings["exclusive"] = True
    try:
        try:
            ser = serial.serial_for_url(port, **settings)
        except termios.error as exc:
            # A pty refuses a tcsetattr whose only change is PARENB (EINVAL),
            # which is what opening an already-raw pty at our speed asks for.
            if not (is_device_path and exc.args[0] == errno.EINVAL and _is_pty_path(port)):
                raise SerialPortError(exc.args[0], f"cannot configure {port!r} as 8E1: {exc.args[-1]}") from exc
            log.debug("%s is a pty, which has no parity: opening it 8N1", port)
            ser = serial.serial_for_url(port, **{**settings, "parity": serial.PARITY_NONE})
    except serial.SerialException as exc:
        raise _translate_open_error(port, exc) from exc
    except ValueError as exc:
        # Unknown URL scheme, or a baud rate the driver rejects.
        raise InvalidArgument(f"cannot open {port!r}: {exc}") from exc

    try:
        fd = ser.fileno() if isinstance(ser, serial.Serial) else None
        if fd is not None and ser.parity == serial.PARITY_EVEN:
            _check_parity(ser, port, fd)
        if low_latency and fd is not None and not _is_pty(fd):
            _try_low_latency(ser, port)
    except BaseException:
        ser.close()
        raise
    return ser


def _check_parity(ser: serial.Serial, port: str, fd: int) -> None:
    """Cope with drivers that drop PARENB without an error.

    A Linux pty accepts the opening tcsetattr (other flags did change) but
    silently clears PARENB; every later re-configuration (even setting
    ``.timeout``, which the asyncio transports do) then asks for PARENB alone
    and fails with EINVAL.  A pty has no wire, so no parity is lost: carry on
    at 8N1.  A real port that drops parity would corrupt every transaction,
    so that is an error.
    """
    if termios.tcgetattr(fd)[2] & termios.PARENB:
        return
    if _is_pty(fd):
        log.debug("%s is a pty, which dropped EVEN parity: continuing 8N1", port)
        ser.parity = serial.PARITY_NONE
        return
    raise ParityNotSupported(
        errno.EINVAL,
        f"the driver of {port!r} silently refused EVEN parity, which ICS 3.5 needs (8E1); "
        "use an adapter whose driver supports parity",
    )


def _try_low_latency(ser: serial.Serial, port: str) -> None:
    setter = getattr(ser, "set_low_latency_mode", None)
    if setter is None:
        return
    try:
        setter(True)
    except (ValueError, OSError, NotImplementedError) as exc:
        # Many drivers (and every pty) lack TIOCSSERIAL; it is only a speed-up.
        log.debug("low-latency mode not available on %s: %s", port, exc)
    else:
        log.debug("low-latency mode enabled on %s", port)


def _choose_kind(kind: str, ser: serial.SerialBase) -> str:
    """Resolve ``transport`` for an open port; ``"thread"`` for fd-less ports."""
    fd_backed = isinstance(ser, serial.Serial)  # serialposix: a real tty or pty
    has_fileno = True
    try:
        ser.fileno()
    except (OSError, AttributeError):
        has_fileno = False
    if not has_fileno:
        if kind != "auto":
            raise InvalidArgument(
                f"transport={kind!r} needs a port with a file descriptor; {ser.port!r} has none "
                "(use transport='auto', which reads it from a thread)"
            )
        return "thread"
    if kind == "direct" and not fd_backed:
        raise InvalidArgument(f"transport='direct' drives device paths only, not {ser.port!r}")
    if kind == "auto":
        if fd_backed and sys.platform != "win32":
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
    it can.

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
    if sep and scheme in _URL_SCHEMES:
        return await _open_in_process(loop, _URL_SCHEMES[scheme](port), baudrate, protocol_factory)
    if not port:
        raise InvalidArgument("port must not be empty")

    opening = loop.run_in_executor(None, _open_serial, port, baudrate, low_latency)
    try:
        ser = await opening
    except asyncio.CancelledError:
        opening.add_done_callback(lambda f: f.cancelled() or f.exception() or f.result().close())
        raise
    try:
        kind = _choose_kind(transport, ser)
        if kind == "thread":
            return await _open_in_process(
                loop, _ThreadedSerialDevice(ser), baudrate, protocol_factory, extra={"serial": ser}
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
    except (OSError, termios.error) as exc:
        log.debug("discarding input failed: %s", exc)


_LATENCY_FIX = (
    "{path} is {ms} ms: a USB adapter holds received bytes up to that long, which slows every "
    "transaction. Set it to 1 ms now with: echo 1 | sudo tee {path}  -- or for good with a udev rule, e.g. "
    '/etc/udev/rules.d/99-ftdi-latency.rules: ACTION=="add", SUBSYSTEM=="usb-serial", '
    'DRIVER=="ftdi_sio", ATTR{{latency_timer}}="1"'
)


def adapter_advice(port: str, *, sysfs_root: str | os.PathLike[str] = "/sys") -> list[str]:
    """Warnings, each with its fix, about the USB adapter behind ``port``.

    Today: an FTDI latency timer above 1 ms (Linux).  Empty when nothing is
    wrong or nothing applies (URLs, ptys, other systems).
    """
    if "://" in port:
        return []
    tty = os.path.basename(os.path.realpath(port))
    timer = Path(sysfs_root, "bus", "usb-serial", "devices", tty, "latency_timer")
    try:
        ms = int(timer.read_text().strip())
    except (OSError, ValueError):
        return []
    if ms <= 1:
        return []
    return [_LATENCY_FIX.format(path=timer, ms=ms)]
