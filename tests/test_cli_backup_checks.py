"""No lost work on the command line: `eeprom restore` checks a backup whole before anything goes on the wire
(each damaged backup is exit 2, names the file and what is wrong, and the line sees no transaction at all);
`eeprom dump` saves only an image two reads agree on; and a write to several servos (restore, free) says,
servo by servo, what happened, also when the line is lost half-way."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from ics35_async.cli import ExitCode, main
from ics35_async.eeprom import Flags
from ics35_async.policies.eeprom_backup import backup_document, backups_document
from ics35_async.protocol import ReadEeprom, WriteEeprom
from ics35_async.sim import VirtualLine, VirtualServo
from tests.support.cli_runs import edit_backup
from tests.support.sim_servos import CtrlCWhenAsked, UnpluggedAfterWrite, UnplugsWhenAsked, free_command

Damage = Callable[[dict[str, Any]], None]


def _set(key: str, value: Any) -> Damage:
    def damage(doc: dict[str, Any]) -> None:
        doc[key] = value

    return damage


def _raw(change: Callable[[str], str]) -> Damage:
    def damage(doc: dict[str, Any]) -> None:
        doc["raw"] = change(doc["raw"])

    return damage


def _field(name: str, value: Any) -> Damage:
    def damage(doc: dict[str, Any]) -> None:
        doc["fields"][name] = value

    return damage


def _drop(key: str) -> Damage:
    def damage(doc: dict[str, Any]) -> None:
        del doc[key]

    return damage


def _both(*damages: Damage) -> Damage:
    def damage(doc: dict[str, Any]) -> None:
        for one in damages:
            one(doc)

    return damage


DAMAGED: dict[str, tuple[Damage, str]] = {
    "unknown format": (_set("format", "something/9"), "'something/9' is not an ics35 EEPROM backup"),
    "newer version": (_set("format", "ics35-eeprom/2"), "reads version 1 of EEPROM backups only"),
    "no format": (_drop("format"), "no 'format'"),
    "raw cut short": (_raw(lambda raw: raw[:100]), "'raw' has 100 hex digits, not 128"),
    "raw too long": (_raw(lambda raw: raw + "00"), "'raw' has 130 hex digits, not 128"),
    "raw starting with zz": (_raw(lambda raw: "zz" + raw[2:]), "'z' at character 1, which is not a hex digit"),
    "a non-nibble byte": (_raw(lambda raw: raw[:20] + "7f" + raw[22:]), "'raw' byte 11 is 7f, not a nibble"),
    "raw deleted": (_drop("raw"), "no 'raw' image"),
    "raw not a string": (_set("raw", 5), "'raw' must be a string"),
    "fields deleted": (_drop("fields"), "no 'fields' object"),
    "a changed field": (_field("speed", 12), "field speed is 12 but the raw image holds 127"),
    "unknown format and a changed field": (
        _both(_set("format", "something/9"), _field("punch", 9)),
        "'something/9' is not an ics35 EEPROM backup",
    ),
    "flags_names disagree": (_set("flags_names", ["REVERSE"]), "'flags_names' is ['REVERSE']"),
    "a field missing": (lambda doc: doc["fields"].pop("damping"), "lacks field(s): damping"),
    "a field misspelt": (
        lambda doc: doc["fields"].update(dampin=doc["fields"].pop("damping")),
        "unknown EEPROM field(s) in the backup: dampin (did you mean damping?)",
    ),
    "a field not a number": (_field("speed", "fast"), "field speed must be an integer"),
    "saved ID out of range": (_set("servo_id", 40), "'servo_id' must be an ID 0..31"),
}


@pytest.mark.parametrize("damage", DAMAGED, ids=list(DAMAGED))
@pytest.mark.parametrize("how", ["to its own servo", "to a named servo", "from a directory"])
def test_each_damaged_backup_is_refused_before_anything_is_sent(
    cli: Any, sim_line: Any, tmp_path: Path, damage: str, how: str
) -> None:
    sim, url = sim_line([1, 2])
    folder = tmp_path / "backup"
    assert cli("--port", url, "eeprom", "dump", "1,2", "-o", f"{folder}/").code == 0
    for i in (1, 2):  # the servos drift from their backups: a restore would write
        sim.servo(i).eeprom = sim.servo(i).eeprom.replace(speed=99)
    bad = folder / "servo-02.json"
    doc = json.loads(bad.read_text())
    change, expected = DAMAGED[damage]
    change(doc)
    bad.write_text(json.dumps(doc))
    before = sim.transactions
    args = {"to its own servo": [str(bad)], "to a named servo": ["2", str(bad)], "from a directory": [str(folder)]}
    result = cli("--port", url, "eeprom", "restore", *args[how], "--yes")
    assert result.code == ExitCode.USAGE, result.err
    assert "servo-02.json" in result.err and expected in " ".join(result.err.split()), result.err
    assert sim.transactions == before  # nothing sent, so nothing written either
    assert sim.servo(1).eeprom_writes == sim.servo(2).eeprom_writes == 0


def test_a_backup_edited_whole_is_restored(cli: Any, sim_line: Any, tmp_path: Path) -> None:
    """Raw image and fields changed together is a backup that agrees with itself: it is written."""
    sim, url = sim_line([1])
    backup = tmp_path / "one.json"
    assert cli("--port", url, "eeprom", "dump", "1", "-o", str(backup)).code == 0
    edit_backup(backup, speed=40)
    result = cli("--port", url, "eeprom", "restore", str(backup), "--yes")
    assert result.code == 0, result.err
    assert sim.servo(1).eeprom.speed == 40 and sim.servo(1).calibration_intact


def test_a_backup_saved_with_a_byte_order_mark_is_restored(cli: Any, sim_line: Any, tmp_path: Path) -> None:
    """Notepad's "UTF-8 with BOM" puts a mark first that JSON refuses ("Unexpected UTF-8 BOM")."""
    sim, url = sim_line([1])
    backup = tmp_path / "one.json"
    assert cli("--port", url, "eeprom", "dump", "1", "-o", str(backup)).code == 0
    edit_backup(backup, speed=40)
    backup.write_bytes(b"\xef\xbb\xbf" + backup.read_bytes().replace(b"\n", b"\r\n"))
    result = cli("--port", url, "eeprom", "restore", str(backup), "--yes")
    assert result.code == 0, result.err
    assert sim.servo(1).eeprom.speed == 40 and sim.servo(1).calibration_intact


# --------------------------------------------------------------------------- the account of every servo


class PullsThePlug(VirtualServo):
    """A servo at whose EEPROM write (``when="write"``), at whose read-back after it (``"read-back"``) or at
    whose EEPROM read (``"read"``) the adapter is pulled out: the servo has done what it was told, no reply
    gets back."""

    def __init__(self, servo_id: int, when: str) -> None:
        super().__init__(servo_id)
        self.when = when
        self.line: VirtualLine | None = None

    def handle(self, command: Any) -> Any:
        reply = super().handle(command)
        written = self.eeprom_writes > 0
        if self.line is not None and (
            (self.when == "write" and isinstance(command, WriteEeprom))
            or (self.when == "read-back" and written and isinstance(command, ReadEeprom))
            or (self.when == "read" and isinstance(command, ReadEeprom))
        ):
            self.line.unplug()
        return reply


def drifted_line(sim_line: Any, tmp_path: Path, when: str) -> tuple[VirtualLine, str, Path, PullsThePlug]:
    """Servos 1-3 backed up into DIR, then changed; servo 2 pulls the plug ``when``."""
    plug = PullsThePlug(2, when)
    sim, url = sim_line([VirtualServo(1), plug, VirtualServo(3)])
    folder = tmp_path / "backup"
    assert ics35_cli("--port", url, "eeprom", "dump", "1-3", "-o", f"{folder}/") == 0
    for i in (1, 2, 3):
        sim.servo(i).eeprom = sim.servo(i).eeprom.replace(speed=99)
    plug.line = sim
    return sim, url, folder, plug


def ics35_cli(*args: str) -> int:
    with pytest.raises(SystemExit) as exited:
        main(list(args))
    return int(exited.value.code or 0)


def test_a_servo_unplugged_after_acknowledging_a_write_is_said_written_not_verified(cli: Any, sim_line: Any) -> None:
    servo = UnpluggedAfterWrite(2)
    sim, url = sim_line([VirtualServo(1), servo])
    servo.line = sim
    result = cli("--port", url, "eeprom", "set", "2", "speed=50", "--yes")
    assert result.code == ExitCode.COMMUNICATION, result.err
    out, err = " ".join(result.out.split()), " ".join(result.err.split())
    told = f"servo 2: 1 EEPROM field(s) written, not verified: no read-back came; check with: ics35 --port {url}"
    assert f"{told} eeprom dump 2 --table" in out, out
    # It was "servo 2 answers as neither ID 2": a sentence cut short, no word of what to do.
    assert "servo 2 acknowledged the EEPROM write, then did not answer its read-back (asked as ID 2)" in err, err
    assert "check its power and cable, then read it again" in err and "neither" not in err, err
    assert servo.eeprom.speed == 50


def test_a_dump_interrupted_while_reading_says_nothing_was_saved(cli: Any, sim_line: Any, tmp_path: Path) -> None:
    # Ctrl-C while the servos were read: "error: interrupted", and no word of whether the backups there were.
    folder = tmp_path / "backup"
    folder.mkdir()
    (folder / "servo-01.json").write_text("an earlier backup")
    _, url = sim_line([VirtualServo(1), CtrlCWhenAsked(2, ReadEeprom), VirtualServo(3)])
    result = cli("--port", url, "eeprom", "dump", "1-3", "-o", f"{folder}/")
    assert result.code == ExitCode.INTERRUPTED, result.err
    said = " ".join(result.err.split())
    assert "interrupted while the servos were read: nothing was saved (the files there are as they were)" in said
    assert sorted(p.name for p in folder.iterdir()) == ["servo-01.json"]
    assert (folder / "servo-01.json").read_text() == "an earlier backup"


def test_eeprom_set_stopped_while_reading_says_nothing_was_written(cli: Any, sim_line: Any) -> None:
    # Ctrl-C, or two new servos answering at ID 0 at once, while the servo was read: "error: interrupted" (or
    # the garbled reply's words), and no word that nothing was written, as `eeprom restore` says it.
    sim, url = sim_line([VirtualServo(1), CtrlCWhenAsked(2, ReadEeprom)])
    result = cli("--port", url, "eeprom", "set", "2", "speed=50", "--yes")
    assert result.code == ExitCode.INTERRUPTED, result.err
    assert "nothing was written (it stopped while reading the servo)" in " ".join(result.err.split()), result.err
    sim, url = sim_line([VirtualServo(0), VirtualServo(0)])
    result = cli("--port", url, "eeprom", "set", "0", "speed=50", "--yes")
    assert result.code == ExitCode.COMMUNICATION, result.err
    assert "nothing was written (it stopped while reading the servo)" in " ".join(result.err.split()), result.err
    assert all(s.eeprom_writes == 0 for s in sim.servos)


def test_a_directory_restore_with_one_servo_missing_says_how_to_restore_the_others(
    cli: Any, sim_line: Any, tmp_path: Path
) -> None:
    # The whole restore was refused (rightly: every servo is read first) with what to check for the missing
    # one, and no word of how to restore the others without it.
    sim, url = sim_line([VirtualServo(1), VirtualServo(2), VirtualServo(3)])
    folder = tmp_path / "backup"
    assert cli("--port", url, "eeprom", "dump", "1-3", "-o", f"{folder}/").code == 0
    sim.remove_servo(2)
    result = cli("--port", url, "--timeout", "0.005", "eeprom", "restore", str(folder), "--yes")
    assert result.code == ExitCode.NO_REPLY, result.err
    said = " ".join(result.err.split())
    assert "nothing was written" in said, said
    assert f"to restore the others without servo 2, move {folder}/servo-02.json out of {folder}" in said, said


def test_a_restore_of_a_file_of_several_with_one_servo_missing_says_how_to_restore_the_others(
    cli: Any, sim_line: Any, tmp_path: Path
) -> None:
    # The others' backups are in the same file: "move it out" would leave none of them.
    sim, url = sim_line([VirtualServo(1), VirtualServo(2), VirtualServo(3)])
    docs = [backup_document(sim.servo(i).eeprom, i, baud=115200, port=url) for i in (1, 2, 3)]
    backup = tmp_path / "servos-01-03.json"
    backup.write_text(json.dumps(backups_document(docs)))
    sim.remove_servo(2)
    result = cli("--port", url, "--timeout", "0.005", "eeprom", "restore", str(backup), "--yes")
    assert result.code == ExitCode.NO_REPLY, result.err
    said = " ".join(result.err.split())
    assert "nothing was written" in said and "move" not in said, said
    again = f"ics35 --port {url} --timeout 0.005 eeprom restore ID {backup} (ID: 1, 3)"
    assert f"to restore the others without servo 2, restore each alone: {again}" in said, said


def test_restore_lost_mid_write_says_what_each_servo_holds(cli: Any, sim_line: Any, tmp_path: Path) -> None:
    sim, url, folder, _ = drifted_line(sim_line, tmp_path, "write")
    result = cli("--port", url, "--timeout", "0.05", "eeprom", "restore", str(folder), "--yes")
    assert result.code == ExitCode.COMMUNICATION, result.err
    out = " ".join(result.out.split())
    assert "servo 1: 1 EEPROM field(s) written and verified" in out
    assert "servo 2: unknown: the command stopped while the write was on its way" in out
    # Every command a hint names carries the line options of the one that ran (else: the simulator).
    assert f"see which with: ics35 --port {url} --timeout 0.05 eeprom dump 2 --table" in out
    assert "servo 3: not written (its EEPROM is as it was)" in out
    err = " ".join(result.err.split())
    assert "lost" in err or "unplugged" in err
    assert f"run it again: ics35 --port {url} --timeout 0.05 eeprom restore {folder}" in err
    # What the report says is what the servos hold.
    assert [sim.servo(i).eeprom.speed for i in (1, 2, 3)] == [127, 127, 99]
    assert [sim.servo(i).eeprom_writes for i in (1, 2, 3)] == [1, 1, 0]


def test_restore_lost_before_the_read_back_in_json(cli: Any, sim_line: Any, tmp_path: Path) -> None:
    sim, url, folder, _ = drifted_line(sim_line, tmp_path, "read-back")
    result = cli("--port", url, "eeprom", "restore", str(folder), "--yes", "--json")
    assert result.code == ExitCode.COMMUNICATION, result.err
    servos = {s["id"]: s for s in result.json()["servos"]}
    assert {i: s["outcome"] for i, s in servos.items()} == {1: "verified", 2: "unverified", 3: "not_written"}
    assert [servos[i]["written"] for i in (1, 2, 3)] == [True, True, False]
    assert "error" in servos[2] and "error" not in servos[1]
    assert [sim.servo(i).eeprom_writes for i in (1, 2, 3)] == [1, 1, 0]


def test_restore_that_succeeds_reports_every_servo(cli: Any, sim_line: Any, tmp_path: Path) -> None:
    sim, url = sim_line([1, 2, 3])
    folder = tmp_path / "backup"
    assert cli("--port", url, "eeprom", "dump", "1-3", "-o", f"{folder}/").code == 0
    for i in (1, 3):
        sim.servo(i).eeprom = sim.servo(i).eeprom.replace(speed=99)
    result = cli("--port", url, "eeprom", "restore", str(folder), "--yes", "--json")
    assert result.code == 0, result.err
    outcomes = {s["id"]: s["outcome"] for s in result.json()["servos"]}
    assert outcomes == {1: "verified", 2: "unchanged", 3: "verified"}
    result = cli("--port", url, "eeprom", "restore", str(folder), "--yes")
    assert result.code == 0 and "servo 2: EEPROM already matches" in result.out


def test_a_dump_over_a_noisy_line_never_saves_a_wrong_image(cli: Any, sim_line: Any, tmp_path: Path) -> None:
    """An EEPROM reply has no checksum: a corrupted nibble reads as a valid image.  A backup is saved only
    from two reads that agree, so it is the servo's image or no backup at all."""
    saved = 0
    for seed in range(12):
        sim, url = sim_line([1], faults="corrupt@1:0.4", seed=seed)
        backup = tmp_path / f"servo-{seed}.json"
        result = cli("--port", url, "eeprom", "dump", "1", "-o", str(backup))
        if result.code != 0:
            assert not backup.exists()
            continue
        saved += 1
        assert json.loads(backup.read_text())["raw"] == sim.servo(1).eeprom.to_bytes().hex(), seed
    assert saved >= 8


@pytest.mark.parametrize(("output", "ids"), [("dir", "1-5"), ("table", "1-5"), ("dir", "all")])
def test_a_dump_cut_by_an_unplug_keeps_what_it_read(
    cli: Any, sim_line: Any, tmp_path: Path, output: str, ids: str
) -> None:
    """Servos 1-5 dumped (5 is not there), the adapter pulled out at servo 3's read: servos 1 and 2 are saved
    (shown), the silent ID is told as ever, and the error says which were saved and how to read the rest (the
    servos that answered and were not read)."""
    plug = PullsThePlug(3, "read")
    sim, url = sim_line([VirtualServo(1), VirtualServo(2), plug, VirtualServo(4)])
    plug.line = sim
    folder = tmp_path / "backup"
    where = ["-o", f"{folder}/"] if output == "dir" else ["--table"]
    result = cli("--port", url, "--timeout", "0.05", "eeprom", "dump", ids, *where)
    assert result.code == ExitCode.COMMUNICATION, result.err
    err = " ".join(result.err.split())
    assert "unplugged" in err and "Traceback" not in err
    if ids == "all":  # the servos on the line: those read and those the loss left unread
        assert "4 servos answered at 115200 baud: IDs 1, 2, 3, 4" in err
    else:
        assert "no answer from ID(s) 5: not saved" in err
    if output == "dir":
        assert sorted(p.name for p in folder.iterdir()) == ["servo-01.json", "servo-02.json"]
        for i in (1, 2):
            saved = json.loads((folder / f"servo-{i:02d}.json").read_text())
            assert saved["raw"] == sim.servo(i).eeprom.to_bytes().hex()
        assert "servo(s) 1, 2 saved" in err
        assert f"read the rest: ics35 --port {url} --timeout 0.05 eeprom dump 3,4 -o {folder}/" in err
    else:
        assert "EEPROM of servo 1" in result.out and "EEPROM of servo 2" in result.out
        assert "servo 3" not in result.out
        assert f"servo(s) 1, 2 shown above; when the line is back, read the rest: ics35 --port {url}" in err
        assert "eeprom dump 3,4 --table" in err


def test_several_servos_dumped_to_one_file_as_the_port_goes_keep_what_was_read(
    cli: Any, sim_line: Any, tmp_path: Path
) -> None:
    """The adapter pulled out at servo 3's read: the file holds servos 1 and 2 and names 3 and 4 as not read;
    the command to read the rest writes another file (the same name would put this one aside as .bak)."""
    plug = PullsThePlug(3, "read")
    sim, url = sim_line([VirtualServo(1), VirtualServo(2), plug, VirtualServo(4)])
    plug.line = sim
    backup = tmp_path / "robot.json"
    result = cli("--port", url, "--timeout", "0.05", "eeprom", "dump", "1-4", "-o", str(backup))
    assert result.code == ExitCode.COMMUNICATION, result.err
    doc = json.loads(backup.read_text())
    assert [s["servo_id"] for s in doc["servos"]] == [1, 2]
    assert [n["servo_id"] for n in doc["not_saved"]] == [3, 4]
    assert all("port was lost" in n["why"] for n in doc["not_saved"]), doc["not_saved"]
    err = " ".join(result.err.split())
    assert f"read the rest: ics35 --port {url} --timeout 0.05 eeprom dump 3,4 -o {tmp_path}/servos-03-04.json" in err


def test_free_of_several_servos_says_which_went_free_when_the_line_is_lost(cli: Any, sim_line: Any) -> None:
    puller = UnplugsWhenAsked(2, free_command)
    sim, url = sim_line([VirtualServo(1), puller, VirtualServo(3)])
    puller.line = sim
    result = cli("--port", url, "free", "1-3")
    assert result.code == ExitCode.COMMUNICATION, result.err
    assert "servo 1: free at 7500" in result.out
    assert "servo 2: unknown: the line was lost before it answered" in " ".join(result.out.split())
    assert "servo 3: unknown" in result.out
    assert "lost" in result.err or "unplugged" in result.err
    assert [t.servo_id for t in sim.log] == [1, 2]  # servo 3 never heard its free: unknown is right
    # (and the command that frees them once the port is back, as a Ctrl-C's account gives it)
    assert f"free them with: ics35 --port {url} free 2-3" in " ".join(result.err.split()), result.err


def test_restore_clearing_pwminh_advises_what_fits_restore(cli: Any, sim_line: Any, tmp_path: Path) -> None:
    """restore writes the backup's flags as saved: eeprom set's flags+= syntax is no advice for it; the
    command that sets the flag again afterwards (on this line) is."""
    sim, url = sim_line([1])
    backup = tmp_path / "one.json"
    assert cli("--port", url, "eeprom", "dump", "1", "-o", str(backup)).code == 0
    assert not json.loads(backup.read_text())["fields"]["flags"] & Flags.PWMINH
    sim.servo(1).eeprom = sim.servo(1).eeprom.replace(flags=sim.servo(1).eeprom.flags | Flags.PWMINH)
    result = cli("--port", url, "eeprom", "restore", str(backup), "--yes")
    assert result.code == 0, result.err
    err = " ".join(result.err.split())
    assert "use flags+=NAME / flags-=NAME" not in err
    assert "this clears flag(s) PWMINH" in err
    assert f"ics35 --port {url} eeprom set 1 flags+=PWMINH" in err, err


@pytest.mark.parametrize("ids", ["all", "7-8"])
def test_a_dump_of_several_says_which_servo_answered_garbled_and_fails(
    cli: Any, sim_line: Any, tmp_path: Path, ids: str
) -> None:
    """Two servos sharing ID 7 beside servo 8: the dump saved 8 and exited 0, saying nothing of 7 (for
    "all") or that 7 did not answer (for 7-8): a backup missing a servo that is there, told wrongly."""
    _, url = sim_line([VirtualServo(7), VirtualServo(7), VirtualServo(8)])
    folder = tmp_path / "backup"
    result = cli("--port", url, "eeprom", "dump", ids, "-o", f"{folder}/")
    err = " ".join(result.err.split())
    assert result.code == ExitCode.COMMUNICATION, err
    assert sorted(p.name for p in folder.iterdir()) == ["servo-08.json"]
    assert "ID(s) 7 answered garbled: not saved" in err and "two servos sharing an ID" in err, err
    assert "no answer from ID(s) 7" not in err
