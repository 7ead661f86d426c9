"""ics35 monitor: watch servos live, leaving the torque alone (ICS 3.5 servos go free only with --free)."""

from __future__ import annotations

import click
from rich.markup import escape

from .. import policies
from ._basic import NO_READ_35
from ._common import (
    ID_LIST,
    CliError,
    ExitCode,
    NegativeNumbersCommand,
    every_id,
    ids_named,
    json_option,
    no_servo_among,
    run,
    seconds_option,
    settings_of,
)
from ._console import TitleInParts, say
from ._errors import at_another_rate
from ._live import AskingIds, LiveOptions, discover, final_report, live_port, run_live, stream_options
from ._live_view import LiveState
from ._plot import Recorder
from ._telemetry import Telemetry


@click.command(cls=NegativeNumbersCommand)
@click.argument("ids", metavar="[IDS]", type=ID_LIST, required=False)
@seconds_option(
    "--seconds",
    "Stop after this long, counted from when the IDs are known, but not before a first cycle has ended (default: "
    "Ctrl-C); with --reconnect a port lost before that first cycle is waited for no longer (an error).",
    low=0.1,
)
@click.option(
    "--free",
    "free_servos",
    is_flag=True,
    help="Read ICS 3.5 servos with the free command: they go limp (and stay free at the end).",
)
@click.option(
    "--reconnect",
    is_flag=True,
    help="Keep watching through a lost port (an adapter unplugged, a loose cable): the view says so, waits for "
    "it and carries on once it is back (without it, a lost port ends the command with an error).",
)
@stream_options
@json_option
@click.pass_context
def monitor(
    ctx: click.Context,
    ids: list[int] | None,
    seconds: float | None,
    free_servos: bool,
    reconnect: bool,
    rate: float | None,
    per_cycle: int,
    plot: str | None,
    as_json: bool,
) -> int:
    """Watch servos live: position, current, temperature, per-ID errors and the cycle rate.

    The torque is left alone: ICS 3.6 servos report their position with their
    position read; ICS 3.5 servos can only by the free command, so with --free
    they go limp (move them by hand and watch), and without it they show "n/a"
    for position.  With only ICS 3.5 servos and no --free, monitor refuses
    (exit 5) and sends nothing (also beside IDs that do not answer).  IDS:
    1-12, 0,3,5, all (the IDs that answer; also the default).  --json prints
    one JSON line per second.  With --reconnect a lost port is waited for (the
    rows show no readings meanwhile) and the view carries on once it is back;
    lost while the IDs are asked, they are asked again once it is back.
    """
    settings = settings_of(ctx)
    shown = live_port(settings, plot)
    options = LiveOptions(
        seconds,
        rate,
        per_cycle,
        with_targets=False,
        as_json=as_json,
        plot=plot,
        free_at_end=free_servos,
        reconnect=reconnect,
    )

    asking = AskingIds(settings, as_json, reconnect=reconnect, seconds=seconds)

    async def body() -> tuple[LiveState, Telemetry, Recorder]:
        async with settings.bus(reconnect=reconnect) as bus:
            if ids and not every_id(ids):
                chosen = ids
            else:
                chosen = await asking.ask(
                    bus, "scanning", lambda: discover(bus, settings, shown, as_json, asked_all=bool(ids))
                )
            if chosen is ids and not as_json:
                # Before the first cycle each ID is asked, on a line where nothing answers a whole --timeout each:
                # said, as a scan says it scans, so a wait of seconds is not a blank terminal (nor a log silent
                # about what came before its first line).
                say(f"asking {ids_named(chosen)} on {escape(shown)} at {settings.baud} baud ...")
            plan = await asking.ask(
                bus,
                f"asking {ids_named(chosen)}",
                lambda: policies.plan_position_stream(bus, chosen, free_ics35=free_servos),
            )
            if set(chosen) <= set(plan.silent):
                # Not one of them answered: at another rate, said at once (a live table of "off" rows until Ctrl-C
                # said it only then); at none, the view starts and takes them in as they answer (powering up).
                wrong = await at_another_rate(settings, bus, chosen)
                if wrong is not None:
                    raise wrong
            searched = set(chosen) <= set(plan.silent)
            freed = plan.free
            missing = dict.fromkeys(plan.left_out, NO_READ_35)
            # Only ICS 3.5 servos (and, streamed, IDs that answer nothing: the stream would watch them alone).
            silent = plan.streamed if plan.left_out and set(plan.streamed) <= set(plan.silent) else []
            if not plan.streamed or silent:
                one = len(plan.left_out) == 1
                which = f"{ids_named(plan.left_out) if silent else 'it' if one else 'they'} speak{'s' if one else ''}"
                absent = f", and no answer from {ids_named(silent)}" if silent else ""
                raise CliError(
                    ExitCode.REFUSED,
                    f"{no_servo_among(chosen)} can report its position without going limp: {which} "
                    f"ICS 3.5, which reads a position only with the free command{absent} (nothing was sent that "
                    "moves or frees them)",
                    "pass --free to read ICS 3.5 servos with the free command (they go limp)",
                )
            how = "ICS 3.5 servos free" if freed else "torque left alone"
            # (The command's name a part of its own, as demo's: a port's name too wide is cut at its start, not it.)
            title = TitleInParts(("monitor", f"{escape(shown)} at {settings.baud} baud", f"({how})"), frozenset({1}))
            state = LiveState(chosen, title, seconds, other_rates_searched=searched)
            state.no_position = missing
            if missing and not as_json:
                for sid, why in missing.items():
                    say(f"[yellow]servo {sid}: no position:[/yellow] {escape(why)}")
            return await run_live(settings, bus, plan.streamed, state, options, None, plan)

    try:
        state, telemetry, recorder = run(settings, body)
    except CliError as exc:
        raise asking.last_words(exc) from None
    final_report(settings, state, telemetry, recorder, options, f"ics35 monitor: {shown}")
    return 0


COMMANDS = [monitor]
