"""The EEPROM backup file: what ``ics35 eeprom dump`` writes and ``eeprom restore`` (and ``ics35 web``) read back.

One JSON object per servo (format ``ics35-eeprom/1``): the decoded fields,
the flag names, the raw image and any code ICS 3.5 does not define.  On the
way back the whole document is checked before anything is sent (format and
version, a whole ``raw`` image, every field agreeing with it), and only the
editable fields are taken, so a restore goes through :func:`.eeprom_write.plan_eeprom_write`
like any other edit: the target servo keeps its own calibration bytes and
read-only flags, and its ID unless the caller asks for the saved one.
"""

from __future__ import annotations

import datetime
from dataclasses import dataclass
from typing import Any

from .. import protocol
from ..eeprom import EEPROM_FIELDS, EEPROM_SIZE, Eeprom
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


BACKUP_NAME, _, BACKUP_VERSION = BACKUP_FORMAT.partition("/")
RAW_HEX_LENGTH = 2 * EEPROM_SIZE  # two hex digits per wire byte


def _raw_image(raw: object) -> Eeprom:
    """The image ``raw`` holds: 64 bytes as 128 hex digits, each byte one nibble (0x00..0x0F)."""
    if not isinstance(raw, str):
        raise InvalidArgument(f"'raw' must be a string of {RAW_HEX_LENGTH} hex digits, got {type(raw).__name__}")
    if len(raw) != RAW_HEX_LENGTH:
        raise InvalidArgument(
            f"'raw' has {len(raw)} hex digits, not {RAW_HEX_LENGTH} ({EEPROM_SIZE} bytes): the image is cut short"
            if len(raw) < RAW_HEX_LENGTH
            else f"'raw' has {len(raw)} hex digits, not {RAW_HEX_LENGTH} ({EEPROM_SIZE} bytes)"
        )
    bad = next((i for i, c in enumerate(raw) if c not in "0123456789abcdefABCDEF"), None)
    if bad is not None:
        raise InvalidArgument(f"'raw' holds {raw[bad]!r} at character {bad + 1}, which is not a hex digit")
    image = bytes.fromhex(raw)
    wide = next((i for i, b in enumerate(image) if b > 0x0F), None)
    if wide is not None:
        raise InvalidArgument(
            f"'raw' byte {wide + 1} is {raw[2 * wide : 2 * wide + 2]}, not a nibble (00..0f): "
            "every EEPROM byte carries 4 bits"
        )
    return Eeprom.from_bytes(image)


def _check_format(doc: dict[str, Any]) -> None:
    fmt = doc.get("format")
    if fmt is None:
        raise InvalidArgument(f"no 'format' (a backup made by `ics35 eeprom dump` says {BACKUP_FORMAT!r})")
    if not isinstance(fmt, str) or fmt.partition("/")[0] != BACKUP_NAME:
        raise InvalidArgument(f"format {fmt!r} is not an ics35 EEPROM backup ({BACKUP_FORMAT!r})")
    if fmt != BACKUP_FORMAT:
        raise InvalidArgument(
            f"format {fmt!r}: this ics35 reads version {BACKUP_VERSION} of EEPROM backups only ({BACKUP_FORMAT!r})"
        )


def fields_from_document(doc: object) -> dict[str, int]:
    """The editable fields of a backup, after checking the whole document.

    A backup is refused unless its format and version are this program's, its
    ``raw`` image is whole (64 nibbles as hex), and every field it states (and
    ``flags_names``, ``unknown_codes``) agrees with that image: a backup that
    disagrees with itself was damaged or edited by hand, and which half is
    right cannot be told.
    """
    if not isinstance(doc, dict):
        raise InvalidArgument("an EEPROM backup is a JSON object (made by `ics35 eeprom dump`)")
    _check_format(doc)
    if "raw" not in doc:
        raise InvalidArgument("no 'raw' image (the whole EEPROM, which every backup carries)")
    image = _raw_image(doc["raw"])
    stated = image.to_dict()
    fields = doc.get("fields")
    if not isinstance(fields, dict):
        raise InvalidArgument("no 'fields' object (every backup carries the fields its raw image decodes to)")
    unknown = set(fields) - set(EEPROM_FIELDS)
    if unknown:
        raise InvalidArgument(f"unknown EEPROM field(s) in the backup: {', '.join(sorted(unknown))}")
    missing = set(EEPROM_FIELDS) - set(fields)
    if missing:
        raise InvalidArgument(f"the backup lacks field(s): {', '.join(sorted(missing))}")
    for name in EEPROM_FIELDS:
        value = fields[name]
        if isinstance(value, bool) or not isinstance(value, int):
            raise InvalidArgument(f"field {name} must be an integer, got {value!r}")
        if value != stated[name]:
            raise InvalidArgument(
                f"field {name} is {value} but the raw image holds {stated[name]}: the backup disagrees with "
                "itself (edited or damaged); make a new one with `ics35 eeprom dump`, or change the servo "
                "with `ics35 eeprom set`"
            )
    for key in ("flags_names", "unknown_codes"):
        if key in doc and doc[key] != stated[key]:
            raise InvalidArgument(f"'{key}' is {doc[key]!r} but the raw image gives {stated[key]!r}")
    saved = doc.get("servo_id")
    if saved is not None and (isinstance(saved, bool) or not isinstance(saved, int) or not 0 <= saved <= 31):
        raise InvalidArgument(f"'servo_id' must be an ID 0..31, got {saved!r}")
    return {name: int(stated[name]) for name in EEPROM_FIELDS}


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
