"""The ports the thread driver's I/O thread blocks on: a file descriptor, a pyserial port, an in-process device.

Each offers the same small face to :class:`~.thread_driver.ThreadDriver`:
``wait(timeout)`` blocks until bytes arrive, ``timeout`` seconds pass or
``wake()`` is called from another thread, and returns the bytes (``b""``
for a timeout or a wake; raises :class:`OSError` when the port is gone);
``bad`` counts bytes that arrived with parity or framing errors since the
driver last took it; ``write``, ``discard_input`` and ``close``.  Only the
I/O thread waits; writes come from either thread under the driver's lock.
"""

from __future__ import annotations

import contextlib
import errno
import math
import os
import select
import threading
import time
from collections import deque
from typing import Protocol

import serial
import serial.rfc2217

from ..transports import WireDevice
from ..transports.direct import ParityMarks, enable_parity_marks
from ..transports.serial_port import (
    TermiosError,
    discard_blocking_input,
    hung_up,
    open_serial,
    posix_fd,
    write_blocking,
)
from ..transports.wire_device import device_factory, take_delivered

try:
    import termios
except ImportError:  # no POSIX terminals (Windows): FdWait is never chosen there
    termios = None  # type: ignore[assignment]

INLINE_PAUSE = 50e-6
"""Seconds the I/O thread sleeps when an in-process device answered inside ``write`` (it never waits
otherwise); about a position transaction's time on the wire at 1.25 Mbit/s."""

SERIAL_POLL = 0.005
"""Seconds a pyserial port with no descriptor (Windows COM, ``rfc2217://``) blocks per read: its
deadlines are judged up to this late, since such a read cannot be woken everywhere."""


class ThreadPort(Protocol):
    bad: int

    def wait(self, timeout: float | None) -> bytes: ...

    def wake(self) -> None: ...

    def write(self, data: bytes) -> None: ...

    def discard_input(self) -> None: ...

    def close(self) -> None: ...


def open_thread_port(port: str | WireDevice, baudrate: int, direction: str) -> ThreadPort:
    """Open ``port`` for the I/O thread (blocking: call it from a thread)."""
    if not isinstance(port, str):
        return DeviceWait(port, baudrate)
    scheme, sep, _ = port.partition("://")
    factory = device_factory(scheme) if sep else None
    if factory is not None:
        return DeviceWait(factory(port), baudrate)
    ser = open_serial(port, baudrate, True, direction)
    try:
        return FdWait(ser) if posix_fd(ser) is not None else SerialWait(ser)
    except BaseException:
        ser.close()
        raise


class FdWait:
    """A port with a POSIX file descriptor: ``poll`` on it and a wake-up pipe, ``os.read``/``os.write``."""

    def __init__(self, ser: serial.SerialBase) -> None:
        self.serial = ser
        self.fd: int = ser.fileno()
        os.set_blocking(self.fd, False)
        # Bytes with parity/framing errors are marked by the kernel (see transports.direct).
        self._marks: ParityMarks | None = ParityMarks() if enable_parity_marks(self.fd) else None
        self.bad = 0
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        os.set_blocking(self._wake_w, False)
        self._poll = select.poll()
        self._poll.register(self.fd, select.POLLIN)
        self._poll.register(self._wake_r, select.POLLIN)
        self._pending = bytearray()  # what a partial write left
        # Writes come from either thread, flushes from the I/O thread, wake-ups and closing from either.
        self._pending_lock = threading.RLock()
        self._closed = False

    def wait(self, timeout: float | None) -> bytes:
        # poll counts whole milliseconds: round up, so a deadline is never judged early.
        events = self._poll.poll(None if timeout is None else math.ceil(timeout * 1000))
        if len(events) == 1 and events[0][1] == select.POLLIN and events[0][0] == self.fd:
            return self._read()  # the usual case: the reply, and nothing else
        data = b""
        for fd, mask in events:
            if fd == self.fd:
                if mask & select.POLLNVAL:
                    raise OSError(errno.EBADF, "the serial port was closed")
                if mask & select.POLLOUT:
                    self._flush()
                if mask & (select.POLLIN | select.POLLHUP | select.POLLERR):
                    data = self._read()
            else:
                with contextlib.suppress(BlockingIOError):
                    os.read(self._wake_r, 512)
        return data

    def _read(self) -> bytes:
        try:
            data = os.read(self.fd, 4096)
        except (BlockingIOError, InterruptedError):
            return b""
        if not data:
            # A raw tty reads 0 bytes when its input was flushed between poll and read: only
            # POLLHUP is a hangup (see transports.direct).
            if hung_up(self.fd):
                raise OSError(errno.EIO, "the serial port hung up (device disconnected?)")
            return b""
        marks = self._marks
        if marks is not None and (0xFF in data or marks.pending):
            data, errors = marks.decode(data)
            self.bad += errors
        return data

    def wake(self) -> None:
        with self._pending_lock:  # never into a descriptor that close() gave back (it may be reused)
            if self._closed:
                return
            with contextlib.suppress(BlockingIOError):  # a full pipe: a wake-up is pending anyway
                os.write(self._wake_w, b"\0")

    def write(self, data: bytes) -> None:
        with self._pending_lock:
            if self._pending:
                self._pending += data
                return
            try:
                n = os.write(self.fd, data)
            except (BlockingIOError, InterruptedError):
                n = 0
            if n < len(data):
                self._pending += data[n:]
                self._poll.modify(self.fd, select.POLLIN | select.POLLOUT)
                self.wake()  # a wait already under way does not watch for POLLOUT yet

    def _flush(self) -> None:
        with self._pending_lock:
            try:
                n = os.write(self.fd, self._pending)
            except (BlockingIOError, InterruptedError):
                return
            del self._pending[:n]
            if not self._pending:
                self._poll.modify(self.fd, select.POLLIN)

    def discard_input(self) -> None:
        with contextlib.suppress(OSError, TermiosError):
            termios.tcflush(self.fd, termios.TCIFLUSH)

    def close(self) -> None:
        with self._pending_lock:
            if self._closed:
                return
            self._closed = True
            for fd in (self._wake_r, self._wake_w):
                with contextlib.suppress(OSError):
                    os.close(fd)
        with contextlib.suppress(Exception):
            self.serial.close()


class SerialWait:
    """A pyserial port with no descriptor (Windows COM ports, ``rfc2217://``, ``loop://``): blocking reads."""

    def __init__(self, ser: serial.SerialBase) -> None:
        self.serial = ser
        self.bad = 0
        # Each setting changes only when it must: over RFC 2217 a change is a round trip.
        if ser.write_timeout is not None:
            ser.write_timeout = None
        if ser.timeout != SERIAL_POLL:
            ser.timeout = SERIAL_POLL
        self._cancel = getattr(ser, "cancel_read", None)

    def wait(self, timeout: float | None) -> bytes:
        ser = self.serial
        try:
            waiting = ser.in_waiting
            if not waiting and timeout is not None and timeout <= 0:
                return b""  # a look, not a wait
            return bytes(ser.read(waiting or 1))
        except serial.SerialException:
            raise
        except Exception as exc:  # a URL handler's socket error
            raise OSError(errno.EIO, f"serial read failed: {exc}") from exc

    def wake(self) -> None:
        if self._cancel is not None:
            with contextlib.suppress(Exception):
                self._cancel()

    def write(self, data: bytes) -> None:
        write_blocking(self.serial, data)

    def discard_input(self) -> None:
        with contextlib.suppress(Exception):
            discard_blocking_input(self.serial)

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self.serial.close()


class DeviceWait:
    """An in-process device (the simulator): its answers queue here, from whatever thread it runs."""

    def __init__(self, device: WireDevice, baudrate: int) -> None:
        self.device = device
        self.bad = 0
        self._cond = threading.Condition()
        self._chunks: deque[bytes] = deque()
        self._lost: Exception | None = None
        self._woken = False
        self._gone = False
        device.connect(self, baudrate)

    # -- the device's side (HostSide), any thread

    def deliver(self, data: bytes) -> None:
        with self._cond:
            if not self._gone:
                self._chunks.append(bytes(data))
                self._cond.notify()

    def lost(self, exc: Exception | None) -> None:
        with self._cond:
            self._lost = exc or OSError(errno.EIO, "the device went away")
            self._cond.notify()

    # -- the driver's side

    def wait(self, timeout: float | None) -> bytes:
        if self._chunks and timeout != 0:
            # The device answered inside write (a fast simulator): pause as a wire would.  A thread
            # that never blocks would keep the engine's lock from the loop's callers for good.
            time.sleep(INLINE_PAUSE)
        with self._cond:
            if not self._chunks and self._lost is None and not self._woken:
                self._cond.wait(timeout)
            self._woken = False
            return take_delivered(self._chunks, self._lost)

    def wake(self) -> None:
        with self._cond:
            self._woken = True
            self._cond.notify()

    def write(self, data: bytes) -> None:
        if not self._gone:
            self.device.write(data)

    def discard_input(self) -> None:
        with self._cond:
            self._chunks.clear()  # arrived but not yet read: the OS buffer of a real port
        discard = getattr(self.device, "discard_input", None)
        if discard is not None:
            discard()

    def close(self) -> None:
        with self._cond:
            if self._gone:
                return
            self._gone = True
        with contextlib.suppress(Exception):
            self.device.disconnect()
