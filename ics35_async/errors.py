"""The error hierarchy, rooted at :class:`IcsError`.

Argument errors also subclass :class:`ValueError` and are raised before any
byte exists, so a bad call never reaches the wire.  Reply errors carry the
command, the servo ID and the raw bytes, so a log line is enough to debug a
wiring or baud problem.
"""

from __future__ import annotations

from typing import Required, Self, TypedDict, Unpack


class IcsError(Exception):
    """Base of every error this library raises on purpose."""


class InvalidArgument(IcsError, ValueError):
    """An argument is out of range or of the wrong kind; nothing was sent."""


class FileContentError(InvalidArgument):
    """A file (or mapping) breaks a rule of its format; ``source`` names it, ``key`` the dotted key.

    The robot's description and motion errors are its kinds.
    """

    def __init__(self, source: str, key: str, message: str) -> None:
        self.source = source
        self.key = key
        super().__init__(f"{source}: {key}: {message}" if key else f"{source}: {message}")


class UnsafeOperation(InvalidArgument):
    """A dangerous write (ID write, baud change) was not explicitly confirmed."""


class PositionReadUnsupported(IcsError):
    """The servo speaks ICS 3.5: it has no position read (ICS 3.6's ``0xA0|id, 0x05``); nothing was freed.

    ``servo_id`` names it.  ICS 3.5 reads a position only with the free
    command, which turns the torque off: :meth:`Servo.free` does that, and says so.
    """

    def __init__(self, message: str, *, servo_id: int) -> None:
        self.servo_id = servo_id
        super().__init__(message)


class MalformedEeprom(IcsError, ValueError):
    """A 64-byte EEPROM image breaks the format (length, nibbles)."""


class ReplyErrorFields(TypedDict, total=False):
    """The failed transaction a [`ReplyError`][ics35_async.errors.ReplyError] is about (its keyword arguments)."""

    command: Required[str]
    """The command's name, e.g. ``"position"``."""
    servo_id: Required[int | None]
    """The addressed ID; ``None`` for the ID command, which addresses the whole line."""
    raw: bytes
    """Every byte received for the transaction, echo included (default none)."""


class ReplyError(IcsError):
    """A transaction did not produce a valid reply.

    ``command`` names the command (e.g. ``"position"``), ``servo_id`` is the
    addressed ID (``None`` for the ID command, which addresses the whole line)
    and ``raw`` holds every byte received for the transaction, echo included; ``reason`` says what went wrong
    alone (the message is ``"<command> to ID <n>: <reason> (raw: <bytes>)"``).
    """

    def __init__(self, message: str, **fields: Unpack[ReplyErrorFields]) -> None:
        command, servo_id = fields["command"], fields["servo_id"]
        self.reason = message
        self.command = command
        self.servo_id = servo_id
        self.raw = bytes(fields.get("raw", b""))
        where = f"{command} to ID {servo_id}" if servo_id is not None else command
        super().__init__(f"{where}: {message} (raw: {self.raw.hex(' ') or 'nothing'})")


class ReplyTimeout(ReplyError, TimeoutError):
    """No byte of the reply arrived before the deadline (also a :class:`TimeoutError`)."""


class PartialReply(ReplyError):
    """Only part of the reply arrived before the deadline."""

    def __init__(
        self, message: str, *, received: int = 0, expected: int = 0, **fields: Unpack[ReplyErrorFields]
    ) -> None:
        self.received = received
        self.expected = expected
        super().__init__(message, **fields)


class EchoMismatch(ReplyError):
    """The echo of our own bytes came back different: a collision, noise, or bytes ahead of it.

    ``echo_at`` is where the echo of what was written starts in ``raw`` (whole, or its first
    bytes where ``raw`` ends), -1 if it is not there.  Further on than the first byte, the
    echo did come, behind bytes that were already on their way (a late reply to an earlier command).
    """

    def __init__(self, message: str, *, echo_at: int = -1, **fields: Unpack[ReplyErrorFields]) -> None:
        self.echo_at = echo_at
        super().__init__(message, **fields)

    @property
    def echo_behind(self) -> bool:
        """The echo came, behind other bytes: not a collision, not an interface without echo."""
        return self.echo_at > 0


class BadReply(ReplyError):
    """A complete reply arrived but breaks the protocol rules."""


class ReplyLengthError(BadReply):
    """The reply has the wrong number of bytes."""


class ReplyHeaderError(BadReply):
    """The reply's command byte (and so its ID) is not the expected one."""


class ReplySubcommandError(BadReply):
    """The reply does not echo the sub-command (or memory address/count)."""


class ReplyValueError(BadReply):
    """A parameter write's reply does not echo the value written."""


class ReplyDataError(BadReply):
    """A data byte breaks its encoding (MSB set, or a nibble above 0x0F)."""


class VerifyError(IcsError):
    """A write could not be confirmed: what was read back, or the ID that answers afterwards, is not what was
    written (the message says what is known of what the servo holds)."""


class BusClosed(IcsError):
    """The bus is closed; the request was not (or no longer) carried out."""


class ClosedByPortLoss(BusClosed):
    """A call on a bus that closed itself when its port was lost (opened without ``reconnect``) or could not
    be reopened: a :class:`BusClosed`, as every call on a closed bus, whose message says what happened to
    the port.  (Not a :class:`PortLost`: a loop that waits out a lost port to go on would wait forever.)"""


class PortLost(IcsError):
    """The serial port failed or disappeared while the request was pending."""


class SerialPortError(IcsError, OSError):
    """The serial port could not be opened or set up as the ICS line needs.

    Also an :class:`OSError`, so code that already handles I/O errors keeps
    working; ``errno`` is set when the system gave one.
    """

    def __str__(self) -> str:
        # The words a program prints are for a person: OSError's "[Errno 2] " in front of them is noise
        # (the number stays in ``errno`` for code).
        return error_text(self) if self.strerror else super().__str__()

    def reworded(self, text: str) -> Self:
        """The same error in the words ``text`` (a caller adding what it knows): the same class and errno, so code
        that tells a missing port from a busy one still can."""
        again = type(self)(text) if self.errno is None else type(self)(self.errno, text)
        again.__dict__.update(self.__dict__)  # (what it was marked with: PortNotFound.may_be_plugged_in)
        return again


class PortNotFound(SerialPortError, FileNotFoundError):
    """No device exists at that path."""

    # The name is a device's that may yet be plugged in (not a misnamed port, nor a stopped simulator's pty): what
    # a bus that reconnects adds words for (it does not wait for a port missing as it opens).
    may_be_plugged_in: bool = False


class PortPermissionDenied(SerialPortError, PermissionError):
    """The device exists but this user may not open it."""


class PortBusy(SerialPortError):
    """Another program (or another line in this one) holds the port."""


class ParityNotSupported(SerialPortError):
    """The driver silently refused EVEN parity, which ICS 3.5 requires."""


class DirectionControlNotSupported(SerialPortError):
    """The port's driver refused RS-485 direction control (RTS toggled while sending)."""


def error_text(exc: BaseException) -> str:
    """An error's words for a person: an OSError's without the ``[Errno 2]`` in front of them."""
    if isinstance(exc, OSError) and exc.strerror:
        named = exc.filename is None or str(exc.filename) in exc.strerror
        return exc.strerror if named else f"{exc.strerror}: {exc.filename}"
    return str(exc) or type(exc).__name__
