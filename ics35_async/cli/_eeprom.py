"""eeprom dump / restore / set: back up and change the persistent settings, safely.

Safety rules, in this order: every value is validated before the port opens;
the new image is built from the servo's own image with ``Eeprom.replace``,
so the factory calibration bytes and the read-only flags always stay the
servo's; the diff is shown and confirmed; a baud-rate change needs
``--change-baud``; an ID change is refused if the new ID already answers.
"""

from __future__ import annotations

import datetime
import json
from pathlib import Path
from typing import Any, TextIO

import click
from rich.markup import escape
from rich.table import Table

from .. import protocol
from ..bus import Bus
from ..eeprom import EEPROM_FIELDS, READ_ONLY_FLAGS, BaudRate, Eeprom, Flags
from ..errors import InvalidArgument, MalformedEeprom, ReplyError, ReplyTimeout
from ..protocol import Param
from ._basic import baud_text, eeprom_table, flag_names
from ._common import (
    SERVO_ID,
    CliError,
    ExitCode,
    Settings,
    confirm,
    emit_json,
    err,
    json_option,
    out,
    run,
    settings_of,
    yes_option,
)

DUMP_FORMAT = "ics35-eeprom/1"
FIELD_ALIASES = {"baud": "baud_rate", "id": "servo_id", "stretch": "stretch_gain"}


@click.group()
def eeprom() -> None:
    """Back up, restore and change a servo's EEPROM (its persistent settings)."""


# --------------------------------------------------------------------------- dump


@eeprom.command()
@click.argument("servo_id", metavar="ID", type=SERVO_ID)
@click.option("--output", "-o", type=click.Path(dir_okay=False, writable=True), help="Write to FILE, not stdout.")
@click.option("--table", "as_table", is_flag=True, help="Print a readable table instead of JSON.")
@click.option("--json", "as_json", is_flag=True, hidden=True, help="JSON (the default; accepted for scripts).")
@click.pass_context
def dump(ctx: click.Context, servo_id: int, output: str | None, as_table: bool, as_json: bool) -> int:
    """Print the servo's EEPROM as JSON (the backup format `eeprom restore` reads)."""
    settings = settings_of(ctx)

    async def body() -> Eeprom:
        async with settings.bus() as bus:
            return await bus.servo(servo_id).read_eeprom()

    image = run(settings, body)
    if image.unknown_codes:
        codes = ", ".join(f"{name} 0x{code:02X}" for name, code in image.unknown_codes.items())
        err.print(
            f"[yellow]warning:[/yellow] servo {servo_id}'s EEPROM holds unknown code(s), not in ICS 3.5 ({codes}): "
            "kept exactly as read; an image holding them cannot be written back"
        )
    if as_table:
        out.print(eeprom_table(image, f"EEPROM of servo {servo_id}"))
        return 0
    doc = dump_document(image, servo_id, settings)
    if output is None:
        emit_json(doc)
    else:
        Path(output).write_text(json.dumps(doc, indent=2) + "\n")
        err.print(f"EEPROM of servo {servo_id} saved to {escape(output)}")
    return 0


def dump_document(image: Eeprom, servo_id: int, settings: Settings) -> dict[str, Any]:
    fields = image.to_dict()
    return {
        "format": DUMP_FORMAT,
        "servo_id": servo_id,
        "baud": settings.baud,
        "port": settings.port,
        "saved": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "fields": {name: fields[name] for name in EEPROM_FIELDS},
        "flags_names": fields["flags_names"],
        "raw": fields["raw"],
        "unknown_codes": fields["unknown_codes"],
    }


def fields_from_document(doc: object) -> dict[str, int]:
    """The editable fields of a dump (``fields`` wins over ``raw`` when both are there)."""
    if not isinstance(doc, dict):
        raise InvalidArgument("an EEPROM backup is a JSON object (made by `ics35 eeprom dump`)")
    fields = doc.get("fields")
    if fields is None and isinstance(doc.get("raw"), str):
        try:
            image = Eeprom.from_bytes(bytes.fromhex(doc["raw"]))
        except ValueError as exc:
            raise InvalidArgument(f"the backup's raw image is unusable: {exc}") from None
        fields = {name: int(getattr(image, name)) for name in EEPROM_FIELDS}
    if not isinstance(fields, dict):
        raise InvalidArgument("the backup has neither 'fields' nor 'raw' (was it made by `ics35 eeprom dump`?)")
    unknown = set(fields) - set(EEPROM_FIELDS)
    if unknown:
        raise InvalidArgument(f"unknown EEPROM field(s) in the backup: {', '.join(sorted(unknown))}")
    missing = set(EEPROM_FIELDS) - set(fields)
    if missing:
        raise InvalidArgument(f"the backup lacks field(s): {', '.join(sorted(missing))}")
    for name, value in fields.items():
        if isinstance(value, bool) or not isinstance(value, int):
            raise InvalidArgument(f"field {name} must be an integer, got {value!r}")
    return dict(fields)


# --------------------------------------------------------------------------- shared write path


def precheck(changes: dict[str, int]) -> None:
    """Validate values before the port opens (against a template image; limits are rechecked later)."""
    template = Eeprom.factory()
    checked = dict(changes)
    if "flags" in checked:
        checked["flags"] = checked["flags"] & ~READ_ONLY_FLAGS if isinstance(checked["flags"], int) else -1
    template.replace(**checked)


def diff_table(servo_id: int, before: Eeprom, after: Eeprom) -> Table:
    table = Table(title=f"EEPROM changes for servo {servo_id}", title_justify="left")
    table.add_column("field")
    table.add_column("now", justify="right")
    table.add_column("new", justify="right")
    for name, (old, new) in before.diff(after).items():
        if name == "flags":
            table.add_row(name, f"{int(old)} ({flag_names(old)})", f"{int(new)} ({flag_names(new)})")
        else:
            table.add_row(name, str(int(old)), str(int(new)))
    return table


BAUD_CONSEQUENCE = (
    "from its next power-up the servo answers ONLY at {new} baud: every later command needs --baud {new}"
    "{hs}, and servos at different rates cannot share one bus session"
)


def baud_refusal(current: BaudRate | int, new: BaudRate | int) -> CliError:
    hs = " and 625000/1250000 need the ICS USB adapter HS" if new != BaudRate.B115200 else ""
    return CliError(
        ExitCode.REFUSED,
        f"refused: this changes the baud rate from {baud_text(current)} to {int(new)}; "
        + BAUD_CONSEQUENCE.format(new=int(new), hs=hs)
        + ". Nothing was written",
        "to do it anyway, add --change-baud",
    )


async def id_is_free(bus: Bus, servo_id: int) -> bool:
    try:
        await bus.request(protocol.ReadParam(servo_id, Param.STRETCH))
    except ReplyError:
        return True
    return False


async def apply_changes(
    settings: Settings,
    bus: Bus,
    servo_id: int,
    changes: dict[str, Any],
    *,
    yes: bool,
    change_baud: bool,
    as_json: bool,
) -> dict[str, Any]:
    """Read, validate, diff, confirm, write, verify.  Returns a JSON-able report."""
    servo = bus.servo(servo_id)
    current = await servo.read_eeprom()
    if "flags" in changes:
        # The FREE and PCM bits report state; they are the servo's, whatever the file says.
        changes["flags"] = Flags((int(changes["flags"]) & ~READ_ONLY_FLAGS) | (current.flags & READ_ONLY_FLAGS))
    wanted = current.replace(**changes)
    diff = current.diff(wanted)
    report: dict[str, Any] = {
        "id": servo_id,
        "changes": {k: [int(a), int(b)] for k, (a, b) in diff.items()},
        "written": False,
    }
    if not diff:
        if not as_json:
            out.print(f"servo {servo_id}: EEPROM already matches, nothing to write")
        return report
    wanted.check_writable()  # an unknown header or baud code: refuse before asking
    if wanted.baud_rate != current.baud_rate and not change_baud:
        raise baud_refusal(current.baud_rate, wanted.baud_rate)
    new_id = wanted.servo_id
    if new_id != current.servo_id and new_id != servo_id and not await id_is_free(bus, new_id):
        raise CliError(
            ExitCode.REFUSED,
            f"refused: ID {new_id} already answers on this line; two servos with one ID garble every reply. "
            "Nothing was written",
            "pick a free ID (see: ics35 scan)",
        )
    (err if as_json else out).print(diff_table(servo_id, current, wanted))
    if wanted.baud_rate != current.baud_rate:
        hs = " (625000/1250000 need the ICS USB adapter HS)" if wanted.baud_rate != BaudRate.B115200 else ""
        err.print(f"[yellow]warning:[/yellow] {BAUD_CONSEQUENCE.format(new=int(wanted.baud_rate), hs=hs)}")
    confirm(f"Write these {len(diff)} change(s) to servo {servo_id}'s EEPROM?", yes)
    try:
        await servo.write_eeprom(wanted, allow_baud_change=change_baud, allow_id_change=True)
    except ReplyTimeout:
        # A servo may switch to the new rate (or ID) before acknowledging; the read-back below decides.
        if wanted.baud_rate == current.baud_rate and wanted.servo_id == current.servo_id:
            raise
    report["written"] = True
    report["verified"] = await verify_after(settings, bus, servo_id, current, wanted)
    return report


async def verify_after(settings: Settings, bus: Bus, servo_id: int, before: Eeprom, after: Eeprom) -> bool:
    """Read the image back where the servo now answers (write_eeprom already did when ID and baud stayed).

    A new ID applies at once.  A new baud rate applies at the servo's next
    power-up (the reference: "from the next time on"), so the servo is read
    at the old rate first, then, for servos that switch at once, at the new one.
    """
    if after.baud_rate == before.baud_rate and after.servo_id == before.servo_id:
        return True
    try:
        back = await bus.servo(after.servo_id).read_eeprom()
    except ReplyTimeout:
        if after.baud_rate == before.baud_rate:
            raise
        async with settings.bus(int(after.baud_rate)) as other:
            back = await other.servo(after.servo_id).read_eeprom()
    if back != after:
        raise CliError(ExitCode.COMMUNICATION, f"read back differs after the write: {back.diff(after)}")
    return True


def report_done(report: dict[str, Any], as_json: bool) -> None:
    if as_json:
        emit_json(report)
        return
    if report["written"]:
        out.print(f"servo {report['id']}: {len(report['changes'])} EEPROM field(s) written and verified")
        changes = report["changes"]
        if "baud_rate" in changes:
            new = changes["baud_rate"][1]
            out.print(f"power-cycle the servo: from then on it talks only at {new} baud (use --baud {new})")
        if "servo_id" in changes:
            out.print(f"the servo now has ID {changes['servo_id'][1]}")


# --------------------------------------------------------------------------- restore


@eeprom.command()
@click.argument("servo_id", metavar="ID", type=SERVO_ID)
@click.argument("backup", metavar="FILE", type=click.File("r"))
@click.option("--restore-id", is_flag=True, help="Also write the ID stored in FILE (default: keep the servo's ID).")
@click.option(
    "--change-baud",
    is_flag=True,
    help="Allow FILE to change the baud rate (the servo then talks only at it).",
)
@yes_option
@json_option
@click.pass_context
def restore(
    ctx: click.Context,
    servo_id: int,
    backup: TextIO,
    restore_id: bool,
    change_baud: bool,
    yes: bool,
    as_json: bool,
) -> int:
    """Write a backup made by `eeprom dump` to servo ID (shows the diff, asks first).

    The servo keeps its own factory calibration bytes and read-only flags, and
    its ID unless --restore-id.  Use - as FILE for stdin (then pass --yes).
    """
    settings = settings_of(ctx)
    try:
        doc = json.load(backup)
        fields = fields_from_document(doc)
    except json.JSONDecodeError as exc:
        raise click.BadParameter(f"not JSON: {exc}", param_hint="FILE") from None
    except InvalidArgument as exc:
        raise click.BadParameter(str(exc), param_hint="FILE") from None
    if not restore_id:
        kept = fields.pop("servo_id")
        if kept != servo_id and not as_json:
            err.print(f"note: the backup is of ID {kept}; servo {servo_id} keeps its ID (--restore-id to write it)")
    try:
        precheck(fields)
    except (InvalidArgument, MalformedEeprom) as exc:
        raise click.BadParameter(str(exc), param_hint="FILE") from None

    async def body() -> dict[str, Any]:
        async with settings.bus() as bus:
            current = await bus.servo(servo_id).read_eeprom()
            changes = {k: v for k, v in fields.items() if int(getattr(current, k)) != v}
            return await apply_changes(
                settings, bus, servo_id, changes, yes=yes, change_baud=change_baud, as_json=as_json
            )

    report_done(run(settings, body), as_json)
    return 0


# --------------------------------------------------------------------------- set


def parse_assignment(text: str) -> tuple[str, int]:
    """``speed=100`` / ``flags=PWMINH|REVERSE`` / ``baud=1250000`` -> (field, value)."""
    name, eq, value = text.partition("=")
    name = name.strip().lower().replace("-", "_")
    name = FIELD_ALIASES.get(name, name)
    if not eq or not value.strip():
        raise InvalidArgument(f"{text!r} is not field=value")
    if name not in EEPROM_FIELDS:
        raise InvalidArgument(f"unknown EEPROM field {name!r}; fields: {', '.join(EEPROM_FIELDS)}")
    value = value.strip()
    if name == "flags" and not value.lstrip("-").isdigit() and not value.lower().startswith("0x"):
        bits = 0
        for part in value.replace(",", "|").split("|"):
            part = part.strip().upper()
            if not part or part in ("0", "NONE"):
                continue
            try:
                bits |= Flags[part]
            except KeyError:
                names = ", ".join(f.name or "" for f in Flags)
                raise InvalidArgument(f"unknown flag {part!r}; flags: {names}") from None
        return name, bits
    try:
        number = int(value, 0)
    except ValueError:
        raise InvalidArgument(f"{name} needs an integer, got {value!r}") from None
    if name == "baud_rate":
        number = int(BaudRate.parse(number))
    return name, number


@eeprom.command(name="set")
@click.argument("servo_id", metavar="ID", type=SERVO_ID)
@click.argument("assignments", metavar="FIELD=VALUE...", nargs=-1, required=True)
@click.option("--change-baud", is_flag=True, help="Allow baud_rate=... (the servo then talks only at that rate).")
@yes_option
@json_option
@click.pass_context
def set_fields(
    ctx: click.Context,
    servo_id: int,
    assignments: tuple[str, ...],
    change_baud: bool,
    yes: bool,
    as_json: bool,
) -> int:
    """Change EEPROM fields, e.g. `eeprom set 1 speed=100 flags=PWMINH`.

    \b
    Fields: stretch_gain (2..254 even), speed, punch, dead_band, damping, safe_timer,
    flags (names REVERSE,PWMINH,ROTATION,SLAVE joined by commas, or a number), pulse_limit_high, pulse_limit_low,
    baud_rate (needs --change-baud), temperature_limit, current_limit, response,
    user_offset (-127..127), servo_id (alias id), stretch_1..3.
    Factory calibration bytes cannot be changed.
    """
    settings = settings_of(ctx)
    changes: dict[str, int] = {}
    try:
        for text in assignments:
            name, value = parse_assignment(text)
            changes[name] = value
        precheck(changes)
    except (InvalidArgument, MalformedEeprom) as exc:
        raise click.BadParameter(str(exc), param_hint="FIELD=VALUE") from None

    async def body() -> dict[str, Any]:
        async with settings.bus() as bus:
            return await apply_changes(
                settings, bus, servo_id, dict(changes), yes=yes, change_baud=change_baud, as_json=as_json
            )

    report_done(run(settings, body), as_json)
    return 0


COMMANDS = [eeprom]
