"""The ``ics35`` command run two ways: in this process (:func:`run_in_process`) and as a real process
(:func:`run_process`); ``tests/conftest.py`` hands both to tests as the ``cli`` and ``cli_process`` fixtures."""

from __future__ import annotations

import dataclasses
import io
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from ics35_async.cli import main
from ics35_async.eeprom import EEPROM_FIELDS, Eeprom

# The start of a ``python -c`` program that dumps every thread's stack on SIGUSR1, so a test whose process
# outlives what it was told can say where it is before killing it.
DUMP_ON_USR1 = "import faulthandler, signal; faulthandler.register(signal.SIGUSR1, all_threads=True); "

# The start of a ``python -c`` program (its arguments: a function's name, a count) that presses Ctrl-C at that
# call of the function, once ``sys.setprofile(press)`` arms it in the main thread: a press lands in the main
# thread between any two steps, and this one at the step a test names, however unlikely its timing.
PRESS_AT_A_CALL = """
import os, signal, sys

where, count = sys.argv[1], int(sys.argv[2])
calls = [0]

def press(frame, event, arg):
    if event == "call" and frame.f_code.co_name == where:
        calls[0] += 1
        if calls[0] == count:
            sys.setprofile(None)
            os.kill(os.getpid(), signal.SIGINT)
"""


@dataclasses.dataclass
class CliResult:
    """What one in-process ``ics35`` run left: its exit code, stdout and stderr."""

    code: int
    out: str
    err: str

    def json(self) -> Any:
        return json.loads(self.out)


def run_in_process(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, *args: str, stdin: str = ""
) -> CliResult:
    """``ics35 ARGS...`` through ``cli.main`` with ``stdin`` as its input; a traceback fails the test."""
    monkeypatch.setattr(sys, "stdin", io.StringIO(stdin))
    capsys.readouterr()
    with pytest.raises(SystemExit) as exited:
        main(list(args))
    captured = capsys.readouterr()
    code = exited.value.code
    result = CliResult(code if isinstance(code, int) else 1, captured.out, captured.err)
    assert "Traceback" not in result.err, result.err
    return result


def run_process(
    *args: str, stdin: str = "", timeout: float = 60, columns: int = 100
) -> subprocess.CompletedProcess[str]:
    """``python -m ics35_async.cli ARGS...`` as a user's shell runs it (``COLUMNS``: 100); a traceback fails the
    test."""
    proc = subprocess.run(
        [sys.executable, "-m", "ics35_async.cli", *args],
        input=stdin,
        capture_output=True,
        text=True,
        timeout=timeout,
        env={**os.environ, "COLUMNS": str(columns)},
    )
    assert "Traceback" not in proc.stderr, proc.stderr
    return proc


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
