"""The two kinds of port the anyio driver reads: a file descriptor, or an in-process device.

Both offer the same small face to :class:`~.anyio_driver.AnyioDriver`:
``wait_input()`` (returns when bytes may be there; the driver's cancel scope
ends it early), ``read()`` (what has arrived, ``b""`` if nothing; raises
:class:`OSError` when the port is gone), ``write()``, ``discard_input()``
and ``close()``.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import os
import select
import threading
from collections import deque
from collections.abc import Callable

import anyio
import anyio.lowlevel
import serial

from ..transports import WireDevice
from ..transports.direct import ParityMarks, enable_parity_marks
from ..transports.serial_port import TermiosError, hung_up
from ..transports.wire_device import take_delivered

try:
    import termios
except ImportError:  # no POSIX terminals (Windows): nothing here is chosen for a port there
    termios = None  # type: ignore[assignment]


def soon_threadsafe() -> Callable[[Callable[[], None]], None]:
    """A function that runs a callback on the running event loop's thread, callable from any thread."""
    try:
        loop = asyncio.get_running_loop()
    except RuntimeError:  # not asyncio: trio (the only other backend anyio has)
        import trio

        token = trio.lowlevel.current_trio_token()

        def trio_soon(callback: Callable[[], None]) -> None:
            token.run_sync_soon(callback)

        return trio_soon

    def asyncio_soon(callback: Callable[[], None]) -> None:
        loop.call_soon_threadsafe(callback)

    return asyncio_soon


class FdPort:
    """A pyserial port read and written on its file descriptor (device paths, ptys)."""

    def __init__(self, ser: serial.Serial) -> None:
        self.serial = ser
        self.fd: int = ser.fileno()
        os.set_blocking(self.fd, False)
        # Bytes with parity/framing errors are marked by the kernel (see transports.direct):
        # ICS replies carry no checksum, so a damaged byte is caught only this way.
        self._marks: ParityMarks | None = ParityMarks() if enable_parity_marks(self.fd) else None
        self.bad = 0  # bytes marked damaged since the driver last took the count
        self.pending = bytearray()  # what a partial write left
        self._ready = False  # the last wait ended because the fd became readable

    async def wait_input(self) -> None:
        if self.pending:
            await anyio.wait_writable(self.fd)
            self.write(b"")
        await anyio.wait_readable(self.fd)
        self._ready = True

    def read(self) -> bytes:
        ready, self._ready = self._ready, False
        # With VMIN=0 (pyserial's timeout=0) a tty read with nothing waiting returns 0 bytes,
        # not EAGAIN: read only what poll says is there, so 0 bytes can mean hangup alone.
        if not ready and not select.select([self.fd], [], [], 0)[0]:
            return b""
        try:
            data = os.read(self.fd, 4096)
        except (BlockingIOError, InterruptedError):
            return b""
        # A raw tty (VMIN=0, VTIME=0) also reads 0 bytes when its input went away between the
        # wake-up and the read (Linux returns 0 there even with O_NONBLOCK): only POLLHUP is a hangup.
        if not data and hung_up(self.fd):
            raise OSError(errno.EIO, "the serial port hung up (device disconnected?)")
        marks = self._marks
        if marks is not None and (0xFF in data or marks.pending):
            data, errors = marks.decode(data)
            self.bad += errors
        return data

    def write(self, data: bytes) -> None:
        self.pending += data
        try:
            n = os.write(self.fd, self.pending)
        except (BlockingIOError, InterruptedError):
            return
        del self.pending[:n]

    def discard_input(self) -> None:
        with contextlib.suppress(OSError, TermiosError):
            termios.tcflush(self.fd, termios.TCIFLUSH)

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self.serial.close()


class DevicePort:
    """An in-process device (the simulator, or a reader thread over a port with no descriptor).

    The device answers through :meth:`deliver` from any thread; bytes are
    queued and the driver's wait is ended through ``wake``.
    """

    bad = 0  # an in-process device marks no bytes damaged

    def __init__(self, device: WireDevice, wake: Callable[[], None]) -> None:
        self.device = device
        self._wake = wake
        self._soon = soon_threadsafe()
        self._thread = threading.get_ident()
        self._chunks: deque[bytes] = deque()
        self._lost: Exception | None = None
        self._gone = False

    # -- the device's side (HostSide), any thread

    def deliver(self, data: bytes) -> None:
        if threading.get_ident() == self._thread:
            self._arrived(bytes(data))
        else:
            with contextlib.suppress(RuntimeError):  # the loop has ended: nobody is left to tell
                self._soon(lambda: self._arrived(bytes(data)))

    def lost(self, exc: Exception | None) -> None:
        def mark() -> None:
            self._lost = exc or OSError(errno.EIO, "the device went away")
            self._wake()

        if threading.get_ident() == self._thread:
            mark()
        else:
            with contextlib.suppress(RuntimeError):
                self._soon(mark)

    def _arrived(self, data: bytes) -> None:
        if not self._gone:
            self._chunks.append(data)
            self._wake()

    # -- the driver's side

    async def wait_input(self) -> None:
        if self._chunks or self._lost is not None:
            # Already here (a fast simulator answers inside write): still let other tasks run,
            # or a line that never waits would starve its own callers.
            await anyio.lowlevel.checkpoint()
            return
        await anyio.sleep_forever()

    def read(self) -> bytes:
        return take_delivered(self._chunks, self._lost)

    def write(self, data: bytes) -> None:
        if not self._gone:
            self.device.write(data)

    def discard_input(self) -> None:
        discard = getattr(self.device, "discard_input", None)
        if discard is not None:
            discard()

    def close(self) -> None:
        if not self._gone:
            self._gone = True
            with contextlib.suppress(Exception):
                self.device.disconnect()
