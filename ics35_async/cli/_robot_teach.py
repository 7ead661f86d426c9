"""ics35 teach (poses by hand -> a motion file) and ics35 calibrate (neutral and range by hand -> the robot file).

Both free the joints, show them live, and wait for Enter on stdin (read by a
daemon thread, so Ctrl-C and the end of input always get through).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import time
from collections.abc import AsyncIterator, Awaitable
from dataclasses import dataclass
from pathlib import Path

import click
from rich.markup import escape
from rich.table import Table

from ..eeprom import Eeprom
from ..errors import IcsError, ReplyError, error_text
from ..robot import PROFILES, Keyframe, Motion, Robot, RobotDescription, RobotFrame, UnsettledReadings, save_motion
from ..robot.calibration import (
    MIN_RANGE_DEGREES,
    NarrowRange,
    beyond_limits,
    calibrate_joint,
    calibrated_limits,
    count_angle,
    reverse_note,
    write_calibration,
)
from ..robot.description import COUNT_DECIMALS, JointSpec
from ..robot.profiles import LONGEST_MOTION
from ..robot.startup import limit_problem
from ..transports.wire_device import url_scheme
from ._common import (
    CliError,
    ExitCode,
    Settings,
    check_backup_path,
    check_output_path,
    choice_option,
    confirm,
    out,
    seconds_option,
    settings_of,
    yes_option,
)
from ._console import TitleInParts, say, say_labelled, signed_tenths
from ._robot_common import (
    Opening,
    TypedLines,
    chosen_joints,
    first_pose,
    joints_option,
    load_robot_file,
    note_ports,
    robot_options,
    run_robot,
    show_warnings,
)
from ._robot_view import Screen, joint_table
from ._signals import nothing_left_to_cut_short

QUIT = ("q", "quit", "exit")


@contextlib.asynccontextmanager
async def freed_robot(
    description: RobotDescription, settings: Settings, names: list[str], opening: Opening
) -> AsyncIterator[Robot]:
    """The robot's joints ``names`` open (freed again when it closes), their first pose read, free to move by
    hand.  The other joints are not opened: not read, freed or commanded, their servos keep what they hold."""
    options = robot_options(settings)
    async with opening.open(description.only(names), on_close="free", start_free=True, **options) as robot:
        show_warnings(robot)
        await first_pose(robot)
        await robot.free(names)
        opening.over()
        yield robot


def ask_before_freeing_all(description: RobotDescription, robot_file: str, joints: str | None, yes: bool) -> None:
    """Without ``--joints`` every joint goes free at once: a humanoid standing on them falls while an arm's wave
    is taught or a knee calibrated.  On a serial line (not the simulator) ask first; ``--yes`` skips it."""
    if joints is not None or all(url_scheme(line.port) == "sim" for line in description.lines.values()):
        return
    robot_name = description.name or robot_file
    if len(description.joints) == 1:
        question = f"Free joint {next(iter(description.joints))} of {robot_name}? (a robot standing on it falls)"
    else:
        question = (
            f"Free all {len(description.joints)} joints of {robot_name}? (a standing robot falls; --joints picks some)"
        )
    confirm(question, yes, "nothing was freed")


WARNING = "[yellow]warning:[/yellow]"


async def answering_pose(robot: Robot, names: list[str], left_out: str, warnings: list[str]) -> dict[str, float]:
    """The pose of the joints ``names`` whose servos answer; a warning naming the others, one a line as the
    open's, with ``left_out`` (what that means for them), is added to ``warnings``.  An offline joint's newest
    known angle (what ``read_pose`` gives for it) is left out too: it was read before the servo fell silent, and
    a hand may have moved it since."""
    pose = await robot.read_pose()
    offline = robot.latest.offline if robot.latest is not None else frozenset()
    # One warning a line and kind: a legs' line unplugged whole said ten lines at each capture.
    silent: dict[tuple[str, bool], list[str]] = {}
    for name in names:
        if name in offline or name not in pose:
            silent.setdefault((robot.joints[name].line, name in offline), []).append(name)
    for (line, gone), joints in silent.items():
        ids = ", ".join(str(robot.joints[name].id) for name in joints)
        one = len(joints) == 1
        what = f"joint{'' if one else 's'} {', '.join(joints)} (servo ID{'' if one else 's'} {ids} on line {line})"
        if gone:
            what += f" {'does' if one else 'do'} not answer (offline)"
        else:
            what += " did not answer"
        warnings.append(f"{WARNING} {escape(what)}: {left_out}")
    return {name: pose[name] for name in names if name in pose and name not in offline}


async def wait_for_line(
    lines: TypedLines, screen: Screen, hint: str, until: asyncio.Future[None] | None = None
) -> str | None:
    """The next typed line (None at the end of input, or once ``until`` is done), redrawing the screen meanwhile."""
    pending = asyncio.ensure_future(lines.get())
    try:
        while not pending.done():
            if until is not None and until.done():
                return None
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(asyncio.shield(pending), 0.05)
            screen.update(hint)
        line = pending.result()
        if line is not None:
            screen.typed(line)
        return line
    finally:
        pending.cancel()


async def watch_lines(robot: Robot) -> None:
    """Return never while the robot's lines run; raise what ended them (a lost port) at once."""
    cycle = 0
    while True:
        cycle = (await robot.wait_frame(cycle)).cycle


async def handled_ctrl_c(work: Awaitable[None]) -> bool:
    """Run ``work``; True if Ctrl-C ended it (then handled: the command goes on to its end)."""
    try:
        await work
    except asyncio.CancelledError:
        current = asyncio.current_task()
        if current is not None:
            current.uncancel()
        return True
    return False


@click.command()
@click.argument("robot_file", metavar="ROBOT.toml")
@click.argument("out_file", metavar="OUT.json")
@joints_option
@choice_option("--profile", PROFILES, "minjerk", "The profile the motion's segments use.")
@click.option("--name", default=None, help="The motion's name (default: the file's).")
@seconds_option(
    "--lead",
    "How long playback takes to reach the first pose (from wherever the robot is then).",
    low=0.1,
    high=30,
    default=1.0,
)
@yes_option
@click.pass_context
def teach(
    ctx: click.Context,
    robot_file: str,
    out_file: str,
    joints: str | None,
    profile: str,
    name: str | None,
    lead: float,
    yes: bool,
) -> int:
    """Teach a motion by hand: the joints go free, Enter captures the pose with its time, q then Enter ends.

    \b
    ics35 teach examples/humanoid.toml mine.json --joints right_shoulder_pitch,right_elbow
    The first pose is at --lead seconds (1 s); each later pose keeps its time after the first capture.
    The file plays back with: ics35 play ROBOT.toml OUT.json.  Ctrl-C ends like q.
    An OUT.json already there is kept as OUT.json.bak.
    Without --joints on a serial line, teach asks before freeing every joint (--yes skips that).
    """
    settings = settings_of(ctx)
    description = load_robot_file(robot_file)
    target = check_output_path(out_file, "OUT.json", {"json"})
    check_backup_path(target, "OUT.json")  # (now: at the end, the poses are taken by hand)
    names = chosen_joints(description, joints)
    note_ports(settings, robot_file)
    if target.exists():
        say_labelled(
            "note:",
            f"{escape(str(target))} exists: the poses you capture replace it when teaching ends "
            f"(its content is kept as {escape(str(target.resolve()))}.bak)",
        )
    ask_before_freeing_all(description, robot_file, joints, yes)
    keyframes: list[Keyframe] = []
    opening = Opening()
    times = TaughtTimes(lead)

    async def body() -> None:
        async with freed_robot(description, settings, names, opening) as robot:
            # The joints are free from here to the end, and the poses are written after the loop: a stop's close
            # frees free joints, and a second Ctrl-C has nothing to cut short.
            nothing_left_to_cut_short()
            lines = TypedLines()
            say(
                "the joints are free: pose the robot by hand; [bold]Enter[/bold] captures the pose, "
                "[bold]q[/bold] then Enter ends (Ctrl-C too)"
            )
            watcher = asyncio.ensure_future(watch_lines(robot))
            lost: list[bool] = []

            def summary() -> str:
                captured = f"{len(keyframes)} pose(s) captured"
                if lost:
                    return f"LINE LOST: no more poses; the {captured} are being saved"
                # The motion's clock, as its poses' times count (from the first capture, at --lead): there is none
                # before it, while the robot is posed.
                now = times.now(time.monotonic())
                if now is None:
                    return f"t=    - s (the first pose is at {times.lead:g} s)  {captured}"
                return f"t={now:5.1f} s  {captured}"

            title = TitleInParts(("teach:", escape(out_file)), frozenset({1}))  # (the file as typed, its folder too)

            def table() -> Table:
                return joint_table(robot, title.whole, names, lost=bool(lost))

            at_limits: dict[str, list[tuple[int, float, float]]] = {}
            with Screen(table, summary, title) as screen:

                async def capture_loop() -> None:
                    while True:
                        hint = "Enter: capture   q then Enter (or Ctrl-C): end"
                        line = await wait_for_line(lines, screen, hint, until=watcher)
                        if watcher.done():
                            lost.append(True)
                            screen.update(force=True)
                            await watcher  # raises what ended the lines
                        if line is None or line.strip().lower() in QUIT:
                            return
                        try:
                            await capture(robot, names, times, keyframes, screen, at_limits)
                        except IcsError:
                            lost.append(True)  # the lines ended while the pose was read
                            screen.update(force=True)
                            raise

                try:
                    await handled_ctrl_c(capture_loop())
                finally:
                    watcher.cancel()
                    with contextlib.suppress(asyncio.CancelledError, IcsError):
                        await watcher

    saving = saved = False
    try:
        # The joints it opened (their line lost: the hint frees those, not the ones left holding as they were),
        # freed by the robot's close on the lines still there.
        run_robot(settings, description.only(names), body, others_left="free", opening=opening)
        if keyframes:  # (inside the try: a second Ctrl-C landing as they are written must not lose them)
            saving = True
            save_taught(keyframes, profile, name, target, robot_file)
            saved = True
    except BaseException as exc:
        # Lost port, error or Ctrl-C: the poses captured so far are written before the error is told (the
        # save's own failure, a CliError with the poses printed instead, is not tried twice).
        if keyframes and not saved and not (saving and isinstance(exc, CliError)):
            save_taught(keyframes, profile, name, target, robot_file, on_error=True)
        if isinstance(exc, KeyboardInterrupt):  # (out of run_robot, which tells its own the same way)
            raise CliError(ExitCode.INTERRUPTED, "interrupted") from None
        raise
    if not keyframes:
        raise CliError(ExitCode.REFUSED, "no pose captured: nothing written", "press Enter to capture a pose")
    return 0


def save_taught(
    keyframes: list[Keyframe], profile: str, name: str | None, target: Path, robot_file: str, *, on_error: bool = False
) -> None:
    """Write the captured poses to ``target`` and say where (after an error: that they are kept, on stderr)."""
    motion = Motion(tuple(keyframes), profile, name or target.stem)
    try:
        backup = save_motion(motion, target)
    except OSError as exc:
        # Not lost all the same: the motion goes to stdout, to be saved from the terminal or a pipe.
        out.print(json.dumps(motion.to_json(), indent=2), soft_wrap=True, markup=False, highlight=False)
        raise CliError(
            ExitCode.USAGE,
            f"cannot write {target}: {exc.strerror or exc}; the {len(keyframes)} pose(s) are printed above instead",
        ) from None
    play = f"play it with: ics35 play {escape(robot_file)} {escape(str(target))}"
    if backup is not None:
        play = f"the file it replaced is kept as {escape(str(backup))}; {play}"
    if on_error:
        say(
            f"the {len(keyframes)} pose(s) captured so far are kept: wrote {escape(str(target))} "
            f"({motion.duration:.1f} s); {play}"
        )
    else:
        say(f"wrote {len(keyframes)} pose(s) over {motion.duration:.1f} s to {escape(str(target))}; {play}", to=out)


@dataclass
class TaughtTimes:
    """A taught keyframe's time: the first at ``lead`` seconds (how long playback takes to reach it from
    wherever the robot is, however long the posing took), each later one its time after the first capture."""

    lead: float
    first: float | None = None

    def at(self, now: float) -> float:
        """The time of a pose captured at ``now`` (``time.monotonic()``); the first one captured sets the clock."""
        if self.first is None:
            self.first = now
        return round(self.lead + now - self.first, 3)

    def now(self, now: float) -> float | None:
        """The motion's time at ``now`` (``time.monotonic()``), as a pose captured then would get it; ``None``
        before the first capture (the motion's clock starts with it)."""
        return None if self.first is None else self.lead + now - self.first


async def capture(
    robot: Robot,
    names: list[str],
    times: TaughtTimes,
    keyframes: list[Keyframe],
    screen: Screen,
    at_limits: dict[str, list[tuple[int, float, float]]],
) -> None:
    """Read the pose and add it as a keyframe, timed by ``times``; ``at_limits``: each joint recorded at a limit,
    with the poses and how far past it stood (a note kept on the screen, see below)."""
    now = time.monotonic()
    warnings: list[str] = []
    try:
        pose = await answering_pose(robot, names, "left out of this pose", warnings)
    except UnsettledReadings as exc:
        # Most often a hand still turning a joint as Enter is pressed: this pose only is not taken, teaching goes on.
        screen.say(
            f"pose not captured: {escape(str(exc))}\nhold the robot still and press Enter again (a joint that never "
            "settles: leave it out with --joints)"
        )
        return
    if not pose:
        # An empty keyframe moves nothing: kept, it would be a pose in name only (and a motion of such poses, taught
        # with the servos silent, one that plays nothing).  (Not the warnings: "left out of this pose" of no pose.)
        names_said = escape(", ".join(names))
        screen.say(f"pose not captured: none of its joints answers ({names_said}): nothing to capture")
        return
    taken = {}
    past: list[str] = []
    for name in pose:
        spec = robot.joints[name]
        if beyond_limits(spec, pose[name]):  # (a little past, as at a calibrated end: recorded at it, unsaid)
            warnings.append(
                # To the count: a tenth of a degree would show a joint a count past its limit as at it.
                f"{WARNING} joint {escape(name)} is at {signed_count_angle(pose[name])}, beyond its limits "
                f"{spec.min:g}..{spec.max:g}: recorded at the limit"
            )
            past.append(name)
        taken[name] = round(spec.clamp(pose[name]), 2)
    previous = keyframes[-1].time if keyframes else 0.0
    when = max(times.at(now), round(previous + 0.001, 3))
    if when > LONGEST_MOTION:  # (a motion that long is refused as it is built: the poses so far would be lost)
        screen.say(f"pose not captured: at {when:.0f} s it is past {LONGEST_MOTION:g} s, the longest a motion lasts")
        return
    keyframes.append(Keyframe(when, taken))
    # Through the screen: on a terminal a line printed beside the live view is written over by its next redraw.
    screen.say("\n".join([f"pose {len(keyframes)} at {taught_time(when)} s", *warnings]))
    # The pose's words go at the next capture's: a joint recorded at a limit stays said, a line of the view each, so
    # that the person who taught ten poses knows which were not where the hands put them.
    for name in past:
        at_limits.setdefault(name, []).append((len(keyframes), taken[name], abs(pose[name] - taken[name])))
        if screen.tty:  # (into a log, each pose's warning stays where it was written: not said again)
            screen.note(f"limit {name}", limit_note(name, at_limits[name]))


def limit_note(name: str, poses: list[tuple[int, float, float]]) -> str:
    """``warning: joint elbow recorded at its limit 120 in poses 1, 3 (it stood up to 15.0 past)`` from ``poses``
    (pose number, the limit, how far past it the joint stood); at both limits, ``in pose 1 at 120, pose 3 at -5``."""
    limits = {limit for _, limit, _ in poses}
    if len(limits) > 1:
        where = "its limits in " + ", ".join(f"pose {k} at {limit:g}" for k, limit, _ in poses)
    else:
        numbers = ", ".join(str(k) for k, _, _ in poses)
        where = f"its limit {poses[0][1]:g} in {'pose' if len(poses) == 1 else 'poses'} {numbers}"
    far = max(f for _, _, f in poses)
    up_to = "up to " if len(poses) > 1 else ""
    return f"{WARNING} joint {escape(name)} recorded at {where} (it stood {up_to}{far:.1f} past)"


def taught_time(seconds: float) -> str:
    """``2.936``, ``1.00``: a pose's time as the motion records it (to the millisecond: see :class:`TaughtTimes`),
    two decimals at least; said to hundredths, a pose at 2.936 s read as 2.94 beside the file's 2.936."""
    text = f"{seconds:.3f}"
    return text[:-1] if text.endswith("0") else text


def signed_count_angle(value: float) -> str:
    """``+10.125``: an angle on a whole count (0.03375 degree) to its last decimal, one at least; ``+0.0``, never
    ``-0.0``."""
    text = f"{round(value, COUNT_DECIMALS) + 0.0:+.{COUNT_DECIMALS}f}".rstrip("0")
    return f"{text}0" if text.endswith(".") else text


@click.command()
@click.argument("robot_file", metavar="ROBOT.toml")
@joints_option
@yes_option
@click.pass_context
def calibrate(ctx: click.Context, robot_file: str, joints: str | None, yes: bool) -> int:
    """Calibrate joints by hand: their neutral (offset) and range (min, max), written back into ROBOT.toml.

    \b
    1. the joints go free: pose the robot at its neutral (every joint at 0 degrees), Enter;
    2. move each joint through its whole range by hand, watching the table, Enter.
    The file keeps its comments and its previous content as ROBOT.toml.bak; where a joint is an inline
    table or dotted keys, ROBOT.calibrated.toml is written beside it instead: ROBOT.toml with only the
    calibration changed.  A joint moved over less than 5 degrees is refused, and then nothing is written.
    Without --joints on a serial line, calibrate asks before freeing every joint (--yes skips that).
    """
    settings = settings_of(ctx)
    description = load_robot_file(robot_file)
    check_backup_path(check_output_path(robot_file, "ROBOT.toml"), "ROBOT.toml")
    names = chosen_joints(description, joints)
    note_ports(settings, robot_file)
    ask_before_freeing_all(description, robot_file, joints, yes)
    neutral: dict[str, float] = {}
    low: dict[str, float] = {}
    high: dict[str, float] = {}
    opening = Opening()
    eeproms: dict[str, Eeprom] = {}
    silent: set[str] = set()  # joints offline at some frame of step 2
    away: set[str] = set()  # joints offline as of the newest frame of step 2
    lost: list[bool] = []  # the lines ended (a port lost): the view says so, and calibrate ends at once

    def extra(name: str) -> list[str]:
        # What the file will get, as it will get it: the offset on a whole count (up to 5 decimals), the limits
        # in joint degrees from that offset, rounded inward (not the servo's extremes: a person checking the
        # table against the file found them apart).
        if name not in neutral:
            return ["-", "-", "-"]
        offset = count_angle(neutral[name])
        if name not in low:
            return [signed_count_angle(offset), "-", "-"]
        limits = sorted(calibrated_limits(description.joints[name], offset, low[name], high[name]))
        return [signed_count_angle(offset), *map(signed_tenths, limits)]

    async def body() -> None:
        async with freed_robot(description, settings, names, opening) as robot:
            lines = TypedLines()
            step = ["neutral"]

            title = TitleInParts(
                (
                    "calibrate:",
                    escape(robot_file),
                    "(on the right: offset, min and max",
                    "as the file will get them)",
                ),
                frozenset({1}),
            )

            def summary() -> str:
                if lost:  # (what was written, nothing, the error says: once)
                    return "LINE LOST: calibration cut short"
                return "step 1/2: the neutral pose" if step[0] == "neutral" else "step 2/2: each joint's range"

            def table() -> Table:
                return joint_table(
                    robot,
                    title.whole,
                    names,
                    (("offset°", "min°", "max°"), extra),
                    lost=bool(lost),
                    # pos° in the frame of the columns on the right, once a neutral is taken: beside the limits
                    # from the new offset, the file's old one would put a joint at its end away from its limit.
                    offsets={name: count_angle(servo) for name, servo in neutral.items()},
                )

            def track(frame: RobotFrame | None) -> None:
                # The robot's readings, not the frame's: a garbled reply would be an end of the range.
                where = robot.positions
                for name in frame.positions if frame else ():
                    if name in names and (deg := where.get(name)) is not None:
                        servo = robot.joints[name].servo_degrees(deg)
                        low[name] = min(servo, low.get(name, servo))
                        high[name] = max(servo, high.get(name, servo))

            def offline_in(frame: RobotFrame) -> set[str]:
                # (A joint with no neutral, silent at step 1, is not calibrated whatever it does at step 2.)
                return {name for name in frame.offline if name in neutral}

            async def track_every_frame() -> None:
                # Every frame, not the screen's ticks: a joint may touch its end only for a moment.  The robot's
                # own frames, not a stream's: a stream ends at a safety stop (one servo's plug working loose),
                # and the other joints' ranges would end with it.
                cycle = 0
                while True:
                    frame = await robot.wait_frame(cycle)
                    cycle = frame.cycle
                    offline = offline_in(frame)
                    # Said at once: the person can sweep again what a joint missed while it was silent (told only
                    # at Enter, the range they had swept was lost).
                    for name in sorted(offline - away):
                        screen.note(
                            name,
                            f"[yellow]warning:[/yellow] joint {escape(name)} stopped answering: its range is not "
                            "read meanwhile (once it answers again, move it through what it missed)",
                        )
                    for name in sorted(away - offline):
                        screen.note(name, f"joint {escape(name)} answers again: move it through what it missed")
                    away.clear()
                    away.update(offline)
                    silent.update(offline)
                    track(frame)

            # Each servo's REVERSE flag (below) and pulse limits (after the ranges); not of the joints the open found
            # silent (they start offline): each read would wait a whole allowance and its retries again, a humanoid's
            # unplugged legs at --timeout 1 over a minute before step 1 showed.
            silent_at_open = robot.latest.offline if robot.latest is not None else frozenset()
            for name in (n for n in names if n not in silent_at_open):
                joint = robot.joints[name]
                with contextlib.suppress(ReplyError):
                    eeproms[name] = await robot.group[joint.line].servo(joint.id).read_eeprom()
            for name, eeprom in eeproms.items():
                spec = description.joints[name]
                note = reverse_note(robot_file, spec, description.lines[spec.line], eeprom)
                if note is not None:
                    say_labelled("[yellow]note:[/yellow]", escape(note))
            # A lost port ends the lines: said at once, not at the next Enter (the hands would go on moving
            # joints no longer read).
            watcher = asyncio.ensure_future(watch_lines(robot))

            async def typed(hint: str) -> str | None:
                line = await wait_for_line(lines, screen, hint, until=watcher)
                if watcher.done():
                    lost.append(True)
                    screen.update(force=True)
                    await watcher  # raises what ended the lines
                return line

            with Screen(table, summary, title) as screen:
                try:
                    screen.say("the joints are free: pose the robot at its neutral (every joint at 0), then Enter")
                    if await typed("Enter: this is the neutral pose") is None:
                        raise CliError(ExitCode.REFUSED, "input ended before the neutral pose: nothing written")
                    warnings: list[str] = []
                    pose = await answering_pose(robot, names, "no neutral taken, so it is not calibrated", warnings)
                    neutral.update({n: robot.joints[n].servo_degrees(deg) for n, deg in pose.items()})
                    step[0] = "range"
                    screen.say(
                        "\n".join([*warnings, "now move each joint through its whole range by hand, then Enter"])
                    )
                    tracking = asyncio.ensure_future(track_every_frame())
                    try:
                        if await typed("Enter: done") is None:
                            raise CliError(ExitCode.REFUSED, "input ended before the ranges were done: nothing written")
                    finally:
                        tracking.cancel()
                        with contextlib.suppress(asyncio.CancelledError):
                            await tracking
                    track(robot.latest)
                    if robot.latest is not None:
                        away.clear()
                        away.update(offline_in(robot.latest))
                finally:
                    watcher.cancel()
                    with contextlib.suppress(asyncio.CancelledError, IcsError):
                        await watcher

    try:
        run_robot(settings, description.only(names), body, others_left="free", opening=opening)  # (as teach's)
    except CliError as exc:
        if lost:
            exc.message = f"{exc.message}; nothing written to {robot_file}"
        if exc.code == ExitCode.INTERRUPTED:  # (the file is written only once step 2 ends with Enter)
            left = opening.joints_left()
            exc.message = (
                f"interrupted{'' if left is None else ' while opening the robot'}: nothing written to {robot_file}"
            )
            exc.hints.append(left or "the joints it opened are left free, as calibrate had them")
        raise
    calibrated: dict[str, JointSpec] = {}
    narrow: list[NarrowRange] = []
    for name in names:
        if name not in neutral and name in low:  # (plugged back in at step 2: it did answer, after step 1)
            say_labelled(
                "[yellow]warning:[/yellow]",
                f"joint {escape(name)} had no neutral (it did not answer at step 1): not "
                "calibrated (calibrate it again with --joints)",
            )
            continue
        if name not in neutral or name not in low:
            say_labelled("[yellow]warning:[/yellow]", f"joint {escape(name)} did not answer: not calibrated")
            continue
        if name in away:  # (silent still at Enter: a plug worked loose, its range likely cut short)
            say_labelled(
                "[yellow]warning:[/yellow]",
                f"joint {escape(name)} stopped answering during step 2: not calibrated "
                "(its range may be cut short; calibrate it again with --joints)",
            )
            continue
        if name in silent:  # (answering again: what it missed was said at once, to be swept again)
            say_labelled(
                "[yellow]warning:[/yellow]",
                f"joint {escape(name)} stopped answering for a moment during step 2: its range is what was seen "
                f"while it answered (narrower than the joint's, if it missed an end: calibrate it again with "
                f"--joints {escape(name)} then)",
            )
        try:
            calibrated[name] = calibrate_joint(description.joints[name], neutral[name], low[name], high[name])
        except NarrowRange as exc:
            narrow.append(exc)
    if narrow:
        # One joint: its own words; more (none moved, often: a humanoid's 17), one sentence naming them.
        said = str(narrow[0])
        if len(narrow) > 1:
            said = (
                f"joints {', '.join(exc.joint for exc in narrow)} moved over less than the "
                f"{MIN_RANGE_DEGREES:g} degrees a range needs (were they moved to both ends of their ranges?)"
            )
        raise CliError(
            ExitCode.REFUSED,
            f"{said}. Nothing was written to {robot_file}",
            "run calibrate again and, at step 2, move each joint to both ends of its range by hand",
            "to calibrate some joints only: --joints NAME,NAME",
        )
    if not calibrated:
        raise CliError(ExitCode.NO_REPLY, "no joint was calibrated (the warnings above say why): nothing written")
    for name, joint in calibrated.items():
        # The offset as written: on a whole count, up to 5 decimals (limits are rounded inward to 0.1 degree).
        offset, least, most = signed_count_angle(joint.offset), signed_tenths(joint.min), signed_tenths(joint.max)
        say(f"{name}: offset {offset}, min {least}, max {most}", to=out)
        # A free servo turns by hand past its pulse limits, which bound only the positions it is sent.
        problem = limit_problem(robot_file, joint, eeproms[name]) if name in eeproms else None
        if problem is not None:
            say_labelled("[yellow]warning:[/yellow]", f"{escape(problem)}: commands stop there")
    try:
        written = write_calibration(robot_file, description, calibrated)
    except OSError as exc:  # (the folder changed since the start: the values found are printed above)
        raise CliError(
            ExitCode.USAGE, f"cannot write {robot_file}: {error_text(exc)}; the calibrated values are printed above"
        ) from None
    if written.in_place:
        say(f"written into {escape(str(written.path))} (comments kept)", to=out)
    elif written.comments_kept:
        say_labelled(
            "[yellow]note:[/yellow]",
            f"{escape(robot_file)} has joints written as inline tables or dotted keys, "
            f"which calibrate does not edit in place; wrote {escape(str(written.path))}: that file with only the "
            "calibration changed (compare the two, then rename it over)",
        )
    else:
        say_labelled(
            "[yellow]note:[/yellow]",
            f"{escape(robot_file)} could not be edited in place; wrote "
            f"{escape(str(written.path))} (a complete file, without comments)",
        )
    if written.backup is not None:
        say(f"the previous {escape(written.path.name)} is kept as {escape(str(written.backup))}", to=out)
    return 0


COMMANDS = [teach, calibrate]
