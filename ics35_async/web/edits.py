"""What a page asks an EEPROM write to do: the changes, the flags to set and clear, what it allows."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from ..eeprom import BaudRate
from ..errors import InvalidArgument


def edit_of(edit: Mapping[str, Any]) -> tuple[dict[str, Any], int, int, bool]:
    """(changes, set_flags, clear_flags, keep_read_only) for :func:`~ics35_async.policies.plan_eeprom_write`,
    which checks each; ``keep_read_only`` only when said in as many words (a restore's edit says it)."""
    changes = edit.get("changes", {})
    if not isinstance(changes, dict):
        raise InvalidArgument("changes must be an object of field: value")
    set_flags, clear_flags = edit.get("set_flags", 0), edit.get("clear_flags", 0)
    if "baud_rate" in changes:
        changes = {**changes, "baud_rate": BaudRate.parse(changes["baud_rate"])}
    return changes, set_flags, clear_flags, edit.get("keep_read_only") is True


def allowances(edit: Mapping[str, Any]) -> dict[str, bool]:
    """An ID or baud change is allowed only when the page says so in as many words (``true``, not truthy)."""
    return {
        "allow_baud_change": edit.get("allow_baud_change") is True,
        "allow_id_change": edit.get("allow_id_change") is True,
    }
