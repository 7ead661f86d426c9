"""ics35 play ROBOT.toml MOTION.json: a keyframe motion on a robot, with the live joint table.

Ctrl-C (or --seconds running out) stops smoothly: each moving joint slows
to rest over --ramp seconds, then the joints hold (--on-stop hold, the
default: a robot standing on its legs stays up) or go free.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import math
import time
from collections.abc import Callable, Iterable

import click
from rich.markup import escape

from ..errors import BusClosed, IcsError, InvalidArgument, PortLost, UnsafeOperation
from ..robot import Motion, MotionStopped, Robot, RobotDescription
from ..robot.motion import SPEEDS, check_pace
from ..robot.startup import check_start_pose
from ..stream import ON_CLOSE
from ..tasks import retrieved
from ._common import CliError, ExitCode, choice_option, out, seconds_option, settings_of
from ._console import TitleInParts, say, say_labelled
from ._numbers import Number
from ._params import yes_option
from ._prompt import confirm
from ._robot_common import (
    Opening,
    chosen_joints,
    first_pose,
    load_motion_file,
    load_robot_file,
    note_ports,
    robot_options,
    run_robot,
    show_warnings,
)
from ._robot_view import Screen, cycles_text, joint_table
from ._signals import stop_name
from ._start_pose import parse_start_pose, start_pose_option


def motion_joints(description: RobotDescription, motion: Motion, text: str | None, motion_file: str) -> Motion:
    """The motion with only the joints ``--joints`` names (each one the motion moves), or a usage error."""
    if text is None:
        return motion
    names = chosen_joints(description, text)
    outside = [name for name in names if name not in motion.joints]
    if outside:
        raise CliError(
            ExitCode.USAGE,
            f"--joints: {', '.join(outside)} not in the motion {motion_file} (nothing was sent)",
            f"the motion moves: {', '.join(motion.joints)}",
        )
    # The keyframes keep their times (the pace is the motion's), each pose without the joints left out.
    return dataclasses.replace(
        motion,
        keyframes=tuple(
            dataclasses.replace(frame, pose={j: deg for j, deg in frame.pose.items() if j in names})
            for frame in motion.keyframes
        ),
    )


async def stop_smoothly(robot: Robot, ramp: float, on_stop: str) -> None:
    """Slow every moving joint to rest, then hold or free.  (A second Ctrl-C meanwhile cuts it short: asyncio's
    runner raises KeyboardInterrupt, and the robot's close then leaves the joints as ``on_stop`` says.)"""
    # Each step on its own: a stop that fails (a line lost) or outlasts its time still leaves the free to run.
    with contextlib.suppress(IcsError, TimeoutError):
        await asyncio.wait_for(retrieved(robot.stop(ramp)), ramp + 2.0)
    if on_stop == "free":
        with contextlib.suppress(IcsError, TimeoutError):
            await asyncio.wait_for(retrieved(robot.free()), 2.0)


@click.command()
@click.argument("robot_file", metavar="ROBOT.toml")
@click.argument("motion_file", metavar="MOTION.json")
@click.option(
    "--speed",
    type=Number(*SPEEDS),
    default=1.0,
    show_default=True,
    help="Time scale: 0.5 plays at half speed.",
)
@click.option("--loop", is_flag=True, help="Play again and again until Ctrl-C (or --seconds).")
@seconds_option("--seconds", "Stop after this long.", low=0.1)
@choice_option(
    "--on-stop",
    ON_CLOSE,
    "hold",
    "What the joints it opens (the motion's, --start-pose's) do once it ends or is stopped.",
)
@seconds_option(
    "--ramp", "How long a stopped motion takes to come to rest (never past its keyframes).", low=0, high=5, default=0.3
)
@start_pose_option
@yes_option
@click.option(
    "--joints",
    default=None,
    help="Comma-separated joint names: play only these of the motion's joints, the others are not opened: not "
    "read, freed, commanded or watched by the file's [safety] (default: every joint the motion moves).",
)
@click.pass_context
def play(
    ctx: click.Context,
    robot_file: str,
    motion_file: str,
    speed: float,
    loop: bool,
    seconds: float | None,
    on_stop: str,
    ramp: float,
    start_pose_text: str | None,
    yes: bool,
    joints: str | None,
) -> int:
    """Play a keyframe motion (MOTION.json) on the robot ROBOT.toml describes, with a live view.

    \b
    No hardware:   ics35 play examples/humanoid.toml examples/wave.json
    One arm only:  ics35 play examples/humanoid.toml examples/wave.json --joints right_shoulder_pitch,right_elbow
    Ctrl-C stops smoothly (--ramp), then the joints hold or go free (--on-stop).
    On a serial line, play asks before freeing ICS 3.5 joints to read them (--yes skips that).
    Exit codes as for every command; 7: the safety watch stopped the motion.
    """
    settings = settings_of(ctx)
    start_pose = parse_start_pose(start_pose_text)
    description = load_robot_file(robot_file)
    motion = motion_joints(description, load_motion_file(motion_file, description), joints, motion_file)
    try:
        check_pace(motion, speed)  # (before the robot opens: it frees its joints to read them)
    except InvalidArgument as exc:
        raise CliError(ExitCode.USAGE, f"{motion_file}: {exc} (nothing was sent)") from None
    note_ports(settings, robot_file)
    # A motion and a robot are named by their names, else by their files' paths: a name is cut at its end where it
    # alone is too wide, a path at its start (its end names the file), after its word.
    parts = [f"play {escape(motion.name)}"] if motion.name else ["play", escape(motion_file)]
    paths = set() if motion.name else {1}
    if description.name:
        parts.append(f"on {escape(description.name)}:")
    else:
        parts += ["on", f"{escape(robot_file)}:"]
        paths.add(len(parts) - 1)
    title = TitleInParts((*parts, f"{len(motion.joints)} joint(s)"), frozenset(paths))
    began = time.monotonic()
    passes = 0
    played = 0.0  # seconds into the motion when it stopped
    # Seconds into the pass stopped part-way, once a --loop has finished one: the status line showed that pass's
    # number, so the summary names it too (a --loop's first pass stopped too; without --loop, the time played).
    unfinished: list[float] = []
    silent: list[str] = []  # the joints offline at the end (continue_on_offline): left as the summary does not say
    rejoined: list[str] = []  # the joints whose servo came back after going offline: given up, sent nothing since
    untargeted: list[str] = []  # the joints opened that never got a target (stopped as it began): left free
    found: list[str] = []  # (likewise, read without freeing: left as they were found)
    # Only the joints the motion moves, and those --start-pose states (asked to hold there: a robot's legs just
    # powered up are free), are opened: the others are not read, freed, commanded or watched, so a joint left
    # holding stays held (a standing robot's legs under a wave of its arms).  (An unknown stated joint is
    # refused in body, against the whole robot.)
    moved = description.only([*motion.joints, *(joint for joint in start_pose or {} if joint in description.joints)])
    untouched = [joint for joint in description.joints if joint not in moved.joints]
    slowing: list[bool] = []  # the smooth stop has begun (a Ctrl-C then, the CLI's second, cuts it short)
    refused: list[bool] = []  # the robot refused the motion (UnsafeOperation): the joints are as the open left them
    opening = Opening()

    async def body() -> str:
        nonlocal passes, played, silent, rejoined, untargeted, found
        options = robot_options(settings)
        check_start_pose(description, start_pose, named="--start-pose")  # (the whole robot: a typo names every joint)
        confirm_free = None if yes else ask_before_freeing_to_read(description, robot_file)
        async with opening.open(
            moved, on_close=on_stop, start_pose=start_pose, confirm_start_free=confirm_free, **options
        ) as robot:
            show_warnings(robot)
            if untouched:
                which = "neither in the motion" if joints is None else "neither in --joints"
                say_labelled(
                    "[dim]note:[/dim]",
                    f"[dim]joints {which} nor in --start-pose, left as they are (nor watched by "
                    f"the file's safety): {escape(', '.join(untouched))}[/dim]",
                )
            limp = [name for name, mode in robot.start_modes.items() if mode == "free"]
            if limp:
                which = "every joint it moves" if len(limp) == len(robot.joints) else escape(", ".join(limp))
                say_labelled(
                    "[dim]note:[/dim]",
                    f"[dim]{which} started free (ICS 3.5 servos are read by freeing them); "
                    "--start-pose states where they are instead[/dim]",
                )
            await first_pose(robot)
            opening.over()
            start = time.monotonic()
            total = motion.duration / speed

            stopped_at: list[float] = []  # seconds in when it ended or was stopped (Ctrl-C, --seconds, a lost line)
            # Seconds in when the pass playing now began: a pass takes a little longer than the motion (its end
            # waits for its last targets to go out), so the time into it is not the time modulo the motion's.
            pass_began = [0.0]

            def clock() -> tuple[float, float]:
                """Seconds since the motion began and into the pass playing, as the status line and summary say
                them: the smooth stop after it (--ramp) is not playing time, the motion stands where it stopped."""
                t = stopped_at[0] if stopped_at else time.monotonic() - start
                if seconds:
                    t = min(t, seconds)
                return t, min(max(0.0, t - pass_began[0]), total)

            def summary() -> str:
                t, into = clock()
                limit = f"/{seconds:g}" if seconds else ""
                # The pass playing; once the loop has ended (a joint given up), the last one played.
                count = f"pass {passes if given_up else passes + 1}  " if loop else ""
                return f"t={t:5.1f}{limit} s  motion {into:4.1f}/{total:.1f} s  {count}" + (
                    cycles_text(robot.latest) if robot.latest else ""
                )

            lost: list[bool] = []  # the lines ended (a port lost): the table's last look says so
            given_up: list[bool] = []  # the loop ended early: a joint came back after going offline

            with Screen(
                lambda: joint_table(robot, title.whole, motion.joints, lost=bool(lost)), summary, title
            ) as screen:
                if not screen.tty:
                    say(f"{title.whole}; one line per second, table at the end", to=out)

                async def one_pass() -> bool:
                    """Play the motion once; False if it gave up a joint whose servo came back after going offline
                    (continue_on_offline): it may have restarted, free and elsewhere, so the robot holds it, sent
                    nothing, and a later pass would be refused."""
                    try:
                        await robot.play(motion, speed=speed)
                    except MotionStopped:
                        if not robot.held:
                            raise
                        return False
                    return True

                async def player() -> None:
                    nonlocal passes
                    whole = await one_pass()
                    passes += 1
                    while loop and whole:
                        pass_began[0] = time.monotonic() - start
                        whole = await one_pass()
                        passes += 1
                    if not whole and loop:
                        given_up.append(True)

                task = asyncio.ensure_future(player())
                how = "done"
                timer = asyncio.timeout(seconds)
                try:
                    async with timer:
                        while not task.done():
                            await asyncio.wait({task}, timeout=0.05)  # then redraw
                            screen.update("Ctrl-C to stop")
                        task.result()
                    if given_up:
                        how = "stopped looping"
                except TimeoutError:
                    if not timer.expired():
                        raise  # the motion's own error (a ReplyTimeout is a TimeoutError too)
                    how = "time is up"
                except (PortLost, BusClosed):
                    lost.append(True)
                    raise
                except UnsafeOperation:
                    refused.append(True)
                    untargeted, found = _not_targeted(robot)
                    raise
                except asyncio.CancelledError:
                    # Ctrl-C (asyncio.run cancels us): the normal way to stop; handled here, so the
                    # command ends normally after the smooth stop.
                    current = asyncio.current_task()
                    if current is not None:
                        current.uncancel()
                    how = f"stopped by {stop_name()}"
                finally:
                    # How far the motion got, for the closing line when no pass completed.
                    stopped_at.append(time.monotonic() - start)
                    played = min(stopped_at[0], seconds or math.inf, total)
                    if not task.done():
                        if passes:
                            unfinished.append(clock()[1])
                        task.cancel()
                        with contextlib.suppress(asyncio.CancelledError, IcsError):
                            await task
                        screen.say(f"{how}: slowing to rest, then the joints {on_stop}", stopping=True)
                        slowing.append(True)
                        await stop_smoothly(robot, ramp, on_stop)
                if on_stop == "free" and not task.cancelled():  # (played to its end: free them now, so
                    await robot.free()  # the table's last look shows what they are left in)
            silent = sorted(robot.latest.offline) if robot.latest is not None else []
            rejoined = sorted(name for name, why in robot.held.items() if why == "rejoined" and name not in silent)
            untargeted, found = _not_targeted(robot)
            return how

    # A line lost mid-motion ends the motion on the others at once: each joint holds the last target it got,
    # where the motion had it (no --ramp: the robot's streams end with the lost line), or goes free.
    held = "holding their last targets (the motion stopped there at once, without the --ramp slow-down)"
    try:
        how = run_robot(settings, moved, body, others_left="free" if on_stop == "free" else held, opening=opening)
    except CliError as exc:
        if exc.code == ExitCode.INTERRUPTED and slowing:  # (the robot's close then leaves them as --on-stop says)
            left = (
                "were freed"
                if on_stop == "free"
                else "hold their last targets, where the slow-down had them (stiff, short of the motion's poses)"
            )
            exc.message = f"interrupted: Ctrl-C again cut the slow-down short; the joints it opened {left}"
        elif exc.code == ExitCode.REFUSED and refused:
            # Refused as it started: its ICS 3.5 joints went limp to be read, which "no motion was started" hides.
            left = "free (those it opened)" if on_stop == "free" else _left_holding(moved.joints, untargeted, found)
            exc.hints.append(f"joints left {left}")
        raise
    length = f"{motion.duration / speed:.1f} s"
    if passes:
        what = f"{passes} pass{'' if passes == 1 else 'es'} of {length}"
        if unfinished:
            into = unfinished[0]
            what += f", then pass {passes + 1} stopped " + ("as it began" if into < 0.05 else f"{into:.1f} s in")
    elif loop:  # (stopped as it began: not "0.0 s in", which reads as if nothing could have moved)
        what = f"pass 1 of {length} stopped " + ("as it began" if played < 0.05 else f"{played:.1f} s in")
    else:
        what = f"{'under 0.1' if played < 0.05 else f'{played:.1f}'} s of {length} played"
    left = "free (those it opened)" if on_stop == "free" else _left_holding(moved.joints, untargeted, found)
    # A servo that does not answer got neither the last targets nor the free: it is left as it last was told.
    buts = []
    if silent:
        one = len(silent) == 1
        buts.append(
            f"{escape(', '.join(silent))}: {'its servo does' if one else 'their servos do'} not answer "
            f"(offline) and {'keeps' if one else 'keep'} whatever {'it' if one else 'they'} last received"
        )
    if rejoined and on_stop != "free":  # (freed as it closed, the free reached them too)
        one = len(rejoined) == 1
        buts.append(
            f"{escape(', '.join(rejoined))}: {'its servo' if one else 'their servos'} came back after going offline "
            f"and {'was' if one else 'were'} sent nothing since (restarted, a servo is free, and may be elsewhere)"
        )
    but = f", but {'; and '.join(buts)}" if buts else ""
    say(f"play {how} after {time.monotonic() - began:.1f} s: {what}; joints left {left}{but}", to=out)
    return 0


def ask_before_freeing_to_read(description: RobotDescription, robot_file: str) -> Callable[[list[str]], bool]:
    """The open's question before it frees the ICS 3.5 joints it reads (their only position read): a humanoid
    standing on them falls.  Asked for those on a serial line (not the simulator); a "no" is exit code 5."""

    def ask(joints: list[str]) -> bool:
        on_hardware = description.on_hardware(joints)
        if on_hardware:
            one = len(on_hardware) == 1
            named = f"joint{'' if one else 's'} {', '.join(on_hardware)} of {description.name or robot_file}"
            servos = "Its servo speaks" if one else "Their servos speak"
            question = (
                f"Free {named} to read where {'it stands' if one else 'they stand'}? {servos} ICS 3.5, read only by"
                " freeing: a robot standing on them falls (--start-pose states where they stand instead)"
            )
            confirm(question, False, "nothing was freed")
        return True

    return ask


def _not_targeted(robot: Robot) -> tuple[list[str], list[str]]:
    """The joints with no target yet: those freed to be read at the start (ICS 3.5), left free ("hold" keeps only
    the targets there are), and those read without freeing (ICS 3.6), left as they were found (free, on a robot
    just powered up)."""
    untargeted = [j for j in robot.joints if robot.targets.get(j) is None and j not in robot.untouched]
    return untargeted, [j for j in robot.joints if j in robot.untouched]


def _left_holding(opened: Iterable[str], free: list[str], found: list[str]) -> str:
    """What the joints ``play`` opened are left in when they keep their targets: holding, but those with no target
    yet are ``free`` (freed to be read at the start) or as ``found`` (read without freeing)."""
    if not free and not found:
        return "holding (those it opened)"
    said = {"free": free, "as found": found}
    if all(j in free or j in found for j in opened):
        if not found or not free:
            return f"{'free' if free else 'as found'} (those it opened: none had a target yet)"
        both = " and ".join(f"{escape(', '.join(names))} {state}" for state, names in said.items())
        return f"{both} (those it opened: none had a target yet)"
    rest = " and ".join(f"{escape(', '.join(names))} {state}" for state, names in said.items() if names)
    return f"holding (those it opened), but {rest} (no target yet)"


COMMANDS = [play]
