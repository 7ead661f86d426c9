"""`ics35 scan`, `set-id` and `eeprom`: the new user's findings (issue 14), in-process, on named simulators."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from ics35_async.cli import ExitCode
from ics35_async.eeprom import BaudRate, Eeprom, Flags
from ics35_async.policies.eeprom_backup import backup_document, backups_document
from ics35_async.protocol import ReadEeprom, ReadParam
from ics35_async.sim import VirtualServo
from ics35_async.sim.virtual_servo import NO_REPLY
from tests.support.cli_runs import edit_backup
from tests.support.sim_servos import UnplugsWhenAsked


def with_flags(servo: VirtualServo, flags: int) -> VirtualServo:
    """Give ``servo`` an EEPROM flags byte as a real servo reports it (read-only bits included)."""
    raw = bytearray(servo.eeprom.to_bytes())
    raw[14], raw[15] = flags >> 4, flags & 0x0F
    servo.eeprom = Eeprom.from_bytes(bytes(raw))
    return servo


class IdAtPowerUp(VirtualServo):
    """A servo that takes a new EEPROM ID only at its next power-up (the reference leaves this open)."""

    def __init__(self, servo_id: int, **options: Any) -> None:
        self._live_id = servo_id
        super().__init__(servo_id, **options)

    @property
    def servo_id(self) -> int:
        return self._live_id


class LossyAt115200(VirtualServo):
    """A 115200 servo on a line that passes every rate, whose replies at 115200 are lost."""

    def answers(self, baudrate: int) -> bool:
        return baudrate != 115200


# --------------------------------------------------------------------------- finding 4: flags


def test_flags_plus_and_minus_keep_the_other_flags(cli: Any, sim_line: Any) -> None:
    sim, url = sim_line([with_flags(VirtualServo(1), Flags.PWMINH)])
    result = cli("--port", url, "eeprom", "set", "1", "flags+=REVERSE", "--yes")
    assert result.code == 0, result.err
    assert sim.servo(1).eeprom.flags == Flags.PWMINH | Flags.REVERSE
    result = cli("--port", url, "eeprom", "set", "1", "flags-=REVERSE", "flags+=ROTATION", "--yes")
    assert result.code == 0, result.err
    assert sim.servo(1).eeprom.flags == Flags.PWMINH | Flags.ROTATION


def test_a_flag_change_keeps_the_unused_bits_the_servo_has(cli: Any, sim_line: Any) -> None:
    sim, url = sim_line([with_flags(VirtualServo(1), Flags.PWMINH | 0x60)])
    result = cli("--port", url, "eeprom", "set", "1", "flags+=REVERSE", "--yes")
    assert result.code == 0, result.err
    assert int(sim.servo(1).eeprom.flags) == 0x60 | Flags.PWMINH | Flags.REVERSE
    result = cli("--port", url, "eeprom", "set", "1", "flags-=PWMINH", "speed=90", "--yes")
    assert result.code == 0, result.err
    assert int(sim.servo(1).eeprom.flags) == 0x60 | Flags.REVERSE and sim.servo(1).eeprom.speed == 90
    assert cli("--port", url, "eeprom", "set", "1", "flags=ROTATION", "--yes").code == 0
    assert int(sim.servo(1).eeprom.flags) == 0x60 | Flags.ROTATION
    assert cli("--port", url, "eeprom", "set", "1", "flags-=0x60", "--yes").code == 0
    assert sim.servo(1).eeprom.flags == Flags.ROTATION


def test_eeprom_set_says_a_ram_value_takes_the_change_at_power_up_and_how_to_use_it_now(
    cli: Any, sim_line: Any
) -> None:
    # The servo loads stretch, speed and its limits from the EEPROM into RAM at power-up: `get` still read the
    # old speed after a write that said only "written and verified".
    sim, url = sim_line([1])
    result = cli("--port", url, "eeprom", "set", "1", "speed=50", "stretch=80", "punch=3", "--yes")
    assert result.code == 0, result.err
    note = [line for line in result.out.splitlines() if "power-up" in line]
    assert len(note) == 1, result.out
    assert "stretch_gain, speed: loaded into RAM at the servo's next power-up" in note[0]
    assert f"ics35 --port {url} set 1 stretch 40" in note[0] and f"ics35 --port {url} set 1 speed 50" in note[0]
    assert "punch" not in note[0]
    assert sim.servo(1).eeprom.speed == 50
    assert "speed = 127" in cli("--port", url, "get", "1", "speed").out  # RAM: until the next power-up
    assert cli("--port", url, "set", "1", "speed", "50").code == 0  # what the note says to run
    assert "speed = 50" in cli("--port", url, "get", "1", "speed").out
    result = cli("--port", url, "eeprom", "set", "1", "punch=4", "current_limit=40", "--yes")
    assert "current_limit: loaded into RAM" in result.out and "set 1 current-limit 40" in result.out, result.out
    assert "power-up" not in cli("--port", url, "eeprom", "set", "1", "punch=5", "--yes").out


def test_flags_replacement_names_every_flag_it_clears_before_asking(cli: Any, sim_line: Any) -> None:
    sim, url = sim_line([with_flags(VirtualServo(1), Flags.PWMINH | Flags.ROTATION)])
    result = cli("--port", url, "eeprom", "set", "1", "flags=REVERSE", stdin="n\n")
    assert result.code == ExitCode.REFUSED
    cleared = [row for row in result.out.splitlines() if "flags CLEARED" in row]
    assert len(cleared) == 1 and "PWMINH|ROTATION" in cleared[0]
    assert "clears flag(s) PWMINH|ROTATION" in result.err
    assert result.err.index("clears flag(s)") < result.err.index("Write these")
    assert sim.servo(1).eeprom_writes == 0


def test_a_flag_cleared_by_name_is_not_met_with_advice_to_clear_it_by_name(cli: Any, sim_line: Any) -> None:
    # flags-=REVERSE warned "this clears flag(s) REVERSE; to change one flag and keep the others use flags+=NAME /
    # flags-=NAME": the very thing typed.  PWMINH's own risk (PWM mode after a brown-out) is still said.
    sim, url = sim_line([with_flags(VirtualServo(1), Flags.PWMINH | Flags.REVERSE | Flags.ROTATION)])
    result = cli("--port", url, "eeprom", "set", "1", "flags-=REVERSE", "--yes")
    assert result.code == 0, result.err
    assert sim.servo(1).eeprom.flags == Flags.PWMINH | Flags.ROTATION
    assert "flags CLEARED" in result.out  # the diff still names it
    assert "warning" not in result.err and "flags-=NAME" not in result.err, result.err
    result = cli("--port", url, "eeprom", "set", "1", "flags-=PWMINH", "--yes")
    assert result.code == 0, result.err
    assert "clears flag(s) PWMINH (without PWMINH a servo may start in PWM mode" in result.err, result.err
    assert "flags-=NAME" not in result.err, result.err
    result = cli("--port", url, "eeprom", "set", "1", "flags=REVERSE", "--yes")
    assert result.code == 0, result.err
    assert sim.servo(1).eeprom.flags == Flags.REVERSE
    assert "clears flag(s) ROTATION; to change one flag and keep the others use flags+=NAME" in result.err, result.err


@pytest.mark.parametrize("assignment", ["flags=FREE", "flags+=PCM", "flags-=FREE", "flags=PWMINH,PCM", "flags=0x0A"])
def test_read_only_flag_names_are_refused_before_the_wire(cli: Any, sim_line: Any, assignment: str) -> None:
    sim, url = sim_line([1])
    result = cli("--port", url, "eeprom", "set", "1", assignment, "--yes")
    assert result.code == ExitCode.USAGE
    assert "read-only" in result.err
    assert sim.transactions == 0


def test_only_flags_take_plus_and_minus(cli: Any, sim_line: Any) -> None:
    sim, url = sim_line([1])
    result = cli("--port", url, "eeprom", "set", "1", "speed+=5", "--yes")
    assert result.code == ExitCode.USAGE and "only flags" in result.err
    assert sim.transactions == 0


def test_the_servos_read_only_flags_survive_a_replacement(cli: Any, sim_line: Any) -> None:
    sim, url = sim_line([with_flags(VirtualServo(1), Flags.PWMINH | Flags.FREE)])
    assert cli("--port", url, "eeprom", "set", "1", "flags=REVERSE,PWMINH", "--yes").code == 0
    assert sim.servo(1).eeprom.flags == Flags.REVERSE | Flags.PWMINH | Flags.FREE


# --------------------------------------------------------------------------- finding 6: one listing per servo


def test_scan_lists_each_servo_once_on_a_line_that_ignores_rates(cli: Any, sim_line: Any) -> None:
    _, url = sim_line([1, 2], follow_host_baud=False)
    for quick in ([], ["--quick"]):
        result = cli("--port", url, "scan", "--ids", "0-3", "--timeout", "0.005", "--json", *quick)
        assert result.code == 0, result.err
        servos = result.json()["servos"]
        assert [(s["id"], s["baud"]) for s in servos] == [(1, 115200), (2, 115200)]
        assert all(s["answered_at"] == [115200, 625000, 1250000] for s in servos)
    text = cli("--port", url, "scan", "--ids", "0-3", "--timeout", "0.005")
    assert "2 servo(s) found" in text.out and "does not enforce rates" in text.err


class EepromUnreadable(VirtualServo):
    """A servo that answers probes but whose EEPROM reads never come back (a reply too long for a bad line)."""

    def handle(self, command: Any) -> Any:
        return NO_REPLY if isinstance(command, ReadEeprom) else super().handle(command)


def test_scan_says_a_rate_is_unconfirmed_when_the_eeprom_cannot_be_read(cli: Any, sim_line: Any) -> None:
    sim, url = sim_line([VirtualServo(1), EepromUnreadable(2)], follow_host_baud=False)
    result = cli("--port", url, "scan", "--ids", "0-3", "--timeout", "0.005", "--json")
    assert result.code == 0, result.err
    servos = {s["id"]: s for s in result.json()["servos"]}
    assert sorted(servos) == [1, 2]  # servo 2 once, though it answered at three rates and was never read
    assert servos[1]["rate_confirmed"] and servos[1]["baud"] == 115200
    assert not servos[2]["rate_confirmed"] and servos[2]["eeprom"] is None
    assert servos[2]["answered_at"] == [115200, 625000, 1250000]
    reads = [t for t in sim.log if t.command == "read_eeprom" and t.servo_id == 2]
    assert len(reads) >= 3  # retried before giving up
    text = cli("--port", url, "scan", "--ids", "0-3", "--timeout", "0.005")
    assert "rate unconfirmed" in " ".join(text.out.split()) and " 115200? " in text.out
    assert "servo 2: its EEPROM could not be read (after retries), so its rate is unconfirmed" in " ".join(
        text.err.split()
    )


def test_the_command_that_reads_an_unconfirmed_servo_again_reaches_the_same_line(cli: Any, sim_line: Any) -> None:
    """The hint's command carries the scan's line options (here --timeout and --no-echo, without which it
    would not hear that line), with the servo's own rate instead of the scan's --baud."""
    _, url = sim_line([VirtualServo(1), EepromUnreadable(2)], follow_host_baud=False, echo=False)
    text = cli("--port", url, "--no-echo", "--timeout", "0.005", "--baud", "625000", "scan", "--ids", "0-3")
    assert text.code == 0, text.err
    said = " ".join(text.err.split())
    expected = f"read it again with: ics35 --port {url} --timeout 0.005 --no-echo --baud 115200 eeprom dump 2 --table"
    assert expected in said, said


@pytest.mark.parametrize(("allowance", "carried"), [("0.1", " --timeout 0.1"), ("0.005", "")])
def test_the_scans_own_longer_allowance_goes_into_the_commands_it_names(
    cli: Any, sim_line: Any, allowance: str, carried: str
) -> None:
    """A scan given a longer --timeout than the line's (a slow link) names commands with it, or they would not
    hear what the scan heard; a shorter one (a quick scan) leaves the line's own allowance to them."""
    _, url = sim_line([VirtualServo(1), EepromUnreadable(2)], follow_host_baud=False)
    text = cli("--port", url, "scan", "--ids", "0-3", "--timeout", allowance)
    assert text.code == 0, text.err
    said = " ".join(text.err.split())
    expected = f"read it again with: ics35 --port {url}{carried} --baud 115200 eeprom dump 2 --table"
    assert expected in said, said


@pytest.mark.parametrize("level", [0.15, 0.30])
@pytest.mark.slow
def test_scan_on_a_noisy_line_lists_each_servo_once_at_its_own_rate(cli: Any, sim_line: Any, level: float) -> None:
    each = level / 4
    for seed in range(6):
        faults = f"drop:{each},truncate:{each},corrupt:{each},late:{each}"
        _, url = sim_line([1, 2, 5], follow_host_baud=False, faults=faults, seed=seed)
        result = cli("--port", url, "scan", "--ids", "0-7", "--timeout", "0.005", "--json")
        assert result.code == 0, result.err
        listed = [(s["id"], s["baud"], s["rate_confirmed"]) for s in result.json()["servos"]]
        ids = [i for i, _, _ in listed]
        assert len(ids) == len(set(ids)), (seed, listed)
        assert all(baud == 115200 for _, baud, confirmed in listed if confirmed), (seed, listed)
        if level == 0.15:
            assert listed == [(1, 115200, True), (2, 115200, True), (5, 115200, True)], (seed, listed)


def test_no_advice_of_a_rate_the_eeprom_contradicts(cli: Any, sim_line: Any) -> None:
    _, url = sim_line([LossyAt115200(1)])
    result = cli("--port", url, "--timeout", "0.005", "get", "1", "speed")
    assert result.code == ExitCode.NO_REPLY
    # (the rates asked are named, "nor at 625000 or 1250000 baud"; none is advised)
    assert "--baud" not in result.err and "at 625000 baud" not in result.err.replace("nor at 625000", ""), result.err
    # A servo really at another rate still gets the advice.
    _, url = sim_line([VirtualServo(2, baud_rate=1250000)])
    result = cli("--port", url, "--timeout", "0.005", "get", "2", "speed")
    assert result.code == ExitCode.WRONG_BAUD and "--baud 1250000" in result.err


def test_a_rate_the_search_could_not_ask_is_not_named_as_one_the_servo_did_not_answer_at(
    cli: Any, sim_line: Any
) -> None:
    # The port lost as servo 5 was asked at 625000 (it answers there, its answer never back): the error said
    # "nor at 625000 baud", as if it had been asked there and stayed silent, and nothing of 1250000, never asked.
    puller = UnplugsWhenAsked(5, ReadParam, baud_rate=625000)
    sim, url = sim_line([puller])
    puller.line = sim
    result = cli("--port", url, "--timeout", "0.005", "get", "5", "speed")
    assert result.code == ExitCode.NO_REPLY, result.err
    said = " ".join(result.err.split())
    assert "nor at" not in said, said
    assert (
        "servo 5 did not answer on " in said and "at 115200 baud (625000 and 1250000 baud could not be tried)" in said
    )


# --------------------------------------------------------------------------- finding 7: ID change


def test_an_eeprom_id_change_reports_which_id_answers(cli: Any, sim_line: Any) -> None:
    sim, url = sim_line([IdAtPowerUp(20)])
    result = cli("--port", url, "eeprom", "set", "20", "id=21", "--yes")
    assert result.code == 0, result.err
    assert "still answers as ID 20" in result.out and "next power-up" in result.out
    assert sim.servos[0].eeprom.servo_id == 21

    sim, url = sim_line([VirtualServo(20)])
    result = cli("--port", url, "eeprom", "set", "20", "id=21", "--yes", "--json")
    assert result.code == 0, result.err
    assert result.json()["answers_as"] == [21] and result.json()["verified"] is True


# --------------------------------------------------------------------------- finding 11: the echo setting


def test_no_echo_scan_says_drop_no_echo_like_get(cli: Any, sim_line: Any) -> None:
    _, url = sim_line([1, 2])
    get = cli("--port", url, "--timeout", "0.005", "--no-echo", "get", "1", "speed")
    scan = cli("--port", url, "--timeout", "0.005", "--no-echo", "scan")
    set_id = cli("--port", url, "--timeout", "0.005", "--no-echo", "set-id", "4", "--yes")
    for result in (get, scan, set_id):
        assert result.code == ExitCode.COMMUNICATION
        assert "drop --no-echo" in result.err and "power" not in result.err


def test_a_missing_echo_is_named_by_scan(cli: Any, sim_line: Any) -> None:
    _, url = sim_line([1], echo=False)
    result = cli("--port", url, "--timeout", "0.005", "scan", "--bauds", "115200")
    assert result.code == ExitCode.COMMUNICATION and "pass --no-echo" in result.err


# --------------------------------------------------------------------------- finding 12: bulk backup


def test_bulk_dump_and_restore_each_servo_to_its_own_id(cli: Any, sim_line: Any, tmp_path: Path) -> None:
    sim, url = sim_line([1, 2, 3])
    for i in (1, 2, 3):
        sim.servo(i).eeprom = sim.servo(i).eeprom.replace(speed=10 * i, punch=i)
    backup = tmp_path / "backup"
    result = cli("--port", url, "eeprom", "dump", "1-3", "-o", f"{backup}/")
    assert result.code == 0, result.err
    assert sorted(p.name for p in backup.iterdir()) == ["servo-01.json", "servo-02.json", "servo-03.json"]
    assert json.loads((backup / "servo-02.json").read_text())["fields"]["speed"] == 20

    for i in (1, 2, 3):
        sim.servo(i).eeprom = sim.servo(i).eeprom.replace(speed=99, flags=Flags.PWMINH)
    result = cli("--port", url, "eeprom", "restore", str(backup), stdin="n\n")
    assert result.code == ExitCode.REFUSED
    assert all(sim.servo(i).eeprom_writes == 0 for i in (1, 2, 3))
    assert result.err.count("[y/N]") == 1

    result = cli("--port", url, "eeprom", "restore", str(backup), stdin="y\n")
    assert result.code == 0, result.err
    assert result.err.count("[y/N]") == 1
    for i in (1, 2, 3):
        image = sim.servo(i).eeprom
        assert (image.speed, image.punch, image.flags, image.servo_id) == (10 * i, i, Flags(0), i)
        assert sim.servo(i).calibration_intact


def test_a_scan_of_some_ids_that_finds_none_names_them_and_points_at_the_others(cli: Any) -> None:
    # `scan --ids 20-31` on a line of servos 1-6: "no servo answered on ... at 115200, 625000, 1250000 baud" with the
    # hint "ics35 scan tries every ID at every baud rate", given to a scan that had been told to try fewer.
    result = cli("--port", "sim://?ids=1-6", "--timeout", "0.02", "scan", "--ids", "20-31", "--bauds", "115200")
    assert result.code == ExitCode.NO_REPLY, result.err
    said = " ".join(result.err.split())
    # (and that other servos answer: the line, its rate and its power are right, the IDs asked are not, as doctor
    # says it; the power hints were given)
    assert "no servo among 20-31 answered on sim://?ids=1-6 at 115200 baud, but servos at other IDs answer" in said
    assert "scan lists the IDs on the line; pass those to --ids" in said and "6-12 V" not in said, said
    assert "tries every ID at every baud rate" not in said, said


def test_a_scan_of_some_ids_on_a_line_of_one_servo_names_the_id_it_answers_at(cli: Any) -> None:
    result = cli("--port", "sim://?ids=2", "--timeout", "0.02", "scan", "--ids", "20-25")
    assert result.code == ExitCode.NO_REPLY, result.err
    said = " ".join(result.err.split())
    where = "sim://?ids=2 at 115200, 625000, 1250000 baud"
    assert f"no servo among 20-25 answered on {where}, but a servo at ID 2 does at 115200 baud" in said, said
    assert "scan --ids 2" in said and "6-12 V" not in said, said
    data = cli("--port", "sim://?ids=2", "--timeout", "0.02", "scan", "--ids", "20-25", "--bauds", "115200", "--json")
    assert data.code == ExitCode.NO_REPLY and data.json()["answered_elsewhere"] == [{"baud": 115200, "id": 2}]
    assert data.json()["servos"] == [] and data.json()["id_read_only"] == []


def test_a_scan_of_some_ids_on_a_line_where_nothing_answers_gives_the_power_hints(cli: Any) -> None:
    result = cli("--port", "sim://?ids=none", "--timeout", "0.02", "scan", "--ids", "20-25", "--bauds", "115200")
    assert result.code == ExitCode.NO_REPLY, result.err
    said = " ".join(result.err.split())
    assert "no servo among 20-25 answered" in said and "another ID" not in said and "6-12 V" in said, said
    assert "without --ids" in said, said


def test_bulk_dump_saves_the_servos_that_answer(cli: Any, sim_line: Any, tmp_path: Path) -> None:
    _, url = sim_line([2, 5])
    result = cli("--port", url, "--timeout", "0.005", "eeprom", "dump", "all", "-o", str(tmp_path) + "/")
    assert result.code == 0, result.err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["servo-02.json", "servo-05.json"]


@pytest.mark.parametrize("into", ["dir", "file"])
def test_a_dump_of_listed_ids_saves_those_that_answer_and_fails_naming_the_others(
    cli: Any, sim_line: Any, tmp_path: Path, into: str
) -> None:
    # `eeprom dump 1-9 -o backup/` with 7-9 unplugged said a warning and exited 0: a backup script could not tell a
    # robot backed up whole from one missing three servos.  IDs listed are servos expected (as `free 1-9` takes them):
    # the others are saved, and the dump fails naming the missing (exit 4); `all` saves whichever answer.
    _, url = sim_line([2, 5])
    target = tmp_path / "backup.json" if into == "file" else tmp_path / "backup"
    result = cli(
        "--port", url, "--timeout", "0.005", "eeprom", "dump", "2,5-7", "-o", f"{target}{'/' * (into == 'dir')}"
    )
    assert result.code == ExitCode.NO_REPLY, result.err
    err = " ".join(result.err.split())
    assert "error: no answer from ID(s) 6, 7 at 115200 baud: not saved" in err, err
    assert err.count("no answer from ID(s) 6, 7") == 1 and "servo(s) 2, 5 saved" in err, err
    assert "all" in err and "scan" in err, err
    if into == "dir":
        assert sorted(p.name for p in target.iterdir()) == ["servo-02.json", "servo-05.json"]
    else:
        assert [s["servo_id"] for s in json.loads(target.read_text())["servos"]] == [2, 5]


def test_bulk_restore_checks_every_file_before_writing_any(cli: Any, sim_line: Any, tmp_path: Path) -> None:
    sim, url = sim_line([1, 2])
    assert cli("--port", url, "eeprom", "dump", "1,2", "-o", f"{tmp_path}/").code == 0
    edit_backup(tmp_path / "servo-02.json", speed=200)  # out of the reference's 1..127, as a hand edit may leave it
    before = sim.transactions
    result = cli("--port", url, "eeprom", "restore", str(tmp_path), "--yes")
    assert result.code == ExitCode.USAGE and "servo-02.json" in result.err
    assert sim.transactions == before

    edit_backup(tmp_path / "servo-02.json", speed=50, baud_rate=BaudRate.B1250000)
    result = cli("--port", url, "eeprom", "restore", str(tmp_path), "--yes")
    assert result.code == ExitCode.REFUSED and "--change-baud" in result.err
    assert sim.servo(1).eeprom_writes == sim.servo(2).eeprom_writes == 0


@pytest.mark.parametrize(("now", "new"), [(625000, 115200), (115200, 625000)])
def test_a_baud_change_says_what_later_commands_need(cli: Any, now: int, new: int) -> None:
    # Back to 115200, the warning said "every later command needs --baud 115200": the default, given by no --baud.
    url = f"sim://later-baud-{now}?ids=1&baud={now}"
    result = cli("--port", url, "--baud", str(now), "eeprom", "set", "1", f"baud={new}", "--change-baud", "--yes")
    said = " ".join(result.err.split())
    assert result.code == 0, said
    if new == 115200:
        assert "needs --baud" not in said and "115200 baud, the default (no --baud)" in said, said
        assert "--baud 115200" not in result.out and "115200 baud (the default: no --baud)" in result.out, result.out
    else:
        assert "every later command needs --baud 625000" in said, said


def test_several_servos_need_a_directory_or_one_file(cli: Any, sim_line: Any, tmp_path: Path) -> None:
    sim, url = sim_line([1, 2])
    result = cli("--port", url, "eeprom", "dump", "1-2")
    assert result.code == ExitCode.USAGE
    assert "-o DIR/ (one file per servo), -o FILE.json (one file of them all) or -o -" in " ".join(result.err.split())
    assert sim.transactions == 0


def test_several_servos_dumped_to_one_file_are_restored_from_it(cli: Any, sim_line: Any, tmp_path: Path) -> None:
    """``-o FILE.json`` for several servos writes the file of several servos' backups (what the configurator's
    Back up all downloads), the servos asked for that did not answer named in it; a restore reads it back."""
    sim, url = sim_line([1, 2, 3])
    for i in (1, 2, 3):
        sim.servo(i).eeprom = sim.servo(i).eeprom.replace(speed=10 * i)
    backup = tmp_path / "robot.json"
    result = cli("--port", url, "--timeout", "0.005", "eeprom", "dump", "1-4", "-o", str(backup))
    assert result.code == ExitCode.NO_REPLY, result.err  # (4 was asked for: the file says it is not in it)
    assert "EEPROMs of servos 1-3 saved to" in " ".join(result.err.split())
    doc = json.loads(backup.read_text())
    assert doc["format"] == "ics35-eeproms/1"
    assert [(s["servo_id"], s["fields"]["speed"]) for s in doc["servos"]] == [(1, 10), (2, 20), (3, 30)]
    assert [n["servo_id"] for n in doc["not_saved"]] == [4] and "no reply" in doc["not_saved"][0]["why"]
    for i in (1, 2, 3):
        sim.servo(i).eeprom = sim.servo(i).eeprom.replace(speed=99)
    result = cli("--port", url, "eeprom", "restore", str(backup), "--yes")
    assert result.code == 0, result.err
    assert [sim.servo(i).eeprom.speed for i in (1, 2, 3)] == [10, 20, 30]


def test_dump_to_dash_writes_to_stdout_as_restore_reads_dash_from_stdin(
    cli: Any, sim_line: Any, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # `-o -` wrote a file named "-" ("EEPROM of servo 1 saved to -"), and several servos' hint offered "-o -/ (one
    # file per servo) or -o -.json", where `eeprom restore -` reads stdin.
    monkeypatch.chdir(tmp_path)
    sim, url = sim_line([1, 2])
    for i in (1, 2):
        sim.servo(i).eeprom = sim.servo(i).eeprom.replace(speed=10 * i)
    one = cli("--port", url, "eeprom", "dump", "1", "-o", "-")
    assert one.code == 0 and json.loads(one.out)["servo_id"] == 1 and "saved to" not in one.err, one.err
    both = cli("--port", url, "eeprom", "dump", "1-2", "-o", "-")
    assert both.code == 0, both.err
    doc = json.loads(both.out)
    assert [(s["servo_id"], s["fields"]["speed"]) for s in doc["servos"]] == [(1, 10), (2, 20)]
    assert not list(tmp_path.iterdir())  # (no file named "-", nor "-.json")
    for i in (1, 2):
        sim.servo(i).eeprom = sim.servo(i).eeprom.replace(speed=99)
    restored = cli("--port", url, "eeprom", "restore", "-", "--yes", stdin=both.out)
    assert restored.code == 0, restored.err
    assert [sim.servo(i).eeprom.speed for i in (1, 2)] == [10, 20]
    several = cli("--port", url, "eeprom", "dump", "1-2")
    assert "-o - (them all on stdout)" in " ".join(several.err.split()), several.err


def test_dump_checks_its_output_before_reading(cli: Any, sim_line: Any, tmp_path: Path) -> None:
    sim, url = sim_line([1])
    result = cli("--port", url, "eeprom", "dump", "1", "-o", str(tmp_path / "missing" / "x.json"))
    assert result.code == ExitCode.USAGE and f"the directory {tmp_path / 'missing'} does not exist" in result.err
    assert sim.transactions == 0


def test_restore_one_file_to_the_servo_it_came_from(cli: Any, sim_line: Any, tmp_path: Path) -> None:
    sim, url = sim_line([1, 2])
    backup = tmp_path / "two.json"
    assert cli("--port", url, "eeprom", "dump", "2", "-o", str(backup)).code == 0
    sim.servo(2).eeprom = sim.servo(2).eeprom.replace(speed=3)
    result = cli("--port", url, "eeprom", "restore", str(backup), "--yes", "--json")
    assert result.code == 0, result.err
    assert result.json()["id"] == 2 and sim.servo(2).eeprom.speed == 127
    assert sim.servo(1).eeprom_writes == 0


def saved_together(sim: Any, ids: tuple[int, ...], path: Path, not_saved: dict[int, str] | None = None) -> Path:
    """Servos ``ids`` of ``sim`` backed up in one file at ``path``, as the configurator's Back up all saves them."""
    docs = [backup_document(sim.servo(i).eeprom, i, baud=115200, port="/dev/ttyUSB0") for i in ids]
    path.write_text(json.dumps(backups_document(docs, not_saved), indent=2) + "\n")
    return path


def test_restore_of_a_file_of_several_servos_restores_each_to_its_own_id(
    cli: Any, sim_line: Any, tmp_path: Path
) -> None:
    sim, url = sim_line([1, 2, 3])
    for i in (1, 2, 3):
        sim.servo(i).eeprom = sim.servo(i).eeprom.replace(speed=10 * i)
    backup = saved_together(sim, (1, 2, 3), tmp_path / "servos-01-05.json", {5: "no reply at 115,200 baud"})
    for i in (1, 2, 3):
        sim.servo(i).eeprom = sim.servo(i).eeprom.replace(speed=99)
    result = cli("--port", url, "eeprom", "restore", str(backup), "--yes", "--json")
    assert result.code == 0, result.err
    assert {s["id"]: s["outcome"] for s in result.json()["servos"]} == {1: "verified", 2: "verified", 3: "verified"}
    assert [(sim.servo(i).eeprom.speed, sim.servo(i).eeprom.servo_id) for i in (1, 2, 3)] == [(10, 1), (20, 2), (30, 3)]
    said = " ".join(result.err.split())
    assert f"note: {backup} holds no backup of servo 5 (when it was saved: no reply at 115,200 baud)" in said, said


def test_restore_of_one_servo_from_a_file_of_several_takes_that_servos_backup(
    cli: Any, sim_line: Any, tmp_path: Path
) -> None:
    sim, url = sim_line([1, 2, 3])
    sim.servo(2).eeprom = sim.servo(2).eeprom.replace(speed=20)
    backup = saved_together(sim, (1, 2, 3), tmp_path / "servos.json", {4: "no reply at 115,200 baud"})
    sim.servo(2).eeprom = sim.servo(2).eeprom.replace(speed=99)
    result = cli("--port", url, "eeprom", "restore", "2", str(backup), "--yes", "--json")
    assert result.code == 0, result.err
    assert result.json()["id"] == 2 and sim.servo(2).eeprom.speed == 20
    assert sim.servo(1).eeprom_writes == sim.servo(3).eeprom_writes == 0
    before = sim.transactions
    for target, why in (("5", ""), ("4", " (when it was saved, servo 4: no reply at 115,200 baud)")):
        refused = cli("--port", url, "eeprom", "restore", target, str(backup), "--yes")
        assert refused.code == ExitCode.USAGE, refused.err
        said = " ".join(refused.err.split())
        assert f"{backup}: the file holds the backups of servos 1-3, none of servo {target}{why}" in said, said
    assert sim.transactions == before


def test_a_directory_holding_two_backups_of_one_servo_in_a_file_of_several_is_refused(
    cli: Any, sim_line: Any, tmp_path: Path
) -> None:
    sim, url = sim_line([1, 2, 3])
    saved_together(sim, (1, 2, 3), tmp_path / "servos-01-03.json")
    assert cli("--port", url, "eeprom", "dump", "2", "-o", str(tmp_path / "servo-02.json")).code == 0
    before = sim.transactions
    refused = cli("--port", url, "eeprom", "restore", str(tmp_path), "--yes")
    assert refused.code == ExitCode.USAGE, refused.err
    said = " ".join(refused.err.split())
    assert "are both backups of servo 2" in said and "servos-01-03.json" in said, said
    assert sim.transactions == before


def test_restore_says_which_read_only_flags_the_servo_keeps(cli: Any, sim_line: Any, tmp_path: Path) -> None:
    sim, url = sim_line([with_flags(VirtualServo(1), Flags.FREE | Flags.PWMINH), VirtualServo(2)])
    backup = tmp_path / "one.json"
    assert cli("--port", url, "eeprom", "dump", "1", "-o", str(backup)).code == 0
    result = cli("--port", url, "eeprom", "restore", "2", str(backup), "--yes")
    assert result.code == 0, result.err
    assert sim.servo(2).eeprom.flags == Flags.PWMINH  # FREE reports servo 2's own state: not written
    assert "note: servo 2 keeps its read-only flag(s) as it reports them (FREE off)" in result.err, result.err
    result = cli("--port", url, "eeprom", "restore", "2", str(backup), "--yes", "--json")
    assert result.code == 0 and result.json()["kept_read_only"] == ["FREE"], result.err
    result = cli("--port", url, "eeprom", "restore", str(backup), "--yes")  # onto its own servo: nothing to say
    assert result.code == 0 and "read-only" not in result.err, result.err


def test_restore_with_change_baud_verifies_at_both_rates(cli: Any, sim_line: Any, tmp_path: Path) -> None:
    sim, url = sim_line([1])
    backup = tmp_path / "one.json"
    assert cli("--port", url, "eeprom", "dump", "1", "-o", str(backup)).code == 0
    edit_backup(backup, baud_rate=BaudRate.B625000)
    result = cli("--port", url, "eeprom", "restore", "1", str(backup), "--change-baud", "--yes", "--json")
    assert result.code == 0, result.err
    assert result.json()["answers_at_new_rate"] is False  # the simulated servo switches at power-up
    assert sim.servo(1).eeprom.baud_rate == BaudRate.B625000


def test_a_dump_over_an_earlier_backup_keeps_it_as_bak(cli: Any, sim_line: Any, tmp_path: Path) -> None:
    # A second dump to the same file (after the servo was changed) overwrote the first backup, the one
    # a user restores to: the earlier file is kept as NAME.bak, and said so.
    sim, url = sim_line([1, 2])
    one, folder = tmp_path / "one.json", tmp_path / "all"
    assert cli("--port", url, "eeprom", "dump", "1", "-o", str(one)).code == 0
    assert cli("--port", url, "eeprom", "dump", "1-2", "-o", f"{folder}/").code == 0
    sim.servo(1).eeprom = sim.servo(1).eeprom.replace(speed=3)
    result = cli("--port", url, "eeprom", "dump", "1", "-o", str(one))
    assert result.code == 0, result.err
    assert "one.json.bak" in result.err
    assert json.loads(one.read_text())["fields"]["speed"] == 3
    assert json.loads((tmp_path / "one.json.bak").read_text())["fields"]["speed"] == 127
    result = cli("--port", url, "eeprom", "dump", "1-2", "-o", f"{folder}/")
    assert result.code == 0, result.err
    assert json.loads((folder / "servo-01.json.bak").read_text())["fields"]["speed"] == 127
    assert json.loads((folder / "servo-01.json").read_text())["fields"]["speed"] == 3


def test_a_dump_whose_bak_is_a_directory_is_refused_before_reading(cli: Any, sim_line: Any, tmp_path: Path) -> None:
    sim, url = sim_line([1])
    one = tmp_path / "one.json"
    assert cli("--port", url, "eeprom", "dump", "1", "-o", str(one)).code == 0
    (tmp_path / "one.json.bak").mkdir()
    before = sim.transactions
    result = cli("--port", url, "eeprom", "dump", "1", "-o", str(one))
    assert result.code == ExitCode.USAGE and "one.json.bak" in result.err, result.err
    assert sim.transactions == before


def test_a_dump_to_an_empty_path_is_refused_not_written_into_the_current_folder(
    cli: Any, sim_line: Any, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # (a script's unset variable: pathlib reads "" as ".", and the backup landed in the current folder)
    sim, url = sim_line([1])
    monkeypatch.chdir(tmp_path)
    result = cli("--port", url, "eeprom", "dump", "1", "-o", "")
    assert result.code == ExitCode.USAGE and "empty" in result.err, result.err
    assert list(tmp_path.iterdir()) == [] and sim.transactions == 0
