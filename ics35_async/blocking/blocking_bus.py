"""The blocking bus, servo and device: the async API's objects, driven from a loop thread."""

from __future__ import annotations

import os
import warnings
from collections.abc import Awaitable, Callable, Iterable
from typing import TYPE_CHECKING, ParamSpec, TypeVar, Unpack

from ..bus import Bus, BusOptions, Priority
from ..bus import open_bus as open_async_bus
from ..engine import State
from ..errors import InvalidArgument
from ..protocol import Command
from ..running import check_async_function, close_step
from ..servo import READ_DEGREES_FREES, Device, Servo
from ..stats import BusStats
from ..transports import WireDevice
from .blocking_stream import BlockingStream
from .forward import ReadThrough, Wrapper, blocking
from .loop_thread import LoopThread, awaited
from .owner import LoopOwner

if TYPE_CHECKING:
    from ..stream import StreamOptions

P = ParamSpec("P")
T = TypeVar("T")


class BlockingServo(Wrapper[Servo]):
    """:class:`~ics35_async.Servo` with blocking methods: ``servo.set_position(9000)`` returns the position.

    Made by ``bus.servo(servo_id)`` of a blocking ``bus``, around the async ``servo``; each method
    raises what the async one raises.
    """

    __slots__ = ("bus",)

    def __init__(self, bus: BlockingBus, servo: Servo) -> None:
        super().__init__(servo, bus._loop)
        self.bus = bus

    id = ReadThrough[int]("The servo's ID (0..31).")
    priority = ReadThrough[Priority]("The priority this servo's requests are queued at.")

    def __repr__(self) -> str:
        return f"<BlockingServo {self.id} on {self.bus!r}>"

    def known_position_read(self) -> bool | None:
        """Whether the servo answers ICS 3.6's position read, if already probed on this line (sends nothing)."""
        return self._async.known_position_read()

    set_position = blocking(Servo.set_position)
    free = blocking(Servo.free)
    set_degrees = blocking(Servo.set_degrees)
    set_radians = blocking(Servo.set_radians)
    free_and_read_degrees = blocking(Servo.free_and_read_degrees)

    def read_degrees(self) -> float:
        # Warned here, in the program's thread: the async method warns on the loop thread, inside this
        # package, where Python's default filters hide a DeprecationWarning, and a script would free its
        # servo (the joint goes limp) with nothing said.
        warnings.warn(READ_DEGREES_FREES, DeprecationWarning, stacklevel=2)
        return self._loop.call(self._async.free_and_read_degrees)

    read_degrees.__doc__ = Servo.read_degrees.__doc__

    has_position_read = blocking(Servo.has_position_read)
    read_position = blocking(Servo.read_position)
    read_position_once_more = blocking(Servo.read_position_once_more)
    read_position_degrees = blocking(Servo.read_position_degrees)
    read_stretch = blocking(Servo.read_stretch)
    read_speed = blocking(Servo.read_speed)
    read_current = blocking(Servo.read_current)
    read_temperature = blocking(Servo.read_temperature)
    write_stretch = blocking(Servo.write_stretch)
    write_speed = blocking(Servo.write_speed)
    write_current_limit = blocking(Servo.write_current_limit)
    write_temperature_limit = blocking(Servo.write_temperature_limit)
    read_eeprom = blocking(Servo.read_eeprom)
    write_eeprom = blocking(Servo.write_eeprom)


class BlockingDevice(Wrapper[Device]):
    """:class:`~ics35_async.Device` (a generic memory device) with blocking methods.

    Made by ``bus.device(device_id)`` of a blocking ``bus``, around the async ``device``.
    """

    __slots__ = ("bus",)

    def __init__(self, bus: BlockingBus, device: Device) -> None:
        super().__init__(device, bus._loop)
        self.bus = bus

    id = ReadThrough[int]("The device's ID (0..31).")

    def __repr__(self) -> str:
        return f"<BlockingDevice {self.id} on {self.bus!r}>"

    read_memory = blocking(Device.read_memory)
    write_memory = blocking(Device.write_memory)


class BlockingBus(LoopOwner[Bus]):
    """One ICS line for code without an event loop.  Create with :func:`open_bus`.

    The async :class:`~ics35_async.Bus` runs on an event loop in a background
    thread; each method call hands its work to that loop and waits for it.
    Errors are the library's own typed errors, raised in the calling thread.
    Several threads may share one bus (the bus serialises their requests).

    Args:
        bus: the async bus to open and run (``open_bus`` makes it).

    Raises:
        InvalidArgument: ``bus`` is not a [`Bus`][ics35_async.bus.Bus].
        SerialPortError: the port cannot be opened.
    """

    __slots__ = ()
    _usage = (
        "a blocking bus is used with `with blocking.open_bus(...) as bus:` (this one is closed now); in async"
        " code, `async with ics35_async.open_bus(...) as bus:`"
    )

    def __init__(self, bus: Bus) -> None:
        if not isinstance(bus, Bus):
            raise InvalidArgument(f"bus must be a Bus (from ics35_async.open_bus), not {type(bus).__name__}")
        super().__init__(bus, LoopThread(name=f"ics35 blocking bus {bus.port}"))
        self._own(self._loop, bus.aclose, f"blocking bus on {bus.port}")
        try:
            self._loop.call(bus.open)
        except BaseException:
            self.close()
            raise

    # ------------------------------------------------------------------ closing

    @close_step
    def close(self) -> None:
        """Close the bus (queued requests fail with BusClosed), release the port, end the loop thread.

        Idempotent.  A Ctrl-C while closing is raised once everything is released.
        """
        super().close()

    # ------------------------------------------------------------------ what the bus is

    @property
    def async_bus(self) -> Bus:
        """The async bus underneath, for :meth:`run` (use it only from code running on the bus's loop)."""
        return self._async

    port = ReadThrough[str | WireDevice]("The port the bus opened (read-only).")
    baudrate = ReadThrough[int]("The line rate in bit/s; changed only by ``reopen``.")
    echo = ReadThrough[bool]("Whether the interface loops the host's bytes back (read-only).")
    driver = ReadThrough[str]('The driver running the line: ``"asyncio"``, ``"thread"`` or ``"anyio"``.')
    state = ReadThrough[State](
        "The line engine's state (``State.IDLE``, ``BUSY``, ``QUIET``, ``LOST``, ``CLOSED``...)."
    )

    @property
    def is_open(self) -> bool:
        """True while the bus and its loop thread run."""
        return self._loop.is_running and self._async.is_open

    @property
    def stats(self) -> BusStats:
        """A snapshot of the line's counters, taken on the bus's loop (after the bus is closed: its
        final counters)."""
        return self._loop.read(_stats_of, self._async)

    def describe(self) -> dict[str, object]:
        """A snapshot of the line for a log (see [`Bus.describe`][ics35_async.bus.Bus.describe]), taken on the
        bus's loop."""
        return self._loop.read(_describe, self._async)

    def __repr__(self) -> str:
        return f"<BlockingBus {self._async!r}>"

    # ------------------------------------------------------------------ requests

    def request(self, command: Command[T], *, priority: Priority = Priority.NORMAL, retries: int | None = None) -> T:
        """Run one command (an ``ics35_async.protocol`` command object) and return its parsed reply.

        ``priority`` and ``retries`` are as in [`Bus.request`][ics35_async.bus.Bus.request].

        Raises:
            InvalidArgument: not a command, or a bad ``priority`` or ``retries``.
            ReplyError: no valid reply.
            BusClosed, PortLost: the bus is closed or its port is gone.
        """
        return self._loop.call(self._async.request, command, priority=priority, retries=retries)

    def run(self, fn: Callable[P, Awaitable[T]], /, *args: P.args, **kwargs: P.kwargs) -> T:
        """Await ``fn(*args, **kwargs)`` on the bus's event loop and return its result.

        For async helpers that take the async bus, e.g.
        ``bus.run(plan_eeprom_write, bus.async_bus, 1, {"speed": 90})``.

        Raises:
            InvalidArgument: ``fn`` is a coroutine (``bus.run(fn(*args))``: pass ``fn`` and its arguments) or not
                callable, or its call gave nothing to await (a plain ``def``: said once that call has returned).
        """
        check_async_function(fn, "bus.run", with_args=True)
        return self._loop.call(awaited, "bus.run", fn, *args, **kwargs)

    scan = blocking(Bus.scan)
    read_id = blocking(Bus.read_id)
    write_id = blocking(Bus.write_id)
    reopen = blocking(Bus.reopen)
    wait_idle = blocking(Bus.wait_idle)
    state_change = blocking(Bus.state_change)

    # ------------------------------------------------------------------ objects on the bus

    def servo(self, servo_id: int) -> BlockingServo:
        """A blocking servo with ID ``servo_id`` (0..31); nothing is sent.

        Raises:
            InvalidArgument: ``servo_id`` is not an ID 0..31.
        """
        # A Servo only checks its ID and keeps a reference: safe to make in this thread.
        return BlockingServo(self, self._async.servo(servo_id))

    def servos(self, ids: Iterable[int]) -> list[BlockingServo]:
        """One blocking servo per ID in ``ids``, in order.

        Raises:
            InvalidArgument: an ID is not 0..31.
        """
        return [BlockingServo(self, servo) for servo in self._async.servos(ids)]

    def device(self, device_id: int) -> BlockingDevice:
        """A blocking generic memory device with ID ``device_id`` (0..31); nothing is sent.

        Raises:
            InvalidArgument: ``device_id`` is not an ID 0..31.
        """
        return BlockingDevice(self, self._async.device(device_id))

    def stream(
        self, ids: Iterable[int], *, rate_hz: float | None = None, **options: Unpack[StreamOptions]
    ) -> BlockingStream:
        """A position stream over ``ids`` (see :meth:`Bus.stream`); use as ``with bus.stream(ids) as stream:``.

        ``rate_hz`` and the ``options`` ([`StreamOptions`][ics35_async.stream.StreamOptions]) are the stream's.

        Raises:
            InvalidArgument: an unknown option, a bad or duplicate ID or an out-of-range value.
        """
        stream = self._loop.call_sync(self._async.stream, ids, rate_hz=rate_hz, **options)
        return BlockingStream(stream, self._loop)


def _stats_of(bus: Bus) -> BusStats:
    return bus.stats


def _describe(bus: Bus) -> dict[str, object]:
    return bus.describe()


def open_bus(port: str | os.PathLike[str] | WireDevice, **options: Unpack[BusOptions]) -> BlockingBus:
    """Open a [`BlockingBus`][ics35_async.blocking.BlockingBus] on ``port``: use ``with open_bus(...) as bus:``.

    Takes what [`ics35_async.open_bus`][ics35_async.bus.open_bus] takes.  The bus is open when this
    returns; leaving the ``with`` block, an exception or Ctrl-C included, closes it and ends its
    loop thread.

    Args:
        port: a serial device path (a ``pathlib.Path`` too), a pyserial URL, ``sim://?...`` or a ``WireDevice``.
        **options: the line's options, each described in [`BusOptions`][ics35_async.bus.BusOptions].

    Raises:
        InvalidArgument: an unknown option, or one with the wrong type or out of range (nothing is opened).
        SerialPortError: the port cannot be opened: [`PortNotFound`][ics35_async.errors.PortNotFound],
            [`PortPermissionDenied`][ics35_async.errors.PortPermissionDenied],
            [`PortBusy`][ics35_async.errors.PortBusy] and the others.  A port missing as the bus opens fails
            at once with ``reconnect=True`` too (it rides out a port lost once the bus is open): its
            ``PortNotFound`` then says so.
    """
    return BlockingBus(open_async_bus(port, **options))
