"""Opening a serial port 8E1 with pyserial, and translating what goes wrong into errors that say what to do."""

from __future__ import annotations

import errno
import logging
import os
import re
from typing import Any

import serial
import serial.rfc2217
from serial.rs485 import RS485Settings

from ..errors import (
    IcsError,
    InvalidArgument,
    ParityNotSupported,
    PortBusy,
    PortNotFound,
    PortPermissionDenied,
    SerialPortError,
)

try:
    import termios

    TermiosError: type[Exception] = termios.error
except ImportError:  # no POSIX terminals (Windows): nothing raises termios.error there
    termios = None  # type: ignore[assignment]
    TermiosError = OSError

from .direction import check_direction, is_rs485_refusal, refused, rs485_settings
from .links import carries_line_settings, check_link_url, set_no_delay, warn_once_if_rate_blind
from .platforms import is_pty, misnamed_port_hints, permission_hint, port_names_hint
from .port_holders import held_by
from .sim_link_lock import PTY_DIRS, left_by_a_stopped_simulator
from .wire_device import is_url, url_scheme

log = logging.getLogger("ics35_async.transports")


def posix_fd(ser: serial.SerialBase) -> int | None:
    """The descriptor to wait on for ``ser``: a POSIX tty or pty that pyserial opened, else None.

    None for ports with no descriptor (a Windows COM port, whose ``fileno()``
    raises ``io.UnsupportedOperation``; ``rfc2217://``, ``loop://``) and for
    URL handlers (``socket://`` has a descriptor, but of a socket), and
    wherever there is no termios to set the port up.
    """
    if termios is None or not isinstance(ser, serial.Serial):
        return None
    try:
        return int(ser.fileno())
    except (OSError, ValueError, AttributeError):  # io.UnsupportedOperation is both OSError and ValueError
        return None


def _is_termios_error(exc: Exception) -> bool:
    """Whether ``exc`` is a ``termios.error`` -- told by its shape where termios cannot be imported
    by us (the Windows stand-in), though pyserial's POSIX backend raises it."""
    if isinstance(exc, TermiosError) and not isinstance(exc, OSError):
        return True
    return type(exc).__module__ == "termios" and len(exc.args) == 2 and isinstance(exc.args[0], int)


def _is_pty_path(path: str) -> bool:
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOCTTY | os.O_NONBLOCK)
    except OSError:
        return False
    try:
        return is_pty(fd)
    finally:
        os.close(fd)


# pyserial's Windows backend puts the cause only in its message: "could not open port 'COM3':
# FileNotFoundError(2, 'The system cannot find the file specified.', None, 2)" (the last number: winerror).
_WINDOWS_ERROR = re.compile(r"(\w+)\((\d+), '(.*?)', None, (\d+)\)")
_WINERROR_NOT_FOUND = (2, 3)  # ERROR_FILE_NOT_FOUND, ERROR_PATH_NOT_FOUND
_WINERROR_ACCESS_DENIED = 5  # what Windows says for a COM port another program holds
_WINERROR_GONE = (31, 433, 1167)  # ERROR_GEN_FAILURE, ERROR_NO_SUCH_DEVICE, ERROR_DEVICE_NOT_CONNECTED


def _error_code(exc: BaseException) -> tuple[int | None, int | None]:
    """(errno, winerror) of ``exc``, or of the OSError it was raised from (pyserial's URL handlers chain them)."""
    seen: BaseException | None = exc
    while seen is not None:
        code = getattr(seen, "errno", None)
        if isinstance(code, int):
            return code, getattr(seen, "winerror", None)
        seen = seen.__cause__ or seen.__context__
    match = _WINDOWS_ERROR.search(str(exc))
    if match:
        return int(match.group(2)), int(match.group(4))
    return None, None


def _dangling_link(port: str) -> str | None:
    """What ``port`` names if it is a symbolic link to nothing, else None."""
    try:
        if os.path.islink(port) and not os.path.exists(port):
            return os.readlink(port)
    except OSError:
        pass
    return None


def _check_not_left_by_a_killed_simulator(port: str) -> None:
    """Refuse a simulator's link the simulator left as it was killed: its pty number may be another program's
    now (a terminal's), which must hear no servo command."""
    if not left_by_a_stopped_simulator(port):
        return
    pts = os.readlink(port)
    now = "another program's pty now" if os.path.exists(pts) else "a pty that no longer exists"
    raise PortNotFound(
        errno.ENOENT,
        f"no serial port at {port!r}: the simulator that made this link was killed and left it; it leads to {pts}, "
        f"{now} (not opened; start the simulator again: ics35 sim --link {port} replaces the link)",
    )


def _may_be_plugged_in(exc: PortNotFound) -> PortNotFound:
    """``exc``, marked as a port whose device may yet be plugged in (see PortNotFound.may_be_plugged_in)."""
    exc.may_be_plugged_in = True
    return exc


def translate_open_error(port: str, exc: Exception) -> Exception:
    """Turn what pyserial raised into an error that says what to do."""
    code, winerror = _error_code(exc)
    if winerror in _WINERROR_NOT_FOUND or (winerror is None and code == errno.ENOENT):
        dangling = _dangling_link(port)
        if dangling is not None and dangling.startswith(PTY_DIRS):  # (a stopped simulator's --link)
            return PortNotFound(
                errno.ENOENT,
                f"no serial port at {port!r}: it is a link to {dangling}, a pty that no longer exists (a simulator "
                f"that stopped? start it again: ics35 sim --link {port})",
            )
        if dangling is not None:  # (a udev link whose adapter is gone)
            return _may_be_plugged_in(
                PortNotFound(
                    errno.ENOENT,
                    f"no serial port at {port!r}: it is a link to {dangling}, which is not there (an adapter "
                    f"unplugged; {port_names_hint()})",
                )
            )
        misnamed = misnamed_port_hints(port)
        if misnamed:  # (sim:/?ids=1-3, ttyUSB0: the cable is not what to check)
            return PortNotFound(errno.ENOENT, f"no serial port at {port!r}: {'; '.join(misnamed)}")
        return _may_be_plugged_in(
            PortNotFound(
                errno.ENOENT,
                f"no serial port at {port!r}: check the cable/adapter is plugged in and the name ({port_names_hint()})",
            )
        )
    if winerror == _WINERROR_ACCESS_DENIED:
        return PortBusy(errno.EBUSY, f"{port!r} is in use by another program (Windows says 'access denied' for that)")
    if code in (errno.EACCES, errno.EPERM):
        return PortPermissionDenied(code, f"permission denied opening {port!r}: {permission_hint()}")
    if code in (errno.EBUSY, errno.EAGAIN, errno.EWOULDBLOCK):
        holder = held_by(port)
        if holder is not None:  # (Linux: the program to close is named)
            return PortBusy(code, f"{port!r} is in use by another program: held open by {holder}")
        return PortBusy(code, f"{port!r} is in use by another program (or already open in this one)")
    if winerror in _WINERROR_GONE or code in (errno.ENXIO, errno.ENODEV):
        return SerialPortError(code or errno.ENXIO, f"{port!r} exists but no device answers behind it (unplugged?)")
    if code == errno.ECONNREFUSED:
        return SerialPortError(code, f"cannot open {port!r}: the connection was refused (is the bridge running?)")
    if code == errno.EISDIR:  # pyserial's own text repeats the errno thrice
        return SerialPortError(code, f"{port!r} is a directory, not a serial port")
    if code is None and "Inappropriate ioctl" in str(exc):
        return SerialPortError(errno.ENOTTY, f"{port!r} is not a serial port")
    return SerialPortError(code if code is not None else errno.EIO, f"cannot open {port!r}: {exc}")


_PYSERIAL_SCHEMES = ("alt", "cp2110", "hwgrep", "loop", "rfc2217", "socket", "spy")


# How long a reader thread's read blocks before it looks for shutdown (ports with no descriptor).
READ_POLL = 0.05
# URL schemes that never have a descriptor: opened with the reader thread's timeout at once, since
# every later re-configuration of an RFC 2217 port is a network round trip.
_THREAD_READ_SCHEMES = ("rfc2217", "loop")


def _serial_for_url(port: str, settings: dict[str, Any], rs485: RS485Settings | None) -> serial.SerialBase:
    if rs485 is None:
        return serial.serial_for_url(port, **settings)
    ser = serial.serial_for_url(port, do_not_open=True, **settings)
    ser.rs485_mode = rs485  # applied by the driver as the port opens
    ser.open()
    return ser


def open_serial(port: str, baudrate: int, low_latency: bool, direction: str = "none") -> serial.SerialBase:
    """Open ``port`` 8E1 with pyserial (blocking; run it in an executor).

    ``direction`` (see :mod:`.direction`) asks the driver to toggle RTS while sending.
    """
    direction = check_direction(direction, port)
    check_link_url(port)
    rs485 = rs485_settings(direction)
    is_device_path = not is_url(port)
    scheme = url_scheme(port)
    settings: dict[str, Any] = {
        "baudrate": baudrate,
        "bytesize": serial.EIGHTBITS,
        "parity": serial.PARITY_EVEN,
        "stopbits": serial.STOPBITS_ONE,
        "timeout": READ_POLL if scheme in _THREAD_READ_SCHEMES else 0,
        # A device path never blocks a write; pyserial's RFC 2217 client refuses any
        # write_timeout but None (and the socket handlers need none).
        "write_timeout": 0 if is_device_path else None,
    }
    if is_device_path:
        settings["exclusive"] = True
        _check_not_left_by_a_killed_simulator(port)
    try:
        try:
            ser = _serial_for_url(port, settings, rs485)
        except (serial.SerialException, ValueError, NotImplementedError):
            raise
        except Exception as exc:
            # termios.error (not an OSError) from pyserial's POSIX backend.  A pty refuses a
            # tcsetattr whose only change is PARENB (EINVAL), which is what opening an
            # already-raw pty at our speed asks for.
            if not _is_termios_error(exc):
                raise
            if not (is_device_path and exc.args[0] == errno.EINVAL and _is_pty_path(port)):
                raise SerialPortError(exc.args[0], f"cannot configure {port!r} as 8E1: {exc.args[-1]}") from exc
            log.debug("%s is a pty, which has no parity: opening it 8N1", port)
            ser = _serial_for_url(port, {**settings, "parity": serial.PARITY_NONE}, rs485)
    except serial.SerialException as exc:
        raise translate_open_error(port, exc) from None  # its message says all; __context__ keeps the original
    except (ValueError, NotImplementedError) as exc:
        if rs485 is not None and is_rs485_refusal(exc):
            raise refused(port, direction, exc) from exc
        if isinstance(exc, NotImplementedError):
            raise translate_open_error(port, exc) from None
        # Unknown URL scheme, or a baud rate the driver rejects.
        raise InvalidArgument(f"cannot open {port!r}: {exc}") from exc
    except IcsError:
        raise
    except Exception as exc:  # a URL handler's own failure (a refused connection), or a driver's odd error
        raise translate_open_error(port, exc) from None

    try:
        fd = posix_fd(ser)
        if fd is not None and ser.parity == serial.PARITY_EVEN:
            _check_parity(ser, port, fd)
        elif fd is None and is_device_path and os.name == "posix" and _is_pty_path(port):
            # A pty with no usable descriptor here (the Windows stand-in): a pty drops PARENB,
            # and any later re-configuration that asks for it fails, so run it 8N1 (no wire, no parity).
            ser.parity = serial.PARITY_NONE
        if low_latency and fd is not None and not is_pty(fd):
            _try_low_latency(ser, port)
        if not carries_line_settings(port):
            warn_once_if_rate_blind(port)
            set_no_delay(ser)
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
