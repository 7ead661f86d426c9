"""The device side: framing a host byte stream into commands, as a servo on the line hears it.

The simulator answers what :func:`decode_request` frames with each command's
``encode_reply``, so the wire rules live only in the command classes.
"""

from __future__ import annotations

from typing import Any, Literal

from ..eeprom import EEPROM_SIZE, Eeprom
from ..errors import InvalidArgument, MalformedEeprom
from .commands import (
    Command,
    Position,
    ReadEeprom,
    ReadId,
    ReadParam,
    ReadPosition,
    WriteEeprom,
    WriteId,
    WriteParam,
)
from .memory import ReadMemory, WriteMemory, check_span
from .wire import (
    CMD_ID,
    CMD_POSITION,
    CMD_READ,
    SC_MEMORY,
    SC_POSITION,
    WRITE_RANGES,
    Param,
    bytes_from_nibbles,
    check_baud,
    join7,
)


def _not_whole(buf: bytes | bytearray, end: int) -> tuple[None, int] | Literal[False] | None:
    """What to answer until the frame ``buf[:end]`` is whole; ``False`` once it is.

    A data byte with its MSB set (as far as the frame has arrived) starts the next command:
    drop only this frame's command byte.  Bytes still missing: wait (``None``).
    """
    if any(b & 0x80 for b in buf[1:end]):
        return None, 1
    if len(buf) < end:
        return None
    return False


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
        if (early := _not_whole(buf, 3)) is not False:
            return early
        return Position(sid, join7(buf[1], buf[2]), baudrate=baud), 3
    if len(buf) < 2:
        return None
    sc = buf[1]
    if sc & 0x80:
        return None, 1
    if kind == CMD_ID:
        if (early := _not_whole(buf, 4)) is not False:
            return early
        if buf[1] == buf[2] == buf[3] == 0:
            return ReadId(sid), 4
        if buf[1] == buf[2] == buf[3] == 1:
            return WriteId(sid), 4
        return None, 4
    if sc == SC_MEMORY:
        if (early := _not_whole(buf, 4)) is not False:
            return early
        address, count = buf[2], buf[3]
        try:
            check_span(address, count)
        except InvalidArgument:
            return None, 4
        if kind == CMD_READ:
            return ReadMemory(sid, address, count), 4
        total = 4 + 2 * count
        if (early := _not_whole(buf, total)) is not False:
            return early
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
        if sc == SC_POSITION:
            return ReadPosition(sid), 2
        return None, 2
    # parameter write
    if sc == Param.EEPROM:
        total = 2 + EEPROM_SIZE
        if (early := _not_whole(buf, total)) is not False:
            return early
        try:
            return WriteEeprom.heard(sid, Eeprom.from_bytes(bytes(buf[2:total]))), total
        except (MalformedEeprom, InvalidArgument):  # InvalidArgument: a code the reference does not define
            return None, total
    if sc not in WRITE_RANGES:
        return None, 2
    if (early := _not_whole(buf, 3)) is not False:
        return early
    try:
        return WriteParam(sid, sc, buf[2]), 3
    except InvalidArgument:
        return None, 3
