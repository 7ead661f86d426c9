"""The Traffic page's record: the last transactions on the line, taken from the engine's own debug log.

The engine logs every finished transaction (``id tx rx``) and every failure
at DEBUG on the ``ics35_async`` logger; while someone watches the Traffic
page this handler is attached and the level lowered, so nothing is added to
the hot path when nobody looks.  A failure is logged right after its
transaction, and is attached to it as its outcome.
"""

from __future__ import annotations

import itertools
import logging
from collections import deque
from typing import Any

LOGGER = logging.getLogger("ics35_async")
FAULTS = "ics35_async.faults"  # (the engine's logger of failed transactions: see engine.machine)
COMMANDS = {0x80: "position", 0xA0: "read", 0xC0: "write", 0xE0: "id"}
SUBCOMMANDS = {0: "eeprom", 1: "stretch", 2: "speed", 3: "current", 4: "temperature", 5: "position (3.6)"}


def describe(tx: bytes) -> tuple[int | None, str]:
    """(servo ID, command name) of a command's bytes, for a person."""
    if not tx:
        return None, "-"
    kind = tx[0] & 0xE0
    name = COMMANDS.get(kind, f"0x{tx[0]:02X}")
    if kind == 0xE0:
        return None, "id read" if len(tx) > 1 and tx[1] == 0 else "id write"
    if kind in (0xA0, 0xC0) and len(tx) > 1:
        name = f"{name} {SUBCOMMANDS.get(tx[1], f'sc {tx[1]}')}"
    if kind == 0x80 and len(tx) >= 3 and tx[1] == 0 and tx[2] == 0:
        name = "free"
    return tx[0] & 0x1F, name


class TrafficLog(logging.Handler):
    """A ring of the last ``size`` transactions, each with a sequence number.

    Recording keeps the log record's own strings (the engine's thread pays
    for nothing more); decoding them for a page happens in :meth:`since`.
    """

    def __init__(self, size: int = 2000) -> None:
        super().__init__(logging.DEBUG)
        # [seq, time, tx hex, rx hex, failure or None]; a list, so a failure logged next can fill it in.
        self.entries: deque[list[Any]] = deque(maxlen=size)
        self._seq = itertools.count(1)
        self._watchers = 0
        self._level_before = LOGGER.level

    def handle(self, record: logging.LogRecord) -> bool:
        self.emit(record)  # no handler lock: the deque's append is atomic, and emit only appends
        return True

    def emit(self, record: logging.LogRecord) -> None:
        args = record.args
        if record.msg == "id %s tx %s rx %s" and isinstance(args, tuple) and len(args) == 3:
            self.entries.append([next(self._seq), record.created, args[1], args[2], None])
        elif record.name == FAULTS and record.levelno == logging.DEBUG and isinstance(args, tuple) and self.entries:
            # A failure of the transaction just logged (see engine.machine, LineEngine._fault): the error, its
            # last argument (the port it may be told after is the page's own line).
            self.entries[-1][4] = str(args[-1])
        elif record.levelno >= logging.WARNING:
            self.entries.append([next(self._seq), record.created, "", "", record.getMessage()])

    def since(self, seq: int) -> list[dict[str, Any]]:
        """The transactions after ``seq``, decoded for a page."""
        # list() copies without letting another thread in (a thread driver logs from its I/O thread).
        return [_decoded(*e) for e in list(self.entries) if e[0] > seq]

    def watch(self) -> None:
        """Someone opened the Traffic page: start recording."""
        self._watchers += 1
        if self._watchers == 1:
            self._level_before = LOGGER.level
            LOGGER.addHandler(self)
            LOGGER.setLevel(logging.DEBUG)

    def unwatch(self) -> None:
        self._watchers = max(0, self._watchers - 1)
        if self._watchers == 0:
            LOGGER.removeHandler(self)
            LOGGER.setLevel(self._level_before)


def _decoded(seq: int, created: float, tx_hex: str, rx_hex: str, failure: str | None) -> dict[str, Any]:
    if not tx_hex:  # the line itself (a lost port)
        return {"seq": seq, "time": created, "id": None, "command": "line", "sent": "", "received": "",
                "outcome": failure}  # fmt: skip
    tx, rx = bytes.fromhex(tx_hex), bytes.fromhex(rx_hex)
    servo_id, command = describe(tx)
    answered = len(rx) > len(tx) or (rx and rx[: len(tx)] != tx)
    outcome = failure or ("ok" if answered else "no reply")
    return {"seq": seq, "time": created, "id": servo_id, "command": command, "sent": tx_hex, "received": rx_hex,
            "outcome": outcome}  # fmt: skip
