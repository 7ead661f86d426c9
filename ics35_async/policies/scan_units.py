"""One servo, however many rates it answered at: what a scan knows of each servo it heard.

An EEPROM reply carries no checksum, so an image counts only when two reads
agree (:func:`read_eeprom_agreed`; a flipped bit would otherwise make one
servo look like two, or a backup wrong).  The per-unit calibration bytes in
the image tell one servo heard at several rates from several servos
(:func:`servos_of`); where a servo's EEPROM names a rate it was not heard
at, it is asked there again (:func:`confirm_eeprom_rates`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from .. import protocol
from ..eeprom import Eeprom
from ..errors import ReplyError
from ..units import check_int
from .failure_kinds import Line, LineOpener


@dataclass(frozen=True)
class FoundServo:
    """One servo a scan found, listed once."""

    servo_id: int
    baud: int  # the rate it is listed at: its EEPROM's rate when it answered at several
    eeprom: Eeprom | None = None  # None: not read (quick scan) or the read failed
    answered_at: tuple[int, ...] = ()  # every rate it answered at (several: the line ignores rates)
    eeprom_error: ReplyError | None = None
    rate_unconfirmed: bool = False  # its EEPROM was wanted but could not be read: ``baud`` is only where it answered

    @property
    def eeprom_baud(self) -> int | None:
        """The baud rate the servo's EEPROM names (``None`` if it was not read)."""
        return None if self.eeprom is None else int(self.eeprom.baud_rate)

    @property
    def baud_pending(self) -> bool:
        """Its EEPROM names another rate: a baud change that takes effect at its next power-up."""
        return self.eeprom is not None and int(self.eeprom.baud_rate) != self.baud


EEPROM_READ_ATTEMPTS = 5  # a servo that answered a probe is there: a noisy line gets more than one go


async def read_eeprom_agreed(line: Line, servo_id: int, *, attempts: int = EEPROM_READ_ATTEMPTS) -> Eeprom:
    """Servo ``servo_id``'s EEPROM image on ``line``, read until two reads agree (at most ``attempts`` reads).

    An EEPROM reply carries no checksum: a flipped bit that leaves a nibble a nibble reads as a valid,
    wrong image (in a scan it would look like another servo; in a backup it would be written back
    one day).  Raises the last read's ReplyError, or a ReplyError saying no two reads agreed.
    """
    attempts = check_int("attempts", attempts, 2, 20)
    seen: list[Eeprom] = []
    error: ReplyError | None = None
    for _ in range(attempts):
        try:
            image = await line.request(protocol.ReadEeprom(servo_id), retries=0)
        except ReplyError as exc:
            error = exc
            continue
        if image in seen:
            return image
        seen.append(image)
    if error is None or len(seen) > 1:
        error = ReplyError(f"{len(seen)} reads, no two alike (a noisy line)", command="read_eeprom", servo_id=servo_id)
    raise error


async def read_eeprom_or_error(line: Line, servo_id: int) -> Eeprom | ReplyError:
    try:
        return await read_eeprom_agreed(line, servo_id)
    except ReplyError as exc:
        return exc


async def read_missing_images(
    open_at: LineOpener, hits: Mapping[int, Sequence[int]], images: dict[tuple[int, int], Eeprom | ReplyError]
) -> None:
    """Read the EEPROM wherever an ID answered at several rates and it is not read yet."""
    todo: dict[int, list[int]] = {}
    for i, at in hits.items():
        if len(at) > 1:
            for baud in at:
                if (baud, i) not in images:
                    todo.setdefault(baud, []).append(i)
    for baud, servo_ids in todo.items():
        async with open_at(baud) as line:
            for i in servo_ids:
                images[(baud, i)] = await read_eeprom_or_error(line, i)


async def confirm_eeprom_rates(
    open_at: LineOpener,
    hits: dict[int, list[int]],
    images: dict[tuple[int, int], Eeprom | ReplyError],
    probed: Sequence[int],
) -> None:
    """Ask a servo again at the rate its EEPROM names, where it was probed but not heard.

    On a noisy line the probes (or the ID read before them) at a servo's own rate can all be lost
    while it is heard at another: a line that ignores rates.  Read there, the same image proves it,
    and the servo is heard at its own rate; silent there, the EEPROM holds a rate change that waits
    for the next power-up.
    """
    todo: dict[int, list[tuple[int, Eeprom]]] = {}
    for servo_id, at in hits.items():
        for baud in at:
            image = images.get((baud, servo_id))
            if isinstance(image, Eeprom):
                own = int(image.baud_rate)
                if own in probed and own not in at and all(sid != servo_id for sid, _ in todo.get(own, [])):
                    todo.setdefault(own, []).append((servo_id, image))
    for baud, wanted in todo.items():
        async with open_at(baud) as line:
            for servo_id, image in wanted:
                again = await read_eeprom_or_error(line, servo_id)
                if again == image:
                    hits[servo_id] = sorted([*hits[servo_id], baud], key=list(probed).index)
                    images[(baud, servo_id)] = again


def one_unit_at_several_rates(
    hits: Mapping[int, Sequence[int]], images: Mapping[tuple[int, int], Eeprom | ReplyError]
) -> bool:
    """Whether one servo (one image, calibration bytes included) answered at two rates: then the line
    does not enforce rates (a pty, some bridges), and every servo on it answers at every rate."""
    for servo_id, at in hits.items():
        read = [images.get((baud, servo_id)) for baud in at]
        units = [image.to_bytes() for image in read if isinstance(image, Eeprom)]
        if len(units) != len(set(units)):
            return True
    return False


def servos_of(
    servo_id: int,
    at: Sequence[int],
    images: Mapping[tuple[int, int], Eeprom | ReplyError],
    ignores_rates: bool = False,
) -> list[FoundServo]:
    """The servos behind one ID's answers: one per distinct EEPROM image (calibration differs per unit).

    On a line that ignores rates (``ignores_rates``) a servo is listed at the rate its EEPROM names,
    never at another it merely answered at, and an answer whose image could not be read makes no entry
    of its own when a servo with this ID was read (it is that servo, heard at one more rate).  An ID
    none of whose images could be read is listed once, its rate unconfirmed.
    """
    groups: dict[bytes | int, list[int]] = {}
    unread: list[int] = []
    for baud in at:
        image = images.get((baud, servo_id))
        if isinstance(image, Eeprom):
            groups.setdefault(image.to_bytes(), []).append(baud)
        else:
            unread.append(baud)
    if unread and (ignores_rates or not groups):
        if groups:  # the servo already read, heard again at another rate
            first = next(iter(groups))
            groups[first] = sorted([*groups[first], *unread], key=list(at).index)
        else:  # one entry: which of these rates is its own, no EEPROM says
            groups[unread[0]] = list(unread)
    else:
        for baud in unread:  # a line that keeps rates apart: another servo may answer there
            groups[baud] = [baud]
    found = []
    for group in groups.values():
        image = next(
            (images.get((b, servo_id)) for b in group if isinstance(images.get((b, servo_id)), Eeprom)),
            images.get((group[0], servo_id)),
        )
        eeprom = image if isinstance(image, Eeprom) else None
        listed = group[0]
        if eeprom is not None and (int(eeprom.baud_rate) in group or ignores_rates):
            listed = int(eeprom.baud_rate)
        error = image if isinstance(image, ReplyError) else None
        found.append(FoundServo(servo_id, listed, eeprom, tuple(group), error, rate_unconfirmed=error is not None))
    return found
