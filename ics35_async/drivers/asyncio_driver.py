"""The asyncio driver's life cycle: open, reopen, close, reconnect after a loss.

The hot path is :class:`~.asyncio_line.AsyncioLine`; this class opens the
port through :func:`~ics35_async.transports.open_line` (any transport:
our direct one, pyserial-asyncio-fast, a reader thread for ports without a
file descriptor, an in-process device) and keeps a supervisor task that
reopens a lost port.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import logging
from collections.abc import Callable
from typing import Any, TypeVar

from ..engine import LineEngine, State
from ..errors import IcsError, SerialPortError
from ..protocol import Command
from ..transports import WireDevice, discard_input, open_line
from .asyncio_line import AsyncioLine, FutureRequest
from .clock import now
from .settings import LineSettings

log = logging.getLogger("ics35_async")

T = TypeVar("T")


async def _released(line: AsyncioLine, timeout: float = 1.0) -> None:
    """Wait until the transport has released the port (connection_lost), within ``timeout``.

    pyserial-asyncio(-fast) close the port from an executor: returning before
    that leaves it open -- a one-client TCP bridge (ser2net) then refuses the
    next connection, and a loop that ends at once never closes it at all.
    """
    with contextlib.suppress(TimeoutError):
        await asyncio.wait_for(asyncio.shield(line.closed), timeout)


class AsyncioDriver:
    """Runs one :class:`LineEngine` on the running asyncio loop."""

    name = "asyncio"

    def __init__(self, engine: LineEngine, port: str | WireDevice, settings: LineSettings) -> None:
        self.engine = engine
        self.port = port
        self.settings = settings
        self.loop = asyncio.get_running_loop()
        self.line: AsyncioLine | None = None
        self._supervisor: asyncio.Task[None] | None = None
        self._lost = asyncio.Event()

    async def open(self) -> None:
        await self._connect()
        self._supervisor = self.loop.create_task(self._supervise(), name=f"ics35 bus {self.port}")

    async def _connect(self) -> None:
        loop = self.loop
        _, line = await open_line(
            self.port,
            baudrate=self.engine.baudrate,
            protocol_factory=lambda: AsyncioLine(self.engine, loop, self._on_connection_lost, discard_input),
            transport=self.settings.transport,
            direction=self.settings.direction,
        )
        if line.closed.done():
            # Lost while opening (a bridge that hangs up at once), before this driver could hear of it.
            raise SerialPortError(errno.ECONNRESET, f"{self.port} closed the line as soon as it was opened")
        self.line = line
        log.info("opened %s at %d baud", self.port, self.engine.baudrate)
        line.pump(self.engine.connected(now()))

    async def reopen(self, baudrate: int) -> None:
        """Close and reopen the port (the engine holds requests meanwhile); only when idle."""
        if self.line is not None:
            self.line.stop_burst()
        self.engine.disconnected()
        line, self.line = self.line, None
        if line is not None:
            line.cancel_timer()
            if line.transport is not None:
                line.transport.close()
            await _released(line)
        self.engine.baudrate = baudrate
        await self._connect()  # a failure closes the line for good (the bus tells the engine)

    async def aclose(self) -> None:
        engine = self.engine
        line = self.line
        if line is not None:
            line.stop_burst()  # the engine hears the burst's bytes first (one transaction at most)
        engine.close()
        if engine.state is State.DRAINING and line is not None:
            waiter = self.loop.create_future()
            line.idle_waiters.append(waiter)
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(waiter, engine.drain_bound)
        engine.abort()
        if self._supervisor is not None:
            self._supervisor.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._supervisor
            self._supervisor = None
        self.line = None
        if line is not None:
            line.cancel_timer()
            line.release_idle_waiters()
            if line.transport is not None and not line.transport.is_closing():
                line.transport.close()
            await _released(line)

    # ------------------------------------------------------------------ losing the port

    def _on_connection_lost(self, line: AsyncioLine, exc: Exception | None) -> None:
        if line is not self.line:
            return
        self.line = None
        if line.transport is not None and not line.transport.is_closing():
            line.transport.close()
        engine = self.engine
        reason = f"port {self.port} lost: {exc}" if exc else f"port {self.port} closed"
        if engine.state not in (State.CLOSED, State.DRAINING):
            log.warning("%s", reason)
        engine.lost(reason, reconnect=self.settings.reconnect)
        line.release_idle_waiters()
        if engine.state is State.LOST:
            self._lost.set()

    async def _supervise(self) -> None:
        backoff = self.settings.reconnect_backoff
        while True:
            await self._lost.wait()
            self._lost.clear()
            attempt = 0
            while self.engine.state is State.LOST:
                await asyncio.sleep(backoff[min(attempt, len(backoff) - 1)])
                attempt += 1
                try:
                    await self._connect()
                except (OSError, IcsError) as exc:
                    log.debug("reconnect %d to %s failed: %s", attempt, self.port, exc)
                else:
                    self.engine.counters.reconnects += 1
                    log.info("reconnected to %s after %d attempt(s)", self.port, attempt)

    # ------------------------------------------------------------------ the user's side

    def submit(self, command: Command[T], priority: int, retries: int) -> asyncio.Future[T]:
        fut: asyncio.Future[T] = self.loop.create_future()
        request = FutureRequest(command, fut, priority, retries)
        line = self.line
        if line is not None and line.burst is not None and line.burst.running:
            line.burst.submit(request, now())  # it joins the queue where the burst stops
            return fut
        out = self.engine.submit(request, now())
        if out is not None and line is not None:
            line.pump(out)
        return fut

    def call(self, step: Callable[[float], bytes | None]) -> None:
        """Run an engine call (given the time): write what it answers and follow its deadline."""
        line = self.line
        if line is not None and line.burst is not None and line.burst.running:
            line.burst.hold(step)  # where the burst stops (it is mid-transaction then: nothing to write)
            return
        out = step(now())
        if line is not None:
            line.pump(out)

    def notify(self, callback: Callable[[], None]) -> None:
        """Run ``callback`` now: the engine runs on the caller's loop."""
        callback()

    async def wait_idle(self) -> None:
        while not self.engine.idle and self.line is not None:
            waiter: asyncio.Future[Any] = self.loop.create_future()
            self.line.idle_waiters.append(waiter)
            await waiter
