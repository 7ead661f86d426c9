"""The servo commands, host side: each one's bytes, reply length, reply check and parse.

A command object knows the bytes the host sends (``tx``), how many echo bytes
come back (``echo_len``, the length of ``tx``), the exact reply length, how to
validate and parse a reply, and how a device would encode that reply
(``encode_reply``, used by the simulator so the wire rules live only here).

Nothing here does I/O or keeps state between calls.  The one baud-dependent
rule (a position reply from ID 0 at 115200 keeps its MSB) takes the baud
rate as an explicit argument.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import ClassVar, Generic, TypeVar

from ..eeprom import EEPROM_SIZE, Eeprom
from ..errors import (
    IcsError,
    InvalidArgument,
    MalformedEeprom,
    ReplyDataError,
    ReplyHeaderError,
    ReplyLengthError,
    ReplySubcommandError,
    ReplyValueError,
)
from ..units import check_int
from .hot_path import position_from_reply, position_reply_header, position_tx
from .wire import (
    CMD_ID,
    CMD_READ,
    CMD_WRITE,
    FREE,
    MAX_ID,
    POSITION_MAX,
    SC_POSITION,
    WRITE_RANGES,
    Param,
    Timing,
    check_baud,
    check_id,
    join7,
    split7,
)

T = TypeVar("T")

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


class Command(Generic[T]):
    """One host command: its bytes, reply length, and reply parser.

    ``servo_id`` is the addressed ID (``None`` for the ID command, which the
    whole line hears).  ``idempotent`` commands may be retried by the bus.
    """

    __slots__ = ("name", "reply_len", "servo_id", "tx")

    idempotent: ClassVar[bool] = True
    changes_nothing: ClassVar[bool] = False
    """A read: the device changes nothing for it (the engine may give up on its reply sooner beside a paced
    stream, see ``LineEngine._begin``)."""
    timing: ClassVar[Timing] = Timing.NORMAL
    silence: ClassVar[str | None] = None
    """What no reply at all means, for a command to which silence is a usual answer (a probe's)."""

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
        self.name = "free" if self.position == FREE else "position"
        self.tx = position_tx(self.servo_id, self.position)
        self.reply_len = 3
        self.reply_header = position_reply_header(self.servo_id, self.baudrate)

    def parse(self, reply: bytes) -> int:
        if len(reply) == 3:
            position = position_from_reply(reply, 0, self.reply_header)
            if position >= 0:
                return position
        self._check_length(reply)  # something is wrong: name it
        self._check_header(reply, self.reply_header)
        self._check_7bit(reply, 1)
        return join7(reply[1], reply[2])

    def encode_reply(self, value: int) -> bytes:
        return bytes((self.reply_header, *split7(value)))


class ProbeFree(Position):
    """The free command sent to an ID that may be empty ("free all": every ID there may be a servo at).

    The same bytes as ``Position(servo_id, FREE, baudrate=...)``; its ``Timing.PROBE``
    lets the bus wait only as long as this link's answers have taken, not the
    adapter's worst case, because most of the IDs asked are empty and the servos
    after them are to go limp at once.
    """

    __slots__ = ()

    timing = Timing.PROBE
    silence = "no reply to the free: no servo at this ID (or one that does not answer)"

    def __init__(self, servo_id: int, *, baudrate: int) -> None:
        super().__init__(servo_id, FREE, baudrate=baudrate)


class SilentFree(Position):
    """The free command to a servo a stream has found silent (offline), as the stream closes.

    The same bytes as ``Position(servo_id, FREE, baudrate=...)``: a servo that came back
    executes it.  Its reply would only confirm that, and the stream already waited the whole
    allowance for this servo and heard nothing, so ``Timing.SILENT`` waits as a probe does,
    and on a line where nothing has answered yet (nothing to learn a probe's wait from: an
    unplugged line) only a probe's least wait, not the whole allowance once more.
    """

    __slots__ = ()

    timing = Timing.SILENT
    silence = "no reply to the free: the servo was already silent (offline)"

    def __init__(self, servo_id: int, *, baudrate: int) -> None:
        super().__init__(servo_id, FREE, baudrate=baudrate)


class SecondLookFree(Position):
    """The free command again, with the full allowance, to an ID its :class:`ProbeFree` found silent
    (or answered garbled): silence is its usual answer too."""

    __slots__ = ()

    silence = "no reply to the free's second look either: no servo at this ID (or one that does not answer)"

    def __init__(self, servo_id: int, *, baudrate: int) -> None:
        super().__init__(servo_id, FREE, baudrate=baudrate)


class ReadParam(Command[int]):
    """Parameter read (0xA0), SC 1..4: one 7-bit value."""

    __slots__ = ("param",)
    changes_nothing = True

    def __init__(self, servo_id: int, param: Param | int) -> None:
        self.servo_id = check_id(servo_id)
        self.param = Param(check_int("parameter", param, 1, 4))
        self.name = _READ_NAMES[self.param]
        self.tx = bytes((CMD_READ | self.servo_id, self.param))
        self.reply_len = 3

    def parse(self, reply: bytes) -> int:
        self._check_param_head(reply)
        self._check_7bit(reply, 2)
        return reply[2]

    def encode_reply(self, value: int) -> bytes:
        return bytes((self.tx[0] & 0x7F, self.param, value))


class ProbeRead(ReadParam):
    """A stretch read asking whether a servo is at ``servo_id`` (scans, the ID write's survey).

    The same bytes as ``ReadParam(servo_id, Param.STRETCH)``; its ``Timing.PROBE``
    lets the bus wait only as long as this link's answers have taken, not the
    adapter's worst case, because most probed IDs are empty.
    """

    __slots__ = ()

    timing = Timing.PROBE
    silence = "no reply to the probe: no servo at this ID (or one that does not answer)"

    def __init__(self, servo_id: int) -> None:
        super().__init__(servo_id, Param.STRETCH)


class ReadPosition(Command[int]):
    """ICS 3.6 position read (0xA0, SC 5): the present position, without moving or freeing the servo.

    The reply is ``0x20|id, 0x05, pos_hi, pos_lo`` (7 bits each).  An ICS 3.5
    servo does not answer it (see :class:`ProbeReadPosition`).
    """

    __slots__ = ()
    changes_nothing = True

    def __init__(self, servo_id: int) -> None:
        self.servo_id = check_id(servo_id)
        self.name = "read_position"
        self.tx = bytes((CMD_READ | self.servo_id, SC_POSITION))
        self.reply_len = 4

    def parse(self, reply: bytes) -> int:
        self._check_param_head(reply)
        self._check_7bit(reply, 2)
        return join7(reply[2], reply[3])

    def encode_reply(self, value: int) -> bytes:
        return bytes((self.tx[0] & 0x7F, SC_POSITION, *split7(value)))


class ProbeReadPosition(ReadPosition):
    """The position read asking whether a servo speaks ICS 3.6: silence (ICS 3.5) is a usual answer.

    The same bytes as :class:`ReadPosition`; ``Timing.PROBE`` waits only as long
    as this link's answers have taken, and a silent probe gets the probe's short
    resync, so an ICS 3.5 servo costs little and does not make the line look slow.
    """

    __slots__ = ()

    timing = Timing.PROBE
    silence = "no reply to the probe: an ICS 3.5 servo has no position read (or no servo answers here)"


class SecondLookReadPosition(ReadPosition):
    """The position read once more, with the full allowance, before a free command to a servo its
    :class:`ProbeReadPosition` found silent (an ICS 3.6 servo's reply may have been lost, or late past the
    probe's short wait): silence (ICS 3.5) is its usual answer too."""

    __slots__ = ()

    silence = "no reply to the position read with the whole allowance either: an ICS 3.5 servo (or no servo here)"


class SecondLookRead(ReadParam):
    """A stretch read asking again, with the full allowance, whether a servo is at ``servo_id`` (a scan's
    second look at an ID its :class:`ProbeRead` found silent): silence is its usual answer too."""

    __slots__ = ()

    silence = "no reply to the second look either: no servo at this ID (or one that does not answer)"

    def __init__(self, servo_id: int) -> None:
        super().__init__(servo_id, Param.STRETCH)


class GuardRead(ReadParam):
    """The read :func:`guard_read` makes: it follows a command that got no reply, so its servo's
    silence is to be expected (the same servo's, or, in a long stall, another's: see :func:`guard_read`)."""

    __slots__ = ()

    silence = "no reply to the guard read (a harmless read sent after a command that got none): its servo is silent"


def guard_read(tx: bytes, servo_id: int, avoid: Sequence[bytes] = ()) -> ReadParam:
    """A harmless read whose reply cannot be mistaken for the reply to ``tx``.

    A parameter read of another sub-command: a late reply to ``tx`` fails its
    header, sub-command or length check.  Not one of ``avoid`` either: commands sent
    whose echo and reply may still come, in the order sent (see the engine's guard
    rule), whose late answer a guard identical to one would take for its own.
    Where both of ``servo_id``'s reads are among them, the one identical to the
    last of them if it is one (bytes come in order: a guard that takes the last
    one's echo and reply shows that every older one's came first); otherwise a
    read of another servo, which a late reply from ``servo_id`` fails by its
    header (first the servos ``avoid`` addressed, last first: those are on the
    line, and a read of an absent one waits out its whole allowance).
    """
    own = tx[:2]
    stretch_first = own != bytes((CMD_READ | servo_id, Param.STRETCH))
    order = (Param.STRETCH, Param.SPEED) if stretch_first else (Param.SPEED, Param.STRETCH)
    for param in order:
        candidate = bytes((CMD_READ | servo_id, param))
        if candidate != own and candidate not in avoid:
            return GuardRead(servo_id, param)
    last = avoid[-1] if avoid else b""
    for param in order:
        candidate = bytes((CMD_READ | servo_id, param))
        if candidate == last and candidate != own:
            return GuardRead(servo_id, param)
    others = dict.fromkeys(sent[0] & MAX_ID for sent in reversed(avoid) if sent)
    others.update(dict.fromkeys(range(MAX_ID + 1)))
    others.pop(servo_id, None)
    for other in others:
        for param in (Param.STRETCH, Param.SPEED):
            if bytes((CMD_READ | other, param)) not in avoid:
                return GuardRead(other, param)
    return GuardRead(servo_id, order[0])  # (never: ``avoid`` as the engine keeps it is shorter than that)


class ReadEeprom(Command[Eeprom]):
    """Parameter read SC 0: the 64-byte EEPROM image."""

    __slots__ = ()
    changes_nothing = True

    def __init__(self, servo_id: int) -> None:
        self.servo_id = check_id(servo_id)
        self.name = _READ_NAMES[Param.EEPROM]
        self.tx = bytes((CMD_READ | self.servo_id, Param.EEPROM))
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
        self.param = Param(check_int("parameter", param, 1, 4))
        self.name = _WRITE_NAMES[self.param]
        low, high = WRITE_RANGES[self.param]
        self.value = check_int(self.name.removeprefix("write_").replace("_", " "), value, low, high)
        self.tx = bytes((CMD_WRITE | self.servo_id, self.param, self.value))
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
    """Parameter write SC 0: all 64 EEPROM bytes at once (persists; slow reply).

    ``eeprom`` is checked before any byte is made: a header or baud code the
    reference does not define (:meth:`Eeprom.check_writable`), and every field
    within the reference's range (:meth:`Eeprom.check_values`).  ``current``:
    the image the servo holds now (read just before); then only the fields
    that differ from it are range-checked, so a value the servo already holds
    outside the ranges (unused flag bits it reports set) is written back as
    read; its read-only flags must stay.

    Raises:
        InvalidArgument: ``eeprom`` (or ``current``) is not an ``Eeprom``, or it holds a value it may not.
    """

    __slots__ = ("eeprom",)
    idempotent = False
    timing = Timing.EEPROM_WRITE

    def __init__(self, servo_id: int, eeprom: Eeprom, *, current: Eeprom | None = None) -> None:
        servo_id = check_id(servo_id)
        if not isinstance(eeprom, Eeprom):
            raise InvalidArgument(f"eeprom must be an Eeprom, not {type(eeprom).__name__}")
        eeprom.check_writable()  # an undefined header or baud code is read, never written
        eeprom.check_values(current)  # (InvalidArgument for a current that is not an Eeprom too)
        self._frame(servo_id, eeprom)

    @classmethod
    def heard(cls, servo_id: int, eeprom: Eeprom) -> WriteEeprom:
        """The command as a device frames it off the wire (the simulator, a sniffer): the image as the host
        sent it, its values unchecked (a host writes a servo's own out-of-range values back as read); one
        with an undefined header or baud code is not framed (InvalidArgument), as no host sends it.

        Sent by a host, it is the one EEPROM write whose ranges are not checked: the raw way, for trying
        what a servo makes of such a value, never for a setting (use ``WriteEeprom(id, image, current=...)``).
        """
        command = cls.__new__(cls)
        eeprom.check_writable()
        command._frame(check_id(servo_id), eeprom)
        return command

    def _frame(self, servo_id: int, eeprom: Eeprom) -> None:
        self.servo_id = servo_id
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
    changes_nothing = True
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


class LineIdRead(ReadId):
    """The ID read a scan sends first at a rate, asking the whole line whether anything answers there:
    silence (no servo at this rate) is its usual answer."""

    __slots__ = ()

    silence = "no reply to the ID read: nothing on the line answers at this baud rate"


class WriteId(Command[int]):
    """ID write: gives the new ID to every device on the line."""

    __slots__ = ("new_id",)
    idempotent = False
    timing = Timing.ID

    def __init__(self, new_id: int) -> None:
        self.new_id = check_id(new_id)
        self.servo_id = None
        self.name = "write_id"
        self.tx = bytes((CMD_ID | self.new_id, 1, 1, 1))
        self.reply_len = 1

    def parse(self, reply: bytes) -> int:
        self._check_length(reply)
        self._check_header(reply, self.tx[0])
        return self.new_id

    def encode_reply(self, value: int) -> bytes:
        return bytes((CMD_ID | value,))
