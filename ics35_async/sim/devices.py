"""The devices on a simulated line, and which of them answer a command.

:class:`DeviceTable` holds the servos and memory devices of one line, finds
them by their current ID, and dispatches a decoded command: every device the
command reaches is brought up to the command's time, and those that hear it
at the line's baud rate handle it.  Several answers at once are combined by
:func:`garble`, as on the wire.
"""

from __future__ import annotations

import functools
from collections.abc import Iterable, Mapping
from typing import Any

from ..errors import InvalidArgument
from ..protocol import ReadId, WriteEeprom, WriteId
from .virtual_servo import NO_REPLY, MemoryDevice, VirtualServo

VirtualDevice = VirtualServo | MemoryDevice
MemorySpec = Mapping[int, bytes | bytearray | MemoryDevice] | Iterable[MemoryDevice]


def build_devices(
    servos: Iterable[VirtualServo | int] | None,
    memory: MemorySpec | None,
    baudrate: int,
    ics36: Iterable[int] = (),
    noisy: Iterable[int] = (),
) -> list[VirtualDevice]:
    """Servos (objects, or IDs for factory servos at ``baudrate``; ``None``: IDs 0..31) and memory devices.

    Servos built from an ID in ``ics36`` speak ICS 3.6 (they answer the position read); those from an ID in
    ``noisy`` report positions that jump at each reply (see :class:`VirtualServo`).

    Raises:
        InvalidArgument: an ID in ``ics36`` or ``noisy`` that no servo is built from.
    """
    newer, jumping = frozenset(ics36), frozenset(noisy)
    built: list[VirtualDevice] = []
    from_ids: set[int] = set()
    for item in range(32) if servos is None else servos:
        if not isinstance(item, VirtualServo):
            from_ids.add(item)
            item = VirtualServo(item, baud_rate=baudrate, ics36=item in newer, noisy=item in jumping)
        built.append(item)
    for what, listed in (("ics36", newer), ("noisy", jumping)):
        # (an ID no servo is built from would be ignored: a typo, or a servo left out, gives a line unlike the
        # one asked for without a word; a servo object carries its own settings)
        if stray := sorted(listed - from_ids):
            raise InvalidArgument(
                f"no servo of this line is built from ID{'s' if len(stray) > 1 else ''} "
                f"{', '.join(map(str, stray))} given in {what} "
                f"(built from IDs: {', '.join(map(str, sorted(from_ids))) or 'none'})"
            )
    if isinstance(memory, Mapping):
        for device_id, content in memory.items():
            built.append(content if isinstance(content, MemoryDevice) else MemoryDevice(device_id, bytes(content)))
    elif memory is not None:
        built.extend(memory)
    return built


def garble(replies: list[bytes]) -> bytes:
    """What the host hears when several devices answer at once.

    The line idles high and any device pulling it low wins, so the bytes
    combine as a wired-AND (a device that has finished contributes idle
    0xFF).  The devices' slightly different turnarounds smear the frames; we
    model that as one extra 0x00 byte (a glitch read as a start bit), so even
    identical replies come out visibly wrong.
    """
    length = max(len(r) for r in replies)
    anded = bytes(
        functools.reduce(lambda a, b: a & b, (r[i] if i < len(r) else 0xFF for r in replies)) for i in range(length)
    )
    return anded + b"\x00"


class Answer:
    """What the line's devices made of one command: who answered, with what, and what the host hears."""

    __slots__ = ("reply", "responders", "value", "values")

    def __init__(self, command: Any, responders: list[VirtualDevice], values: list[Any]) -> None:
        self.responders = responders
        self.values = values
        replies = [command.encode_reply(v) for v in values]
        self.reply: bytes = b"" if not replies else replies[0] if len(replies) == 1 else garble(replies)
        # The value answered, if exactly one device answered.
        self.value: Any = values[0] if len(values) == 1 else None


NO_ANSWER = Answer(None, [], [])


class DeviceTable:
    """The devices of one line, indexed by their current ID."""

    def __init__(self, devices: list[VirtualDevice]) -> None:
        self.devices = devices
        self.reindex()

    def reindex(self) -> None:
        """Rebuild the ID index (after a device changed its ID, or the list changed)."""
        index: dict[int, list[VirtualDevice]] = {}
        for device in self.devices:
            index.setdefault(device.servo_id, []).append(device)
        self._by_id = index

    def add(self, device: VirtualDevice) -> None:
        self.devices.append(device)
        self.reindex()

    def remove(self, device: VirtualDevice) -> None:
        """Take ``device`` (that object, not another at its ID) off the line.

        Raises:
            ValueError: it is not on the line.
        """
        for index, present in enumerate(self.devices):
            if present is device:
                del self.devices[index]
                self.reindex()
                return
        raise ValueError(f"{device!r} is not on this simulated line")

    def servos_at(self, servo_id: int) -> list[VirtualServo]:
        """Every servo whose current ID is ``servo_id``, in the order they were plugged in."""
        return [d for d in self._by_id.get(servo_id, ()) if isinstance(d, VirtualServo)]

    @property
    def servos(self) -> list[VirtualServo]:
        return [d for d in self.devices if isinstance(d, VirtualServo)]

    def servo(self, servo_id: int) -> VirtualServo:
        """The (first) servo whose current ID is ``servo_id``."""
        for device in self._by_id.get(servo_id, ()):
            if isinstance(device, VirtualServo):
                return device
        raise KeyError(f"no servo with ID {servo_id} on the simulated line")

    def memory_device(self, device_id: int) -> MemoryDevice:
        for device in self._by_id.get(device_id, ()):
            if isinstance(device, MemoryDevice):
                return device
        raise KeyError(f"no memory device with ID {device_id} on the simulated line")

    def update(self, now: float) -> None:
        """Bring every device's state (motion, temperature) up to ``now``."""
        for device in self.devices:
            device.update(now)

    def dispatch(self, command: Any, now: float, baudrate: int) -> Answer:
        """Let every device the decoded ``command`` reaches handle it at ``now``."""
        if isinstance(command, (ReadId, WriteId)):
            candidates: Iterable[VirtualDevice] = self.servos  # the ID command reaches every servo
        else:
            candidates = self._by_id.get(command.servo_id, ())
        responders: list[VirtualDevice] = []
        values: list[Any] = []
        for device in candidates:
            # Devices advance lazily: only the ones a command reaches (and all of
            # them on update()), which keeps a transaction cheap.
            device.update(now)
            if device.answers(baudrate):
                value = device.handle(command)
                if value is not NO_REPLY:
                    responders.append(device)
                    values.append(value)
        if not responders:
            return NO_ANSWER
        if isinstance(command, (WriteId, WriteEeprom)):
            self.reindex()
        return Answer(command, responders, values)
