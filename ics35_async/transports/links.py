"""Lines on another machine: which links carry the baud rate and parity, and what is said about those that do not.

``rfc2217://host:port`` (RFC 2217, e.g. ser2net's ``telnet`` mode with
rfc2217 or pyserial's server) sends the client's baud rate and parity to the
far end's port.  ``socket://host:port`` (a raw TCP bridge: ser2net's ``raw``
mode, ``socat TCP-LISTEN:...``) does not: the line runs at whatever the
bridge's serial side is set to, and pyserial drops our settings silently.
"""

from __future__ import annotations

import contextlib
import logging
import os
import socket
import threading
from urllib.parse import parse_qs, urlsplit

import serial

from ..errors import InvalidArgument
from .wire_device import url_scheme

log = logging.getLogger("ics35_async.transports")

# Schemes whose bytes reach a wire we set nothing on: the far end's settings rule.
_RATE_BLIND_SCHEMES = frozenset({"socket"})

_warned: set[str] = set()
_warned_lock = threading.Lock()


def same_port(a: str, b: str) -> bool:
    """Whether two port names open the same line: equal URLs, or device paths that lead to the same
    device (``/dev/serial/by-id/...`` and the ``/dev/ttyUSB0`` it links to).  A device cannot be open
    twice, so whoever switches between them closes the one first.  A URL's scheme is read in any case
    (``SIM://x`` is ``sim://x``), as opening it reads it."""
    scheme = url_scheme(a)
    if scheme or url_scheme(b):
        return scheme == url_scheme(b) and a.partition("://")[2] == b.partition("://")[2]
    return a == b or os.path.realpath(a) == os.path.realpath(b)


# The options pyserial's handlers take, by scheme, each with what its value must be (None: any, or none).
_LOGGING_LEVELS = ("debug", "info", "warning", "error")
_LINK_OPTIONS: dict[str, dict[str, tuple[str, ...] | None]] = {
    "socket": {"logging": _LOGGING_LEVELS},
    "rfc2217": {"logging": _LOGGING_LEVELS, "ign_set_control": None, "poll_modem": None, "timeout": None},
}


def check_link_url(port: str) -> None:
    """Refuse a ``socket://`` or ``rfc2217://`` URL pyserial cannot read, saying what is wrong with it.

    pyserial's own words for these are Python errors of its handlers (a format string's braces taken for a
    field, ``None`` compared with a number): a URL without a port, a port out of range, an unknown option.
    Read here first, before anything connects.  Other ports pass untouched.

    Raises:
        InvalidArgument: the URL has no host, no port or one outside 1..65535, or an option its scheme
            does not take (or a value it cannot).
    """
    scheme = url_scheme(port)
    options = _LINK_OPTIONS.get(scheme)
    if options is None:
        return
    form = f"{scheme}://HOST:PORT, e.g. {scheme}://192.168.1.20:4000"

    def refuse(what: str) -> InvalidArgument:
        return InvalidArgument(f"cannot open {port!r}: {what} (write {form})")

    parts = urlsplit(port)
    if not parts.hostname:
        raise refuse("the URL names no host")
    _, colon, number = parts.netloc.rpartition(":")
    if not colon or not number or number.endswith("]"):  # (an IPv6 host's bracket: no port after it)
        raise refuse("the URL names no TCP port")
    if not number.isdigit() or not 1 <= int(number) <= 65535:
        raise refuse(f"the TCP port must be a number in 1..65535, got {number!r}")
    for option, values in parse_qs(parts.query, keep_blank_values=True).items():
        if option not in options:
            raise refuse(f"unknown option {option!r} ({scheme}:// takes {', '.join(options)})")
        allowed = options[option]
        if allowed is not None and values[-1] not in allowed:
            raise refuse(f"{option} must be one of {', '.join(allowed)}, got {values[-1]!r}")
        if option == "timeout":
            try:
                float(values[-1])
            except ValueError:
                raise refuse(f"timeout must be a number of seconds, got {values[-1]!r}") from None


def carries_line_settings(port: object) -> bool:
    """Whether opening ``port`` at a baud rate (8E1) sets that rate and parity on the servo line.

    False for ``socket://`` links, whose far end keeps its own settings.
    True for device paths, ``rfc2217://`` and anything else (an in-process
    device is told the rate it is opened at).
    """
    if not isinstance(port, str):
        return True
    return url_scheme(port) not in _RATE_BLIND_SCHEMES


def rate_blind_note(port: str) -> str:
    """What a person must know about a link that does not carry the baud rate and parity."""
    return (
        f"{port} does not carry the baud rate or parity: the servo line runs at whatever the bridge's serial "
        "side is set to (set it to the servos' rate, 8 data bits, EVEN parity, 1 stop bit), "
        "or use rfc2217:// so the settings travel"
    )


def warn_once_if_rate_blind(port: str) -> None:
    """Log :func:`rate_blind_note` as a warning, once per port per process."""
    if carries_line_settings(port):
        return
    with _warned_lock:
        if port in _warned:
            return
        _warned.add(port)
    log.warning("%s", rate_blind_note(port))


def set_no_delay(ser: serial.SerialBase) -> None:
    """Send each write at once on a TCP link (no Nagle hold-back): a command is a few bytes.

    Done on a duplicate of the socket's descriptor (pyserial keeps its socket
    private); socket options belong to the connection, so they apply to both.
    """
    try:
        fd = ser.fileno()
        dup = socket.fromfd(fd, socket.AF_INET, socket.SOCK_STREAM)
    except (OSError, ValueError, AttributeError):
        return
    with contextlib.closing(dup), contextlib.suppress(OSError):
        dup.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
