"""How an EEPROM image and a planned change look on the terminal."""

from __future__ import annotations

from rich.table import Table

from ..eeprom import BaudRate, Eeprom, flag_names
from ..policies import EepromPlan


def flags_text(flags: int) -> str:
    """A flags field as shown: the names set, ``|`` between them; ``-`` for none."""
    return "|".join(flag_names(flags)) or "-"


def unknown_code_text(code: int) -> str:
    return f"[yellow]0x{code:02X} (unknown code)[/yellow]"


def baud_text(baud: int) -> str:
    """A baud_rate field as shown: the rate, or the raw code the reference does not define."""
    return str(int(baud)) if isinstance(baud, BaudRate) else f"unknown code 0x{baud:02X}"


def eeprom_table(eeprom: Eeprom, title: str = "EEPROM") -> Table:
    table = Table(title=title, title_justify="left")
    table.add_column("field")
    table.add_column("value", justify="right")
    unknown = eeprom.unknown_codes
    if unknown:
        table.caption = "unknown code: a value ICS 3.5 does not define, kept as read; such an image is not written"
    if "header" in unknown:
        table.add_row("header", unknown_code_text(unknown["header"]))
    for name, value in eeprom.to_dict().items():
        if name in ("raw", "flags_names", "unknown_codes"):
            continue
        if name in unknown:
            shown = unknown_code_text(unknown[name])
        else:
            shown = f"{value} ({flags_text(eeprom.flags)})" if name == "flags" else str(value)
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
            table.add_row(name, f"{int(old)} ({flags_text(old)})", f"{int(new)} ({flags_text(new)})")
            if plan.added_flags:
                table.add_row("  flags set", "", flags_text(plan.added_flags))
            if plan.cleared_flags:
                table.add_row("  flags CLEARED", "", flags_text(plan.cleared_flags))
        else:
            table.add_row(name, str(int(old)), str(int(new)))
    return table
