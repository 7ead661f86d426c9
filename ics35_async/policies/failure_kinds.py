"""What the policies need from a line (:class:`ics35_async.line.Line`), and how to tell its failures apart.

The policies use only that protocol, not the bus, so they survive a
rewrite of the core and can be driven by any object with its members
(``Bus`` from :func:`ics35_async.open_bus` is the usual one).
"""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator, Callable
from contextlib import AbstractAsyncContextManager
from typing import TypeVar

from ..errors import EchoMismatch, ReplyError, ReplyHeaderError, ReplyTimeout
from ..line import Line as Line
from ..protocol import Param, ReadParam, position_reply_header

T = TypeVar("T")


# A not-yet-open line at the given baud rate, used as ``async with open_at(baud) as line``
# (``lambda baud: open_bus(port, baudrate=baud)``).  Scans take this rather than one open
# line because a rate the adapter cannot do must not cost the line for the other rates.
LineOpener = Callable[[int], AbstractAsyncContextManager[Line]]


def reopening(line: Line) -> LineOpener:
    """``line`` as a :data:`.LineOpener`: "opened" at a rate, it is reopened there (and left so)."""

    @contextlib.asynccontextmanager
    async def at(baud: int) -> AsyncIterator[Line]:
        if baud != int(line.baudrate):
            await line.reopen(baudrate=baud)
        yield line

    return at


def nothing_came_back(exc: ReplyError) -> bool:
    """Whether the failed transaction of ``exc`` is plain silence: no reply byte (the echo alone may have come).

    The bus raises :class:`ReplyTimeout` only then; a reply cut short is a
    ``PartialReply`` and an echo that came back changed an ``EchoMismatch``.
    """
    return isinstance(exc, ReplyTimeout)


def echo_setting_wrong(exc: ReplyError, echo: bool) -> bool:
    """Whether ``exc`` shows that the line's echo setting does not match the interface.

    Every command byte has its most significant bit set and almost every reply
    header has it clear, so the first byte back tells an echo from a reply:
    expecting an echo and getting a reply first means the interface does not
    loop TX back; expecting none and getting a command byte first means it does.
    A reply ahead of an echo that did come (whole, or cut off by the byte count) is a late
    answer, not evidence.
    """
    if not exc.raw:
        return False
    if echo:
        return isinstance(exc, EchoMismatch) and exc.raw[0] < 0x80 and not exc.echo_behind
    return exc.raw[0] >= 0x80


async def answers_short_read(line: Line, servo_id: int) -> bool:
    """Whether ``servo_id`` answers a temperature read on ``line`` (2 bytes out, 3 back; nothing moves or frees).

    It tells whether an ID answers now (after an ID write whose acknowledgement was lost, before an
    EEPROM write gives a servo an ID); after a long command went unanswered (the EEPROM read's reply
    is 66 bytes), it tells a servo that is not there from one that half-answers.
    """
    try:
        await line.request(ReadParam(servo_id, Param.TEMPERATURE), retries=1)
    except ReplyError:
        return False
    return True


def id0_top_bit_differs(exc: ReplyError, baudrate: int) -> bool:
    """Whether ``exc`` is a position reply from ID 0 whose first byte is wrong in its top bit alone
    (``baudrate``: the line's rate, which decides the reply's form).

    ICS 3.5 servos answer a position command to ID 0 with the top bit set at
    115200 baud (ICS 2.0 compatibility) and clear at the other rates; a
    device that follows the rule the other way round fails exactly so.
    """
    if not isinstance(exc, ReplyHeaderError) or exc.servo_id != 0 or exc.command not in ("position", "free"):
        return False
    return bool(exc.raw) and exc.raw[0] ^ position_reply_header(0, baudrate) == 0x80
