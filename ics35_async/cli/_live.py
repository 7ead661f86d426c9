"""monitor and demo: a position stream with telemetry reads fitted between its cycles, shown live.

On a terminal the table redraws in place (rich Live); anywhere else (CI,
pipes, ``make demo | tee``) a one-line summary is printed every second and
the full table once at the end, so logs stay readable.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, TypeVar

import click
from rich import box
from rich.console import Group
from rich.live import Live
from rich.markup import escape
from rich.table import Table
from rich.text import Text

from .. import protocol, units
from ..bus import Bus, Priority
from ..errors import BusClosed, IcsError, PortLost, ReplyError
from ..frames import Frame
from ..protocol import Param
from ..stream import Stream
from ._basic import probe_ids
from ._common import (
    ID_LIST,
    NO_REPLY_HINTS,
    CliError,
    ExitCode,
    Settings,
    emit_json,
    err,
    ids_text,
    json_option,
    nothing_answered,
    out,
    run,
    settings_of,
)

TargetFunction = Callable[[float, Frame], dict[int, int]]


class Telemetry:
    """Current and temperature reads, a few servos per cycle, queued between position transactions."""

    def __init__(self, bus: Bus, ids: Sequence[int], per_cycle: int) -> None:
        self.bus = bus
        self.ids = list(ids)
        self.per_cycle = per_cycle
        self.current: dict[int, int] = {}
        self.temperature: dict[int, int] = {}
        self.errors: dict[int, int] = dict.fromkeys(self.ids, 0)
        self._next = 0
        self._pending = 0

    def after_frame(self) -> None:
        # At most one round outstanding: telemetry must never starve the stream.
        if self._pending or not self.per_cycle or not self.ids:
            return
        for _ in range(min(self.per_cycle, len(self.ids))):
            sid = self.ids[self._next % len(self.ids)]
            self._next += 1
            for param, store in ((Param.CURRENT, self.current), (Param.TEMPERATURE, self.temperature)):
                fut = asyncio.ensure_future(self.bus.submit(protocol.ReadParam(sid, param), priority=Priority.LOW))
                self._pending += 1
                fut.add_done_callback(self._done_callback(sid, store))

    def _done_callback(self, sid: int, store: dict[int, int]) -> Callable[[asyncio.Future[int]], None]:
        def done(fut: asyncio.Future[int]) -> None:
            self._pending -= 1
            if fut.cancelled():
                return
            exc = fut.exception()
            if exc is None:
                store[sid] = fut.result()
            elif isinstance(exc, ReplyError):
                self.errors[sid] = self.errors.get(sid, 0) + 1

        return done


@dataclass
class LiveState:
    """Everything the table shows, updated per frame."""

    ids: list[int]
    title: str
    seconds: float | None
    positions: dict[int, int] = field(default_factory=dict)
    targets: dict[int, int] = field(default_factory=dict)
    failed: frozenset[int] = frozenset()
    offline: frozenset[int] = frozenset()
    position_errors: dict[int, int] = field(default_factory=dict)
    cycle: int = 0
    elapsed: float = 0.0
    rate_now: float = 0.0
    rate_avg: float = 0.0
    answered_ever: set[int] = field(default_factory=set)
    window: deque[tuple[float, int]] = field(default_factory=lambda: deque(maxlen=400))

    def update(self, frame: Frame, elapsed: float, stream: Stream) -> None:
        self.positions.update(frame.positions)
        self.answered_ever.update(frame.positions)
        self.failed = frame.failed
        self.offline = frame.offline
        self.cycle = frame.cycle
        self.elapsed = elapsed
        self.window.append((frame.finished, frame.cycle))
        while len(self.window) > 2 and self.window[-1][0] - self.window[0][0] > 1.0:
            self.window.popleft()
        (t0, c0), (t1, c1) = self.window[0], self.window[-1]
        self.rate_now = (c1 - c0) / (t1 - t0) if t1 > t0 else 0.0

    def refresh_stats(self, stream: Stream) -> None:
        stats = stream.stats
        self.rate_avg = stats.rate_hz
        self.position_errors = dict(stats.failures)

    def summary(self, telemetry: Telemetry) -> str:
        answering = len(self.ids) - len(self.failed | self.offline)
        limit = f"/{self.seconds:g}" if self.seconds else ""
        errors = sum(self.position_errors.values()) + sum(telemetry.errors.values())
        return (
            f"t={self.elapsed:5.1f}{limit} s  cycle {self.cycle}  rate {self.rate_now:5.1f} Hz "
            f"(avg {self.rate_avg:5.1f})  answering {answering}/{len(self.ids)}  errors {errors}"
        )

    def table(self, telemetry: Telemetry, with_targets: bool) -> Table:
        per_row = 2 if len(self.ids) > 16 else 1
        table = Table(
            title=self.title, title_justify="left", box=box.SIMPLE_HEAD, pad_edge=False, collapse_padding=True
        )
        names = (
            ("ID", "target°", "pos°", "cur", "temp", "err")
            if with_targets
            else ("ID", "pos", "pos°", "cur", "temp", "err")
        )
        for k in range(per_row):
            if k:
                table.add_column("│", style="dim")
            for name in names:
                table.add_column(name, justify="right", style="bold" if name == "ID" else "")
        rows = math.ceil(len(self.ids) / per_row)
        for r in range(rows):
            cells: list[str | Text] = []
            for k in range(per_row):
                if k:
                    cells.append("│")
                idx = r + k * rows
                if idx >= len(self.ids):
                    cells += [""] * len(names)
                    continue
                cells += self._cells(self.ids[idx], telemetry, with_targets)
            table.add_row(*cells)
        return table

    def _cells(self, sid: int, telemetry: Telemetry, with_targets: bool) -> list[str | Text]:
        pos = self.positions.get(sid)
        cur = telemetry.current.get(sid)
        temp = telemetry.temperature.get(sid)
        errors = self.position_errors.get(sid, 0) + telemetry.errors.get(sid, 0)
        if sid in self.offline:
            state: str | Text = Text("off", style="red")
        elif sid in self.failed:
            state = Text(f"{errors}!", style="yellow")
        else:
            state = str(errors)
        cells: list[str | Text] = [str(sid)]
        if with_targets:
            target = self.targets.get(sid)
            cells.append("free" if not target else f"{units.position_to_degrees(target):+.1f}")
        else:
            cells.append("-" if pos is None else str(pos))
        cells += [
            "-" if pos is None else f"{units.position_to_degrees(pos):+.1f}",
            "-" if cur is None else f"{'-' if cur & 0x40 else ''}{cur & 0x3F}",
            "-" if temp is None else f"{units.temperature_to_celsius(temp):.0f}C",
            state,
        ]
        return cells

    def snapshot(self, telemetry: Telemetry) -> dict[str, Any]:
        return {
            "t": round(self.elapsed, 3),
            "cycle": self.cycle,
            "rate_hz": round(self.rate_now, 2),
            "rate_avg_hz": round(self.rate_avg, 2),
            "servos": {
                str(sid): {
                    "position": self.positions.get(sid),
                    "current": telemetry.current.get(sid),
                    "temperature": telemetry.temperature.get(sid),
                    "errors": self.position_errors.get(sid, 0) + telemetry.errors.get(sid, 0),
                    "offline": sid in self.offline,
                }
                for sid in self.ids
            },
        }


@dataclass
class LiveOptions:
    seconds: float | None
    rate_hz: float | None
    telemetry_per_cycle: int
    with_targets: bool
    as_json: bool = False
    plot: str | None = None


class Recorder:
    """Position traces for --plot."""

    def __init__(self, limit: int = 200_000) -> None:
        self.times: list[float] = []
        self.traces: dict[int, list[float]] = {}
        self.limit = limit

    def add(self, t: float, frame: Frame) -> None:
        if len(self.times) >= self.limit:
            return
        self.times.append(t)
        n = len(self.times)
        for sid, pos in frame.positions.items():
            trace = self.traces.setdefault(sid, [])
            trace.extend([math.nan] * (n - 1 - len(trace)))
            trace.append(units.position_to_degrees(pos))

    def write(self, path: str, title: str) -> None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(10, 5))
        for sid, trace in sorted(self.traces.items()):
            trace = trace + [math.nan] * (len(self.times) - len(trace))
            ax.plot(self.times, trace, label=f"ID {sid}", linewidth=1)
        ax.set_xlabel("time (s)")
        ax.set_ylabel("position (degrees)")
        ax.set_title(title)
        ax.grid(True, alpha=0.3)
        if len(self.traces) <= 16:
            ax.legend(fontsize="small", ncol=2)
        fig.tight_layout()
        fig.savefig(path, dpi=100)
        plt.close(fig)


def require_matplotlib() -> None:
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        raise CliError(
            ExitCode.USAGE,
            "--plot needs matplotlib, which is not installed",
            "pip install 'ics35_async[plot]'  (or: pip install matplotlib)",
        ) from None


async def run_live(
    bus: Bus,
    ids: list[int],
    state: LiveState,
    options: LiveOptions,
    targets: TargetFunction | None,
) -> tuple[LiveState, Telemetry, Recorder]:
    """Stream to ``ids`` until the time is up or Ctrl-C; leave every servo free."""
    loop = asyncio.get_running_loop()
    telemetry = Telemetry(bus, ids, options.telemetry_per_cycle)
    recorder = Recorder()
    tty = out.is_terminal and not options.as_json
    render_every = 0.1 if tty else 1.0
    live = Live(console=out, auto_refresh=False, transient=False, vertical_overflow="visible") if tty else None
    stream = bus.stream(ids, rate_hz=options.rate_hz, free_on_close=True)
    start = loop.time()
    # A terminal gets a table at once; a log gets its first line after a second, with a meaningful rate.
    last_render = -math.inf if tty or options.as_json else start
    deadline = None if options.seconds is None else start + options.seconds

    def render(final: bool = False) -> None:
        state.refresh_stats(stream)
        if options.as_json:
            emit_json({**state.snapshot(telemetry), "final": final})
        elif live is not None:
            hint = "" if final else "   Ctrl-C to stop"
            live.update(Group(state.table(telemetry, options.with_targets), Text(state.summary(telemetry) + hint)))
            live.refresh()
        elif not final:
            out.print(state.summary(telemetry))

    try:
        if live is not None:
            live.start()
        async with stream:
            try:
                # asyncio.timeout, not wait_for: Python 3.11's wait_for can swallow the Ctrl-C
                # cancellation when a frame arrives at the same moment.
                async with asyncio.timeout_at(deadline):
                    while True:
                        frame = await stream.next_frame()
                        now = loop.time()
                        elapsed = now - start
                        state.update(frame, elapsed, stream)
                        if targets is not None:
                            wanted = targets(elapsed, frame)
                            stream.set_targets(wanted)
                            state.targets.update(wanted)
                        telemetry.after_frame()
                        if options.plot:
                            recorder.add(elapsed, frame)
                        if now - last_render >= render_every:
                            last_render = now
                            render()
            except TimeoutError:
                pass  # --seconds is up
            except asyncio.CancelledError:
                # Ctrl-C (asyncio.run cancels us): the normal way to stop; fall through to freeing the servos.
                if not options.as_json:
                    err.print("stopping: freeing the servos")
            finally:
                await _free_all(stream, ids, state)
        render(final=True)
    finally:
        if live is not None:
            live.stop()
    return state, telemetry, recorder


async def _free_all(stream: Stream, ids: list[int], state: LiveState) -> None:
    """Send free to everyone through the stream and wait for one full cycle to carry it."""
    with contextlib.suppress(IcsError):
        stream.free()
        state.targets.update(dict.fromkeys(ids, protocol.FREE))
        with contextlib.suppress(TimeoutError, BusClosed, PortLost, asyncio.CancelledError):
            first = await asyncio.wait_for(stream.next_frame(), 1.0)
            # The cycle in flight may have started before free(); the next one certainly did not.
            if first is not None:
                await asyncio.wait_for(stream.next_frame(), 1.0)


async def discover(bus: Bus, settings: Settings, quiet: bool) -> list[int]:
    if not quiet:
        err.print(f"no IDs given: scanning {escape(settings.port)} at {settings.baud} baud ...")
    answered, _ = await probe_ids(bus, range(32))
    if not answered:
        where = f"{settings.port} at {settings.baud} baud"
        raise nothing_answered(settings, where, silent=bus.stats.total.bytes_rx == 0)
    return answered


def final_report(state: LiveState, telemetry: Telemetry, options: LiveOptions) -> None:
    if not options.as_json and not out.is_terminal:
        out.print(state.table(telemetry, options.with_targets))
        out.print(state.summary(telemetry))
    if not state.answered_ever:
        raise CliError(ExitCode.NO_REPLY, f"no servo among {ids_text(state.ids)} answered", *NO_REPLY_HINTS)


F = TypeVar("F", bound=Callable[..., Any])


def stream_options(command: F) -> F:
    """--rate, --telemetry and --plot, shared by monitor and demo."""
    for option in reversed(_STREAM_OPTIONS):
        command = option(command)
    return command


_STREAM_OPTIONS = (
    click.option(
        "--rate",
        type=click.FloatRange(0.1, 10000),
        default=None,
        help="Position cycles per second (default: as fast as the line allows).",
    ),
    click.option(
        "--telemetry",
        "per_cycle",
        type=click.IntRange(0, 32),
        default=2,
        show_default=True,
        help="Servos whose current and temperature are read per cycle.",
    ),
    click.option(
        "--plot",
        type=click.Path(dir_okay=False, writable=True),
        default=None,
        help="Record position traces and write a plot to FILE.png at the end (needs matplotlib).",
    ),
)


# --------------------------------------------------------------------------- monitor


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
        require_matplotlib()
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


# --------------------------------------------------------------------------- demo


def wave(ids: Sequence[int], amplitude: float, frequency: float, ramp: float) -> TargetFunction:
    """A travelling sine wave across the servos, blended in from where each one starts."""
    n = len(ids)
    start: dict[int, int] = {}

    def targets(t: float, frame: Frame) -> dict[int, int]:
        for sid in ids:
            if sid not in start and sid in frame.positions:
                # Start from where the servo is, clamped into the safe range, so nothing jumps.
                start[sid] = min(max(frame.positions[sid], 3500), 11500)
        s = 1.0 if ramp <= 0 else min(1.0, t / ramp)
        s = s * s * (3 - 2 * s)  # smoothstep: no jerk at either end of the blend
        wanted = {}
        for k, sid in enumerate(ids):
            deg = amplitude * math.sin(2 * math.pi * (frequency * t - k / n))
            goal = units.degrees_to_position(deg)
            begin = start.get(sid, units.NEUTRAL)
            wanted[sid] = round(begin + (goal - begin) * s)
        return wanted

    return targets


@click.command()
@click.option(
    "--ids",
    "ids",
    type=ID_LIST,
    default=None,
    help="Servos to drive (default: 0-31 on the simulator, the IDs a scan finds on hardware).",
)
@click.option(
    "--seconds",
    type=click.FloatRange(min=0.1),
    default=10.0,
    show_default=True,
    help="Run this long (Ctrl-C stops earlier).",
)
@click.option(
    "--amplitude",
    type=click.FloatRange(1, 120),
    default=None,
    help="Wave amplitude in degrees (default: 45 on the simulator, 15 on hardware).",
)
@click.option("--frequency", type=click.FloatRange(0.01, 5), default=0.5, show_default=True, help="Wave frequency, Hz.")
@stream_options
@click.pass_context
def demo(
    ctx: click.Context,
    ids: list[int] | None,
    seconds: float,
    amplitude: float | None,
    frequency: float,
    rate: float | None,
    per_cycle: int,
    plot: str | None,
) -> int:
    """A smooth wave streamed to every servo, with a live table; leaves the servos free.

    \b
    No hardware:   ics35 demo                      (built-in simulator, 32 servos)
    Hardware:      ics35 --port /dev/ttyUSB0 demo --ids 1-12 --amplitude 20
    """
    settings = settings_of(ctx)
    if plot is not None:
        require_matplotlib()
    shown = settings.port
    if settings.port == "sim://":
        settings.port = f"sim://?ids=0-31&realtime=1&baud={settings.baud}"
        settings.port_defaulted = False  # the simulator is the point here
        shown = "the built-in simulator"
        ids = ids or list(range(32))
    if amplitude is None:
        # A real robot's joints may hit each other or the frame: start small there.
        amplitude = 45.0 if settings.is_sim else 15.0
    swing = amplitude
    options = LiveOptions(seconds, rate, per_cycle, with_targets=True, plot=plot)

    async def body() -> tuple[LiveState, Telemetry, Recorder]:
        async with settings.bus() as bus:
            chosen = ids or await discover(bus, settings, False)
            title = f"demo: wave on {len(chosen)} servo(s), {escape(shown)} at {settings.baud} baud"
            state = LiveState(chosen, title, seconds)
            if not out.is_terminal:
                out.print(f"{title}; one line per second, table at the end")
            return await run_live(bus, chosen, state, options, wave(chosen, swing, frequency, ramp=1.5))

    began = time.monotonic()
    state, telemetry, recorder = run(settings, body)
    if plot is not None:
        recorder.write(plot, f"ics35 demo: {shown}")
        err.print(f"plot written to {escape(plot)}")
    final_report(state, telemetry, options)
    out.print(
        f"demo done after {time.monotonic() - began:.1f} s: {state.cycle} cycles, "
        f"{state.rate_avg:.1f} cycles/s over {len(state.ids)} servos; all servos left free"
    )
    return 0


COMMANDS = [monitor, demo]
