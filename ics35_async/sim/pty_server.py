"""Serve a simulated line on a pseudo-terminal, for any program that opens a serial port.

:class:`PtyServer` is the second driver of the line model (the first is
:class:`~.virtual_line.VirtualLine`'s in-process face): one thread reads what the
client writes to the pty (:mod:`.pty_port`), feeds it to the device with the
time it was read, and writes each chunk of the answer back when it is due.
Its command line is :mod:`.server_cli` (``python -m ics35_async.sim``,
``ics35 sim``).

Timing: in fast mode answers are written at once.  In real-time mode the
server waits for each chunk's wire time with sleep-then-spin
(:func:`.precise_wait.wait_until`) and then writes it to the master.  The pty adds
its own latency on top (see the figures in :mod:`ics35_async.sim`).

Line speed: the line runs at the speed the client set on the pty, so servos
at another rate stay silent, as on a real wire (``follow_host_baud=False``
keeps the line at its own rate instead).
"""

from __future__ import annotations

import collections
import contextlib
import heapq
import itertools
import os
import select
import time
from pathlib import Path

from .precise_wait import SPIN_MARGIN, lower_timer_slack, wait_until
from .pty_port import PtyPort
from .record import ReplayDevice
from .virtual_line import VirtualLine

_ABSENT_POLL = 0.02  # seconds between checks for a client while none has the pty open
_ABSENT_POLL_NO_INOTIFY = 0.002


class PtyServer:
    """Serves ``device`` (a :class:`VirtualLine` or :class:`ReplayDevice`) on a pty."""

    def __init__(
        self,
        device: VirtualLine | ReplayDevice,
        *,
        link: str | Path | None = None,
        follow_host_baud: bool = True,
        spin_margin: float = SPIN_MARGIN,
        keep_last: int = 0,
    ) -> None:
        self.device = device
        self.follow_host_baud = follow_host_baud
        self.spin_margin = spin_margin
        self.port = PtyPort(link)
        # Chunks to write: (perf_counter time due, order, bytes; None means "unplug now").
        self._heap: list[tuple[float, int, bytes | None]] = []
        self._order = itertools.count()
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        os.set_blocking(self._wake_w, False)
        self._stopping = False
        self.dropped_bytes = 0
        # The last reads and writes on the pty, (time.monotonic(), "read" or "wrote", bytes): the
        # library's drivers stamp with the same clock, so a client's log lines up with these.  A read
        # is stamped once done, a write as it starts: each stamp lies between the client's own.
        self.last: collections.deque[tuple[float, str, bytes]] = collections.deque(maxlen=keep_last)
        device.add_listener(lambda plugged: self.wake())

    @property
    def path(self) -> Path:
        """The path clients open (a symlink to the current pty)."""
        return self.port.path

    @property
    def pts_name(self) -> str | None:
        return self.port.pts_name

    def open(self) -> Path:
        """Create the pty and the link; returns the path clients should open."""
        if self.port.master is None and getattr(self.device, "plugged", True):
            self.port.open()
        return self.path

    def wake(self) -> None:
        with contextlib.suppress(BlockingIOError, OSError):
            os.write(self._wake_w, b"x")

    def stop(self) -> None:
        """Make :meth:`serve` return (safe from a signal handler or another thread)."""
        self._stopping = True
        self.wake()

    def close(self) -> None:
        self._heap.clear()
        self.port.dispose()
        for fd in (self._wake_r, self._wake_w):
            with contextlib.suppress(OSError):
                os.close(fd)

    # -- the loop

    def serve(self) -> None:
        """Answer the client until :meth:`stop`."""
        lower_timer_slack()
        self.open()
        port = self.port
        while not self._stopping:
            self._follow_plug_state()
            master = port.master
            timeout: float | None = None
            if self._heap:
                timeout = max(0.0, self._heap[0][0] - time.perf_counter() - self.spin_margin)
            watch = [self._wake_r]
            if master is not None:
                if port.client_present:
                    watch.append(master)
                else:
                    if port.opens is not None:
                        watch.append(port.opens)
                    absent_poll = _ABSENT_POLL if port.opens is not None else _ABSENT_POLL_NO_INOTIFY
                    timeout = absent_poll if timeout is None else min(timeout, absent_poll)
            readable, _, _ = select.select(watch, [], [], timeout)
            if self._wake_r in readable:
                with contextlib.suppress(BlockingIOError):
                    os.read(self._wake_r, 4096)
            if port.opens is not None and port.opens in readable:
                port.drain_opens()
            if master is not None and (master in readable or (not port.client_present and port.check_client())):
                self._read()
            self._deliver_due()

    def _read(self) -> None:
        data = self.port.read()
        if data is None:
            return
        if not data:
            self._heap.clear()  # the last client closed the pty: nobody to answer
            return
        if self.last.maxlen:
            self.last.append((time.monotonic(), "read", data))
        device = self.device
        baud = self.port.client_baudrate()
        if baud:
            # The client set its speed since we last looked: note it, then park
            # the pty at the idle speed again (see :mod:`.pty_port`).
            if self.follow_host_baud and isinstance(device, VirtualLine):
                device.baudrate = baud
            self.port.park_speed(only_if=baud)
        realtime = device.realtime
        chunks = device.process(data)
        if not getattr(device, "plugged", True):
            # A device pulled the line while handling these bytes (a servo that unplugs as it hears a
            # command): nothing it answered gets out, as nothing would through a pulled cable.
            self._follow_plug_state()
            return
        epoch = device.epoch
        for when, chunk in chunks:
            heapq.heappush(self._heap, (epoch + when if realtime else 0.0, next(self._order), chunk))
        if device.take_unplug_request() and isinstance(device, VirtualLine):
            line_free = epoch + device.line_free if realtime else 0.0
            heapq.heappush(self._heap, (line_free, next(self._order), None))

    def _deliver_due(self) -> None:
        heap = self._heap
        while heap and heap[0][0] - time.perf_counter() <= self.spin_margin:
            when, _, chunk = heapq.heappop(heap)
            wait_until(when, self.spin_margin)
            if chunk is None:
                device = self.device
                if isinstance(device, VirtualLine):
                    device.unplug(replug_after=device.replug_after)
                self._follow_plug_state()
                return
            if self.last.maxlen:  # stamped before the write: the client may have read it before we run again
                self.last.append((time.monotonic(), "wrote", chunk))
            # A client that does not read (or is gone) loses bytes.
            self.dropped_bytes += len(chunk) - self.port.write(chunk)

    def _follow_plug_state(self) -> None:
        plugged = getattr(self.device, "plugged", True)
        if plugged and self.port.master is None:
            self.port.open()
        elif not plugged and self.port.master is not None:
            self.port.close()
            self._heap.clear()
