"""Which serial ports this machine has, which are Kondo adapters, and a Kondo adapter that has no port yet.

Kondo's USB devices carry USB vendor ID 0x165C.  The ICS USB adapter HS
(No.02042, needed for 625000 and 1250000 baud) is an FTDI FT232R with USB ID
165C:0006, the common one (some of Kondo's pages give 0007 by mistake); the
Dual USB adapter HS is 165C:0008.  Linux's ``ftdi_sio`` driver knows
neither ID, so the adapter gets no ``/dev/ttyUSB*`` until told:
:func:`linux_adapter_steps` (or the rules ``ics35 udev`` writes).
"""

from __future__ import annotations

import sys
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

KONDO_VID = 0x165C
FTDI_VID = 0x0403
SYSFS_ROOT = "/sys"

HS_ADAPTER_USB_ID = "165C:0006"
DUAL_ADAPTER_USB_ID = "165C:0008"
KONDO_ADAPTERS = {
    HS_ADAPTER_USB_ID: "ICS USB adapter HS",
    DUAL_ADAPTER_USB_ID: "Dual USB adapter HS",
}
"""Kondo's USB serial adapters by USB ID (both FTDI chips that Linux's ftdi_sio must be told about)."""


def adapter_name(usb_id: str | None) -> str | None:
    """The Kondo adapter a USB ID (``VVVV:PPPP``) belongs to, or None."""
    return KONDO_ADAPTERS.get((usb_id or "").upper())


def linux_adapter_steps(usb_id: str = HS_ADAPTER_USB_ID) -> tuple[str, ...]:
    """The commands that make Linux's ftdi_sio driver take a Kondo adapter (a /dev/ttyUSB* appears)."""
    vid, _, pid = usb_id.partition(":")
    return ("sudo modprobe ftdi_sio", f"echo {vid} {pid} | sudo tee /sys/bus/usb-serial/drivers/ftdi_sio/new_id")


@dataclass(frozen=True)
class SerialPortInfo:
    """One serial port as pyserial's ``list_ports`` sees it."""

    device: str
    description: str
    vid: int | None = None
    pid: int | None = None
    serial_number: str | None = None
    manufacturer: str | None = None

    @property
    def usb_id(self) -> str | None:
        """``VVVV:PPPP`` in hex (as lsusb prints it), or None for a port that is not USB."""
        if self.vid is None or self.pid is None:
            return None
        return f"{self.vid:04X}:{self.pid:04X}"

    @property
    def kondo(self) -> bool:
        return self.vid == KONDO_VID

    @property
    def ftdi_based(self) -> bool:
        """Kondo's adapters and FTDI's own: a latency timer holds received bytes back (see latency advice)."""
        return self.vid in (KONDO_VID, FTDI_VID)

    def to_dict(self) -> dict[str, Any]:
        return {**asdict(self), "usb_id": self.usb_id, "kondo": self.kondo, "adapter": adapter_name(self.usb_id)}


def list_serial_ports() -> list[SerialPortInfo]:
    """The serial ports pyserial finds (``serial.tools.list_ports.comports``), Kondo adapters first."""
    from serial.tools import list_ports

    found = []
    for port in list_ports.comports():
        description = port.description if port.description and port.description != "n/a" else ""
        found.append(
            SerialPortInfo(
                device=str(port.device),
                description=str(description),
                vid=port.vid,
                pid=port.pid,
                serial_number=port.serial_number,
                manufacturer=port.manufacturer,
            )
        )
    return sorted(found, key=lambda p: (not p.kondo, p.vid is None, p.device))


def kondo_usb_without_port(sysfs_root: str | Path | None = None) -> list[str]:
    """USB IDs (``165C:PPPP``) of Kondo devices plugged in with no serial port (Linux; [] elsewhere).

    Read from sysfs: a USB device whose ``idVendor`` is 165c and none of
    whose interfaces has a tty.
    """
    if sysfs_root is None and not sys.platform.startswith("linux"):
        return []
    devices = Path(sysfs_root or SYSFS_ROOT, "bus", "usb", "devices")
    unbound = []
    try:
        entries = sorted(devices.iterdir())
    except OSError:
        return []
    for device in entries:
        try:
            vendor = (device / "idVendor").read_text().strip().lower()
            product = (device / "idProduct").read_text().strip().upper()
        except OSError:
            continue  # an interface, or not a device
        if vendor != f"{KONDO_VID:04x}":
            continue
        interfaces = devices.glob(f"{device.name}:*")
        if not any(any(i.glob("tty*")) or any(i.glob("tty/*")) for i in interfaces):
            unbound.append(f"{KONDO_VID:04X}:{product}")
    return unbound
