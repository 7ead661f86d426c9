"""The library's results as JSON for the pages: EEPROM images with each field's unit, range and meaning,
planned changes, write results and the renumbering survey.  Presentation only: no rule lives here."""

from __future__ import annotations

from typing import Any

from ..eeprom import READ_ONLY_FLAGS, BaudRate, Eeprom, Flags, field_range
from ..policies import EepromPlan, EepromWriteResult, IdSurvey

# name -> (unit, meaning), in the order the Servo page lists them.
FIELD_HELP: dict[str, tuple[str, str]] = {
    "servo_id": ("", "the ID the servo answers to (changed on the ID page, or here with 'allow ID change')"),
    "baud_rate": ("bit/s", "the line rate the servo talks at after its next power-up"),
    "stretch_gain": ("", "holding stiffness (P gain) used when no stretch 1..3 is selected; even values"),
    "speed": ("", "output speed limit, 127 = full speed"),
    "punch": ("", "minimum drive added when starting to move (overcomes static friction)"),
    "dead_band": ("", "how far off target the servo may be before it drives (steps of about 0.1 degree)"),
    "damping": ("", "braking characteristic as the servo nears its target"),
    "safe_timer": ("x10 ms", "how long an over-current or over-temperature may last before the servo frees"),
    "flags": ("", "REVERSE turns the direction round, ROTATION makes it a wheel, PWMINH inhibits the output "
                  "while free, SLAVE for paired servos; FREE and PCM only report the servo's state"),
    "pulse_limit_high": ("position", "the highest position the servo will go to (the joint's upper limit)"),
    "pulse_limit_low": ("position", "the lowest position the servo will go to (the joint's lower limit)"),
    "temperature_limit": ("", "temperature parameter at which the servo protects itself (smaller is hotter)"),
    "current_limit": ("", "current at which the servo protects itself (about 0.1 A per step)"),
    "response": ("", "reply delay setting (1 is the fastest)"),
    "user_offset": ("position steps", "shifts the neutral position (-127..127)"),
    "stretch_1": ("", "stiffness preset 1 (even values)"),
    "stretch_2": ("", "stiffness preset 2 (even values)"),
    "stretch_3": ("", "stiffness preset 3 (even values)"),
}  # fmt: skip


def flag_names(flags: int) -> list[str]:
    return [f.name or "" for f in Flags if f in Flags(flags)]


def field_rows(image: Eeprom) -> list[dict[str, Any]]:
    values = image.to_dict()
    rows = []
    for name, (unit, meaning) in FIELD_HELP.items():
        bounds = field_range(name)
        row: dict[str, Any] = {"name": name, "value": values[name], "unit": unit, "meaning": meaning}
        if bounds is not None:
            row.update(low=bounds[0], high=bounds[1], even=bounds[2])
        elif name == "baud_rate":
            row["choices"] = [int(b) for b in BaudRate]
        else:
            row["flags"] = [
                {"name": f.name, "bit": int(f), "on": f in image.flags, "read_only": bool(f & READ_ONLY_FLAGS)}
                for f in Flags
            ]
        rows.append(row)
    return rows


def eeprom_view(image: Eeprom) -> dict[str, Any]:
    return {
        "fields": field_rows(image),
        "raw": image.to_bytes().hex(),
        "unknown_codes": image.unknown_codes,
        "flags_names": flag_names(image.flags),
    }


def _plain(value: Any) -> Any:
    return int(value) if isinstance(value, int) else value


def plan_view(plan: EepromPlan, refusal: str | None) -> dict[str, Any]:
    return {
        "servo_id": plan.servo_id,
        "before": plan.before.to_bytes().hex(),
        "diff": [{"name": k, "now": _plain(a), "new": _plain(b)} for k, (a, b) in plan.diff.items()],
        "flags_set": flag_names(plan.added_flags),
        "flags_cleared": flag_names(plan.cleared_flags),
        "changes_id": plan.changes_id,
        "changes_baud": plan.changes_baud,
        "refusal": refusal,
    }


def result_view(result: EepromWriteResult) -> dict[str, Any]:
    return {
        "written": result.written,
        "verified": result.verified,
        "acknowledged": result.acknowledged,
        "answering_ids": list(result.answering_ids),
        "new_rate_answers": result.new_rate_answers,
        "new_rate_error": result.new_rate_error,
        "diff": [{"name": k, "now": _plain(a), "new": _plain(b)} for k, (a, b) in result.plan.diff.items()],
        "read_back": None if result.read_back is None else eeprom_view(result.read_back),
    }


def survey_view(survey: IdSurvey) -> dict[str, Any]:
    return {
        "baud": survey.baud,
        "lone_id": survey.lone_id,
        "answered": list(survey.answered),
        "garbled": sorted(survey.garbled),
        "refusal": survey.reason() or None,
    }
