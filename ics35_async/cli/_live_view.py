"""What the live table of monitor and demo shows: positions, targets, telemetry, errors and the cycle rate."""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import Any

from rich import box
from rich.table import Table
from rich.text import Text

from .. import units
from ..frames import Frame
from ..policies import Joining
from ..stream import WATCH, Stream
from ._console import TitleInParts, current_json, signed_tenths, temperature_json
from ._telemetry import Telemetry

# The columns a terminal too narrow for the whole table goes without, in turn (from both halves of a row of two
# servos): the raw position (its angle stays), then the telemetry (a servo's trouble shows in its err), then
# demo's target.  The ID, its angle and its errors stay.
LEAVE_OUT = ("pos", "cur", "temp", "target°")
# Seconds a servo's coming back stays in the status line once it is back in the targets: a log prints a line a
# second, and a blend shorter than that would pass unsaid.
COMEBACK_SHOWN = 3.0


@dataclass
class LiveState:
    """Everything the table shows, updated per frame."""

    ids: list[int]
    title: TitleInParts
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
    rate_asked: float | None = None  # --rate (None: as fast as the line goes)
    answered_ever: set[int] = field(default_factory=set)
    # The other rates were searched as the IDs were asked, none answering (see _errors.at_another_rate): not again
    # at the end of a run in which none ever answered.
    other_rates_searched: bool = False
    no_position: dict[int, str] = field(default_factory=dict)  # IDs not streamed, and why
    stopped_by_signal: bool = False  # Ctrl-C, SIGTERM or SIGHUP (see _signals): the normal way to stop
    ended: bool = False  # the stream's frames are over (the time up, a stop signal, an error)
    freed: bool = False  # the free at the end reached every streamed servo (a whole cycle carried it)
    lost_at: float | None = None  # seconds in when the port was found lost, while it is (the bus reconnecting)
    reconnects: int = 0  # times the port came back
    window: deque[tuple[float, int]] = field(default_factory=lambda: deque(maxlen=400))
    # Servos that came back (from offline, or their lost port), what the status line says of each, and until when.
    comebacks: dict[int, tuple[str, float]] = field(default_factory=dict)

    def update(self, frame: Frame, elapsed: float, stream: Stream) -> None:
        self.lost_at = None  # (a frame is a cycle run: the port is there)
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

    def note_comebacks(self, joining: dict[int, Joining], elapsed: float) -> None:
        """Say of each servo of ``joining`` that came back what is done with it: read where it stands (the free
        command, or ICS 3.6's position read), then brought from there into the wave (see BlendIn), not thrown to the
        wave's target."""
        for sid, join in joining.items():
            if not join.came_back:
                continue
            if join.position is None:
                doing = f"reading where it stands ({'free' if join.frees else 'position read, torque left on'})"
            else:
                degrees = signed_tenths(units.position_to_degrees(join.position))
                doing = f"rejoining the wave from {join.position} ({degrees}°)"
            self.comebacks[sid] = (f"servo {sid} came back: {doing}", elapsed + COMEBACK_SHOWN)

    def port_lost(self, elapsed: float, telemetry: Telemetry) -> None:
        """The port is lost, the bus reconnecting (``--reconnect``): nothing read before says where the servos are
        now (a hand may move them, a power cut restart them), so no reading is shown until one is read again, and
        no rate, none being run."""
        if self.lost_at is None:
            self.lost_at = elapsed
        self.elapsed = elapsed
        self.positions.clear()
        self.window.clear()
        self.rate_now = 0.0
        telemetry.forget()

    def refresh_stats(self, stream: Stream) -> None:
        stats = stream.stats
        self.rate_avg = stats.rate_hz
        self.position_errors = dict(stats.failures)
        self.reconnects = stream.bus.stats.reconnects

    def summary(self, telemetry: Telemetry) -> str:
        # Before the first cycle has ended nothing is known: no servo is counted as answering yet.
        answering = len(self.ids) - len(self.failed | self.offline) if self.cycle else 0
        limit = f"/{self.seconds:g}" if self.seconds else ""
        errors = sum(self.position_errors.values()) + sum(telemetry.errors.values())
        head = f"t={self.elapsed:5.1f}{limit} s  cycle {self.cycle}"
        if self.lost_at is not None:
            lost = f"port lost for {self.elapsed - self.lost_at:.1f} s"
            waiting = not (self.ended or self.stopped_by_signal)  # (once stopping, it waits no more)
            return f"{head}  {lost}{': waiting for it to come back' if waiting else ''}  errors {errors}"
        # The rate asked beside the rate reached: "35.8 Hz" alone leaves the reader to remember whether it is short.
        asked = f" of {self.rate_asked:g}" if self.rate_asked is not None else ""
        # (the port's comings back, counted, so that a loose cable is seen also once it no longer is)
        back = f"  reconnects {self.reconnects}" if self.reconnects else ""
        news = "".join(f"  {said}" for said, until in self.comebacks.values() if until >= self.elapsed)
        return (
            f"{head}  rate {self.rate_now:5.1f}{asked} Hz (avg {self.rate_avg:5.1f})  "
            f"answering {answering}/{len(self.ids)}  errors {errors}{back}{news}"
        )

    def table(self, telemetry: Telemetry, with_targets: bool) -> Table:
        per_row = 2 if len(self.ids) > 16 else 1
        table = Table(
            title=self.title.whole, title_justify="left", box=box.SIMPLE_HEAD, pad_edge=False, collapse_padding=True
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

    def readings(self, sid: int, telemetry: Telemetry) -> tuple[int | None, int | None, int | None]:
        """Position, raw current and raw temperature to show for ``sid`` (None: none to show)."""
        # An offline servo's last readings no longer say what it does (a hand or gravity may move it): none shown;
        # nor any while the port is lost.
        if sid in self.offline or self.lost_at is not None:
            return None, None, None
        return self.positions.get(sid), telemetry.current.get(sid), telemetry.temperature.get(sid)

    def _cells(self, sid: int, telemetry: Telemetry, with_targets: bool) -> list[str | Text]:
        pos, cur, temp = self.readings(sid, telemetry)
        errors = self.position_errors.get(sid, 0) + telemetry.errors.get(sid, 0)
        if self.lost_at is not None:
            state: str | Text = Text("lost", style="red")
        elif sid in self.offline:
            state = Text("off", style="red")
        elif sid in self.failed:
            state = Text(f"{errors}!", style="yellow")
        else:
            state = str(errors)
        cells: list[str | Text] = [str(sid)]
        if with_targets:
            target = self.targets.get(sid)
            if target == WATCH:  # (read with ICS 3.6's position read: sent no target meanwhile)
                cells.append("-")
            elif not target:
                cells.append("free")
            else:
                cells.append(signed_tenths(units.position_to_degrees(target)))
        else:
            cells.append("-" if pos is None else str(pos))
        if sid in self.no_position:
            cells[-1] = Text("n/a", style="dim")
        cells += [
            "n/a" if sid in self.no_position else "-" if pos is None else signed_tenths(units.position_to_degrees(pos)),
            "-" if cur is None else f"{'-' if cur & 0x40 else ''}{cur & 0x3F}",
            "-" if temp is None else f"{units.temperature_to_celsius(temp):.0f}C",
            state,
        ]
        return cells

    def snapshot(self, telemetry: Telemetry) -> dict[str, Any]:
        # The raw current and temperature alone read as a servo at 127 degrees drawing 70 (a cool one with a
        # reverse current of 6): each goes with what it means, as in `ics35 get` and `info`.
        def servo(sid: int) -> dict[str, Any]:
            pos, cur, temp = self.readings(sid, telemetry)
            return {
                "position": pos,
                "current": None if cur is None else current_json(cur),
                "temperature": None if temp is None else temperature_json(temp),
                "errors": self.position_errors.get(sid, 0) + telemetry.errors.get(sid, 0),
                "offline": sid in self.offline,
                "no_position_because": self.no_position.get(sid),
            }

        return {
            "t": round(self.elapsed, 3),
            "cycle": self.cycle,
            "rate_hz": round(self.rate_now, 2),
            "rate_avg_hz": round(self.rate_avg, 2),
            "rate_asked_hz": self.rate_asked,
            "port_lost": self.lost_at is not None,
            "reconnects": self.reconnects,
            "servos": {str(sid): servo(sid) for sid in self.ids},
        }
