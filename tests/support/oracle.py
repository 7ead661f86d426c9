"""What the bus must conclude from the bytes it received: the oracle of the reliability tests and soaks.

:class:`WirePredictor` rebuilds, from the simulator's log, the bytes the
bus received for each transaction and judges them by the bus's documented
rules (exact length, echo first, then the codec's checks).  Also here: the
chaos workload's servos and the rule that tells a stream transaction from
a request by its bytes, which both the tests and benchmarks/soak use.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass
from typing import Any

from ics35_async import (
    ReplyError,
    protocol,
)
from ics35_async.protocol import Command, Param, decode_request
from ics35_async.sim import (
    Transaction,
    VirtualServo,
)

FAULT_KINDS = ("drop", "truncate", "corrupt", "msb", "late", "noise", "echo")


class CheckError(AssertionError):
    """The log and the outcomes cannot be lined up: the checker (or the bus) lost track."""


# ====================================================================== what the bus must conclude


@functools.lru_cache(maxsize=1 << 16)
def _decode(tx: bytes, baudrate: int) -> Command[Any]:
    framed = decode_request(tx, baudrate=baudrate)
    if framed is None or framed[0] is None or framed[1] != len(tx):
        raise CheckError(f"the log holds bytes that are not one whole command: {tx.hex(' ')}")
    return framed[0]


@dataclass(frozen=True, slots=True)
class Verdict:
    """What the bus must make of one transaction: a value (``ok``) or an error of class ``error``.

    ``source`` says where the bytes in the reply's place came from: ``"own"``
    (this transaction's reply, possibly damaged in place), ``"stale"`` (they
    include the held-back reply of an earlier transaction) or ``"noise"``
    (they include noise bytes, e.g. after a truncated reply).
    """

    ok: bool
    value: Any
    error: str | None
    received: bytes
    source: str = "own"


class WirePredictor:
    """Rebuilds, from the simulator's log, the bytes the bus received for each transaction.

    In fast mode the simulator answers each host write with one chunk:
    the echo (as damaged by an ``echo`` fault), then a reply held back by a
    ``late`` fault of the previous transaction, then this transaction's
    reply (none if it is held back itself), then ``noise``.  The log keeps
    all the parts (``echo``, ``extra`` = held reply + noise, ``reply``,
    ``clean_reply``), so the chunk, and therefore the one right conclusion,
    follow.  Feed every logged transaction, in order, to :meth:`predict`.
    ``noise`` is the noise bytes at the end of the last transaction's chunk (across a real port they
    may come after the bus has taken the reply: see :class:`.matcher.LogMatcher`).
    """

    def __init__(self, baudrate: int, echo: bool = True) -> None:
        self.baudrate = baudrate
        self.echo = echo
        self.held = b""
        self.noise = b""

    def predict(self, t: Transaction) -> Verdict:
        held, self.held = self.held, b""
        faults = t.fault.split("+") if t.fault else ()
        if "late" in faults:
            own = b""
            self.held = t.clean_reply
        else:
            own = t.reply
        if not t.extra.startswith(held):
            raise CheckError(f"seq {t.seq}: the held-back reply {held.hex()} is not where expected: {t.extra.hex()}")
        noise = self.noise = t.extra[len(held) :]
        received = t.echo + held + own + noise
        verdict = self.judge(t.tx, received)
        if verdict.ok:
            # The reply's place starts right after the echo (intact, since the verdict is ok).
            if held:
                verdict = dataclasses.replace(verdict, source="stale")
            elif len(own) < len(received) - len(t.echo):
                verdict = dataclasses.replace(verdict, source="noise")
        return verdict

    def judge(self, tx: bytes, received: bytes) -> Verdict:
        """The bus's rules, as documented: the echo first (bytes ahead of it or in its place), then the exact
        length, then the codec's checks."""
        command = _decode(tx, self.baudrate)
        echo_len = len(tx) if self.echo else 0
        expected = echo_len + command.reply_len
        n = len(received)
        m = min(n, echo_len)
        if received[:m] != tx[:m]:
            return Verdict(False, None, "EchoMismatch", received)
        if n > expected:
            return Verdict(False, None, "BadReply", received)
        if n == expected:
            try:
                value = command.parse(received[echo_len:])
            except ReplyError as exc:
                return Verdict(False, None, type(exc).__name__, received)
            return Verdict(True, value, None, received)
        if n <= echo_len:
            return Verdict(False, None, "ReplyTimeout", received)
        return Verdict(False, None, "PartialReply", received)


GUARD_TXS = frozenset(
    protocol.guard_read(tx, i).tx for i in range(32) for tx in (b"\x80", protocol.ReadParam(i, Param.STRETCH).tx)
)
"""Every guard read the engine can send (what :func:`ics35_async.protocol.guard_read` makes, for
any command and ID); the workloads here never send these themselves."""


def band(i: int) -> tuple[int, int]:
    """Positions servo ``i`` is sent to (stream: even targets; requests: odd positions)."""
    low = 4000 + 200 * i
    return low, low + 150


def is_stream_tx(tx: bytes) -> bool:
    if len(tx) != 3 or tx[0] & 0xE0 != protocol.CMD_POSITION:
        return False
    position = (tx[1] << 7) | tx[2]
    return position != protocol.FREE and position % 2 == 0


def chaos_servos() -> list[VirtualServo]:
    servos = []
    for i in range(32):
        servo = VirtualServo(i, position=band(i)[0] + 40)
        servo.stretch, servo.speed = 10 + i, 60 + i  # per-ID values: a reply given to the wrong ID shows
        servos.append(servo)
    return servos
