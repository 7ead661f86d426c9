"""Renumbering the one servo on a line: prove it is alone, cheaply, then write and verify.

The ID command renames every device that hears it, so an ID write is safe
only with exactly one device on the line.  The proof, in 33-35 transactions
when every answer comes in time (more when some come late, see below):

1. an ID read, which every device at this rate answers: silence means nobody
   is there (one transaction, nothing more to do); a garbled answer means
   several devices answered at once;
2. one stretch read per ID (32): exactly one ID may answer, none garbled,
   and it must be the ID the ID read reported.  The ID read alone is not
   enough: two replies pulled onto one wire can combine into a clean-looking
   third ID (a wired AND of 0xE1 and 0xE3 reads 0xE1).

Then the write (1) and a stretch read at the new ID (1): 35-37 in all, plus
the re-reads below.
Silent IDs are probed once each, with the bus's short probe allowance; a
servo slower than that shows itself by late bytes, and the survey then
probes the silent IDs again with the normal one.  The last ID, when silent,
is read once more with the normal allowance (behind a guard read, 2 more
transactions), since nothing after it would catch its late reply (see
:func:`.scan.probe_ids`).
"""

from __future__ import annotations

import dataclasses
import enum
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

from .. import protocol
from ..errors import IcsError, ReplyError, UnsafeOperation, VerifyError
from ..protocol import Param
from .failure_kinds import Line, LineOpener, answers_short_read, nothing_came_back
from .scan import ALL_IDS, RateCallback, probe_ids, search_other_rates


class Refusal(enum.Enum):
    """Why an ID write is not safe on this line."""

    NOBODY = "nobody"  # no device answered
    GARBLED = "garbled"  # some ID answered garbled: two servos sharing it, most likely
    SEVERAL = "several"  # more than one ID answered
    ID_READ = "id_read"  # the ID read came back garbled or names another ID


@dataclass(frozen=True)
class IdSurvey:
    """What the line showed before an ID write."""

    baud: int
    id_read: int | None  # the ID read's answer; None when it failed
    id_read_error: ReplyError | None = None
    answered: tuple[int, ...] = ()  # IDs answering a stretch read
    garbled: Mapping[int, ReplyError] = field(default_factory=dict)
    silent: bool = False  # not one byte came back, not even the echo
    elsewhere: tuple[int, ...] = ()  # nobody answered: the other rates a device answers at (see look_elsewhere)

    @property
    def refusal(self) -> Refusal | None:
        """Why an ID write would be unsafe on this line (``None``: exactly one device, safe)."""
        quiet_id_read = self.id_read_error is None or nothing_came_back(self.id_read_error)
        if not self.answered and not self.garbled and self.id_read is None and quiet_id_read:
            return Refusal.NOBODY
        if self.garbled:
            return Refusal.GARBLED
        if len(self.answered) > 1:
            return Refusal.SEVERAL
        if not self.answered or self.id_read != self.answered[0]:
            return Refusal.ID_READ
        return None

    @property
    def lone_id(self) -> int | None:
        """The ID of the only device on the line, when that is proven."""
        return self.answered[0] if self.refusal is None else None

    def reason(self, new_id: int | None = None) -> str:
        """Why the write (of ``new_id``, when given) is refused, for a person ("" when it is safe)."""
        refusal = self.refusal
        ids = ", ".join(map(str, self.answered))
        if refusal is Refusal.NOBODY:
            if self.elsewhere:
                return f"no device answered at {self.baud} baud, but one does at {self.elsewhere[0]} baud"
            return f"no device answered at {self.baud} baud"
        if refusal is Refusal.GARBLED:
            shared = ", ".join(map(str, sorted(self.garbled)))
            return f"garbled replies from ID(s) {shared}: probably two servos sharing an ID"
        if refusal is Refusal.SEVERAL:
            target = "the same ID" if new_id is None else f"ID {new_id}"
            return f"{len(self.answered)} servos answer (IDs {ids}): an ID write would give ALL of them {target}"
        if refusal is Refusal.ID_READ:
            if self.id_read is None:
                return f"the ID command got a garbled answer ({self.id_read_error}): another device is on the line"
            if not self.answered:
                return f"the ID command reports ID {self.id_read}, but no ID answers a stretch read"
            return f"servo {ids} answers, but the ID command reports ID {self.id_read}: another device is on the line"
        return ""

    def advice(self) -> str:
        """What to do about the refusal, for a person ("" when the write is safe)."""
        refusal = self.refusal
        if refusal is Refusal.NOBODY:
            if self.elsewhere:
                return f"open the line at {self.elsewhere[0]} baud to renumber it"
            return (
                "check the servo's power (6-12 V on the servo line, not just USB), its wiring, and that a servo "
                "set to another baud rate answers only at that rate (scan every rate)"
            )
        if refusal is Refusal.GARBLED or refusal is Refusal.SEVERAL:
            return "unplug every servo but the one to renumber, then try again"
        if refusal is Refusal.ID_READ:
            return "unplug every device but the servo to renumber, then try again"
        return ""


@dataclass(frozen=True)
class IdChange:
    """The outcome of an ID write."""

    old_id: int
    new_id: int
    written: bool  # False: the servo already had the ID


async def _read_id(line: Line) -> tuple[int | None, ReplyError | None]:
    try:
        return await line.request(protocol.ReadId(), retries=0), None
    except ReplyError as exc:
        return None, exc


async def survey_for_id_write(line: Line) -> IdSurvey:
    """Find out whether exactly one device is on the line: an ID read, then a stretch read per ID, and a guard
    read and a second read for a silent ID 31 (33 to 35 transactions; garbled or late replies are asked again).
    """
    rx_before = line.stats.total.bytes_rx
    seen, error = await _read_id(line)
    baud = int(line.baudrate)
    if error is not None and nothing_came_back(error):
        return IdSurvey(baud, None, error, silent=line.stats.total.bytes_rx == rx_before)
    rate = await probe_ids(line, ALL_IDS, id_read_first=False)
    if seen is None and len(rate.answered) == 1 and not rate.garbled:
        # One servo answers alone: the garbled ID read may have been noise.  Ask once more.
        seen, error = await _read_id(line)
    return IdSurvey(baud, seen, error, rate.answered, rate.garbled, line.stats.total.bytes_rx == rx_before)


async def look_elsewhere(
    survey: IdSurvey, open_at: LineOpener, *, echo: bool = True, on_rate: RateCallback | None = None
) -> IdSurvey:
    """``survey``, with the other rates a device answers at (``elsewhere``) when none answered at its own.

    A servo set to another baud rate is silent at this one: the refusal then names the rate to open the
    line at.  Not looked for when not even the echo came back (``echo``: the line loops what it sends):
    the adapter or its wiring, which no rate mends.  ``open_at(baud)`` opens the line at a rate, as for
    :func:`~.scan.scan` (:func:`~.failure_kinds.reopening` leaves a line at the last rate tried); ``on_rate(baud)``
    is told each rate as it is tried (see :func:`~.scan.search_other_rates`).
    """
    if survey.refusal is not Refusal.NOBODY or (survey.silent and echo):
        return survey
    try:
        search = await search_other_rates(open_at, [survey.baud], on_rate=on_rate)
    except (IcsError, OSError):
        return survey  # advice only: a port that cannot be opened again leaves the refusal as it was
    return dataclasses.replace(survey, elsewhere=search.found)


def cut_short_words(sent_from: int | None, new_id: int) -> str:
    """What a renumbering to ``new_id`` cut short (Ctrl-C, a lost port) leaves, in words, from ``on_sent`` of
    :func:`write_lone_id`: ``sent_from``, the ID the servo had as the ID command went out (None: it had not gone
    out).  After it the servo took the new ID or did not: only asking tells which."""
    if sent_from is None:
        return "before the ID write: nothing was written"
    return f"while the ID write was on its way: the servo answers as ID {sent_from} or as ID {new_id} now"


async def write_lone_id(
    line: Line, new_id: int, *, survey: IdSurvey | None = None, on_sent: Callable[[], None] | None = None
) -> IdChange:
    """Give the only device on the line the ID ``new_id`` (stored in its EEPROM), then check it answers.

    ``survey`` (from :func:`survey_for_id_write`, e.g. shown to a person
    before confirming) saves proving it again.  ``on_sent`` is called just
    before the ID command goes out: a call cancelled (Ctrl-C) after it leaves
    the device at its old or its new ID, one cancelled before it wrote nothing.  Raises UnsafeOperation,
    writing nothing, unless exactly one device is proven on the line; raises
    VerifyError if the new ID does not answer after the write.  A write whose
    acknowledgement is lost is settled by asking who answers now: the new ID
    (the write took: returned as written), else the old one (VerifyError: the
    ID is unchanged), else neither (VerifyError: scan the line).
    """
    new_id = protocol.check_id(new_id)
    if survey is None:
        survey = await survey_for_id_write(line)
    old_id = survey.lone_id
    if old_id is None:
        raise UnsafeOperation(
            f"{survey.reason(new_id)}; an ID write needs exactly one device; nothing was written: {survey.advice()}"
        )
    if old_id == new_id:
        return IdChange(old_id, new_id, written=False)
    if on_sent is not None:
        on_sent()
    try:
        # Sent once: the ID command renames every device that hears it, so it is never retried blindly.
        await line.request(protocol.WriteId(new_id), retries=0)
    except ReplyError as exc:
        # The write may have been heard with only its acknowledgement lost: who answers now settles it.
        if await answers_short_read(line, new_id):
            return IdChange(old_id, new_id, written=True)
        if await answers_short_read(line, old_id):
            raise VerifyError(
                f"the ID write got no acknowledgement ({exc}) and the servo still answers as ID {old_id}: "
                "its ID is unchanged"
            ) from exc
        raise VerifyError(
            f"the ID write got no acknowledgement ({exc}) and neither ID {old_id} nor ID {new_id} answers "
            "now: scan the line to find the servo"
        ) from exc
    try:
        await line.request(protocol.ReadParam(new_id, Param.STRETCH))
    except ReplyError as exc:
        raise VerifyError(f"the servo acknowledged ID {new_id}, but ID {new_id} does not answer: {exc}") from exc
    return IdChange(old_id, new_id, written=True)
