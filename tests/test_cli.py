"""The ``ics35`` command, run in this process against named in-process simulated lines.

Each test builds its own :class:`VirtualLine` and reaches it as ``sim://NAME``, so
it can check what the command did to the servos (or that it sent nothing).
The serial boundary (a real subprocess on a pty) is covered by test_cli_pty.py.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import anyio
import pytest

from ics35_async import units
from ics35_async.cli import ExitCode
from ics35_async.cli._common import CliError, Settings, translate
from ics35_async.cli._console import TitleInParts
from ics35_async.cli._live import forced_out
from ics35_async.cli._live_view import LiveState
from ics35_async.eeprom import BaudRate, Flags
from ics35_async.errors import InvalidArgument, PortLost
from ics35_async.extras import install_command, installed_from
from ics35_async.protocol import ReadEeprom, ReadParam, WriteId
from ics35_async.sim import VirtualServo
from ics35_async.transports import PortPermissionDenied
from tests.support.sim_servos import CtrlCWhenAsked, UnplugsWhenAsked

# --------------------------------------------------------------------------- bad arguments


@pytest.mark.parametrize(
    "args",
    [
        ["move", "32", "7500"],
        ["move", "1", "20000"],
        ["move", "1", "0"],
        ["move", "1", "7500.5"],
        ["move", "1", "400", "--deg"],
        ["move", "1", "abc"],
        ["get", "1", "voltage"],
        ["get", "-1", "speed"],
        ["set", "1", "speed", "0"],
        ["set", "1", "current-limit", "64"],
        ["set", "1", "current", "10"],
        ["free", "1-40"],
        ["info", "abc"],
        ["info", "1_0"],  # (int() reads 10: a "1-0"... mistyped, never an ID)
        ["free", "1_3"],
        ["monitor", "1_3"],
        ["eeprom", "set", "1", "colour=3"],
        ["eeprom", "set", "1", "speed=300"],
        ["eeprom", "set", "1", "stretch_gain=61"],
        ["eeprom", "set", "1", "flags=0x20"],
        ["eeprom", "set", "1", "flags=TURBO"],
        ["eeprom", "set", "1", "baud=9600", "--change-baud", "--yes"],
        ["eeprom", "set", "1", "speed"],
        ["set-id", "32"],
        ["scan", "--bauds", "9600"],
        ["monitor", "0-40"],
    ],
)
def test_bad_arguments_exit_2_and_send_nothing(cli: Any, sim_line: Any, args: list[str]) -> None:
    sim, url = sim_line()
    result = cli("--port", url, *args)
    assert result.code == ExitCode.USAGE == 2
    assert "Error" in result.err or "error" in result.err
    assert sim.transactions == 0


def test_unknown_param_names_the_choices(cli: Any, sim_line: Any) -> None:
    _, url = sim_line()
    result = cli("--port", url, "get", "1", "voltage")
    for name in ("stretch", "speed", "current", "temperature"):
        assert name in result.err


def test_id_lists() -> None:
    assert units.parse_id_list("1-3,7, 9") == [1, 2, 3, 7, 9]
    assert units.parse_id_list("all") == list(range(32))
    for bad in ("3-1", "x", "31-32", ""):
        with pytest.raises(InvalidArgument):
            units.parse_id_list(bad)


# --------------------------------------------------------------------------- reads, with --json


def test_scan_json_lists_exactly_the_servos(cli: Any, sim_line: Any) -> None:
    _, url = sim_line([4, 9, 30])
    result = cli("--port", url, "scan", "--bauds", "115200", "--timeout", "0.005", "--json")
    assert result.code == 0
    doc = result.json()
    assert [(s["id"], s["baud"]) for s in doc["servos"]] == [(4, 115200), (9, 115200), (30, 115200)]
    assert [s["eeprom"]["servo_id"] for s in doc["servos"]] == [4, 9, 30]
    assert doc["garbled"] == []


def test_scan_finds_servos_at_every_baud(cli: Any, sim_line: Any) -> None:
    servos = [VirtualServo(1), VirtualServo(2, baud_rate=1250000), VirtualServo(3, baud_rate=625000)]
    _, url = sim_line(servos)
    result = cli("--port", url, "scan", "--ids", "0-4", "--timeout", "0.005")
    assert result.code == 0
    lines = [ln.split() for ln in result.out.splitlines()]
    rows = {int(cols[0]): int(cols[1]) for cols in lines if len(cols) > 2 and cols[0].isdigit() and cols[1].isdigit()}
    assert rows == {1: 115200, 2: 1250000, 3: 625000}
    assert "servos at different baud rates" in result.err
    # ... and how to bring one to another's rate (the note alone left a newcomer there).
    assert "eeprom set ID baud_rate=" in result.err and "--change-baud" in result.err, result.err


def test_scan_names_one_baud_rate_in_the_command_that_moves_a_servo_to_another(cli: Any, sim_line: Any) -> None:
    """Scanned with --baud 1250000, the command the note gives reaches the servo at ITS_RATE only: the line's
    own --baud (the scan's) is left out of it, not given twice."""
    _, url = sim_line([VirtualServo(1), VirtualServo(2), VirtualServo(3, baud_rate=1250000)])
    result = cli("--port", url, "--baud", "1250000", "scan", "--ids", "0-4", "--timeout", "0.005")
    assert result.code == 0, result.err
    note = " ".join(line for line in result.err.splitlines() if "to bring one to" in line or "--change-baud" in line)
    assert "--baud ITS_RATE eeprom set ID baud_rate=115200 --change-baud" in note, result.err
    assert note.count("--baud") == 1, result.err


@pytest.mark.parametrize("as_json", [False, True], ids=["text", "json"])
def test_scan_whose_port_is_lost_part_way_shows_what_it_found_then_the_loss(
    cli: Any, sim_line: Any, as_json: bool
) -> None:
    puller = UnplugsWhenAsked(20, ReadEeprom)
    sim, url = sim_line([VirtualServo(1), VirtualServo(2), puller, VirtualServo(7, baud_rate=625000)])
    puller.line = sim
    result = cli("--port", url, "scan", "--timeout", "0.005", *(["--json"] if as_json else []))
    assert result.code not in (0, ExitCode.NO_REPLY), (result.code, result.err)
    assert "unplugged" in result.err, result.err
    if as_json:
        doc = result.json()
        assert [s["id"] for s in doc["servos"]] == [1, 2, 20]
        assert doc["servos"][0]["eeprom"]["servo_id"] == 1 and doc["servos"][2]["eeprom"] is None
        assert "unplugged" in doc["lost"]
    else:
        rows = [ln.split()[:2] for ln in result.out.splitlines() if ln.split()[:1] and ln.split()[0].isdigit()]
        assert [row[0] for row in rows if row[1] == "115200"] == ["1", "2", "20"], result.out
        assert "before the line was lost" in " ".join(result.err.split()), result.err


@pytest.mark.parametrize("as_json", [False, True], ids=["text", "json"])
def test_scan_lost_part_way_names_the_port_as_given(cli: Any, as_json: bool) -> None:
    """An unnamed sim:// line gets a name of the command's own for its reopenings at each rate; the loss, said
    once the line is closed, names the port as it was given, not that name."""
    port = "sim://?ids=1,2,20&faults=unplug@20:1&replug_after=30"  # lost as ID 20 is asked, at the first rate
    result = cli("--port", port, "scan", *(["--json"] if as_json else []))
    assert result.code == ExitCode.COMMUNICATION, result.err
    said = result.json()["lost"] if as_json else result.err
    assert f"port {port} lost" in " ".join(said.split()) and "ics35-cli" not in said, said


def test_scan_reports_a_shared_id_as_garbled(cli: Any, sim_line: Any) -> None:
    _, url = sim_line([VirtualServo(1), VirtualServo(3), VirtualServo(3)])
    result = cli("--port", url, "scan", "--bauds", "115200", "--ids", "0-4", "--json")
    doc = result.json()
    assert [s["id"] for s in doc["servos"]] == [1]
    assert doc["garbled"] == [{"id": 3, "baud": 115200}]
    # The table's summary (stdout) said only "1 servo(s) found ...: 1 at 115200 baud", the garbled ID on stderr alone.
    shown = cli("--port", url, "scan", "--bauds", "115200", "--ids", "0-4")
    assert shown.code == 0, shown.err
    summary = " ".join(shown.out.split()).split("servo(s) found", 1)[1]
    assert "ID 3 at 115200 baud answered garbled" in summary, shown.out


def test_new_servos_chained_at_id_0_are_named_not_blamed_on_power(cli: Any, sim_line: Any) -> None:
    # Every new KRS servo has ID 0: a newcomer who chains two and scans was told "no servo answered" with
    # the hints of an unpowered line (check the supply), under a warning about garbled replies.
    _, url = sim_line([VirtualServo(0), VirtualServo(0)])
    for command in (("scan", "--bauds", "115200", "--ids", "0-3"), ("doctor", "--ids", "0-3")):
        result = cli("--port", url, *command)
        assert result.code == 4, result.err
        (error,) = [ln for ln in result.err.splitlines() if ln.startswith("error:")]
        assert "ID 0" in error and "garbled" in error, result.err
        assert "set-id" in result.err and "check the servo has power" not in result.err, result.err


def test_info_json_matches_the_servo(cli: Any, sim_line: Any) -> None:
    sim, url = sim_line([VirtualServo(7, position=9000)])
    result = cli("--port", url, "info", "7", "--json", "--free")
    assert result.code == 0
    doc = result.json()
    assert doc["position"] == 9000 and doc["free"] is True and doc["protocol"] == "ICS 3.5"
    assert doc["degrees"] == pytest.approx(units.position_to_degrees(9000), abs=0.01)
    assert doc["eeprom"]["servo_id"] == 7
    assert doc["eeprom"]["raw"] == sim.servo(7).eeprom.to_bytes().hex()
    assert doc["temperature"]["raw"] == sim.servo(7).temperature


def test_info_no_position_says_why_once(cli: Any, sim_line: Any) -> None:
    # `ics35 info 1 --no-position` showed "position  not read: not read (--no-position)".
    _, url = sim_line([1])
    result = cli("--port", url, "info", "1", "--no-position")
    assert result.code == 0, result.err
    row = next(line for line in result.out.splitlines() if "position" in line)
    assert row.count("not read") == 1 and "--no-position" in row, row
    doc = cli("--port", url, "info", "1", "--no-position", "--json").json()
    assert doc["position"] is None and "--no-position" in doc["no_position_because"], doc
    assert not doc["no_position_because"].startswith("not read"), doc


def test_info_no_position_keeps_the_servo_holding(cli: Any, sim_line: Any) -> None:
    sim, url = sim_line([1])
    assert cli("--port", url, "move", "1", "8000").code == 0
    result = cli("--port", url, "info", "1", "--no-position")
    assert result.code == 0
    assert "not read" in result.out
    assert not sim.servo(1).free
    result = cli("--port", url, "info", "1")
    assert "pass --free" in result.out
    assert not sim.servo(1).free
    result = cli("--port", url, "info", "1", "--free")
    assert "torque now OFF" in result.out
    assert sim.servo(1).free


def test_move_counts_and_degrees(cli: Any, sim_line: Any) -> None:
    sim, url = sim_line([1])
    result = cli("--port", url, "move", "1", "8200", "--json")
    assert result.code == 0
    assert result.json()["target"] == 8200
    assert sim.servo(1).target == 8200
    result = cli("--port", url, "move", "1", "-30", "--deg")
    assert result.code == 0
    assert sim.servo(1).target == units.degrees_to_position(-30)
    result = cli("--port", url, "move", "1", "7499")  # -0.03 degrees
    assert result.code == 0
    assert "target 7499 (+0.0°)" in result.out  # never "-0.0"


def test_free_several(cli: Any, sim_line: Any) -> None:
    sim, url = sim_line([1, 2, 3])
    for i in (1, 2, 3):
        sim.servo(i).command_position(8000)
    result = cli("--port", url, "free", "1-2", "--json")
    assert result.code == 0
    assert set(result.json()["freed"]) == {"1", "2"}
    assert sim.servo(1).free and sim.servo(2).free and not sim.servo(3).free


def test_free_reports_the_missing_one(cli: Any, sim_line: Any) -> None:
    _, url = sim_line([1])
    result = cli("--port", url, "--timeout", "0.005", "free", "1", "2")
    assert result.code == ExitCode.NO_REPLY
    assert "servo 1: free at" in result.out
    assert "2" in result.err


def test_free_all_frees_the_servos_there_and_names_the_absent_ids_in_one_line(cli: Any, sim_line: Any) -> None:
    # "free all" makes a robot go limp: the 29 empty IDs of a 3-servo line are no failure, and no flood of lines.
    sim, url = sim_line([1, 2, 3])
    result = cli("--port", url, "--timeout", "0.005", "free", "all")
    assert result.code == 0, result.err
    assert [line.split(":")[0] for line in result.out.splitlines()] == ["servo 1", "servo 2", "servo 3"]
    assert all(sim.servo(i).free for i in (1, 2, 3))
    said = [line for line in result.err.splitlines() if line.strip()]
    assert len(said) == 1 and "0, 4-31" in said[0] and "no answer" in said[0], result.err


def test_free_all_asks_each_empty_id_once_whatever_the_allowance_and_retries(cli: Any, sim_line: Any) -> None:
    # A robot that misbehaves, over a TCP bridge (a long allowance): servo 20 is not to wait while each empty ID
    # below it takes the allowance and the retries (24 s here).  Each ID gets one free (the last, silent, a
    # second look behind a guard read, as a scan's last probe), and the report is what it was.
    sim, url = sim_line([1, 7, 20])
    result = cli("--port", url, "--timeout", "0.25", "--retries", "2", "free", "all")
    assert result.code == 0, result.err
    assert [line.split(":")[0] for line in result.out.splitlines()] == ["servo 1", "servo 7", "servo 20"]
    assert all(sim.servo(i).free for i in (1, 7, 20))
    said = [line for line in result.err.splitlines() if line.strip()]
    assert len(said) == 1 and "0, 2-6, 8-19, 21-31" in said[0] and "no answer" in said[0], result.err
    assert [(t.command, t.servo_id) for t in sim.log] == [
        *(("free", i) for i in range(32)),
        ("read_stretch", 31),
        ("free", 31),
    ]


def test_free_all_as_json_lists_the_absent_ids(cli: Any, sim_line: Any) -> None:
    _, url = sim_line([1, 2, 3])
    result = cli("--port", url, "--timeout", "0.005", "free", "all", "--json")
    assert result.code == 0, result.err
    doc = result.json()
    assert set(doc["freed"]) == {"1", "2", "3"} and doc["failed"] == {}
    assert doc["absent"] == [0, *range(4, 32)]
    assert result.err == ""


def test_free_all_where_nothing_answers_is_still_an_error(cli: Any, sim_line: Any) -> None:
    _, url = sim_line([])
    result = cli("--port", url, "--timeout", "0.005", "free", "all")
    assert result.code == ExitCode.NO_REPLY
    assert "power" in result.err


def test_free_all_where_nothing_answers_at_this_rate_names_the_rate_they_answer_at(cli: Any, sim_line: Any) -> None:
    # "servo 0 did not answer ... check the power" sent a builder whose servos are at 625000 the wrong way.
    _, url = sim_line([VirtualServo(1, baud_rate=625000), VirtualServo(2, baud_rate=625000)])
    result = cli("--port", url, "--timeout", "0.005", "free", "all")
    assert result.code == ExitCode.WRONG_BAUD, result.err
    assert "--baud 625000" in result.err and "servo 0" not in result.err, result.err
    assert "power" not in result.err, result.err


def test_eeprom_dump_of_several_where_none_answers_at_this_rate_names_the_rate_they_answer_at(
    cli: Any, sim_line: Any, tmp_path: Path
) -> None:
    _, url = sim_line([VirtualServo(1, baud_rate=1250000), VirtualServo(2, baud_rate=1250000)])
    result = cli("--port", url, "--timeout", "0.005", "eeprom", "dump", "1,2", "-o", f"{tmp_path}/")
    assert result.code == ExitCode.WRONG_BAUD, result.err
    assert "--baud 1250000" in result.err and "power" not in result.err, result.err


def test_free_of_named_ids_that_are_absent_is_still_an_error(cli: Any, sim_line: Any) -> None:
    _, url = sim_line([1, 2, 3])
    result = cli("--port", url, "--timeout", "0.005", "free", "1-5", "--json")
    assert result.code == ExitCode.NO_REPLY
    doc = result.json()
    assert set(doc["freed"]) == {"1", "2", "3"} and set(doc["failed"]) == {"4", "5"}
    assert "absent" not in doc


@pytest.mark.parametrize("ids", ["0,1", "all"])
def test_free_of_several_names_a_garbled_reply_as_such_not_as_a_silent_servo(cli: Any, sim_line: Any, ids: str) -> None:
    # Two new servos at ID 0 beside a third: "servo 0: no answer" and "check the servo has power" sent a
    # builder to the supply when the line says two servos share the ID (its reply came back garbled).
    sim, url = sim_line([VirtualServo(0), VirtualServo(0), VirtualServo(1)])
    result = cli("--port", url, "--timeout", "0.005", "free", ids)
    assert result.code == ExitCode.COMMUNICATION, result.err
    assert "servo 1: free at" in result.out and sim.servo(1).free
    assert "servo 0: no answer" not in result.err and "power" not in result.err, result.err
    assert "servo 0: garbled reply" in result.err and "two servos sharing one ID" in result.err, result.err


def test_get_and_set_are_ram(cli: Any, sim_line: Any) -> None:
    sim, url = sim_line([1])
    result = cli("--port", url, "set", "1", "speed", "50")
    assert result.code == 0
    assert "RAM" in result.out
    assert sim.servo(1).speed == 50
    assert sim.servo(1).eeprom.speed == 127  # RAM only
    result = cli("--port", url, "get", "1", "speed", "--json")
    assert result.json() == {"id": 1, "param": "speed", "value": 50, "memory": "RAM"}
    result = cli("--port", url, "get", "1", "temperature")
    assert "RAM" in result.out and "hotter" in result.out
    result = cli("--port", url, "set", "1", "current-limit", "20", "--json")
    assert result.json()["value"] == 20
    assert sim.servo(1).current_limit == 20


@pytest.mark.parametrize(
    ("param", "value", "eeprom_field"),
    [("stretch", "40", "stretch_gain=80"), ("speed", "50", "speed=50"), ("current-limit", "20", "current_limit=20")],
)
def test_set_names_the_eeprom_value_that_keeps_it(
    cli: Any, sim_line: Any, param: str, value: str, eeprom_field: str
) -> None:
    # The EEPROM stores the stretch twice over (RAM 1..127, EEPROM 2..254): the hint gives the value to type,
    # so stretch 40 is kept as stretch_gain=80, not 40 (which the servo would load as stretch 20).
    sim, url = sim_line([1])
    result = cli("--port", url, "set", "1", param, value)
    assert result.code == 0, result.err
    assert f"eeprom set 1 {eeprom_field})" in " ".join(result.out.split())
    kept = cli("--port", url, "eeprom", "set", "1", eeprom_field, "--yes")
    assert kept.code == 0, kept.err
    sim.servo(1).power_cycle()
    assert cli("--port", url, "get", "1", param).out.split("=")[1].split()[0] == value


@pytest.mark.parametrize("word", ["position", "Pos", "angle"])
def test_get_of_the_position_says_which_commands_read_it(cli: Any, sim_line: Any, word: str) -> None:
    # `ics35 get 1 position`, a newcomer's first guess, listed the RAM parameters and nothing more: the
    # position is not one of them (a servo tells it as it answers a position or free command).
    sim, url = sim_line([1])
    result = cli("--port", url, "get", "1", word)
    assert result.code == 2, result.err
    said = " ".join(result.err.split())
    assert "ics35 info 1" in said and "ics35 free 1" in said and "ics35 monitor 1 --free" in said, said
    assert sim.transactions == 0  # nothing sent


def test_get_limit_reads_the_eeprom_and_says_so(cli: Any, sim_line: Any) -> None:
    sim, url = sim_line([1])
    sim.servo(1).eeprom = sim.servo(1).eeprom.replace(temperature_limit=70)
    result = cli("--port", url, "get", "1", "temperature-limit", "--json")
    assert result.json() == {"id": 1, "param": "temperature-limit", "value": 70, "memory": "EEPROM"}
    result = cli("--port", url, "get", "1", "current-limit")
    assert "= 63" in result.out and "EEPROM" in result.out and "cannot be read back" in result.out


def test_a_temperature_limit_is_shown_in_celsius_and_which_way_is_hotter(cli: Any, sim_line: Any) -> None:
    # A limit of 60 is about 96 C, hotter than the factory 80 (about 80 C): a builder who meant "60 C" was
    # told only "temperature-limit = 60" and had loosened the servo's protection.
    _, url = sim_line([1])
    written = cli("--port", url, "set", "1", "temperature-limit", "60")
    assert written.code == 0, written.err
    assert "~96 °C" in written.out and "smaller is hotter" in written.out, written.out
    read = cli("--port", url, "get", "1", "temperature-limit")
    assert "= 80 (~80 °C)" in read.out and "smaller is hotter" in read.out, read.out


# --------------------------------------------------------------------------- errors a person can act on


def test_no_servo_answering(cli: Any, sim_line: Any) -> None:
    _, url = sim_line([])
    result = cli("--port", url, "--timeout", "0.005", "info", "1")
    assert result.code == ExitCode.NO_REPLY
    assert "power" in result.err and "scan" in result.err
    result = cli("--port", url, "scan", "--ids", "0-3", "--timeout", "0.005")
    assert result.code == ExitCode.NO_REPLY


def test_a_silent_line_points_at_the_adapter(cli: Any, sim_line: Any) -> None:
    _, url = sim_line([], echo=False)
    result = cli("--port", url, "scan", "--ids", "0-3", "--timeout", "0.005")
    assert result.code == ExitCode.NO_REPLY
    assert "not even the echo" in result.err


def test_wrong_baud_is_named(cli: Any, sim_line: Any) -> None:
    _, url = sim_line([VirtualServo(1, baud_rate=1250000)])
    result = cli("--port", url, "--timeout", "0.005", "get", "1", "speed")
    assert result.code == ExitCode.WRONG_BAUD
    assert "--baud 1250000" in result.err
    assert cli("--port", url, "--baud", "1250000", "get", "1", "speed").code == 0


def test_missing_port(cli: Any) -> None:
    result = cli("--port", "/dev/ics35-no-such-port", "info", "1")
    assert result.code == ExitCode.PORT
    assert "no serial port" in result.err
    assert result.err.count("ics35 ports") == 1  # where to look, said once


@pytest.mark.skipif(sys.platform == "win32", reason="a COM name is a real port name there")
def test_a_windows_port_name_elsewhere_is_named_as_such(cli: Any) -> None:
    result = cli("--port", "COM3", "info", "1")
    assert result.code == ExitCode.PORT
    assert "COM names are Windows'" in result.err


@pytest.mark.skipif(sys.platform == "win32", reason="device paths are POSIX ones")
@pytest.mark.parametrize("port", ["ttyUSB0", "ttyACM1", "tty.usbserial-A1", "cu.usbserial-A1"])
def test_a_device_name_without_its_directory_is_named_with_it(cli: Any, port: str) -> None:
    # `--port ttyUSB0`: the person meant /dev/ttyUSB0 (which exists on this machine or not).
    result = cli("--port", port, "info", "1")
    assert result.code == ExitCode.PORT
    assert f"a device path starts with /dev/: /dev/{port}" in result.err, result.err


@pytest.mark.skipif(sys.platform == "win32", reason="device paths are POSIX ones")
@pytest.mark.parametrize("port", ["tty1", "tty"])
def test_a_name_that_is_no_serial_ports_is_not_sent_to_a_terminals_device(cli: Any, port: str) -> None:
    # `port = "tty1"` in a robot file (a link beside it, the command run from elsewhere) was told "a device path
    # starts with /dev/: /dev/tty1": Linux's text console, not a serial adapter.
    result = cli("--port", port, "info", "1")
    assert result.code == ExitCode.PORT
    assert "a device path starts with" not in result.err and f"/dev/{port} " not in result.err, result.err


@pytest.mark.parametrize("port", ["sim:/?ids=1-6", "sim:?ids=1-6", "socket:/localhost:4000", "rfc2217:host:2217"])
def test_a_url_with_its_slashes_mistyped_is_named_as_such(cli: Any, port: str) -> None:
    # `sim:/?ids=1-6` was a port not found, with advice about the cable.
    result = cli("--port", port, "info", "1")
    assert result.code == ExitCode.PORT
    scheme = port.split(":")[0]
    assert f"a URL starts with {scheme}://" in result.err, result.err


@pytest.mark.skipif(sys.platform == "win32", reason="a COM name is a real port name there")
def test_the_configurator_names_misnamed_ports_as_the_command_does() -> None:
    from ics35_async.web import LineConfig, LineSession

    async def refused(port: str) -> str:
        session = LineSession(LineConfig())
        try:
            with pytest.raises(OSError):
                await session.connect(port)
            return session.status()["error"]
        finally:
            await session.close()

    assert "COM names are Windows' own" in anyio.run(refused, "COM3")
    assert "/dev/ttyUSB0" in anyio.run(refused, "ttyUSB0")


def test_missing_echo_is_named(cli: Any, sim_line: Any) -> None:
    _, url = sim_line([1], echo=False)
    result = cli("--port", url, "--timeout", "0.005", "get", "1", "speed")
    assert result.code == ExitCode.COMMUNICATION
    assert "pass --no-echo" in result.err
    assert cli("--port", url, "--no-echo", "get", "1", "speed").code == 0


def test_a_late_reply_ahead_of_the_echo_is_not_named_as_a_missing_echo(cli: Any) -> None:
    # Every reply's last 2 bytes come late (a TCP bridge holding a tail): the retry's echo arrives
    # behind them.  The echo is there, so --no-echo would be the wrong advice.
    result = cli("--port", "sim://?ids=1&faults=tail@1:1.0&tail_bytes=2", "get", "1", "stretch")
    assert result.code == ExitCode.COMMUNICATION
    assert "ahead of the echo" in result.err
    assert "--no-echo" not in result.err
    assert "--timeout" in result.err


def test_needless_no_echo_is_named(cli: Any, sim_line: Any) -> None:
    _, url = sim_line([1])
    result = cli("--port", url, "--timeout", "0.005", "--no-echo", "get", "1", "speed")
    assert result.code == ExitCode.COMMUNICATION
    assert "drop --no-echo" in result.err


def test_permission_denied_points_at_dialout() -> None:
    error = translate(Settings(port="/dev/ttyUSB0"), PortPermissionDenied(13, "permission denied opening it"))
    assert error.code == ExitCode.PORT
    assert any("dialout" in hint for hint in error.hints)


def test_a_lost_port_is_hinted_as_what_it_is(tmp_path: Path) -> None:
    # "hint: is the USB adapter still plugged in?" under `ics35 sim`'s pty gone (a stopped simulator) and under the
    # built-in simulator's own unplugged port: no USB adapter behind either.
    lost = PortLost("port lost: the device went away")
    assert translate(Settings(port="/dev/ttyUSB0"), lost).hints == ["is the USB adapter still plugged in?"]
    assert translate(Settings(port="sim://arm?ids=1"), lost).hints == []  # (its own words say it was unplugged)
    import pty as ptys

    master, slave = ptys.openpty()
    try:
        link = tmp_path / "ttyICS0"
        link.symlink_to(os.ttyname(slave))
        (hint,) = translate(Settings(port=str(link)), lost).hints
        assert "USB" not in hint and "simulator" in hint and "bridge" in hint, hint
        link.unlink()  # (a stopped `ics35 sim` removes its link: gone, the path is still not an adapter's)
        assert translate(Settings(port=str(link)), lost).hints == [hint]
    finally:
        os.close(master)
        os.close(slave)


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() != 0, reason="giving a file a group needs root")
def test_permission_denied_names_the_group_that_owns_the_port(tmp_path: Path) -> None:
    # On Arch and others serial ports belong to uucp: "sudo usermod -aG dialout" added the user to a
    # group that does not own the port (or to none at all).
    import grp

    group = next(g for g in grp.getgrall() if g.gr_gid != 0 and g.gr_name != "dialout")
    port = tmp_path / "ttyUSB0"
    port.write_text("")
    os.chown(port, 0, group.gr_gid)
    error = translate(Settings(port=str(port)), PortPermissionDenied(13, "permission denied opening it"))
    assert any(f"usermod -aG {group.gr_name} " in hint for hint in error.hints), error.hints


# --------------------------------------------------------------------------- EEPROM


def test_eeprom_set_shows_diff_and_needs_confirmation(cli: Any, sim_line: Any) -> None:
    sim, url = sim_line([1])
    result = cli("--port", url, "eeprom", "set", "1", "speed=90", "flags=PWMINH", stdin="n\n")
    assert result.code == ExitCode.REFUSED
    assert "speed" in result.out and "90" in result.out
    assert sim.servo(1).eeprom.speed == 127 and sim.servo(1).eeprom_writes == 0
    result = cli("--port", url, "eeprom", "set", "1", "speed=90", "flags=PWMINH", stdin="y\n")
    assert result.code == 0
    image = sim.servo(1).eeprom
    assert image.speed == 90 and image.flags == Flags.PWMINH
    assert sim.servo(1).calibration_intact


def test_eeprom_set_without_terminal_or_yes_writes_nothing(cli: Any, sim_line: Any) -> None:
    sim, url = sim_line([1])
    result = cli("--port", url, "eeprom", "set", "1", "punch=5")
    assert result.code == ExitCode.REFUSED
    assert "--yes" in result.err
    assert sim.servo(1).eeprom_writes == 0


def test_eeprom_baud_change_needs_its_own_flag(cli: Any, sim_line: Any) -> None:
    sim, url = sim_line([1])
    result = cli("--port", url, "eeprom", "set", "1", "baud=1250000", "--yes")
    assert result.code == ExitCode.REFUSED
    assert "--change-baud" in result.err and "HS" in result.err and "ONLY at 1250000" in result.err
    assert sim.servo(1).eeprom.baud_rate == BaudRate.B115200 and sim.servo(1).eeprom_writes == 0

    result = cli("--port", url, "eeprom", "set", "1", "baud=1250000", "--change-baud", "--yes", "--json")
    assert result.code == 0
    assert result.json()["changes"] == {"baud_rate": [115200, 1250000]}
    assert sim.servo(1).eeprom.baud_rate == BaudRate.B1250000
    assert sim.servo(1).calibration_intact
    sim.servo(1).power_cycle()
    assert cli("--port", url, "--baud", "1250000", "get", "1", "speed").code == 0


def test_an_eeprom_refusal_is_the_librarys_reason_and_the_flag_that_allows_it(
    cli: Any, sim_line: Any, tmp_path: Path
) -> None:
    """The CLI says why a write is refused in the library's words (``EepromPlan.why_refused``: the one rule) and
    adds only which of its flags allows it, not the keyword a program passes."""
    from ics35_async import open_bus
    from ics35_async.eeprom import WriteRefusal
    from ics35_async.policies import plan_eeprom_write

    sim, url = sim_line([1])

    def refusal(baud: int) -> WriteRefusal:
        async def plan() -> WriteRefusal | None:
            async with open_bus(url) as bus:
                return (await plan_eeprom_write(bus, 1, {"baud_rate": baud})).why_refused()

        why = anyio.run(plan)
        assert why is not None and why.allowed_by == "allow_baud_change"
        return why

    why = refusal(1250000)
    result = cli("--port", url, "eeprom", "set", "1", "baud=1250000", "--yes")
    said = " ".join(result.err.split())
    assert result.code == ExitCode.REFUSED
    assert f"refused: {why.reason}. Nothing was written" in said, said
    assert "to do it anyway, add --change-baud" in said and "allow_baud_change" not in said, said

    assert cli("--port", url, "eeprom", "dump", "1", "-o", str(tmp_path / "one.json")).code == 0
    sim.servo(1).eeprom = sim.servo(1).eeprom.replace(baud_rate=BaudRate.B625000)  # the backup's rate is now another
    why = refusal(115200)
    result = cli("--port", url, "eeprom", "restore", "1", str(tmp_path / "one.json"), "--yes")
    said = " ".join(result.err.split())
    assert result.code == ExitCode.REFUSED
    assert f"refused: {why.reason}. Nothing was written" in said, said
    assert "add --keep-baud" in said and "add --change-baud" in said and "allow_baud_change" not in said, said
    assert sim.servo(1).eeprom_writes == 0


def test_eeprom_id_change_refused_on_collision(cli: Any, sim_line: Any) -> None:
    sim, url = sim_line([1, 2])
    result = cli("--port", url, "eeprom", "set", "1", "id=2", "--yes")
    assert result.code == ExitCode.REFUSED
    assert sim.servo(1).eeprom_writes == 0
    result = cli("--port", url, "eeprom", "set", "1", "id=5", "--yes")
    assert result.code == 0
    assert sorted(s.servo_id for s in sim.servos) == [2, 5]


def test_restore_keeps_the_target_servos_calibration_and_id(cli: Any, sim_line: Any, tmp_path: Path) -> None:
    sim, url = sim_line([1, 2])
    sim.servo(1).eeprom = sim.servo(1).eeprom.replace(speed=33, punch=4, user_offset=-5, flags=Flags.PWMINH)
    backup = tmp_path / "one.json"
    assert cli("--port", url, "eeprom", "dump", "1", "-o", str(backup)).code == 0

    result = cli("--port", url, "eeprom", "restore", "2", str(backup), "--yes")
    assert result.code == 0, result.err
    two = sim.servo(2).eeprom
    assert (two.speed, two.punch, two.user_offset, two.flags) == (33, 4, -5, Flags.PWMINH)
    assert two.servo_id == 2
    assert sim.servo(2).calibration_intact

    # Servo 1's backup (with servo 1's calibration in its raw image) leaves servo 3's alone too.
    sim.add_device(VirtualServo(3))
    assert cli("--port", url, "eeprom", "restore", "3", str(backup), "--yes").code == 0
    assert sim.servo(3).eeprom.speed == 33 and sim.servo(3).calibration_intact


def test_restore_rejects_a_broken_backup(cli: Any, sim_line: Any, tmp_path: Path) -> None:
    sim, url = sim_line([1])
    bad = tmp_path / "bad.json"
    for content in ("not json", json.dumps({"fields": {"speed": 500}}), json.dumps([1, 2])):
        bad.write_text(content)
        result = cli("--port", url, "eeprom", "restore", "1", str(bad), "--yes")
        assert result.code == ExitCode.USAGE
    bad.write_bytes(b"\x7fELF\x02\x01\xd0\xd1")  # a program given by mistake: no traceback
    result = cli("--port", url, "eeprom", "restore", "1", str(bad), "--yes")
    assert result.code == ExitCode.USAGE and "not a text file" in result.err, result.err
    # Brackets nested deeper than Python's parser goes (a file edited into nonsense): refused as not JSON.
    for nested in ('{"a":' * 100_000, "[" * 100_000 + "]" * 100_000):
        bad.write_text(nested)
        result = cli("--port", url, "eeprom", "restore", "1", str(bad), "--yes")
        assert result.code == ExitCode.USAGE and "bad.json: not JSON: nested too deeply" in result.err, result.err
    assert sim.transactions == 0


# --------------------------------------------------------------------------- set-id, monitor, demo


def test_set_id_refused_with_a_shared_id(cli: Any, sim_line: Any) -> None:
    sim, url = sim_line([VirtualServo(3), VirtualServo(3)])
    result = cli("--port", url, "--timeout", "0.005", "set-id", "9", "--yes")
    assert result.code == ExitCode.REFUSED
    assert "unplug every servo but the one to renumber" in result.err, result.err
    assert [s.servo_id for s in sim.servos] == [3, 3]


@pytest.mark.parametrize(
    "command", [["monitor", "1-2", "--free", "--seconds", "0.3"], ["demo", "--ids", "1-2", "--seconds", "0.3"]]
)
def test_monitor_and_demo_name_the_rate_their_servos_answer_at(cli: Any, sim_line: Any, command: list[str]) -> None:
    # Servos at another rate: the stream ran "offline" to its end, then "no servo among 1-2 answered" with
    # power hints (exit 4), where get, info, free and eeprom name the rate (exit 6).
    _, url = sim_line([VirtualServo(1, baud_rate=1250000), VirtualServo(2, baud_rate=1250000)])
    result = cli("--port", url, "--timeout", "0.005", *command)
    assert result.code == ExitCode.WRONG_BAUD, result.err
    assert "--baud 1250000" in result.err and "Traceback" not in result.err
    assert cli("--port", url, "--baud", "1250000", *command).code == 0


def test_set_id_names_the_rate_a_lone_servo_answers_at(cli: Any, sim_line: Any) -> None:
    sim, url = sim_line([VirtualServo(3, baud_rate=625000)])
    result = cli("--port", url, "--timeout", "0.005", "set-id", "9", "--yes")
    assert result.code == ExitCode.WRONG_BAUD, result.err
    assert "625000" in result.err and "--baud 625000" in result.err
    assert [s.servo_id for s in sim.servos] == [3]  # nothing written
    assert cli("--port", url, "--baud", "625000", "set-id", "9", "--yes").code == 0
    assert [s.servo_id for s in sim.servos] == [9]


def test_set_id_interrupted_says_whether_the_id_write_was_on_its_way(cli: Any, sim_line: Any) -> None:
    # Ctrl-C as the ID command went out: the servo took ID 3, and all that was said was "error: interrupted".
    sim, url = sim_line([CtrlCWhenAsked(0, WriteId)])
    result = cli("--port", url, "set-id", "3", "--yes")
    assert result.code == ExitCode.INTERRUPTED, result.err
    said = " ".join(result.err.split())
    assert "interrupted while the ID write was on its way: the servo answers as ID 0 or as ID 3 now" in said, said
    assert f"see which with: ics35 --port {url} scan --ids 0,3 --bauds 115200 --quick" in said, said
    assert [s.servo_id for s in sim.servos] == [3]
    # Ctrl-C while the line is surveyed: nothing was written, and that is said.
    sim, url = sim_line([CtrlCWhenAsked(0, ReadParam)])
    result = cli("--port", url, "set-id", "3", "--yes")
    assert result.code == ExitCode.INTERRUPTED, result.err
    assert "interrupted before the ID write: nothing was written" in result.err, result.err
    assert [s.servo_id for s in sim.servos] == [0]


def test_set_id_with_its_port_lost_says_whether_the_id_write_was_on_its_way(cli: Any, sim_line: Any) -> None:
    # Lost as it surveyed the line, or as the ID command went out: only "port ... lost" was said, where Ctrl-C at
    # the same points says whether anything was written.
    for heard, written in ((ReadParam, False), (WriteId, True)):
        servo = UnplugsWhenAsked(0, heard)
        sim, url = sim_line([servo])
        servo.line = sim
        result = cli("--port", url, "set-id", "3", "--yes")
        said = " ".join(result.err.split())
        assert result.code == ExitCode.COMMUNICATION, said
        if written:
            assert "the ID write was on its way: the servo answers as ID 0 or as ID 3 now" in said, said
        else:
            assert "before the ID write: nothing was written" in said, said


def test_set_id_on_an_empty_line_says_nothing_answered(cli: Any, sim_line: Any) -> None:
    _, url = sim_line([])
    result = cli("--port", url, "--timeout", "0.005", "set-id", "9", "--yes")
    assert result.code == ExitCode.NO_REPLY, result.err
    assert "--baud" not in result.err


def test_demo_leaves_every_servo_free(cli: Any, sim_line: Any) -> None:
    sim, url = sim_line(range(4))
    result = cli("--port", url, "demo", "--ids", "0-3", "--seconds", "0.5")
    assert result.code == 0, result.err
    assert "left free" in result.out
    assert all(s.free for s in sim.servos)
    assert any(s.position != units.NEUTRAL for s in sim.servos)  # the wave moved them
    assert all(s.eeprom_writes == 0 for s in sim.servos)


def test_demo_frees_its_servos_at_the_end_beside_a_silent_id_on_a_long_allowance(cli: Any, sim_line: Any) -> None:
    # ID 3 named but absent, --timeout 0.25: the end's free waited a fixed second for two cycles while the table's
    # current and temperature reads of ID 3 (each with its guard read) took the line half a second each, and demo
    # said "the servos did not confirm the free command at the end; servo(s) 1, 2, 3 may still be holding" (exit
    # 5) with 1 and 2 freed.
    sim, url = sim_line(range(1, 3))
    result = cli("--port", url, "--timeout", "0.25", "demo", "--ids", "1-3", "--seconds", "0.6")
    assert result.code == 0, result.err
    assert "all servos left free" in result.out
    assert all(s.free for s in sim.servos)
    # Its time, not its last frame's (it said "done after 0.3 s", the next frame due after the time was up).
    assert float(result.out.split("demo done after ")[1].split()[0]) >= 0.6, result.out


def test_a_stop_forced_out_before_the_free_names_the_free_command_with_no_lost_line_to_wait_for() -> None:
    # A second Ctrl-C cutting demo's end short said "once the line is back, free them with: ..." though the line
    # was never lost: the command works at once.
    # (Neighbouring IDs as a range, as the robot commands write their free commands: "1,2,...,9" was demo's.)
    state = LiveState([1, 2, 3, 7], TitleInParts(("demo",)), 30.0, cycle=4)
    error = forced_out(Settings(port="/dev/ttyUSB0"), state, CliError(ExitCode.INTERRUPTED, "interrupted"))
    assert "servo(s) 1, 2, 3, 7 may still be holding" in error.message, error.message
    assert error.hints == ["free them with: ics35 --port /dev/ttyUSB0 free 1-3,7"], error.hints


def test_demo_counts_one_cycle_and_one_servo_in_the_singular(cli: Any, sim_line: Any) -> None:
    # A first cycle longer than --seconds (a servo that answers after 0.15 s) ends it after that cycle: it said
    # "1 cycles ... over 1 servos".
    sim, url = sim_line([1], realtime=True, turnaround=0.15)
    result = cli("--port", url, "--timeout", "1", "demo", "--ids", "1", "--seconds", "0.1")
    assert result.code == 0, result.err
    assert ": 1 cycle, " in result.out and " over 1 servo; " in result.out, result.out
    assert sim.servo(1).free


LIVE_ALL = [["demo", "--ids", "all"], ["monitor", "all", "--free"]]


@pytest.mark.parametrize("command", LIVE_ALL, ids=["demo", "monitor"])
def test_live_commands_on_all_name_an_id_that_answered_garbled_not_as_an_empty_one(
    cli: Any, sim_line: Any, command: list[str]
) -> None:
    # Two new servos at ID 0 beside servo 1: "no answer from ID(s) 0, 2-31: no servo there" hid the two left out.
    sim, url = sim_line([VirtualServo(0), VirtualServo(0), VirtualServo(1)])
    result = cli("--port", url, "--timeout", "0.005", *command, "--seconds", "0.3")
    assert result.code == 0, result.err
    assert sim.servo(1).free
    assert "no answer from ID(s) 2-31 at 115200 baud: no servo there" in result.err, result.err
    assert "ID(s) 0 answered garbled" in result.err and "two servos sharing an ID" in result.err, result.err


@pytest.mark.parametrize("command", LIVE_ALL, ids=["demo", "monitor"])
def test_live_commands_on_all_where_only_garbled_replies_came_say_so(
    cli: Any, sim_line: Any, command: list[str]
) -> None:
    # Only new servos, all at ID 0: not the unpowered line's "no servo answered ... check the power".
    _, url = sim_line([VirtualServo(0), VirtualServo(0)])
    result = cli("--port", url, "--timeout", "0.005", *command, "--seconds", "0.3")
    assert result.code == ExitCode.NO_REPLY, result.err
    assert "ID 0 at 115200 answered garbled" in result.err and "set-id" in result.err, result.err
    assert "power" not in result.err, result.err


def test_monitor_on_ics35_servos_without_free_refuses_as_its_help_says(cli: Any, sim_line: Any) -> None:
    # Its --help promised "current and temperature but no position" where it refuses (KRS servos are ICS 3.5).
    _, url = sim_line([1, 2])
    result = cli("--port", url, "monitor", "1-2", "--seconds", "0.3")
    assert result.code == ExitCode.REFUSED, result.err
    shown = " ".join(cli("monitor", "--help").out.split())
    assert "show current and temperature but no position" not in shown
    assert "With only ICS 3.5 servos and no --free, monitor refuses (exit 5)" in shown, shown


def test_monitor_on_ics35_servos_beside_an_absent_id_without_free_refuses_naming_both(cli: Any, sim_line: Any) -> None:
    # Servos 1 and 2 (ICS 3.5) left out, absent ID 3 the only one streamed: monitor ran its whole time on nothing,
    # then said "no servo among 1, 2, 3 answered" with power hints (exit 4), though 1 and 2 had answered.
    sim, url = sim_line([1, 2])
    result = cli("--port", url, "--timeout", "0.005", "monitor", "1-3", "--seconds", "0.3")
    assert result.code == ExitCode.REFUSED, result.err
    assert "1, 2 speak ICS 3.5" in result.err and "no answer from ID 3" in result.err, result.err
    assert "--free" in result.err and "power" not in result.err, result.err
    assert not [t for t in sim.log_since(0) if t.command in ("position", "free")]  # nothing that moves or frees


def test_monitor_json_lines(cli: Any, sim_line: Any) -> None:
    _, url = sim_line([1, 2])
    result = cli("--port", url, "--timeout", "0.005", "monitor", "--free", "--seconds", "0.3", "--json")
    assert result.code == 0
    docs = [json.loads(ln) for ln in result.out.splitlines()]
    assert docs[-1]["final"] is True
    assert set(docs[-1]["servos"]) == {"1", "2"}
    assert docs[-1]["servos"]["1"]["position"] == units.NEUTRAL
    assert docs[-1]["cycle"] > 0
    assert len(docs) == 1  # under a second: the final line only (one line per second)


@pytest.mark.realtime
def test_monitor_json_lines_come_once_a_second_each_with_a_measured_rate(cli: Any, sim_line: Any) -> None:
    _, url = sim_line([1, 2])
    result = cli("--port", url, "--timeout", "0.005", "monitor", "--free", "--seconds", "1.5", "--json")
    assert result.code == 0, result.err
    docs = [json.loads(ln) for ln in result.out.splitlines()]
    assert [d["final"] for d in docs] == [False] * (len(docs) - 1) + [True]
    # Never a first line at t=0 with no rate yet (how many lines a loaded machine fits in: not checked).
    assert docs[0]["t"] >= 1.0 and all(d["rate_hz"] > 0 for d in docs), docs


def test_monitor_plot_without_matplotlib(cli: Any, sim_line: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    sim, url = sim_line([1])
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # makes `import matplotlib` fail
    result = cli("--port", url, "monitor", "1", "--seconds", "0.2", "--plot", "x.png")
    assert result.code == ExitCode.USAGE
    assert install_command("plot", installed_from()) in result.err and "pip install matplotlib" in result.err
    assert sim.transactions == 0


def test_monitor_plot_writes_a_png(cli: Any, sim_line: Any, tmp_path: Path) -> None:
    pytest.importorskip("matplotlib")
    _, url = sim_line([1, 2])
    target = tmp_path / "trace.png"
    result = cli("--port", url, "monitor", "--free", "1,2", "--seconds", "0.3", "--plot", str(target))
    assert result.code == 0, result.err
    assert target.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_each_command_gets_a_fresh_unnamed_simulator(cli: Any) -> None:
    first = cli("--port", "sim://?ids=4", "scan", "--bauds", "115200", "--ids", "0-7", "--quick", "--json")
    second = cli("--port", "sim://?ids=6", "scan", "--bauds", "115200", "--ids", "0-7", "--quick", "--json")
    assert [s["id"] for s in first.json()["servos"]] == [4]
    assert [s["id"] for s in second.json()["servos"]] == [6]


# A command's line lost and reconnected (what `ics35 web` does on a robot's line), with its logging set up
# as every command sets it (argv[1]: the -v count); it reads its port from stdin once it has imported everything.
LOST_AND_BACK = """
import sys
from ics35_async import blocking
from ics35_async.cli._settings import setup_logging

setup_logging(int(sys.argv[1]))
print("ready", flush=True)
with blocking.open_bus(input(), reconnect=True) as bus, bus.stream([1, 2]) as stream:
    for frame in stream:
        if frame.resumed:
            break
"""


@pytest.mark.parametrize("verbose", [0, 1])
def test_a_port_lost_and_back_is_logged_by_a_command_only_at_v(pty_sim: Any, verbose: int) -> None:
    # The library warns of both (a plain program hears them): a command says what happened itself and keeps
    # its stderr to that unless -v asks for the log, where both appear.
    proc = subprocess.Popen(
        [sys.executable, "-c", LOST_AND_BACK, str(verbose)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().strip() == "ready"  # (the simulator's unplug counts from its start)
        path = pty_sim("--ids", "1-2", "--unplug-after", "1", "--replug-after", "0.3").path
        _, err = proc.communicate(f"{path}\n", timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    if not verbose:
        assert err == "", err
    else:
        assert f"WARNING ics35_async: port {path} lost" in err, err
        assert f"WARNING ics35_async: port {path} back: reconnected" in err, err
