"""`eeprom restore` and baud rates: an old backup restored keeping each servo's new rate (--keep-baud), and a
folder of backups whose servos answer at different rates, each restored at its own; on named simulators whose
servos at another rate stay silent, as on a real wire."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ics35_async.cli import ExitCode
from ics35_async.eeprom import BaudRate
from ics35_async.sim import VirtualServo
from tests.test_cli_backup_checks import PullsThePlug

FAST = BaudRate.B1250000


def move_to_rate(sim: Any, servo_id: int, baud: int) -> None:
    """What `ics35 eeprom set ID baud_rate=...` and a power-cycle leave: the servo talks only at ``baud``."""
    servo = sim.servo(servo_id)
    servo.eeprom = servo.eeprom.replace(baud_rate=baud)
    servo.power_cycle()


def backed_up(cli: Any, sim: Any, url: str, ids: tuple[int, ...], folder: Path) -> None:
    """Back up ``ids`` (at 115200) into ``folder``, then change each one's speed, so a restore has work."""
    result = cli("--port", url, "eeprom", "dump", ",".join(map(str, ids)), "-o", f"{folder}/")
    assert result.code == 0, result.err
    for i in ids:
        sim.servo(i).eeprom = sim.servo(i).eeprom.replace(speed=9)


def writes(sim: Any) -> list[int]:
    return [servo.eeprom_writes for servo in sim.servos]


# --------------------------------------------------------------------------- --keep-baud


def test_an_old_backup_is_restored_keeping_the_servos_new_rate(cli: Any, sim_line: Any, tmp_path: Path) -> None:
    sim, url = sim_line([1, 2])
    backed_up(cli, sim, url, (1, 2), tmp_path)
    for i in (1, 2):
        move_to_rate(sim, i, FAST)
    fast = ("--port", url, "--baud", str(int(FAST)))
    refused = cli(*fast, "eeprom", "restore", str(tmp_path), "--yes")
    assert refused.code == ExitCode.REFUSED
    assert "--keep-baud" in refused.err and "--change-baud" in refused.err
    said = " ".join(refused.err.split())
    assert "servo 1" in said and "servo 2" in said, said  # every servo the restore would move, not the first
    assert writes(sim) == [0, 0]

    both = cli(*fast, "eeprom", "restore", str(tmp_path), "--keep-baud", "--change-baud", "--yes")
    assert both.code == ExitCode.USAGE and writes(sim) == [0, 0]

    result = cli(*fast, "eeprom", "restore", str(tmp_path), "--keep-baud", "--yes", "--json")
    assert result.code == 0, result.err
    for report in result.json()["servos"]:
        assert report["outcome"] == "verified" and "baud_rate" not in report["changes"]
    for i in (1, 2):
        servo = sim.servo(i)
        assert servo.eeprom.speed == 127 and servo.eeprom.baud_rate == FAST
        servo.power_cycle()
        assert servo.answers(int(FAST))  # still at its new rate after the next power-up


def test_keep_baud_restores_one_file_too(cli: Any, sim_line: Any, tmp_path: Path) -> None:
    sim, url = sim_line([1])
    backed_up(cli, sim, url, (1,), tmp_path)
    move_to_rate(sim, 1, FAST)
    fast = ("--port", url, "--baud", str(int(FAST)))
    refused = cli(*fast, "eeprom", "restore", str(tmp_path / "servo-01.json"), "--yes")
    assert refused.code == ExitCode.REFUSED and "--keep-baud" in refused.err
    result = cli(*fast, "eeprom", "restore", str(tmp_path / "servo-01.json"), "--keep-baud", "--yes")
    assert result.code == 0, result.err
    assert sim.servo(1).eeprom.speed == 127 and sim.servo(1).eeprom.baud_rate == FAST


# --------------------------------------------------------------------------- a folder at two rates


def test_a_folder_at_two_rates_is_restored_each_servo_at_its_own(cli: Any, sim_line: Any, tmp_path: Path) -> None:
    sim, url = sim_line([1, 2, 3])
    backed_up(cli, sim, url, (1, 2, 3), tmp_path)
    move_to_rate(sim, 2, FAST)
    for baud in (BaudRate.B115200, FAST):  # whichever rate the command is given
        line = ("--port", url, "--baud", str(int(baud)))
        # The backup would move servo 2 back to 115200: refused, naming both ways on; nothing written anywhere.
        refused = cli(*line, "eeprom", "restore", str(tmp_path), "--yes")
        assert refused.code == ExitCode.REFUSED, refused.err
        assert "servo 2" in refused.err and "--keep-baud" in refused.err
        assert writes(sim) == [0, 0, 0]
        declined = cli(*line, "eeprom", "restore", str(tmp_path), "--keep-baud", stdin="n\n")
        assert declined.code == ExitCode.REFUSED and declined.err.count("[y/N]") == 1
        assert writes(sim) == [0, 0, 0]
        # Every diff shown before the one question names the rate the servo answers at.
        said = declined.out + declined.err
        assert "answers at 1250000 baud" in said or "the line's rate is 1250000" in said, said

    result = cli("--port", url, "eeprom", "restore", str(tmp_path), "--keep-baud", "--yes", "--json")
    assert result.code == 0, result.err
    reports = {r["id"]: r for r in result.json()["servos"]}
    assert {i: (r["outcome"], r["baud"]) for i, r in reports.items()} == {
        1: ("verified", 115200),
        2: ("verified", int(FAST)),
        3: ("verified", 115200),
    }
    assert [sim.servo(i).eeprom.speed for i in (1, 2, 3)] == [127, 127, 127]
    assert sim.servo(2).eeprom.baud_rate == FAST and sim.servo(1).eeprom.baud_rate == BaudRate.B115200


def test_a_folder_at_two_rates_with_change_baud_brings_each_to_its_backups_rate(
    cli: Any, sim_line: Any, tmp_path: Path
) -> None:
    sim, url = sim_line([1, 2])
    backed_up(cli, sim, url, (1, 2), tmp_path)
    move_to_rate(sim, 2, FAST)
    result = cli("--port", url, "eeprom", "restore", str(tmp_path), "--change-baud", "--yes", "--json")
    assert result.code == 0, result.err
    reports = {r["id"]: r for r in result.json()["servos"]}
    assert reports[2]["changes"]["baud_rate"] == [int(FAST), 115200] and reports[2]["verified"]
    sim.power_cycle()
    assert [sim.servo(i).answers(115200) for i in (1, 2)] == [True, True]


def test_an_id_answering_at_two_rates_is_refused_before_anything_is_written(
    cli: Any, sim_line: Any, tmp_path: Path
) -> None:
    sim, url = sim_line([1, 2])
    backed_up(cli, sim, url, (1, 2), tmp_path)
    move_to_rate(sim, 1, FAST)  # servo 1 is at 1,250,000 and another servo 2 joins there: ID 2 at both rates
    sim.add_device(VirtualServo(2, baud_rate=FAST))
    result = cli("--port", url, "eeprom", "restore", str(tmp_path), "--keep-baud", "--yes")
    assert result.code == ExitCode.REFUSED, result.err
    assert "ID 2 answers at 115,200 and 1,250,000 baud" in " ".join(result.err.split())
    assert writes(sim) == [0, 0, 0]


def test_a_servo_that_answers_at_no_rate_stops_the_restore_before_any_write(
    cli: Any, sim_line: Any, tmp_path: Path
) -> None:
    sim, url = sim_line([1, 2, 3])
    backed_up(cli, sim, url, (1, 2, 3), tmp_path)
    sim, url = sim_line([1, 2])  # the backups of three servos, restored where servo 3 is not
    for i in (1, 2):
        sim.servo(i).eeprom = sim.servo(i).eeprom.replace(speed=9)
    move_to_rate(sim, 2, FAST)
    result = cli("--port", url, "--timeout", "0.02", "eeprom", "restore", str(tmp_path), "--keep-baud", "--yes")
    assert result.code == ExitCode.NO_REPLY, result.err
    assert "servo 3 did not answer" in result.err and "nothing was written" in result.err
    assert writes(sim) == [0, 0]


def test_a_line_lost_at_the_second_rate_says_what_each_servo_holds(cli: Any, sim_line: Any, tmp_path: Path) -> None:
    plug = PullsThePlug(2, "write")  # at 1,250,000: the adapter is pulled out as its write goes
    sim, url = sim_line([VirtualServo(1), plug, VirtualServo(3)])
    backed_up(cli, sim, url, (1, 2, 3), tmp_path)
    move_to_rate(sim, 2, FAST)
    plug.line = sim
    result = cli("--port", url, "--timeout", "0.05", "eeprom", "restore", str(tmp_path), "--keep-baud", "--yes")
    assert result.code == ExitCode.COMMUNICATION, result.err
    out = " ".join(result.out.split())
    assert "servo 1: 1 EEPROM field(s) written and verified" in out
    assert "servo 3: 1 EEPROM field(s) written and verified" in out
    assert "servo 2: unknown: the command stopped while the write was on its way" in out
    # The command that tells which image servo 2 holds reaches it at its own rate, not the line's.
    assert f"see which with: ics35 --port {url} --baud 1250000 --timeout 0.05 eeprom dump 2 --table" in out
    err = " ".join(result.err.split())
    assert f"run it again: ics35 --port {url} --timeout 0.05 eeprom restore {tmp_path} --keep-baud" in err
    # What the report says is what the servos hold.
    assert [servo.eeprom.speed for servo in sim.servos] == [127, 127, 127]
    assert writes(sim) == [1, 1, 1]


def test_a_folder_on_a_line_without_echo_finds_servos_all_at_another_rate(
    cli: Any, sim_line: Any, tmp_path: Path
) -> None:
    """Without the echo nothing at all comes back when no servo is at --baud: the other rates are looked at."""
    sim, url = sim_line([1, 2], echo=False)
    line = ("--port", url, "--no-echo")
    assert cli(*line, "eeprom", "dump", "1,2", "-o", f"{tmp_path}/").code == 0
    for i in (1, 2):
        sim.servo(i).eeprom = sim.servo(i).eeprom.replace(speed=9)
        move_to_rate(sim, i, FAST)
    result = cli(*line, "eeprom", "restore", str(tmp_path), "--keep-baud", "--yes", "--json")
    assert result.code == 0, result.err
    assert {r["id"]: (r["outcome"], r["baud"]) for r in result.json()["servos"]} == {
        1: ("verified", int(FAST)),
        2: ("verified", int(FAST)),
    }
    assert [servo.eeprom.speed for servo in sim.servos] == [127, 127]
