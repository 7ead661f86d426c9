"""Opening a serial port 8E1 with pyserial, and translating what goes wrong into errors that say what to do."""

from __future__ import annotations

import errno
import logging
import os
import sys
from typing import Any

import serial

from ..errors import InvalidArgument, ParityNotSupported, PortBusy, PortNotFound, PortPermissionDenied, SerialPortError

try:
    import termios

    TermiosError: type[Exception] = termios.error
except ImportError:  # no POSIX terminals (Windows): nothing raises termios.error there
    termios = None  # type: ignore[assignment]
    TermiosError = OSError

log = logging.getLogger("ics35_async.transports")


def is_pty(fd: int) -> bool:
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
        return is_pty(fd)
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


def open_serial(port: str, baudrate: int, low_latency: bool) -> serial.SerialBase:
    """Open ``port`` 8E1 with pyserial (blocking; run it in an executor)."""
    is_device_path = "://" not in port
    settings: dict[str, Any] = {
        "baudrate": baudrate,
        "bytesize": serial.EIGHTBITS,
        "parity": serial.PARITY_EVEN,
        "stopbits": serial.STOPBITS_ONE,
        "timeout": 0,
        # A device path never blocks a write; pyserial's RFC 2217 client refuses any
        # write_timeout but None (and the socket handlers need none).
        "write_timeout": 0 if is_device_path else None,
    }
    if is_device_path:
        settings["exclusive"] = True
    try:
        try:
            ser = serial.serial_for_url(port, **settings)
        except TermiosError as exc:
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
    except (OSError, NotImplementedError) as exc:  # a URL handler's own failure (a refused connection)
        raise _translate_open_error(port, exc) from exc

    try:
        fd = ser.fileno() if isinstance(ser, serial.Serial) else None
        if fd is not None and ser.parity == serial.PARITY_EVEN:
            _check_parity(ser, port, fd)
        if low_latency and fd is not None and not is_pty(fd):
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
    if is_pty(fd):
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
