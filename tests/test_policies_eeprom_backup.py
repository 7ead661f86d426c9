"""The backup files, as documents: one servo's (``ics35 eeprom dump``) and several servos' in one (the
configurator's Back up all), written, read back and refused when damaged, with nothing on a line."""

from __future__ import annotations

import json
from typing import Any

import pytest

from ics35_async.errors import InvalidArgument
from ics35_async.policies.eeprom_backup import (
    BACKUPS_FORMAT,
    backup_changes,
    backup_document,
    backups_document,
    backups_in,
)
from ics35_async.sim import VirtualServo

PORT = "/dev/ttyUSB0"


def saved(servo_id: int, **changes: int) -> dict[str, Any]:
    """Servo ``servo_id``'s backup as `ics35 eeprom dump` makes it, its image with ``changes``."""
    image = VirtualServo(servo_id).eeprom.replace(**changes)
    return backup_document(image, servo_id, baud=115200, port=PORT)


def on_disk(doc: dict[str, Any]) -> Any:
    """``doc`` as a file gives it back: written as JSON and read again."""
    return json.loads(json.dumps(doc, indent=2))


def test_several_servos_backups_in_one_file_come_back_each_for_its_own_servo() -> None:
    docs = [saved(i, speed=10 * i, punch=i) for i in (3, 1, 2)]
    whole = on_disk(backups_document(docs))
    assert whole["format"] == BACKUPS_FORMAT == "ics35-eeproms/1"
    assert [d["servo_id"] for d in whole["servos"]] == [1, 2, 3]  # in ID order, whatever order they were read in
    held = backups_in(whole)
    assert held.several and sorted(held.servos) == [1, 2, 3] and held.not_saved == {}
    for i in (1, 2, 3):
        # Each servo's part is the very file `eeprom dump` writes for it: restored as that file is.
        assert held.backup_for(i) == next(d for d in docs if d["servo_id"] == i)
        changes = backup_changes(held.backup_for(i))
        assert (changes.saved_id, changes.fields["speed"], changes.fields["punch"]) == (i, 10 * i, i)


def test_one_servos_backup_is_read_as_before_and_goes_to_any_servo() -> None:
    one = on_disk(saved(4, speed=9))
    held = backups_in(one)
    assert not held.several and list(held.servos) == [4]
    assert held.backup_for(4) == one and held.backup_for(7) == one  # (servo 7 takes servo 4's settings)


def test_a_file_without_a_servos_backup_names_the_servos_it_holds_and_why_the_others_are_missing() -> None:
    not_saved = {5: "no reply at 115,200 baud", 6: "not read: the port was lost"}
    whole = on_disk(backups_document([saved(i) for i in (1, 2, 3, 4, 7)], not_saved))
    held = backups_in(whole)
    assert sorted(held.servos) == [1, 2, 3, 4, 7] and held.not_saved == not_saved
    with pytest.raises(InvalidArgument) as missing:
        held.backup_for(5)
    words = str(missing.value)
    assert "servos 1-4, 7" in words and "none of servo 5" in words, words
    assert "(when it was saved, servo 5: no reply at 115,200 baud)" in words, words
    with pytest.raises(InvalidArgument) as never_asked:
        held.backup_for(9)
    assert "none of servo 9" in str(never_asked.value) and "when it was saved" not in str(never_asked.value)


def test_a_file_of_no_servo_says_so() -> None:
    held = backups_in(on_disk(backups_document([], {1: "no reply"})))
    assert held.servos == {}
    with pytest.raises(
        InvalidArgument, match=r"holds no servo's backup, none of servo 1 \(when it was saved, servo 1: no reply\)"
    ):
        held.backup_for(1)


def damaged(doc: dict[str, Any], where: str) -> dict[str, Any]:
    """``doc`` (a file of several servos' backups) damaged at ``where``."""
    if where == "servos":
        doc["servos"] = {"1": doc["servos"][0]}
    elif where == "member raw":
        doc["servos"][1]["raw"] = doc["servos"][1]["raw"][:-2]
    elif where == "member not an object":
        doc["servos"][1] = [1, 2]
    elif where == "same servo twice":
        doc["servos"].append(dict(doc["servos"][0]))
    elif where == "version":
        doc["format"] = "ics35-eeproms/2"
    elif where == "not_saved":
        doc["not_saved"] = [{"servo_id": 40, "why": "no reply"}]
    return doc


@pytest.mark.parametrize(
    ("where", "said"),
    [
        ("servos", "'servos' must be a list"),
        ("member raw", "the backup of servo 2 (number 2 in 'servos'): 'raw' has 126 hex digits"),
        ("member not an object", "number 2 in 'servos' is not a servo's backup"),
        ("same servo twice", "two backups of servo 1 (numbers 1 and 3 in 'servos')"),
        ("version", "this ics35 reads version 1 of backups of several servos only"),
        ("not_saved", "'not_saved' must list"),
    ],
)
def test_a_damaged_file_of_several_servos_is_refused_in_words_before_any_servo_is_chosen(where: str, said: str) -> None:
    doc = damaged(on_disk(backups_document([saved(1), saved(2)])), where)
    with pytest.raises(InvalidArgument) as refused:
        backups_in(doc)
    assert said in str(refused.value), str(refused.value)


def test_a_file_is_not_made_with_two_backups_of_one_servo() -> None:
    with pytest.raises(InvalidArgument, match="two backups of servo"):
        backups_document([saved(1), saved(2), saved(1)])


def test_what_is_no_backup_at_all_is_refused_as_one_servos_backup_is() -> None:
    for doc, said in (([1, 2], "a JSON object"), ({"format": "other/1"}, "is not an ics35 EEPROM backup")):
        with pytest.raises(InvalidArgument, match=said):
            backups_in(doc)
