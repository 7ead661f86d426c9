"""What went wrong with a transaction, judged from the bytes that did arrive."""

from __future__ import annotations

from typing import Any

from ..errors import BadReply, EchoMismatch, PartialReply, ReplyDataError, ReplyError, ReplyTimeout
from ..protocol.wire import echo_offset
from .counters import NO_ID
from .requests import Request


def _error(
    cls: type[ReplyError], message: str, req: Request | None, sid: int, buf: bytes | bytearray, **extra: Any
) -> ReplyError:
    """A ``cls`` error about the transaction on the wire, carrying every byte received."""
    return cls(
        message,
        command=req.command.name if req is not None else "position",
        servo_id=None if sid == NO_ID else sid,
        raw=bytes(buf),
        **extra,
    )


def echo_mismatch(req: Request | None, sid: int, tx: bytes, buf: bytes | bytearray) -> ReplyError:
    """The echo is not the bytes sent: changed on the wire, missing, or behind other bytes."""
    ahead = echo_offset(buf, tx, 1)
    if ahead > 0:  # the echo came (whole, or cut off by the byte count), behind bytes already on their way
        message = f"{ahead} byte(s) ahead of the echo (a late reply to an earlier command?)"
    else:
        message = f"echo differs from the bytes sent ({tx.hex(' ')})"
    return _error(EchoMismatch, message, req, sid, buf, echo_at=ahead)


def framing_error(
    req: Request | None, sid: int, tx: bytes, buf: bytearray, echo_len: int, expect: int, corrupted: bool
) -> ReplyError:
    """All bytes are in but the transaction is wrong: a damaged byte, a wrong echo, or extra bytes."""
    if corrupted:
        message = "a byte arrived with a parity or framing error (noise on the line?)"
        return _error(ReplyDataError, message, req, sid, buf)
    if echo_len and not buf.startswith(tx):
        # (Before counting bytes: a late reply read in one chunk with this echo and reply makes more bytes than
        # expected, and it is the late reply, not extra bytes after this one, that a reader must be told of.)
        return echo_mismatch(req, sid, tx, buf)
    if len(buf) > expect:
        extra = len(buf) - expect
        if req is not None and req.command.servo_id is None:  # the ID command: every device answers it
            message = f"{extra} extra byte(s) after the reply: more than one device answering the ID command?"
            return _error(BadReply, message, req, sid, buf)
        return _error(BadReply, f"{extra} unexpected extra byte(s) after the reply", req, sid, buf)
    return echo_mismatch(req, sid, tx, buf)


def timeout_error(req: Request | None, sid: int, tx: bytes, buf: bytearray, echo_len: int, expect: int) -> ReplyError:
    """The deadline passed: what arrived says whether the echo, the servo or the reply's tail is missing."""
    got = len(buf)
    if echo_len and buf[: min(got, echo_len)] != tx[: min(got, echo_len)]:
        return echo_mismatch(req, sid, tx, buf)
    silence = req.command.silence if req is not None else None  # (a probe's: see .probe)
    if got == 0 and echo_len:
        # (A USB adapter that holds bytes back longer than the allowance looks the same as none at all.)
        return _error(
            ReplyTimeout,
            "no echo and no reply: is the adapter connected? (one that holds bytes back past the reply "
            "allowance, as an FTDI latency timer of 16 ms can, looks the same)",
            req,
            sid,
            buf,
        )
    if got <= echo_len:
        return _error(ReplyTimeout, silence or "no reply (check ID, baud rate, power)", req, sid, buf)
    n, m = got - echo_len, expect - echo_len
    return _error(PartialReply, f"{n} of {m} reply bytes", req, sid, buf, received=n, expected=m)
