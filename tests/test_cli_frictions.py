"""Small things a new user tripped over: the simulator named once, on stderr, help texts, --json before the
command, the environment named in errors, a directory as a port, joint angles without float noise."""

from __future__ import annotations

import asyncio
import json
import re
import sys
from pathlib import Path
from typing import Any

import click
import pytest

from ics35_async.cli import ExitCode
from ics35_async.cli._runner import simulator_note
from ics35_async.robot import load_description, open_robot
from ics35_async.sim import VirtualLine, VirtualServo
from ics35_async.sim.console import LineConsole

_WITH_JSON = [
    ["get", "1", "speed"],
    ["info", "1"],
    ["info", "1", "--free"],
    ["scan", "--ids", "1-2"],
    ["eeprom", "dump", "1"],
    ["monitor", "1", "--free", "--seconds", "0.2"],
]


@pytest.mark.parametrize(
    ("command", "as_json"),
    [
        *((command, as_json) for command in _WITH_JSON for as_json in (False, True)),
        (["demo", "--ids", "1-2", "--seconds", "0.2"], False),  # (demo has no --json)
    ],
    ids=lambda value: " ".join(value) if isinstance(value, list) else ("json" if value else "text"),
)
def test_a_command_without_port_names_the_simulator_once_on_stderr(cli: Any, command: list[str], as_json: bool) -> None:
    # It was said twice: a note on stderr and a line on stdout ("simulated servos (the built-in simulator: no
    # --port given)"), which a pipe (`ics35 get 1 speed | cut -d' ' -f3`) took for a result.
    result = cli(*command, *(["--json"] if as_json and command[:2] != ["eeprom", "dump"] else []))
    assert result.code == 0, result.err
    assert result.err.splitlines().count(simulator_note()) == 1, result.err
    assert result.err.count("no --port") == 1, result.err
    assert "no --port" not in result.out and "simulated servos" not in result.out, result.out
    if as_json or command[:2] == ["eeprom", "dump"]:
        # The data says where it came from, as data: its plausible values must not pass for a robot's.
        documents = [json.loads(line) for line in result.out.splitlines() if line.startswith("{")]
        assert documents and all(document["simulated"] is True for document in documents), result.out


def test_a_read_with_a_port_is_not_marked(cli: Any, sim_line: Any) -> None:
    _, url = sim_line([1])
    result = cli("--port", url, "get", "1", "speed", "--json")
    assert result.code == 0 and "simulated" not in result.json()
    text = cli("--port", url, "get", "1", "speed")
    assert "simulat" not in text.out and "built-in simulator" not in text.err


def test_a_dump_without_port_stays_a_valid_backup_and_says_so(cli: Any) -> None:
    result = cli("eeprom", "dump", "1")
    assert result.code == 0, result.err
    assert result.json()["simulated"] is True and result.json()["format"] == "ics35-eeprom/1"


def test_a_dump_to_files_without_port_says_so_in_the_files_and_a_restore_of_one_warns(
    cli: Any, sim_line: Any, tmp_path: Any
) -> None:
    one, folder = tmp_path / "one.json", tmp_path / "all"
    assert cli("eeprom", "dump", "4", "-o", str(one)).code == 0
    assert cli("eeprom", "dump", "1-2", "-o", f"{folder}/").code == 0
    for path in (one, folder / "servo-01.json", folder / "servo-02.json"):
        assert json.loads(path.read_text())["simulated"] is True, path
    _, url = sim_line([4])
    restored = cli("--port", url, "eeprom", "restore", str(one), "--yes")
    assert restored.code == 0, restored.err
    assert "read from the built-in simulator" in restored.err
    # Without --port the restore is refused before any line opens: no hint that it stopped reading servos.
    refused = cli("eeprom", "restore", str(one), "--yes")
    assert refused.code == 2 and "nothing was sent" in refused.err, refused.err
    assert "while reading the servos" not in refused.err, refused.err
    # Nor when the port cannot be opened (no line, so no servo was read).
    missing = cli("--port", "/dev/ttyICS35-none", "eeprom", "restore", str(one), "--yes")
    assert missing.code == 3 and "while reading the servos" not in missing.err, missing.err


def test_a_restore_of_several_servos_saved_without_port_warns_once_for_the_file(
    cli: Any, sim_line: Any, tmp_path: Any
) -> None:
    # A file of four servos' backups dumped from the built-in simulator repeated its warning four times.
    several = tmp_path / "arm.json"
    assert cli("eeprom", "dump", "1-4", "-o", str(several)).code == 0
    _, url = sim_line([1, 2, 3, 4])
    restored = cli("--port", url, "eeprom", "restore", str(several), "--yes")
    assert restored.code == 0, restored.err
    assert restored.err.count("read from the built-in simulator") == 1, restored.err


def test_eeprom_help_shows_the_summary_of_set_whole(cli: Any) -> None:
    result = cli("eeprom", "--help")
    assert result.code == 0
    text = " ".join(result.out.split())
    assert "Change EEPROM fields: eeprom set 1 speed=100 flags+=PWMINH." in text
    assert "e.g.\n" not in result.out and "asks..." not in text


def test_json_before_the_command_is_accepted_like_the_line_options(cli: Any, sim_line: Any) -> None:
    _, url = sim_line([1])
    result = cli("--json", "--port", url, "get", "1", "speed")
    assert result.code == 0, result.err
    assert result.json()["value"] == 127
    result = cli("--json", "teach", "robot.toml", "out.json")
    assert result.code == ExitCode.USAGE and "--json: `ics35 teach` has no JSON output" in result.err


def test_a_bad_baud_from_the_environment_names_the_variable(cli: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("ICS35_BAUD", "12")
    result = cli("get", "1", "speed")
    assert result.code == ExitCode.USAGE and "(from ICS35_BAUD=12)" in result.err


def test_a_port_from_the_environment_is_named_when_it_fails(
    cli: Any, monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    missing = str(tmp_path / "ttyUSB9")
    monkeypatch.setenv("ICS35_PORT", missing)
    result = cli("get", "1", "speed")
    assert result.code == ExitCode.PORT
    assert f"from the environment: ICS35_PORT={missing}" in result.err
    result = cli("--port", str(tmp_path / "other"), "get", "1", "speed")  # --port wins: not named
    assert result.code == ExitCode.PORT and "ICS35_PORT" not in result.err


@pytest.mark.skipif(sys.platform == "win32", reason="a POSIX directory")
def test_a_directory_as_a_port_says_so_once(cli: Any, tmp_path: Path) -> None:
    result = cli("--port", str(tmp_path), "get", "1", "speed")
    assert result.code == ExitCode.PORT
    assert result.err.lower().count("is a directory") == 1 and "Errno" not in result.err, result.err


def test_a_missing_port_is_said_in_words_not_an_errno(cli: Any, tmp_path: Path) -> None:
    result = cli("--port", str(tmp_path / "ttyUSB9"), "get", "1", "speed")
    assert result.code == ExitCode.PORT
    assert result.err.startswith(f"error: no serial port at '{tmp_path / 'ttyUSB9'}'"), result.err


@pytest.mark.skipif(sys.platform == "win32", reason="the pty simulator is POSIX only")
def test_sim_help_is_laid_out_like_every_other_command(cli: Any) -> None:
    theirs = cli("scan", "--help").out
    result = cli("sim", "--help")
    assert result.code == 0
    assert result.out.startswith("Usage: ics35 sim [OPTIONS]") and theirs.startswith("Usage: ics35 scan [OPTIONS]")
    assert "\nOptions:\n" in result.out and "\nOptions:\n" in theirs
    assert "  --ids TEXT " in result.out and "Servo IDs, e.g. 0-31" in result.out  # click's metavars, capitals
    assert "  -h, --help " in result.out and "Show this message and exit." in result.out
    assert "usage:" not in result.out and "options:" not in result.out  # argparse's own layout


@pytest.mark.skipif(sys.platform == "win32", reason="the pty simulator is POSIX only")
def test_sim_help_names_every_command_its_console_takes(cli: Any) -> None:
    """The simulator's pages send people to ``ics35 sim --help`` for the console: a command the console takes
    (``turn``, which stands in for a hand in calibrate's practice) must be named there too."""
    commands = LineConsole(VirtualLine([]), 115200).execute("help").removeprefix("commands: ")
    names = [item.split()[0] for item in re.sub(r"\([^)]*\)", "", commands).split(", ")]
    assert "turn" in names, names
    result = cli("sim", "--help")
    assert result.code == 0
    console = " ".join(result.out.split("--console", 1)[1].split("--last", 1)[0].split())
    missing = [name for name in names if not re.search(rf"\b{name}\b", console)]
    assert not missing, console


@pytest.mark.skipif(sys.platform == "win32", reason="the pty simulator is POSIX only")
@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["--bogus"], "Error: Unrecognized arguments: --bogus"),
        (["--ids", "x"], "Error: --ids x: 'x' is not an ID (0..31) or a range of IDs"),
        (["--ids", ""], "Error: --ids '': no IDs given: write IDs 0..31"),  # (was a line of no servos)
        (["--noisy", "40"], "Error: --noisy 40: servo ID must be in 0..31, got 40"),
        (["--ics36", "x"], "Error: --ics36 x: 'x' is not an ID (0..31) or a range of IDs"),
        (["--ids", "1-3", "--noisy", "7"], "Error: No servo of this line is built from ID 7 given in noisy"),
        (["--baud", "3"], "Error: Baud rate must be one of 115200, 625000, 1250000, got 3"),
        (["--baud", "fast"], "Error: Argument --baud: invalid int value: 'fast'"),
    ],
)
def test_sim_usage_errors_look_like_every_other_commands(cli: Any, args: list[str], says: str) -> None:
    theirs = cli("scan", "--ids", "x")
    result = cli("sim", *args)
    assert result.code == theirs.code == ExitCode.USAGE
    assert theirs.err.startswith("Usage: ics35 scan [OPTIONS]\nTry 'ics35 scan --help' for help.\n\nError: ")
    assert result.err.startswith("Usage: ics35 sim [OPTIONS]\nTry 'ics35 sim --help' for help.\n\nError: "), result.err
    assert says in result.err, result.err
    assert "usage:" not in result.err and "ics35 sim: error:" not in result.err  # argparse's own layout
    assert result.out == ""


def test_restore_to_a_silent_servo_names_restores_own_syntax(cli: Any, sim_line: Any, tmp_path: Path) -> None:
    _, url = sim_line([1])
    backup = tmp_path / "one.json"
    assert cli("--port", url, "eeprom", "dump", "1", "-o", str(backup)).code == 0
    _, other = sim_line([2])
    result = cli("--port", other, "--timeout", "0.005", "eeprom", "restore", str(backup), "--yes")
    assert result.code == ExitCode.NO_REPLY
    hint = f"to write it to another servo: ics35 --port {other} --timeout 0.005 eeprom restore ID {backup}"
    assert hint in " ".join(result.err.split())
    assert "nothing was written" in result.err  # it stopped reading the servo, before any write


def test_restore_to_its_own_servo_at_another_rate_says_the_rate_not_another_servo(cli: Any, tmp_path: Path) -> None:
    # Servo 1 moved to 625000 baud since its backup: the restore at 115200 said where it answers, then offered to
    # write the file "to another servo", when it is this servo's own file at another rate.
    url = "sim://another-rate?ids=1&baud=625000"
    backup = tmp_path / "one.json"
    assert cli("--port", url, "--baud", "625000", "eeprom", "dump", "1", "-o", str(backup)).code == 0
    result = cli("--port", url, "eeprom", "restore", str(backup), "--yes")
    said = " ".join(result.err.split())
    assert result.code == ExitCode.WRONG_BAUD and "pass --baud 625000" in said, said
    assert "another servo" not in said, said


def test_a_servo_that_did_not_go_free_is_said_in_words_not_the_librarys_record(cli: Any) -> None:
    # "servo 5: no answer (free to ID 5: no reply (check ID, baud rate, power) (raw: 85 00 00))": the library's
    # record of the transaction, its command's name and bytes, where a person reads why (the bytes are in -v's log).
    result = cli("--port", "sim://?ids=1", "free", "1,5")
    said = result.out + result.err
    assert result.code == ExitCode.NO_REPLY, said
    assert "servo 5: no answer\n" in said and "raw:" not in said and "free to ID" not in said, said


def test_read_pose_has_no_float_noise_and_no_negative_zero(tmp_path: Path) -> None:
    sim = VirtualLine([VirtualServo(1), VirtualServo(2)], name="frictions-pose")
    robot_file = tmp_path / "robot.toml"
    robot_file.write_text(
        '[lines.main]\nport = "sim://frictions-pose"\n\n'
        '[joints.a]\nline = "main"\nid = 1\noffset = 5\n\n'
        '[joints.b]\nline = "main"\nid = 2\nreverse = true\n'
    )
    sim.servo(1).move_by_hand(7648)  # 4.995 servo degrees: joint -0.005, not -0.004999999999999893
    sim.servo(2).move_by_hand(7500)  # neutral, reversed: 0.0, not -0.0

    async def pose() -> dict[str, float]:
        async with open_robot(load_description(robot_file), on_close="free") as robot:
            return await robot.read_pose()

    try:
        got = asyncio.run(pose())
    finally:
        sim.close()
    assert json.dumps(got) == json.dumps({"a": round((148 * 270 / 8000) - 5, 5), "b": 0.0})
    assert str(got["b"]) == "0.0"


@pytest.mark.parametrize(
    "args",
    [["move", "--bogus"], ["move", "1", "--bogus"], ["move", "1", "7500", "--degs"], ["set", "--bogus", "1", "speed"]],
    ids=["move-first", "move-second", "move-misspelt", "set"],
)
def test_an_unknown_option_of_a_command_taking_negative_numbers_is_named_as_such(cli: Any, args: list[str]) -> None:
    # move and set take negative values (move 1 -30 --deg): an unknown option was read as the ID or the
    # position ("'--bogus' is not a servo ID"), or went unsaid.
    result = cli("--port", "sim://?ids=1", *args)
    assert result.code == ExitCode.USAGE, result.err
    assert "No such option: --" in result.err or "No such option '--" in result.err, result.err


def test_negative_values_still_reach_move_and_set(cli: Any) -> None:
    assert cli("--port", "sim://?ids=1", "move", "1", "-30", "--deg").code == 0
    for value in ("-.5", "-1e1", "-2.5"):  # (any number Python reads)
        moved = cli("--port", "sim://?ids=1", "move", "1", value, "--deg")
        assert moved.code == 0, (value, moved.err)
    refused = cli("--port", "sim://?ids=1", "set", "1", "speed", "-5")
    assert refused.code == ExitCode.USAGE and "No such option" not in refused.err, refused.err


@pytest.mark.parametrize(
    "args",
    [
        ["info", "-1"],
        ["get", "-1", "speed"],
        ["free", "-1"],
        ["free", "1", "-3"],
        ["eeprom", "dump", "-1"],
        ["eeprom", "set", "-1", "speed=100"],
        ["monitor", "-1"],
        ["set-id", "-1"],
        ["eeprom", "restore", "-1", "backup.json"],
    ],
    ids=["info", "get", "free", "free-second", "dump", "eeprom-set", "monitor", "set-id", "restore"],
)
def test_a_negative_id_is_said_to_be_no_servo_id(cli: Any, args: list[str]) -> None:
    # Click took it for an option: "No such option '-1'", for an ID out of range.
    result = cli("--port", "sim://?ids=1", *args)
    assert result.code == ExitCode.USAGE and "No such option" not in result.err, result.err
    negative = next(a for a in args if a.startswith("-"))
    assert "0..31" in result.err and negative in result.err, result.err


@pytest.mark.parametrize(
    "args",
    [
        ["info", "-x", "1"],
        ["info", "1", "-1x"],
        ["eeprom", "dump", "1", "-q"],
        ["free", "-z", "1"],
        ["free", "-v", "--bogus", "1"],  # (-v counts: it takes no value, and --bogus is no word of its)
        ["info", "-v", "--bogus", "1"],
    ],
    ids=["info-letter", "info-mixed", "dump", "free", "free-after-count", "info-after-count"],
)
def test_an_unknown_short_option_of_a_command_taking_ids_is_still_named_as_such(cli: Any, args: list[str]) -> None:
    result = cli("--port", "sim://?ids=1", *args)
    assert result.code == ExitCode.USAGE and "No such option" in result.err, result.err


def test_a_value_that_starts_with_a_dash_still_reaches_its_option(cli: Any, tmp_path: Path) -> None:
    # (-o's value is the file's name, whatever it looks like; joined to its option too)
    result = cli("--port", "sim://?ids=1", "eeprom", "dump", "1", "-o", str(tmp_path / "-one.json"))
    assert result.code == 0 and (tmp_path / "-one.json").exists(), result.err
    joined = cli("eeprom", "dump", "1", "-psim://?ids=1", f"-o{tmp_path / 'two.json'}")
    assert joined.code == 0 and (tmp_path / "two.json").exists(), joined.err


@pytest.mark.parametrize(
    "command",
    [
        ["get", "1", "speed", "--json"],
        ["info", "1", "--json"],
        ["info", "1", "--free", "--json"],
        ["scan", "--ids", "1-2", "--json"],
        ["eeprom", "dump", "1"],
        ["monitor", "1", "--free", "--seconds", "0.2", "--json"],
        ["demo", "--ids", "1-2", "--seconds", "0.2"],
    ],
    ids=lambda words: " ".join(words),
)
@pytest.mark.parametrize("port", [[], ["--port", "sim://"]], ids=["no port", "sim://"])
def test_the_built_in_simulators_servos_run_at_the_baud_rate_the_command_is_given(
    cli: Any, command: list[str], port: list[str]
) -> None:
    # `get 1 speed --baud 625000` exited 6 ("servo 1 does not answer at 625000 baud, but does at 115200 baud")
    # while monitor and demo ran the simulator's servos at that rate: it stands in for servos set up for the line.
    result = cli(*port, *command, "--baud", "625000")
    assert result.code == 0, result.err
    if command[0] == "scan":  # (it tries every rate: the servos answer at one)
        assert [servo["answered_at"] for servo in result.json()["servos"]] == [[625000], [625000]]
    else:
        assert "115200" not in result.err + result.out, result.err + result.out
    if command[:2] == ["eeprom", "dump"]:
        assert result.json()["baud"] == 625000 and result.json()["fields"]["baud_rate"] == 625000


def test_sim_given_a_port_says_it_serves_a_line_of_its_own(cli: Any) -> None:
    # `ics35 --port /tmp/robot-line sim --ids 1` served a new pty and said nothing of the port given, which a
    # builder meant as where to serve (that is --link).
    result = cli("--port", "/tmp/robot-line", "sim", "--idz", "1")  # (a usage error: it ends before serving)
    said = " ".join(result.err.split())
    assert "--port is not used" in said and "--link" in said, said


def test_a_field_set_twice_or_a_table_asked_as_json_is_refused_before_anything_is_sent(cli: Any) -> None:
    # `eeprom set 1 speed=60 speed=70` quietly took 70; `eeprom dump 1 --table --json` printed the table.
    twice = cli("--port", "sim://", "eeprom", "set", "1", "speed=60", "speed=70", "--yes")
    assert twice.code == ExitCode.USAGE and "speed is given twice (60 and 70)" in twice.err, twice.err
    both = cli("--port", "sim://", "eeprom", "dump", "1", "--table", "--json")
    assert both.code == ExitCode.USAGE and "--table" in both.err and "--json" in both.err, both.err
    assert not both.out


@pytest.mark.parametrize(
    ("assignment", "meant"),
    [("strech_gain=50", "stretch_gain"), ("temprature_limit=80", "temperature_limit"), ("flags+=REVERS", "REVERSE")],
)
def test_a_misspelt_eeprom_field_or_flag_names_the_one_meant(cli: Any, assignment: str, meant: str) -> None:
    # `eeprom set 1 strech_gain=50` listed all 18 fields, where one was meant.
    said = cli("--port", "sim://", "eeprom", "set", "1", assignment, "--yes")
    assert said.code == ExitCode.USAGE and f"did you mean {meant}?" in " ".join(said.err.split()), said.err


def test_set_given_a_field_assignment_or_the_position_points_at_the_command_that_takes_it(cli: Any) -> None:
    # `ics35 set 1 speed=60` (eeprom set's form) and `ics35 set 1 position 8000` got only the list of parameters.
    said = " ".join(cli("set", "1", "speed=60").err.split())
    assert "ics35 set 1 speed 60" in said and "ics35 eeprom set 1 speed=60" in said, said
    said = " ".join(cli("set", "1", "position", "8000").err.split())
    assert "ics35 move 1 POSITION" in said, said


def test_set_id_given_an_old_id_too_says_it_takes_the_new_one_only(cli: Any) -> None:
    # `ics35 set-id 1 5` (old and new, as other tools take them): "Got unexpected extra argument (5)", no more.
    result = cli("set-id", "1", "5")
    assert result.code == ExitCode.USAGE, result.err
    said = " ".join(result.err.split())
    assert "takes the new ID only" in said and "ics35 set-id 5" in said, said
    # (a line option's value after the ID is no second ID, given apart, joined to its letter, or after flags run
    # together with it; -v counts, taking no value)
    for words in (["5", "--baud", "115200"], ["5", "-b115200"], ["-yb", "115200", "5"], ["-v", "5"]):
        renamed = cli("--port", "sim://?ids=1", "set-id", *words, "--yes")
        assert renamed.code == 0 and "takes the new ID only" not in renamed.err, (words, renamed.err)
    assert "takes the new ID only" in cli("set-id", "-v", "1", "5").err


def test_an_id_list_that_is_not_one_is_refused_with_one_example(cli: Any) -> None:
    # `ics35 free x`: "'x' is not an ID or a range of IDs (write e.g. 3, 1-12 or 0,4,7) (IDs are 0..31; write e.g.
    # 3, 1-12, 0,4,7 or all)": the example twice, the first without `all`.
    result = cli("free", "x")
    assert result.code == ExitCode.USAGE, result.err
    said = " ".join(result.err.split())
    assert said.count("write e.g.") == 1 and "0,4,7 or all" in said, said
    # `ics35 scan --ids 40`: "the IDs '40' must lie within 0..31 (IDs are 0..31; write e.g. ...)": the range twice.
    for ids, says in (("40", "servo ID must be in 0..31, got 40"), ("3-40", "'3-40'"), ("x", "'x'")):
        result = cli("scan", "--ids", ids)
        assert result.code == ExitCode.USAGE, result.err
        said = " ".join(result.err.split())
        assert said.count("0..31") == 1 and says in said and said.count("write e.g.") == 1, said


def test_the_search_of_the_other_rates_never_says_a_rate_that_answered_did_not() -> None:
    # `ics35 --baud 1250000 info 1` on a line at 115200: the search went on after 115200 answered (it looks at every
    # rate) and said "no answer at 115200 baud either: trying 625000 baud ...", above "servo 1 does not answer at
    # 1250000 baud, but does at 115200 baud".
    from tests.support.terminal import screen_of, typed_on_a_terminal

    port = "sim://?ids=1-3"
    code, shown = typed_on_a_terminal(["--port", port, "--baud", "1250000", "--timeout", "0.05", "info", "1"], [])
    screen = " ".join(" ".join(screen_of(shown)).split())
    assert code == ExitCode.WRONG_BAUD, screen
    assert "no answer at 1250000 baud: trying 115200 baud ... trying 625000 baud too ..." in screen, screen
    assert "115200 baud either" not in screen and "does at 115200 baud" in screen, screen


def test_a_wrong_id_is_said_asked_at_every_rate_as_each_is_tried() -> None:
    # `ics35 --port sim://?ids=1-3 info 5`, an ID nobody has: the search of the other rates said "no answer at 115200
    # baud" before each of them ("trying 625000", then again "trying 1250000", as if 625000 had not been asked), and
    # the error named 115200 alone once all three had gone unanswered.
    from tests.support.terminal import screen_of, typed_on_a_terminal

    code, shown = typed_on_a_terminal(["--port", "sim://?ids=1-3", "--timeout", "0.05", "info", "5"], [])
    screen = " ".join(" ".join(screen_of(shown)).split())
    assert code == ExitCode.NO_REPLY, screen
    tried = "no answer at 115200 baud: trying 625000 baud ... trying 1250000 baud too ..."
    assert tried in screen, screen
    assert "error: servo 5 did not answer on sim://?ids=1-3 at 115200 baud, nor at 625000 or 1250000 baud" in screen


@pytest.mark.parametrize(
    "command",
    [["monitor", "1", "--free", "--seconds", "0.2"], ["demo", "--ids", "1", "--seconds", "0.2"]],
    ids=lambda command: command[0],
)
def test_one_id_asked_is_said_in_the_singular(cli: Any, command: list[str]) -> None:
    # `monitor 1` said "asking IDs 1 on ...".
    result = cli("--port", "sim://?ids=1", *command)
    assert result.code == 0, result.err
    assert "asking ID 1 on sim://?ids=1 at 115200 baud ..." in result.err and "IDs 1 " not in result.err, result.err


def test_one_id_that_cannot_be_read_without_going_limp_is_named_as_one(cli: Any) -> None:
    # `monitor 1` without --free on an ICS 3.5 servo said "no servo among 1 can report its position ...".
    result = cli("--port", "sim://?ids=1", "monitor", "1", "--seconds", "0.2")
    assert result.code == ExitCode.REFUSED, result.err
    said = " ".join(result.err.split())
    assert "no servo at ID 1 can report its position without going limp" in said and "among 1 " not in said, said


def test_one_servo_in_a_dump_of_all_and_in_a_robot_files_line_is_named_as_one(cli: Any, tmp_path: Path) -> None:
    # "1 servo(s) answered at 115200 baud: IDs 3"; check's "line main: ..., IDs 1".
    dumped = cli("--port", "sim://?ids=3", "eeprom", "dump", "all", "-o", f"{tmp_path}/backup/")
    assert dumped.code == 0, dumped.err
    assert "1 servo answered at 115200 baud: ID 3 (" in " ".join(dumped.err.split()), dumped.err
    robot = tmp_path / "one.toml"
    robot.write_text('[lines.main]\nport = "sim://"\n\n[joints.neck]\nline = "main"\nid = 1\n')
    shown = cli("check", str(robot))
    assert shown.code == 0, shown.err
    assert "115200 baud, as fast as the line goes, ID 1" in " ".join(shown.out.split()), shown.out


def _numeric_options() -> list[tuple[list[str], str, float | None, float | None, bool]]:
    """(command path, option, low, high, whole) for every option of every command that takes a bounded number."""
    from ics35_async.cli import cli as group

    found: list[tuple[list[str], str, float | None, float | None, bool]] = []
    seen: set[tuple[str, object, object]] = set()  # (the line options, on every command: tried on the first)

    def walk(command: click.Command, path: list[str]) -> None:
        ctx = click.Context(command)
        if isinstance(command, click.Group):
            for name in command.list_commands(ctx):
                sub = command.get_command(ctx, name)
                assert sub is not None
                walk(sub, [*path, name])
        for param in command.params:
            kind = param.type
            if isinstance(param, click.Option) and isinstance(kind, (click.FloatRange, click.IntRange)):
                if param.count or (param.opts[0], kind.min, kind.max) in seen:
                    continue
                seen.add((param.opts[0], kind.min, kind.max))
                found.append(
                    (
                        path,
                        param.opts[0],
                        kind.min,
                        kind.max,
                        isinstance(kind, click.IntRange) or kind.name == "integer",
                    )  # type: ignore[arg-type]
                )

    walk(group, [])
    return found


@pytest.mark.parametrize(
    "path,option,low,high,whole", [pytest.param(*o, id=" ".join([*o[0], o[1]])) for o in _numeric_options()]
)
def test_a_bad_number_is_said_in_words_not_clicks_type_names(
    cli: Any, path: list[str], option: str, low: float | None, high: float | None, whole: bool
) -> None:
    # Click said "'x' is not a valid float range." and "9.0 is not in the range 0.001<=x<=5.0.".
    result = cli(*path, option, "x")
    assert result.code == ExitCode.USAGE, result.err
    said = "not a whole number" if whole else "not a number"
    assert f"'x' is {said}" in result.err and "range" not in result.err, result.err
    for text in ("nan", "inf", "1_0", "\u0663"):  # (float() and int() read them: NaN within every range; 10; 3)
        result = cli(*path, option, text)
        assert result.code == ExitCode.USAGE and f"{text!r} is {said}" in result.err, result.err
    for beyond in ([high + 1] if high is not None else []) + ([low - 1] if low is not None else []):
        shown = f"{beyond:g}"
        result = cli(*path, option, shown)
        assert result.code == ExitCode.USAGE, result.err
        said = " ".join(result.err.split())
        assert "<=" not in said and ".0 " not in said and "must be " in said and f", not {shown}" in said, said
        bound = f"{high:g}" if beyond > (high or 0) else f"{low:g}"
        assert re.search(rf"(?<!\d)(?<!\d\.){re.escape(bound)}(?!\d|\.\d)", said.split("must be", 1)[1]), said


def test_the_port_named_as_an_example_is_one_of_this_systems(cli: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    # On Linux `ics35 --port '' scan` offered "e.g. '/dev/ttyUSB0' or 'COM3'" and the no-port refusal "(or COM3; ...)",
    # and `--port COM3` is then refused there: "COM names are Windows' own".
    from ics35_async.transports.wire_device import example_port

    assert (example_port("win32"), example_port("linux")) == ("COM3", "/dev/ttyUSB0")
    assert example_port("darwin").startswith("/dev/cu.")
    for platform in ("linux", "win32", "darwin"):
        monkeypatch.setattr(sys, "platform", platform)
        others = [o for o in ("COM3", "/dev/ttyUSB0", "/dev/cu.") if not example_port(platform).startswith(o)]
        for args in (["move", "1", "7500"], ["info", "1"]):  # (a refusal; the simulator's note)
            said = " ".join(cli(*args).err.split())
            assert example_port(platform) in said and not [o for o in others if o in said], (platform, said)
    # (the library's words, read on any machine: each system's name said as that system's)
    said = " ".join(cli("--port", "", "scan").err.split())
    assert "/dev/ttyUSB0 on Linux" in said and "COM3 on Windows" in said, said
