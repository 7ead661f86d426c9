"""How an EEPROM image and a planned change look on the terminal."""

from __future__ import annotations

from rich.table import Table

from ..eeprom import Eeprom, Flags
from ..policies import EepromPlan


def flag_names(flags: int) -> str:
    return "|".join(f.name or "" for f in Flags if f in Flags(flags)) or "-"


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


def diff_table(plan: EepromPlan) -> Table:
    """The fields a write changes; the flags row names every flag it sets and clears."""
    table = Table(title=f"EEPROM changes for servo {plan.servo_id}", title_justify="left")
    table.add_column("field")
    table.add_column("now", justify="right")
    table.add_column("new", justify="right")
    for name, (old, new) in plan.diff.items():
        if name == "flags":
            table.add_row(name, f"{int(old)} ({flag_names(old)})", f"{int(new)} ({flag_names(new)})")
            if plan.added_flags:
                table.add_row("  flags set", "", flag_names(plan.added_flags))
            if plan.cleared_flags:
                table.add_row("  flags CLEARED", "", flag_names(plan.cleared_flags))
        else:
            table.add_row(name, str(int(old)), str(int(new)))
    return table
