"""The machine's side of a diagnosis: adapters and their driver, who may open the port, who holds it,
the FTDI latency timer, programs known to grab serial ports, WSL2, a board's own UART that cannot carry the line.

Every check reads system files below ``root`` (``/``: ``sys``, ``dev``,
``proc``, ``etc/group``), so a test can hand it a fake tree.  The port
list comes from the caller (pyserial's, in ``ics35 doctor``).  Linux is
checked from its files; on macOS and Windows only the advice applies.
"""

from __future__ import annotations

import os
import stat
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..transports.advice import MINI_UART_DRIVER, MINI_UART_FIX, MINI_UART_PROBLEM, tty_driver
from ..transports.listing import (
    DUAL_ADAPTER_USB_ID,
    HS_ADAPTER_USB_ID,
    KONDO_ADAPTERS,
    SerialPortInfo,
    kondo_usb_without_port,
    linux_adapter_steps,
)
from ..transports.platforms import is_pty_name, latency_timer_advice, port_names_hint
from ..transports.port_holders import below, holders, processes
from ..transports.wire_device import is_url
from .findings import Finding
from .udev import system_groups

# Programs that open FTDI serial ports on their own (Ubuntu ships both).
GRABBERS = {
    "brltty": "the braille display daemon (brltty) claims FTDI serial adapters on Ubuntu",
    "ModemManager": "ModemManager probes new serial ports for modems, holding them for seconds",
}
GRABBER_FIXES = {
    "brltty": "sudo apt remove brltty   (if you use no braille display; or: sudo systemctl mask brltty-udev.service)",
    "ModemManager": "sudo systemctl disable --now ModemManager   (if this machine has no modem)",
}
USBIPD_STEPS = (
    "in Windows PowerShell as administrator: usbipd list ; usbipd bind --busid BUSID ; "
    "usbipd attach --wsl --busid BUSID  (BUSID: the adapter's row in the list); then in WSL: ics35 doctor"
)


@dataclass
class SystemReport:
    """What the machine's side shows: the ports, Kondo devices without one, the port's latency timer."""

    ports: list[SerialPortInfo] = field(default_factory=list)
    kondo_without_port: list[str] = field(default_factory=list)
    latency_timer_ms: int | None = None  # the checked port's, where the system shows it
    findings: list[Finding] = field(default_factory=list)
    # The checked port, its kernel name (ttyUSB0) and whether its adapter is Kondo's (None: not known): for
    # the timer read again once the port is open (see timer_while_open).
    device: str | None = None
    tty: str | None = None
    kondo_adapter: bool | None = None
    timer_read_open: bool = False  # latency_timer_ms was read with the port open
    pseudo_terminal: bool = False  # the checked port is a pty: no adapter behind it to advise about

    def timer_while_open(self, root: str | Path = "/") -> None:
        """Read the port's latency timer again, with the port open (by this program, which asked the driver for
        low latency as it opened it: ftdi_sio then runs the timer at 1 ms and its sysfs file reads 1), and
        judge that reading: the one before the open is what a program that does not ask gets."""
        if self.device is None or self.tty is None:
            return
        before = self.latency_timer_ms
        self.latency_timer_ms = read_latency_timer(Path(root), self.tty)
        self.timer_read_open = True
        kept = [f for f in self.findings if f.check != "latency_timer"]
        self.findings = kept + check_latency_timer(
            self.device, self.tty, self.latency_timer_ms, self.kondo_adapter, before=before
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "ports": [p.to_dict() for p in self.ports],
            "kondo_without_port": self.kondo_without_port,
            "latency_timer_ms": self.latency_timer_ms,
            "pseudo_terminal": self.pseudo_terminal,
        }


def is_pseudo_terminal(port: str | None, root: str | Path = "/") -> bool:
    """Whether ``port`` (a device path, or a link to one such as ``ics35 sim``'s) is a pty slave below ``root``:
    by its resolved name, without opening it."""
    if not port or is_url(port):
        return False
    path = Path(port)
    if not path.is_absolute():  # (a link in the working directory: ./sim-link)
        path = Path.cwd() / path
    real = Path(os.path.realpath(below(Path(root), str(path))))
    try:
        inside = real.relative_to(os.path.realpath(root))
    except ValueError:
        return False
    return is_pty_name("/" + inside.as_posix())


def pseudo_terminal_finding(port: str) -> Finding:
    """What a pty port is, said in place of the adapter checks, which mean nothing for it."""
    return Finding(
        "pty",
        "info",
        f"{port} is a pseudo-terminal: a simulator (ics35 sim) or a bridge (socat, ser2net, a virtual machine's "
        "serial port), not a USB adapter; the adapter's checks (its driver, its timer) are skipped",
    )


def read_latency_timer(root: Path, tty: str) -> int | None:
    """The FTDI latency timer (ms) of ``tty`` (``ttyUSB0``) from sysfs, or None where the system shows none."""
    try:
        return int(below(root, f"/sys/bus/usb-serial/devices/{tty}/latency_timer").read_text().strip())
    except (OSError, ValueError):
        return None


def _may_open(st: os.stat_result, uid: int, gids: set[int]) -> bool:
    mode = st.st_mode
    if uid == 0:
        return True
    if st.st_uid == uid:
        return mode & stat.S_IRUSR != 0 and mode & stat.S_IWUSR != 0
    if st.st_gid in gids:
        return mode & stat.S_IRGRP != 0 and mode & stat.S_IWGRP != 0
    return mode & stat.S_IROTH != 0 and mode & stat.S_IWOTH != 0


def _user_name() -> str:
    for key in ("USER", "LOGNAME"):
        if os.environ.get(key):
            return os.environ[key]
    return ""


def check_port_access(root: Path, port: str, *, uid: int, gids: set[int]) -> list[Finding]:
    """Whether the port exists, and whether this user may open it (with the group to join if not)."""
    node = below(root, port)
    try:
        st = node.stat()
    except FileNotFoundError:
        return [Finding("port", "error", f"{port} does not exist", f"find the adapter's port: {port_names_hint()}")]
    except OSError as exc:
        return [Finding("port", "error", f"{port} cannot be examined: {exc.strerror}")]
    if _may_open(st, uid, gids):
        return []
    groups = system_groups(below(root, "/etc/group"))
    name = next((n for n, (gid, _) in groups.items() if gid == st.st_gid), str(st.st_gid))
    members = groups.get(name, (0, ()))[1]
    user = _user_name()
    if user and user in members:
        return [
            Finding(
                "permission",
                "error",
                f"you may not open {port} yet: you are in group {name} now, but this session started before",
                f"log out and in again (or for this shell: newgrp {name}); check with: groups",
            )
        ]
    return [
        Finding(
            "permission",
            "error",
            f"you may not open {port}: it belongs to group {name} (mode {stat.filemode(st.st_mode)}), "
            "and you are not in it",
            f"sudo usermod -aG {name} $USER, then log out and in again (check with: groups)",
        )
    ]


def check_holders(root: Path, port: str, *, own_pid: int | None) -> list[Finding]:
    found = []
    for pid, name in holders(root, port, own_pid=own_pid):
        fix = GRABBER_FIXES.get(name, f"close {name} (or: kill {pid}), then try again")
        found.append(Finding("holder", "error", f"{port} is held open by {name} (process {pid})", fix))
    return found


# For an FTDI adapter of another vendor (a DIY interface): ics35 udev's rules match Kondo's vendor ID only.
FTDI_LATENCY_RULE = (
    'a udev rule: ACTION=="add", SUBSYSTEM=="usb-serial", DRIVER=="ftdi_sio", ATTR{latency_timer}="1" '
    "in /etc/udev/rules.d/99-ftdi-latency.rules"
)


def check_latency_timer(
    port: str, tty: str, ms: int | None, kondo: bool | None = True, *, before: int | None = None
) -> list[Finding]:
    """A warning when ``port`` (whose kernel name is ``tty``) holds received bytes more than 1 ms.

    ``kondo``: whether the adapter is Kondo's (None: not known), which ``ics35 udev``'s rules fix for good.
    ``before``: for ``ms`` read with the port open, the reading before it opened; a timer at 1 ms only while
    this program has the port (it asked for low latency) is a note for the programs that do not ask.
    """
    if kondo:
        for_good = "ics35 udev --install"
    elif kondo is None:
        for_good = f"ics35 udev --install (Kondo's adapters), or {FTDI_LATENCY_RULE}"
    else:
        for_good = FTDI_LATENCY_RULE
    if ms is None or ms <= 1:
        if ms is None or before is None or before <= 1:
            return []
        return [
            Finding(
                "latency_timer",
                "info",
                f"{port}'s USB adapter timer (its FTDI latency timer) read {before} ms before ics35 opened the port "
                f"and {ms} ms with it open (ics35 asks the driver for low latency): a program that does not ask "
                f"(ser2net, screen, a virtual machine's) may wait {before} ms a transaction",
                f"for every program: {for_good}",
            )
        ]
    return [
        Finding(
            "latency_timer",
            "warning",
            f"{port}'s USB adapter holds received bytes up to {ms} ms (its FTDI latency timer): every "
            f"transaction waits that long",
            f"now: echo 1 | sudo tee /sys/bus/usb-serial/devices/{tty}/latency_timer ; for good: {for_good}",
        )
    ]


CONSOLE_FIX = (
    "turn the serial console off: sudo raspi-config, Interface Options, Serial Port: login shell No, serial "
    "port hardware Yes; or remove its console=... from the kernel command line (cmdline.txt beside config.txt) "
    "and reboot"
)


def _on_usb(root: Path, tty: str) -> bool:
    """Whether ``tty`` is a USB device's (or not known to be otherwise): False for a UART on the board's bus."""
    try:
        bus = os.path.basename(os.readlink(below(root, f"/sys/class/tty/{tty}/device/subsystem")))
    except OSError:
        return True
    return bus in ("usb", "usb-serial")


def check_board_uart(root: Path, device: str, tty: str) -> list[Finding]:
    """An error for a board's own UART that cannot carry the line: a Raspberry Pi's mini UART (no parity), or
    one the kernel writes its console to (its messages would go out onto the servos' line as bytes)."""
    found = []
    if tty_driver(tty, sysfs_root=below(root, "/sys")) == MINI_UART_DRIVER:
        found.append(Finding("uart", "error", MINI_UART_PROBLEM.format(port=device), MINI_UART_FIX))
    try:
        words = below(root, "/proc/cmdline").read_text().split()
    except OSError:
        words = []
    for word in words:
        if not word.startswith("console="):
            continue
        name = word.removeprefix("console=").split(",")[0]
        named = os.path.basename(os.path.realpath(below(root, f"/dev/{name}"))) if name else ""
        if tty in (name, named):
            found.append(
                Finding(
                    "console",
                    "error",
                    f"the kernel writes its console to {device} ({word} on its command line): its messages go out "
                    "onto the servos' line",
                    CONSOLE_FIX,
                )
            )
            break
    return found


def check_grabbers(root: Path) -> list[Finding]:
    running = {name for _, name in processes(root)}
    return [
        Finding("grabber", "warning", f"{GRABBERS[name]}: it is running", GRABBER_FIXES[name])
        for name in GRABBERS
        if name in running
    ]


def is_wsl(root: Path) -> bool:
    try:
        version = below(root, "/proc/version").read_text().lower()
    except OSError:
        return False
    return "microsoft" in version or "wsl" in version


UNTESTED = "untested here without the hardware"


def missing_adapter(
    ports: list[SerialPortInfo], unbound: list[str], *, linux: bool, usb_port: bool = True
) -> list[Finding]:
    """What to say of a Kondo adapter that is missing, worded once for ``ics35 doctor`` (its findings) and
    ``ics35 ports`` (its notes): each Kondo device plugged in with no serial port (``unbound``: its USB IDs),
    with the commands that make ftdi_sio take it; on Linux, no Kondo adapter among ``ports`` at all, unless the
    port checked is not a USB one (``usb_port``: a board's own UART needs no adapter)."""
    found = []
    for usb_id in unbound:
        name = KONDO_ADAPTERS.get(usb_id, "a Kondo USB device")
        found.append(
            Finding(
                "adapter",
                "error",
                f"{name} ({usb_id}) is plugged in but has no serial port: Linux's ftdi_sio driver does not "
                "know its USB ID",
                f"{' ; '.join(linux_adapter_steps(usb_id))}   (for good: ics35 udev --install; {UNTESTED})",
            )
        )
    if linux and usb_port and not unbound and not any(p.kondo for p in ports):
        # (A Kondo device the system shows has no serial port is in ``unbound``: this is lsusb's to tell.)
        found.append(
            Finding(
                "adapter",
                "info",
                "no Kondo adapter (USB vendor 165C) is plugged in, or the system does not show it",
                "check with lsusb: 165c:0006 is the ICS USB adapter HS, 165c:0008 the Dual USB adapter HS; one "
                "listed there needs Linux's ftdi_sio driver told its USB ID: "
                f"{' ; '.join(linux_adapter_steps(HS_ADAPTER_USB_ID))}   (for {DUAL_ADAPTER_USB_ID}: echo 165C 0008 "
                f"instead; for good: ics35 udev --install; {UNTESTED})",
            )
        )
    return found


def missing_adapter_notes(
    ports: list[SerialPortInfo], unbound: list[str], *, linux: bool, port: str | None = None
) -> list[str]:
    """:func:`missing_adapter`'s findings, one line each: ``ics35 ports``'s notes and the web page's.  With
    ``port`` (the one in use) a pseudo-terminal, what it is instead: no adapter is missing behind it."""
    if port is not None and is_pseudo_terminal(port):
        return [pseudo_terminal_finding(port).problem]
    return [f"{f.problem}: {f.fix}" for f in missing_adapter(ports, unbound, linux=linux)]


def check_system(
    ports: list[SerialPortInfo],
    port: str | None = None,
    *,
    root: str | Path = "/",
    uid: int | None = None,
    gids: set[int] | None = None,
    platform: str | None = None,
    own_pid: int | None = None,
) -> SystemReport:
    """Every check of the machine's side, for ``port`` (a device path; None or a URL: the port checks are skipped).

    ``uid``/``gids`` default to this process's; ``platform`` to ``sys.platform``.
    """
    root = Path(root)
    platform = platform or sys.platform
    linux = platform.startswith("linux")
    report = SystemReport(ports=list(ports))
    device = port if port and not is_url(port) and not port.upper().startswith("COM") else None
    if linux:
        report.kondo_without_port = kondo_usb_without_port(below(root, "/sys"))
    if device is not None and is_pseudo_terminal(device, root):
        # (a simulator's or a bridge's pty: who may open it and who holds it still matter, adapters do not)
        report.pseudo_terminal = True
        report.device = device
        report.findings.append(pseudo_terminal_finding(device))
        if linux:
            uid = os.geteuid() if uid is None else uid
            gids = set(os.getgroups()) | {os.getegid()} if gids is None else gids
            report.findings += check_port_access(root, device, uid=uid, gids=gids)
            report.findings += check_holders(root, device, own_pid=own_pid)
        return report
    # (A port on a board's own UART or a PC's serial port needs no USB adapter: none missing is no news.)
    on_usb = device is None or not linux or _on_usb(root, os.path.basename(os.path.realpath(below(root, device))))
    report.findings += missing_adapter(report.ports, report.kondo_without_port, linux=linux, usb_port=on_usb)
    if linux and is_wsl(root) and not any(p.usb_id for p in ports):
        report.findings.append(
            Finding("wsl", "warning", "this is WSL2: it sees a USB adapter only once Windows attaches it", USBIPD_STEPS)
        )
    if linux:
        report.findings += check_grabbers(root)
    if device is not None and linux:
        uid = os.geteuid() if uid is None else uid
        gids = set(os.getgroups()) | {os.getegid()} if gids is None else gids
        report.findings += check_port_access(root, device, uid=uid, gids=gids)
        report.findings += check_holders(root, device, own_pid=own_pid)
        tty = os.path.basename(os.path.realpath(below(root, device)))  # /dev/serial/by-id/... -> ttyUSB0
        report.latency_timer_ms = read_latency_timer(root, tty)
        listed = [p.kondo for p in ports if os.path.basename(p.device) == tty]
        report.device, report.tty, report.kondo_adapter = device, tty, listed[0] if listed else None
        report.findings += check_latency_timer(device, tty, report.latency_timer_ms, report.kondo_adapter)
        report.findings += check_board_uart(root, device, tty)
    elif not linux and any(p.ftdi_based for p in ports):
        report.findings.append(
            Finding(
                "latency_timer",
                "info",
                "this system does not show an FTDI adapter's latency timer (the line measurement below infers it)",
                latency_timer_advice(platform),
            )
        )
    return report
