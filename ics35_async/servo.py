"""The friendly per-servo and per-device API on top of a line (:class:`~ics35_async.bus.Bus`)."""

from __future__ import annotations

import warnings
import weakref
from collections.abc import Sequence

from . import protocol, units
from .eeprom import Eeprom
from .engine import Priority
from .errors import (
    BadReply,
    InvalidArgument,
    PartialReply,
    PositionReadUnsupported,
    ReplyError,
    ReplyTimeout,
    UnsafeOperation,
    VerifyError,
)
from .line import Line
from .protocol import Param

# What the deprecated read_degrees() says, at the program's line (the blocking servo says it too).
READ_DEGREES_FREES = (
    "Servo.read_degrees() turns the torque off; call free_and_read_degrees() for that, or "
    "read_position_degrees() to read without freeing (ICS 3.6 servos)"
)

# Per line, per ID: whether the servo answers ICS 3.6's position read (probed once, then remembered).
_POSITION_READS: weakref.WeakKeyDictionary[Line, dict[int, bool]] = weakref.WeakKeyDictionary()


def _check_bus(bus: object) -> Line:
    if not isinstance(bus, Line):
        raise InvalidArgument(f"bus must be a Bus (from open_bus), not {type(bus).__name__}")
    return bus


def check_pulse_limits(servo_id: int, position: object, low: int, high: int) -> int:
    """``position`` if it is a whole number within servo ``servo_id``'s EEPROM pulse limits ``low..high``.

    The servo clamps a target beyond them itself, but a tool that sends one (``ics35 move``, the
    configurator's jog) refuses it first, by this rule and in these words, rather than send what the
    servo will not do.

    Raises:
        InvalidArgument: ``position`` is not a whole number, or is outside ``low..high`` (nothing was sent).
    """
    number = units.whole_number(position)
    if number is None:
        raise InvalidArgument(f"position must be an int, not {type(position).__name__}")
    if not low <= number <= high:
        degrees = units.position_to_degrees  # (in degrees too: `ics35 move 1 60 --deg` names the angle asked)
        raise InvalidArgument(
            f"position {number} ({degrees(number):+.1f}°) is outside servo {servo_id}'s EEPROM pulse limits "
            f"{low}..{high} ({degrees(low):+.1f}..{degrees(high):+.1f}°); nothing was sent"
        )
    return number


class Servo:
    """One servo ID on a bus.  Every call is one transaction (two for verified writes).

    Positions are counts (1..16383, 7500 neutral, 3500..11500 is -135..+135
    degrees).  Each position command returns the position the servo reports.
    Parameter writes change RAM only; :meth:`write_eeprom` persists.  A
    method that turns the torque off says so in its name (``free...``);
    :meth:`read_position` leaves it alone (ICS 3.6 servos only).

    Every method raises the same errors, besides those it names: ``InvalidArgument``
    for a bad argument, before anything is sent; a ``ReplyError`` (``ReplyTimeout``,
    ``PartialReply``, ``EchoMismatch``, a ``BadReply``) when the servo does not answer
    or answers wrongly; ``BusClosed`` or ``PortLost`` when the line is closed or gone.
    Each method's "Raises" section lists them.

    Args:
        bus: the line the servo is on (a [`Bus`][ics35_async.bus.Bus] or another
            [`Line`][ics35_async.line.Line]); ``bus.servo(servo_id)`` is the usual way to make one.
        servo_id: the servo's ID, 0..31.
        priority: the [`Priority`][ics35_async.engine.requests.Priority] its requests queue at.

    Raises:
        InvalidArgument: ``bus`` is not a line, ``servo_id`` is not 0..31 or ``priority`` is not a priority.
    """

    __slots__ = ("_bus", "id", "priority")

    def __init__(self, bus: Line, servo_id: int, *, priority: Priority = Priority.NORMAL) -> None:
        self._bus = _check_bus(bus)
        self.id = protocol.check_id(servo_id)
        self.priority = Priority(units.check_int("priority", priority, Priority.URGENT, Priority.LOW))

    @property
    def bus(self) -> Line:
        """The line this servo is on."""
        return self._bus

    def __repr__(self) -> str:
        return f"<Servo {self.id} on {self._bus!r}>"

    async def set_position(self, position: int) -> int:
        """Move to ``position`` (1..16383); returns the position the servo reports now.

        Raises:
            InvalidArgument: ``position`` is not 1..16383.
            ReplyError, BusClosed, PortLost: no valid reply, or the line is closed or gone (see the class).
        """
        position = units.check_int("position", position, 1, protocol.POSITION_MAX)
        cmd = protocol.Position(self.id, position, baudrate=self._bus.baudrate)
        return await self._bus.request(cmd, priority=self.priority)

    async def free(self, *, priority: Priority | None = None) -> int:
        """Torque off (the servo goes limp); returns the current position (ICS 3.5's only position read).

        ``priority``: this request's priority (default: the servo's).

        Raises:
            InvalidArgument: ``priority`` is not a priority.
            ReplyError, BusClosed, PortLost: no valid reply, or the line is closed or gone (see the class).
        """
        cmd = protocol.Position(self.id, protocol.FREE, baudrate=self._bus.baudrate)
        return await self._bus.request(cmd, priority=self.priority if priority is None else priority)

    async def set_degrees(self, degrees: float) -> float:
        """Move to ``degrees`` (0 = neutral); returns the reported angle in degrees.

        Raises:
            InvalidArgument: the angle is outside -135..+135 degrees.
            ReplyError, BusClosed, PortLost: no valid reply, or the line is closed or gone (see the class).
        """
        return units.position_to_degrees(await self.set_position(units.degrees_to_position(degrees)))

    async def set_radians(self, radians: float) -> float:
        """Move to ``radians`` (0 is neutral); returns where the servo was when the command arrived, in radians.

        Raises:
            InvalidArgument: the angle is outside -135..+135 degrees.
            ReplyError, BusClosed, PortLost: no valid reply, or the line is closed or gone (see the class).
        """
        return units.position_to_radians(await self.set_position(units.radians_to_position(radians)))

    async def free_and_read_degrees(self) -> float:
        """Torque off (the servo goes limp) and return the angle in degrees: ICS 3.5's only position read.

        Raises:
            ReplyError, BusClosed, PortLost: no valid reply, or the line is closed or gone (see the class).
        """
        return units.position_to_degrees(await self.free())

    async def read_degrees(self) -> float:
        """Deprecated: it turns the torque off.  Use :meth:`free_and_read_degrees` (the same) or
        :meth:`read_position_degrees` (ICS 3.6: torque left alone).

        Raises:
            ReplyError, BusClosed, PortLost: no valid reply, or the line is closed or gone (see the class).
        """
        warnings.warn(READ_DEGREES_FREES, DeprecationWarning, stacklevel=2)
        return await self.free_and_read_degrees()

    # ------------------------------------------------------------------ ICS 3.6 position read

    def known_position_read(self) -> bool | None:
        """Whether this servo answers ICS 3.6's position read, if already probed on this line; else ``None``.

        A plain method, not a coroutine: it sends nothing, so it is called without ``await`` (awaiting its
        answer raises ``TypeError: object NoneType can't be used in 'await' expression``, or ``bool``).
        """
        return _POSITION_READS.get(self._bus, {}).get(self.id)

    async def has_position_read(self, *, silent_before: bool = False) -> bool:
        """Whether the servo speaks ICS 3.6 (answers the position read); probed once per line, then remembered.

        Nothing it sends moves or frees the servo.  A servo silent to the
        read but answering a parameter read speaks ICS 3.5 (``False``); a
        servo silent to both raises :class:`ReplyTimeout` (and is probed
        again next time).

        Args:
            silent_before: the caller's own read of this servo (a whole reply allowance, or a scan's probe
                with its second looks: see :func:`~ics35_async.policies.probe_ids`) has just gone
                unanswered: a silent probe then raises ReplyTimeout at once, the parameter read that tells
                ICS 3.5 from no servo left out (two silences in a row already say nothing answers; that read,
                and the guard read before it, would each wait a whole allowance more).

        Raises:
            ReplyError, BusClosed, PortLost: no valid reply, or the line is closed or gone (see the class).
        """
        known = self.known_position_read()
        if known is None:
            await self._probe_position(silent_before=silent_before)
            known = self.known_position_read()
        return bool(known)

    async def read_position(self) -> int:
        """The present position in counts, torque and target left alone (ICS 3.6's position read).

        ICS 3.5 reads a position only with :meth:`free`.

        Raises:
            PositionReadUnsupported: the servo speaks ICS 3.5 (nothing was freed).
            ReplyError, BusClosed, PortLost: no valid reply, or the line is closed or gone (see the class).
        """
        known = self.known_position_read()
        if known is None:
            position = await self._probe_position()
            if position is not None:
                return position
            known = self.known_position_read()
        if not known:
            raise PositionReadUnsupported(
                f"servo {self.id} speaks ICS 3.5: it has no position read (it stays silent to 0xA0|id, 0x05); "
                "ICS 3.5 reads a position only with the free command, which turns the torque off (Servo.free)",
                servo_id=self.id,
            )
        return await self._bus.request(protocol.ReadPosition(self.id), priority=self.priority)

    async def read_position_degrees(self) -> float:
        """:meth:`read_position` in degrees (0 = neutral): the torque is left alone.

        Raises:
            PositionReadUnsupported: the servo speaks ICS 3.5 (nothing was freed).
            ReplyError, BusClosed, PortLost: no valid reply, or the line is closed or gone (see the class).
        """
        return units.position_to_degrees(await self.read_position())

    async def read_position_once_more(self) -> int | None:
        """The position read once more, with the whole reply allowance and no retry: what to ask before a free
        command to a servo :meth:`has_position_read` took for ICS 3.5.  Its position if it answers (ICS 3.6 after
        all, remembered as such on this line), ``None`` if silent (ICS 3.5, or nobody there).  Moves and frees
        nothing.

        The probe that tells the protocols apart waits only as long as this line's answers have taken, and takes
        two silences around an answered parameter read for ICS 3.5: an ICS 3.6 servo whose two replies were lost
        (a lossy line) or came after those short waits (a TCP bridge, an adapter's latency timer) is taken for
        one, and the free command reaches a servo whose reply is lost.  Costs one reply allowance where the
        servo is silent.

        Raises:
            ReplyError: a garbled answer (something is there: free nothing on it).
            BusClosed, PortLost: the line is closed or gone.
        """
        try:
            position = await self._bus.request(
                protocol.SecondLookReadPosition(self.id), priority=self.priority, retries=0
            )
        except ReplyTimeout:
            return None
        _POSITION_READS.setdefault(self._bus, {})[self.id] = True
        return position

    async def _probe_position(self, *, silent_before: bool = False) -> int | None:
        """Probe the position read: the position (ICS 3.6), or ``None`` (ICS 3.5); the answer is remembered.
        ``silent_before``: see :meth:`has_position_read`."""
        # A probe's short wait (Timing.PROBE) is what makes silence cheap and keeps it from teaching
        # the link to wait longer. Silence twice, with a parameter read answered in between (so the
        # servo is there), is ICS 3.5: one lost reply of an ICS 3.6 servo does not decide it.
        silences = 0
        garbled: ReplyError | None = None
        for _ in range(4):
            try:
                position = await self._bus.request(
                    protocol.ProbeReadPosition(self.id), priority=self.priority, retries=0
                )
            except ReplyTimeout:
                silences += 1
                if silences == 1:
                    if silent_before:
                        raise
                    await self._read(Param.STRETCH)  # silent too: no servo here, and nothing remembered
                    continue
                _POSITION_READS.setdefault(self._bus, {})[self.id] = False
                return None
            except (PartialReply, BadReply) as exc:
                garbled = exc  # something answered: try again
                continue
            _POSITION_READS.setdefault(self._bus, {})[self.id] = True
            return position
        assert garbled is not None
        raise garbled

    async def _read(self, param: Param) -> int:
        return await self._bus.request(protocol.ReadParam(self.id, param), priority=self.priority)

    async def _write(self, param: Param, value: int) -> int:
        return await self._bus.request(protocol.WriteParam(self.id, param, value), priority=self.priority)

    async def read_stretch(self) -> int:
        """The stretch (holding gain, 1..127) from RAM.

        Raises:
            ReplyError, BusClosed, PortLost: no valid reply, or the line is closed or gone (see the class).
        """
        return await self._read(Param.STRETCH)

    async def read_speed(self) -> int:
        """The speed parameter (1..127) from RAM.

        Raises:
            ReplyError, BusClosed, PortLost: no valid reply, or the line is closed or gone (see the class).
        """
        return await self._read(Param.SPEED)

    async def read_current(self) -> int:
        """Raw current 0..127: bits 0-5 magnitude, bit 6 direction (see ``units.current_from_raw``).

        Raises:
            ReplyError, BusClosed, PortLost: no valid reply, or the line is closed or gone (see the class).
        """
        return await self._read(Param.CURRENT)

    async def read_temperature(self) -> int:
        """Raw temperature 1..127; SMALLER is HOTTER (see ``units.temperature_to_celsius``).

        Raises:
            ReplyError, BusClosed, PortLost: no valid reply, or the line is closed or gone (see the class).
        """
        return await self._read(Param.TEMPERATURE)

    async def write_stretch(self, value: int) -> int:
        """Set the holding gain (stretch) to ``value``, 1..127 (RAM only); returns the value the servo echoes.

        Raises:
            InvalidArgument: ``value`` is not 1..127.
            ReplyError, BusClosed, PortLost: no valid reply, or the line is closed or gone (see the class).
        """
        return await self._write(Param.STRETCH, value)

    async def write_speed(self, value: int) -> int:
        """Set the speed to ``value``, 1..127 (RAM only); returns the value the servo echoes.

        Raises:
            InvalidArgument: ``value`` is not 1..127.
            ReplyError, BusClosed, PortLost: no valid reply, or the line is closed or gone (see the class).
        """
        return await self._write(Param.SPEED, value)

    async def write_current_limit(self, value: int) -> int:
        """Set the current limit to ``value``, 1..63 (RAM only); returns the value the servo echoes.

        Raises:
            InvalidArgument: ``value`` is not 1..63.
            ReplyError, BusClosed, PortLost: no valid reply, or the line is closed or gone (see the class).
        """
        return await self._write(Param.CURRENT, value)

    async def write_temperature_limit(self, value: int) -> int:
        """Set the temperature limit to ``value``, 1..127 (RAM only; smaller is hotter); returns the value echoed.

        Raises:
            InvalidArgument: ``value`` is not 1..127.
            ReplyError, BusClosed, PortLost: no valid reply, or the line is closed or gone (see the class).
        """
        return await self._write(Param.TEMPERATURE, value)

    async def read_eeprom(self) -> Eeprom:
        """Read the servo's 64-byte EEPROM, decoded.

        Raises:
            MalformedEeprom: the image has a bad length or a byte that is not a nibble.
            ReplyError, BusClosed, PortLost: no valid reply, or the line is closed or gone (see the class).
        """
        return await self._bus.request(protocol.ReadEeprom(self.id), priority=self.priority)

    async def write_eeprom(
        self,
        eeprom: Eeprom,
        *,
        verify: bool = True,
        allow_baud_change: bool = False,
        allow_id_change: bool = False,
    ) -> None:
        """Write the whole 64-byte EEPROM (persists) after checking it against the servo's.

        The servo's current image is read first: the write is refused if it
        would change the factory calibration bytes, the baud rate (unless
        ``allow_baud_change``: the servo then only talks at the new rate) or
        the ID (unless ``allow_id_change``).  With ``verify`` the image is
        read back and compared; not after a baud or ID change, since the
        servo may already answer only at its new rate or ID.  A new baud rate
        takes effect at the servo's next power-up: then ``bus.reopen(baudrate=...)``.

        Args:
            eeprom: the whole new image, e.g. ``(await servo.read_eeprom()).replace(speed=90)``.
            verify: read the image back and compare (default ``True``).
            allow_baud_change: allow an image that changes the servo's baud rate.
            allow_id_change: allow an image that changes the servo's ID.

        Raises:
            InvalidArgument: ``eeprom`` is not an ``Eeprom``, a flag is not a bool, or a field it changes is
                outside the reference's range (as :meth:`Eeprom.replace` checks it; nothing is written).
            UnsafeOperation: the image changes the calibration bytes, or the baud rate or ID without its
                ``allow_...`` flag (nothing is written).
            VerifyError: the image read back differs from the one written.
            MalformedEeprom: the servo's current image has a bad length or a byte that is not a nibble.
            ReplyError, BusClosed, PortLost: no valid reply, or the line is closed or gone (see the class).
        """
        if not isinstance(eeprom, Eeprom):
            raise InvalidArgument(f"eeprom must be an Eeprom, not {type(eeprom).__name__}")
        units.check_bool("verify", verify)
        units.check_bool("allow_baud_change", allow_baud_change)
        units.check_bool("allow_id_change", allow_id_change)
        eeprom.check_writable()  # (an undefined header or baud code: refused before the read goes out)
        current = await self.read_eeprom()
        reason = eeprom.write_refusal(
            current, self.id, allow_baud_change=allow_baud_change, allow_id_change=allow_id_change
        )
        if reason:
            raise UnsafeOperation(f"{reason}; nothing was written")
        # Each field the image changes passes replace()'s checks (the reference's range, even stretch, flag
        # rules), as if it had been made so; a value the servo already holds is written back as read.
        command = protocol.WriteEeprom(self.id, eeprom, current=current)
        await self._bus.request(command, priority=self.priority)
        if verify and eeprom.baud_rate == current.baud_rate and eeprom.servo_id == current.servo_id:
            back = await self.read_eeprom()
            if back != eeprom:
                raise VerifyError(f"servo {self.id}: EEPROM read back differs: {back.diff(eeprom)}")


class Device:
    """A generic ICS device (not a servo) exposing a 128-byte virtual memory.

    Args:
        bus: the line the device is on; ``bus.device(device_id)`` is the usual way to make one.
        device_id: the device's ID, 0..31.

    Raises:
        InvalidArgument: ``bus`` is not a line or ``device_id`` is not 0..31.
    """

    __slots__ = ("_bus", "id")

    def __init__(self, bus: Line, device_id: int) -> None:
        self._bus = _check_bus(bus)
        self.id = protocol.check_id(device_id)

    def __repr__(self) -> str:
        return f"<Device {self.id} on {self._bus!r}>"

    async def read_memory(self, address: int, count: int) -> bytes:
        """Read ``count`` bytes from ``address`` of a generic memory device.

        Raises:
            InvalidArgument: the address or count is out of range.
            ReplyError: the device did not answer, or answered wrongly.
            BusClosed, PortLost: the bus is closed or its port is gone.
        """
        return await self._bus.request(protocol.ReadMemory(self.id, address, count))

    async def write_memory(self, address: int, data: bytes | Sequence[int]) -> None:
        """Write ``data`` at ``address`` of a generic memory device (never retried).

        Raises:
            InvalidArgument: the address or data is out of range.
            ReplyError: the device did not answer, or answered wrongly.
            BusClosed, PortLost: the bus is closed or its port is gone.
        """
        await self._bus.request(protocol.WriteMemory(self.id, address, data))
