"""The library's results as JSON for the pages: EEPROM images with each field's unit, range and meaning,
planned changes, write results and the renumbering survey.  Presentation only: no rule lives here."""

from __future__ import annotations

from typing import Any

from ..eeprom import FIELD_MEANINGS, READ_ONLY_FLAGS, BaudRate, Eeprom, Flags, field_range, flag_names
from ..policies import EepromPlan, EepromWriteResult, IdSurvey, power_up_note
from ..units import CURRENT_NOTE, TEMPERATURE_NOTE, current_text, temperature_text


def field_rows(image: Eeprom) -> list[dict[str, Any]]:
    values = image.to_dict()
    rows = []
    for name, (unit, meaning) in FIELD_MEANINGS.items():
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


def ram_view(values: dict[str, int]) -> dict[str, Any]:
    """The RAM values as read, and ``shown``: each in words as ``ics35 get`` says it.  The raw current carries
    its direction in bit 6 (64..127 is reverse) and the temperature parameter is smaller when hotter: shown
    bare, 70 would read as a large current and 127 as hot."""
    shown = {name: str(value) for name, value in values.items()}
    if "current" in values:
        shown["current"] = f"{current_text(values['current'])}  ({CURRENT_NOTE})"
    if "temperature" in values:
        shown["temperature"] = f"{temperature_text(values['temperature'])}  ({TEMPERATURE_NOTE})"
    return {**values, "shown": shown}


def eeprom_view(image: Eeprom) -> dict[str, Any]:
    return {
        "fields": field_rows(image),
        "raw": image.to_bytes().hex(),
        "unknown_codes": image.unknown_codes,
        "flags_names": flag_names(image.flags),
    }


def _plain(value: Any) -> Any:
    return int(value) if isinstance(value, int) else value


def plan_view(plan: EepromPlan, refusal: str | None, allowed_by: str | None = None) -> dict[str, Any]:
    """``refusal``: why the plan may not be written (None: it may); ``allowed_by``: the allowance that would let
    it through (``allow_id_change``, ``allow_baud_change``), for the page to name its tick."""
    return {
        "servo_id": plan.servo_id,
        "before": plan.before.to_bytes().hex(),
        "diff": [{"name": k, "now": _plain(a), "new": _plain(b)} for k, (a, b) in plan.diff.items()],
        "flags_set": flag_names(plan.added_flags),
        "flags_cleared": flag_names(plan.cleared_flags),
        "changes_id": plan.changes_id,
        "changes_baud": plan.changes_baud,
        "refusal": refusal,
        "allowed_by": allowed_by,
        "note": plan.kept_note,
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
        # (the Servo page's RAM box writes a RAM parameter now: named by its button)
        "note": power_up_note(
            {name: int(new) for name, (_, new) in result.plan.diff.items()} if result.written else {},
            lambda param, value: f"Write to RAM {param} {value}",
        ),
    }


def survey_view(survey: IdSurvey) -> dict[str, Any]:
    return {
        "baud": survey.baud,
        "lone_id": survey.lone_id,
        "answered": list(survey.answered),
        "garbled": sorted(survey.garbled),
        "refusal": f"{survey.reason()}; {survey.advice()}" if survey.refusal is not None else None,
    }
