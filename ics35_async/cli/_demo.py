"""ics35 demo: a smooth travelling wave streamed to every servo, with the live table; leaves them free."""

from __future__ import annotations

import math
from collections.abc import Sequence

import click
from rich.markup import escape

from .. import units
from ..frames import Frame
from ..policies import ALL_IDS, StreamPlan
from ..robot.description import MIN_LINE_RATE_HZ
from ._basic import probe_ids
from ._common import (
    ID_LIST,
    CliError,
    confirm,
    every_id,
    id_ranges,
    ids_named,
    out,
    run,
    seconds_option,
    settings_of,
    yes_option,
)
from ._console import TitleInParts, say
from ._errors import at_another_rate
from ._live import (
    AskingIds,
    LiveOptions,
    TargetFunction,
    discover,
    final_report,
    forced_out,
    live_port,
    run_live,
    stream_options,
)
from ._live_view import LiveState
from ._numbers import Number
from ._plot import Recorder
from ._signals import stop_name
from ._telemetry import Telemetry


def wave(ids: Sequence[int], amplitude: float, frequency: float) -> TargetFunction:
    """A travelling sine wave across the servos (each joins it from where it stands: see BlendIn)."""
    n = len(ids)

    def targets(t: float, frame: Frame) -> dict[int, int]:
        return {
            sid: units.degrees_to_position(amplitude * math.sin(2 * math.pi * (frequency * t - k / n)))
            for k, sid in enumerate(ids)
        }

    return targets


@click.command()
@click.option(
    "--ids",
    "ids",
    type=ID_LIST,
    default=None,
    help="Servos to drive; all: those that answer (default: 0-31 on the simulator; on hardware, the IDs a scan "
    "finds, after asking).",
)
@seconds_option(
    "--seconds", "Run this long, but not less than a first cycle (Ctrl-C stops earlier).", low=0.1, default=10.0
)
@click.option(
    "--amplitude",
    type=Number(1, 120),
    default=None,
    help="Wave amplitude in degrees (default: 45 on the simulator, 15 on hardware).",
)
@click.option("--frequency", type=Number(0.01, 5), default=0.5, show_default=True, help="Wave frequency, Hz.")
@click.option(
    "--reconnect",
    is_flag=True,
    help="Keep going through a lost port (an adapter unplugged, a loose cable): the view says so, waits for it, "
    "and once it is back reads each servo again and brings it into the wave from where it stands (without it, a "
    "lost port ends the command with an error).",
)
@stream_options
@yes_option
@click.pass_context
def demo(
    ctx: click.Context,
    ids: list[int] | None,
    seconds: float,
    amplitude: float | None,
    frequency: float,
    reconnect: bool,
    rate: float | None,
    per_cycle: int,
    plot: str | None,
    yes: bool,
) -> int:
    """A smooth wave streamed to every servo, with a live table; leaves the servos free.

    Every servo goes limp for the first cycle (where it stands is read with the free command) and at the
    end: servos on the desk, or a robot held up, not one standing on them.  A servo that stops answering and
    comes back (it may have restarted elsewhere) is read so too, and joins the wave from where it stands, no
    faster than 60 degrees a second.  With --reconnect a lost port is waited for, and each servo is read and
    brought in so once it is back.

    \b
    No hardware:   ics35 demo                      (built-in simulator, 32 servos)
    Hardware:      ics35 --port /dev/ttyUSB0 demo --ids 1-12 --amplitude 20
    Without --ids on hardware, demo scans and asks before moving every servo it finds (--yes skips that).

    --rate is the stream's cycles per second, a target to each servo each cycle: at least 20 (fewer move the
    servos in jumps); a slower wave is --frequency.
    """
    if rate is not None and rate < MIN_LINE_RATE_HZ:
        # A target a cycle, each reached at the servos' full speed: fewer cycles move the wave in jumps (and at a
        # rate that divides --frequency, the same phase every cycle: one jump, then nothing), as a robot file's
        # rate_hz is floored for its motions.
        raise click.BadParameter(
            f"{rate:g} cycles per second is too few: it must be at least {MIN_LINE_RATE_HZ:g}, as the wave goes out "
            "as one target a cycle and fewer would move the servos in jumps at their full speed (a slower wave: "
            "--frequency; leave --rate out to cycle as fast as the line allows)",
            param_hint="'--rate'",
        )
    settings = settings_of(ctx)
    asked_all = every_id(ids)  # "all": the servos that answer, as the user asked for every one (no question)
    builtin = settings.is_bare_sim  # (the built-in simulator: a servo at every ID, none to ask)
    if settings.is_bare_sim:
        ids = ids or list(ALL_IDS)
    shown = live_port(settings, plot, "ids=0-31&")
    if amplitude is None:
        # A real robot's joints may hit each other or the frame: start small there.
        amplitude = 45.0 if settings.is_sim else 15.0
    swing = amplitude
    options = LiveOptions(seconds, rate, per_cycle, with_targets=True, plot=plot, reconnect=reconnect)

    started: list[LiveState] = []  # (what it left the servos in, should a second Ctrl-C force it out)
    asking = AskingIds(settings, False, reconnect=reconnect, seconds=seconds)

    async def body() -> tuple[LiveState, Telemetry, Recorder]:
        async with settings.bus(reconnect=reconnect) as bus:
            silent: list[int] = []
            searched = False  # (the other rates, none of the IDs answering: see at_another_rate)
            if ids and not asked_all:
                chosen = ids
                if not builtin:
                    # Each named ID is asked first, as a scan asks (a short wait each once a servo has answered):
                    # streamed unasked, an ID where no servo is cost the stream's first cycles its whole --timeout
                    # each, three cycles before the stream left it out (the terminal blank meanwhile).
                    say(f"asking {ids_named(chosen)} on {escape(shown)} at {settings.baud} baud ...")
                    answered, garbled = await asking.ask(
                        bus, f"asking {ids_named(chosen)}", lambda: probe_ids(bus, chosen)
                    )
                    if not answered and not garbled:
                        # Not one of them answered: at another rate, said at once (a wave of "off" rows for --seconds
                        # said it only then); at none, streamed as they are (powering up), the run's end says so.
                        wrong = await at_another_rate(settings, bus, chosen)
                        if wrong is not None:
                            raise wrong
                        searched = True
                    else:
                        silent = [i for i in chosen if i not in answered and i not in garbled]
            else:
                chosen = await asking.ask(
                    bus, "scanning", lambda: discover(bus, settings, shown, False, asked_all=asked_all)
                )
            if ids is None and not settings.is_sim:
                # Nobody named these servos: a robot's joints may collide, so ask first.
                question = (
                    f"Move servo(s) {id_ranges(chosen)} (every servo the scan found) in a {swing:g}° wave (they go "
                    "limp as it starts and when it ends)?"
                )
                confirm(question, yes, "nothing moved")
            where = f"{escape(shown)} at {settings.baud} baud"
            title = TitleInParts(
                (f"demo: wave on {len(chosen)} servo(s),", where, "(left free at the end)"), frozenset({1})
            )
            state = LiveState(chosen, title, seconds, other_rates_searched=searched)
            started.append(state)
            # The silent IDs start out of the stream's cycle, probed as any servo that stops answering.
            plan = StreamPlan(free=list(chosen), silent=silent)
            targets = wave(chosen, swing, frequency)
            return await run_live(settings, bus, chosen, state, options, targets, plan)

    try:
        state, telemetry, recorder = run(settings, body)
    except CliError as exc:
        raise forced_out(settings, started[0] if started else None, asking.last_words(exc)) from None
    final_report(settings, state, telemetry, recorder, options, f"ics35 demo: {shown}")
    cycles = f"{state.cycle} cycle{'' if state.cycle == 1 else 's'}"
    servos = f"{len(state.ids)} servo{'' if len(state.ids) == 1 else 's'}"
    say(
        f"demo {f'stopped by {stop_name()}' if state.stopped_by_signal else 'done'} after "
        f"{state.elapsed:.1f} s: {cycles}, "  # (the wave's time: not the scan's, nor the question's)
        f"{state.rate_avg:.1f} cycles/s over {servos}; all servos left free",
        to=out,
    )
    return 0


COMMANDS = [demo]
