"""The port layer: open_port and its three kinds of port, on real ptys and a small fake far end.

The pty tests play the device on the master side from the test itself (no
timing games): what the host writes is read from the master, and replies
are written to it, piece by piece when the test needs split chunks.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import logging
import os
import re
import socket
import sys
import termios
import threading
import time
import traceback
import tty
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import serial

from ics35_async import transports as transport
from ics35_async.errors import InvalidArgument
from ics35_async.transports import (
    DevicePort,
    HostSide,
    ParityNotSupported,
    Port,
    PortBusy,
    PortNotFound,
    PortPermissionDenied,
    SerialPort,
    SerialPortError,
    TtyPort,
    WireDevice,
    adapter_advice,
    open_port,
    register_url_scheme,
)
from tests.support.terminal import write_until_refused

WAIT = 5.0  # generous: only ever reached when something is broken


def read_until(port: Port, n: int) -> bytes:
    """Read from ``port`` until ``n`` bytes in all have come (a port never waits: poll it)."""
    data = b""
    deadline = time.monotonic() + WAIT
    while len(data) < n:
        assert time.monotonic() < deadline, data
        data += port.read()
        time.sleep(0.001)
    return data


class Pty:
    """A pty pair; the test plays the device on ``master``."""

    def __init__(self) -> None:
        self.master, slave = os.openpty()
        self.port = os.ttyname(slave)
        os.close(slave)  # the host opens it by name
        os.set_blocking(self.master, False)

    def read(self, n: int) -> bytes:
        """Read exactly ``n`` bytes the host wrote."""
        buf = b""
        deadline = time.monotonic() + WAIT
        while len(buf) < n:
            assert time.monotonic() < deadline, buf
            with contextlib.suppress(BlockingIOError):
                buf += os.read(self.master, n - len(buf))
            time.sleep(0.001)
        return buf

    def write(self, data: bytes) -> None:
        assert os.write(self.master, data) == len(data)

    def close(self) -> None:
        if self.master >= 0:
            os.close(self.master)
            self.master = -1


@pytest.fixture
def pty() -> Iterator[Pty]:
    p = Pty()
    yield p
    p.close()


def open_at(port: Any, **kwargs: Any) -> Port:
    return open_port(port, kwargs.pop("baudrate", 115200), **kwargs)


# --------------------------------------------------------------------------- a tty with a descriptor


@pytest.mark.parametrize("kind", ["auto", "direct"])
def test_pty_round_trip(pty: Pty, kind: str) -> None:
    port = open_at(pty.port, transport=kind)
    assert isinstance(port, TtyPort)
    try:
        for command in [b"\x80\x3a\x4c", b"\xa5\x01", bytes(range(255))]:
            assert port.write(command)
            assert pty.read(len(command)) == command
            reply = bytes(b ^ 0x55 for b in command)
            pty.write(command + reply)  # echo, then the reply
            assert read_until(port, 2 * len(command)) == command + reply
    finally:
        port.close()


def test_pty_split_chunks_arrive_in_order(pty: Pty) -> None:
    port = open_at(pty.port)
    try:
        sent = b""
        got = b""
        for piece in [b"\x80\x3a\x4c", b"\x00", b"\x3a", b"\x4c"]:  # echo, then the reply byte by byte
            pty.write(piece)
            sent += piece
            got += read_until(port, len(piece))
            assert got == sent  # each piece lands before the next is written
    finally:
        port.close()


def test_pty_parity_dropped_is_handled_at_debug(pty: Pty, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.DEBUG, logger="ics35_async.transports")
    port = open_at(pty.port)
    assert isinstance(port, TtyPort)
    try:
        assert port.serial.parity == serial.PARITY_NONE
        assert not termios.tcgetattr(port.fd)[2] & termios.PARENB
        assert any("pty" in r.getMessage() and r.levelno == logging.DEBUG for r in caplog.records)
        assert not [r for r in caplog.records if r.levelno >= logging.WARNING]
        port.serial.timeout = 0  # re-configuring works (it failed with EINVAL once)
    finally:
        port.close()


def test_pty_already_raw_at_our_speed_still_opens(pty: Pty) -> None:
    # A slave already raw at 115200 makes pyserial's opening tcsetattr ask for
    # PARENB alone, which a pty refuses with EINVAL at open time.
    serial.serial_for_url(pty.port, baudrate=115200, parity=serial.PARITY_NONE).close()
    with pytest.raises(termios.error):
        serial.serial_for_url(pty.port, baudrate=115200, parity=serial.PARITY_EVEN).close()
    port = open_at(pty.port)
    try:
        port.write(b"\x01")
        assert pty.read(1) == b"\x01"
    finally:
        port.close()


def test_parity_drop_on_a_non_pty_is_an_error(pty: Pty, monkeypatch: pytest.MonkeyPatch) -> None:
    # No real non-pty driver that drops PARENB is at hand, so a pty stands in
    # for one: only the pty detection is overridden.
    from ics35_async.transports import serial_port

    monkeypatch.setattr(serial_port, "is_pty", lambda fd: False)
    monkeypatch.setattr(serial_port, "_is_pty_path", lambda path: False)
    with pytest.raises(ParityNotSupported, match="EVEN parity"):
        open_at(pty.port)
    monkeypatch.undo()
    open_at(pty.port).close()  # the port was released: a normal open works again


def test_pty_detection() -> None:
    from ics35_async.transports.serial_port import is_pty

    master, slave = os.openpty()
    read_end, write_end = os.pipe()
    try:
        assert is_pty(slave)
        assert not is_pty(read_end)
        with open(os.devnull, "rb") as null:
            assert not is_pty(null.fileno())
    finally:
        for fd in (master, slave, read_end, write_end):
            os.close(fd)


def test_pty_master_closed_is_a_hangup(pty: Pty) -> None:
    port = open_at(pty.port)
    try:
        port.write(b"\x80")
        pty.read(1)
        pty.close()
        with pytest.raises(OSError, match="hung up"):
            read_until(port, 1)
    finally:
        port.close()


def test_a_write_to_a_hung_up_port_says_so_in_the_reads_words(pty: Pty) -> None:
    # The read of a port gone said "the serial port hung up (device disconnected?)", a write to it the OS's
    # "Input/output error": one adapter pulled out, told two ways by which call met it first.
    port = open_at(pty.port)
    try:
        pty.close()
        with pytest.raises(OSError, match=r"hung up \(device disconnected\?\)") as lost:
            for _ in range(100):  # (until the write meets the hang-up, not only the kernel's buffer)
                port.write(b"\x80")
                port.write_pending()
        assert lost.value.errno == errno.EIO
    finally:
        port.close()


def test_input_flushed_between_readiness_and_read_is_not_a_hangup(pty: Pty) -> None:
    """The resync's flush can empty the input after the driver saw it readable and before it reads.

    A raw tty (VMIN=0) then reads 0 bytes, which is not the device going away.
    """
    port = open_at(pty.port)
    try:
        pty.write(b"\x55\xaa")
        time.sleep(0.05)  # the bytes wait in the input queue
        port.discard_input()  # what a driver does when a resync ends
        assert port.read() == b""  # the read that was already due: nothing, and no hangup
        pty.write(b"\x01")
        assert read_until(port, 1) == b"\x01"
    finally:
        port.close()


def test_discard_input_drops_pending_bytes(pty: Pty) -> None:
    port = open_at(pty.port)
    assert isinstance(port, TtyPort)
    try:
        late = b"late bytes of a failed transaction"
        pty.write(late)
        deadline = time.monotonic() + WAIT
        while port.serial.in_waiting < len(late):
            assert time.monotonic() < deadline
            time.sleep(0.001)
        assert port.discard_input() == len(late)  # counted, as the engine counts them (stray bytes)
        assert port.serial.in_waiting == 0
        pty.write(b"fresh")
        assert read_until(port, 5) == b"fresh"
    finally:
        port.close()


def test_a_write_the_port_cannot_take_yet_goes_out_once_it_drains(pty: Pty) -> None:
    port = open_at(pty.port)
    assert isinstance(port, TtyPort)
    try:
        tty.setraw(port.fd)
        # Nobody reads the far end: fill the pty until it takes not one byte more (full is when it stays
        # full for a while: see write_until_refused).
        filled = 0
        quiet_checks = 0
        while quiet_checks < 3:
            took = write_until_refused(port.fd)
            filled += took
            quiet_checks = quiet_checks + 1 if not took else 0
            time.sleep(0.02)
        assert port.write(b"\x81\x3a\x4c") is False  # the rest waits for room
        assert port.write_pending() is False  # still nowhere to put it
        expected = b"x" * filled + b"\x81\x3a\x4c"
        drained = b""
        deadline = time.monotonic() + WAIT
        while len(drained) < len(expected) and time.monotonic() < deadline:
            port.write_pending()  # room again: what was left goes out
            with contextlib.suppress(BlockingIOError):
                drained += os.read(pty.master, 65536)
        assert drained == expected  # everything, once, in order
        assert port.write_pending() is True
    finally:
        port.close()


def test_same_port_twice_is_busy(pty: Pty) -> None:
    port = open_at(pty.port)
    try:
        with pytest.raises(PortBusy, match="in use"):
            open_at(pty.port)
    finally:
        port.close()


def test_missing_port_is_a_clear_error() -> None:
    with pytest.raises(PortNotFound, match="no serial port at '/dev/ttyUSB-nonexistent'") as info:
        open_at("/dev/ttyUSB-nonexistent")
    assert isinstance(info.value, FileNotFoundError) and info.value.errno == errno.ENOENT
    # Its words as a program prints them, the number kept in errno: "[Errno 2] no serial port at ..." read as noise.
    assert str(info.value).startswith("no serial port at "), str(info.value)
    # One traceback on screen, ours (it says all pyserial's two chained ones said); theirs kept for a debugger.
    printed = "".join(traceback.format_exception(info.value))
    assert printed.count("Traceback (most recent call last)") == 1, printed
    assert isinstance(info.value.__context__, serial.SerialException)


@pytest.mark.parametrize(("port", "meant"), [("sim:/?ids=1-3", "sim://?ids=1-3"), ("sim:x", "sim://x")])
def test_a_url_with_its_slashes_mistyped_says_so_to_a_program(port: str, meant: str) -> None:
    # A program's open_bus("sim:/?ids=1-3") was told to check the cable: only the command line said what was meant.
    with pytest.raises(PortNotFound, match=f"a URL starts with sim://: {re.escape(meant)}") as info:
        open_at(port)
    assert "cable" not in str(info.value)


def test_a_dangling_link_is_named_as_such(tmp_path: Path) -> None:
    # A simulator's --link left by a run that stopped, or a udev symlink whose device is gone: "no serial port
    # at 'ttyICS'" sent the user to the cable; the link and what it names say what happened.
    link = tmp_path / "ttyICS"
    link.symlink_to("/dev/pts/ics35-gone")
    with pytest.raises(PortNotFound, match=r"a link to /dev/pts/ics35-gone, a pty that no longer exists") as info:
        open_at(str(link))
    assert "simulator" in str(info.value) and "adapter" not in str(info.value)
    adapter = tmp_path / "ttyKondo"
    adapter.symlink_to("/dev/ttyUSB-ics35-gone")  # (a udev link whose adapter is unplugged)
    with pytest.raises(PortNotFound, match=r"a link to /dev/ttyUSB-ics35-gone, which is not there") as info:
        open_at(str(adapter))
    assert "adapter unplugged" in str(info.value) and "simulator" not in str(info.value)


def test_the_path_of_a_simulator_that_stopped_says_so(pty_sim: Any, cli: Any) -> None:
    # ics35 sim's path, used after the simulator stopped (its terminal closed, ICS35_PORT still set to it):
    # "check the cable/adapter is plugged in" sent a newcomer without hardware to a cable there is not.
    server = pty_sim("--ids", "1")
    assert server.stop() == 0
    with pytest.raises(PortNotFound) as info:
        open_at(server.path)
    said = str(info.value)
    assert "ics35 sim" in said and "stopped" in said and "cable" not in said, said
    result = cli("--port", server.path, "get", "1", "speed")
    assert result.code == 3 and "ics35 sim" in result.err and "cable" not in result.err, result.err


def test_not_a_tty_is_a_clear_error() -> None:
    with pytest.raises(SerialPortError, match="not a serial port"):
        open_at(os.devnull)


def _open_error_as(port: str) -> tuple[str, str]:
    try:
        open_at(port).close()
    except Exception as exc:
        return type(exc).__name__, str(exc)
    return "no error", ""


def test_permission_denied_mentions_dialout(pty: Pty) -> None:
    if os.geteuid() != 0:
        os.chmod(pty.port, 0)
        name, message = _open_error_as(pty.port)
    else:
        # root opens anything: try as 'nobody' in a child process instead.
        read_end, write_end = os.pipe()
        pid = os.fork()
        if pid == 0:  # pragma: no cover - child
            try:
                os.close(read_end)
                os.setgid(65534)
                os.setuid(65534)
                os.write(write_end, "\n".join(_open_error_as(pty.port)).encode())
            finally:
                os._exit(0)
        os.close(write_end)
        with os.fdopen(read_end, "rb") as pipe:
            name, message = pipe.read().decode().split("\n", 1)
        os.waitpid(pid, 0)
    assert name == PortPermissionDenied.__name__
    assert "dialout" in message and pty.port in message


def test_bad_arguments_are_invalid_argument(pty: Pty) -> None:
    with pytest.raises(InvalidArgument, match="transport"):
        open_at(pty.port, transport="turbo")
    with pytest.raises(InvalidArgument, match="baudrate"):
        open_at(pty.port, baudrate=0)
    with pytest.raises(InvalidArgument, match="port"):
        open_at(42)
    with pytest.raises(InvalidArgument):
        open_at("nosuchscheme://x")
    with pytest.raises(InvalidArgument, match="direct"):
        open_at("loop://", transport="direct")
    open_at(pty.port).close()  # none of these left the pty open


def test_unmarks_ff_bytes_on_a_real_pty() -> None:
    """The kernel doubles 0xFF once PARMRK is on: the host must still see one FF."""
    master, slave = os.openpty()
    try:
        port = open_at(os.ttyname(slave))
        try:
            os.write(master, b"\xff\x00\x00\x00\xf4")
            assert read_until(port, 5) == b"\xff\x00\x00\x00\xf4"
            assert port.bad == 0
        finally:
            port.close()
    finally:
        os.close(master)
        os.close(slave)


# --------------------------------------------------------------------------- pyserial ports without a descriptor


def test_a_tty_read_by_a_thread_survives_input_discards_while_bytes_arrive(pty: Pty) -> None:
    # The reader thread waits for input, then reads it; a discard from the driver's thread can empty the
    # input in between, and pyserial then says "readiness to read but returned no data", as it does for
    # a device that went away.  The port is fine: it must not be reported lost.  Switching threads as
    # often as the interpreter can makes that window come round within a second here.
    port = open_at(pty.port, transport="thread")
    assert isinstance(port, DevicePort)
    interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)
    try:
        until = time.monotonic() + 1.5
        while time.monotonic() < until:
            pty.write(b"\x80\x01\x02")
            port.discard_input()
            port.read()  # raises what the reader thread reported, if it gave up on the port
    finally:
        sys.setswitchinterval(interval)
    try:
        port.discard_input()
        pty.write(b"\x21\x22")  # and it still reads
        # (The loop's last bytes can reach the input after that discard: the kernel moves a pty's bytes between
        # its buffers in a worker of its own, late on a loaded machine.  What comes first may be those.)
        data = b""
        deadline = time.monotonic() + WAIT
        while not data.endswith(b"\x21\x22"):
            assert time.monotonic() < deadline, data
            data += port.read()
            time.sleep(0.001)
        assert set(data[:-2]) <= set(b"\x80\x01\x02"), data
    finally:
        port.close()


def test_loop_url_behind_a_reader_thread() -> None:
    port = open_at("loop://")
    assert isinstance(port, DevicePort)  # no descriptor: a reader thread hands the bytes over
    try:
        port.write(b"\x80\x3a\x4c")
        port.write(b"\x01\x02")
        assert read_until(port, 5) == b"\x80\x3a\x4c\x01\x02"
        port.discard_input()
    finally:
        port.close()


def test_loop_url_read_with_blocking_reads() -> None:
    port = open_at("loop://", blocking_reads=True)
    assert isinstance(port, SerialPort)
    try:
        assert port.read() == b""  # a look, not a wait
        port.write(b"\x80\x3a\x4c")
        # A blocking read returns what has come (at least a byte), not a whole command: read by count.
        got = b""
        while len(got) < 3:
            chunk = port.read(block=True)
            assert chunk, got  # nothing came within the port's read timeout
            got += chunk
        assert got == b"\x80\x3a\x4c"
    finally:
        port.close()


@pytest.mark.parametrize("blocking_reads", [False, True])
def test_socket_url_round_trip_and_hangup(blocking_reads: bool) -> None:
    async def scenario() -> None:
        async def echo(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            while data := await reader.read(100):
                writer.write(data + b"!")
            writer.close()

        server = await asyncio.start_server(echo, "127.0.0.1", 0, family=socket.AF_INET)
        number = server.sockets[0].getsockname()[1]
        async with server:
            port = await asyncio.to_thread(open_at, f"socket://127.0.0.1:{number}", blocking_reads=blocking_reads)
            try:
                port.write(b"\x80\x3a\x4c")
                assert await asyncio.to_thread(read_until, port, 4) == b"\x80\x3a\x4c!"
            finally:
                await asyncio.to_thread(port.close)

    asyncio.run(scenario())


# --------------------------------------------------------------------------- in-process devices


class FakeDevice:
    """A stand-in for the simulator: answers from write(), or from its own thread."""

    def __init__(self, *, threaded: bool = False, refuse: bool = False) -> None:
        self.threaded = threaded
        self.refuse = refuse
        self.host: HostSide | None = None
        self.written: list[bytes] = []
        self.disconnected = False
        self.baudrate = 0

    def connect(self, host: HostSide, baudrate: int) -> None:
        if self.refuse:
            raise OSError(errno.ENODEV, "simulated unplugged")
        self.host, self.baudrate = host, baudrate
        host.deliver(b"hello")  # said while connecting

    def write(self, data: bytes) -> None:
        assert self.host is not None
        self.written.append(data)
        if self.threaded:
            host = self.host
            threading.Thread(target=lambda: [host.deliver(bytes([b])) for b in data * 2]).start()
        else:
            self.host.deliver(data)  # echo, synchronously: the transport must defer it
            self.host.deliver(bytes(b ^ 0xFF for b in data))

    def disconnect(self) -> None:
        self.disconnected = True


def test_fake_device_matches_the_protocol() -> None:
    assert isinstance(FakeDevice(), WireDevice)


def test_an_in_process_device_answers_are_read_on_the_drivers_side() -> None:
    device = FakeDevice()
    port = open_at(device, baudrate=1250000)
    assert isinstance(port, DevicePort)
    told: list[bool] = []
    port.on_input = lambda: told.append(True)
    assert device.baudrate == 1250000
    assert port.read() == b"hello"  # said while connecting: kept for the driver
    port.write(b"\x80")
    assert told == [True, True]  # the driver is told; it reads when it chooses, never inside write
    assert port.read() == b"\x80\x7f"
    port.close()
    assert device.disconnected


def test_in_process_delivery_from_another_thread_keeps_order() -> None:
    port = open_at(FakeDevice(threaded=True))
    try:
        payload = bytes(range(200))
        port.write(payload)
        assert read_until(port, 5 + 400) == b"hello" + payload * 2
    finally:
        port.close()


def test_in_process_loss_is_read_after_the_bytes_before_it() -> None:
    device = FakeDevice()
    port = open_at(device)
    assert device.host is not None
    host = device.host
    gone = OSError(errno.EIO, "unplugged")
    thread = threading.Thread(target=lambda: (host.deliver(b"last words"), host.lost(gone), host.deliver(b"x")))
    thread.start()
    thread.join()
    assert port.read() == b"hellolast words"  # and nothing said after the loss
    with pytest.raises(OSError) as info:
        port.read()
    assert info.value is gone
    port.close()


def test_in_process_close_drops_late_data() -> None:
    device = FakeDevice()
    port = open_at(device)
    assert device.host is not None
    port.read()
    port.close()
    device.host.deliver(b"too late")
    port.close()  # harmless twice
    assert port.read() == b""
    port.write(b"ignored after close")
    assert device.written == []


def test_in_process_connect_failure_propagates() -> None:
    with pytest.raises(OSError, match="unplugged"):
        open_at(FakeDevice(refuse=True))


def test_registered_url_scheme_builds_the_device() -> None:
    devices: dict[str, FakeDevice] = {}

    def factory(url: str) -> WireDevice:
        devices[url] = FakeDevice()
        return devices[url]

    register_url_scheme("faketest", factory)
    port = open_at("faketest://bus0?servos=3", transport="thread")  # transport is for serial ports
    assert isinstance(port, DevicePort)
    assert port.device is devices["faketest://bus0?servos=3"]
    assert port.read() == b"hello"
    port.close()


# --------------------------------------------------------------------------- adapter advice


def _fake_sysfs(root: Path, tty: str, latency: str) -> Path:
    device = root / "bus" / "usb-serial" / "devices" / tty
    device.mkdir(parents=True)
    (device / "latency_timer").write_text(latency)
    return device / "latency_timer"


def test_adapter_advice_warns_about_a_slow_latency_timer(tmp_path: Path) -> None:
    timer = _fake_sysfs(tmp_path / "sys", "ttyUSB0", "16\n")
    [advice] = adapter_advice("/dev/ttyUSB0", sysfs_root=tmp_path / "sys")
    assert "16 ms" in advice
    assert f"echo 1 | sudo tee {timer}" in advice
    assert "udev" in advice


def test_adapter_advice_follows_symlinks_to_the_tty(tmp_path: Path) -> None:
    _fake_sysfs(tmp_path / "sys", "ttyUSB3", "16")
    (tmp_path / "dev").mkdir()
    (tmp_path / "dev" / "ttyUSB3").touch()
    (tmp_path / "dev" / "usb-FTDI_FT232R-if00-port0").symlink_to(tmp_path / "dev" / "ttyUSB3")
    assert len(adapter_advice(str(tmp_path / "dev" / "usb-FTDI_FT232R-if00-port0"), sysfs_root=tmp_path / "sys")) == 1


@pytest.mark.parametrize("latency", ["1", "0", "garbage"])
def test_adapter_advice_is_quiet_when_fine(tmp_path: Path, latency: str) -> None:
    _fake_sysfs(tmp_path / "sys", "ttyUSB0", latency)
    assert adapter_advice("/dev/ttyUSB0", sysfs_root=tmp_path / "sys") == []


@pytest.mark.parametrize("driver", ["bcm2835-aux-uart", "uart-pl011"])
def test_adapter_advice_names_a_raspberry_pi_mini_uart_at_every_command(tmp_path: Path, driver: str) -> None:
    # A first scan on a Raspberry Pi's /dev/serial0 (its mini UART: no parity bit) said only that no servo
    # answered, with hints about power and IDs; doctor knew, but nothing sent the person there.  Every command
    # on that port warns, with the fix; the PL011 (ttyAMA0) is fine.
    (tmp_path / "dev").mkdir()
    (tmp_path / "dev" / "ttyS0").touch()
    (tmp_path / "dev" / "serial0").symlink_to("ttyS0")
    device = tmp_path / "sys" / "devices" / "platform" / "soc" / "fe215040.serial"
    device.mkdir(parents=True)
    (tmp_path / "sys" / "bus" / "platform" / "drivers" / driver).mkdir(parents=True)
    (device / "driver").symlink_to(tmp_path / "sys" / "bus" / "platform" / "drivers" / driver)
    (tmp_path / "sys" / "class" / "tty" / "ttyS0").mkdir(parents=True)
    (tmp_path / "sys" / "class" / "tty" / "ttyS0" / "device").symlink_to(device)
    advice = adapter_advice(str(tmp_path / "dev" / "serial0"), sysfs_root=tmp_path / "sys")
    if driver == "uart-pl011":
        assert advice == []
        return
    [said] = advice
    assert "mini UART" in said and "parity" in said and "dtoverlay=disable-bt" in said and "/dev/ttyAMA0" in said


def test_adapter_advice_does_not_apply_elsewhere(tmp_path: Path) -> None:
    _fake_sysfs(tmp_path / "sys", "ttyUSB0", "16")
    assert adapter_advice("/dev/ttyACM0", sysfs_root=tmp_path / "sys") == []
    assert adapter_advice("socket://ttyUSB0:1", sysfs_root=tmp_path / "sys") == []
    assert adapter_advice("sim://", sysfs_root=tmp_path / "sys") == []
    assert adapter_advice("/dev/pts/0") == []  # the real /sys: a pty is no USB adapter


# --------------------------------------------------------------------------- parity-error marks (PARMRK)


def test_parity_marks_pass_clean_data_through_untouched() -> None:
    marks = transport.ParityMarks()
    data = bytes([0x81, 0x3A, 0x4C, 0x01, 0x3A, 0x4C])
    assert marks.decode(data) == (data, 0)


def test_parity_marks_undo_doubled_ff_and_count_marked_bytes() -> None:
    marks = transport.ParityMarks()
    assert marks.decode(b"\xff\xff\x00\x00\x00\xff\xff") == (b"\xff\x00\x00\x00\xff", 0)
    assert marks.decode(b"\x21\xff\x00\x41\x1e\xff\x00\x00") == (b"\x21\x41\x1e\x00", 2)


def test_parity_marks_split_across_reads() -> None:
    marks = transport.ParityMarks()
    assert marks.decode(b"\x01\xff") == (b"\x01", 0)
    assert marks.decode(b"\xff\x02\xff\x00") == (b"\xff\x02", 0)
    assert marks.decode(b"\x33") == (b"\x33", 1)
    assert marks.decode(b"\x44") == (b"\x44", 0)
