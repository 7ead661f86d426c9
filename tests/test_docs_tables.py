"""Tables in the docs that the code is the source of: the environment variables the package reads, the
EEPROM fields with their ranges and meanings."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

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


# What the reference (section 7's table, section 8's flags, the PWM section) says of a field, in words its
# meaning must carry: the configurator's Servo page and the field table show these to a person choosing a value.
REFERENCE_SAYS = {
    "response": ["from standstill", "larger is sharper"],  # レスポンス: not a reply delay
    "flags": ["PWMINH keeps the servo in serial mode", "brown-out"],  # not an output inhibit while free
    "stretch_1": ["characteristic change", "100 us"],
    "stretch_2": ["characteristic change", "150 us"],
    "stretch_3": ["characteristic change", "200 us"],
    "stretch_gain": ["half"],  # the RAM stretch (1..127) is half the EEPROM's (2..254)
}


@pytest.mark.parametrize("name", sorted(REFERENCE_SAYS))
def test_a_fields_meaning_says_what_the_reference_says(name: str) -> None:
    meaning = FIELD_MEANINGS[name][1]
    for words in REFERENCE_SAYS[name]:
        assert words in meaning, (name, meaning)


def test_the_eeprom_page_names_kondos_term_for_every_field() -> None:
    page = (ROOT / "docs" / "reference" / "eeprom.md").read_text(encoding="utf-8")
    table = page.partition("## Kondo's names")[2].partition("\n## ")[0]
    named = re.findall(r"^\| `(\w+)` \| [^|]*\S[^|]* \| [^|]*\S[^|]* \|$", table, re.MULTILINE)
    assert named == list(FIELD_MEANINGS)
