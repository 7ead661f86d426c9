"""Reliability soak runs: chaos, cancellation, unplug/replug and fuzzing, with figures.

    .venv/bin/python benchmarks/soak.py             # every part at full size (``make soak``)
    .venv/bin/python benchmarks/soak.py --quick     # every part, small (about 20 s)
    .venv/bin/python benchmarks/soak.py --only chaos,fuzz --transactions 200000 --seed 3

Prints one markdown table (check, result, target met) and exits 1 if a
target is missed; ``--json FILE`` keeps every figure.  The full run takes
about 6.5 minutes on two cores.  Parts (the test suite runs short versions
of each: tests/test_reliability.py, tests/test_fuzz.py):

chaos
    A 32-servo position stream plus concurrent mixed requests (positions,
    parameter reads and writes, EEPROM reads and writes, a silent memory
    read) on the in-process simulator in fast mode, with about 2 % of the
    transactions faulted, every fault kind mixed.  Every outcome (each
    stream slot of each frame, each request) is matched to the simulator's
    own log entry of that transaction, and checked against what the bus
    had to conclude from the bytes the simulator actually sent (see
    :class:`WirePredictor`).  Reports misattributed replies, requests that
    never completed, outcomes that were not a value or a typed error, the
    recovery after each fault, and throughput against a fault-free run of
    the same workload measured in the same process.
cancel
    Random cancellations of in-flight and queued requests and of whole
    streams, then a consistency check (every servo answers correctly, bus
    idle, nothing queued, counters consistent).
unplug
    The pty simulator's device disappears mid-stream and comes back at the
    same path, with and without ``reconnect=True``.  Measures the time from
    the device's return to the first new frame; counts tasks and file
    descriptors before and after.
fuzz
    Hypothesis draws batches of byte streams; every stream goes through
    every command's reply parser (and the stream's fast path), and through
    the bus's framing as the reply of a real transaction on a fuzzing
    WireDevice double.  Only typed errors, a value exactly when the bytes
    form a valid reply, and a clean device answers correctly afterwards.

Matching outcomes to the log (chaos).  The bus runs transactions strictly
one at a time, in the order the simulator logs them, so:

* stream transactions are the position commands with an even, non-zero
  target (requests only ever send odd positions or FREE), and frame ``c``
  holds one outcome per ID it tried: the n-th stream outcome of ID ``i``
  belongs to the n-th stream log entry addressed to ``i``;
* a request is the only one in flight for its servo ID (the workers take an
  ID at a time), and two requests in a row to one ID never send the same
  bytes, so the request log entries of ID ``i`` split into runs of equal
  ``tx``, one run per request (one entry per attempt: retries resend it);
* the bus's own guard reads (a stretch or speed read after a timeout, see
  ``Bus._guard``) are told by their bytes: the workloads never send those.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import dataclasses
import functools
import json
import logging
import math
import os
import random
import statistics
import subprocess
import sys
import threading
import time
from array import array
from collections import Counter, deque
from collections.abc import Awaitable, Callable, Iterable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

from ics35_async import (
    Bus,
    BusTiming,
    Eeprom,
    Frame,
    IcsError,
    PortLost,
    Priority,
    ReplyError,
    Servo,
    open_bus,
    protocol,
)
from ics35_async.protocol import Command, Param, decode_request
from ics35_async.sim import (
    FaultConfig,
    FaultInjector,
    Transaction,
    VirtualLine,
    VirtualServo,
    start_subprocess,
    stop_subprocess,
)

FAULT_KINDS = ("drop", "truncate", "corrupt", "msb", "late", "noise", "echo")
FAST_TIMING = BusTiming(adapter_latency=0.003, quiet_time=0.001, eeprom_write=0.005)
"""Bus timing for the fast-mode simulator: replies arrive at once, so a short allowance is enough."""


def fault_spec(rate: float, kinds: Sequence[str] = FAULT_KINDS) -> str:
    """A spec giving every kind the same rate so that about ``rate`` of transactions get a fault."""
    if rate <= 0:
        return "none"
    each = 1 - (1 - rate) ** (1 / len(kinds))
    return ",".join(f"{kind}:{each:.6f}" for kind in kinds)


def percentile(values: Sequence[float], p: float) -> float:
    if not values:
        return 0.0
    ordered = sorted(values)
    k = min(len(ordered) - 1, max(0, math.ceil(len(ordered) * p / 100) - 1))
    return ordered[k]


class CheckError(AssertionError):
    """The log and the outcomes cannot be lined up: the checker (or the bus) lost track."""


# ====================================================================== what the bus must conclude


@functools.lru_cache(maxsize=1 << 16)
def _decode(tx: bytes, baudrate: int) -> Command[Any]:
    framed = decode_request(tx, baudrate=baudrate)
    if framed is None or framed[0] is None or framed[1] != len(tx):
        raise CheckError(f"the log holds bytes that are not one whole command: {tx.hex(' ')}")
    return framed[0]


@dataclass(frozen=True, slots=True)
class Verdict:
    """What the bus must make of one transaction: a value (``ok``) or an error of class ``error``.

    ``source`` says where the bytes in the reply's place came from: ``"own"``
    (this transaction's reply, possibly damaged in place), ``"stale"`` (they
    include the held-back reply of an earlier transaction) or ``"noise"``
    (they include noise bytes, e.g. after a truncated reply).
    """

    ok: bool
    value: Any
    error: str | None
    received: bytes
    source: str = "own"


class WirePredictor:
    """Rebuilds, from the simulator's log, the bytes the bus received for each transaction.

    In fast mode the simulator answers each host write with one chunk:
    the echo (as damaged by an ``echo`` fault), then a reply held back by a
    ``late`` fault of the previous transaction, then this transaction's
    reply (none if it is held back itself), then ``noise``.  The log keeps
    all the parts (``echo``, ``extra`` = held reply + noise, ``reply``,
    ``clean_reply``), so the chunk, and therefore the one right conclusion,
    follow.  Feed every logged transaction, in order, to :meth:`predict`.
    """

    def __init__(self, baudrate: int, echo: bool = True) -> None:
        self.baudrate = baudrate
        self.echo = echo
        self.held = b""

    def predict(self, t: Transaction) -> Verdict:
        held, self.held = self.held, b""
        faults = t.fault.split("+") if t.fault else ()
        if "late" in faults:
            own = b""
            self.held = t.clean_reply
        else:
            own = t.reply
        if not t.extra.startswith(held):
            raise CheckError(f"seq {t.seq}: the held-back reply {held.hex()} is not where expected: {t.extra.hex()}")
        noise = t.extra[len(held) :]
        received = t.echo + held + own + noise
        verdict = self.judge(t.tx, received)
        if verdict.ok:
            # The reply's place starts right after the echo (intact, since the verdict is ok).
            if held:
                verdict = dataclasses.replace(verdict, source="stale")
            elif len(own) < len(received) - len(t.echo):
                verdict = dataclasses.replace(verdict, source="noise")
        return verdict

    def judge(self, tx: bytes, received: bytes) -> Verdict:
        """The bus's rules, as documented: exact length, echo first, then the codec's checks."""
        command = _decode(tx, self.baudrate)
        echo_len = len(tx) if self.echo else 0
        expected = echo_len + command.reply_len
        n = len(received)
        if n > expected:
            return Verdict(False, None, "BadReply", received)
        if n == expected:
            if received[:echo_len] != tx[:echo_len]:
                return Verdict(False, None, "EchoMismatch", received)
            try:
                value = command.parse(received[echo_len:])
            except ReplyError as exc:
                return Verdict(False, None, type(exc).__name__, received)
            return Verdict(True, value, None, received)
        m = min(n, echo_len)
        if received[:m] != tx[:m]:
            return Verdict(False, None, "EchoMismatch", received)
        if n <= echo_len:
            return Verdict(False, None, "ReplyTimeout", received)
        return Verdict(False, None, "PartialReply", received)


# ====================================================================== chaos: matching outcomes to the log

_GUARD_TXS = frozenset(protocol.ReadParam(i, p).tx for i in range(32) for p in (Param.STRETCH, Param.SPEED))
"""The bytes of the bus's guard reads; the workloads here never send them themselves."""


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
    untyped_outcomes: int = 0
    extra_attempts: int = 0  # more attempts than the request's retries allow
    predicted_errors: int = 0  # transactions whose bytes call for an error
    cancelled_queued: int = 0  # cancelled before any attempt reached the wire
    cancelled_in_flight: int = 0  # cancelled with an attempt on the wire (or between attempts)
    examples: list[str] = field(default_factory=list)

    def note(self, text: str) -> None:
        if len(self.examples) < 10:
            self.examples.append(text)


class LogMatcher:
    """Lines up stream and request outcomes with the simulator's log, entry by entry.

    ``is_stream`` tells a stream transaction from a request by its bytes.
    Call :meth:`drain` to take new log entries (in order, never skipping),
    :meth:`add_frame` and :meth:`add_request` as outcomes come, and
    :meth:`match` to pair what can be paired.
    """

    def __init__(
        self, sim: VirtualLine, is_stream: Callable[[bytes], bool], ids: Iterable[int], track_stream: bool = True
    ) -> None:
        self.sim = sim
        self.is_stream = is_stream
        self.track_stream = track_stream
        self.predictor = WirePredictor(sim.baudrate, sim.echo)
        self.next_seq: int | None = None
        self.first_seq = 0
        self.stream_entries: dict[int, deque[tuple[int, Verdict, Any, str | None]]] = {i: deque() for i in ids}
        self.stream_outcomes: dict[int, deque[tuple[bool, Any, float]]] = {i: deque() for i in ids}
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
            if t.tx in _GUARD_TXS:
                # A guard read the bus put between a timed-out command and its twin (see Bus._guard):
                # no caller asked for it. Its outcome is what its bytes call for.
                counts.guards += 1
                if not verdict.ok:
                    self.ok[-1] = 0  # a failed guard (it took the late bytes) counts as a failed transaction
            elif self.is_stream(t.tx):
                counts.stream_entries += 1
                if self.track_stream:
                    self.stream_entries[sid].append((t.seq, verdict, t.value, t.fault))
            else:
                counts.request_entries += 1
                self.request_entries[sid].append((t.seq, t.tx, verdict, t.value, t.fault))
            taken += 1
        return taken

    def add_frame(self, frame: Frame) -> None:
        outcomes = self.stream_outcomes
        stamps = frame.timestamps
        for sid, position in frame.positions.items():
            outcomes[sid].append((True, position, stamps[sid]))
        for sid in frame.failed:
            outcomes[sid].append((False, None, 0.0))
        self.counts.stream_outcomes += len(frame.positions) + len(frame.failed)

    def add_request(self, record: RequestRecord) -> None:
        self.requests[record.servo_id].append(record)
        self.counts.requests += 1
        if not record.typed:
            self.counts.untyped_outcomes += 1
            self.counts.note(f"untyped outcome for {record.tx.hex(' ')}: {record.error}")

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
        if ok:
            self.when[k] = when
            counts.accepted += 1
            if not verdict.ok or verdict.value != value:
                counts.misattributed += 1
                counts.note(
                    f"seq {seq}: bus returned {value!r}, the bytes {verdict.received.hex(' ')} "
                    f"call for {verdict.value if verdict.ok else verdict.error} (fault {fault})"
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
                    f"to this one (fault {fault}; after seq {seq - 1}: {self.previous.get(seq - 1, '?')})"
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
                seq, verdict, clean, fault = entries.popleft()
                ok, value, when = outcomes.popleft()
                self._settle(seq, verdict, clean, fault, ok, value, when)
            if outcomes and final:
                raise CheckError(f"ID {sid}: {len(outcomes)} stream outcomes with no log entry")
        drained_to = self.next_seq or 0
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
            if record.ok or record.error not in ("BusClosed", "PortLost"):
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
                and record.error not in ("BusClosed", "PortLost")
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


# ====================================================================== chaos: the workload


def band(i: int) -> tuple[int, int]:
    """Positions servo ``i`` is sent to (stream: even targets; requests: odd positions)."""
    low = 4000 + 200 * i
    return low, low + 150


def is_stream_tx(tx: bytes) -> bool:
    if len(tx) != 3 or tx[0] & 0xE0 != protocol.CMD_POSITION:
        return False
    position = (tx[1] << 7) | tx[2]
    return position != protocol.FREE and position % 2 == 0


def stream_target(i: int, cycle: int) -> int:
    low, high = band(i)
    middle, amplitude = (low + high) // 2, (high - low) // 2 - 2
    return 2 * ((middle + round(amplitude * math.sin(cycle / 15 + i))) // 2)


def random_request(
    rng: random.Random, bus: Bus, sid: int, image: Eeprom
) -> tuple[Command[Any], Callable[[], Awaitable[Any]], int]:
    """A random request to ``sid``: its command (for the bytes), how to make it, attempts allowed."""
    priority = rng.choice(list(Priority))
    servo = Servo(bus, sid, priority=priority)
    roll = rng.random()
    default_attempts = 1 + bus.retries
    if roll < 0.25:
        low, high = band(sid)
        position = rng.randrange(low + 1, high, 2)
        return (
            protocol.Position(sid, position, baudrate=bus.baudrate),
            lambda: servo.set_position(position),
            default_attempts,
        )
    if roll < 0.33:
        return protocol.Position(sid, protocol.FREE, baudrate=bus.baudrate), servo.free, default_attempts
    if roll < 0.55:
        # Current and temperature only: the bus's own guard reads (after a timeout) read stretch or
        # speed, so those bytes in the log are always a guard, never a caller's request.
        param = rng.choice((Param.CURRENT, Param.TEMPERATURE))
        reader = servo.read_current if param is Param.CURRENT else servo.read_temperature
        return protocol.ReadParam(sid, param), reader, default_attempts
    if roll < 0.70:
        # Straight to the bus, with its own priority and retries.
        cmd: Command[Any] = protocol.ReadParam(sid, rng.choice((Param.CURRENT, Param.TEMPERATURE)))
        retries = rng.randrange(3)
        return cmd, lambda: bus.request(cmd, priority=priority, retries=retries), 1 + retries
    if roll < 0.88:
        param = Param(rng.randrange(1, 5))
        low, high = protocol.WRITE_RANGES[param]
        if param is Param.TEMPERATURE:
            high = 80  # a limit this hot (smaller is hotter) never trips: the servos keep their torque
        value = rng.randint(low, high)
        writer = {
            Param.STRETCH: servo.write_stretch,
            Param.SPEED: servo.write_speed,
            Param.CURRENT: servo.write_current_limit,
            Param.TEMPERATURE: servo.write_temperature_limit,
        }[param]
        return protocol.WriteParam(sid, param, value), lambda: writer(value), default_attempts
    if roll < 0.97:
        return protocol.ReadEeprom(sid), servo.read_eeprom, default_attempts
    if roll < 0.995:
        write = protocol.WriteEeprom(sid, image)  # not idempotent: never retried
        return write, lambda: bus.request(write, priority=priority, retries=2), 1
    # A servo has no generic memory: it stays silent, the caller gets a timeout.
    silent = protocol.ReadMemory(sid, rng.randrange(100), rng.randrange(1, 8))
    return silent, lambda: bus.request(silent, priority=priority, retries=0), 1


@dataclass
class WorkloadStats:
    frames: int = 0
    skipped_frames: int = 0
    requests_issued: int = 0
    requests_done: int = 0
    requests_ok: int = 0
    requests_failed: Counter[str] = field(default_factory=Counter)


class ChaosWorkload:
    """Stream + request workers on one bus, feeding a :class:`LogMatcher`."""

    def __init__(self, sim: VirtualLine, bus: Bus, seed: int, workers: int, request_pause: float) -> None:
        self.sim = sim
        self.bus = bus
        self.seed = seed
        self.workers = workers
        self.request_pause = request_pause
        self.ids = list(range(32))
        self.matcher = LogMatcher(sim, is_stream_tx, self.ids)
        self.never_completed = 0
        self.stats = WorkloadStats()
        self.stop = False
        self.busy: set[int] = set()
        self.last_tx: dict[int, bytes] = {}
        self.images = {i: sim.servo(i).eeprom for i in self.ids}

    async def worker(self, k: int) -> None:
        rng = random.Random(self.seed * 1000 + k)
        stats = self.stats
        while not self.stop:
            free = [i for i in self.ids if i not in self.busy]
            sid = rng.choice(free)
            self.busy.add(sid)
            cmd, call, attempts = random_request(rng, self.bus, sid, self.images[sid])
            while cmd.tx == self.last_tx.get(sid):  # two requests in a row to one ID never look alike
                cmd, call, attempts = random_request(rng, self.bus, sid, self.images[sid])
            self.last_tx[sid] = cmd.tx
            stats.requests_issued += 1
            ok, value, error, typed = False, None, None, True
            try:
                value = await call()
                ok = True
            except IcsError as exc:
                error = type(exc).__name__
            except Exception as exc:  # an untyped error escaped the library: counted, reported
                error, typed = f"{type(exc).__name__}: {exc}", False
            stats.requests_done += 1
            if ok:
                stats.requests_ok += 1
            else:
                stats.requests_failed[error or "?"] += 1
            self.matcher.add_request(
                RequestRecord(sid, cmd.tx, attempts, ok, value, error, typed, time.monotonic(), self.sim.transactions)
            )
            self.busy.discard(sid)
            if self.request_pause and rng.random() < 0.5:
                await asyncio.sleep(rng.uniform(0, self.request_pause))

    async def run(self, transactions: int, drain_every: int = 1) -> float:
        """Run until the simulator has seen ``transactions`` more transactions; returns the seconds taken."""
        sim, bus, matcher = self.sim, self.bus, self.matcher
        stream = bus.stream(self.ids, offline_after=3, probe_interval=0.05)
        stream.set_targets({i: stream_target(i, 0) for i in self.ids})
        start_txns = sim.transactions
        sim.log.clear()  # anything before the run is not ours
        t0 = time.perf_counter()
        async with stream:
            tasks = [asyncio.create_task(self.worker(k), name=f"soak worker {k}") for k in range(self.workers)]
            loop = asyncio.get_running_loop()
            give_up = math.inf
            try:
                # Frames keep coming while the workers finish their last requests: take them all,
                # so that only the cycle cut short by closing the stream has no frame.
                while not (self.stop and all(t.done() for t in tasks)) and loop.time() < give_up:
                    frame = await stream.next_frame()
                    self.stats.frames += 1
                    self.stats.skipped_frames += frame.skipped
                    matcher.add_frame(frame)
                    stream.set_targets({i: stream_target(i, frame.cycle) for i in self.ids})
                    if frame.cycle % drain_every == 0:
                        matcher.drain()
                        matcher.match()
                    if not self.stop and sim.transactions - start_txns >= transactions:
                        self.stop = True
                        give_up = loop.time() + 30
            finally:
                self.stop = True
                pending = [t for t in tasks if not t.done()]
                self.never_completed = len(pending)
                for task in pending:
                    task.cancel()
                for task in tasks:
                    if task.done() and not task.cancelled() and task.exception() is not None:
                        raise task.exception()  # type: ignore[misc]
        elapsed = time.perf_counter() - t0
        matcher.drain()
        matcher.match()
        return elapsed

    def finish(self) -> dict[str, Any]:
        """Match the rest; the last, unfinished cycle of the stream has no frame."""
        matcher = self.matcher
        leftovers = {sid: len(e) for sid, e in matcher.stream_entries.items() if e}
        if any(n > 1 for n in leftovers.values()):
            raise CheckError(f"stream log entries with no frame: {leftovers}")
        for entries in matcher.stream_entries.values():
            entries.clear()
        matcher.match(final=True)
        return {"unfinished_cycle_entries": sum(leftovers.values())}


@dataclass
class ChaosReport:
    transactions: int
    seconds: float
    fault_rate_target: float
    fault_spec: str
    faulted_fraction: float
    fault_kinds: dict[str, int]
    frames: int
    skipped_frames: int
    stream_outcomes: int
    requests: int
    requests_ok: int
    requests_failed: dict[str, int]
    requests_never_completed: int
    untyped_outcomes: int
    misattributed: int
    valid_replies_rejected: int
    error_class_differs: int
    undetectable_corruptions: int
    undetectable_without_corrupt_fault: int
    stale_accepted: int
    late_reply_to_own_retry: int
    guard_reads: int
    noise_accepted: int
    extra_attempts: int
    accepted: int
    recovery: dict[str, Any]
    txn_per_s: float
    ok_txn_per_s: float
    frames_per_s: float
    baseline_txn_per_s: float
    baseline_frames_per_s: float
    throughput_ratio: float
    ok_throughput_ratio: float
    frames_ratio: float
    post_check: dict[str, Any]
    examples: list[str]

    @property
    def passed(self) -> bool:
        return (
            self.misattributed == 0
            and self.requests_never_completed == 0
            and self.untyped_outcomes == 0
            and self.valid_replies_rejected == 0
            and self.undetectable_without_corrupt_fault == 0
            and self.stale_accepted == 0
            and self.extra_attempts == 0
            and self.error_class_differs == 0
            and self.post_check["consistent"]
        )


async def consistency_check(sim: VirtualLine, bus: Bus) -> dict[str, Any]:
    """Faults off; every servo must answer exactly what the simulator holds; the bus idle and its counters sane."""
    sim.faults = FaultInjector(FaultConfig(), 0)
    problems: list[str] = []
    # A reply held back by a `late` fault of the very last transaction lands on the next one: let it.
    with contextlib.suppress(ReplyError):
        await bus.request(protocol.ReadParam(0, Param.STRETCH), retries=1)
    before = bus.stats.total.errors
    for servo in sim.servos:
        i = servo.servo_id
        s = bus.servo(i)
        # Each expected value is read from the servo right after the transaction (left to right).
        for what, got, want in (
            ("stretch", await s.read_stretch(), servo.stretch),
            ("speed", await s.read_speed(), servo.speed),
            ("current limit", await s.write_current_limit(servo.current_limit), servo.current_limit),
            ("eeprom", await s.read_eeprom(), servo.eeprom),
            ("position", await s.free(), servo.position),
        ):
            if got != want:
                problems.append(f"ID {i} {what}: bus says {got!r}, servo holds {want!r}")
        if not servo.calibration_intact:
            problems.append(f"ID {i}: factory calibration bytes changed")
    await bus.wait_idle()
    stats = bus.stats
    if stats.total.errors != before:
        problems.append(f"{stats.total.errors - before} errors on a fault-free line")
    if stats.queued:
        problems.append(f"{stats.queued} requests still queued")
    if stats.total.transactions != sim.transactions:
        problems.append(f"bus counted {stats.total.transactions} transactions, the line saw {sim.transactions}")
    if stats.total.ok + stats.total.errors != stats.total.transactions:
        problems.append(f"ok {stats.total.ok} + errors {stats.total.errors} != {stats.total.transactions}")
    if sum(s.transactions for s in stats.per_id.values()) != stats.total.transactions:
        problems.append("per-ID transaction counts do not add up")
    return {"consistent": not problems, "problems": problems, "resyncs": stats.resyncs}


def chaos_servos() -> list[VirtualServo]:
    servos = []
    for i in range(32):
        servo = VirtualServo(i, position=band(i)[0] + 40)
        servo.stretch, servo.speed = 10 + i, 60 + i  # per-ID values: a reply given to the wrong ID shows
        servos.append(servo)
    return servos


async def chaos_run(
    transactions: int, fault_rate: float, seed: int, workers: int = 4, request_pause: float = 0.002
) -> tuple[ChaosWorkload, float, VirtualLine, Bus, dict[str, Any]]:
    spec = fault_spec(fault_rate)
    sim = VirtualLine(chaos_servos(), faults=spec, seed=seed, log_size=max(100_000, transactions // 4))
    bus = await open_bus(sim, retries=1, timing=FAST_TIMING)
    try:
        workload = ChaosWorkload(sim, bus, seed, workers, request_pause)
        elapsed = await workload.run(transactions)
        extra = workload.finish()
        extra["fault_spec"] = spec
        extra["bus_guards"] = bus.stats.guards
        return workload, elapsed, sim, bus, extra
    except BaseException:
        await bus.aclose()
        raise


async def chaos_soak(
    transactions: int = 1_000_000,
    fault_rate: float = 0.02,
    seed: int = 1,
    baseline_transactions: int | None = None,
    workers: int = 4,
    progress: Callable[[str], None] | None = None,
) -> ChaosReport:
    """The chaos soak: a fault-free baseline, then the faulted run, checked entry by entry."""
    base_n = baseline_transactions if baseline_transactions is not None else max(20_000, transactions // 5)
    if progress:
        progress(f"chaos: fault-free baseline, {base_n} transactions")
    base, base_s, base_sim, base_bus, _ = await chaos_run(base_n, 0.0, seed, workers)
    base_counts = base.matcher.counts
    await base_bus.aclose()
    base_sim.close()
    if base_counts.misattributed or base_counts.valid_rejected:
        raise CheckError(f"fault-free baseline: {base_counts.examples}")
    if progress:
        progress(f"chaos: {transactions} transactions, {fault_rate:.1%} faulted")
    work, seconds, sim, bus, extra = await chaos_run(transactions, fault_rate, seed, workers)
    try:
        post = await consistency_check(sim, bus)
    finally:
        await bus.aclose()
        sim.close()
    if extra["bus_guards"] != work.matcher.counts.guards:
        post["consistent"] = False
        post["problems"].append(
            f"bus counted {extra['bus_guards']} guard reads, the log shows {work.matcher.counts.guards}"
        )
    counts = work.matcher.counts
    recovery = work.matcher.recovery()
    n = counts.entries
    ok_entries = counts.accepted
    base_rate = base_counts.entries / base_s
    base_ok_rate = base_counts.accepted / base_s
    base_frames = base.stats.frames / base_s
    return ChaosReport(
        transactions=n,
        seconds=seconds,
        fault_rate_target=fault_rate,
        fault_spec=extra["fault_spec"],
        faulted_fraction=counts.faulted_entries / n if n else 0.0,
        fault_kinds=dict(counts.fault_kinds),
        frames=work.stats.frames,
        skipped_frames=work.stats.skipped_frames,
        stream_outcomes=counts.stream_outcomes,
        requests=counts.requests,
        requests_ok=work.stats.requests_ok,
        requests_failed=dict(work.stats.requests_failed),
        requests_never_completed=work.never_completed + (work.stats.requests_issued - work.stats.requests_done),
        untyped_outcomes=counts.untyped_outcomes,
        misattributed=counts.misattributed,
        valid_replies_rejected=counts.valid_rejected,
        error_class_differs=counts.error_class_differs,
        undetectable_corruptions=counts.undetectable_corruptions,
        undetectable_without_corrupt_fault=counts.undetectable_without_corrupt_fault,
        stale_accepted=counts.stale_accepted,
        late_reply_to_own_retry=counts.late_reply_to_own_retry,
        guard_reads=counts.guards,
        noise_accepted=counts.noise_accepted,
        extra_attempts=counts.extra_attempts,
        accepted=ok_entries,
        recovery=recovery,
        txn_per_s=n / seconds,
        ok_txn_per_s=ok_entries / seconds,
        frames_per_s=work.stats.frames / seconds,
        baseline_txn_per_s=base_rate,
        baseline_frames_per_s=base_frames,
        throughput_ratio=(n / seconds) / base_rate,
        ok_throughput_ratio=(ok_entries / seconds) / base_ok_rate,
        frames_ratio=(work.stats.frames / seconds) / base_frames,
        post_check=post,
        examples=counts.examples,
    )


# ====================================================================== cancellation


@dataclass
class CancelReport:
    cancellations: int
    requests_cancelled_queued: int
    requests_cancelled_in_flight: int
    streams_cancelled: int
    stream_frames_seen: int
    requests_completed: int
    requests_checked: int
    misattributed: int
    valid_replies_rejected: int
    stream_positions_out_of_band: int
    untyped_outcomes: int
    bus_errors: int
    expected_errors: int
    stray_bytes: int
    desyncs: int
    post_check: dict[str, Any]
    seconds: float
    examples: list[str]

    @property
    def passed(self) -> bool:
        return self.desyncs == 0 and self.misattributed == 0 and self.untyped_outcomes == 0


async def cancellation_soak(
    cancellations: int = 10_000, seed: int = 2, concurrency: int = 6, stream_share: float = 0.05
) -> CancelReport:
    """Cancel requests (queued, on the wire, between retries) and streams at random; then check for desyncs.

    The line has no faults, so every transaction's bytes are valid except
    those of the silent memory reads: any other error, a stray byte or a
    wrong value is a desync.  Requests that were not cancelled are matched
    to the log like in the chaos soak; stream frames are checked against
    the servos' disjoint position bands.
    """
    sim = VirtualLine(chaos_servos(), log_size=200_000)
    bus = await open_bus(sim, retries=1, timing=FAST_TIMING)
    matcher = LogMatcher(sim, is_stream_tx, range(32), track_stream=False)
    images = {i: sim.servo(i).eeprom for i in range(32)}
    loop = asyncio.get_running_loop()
    busy: set[int] = set()
    last_tx: dict[int, bytes] = {}
    tally: Counter[str] = Counter()
    out_of_band: list[str] = []
    stream_target_ids = list(range(32))
    t0 = time.perf_counter()

    def record(sid: int, cmd: Command[Any], attempts: int, outcome: BaseException | None, value: Any) -> None:
        if outcome is None:
            rec = RequestRecord(sid, cmd.tx, attempts, True, value, None, True, time.monotonic(), sim.transactions)
            tally["completed"] += 1
        else:
            typed = isinstance(outcome, (IcsError, asyncio.CancelledError, TimeoutError))
            name = "CancelledError" if isinstance(outcome, (asyncio.CancelledError, TimeoutError)) else None
            name = name or type(outcome).__name__
            rec = RequestRecord(sid, cmd.tx, attempts, False, None, name, typed, time.monotonic(), sim.transactions)
            tally["cancelled" if name == "CancelledError" else "failed"] += 1
        matcher.add_request(rec)

    async def request_victim(rng: random.Random) -> None:
        free = [i for i in range(32) if i not in busy]
        sid = rng.choice(free)
        busy.add(sid)
        try:
            cmd, call, attempts = random_request(rng, bus, sid, images[sid])
            while cmd.tx == last_tx.get(sid):
                cmd, call, attempts = random_request(rng, bus, sid, images[sid])
            if rng.random() < 0.1:
                # A silent servo: the request waits out its deadline on the wire, cancellable all along.
                silent = protocol.ReadMemory(sid, rng.randrange(100), rng.randrange(1, 8))
                if silent.tx != last_tx.get(sid):
                    cmd, call, attempts = silent, functools.partial(bus.request, silent, retries=1), 2
            last_tx[sid] = cmd.tx
            style = rng.random()
            outcome: BaseException | None = None
            value: Any = None
            if style < 0.6:
                # A bare future from submit(), cancelled while queued or exactly while on the wire.
                priority = rng.choice(list(Priority))
                retries = rng.randrange(3) if cmd.idempotent else 0
                attempts = 1 + retries
                fut = bus.submit(cmd, priority=priority, retries=retries)
                if style < 0.25:
                    for _ in range(rng.randrange(3)):
                        await asyncio.sleep(0)
                else:
                    give_up = loop.time() + 0.1
                    while loop.time() < give_up:
                        log = sim.log
                        if fut.done() or (log and log[-1].tx == cmd.tx):
                            break  # written, its reply not handled yet: on the wire
                        await asyncio.sleep(0)
                fut.cancel()
                try:
                    value = await fut
                except BaseException as exc:
                    outcome = exc
            elif style < 0.85:
                # A task inside a Servo call, cancelled after it has submitted its request.
                task = asyncio.ensure_future(call())
                await asyncio.sleep(0)
                if rng.random() < 0.5:
                    for _ in range(rng.randrange(4)):
                        await asyncio.sleep(0)
                else:
                    await asyncio.sleep(rng.uniform(0, 0.004))
                task.cancel()
                try:
                    value = await task
                except BaseException as exc:
                    outcome = exc
            else:
                # A caller's own timeout.
                try:
                    async with asyncio.timeout(rng.uniform(0, 0.003)):
                        value = await call()
                except BaseException as exc:
                    outcome = exc
            record(sid, cmd, attempts, outcome, value)
        finally:
            busy.discard(sid)

    async def stream_victim(rng: random.Random) -> None:
        ids = sorted(rng.sample(stream_target_ids, rng.randrange(1, 33)))
        rate = rng.choice([None, None, 500.0, 2000.0])

        async def body() -> None:
            stream = bus.stream(ids, rate_hz=rate, probe_interval=0.01)
            # Targets first: a stream starts with every ID free, and a free command looks like a request.
            stream.set_targets({i: stream_target(i, rng.randrange(100)) for i in ids})
            async with stream:
                async for frame in stream:
                    tally["frames"] += 1
                    for i, position in frame.positions.items():
                        low, high = band(i)
                        if not low <= position <= high:
                            out_of_band.append(f"frame {frame.cycle}: ID {i} at {position}, band {low}..{high}")

        task = asyncio.ensure_future(body())
        for _ in range(rng.randrange(3)):
            await asyncio.sleep(0)
        if rng.random() < 0.8:
            await asyncio.sleep(rng.uniform(0, 0.05))
        task.cancel()
        result = await asyncio.gather(task, return_exceptions=True)
        if isinstance(result[0], asyncio.CancelledError):
            tally["streams_cancelled"] += 1
        elif result[0] is not None:
            tally["stream_errors"] += 1
            out_of_band.append(f"stream ended with {result[0]!r}")

    stream_goal = round(stream_share * cancellations)
    request_goal = cancellations - stream_goal

    async def canceller(k: int) -> None:
        rng = random.Random(seed * 7919 + k)
        while tally["cancelled"] < request_goal:
            await request_victim(rng)
            matcher.drain()
            matcher.match()

    async def stream_canceller() -> None:
        rng = random.Random(seed * 31 + 5)
        while tally["streams_cancelled"] < stream_goal:
            await stream_victim(rng)

    try:
        await asyncio.gather(stream_canceller(), *(canceller(k) for k in range(concurrency)))
        await bus.wait_idle()
        matcher.drain()
        matcher.match(final=True)
        counts = matcher.counts
        expected_errors = counts.predicted_errors
        stats = bus.stats
        bus_errors, stray = stats.total.errors, stats.stray_bytes
        queued = stats.queued
        post = await consistency_check(sim, bus)
    finally:
        await bus.aclose()
        sim.close()
    problems = list(post["problems"])
    if bus_errors != expected_errors:
        problems.append(f"bus counted {bus_errors} errors, the bytes on the line call for {expected_errors}")
    if stray:
        problems.append(f"{stray} stray bytes")
    if queued:
        problems.append(f"{queued} requests still queued after wait_idle()")
    problems += out_of_band[:5]
    desyncs = len(problems) + counts.misattributed + counts.valid_rejected + len(out_of_band)
    return CancelReport(
        cancellations=tally["cancelled"] + tally["streams_cancelled"],
        requests_cancelled_queued=counts.cancelled_queued,
        requests_cancelled_in_flight=counts.cancelled_in_flight,
        streams_cancelled=tally["streams_cancelled"],
        stream_frames_seen=tally["frames"],
        requests_completed=tally["completed"] + tally["failed"],
        requests_checked=counts.requests - counts.cancelled_queued - counts.cancelled_in_flight,
        misattributed=counts.misattributed,
        valid_replies_rejected=counts.valid_rejected,
        stream_positions_out_of_band=len(out_of_band),
        untyped_outcomes=counts.untyped_outcomes,
        bus_errors=bus_errors,
        expected_errors=expected_errors,
        stray_bytes=stray,
        desyncs=desyncs,
        post_check={**post, "problems": problems},
        seconds=time.perf_counter() - t0,
        examples=counts.examples + out_of_band[:5],
    )


# ====================================================================== unplug and replug


def start_pty_server(args: Sequence[str], timeout: float = 15.0) -> tuple[subprocess.Popen[str], str]:
    """``python -m ics35_async.sim ARGS`` quietly (its notes go to /dev/null); returns it and its device path."""
    return start_subprocess(args, timeout=timeout, quiet=True)


def open_fds() -> int:
    return len(os.listdir("/proc/self/fd"))


def other_tasks() -> int:
    current = asyncio.current_task()
    return sum(1 for t in asyncio.all_tasks() if t is not current and not t.done())


@dataclass
class UnplugCycle:
    down_s: float  # how long the device path was gone
    resume_s: float  # device path back -> first frame with every ID answering


@dataclass
class UnplugReport:
    reconnect_cycles: list[UnplugCycle]
    resume_s_median: float
    resume_s_max: float
    reconnects_counted: int
    requests: int
    requests_ok: int
    failed_port_lost: int
    failed_other_typed: dict[str, int]
    untyped_outcomes: int
    requests_hung: int
    values_wrong: int
    no_reconnect_stream_end: str
    no_reconnect_request_error: str
    no_reconnect_pending_errors: dict[str, int]
    tasks_before: int
    tasks_after: int
    fds_before: int
    fds_after: int
    threads_before: int
    threads_after: int
    seconds: float

    @property
    def passed(self) -> bool:
        return (
            bool(self.reconnect_cycles)
            and self.resume_s_max < 1.0
            and self.untyped_outcomes == 0
            and self.requests_hung == 0
            and self.values_wrong == 0
            and not self.failed_other_typed
            and self.no_reconnect_stream_end == "PortLost"
            and self.no_reconnect_request_error == "BusClosed"
            and set(self.no_reconnect_pending_errors) <= {"PortLost", "ReplyTimeout"}  # silent reads time out
            and self.no_reconnect_pending_errors.get("PortLost", 0) > 0
            and self.tasks_after == self.tasks_before
            and self.fds_after == self.fds_before
            and self.threads_after == self.threads_before
        )


class _PathWatch:
    """Notes when the pty server's device path disappears and comes back (``time.monotonic()``)."""

    def __init__(self, path: str) -> None:
        self.path = path
        self.events: list[tuple[str, float]] = []
        self.task: asyncio.Task[None] | None = None

    async def run(self) -> None:
        present = True
        while True:
            exists = os.path.exists(self.path)
            if exists != present:
                present = exists
                # The clock of frame timestamps (see Bus.open).
                self.events.append(("back" if exists else "gone", time.monotonic()))
            await asyncio.sleep(0.0005)


async def reconnect_session(
    down_times: Sequence[float], cycles_each: int, seed: int, report: dict[str, Any], unplug_rate: float = 0.002
) -> None:
    """reconnect=True: a stream plus requests across repeated unplugs, at several down times.

    The pty server unplugs after a transaction to ID 7 with probability
    ``unplug_rate`` (its ``unplug`` fault) and plugs back in after the down time.
    """
    loop = asyncio.get_running_loop()
    ids = list(range(8))
    for n, down in enumerate(down_times):
        proc, path = start_pty_server(
            [
                "--fast",
                "--ids",
                "0-7",
                "--faults",
                f"unplug@7:{unplug_rate}",
                "--replug-after",
                f"{down}",
                "--seed",
                str(seed + n),
            ]
        )
        watch = _PathWatch(path)
        stop = asyncio.Event()
        try:
            async with open_bus(path, reconnect=True, adapter_latency=0.02) as bus:
                watch.task = asyncio.create_task(watch.run())

                async def requests(k: int, bus: Bus = bus, stop: asyncio.Event = stop) -> None:
                    rng = random.Random(seed * 100 + k)
                    while not stop.is_set():
                        sid = rng.choice(ids)
                        report["requests"] += 1
                        try:
                            async with asyncio.timeout(5):
                                value = await bus.servo(sid).read_stretch()
                        except TimeoutError:
                            report["hung"] += 1
                        except PortLost:
                            report["port_lost"] += 1
                            await asyncio.sleep(0.01)
                        except IcsError as exc:
                            report["other"][type(exc).__name__] += 1
                        except Exception:
                            report["untyped"] += 1
                        else:
                            report["ok"] += 1
                            if value != 30:  # factory RAM stretch
                                report["wrong"] += 1

                stream = bus.stream(ids)
                stream.set_targets({i: 7000 + 100 * i for i in ids})
                async with stream:
                    workers = [asyncio.create_task(requests(k)) for k in range(3)]
                    seen_cycles = 0
                    give_up = loop.time() + 6 + cycles_each * (down + 1.5)
                    while seen_cycles < cycles_each and loop.time() < give_up:
                        frame = await stream.next_frame()
                        backs = [t for kind, t in watch.events if kind == "back"]
                        if len(backs) > seen_cycles and len(frame.positions) == len(ids):
                            gone = [t for kind, t in watch.events if kind == "gone"][len(backs) - 1]
                            back = backs[len(backs) - 1]
                            if frame.started >= back:
                                report["cycles"].append(UnplugCycle(back - gone, frame.finished - back))
                                seen_cycles = len(backs)
                    stop.set()
                    await asyncio.gather(*workers)
                report["reconnects"] += bus.stats.reconnects
        finally:
            stop.set()
            if watch.task is not None:
                watch.task.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await watch.task
            stop_subprocess(proc)


async def no_reconnect_session(report: dict[str, Any]) -> None:
    """reconnect=False: the stream ends with PortLost, pending requests fail, later calls get BusClosed."""
    proc, path = start_pty_server(["--fast", "--ids", "0-7", "--unplug-after", "1.0", "--replug-after", "0.3"])
    try:
        bus = await open_bus(path, adapter_latency=0.02)
        pending: list[asyncio.Future[Any]] = []

        async def keep_requests_queued() -> None:
            # Reads nobody answers (each waits out its deadline on the wire) and ordinary reads,
            # topped up all along: whenever the port goes, some are on the wire or queued.
            with contextlib.suppress(IcsError):
                while True:
                    if sum(not f.done() for f in pending) < 6:
                        pending.append(bus.submit(protocol.ReadMemory(3, 0, 4), priority=Priority.LOW))
                        pending.append(bus.submit(protocol.ReadParam(1, Param.SPEED), priority=Priority.LOW))
                    await asyncio.sleep(0.002)

        stream = bus.stream(range(8))
        stream.set_targets({i: 7000 + 100 * i for i in range(8)})
        feeder = asyncio.create_task(keep_requests_queued())
        try:
            async with stream:
                while True:
                    await stream.next_frame()
        except IcsError as exc:
            report["stream_end"] = type(exc).__name__
        await feeder
        outcomes = await asyncio.gather(*pending, return_exceptions=True)
        report["pending"] = dict(Counter(type(o).__name__ for o in outcomes if isinstance(o, BaseException)))
        try:
            await bus.servo(1).read_stretch()
            report["request_error"] = "none"
        except IcsError as exc:
            report["request_error"] = type(exc).__name__
        await bus.aclose()
        await asyncio.sleep(0.05)
        # Counted while the bus object is alive: a task left pending by it is still referenced.
        report["tasks_after_close"] = other_tasks()
    finally:
        stop_subprocess(proc)


def new_unplug_tally() -> dict[str, Any]:
    """The counters :func:`reconnect_session` and :func:`no_reconnect_session` fill in."""
    return {
        "cycles": [],
        "requests": 0,
        "ok": 0,
        "port_lost": 0,
        "other": Counter(),
        "untyped": 0,
        "hung": 0,
        "wrong": 0,
        "reconnects": 0,
    }


def non_executor_threads() -> int:
    """Threads, not counting the event loop's default executor (a pool kept for the loop's lifetime)."""
    return sum(1 for t in threading.enumerate() if not t.name.startswith("asyncio_"))


async def unplug_soak(
    down_times: Sequence[float] = (0.05, 0.2, 0.5, 0.856, 1.4, 1.856, 2.4), cycles_each: int = 3, seed: int = 3
) -> UnplugReport:
    """The pty simulator's device vanishes and returns (same path), again and again.

    The down times include the worst case of the default reconnect backoff
    (0.05, 0.1, 0.2, 0.5, 1.0 s): a device that returns just after the 4th or
    5th attempt (0.85 s, 1.85 s after the loss) waits for the next one.
    """
    t0 = time.perf_counter()
    await asyncio.sleep(0)
    tasks0, fds0, threads0 = other_tasks(), open_fds(), non_executor_threads()
    report = new_unplug_tally()
    await reconnect_session(down_times, cycles_each, seed, report)
    await no_reconnect_session(report)
    await asyncio.sleep(0.05)  # closing transports release their fds on the next loop passes
    resume = [c.resume_s for c in report["cycles"]]
    return UnplugReport(
        reconnect_cycles=report["cycles"],
        resume_s_median=statistics.median(resume) if resume else math.nan,
        resume_s_max=max(resume, default=math.nan),
        reconnects_counted=report["reconnects"],
        requests=report["requests"],
        requests_ok=report["ok"],
        failed_port_lost=report["port_lost"],
        failed_other_typed=dict(report["other"]),
        untyped_outcomes=report["untyped"],
        requests_hung=report["hung"],
        values_wrong=report["wrong"],
        no_reconnect_stream_end=report.get("stream_end", "none"),
        no_reconnect_request_error=report.get("request_error", "none"),
        no_reconnect_pending_errors=report.get("pending", {}),
        tasks_before=tasks0,
        tasks_after=max(other_tasks(), report.get("tasks_after_close", 0)),
        fds_before=fds0,
        fds_after=open_fds(),
        threads_before=threads0,
        threads_after=non_executor_threads(),
        seconds=time.perf_counter() - t0,
    )


# ====================================================================== fuzzing


BAUDS = (115200, 625000, 1250000)


@dataclass(frozen=True, slots=True)
class FuzzCase:
    """One fuzzed transaction: the command the host sends and the bytes the "device" answers."""

    command: Command[Any]
    echo: bytes  # what comes back in place of the echo (the real echo, damaged, or nothing)
    reply: bytes  # what follows it

    @property
    def received(self) -> bytes:
        return self.echo + self.reply


def _command_from(blob: bytes, baudrate: int) -> Command[Any]:
    kind, sid, arg = blob[0] % 10, blob[1] % 32, blob[2]
    extra = blob[5] if len(blob) > 5 else 0
    if kind == 0:
        return protocol.Position(sid, (arg << 6 | extra) % (protocol.POSITION_MAX + 1), baudrate=baudrate)
    if kind == 1:
        return protocol.Position(sid, protocol.FREE, baudrate=baudrate)
    if kind == 2:
        return protocol.ReadParam(sid, 1 + arg % 4)
    if kind == 3:
        param = Param(1 + arg % 4)
        low, high = protocol.WRITE_RANGES[param]
        return protocol.WriteParam(sid, param, low + extra % (high - low + 1))
    if kind == 4:
        return protocol.ReadEeprom(sid)
    if kind == 5:
        return protocol.WriteEeprom(sid, Eeprom.factory(sid))
    if kind == 6:
        address = arg % protocol.MEMORY_SIZE
        return protocol.ReadMemory(sid, address, 1 + extra % min(16, protocol.MEMORY_SIZE - address))
    if kind == 7:
        address = arg % (protocol.MEMORY_SIZE - 1)
        return protocol.WriteMemory(sid, address, bytes(range(1 + extra % min(8, protocol.MEMORY_SIZE - address))))
    if kind == 8:
        return protocol.ReadId(sid)
    return protocol.WriteId(sid)


def _valid_value(command: Command[Any], payload: bytes) -> Any:
    p = payload + bytes(8)
    if isinstance(command, protocol.Position):
        return (p[0] << 7 | p[1]) & protocol.POSITION_MAX
    if isinstance(command, protocol.ReadParam):
        return p[0] & 0x7F
    if isinstance(command, protocol.WriteParam):
        return command.value
    if isinstance(command, protocol.ReadEeprom):
        image = Eeprom.factory(command.servo_id or 0)
        return image.replace(speed=1 + p[0] % 127, punch=p[1] % 11)
    if isinstance(command, protocol.ReadMemory):
        return (payload * command.count)[: command.count] if payload else bytes(command.count)
    if isinstance(command, (protocol.ReadId, protocol.WriteId)):
        return command.new_id if isinstance(command, protocol.WriteId) else p[0] % 32
    return None


def fuzz_case(blob: bytes, baudrate: int) -> FuzzCase:
    """Turn a hypothesis-drawn blob into a command and the (mostly broken) bytes answering it.

    Byte 0: command kind; 1: ID; 2 and 5: arguments; 3: what happens to the
    echo; 4: what the reply is; the rest: bytes for values and damage.
    """
    blob = blob.ljust(6, b"\0")
    command = _command_from(blob, baudrate)
    tx = command.tx
    payload = blob[6:]
    pick = payload[0] if payload else 0
    echo_style, reply_style = blob[3] % 16, blob[4] % 10
    # The echo: usually intact, else missing, damaged, short or long.
    if echo_style < 10:
        echo = tx
    elif echo_style == 10:
        echo = b""
    elif echo_style == 11:
        i = pick % len(tx)
        echo = tx[:i] + bytes([tx[i] ^ (1 + (blob[2] % 255))]) + tx[i + 1 :]
    elif echo_style == 12:
        echo = tx[: pick % len(tx)]
    elif echo_style == 13:
        echo = tx + payload[:1]
    elif echo_style == 14:
        echo = bytes(reversed(tx))
    else:
        echo = payload[: len(tx)]
    clean = command.encode_reply(_valid_value(command, payload))
    if reply_style < 3:
        reply = clean
    elif reply_style == 3:  # one byte changed
        i = pick % len(clean)
        reply = clean[:i] + bytes([clean[i] ^ (1 + blob[5] % 255)]) + clean[i + 1 :]
    elif reply_style == 4:  # cut short
        reply = clean[: pick % len(clean)]
    elif reply_style == 5:  # trailing bytes
        reply = clean + payload[: 1 + pick % 4]
    elif reply_style == 6:  # random bytes of the right length
        reply = (payload * len(clean))[: len(clean)] if payload else bytes(len(clean))
    elif reply_style == 7:  # random bytes of any length
        reply = payload
    elif reply_style == 8:  # a valid reply of another command or another ID
        other = _command_from(bytes([(blob[0] + 1 + pick % 9) % 256, (blob[1] + pick % 2) % 256, *blob[2:]]), baudrate)
        reply = other.encode_reply(_valid_value(other, payload))
    else:  # an MSB set somewhere
        i = pick % len(clean)
        reply = clean[:i] + bytes([clean[i] | 0x80]) + clean[i + 1 :]
    return FuzzCase(command, echo, reply)


class FuzzDevice:
    """A WireDevice double that answers each command with the scripted (fuzzed) bytes, or cleanly.

    ``script`` holds the next answers; ``clean=True`` makes it a healthy
    device that echoes and answers every command correctly.
    """

    def __init__(self, echo: bool = True) -> None:
        self.host: Any = None
        self.echo = echo
        self.baudrate = 115200
        self.script: deque[FuzzCase] = deque()
        self.clean = False
        self.writes = 0
        self.guards = 0
        self.mismatched_writes = 0

    def connect(self, host: Any, baudrate: int) -> None:
        self.host, self.baudrate = host, baudrate

    def disconnect(self) -> None:
        self.host = None

    def write(self, data: bytes) -> None:
        self.writes += 1
        if self.clean:
            framed = decode_request(data, baudrate=self.baudrate)
            assert framed is not None and framed[0] is not None
            command = framed[0]
            answer = command.encode_reply(_valid_value(command, bytes([command.servo_id or 0, 5])))
            out = (data if self.echo else b"") + answer
        elif data in _GUARD_TXS and not (self.script and self.script[0].command.tx == data):
            # The bus's guard read after a timeout (see Bus._guard): a healthy answer, no script used.
            self.guards += 1
            framed = decode_request(data, baudrate=self.baudrate)
            assert framed is not None and framed[0] is not None
            answer = framed[0].encode_reply(_valid_value(framed[0], b"\x05"))
            out = (data if self.echo else b"") + answer
        else:
            case = self.script.popleft()
            if case.command.tx != data:
                self.mismatched_writes += 1
            out = (case.echo if self.echo else b"") + case.reply
        if out and self.host is not None:
            self.host.deliver(out)


@dataclass
class FuzzCounts:
    streams: int = 0
    parses: int = 0
    parse_values: int = 0
    untyped: int = 0
    fast_path_disagrees: int = 0
    decode_problems: int = 0
    bus_transactions: int = 0
    bus_values: int = 0
    bus_errors: Counter[str] = field(default_factory=Counter)
    bus_wrong: int = 0  # value where the bytes call for an error, wrong value, or another error class
    bus_untyped: int = 0
    examples: list[str] = field(default_factory=list)

    def note(self, text: str) -> None:
        if len(self.examples) < 10:
            self.examples.append(text)


@functools.lru_cache(maxsize=128)
def _parsers(sid: int, baudrate: int) -> tuple[Command[Any], ...]:
    return (
        protocol.Position(sid, 7500, baudrate=baudrate),
        protocol.Position(0, protocol.FREE, baudrate=baudrate),
        protocol.ReadParam(sid, Param.STRETCH),
        protocol.ReadParam(sid, Param.TEMPERATURE),
        protocol.WriteParam(sid, Param.SPEED, 100),
        protocol.ReadEeprom(sid),
        protocol.WriteEeprom(sid, Eeprom.factory(sid)),
        protocol.ReadMemory(sid, 3, 2),
        protocol.WriteMemory(sid, 0, b"\x01"),
        protocol.ReadId(),
        protocol.WriteId(sid),
    )


def fuzz_parsers(case: FuzzCase, baudrate: int, counts: FuzzCounts) -> None:
    """Every reply parser on the fuzzed bytes: a value or a ReplyError, nothing else."""
    sid = case.command.servo_id or 0
    parsers = _parsers(sid, baudrate)
    for parser in (*parsers, case.command):
        counts.parses += 1
        try:
            parser.parse(case.reply)
            counts.parse_values += 1
        except ReplyError:
            pass
        except Exception as exc:
            counts.untyped += 1
            counts.note(f"{parser!r}.parse({case.reply.hex(' ')}) raised {exc!r}")
    if len(case.reply) == 3:
        # The stream's hot path must agree with the codec on every 3-byte reply.
        position = parsers[0]
        assert isinstance(position, protocol.Position)
        fast = protocol.position_from_reply(case.reply, 0, position.reply_header)
        try:
            slow = position.parse(case.reply)
        except ReplyError:
            slow = -1
        if fast != slow:
            counts.fast_path_disagrees += 1
            counts.note(f"position reply {case.reply.hex(' ')}: fast path {fast}, codec {slow}")
    # The device side's framing: consumes at least one byte, and a command it finds
    # re-encodes to exactly the bytes it consumed.
    for data in (case.reply, case.received):
        try:
            framed = decode_request(data, baudrate=baudrate)
        except Exception as exc:
            counts.untyped += 1
            counts.note(f"decode_request({data.hex(' ')}) raised {exc!r}")
            continue
        if framed is not None:
            command, used = framed
            if not 1 <= used <= len(data) or (command is not None and command.tx != data[:used]):
                counts.decode_problems += 1
                counts.note(f"decode_request({data.hex(' ')}) -> {command!r}, {used}")


class FuzzRig:
    """Buses on :class:`FuzzDevice` doubles (every ICS rate, echo on and off), run side by side."""

    def __init__(self, lines: int = 48) -> None:
        self.devices = [FuzzDevice(echo=k % 8 != 7) for k in range(lines)]
        self.bauds = [BAUDS[k % 3] for k in range(lines)]
        self.buses: list[Bus] = []
        self.predictors = [WirePredictor(b, d.echo) for b, d in zip(self.bauds, self.devices, strict=True)]
        self.counts = FuzzCounts()

    async def open(self) -> None:
        for device, baud in zip(self.devices, self.bauds, strict=True):
            bus = await open_bus(
                device,
                baudrate=baud,
                echo=device.echo,
                adapter_latency=0.0005,
                turnaround=0.0,
                quiet_time=0.0,
                eeprom_write=0.0005,
                id_command=0.0005,
            )
            self.buses.append(bus)

    async def close(self) -> None:
        for bus in self.buses:
            await bus.aclose()

    async def _line(self, k: int, blobs: Sequence[bytes]) -> None:
        bus, device, predictor, counts = self.buses[k], self.devices[k], self.predictors[k], self.counts
        for blob in blobs:
            case = fuzz_case(blob, bus.baudrate)
            counts.streams += 1
            fuzz_parsers(case, bus.baudrate, counts)
            verdict = predictor.judge(case.command.tx, case.received if device.echo else case.reply)
            device.script.append(case)
            counts.bus_transactions += 1
            try:
                value = await bus.request(case.command, retries=0)
            except IcsError as exc:
                name = type(exc).__name__
                counts.bus_errors[name] += 1
                if verdict.ok or verdict.error != name:
                    counts.bus_wrong += 1
                    counts.note(
                        f"{case.command!r} got {case.received.hex(' ')}: bus {name}, bytes call for "
                        f"{verdict.value if verdict.ok else verdict.error}"
                    )
            except Exception as exc:
                counts.bus_untyped += 1
                counts.note(f"{case.command!r} got {case.received.hex(' ')}: bus raised {exc!r}")
            else:
                counts.bus_values += 1
                if not verdict.ok or verdict.value != value:
                    counts.bus_wrong += 1
                    counts.note(
                        f"{case.command!r} got {case.received.hex(' ')}: bus value {value!r}, bytes call "
                        f"for {verdict.value if verdict.ok else verdict.error}"
                    )

    async def run(self, blobs: Sequence[bytes]) -> None:
        n = len(self.buses)
        await asyncio.gather(*(self._line(k, blobs[k::n]) for k in range(n)))

    async def health_check(self) -> list[str]:
        """Clean devices now: every bus must answer every command right, with consistent counters."""
        problems = []
        for k, (bus, device) in enumerate(zip(self.buses, self.devices, strict=True)):
            device.clean = True
            if device.script:
                problems.append(f"line {k}: {len(device.script)} scripted answers never asked for")
                device.script.clear()
            for sid in (0, 7, 31):
                expect_image = _valid_value(protocol.ReadEeprom(sid), bytes([sid, 5]))
                checks: list[tuple[Awaitable[Any], Any]] = [
                    (bus.servo(sid).read_stretch(), sid & 0x7F),
                    (bus.servo(sid).set_position(9000), (sid << 7 | 5) & protocol.POSITION_MAX),
                    (bus.servo(sid).read_eeprom(), expect_image),
                    (bus.device(sid).read_memory(0, 2), bytes([sid, 5])),
                ]
                for call, want in checks:
                    try:
                        got = await call
                    except IcsError as exc:
                        problems.append(f"line {k} ID {sid}: {exc!r}")
                        continue
                    if got != want:
                        problems.append(f"line {k} ID {sid}: {got!r}, expected {want!r}")
            stats = bus.stats
            if stats.total.transactions != device.writes:
                problems.append(f"line {k}: bus counted {stats.total.transactions}, device saw {device.writes}")
            if stats.total.ok + stats.total.errors != stats.total.transactions or stats.queued:
                problems.append(f"line {k}: counters inconsistent {stats.total} queued {stats.queued}")
            if device.mismatched_writes:
                problems.append(f"line {k}: {device.mismatched_writes} writes were not the command submitted")
        return problems


@dataclass
class FuzzReport:
    streams: int
    parses: int
    parse_values: int
    untyped: int
    fast_path_disagrees: int
    decode_problems: int
    bus_transactions: int
    bus_values: int
    bus_errors: dict[str, int]
    bus_wrong: int
    bus_untyped: int
    loop_exceptions: int
    health_problems: list[str]
    seconds: float
    examples: list[str]

    @property
    def passed(self) -> bool:
        return not (
            self.untyped
            or self.fast_path_disagrees
            or self.decode_problems
            or self.bus_wrong
            or self.bus_untyped
            or self.loop_exceptions
            or self.health_problems
        )


def fuzz_soak(streams: int = 1_000_000, batch: int = 400, lines: int = 64, seed: int | None = 4) -> FuzzReport:
    """Hypothesis draws ``streams`` byte streams, in batches, through the parsers and the bus."""
    from hypothesis import HealthCheck, Phase, given, settings
    from hypothesis import strategies as st

    loop = asyncio.new_event_loop()
    loop_errors: list[dict[str, Any]] = []
    loop.set_exception_handler(lambda _loop, context: loop_errors.append(context))
    rig = FuzzRig(lines)
    t0 = time.perf_counter()
    try:
        loop.run_until_complete(rig.open())
        batches = max(1, math.ceil(streams / batch))

        @settings(
            max_examples=batches,
            database=None,
            deadline=None,
            derandomize=seed is not None,
            suppress_health_check=list(HealthCheck),
            phases=[Phase.generate],
        )
        @given(st.lists(st.binary(min_size=6, max_size=80), min_size=batch, max_size=batch))
        def drive(blobs: list[bytes]) -> None:
            loop.run_until_complete(rig.run(blobs))

        drive()
        problems = loop.run_until_complete(rig.health_check())
        loop.run_until_complete(rig.close())
    finally:
        loop.close()
    c = rig.counts
    return FuzzReport(
        streams=c.streams,
        parses=c.parses,
        parse_values=c.parse_values,
        untyped=c.untyped,
        fast_path_disagrees=c.fast_path_disagrees,
        decode_problems=c.decode_problems,
        bus_transactions=c.bus_transactions,
        bus_values=c.bus_values,
        bus_errors=dict(c.bus_errors),
        bus_wrong=c.bus_wrong,
        bus_untyped=c.bus_untyped,
        loop_exceptions=len(loop_errors),
        health_problems=problems,
        seconds=time.perf_counter() - t0,
        examples=c.examples + [str(e.get("message")) for e in loop_errors[:5]],
    )


# ====================================================================== the command


def _ms(seconds: float) -> str:
    return f"{seconds * 1e3:.1f} ms"


def summarize_chaos(r: ChaosReport) -> list[tuple[str, str, bool | None]]:
    rec = r.recovery
    return [
        ("chaos: transactions (faulted)", f"{r.transactions:,} ({r.faulted_fraction:.2%}, every kind)", None),
        (
            "chaos: replies misattributed",
            f"{r.misattributed + r.stale_accepted} ({r.misattributed} not carried by the bytes received, "
            f"{r.stale_accepted} another command's late reply in a lost reply's place; "
            f"{r.late_reply_to_own_retry} late first replies taken by their own retry; "
            f"{r.guard_reads:,} guard reads after timeouts)",
            r.misattributed + r.stale_accepted == 0,
        ),
        (
            "chaos: requests never completed",
            f"{r.requests_never_completed} of {r.requests:,}",
            r.requests_never_completed == 0,
        ),
        ("chaos: outcomes neither a value nor a typed error", f"{r.untyped_outcomes}", r.untyped_outcomes == 0),
        ("chaos: valid replies the bus rejected", f"{r.valid_replies_rejected}", r.valid_replies_rejected == 0),
        (
            "chaos: damaged replies that look valid (no checksum in ICS 3.5)",
            f"{r.undetectable_corruptions} bits flipped in place (corrupt fault), "
            f"{r.noise_accepted} truncated and completed by noise",
            r.undetectable_without_corrupt_fault == 0,
        ),
        (
            "chaos: recovery per fault, failed transactions",
            f"median {rec['failed_txns_median']}, max {rec['failed_txns_max']}",
            None,
        ),
        (
            "chaos: recovery per fault, line outage",
            f"median {rec['outage_ms_median']:.1f} ms, p99 {rec['outage_ms_p99']:.1f} ms, "
            f"max {rec['outage_ms_max']:.1f} ms",
            None,
        ),
        (
            "chaos: throughput vs fault-free",
            f"{r.throughput_ratio:.2f} (transactions), {r.ok_throughput_ratio:.2f} (answered), "
            f"{r.frames_ratio:.2f} (frames); {r.txn_per_s:,.0f} vs {r.baseline_txn_per_s:,.0f} txn/s",
            None,
        ),
        (
            "chaos: consistent afterwards",
            "yes" if r.post_check["consistent"] else "; ".join(r.post_check["problems"]),
            r.post_check["consistent"],
        ),
    ]


def summarize_cancel(r: CancelReport) -> list[tuple[str, str, bool | None]]:
    return [
        (
            "cancel: cancellations",
            f"{r.cancellations:,}: {r.requests_cancelled_queued:,} queued, "
            f"{r.requests_cancelled_in_flight:,} on the wire, {r.streams_cancelled} streams",
            None,
        ),
        ("cancel: desyncs", f"{r.desyncs}", r.desyncs == 0),
        (
            "cancel: wrong values (requests, stream frames)",
            f"{r.misattributed}, {r.stream_positions_out_of_band}",
            r.misattributed == 0 and r.stream_positions_out_of_band == 0,
        ),
    ]


def summarize_unplug(r: UnplugReport) -> list[tuple[str, str, bool | None]]:
    downs = sorted({round(c.down_s, 2) for c in r.reconnect_cycles})
    return [
        (
            "unplug: stream resumes after the device returns",
            f"median {_ms(r.resume_s_median)}, max {_ms(r.resume_s_max)} over {len(r.reconnect_cycles)} unplugs "
            f"(down {downs[0] if downs else 0:g}-{downs[-1] if downs else 0:g} s)",
            r.resume_s_max < 1.0,
        ),
        (
            "unplug: request outcomes",
            f"{r.requests_ok:,} ok, {r.failed_port_lost:,} PortLost, {sum(r.failed_other_typed.values())} other, "
            f"{r.untyped_outcomes} untyped, {r.requests_hung} hung, {r.values_wrong} wrong",
            r.untyped_outcomes == 0 and r.requests_hung == 0 and r.values_wrong == 0 and not r.failed_other_typed,
        ),
        (
            "unplug: without reconnect",
            f"stream ends with {r.no_reconnect_stream_end}, pending {r.no_reconnect_pending_errors}, "
            f"later calls {r.no_reconnect_request_error}",
            r.no_reconnect_stream_end == "PortLost" and r.no_reconnect_request_error == "BusClosed",
        ),
        (
            "unplug: leaks (tasks, fds, threads before -> after)",
            f"{r.tasks_before}->{r.tasks_after}, {r.fds_before}->{r.fds_after}, {r.threads_before}->{r.threads_after}",
            r.tasks_after == r.tasks_before and r.fds_after == r.fds_before and r.threads_after == r.threads_before,
        ),
    ]


def summarize_fuzz(r: FuzzReport) -> list[tuple[str, str, bool | None]]:
    return [
        (
            "fuzz: byte streams",
            f"{r.streams:,} ({r.parses:,} parses, {r.bus_transactions:,} bus transactions, {r.seconds:.0f} s)",
            None,
        ),
        (
            "fuzz: untyped exceptions (parsers, bus, loop)",
            f"{r.untyped}, {r.bus_untyped}, {r.loop_exceptions}",
            not (r.untyped or r.bus_untyped or r.loop_exceptions),
        ),
        ("fuzz: bus conclusions differing from the bytes", f"{r.bus_wrong}", r.bus_wrong == 0),
        (
            "fuzz: stream fast path vs codec; decode_request",
            f"{r.fast_path_disagrees}; {r.decode_problems}",
            not (r.fast_path_disagrees or r.decode_problems),
        ),
        (
            "fuzz: clean device afterwards",
            "ok" if not r.health_problems else "; ".join(r.health_problems[:3]),
            not r.health_problems,
        ),
    ]


def markdown(rows: Sequence[tuple[str, str, bool | None]]) -> str:
    lines = ["| check | result | target met |", "|---|---|---|"]
    for name, value, ok in rows:
        lines.append(f"| {name} | {value} | {'' if ok is None else 'yes' if ok else '**NO**'} |")
    return "\n".join(lines)


PARTS = ("chaos", "cancel", "unplug", "fuzz")


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--quick", action="store_true", help="small sizes (about a minute in all)")
    parser.add_argument("--only", default=",".join(PARTS), help=f"comma-separated parts: {', '.join(PARTS)}")
    parser.add_argument("--transactions", type=int, default=None, help="chaos: transactions (default 1,000,000)")
    parser.add_argument("--fault-rate", type=float, default=0.02, help="chaos: share of faulted transactions")
    parser.add_argument("--cancellations", type=int, default=None, help="cancel: cancellations (default 10,000)")
    parser.add_argument("--fuzz-streams", type=int, default=None, help="fuzz: byte streams (default 1,000,000)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--json", default=None, help="also write every figure to this JSON file")
    args = parser.parse_args(argv)
    # Port losses and resyncs are the point here: the library's warnings about them are expected.
    logging.getLogger("ics35_async").setLevel(logging.ERROR)
    parts = [p.strip() for p in args.only.split(",") if p.strip()]
    unknown = set(parts) - set(PARTS)
    if unknown:
        parser.error(f"unknown part(s): {', '.join(sorted(unknown))}")
    quick = args.quick
    transactions = args.transactions or (50_000 if quick else 1_000_000)
    cancellations = args.cancellations or (1_000 if quick else 10_000)
    fuzz_streams = args.fuzz_streams or (20_000 if quick else 1_000_000)

    def say(text: str) -> None:
        print(text, file=sys.stderr, flush=True)

    rows: list[tuple[str, str, bool | None]] = []
    figures: dict[str, Any] = {"python": sys.version.split()[0], "cpus": os.cpu_count()}
    started = time.perf_counter()
    if "chaos" in parts:
        chaos = asyncio.run(chaos_soak(transactions, args.fault_rate, args.seed, progress=say))
        figures["chaos"] = asdict(chaos)
        rows += summarize_chaos(chaos)
        say(f"chaos: {chaos.seconds:.0f} s")
    if "cancel" in parts:
        say(f"cancel: {cancellations} cancellations")
        cancel = asyncio.run(cancellation_soak(cancellations, args.seed + 1))
        figures["cancel"] = asdict(cancel)
        rows += summarize_cancel(cancel)
        say(f"cancel: {cancel.seconds:.0f} s")
    if "unplug" in parts:
        say("unplug: pty simulator, device unplugged and replugged")
        unplug = asyncio.run(unplug_soak((0.05, 1.0), 1, args.seed + 2) if quick else unplug_soak(seed=args.seed + 2))
        figures["unplug"] = asdict(unplug)
        rows += summarize_unplug(unplug)
        say(f"unplug: {unplug.seconds:.0f} s")
    if "fuzz" in parts:
        say(f"fuzz: {fuzz_streams} byte streams")
        fuzz = fuzz_soak(fuzz_streams, seed=args.seed + 3)
        figures["fuzz"] = asdict(fuzz)
        rows += summarize_fuzz(fuzz)
        say(f"fuzz: {fuzz.seconds:.0f} s")
    figures["seconds"] = time.perf_counter() - started
    print(markdown(rows))
    print(f"\n{figures['seconds']:.0f} s in all, Python {figures['python']}, {figures['cpus']} CPUs")
    for part in ("chaos", "cancel", "fuzz"):
        examples = figures.get(part, {}).get("examples")
        if examples:
            print(f"\n{part} examples:\n  " + "\n  ".join(examples))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(figures, f, indent=1, default=str)
    failed = [name for name, _value, ok in rows if ok is False]
    if failed:
        print(f"\nFAILED: {', '.join(failed)}")
        return 1
    print("\nevery target met")
    return 0


if __name__ == "__main__":
    sys.exit(main())
