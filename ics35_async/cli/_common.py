"""What every command shares: settings, argument types, exit codes, output, error translation."""

from __future__ import annotations

import asyncio
import contextlib
import enum
import itertools
import json
import logging
import os
import sys
from collections.abc import Awaitable, Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any, NoReturn, TypeVar
from urllib.parse import urlsplit, urlunsplit

import click
from rich.console import Console
from rich.markup import escape

from .. import (
    protocol,
    sim,  # registers the sim:// URL scheme
    units,
)
from ..bus import Bus, open_bus
from ..eeprom import BaudRate
from ..errors import (
    BadReply,
    BusClosed,
    EchoMismatch,
    IcsError,
    InvalidArgument,
    PartialReply,
    PortLost,
    ReplyError,
    ReplyTimeout,
    UnsafeOperation,
    VerifyError,
)
from ..policies import servo_rates
from ..transports import PortBusy, PortNotFound, PortPermissionDenied, SerialPortError, adapter_advice

T = TypeVar("T")

_SIM_NAMES = itertools.count(1)

DEFAULT_PORT = "sim://"
ALL_BAUDS: tuple[int, ...] = tuple(int(b) for b in BaudRate)


class ExitCode(enum.IntEnum):
    """Process exit codes; documented in the README's CLI reference."""

    OK = 0
    COMMUNICATION = 1  # garbled reply, echo mismatch, verify failure, port lost mid-command
    USAGE = 2  # bad argument (ID 32, position 20000, unknown field): nothing was sent
    PORT = 3  # the port cannot be opened: missing, permission denied, busy, not a serial port
    NO_REPLY = 4  # no servo answered: baud, power, wiring, ID
    REFUSED = 5  # a dangerous operation was refused or not confirmed: nothing was written
    WRONG_BAUD = 6  # the servo answers, but at another baud rate than --baud
    INTERRUPTED = 130  # Ctrl-C during a command that is not meant to be stopped that way


class CliError(Exception):
    """An error for a person: a message, hints on what to do, and an exit code."""

    def __init__(self, code: ExitCode, message: str, *hints: str) -> None:
        super().__init__(message)
        self.code = code
        self.message = message
        self.hints = list(hints)


@dataclass
class Settings:
    """The group's options, shared with every command through ``ctx.obj``."""

    port: str = DEFAULT_PORT
    baud: int = 115200
    timeout: float = 0.020
    retries: int = 1
    echo: bool = True
    transport: str = "auto"
    verbose: int = 0
    port_defaulted: bool = False  # --port not given: say that this is the simulator
    _sim_name: str | None = field(default=None, init=False, repr=False)

    @property
    def is_sim(self) -> bool:
        return self.port.startswith("sim://")

    @property
    def url(self) -> str:
        """The port to open.  An unnamed sim:// line gets a name, so that every reopening
        within this command (scan at each baud, a read-back) finds the same simulated servos."""
        if not self.is_sim:
            return self.port
        parts = urlsplit(self.port)
        if parts.netloc or parts.path.strip("/"):
            return self.port
        if self._sim_name is None:
            self._sim_name = f"ics35-cli-{os.getpid()}-{next(_SIM_NAMES)}"
        return urlunsplit(parts._replace(netloc=self._sim_name))

    def release_sim(self) -> None:
        """Close the simulated line :attr:`url` named, if any (it lives for one command)."""
        name, self._sim_name = self._sim_name, None
        if name is not None:
            with contextlib.suppress(KeyError):
                sim.named(name).close()

    def bus(self, baud: int | None = None, *, timeout: float | None = None, retries: int | None = None) -> Bus:
        """A not-yet-open bus with these settings (``async with`` it)."""
        return open_bus(
            self.url,
            baudrate=self.baud if baud is None else baud,
            echo=self.echo,
            transport=self.transport,
            retries=self.retries if retries is None else retries,
            adapter_latency=self.timeout if timeout is None else timeout,
        )


out = Console(highlight=False, soft_wrap=True)
err = Console(stderr=True, highlight=False, soft_wrap=True)


def settings_of(ctx: click.Context) -> Settings:
    obj = ctx.find_object(Settings)
    return obj if obj is not None else Settings()


def emit_json(value: Any) -> None:
    """One JSON document on stdout (plain print: rich would wrap long lines)."""
    sys.stdout.write(json.dumps(value, sort_keys=False) + "\n")
    sys.stdout.flush()


# --------------------------------------------------------------------------- argument types


def parse_id_list(text: str) -> list[int]:
    """``"1-12"``, ``"0,3,5-7"``, ``"all"`` -> sorted unique IDs; InvalidArgument on anything else."""
    text = text.strip().lower()
    if text in ("all", "*"):
        return list(range(32))
    ids: set[int] = set()
    for part in text.replace(" ", ",").split(","):
        if not part:
            continue
        low_s, dash, high_s = part.partition("-")
        try:
            low = int(low_s)
            high = int(high_s) if dash else low
        except ValueError:
            raise InvalidArgument(f"{part!r} is not an ID or a range like 1-12") from None
        if low > high:
            raise InvalidArgument(f"range {part!r} runs backwards")
        for i in (low, high):
            protocol.check_id(i)
        ids.update(range(low, high + 1))
    if not ids:
        raise InvalidArgument("no IDs given")
    return sorted(ids)


class ServoIdType(click.ParamType[int]):
    name = "ID"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> int:
        if isinstance(value, int) and not isinstance(value, bool):
            candidate: object = value
        else:
            try:
                candidate = int(str(value), 10)
            except ValueError:
                self.fail(f"{value!r} is not a servo ID (0..31)", param, ctx)
        try:
            return protocol.check_id(candidate)
        except InvalidArgument:
            self.fail(f"servo ID must be 0..31, got {candidate}", param, ctx)


class IdListType(click.ParamType[list[int]]):
    name = "IDS"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> list[int]:
        if isinstance(value, list):
            return value
        try:
            return parse_id_list(str(value))
        except InvalidArgument as exc:
            self.fail(f"{exc} (IDs are 0..31; write e.g. 3, 1-12, 0,4,7 or all)", param, ctx)


class BaudListType(click.ParamType[list[int]]):
    name = "BAUDS"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> list[int]:
        if isinstance(value, list):
            return value
        bauds: list[int] = []
        for part in str(value).split(","):
            try:
                baud = int(BaudRate.parse(part.strip()))
            except InvalidArgument as exc:
                self.fail(str(exc), param, ctx)
            if baud not in bauds:
                bauds.append(baud)
        return bauds


SERVO_ID = ServoIdType()
ID_LIST = IdListType()
BAUD_LIST = BaudListType()


def json_option(f: Callable[..., T]) -> Callable[..., T]:
    return click.option("--json", "as_json", is_flag=True, help="Print machine-readable JSON on stdout.")(f)


def yes_option(f: Callable[..., T]) -> Callable[..., T]:
    return click.option("--yes", "-y", is_flag=True, help="Do not ask for confirmation.")(f)


def confirm(question: str, yes: bool) -> None:
    """Ask on stderr; a 'no', end of input or Ctrl-C means nothing gets written."""
    if yes:
        return
    try:
        answered = click.confirm(question, default=False, err=True)
    except click.Abort:
        err.print()  # the prompt line got no newline from the user
        answered = False
    if not answered:
        raise CliError(ExitCode.REFUSED, "not confirmed: nothing was written", "pass --yes to skip the question")


# --------------------------------------------------------------------------- running a command


_advised: set[str] = set()


def advise(port: str) -> None:
    """Print the adapter warnings (FTDI latency timer) once per port."""
    if port in _advised:
        return
    _advised.add(port)
    for warning in adapter_advice(port):
        err.print(f"[yellow]warning:[/yellow] {escape(warning)}", soft_wrap=True)


def run_loop(main: Awaitable[T]) -> T:
    """asyncio.run, on uvloop when it is installed (about 20% less CPU per transaction)."""
    try:
        import uvloop
    except ImportError:
        return asyncio.run(main)  # type: ignore[arg-type]
    with asyncio.Runner(loop_factory=uvloop.new_event_loop) as runner:
        return runner.run(main)  # type: ignore[arg-type]


def run(settings: Settings, make: Callable[[], Awaitable[T]]) -> T:
    """Run the command's coroutine; turn every expected failure into a :class:`CliError`."""
    if not settings.is_sim:
        advise(settings.port)
    elif settings.port_defaulted:
        settings.port_defaulted = False
        err.print("[dim]note: this is the built-in simulator; pass --port /dev/ttyUSB0 (or COM3) for hardware[/dim]")
    try:
        try:
            return run_loop(_guarded(make))
        except KeyboardInterrupt:
            raise CliError(ExitCode.INTERRUPTED, "interrupted") from None
        except ReplyTimeout as exc:
            raise no_reply_error(settings, exc) from None
        except IcsError as exc:
            raise translate(settings, exc) from None
    finally:
        settings.release_sim()


async def _guarded(make: Callable[[], Awaitable[T]]) -> T:
    return await make()


def translate(settings: Settings, exc: IcsError) -> CliError:
    """The person-facing form of a library error."""
    text = str(exc).replace(settings.url, settings.port)
    if isinstance(exc, PortPermissionDenied):
        return CliError(
            ExitCode.PORT,
            text,
            "on Linux: sudo usermod -aG dialout $USER, then log out and in again (check with: groups)",
        )
    if isinstance(exc, PortNotFound):
        return CliError(ExitCode.PORT, text, "list ports with: ls /dev/ttyUSB* /dev/ttyACM* /dev/serial/by-id/")
    if isinstance(exc, PortBusy):
        return CliError(ExitCode.PORT, text, "close the other program (another ics35, a serial monitor, ModemManager)")
    if isinstance(exc, SerialPortError):
        return CliError(ExitCode.PORT, text)
    if isinstance(exc, PortLost):
        return CliError(ExitCode.COMMUNICATION, text, "is the USB adapter still plugged in?")
    if isinstance(exc, BusClosed):
        return CliError(ExitCode.COMMUNICATION, text)
    if isinstance(exc, UnsafeOperation):
        return CliError(ExitCode.REFUSED, f"refused: {text}")
    if isinstance(exc, InvalidArgument):
        if "://" in settings.port and "cannot open" in text:
            return CliError(ExitCode.PORT, text, "ports are device paths (/dev/ttyUSB0), pyserial URLs or sim://")
        return CliError(ExitCode.USAGE, f"{text} (nothing was written)")
    # Every command byte has its MSB set and almost every reply header has it clear,
    # so the first byte back tells an echo from a reply.
    if isinstance(exc, ReplyError) and exc.raw:
        if settings.echo and isinstance(exc, EchoMismatch) and exc.raw[0] < 0x80:
            return CliError(
                ExitCode.COMMUNICATION,
                f"{text}: the first byte back is a servo's reply, not the echo of the command sent",
                "this interface does not loop TX back to RX: pass --no-echo",
            )
        if not settings.echo and exc.raw[0] >= 0x80:
            return CliError(
                ExitCode.COMMUNICATION,
                f"{text}: the bytes sent came back before the reply (an echo)",
                "this interface echoes what it sends (ICS adapters do): drop --no-echo",
            )
    if isinstance(exc, EchoMismatch):
        return CliError(
            ExitCode.COMMUNICATION,
            text,
            "the bytes sent came back changed: two servos answering at once (duplicate ID), noise, or loose wiring",
            "if your interface does not loop TX back to RX, pass --no-echo",
        )
    if isinstance(exc, (BadReply, PartialReply)):
        return CliError(
            ExitCode.COMMUNICATION,
            text,
            "a garbled reply: a wrong baud rate (try: ics35 scan), two servos sharing one ID, or noise on the line",
        )
    if isinstance(exc, VerifyError):
        return CliError(ExitCode.COMMUNICATION, text, "the servo did not store what was written; check its power")
    if isinstance(exc, ReplyError):
        return CliError(ExitCode.COMMUNICATION, text)
    return CliError(ExitCode.COMMUNICATION, text)


def no_reply_error(settings: Settings, exc: ReplyTimeout) -> CliError:
    """No answer: say whether the servo answers at another baud rate, else what to check."""
    if exc.servo_id is not None and not exc.raw and settings.echo:
        # Not even our own echo came back: the adapter or its wiring, not the servo.
        return CliError(
            ExitCode.NO_REPLY,
            f"no echo and no reply from {settings.port}: the bytes sent never came back",
            "check the adapter is an ICS adapter (TX looped back to RX) and the cable is plugged in",
            "if your interface does not echo what it sends, pass --no-echo",
        )
    if exc.servo_id is not None:
        found = other_bauds(settings, exc.servo_id)
        if found:
            return CliError(
                ExitCode.WRONG_BAUD,
                f"servo {exc.servo_id} does not answer at {settings.baud} baud, but does at {found[0]} baud",
                f"pass --baud {found[0]}",
            )
    what = f"servo {exc.servo_id}" if exc.servo_id is not None else "no device"
    return CliError(
        ExitCode.NO_REPLY, f"{what} did not answer on {settings.port} at {settings.baud} baud", *NO_REPLY_HINTS
    )


def nothing_answered(settings: Settings, where: str, *, silent: bool) -> CliError:
    """The error for a line where no servo answered; ``silent``: not a single byte came back."""
    if silent and settings.echo:
        return CliError(
            ExitCode.NO_REPLY,
            f"nothing came back from {where}, not even the echo of the bytes sent",
            "check the adapter is an ICS adapter (TX looped back to RX) and the cable is plugged in",
            "if your interface does not echo what it sends, pass --no-echo",
        )
    return CliError(ExitCode.NO_REPLY, f"no servo answered on {where}", *NO_REPLY_HINTS)


NO_REPLY_HINTS = (
    "check the servo has power (6-12 V on the servo line, not just USB)",
    "check the wiring and the servo ID (ics35 scan tries every ID at every baud rate)",
    "a servo powered up with its signal line low starts in PWM mode: set its PWMINH flag and power-cycle",
)


def other_bauds(settings: Settings, servo_id: int) -> list[int]:
    """Bauds other than ``settings.baud`` at which ``servo_id`` answers and its own EEPROM names that rate."""
    others = [baud for baud in ALL_BAUDS if baud != settings.baud]
    try:
        return list(run_loop(servo_rates(lambda baud: settings.bus(baud, retries=1), servo_id, others)))
    except (IcsError, OSError):
        return []


def fail(error: CliError) -> NoReturn:
    err.print(f"[bold red]error:[/bold red] {escape(error.message)}", soft_wrap=True)
    for hint in error.hints:
        err.print(f"  [cyan]hint:[/cyan] {escape(hint)}", soft_wrap=True)
    sys.exit(int(error.code))


_QUIET = logging.NullHandler()


def setup_logging(verbose: int) -> None:
    if not verbose:
        # The library logs a lost port as a warning, which Python's last-resort handler would
        # print; the command reports it itself, once.  (Configured handlers still get records.)
        logging.getLogger("ics35_async").addHandler(_QUIET)
        return
    if verbose:
        logging.basicConfig(
            level=logging.DEBUG if verbose > 1 else logging.INFO,
            format="%(asctime)s %(levelname)s %(name)s: %(message)s",
            stream=sys.stderr,
        )


# --------------------------------------------------------------------------- formatting


def fmt_degrees(position: int) -> str:
    return f"{units.position_to_degrees(position):+7.1f}°"


def current_text(raw: int) -> str:
    c = units.current_from_raw(raw)
    return f"{'-' if c.reverse else '+'}{c.magnitude}"


def temperature_text(raw: int) -> str:
    return f"{raw} (~{units.temperature_to_celsius(raw):.0f} °C)"


def current_json(raw: int) -> dict[str, Any]:
    c = units.current_from_raw(raw)
    return {"raw": raw, "magnitude": c.magnitude, "reverse": c.reverse}


def temperature_json(raw: int) -> dict[str, Any]:
    return {"raw": raw, "celsius_approx": round(units.temperature_to_celsius(raw), 1)}


def ids_text(ids: Sequence[int] | Iterable[int]) -> str:
    return ", ".join(str(i) for i in ids) or "none"
