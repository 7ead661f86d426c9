"""What servos, streams and the policies need from an ICS line: a small protocol.

:class:`~ics35_async.bus.Bus` (from :func:`~ics35_async.open_bus`) is the
line the library makes; code above it depends on this protocol, not on the
bus, so the layers stay one-way and a test double or another driver fits.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from typing import Protocol, TypeVar, runtime_checkable

from .engine import BackgroundSource, Priority
from .protocol import Command
from .stats import BusStats

T = TypeVar("T")


@runtime_checkable
class Line(Protocol):
    """An ICS line: one transaction at a time, a background source (the stream), counters.

    Two methods are optional, called only where a line has them (a stream's close looks them up):
    ``close_out_begins(done)``, told when a stream's close-out (its ``on_close`` commands) begins, until
    ``done`` (an ``anyio.Event``) is set, and ``close_out_ends(done)`` when it has ended.  A line whose own
    close waits for the close-outs under way (as :class:`~ics35_async.bus.Bus` does) has them; without them a
    stream closes out all the same, and the line's close does not wait for it.
    """

    @property
    def baudrate(self) -> int:
        """The line rate in bit/s."""

    @property
    def echo(self) -> bool:
        """Whether the interface loops the host's bytes back."""

    @property
    def is_open(self) -> bool:
        """True while requests can be submitted."""

    @property
    def stats(self) -> BusStats:
        """A snapshot of the line's counters."""

    async def request(
        self, command: Command[T], *, priority: Priority = Priority.NORMAL, retries: int | None = None
    ) -> T:
        """Run ``command`` at ``priority`` (``retries``: after a failure) and return its reply (see ``Bus.request``)."""

    def submit(
        self, command: Command[T], *, priority: Priority = Priority.NORMAL, retries: int | None = None
    ) -> Awaitable[T]:
        """Queue ``command`` at ``priority`` (``retries``: as ``request``); an awaitable of its reply."""

    async def reopen(self, *, baudrate: int | None = None) -> None:
        """Close and reopen the port, optionally at a new rate ``baudrate`` (see ``Bus.reopen``)."""

    def attach_source(
        self, source: BackgroundSource | None, *, close_out: Callable[[], Awaitable[None]] | None = None
    ) -> None:
        """Let ``source`` (a stream) fill the line's idle time; ``None`` detaches.  ``close_out``: awaited
        on the open line when the line closes (a stream's ``on_close``)."""

    def detach_source(self, source: BackgroundSource) -> None:
        """Stop ``source`` filling the line."""

    def kick(self) -> None:
        """Tell an idle line that its source has work again."""

    def notify(self, callback: Callable[[], None]) -> None:
        """Run ``callback`` on the caller's event loop (a driver may run the engine in its own thread)."""
