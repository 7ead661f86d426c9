"""The asyncio driver: the engine fed from the event loop's I/O callbacks.

The hot path is ``data_received``: the callback that completes one
transaction writes the next one straight away, so a transaction costs no
task switch and no extra loop pass.  One timer follows the engine's moving
deadline instead of a timer per transaction: transactions normally finish
long before their deadline, and deadlines usually only move later.

The armed time is kept here, never read back from the timer handle: uvloop's
``call_at`` with a time already past returns a plain ``Handle`` without
``when()``.
"""

from __future__ import annotations

import asyncio
import logging
import os
from collections.abc import Callable
from typing import Any, TypeVar

from ..engine import LineEngine, Request, State
from ..errors import IcsError
from ..protocol import Command
from .burst import FAILED, BurstRunner, open_runner
from .clock import now

log = logging.getLogger("ics35_async")

T = TypeVar("T")
INF = float("inf")
IDLE = State.IDLE



class FutureRequest(Request):
    """A request whose outcome goes to an asyncio future."""

    __slots__ = ("future",)

    def __init__(self, command: Command[Any], future: asyncio.Future[Any], priority: int, retries: int) -> None:
        super().__init__(command, priority, retries)
        self.future = future

    def abandoned(self) -> bool:
        return self.future.done()

    def resolve(self, value: Any) -> None:
        if not self.future.done():
            self.future.set_result(value)

    def reject(self, error: IcsError) -> None:
        if not self.future.done():
            self.future.set_exception(error)


class AsyncioLine(asyncio.Protocol):
    """Moves bytes and time between one :class:`LineEngine` and an asyncio transport."""

    def __init__(
        self,
        engine: LineEngine,
        loop: asyncio.AbstractEventLoop,
        on_lost: Callable[[AsyncioLine, Exception | None], None],
        discard_input: Callable[[asyncio.BaseTransport], None],
    ) -> None:
        self.engine = engine
        self.loop = loop
        self.transport: asyncio.Transport | None = None
        self._on_lost = on_lost
        self._discard_input = discard_input
        self._timer: asyncio.TimerHandle | asyncio.Handle | None = None
        self._armed = INF  # when the timer fires (INF: no timer)
        self._second_look = -1.0  # the deadline whose expiry waits for one more I/O poll
        self.idle_waiters: list[asyncio.Future[None]] = []
        # Done once the transport has released the port (some close it from an executor, later).
        self.closed: asyncio.Future[None] = loop.create_future()
        # The burst path (see .burst), on ports with a descriptor when the executor is built.
        self.burst: BurstRunner | None = None

    # ------------------------------------------------------------------ from the transport

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]
        fd = getattr(transport, "burst_fd", None)
        if fd is not None:
            marks = getattr(transport, "marks", None)
            decode = marks.decode if marks is not None else None
            self.burst = open_runner(self.engine, fd, decode, transport.in_between)  # type: ignore[attr-defined]
            if self.burst is not None:
                self.loop.add_reader(self.burst.done_fd, self._burst_done)

    def data_received(self, data: bytes) -> None:
        engine = self.engine
        out = engine.receive(data, now())
        if out is not None:
            burst = self.burst
            if burst is not None and self._start_burst(burst):
                return
            try:
                self.transport.write(out)  # type: ignore[union-attr]
            except Exception as exc:  # the port vanished under us (or was already gone: None)
                self.write_failed(exc)
            if engine.deadline < self._armed:
                self._arm()
        elif engine.deadline < self._armed:  # a resync's quiet time, or the source's wake-up
            self._arm()
        if self.idle_waiters and engine.idle:
            self.release_idle_waiters()

    def line_error(self, count: int) -> None:
        """The transport saw ``count`` bytes arrive with parity or framing errors."""
        self.engine.line_error(count)

    def connection_lost(self, exc: Exception | None) -> None:
        self.cancel_timer()
        self.close_burst()
        if not self.closed.done():
            self.closed.set_result(None)
        self._on_lost(self, exc)

    # ------------------------------------------------------------------ to the transport

    def write(self, data: bytes) -> None:
        transport = self.transport
        if transport is None:
            return
        burst = self.burst
        if burst is not None and self._start_burst(burst):
            return
        try:
            transport.write(data)
        except Exception as exc:  # the port vanished under us
            self.write_failed(exc)

    def write_failed(self, exc: Exception) -> None:
        if self.transport is not None:
            self.transport = None
            self.connection_lost(exc)

    def pump(self, out: bytes | None) -> None:
        """After any engine call from outside the I/O callbacks: write, arm, wake waiters."""
        if out is not None:
            self.write(out)
        if self.engine.deadline < self._armed and not self.bursting:
            self._arm()
        if self.idle_waiters and self.engine.idle:
            self.release_idle_waiters()

    # ------------------------------------------------------------------ the burst path

    @property
    def bursting(self) -> bool:
        """A burst runs: the executor's thread has the port; the engine waits to be fed."""
        return self.burst is not None and self.burst.running

    def _start_burst(self, burst: BurstRunner) -> bool:
        """The engine just put a stream transaction on the wire: run it and the rest of the plan as a burst."""
        if not burst.start():
            return False
        self.transport.pause_reading()  # type: ignore[union-attr]  # the executor reads the port now
        self.cancel_timer()  # and keeps the deadlines
        return True

    def _burst_done(self, *, wait: bool = False) -> None:
        burst = self.burst
        if burst is None or not burst.running:
            return
        done, out = burst.finish(now, wait=wait)
        if not done:
            return
        if wait:
            self.close_burst()  # closing or reopening: the rest goes the ordinary way
        transport = self.transport
        if burst.status == FAILED:
            self.write_failed(OSError(burst.errno, os.strerror(burst.errno)))
            return
        if transport is None or transport.is_closing():
            return
        transport.resume_reading()  # a hang-up or what came after the burst: the ordinary read sees it
        self.pump(out)

    def stop_burst(self) -> None:
        """Stop a running burst at its next boundary, feed its bytes to the engine, now, and take
        the ordinary path from then on.

        Blocks for at most one transaction (closing or reopening the port): no await, so a
        cancelled close still leaves the engine knowing what was on the wire.
        """
        if self.bursting:
            self._burst_done(wait=True)
        else:
            self.close_burst()

    def close_burst(self) -> None:
        burst, self.burst = self.burst, None
        if burst is not None:
            self.loop.remove_reader(burst.done_fd)
            burst.close()

    # ------------------------------------------------------------------ time

    def _arm(self) -> None:
        if self.bursting:  # the executor keeps the deadlines until the burst is fed
            return
        if self._timer is not None:
            self._timer.cancel()
        deadline = self.engine.deadline
        self._armed = deadline
        self._timer = self.loop.call_at(deadline, self._on_timer)

    def cancel_timer(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        self._armed = INF

    def _on_timer(self) -> None:
        self._timer = None
        self._armed = INF
        engine = self.engine
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
            self._armed = t  # already passed: a new transaction's later deadline arms its own timer
            self._timer = self.loop.call_soon(self._hop)
            return
        out = engine.tick(t)
        if engine.flush_input:
            engine.flush_input = False
            if self.transport is not None:
                self._discard_input(self.transport)
        self.pump(out)
        if self._timer is None and engine.deadline < INF:
            self._arm()

    def _hop(self) -> None:
        self._timer = self.loop.call_soon(self._on_timer)

    # ------------------------------------------------------------------ waiting for quiet

    def release_idle_waiters(self) -> None:
        waiters, self.idle_waiters = self.idle_waiters, []
        for w in waiters:
            if not w.done():
                w.set_result(None)
