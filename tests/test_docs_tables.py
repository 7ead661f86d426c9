"""Every environment variable the package reads is in the command-line reference's table of them."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_every_environment_variable_the_package_reads_is_in_the_reference() -> None:
    used = set()
    for path in (ROOT / "ics35_async").rglob("*.py"):
        used.update(re.findall(r"\bICS35_[A-Z_]+\b", path.read_text(encoding="utf-8")))
    page = (ROOT / "docs" / "reference" / "cli.md").read_text(encoding="utf-8")
    table = page.partition("## Environment variables")[2]
    listed = set(re.findall(r"^\| `(ICS35_[A-Z_]+)` \|", table, re.MULTILINE))
    assert used and used == listed, (used - listed, listed - used)
