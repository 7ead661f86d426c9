"""The generic commands (0xA0 / 0xC0 with SC 0x7F): a non-servo device's 128-byte memory.

Every memory byte travels as two nibble bytes, high nibble first (spec section 9).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TypeVar

from ..errors import InvalidArgument, ReplyDataError, ReplyHeaderError, ReplySubcommandError
from ..units import check_int
from .commands import Command
from .wire import CMD_READ, CMD_WRITE, MEMORY_SIZE, SC_MEMORY, bytes_from_nibbles, check_id, nibbles_from_bytes

T = TypeVar("T")


def check_span(address: object, count: object) -> tuple[int, int]:
    address = check_int("address", address, 0, MEMORY_SIZE - 1)
    count = check_int("count", count, 1, MEMORY_SIZE - 1)
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
    changes_nothing = True

    def __init__(self, device_id: int, address: int, count: int) -> None:
        self.servo_id = check_id(device_id)
        self.address, self.count = check_span(address, count)
        self.name = "read_memory"
        self.tx = bytes((CMD_READ | self.servo_id, SC_MEMORY, self.address, self.count))
        self.reply_len = 4 + 2 * self.count  # (the checked count: a Python int, whatever number was given)

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
        self.address, self.count = check_span(address, len(payload))
        self.data = payload
        self.name = "write_memory"
        self.tx = bytes((CMD_WRITE | self.servo_id, SC_MEMORY, self.address, self.count)) + nibbles_from_bytes(payload)
        self.reply_len = 4

    def parse(self, reply: bytes) -> None:
        self._check_length(reply)
        self._check_memory_header(reply)

    def encode_reply(self, value: None) -> bytes:
        return self.tx[:4]
