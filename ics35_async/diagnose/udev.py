"""The udev rules for Kondo's USB adapters on Linux, and where they go.

What they do, rule by rule: make ``ftdi_sio`` take the ICS USB adapter HS
(165C:0006) and the Dual USB adapter HS (165C:0008), which it does not know
by ID; give the port a group its user is in (``dialout``, or ``uucp`` on
some distributions); a stable name by the adapter's serial number
(``/dev/kondo-ics-SERIAL-ifNN``); and the FTDI latency timer at 1 ms.
:func:`rules_text` writes them; ``ics35 udev`` prints or installs them.
"""

from __future__ import annotations

from pathlib import Path

from ..transports.listing import KONDO_ADAPTERS, KONDO_VID

RULES_PATH = Path("/etc/udev/rules.d/99-ics35-kondo.rules")
RELOAD_STEPS = (
    "sudo udevadm control --reload-rules",
    "sudo udevadm trigger",
    "then unplug the adapter and plug it in again",
)
SERIAL_GROUPS = ("dialout", "uucp")
"""The groups that own serial ports: Debian, Ubuntu and Fedora use dialout; Arch and others uucp."""


def system_groups(etc_group: str | Path = "/etc/group") -> dict[str, tuple[int, tuple[str, ...]]]:
    """``/etc/group`` as ``{name: (gid, members)}`` (empty when it cannot be read)."""
    groups: dict[str, tuple[int, tuple[str, ...]]] = {}
    try:
        text = Path(etc_group).read_text(encoding="utf-8", errors="replace")
    except OSError:
        return groups
    for line in text.splitlines():
        fields = line.split(":")
        if len(fields) < 4 or not fields[2].isdigit():
            continue
        groups[fields[0]] = (int(fields[2]), tuple(m for m in fields[3].split(",") if m))
    return groups


def serial_group(etc_group: str | Path = "/etc/group", user_gids: set[int] | None = None) -> str:
    """The serial-port group to use: one the user is in, else the first this system has, else dialout."""
    groups = system_groups(etc_group)
    present = [name for name in SERIAL_GROUPS if name in groups]
    if user_gids is not None:
        for name in present:
            if groups[name][0] in user_gids:
                return name
    return present[0] if present else SERIAL_GROUPS[0]


def rules_text(group: str = "dialout", latency_ms: int = 1) -> str:
    """The rules file: bind both adapters to ftdi_sio, group, stable name, latency timer."""
    vid = f"{KONDO_VID:04x}"
    lines = [
        "# Kondo ICS USB adapters (FTDI chips) for ics35: written by `ics35 udev`.",
        "# Reload after a change: sudo udevadm control --reload-rules && sudo udevadm trigger",
        "",
        "# 1. Linux's ftdi_sio driver does not know Kondo's USB IDs: tell it when an adapter appears.",
    ]
    for usb_id, name in KONDO_ADAPTERS.items():
        pid = usb_id.partition(":")[2].lower()
        lines.append(f"#    {name} ({usb_id})")
        lines.append(
            f'ACTION=="add", SUBSYSTEM=="usb", ENV{{DEVTYPE}}=="usb_device", ATTR{{idVendor}}=="{vid}", '
            f'ATTR{{idProduct}}=="{pid}", RUN+="/sbin/modprobe ftdi_sio", '
            # The ID stays known until reboot: a second write fails harmlessly (quiet for udev's log).
            f"RUN+=\"/bin/sh -c 'echo {vid} {pid} > /sys/bus/usb-serial/drivers/ftdi_sio/new_id 2>/dev/null || true'\""
        )
    pids = "|".join(usb_id.partition(":")[2].lower() for usb_id in KONDO_ADAPTERS)
    lines += [
        "",
        f"# 2. The port: group {group} (add yourself: sudo usermod -aG {group} $USER, then log in again),",
        "#    and a name that stays the same whichever ttyUSB number it gets: /dev/kondo-ics-SERIAL-ifNN.",
        f'ACTION=="add", SUBSYSTEM=="tty", ATTRS{{idVendor}}=="{vid}", ATTRS{{idProduct}}=="{pids}", '
        f'GROUP="{group}", MODE="0660", SYMLINK+="kondo-ics-$attr{{serial}}-if$env{{ID_USB_INTERFACE_NUM}}"',
        "",
        f"# 3. The FTDI latency timer at {latency_ms} ms (default 16 ms: every reply would wait that long).",
        f'ACTION=="add", SUBSYSTEM=="usb-serial", DRIVER=="ftdi_sio", ATTRS{{idVendor}}=="{vid}", '
        f'ATTR{{latency_timer}}="{latency_ms}"',
        "",
    ]
    return "\n".join(lines)
