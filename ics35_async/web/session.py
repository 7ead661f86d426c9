"""The configurator's one line: the open bus, what a scan found, and every action a page asks for.

Each action is a call into the library's policies (scan, EEPROM plan and
write, backup, the guarded ID write) with the bus this session holds; the
web layer adds no rule of its own beyond refusing motion until a page has
switched it on.  Actions that reopen the port or must be alone on the line
(scan, EEPROM write, renumbering) take :attr:`LineSession.exclusive`; the
Line page's temperature/current reads skip a round while it is held.

With ``--robot`` the pages can also work on one of the robot's lines: the
session then uses the robot's own open bus (the robot keeps streaming on it)
and refuses what would fight the robot for its servos: moving or freeing
one, a live stream of its own, renumbering, another baud rate, and a write
that changes a servo's ID or rate (the robot file names both).
"""

from __future__ import annotations

import asyncio
import contextlib
import contextvars
import re
from collections.abc import AsyncIterator, Iterable, Iterator, Mapping
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

from .. import protocol, units
from ..bus import Bus, open_bus
from ..eeprom import BaudRate, Eeprom
from ..engine import State
from ..errors import (
    BadReply,
    BusClosed,
    IcsError,
    InvalidArgument,
    PartialReply,
    PortLost,
    ReplyError,
    ReplyTimeout,
    SerialPortError,
    UnsafeOperation,
    VerifyError,
    error_text,
)
from ..frames import STALE_AFTER_FAILED_READS
from ..policies import (
    ALL_IDS,
    EepromPlan,
    FoundServo,
    IdSurvey,
    NoReply,
    NoReplyCause,
    RateSearch,
    Refusal,
    ScanReport,
    ServoWriteReport,
    WriteOutcome,
    check_changes,
    cut_short_words,
    look_elsewhere,
    off_its_way,
    plan_eeprom_write,
    read_eeprom_agreed,
    read_position_without_freeing,
    reopening,
    scan,
    search_other_rates,
    survey_for_id_write,
    trying_rate,
    why_no_reply,
    write_eeprom_plans,
    write_lone_id,
)
from ..policies.eeprom_backup import (
    backup_changes,
    backup_document,
    backups_document,
    backups_in,
    port_lost_why,
    read_failed_why,
)
from ..policies.scan import rates_in_words
from ..protocol import Param
from ..protocol.wire import id_ranges
from ..servo import check_pulse_limits
from ..transports import carries_line_settings, same_port
from .config import LineConfig, said_on_the_page
from .edits import allowances, edit_of
from .live import LIVE_RATE_HZ, LiveView, read_health
from .traffic import TrafficLog
from .views import eeprom_view, plan_view, ram_view, result_view, survey_view

if TYPE_CHECKING:
    from .joints import RobotSession

# The RAM parameters a page may write, as `ics35 set` names them (read back: current and temperature
# are the measured values, not the limits written).
RAM_PARAMS = {
    "stretch": Param.STRETCH,
    "speed": Param.SPEED,
    "current_limit": Param.CURRENT,
    "temperature_limit": Param.TEMPERATURE,
}

# What the Servo page shows of a servo that reads no position without going free (ICS 3.5).
POSITION_AT_COMMAND = (
    "ICS 3.5: where the servo stood when the last command reached it, before it moved "
    "(it reads its position only by going free, so it is not read again)"
)


# Why the server switched a servo's motion off when the page that switched it on went (see page_gone).
PAGE_GONE = "the page that switched it on was closed or lost its connection to the server"
# A port missing as the Line page connects (see said_on_the_page): the line comes back by itself only once open.
MISSING_AT_CONNECT = (
    "the line reconnects by itself to a port lost once it is open, not to one missing as it opens: plug the adapter"
    " in, then press Connect on the Line page"
)


def said_at_connect(exc: BaseException) -> str:
    """Why a Connect failed, in the page's words (a misnamed port's says what it meant: see said_on_the_page)."""
    return said_on_the_page(exc, MISSING_AT_CONNECT)


# A page's name for itself (see page_came), as long as it may be.
PAGE_NAME_MAX = 64


# How long Hold here waits at least for the live stream to read a servo it carries (a frame after the press);
# longer where two of the stream's cycles may take longer (Stream.longest_cycle).
HOLD_READ_WAIT = 2.0


# The line a request was last handed (:meth:`LineSession._quiet`) in the task that runs it, and its rate then:
# a servo that did not answer there is looked for on that line only (:meth:`LineSession.no_reply`).
_ASKED_ON: contextvars.ContextVar[tuple[Bus, int] | None] = contextvars.ContextVar("asked_on", default=None)


class JogFreedServo(UnsafeOperation):
    """A jog refused after it went out: its reply showed the servo off its way (see ``off_its_way``), so the
    servo was freed; ``position`` is where the free's reply says it stands (the page shows it free there)."""

    def __init__(self, message: str, position: int) -> None:
        super().__init__(message)
        self.position = position


@dataclass
class ScanProgress:
    done: int = 0
    total: int = 0
    running: bool = False


def _lost_mid_write(report: ServoWriteReport, who: str | None = None) -> IcsError:
    """The error of a write that failed (``report``'s): a port lost while the write was on its way, or before its
    read-back, says what the servo may hold and that it is read once the line is back (the write's own words
    are the command line's); a write that went out unanswered gets a note saying so; any other failure as it
    is.  ``who``: the servo in those words (default "servo N"; the Many servos page's rows name it already)."""
    error = report.error
    assert error is not None
    who = who or f"servo {report.plan.servo_id}"
    if not isinstance(error, PortLost) and report.outcome is WriteOutcome.UNKNOWN:
        # Unanswered or answered garbled: the page's words on it are why a servo would not answer (or why two
        # would answer at once); the write went out all the same (an error_response adds a note to them).
        error.add_note(f"the write may have reached {who} (it went out; no answer confirmed it): read it first")
        return error
    if not isinstance(error, PortLost) or report.outcome not in (WriteOutcome.UNKNOWN, WriteOutcome.UNVERIFIED):
        return error
    if report.outcome is WriteOutcome.UNKNOWN:
        what = f"as the EEPROM write went out: the write may have reached {who}"
    else:
        what = f"after {who} acknowledged the EEPROM write, before its read-back: written, not verified"
    return PortLost(f"{error_text(error)} {what}; read it once the line is back")


def _how_far(report: ServoWriteReport | None) -> dict[str, bool]:
    """What a Many servos row says of a write that failed (``report``, None if it failed before the write went out)
    beyond "failed", as its words do: it may be written (the port lost, or no answer, as it went) or it is
    (acknowledged, then the port lost before its read-back)."""
    if report is None:
        return {}
    if report.outcome is WriteOutcome.UNKNOWN:
        return {"maybe_written": True}
    if report.outcome is WriteOutcome.UNVERIFIED:
        return {"written": True}
    return {}


class LineSession:
    """The line the pages work on (one per server)."""

    def __init__(self, config: LineConfig) -> None:
        self.config = config
        self.bus: Bus | None = None
        self.error: str | None = None  # why the last connect failed
        # Many servos' last Apply (its IDs, running or its outcome): a page reloaded while it ran, or another tab,
        # shows what it did (the servos were written whether a page heard the answer or not)
        self.many_last: dict[str, Any] | None = None
        self.found: list[FoundServo] = []
        self.progress = ScanProgress()
        self.searching: str | None = None  # the rate a search of the other rates tries now, in words (its on_rate)
        self._tried: int | None = None  # the other rate that search tried before it (nothing answered there)
        self.exclusive = asyncio.Lock()
        self.traffic = TrafficLog()
        self.live: LiveView | None = None
        self.telemetry: dict[int, dict[str, Any]] = {}
        self.motion_enabled: set[int] = set()  # servos a page switched motion on for
        # Counts the changes of motion on or off (in the status and in the answer to a page's switch): the
        # status pushed to a page and the answer travel apart, and a page takes a status counting fewer than
        # its answer for one from before it (it would untick a switch the server has just switched on).
        self.motion_switches = 0
        self._motion_line: tuple[Bus, int] | None = None  # the bus and its reconnections when motion went on
        self.motion_off: dict[int, str] = {}  # servos whose motion the server switched off, and why
        # The pages connected now (their WebSocket open, see page_came), by the name each gives itself, and the
        # page that switched each servo's motion on: once that page is gone its motion goes off, as when it is left.
        self._pages: dict[str, int] = {}
        self._motion_page: dict[int, str] = {}
        # Servos a page left holding (Hold, enable motion, a jog): their target, and the line it was sent on
        # (a live plot keeps them held rather than freeing them; one held before a lost port, or before it
        # stopped answering, None, is in doubt).
        self.holding: dict[int, tuple[int, tuple[Bus, int] | None]] = {}
        # Where each servo stood as a page's last command to it (Hold, a jog) came: its reply (see off_its_way).
        self._stood: dict[int, int] = {}
        # The holds of the ports worked on before (their servos stay holding): given back, in doubt, when the
        # pages come back to that port (see _switch_to).
        self._holds_elsewhere: dict[str, dict[int, int]] = {}
        self._limits: dict[int, tuple[int, int]] = {}
        self._looked: dict[tuple[int, int], NoReply] = {}  # (ID, the line's rate): what the other rates told
        self.robot: RobotSession | None = None  # the robot `ics35 web --robot` serves, if any
        self.robot_line: str | None = None  # the robot's line the pages work on (its bus is the robot's)
        # The robot's line the pages were to start on, its robot not open at the start: they stand in on another
        # port until Reconnect opens the robot, and go to that line then, unless a port was chosen meanwhile.
        self.robot_line_to_come: str | None = None

    # ------------------------------------------------------------------ the line

    def _motion_off_if_line_lost(self) -> None:
        """Switch motion off for every servo once the port was lost since it was switched on: the servos'
        supply may have gone with it, and a servo that restarted is free, somewhere else; a jog from its
        old target would throw it there.  Switched on again, it holds where it stands."""
        bus = self.bus
        if self.motion_enabled and (bus is None or bus.state is State.LOST or self._line_now() != self._motion_line):
            why = "the port was lost (the servo may have restarted, free and elsewhere)"
            self._switch_motion_off(self.motion_enabled, why)

    def _switch_motion_off(self, ids: Iterable[int], why: str) -> None:
        """Motion off for ``ids`` (those that had it) by the server, for ``why``: a jog is refused with it, and
        the page unticks its switch (status ``motion_off``); switched on again, the servo holds where it stands."""
        for sid in [i for i in ids if i in self.motion_enabled]:
            self.motion_enabled.discard(sid)
            self._motion_page.pop(sid, None)
            self.motion_switches += 1
            self.motion_off[sid] = why

    def lost_touch(
        self, ids: Iterable[int], why: str = "it stopped answering (it may have restarted, free and elsewhere)"
    ) -> None:
        """``ids`` did not answer (a request, a telemetry read, the live stream): a servo that restarted meanwhile
        (its cable or supply) is free, somewhere else.  Its motion goes off (a jog from its old target would throw
        it there) and the hold a page left it in is in doubt (a live plot would send it that target)."""
        ids = [i for i in ids if i in self.holding or i in self.motion_enabled]
        for sid in ids:
            if sid in self.holding:
                self.holding[sid] = (self.holding[sid][0], None)  # (held on no line: in doubt, see _holding_split)
        self._switch_motion_off(ids, why)

    def answered_garbled(self, exc: BadReply | PartialReply) -> str:
        """A servo's answer came back garbled (``exc``): the page's words for it.  Most often a second servo
        answers at its ID too (a new one, ID 0 as they all come, plugged in beside it): a jog would move both,
        the other from wherever it is, so its motion goes off and its hold is in doubt, as when it stops
        answering (see lost_touch); switched on again, it is read first, and refused while the answers stay
        garbled."""
        sid = exc.servo_id
        if sid is None:  # (the ID command addresses the whole line)
            return error_text(exc)
        self.lost_touch([sid], f"it answered garbled (two servos sharing ID {sid}?)")
        return (
            f"{error_text(exc)}: a garbled answer: two servos sharing ID {sid} answer at once (new servos all have "
            "ID 0: connect one at a time and renumber it on the ID and baud page), or noise on the line"
        )

    def _lost_touch_in_live(self) -> None:
        """The live stream's servos that went offline, or came back held, since they were held (see lost_touch)."""
        live = self.live
        if live is not None and (self.holding or self.motion_enabled):
            self.lost_touch(live.stream.offline | live.stream.held.keys())

    def _line_now(self) -> tuple[Bus, int] | None:
        bus = self.bus
        return None if bus is None else (bus, bus.stats.reconnects)

    def status(self) -> dict[str, Any]:
        self._motion_off_if_line_lost()
        self._lost_touch_in_live()
        bus = self.bus
        state = "closed" if bus is None else bus.state.value
        error = self.error
        if error is None:
            error = self._robot_stopped()
        return {
            "port": self.config.port,
            "baud": self.config.baud,
            "simulator": self.config.is_sim,
            "connected": bus is not None and bus.is_open and self._robot_stopped() is None,
            "state": state,
            "lost": bus is not None and bus.state is State.LOST,
            "error": error,
            "live": None if self.live is None else list(self.live.ids),
            "scanning": self.progress.running,
            "searching": self.searching,
            "robot_line": self.robot_line,
            "robot": None if self.robot is None else self.robot.lines_view(),
            "motion_off": {str(k): v for k, v in sorted(self.motion_off.items())},  # (the page unticks them)
            "motion_on": sorted(self.motion_enabled),  # (a page whose switch says on for another unticks it)
            "motion_switches": self.motion_switches,
        }

    async def connect(self, port: str | None = None, baud: int | None = None) -> dict[str, Any]:
        """Open the line ``port`` at ``baud`` (each: the one open now if None); a refused one raises, its
        error (with hints) also kept for :meth:`status`.

        Another port opens before the open one closes, so a refused one leaves the line that worked;
        the same device (another baud rate, or another name for it) cannot be open twice: it closes
        first.  A port that is one of the robot's lines is that line (:meth:`use_robot_line`): the
        robot holds it open.
        """
        config = self.config
        if self.robot is not None and isinstance(port, str):
            named = self.robot.line_named_by_port(port.strip())
            if named is not None and baud in (None, named.baudrate):
                return await self.use_robot_line(named.name)
        if port is not None:
            if not isinstance(port, str) or not port.strip():
                raise InvalidArgument("name a port (see the list) or sim://")
            config = replace(config, port=port.strip())
        if baud is not None:
            config = replace(config, baud=int(BaudRate.parse(baud)))
        async with self.exclusive:
            same = self.robot_line is None and same_port(config.url, self.config.url)
            if same or self.bus is None:
                # The same port closed and opened again: its servos' holds are in doubt, not forgotten (see
                # disconnect); the servos of another port were never held here.
                await self.disconnect(keep_holds=same)
                self._switch_to(config)
            bus = self._open(config.baud, config)
            try:
                await bus.open()
            except (OSError, InvalidArgument) as exc:
                if self.bus is None or not self.bus.is_open:  # (where a line stays open, its answer says it alone)
                    self.error = said_at_connect(exc)
                raise
            if self.config is not config:  # another port, open now: the old one goes
                await self.disconnect()
                self._switch_to(config)
            self.bus = bus
            self.error = None
            self._looked = {}  # a Connect looks for a silent servo at the other rates again
            self.robot_line_to_come = None  # (a port chosen: the pages stay there)
        return self.status()

    def _switch_to(self, config: LineConfig) -> None:
        """Work on the line ``config`` from now on: what was found on the old one is forgotten, and the
        simulated line the pages named for an unnamed ``sim://`` too (see LineConfig.url)."""
        if not same_port(config.url, self.config.url):
            back = next((url for url in self._holds_elsewhere if same_port(url, config.url)), None)
            held = self._holds_elsewhere.pop(back, {}) if back is not None else {}
            self.holding = {sid: (target, None) for sid, target in held.items()}  # (in doubt: see lost_touch)
        if config.url != self.config.url:
            self._forget_simulator()
        self.config = config
        self.found = []
        self.telemetry = {}
        self._limits = {}
        self._looked = {}

    async def use_robot_line(self, name: str) -> dict[str, Any]:
        """Work on the robot's line ``name``: its bus, open and streamed by the robot, not reopened here."""
        if self.robot is None:
            raise InvalidArgument("no robot: start with `ics35 web --robot ROBOT.toml`")
        bus, spec = self.robot.line(name)
        async with self.exclusive:
            await self.disconnect()
            self._switch_to(replace(self.config, port=spec.port, baud=spec.baudrate))
            self.bus = bus
            self.robot_line = name
            self.robot_line_to_come = None
            self.error = None
        return self.status()

    def _refuse_on_robot_line(self, what: str, instead: str) -> None:
        if self.robot_line is not None:
            raise UnsafeOperation(f"{what}: the robot streams its line {self.robot_line!r}; {instead}")

    def _refuse_joint_motion(self, servo_id: int) -> None:
        if self.robot_line is not None:
            joint = self.robot.joint_at(self.robot_line, servo_id) if self.robot is not None else None
            who = f"servo {servo_id} is the robot's joint {joint}" if joint else f"servo {servo_id} is on it"
            self._refuse_on_robot_line(who, "move or free it on the Robot page")

    def _open(self, baud: int, config: LineConfig | None = None) -> Bus:
        c = self.config if config is None else config
        return open_bus(
            c.url,
            baudrate=baud,
            echo=c.echo,
            transport=c.transport,
            direction=c.direction,
            retries=c.retries,
            reconnect=True,
            adapter_latency=c.adapter_latency,
        )

    async def disconnect(self, *, keep_holds: bool = False) -> None:
        """Close the line (a robot's stays open); motion goes off.  With ``keep_holds`` (the same port is opened
        again) the servos pages held are kept in doubt: a servo that still holds would go limp in a live plot
        that forgot it was held, and one that restarted meanwhile would be thrown to its old target; the plot
        refuses them by name until their Servo page frees or holds them.  Without it (another port) they are put
        aside for this port, and come back in doubt with it (see _switch_to)."""
        await self.stop_live()
        bus, self.bus = self.bus, None
        borrowed, self.robot_line = self.robot_line, None
        if self.motion_enabled or self.motion_off:
            self.motion_switches += 1
        self.motion_enabled.clear()
        self._motion_page.clear()
        self.motion_off.clear()
        if keep_holds:
            self.holding = {sid: (target, None) for sid, (target, _) in self.holding.items()}
        else:  # (put aside: its servos stay holding, and come back in doubt with their port: see _switch_to)
            if self.holding:
                self._holds_elsewhere[self.config.url] = {sid: target for sid, (target, _) in self.holding.items()}
            self.holding = {}
        if bus is not None and borrowed is None:  # a robot's line stays the robot's
            await bus.aclose()

    async def close(self) -> None:
        await self.disconnect()
        self._forget_simulator()

    def _forget_simulator(self) -> None:
        """Close the simulated line the pages named for an unnamed ``sim://`` (see LineConfig.url), if any."""
        if self.config.is_sim and self.config.url != self.config.port:
            from .. import sim

            name, _ = sim.parse_url(self.config.url)  # (the name LineConfig.url gave it)
            with contextlib.suppress(KeyError):
                sim.named(str(name)).close()

    def line(self) -> Bus:
        if self.bus is None or not self.bus.is_open:
            # (why the last Connect failed, where it did: a port was chosen, and "choose a port" alone hid it)
            if self.error is not None and self.error.endswith(MISSING_AT_CONNECT):  # (it says what to do itself)
                raise BusClosed(f"not connected: {self.error}")
            why = "" if self.error is None else f"{self.error}; "
            raise BusClosed(f"not connected: {why}choose a port and press Connect on the Line page")
        stopped = self._robot_stopped()
        if stopped is not None:
            raise BusClosed(f"not connected: {stopped}")
        return self.bus

    def _robot_stopped(self) -> str | None:
        """Why the robot's line the pages work on is not theirs now, and the way back: the robot is not open (a
        line lost, this one or another).  The robot a lost line stopped keeps its other lines streaming until
        Reconnect (see RobotSession.free): the pages work on none of them meanwhile."""
        if self.robot_line is None or self.robot is None or self.robot.robot is not None:
            return None
        return f"{self.robot.error or 'the robot is not open'} (on the Robot page)"

    async def _line_at_its_rate(self) -> Bus:
        """The line, at the rate the page connected at (called holding :attr:`exclusive`).

        A scan or the search for a silent servo reopens the port at other rates and then at the line's
        own; when the port is lost meanwhile, that last reopen fails and the bus comes back by itself at
        the rate it had then.  It is put back at the line's rate here, where the line is handed out
        (PortLost while it is still away).
        """
        bus = self.line()
        if self.robot_line is None and bus.baudrate != self.config.baud:
            await bus.reopen(baudrate=self.config.baud)
        return bus

    @staticmethod
    async def _back_at(bus: Bus, baud: int) -> None:
        """``bus`` reopened at ``baud`` after a look at other rates (a scan, a search for a silent servo).

        A port lost meanwhile cannot be reopened now, and is left to come back by itself at the rate it was
        lost at (:meth:`_line_at_its_rate` puts it back where the line is next handed out): raised from here,
        the loss would take with it what the look found before it (a scan's servos, listed with the loss).
        """
        if bus.is_open and bus.baudrate != baud:
            with contextlib.suppress(PortLost):
                await bus.reopen(baudrate=baud)

    @contextlib.asynccontextmanager
    async def _quiet(self) -> AsyncIterator[Bus]:
        """The line at its own rate for one action: it waits while a scan (which reopens the port at
        other rates), an EEPROM write or a renumbering has the line."""
        async with self.exclusive:
            bus = await self._line_at_its_rate()
            _ASKED_ON.set((bus, bus.baudrate))
            yield bus

    # ------------------------------------------------------------------ scan

    async def scan(self, bauds: list[int] | None = None, ids: list[int] | None = None) -> dict[str, Any]:
        """Probe ``ids`` at ``bauds`` (policies.scan), then return the line to its own rate."""
        bauds = bauds or [self.config.baud]
        wanted = list(ALL_IDS) if ids is None else [protocol.check_id(i) for i in ids]
        checked = [int(BaudRate.parse(b)) for b in bauds]
        if checked != [self.config.baud]:
            self._refuse_on_robot_line("a scan at other baud rates", f"scan it at its own rate ({self.config.baud})")
        await self.stop_live()
        async with self.exclusive:
            bus = await self._line_at_its_rate()
            self._looked = {}  # the rates looked at anew: a servo found (or not) now is told so, not as before
            self.progress = ScanProgress(0, len(wanted) * len(checked), True)

            def step(n: int) -> None:
                self.progress.done += n

            try:
                report = await scan(reopening(bus), bauds=checked, ids=wanted, on_probe=step)
                search = await self._answered_elsewhere(bus, report, checked)
            finally:
                self.progress.running = False
                await self._back_at(bus, self.config.baud)
        # A line lost part-way: the servos found before it are listed all the same (nothing found is lost
        # work), with the loss, which the page says beside them (and the line's status, pushed, shows it lost).
        self.found = list(report.servos)
        for servo in report.servos:
            if servo.eeprom is not None:
                self._limits[servo.servo_id] = (servo.eeprom.pulse_limit_low, servo.eeprom.pulse_limit_high)
        return {
            "servos": [self.found_view(s) for s in self.found],
            "skipped": {str(b): why for b, why in report.skipped.items()},
            "garbled": [{"baud": b, "id": i, "error": str(e)} for b, i, e in report.garbled],
            "silent": report.silent,
            "echo_wrong": None if report.echo_evidence is None else str(report.echo_evidence),
            "lost": None if report.lost is None else str(report.lost),
            # Nothing here: the rate a device answers at, which the page offers; the rates looked at (in vain, when
            # nothing answers at any: the page says so, not to tick "every baud rate").
            "answers_at": search.found[0] if search.found else None,
            "rates_tried": list(search.tried),
        }

    async def _answered_elsewhere(self, bus: Bus, report: ScanReport, scanned: list[int]) -> RateSearch:
        """After a scan where nothing answered: the rates not scanned, and those a device answers the ID read at
        (policies.search_other_rates, as ``ics35 doctor`` looks), to reopen the line at; none tried when something
        answered, not even the echo came back (the adapter or its wiring, which no rate mends), or the other rates
        may not be tried on this line.  The port is left at the last rate tried (the scan's close puts it back)."""
        none = RateSearch(tuple(scanned))
        if report.servos or report.garbled or report.lost is not None:
            return none
        if (report.silent and self.config.echo) or self._other_rates_not_tried() is not None:
            return none
        try:
            with self._searching():
                return await search_other_rates(reopening(bus), scanned, on_rate=self._trying)
        except (IcsError, OSError):
            return none  # advice only: the scan's own outcome stands

    def _trying(self, baud: int) -> None:
        """A search of the other rates' progress (its ``on_rate``): said in the status the pages show, as the
        command line prints it (each rate may cost a whole reply allowance)."""
        self.searching = trying_rate(self.config.baud, baud, self._tried)
        self._tried = baud

    @contextlib.contextmanager
    def _searching(self) -> Iterator[None]:
        """Around a search of the other rates: once it has ended, the status no longer names a rate it tries."""
        self._tried = None
        try:
            yield
        finally:
            self.searching = None

    def found_view(self, servo: FoundServo) -> dict[str, Any]:
        return {
            "id": servo.servo_id,
            "baud": servo.baud,
            "answered_at": list(servo.answered_at),
            "baud_pending": servo.baud_pending,
            "eeprom_error": None if servo.eeprom_error is None else str(servo.eeprom_error),
            **self.telemetry.get(servo.servo_id, {}),
        }

    def servos_view(self) -> list[dict[str, Any]]:
        """The Line page's table: the servos found with their last reads, or, for those a live stream
        carries, the stream's newest position, temperature and current."""
        rows = [self.found_view(s) for s in self.found]
        live = self.live
        if live is None:
            return rows
        for row in rows:
            sid = row["id"]
            if sid not in live.ids:
                continue
            position = live.position(sid)
            row["position"] = None if position < 0 else position
            if position >= 0:
                row["telemetry_error"] = None  # answering the stream: a read that failed before it is old news
            row["position_note"] = "from the live stream" if position >= 0 else "not yet read by the live stream"
            # Its temperature and current are the stream's alone: the row's own reads stopped as it started, and
            # one the stream has none of (not read yet, or its reads failing: see LiveReadings) is not shown.
            for key in ("temperature", "temperature_c", "temperature_text", "current"):
                row.pop(key, None)
            if sid in live.temperature:
                row["temperature_c"], row["temperature"] = live.temperature[sid], None
                row["temperature_text"] = live.temperature_text[sid]
            if sid in live.current:
                row["current"] = live.current[sid]
        return rows

    async def read_telemetry(self) -> dict[int, dict[str, Any]]:
        """Temperature, current, protocol and (ICS 3.6) position of the servos found; skipped while busy.

        Nothing sent moves a servo or turns its torque off: the position is
        read only with ICS 3.6's position read (policies.position_read); an
        ICS 3.5 servo, which reads a position only by going free, shows none.
        """
        if self.exclusive.locked() or self.bus is None or not self.bus.is_open or self.live is not None:
            return self.telemetry
        async with self.exclusive:  # a scan that starts meanwhile waits for this round, not the other way
            await self._read_telemetry(await self._line_at_its_rate())
        return self.telemetry

    async def _read_telemetry(self, bus: Bus) -> None:
        for servo in list(self.found):
            sid = servo.servo_id
            if servo.baud != bus.baudrate:
                continue
            try:
                health = await read_health(bus, sid)
                reading = await read_position_without_freeing(bus.servo(sid))
            except ReplyError as exc:
                # (a garbled answer is told as such, not as silence: the page sends a person to the power for that)
                garbled = isinstance(exc, (BadReply, PartialReply))
                said = self.answered_garbled(exc) if isinstance(exc, (BadReply, PartialReply)) else str(exc)
                row = self.telemetry.get(sid, {})
                failed = row.get("failed_reads", 0) + 1
                if failed < STALE_AFTER_FAILED_READS and row and row.get("telemetry_error") is None:
                    # One round that failed leaves the round before's readings standing, as the live views keep a
                    # reading (see frames.STALE_AFTER_FAILED_READS): a servo missing a read now and then does not
                    # flicker "not answering".  Its motion still goes off at once (lost_touch: it may have restarted).
                    self.telemetry[sid] = {**row, "failed_reads": failed}
                else:
                    self.telemetry[sid] = {**row, "telemetry_error": said, "garbled": garbled, "failed_reads": failed}
                if isinstance(exc, ReplyTimeout):
                    self.lost_touch([sid])
                continue
            self.telemetry[sid] = {
                "garbled": False,
                **health,
                "protocol": reading.protocol,
                "position": reading.position,
                "position_note": reading.why,
                "telemetry_error": None,
                "failed_reads": 0,
            }

    # ------------------------------------------------------------------ a servo that did not answer

    async def no_reply(self, exc: ReplyTimeout, *, look_at_other_rates: bool = False) -> dict[str, Any]:
        """The page's words for a command to one servo that went unanswered (policies.why_no_reply), and
        ``answers_at``: the rate the servo answers at instead, which the page offers to reopen the line at.

        Other rates are looked for (``look_at_other_rates``) as a scan does, holding the line and reopening
        the port at each, then at the line's own rate again; not while a robot streams on the line or a
        live plot runs on it (each would lose its line meanwhile), nor on a link that does not carry the
        baud rate.  Only on the line the command went unanswered on, at its rate: a Connect that ran in
        between leaves the words plain.  What the other rates told of a servo is kept until the next
        Connect: it is told again, not looked for again.
        """
        asked = _ASKED_ON.get()
        if exc.servo_id is None or asked is None:
            return {"error": error_text(exc)}
        bus, baud = asked
        key = (exc.servo_id, baud)
        looked_before = False
        async with self.exclusive:
            if self.bus is bus and not bus.is_open:
                return {"error": error_text(exc)}
            if self.bus is not bus or self.config.baud != baud:
                finding = NoReply(NoReplyCause.UNKNOWN, exc.servo_id, baud)
                not_tried: str | None = (
                    "the line has been reopened since, so it was not looked for at the other rates: read it again"
                )
            else:
                looked = self._looked.get(key)
                not_tried = self._other_rates_not_tried()
                if not_tried is None and not look_at_other_rates:
                    not_tried = (
                        "the Servo page looks for it at the other baud rates when it reads its EEPROM "
                        "(Read on the Servo page)"
                    )
                search = not_tried is None and looked is None
                try:
                    opener, echo = reopening(bus), self.config.echo
                    with self._searching():
                        finding = await why_no_reply(
                            exc, opener, baud, echo=echo, other_rates=search, on_rate=self._trying
                        )
                finally:
                    await self._back_at(bus, baud)
                if finding.rates_tried and not finding.not_searched:  # (a rate not asked: looked for again)
                    self._looked[key] = finding
                elif looked is not None and finding.cause is NoReplyCause.UNKNOWN:
                    finding, not_tried, looked_before = looked, None, True
        answer: dict[str, Any] = {"error": self._no_reply_words(finding, not_tried, looked_before=looked_before)}
        if finding.cause is NoReplyCause.OTHER_RATE:
            answer["answers_at"] = finding.rates[0]
        return answer

    def _other_rates_not_tried(self) -> str | None:
        """Why the other rates may not be tried on this line now (None: they may)."""
        if self.robot_line is not None:
            return (
                f"the page does not try other rates on the robot's line {self.robot_line!r} (the robot streams "
                "on it): find its rate with the robot stopped (`ics35 scan` on that port)"
            )
        if self.live is not None:
            return (
                "other rates are not tried while the live plot runs (the port would be reopened under it): "
                "stop the live plot and try again to look for it at the other rates"
            )
        if not carries_line_settings(self.config.url):
            return (
                f"{self.config.port} does not carry the baud rate (the far end keeps its own): set the bridge's "
                "serial side to the servo's rate"
            )
        return None

    def _no_reply_words(self, finding: NoReply, not_tried: str | None, *, looked_before: bool = False) -> str:
        sid, baud, port = finding.servo_id, f"{finding.baud:,}", self.config.port
        if finding.cause is NoReplyCause.NO_ECHO:
            return (
                f"no echo and no reply from {port}: the bytes sent never came back; check the adapter is an ICS "
                "adapter (TX looped back to RX) and its cable is plugged in (an interface that does not echo "
                "what it sends needs `ics35 web --no-echo`)"
            )
        if finding.cause is NoReplyCause.LONG_REPLY_LOST:
            return (
                f"ID {sid} answers short reads at {baud} baud, but not the EEPROM read: its reply, the longest "
                "(66 bytes), is lost on the way (an adapter or bridge that drops long replies; a longer "
                "`ics35 web --timeout` may do), or the device is not an ICS 3.5 servo"
            )
        if finding.cause is NoReplyCause.OTHER_RATE:
            return (
                f"ID {sid} did not answer at {baud} baud. ID {sid} answers at {finding.rates[0]:,} baud; "
                "reopen the line at that rate (Baud, then Connect, on the Line page)"
            )
        checks = "check its power (6-12 V on the servo line, not just USB), the wiring and its ID"
        if not_tried is not None:
            return f"ID {sid} did not answer at {baud} baud; {not_tried}; else {checks}"
        if finding.not_searched:
            # (not "at no other baud rate": a rate the search could not ask, the port lost there, said apart)
            nor = f", nor at {rates_in_words(finding.searched, grouped=True)} baud" if finding.searched else ""
            untried = f"{rates_in_words(finding.not_searched, 'and', grouped=True)} baud could not be tried"
            return f"ID {sid} did not answer on {port} at {baud} baud{nor} ({untried}): {checks}"
        if looked_before:
            return (
                f"ID {sid} did not answer on {port} at {baud} baud, and at no other baud rate when it was looked for "
                f"since the line was connected (Connect on the Line page looks again): {checks}"
            )
        return f"ID {sid} did not answer on {port} at {baud} baud, and at no other baud rate: {checks}"

    # ------------------------------------------------------------------ one servo's EEPROM

    async def read_eeprom(self, servo_id: int) -> dict[str, Any]:
        async with self._quiet() as bus:
            image: Eeprom = await bus.request(protocol.ReadEeprom(protocol.check_id(servo_id)))
        self._limits[servo_id] = (image.pulse_limit_low, image.pulse_limit_high)
        return eeprom_view(image)

    async def read_ram(self, servo_id: int) -> dict[str, Any]:
        protocol.check_id(servo_id)
        values = {}
        async with self._quiet() as bus:
            for param in (Param.STRETCH, Param.SPEED, Param.CURRENT, Param.TEMPERATURE):
                values[param.name.lower()] = await bus.request(protocol.ReadParam(servo_id, param))
        return ram_view(values)

    async def write_ram(self, servo_id: int, name: str, value: int) -> int:
        """Write a RAM parameter (lost at power-off); the command checks the value's range."""
        param = RAM_PARAMS.get(name)
        if param is None:
            raise InvalidArgument(f"RAM parameter {name!r}: one of {', '.join(RAM_PARAMS)}")
        command = protocol.WriteParam(protocol.check_id(servo_id), param, value)
        async with self._quiet() as bus:
            written: int = await bus.request(command)
        return written

    async def plan(self, servo_id: int, edit: Mapping[str, Any]) -> tuple[EepromPlan, dict[str, Any]]:
        async with self._quiet() as bus:
            return await self._plan(bus, servo_id, edit)

    async def _plan(self, bus: Bus, servo_id: int, edit: Mapping[str, Any]) -> tuple[EepromPlan, dict[str, Any]]:
        changes, set_flags, clear_flags, keep = edit_of(edit)
        plan = await plan_eeprom_write(
            bus, servo_id, changes, set_flags=set_flags, clear_flags=clear_flags, keep_read_only=keep
        )
        robot_line = self._robot_line_refusal(plan)
        if robot_line is not None:
            return plan, plan_view(plan, robot_line)
        # The library's reason, as it words it; what allows the write is the page's tick, not a program's keyword.
        why = plan.why_refused(**allowances(edit))
        return plan, plan_view(plan, None if why is None else why.reason, None if why is None else why.allowed_by)

    def _robot_line_refusal(self, plan: EepromPlan) -> str | None:
        if self.robot_line is None or not (plan.changes_id or plan.changes_baud):
            return None
        return (
            f"servo {plan.servo_id} is on the robot's line {self.robot_line!r}, whose file names its ID and the "
            "line's rate: change them with the robot stopped (start `ics35 web` on that port without --robot)"
        )

    async def write(self, servo_id: int, edit: Mapping[str, Any]) -> dict[str, Any]:
        """Plan and write ``edit`` (policies.eeprom_write: refusals, the re-read before, the read-back after).

        ``edit["before"]`` (the raw image the person saw the diff against) must
        still be the servo's, so what is written is what was shown.  A port lost
        with the write on its way, or before its read-back, raises a ``PortLost``
        saying what the servo may hold and to read it once the line is back.
        """
        return self._written(servo_id, await self._write_report(servo_id, edit))

    async def _write_report(self, servo_id: int, edit: Mapping[str, Any]) -> ServoWriteReport:
        """How far :meth:`write`'s write got (refusals raised, nothing written)."""
        async with self._quiet() as bus:
            self._looked = {}  # a write may move a servo to another ID or rate: look for silent ones anew
            plan, _ = await self._plan(bus, servo_id, edit)
            seen = edit.get("before")
            if seen is not None and seen != plan.before.to_bytes().hex():
                # Most often a write of these very values that reached it, its answer lost with the port.
                raise UnsafeOperation(
                    f"servo {servo_id}'s EEPROM changed since the diff was shown (a write may have reached it, or "
                    "another program wrote to it): press Read to see what it holds now, then show the changes "
                    "again; nothing was written"
                )
            refusal = self._robot_line_refusal(plan)
            if refusal:
                raise UnsafeOperation(f"{refusal}; nothing was written")
            # The batch's report (of one) says how far the write got when it fails: a port lost with the write
            # on its way is told as a write that may have reached the servo, not as a bare "port lost".
            allowed = allowances(edit)
            [report] = await write_eeprom_plans(
                bus,
                [plan],
                allow_baud_change=allowed["allow_baud_change"],
                allow_id_change=allowed["allow_id_change"],
            )
            return report

    def _written(self, servo_id: int, report: ServoWriteReport, who: str | None = None) -> dict[str, Any]:
        """The page's view of a finished write (``report``), the Line page's list brought up to date with it; a
        failed one raised in the page's words (see _lost_mid_write, and ``who`` there)."""
        if report.error is not None:
            raise _lost_mid_write(report, who) from report.error
        assert report.result is not None  # (a report without an error is a finished write's)
        plan, result = report.plan, report.result
        after = result.read_back or plan.after
        if plan.changes_id:
            self._limits.pop(servo_id, None)
            if servo_id in self.motion_enabled:
                self.motion_switches += 1
            self.motion_enabled.discard(servo_id)
            self._held_now_at(servo_id, after.servo_id)
        self._limits[after.servo_id] = (after.pulse_limit_low, after.pulse_limit_high)
        if result.written:
            self._found_now(servo_id, after.servo_id, after)
        return result_view(result)

    def _found_now(self, old_id: int, new_id: int, image: Eeprom | None = None) -> None:
        """The Line page's list after a write to ``old_id``: listed (and read) at ``new_id`` with the EEPROM
        ``image`` it has now; the old ID, where nothing answers any more, is not read again."""
        baud = self.config.baud  # (the write went at the line's rate: a servo listed at another is another)
        if not any(s.servo_id == old_id and s.baud == baud for s in self.found):
            return
        found: list[FoundServo] = []
        for servo in self.found:
            if servo.baud == baud and servo.servo_id == old_id:
                eeprom = image or (None if servo.eeprom is None else servo.eeprom.replace(servo_id=new_id))
                found.append(replace(servo, servo_id=new_id, eeprom=eeprom))
            elif not (servo.baud == baud and servo.servo_id == new_id):  # (one listed there is gone since the
                found.append(servo)  # scan: the write is refused while new_id answers)
        self.found = sorted(found, key=lambda s: (s.servo_id, s.baud))  # (in ID order, as a scan lists them)
        if old_id != new_id:
            self.telemetry.pop(old_id, None)
            self.telemetry.pop(new_id, None)

    async def backup(self, servo_id: int) -> dict[str, Any]:
        async with self._quiet() as bus:
            # Read until two reads agree, as `ics35 eeprom dump` reads the same file: a reply carries no checksum,
            # and one flipped bit would be a valid-looking, wrong backup.
            image = await read_eeprom_agreed(bus, protocol.check_id(servo_id))
            return backup_document(image, servo_id, baud=bus.baudrate, port=self.config.port)

    async def backup_many(self, ids: list[Any]) -> dict[str, Any]:
        """The backups of ``ids``, each read as :meth:`backup` reads one, in one document (policies.eeprom_backup's
        backups_document), with the servos not saved and why in the file's words (policies.eeprom_backup's, as
        ``ics35 eeprom dump IDS -o FILE.json`` writes them).

        A servo that does not answer, or answers garbled, is left out and the others are read; a lost line ends
        the reading, the servo it was lost at and those after it "not read" (a port back half-way would have read
        them at another moment with no word of it): what was read before is in the document all the same."""
        checked = list(dict.fromkeys(protocol.check_id(i) for i in ids))  # (each once: a file holds one per servo)
        self.line()  # (no line open: said once, not "lost at servo 1" for the others)
        saved: list[dict[str, Any]] = []
        not_saved: dict[int, str] = {}
        for k, sid in enumerate(checked):
            try:
                saved.append(await self.backup(sid))
            except ReplyError as exc:  # (a ReplyTimeout is an OSError too: this servo's, not the line's)
                not_saved[sid] = read_failed_why(exc, self.config.baud, echo=self.config.echo)
                if isinstance(exc, ReplyTimeout):
                    self.lost_touch([sid])
            except (PortLost, BusClosed, SerialPortError, OSError):
                not_saved.update(dict.fromkeys(checked[k:], port_lost_why(sid)))
                break
        return backups_document(saved, not_saved)

    def restore_edit(self, doc: object, servo_id: int, *, restore_id: bool, keep_baud: bool = False) -> dict[str, Any]:
        """The edit a backup asks for servo ``servo_id`` (policies.eeprom_backup's checks; from a file of several
        servos' backups, the one saved from ``servo_id``), for :meth:`plan` and :meth:`write`; ``keep_baud``: all
        but the backup's baud rate (the servo stays at the rate the line reaches it at)."""
        backups = backups_in(doc)
        backup = backups.backup_for(servo_id)
        changes = backup_changes(backup, restore_id=restore_id, keep_baud=keep_baud)
        # Restoring the saved ID is what "restore its ID" asks for; otherwise the ID is not in the changes.  The
        # backup's read-only flags are another moment's state: the servo keeps its own (the plan names them).
        return {
            "changes": changes.fields,
            "saved_id": changes.saved_id,
            # (which of them: the page says, the IDs as ranges)
            "file_holds": id_ranges(backups.servos) if backups.several else None,
            "allow_id_change": restore_id,
            "keep_read_only": True,
        }

    async def apply_to_many(self, ids: list[Any], edit: Mapping[str, Any]) -> list[dict[str, Any]]:
        """The same edit (a profile of chosen fields) written to each servo in turn; an outcome per servo.

        A failure's words name no servo (the page lists the servos that share them once, not the same news
        per servo); a lost line ends the run, the servos after it ``not_tried`` (a port back half-way would
        have written some of them and not the others)."""
        checked = [protocol.check_id(i) for i in ids]
        profile = {k: v for k, v in edit.items() if k in ("changes", "set_flags", "clear_flags")}
        # A value out of range is the same for every servo: refused once, before any is asked (not once a servo).
        changes, set_flags, clear_flags, keep = edit_of(profile)
        check_changes(changes, set_flags=set_flags, clear_flags=clear_flags, keep_read_only=keep)
        self.line()  # (no line open: said once, not "lost at servo 1" for the others)
        results: list[dict[str, Any]] = []
        self.many_last = {"ids": checked, "running": True, "results": results}
        try:
            await self._apply_each(checked, profile, results)
        finally:
            self.many_last = {"ids": checked, "running": False, "results": results}
        return results

    async def _apply_each(self, checked: list[int], profile: Mapping[str, Any], results: list[dict[str, Any]]) -> None:
        """:meth:`apply_to_many`'s writes, each servo's outcome added to ``results`` as it comes."""
        for k, sid in enumerate(checked):
            report: ServoWriteReport | None = None  # (None: it failed before the write went out)
            try:
                report = await self._write_report(sid, profile)
                results.append({"id": sid, **self._written(sid, report, who="it")})  # (its row names it)
            except ReplyError as exc:  # (a ReplyTimeout is an OSError too: this servo's, not the line's)
                words = self._many_words(exc)
                results.append({"id": sid, "error": words, "kind": type(exc).__name__, **_how_far(report)})
                if isinstance(exc, ReplyTimeout):
                    self.lost_touch([sid])
            except (PortLost, BusClosed, SerialPortError, OSError) as exc:
                results.append({"id": sid, "error": error_text(exc), "kind": type(exc).__name__, **_how_far(report)})
                rest = f"not tried: the line was lost at servo {sid}; apply again once it is back"
                results.extend(
                    {"id": i, "error": rest, "kind": "NotTried", "not_tried": True} for i in checked[k + 1 :]
                )
                break
            except VerifyError as exc:  # (the write went out and was taken, or partly: never "failed")
                results.append({"id": sid, "error": self._many_words(exc), "kind": "VerifyError", "written": True})
            except IcsError as exc:
                results.append({"id": sid, "error": self._many_words(exc), "kind": type(exc).__name__})

    def _many_words(self, exc: IcsError) -> str:
        """``exc``'s words for the Many servos page's edits, naming no servo and showing no bytes (the Traffic page
        has them): "no reply" with what to check (policies.why_no_reply's checks that need nothing sent)."""
        if isinstance(exc, VerifyError):  # "servo 2 acknowledged the write, then ...": the row names the servo
            return re.sub(r"^servo \d+:? ", "", error_text(exc))
        if not isinstance(exc, ReplyError):
            return error_text(exc)  # (a refusal's words: the same for each servo the edit is refused for)
        if isinstance(exc, ReplyTimeout):
            if exc.command == "write_eeprom":  # (sent: the servo may have taken it; no read-back ran)
                return (
                    f"no reply to the EEPROM write at {self.config.baud:,} baud: it may or may not have been "
                    "written; open its Servo page to read what it has"
                )
            if self.config.echo and not exc.raw:
                return self._no_reply_words(NoReply(NoReplyCause.NO_ECHO, exc.servo_id, self.config.baud), None)
            return (
                f"no reply at {self.config.baud:,} baud, nothing written: check the power (6-12 V on the servo "
                "line, not just USB), the wiring and the ID; a servo's own page looks for it at the other baud rates"
            )
        what = exc.reason
        if exc.command == "write_eeprom":  # (garbled, but the write went out: the servo may have taken it)
            return (
                f"{what}; it may or may not have been written: open its Servo page to read what it has (the "
                "bytes are on the Traffic page)"
            )
        return f"{what}; nothing written (the bytes are on the Traffic page)"

    # ------------------------------------------------------------------ torque and motion

    async def free(self, servo_id: int) -> int | None:
        """Torque off; where the servo stood, or None for a streamed servo the stream has no reading of (one
        not answering, freed once it answers)."""
        self._refuse_joint_motion(servo_id)
        self._motion_goes_off(servo_id)
        self.holding.pop(servo_id, None)
        if self.live is not None and servo_id in self.live.ids:
            self.live.stream.free([servo_id])
            position = self.live.position(servo_id)
            return None if position < 0 else position  # (-1, the stream's "not read", is no position)
        async with self._quiet() as bus:
            return await bus.servo(protocol.check_id(servo_id)).free()

    async def hold(self, servo_id: int) -> int:
        """Torque on where the servo stands now: read by ICS 3.6's position read, which leaves its torque alone,
        or on an ICS 3.5 servo by the free command (the only way it tells), then held there."""
        protocol.check_id(servo_id)
        self._refuse_joint_motion(servo_id)
        live = self.live
        if live is not None and servo_id in live.ids:
            position = await self._position_read_now(live, servo_id)
            live.stream.set_target(servo_id, self.check_target(servo_id, position))
            self._holds(servo_id, position)
            return position
        async with self._quiet() as bus:
            servo = bus.servo(servo_id)
            # (A standing robot's joint under load sags while free, even between two commands: ICS 3.6 first.)
            reading = await read_position_without_freeing(servo, free_ics35=True)
            here = reading.position
            assert here is not None  # (free_ics35: read either way)
            if reading.how == "free":
                self.holding.pop(servo_id, None)  # (free now: held again only once the next command is sent)
            held = await servo.set_position(self.check_target(servo_id, here))
            self._holds(servo_id, here)
            self._stood[servo_id] = held
            return held

    async def _position_read_now(self, live: LiveView, servo_id: int) -> int:
        """Where the stream reads ``servo_id`` now, from a frame finished after this call.  Its newest frame
        may be from before a lost port (all the while it is away, and for a moment after it is back): a servo
        that restarted meanwhile, free and elsewhere, would be held there, thrown back."""
        stream = live.stream

        def refuse_unless_read() -> None:
            bus = self.bus
            if bus is None or bus.state is State.LOST:
                raise PortLost(f"the port is lost: servo {servo_id} is not held; hold it once the line is back")
            if servo_id in stream.held or servo_id in stream.offline:
                raise UnsafeOperation(
                    f"the live stream has no position of servo {servo_id} to hold it at: since the port came back "
                    "or it answered again, held with no command sent (it may have restarted, free and elsewhere), "
                    "or not answering; press Free to have the stream read it, then hold it"
                )

        refuse_unless_read()
        before = stream.latest
        after = -1 if before is None else before.cycle
        position = -1
        # A cycle or two (more after a reply went missing).  A long allowance makes a cycle long where IDs beside
        # it do not answer, each waiting its whole allowance until the stream takes it out: a fixed wait ran out
        # there, and a servo read all along was "not read yet".
        wait = max(HOLD_READ_WAIT, 2 * stream.longest_cycle())
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(wait):
                while position < 0:
                    frame = await stream.next_frame()
                    if frame.cycle > after:
                        position = frame.positions.get(servo_id, -1)
        refuse_unless_read()  # (lost, or back, while it waited)
        if position < 0:  # (a target from elsewhere would throw it there)
            raise UnsafeOperation(
                f"the live stream has no position of servo {servo_id} to hold it at: not read yet; "
                "press Free to have the stream read it, then hold it"
            )
        return position

    async def enable_motion(self, servo_id: int, page: object = None) -> int:
        """Switch motion on: read the limits, then hold the servo where it stands, so the first jog
        steps from there rather than jumping to wherever the slider happened to be.

        ``page``: the name of the page asking (see :meth:`page_came`), whose motion goes off once it is gone;
        a page not connected now is refused before anything is sent.  Without one (a script), motion stays on
        until it is switched off.
        """
        self._refuse_joint_motion(servo_id)
        self.refuse_absent_page(page, f"for servo {servo_id}")
        await self.read_eeprom(servo_id)
        position = await self.hold(servo_id)
        self._motion_off_if_line_lost()  # (another servo's, switched on before a loss, stays off)
        if not self.motion_enabled:
            self._motion_line = self._line_now()  # the line this servo was just held on
        if servo_id not in self.motion_enabled:
            self.motion_switches += 1
        self.motion_enabled.add(servo_id)
        self.motion_off.pop(servo_id, None)
        if isinstance(page, str):
            self._motion_page[servo_id] = page
            if page not in self._pages:  # (gone while the servo was read and held: it keeps holding)
                self._switch_motion_off([servo_id], PAGE_GONE)
        else:
            self._motion_page.pop(servo_id, None)
        return position

    def refuse_absent_page(self, page: object, what: str) -> None:
        """Refuse a page's "enable motion" ``what`` (e.g. "for servo 3") unless that page is connected now:
        the motion it switches on goes off once it is gone, which the server learns only from its socket.

        Raises:
            UnsafeOperation: ``page`` is given and not connected.
        """
        if page is not None and not (isinstance(page, str) and page in self._pages):  # (a page's name is a str)
            raise UnsafeOperation(
                f"this page is not connected to the server now, so its motion could not go off should the page "
                f"go: wait for the page to be connected again, then switch on 'enable motion' {what}; "
                "nothing was sent"
            )

    def page_came(self, page: str) -> None:
        """A page named ``page`` is connected (its WebSocket opened: a page may connect again under its name)."""
        self._pages[page] = self._pages.get(page, 0) + 1

    def page_gone(self, page: str) -> None:
        """A page's WebSocket closed: its tab was closed, reloaded or went elsewhere, or its network went quiet
        (the server's pings went unanswered).  Once none of that page's is left, the motion it switched on goes off,
        as when it leaves a servo's page: a later page, another tab or a script must not find jogging armed, and
        the servo keeps holding (no joint goes limp unasked)."""
        left = self._pages.get(page, 0) - 1
        if left > 0:
            self._pages[page] = left
            return
        self._pages.pop(page, None)
        self._switch_motion_off([sid for sid, p in self._motion_page.items() if p == page], PAGE_GONE)
        if self.robot is not None:
            self.robot.page_gone(page, PAGE_GONE)  # (the robot's, a motion playing stopping smoothly)

    def _holds(self, servo_id: int, target: int) -> None:
        """``servo_id`` was sent ``target`` by a page (on the line as it is now)."""
        self.holding[servo_id] = (target, self._line_now())

    def _held_now_at(self, old_id: int, new_id: int) -> None:
        """A servo a page held answers at ``new_id`` now (an ID write changes no target)."""
        held = self.holding.pop(old_id, None)
        if held is not None:
            self.holding[new_id] = held

    def _holding_split(self) -> tuple[dict[int, int], list[int]]:
        """The servos pages hold, ``{ID: target}``, held on the line as it is now; and those held before the
        port was lost since, or before they stopped answering (see lost_touch), which may still hold or may
        have restarted (free, elsewhere)."""
        bus, now = self.bus, self._line_now()
        sure: dict[int, int] = {}
        unsure: list[int] = []
        for sid, (target, line) in self.holding.items():
            if bus is not None and bus.state is not State.LOST and line == now:
                sure[sid] = target
            else:
                unsure.append(sid)
        return sure, unsure

    def disable_motion(self, servo_id: int) -> None:
        """Motion off: jogs are refused again; the servo keeps holding (Free lets go)."""
        self._motion_goes_off(servo_id)

    def _motion_goes_off(self, servo_id: int) -> None:
        """Motion off for ``servo_id`` as a page asked (no reason kept for the page: it asked)."""
        if servo_id in self.motion_enabled or servo_id in self.motion_off:
            self.motion_switches += 1
        self.motion_enabled.discard(servo_id)
        self._motion_page.pop(servo_id, None)
        self.motion_off.pop(servo_id, None)

    def check_limits(self, servo_id: int) -> list[int] | None:
        limits = self._limits.get(servo_id)
        return None if limits is None else list(limits)

    def check_target(self, servo_id: int, position: int) -> int:
        limits = self._limits.get(servo_id)
        if limits is None:
            raise InvalidArgument(f"servo {servo_id}'s limits are not known yet: open its page (reads its EEPROM)")
        return check_pulse_limits(servo_id, position, *limits)

    async def read_position(self, servo_id: int) -> dict[str, Any]:
        """The Servo page's "reported" position: read now, moving and freeing nothing (policies.position_read).

        A position command's reply is where the servo stood when the command
        arrived, before it moved, so the page reads the position again while
        it is open.  A live stream's servo: the stream's newest reading.  An
        ICS 3.5 servo reads a position only by going free: none is read (its
        temperature is, so that a servo gone silent is noticed), and ``note``
        says what the page shows instead.
        """
        protocol.check_id(servo_id)
        live = self.live
        if live is not None and servo_id in live.ids:
            position = live.position(servo_id)
            return {"position": None if position < 0 else position, "how": "stream", "note": "from the live stream"}
        async with self._quiet() as bus:
            servo = bus.servo(servo_id)
            reading = await read_position_without_freeing(servo)
            if reading.how is None:
                # Nothing to read (ICS 3.5), but the poll is how an open page learns that its servo stopped
                # answering (a servo that restarted is free, elsewhere: a jog from its old target would throw
                # it there): a read that moves nothing, the temperature, asks it all the same.
                await servo.read_temperature()
        note = "read now (ICS 3.6 position read)" if reading.how == "read" else POSITION_AT_COMMAND
        return {"position": reading.position, "how": reading.how, "note": note}

    async def move(self, servo_id: int, position: int) -> int:
        """Move (jog) a servo whose motion a page switched on, within its EEPROM pulse limits."""
        protocol.check_id(servo_id)
        self._refuse_joint_motion(servo_id)
        self._motion_off_if_line_lost()
        self._lost_touch_in_live()
        why = self.motion_off.get(servo_id)
        if why is not None:
            raise UnsafeOperation(
                f"motion was switched off for servo {servo_id}: {why}; switch on 'enable motion' again, which "
                "holds it where it stands; nothing was sent"
            )
        if servo_id not in self.motion_enabled:
            raise UnsafeOperation(f"motion is not enabled for servo {servo_id}: switch on 'enable motion' first")
        if servo_id not in self._limits:
            await self.read_eeprom(servo_id)
            # (while it read, the port may have been lost, or the stream held the servo: checked again)
            return await self.move(servo_id, position)
        target = self.check_target(servo_id, position)
        if self.live is not None and servo_id in self.live.ids:
            self.live.stream.set_target(servo_id, target)
            self._holds(servo_id, target)
            return self.live.position(servo_id)
        before, came_from = self.holding.get(servo_id), self._stood.get(servo_id)
        async with self._quiet() as bus:
            servo = bus.servo(servo_id)
            reply = await servo.set_position(target)
            self._holds(servo_id, target)
            self._stood[servo_id] = reply
            if before is None or came_from is None or not off_its_way(reply, came_from, before[0]):
                return reply
            # Not holding where it was left: it restarted (free) and was turned, or was forced, and this jog throws
            # it to its target from there.  Let go at once (it was free before the jog), and motion off.
            why = (
                f"it answered from {reply}, off its way from {came_from} to {before[0]}: it restarted (free) and "
                "was turned, or was forced"
            )
            self._switch_motion_off([servo_id], why)
            self.holding.pop(servo_id, None)
            self._stood.pop(servo_id, None)
            freed_at = await servo.free()
        raise JogFreedServo(
            f"servo {servo_id} {why}; the jog would have thrown it to {target}: it was freed at once. Switch on "
            "'enable motion' again, which holds it where it stands",
            freed_at,
        )

    # ------------------------------------------------------------------ renumbering

    async def survey(self) -> dict[str, Any]:
        self._refuse_on_robot_line("renumbering", "it needs one servo alone on a line of its own")
        await self.stop_live()
        async with self.exclusive:
            return survey_view(await self._survey_for_id_write(await self._line_at_its_rate()))

    async def renumber(self, new_id: int) -> dict[str, Any]:
        """The guarded one-servo ID write (policies.id_write): refused unless exactly one device answers."""
        protocol.check_id(new_id)
        self._refuse_on_robot_line("renumbering", "it needs one servo alone on a line of its own")
        await self.stop_live()
        async with self.exclusive:
            bus = await self._line_at_its_rate()
            self._looked = {}  # a servo moved to another ID: look for silent ones anew
            sent_from: list[int | None] = [None]  # the ID the servo had as the ID command went out

            def sent() -> None:
                sent_from[0] = survey.lone_id

            try:
                survey = await self._survey_for_id_write(bus)
                change = await write_lone_id(bus, new_id, survey=survey, on_sent=sent)
            except (PortLost, BusClosed) as exc:
                # As `ics35 set-id` says it: whether the write went out, and (if it did) how to learn where it left
                # the servo; the port's own words first.
                after = (
                    "" if sent_from[0] is None else "; once the line is back, press Who is on the line? to see which"
                )
                raise PortLost(f"{error_text(exc)}: {cut_short_words(sent_from[0], new_id)}{after}") from exc
        if change.written and change.old_id in self._limits:
            self._limits[new_id] = self._limits.pop(change.old_id)
        if change.written:
            self._held_now_at(change.old_id, change.new_id)
        if change.written:
            self._found_now(change.old_id, change.new_id)
        return {"old_id": change.old_id, "new_id": change.new_id, "written": change.written}

    async def _survey_for_id_write(self, bus: Bus) -> IdSurvey:
        """The survey before an ID write; when nobody answered, the other rates a device answers at
        (policies.look_elsewhere: the port reopened at each, then at the line's own rate again)."""
        survey = await survey_for_id_write(bus)
        if survey.refusal is not Refusal.NOBODY or self._other_rates_not_tried() is not None:
            return survey
        baud = int(bus.baudrate)
        try:
            with self._searching():
                return await look_elsewhere(survey, reopening(bus), echo=self.config.echo, on_rate=self._trying)
        finally:
            await self._back_at(bus, baud)

    # ------------------------------------------------------------------ live

    async def start_live(self, ids: list[int], rate_hz: float = LIVE_RATE_HZ, free_ics35: object = False) -> LiveView:
        self._refuse_on_robot_line("a live stream of the page's own", "its joints' angles are on the Robot page")
        # Checked before the running plot stops or anything is sent (a page's JSON can hold anything).
        ids = units.check_ids("ids", ids)
        free_ics35 = units.check_bool("free_ics35", free_ics35)
        if units.check_rate_hz(rate_hz) is None:
            raise InvalidArgument("rate_hz must be a number of cycles a second")
        await self.stop_live()
        async with self.exclusive:
            holding, unsure = self._holding_split()
            bus = await self._line_at_its_rate()
            self.live = await LiveView.start(
                bus,
                ids,
                rate_hz=rate_hz,
                holding=holding,
                unsure=unsure,
                lost_touch=self.lost_touch,
                free_ics35=free_ics35,
            )
        # A servo the stream frees to read it (ICS 3.5, held by no page) may fall: a jog from an old target
        # would throw it back there.  One a page held is streamed its target, and its jogs go on through it.
        self._switch_motion_off(self.live.freed, "the live plot freed it to read it (ICS 3.5)")
        return self.live

    async def stop_live(self) -> None:
        self._lost_touch_in_live()  # (its servos' holds in doubt stay so once it is gone)
        live, self.live = self.live, None
        if live is not None:
            await live.stop()
