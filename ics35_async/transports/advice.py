"""Advice about the hardware behind a port: a USB adapter's FTDI latency timer, a board's UART without parity."""

from __future__ import annotations

import os
from pathlib import Path

from .wire_device import is_url

_LATENCY_FIX = (
    "{path} is {ms} ms: a USB adapter holds received bytes up to that long, which slows every "
    "transaction. Set it to 1 ms now with: echo 1 | sudo tee {path}  -- or for good with the udev rules "
    'ics35 udev --install writes (or your own: ACTION=="add", SUBSYSTEM=="usb-serial", '
    'DRIVER=="ftdi_sio", ATTR{{latency_timer}}="1")'
)


# The Raspberry Pi's mini UART (Linux's 8250_bcm2835aux driver): the BCM2835 peripherals datasheet lists it
# with "no parities".  ICS frames carry even parity, so what it sends is no command a servo takes.
MINI_UART_DRIVER = "bcm2835-aux-uart"
MINI_UART_PROBLEM = (
    "{port} is the Raspberry Pi's mini UART: it sends no parity bit, and ICS frames carry even parity, so no "
    "servo takes what it sends"
)
MINI_UART_FIX = (
    "use the board's PL011 UART: on a Raspberry Pi 3, 4 or Zero W add dtoverlay=disable-bt to config.txt "
    "(/boot/firmware/config.txt; it takes the PL011 back from Bluetooth for GPIO 14 and 15) and reboot, then "
    "--port /dev/ttyAMA0 (/dev/serial0 points there then)"
)


def tty_driver(tty: str, *, sysfs_root: str | os.PathLike[str] = "/sys") -> str:
    """The kernel driver of ``tty`` (``ttyS0``) as sysfs names it, or "" where it shows none."""
    try:
        return os.path.basename(os.readlink(Path(sysfs_root, "class", "tty", tty, "device", "driver")))
    except OSError:
        return ""


def adapter_advice(port: str, *, sysfs_root: str | os.PathLike[str] = "/sys") -> list[str]:
    """Warnings, each with its fix, about the hardware behind ``port``.

    Today: an FTDI latency timer above 1 ms, a Raspberry Pi's mini UART (Linux).  Empty when nothing is
    wrong or nothing applies (URLs, ptys, other systems).
    """
    if is_url(port):
        return []
    tty = os.path.basename(os.path.realpath(port))
    if tty_driver(tty, sysfs_root=sysfs_root) == MINI_UART_DRIVER:
        return [f"{MINI_UART_PROBLEM.format(port=port)}: {MINI_UART_FIX}"]
    timer = Path(sysfs_root, "bus", "usb-serial", "devices", tty, "latency_timer")
    try:
        ms = int(timer.read_text().strip())
    except (OSError, ValueError):
        return []
    if ms <= 1:
        return []
    return [_LATENCY_FIX.format(path=timer, ms=ms)]
