"""Position streaming: one position transaction per servo per cycle, at the wire's pace.

ICS 3.5 has no broadcast, so a cycle over N servos is N position transactions.  A
:class:`Stream` is the line's background source: the I/O callback that completes one
servo's reply writes the next servo's command, with no task switch per servo.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import logging
import math
import statistics
import threading
import warnings
from collections import deque
from collections.abc import Callable, Iterable, Mapping
from typing import Literal, TypedDict

import anyio

from . import protocol, units
from .engine.source import BoundSource, Upcoming, keep_old_hook_names
from .engine.timing import BusTiming
from .errors import BusClosed, IcsError, InvalidArgument, ReplyError
from .frames import Frame, FrameIterator, StreamStats, percentile
from .line import Line
from .protocol.hot_path import position_from_reply
from .tasks import again, despite_cancellation

log = logging.getLogger("ics35_async")

INF = math.inf


# Options of Stream beyond its IDs and rate (what Bus.stream passes through).
STREAM_OPTIONS = frozenset(
    {
        "offline_after",
        "probe_interval",
        "free_on_close",
        "on_close",
        "on_resume",
        "history",
        "watch",
        "offline",
        "hold_offline",
    }
)
DEPRECATED_STREAM_OPTIONS = frozenset({"free_on_close"})  # (taken, never suggested for a misspelt option)
WATCH = -1
"""The target of a watched ID: ICS 3.6's position read each cycle, torque and target left alone."""
IDLE_FRAME_INTERVAL = 0.01  # seconds between frames of an unpaced stream with every ID held
# Seconds a stream's close-out (its on_close commands) may take, at least: more on a line whose allowances are
# long (see Stream._bound_for).
FREE_ON_CLOSE_BOUND = 2.0
ON_CLOSE = ("hold", "free")
ON_RESUME = ("wait", "free")
# A paced stream judges its rate over each window of this many cycles: one that ran past nearly every slot
# of one says that its rate cannot be kept (stats.overruns counts it too, but a program that never reads it
# runs slow without a word).  Said once an episode: again only once the stream has kept its rate (at most
# the complement late) for RATE_KEPT_WINDOWS windows in a row, a flood never (a stream that stays behind).
RATE_CHECK_CYCLES = 20
RATE_CHECK_LATE = 18
RATE_KEPT_WINDOWS = 5
# Requests whose transaction outlasts a paced stream's slack (a whole 64-byte image each way): each goes once
# passed over in two slots, delaying that cycle (see _tell_rate_not_kept).
LONG_REQUESTS = ("read_eeprom", "write_eeprom", "read_memory", "write_memory")
NOT_STARTED = (
    "the stream is not started: use it as `async with bus.stream(...) as stream:` "
    "(blocking: `with bus.stream(...) as stream:`), or call its start()"
)
OnClose = Literal["hold", "free"]
OnResume = Literal["wait", "free"]


@dataclasses.dataclass(frozen=True, slots=True)
class _RateWindow:
    """Where a paced stream's window of cycles judged for its rate began: when, after which cycle, and the
    counts then of what a cycle's time can go to (see Stream._tell_rate_not_kept)."""

    started: float
    cycle: int
    overruns: int
    failures: list[int]  # the stream's per-slot failures
    others: dict[int, int]  # other IDs' unanswered requests on the line
    long: int  # the line's EEPROM and memory requests


class LineStreamOptions(TypedDict, total=False):
    """The options a stream takes beyond its IDs, ``rate_hz``, ``watch`` and ``offline``: the same for a
    line's stream and each line of a group's."""

    offline_after: int
    probe_interval: float
    on_close: OnClose
    on_resume: OnResume
    history: int
    free_on_close: bool  # deprecated: on_close="free"


class StreamOptions(LineStreamOptions, total=False):
    """The options of :meth:`Bus.stream <ics35_async.Bus.stream>` beyond the IDs and ``rate_hz``
    (see :class:`Stream`); a misspelt name is a type error."""

    watch: Iterable[int]
    offline: Iterable[int]
    hold_offline: bool


class Stream(FrameIterator[Frame]):
    """Streams position targets to ``ids`` and publishes a :class:`Frame` per cycle.

    Create with :meth:`Bus.stream` and use as ``async with``.  Every ID
    starts free (torque off, position still read back) until it is given a
    target: the safe start-up the reference recommends.  IDs in ``watch``
    (ICS 3.6 servos only) start *watched* instead: each cycle reads their
    position with ICS 3.6's position read, which neither moves nor frees
    them, until they are given a target (:meth:`watch` returns an ID to it).

    Args:
        bus: the line to stream on (a [`Bus`][ics35_async.bus.Bus] or another [`Line`][ics35_async.line.Line]).
        ids: the servo IDs of each cycle, in order (0..31, at least one, no repeats).
        rate_hz: cycles per second, paced (``None``: cycles back to back, as fast as the line allows).
        offline_after: failed cycles in a row before an ID leaves the cycle (it is probed meanwhile: an ID
            with a position target by a parameter read, which moves nothing; it comes back as ``on_resume`` says).
        probe_interval: seconds between probes of an offline ID.
        free_on_close: deprecated: ``on_close="free"``.
        history: how many cycles the statistics look back over.
        on_close: what the servos do when the stream ends: ``"hold"`` (keep their last target: one set
            since the last cycle is sent as the stream closes; an offline ID gets nothing) or ``"free"`` (torque
            off).  An offline ID's free, and the close command of one that failed twice and never answered, goes
            once, without the bus's retries (a free: with a probe's short wait; an offline ID's even on a line
            where nothing has answered yet).
        on_resume: after a lost port comes back, or an offline ID answers again: ``"wait"`` (hold each
            such ID that had a position target, sending no command, until the program sets its target
            again) or ``"free"``.
        watch: IDs (ICS 3.6 servos) read with the position read instead of starting free.
        offline: IDs the caller has just found silent (a robot's open: an unplugged leg): they start offline, out
            of the cycle, first probed one ``probe_interval`` after the start, instead of each failing
            ``offline_after`` cycles first at its whole reply allowance; one that answers comes back as any
            offline ID does.
        hold_offline: the IDs in ``offline`` with no target are probed with a parameter read too, which moves
            nothing, and come back held (see :attr:`held`), sent nothing, once they answer (default ``False``: such
            an ID is probed with its free, which reads it).  For a program that asks before freeing a servo (the
            free is an ICS 3.5 servo's only position read): one that kept its power and its target while its
            replies were lost (a loose signal wire) would drop what it bears.  A target, free or watch the program
            sets for one meanwhile ends this.

    Raises:
        InvalidArgument: a bad, duplicate or missing ID (in ``ids``, ``watch`` or ``offline``: theirs must be
            among ``ids``), or an option out of range.
    """

    _used_with = (
        "a stream runs in `async with bus.stream(...) as stream:`; in code without an event loop, a bus of"
        " `ics35_async.blocking` gives a stream for `with`"
    )
    _made_with = "bus.stream(...), group.stream(...)"

    def __init__(
        self,
        bus: Line,
        ids: Iterable[int],
        *,
        rate_hz: float | None = None,
        offline_after: int = 3,
        probe_interval: float = 0.5,
        free_on_close: bool | None = None,
        history: int = 2000,
        on_close: OnClose = "hold",
        on_resume: OnResume = "wait",
        watch: Iterable[int] = (),
        offline: Iterable[int] = (),
        hold_offline: bool = False,
    ) -> None:
        id_list = units.check_ids("ids", ids)
        if not id_list:
            raise InvalidArgument("a stream needs at least one ID")
        if len(set(id_list)) != len(id_list):
            raise InvalidArgument(f"duplicate IDs in {id_list}")
        rate_hz = units.check_rate_hz(rate_hz)
        offline_after = units.check_int("offline_after", offline_after, 1, 1_000_000)
        probe_interval = units.check_seconds("probe_interval", probe_interval, 0.001, 3600)
        history = units.check_int("history", history, 1, 10_000_000)
        if free_on_close is not None:
            units.check_bool("free_on_close", free_on_close)
            warnings.warn("free_on_close is deprecated: use on_close='free'", DeprecationWarning, stacklevel=2)
            on_close = "free" if free_on_close else "hold"
        if on_close not in ON_CLOSE:
            raise InvalidArgument(f"on_close must be one of {', '.join(ON_CLOSE)}, not {on_close!r}")
        if on_resume not in ON_RESUME:
            raise InvalidArgument(f"on_resume must be one of {', '.join(ON_RESUME)}, not {on_resume!r}")
        units.check_bool("hold_offline", hold_offline)
        self.bus = bus
        self.ids: tuple[int, ...] = tuple(id_list)
        self.rate_hz = rate_hz
        self.offline_after = offline_after
        self.probe_interval = float(probe_interval)
        self.on_close = on_close
        self.on_resume = on_resume
        n = len(id_list)
        self._index = {sid: k for k, sid in enumerate(id_list)}
        self._targets = [protocol.FREE] * n
        self._jobs = [(protocol.position_tx(sid, protocol.FREE), 3, sid) for sid in id_list]
        self._readers: list[protocol.ReadPosition | protocol.ReadParam | None] = [None] * n
        self._headers = [protocol.position_reply_header(sid, bus.baudrate) for sid in id_list]
        self._shapes = [protocol.position_reply_shape(header) for header in self._headers]  # (for bursts)
        self._positions = [-1] * n
        self._stamps = [0.0] * n
        self._answered = [False] * n
        self._none_answered = [False] * n  # (what each cycle starts from, and its order with every slot in it)
        self._every_slot = list(range(n))
        self._fail_run = [0] * n
        self._failures = [0] * n
        # Slots a transaction has been handed out for (to the wire, answered or not): what a program cut short as
        # its stream began can tell (see reached).
        self._reached = [False] * n
        self._offline = [False] * n
        self._next_probe = [0.0] * n
        # Slots that have answered a watch read (ICS 3.6's position read): one watched that goes offline unheard
        # may be an ICS 3.5 servo (see _fail); and the IDs told so (once each).
        self._watch_heard: set[int] = set()
        self._told_unwatchable: set[int] = set()
        # Why each slot is held ("" when not): no command until the program sets its target (see held).
        self._held = [""] * n
        # Slots offline from the start with no target that come back held rather than freed (see hold_offline).
        self._hold_return = [False] * n
        # Orders the program's target changes against the hooks that change a slot's hold or offline state
        # (a driver's I/O thread): a free landing in a rejoin must not end up held, sent nothing.  Never held
        # while calling into the bus (the driver's lock is taken first by the hooks' callers).
        self._slot_lock = threading.Lock()
        self._rejoined: set[int] = set()  # slots back from offline in the cycle in progress (see _rejoin)
        self._not_sent: list[int] = []  # the IDs the engine held back in the cycle in progress (see _skip)
        self._probes = 0  # offline IDs' probe reads (see _renew_job) that ended, answered or not
        # Slots whose target changed since a transaction last carried one for them: with on_close="hold"
        # the close sends these (a final pose set just before the block ends would be dropped otherwise).
        # A slot leaves it when a reply comes to the job that carries its current target (see _complete).
        self._unsent: set[int] = set()
        self._sent_on_close: dict[int, int] = {}
        # A burst (see the engine's plan_burst) runs the cycle's next transactions as planned: a new
        # target for one of them is held back (its slot in _stale) until the burst is over.  It may
        # run on into the cycles after this one (_beyond) where they are certain (see _upcoming).
        self._frozen: set[int] = set()
        self._stale: set[int] = set()
        self._beyond = False
        # The cycle in progress.
        self._order: list[int] = []
        self._pos = 0
        self._cur = -1
        self._cur_reader: protocol.ReadPosition | protocol.ReadParam | None = None  # how the reply on the wire is read
        self._cur_job: tuple[bytes, int, int] | None = None  # the job on the wire, as handed out
        self._cycle = 0
        self._cycle_start = 0.0
        self._t0 = 0.0
        self._wake_at = INF  # when a cycle waiting for its fixed-rate slot (or a probe) is due
        self._running = False
        self._closed = False
        self._closing_out: anyio.Event | None = None  # set once a close's commands are out (see aclose)
        self._close_out_bound = FREE_ON_CLOSE_BOUND  # how long that may take (see _bound_for)
        self._end_error: IcsError = BusClosed("stream closed")
        # Publishing.
        self._latest: Frame | None = None
        self._new_frame: anyio.Event | None = None  # made by the first waiter, set by the next frame
        # How the waiter makes it: anyio.Event() finds the running backend on every call (a few microseconds a
        # frame); once one is made, its own class (the backend's) is made directly.
        self._make_event: Callable[[], anyio.Event] = anyio.Event
        self._consumed_cycle = 0
        self._dropped = 0
        self._seen_latest = True
        # Statistics.
        self._cycle_times: deque[float] = deque(maxlen=history)
        self._starts: deque[float] = deque(maxlen=history)
        self._overruns = 0
        self._slot_checked = True
        self._first_start = 0.0
        self._window = _RateWindow(0.0, 0, 0, [], {}, 0)  # what the rate check judges, since its window began
        self._checked = 0  # cycles checked against their slot in the window
        self._behind = False  # told the rate is not kept, and not kept since (see RATE_KEPT_WINDOWS)
        self._kept_windows = 0
        self._missed = 0  # slots passed with no cycle, in all...
        self._frame_missed = 0  # ...and before the cycle in progress
        self._resumed = False  # the cycle in progress is the first since the line came back
        # Totals published with the latest frame (one tuple: the I/O thread may publish while the
        # consumer reads), and what the consumer has seen of them: a consumer that skips frames
        # still learns of every missed slot and every resume.
        self._resumes = 0
        self._published: tuple[Frame | None, int, int] = (None, 0, 0)  # the latest frame, its totals
        self._seen: tuple[int, int] = (0, 0)
        self._hooks = BoundSource.of(self)  # what the engine calls, kept off the public face
        # As if each had failed offline_after cycles (the caller's silence stands for them): a free one comes
        # back once its probe is answered (see _complete), one with a position target is probed with a read.
        self._offline_at_start = self._option_slots("offline", offline)
        watched = self._option_slots("watch", watch)  # (both checked before either takes effect)
        for k in self._offline_at_start:
            self._offline[k] = True
            self._fail_run[k] = offline_after
            self._hold_return[k] = hold_offline
        self.watch([self.ids[k] for k in watched])
        for k in self._offline_at_start:
            self._renew_job(k)

    def _option_slots(self, name: str, ids: Iterable[int]) -> list[int]:
        """The slots of the IDs an option of the stream's names (``offline``, ``watch``), checked as its own IDs
        are: a repeated one, or one the stream does not carry, is a mistake said with the option's name."""
        id_list = units.check_ids(name, ids)
        if len(set(id_list)) != len(id_list):
            raise InvalidArgument(f"duplicate IDs in {name} {id_list}")
        for sid in id_list:
            if sid not in self._index:
                raise InvalidArgument(f"{name}: ID {sid} is not in this stream {list(self.ids)}")
        return [self._index[sid] for sid in id_list]

    # ------------------------------------------------------------------ targets

    def _slot(self, servo_id: int) -> int:
        # (1.0 and True would find ID 1 in the index: an ID is a whole number here as everywhere, as bus.servo's;
        # a plain int, every ID of a control loop's targets each cycle, goes straight to the index)
        number = servo_id if type(servo_id) is int else units.whole_number(servo_id)
        if number is None:
            raise InvalidArgument(f"servo ID must be an int, not {type(servo_id).__name__}")
        try:
            return self._index[number]
        except KeyError:
            raise InvalidArgument(f"ID {servo_id!r} is not in this stream {list(self.ids)}") from None

    def set_target(self, servo_id: int, position: int) -> None:
        """Latest-value target ``position`` for ``servo_id``: 1..16383, or 0 for free (torque off, still read back).

        Raises:
            InvalidArgument: ``servo_id`` is not in the stream or ``position`` is out of range.
            BusClosed: the stream (or its bus) was closed.
        """
        self.apply_targets([(self._slot(servo_id), units.check_int("position", position, 0, protocol.POSITION_MAX))])

    def set_targets(self, targets: Mapping[int, int], *, lift_holds: bool = True) -> None:
        """Several ``targets`` ``{id: position}`` at once (1..16383; 0 frees: torque off, still read back); all are
        checked before any is applied.

        ``lift_holds=False``: an ID held now (see :attr:`held`) takes its target but stays held, sent nothing
        (a control loop that sets every target each cycle: a hold may begin after the frame it looked at).

        Raises:
            InvalidArgument: not a mapping, an ID not in the stream or a position out of range (nothing applied).
            BusClosed: the stream (or its bus) was closed.
        """
        self.apply_targets(self.check_targets(targets), lift_holds=lift_holds)

    def check_targets(self, targets: Mapping[int, int]) -> list[tuple[int, int]]:
        """Check every target (raising before anything changes) and return them ready for apply_targets.

        Raises:
            InvalidArgument: not a mapping, an ID not in the stream or a position out of range.
        """
        self._refuse_if_closed()
        if not isinstance(targets, Mapping):
            raise InvalidArgument(f"targets must be a mapping {{id: position}}, not {type(targets).__name__}")
        return [(self._slot(i), units.check_int("position", p, 0, protocol.POSITION_MAX)) for i, p in targets.items()]

    def _refuse_if_closed(self) -> None:
        """Targets for a stream closed by the program (or on a closed bus) would never be sent.  After a
        lost port they are still taken, silently: a group or a robot driving several lines goes on with
        the lines left through calls that reach every line's stream."""
        if self._closed and isinstance(self._end_error, BusClosed):
            raise BusClosed(str(self._end_error))

    def apply_targets(self, checked: list[tuple[int, int]], *, lift_holds: bool = True) -> None:
        """Apply the targets ``checked`` that :meth:`check_targets` returned.

        ``lift_holds=False``: a held ID (see :attr:`held`) takes the target but stays held, sent nothing, until a
        target set with ``lift_holds`` (the program's decision, not the next step of a running motion).

        Raises:
            BusClosed: the stream (or its bus) was closed: nothing would send them.
        """
        self._refuse_if_closed()
        kick = False
        frozen = self._frozen
        unsent = self._unsent
        with self._slot_lock:
            for k, p in checked:
                if self._held[k] and lift_holds:
                    self._held[k] = ""
                    unsent.add(k)
                    kick = True  # a stream waiting with every ID held has work again
                if self._hold_return[k] and lift_holds:  # (the program's own word for it: its probe follows it)
                    self._hold_return[k] = False
                    if self._targets[k] == p:  # (free already: the probe becomes the free itself)
                        self._job_changed(k)
                if self._targets[k] != p:
                    self._targets[k] = p
                    if frozen and k in frozen:
                        self._stale.add(k)  # (and unsent again once renewed, see _upcoming_done)
                        kick = True  # a burst runs the old target: it stops at its next boundary
                    else:
                        self._renew_job(k)
                    # After the new job (a driver's I/O thread may be completing the old one meanwhile: its
                    # reply, to a job no longer current, leaves the slot unsent, see _complete).
                    unsent.add(k)
        if kick and self._running:
            self.bus.kick()

    def set_target_degrees(self, servo_id: int, degrees: float) -> None:
        """Like :meth:`set_target`: ``servo_id`` to ``degrees`` (-135..+135, 0 neutral).

        Raises:
            InvalidArgument: ``servo_id`` is not in the stream or the angle is out of range.
        """
        self.set_target(servo_id, units.degrees_to_position(degrees))

    def set_targets_degrees(self, targets: Mapping[int, float], *, lift_holds: bool = True) -> None:
        """Like :meth:`set_targets`, in degrees; ``lift_holds=False`` leaves a held ID held, as there.

        Raises:
            InvalidArgument: not a mapping, an ID not in the stream or an angle out of range (nothing applied).
        """
        if not isinstance(targets, Mapping):
            raise InvalidArgument(f"targets must be a mapping {{id: degrees}}, not {type(targets).__name__}")
        self.set_targets({i: units.degrees_to_position(d) for i, d in targets.items()}, lift_holds=lift_holds)

    def free(self, ids: Iterable[int] | None = None) -> None:
        """Put ``ids`` (default: all) in free mode: torque off, positions still read back.

        Raises:
            InvalidArgument: an ID is not in the stream (nothing changes).
            BusClosed: the stream (or its bus) was closed.
        """
        self.set_targets(dict.fromkeys(self.ids if ids is None else units.check_ids("ids", ids), protocol.FREE))

    def watch(self, ids: Iterable[int] | None = None) -> None:
        """Watch ``ids`` (default: all): read their position with ICS 3.6's read, sending no target.

        For ICS 3.6 servos only (an ICS 3.5 servo stays silent to the read,
        and goes offline in the stream); the torque is left as it is.

        Raises:
            InvalidArgument: an ID is not in the stream (nothing changes).
        """
        slots = [self._slot(i) for i in (self.ids if ids is None else units.check_ids("ids", ids))]
        kick = False
        with self._slot_lock:
            for k in slots:
                if self._targets[k] != WATCH:
                    self._watch_heard.discard(k)  # (heard by this watch, not an earlier one)
                self._targets[k] = WATCH
                self._held[k] = ""
                self._hold_return[k] = False
                self._unsent.discard(k)  # (a watched ID gets no command)
                if k in self._frozen:
                    self._stale.add(k)
                    kick = True
                else:
                    self._renew_job(k)
        if kick and self._running:
            self.bus.kick()

    def _renew_job(self, k: int) -> None:
        """The command that carries ID slot ``k``'s target, and how its reply is read.

        An offline ID with a position target is probed with a parameter read, which moves nothing: its servo
        may have restarted (a brown-out: free, where the load left it) and its old target would throw it there
        at full speed.  Once it answers it comes back held or free (see :meth:`_rejoin`).  So is one offline from
        the start under ``hold_offline``, whose free would drop what its servo bears.  Free and watched IDs are
        probed with their own command: neither moves a servo.
        """
        sid, target = self.ids[k], self._targets[k]
        reader: protocol.ReadPosition | protocol.ReadParam
        if target == WATCH or (self._offline[k] and (target != protocol.FREE or self._hold_return[k])):
            reader = protocol.ReadPosition(sid) if target == WATCH else protocol.ReadParam(sid, protocol.Param.STRETCH)
            self._readers[k] = reader
            self._jobs[k] = (reader.tx, reader.reply_len, sid)
        else:
            self._readers[k] = None
            self._jobs[k] = (protocol.position_tx(sid, target), 3, sid)

    def target(self, servo_id: int) -> int:
        """The current target of ``servo_id``: a position, 0 (free) or :data:`WATCH`; InvalidArgument if it
        is not in the stream."""
        return self._targets[self._slot(servo_id)]

    @property
    def held(self) -> dict[int, str]:
        """IDs held now, sent no command until the program sets their target (or frees or watches them), and
        why: ``"resumed"`` (their lost port came back) or ``"rejoined"`` (they answered again after going
        offline): their servos may have restarted, free and elsewhere.  (Frames list them in ``held`` too, as
        of their cycle.)"""
        return {sid: why for sid, why in zip(self.ids, self._held, strict=True) if why}

    @property
    def reached(self) -> frozenset[int]:
        """IDs the stream has sent a transaction to so far (its target, ICS 3.6's read or an offline ID's probe),
        answered or not: those never reached have heard nothing from it (the close's commands aside: see
        :attr:`targets_sent_on_close`)."""
        return frozenset(sid for sid, reached in zip(self.ids, self._reached, strict=True) if reached)

    @property
    def offline(self) -> frozenset[int]:
        """IDs out of the cycle after failing ``offline_after`` cycles in a row (probed every ``probe_interval``)."""
        return frozenset(sid for sid, off in zip(self.ids, self._offline, strict=True) if off)

    # ------------------------------------------------------------------ the engine's hooks (BackgroundSource)

    def _slot_due(self, now: float) -> float | None:
        if self.rate_hz is None or not self._running:
            return None
        if self._pos < len(self._order) or not self._cycle:
            return now  # a cycle runs (or the first one starts at once): its transactions go first
        return self._t0 + self._cycle / self.rate_hz

    def _next_transaction(self, now: float) -> tuple[bytes, int, int] | None:
        if not self._running and not self._planned_next():
            # (stopped: nothing more, but what a running burst planned, and so already put on the line,
            # until the burst is over: the engine is fed it afterwards, and the detach waits for it)
            return None
        if self._pos >= len(self._order) and not self._start_cycle(now):
            return None
        k = self._order[self._pos]
        self._cur = k
        self._reached[k] = True
        # The reply is read as the command sent (set_targets or watch may change it meanwhile).
        self._cur_reader = self._readers[k]
        self._cur_job = job = self._jobs[k]
        return job

    def _probing_silent(self) -> bool:
        # (Asked by the engine as it detaches this stream with its transaction on the wire: see BackgroundSource.)
        k = self._cur
        return k >= 0 and self._offline[k]

    def _planned_next(self) -> bool:
        """Has a running burst put this stream's next transaction on the line already (see _upcoming)?"""
        if self._pos < len(self._order):
            return self._order[self._pos] in self._frozen
        return self._beyond  # the next cycle's first

    def _upcoming(self, limit: int) -> list[Upcoming]:
        start = self._pos  # the one on the wire
        order = self._order
        slots = order[start : start + limit] if limit > 0 else []
        ends = {len(slots) - 1} if slots and start + len(slots) == len(order) else set()
        n = len(self.ids)
        if (
            ends
            and len(slots) < limit
            and self.rate_hz is None
            and self._running
            and len(order) == n  # none held, none offline but one probed now
            and not any(self._offline)  # (one gone offline in this cycle is in its order still)
            and not any(self._held)  # (one back from offline in this cycle too: held, it leaves the next)
            and all(reader is None for reader in self._readers)  # (a watched ID's read ends a plan)
        ):
            # Unpaced, with every ID in the cycle: the next cycle starts as soon as this one ends, with
            # every ID again (only a failure, which ends a burst, takes one out), so a burst may run on
            # through the cycles after it.  Each cycle's frame is news: the burst is fed there.
            self._beyond = True
            while len(slots) < limit:
                more = order[: limit - len(slots)]
                slots += more
                if len(more) == n:
                    ends.add(len(slots) - 1)
        with self._slot_lock:  # (a target set now goes to _stale, renewed once the burst is over)
            self._frozen.update(slots[1:])
        for k in slots:  # (on the wire as planned, whether or not the burst runs to its end)
            self._reached[k] = True
        jobs, readers, shapes = self._jobs, self._readers, self._shapes
        # (a watched ID's reply is read by the codec's ICS 3.6 read, which gives no shape: a burst ends there)
        return [(*jobs[k], b"" if readers[k] is not None else shapes[k], i in ends) for i, k in enumerate(slots)]

    def _upcoming_done(self) -> None:
        self._beyond = False
        with self._slot_lock:  # (a target set meanwhile lands before or after, not in between)
            self._frozen.clear()
            stale, self._stale = self._stale, set()
            for k in stale:
                self._renew_job(k)
                self._unsent.add(k)  # (its reply came to the planned job: the new target is not yet sent)

    def _complete(self, buf: bytearray, offset: int, now: float) -> ReplyError | None:
        k = self._cur
        if k < 0:
            return None  # not ours: the bus routes only our own, but stay safe
        reader = self._cur_reader
        if reader is not None:  # a watched ID (ICS 3.6's position read), or an offline one's probe
            try:
                position = reader.parse(bytes(buf[offset:]))
            except ReplyError as exc:
                return exc
            if type(reader) is protocol.ReadParam:  # (a stretch, not a position)
                self._probes += 1
                with self._slot_lock:
                    if self._offline[k]:
                        self._rejoin(k)
                    else:  # (back online already: its job is its target's again)
                        self._rejoined.add(k)
                        self._job_changed(k)
                self._advance(now)
                return None
            self._watch_heard.add(k)
        else:
            position = position_from_reply(buf, offset, self._headers[k])
        if position < 0:  # let the codec name what is wrong
            try:
                # (any target: a position reply's shape is the same; the target may be WATCH by now)
                command = protocol.Position(self.ids[k], protocol.FREE, baudrate=self.bus.baudrate)
                position = command.parse(bytes(buf[offset:]))
            except ReplyError as exc:
                return exc  # the engine counts it, then calls fail
        self._positions[k] = position
        self._stamps[k] = now
        self._answered[k] = True
        if self._unsent and self._cur_job is self._jobs[k] and k not in self._stale:
            self._unsent.discard(k)  # the slot's current target went out (a stale one's job is not yet renewed)
        if self._fail_run[k]:  # only fail() marks an ID offline, always after a failure
            self._fail_run[k] = 0
            self._offline[k] = False
        self._pos = pos = self._pos + 1  # _advance, inline: this runs once per transaction
        if pos >= len(self._order):
            self._publish(now)
        return None

    def _fail(self, exc: ReplyError, now: float, sent: bool) -> None:
        k = self._cur
        if k < 0:
            return
        if not sent:  # (failed by the guard read before it: its frame lists it as sent nothing, as a held one)
            self._not_sent.append(self.ids[k])
        self._failures[k] += 1
        self._fail_run[k] += 1
        if type(self._cur_reader) is protocol.ReadParam:
            self._probes += 1
        if self._fail_run[k] >= self.offline_after and not self._offline[k]:
            with self._slot_lock:
                self._offline[k] = True
                self._job_changed(k)  # probed with a read from now on (see _renew_job)
            if self._targets[k] == WATCH and k not in self._watch_heard:
                self._tell_unwatchable(k)
        if self._offline[k]:
            self._next_probe[k] = now + self.probe_interval
        self._advance(now)

    def _tell_unwatchable(self, k: int) -> None:
        """Watched slot ``k`` went offline without answering one watch read since its watch began: say it
        may be an ICS 3.5 servo (most KRS servos), silent to the ICS 3.6 position read, once an ID (its
        frames say only "offline", as for a servo that is not there)."""
        sid = self.ids[k]
        if sid in self._told_unwatchable:
            return
        self._told_unwatchable.add(sid)
        log.warning(
            "ID %d went offline without answering the position read watch() sends: it is not on the line,"
            " or it is an ICS 3.5 servo, which stays silent to that ICS 3.6 read; free it to read where it is"
            " (stream.free([%d]), torque off) or give it a target",
            sid,
            sid,
        )

    def _rejoin(self, k: int) -> None:
        """Offline ID slot ``k`` answered its probe (under ``_slot_lock``).  Its servo may have restarted
        meanwhile (free, elsewhere): as after a lost port (see _line_resumed), a position target waits for the
        program (held: no command until it sets the target again) or is dropped for free, as ``on_resume``
        says."""
        self._fail_run[k] = 0
        self._offline[k] = False
        self._rejoined.add(k)
        target = self._targets[k]
        if target != protocol.FREE and target != WATCH:  # (freed or watched meanwhile: neither moves a servo)
            if self.on_resume == "free":
                self._targets[k] = protocol.FREE
            else:
                self._held[k] = "rejoined"
        elif self._hold_return[k]:  # (no target yet: its free waits for the program, see hold_offline)
            self._held[k] = "rejoined"
        self._hold_return[k] = False
        self._job_changed(k)

    def _job_changed(self, k: int) -> None:
        """Slot ``k``'s command is to change: now, or where a running burst that planned it is over."""
        if k in self._frozen:
            self._stale.add(k)
        else:
            self._renew_job(k)

    def _skip(self, now: float) -> None:
        # The engine held this ID's transaction back (its reply to a failed command may still
        # come): the frame shows it unanswered this cycle, and sent nothing; nothing failed, so nothing is counted.
        if self._cur >= 0:
            self._not_sent.append(self.ids[self._cur])
            self._advance(now)

    def _advance(self, now: float) -> None:
        self._pos += 1
        if self._pos >= len(self._order):
            self._publish(now)

    def _line_resumed(self, now: float) -> None:
        # The servos may have lost power and restarted (free, somewhere else) while the port was
        # gone: the old targets could throw them across their range.  A targeted ID gets no
        # command until the program sets its target again ("wait"), or goes free ("free").
        # Free and watched IDs carry on: neither command moves a servo.
        with self._slot_lock:
            for k, target in enumerate(self._targets):
                # (An offline ID is left to its probe, a read: held now, it would never be probed again; it
                # comes back as _rejoin says once it answers.)
                if target != protocol.FREE and target != WATCH and not self._offline[k]:
                    if self.on_resume == "free":
                        self._targets[k] = protocol.FREE
                        self._renew_job(k)
                    else:
                        self._held[k] = "resumed"
        # The cycle the loss cut short is dropped; the next starts on a fresh schedule.
        self._rejoined.clear()
        self._not_sent.clear()
        self._order = []
        self._pos = 0
        self._cur = -1
        self._slot_checked = True
        self._resumed = True
        if self.rate_hz is not None and self._cycle:
            self._reanchor(now, self._t0 + self._cycle / self.rate_hz)  # (the outage's slots count as missed)

    def _tell_rate_not_kept(self, now: float) -> None:
        """Warn that the rate is not kept in the window ending ``now`` (its first cycles, or a later window),
        naming every cause it can count that cost the window's cycles (the stream's own silent servos, requests
        to silent servos on the line, the program's EEPROM and memory requests) when together they could
        account for half the late cycles; or else the wire time of its cycle (or, where the wire leaves half
        the period, the answers' waits and a busy host)."""
        n, baud, window = len(self.ids), int(self.bus.baudrate), self._window
        overruns, cycles = self._overruns - window.overruns, self._cycle - window.cycle
        which = f"its first {cycles}" if not window.cycle else f"its last {cycles}"
        late = (
            f"stream of {n} IDs cannot keep rate_hz={self.rate_hz:g}: {overruns} of {which} cycles ran past "
            f"their slot (about {cycles / max(now - window.started, 1e-9):.0f} cycles/s)"
        )
        # Each cause the stream can count, with what it cost: the stream's own IDs that never answered, or
        # failed in half its cycles (each costs its whole reply allowance a cycle until it goes offline: a wrong
        # baud rate silences them all); the program's requests to other IDs that went unanswered (each holds the
        # line for its allowance); its EEPROM and memory requests (each goes once passed over in two slots: see
        # LONG_REQUESTS).  Told when together they could account for half the late cycles (one ID gone offline
        # early could not), every one that cost any: the first alone would send the program to mend one of them.
        causes: list[tuple[str, int]] = []  # (what to say, the transactions it cost)
        failures = [now_ - then for now_, then in zip(self._failures, window.failures, strict=True)]
        own = [sid for sid, seen, failed in zip(self.ids, self._positions, failures, strict=True)
               if failed and (seen < 0 or 2 * failed >= cycles)]  # fmt: skip
        if own:
            said = (
                f"its ID(s) {', '.join(map(str, own))} did not answer: each silent servo costs its whole reply "
                f"allowance every cycle until it goes offline (offline_after={self.offline_after}): check its "
                "power, wiring, ID and baud rate (ics35 scan looks at every ID at every rate)"
            )
            causes.append((said, sum(failures[self._index[sid]] for sid in own)))
        others = self._others_unanswered()
        grown = {i: count - window.others.get(i, 0) for i, count in others.items()}
        silent = sorted(i for i, more in grown.items() if more > 0)
        if silent:
            said = (
                f"requests on the same line to ID(s) {', '.join(map(str, silent))} went unanswered "
                f"{sum(grown.values())} times: a request to a servo that does not answer holds the line for its "
                "whole reply allowance (poll such a servo less often)"
            )
            causes.append((said, sum(grown.values())))
        long = self._long_requests() - window.long
        if long:
            image = protocol.ReadEeprom(0)
            said = (
                f"the program's requests read or wrote {long} EEPROM or memory images on the same line: each "
                f"takes {protocol.wire_time(len(image.tx) + image.reply_len, baud) * 1e3:.1f} ms at {baud} baud "
                "on the wire alone, more than a cycle's slack, so it goes once passed over in two slots and delays "
                "that cycle (read and write EEPROMs with the stream stopped, or ask a lower rate)"
            )
            causes.append((said, long))
        if causes and 2 * sum(cost for _, cost in causes) >= overruns:
            first = ", and " if own else ", while "
            log.warning("%s%s", late + first, "; and ".join(said for said, _ in causes))
            return
        command = protocol.Position(self.ids[0], protocol.FREE, baudrate=baud)
        wire = n * protocol.wire_time(len(command.tx) + command.reply_len, baud)  # each command and its reply
        period = 1 / self.rate_hz if self.rate_hz is not None else 0.0  # (only a paced stream is told)
        if wire < period / 2:
            # The wire leaves half the period or more: a faster rate would not help.  The time went to the
            # answers (an adapter's latency timer) or to the host (a busy thread: what holds the loop's thread
            # back also lengthens the answers it measures, so the two are not told apart here).
            log.warning(
                "%s; at %d baud its %d position transactions take only %.1f ms of each %.1f ms period on the wire: "
                "the rest goes to each answer's wait, where an adapter's latency timer adds up to 16 ms "
                "(ics35 doctor measures it), or to a busy host (a thread of this program computing without "
                "pause holds Python's GIL, which the stream's event loop needs at each transaction on the "
                "ordinary path, once a cycle on the compiled one: see the control-loop docs); or ask a lower rate",
                late,
                baud,
                n,
                wire * 1e3,
                period * 1e3,
            )
            return
        log.warning(
            "%s; at %d baud its %d position transactions take %.1f ms on the wire alone, plus each servo's answer "
            "time: raise the baud rate, stream fewer IDs or ask a lower rate (or the host is busy)",
            late,
            baud,
            n,
            wire * 1e3,
        )

    def _long_requests(self) -> int:
        """The line's EEPROM and memory transactions so far (the program's requests: the stream sends none)."""
        done = self.bus.stats.by_command
        return sum(done.get(name, 0) for name in LONG_REQUESTS)

    def _others_unanswered(self) -> dict[int, int]:
        """Each other ID's unanswered transactions on this line so far (requests: the stream's are its own)."""
        mine = set(self.ids)
        return {i: c.timeouts for i, c in self.bus.stats.per_id.items() if i is not None and i not in mine}

    def _line_closed(self, exc: IcsError) -> None:
        self._end_error = exc
        self._stop(detach=False)  # the engine has detached us already (and may hold its driver's lock)

    # ------------------------------------------------------------------ cycles

    def _start_cycle(self, now: float) -> bool:
        """Begin the next cycle if it is due; False (and ``wake_at`` set) while waiting for a slot."""
        self._wake_at = INF
        if self.rate_hz is not None and self._cycle:
            due = self._t0 + self._cycle / self.rate_hz  # start of cycle number self._cycle + 1
            if not self._slot_checked:
                self._check_slot(now, due)
            if now < due:
                self._wake_at = due
                return False
            if now - due > 1 / self.rate_hz:
                self._reanchor(now, due)
        if not self._cycle:
            self._t0 = now
            self._first_start = now
            for k in self._offline_at_start:  # (not in the first cycle: the caller has just asked them)
                self._next_probe[k] = now + self.probe_interval
            if self.rate_hz is not None:  # (what the rate check tells apart, see _tell_rate_not_kept)
                self._window = self._window_from(now)
        self._cycle += 1
        n = len(self.ids)
        self._answered[:] = self._none_answered  # (slices: this runs once a cycle, in C)
        if any(self._held) or any(self._offline):
            held, offline, probe = self._held, self._offline, self._next_probe
            order = [k for k in range(n) if not held[k] and (not offline[k] or now >= probe[k])]
        else:
            order = self._every_slot[:]
        self._order = order
        self._pos = 0
        self._cycle_start = now
        self._starts.append(now)
        if not order:
            # Nothing to send (every ID offline or held): a frame says so; then wait for the next
            # probe or slot (unpaced: frames keep coming at IDLE_FRAME_INTERVAL, so a program
            # waiting for one sees what is held) instead of spinning.
            self._publish(now)
            probes = [t for k, t in enumerate(self._next_probe) if self._offline[k] and not self._held[k]]
            if self.rate_hz is not None:
                slot = self._t0 + self._cycle / self.rate_hz
                # Its work (none) ended now, before the next slot: checked here, not when the timer for
                # that slot fires (just after it, which would make every empty cycle an overrun).
                self._check_slot(now, slot)
            else:
                slot = now + IDLE_FRAME_INTERVAL if any(self._held) else INF
            self._wake_at = min([*probes, slot])
            return False
        return True

    def _check_slot(self, now: float, due: float) -> None:
        """The cycle just published ended ``now``; the next is due at ``due``: count it an overrun if late, and
        judge the rate at the end of each window of cycles (see _judge_rate).  An overrun is a cycle whose own
        work ran past the next slot, not a timer that fired late (the loop's timers have ~1 ms resolution)."""
        self._slot_checked = True
        if now > due:
            self._overruns += 1
        self._checked += 1
        if self._checked == RATE_CHECK_CYCLES:
            self._judge_rate(now)

    def _judge_rate(self, now: float) -> None:
        """A window of cycles is checked: tell the rate not kept if nearly all of them were late and it is
        not told already in this episode; end the episode once the rate has been kept a while; open the next
        window."""
        late = self._overruns - self._window.overruns
        if late >= RATE_CHECK_LATE:
            if not self._behind:
                self._tell_rate_not_kept(now)
            self._behind = True
            self._kept_windows = 0
        elif late <= RATE_CHECK_CYCLES - RATE_CHECK_LATE:
            self._kept_windows += 1
            if self._kept_windows >= RATE_KEPT_WINDOWS:
                self._behind = False
        else:  # (neither kept nor lost: the episode goes on)
            self._kept_windows = 0
        self._window = self._window_from(now)
        self._checked = 0

    def _window_from(self, now: float) -> _RateWindow:
        """A rate window beginning ``now``: the counts its causes are told from (see _tell_rate_not_kept)."""
        return _RateWindow(
            now, self._cycle, self._overruns, self._failures[:], self._others_unanswered(), self._long_requests()
        )

    def _reanchor(self, now: float, due: float) -> None:
        """A paced stream's next cycle starts now (on a fresh schedule, rather than bursting to catch up),
        its cycle number ``self._cycle + 1`` having been due at ``due``: the whole slots since are missed."""
        rate = self.rate_hz
        assert rate is not None
        missed = max(0, int((now - due) * rate))
        self._missed += missed
        self._frame_missed += missed
        self._t0 = now - self._cycle / rate

    def _publish(self, now: float) -> None:
        self._slot_checked = False
        ids, answered, values, times, rejoined = self.ids, self._answered, self._positions, self._stamps, self._rejoined
        positions: dict[int, int]
        stamps: dict[int, float]
        failed = []
        if len(self._order) == len(ids) and all(answered):  # every ID in the cycle answered: in C
            positions, stamps = dict(zip(ids, values, strict=True)), dict(zip(ids, times, strict=True))
        else:
            positions, stamps = {}, {}
            for k in self._order:  # (locals: this runs for every ID of every cycle)
                if answered[k]:
                    sid = ids[k]
                    positions[sid] = values[k]
                    stamps[sid] = times[k]
                elif k not in rejoined:  # (back from offline: answered a read that gives no position)
                    failed.append(ids[k])
        self._rejoined.clear()
        not_sent = frozenset(self._not_sent) if self._not_sent else frozenset()
        self._not_sent.clear()
        self._order = []
        self._pos = 0
        self._cycle_times.append(now - self._cycle_start)
        if not self._seen_latest:
            self._dropped += 1
        self._seen_latest = False
        self._latest = Frame(
            cycle=self._cycle,
            positions=positions,
            timestamps=stamps,
            failed=frozenset(failed),
            offline=self.offline if any(self._offline) else frozenset(),
            started=self._cycle_start,
            finished=now,
            missed_slots=self._frame_missed,
            resumed=self._resumed,
            held=frozenset(sid for sid, held in zip(ids, self._held, strict=True) if held)
            if any(self._held)
            else frozenset(),
            not_sent=not_sent,
        )
        if self._resumed:
            self._resumes += 1
        self._published = (self._latest, self._missed, self._resumes)  # one write: read whole
        self._frame_missed = 0
        self._resumed = False
        self.bus.notify(self._wake_waiters)  # this may run in a driver's I/O thread

    def _wake_waiters(self) -> None:
        event, self._new_frame = self._new_frame, None
        if event is not None:
            event.set()

    # ------------------------------------------------------------------ consuming

    async def next_frame(self) -> Frame:
        """The newest frame not yet returned; waits for one if needed.

        A slow consumer never slows the bus: it gets the latest frame, with
        ``skipped`` telling how many it missed.  Each frame goes to one caller: a second task
        calling it takes frames from the first (read :attr:`latest` there).  Once the stream is closed
        (or its bus closed or lost), it raises, even if a frame came meanwhile.

        Raises:
            InvalidArgument: the stream was never started (``async with bus.stream(...)`` starts it).
            BusClosed, PortLost: the stream or its bus was closed, or the port is lost.
        """
        while self._closed or self._latest is None or self._latest.cycle <= self._consumed_cycle:
            if self._closed:
                raise again(self._end_error)
            if not self._running:
                raise InvalidArgument(NOT_STARTED)
            if self._new_frame is None:
                self._new_frame = event = self._make_event()
                self._make_event = type(event)
            await self._new_frame.wait()
        published, missed_total, resumes = self._published  # the frame and its totals, together
        # (the I/O thread may have set _latest and not yet _published: then the totals lag one frame)
        frame = published if published is not None and published.cycle > self._consumed_cycle else self._latest
        skipped = frame.cycle - self._consumed_cycle - 1 if self._consumed_cycle else 0
        self._consumed_cycle = frame.cycle
        self._seen_latest = True
        seen = self._seen
        self._seen = (missed_total, resumes)
        missed, resumed = missed_total - seen[0], resumes > seen[1]
        if skipped or missed != frame.missed_slots or resumed != frame.resumed:
            # What the skipped frames told is not lost: their missed slots add up, a resume sticks.
            frame = dataclasses.replace(frame, skipped=skipped, missed_slots=missed, resumed=resumed)
        return frame

    @property
    def latest(self) -> Frame | None:
        """The newest published frame (does not mark it consumed)."""
        return self._latest

    @property
    def stats(self) -> StreamStats:
        """Achieved rate, cycle-time percentiles, jitter, overruns and per-ID failures so far."""
        times = sorted(self._cycle_times)
        starts = list(self._starts)
        intervals = [b - a for a, b in itertools.pairwise(starts)]
        # Intervals between cycle starts: the first frame is no whole period yet (counted as one, a new
        # stream's rate would read far above its rate_hz: after one frame, one over its cycle time).
        latest = self._latest
        elapsed = (latest.started - self._first_start) if latest else 0.0
        return StreamStats(
            cycles=self._cycle,
            rate_hz=(latest.cycle - 1) / elapsed if latest and elapsed > 0 else 0.0,
            cycle_time_p50=percentile(times, 50),
            cycle_time_p90=percentile(times, 90),
            cycle_time_p99=percentile(times, 99),
            cycle_time_max=times[-1] if times else 0.0,
            jitter=statistics.pstdev(intervals) if len(intervals) > 1 else 0.0,
            overruns=self._overruns,
            frames_dropped=self._dropped,
            failures={sid: n for sid, n in zip(self.ids, self._failures, strict=True) if n},
            offline=self.offline,
            missed_slots=self._missed,
            probes=self._probes,
        )

    # ------------------------------------------------------------------ lifetime

    async def start(self) -> Stream:
        """Start streaming (``async with`` does); BusClosed if closed or the bus is not, InvalidArgument if busy."""
        if self._closed:  # (a program in phases: the second `async with stream:` needs a new one)
            raise self._ran_once()
        if not self._running:
            self._running = True
            try:
                self.bus.attach_source(self._hooks, close_out=self.aclose)
            except BaseException:
                self._running = False
                raise
        return self

    @property
    def targets_sent_on_close(self) -> dict[int, int]:
        """What the stream's close sent, ``{id: position}`` (0: free): with ``on_close="free"`` every ID's free,
        with ``"hold"`` the targets set since their last cycle (offline, held and watched IDs get nothing);
        empty before the close, or if the bus was closed first.  A command the line could not take (its port
        lost, the bus closed meanwhile, the close's time bound run out) is left out: its servo may still hold
        what it held (one cut off on the wire by a lost port may have arrived)."""
        return dict(self._sent_on_close)

    @property
    def free_on_close(self) -> bool:
        """Deprecated: ``on_close == "free"``."""
        return self.on_close == "free"

    async def aclose(self) -> None:
        """Stop streaming; the bus stays usable.  With ``on_close="free"`` every ID goes free
        (torque off); with ``"hold"`` (the default) each servo keeps holding its last target (a held or
        offline ID is sent nothing: it keeps what it last had, free if it restarted), and a
        target set since the last cycle (a final pose set just before the block ends) is sent first."""
        if self._closed:
            # Another close (the bus's, a second task's) waits until this stream's close-out is done: the
            # bus closing meanwhile would fail the commands it queued (the servos left holding).
            closing = self._closing_out
            if closing is not None:
                await despite_cancellation(closing.wait, self._close_out_bound)
            return
        self._stop()
        if self.on_close == "free":
            last: dict[int, int] = dict.fromkeys(self.ids, protocol.FREE)
        else:  # "hold": the targets set since their last cycle (offline and held IDs get nothing)
            last = {
                self.ids[k]: self._targets[k]
                # (copied at once: an I/O thread may still be finishing; a stale slot's target is set, not sent)
                for k in sorted(self._unsent | self._stale)
                if not self._offline[k] and not self._held[k] and self._targets[k] != WATCH
            }
        if not self.bus.is_open:
            last = {}
        self._sent_on_close = dict(last)  # (a copy: a send the line could not take leaves it)
        if last:
            # To its end: a stream closed because its program was cancelled (Ctrl-C, SIGTERM through
            # ics35_async.run, another cancellation meanwhile) must still free its servos, or send the
            # last pose it was given; bounded, in case the line is gone.
            self._closing_out = closing = anyio.Event()
            self._close_out_bound = self._bound_for(len(last))
            # (Optional hooks of a Line: one made elsewhere may lack them, and must still close out.)
            getattr(self.bus, "close_out_begins", _no_hook)(closing)
            try:
                await despite_cancellation(functools.partial(self._send_all, last), self._close_out_bound)
            finally:
                closing.set()
                getattr(self.bus, "close_out_ends", _no_hook)(closing)

    def longest_cycle(self) -> float:
        """Seconds one of this stream's cycles may take at most (a bound, not a forecast): each ID's command
        waiting its whole reply allowance (a servo that does not answer, a slow link's learnt lateness at its most)
        and a resync after it, or a paced stream's period if longer; requests beside the stream add their own
        time.  For a program waiting for a cycle to carry a command (a free before it stops); 2 s
        (:data:`FREE_ON_CLOSE_BOUND`) on a line that does not tell its allowances."""
        each = self._longest_command()
        if each is None:
            return FREE_ON_CLOSE_BOUND
        return max(0.0 if self.rate_hz is None else 1.0 / self.rate_hz, len(self.ids) * each)

    def _longest_command(self) -> float | None:
        """Seconds one position command may take on this line at most (see :meth:`longest_cycle`); None where
        the line does not tell its allowances."""
        timing: BusTiming | None = getattr(self.bus, "timing", None)  # (a Line made elsewhere may not say)
        if timing is None:
            return None
        position = 6  # bytes on the wire: a position command and its reply
        return timing.allowance(position, self.bus.baudrate) + timing.link_extra_max + timing.quiet_time

    def _bound_for(self, commands: int) -> float:
        """Seconds a close-out of ``commands`` may take: :data:`FREE_ON_CLOSE_BOUND`, or, where more, the time
        the line may need for them and a transaction already on the wire, each at its longest.  A fixed bound
        ran out on a slow link's long allowance (a TCP bridge) in the frees of absent IDs, and a servo queued
        behind them was never freed.  The close-out's requests take the bus's retries: a command that is not
        answered is tried again, each retry after a guard read (see the engine's guard), so each may cost
        ``1 + 2 * retries`` allowances; counted once, the bound ran out with ``retries=1`` (ics35's default)."""
        each = self._longest_command()
        if each is None:
            return FREE_ON_CLOSE_BOUND
        retries: int = getattr(self.bus, "retries", 0)  # (a Line made elsewhere may not have them)
        return max(FREE_ON_CLOSE_BOUND, (commands * (1 + 2 * retries) + 1) * each)

    async def _send_all(self, targets: dict[int, int]) -> None:
        async with anyio.create_task_group() as group:
            for servo_id, position in targets.items():
                group.start_soon(self._send_quietly, servo_id, position)

    async def _send_quietly(self, servo_id: int, position: int) -> None:
        k = self._index[servo_id]
        # An offline ID (silent offline_after times in a row), or one that never answered and failed twice or more
        # (not yet offline: a short run, a long allowance), does not answer, most likely.  It gets its command
        # once: a retry, and the guard read before it, would each wait a whole reply allowance more at the end of
        # the program, for each such ID.
        offline = self._offline[k]
        unheard = offline or (self._positions[k] < 0 and self._failures[k] >= 2)
        baudrate = self.bus.baudrate
        command: protocol.Position = protocol.Position(servo_id, position, baudrate=baudrate)
        if offline and position == protocol.FREE:
            # Nor a whole allowance for its silence, which the stream has already waited for: the free goes out
            # (a servo back executes it), its reply, which would only confirm it, waited for as briefly as a probe's,
            # even on a line where nothing has answered yet (ten joints of an unplugged leg line under a 1 s
            # allowance: ten seconds).  Unanswered, it counts as sent (targets_sent_on_close), not as confirmed.
            command = protocol.SilentFree(servo_id, baudrate=baudrate)
        elif unheard and position == protocol.FREE:
            # As `free all` frees an ID that may be empty: it waits only as long as this line's answers take.
            command = protocol.ProbeFree(servo_id, baudrate=baudrate)
        try:
            await self.bus.request(command, retries=0 if unheard else None)
        except ReplyError:
            pass  # its bytes went out (unanswered or answered badly): the servo heard it as likely as not
        except IcsError:  # never on the wire, or cut off by a lost port: nothing says it arrived
            self._sent_on_close.pop(servo_id, None)
        except BaseException:  # still queued when the close's bound ran out (or cancelled on the wire)
            self._sent_on_close.pop(servo_id, None)
            raise

    def _stop(self, *, detach: bool = True) -> None:
        self._running = False
        self._closed = True
        self._wake_at = INF
        if detach:
            # The reply on the wire (and what a running burst sent) still reaches these hooks until the
            # engine detaches them; the engine hears no reply of a source it has detached.
            self.bus.detach_source(self._hooks)
        else:
            self._cur = -1
        self.bus.notify(self._wake_waiters)

    def _pace(self) -> str:
        """``at 100 Hz`` or ``back to back`` (for reprs)."""
        return "back to back" if self.rate_hz is None else f"at {self.rate_hz:g} Hz"

    def _life(self) -> str:
        """``not started``, ``running`` or ``closed`` (for reprs)."""
        return "closed" if self._closed else "running" if self._running else "not started"

    def __repr__(self) -> str:
        return f"<Stream {list(self.ids)} {self._pace()}, {self._life()}, on {self.bus!r}>"

    async def __aenter__(self) -> Stream:
        return await self.start()

    async def __aexit__(self, *exc: object) -> None:
        await self.aclose()


def _no_hook(done: anyio.Event) -> None:
    """A line without the close-out hooks (see :class:`~ics35_async.line.Line`)."""


keep_old_hook_names(Stream)  # the hooks had public names: they still work, with a warning, for one release
