"""Lining up every outcome (stream slots, requests) with the simulator's log entry of that transaction.

The bus runs transactions strictly one at a time, in the order the
simulator logs them, so:

* stream transactions are the position commands with an even, non-zero
  target (requests only ever send odd positions or FREE), and frame ``c``
  holds one outcome per ID it tried: the n-th stream outcome of ID ``i``
  belongs to the n-th stream log entry addressed to ``i``; a frame the consumer never took (skipped: on the
  burst path a loop held up while the executor ran several cycles is fed them at once, and takes the last
  frame; a loaded machine's slow consumer too) has its cycle's entries set aside unchecked, told by the
  stream's order of IDs, none for an ID held back there (see :meth:`LogMatcher.add_frame`); an
  offline ID's probe is a stretch read (a guard read's bytes), so a frame's failed probe has no stream entry,
  nor has a failed ID the frame says was sent nothing (``not_sent``: held back after a failure);
* a request is the only one in flight for its servo ID (the workers take an
  ID at a time), and two requests in a row to one ID never send the same
  bytes, so the request log entries of ID ``i`` split into runs of equal
  ``tx``, one run per request (one entry per attempt: retries resend it);
* the bus's own guard reads (a stretch or speed read after a timeout, see
  ``ics35_async.engine.guard``) are told by their bytes: the workloads never send those.
"""

from __future__ import annotations

import math
import statistics
from array import array
from collections import Counter, deque
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

from ics35_async import (
    Frame,
)
from ics35_async.sim import (
    VirtualLine,
)

from .oracle import GUARD_TXS, CheckError, Verdict, WirePredictor


def percentile(values: Sequence[float], p: float) -> float:
    if not values:
        return 0.0
    ordered = sorted(values)
    k = min(len(ordered) - 1, max(0, math.ceil(len(ordered) * p / 100) - 1))
    return ordered[k]


@dataclass(slots=True)
class RequestRecord:
    """One finished request: what was sent, how many attempts it could make, how it ended."""

    servo_id: int
    tx: bytes
    attempts_allowed: int
    ok: bool
    value: Any
    error: str | None
    typed: bool  # a value or an IcsError (anything else escaped the library)
    done_time: float  # time.monotonic(), the clock of frame timestamps
    log_mark: int  # sim.transactions when it finished: its entries are all below this


SKIPPED = None
"""An entry set aside in :meth:`LogMatcher.match`: its cycle's frame was skipped (see :class:`SkippedBefore`)."""


@dataclass(frozen=True, slots=True)
class SkippedBefore:
    """The outcomes never seen of the cycles whose frames were skipped before the frame of the cycle the log shows
    as ``cycle`` (see :meth:`LogMatcher.add_frame`): an ID's entries of earlier cycles are theirs, however many."""

    cycle: int


Outcome = tuple[bool, Any, float] | SkippedBefore | None

REALTIME_LAG = 8
"""Transactions the log may trail a request's outcome by when the simulator answers on a real port."""


@dataclass
class MatchCounts:
    entries: int = 0
    stream_entries: int = 0
    request_entries: int = 0
    stream_outcomes: int = 0
    requests: int = 0
    faulted_entries: int = 0
    fault_kinds: Counter[str] = field(default_factory=Counter)
    accepted: int = 0
    misattributed: int = 0  # a value the bytes of that very transaction did not carry
    valid_rejected: int = 0  # the bytes formed a valid reply but the bus failed the transaction
    error_class_differs: int = 0  # a request failed, but not with the error its bytes call for
    undetectable_corruptions: int = 0  # accepted, carried by the bytes, but differs from the servo's answer
    undetectable_without_corrupt_fault: int = 0
    stale_accepted: int = 0  # another transaction's late reply taken as this one's (same length and header)
    late_reply_to_own_retry: int = 0  # a request's late first reply arriving during (and taken by) its retry
    guards: int = 0  # guard reads the bus inserted after a timeout
    noise_accepted: int = 0  # a truncated reply completed by noise bytes into a valid-looking one
    noise_after_reply: int = 0  # real time: a whole reply taken before the noise behind it came (see LogMatcher)
    untyped_outcomes: int = 0
    extra_attempts: int = 0  # more attempts than the request's retries allow
    predicted_errors: int = 0  # transactions whose bytes call for an error
    cancelled_queued: int = 0  # cancelled before any attempt reached the wire
    cancelled_in_flight: int = 0  # cancelled with an attempt on the wire (or between attempts)
    skipped_cycle_entries: int = 0  # stream entries of cycles whose frame was skipped: no outcome to check
    failed_probes: int = 0  # offline IDs' probes that failed (in a frame's failed, with no stream entry)
    held_back: int = 0  # stream slots the engine held back after a failure (a frame's not_sent: no stream entry)
    examples: list[str] = field(default_factory=list)
    serious_examples: int = 0  # the first of examples: what a failed check is about, kept ahead of the rest

    def note(self, text: str, *, serious: bool = False) -> None:
        """Keep ``text`` among the examples: ten of each kind, the ``serious`` ones (what fails a check: a reply
        misattributed, an untyped outcome) first, so that ten notes of what is only counted cannot crowd out the
        one a failed check needs."""
        if serious:
            if self.serious_examples < 10:
                self.examples.insert(self.serious_examples, text)
                self.serious_examples += 1
        elif len(self.examples) - self.serious_examples < 10:
            self.examples.append(text)


class LogMatcher:
    """Lines up stream and request outcomes with the simulator's log, entry by entry.

    ``is_stream`` tells a stream transaction from a request by its bytes.
    Call :meth:`drain` to take new log entries (in order, never skipping),
    :meth:`add_frame` and :meth:`add_request` as outcomes come, and
    :meth:`match` to pair what can be paired.

    ``realtime``: the simulator answers through a real port (a pty), where the bytes of one
    transaction may arrive in several reads, and an outcome may come before the simulator's thread
    has logged its command (requests are then matched once :data:`REALTIME_LAG` more are logged).
    The predictor judges the bytes as one piece, as the
    in-process line delivers them; across a port, noise on the idle line after a whole reply may
    come after the bus has taken the reply, so what the bytes without the noise call for is then
    right too (counted as ``noise_after_reply``, then checked as any accepted reply).
    """

    def __init__(
        self,
        sim: VirtualLine,
        is_stream: Callable[[bytes], bool],
        ids: Iterable[int],
        track_stream: bool = True,
        *,
        realtime: bool = False,
    ) -> None:
        self.sim = sim
        self.realtime = realtime
        self.without_noise: dict[int, Verdict] = {}  # realtime: seq -> what its bytes call for without the noise
        self.is_stream = is_stream
        self.track_stream = track_stream
        self.predictor = WirePredictor(sim.baudrate, sim.echo)
        self.next_seq: int | None = None
        self.first_seq = 0
        # (seq, verdict, value, fault, tx, the cycle the log shows it in: see drain) of each stream transaction not
        # yet matched with a frame's outcome
        self.stream_entries: dict[int, deque[tuple[int, Verdict, Any, str | None, bytes, int]]] = {
            i: deque() for i in ids
        }
        # Per ID, each stream outcome (ok, value, when) in cycle order, or SkippedBefore for cycles whose frames were
        # skipped
        self.stream_outcomes: dict[int, deque[Outcome]] = {i: deque() for i in ids}
        # A cycle sends its IDs in the stream's order (``ids``, the order the stream was given them), so an entry
        # whose ID comes no later in it than the entry before begins the next cycle.
        self._slot = {sid: k for k, sid in enumerate(self.stream_outcomes)}
        self._log_cycle, self._last_slot = 1, -1
        self._frame_log_cycle = 0  # the log's cycle of the last frame added
        # Per ID, its last stream entry paired with an outcome: (tx, whether the bus took a value; None: skipped)
        self.last_stream: dict[int, tuple[bytes, bool | None]] = {}
        self.last_cycle = 0  # of the frames added
        self.offline: frozenset[int] = frozenset()  # the IDs offline in the last frame added
        self.request_entries: dict[int, deque[tuple[int, bytes, Verdict, Any, str | None]]] = {
            i: deque() for i in range(32)
        }
        self.requests: dict[int, deque[RequestRecord]] = {i: deque() for i in range(32)}
        self.counts = MatchCounts()
        # Per log entry (index seq - first_seq): 1 = the bus got a value, 0 = it did not, -1 = unmatched.
        self.ok = array("b")
        self.when = array("d")  # loop time of the accepted reply (ok entries only)
        self.faults: list[tuple[int, str]] = []
        self.previous: dict[int, str] = {}  # seq -> short description, for the last few entries

    # -- feeding

    def drain(self) -> int:
        """Take every log entry the simulator has appended since the last call."""
        log = self.sim.log
        taken = 0
        predict = self.predictor.predict
        counts = self.counts
        while log:
            t = log.popleft()
            if self.next_seq is None:
                self.next_seq = self.first_seq = t.seq
            if t.seq != self.next_seq:
                raise CheckError(f"log entries {self.next_seq}..{t.seq - 1} were lost (log_size too small?)")
            self.next_seq += 1
            verdict = predict(t)
            if self.realtime and self.predictor.noise:
                received = verdict.received
                self.without_noise[t.seq] = self.predictor.judge(
                    t.tx, received[: len(received) - len(self.predictor.noise)]
                )
            self.previous[t.seq] = f"{t.command} to ID {t.servo_id} {t.tx.hex(' ')}, fault {t.fault}"
            self.previous.pop(t.seq - 4096, None)
            self.ok.append(-1)
            self.when.append(0.0)
            counts.entries += 1
            if not verdict.ok:
                counts.predicted_errors += 1
            if t.fault:
                counts.faulted_entries += 1
                counts.fault_kinds.update(t.fault.split("+"))
                self.faults.append((t.seq, t.fault))
            sid = t.servo_id
            if sid is None:
                raise CheckError(f"seq {t.seq}: a transaction addressed to no servo ({t.command})")
            if t.tx in GUARD_TXS:
                # A guard read the bus put between a timed-out command and its twin (see ics35_async.engine.guard):
                # no caller asked for it. Its outcome is what its bytes call for.
                counts.guards += 1
                if not verdict.ok:
                    self.ok[-1] = 0  # a failed guard (it took the late bytes) counts as a failed transaction
            elif self.is_stream(t.tx):
                counts.stream_entries += 1
                if self.track_stream:
                    slot = self._slot.get(sid, -1)
                    if slot <= self._last_slot:
                        self._log_cycle += 1
                    self._last_slot = slot
                    self.stream_entries[sid].append((t.seq, verdict, t.value, t.fault, t.tx, self._log_cycle))
            else:
                counts.request_entries += 1
                self.request_entries[sid].append((t.seq, t.tx, verdict, t.value, t.fault))
            taken += 1
        return taken

    def add_frame(self, frame: Frame) -> None:
        """The outcomes of ``frame``'s cycle, after those of the cycles before it whose frames were skipped.

        A skipped cycle's outcomes are unknown, but not which log entries are its.  A cycle sends its IDs in the
        stream's order, so the log shows where each cycle begins (an entry whose ID comes no later than the one
        before it), and the skipped cycles' entries are an ID's before this frame's cycle, however many: one each,
        as the burst path runs them (a burst runs on past a cycle's end only with every ID in the cycle), or none
        for an ID held back after a failure, as a frame skipped on the ordinary path (a loaded machine) may have.
        Those entries are set aside unchecked.  (The log's cycles and the stream's agree while every cycle sends
        something and no two run into each other: a frame taken whose cycle sent nothing, every ID held or
        offline, is counted as such; a skipped one that sent nothing, or two cycles of which the first sent only
        IDs later in the order than every one the second sent, would put them apart.  With the soak's 32 IDs
        and a few failures a cycle neither has been seen.)

        An ID offline as the cycle began (in the frame before: a burst never runs with one offline, so never
        across a skipped cycle) was probed, if at all, with a stretch read, which the log shows as a guard read:
        the frame lists it as failed if the probe failed, and that outcome has no stream entry.
        """
        outcomes = self.stream_outcomes
        skipped = frame.cycle - self.last_cycle - 1  # (frame.skipped, counted from the stream's first cycle)
        self.last_cycle = frame.cycle
        if skipped > 0:
            tried = set(frame.positions) | frame.failed
            if self.offline:  # (a burst never runs with one offline: these cycles were not one burst's)
                raise CheckError(
                    f"frame of cycle {frame.cycle}: {skipped} cycle(s) before it skipped after a frame with "
                    f"{sorted(self.offline)} offline: the skipped cycles' log entries cannot be told apart"
                )
            if tried != set(outcomes):
                raise CheckError(
                    f"frame of cycle {frame.cycle}: {skipped} cycle(s) before it skipped, and it tried "
                    f"{sorted(tried)}, not every ID: the skipped cycles' log entries cannot be told apart"
                )
            for sid in tried:
                outcomes[sid].append(SkippedBefore(self._frame_log_cycle + skipped + 1))
        probing = self.offline  # (the IDs offline in the frame before: their probes are no stream entries)
        sent = bool(frame.positions) or any(s not in frame.not_sent and s not in probing for s in frame.failed)
        self._frame_log_cycle += skipped + (1 if sent else 0)
        stamps = frame.timestamps
        for sid, position in frame.positions.items():
            outcomes[sid].append((True, position, stamps[sid]))
        probed, self.offline = self.offline, frame.offline
        for sid in frame.failed:
            if sid in probed:
                self.counts.failed_probes += 1
            elif sid in frame.not_sent:  # held back after a failure: sent nothing, so no log entry
                self.counts.held_back += 1
            else:
                outcomes[sid].append((False, None, 0.0))
                self.counts.stream_outcomes += 1
        self.counts.stream_outcomes += len(frame.positions)

    def add_request(self, record: RequestRecord) -> None:
        self.requests[record.servo_id].append(record)
        self.counts.requests += 1
        if not record.typed:
            self.counts.untyped_outcomes += 1
            self.counts.note(f"untyped outcome for {record.tx.hex(' ')}: {record.error}", serious=True)

    # -- pairing

    def _settle(
        self,
        seq: int,
        verdict: Verdict,
        clean: Any,
        fault: str | None,
        ok: bool,
        value: Any,
        when: float,
        retry_of_previous: bool = False,
    ) -> None:
        counts = self.counts
        k = seq - self.first_seq
        self.ok[k] = 1 if ok else 0
        quiet = self.without_noise.pop(seq, None)
        misfit = not verdict.ok or verdict.value != value
        if ok and misfit and quiet is not None and quiet.ok and quiet.value == value:
            counts.noise_after_reply += 1  # taken before the noise came (see the class): judged without it
            verdict = quiet
        if ok:
            self.when[k] = when
            counts.accepted += 1
            if not verdict.ok or verdict.value != value:
                counts.misattributed += 1
                counts.note(
                    f"seq {seq}: bus returned {value!r}, the bytes {verdict.received.hex(' ')} "
                    f"call for {verdict.value if verdict.ok else verdict.error} (fault {fault})",
                    serious=True,
                )
            elif verdict.source == "stale" and retry_of_previous:
                # The late reply of this request's previous attempt, taken by its retry: the same
                # request's answer, correctly attributed.
                counts.late_reply_to_own_retry += 1
            elif verdict.source == "stale":
                # The bytes in the reply's place were another transaction's late reply (this one's
                # own reply was lost): the servo's answer to another command handed out as this one.
                counts.stale_accepted += 1
                counts.note(
                    f"seq {seq}: accepted {value!r} from an earlier, late reply; the servo answered {clean!r} "
                    f"to this one (fault {fault}; after seq {seq - 1}: {self.previous.get(seq - 1, '?')})",
                    serious=True,
                )
            elif verdict.source == "noise":
                counts.noise_accepted += 1
                counts.note(
                    f"seq {seq}: accepted {value!r}, made of reply and noise bytes; the servo answered "
                    f"{clean!r} (fault {fault})"
                )
            elif value != clean:
                counts.undetectable_corruptions += 1
                if not fault or "corrupt" not in fault:
                    counts.undetectable_without_corrupt_fault += 1
                    counts.note(f"seq {seq}: accepted {value!r}, servo answered {clean!r}, fault {fault}")
        elif verdict.ok:
            counts.valid_rejected += 1
            counts.note(f"seq {seq}: valid reply {verdict.received.hex(' ')} rejected (fault {fault})")

    def match(self, final: bool = False) -> None:
        for sid, entries in self.stream_entries.items():
            outcomes = self.stream_outcomes[sid]
            while entries and outcomes:
                if isinstance(outcomes[0], SkippedBefore):
                    if entries[0][5] >= outcomes[0].cycle:  # the skipped cycles' entries are all set aside
                        outcomes.popleft()
                        continue
                    outcome: Outcome = SKIPPED
                else:
                    outcome = outcomes.popleft()
                seq, verdict, clean, fault, tx, _cycle = entries.popleft()
                if outcome is SKIPPED:
                    self.counts.skipped_cycle_entries += 1
                    self.last_stream[sid] = (tx, None)
                    continue
                assert not isinstance(outcome, SkippedBefore)
                ok, value, when = outcome
                self.last_stream[sid] = (tx, ok)
                self._settle(seq, verdict, clean, fault, ok, value, when)
            if outcomes and final:
                raise CheckError(f"ID {sid}: {len(outcomes)} stream outcomes with no log entry")
        # (real time: an outcome may come before the simulator's thread has logged its command, but not
        # after the line has run a few more transactions)
        drained_to = (self.next_seq or 0) - (REALTIME_LAG if self.realtime else 0)
        for sid, records in self.requests.items():
            attempts = self.request_entries[sid]
            while records and (records[0].log_mark <= drained_to or final):
                self._match_request(records.popleft(), attempts)
            if final and attempts:
                raise CheckError(f"ID {sid}: {len(attempts)} request log entries with no request")

    def _match_request(
        self, record: RequestRecord, entries: deque[tuple[int, bytes, Verdict, Any, str | None]]
    ) -> None:
        """A request's attempts are the run of its ID's request entries with its bytes (the next differs)."""
        counts = self.counts
        run = []
        while entries and entries[0][1] == record.tx:
            run.append(entries.popleft())
        if len(run) > record.attempts_allowed:
            counts.extra_attempts += 1
            counts.note(f"request {record.tx.hex(' ')} to ID {record.servo_id}: {len(run)} attempts")
        cancelled = record.error == "CancelledError"
        if cancelled:
            if run:
                counts.cancelled_in_flight += 1
            else:
                counts.cancelled_queued += 1
            for seq, _tx, _verdict, _clean, _fault in run:
                self.ok[seq - self.first_seq] = 0  # the engine finished it and dropped the reply
            return
        if not run:
            if record.ok or record.error not in ("BusClosed", "PortLost", "ClosedByPortLoss"):
                raise CheckError(
                    f"request {record.tx.hex(' ')} to ID {record.servo_id} ({'ok' if record.ok else record.error}) "
                    f"has no log entry; next entries: {[(e[0], e[1].hex(' ')) for e in list(entries)[:3]]}"
                )
            return
        for k, (seq, _tx, verdict, clean, fault) in enumerate(run):
            last = k == len(run) - 1
            if last and record.ok:
                retry_of_previous = k > 0 and run[k - 1][0] == seq - 1
                self._settle(seq, verdict, clean, fault, True, record.value, record.done_time, retry_of_previous)
            else:
                self._settle(seq, verdict, clean, fault, False, None, 0.0)
            if (
                last
                and not record.ok
                and verdict.error != record.error
                and record.error not in ("BusClosed", "PortLost", "ClosedByPortLoss")
            ):
                counts.error_class_differs += 1
                counts.note(f"seq {seq}: request failed with {record.error}, its bytes call for {verdict.error}")

    # -- results

    def recovery(self) -> dict[str, Any]:
        """Per fault: failed transactions until the next value, and the line's outage in loop time."""
        ok, when = self.ok, self.when
        n = len(ok)
        next_ok = [n] * (n + 1)
        for k in range(n - 1, -1, -1):
            next_ok[k] = k if ok[k] == 1 else next_ok[k + 1]
        prev_ok = [-1] * n
        last = -1
        for k in range(n):
            prev_ok[k] = last
            if ok[k] == 1:
                last = k
        lost: list[int] = []
        outage: list[float] = []
        by_kind: dict[str, list[int]] = {}
        by_kind_ms: dict[str, list[float]] = {}
        cut_off = 0  # faults in the last transactions, with no answered one after them in the run
        for seq, fault in self.faults:
            k = seq - self.first_seq
            j = next_ok[k]
            if j >= n:
                cut_off += 1  # the consistency check after the run shows the line recovered from these too
                continue
            lost.append(j - k)
            p = prev_ok[k]
            ms = (when[j] - when[p]) * 1e3 if p >= 0 else float("nan")
            if p >= 0:
                outage.append(ms)
            for kind in fault.split("+"):
                by_kind.setdefault(kind, []).append(j - k)
                if p >= 0:
                    by_kind_ms.setdefault(kind, []).append(ms)
        return {
            "faults": len(self.faults),
            "cut_off_at_end": cut_off,
            "failed_txns_median": statistics.median(lost) if lost else 0,
            "failed_txns_max": max(lost, default=0),
            "outage_ms_median": statistics.median(outage) if outage else 0.0,
            "outage_ms_p99": percentile(outage, 99),
            "outage_ms_max": max(outage, default=0.0),
            "by_kind": {
                kind: {
                    "n": len(v),
                    "failed_txns_median": statistics.median(v),
                    "failed_txns_max": max(v),
                    "outage_ms_median": statistics.median(by_kind_ms.get(kind, [0.0])),
                    "outage_ms_max": max(by_kind_ms.get(kind, [0.0])),
                }
                for kind, v in sorted(by_kind.items())
            },
        }
