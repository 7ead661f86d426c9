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
    """An ICS line: one transaction at a time, a background source (the stream), counters."""

    @property
    def baudrate(self) -> int: ...

    @property
    def echo(self) -> bool: ...

    @property
    def is_open(self) -> bool: ...

    @property
    def stats(self) -> BusStats: ...

    async def request(
        self, command: Command[T], *, priority: Priority = Priority.NORMAL, retries: int | None = None
    ) -> T: ...

    def submit(
        self, command: Command[T], *, priority: Priority = Priority.NORMAL, retries: int | None = None
    ) -> Awaitable[T]: ...

    async def reopen(self, *, baudrate: int | None = None) -> None: ...

    def attach_source(self, source: BackgroundSource | None) -> None: ...

    def detach_source(self, source: BackgroundSource) -> None: ...

    def kick(self) -> None: ...

    def notify(self, callback: Callable[[], None]) -> None:
        """Run ``callback`` on the caller's event loop (a driver may run the engine in its own thread)."""
