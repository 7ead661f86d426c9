"""The path every EEPROM write of the CLI takes: show the plan, refuse or confirm, write, report.

The rules themselves (what may change, read-only flags, verification) are the
library's (:mod:`ics35_async.policies.eeprom_write`); this module only puts
them in front of a person.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from rich.markup import escape

from ..bus import Bus
from ..eeprom import BaudRate, Flags, after_baud_change
from ..errors import IcsError, ReplyTimeout
from ..policies import EepromPlan, ServoWriteReport, WriteOutcome, power_up_note, write_eeprom_plans
from ._common import (
    CliError,
    ExitCode,
    Settings,
    confirm,
    emit_json,
    err,
    ids_text,
    no_reply_error,
    out,
    translate,
)
from ._console import say, say_labelled
from ._eeprom_view import baud_text, diff_table, flags_text


def _later_commands(new: int) -> str:
    """What a change to baud rate ``new`` asks of every command after it (the servo's side the library says)."""
    shared = "servos at different rates cannot share one bus session"
    if new == BaudRate.B115200:  # (the factory rate, --baud's default: a command without --baud runs at it)
        return f"every later command talks to it at {new} baud, the default (no --baud), and {shared}"
    return f"every later command needs --baud {new} and 625000/1250000 need the ICS USB adapter HS, and {shared}"


CHANGE_BAUD_ADVICE = ("to do it anyway, add --change-baud",)


def check_allowed(
    plan: EepromPlan, *, change_baud: bool, allow_id_change: bool, baud_advice: Sequence[str] = CHANGE_BAUD_ADVICE
) -> None:
    """Refuse (exit 5, nothing written) what the person did not ask for: the library's reason (the one rule, in
    its words), and what to do instead in this command's terms (``baud_advice``: the flags that allow a baud
    change)."""
    why = plan.why_refused(allow_baud_change=change_baud, allow_id_change=allow_id_change)
    if why is None:
        return
    if why.allowed_by == "allow_baud_change":
        hints: Sequence[str] = (f"then {_later_commands(int(plan.after.baud_rate))}", *baud_advice)
    elif plan.changes_id and plan.id_taken:
        hints = ("pick a free ID (see: ics35 scan)",)
    else:  # (eeprom set allows the ID it is given, restore the backup's with --restore-id: no ID change is refused)
        hints = ()
    raise CliError(ExitCode.REFUSED, f"refused: {why.reason}. Nothing was written", *hints)


SET_FLAG_ADVICE = "to change one flag and keep the others use flags+=NAME / flags-=NAME"


def show_plan(
    plan: EepromPlan,
    as_json: bool,
    flag_advice: Callable[[EepromPlan], str],
    line_baud: int,
    asked_cleared: int = 0,
) -> None:
    """The plan's diff, and warnings for what it does that the person may not have meant: flags it clears
    that were not named to be cleared (``asked_cleared``, as ``flags-=NAME`` names them), PWMINH cleared
    however asked, a new baud rate."""
    if plan.baud != line_baud:
        say(
            f"servo {plan.servo_id} answers at {plan.baud} baud (the line's rate is {line_baud}): "
            "it is read, written and verified at its own rate",
            to=err if as_json else out,
        )
    (err if as_json else out).print(diff_table(plan))
    # A flag cleared by name (flags-=NAME) was meant: advice to clear flags by name would send the person to
    # what they typed.  PWMINH's risk is said however it was cleared.
    unasked = plan.cleared_flags & ~asked_cleared
    if unasked or plan.cleared_flags & Flags.PWMINH:
        note = (
            " (without PWMINH a servo may start in PWM mode after a brown-out)"
            if plan.cleared_flags & Flags.PWMINH
            else ""
        )
        advice = f"; {escape(flag_advice(plan))}" if unasked else ""
        say_labelled("[yellow]warning:[/yellow]", f"this clears flag(s) {flags_text(plan.cleared_flags)}{note}{advice}")
    if plan.changes_baud:
        new = int(plan.after.baud_rate)
        say_labelled("[yellow]warning:[/yellow]", f"{after_baud_change(new)}: {_later_commands(new)}")


def report_of(plan: EepromPlan, report: ServoWriteReport | None) -> dict[str, Any]:
    """The JSON-able account of one servo's write (``report`` None: nothing was asked of the servo)."""
    outcome = WriteOutcome.UNCHANGED if report is None and not plan.diff else WriteOutcome.NOT_WRITTEN
    if report is not None:
        outcome = report.outcome
    result = report.result if report is not None else None
    written = {WriteOutcome.UNKNOWN: None, WriteOutcome.UNCHANGED: False, WriteOutcome.NOT_WRITTEN: False}
    out: dict[str, Any] = {
        "id": plan.servo_id,
        "changes": {k: [int(a), int(b)] for k, (a, b) in plan.diff.items()},
        "outcome": outcome.name.lower(),
        "written": written.get(outcome, True),
        "baud": plan.baud,
    }
    if plan.kept_read_only:
        out["kept_read_only"] = plan.kept_names
    if report is not None and report.error is not None:
        out["error"] = str(report.error)
    if result is not None and result.written:
        out["verified"] = result.verified
        if plan.changes_id:
            out["answers_as"] = list(result.answering_ids)
        if plan.changes_baud:
            out["answers_at_new_rate"] = result.new_rate_answers
            if result.new_rate_error:
                out["new_rate_error"] = result.new_rate_error
    return out


@dataclass
class WriteBatch:
    """Every servo's account, and the failure that ended the writes (None: none did)."""

    reports: list[dict[str, Any]]
    error: IcsError | None = None
    interrupted: bool = False  # Ctrl-C ended the writes


async def write_plans(
    bus: Bus,
    plans: Sequence[EepromPlan],
    *,
    yes: bool,
    change_baud: bool,
    allow_id_change: bool,
    as_json: bool,
    flag_advice: Callable[[EepromPlan], str] = lambda plan: SET_FLAG_ADVICE,
    baud_advice: Sequence[str] = CHANGE_BAUD_ADVICE,
    asked_cleared: int = 0,
) -> WriteBatch:
    """Check every plan, show them, ask once, write them in order; one report per plan, even after a failure.

    ``flag_advice``: what to do instead of clearing a plan's flags (``asked_cleared``: those named to be cleared,
    which get none), and ``baud_advice``: what to do about a refused baud change, in the command's own terms.
    A plan made at another rate than the line's now (a servo that answers there) is said so, and written and
    verified at its own rate."""
    moved = [plan for plan in plans if plan.changes_baud] if not change_baud else []
    if len(moved) > 1:  # every servo the batch would move, not only the first (each one's rate in words)
        which = ", ".join(
            f"servo {plan.servo_id}'s from {baud_text(plan.before.baud_rate)} to {int(plan.after.baud_rate)}"
            for plan in moved
        )
        raise CliError(
            ExitCode.REFUSED,
            f"refused: this changes the baud rate of {len(moved)} servos ({which}); from its next power-up each "
            "answers ONLY at its new rate, and servos at different rates cannot share one bus session. Nothing "
            "was written",
            *baud_advice,
        )
    for plan in plans:
        check_allowed(plan, change_baud=change_baud, allow_id_change=allow_id_change, baud_advice=baud_advice)
    pending = [plan for plan in plans if plan.diff]
    line_baud = int(bus.baudrate)
    for plan in plans:
        if plan.diff:
            show_plan(plan, as_json, flag_advice, line_baud, asked_cleared)
        elif not as_json:
            say(f"servo {plan.servo_id}: EEPROM already matches, nothing to write", to=out)
        if plan.kept_note and not as_json:
            say_labelled("note:", escape(plan.kept_note))
    if not pending:
        return WriteBatch([report_of(plan, None) for plan in plans])
    count = sum(len(plan.diff) for plan in pending)
    servos = f"servo {pending[0].servo_id}" if len(pending) == 1 else f"servos {ids_text(p.servo_id for p in pending)}"
    confirm(f"Write these {count} change(s) to the EEPROM of {servos}?", yes)
    done: list[ServoWriteReport] = []
    task = asyncio.current_task()
    with contextlib.suppress(asyncio.CancelledError):
        await write_eeprom_plans(
            bus, pending, allow_baud_change=change_baud, allow_id_change=allow_id_change, on_report=done.append
        )
    # Ctrl-C (the task cancelled; a request it cut short may have ended as a timeout instead): the account of
    # every servo is printed before the command ends with exit code 130.
    interrupted = task is not None and task.cancelling() > 0
    while task is not None and task.cancelling():
        task.uncancel()
    by_id = {report.plan.servo_id: report for report in done}
    error = next((report.error for report in done if report.error is not None), None)
    return WriteBatch([report_of(plan, by_id.get(plan.servo_id)) for plan in plans], error, interrupted)


def print_done(settings: Settings, report: dict[str, Any], *, whole: bool) -> None:
    """What a person needs to know after one servo's write: verified, and where it answers now; or what the
    servo may hold after a failure.  ``whole``: a servo with nothing to write is listed too."""
    sid, changes, outcome = report["id"], report["changes"], WriteOutcome[report["outcome"].upper()]
    if outcome is WriteOutcome.UNCHANGED:
        if whole:
            say(f"servo {sid}: {outcome.value}", to=out)
        return
    # The outcomes short of a verified write: one line each, naming what the servo may hold; the command that
    # tells which reaches the servo at the rate it was written at (a restore's servo at another rate too).
    rate = report.get("baud", settings.baud)
    there = settings if rate == settings.baud else dataclasses.replace(settings, baud=rate)
    check = escape(there.command_line("eeprom", "dump", str(sid), "--table"))
    short_of_verified = {
        WriteOutcome.NOT_WRITTEN: "[bold]not written[/bold] (its EEPROM is as it was)",
        WriteOutcome.UNKNOWN: "[bold red]unknown[/bold red]: the command stopped while the write was on its way, "
        f"so the servo holds its old or its new EEPROM; see which with: {check}",
        # (no read-back came: the command stopped first, or the servo did not answer it; the error line says which)
        WriteOutcome.UNVERIFIED: f"{len(changes)} EEPROM field(s) [bold]written, not verified[/bold]: no read-back "
        f"came; check with: {check}",
        WriteOutcome.DIFFERS: "[bold red]written, but the image read back differs[/bold red]",
    }
    if outcome in short_of_verified:
        say(f"servo {sid}: {short_of_verified[outcome]}", to=out)
        return
    elsewhere = f" at {report['baud']} baud" if report.get("baud", settings.baud) != settings.baud else ""
    say(f"servo {sid}: {len(changes)} EEPROM field(s) written and verified{elsewhere}", to=out)
    new_id = changes.get("servo_id", [sid, sid])[1]
    now_id = new_id if report.get("answers_as") == [new_id] else sid  # (the ID it answers as now)
    note = power_up_note(
        {name: new for name, (_, new) in changes.items()},
        lambda param, value: there.command_line("set", str(now_id), param.replace("_", "-"), str(value)),
    )
    if note:
        say(escape(note), to=out)
    if "baud_rate" in changes:
        new = changes["baud_rate"][1]
        use = "the default: no --baud" if new == BaudRate.B115200 else f"use --baud {new}"
        if report.get("answers_at_new_rate"):
            say(f"it already answers at {new} baud ({use})", to=out)
        else:
            checked = f" (not checked: {report['new_rate_error']})" if report.get("new_rate_error") else ""
            say(f"power-cycle the servo: from then on it talks only at {new} baud ({use}){checked}", to=out)
    if "servo_id" in changes:
        old, new = changes["servo_id"]
        answers = report.get("answers_as", [])
        if answers == [new]:
            say(f"the servo now answers as ID {new}", to=out)
        elif answers == [old]:
            say(
                f"the servo still answers as ID {old}: its EEPROM holds ID {new}, which it takes at its next power-up",
                to=out,
            )
        elif answers:
            say(f"both ID {new} and ID {old} answer now; after a power-cycle only ID {new} should", to=out)
        else:
            say(f"neither ID {new} nor ID {old} answers at this rate now (the write was verified elsewhere)", to=out)


def said_nothing_written(exc: CliError, servos: str) -> bool:
    """Add to ``exc``, a command's failure while it read ``servos`` ("the servo", "the servos") before writing any,
    that nothing was written, unless its message says so already; True if added."""
    if "nothing was written" in exc.message.lower():
        return False
    exc.hints.insert(0, f"nothing was written (it stopped while reading {servos})")
    return True


def finish(
    settings: Settings, batch: WriteBatch, as_json: bool, *, bulk: bool = False, again: Sequence[str] = ()
) -> None:
    """Print every servo's account (after a failure too), then raise the failure, if any, as the exit code.

    ``again``: the command's words to run once the line is back (servos already written have nothing left
    to write); the hint gives them with this command's line options.
    """
    if as_json:
        emit_json({"servos": batch.reports} if bulk else batch.reports[0])
    else:
        for report in batch.reports:
            print_done(settings, report, whole=batch.error is not None or batch.interrupted)
    if batch.interrupted:
        failure = CliError(ExitCode.INTERRUPTED, "interrupted: the servos above say what each holds")
    elif batch.error is None:
        return
    elif isinstance(batch.error, ReplyTimeout):
        failure = no_reply_error(settings, batch.error)
    else:
        failure = translate(settings, batch.error)
    if again:
        when = "to finish" if batch.interrupted else "when the line is back"
        failure.hints.append(
            f"{when}, run it again: {settings.command_line(*again)} (servos already written are skipped)"
        )
    raise failure
