"""ICS 3.5 wire codec (and ICS 3.6's position read), sans-IO: every command's bytes, lengths and reply rules.

The package's modules, each with one job:

- :mod:`.wire`: the line's constants, :class:`Param`, :class:`Timing`, 7-bit and nibble packing;
- :mod:`.hot_path`: allocation-free position helpers for the streaming hot path;
- :mod:`.commands`: the servo commands (host side) and their base class :class:`Command`;
- :mod:`.memory`: the generic commands for non-servo devices' memory;
- :mod:`.device`: :func:`decode_request`, the device side's framing of a host byte stream;
- :mod:`.listening`: a line one only listens to, cut into transactions (``ics35 sniff``).

Import from the package (``from ics35_async.protocol import X``); the split is an
implementation detail.
"""

from ..eeprom import EEPROM_SIZE, BaudRate, Eeprom
from .commands import (
    Command,
    GuardRead,
    LineIdRead,
    Position,
    ProbeFree,
    ProbeRead,
    ProbeReadPosition,
    ReadEeprom,
    ReadId,
    ReadParam,
    ReadPosition,
    SecondLookFree,
    SecondLookRead,
    SecondLookReadPosition,
    SilentFree,
    WriteEeprom,
    WriteId,
    WriteParam,
    guard_read,
)
from .device import decode_request
from .hot_path import position_from_reply, position_reply_header, position_reply_shape, position_tx
from .memory import ReadMemory, WriteMemory
from .wire import (
    ADAPTER_LATENCY,
    BITS_PER_BYTE,
    CMD_ID,
    CMD_POSITION,
    CMD_READ,
    CMD_WRITE,
    FREE,
    MAX_ID,
    MAX_RETRIES,
    MEMORY_SIZE,
    POSITION_MAX,
    SC_MEMORY,
    SC_POSITION,
    TOOL_RETRIES,
    WRITE_RANGES,
    Param,
    Timing,
    bytes_from_nibbles,
    check_baud,
    check_id,
    check_retries,
    join7,
    nibbles_from_bytes,
    split7,
    wire_time,
)

__all__ = [
    "ADAPTER_LATENCY",
    "BITS_PER_BYTE",
    "CMD_ID",
    "CMD_POSITION",
    "CMD_READ",
    "CMD_WRITE",
    "EEPROM_SIZE",
    "FREE",
    "MAX_ID",
    "MAX_RETRIES",
    "MEMORY_SIZE",
    "POSITION_MAX",
    "SC_MEMORY",
    "SC_POSITION",
    "TOOL_RETRIES",
    "WRITE_RANGES",
    "BaudRate",
    "Command",
    "Eeprom",
    "Param",
    "Position",
    "ReadEeprom",
    "ReadId",
    "ReadMemory",
    "ProbeFree",
    "ProbeRead",
    "ProbeReadPosition",
    "GuardRead",
    "LineIdRead",
    "SecondLookFree",
    "SecondLookRead",
    "SecondLookReadPosition",
    "SilentFree",
    "ReadParam",
    "ReadPosition",
    "Timing",
    "WriteEeprom",
    "WriteId",
    "WriteMemory",
    "WriteParam",
    "bytes_from_nibbles",
    "check_baud",
    "check_id",
    "check_retries",
    "decode_request",
    "guard_read",
    "join7",
    "nibbles_from_bytes",
    "position_from_reply",
    "position_reply_header",
    "position_reply_shape",
    "position_tx",
    "split7",
    "wire_time",
]
