"""An in-process device as a port: the simulator, a test double, or a reader thread over a pyserial port.

The device answers through :meth:`DevicePort.deliver` (the port is the
device's :class:`~.wire_device.HostSide`), from whatever thread it runs on;
the bytes queue here and :attr:`DevicePort.on_input` tells the driver,
which reads them on its own side, never from inside ``write``.
"""

from __future__ import annotations

import contextlib
import errno
import logging
from collections import deque
from collections.abc import Callable

from .wire_device import WireDevice

log = logging.getLogger("ics35_async.transports")


def _nobody() -> None:
    pass


class DevicePort:
    """The host end of an in-process line."""

    kind = "device"
    bad = 0  # an in-process device marks no bytes damaged

    def __init__(self, device: WireDevice) -> None:
        self.device = device
        # Told (from any thread) that bytes came or the device went away; the driver sets it
        # before anything can arrive that it must hear of, and reads on its own side.
        self.on_input: Callable[[], None] = _nobody
        self._chunks: deque[bytes] = deque()  # append and popleft only: safe across threads
        # A device that delivers from a thread of its own may hand over what is due when the driver looks (see
        # WireDevice): a busy program holds that thread back, where a real port's bytes wait in the OS's buffer.
        # So a driver looks (has_input, read) holding nothing that on_input takes: the look may wait for that
        # thread's own hand-over, which tells on_input.
        self._take_due: Callable[[], object] | None = getattr(device, "deliver_due", None)
        self._lost: Exception | None = None
        self._gone = False

    def stop_telling(self) -> None:
        """Tell nobody of input from now on (the driver stops waiting on this port)."""
        self.on_input = _nobody

    def connect(self, baudrate: int) -> None:
        """Attach to the device (raises :class:`OSError` when it cannot be opened)."""
        self.device.connect(self, baudrate)

    # -- the device's side (HostSide), any thread

    def deliver(self, data: bytes) -> None:
        if not self._gone and self._lost is None:  # nothing arrives after the line went away
            self._chunks.append(data if type(data) is bytes else bytes(data))
            self.on_input()

    def lost(self, exc: Exception | None) -> None:
        self._lost = exc or OSError(errno.EIO, "the device went away")
        self.on_input()

    # -- the driver's side

    @property
    def has_input(self) -> bool:
        """Something to read: bytes, or the news that the device went away."""
        if self._take_due is not None:
            self._take_due()
        return bool(self._chunks) or self._lost is not None

    def read(self) -> bytes:
        """What the device delivered, as one chunk; else why it went away, raised; else ``b""``.

        Bytes that came before a loss are read first.
        """
        if self._take_due is not None:
            self._take_due()
        chunks = self._chunks
        if chunks:
            data = chunks.popleft()
            while chunks:
                data += chunks.popleft()
            return data
        if self._lost is not None:
            raise self._lost
        return b""

    def write(self, data: bytes) -> bool:
        if not self._gone:
            self.device.write(data)
        return True

    def discard_input(self) -> int:
        """Drop what arrived but was not read (a real port's OS buffer), and the device's own if it can;
        return how many bytes that was (the device's count where it gives one)."""
        chunks = self._chunks
        dropped = 0
        with contextlib.suppress(IndexError):  # a device's thread may deliver meanwhile: one chunk at a time
            while chunks:
                dropped += len(chunks.popleft())
        discard = getattr(self.device, "discard_input", None)
        if discard is not None:
            more = discard()
            if isinstance(more, int):
                dropped += more
        return dropped

    def close(self) -> None:
        if self._gone:
            return
        self._gone = True
        try:
            self.device.disconnect()
        except Exception:
            log.debug("device %r failed to disconnect", self.device, exc_info=True)
