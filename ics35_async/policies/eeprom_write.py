"""Changing a servo's EEPROM safely: plan from its own image, write only what was asked, verify.

The rules, in order:

* the new image is the servo's own image with the requested fields changed
  (``Eeprom.replace`` checks each), so the factory calibration bytes stay the
  servo's;
* the read-only flags (FREE, PCM) report the servo's state: they stay as the
  servo has them, and an edit naming them (in a ``flags`` value, or to set or
  clear) is refused; a restore (``keep_read_only``: the flags of an image saved
  at another moment, or from another servo) keeps the servo's and names those
  it keeps otherwise than the image has them (:attr:`EepromPlan.kept_note`);
* the ID and the baud rate change only when the caller allows it, and an ID
  change is refused when the new ID already answers (two servos with one ID
  garble every reply);
* right before writing, the image is read again and must still be the one
  planned from; after writing it is read back and compared.  After an ID
  change both IDs are probed (the reference does not say when a new ID takes
  effect); after a baud change the servo is also asked at the new rate;
* a plan is written at the rate it was made at (the rate the servo answers
  at): a line at another rate is reopened there first, so servos at different
  rates (a restore of several backups) are each written and verified at their
  own, and returned to its rate after (a cancellation too waits for that).
"""

from __future__ import annotations

import contextlib
import enum
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from .. import protocol
from ..eeprom import (
    READ_ONLY_FLAGS,
    UNUSED_FLAG_BITS,
    BaudRate,
    Eeprom,
    Flags,
    WriteRefusal,
    flag_names,
    flags_value,
)
from ..errors import IcsError, InvalidArgument, ReplyError, ReplyTimeout, UnsafeOperation, VerifyError
from ..tasks import despite_cancellation
from ..units import check_int, stretch_from_eeprom
from .failure_kinds import Line, answers_short_read

NO_FLAGS = Flags(0)
RETURN_BOUND = 5.0  # seconds a line's return to its rate may take when the work that moved it is cancelled

# The EEPROM fields whose RAM twin the servo works with, named as its RAM parameter: the reference gives each
# parameter write's value with "the EEPROM's in parentheses", and the RAM stretch as loaded from the EEPROM at
# power-up.  An EEPROM write changes what the servo powers up with; the RAM keeps its value until then.
POWER_UP_PARAMS: Mapping[str, str] = {
    "stretch_gain": "stretch",
    "speed": "speed",
    "current_limit": "current_limit",
    "temperature_limit": "temperature_limit",
}


def power_up_note(changed: Mapping[str, int], set_now: Callable[[str, int], str]) -> str | None:
    """One line for a person after an EEPROM write of ``changed`` (field -> new value): the fields the servo
    loads into RAM only at its next power-up, and how to use them now (``set_now(param, value)``: the RAM write
    in the caller's words, e.g. an ``ics35 set`` command line); ``None`` when it wrote none of them."""
    loaded = [name for name in changed if name in POWER_UP_PARAMS]
    if not loaded:
        return None
    ways = [
        set_now(POWER_UP_PARAMS[name], stretch_from_eeprom(changed[name]) if name == "stretch_gain" else changed[name])
        for name in loaded
    ]
    it = "it" if len(loaded) == 1 else "them"
    return f"{', '.join(loaded)}: loaded into RAM at the servo's next power-up; to use {it} now: {'; '.join(ways)}"


def _refuse_read_only(bits: int) -> None:
    """Refuse an edit naming a read-only flag, in the words every caller (command line, configurator) gives."""
    if bits & READ_ONLY_FLAGS:
        names = "|".join(flag_names(bits & READ_ONLY_FLAGS))
        raise InvalidArgument(
            f"{names}: the FREE and PCM flags are read-only (they report the servo's state and cannot be set "
            "or cleared)"
        )


def _check_flag_edit(set_flags: int, clear_flags: int) -> tuple[int, int]:
    """``set_flags`` and ``clear_flags`` as ints, checked."""
    checked = []
    for what, value in (("set_flags", set_flags), ("clear_flags", clear_flags)):
        number = check_int(what, value, 0, 0xFF)
        _refuse_read_only(number)
        checked.append(number)
    set_flags, clear_flags = checked
    both = set_flags & clear_flags
    if both:
        raise InvalidArgument(f"flag(s) {Flags(both)!r} both set and cleared")
    return set_flags, clear_flags


# The flags byte's bits that are the servo's own state, not a setting: its read-only flags and the unused
# bits 5-6 (the reference fixes them at 0, yet a servo may report them set).
_STATE_BITS = READ_ONLY_FLAGS | UNUSED_FLAG_BITS


def _edit(
    current: Eeprom, changes: Mapping[str, Any], set_flags: int, clear_flags: int, keep_read_only: bool
) -> tuple[Eeprom, Flags]:
    """The edited image, and the state bits (read-only flags, unused bits 5-6) a restored ``flags`` value
    asked otherwise than ``current`` has them, which stay the servo's."""
    set_flags, clear_flags = _check_flag_edit(set_flags, clear_flags)
    fields = dict(changes)
    kept = NO_FLAGS
    if "flags" in fields or set_flags or clear_flags:
        flags = flags_value(fields.get("flags", int(current.flags)))
        if "flags" in fields and keep_read_only:  # a saved byte: its state bits were another moment's
            kept = Flags((flags ^ current.flags) & _STATE_BITS)
            flags = (flags & ~_STATE_BITS) | (current.flags & _STATE_BITS)
        elif "flags" in fields:
            _refuse_read_only(flags)
            # A value names the writable flags: the servo's state bits stay (a bit 5-6 it has not is a setting,
            # which replace() refuses).
            flags |= current.flags & _STATE_BITS
        fields["flags"] = (flags | set_flags) & ~clear_flags
    return current.replace(**fields), kept


def edit_image(
    current: Eeprom,
    changes: Mapping[str, Any],
    *,
    set_flags: int = NO_FLAGS,
    clear_flags: int = NO_FLAGS,
    keep_read_only: bool = False,
) -> Eeprom:
    """``current`` with ``changes`` applied, then ``set_flags`` set and ``clear_flags`` cleared.

    A ``flags`` value gives the writable flags (REVERSE, PWMINH, ROTATION,
    SLAVE); the read-only ones (FREE, PCM) stay as ``current`` has them, and
    naming one is refused, in the value or to set or clear.  The unused bits
    5-6 stay as ``current`` has them too: setting one is refused, clearing
    them takes ``clear_flags``.  ``keep_read_only`` (a restore: the value is a
    saved image's flags byte): the value's read-only flags and unused bits are
    not written, whatever they are.  Every value is checked (InvalidArgument).
    """
    return _edit(current, changes, set_flags, clear_flags, keep_read_only)[0]


def check_changes(
    changes: Mapping[str, Any],
    *,
    set_flags: int = NO_FLAGS,
    clear_flags: int = NO_FLAGS,
    keep_read_only: bool = False,
) -> None:
    """Check ``changes``, ``set_flags`` and ``clear_flags`` (as :func:`edit_image` takes them, with
    ``keep_read_only``) before any port opens, against a factory image; limits are checked again on the
    servo's.

    Raises:
        InvalidArgument: an unknown field, a value out of range, a read-only flag named, or a flag both set
            and cleared.
    """
    edit_image(Eeprom.factory(), changes, set_flags=set_flags, clear_flags=clear_flags, keep_read_only=keep_read_only)


@dataclass(frozen=True)
class EepromPlan:
    """A checked EEPROM change for one servo, not yet written."""

    servo_id: int  # the ID the servo answers at now
    baud: int  # the rate it answers at now
    before: Eeprom
    after: Eeprom
    id_taken: bool = False  # the new ID already answers on this line
    kept_read_only: Flags = NO_FLAGS  # read-only flags and unused bits 5-6 a restored image has otherwise: the servo's

    def _kept_bits(self) -> list[tuple[str, int]]:
        bits = [1 << n for n in range(8) if self.kept_read_only & (1 << n)]
        return [(Flags(bit).name or f"bit {bit.bit_length() - 1}", bit) for bit in bits]

    @property
    def kept_names(self) -> list[str]:
        """The names of :attr:`kept_read_only` (``FREE``, ``PCM``, ``bit 5``, ``bit 6``)."""
        return [name for name, _ in self._kept_bits()]

    @property
    def kept_note(self) -> str | None:
        """What the write leaves as the servo has it though the image asked otherwise (``None``: nothing):
        its read-only flags (and unused bits 5-6), in one line for a person."""
        if not self.kept_read_only:
            return None
        states = ", ".join(f"{name} {'on' if self.before.flags & bit else 'off'}" for name, bit in self._kept_bits())
        kinds = [
            kind
            for kind, bits in (("read-only flag(s)", READ_ONLY_FLAGS), ("unused flag bits", UNUSED_FLAG_BITS))
            if self.kept_read_only & bits
        ]
        return (
            f"servo {self.servo_id} keeps its {' and '.join(kinds)} as it reports them ({states}): they report the "
            "servo's state and are not written"
        )

    @property
    def diff(self) -> dict[str, tuple[Any, Any]]:
        """Field -> (before, after) for every field the write changes."""
        return self.before.diff(self.after)

    @property
    def changes_baud(self) -> bool:
        """True if the write changes the baud rate (needs ``allow_baud_change``)."""
        return self.after.baud_rate != self.before.baud_rate

    @property
    def changes_id(self) -> bool:
        """True if the write changes the servo's ID (needs ``allow_id_change``)."""
        return self.after.servo_id != self.before.servo_id

    @property
    def cleared_flags(self) -> Flags:
        """Flags the servo has now and loses with this write (unused bits 5-6, nameless, excluded)."""
        return Flags(self.before.flags & ~self.after.flags & ~READ_ONLY_FLAGS & ~UNUSED_FLAG_BITS)

    @property
    def added_flags(self) -> Flags:
        """Flags the write sets that were clear (read-only flags excluded)."""
        return Flags(self.after.flags & ~self.before.flags & ~READ_ONLY_FLAGS & ~UNUSED_FLAG_BITS)

    def refusal(self, *, allow_baud_change: bool = False, allow_id_change: bool = False) -> str | None:
        """Why this write must not happen (``None``: it may), given whether a baud change
        (``allow_baud_change``) and an ID change (``allow_id_change``) are allowed."""
        why = self.why_refused(allow_baud_change=allow_baud_change, allow_id_change=allow_id_change)
        return None if why is None else str(why)

    def why_refused(self, *, allow_baud_change: bool = False, allow_id_change: bool = False) -> WriteRefusal | None:
        """:meth:`refusal`, its parts apart (see ``Eeprom.why_refused``), ``allow_baud_change`` and
        ``allow_id_change`` as there: the ID another servo answers at is allowed by nothing."""
        why = self.after.why_refused(
            self.before, self.servo_id, allow_baud_change=allow_baud_change, allow_id_change=allow_id_change
        )
        if why is None and self.changes_id and self.id_taken:
            why = WriteRefusal(
                f"ID {self.after.servo_id} already answers on this line; two servos with one ID garble every reply"
            )
        return why


async def plan_eeprom_write(
    line: Line,
    servo_id: int,
    changes: Mapping[str, Any],
    *,
    set_flags: int = NO_FLAGS,
    clear_flags: int = NO_FLAGS,
    keep_read_only: bool = False,
) -> EepromPlan:
    """Read servo ``servo_id``'s image on ``line`` and build the change (``changes``, ``set_flags``,
    ``clear_flags``, ``keep_read_only``: see :func:`edit_image`); nothing is written.

    When the change gives the servo a new ID, that ID is probed first
    (``id_taken``).  With ``keep_read_only`` the plan names the read-only flags
    it keeps otherwise than ``changes`` has them (``kept_read_only``, ``kept_note``).

    Raises:
        InvalidArgument: an unknown field, a value out of range, a read-only flag named, or a flag both set
            and cleared.
        ReplyError: the servo does not answer the EEPROM read, or answers wrongly.
        BusClosed, PortLost: the line is closed or its port is gone.
    """
    servo_id = protocol.check_id(servo_id)
    # Bad values never reach the wire.
    check_changes(changes, set_flags=set_flags, clear_flags=clear_flags, keep_read_only=keep_read_only)
    before = await line.request(protocol.ReadEeprom(servo_id))
    after, kept = _edit(before, changes, set_flags, clear_flags, keep_read_only)
    taken = after.servo_id not in (before.servo_id, servo_id) and await answers_short_read(line, after.servo_id)
    return EepromPlan(servo_id, int(line.baudrate), before, after, id_taken=taken, kept_read_only=kept)


@dataclass(frozen=True)
class EepromWriteResult:
    """What happened to a planned EEPROM write."""

    plan: EepromPlan
    written: bool  # False: the image already matched, nothing was sent
    acknowledged: bool = False  # the servo answered the write itself
    read_back: Eeprom | None = None  # the image read after the write
    answering_ids: tuple[int, ...] = ()  # after an ID change: which of the new and old IDs answer now
    new_rate_answers: bool | None = None  # after a baud change: it answered at the new rate at once
    new_rate_error: str | None = None  # the port could not be reopened at the new rate

    @property
    def verified(self) -> bool:
        """True if the image read back after the write equals the one planned."""
        return self.read_back is not None and self.read_back == self.plan.after


async def _read_image(line: Line, servo_id: int) -> Eeprom | None:
    try:
        return await line.request(protocol.ReadEeprom(servo_id))
    except ReplyError:
        return None


class _Progress:
    """How far one write got, for telling what a failure left behind."""

    def __init__(self) -> None:
        self.sending = False  # the write command has gone (or is going) out
        self.acknowledged = False  # the servo answered it (or did not have to): the read-back is next
        self.read_back: Eeprom | None = None  # the image read back, when one was


async def write_eeprom_plan(
    line: Line,
    plan: EepromPlan,
    *,
    allow_baud_change: bool = False,
    allow_id_change: bool = False,
) -> EepromWriteResult:
    """Write ``plan`` on ``line`` (after the checks of :meth:`EepromPlan.refusal`, with
    ``allow_baud_change`` and ``allow_id_change``) and verify it by reading back.

    The write goes at the rate the plan was made at (``plan.baud``): a line at
    another rate is reopened there for it, and returned to its own rate when
    the write ends, however it ends (see :func:`back_at_rate`).

    Raises:
        InvalidArgument: a field the plan changes is outside the reference's range (nothing written).
        UnsafeOperation: the write is refused, or the servo's image changed since the plan (nothing written).
        VerifyError: the image read back differs, or the servo answers neither at its old nor its new ID / rate.
        ReplyError: the servo does not answer the write.
        BusClosed, PortLost: the line is closed or its port is gone.
    """
    home = int(line.baudrate)
    try:
        return await _write(line, plan, allow_baud_change, allow_id_change, _Progress())
    finally:
        await back_at_rate(line, home)


async def back_at_rate(line: Line, baud: int) -> None:
    """Reopen ``line`` at ``baud`` if it is at another (work that moved it has ended, however).

    It runs to its end (:data:`RETURN_BOUND` seconds at most) even when the
    caller is cancelled meanwhile, and a cancellation that came is raised
    after.  A line that is closed, or lost meanwhile, is left as it is (one
    that reconnects comes back at the rate it was lost at), and a reopen that
    fails is not raised: the line's next request fails, as its own error.
    """

    async def back() -> None:
        with contextlib.suppress(IcsError, OSError):
            if line.is_open and int(line.baudrate) != baud:
                await line.reopen(baudrate=baud)

    await despite_cancellation(back, RETURN_BOUND)


async def _write(
    line: Line, plan: EepromPlan, allow_baud_change: bool, allow_id_change: bool, progress: _Progress
) -> EepromWriteResult:
    reason = plan.refusal(allow_baud_change=allow_baud_change, allow_id_change=allow_id_change)
    if reason:
        raise UnsafeOperation(f"{reason}; nothing was written")
    # A plan is a plain dataclass: one not made by plan_eeprom_write has its changes checked here, as replace()
    # checks them (InvalidArgument), so what goes out is within the reference's ranges.
    command = protocol.WriteEeprom(plan.servo_id, plan.after, current=plan.before)
    if not plan.diff:
        return EepromWriteResult(plan, written=False, read_back=plan.before)
    if int(line.baudrate) != plan.baud:  # planned at the servo's own rate: written and verified there
        await line.reopen(baudrate=plan.baud)
    now = await line.request(protocol.ReadEeprom(plan.servo_id))
    if now != plan.before:
        raise UnsafeOperation(
            f"servo {plan.servo_id}'s EEPROM changed since it was read ({now.diff(plan.before)}); nothing was written"
        )
    acknowledged = True
    progress.sending = True
    try:
        await line.request(command)
    except ReplyTimeout:
        # A servo may take a new ID or rate before acknowledging; the read-back decides.
        if not (plan.changes_id or plan.changes_baud):
            raise
        acknowledged = False
    progress.acknowledged = True
    ids = (plan.after.servo_id, plan.servo_id) if plan.changes_id else (plan.servo_id,)
    answering, read_back = await _ask(line, ids)
    new_rate_answers: bool | None = None
    new_rate_error: str | None = None
    if plan.changes_baud:
        new_rate_answers, at_new, new_rate_error = await _ask_at(line, int(plan.after.baud_rate), ids)
        read_back = read_back if read_back is not None else at_new
    result = EepromWriteResult(
        plan, True, acknowledged, read_back, answering if plan.changes_id else (), new_rate_answers, new_rate_error
    )
    progress.read_back = read_back
    if read_back is None:
        # Most often the servo's power or cable went mid-write: say what it may hold and what to do, in the
        # words a person reads on the command line and the configurator alike.
        asked = " and as ".join(f"ID {i}" for i in ids)
        rates = f", at {plan.baud} and at {int(plan.after.baud_rate)} baud" if plan.changes_baud else ""
        heard = "acknowledged the EEPROM write" if acknowledged else "did not acknowledge the EEPROM write"
        raise VerifyError(
            f"servo {plan.servo_id} {heard}, then did not answer its read-back (asked as {asked}{rates}): "
            "written, not verified; check its power and cable, then read it again"
        )
    if read_back != plan.after:
        raise VerifyError(f"servo {plan.servo_id}: EEPROM read back differs: {read_back.diff(plan.after)}")
    return result


async def _ask(line: Line, ids: tuple[int, ...]) -> tuple[tuple[int, ...], Eeprom | None]:
    """Which of ``ids`` answer an EEPROM read, and the first image read."""
    answering: list[int] = []
    first: Eeprom | None = None
    for i in ids:
        image = await _read_image(line, i)
        if image is not None:
            answering.append(i)
            first = image if first is None else first
    return tuple(answering), first


async def _ask_at(line: Line, baud: int, ids: tuple[int, ...]) -> tuple[bool | None, Eeprom | None, str | None]:
    """Ask ``ids`` at another rate, then return the line to its own rate."""
    home = int(line.baudrate)
    try:
        await line.reopen(baudrate=int(BaudRate.parse(baud)))
    except (IcsError, OSError) as exc:
        return None, None, str(exc)
    try:
        answering, image = await _ask(line, ids)
    finally:
        await line.reopen(baudrate=home)
    return bool(answering), image, None


class WriteOutcome(enum.Enum):
    """What one servo's EEPROM holds after a write of several, as far as can be told."""

    VERIFIED = "written and verified"
    UNCHANGED = "already matched: nothing written"
    NOT_WRITTEN = "not written"
    UNKNOWN = "unknown: the line failed (or Ctrl-C came) while the write was on its way"
    UNVERIFIED = "written, not verified: the line failed (or Ctrl-C came) before the read-back"
    DIFFERS = "written, but the image read back differs"


@dataclass(frozen=True)
class ServoWriteReport:
    """One servo's part in :func:`write_eeprom_plans`."""

    plan: EepromPlan
    outcome: WriteOutcome
    result: EepromWriteResult | None = None  # the finished write (VERIFIED, UNCHANGED)
    error: IcsError | None = None  # what stopped this servo's write (the first failure only)


async def write_eeprom_plans(
    line: Line,
    plans: Sequence[EepromPlan],
    *,
    allow_baud_change: bool = False,
    allow_id_change: bool = False,
    on_report: Callable[[ServoWriteReport], None] | None = None,
) -> list[ServoWriteReport]:
    """Write ``plans`` in order (each as :func:`write_eeprom_plan`), one report per plan.

    A servo's failure is not raised: it ends the batch, its report says how
    far that write got and carries the error, and every later servo is
    NOT_WRITTEN.  So a line lost in the middle of a restore still tells which
    servos hold their new image.  ``on_report`` hears each report as it is
    made; when the batch is cancelled (Ctrl-C) it still hears every servo's
    (the one being written: as far as it got) before the cancellation goes on.
    ``allow_baud_change`` and ``allow_id_change`` apply to every plan.  Each
    plan is written at its own rate (``plan.baud``); a batch that reopened the
    line at another rate returns it to the rate it had when it ends, however it
    ends, cancelled too (:func:`back_at_rate`): a line lost meanwhile is not
    reopened, and comes back at the rate it was at when it was lost.
    """
    reports: list[ServoWriteReport] = []
    home = int(line.baudrate)

    def add(report: ServoWriteReport) -> None:
        reports.append(report)
        if on_report is not None:
            on_report(report)

    failed = False
    try:
        for n, plan in enumerate(plans):
            if failed:
                add(ServoWriteReport(plan, WriteOutcome.NOT_WRITTEN))
                continue
            progress = _Progress()
            try:
                result = await _write(line, plan, allow_baud_change, allow_id_change, progress)
            except IcsError as exc:
                failed = True
                add(ServoWriteReport(plan, _failed_outcome(progress), error=exc))
                continue
            except BaseException:  # cancelled mid-write: account for every servo, then stay cancelled
                add(ServoWriteReport(plan, _failed_outcome(progress)))
                for rest in plans[n + 1 :]:
                    add(ServoWriteReport(rest, WriteOutcome.NOT_WRITTEN))
                raise
            outcome = WriteOutcome.VERIFIED if result.written else WriteOutcome.UNCHANGED
            add(ServoWriteReport(plan, outcome, result))
    finally:
        # Every servo's report is made: a line that cannot go back is the caller's next failure, not theirs.
        await back_at_rate(line, home)
    return reports


def _failed_outcome(progress: _Progress) -> WriteOutcome:
    if progress.acknowledged:
        # The read-back answered and differs, or the line failed before it could.
        return WriteOutcome.DIFFERS if progress.read_back is not None else WriteOutcome.UNVERIFIED
    if progress.sending:
        return WriteOutcome.UNKNOWN
    return WriteOutcome.NOT_WRITTEN
