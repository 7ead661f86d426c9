"""Decoding a line one only listens to: every byte heard once, commands and replies in one stream.

A second adapter whose receive pin sits on a line another controller drives
(an RCB-4 board, an Arduino, an ESP32) hears the controller's commands and
the servos' replies, each once.  :class:`LineListener` cuts that stream into
transactions with the codec's own rules: a byte with its top bit set starts a
command (:func:`~.device.decode_request` frames it and says its length), the
command says how long its reply is and what its first byte looks like, and
the reply parses with the command's own :meth:`~.commands.Command.parse`.
Where byte values leave it open (the ID command's reply, and a position
reply from ID 0 at 115200, keep their top bit), the gap between bytes
decides: a reply follows its command at once, so bytes after a pause longer
than ``gap`` start something new.  Bytes that fit nothing are reported as
``unknown`` and the listener picks up again at the next command byte.

Sans-IO: :meth:`LineListener.feed` takes bytes with the time they were
heard; :meth:`LineListener.poll` closes a transaction whose reply never came
once ``gap`` has passed.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from ..eeprom import FACTORY_BAUD
from ..errors import IcsError
from .commands import Command, Position, ReadId, WriteId
from .device import decode_request
from .memory import ReadMemory, WriteMemory
from .wire import check_baud

DEFAULT_GAP = 5e-3
"""Seconds of silence after which a listener stops waiting for a reply.  Servos answer within
about 100 us (an EEPROM write takes longer); a controller waits at least a few ms before its next
command.  Timestamps from a USB adapter come in packets, so set its latency timer to 1 ms."""


@dataclass(frozen=True)
class HeardTransaction:
    """One transaction heard on the line.

    ``t``: when its first byte was heard (seconds, the caller's clock);
    ``kind``: the command's name (``position``, ``free``, ``read_temperature``,
    ...) or ``unknown`` for bytes that fit no command; ``sent``/``reply``: the
    bytes (``reply`` empty when none came); ``value``: the decoded reply
    (``None`` when there is none, or it did not parse: see ``error``).
    """

    t: float
    kind: str
    servo_id: int | None
    sent: bytes
    reply: bytes = b""
    value: Any = None
    error: str | None = None

    def value_json(self) -> Any:
        """``value`` as JSON can carry it (an EEPROM image as its fields, memory bytes as hex)."""
        value = self.value
        if hasattr(value, "to_dict"):
            return value.to_dict()
        if isinstance(value, bytes):
            return value.hex()
        return value

    def to_dict(self) -> dict[str, Any]:
        return {
            "t": round(self.t, 6),
            "kind": self.kind,
            "id": self.servo_id,
            "sent": self.sent.hex(" "),
            "reply": self.reply.hex(" "),
            "value": self.value_json(),
            "error": self.error,
        }


def _reply_headers(command: Command[Any]) -> range | frozenset[int]:
    """The first bytes a reply to ``command`` may start with."""
    if isinstance(command, (ReadId, WriteId)):
        return range(0xE0, 0x100)  # the answering servo's own ID, top bit set
    if isinstance(command, Position):
        return frozenset({command.reply_header})
    if isinstance(command, (ReadMemory, WriteMemory)):
        return frozenset({command.tx[0], command.tx[0] & 0x7F})  # the reference shows both forms
    return frozenset({command.tx[0] & 0x7F})


class LineListener:
    """Cuts the heard byte stream of a line at ``baudrate`` into :class:`HeardTransaction` s."""

    def __init__(self, baudrate: int = FACTORY_BAUD, *, gap: float = DEFAULT_GAP) -> None:
        self.baudrate = check_baud(baudrate)
        self.gap = gap
        self._sent = bytearray()  # a command (or junk) still arriving
        self._start = 0.0
        self._junk = bytearray()
        self._junk_start = 0.0
        self._command: Command[Any] | None = None
        self._command_bytes = b""
        self._reply = bytearray()
        self._last = 0.0

    def feed(self, data: bytes, t: float) -> list[HeardTransaction]:
        """Bytes heard at ``t``: the transactions they complete (and any they prove over)."""
        out = self.poll(t)
        for byte in data:
            self._byte(byte, t, out)
            self._last = t
        return out

    def poll(self, now: float) -> list[HeardTransaction]:
        """Close what the silence since the last byte has ended (a reply that did not come)."""
        out: list[HeardTransaction] = []
        if now - self._last > self.gap:
            self._end_command(out, "no reply" if not self._reply else "reply cut off")
            if self._sent:
                self._junk_start = self._junk_start if self._junk else self._start
                self._junk += self._sent
                self._sent.clear()
            self._end_junk(out)
        return out

    def flush(self) -> list[HeardTransaction]:
        """Everything still open (end of input)."""
        return self.poll(self._last + self.gap + 1.0)

    # -- the byte machine

    def _byte(self, byte: int, t: float, out: list[HeardTransaction]) -> None:
        if self._command is not None and t - self._last > self.gap:
            self._end_command(out, "no reply" if not self._reply else "reply cut off")
        command = self._command
        if command is not None:
            if not self._reply:
                if byte & 0x80 == 0 or byte in _reply_headers(command):
                    self._reply.append(byte)
                    self._maybe_complete(out)
                    return
                self._end_command(out, "no reply")
            elif byte & 0x80:
                self._end_command(out, "reply cut off")  # data bytes never have the top bit: a new command
            else:
                self._reply.append(byte)
                self._maybe_complete(out)
                return
        if self._sent and t - self._last > self.gap:
            self._junk_start = self._junk_start if self._junk else self._start
            self._junk += self._sent  # a command that never finished
            self._sent.clear()
        if not self._sent:
            if not byte & 0x80:
                if not self._junk:
                    self._junk_start = t
                self._junk.append(byte)
                return
            self._start = t
        self._sent.append(byte)
        self._frame(out)

    def _frame(self, out: list[HeardTransaction]) -> None:
        while self._sent:
            framed = decode_request(self._sent, baudrate=self.baudrate)
            if framed is None:
                return
            command, used = framed
            if command is None:
                if not self._junk:
                    self._junk_start = self._start
                self._junk += self._sent[:used]
                del self._sent[:used]
                while self._sent and not self._sent[0] & 0x80:
                    self._junk.append(self._sent.pop(0))
                continue
            self._end_junk(out)
            self._command = command
            self._command_bytes = bytes(self._sent[:used])
            del self._sent[:used]
            self._reply.clear()
            return

    def _maybe_complete(self, out: list[HeardTransaction]) -> None:
        command = self._command
        assert command is not None
        if len(self._reply) < command.reply_len:
            return
        reply = bytes(self._reply)
        try:
            value, error = command.parse(reply), None
        except IcsError as exc:
            value, error = None, str(exc)
        out.append(
            HeardTransaction(self._start, command.name, command.servo_id, self._command_bytes, reply, value, error)
        )
        self._command = None
        self._reply.clear()

    def _end_command(self, out: list[HeardTransaction], why: str) -> None:
        command = self._command
        if command is None:
            return
        out.append(
            HeardTransaction(
                self._start, command.name, command.servo_id, self._command_bytes, bytes(self._reply), None, why
            )
        )
        self._command = None
        self._reply.clear()

    def _end_junk(self, out: list[HeardTransaction]) -> None:
        if self._junk:
            out.append(HeardTransaction(self._junk_start, "unknown", None, bytes(self._junk), error="fits no command"))
            self._junk.clear()
