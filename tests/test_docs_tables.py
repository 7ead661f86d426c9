"""Tables in the docs that the code is the source of: the environment variables the package reads, the
EEPROM fields with their ranges and meanings."""

from __future__ import annotations

import re
from pathlib import Path

from ics35_async.eeprom import FIELD_MEANINGS, BaudRate, Flags, field_range

ROOT = Path(__file__).resolve().parents[1]


def test_every_environment_variable_the_package_reads_is_in_the_reference() -> None:
    used = set()
    for path in (ROOT / "ics35_async").rglob("*.py"):
        used.update(re.findall(r"\bICS35_[A-Z_]+\b", path.read_text(encoding="utf-8")))
    page = (ROOT / "docs" / "reference" / "cli.md").read_text(encoding="utf-8")
    table = page.partition("## Environment variables")[2]
    listed = set(re.findall(r"^\| `(ICS35_[A-Z_]+)` \|", table, re.MULTILINE))
    assert used and used == listed, (used - listed, listed - used)


def test_the_eeprom_field_table_is_the_librarys() -> None:
    page = (ROOT / "docs" / "reference" / "eeprom.md").read_text(encoding="utf-8")
    rows = re.findall(r"^\| `(\w+)` \| ([^|]*) \| ([^|]*) \| ([^|]*) \|$", page, re.MULTILINE)
    assert [row[0] for row in rows] == list(FIELD_MEANINGS)
    for name, shown_range, unit, meaning in rows:
        assert (unit.strip(), meaning.strip()) == FIELD_MEANINGS[name], name
        bounds = field_range(name)
        if bounds is not None:
            expected = f"{bounds[0]}..{bounds[1]}" + (", even" if bounds[2] else "")
        elif name == "baud_rate":
            expected = ", ".join(str(int(rate)) for rate in BaudRate)
        else:
            expected = ", ".join(flag.name or "" for flag in Flags)
        assert shown_range.strip() == expected, name
