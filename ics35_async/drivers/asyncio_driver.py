"""The asyncio driver: the engine fed from the event loop's I/O callbacks.

Its way of waiting: a reader on a tty's descriptor (``loop.add_reader``), a
``call_soon`` from an in-process device (or from the reader thread of a
port without a descriptor), and one timer that follows the engine's moving
deadline.  The callback that completes one transaction writes the next one
straight away, so a transaction costs no task switch and no extra loop
pass; one timer rather than one per transaction, since transactions
normally finish long before their deadline and deadlines usually only move
later.  A supervisor task reopens a lost port.

The armed time is kept here, never read back from the timer handle:
uvloop's ``call_at`` with a time already past returns a plain ``Handle``
without ``when()``.
"""

from __future__ import annotations

import asyncio
import contextlib
import threading
from typing import Any

from ..engine import LineEngine, State
from ..protocol import Command
from ..transports.device_port import DevicePort
from ..transports.opening import Port
from ..transports.tty_port import TtyPort
from ..transports.wire_device import WireDevice
from .burst import BurstRunner, open_runner
from .clock import now
from .core import INF, STALL, CallerRequest, LoopDriver, settle_future
from .fine_timer import FineTimer, open_fine_timer
from .settings import LineSettings

IDLE = State.IDLE


class AsyncioDriver(LoopDriver):
    """Runs one :class:`LineEngine` on the running asyncio loop."""

    name = "asyncio"

    def __init__(self, engine: LineEngine, port: str | WireDevice, settings: LineSettings) -> None:
        super().__init__(engine, port, settings)
        self._loop_thread = threading.get_ident()
        self._timer: asyncio.TimerHandle | asyncio.Handle | FineTimer | None = None
        self._fine: FineTimer | None = None  # deadlines to the microsecond where the system has it (see .fine_timer)
        self._second_look = -1.0  # the deadline whose expiry waits for one more I/O poll
        self._writing = False  # a writer waits for a tty to take what a partial write left
        self._reading = False  # the loop's reader watches the tty (not while a burst's executor reads it)
        self._reads = 0  # calls of _readable, and their count at the last look (see _look)
        self._reads_at_look = -1

    # ------------------------------------------------------------------ life cycle

    async def open(self) -> None:
        port = await self._open()
        self._fine = open_fine_timer()
        if self._fine is not None:
            self.loop.add_reader(self._fine.fd, self._fine_fired)
        self._connected(port)
        self._supervise()

    async def aclose(self) -> None:
        try:
            await self._drain()
        finally:
            await self._end_supervisor()
            self._drop_port()
            self._release_idle()
            self._close_fine_timer()

    @property
    def fine_deadlines(self) -> bool:
        return self._fine is not None

    def _close_fine_timer(self) -> None:
        fine, self._fine = self._fine, None
        if fine is not None:
            if self._timer is fine:
                self._timer = None
            with contextlib.suppress(RuntimeError):  # (the loop closed under an unclosed bus: nothing to remove)
                self.loop.remove_reader(fine.fd)
            fine.close()

    # ------------------------------------------------------------------ waiting on the port

    def _watch(self, port: Port) -> None:
        if isinstance(port, TtyPort):
            self.loop.add_reader(port.fd, self._readable)
            self._reading = True
            self.burst = open_runner(
                self.engine, port.fd, port.decode_marks, port.in_between, lambda: self.requested_at
            )
            if self.burst is not None:
                self.loop.add_reader(self.burst.done_fd, self._burst_readable)
        elif isinstance(port, DevicePort):  # (a port without a descriptor comes behind a reader thread)
            port.on_input = self._input_came
            if port.has_input:
                self._input_came()  # delivered while it opened

    def _unwatch(self, port: Port) -> None:
        self.cancel_timer()
        self._close_burst()
        if isinstance(port, TtyPort):
            self.loop.remove_reader(port.fd)
            self._reading = False
            if self._writing:
                self.loop.remove_writer(port.fd)
                self._writing = False
        elif isinstance(port, DevicePort):
            port.stop_telling()

    def _input_came(self) -> None:
        # Never read from inside the device's call: the engine may be in the middle of a write.
        if threading.get_ident() == self._loop_thread:
            self.loop.call_soon(self._readable)
        else:
            with contextlib.suppress(RuntimeError):  # the loop has ended: nobody is left to tell
                self.loop.call_soon_threadsafe(self._readable)

    def _readable(self) -> None:
        self._reads += 1
        port = self.port
        if port is None:
            return
        data = self._read(port)
        if data:
            self._step(port, data, now())
            if self.engine.deadline < self._waiting_until:  # a resync's quiet time, or the source's wake-up
                self._arm()

    def _write_blocked(self, port: Port) -> None:
        if not self._writing and isinstance(port, TtyPort):
            self._writing = True
            self.loop.add_writer(port.fd, self._writable)

    def _writable(self) -> None:
        port = self.port
        if not isinstance(port, TtyPort):
            return
        try:
            done = port.write_pending()
        except OSError as exc:
            self._lose(port, exc)
            return
        if done:
            self.loop.remove_writer(port.fd)
            self._writing = False

    # ------------------------------------------------------------------ the burst path

    def _start_burst(self, burst: BurstRunner) -> bool:
        port = self.port
        if not isinstance(port, TtyPort) or not burst.start(now()):
            return False
        if self._reading:  # (not after a burst that ran on into this one: see DriverCore._burst_done)
            self.loop.remove_reader(port.fd)  # the executor reads the port now
            self._reading = False
        self.cancel_timer()  # and keeps the deadlines
        return True

    def _burst_readable(self) -> None:
        burst = self.burst
        if burst is not None and burst.running:
            self._burst_done(burst)

    def _burst_over(self, port: Port | None) -> None:
        if isinstance(port, TtyPort) and not self._reading:
            self.loop.add_reader(port.fd, self._readable)  # a hang-up or what came after: the ordinary read sees it
            self._reading = True

    def _burst_closing(self, burst: BurstRunner) -> None:
        self.loop.remove_reader(burst.done_fd)

    # ------------------------------------------------------------------ time

    def _rewait(self) -> None:
        self._arm()

    def _arm(self) -> None:
        if self.bursting:  # the executor keeps the deadlines until the burst is fed
            return
        deadline = self.engine.deadline
        self._waiting_until = deadline
        fine = self._fine
        if fine is not None and now() < deadline < INF:
            if self._timer is not None and self._timer is not fine:
                self._timer.cancel()
            fine.arm(deadline)  # (moves it, if armed: one system call)
            self._timer = fine
            return
        if self._timer is not None:
            self._timer.cancel()
        if deadline <= now():
            # Due already (the engine gives a caller the line's next turn with a deadline of now): a timer would
            # come back a millisecond later on uvloop, whose loop time is whole milliseconds, and the line idle.
            self._timer = self.loop.call_soon(self._on_timer)
        else:
            self._timer = self.loop.call_at(deadline, self._on_timer)

    def _fine_fired(self) -> None:
        fine = self._fine
        if fine is not None and fine.fired() and self._timer is fine:
            self._on_timer()

    def cancel_timer(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        self._waiting_until = INF

    def _on_timer(self) -> None:
        self._timer = None
        self._waiting_until = INF
        engine = self.engine
        port = self.port
        if port is None:
            return
        t = now()
        deadline = engine.deadline
        if t < deadline:
            if deadline < INF:
                self._arm()
            return
        if self._second_look != deadline and engine.state is not IDLE:
            # The loop may have stalled past the deadline with the reply already read or
            # queued behind this callback: judge after one more I/O poll.  (Not for an idle
            # line's deadline, a paced stream's next slot: no reply can be waiting.)  Two
            # call_soon hops, not a timer: a timer comes back a millisecond later at best
            # (epoll's resolution), which every failed transaction of a paced stream would pay.
            # One hop is not enough: asyncio runs it before the I/O callbacks of the next poll,
            # uvloop before its next poll; the second hop runs after that poll's callbacks on
            # both.  It belongs to this deadline only: a new transaction gets its own first look.
            self._second_look = deadline
            self._waiting_until = t  # already passed: a new transaction's later deadline arms its own timer
            self._timer = self.loop.call_soon(self._hop)
            return
        if isinstance(port, DevicePort) and port.has_input:
            # An in-process device tells its input once, and its callback has run by the end of the second look:
            # input still waiting means an exception raised inside that callback (by a signal handler) dropped it.
            # Read now, or the reply would be judged missing, and every later one behind it.  (Only here: read at
            # the timer's first call, it would go before callbacks already queued, a stream's frame among them.)
            self._readable()
            if self._timer is None and engine.deadline < INF:
                self._arm()
            return
        self._step(port, b"", t)
        if self._timer is None and engine.deadline < INF:
            self._arm()

    def _hop(self) -> None:
        self._timer = self.loop.call_soon(self._on_timer)

    def _look(self) -> None:
        port = self.port
        if port is None or self.bursting:
            return
        if isinstance(port, DevicePort) and port.has_input:
            if self._reads == self._reads_at_look:
                self._readable()  # told once (an edge), and that callback dropped: nothing was read for a whole look
            self._reads_at_look = self._reads
        if self.engine.deadline + STALL < now():
            self._arm()  # the timer's callback (or its second look) dropped: the line would wait for ever

    # ------------------------------------------------------------------ the user's side

    def _new_request(self, command: Command[Any], priority: int, retries: int) -> tuple[CallerRequest, Any]:
        future = self.loop.create_future()
        return CallerRequest(command, priority, retries, future, settle_future), future
