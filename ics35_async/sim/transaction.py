"""One host command as the simulated line saw and answered it: the line's log entry.

Its own module because both the line (which makes them) and the recorder
(which writes them out) use it, and the recorder must not depend on the line.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True, slots=True)
class Transaction:
    """One host command as the simulated line saw and answered it.

    ``time`` is the line's clock when the command's last byte arrived;
    ``servo_id`` the addressed ID (``None`` for the ID command; for bytes no
    device understood, ``command == "unknown"``, the ID bits of their first
    byte if it is a command byte, else ``None``).  ``echo`` and ``reply``
    are the bytes actually sent back (after faults; ``reply`` of a ``late``
    transaction arrives during a later one); ``clean_reply`` is what healthy
    devices would have sent; ``value`` the value answered (a position, a
    parameter, an :class:`Eeprom`, an ID, memory bytes; ``None`` if none or
    if several devices answered at once); ``responders`` the IDs of the
    devices that answered; ``fault`` the injected faults joined with ``+``;
    ``extra`` bytes sent during this transaction that do not belong to it
    (an earlier late reply, noise); ``reply_time`` when the reply's last byte
    is delivered (``None`` without a reply).
    """

    seq: int
    time: float
    servo_id: int | None
    command: str
    tx: bytes
    echo: bytes
    reply: bytes
    clean_reply: bytes
    value: Any
    responders: tuple[int, ...]
    fault: str | None
    extra: bytes
    reply_time: float | None
