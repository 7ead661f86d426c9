"""An asyncio transport whose far end is an in-process device (see :mod:`.wire_device`)."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
from collections.abc import Callable
from typing import Any, cast

from .wire_device import HostSide, WireDevice

log = logging.getLogger("ics35_async.transports")

class _Host:
    """The :class:`HostSide` handed to a device; forwards to its transport."""

    __slots__ = ("_transport",)

    def __init__(self, transport: InProcessTransport) -> None:
        self._transport = transport

    def deliver(self, data: bytes) -> None:
        self._transport._schedule(self._transport._data_received, data)

    def lost(self, exc: Exception | None) -> None:
        self._transport._schedule(self._transport._device_lost, exc)


class InProcessTransport(asyncio.Transport):
    """An asyncio transport whose far end is a :class:`WireDevice` in this process.

    ``write`` hands the bytes straight to ``device.write``.  The device's
    answers always reach ``protocol.data_received`` through the event loop,
    never synchronously: the bus writes from inside ``data_received``, and a
    device answering inside ``write`` would otherwise re-enter it.

    Create it on the event loop's thread.  It is on the hot path of every
    in-process transaction, hence the plain attribute juggling.
    """

    def __init__(
        self,
        loop: asyncio.AbstractEventLoop,
        protocol: asyncio.Protocol,
        device: WireDevice,
        *,
        extra: dict[str, Any] | None = None,
    ) -> None:
        super().__init__({"device": device, **(extra or {})})
        self._loop = loop
        self._protocol = protocol
        self._device = device
        self._loop_thread = threading.get_ident()
        self._closing = False
        self._lost_reported = False
        self._paused: list[bytes] | None = None
        self.host: HostSide = _Host(self)

    # -- called by the device, from any thread

    def _schedule(self, callback: Callable[[Any], None], arg: Any) -> None:
        if threading.get_ident() == self._loop_thread:
            self._loop.call_soon(callback, arg)
            return
        with contextlib.suppress(RuntimeError):  # a closed loop: nobody is left to tell
            self._loop.call_soon_threadsafe(callback, arg)

    # -- run on the loop

    def _data_received(self, data: bytes) -> None:
        if self._closing:
            return
        if type(data) is not bytes:
            data = bytes(data)
        if self._paused is not None:
            self._paused.append(data)
            return
        self._protocol.data_received(data)

    def _device_lost(self, exc: Exception | None) -> None:
        self._closing = True
        self._report_lost(exc)

    def _report_lost(self, exc: Exception | None) -> None:
        if not self._lost_reported:
            self._lost_reported = True
            self._protocol.connection_lost(exc)

    # -- asyncio.Transport

    def write(self, data: bytes | bytearray | memoryview) -> None:
        if self._closing:
            return
        try:
            self._device.write(data if type(data) is bytes else bytes(data))
        except OSError as exc:
            self._closing = True
            self._loop.call_soon(self._report_lost, exc)

    def is_closing(self) -> bool:
        return self._closing

    def close(self) -> None:
        if self._closing:
            return
        self._closing = True
        try:
            self._device.disconnect()
        except Exception:
            log.debug("device %r failed to disconnect", self._device, exc_info=True)
        self._loop.call_soon(self._report_lost, None)

    def abort(self) -> None:
        self.close()

    def get_write_buffer_size(self) -> int:
        return 0

    def set_write_buffer_limits(self, high: int | None = None, low: int | None = None) -> None:
        pass  # writes never queue here

    def can_write_eof(self) -> bool:
        return False

    def pause_reading(self) -> None:
        if self._paused is None:
            self._paused = []

    def resume_reading(self) -> None:
        held, self._paused = self._paused, None
        for data in held or ():
            self._loop.call_soon(self._data_received, data)

    def is_reading(self) -> bool:
        return self._paused is None and not self._closing

    def get_protocol(self) -> asyncio.BaseProtocol:
        return self._protocol

    def set_protocol(self, protocol: asyncio.BaseProtocol) -> None:
        self._protocol = cast(asyncio.Protocol, protocol)

    def discard_input(self) -> None:
        """Ask the device to drop what it has not delivered yet, if it can."""
        discard = getattr(self._device, "discard_input", None)
        if discard is not None:
            discard()
