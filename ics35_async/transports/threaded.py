"""pyserial ports without a file descriptor (``loop://``, ``rfc2217://``, Windows COM ports): a reader thread."""

from __future__ import annotations

import contextlib
import errno
import threading

import serial

from .wire_device import HostSide


class ThreadedSerialDevice:
    """A pyserial port without a file descriptor (``loop://``, ``rfc2217://``).

    The event loop cannot wait on such a port, so a reader thread blocks in
    ``read`` and hands the bytes over like any in-process device would.
    """

    _POLL = 0.05  # how long the reader thread blocks before checking for shutdown

    def __init__(self, ser: serial.SerialBase) -> None:
        self._serial = ser
        self._host: HostSide | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def connect(self, host: HostSide, baudrate: int) -> None:
        self._host = host
        # write_timeout=0 makes loop:// refuse every write; these ports buffer.
        self._serial.write_timeout = None
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

    def write(self, data: bytes) -> None:
        try:
            self._serial.write(data)
        except serial.SerialException:
            raise
        except Exception as exc:
            raise OSError(errno.EIO, f"serial write failed: {exc}") from exc

    def discard_input(self) -> None:
        self._serial.reset_input_buffer()

    def disconnect(self) -> None:
        self._stop.set()
        cancel_read = getattr(self._serial, "cancel_read", None)
        if cancel_read is not None:
            with contextlib.suppress(Exception):
                cancel_read()  # wakes the reader now rather than after its poll timeout
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=1.0)
        self._serial.close()
