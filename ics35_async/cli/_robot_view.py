"""The live joint table of play, teach and calibrate.

On a terminal it redraws in place (rich Live) ten times a second; anywhere
else (CI, pipes) a one-line summary is printed every second and the whole
table once at the end, so logs stay readable.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from types import TracebackType

from rich import box
from rich.cells import cell_len
from rich.table import Table
from rich.text import Text

from ..engine import State
from ..robot import JointSpec, Robot, RobotFrame
from ..robot.description import SERVO_DEGREES
from ..terminal import clear_echoed_ctrl_c
from ._common import out
from ._console import (
    LiveTable,
    Redraws,
    StatusLine,
    TitleInParts,
    live_view,
    printed_table,
    say,
    signed_tenths,
    wrapped_at_width,
)

Extra = Callable[[str], Sequence[str]]
# The columns a terminal too narrow for the whole table goes without, in turn: the servo behind each joint (the
# robot file says it), then the telemetry (a trip says itself in the state), then the target (calibrate's joints
# are all free).  The joint's name, its position, its state and calibrate's columns stay.
LEAVE_OUT = ("line:ID", "cur", "temp", "target°")
_GONE = (State.LOST, State.CLOSED, State.DRAINING)  # a line's port lost (reconnecting or for good)


# A joint's widest angle: a servo's end from an offset at its other end.
_WIDEST_ANGLE = signed_tenths(-2 * SERVO_DEGREES)


def _deg(value: float | None) -> str:
    return "-" if value is None else signed_tenths(value)


def cycles_text(frame: RobotFrame) -> str:
    """The cycles run so far, each line's (by name) on a robot of several: its frames come each time any line ends
    a cycle, so their count over two 100 Hz lines would read as 200 Hz."""
    if len(frame.line_cycles) <= 1:
        return f"cycle {frame.cycle}"
    return "cycles " + ", ".join(f"{line} {cycles}" for line, cycles in sorted(frame.line_cycles.items()))


def _reframed(spec: JointSpec, degrees: float | None, offset: float | None) -> float | None:
    """``degrees`` of the joint ``spec`` describes, from ``offset`` (servo degrees) in place of its own."""
    if degrees is None or offset is None:
        return degrees
    return replace(spec, offset=offset).joint_degrees(spec.servo_degrees(degrees))


def joint_table(
    robot: Robot,
    title: str,
    joints: Sequence[str] | None = None,
    extra: tuple[Sequence[str], Extra] | None = None,
    *,
    lost: bool = False,
    offsets: Mapping[str, float] | None = None,
) -> Table:
    """One row per joint: where it is, its target, telemetry and state (plus ``extra`` columns).

    ``lost``: the robot's lines stopped (a port lost); the joints of each line whose port is gone say
    so (their positions are only the last ones read), the others keep their state.  A joint whose servo is
    offline shows no target ("-", as its position): nothing is sent to it.  Its temperature and current are those
    :attr:`Robot.telemetry` has: none for a joint offline, on a lost line, or not read again since it came back.
    ``offsets``: servo degrees that read 0 in place of the robot file's, by joint (calibrate's, as found): its
    ``pos°`` from that offset.
    """
    table = Table(title=title, title_justify="left", box=box.SIMPLE_HEAD, pad_edge=False, collapse_padding=True)
    # Only the state (words) wraps: a name or a number cut short reads as another (see FittedTable).  An angle's
    # column is as wide as a joint's widest angle from the start: on a narrow terminal, a joint turning past
    # +99.9 would leave a column out, and turning back bring it back.
    for name in ("joint", "line:ID", "target°", "pos°", "temp", "cur", "state", *(extra[0] if extra else ())):
        table.add_column(
            name,
            justify="left" if name == "joint" else "right",
            style="bold" if name == "joint" else "",
            no_wrap=name != "state",
            min_width=len(_WIDEST_ANGLE) if name.endswith("°") else None,
        )
    frame = robot.latest
    positions = dict(frame.positions) if frame else {}
    uncommanded = robot.uncommanded  # ("-" for their target: only read, or offline; the Robot page's rule too)
    readings = robot.telemetry  # (made afresh at each read: once a drawing)
    gone = {line for line, bus in robot.group.buses.items() if bus.state in _GONE} if lost else set()
    for name in joints or list(robot.joints):
        spec = robot.joints[name]
        seen = readings.get(name)
        target = robot.targets.get(name)
        waiting = False  # held since its line or its servo came back: sent nothing, its target is not this one
        if spec.line in gone:
            state: str | Text = Text("LINE LOST", style="bold red")
        elif name in robot.tripped:
            state = Text(f"STOP: {robot.tripped[name].reason}", style="bold red")
        elif frame is not None and name in frame.offline:
            state = Text("offline", style="red")
        elif frame is not None and name in frame.failed:
            state = Text("no reply", style="yellow")
        elif frame is not None and name in frame.held:  # (after its line or its servo came back: sent nothing)
            state = Text("waiting for a target", style="yellow")
            waiting = True
        else:
            state = "as found" if name in robot.untouched else "free" if target is None else "held"
        cells: list[str | Text] = [
            name,
            f"{spec.line}:{spec.id}",
            "-" if name in uncommanded or waiting else "free" if target is None else _deg(target),
            _deg(_reframed(spec, positions.get(name), (offsets or {}).get(name))),
            "-" if seen is None or seen.temperature_c is None else f"{seen.temperature_c:.0f}C",
            "-" if seen is None or seen.current is None else str(seen.current),
            state,
        ]
        if extra is not None:
            cells += list(extra[1](name))
        table.add_row(*cells)
    return table


class Screen:
    """Where the table goes: redrawn in place on a terminal, a summary line a second elsewhere.  ``title``: the
    view's title in parts, drawn above the table on a line each where the terminal is too narrow for the whole
    (see :class:`TitleInParts`); else the table's own, cut with an ellipsis there."""

    def __init__(
        self, render: Callable[[], Table], summary: Callable[[], str], title: TitleInParts | None = None
    ) -> None:
        self.render = render
        self.summary = summary
        self.title = title
        self.tty = out.is_terminal
        self._live = live_view(auto_refresh=False, transient=False) if self.tty else None
        self._redraws = Redraws.of_view(self._live is not None, time.monotonic())
        self._said = ""
        self._notes: dict[str, str] = {}  # (see note)

    def say(self, message: str, *, stopping: bool = False) -> None:
        """A note for the person (on stderr); on a terminal, a line of the live view instead, since a line
        printed beside it garbles the redraw (the table's title twice on the screen).  ``stopping``: said as a
        stop signal is handled, so not after the ``^C`` a terminal echoed (a live view's redraw wipes that)."""
        if self._live is None:
            if stopping:
                clear_echoed_ctrl_c()
            say(message)
            return
        self._said = message
        self.update(force=True)

    def note(self, about: str, line: str) -> None:
        """A note on ``about`` (a joint's name) under what :meth:`say` said: on a terminal a line of the view, in
        place of the one before on the same thing (a plug that keeps working loose does not grow the view past
        the terminal); into a log, the line written."""
        if self._live is None:
            say(line)
            return
        self._notes[about] = line
        self.update(force=True)

    def typed(self, line: str) -> None:
        """``line`` was typed on the terminal: echoed on the live view's empty last line (where the cursor rests:
        see ``live_view``), it and its newline moved the cursor below, so the next redraw would start that low and
        leave the old title on the screen; step back up."""
        if self._live is not None and sys.stdin.isatty():
            rows = 1 + max(0, cell_len(line) - 1) // max(1, out.width)  # (a line longer than the width wrapped)
            out.file.write(f"\x1b[{rows}A")
            out.file.flush()

    def _lines(self, hint: str) -> LiveTable:
        said = [wrapped_at_width(Text.from_markup(text)) for text in [self._said, *self._notes.values()] if text]
        status = StatusLine(f"{self.summary()}   {hint}".rstrip())
        return LiveTable(self.render(), self.title, [*said, status], leave_out=LEAVE_OUT, noun="joints")

    def __enter__(self) -> Screen:
        if self._live is not None:
            self._live.start()
        return self

    def update(self, hint: str = "", *, force: bool = False) -> None:
        now = time.monotonic()
        if force or self._redraws.due(now):
            self._redraws.draw(now, lambda: self._draw(hint))

    def _draw(self, hint: str) -> None:
        if self._live is not None:
            self._live.update(self._lines(hint))
            self._live.refresh()
        else:
            out.print(self.summary())

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        if self._live is not None:
            self._live.update(self._lines(""))
            self._live.refresh()
            self._live.stop()
        else:
            out.print(printed_table(self.render()))
            out.print(self.summary())
