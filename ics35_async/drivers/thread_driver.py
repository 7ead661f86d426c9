"""The thread driver: the engine runs in an I/O thread that blocks on the port; the event loop sees outcomes.

Its way of waiting: the I/O thread blocks on the port (``poll`` on a tty's
descriptor and a wake-up pipe, a blocking pyserial read, or an in-process
device's condition) up to the engine's deadline, feeds it what came, and
writes what it answers at once.  A stream's transactions therefore never
touch the event loop: the loop is told once per frame, and a request only
when it ends (``call_soon_threadsafe``).  That makes it the cheapest driver
for streaming beside a quiet event loop on the ordinary path, and the one for
ports the loop cannot wait on (Windows COM ports, ``rfc2217://``).  On the
ordinary path this thread needs the GIL after every system call, which a loop
or a thread kept busy with Python work holds almost entirely.  On a tty where
the compiled helper is built, a stream's transactions run in bursts as under
the asyncio driver (see .burst): this thread then waits on the burst's notices,
never on the port, and needs the GIL about once a cycle, which a busy thread
hands over at its switch interval but a busy event loop, which takes the GIL
back after each of its short system calls, hardly ever (measured in the
control-loop docs).  Only this thread
starts a burst: a caller's thread that puts the stream's transaction on the
wire writes it the ordinary way, as the I/O thread may be about to read the port.

Every engine call, from either thread, holds ``lock``.  Requests are put
on the wire by the caller's thread (no hand-over when the line is idle);
the I/O thread is woken only when its wait would outlast the engine's new
deadline.  A lost port ends its I/O thread; the supervisor task on the loop
reopens it with the bus's back-off and starts a new one.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import math
import os
import select
import threading
import time
from collections.abc import Callable
from typing import Any

from ..engine import LineEngine
from ..protocol import Command
from ..transports.device_port import DevicePort
from ..transports.opening import Port
from ..transports.pyserial_port import SerialPort
from ..transports.tty_port import TtyPort
from ..transports.wire_device import WireDevice
from .burst import BurstRunner, open_runner
from .clock import now
from .core import INF, CallerRequest, LoopDriver, settle_future
from .fine_timer import open_fine_timer
from .settings import LineSettings

log = logging.getLogger("ics35_async")

INLINE_PAUSE = 50e-6
"""Seconds the I/O thread sleeps when an in-process device answered inside ``write`` (it never waits
otherwise); about a position transaction's time on the wire at 1.25 Mbit/s."""


class _Run:
    """One I/O thread's stop signal: a reopen starts a new thread with a new one, so a thread
    that outlived its join can never serve the new port alongside its successor."""

    __slots__ = ("stopping",)

    def __init__(self) -> None:
        self.stopping = False

    def end(self) -> None:
        self.stopping = True


class _TtyWait:
    """Waits on a tty: ``poll`` on its descriptor and a wake-up pipe (and POLLOUT while a write is pending), and
    on a ``timerfd`` for the last millisecond before a deadline where the system has one (see .fine_timer)."""

    def __init__(self, port: TtyPort) -> None:
        self.port = port
        self.writable = False  # the tty can take what a partial write left
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        os.set_blocking(self._wake_w, False)
        self._poll = select.poll()
        self._poll.register(port.fd, select.POLLIN)
        self._poll.register(self._wake_r, select.POLLIN)
        self.fine = open_fine_timer()
        if self.fine is not None:
            self._poll.register(self.fine.fd, select.POLLIN)
        self._burst_poll: select.poll | None = None  # the burst's done_fd and the wake-up pipe (not the port)
        self._closed = False

    def wait(self, timeout: float | None) -> bytes:
        events = self._poll.poll(self._poll_ms(timeout))
        fd = self.port.fd
        if len(events) == 1 and events[0][1] == select.POLLIN and events[0][0] == fd:
            return self.port.read()  # the usual case: the reply, and nothing else
        data = b""
        for polled, mask in events:
            if polled == fd:
                if mask & select.POLLNVAL:
                    raise OSError(errno.EBADF, "the serial port was closed")
                if mask & select.POLLOUT:
                    self.writable = True
                if mask & (select.POLLIN | select.POLLHUP | select.POLLERR):
                    data = self.port.read()
            elif self.fine is not None and polled == self.fine.fd:
                self.fine.fired()  # (the thread looks at the clock itself: a deadline moved since is not due)
            else:
                with contextlib.suppress(BlockingIOError):
                    os.read(self._wake_r, 512)
        return data

    def _poll_ms(self, timeout: float | None) -> int | None:
        """What to give ``poll``, which counts whole milliseconds, for a wait of ``timeout`` seconds.  A deadline
        less than one away goes to the timer, which fires to the microsecond; one further is waited up to its
        last whole millisecond, and the thread, woken with nothing, looks again (so only a wait that reaches its
        deadline costs the timer's system call: a reply that comes in time costs none).  Without a timer the
        wait is rounded up, so a deadline is never judged early, up to a millisecond late."""
        if timeout is None:
            return None
        fine = self.fine
        if fine is None or timeout <= 0.0:
            return math.ceil(timeout * 1000)
        whole = math.floor(timeout * 1000)
        if whole >= 1:
            return whole
        fine.arm(now() + timeout)
        return 2  # (the timer wakes it first: this only bounds a wait it would not end)

    def watch_bursts(self, done_fd: int) -> None:
        """The port's burst runner tells on ``done_fd`` (see .burst): taken once, as the runner opens (read
        later, outside the lock, it could be a closed runner's)."""
        self._burst_poll = select.poll()
        self._burst_poll.register(done_fd, select.POLLIN)
        self._burst_poll.register(self._wake_r, select.POLLIN)

    def wait_for_burst(self) -> bool:
        """Wait for a running burst's notice or a wake-up, never on the port (the executor reads it
        meanwhile); True if the burst told (its notice or its end), False for a mere wake-up, after which
        the burst's records so far are not to be taken (the executor may not have begun them)."""
        assert self._burst_poll is not None
        told = False
        for polled, _ in self._burst_poll.poll():
            if polled == self._wake_r:
                with contextlib.suppress(BlockingIOError):
                    os.read(self._wake_r, 512)
            else:
                told = True
        return told

    def want_writable(self, want: bool) -> None:
        self._poll.modify(self.port.fd, select.POLLIN | select.POLLOUT if want else select.POLLIN)
        if want:
            self.wake()  # a wait already under way does not watch for POLLOUT yet

    def wake(self) -> None:  # under the driver's lock: never into a pipe that close() gave back
        if not self._closed:
            with contextlib.suppress(BlockingIOError):  # a full pipe: a wake-up is pending anyway
                os.write(self._wake_w, b"\0")

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            for fd in (self._wake_r, self._wake_w):
                with contextlib.suppress(OSError):
                    os.close(fd)
            if self.fine is not None:
                self.fine.close()


class _DeviceWait:
    """Waits on an in-process device: its answers come from whatever thread it runs on."""

    writable = False

    def __init__(self, port: DevicePort) -> None:
        self.port = port
        self._cond = threading.Condition()
        self._woken = False
        port.on_input = self.wake

    def wait(self, timeout: float | None) -> bytes:
        port = self.port
        # Looked at outside the lock: a device may hand input over as it is looked for, from a thread of its own
        # that this look waits for (the real-time simulator), and that hand-over wakes this waiter, taking the lock.
        # Input that comes after the look sets _woken first, under the lock: no wake-up is lost.
        ready = port.has_input
        if ready and timeout != 0:
            # The device answered inside write (a fast simulator): pause as a wire would.  A thread
            # that never blocks would keep the engine's lock from the loop's callers for good.
            time.sleep(INLINE_PAUSE)
        with self._cond:
            if not ready and not self._woken:
                self._cond.wait(timeout)
            self._woken = False
        return port.read()

    def wake(self) -> None:
        with self._cond:
            self._woken = True
            self._cond.notify()

    def want_writable(self, want: bool) -> None:
        pass

    def close(self) -> None:
        self.port.stop_telling()


class _SerialWait:
    """Waits on a pyserial port with no descriptor: by reading it (up to its short read timeout)."""

    writable = False

    def __init__(self, port: SerialPort) -> None:
        self.port = port

    def wait(self, timeout: float | None) -> bytes:
        return self.port.read(block=timeout is None or timeout > 0)  # a look, not a wait, at 0

    def wake(self) -> None:
        self.port.wake()

    def want_writable(self, want: bool) -> None:
        pass

    def close(self) -> None:
        pass


_Wait = _TtyWait | _DeviceWait | _SerialWait


class ThreadDriver(LoopDriver):
    """Runs one :class:`LineEngine` in an I/O thread, for callers on the running asyncio loop."""

    name = "thread"
    blocking_reads = True

    def __init__(self, engine: LineEngine, port: str | WireDevice, settings: LineSettings) -> None:
        super().__init__(engine, port, settings)
        self.lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._wait: _Wait | None = None
        self._running = _Run()
        self._write_error: tuple[Port, OSError] | None = None  # from a write in the caller's thread
        self._unsettled: set[CallerRequest] = set()  # outcomes handed to the loop's thread, not yet settled there
        self._unsettled_before: set[CallerRequest] = set()  # those of them the previous look found

    @property
    def fine_deadlines(self) -> bool:
        # (On a tty; an in-process device's condition and a pyserial port's read keep their own waits.)
        wait = self._wait
        return isinstance(wait, _TtyWait) and wait.fine is not None

    # ------------------------------------------------------------------ life cycle (the loop's side)

    async def open(self) -> None:
        port = await self._open()
        with self.lock:
            self._connected(port)
        self._supervise()

    async def _before_reconnect(self) -> None:
        await self._stop_thread()  # the lost port's thread has ended, or is about to

    async def _stop_thread(self) -> None:
        with self.lock:
            port, self.port = self.port, None
            if port is not None:
                self._unwatch(port)
        thread, self._thread = self._thread, None
        if thread is not None and thread is not threading.current_thread():
            # The thread closes its port on the way out (pyserial's RFC 2217 close sleeps 0.3 s).
            await self.loop.run_in_executor(None, thread.join, 2.0)
        elif port is not None:
            port.close()

    async def _release_port(self) -> None:
        await self._stop_thread()  # (the I/O thread waits on the port, and closes it as it ends)

    async def aclose(self) -> None:
        try:
            await self._drain()
        finally:  # even when cancelled: no I/O thread may keep the port
            await self._end_supervisor()
            await self._stop_thread()
            with self.lock:
                self._release_idle()

    # ------------------------------------------------------------------ waiting on the port (under the lock)

    def _watch(self, port: Port) -> None:
        wait: _Wait
        if isinstance(port, TtyPort):
            wait = _TtyWait(port)
            self.burst = open_runner(
                self.engine, port.fd, port.decode_marks, port.in_between, lambda: self.requested_at
            )
            if self.burst is not None:
                wait.watch_bursts(self.burst.done_fd)
        elif isinstance(port, DevicePort):
            wait = _DeviceWait(port)
        else:
            wait = _SerialWait(port)
        self._wait = wait
        run = self._running = _Run()
        self._waiting_until = INF  # the new thread reads the deadline afresh before it waits
        self._thread = threading.Thread(
            target=self._run, args=(port, wait, run), name=f"ics35 line {self.target}", daemon=True
        )
        self._thread.start()

    def _unwatch(self, port: Port) -> None:
        self._running.end()
        self._close_burst()
        if self._wait is not None:
            self._wait.wake()

    def _rewait(self) -> None:
        if self._wait is not None:
            self._wait.wake()  # its wait would outlast the new deadline

    def _write_blocked(self, port: Port) -> None:
        if self._wait is not None:
            self._wait.want_writable(True)

    def _write_failed(self, port: Port, exc: Exception) -> None:
        # The I/O thread takes the loss at its next turn: it is the one waiting on the port.
        log.debug("write to %s failed: %s", self.target, exc)
        error = exc if isinstance(exc, OSError) else OSError(errno.EIO, f"write failed: {exc!r}")
        self._write_error = (port, error)
        if self._wait is not None:
            self._wait.wake()

    # ------------------------------------------------------------------ the I/O thread

    def _run(self, port: Port, wait: _Wait, run: _Run) -> None:
        try:
            self._serve(port, wait, run)
        except Exception as exc:
            reconnect = isinstance(exc, OSError)
            if not reconnect:  # a bug: callers must not wait for a thread that is gone
                log.error("the I/O thread of %s failed", self.target, exc_info=exc)
                exc = OSError(errno.EIO, f"the line's I/O thread failed: {exc!r}")
            with self.lock:
                if not run.stopping:
                    self._lose(port, exc, reconnect=reconnect)
        finally:
            with self.lock:
                wait.close()
            port.close()  # after the engine knows: nothing is written to a closed port meanwhile

    def _serve(self, port: Port, wait: _Wait, run: _Run) -> None:
        engine, lock, step = self.engine, self.lock, self._step
        waiting = wait.wait
        while not run.stopping:
            burst = self.burst
            if burst is not None and burst.running and isinstance(wait, _TtyWait):
                told = wait.wait_for_burst()
                with lock:
                    if run.stopping:
                        return
                    if told and burst is self.burst and burst.running:
                        self._burst_done(burst)
                    self._waiting_until = engine.deadline
                continue
            until = self._waiting_until
            if until == INF:
                data = waiting(None)
            else:
                left = until - now()
                data = waiting(left if left > 0.0 else 0.0)
            with lock:
                if run.stopping:
                    return
                if self._write_error is not None:  # a write from the caller's thread failed
                    failed, error = self._write_error
                    self._write_error = None
                    if failed is port:  # not an error of a port already replaced
                        raise error
                if wait.writable:
                    wait.writable = False
                    if isinstance(port, TtyPort) and port.write_pending():
                        wait.want_writable(False)
                t = now()
                if not data and t >= engine.deadline:
                    # Bytes that came while this thread waited for the lock are not late.
                    data = waiting(0)
                step(port, data, t)
                self._waiting_until = engine.deadline

    # ------------------------------------------------------------------ the burst path (under the lock)

    def _start_burst(self, burst: BurstRunner) -> bool:
        # Only from this port's I/O thread, which then waits for the burst's notices instead of reading the
        # port: a burst started by a caller's thread could find the I/O thread about to read the port
        # beside the executor.  (The caller's transaction goes the ordinary way; the stream's next, put on
        # the wire by the I/O thread, starts the burst.)
        return self._thread is threading.current_thread() and isinstance(self.port, TtyPort) and burst.start(now())

    def _burst_over(self, port: Port | None) -> None:
        if threading.current_thread() is not self._thread and self._wait is not None:
            self._wait.wake()  # it waits for the burst's notices: the port is its own again

    # ------------------------------------------------------------------ the user's side

    def notify(self, callback: Callable[[], None]) -> None:
        """Run ``callback`` on the loop's thread (the stream's frames are made in the I/O thread)."""
        with contextlib.suppress(RuntimeError):  # the loop has ended: nobody is left to tell
            self.loop.call_soon_threadsafe(callback)

    def _deliver(self, request: CallerRequest) -> None:
        self._unsettled.add(request)  # (a set's add and discard are atomic: no lock between the threads)
        with contextlib.suppress(RuntimeError):
            self.loop.call_soon_threadsafe(self._settle, request)

    def _settle(self, request: CallerRequest) -> None:
        self._unsettled.discard(request)
        settle_future(request)

    def _look(self) -> None:
        # An outcome still unsettled a whole look later: its callback was dropped (see _supervisor_task).
        unsettled = set(self._unsettled)
        for request in unsettled & self._unsettled_before:
            self._settle(request)
        self._unsettled_before = unsettled - self._unsettled_before

    def _new_request(self, command: Command[Any], priority: int, retries: int) -> tuple[CallerRequest, Any]:
        future = self.loop.create_future()
        return CallerRequest(command, priority, retries, future, self._deliver), future
