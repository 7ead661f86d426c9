"""Exit codes are written once, in ExitCode: the CLI's help and the docs' table are made from it."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from click.testing import CliRunner

from ics35_async.cli import cli
from ics35_async.cli._settings import ExitCode
from ics35_async.robot import load_description
from ics35_async.robot.calibration import dump_description
from tests.support.robot_rig import JOINTS, joint_position, make_rig, targets_sent

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


def test_the_table_gives_play_refusing_a_joint_turned_past_its_limit_its_code(cli: Any, tmp_path: Path) -> None:
    # Row 5 named, of play, a joint whose servo has not answered, not one turned past a limit by hand, which play
    # refuses with that code too (the motion's first command would throw the joint to the limit at full speed).
    rig = make_rig()
    try:
        robot_file, motion = tmp_path / "robot.toml", tmp_path / "m.json"
        robot_file.write_text(dump_description(load_description(rig.description)))
        motion.write_text(
            json.dumps(
                {"format": "ics35-motion", "version": 1, "keyframes": [{"time": 0.5, "pose": {"knee": -10, "hip": 5}}]}
            )
        )
        rig.servo("knee").move_by_hand(joint_position(JOINTS["knee"], 40.0))  # (its max: 20)
        result = cli("play", str(robot_file), str(motion))
        assert result.code == ExitCode.REFUSED and "past its limit 20" in result.err, result.err
        assert targets_sent(rig.sim("lower"), 2) == [], result.err
    finally:
        rig.close()
    refused = next(row for row in mkdocs_hooks.exit_code_table().splitlines() if row.startswith("| 5 |"))
    assert "a joint turned past its limit" in refused, refused


def test_the_table_gives_the_robot_commands_interrupted_their_code() -> None:
    # Row 0 names play and teach stopped with Ctrl-C; row 130 named neither calibrate stopped with it (nothing
    # written: test_robot_cli) nor a robot command interrupted as its robot opens (test_cli_pty), which exit 130.
    row = next(r for r in mkdocs_hooks.exit_code_table().splitlines() if r.startswith("| 130 |"))
    assert "`calibrate` stopped before it writes" in row, row
    assert "`play`, `teach` or `calibrate` interrupted while the robot opens" in row, row


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
