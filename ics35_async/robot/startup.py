"""Opening a robot: the file checked first, every line opened, the servos' EEPROM limits compared, the stream started.

Nothing is opened before the description has passed every check, so a
mistake in the file never reaches a port.

How each joint starts (``Robot.start_modes``): a joint whose servo speaks
ICS 3.6 is *read* (its position read each cycle, torque left as it was);
a joint the caller gives in ``start_pose`` is *stated* (it holds that
angle from the first cycle on: the caller says the robot is there); any
other joint (ICS 3.5, or a servo that did not answer) starts *free*, since
ICS 3.5 reads a position only with the free command.  With ``start_free`` every
joint not stated starts free, whatever its protocol: no probe tells them apart.
"""

from __future__ import annotations

import contextlib
import functools
import inspect
import os
import sys
import warnings
from collections.abc import AsyncIterator, Awaitable, Callable, Iterable, Mapping
from contextvars import ContextVar
from pathlib import Path
from typing import Any, NoReturn, TypeVar, Unpack

import anyio

from .. import units
from ..bus import CLI_OPTION_NAMES, Bus, BusOptions, open_bus
from ..eeprom import Eeprom
from ..engine import State
from ..errors import (
    InvalidArgument,
    PortLost,
    ReplyError,
    ReplyTimeout,
    SerialPortError,
    UnsafeOperation,
    error_text,
)
from ..group import BusGroup, GroupStream
from ..policies.scan import anyone_there
from ..protocol import FREE
from ..stream import ON_CLOSE
from ..tasks import only_error, task_group
from .description import JointSpec, LineSpec, RobotDescription, check_not_a_port, load_description
from .robot import Robot

T = TypeVar("T")

# open_bus options the description sets per line, so they may not be given to open_robot.
_PER_LINE = frozenset({"baudrate", "echo", "retries", "direction"})


class RobotWarning(UserWarning):
    """Something about the robot worth knowing that does not stop it (e.g. limits wider than the servo's)."""


class RobotOptions(BusOptions, total=False):
    """The options of [`open_robot`][ics35_async.robot.open_robot], every one optional: the robot's own,
    and the [`BusOptions`][ics35_async.bus.BusOptions] every line is opened with (but ``baudrate``,
    ``echo`` and ``retries``, which the description sets per line)."""

    on_close: str
    """What the joints do when the block ends: ``"hold"`` (the default: keep their targets; a free
    joint stays free) or ``"free"`` (each line's stream sends every servo its free once as it closes)."""
    check_limits: bool
    """Read each joint's servo EEPROM at open and issue a [`RobotWarning`][ics35_async.robot.RobotWarning]
    (kept in ``robot.warnings``) where the file allows more than the servo's pulse limits (default ``True``)."""
    offline_after: int
    """Every line's stream: failed cycles before a servo counts as offline (default 3)."""
    probe_interval: float
    """Every line's stream: seconds between probes of an offline servo (default 0.5)."""
    start_pose: Mapping[str, float] | None
    """``{joint: degrees}``: where the named joints are, so they hold that angle from the first
    command on (default ``None``)."""
    confirm_start_free: Callable[[list[str]], bool | Awaitable[bool]] | None
    """Called with the names of the joints about to start free, once the open knows them and before any is freed
    or commanded: those whose servos answered as ICS 3.5 (the free command is their only position read) and are
    not in ``start_pose`` (with ``start_free``, every answering joint not stated).  A false answer ends the open
    with [`UnsafeOperation`][ics35_async.errors.UnsafeOperation], no joint freed or moved; an exception it raises
    ends it the same way, raised as it is.  Not called when no joint starts free (default ``None``: not asked).
    For a program that asks a person first, as ``ics35 play`` does on a serial line: a robot standing on ICS 3.5
    servos falls as they are freed.  A plain function runs in the event loop, which waits for it (the lines are
    open, nothing streams yet); one that waits for something else is a coroutine function.  (A joint whose servo
    did not answer starts offline: once it answers it is held, sent nothing (see ``Robot.held``), until the program
    sets its target or frees it, where without this option it is freed to be read; the open's warnings name it.)"""
    start_free: bool
    """Every joint not in ``start_pose`` starts free, ICS 3.6 ones too, read by the free command (which answers
    with the position on both protocols), and the open asks no servo its protocol (default ``False``).  For a
    program that frees every joint it opens anyway (teaching or calibrating by hand): the probe, and the read
    once more of each ICS 3.5 servo at the whole reply allowance, would be wasted.  A servo is still asked once
    whether it is there (its EEPROM read, with ``check_limits``; else a parameter read): one that does not
    answer starts offline."""


_HOW_TO_OPEN = (
    "a robot is opened with `async with open_robot(...) as robot:` (the block keeps its lines streaming"
    " and ends them); in code without an event loop, `ics35_async.blocking.open_robot`"
)


class RobotBlock(contextlib.AbstractAsyncContextManager[Robot]):
    """What [`open_robot`][ics35_async.robot.open_robot] returns: entered with ``async with``; used any other
    way, it says how.  Kept by a program that must tell what an open cut short (Ctrl-C) left the joints in:
    :meth:`joints_left`.

    Args:
        source: as ``open_robot``'s.
        options: ``open_robot``'s options, as a mapping (checked as the block is entered).
    """

    def __init__(self, source: str | Path | Mapping[str, Any] | RobotDescription, options: RobotOptions) -> None:
        self.robot: Robot | None = None
        """The robot once its lines are open (``None`` before): as the block's ``async with ... as`` gives it."""
        self._session = _robot_session(source, self, **options)

    def joints_left(self) -> str:
        """In words, what the open has left the joints in so far, its close included (see
        [`Robot.joints_left`][ics35_async.robot.Robot.joints_left]): for an open cut short (Ctrl-C) before the
        block's body had the robot."""
        if self.robot is None:
            return "no servo was sent anything (its lines were still being opened)"
        return self.robot.joints_left()

    async def __aenter__(self) -> Robot:
        return await self._session.__aenter__()

    async def __aexit__(self, *exc: Any) -> bool | None:
        return await self._session.__aexit__(*exc)

    def __getattr__(self, name: str) -> NoReturn:
        raise AttributeError(f"{_HOW_TO_OPEN} (open_robot(...) itself has no {name!r})")

    def __enter__(self) -> NoReturn:
        raise TypeError(_HOW_TO_OPEN)

    def __exit__(self, *exc: object) -> None:
        return None

    def __await__(self) -> NoReturn:
        raise TypeError(_HOW_TO_OPEN)


def open_robot(
    source: str | Path | Mapping[str, Any] | RobotDescription, **options: Unpack[RobotOptions]
) -> RobotBlock:
    """Open every line of a robot and stream to all its joints: ``async with open_robot("robot.toml") as robot``.

    The robot opens without moving or freeing a joint whose servo speaks
    ICS 3.6 (its position read).  An ICS 3.5 joint starts free (its only
    position read), unless ``start_pose`` names it: it
    then holds that angle from the first command on, so state where the
    robot really is (a joint elsewhere jumps there).  A program that frees
    every joint it opens passes ``start_free=True``: every joint not stated
    starts free, ICS 3.6 ones too, and the open probes no servo's protocol
    (a robot of ICS 3.5 servos opens about one reply allowance a joint
    sooner).  ``robot.start_modes`` tells how each joint started.

    Args:
        source: a TOML file's path, the same structure as a mapping, or a
            [`RobotDescription`][ics35_async.robot.RobotDescription].
        **options: the robot's options and every line's bus options (e.g. ``adapter_latency=0.005``,
            ``driver="anyio"``), each described in [`RobotOptions`][ics35_async.robot.RobotOptions].

    Raises:
        DescriptionError: the description is not valid (nothing is opened); or ``source`` is a port, not a file
            (``"sim://arm"``, ``"/dev/ttyUSB0"``): a robot's ports go in its file, one a line.
        InvalidArgument: an unknown or bad option, a ``start_pose`` naming an unknown joint or an
            angle outside its limits, or a per-line option (``baudrate``, ``echo``, ``retries``) given here;
            or a line's port refused as written at its open (a ``socket://`` URL without its TCP port; its message
            names the line: a ``sim://`` port the simulator refuses is a DescriptionError).
        SerialPortError: a line's port cannot be opened (its message names the line; a servo that does not
            answer is not an error: its joint starts free and, with ``check_limits``, gets a warning).  At once,
            ``reconnect=True`` or not: it rides out a port lost once its line is open, not one missing (a
            ``PortNotFound`` then says so).
        PortLost: a line's port was lost during the open: at once without ``reconnect``; with
            ``reconnect=True`` only if it was not back within ``LOST_AT_OPEN`` (5) seconds, the open's reads made
            again once it is (they move and free nothing).
    """
    return RobotBlock(source, options)


@contextlib.asynccontextmanager
async def _robot_session(
    source: str | Path | Mapping[str, Any] | RobotDescription, block: RobotBlock, **options: Unpack[RobotOptions]
) -> AsyncIterator[Robot]:
    on_close = options.pop("on_close", "hold")
    check_limits = options.pop("check_limits", True)
    offline_after = options.pop("offline_after", 3)
    probe_interval = options.pop("probe_interval", 0.5)
    start_pose = options.pop("start_pose", None)
    start_free = options.pop("start_free", False)
    confirm_start_free = options.pop("confirm_start_free", None)
    # Checked here, not left to open_bus: a misspelt robot option (``onclose``) would be refused as an
    # "open_bus option", a call the program never made.
    unknown = set(options) - BusOptions.__optional_keys__
    if unknown:
        own = ", ".join(sorted(RobotOptions.__optional_keys__ - BusOptions.__optional_keys__))
        told = units.unknown_options("open_robot", unknown, RobotOptions.__optional_keys__, CLI_OPTION_NAMES)
        raise InvalidArgument(f"{told} (the robot's own: {own}; and open_bus's)")
    bus_options: BusOptions = options
    if isinstance(source, (str, os.PathLike)):  # (a port given for the file: said as open_robot's argument)
        check_not_a_port(source, "open_robot")
    description = source if isinstance(source, RobotDescription) else load_description(source)
    stated = check_start_pose(description, start_pose)
    if on_close not in ON_CLOSE:
        raise InvalidArgument(f"on_close must be one of {', '.join(ON_CLOSE)}, not {on_close!r}")
    units.check_bool("check_limits", check_limits)
    units.check_bool("start_free", start_free)
    if confirm_start_free is not None and not callable(confirm_start_free):
        raise InvalidArgument(f"confirm_start_free must be a function or None, not {type(confirm_start_free).__name__}")
    clash = _PER_LINE & set(bus_options)
    if clash:
        raise InvalidArgument(f"{', '.join(sorted(clash))}: set per line in the robot description, not here")
    buses = {name: open_bus(line.port, **_line_options(bus_options, line)) for name, line in description.lines.items()}
    async with contextlib.AsyncExitStack() as stack:
        # Each bus opened by this task, one after the other: a line that cannot be opened closes
        # the ones opened before it, in reverse order, as the stack unwinds.
        for name, bus in buses.items():
            try:
                await stack.enter_async_context(bus)
            except SerialPortError as exc:
                raise _on_line(exc, description.source, name) from exc
            except InvalidArgument as exc:  # a port refused as written (a bridge URL without its TCP port)
                raise InvalidArgument(f"{description.source}: line {name}: {exc}") from exc
        group = BusGroup(buses)
        robot = block.robot = Robot(description, group)
        waits = _LostAtOpen(buses)
        lines = _LineAnswers(robot)
        silent = (await waits.despite(lambda: _check_limits(robot, lines)))[1] if check_limits else set()
        probed = [j for j in robot.joints.values() if j.name not in stated]
        if start_free:  # (every joint is read by its free: only whether it is there is asked)
            readable: set[str] = set()
            unheard = await waits.despite(lambda: _presence(robot, probed, silent if check_limits else None, lines))
        else:
            readable, unheard = await waits.despite(lambda: _position_reads(robot, probed, silent, lines))
        # The joints the open found silent start offline (probed every probe_interval, back as any offline joint
        # once they answer): asked offline_after cycles first, each at its whole reply allowance, two unplugged
        # legs kept the robot from its first pose (read_pose waits for every joint not offline) for three
        # allowances a joint.
        unheard |= {j.name for j in robot.joints.values() if j.line in lines.empty}
        going_free = [j.name for j in probed if j.name not in readable and j.name not in unheard]
        if confirm_start_free is not None and going_free:
            answer = confirm_start_free(list(going_free))
            if inspect.isawaitable(answer):
                answer = await answer
            if not answer:
                raise UnsafeOperation(
                    f"joint(s) {', '.join(going_free)} would start free (read by freeing them), which was not "
                    "confirmed: no joint was freed or moved"
                )
        streams = {
            line: group[line].stream(
                [j.id for j in description.joints_on(line)],
                rate_hz=spec.rate_hz,
                watch=[j.id for j in description.joints_on(line) if j.name in readable],
                offline=[j.id for j in description.joints_on(line) if j.name in unheard],
                # (a program that asks before freeing is asked again for those: back, they are held, sent nothing)
                hold_offline=confirm_start_free is not None,
                offline_after=offline_after,
                probe_interval=probe_interval,
                # The streams' close is the robot's close: with "free", each line's stream sends every
                # servo its free once as it closes, to its end however the block ended (a cancellation,
                # Ctrl-C, another line lost), a line that lost its port and came back included.
                on_close="free" if on_close == "free" else "hold",
            )
            for line, spec in description.lines.items()
        }
        for name, deg in stated.items():
            joint = robot.joints[name]
            streams[joint.line].set_target(joint.id, joint.position(deg))  # before the first cycle
        # (with start_free no probe remembers which servos answered the open: the robot is told, for joints_left)
        heard = {j.name for j in probed} - unheard if start_free else ()
        robot.started(stated, readable, streams, heard)
        try:
            async with GroupStream(streams) as gstream:
                try:
                    # The robot's cycles run until its block ends, not until a scope around it is cancelled
                    # (run()'s Ctrl-C, a move_on_after): the body's own close-out (a shielded robot.stop() in a
                    # finally) would wait for ever for frames that never come.
                    running: list[anyio.CancelScope] = []

                    async def cycles(work: Callable[[], Awaitable[None]]) -> None:
                        with anyio.CancelScope(shield=True) as scope:
                            running.append(scope)
                            await work()

                    async with anyio.create_task_group() as tasks:
                        tasks.start_soon(cycles, functools.partial(robot.pump, gstream))
                        tasks.start_soon(cycles, functools.partial(robot.watch.run, robot))
                        tasks.start_soon(cycles, robot.watch_lines)
                        try:
                            await waits.first_frame(robot)
                            # A joint's first reading counts only once the next agrees (see Robot._agreed): one
                            # more reply of each read in the first frame, so that hold() or a motion right after the
                            # open finds where they are, as before, rather than leaving them all out as not read yet.
                            # (Not of one unread there: it was not found before either, and a servo that does not
                            # answer would keep the open waiting until it is taken offline.)
                            first = robot.latest
                            read = [n for n in first.positions if n not in first.failed] if first is not None else []
                            await robot.fresh_replies(read, 1)
                            yield robot
                        finally:
                            # From here on nothing commands the joints but the streams' close (a task that
                            # outlived the block is refused): the joints hold their last targets until then.
                            robot.mark_closed()
                            for scope in running:
                                scope.cancel()
                            tasks.cancel_scope.cancel()
                except BaseExceptionGroup as group_error:
                    # The body's own error, not wrapped: the task group is an implementation detail.
                    raise only_error(group_error) from None
        finally:  # (the closed robot's targets then say where the close left the joints)
            robot.freed_on_close(
                (line, servo_id)
                for line, stream in streams.items()
                for servo_id, position in stream.targets_sent_on_close.items()
                if position == FREE
            )


LOST_AT_OPEN = 5.0
"""Seconds an open with ``reconnect=True`` waits in all for lines whose port was lost during its reads (or, every
line lost, as its streams start)."""


class _LostAtOpen:
    """The open's reads (EEPROM limits, which joints answer the position read) despite a port lost meanwhile.

    With ``reconnect=True`` a person expects a robot to ride out a port lost and back (a USB adapter that
    re-enumerates as the servos power up), and a running robot does.  Its reads are begun again once its lines
    are back: they neither move nor free a joint, and what a joint starts as must not be decided on a read the
    loss cut short (a joint taken for silent would start free).  The wait is bounded (:data:`LOST_AT_OPEN`, in
    all): a port that does not come back ends the open with an error saying so, rather than a program waiting
    at its open with nothing on the screen.  Without ``reconnect`` the loss is for good: raised as it is."""

    def __init__(self, buses: Mapping[str, Bus]) -> None:
        self.buses = buses
        self.deadline: float | None = None  # set at the first loss

    def reconnecting(self) -> dict[str, Bus]:
        return {name: bus for name, bus in self.buses.items() if bus.reconnect}

    async def despite(self, step: Callable[[], Awaitable[T]]) -> T:
        while True:
            try:
                return await step()
            except PortLost as lost:
                if not self.reconnecting():
                    raise
                await self._back(self.reconnecting(), str(lost))

    async def first_frame(self, robot: Robot) -> None:
        """``robot.wait_frame(0)``.  With a line lost as the streams start, the others' frames come and the robot
        opens with it lost, as a running robot goes on; with every line lost none comes until one is back: that
        wait is bounded as the reads' is."""
        buses = self.reconnecting()
        if not buses:
            await robot.wait_frame(0)
            return
        async with task_group() as tasks:

            async def every_line_lost() -> None:
                while True:
                    for bus in buses.values():
                        if bus.state is State.CLOSED:
                            return  # (its state changes no more: the wait for the frame meets the closed bus)
                        if bus.state is not State.LOST:  # (changes only once that one is lost too)
                            await bus.state_change()
                            break
                    else:
                        await self._back(buses, "every line's port was lost")

            tasks.start_soon(every_line_lost)
            await robot.wait_frame(0)
            tasks.cancel_scope.cancel()

    async def _back(self, buses: Mapping[str, Bus], lost: str) -> None:
        if self.deadline is None:
            self.deadline = anyio.current_time() + LOST_AT_OPEN
        with anyio.move_on_after(self.deadline - anyio.current_time()):
            for bus in buses.values():
                while bus.state is State.LOST:
                    await bus.state_change()
            return
        away = ", ".join(f"line {name} ({bus.port})" for name, bus in buses.items() if bus.state is State.LOST)
        raise PortLost(
            f"{lost}, while the robot was opening: {away} not back within {LOST_AT_OPEN:g} s (with reconnect=True"
            " an open waits that long for a lost port; once open, the robot waits for it as long as it runs)"
        ) from None


def _on_line(exc: SerialPortError, source: str, line: str) -> SerialPortError:
    """``exc`` (a line's port that could not be opened) naming the robot file's line too: the port's own words
    do not say which line of the robot it is, and a robot has one adapter a line.  (A port missing with
    ``reconnect``: the bus's own words already say that reconnecting does not wait for it.)"""
    return exc.reworded(f"{source}: line {line}: {error_text(exc)}")


def _line_options(shared: BusOptions, line: LineSpec) -> BusOptions:
    return {
        **shared,
        "baudrate": line.baudrate,
        "echo": line.echo,
        "retries": line.retries,
        "direction": line.direction,
    }


def check_start_pose(
    description: RobotDescription, pose: Mapping[str, float] | None, *, named: str = "start_pose"
) -> dict[str, float]:
    """``pose`` checked against ``description`` as ``open_robot``'s ``start_pose`` (InvalidArgument naming it
    ``named``: a command line names its option, ``--start-pose``, as typed)."""
    if pose is None:
        return {}
    try:
        return description.check_pose(pose)
    except InvalidArgument as exc:
        raise InvalidArgument(f"{named}: {exc}") from None


async def _silent_to(
    robot: Robot, joints: Iterable[JointSpec], lines: _LineAnswers, ask: Callable[[JointSpec], Awaitable[object]]
) -> set[str]:
    """The joints whose servo answered ``ask`` nothing (ReplyTimeout): each line's joints asked in turn, the lines at
    once.  A garbled answer is an answer (something is there).  A line where nothing answers (``lines.empty``) has
    its joints left unasked from then on: the caller takes them as absent."""
    absent: set[str] = set()
    by_line: dict[str, list[JointSpec]] = {}
    for joint in joints:
        by_line.setdefault(joint.line, []).append(joint)

    async def ask_line(line: str) -> None:
        joints = by_line[line]
        for index, joint in enumerate(joints):
            if line in lines.empty:
                return
            try:
                await ask(joint)
            except ReplyTimeout:
                absent.add(joint.name)
                await lines.silent(line, len(joints) - index - 1)
                continue
            except ReplyError:  # garbled: something is there
                pass
            lines.answered(line)

    async with task_group() as tasks:
        for line in by_line:
            tasks.start_soon(ask_line, line)
    return absent


async def _position_reads(
    robot: Robot, joints: Iterable[JointSpec], silent: set[str], lines: _LineAnswers
) -> tuple[set[str], set[str]]:
    """The joints whose servo answers ICS 3.6's position read (probed without moving or freeing anything; one taken
    for ICS 3.5, whose joint starts free, read once more with the whole allowance: see
    :meth:`~ics35_async.Servo.read_position_once_more`), and those whose servo answered nothing
    (absent).  ``silent``: the joints whose EEPROM read just got no reply:
    one silent probe more says they are absent (an unplugged leg then costs its joints one allowance each, not
    three).  The joints of a line where nothing answers (``lines.empty``) are not probed.  A silent or garbled
    servo starts free, as ICS 3.5 does (a silent one offline too: see open_robot)."""
    found: set[str] = set()

    async def probe(joint: JointSpec) -> None:
        servo = robot.group[joint.line].servo(joint.id)
        # (A servo taken for ICS 3.5 starts free: read once more first, as before any free command.)
        if await servo.has_position_read(silent_before=joint.name in silent) or (
            await servo.read_position_once_more() is not None
        ):
            found.add(joint.name)

    absent = await _silent_to(robot, joints, lines, probe)
    return found, absent


async def _presence(
    robot: Robot, joints: Iterable[JointSpec], silent: set[str] | None, lines: _LineAnswers
) -> set[str]:
    """The joints whose servo answered nothing (absent), for ``start_free``: ``silent``, the joints whose EEPROM
    read just went unanswered (that read's silence says it: asking again would cost another allowance), or,
    without that read (``None``), those silent to one parameter read, which either protocol answers and which
    moves nothing.  The joints of a line where nothing answers (``lines.empty``) are not asked (the caller takes
    them as absent)."""
    if silent is not None:
        return {joint.name for joint in joints if joint.name in silent}
    return await _silent_to(robot, joints, lines, lambda joint: robot.group[joint.line].servo(joint.id).read_stretch())


# Joints left to ask on a line where nothing has answered, from which one ID read costs less than their silences.
_ASK_LINE_FROM = 2


class _LineAnswers:
    """What the open has heard on each line so far: a line where nothing answers is asked once as a whole (see
    :meth:`silent`) instead of each of its joints at its whole reply allowance."""

    def __init__(self, robot: Robot) -> None:
        self._robot = robot
        self.settled: set[str] = set()  # lines something answered on (garbled too), or asked as a whole already
        self.empty: set[str] = set()  # lines where nothing answered the ID read

    def answered(self, line: str) -> None:
        self.settled.add(line)

    async def silent(self, line: str, left: int) -> None:
        """A joint's read on ``line`` has just gone unanswered, with ``left`` of the line's joints still to ask.
        If nothing on the line has answered yet, one ID read (which every servo on the line answers, garbled
        when several do) asks whether anything is there at all; nothing: the line is ``empty``, and its joints
        are asked nothing more (two legs unplugged on their own line waited an allowance for each read of each
        of their joints, since a line where nothing has answered gives even a probe the whole allowance)."""
        if line in self.settled or left < _ASK_LINE_FROM:
            return
        self.settled.add(line)
        if not await anyone_there(self._robot.group[line]):
            self.empty.add(line)


warn_at_open: ContextVar[bool] = ContextVar("warn_at_open", default=True)
"""False where the opener issues the robot's warnings itself, from its caller's thread: the blocking
robot opens on a loop thread, whose stack holds no line of the program."""


async def check_servo_limits(robot: Robot) -> list[str]:
    """Warn (RobotWarning, and ``robot.warnings``) where a joint's limits exceed its servo's EEPROM pulse limits."""
    return (await _check_limits(robot, _LineAnswers(robot)))[0]


async def _check_limits(robot: Robot, lines: _LineAnswers) -> tuple[list[str], set[str]]:
    """:func:`check_servo_limits`'s warnings, and the joints whose servo sent no reply at all (ReplyTimeout); a
    line where nothing answers (``lines.empty``) has its joints after the first taken as silent, not read."""
    found: list[str] = []
    unanswered: set[str] = set()

    async def check_line(line: str) -> None:
        silent: list[JointSpec] = []
        why = ""
        joints = robot.description.joints_on(line)
        for index, joint in enumerate(joints):
            if line in lines.empty:  # (the line's silence to the ID read stands for theirs)
                silent.append(joint)
                unanswered.add(joint.name)
                continue
            try:
                eeprom = await robot.group[joint.line].servo(joint.id).read_eeprom()
            except ReplyError as exc:
                silent.append(joint)
                why = why or str(exc)
                if isinstance(exc, ReplyTimeout):  # (a garbled reply: something is there)
                    unanswered.add(joint.name)
                    await lines.silent(line, len(joints) - index - 1)
                else:
                    lines.answered(line)
                continue
            lines.answered(line)
            # A warning, not a refusal: opening moves nothing, and the servo clamps to its pulse limits anyway.
            message = limit_problem(robot.description.source, joint, eeprom)
            if message is not None:
                found.append(message)
        if silent:  # one message a line (a line with nothing answering said it once a joint)
            source = robot.description.source
            if len(silent) == 1:
                joint = silent[0]
                what = f"joints.{joint.name}: servo ID {joint.id} on line {line} did not answer as the robot opened"
            else:
                names = ", ".join(joint.name for joint in silent)
                ids = ", ".join(str(joint.id) for joint in silent)
                what = f"joints {names} (servo IDs {ids} on line {line}) did not answer as the robot opened"
                why = f"the first: {why}"
            found.append(f"{source}: {what} ({why}); limits not checked")

    async with task_group() as tasks:
        for line in robot.description.lines:
            tasks.start_soon(check_line, line)
    for message in found:
        robot.warnings.append(message)
        if warn_at_open.get():
            warn_program(message)
    return found, unanswered


def warn_program(message: str) -> None:
    """Issue ``message`` as a RobotWarning located at the program's line that opened the robot.

    The warning is issued deep inside ``open_robot`` (this package, contextlib's ``__aenter__``, the
    blocking layer): a fixed ``stacklevel`` would point into one of them.  Python 3.12's
    ``skip_file_prefixes`` does this walk; 3.11 does not have it."""
    skipped = (os.path.dirname(os.path.dirname(__file__)) + os.sep, contextlib.__file__)
    level, frame = 1, sys._getframe(0)  # stacklevel 1 is this function
    while frame.f_back is not None and frame.f_code.co_filename.startswith(skipped):
        level, frame = level + 1, frame.f_back
    warnings.warn(message, RobotWarning, stacklevel=level)


def limit_problem(source: str, joint: JointSpec, eeprom: Eeprom) -> str | None:
    """What is wrong, in words, when ``joint``'s limits reach past its servo's EEPROM pulse limits (the servo
    is never sent past them); None when they do not.  ``source`` names the robot file."""
    where = f"{source}: joints.{joint.name}"
    low, high = sorted((joint.position(joint.min), joint.position(joint.max)))
    if low >= eeprom.pulse_limit_low and high <= eeprom.pulse_limit_high:
        return None
    a, b = sorted((joint.degrees(eeprom.pulse_limit_low), joint.degrees(eeprom.pulse_limit_high)))
    return (
        f"{where}: the file allows {joint.min:g}..{joint.max:g} degrees, but servo ID {joint.id} on line "
        f"{joint.line} stops at {a:.1f}..{b:.1f} (EEPROM pulse limits {eeprom.pulse_limit_low}.."
        f"{eeprom.pulse_limit_high})"
    )
