"""Freeing several servos at once (torque off: they go limp), told apart by how each answered.

``ics35 free`` follows these rules.  Named IDs are servos the caller expects
on the line: one that does not answer has failed.  Asked for *every servo*
(``every_servo``, as "free all" is: what makes a robot go limp), an ID where
nothing at all came back is no servo, not a failure, so a 3-servo line does
not fail for its 29 empty IDs.  A reply that came back wrong still fails
there: something at that ID answered (two servos sharing it, noise) and may
still hold.  When no ID answered, every servo is not "none": the line is
unpowered, at another rate or miswired, so the silent IDs fail as named ones
would.

Every servo is asked as a scan probes (see :mod:`.scan`): each ID once,
with the bus's probe allowance (:class:`~ics35_async.protocol.ProbeFree`:
what this link's answers take, learnt, not the adapter's worst case) and no
retry, so an empty ID costs milliseconds and a servo after it goes limp at
once.  The scan's rule then decides which silent IDs are empty: the last
one, and every silent one if some answer came after its wait, are freed
once more with the normal allowance; a garbled one is freed once more after
the line has settled.  Until something has answered (a fresh port) the
probe allowance is the normal one, so the empty IDs before the first servo
cost that each.  Named IDs get the normal allowance and the bus's retries:
a slow servo the caller expects must not be called absent.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field

from .. import protocol
from ..errors import BusClosed, IcsError, PortLost, ReplyError
from ..servo import Servo
from ..tasks import task_group
from .failure_kinds import Line, nothing_came_back
from .scan import ask_each


@dataclass(frozen=True)
class FreeReport:
    """What freeing some IDs did.

    ``freed``: ID -> the position it reported as it went free; ``failed``: ID
    -> why it did not answer (validly); ``absent``: with ``every_servo``, the
    IDs where nothing came back (no servo there); ``unknown``: the IDs whose
    free was pending when the line was lost (``lost``): free or still holding.
    """

    freed: Mapping[int, int] = field(default_factory=dict)
    failed: Mapping[int, ReplyError] = field(default_factory=dict)
    absent: tuple[int, ...] = ()
    unknown: tuple[int, ...] = ()
    lost: IcsError | None = None

    @property
    def ok(self) -> bool:
        """Every servo asked for (every one there, with ``every_servo``) went free."""
        return not self.failed and self.lost is None


async def free_servos(
    line: Line,
    ids: Iterable[int],
    *,
    every_servo: bool = False,
    on_freed: Callable[[int, int], object] | None = None,
) -> FreeReport:
    """Send the free command to each of ``ids`` (queued at once: the line runs them back to back).

    With ``every_servo`` the IDs are every servo there may be, not servos the
    caller named: each is asked as a scan probes (a short wait, no retry: see
    the module), and a silent one is ``absent``, unless none answered at all.
    A line lost part-way does not raise: the servos freed before it are in
    ``freed``, the rest in ``unknown``, the loss in ``lost``.
    ``on_freed(id, position)`` is called as each servo answers that it went
    free: what a caller cancelled part-way (Ctrl-C) knows was done, as no
    report is returned then.

    Raises:
        InvalidArgument: an ID is not 0..31.
    """
    wanted = sorted({protocol.check_id(i) for i in ids})
    outcomes: dict[int, int | IcsError] = {}
    if every_servo:
        await _free_every_servo(line, wanted, outcomes, on_freed)
    else:

        async def free_one(sid: int) -> None:
            try:
                outcomes[sid] = position = await Servo(line, sid).free()
            except IcsError as exc:
                outcomes[sid] = exc
            else:
                if on_freed is not None:
                    on_freed(sid, position)

        async with task_group() as group:
            for sid in wanted:
                group.start_soon(free_one, sid)
    freed = {i: r for i, r in sorted(outcomes.items()) if isinstance(r, int)}
    failed = {i: r for i, r in sorted(outcomes.items()) if isinstance(r, ReplyError)}
    unknown = tuple(i for i, r in sorted(outcomes.items()) if isinstance(r, IcsError) and i not in failed)
    lost = next((r for i, r in sorted(outcomes.items()) if i in unknown and isinstance(r, IcsError)), None)
    absent: tuple[int, ...] = ()
    if every_servo and (freed or not all(nothing_came_back(e) for e in failed.values())):
        # Some servo answered, so the line works at this rate: an ID silent on it is an empty slot.
        absent = tuple(i for i, e in failed.items() if nothing_came_back(e))
        failed = {i: e for i, e in failed.items() if i not in absent}
    return FreeReport(freed, failed, absent, unknown, lost)


async def _free_every_servo(
    line: Line,
    wanted: list[int],
    outcomes: dict[int, int | IcsError],
    on_freed: Callable[[int, int], object] | None,
) -> None:
    """Free each of ``wanted`` as a scan probes (see the module), into ``outcomes`` (ID -> position or error),
    calling ``on_freed`` as each goes free.

    A line lost part-way leaves its error at every ID not answered by then (free or still holding).
    """
    baud = line.baudrate

    async def free(sid: int, short: bool) -> ReplyError | None:
        command = protocol.ProbeFree(sid, baudrate=baud) if short else protocol.SecondLookFree(sid, baudrate=baud)
        outcomes.pop(sid, None)  # pending again: a line lost now leaves it free or still holding (unknown)
        try:
            position: int = await line.request(command, retries=0)
            outcomes[sid] = position
            if on_freed is not None:
                on_freed(sid, position)
        except ReplyError as exc:
            outcomes[sid] = exc
            return exc
        return None

    try:
        await ask_each(line, wanted, free)
    except (BusClosed, PortLost) as exc:
        for sid in wanted:
            if not isinstance(outcomes.get(sid), int | ReplyError):
                outcomes[sid] = exc
