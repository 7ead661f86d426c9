"""Every ```python block in README.md and docs/ runs as written (against the built-in simulator)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
FENCE = re.compile(r"^```python\n(.*?)^```", flags=re.S | re.M)


def _blocks() -> list[tuple[str, str]]:
    found = []
    for page in PAGES:
        for number, code in enumerate(FENCE.findall(page.read_text()), start=1):
            found.append((f"{page.relative_to(ROOT)}#{number}", code))
    return found


BLOCKS = _blocks()


def test_readme_and_docs_have_examples() -> None:
    where = {name.split("#")[0] for name, _ in BLOCKS}
    assert "README.md" in where
    assert len(where) >= 8, where


def test_no_other_python_fences() -> None:
    """A block fenced as ``py`` or ``python3`` would escape this test: there is one spelling."""
    for page in PAGES:
        odd = re.findall(r"^```(py|python3|pycon)\s*$", page.read_text(), flags=re.M)
        assert not odd, f"{page.relative_to(ROOT)}: fence it as ```python so the test runs it"


@pytest.mark.parametrize(("name", "code"), BLOCKS, ids=[name for name, _ in BLOCKS])
def test_example_runs(name: str, code: str, tmp_path: Path) -> None:
    script = tmp_path / "example.py"
    script.write_text(code)
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert done.returncode == 0, f"{name}:\n{done.stderr}"
    assert "Traceback" not in done.stderr


def _quick_start() -> str:
    (code,) = [code for name, code in BLOCKS if name.startswith("docs/getting-started/quick-start.md")]
    return code


def test_the_quick_start_servo_gets_where_its_comments_say(tmp_path: Path) -> None:
    """The quick start moves a servo to +30 degrees, waits and prints where it is: the simulated servo must
    have moved in that real wait (a fast-mode simulator's clock does not follow sleeps), so it prints about
    7500 + 30 * 8000 / 270 counts."""
    done = subprocess.run(
        [sys.executable, "-c", _quick_start()], capture_output=True, text=True, timeout=60, cwd=tmp_path
    )
    assert done.returncode == 0, done.stderr
    found = re.search(r"^now at (\d+)", done.stdout, flags=re.M)
    assert found, done.stdout
    assert abs(int(found.group(1)) - 8389) <= 30, done.stdout


def test_the_quick_start_backups_are_what_eeprom_restore_reads(tmp_path: Path) -> None:
    """The quick start's Python twin of `ics35 eeprom dump all -o backup/` writes backups that
    `ics35 eeprom restore backup/` takes, as the page says of them: restored onto servos that already
    hold those settings, each is checked whole and nothing is written."""
    made = subprocess.run(
        [sys.executable, "-c", _quick_start()], capture_output=True, text=True, timeout=60, cwd=tmp_path
    )
    assert made.returncode == 0, made.stderr
    saved = sorted(path.name for path in (tmp_path / "backup").iterdir())
    assert saved == ["servo-01.json", "servo-02.json", "servo-03.json"], made.stdout
    restored = subprocess.run(
        [sys.executable, "-m", "ics35_async.cli", "--port", "sim://?ids=1-3", "eeprom", "restore", "backup/", "--yes"],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=tmp_path,
    )
    assert restored.returncode == 0, restored.stderr
    assert restored.stdout.count("EEPROM already matches, nothing to write") == 3, restored.stdout
