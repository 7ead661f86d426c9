"""Exit codes are written once, in ExitCode: the CLI's help and the docs' table are made from it."""

from __future__ import annotations

import sys
from pathlib import Path

from click.testing import CliRunner

from ics35_async.cli import cli
from ics35_async.cli._settings import ExitCode

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tools"))
import mkdocs_hooks


def test_help_lists_every_exit_code() -> None:
    result = CliRunner().invoke(cli, ["--help"])
    assert result.exit_code == 0
    text = " ".join(result.output.split())
    for code in ExitCode:
        assert f"{int(code)} {code.name.lower().replace('_', ' ')}" in text


def test_docs_table_has_every_exit_code_with_its_meaning() -> None:
    rows = mkdocs_hooks.exit_code_table().splitlines()[2:]
    assert [row.split("|")[1].strip() for row in rows] == [str(int(code)) for code in ExitCode]
    assert all(len(row.split("|")[3].strip()) > 20 for row in rows)


def test_docs_engine_diagram_comes_from_a_real_engine() -> None:
    transitions = mkdocs_hooks.engine_transitions()
    assert transitions[("IDLE", "BUSY")] == ["request submitted"]
    assert ("QUIET", "IDLE") in transitions and ("BUSY", "DRAINING") in transitions
    assert not any(before == "CLOSED" for before, _ in transitions), "nothing leaves CLOSED"


def test_docs_engine_diagram_draws_a_reopen_asked_while_busy() -> None:
    # A reopen asked while a transaction is on the wire (or a resync runs) takes the line offline when that ends:
    # two events, and the diagram drew only what one event changes, so that path was missing.
    transitions = mkdocs_hooks.engine_transitions()
    assert transitions[("BUSY", "BUSY_THEN_OFFLINE")] == ["disconnected"]
    assert "echo and reply received" in transitions[("BUSY_THEN_OFFLINE", "OFFLINE")]
    assert ("QUIET", "QUIET_THEN_OFFLINE") in transitions
    assert any(after == "OFFLINE" for before, after in transitions if before == "QUIET_THEN_OFFLINE")
    diagram = mkdocs_hooks.engine_state_diagram()
    assert 'state "BUSY, then OFFLINE" as BUSY_THEN_OFFLINE' in diagram
    assert "| BUSY, then OFFLINE | echo and reply received" in diagram
