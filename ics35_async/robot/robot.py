"""The :class:`Robot`: named joints in degrees over every line of a :class:`BusGroup`, streaming all the time.

While a robot is open its group stream runs on every line: one task (the
*pump*) takes a merged frame each time any line ends a cycle, turns it into
joint degrees, checks for offline joints, advances the running motions
(computing every moving joint's next target from the time now, once each of
its lines has run a cycle since its last) and publishes the frame.  Motions
are *plans*: a :class:`~.profiles.Trajectory` and its start time.  A joint
belongs to at most one plan; a new motion naming a joint takes it over.
Joints no motion names keep their target (a held joint holds, a free one
stays free).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections import deque
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import anyio

from .. import protocol, units
from ..bus import Bus
from ..engine import State
from ..errors import BusClosed, IcsError, InvalidArgument, PortLost, UnsafeOperation
from ..frames import GroupFrame
from ..group import BusGroup, GroupStream
from ..stream import WATCH, Stream
from ..tasks import again
from .description import JointSpec, RobotDescription
from .frame import RobotFrame
from .joint_stream import RobotStream
from .motion import Motion, play_motion
from .plans import Plan, Replies
from .profiles import PROFILES, Segment, Trajectory, check_duration, check_profile, stopping
from .safety import JointTelemetry, MotionStopped, SafetyStop, SafetyWatch, UnsettledReadings

log = logging.getLogger("ics35_async.robot")
CLOSED = "the robot is closed (its `async with open_robot(...)` block has ended)"
# Degrees a free joint may stand past a limit and still be held or moved from it (the limit, reached at the
# servo's own speed): a joint resting at its limit reads a little either side of it.  Farther past, the first
# command would throw it there at full speed (see Robot.check_ready and Robot.hold).
LIMIT_SLACK = 2.0
# A reply has no checksum: a byte garbled on the wire reads as another position (100 degrees away), and holding
# or moving a free joint from that one reading throws its servo there at full speed.  A reading is taken as where
# a joint is only when it agrees with the reading before it: within what no servo turns in the time between the
# two (under power or by hand), in degrees per second, but never more than TURN_STEP degrees (on a slow line, or
# beside a busy host, readings 40 ms apart would let a garble of 40 degrees through), plus a slack in degrees for
# the counts' rounding.  A joint turning faster than that (a limb falling free) is not taken anywhere until its
# readings settle: hold() leaves it free rather than hold it where it was read before.
TURN_SPEED = 1000.0
TURN_STEP = 8.0
TURN_SLACK = 1.0
# Readings in a row that disagree with the one before, after which a wait for one that agrees (read_pose(), a
# motion starting from a free joint) gives up with UnsettledReadings.  Readings disagree only while the joint turns
# more than TURN_STEP degrees between two of them, and no joint turns farther one way than its servo's whole travel
# (270 degrees: 34 such steps): past that, what the servo reports is not where it is (a broken potentiometer, a
# noisy line), and the wait would never end.  Counted in readings, not seconds: a slow line or a stalled host
# gives every joint as many chances to agree before it is given up.
UNSETTLED_READINGS = math.ceil(2 * units.DEGREES_MAX / TURN_STEP) + 1
SHOWN_READINGS = 3  # a joint's last readings an UnsettledReadings names


def _lost_words(lines: list[str], *, went_on: bool) -> str:
    """Why a motion gave up the joints on ``lines``, whose port is lost: it ``went_on`` with joints on other
    lines, or had none left and stopped (a robot of one line, or every line it moves lost)."""
    which = f"line {lines[0]} lost its port" if len(lines) == 1 else f"lines {', '.join(lines)} lost their ports"
    kept = (
        "their servos keep their last command; once the line is back, they are sent nothing until a target is set again"
    )
    if went_on:
        return f"{which}: the motion gave its joints up ({kept}) and went on with its joints on the other lines"
    where = "that line" if len(lines) == 1 else "those lines"
    return f"{which}: the motion stopped, all its joints being on {where} ({kept})"


class Robot:
    """A robot over its lines; get one from :func:`~ics35_async.open_robot`.

    Args:
        description: the checked robot description.
        group: its lines, open, one bus per line of the description.
    """

    def __init__(self, description: RobotDescription, group: BusGroup) -> None:
        self.description = description
        self.joints: dict[str, JointSpec] = dict(description.joints)
        self.group = group
        self.warnings: list[str] = []
        self.trips: list[SafetyStop] = []
        self.watch = SafetyWatch(description.safety, group.buses, list(self.joints.values()))
        self._by_key = {(j.line, j.id): name for name, j in self.joints.items()}
        self._targets: dict[str, float | None] = dict.fromkeys(self.joints)
        self._velocity: dict[str, float] = dict.fromkeys(self.joints, 0.0)
        # Joints a cancelled motion left moving: when it was cancelled (time.monotonic, a frame's line_started
        # clock) and the first cycle of their line begun since.  A stop() right after (a finally) slows them
        # from that speed; once their line has run a second cycle with the target frozen, they are at rest.
        self._coasting: dict[str, tuple[float, int | None]] = {}
        # Per joint, the interval a stop may slow it down in: the ends of the segment its newest motion is on
        # (before its first step: the pose the motion started from and its targets).
        self._envelope: dict[str, tuple[float, float]] = {}
        self.start_modes: dict[str, str] = dict.fromkeys(self.joints, "free")
        self.untouched: set[str] = set()  # read with ICS 3.6's read, not commanded since: torque as found
        self._positions: dict[str, float] = {}
        self._last_read: dict[str, tuple[float, float]] = {}  # each joint's newest reading and its stamp (_agreed)
        self._agreed_stamps: dict[str, float] = {}  # the stamp of each joint's newest reading taken (_agreed)
        # Joints whose newest reading is not taken as where they are (it did not agree with the one before, or it
        # is a first one), and how many in a row disagreed (_agreed); each joint's last readings, for a message.
        self._unsettled: dict[str, int] = {}
        self._recent: dict[str, deque[float]] = {}
        # Joints held since their line came back or their servo came back from offline, not yet given a target,
        # and why, as the streams say it ("resumed", "rejoined": see _held_since): they answer nothing.
        self._held: dict[str, str] = {}
        # Joints whose servo has answered since the robot opened: only these are under control, so only their
        # going offline trips the watch (one never heard from is refused by motions instead: see check_ready).
        self._answered: set[str] = set()
        self._latest: RobotFrame | None = None
        self._new_frame = anyio.Event()
        self._plans: list[Plan] = []
        self._latched: dict[str, SafetyStop] = {}
        self._end_error: IcsError | None = None
        self._ended = anyio.Event()
        self._end_reason: IcsError | None = None
        self._closing = False  # the block has ended: commands from elsewhere are refused (mark_closing)
        self._lost_lines: set[str] = set()  # lost ports not yet back in a frame (see _on_frame)
        self._lines_changed = anyio.Event()  # set (and replaced) as lost_lines changes: see line_change
        self._gstream: GroupStream | None = None
        self._streams: dict[str, Stream] = {}  # every line's, once the open has made them (see started)
        self._heard_at_open: set[str] = set()  # (see started)
        self._stated: dict[str, int] = {}  # the start pose's targets, in counts (see started, joints_left)
        # Every stop() and safety trip so far, and the newest one's error: a looping play between two passes has
        # no plan for them to end, and its next pass must not start after them (see run's ``unless_stopped_since``).
        self._stops = 0
        self._last_stop: IcsError | None = None

    def __repr__(self) -> str:
        name = self.description.name or self.description.source
        return f"<Robot {name}: {len(self.joints)} joints on {len(self.group.buses)} line(s)>"

    # ------------------------------------------------------------------ what it knows

    @property
    def latest(self) -> RobotFrame | None:
        """The newest frame in joint degrees (``None`` before the first cycle)."""
        return self._latest

    @property
    def positions(self) -> dict[str, float]:
        """Where each joint was last read, in degrees: its newest reading that agrees with the one before it
        (see :data:`TURN_SPEED`; a frame's ``positions`` are the replies as they came, a garbled one
        included).  A joint not read yet, or held since its servo or line came back, is left out."""
        return dict(self._positions)

    @property
    def targets(self) -> dict[str, float | None]:
        """Every joint's target in degrees (``None``: free, or never commanded: see ``start_modes``).  A held
        joint (see :attr:`held`) shows the newest target set for it, not being sent."""
        return dict(self._targets)

    @property
    def held(self) -> dict[str, str]:
        """The joints their streams hold now, sent nothing until a target is set for them, and why:
        ``"resumed"`` (their line's lost port came back) or ``"rejoined"`` (their servo answered again after
        going offline): the servo may have restarted, free and elsewhere.  Live, where ``latest.held`` is as
        of that frame's cycles: a control loop filters its targets by this (or sets them with
        ``lift_holds=False``)."""
        if self._gstream is None:
            return {}
        by_key = self._by_key
        return {by_key[k]: why for k, why in self._gstream.held.items() if k in by_key}

    @property
    def unreached(self) -> frozenset[str]:
        """The joints whose servo is offline as of the newest frame: their stream sends them nothing, so a target
        set meanwhile (a motion playing on past one) never reached them, and the temperature and current last
        read are not theirs now (:attr:`telemetry` has none).  A view of the robot shows neither for them ("-":
        ``ics35 play``'s live table, the configurator's Robot page), where :attr:`targets` keeps what they were
        asked; once a servo answers again its joint is :attr:`held`."""
        frame = self._latest
        return frozenset() if frame is None else frame.offline

    @property
    def uncommanded(self) -> frozenset[str]:
        """The joints no target of the program's reaches now: the :attr:`untouched` (ICS 3.6, only read since the
        robot opened: their torque as found) and the :attr:`unreached` (their servo offline).  A view of the robot
        shows "-" for their target, no target set (``ics35 play``'s live table, the configurator's Robot page),
        where a ``None`` in :attr:`targets` of any other joint is "free" (sent the free command, or freed to be
        read)."""
        return frozenset(self.untouched) | self.unreached

    @property
    def telemetry(self) -> dict[str, JointTelemetry]:
        """The temperature and current of every joint's servo now, as the safety watch last read them.  A joint
        whose servo is offline (:attr:`unreached`) or on a line whose port is lost (:attr:`lost`, or for good:
        ``bus.port_lost``) has none (``None``), nor has one since, until the watch reads it again: the servo may
        have come back restarted, and what was read before is not its own now.  Nor has a joint whose readings
        have failed :data:`~ics35_async.frames.STALE_AFTER_FAILED_READS` times in a row (``stale``: its servo may
        answer its position commands still, but what was read before these reads is not its now), until one is
        taken.  A view shows "-" for them (``ics35 play``'s live table, the configurator's Robot page)."""
        ended = {line for line, bus in self.group.buses.items() if bus.port_lost}
        gone = self.unreached | self.lost | {name for name, joint in self.joints.items() if joint.line in ended}
        return {
            name: dataclasses.replace(seen, temperature_c=None, current=None) if name in gone or seen.stale else seen
            for name, seen in self.watch.telemetry.items()
        }

    @property
    def tripped(self) -> dict[str, SafetyStop]:
        """Joints whose safety stop still stands: until a reading is back within the limits (a current trip: one
        taken with the joint powered, so not of a joint the watch freed), it is back online, or
        :meth:`reset_trip`."""
        return dict(self._latched)

    @property
    def lost(self) -> frozenset[str]:
        """Joints on a line whose port is lost now (``reconnect=True``: its bus reconnecting), until the frame
        whose ``resumed`` names the line back: nothing sent to them is confirmed meanwhile (``free()`` and
        ``on_wire()`` do not wait for them), and while the port is away :meth:`set_targets` refuses an angle for
        them and :meth:`hold` leaves them out.  A frame's ``lost`` as of now: with every line lost no frame comes."""
        lines = self.lost_lines
        return frozenset(n for n, j in self.joints.items() if j.line in lines) if lines else frozenset()

    @property
    def lost_lines(self) -> frozenset[str]:
        """The lines whose port is lost now (``reconnect=True``: their bus reconnecting), from the moment their
        bus knows until the frame whose ``resumed`` names them back: the lines of :attr:`lost`'s joints.
        :meth:`line_change` waits for it to change."""
        return frozenset(self._lost_lines | {n for n, bus in self.group.buses.items() if bus.state is State.LOST})

    async def line_change(self, lost: Iterable[str] | None = None) -> frozenset[str]:
        """Wait until the lines whose port is lost (:attr:`lost_lines`) are others than ``lost`` (default: those
        lost now): a line lost (as soon as its bus knows, frames or not) or back (at the frame whose
        ``resumed`` names it, once its joints are held: see :attr:`held`).  Returns the lines lost then, at once
        if they differ already; their joints are :attr:`lost`.  A line lost and back between two calls is not
        seen here: pass what the last call returned, or read a frame's ``resumed``.

        A program (or the configurator) that stops when a line goes, and carries on once it is back::

            lost = await robot.line_change(())  # returns once a line is lost
            print(f"line {', '.join(sorted(lost))} lost: joints {', '.join(sorted(robot.lost))} wait")
            while lost:
                lost = await robot.line_change(lost)  # every line back: an empty set

        Raises:
            InvalidArgument: ``lost`` is not line names, or names a line the robot does not have.
            BusClosed, PortLost: the robot was closed (its ``async with`` block has ended), or a line is gone
                (without ``reconnect``: the robot's frames have ended).
        """
        if lost is None:
            before = self.lost_lines
        else:
            names = [lost] if isinstance(lost, str) else list(lost) if isinstance(lost, Iterable) else None
            if names is None or not all(isinstance(name, str) for name in names):
                raise InvalidArgument(f"lost must be line names (what line_change returned), not {lost!r}")
            before = frozenset(names)
            unknown = sorted(before - self.group.buses.keys())
            if unknown:
                raise InvalidArgument(
                    f"the robot has no line {', '.join(map(repr, unknown))} (its lines: {', '.join(self.group.buses)})"
                )
        while True:
            if self._end_error is not None:
                raise again(self._end_error)
            now = self.lost_lines
            if now != before:
                return now
            await self._lines_changed.wait()

    @property
    def stops(self) -> int:
        """How many times motions were ended so far (``stop()`` and safety trips): what a motion made of several
        runs (a looping play) passes to :meth:`run` as ``unless_stopped_since``."""
        return self._stops

    def has_answered(self, joint: str) -> bool:
        """Whether ``joint``'s servo has answered since the robot opened (a position, or a probe once offline):
        only such a joint is under control, its going offline a safety matter and its telemetry read."""
        return joint in self._answered

    def joint_names(self, joints: Iterable[str] | None) -> list[str]:
        """``joints`` checked and as a list (``None``: every joint; a string: that one).

        Raises:
            InvalidArgument: an unknown joint name.
        """
        if joints is None:
            return list(self.joints)
        if isinstance(joints, str):
            joints = [joints]
        return self.description.known_joints(joints)

    def check_pose(self, pose: Mapping[str, float]) -> dict[str, float]:
        """``pose`` ``{joint: degrees}`` checked: every name known and every angle a number within its limits
        (the description's :meth:`~.description.RobotDescription.check_pose`).

        Raises:
            InvalidArgument: not a mapping, an unknown joint or an angle outside its limits.
        """
        return self.description.check_pose(pose)

    # ------------------------------------------------------------------ frames

    async def wait_frame(self, after: int) -> RobotFrame:
        """The newest frame with a cycle number above ``after`` (waits for one)."""
        while True:
            if self._end_error is not None:
                raise again(self._end_error)
            latest = self._latest
            if latest is not None and latest.cycle > after:
                return latest
            await self._new_frame.wait()

    async def wait_end(self) -> IcsError:
        """Wait until the robot's lines stop streaming: a line's port lost (without ``reconnect``) or the
        ``async with`` block's end.  Returns why (the first reason, if the block's end followed a lost line)."""
        await self._ended.wait()
        assert self._end_reason is not None
        return self._end_reason

    async def read_pose(self) -> dict[str, float]:
        """Every joint's angle as read after this call (an offline joint, or one on a line whose port is lost
        while it reconnects: its newest known angle).

        A joint whose servo has not answered once since the robot opened has no angle to give: it is
        left out (``robot.latest.offline`` names it), so index the result only by joints you know answer;
        so is a joint held since its line came back after a lost port (``robot.latest.held``).

        Raises:
            UnsettledReadings: a joint's readings disagreed :data:`UNSETTLED_READINGS` times in a row (a broken
                potentiometer, a noisy line): no reading of it would ever be taken.
            BusClosed, PortLost: the robot was closed, or a line is gone.
        """
        # The servo measures when the command reaches it: the reply after a reply is a command sent after now.
        # Only readings taken as where the joints are count (see TURN_SPEED): not a garbled one.
        await self.fresh_replies(self.joints, 2, agreed=True)
        return {name: self._positions[name] for name in self.joints if name in self._positions}

    async def fresh_replies(self, joints: Iterable[str], replies: int, *, agreed: bool = False) -> None:
        """Wait until each of ``joints`` (but the offline ones, those on a line whose port is lost, and those
        held after their line came back) has answered ``replies`` times from now on: a line reconnecting
        answers nothing for as long as it is away, and the other lines' joints are not kept waiting for it.
        ``agreed``: count only the readings taken as where the joints are (see TURN_SPEED)."""
        counter = Replies(joints, time.monotonic())
        frame = self._latest
        while frame is None or not counter.reached(replies, frame.offline | self._held.keys() | self.lost):
            if self._end_error is not None:
                raise again(self._end_error)
            await self._new_frame.wait()  # a frame, or a line lost (with every line lost no frame comes)
            if self._latest is not frame and self._latest is not None:
                frame = self._latest
                counter.add(self._agreed_stamps if agreed else frame.stamps)
                if agreed:
                    self._give_up_unsettled(counter, replies, frame.offline | self._held.keys() | self.lost)

    def _give_up_unsettled(self, counter: Replies, replies: int, skipped: Iterable[str]) -> None:
        """Raise UnsettledReadings naming the joints ``counter`` still waits for whose readings disagreed
        UNSETTLED_READINGS times in a row, the newest since the wait began (a joint that rests after being
        turned gets its chance to agree)."""
        skip = set(skipped)
        stuck = [
            name
            for name, count in counter.counts.items()
            if count < replies
            and name not in skip
            and self._unsettled.get(name, 0) >= UNSETTLED_READINGS
            and self._last_read.get(name, (0.0, 0.0))[1] > counter.since
        ]
        if not stuck:
            return
        told = "; ".join(
            f"joint {name} (line {self.joints[name].line}, ID {self.joints[name].id}) last read at "
            f"{', '.join(f'{deg:.1f}' for deg in self._recent[name])} degrees"
            for name in stuck
        )
        raise UnsettledReadings(
            f"{told}: {UNSETTLED_READINGS} position readings in a row and more, each farther from the one before "
            "than a joint turns between two, no two agreeing: not where the joint is (a broken potentiometer, a noisy "
            "line or loose wiring); nothing was moved on them: check the servo and its cable, or free the joint and "
            "leave it out",
            readings={name: self._recent[name] for name in stuck},
        )

    def stream(self) -> RobotStream:
        """Frames in joint space and targets by name; ``async with robot.stream() as s: async for frame in s``."""
        return RobotStream(self)

    async def on_wire(self, joints: Iterable[str] | None = None) -> None:
        """Wait until the targets set so far have gone out to ``joints`` (default: all), but those that cannot
        be sent now: an offline joint's, one held since its servo or line came back, one on a line whose port is
        lost (reconnecting)."""
        # The command in flight may predate the target; the one after its reply cannot.
        await self.fresh_replies(self.joint_names(joints), 2)

    # ------------------------------------------------------------------ targets

    def set_targets(
        self, pose: Mapping[str, float | None], *, allow_free: bool = False, lift_holds: bool = True
    ) -> None:
        """Targets ``pose`` ``{joint: degrees}`` (``None`` frees, with ``allow_free``), all checked first;
        they take over those joints from any running motion.  A held joint (see :attr:`held`) is sent its
        target: the program has decided; ``lift_holds=False`` (a loop that sets every joint each pass) leaves
        it held, sent nothing.  A joint whose servo does not answer (offline, or never heard from since the
        robot opened) takes the target, but its servo, once it answers, is not thrown there from wherever it
        stands: it comes back held, until the program sets its target again.  An angle for a joint on a line
        whose port is lost (``reconnect=True``: see :attr:`lost`) would never go out (the line comes back with
        its joints held): it is refused, nothing applied; with ``lift_holds=False`` the others' targets are
        set and that joint takes its target as a held one does, sent nothing (its frames list it in ``lost``,
        then in ``held`` once the line is back).

        Raises:
            InvalidArgument: not a mapping, an unknown joint, an angle outside its limits or a ``None``
                without ``allow_free`` (nothing applied).
            SafetyStop: an angle for a joint the safety watch tripped (``tripped``), until it is back within
                its limits: the target would undo the safety action (nothing applied; freeing it is allowed).
            PortLost: an angle for a joint on a line whose port is lost (``reconnect=True``), unless
                ``lift_holds=False``: the message names the joints and their lines (nothing applied; freeing it
                is allowed: the free goes out as the line comes back).
            BusClosed, PortLost: the robot was closed (its ``async with`` block has ended), or a line is gone
                (without ``reconnect``: the robot's frames have ended; nothing applied unless every target frees).
        """
        if not isinstance(pose, Mapping):
            raise InvalidArgument(f"a pose is a mapping {{joint: degrees}}, not {type(pose).__name__}")
        self.joint_names(pose)
        freeing = [] if allow_free else [n for n, d in pose.items() if d is None]  # (by identity: any value compares)
        if freeing:  # (None frees: only where the program says it means it)
            raise InvalidArgument(f"joint {freeing[0]}: a target of None frees the joint, which takes allow_free=True")
        checked = {n: None if d is None else self.joints[n].check(d) for n, d in pose.items()}  # (None: allowed)
        if any(d is not None for d in checked.values()):
            self._check_watched()  # (freeing alone still reaches the lines left)
        self._refuse_tripped(n for n, d in checked.items() if d is not None)
        if lift_holds:
            self._refuse_lost(n for n, d in checked.items() if d is not None)
        self._release(checked)
        self._apply(checked, lift_holds=lift_holds)

    def _port_lost_now(self, joints: Iterable[str]) -> list[str]:
        """Those of ``joints`` whose line's bus has lost its port now.  Not :attr:`lost`, which lasts until a
        frame says the line is back: by then its stream has held the joints that had a target (one set now lifts
        the hold and goes out), where a target set while the port is away is held with them as it comes back."""
        buses = self.group.buses
        return [name for name in joints if buses[self.joints[name].line].state is State.LOST]

    def _refuse_lost(self, joints: Iterable[str]) -> None:
        """Raise PortLost naming those of ``joints`` on a line whose port is lost (``reconnect=True``): their
        target would not reach their servos, and once the line is back they are held, sent nothing until a target
        is set again (see _line_resumed), so it would never go out.  The program decided for those joints: it
        hears so, nothing applied, as for a tripped one (a motion, or a loop passing ``lift_holds=False``, goes on
        with the other joints and says so afterwards: MotionStopped, a frame's ``lost``)."""
        named = self._port_lost_now(joints)
        if not named:
            return
        lines = sorted({self.joints[name].line for name in named})
        which = ", ".join(f"{name} (line {self.joints[name].line}, ID {self.joints[name].id})" for name in named)
        several, many_lines = len(named) > 1, len(lines) > 1
        raise PortLost(
            f"joint{'s' if several else ''} {which}: line{'s' if many_lines else ''} {', '.join(lines)} lost "
            f"{'their' if many_lines else 'its'} port (reconnecting): a target would not reach "
            f"{'their servos' if several else 'its servo'}, and once the line is back a joint that had a target is "
            "held, sent nothing until a target is set again; nothing was applied (robot.lost names the joints on a "
            "lost line: leave them out, or pass lift_holds=False to set the others' targets and leave them)"
        )

    def started(
        self, stated: Mapping[str, float], read: Iterable[str], streams: Mapping[str, Stream], heard: Iterable[str] = ()
    ) -> None:
        """How the joints start (see :mod:`.startup`): ``stated`` angles already in the ``streams`` (every line's,
        about to start), ``read`` watched; ``heard``: joints whose servo answered the open without a protocol probe
        (``start_free``)."""
        self._heard_at_open = set(heard)
        self._streams = dict(streams)
        self._stated = {name: self.joints[name].position(deg) for name, deg in stated.items()}  # (as sent: counts)
        self._targets.update(stated)
        self.untouched = set(read)
        self.start_modes.update({**dict.fromkeys(read, "read"), **dict.fromkeys(stated, "stated")})

    def joints_left(self) -> str:
        """In words, what the robot's streams have left its joints in so far (their close's commands included):
        which were freed, which hold an angle, which were left as they were (only read: the open's EEPROM reads
        and probes, ICS 3.6's position read).  For a person whose program was cut short as it opened the robot
        (Ctrl-C), who needs to know which servos went limp.  From what was sent, not from what the servos did:
        one that does not answer now may not have heard it; one that never answered is said apart."""
        groups: dict[str, list[str]] = {"read free": [], "freed": [], "held": [], "as found": [], "unheard": []}
        stated = True  # (a stated angle only while every held joint still carries it: moved since, its last target)
        for name, joint in self.joints.items():
            stream = self._streams.get(joint.line)
            if stream is None:  # (the open was cut short before it made them: only reads went out)
                groups["as found"].append(name)
                continue
            # (every transaction to it carried its start's target: none is set while the robot opens)
            carried = stream.target(joint.id) if joint.id in stream.reached else None
            closing = stream.targets_sent_on_close.get(joint.id)
            if not self._heard_from(name):
                # An unplugged leg: "freed" would be news its servos never got (plugged in, they power up free); nor
                # was it "left as it was" (it starts offline, sent nothing until its first probe): it is not there.
                groups["unheard"].append(name)
            elif carried == protocol.FREE and self.start_modes[name] == "free":
                groups["read free"].append(name)
            elif protocol.FREE in (carried, closing):  # (freed by the program, or by the close: on_close="free")
                groups["freed"].append(name)
            elif closing is not None or carried not in (None, WATCH):
                groups["held"].append(name)
                stated = stated and stream.target(joint.id) == self._stated.get(name)
            else:
                groups["as found"].append(name)
        if not any(groups[group] for group in ("read free", "freed", "held")):
            return "no joint was sent anything that moves or frees it (its servos were only read)"
        words = {
            "read free": ("was freed to read where it stands", "were freed to read where they stand"),
            "freed": ("was freed", "were freed"),
            "held": ("holds its stated angle", "hold their stated angles")
            if stated
            else ("holds its last target", "hold their last targets"),
            "as found": ("was left as it was (only read)", "were left as they were (only read)"),
            "unheard": (
                "never answered (whatever was sent to it went unheard)",
                "never answered (whatever was sent to them went unheard)",
            ),
        }
        return "; ".join(
            f"joint{'s' if len(names) > 1 else ''} {', '.join(names)} {words[group][len(names) > 1]}"
            for group, names in groups.items()
            if names
        )

    def _heard_from(self, name: str) -> bool:
        """Whether ``name``'s servo has answered anything since the robot opened: a position, or the open's probe
        (a stated joint is not probed: taken as heard), or, with ``start_free``, the open's reads."""
        if name in self._answered or name in self._heard_at_open or self.start_modes[name] == "stated":
            return True
        joint = self.joints[name]
        return self.group[joint.line].servo(joint.id).known_position_read() is not None

    def hold(self, joints: Iterable[str] | None = None) -> dict[str, str]:
        """Hold ``joints`` (default: all but the tripped ones) where they are now (within their limits), torque on:
        one a motion drives at the target last sent (its servo is on its way there: where it was last read lags
        it), the others where they were last read.  Left out, as they are, and returned with why
        (``{joint: why}``): one on a line whose port is lost now (see :attr:`lost`: nothing reaches its servo), a
        held joint (see :attr:`held`: its servo may have restarted, so where it is is unknown and nothing reads it;
        set its target once you know, or free it), one whose position was not read yet, one whose newest reading
        did not agree with the one before or is its first since it answered again (see :data:`TURN_SPEED`), and a
        free one standing more than :data:`LIMIT_SLACK` degrees past a limit (turned there by hand: holding it
        would throw it to the limit at full speed; bring it within its limits first).

        Raises:
            InvalidArgument: an unknown joint.
            SafetyStop: ``joints`` names a joint the safety watch tripped (nothing applied; see :meth:`set_targets`).
            BusClosed, PortLost: the robot was closed, or a line is gone (nothing applied; see :meth:`set_targets`).
        """
        names = self.joint_names(joints)
        if joints is None:
            names = [n for n in names if n not in self._latched]
        self._check_watched()
        self._refuse_tripped(names)
        # A joint a motion drives (or a cancelled one left moving) holds at the target last sent: where it was last
        # read lags it (the servo is on its way), and holding there would step it back against its motion.
        driven = {
            n: target
            for n in names
            if (target := self._targets[n]) is not None
            and (self._velocity[n] or any(n in plan.joints for plan in self._plans))
        }
        self._release(names)
        # A lost line's joints first: nothing reaches their servos, and whatever their readings say is from before.
        lost = self._port_lost_now(names)
        left = {
            n: f"its line {self.joints[n].line} is lost (its port reconnecting): nothing reaches its servo, which "
            "keeps its last command; once the line is back, one that had a target is held until a target is set (see "
            "Robot.held)"
            for n in names
            if n in lost
        }
        # (the streams' holds now, not only those a frame has told the robot of: a servo back from offline
        # since has no position but the one from before it fell silent)
        held = {**self._held, **self.held}
        left.update(
            (
                n,
                f"held since {self._held_since(n, held[n])}: its servo may have restarted, free and elsewhere, and "
                "nothing reads it, so where it stands is unknown; set its target once you know where it is, or free "
                "it to have it read where it stands",
            )
            for n in names
            if n in held and n not in left
        )
        left.update(
            (n, "its position is not read yet")
            for n in names
            if n not in self._positions and n not in driven and n not in left
        )
        left.update(
            (
                n,
                "its newest reading is not confirmed by one agreeing with it (turning fast, a garbled reply, or its "
                "first since it answered again): hold it again once it settles",
            )
            for n in names
            if n in self._unsettled and n not in driven and n not in left
        )
        left.update((n, why) for n, why in self._past_limits(names).items() if n not in left)
        self._apply(
            {n: driven[n] if n in driven else self.joints[n].clamp(self._positions[n]) for n in names if n not in left}
        )
        return left

    def _held_since(self, name: str, why: str) -> str:
        """What ``name`` is held since, in words, from its stream's why (``"resumed"`` or ``"rejoined"``)."""
        if why == "resumed":
            return f"line {self.joints[name].line} came back after its port was lost"
        return "it came back after going offline"

    def _past_limits(self, joints: Iterable[str]) -> dict[str, str]:
        """Those of ``joints`` sent no target (free, or read and left alone) that stand more than LIMIT_SLACK
        degrees past a limit, and where: their first command would be the limit, reached at full speed."""
        past = {}
        for name in joints:
            where = self._positions.get(name)
            if self._targets[name] is not None or where is None:
                continue
            spec = self.joints[name]
            limit = spec.max if where > spec.max + LIMIT_SLACK else spec.min if where < spec.min - LIMIT_SLACK else None
            if limit is not None:
                past[name] = f"stands at {where:.1f} degrees, past its limit {limit:g}"
        return past

    async def free(self, joints: Iterable[str] | None = None) -> None:
        """Torque off for ``joints`` (default: all); returns once that has gone out on the wire.

        Raises:
            InvalidArgument: an unknown joint.
            BusClosed, PortLost: the robot was closed, or a line is gone.
        """
        names = self.joint_names(joints)
        self._release(names)
        self._apply(dict.fromkeys(names))
        await self.on_wire(names)

    def _offline_now(self, name: str) -> bool:
        """Whether ``name``'s servo is offline in its stream now (frames tell it as of their cycles)."""
        joint = self.joints[name]
        return self._gstream is not None and (joint.line, joint.id) in self._gstream.offline

    def _refuse_tripped(self, joints: Iterable[str]) -> None:
        """Raise the safety stop of the first of ``joints`` still tripped: a target for it would undo what the
        watch did (a freed joint's torque back on: a control loop setting every joint each pass did so at its
        next pass), as a motion naming it would (see check_ready)."""
        for name in joints:
            if name in self._latched:
                raise again(self._latched[name])

    def _release(self, joints: Iterable[str]) -> None:
        for name in joints:
            self._velocity[name] = 0.0
            self._coasting.pop(name, None)
            for plan in self._plans:
                plan.joints.discard(name)

    def _apply(self, targets: Mapping[str, float | None], *, lift_holds: bool = True) -> None:
        """Send ``targets``; ``lift_holds=False`` (a motion's step): a joint its stream holds stays held, sent
        nothing (the robot may not have seen the frame that says so yet: see _on_frame)."""
        self._check_commands()
        if not targets or self._gstream is None:
            return
        wanted: dict[tuple[str, int], int] = {}
        for name, deg in targets.items():
            joint = self.joints[name]
            # Clamped again here: whatever computed it, no command leaves the joint's limits.
            wanted[(joint.line, joint.id)] = protocol.FREE if deg is None else joint.position(joint.clamp(deg))
        self._gstream.set_targets(wanted, lift_holds=lift_holds)
        self._targets.update(targets)
        self.untouched.difference_update(targets)
        if lift_holds:
            for name in targets:
                self._held.pop(name, None)

    # ------------------------------------------------------------------ motions

    async def move_to(self, pose: Mapping[str, float], duration: float = 1.0, profile: str = "minjerk") -> None:
        """Move the named joints to ``pose`` (joint degrees) in ``duration`` seconds; the others hold still.

        Every target is checked against its joint's limits before anything is
        sent.  Returns when the final targets have gone out on every line.
        ``profile``: ``"minjerk"`` (smooth start and stop) or ``"linear"``.
        ``duration`` meets a keyframe's rule (:func:`~.profiles.check_duration`): above 0 (a move in no time
        throws the joints to the pose at full speed; :meth:`set_targets` sets targets at once) and at most
        :data:`~.profiles.LONGEST_MOTION`.

        Raises:
            InvalidArgument: an unknown joint, an angle outside its limits, a bad duration or profile.
            UnsettledReadings: a free joint's readings never agreed (see :meth:`start_pose`; nothing moved).
            SafetyStop: the safety watch stopped the motion (or a stop still stands for a joint).
            BusClosed, PortLost: the robot was closed, or a line is gone.
        """
        goal = self.check_pose(pose)
        seconds = check_duration(duration)
        shape = check_profile(profile)
        self.check_ready(goal)
        if goal:
            # A joint whose position was never read starts at its goal: nothing to interpolate from.
            stops = self._stops  # (a stop() while start_pose waits for a joint to settle ends this motion too)
            start = {**goal, **await self.start_pose(goal)}
            await self.run(Trajectory([Segment(0.0, seconds, start, goal, shape)]), unless_stopped_since=stops)

    async def play(
        self, motion: Motion | str | Path | Mapping[str, Any], *, speed: float = 1.0, loop: bool = False
    ) -> None:
        """Play a motion (a :class:`~.motion.Motion`, a JSON file's path or its mapping); see :mod:`.motion`.

        ``speed`` scales time (2: twice as fast), from 0.05 to 10 (:data:`~.motion.SPEEDS`, the rule
        ``ics35 play`` and the configurator follow too); with ``loop`` it repeats until cancelled.  Checked
        against the limits before anything moves.

        Raises:
            MotionError: the motion file breaks its format.
            InvalidArgument: a keyframe names an unknown joint or an angle outside its limits, or a bad ``speed``.
            SafetyStop: the safety watch stopped the motion.
            BusClosed, PortLost: the robot was closed, or a line is gone.
        """
        await play_motion(self, motion, speed=speed, loop=loop)

    def check_ready(self, joints: Iterable[str]) -> None:
        """Raise why a motion of ``joints`` cannot start: the robot's end, a safety stop that still stands, a
        joint held since its line came back (UnsafeOperation: it would start from the target it had), or a free
        one standing past a limit (UnsafeOperation: it would be thrown to the limit; see :data:`LIMIT_SLACK`)."""
        joints = list(joints)
        if self._end_error is not None:
            raise again(self._end_error)
        for name in joints:
            if name in self._latched:
                raise again(self._latched[name])
            if self._unheard(name):
                # Every such joint at once: an unplugged leg refused one joint at a time, each plugged in only to
                # be refused for the next.
                raise self._unheard_error([n for n in joints if self._unheard(n)])
            if name in self._held:
                raise UnsafeOperation(
                    f"joint {name} is held since {self._held_since(name, self._held[name])}: where it is is unknown "
                    "(its servo may have restarted elsewhere), and a motion would start from the target it had; "
                    "set its target (set_targets) or free it first"
                )
        for name, where in self._past_limits(joints).items():
            raise UnsafeOperation(
                f"joint {name} {where}: a motion would send it to that limit at full speed first; bring it within "
                "its limits (by hand, while it is free) or widen them in the robot file"
            )

    def _unheard(self, name: str) -> bool:
        """``name``'s servo has not answered since the robot opened and is offline: a motion would drive it blind
        (unless the file's safety plays on without it)."""
        return (
            name not in self._answered
            and self._offline_now(name)
            and not self.description.safety.continue_on_offline  # (there: played on without it)
        )

    def _unheard_error(self, names: list[str]) -> UnsafeOperation:
        if len(names) == 1:
            joint = self.joints[names[0]]
            return UnsafeOperation(
                f"joint {joint.name} has not answered since the robot opened (line {joint.line}, servo ID {joint.id}: "
                "check its power, wiring, ID and the line's baud rate): a motion would drive it blind"
            )
        by_line: dict[str, list[str]] = {}
        for name in names:
            by_line.setdefault(self.joints[name].line, []).append(str(self.joints[name].id))
        where = "; ".join(
            f"line {line}, servo ID{'s' if len(ids) > 1 else ''} {', '.join(ids)}" for line, ids in by_line.items()
        )
        return UnsafeOperation(
            f"joints {', '.join(names)} have not answered since the robot opened ({where}: check their power, "
            "wiring, IDs and the lines' baud rates): a motion would drive them blind"
        )

    async def start_pose(self, joints: Iterable[str]) -> dict[str, float]:
        """Where a motion of ``joints`` starts: each one's target, else where it is (within its limits).  A free
        joint whose newest reading did not agree with the one before (turned fast, or a garbled reply: see
        :data:`TURN_SPEED`), or is its first since it answered again, is waited for until one does: started
        where it was read before, its first target would throw it back there.

        Raises:
            UnsettledReadings: such a joint's readings disagreed :data:`UNSETTLED_READINGS` times in a row (nothing
                was moved).
        """
        joints = list(joints)
        unsettled = [n for n in joints if n in self._unsettled and self._targets[n] is None]
        if unsettled:
            await self.fresh_replies(unsettled, 1, agreed=True)
        start = {}
        for name in joints:
            target = self._targets[name]
            if target is None and name in self._positions:
                target = self.joints[name].clamp(self._positions[name])
            if target is not None:
                start[name] = target
        return start

    async def run(
        self, trajectory: Trajectory, *, wait_on_wire: bool = True, unless_stopped_since: int | None = None
    ) -> frozenset[str]:
        """Play a trajectory from the next frame on; returns when it is done (its end on the wire, with
        ``wait_on_wire``).  Its time zero is that frame's: a host stall before it delays the motion rather
        than skipping its start.  Returns the joints it still drove at its end (a joint another command
        took over meanwhile is not among them).  ``unless_stopped_since``: a count of :attr:`stops` taken
        when the motion this trajectory belongs to began; a stop since (one that came between two of its
        runs, with no plan of it to end) is raised at once, nothing sent.  Every segment's ends are checked
        against the robot's joints and limits first (a segment moves each joint between its two ends), and the
        first segment's start against where a motion of each joint starts (:meth:`start_pose`), within
        :data:`LIMIT_SLACK` degrees.

        Raises:
            InvalidArgument: not a :class:`~.profiles.Trajectory`, an unknown joint or an angle outside its
                limits, a segment with the stop's own profile (``decel``) (nothing sent).
            UnsafeOperation: the first segment starts a joint farther than :data:`LIMIT_SLACK` from where a
                motion of it starts: its first command would throw it there at full speed (nothing sent).
            UnsettledReadings: a free joint's readings never agreed (see :meth:`start_pose`; nothing sent).
            MotionStopped: ``stop()`` was called since ``unless_stopped_since``.
            SafetyStop: the trajectory names a joint the safety watch tripped (at once, nothing sent), or the watch
                stopped it.
            BusClosed, PortLost: the robot was closed, or a line is gone (at once, or when it happens).
        """
        if not isinstance(trajectory, Trajectory):
            raise InvalidArgument(f"a trajectory is a Trajectory of Segments, not {type(trajectory).__name__}")
        for k, segment in enumerate(trajectory.segments):
            if segment.profile not in PROFILES:  # (a stop's ramp is taken over by the next stop, not stopped: see stop)
                raise InvalidArgument(
                    f"segments[{k}]: profile {segment.profile!r} is Robot.stop's own ramp; a trajectory's segments are "
                    f"{' or '.join(PROFILES)}"
                )
            for end, pose in (("start", segment.start), ("end", segment.end)):
                try:
                    self.check_pose(pose)
                except InvalidArgument as exc:
                    raise InvalidArgument(f"segments[{k}].{end}: {exc}") from None
        self._check_watched()  # (a closed robot says so: where its joints stand is no longer known)
        first = trajectory.segments[0].start
        for name, here in (await self.start_pose(trajectory.joints)).items():
            # (The slack a free joint may stand past a limit and still be moved from it: a step the robot takes
            # at the servo's own speed anyway, and room for a reading a count off where it was read before.)
            if abs(first[name] - here) > LIMIT_SLACK:
                raise UnsafeOperation(
                    f"segments[0] starts {name} at {first[name]:g} degrees, not where a motion of it starts "
                    f"({here:g}: its target, or where it stands if free; see Robot.start_pose): its first command "
                    "would throw it there at full speed"
                )
        return await self._played(self._planned(trajectory, wait_on_wire, unless_stopped_since))

    def _planned(self, trajectory: Trajectory, wait_on_wire: bool, unless_stopped_since: int | None = None) -> Plan:
        """The trajectory's plan, stepped from the next frame on: registered at once, with no await, so a stop()
        called in the same moment as another finds the other's ramp to take over (not a joint at rest)."""
        self._check_watched()  # (no pump would ever step it)
        if unless_stopped_since is not None and self._stops != unless_stopped_since:
            assert self._last_stop is not None
            raise again(self._last_stop)
        plan = Plan(trajectory, wait_on_wire)
        # A trajectory does not drive a tripped joint: a motion checks that before it starts (check_ready), but a
        # trip may have landed since (a stop()'s ramp comes from the motions it stops).
        self._refuse_tripped(plan.joints)
        self._release(plan.joints)
        self._envelope.update(trajectory.envelope())
        self._plans.append(plan)
        if self.lost:  # (its joints there given up now: every line lost, no frame would come to do it)
            self._drop_lost_joints()
        return plan

    async def _played(self, plan: Plan) -> frozenset[str]:
        try:
            await plan.done.wait()
        finally:
            if plan in self._plans and not plan.done.is_set():
                # Cancelled: the joints keep their last target (and speed, for a smooth stop() right after).
                self._plans.remove(plan)
                cancelled = time.monotonic()
                self._coasting.update((name, (cancelled, None)) for name in plan.joints if self._velocity[name])
        if plan.error is not None:
            raise again(plan.error)
        return frozenset(plan.joints)

    async def stop(self, ramp: float = 0.3) -> None:
        """End every motion smoothly: each moving joint slows to rest (at the rate that would take ``ramp``
        seconds), then holds, never leaving its motion's envelope (the pose the motion started from and its
        targets), nor passing the keyframe it is heading for: one that would pass it rests on it, sooner.  Each
        motion stopped raises :class:`MotionStopped` in its caller once its joints are at rest.  A stop during
        another's ramp takes it over: both return once the joints are at rest.

        Raises:
            MotionStopped: a line came back after a lost port during the ramp (its joints were given up).
            BusClosed, PortLost: the robot was closed, or a line is gone.
        """
        seconds = units.check_seconds("ramp", ramp, 0.0, 10.0)
        self._check_watched()  # (no frames: nothing to ramp by)
        stopped, self._plans = self._plans, []  # no longer stepped: the ramp drives their joints now
        stopped_here = MotionStopped("the motion was stopped (Robot.stop)")
        self._stops += 1
        self._last_stop = stopped_here
        outcome: IcsError = stopped_here
        try:
            await self._come_to_rest(seconds)
        except IcsError as exc:  # the ramp's own end (a lost line): the stopped motions hear that too
            outcome = exc
            raise
        finally:
            # Told once their joints are at rest (or the ramp failed), not as the stop begins: code
            # after a motion (a program leaving its block, closing the robot) must not cut the ramp short.
            for plan in stopped:
                # An earlier stop's ramp, taken over by this one, is no motion stopped short: its joints came to
                # rest here, and that stop returns as this one does (not with MotionStopped, into a close-out).
                taken_over = plan.slowing_down and outcome is stopped_here
                plan.finish(None if taken_over else outcome)

    async def _come_to_rest(self, seconds: float) -> None:
        moving = {}
        for name, speed in self._velocity.items():
            target = self._targets[name]
            if speed and target is not None:
                low, high = self._envelope.get(name, (target, target))
                moving[name] = (target, speed, (self.joints[name].clamp(low), self.joints[name].clamp(high)))
        self._velocity = dict.fromkeys(self.joints, 0.0)
        self._coasting.clear()
        segments = stopping(moving, seconds)
        if not segments:
            return
        errors: list[IcsError] = []
        ramps: list[Plan] = []
        for segment in segments:  # registered before any await: a stop right after this one takes them over
            try:
                ramps.append(self._planned(Trajectory([segment]), wait_on_wire=True))
            except IcsError as exc:  # a safety stop meanwhile, the line's end: the caller hears it
                errors.append(exc)

        async def slow_down(plan: Plan) -> None:
            try:
                await self._played(plan)
            except IcsError as exc:  # a later stop, a safety stop, the line's end: the caller hears it
                errors.append(exc)

        async with anyio.create_task_group() as tasks:
            for ramp in ramps:
                tasks.start_soon(slow_down, ramp)
        if errors:
            raise again(errors[0])

    def _step(self, frame: RobotFrame, line_started: Mapping[str, float]) -> None:
        """Advance every running plan to the frame's time: the targets for the next cycle.

        A frame comes as soon as any line ends a cycle; a plan steps once every line its joints are
        on has ended a cycle since its last step, so a plan on one line keeps that line's pace whatever
        the others' pace.  After a keyframe it waits for cycles that began after it on each of those
        lines (a cycle already under way may have sent a joint's command before it): no keyframe is
        overwritten unsent.
        """
        targets: dict[str, float | None] = {}
        keyframes: list[Plan] = []
        line_cycles = frame.line_cycles
        # A line whose port is lost (reconnecting) runs no cycle until it is back: a plan waiting for one would
        # stall its joints on the other lines, then throw them to where its clock is by then.  Its joints are
        # given up at once (they keep their last command; back, their line holds them: see _line_resumed).
        lost = frame.lost
        driven_lost = frozenset(name for plan in self._plans for name in plan.joints & lost)
        if driven_lost:
            self._give_up_lost(driven_lost)
        for plan in list(self._plans):
            if plan.ending is not None:
                plan.ending.add(frame.stamps)
            unknown = frame.offline | self._held.keys() | lost  # (joints that cannot answer)
            if not plan.joints or (plan.ending is not None and plan.ending.reached(2, unknown)):
                plan.finish()
                self._plans.remove(plan)
                continue
            if plan.ending is not None:
                continue
            lines = {self.joints[name].line for name in plan.joints}
            if any(line_cycles[line] <= plan.stepped.get(line, 0) for line in lines):
                continue
            if plan.keyframe_at is not None and any(line_started[line] <= plan.keyframe_at for line in lines):
                continue
            plan.stepped.update((line, line_cycles[line]) for line in lines)
            plan.keyframe_at = None
            if plan.t0 is None:
                plan.t0 = frame.time
            segments, t = plan.trajectory.segments, frame.time - plan.t0
            if plan.segment < len(segments) - 1 and t >= segments[plan.segment].end_time:
                # Past the segment the last targets came from: its keyframe first, exactly, and
                # one keyframe per frame, so a cycle longer than a segment skips none of them.
                pose = dict(segments[plan.segment].end)
                plan.segment += 1
                keyframes.append(plan)
                speed = segments[plan.segment].velocity_at(t)
            elif t >= plan.trajectory.duration:
                pose, speed = plan.trajectory.final, {}
                plan.ending = Replies(plan.joints, time.monotonic())
                if not plan.wait_on_wire:
                    plan.finish()
                    self._plans.remove(plan)
            else:
                segment = segments[plan.segment]
                pose, speed = segment.pose_at(t), segment.velocity_at(t)
            # A stop slows a joint down within the segment it is on (the keyframe it heads for, not past it
            # towards the motion's other poses): that segment's ends.
            heading = segments[plan.segment]
            for name in plan.joints:
                if name in pose:
                    targets[name] = pose[name]
                    self._velocity[name] = speed.get(name, 0.0)
                    ends = (heading.start[name], heading.end[name])
                    self._envelope[name] = (min(ends), max(ends))
        self._apply(targets, lift_holds=False)
        if keyframes:
            applied = time.monotonic()  # (the clock of a frame's ``started``)
            for plan in keyframes:
                plan.keyframe_at = applied

    # ------------------------------------------------------------------ the pump

    async def pump(self, gstream: GroupStream) -> None:
        """Take a merged frame of ``gstream`` as each line ends a cycle, until it ends (then every waiter
        gets the reason)."""
        self._gstream = gstream
        try:
            while True:
                self._on_frame(await gstream.next_update())  # each line's cycle at once, whatever the others' pace
        except IcsError as exc:
            self._end(exc)

    def _on_frame(self, frame: GroupFrame) -> None:
        now = anyio.current_time()
        # A line whose port is lost (reconnect=True: its bus reconnecting) from the moment its bus knows until the
        # frame that says it is back (resumed): the reopened port runs no cycle of the stream before that, and its
        # joints are held only from then on.
        was_lost = self._lost_lines
        self._lost_lines = (
            self._lost_lines | {n for n, bus in self.group.buses.items() if bus.state is State.LOST}
        ) - frame.resumed
        if self._lost_lines != was_lost:
            self._tell_lines_changed()
        lost = self.lost
        by_key, joints = self._by_key, self.joints
        positions = {by_key[k]: joints[by_key[k]].degrees(p) for k, p in frame.positions.items() if k in by_key}
        stamps = {by_key[k]: t for k, t in frame.timestamps.items() if k in by_key}
        self._positions.update(self._agreed(positions, stamps))
        self._answered.update(positions)
        failed = frozenset(by_key[k] for k in frame.failed if k in by_key)
        not_sent = frozenset(by_key[k] for k in frame.not_sent if k in by_key)
        offline = frozenset(by_key[k] for k in frame.offline if k in by_key)
        # A joint offline, or on a line whose port is lost, may come back restarted elsewhere: its next reading is a
        # first one again (see _agreed), not one that agrees with a reading from before.  (After _agreed: a lost
        # line's frame, brought again with every frame, is no reading from after it is back.)
        for name in offline | lost:
            self._last_read.pop(name, None)
        self.watch.forget(offline | lost)  # (nor its temperature and current: read again once it is back)
        held = frozenset(by_key[k] for k in frame.held if k in by_key)
        # What the streams hold now, not as of this frame's cycles: a joint whose target was set since is held
        # no more, and one that came back from offline since is (the robot may lag behind its frames).
        held_now = self.held
        self._held = {name: why for name, why in self._held.items() if name in held_now}
        self._watch_offline(offline)
        if frame.resumed:  # (held as of now, and for the lost port: not a joint on another line back from offline)
            resumed = frozenset(
                n for n, why in held_now.items() if why == "resumed" and self.joints[n].line in frame.resumed
            )
            self._line_resumed(frame.resumed, resumed)
        came_back = {name for name, why in held_now.items() if why == "rejoined" and name not in self._held}
        self._answered.update(came_back)  # (it answered its probe: under the watch from now on)
        if came_back:
            self._came_back(frozenset(came_back))
        merged = RobotFrame(
            frame.cycle,
            now,
            positions,
            {},
            failed,
            offline,
            stamps,
            line_cycles=frame.line_cycles,
            resumed=frame.resumed,
            held=held,
            not_sent=not_sent,
            lost=lost,
        )
        self._settle(frame.line_cycles, frame.line_started)
        self._step(merged, frame.line_started)
        self._latest = dataclasses.replace(merged, targets=dict(self._targets))
        event, self._new_frame = self._new_frame, anyio.Event()
        event.set()

    def _agreed(self, readings: Mapping[str, float], stamps: Mapping[str, float]) -> dict[str, float]:
        """Those of ``readings`` that agree with their joint's reading before (see TURN_SPEED): where the joints
        are.  A garbled one, and the one after it, are left out."""
        agreed = {}
        for name, degrees in readings.items():
            stamp = stamps.get(name, 0.0)
            before = self._last_read.get(name)
            if before is not None and stamp == before[1]:
                # The same reply again: a frame carries each line's newest cycle, so a line that ran no cycle since
                # the one before brings its readings once more.  A reading cannot agree with itself.
                continue
            self._last_read[name] = (degrees, stamp)
            self._recent.setdefault(name, deque(maxlen=SHOWN_READINGS)).append(degrees)
            if before is None:
                # A joint's first reading (at the open, or since it answered again: see _on_frame) has none to agree
                # with: a garbled one would be held or moved from.  Unsettled until the next agrees, as any is.
                self._unsettled.setdefault(name, 0)
                continue
            step = min(TURN_SPEED * abs(stamp - before[1]), TURN_STEP)
            if abs(degrees - before[0]) <= step + TURN_SLACK:
                agreed[name] = degrees
                self._agreed_stamps[name] = stamp
                self._unsettled.pop(name, None)
            else:
                self._unsettled[name] = self._unsettled.get(name, 0) + 1
        return agreed

    async def watch_lines(self) -> None:
        """Tell the robot of each line's port lost or back as its bus knows it (see :meth:`_line_changed`);
        runs beside :meth:`pump` until the robot's block ends."""

        async def watch(bus: Bus) -> None:
            while await bus.state_change() is not State.CLOSED:
                self._line_changed()

        async with anyio.create_task_group() as tasks:
            for bus in self.group.buses.values():
                tasks.start_soon(watch, bus)

    def _line_changed(self) -> None:
        """A line's port was lost (or is back).  A frame tells the robot so as well, but with every line lost no
        frame comes: the motions give up the lost lines' joints here (a motion with none left ends), and what
        waits for replies (on_wire, free, read_pose) is woken to leave them out."""
        self._lost_lines |= {n for n, bus in self.group.buses.items() if bus.state is State.LOST}
        self.watch.forget(self.lost)  # (no frame may come to say so: every line lost)
        for name in self.lost:  # (coasting from a cancelled motion: a stop's ramp would wait for frames too)
            self._velocity[name] = 0.0
            self._coasting.pop(name, None)
        self._drop_lost_joints()
        self._tell_lines_changed()
        event, self._new_frame = self._new_frame, anyio.Event()
        event.set()

    def _tell_lines_changed(self) -> None:
        """Wake what waits in line_change: the lost lines may be others now."""
        event, self._lines_changed = self._lines_changed, anyio.Event()
        event.set()

    def _drop_lost_joints(self) -> None:
        """The motions give up the joints on a line whose port is lost, and a motion with none left ends: with
        every line lost no frame comes to step it (see _line_changed, and run for a motion started meanwhile)."""
        lost = self.lost
        driven = frozenset(name for plan in self._plans for name in plan.joints & lost)
        if driven:
            self._give_up_lost(driven)
        for plan in [plan for plan in self._plans if not plan.joints]:
            plan.finish()
            self._plans.remove(plan)

    def _settle(self, line_cycles: Mapping[str, int], line_started: Mapping[str, float]) -> None:
        """Joints a cancelled motion left (see run) come to rest once their line has run two cycles begun since:
        the servo has been sent the frozen target for a whole cycle, and a stop() starting it again at the speed
        it had would throw it from rest (a joint still within a cycle of the cancel is slowed down smoothly)."""
        for name, (cancelled, first) in list(self._coasting.items()):
            line = self.joints[name].line
            if line_started.get(line, 0.0) <= cancelled:
                continue
            if first is None:
                self._coasting[name] = (cancelled, line_cycles[line])
            elif line_cycles[line] > first:
                del self._coasting[name]
                self._velocity[name] = 0.0

    def _line_resumed(self, lines: frozenset[str], held: frozenset[str]) -> None:
        """Lines whose lost port came back: their servos may have restarted, free and elsewhere, so the streams
        hold those joints (no command until a target is set again).  A motion driving on from where its plan
        was could throw them there: it gives them up (going on with its joints elsewhere, then raising
        MotionStopped); where they are is unknown until they answer again (hold() and read_pose() leave
        them out), and a stop has nothing to ramp for them."""
        error = MotionStopped(
            f"line {', '.join(sorted(lines))} came back after its port was lost: its joints are sent nothing "
            "until a target is set again (their servos may have restarted, free and elsewhere); the motion gave "
            "them up"
        )
        on = {name for name, joint in self.joints.items() if joint.line in lines}
        self._give_up(on, error)
        for name in held:
            self._hold_unknown(name, "resumed")

    def _give_up_lost(self, joints: frozenset[str]) -> None:
        """The motions stop driving ``joints``, on lines whose port is lost: they go on with their others, then
        raise MotionStopped; a motion left with none ends at once (one line, or every line it moves, lost)."""
        for plan in self._plans:
            mine = plan.joints & joints
            if not mine:
                continue
            plan.joints -= mine
            if plan.given_up is not None and not plan.lost_lines:
                continue  # (given up first as a line came back: said so, as _give_up keeps the first reason)
            plan.lost_lines |= {self.joints[name].line for name in mine}
            # Said as it stands: a later loss that takes a motion's last joints makes "went on" untrue.
            plan.given_up = MotionStopped(_lost_words(sorted(plan.lost_lines), went_on=bool(plan.joints)))
        for name in joints:  # (nothing moves them now: a stop has nothing to slow down)
            self._velocity[name] = 0.0
            self._coasting.pop(name, None)

    def _came_back(self, joints: frozenset[str]) -> None:
        """Joints whose servo answered again after going offline: the streams hold them, as after a lost port
        (see _line_resumed): their servos may have restarted meanwhile (a brown-out), free and elsewhere."""
        names = ", ".join(sorted(joints))
        self._give_up(
            joints,
            MotionStopped(
                f"joint {names} came back after going offline: sent nothing until a target is set again (its "
                "servo may have restarted, free and elsewhere); the motion gave it up"
            ),
        )
        for name in joints:
            self._hold_unknown(name, "rejoined")

    def _give_up(self, joints: set[str] | frozenset[str], error: MotionStopped) -> None:
        """Running motions stop driving ``joints`` (going on with their others, then raising ``error``)."""
        for plan in self._plans:
            if plan.joints & joints:
                plan.joints -= joints
                plan.given_up = plan.given_up or error

    def _hold_unknown(self, name: str, why: str) -> None:
        """``name`` is held (sent nothing until a target is set) since something (``why``: ``"resumed"``,
        ``"rejoined"``) after which where it is is unknown: nothing to ramp, hold or read for it."""
        self._held[name] = why
        self._velocity[name] = 0.0
        self._envelope.pop(name, None)
        self._positions.pop(name, None)

    def mark_closing(self) -> None:
        """The robot's block has ended (see :mod:`.startup`): from now on a command from elsewhere (a task
        that outlived the block) is refused with BusClosed, and motions still running end with it; the
        joints keep their last targets until the lines' streams close (as the robot's ``on_close`` says)."""
        if self._closing:
            return
        self._closing = True
        for plan in self._plans:
            plan.finish(BusClosed(CLOSED))
        self._plans.clear()
        self._velocity = dict.fromkeys(self.joints, 0.0)

    def mark_closed(self) -> None:
        """The block's end is through: every call now fails at once with BusClosed, frame waits included."""
        self.mark_closing()
        self._end(BusClosed(CLOSED))

    def freed_on_close(self, freed: Iterable[tuple[str, int]]) -> None:
        """The servos ``freed`` ``(line, id)`` were sent free as their line's stream closed: their joints'
        targets say so from then on (a closed robot's snapshots still read)."""
        names = {self._by_key[key] for key in freed if key in self._by_key}
        self._targets.update(dict.fromkeys(names))
        self.untouched.difference_update(names)
        for name in names:
            self._held.pop(name, None)

    def _check_commands(self) -> None:
        if self._closing:
            raise BusClosed(CLOSED)

    def _check_watched(self) -> None:
        """Refuse a command the robot could not follow: the block has ended, or its frames have (a line lost
        without ``reconnect``).  The other lines' streams would still send a target, but nothing reads where
        the joints go, the safety watch included: a control loop must not run on blind.  (Freeing is not
        refused: it still reaches the lines left.)"""
        self._check_commands()
        if self._end_error is not None:
            raise again(self._end_error)

    def _end(self, error: IcsError) -> None:
        self._velocity = dict.fromkeys(self.joints, 0.0)  # nothing moves them any more: a stop has nothing to slow
        self._end_error = error
        if not self._ended.is_set():
            self._end_reason = error  # the first: a lost line's, not the block's end that followed it
            self._ended.set()
        for plan in self._plans:
            plan.finish(error)
        self._plans.clear()
        self._new_frame.set()
        self._lines_changed.set()

    # ------------------------------------------------------------------ safety

    def _watch_offline(self, offline: frozenset[str]) -> None:
        for name in list(self._latched):
            if self._latched[name].reason == "offline" and name not in offline:
                del self._latched[name]
        if self.description.safety.continue_on_offline:
            return
        for name in offline:
            if name not in self._answered:
                # Never heard from since the robot opened (unplugged, another rate: the open named it): nothing
                # of it is under control, and stopping the others (action "stop" frees them all) would drop a
                # robot standing on its start pose.  Motions naming it are refused (check_ready).
                continue
            joint = self.joints[name]
            action = self.description.safety.action
            self.trip(
                SafetyStop(
                    f"joint {name} (line {joint.line}, ID {joint.id}) went offline (no answer); action: {action}",
                    joint=name,
                    reason="offline",
                    action=action,
                )
            )

    def trip(self, stop: SafetyStop) -> None:
        """A safety limit was crossed (``stop`` says which and why): end every motion, carry out the
        action, tell every waiter."""
        if stop.joint in self._latched:
            return  # already reported; it stands until the joint is back within limits
        self._latched[stop.joint] = stop
        self.trips.append(stop)
        log.warning("safety stop: %s", stop)
        self._stops += 1
        self._last_stop = stop
        for plan in self._plans:
            plan.finish(stop)
        self._plans.clear()
        self._velocity = dict.fromkeys(self.joints, 0.0)
        if stop.action == "free":
            self._apply({stop.joint: None})
        elif stop.action == "stop":
            self._apply(dict.fromkeys(self.joints))
        # "hold": every joint keeps its last target, the crossing one included.

    def clear_trip(self, joint: str, reasons: Iterable[str]) -> None:
        """Clear ``joint``'s safety trip if it was for one of ``reasons``.

        The safety watch calls this once a reading is back within the limits.  Not a current trip of a joint
        left free: a free servo draws nothing, so its reading says nothing of the load that tripped it (the
        program's next target would power the joint into it again); :meth:`reset_trip` clears that one.
        """
        stop = self._latched.get(joint)
        if stop is None or stop.reason not in reasons:
            return
        if stop.reason == "current" and self._targets.get(joint) is None:
            return
        del self._latched[joint]

    def reset_trip(self, joint: str) -> None:
        """Clear ``joint``'s safety trip by the program's decision, once it has dealt with the cause: targets
        and motions for the joint go again.  A current trip of a joint the watch freed (``action`` ``free`` or
        ``stop``) stands until this call; the others also clear by themselves (see :attr:`tripped`).  The stop
        stays in :attr:`trips`; a joint not tripped is left as it is.

        Raises:
            InvalidArgument: an unknown joint.
        """
        (name,) = self.joint_names([joint])
        self._latched.pop(name, None)
