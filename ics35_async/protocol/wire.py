"""The line's constants and byte-level helpers: command bytes, sub-commands, 7-bit and nibble packing.

Everything else in :mod:`ics35_async.protocol` builds on these; nothing here
knows about a particular command's reply rules.
"""

from __future__ import annotations

import enum
from collections.abc import Iterable

from ..eeprom import BaudRate
from ..units import POSITION_MAX as POSITION_MAX  # (the 14-bit position field: units keeps the one number)
from ..units import check_int

BITS_PER_BYTE = 11  # start + 8 data + even parity + stop
# Seconds an interface may add to a reply by default (USB adapters add 0.1-16 ms: the FTDI latency timer), the
# most retries a request may have, and the retries the tools (the ics35 commands, the configurator) give a line
# unless told otherwise: one, so that a single reply lost on a healthy line does not fail a person's command (a
# program's bus has none unless it asks).  Kept here, below everything that reads them (the engine's timing, the
# bus, a robot file, the configurator, the CLI's line options, which load no engine to show --help).
ADAPTER_LATENCY = 0.020
MAX_RETRIES = 10
TOOL_RETRIES = 1
MAX_ID = 31
ALL_IDS: tuple[int, ...] = tuple(range(MAX_ID + 1))
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


# ICS 3.6's position read: 0xA0|id, SC_POSITION -> 0x20|id, SC_POSITION, pos_hi, pos_lo (ICS 3.5 stays silent).
SC_POSITION = 0x05

# Valid write ranges for SC 1..4.
WRITE_RANGES: dict[Param, tuple[int, int]] = {
    Param.STRETCH: (1, 127),
    Param.SPEED: (1, 127),
    Param.CURRENT: (1, 63),
    Param.TEMPERATURE: (1, 127),
}


class Timing(enum.Enum):
    """Which deadline allowance a command needs (the bus maps these to seconds)."""

    NORMAL = "normal"
    EEPROM_WRITE = "eeprom_write"  # the servo answers noticeably later
    ID = "id"
    PROBE = "probe"  # asks whether anybody is there: silence is the usual answer (see ProbeRead)
    SILENT = "silent"  # to a servo already found silent: its reply would only confirm (see SilentFree)


def wire_time(nbytes: int, baudrate: int) -> float:
    """Seconds the line needs for ``nbytes`` bytes at ``baudrate``."""
    return nbytes * BITS_PER_BYTE / baudrate


def check_id(servo_id: object) -> int:
    return check_int("servo ID", servo_id, 0, MAX_ID)


def id_runs(ids: Iterable[int]) -> list[list[int]]:
    """``ids`` sorted, without repeats, in runs of neighbours: ``[[0], [4, 5, 6]]``."""
    runs: list[list[int]] = []
    for i in sorted(set(ids)):
        if runs and i == runs[-1][-1] + 1:
            runs[-1].append(i)
        else:
            runs.append([i])
    return runs


def id_ranges(ids: Iterable[int]) -> str:
    """``0, 4-31``, for a person: a run of three or more IDs as a range (29 empty IDs in one short line), the
    rest one by one."""
    return ", ".join(f"{r[0]}-{r[-1]}" if len(r) >= 3 else ", ".join(map(str, r)) for r in id_runs(ids)) or "none"


def ids_named(ids: Iterable[int]) -> str:
    """``ID 4`` or ``IDs 0, 4-31`` (:func:`id_ranges`): one ID is no plural ("asking IDs 1")."""
    listed = list(ids)  # (an iterator is read once)
    return f"ID {listed[0]}" if len(set(listed)) == 1 else f"IDs {id_ranges(listed)}"


def no_servo_among(ids: Iterable[int]) -> str:
    """``no servo among 1-4`` or, of one ID, ``no servo at ID 1`` (not "among 1")."""
    listed = list(ids)
    return f"no servo at ID {listed[0]}" if len(set(listed)) == 1 else f"no servo among {id_ranges(listed)}"


def check_retries(retries: object) -> int:
    return check_int("retries", retries, 0, MAX_RETRIES)


ALL_BAUDS: tuple[int, ...] = tuple(int(b) for b in BaudRate)
_BAUD_BY_INT = {int(b): b for b in BaudRate}  # check_baud's common case, without building an enum member


def check_baud(baudrate: object) -> BaudRate:
    if type(baudrate) is int or type(baudrate) is BaudRate:
        known = _BAUD_BY_INT.get(baudrate)
        if known is not None:
            return known
    return BaudRate.parse(baudrate)


def echo_offset(buf: bytes | bytearray, tx: bytes, start: int) -> int:
    """Where, from ``start`` on, ``tx``'s echo starts in ``buf`` (at least its first two bytes if
    ``buf`` ends before the rest); -1 if nowhere.  Bytes ahead of an echo were already on their way."""
    k = buf.find(tx, start)
    if k >= 0:
        return k
    n = len(buf)
    for k in range(max(start, n - len(tx) + 1), n - 1):
        if buf[k:] == tx[: n - k]:
            return k
    return -1


def join7(high: int, low: int) -> int:
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
