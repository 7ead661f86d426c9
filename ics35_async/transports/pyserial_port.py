"""A pyserial port with no descriptor to wait on (Windows COM ports, ``rfc2217://``, ``loop://``, ``socket://``).

Such a port can only be waited on by reading it: :meth:`SerialPort.read`
with ``block=True`` blocks until a byte comes or the port's short read
timeout passes.  The thread driver does that in its I/O thread; an event
loop cannot, so the asyncio and anyio drivers get the port behind a
:class:`ReaderThread`, which hands what it reads over as an in-process
device would (see :mod:`.device_port`).
"""

from __future__ import annotations

import contextlib
import errno
import threading
import time

import serial
import serial.rfc2217

from .wire_device import HostSide

SERIAL_POLL = 0.005
"""Seconds the thread driver's read of such a port blocks: its deadlines are judged up to this late,
since such a read cannot be woken everywhere.  A reader thread's reads block for ``READ_POLL`` before it
looks whether it should stop (most ports wake it at once through ``cancel_read``)."""


class SerialPort:
    """A pyserial port read with pyserial's own blocking reads."""

    kind = "serial"
    bad = 0  # pyserial reports no parity marks

    def __init__(self, ser: serial.SerialBase, poll: float = SERIAL_POLL) -> None:
        self.serial = ser
        # write_timeout=0 makes loop:// refuse every write; these ports buffer.  Each setting
        # changes only when it must: over RFC 2217 a change is a round trip to the far end.
        if ser.write_timeout is not None:
            ser.write_timeout = None
        if ser.timeout != poll:
            ser.timeout = poll
        self._cancel = getattr(ser, "cancel_read", None)
        # Counts up as each input discard starts and again as it ends (odd: one is under way).
        self._discards = 0

    def read(self, block: bool = False) -> bytes:
        """What has arrived; with ``block``, wait up to the port's read timeout for a first byte."""
        ser = self.serial
        discards = self._discards
        try:
            waiting = ser.in_waiting
            if not waiting and not block:
                return b""
            return bytes(ser.read(waiting or 1))
        except serial.SerialException:
            if discards % 2 or discards != self._discards:
                # A discard from another thread (a reader thread's driver) emptied the input between
                # pyserial's wait and its read, which then says "readiness to read but returned no
                # data", as for a device that went away.  The port is fine; what was read is dropped,
                # as the discard asked.  A port that did go away fails the next read too.
                return b""
            raise
        except Exception as exc:  # a URL handler's socket error
            raise OSError(errno.EIO, f"serial read failed: {exc}") from exc

    def wake(self) -> None:
        """End a blocking read early, where pyserial can (not every platform)."""
        if self._cancel is not None:
            with contextlib.suppress(Exception):
                self._cancel()

    def write(self, data: bytes) -> bool:
        try:
            self.serial.write(data)
        except serial.SerialException:
            raise
        except Exception as exc:  # a URL handler's own error comes out as an OSError
            raise OSError(errno.EIO, f"serial write failed: {exc}") from exc
        return True

    def discard_input(self) -> int:
        """Drop what pyserial holds unread; return how many bytes it said were waiting just before.

        (pyserial has no way to drop and count at once: bytes that come in between go uncounted.)
        """
        # pyserial's RFC 2217 purge waits for the far end's answer (in 50 ms sleeps), past the
        # next transaction's deadline; the engine's quiet time does the job there instead.
        if isinstance(self.serial, serial.rfc2217.Serial):
            return 0
        waiting = 0
        self._discards += 1
        try:
            with contextlib.suppress(Exception):
                waiting = self.serial.in_waiting
                self.serial.reset_input_buffer()
        finally:
            self._discards += 1
        return waiting

    def close(self) -> None:
        # pyserial's socket and RFC 2217 handlers shut their socket, then sleep 0.3 s "to give
        # the server time": a driver closes from a thread of its own, never its event loop.
        with contextlib.suppress(Exception):
            self.serial.close()


class ReaderThread:
    """A :class:`SerialPort` as an in-process device: a thread blocks in its reads and delivers."""

    def __init__(self, port: SerialPort) -> None:
        self.port = port
        self._host: HostSide | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def connect(self, host: HostSide, baudrate: int) -> None:
        self._host = host
        name = f"ics35-reader {self.port.serial.port}"
        self._thread = threading.Thread(target=self._read_loop, args=(host,), name=name, daemon=True)
        self._thread.start()

    def _read_loop(self, host: HostSide) -> None:
        port, stop = self.port, self._stop
        try:
            while not stop.is_set():
                data = port.read(block=True)
                if data and not stop.is_set():
                    host.deliver(data)
        except OSError as exc:
            if not stop.is_set():
                host.lost(exc)
        finally:
            port.close()  # here, so that pyserial's closing sleep holds no event loop up

    def write(self, data: bytes) -> None:
        self.port.write(data)

    def discard_input(self) -> int:
        return self.port.discard_input()

    def disconnect(self) -> None:
        self._stop.set()
        self.port.wake()  # the reader sees the stop now rather than after its read timeout
        thread = self._thread
        if thread is None or not thread.is_alive():
            self.port.close()
            return
        if thread is threading.current_thread():
            return  # the reader closes the port on its way out
        # Wait until the reader has shut the port (is_open drops before pyserial's closing sleep),
        # so that it is free when this returns: a one-client bridge takes the next connection then.
        deadline = time.monotonic() + 1.0
        while self.port.serial.is_open and thread.is_alive() and time.monotonic() < deadline:
            thread.join(0.005)
