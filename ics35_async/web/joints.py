"""The Robot page's side: a robot opened from its description file, its joints by name, motions played.

Everything goes through :class:`~ics35_async.robot.Robot`: poses are checked
against the joints' limits there, motions are checked and played there, and
its safety watch trips there; this module only keeps the robot open while the
server runs, refuses to move joints until the page switches motion on (and
switches it off again once that page is gone), and runs a motion in the
background so the page stays live while it plays.  A lost line stops the
page's robot until Reconnect, but keeps it open (``reconnect=True``): freeing
still goes through ``Robot.free`` to the lines left.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Callable, Collection, Iterable, Mapping
from typing import Any

from ..bus import Bus
from ..errors import IcsError, InvalidArgument, UnsafeOperation, error_text
from ..robot import Robot, load_description, open_robot, parse_motion
from ..robot.description import LineSpec
from ..robot.motion import check_motion, check_pace
from ..robot.profiles import check_duration
from ..robot.safety import SafetyStop, UnsettledReadings
from ..robot.startup import check_start_pose, warn_at_open
from ..sim.url import parse_url
from ..tasks import retrieved
from ..transports import same_port
from ..transports.wire_device import url_scheme
from .config import said_on_the_page

# A robot's line missing as the robot opens (see said_on_the_page): its lines come back by themselves only once open.
MISSING_AT_OPEN = (
    "its lines reconnect by themselves to a port lost once the robot is open, not to one missing as it opens: plug"
    " the adapter in, then press Reconnect on the Robot page"
)
# How long Reconnect waits for a lost line that the robot reopens by itself (a reconnect delay: RECONNECT_BACKOFF's
# longest, 0.1 s, with room for a loaded machine and a port slow to open) before it says the line is still lost.
RECONNECT_WAIT = 2.0
FRAME_WAIT = 1.0  # seconds Reconnect's words wait for a frame of the reopened robot (which joints answer)


class RobotSession:
    """The robot ``ics35 web --robot FILE`` serves (open from :meth:`open` to :meth:`close`)."""

    def __init__(
        self,
        path: str,
        options: Mapping[str, Any] | None = None,
        start_pose: Mapping[str, float] | None = None,
        *,
        ask_before_freeing: bool = True,
    ) -> None:
        self.description = load_description(path)  # checked before the server starts
        # Until a robot has been open, an ICS 3.5 joint on a serial line that would start free (read by its free
        # command: a robot standing on it falls) waits for the page's answer: the open frees nothing and says which
        # (start_free_choice), and Reconnect with those joints named opens it (ask_before_freeing=False, the CLI's
        # --yes: not asked).  At a reopen the same: a joint free when the robot ended, or one the person said starts
        # free at Reconnect (lost_joints="free"), is not asked about again; any other is (one held since its servo
        # answered again, with no target: its servo may be bearing the robot).  And a joint silent at an open comes
        # back held, not freed, once it answers (open_robot's confirm_start_free).
        self.ask_before_freeing = ask_before_freeing
        self.start_free_choice: list[str] | None = None
        self._free_confirmed: frozenset[str] = frozenset()  # the joints the page said may start free (this open)
        self._free_known: frozenset[str] = frozenset()  # those free when the robot ended, or said free at Reconnect
        self._lost_answer: str | None = None  # Reconnect's answer for lost_pose, while the open's question waits
        self._freed_to_read: list[str] = []  # those the last open freed to read them (asked about, or --yes)
        self._opened_once = False
        self.path = path
        self.options = dict(options or {})  # open_robot's options for every line (the CLI's --timeout, ...)
        # The next open's start_pose: the one given (--start-pose); after a lost line ended the robot, the
        # targets its joints on the other lines held (they kept holding them), and those of the lost line's
        # ICS 3.5 joints only if the person says so at Reconnect (lost_pose: right if their servos kept their
        # power, wrong if they restarted elsewhere); the lost line's ICS 3.6 joints are read again instead.
        self.start_pose = check_start_pose(self.description, start_pose)
        self.lost_pose: dict[str, float] = {}
        self.lost_lines: list[str] = []
        self.last_targets: dict[str, float | None] = {}  # each joint's last command when a lost line ended the robot
        # and those no target reached then (Robot.uncommanded); before any robot is open, every joint: nothing sent
        # (a joint shown "free" there may be holding, bearing the robot)
        self.last_uncommanded: frozenset[str] = frozenset(self.description.joints)
        self.last_held: dict[str, str] = {}  # and those held then, sent nothing (Robot.held)
        self.ics36: set[str] = set()  # joints seen answering ICS 3.6's position read (read at an open)
        self.kept_trips: list[SafetyStop] = []  # the stops the next open's robot is told of (see _carry_on_from)
        self.robot: Robot | None = None
        self.error: str | None = None
        self.warnings: list[str] = []  # the last open's robot.warnings, which the server says itself (see _hold)
        self.motion_enabled = False
        # The page that switched motion on (see page_gone; None: a script, whose motion stays on until switched
        # off), and the smooth stop that page's going started (set_motion and stop wait for it).
        self._motion_page: str | None = None
        self._page_stop: asyncio.Task[None] | None = None
        self.outcome: str | None = None  # how the last motion ended
        self.tell: Callable[[str], None] | None = None  # the server's terminal (create_app's note): a lost line
        self.left_words: str | None = None  # what the last robot closed left its joints in (Robot.joints_left)
        self._open_said: str | None = None  # the outcome the last open or Reconnect said (see _stop_at_loss)
        # What plays, by name: a motion, or the moves of the sliders (a slider moved while another's move runs
        # leaves that one to finish: the robot gives each joint to the newest move naming it).
        self._jobs: dict[asyncio.Task[None], str] = {}
        self._moves_only = False  # every job playing is a slider's move (see move)
        self._stopped_because = ""  # why the motion playing was stopped, if not by Stop
        self._holder: asyncio.Task[None] | None = None  # the task holding the robot open (see open)
        self._closing = asyncio.Event()
        # The robot a lost line stopped, kept open until Reconnect (its lines reconnect by themselves): the lines
        # still there stream on, so Free all reaches their joints and sees it on the wire (see free).
        self._stopped_robot: Robot | None = None
        # Joints Free all could not reach (a lost line's): freed as their line is back, and again at Reconnect
        self._free_at_reopen: list[str] = []

    async def open(self) -> None:
        """Open the robot's lines (an error is kept for the page, not raised): a task of its own holds the
        robot open until :meth:`close`, or until a line is lost, and leaves it in the task that entered it."""
        if self._holder is not None and not self._holder.done():
            return
        await self._open(self.start_pose)

    async def _open(self, start_pose: dict[str, float]) -> None:
        opened = asyncio.Event()
        self._closing = asyncio.Event()
        hold = self._hold(opened, self._closing, start_pose)
        self._holder = asyncio.create_task(hold, name="ics35 web robot")
        await opened.wait()

    async def reopen(self, lost_joints: object = None, start_free: object = None) -> None:
        """Open the robot again after a lost line (or a failed start): what the page's Reconnect asks.

        ``start_free`` names the joints the page's question named (:attr:`start_free_choice`) that may start free:
        freed to read where they stand.  Any other that would start free (but one free when the robot stopped, or
        one ``lost_joints="free"`` names) keeps the robot closed again, nothing freed, and is asked about; an answer
        to ``lost_joints`` given then stands for the next Reconnect (not after an open that failed otherwise).

        A joint that held a target when the robot ended carries on: on a line that stayed, it holds that
        target from the first command (its servo kept holding it); on the lost line an ICS 3.6 joint is
        read, torque left as it is; a free one stays free.  The lost line's holding ICS 3.5 joints
        (:attr:`lost_pose`) hold their last targets with ``lost_joints="hold"`` (their servos kept their
        power) or start free with ``"free"`` (they restarted); with such joints, one of the two must be given.

        Raises:
            InvalidArgument: ``lost_joints`` is not "hold" or "free" while the lost line had holding joints;
                ``start_free`` is not a list of the robot's joint names.
            UnsafeOperation: the lost line is not back (the robot a lost line stopped stays as it is).
        """
        if self.robot is not None:
            return
        if start_free is not None:
            if not isinstance(start_free, list):
                raise InvalidArgument(
                    f"start_free must be a list of joint names (those the question named), not {start_free!r}"
                )
            # (added to the joints named before: a servo that answered only since is asked about alone)
            self._free_confirmed |= frozenset(self.description.known_joints(start_free))
        stopped = self._stopped_robot
        if stopped is not None:
            # Its lost line reopens by itself once its port is back (within a reconnect delay of it): until then
            # the robot stays as it is, not closed for an open that would fail (Free all would reach nothing).
            still = stopped.lost_lines
            with contextlib.suppress(TimeoutError, IcsError):  # (IcsError: the robot closed meanwhile, see below)
                async with asyncio.timeout(RECONNECT_WAIT):
                    while still:
                        still = await stopped.line_change(still)
            if self._stopped_robot is not stopped:  # (the server closing meanwhile: the robot is gone)
                raise UnsafeOperation("the robot was closed while Reconnect waited for its line")
            if still:
                named = self._in_order(still)
                raise UnsafeOperation(
                    f"{_lines_named(named)} {'is' if len(named) == 1 else 'are'} still lost (the port is not back):"
                    " plug it back in, then press Reconnect"
                    + ("; meanwhile Free all reaches the joints on the other lines" if self._other_lines(named) else "")
                )
            self._carry_on_from(stopped)  # (as it is now: a safety stop since, a joint back held)
        # (an answer given to an open its question kept closed stands for the next: the page then asks only that)
        answer = lost_joints if lost_joints is not None else self._lost_answer
        if self.lost_pose and answer not in ("hold", "free"):
            raise InvalidArgument(
                f"line {', '.join(self.lost_lines)} held joints {', '.join(self.lost_pose)} when it was lost:"
                " say whether they hold their last targets ('hold': right if their servos kept their power)"
                " or start free ('free': right if they restarted, free and elsewhere)"
            )
        await self.close()
        # The pose as the close left it: pressed while the other lines still slowed to rest, the stop's end
        # (see _stop_at_loss) takes it again where they came to rest; taken before, they were sent back.
        pose = dict(self.start_pose)
        if self.lost_pose:
            self._lost_answer = str(answer)
            if answer == "hold":
                pose.update(self.lost_pose)
        first = not self._opened_once
        await self._open(pose)
        robot = self.robot
        if robot is None:
            if not self.start_free_choice:  # (a line missing: the servos may restart before the next Reconnect)
                self._lost_answer = None
            elif self.tell is not None and not first:  # (the terminal heard the robot stop: it hears why it waits)
                joints = self.start_free_choice
                one = len(joints) == 1
                self.tell(
                    f"Reconnect did not open the robot, nothing freed: joint{'' if one else 's'} {', '.join(joints)}"
                    f" {'speaks' if one else 'speak'} ICS 3.5 and would start free (read by freeing"
                    f" {'it' if one else 'them'}), which was not free when the robot stopped: the Robot page asks"
                )
            return
        freed = self._freed_to_read
        where = "it stands" if len(freed) == 1 else "they stand"
        said = [] if first else await self._reopen_words(robot, str(answer))
        if self.robot is not robot:  # (a line lost again meanwhile: _stop_at_loss has said how it stands)
            return
        if freed:  # (at a reopen, those the page's answer named: the others were free already, or said free above)
            said.append(f"{', '.join(freed)} freed to read where {where}")
        if first:  # (its first open, after a failed start or the open's question)
            self.outcome = f"opened: {'; '.join(said)}" if said else "opened"
        else:
            free_now, self._free_at_reopen = self._free_at_reopen, []
            if free_now:
                # Free all was asked while their line was lost: an ICS 3.6 joint read at the open keeps its torque.
                with contextlib.suppress(IcsError):
                    await robot.free(free_now)
                said.append(f"{', '.join(free_now)} freed, as Free all asked")
                if self.robot is not robot:
                    return
            self.outcome = "; ".join(["reconnected", *said])
            self.start_pose, self.lost_pose, self.lost_lines = pose, {}, []
        self._open_said = self.outcome
        if self.tell is not None:
            # The terminal said the robot was not open (its question, a line missing or lost): it hears it is now.
            how = "answer" if start_free is not None else "Reconnect"
            what = f"{'opened' if first else 'reopened'} the robot" + (f": {'; '.join(said)}" if said else "")
            self.tell(f"the Robot page's {how} {what}")

    async def _reopen_words(self, robot: Robot, answer: str) -> list[str]:
        """What Reconnect's ``answer`` did to the lost line's joints (none: nothing asked), for its outcome: those
        whose servo failed the newest cycle are said apart (not answering yet), not said to hold or start free."""
        lost = list(self.lost_pose)
        if not lost:
            return []
        failed: frozenset[str] = frozenset()
        with contextlib.suppress(TimeoutError, IcsError):  # (a frame of the robot just opened: at once, or its first)
            async with asyncio.timeout(FRAME_WAIT):
                failed = (await robot.wait_frame(0)).failed
        silent = [name for name in lost if name in failed or name in robot.unreached]
        there = [name for name in lost if name not in silent]
        said = []
        if there:
            one = len(there) == 1
            done = (
                ("holds its last target" if one else "hold their last targets")
                if answer == "hold"
                else ("starts free" if one else "start free")
            )
            said.append(f"{', '.join(there)} {done}")
        if silent:  # (the table says what comes of them: offline, then held once they answer; or the answer's)
            said.append(f"{', '.join(silent)} not answering yet")
        return said

    async def _hold(self, opened: asyncio.Event, closing: asyncio.Event, start_pose: dict[str, float]) -> None:
        # No RobotWarning from the open (this task's own context): issued in the server's loop, it would point
        # into asyncio; the server says self.warnings in its own words, as it does the other start-up problems.
        warn_at_open.set(False)
        # reconnect: a lost line leaves the others streaming (see _stop_at_loss), its own reopened once it is back.
        options = {**self.options, "reconnect": True}
        unconfirmed: list[str] = []  # the joints this open would have freed unasked: it freed nothing
        self._freed_to_read = []

        def may_start_free(joints: list[str]) -> bool:
            asked = self.description.on_hardware(joints)
            # (free when the robot stopped, or said to start free at Reconnect: freeing them changes nothing asked)
            known = self._free_known | (self.lost_pose.keys() if self._lost_answer == "free" else set())
            unconfirmed[:] = [j for j in asked if j not in self._free_confirmed and j not in known]
            self._freed_to_read = [j for j in asked if j not in known] if not unconfirmed else []
            return not unconfirmed

        if self.ask_before_freeing:
            options["confirm_start_free"] = may_start_free
        block = open_robot(self.description, on_close="hold", start_pose=start_pose, **options)
        try:
            async with block as robot:
                self._opened_once, self.start_free_choice = True, None
                # (each answer was for this open: a later one asks again of what is not known free then)
                self._free_confirmed = self._free_known = frozenset()
                self._lost_answer = None
                for stop in self.kept_trips:  # (before anyone can move it: motion is off until the page's switch)
                    # Told as a "free" stop: the joint is free already, and "stop" would free the others too.
                    robot.trip(SafetyStop(str(stop), joint=stop.joint, reason=stop.reason, action="free"))
                self.robot, self.error, self.warnings = robot, None, list(robot.warnings)
                self.kept_trips = []
                self.last_targets, self.last_uncommanded, self.last_held = {}, frozenset(), {}
                opened.set()
                asked = asyncio.ensure_future(closing.wait())
                ended = asyncio.ensure_future(robot.wait_end())
                lost = retrieved(robot.line_change(()))  # (its error: the robot's end, which `ended` tells)
                try:
                    done, _ = await asyncio.wait({asked, ended, lost}, return_when=asyncio.FIRST_COMPLETED)
                    if lost in done and lost.exception() is None and not closing.is_set():
                        await self._stop_at_loss(robot, lost.result())
                    # Kept open, its other lines streaming, until Reconnect or the server's end (or until its
                    # lines end: a lost port that could not be reopened).
                    await asyncio.wait({asked, ended}, return_when=asyncio.FIRST_COMPLETED)
                    if ended.done() and not closing.is_set() and self._stopped_robot is None:
                        why = error_text(ended.result())
                        self.error = f"the robot stopped: {why}; with the line back, press Reconnect"
                        self._carry_on_from(robot)
                finally:  # (cancelled too, if this task is: none is left pending)
                    for task in (asked, ended, lost):
                        task.cancel()
        except (IcsError, OSError) as exc:
            # (the question stands only while it is what keeps the robot closed: a line missing is said instead)
            self.start_free_choice = unconfirmed or None
            if unconfirmed:
                self.error = "the robot is not open, nothing freed: it waits for the answer to its question (below)"
                # (what the open warned of: a joint left out of the question, its servo silent, says why)
                self.warnings = [] if block.robot is None else list(block.robot.warnings)
            else:  # (an answer is for the open it was given to: the robot may stand otherwise later)
                self._free_confirmed = frozenset()
                self.error = f"the robot's lines could not be opened: {said_on_the_page(exc, MISSING_AT_OPEN)}"
        finally:
            self.robot = self._stopped_robot = None
            self.motion_enabled = False
            opened.set()

    async def _stop_at_loss(self, robot: Robot, lost: frozenset[str]) -> None:
        """Line(s) ``lost`` lost their port: the page's robot stops (motion off, what plays slowed to rest on the
        lines left, nothing moved until Reconnect), kept open so that Free all still reaches the other lines."""
        self.robot, self._stopped_robot = None, robot
        self.motion_enabled, self._motion_page = False, None
        # Kept from here, not read again once the stop is over: a line back by then (within the ramp) is still the
        # one Reconnect asks about (its servos may have restarted while it was away).
        lines = self.lost_lines = self._in_order(lost)
        self.error = f"{self._stopped_by(lines)}; with the line back, press Reconnect"
        if self.tell is not None:  # (the terminal said how the robot opened: it hears that it stopped)
            self.tell(f"{self._stopped_by(lines)}; with the line back, press Reconnect on the Robot page")
        if self.outcome == self._open_said:  # (how the open went is no longer how it stands; a motion's end is)
            self.outcome = None
        # Reconnect's question goes with its offer: taken now (the lost line's joints keep their targets through
        # the stop), and again once the other lines have slowed to rest (their targets, where they came to rest).
        self._carry_on_from(robot)
        await self._stop(why=f"line {', '.join(lines)} was lost", robot=robot)
        self._carry_on_from(robot)

    def _carry_on_from(self, robot: Robot) -> None:
        """What Reconnect starts from (see :meth:`reopen`), taken as a lost line stops ``robot`` and again once the
        other lines have slowed to rest (and once Free all has freed joints, and at Reconnect: what it is then)."""
        self.ics36.update(name for name, mode in robot.start_modes.items() if mode == "read")
        # A joint held since its servo answered again was sent nothing: its servo may have restarted (free and
        # elsewhere: its old target would throw it there) or kept its power (holding: freeing it drops what it
        # bears).  Which, the person knows: it is asked about with the lost line's joints.
        held = robot.held
        targets = robot.targets
        self.last_targets = targets  # what the page shows until Reconnect (each joint keeps it)
        self.last_uncommanded = robot.uncommanded
        self.last_held = held
        # Freed and free since: Reconnect frees it again to read it without asking (that changes nothing).
        unknown = robot.uncommanded | held.keys()  # (held with no target: its servo may bear the robot)
        self._free_known = frozenset(name for name, target in targets.items() if target is None and name not in unknown)
        # (a line back by itself since keeps its place: its joints are held, sent nothing, until Reconnect)
        self.lost_lines = self._in_order({*self.lost_lines, *robot.lost_lines})
        # A current trip of a joint the watch freed stands until the person's Reset (a free servo draws nothing, so
        # no reading clears it): a new robot knows nothing of it, and would let the next move drive the joint into
        # the load that tripped it.  (The other stops clear, or trip again, by the new robot's own readings.)
        self.kept_trips = [
            stop for name, stop in robot.tripped.items() if stop.reason == "current" and robot.targets[name] is None
        ]
        kept: dict[str, float] = {}
        lost: dict[str, float] = {}
        for name, target in targets.items():
            if target is None:
                continue  # free: stays free
            if name in self.ics36 and (name in held or self.description.joints[name].line in self.lost_lines):
                continue  # read again (ICS 3.6): torque left as it is
            if name in held or self.description.joints[name].line in self.lost_lines:
                lost[name] = target  # the person says whether it still holds it
            else:
                kept[name] = target  # its servo kept holding it
        self.start_pose, self.lost_pose = kept, lost

    async def close(self) -> None:
        await self.stop()
        # (what its streams leave each joint in, from what they sent: words for the server's end, see left_words)
        kept = self.robot or self._stopped_robot
        if kept is not None:  # (none open: the joints are as the last one left them)
            self.left_words = kept.joints_left()
        holder, self._holder = self._holder, None
        if holder is not None:
            self._closing.set()
            with contextlib.suppress(asyncio.CancelledError):
                await holder
        self.robot = None

    def flat_out_lines(self) -> list[str]:
        """A word for each robot line on a fast in-process simulator with no ``rate_hz``: nothing paces its
        stream (on hardware the wire does), so it runs as fast as the CPU allows, in this server's loop."""
        said = []
        for line in self.description.lines.values():
            if line.rate_hz is not None or url_scheme(line.port) != "sim":
                continue
            try:
                realtime = parse_url(line.port)[1].get("realtime", False)
            except InvalidArgument:
                continue  # (opening the line says what is wrong with it)
            if not realtime:
                said.append(
                    f"robot line {line.name} ({line.port}) is a fast simulator with no rate_hz: its stream runs "
                    "as fast as the CPU allows, in this server's loop, and the pages answer slowly; give the "
                    "line rate_hz = 100, or its port realtime=1"
                )
        return said

    @property
    def playing(self) -> str | None:
        """The names of the motion or the moves playing (``None``: nothing plays)."""
        return ", ".join(dict.fromkeys(self._jobs.values())) or None  # (a move taken over runs out its time)

    def _stopped_by(self, lines: list[str]) -> str:
        ports = ", ".join(f"{name} ({self.description.lines[name].port})" for name in lines)
        one = len(lines) == 1
        return f"the robot stopped: {'line' if one else 'lines'} {ports} lost {'its port' if one else 'their ports'}"

    def _reconnect_ready(self) -> str | None:
        """Words for the robot a lost line stopped once every line it lost is back (they reopen by themselves):
        Reconnect goes now, where the stop's error and an early Reconnect's refusal said to wait for them."""
        stopped = self._stopped_robot
        if stopped is None or not self.lost_lines or stopped.lost_lines:
            return None
        return f"{_lines_named(self.lost_lines)} {'is' if len(self.lost_lines) == 1 else 'are'} back: press Reconnect"

    def _other_lines(self, lost: Collection[str]) -> bool:
        """Whether the robot has lines other than ``lost`` (a robot of one line is told of none)."""
        return len(set(lost)) < len(self.description.lines)

    def _in_order(self, lines: Collection[str]) -> list[str]:
        """``lines`` in the order the robot file gives them."""
        return [line for line in self.description.lines if line in lines]

    def _robot(self) -> Robot:
        if self.robot is None:
            raise UnsafeOperation(self.error or "the robot is not open")
        return self.robot

    def line(self, name: object) -> tuple[Bus, LineSpec]:
        """The robot's open bus for line ``name``, and the line as the file describes it."""
        spec = self.description.lines.get(name) if isinstance(name, str) else None
        if spec is None:
            raise InvalidArgument(f"the robot has no line {name!r} (its lines: {', '.join(self.description.lines)})")
        return self._robot().group.buses[spec.name], spec

    def line_named_by_port(self, port: str) -> LineSpec | None:
        """The robot's line on ``port``, if one is (under any name of it: ``SIM://x`` for ``sim://x``, a device's
        link for the device: the port is the robot's either way, and cannot be opened beside it)."""
        return next((spec for spec in self.description.lines.values() if same_port(spec.port, port)), None)

    def joint_at(self, line: str, servo_id: int) -> str | None:
        """The joint driven by servo ``servo_id`` on ``line``, if any."""
        return next((j.name for j in self.description.joints_on(line) if j.id == servo_id), None)

    def lines_view(self) -> dict[str, Any]:
        """The robot's name and lines, for every page's navigation."""
        lines = [
            # (simulated: the built-in simulator's, by the library's one rule for a port's scheme)
            {"name": s.name, "port": s.port, "baud": s.baudrate, "simulated": url_scheme(s.port) == "sim"}
            for s in self.description.lines.values()
        ]
        return {"name": self.description.name or self.path, "open": self.robot is not None, "lines": lines}

    def _moving_allowed(self) -> Robot:
        robot = self._robot()
        if not self.motion_enabled:
            raise UnsafeOperation("motion is not enabled: switch on 'enable motion' first")
        return robot

    def view(self) -> dict[str, Any]:
        robot = self.robot
        frame = None if robot is None else robot.latest
        telemetry = {} if robot is None else robot.telemetry
        # Sent nothing, their servo offline: no target went out (the robot's rule, as `ics35 play`'s live table
        # follows it); their targets stay, where their sliders stand.  Their readings: robot.telemetry has none.
        unreached = frozenset() if robot is None else robot.unreached
        tripped = {} if robot is None else robot.tripped
        # Sent nothing since their servo answered again (or their line came back), and why: the target they
        # had is not where they are (restarted, free and elsewhere), so the page says so beside it.
        # (the robot a lost line stopped: its targets and holds as they are now, a joint freed since included)
        kept = robot or self._stopped_robot
        held = self.last_held if kept is None else kept.held
        targets = self.last_targets if kept is None else kept.targets
        # No target set ("-": only read, torque as found; or offline), where another joint's None is "free": the
        # robot's rule, as `ics35 play`'s live table follows it.
        uncommanded = self.last_uncommanded if kept is None else kept.uncommanded
        joints = []
        for name, spec in self.description.joints.items():
            t = telemetry.get(name)
            stop = tripped.get(name)
            joints.append(
                {
                    "name": name,
                    "line": spec.line,
                    "id": spec.id,
                    "min": spec.min,
                    "max": spec.max,
                    "position": None if frame is None else _round(frame.positions.get(name)),
                    "target": _round(targets.get(name)),
                    "temperature_c": None if t is None else _round(t.temperature_c),
                    "current": None if t is None else t.current,
                    "offline": name in unreached,
                    "uncommanded": name in uncommanded,  # (the page shows "-" for its target)
                    "tripped": None if stop is None else str(stop),
                    "held": held.get(name),
                    # Free all asked while its line is lost: its free goes out the moment the line is back
                    "free_when_back": name in self._free_at_reopen and kept is not None and name in kept.lost,
                }
            )
        ready = self._reconnect_ready()
        error = self.error if ready is None else f"{self._stopped_by(self.lost_lines)}; {ready}"
        asking = None if robot or not self.start_free_choice else {"joints": self.start_free_choice}
        return {
            "name": self.description.name or self.path,
            "open": robot is not None,
            "error": error,
            "reconnect_ready": ready,  # (the page says it in place of an early Reconnect's refusal)
            "warnings": self.warnings if robot is not None or asking else [],
            "cycle": None if frame is None else frame.cycle,
            "motion_enabled": self.motion_enabled,
            "playing": self.playing,
            "outcome": self.outcome,
            "joints": joints,
            # Reconnect's question: what the lost line's holding joints do (see reopen)
            "reconnect_choice": (
                {"lines": self.lost_lines, "joints": list(self.lost_pose)}
                if self.lost_pose and self._lost_answer is None
                else None
            ),
            # The open's question: the joints it would free to read them (see reopen's start_free)
            "start_free_choice": asking,
        }

    async def set_motion(self, enabled: bool, page: str | None = None) -> None:
        """Motion on: the joints hold where they stand (their targets become their positions).  Off: a
        motion playing stops smoothly (``Robot.stop``), and nothing moves the joints until it is on again.

        ``page``: the page switching it on (its name on its WebSocket, connected now: the caller checks),
        whose going switches it off again (:meth:`page_gone`); the last page to switch it on is the one.
        Without one (a script), it stays on until it is switched off.  Switching on waits for nothing but
        the smooth stop a gone page started (:meth:`settled`), so a caller's check that the page is connected,
        made once that stop is over, still holds when motion goes on; a caller waits for
        :meth:`ready_for_motion` first (the joints' readings confirmed, so that hold() holds them all).
        """
        await self.settled()
        robot = self._robot()
        if enabled:
            left = robot.hold()
            held = robot.held
            for name in left.keys() & held.keys():  # (the library's words name its API; the page's way out is a button)
                left[name] = _held_on_the_page(held[name])
            # (the page's state line: not "joints free"; and each joint left as it was, with why)
            self.outcome = "joints hold where they stand" + "".join(
                f"; {n} left as it is: {w}" for n, w in left.items()
            )
            self.motion_enabled = True
            self._motion_page = page
        else:
            self.motion_enabled = False  # first (and not again after the stop: an "on" meanwhile stands)
            await self.stop(why="motion switched off")

    def page_gone(self, page: str, why: str) -> None:
        """The page named ``page`` is gone (its tab closed or reloaded, or its network: see ``api.updates``).
        If it switched motion on, motion goes off as the switch turned off does: at once for moves and
        motions, and a motion playing stops smoothly (in a task of its own: the caller cannot wait).
        ``why``: said in the state line (``outcome``), or in the stopped motion's."""
        if not self.motion_enabled or self._motion_page != page:
            return
        self.motion_enabled = False
        self._motion_page = None
        said = f"motion switched off: {why}"
        if self.playing is None:
            self.outcome = said  # (else the motion's own "stopped (...)" says it)
        self._page_stop = retrieved(self._stop(why=said))

    async def ready_for_motion(self) -> None:
        """Returns once motion may be switched on: every joint read twice from now on, each reading agreeing with
        the one before it (``Robot.read_pose``), then the smooth stop a gone page started over (:meth:`settled`).
        A joint posed by hand just before, its newest reading not yet confirmed, is then held where it stands
        rather than left free; one whose readings keep disagreeing (``UnsettledReadings``) is left to ``hold()``,
        which leaves it free and says why."""
        with contextlib.suppress(UnsettledReadings):
            await self._robot().read_pose()
        await self.settled()

    async def settled(self) -> None:
        """Returns once the smooth stop a gone page started is over (at once, without yielding, if none is
        under way): nothing else drives the joints meanwhile."""
        pending = self._page_stop
        if pending is not None and not pending.done():
            await asyncio.wait({pending})  # (its error, if any, is its own: see page_gone)

    async def move(self, pose: Mapping[str, Any], duration: float) -> None:
        """Move the named joints smoothly (``Robot.move_to``: limits checked before anything moves; what the robot
        refuses to start is the request's answer: see _check_ready)."""
        robot = self._moving_allowed()
        checked = robot.check_pose(pose)
        seconds = check_duration(duration)  # (move_to's own rule, checked here to be the request's answer)
        _check_ready(robot, checked)
        await self._run(robot.move_to(checked, seconds), f"move {', '.join(checked)}", alongside=True)

    async def play(self, doc: object, speed: float = 1.0) -> None:
        """Play a motion file's content (``parse_motion`` checks it; ``Robot.play`` checks it against the robot)."""
        robot = self._moving_allowed()
        motion = parse_motion(doc, "the uploaded motion")
        # (Robot.play's own rule, a keyframe played at that speed past an hour included, checked here to be the
        # request's answer rather than the outcome of a play that stopped the motion playing first)
        speed = check_pace(motion, speed)
        # Unknown joints, limits: against the description, as `ics35 play` does, before anything moves.
        check_motion(self.description, motion, "the uploaded motion")
        _check_ready(robot, motion.joints)
        await self._run(robot.play(motion, speed=speed), motion.name or "motion")

    async def _run(self, job: Any, name: str, alongside: bool = False) -> None:
        """Play ``job`` in the background; what plays stops first, but for moves ``alongside`` one another."""
        robot = self.robot
        if alongside and self._moves_only:
            await self.settled()
        else:
            await self.stop()
        # Motion may have gone off while the motion playing stopped (its page gone, the switch, a lost line):
        # asked again here, or the job would move a robot with motion off.
        try:
            if self._moving_allowed() is not robot:
                raise UnsafeOperation("the robot was opened again meanwhile: nothing was sent")
        except BaseException:
            job.close()  # (never started: no "coroutine was never awaited" warning)
            raise
        if not self._jobs:
            self._stopped_because = ""
        self.outcome, self._moves_only = None, alongside and (self._moves_only or not self._jobs)

        async def run() -> None:
            try:
                await job
                self.outcome = f"{name}: done"
            except asyncio.CancelledError:
                because = f" ({self._stopped_because})" if self._stopped_because else ""
                self.outcome = f"{name}: stopped{because}"
                raise
            except IcsError as exc:
                self.outcome = f"{name}: {exc}"
            finally:
                self._jobs.pop(task, None)

        task = asyncio.create_task(run())
        self._jobs[task] = name

    async def stop(self, ramp: float = 0.3, why: str = "") -> None:
        """Stop a motion smoothly (``Robot.stop``); the joints hold.  ``why``: said in the outcome."""
        await self.settled()
        await self._stop(ramp, why)

    async def press_stop(self) -> None:
        """The page's Stop (see :meth:`stop`).

        Raises:
            UnsafeOperation: the robot is not open (nothing plays): how it stands, and what the person can do.
        """
        if self.robot is None:
            if self._stopped_robot is not None:  # (kept: its other lines stream on, see free)
                there = " on the lines still there" if self._other_lines(self.lost_lines) else ""
                todo = f"Free all lets go of those{there}; Reconnect opens the robot again"
            elif self.start_free_choice:
                todo = "the answer to its question opens it (Free all then lets them go)"
            else:
                todo = "Reconnect opens the robot again (Free all then lets them go)"
            raise UnsafeOperation(
                f"nothing to stop: the robot is not open ({self.error or 'closed'}); nothing plays, and its joints "
                f"keep their last commands (a holding joint holds): {todo}"
            )
        await self.stop()

    async def _stop(self, ramp: float = 0.3, why: str = "", robot: Robot | None = None) -> None:
        jobs = [task for task in self._jobs if not task.done()]
        self._jobs.clear()
        robot = self.robot if robot is None else robot
        if jobs:
            self._stopped_because = why
            for task in jobs:
                task.cancel()
            await asyncio.wait(jobs)  # (each one's end is its own: see _run)
            if robot is not None:
                with contextlib.suppress(IcsError):
                    await robot.stop(ramp)

    def reset_trip(self, joint: object) -> None:
        """The person says a tripped joint's cause is dealt with (``Robot.reset_trip``: a current trip of a joint
        the watch freed stands until then); the joint stays as it is until it is moved."""
        if not isinstance(joint, str):
            raise InvalidArgument(f"joint must be a joint's name, not {type(joint).__name__}")
        self._robot().reset_trip(joint)
        self.outcome = f"joint {joint}: safety stop reset (as it was left until it is moved)"

    async def free(self, joint: object = None) -> None:
        """Every joint free (torque off: a motion playing stops at once, and motion goes off), or only ``joint``
        (one held since its servo answered again: freed, it is read where it stands and may be moved from there;
        a motion playing goes on with the others).

        Every joint, with the robot stopped by a lost line: those on the lines still there are freed on the wire,
        the lost line's are named (their servos may still hold) and go free the moment their line is back (their
        streams send the free, before Reconnect; Reconnect frees them once more).
        """
        if joint is None:
            await self.stop(ramp=0.0)
            self.motion_enabled = False
            if self.robot is None and self._stopped_robot is not None:
                await self._free_stopped(self._stopped_robot)
                return
            await self._robot().free()
            self.outcome = "joints free"  # (the page's state line: no longer how the last motion ended)
            return
        if not isinstance(joint, str):
            raise InvalidArgument(f"joint must be a joint's name, not {type(joint).__name__}")
        await self._robot().free([joint])
        self.outcome = f"joint {joint} free"

    async def _free_stopped(self, robot: Robot) -> None:
        """Free all on the robot a lost line stopped (see free)."""
        lost = [name for name in robot.joints if name in robot.lost]
        # Robot.free: the other lines' joints are freed on the wire (waited for); the lost line's take the free as
        # their target, sent once the line is back (not waited for: it answers nothing).
        await robot.free()
        self._free_at_reopen = sorted(set(self._free_at_reopen) | set(lost), key=list(robot.joints).index)
        self._carry_on_from(robot)  # (Reconnect holds none of them now)
        if not lost:
            self.outcome = "joints free"
            return
        names = ", ".join(self._free_at_reopen)
        one = len(self._free_at_reopen) == 1
        self.outcome = ("joints free on the lines still there; " if self._other_lines(self.lost_lines) else "") + (
            f"{names} not reached ({_lines_named(self.lost_lines)} lost): "
            f"{'its servo' if one else 'their servos'} may still hold; {'it goes' if one else 'they go'} free the"
            " moment the line is back: hold the robot as you plug it in"
        )


def not_freed_at_start(joints: list[str]) -> str:
    """What the server's terminal says of a robot its start left closed: ``joints`` would start free, which the
    page has not confirmed."""
    one = len(joints) == 1
    named = f"joint{'' if one else 's'} {', '.join(joints)}"
    return (
        f"the robot was not opened, nothing freed: {named} {'speaks' if one else 'speak'} ICS 3.5, whose position is"
        f" read only by freeing {'it' if one else 'them'}, and a robot standing on {'it' if one else 'them'} falls:"
        " hold the robot,"
        " then answer the question on the Robot page (or start the server with --start-pose stating where"
        f" {'it stands' if one else 'they stand'}, or --yes)"
    )


def _lines_named(lines: list[str]) -> str:
    """Lines named in words: ``line arm``, ``lines legs, arms``."""
    return f"{'line' if len(lines) == 1 else 'lines'} {', '.join(lines)}"


def _held_on_the_page(why: str) -> str:
    """A held joint (``Robot.held``: sent nothing since its servo answered again, or its line came back, ``why``)
    and the page's way out, its row's Free button: the library's words name its API (set its target)."""
    return (
        f"held, sent nothing, since its servo answered again ({why}): where it stands is unknown; the Free button"
        " in its row frees it to read where it stands"
    )


def _check_ready(robot: Robot, joints: Iterable[str]) -> None:
    """What the robot would refuse a motion of ``joints`` for (``Robot.check_ready``: a joint held, tripped, never
    heard from or standing past a limit), raised now, as the request's answer, rather than told only in the state
    line once the motion has failed."""
    joints = list(joints)
    held = [name for name in joints if name in robot.held]
    if held:
        # The library's words name its API (set_targets); the page's way out is the joint's Free button.
        raise UnsafeOperation(f"joint {held[0]} is {_held_on_the_page(robot.held[held[0]])}, then move it")
    robot.check_ready(joints)


def _round(value: float | None) -> float | None:
    return None if value is None else round(value, 1)
