"""The live loop of monitor and demo: a position stream, telemetry between its cycles, the table shown live.

On a terminal the table redraws in place (rich Live); anywhere else (CI,
pipes, ``make demo | tee``) a one-line summary is printed every second and
the full table once at the end, so logs stay readable.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import Awaitable, Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

import click
from rich.markup import escape

from .. import protocol
from ..bus import Bus
from ..engine import State
from ..errors import BusClosed, ClosedByPortLoss, IcsError, PortLost
from ..frames import Frame
from ..policies import ALL_IDS, BlendIn, StreamPlan
from ..stream import Stream, StreamOptions
from ..terminal import clear_echoed_ctrl_c
from ._basic import probe_ids
from ._common import (
    NO_REPLY_HINTS,
    CliError,
    ExitCode,
    NobodyAnswered,
    Settings,
    answered_garbled,
    emit_json,
    id_ranges,
    ids_text,
    no_servo_among,
    none_of_them_answered,
    out,
)
from ._console import (
    LiveTable,
    Redraws,
    StatusLine,
    ids_argument,
    library_warnings_said,
    live_view,
    printed_table,
    say,
    say_labelled,
    scan_progress,
)
from ._live_view import LEAVE_OUT, LiveState
from ._numbers import Number, WholeNumber
from ._plot import Recorder, check_plot_path
from ._runner import line_error
from ._telemetry import Telemetry

TargetFunction = Callable[[float, Frame], dict[int, int]]
T = TypeVar("T")


@dataclass
class LiveOptions:
    seconds: float | None
    rate_hz: float | None
    telemetry_per_cycle: int
    with_targets: bool
    as_json: bool = False
    plot: str | None = None
    free_at_end: bool = True  # every streamed servo goes free at the end (not when they are only watched)
    # A lost port waited for, the bus reconnecting (monitor --reconnect); None: the command has no --reconnect.
    reconnect: bool | None = None
    # Seconds over which a servo's target goes from where it stands into the targets (demo's wave): as the command
    # starts, and when a servo comes back (see BlendIn).
    blend_seconds: float = 1.5


async def run_live(
    settings: Settings,
    bus: Bus,
    ids: list[int],
    state: LiveState,
    options: LiveOptions,
    targets: TargetFunction | None,
    plan: StreamPlan | None = None,
) -> tuple[LiveState, Telemetry, Recorder]:
    """Stream to ``ids`` (as ``plan`` says: its watched IDs read with ICS 3.6's read, its silent ones offline from
    the start) until the time is up or Ctrl-C; then free every streamed servo if ``options.free_at_end``.
    Telemetry covers every ID of ``state``.

    Servos sent targets that could not be freed at the end (the port lost) may still hold them: the
    command then fails saying so, with the command that frees them (:func:`still_holding`)."""
    loop = asyncio.get_running_loop()
    planned: StreamOptions = plan.stream_options(ids) if plan is not None else {}
    watch = set(planned.get("watch", ()))
    # A watched servo is never freed: on_close="free" would free every ID, so the end frees the others itself.
    planned["on_close"] = "free" if options.free_at_end and not watch else "hold"
    stream = bus.stream(ids, rate_hz=options.rate_hz, **planned)
    # Each servo joins the targets from where it stands: at the start, and back from offline (it may have restarted
    # and been turned elsewhere: the targets' own would throw it across its range).
    blend = BlendIn(stream, options.blend_seconds)
    state.rate_asked = options.rate_hz
    telemetry = Telemetry(bus, state.ids, options.telemetry_per_cycle, probe_interval=stream.probe_interval)
    recorder = Recorder()
    tty = out.is_terminal and not options.as_json
    live = live_view(auto_refresh=False, transient=False, vertical_overflow="visible") if tty else None
    start = loop.time()
    redraws = Redraws.of_view(tty, start)  # (a log's and --json's first line a second on: see Redraws.of_view)
    deadline = None if options.seconds is None else start + options.seconds

    def render(final: bool = False, hint: str = "   Ctrl-C to stop") -> None:
        state.refresh_stats(stream)
        if options.as_json:
            emit_json({**state.snapshot(telemetry), "final": final})
        elif live is not None:
            hint = "" if final else hint
            status = StatusLine(state.summary(telemetry) + hint)
            table = state.table(telemetry, options.with_targets)
            live.update(LiveTable(table, state.title, [status], leave_out=LEAVE_OUT, noun="servos"))
            live.refresh()
        elif not final:
            out.print(state.summary(telemetry))

    def draw_if_due(now: float) -> None:
        if redraws.due(now):
            redraws.draw(now, render)

    async def next_frame() -> Frame:
        """The stream's next frame.  With --reconnect a lost port pauses the stream until it is back: meanwhile
        the view stays, drawn as often as ever, and says so."""
        if not options.reconnect:
            return await stream.next_frame()
        while True:
            # (a tenth of a second, also where the view is drawn once a second: the loss is told from when it was)
            pause = asyncio.timeout(LOST_PORT_LOOK)
            try:
                async with pause:
                    return await stream.next_frame()
            except TimeoutError:
                if not pause.expired():
                    raise  # (a ReplyTimeout: the line's own)
            now = loop.time()
            if bus.state is State.LOST:
                state.port_lost(now - start, telemetry)
                # (--seconds is set at the first frame, where the port is lost before it: it bounds this wait too)
                if not state.cycle and deadline is not None and now >= deadline:
                    raise not_back_in_time(settings, PortLost(f"port {settings.port} lost"), options.seconds)
            draw_if_due(now)

    # Servos sent targets hold them until a free reaches them (monitor's are only read: by freeing, or watched).
    commanded = [i for i in ids if i not in watch] if options.with_targets and options.free_at_end else []
    freed = not commanded
    with library_warnings_said("stream"):  # (a rate not kept: the stream's warning says so and why)
        try:
            if live is not None:
                live.start()
            elif not options.as_json:  # (a log's lines name no command: what they are comes first)
                say(f"{state.title.whole}; one line per second, table at the end", to=out)
            try:
                async with stream:
                    try:
                        # asyncio.timeout, not wait_for: Python 3.11's wait_for can swallow the Ctrl-C
                        # cancellation when a frame arrives at the same moment.  --seconds counts from the
                        # start but is set once the first cycle has ended: before it nothing is known of the
                        # servos (a slow adapter or a loaded machine can take longer than a short --seconds).
                        # A port lost before then is waited for until --seconds runs out (next_frame).
                        timer = asyncio.timeout(None)
                        async with timer:
                            while True:
                                frame = await next_frame()
                                now = loop.time()
                                elapsed = now - start
                                state.update(frame, elapsed, stream)
                                if targets is not None:
                                    state.targets.update(blend.set_targets(targets(elapsed, frame), frame))
                                    state.note_comebacks(blend.joining, elapsed)
                                telemetry.after_frame(frame)
                                if options.plot:
                                    recorder.add(elapsed, frame)
                                draw_if_due(now)
                                if deadline is not None and timer.when() is None:
                                    timer.reschedule(deadline)  # (if already past, it fires at the next wait)
                    except TimeoutError:
                        if not timer.expired():
                            raise  # a line's own error (a ReplyTimeout is a TimeoutError too)
                        # --seconds is up
                    except asyncio.CancelledError:
                        # Ctrl-C (asyncio.run cancels us): the normal way to stop; fall through to freeing the servos.
                        state.stopped_by_signal = True
                        if live is not None:
                            # In the live view itself: a line printed beside it (stderr) garbles the redraw,
                            # leaving the table's title twice on the screen.
                            render(hint="   stopping: freeing the servos" if options.free_at_end else "   stopping")
                        else:
                            clear_echoed_ctrl_c()  # (not after the ^C the terminal echoed: nor the last JSON line)
                            if not options.as_json:
                                say("stopping: freeing the servos" if options.free_at_end else "stopping")
                    finally:
                        # The run's time, not its last frame's (the next one may have been due after the time was up).
                        state.elapsed = max(state.elapsed, loop.time() - start)
                        state.ended = True
                        telemetry.stop()
                        if options.free_at_end:
                            done = await _free_all(bus, stream, [i for i in ids if i not in watch], state)
                            freed = freed or done
                            state.freed = done
            except (IcsError, OSError) as exc:
                if options.as_json and state.cycle:
                    # A log of the lines is told the run is over, with the readings it ended on (the error
                    # itself goes to stderr).
                    render(final=True)
                lost = isinstance(exc, (PortLost, ClosedByPortLoss, OSError))
                error = line_error(settings, exc)
                if lost and options.reconnect is False:
                    error.hints.append(RECONNECT_HINT)
                if not freed:
                    raise still_holding(settings, commanded, error, line_lost=lost) from None
                if lost and options.reconnect is False:
                    raise error from None
                raise
            if not freed:
                failure = CliError(ExitCode.COMMUNICATION, "the servos did not confirm the free command at the end")
                raise still_holding(settings, commanded, failure)
            render(final=True)
        finally:
            if live is not None:
                live.stop()
    return state, telemetry, recorder


async def _free_all(bus: Bus, stream: Stream, ids: list[int], state: LiveState) -> bool:
    """Send free to ``ids`` through the stream and wait for one full cycle to carry it; whether one did."""
    if not ids:
        # (Every ID watched: nothing to carry.  On a line where nothing answers a cycle of offline IDs takes a whole
        # allowance each, and two of them were waited for with nothing to free.)
        return True
    if bus.state is State.LOST:  # (reconnecting: no cycle runs to carry it, and a stop must not wait for the port)
        return False
    with contextlib.suppress(IcsError):
        stream.free(ids)
        state.targets.update(dict.fromkeys(ids, protocol.FREE))
        # (A second at least; longer where a cycle may take longer: long allowances and servos that do not answer.)
        bound = max(1.0, stream.longest_cycle())
        with contextlib.suppress(TimeoutError, BusClosed, PortLost, asyncio.CancelledError):
            first = await asyncio.wait_for(stream.next_frame(), bound)
            # The cycle in flight may have started before free(); the next one certainly did not.
            if first is not None:
                await asyncio.wait_for(stream.next_frame(), bound)
                return True
    return False


def forced_out(settings: Settings, state: LiveState | None, error: CliError) -> CliError:
    """``error``, a stop forced out (a second Ctrl-C), saying what the streamed servos were left in when the error
    itself does not: the command's own account is lost when the press lands after it freed them (as its stream
    or its port closed) or before it could say so."""
    if error.code != ExitCode.INTERRUPTED or state is None or "servo" in error.message:
        return error
    if state.freed:
        error.message = "interrupted: Ctrl-C again cut the end short, once the servos were freed: all servos left free"
    elif state.cycle:  # (targets go out from the first frame on)
        still_holding(settings, state.ids, error)
    return error


def still_holding(settings: Settings, ids: Sequence[int], error: CliError, *, line_lost: bool = False) -> CliError:
    """``error``, saying that servos ``ids`` were sent targets and may still hold them (torque on), with the
    command that frees them on this same line (to run once it is back where the line was lost; a stop forced
    out by a second Ctrl-C or a free the servos did not confirm left the line as it was)."""
    error.message += f"; servo(s) {ids_text(ids)} may still be holding their last target (torque on)"
    free = settings.command_line("free", ids_argument(ids))
    error.hints.append(f"once the line is back, free them with: {free}" if line_lost else f"free them with: {free}")
    return error


async def discover(bus: Bus, settings: Settings, shown: str, quiet: bool, *, asked_all: bool = False) -> list[int]:
    """The IDs that answer a probe (no IDs given, or "all": each absent one would cost a reply timeout every
    cycle and a row of errors); none answering is an error.  Asked for "all", the others are named in one line;
    IDs that answered garbled (left out: two servos sharing one, most often) are named whatever was asked.
    ``shown`` is the port as the command's other lines name it (:func:`live_port`): the default simulator's
    URL is the live view's own, which the user never typed."""
    if not quiet:
        # (Said first, whatever was asked: on a line where IDs stay silent the scan takes a --timeout each, and a
        # log keeps this line where the terminal's progress bar is gone once the scan ends.)
        say(f"{'' if asked_all else 'no IDs given: '}scanning {escape(shown)} at {settings.baud} baud ...")
    with scan_progress([settings.baud], len(ALL_IDS), show=not quiet) as steps:
        steps.line_open()  # (the command's line, opened before)
        answered, garbled = await probe_ids(bus, ALL_IDS, on_probe=steps.advance)
    where = f"{shown} at {settings.baud} baud"
    if not answered and garbled:  # new servos, all at ID 0: not the unpowered line NobodyAnswered tells of
        raise answered_garbled(settings, where, [(settings.baud, i) for i in garbled])
    if not answered:
        raise NobodyAnswered(settings, where, silent=bus.stats.total.bytes_rx == 0)
    absent = sorted(set(ALL_IDS) - set(answered) - set(garbled))
    if asked_all and absent and not quiet:
        say(f"no answer from ID(s) {id_ranges(absent)} at {settings.baud} baud: no servo there")
    if garbled:  # left out of the stream, said whatever was asked: servos there, which it will not move or read
        say_labelled(
            "[yellow]warning:[/yellow]",
            f"ID(s) {ids_text(garbled)} answered garbled: left out (two servos sharing "
            "an ID, most likely: connect them one at a time and renumber one; or noise)",
        )
    return answered


# What a lost port's error adds where the command has --reconnect and it was not given.
RECONNECT_HINT = "--reconnect keeps the command going through a lost port: it waits for it to come back"

# Seconds between looks at the port while no frame comes (--reconnect): how late a loss is told.
LOST_PORT_LOOK = 0.1

# Seconds: a reply allowance (--timeout) a person notices when Ctrl-C waits it out.
NOTICEABLE_WAIT = 0.2


def not_back_in_time(settings: Settings, lost: IcsError, seconds: float | None, when: str = "") -> CliError:
    """The error of a port ``lost`` before a live command's first cycle (``when``: what it was doing) and not back
    when --seconds ran out (``seconds``): no cycle ran, so there is no table to show."""
    error = line_error(settings, lost)
    error.message += f"; it was not back when --seconds ({seconds:g} s) ran out, {when + ', ' if when else ''}"
    error.message += "before a first cycle"
    return error


class AskingIds:
    """A live command's asking of its IDs before its view begins (a scan, each named ID's probe), for a Ctrl-C
    there: it ends the command with what was being asked, and that nothing sent moved or freed a servo.

    The line first waits out the request on the wire, its whole reply allowance where the ID does not answer
    (the bus's close: its late reply must not reach the port's next command), so with a --timeout of seconds the
    press is answered at once with what it waits for, and that a second Ctrl-C leaves without waiting."""

    def __init__(
        self, settings: Settings, quiet: bool, *, reconnect: bool | None = None, seconds: float | None = None
    ) -> None:
        self.settings = settings
        self.quiet = quiet
        self.asking: str | None = None  # what was being asked when the command ended
        # --reconnect (None: the command has no such option); --seconds, from now, ends a wait for a lost port.
        self.reconnect = reconnect
        self.deadline = None if seconds is None else time.monotonic() + seconds
        self.seconds = seconds
        self.waiting_for_port = False

    @contextlib.contextmanager
    def while_asking(self, what: str) -> Iterator[None]:
        """Around the asking of ``what`` (``scanning``, ``asking IDs 1-20``)."""
        self.asking = what
        try:
            yield
        except asyncio.CancelledError:
            timeout = self.settings.timeout
            if not self.quiet and timeout >= NOTICEABLE_WAIT and not self.waiting_for_port:
                clear_echoed_ctrl_c()  # (not after the ^C the terminal echoed)
                say(
                    f"stopping: waiting out the request on the wire (up to {timeout:g} s, --timeout) so that its "
                    "late reply cannot reach the port's next command; Ctrl-C again leaves at once"
                )
            raise
        self.asking = None

    async def ask(self, bus: Bus, what: str, request: Callable[[], Awaitable[T]]) -> T:
        """``request()``, the asking of ``what`` (:meth:`while_asking`).  With --reconnect a port lost meanwhile is
        waited for (said, and that it is back) and the asking starts again: the transactions in flight were lost
        with the port, nothing asked moves or frees a servo, and an answer from before the loss may be another
        adapter's servos'.  --seconds, counted from the command's start, ends the wait with the loss's error (no
        cycle ran: no table to show).  Without --reconnect the error names it."""
        with self.while_asking(what):
            while True:
                try:
                    return await request()
                except (PortLost, ClosedByPortLoss) as exc:
                    if not self.reconnect or bus.state is State.CLOSED:
                        error = line_error(self.settings, exc)
                        if self.reconnect is False:
                            error.hints.append(RECONNECT_HINT)
                        raise error from None
                    await self._wait_for_port(bus, exc, what)

    async def _wait_for_port(self, bus: Bus, lost: IcsError, what: str) -> None:
        say(f"the port is lost while {what}: waiting for it to come back (--reconnect; Ctrl-C ends)")
        # (A Ctrl-C meanwhile has no request on the wire to wait out: read by while_asking's handler, so left set
        # where the wait ends by an exception.)
        self.waiting_for_port = True
        while bus.state is State.LOST:
            left = None if self.deadline is None else self.deadline - time.monotonic()
            if left is not None and left <= 0:
                raise not_back_in_time(self.settings, lost, self.seconds, f"while {what}")
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(bus.state_change(), left)
        self.waiting_for_port = False
        if bus.state is State.CLOSED:
            raise line_error(self.settings, lost)
        say(f"the port is back: {what} again")

    def last_words(self, error: CliError) -> CliError:
        """``error``, an interruption while asking, saying what was asked and that nothing moved or was freed."""
        if error.code == ExitCode.INTERRUPTED and self.asking is not None and error.message == "interrupted":
            error.message = f"interrupted while {self.asking}: nothing was sent that moves or frees a servo"
        return error


def live_port(settings: Settings, plot: str | None, sim_query: str = "") -> str:
    """A live command's port as shown; a --plot path is checked first (nothing sent).

    The default ``sim://`` becomes a real-time simulator (``sim_query`` adds to its URL): real time
    paces replies at the modelled wire time, so the rate shown is the real one.
    """
    if plot is not None:
        check_plot_path(plot)
    if not settings.is_bare_sim:
        return settings.port
    settings.port = settings.builtin_sim(f"{sim_query}realtime=1&")
    return "the built-in simulator"


def final_report(
    settings: Settings,
    state: LiveState,
    telemetry: Telemetry,
    recorder: Recorder,
    options: LiveOptions,
    plot_title: str,
) -> None:
    """The plot (with --plot), the table and summary where no live table was drawn; no answer at all is an error
    (naming the rate the servos answer at when it is another)."""
    if options.plot is not None:
        recorder.write(options.plot, plot_title)
        say(f"plot written to {escape(options.plot)}")
    if not options.as_json and not out.is_terminal:
        out.print(printed_table(state.table(telemetry, options.with_targets)))
        out.print(state.summary(telemetry))
    # Stopped by Ctrl-C before any cycle ended, nothing is known of the servos: no error for that.
    asked = state.cycle > 0 or not state.stopped_by_signal
    if asked and not state.answered_ever:
        if state.other_rates_searched:
            raise CliError(ExitCode.NO_REPLY, f"{no_servo_among(state.ids)} answered, at any rate", *NO_REPLY_HINTS)
        raise none_of_them_answered(settings, state.ids)


F = TypeVar("F", bound=Callable[..., Any])


def stream_options(command: F) -> F:
    """--rate, --telemetry and --plot, shared by monitor and demo."""
    for option in reversed(_STREAM_OPTIONS):
        command = option(command)
    return command


_STREAM_OPTIONS = (
    click.option(
        "--rate",
        type=Number(0.1, 10000),
        default=None,
        help="Position cycles per second (default: as fast as the line allows).",
    ),
    click.option(
        "--telemetry",
        "per_cycle",
        type=WholeNumber(0, 32),
        default=2,
        show_default=True,
        help="Servos whose current and temperature are read per cycle (a servo that stopped answering is skipped).",
    ),
    click.option(
        "--plot",
        type=click.Path(dir_okay=False),
        default=None,
        help="Record position traces and write a plot to FILE at the end (.png, .pdf, .svg, ...; needs matplotlib).",
    ),
)
