"""pyserial ports without a file descriptor (``loop://``, ``rfc2217://``, Windows COM ports): a reader thread."""

from __future__ import annotations

import contextlib
import errno
import threading
import time

import serial

from .serial_port import READ_POLL, discard_blocking_input, write_blocking
from .wire_device import HostSide


class ThreadedSerialDevice:
    """A pyserial port without a file descriptor (``loop://``, ``rfc2217://``).

    The event loop cannot wait on such a port, so a reader thread blocks in
    ``read`` and hands the bytes over like any in-process device would.
    """

    _POLL = READ_POLL  # how long the reader thread blocks before checking for shutdown

    def __init__(self, ser: serial.SerialBase) -> None:
        self._serial = ser
        self._host: HostSide | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def connect(self, host: HostSide, baudrate: int) -> None:
        self._host = host
        # write_timeout=0 makes loop:// refuse every write; these ports buffer.  Each setting is
        # changed only when it must be: over RFC 2217 a change is a round trip to the far end.
        if self._serial.write_timeout is not None:
            self._serial.write_timeout = None
        if self._serial.timeout != self._POLL:
            self._serial.timeout = self._POLL
        self._thread = threading.Thread(target=self._read_loop, name=f"ics35-reader {self._serial.port}", daemon=True)
        self._thread.start()

    def _read_loop(self) -> None:
        ser, host = self._serial, self._host
        assert host is not None
        try:
            while not self._stop.is_set():
                data = ser.read(ser.in_waiting or 1)
                if data and not self._stop.is_set():
                    host.deliver(data)
        except Exception as exc:
            if not self._stop.is_set():
                host.lost(exc if isinstance(exc, OSError) else OSError(errno.EIO, f"serial read failed: {exc}"))
        finally:
            self._close_port()

    def _close_port(self) -> None:
        # pyserial's socket and RFC 2217 handlers shut their socket, then sleep 0.3 s "to give the
        # server time": done here, in the reader thread, that sleep holds no event loop up.
        with contextlib.suppress(Exception):
            self._serial.close()

    def write(self, data: bytes) -> None:
        write_blocking(self._serial, data)

    def discard_input(self) -> None:
        discard_blocking_input(self._serial)

    def disconnect(self) -> None:
        self._stop.set()
        cancel_read = getattr(self._serial, "cancel_read", None)
        if cancel_read is not None:
            with contextlib.suppress(Exception):
                cancel_read()  # wakes the reader now rather than after its poll timeout
        thread = self._thread
        if thread is None or not thread.is_alive():
            self._close_port()
            return
        if thread is threading.current_thread():
            return  # the reader closes the port on its way out
        # Wait until the reader has shut the port (is_open drops before pyserial's closing sleep),
        # so that it is free when this returns: a one-client bridge takes the next connection then.
        deadline = time.monotonic() + 1.0
        while self._serial.is_open and thread.is_alive() and time.monotonic() < deadline:
            thread.join(0.005)
