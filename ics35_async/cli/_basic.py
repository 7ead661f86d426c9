"""info, move, free, get, set (scan and set-id are in _scan)."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import click
from rich.markup import escape
from rich.table import Table

from .. import policies, protocol, units
from ..bus import Bus
from ..eeprom import Eeprom
from ..errors import BadReply, EchoMismatch, InvalidArgument, PartialReply, ReplyTimeout
from ..protocol import Param
from ._common import (
    ID_LIST,
    NO_REPLY_HINTS,
    SERVO_ID,
    CliError,
    ExitCode,
    NegativeNumbersCommand,
    NobodyAnswered,
    Settings,
    current_json,
    current_text,
    emit_json,
    every_id,
    fmt_degrees,
    id_ranges,
    ids_text,
    json_option,
    out,
    run,
    settings_of,
    temperature_json,
    temperature_text,
    translate,
)
from ._console import ids_argument, print_heading, say
from ._eeprom_view import eeprom_table
from ._targets import parse_target, refuse_outside_pulse_limits

# --------------------------------------------------------------------------- probing


async def probe_ids(
    bus: Bus, ids: Sequence[int], on_probe: Callable[[int], None] | None = None
) -> tuple[list[int], list[int]]:
    """IDs answering a stretch read (harmless), and IDs whose reply was garbled: the library's scan policy
    (``on_probe`` hears how many IDs each step finished)."""
    rate = await policies.probe_ids(bus, ids, on_probe=on_probe)
    return list(rate.answered), sorted(rate.garbled)


# --------------------------------------------------------------------------- info


# What info and monitor say of a servo with no position: the library's reason, and what to do.
NO_READ_35 = f"{policies.NO_READ_ICS35}; pass --free"


# Whose values the EEPROM table shows, beside `get`'s (RAM): a `set` since power-up shows in RAM only, and the RAM
# stretch is on its own scale (half stretch_gain).
INFO_EEPROM_TITLE = "EEPROM (loaded into RAM at power-up; ics35 get reads RAM, where stretch is half stretch_gain)"


@click.command(cls=NegativeNumbersCommand)
@click.argument("servo_id", metavar="ID", type=SERVO_ID)
@click.option(
    "--free",
    "free_servo",
    is_flag=True,
    help="On an ICS 3.5 servo, read the position with the free command: the servo goes limp.",
)
@click.option("--no-position", is_flag=True, help="Do not read the position at all.")
@json_option
@click.pass_context
def info(ctx: click.Context, servo_id: int, free_servo: bool, no_position: bool, as_json: bool) -> int:
    """Decoded EEPROM plus live position, current and temperature of one servo.

    The torque is left alone: an ICS 3.6 servo reports its position with its
    position read; an ICS 3.5 servo can only by the free command, which turns
    its torque off, so its position is shown only with --free.
    """
    settings = settings_of(ctx)
    if free_servo and no_position:
        raise click.UsageError("--free and --no-position contradict each other")

    async def body() -> dict[str, Any]:
        async with settings.bus() as bus:
            servo = bus.servo(servo_id)
            eeprom = await servo.read_eeprom()
            current = await servo.read_current()
            temperature = await servo.read_temperature()
            where: dict[str, Any]
            if no_position:
                where = {"position": None, "how": None, "protocol": None, "why": "asked not to (--no-position)"}
            else:
                reading = await policies.read_position_without_freeing(servo, free_ics35=free_servo)
                where = {
                    "position": reading.position,
                    "how": reading.how,
                    "protocol": reading.protocol,
                    "why": None if reading.why is None else NO_READ_35,
                }
            return {"eeprom": eeprom, "current": current, "temperature": temperature, **where}

    got = run(settings, body)
    eeprom: Eeprom = got["eeprom"]
    position: int | None = got["position"]
    if as_json:
        emit_json(
            {
                "id": servo_id,
                "baud": settings.baud,
                "protocol": got["protocol"],
                "position": position,
                "degrees": None if position is None else round(units.position_to_degrees(position), 2),
                "position_read_by": got["how"],
                "no_position_because": got["why"],
                "free": got["how"] == "free",
                "current": current_json(got["current"]),
                "temperature": temperature_json(got["temperature"]),
                "eeprom": eeprom.to_dict(),
            }
        )
        return 0
    # (its title a line above it, wrapped between its words: as the table's title the terminal cut it mid-word)
    print_heading(f"servo {servo_id} on {settings.port} at {settings.baud} baud")
    live = Table(show_header=False)
    live.add_column("what")
    live.add_column("value")
    if got["protocol"] is not None:
        live.add_row("protocol", got["protocol"])
    if position is None:
        live.add_row("position", f"not read: {got['why']}")
    elif got["how"] == "free":
        live.add_row("position", f"{position}  ({fmt_degrees(position).strip()})  - torque now OFF (free, --free)")
    else:
        live.add_row("position", f"{position}  ({fmt_degrees(position).strip()})  - torque left as it was")
    live.add_row("current", f"{current_text(got['current'])}  ({units.CURRENT_NOTE})")
    live.add_row("temperature", f"{temperature_text(got['temperature'])}  ({units.TEMPERATURE_NOTE})")
    out.print(live)
    print_heading(INFO_EEPROM_TITLE)  # (above the table: a title is cut at the table's width)
    out.print(eeprom_table(eeprom, title=""))
    return 0


# --------------------------------------------------------------------------- move / free


@click.command(cls=NegativeNumbersCommand)
@click.argument("servo_id", metavar="ID", type=SERVO_ID)
@click.argument("position", metavar="POS")
@click.option("--deg", "degrees", is_flag=True, help="POS is in degrees (0 = neutral, -135..+135).")
@click.option("--force", is_flag=True, help="Send counts outside 3500..11500 and the servo's EEPROM pulse limits.")
@json_option
@click.pass_context
def move(ctx: click.Context, servo_id: int, position: str, degrees: bool, force: bool, as_json: bool) -> int:
    """Move a servo to POS counts (3500..11500 is -135..+135 degrees, 7500 neutral), or degrees with --deg.

    A target outside the servo's EEPROM pulse limits is refused unless --force.
    """
    settings = settings_of(ctx)
    try:
        target = parse_target(settings, position, servo_id, degrees=degrees, force=force)
    except InvalidArgument as exc:
        raise click.BadParameter(str(exc), param_hint="POS") from None

    async def body() -> int:
        async with settings.bus() as bus:
            servo = bus.servo(servo_id)
            if not force:
                await refuse_outside_pulse_limits(servo, target)
            return await servo.set_position(target)

    reported = run(settings, body)
    if as_json:
        emit_json(
            {
                "id": servo_id,
                "target": target,
                "reported": reported,
                "reported_degrees": round(units.position_to_degrees(reported), 2),
            }
        )
    else:
        say(
            f"servo {servo_id}: target {target} ({fmt_degrees(target).strip()}), "
            f"now at {reported} ({fmt_degrees(reported).strip()})",
            to=out,
        )
    return 0


@click.command(cls=NegativeNumbersCommand)
@click.argument("ids", metavar="IDS...", nargs=-1, required=True)
@json_option
@click.pass_context
def free(ctx: click.Context, ids: tuple[str, ...], as_json: bool) -> int:
    """Turn the torque off (servo goes limp) and print where each servo is.  IDS: 3, 1-12, all."""
    settings = settings_of(ctx)
    try:
        wanted = sorted({i for text in ids for i in ID_LIST.convert(text, None, None)})
    except click.BadParameter as exc:
        raise click.BadParameter(exc.message, param_hint="IDS") from None

    every_servo = every_id(wanted)  # "all": the servos on the line, whichever they are
    freed_so_far: dict[int, int] = {}  # (what a Ctrl-C part-way leaves to say: see below)

    async def body() -> policies.FreeReport | None:
        task = asyncio.current_task()
        report = None
        async with settings.bus() as bus:
            with contextlib.suppress(asyncio.CancelledError):
                report = await policies.free_servos(
                    bus, wanted, every_servo=every_servo, on_freed=freed_so_far.__setitem__
                )
            # Ctrl-C (the task cancelled; a request it cut short may have ended otherwise): the servos freed so far
            # are said before the command ends (exit code 130), the line closed as usual first.
            interrupted = task is not None and task.cancelling() > 0
            while task is not None and task.cancelling():
                task.uncancel()
        if report is None or interrupted:
            return None
        if not report.freed and not report.unknown and len(report.failed) == len(wanted):
            if every_servo and all(isinstance(e, ReplyTimeout) for e in report.failed.values()):
                # No servo at all at this rate: perhaps at another (not servo 0's no-reply diagnosis)
                where = f"{settings.port} at {settings.baud} baud"
                raise NobodyAnswered(settings, where, silent=bus.stats.total.bytes_rx == 0)
            raise next(iter(report.failed.values()))  # nothing answered: the no-reply diagnosis
        return report

    try:
        report = run(settings, body)
    except CliError as exc:
        if exc.code != ExitCode.INTERRUPTED:
            raise
        # A press as the line opened or closed, or a second one forcing the command out: what went free is said.
        report = None
    if report is None:
        raise _interrupted_freeing(settings, wanted, freed_so_far, as_json=as_json, every_servo=every_servo)
    if as_json:
        emit_json(
            {
                "freed": _freed_json(report.freed),
                "failed": {str(i): str(e) for i, e in report.failed.items()},
                **({"absent": list(report.absent)} if every_servo else {}),
                **({"unknown": [str(i) for i in report.unknown]} if report.unknown else {}),
            }
        )
    else:
        _say_freed(report.freed)
        for i, e in report.failed.items():
            # Only silence is "no answer": a garbled reply means something at that ID did answer (two servos
            # sharing it, most often), which the supply and wiring hints below would not mend.
            # (why in words: the library's record of the transaction, its bytes, is in -v's log)
            if isinstance(e, ReplyTimeout):
                say(f"[red]servo {i}: no answer[/red]")
            else:
                what = "garbled reply" if _garbled(e) else "failed"
                say(f"[red]servo {i}: {what}[/red] ({escape(e.reason)})")
        if report.unknown and every_servo:  # (most of them empty IDs: one line)
            say(
                f"ID(s) {id_ranges(report.unknown)}: [bold]unknown[/bold]: the line was lost before they answered "
                "(free or still holding)",
                to=out,
            )
        else:
            for i in report.unknown:
                say(
                    f"servo {i}: [bold]unknown[/bold]: the line was lost before it answered (free or still holding)",
                    to=out,
                )
        if report.absent:
            say(f"no answer from ID(s) {id_ranges(report.absent)} at {settings.baud} baud: no servo there")
    if report.lost is not None:
        lost = translate(settings, report.lost)
        if report.unknown:  # (the command that frees them once the port is back, as a Ctrl-C's account gives it)
            again = "all" if every_servo else ids_argument(report.unknown)
            lost.hints.append(f"once the port is back, free them with: {settings.command_line('free', again)}")
        raise lost
    if report.failed:
        timed_out = any(isinstance(e, ReplyTimeout) for e in report.failed.values())
        code = ExitCode.NO_REPLY if timed_out else ExitCode.COMMUNICATION
        hints = [*NO_REPLY_HINTS[:2]] if timed_out else []
        for e in report.failed.values():  # each failure's own hints, once (the silent ones': the supply above)
            if not isinstance(e, ReplyTimeout):
                hints += [hint for hint in translate(settings, e).hints if hint not in hints]
        raise CliError(code, f"servo(s) {ids_text(report.failed)} did not go free", *hints)
    return 0


def _interrupted_freeing(
    settings: Settings, wanted: list[int], freed: dict[int, int], *, as_json: bool, every_servo: bool
) -> CliError:
    """Ctrl-C while ``free`` ran: the servos that answered that they went free are printed as ``free`` prints
    them, and the error names the rest, which may still hold (one the press cut short may have gone free; an ID
    "all" had not reached yet may be an empty one), with the command that frees them."""
    left = [i for i in wanted if i not in freed]
    freed = dict(sorted(freed.items()))
    if as_json:
        emit_json({"freed": _freed_json(freed), "not_freed": left, "interrupted": True})
    else:
        _say_freed(freed)
    went = f"servo(s) {id_ranges(freed)} went free" if freed else "no servo had answered that it went free"
    if not left:
        return CliError(ExitCode.INTERRUPTED, f"interrupted: {went}, every one asked for")
    who = "a servo among them" if every_servo else "they"
    error = CliError(
        ExitCode.INTERRUPTED,
        f"interrupted: {went}; {'ID' if every_servo else 'servo'}(s) {id_ranges(left)} not freed: {who} may still "
        "hold (torque on)",
    )
    # ("all" again for every servo: named, the empty IDs among the rest would each be waited for and fail)
    again = "all" if every_servo else ids_argument(left)
    error.hints.append(f"free them with: {settings.command_line('free', again)}")
    return error


def _freed_json(freed: Mapping[int, int]) -> dict[str, int]:
    """``free --json``'s ``freed``: ID (as a JSON key) -> the position each reported as it went free."""
    return {str(i): p for i, p in freed.items()}


def _say_freed(freed: Mapping[int, int]) -> None:
    """A line on stdout for each servo that went free, where it reported it stood."""
    for i, p in freed.items():
        say(f"servo {i}: free at {p} ({fmt_degrees(p).strip()})", to=out)


def _garbled(exc: Exception) -> bool:
    """Whether ``exc`` says a reply came back, but not as sent or not whole (an echo changed, bytes cut short)."""
    return isinstance(exc, BadReply | PartialReply | EchoMismatch)


# --------------------------------------------------------------------------- get / set (RAM)

READ_PARAMS: dict[str, Param] = {
    "stretch": Param.STRETCH,
    "speed": Param.SPEED,
    "current": Param.CURRENT,
    "temperature": Param.TEMPERATURE,
}
WRITE_PARAMS: dict[str, Param] = {
    "stretch": Param.STRETCH,
    "speed": Param.SPEED,
    "current-limit": Param.CURRENT,
    "temperature-limit": Param.TEMPERATURE,
}
_PARAM_NOTES = {
    # (scan and info show the EEPROM's values, loaded at power-up: where each number comes from, said beside it)
    "stretch": "holding gain {}..{}, half the scale of the EEPROM's stretch_gain that scan and info show".format(
        *protocol.WRITE_RANGES[Param.STRETCH]
    ),
    "speed": "{}..{}; scan and info show the EEPROM's speed, loaded at power-up".format(
        *protocol.WRITE_RANGES[Param.SPEED]
    ),
    "current": f"measured; {units.CURRENT_NOTE}",
    "temperature": f"measured; {units.TEMPERATURE_NOTE}",
}
_EEPROM_TWIN = {
    "stretch": "stretch_gain (EEPROM stores 2x: 2..254)",
    "speed": "speed",
    "current-limit": "current_limit",
    "temperature-limit": "temperature_limit",
}


# A temperature limit counts the other way from degrees (60 is about 96 C, hotter than the factory 80): shown
# in Celsius and said, or a limit meant as "60 C" loosens the servo's protection unnoticed.
HOTTER = {"temperature-limit": f"{units.TEMPERATURE_NOTE}; "}


def limit_text(param: str, value: int) -> str:
    """A written or read value of ``param`` as shown: a temperature limit with its Celsius."""
    return temperature_text(value) if param == "temperature-limit" else str(value)


# The limits are write-only in RAM (reading SC 3/4 returns the measured values),
# so `get` reports the EEPROM limit, which the servo loads into RAM at power-up.
EEPROM_LIMITS = {"current-limit": "current_limit", "temperature-limit": "temperature_limit"}


class _ReadParamChoice(click.Choice):  # type: ignore[type-arg]
    """``get``'s parameters; asked for the position (a newcomer's first guess), it names the commands that read
    it: the servo tells its position only as it answers a position or free command, not as a parameter."""

    POSITION_WORDS = frozenset({"position", "pos", "angle"})

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        if isinstance(value, str) and value.lower() in self.POSITION_WORDS:
            servo = ctx.params.get("servo_id", "ID") if ctx is not None else "ID"
            self.fail(
                f"{value!r} is not a parameter get reads (the servo tells its position only as it answers a command):"
                f" `ics35 info {servo}` reads it (an ICS 3.5 servo only with --free, which frees it), `ics35 free"
                f" {servo}` frees the servo and prints it, `ics35 monitor {servo} --free` shows it live as you move"
                " the servo by hand",
                param,
                ctx,
            )
        return super().convert(value, param, ctx)


@click.command(cls=NegativeNumbersCommand)
@click.argument("servo_id", metavar="ID", type=SERVO_ID)
@click.argument("param", metavar="PARAM", type=_ReadParamChoice([*READ_PARAMS, *EEPROM_LIMITS], case_sensitive=False))
@json_option
@click.pass_context
def get(ctx: click.Context, servo_id: int, param: str, as_json: bool) -> int:
    """Read stretch, speed, current (measured) or temperature (measured) from RAM.

    current-limit and temperature-limit cannot be read back from RAM over ICS 3.5:
    for those, the EEPROM value (loaded into RAM at power-up) is shown, and says so.
    """
    settings = settings_of(ctx)
    param = param.lower()
    memory = "EEPROM" if param in EEPROM_LIMITS else "RAM"

    async def body() -> int:
        async with settings.bus() as bus:
            if param in EEPROM_LIMITS:
                image = await bus.servo(servo_id).read_eeprom()
                return int(getattr(image, EEPROM_LIMITS[param]))
            return await bus.request(protocol.ReadParam(servo_id, READ_PARAMS[param]))

    value = run(settings, body)
    if as_json:
        doc: dict[str, Any] = {"id": servo_id, "param": param, "value": value, "memory": memory}
        if param == "current":
            doc.update(current=current_json(value))
        elif param == "temperature":
            doc.update(temperature=temperature_json(value))
        emit_json(doc)
        return 0
    if memory == "EEPROM":
        say(
            f"servo {servo_id} {param} = {limit_text(param, value)}  ({HOTTER.get(param, '')}EEPROM value, "
            f"loaded at power-up: the RAM limit cannot be read back, so a later `ics35 set {servo_id} {param} ...` "
            "is not reflected here)",
            to=out,
        )
        return 0
    shown = {"current": current_text, "temperature": temperature_text}.get(param, str)(value)
    say(f"servo {servo_id} {param} = {shown}  (RAM, now; {_PARAM_NOTES[param]})", to=out)
    return 0


class _WriteParamChoice(click.Choice):  # type: ignore[type-arg]
    """``set``'s parameters; given ``eeprom set``'s form (``speed=60``) or the position, it names the command that
    takes it."""

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        servo = ctx.params.get("servo_id", "ID") if ctx is not None else "ID"
        if isinstance(value, str) and "=" in value:
            name, _, number = value.partition("=")
            self.fail(
                f"{value!r}: set takes PARAM VALUE, into RAM (ics35 set {servo} {name} {number}); a field=value goes "
                f"into the EEPROM with ics35 eeprom set {servo} {value}",
                param,
                ctx,
            )
        if isinstance(value, str) and value.lower() in _ReadParamChoice.POSITION_WORDS:
            self.fail(
                f"{value!r} is not a parameter: a servo is sent a position with ics35 move {servo} POSITION", param, ctx
            )
        return super().convert(value, param, ctx)


@click.command(name="set", cls=NegativeNumbersCommand)
@click.argument("servo_id", metavar="ID", type=SERVO_ID)
@click.argument("param", metavar="PARAM", type=_WriteParamChoice(list(WRITE_PARAMS), case_sensitive=False))
@click.argument("value", metavar="VALUE", type=int)
@json_option
@click.pass_context
def set_(ctx: click.Context, servo_id: int, param: str, value: int, as_json: bool) -> int:
    """Write a RAM parameter: stretch, speed, current-limit or temperature-limit.

    RAM only: the servo forgets it at power-off.  To persist, use `ics35 eeprom set`.
    A temperature limit counts the other way: smaller is hotter (80, the factory
    value, is about 80 °C; 60 about 96 °C).
    """
    settings = settings_of(ctx)
    param = param.lower()
    try:
        command = protocol.WriteParam(servo_id, WRITE_PARAMS[param], value)
    except InvalidArgument as exc:
        raise click.BadParameter(str(exc), param_hint="VALUE") from None

    async def body() -> int:
        async with settings.bus() as bus:
            return await bus.request(command)

    written = run(settings, body)
    if as_json:
        emit_json({"id": servo_id, "param": param, "value": written, "memory": "RAM"})
    else:
        # The value to type: the EEPROM keeps the stretch twice over (RAM 1..127 is 2..254 there).
        stored = units.stretch_to_eeprom(written) if param == "stretch" else written
        keep = settings.command_line("eeprom", "set", str(servo_id), f"{_EEPROM_TWIN[param].split()[0]}={stored}")
        say(
            f"servo {servo_id} {param} = {limit_text(param, written)} ({HOTTER.get(param, '')}RAM only: lost at "
            f"power-off; to keep it: {escape(keep)})",
            to=out,
        )
    return 0


COMMANDS = [info, move, free, get, set_]
