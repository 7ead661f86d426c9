"""Fixtures for the CLI tests: ``ics35(*args)`` run in this process, ``line(servos)`` a named simulated line.

Import them into a test module (``from tests._cli_fixtures import ics35, line``); pytest
finds fixtures by name in the module's namespace.
"""

from __future__ import annotations

import dataclasses
import io
import itertools
import json
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from ics35_async.cli import main
from ics35_async.eeprom import EEPROM_FIELDS, Eeprom
from ics35_async.sim import VirtualLine


class Result:
    def __init__(self, code: int, out: str, err: str) -> None:
        self.code = code
        self.out = out
        self.err = err

    def json(self) -> Any:
        return json.loads(self.out)


@pytest.fixture
def ics35(capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> Any:
    """Run ``ics35 ARGS...`` in-process (no port in the environment); optional ``stdin`` text."""
    monkeypatch.delenv("ICS35_PORT", raising=False)
    monkeypatch.delenv("ICS35_BAUD", raising=False)

    def invoke(*args: str, stdin: str = "") -> Result:
        monkeypatch.setattr(sys, "stdin", io.StringIO(stdin))
        capsys.readouterr()
        with pytest.raises(SystemExit) as exited:
            main(list(args))
        captured = capsys.readouterr()
        code = exited.value.code
        result = Result(code if isinstance(code, int) else 1, captured.out, captured.err)
        assert "Traceback" not in result.err, result.err
        return result

    return invoke


_names = itertools.count()


@pytest.fixture
def line() -> Iterator[Any]:
    """``line(servos, **VirtualLine options)`` -> (VirtualLine, its sim://NAME URL); closed after the test."""
    made: list[VirtualLine] = []

    def make(servos: Any = (1, 2, 3), **options: Any) -> tuple[VirtualLine, str]:
        name = f"cli-user-test-{next(_names)}"
        options.setdefault("log_size", None)  # keep every transaction: tests read the whole log
        sim = VirtualLine(list(servos), name=name, **options)
        made.append(sim)
        return sim, f"sim://{name}"

    yield make
    for sim in made:
        sim.close()


def edit_backup(path: Path, **changes: Any) -> dict[str, Any]:
    """Change fields of an `eeprom dump` backup as a careful person would: the raw image and the fields
    together (a backup whose halves disagree is refused).  Values go in unchecked, as a hand edit would."""
    doc: dict[str, Any] = json.loads(path.read_text())
    image = dataclasses.replace(Eeprom.from_bytes(bytes.fromhex(doc["raw"])), **changes)
    stated = image.to_dict()
    doc["raw"] = stated["raw"]
    doc["fields"] = {name: stated[name] for name in EEPROM_FIELDS}
    doc["flags_names"] = stated["flags_names"]
    path.write_text(json.dumps(doc, indent=2))
    return doc
