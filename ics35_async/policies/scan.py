"""Finding servos: which IDs answer at which baud rates, told apart from garbled replies.

A probe is a stretch *read* (harmless: it moves nothing), sent as a
:class:`~ics35_async.protocol.ProbeRead`: the bus waits for it only as long
as this link's answers have taken (see :mod:`ics35_async.engine.probe`), not
the adapter's worst case, since most probed IDs are empty.  Each ID is probed
once; a policy-level retry would only double the cost of every empty slot.
Two exceptions: an ID whose reply came back garbled is probed again, to tell
noise (answers the second time) from two servos sharing the ID (garbled
again); and if any reply came garbled or wrong, or any bytes arrived after
a probe had given up (a servo slower than the probes waited lands in the
next probe, or between probes), every silent ID is probed again with the
normal allowance first, so a slow servo is never taken for an empty ID.
The last probe has nothing after it to catch its late reply, so a silent
last ID is always read once more with the normal allowance.
That rule is :func:`ask_each`, for any command sent to IDs that are mostly
empty: "free all" (:func:`~ics35_async.policies.free_servos` with
``every_servo``) frees by it too.

Before probing a rate's IDs one by one, an ID *read* (which every device at
that rate answers) asks whether anyone is there at all: a rate where nothing
answers costs one transaction instead of one per ID.

On a line that does not enforce baud rates (a pty, some bridges) a servo
answers at every rate.  Its EEPROM names its real rate, and the per-unit
calibration bytes tell one servo heard at several rates from several servos,
so each servo is listed once.  An EEPROM reply carries no checksum, so an
image counts only when two reads agree (a flipped bit would otherwise make
one servo look like two), and reads are retried on a noisy line.  Where a
servo's EEPROM names a rate it was not heard at, it is asked there again
(the probes at its own rate may all have been lost).  Once one servo has
answered at two rates, the line is known to ignore rates: a servo is then
listed at its EEPROM's rate only, and an answer whose image could not be
read adds no entry beside the servo read under that ID.  An ID none of
whose images could be read is listed once, ``rate_unconfirmed``.

A search of the other rates after nothing answered at a line's own
(:func:`device_rates`, :func:`search_other_rates`, :func:`servo_rates`) asks each rate once: it only
needs to hear whether anything answers there, and a retry at a silent rate
would cost two whole allowances more (the retry, and the guard read before
it).  Each ask keeps the line's whole allowance: nothing has answered to
learn a shorter wait from, and a link slow enough to need a long one (a
bridge) delays a reply at every rate alike.  ``on_rate`` hears each rate as
it is tried, so that a person waiting sees why.

A link known not to carry the baud rate at all (``socket://``: the far end
keeps its own settings) is probed once, at the first rate asked for: every
other rate would be the same line again.  Its servos are listed at the rate
their EEPROM names when it was read.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
from collections.abc import Awaitable, Callable, Collection, Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import anyio

from .. import protocol
from ..eeprom import BaudRate, Eeprom
from ..errors import BusClosed, IcsError, InvalidArgument, PortLost, ReplyError
from ..protocol import Param
from ..protocol.wire import ALL_BAUDS as ALL_BAUDS  # (re-exported: policies.ALL_BAUDS)
from ..protocol.wire import ALL_IDS as ALL_IDS
from ..tasks import task_group
from ..transports import PortBusy, PortNotFound, PortPermissionDenied, SerialPortError, carries_line_settings
from ..units import check_int
from .failure_kinds import Line, LineOpener, echo_setting_wrong, nothing_came_back
from .scan_units import (
    FoundServo,
    confirm_eeprom_rates,
    one_unit_at_several_rates,
    read_eeprom_or_error,
    read_missing_images,
    servos_of,
)

# Below this many IDs the ID read's longer allowance costs more than the probes it can save.
ID_READ_MIN_IDS = 8

ProbeCallback = Callable[[int], None]  # called with the number of IDs just finished
RateCallback = Callable[[int], object]  # called with the baud rate a search of other rates tries next
FoundCallback = Callable[[int, int], object]  # called with (ID, baud) as an ID answers a probe at that rate


def trying_rate(line_baud: int, baud: int, previous: int | None = None) -> str:
    """What a search of the other rates (``on_rate``) tells a person as it tries ``baud``, nothing having answered
    at the line's rate ``line_baud``: each rate may cost a whole reply allowance, so the wait is said.  ``previous``:
    the other rate tried just before, if any (only whether there was one is said).  The search asks every rate, a
    rate that answered included, so a later one is said as tried "too", not after "no answer" (a line saying the
    line's rate again would read as if the rate before had been skipped)."""
    if previous is None:
        return f"no answer at {line_baud} baud: trying {baud} baud ..."
    return f"trying {baud} baud too ..."


@dataclass(frozen=True)
class RateScan:
    """What probing some IDs at one baud rate found."""

    baud: int
    answered: tuple[int, ...] = ()
    garbled: Mapping[int, ReplyError] = field(default_factory=dict)  # ID -> the error of its last probe
    silent: bool = False  # not one byte came back at this rate, not even the echo of what was sent
    nobody: bool = False  # nothing answered the ID read, so no ID was probed one by one
    echo_evidence: ReplyError | None = None  # an error showing the line's echo setting is wrong
    id_answer: int | None = None  # the ID a device gave to the ID read (None: not asked, or no clean answer)
    lost: IcsError | None = None  # the line was lost part-way (in a scan's report; probe_ids raises it)
    # None of the IDs probed answered, but a device answers the ID read: at an ID not probed (asked by a scan of
    # some IDs only; id_answer, its ID where one device gave it)
    elsewhere: bool = False

    @property
    def only_id_read(self) -> bool:
        """A device answered the ID read, but no probed ID the stretch read (nor garbled), and it is not known to be
        at an ID that was not probed (``elsewhere``)."""
        return self.id_answer is not None and not self.answered and not self.garbled and not self.elsewhere


@dataclass(frozen=True)
class ScanReport:
    """What a scan over several baud rates found."""

    servos: tuple[FoundServo, ...]
    rates: tuple[RateScan, ...]  # the rates probed, in order
    skipped: Mapping[int, str] = field(default_factory=dict)  # baud -> why the port would not open at it
    rate_blind: bool = False  # the link does not carry the baud rate (socket://): probed once, at the first rate
    lost: IcsError | None = None  # the line was lost part-way: ``servos`` are those found before it

    @property
    def garbled(self) -> list[tuple[int, int, ReplyError]]:
        """(baud, ID, error) of every probe that stayed garbled."""
        return [(r.baud, i, e) for r in self.rates for i, e in sorted(r.garbled.items())]

    @property
    def silent(self) -> bool:
        """Nothing came back at any rate probed, not even an echo: the adapter or its wiring."""
        return bool(self.rates) and all(r.silent for r in self.rates)

    @property
    def echo_evidence(self) -> ReplyError | None:
        """An error showing that the echo setting is wrong for this interface, if any."""
        return next((r.echo_evidence for r in self.rates if r.echo_evidence is not None), None)


def _done(on_probe: ProbeCallback | None, n: int) -> None:
    if on_probe is not None and n:
        on_probe(n)


async def _probe(line: Line, servo_id: int, *, short: bool = True) -> ReplyError | None:
    """A stretch read at ``servo_id``: with ``short``, the bus's probe allowance (see engine.probe)."""
    command = protocol.ProbeRead(servo_id) if short else protocol.SecondLookRead(servo_id)
    try:
        await line.request(command, retries=0)
    except ReplyError as exc:
        return exc
    return None


def _garbled(outcomes: Mapping[int, ReplyError | None]) -> dict[int, ReplyError]:
    """The probes that got something back, but not a valid reply."""
    return {i: e for i, e in outcomes.items() if e is not None and not nothing_came_back(e)}


def _late_evidence(line: Line) -> tuple[int, int, int]:
    """What grows when an answer comes after its wait: stray bytes, late replies, and replies that
    came wrong (another transaction's, a guard's) rather than not at all."""
    stats = line.stats
    total = stats.total
    return stats.stray_bytes, stats.late_replies, total.partial_replies + total.echo_mismatches + total.bad_replies


# ``ask(servo_id, short)`` asks one ID: ``short``, with the bus's probe allowance and no retry; else once
# more with the normal allowance.  It returns the error, or None when the ID answered.
Ask = Callable[[int, bool], Awaitable[ReplyError | None]]


async def ask_each(
    line: Line, wanted: Sequence[int], ask: Ask
) -> tuple[dict[int, ReplyError | None], ReplyError | None]:
    """Ask each of ``wanted`` once, short, all queued at once (the line runs them back to back in this
    order), then ask again those whose answer the short wait may have missed or that came back garbled
    (see the module: the rule that makes a silent ID an empty one, not a slow servo's).

    Returns each ID's outcome (``None``: it answered; a :func:`nothing_came_back` error: nothing is
    there) and the error showing the echo setting wrong, if one did (then no garbled ID is asked again).

    Raises:
        BusClosed, PortLost: the line is closed or its port is gone (what was answered before is lost
            with the outcomes: an ``ask`` that must keep it keeps it itself).
    """
    outcomes: dict[int, ReplyError | None] = dict.fromkeys(wanted)
    late_before = _late_evidence(line)

    async def first(i: int) -> None:
        outcomes[i] = await ask(i, True)

    async with task_group() as group:
        for i in wanted:
            group.start_soon(first, i)
    last = wanted[-1] if wanted else None
    if last is not None and outcomes[last] is not None and nothing_came_back(outcomes[last]):  # type: ignore[arg-type]
        # The last ID's late reply would land after every other ID's: wait for it with the normal
        # allowance (a guard read goes first and takes any late bytes, see engine.guard).
        outcomes[last] = await ask(last, False)
    silent_ids = [i for i, e in outcomes.items() if e is not None and nothing_came_back(e)]
    garbled = _garbled(outcomes)
    if silent_ids and (garbled or _late_evidence(line) != late_before):
        # Bytes came after a short wait had given up (as strays, in a guard, or garbling a later
        # transaction): some servo may answer slower than the short waits.  Every silent ID once
        # more with the normal allowance, so none is taken for empty.
        for i in silent_ids:
            outcomes[i] = await ask(i, False)
        garbled = _garbled(outcomes)
    evidence = next((e for e in garbled.values() if echo_setting_wrong(e, line.echo)), None)
    if garbled and evidence is None:
        # Once more, after the line has settled: noise answers cleanly now, a shared ID does not.
        for i in sorted(garbled):
            outcomes[i] = await ask(i, False)
    return outcomes, evidence


async def _id_read(line: Line) -> int | ReplyError:
    try:
        return await line.request(protocol.LineIdRead(), retries=0)
    except ReplyError as exc:
        return exc


async def anyone_there(line: Line) -> bool:
    """Whether any device at the line's rate answers an ID read (garbled counts: several answer)."""
    result = await _id_read(line)
    return not isinstance(result, ReplyError) or not nothing_came_back(result)


async def probe_ids(
    line: Line,
    ids: Iterable[int] = ALL_IDS,
    *,
    id_read_first: bool | None = None,
    on_probe: ProbeCallback | None = None,
    concurrency: int = 32,
) -> RateScan:
    """Probe ``ids`` at the line's current rate: which answer, which answer garbled.

    ``id_read_first`` (default: when 8 or more IDs are probed) first asks the
    whole line with an ID read and probes no ID when nothing answers it.
    ``concurrency`` bounds how many probes are queued at once (the line still
    runs them one at a time), leaving room for other callers.  ``on_probe``
    hears each probe's outcome as it comes (for a progress display).

    Raises:
        InvalidArgument: an ID is not 0..31 or ``concurrency`` is not 1..32.
        BusClosed, PortLost: the line is closed or its port is gone.
    """
    gate = anyio.Semaphore(check_int("concurrency", concurrency, 1, 32))
    wanted = [protocol.check_id(i) for i in ids]
    rate = await _probe_rate(line, wanted, gate, id_read_first, on_probe, None)
    if rate.lost is not None:
        raise rate.lost
    return rate


async def _probe_rate(
    line: Line,
    wanted: list[int],
    gate: anyio.Semaphore,
    id_read_first: bool | None,
    on_probe: ProbeCallback | None,
    on_found: FoundCallback | None,
) -> RateScan:
    """:func:`probe_ids`, but a line lost part-way is returned (``lost``) with the IDs that answered before it;
    ``on_found(id, baud)`` hears each ID the first time it answers."""
    heard: list[int] = []
    baud = int(line.baudrate)

    def answered(i: int) -> None:
        if i not in heard:
            heard.append(i)
            if on_found is not None:
                on_found(i, baud)

    try:
        return await _probe_all(line, wanted, gate, id_read_first, on_probe, answered)
    except (BusClosed, PortLost) as exc:
        return RateScan(int(line.baudrate), answered=tuple(i for i in wanted if i in heard), lost=exc)


async def _probe_all(
    line: Line,
    wanted: list[int],
    gate: anyio.Semaphore,
    id_read_first: bool | None,
    on_probe: ProbeCallback | None,
    answered: Callable[[int], None],
) -> RateScan:
    """The body of :func:`probe_ids`; ``answered(id)`` hears each answer as it comes (a first look's or a second's)."""
    rx_before = line.stats.total.bytes_rx
    if id_read_first is None:
        id_read_first = len(wanted) >= ID_READ_MIN_IDS
    id_answer: int | None = None
    if id_read_first:
        result = await _id_read(line)
        error = result if isinstance(result, ReplyError) else None
        id_answer = None if isinstance(result, ReplyError) else result
        nobody = error is not None and nothing_came_back(error)
        if nobody or (error is not None and echo_setting_wrong(error, line.echo)):
            # Nobody there, or every probe would fail the same way: the echo setting is wrong.
            _done(on_probe, len(wanted))
            silent = line.stats.total.bytes_rx == rx_before
            return RateScan(int(line.baudrate), silent=silent, nobody=nobody, echo_evidence=None if nobody else error)

    # The first look at each ID: at most ``concurrency`` queued at once, each counted for the progress display.
    async def probe(i: int, short: bool) -> ReplyError | None:
        if not short:
            error = await _probe(line, i, short=False)
        else:
            async with gate:
                error = await _probe(line, i)
            _done(on_probe, 1)
        if error is None:
            answered(i)
        return error

    outcomes, evidence = await ask_each(line, wanted, probe)
    garbled = _garbled(outcomes)
    return RateScan(
        int(line.baudrate),
        answered=tuple(i for i, e in outcomes.items() if e is None),
        garbled=garbled,
        silent=line.stats.total.bytes_rx == rx_before,
        echo_evidence=evidence,
        id_answer=id_answer,
    )


def _check_bauds(bauds: Iterable[int]) -> list[int]:
    checked: list[int] = []
    for baud in bauds:
        value = int(BaudRate.parse(baud))
        if value not in checked:
            checked.append(value)
    if not checked:
        raise InvalidArgument("no baud rate to scan")
    return checked


async def _open_or_skip(
    stack: contextlib.AsyncExitStack, open_at: LineOpener, baud: int, skipped: dict[int, IcsError]
) -> Line | None:
    """The line at ``baud`` (closed with ``stack``), or None and the reason in ``skipped``
    when the adapter cannot do that rate."""
    try:
        return await stack.enter_async_context(open_at(baud))
    except (PortNotFound, PortPermissionDenied, PortBusy):
        raise  # the same at every rate: the caller reports it
    except (InvalidArgument, SerialPortError) as exc:
        if isinstance(exc, SerialPortError) and exc.errno in (errno.ENOTTY, errno.EISDIR):
            raise  # not a serial port (a file, a directory): the same at every rate
        skipped[baud] = exc
        return None


async def scan(
    open_at: LineOpener,
    *,
    bauds: Iterable[int] = ALL_BAUDS,
    ids: Iterable[int] = ALL_IDS,
    read_eeprom: bool = True,
    on_probe: ProbeCallback | None = None,
    on_found: FoundCallback | None = None,
) -> ScanReport:
    """Probe ``ids`` at each of ``bauds``, opening the line at each rate with ``open_at(baud)``.

    With ``read_eeprom`` every servo found has its EEPROM read; without it,
    only servos answering at several rates do (their EEPROM says which is
    theirs).  A rate the port cannot be opened at is skipped (``skipped``);
    a missing port, a denied permission, a busy port or a path that is no serial port raises, and so does
    the first rate's error when no rate opened at all (a refused bridge, a
    malformed port name: nothing about the rates).  ``on_probe`` hears each
    probe's outcome as it comes; ``on_found(id, baud)`` hears each ID as it
    first answers at a rate, before its EEPROM is read (so that a scan cut
    short, cancelled, loses no servo it had found: on a pty, which ignores
    rates without saying so, one servo is heard at every rate, where the report
    lists it once).

    With ``ids`` fewer than every ID, a rate where none of them answers (nor comes
    back garbled) gets one ID read, unless the probes' own ID read was answered
    (by one device: it gave its ID): a device answering it at an ID not asked sets
    ``elsewhere`` on that rate's report (it costs one ID command's allowance where
    nothing answers).

    A line lost part-way (its port gone, the bus closed) does not cost what was
    found before it: the report lists those servos (an EEPROM not read by then
    is ``None``) and holds the loss in ``lost``; the rates after it are not
    probed.

    Raises:
        InvalidArgument: a bad baud rate or ID.
        SerialPortError: the port is missing, denied or busy, or no rate could be opened (before any was probed).
    """
    rates_wanted = _check_bauds(bauds)
    wanted = [protocol.check_id(i) for i in ids]
    rates: list[RateScan] = []
    skipped: dict[int, IcsError] = {}
    images: dict[tuple[int, int], Eeprom | ReplyError] = {}
    rate_blind = False
    lost: IcsError | None = None
    for baud in rates_wanted:
        if rate_blind or lost is not None:
            _done(on_probe, len(wanted))  # the same line again, or none: nothing to learn
            continue
        async with contextlib.AsyncExitStack() as stack:
            try:
                line = await _open_or_skip(stack, open_at, baud, skipped)
            except (SerialPortError, BusClosed, PortLost) as exc:  # (PortLost: a line reopened at each rate)
                if not rates:
                    raise
                lost = exc  # it opened before: the port went away between two rates
                continue
            if line is None:
                _done(on_probe, len(wanted))
                continue
            rate_blind = not carries_line_settings(getattr(line, "port", None))
            rate = await _probe_rate(line, wanted, anyio.Semaphore(32), None, on_probe, on_found)
            if len(set(wanted)) < len(ALL_IDS):
                rate = await check_other_ids(line, rate, wanted)
            rates.append(rate)
            lost = rate.lost
            if read_eeprom and lost is None:
                lost = await _read_images(line, baud, rate.answered, images)
    if len(skipped) == len(rates_wanted):
        raise skipped[rates_wanted[0]]
    hits: dict[int, list[int]] = {}
    for rate in rates:
        for i in rate.answered:
            hits.setdefault(i, []).append(rate.baud)
    if lost is None:
        try:
            await read_missing_images(open_at, hits, images)
            if not rate_blind:
                await confirm_eeprom_rates(open_at, hits, images, [r.baud for r in rates])
        except (SerialPortError, BusClosed, PortLost) as exc:
            lost = exc
    ignores_rates = rate_blind or one_unit_at_several_rates(hits, images)
    servos = [servo for i, at in sorted(hits.items()) for servo in servos_of(i, at, images, ignores_rates)]
    if rate_blind:  # the rate opened at says nothing: the EEPROM's is the servo's own
        servos = [dataclasses.replace(s, baud=s.eeprom_baud or s.baud) for s in servos]
    reasons = {baud: str(exc) for baud, exc in skipped.items()}
    listed = tuple(sorted(servos, key=lambda s: (s.servo_id, s.baud)))
    return ScanReport(listed, tuple(rates), reasons, rate_blind, lost)


def _none_there(rate: RateScan, echo: bool) -> bool:
    """None of the IDs probed at this rate answered, cleanly or not, on a line that is heard (with ``echo``, a
    line where not even the echo came back is the adapter's or the wiring's, not the IDs')."""
    heard = not (rate.silent and echo)
    return heard and not (rate.answered or rate.garbled or rate.nobody or rate.echo_evidence or rate.lost)


async def check_other_ids(line: Line, rate: RateScan, wanted: Collection[int]) -> RateScan:
    """``rate`` (what :func:`probe_ids` found of ``wanted`` on ``line``) with ``elsewhere`` where none of ``wanted``
    answered, cleanly or not, on a line that is heard, but a device at an ID not in ``wanted`` answers the ID read,
    and ``id_answer`` its ID where one device gave it (several at once answer it garbled): the line and its rate
    are right, the IDs asked are not.  One ID read, asked unless the probes' own was answered with an ID (a device
    answering it as an ID that was probed is ``only_id_read``: not elsewhere); none where something of ``wanted``
    answered.  A line lost meanwhile is ``lost``, as a probe's loss is in a scan's report."""
    if not _none_there(rate, line.echo):
        return rate
    answer: int | ReplyError | None = rate.id_answer
    if answer is None:
        try:
            answer = await _id_read(line)
        except (BusClosed, PortLost) as exc:
            return dataclasses.replace(rate, lost=exc)  # (the scan's loss, as a probe's: not "nobody answered")
    if isinstance(answer, ReplyError):
        return rate if nothing_came_back(answer) else dataclasses.replace(rate, elsewhere=True)
    if answer in wanted:  # (a device answering only the ID read: the report's note names it)
        return dataclasses.replace(rate, id_answer=answer)
    return dataclasses.replace(rate, elsewhere=True, id_answer=answer)


async def _read_images(
    line: Line, baud: int, ids: Iterable[int], images: dict[tuple[int, int], Eeprom | ReplyError]
) -> IcsError | None:
    """Read the EEPROM of each of ``ids`` into ``images``; the line's loss, if it was lost (the rest unread)."""
    try:
        for i in ids:
            images[(baud, i)] = await read_eeprom_or_error(line, i)
    except (BusClosed, PortLost) as exc:
        return exc
    return None


async def _rates_where(
    open_at: LineOpener,
    bauds: Iterable[int],
    answers: Callable[[Line, int], Awaitable[bool]],
    on_rate: RateCallback | None,
    tried: list[int] | None = None,
    not_tried: list[int] | None = None,
) -> tuple[int, ...]:
    """The rates among ``bauds`` at which ``answers(line, baud)`` is True, the line opened there with
    ``open_at(baud)`` (``on_rate(baud)`` told first, and the rate added to ``tried`` once its ask has run to its
    end).  A rate the port cannot be opened at is left out (added to ``not_tried``); an ask that raises ends the
    search with its error, that rate and those after it added to ``not_tried`` (no answer could come back from
    them: they were not asked).  On a line that ignores rates none is offered, nor added to either (every rate is
    the far end's one rate)."""
    found: list[int] = []
    skipped: dict[int, IcsError] = {}
    asked: list[int] = []
    checked = _check_bauds(bauds)
    try:
        for baud in checked:
            async with contextlib.AsyncExitStack() as stack:
                line = await _open_or_skip(stack, open_at, baud, skipped)
                if line is None:
                    continue
                if not carries_line_settings(getattr(line, "port", None)):
                    return ()
                if on_rate is not None:
                    on_rate(baud)
                answered = await answers(line, baud)
                asked.append(baud)
                if tried is not None:
                    tried.append(baud)
                if answered:
                    found.append(baud)
    except BaseException:
        if not_tried is not None:
            not_tried.extend(baud for baud in checked if baud not in asked)
        raise
    if not_tried is not None:
        not_tried.extend(skipped)
    return tuple(found)


@dataclass(frozen=True)
class RateSearch:
    """What :func:`search_other_rates` found, after nothing answered at the rates ``asked``."""

    asked: tuple[int, ...]  # the rates nothing answered at before the search (a line's own, or a scan's)
    # The other rates asked, in order: not one the port cannot be opened at, nor any on a link that does not
    # carry the rate (``socket://``, where every rate is the far end's one).
    tried: tuple[int, ...] = ()
    found: tuple[int, ...] = ()  # those a device answers the ID read at, the one to use first

    def nothing_elsewhere(self) -> str | None:
        """The search's outcome in words when it tried rates and found nothing at any (``nor any device at 625000
        or 1250000 baud``, to follow what did not answer at the line's rate); None otherwise."""
        if self.found or not self.tried:
            return None
        return f"nor any device at {rates_in_words(self.tried)} baud"


def rates_in_words(rates: Sequence[int], joined_by: str = "or", *, grouped: bool = False) -> str:
    """``rates`` as a sentence names them: ``625000 or 1250000``, ``115200, 625000 or 1250000`` (``joined_by``:
    the word before the last, "or" or "and"; ``grouped``: thousands set apart, ``625,000``, as a page writes them)."""
    *first, last = (f"{rate:,}" if grouped else str(rate) for rate in rates)
    return f"{', '.join(first) + f' {joined_by} ' if first else ''}{last}"


async def search_other_rates(
    open_at: LineOpener, asked: Iterable[int], *, on_rate: RateCallback | None = None
) -> RateSearch:
    """After nothing answered at the rates ``asked``: the other rates (of :data:`ALL_BAUDS`) at which some device
    answers the ID read, as :func:`device_rates` looks for them, and which rates were tried.

    ``open_at`` and ``on_rate`` as for :func:`device_rates` (each rate tried may cost a whole reply allowance:
    a person waiting is told which, and afterwards :meth:`RateSearch.nothing_elsewhere` says they were tried).

    Raises:
        InvalidArgument: a rate in ``asked`` is no ICS rate.
    """
    done = tuple(_check_bauds(asked))
    others = other_bauds(done)
    tried: list[int] = []
    found = await _rates_where(open_at, others, _anyone_at, on_rate, tried) if others else ()
    return RateSearch(done, tuple(tried), found)


def other_bauds(asked: Iterable[int]) -> list[int]:
    """The ICS rates (:data:`ALL_BAUDS`, in its order) other than ``asked``: where to look for a servo or device
    after nothing answered at the rates asked."""
    done = set(asked)
    return [rate for rate in ALL_BAUDS if rate not in done]


async def _anyone_at(line: Line, baud: int) -> bool:
    return await anyone_there(line)


async def device_rates(
    open_at: LineOpener, bauds: Iterable[int], *, on_rate: RateCallback | None = None
) -> tuple[int, ...]:
    """The rates among ``bauds`` at which some device answers the ID read (garbled counts: several answer).

    For advice after nothing answered at a line's rate, where no servo ID is known (an ID write).
    ``open_at(baud)`` opens the line at a rate, as for :func:`scan`; ``on_rate(baud)`` is told each rate as it
    is tried (each costs a whole reply allowance where nothing answers: see the module's search rule).
    """

    return await _rates_where(open_at, bauds, _anyone_at, on_rate)


async def servo_rates(
    open_at: LineOpener,
    servo_id: int,
    bauds: Iterable[int],
    *,
    on_rate: RateCallback | None = None,
    tried: list[int] | None = None,
    not_tried: list[int] | None = None,
) -> tuple[int, ...]:
    """The rates among ``bauds`` at which ``servo_id`` answers and its EEPROM names that rate.

    For advice after a servo did not answer: a rate is offered only when the
    servo's own EEPROM agrees with it, never one its EEPROM contradicts (on a
    line that ignores rates a servo answers at all of them).  ``open_at(baud)``
    opens the line at a rate, as for :func:`scan`; ``on_rate`` as for
    :func:`device_rates`.  The servo is asked once at each rate (see the module's search rule); one that
    answers has its EEPROM read until two reads agree (see :func:`~.scan_units.read_eeprom_agreed`).
    ``tried`` gets each rate whose ask ran to its end; ``not_tried`` each rate that could not be asked (the port
    not opened at it, or an ask that raised, which ends the search with its error: that rate and those after it).

    Raises:
        InvalidArgument: ``servo_id`` is not 0..31.
    """
    servo_id = protocol.check_id(servo_id)

    async def answers(line: Line, baud: int) -> bool:
        try:
            await line.request(protocol.ReadParam(servo_id, Param.STRETCH), retries=0)
        except ReplyError:
            return False
        image = await read_eeprom_or_error(line, servo_id)
        return isinstance(image, Eeprom) and int(image.baud_rate) == baud

    return await _rates_where(open_at, bauds, answers, on_rate, tried, not_tried)
