"""The thread driver: the engine runs in an I/O thread that blocks on the port; the event loop sees outcomes.

The I/O thread waits on the port (``poll`` on a descriptor, a blocking
pyserial read, or an in-process device's queue) up to the engine's
deadline, feeds it what came, and writes what it answers at once.  A
stream's transactions therefore never touch the event loop: the loop is
told once per frame, and a request only when it ends
(``call_soon_threadsafe``).  That makes it the cheapest driver for
streaming, and the one for ports the loop cannot wait on (Windows COM
ports, ``rfc2217://``).

Every engine call, from either thread, holds ``lock``.  Requests are put
on the wire by the caller's thread (no hand-over when the line is idle);
the I/O thread is woken only when its wait would outlast the engine's new
deadline.  A lost port is reopened by the I/O thread itself, with the
bus's back-off.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import logging
import threading
from collections.abc import Callable
from typing import Any, TypeVar

from ..engine import LineEngine, Request, State
from ..errors import IcsError
from ..protocol import Command
from ..transports import WireDevice
from .clock import now
from .settings import LineSettings
from .thread_ports import ThreadPort, open_thread_port

log = logging.getLogger("ics35_async")

T = TypeVar("T")
INF = float("inf")


def _set_result(future: asyncio.Future[Any], value: Any) -> None:
    if not future.done():
        future.set_result(value)


def _set_exception(future: asyncio.Future[Any], error: BaseException) -> None:
    if not future.done():
        future.set_exception(error)


class ThreadRequest(Request):
    """A request whose outcome goes to an asyncio future on another thread's loop."""

    __slots__ = ("future", "loop")

    def __init__(
        self, command: Command[Any], future: asyncio.Future[Any], loop: asyncio.AbstractEventLoop, priority: int,
        retries: int,
    ) -> None:
        super().__init__(command, priority, retries)
        self.future = future
        self.loop = loop

    def abandoned(self) -> bool:
        return self.future.done()

    def resolve(self, value: Any) -> None:
        with contextlib.suppress(RuntimeError):  # the loop has ended: nobody is left to tell
            self.loop.call_soon_threadsafe(_set_result, self.future, value)

    def reject(self, error: IcsError) -> None:
        with contextlib.suppress(RuntimeError):
            self.loop.call_soon_threadsafe(_set_exception, self.future, error)


class _Run:
    """One I/O thread's stop signal: a reopen starts a new thread with a new one, so a thread
    that outlived its join can never serve the new port alongside its successor."""

    __slots__ = ("stop", "stopping")

    def __init__(self) -> None:
        self.stop = threading.Event()  # for the reconnect back-off's sleep
        self.stopping = False  # the same, as a plain flag for the hot loop

    def end(self) -> None:
        self.stopping = True
        self.stop.set()


class ThreadDriver:
    """Runs one :class:`LineEngine` in an I/O thread, for callers on the running asyncio loop."""

    name = "thread"

    def __init__(self, engine: LineEngine, port: str | WireDevice, settings: LineSettings) -> None:
        self.engine = engine
        self.port = port
        self.settings = settings
        self.loop = asyncio.get_running_loop()
        self.lock = threading.Lock()
        self._io: ThreadPort | None = None
        self._thread: threading.Thread | None = None
        self._running = _Run()
        self._waiting_until = INF  # when the I/O thread's current wait ends (it is woken for earlier)
        self._idle_waiters: list[asyncio.Future[None]] = []
        self._write_error: tuple[ThreadPort, OSError] | None = None  # from a write in the caller's thread

    # ------------------------------------------------------------------ life cycle (the loop's side)

    async def open(self) -> None:
        self._start(await self._open_port())

    async def _open_port(self) -> ThreadPort:
        opening = self.loop.run_in_executor(
            None, open_thread_port, self.port, self.engine.baudrate, self.settings.direction
        )
        try:
            return await opening
        except asyncio.CancelledError:

            def close_late(f: asyncio.Future[ThreadPort]) -> None:
                if not f.cancelled() and f.exception() is None:
                    f.result().close()

            opening.add_done_callback(close_late)
            raise

    def _start(self, io: ThreadPort) -> None:
        self._io = io
        run = self._running = _Run()
        log.info("opened %s at %d baud", self.port, self.engine.baudrate)
        with self.lock:
            self._write(io, self.engine.connected(now()))
            self._waiting_until = self.engine.deadline
        self._thread = threading.Thread(target=self._run, args=(io, run), name=f"ics35 line {self.port}", daemon=True)
        self._thread.start()

    async def _stop_thread(self) -> None:
        self._running.end()
        io, thread, self._thread = self._io, self._thread, None
        if io is not None:
            io.wake()
        if thread is not None and thread is not threading.current_thread():
            # The thread closes its port on the way out (pyserial's RFC 2217 close sleeps 0.3 s).
            await self.loop.run_in_executor(None, thread.join, 2.0)
        elif io is not None:
            io.close()
        self._io = None

    async def reopen(self, baudrate: int) -> None:
        """Close and reopen the port (the engine holds requests meanwhile); only when idle."""
        while True:
            await self.wait_idle()
            with self.lock:
                # A stray byte may have started a resync since the caller saw the line idle.
                if self.engine.state not in (State.BUSY, State.QUIET):
                    self.engine.disconnected()  # raises unless idle (a lost port, a closed bus)
                    break
        await self._stop_thread()
        self.engine.baudrate = baudrate
        self._start(await self._open_port())  # a failure closes the line for good (the bus tells the engine)

    async def aclose(self) -> None:
        engine = self.engine
        with self.lock:
            engine.close()
            draining = engine.state is State.DRAINING
            waiter: asyncio.Future[None] = self.loop.create_future()
            self._idle_waiters.append(waiter)
        try:
            if draining and self._thread is not None:
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(waiter, engine.drain_bound)
        finally:  # even when cancelled: no I/O thread may keep the port
            with self.lock:
                engine.abort()
            await self._stop_thread()
            self._release_idle()

    # ------------------------------------------------------------------ the I/O thread

    def _run(self, io: ThreadPort, run: _Run) -> None:
        while True:
            try:
                self._serve(io, run)
            except Exception as exc:
                if not isinstance(exc, OSError):  # a bug: callers must not wait for a thread that is gone
                    log.error("the I/O thread of %s failed", self.port, exc_info=exc)
                    self._lose(OSError(errno.EIO, f"the line's I/O thread failed: {exc!r}"), run, reconnect=False)
                    io.close()
                    return
                again = self._lose(exc, run)
                io.close()  # after the engine knows: nothing is written to a closed port meanwhile
                if not again:
                    return
                reopened = self._reconnect(run)
                if reopened is None:
                    return
                io = reopened
            else:
                io.close()
                return

    def _serve(self, io: ThreadPort, run: _Run) -> None:
        engine, lock = self.engine, self.lock
        wait, write = io.wait, io.write
        while not run.stopping:
            until = self._waiting_until
            if until == INF:
                data = wait(None)
            else:
                left = until - now()
                data = wait(left if left > 0.0 else 0.0)
            with lock:
                if run.stopping:
                    return
                if self._write_error is not None:  # a write from the caller's thread failed
                    failed, error = self._write_error
                    self._write_error = None
                    if failed is io:  # not an error of a port already replaced
                        raise error
                t = now()
                if not data and t >= engine.deadline:
                    # Bytes that came while this thread waited for the lock are not late.
                    data = wait(0)
                if data:
                    if io.bad:
                        engine.line_error(io.bad)
                        io.bad = 0
                    out = engine.receive(data, t)
                elif t >= engine.deadline:
                    out = engine.tick(t)
                    if engine.flush_input:
                        engine.flush_input = False
                        io.discard_input()
                else:
                    out = None
                if out is not None:
                    write(out)
                if self._idle_waiters and engine.idle:
                    self._release_idle()
                self._waiting_until = engine.deadline

    def _lose(self, exc: OSError, run: _Run, *, reconnect: bool = True) -> bool:
        """The port went away: tell the engine; True if it should be reopened."""
        with self.lock:
            engine = self.engine
            reason = f"port {self.port} lost: {exc}"
            if engine.state not in (State.CLOSED, State.DRAINING) and not run.stopping:
                log.warning("%s", reason)
            self._io = None  # callers write nothing more to it
            engine.lost(reason, reconnect=reconnect and self.settings.reconnect)
            self._release_idle()
            return engine.state is State.LOST and not run.stopping

    def _reconnect(self, run: _Run) -> ThreadPort | None:
        backoff = self.settings.reconnect_backoff
        attempt = 0
        while not run.stop.wait(backoff[min(attempt, len(backoff) - 1)]):
            attempt += 1
            try:
                io = open_thread_port(self.port, self.engine.baudrate, self.settings.direction)
            except (OSError, IcsError) as exc:
                log.debug("reconnect %d to %s failed: %s", attempt, self.port, exc)
                continue
            except Exception as exc:  # a bug (a device factory's): stop trying, and say so
                log.error("reopening %s failed", self.port, exc_info=exc)
                with self.lock:
                    self.engine.close()  # callers get BusClosed rather than "reconnecting" for ever
                    self._release_idle()
                return None
            with self.lock:
                if run.stopping or self.engine.state is not State.LOST:
                    io.close()
                    return None
                self._io = io
                self._write(io, self.engine.connected(now()))
                self.engine.counters.reconnects += 1
                self._waiting_until = self.engine.deadline
            log.info("reconnected to %s after %d attempt(s)", self.port, attempt)
            return io
        return None

    # ------------------------------------------------------------------ either thread, under the lock

    def _write(self, io: ThreadPort | None, out: bytes | None) -> None:
        if out is None or io is None:
            return
        try:
            io.write(out)
        except Exception as exc:  # the port is gone: the I/O thread raises it at its next turn
            log.debug("write to %s failed: %s", self.port, exc)
            error = exc if isinstance(exc, OSError) else OSError(errno.EIO, f"write failed: {exc!r}")
            self._write_error = (io, error)
            io.wake()

    def _after_call(self, out: bytes | None) -> None:
        io = self._io
        self._write(io, out)
        if io is not None and self.engine.deadline < self._waiting_until:
            io.wake()  # its wait would outlast the new deadline
        if self._idle_waiters and self.engine.idle:
            self._release_idle()

    def _release_idle(self) -> None:
        waiters, self._idle_waiters = self._idle_waiters, []
        for w in waiters:
            with contextlib.suppress(RuntimeError):
                self.loop.call_soon_threadsafe(_set_result, w, None)

    # ------------------------------------------------------------------ the user's side

    def submit(self, command: Command[T], priority: int, retries: int) -> asyncio.Future[T]:
        fut: asyncio.Future[T] = self.loop.create_future()
        request = ThreadRequest(command, fut, self.loop, priority, retries)
        with self.lock:
            self._after_call(self.engine.submit(request, now()))
        return fut

    def call(self, step: Callable[[float], bytes | None]) -> None:
        """Run an engine call (given the time) and act on what it answers."""
        with self.lock:
            self._after_call(step(now()))

    def notify(self, callback: Callable[[], None]) -> None:
        """Run ``callback`` on the loop's thread (the stream's frames are made in the I/O thread)."""
        with contextlib.suppress(RuntimeError):
            self.loop.call_soon_threadsafe(callback)

    async def wait_idle(self) -> None:
        while True:
            with self.lock:
                if self.engine.idle or self._thread is None:
                    return
                waiter: asyncio.Future[None] = self.loop.create_future()
                self._idle_waiters.append(waiter)
            await waiter
