"""The bus: the public face of one ICS line.

A :class:`Bus` checks options, opens and closes the port, reconnects after a
loss, and hands requests and the stream to a
:class:`~ics35_async.engine.LineEngine` (every transaction rule) through a
driver that moves bytes and time between the engine and the event loop
(:mod:`ics35_async.drivers`).  Servos, streams and groups build on it.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import warnings
import weakref
from collections.abc import Awaitable, Callable, Generator, Iterable, Sequence
from typing import TYPE_CHECKING, Any, NoReturn, TypeVar, Unpack

from . import protocol
from .drivers.choice import DRIVERS, Driver, make_driver
from .drivers.clock import now
from .drivers.settings import RECONNECT_BACKOFF, LineSettings
from .eeprom import FACTORY_BAUD
from .engine import BackgroundSource, BusTiming, LineEngine, Priority, RequestHandle, State, TimingOverrides
from .engine.machine import ANOTHER_STREAM
from .errors import (
    BusClosed,
    ClosedByPortLoss,
    InvalidArgument,
    PortLost,
    PortNotFound,
    UnsafeOperation,
    error_text,
)
from .protocol import Command
from .stats import BusStats
from .tasks import despite_cancellation
from .transports.direction import check_direction
from .transports.wire_device import TRANSPORT_KINDS, WireDevice, port_argument
from .units import check_bool, check_ids, check_int, finite_number, said, unknown_options

if TYPE_CHECKING:
    from .servo import Device, Servo
    from .stream import Stream, StreamOptions

log = logging.getLogger("ics35_async")

T = TypeVar("T")

_URGENT, _LOW = int(Priority.URGENT), int(Priority.LOW)  # per request: no enum lookups on the way


class BusOptions(TimingOverrides, total=False):
    """The options of [`open_bus`][ics35_async.bus.open_bus] (and ``Bus``) beyond the port, every one optional.

    The [`BusTiming`][ics35_async.engine.timing.BusTiming] fields (``turnaround``,
    ``adapter_latency``, ``eeprom_write``, ``id_command``, ``quiet_time``, ``max_resync``,
    ``link_extra_max``; seconds each) are options too: each replaces that field of ``timing``.
    Annotate a dict of options with it and a type checker catches a misspelt name or a wrong type:

    ```python
    line: BusOptions = {"baudrate": 1250000, "adapter_latency": 0.002, "retries": 1}
    bus = await open_bus("/dev/ttyUSB0", **line)
    ```
    """

    baudrate: int
    """The line rate in bit/s: 115200 (the default), 625000 or 1250000 (the last two need the ICS USB
    adapter HS).  Changed later only by [`Bus.reopen`][ics35_async.bus.Bus.reopen]."""
    echo: bool
    """Whether the interface loops the host's bytes back, as Kondo's adapters do (default ``True``).
    The engine frames replies by it, so it is fixed for the bus's life."""
    driver: str
    """What runs the line (default ``"auto"``): ``"asyncio"`` (I/O callbacks, and the compiled burst path
    for streams where it is built; the default under asyncio), ``"anyio"`` (one bus task, and the compiled
    burst path too; the default under trio), ``"thread"`` (the engine in an I/O thread that blocks on the
    port: for ports the loop cannot wait on, and cheap for streaming beside a quiet event loop; on the
    compiled burst path where it is built, a stream beside a busy Python thread keeps its rate; beside a loop
    kept busy with Python work its stream all but stops, the thread waiting for the GIL; under trio, the anyio
    driver's reader thread)."""
    transport: str
    """How a serial port is read (default ``"auto"``): ``"auto"`` and ``"direct"`` read a port
    with a descriptor on it (``"direct"`` refuses one without), ``"thread"`` reads any serial port
    with blocking reads in a thread."""
    timing: BusTiming | None
    """The deadline and quiet-time allowances (default ``BusTiming()``); the timing fields given as
    options replace its fields."""
    retries: int
    """Retries (0..10, default 0) for idempotent requests that do not give their own; the bus's
    ``retries`` may be changed later."""
    reconnect: bool
    """Reopen a lost port with backoff (default ``False``: a loss closes the bus).  Meanwhile a
    request fails at once with ``PortLost`` and a stream pauses (it resumes once the port is back);
    to wait for the port, see [`Bus.state_change`][ics35_async.bus.Bus.state_change]."""
    reconnect_backoff: Sequence[float]
    """Seconds between reopen attempts after a loss, at least one (each more than 0, at most 60); the last repeats
    (default 0.05, then every 0.1)."""
    max_requests_between: int
    """At most this many requests (1..10000, default 16) run between two of a stream's transactions."""
    direction: str | None
    """``"rts"`` (or ``"rts-inverted"``): the serial driver raises (lowers) RTS while sending, for DIY
    half-duplex interfaces whose driver-enable pin is on RTS (default ``None``: RTS left alone; see
    ``ics35_async.transports.direction``)."""


# open_bus's names for what the ics35 commands' options of another name set (a program written after them).
CLI_OPTION_NAMES = {"timeout": "the reply allowance is adapter_latency, in seconds: the ics35 commands' --timeout"}


# The longest delay reconnect_backoff takes between two reopen attempts, in seconds.
_LONGEST_RECONNECT_DELAY = 60.0


def _reconnect_delay(delay: object) -> float:
    """One of ``reconnect_backoff``'s delays: a number of seconds, more than 0 (a 0, the last one repeating, would
    try the lost port again and again with no pause, holding a core for as long as the port stays away) and at
    most :data:`_LONGEST_RECONNECT_DELAY`."""
    number = finite_number(delay)
    if number is None or not 0 < number <= _LONGEST_RECONNECT_DELAY:
        raise InvalidArgument(
            f"reconnect_backoff's delays must each be a number of seconds more than 0 and at most "
            f"{_LONGEST_RECONNECT_DELAY:g} (with 0 a lost port is tried again with no pause), got {said(delay)}"
        )
    return number


class Bus:
    """One ICS line.  Create it with [`open_bus`][ics35_async.bus.open_bus], which documents every option.

    The options that shape the line (``port``, ``echo``, ``max_requests_between``,
    the serial ``settings``) are read-only: the engine and the driver take them when
    the bus is made.  ``retries`` (the default for requests that do not give their
    own) may be changed at any time.

    Raises:
        InvalidArgument: an option has the wrong type or is out of range (nothing is opened).
    """

    def __init__(self, port: str | os.PathLike[str] | WireDevice, **options: Unpack[BusOptions]) -> None:
        port = port_argument(port)  # here, not at the open: an empty port is refused before anything starts
        unknown = set(options) - BusOptions.__optional_keys__
        if unknown:
            raise InvalidArgument(unknown_options("open_bus", unknown, BusOptions.__optional_keys__, CLI_OPTION_NAMES))
        timing = options.get("timing")
        if timing is not None and not isinstance(timing, BusTiming):
            raise InvalidArgument(f"timing must be a BusTiming, not {type(timing).__name__}")
        timing_fields = TimingOverrides.__optional_keys__
        overrides: dict[str, Any] = {name: value for name, value in options.items() if name in timing_fields}
        if overrides:
            timing = dataclasses.replace(timing or BusTiming(), **overrides)
        backoff = options.get("reconnect_backoff", RECONNECT_BACKOFF)
        if isinstance(backoff, (str, bytes)) or not isinstance(backoff, Iterable):
            raise InvalidArgument(f"reconnect_backoff must be a sequence of seconds, not {backoff!r}")
        backoff = tuple(_reconnect_delay(d) for d in backoff)
        if not backoff:  # (its last delay repeats: an empty one has none to)
            raise InvalidArgument("reconnect_backoff must hold at least one delay in seconds (its last one repeats)")
        driver = options.get("driver", "auto")
        if driver not in DRIVERS:
            raise InvalidArgument(f"driver must be one of {', '.join(DRIVERS)}, not {driver!r}")
        transport = options.get("transport", "auto")
        if transport not in TRANSPORT_KINDS:
            raise InvalidArgument(f"transport must be one of {', '.join(TRANSPORT_KINDS)}, not {transport!r}")
        self._port = port
        self.driver_kind = driver
        """The driver asked for (``"auto"``, ``"asyncio"``, ``"thread"``, ``"anyio"``); ``driver``: the one running."""
        self.retries = protocol.check_retries(options.get("retries", 0))
        """Retries for idempotent requests that do not give their own (0..10); may be changed at any time."""
        self._settings = LineSettings(
            transport="thread" if driver == "thread" else transport,
            direction=check_direction(options.get("direction"), port),
            reconnect=check_bool("reconnect", options.get("reconnect", False)),
            reconnect_backoff=backoff,
        )
        self._engine = LineEngine(
            baudrate=protocol.check_baud(options.get("baudrate", FACTORY_BAUD)),
            echo=check_bool("echo", options.get("echo", True)),
            timing=timing or BusTiming(),
            max_requests_between=check_int("max_requests_between", options.get("max_requests_between", 16), 1, 10_000),
            port=port,
        )
        self._driver: Driver | None = None
        self._opening: Any = None  # an anyio.Event while open() runs: later callers wait for its outcome
        self._reopening = False
        self._state_event: Any = None  # an anyio.Event while someone waits in state_change()
        self._close_out: tuple[BackgroundSource, Callable[[], Awaitable[None]]] | None = None  # see attach_source
        self._closing_outs: set[Any] = set()  # streams' close-outs under way (see close_out_begins)
        self._leaving: BackgroundSource | None = None  # detached by its program, maybe at a burst's end (see reopen)
        self._closed_event: Any = None  # an anyio.Event, set once aclose() is done (see aclose)
        # Weakly: a driver's I/O thread holds the engine, and through it would keep a bus its program dropped
        # unclosed alive for ever (never collected, never warned of: see __del__).
        self._engine.on_state_change = _state_callback(weakref.ref(self))

    @property
    def port(self) -> str | WireDevice:
        """The port this bus opens: a path, a URL or a WireDevice (read-only)."""
        return self._port

    @property
    def echo(self) -> bool:
        """Whether the interface loops the host's bytes back (read-only: the engine frames replies by it)."""
        return self._engine.echo

    @property
    def max_requests_between(self) -> int:
        """At most this many requests run between two of a stream's transactions (read-only)."""
        return self._engine.max_requests_between

    @property
    def settings(self) -> LineSettings:
        """The serial settings the driver opens the port with: transport, direction, reconnection (read-only)."""
        return self._settings

    @property
    def baudrate(self) -> protocol.BaudRate:
        """The line rate in bit/s (a [`BaudRate`][ics35_async.eeprom.BaudRate], an int); changed only by
        :meth:`reopen`."""
        # (As a BaudRate again: a compiled engine keeps the plain int its attribute is declared as.)
        return protocol.check_baud(self._engine.baudrate)

    @property
    def timing(self) -> BusTiming:
        """The deadline and quiet-time allowances (a frozen :class:`BusTiming`)."""
        return self._engine.timing

    @property
    def reconnect(self) -> bool:
        """Whether a lost port is reopened with backoff (``open_bus(..., reconnect=True)``)."""
        return self._settings.reconnect

    @property
    def reconnect_backoff(self) -> tuple[float, ...]:
        """Seconds between reopen attempts after a loss; the last repeats."""
        return self._settings.reconnect_backoff

    @property
    def state(self) -> State:
        """The engine's state (``State.IDLE``, ``BUSY``, ``QUIET``, ``LOST``, ``CLOSED``...)."""
        return self._engine.state

    async def state_change(self) -> State:
        """Wait until the port is lost (``State.LOST`` while reconnecting, ``State.CLOSED`` without
        ``reconnect``) or comes back (``State.IDLE``), or the bus closes; return the state then.

        It wakes on a change, not per change: a loss and a reconnect that both happen while your
        code is not waiting are one wake that returns ``State.IDLE``; ``stats.reconnects`` counts
        every reconnection, and a stream's first frame after one has ``resumed`` set.

        A controller can watch its line with it beside its loop::

            while (state := await bus.state_change()) is not State.CLOSED:
                log.warning("line %s: %s", bus.port, state.value)

        Once the bus is closed, every call returns ``State.CLOSED`` at once: a loop must end there (one that
        waits for another state would go round for ever).
        """
        import anyio
        import anyio.lowlevel

        if self.state is State.CLOSED:
            # Still a checkpoint: a loop around this call must not keep the program's other tasks out.
            await anyio.lowlevel.checkpoint()
            return State.CLOSED
        if self._state_event is None:
            self._state_event = anyio.Event()
        await self._state_event.wait()
        return self.state

    def _state_changed(self, state: State) -> None:
        self.notify(self._wake_state_waiters)  # the engine may run in a driver's I/O thread

    def _wake_state_waiters(self) -> None:
        event, self._state_event = self._state_event, None
        if event is not None:
            event.set()

    def describe(self) -> dict[str, object]:
        """A snapshot of the line for a diagnostic dump: the port, the driver and what the engine is
        doing (:meth:`LineEngine.describe <ics35_async.engine.LineEngine.describe>`: the transaction on
        the wire, the queued requests, the next deadline), ``burst_path``: whether the port open now
        runs streams on the burst path (see ``ics35 --version -v``), and ``fine_deadlines``: whether the
        line's deadlines (a paced stream's slots, a reply given up on) fire to the microsecond, on a Linux
        ``timerfd``, rather than on the event loop's millisecond timers or ``poll``'s whole milliseconds (the
        asyncio driver on Linux, under asyncio and uvloop; the thread driver on a tty on Linux).  Plain values;
        safe to call at any time."""
        driver = self._driver
        bursts = driver is not None and driver.burst is not None
        fine = driver is not None and driver.fine_deadlines
        return {
            "port": str(self.port),
            "driver": self.driver,
            "burst_path": bursts,
            "fine_deadlines": fine,
            **self._engine.describe(now()),
        }

    @property
    def driver(self) -> str:
        """The driver running the line once open: ``"asyncio"``, ``"thread"`` or ``"anyio"``."""
        return self._driver.name if self._driver is not None else self.driver_kind

    # ------------------------------------------------------------------ opening / closing

    def __await__(self) -> Generator[Any, None, Bus]:
        return self.open().__await__()

    async def __aenter__(self) -> Bus:
        return await self.open()

    def __enter__(self) -> NoReturn:
        raise TypeError(
            "a bus is opened with `async with open_bus(...) as bus:` (or `bus = await open_bus(...)`, then"
            " `await bus.aclose()`); in code without an event loop, `ics35_async.blocking.open_bus`"
        )

    def __exit__(self, *exc: object) -> None:
        return None

    async def __aexit__(self, *exc: object) -> None:
        await self.aclose()

    async def open(self) -> Bus:
        """Open the line (idempotent); ``async with bus`` and ``await bus`` call it.

        Raises:
            BusClosed: the bus was closed, or an ``open()`` running at the same time failed.
            SerialPortError: the port cannot be opened ([`PortNotFound`][ics35_async.errors.PortNotFound],
                [`PortPermissionDenied`][ics35_async.errors.PortPermissionDenied],
                [`PortBusy`][ics35_async.errors.PortBusy], ...).  At once, ``reconnect=True`` or not: it rides
                out a port lost once the bus is open, not one missing (a ``PortNotFound`` then says so).
        """
        if self._engine.state is State.CLOSED or self._engine.state is State.DRAINING:
            raise self._engine.closed_error()
        if self._opening is not None:  # another open() is under way: share its outcome
            await self._opening.wait()
            if self._driver is None:
                raise BusClosed(f"opening {self.port} failed")
            return self
        if self._driver is not None:
            return self
        import anyio

        self._opening = anyio.Event()
        try:
            driver = make_driver(self.driver_kind, self._engine, self._port, self._settings)
            self._engine.debug = log.isEnabledFor(logging.DEBUG)
            try:
                await driver.open()
            except PortNotFound as exc:
                if (
                    not self._settings.reconnect or not exc.may_be_plugged_in
                ):  # (a misnamed port: no adapter to plug in)
                    raise
                # (one who asked for a lost port to be reopened expects a wait for a missing one too: it is not)
                raise exc.reworded(f"{error_text(exc)}; {MISSING_AS_IT_OPENS}") from exc
            self._driver = driver
        finally:
            self._opening.set()
            self._opening = None
        return self

    async def reopen(self, *, baudrate: int | None = None) -> None:
        """Close and reopen the port, optionally at a new line rate.

        For a baud-rate change: write the servos' EEPROM (``allow_baud_change=True``),
        power-cycle them, then ``await bus.reopen(baudrate=...)``.  The transaction on the wire
        finishes first; requests already queued and those submitted meanwhile wait and run after the
        reopen (at the new rate).  A reopen runs to its end even if
        its caller is cancelled meanwhile (the cancellation comes after it): cut off half-way,
        it would leave no port open.

        Args:
            baudrate: the new line rate in bit/s (``None``: the current one).

        Raises:
            InvalidArgument: a bad ``baudrate``, or a stream (or another reopen) is running.
            BusClosed: the bus is not open.
            PortLost: the port is lost (reconnecting), so it cannot be reopened now.
            SerialPortError: the port cannot be opened again (the bus is then closed).
        """
        new_baud = self.baudrate if baudrate is None else protocol.check_baud(baudrate)
        driver = self._driver
        if driver is not None:  # first, as for a request: a bus from another loop is that mistake, open or not
            driver.check_caller()
        if driver is None or not self.is_open:
            raise self._engine.closed_error()
        if self._engine.source is not None and self._engine.source is self._leaving and not self._reopening:
            # A stream closed during a burst is detached where the burst stops (see attach_source): stop it now
            # (one transaction at most), so that a reopen right after the close finds the stream gone.  Only
            # then: a stream still running would lose its burst to a reopen refused all the same.
            driver.call_now(lambda t: None)
        if self._engine.source is not None or self._reopening:
            raise InvalidArgument("stop the running stream (or the other reopen) before reopening the bus")
        self._reopening = True  # attach_source refuses from here on

        async def swap() -> None:
            try:
                await driver.reopen(new_baud)
            except BaseException as exc:
                if isinstance(exc, PortLost) and self._engine.state is not State.OFFLINE:
                    raise  # lost before it went offline: nothing was changed, the reconnect goes on
                if self._engine.state in (State.CLOSED, State.DRAINING):
                    raise  # a close came first: its drain goes on (the request on the wire finishes)
                reason = f"reopening {self.port} failed: {error_text(exc)}"
                driver.call(lambda t: self._engine.lost(reason, reconnect=False))
                raise

        try:
            if self._engine.state is State.LOST:
                raise PortLost(f"port {self.port} is lost; cannot reopen now")
            # To its end (the transaction on the wire first: requests queued meanwhile wait for the reopened
            # port): a reopen cut off half-way (a timeout around it) would leave no port open; a cancellation
            # meanwhile is raised once the line is open again.
            await despite_cancellation(swap, None)
        finally:
            self._reopening = False

    @property
    def is_open(self) -> bool:
        """True from a successful :meth:`open` until :meth:`aclose` or the port's loss (without reconnect)."""
        return self._driver is not None and self._engine.state not in (State.CLOSED, State.DRAINING)

    @property
    def port_lost(self) -> bool:
        """Whether losing its port closed the bus (opened without ``reconnect``, or it could not reopen): a
        program whose lines ended can tell the lost one from those its own close closed."""
        return not self.is_open and isinstance(self._not_open_error(), ClosedByPortLoss)

    def _not_open_error(self) -> BusClosed:
        """The error work on this bus meets while it is not open: why it closed (a ClosedByPortLoss if
        losing its port closed it), or how to open it."""
        if self._engine.state in (State.CLOSED, State.DRAINING):
            return self._engine.closed_error()
        return BusClosed("the bus is not open (use `async with open_bus(...) as bus`)")

    async def aclose(self) -> None:
        """Close the attached stream first (its ``on_close`` done on the open line: the program's block for
        the bus may end before the stream's), then fail queued requests with BusClosed, finish the one on
        the wire, release the port."""
        import anyio

        if self._closed_event is not None:
            # Another close is under way: it may be waiting for the stream's close-out, which closing the
            # line now would fail.  (Cancelled meanwhile, it still runs to its end.)
            await despite_cancellation(self._closed_event.wait, None)
            return
        self._closed_event = closed = anyio.Event()
        try:
            await self._close()
        finally:
            closed.set()

    def __del__(self, _warn: Callable[..., None] = warnings.warn) -> None:
        # As asyncio's transports do: a bus dropped open (`bus = await open_bus(...)`, never closed) is said
        # once it is collected.  Closing is async (a stream's on_close, the request on the wire), so it cannot
        # be done from here: its servos keep their last command.  (_warn is bound at definition: at
        # interpreter shutdown the module's globals may already be gone.)
        try:
            unclosed = self._driver is not None and self._closed_event is None and self.is_open
        except Exception:  # half-made (its __init__ raised), or the interpreter is shutting down
            return
        if unclosed:
            _warn(
                f"unclosed bus {self._port!s}: use `async with open_bus(...) as bus:` or `await bus.aclose()`"
                " (its servos keep their last command; a stream's on_close did not run)",
                ResourceWarning,
                source=self,
            )

    async def _close(self) -> None:
        close_out, self._close_out = self._close_out, None
        try:
            # Also when the stream has already detached: its own close may still be sending its close-out
            # (it returns once that is done), which the line closing now would fail.
            if close_out is not None:
                await close_out[1]()
            # And an earlier stream's, still sending with another stream attached since (one that begins
            # meanwhile too: each ends by leaving the set).
            while self._closing_outs:
                await despite_cancellation(next(iter(self._closing_outs)).wait, None)
        finally:  # (a cancellation raised once the close-out is done must not keep the port open)
            driver, self._driver = self._driver, None
            if driver is None:
                self._engine.close()
                self._wake_state_waiters()
            else:
                try:
                    await driver.aclose()
                finally:
                    self._wake_state_waiters()
                log.info("closed %s", self.port)

    # ------------------------------------------------------------------ submitting

    async def request(
        self, command: Command[T], *, priority: Priority = Priority.NORMAL, retries: int | None = None
    ) -> T:
        """Run one command and return its parsed reply.

        Args:
            command: an ``ics35_async.protocol`` command object.
            priority: where the request queues (a [`Priority`][ics35_async.engine.requests.Priority]).
            retries: retries after a failure (0..10; default: the bus's), for idempotent commands only.

        Raises:
            InvalidArgument: not a command, a bad ``priority`` or ``retries``, or a call from another
                event loop than the one the bus was opened in.
            ReplyError: no valid reply ([`ReplyTimeout`][ics35_async.errors.ReplyTimeout],
                [`PartialReply`][ics35_async.errors.PartialReply], [`BadReply`][ics35_async.errors.BadReply], ...).
            BusClosed: the bus is not open, or closed before the reply.
            PortLost: the port went away before the reply.
        """
        result: T = await self.submit(command, priority=priority, retries=retries)
        return result

    def submit(
        self, command: Command[T], *, priority: Priority = Priority.NORMAL, retries: int | None = None
    ) -> RequestHandle[T]:
        """Queue ``command`` and return a handle: awaited, its result.

        ``priority`` and ``retries`` are as in [`request`][ics35_async.bus.Bus.request]; awaiting the
        result raises what ``request`` raises.  On every driver the handle also answers as an asyncio
        future ([`RequestHandle`][ics35_async.engine.requests.RequestHandle]): ``done()``, ``cancelled()``,
        ``result()``, ``exception()`` and ``cancel()`` (it is one on the asyncio and thread drivers; under
        the anyio driver, trio included, these raise asyncio's ``CancelledError`` and ``InvalidStateError``
        as a future does).  A request cancelled while queued is never sent; one already on the wire finishes
        there (its reply read and dropped, no retry), so the line stays in step.  A caller that stops
        awaiting it (a timeout, a cancelled task) cancels it.

        Raises:
            InvalidArgument: not a command, a bad ``priority`` or ``retries``, or a call from another
                event loop than the one the bus was opened in.
            BusClosed: the bus is not open.
            PortLost: the port is lost and the bus reconnects (``reconnect``): a request fails at once until
                it is back (``state_change()`` waits for that).
        """
        if not isinstance(command, Command):
            raise InvalidArgument(f"not a command: {command!r}")
        level = check_int("priority", priority, _URGENT, _LOW)
        retries = self.retries if retries is None else protocol.check_retries(retries)
        driver = self._driver
        if driver is None:
            raise self._not_open_error()
        # Re-read per request (not per stream transaction) so enabling DEBUG takes effect.
        self._engine.debug = log.isEnabledFor(logging.DEBUG)
        return driver.submit(command, level, retries)

    def attach_source(
        self, source: BackgroundSource | None, *, close_out: Callable[[], Awaitable[None]] | None = None
    ) -> None:
        """Let ``source`` fill the line's idle time (one at a time); ``None`` detaches.  ``close_out``:
        awaited on the open line by :meth:`aclose` (a stream's ``on_close``; it returns at once when it has
        already run, and waits for it when it is under way).

        Raises:
            InvalidArgument: the bus is reopening.
            BusClosed: the bus is not open (a ClosedByPortLoss if losing its port closed it).
        """
        engine = self._engine
        if source is None:
            if engine.source is not None:
                self.detach_source(engine.source)
            return
        if self._reopening:
            raise InvalidArgument("the bus is reopening; start the stream afterwards")
        driver = self._driver
        if driver is not None:  # first, as for a request: a bus from another loop is that mistake, open or not
            driver.check_caller()
        if driver is None or not self.is_open:
            raise self._not_open_error()
        running = engine.source
        if running is not None and running is not source and running is not self._leaving:
            # Refused before the running burst is stopped: the stream that runs on would pay for it.
            raise InvalidArgument(ANOTHER_STREAM)
        # At once (a running burst stops first): a refusal (another stream runs: one closed during a burst is
        # detached where the burst stops) reaches the caller.
        driver.call_now(lambda t: engine.attach_source(source, t))
        self._close_out = None if close_out is None else (source, close_out)
        self._leaving = None

    def close_out_begins(self, done: Any) -> None:
        """A stream's close-out (its ``on_close`` commands) is under way, until ``done`` (an ``anyio.Event``)
        is set: :meth:`aclose` waits for it before it closes the line, attached or not (the program's next
        stream may have started meanwhile)."""
        self._closing_outs.add(done)

    def close_out_ends(self, done: Any) -> None:
        """The close-out :meth:`close_out_begins` was told of, with ``done``, has ended."""
        self._closing_outs.discard(done)

    def detach_source(self, source: BackgroundSource) -> None:
        """Stop ``source`` filling the line (no-op if it is not attached)."""
        engine = self._engine
        if self._driver is None:
            engine.detach_source(source)
        else:
            if engine.source is source:  # (one never attached, closed now, must not hide the one really leaving)
                self._leaving = source
            self._driver.call(lambda t: engine.detach_source(source))

    def kick(self) -> None:
        """Tell an idle bus that the background source has work again."""
        if self._driver is not None:
            self._driver.call(self._engine.kick)

    def notify(self, callback: Callable[[], None]) -> None:
        """Run ``callback`` on the caller's event loop: now, or soon when the engine runs in a thread."""
        if self._driver is None:
            callback()
        else:
            self._driver.notify(callback)

    async def wait_idle(self) -> None:
        """Wait until nothing is queued or on the wire."""
        if self._driver is not None:
            await self._driver.wait_idle()

    @property
    def stats(self) -> BusStats:
        """A snapshot of the line's counters: per bus and per ID, latency, what a slow link taught."""
        return self._engine.counters.snapshot(queued=self._engine.queue.count)

    def servo(self, servo_id: int) -> Servo:
        """A [`Servo`][ics35_async.servo.Servo] with ID ``servo_id`` (0..31) on this line; nothing is sent.

        Raises:
            InvalidArgument: ``servo_id`` is not an ID 0..31.
        """
        from .servo import Servo

        return Servo(self, servo_id)

    def device(self, device_id: int) -> Device:
        """A generic memory [`Device`][ics35_async.servo.Device] with ID ``device_id`` (0..31); nothing is sent.

        Raises:
            InvalidArgument: ``device_id`` is not an ID 0..31.
        """
        from .servo import Device

        return Device(self, device_id)

    def servos(self, ids: Iterable[int]) -> list[Servo]:
        """One :class:`Servo` per ID in ``ids``, in order.

        Raises:
            InvalidArgument: an ID is not 0..31 or ``ids`` is not an iterable of IDs.
        """
        return [self.servo(i) for i in check_ids("ids", ids)]

    def stream(self, ids: Iterable[int], *, rate_hz: float | None = None, **options: Unpack[StreamOptions]) -> Stream:
        """A position [`Stream`][ics35_async.stream.Stream] over ``ids``; use it as ``async with``.

        ``rate_hz`` (``None``: cycles back to back) and the options
        ([`StreamOptions`][ics35_async.stream.StreamOptions]: ``on_close``, ``on_resume``,
        ``offline_after``, ``probe_interval``, ``history``, ``watch``, ``offline``) are the stream's.

        Raises:
            InvalidArgument: an unknown option, a bad ID, a duplicate ID or an out-of-range value.
        """
        from .stream import DEPRECATED_STREAM_OPTIONS, STREAM_OPTIONS, Stream

        unknown = set(options) - STREAM_OPTIONS
        if unknown:
            # (rate_hz among them, though a parameter of its own: `rate=50` most likely meant it)
            suggested = STREAM_OPTIONS - DEPRECATED_STREAM_OPTIONS | {"rate_hz"}
            raise InvalidArgument(unknown_options("stream", unknown, suggested))
        return Stream(self, ids, rate_hz=rate_hz, **options)

    async def read_id(self, *, exactly_one_device: bool = False) -> int:
        """Read the ID of the only device on the line.

        With several devices on the line every one answers at once and the
        result is garbage, so the caller must confirm there is exactly one
        (``exactly_one_device=True``).

        Raises:
            UnsafeOperation: ``exactly_one_device`` is not ``True`` (nothing is sent).
            ReplyError: no valid reply.
        """
        if exactly_one_device is not True:
            raise UnsafeOperation(
                "read_id() needs exactly one device on the line (every device answers the ID command); "
                "pass exactly_one_device=True to confirm"
            )
        return await self.request(protocol.ReadId())

    async def write_id(self, new_id: int, *, exactly_one_device: bool = False) -> int:
        """Give the only device on the line the ID ``new_id`` (stored in its EEPROM).

        Every device on the line takes the new ID, so this is refused unless
        the caller confirms with ``exactly_one_device=True`` -- and then still
        unless exactly one device is proven on the line
        (:func:`~ics35_async.policies.write_lone_id`).

        Raises:
            InvalidArgument: ``new_id`` is not 0..31.
            UnsafeOperation: ``exactly_one_device`` is not ``True``, or not exactly one device
                answers (nothing is written).
            VerifyError: the device took the ID but does not answer at it.
            ReplyError: the device stops answering during the change.
        """
        new_id = protocol.check_id(new_id)
        if exactly_one_device is not True:
            raise UnsafeOperation(
                "write_id() renames EVERY device on the line; disconnect all but one and pass exactly_one_device=True"
            )
        from .policies import write_lone_id

        return (await write_lone_id(self, new_id)).new_id

    async def scan(self, ids: Iterable[int] = range(32), *, concurrency: int = 32) -> list[int]:
        """IDs that answer a harmless read (it moves nothing), in the order asked.

        When not even the echo of what was sent came back (an adapter not
        connected, a port with nothing on it), when no servo answered (their
        power, or servos set to another baud rate), or when an ID answered
        garbled (two servos sharing it), it logs a warning saying so on the
        ``ics35_async`` logger: the list cannot tell those apart.
        ``concurrency`` bounds how many probes are queued at once (the line
        still runs them one at a time), leaving room for other callers.  The
        whole scan over baud rates, with EEPROM cross-checks, is
        :func:`ics35_async.policies.scan`.

        Args:
            ids: the IDs to probe (0..31 each).
            concurrency: how many probes are queued at once.

        Raises:
            InvalidArgument: an ID is not 0..31.
            BusClosed: the bus is not open.
        """
        from .policies import probe_ids

        checked = check_ids("ids", ids)
        found = await probe_ids(self, checked, id_read_first=False, concurrency=concurrency)
        if found.silent and self.echo and checked:
            # An empty list either way: say which (a request says it in its error, a scan has none).
            log.warning(
                "scan of %s: nothing came back, not even the echo of what was sent: is the adapter connected "
                "and the line powered?",
                self.port,
            )
        elif found.garbled:
            # Left out of the list, which cannot say "two servos here": new servos all come with ID 0.
            log.warning(
                "scan of %s: %s answered garbled: two servos sharing one ID (new ones all have ID 0)? connect "
                "them one at a time and give each its own ID (`ics35 set-id`)",
                self.port,
                ", ".join(f"ID {i}" for i in sorted(found.garbled)),
            )
        elif checked and not found.answered:
            # Servos set to another rate are as silent as no servos: the program's fix is the rate it opened at.
            # (A line without echo gives no byte back either way: its silence is this case, not the adapter's.)
            others = " or ".join(
                f"baudrate={int(rate)}" for rate in reversed(protocol.BaudRate) if rate != self.baudrate
            )
            log.warning(
                "scan of %s: no servo answered at %d bit/s: check their power; servos set to another rate are "
                "silent at this one: open the bus at theirs (%s), or find them with `ics35 --port %s scan`, "
                "which tries every rate",
                self.port,
                int(self.baudrate),
                others,
                self.port,
            )
        return list(found.answered)

    def __repr__(self) -> str:
        return f"<Bus {self.port!s} {int(self.baudrate)} baud {self._engine.state.value}>"


def _state_callback(bus: weakref.ref[Bus]) -> Callable[[State], None]:
    def state_changed(state: State) -> None:
        alive = bus()
        if alive is not None:
            alive._state_changed(state)

    return state_changed


MISSING_AS_IT_OPENS = (
    "reconnecting rides out a port lost once the bus is open, not one missing as it opens: plug the adapter in, then"
    " open it again"
)
"""What a ``PortNotFound`` adds as a bus with ``reconnect`` opens (the configurator says it in its pages' words)."""


def open_bus(port: str | os.PathLike[str] | WireDevice, **options: Unpack[BusOptions]) -> Bus:
    """A :class:`Bus` on ``port``: use ``async with open_bus(...) as bus`` or ``bus = await open_bus(...)``.

    Nothing is opened until ``async with`` (or ``await``).  ``Bus(port, **options)`` is the same.

    Args:
        port: a serial device path (``/dev/ttyUSB0``, ``COM3``; a ``pathlib.Path`` too), a pyserial URL (``socket://``,
            ``rfc2217://``, ``loop://``), ``sim://?...`` for the built-in simulator, or a
            ``WireDevice`` (``ics35_async.transports``: a device in this process).
        **options: the line's options, each described in [`BusOptions`][ics35_async.bus.BusOptions]
            (``baudrate``, ``echo``, ``driver``, ``retries``, ``reconnect``, ... and the
            [`BusTiming`][ics35_async.engine.timing.BusTiming] fields such as ``adapter_latency``).

    Raises:
        InvalidArgument: an unknown option, or one with the wrong type or out of range (nothing is opened).
            Opening (``async with`` or ``await``) raises
            [`PortNotFound`][ics35_async.errors.PortNotFound],
            [`PortPermissionDenied`][ics35_async.errors.PortPermissionDenied],
            [`PortBusy`][ics35_async.errors.PortBusy] or another
            [`SerialPortError`][ics35_async.errors.SerialPortError]
            ([`ParityNotSupported`][ics35_async.errors.ParityNotSupported],
            [`DirectionControlNotSupported`][ics35_async.errors.DirectionControlNotSupported]).
            A port missing as the bus opens fails at once with ``reconnect=True`` too (it rides out a port lost
            once the bus is open): its ``PortNotFound`` then says so.
    """
    return Bus(port, **options)


__all__ = ["BackgroundSource", "Bus", "BusOptions", "BusTiming", "Priority", "RequestHandle", "State", "open_bus"]
