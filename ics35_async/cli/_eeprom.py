"""eeprom set (and the eeprom group, with dump / restore from _eeprom_backup).

Every value is checked before the port opens; the new image is built from the
servo's own image by the library's EEPROM write rules
(:mod:`ics35_async.policies.eeprom_write`), so the factory calibration bytes
and the read-only flags stay the servo's; the diff is shown and confirmed; a
baud-rate change needs ``--change-baud``; an ID change is refused if the new ID
already answers.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import click

from ..eeprom import EEPROM_FIELDS, READ_ONLY_FLAGS, BaudRate, Flags
from ..errors import InvalidArgument, MalformedEeprom
from ..policies import check_changes, plan_eeprom_write
from ..units import closest_name
from ._common import SERVO_ID, CliError, NegativeNumbersCommand, json_option, run, settings_of, yes_option
from ._eeprom_backup import dump, restore
from ._eeprom_write import WriteBatch, finish, said_nothing_written, write_plans

FIELD_ALIASES = {"baud": "baud_rate", "id": "servo_id", "stretch": "stretch_gain"}


@click.group()
def eeprom() -> None:
    """Back up, restore and change a servo's EEPROM (its persistent settings)."""


eeprom.add_command(dump)
eeprom.add_command(restore)


@dataclass
class Edit:
    """What `eeprom set` was asked to change."""

    changes: dict[str, int] = field(default_factory=dict)
    set_flags: int = 0
    clear_flags: int = 0


def parse_flag_names(text: str) -> int:
    """``PWMINH,REVERSE`` / ``PWMINH|REVERSE`` / ``0x08`` -> bits (the library refuses the read-only ones)."""
    text = text.strip()
    if text.lstrip("-").isdigit() or text.lower().startswith("0x"):
        try:
            return int(text, 0)
        except ValueError:
            raise InvalidArgument(f"flags needs names or an integer, got {text!r}") from None
    bits = 0
    for part in text.replace(",", "|").split("|"):
        part = part.strip().upper()
        if not part or part in ("0", "NONE"):
            continue
        try:
            flag = Flags[part]
        except KeyError:
            names = [f.name or "" for f in Flags if not f & READ_ONLY_FLAGS]
            close = closest_name(part, names)
            if close is not None:
                raise InvalidArgument(f"unknown flag {part!r}: did you mean {close}?") from None
            raise InvalidArgument(f"unknown flag {part!r}; flags: {', '.join(names)}") from None
        bits |= flag
    return bits


def parse_assignment(text: str, edit: Edit) -> None:
    """``speed=100`` / ``flags=PWMINH|REVERSE`` / ``flags+=REVERSE`` / ``flags-=PWMINH`` / ``baud=1250000``."""
    name, eq, value = text.partition("=")
    op = ""
    if name.endswith(("+", "-")):
        name, op = name[:-1], name[-1]
    name = name.strip().lower().replace("-", "_")
    name = FIELD_ALIASES.get(name, name)
    if not eq or not value.strip():
        raise InvalidArgument(f"{text!r} is not field=value")
    if name not in EEPROM_FIELDS:
        close = closest_name(name, [*EEPROM_FIELDS, *FIELD_ALIASES])
        # (the list too: the closest of two near names, pulse_limit_low for pulse_limit, may not be the one meant)
        meant = "" if close is None else f": did you mean {FIELD_ALIASES.get(close, close)}?"
        raise InvalidArgument(f"unknown EEPROM field {name!r}{meant} (fields: {', '.join(EEPROM_FIELDS)})")
    if op and name != "flags":
        raise InvalidArgument(f"only flags takes {op}= (flags+=NAME sets a flag, flags-=NAME clears one)")
    if name == "flags":
        bits = parse_flag_names(value)
        if op == "+":
            edit.set_flags |= bits
        elif op == "-":
            edit.clear_flags |= bits
        else:
            if "flags" in edit.changes and edit.changes["flags"] != bits:
                raise InvalidArgument("flags is given twice: give it once (flags+=NAME and flags-=NAME add to it)")
            edit.changes["flags"] = bits
        return
    try:
        number = int(value.strip(), 0)
    except ValueError:
        raise InvalidArgument(f"{name} needs an integer, got {value.strip()!r}") from None
    if name == "baud_rate":
        number = int(BaudRate.parse(number))
    if name in edit.changes and edit.changes[name] != number:  # (the last one taken, silently, was a guess)
        raise InvalidArgument(f"{name} is given twice ({edit.changes[name]} and {number}): give it once")
    edit.changes[name] = number


@eeprom.command(
    name="set", cls=NegativeNumbersCommand, short_help="Change EEPROM fields: eeprom set 1 speed=100 flags+=PWMINH."
)
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
    """Change EEPROM fields, e.g. `eeprom set 1 speed=100 flags+=PWMINH`.

    \b
    Fields: stretch_gain (2..254 even), speed, punch, dead_band, damping, safe_timer,
    flags, pulse_limit_high, pulse_limit_low, baud_rate (needs --change-baud),
    temperature_limit, current_limit, response, user_offset (-127..127),
    servo_id (alias id), stretch_1..3.
    Flags: REVERSE, PWMINH, ROTATION, SLAVE.  flags+=NAME sets one, flags-=NAME
    clears one and keeps the others; flags=NAME,NAME replaces them all (the diff
    names every flag it clears).  FREE and PCM are read-only; the unused bits
    5-6 stay as the servo has them (flags-=0x60 clears them).
    Stretch, speed and the limits reach the servo's RAM at its next power-up
    (ics35 set changes the RAM now).  Factory calibration bytes cannot be changed.
    """
    settings = settings_of(ctx)
    edit = Edit()
    try:
        for text in assignments:
            parse_assignment(text, edit)
        check_changes(edit.changes, set_flags=edit.set_flags, clear_flags=edit.clear_flags)
    except (InvalidArgument, MalformedEeprom) as exc:
        raise click.BadParameter(str(exc), param_hint="FIELD=VALUE") from None

    reading = False  # the line open, the servo being read: a failure then comes before any write
    planned = False  # the servo read and its write planned: until then nothing was written

    async def body() -> WriteBatch:
        nonlocal reading, planned
        async with settings.bus() as bus:
            reading = True
            plan = await plan_eeprom_write(
                bus, servo_id, edit.changes, set_flags=edit.set_flags, clear_flags=edit.clear_flags
            )
            planned = True
            return await write_plans(
                bus,
                [plan],
                yes=yes,
                change_baud=change_baud,
                allow_id_change="servo_id" in edit.changes,
                as_json=as_json,
                asked_cleared=edit.clear_flags,
            )

    try:
        batch = run(settings, body)
    except CliError as exc:
        if reading and not planned:
            said_nothing_written(exc, "the servo")
        raise
    finish(settings, batch, as_json)
    return 0


COMMANDS = [eeprom]
