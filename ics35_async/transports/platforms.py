"""What differs between Linux, macOS and Windows at the port: pty detection, port names, and the advice we give.

Needs nothing POSIX-only to import: the pty checks use :mod:`os` alone, and
answer False where there are no ptys (Windows).
"""

from __future__ import annotations

import functools
import os
import re
import sys
from pathlib import PurePath

from .wire_device import is_url

# The names pty slaves get: Linux and FreeBSD /dev/pts/N, macOS /dev/ttysNNN (lower-case s:
# Linux's /dev/ttyS0 is a real UART), and the legacy BSD /dev/tty[p-za-e][0-9a-f].
_PTY_NAME = re.compile(r"/dev/(pts/\d+|ttys\d+|tty[p-za-e][0-9a-f])")


def is_pty_name(name: str) -> bool:
    """Whether ``name`` (a resolved device path, e.g. from ``os.ttyname``) is a pty slave's."""
    return _PTY_NAME.fullmatch(name) is not None


@functools.cache
def _pty_major() -> int | None:
    """The device major number of this system's pty slaves, learnt from a pty of our own (None: no ptys)."""
    openpty = getattr(os, "openpty", None)
    if openpty is None:
        return None
    try:
        master, slave = openpty()
    except OSError:
        return None
    try:
        return os.major(os.fstat(slave).st_rdev)
    finally:
        os.close(master)
        os.close(slave)


def is_pty(fd: int) -> bool:
    """Whether ``fd`` is the slave side of a pseudo-terminal.

    Linux: by the device major (136-143 UNIX98 slaves, 3 legacy BSD-style).
    Elsewhere: by the name ``os.ttyname`` gives (macOS ``/dev/ttysNNN``), or
    failing that by the major number a fresh pty of our own has.
    """
    try:
        st = os.fstat(fd)
    except OSError:
        return False
    if sys.platform.startswith("linux"):
        major = os.major(st.st_rdev)
        return 136 <= major <= 143 or major == 3
    try:
        if is_pty_name(os.ttyname(fd)):
            return True
    except (OSError, AttributeError):
        pass
    pty_major = _pty_major()
    return pty_major is not None and st.st_rdev != 0 and os.major(st.st_rdev) == pty_major


# What a person is told, per platform: sys.platform's value, or "" for every other (Linux and the BSDs).
_PORT_NAMES = {
    "win32": "COM ports are listed in Device Manager under 'Ports (COM & LPT)', or by: ics35 ports",
    "darwin": "ls /dev/cu.*  (use the /dev/cu. name, not /dev/tty.), or: ics35 ports",
    "": "ls /dev/ttyUSB* /dev/ttyACM* /dev/serial/by-id/, or: ics35 ports",
}
_PERMISSION = {
    "darwin": "check the port's owner and mode (ls -l); macOS needs no group for USB serial ports",
    "win32": "Windows reports a port that another program holds as access denied: close that program",
    "": "add your user to the group owning the port "
    "(usually 'dialout': sudo usermod -aG dialout $USER, then log in again)",
}
_LATENCY_TIMER = {
    "win32": "Device Manager > Ports (COM & LPT) > the adapter's port > Properties > Port Settings > Advanced > "
    "Latency Timer (msec): 1",
    "darwin": "macOS offers no latency setting for the built-in FTDI driver; FTDI's own VCP driver takes "
    "'LatencyTimer' in its configuration (FTDI application note AN_134). Otherwise give each reply "
    "more time: --timeout / open_bus(adapter_latency=...)",
    "": "echo 1 | sudo tee /sys/bus/usb-serial/devices/ttyUSB0/latency_timer  (for good: a udev rule, "
    'ATTR{latency_timer}="1")',
}


def _for_platform(texts: dict[str, str], platform: str | None) -> str:
    platform = platform or sys.platform
    return texts.get(platform, texts[""])


def port_names_hint(platform: str | None = None) -> str:
    """Where a person finds the name of their serial port on ``platform`` (default: this one)."""
    return _for_platform(_PORT_NAMES, platform)


# Where ``ics35 sim`` serves its pty unless given --link: a directory of its own, removed when it stops.
SIM_PTY_DIR_PREFIX = "ics35-sim-"
SIM_PTY_NAME = "ttyICS0"


def misnamed_port_hints(port: str, platform: str | None = None) -> list[str]:
    """What a port name that opened nothing probably meant on ``platform`` (default: this one): a URL without
    the ``//`` after its scheme, a Windows ``COM`` name elsewhere, a device's name without its ``/dev/``
    directory, the path of a pty simulator that has stopped.  Empty: nothing to say."""
    platform = platform or sys.platform
    path = PurePath(port)
    if path.name == SIM_PTY_NAME and path.parent.name.startswith(SIM_PTY_DIR_PREFIX):
        # (its directory went with it: no cable or adapter to check, and the next one gets a new path)
        return [
            "the path a pty simulator printed (ics35 sim); that simulator has stopped: start it again and use "
            "the new path it prints (ics35 sim --link PATH keeps one path across runs)"
        ]
    url = re.match(r"([A-Za-z][A-Za-z0-9+.-]+):(?!//)/?(.*)", port)  # (two letters at least: not C:)
    if url:  # sim:/?ids=1-6, rfc2217:host:2217
        scheme, rest = url.groups()
        return [f"a URL starts with {scheme}://: {scheme}://{rest}"]
    if platform == "win32" or is_url(port) or "/" in port:
        return []
    if port.upper().startswith("COM"):
        return ["COM names are Windows' own: here a serial port is a /dev/ path"]
    # (A serial port's name, not a terminal's: /dev/tty, /dev/tty1.. are the text consoles.)
    if re.match(r"tty[A-Za-z.]|cu\.|serial", port):
        return [f"a device path starts with /dev/: /dev/{port}"]
    return []


def port_group(port: str) -> str | None:
    """The name of the group that owns the device node ``port`` (``dialout``, ``uucp``...), or None where it
    cannot be told (no such node, no POSIX groups) or is ``root`` (no group for a user to join)."""
    try:
        import grp

        gid = os.stat(port).st_gid
        return None if gid == 0 else grp.getgrgid(gid).gr_name
    except (ImportError, OSError, KeyError):
        return None


def permission_hint(platform: str | None = None) -> str:
    """How to get the right to open a serial port on ``platform`` (default: this one)."""
    return _for_platform(_PERMISSION, platform)


def latency_timer_advice(platform: str | None = None) -> str:
    """How to set an FTDI-based adapter's latency timer (USB receive hold-back) to 1 ms on ``platform``.

    Kondo's ICS USB adapters are FTDI-based.  Only the Linux way is checked
    by the library (sysfs, see :func:`~.advice.adapter_advice`); the others
    are the vendor drivers' documented settings, untested here.
    """
    return _for_platform(_LATENCY_TIMER, platform)
