"""The blocking robot: :func:`ics35_async.open_robot` held open by one task on a loop thread.

The async ``open_robot`` is a context manager holding task groups (the pump,
the safety watch, every line's stream), and a task group must end in the
task that began it.  So one *holder* task on the loop thread enters it,
hands the :class:`~ics35_async.Robot` back, waits for the close event and
leaves it; every blocking call is a separate hop onto that loop.

Ctrl-C during a blocking call cancels the call on the loop (a cancelled
motion leaves its joints at their last target), then closes the robot the
way :meth:`BlockingRobot.close` does (``on_close``: hold or free) and ends
the thread, before the ``KeyboardInterrupt`` goes on.
"""

from __future__ import annotations

import asyncio
import contextlib
import copy
from collections.abc import Awaitable, Callable, Iterable, Mapping
from pathlib import Path
from typing import Any, ParamSpec, TypeVar, Unpack, overload

from .. import units
from ..robot import JointSpec, Motion, Robot, RobotDescription, RobotFrame, RobotOptions, SafetyStop, Trajectory
from ..robot import open_robot as open_async_robot
from ..robot.safety import JointTelemetry
from ..robot.startup import warn_at_open, warn_program
from ..running import check_async_function, close_step
from .loop_thread import LoopThread, awaited, within
from .owner import LoopOwner

P = ParamSpec("P")
T = TypeVar("T")


class _Holder:
    """The task on the loop that keeps ``open_robot`` entered until asked to close (lives on the loop thread)."""

    def __init__(self, opener: contextlib.AbstractAsyncContextManager[Robot]) -> None:
        self._opener = opener
        self.ready: asyncio.Future[Robot] | None = None
        self.closing: asyncio.Event | None = None
        self.task: asyncio.Task[None] | None = None
        self.exit_error: BaseException | None = None

    async def _hold(self, ready: asyncio.Future[Robot], closing: asyncio.Event) -> None:
        warn_at_open.set(False)  # this task's own context: BlockingRobot warns from the program's thread
        try:
            async with self._opener as robot:
                ready.set_result(robot)
                await closing.wait()
        except asyncio.CancelledError:
            if not ready.done():
                ready.cancel()
            raise
        except BaseException as exc:  # kept for the caller, not left unretrieved on the task
            if ready.done():
                self.exit_error = exc
            else:
                ready.set_exception(exc)

    async def open(self) -> Robot:
        """Start the holder; return its robot once open (cancelled: the holder is cancelled and awaited)."""
        self.ready = asyncio.get_running_loop().create_future()
        self.closing = asyncio.Event()
        self.task = asyncio.create_task(self._hold(self.ready, self.closing))
        try:
            return await asyncio.shield(self.ready)
        except asyncio.CancelledError:
            self.task.cancel()
            await asyncio.wait([self.task])
            raise

    async def close(self) -> None:
        """Ask the holder to leave ``open_robot`` (the robot's on_close action runs there) and wait for it."""
        if self.task is None or self.closing is None:
            return
        self.closing.set()
        await asyncio.wait([self.task])
        error, self.exit_error = self.exit_error, None
        if error is not None:
            raise error


class BlockingRobot(LoopOwner[Robot]):
    """A robot for code without an event loop.  Create with :func:`open_robot`.

    Motions (:meth:`move_to`, :meth:`play`, :meth:`stop`) and :meth:`read_pose`
    block until done; :meth:`set_targets` and :meth:`hold` take effect before
    they return.  Properties are snapshots taken on the loop thread.  Errors
    are the async robot's own typed errors (:class:`~ics35_async.InvalidArgument`,
    :class:`~ics35_async.robot.SafetyStop`, ...), raised in the calling thread.

    Args:
        opener: the async robot's opener (what ``ics35_async.open_robot(...)`` returns), entered on the loop thread.
        name: the loop thread's name.
    """

    __slots__ = ("_holder",)
    _usage = (
        "a blocking robot is used with `with blocking.open_robot(...) as robot:` (this one is closed now); in"
        " async code, `async with ics35_async.open_robot(...) as robot:`"
    )

    def __init__(self, opener: contextlib.AbstractAsyncContextManager[Robot], name: str = "robot") -> None:
        loop = LoopThread(name=f"ics35 blocking robot {name}", what="robot")
        holder = _Holder(opener)
        self._holder = holder
        self._own(loop, holder.close, "blocking robot")
        try:
            robot = loop.call(holder.open)
        except BaseException:
            self._finalizer.detach()
            loop.stop()
            raise
        super().__init__(robot, loop)
        for message in self.warnings:
            warn_program(message)

    # ------------------------------------------------------------------ closing

    @close_step
    def close(self) -> None:
        """Leave the robot as ``on_close`` says (hold or free), close every line, end the loop thread.

        Idempotent.  A Ctrl-C while closing is raised once everything is released.
        """
        super().close()

    @property
    def is_open(self) -> bool:
        """True while the robot's loop thread runs (until ``close()``)."""
        return self._loop.is_running

    @property
    def async_robot(self) -> Robot:
        """The async robot underneath (use it only from code running on the robot's loop, e.g. via :meth:`run`)."""
        return self._async

    def __repr__(self) -> str:
        return f"<BlockingRobot {self._async!r}>"

    @overload
    def run(self, fn: Trajectory, /) -> frozenset[str]: ...

    @overload
    def run(self, fn: Callable[P, Awaitable[T]], /, *args: P.args, **kwargs: P.kwargs) -> T: ...

    def run(self, fn: Any, /, *args: Any, **kwargs: Any) -> Any:
        """Await ``fn(*args, **kwargs)`` on the robot's loop; Ctrl-C cancels it and closes the robot.

        ``robot.run(trajectory)`` plays a :class:`~ics35_async.robot.Trajectory` as :meth:`Robot.run` does (its
        checks first, nothing sent if one fails) and returns the joints it drove to the end.

        Raises:
            InvalidArgument: ``fn`` is a coroutine (``robot.run(fn(*args))``: pass ``fn`` and its arguments) or
                not callable, or its call gave nothing to await (a plain ``def``: said once that call has returned);
                or a trajectory that does not fit the robot (see :meth:`Robot.run`).
        """
        if isinstance(fn, Trajectory) and not args and not kwargs:
            # (Robot.run's own call, as the async robot's documentation shows it)
            return self.run(self._async.run, fn)
        check_async_function(fn, "robot.run", with_args=True)
        try:
            return self._loop.call(awaited, "robot.run", fn, *args, **kwargs)
        except KeyboardInterrupt:
            self._loop.closed_because = "a Ctrl-C during a call closed it"
            self.close()
            raise

    # ------------------------------------------------------------------ blocking calls

    def read_pose(self) -> dict[str, float]:
        """Every joint's angle in degrees, as read after this call (see :meth:`Robot.read_pose`)."""
        return self.run(self._async.read_pose)

    def move_to(self, pose: Mapping[str, float], duration: float = 1.0, profile: str = "minjerk") -> None:
        """Move the named joints to ``pose`` in ``duration`` seconds; returns when the goal is on the wire.

        ``profile``: ``"minjerk"`` or ``"linear"``.

        Raises:
            InvalidArgument: an unknown joint, an angle outside its limits, a bad duration or profile.
            SafetyStop: the safety watch stopped the motion.
        """
        self.run(self._async.move_to, pose, duration, profile)

    def play(self, motion: Motion | str | Path | Mapping[str, Any], *, speed: float = 1.0, loop: bool = False) -> None:
        """Play a motion (object, JSON file path or mapping) at ``speed`` (2: twice as fast); ``loop``: until Ctrl-C.

        Raises:
            MotionError: the motion file breaks its format.
            InvalidArgument: an unknown joint, an angle outside its limits or a bad ``speed``.
            SafetyStop: the safety watch stopped the motion.
        """
        self.run(self._async.play, motion, speed=speed, loop=loop)

    def free(self, joints: Iterable[str] | None = None) -> None:
        """Torque off for ``joints`` (default: all); returns once that has gone out on the wire."""
        self.run(self._async.free, joints)

    def stop(self, ramp: float = 0.3) -> None:
        """End every motion smoothly over ``ramp`` seconds, then hold."""
        self.run(self._async.stop, ramp)

    def on_wire(self, joints: Iterable[str] | None = None) -> None:
        """Wait until the targets set so far have gone out to ``joints`` (default: all)."""
        self.run(self._async.on_wire, joints)

    def line_change(self, lost: Iterable[str] | None = None, timeout: float | None = None) -> frozenset[str]:
        """Wait until the lines whose port is lost (:attr:`lost_lines`) are others than ``lost`` (default: those
        lost now), at most ``timeout`` seconds (then ``TimeoutError``), and return the lines lost then: a line
        lost (``reconnect=True``: as soon as its bus knows) or back (at the frame whose ``resumed`` names it,
        its joints held).  See ``Robot.line_change``; a program that stops when a line goes::

            lost = robot.line_change(())  # returns once a line is lost
            while lost:
                lost = robot.line_change(lost)  # every line back: an empty set

        Raises:
            InvalidArgument: ``lost`` is not line names or names a line the robot does not have, or a bad
                ``timeout``.
            BusClosed, PortLost: the robot is closed, or a line is gone (without ``reconnect``).
        """
        if timeout is not None:
            units.check_seconds("timeout", timeout, 0.0, 1e9)
        return self.run(within, timeout, "line lost or back", self._async.line_change, lost)

    # ------------------------------------------------------------------ plain calls, run on the loop thread

    def hold(self, joints: Iterable[str] | None = None) -> dict[str, str]:
        """Hold ``joints`` (default: all but the tripped and the held ones) where they are now, torque on; returns
        those left out and why (see ``Robot.hold``: one on a lost line, a held joint, one not read yet, a free one
        past a limit).

        Raises:
            SafetyStop: ``joints`` names a tripped joint (see ``Robot.hold``).
            PortLost: a line was lost (without ``reconnect``): nothing applied (see ``Robot.set_targets``).
        """
        return self._loop.call_sync(self._async.hold, joints)

    def set_targets(
        self, pose: Mapping[str, float | None], *, allow_free: bool = False, lift_holds: bool = True
    ) -> None:
        """Targets ``pose`` ``{joint: degrees}``, all checked first (``None`` frees, with ``allow_free``);
        ``lift_holds=False``: a held joint stays held (see ``Robot.set_targets``, :attr:`held`).

        Raises:
            InvalidArgument: an unknown joint, an angle outside its limits or a ``None`` without ``allow_free``.
            SafetyStop: an angle for a tripped joint (see ``Robot.set_targets``).
            PortLost: an angle after a line was lost (without ``reconnect``), or, with it, for a joint on a line
                lost now and ``lift_holds`` true: nothing applied, freeing is allowed (see ``Robot.set_targets``).
        """
        self._loop.call_sync(self._async.set_targets, pose, allow_free=allow_free, lift_holds=lift_holds)

    def reset_trip(self, joint: str) -> None:
        """Clear ``joint``'s safety trip once the program has dealt with its cause (see ``Robot.reset_trip``:
        a current trip of a joint the watch freed stands until this call).

        Raises:
            InvalidArgument: an unknown joint.
        """
        self._loop.call_sync(self._async.reset_trip, joint)

    # ------------------------------------------------------------------ snapshots

    @property
    def description(self) -> RobotDescription:
        """The checked robot description (lines, joints, safety); immutable."""
        return self._async.description  # immutable

    @property
    def joints(self) -> dict[str, JointSpec]:
        """Joint name -> its ``JointSpec`` (line, ID, offset, reverse, limits)."""
        return self._loop.read(_joints_of, self._async)

    @property
    def targets(self) -> dict[str, float | None]:
        """Every joint's target in degrees (``None``: free)."""
        return self._loop.read(_targets_of, self._async)

    @property
    def telemetry(self) -> dict[str, JointTelemetry]:
        """The newest temperature and current of every joint."""
        return self._loop.read(_telemetry_of, self._async)

    @property
    def positions(self) -> dict[str, float]:
        """Where each joint was last read, in degrees: its newest reading that agrees with the one before it (see
        ``Robot.positions``; the frames' ``positions`` are the replies as they came)."""
        return self._loop.read(_positions_of, self._async)

    @property
    def untouched(self) -> frozenset[str]:
        """The ICS 3.6 joints not commanded since the robot opened: their torque is as it was found (see
        ``Robot.untouched``)."""
        return self._loop.read(_untouched_of, self._async)

    @property
    def unreached(self) -> frozenset[str]:
        """The joints whose servo is offline as of the newest frame, sent nothing: a view shows no target or
        readings for them (see ``Robot.unreached``)."""
        return self._loop.read(_unreached_of, self._async)

    @property
    def uncommanded(self) -> frozenset[str]:
        """The joints no target of the program's reaches now, only read or offline: a view shows "-" for their
        target (see ``Robot.uncommanded``)."""
        return self._loop.read(_uncommanded_of, self._async)

    @property
    def tripped(self) -> dict[str, SafetyStop]:
        """Joints whose safety stop still stands (see ``Robot.tripped``; :meth:`reset_trip`)."""
        return self._loop.read(_tripped_of, self._async)

    @property
    def held(self) -> dict[str, str]:
        """Joints their streams hold now, sent nothing until a target is set, and why (see ``Robot.held``)."""
        return self._loop.read(_held_of, self._async)

    @property
    def lost(self) -> frozenset[str]:
        """Joints on a line whose port is lost now (``reconnect=True``), until the frame whose ``resumed`` names
        the line back (see ``Robot.lost``)."""
        return self._loop.read(_lost_of, self._async)

    @property
    def lost_lines(self) -> frozenset[str]:
        """The lines whose port is lost now: the lines of :attr:`lost`'s joints (see ``Robot.lost_lines``);
        :meth:`line_change` waits for it to change."""
        return self._loop.read(_lost_lines_of, self._async)

    @property
    def warnings(self) -> list[str]:
        """What opening found worth knowing (e.g. limits wider than a servo's EEPROM limits)."""
        return self._loop.read(_warnings_of, self._async)

    @property
    def start_modes(self) -> dict[str, str]:
        """How each joint started: ``"read"`` (ICS 3.6), ``"stated"`` (start_pose) or ``"free"``."""
        return self._loop.read(_start_modes_of, self._async)

    @property
    def latest(self) -> RobotFrame | None:
        """The newest frame (immutable)."""
        return self._loop.read(_latest_of, self._async)


def _joints_of(robot: Robot) -> dict[str, JointSpec]:
    return dict(robot.joints)


def _targets_of(robot: Robot) -> dict[str, float | None]:
    return robot.targets


def _telemetry_of(robot: Robot) -> dict[str, JointTelemetry]:
    return {name: copy.copy(seen) for name, seen in robot.telemetry.items()}


def _positions_of(robot: Robot) -> dict[str, float]:
    return robot.positions


def _untouched_of(robot: Robot) -> frozenset[str]:
    return frozenset(robot.untouched)


def _unreached_of(robot: Robot) -> frozenset[str]:
    return robot.unreached


def _uncommanded_of(robot: Robot) -> frozenset[str]:
    return robot.uncommanded


def _tripped_of(robot: Robot) -> dict[str, SafetyStop]:
    return robot.tripped


def _held_of(robot: Robot) -> dict[str, str]:
    return robot.held


def _lost_of(robot: Robot) -> frozenset[str]:
    return robot.lost


def _lost_lines_of(robot: Robot) -> frozenset[str]:
    return robot.lost_lines


def _warnings_of(robot: Robot) -> list[str]:
    return list(robot.warnings)


def _start_modes_of(robot: Robot) -> dict[str, str]:
    return dict(robot.start_modes)


def _latest_of(robot: Robot) -> RobotFrame | None:
    return robot.latest


def open_robot(
    source: str | Path | Mapping[str, Any] | RobotDescription, **options: Unpack[RobotOptions]
) -> BlockingRobot:
    """A [`BlockingRobot`][ics35_async.blocking.BlockingRobot]: ``with blocking.open_robot("robot.toml") as robot:``.

    Takes what [`ics35_async.open_robot`][ics35_async.robot.open_robot] takes.  The robot is open and
    streaming when this returns; leaving the ``with`` block, an exception or Ctrl-C included,
    closes it as ``on_close`` says and ends its loop thread.

    Args:
        source: a TOML file's path, the same structure as a mapping, or a
            [`RobotDescription`][ics35_async.robot.RobotDescription].
        **options: the robot's options and every line's bus options, each described in
            [`RobotOptions`][ics35_async.robot.RobotOptions].

    Raises:
        DescriptionError: the description is not valid (nothing is opened); or ``source`` is a port, not a file
            (``"sim://arm"``, ``"/dev/ttyUSB0"``): a robot's ports go in its file, one a line.
        InvalidArgument: an unknown or bad option (see [`ics35_async.open_robot`][ics35_async.robot.open_robot]).
        SerialPortError: a line's port cannot be opened.
    """
    opener = open_async_robot(source, **options)
    if isinstance(source, RobotDescription):
        name = source.name or str(source.source)
    else:
        name = str(source) if isinstance(source, str | Path) else "from a mapping"
    return BlockingRobot(opener, name)
