"""``ics35 ports``: serial ports with description and USB IDs, Kondo adapters marked, the Linux ftdi_sio note.

pyserial's ``list_ports.comports`` is replaced by a list of pyserial's own
``ListPortInfo`` objects (this machine has no USB adapters); the sysfs tree
a Kondo device without a port leaves is built under tmp_path.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import pytest
from serial.tools import list_ports
from serial.tools.list_ports_common import ListPortInfo

from ics35_async.transports import listing
from ics35_async.transports.listing import kondo_usb_without_port, list_serial_ports


def port_info(device: str, description: str, vid: int | None = None, pid: int | None = None) -> ListPortInfo:
    info = ListPortInfo(device, skip_link_detection=True)
    info.description = description
    info.vid, info.pid = vid, pid
    info.serial_number = "A10KZ9" if vid else None
    return info


@pytest.fixture
def machine_ports(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> list[ListPortInfo]:
    ports = [
        port_info("/dev/ttyS0", "n/a"),
        port_info("/dev/ttyUSB1", "FT232R USB UART", 0x0403, 0x6001),
        port_info("/dev/ttyUSB0", "DUAL USB ADAPTER HS", 0x165C, 0x0008),
    ]
    monkeypatch.setattr(list_ports, "comports", lambda include_links=False: list(ports))
    monkeypatch.setattr(listing, "SYSFS_ROOT", str(tmp_path / "sys"))  # no sysfs: nothing unbound
    return ports


def usb_device(root: Path, name: str, vendor: str, product: str, tty: str | None) -> None:
    devices = root / "bus" / "usb" / "devices"
    (devices / name).mkdir(parents=True)
    (devices / name / "idVendor").write_text(vendor + "\n")
    (devices / name / "idProduct").write_text(product + "\n")
    interface = devices / f"{name}:1.0"
    interface.mkdir()
    if tty:
        (interface / tty).mkdir()


def test_kondo_adapters_come_first_and_are_marked(machine_ports: list[ListPortInfo]) -> None:
    found = list_serial_ports()
    assert [p.device for p in found] == ["/dev/ttyUSB0", "/dev/ttyUSB1", "/dev/ttyS0"]
    assert [p.kondo for p in found] == [True, False, False]
    assert [p.usb_id for p in found] == ["165C:0008", "0403:6001", None]
    assert found[2].description == ""  # pyserial's "n/a"


def test_cli_table(machine_ports: list[ListPortInfo], cli: Any) -> None:
    result = cli("ports")
    assert result.code == 0, result.err
    lines = result.out.splitlines()
    kondo = next(line for line in lines if "/dev/ttyUSB0" in line)
    assert "DUAL USB ADAPTER HS" in kondo and "165C:0008" in kondo and "Kondo adapter" in kondo
    ftdi = next(line for line in lines if "/dev/ttyUSB1" in line)
    assert "0403:6001" in ftdi and "Kondo" not in ftdi
    assert "/dev/ttyS0" in result.out


def test_cli_json(machine_ports: list[ListPortInfo], cli: Any) -> None:
    result = cli("ports", "--json")
    assert result.code == 0, result.err
    data = result.json()
    assert [(p["device"], p["usb_id"], p["kondo"]) for p in data["ports"]] == [
        ("/dev/ttyUSB0", "165C:0008", True),
        ("/dev/ttyUSB1", "0403:6001", False),
        ("/dev/ttyS0", None, False),
    ]
    assert data["kondo_without_port"] == []


def test_cli_no_ports_exits_3(monkeypatch: pytest.MonkeyPatch, tmp_path: Path, cli: Any) -> None:
    monkeypatch.setattr(list_ports, "comports", lambda include_links=False: [])
    monkeypatch.setattr(listing, "SYSFS_ROOT", str(tmp_path / "sys"))
    result = cli("ports", "--json")
    assert result.code == 3
    assert result.json()["ports"] == []
    assert "no serial ports found" in result.err
    assert cli("ports").code == 3


def test_kondo_device_without_a_port_is_found_in_sysfs(tmp_path: Path) -> None:
    root = tmp_path / "sys"
    usb_device(root, "1-1", "165c", "0008", tty=None)  # the Dual USB adapter HS, no driver took it
    usb_device(root, "1-2", "165c", "0006", tty="ttyUSB3")  # another Kondo adapter with its port
    usb_device(root, "1-3", "0403", "6001", tty=None)  # not Kondo
    assert kondo_usb_without_port(root) == ["165C:0008"]
    assert kondo_usb_without_port(tmp_path / "nothing") == []


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the ftdi_sio note is Linux's")
def test_cli_tells_how_to_make_the_dual_adapter_appear(
    machine_ports: list[ListPortInfo], tmp_path: Path, cli: Any
) -> None:
    usb_device(tmp_path / "sys", "1-1", "165c", "0008", tty=None)
    result = cli("ports")
    assert result.code == 0
    assert "sudo modprobe ftdi_sio" in result.err
    assert "echo 165C 0008 | sudo tee /sys/bus/usb-serial/drivers/ftdi_sio/new_id" in result.err
    assert "untested" in result.err
    data = cli("ports", "--json").json()
    assert data["kondo_without_port"] == ["165C:0008"]
    assert any("new_id" in note for note in data["notes"])


def test_latency_advice_for_ftdi_ports_off_linux(
    machine_ports: list[ListPortInfo], monkeypatch: pytest.MonkeyPatch, cli: Any
) -> None:
    monkeypatch.setattr(sys, "platform", "win32")
    result = cli("ports")
    assert result.code == 0
    assert "Latency Timer" in result.err
    assert "/dev/ttyS0: set" not in result.err  # only for FTDI-based adapters


def test_this_machine(cli: Any) -> None:
    """Whatever this machine has: the listing and the exit code agree."""
    result = cli("ports", "--json")
    assert result.code == (0 if result.json()["ports"] else 3)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the ftdi_sio note is Linux's")
def test_the_common_hs_adapter_is_told_its_own_usb_id(
    machine_ports: list[ListPortInfo], tmp_path: Path, cli: Any
) -> None:
    usb_device(tmp_path / "sys", "1-1", "165c", "0006", tty=None)  # the ICS USB adapter HS (FT232R), unbound
    result = cli("ports")
    assert "ICS USB adapter HS (165C:0006)" in result.err
    assert "echo 165C 0006 | sudo tee /sys/bus/usb-serial/drivers/ftdi_sio/new_id" in result.err
    assert "165C 0008" not in result.err


def test_adapters_are_named_by_usb_id() -> None:
    from ics35_async.transports.listing import adapter_name

    assert adapter_name("165C:0006") == "ICS USB adapter HS"
    assert adapter_name("165c:0008") == "Dual USB adapter HS"
    assert adapter_name("0403:6001") is None and adapter_name(None) is None


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the ftdi_sio note is Linux's")
@pytest.mark.parametrize("unbound", [None, "0006", "0008"], ids=["none-plugged-in", "hs-unbound", "dual-unbound"])
def test_ports_and_doctor_say_the_same_of_a_missing_kondo_adapter(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, cli: Any, unbound: str | None
) -> None:
    # ports told the ftdi_sio commands where doctor said "plugged in, or the system does not show it" (and
    # doctor's fix left out that the commands are untested): one text now, whichever command a user runs.
    others = [port_info("/dev/ttyS0", "n/a"), port_info("/dev/ttyUSB1", "FT232R USB UART", 0x0403, 0x6001)]
    monkeypatch.setattr(list_ports, "comports", lambda include_links=False: list(others))
    monkeypatch.setattr(listing, "SYSFS_ROOT", str(tmp_path / "sys"))
    (tmp_path / "sys" / "bus" / "usb" / "devices").mkdir(parents=True)
    if unbound is not None:
        usb_device(tmp_path / "sys", "1-1", "165c", unbound, tty=None)
    notes = cli("ports", "--json").json()["notes"]
    doctor = cli("doctor", "--system-root", str(tmp_path), "--json")
    assert doctor.code == 0, doctor.err
    (finding,) = [f for f in doctor.json()["findings"] if f["check"] == "adapter"]
    said = f"{finding['problem']}: {finding['fix']}"
    assert said in notes, (said, notes)
    assert len([n for n in notes if "165C" in n]) == 1, notes  # (said once)
    if unbound is not None:
        assert f"165C:{unbound}" in said and f"echo 165C {unbound} |" in said and "has no serial port" in said
    else:
        assert "lsusb" in said and "no Kondo adapter" in said
