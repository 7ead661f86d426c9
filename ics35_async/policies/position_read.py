"""Reading positions without letting go: ICS 3.6's position read where a servo has it, the free command only
where the caller says the servo may go limp.

``ics35 info`` and ``ics35 monitor`` follow these rules; a program gets the
same ones.  Nothing here sends a position or free command to a servo unless
``free_ics35`` says it may go limp.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from .. import protocol
from ..errors import ReplyError
from ..line import Line
from ..servo import Servo
from .scan import anyone_there, probe_ids

if TYPE_CHECKING:
    from ..stream import StreamOptions

NO_READ_ICS35 = "ICS 3.5 servo: it reads a position only with the free command (the servo goes limp)"


@dataclass(frozen=True)
class PositionReading:
    """One servo's position, how it was read (``"read"``: ICS 3.6, torque left alone; ``"free"``: the free
    command, torque now off; ``None``: not read), its protocol, and why there is no position."""

    position: int | None
    how: str | None
    protocol: str
    why: str | None = None


async def read_position_without_freeing(servo: Servo, *, free_ics35: bool = False) -> PositionReading:
    """The servo's position by ICS 3.6's read; on an ICS 3.5 servo by the free command only with ``free_ics35``.

    Before the free command, the position read once more with the whole allowance (an ICS 3.6 servo whose replies
    were lost answers it, and is read, not freed), then a read that moves nothing (its temperature): two servos
    sharing the ID (a new one, ID 0 as they all come, plugged in beside it) answer it garbled, and it raises,
    freeing neither, where the free command would let go of both, one that held included.
    """
    if await servo.has_position_read():
        return PositionReading(await servo.read_position(), "read", "ICS 3.6")
    if free_ics35:
        position = await servo.read_position_once_more()
        if position is not None:
            return PositionReading(position, "read", "ICS 3.6")
        await servo.read_temperature()
        return PositionReading(await servo.free(), "free", "ICS 3.5")
    return PositionReading(None, None, "ICS 3.5", NO_READ_ICS35)


@dataclass
class StreamPlan:
    """How to stream a set of IDs without freeing what may not go limp.

    ``watch``: IDs read with ICS 3.6's read (``Stream(watch=...)``), torque
    left alone, and the IDs whose protocol could not be told; ``free``: IDs
    known to speak ICS 3.5, read with the free command (only with
    ``free_ics35``); ``left_out``: IDs not to stream, and why; ``silent``:
    the IDs (in ``watch`` or ``free``) that answered nothing as they were
    probed: a servo held at a target may have lost its supply and restarted,
    free and elsewhere, so a caller that would stream it that target knows.
    """

    watch: list[int] = field(default_factory=list)
    free: list[int] = field(default_factory=list)
    left_out: dict[int, str] = field(default_factory=dict)
    silent: list[int] = field(default_factory=list)

    @property
    def streamed(self) -> list[int]:
        """Every ID the stream carries (watched or freed), sorted."""
        return sorted(self.watch + self.free)

    def stream_options(self, ids: Iterable[int] | None = None) -> StreamOptions:
        """The options of a stream over ``ids`` (default: :attr:`streamed`) that follows the plan:
        ``bus.stream(plan.streamed, **plan.stream_options())``.  ``watch``: the IDs read with ICS 3.6's read;
        ``offline``: the ``silent`` ones, out of the cycle from the first frame and probed, instead of each
        asked ``offline_after`` cycles first at its whole reply allowance (a servo there after all comes back
        as any offline ID does: held, with a position target)."""
        chosen = set(self.streamed if ids is None else ids)
        return {
            "watch": [sid for sid in self.watch if sid in chosen],
            "offline": [sid for sid in self.silent if sid in chosen],
        }


async def plan_position_stream(line: Line, ids: Iterable[int], *, free_ics35: bool = False) -> StreamPlan:
    """Probe the position read of each of ``ids`` on ``line`` (nothing sent moves or frees a servo) and
    sort the IDs into a plan.

    Every ID is first asked as a scan probes (:func:`~.scan.probe_ids`: a
    short wait, no retry, a second look where a reply may have come late), so
    an ID where no servo is costs a command's start a few milliseconds, not
    several reply allowances.  A silent one gets one short position-read
    probe more (``has_position_read(silent_before=True)``): an ICS 3.6 servo
    whose first reply was lost answers it; silent twice, the ID is
    ``silent``.  Where no ID answered at all, the line is asked once instead,
    by the ID read every device at its rate answers (the scan's question
    whether anyone is there): until something has answered each probe waits
    the whole allowance, so asking every ID again would cost one allowance an
    ID; nobody answers, and every ID is ``silent``, else each is asked again
    as above.  A servo that answered is probed as ever: its position read,
    and if it is silent to that, a parameter read and the position read
    again, so an ICS 3.5 servo is told from an ICS 3.6 one.

    Only an ID known to speak ICS 3.5 is freed (with ``free_ics35``), and
    only once its position read with the whole allowance has gone unanswered
    too: the protocol probe's two short waits take an ICS 3.6 servo whose two
    replies were lost or late for ICS 3.5 (one allowance more per servo to be
    freed, none for an empty ID).  One whose protocol could not be told is
    watched, whatever ``free_ics35`` says: silent to the short probes (nobody
    there, or a present servo whose replies were lost or came after the short
    wait: a lossy line, a TCP bridge, an adapter's latency timer), or heard but
    silent to the reads that tell ICS 3.5 from 3.6.  The free command reaches
    a servo whose reply is lost, and a holding ICS 3.6 servo would go limp; a
    read never frees it, and an empty ID costs no more probes.  A stream marks
    such an ID offline and probes it, as any servo that stops answering (an
    ICS 3.5 servo there stays silent to the read: the stream logs a warning
    naming it, and a new plan asks it again).  A servo whose protocol this
    line already knows is asked all the same (the scan's probe; silent to it,
    its position read, or an ICS 3.5 servo's temperature): ``silent`` is what
    the servos say now; silent, it is still read as its protocol says (an ICS
    3.6 servo watched, never freed).
    """
    wanted = [protocol.check_id(i) for i in ids]
    probed = await probe_ids(line, wanted, id_read_first=False) if wanted else None
    present = set(probed.answered) if probed is not None else set()
    # No ID answered: until something has, every probe waits the whole allowance, and asking each silent ID again
    # would wait it once more for each.  One ID read, which every device at this rate answers (the scan's rule, see
    # probe_ids), says whether anyone is there; nobody, and every ID has been asked twice without an answer (its
    # probe, and the line).
    nobody = probed is not None and not present and not probed.garbled and not await anyone_there(line)
    plan = StreamPlan()
    for sid in wanted:
        servo = Servo(line, sid)
        readable = servo.known_position_read()
        if nobody:
            plan.silent.append(sid)
        else:
            try:
                if readable is None:
                    # (probed: which asks the servo; silent to the scan's probe, one silent probe more says nobody)
                    readable = await servo.has_position_read(silent_before=sid not in present)
                elif sid not in present:
                    await (servo.read_position() if readable else servo.read_temperature())
            except ReplyError:
                plan.silent.append(sid)
        if readable is False and free_ics35:
            try:
                if await servo.read_position_once_more() is not None:
                    readable = True  # ICS 3.6 after all: its probes' replies were lost or late
            except ReplyError:
                readable = None  # garbled: not told apart
        if readable is not False:
            # ICS 3.6, or not told apart (nobody there, or a servo whose replies were lost or came too late):
            # a read frees nothing, where the free command would reach a holding servo whose reply is lost.
            plan.watch.append(sid)
        elif free_ics35:
            plan.free.append(sid)
        else:
            plan.left_out[sid] = NO_READ_ICS35
    return plan
