"""ics35 check ROBOT.toml [MOTION.json]...: a robot file, and motions against it, checked with no port opened."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from ics35_async.cli import ExitCode
from ics35_async.errors import InvalidArgument
from ics35_async.robot import load_description
from ics35_async.sim import open_url
from tests.support.cli_runs import run_process
from tests.support.terminal import screen_of, typed_on_a_terminal

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"

ROBOT = """\
name = "arm"

[lines.main]
port = "{port}"
baudrate = 1250000
rate_hz = 100

[safety]
max_temperature_c = 70
action = "hold"

[joints.shoulder]
line = "main"
id = 1
min = -90
max = 45

[joints.elbow]
line = "main"
id = 2
reverse = true
offset = 2.4975

[joints.wrist]
line = "main"
id = 5
min = -30
max = 30
"""


def robot_file(tmp_path: Path, port: str = "/dev/ttyUSB9") -> Path:
    path = tmp_path / "arm.toml"
    path.write_text(ROBOT.format(port=port))
    return path


def motion_file(path: Path, *poses: dict[str, float]) -> Path:
    keyframes = [{"time": 0.5 * (k + 1), "pose": pose} for k, pose in enumerate(poses)]
    path.write_text(json.dumps({"format": "ics35-motion", "version": 1, "keyframes": keyframes}))
    return path


def test_a_robot_file_is_summed_up_with_no_port_opened(cli: Any, tmp_path: Path) -> None:
    # Its port is a path no adapter has here: nothing is opened, so nothing is missing.
    result = cli("check", str(robot_file(tmp_path)))
    assert result.code == 0, result.err
    said = " ".join(result.out.split())
    assert "arm.toml: robot arm, 1 line, 3 joints (no port opened)" in said, said
    # (said as not there now: a builder who mistyped it learns it before play, nothing failing for it)
    assert "line main: /dev/ttyUSB9 (not there now) at 1250000 baud, 100 cycles/s, IDs 1, 2, 5" in said, said
    for row in ("shoulder main 1 0 -90 45", "elbow main 2 reversed 2.4975 -132.5025 137.4975", "wrist main 5 0 -30 30"):
        assert row in said, said
    # (the elbow's default limits: the servo's whole travel, in joint degrees from its offset)
    # The joints at the servo's whole travel (no limits of their own, never calibrated?) are named.
    assert "elbow: its limits are the servo's whole travel" in said, said
    assert (
        "safety: above 70 °C (approximate), or a servo going offline: motions end and every joint keeps its last "
        "target (action = hold)"
    ) in said, said


def test_a_joint_whose_file_gives_the_whole_travel_as_its_limits_is_not_said_to_have_none(
    cli: Any, tmp_path: Path
) -> None:
    # After calibrate measured a wrist that turns the servo's whole way (min = -135, max = 135): "no min or max in
    # the file: ics35 calibrate finds a joint's own", sending the builder to calibrate again.
    path = tmp_path / "wrist.toml"
    path.write_text(
        '[lines.main]\nport = "/dev/ttyUSB9"\n[joints.wrist]\nline = "main"\nid = 1\nmin = -135\nmax = 135\n'
        '[joints.elbow]\nline = "main"\nid = 2\n'
    )
    said = " ".join(cli("check", str(path)).out.split())
    assert "elbow: its limits are the servo's whole travel (no min or max in the file" in said, said
    assert "wrist, elbow:" not in said and "wrist:" not in said, said


def test_motions_are_checked_against_the_robot(cli: Any, tmp_path: Path) -> None:
    robot = robot_file(tmp_path)
    wave = motion_file(tmp_path / "wave.json", {"shoulder": 20, "wrist": -10}, {"shoulder": 0}, {"wrist": 0})
    result = cli("check", str(robot), str(wave))
    assert result.code == 0, result.err
    said = " ".join(result.out.split())
    assert "wave.json: 3 keyframes, 1.5 s, moves shoulder, wrist: fits the robot" in said, said

    beyond = motion_file(tmp_path / "beyond.json", {"shoulder": 20}, {"wrist": 40})
    result = cli("check", str(robot), str(wave), str(beyond))
    assert result.code == ExitCode.USAGE, result.err
    err = " ".join(result.err.split())
    assert "beyond.json" in err and "keyframes[1]" in err and "wrist" in err and "-30..30" in err, err

    stranger = motion_file(tmp_path / "stranger.json", {"knee": 20})
    result = cli("check", str(robot), str(stranger))
    assert result.code == ExitCode.USAGE and "knee" in result.err, result.err


def test_a_robot_file_that_breaks_a_rule_is_refused_naming_its_key(cli: Any, tmp_path: Path) -> None:
    path = tmp_path / "arm.toml"
    path.write_text(ROBOT.format(port="/dev/ttyUSB9").replace("id = 5", "id = 40"))
    result = cli("check", str(path))
    assert result.code == ExitCode.USAGE, result.err
    assert "joints.wrist.id" in result.err and "arm.toml" in result.err, result.err
    assert "Traceback" not in result.err
    # With --json a script reading stdout got nothing at all: the same error, as data (and the same exit code).
    wave = motion_file(tmp_path / "wave.json", {"shoulder": 20})
    result = cli("check", str(path), str(wave), "--json")
    assert result.code == ExitCode.USAGE, result.err
    doc = result.json()
    assert doc["robot"] is None and doc["motions"] == [], doc
    assert "joints.wrist.id" in doc["error"] and "nothing was sent" not in doc["error"], doc


@pytest.mark.parametrize("port", ["sim://?ids=", "sim://?idz=1-3", "sim://?ids=1-4&ics36=7"])
def test_a_sim_port_the_simulator_would_refuse_is_named_with_its_reason(cli: Any, tmp_path: Path, port: str) -> None:
    """check passed a robot file whose line names a sim:// URL the simulator refuses (an empty ID list, a misspelt
    option): the builder learnt it only from play, at the open.  check says so, in the simulator's own words."""
    with pytest.raises(InvalidArgument) as at_open:
        open_url(port)
    result = cli("check", str(robot_file(tmp_path, port)))
    assert result.code == ExitCode.USAGE, (result.out, result.err)
    said = " ".join(result.err.split())
    assert f"arm.toml: lines.main.port: {json.dumps(port)} is refused: {at_open.value}" in said, said
    assert "Traceback" not in said and "nothing was sent" not in said and not result.out, (result.out, said)


def test_the_example_humanoid_and_its_wave_fit(cli: Any) -> None:
    result = cli("check", str(EXAMPLES / "humanoid.toml"), str(EXAMPLES / "wave.json"), "--json")
    assert result.code == 0, result.err
    doc = result.json()
    assert doc["robot"]["name"] == "humanoid"
    assert [line["name"] for line in doc["robot"]["lines"]] == ["upper", "legs"]
    assert len(doc["robot"]["joints"]) == 17
    assert doc["robot"]["joints"][0] == {
        "name": "head_yaw",
        "line": "upper",
        "id": 1,
        "reverse": False,
        "offset": 0.0,
        "min": -90.0,
        "max": 90.0,
    }
    assert doc["motions"][0]["file"].endswith("wave.json") and doc["motions"][0]["keyframes"] > 1
    assert doc["robot"]["safety"]["action"] == "hold"


def test_every_motion_is_checked_and_each_one_that_does_not_fit_is_named(cli: Any, tmp_path: Path) -> None:
    # After a calibration, checking the motions taught before: the first that did not fit ended the command, and
    # the others (and the robot's summary) went unsaid.
    robot = robot_file(tmp_path)
    beyond = motion_file(tmp_path / "beyond.json", {"shoulder": 20}, {"wrist": 40})
    wave = motion_file(tmp_path / "wave.json", {"shoulder": 20, "wrist": -10}, {"shoulder": 0})
    stranger = motion_file(tmp_path / "stranger.json", {"knee": 20})
    result = cli("check", str(robot), str(beyond), str(wave), str(stranger))
    assert result.code == ExitCode.USAGE, result.err
    said, err = " ".join(result.out.split()), " ".join(result.err.split())
    assert "arm.toml: robot arm, 1 line, 3 joints (no port opened)" in said, said
    assert "wave.json: 2 keyframes, 1 s, moves shoulder, wrist: fits the robot" in said, said
    assert "beyond.json: keyframes[1]: joint wrist: 40 degrees is outside its limits -30..30" in err, err
    assert "stranger.json: keyframes[0]: unknown joint(s): knee" in err, err
    assert f"2 of 3 motions do not fit {robot}" in err, err
    assert "nothing was sent" not in err, err  # (check sends nothing, ever)

    result = cli("check", str(robot), str(beyond), str(wave), "--json")
    assert result.code == ExitCode.USAGE, result.err
    motions = {Path(m["file"]).name: m for m in result.json()["motions"]}
    assert motions["wave.json"]["fits"] is True and "error" not in motions["wave.json"], motions
    assert motions["beyond.json"]["fits"] is False and "keyframes[1]" in motions["beyond.json"]["error"], motions


def test_a_motion_file_missing_or_broken_is_said_so_not_that_it_does_not_fit(cli: Any, tmp_path: Path) -> None:
    # A motion file not there, a folder, or not a motion at all was counted among the motions that "do not fit".
    robot = robot_file(tmp_path)
    missing = tmp_path / "gone.json"
    folder = tmp_path / "folder.json"
    folder.mkdir()
    broken = tmp_path / "broken.json"
    broken.write_text("{not json")
    beyond = motion_file(tmp_path / "beyond.json", {"wrist": 40})
    wave = motion_file(tmp_path / "wave.json", {"shoulder": 20})
    paths = [str(p) for p in (missing, folder, broken, beyond, wave)]
    result = cli("check", str(robot), *paths)
    assert result.code == ExitCode.USAGE, result.err
    said, err = " ".join(result.out.split()), " ".join(result.err.split())
    assert "wave.json: 1 keyframe, 0.5 s, moves shoulder: fits the robot" in said, said  # (the others still checked)
    # Each named with what is wrong, in the words play uses for the same file (less its "nothing was sent").
    for path in (missing, folder, broken):
        played = cli("play", str(robot), str(path))
        assert played.code == ExitCode.USAGE, played.err
        words = " ".join(played.err.split()).removeprefix("error: ").split(" (nothing was sent)")[0]
        assert f"error: {words}" in err, (words, err)
    assert f"MOTION.json {missing}: no such file" in err, err
    assert f"{broken}: not valid JSON" in err, err
    assert (
        f"4 of 5 motions: 1 was not found, 1 is not readable, 1 is not a motion file and 1 does not fit {robot}"
    ) in err, err

    result = cli("check", str(robot), *paths, "--json")
    assert result.code == ExitCode.USAGE, result.err
    motions = {Path(m["file"]).name: m for m in result.json()["motions"]}
    assert {name: m["problem"] for name, m in motions.items() if not m["fits"]} == {
        "gone.json": "not found",
        "folder.json": "not readable",
        "broken.json": "not a motion file",
        "beyond.json": "does not fit",
    }, motions
    assert motions["gone.json"]["fits"] is None and "no such file" in motions["gone.json"]["error"], motions
    assert motions["beyond.json"]["fits"] is False and motions["wave.json"]["fits"] is True, motions
    assert "problem" not in motions["wave.json"], motions


def test_a_single_motion_refused_is_said_once(cli: Any, tmp_path: Path) -> None:
    # "error: MOTION.json gone.json: no such file" was followed by "error: 1 of 1 motion was not found": the same
    # news twice.  With one motion its own error is the verdict; the count is for several.
    robot = robot_file(tmp_path)
    missing = tmp_path / "gone.json"
    beyond = motion_file(tmp_path / "beyond.json", {"wrist": 40})
    for path, words in ((missing, f"MOTION.json {missing}: no such file"), (beyond, "40 degrees is outside")):
        result = cli("check", str(robot), str(path))
        assert result.code == ExitCode.USAGE, result.err
        err = " ".join(result.err.split())
        assert words in err, err
        assert err.count("error:") == 1 and err.count(path.name) == 1, err
        assert "arm.toml: robot arm, 1 line, 3 joints" in " ".join(result.out.split()), result.out
        result = cli("check", str(robot), str(path), "--json")
        assert result.code == ExitCode.USAGE, result.err
        assert [m["fits"] for m in result.json()["motions"]] == [None if path == missing else False], result.out


def check_table_rows(lines: list[str]) -> list[str]:
    """The lines of check's joint table among ``lines``: below its header, up to the line naming the columns left
    out or the safety's."""
    top = next(k for k, line in enumerate(lines) if line.split()[:1] == ["joint"])
    end = next(k for k in range(top + 1, len(lines)) if lines[k].lstrip().startswith(("columns left out", "safety:")))
    return lines[top + 1 : end]


def test_the_joint_table_on_a_narrow_terminal_keeps_every_value_whole() -> None:
    # At 50 columns rich fitted the table by cutting every column's values: "right_s…" for any of four joints,
    # "revers…", "offse…".  As the live views' table: the joints' line left out (named under the table), then
    # long names wrapped after an underscore.
    columns = 50
    humanoid = load_description(EXAMPLES / "humanoid.toml")
    code, written = typed_on_a_terminal(["check", str(EXAMPLES / "humanoid.toml")], [], columns=columns)
    screen = [line for line in screen_of(written, width=columns) if line]
    said = "\n".join(screen)
    assert code == 0 and "Traceback" not in written, said
    rows = check_table_rows(screen)
    assert not any("…" in line for line in rows) and all(len(line) <= columns for line in rows), said
    assert "".join(line.split()[0] for line in rows) == "".join(humanoid.joints), said
    reversed_ = sum(joint.reverse for joint in humanoid.joints.values())
    assert sum(line.split().count("reversed") for line in rows) == reversed_, said
    assert "  columns left out: line" in screen, said


NARROW_ROBOT = """\
[lines.upper]
port = "sim://narrow-upper"
[lines.legs]
port = "sim://narrow-legs"
[joints.head_yaw]
line = "upper"
id = 1
offset = 10.125
min = -94.5
max = 74.2
[joints.r_shoulder_pitch]
line = "upper"
id = 2
min = -84.3
max = 84.3
[joints.l_shoulder_roll]
line = "upper"
id = 10
reverse = true
min = -84.3
max = 84.3
[joints.r_knee]
line = "legs"
id = 3
offset = -10.125
min = -108
max = 128.2
"""


@pytest.mark.parametrize("columns", [30, 36, 40, 45, 50])
def test_the_joint_table_on_any_narrow_terminal_cuts_no_value_and_names_every_column_it_leaves_out(
    columns: int, tmp_path: Path
) -> None:
    # At 45 columns a table of short names and wide values ("-10.125", "128.2") was cut by rich: "-10.1…", "128…"
    # and a header "offse…"; at 40 an ID "…" and "mi…".  Columns now go (named under the table) before a value
    # is cut: the joints' line first, then long names wrapped, then whether joints are reversed, then from the right.
    robot = tmp_path / "narrow.toml"
    robot.write_text(NARROW_ROBOT)
    joints = load_description(robot).joints
    code, written = typed_on_a_terminal(["check", str(robot)], [], columns=columns)
    screen = [line for line in screen_of(written, width=columns) if line]
    said = "\n".join(screen)
    assert code == 0 and "Traceback" not in written, said
    top = next(k for k, line in enumerate(screen) if line.split()[:1] == ["joint"])
    shown = screen[top].split()
    end = next(k for k in range(top + 1, len(screen)) if screen[k].lstrip().startswith(("columns left out", "safety:")))
    caption = " ".join(screen[end : next(k for k in range(end, len(screen)) if "safety:" in screen[k])]).split()
    left_out = " ".join(caption[3:]).split(", ") if caption[:3] == ["columns", "left", "out:"] else []
    assert sorted(shown + left_out) == sorted(["joint", "line", "ID", "reverse", "offset°", "min°", "max°"]), said
    rows = [line.split() for line in screen[top + 1 : end]]
    values = [row for row in rows if len(row) > 1]  # (a name's wrapped lines hold its next parts alone)
    assert len(values) == len(joints), said
    for row, joint in zip(values, joints.values(), strict=True):
        assert "…" not in " ".join(row[1:]), said  # (a name may be cut, with its ellipsis; a value never)
        whole = {
            "ID": str(joint.id),
            "offset°": f"{joint.offset:g}",
            "min°": f"{joint.min:g}",
            "max°": f"{joint.max:g}",
        }
        expected = [whole[h] for h in shown if h in whole]
        assert [v for v in row[1:] if v not in ("upper", "legs", "reversed")] == expected, said


def test_the_joint_table_into_a_log_is_printed_whole() -> None:
    # (`COLUMNS=50 ics35 check robot.toml > log`: as the live commands' logs, the whole table at its own width)
    proc = run_process("check", str(EXAMPLES / "humanoid.toml"), columns=50)
    assert proc.returncode == 0, proc.stderr
    rows = check_table_rows(proc.stdout.splitlines())
    assert not any("…" in line for line in rows) and "columns left out" not in proc.stdout, proc.stdout
    joints = load_description(EXAMPLES / "humanoid.toml").joints
    assert [line.split()[0] for line in rows] == list(joints), proc.stdout
    assert [line.split()[1:3] for line in rows] == [[joint.line, str(joint.id)] for joint in joints.values()], rows
