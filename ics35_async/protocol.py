"""ICS 3.5 wire codec, sans-IO: every command's bytes, lengths and reply rules.

A command object knows the bytes the host sends (``tx``), how many echo bytes
come back (``len(tx)``), the exact reply length, how to validate and parse a
reply, and how a device would encode that reply (``encode_reply``, used by
the simulator so the wire rules live only here).  :func:`decode_request`
is the device side's framing of a host byte stream.

Nothing here does I/O or keeps state between calls.  The one baud-dependent
rule (a position reply from ID 0 at 115200 keeps its MSB) takes the baud
rate as an explicit argument.
"""

from __future__ import annotations

import enum
from collections.abc import Sequence
from typing import Any, ClassVar, Generic, TypeVar

from .eeprom import EEPROM_SIZE, BaudRate, Eeprom
from .errors import (
    IcsError,
    InvalidArgument,
    MalformedEeprom,
    ReplyDataError,
    ReplyHeaderError,
    ReplyLengthError,
    ReplySubcommandError,
    ReplyValueError,
)
from .units import check_int

T = TypeVar("T")

BITS_PER_BYTE = 11  # start + 8 data + even parity + stop
MAX_ID = 31
POSITION_MAX = 16383
FREE = 0

CMD_POSITION = 0x80
CMD_READ = 0xA0
CMD_WRITE = 0xC0
CMD_ID = 0xE0
SC_MEMORY = 0x7F
MEMORY_SIZE = 128


class Param(enum.IntEnum):
    """Parameter sub-commands (SC) of the read and write commands."""

    EEPROM = 0
    STRETCH = 1
    SPEED = 2
    CURRENT = 3  # read: the measured current; write: the current limit
    TEMPERATURE = 4  # read: the measured temperature; write: the limit


# Valid write ranges for SC 1..4.
WRITE_RANGES: dict[Param, tuple[int, int]] = {
    Param.STRETCH: (1, 127),
    Param.SPEED: (1, 127),
    Param.CURRENT: (1, 63),
    Param.TEMPERATURE: (1, 127),
}
_READ_NAMES = {
    Param.EEPROM: "read_eeprom",
    Param.STRETCH: "read_stretch",
    Param.SPEED: "read_speed",
    Param.CURRENT: "read_current",
    Param.TEMPERATURE: "read_temperature",
}
_WRITE_NAMES = {
    Param.EEPROM: "write_eeprom",
    Param.STRETCH: "write_stretch",
    Param.SPEED: "write_speed",
    Param.CURRENT: "write_current_limit",
    Param.TEMPERATURE: "write_temperature_limit",
}


class Timing(enum.Enum):
    """Which deadline allowance a command needs (the bus maps these to seconds)."""

    NORMAL = "normal"
    EEPROM_WRITE = "eeprom_write"  # the servo answers noticeably later
    ID = "id"


def wire_time(nbytes: int, baudrate: int) -> float:
    """Seconds the line needs for ``nbytes`` bytes at ``baudrate``."""
    return nbytes * BITS_PER_BYTE / baudrate


def check_id(servo_id: object) -> int:
    return check_int("servo ID", servo_id, 0, MAX_ID)


def check_baud(baudrate: object) -> BaudRate:
    return BaudRate.parse(baudrate)


# --- fast helpers for the streaming hot path (callers validate beforehand) ---


def position_tx(servo_id: int, position: int) -> bytes:
    return bytes((CMD_POSITION | servo_id, (position >> 7) & 0x7F, position & 0x7F))


def position_reply_header(servo_id: int, baudrate: int) -> int:
    """The first byte of a position reply; ID 0 at 115200 keeps the MSB (ICS 2.0)."""
    cmd = CMD_POSITION | servo_id
    return cmd if (servo_id == 0 and baudrate == BaudRate.B115200) else cmd & 0x7F


def join7(high: int, low: int) -> int:
    return (high << 7) | low


def position_from_reply(buf: bytes | bytearray, offset: int, header: int) -> int:
    """The position in a 3-byte position reply at ``buf[offset:]``, or -1 if invalid.

    The streaming hot path's check; on -1, :meth:`Position.parse` gives the typed error.
    """
    high, low = buf[offset + 1], buf[offset + 2]
    if buf[offset] != header or (high | low) & 0x80:
        return -1
    return (high << 7) | low


def split7(value: int) -> tuple[int, int]:
    return (value >> 7) & 0x7F, value & 0x7F


def nibbles_from_bytes(data: bytes) -> bytes:
    """Each memory byte as two wire bytes, high nibble first."""
    out = bytearray()
    for b in data:
        out.append(b >> 4)
        out.append(b & 0x0F)
    return bytes(out)


def bytes_from_nibbles(wire: bytes) -> bytes:
    """Inverse of :func:`nibbles_from_bytes`; raises ValueError on a non-nibble."""
    if len(wire) % 2 or any(b > 0x0F for b in wire):
        raise ValueError("not a whole number of nibble pairs")
    return bytes((wire[i] << 4) | wire[i + 1] for i in range(0, len(wire), 2))


# --- commands ---


class Command(Generic[T]):
    """One host command: its bytes, reply length, and reply parser.

    ``servo_id`` is the addressed ID (``None`` for the ID command, which the
    whole line hears).  ``idempotent`` commands may be retried by the bus.
    """

    __slots__ = ("name", "reply_len", "servo_id", "tx")

    idempotent: ClassVar[bool] = True
    timing: ClassVar[Timing] = Timing.NORMAL

    servo_id: int | None
    tx: bytes
    reply_len: int
    name: str

    @property
    def echo_len(self) -> int:
        return len(self.tx)

    def parse(self, reply: bytes) -> T:
        """Validate a reply (echo already removed) and return its value."""
        raise NotImplementedError

    def encode_reply(self, value: T) -> bytes:
        """The reply a well-behaved device sends for ``value`` (simulator side)."""
        raise NotImplementedError

    def _fail(self, cls: type[IcsError], message: str, reply: bytes) -> IcsError:
        return cls(message, command=self.name, servo_id=self.servo_id, raw=reply)  # type: ignore[call-arg]

    def _check_length(self, reply: bytes) -> None:
        if len(reply) != self.reply_len:
            raise self._fail(ReplyLengthError, f"reply is {len(reply)} bytes, expected {self.reply_len}", reply)

    def _check_header(self, reply: bytes, expected: int) -> None:
        if reply[0] != expected:
            raise self._fail(
                ReplyHeaderError,
                f"reply command byte 0x{reply[0]:02X}, expected 0x{expected:02X}",
                reply,
            )

    def _check_param_head(self, reply: bytes) -> None:
        """Length, then ``CMD & 0x7F`` and the echoed sub-command: every parameter reply starts so."""
        self._check_length(reply)
        self._check_header(reply, self.tx[0] & 0x7F)
        if reply[1] != self.tx[1]:
            raise self._fail(ReplySubcommandError, f"reply SC 0x{reply[1]:02X}, expected 0x{self.tx[1]:02X}", reply)

    def _check_7bit(self, reply: bytes, start: int) -> None:
        for i in range(start, len(reply)):
            if reply[i] & 0x80:
                raise self._fail(ReplyDataError, f"reply byte {i + 1} is 0x{reply[i]:02X}, MSB set", reply)

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.name} id={self.servo_id} tx={self.tx.hex(' ')}>"


class Position(Command[int]):
    """Position set (0x80); position 0 is FREE.  Returns the reported position."""

    __slots__ = ("baudrate", "position", "reply_header")

    def __init__(self, servo_id: int, position: int, *, baudrate: int) -> None:
        self.servo_id = check_id(servo_id)
        self.position = check_int("position", position, 0, POSITION_MAX)
        self.baudrate = check_baud(baudrate)
        self.name = "free" if position == FREE else "position"
        self.tx = position_tx(servo_id, position)
        self.reply_len = 3
        self.reply_header = position_reply_header(servo_id, self.baudrate)

    def parse(self, reply: bytes) -> int:
        self._check_length(reply)
        self._check_header(reply, self.reply_header)
        self._check_7bit(reply, 1)
        return join7(reply[1], reply[2])

    def encode_reply(self, value: int) -> bytes:
        return bytes((self.reply_header, *split7(value)))


class ReadParam(Command[int]):
    """Parameter read (0xA0), SC 1..4: one 7-bit value."""

    __slots__ = ("param",)

    def __init__(self, servo_id: int, param: Param | int) -> None:
        self.servo_id = check_id(servo_id)
        check_int("parameter", param, 1, 4)
        self.param = Param(param)
        self.name = _READ_NAMES[self.param]
        self.tx = bytes((CMD_READ | servo_id, self.param))
        self.reply_len = 3

    def parse(self, reply: bytes) -> int:
        self._check_param_head(reply)
        self._check_7bit(reply, 2)
        return reply[2]

    def encode_reply(self, value: int) -> bytes:
        return bytes((self.tx[0] & 0x7F, self.param, value))


def guard_read(tx: bytes, servo_id: int) -> ReadParam:
    """A harmless read whose reply cannot be mistaken for the reply to ``tx``.

    A parameter read of another sub-command: a late reply to ``tx`` fails its
    header, sub-command or length check.
    """
    same_as_stretch_read = tx[:2] == bytes((CMD_READ | servo_id, Param.STRETCH))
    return ReadParam(servo_id, Param.SPEED if same_as_stretch_read else Param.STRETCH)


class ReadEeprom(Command[Eeprom]):
    """Parameter read SC 0: the 64-byte EEPROM image."""

    __slots__ = ()

    def __init__(self, servo_id: int) -> None:
        self.servo_id = check_id(servo_id)
        self.name = _READ_NAMES[Param.EEPROM]
        self.tx = bytes((CMD_READ | servo_id, Param.EEPROM))
        self.reply_len = 2 + EEPROM_SIZE

    def parse(self, reply: bytes) -> Eeprom:
        self._check_param_head(reply)
        try:
            return Eeprom.from_bytes(reply[2:])
        except MalformedEeprom as exc:
            raise self._fail(ReplyDataError, f"EEPROM image: {exc}", reply) from exc

    def encode_reply(self, value: Eeprom) -> bytes:
        return bytes((self.tx[0] & 0x7F, Param.EEPROM)) + value.to_bytes()


class WriteParam(Command[int]):
    """Parameter write (0xC0), SC 1..4, RAM only.  Returns the echoed value."""

    __slots__ = ("param", "value")

    def __init__(self, servo_id: int, param: Param | int, value: int) -> None:
        self.servo_id = check_id(servo_id)
        check_int("parameter", param, 1, 4)
        self.param = Param(param)
        self.name = _WRITE_NAMES[self.param]
        low, high = WRITE_RANGES[self.param]
        self.value = check_int(self.name.removeprefix("write_").replace("_", " "), value, low, high)
        self.tx = bytes((CMD_WRITE | servo_id, self.param, value))
        self.reply_len = 3

    def parse(self, reply: bytes) -> int:
        self._check_param_head(reply)
        self._check_7bit(reply, 2)
        if reply[2] != self.value:
            raise self._fail(ReplyValueError, f"reply value {reply[2]}, wrote {self.value}", reply)
        return reply[2]

    def encode_reply(self, value: int) -> bytes:
        return bytes((self.tx[0] & 0x7F, self.param, value))


class WriteEeprom(Command[None]):
    """Parameter write SC 0: all 64 EEPROM bytes at once (persists; slow reply)."""

    __slots__ = ("eeprom",)
    idempotent = False
    timing = Timing.EEPROM_WRITE

    def __init__(self, servo_id: int, eeprom: Eeprom) -> None:
        self.servo_id = check_id(servo_id)
        if not isinstance(eeprom, Eeprom):
            raise InvalidArgument(f"eeprom must be an Eeprom, not {type(eeprom).__name__}")
        self.eeprom = eeprom
        self.name = _WRITE_NAMES[Param.EEPROM]
        self.tx = bytes((CMD_WRITE | servo_id, Param.EEPROM)) + eeprom.to_bytes()
        self.reply_len = 2

    def parse(self, reply: bytes) -> None:
        self._check_param_head(reply)

    def encode_reply(self, value: None) -> bytes:
        return bytes((self.tx[0] & 0x7F, Param.EEPROM))


class ReadId(Command[int]):
    """ID read: only safe with exactly one device on the line."""

    __slots__ = ()
    timing = Timing.ID

    def __init__(self, servo_id: int = MAX_ID) -> None:
        # The ID bits are ignored by the servo; 0xFF is the reference's choice.
        self.servo_id = None
        self.name = "read_id"
        self.tx = bytes((CMD_ID | check_id(servo_id), 0, 0, 0))
        self.reply_len = 1

    def parse(self, reply: bytes) -> int:
        self._check_length(reply)
        if reply[0] & 0xE0 != CMD_ID:
            raise self._fail(ReplyHeaderError, f"ID reply 0x{reply[0]:02X} is not 0xE0 | id", reply)
        return reply[0] & 0x1F

    def encode_reply(self, value: int) -> bytes:
        return bytes((CMD_ID | value,))


class WriteId(Command[int]):
    """ID write: gives the new ID to every device on the line."""

    __slots__ = ("new_id",)
    idempotent = False
    timing = Timing.ID

    def __init__(self, new_id: int) -> None:
        self.new_id = check_id(new_id)
        self.servo_id = None
        self.name = "write_id"
        self.tx = bytes((CMD_ID | new_id, 1, 1, 1))
        self.reply_len = 1

    def parse(self, reply: bytes) -> int:
        self._check_length(reply)
        self._check_header(reply, self.tx[0])
        return self.new_id

    def encode_reply(self, value: int) -> bytes:
        return bytes((CMD_ID | value,))


def _check_span(address: object, count: object) -> tuple[int, int]:
    check_int("address", address, 0, MEMORY_SIZE - 1)
    check_int("count", count, 1, MEMORY_SIZE - 1)
    assert isinstance(address, int) and isinstance(count, int)
    if address + count > MEMORY_SIZE:
        raise InvalidArgument(f"address {address} + count {count} runs past the {MEMORY_SIZE}-byte memory")
    return address, count


class _MemoryCommand(Command[T]):
    __slots__ = ("address", "count")

    address: int
    count: int

    def _check_memory_header(self, reply: bytes) -> None:
        # The reference's own example keeps the MSB on generic replies: accept both.
        if reply[0] not in (self.tx[0], self.tx[0] & 0x7F):
            raise self._fail(
                ReplyHeaderError,
                f"reply command byte 0x{reply[0]:02X}, expected 0x{self.tx[0]:02X} or 0x{self.tx[0] & 0x7F:02X}",
                reply,
            )
        if tuple(reply[1:4]) != (SC_MEMORY, self.address, self.count):
            raise self._fail(
                ReplySubcommandError,
                f"reply SC/address/count {reply[1:4].hex(' ')}, expected 7f {self.address:02x} {self.count:02x}",
                reply,
            )


class ReadMemory(_MemoryCommand[bytes]):
    """Generic read (0xA0, SC 0x7F): ``count`` bytes from a device's 128-byte memory."""

    __slots__ = ()

    def __init__(self, device_id: int, address: int, count: int) -> None:
        self.servo_id = check_id(device_id)
        self.address, self.count = _check_span(address, count)
        self.name = "read_memory"
        self.tx = bytes((CMD_READ | device_id, SC_MEMORY, address, count))
        self.reply_len = 4 + 2 * count

    def parse(self, reply: bytes) -> bytes:
        self._check_length(reply)
        self._check_memory_header(reply)
        try:
            return bytes_from_nibbles(reply[4:])
        except ValueError:
            raise self._fail(ReplyDataError, "memory payload byte is not a nibble", reply) from None

    def encode_reply(self, value: bytes) -> bytes:
        return self.tx[:4] + nibbles_from_bytes(value)


class WriteMemory(_MemoryCommand[None]):
    """Generic write (0xC0, SC 0x7F): ``data`` to a device's memory."""

    __slots__ = ("data",)
    idempotent = False

    def __init__(self, device_id: int, address: int, data: bytes | Sequence[int]) -> None:
        self.servo_id = check_id(device_id)
        try:
            # bytes(5) would be five zero bytes, not an error.
            if isinstance(data, int):
                raise TypeError
            payload = bytes(data)
        except (TypeError, ValueError):
            raise InvalidArgument("data must be bytes or a sequence of ints 0..255") from None
        self.address, self.count = _check_span(address, len(payload))
        self.data = payload
        self.name = "write_memory"
        self.tx = bytes((CMD_WRITE | device_id, SC_MEMORY, address, len(payload))) + nibbles_from_bytes(payload)
        self.reply_len = 4

    def parse(self, reply: bytes) -> None:
        self._check_length(reply)
        self._check_memory_header(reply)

    def encode_reply(self, value: None) -> bytes:
        return self.tx[:4]


def _msb_in(buf: bytes | bytearray, end: int) -> bool:
    """Whether a data byte of the frame ``buf[:end]`` (as far as it has arrived) has its MSB set."""
    return any(b & 0x80 for b in buf[1:end])


def decode_request(buf: bytes | bytearray, *, baudrate: int) -> tuple[Command[Any] | None, int] | None:
    """Frame one host command at the start of ``buf`` (device side).

    Returns ``None`` when more bytes are needed, else ``(command, consumed)``
    where ``command`` is ``None`` for bytes a device ignores (a stray data
    byte, an unknown sub-command or an out-of-range value).
    """
    baud = check_baud(baudrate)
    if not buf:
        return None
    first = buf[0]
    if not first & 0x80:
        return None, 1  # not a command byte: another device's reply or noise
    # Data bytes never have the MSB set, so one that does starts the next
    # command: drop only the broken frame's command byte, never swallow it.
    kind, sid = first & 0xE0, first & 0x1F
    if kind == CMD_POSITION:
        if _msb_in(buf, 3):
            return None, 1
        if len(buf) < 3:
            return None
        return Position(sid, join7(buf[1], buf[2]), baudrate=baud), 3
    if len(buf) < 2:
        return None
    sc = buf[1]
    if sc & 0x80:
        return None, 1
    if kind == CMD_ID:
        if _msb_in(buf, 4):
            return None, 1
        if len(buf) < 4:
            return None
        if buf[1] == buf[2] == buf[3] == 0:
            return ReadId(sid), 4
        if buf[1] == buf[2] == buf[3] == 1:
            return WriteId(sid), 4
        return None, 4
    if sc == SC_MEMORY:
        if _msb_in(buf, 4):
            return None, 1
        if len(buf) < 4:
            return None
        address, count = buf[2], buf[3]
        try:
            _check_span(address, count)
        except InvalidArgument:
            return None, 4
        if kind == CMD_READ:
            return ReadMemory(sid, address, count), 4
        total = 4 + 2 * count
        if _msb_in(buf, total):
            return None, 1
        if len(buf) < total:
            return None
        try:
            data = bytes_from_nibbles(bytes(buf[4:total]))
        except ValueError:
            return None, total
        return WriteMemory(sid, address, data), total
    if kind == CMD_READ:
        if sc == Param.EEPROM:
            return ReadEeprom(sid), 2
        if sc in WRITE_RANGES:
            return ReadParam(sid, sc), 2
        return None, 2
    # parameter write
    if sc == Param.EEPROM:
        total = 2 + EEPROM_SIZE
        if _msb_in(buf, total):
            return None, 1
        if len(buf) < total:
            return None
        try:
            return WriteEeprom(sid, Eeprom.from_bytes(bytes(buf[2:total]))), total
        except MalformedEeprom:
            return None, total
    if sc not in WRITE_RANGES:
        return None, 2
    if _msb_in(buf, 3):
        return None, 1
    if len(buf) < 3:
        return None
    try:
        return WriteParam(sid, sc, buf[2]), 3
    except InvalidArgument:
        return None, 3
