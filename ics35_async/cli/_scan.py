"""scan and set-id: the library's scan and safe ID write, put in front of a person."""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator, Callable, Sequence
from dataclasses import replace

import click
from rich import box
from rich.markup import escape
from rich.table import Table

from .. import policies
from ..bus import Bus
from ..errors import BusClosed, PortLost, ReplyError
from ..policies import FoundServo, IdSurvey, Refusal, ScanReport, echo_setting_wrong
from ..transports import rate_blind_note
from ._common import (
    ALL_BAUDS,
    BAUD_LIST,
    NO_REPLY_HINTS,
    SERVO_ID,
    CliError,
    ExitCode,
    NegativeNumbersCommand,
    Settings,
    all_ids_option,
    answered_garbled,
    confirm,
    emit_json,
    every_id,
    ids_text,
    json_option,
    no_servo_among,
    nothing_answered,
    out,
    run,
    seconds_option,
    settings_of,
    translate,
    yes_option,
)
from ._console import ids_argument, print_heading, printed_table, say, say_labelled, scan_progress
from ._eeprom_view import baud_text, flags_text
from ._errors import answered_at_another_id

# --------------------------------------------------------------------------- scan


async def scan_with_progress(
    settings: Settings,
    bauds: Sequence[int],
    ids: Sequence[int],
    *,
    read_eeprom: bool,
    timeout: float | None,
    show_progress: bool,
    on_found: Callable[[int, int], object] | None = None,
) -> ScanReport:
    """The library's scan, opening the port at each rate, with a progress bar on a terminal once it has opened
    (``on_found``: the library's, each servo as it answers)."""
    with scan_progress(bauds, len(ids), show=show_progress) as steps:

        @contextlib.asynccontextmanager
        async def open_at(baud: int) -> AsyncIterator[Bus]:
            async with settings.bus(baud, timeout=timeout) as bus:
                steps.line_open()
                yield bus

        return await policies.scan(
            open_at, bauds=bauds, ids=ids, read_eeprom=read_eeprom, on_probe=steps.advance, on_found=on_found
        )


def baud_cell(s: FoundServo) -> str:
    """The rate as known: with a ? when the servo answered there but its EEPROM could not be read."""
    return f"{s.baud}?" if s.rate_unconfirmed else str(s.baud)


# The columns of the scan's table a terminal too narrow for it goes without, in turn (named under the table): the
# limits first, kept whole by `ics35 info ID` and `ics35 eeprom dump ID --table`.
LEAVE_OUT = ("pulse range", "T-limit", "I-limit", "offset")

# Whose settings the table shows: the EEPROM's, which the servo loads into RAM at power-up; `get` reads RAM, where a
# `set` since then shows, and where the stretch is on its own scale (half the EEPROM's stretch_gain).
EEPROM_TITLE = "servos found, with the settings in their EEPROM (loaded into RAM at power-up; ics35 get reads RAM)"


def scan_heading(servos: Sequence[FoundServo]) -> str:
    """What goes above the scan's table (not its title: rich cuts a title at the table's width)."""
    return "servos found" if all(s.eeprom is None for s in servos) else EEPROM_TITLE


def scan_table(servos: Sequence[FoundServo]) -> Table:
    table = Table(box=box.SIMPLE_HEAD, pad_edge=False, collapse_padding=True)
    if all(s.eeprom is None for s in servos):
        # (values whole: a column that may wrap, beside an empty one, was cut even at a log's unlimited width)
        table.add_column("ID", justify="right", no_wrap=True)
        table.add_column("baud", justify="right", no_wrap=True)
        table.add_column("")
        for s in servos:
            table.add_row(str(s.servo_id), baud_cell(s), "rate unconfirmed" if s.rate_unconfirmed else "")
        return table
    # (values whole, never cut: a terminal too narrow leaves columns out instead, see printed_table)
    for name in ("ID", "baud", "stretch_gain", "speed", "I-limit", "T-limit", "pulse range", "offset"):
        table.add_column(name, justify="right", no_wrap=True)
    table.add_column("flags")
    for s in servos:
        e = s.eeprom
        if e is None:
            why = "rate unconfirmed (EEPROM not read)" if s.rate_unconfirmed else "(EEPROM not read)"
            table.add_row(str(s.servo_id), baud_cell(s), *["?"] * 6, why)
            continue
        note = f" (EEPROM: {baud_text(e.baud_rate)})" if s.baud_pending else ""
        table.add_row(
            str(s.servo_id),
            f"{s.baud}{note}",
            str(e.stretch_gain),
            str(e.speed),
            str(e.current_limit),
            str(e.temperature_limit),
            f"{e.pulse_limit_low}-{e.pulse_limit_high}",
            f"{e.user_offset:+d}",
            flags_text(e.flags),
        )
    return table


def scan_json(settings: Settings, bauds: Sequence[int], report: ScanReport) -> None:
    emit_json(
        {
            "port": settings.port,
            "bauds": list(bauds),
            "servos": [
                {
                    "id": s.servo_id,
                    "baud": s.baud,
                    "answered_at": list(s.answered_at),
                    "rate_confirmed": not s.rate_unconfirmed,
                    "eeprom": None if s.eeprom is None else s.eeprom.to_dict(),
                }
                for s in report.servos
            ],
            "garbled": [{"id": i, "baud": baud} for baud, i, _ in report.garbled],
            "skipped_bauds": {str(baud): why for baud, why in report.skipped.items()},
            "rate_blind": report.rate_blind,
            "id_read_only": [{"baud": r.baud, "id": r.id_answer} for r in report.rates if r.only_id_read],
            # (none of the IDs asked answered there, but a device at an ID not asked did: its ID, null if several)
            "answered_elsewhere": [{"baud": r.baud, "id": r.id_answer} for r in report.rates if r.elsewhere],
            "lost": None if report.lost is None else settings.as_given(str(report.lost)),
        }
    )


def scan_notes(settings: Settings, report: ScanReport) -> None:
    if report.rate_blind:
        say_labelled(
            "[yellow]note:[/yellow]",
            f"{escape(rate_blind_note(settings.port))}; probed once. "
            + ("Each servo's rate shown is its EEPROM's." if any(s.eeprom for s in report.servos) else ""),
        )
    for baud, why in report.skipped.items():
        say_labelled("[yellow]warning:[/yellow]", f"skipped {baud} baud: {escape(why)}")
    for s in report.servos:
        if s.eeprom_error is not None:
            heard = ", ".join(str(b) for b in s.answered_at)
            again = settings.command_line("--baud", str(s.baud), "eeprom", "dump", str(s.servo_id), "--table")
            say_labelled(
                "[yellow]warning:[/yellow]",
                f"servo {s.servo_id}: its EEPROM could not be read (after retries), so its "
                f"rate is unconfirmed: it answered at {heard} baud; read it again with: {escape(again)}  "
                f"(last error: {escape(s.eeprom_error.reason)})",
            )
    # IDs that answered garbled where no wrong echo setting explains it (said twice: here and in the summary)
    garbled_ids = [(i, baud) for baud, i, _ in report.garbled] if report.echo_evidence is None else []
    if garbled_ids:
        where = ", ".join(f"ID {i} at {baud}" for i, baud in garbled_ids)
        say_labelled(
            "[yellow]warning:[/yellow]",
            f"garbled replies from {where}: two servos sharing an ID, a servo at another baud rate, or noise",
        )
    for rate in report.rates:
        if rate.only_id_read:
            say_labelled(
                "[yellow]note:[/yellow]",
                f"at {rate.baud} baud a device answered the ID read (as ID {rate.id_answer}) "
                "but no stretch read: if that ID was not scanned, try --ids "
                f"{rate.id_answer}; otherwise it is not an ICS 3.5 servo (a board or sensor answers the ID "
                "command and memory reads only) or its other replies are lost (wiring, power)",
            )
    several = [s for s in report.servos if len(s.answered_at) > 1]
    if several:
        say_labelled(
            "[yellow]note:[/yellow]",
            f"servo(s) {ids_text(s.servo_id for s in several)} answered at several baud rates: "
            "this line does not enforce rates (a pty or a bridge); each is listed once, at the rate its EEPROM names "
            "(where it could be read)",
        )
    if not report.servos:
        return
    by_baud: dict[int, int] = {}
    for s in report.servos:
        if not s.rate_unconfirmed:
            by_baud[s.baud] = by_baud.get(s.baud, 0) + 1
    unconfirmed = sum(s.rate_unconfirmed for s in report.servos)
    summary = ", ".join(
        [f"{n} at {b} baud" for b, n in by_baud.items()]
        + ([f"{unconfirmed} at a rate unconfirmed"] if unconfirmed else [])
    )
    # (a shared ID in the summary too: on stderr alone, a glance at the table missed two servos answering as one)
    garbled = "".join(f"; ID {i} at {baud} baud answered garbled (two servos sharing it?)" for i, baud in garbled_ids)
    say(f"{len(report.servos)} servo(s) found on {escape(settings.port)}: {summary}{garbled}", to=out)
    if len(by_baud) > 1:
        most = max(by_baud, key=lambda b: by_baud[b])
        move = settings.command_line("--baud", "ITS_RATE", "eeprom", "set", "ID", f"baud_rate={most}", "--change-baud")
        say_labelled(
            "[yellow]note:[/yellow]",
            "servos at different baud rates cannot share one bus session; to bring one to "
            f"{most} baud: {escape(move)}, then power-cycle it",
        )


@click.command()
@click.option(
    "--bauds",
    type=BAUD_LIST,
    default=",".join(map(str, ALL_BAUDS)),
    show_default=True,
    help="Baud rates to try, comma-separated.",
)
@all_ids_option("IDs to try, e.g. 0-7 or 1,3,5.")
@seconds_option("--timeout", "Reply allowance per probe (default: the global --timeout).", low=0.001, high=5.0)
@click.option("--quick", is_flag=True, help="Do not read each servo's EEPROM.")
@json_option
@click.pass_context
def scan(
    ctx: click.Context, bauds: list[int], ids: list[int], timeout: float | None, quick: bool, as_json: bool
) -> int:
    """Find servos: try every baud rate x every ID (reopening the port at each rate).

    Sends only harmless reads: an ID read per rate (a rate where nothing answers
    it is done), then a stretch read per ID, then each servo's EEPROM.  A servo
    that answers at several rates is listed once, at the rate its EEPROM names.
    With --ids, a rate where none of them answers gets an ID read (if not already
    asked) to tell whether a servo at another ID is there.
    Exit code 4 when nothing answers.  A port lost part-way: the servos found
    before it are listed, then the error; Ctrl-C part-way: the servos that had
    answered are named, with the rates they answered at.
    """
    settings = settings_of(ctx)
    # The commands the notes name must hear what the scan heard: a longer allowance than the line's (a slow
    # link) goes into them; a shorter one (a quick scan) leaves them the line's own.
    named = settings if timeout is None or timeout <= settings.timeout else replace(settings, timeout=timeout)
    found: dict[int, list[int]] = {}  # baud -> the IDs that answered there so far (what Ctrl-C leaves to say)
    try:
        report = run(
            settings,
            lambda: scan_with_progress(
                settings,
                bauds,
                ids,
                read_eeprom=not quick,
                timeout=timeout,
                show_progress=not as_json,
                on_found=lambda i, baud: found.setdefault(baud, []).append(i),
            ),
        )
    except CliError as exc:
        if exc.code is not ExitCode.INTERRUPTED or not found:
            raise
        raise _interrupted_scan(named, found, as_json=as_json) from None
    if as_json:
        scan_json(settings, bauds, report)
    else:
        if report.servos:
            print_heading(scan_heading(report.servos))
            out.print(printed_table(scan_table(report.servos), LEAVE_OUT))
        scan_notes(named, report)
    if report.lost is not None:  # what was found is shown above; then the loss, not "no servo answered"
        failure = translate(settings, report.lost)
        if report.servos:
            shown = "listed" if as_json else "shown above"
            failure.hints.append(
                f"servo(s) {ids_text(sorted({s.servo_id for s in report.servos}))} were found before the line was "
                f"lost ({shown}; the rates after it were not scanned); when it is back: {named.command_line('scan')}"
            )
        raise failure
    if not report.servos:
        evidence = report.echo_evidence
        if evidence is not None:
            raise translate(settings, evidence)  # the same diagnosis `get` gives
        scanned = [r.baud for r in report.rates]
        where = f"{settings.port} at {', '.join(map(str, scanned))} baud"
        if report.rate_blind:
            where = f"{settings.port} (at the bridge's own rate)"
        if report.garbled:
            raise answered_garbled(settings, where, [(baud, i) for baud, i, _ in report.garbled])
        elsewhere = next((r for r in report.rates if r.elsewhere), None)
        if elsewhere is not None:  # (`--ids 20-31` on a line of servos 1-6: as doctor says it)
            rate = f" at {elsewhere.baud} baud" if len(scanned) > 1 else ""
            # (no ID given back: several devices answered the ID read at once)
            at_id = elsewhere.id_answer
            raise answered_at_another_id(named, ids, where, at_id, rate, several=at_id is None)
        failure = nothing_answered(settings, where, silent=report.silent)
        if not every_id(ids) and not (report.silent and settings.echo):
            # Told to try some IDs: those are named, and the hint that scan tries every ID says how.
            failure.message = f"{no_servo_among(ids)} answered on {where}"
            every = f"check the wiring and the servo ID ({named.command_line('scan')} without --ids tries every ID)"
            failure.hints = [every if hint == NO_REPLY_HINTS[1] else hint for hint in failure.hints]
        raise failure
    return 0


def _interrupted_scan(settings: Settings, found: dict[int, list[int]], *, as_json: bool) -> CliError:
    """Ctrl-C part-way through a scan: the servos that had answered are said (at the rates they answered at; their
    EEPROMs not read, so a pty, which ignores rates without saying so, shows one servo at each), with the command
    that lists them with their settings, of those IDs at those rates only (seconds, not the scan cut short)."""
    if as_json:
        emit_json(
            {
                "port": settings.port,
                "interrupted": True,
                "found": [{"id": i, "baud": baud} for baud, at in found.items() for i in sorted(at)],
            }
        )
    else:
        for baud, at in found.items():
            say(f"servo(s) {ids_text(sorted(at))} answered at {baud} baud", to=out)
    every = sorted({i for at in found.values() for i in at})
    shown = "listed" if as_json else "shown above"
    again = settings.command_line("scan", "--ids", ids_argument(every), "--bauds", ",".join(map(str, found)))
    return CliError(
        ExitCode.INTERRUPTED,
        f"interrupted before the scan ended: servo(s) {ids_text(every)} had answered ({shown})",
        f"to see their settings: {again}",
    )


# --------------------------------------------------------------------------- set-id


def refuse_unless_alone(settings: Settings, survey: IdSurvey, new_id: int) -> int:
    """The lone servo's ID, or the CliError that says why there is none."""
    errors: list[ReplyError] = [*survey.garbled.values()]
    if survey.id_read_error is not None:
        errors.insert(0, survey.id_read_error)
    for exc in errors:
        if echo_setting_wrong(exc, settings.echo):
            raise translate(settings, exc)  # the same diagnosis `get` gives
    refusal = survey.refusal
    if refusal is Refusal.NOBODY and survey.elsewhere:
        raise CliError(
            ExitCode.WRONG_BAUD,
            f"{survey.reason()} on {settings.port}. Nothing was written",
            f"pass --baud {survey.elsewhere[0]}",
        )
    if refusal is Refusal.NOBODY:
        raise nothing_answered(settings, f"{settings.port} at {settings.baud} baud", silent=survey.silent)
    if refusal is not None:
        raise CliError(ExitCode.REFUSED, f"{survey.reason(new_id)}. Nothing was written", survey.advice())
    assert survey.lone_id is not None
    return survey.lone_id


class _NewIdOnly(NegativeNumbersCommand):
    """``set-id NEW``: given an old ID too (``set-id 1 5``, as other tools take them), it says why NEW is enough."""

    def check_arguments(self, ctx: click.Context, arguments: list[str]) -> None:
        # (counted before click's parser, whose words for an extra argument are its own)
        numbers = [a for a in arguments if a.isdigit()]
        if len(numbers) >= 2:
            raise click.UsageError(
                f"set-id takes the new ID only: the one servo on the line is found whatever its ID now "
                f"(ics35 set-id {numbers[-1]})",
                ctx,
            )


@click.command(name="set-id", cls=_NewIdOnly)
@click.argument("new_id", metavar="NEW", type=SERVO_ID)
@yes_option
@json_option
@click.pass_context
def set_id(ctx: click.Context, new_id: int, yes: bool, as_json: bool) -> int:
    """Give the ONLY servo on the line the ID NEW (stored in its EEPROM).

    The ID command renames every device that hears it, so this first proves
    that exactly one device is on the line (an ID read, then a stretch read per
    ID) and refuses otherwise.
    """
    settings = settings_of(ctx)
    # How far it got, for what Ctrl-C leaves: at the question (which says so itself), then the ID the servo had
    # once the ID command is on its way.
    asking = False
    sent_from: int | None = None
    port_lost = False  # (the port went while the ID was surveyed or written: said as Ctrl-C is, below)

    def sent(old: int) -> None:
        nonlocal sent_from
        sent_from = old

    async def body() -> tuple[int, int]:
        nonlocal port_lost
        try:
            return await write_id()
        except (PortLost, BusClosed):
            port_lost = True
            raise

    async def write_id() -> tuple[int, int]:
        nonlocal asking
        async with settings.bus() as bus:
            survey = await policies.survey_for_id_write(bus)
            survey = await policies.look_elsewhere(survey, policies.reopening(bus), echo=settings.echo)
            old = refuse_unless_alone(settings, survey, new_id)
            if old == new_id:
                return old, new_id
            if not as_json:
                say(f"one servo on the line: ID {old}", to=out)
            asking = True
            confirm(f"Change servo ID {old} -> {new_id} (stored in its EEPROM)?", yes)
            await policies.write_lone_id(bus, new_id, survey=survey, on_sent=lambda: sent(old))
            return old, new_id

    try:
        old, new = run(settings, body)
    except CliError as exc:
        # Cut short by Ctrl-C or a lost port: whether the ID write went out is said (a refusal says its own).
        interrupted = exc.code is ExitCode.INTERRUPTED
        if not (interrupted or port_lost) or (interrupted and asking and sent_from is None):
            raise
        how = "interrupted" if interrupted else f"{exc.message}:"
        words = policies.cut_short_words(sent_from, new_id)
        if sent_from is None:
            raise CliError(exc.code, f"{how} {words}", *exc.hints) from None
        # Cut short as the ID command went out, or before the new ID was seen to answer: the servo took it or not.
        ids = f"{sent_from},{new_id}"
        raise CliError(
            exc.code,
            f"{how} {words}",
            f"see which with: {settings.command_line('scan', '--ids', ids, '--bauds', str(settings.baud), '--quick')}",
        ) from None
    if as_json:
        emit_json({"old": old, "new": new, "changed": old != new})
    elif old == new:
        say(f"servo already has ID {new}: nothing written", to=out)
    else:
        say(f"servo ID {old} -> {new}: done (verified: ID {new} answers)", to=out)
    return 0


COMMANDS = [scan, set_id]
