"""Which driver runs a line: the one asked for by name, or the one that fits the running event loop.

Each driver module is imported only when a line opens with it, so importing
the library loads no event loop.  Every driver offers :class:`Driver`.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Protocol

from ..engine import LineEngine, RequestHandle
from ..errors import InvalidArgument
from ..protocol import Command
from ..transports.wire_device import WireDevice
from .settings import LineSettings

if TYPE_CHECKING:  # (the burst path's module loads with the driver that runs it)
    from .burst import BurstRunner

DRIVERS = ("auto", "asyncio", "thread", "anyio")


class Driver(Protocol):
    """What the bus asks of a driver."""

    name: str
    burst: BurstRunner | None  # the port open now runs streams on the burst path (see .burst)

    @property
    def fine_deadlines(self) -> bool:
        """Its deadlines fire to the microsecond (see .fine_timer), not on the loop's millisecond timers."""

    async def open(self) -> None: ...

    async def reopen(self, baudrate: int) -> None: ...

    async def aclose(self) -> None: ...

    def submit(self, command: Command[Any], priority: int, retries: int) -> RequestHandle[Any]: ...

    def check_caller(self) -> None:
        """InvalidArgument if the caller runs on another event loop than the one the bus opened in."""

    def call(self, step: Callable[[float], bytes | None]) -> None:
        """Run an engine call, given the time, where the engine may be touched; act on its answer."""

    def call_now(self, step: Callable[[float], bytes | None]) -> None:
        """As :meth:`call`, at once: what the step raises reaches the caller."""

    def notify(self, callback: Callable[[], None]) -> None:
        """Run ``callback`` on the caller's event loop (the engine may run elsewhere)."""

    async def wait_idle(self) -> None: ...


def running_asyncio() -> bool:
    # No asyncio imported: no asyncio loop can be running (and importing it costs ~40 ms).
    asyncio = sys.modules.get("asyncio")
    return asyncio is not None and asyncio.events._get_running_loop() is not None


def make_driver(kind: str, engine: LineEngine, port: str | WireDevice, settings: LineSettings) -> Driver:
    """The driver ``kind`` names (``"auto"``: asyncio under asyncio, anyio under trio)."""
    on_asyncio = running_asyncio()
    if kind == "auto":
        kind = "asyncio" if on_asyncio else "anyio"
    if kind == "asyncio" and not on_asyncio:
        raise InvalidArgument("driver='asyncio' needs a running asyncio loop; under trio use driver='anyio'")
    if kind == "anyio" or not on_asyncio:  # "thread" under trio: the anyio driver's reader thread
        from .anyio_driver import AnyioDriver

        return AnyioDriver(engine, port, settings)
    if kind == "thread":
        from .thread_driver import ThreadDriver

        return ThreadDriver(engine, port, settings)
    from .asyncio_driver import AsyncioDriver

    return AsyncioDriver(engine, port, settings)
