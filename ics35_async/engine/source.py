"""The background source: what fills the line's idle time (the position stream)."""

from __future__ import annotations

from typing import Protocol

from ..errors import IcsError, ReplyError


class BackgroundSource(Protocol):
    """Something that fills the line's idle time (the position stream).

    Everything here is a plain call from the engine, with the engine's
    ``now``: a source does no I/O and reads no clock of its own.

    ``next_transaction(now)`` returns ``(tx, reply_len, servo_id)``, or
    ``None`` when it has nothing to send now; then ``wake_at`` says when it
    will have (``math.inf``: only when told through the line's ``kick``).
    ``complete`` gets the receive buffer and the reply's offset in it (after
    the echo) and returns ``None`` or the error that made the reply invalid;
    it changes nothing when it returns an error: the engine counts the fault,
    then calls ``fail`` with it, as it does for a timeout or echo fault (so a
    frame published from ``fail`` comes with its transactions counted).  ``line_closed`` is told when
    the line closes for good (or loses its port with reconnect off); ``line_resumed`` when it
    comes back after a lost port.
    """

    wake_at: float

    def slot_due(self, now: float) -> float | None:
        """When this source's next transaction must start, if it keeps a schedule (a stream with a
        rate): ``now`` or earlier while a cycle runs, the next cycle's slot while it waits.  ``None``:
        it keeps none, and requests share the line with it by count (``max_requests_between``)."""
        ...

    def next_transaction(self, now: float) -> tuple[bytes, int, int] | None: ...

    def complete(self, buf: bytearray, offset: int, now: float) -> ReplyError | None: ...

    def fail(self, exc: ReplyError, now: float) -> None: ...

    def line_closed(self, exc: IcsError) -> None: ...

    def line_resumed(self, now: float) -> None:
        """The line came back after a lost port (a reconnect): the servos may have restarted or
        moved meanwhile."""
        ...
