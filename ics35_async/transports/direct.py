"""Our own POSIX transport on the file descriptor of an open pyserial port (device paths, ptys)."""

from __future__ import annotations

import asyncio
import errno
import logging
import os
from typing import cast

import serial

from .serial_port import hung_up

try:
    import termios
except ImportError:  # no POSIX terminals (Windows): nothing here is chosen for a port there
    termios = None  # type: ignore[assignment]

log = logging.getLogger("ics35_async.transports")


class ParityMarks:
    """Undo the kernel's PARMRK marking of received bytes.

    With INPCK and PARMRK set (and IGNPAR, ISTRIP clear), Linux passes a
    byte that arrived with a parity or framing error as ``FF 00 x`` and a
    genuine ``FF`` as ``FF FF``.  :meth:`decode` returns the bytes as they
    were on the wire and how many of them were marked bad; a mark split
    across two reads is completed by the next call.
    """

    __slots__ = ("_pending",)

    def __init__(self) -> None:
        self._pending = b""

    @property
    def pending(self) -> bool:
        """A mark split across reads waits for its next byte: the next chunk must be decoded."""
        return bool(self._pending)

    def decode(self, data: bytes) -> tuple[bytes, int]:
        if self._pending:
            data = self._pending + data
            self._pending = b""
        elif 0xFF not in data:
            return data, 0
        out = bytearray()
        errors = 0
        i, n = 0, len(data)
        while i < n:
            j = data.find(b"\xff", i)
            if j < 0:
                out += data[i:]
                break
            out += data[i:j]
            if j + 1 >= n:
                self._pending = data[j:]
                break
            if data[j + 1] == 0xFF:
                out.append(0xFF)
                i = j + 2
            elif data[j + 1] == 0x00:
                if j + 2 >= n:
                    self._pending = data[j:]
                    break
                out.append(data[j + 2])
                errors += 1
                i = j + 3
            else:  # not a mark (PARMRK off after all): keep it as it came
                out.append(0xFF)
                i = j + 1
        return bytes(out), errors


def enable_parity_marks(fd: int) -> bool:
    """Ask the kernel to mark bytes received with parity/framing errors; True if set."""
    try:
        attrs = termios.tcgetattr(fd)
        attrs[0] |= termios.INPCK | termios.PARMRK
        attrs[0] &= ~(termios.IGNPAR | termios.ISTRIP)
        termios.tcsetattr(fd, termios.TCSANOW, attrs)
        return bool(termios.tcgetattr(fd)[0] & termios.PARMRK)
    except termios.error:
        log.debug("could not enable parity-error marks on fd %d", fd, exc_info=True)
        return False


class DirectSerialTransport(asyncio.Transport):
    """A minimal POSIX transport on the file descriptor of an open pyserial port.

    pyserial opens and configures the port; after that, reading is one
    ``os.read`` per readiness event and ``write`` calls ``os.write`` at once,
    skipping pyserial's per-call ``select`` and timeout bookkeeping.  Only for
    ports that are real file descriptors (device paths, ptys).
    """

    max_read_size = 4096

    def __init__(self, loop: asyncio.AbstractEventLoop, protocol: asyncio.Protocol, ser: serial.Serial) -> None:
        super().__init__({"serial": ser})
        self._loop = loop
        self._protocol = protocol
        self._serial: serial.Serial | None = ser
        self._fd: int = ser.fileno()
        # pyserial opens O_NONBLOCK; rely on it being so, since with VMIN=0 a
        # blocking read of an empty tty returns 0 bytes, which means hangup here.
        os.set_blocking(self._fd, False)
        # pyserial turns input parity checking off; we want corrupted bytes reported
        # (ICS has no checksum), so the kernel marks them and we unmark them here.
        self._marks: ParityMarks | None = ParityMarks() if enable_parity_marks(self._fd) else None
        self._line_error = getattr(protocol, "line_error", None)
        self._buffer = bytearray()
        self._closing = False
        self._finish_scheduled = False
        self._reading = False
        self._writing = False
        self._high_water = 64 * 1024
        self._low_water = 16 * 1024
        self._protocol_paused = False
        loop.call_soon(protocol.connection_made, self)
        loop.call_soon(self._start_reading)

    @property
    def serial(self) -> serial.Serial | None:
        return self._serial

    # -- the burst path (ics35_async.drivers.burst): a compiled executor reads and writes the descriptor

    @property
    def burst_fd(self) -> int:
        """The descriptor a burst executor may run transactions on while reading is paused."""
        return self._fd

    @property
    def marks(self) -> ParityMarks | None:
        """The decoder of the kernel's parity marks, when the port marks them."""
        return self._marks

    def in_between(self) -> bool:
        """Bytes still to write, or half a parity mark read: the ordinary path must finish them first."""
        return bool(self._buffer) or (self._marks is not None and self._marks.pending)

    # -- reading

    def _start_reading(self) -> None:
        if not self._reading and not self._closing:
            self._loop.add_reader(self._fd, self._read_ready)
            self._reading = True

    def _stop_reading(self) -> None:
        if self._reading:
            self._loop.remove_reader(self._fd)
            self._reading = False

    def _read_ready(self) -> None:
        try:
            data = os.read(self._fd, self.max_read_size)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as exc:
            self._abort(exc)
            return
        if data:
            marks = self._marks
            if marks is not None:
                data, errors = marks.decode(data)
                if errors and self._line_error is not None:
                    self._line_error(errors)
                if not data:
                    return
            self._protocol.data_received(data)
        elif hung_up(self._fd):
            # 0 bytes from a readable tty: the device is gone (hangup) -- or, with VMIN=0, the
            # input was flushed (a resync) between the readiness event and this read: not an end.
            self._abort(OSError(errno.EIO, "the serial port hung up (device disconnected?)"))

    # -- writing

    def write(self, data: bytes | bytearray | memoryview) -> None:
        if self._closing:
            return
        if self._buffer:
            self._buffer += data
            self._maybe_pause_protocol()
            return
        try:
            n = os.write(self._fd, data)
        except (BlockingIOError, InterruptedError):
            n = 0
        except OSError as exc:
            self._abort(exc)
            return
        if n == len(data):
            return
        self._buffer += memoryview(data)[n:]
        self._loop.add_writer(self._fd, self._write_ready)
        self._writing = True
        self._maybe_pause_protocol()

    def _write_ready(self) -> None:
        try:
            n = os.write(self._fd, self._buffer)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as exc:
            self._abort(exc)
            return
        del self._buffer[:n]
        if not self._buffer:
            self._loop.remove_writer(self._fd)
            self._writing = False
            if self._closing:
                self._schedule_finish(None)
        self._maybe_resume_protocol()

    def _maybe_pause_protocol(self) -> None:
        if not self._protocol_paused and len(self._buffer) > self._high_water:
            self._protocol_paused = True
            self._protocol.pause_writing()

    def _maybe_resume_protocol(self) -> None:
        if self._protocol_paused and len(self._buffer) <= self._low_water:
            self._protocol_paused = False
            self._protocol.resume_writing()

    def get_write_buffer_size(self) -> int:
        return len(self._buffer)

    def get_write_buffer_limits(self) -> tuple[int, int]:
        return self._low_water, self._high_water

    def set_write_buffer_limits(self, high: int | None = None, low: int | None = None) -> None:
        if high is None:
            high = 64 * 1024 if low is None else 4 * low
        if low is None:
            low = high // 4
        if not high >= low >= 0:
            raise ValueError(f"high ({high!r}) must be >= low ({low!r}) must be >= 0")
        self._high_water, self._low_water = high, low
        self._maybe_pause_protocol()

    def can_write_eof(self) -> bool:
        return False

    # -- life cycle

    def is_closing(self) -> bool:
        return self._closing

    def is_reading(self) -> bool:
        return self._reading

    def pause_reading(self) -> None:
        self._stop_reading()

    def resume_reading(self) -> None:
        self._start_reading()

    def get_protocol(self) -> asyncio.BaseProtocol:
        return self._protocol

    def set_protocol(self, protocol: asyncio.BaseProtocol) -> None:
        self._protocol = cast(asyncio.Protocol, protocol)

    def close(self) -> None:
        """Stop reading; finish writing what is buffered; then release the port."""
        if self._closing:
            return
        self._closing = True
        self._stop_reading()
        if not self._buffer:
            self._schedule_finish(None)

    def abort(self) -> None:
        self._abort(None)

    def _abort(self, exc: Exception | None) -> None:
        self._closing = True
        self._stop_reading()
        if self._writing:
            self._loop.remove_writer(self._fd)
            self._writing = False
        self._buffer.clear()
        self._schedule_finish(exc)

    def _schedule_finish(self, exc: Exception | None) -> None:
        if not self._finish_scheduled:
            self._finish_scheduled = True
            self._loop.call_soon(self._finish, exc)

    def _finish(self, exc: Exception | None) -> None:
        ser, self._serial = self._serial, None
        if ser is None:
            return
        try:
            ser.close()
        except OSError:
            log.debug("closing %s failed", ser.port, exc_info=True)
        self._protocol.connection_lost(exc)

    def discard_input(self) -> None:
        """Drop what sits in the OS input buffer."""
        if self._serial is not None:
            termios.tcflush(self._fd, termios.TCIFLUSH)
