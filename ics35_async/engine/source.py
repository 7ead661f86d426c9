"""The background source: what fills the line's idle time (the position stream)."""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

from ..errors import IcsError, ReplyError

Upcoming = tuple[bytes, int, int, bytes, bool]
"""A transaction a source will ask for: ``(tx, reply_len, servo_id, shape, news)``; ``shape`` is the shape
of a reply the source takes (``reply_len`` bytes wanted, then as many masks: a reply ``r`` fits when
``r[i] & mask[i] == wanted[i]``), or ``b""`` if the source cannot tell a reply it would refuse by
such a comparison (see :meth:`BackgroundSource.upcoming`); ``news``: once this one is answered, the
source has news for its program (a stream: a cycle's frame), so a burst should be fed to the engine
promptly there rather than at its end."""


class BackgroundSource(Protocol):
    """Something that fills the line's idle time (the position stream).

    Everything here is a plain call from the engine, with the engine's
    ``now``: a source does no I/O and reads no clock of its own.

    ``next_transaction(now)`` returns ``(tx, reply_len, servo_id)``, or
    ``None`` when it has nothing to send now; then ``wake_at`` says when it
    will have (``math.inf``: only when told through the line's ``kick``).  The
    engine either puts an offer on the wire or passes it over with ``skip``
    (its servo's reply to an earlier command may still come); an offer it does
    neither with is made again on the next call.
    ``complete`` gets the receive buffer and the reply's offset in it (after
    the echo) and returns ``None`` or the error that made the reply invalid;
    it changes nothing when it returns an error: the engine counts the fault,
    then calls ``fail`` with it, as it does for a timeout or echo fault, or for an offer failed unsent (so a
    frame published from ``fail`` comes with its transactions counted).  ``line_closed`` is told when
    the line closes for good (or loses its port with reconnect off); ``line_resumed`` when it
    comes back after a lost port.  ``probing_silent`` is asked as the source is detached with its
    transaction on the wire: is that a probe of a servo it has found silent (see
    ``LineEngine.detach_source``)?  ``slot_due`` says whether the source keeps a schedule
    (see the engine's sharing rule).  ``upcoming`` and ``upcoming_done`` serve a burst (see
    :meth:`LineEngine.plan_burst <ics35_async.engine.LineEngine.plan_burst>`).
    """

    @property
    def wake_at(self) -> float:
        """When the source next has something to send (``math.inf``: only when kicked)."""

    def slot_due(self, now: float) -> float | None:
        """When this source's next transaction must start, if it keeps a schedule (a stream with a
        rate): exactly ``now`` while a cycle runs, the next cycle's slot while it waits (earlier than
        ``now`` when the source runs late: its cycles take longer than its period).  ``None``:
        it keeps none, and requests share the line with it by count (``max_requests_between``)."""
        ...

    def next_transaction(self, now: float) -> tuple[bytes, int, int] | None: ...

    def complete(self, buf: bytearray, offset: int, now: float) -> ReplyError | None: ...

    def fail(self, exc: ReplyError, now: float, sent: bool) -> None:
        """The transaction just offered failed with ``exc``.  ``sent`` False: it never went on the wire (the
        guard read before it got nothing back, on a line that answered nothing to it either, and counts as its
        try: see ``LineEngine._guard_proved_nothing``)."""
        ...

    def skip(self, now: float) -> None:
        """The transaction just offered was not sent (see above): move on as after a failure, counting none."""
        ...

    def line_closed(self, exc: IcsError) -> None: ...

    def line_resumed(self, now: float) -> None:
        """The line came back after a lost port (a reconnect): the servos may have restarted or
        moved meanwhile."""
        ...

    def probing_silent(self) -> bool:
        """Is the transaction this source last offered a probe of a servo it has found silent (an offline
        ID's)?  Asked only while that transaction is on the wire."""
        ...

    def upcoming(self, limit: int) -> list[Upcoming]:
        """The one on the wire and the transactions it will ask for after it, if each succeeds,
        without waiting for a slot (the rest of its cycle, and the cycles after it where they are
        certain: an unpaced stream with every ID in its cycle), at most ``limit`` in all, each with
        the shape of a reply it takes (a burst stops where a reply is not of that shape: the source
        would refuse it, and the line must then go as it goes without a burst).  It keeps the ones
        after the one on the wire as they are (a new target for one of them waits) until
        :meth:`upcoming_done`."""
        ...

    def upcoming_done(self) -> None:
        """The planned transactions are over: changes held back meanwhile apply now."""
        ...


@dataclass(slots=True, eq=False)
class BoundSource:
    """A :class:`BackgroundSource` made of callables, so an object can keep its hooks off its public face.

    The callables are bound methods taken once: calling ``source.complete(...)``
    costs what a method call on the object itself would.
    """

    next_transaction: Callable[[float], tuple[bytes, int, int] | None]
    complete: Callable[[bytearray, int, float], ReplyError | None]
    fail: Callable[[ReplyError, float, bool], None]
    line_closed: Callable[[IcsError], None]
    _wake_at: Callable[[], float]
    slot_due: Callable[[float], float | None]
    line_resumed: Callable[[float], None]
    skip: Callable[[float], None]
    upcoming: Callable[[int], list[Upcoming]]
    upcoming_done: Callable[[], None]
    probing_silent: Callable[[], bool]

    @classmethod
    def of(cls, owner: Any) -> BoundSource:
        """``owner``'s hooks: ``_next_transaction``, ``_complete``, ``_fail``, ``_line_closed``, ``_wake_at``,
        ``_slot_due``, ``_line_resumed``, ``_skip``, ``_upcoming``, ``_upcoming_done``, ``_probing_silent``."""
        return cls(
            owner._next_transaction,
            owner._complete,
            owner._fail,
            owner._line_closed,
            lambda: owner._wake_at,
            owner._slot_due,
            owner._line_resumed,
            owner._skip,
            owner._upcoming,
            owner._upcoming_done,
            owner._probing_silent,
        )

    @property
    def wake_at(self) -> float:
        return self._wake_at()


HOOK_NAMES = ("next_transaction", "complete", "fail", "line_closed", "wake_at")


def keep_old_hook_names(cls: type) -> None:
    """Give ``cls`` its hooks' old public names for one release: each still works, with a DeprecationWarning.

    ``cls`` keeps its :class:`BoundSource` in ``_hooks``.
    """
    for name in HOOK_NAMES:

        def get(self: Any, name: str = name) -> Any:
            warnings.warn(
                f"{type(self).__name__}.{name} is the line engine's hook, not public API; it goes in the next release",
                DeprecationWarning,
                stacklevel=2,
            )
            return getattr(self._hooks, name)

        setattr(cls, name, property(get, doc="Deprecated: the line engine's hook (warns); goes in the next release."))
