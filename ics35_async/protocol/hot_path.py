"""Position-command helpers for the streaming hot path: no object per frame, no validation.

Callers validate IDs, positions and the baud rate beforehand (the
:class:`~ics35_async.protocol.Position` command does, and uses these same
helpers, so the bytes cannot drift apart).
"""

from __future__ import annotations

from ..eeprom import BaudRate
from .wire import CMD_POSITION


def position_tx(servo_id: int, position: int) -> bytes:
    return bytes((CMD_POSITION | servo_id, (position >> 7) & 0x7F, position & 0x7F))


_B115200 = int(BaudRate.B115200)


def position_reply_header(servo_id: int, baudrate: int) -> int:
    """The first byte of a position reply; ID 0 at 115200 keeps the MSB (ICS 2.0)."""
    cmd = CMD_POSITION | servo_id
    return cmd if (servo_id == 0 and baudrate == _B115200) else cmd & 0x7F


# What position_from_reply checks, as bytes a burst executor compares under a mask (no rule in C):
# the header exactly, the two data bytes' MSB clear.
_POSITION_REPLY_MASKS = bytes((0xFF, 0x80, 0x80))


def position_reply_shape(header: int) -> bytes:
    """The shape of a valid position reply with ``header``: three bytes wanted, then three masks (a
    reply ``r`` has it when ``r[i] & mask[i] == wanted[i]``): exactly the replies
    :func:`position_from_reply` takes (tests/test_protocol.py checks every reply)."""
    return bytes((header, 0, 0)) + _POSITION_REPLY_MASKS


def position_from_reply(buf: bytes | bytearray, offset: int, header: int) -> int:
    """The position in a 3-byte position reply at ``buf[offset:]``, or -1 if invalid.

    The streaming hot path's check; on -1, :meth:`Position.parse` gives the typed error.
    """
    high, low = buf[offset + 1], buf[offset + 2]
    if buf[offset] != header or (high | low) & 0x80:
        return -1
    return (high << 7) | low
