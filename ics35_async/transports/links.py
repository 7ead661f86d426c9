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

import serial

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
