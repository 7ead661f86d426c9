"""Files a command writes or reads are checked before the line is touched: exit 2, nothing sent, no traceback."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from ics35_async.cli import CliError, ExitCode
from ics35_async.cli._paths import check_output_path
from tests.support.terminal import screen_of, typed_on_a_terminal


def test_a_sim_record_file_in_a_missing_directory(cli: Any) -> None:
    result = cli("--port", "sim://?record=/nonexistent/x.txt", "move", "1", "7500")
    assert result.code == ExitCode.USAGE
    assert "/nonexistent" in result.err and "does not exist" in result.err


def test_several_servos_dumped_to_a_name_that_is_not_a_json_file_are_told_both_ways(cli: Any, tmp_path: Path) -> None:
    # `-o backup` for 1-3: a directory meant (backup/) or one file of them all (backup.json)?  Nothing is read.
    result = cli("--port", "sim://?ids=1-3", "eeprom", "dump", "1-3", "-o", str(tmp_path / "backup"))
    said = " ".join(result.err.split())
    assert result.code == ExitCode.USAGE, result.err
    assert f"-o {tmp_path}/backup/ (one file per servo) or -o {tmp_path}/backup.json (one file of them all)" in said


def test_a_sim_replay_file_that_is_not_there(cli: Any, tmp_path: Path) -> None:
    result = cli("--port", f"sim://?replay={tmp_path}/missing.txt", "get", "1", "speed")
    assert result.code == ExitCode.USAGE
    assert "no such file" in result.err


def test_a_sim_replay_file_that_is_not_text(cli: Any, tmp_path: Path) -> None:
    given = tmp_path / "session.bin"
    given.write_bytes(b"\x7fELF\x02\x01\x01\x00\x00\xd0\xd1")
    result = cli("--port", f"sim://?replay={given}", "get", "1", "speed")
    assert result.code == ExitCode.USAGE, result.err
    assert f"{given}: not a text file" in result.err


@pytest.mark.parametrize(
    "args",
    [
        ["play", "", "motion.json"],
        ["calibrate", ""],
        ["--port", "sim://", "monitor", "--free", "--plot", "", "--seconds", "0.2"],
        ["--port", "sim://?record=", "get", "1", "speed"],
    ],
    ids=["ROBOT.toml", "calibrate", "--plot", "record="],
)
def test_an_empty_file_name_is_named_empty(cli: Any, args: list[str]) -> None:
    # (a script's unset variable) It was "is a directory", for the current directory an empty path stands for.
    result = cli(*args)
    assert result.code == ExitCode.USAGE, result.err
    assert "the path is empty" in result.err and "directory" not in result.err, result.err


@pytest.mark.skipif(sys.platform == "win32", reason="a pseudo-terminal stands for the serial port")
@pytest.mark.parametrize("command", [["check"], ["play"], ["calibrate"]])
def test_a_serial_port_given_for_the_robot_file_is_named_a_device(cli: Any, command: list[str]) -> None:
    # (the port where the robot file goes) It was "no such file", of a port the user could see was there.
    master, slave = os.openpty()
    port = os.ttyname(slave)
    try:
        result = cli(*command, port, *(["wave.json"] if command == ["play"] else []))
    finally:
        os.close(slave)
        os.close(master)
    assert result.code == ExitCode.USAGE, result.err
    said = " ".join(result.err.split())
    assert f"{port}: this looks like a port (a device), not a robot file" in said and "no such file" not in said, said
    assert f'[lines.NAME] table each: port = "{port}"' in said, said


@pytest.mark.parametrize(
    "command",
    [["check"], ["play", "X", "wave.json"], ["teach", "X", "taught.json"], ["calibrate"], ["web", "--robot", "X"]],
    ids=lambda command: command[0],
)
def test_a_sim_url_given_for_the_robot_file_is_said_to_be_a_port_and_where_it_goes(
    cli: Any, command: list[str]
) -> None:
    # ics35 play sim://x wave.json said "ROBOT.toml sim://x: no such file" (the web page "sim:/x: no such file").
    args = [arg.replace("X", "sim://x") for arg in command] if "X" in command else [*command, "sim://x"]
    result = cli(*args)
    assert result.code == ExitCode.USAGE, result.err
    said = " ".join(result.err.split())
    assert "sim://x: this looks like a port (a sim:// URL), not a robot file" in said, said
    assert '[lines.NAME] table each: port = "sim://x"' in said and "no such file" not in said, said
    assert "Traceback" not in result.err and result.out == "", result.out


def test_a_sim_record_file_is_written(cli: Any, tmp_path: Path) -> None:
    target = tmp_path / "session.txt"
    assert cli("--port", f"sim://?record={target}", "move", "1", "7600").code == 0
    assert "position" in target.read_text()


def test_no_traceback_as_a_process() -> None:
    done = subprocess.run(
        [sys.executable, "-m", "ics35_async.cli", "--port", "sim://?record=/nonexistent/x.txt", "move", "1", "7500"],
        capture_output=True,
        text=True,
        timeout=60,
        env={k: v for k, v in os.environ.items() if k != "ICS35_PORT"},
    )
    assert done.returncode == ExitCode.USAGE
    assert "Traceback" not in done.stderr and "error:" in done.stderr


# ------------------------------------------------------------------- the helper itself (eeprom dump -o uses it too)


def test_check_output_path(tmp_path: Path) -> None:
    assert check_output_path(str(tmp_path / "a.json"), "-o") == tmp_path / "a.json"
    cases = {
        "/nonexistent/x.json": "does not exist",
        str(tmp_path): "is a directory",
        str(tmp_path / "a.txt"): "cannot write .txt files",
    }
    for path, says in cases.items():
        with pytest.raises(CliError) as caught:
            check_output_path(path, "-o", {"json"})
        assert caught.value.code == ExitCode.USAGE
        assert says in caught.value.message and "-o" in caught.value.message
    (tmp_path / "file").write_text("")
    with pytest.raises(CliError, match="not a directory"):
        check_output_path(str(tmp_path / "file" / "x.json"), "-o")


@pytest.mark.pty
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="a pty")
def test_a_backup_read_from_a_terminal_says_it_waits_for_one(tmp_path: Path) -> None:
    # `eeprom restore 1 -` typed at a terminal waited for standard input without a word: it looked hung.
    code, shown = typed_on_a_terminal(
        ["--port", "sim://?ids=1", "eeprom", "restore", "1", "-", "--yes"],
        [("standard input", b"\x04")],  # Ctrl-D: nothing pasted
    )
    said = " ".join(" ".join(screen_of(shown)).split())
    assert "reading the backup from standard input: paste it, then Ctrl-D" in said, said
    assert code == ExitCode.USAGE and "not JSON" in said, said


# ------------------------------------------------------------------- a directory given where a file goes


@pytest.mark.skipif(sys.platform == "win32", reason="a pseudo-terminal stands for the serial port")
def test_sniff_output_ending_in_a_slash_is_refused_not_written_as_a_file(cli: Any, tmp_path: Path) -> None:
    # `ics35 sniff -o heard/` wrote the decoded lines into a file named "heard": sniff names no file of its own.
    master, slave = os.openpty()
    try:
        result = cli("--port", os.ttyname(slave), "sniff", "-o", f"{tmp_path}/heard/", "--duration", "0.1")
    finally:
        os.close(slave)
        os.close(master)
    assert result.code == ExitCode.USAGE, result.err
    said = " ".join(result.err.split())
    assert f"--output {tmp_path}/heard/: names a directory; give a file name (nothing was sent)" in said, said
    assert list(tmp_path.iterdir()) == []


def test_one_servo_dumped_into_a_directory_gets_the_file_name_a_dump_of_several_gives(
    cli: Any, sim_line: Any, tmp_path: Path
) -> None:
    _, url = sim_line([1])
    (tmp_path / "there").mkdir()
    for given in (f"{tmp_path}/there", f"{tmp_path}/there/", f"{tmp_path}/new/"):
        result = cli("--port", url, "eeprom", "dump", "1", "-o", given)
        assert result.code == 0, result.err
        written = Path(given.rstrip("/")) / "servo-01.json"
        assert f"EEPROM of servo 1 saved to {written}" in result.err and written.is_file(), result.err


@pytest.mark.parametrize("ids", ["1", "1-2"])
def test_a_dump_into_a_directory_whose_parent_is_missing_is_refused_before_reading(
    cli: Any, sim_line: Any, tmp_path: Path, ids: str
) -> None:
    # `-o bakcup/2024/` (a typo) made the whole chain of directories, and the backup went where nobody looks.
    sim, url = sim_line([1, 2])
    given = f"{tmp_path}/bakcup/2024/"
    result = cli("--port", url, "eeprom", "dump", ids, "-o", given)
    assert result.code == ExitCode.USAGE, result.err
    said = " ".join(result.err.split())
    assert f"--output {given}: the directory {tmp_path}/bakcup does not exist (nothing was sent)" in said, said
    assert sim.transactions == 0 and list(tmp_path.iterdir()) == []


def test_a_plot_path_ending_in_a_slash_is_named_a_directory(tmp_path: Path) -> None:
    with pytest.raises(CliError) as caught:
        check_output_path(f"{tmp_path}/plots/", "--plot", {"png"})
    assert "names a directory; give a file name" in caught.value.message, caught.value.message


@pytest.mark.pty
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="a pty")
def test_ctrl_c_while_a_backup_is_pasted_says_nothing_was_written(tmp_path: Path) -> None:
    # It ended "interrupted" alone, where every other command's Ctrl-C says what was (not) done as an error line.
    code, shown = typed_on_a_terminal(
        ["--port", "sim://?ids=1", "eeprom", "restore", "1", "-", "--yes"], [("standard input", b"\x03")]
    )
    said = " ".join(" ".join(screen_of(shown)).split())
    assert code == ExitCode.INTERRUPTED and "error: interrupted" in said and "nothing was written" in said, said
