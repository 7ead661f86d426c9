"""Bringing servos into a loop that sets every target each cycle from where they stand, not at the loop's target.

A servo the loop has not read yet, one freed by the loop, and one its stream holds (back from offline, or its lost
port back: it may have restarted, free, and been turned elsewhere meanwhile) would go to the loop's target at full
speed on its first command.  :class:`BlendIn` reads where such a servo stands, then blends its target from there to
the loop's, no faster than a speed limit.  It reads an ICS 3.6 servo with ICS 3.6's position read, which leaves its
torque alone (one that only missed replies keeps holding: a standing robot does not sag), and any other with the
free command (ICS 3.5 has no other read).  ``ics35 demo`` follows it; a program's loop gets the same rule.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

from .. import protocol, units
from ..errors import InvalidArgument, ReplyError
from ..line import Line
from ..servo import Servo
from ..stream import WATCH

if TYPE_CHECKING:
    from ..frames import Frame
    from ..stream import Stream

MAX_SPEED = 60.0
"""Degrees per second no blend goes faster than, by default: well under a KRS servo's top speed (some 400..600)."""
MAX_SPEED_RANGE = (1.0, 1000.0)
# Smoothstep's steepest slope (halfway) over its average: a blend over T seconds of D degrees peaks at 1.5 D / T.
SMOOTHSTEP_PEAK = 1.5


@dataclass(frozen=True)
class Joining:
    """A servo being brought into the loop: why (``"start"``: not read yet, or freed by the loop; ``"rejoined"``:
    back from offline; ``"resumed"``: its lost port back, as :attr:`Stream.held <ics35_async.Stream.held>` says),
    where it stood when read (``None``: not read yet), when its blend began (the clock of the frames'
    ``finished``), how long the blend takes (``seconds``: the blend's own, or longer for a long way, see
    :class:`BlendIn`; 0 until read) and how it is read (``frees``: with the free command, its torque off for that
    moment; ``False``: with ICS 3.6's position read, its torque left alone)."""

    why: str
    position: int | None = None
    since: float = 0.0
    seconds: float = 0.0
    frees: bool = True

    @property
    def came_back(self) -> bool:
        """Whether the servo came back (from offline, or with its lost port): it may have restarted elsewhere."""
        return self.why != "start"


class BlendIn:
    """Sets a loop's targets on ``stream`` each frame, each servo brought in from where it stands.

    A servo not read yet (the loop's first frames), one the loop freed, and one the stream holds (see
    :attr:`Stream.held <ics35_async.Stream.held>`) is read until a cycle says where it stands, then its target goes
    smoothly (smoothstep: no jerk at either end) from there to the loop's.  The blend takes ``seconds``, or longer
    where the way is long: no blend goes faster than ``max_speed`` degrees per second (smoothstep is fastest
    halfway, at 1.5 times its average speed), the way judged at the blend's start; a loop's target that moves on
    meanwhile adds none of its speed (no target set moves faster than ``max_speed`` from the one before it), and a
    servo joins the loop once its target has caught the loop's (one that runs away faster than ``max_speed`` is
    followed at that speed).  Where it stood is held within the servos' travel (3500..11500), as a target is.

    How a servo is read:

    * an ICS 3.6 servo, with ICS 3.6's position read (the stream watches it meanwhile: see
      :meth:`Stream.watch <ics35_async.Stream.watch>`), which neither moves nor frees it: one that only missed
      replies goes on holding where it was (a standing robot does not sag), one that restarted stays free until
      its blend's first target.  A servo is taken for ICS 3.6 once it has been heard answering that read: the
      stream watching it as the loop begins (``bus.stream(ids, watch=...)``, as
      :func:`~ics35_async.policies.plan_position_stream` plans), or a probe of the line
      (:meth:`Servo.has_position_read <ics35_async.Servo.has_position_read>`);
    * any other servo, with the free command, whose reply says where it stands: ICS 3.5 has no other read, and
      does not tell a servo that only missed replies from one that restarted (free already), so one that only
      missed replies lets go for that moment.  A servo the stream watches whose protocol nobody has told is read
      with the free command only once it has gone offline unheard (an ICS 3.5 servo is silent to the read).

    Call :meth:`set_targets` with every frame instead of ``stream.set_targets``: it sets the targets with
    ``lift_holds=False``, so a hold that begins after the frame it looked at keeps the servo held, sent nothing,
    until the next call reads it.

    Raises:
        InvalidArgument: ``seconds`` is not 0..3600, ``max_speed`` not 1..1000 degrees per second, or ``stream``
            frees a servo that comes back (``on_resume="free"``): it holds none, so nothing would tell that servo
            from one that never left.
    """

    def __init__(self, stream: Stream, seconds: float, *, max_speed: float = MAX_SPEED) -> None:
        if stream.on_resume != "wait":
            raise InvalidArgument(
                f"BlendIn needs a stream with on_resume='wait', not {stream.on_resume!r}: a stream that frees a servo"
                " that comes back holds none, and the loop's next target would throw it from where it restarted"
            )
        self.stream = stream
        self.seconds = float(units.check_seconds("seconds", seconds, 0.0, 3600))
        self.max_speed = float(units.check_number("max_speed", max_speed, *MAX_SPEED_RANGE, "degrees per second"))
        self._joining: dict[int, Joining] = {}
        # The newest cycle when a held servo was freed or watched to be read: a frame up to it may carry a reading
        # from before the servo went silent (or its port away), not where it stands now.
        self._read_after: dict[int, int] = {}
        self._joined: set[int] = set()
        self._sent: dict[int, tuple[int, float]] = {}  # a blend's last target, and its frame's time
        # IDs heard answering ICS 3.6's position read while the stream watched them (beside what the line knows).
        self._heard_reading: set[int] = set()

    @property
    def joining(self) -> dict[int, Joining]:
        """The servos being brought in now (read, or blended), and how (see :class:`Joining`)."""
        return dict(self._joining)

    def set_targets(self, wanted: Mapping[int, int], frame: Frame) -> dict[int, int]:
        """Set the loop's targets ``wanted`` ``{id: position}`` (0: free) on the stream after ``frame``, those of
        servos being brought in as the class says; returns what each ID was given: a target, 0 (free: read with
        the free command, or freed by the loop) or :data:`~ics35_async.stream.WATCH` (read with ICS 3.6's read).

        Raises:
            InvalidArgument: an ID not in the stream or a position out of range (nothing applied).
            BusClosed: the stream (or its bus) was closed.
        """
        stream = self.stream
        stream.check_targets(wanted)  # (before anything changes here: a bad target applies nothing)
        for sid in wanted:
            # (watched, and read: its reading came from ICS 3.6's read, the only command a watched ID is sent)
            if sid in frame.positions and stream.target(sid) == WATCH:
                self._heard_reading.add(sid)
        held = stream.held
        newest = stream.latest.cycle if stream.latest is not None else frame.cycle
        to_read = [sid for sid in wanted if sid in held]
        for sid in to_read:
            self._joining[sid] = Joining(held[sid])
            self._read_after[sid] = newest
            self._joined.discard(sid)
            self._sent.pop(sid, None)
        out: dict[int, int] = {}
        for sid, goal in wanted.items():
            out[sid] = self._target(sid, goal, frame)
        to_watch = [sid for sid, target in out.items() if target == WATCH and stream.target(sid) != WATCH]
        to_free = [sid for sid in to_read if out[sid] == protocol.FREE]
        if to_watch:
            stream.watch(to_watch)  # (lifts their holds: the read moves and frees nothing)
        if to_free:
            stream.free(to_free)  # (lifts their holds: the free command moves nothing and reads where they stand)
        stream.set_targets({sid: p for sid, p in out.items() if p != WATCH}, lift_holds=False)
        return out

    def _reads_position(self, sid: int, frame: Frame) -> bool:
        """Whether ``sid`` is read with ICS 3.6's position read (see the class), not the free command."""
        if sid in self._heard_reading or Servo(self.stream.bus, sid).known_position_read():
            return True
        # Watched by the program, its protocol untold: read so until it goes offline unheard (ICS 3.5, likely).
        return self.stream.target(sid) == WATCH and sid not in frame.offline

    def _target(self, sid: int, goal: int, frame: Frame) -> int:
        """What ``sid`` is sent this frame for the loop's ``goal``."""
        if goal == protocol.FREE:  # (freed by the loop: targeted again, it is read and blended in again)
            self._joined.discard(sid)
            self._joining.pop(sid, None)
            self._sent.pop(sid, None)
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
                frees = not self._reads_position(sid, frame)
                if frees != joining.frees:
                    self._joining[sid] = replace(joining, frees=frees)
                return protocol.FREE if frees else WATCH  # (its reply reads it)
            self._read_after.pop(sid, None)
            where = min(max(where, units.TRAVEL_MIN), units.TRAVEL_MAX)
            joining = self._joining[sid] = replace(
                joining,
                position=where,
                since=frame.finished,
                seconds=self._blend_seconds(where, goal),
                frees=self.stream.target(sid) != WATCH,  # (what read it: the command its stream sends it still)
            )
        assert joining.position is not None
        s = 1.0 if joining.seconds <= 0 else min(1.0, (frame.finished - joining.since) / joining.seconds)
        if s >= 1.0:
            aim = goal
        else:
            s = s * s * (3 - 2 * s)  # smoothstep: no jerk at either end of the blend
            aim = round(joining.position + (goal - joining.position) * s)
        # No faster than max_speed from the target sent last, whatever the loop's target does meanwhile (the blend
        # is judged at its start: a target that moves on would add its own speed).
        last, since = self._sent.get(sid, (joining.position, joining.since))
        reach = self.max_speed * units.COUNTS_PER_DEGREE * max(0.0, frame.finished - since)
        target = round(min(max(aim, last - reach), last + reach))
        if target == goal and s >= 1.0:
            del self._joining[sid]
            self._sent.pop(sid, None)
            self._joined.add(sid)
            return goal
        self._sent[sid] = (target, frame.finished)
        return target

    def _blend_seconds(self, where: int, goal: int) -> float:
        """How long a blend from ``where`` to ``goal`` takes: ``seconds``, or as long as its steepest point
        (halfway) needs to stay within ``max_speed``."""
        degrees = abs(units.position_to_degrees(goal) - units.position_to_degrees(where))
        return max(self.seconds, SMOOTHSTEP_PEAK * degrees / self.max_speed)


async def probe_position_reads(line: Line, ids: Iterable[int]) -> list[int]:
    """Ask each of ``ids`` on ``line`` whether it answers ICS 3.6's position read, so that a :class:`BlendIn` on that
    line reads one that comes back with it, not the free command; returns the IDs that do.

    Nothing sent moves or frees a servo: the read and, where it is silent, a parameter read (each ID asked once a
    line, then remembered: see :meth:`Servo.has_position_read <ics35_async.Servo.has_position_read>`).  An ID silent
    or garbled is left untold (read with the free command, as an ICS 3.5 servo).

    Raises:
        InvalidArgument: an ID is not 0..31.
        BusClosed, PortLost: the line is closed or its port is gone.
    """
    readable = []
    for sid in [protocol.check_id(i) for i in ids]:
        try:
            if await Servo(line, sid).has_position_read():
                readable.append(sid)
        except ReplyError:
            pass  # (nobody there, or a garbled answer: nothing told)
    return readable
