"""Bringing servos into a loop that sets every target each cycle from where they stand, not at the loop's target.

A servo the loop has not read yet, one freed by the loop, and one its stream holds (back from offline, or its lost
port back: it may have restarted, free, and been turned elsewhere meanwhile) would go to the loop's target at full
speed on its first command.  :class:`BlendIn` sends such a servo the free command until a cycle has read it (the
free command's reply says where it stands; it is free already if it restarted), then blends its target from there
to the loop's over ``seconds``.  ``ics35 demo`` follows it; a program's loop gets the same rule.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING

from .. import protocol, units
from ..errors import InvalidArgument

if TYPE_CHECKING:
    from ..frames import Frame
    from ..stream import Stream


@dataclass(frozen=True)
class Joining:
    """A servo being brought into the loop: why (``"start"``: not read yet, or freed by the loop; ``"rejoined"``:
    back from offline; ``"resumed"``: its lost port back, as :attr:`Stream.held <ics35_async.Stream.held>` says),
    where it stood when read (``None``: not read yet, sent the free command meanwhile) and when its blend began
    (the clock of the frames' ``finished``)."""

    why: str
    position: int | None = None
    since: float = 0.0

    @property
    def came_back(self) -> bool:
        """Whether the servo came back (from offline, or with its lost port): it may have restarted elsewhere."""
        return self.why != "start"


class BlendIn:
    """Sets a loop's targets on ``stream`` each frame, each servo brought in from where it stands.

    A servo not read yet (the loop's first frames), one the loop freed, and one the stream holds (see
    :attr:`Stream.held <ics35_async.Stream.held>`) is sent the free command until a cycle reads it, then its target
    goes smoothly (smoothstep: no jerk at either end) from where it stood to the loop's over ``seconds``.  The free
    command reads a servo on either protocol; one that restarted is free already, one that only missed replies
    lets go for that moment.  Where it stood is held within the servos' travel (3500..11500), as a target is.

    Call :meth:`set_targets` with every frame instead of ``stream.set_targets``: it sets the targets with
    ``lift_holds=False``, so a hold that begins after the frame it looked at keeps the servo held, sent nothing,
    until the next call reads it.

    Raises:
        InvalidArgument: ``seconds`` is not 0..3600, or ``stream`` frees a servo that comes back
            (``on_resume="free"``): it holds none, so nothing would tell that servo from one that never left.
    """

    def __init__(self, stream: Stream, seconds: float) -> None:
        if stream.on_resume != "wait":
            raise InvalidArgument(
                f"BlendIn needs a stream with on_resume='wait', not {stream.on_resume!r}: a stream that frees a servo"
                " that comes back holds none, and the loop's next target would throw it from where it restarted"
            )
        self.stream = stream
        self.seconds = float(units.check_seconds("seconds", seconds, 0.0, 3600))
        self._joining: dict[int, Joining] = {}
        # The newest cycle when a held servo was freed to be read: a frame up to it may carry a reading from
        # before the servo went silent (or its port away), not where it stands now.
        self._read_after: dict[int, int] = {}
        self._joined: set[int] = set()

    @property
    def joining(self) -> dict[int, Joining]:
        """The servos being brought in now (read, or blended), and how (see :class:`Joining`)."""
        return dict(self._joining)

    def set_targets(self, wanted: Mapping[int, int], frame: Frame) -> dict[int, int]:
        """Set the loop's targets ``wanted`` ``{id: position}`` (0: free) on the stream after ``frame``, those of
        servos being brought in as the class says; returns the targets set.

        Raises:
            InvalidArgument: an ID not in the stream or a position out of range (nothing applied).
            BusClosed: the stream (or its bus) was closed.
        """
        stream = self.stream
        stream.check_targets(wanted)  # (before anything changes here: a bad target applies nothing)
        held = stream.held
        newest = stream.latest.cycle if stream.latest is not None else frame.cycle
        to_read = [sid for sid in wanted if sid in held]
        for sid in to_read:
            self._joining[sid] = Joining(held[sid])
            self._read_after[sid] = newest
            self._joined.discard(sid)
        out: dict[int, int] = {}
        for sid, goal in wanted.items():
            out[sid] = self._target(sid, goal, frame)
        if to_read:
            stream.free(to_read)  # (lifts their holds: the free command moves nothing and reads where they stand)
        stream.set_targets(out, lift_holds=False)
        return out

    def _target(self, sid: int, goal: int, frame: Frame) -> int:
        """What ``sid`` is sent this frame for the loop's ``goal``."""
        if goal == protocol.FREE:  # (freed by the loop: targeted again, it is read and blended in again)
            self._joined.discard(sid)
            self._joining.pop(sid, None)
            self._read_after.pop(sid, None)  # (targeted again, it is read afresh: a reading after this frame's)
            return protocol.FREE
        if sid in self._joined:
            return goal
        joining = self._joining.get(sid)
        if joining is None:
            joining = self._joining[sid] = Joining("start")
        if joining.position is None:
            where = frame.positions.get(sid)
            if where is None or frame.cycle <= self._read_after.get(sid, -1):
                return protocol.FREE  # (its reply reads it)
            self._read_after.pop(sid, None)
            where = min(max(where, units.TRAVEL_MIN), units.TRAVEL_MAX)
            joining = self._joining[sid] = Joining(joining.why, where, frame.finished)
        assert joining.position is not None
        s = 1.0 if self.seconds <= 0 else min(1.0, (frame.finished - joining.since) / self.seconds)
        if s >= 1.0:
            del self._joining[sid]
            self._joined.add(sid)
            return goal
        s = s * s * (3 - 2 * s)  # smoothstep: no jerk at either end of the blend
        return round(joining.position + (goal - joining.position) * s)
