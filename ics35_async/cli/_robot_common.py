"""What play, teach and calibrate share: the robot file checked first, running a robot command, lines typed
on stdin, and errors in a person's words.

The ports come from the robot file, so these commands do not use --port or
--baud; --timeout and --transport apply to every line of the robot.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import os
import shlex
import sys
import threading
import warnings
from collections.abc import Awaitable, Callable, Iterator
from typing import Any, TextIO, TypeVar

import click
from rich.markup import escape

from ..errors import (
    ClosedByPortLoss,
    IcsError,
    InvalidArgument,
    PortLost,
    PortNotFound,
    ReplyTimeout,
    SerialPortError,
    UnsafeOperation,
)
from ..robot import (
    DescriptionError,
    LineSpec,
    Motion,
    Robot,
    RobotBlock,
    RobotDescription,
    RobotWarning,
    SafetyStop,
    load_description,
    load_motion,
    open_robot,
)
from ..robot.description import check_not_a_port
from ..robot.motion import MotionError, check_motion
from ..transports.wire_device import is_url, url_scheme
from ._common import NO_REPLY_HINTS, CliError, ExitCode, Settings, check_input_path, run_loop, translate
from ._console import ids_argument, library_warnings_said, say_labelled
from ._paths import InputPathError

T = TypeVar("T")

SAFETY_HINTS = (
    "let the servo cool down, and check nothing blocks the joint (a stalled servo draws its full current)",
    "the thresholds are [safety] max_temperature_c and max_current in the robot file",
)


def _usage_error(exc: InvalidArgument, path: str, placeholder: str) -> CliError:
    # A robot file where the motion goes, or the other way round: the two given in the wrong order.
    wanted, other = (".toml", ".json") if placeholder.endswith(".toml") else (".json", ".toml")
    swapped = path.lower().endswith(other) and not path.lower().endswith(wanted)
    hints = ["the robot file (ROBOT.toml) comes first, then the motion (MOTION.json)"] if swapped else []
    return CliError(ExitCode.USAGE, f"{exc} (nothing was sent)", *hints)


def load_input_file(path: str, placeholder: str, load: Callable[[str], T]) -> T:
    """``load(path)`` of a checked input file; one that breaks its format (a FileContentError, which
    names the file and key) is a usage error (exit code 2)."""
    check_input_path(path, placeholder)
    try:
        return load(path)
    except InvalidArgument as exc:
        raise _usage_error(exc, path, placeholder) from None


def load_robot_file(path: str) -> RobotDescription:
    """The checked description, or a usage error (exit code 2) naming the file and key.  A port given for the
    file (``sim://x``, ``/dev/ttyUSB0``) is said as one, before the checks of a file's path would call it missing."""
    try:
        check_not_a_port(path)
    except DescriptionError as exc:
        raise _usage_error(exc, path, "ROBOT.toml") from None
    return load_input_file(path, "ROBOT.toml", load_description)


# What can be wrong with a motion file given to a robot command, in the order ``ics35 check`` sums them up.
MOTION_FILE_PROBLEMS = ("not found", "not readable", "not a motion file", "does not fit")


class MotionFileError(CliError):
    """A motion file refused before any port opens (exit code 2); ``problem`` is which of
    :data:`MOTION_FILE_PROBLEMS`: no file at the path, one that cannot be read, not a motion (not JSON, or
    breaking the format), or a motion the robot cannot play (a joint it lacks, an angle beyond a limit)."""

    def __init__(self, problem: str, error: CliError) -> None:
        super().__init__(error.code, error.message, *error.hints)
        self.problem = problem


def load_motion_file(path: str, description: RobotDescription) -> Motion:
    """The motion, checked against the robot's joints and limits before any port opens (a robot that
    starts frees its joints), or a :class:`MotionFileError` (exit code 2) naming the file, and the key."""
    try:
        motion = load_input_file(path, "MOTION.json", load_motion)
    except InputPathError as exc:
        raise MotionFileError("not found" if exc.missing else "not readable", exc) from None
    except CliError as exc:
        raise MotionFileError("not a motion file", exc) from None
    try:
        check_motion(description, motion, path)
        if not motion.joints:  # (one taught with every servo silent): play would open no joint, and play nothing
            raise MotionError(path, "", "the motion moves no joint (every keyframe's pose is empty): nothing to play")
    except InvalidArgument as exc:
        raise MotionFileError("does not fit", _usage_error(exc, path, "MOTION.json")) from None
    return motion


def chosen_joints(description: RobotDescription, text: str | None) -> list[str]:
    if text is None:
        return list(description.joints)
    names = [n.strip() for n in text.split(",") if n.strip()]
    if not names:
        raise CliError(
            ExitCode.USAGE, "--joints: no joint named (nothing was sent)", f"joints: {', '.join(description.joints)}"
        )
    try:
        return description.known_joints(names)
    except InvalidArgument as exc:
        raise CliError(ExitCode.USAGE, f"--joints: {exc} (nothing was sent)") from None


joints_option = click.option(
    "--joints",
    default=None,
    help="Comma-separated joint names (default: every joint); the others are not opened: not read, freed, "
    "commanded or watched by the file's [safety].",
)


def robot_options(settings: Settings) -> dict[str, Any]:
    """open_robot options from the line options that apply to every line of a robot."""
    return {"adapter_latency": settings.timeout, "transport": settings.transport}


def note_ports(settings: Settings, robot_file: str) -> None:
    """Name the line options given that the robot file decides (see :func:`robot_options` for those that apply):
    each line's port, baud rate, echo, retries and a DIY interface's direction control are the file's.  Left unsaid,
    a --direction meant for a DIY interface would be dropped without a word."""
    # (a value the environment set is named as its variable: --baud was not typed)
    env = {v.split("=", 1)[0] for v in settings.from_environment}
    unused = [
        option
        for option, given in (
            ("ICS35_PORT" if "ICS35_PORT" in env else "--port", not settings.port_defaulted),
            ("ICS35_BAUD" if "ICS35_BAUD" in env else "--baud", "baud" in settings.given),  # (whatever its value)
            ("--retries", "retries" in settings.given),
            ("--no-echo", not settings.echo),
            ("--direction", "direction" in settings.given),
        )
        if given
    ]
    if unused:
        names = ", ".join(unused[:-1]) + f" and {unused[-1]}" if len(unused) > 1 else unused[0]
        verb = "are" if len(unused) > 1 else "is"
        say_labelled(
            "[dim]note:[/dim]", f"[dim]the lines come from {escape(robot_file)}; {names} {verb} not used[/dim]"
        )


def left_after_trip(exc: SafetyStop, left: str | None) -> str:
    """What the joints the command opened were left in by the trip's action (and then, on ``left == "free"``,
    by the command's own free as it closed): a bare "action: stop" read as if the robot had stopped and held."""
    # A servo that went offline hears no command: not the free either, so it may still hold.
    unheard = "silent servo may not have heard it (its torque may still be on)"
    offline = exc.reason == "offline"
    among = f", but joint {exc.joint}'s {unheard}" if offline else ""  # (the joint named here first)
    if left == "free":
        return f"the command then freed every joint it opened (--on-stop free){among}"
    if exc.action == "stop":
        return (
            f'action = "stop": every joint it opened was freed (torque off: a standing robot falls){among}; '
            '[safety] action = "hold" keeps every joint at its last target instead'
        )
    if exc.action == "free":
        return (
            f'action = "free": joint {exc.joint} was freed{f", but its {unheard}" if offline else ""}; the others '
            "keep their last targets (a free one stays free)"
        )
    return 'action = "hold": every joint it opened keeps its last target (a free one stays free)'


def safety_error(exc: SafetyStop, left: str | None = None) -> CliError:
    """The error of a safety stop; ``left``: what the command leaves its joints in as it closes (its on_close)."""
    if exc.reason == "offline":
        return CliError(
            ExitCode.SAFETY_STOP,
            f"safety stop: {exc}",
            left_after_trip(exc, left),
            *NO_REPLY_HINTS[:2],
            "to carry on without it: [safety] continue_on_offline = true",
        )
    return CliError(ExitCode.SAFETY_STOP, f"safety stop: {exc}", left_after_trip(exc, left), *SAFETY_HINTS)


def show_warnings(robot: Robot) -> None:
    for warning in robot.warnings:
        say_labelled("[yellow]warning:[/yellow]", escape(warning))


async def first_pose(robot: Robot) -> dict[str, float]:
    """The pose after open; a robot whose servos all stay silent is exit code 4."""
    pose = await robot.read_pose()
    if not pose:
        specs = robot.description.lines.values()
        lines = ", ".join(f"{line.name} ({line.port})" for line in specs)
        # The scan of each silent line, and the rate the file has it talk at: a servo at another rate (a factory
        # 115200 on a line set to the HS adapter's 1250000) is the first day's most likely silence.
        scans = [
            f"check the wiring and the servo IDs: {_scan_command(line)} tries every ID at every baud rate "
            f"(line {line.name} talks at {line.baudrate} baud, the robot file's baudrate)"
            for line in specs
        ]
        power, _wiring, pwm_mode = NO_REPLY_HINTS  # (the wiring hint's general scan: each line's own above)
        raise CliError(ExitCode.NO_REPLY, f"no joint's servo answered on line(s) {lines}", power, *scans, pwm_mode)
    return pose


def _scan_command(line: LineSpec) -> str:
    """``ics35 scan`` on ``line``'s port as the robot file has it reached (its echo and direction control), quoted
    for a shell (a ``sim://`` URL's ``?`` and ``&``)."""
    reach = ([] if line.echo else ["--no-echo"]) + ([] if line.direction == "none" else ["--direction", line.direction])
    return shlex.join(["ics35", "--port", line.port, *reach, "scan"])


@contextlib.contextmanager
def _sim_lines_of(description: RobotDescription) -> Iterator[None]:
    """Simulated lines the robot file names live for this command only (unless they existed before it)."""
    named = [line.port for line in description.lines.values() if url_scheme(line.port) == "sim"]
    if not named:
        yield
        return
    from .. import sim

    names = set()
    for port in named:
        # A URL the simulator refuses as written is left to the open, which says so naming the robot file's line.
        with contextlib.suppress(InvalidArgument):
            names.add(sim.parse_url(port)[0])
    names -= {None}
    before = set()
    for name in names:
        with contextlib.suppress(KeyError):
            sim.named(str(name))
            before.add(name)
    try:
        yield
    finally:
        for name in names - before:
            with contextlib.suppress(KeyError):
                sim.named(str(name)).close()


def _line_of(description: RobotDescription, exc: IcsError) -> LineSpec | None:
    """The line whose port ``exc`` names, if one."""
    lines = [line for line in description.lines.values() if line.port in str(exc)]
    return max(lines, key=lambda spec: len(spec.port)) if lines else None  # (one port's name may start another's)


def _not_there(port: str) -> bool:
    """Whether ``port`` is a device path with nothing at it (an adapter not plugged in), as known without opening
    it; a URL, or a name that is no path (``COM3``), is not known to be missing."""
    return not is_url(port) and os.path.isabs(port) and not os.path.exists(port)


def other_lines_hint(description: RobotDescription, exc: IcsError) -> list[str]:
    """For a line whose port could not be opened: the robot's other lines whose device path is not there either
    (a file given its adapters' names before they were plugged in), and the ``--joints`` that opens the rest of
    them meanwhile (one offering the joints of a line whose port is missing too would fail the same way)."""
    line = _line_of(description, exc)
    if line is None:
        return []
    gone = [spec.name for spec in description.lines.values() if spec.name != line.name and _not_there(spec.port)]
    either = " either" if isinstance(exc, PortNotFound) else ""  # (not for a port busy, refused or not a tty)
    hints = [f"the port of line {name}, {description.lines[name].port}, is not there{either}" for name in gone]
    others = [name for name, joint in description.joints.items() if joint.line not in (line.name, *gone)]
    if others:
        where = "the other line" if len(description.lines) == 2 else "the other lines"
        if gone:
            still = sorted({description.joints[name].line for name in others})
            where = f"line{'s' if len(still) > 1 else ''} {', '.join(still)}"
        hints.append(f"--joints can open only the joints on {where} meanwhile: --joints {','.join(others)}")
    return hints


def lost_line_hint(
    settings: Settings,
    description: RobotDescription,
    exc: IcsError,
    others_left: str | None,
    opening_left: str | None = None,
    holding: Callable[[str], list[str] | None] | None = None,
) -> str:
    """What the servos of the line whose port ``exc`` reports lost do now, and the command that frees them
    (that line's port, baud rate, echo and direction control: the robot file's; ``others_left``: what the
    command left the other lines' joints in, when it has several; ``opening_left``: what the open left every
    joint in, when the port was lost as the robot opened: the command had done nothing with them yet;
    ``holding``: the joints of a line that may hold something when it went, None where that is not known)."""
    line = _line_of(description, exc)
    others = f"; the other lines' joints were left {others_left}" if others_left and len(description.lines) > 1 else ""
    if opening_left is not None:
        others = f"; the port was lost as the robot opened: {opening_left}"
    held = None if line is None or holding is None or opening_left is not None else holding(line.name)
    if held == [] and line is not None:  # (all of them free: calibrate's, teach's; nothing to free)
        names = [j.name for j in description.joints_on(line.name)]
        one = len(names) == 1
        named = f"joint {names[0]} on the lost line was" if one else f"joints {', '.join(names)} on the lost line were"
        return f"{named} free when the line went: nothing holds {'it' if one else 'them'}{others}"
    free = "ics35 free all -p PORT"
    if line is not None:
        here = dataclasses.replace(
            settings,
            port=line.port,
            baud=line.baudrate,
            echo=line.echo,
            direction=line.direction,
            port_defaulted=False,
        )
        # Its joints' IDs, not "all": the 32 IDs' absent ones would end it "did not go free", exit code 4.
        free = here.command_line("free", ids_argument(j.id for j in description.joints_on(line.name)))
    return (
        "the servos on the lost line keep their last command (a holding joint stays stiff) until they lose"
        f" power or, with the line back, get: {free}{others}"
    )


class Opening:
    """The robot a command opens, until it has its first pose: a Ctrl-C before then is told with what the open
    left the joints in (the library's account: some may have gone limp to be read, others not sent anything)."""

    def __init__(self) -> None:
        self._block: RobotBlock | None = None
        self._over = False

    def open(self, description: RobotDescription, **options: Any) -> RobotBlock:
        self._block = open_robot(description, **options)
        return self._block

    def over(self) -> None:
        """The command has its robot's first pose: what it leaves from now on is its own to say."""
        self._over = True

    def joints_left(self) -> str | None:
        """What the open left the joints in, if the command was still opening its robot; else None."""
        return None if self._over or self._block is None else self._block.joints_left()

    def holding_on(self, line: str) -> list[str] | None:
        """The joints of ``line`` whose servos may hold something: a target, or torque as found (only read, or
        offline: not known); None before the robot had its lines."""
        robot = None if self._block is None else self._block.robot
        if robot is None:
            return None
        targets, uncommanded = robot.targets, robot.uncommanded
        joints = [j.name for j in robot.description.joints_on(line)]
        return [j for j in joints if targets[j] is not None or j in uncommanded]


def run_robot(
    settings: Settings,
    description: RobotDescription,
    make: Callable[[], Awaitable[T]],
    *,
    others_left: str | None = None,
    opening: Opening | None = None,
) -> T:
    """Run a robot command's coroutine; every expected failure becomes a :class:`CliError`.  ``others_left``:
    what the robot leaves the joints of lines still there in when one is lost (its ``on_close``); ``opening``:
    the robot the coroutine opens (see :class:`Opening`)."""
    # (the safety watch's warning of a guarded joint whose telemetry does not read: the trips are said as errors)
    with _sim_lines_of(description), warnings.catch_warnings(), library_warnings_said("safety"):
        # The command prints robot.warnings itself, once, in its own words.
        warnings.simplefilter("ignore", RobotWarning)
        try:
            return run_loop(make)
        except KeyboardInterrupt:
            left = opening.joints_left() if opening is not None else None
            if left is not None:
                raise CliError(ExitCode.INTERRUPTED, f"interrupted while opening the robot: {left}") from None
            raise CliError(ExitCode.INTERRUPTED, "interrupted") from None
        except SafetyStop as exc:
            raise safety_error(exc, others_left) from None
        except ReplyTimeout as exc:
            raise CliError(ExitCode.NO_REPLY, str(exc), *NO_REPLY_HINTS) from None
        except UnsafeOperation as exc:
            # The robot's refusal (a joint whose servo never answered, driven blind), not a mistake in the command.
            # The robot was open by then (its ICS 3.5 joints freed to be read): not "nothing was sent".
            raise CliError(ExitCode.REFUSED, f"{exc} (no motion was started)") from None
        except InvalidArgument as exc:
            raise CliError(ExitCode.USAGE, f"{exc} (nothing was sent)") from None
        except (PortLost, ClosedByPortLoss) as exc:
            error = translate(settings, exc)
            # Lost before the command had its robot: what others_left says of a running command is not so yet.
            opened = opening.joints_left() if opening is not None else None
            holding = None if opening is None else opening.holding_on
            error.hints.append(lost_line_hint(settings, description, exc, others_left, opened, holding))
            raise error from None
        except SerialPortError as exc:
            error = translate(settings, exc)
            error.hints.extend(other_lines_hint(description, exc))
            raise error from None
        except IcsError as exc:
            raise translate(settings, exc) from None
        except BrokenPipeError:
            raise
        except OSError as exc:
            raise CliError(ExitCode.COMMUNICATION, str(exc)) from None


def _discard_typed_ahead(stdin: TextIO) -> None:
    """Drop what was typed at a terminal before the lines are asked for: an Enter pressed while the robot opened
    (an unplugged servo makes that last a few --timeouts) would be the first answer, teach capturing a pose the
    hands had not set, calibrate taking it as the neutral.  Input from a file or a pipe is kept: written ahead."""
    with contextlib.suppress(ImportError, OSError, ValueError):
        import termios  # (not on Windows)

        if stdin.isatty():
            termios.tcflush(stdin.fileno(), termios.TCIFLUSH)


class TypedLines:
    """Lines typed on stdin, read by a daemon thread (a blocked read must not keep the process alive)."""

    def __init__(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._queue: asyncio.Queue[str | None] = asyncio.Queue()
        self._stdin = sys.stdin
        _discard_typed_ahead(self._stdin)
        threading.Thread(target=self._read, name="ics35 stdin", daemon=True).start()

    def _read(self) -> None:
        try:
            while True:
                line = self._stdin.readline()
                self._put(line if line else None)
                if not line:
                    return
        except (OSError, ValueError, RuntimeError):
            with contextlib.suppress(RuntimeError):
                self._put(None)

    def _put(self, line: str | None) -> None:
        with contextlib.suppress(RuntimeError):  # the loop has closed: nobody is listening any more
            self._loop.call_soon_threadsafe(self._queue.put_nowait, line)

    async def get(self) -> str | None:
        """The next line (without its newline), or None at the end of input."""
        line = await self._queue.get()
        if line is None:
            self._queue.put_nowait(None)  # every later call sees the end too
            return None
        return line.rstrip("\r\n")
