"""The devices on the simulated line: :class:`VirtualServo` and :class:`MemoryDevice`.

A device answers a decoded :class:`~ics35_async.protocol.Command` with a
value; the line (:mod:`.virtual_line`) turns that value into bytes with the command's
own ``encode_reply``, so no byte layout is repeated here.

Model of a servo, in brief (all of it deliberately simple and deterministic):

* **EEPROM vs RAM.**  The 64-byte image is kept as an :class:`Eeprom`.
  Stretch, speed, current limit and temperature limit live in RAM, loaded
  from the EEPROM at power-up (held to the RAM's ranges: an image out of the
  reference's loads its nearest values); the parameter-write command changes RAM only.
  The EEPROM write stores the image (protected calibration bytes included, as
  written: the firmware does not guard them, the host must write them back
  as read; :attr:`VirtualServo.calibration_intact` tells a test whether it did).
  The ID, flags and pulse limits of a newly written image apply at once; the
  RAM parameters and the baud rate only at the next :meth:`power_cycle`
  (the reference: "from the next time on, talk at the new speed").
* **Motion.**  The servo moves toward its target at ``speed / 127 *``
  :data:`MAX_RATE` counts per second.  Targets are clamped to the EEPROM
  pulse limits.  With the REVERSE flag the host's coordinates are mirrored
  about neutral (7500): the host sees the position it asked for, the shaft
  (:attr:`VirtualServo.shaft_position`) turns the other way.  The user offset
  and continuous rotation are not modelled.
* **ICS 3.6.**  With ``ics36`` the servo also answers the position read
  (:class:`~ics35_async.protocol.ReadPosition`) with where it is, torque
  and target unchanged; an ICS 3.5 servo (the default) stays silent to it.
* **Noisy readings.**  With ``noisy`` (a broken potentiometer, a noisy wiper)
  every position it reports is up to :data:`NOISY_JUMP` counts off where it is,
  either side, so that no two of any 25 reports in a row agree (a reader that
  takes every few, as a robot at its own pace does, sees none agree either); it
  moves as any servo does.
* **Free.**  Position 0 turns the torque off: the servo stays where it is and
  :meth:`VirtualServo.move_by_hand` may turn it.  A servo powers up free.
* **Current** (0..63, bit 6 = direction): about 1 when holding, more while
  moving (grows with speed), plus the external :attr:`VirtualServo.load`
  (signed, in current units), capped by the RAM current limit; 0 when free.
* **Temperature** follows the current with a first-order lag
  (:data:`THERMAL_TIME_CONSTANT` seconds) from :data:`AMBIENT_CELSIUS` and is
  reported as the spec's parameter (smaller = hotter).  A servo hotter than
  its temperature limit drops its torque (goes free) until it cools down.

Time is whatever the line says it is (simulated in fast mode, wall-clock in
real-time mode); a servo's state is advanced lazily to the time it is asked.
"""

from __future__ import annotations

import math
import random
from collections.abc import Iterable
from typing import Any

from ..eeprom import PROTECTED_OFFSETS, BaudRate, Eeprom, Flags
from ..errors import InvalidArgument
from ..protocol import (
    FREE,
    MEMORY_SIZE,
    WRITE_RANGES,
    Param,
    Position,
    ReadEeprom,
    ReadId,
    ReadMemory,
    ReadParam,
    ReadPosition,
    WriteEeprom,
    WriteId,
    WriteMemory,
    WriteParam,
)
from ..units import (
    NEUTRAL,
    POSITION_MAX,
    Current,
    celsius_to_temperature,
    check_int,
    current_to_raw,
)

MAX_RATE = 12000.0
"""Counts per second at speed 127 (KRS servos turn 60 degrees in about 0.14 s)."""
AMBIENT_CELSIUS = 25.0
THERMAL_TIME_CONSTANT = 60.0
"""Seconds for the temperature to cover 63 % of the way to its steady state."""
CELSIUS_PER_CURRENT = 1.6
"""Steady-state temperature rise per unit of current (63 units: about 125 C)."""
CALIBRATION_NIBBLES = len(PROTECTED_OFFSETS)
HOLDING_CURRENT = 1
MOVING_CURRENT = 8
"""Extra current while moving at full speed (scaled by speed / 127)."""
NOISY_JUMP = 4000
"""Counts (135 degrees): the farthest a ``noisy`` servo's reported position is off where it is, either side."""
# A noisy servo's offset walks NOISY_STRIDE counts a report, wrapping within 2 * NOISY_JUMP: reports up to 25 apart
# are then at least 307 counts (10.4 degrees) apart, more than a robot lets two readings differ by (TURN_STEP and
# TURN_SLACK), so readings taken every few reports (a robot takes each line's newest cycle, more than 20 apart on a
# loaded host) never agree either.  Two offsets alternating agreed with themselves every other report.
NOISY_STRIDE = 2769


def factory_calibration(servo_id: int) -> bytes:
    """Plausible calibration nibbles, fixed per ID and different for each of the 32 IDs."""
    rng = random.Random(0x1C5 * 32 + servo_id)
    return bytes(rng.randrange(16) for _ in range(CALIBRATION_NIBBLES))


def _held(param: Param, value: int) -> int:
    """``value`` within the range RAM parameter ``param`` takes."""
    low, high = WRITE_RANGES[param]
    return min(high, max(low, value))


class Silence:
    """Marker: the device heard the command but stays silent."""


NO_REPLY = Silence()


class VirtualServo:
    """One simulated ICS 3.5 servo (ICS 3.6 with ``ics36``: it also answers the position read).

    ``servo_id`` and ``baud_rate`` build the spec's factory image
    (:meth:`Eeprom.factory`, with a calibration that differs per ID) unless
    ``eeprom`` is given.  A given image whose baud-rate code the reference does
    not define leaves the servo talking at ``baud_rate`` (what a real one does
    is not documented).  ``position`` is where the shaft starts (host
    coordinates); ``load`` is an external torque in current units (signed).
    ``ignores``: names of commands it leaves unanswered (``{"read_eeprom"}``),
    as a device that half-answers does (another firmware, not a servo).
    ``ambient_celsius`` is the temperature it starts at and cools towards.
    ``noisy``: every position it reports jumps up to :data:`NOISY_JUMP` counts either side of where it is.

    Raises:
        InvalidArgument: a bad ID, baud rate, position or image.
    """

    def __init__(
        self,
        servo_id: int = 0,
        *,
        eeprom: Eeprom | None = None,
        baud_rate: int = BaudRate.B115200,
        position: int = NEUTRAL,
        load: int = 0,
        ambient_celsius: float = AMBIENT_CELSIUS,
        ignores: Iterable[str] = (),
        ics36: bool = False,
        noisy: bool = False,
    ) -> None:
        self.ignores = frozenset(ignores)
        if eeprom is None:
            eeprom = Eeprom.factory(
                servo_id, baud_rate=BaudRate.parse(baud_rate), calibration=factory_calibration(servo_id)
            )
        elif not isinstance(eeprom, Eeprom):
            raise TypeError(f"eeprom must be an Eeprom, not {type(eeprom).__name__}")
        self._eeprom = eeprom
        self._undefined_code_baud = BaudRate.parse(baud_rate)
        self.factory_calibration = eeprom.calibration
        self._position = float(check_int("position", position, 1, POSITION_MAX))
        self.load = load
        self.ics36 = bool(ics36)
        self.noisy = bool(noisy)
        self._reports = 0  # positions reported (with ``noisy``: which offset the next one has)
        self.ambient_celsius = ambient_celsius
        self.temperature_celsius = ambient_celsius
        self._target: int | None = None
        self._time = 0.0
        self.eeprom_writes = 0
        self.power_cycles = 0
        self._load_ram()

    # -- identity and persistent state

    @property
    def eeprom(self) -> Eeprom:
        """The servo's EEPROM image (it persists across power cycles)."""
        return self._eeprom

    @eeprom.setter
    def eeprom(self, image: Eeprom) -> None:
        """Replace the image directly (a test fixture; no wire traffic)."""
        self._eeprom = image

    @property
    def servo_id(self) -> int:
        """The ID it answers to (its EEPROM's)."""
        return self._eeprom.servo_id

    @property
    def calibration_intact(self) -> bool:
        """Whether the protected calibration bytes are still the factory ones."""
        return self._eeprom.calibration == self.factory_calibration

    def _load_ram(self) -> None:
        image = self._eeprom
        self.baud_rate = image.baud_rate if isinstance(image.baud_rate, BaudRate) else self._undefined_code_baud
        # An image out of the reference's ranges loads held to what the RAM holds (the parameter write's ranges,
        # sections 4-5; stretch 1..127 is the EEPROM's 2..254 halved): a speed of 0 would stop the motion model,
        # a RAM value of 200 could not be answered in 7 bits.  What a real servo makes of such an image is not
        # documented.
        self.stretch = _held(Param.STRETCH, image.stretch_gain // 2)
        self.speed = _held(Param.SPEED, image.speed)
        self.current_limit = _held(Param.CURRENT, image.current_limit)
        self.temperature_limit = _held(Param.TEMPERATURE, image.temperature_limit)

    def power_cycle(self) -> None:
        """Power off and on: RAM reloads from the EEPROM, the servo wakes up free."""
        self._load_ram()
        self._target = None
        self.power_cycles += 1

    # -- motion

    @property
    def position(self) -> int:
        """The position the servo reports (host coordinates) at its last update."""
        return round(self._position)

    @property
    def shaft_position(self) -> int:
        """Where the output shaft physically is (mirrored when REVERSE is set)."""
        return self._to_shaft(self.position)

    def _to_shaft(self, position: int) -> int:
        return 2 * NEUTRAL - position if self._eeprom.flags & Flags.REVERSE else position

    @property
    def target(self) -> int | None:
        """The clamped target, or ``None`` when free."""
        return self._target

    @property
    def free(self) -> bool:
        """Torque off: no target."""
        return self._target is None

    @property
    def moving(self) -> bool:
        """It has a target and is not there yet."""
        return self._target is not None and self._position != self._target

    @property
    def rate(self) -> float:
        """Counts per second the servo moves at, from the RAM speed."""
        return MAX_RATE * self.speed / 127

    def move_by_hand(self, position: int) -> None:
        """Turn the horn by hand to ``position`` (host coordinates): a free servo stays there.

        Raises:
            InvalidArgument: ``position`` is not 1..16383.
        """
        self._position = float(check_int("position", position, 1, POSITION_MAX))

    def command_position(self, position: int) -> None:
        """Take a position command's ``position`` (0 frees): the target, within the EEPROM's pulse limits."""
        if position == FREE or self.overheated:
            self._target = None
            return
        low, high = self._eeprom.pulse_limit_low, self._eeprom.pulse_limit_high
        self._target = min(high, max(low, position))

    # -- current and temperature

    @property
    def current(self) -> int:
        """Current magnitude 0..63 (not counting the direction bit)."""
        if self._target is None:
            return 0
        moving = MOVING_CURRENT * self.speed / 127 if self.moving else 0.0
        return min(self.current_limit, round(HOLDING_CURRENT + moving + abs(self.load)))

    @property
    def current_raw(self) -> int:
        """The current as the read command returns it (bit 6 set = reverse)."""
        magnitude = self.current
        if self.moving and self._target is not None:
            reverse = self._to_shaft(self._target) < self._to_shaft(self.position)
        else:
            reverse = self.load < 0
        return current_to_raw(Current(magnitude, reverse and magnitude > 0))

    @property
    def temperature(self) -> int:
        """The temperature parameter (1..127, smaller is hotter)."""
        return celsius_to_temperature(self.temperature_celsius)

    @property
    def overheated(self) -> bool:
        """Hotter than its temperature limit: it frees itself, as a real one does."""
        return self.temperature < self.temperature_limit

    def _steady_celsius(self) -> float:
        return self.ambient_celsius + CELSIUS_PER_CURRENT * self.current

    def _heat(self, dt: float) -> None:
        steady = self._steady_celsius()
        self.temperature_celsius = steady + (self.temperature_celsius - steady) * math.exp(-dt / THERMAL_TIME_CONSTANT)

    def update(self, now: float) -> None:
        """Advance motion and temperature to time ``now`` (seconds, the line's clock)."""
        dt = now - self._time
        if dt <= 0:
            return
        self._time = now
        target = self._target
        if target is not None and self._position != target:
            distance = target - self._position
            travel_time = abs(distance) / self.rate
            if travel_time <= dt:
                self._heat(travel_time)
                self._position = float(target)
                self._heat(dt - travel_time)
            else:
                self._heat(dt)
                self._position += math.copysign(self.rate * dt, distance)
        else:
            self._heat(dt)
        if self.overheated:
            self._target = None

    # -- the wire

    def answers(self, baudrate: int) -> bool:
        """Whether it hears a line at ``baudrate`` (its EEPROM's rate)."""
        return self.baud_rate == baudrate

    def handle(self, command: Any) -> Any:
        """Carry out ``command`` (already addressed to this servo); return the reply value."""
        if command.name in self.ignores:
            return NO_REPLY
        if isinstance(command, Position):
            reported = self._reported()
            self.command_position(command.position)
            return reported
        if isinstance(command, ReadPosition):
            return self._reported() if self.ics36 else NO_REPLY
        if isinstance(command, ReadParam):
            return self._read_param(command.param)
        if isinstance(command, WriteParam):
            self._write_param(command.param, command.value)
            return command.value
        if isinstance(command, ReadEeprom):
            return self._eeprom
        if isinstance(command, WriteEeprom):
            self._eeprom = command.eeprom
            self.eeprom_writes += 1
            return None
        if isinstance(command, ReadId):
            return self.servo_id
        if isinstance(command, WriteId):
            self._eeprom = self._eeprom.replace(servo_id=command.new_id)
            return command.new_id
        return NO_REPLY  # generic memory commands: a servo has no such memory

    def _reported(self) -> int:
        """The position a reply carries: where it is, or with ``noisy`` a jump either side of it."""
        if not self.noisy:
            return self.position
        self._reports += 1
        offset = (self._reports * NOISY_STRIDE) % (2 * NOISY_JUMP) - NOISY_JUMP
        return min(POSITION_MAX, max(1, self.position + offset))

    def _read_param(self, param: Param) -> int:
        if param == Param.STRETCH:
            return self.stretch
        if param == Param.SPEED:
            return self.speed
        if param == Param.CURRENT:
            return self.current_raw
        return self.temperature

    def _write_param(self, param: Param, value: int) -> None:
        if param == Param.STRETCH:
            self.stretch = value
        elif param == Param.SPEED:
            self.speed = value
        elif param == Param.CURRENT:
            self.current_limit = value
        else:
            self.temperature_limit = value

    def __repr__(self) -> str:
        state = "free" if self._target is None else f"target={self._target}"
        version = " ICS 3.6" if self.ics36 else ""
        version += " noisy" if self.noisy else ""
        return f"<VirtualServo id={self.servo_id}{version} pos={self.position} {state} baud={int(self.baud_rate)}>"


class MemoryDevice:
    """A generic (non-servo) device: 128 bytes of memory behind the generic commands.

    It answers only the generic read and write (spec section 9), ignores the
    servo and ID commands, and talks at ``baud_rate`` (``None``: any rate).
    ``device_id`` is its ID (0..31), ``memory`` the memory's first bytes (the rest is zero).

    Raises:
        InvalidArgument: a bad ID or baud rate, or more than 128 bytes of memory.
    """

    def __init__(
        self, device_id: int, memory: bytes | bytearray | None = None, *, baud_rate: int | None = None
    ) -> None:
        self._device_id = check_int("device ID", device_id, 0, 31)
        data = bytes(memory or b"")
        if len(data) > MEMORY_SIZE:
            raise InvalidArgument(f"memory is {len(data)} bytes, at most {MEMORY_SIZE}")
        self.memory = bytearray(data.ljust(MEMORY_SIZE, b"\0"))
        self.baud_rate = None if baud_rate is None else BaudRate.parse(baud_rate)

    @property
    def servo_id(self) -> int:
        """Its ID (the name every device on a line shares)."""
        return self._device_id

    def update(self, now: float) -> None:
        """Nothing changes with time (``now``) in a memory."""

    def answers(self, baudrate: int) -> bool:
        """Whether it hears a line at ``baudrate``."""
        return self.baud_rate is None or self.baud_rate == baudrate

    def handle(self, command: Any) -> Any:
        """Carry out ``command`` (addressed to it): the generic read's bytes, or no reply to anything else."""
        if isinstance(command, ReadMemory):
            return bytes(self.memory[command.address : command.address + command.count])
        if isinstance(command, WriteMemory):
            self.memory[command.address : command.address + command.count] = command.data
            return None
        return NO_REPLY

    def __repr__(self) -> str:
        return f"<MemoryDevice id={self._device_id}>"
