"""The EEPROM backup file: what ``ics35 eeprom dump`` writes and ``eeprom restore`` (and ``ics35 web``) read back.

One JSON object per servo (format ``ics35-eeprom/1``): the decoded fields,
the flag names, the raw image and any code ICS 3.5 does not define.  The
configurator's Back up all puts several servos' in one file (format
``ics35-eeproms/1``: each servo's object as it would be alone, and the servos
asked for that are not in it, with why, in the words of :func:`no_reply_why`,
:func:`read_failed_why`, :func:`port_lost_why` and :data:`GARBLED_WHY`, which
``ics35 eeprom dump`` uses too); :func:`backups_in` reads either kind,
and :meth:`Backups.backup_for` picks the backup a servo is restored from.  On the
way back the whole document is checked before anything is sent (format and
version, a whole ``raw`` image, every field agreeing with it), and only the
editable fields are taken, so a restore goes through :func:`.eeprom_write.plan_eeprom_write`
like any other edit: the target servo keeps its own calibration bytes and
read-only flags (``keep_read_only``: the plan names those the backup has
otherwise), and its ID unless the caller asks for the saved one; and
its baud rate when the caller asks to keep it (``keep_baud``: a backup made
before the servo was moved to another rate).

Restoring several backups, the servos may answer at different rates (some
moved to 1,250,000, others not): :func:`restore_rates` finds the rate each
answers at, on the one line the restore holds, and :func:`plan_restores` reads
each servo and plans its write there, so each is read, written and verified at
its own (:func:`.eeprom_write.write_eeprom_plans` reopens the line at each
plan's rate).  One run over every rate rather than one run per rate: the wire
carries the same traffic, while one run asks once over every diff and can
refuse an ID that answers at two rates (two servos: a run per rate would give
both of them the one backup).
"""

from __future__ import annotations

import datetime
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from .. import protocol
from ..eeprom import EEPROM_FIELDS, EEPROM_SIZE, Eeprom
from ..errors import InvalidArgument, ReplyError, ReplyTimeout, UnsafeOperation
from ..protocol.wire import id_ranges
from ..transports import carries_line_settings
from ..units import named_with_the_one_meant
from .eeprom_write import EepromPlan, back_at_rate, check_changes, plan_eeprom_write
from .failure_kinds import Line, reopening
from .scan import ALL_BAUDS, probe_ids, scan

BACKUP_FORMAT = "ics35-eeprom/1"
BACKUPS_FORMAT = "ics35-eeproms/1"  # several servos' backups in one file


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


def backups_document(
    backups: Iterable[Mapping[str, Any]], not_saved: Mapping[int, str] | None = None
) -> dict[str, Any]:
    """Several servos' backups (each as :func:`backup_document` makes it) in one document, in ID order, and
    the servos asked for that are not in it (``not_saved``: ID -> why, in the words said of it then)."""
    servos = sorted(backups, key=lambda doc: int(doc["servo_id"]))
    twice = sorted({doc["servo_id"] for doc in servos if [d["servo_id"] for d in servos].count(doc["servo_id"]) > 1})
    if twice:  # (the file would be refused when read back: which one is meant cannot be told)
        raise InvalidArgument(f"two backups of servo(s) {id_ranges(twice)}: a file holds one backup per servo")
    return {
        "format": BACKUPS_FORMAT,
        "saved": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "servos": [dict(doc) for doc in servos],
        "not_saved": [{"servo_id": i, "why": why} for i, why in sorted((not_saved or {}).items())],
    }


# Why a servo asked for is not in a file of several (its ``not_saved`` words), made here for every writer of the
# file (``ics35 eeprom dump IDS -o FILE.json``, the configurator's Back up all): the same cause reads the same in
# the file whichever wrote it, and names no screen or command of one of them.

GARBLED_WHY = "answered garbled: two servos sharing an ID, most likely, or noise on the line"
"""A servo whose answer to the probe before the reads was garbled."""


def no_reply_why(baud: int, *, no_echo: bool = False) -> str:
    """A servo that did not answer at ``baud``; ``no_echo``: on a line that echoes, not even the echo of the
    request came back (the adapter or its cable, not the servo)."""
    if no_echo:
        return f"no reply at {baud:,} baud, not even the echo of the request: check the adapter and its cable"
    return f"no reply at {baud:,} baud: check its power, the wiring, its ID and its baud rate"


def read_failed_why(error: ReplyError, baud: int, *, echo: bool = True) -> str:
    """A servo whose EEPROM read ended in ``error`` (at ``baud``; ``echo``: the line echoes what it sends), not a
    lost port's: no reply (:func:`no_reply_why`), or an answer no backup can be made of, in words naming no
    servo and showing no bytes."""
    if isinstance(error, ReplyTimeout):
        return no_reply_why(baud, no_echo=echo and not error.raw)
    return f"answered, but its EEPROM could not be read: {error.reason}"


def port_lost_why(at_servo: int) -> str:
    """A servo not read because the port was lost, at servo ``at_servo`` (the one it was read from then, or one
    before it)."""
    return f"not read: the port was lost at servo {at_servo}; back it up again once the port is back"


def backup_file_name(ids: Sequence[int]) -> str:
    """The name a backup of ``ids`` is offered under: ``servo-05.json`` for one servo, ``servos-01-17.json``
    for several (the first and the last asked for)."""
    first, last = protocol.check_id(ids[0]), protocol.check_id(ids[-1])
    return f"servo-{first:02d}.json" if len(ids) == 1 else f"servos-{first:02d}-{last:02d}.json"


BACKUP_NAME, _, BACKUP_VERSION = BACKUP_FORMAT.partition("/")
BACKUPS_NAME, _, BACKUPS_VERSION = BACKUPS_FORMAT.partition("/")
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
        raise InvalidArgument(
            f"format {fmt!r} is not an ics35 EEPROM backup ({BACKUP_FORMAT!r}, "
            f"or {BACKUPS_FORMAT!r} for several servos)"
        )
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
        told = (named_with_the_one_meant(name, EEPROM_FIELDS) for name in sorted(unknown))
        raise InvalidArgument(f"unknown EEPROM field(s) in the backup: {', '.join(told)}")
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


def _saved_id(doc: Mapping[str, Any], fields: Mapping[str, int]) -> int:
    """The ID a checked backup was saved from: its ``servo_id``, else the one its image holds."""
    saved = doc.get("servo_id")
    return saved if isinstance(saved, int) and not isinstance(saved, bool) else fields["servo_id"]


@dataclass(frozen=True)
class Backups:
    """The backups a file holds (:func:`backups_in`), each checked whole."""

    servos: dict[int, dict[str, Any]]  # the ID each was saved from -> its backup, as one servo's file holds it
    several: bool  # a file of several servos' backups (one servo's may go to any servo)
    not_saved: dict[int, str] = field(default_factory=dict)  # IDs asked for and not in the file -> why

    def backup_for(self, servo_id: int) -> dict[str, Any]:
        """The backup to restore servo ``servo_id`` from: one servo's file whichever servo it was saved from (a
        servo may take another's settings); from a file of several, the one saved from ``servo_id``.

        Raises:
            InvalidArgument: a file of several that holds none of ``servo_id`` (the words name those it holds,
                and why ``servo_id`` is not among them when the file says).
        """
        protocol.check_id(servo_id)
        if not self.several:
            [doc] = self.servos.values()
            return doc
        if servo_id in self.servos:
            return self.servos[servo_id]
        held = f"the backups of servos {id_ranges(self.servos)}" if self.servos else "no servo's backup"
        why = self.not_saved.get(servo_id)
        because = f" (when it was saved, servo {servo_id}: {why})" if why else ""
        raise InvalidArgument(f"the file holds {held}, none of servo {servo_id}{because}")


def backups_in(doc: object) -> Backups:
    """The backups in ``doc``: one servo's (``ics35 eeprom dump``'s) or several servos' (:func:`backups_document`).

    Everything is checked before any servo is chosen: each servo's backup as
    :func:`fields_from_document` checks one (the words name the servo and its
    place in the file), and a file holding two backups of one servo is refused
    (which one is meant cannot be told).

    Raises:
        InvalidArgument: not a backup, or a damaged one.
    """
    if not isinstance(doc, dict):
        raise InvalidArgument("an EEPROM backup is a JSON object (made by `ics35 eeprom dump` or `ics35 web`)")
    fmt = doc.get("format")
    if not isinstance(fmt, str) or fmt.partition("/")[0] != BACKUPS_NAME:
        fields = fields_from_document(doc)
        return Backups({_saved_id(doc, fields): doc}, several=False)
    if fmt != BACKUPS_FORMAT:
        raise InvalidArgument(
            f"format {fmt!r}: this ics35 reads version {BACKUPS_VERSION} of backups of several servos only "
            f"({BACKUPS_FORMAT!r})"
        )
    members = doc.get("servos")
    if not isinstance(members, list):
        raise InvalidArgument("'servos' must be a list: the backup of each servo the file holds")
    servos: dict[int, dict[str, Any]] = {}
    place: dict[int, int] = {}
    for n, member in enumerate(members, 1):
        if not isinstance(member, dict):
            raise InvalidArgument(f"number {n} in 'servos' is not a servo's backup (a JSON object)")
        named = member.get("servo_id")
        who = f"servo {named}" if isinstance(named, int) and not isinstance(named, bool) else "a servo"
        try:
            fields = fields_from_document(member)
        except InvalidArgument as exc:
            raise InvalidArgument(f"the backup of {who} (number {n} in 'servos'): {exc}") from None
        sid = _saved_id(member, fields)
        if sid in servos:
            raise InvalidArgument(
                f"two backups of servo {sid} (numbers {place[sid]} and {n} in 'servos'): which one is meant "
                "cannot be told"
            )
        servos[sid], place[sid] = member, n
    return Backups(servos, several=True, not_saved=_not_saved(doc.get("not_saved", [])))


def _not_saved(listed: object) -> dict[int, str]:
    """A file of several's ``not_saved``: ID -> why."""
    shape = '\'not_saved\' must list the servos not saved, each as {"servo_id": 0..31, "why": words}'
    if not isinstance(listed, list):
        raise InvalidArgument(shape)
    missing: dict[int, str] = {}
    for entry in listed:
        sid = entry.get("servo_id") if isinstance(entry, dict) else None
        why = entry.get("why") if isinstance(entry, dict) else None
        if (
            isinstance(sid, bool)
            or not isinstance(sid, int)
            or not 0 <= sid <= protocol.MAX_ID
            or not isinstance(why, str)
        ):
            raise InvalidArgument(f"{shape}, not {entry!r}")
        missing[sid] = why
    return missing


@dataclass(frozen=True)
class BackupChanges:
    """A checked backup, as the changes to plan for its target servo."""

    saved_id: int  # the ID the backup was saved from
    fields: dict[str, int]  # servo_id removed unless the saved ID is to be restored; baud_rate if kept
    saved_baud: int  # the baud rate the backup's image names


def backup_changes(doc: object, *, restore_id: bool = False, keep_baud: bool = False) -> BackupChanges:
    """Check a backup document and return what restoring it changes (InvalidArgument when unusable).

    ``restore_id``: the saved ID is written too (else the target keeps its own).  ``keep_baud``: the
    backup's baud rate is not written, so the target stays at the rate it answers at now (a backup made
    before the servo was moved to another rate); without it a backup naming another rate changes the
    servo's, which :meth:`.EepromPlan.refusal` refuses unless a baud change is allowed.
    """
    fields = fields_from_document(doc)
    assert isinstance(doc, dict)  # fields_from_document refused anything else
    saved_id = protocol.check_id(_saved_id(doc, fields))
    saved_baud = fields["baud_rate"]
    if not restore_id:
        del fields["servo_id"]
    if keep_baud:
        del fields["baud_rate"]
    check_changes(fields, keep_read_only=True)
    return BackupChanges(saved_id, fields, saved_baud)


@dataclass(frozen=True)
class RestoreRates:
    """Where the servos of a restore of several backups answer (:func:`restore_rates`)."""

    rates: Mapping[int, int]  # ID -> the rate to read, write and verify it at
    several: Mapping[int, tuple[int, ...]] = field(default_factory=dict)  # ID -> rates: one servo at each
    looked: bool = False  # the other rates were probed (some ID was silent at the line's own)

    def refusal(self) -> str | None:
        """Why the restore must not go on (``None``: it may): an ID answering at several rates is several
        servos, and which of them a backup of that ID belongs to cannot be told."""
        if not self.several:
            return None
        which = "; ".join(
            f"ID {i} answers at {' and '.join(f'{b:,}' for b in at)} baud" for i, at in sorted(self.several.items())
        )
        return f"{which}: one servo at each rate, and which one its backup belongs to cannot be told"


async def restore_rates(line: Line, ids: Iterable[int], *, bauds: Iterable[int] = ALL_BAUDS) -> RestoreRates:
    """The rate each of ``ids`` answers at, for restoring their backups on ``line`` in one go.

    Every ID is probed at the line's rate first; when all answer there, that
    is all (nothing is sent at another rate, so an ID that also answers at
    another rate goes unseen).  Otherwise the line is held and reopened at each
    of ``bauds`` to scan those IDs, as :func:`.scan.scan` does (a stretch read,
    the EEPROM of what answers, one servo heard at several rates told from
    several servos by its calibration bytes), and returned to its rate however
    the scan ends (:func:`.eeprom_write.back_at_rate`).  An ID found nowhere
    keeps the line's rate (its read then fails as a read there does).  A link
    that does not carry the baud rate (``socket://``) and a line with the echo
    that gives nothing back, not even the echo, are not scanned: another rate
    tells nothing there (without the echo, nothing back is what a line whose
    servos are all at another rate gives: it is scanned).  See :meth:`RestoreRates.refusal`.

    Raises:
        InvalidArgument: a bad ID or baud rate.
        BusClosed, PortLost, SerialPortError: the line is closed, its port gone, or it cannot be reopened.
    """
    wanted = [protocol.check_id(i) for i in ids]
    home = int(line.baudrate)
    first = await probe_ids(line, wanted)
    dead = first.silent and line.echo  # not even the echo: the adapter or its wiring, at any rate
    if set(first.answered) == set(wanted) or dead or not carries_line_settings(getattr(line, "port", None)):
        return RestoreRates(dict.fromkeys(wanted, home))
    try:
        report = await scan(reopening(line), bauds=[home, *(int(b) for b in bauds if int(b) != home)], ids=wanted)
    finally:
        await back_at_rate(line, home)  # (a line that cannot go back fails the first read after)
    if report.lost is not None:
        raise report.lost  # (the rates the loss cut off are unknown: no restore is planned on half a scan)
    found: dict[int, list[int]] = {}
    for servo in report.servos:
        found.setdefault(servo.servo_id, []).append(servo.baud)
    rates = {i: home if i in first.answered or len(found.get(i, ())) != 1 else found[i][0] for i in wanted}
    several = {i: tuple(sorted(at)) for i, at in found.items() if len(at) > 1}
    return RestoreRates(rates, several, looked=True)


async def plan_restores(
    line: Line, changes: Mapping[int, Mapping[str, Any]], *, bauds: Iterable[int] = ALL_BAUDS
) -> list[EepromPlan]:
    """Plan the restore of several backups on ``line`` (``changes``: servo ID -> the fields to write, as
    :func:`backup_changes` gives them); nothing is written.

    The rate each servo answers at is found first (:func:`restore_rates`, over
    ``bauds``); each servo is then read and its write planned there
    (:func:`.eeprom_write.plan_eeprom_write`), the servos at the line's rate
    first, then those of each other rate (one reopen per rate), and the line is
    returned to its rate however the planning ends
    (:func:`.eeprom_write.back_at_rate`).  The plans come in that order, each
    with its rate (``plan.baud``), for :func:`.eeprom_write.write_eeprom_plans`.

    Raises:
        InvalidArgument: a bad ID, field value or baud rate (before anything is sent).
        UnsafeOperation: an ID answers at several rates (:meth:`RestoreRates.refusal`); nothing was written.
        ReplyError: a servo does not answer its EEPROM read (at the line's rate when it was found nowhere).
        BusClosed, PortLost, SerialPortError: the line is closed, its port gone, or it cannot be reopened.
    """
    for fields in changes.values():
        check_changes(fields, keep_read_only=True)
    found = await restore_rates(line, changes, bauds=bauds)
    refusal = found.refusal()
    if refusal:
        raise UnsafeOperation(f"{refusal}; nothing was written")
    home = int(line.baudrate)
    order = sorted(changes, key=lambda i: (found.rates[i] != home, found.rates[i]))
    plans: list[EepromPlan] = []
    try:
        for servo_id in order:
            if int(line.baudrate) != found.rates[servo_id]:
                await line.reopen(baudrate=found.rates[servo_id])
            plans.append(await plan_eeprom_write(line, servo_id, changes[servo_id], keep_read_only=True))
    finally:
        await back_at_rate(line, home)
    return plans
