"""ics35 doctor and its library (ics35_async.diagnose): every system check against a fake system tree,
the line part against the simulator's USB adapter model, and ics35 udev."""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from ics35_async.cli import ExitCode
from ics35_async.diagnose.line_report import LineReport, suspect_latency_timer
from ics35_async.diagnose.system import check_system, is_pseudo_terminal
from ics35_async.diagnose.udev import rules_text, serial_group
from ics35_async.transports.listing import SerialPortInfo
from ics35_async.transports.port_holders import holders
from tests.support.timing import GUARD, NO_TIMEOUTS_OPTION

UID, GID = 1000, 1000
DIALOUT = 20
FTDI_PORT = SerialPortInfo("/dev/ttyUSB0", "ICS USB ADAPTER HS", 0x165C, 0x0006)


def tree(tmp_path: Path, *, mode: int = 0o660, gid: int = DIALOUT, members: str = "") -> Path:
    """A fake system: /dev/ttyUSB0 (owned by root, group ``gid``), /etc/group, an empty /proc and /sys."""
    root = tmp_path / "root"
    (root / "dev").mkdir(parents=True)
    (root / "etc").mkdir()
    (root / "proc").mkdir()
    (root / "sys" / "bus" / "usb" / "devices").mkdir(parents=True)
    node = root / "dev" / "ttyUSB0"
    node.write_text("")
    node.chmod(mode)
    if os.geteuid() == 0:
        os.chown(node, 0, gid)
    (root / "etc" / "group").write_text(f"root:x:0:\ndialout:x:{DIALOUT}:{members}\nusers:x:100:\n")
    return root


def check(root: Path, ports: list[SerialPortInfo] | None = None, **kw: Any) -> Any:
    st = (root / "dev" / "ttyUSB0").stat() if (root / "dev" / "ttyUSB0").exists() else None
    # The node belongs to whoever runs the test: check as another user who is not in its group.
    owner_gid = st.st_gid if st else DIALOUT
    kw.setdefault("uid", (st.st_uid + 1) if st else UID)
    kw.setdefault("gids", {owner_gid + 1})
    return check_system([FTDI_PORT] if ports is None else ports, "/dev/ttyUSB0", root=root, platform="linux", **kw)


def by_check(report: Any, name: str) -> list[Any]:
    return [f for f in report.findings if f.check == name]


def test_an_unbound_hs_adapter_gets_the_commands_for_its_own_usb_id(tmp_path: Path) -> None:
    root = tree(tmp_path)
    device = root / "sys" / "bus" / "usb" / "devices" / "1-1"
    device.mkdir()
    (device / "idVendor").write_text("165c\n")
    (device / "idProduct").write_text("0006\n")
    (root / "sys" / "bus" / "usb" / "devices" / "1-1:1.0").mkdir()  # its interface: no tty
    report = check(root, ports=[])
    assert report.kondo_without_port == ["165C:0006"]
    (finding,) = by_check(report, "adapter")
    assert finding.severity == "error" and "ICS USB adapter HS (165C:0006)" in finding.problem
    assert "echo 165C 0006 | sudo tee /sys/bus/usb-serial/drivers/ftdi_sio/new_id" in finding.fix


def test_a_port_the_user_may_not_open_names_the_group_to_join(tmp_path: Path) -> None:
    root = tree(tmp_path)
    st = (root / "dev" / "ttyUSB0").stat()
    group_line = f"root:x:0:\nserialgrp:x:{st.st_gid}:\n"
    (root / "etc" / "group").write_text(group_line)
    (finding,) = by_check(check(root), "permission")
    assert finding.severity == "error" and "group serialgrp" in finding.problem
    assert finding.fix.startswith("sudo usermod -aG serialgrp $USER")
    assert by_check(check(root, gids={st.st_gid}), "permission") == []  # in the group: fine
    assert by_check(check(root, uid=0), "permission") == []  # root may


def test_a_user_added_to_the_group_but_not_logged_in_again_is_told_so(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    root = tree(tmp_path)
    st = (root / "dev" / "ttyUSB0").stat()
    (root / "etc" / "group").write_text(f"dialout:x:{st.st_gid}:alice,bob\n")
    monkeypatch.setenv("USER", "bob")
    (finding,) = by_check(check(root), "permission")
    assert "this session started before" in finding.problem and "log out and in again" in finding.fix


def test_a_missing_port_is_an_error(tmp_path: Path) -> None:
    root = tree(tmp_path)
    (root / "dev" / "ttyUSB0").unlink()
    (finding,) = by_check(check(root), "port")
    assert "/dev/ttyUSB0 does not exist" in finding.problem


def test_the_process_holding_the_port_is_named(tmp_path: Path) -> None:
    root = tree(tmp_path)
    for pid, name, target in ((4242, "minicom", "/dev/ttyUSB0"), (77, "bash", "/dev/pts/1")):
        fd = root / "proc" / str(pid) / "fd"
        fd.mkdir(parents=True)
        (root / "proc" / str(pid) / "comm").write_text(name + "\n")
        os.symlink(target, fd / "3")
    assert holders(root, "/dev/ttyUSB0") == [(4242, "minicom")]
    (finding,) = by_check(check(root), "holder")
    assert "held open by minicom (process 4242)" in finding.problem and "kill 4242" in finding.fix
    assert by_check(check(root, own_pid=4242), "holder") == []  # doctor's own process does not count


def test_brltty_and_modemmanager_are_named_with_their_fixes(tmp_path: Path) -> None:
    root = tree(tmp_path)
    for pid, name in ((10, "brltty"), (11, "ModemManager"), (12, "sshd")):
        (root / "proc" / str(pid)).mkdir()
        (root / "proc" / str(pid) / "comm").write_text(name + "\n")
    found = by_check(check(root), "grabber")
    assert [f.fix.split()[0:3] for f in found] == [["sudo", "apt", "remove"], ["sudo", "systemctl", "disable"]]


def test_the_latency_timer_is_read_from_sysfs(tmp_path: Path) -> None:
    root = tree(tmp_path)
    timer = root / "sys" / "bus" / "usb-serial" / "devices" / "ttyUSB0" / "latency_timer"
    timer.parent.mkdir(parents=True)
    timer.write_text("16\n")
    report = check(root)
    assert report.latency_timer_ms == 16
    (finding,) = by_check(report, "latency_timer")
    assert "up to 16 ms" in finding.problem
    assert "echo 1 | sudo tee /sys/bus/usb-serial/devices/ttyUSB0/latency_timer" in finding.fix
    timer.write_text("1\n")
    report = check(root)
    assert report.latency_timer_ms == 1 and by_check(report, "latency_timer") == []


def test_wsl2_without_usb_ports_is_told_about_usbipd(tmp_path: Path) -> None:
    root = tree(tmp_path)
    (root / "proc" / "version").write_text("Linux version 5.15.153.1-microsoft-standard-WSL2\n")
    (finding,) = by_check(check(root, ports=[]), "wsl")
    assert "usbipd attach --wsl" in finding.fix
    (root / "proc" / "version").write_text("Linux version 6.8.0-generic\n")
    assert by_check(check(root, ports=[]), "wsl") == []


def test_other_systems_get_the_latency_advice_for_ftdi_ports(tmp_path: Path) -> None:
    report = check_system([FTDI_PORT], "/dev/cu.usbserial-1", root=tmp_path, platform="darwin")
    (finding,) = by_check(report, "latency_timer")
    assert finding.severity == "info" and "AN_134" in finding.fix


def test_the_timer_is_inferred_from_round_trips() -> None:
    assert suspect_latency_timer([0.016] * 20, 115200) == 16
    assert suspect_latency_timer([0.0081] * 20, 115200) == 8
    assert suspect_latency_timer([0.0007] * 20, 115200) is None  # the wire's own time: nothing held back
    assert suspect_latency_timer([0.011] * 20, 115200) is None  # slow, but no timer explains it
    report = LineReport(115200, {1: [0.0007] * 10}, system_latency_timer_ms=16)
    assert report.suspected_timer_ms == 16  # the system shows one: it counts even if the times hide it


def test_slow_round_trips_beside_a_timer_the_system_shows_at_1_ms_are_not_blamed_on_the_timer() -> None:
    # A busy machine (or a bridge) can make round trips look like a 16 ms timer's; with the system showing the
    # port's timer at 1 ms, doctor said they "sit at a 16 ms USB latency timer" and advised setting it to 1 ms.
    report = LineReport(115200, {1: [0.016] * 20}, system_latency_timer_ms=1)
    assert report.suspected_timer_ms is None
    found = report.judge()
    assert [f.check for f in found] == ["round_trip"], found
    assert report.cycle_hz()["after_fixes"] == []


def test_udev_rules_bind_both_adapters_and_set_the_timer() -> None:
    text = rules_text("uucp")
    for pid in ("0006", "0008"):
        assert f'ATTR{{idProduct}}=="{pid}"' in text and f"echo 165c {pid} > /sys/bus/usb-serial/drivers" in text
    assert 'ATTR{latency_timer}="1"' in text and 'GROUP="uucp"' in text and "$attr{serial}" in text


def test_the_serial_group_is_one_the_user_is_in(tmp_path: Path) -> None:
    group = tmp_path / "group"
    group.write_text("uucp:x:14:\ndialout:x:20:\n")
    assert serial_group(group, {14}) == "uucp"
    assert serial_group(group, {99}) == "dialout"
    group.write_text("uucp:x:14:\n")
    assert serial_group(group, {99}) == "uucp"
    assert serial_group(tmp_path / "nothing", set()) == "dialout"


# ----------------------------------------------------------------------------- the command


# Real time: the inference reads the round trips' wall-clock times through the adapter model, which a
# machine busy with other tests stretches past the timer (see CONTRIBUTING).
@pytest.mark.realtime
def test_doctor_names_a_16_ms_latency_timer_on_the_adapter_model(cli: Any) -> None:
    # Only the IDs there, each reply waited for (the timer's 16 ms plus whatever a busy machine adds).
    line = ("--port", "sim://?ids=1,2&adapter=ftdi&latency_timer=16", "--ids", "1,2", *NO_TIMEOUTS_OPTION)
    result = cli("doctor", *line, "--samples", "8", "--json")
    assert result.code == 0, result.err
    data = result.json()
    assert data["servos"] == [1, 2] and data["transactions"] == 16
    assert data["latency_timer_suspected_ms"] == 16
    assert 14 <= data["round_trip_ms"]["median"] <= data["round_trip_ms"]["p99"]
    fixes = data["cycle_hz"]["after_fixes"]
    assert fixes[0]["fix"] == "latency timer 1 ms" and fixes[0]["cycle_hz_32"] > 5 * data["cycle_hz"]["now_32"]
    (finding,) = [f for f in data["findings"] if f["check"] == "latency_timer"]
    assert "16 ms USB latency timer" in finding["problem"] and finding["fix"]


# Real time, as above.
@pytest.mark.realtime
def test_doctor_on_the_simulators_adapter_model_gives_the_simulators_fix(cli: Any) -> None:
    # "fix: echo 1 | sudo tee /sys/bus/usb-serial/devices/ttyUSB0/latency_timer" for a timer that is a URL key:
    # on the simulator there is no such file, and the page that shows the model asks to try the fix.
    port = "sim://?ids=1,2&adapter=ftdi&latency_timer=16"
    line = ("--ids", "1,2", *NO_TIMEOUTS_OPTION, "--samples", "8", "--json")
    data = cli("doctor", "--port", port, *line).json()
    (finding,) = [f for f in data["findings"] if f["check"] == "latency_timer"]
    assert "latency_timer=1" in finding["fix"] and "sudo" not in finding["fix"], finding
    fixed = cli("doctor", "--port", port.replace("latency_timer=16", "latency_timer=1"), *line).json()
    assert fixed["latency_timer_suspected_ms"] is None, fixed
    assert not [f for f in fixed["findings"] if f["check"] == "latency_timer"], fixed["findings"]


# Real time: a machine busy with other tests stretches the simulator's round trips to look like a timer's.
@pytest.mark.realtime
def test_doctor_reports_a_round_trip_and_no_timer_without_the_adapter(cli: Any) -> None:
    result = cli("doctor", "--port", "sim://?ids=3&realtime=1", "--samples", "20", "--json")
    assert result.code == 0, result.err
    data = result.json()
    assert data["servos"] == [3] and data["round_trip_ms"]["median"] > 0
    assert data["latency_timer_suspected_ms"] is None
    assert data["cycle_hz"]["after_fixes"] == []
    assert not [f for f in data["findings"] if f["check"] == "latency_timer"]


def position_cycle_hz(read_round_trip: float, baud: int, servos: int) -> float:
    """A position cycle's rate from a read's round trip: the read's own wire time (2 bytes out, 3 back) swapped
    for a position command's (3 out, 3 back), capped at the wire's limit (100 us turnaround per transaction)."""
    byte = 11 / baud
    position = read_round_trip - 5 * byte + 6 * byte
    return 1 / (servos * max(position, 6 * byte + 100e-6))


def test_doctor_expects_a_position_cycle_and_never_above_the_wire(cli: Any) -> None:
    result = cli("doctor", "--port", "sim://?ids=3&realtime=1", "--samples", "40", "--json")
    assert result.code == 0, result.err
    data = result.json()
    rates, median = data["cycle_hz"], data["round_trip_ms"]["median"] * 1e-3
    assert rates["now_32"] <= rates["wire_limit_32"]
    assert rates["now_32"] == pytest.approx(position_cycle_hz(median, 115200, 32), rel=0.01)
    assert rates["now"] == pytest.approx(position_cycle_hz(median, 115200, 1), rel=0.01)


def test_round_trips_faster_than_the_wire_give_the_wire_limit() -> None:
    report = LineReport(1250000, {1: [5 * 11 / 1250000] * 5})  # a read exactly its wire time: no turnaround
    rates = report.cycle_hz()
    assert rates["now_32"] == pytest.approx(rates["wire_limit_32"], rel=0.01)
    slow = LineReport(115200, {1: [16e-3] * 5}).cycle_hz()  # a 16 ms timer
    assert slow["now_32"] == pytest.approx(position_cycle_hz(16e-3, 115200, 32), rel=0.01)


# Real time: the inference reads the round trips' wall-clock times through the adapter model, which a
# machine busy with other tests stretches past the timer (see CONTRIBUTING).
@pytest.mark.realtime
def test_doctor_text_and_no_servo(cli: Any) -> None:
    line = ("--port", "sim://?ids=1&adapter=ftdi&latency_timer=16", "--ids", "1", *NO_TIMEOUTS_OPTION)
    result = cli("doctor", *line, "--samples", "20")
    assert result.code == 0
    assert "latency timer suspected: 16 ms" in result.out and "fix:" in result.err
    none = cli("doctor", "--port", "sim://?ids=none", "--ids", "0-3", "--json")
    assert none.code == 4
    assert none.json()["servos"] == [] and "no servo answered" in none.err


def test_doctor_on_the_simulator_says_so_and_checks_no_adapter(cli: Any) -> None:
    # "info: no Kondo adapter (USB vendor 165C) is plugged in" and the machine's serial ports, under a line
    # that was the simulator: advice about hardware the user did not ask about, beside figures that read
    # as a real line's.
    result = cli("doctor", "--port", "sim://?ids=1-3", "--samples", "6")
    assert result.code == 0, result.err
    said = result.out + result.err
    assert "simulat" in result.out and "Kondo adapter" not in said and "lsusb" not in said, said
    assert not [ln for ln in result.out.splitlines() if ln.startswith("ports")], result.out
    assert "line (simulated)" in result.out
    data = cli("doctor", "--port", "sim://?ids=1-3", "--samples", "6", "--json").json()
    assert data["simulated"] is True and data["servos"] == [1, 2, 3] and data["ports"] == []
    assert not {f["check"] for f in data["findings"]} & {"adapter", "grabber", "wsl", "latency_timer"}
    # Without --port, the machine is what is checked: its adapters still are.
    assert cli("doctor", "--json").json()["simulated"] is False


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the system checks read Linux's files")
def test_doctor_reads_the_system_from_the_given_root(tmp_path: Path, cli: Any) -> None:
    root = tree(tmp_path)
    (root / "dev" / "ttyUSB0").rename(root / "dev" / "ttyICS-missing")
    timer = root / "sys" / "bus" / "usb-serial" / "devices" / "ttyICS-missing" / "latency_timer"
    timer.parent.mkdir(parents=True)
    timer.write_text("16\n")
    result = cli("doctor", "--port", "/dev/ttyICS-missing", "--system-root", str(root), "--json")
    assert result.code == 3  # the port cannot be opened (it is not on this machine)
    data = result.json()
    assert data["latency_timer_ms"] == 16 and data["latency_timer_suspected_ms"] is None
    checks = {f["check"] for f in data["findings"]}
    assert {"latency_timer", "line"} <= checks


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the system checks read Linux's files")
def test_doctor_names_a_missing_port_once_with_its_hints(cli: Any) -> None:
    for port, hint in (("/dev/ttyUSB-ics35-none", "ls /dev/ttyUSB*"), ("ttyUSB0", "/dev/ttyUSB0")):
        result = cli("doctor", "--port", port)
        assert result.code == 3, result.err
        errors = [ln for ln in result.err.splitlines() if ln.startswith("error:")]
        assert len(errors) == 1 and port in errors[0], result.err
        assert hint in result.err


def test_udev_prints_the_rules(cli: Any) -> None:
    if not sys.platform.startswith("linux"):
        assert cli("udev").code == 2
        return
    result = cli("udev")
    assert result.code == 0
    assert "165c" in result.out and '"0006"' in result.out and '"0008"' in result.out


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="udev is Linux's")
def test_udev_install_writes_where_it_may(tmp_path: Path, cli: Any) -> None:
    target = tmp_path / "99-ics35-kondo.rules"
    result = cli("udev", "--install", "--path", str(target))
    assert result.code == 0, result.err
    assert "ftdi_sio" in target.read_text() and "udevadm control --reload-rules" in result.err


def one_error(result: Any) -> str:
    """The one ``error:`` line of a failed command (a traceback fails the test in ``cli``)."""
    errors = [ln for ln in result.err.splitlines() if ln.startswith("error:")]
    assert len(errors) == 1, result.err
    return errors[0]


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="udev is Linux's")
def test_udev_install_says_in_one_line_why_it_cannot_write_and_asks_no_sudo_for_it(tmp_path: Path, cli: Any) -> None:
    # A directory that is not there (a machine or container without udev): sudo tee cannot make it, so no sudo
    # question (as root it said "needs root to write, and there is no sudo here").
    missing = tmp_path / "no-such-dir" / "x.rules"
    result = cli("udev", "--install", "--path", str(missing), stdin="y\n")
    assert result.code == 3 and "[y/N]" not in result.err, result.err
    assert f"{missing.parent} does not exist" in one_error(result) and not missing.parent.exists()
    a_file = tmp_path / "a-file"
    a_file.write_text("")
    result = cli("udev", "--install", "--path", str(a_file / "x.rules"), stdin="y\n")
    assert result.code == 3 and "[y/N]" not in result.err, result.err
    assert f"{a_file} is not a directory" in one_error(result)
    # A write that fails although the file may be written (a full disk; /proc and /sys as root): a traceback.
    result = cli("udev", "--install", "--path", "/dev/full")
    assert result.code == 3, result.err
    assert "cannot write /dev/full: No space left on device" in one_error(result)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="udev is Linux's")
def test_udev_refuses_to_install_rules_for_a_group_this_system_does_not_have(tmp_path: Path, cli: Any) -> None:
    # GROUP="dailout" in a rule: udev leaves the port root's, and the user finds out at the next plug-in.
    target = tmp_path / "x.rules"
    result = cli("udev", "--install", "--group", "ics35-no-such-group", "--path", str(target))
    assert result.code == 2, result.err
    assert "group ics35-no-such-group does not exist" in one_error(result) and not target.exists()
    printed = cli("udev", "--group", "ics35-no-such-group")  # (printed for another machine, perhaps: said, not refused)
    assert printed.code == 0 and 'GROUP="ics35-no-such-group"' in printed.out
    assert "group ics35-no-such-group does not exist" in printed.err


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="udev is Linux's")
def test_udev_install_says_when_udevadm_is_missing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, cli: Any) -> None:
    empty = tmp_path / "bin"
    empty.mkdir()
    monkeypatch.setenv("PATH", str(empty))
    target = tmp_path / "x.rules"
    result = cli("udev", "--install", "--path", str(target))
    assert result.code == 0 and target.exists(), result.err
    assert "udevadm is not on this system" in result.err


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="udev is Linux's")
def test_udev_install_runs_sudo_only_after_a_yes(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, cli: Any) -> None:
    # A stand-in for the system's sudo (not our code): it logs its arguments, lets its caller write the
    # directory (the test's own) and runs them.
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    log = tmp_path / "sudo.log"
    sudo = bin_dir / "sudo"
    sudo.write_text(f'#!/bin/sh\necho "$@" >> {log}\nchmod u+w "$(dirname "$2")"\nexec "$@"\n')
    sudo.chmod(0o755)
    monkeypatch.setenv("PATH", f"{bin_dir}{os.pathsep}{os.environ['PATH']}")
    rules_d = tmp_path / "rules.d"
    rules_d.mkdir()
    rules_d.chmod(0o555)  # not ours to write
    target = rules_d / "99-ics35-kondo.rules"
    if os.geteuid() == 0:  # root writes it itself: sudo would change nothing
        done = cli("udev", "--install", "--path", str(target), stdin="")
        assert done.code == 0, done.err
        assert not log.exists() and "165c 0006" in target.read_text()
        return
    refused = cli("udev", "--install", "--path", str(target), stdin="n\n")
    assert refused.code == 5 and "[y/N]" in refused.err and "sudo tee" in refused.err
    assert "nothing was written" in refused.err
    assert not log.exists() and not target.exists()  # sudo never ran
    silent = cli("udev", "--install", "--path", str(target), stdin="")  # no answer: no sudo
    assert silent.code == 5 and not log.exists() and not target.exists()
    done = cli("udev", "--install", "--path", str(target), stdin="y\n")
    assert done.code == 0, done.err
    assert log.read_text().split() == ["tee", str(target)]
    assert "165c 0006" in target.read_text() and "udevadm trigger" in done.err


def test_a_port_named_by_id_reads_the_timer_of_its_tty(tmp_path: Path) -> None:
    root = tree(tmp_path)
    by_id = root / "dev" / "serial" / "by-id"
    by_id.mkdir(parents=True)
    (by_id / "usb-Kondo_ICS_HS_A1B2-if00-port0").symlink_to("../../ttyUSB0")
    timer = root / "sys" / "bus" / "usb-serial" / "devices" / "ttyUSB0" / "latency_timer"
    timer.parent.mkdir(parents=True)
    timer.write_text("16\n")
    port = "/dev/serial/by-id/usb-Kondo_ICS_HS_A1B2-if00-port0"
    report = check_system([FTDI_PORT], port, root=root, platform="linux", uid=0, gids=set())
    assert report.latency_timer_ms == 16
    (finding,) = by_check(report, "latency_timer")
    assert "/sys/bus/usb-serial/devices/ttyUSB0/latency_timer" in finding.fix and port in finding.problem


def system_with_the_pty(tmp_path: Path, pty: str) -> tuple[Path, Path, Path]:
    """A fake system (:func:`tree`) that has the simulator's pty as a device node: (its root, the node, the
    node's empty usb-serial device directory in /sys, for a ``latency_timer`` file)."""
    root = tree(tmp_path)
    node = root / pty.lstrip("/")
    node.parent.mkdir(parents=True)
    node.write_text("")
    node.chmod(0o666)
    devices = root / "sys" / "bus" / "usb-serial" / "devices" / node.name
    devices.mkdir(parents=True)
    return root, node, devices


@pytest.mark.pty
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the system checks read Linux's files")
def test_a_timer_the_system_shows_is_one_finding_for_the_ports_own_tty(tmp_path: Path, cli: Any, pty_sim: Any) -> None:
    # The adapter is not always ttyUSB0 (an Arduino plugged in first takes it): the line's measurement
    # repeated the system's finding with a fix for ttyUSB0, and with round trips that did not wait for the
    # timer (ics35 asks the driver for low latency) it said they "sit at" it.
    sim = pty_sim("--ids", "1", "--fast")
    root, node, devices = system_with_the_pty(tmp_path, sim.path)
    timer = devices / "latency_timer"
    timer.write_text("16\n")
    result = cli("doctor", "--port", sim.path, "--ids", "1", "--samples", "10", "--system-root", str(root), "--json")
    assert result.code == 0, result.err
    data = result.json()
    assert data["latency_timer_ms"] == 16 and data["servos"] == [1]
    (finding,) = [f for f in data["findings"] if f["check"] == "latency_timer"]
    assert f"/sys/bus/usb-serial/devices/{node.name}/latency_timer" in finding["fix"]
    assert "ttyUSB0" not in finding["fix"]


class FtdiTimerFile:
    """A stand-in for ftdi_sio's sysfs ``latency_timer`` (the kernel's, not our code): a FIFO whose every read
    finds 1 while this process has ``port`` open (the library asks the driver for low latency as it opens a
    port, and ftdi_sio then runs the chip's timer at 1 ms), else the adapter's own 16."""

    def __init__(self, path: Path, port: str) -> None:
        os.mkfifo(path)
        self.path, self.port = path, os.path.realpath(port)
        self.stopping = False
        self.said: list[str] = []
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _held(self) -> bool:
        """Whether this process has the port open."""
        for fd in os.listdir("/proc/self/fd"):
            with contextlib.suppress(OSError):
                if os.readlink(f"/proc/self/fd/{fd}") == self.port:
                    return True
        return False

    def _serve(self) -> None:
        while not self.stopping:
            with open(self.path, "w") as reader:  # (opens once a reader does: what it finds is then's)
                # A new FIFO in its place before the answer: the next read, which begins once this one has
                # its answer, waits for an answer of its own (the same FIFO would give it this one again).
                fresh = self.path.with_name("latency_timer.next")
                os.mkfifo(fresh)
                os.replace(fresh, self.path)
                if not self.stopping:
                    self.said.append("1" if self._held() else "16")
                    reader.write(f"{self.said[-1]}\n")

    def stop(self) -> None:
        self.stopping = True
        os.close(os.open(self.path, os.O_RDONLY | os.O_NONBLOCK))  # (ends its wait for the next reader)
        self.thread.join(GUARD)
        assert not self.thread.is_alive()


@pytest.mark.pty
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the system checks read Linux's files")
def test_doctor_reads_the_latency_timer_with_the_port_open(tmp_path: Path, cli: Any, pty_sim: Any) -> None:
    # A fresh adapter's timer reads 16 ms until a program asks for low latency, as ics35 does as it opens the
    # port: doctor read it before opening the port and warned of a 16 ms timer its own round trips did not show.
    sim = pty_sim("--ids", "1", "--fast")
    root, _node, devices = system_with_the_pty(tmp_path, sim.path)
    timer = FtdiTimerFile(devices / "latency_timer", sim.path)
    try:
        line = ("--port", sim.path, "--ids", "1", "--samples", "10", "--system-root", str(root))
        result = cli("doctor", *line, "--json")
        assert result.code == 0, result.err
        data = result.json()
        assert data["latency_timer_ms"] == 1 and data["servos"] == [1], timer.said
        (finding,) = [f for f in data["findings"] if f["check"] == "latency_timer"]
        # What is left to say: a program that does not ask for low latency still waits the adapter's 16 ms.
        assert finding["severity"] == "info" and "16 ms" in finding["problem"], finding
        assert "ics35 udev --install" in finding["fix"]
        text = cli("doctor", *line)
        assert text.code == 0, text.err
        assert "latency timer (from the system, with the port open): 1 ms" in text.out, text.out
        # (No warning of the timer; a busy machine's slow round trips may be warned of, rightly.)
        warned = [ln for ln in text.err.splitlines() if ln.lstrip().startswith("warning:")]
        assert not [ln for ln in warned if "16 ms" in ln], text.err
    finally:
        timer.stop()


def test_doctor_says_why_no_servo_answered_as_the_other_commands_do(cli: Any) -> None:
    # The first command a newcomer runs said only "no servo answered", where get and set-id name the rate
    # the servos answer at, or the adapter when not even the echo came back.
    other_rate = cli("doctor", "--port", "sim://?ids=4&baud=1250000", "--json")
    assert other_rate.code == 6, other_rate.err
    assert "1250000" in other_rate.err and "--baud 1250000" in other_rate.err
    (line,) = [f for f in other_rate.json()["findings"] if f["check"] == "line"]
    assert "--baud 1250000" in line["fix"]
    no_echo = cli("doctor", "--port", "sim://?ids=5&echo=0", "--ids", "1")
    assert no_echo.code == 4, no_echo.err
    assert "not even the echo" in no_echo.err and "--no-echo" in no_echo.err
    nobody = cli("doctor", "--port", "sim://?ids=none", "--ids", "0-3")
    assert nobody.code == 4, nobody.err
    assert "no servo answered" in nobody.err and "hint: check the servo has power" in nobody.err


def test_doctor_says_which_other_rates_it_tried_when_nothing_answered_at_any(cli: Any) -> None:
    # Nothing at the line's rate, nor at the others doctor then asks (a whole allowance each): the wait went
    # unexplained, and the advice read as if the other rates were still to be tried.  One line names them, in the
    # text and in the JSON's finding alike (on a terminal each is also said as it is tried: see below).
    text = cli("doctor", "--port", "sim://?ids=none", "--ids", "0-3")
    assert text.code == 4, text.err
    assert text.err.count("nor any device at 625000 or 1250000 baud") == 1, text.err
    assert "error: no servo answered on sim://?ids=none at 115200 baud, nor any device at 625000 or 1250000 baud" in (
        text.err
    )
    report = cli("doctor", "--port", "sim://?ids=none", "--baud", "625000", "--json")
    (line,) = [f for f in report.json()["findings"] if f["check"] == "line"]
    assert line["problem"].endswith("at 625000 baud, nor any device at 115200 or 1250000 baud"), line


async def test_a_port_lost_while_measuring_is_the_ports_error_not_failed_reads() -> None:
    # An adapter pulled during doctor's measurement was "N of M reads failed: check the wiring and the
    # servos' power", exit 0.
    from ics35_async import BusClosed, PortLost, open_bus
    from ics35_async.diagnose.line_report import measure_round_trips
    from ics35_async.sim import VirtualLine, VirtualServo

    sim = VirtualLine([VirtualServo(1), VirtualServo(2)])
    async with open_bus(sim) as bus:
        assert await bus.scan([1, 2]) == [1, 2]
        sim.unplug()
        with pytest.raises((PortLost, BusClosed)):
            await measure_round_trips(bus, [1, 2], per_servo=5)
    sim.close()


def test_the_timer_fix_for_good_is_the_udev_rule_that_matches_the_adapter(tmp_path: Path) -> None:
    # ics35 udev's rules match Kondo's vendor ID only: for an FTDI adapter of FTDI's own (a DIY interface),
    # "for good: ics35 udev --install" left its timer at 16 ms.
    root = tree(tmp_path)
    timer = root / "sys" / "bus" / "usb-serial" / "devices" / "ttyUSB0" / "latency_timer"
    timer.parent.mkdir(parents=True)
    timer.write_text("16\n")
    (kondo,) = by_check(check(root, uid=0), "latency_timer")
    assert "ics35 udev --install" in kondo.fix
    ftdi = SerialPortInfo("/dev/ttyUSB0", "FT232R USB UART", 0x0403, 0x6001)
    (other,) = by_check(check(root, ports=[ftdi], uid=0), "latency_timer")
    assert "ics35 udev" not in other.fix and 'ATTR{latency_timer}="1"' in other.fix


def board_uart(tmp_path: Path, tty: str, driver: str, *, alias: str | None = None) -> Path:
    """A fake board: /dev/``tty`` (``/dev/alias`` linking to it, as Raspberry Pi OS's /dev/serial0 does), run by
    the kernel driver ``driver``."""
    root = tree(tmp_path)
    (root / "dev" / tty).write_text("")
    if alias:
        os.symlink(tty, root / "dev" / alias)
    drivers = root / "sys" / "bus" / "platform" / "drivers" / driver
    drivers.mkdir(parents=True)
    device = root / "sys" / "devices" / "platform" / "soc" / "fe215040.serial"
    device.mkdir(parents=True)
    os.symlink(drivers, device / "driver")
    (root / "sys" / "bus" / "platform").mkdir(exist_ok=True)
    os.symlink(root / "sys" / "bus" / "platform", device / "subsystem")
    (root / "sys" / "class" / "tty" / tty).mkdir(parents=True)
    os.symlink(device, root / "sys" / "class" / "tty" / tty / "device")
    return root


@pytest.mark.parametrize("port", ["/dev/ttyS0", "/dev/serial0"])
def test_a_raspberry_pi_mini_uart_is_named_for_its_missing_parity(tmp_path: Path, port: str) -> None:
    # ICS frames carry even parity.  A Raspberry Pi's mini UART (ttyS0, /dev/serial0 where Bluetooth has the
    # other UART) has none: every command goes out without it, and the servos answer none.  doctor says so, and
    # which UART to use instead; the PL011 (ttyAMA0) is fine.
    root = board_uart(tmp_path, "ttyS0", "bcm2835-aux-uart", alias="serial0")
    (finding,) = by_check(check_system([], port, root=root, platform="linux", uid=0, gids=set()), "uart")
    assert finding.severity == "error" and "mini UART" in finding.problem and "parity" in finding.problem
    assert "dtoverlay=disable-bt" in finding.fix and "/dev/ttyAMA0" in finding.fix
    # (a board's UART needs no USB adapter: "no Kondo adapter is plugged in" would be noise)
    assert by_check(check_system([], port, root=root, platform="linux", uid=0, gids=set()), "adapter") == []
    other = board_uart(tmp_path / "pl011", "ttyAMA0", "uart-pl011")
    assert by_check(check_system([], "/dev/ttyAMA0", root=other, platform="linux", uid=0, gids=set()), "uart") == []


@pytest.mark.parametrize("cmdline", ["console=serial0,115200 console=tty1", "console=ttyAMA0,115200 root=/dev/x"])
def test_the_kernel_console_on_the_servo_port_is_named(tmp_path: Path, cmdline: str) -> None:
    # A board's serial console on the UART the servos hang on: the kernel's messages go out onto their line.
    root = board_uart(tmp_path, "ttyAMA0", "uart-pl011", alias="serial0")
    (root / "proc" / "cmdline").write_text(cmdline + "\n")
    (finding,) = by_check(check_system([], "/dev/ttyAMA0", root=root, platform="linux", uid=0, gids=set()), "console")
    assert finding.severity == "error" and "console" in finding.problem and "/dev/ttyAMA0" in finding.problem
    assert "cmdline.txt" in finding.fix and "raspi-config" in finding.fix
    (root / "proc" / "cmdline").write_text("console=tty1 root=/dev/x\n")
    assert by_check(check_system([], "/dev/ttyAMA0", root=root, platform="linux", uid=0, gids=set()), "console") == []


def test_doctors_search_of_the_other_rates_says_which_it_tries_on_a_terminal() -> None:
    # Nothing answers at the line's rate: doctor asks the other rates, a whole allowance each where nothing
    # answers, and says which it tries as every command's search does (the policy's on_rate).
    from ics35_async.cli import ExitCode
    from tests.support.terminal import screen_of, typed_on_a_terminal

    port = "sim://doctor-search?ids=1&baud=1250000"  # (servo 1 at 1250000, the line at the default 115200)
    code, shown = typed_on_a_terminal(["--port", port, "--timeout", "0.05", "doctor", "--ids", "1"], [])
    screen = " ".join(" ".join(screen_of(shown)).split())
    assert code == ExitCode.WRONG_BAUD, screen
    tried = "no answer at 115200 baud: trying 625000 baud ... trying 1250000 baud too ..."
    assert tried in screen and "--baud 1250000" in screen, screen


def test_doctor_asked_ids_nobody_has_says_other_ids_answer_not_that_no_device_does(cli: Any) -> None:
    # `doctor --ids 9` on a line of servos 1-6: "no servo answered on ... at 115200 baud, nor any device at 625000
    # or 1250000 baud", where devices answer at 115200, at their own IDs.
    result = cli("--port", "sim://doctor-other-ids?ids=1-6", "--timeout", "0.05", "doctor", "--ids", "9")
    assert result.code == ExitCode.NO_REPLY, result.err
    said = " ".join((result.out + result.err).split())
    assert "no servo at ID 9 answered on sim://doctor-other-ids?ids=1-6 at 115200 baud" in said, said
    assert "servos at other IDs answer" in said and "scan lists the IDs" in said and "nor any device" not in said, said


def test_doctor_names_the_id_of_the_one_servo_that_answers_elsewhere(cli: Any) -> None:
    # (as `scan --ids` does: one servo there answers the ID read with its ID, and the hint asks for it there)
    result = cli("--port", "sim://doctor-one-other-id?ids=4", "--timeout", "0.05", "doctor", "--ids", "9")
    assert result.code == ExitCode.NO_REPLY, result.err
    said = " ".join((result.out + result.err).split())
    assert "no servo at ID 9 answered on sim://doctor-one-other-id?ids=4 at 115200 baud, but a servo at ID 4 does" in (
        said
    ), said
    assert "--ids 4" in said, said


ADAPTER_WORDS = ("lsusb", "ftdi_sio", "latency_timer", "USB vendor 165C", "udev")


@pytest.mark.pty
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the system checks read Linux's files")
def test_doctor_and_ports_on_a_pseudo_terminal_say_so_and_give_no_adapter_advice(cli: Any, pty_sim: Any) -> None:
    # On `ics35 sim`'s pty (a /dev/pts/N, behind its link) doctor and ports told a newcomer of USB adapters: no
    # Kondo adapter plugged in, ftdi_sio, lsusb, udev rules.  A pty has no adapter: a simulator or a bridge.
    sim = pty_sim("--ids", "1", "--fast")
    for port in (sim.path, os.path.realpath(sim.path)):
        result = cli("--port", port, "doctor", "--ids", "1", "--samples", "10", "--json")
        assert result.code == 0, result.err
        findings = result.json()["findings"]
        (pty,) = [f for f in findings if f["check"] == "pty"]
        assert pty["severity"] == "info" and "pseudo-terminal" in pty["problem"], pty
        assert "ics35 sim" in pty["problem"] and "socat" in pty["problem"], pty
        assert not [f for f in findings if f["check"] in ("adapter", "latency_timer", "grabber", "wsl")], findings
        assert result.json()["pseudo_terminal"] is True

        text = cli("--port", port, "doctor", "--ids", "1", "--samples", "10")
        assert text.code == 0, text.err
        said = " ".join((text.out + text.err).split())
        assert f"{port} is a pseudo-terminal" in said, said
        assert not [w for w in ADAPTER_WORDS if w in said], said

        listed = cli("--port", port, "ports")
        assert listed.code in (0, ExitCode.PORT), listed.err  # (a machine may have no serial port at all)
        said = " ".join(listed.err.split())
        assert f"{port} is a pseudo-terminal" in said, said
        assert not [w for w in ADAPTER_WORDS if w in said], said
        notes = cli("--port", port, "ports", "--json").json()["notes"]
        assert any("pseudo-terminal" in note for note in notes), notes
        assert not [n for n in notes if any(w in n for w in ADAPTER_WORDS)], notes


@pytest.mark.pty
def test_doctor_takes_a_port_path_relative_to_the_working_directory(
    cli: Any, pty_sim: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    # `cd` beside `ics35 sim`'s link, `doctor --port ttyA`: "ttyA does not exist" (looked up below /), hint
    # "/dev/ttyA", where every other command opened it.
    sim = pty_sim("--ids", "1", "--fast")
    monkeypatch.chdir(os.path.dirname(sim.path))
    for port in (os.path.basename(sim.path), f"./{os.path.basename(sim.path)}"):
        result = cli("--port", port, "doctor", "--ids", "1", "--samples", "10")
        said = " ".join((result.out + result.err).split())
        assert result.code == 0 and "does not exist" not in said, said


@pytest.mark.pty
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the holder is found in Linux's /proc")
def test_doctor_on_a_port_another_program_holds_says_so_once(cli: Any, pty_sim: Any) -> None:
    # It said who held the port, then tried to open it all the same and said "in use by another program" too:
    # two errors for one cause.
    sim = pty_sim("--ids", "1", "--fast")
    with held_open(sim.path, exclusive=False) as (pid, name):
        text = cli("--port", sim.path, "doctor", "--ids", "1")
        said = " ".join(text.err.split())
        assert text.code == ExitCode.PORT and said.count("error:") == 1, text.err
        assert f"is held open by {name} (process {pid})" in said and f"kill {pid}" in said, said
        assert "in use by another program" not in said, said
        data = cli("--port", sim.path, "doctor", "--ids", "1", "--json")
        errors = [f for f in data.json()["findings"] if f["severity"] == "error"]
        assert data.code == ExitCode.PORT and [f["check"] for f in errors] == ["holder"], errors


@pytest.mark.pty
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the holder is found in Linux's /proc")
def test_a_command_on_a_port_another_program_holds_names_that_program(cli: Any, pty_sim: Any) -> None:
    # "in use by another program (or already open in this one)", hint "close the other program (another ics35, a
    # serial monitor, ModemManager)": which of them, doctor knew; the command did not say.
    sim = pty_sim("--ids", "1", "--fast")
    with held_open(sim.path, exclusive=True) as (pid, name):
        result = cli("--port", sim.path, "get", "1", "speed")
        said = " ".join(result.err.split())
        assert result.code == ExitCode.PORT and "in use by another program" in said, said
        assert f"held open by {name} (process {pid})" in said and f"kill {pid}" in said, said


@contextlib.contextmanager
def held_open(path: str, *, exclusive: bool) -> Iterator[tuple[int, str]]:
    """``path`` held open by another process (with ``exclusive``, as pyserial's exclusive open holds it: other
    opens are refused); its PID and its name as the system gives it (python, python3, python3.11)."""
    holding = (
        "import serial, sys, time; port = serial.Serial(sys.argv[1], exclusive=True); time.sleep(60)"
        if exclusive
        else "import os, sys, time; os.open(sys.argv[1], os.O_RDWR | os.O_NOCTTY); time.sleep(60)"
    )
    holder = subprocess.Popen([sys.executable, "-c", holding, path])
    try:
        wait_until_held(os.path.realpath(path), holder.pid)
        yield holder.pid, Path(f"/proc/{holder.pid}/comm").read_text().strip()
    finally:
        holder.kill()
        holder.wait()


def wait_until_held(path: str, pid: int) -> None:
    """Until process ``pid`` has ``path`` open (its start takes a moment)."""
    deadline = time.monotonic() + GUARD
    while not any(os.path.realpath(f"/proc/{pid}/fd/{fd}") == path for fd in os.listdir(f"/proc/{pid}/fd")):
        assert time.monotonic() < deadline, f"process {pid} never opened {path}"
        time.sleep(0.02)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="a pty's name: Linux's /dev/pts")
def test_a_relative_link_to_a_pseudo_terminal_is_one(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # `--port ./sim-link` (a link in the working directory) was resolved below / and given the adapter's advice.
    master, slave = os.openpty()
    try:
        (tmp_path / "sim-link").symlink_to(os.ttyname(slave))
        monkeypatch.chdir(tmp_path)
        assert is_pseudo_terminal("sim-link") and is_pseudo_terminal("./sim-link")
        assert not is_pseudo_terminal("nothing-here")
    finally:
        os.close(master)
        os.close(slave)
