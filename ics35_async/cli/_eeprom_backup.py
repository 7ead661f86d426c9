"""eeprom dump / restore: back up servos' EEPROMs to JSON files and write them back, one or many at a time."""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import click
from rich.markup import escape

from ..bus import Bus
from ..eeprom import Eeprom, Flags
from ..errors import ClosedByPortLoss, InvalidArgument, MalformedEeprom, PortLost, ReplyError, UnsafeOperation
from ..policies import EepromPlan, plan_eeprom_write, probe_ids, read_eeprom_agreed
from ..policies.eeprom_backup import (
    GARBLED_WHY,
    Backups,
    backup_changes,
    backup_document,
    backup_file_name,
    backups_document,
    backups_in,
    no_reply_why,
    plan_restores,
    port_lost_why,
    read_failed_why,
)
from ..user_files import (
    UnreadableText,
    decode_user_text,
    empty_path,
    parse_json,
    read_user_text,
    replace_keeping_backup,
)
from ._common import (
    ID_LIST,
    SERVO_ID,
    CliError,
    ExitCode,
    NegativeNumbersCommand,
    NobodyAnswered,
    Settings,
    emit_json,
    every_id,
    id_ranges,
    ids_text,
    json_option,
    out,
    run,
    settings_of,
    yes_option,
)
from ._console import SIMULATED_KEY, say, say_labelled
from ._eeprom_view import eeprom_table
from ._eeprom_write import WriteBatch, finish, said_nothing_written, write_plans
from ._paths import check_backup_path, check_output_dir, check_output_path, names_directory
from ._runner import line_error

# --------------------------------------------------------------------------- dump


def output_target(ids: list[int], output: str | None, as_table: bool) -> tuple[str, Path | None]:
    """Where the dump goes ("stdout", "file", "dir" or "several": one document of several servos' backups), checked
    before the line is touched: for "dir", the directory (each servo's file in it named as
    :func:`backup_file_name` names it), else the file (one servo's into a directory: its file there; None:
    stdout)."""
    if output is None:
        if len(ids) > 1 and not as_table:
            raise click.BadParameter(
                "several servos need -o DIR/ (one file per servo), -o FILE.json (one file of them all) or -o - "
                "(them all on stdout)",
                param_hint="IDS",
            )
        return "stdout", None
    if output == "-":  # stdout, as `eeprom restore -` reads stdin (several servos: one document of them all)
        return ("stdout" if len(ids) == 1 else "several"), None
    if empty_path(output):
        raise click.BadParameter("the path is empty; give a file name or DIR/", param_hint="--output")
    if names_directory(output):
        if len(ids) == 1:  # (its file in it named as a dump of several names it: DIR/servo-01.json)
            return "file", check_output_path(output, "--output", default_name=backup_file_name(ids))
        return "dir", check_output_dir(output, "--output")
    path = Path(output)
    if len(ids) > 1 and path.suffix.lower() != ".json" and not path.is_file():
        # A name that is neither a JSON file's nor a folder's yet: which of the two is meant cannot be told.
        raise click.BadParameter(
            f"several servos: -o {output}/ (one file per servo) or -o {output}.json (one file of them all)",
            param_hint="--output",
        )
    return ("file" if len(ids) == 1 else "several"), check_output_path(output, "--output")


def dump_document(image: Eeprom, servo_id: int, settings: Settings) -> dict[str, Any]:
    doc = backup_document(image, servo_id, baud=settings.baud, port=settings.port)
    if settings.simulated:  # (a file too, not only stdout: its plausible data must not pass for a servo's)
        doc[SIMULATED_KEY] = True
    return doc


@dataclass
class ImagesRead:
    """The EEPROM images read; if the port was lost before all were, the error to tell once they are saved
    and the IDs that answered but were not read."""

    images: dict[int, Eeprom]
    lost: CliError | None = None
    unread: list[int] = field(default_factory=list)
    garbled: list[int] = field(default_factory=list)  # answered garbled to the probe (two servos on one ID?)
    failed: dict[int, str] = field(default_factory=dict)  # answered the probe, its EEPROM read failed -> why


async def read_images(settings: Settings, ids: list[int]) -> ImagesRead:
    """One servo's image (its errors raise), or the images of those of several that answer (a lost port
    after the first of them ends the reading, keeping what was read)."""
    # Read until two reads agree: an EEPROM reply has no checksum, and a backup is written back one day.
    async with settings.bus() as bus:
        if len(ids) == 1:
            return ImagesRead({ids[0]: await read_eeprom_agreed(bus, ids[0])})
        rate = await probe_ids(bus, ids)
        images: dict[int, Eeprom] = {}
        failed: dict[int, str] = {}
        garbled = sorted(rate.garbled)
        for n, i in enumerate(rate.answered):
            try:
                images[i] = await read_eeprom_agreed(bus, i)
            except ReplyError as exc:
                say_labelled("[yellow]warning:[/yellow]", f"servo {i}: EEPROM read failed: {escape(exc.reason)}")
                failed[i] = read_failed_why(exc, settings.baud, echo=settings.echo)
            except (PortLost, ClosedByPortLoss) as exc:
                if not images:
                    raise
                # The error in words now, while the port's name is known; told once the images are saved.
                return ImagesRead(images, line_error(settings, exc), list(rate.answered[n:]), garbled, failed)
        if not images and not garbled:
            where = f"{settings.port} at {settings.baud} baud (IDs {id_ranges(ids)})"
            raise NobodyAnswered(settings, where, silent=rate.silent)
        return ImagesRead(images, garbled=garbled, failed=failed)


def write_backup(path: Path, doc: dict[str, Any]) -> Path | None:
    """Write the backup whole; an earlier file there is kept as ``NAME.bak`` (returned), never overwritten: it
    may be the one the user restores to."""
    try:
        path.parent.mkdir(exist_ok=True)  # (-o DIR/: its parent is there, see check_output_dir)
        return replace_keeping_backup(path, json.dumps(doc, indent=2) + "\n")
    except OSError as exc:
        raise CliError(ExitCode.USAGE, f"cannot write {path}: {exc.strerror or exc}") from None


@click.command(cls=NegativeNumbersCommand)
@click.argument("ids", metavar="IDS", type=ID_LIST)
@click.option(
    "--output",
    "-o",
    metavar="FILE|DIR/",
    help="Write to FILE (several servos: all in it), or one file per servo into DIR/ (-: stdout).",
)
@click.option("--table", "as_table", is_flag=True, help="Print a readable table instead of JSON.")
# Not "as_json": JSON is this command's default output, not a choice made with the flag.
@click.option("--json", "json_default", is_flag=True, hidden=True, help="JSON (the default; accepted for scripts).")
@click.pass_context
def dump(ctx: click.Context, ids: list[int], output: str | None, as_table: bool, json_default: bool) -> int:
    """Save EEPROMs as JSON (the backup format `eeprom restore` reads).

    \b
    One servo:   ics35 eeprom dump 1 > servo1.json    (or -o servo1.json)
    Several:     ics35 eeprom dump 1-20 -o backup/    (backup/servo-01.json, ...)
    In one file: ics35 eeprom dump 1-20 -o robot.json (as ics35 web's Back up all)
    """
    settings = settings_of(ctx)
    if as_table and (json_default or settings.json_output):
        raise CliError(ExitCode.USAGE, "--table and --json ask for two outputs: give one (JSON is the default)")
    kind, path = output_target(ids, output, as_table)
    if path is not None and not as_table:  # (an earlier backup there is kept as NAME.bak: room for it first)
        for target in [path / backup_file_name([i]) for i in ids] if kind == "dir" else [path]:  # (one: "several")
            check_backup_path(target, "--output")
    try:
        read = run(settings, lambda: read_images(settings, ids))
    except CliError as exc:
        if exc.code is not ExitCode.INTERRUPTED:
            raise
        # (the files are written once every servo is read: a backup already there is untouched)
        untouched = "the files there are as they were" if kind == "dir" else "a file there is as it was"
        saved = "nothing was shown" if as_table or path is None else f"nothing was saved ({untouched})"
        raise CliError(ExitCode.INTERRUPTED, f"interrupted while the servos were read: {saved}") from None
    images = read.images
    for i, image in images.items():
        if image.unknown_codes:
            codes = ", ".join(f"{name} 0x{code:02X}" for name, code in image.unknown_codes.items())
            say_labelled(
                "[yellow]warning:[/yellow]",
                f"servo {i}'s EEPROM holds unknown code(s), not in ICS 3.5 ({codes}): "
                "kept exactly as read; an image holding them cannot be written back",
            )
    there = set(read.unread) | set(read.garbled) | set(read.failed)  # answered, not saved (told apart below)
    missing = [i for i in ids if i not in images and i not in there]
    if missing and len(ids) > 1:
        if every_id(ids):  # "all": the servos on the line, whichever they are
            answered = sorted([*images, *read.unread, *read.garbled, *read.failed])
            say(
                f"{len(answered)} servo{'' if len(answered) == 1 else 's'} answered at {settings.baud} baud: "
                f"{'ID' if len(answered) == 1 else 'IDs'} {ids_text(answered)} (a servo "
                f"at another rate does not: {settings.command_line('scan')} finds every rate)"
            )
        elif read.lost is not None or read.garbled or read.failed:  # (else the dump's own error, at its end)
            say_labelled("[yellow]warning:[/yellow]", f"no answer from ID(s) {ids_text(missing)}: not saved")
    if read.garbled:
        say_labelled(
            "[yellow]warning:[/yellow]",
            f"ID(s) {ids_text(read.garbled)} answered garbled: not saved (two servos "
            "sharing an ID, most likely: connect them one at a time and renumber one; or noise)",
        )
    if as_table:
        for i, image in images.items():
            out.print(eeprom_table(image, f"EEPROM of servo {i}"))
    elif kind == "several":
        if images:  # (the servos asked for that are not in it named in the file too: see not_saved)
            doc = backups_document(
                [dump_document(image, i, settings) for i, image in images.items()],
                {
                    **({} if every_id(ids) else dict.fromkeys(missing, no_reply_why(settings.baud))),
                    **dict.fromkeys(read.garbled, GARBLED_WHY),
                    **read.failed,
                    **(dict.fromkeys(read.unread, port_lost_why(read.unread[0])) if read.unread else {}),
                },
            )
            if path is None:
                emit_json(doc)
            else:
                kept = write_backup(path, doc)
                also = f" (the file there before kept as {escape(str(kept))})" if kept is not None else ""
                say(f"EEPROMs of servos {id_ranges(images)} saved to {escape(str(path))}{also}")
    else:
        for i, image in images.items():
            doc = dump_document(image, i, settings)
            if kind == "stdout":
                emit_json(doc)
                continue
            assert path is not None
            target = path / backup_file_name([i]) if kind == "dir" else path
            kept = write_backup(target, doc)
            also = f" (the file there before kept as {escape(str(kept))})" if kept is not None else ""
            say(f"EEPROM of servo {i} saved to {escape(str(target))}{also}")
    done = f"servo(s) {ids_text(images)} {'shown above' if as_table else 'saved'}"  # (the hints after a failure)
    if read.lost is not None:
        failure = read.lost
        rest = ",".join(str(i) for i in read.unread)
        # (a file of several: the rest into another, the same name would put this one aside as .bak)
        into = str(path.parent / backup_file_name(read.unread)) if kind == "several" and path else str(output)
        again = ["eeprom", "dump", rest, *(["--table"] if as_table else ["-o", into])]
        failure.hints.append(f"{done}; when the line is back, read the rest: {settings.command_line(*again)}")
        raise failure
    unsaved = sorted([*read.garbled, *read.failed])
    if unsaved:  # servos that are there, and are not in the backup: not a success for a script to go on from
        raise CliError(
            ExitCode.COMMUNICATION,
            f"servo(s) at ID(s) {ids_text(unsaved)} answered but could not be saved (see above)",
            *([done] if images else []),
        )
    if missing and len(ids) > 1 and not every_id(ids):
        # IDs listed are servos expected: a backup missing some is not a success for a script to go on from.
        raise CliError(
            ExitCode.NO_REPLY,
            f"no answer from ID(s) {ids_text(missing)} at {settings.baud} baud: not saved",
            *([done] if images else []),
            f"a servo at another rate does not answer at this one ({settings.command_line('scan')} finds every "
            f"rate); {settings.command_line('eeprom', 'dump', 'all')} saves whichever servos answer",
        )
    return 0


# --------------------------------------------------------------------------- restore


BACKUP_IS = "a backup is UTF-8 JSON"  # (what a file given as one should be, for its refusal)


@dataclass
class Backup:
    """One checked backup and the servo it goes to."""

    source: str  # the file it is in
    target: int
    fields: dict[str, int]
    saved_id: int  # the ID the backup was saved from
    simulated: bool = False  # read from the implicit built-in simulator, not a servo
    together: bool = False  # in a file of several servos' backups (one of them is restored by ID FILE)


def read_backups(source: str) -> Backups:
    """One file's backups, checked whole (BadParameter, naming the file, on anything wrong)."""
    try:
        if source == "-":
            stdin = getattr(sys.stdin, "buffer", None)  # (the bytes, decoded as UTF-8 whatever the locale)
            try:  # (from the words on: a Ctrl-C pressed as they show lands before the read begins)
                if sys.stdin.isatty():  # (typed at a terminal, nothing piped: waiting silently looked hung)
                    say("reading the backup from standard input: paste it, then Ctrl-D (Windows: Ctrl-Z, Enter)")
                raw = stdin.read() if stdin is not None else sys.stdin.read().encode("utf-8")
            except KeyboardInterrupt:  # (said as every command's Ctrl-C is: what was done, here nothing)
                raise CliError(
                    ExitCode.INTERRUPTED,
                    "interrupted while the backup was read from standard input: nothing was written",
                ) from None
            text = decode_user_text(raw, BACKUP_IS)
        else:
            text = read_user_text(source, BACKUP_IS)
        return backups_in(parse_json(text))
    except OSError as exc:
        raise click.BadParameter(f"{source}: {exc.strerror or exc}", param_hint="FILE") from None
    except UnreadableText as exc:
        raise click.BadParameter(f"{source}: {exc}", param_hint="FILE") from None
    except json.JSONDecodeError as exc:
        raise click.BadParameter(f"{source}: not JSON: {exc}", param_hint="FILE") from None
    except (InvalidArgument, MalformedEeprom) as exc:
        raise click.BadParameter(f"{source}: {exc}", param_hint="FILE") from None


def load_backup(source: str, target: int | None, restore_id: bool, keep_baud: bool = False) -> list[Backup]:
    """The backups of one file, checked, each with the servo it goes to: ``target`` (one servo's backup whichever
    servo it was saved from; from a file of several, the one of ``target``), or without it each to the servo it
    was saved from (BadParameter, naming the file, on anything wrong)."""
    held = read_backups(source)
    try:
        docs = list(held.servos.values()) if target is None else [held.backup_for(target)]
        backups: list[Backup] = []
        for doc in docs:
            changes = backup_changes(doc, restore_id=restore_id, keep_baud=keep_baud)
            saved_id = changes.saved_id
            simulated = doc.get(SIMULATED_KEY) is True
            goes_to = saved_id if target is None else target
            backups.append(Backup(source, goes_to, changes.fields, saved_id, simulated, held.several))
    except (InvalidArgument, MalformedEeprom) as exc:
        raise click.BadParameter(f"{source}: {exc}", param_hint="FILE") from None
    if not backups:
        lacking = "; ".join(f"servo(s) {id_ranges(ids)}: {why}" for why, ids in not_saved_by_words(held).items())
        when = f" (when it was saved, {lacking})" if lacking else ""
        raise click.BadParameter(f"{source}: the file holds no servo's backup{when}", param_hint="FILE")
    if target is None:
        for why, ids in not_saved_by_words(held).items():
            say_labelled(
                "[yellow]note:[/yellow]",
                f"{escape(source)} holds no backup of servo{'s' if len(ids) > 1 else ''} {id_ranges(ids)} "
                f"(when it was saved: {escape(why)})",
            )
    return backups


def not_saved_by_words(held: Backups) -> dict[str, list[int]]:
    """The servos a file of several says it does not hold, by the words said of them (the same words once)."""
    by_words: dict[str, list[int]] = {}
    for servo_id, why in sorted(held.not_saved.items()):
        by_words.setdefault(why, []).append(servo_id)
    return by_words


def load_backups(args: tuple[str, ...], restore_id: bool, keep_baud: bool = False) -> list[Backup]:
    if len(args) == 2:
        try:
            target = SERVO_ID.convert(args[0], None, None)
        except click.BadParameter as exc:
            raise click.BadParameter(exc.message, param_hint="ID") from None
        return load_backup(args[1], target, restore_id, keep_baud)
    if len(args) != 1:
        raise click.BadParameter("give ID FILE, FILE or DIR", param_hint="[ID] FILE|DIR")
    if not Path(args[0]).is_dir():
        return load_backup(args[0], None, restore_id, keep_baud)
    files = sorted(str(p) for p in Path(args[0]).glob("*.json"))
    if not files:
        raise click.BadParameter(f"no *.json backups in {args[0]}", param_hint="DIR")
    backups = [backup for name in files for backup in load_backup(name, None, restore_id, keep_baud)]
    seen: dict[int, str] = {}
    for backup in backups:
        if backup.target in seen:
            raise click.BadParameter(
                f"{seen[backup.target]} and {backup.source} are both backups of servo {backup.target}", param_hint="DIR"
            )
        seen[backup.target] = backup.source
    return backups


RESTORE_BAUD_ADVICE = (
    "to restore the rest and keep the servo at the rate it has now, add --keep-baud",
    "to write the backup's rate too, add --change-baud",
)


async def plan_restore(bus: Bus, backups: list[Backup], bulk: bool) -> list[EepromPlan]:
    """Every backup's write, planned; nothing is written.

    One file goes to one servo at the line's rate: one that answers elsewhere is told "pass --baud" as by
    every command.  The servos of a DIR, or of a file of several servos' backups restored whole, may answer
    at different rates (some moved to 1,250,000, others not), and
    no one --baud reaches them all: each is planned at the rate it answers at (policies.eeprom_backup's
    plan_restores), then written and verified there, after one question over every diff.
    """
    if not bulk:
        return [await plan_eeprom_write(bus, b.target, b.fields, keep_read_only=True) for b in backups]
    try:
        return await plan_restores(bus, {b.target: b.fields for b in backups})
    except UnsafeOperation as exc:  # an ID at two rates: two servos, and whose the backup is cannot be told
        raise CliError(
            ExitCode.REFUSED,
            f"refused: {exc}",
            "connect one of them at a time, or restore it by its file: ics35 --baud RATE eeprom restore FILE",
        ) from None


def restore_flag_advice(settings: Settings, plan: EepromPlan) -> str:
    """restore writes the backup's flags as saved: to keep a flag it clears, decline, or set it again after."""
    names = [flag.name for flag in Flags if flag.name and flag in Flags(plan.cleared_flags)]
    again = settings.command_line("eeprom", "set", str(plan.servo_id), *(f"flags+={name}" for name in names))
    return f"restore writes the backup's flags as saved: to keep them, answer no, or set them again after: {again}"


@click.command(
    cls=NegativeNumbersCommand,
    short_help="Write backups made by `eeprom dump`, checked first (every diff shown, one question).",
)
@click.argument("args", metavar="[ID] FILE|DIR", nargs=-1, required=True)
@click.option("--restore-id", is_flag=True, help="Also write the ID stored in FILE (default: keep the servo's ID).")
@click.option(
    "--change-baud", is_flag=True, help="Allow a backup to change the baud rate (the servo then talks only at it)."
)
@click.option(
    "--keep-baud", is_flag=True, help="Write everything but the baud rate: each servo stays at the rate it has now."
)
@yes_option
@json_option
@click.pass_context
def restore(
    ctx: click.Context,
    args: tuple[str, ...],
    restore_id: bool,
    change_baud: bool,
    keep_baud: bool,
    yes: bool,
    as_json: bool,
) -> int:
    """Write backups made by `eeprom dump` (shows every diff, asks once).

    \b
    ics35 eeprom restore 2 servo1.json   servo 2 gets servo 1's settings
    ics35 eeprom restore servo1.json     back to the servo the file was saved from
    ics35 eeprom restore backup/         every file in backup/ to its own servo
    ics35 eeprom restore servos.json     a file of several (ics35 web's Back up all):
                                         each servo in it to its own servo
    ics35 eeprom restore 2 servos.json   servo 2 from its own backup in that file

    Each servo keeps its own factory calibration bytes and read-only flags, and
    its ID unless --restore-id.  A backup naming another baud rate than the
    servo's is refused unless --keep-baud (the servo keeps its rate) or
    --change-baud (it takes the backup's).  The servos of a DIR or of a file of
    several are each restored at the rate they answer at.  Use - as FILE for
    stdin (then pass --yes).
    """
    settings = settings_of(ctx)
    if keep_baud and change_baud:
        raise click.UsageError("--keep-baud and --change-baud: choose one (keep the servo's rate, or the backup's)")
    backups = load_backups(args, restore_id, keep_baud)
    # Once a file: a file of several servos' backups was saved from the simulator as a whole.
    for source in dict.fromkeys(backup.source for backup in backups if backup.simulated):
        say_labelled(
            "[yellow]warning:[/yellow]",
            f"{escape(source)} was read from the built-in simulator (no --port when it was saved), not from a servo",
        )
    for backup in backups:
        if backup.saved_id != backup.target and not restore_id and not as_json:
            say_labelled(
                "[yellow]note:[/yellow]",
                f"{escape(backup.source)} is a backup of ID {backup.saved_id}; servo {backup.target} keeps "
                "its ID (--restore-id to write it)",
            )

    reading = False  # the servos are being read (the line opened): a failure then comes before any write
    planned = False  # every servo read and its write planned: until then nothing was written
    silent: list[int] = []  # the servo whose read failed, then
    bulk = len(args) == 1 and (Path(args[0]).is_dir() or backups[0].together)  # (several servos, each its own)

    async def body() -> WriteBatch:
        nonlocal reading, planned
        async with settings.bus() as bus:
            reading = True
            try:
                plans = await plan_restore(bus, backups, bulk)
            except ReplyError as exc:
                silent.extend([] if exc.servo_id is None else [exc.servo_id])
                raise
            planned = True
            return await write_plans(
                bus,
                plans,
                yes=yes,
                change_baud=change_baud,
                allow_id_change=restore_id,
                as_json=as_json,
                flag_advice=lambda plan: restore_flag_advice(settings, plan),
                baud_advice=RESTORE_BAUD_ADVICE,
            )

    again = ["eeprom", "restore", *args]
    again += [
        flag
        for flag, on in (("--restore-id", restore_id), ("--change-baud", change_baud), ("--keep-baud", keep_baud))
        if on
    ]
    try:
        batch = run(settings, body)
    except CliError as exc:
        if reading and not planned and said_nothing_written(exc, "the servos"):
            # Every servo is read before any is written: one missing servo holds the others back until it is
            # back, or until its backup is out of the way.
            missing = [b for b in backups if b.target in silent] if bulk and len(backups) > 1 else []
            if missing and missing[0].together:  # (its file holds the others' too: they go one by one)
                source = missing[0].source
                others = [b.target for b in backups if b.source == source and b.target != silent[0]]
                exc.hints.insert(
                    1,
                    f"to restore the others without servo {silent[0]}, restore each alone: "
                    f"{settings.command_line('eeprom', 'restore', 'ID', source)} (ID: {id_ranges(others)})",
                )
            elif missing:
                exc.hints.insert(
                    1, f"to restore the others without servo {silent[0]}, move {missing[0].source} out of {args[0]}"
                )
        # (Not where the servo answers at another rate: it is the file's own servo, and the rate is the mend.)
        if exc.code is ExitCode.NO_REPLY and len(args) == 1 and not bulk:
            source = backups[0].source
            exc.hints.append(
                f"{source} is a backup of servo {backups[0].saved_id}; to write it to another servo: "
                + settings.command_line("eeprom", "restore", "ID", source)
            )
        raise
    finish(settings, batch, as_json, bulk=bulk, again=again)
    return 0
