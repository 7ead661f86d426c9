"""The chaos soak: a 32-servo stream plus concurrent mixed requests on a faulty line, checked entry by entry.

A 32-servo position stream plus concurrent mixed requests (positions,
parameter reads and writes, EEPROM reads and writes, a silent memory read)
on the in-process simulator in fast mode, with about 2 % of the
transactions faulted, every fault kind mixed.  Every outcome (each stream
slot of each frame, each request) is matched to the simulator's own log
entry of that transaction (:class:`tests.support.matcher.LogMatcher`) and
checked against what the bus had to conclude from the bytes the simulator
actually sent (:class:`tests.support.oracle.WirePredictor`).  Reports
misattributed replies, requests that never completed, outcomes that were
not a value or a typed error, the recovery after each fault, and
throughput against a fault-free run of the same workload measured in the
same process.

``link=PTY``: the same simulator served on a pseudo-terminal from a thread of this process
(:class:`ics35_async.sim.PtyServer`), the bus opened on its path; ``link=PTY_BURST``: the same
with the burst path on (``ICS35_BURST=1``) where it is built: the stream's transactions then run
in the compiled executor and are fed to the engine afterwards; ``link=PTY_BURST_ANYIO``: the same under the
anyio driver (on asyncio), whose bus task feeds the bursts.  Real time decides there how the bytes of a
transaction are split between reads, so a valid reply may time out behind a slow thread, or be
taken before the noise behind it comes (see :class:`tests.support.matcher.LogMatcher`): rejected
valid replies and differing error classes are counted but are not targets; misattribution is.  On the
burst path, a loop held up (a loaded machine) while the executor runs on is fed several cycles at once and
takes the newest frame: the cycles of the frames skipped have no outcome to check, and their transactions are
set aside, counted (see :meth:`tests.support.matcher.LogMatcher.add_frame`).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import random
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from benchmarks.bench_common import burst_setting, executor_transactions
from ics35_async import (
    Bus,
    IcsError,
    open_bus,
)
from ics35_async.protocol import position_tx
from ics35_async.sim import (
    VirtualLine,
)
from tests.support.matcher import LogMatcher, RequestRecord
from tests.support.oracle import CheckError, chaos_servos, is_stream_tx
from tests.support.timing import FAST_TIMING

from .common import (
    BURST_LINKS,
    IN_PROCESS,
    Row,
    consistency_check,
    executor_row,
    fault_spec,
    link_driver,
    random_request,
    served_on_a_pty,
    stream_target,
)
from .watchdog import under_watchdog, watched


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

    def __init__(
        self, sim: VirtualLine, bus: Bus, seed: int, workers: int, request_pause: float, *, realtime: bool = False
    ) -> None:
        self.sim = sim
        self.bus = bus
        self.seed = seed
        self.workers = workers
        self.request_pause = request_pause
        self.ids = list(range(32))
        self.matcher = LogMatcher(sim, is_stream_tx, self.ids, realtime=realtime)
        self.never_completed = 0
        self.stats = WorkloadStats()
        self.stop = False
        self.busy: set[int] = set()
        self.last_tx: dict[int, bytes] = {}
        self.images = {i: sim.servo(i).eeprom for i in self.ids}
        self.sent_on_close: dict[int, int] = {}  # what the stream's close sent (on_close="hold": targets not yet sent)
        # How many times the bus put each of those sends on the line (its retries of the ID during the close: over
        # a pty an attempt whose reply came whole may still time out behind a slow thread, and go again).
        self.close_attempts: dict[int, int] = {}
        # Cycles the stream completed after the last frame the workload took (their frames never read): between
        # that frame's publication and the close, the loop may run a whole cycle or more on a loaded machine.
        self.unread_cycles = 0
        self.stream_probes = 0  # the stream's probe reads of offline IDs (as guard reads on the wire: see chaos_soak)

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
                frame = first = None
                while not (self.stop and all(t.done() for t in tasks)) and loop.time() < give_up:
                    frame = await stream.next_frame()
                    first = first or frame
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
                retried = self._retries()  # (the close's sends are all the requests from here on)
        elapsed = time.perf_counter() - t0
        self.sent_on_close = stream.targets_sent_on_close
        self.close_attempts = {sid: 1 + n - retried.get(sid, 0) for sid, n in self._retries().items()}
        self.stream_probes = stream.stats.probes
        newest = stream.latest
        if frame is not None and first is not None and newest is not None:
            self.unread_cycles = newest.cycle - frame.cycle
            # Every cycle from the first frame taken to the newest is a frame taken, one skipped or one unread:
            # the allowance for unread cycles (finish) can then not hide a frame the stream failed to publish.
            counted = self.stats.frames + self.stats.skipped_frames - first.skipped + self.unread_cycles
            if counted != newest.cycle - first.cycle + 1:
                raise CheckError(f"cycles {first.cycle}..{newest.cycle}: {counted} frames taken, skipped or unread")
        if matcher.realtime:
            # The close's last sends may have timed out before the simulator's thread, held up on a loaded machine,
            # read them: their log entries come once it has (finish looks for them), so wait for a quiet log.
            seen, quiet_since = sim.transactions, loop.time()
            give_up = quiet_since + 5
            while loop.time() - quiet_since < 0.2 and loop.time() < give_up:
                await asyncio.sleep(0.005)
                if sim.transactions != seen:
                    seen, quiet_since = sim.transactions, loop.time()
        matcher.drain()
        matcher.match()
        return elapsed

    def _retries(self) -> dict[int, int]:
        return {sid: c.retries for sid, c in self.bus.stats.per_id.items() if sid is not None}

    def finish(self) -> dict[str, Any]:
        """Match the rest; the last, unfinished cycle of the stream has no frame, nor have the cycles completed
        after the last frame taken (:attr:`unread_cycles`), nor the close's sends of the targets set after their
        last cycle (on_close="hold"), which must be there, last, each as many times as the bus sent it."""
        matcher = self.matcher
        for sid, target in self.sent_on_close.items():
            entries = matcher.stream_entries[sid]
            sent = position_tx(sid, target)
            attempts = self.close_attempts.get(sid, 1)
            if len(entries) < attempts and matcher.last_stream.get(sid) == (sent, False):
                # The stream's own last command had these bytes and got nothing back, not even the echo: a guard
                # read before the close's send that got nothing either spent its first try, and it did not go
                # (see ics35_async.engine.machine's _guard_proved_nothing); the target had gone, unanswered.
                attempts -= 1
                if not attempts:
                    continue
            if len(entries) < attempts or any(e[4] != sent for e in list(entries)[-attempts:]):
                last = [matcher.previous.get(e[0], e[4].hex(" ")) + f" ({e[1]})" for e in list(entries)[-3:]]
                raise CheckError(
                    f"ID {sid}: the close's send of target {target} ({sent.hex(' ')}, {attempts} attempt(s)) is not "
                    f"the last on the line; its last stream entries: {last}"
                )
            # In-process the bus retries only an attempt whose bytes call for a failure (a valid reply taken as
            # bad would be retried too: that must not pass unseen here); over a pty a slow thread may time out
            # one whose reply came whole (see close_attempts).
            valid = [e for e in list(entries)[-attempts:-1] if e[1].ok and not e[3]]
            if valid and not self.matcher.realtime:
                raise CheckError(f"ID {sid}: the close's send of target {target} went again after a valid reply")
            for _ in range(attempts):
                entries.pop()
        leftovers = {sid: len(e) for sid, e in matcher.stream_entries.items() if e}
        if any(n > 1 + self.unread_cycles for n in leftovers.values()):
            over = {
                sid: [matcher.previous.get(e[0], e[4].hex(" ")) + f" (seq {e[0]}, {e[1]})" for e in entries]
                for sid, entries in matcher.stream_entries.items()
                if len(entries) > 1 + self.unread_cycles
            }
            shown = dict(list(over.items())[:3])  # (a cycle's worth over is 32 IDs' entries: the first few tell)
            raise CheckError(
                f"stream log entries with no frame: {leftovers} ({self.unread_cycles} cycle(s) unread; "
                f"{self.stats.frames} frames taken, {self.stats.skipped_frames} skipped); "
                f"those over{' (the first 3 IDs)' if len(over) > 3 else ''}: {shown}"
            )
        for entries in matcher.stream_entries.values():
            entries.clear()
        matcher.match(final=True)
        return {"unfinished_cycle_entries": sum(leftovers.values())}


@dataclass
class ChaosReport:
    link: str  # IN_PROCESS, PTY or one of BURST_LINKS
    burst_transactions: int  # of the run's transactions, those the compiled executor ran (over a pty)
    noise_after_reply: int  # over a pty: replies taken whole before the noise behind them came
    transactions: int
    seconds: float
    fault_rate_target: float
    fault_spec: str
    faulted_fraction: float
    fault_kinds: dict[str, int]
    frames: int
    skipped_frames: int
    skipped_cycle_entries: int  # stream entries of the cycles whose frames were skipped: no outcome to check
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
    failed_probes: int  # offline IDs' probes (stretch reads, among the guard reads) that failed
    held_back_slots: int  # stream slots held back after a failure (failed in their frame, nothing sent)
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
            and (self.valid_replies_rejected == 0 or self.realtime)
            and self.undetectable_without_corrupt_fault == 0
            and self.stale_accepted == 0
            and self.extra_attempts == 0
            and (self.error_class_differs == 0 or self.realtime)
            and self.post_check["consistent"]
        )

    @property
    def realtime(self) -> bool:
        """Real time decides how bytes split between reads (over a pty): rejected valid replies and
        differing error classes are counted, not targets."""
        return self.link != IN_PROCESS


async def chaos_run(
    transactions: int,
    fault_rate: float,
    seed: int,
    workers: int = 4,
    request_pause: float = 0.002,
    link: str = IN_PROCESS,
    check: bool = True,
) -> tuple[ChaosWorkload, float, dict[str, Any]]:
    """One run; ``check``: then checked with the faults off (``extra["post_check"]``).  The bus is closed on return."""
    spec = fault_spec(fault_rate)
    sim = VirtualLine(chaos_servos(), faults=spec, seed=seed, log_size=max(100_000, transactions // 4))
    async with contextlib.AsyncExitStack() as stack:
        stack.callback(sim.close)
        if link != IN_PROCESS:
            path = await stack.enter_async_context(served_on_a_pty(sim))
            with burst_setting("1" if link in BURST_LINKS else "0", beside_requests=True):
                bus = watched(await open_bus(path, retries=1, timing=FAST_TIMING, driver=link_driver(link)))
        else:
            bus = watched(await open_bus(sim, retries=1, timing=FAST_TIMING))
        stack.push_async_callback(bus.aclose)
        workload = ChaosWorkload(sim, bus, seed, workers, request_pause, realtime=link != IN_PROCESS)
        elapsed = await workload.run(transactions)
        extra = workload.finish()
        extra["fault_spec"] = spec
        extra["bus_guards"] = bus.stats.guards
        extra["stream_probes"] = workload.stream_probes
        extra["burst_transactions"] = executor_transactions(bus)
        if check:
            extra["post_check"] = await consistency_check(sim, bus, realtime=link != IN_PROCESS)
    return workload, elapsed, extra


@under_watchdog("chaos")
async def chaos_soak(
    transactions: int = 1_000_000,
    fault_rate: float = 0.02,
    seed: int = 1,
    baseline_transactions: int | None = None,
    workers: int = 4,
    progress: Callable[[str], None] | None = None,
    link: str = IN_PROCESS,
) -> ChaosReport:
    """The chaos soak: a fault-free baseline, then the faulted run, checked entry by entry."""
    base_n = baseline_transactions if baseline_transactions is not None else max(20_000, transactions // 5)
    name = "chaos" if link == IN_PROCESS else f"chaos over a {link}"
    if progress:
        progress(f"{name}: fault-free baseline, {base_n} transactions")
    base, base_s, _ = await chaos_run(base_n, 0.0, seed, workers, link=link, check=False)
    base_counts = base.matcher.counts
    # (over a pty a valid reply may time out behind a slow thread: see the module)
    if base_counts.misattributed or (base_counts.valid_rejected and link == IN_PROCESS):
        raise CheckError(f"fault-free baseline: {base_counts.examples}")
    if progress:
        progress(f"{name}: {transactions} transactions, {fault_rate:.1%} faulted")
    work, seconds, extra = await chaos_run(transactions, fault_rate, seed, workers, link=link)
    post = extra["post_check"]
    # The stream's probe of an offline ID is a stretch read too: one still on the wire as the stream closed has
    # no outcome, so the log may show one more.
    unexplained = work.matcher.counts.guards - extra["bus_guards"] - extra["stream_probes"]
    if not 0 <= unexplained <= 1:
        post["consistent"] = False
        post["problems"].append(
            f"bus counted {extra['bus_guards']} guard reads and the stream {extra['stream_probes']} probe reads, "
            f"the log shows {work.matcher.counts.guards} of their shape"
        )
    counts = work.matcher.counts
    recovery = work.matcher.recovery()
    n = counts.entries
    ok_entries = counts.accepted
    base_rate = base_counts.entries / base_s
    base_ok_rate = base_counts.accepted / base_s
    base_frames = base.stats.frames / base_s
    return ChaosReport(
        link=link,
        burst_transactions=extra["burst_transactions"],
        noise_after_reply=counts.noise_after_reply,
        transactions=n,
        seconds=seconds,
        fault_rate_target=fault_rate,
        fault_spec=extra["fault_spec"],
        faulted_fraction=counts.faulted_entries / n if n else 0.0,
        fault_kinds=dict(counts.fault_kinds),
        frames=work.stats.frames,
        skipped_frames=work.stats.skipped_frames,
        skipped_cycle_entries=counts.skipped_cycle_entries,
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
        failed_probes=counts.failed_probes,
        held_back_slots=counts.held_back,
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


def summarize_chaos(r: ChaosReport) -> list[Row]:
    rec = r.recovery
    rows: list[Row] = [
        (
            "chaos: transactions (faulted)",
            f"{r.transactions:,} ({r.faulted_fraction:.2%}, every kind)"
            + (
                f"; {r.skipped_frames} frames skipped (the loop held up while the executor ran on), "
                f"their cycles' {r.skipped_cycle_entries} stream transactions unchecked"
                if r.skipped_frames
                else ""
            ),
            None,
        ),
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
        (
            "chaos: valid replies the bus rejected",
            f"{r.valid_replies_rejected}"
            + (
                f" (real time: timed out behind a slow thread, or the noise after them came in the same read; "
                f"{r.noise_after_reply} taken before the noise came; {r.error_class_differs} requests failed "
                "with another error than their bytes alone call for)"
                if r.realtime
                else ""
            ),
            None if r.realtime else r.valid_replies_rejected == 0,
        ),
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
            "; ".join(r.post_check["problems"])
            if not r.post_check["consistent"]
            else "yes" + "".join(f" ({note})" for note in r.post_check.get("notes", [])),
            r.post_check["consistent"],
        ),
    ]
    if not r.realtime:
        return rows
    # Over a pty: the same rows under their own name, and how much of the run the compiled executor ran.
    if r.link in BURST_LINKS:
        rows.insert(
            1,
            executor_row(
                "chaos: transactions the compiled executor ran",
                r.burst_transactions,
                f" ({r.burst_transactions / max(1, r.transactions):.0%}; the rest on the ordinary path: requests, "
                "and the stream after a fault until the line is in step again)",
            ),
        )
    return [(f"chaos over a {r.link}" + name.removeprefix("chaos"), value, ok) for name, value, ok in rows]
