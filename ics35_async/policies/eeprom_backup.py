"""The EEPROM backup file: what ``ics35 eeprom dump`` writes and ``eeprom restore`` (and ``ics35 web``) read back.

One JSON object per servo (format ``ics35-eeprom/1``): the decoded fields,
the flag names, the raw image and any code ICS 3.5 does not define.  On the
way back only the editable fields are taken (``fields`` wins over ``raw``),
each checked, so a restore goes through :func:`.eeprom_write.plan_eeprom_write`
like any other edit: the target servo keeps its own calibration bytes and
read-only flags, and its ID unless the caller asks for the saved one.
"""

from __future__ import annotations

import datetime
from dataclasses import dataclass
from typing import Any

from .. import protocol
from ..eeprom import EEPROM_FIELDS, Eeprom
from ..errors import InvalidArgument
from .eeprom_write import check_changes

BACKUP_FORMAT = "ics35-eeprom/1"


def backup_document(image: Eeprom, servo_id: int, *, baud: int, port: str) -> dict[str, Any]:
    """The backup of ``image``, read from servo ``servo_id`` on ``port`` at ``baud``."""
    fields = image.to_dict()
    return {
        "format": BACKUP_FORMAT,
        "servo_id": servo_id,
        "baud": baud,
        "port": port,
        "saved": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "fields": {name: fields[name] for name in EEPROM_FIELDS},
        "flags_names": fields["flags_names"],
        "raw": fields["raw"],
        "unknown_codes": fields["unknown_codes"],
    }


def fields_from_document(doc: object) -> dict[str, int]:
    """The editable fields of a backup (``fields`` wins over ``raw`` when both are there)."""
    if not isinstance(doc, dict):
        raise InvalidArgument("an EEPROM backup is a JSON object (made by `ics35 eeprom dump`)")
    fields = doc.get("fields")
    if fields is None and isinstance(doc.get("raw"), str):
        try:
            image = Eeprom.from_bytes(bytes.fromhex(doc["raw"]))
        except ValueError as exc:
            raise InvalidArgument(f"the backup's raw image is unusable: {exc}") from None
        fields = {name: int(getattr(image, name)) for name in EEPROM_FIELDS}
    if not isinstance(fields, dict):
        raise InvalidArgument("the backup has neither 'fields' nor 'raw' (was it made by `ics35 eeprom dump`?)")
    unknown = set(fields) - set(EEPROM_FIELDS)
    if unknown:
        raise InvalidArgument(f"unknown EEPROM field(s) in the backup: {', '.join(sorted(unknown))}")
    missing = set(EEPROM_FIELDS) - set(fields)
    if missing:
        raise InvalidArgument(f"the backup lacks field(s): {', '.join(sorted(missing))}")
    for name, value in fields.items():
        if isinstance(value, bool) or not isinstance(value, int):
            raise InvalidArgument(f"field {name} must be an integer, got {value!r}")
    return dict(fields)


@dataclass(frozen=True)
class BackupChanges:
    """A checked backup, as the changes to plan for its target servo."""

    saved_id: int  # the ID the backup was saved from
    fields: dict[str, int]  # servo_id removed unless the saved ID is to be restored


def backup_changes(doc: object, *, restore_id: bool = False) -> BackupChanges:
    """Check a backup document and return what restoring it changes (InvalidArgument when unusable)."""
    fields = fields_from_document(doc)
    assert isinstance(doc, dict)  # fields_from_document refused anything else
    saved = doc.get("servo_id")
    saved_id = saved if isinstance(saved, int) and not isinstance(saved, bool) else fields["servo_id"]
    protocol.check_id(saved_id)
    if not restore_id:
        del fields["servo_id"]
    check_changes(fields)
    return BackupChanges(saved_id, fields)
