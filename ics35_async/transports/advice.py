"""Advice about the USB adapter behind a port (the FTDI latency timer)."""

from __future__ import annotations

import os
from pathlib import Path

_LATENCY_FIX = (
    "{path} is {ms} ms: a USB adapter holds received bytes up to that long, which slows every "
    "transaction. Set it to 1 ms now with: echo 1 | sudo tee {path}  -- or for good with the udev rules "
    'ics35 udev --install writes (or your own: ACTION=="add", SUBSYSTEM=="usb-serial", '
    'DRIVER=="ftdi_sio", ATTR{{latency_timer}}="1")'
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
