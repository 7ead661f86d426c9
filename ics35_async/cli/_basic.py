"""scan, info, move, free, get, set, set-id."""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import click
from rich import box
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn
from rich.table import Table

from .. import protocol, units
from ..bus import Bus
from ..eeprom import Eeprom, Flags
from ..errors import EchoMismatch, InvalidArgument, ReplyError, ReplyTimeout
from ..protocol import Param
from ..transport import PortBusy, PortNotFound, PortPermissionDenied, SerialPortError
from ._common import (
    ALL_BAUDS,
    BAUD_LIST,
    ID_LIST,
    NO_REPLY_HINTS,
    SERVO_ID,
    CliError,
    ExitCode,
    Settings,
    confirm,
    current_json,
    current_text,
    emit_json,
    err,
    fmt_degrees,
    ids_text,
    json_option,
    nothing_answered,
    out,
    run,
    settings_of,
    temperature_json,
    temperature_text,
    yes_option,
)
from ._targets import check_pulse_limits, parse_target

# --------------------------------------------------------------------------- scanning


@dataclass
class ScanResult:
    """What a scan found: servos per baud, and IDs that answered with garbage (suspects)."""

    found: list[tuple[int, int, Eeprom | None]] = field(default_factory=list)  # (baud, id, eeprom)
    garbled: list[tuple[int, int]] = field(default_factory=list)  # (baud, id)
    eeprom_errors: dict[tuple[int, int], str] = field(default_factory=dict)
    skipped: dict[int, str] = field(default_factory=dict)  # baud -> why the port would not open at it
    silent: list[int] = field(default_factory=list)  # bauds at which not a byte came back, not even the echo


async def probe_ids(
    bus: Bus, ids: Sequence[int], on_done: Callable[[], None] | None = None
) -> tuple[list[int], list[int]]:
    """IDs answering a stretch read (harmless), and IDs whose reply was garbled."""
    answered: list[int] = []
    garbled: list[int] = []

    async def probe(i: int) -> None:
        try:
            await bus.request(protocol.ReadParam(i, Param.STRETCH))
        except ReplyTimeout:
            pass
        except ReplyError:
            garbled.append(i)
        else:
            answered.append(i)
        finally:
            if on_done is not None:
                on_done()

    await asyncio.gather(*(probe(i) for i in ids))
    return sorted(answered), sorted(garbled)


async def scan_line(
    settings: Settings,
    bauds: Sequence[int],
    ids: Sequence[int],
    *,
    read_eeprom: bool,
    timeout: float | None,
    show_progress: bool,
) -> ScanResult:
    """Probe ``ids`` at each of ``bauds`` (reopening the port at each rate)."""
    result = ScanResult()
    progress = Progress(
        TextColumn("[progress.description]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("found {task.fields[found]}"),
        console=err,
        transient=True,
        disable=not show_progress or not err.is_terminal,
    )
    with progress:
        task = progress.add_task("scanning", total=len(bauds) * len(ids), found=0)
        for baud in bauds:
            progress.update(task, description=f"scanning {baud:>7} baud")
            bus = settings.bus(baud, timeout=timeout)
            try:
                await bus.open()
            except (InvalidArgument, SerialPortError) as exc:
                # A missing port or a permission problem is the same at every rate: report it.
                # A rate the adapter cannot do (625k/1.25M without the HS adapter) is skipped.
                if isinstance(exc, (PortNotFound, PortPermissionDenied, PortBusy)):
                    raise
                result.skipped[baud] = str(exc)
                progress.advance(task, len(ids))
                continue
            async with bus:
                answered, garbled = await probe_ids(bus, ids, lambda: progress.advance(task))
                if bus.stats.total.bytes_rx == 0:
                    result.silent.append(baud)
                result.garbled.extend((baud, i) for i in garbled)
                for i in answered:
                    eeprom: Eeprom | None = None
                    if read_eeprom:
                        try:
                            eeprom = await bus.servo(i).read_eeprom()
                        except ReplyError as exc:
                            result.eeprom_errors[(baud, i)] = str(exc)
                    result.found.append((baud, i, eeprom))
            progress.update(task, found=len(result.found))
    return result


def flag_names(flags: Flags) -> str:
    return "|".join(f.name or "" for f in Flags if f in flags) or "-"


def scan_table(result: ScanResult) -> Table:
    table = Table(
        title="servos found", title_justify="left", box=box.SIMPLE_HEAD, pad_edge=False, collapse_padding=True
    )
    if all(e is None for _, _, e in result.found):
        table.add_column("ID", justify="right")
        table.add_column("baud", justify="right")
        for baud, i, _ in result.found:
            table.add_row(str(i), str(baud))
        return table
    for name in ("ID", "baud", "stretch", "speed", "I-limit", "T-limit", "pulse range", "offset"):
        table.add_column(name, justify="right")
    table.add_column("flags")
    for baud, i, e in result.found:
        if e is None:
            table.add_row(str(i), str(baud), *["?"] * 6, "(EEPROM not read)")
            continue
        note = "" if int(e.baud_rate) == baud else f" (EEPROM: {int(e.baud_rate)})"
        table.add_row(
            str(i),
            f"{baud}{note}",
            str(e.stretch_gain),
            str(e.speed),
            str(e.current_limit),
            str(e.temperature_limit),
            f"{e.pulse_limit_low}-{e.pulse_limit_high}",
            f"{e.user_offset:+d}",
            flag_names(e.flags),
        )
    return table


@click.command()
@click.option(
    "--bauds",
    type=BAUD_LIST,
    default=",".join(map(str, ALL_BAUDS)),
    show_default=True,
    help="Baud rates to try, comma-separated.",
)
@click.option("--ids", "ids", type=ID_LIST, default="all", show_default=True, help="IDs to try, e.g. 0-7 or 1,3,5.")
@click.option(
    "--timeout",
    type=click.FloatRange(0.001, 5.0),
    default=None,
    help="Reply allowance per probe in seconds (default: the global --timeout).",
)
@click.option("--quick", is_flag=True, help="Do not read each servo's EEPROM.")
@json_option
@click.pass_context
def scan(
    ctx: click.Context, bauds: list[int], ids: list[int], timeout: float | None, quick: bool, as_json: bool
) -> int:
    """Find servos: try every baud rate x every ID (reopening the port at each rate).

    Sends only harmless stretch reads, then reads each servo's EEPROM for its key fields.
    Exit code 4 when nothing answers.
    """
    settings = settings_of(ctx)
    result = run(
        settings,
        lambda: scan_line(settings, bauds, ids, read_eeprom=not quick, timeout=timeout, show_progress=not as_json),
    )
    if as_json:
        emit_json(
            {
                "port": settings.port,
                "bauds": bauds,
                "servos": [
                    {"id": i, "baud": baud, "eeprom": None if e is None else e.to_dict()} for baud, i, e in result.found
                ],
                "garbled": [{"id": i, "baud": baud} for baud, i in result.garbled],
                "skipped_bauds": {str(baud): why for baud, why in result.skipped.items()},
            }
        )
    else:
        if result.found:
            out.print(scan_table(result))
        for baud, why in result.skipped.items():
            err.print(f"[yellow]warning:[/yellow] skipped {baud} baud: {escape(why)}")
        for (baud, i), message in result.eeprom_errors.items():
            err.print(f"[yellow]warning:[/yellow] servo {i} at {baud} baud: EEPROM read failed: {escape(message)}")
        if result.garbled:
            where = ", ".join(f"ID {i} at {baud}" for baud, i in result.garbled)
            err.print(
                f"[yellow]warning:[/yellow] garbled replies from {where}: two servos sharing an ID, "
                "a servo at another baud rate, or noise",
                soft_wrap=True,
            )
        by_baud: dict[int, int] = {}
        for baud, _, _ in result.found:
            by_baud[baud] = by_baud.get(baud, 0) + 1
        if result.found:
            summary = ", ".join(f"{n} at {b} baud" for b, n in by_baud.items())
            out.print(f"{len(result.found)} servo(s) found on {escape(settings.port)}: {summary}")
            if len(by_baud) > 1:
                err.print("[yellow]note:[/yellow] servos at different baud rates cannot share one bus session")
    if not result.found:
        scanned = [b for b in bauds if b not in result.skipped]
        where = f"{settings.port} at {', '.join(map(str, scanned))} baud"
        raise nothing_answered(settings, where, silent=bool(scanned) and len(result.silent) == len(scanned))
    return 0


# --------------------------------------------------------------------------- info


@click.command()
@click.argument("servo_id", metavar="ID", type=SERVO_ID)
@click.option("--no-position", is_flag=True, help="Do not read the position (reading it turns the torque off).")
@json_option
@click.pass_context
def info(ctx: click.Context, servo_id: int, no_position: bool, as_json: bool) -> int:
    """Decoded EEPROM plus live position, current and temperature of one servo.

    ICS 3.5 can only read a position by sending the free command, so this turns
    the servo's torque off (use --no-position to keep it holding).
    """
    settings = settings_of(ctx)

    async def body() -> dict[str, Any]:
        async with settings.bus() as bus:
            servo = bus.servo(servo_id)
            eeprom = await servo.read_eeprom()
            current = await servo.read_current()
            temperature = await servo.read_temperature()
            position = None if no_position else await servo.free()
            return {"eeprom": eeprom, "current": current, "temperature": temperature, "position": position}

    got = run(settings, body)
    eeprom: Eeprom = got["eeprom"]
    position: int | None = got["position"]
    if as_json:
        emit_json(
            {
                "id": servo_id,
                "baud": settings.baud,
                "position": position,
                "degrees": None if position is None else round(units.position_to_degrees(position), 2),
                "free": position is not None,
                "current": current_json(got["current"]),
                "temperature": temperature_json(got["temperature"]),
                "eeprom": eeprom.to_dict(),
            }
        )
        return 0
    live = Table(
        title=f"servo {servo_id} on {escape(settings.port)} at {settings.baud} baud",
        title_justify="left",
        show_header=False,
    )
    live.add_column("what")
    live.add_column("value")
    if position is None:
        live.add_row("position", "not read (--no-position)")
    else:
        live.add_row("position", f"{position}  ({fmt_degrees(position).strip()})  - torque now OFF (free)")
    live.add_row("current", f"{current_text(got['current'])}  (magnitude 0..63, sign = direction)")
    live.add_row("temperature", f"{temperature_text(got['temperature'])}  (smaller is hotter)")
    out.print(live)
    out.print(eeprom_table(eeprom))
    return 0


def eeprom_table(eeprom: Eeprom, title: str = "EEPROM") -> Table:
    table = Table(title=title, title_justify="left")
    table.add_column("field")
    table.add_column("value", justify="right")
    for name, value in eeprom.to_dict().items():
        if name in ("raw", "flags_names"):
            continue
        shown = f"{value} ({flag_names(eeprom.flags)})" if name == "flags" else str(value)
        table.add_row(name, shown)
    return table


# --------------------------------------------------------------------------- move / free


@click.command(context_settings={"ignore_unknown_options": True})
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
        target = parse_target(position, servo_id, degrees=degrees, force=force)
    except InvalidArgument as exc:
        raise click.BadParameter(str(exc), param_hint="POS") from None

    async def body() -> int:
        async with settings.bus() as bus:
            servo = bus.servo(servo_id)
            if not force:
                await check_pulse_limits(servo, target)
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
        out.print(
            f"servo {servo_id}: target {target} ({fmt_degrees(target).strip()}), "
            f"now at {reported} ({fmt_degrees(reported).strip()})"
        )
    return 0


@click.command()
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

    async def body() -> dict[int, int | ReplyError]:
        async with settings.bus() as bus:
            results = await asyncio.gather(*(bus.servo(i).free() for i in wanted), return_exceptions=True)
        done: dict[int, int | ReplyError] = {}
        for i, r in zip(wanted, results, strict=True):
            if isinstance(r, ReplyError):
                done[i] = r
            elif isinstance(r, BaseException):
                raise r
            else:
                done[i] = r
        if all(isinstance(r, ReplyError) for r in done.values()):
            first = next(iter(done.values()))
            assert isinstance(first, ReplyError)
            raise first
        return done

    done = run(settings, body)
    failed = {i: r for i, r in done.items() if isinstance(r, ReplyError)}
    if as_json:
        emit_json(
            {
                "freed": {str(i): p for i, p in done.items() if isinstance(p, int)},
                "failed": {str(i): str(e) for i, e in failed.items()},
            }
        )
    else:
        for i, p in done.items():
            if isinstance(p, int):
                out.print(f"servo {i}: free at {p} ({fmt_degrees(p).strip()})")
            else:
                err.print(f"[red]servo {i}: no answer[/red] ({escape(str(p))})")
    if failed:
        timed_out = any(isinstance(e, ReplyTimeout) for e in failed.values())
        code = ExitCode.NO_REPLY if timed_out else ExitCode.COMMUNICATION
        raise CliError(code, f"servo(s) {ids_text(failed)} did not go free", *NO_REPLY_HINTS[:2])
    return 0


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
    "stretch": "holding gain 1..127",
    "speed": "1..127",
    "current": "measured; magnitude 0..63, sign = direction",
    "temperature": "measured; smaller is hotter",
}
_EEPROM_TWIN = {
    "stretch": "stretch_gain (EEPROM stores 2x: 2..254)",
    "speed": "speed",
    "current-limit": "current_limit",
    "temperature-limit": "temperature_limit",
}


# The limits are write-only in RAM (reading SC 3/4 returns the measured values),
# so `get` reports the EEPROM limit, which the servo loads into RAM at power-up.
EEPROM_LIMITS = {"current-limit": "current_limit", "temperature-limit": "temperature_limit"}


@click.command()
@click.argument("servo_id", metavar="ID", type=SERVO_ID)
@click.argument("param", metavar="PARAM", type=click.Choice([*READ_PARAMS, *EEPROM_LIMITS], case_sensitive=False))
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
        out.print(
            f"servo {servo_id} {param} = {value}  (EEPROM value, loaded at power-up: the RAM limit cannot be "
            f"read back, so a later `ics35 set {servo_id} {param} ...` is not reflected here)"
        )
        return 0
    shown = {"current": current_text, "temperature": temperature_text}.get(param, str)(value)
    out.print(f"servo {servo_id} {param} = {shown}  (RAM; {_PARAM_NOTES[param]})")
    return 0


@click.command(name="set", context_settings={"ignore_unknown_options": True})
@click.argument("servo_id", metavar="ID", type=SERVO_ID)
@click.argument("param", metavar="PARAM", type=click.Choice(list(WRITE_PARAMS), case_sensitive=False))
@click.argument("value", metavar="VALUE", type=int)
@json_option
@click.pass_context
def set_(ctx: click.Context, servo_id: int, param: str, value: int, as_json: bool) -> int:
    """Write a RAM parameter: stretch, speed, current-limit or temperature-limit.

    RAM only: the servo forgets it at power-off.  To persist, use `ics35 eeprom set`.
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
        out.print(
            f"servo {servo_id} {param} = {written} (RAM only: lost at power-off; "
            f"to keep it: ics35 eeprom set {servo_id} {_EEPROM_TWIN[param].split()[0]}=...)"
        )
    return 0


# --------------------------------------------------------------------------- set-id


@click.command(name="set-id")
@click.argument("new_id", metavar="NEW", type=SERVO_ID)
@yes_option
@json_option
@click.pass_context
def set_id(ctx: click.Context, new_id: int, yes: bool, as_json: bool) -> int:
    """Give the ONLY servo on the line the ID NEW (stored in its EEPROM).

    The ID command renames every device that hears it, so this first scans all
    32 IDs and refuses unless exactly one servo answers.
    """
    settings = settings_of(ctx)

    async def body() -> tuple[int, int]:
        async with settings.bus() as bus:
            answered, garbled = await probe_ids(bus, range(32))
            if garbled:
                raise CliError(
                    ExitCode.REFUSED,
                    f"garbled replies from ID(s) {ids_text(garbled)}: probably two servos sharing an ID",
                    "connect only the servo to renumber, then retry",
                )
            if not answered:
                where = f"{settings.port} at {settings.baud} baud"
                raise nothing_answered(settings, where, silent=bus.stats.total.bytes_rx == 0)
            if len(answered) > 1:
                raise CliError(
                    ExitCode.REFUSED,
                    f"{len(answered)} servos answer (IDs {ids_text(answered)}): set-id would give ALL of them ID "
                    f"{new_id}. Nothing was written",
                    "disconnect every servo but the one to renumber, then retry",
                )
            (old,) = answered
            try:
                seen = await bus.read_id(exactly_one_device=True)
            except (EchoMismatch, ReplyError) as exc:
                raise CliError(
                    ExitCode.REFUSED,
                    f"the ID command got a garbled answer ({exc}): another device is on the line. Nothing was written",
                    "disconnect every device but the servo to renumber",
                ) from None
            if seen != old:
                raise CliError(
                    ExitCode.REFUSED,
                    f"servo {old} answers, but the ID command reports ID {seen}: another device is on the line",
                    "disconnect every device but the servo to renumber",
                )
            if old == new_id:
                return old, new_id
            if not as_json:
                out.print(f"one servo on the line: ID {old}")
            confirm(f"Change servo ID {old} -> {new_id} (stored in its EEPROM)?", yes)
            await bus.write_id(new_id, exactly_one_device=True)
            await bus.request(protocol.ReadParam(new_id, Param.STRETCH))
            return old, new_id

    old, new = run(settings, body)
    if as_json:
        emit_json({"old": old, "new": new, "changed": old != new})
    elif old == new:
        out.print(f"servo already has ID {new}: nothing written")
    else:
        out.print(f"servo ID {old} -> {new}: done (verified: ID {new} answers)")
    return 0


COMMANDS = [scan, info, move, free, get, set_, set_id]
