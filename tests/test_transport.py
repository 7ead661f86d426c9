"""The transport layer: real ptys for the serial paths, a small fake far end for in-process lines.

The pty tests drive the master side from the test itself (no timing games):
what the host writes is read from the master, and replies are written to it,
piece by piece when the test needs split chunks.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import logging
import os
import socket
import termios
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import serial

from ics35_async import transports as transport
from ics35_async.errors import InvalidArgument
from ics35_async.transports import (
    DirectSerialTransport,
    HostSide,
    InProcessTransport,
    ParityNotSupported,
    PortBusy,
    PortNotFound,
    PortPermissionDenied,
    SerialPortError,
    WireDevice,
    adapter_advice,
    discard_input,
    open_line,
    register_url_scheme,
)

SERIAL_KINDS = ["auto", "direct", "fast", "stock"]
WAIT = 5.0  # generous: only ever reached when something is broken


class Recorder(asyncio.Protocol):
    """Records everything the transport tells it."""

    def __init__(self) -> None:
        self.transport: asyncio.BaseTransport | None = None
        self.chunks: list[bytes] = []
        self.lost: asyncio.Future[Exception | None] = asyncio.get_running_loop().create_future()
        self.made_count = 0
        self._arrived = asyncio.Event()

    @property
    def data(self) -> bytes:
        return b"".join(self.chunks)

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport
        self.made_count += 1

    def data_received(self, data: bytes) -> None:
        assert not self.lost.done(), "data after connection_lost"
        self.chunks.append(data)
        self._arrived.set()

    def connection_lost(self, exc: Exception | None) -> None:
        assert not self.lost.done(), "connection_lost twice"
        self.lost.set_result(exc)

    async def until(self, n: int) -> bytes:
        """Wait until ``n`` bytes in all have arrived."""
        async with asyncio.timeout(WAIT):
            while len(self.data) < n:
                self._arrived.clear()
                await self._arrived.wait()
        return self.data


# --------------------------------------------------------------------------- pty helpers


class Pty:
    """A pty pair; the test plays the device on ``master``."""

    def __init__(self) -> None:
        self.master, slave = os.openpty()
        self.port = os.ttyname(slave)
        os.close(slave)  # the host opens it by name
        os.set_blocking(self.master, False)

    async def read(self, n: int) -> bytes:
        """Read exactly ``n`` bytes the host wrote."""
        loop = asyncio.get_running_loop()
        buf = b""
        async with asyncio.timeout(WAIT):
            while len(buf) < n:
                ready = loop.create_future()
                loop.add_reader(self.master, lambda f=ready: f.done() or f.set_result(None))
                try:
                    await ready
                finally:
                    loop.remove_reader(self.master)
                with contextlib.suppress(BlockingIOError):
                    buf += os.read(self.master, n - len(buf))
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


async def open_recorder(port: Any, **kwargs: Any) -> tuple[asyncio.Transport, Recorder]:
    kwargs.setdefault("baudrate", 115200)
    return await open_line(port, protocol_factory=Recorder, **kwargs)


async def close_line(line: asyncio.Transport, rec: Recorder) -> None:
    line.close()
    async with asyncio.timeout(WAIT):
        assert await rec.lost is None


EXPECTED_CLASS = {
    "auto": DirectSerialTransport,
    "direct": DirectSerialTransport,
    "fast": pytest.importorskip("serial_asyncio_fast").SerialTransport,
    "stock": pytest.importorskip("serial_asyncio").SerialTransport,
}


# --------------------------------------------------------------------------- serial ports over a pty


@pytest.mark.parametrize("kind", SERIAL_KINDS)
async def test_pty_round_trip(pty: Pty, kind: str) -> None:
    line, rec = await open_recorder(pty.port, transport=kind)
    assert isinstance(line, EXPECTED_CLASS[kind])
    assert rec.made_count == 1 and rec.transport is line
    expected = b""
    for command in [b"\x80\x3a\x4c", b"\xa5\x01", bytes(range(256))]:
        line.write(command)
        assert await pty.read(len(command)) == command
        reply = bytes(b ^ 0x55 for b in command)
        pty.write(command + reply)  # echo, then the reply
        expected += command + reply
        assert await rec.until(len(expected)) == expected
    await close_line(line, rec)


@pytest.mark.parametrize("kind", SERIAL_KINDS)
async def test_pty_split_chunks_arrive_in_order(pty: Pty, kind: str) -> None:
    line, rec = await open_recorder(pty.port, transport=kind)
    line.write(b"\x80\x3a\x4c")
    assert await pty.read(3) == b"\x80\x3a\x4c"
    pieces = [b"\x80\x3a\x4c", b"\x00", b"\x3a", b"\x4c"]  # echo, then the reply byte by byte
    sent = b""
    for piece in pieces:
        pty.write(piece)
        sent += piece
        assert await rec.until(len(sent)) == sent  # each piece lands before the next is written
    assert len(rec.chunks) == len(pieces)
    await close_line(line, rec)


@pytest.mark.parametrize("kind", SERIAL_KINDS)
async def test_pty_parity_dropped_is_handled_at_debug(pty: Pty, kind: str, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.DEBUG, logger="ics35_async.transports")
    line, rec = await open_recorder(pty.port, transport=kind)
    ser = line.get_extra_info("serial")
    assert ser.parity == serial.PARITY_NONE
    assert not termios.tcgetattr(ser.fd)[2] & termios.PARENB
    assert any("pty" in r.getMessage() and r.levelno == logging.DEBUG for r in caplog.records)
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING]
    # Re-configuring now works (this is what failed with EINVAL before the fix).
    ser.timeout = 0
    await close_line(line, rec)


async def test_pty_already_raw_at_our_speed_still_opens(pty: Pty) -> None:
    # A slave already raw at 115200 makes pyserial's opening tcsetattr ask for
    # PARENB alone, which a pty refuses with EINVAL at open time.
    serial.serial_for_url(pty.port, baudrate=115200, parity=serial.PARITY_NONE).close()
    with pytest.raises(termios.error):
        serial.serial_for_url(pty.port, baudrate=115200, parity=serial.PARITY_EVEN).close()
    line, rec = await open_recorder(pty.port)
    line.write(b"\x01")
    assert await pty.read(1) == b"\x01"
    await close_line(line, rec)


async def test_parity_drop_on_a_non_pty_is_an_error(pty: Pty, monkeypatch: pytest.MonkeyPatch) -> None:
    # No real non-pty driver that drops PARENB is at hand, so a pty stands in
    # for one: only the pty detection is overridden.
    from ics35_async.transports import serial_port

    monkeypatch.setattr(serial_port, "is_pty", lambda fd: False)
    monkeypatch.setattr(serial_port, "_is_pty_path", lambda path: False)
    with pytest.raises(ParityNotSupported, match="EVEN parity"):
        await open_recorder(pty.port)
    # The port was released: a normal open works again.
    monkeypatch.undo()
    line, rec = await open_recorder(pty.port)
    await close_line(line, rec)


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


@pytest.mark.parametrize("kind", SERIAL_KINDS)
async def test_pty_master_closed_reports_connection_lost(pty: Pty, kind: str) -> None:
    line, rec = await open_recorder(pty.port, transport=kind)
    line.write(b"\x80")
    await pty.read(1)
    pty.close()
    async with asyncio.timeout(WAIT):
        exc = await rec.lost
    assert isinstance(exc, OSError)
    assert line.is_closing()
    line.write(b"ignored after loss")  # must not raise


def test_direct_transport_under_uvloop() -> None:
    uvloop = pytest.importorskip("uvloop")

    async def scenario() -> None:
        pty = Pty()
        try:
            line, rec = await open_recorder(pty.port)
            assert isinstance(line, DirectSerialTransport)
            line.write(b"\x80\x3a\x4c")
            assert await pty.read(3) == b"\x80\x3a\x4c"
            pty.write(b"\x80\x3a\x4c\x00\x3a\x4c")
            assert await rec.until(6) == b"\x80\x3a\x4c\x00\x3a\x4c"
        finally:
            pty.close()
        async with asyncio.timeout(WAIT):
            assert isinstance(await rec.lost, OSError)

    with asyncio.Runner(loop_factory=uvloop.new_event_loop) as runner:
        runner.run(scenario())


class FlowRecorder(Recorder):
    def __init__(self) -> None:
        super().__init__()
        self.flow: list[str] = []

    def pause_writing(self) -> None:
        self.flow.append("pause")

    def resume_writing(self) -> None:
        self.flow.append("resume")


@pytest.mark.parametrize("kind", SERIAL_KINDS)
async def test_pty_large_writes_are_buffered_in_order_and_flushed_on_close(pty: Pty, kind: str) -> None:
    # Far more than a pty holds: the transport must buffer, apply flow control and keep order.
    line, rec = await open_line(pty.port, baudrate=115200, protocol_factory=FlowRecorder, transport=kind)
    line.set_write_buffer_limits(high=16 * 1024)
    payload = bytes(i * 7 % 251 for i in range(256 * 1024))
    for i in range(0, len(payload), 4096):
        line.write(payload[i : i + 4096])
    assert line.get_write_buffer_size() > 0
    line.close()  # graceful: what is buffered still goes out
    assert await pty.read(len(payload)) == payload
    async with asyncio.timeout(WAIT):
        assert await rec.lost is None
    assert rec.flow[:1] == ["pause"]


@pytest.mark.parametrize("kind", SERIAL_KINDS)
async def test_pty_abort_while_closing_still_reports_lost(pty: Pty, kind: str) -> None:
    line, rec = await open_recorder(pty.port, transport=kind)
    line.write(bytes(256 * 1024))
    line.close()
    line.abort()
    async with asyncio.timeout(WAIT):
        assert await rec.lost is None


@pytest.mark.parametrize("kind", SERIAL_KINDS)
async def test_discard_input_drops_pending_bytes(pty: Pty, kind: str) -> None:
    line, rec = await open_recorder(pty.port, transport=kind)
    line.pause_reading()
    pty.write(b"late bytes of a failed transaction")
    ser = line.get_extra_info("serial")
    async with asyncio.timeout(WAIT):
        while ser.in_waiting == 0:
            await asyncio.sleep(0.001)
    discard_input(line)
    assert ser.in_waiting == 0
    line.resume_reading()
    pty.write(b"fresh")
    assert await rec.until(5) == b"fresh"
    await close_line(line, rec)


async def test_same_port_twice_is_busy(pty: Pty) -> None:
    line, rec = await open_recorder(pty.port)
    with pytest.raises(PortBusy, match="in use"):
        await open_recorder(pty.port)
    await close_line(line, rec)


async def test_missing_port_is_a_clear_error() -> None:
    with pytest.raises(PortNotFound, match="no serial port at '/dev/ttyUSB-nonexistent'") as info:
        await open_recorder("/dev/ttyUSB-nonexistent")
    assert isinstance(info.value, FileNotFoundError) and info.value.errno == errno.ENOENT


async def test_not_a_tty_is_a_clear_error() -> None:
    with pytest.raises(SerialPortError, match="not a serial port"):
        await open_recorder(os.devnull)


def _open_error_as(port: str) -> tuple[str, str]:
    try:
        asyncio.run(open_recorder(port))
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


async def test_bad_arguments_are_invalid_argument(pty: Pty) -> None:
    with pytest.raises(InvalidArgument, match="transport"):
        await open_recorder(pty.port, transport="turbo")
    with pytest.raises(InvalidArgument, match="baudrate"):
        await open_recorder(pty.port, baudrate=0)
    with pytest.raises(InvalidArgument, match="port"):
        await open_recorder(42)
    with pytest.raises(InvalidArgument):
        await open_recorder("nosuchscheme://x")
    with pytest.raises(InvalidArgument, match="direct"):
        await open_recorder("loop://", transport="direct")
    # None of these left the pty open: it can be opened now.
    line, rec = await open_recorder(pty.port)
    await close_line(line, rec)


# --------------------------------------------------------------------------- pyserial URLs


async def test_loop_url_round_trip() -> None:
    line, rec = await open_recorder("loop://")
    assert isinstance(line, InProcessTransport)  # no file descriptor: read from a thread
    line.write(b"\x80\x3a\x4c")
    line.write(b"\x01\x02")
    assert await rec.until(5) == b"\x80\x3a\x4c\x01\x02"
    discard_input(line)
    await close_line(line, rec)


@pytest.mark.parametrize("kind", ["auto", "fast", "stock"])
async def test_socket_url_round_trip(kind: str) -> None:
    async def echo(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        while data := await reader.read(100):
            writer.write(data + b"!")
        writer.close()

    server = await asyncio.start_server(echo, "127.0.0.1", 0, family=socket.AF_INET)
    port = server.sockets[0].getsockname()[1]
    async with server:
        line, rec = await open_recorder(f"socket://127.0.0.1:{port}", transport=kind)
        line.write(b"\x80\x3a\x4c")
        assert await rec.until(4) == b"\x80\x3a\x4c!"
        server.close()
        line.close()
        async with asyncio.timeout(WAIT):
            await rec.lost


# --------------------------------------------------------------------------- in-process lines


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


class Chatty(Recorder):
    """Writes from inside data_received, as the bus does, and checks for reentrancy."""

    def __init__(self, rounds: int) -> None:
        super().__init__()
        self.rounds = rounds
        self.depth = 0
        self.max_depth = 0

    def data_received(self, data: bytes) -> None:
        self.depth += 1
        self.max_depth = max(self.max_depth, self.depth)
        super().data_received(data)
        if self.rounds and data != b"hello" and data[0] < 0x80:  # after each reply, write again
            self.rounds -= 1
            assert isinstance(self.transport, asyncio.WriteTransport)
            self.transport.write(bytes([0x80 | self.rounds]))
        self.depth -= 1


async def test_in_process_delivery_is_never_reentrant() -> None:
    device = FakeDevice()
    line, proto = await open_line(device, baudrate=1250000, protocol_factory=lambda: Chatty(rounds=50))
    assert isinstance(line, InProcessTransport)
    assert device.baudrate == 1250000
    assert proto.chunks == [b"hello"]  # after connection_made, not before
    line.write(b"\x80")
    assert proto.chunks == [b"hello"], "delivered synchronously inside write()"
    await proto.until(len(b"hello") + 2 * 51)
    assert proto.max_depth == 1
    assert len(device.written) == 51
    await close_line(line, proto)
    assert device.disconnected


async def test_in_process_delivery_from_another_thread_keeps_order() -> None:
    device = FakeDevice(threaded=True)
    line, rec = await open_recorder(device)
    payload = bytes(range(200))
    line.write(payload)
    assert await rec.until(5 + 400) == b"hello" + payload * 2
    await close_line(line, rec)


async def test_in_process_lost_propagates_after_pending_data() -> None:
    device = FakeDevice()
    line, rec = await open_recorder(device)
    assert device.host is not None
    host = device.host
    gone = OSError(errno.EIO, "unplugged")
    thread = threading.Thread(target=lambda: (host.deliver(b"last words"), host.lost(gone)))
    thread.start()
    thread.join()
    async with asyncio.timeout(WAIT):
        assert await rec.lost is gone
    assert rec.data == b"hellolast words"
    assert line.is_closing()
    line.write(b"ignored")
    line.close()  # harmless after loss
    assert device.written == []


async def test_in_process_close_drops_late_data_and_reports_once() -> None:
    device = FakeDevice()
    line, rec = await open_recorder(device)
    assert device.host is not None
    await rec.until(5)
    line.close()
    device.host.deliver(b"too late")
    device.host.lost(OSError("after close"))
    line.close()
    async with asyncio.timeout(WAIT):
        assert await rec.lost is None
    await asyncio.sleep(0.01)  # let any stray callback run (the recorder asserts on them)
    assert rec.data == b"hello"


async def test_in_process_write_failure_reports_lost() -> None:
    class Unplugged(FakeDevice):
        def write(self, data: bytes) -> None:
            raise OSError(errno.EIO, "gone")

    line, rec = await open_recorder(Unplugged())
    line.write(b"\x80")
    async with asyncio.timeout(WAIT):
        exc = await rec.lost
    assert isinstance(exc, OSError) and exc.errno == errno.EIO


async def test_in_process_connect_failure_propagates() -> None:
    made: list[Recorder] = []

    def factory() -> Recorder:
        made.append(Recorder())
        return made[0]

    with pytest.raises(OSError, match="unplugged"):
        await open_line(FakeDevice(refuse=True), baudrate=115200, protocol_factory=factory)
    await asyncio.sleep(0)
    assert made[0].made_count == 0


async def test_in_process_pause_and_resume_reading() -> None:
    device = FakeDevice()
    line, rec = await open_recorder(device)
    await rec.until(5)
    line.pause_reading()
    line.write(b"\x01")
    await asyncio.sleep(0.01)
    assert rec.data == b"hello"
    line.resume_reading()
    assert await rec.until(7) == b"hello\x01\xfe"
    discard_input(line)  # nothing to discard in-process; must not fail
    await close_line(line, rec)


async def test_registered_url_scheme_builds_the_device() -> None:
    devices: dict[str, FakeDevice] = {}

    def factory(url: str) -> WireDevice:
        devices[url] = FakeDevice()
        return devices[url]

    register_url_scheme("faketest", factory)
    line, rec = await open_recorder("faketest://bus0?servos=3", transport="stock")  # transport is ignored
    assert isinstance(line, InProcessTransport)
    assert line.get_extra_info("device") is devices["faketest://bus0?servos=3"]
    assert await rec.until(5) == b"hello"
    await close_line(line, rec)


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


async def test_direct_transport_unmarks_ff_bytes_on_a_real_pty() -> None:
    """The kernel doubles 0xFF once PARMRK is on: the host must still see one FF."""
    master, slave = os.openpty()
    path = os.ttyname(slave)
    try:
        received: list[bytes] = []

        class Collect(asyncio.Protocol):
            def data_received(self, data: bytes) -> None:
                received.append(data)

        line, _ = await transport.open_line(path, baudrate=115200, protocol_factory=Collect, transport="direct")
        try:
            os.write(master, b"\xff\x00\x00\x00\xf4")
            for _ in range(200):
                if sum(map(len, received)) >= 5:
                    break
                await asyncio.sleep(0.005)
            assert b"".join(received) == b"\xff\x00\x00\x00\xf4"
        finally:
            line.close()
            await asyncio.sleep(0.01)
    finally:
        os.close(master)
        os.close(slave)


async def test_input_flushed_between_readiness_and_read_is_not_a_hangup(pty: Pty) -> None:
    """The resync's flush can empty the input after the loop saw it readable and before our reader runs.

    A raw tty (VMIN=0) then reads 0 bytes, which is not the device going away.
    """
    line, rec = await open_recorder(pty.port, transport="direct")
    assert isinstance(line, DirectSerialTransport)
    os.write(pty.master, b"\x55\xaa")
    await asyncio.sleep(0.05)  # the bytes wait in the input queue; the reader callback is due
    line.discard_input()  # what the bus does when a resync ends
    line._read_ready()  # the reader callback that was already due
    await asyncio.sleep(0.01)
    assert not rec.lost.done(), "an emptied input was taken for a hangup"
    os.write(pty.master, b"\x01")
    async with asyncio.timeout(WAIT):
        while b"\x01" not in rec.data:
            await asyncio.sleep(0.005)
    await close_line(line, rec)
