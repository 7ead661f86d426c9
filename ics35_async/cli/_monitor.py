"""ics35 monitor: watch servos live (they go free: ICS 3.5 reads a position only with the free command)."""

from __future__ import annotations

import click
from rich.markup import escape

from ._common import ID_LIST, err, json_option, run, settings_of
from ._live import LiveOptions, discover, final_report, run_live, stream_options
from ._live_view import LiveState
from ._plot import Recorder, check_plot_path
from ._telemetry import Telemetry


@click.command()
@click.argument("ids", metavar="[IDS]", type=ID_LIST, required=False)
@click.option("--seconds", type=click.FloatRange(min=0.1), default=None, help="Stop after this long (default: Ctrl-C).")
@stream_options
@json_option
@click.pass_context
def monitor(
    ctx: click.Context,
    ids: list[int] | None,
    seconds: float | None,
    rate: float | None,
    per_cycle: int,
    plot: str | None,
    as_json: bool,
) -> int:
    """Watch servos live: position, current, temperature, per-ID errors and the cycle rate.

    Positions are read with the free command (the only position read ICS 3.5 has),
    so the monitored servos go limp: move them by hand and watch.  IDS: 1-12, 0,3,5, all
    (default: the IDs that answer a scan).  --json prints one JSON line per second.
    """
    settings = settings_of(ctx)
    if plot is not None:
        check_plot_path(plot)
    shown = settings.port
    if settings.port == "sim://":
        # Real-time mode paces replies at the modelled wire time, so the rate shown is the real one.
        settings.port = f"sim://?realtime=1&baud={settings.baud}"
        shown = "the built-in simulator"
    options = LiveOptions(seconds, rate, per_cycle, with_targets=False, as_json=as_json, plot=plot)

    async def body() -> tuple[LiveState, Telemetry, Recorder]:
        async with settings.bus() as bus:
            chosen = ids or await discover(bus, settings, as_json)
            state = LiveState(chosen, f"monitor {escape(shown)} at {settings.baud} baud (servos free)", seconds)
            return await run_live(bus, chosen, state, options, None)

    state, telemetry, recorder = run(settings, body)
    if plot is not None:
        recorder.write(plot, f"ics35 monitor: {shown}")
        err.print(f"plot written to {escape(plot)}")
    final_report(state, telemetry, options)
    return 0


COMMANDS = [monitor]
