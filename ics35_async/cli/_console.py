"""Output: the two consoles (results on stdout, everything else on stderr), JSON, and value formatting."""

from __future__ import annotations

import contextlib
import copy
import io
import json
import logging
import math
import re
import sys
import time
import weakref
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, replace
from typing import Any, NoReturn

import click
from rich.cells import cell_len, set_cell_size
from rich.console import Console, ConsoleOptions, Group, RenderableType, RenderResult
from rich.file_proxy import FileProxy
from rich.live import Live
from rich.markup import escape
from rich.measure import Measurement
from rich.padding import Padding
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn
from rich.segment import Segment
from rich.table import Table
from rich.text import Text

from .. import units
from ..protocol.wire import id_ranges as id_ranges
from ..protocol.wire import id_runs as id_runs
from ..protocol.wire import ids_named as ids_named
from ..protocol.wire import no_servo_among as no_servo_among
from ..terminal import clear_after_ctrl_c, clear_echoed_ctrl_c, keep_output_at_ctrl_c, whole_writes
from ._settings import LIBRARY_QUIET, CliError, ExitCode, Settings
from ._signals import same_stop_for_a_moment


class _Console(Console):
    """A console whose first words after a Ctrl-C start a line of their own: a press taken for the stop before
    it (a double Ctrl-C's second, landing as the command ends) has its ``^C`` echoed where they go next
    (``^Cwrote 1 pose(s) ...``).  Not while a live view runs, nor as it stops: it redraws its own lines, the
    echoed ``^C``'s among them, and stderr still goes through the view then, which would print the clearing as
    a line of its own above the view (an empty line between the lines above and the table)."""

    def print(self, *objects: Any, **options: Any) -> None:
        if not any(view.drawing for view in _live_views):
            clear_after_ctrl_c()
        super().print(*objects, **options)


_live_views: weakref.WeakSet[_LiveView | _ScanBar] = weakref.WeakSet()
out = _Console(highlight=False, soft_wrap=True)
err = _Console(stderr=True, highlight=False, soft_wrap=True)


def wrapped_at_width(text: Text) -> Text:
    """``text``, a line of words in a live view (its status line, a note), wrapped at the terminal's width: the
    consoles soft-wrap, so rich would cut it at the last column (the status line's hint lost on a narrow one)."""
    text.no_wrap = False
    text.overflow = "fold"
    return text


class StatusLine:
    """``text``, a live view's status line (fields such as ``cycle 412  errors 0``, two spaces apart), wrapped at
    the width it is drawn at between its fields, a field wider than that between its words: wrapped at words,
    a count went to the next line without its label ("... waiting for it to come back  errors" / "0")."""

    def __init__(self, text: str) -> None:
        self.text = text

    def fields(self) -> list[tuple[str, str]]:
        """The text's fields, each with the gap before it (the first's empty).  Two spaces or more part two fields
        before a word ("cycle 412  errors 0") or before a count that does not follow a label ("... at 1 s)  12
        pose(s) captured"); not those that pad a number to its width after one ("t=  3.0 s", "rate  35.8 Hz",
        "(avg  35.7)")."""
        text, gap_before, start = self.text, "", 0
        fields: list[tuple[str, str]] = []
        for gap in re.finditer(r" {2,}", text):
            after, before = text[gap.end() : gap.end() + 1], text[gap.start() - 1 : gap.start()]
            if after.isalpha() or (after.isdigit() and not (before.isalpha() or before in "=(")):
                fields.append((gap_before, text[start : gap.start()]))
                gap_before, start = gap.group(), gap.end()
        fields.append((gap_before, text[start:]))
        return fields

    def __rich_console__(self, console: Console, options: ConsoleOptions) -> RenderResult:
        width = options.max_width
        (_, line), *rest = self.fields()
        for gap, field in rest:
            if cell_len(line + gap + field) <= width:
                line += gap + field
            else:
                yield wrapped_at_width(Text(line))
                line = field
        yield wrapped_at_width(Text(line))


def print_heading(line: str) -> None:
    """``line`` (plain text: what a table shows) printed above its table, wrapped between its words on a terminal,
    whole into a log.  Not the table's title: rich cuts a title at the table's width ("...in their EEPROM (l")."""
    say(escape(line), to=out)


@dataclass(frozen=True)
class TitleInParts:
    """A live view's title in parts (rich markup), joined by spaces: drawn whole where the terminal is wide enough,
    else a line per part (neighbours sharing one where they fit together).  A part too wide by itself is cut with
    an ellipsis: at its start where its index is in ``cut_at_start``, since a port's or a file's name tells itself
    from another's by its end (``...-if00-port0``, ``?ids=1-3``, ``.../walk_v2.json``); the others (words, a
    motion's name) at their end.  One line cut with an ellipsis lost whatever came last (what the servos are
    left in, then the rate, then the port)."""

    parts: tuple[str, ...]
    cut_at_start: frozenset[int] = frozenset()

    @property
    def whole(self) -> str:
        return " ".join(self.parts)


class LiveTable:
    """A live view: ``table`` fitted to the terminal's width (a :class:`FittedTable`, leaving out ``leave_out``'s
    columns in turn), its title on lines of its own above it (``title``: in parts, see :class:`TitleInParts`; else
    the table's own, cut with an ellipsis at the terminal's width), and ``below`` (a status line, a note) under
    it, all within the height it is drawn at (a live view's: the terminal's rows, see :class:`_Drawn`).  Where
    they do not fit, the table loses its last rows for a line saying how many more ``noun`` there are: rich cut
    the view's last lines, the status line (what is happening, how to stop) among them, or let it run past the
    terminal's top (each redraw then left its title on the screen once more).

    The title goes above the table, not in it: a table's own title is laid out at the table's width, often
    narrower than the title, and as the consoles soft-wrap, rich cuts it at the terminal's last column with
    nothing to say so (a port's or a file's name cut short reads as another's).  (A table printed whole, into a
    log, keeps its title.)"""

    def __init__(
        self,
        table: Table,
        title: TitleInParts | None,
        below: Sequence[RenderableType],
        *,
        leave_out: Sequence[str] = (),
        noun: str = "rows",
    ) -> None:
        own, table.title = table.title, None
        self.table = table
        self.above: list[RenderableType] = []
        if title is not None:
            self.above.append(_TitleLines(title))
        elif own is not None:
            self.above.append(_cut_at_width(Text.from_markup(own) if isinstance(own, str) else own))
        self.below = below
        self.leave_out = leave_out
        self.noun = noun

    def __rich_console__(self, console: Console, options: ConsoleOptions) -> RenderResult:
        def lines(*renderables: RenderableType) -> list[list[Segment]]:
            return console.render_lines(Group(*renderables), options, pad=False) if renderables else []

        head, tail = lines(*self.above), lines(*self.below)
        room = options.max_height - len(head) - len(tail)
        fitted = FittedTable(self.table, self.leave_out).fitted(console, options)
        body = lines(fitted)
        kept = every = len(fitted.rows)
        while len(body) > room and kept > 0:
            # (A row is a line at least: as many rows off as lines too many, and one more for the line saying so
            # the first time; a row of wrapped names is more, which the next turn sees.)
            kept = max(0, kept - (len(body) - room) - (1 if kept == every else 0))
            body = lines(_first_rows(fitted, kept, self.noun))
        for line in [*head, *body, *tail]:
            yield from line
            yield Segment.line()


def _first_rows(table: Table, kept: int, noun: str) -> RenderableType:
    """``table``'s first ``kept`` rows, and a line under it saying how many ``noun`` the others hold (the values in
    the columns named as its first one: two a row in monitor's table of many servos), at the view's width (as the
    table's caption it wrapped at the table's, a line more that cost a row)."""
    first = str(table.columns[0].header) if table.columns else ""
    hidden = sum(
        1
        for column in table.columns
        if str(column.header) == first
        for cell in list(column.cells)[kept:]
        if (cell.plain if isinstance(cell, Text) else str(cell)).strip()
    )
    cut = _narrowed(table, None, None, range(kept))  # (its caption, the columns left out, kept)
    counted = noun if hidden != 1 else noun.removesuffix("s")
    return Group(cut, wrapped_at_width(Text(f"… {hidden} more {counted}: a taller terminal shows them", style="dim")))


def printed_table(
    table: Table, leave_out: Sequence[str] = (), *, indent: int = 0, last: Sequence[str] = ()
) -> RenderableType:
    """``table`` to print on stdout, ``indent`` spaces in.  On a terminal, fitted to its width (a
    :class:`FittedTable`, leaving out ``leave_out``'s columns in turn, and ``last``'s once its names are at their
    narrowest); into a log (a pipe, a file, CI), whole at its
    own width, whatever the terminal's or ``COLUMNS``: a log is read later, in a wider window or an editor, where
    a column left out or a value cut to fit is lost for good."""
    if out.is_terminal:
        return Padding(FittedTable(table, leave_out, last), (0, 0, 0, indent), expand=False)
    parts: list[RenderableType] = [table]
    if table.title is not None:
        # Its title a line of its own: rich cuts a table's title at the table's width ("monitor /tmp/ics35-sim-x/t").
        title = Text.from_markup(table.title) if isinstance(table.title, str) else table.title
        untitled = copy.copy(table)
        untitled.title = None
        parts = [title, untitled]
    return _AtItsOwnWidth(Group(*(Padding(part, (0, 0, 0, indent), expand=False) for part in parts)))


class _AtItsOwnWidth:
    """``renderable`` drawn as wide as it is, whatever the console's width."""

    def __init__(self, renderable: RenderableType) -> None:
        self.renderable = renderable

    def __rich_console__(self, console: Console, options: ConsoleOptions) -> RenderResult:
        yield from console.render(self.renderable, options.update_width(_UNLIMITED))


_UNLIMITED = 1_000_000  # cells: a width no table reaches


class FittedTable:
    """``table`` drawn at the width it is given with each of its values whole.  rich fits a table wider than the
    terminal by cutting every column's values short ("right…" for any of five joints, "+2…" for a position of
    +23.5), each then reading as another's or as nothing.  Here a table too wide loses its edges (the blank
    lines and columns around it), then the columns ``leave_out`` names in turn until the rest fits (those left
    out named under the table), then its first column's values (names) wrap after their underscores and hyphens,
    then a part of a name still too wide is cut with an ellipsis (down to :data:`SHORTEST_CUT_NAME` cells: the
    ellipsis says it is cut, where a value cut reads as another), and only then more columns: those ``last`` names,
    then from the right (named too): no value is cut short, nor a column drawn to nothing.  The table's
    columns that may wrap (words) do; the others should be ``no_wrap``, or rich cuts them before this does anything."""

    def __init__(self, table: Table, leave_out: Sequence[str], last: Sequence[str] = ()) -> None:
        self.table = table
        self.leave_out = leave_out
        self.last = last

    def __rich_console__(self, console: Console, options: ConsoleOptions) -> RenderResult:
        yield self.fitted(console, options)

    def fitted(self, console: Console, options: ConsoleOptions) -> Table:
        """The table as drawn at ``options``' width: itself where it fits, else narrowed."""
        width = options.max_width
        unlimited = options.update_width(_UNLIMITED)
        # Measured on the rows holding each column's widest value alone: as wide as the whole table, measured in a
        # fraction of its time (a live view draws it ten times a second, on the loop that streams).
        widest = _widest_rows(self.table)

        def excess(left_out: Sequence[str] | None, names_width: int | None = None) -> int:
            narrowed = _narrowed(self.table, left_out, names_width, widest)
            return Measurement.get(console, unlimited, narrowed).minimum - width

        def names_width_for(left_out: Sequence[str]) -> int | None:
            if (over := excess(left_out)) <= 0 or not self.table.columns:
                return None
            names = [str(cell) for cell in self.table.columns[0].cells]
            longest = max(map(cell_len, names), default=0)
            # (Names are cut to no fewer than SHORTEST_CUT_NAME cells, and one shorter than that not at all, so an
            # ID's number is never cut.)
            parts = max((cell_len(part) for name in names for part in _name_parts(name)), default=1)
            return max(min(parts, SHORTEST_CUT_NAME), longest - over)

        if excess(None) <= 0:
            return self.table
        headers = [str(column.header) for column in self.table.columns]
        left_out: list[str] = []
        for header in (header for header in self.leave_out if header in headers):
            if excess(left_out) <= 0:
                break
            left_out.append(header)
        names_width = names_width_for(left_out)
        # Still too wide with the names at their narrowest: more columns go, from the right, each named under the
        # table, rather than rich cutting values short ("-10.1…") or drawing a column to nothing, unnamed.
        spare = [header for header in self.last if header in headers and header not in left_out]
        spare += [header for header in reversed(headers[1:]) if header not in left_out and header not in spare]
        while names_width is not None and excess(left_out, names_width) > 0 and spare:
            left_out.append(spare.pop(0))
            names_width = names_width_for(left_out)
        return _narrowed(self.table, left_out, names_width)


def _widest_rows(table: Table) -> list[int]:
    """The rows of ``table`` holding each column's longest value and its longest word (what its width is
    measured by, as its cells' text goes: a value drawn otherwise is not looked at)."""

    def text(cell: object) -> str:
        return cell.plain if isinstance(cell, Text) else cell if isinstance(cell, str) else ""

    rows: set[int] = set()
    for column in table.columns:
        texts = [text(cell) for cell in column.cells]
        for size in (cell_len, lambda value: max(map(cell_len, value.split()), default=0)):
            if texts:
                rows.add(max(range(len(texts)), key=lambda k: size(texts[k])))
    return sorted(rows)


def _narrowed(
    table: Table, left_out: Sequence[str] | None, names_width: int | None, rows: Sequence[int] | None = None
) -> Table:
    """``table`` without its edges and the columns ``left_out`` (named in its caption), or as it is with ``None``;
    ``names_width``: its first column's values wrapped at that width (:func:`_wrapped_name`); ``rows``: only
    those rows."""
    kept = range(len(table.rows)) if rows is None else rows
    narrowed = copy.copy(table)
    narrowed.columns, narrowed.rows = [], [table.rows[k] for k in kept]
    for column in table.columns:
        if left_out is not None and str(column.header) in left_out:
            continue
        every = list(column.cells)
        cells = [every[k] for k in kept]
        if names_width is not None and not narrowed.columns:
            cells = [_wrapped_name(cell, names_width) if isinstance(cell, str) else cell for cell in cells]
        narrowed.columns.append(replace(column, _index=len(narrowed.columns), _cells=cells))
    if left_out is not None:
        narrowed.show_edge = False
    if left_out:
        narrowed.caption = wrapped_at_width(Text(f"columns left out: {', '.join(left_out)}"))
        narrowed.caption_justify = "left"
        narrowed.caption_style = "dim"
    return narrowed


# The fewest cells a name in a table's first column is cut to (with its ellipsis) where it does not fit whole:
# fewer say too little of which it is; a value cut then instead (rich's) says so with its own ellipsis.
SHORTEST_CUT_NAME = 8


def _name_parts(name: str) -> list[str]:
    """``name`` broken after its underscores and hyphens: ``right_``, ``shoulder-``, ``pitch``."""
    return re.split(r"(?<=[_-])", name)


def _wrapped_name(name: str, width: int) -> str:
    """``name`` in lines of ``width`` cells at most, broken after its underscores and hyphens
    (``right_shoulder_`` / ``pitch``); a part wider than ``width`` by itself cut with an ellipsis there."""
    lines: list[str] = []
    for part in _name_parts(name):
        if lines and cell_len(lines[-1]) + cell_len(part) <= width:
            lines[-1] += part
        else:
            lines.append(part if cell_len(part) <= width else set_cell_size(part, width - 1) + "…")
    return "\n".join(lines)


def _cut_at_width(text: Text) -> Text:
    text.no_wrap = True
    text.overflow = "ellipsis"
    return text


class _TitleLines:
    """A :class:`TitleInParts` laid out at the width it is drawn at."""

    def __init__(self, title: TitleInParts) -> None:
        self.title = title

    def __rich_console__(self, console: Console, options: ConsoleOptions) -> RenderResult:
        width = options.max_width
        lines: list[Text] = []
        for k, part in enumerate(Text.from_markup(part) for part in self.title.parts):
            if lines and lines[-1].cell_len + 1 + part.cell_len <= width:
                lines[-1] = Text(" ").join([lines[-1], part])
                continue
            if k in self.title.cut_at_start and part.cell_len > width:
                part = Text("…").append_text(part[len(part) - max(0, width - 1) :])
            lines.append(part)
        for line in lines:
            yield _cut_at_width(line)


class _Drawn:
    """What a live view draws of ``renderable``: with ``resting``, an empty line below it (see :class:`_LiveView`),
    ``renderable`` drawn within the terminal's rows but that one (a :class:`LiveTable`); without (its last
    drawing, as it stops), whole: the terminal scrolls, and keeps what went past its top."""

    def __init__(self, renderable: RenderableType, *, resting: bool) -> None:
        self.renderable = renderable
        self.resting = resting

    def __rich_console__(self, console: Console, options: ConsoleOptions) -> RenderResult:
        within = options.copy()
        within.max_height = options.max_height - 1 if self.resting else sys.maxsize
        yield from console.render(self.renderable, within)
        if self.resting:
            yield Segment.line()


class _ScanBar(Progress):
    """rich's ``Progress`` with the cursor resting on an empty line below the bar, as a live view's (see
    :class:`_LiveView`): on a terminal narrower than the bar's line the bar fills the width, and the ``^C`` of a
    Ctrl-C wrapped to a line of its own, so that the bar, cleared from one line too low, stayed on the screen.
    The last drawing, as it stops, leaves the empty line out, as a live view's does.  Counted among the live
    views (see :func:`live_view`), so that the consoles leave the ``^C`` to its redraw: their clearing of it,
    written to stderr while the bar held it, came out above the bar as an empty line."""

    _stopping = False

    @property
    def drawing(self) -> bool:
        """Whether the bar is on the screen and redrawn (see :attr:`_LiveView.drawing`)."""
        return self.live.is_started or self._stopping

    def get_renderable(self) -> RenderableType:
        return _Drawn(super().get_renderable(), resting=not self._stopping)

    def stop(self) -> None:
        self._stopping = True
        try:
            super().stop()
        finally:
            self._stopping = False


class ScanSteps:
    """A scan's progress bar as the scan hears of it: :meth:`advance` with the probes each step finished (the
    library's ``on_probe``), :meth:`line_open` once the port has opened.  The bar is drawn from then on: drawn
    at once, it stood above the error of a port that never opened (``scanning 115200 baud ━━━ 0/96``), a scan
    seemingly under way."""

    def __init__(self, bar: _ScanBar, bauds: Sequence[int], ids: int) -> None:
        self._bar = bar
        self._bauds = bauds
        self._ids = ids
        self._done = 0
        self._task = bar.add_task(f"scanning {bauds[0]:>7} baud", total=len(bauds) * ids)

    def line_open(self) -> None:
        if not self._bar.live.is_started:
            self._bar.start()

    def advance(self, n: int) -> None:
        self._done += n
        rate = self._bauds[min(self._done // self._ids, len(self._bauds) - 1)]
        self._bar.update(self._task, advance=n, description=f"scanning {rate:>7} baud")


@contextlib.contextmanager
def scan_progress(bauds: Sequence[int], ids: int, *, show: bool = True) -> Iterator[ScanSteps]:
    """A scan's progress on a terminal (stderr), gone once it ends: ``scanning 115200 baud``, a bar and the probes
    done of ``ids`` at each of ``bauds``, drawn once the line is open (see :class:`ScanSteps`)."""
    progress = _ScanBar(
        TextColumn("[progress.description]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        console=err,
        transient=True,
        disable=not show or not err.is_terminal,
    )
    _live_views.add(progress)
    try:
        yield ScanSteps(progress, bauds, ids)
    finally:
        if progress.live.is_started:  # (a bar never drawn, the port not opened, has nothing to stop)
            progress.stop()


class _LiveView(Live):
    """rich's ``Live`` with the cursor resting on an empty line below the view while it runs.

    Rich leaves the cursor at the end of the view's last line (the status line), and redraws from there.  What
    the terminal echoes went there: a key typed (q, or Enter for teach), or Ctrl-C's ``^C``; and a line filling
    the terminal's width leaves the cursor past its last column, so that echo wrapped to a line of its own, and
    the next redraw, counting up from one line too low, left the view's title on the screen once more.  On the
    empty line the echo goes where the next redraw clears it.  The last drawing, as the view stops, leaves it
    out: what the command says next starts on the line below the view.

    Its redraws reach the terminal whole: the terminal keeps its output at Ctrl-C from the start (see
    ``keep_output_at_ctrl_c``), and the view writes all it is given where Python runs unbuffered (see
    ``whole_writes``).  A redraw cut short left the cursor elsewhere, and the next one overwrote the lines above
    the view.
    """

    _content: RenderableType = ""
    _stopping = False

    @property
    def drawing(self) -> bool:
        """Whether the view is on the screen and redrawn: started, or drawn a last time as it stops."""
        return self.is_started or self._stopping

    def start(self, refresh: bool = False) -> None:
        keep_output_at_ctrl_c(self.console.file)
        # (the console's own stream meanwhile, stdout as the view starts: live_view's console is stdout's)
        self.console.file = whole_writes(self.console.file)
        super().start(refresh=refresh)

    def update(self, renderable: RenderableType, *, refresh: bool = False) -> None:
        self._content = renderable
        super().update(_Drawn(renderable, resting=True), refresh=refresh)

    def stop(self) -> None:
        self._stopping = True
        try:
            super().update(_Drawn(self._content, resting=False))
            super().stop()
        finally:
            self._stopping = False
            with contextlib.suppress(OSError, ValueError):  # (a hung-up terminal, a closed stream)
                self.console.file.flush()
            self.console.file = None  # type: ignore[assignment]  # (stdout again, whatever it is then)


DRAW_SHARE = 0.2
"""The most of the event loop's time a live view's drawing takes: the loop that draws also streams to the servos."""


class Redraws:
    """When a live view draws next: ``every`` seconds (the first at ``first``), or less often where a drawing takes
    longer than :data:`DRAW_SHARE` of that.  Drawing monitor's table of 32 servos at 60 columns takes 30-70 ms on a
    2-core machine: drawn ten times a second, the stream at 115200 baud ran 19-23 cycles/s (35 into a file), drawn
    so 29, the command's CPU 2.2-2.7 s against 1.4-1.5 in 4 s.  ``clock``: what a drawing is timed by."""

    def __init__(
        self, every: float, first: float = -math.inf, *, clock: Callable[[], float] = time.perf_counter
    ) -> None:
        self.every = every
        self.clock = clock
        self._next = first

    @classmethod
    def of_view(cls, on_terminal: bool, now: float) -> Redraws:
        """A view's: on a terminal, ten drawings a second from ``now`` on; into a log, a line a second, the first
        a second after ``now`` (with a rate measured by then: a line at once would say 0 Hz)."""
        return cls(0.1) if on_terminal else cls(1.0, first=now + 1.0)

    def due(self, now: float) -> bool:
        """Whether a drawing is due at ``now`` (the caller's clock)."""
        return now >= self._next

    def draw(self, now: float, drawing: Callable[[], None]) -> None:
        """Draw now (``now``: the caller's clock) with ``drawing``, and set when the next one is due."""
        started = self.clock()
        drawing()
        self._next = now + max(self.every, (self.clock() - started) / DRAW_SHARE)


def live_view(**options: Any) -> _LiveView:
    """A live view (rich's ``Live``: see :class:`_LiveView`) on stdout, ended by :func:`end_live_views` should its
    own stop be cut short."""
    live = _LiveView(console=out, **options)
    _live_views.add(live)
    return live


def end_live_views() -> None:
    """Stop every live view still running: the command's own stop of it was cut short (a later Ctrl-C forced it
    out).  A live view not stopped keeps stdout and stderr redirected through itself: what the command says next
    (its error) is drawn into the view's last line and the view redrawn around it ("cycle 509error: interrupted",
    "error: interruptedral pose"), or over it."""
    for live in list(_live_views):
        with contextlib.suppress(Exception):
            live.stop()
    for name in ("stdout", "stderr"):  # (a stop itself cut short, after its first steps)
        stream = getattr(sys, name)
        if isinstance(stream, FileProxy):
            setattr(sys, name, stream.rich_proxied_file)


SIMULATED_KEY = "simulated"  # in a JSON result read from the implicit built-in simulator


def emit_json(value: Any) -> None:
    """One JSON document on stdout (plain print: rich would wrap long lines).

    A result read from the implicit built-in simulator says so (``"simulated": true``): plausible fake
    data must not pass for a robot's.
    """
    context = click.get_current_context(silent=True)
    settings = context.find_object(Settings) if context is not None else None
    if settings is not None and settings.simulated and isinstance(value, dict):
        value = {**value, SIMULATED_KEY: True}
    sys.stdout.write(json.dumps(value, sort_keys=False) + "\n")
    sys.stdout.flush()


def fail(error: CliError) -> NoReturn:
    end_live_views()
    if error.code == ExitCode.INTERRUPTED:
        same_stop_for_a_moment()  # (a double Ctrl-C's second press, landing as this is said)
        clear_echoed_ctrl_c()
    say_error(error)
    sys.exit(int(error.code))


def say_error(error: CliError) -> None:
    """``error`` and its hints on stderr, as a command that ends with it says them (one that goes on may too)."""
    say_labelled("[bold red]error:[/bold red]", escape(error.message))
    for hint in error.hints:
        say_labelled("  [cyan]hint:[/cyan]", escape(hint))


def say_click_error(error: click.ClickException) -> None:
    """click's own error (a usage error: the command's usage, the help hint, ``Error: ...``) in click's words on
    stderr.  On a terminal, wrapped at words to its width (``Error:`` as a label, see :func:`say_labelled`): click
    writes the error whole, for the terminal to cut mid-word, and lays the usage out for 50 columns at least.  Into
    a log, as click writes it."""
    if not err.is_terminal:
        error.show()
        return
    context = getattr(error, "ctx", None)
    if isinstance(context, click.Context):  # (click's own margin of two columns, without its 50 at least)
        context.terminal_width = max(min(err.width, context.max_content_width or 80) - 2, 1)
    shown = io.StringIO()
    error.show(shown)
    for line in shown.getvalue().splitlines():
        label, _, text = line.partition(" ")
        if label == "Error:":
            say_labelled(label, escape(text))
        else:
            say(escape(line))


# The fewest columns a labelled line's text is wrapped to beside its label: on a terminal narrower still, its
# further lines start at the left edge (a column of a word or two a line, under an indent, reads worse).
NARROWEST_TEXT = 16


def say_labelled(label: str, text: str, *, to: Console = err) -> None:
    """``label`` (``error:``, ``  hint:``, ``warning:``, ``note:``) and ``text`` after it (both rich markup), on
    stderr (or ``to``).  On a terminal, wrapped at words to its width, each further line indented under the text:
    the consoles soft-wrap (see ``out``), so the terminal cut a long line at its last column, mid-word (``chec`` /
    ``k the cable``), and its further lines began under the label.  Into a log (a pipe, a file, CI), one line
    however long, as a table goes into one whole (see :func:`printed_table`): read later in a wider window, and
    found whole by grep."""
    to.print(fitted_to(to, Text.from_markup(label).append(" "), Text.from_markup(text)), soft_wrap=True)


def say(text: str, *, to: Console = err) -> None:
    """``text`` (rich markup), a sentence on a line of its own (what the command is doing, how it ended), on stderr
    (or ``to``): on a terminal wrapped at words to its width, as :func:`say_labelled` wraps its text, further lines
    indented as far as its first (``  line arms: ...``); into a log, one line."""
    body = Text.from_markup(text)
    indent = len(body.plain) - len(body.plain.lstrip(" "))
    to.print(fitted_to(to, body[:indent], body[indent:]), soft_wrap=True)


def fitted_to(console: Console, head: Text, body: Text) -> Text:
    """``head`` (a label and the space after it, an indent, nothing) and ``body`` after it, as written to
    ``console``: on a terminal, ``body`` wrapped at words to its width, each further line under its first word;
    into a log, one line (see :func:`say_labelled`)."""
    if not console.is_terminal:
        return Text.assemble(head, body)
    width, indent = console.width, head.cell_len
    if width - indent < NARROWEST_TEXT:
        lines = words_wrapped(Text.assemble(head, body), width)
    else:
        lines = [
            Text.assemble(head if k == 0 else " " * indent, line)
            for k, line in enumerate(words_wrapped(body, width - indent))
        ]
    return Text("\n").join(lines)


class _LibraryWarnings(logging.Handler):
    """Says the library's warnings from ``modules`` on stderr (``warning: ...``), which the command does not report
    itself: a stream's (a rate not kept, an ID silent to the watch read: without them a monitor asked for 100 Hz
    ran at 40 with not a word why), a robot's safety watch's (a guarded joint whose telemetry does not read)."""

    def __init__(self, modules: frozenset[str]) -> None:
        super().__init__(logging.WARNING)
        self.modules = modules

    def filter(self, record: logging.LogRecord) -> bool:
        return record.module in self.modules and super().filter(record)

    def emit(self, record: logging.LogRecord) -> None:
        # sys.stderr as it is now: while a live view runs, its proxy puts the line above the view (rich's own
        # stderr console would write past it, and the view's next redraw would overwrite the line).  Wrapped at
        # words on a terminal as the command's own warnings are (the proxy writes through the view's console).
        try:
            said = fitted_to(
                out if isinstance(sys.stderr, FileProxy) else err, Text("warning: "), Text(record.getMessage())
            )
            sys.stderr.write(f"{said.plain}\n")
            sys.stderr.flush()
        except Exception:  # (a log record must never end the command)
            self.handleError(record)


@contextlib.contextmanager
def library_warnings_said(*modules: str) -> Iterator[None]:
    """Within: the library's warnings from ``modules`` (``"stream"``, ``"safety"``) are said on stderr, where its
    records are otherwise quiet (without -v, which logs them with everything else).  For the commands whose
    stream or robot is theirs to tell of (monitor and demo: ``"stream"``; play, teach and calibrate: ``"safety"``,
    their trips said in their own words); the configurator's live stream runs at its line's own pace by design,
    and its page shows warnings."""
    library = logging.getLogger("ics35_async")
    quiet = LIBRARY_QUIET in library.handlers
    handler = _LibraryWarnings(frozenset(modules))
    if quiet:
        library.addHandler(handler)
    try:
        yield
    finally:
        if quiet:
            library.removeHandler(handler)


def words_wrapped(text: Text, width: int) -> list[Text]:
    """``text`` in lines of at most ``width`` cells, broken between words (a word wider than that is broken where
    it must: a path, a URL), without the spaces at their ends."""
    lines = list(text.wrap(err, max(width, 1), overflow="fold"))
    for line in lines:
        line.rstrip()
    return lines or [Text()]


def question_text(question: str, answers: str) -> str:
    """``question`` and its ``answers`` (``[y/N]:``) as written to stderr, the answer to be typed after them.  On a
    terminal, the question wrapped at words to its width (the terminal cut it mid-word), ``answers`` on its last
    line with the question's last word at least (alone on a line, it read as a question of its own); into a log, one
    line (see :func:`say_labelled`)."""
    asked = f" {answers} "
    if not err.is_terminal:
        return question + asked
    width = err.width
    lines = [line.plain for line in words_wrapped(Text(question), width)]
    if cell_len(lines[-1]) + cell_len(asked) > width and " " in lines[-1]:
        head, word = lines[-1].rsplit(" ", 1)
        lines[-1:] = [head, word]
    return "\n".join(lines) + asked


def signed_tenths(value: float) -> str:
    """``+12.3``; a value that rounds to zero is ``+0.0``, never ``-0.0``."""
    return f"{round(value, 1) + 0.0:+.1f}"


def fmt_degrees(position: int) -> str:
    return f"{signed_tenths(units.position_to_degrees(position)):>7}°"


def current_json(raw: int) -> dict[str, Any]:
    c = units.current_from_raw(raw)
    return {"raw": raw, "magnitude": c.magnitude, "reverse": c.reverse}


def temperature_json(raw: int) -> dict[str, Any]:
    return {"raw": raw, "celsius_approx": round(units.temperature_to_celsius(raw), 1)}


def ids_text(ids: Sequence[int] | Iterable[int]) -> str:
    return ", ".join(str(i) for i in ids) or "none"


def ids_argument(ids: Iterable[int]) -> str:
    """``ids`` as the ID lists of the command line take them, runs of neighbours as ranges: ``2-4,9``."""
    return ",".join(f"{run[0]}-{run[-1]}" if len(run) > 1 else str(run[0]) for run in id_runs(ids))
