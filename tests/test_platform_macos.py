"""macOS (and Windows) at the port: pty detection without /dev/pts, port names in the hints, latency advice.

The pty checks run on a real pty of this system, asked as macOS would answer
(``os.ttyname`` naming a ``/dev/ttysNNN``, or naming nothing at all); the
hints are checked per platform.  What this does not prove: macOS itself.
"""

from __future__ import annotations

import errno
import os
import sys
from collections.abc import Iterator
from typing import Any

import pytest

from ics35_async.errors import PortPermissionDenied
from ics35_async.transports import platforms, serial_port
from ics35_async.transports.platforms import is_pty_name, latency_timer_advice, port_names_hint
from ics35_async.transports.serial_port import is_pty, translate_open_error


@pytest.fixture
def pty_pair() -> Iterator[tuple[int, int]]:
    master, slave = os.openpty()
    try:
        yield master, slave
    finally:
        os.close(master)
        os.close(slave)


@pytest.mark.parametrize(
    ("name", "expected"),
    [
        ("/dev/pts/4", True),  # Linux, FreeBSD
        ("/dev/ttys004", True),  # macOS
        ("/dev/ttyp3", True),  # legacy BSD
        ("/dev/ttyS0", False),  # a Linux UART
        ("/dev/tty.usbserial-A10KZ9", False),  # macOS USB serial, dial-in side
        ("/dev/cu.usbserial-A10KZ9", False),  # macOS USB serial, call-out side
        ("/dev/ttyUSB0", False),
        ("/dev/ttys", False),
    ],
)
def test_pty_names(name: str, expected: bool) -> None:
    assert is_pty_name(name) is expected


def test_a_pty_is_detected_by_its_macos_name(pty_pair: tuple[int, int], monkeypatch: pytest.MonkeyPatch) -> None:
    _, slave = pty_pair
    monkeypatch.setattr(sys, "platform", "darwin")
    monkeypatch.setattr(os, "ttyname", lambda fd: "/dev/ttys004")
    assert serial_port.is_pty(slave)


def test_a_pty_is_detected_by_its_device_major_when_unnamed(
    pty_pair: tuple[int, int], monkeypatch: pytest.MonkeyPatch
) -> None:
    _, slave = pty_pair

    def no_name(fd: int) -> str:
        raise OSError(25, "Inappropriate ioctl for device")

    monkeypatch.setattr(sys, "platform", "darwin")
    monkeypatch.setattr(os, "ttyname", no_name)
    assert is_pty(slave)
    read_end, write_end = os.pipe()
    try:
        assert not is_pty(read_end)
        with open(os.devnull, "rb") as null:
            assert not is_pty(null.fileno())
    finally:
        os.close(read_end)
        os.close(write_end)


def test_a_usb_serial_name_is_not_a_pty_on_macos(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(sys, "platform", "darwin")
    monkeypatch.setattr(os, "ttyname", lambda fd: "/dev/cu.usbserial-A10KZ9")
    monkeypatch.setattr(platforms, "_pty_major", lambda: None)
    with open(os.devnull, "rb") as null:
        assert not is_pty(null.fileno())


@pytest.mark.parametrize(
    ("platform", "wanted"),
    [("darwin", "/dev/cu."), ("win32", "Device Manager"), ("linux", "/dev/ttyUSB")],
)
def test_missing_port_hint_names_the_platforms_devices(
    platform: str, wanted: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(sys, "platform", platform)
    assert wanted in port_names_hint()
    error = translate_open_error("/dev/cu.usbserial-X", FileNotFoundError(2, "No such file or directory"))
    assert wanted in str(error)
    assert "ics35 ports" in str(error)


@pytest.mark.parametrize(
    ("platform", "wanted", "unwanted"),
    [
        ("darwin", "AN_134", "/sys/"),
        ("win32", "Latency Timer", "/sys/"),
        ("linux", "/sys/bus/usb-serial", "Device Manager"),
    ],
)
def test_latency_advice_fits_the_platform(platform: str, wanted: str, unwanted: str) -> None:
    advice = latency_timer_advice(platform)
    assert wanted in advice
    assert unwanted not in advice


def test_cli_missing_port_hint_on_macos(cli: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(sys, "platform", "darwin")
    result = cli("--port", "/dev/cu.usbserial-nothere", "get", "1", "stretch")
    assert result.code == 3
    assert "ls /dev/cu.*" in result.err
    assert "/dev/ttyUSB" not in result.err


def test_permission_hint_off_linux(monkeypatch: pytest.MonkeyPatch) -> None:
    # A denied open as pyserial reports it (a file with mode 0 cannot deny root, who runs CI).
    from ics35_async.transports import serial_port

    monkeypatch.setattr(sys, "platform", "darwin")
    exc = serial_port.translate_open_error("/dev/cu.usbserial-1", OSError(errno.EACCES, "Permission denied"))
    assert isinstance(exc, PortPermissionDenied)
    assert "macOS" in str(exc) and "dialout" not in str(exc)
