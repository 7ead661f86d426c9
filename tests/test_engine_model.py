"""The engine against a model of the line, driven by hypothesis: random submits, cancels, faults and time.

The model: servos 1..3 answer (4 never does), each answer with a fresh value,
so a reply taken for the wrong request shows; a fault per transaction (reply
dropped, no echo either, reply split in chunks, late into the resync, so late
it lands in the next transaction, its tail held, a parity-marked byte, a wrong
echo, an extra byte, or the far end stalling: every command written meanwhile
answered late, whole and in order, on a line with echo); noise; a stream-like background source; the port lost and
reconnected, or reopened.  Plain calls and simulated time only: no event loop.

Late replies are kept to what the engine can tell apart: a late reply lands in
the resync or in the first transaction after it (the guard read's window; on a
line that echoes, after that transaction's echo when it went right as the resync
ended, where the echo cannot tell the reply from the transaction's own), and
not after an early failure of the transaction it belongs to (noise is sent only
when no late reply is in flight).  A guard read's reply is never very late:
that case is ``test_a_timed_out_guards_late_reply_is_not_taken_for_the_next_commands_reply``
(a known engine bug, xfail).  The stream leaves only between its transactions (see detach_stream).
"""

from __future__ import annotations

import itertools
import math
from collections import deque

import pytest
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st
from hypothesis.stateful import (
    RuleBasedStateMachine,
    initialize,
    invariant,
    precondition,
    rule,
    run_state_machine_as_test,
)

from ics35_async import protocol
from ics35_async.engine import BusTiming, LineEngine, Priority, State
from ics35_async.errors import PortLost, ReplyTimeout
from ics35_async.protocol import Param
from tests.support.engine_support import (
    BAUD,
    TURNAROUND,
    FakeSource,
    Recorded,
    Servos,
    Wire,
    misattributed,
    ready_engine,
    wire_time,
)

PRESENT = (1, 2, 3)
IDS = (1, 2, 3, 4)
KINDS = (
    "clean",
    "split",
    "drop",
    "silent",
    "late",
    "very_late",
    "tail_late",
    "garble",
    "echo_garble",
    "extra_byte",
    "stall",
)
LATE = {"late", "very_late", "tail_late"}

# The faults that test the engine's judgement most (late replies) come up more often.
faults = st.tuples(
    st.sampled_from([*KINDS, "late", "very_late", "tail_late", "very_late"]),
    st.floats(0.0, 1.0),
    st.lists(st.integers(1, 5), max_size=4),
)


class FaultyServos(Servos):
    """Servos whose next transactions suffer the queued faults."""

    def __init__(self, echo: bool) -> None:
        super().__init__(PRESENT, echo=echo)
        self.faults: deque[tuple[str, float, list[int]]] = deque()
        self.late_until = -math.inf  # when the last late reply in flight lands
        self.guards_seen = 0
        self.bad_writes: set[int] = set()  # writes whose answer the engine must not accept
        self.stalled: set[int] = set()  # writes answered late by a stalled far end (whole, in order)
        self.stall_end = -math.inf  # the far end reads nothing until then
        self.backlog_until = -math.inf  # when the last write answered after a stall has been answered

    def __call__(self, wire: Wire, tx: bytes) -> None:
        engine = wire.engine
        t = wire.now
        if t < self.stall_end or t < self.backlog_until:
            self._answer_after_the_stall(wire, tx)
            return
        guard = engine.counters.guards != self.guards_seen
        self.guards_seen = engine.counters.guards
        kind, u, cuts = self.faults.popleft() if self.faults else ("clean", 0.0, [])
        if kind == "stall":  # the far end stops reading for up to 0.1 s (see _answer_after_the_stall)
            if self.late_until > t or not self.echo:  # (without echo nothing tells a stall from silence: see .guard)
                kind = "drop"  # (no late reply still to come: kept to what the engine can tell apart)
            else:
                self.stall_end = t + 0.1 * u
                self._answer_after_the_stall(wire, tx)
                return
        if kind in LATE and (self.late_until > t or (guard and kind == "very_late")):
            kind = "drop"  # see the module docstring: kept to what the engine can tell apart
        if kind == "echo_garble" and not self.echo:
            kind = "clean"
        k = len(self.answers)  # this write's number, which tags its bytes
        if self.echo and kind != "silent":
            echo = bytes([tx[0] ^ 0x01]) + tx[1:] if kind == "echo_garble" else tx
            wire.schedule(t + wire_time(len(tx)), echo, tag=k)
        reply, value = self.reply_for(tx)
        if kind not in ("clean", "split"):
            self.bad_writes.add(k)
        if reply is None or kind in ("drop", "silent"):
            self.answers.append(None)
            return
        self.answers.append(value)
        on_time = t + wire_time(len(tx) + len(reply)) + TURNAROUND
        deadline, extra, quiet = engine.deadline, engine.link.extra, engine.timing.quiet_time
        base = deadline - t - extra
        if kind == "split":
            for n, (start, end) in enumerate(pieces(len(reply), cuts)):
                wire.schedule(on_time + n * u * 0.001, reply[start:end], tag=k)
        elif kind == "late":  # lands in the resync after the timeout
            self.late_until = deadline + (0.05 + 0.85 * u) * (quiet + extra)
            wire.schedule(self.late_until, reply, tag=k)
        elif kind == "very_late":  # lands just after that resync: in the next transaction, if any
            land = deadline + quiet + extra + 0.0001 + 0.0001 * u
            self.late_until = until = land + wire_time(8)  # (moved past an echo, it lands by then)
            wire.at(land, lambda: self._land_very_late(wire, reply, k, land, u, until))
        elif kind == "tail_late":  # the head in time, the tail in the resync after the partial reply
            self.late_until = deadline + (0.05 + 0.85 * u) * max(quiet + extra, base)
            wire.schedule(on_time, reply[:1], tag=k)
            wire.schedule(self.late_until, reply[1:], tag=k)
        elif kind == "garble":  # a byte damaged on the wire, which the port marks (mostly one the codec can't check)
            i = len(reply) - 1 - min(int(u * 3), len(reply) - 1)
            wire.schedule(on_time, reply[:i] + bytes([reply[i] ^ 0x01]) + reply[i + 1 :], parity_errors=1, tag=k)
        elif kind == "extra_byte":
            wire.schedule(on_time, reply + b"\xff", tag=k)
        else:
            wire.schedule(on_time, reply, tag=k)

    def _answer_after_the_stall(self, wire: Wire, tx: bytes) -> None:
        # A far end that stalls (a simulator not scheduled, an adapter or a bridge holding bytes) answers what
        # was written meanwhile once it runs again: each write's echo and reply together, in the order written.
        k = len(self.answers)
        reply, value = self.reply_for(tx)
        self.answers.append(value)
        self.stalled.add(k)
        begin = max(wire.now, self.stall_end, self.backlog_until)
        answer = (tx if self.echo else b"") + (reply or b"")
        self.backlog_until = at = begin + wire_time(len(tx) + (len(reply) if reply else 0)) + TURNAROUND
        self.late_until = max(self.late_until, at)
        if answer:
            wire.schedule(at, answer, tag=k)

    def _land_very_late(self, wire: Wire, reply: bytes, k: int, land: float, u: float, until: float) -> None:
        # A command that went on the wire in the 0.1-0.2 ms just before (the first after the resync) has its echo
        # on its way: the reply lands after that echo, where the echo cannot tell it from the command's own.
        if self.late_until != until:
            return  # the port was lost meanwhile (and the bytes with it)
        at = land
        if wire.writes and land - 0.0002 <= wire.writes[-1][0] <= land:
            written, tx = wire.writes[-1]
            at = written + wire_time(len(tx)) + 1e-6 + u * wire_time(1) if self.echo else land
        wire.schedule(at, reply, tag=k)


def pieces(n: int, cuts: list[int]) -> list[tuple[int, int]]:
    points = sorted({c for c in cuts if 0 < c < n})
    bounds = [0, *points, n]
    return list(itertools.pairwise(bounds))


class LineModel(RuleBasedStateMachine):
    engine: LineEngine
    wire: Wire
    servos: FaultyServos
    timing = BusTiming()

    @initialize(echo=st.booleans(), share=st.integers(1, 4))
    def open_line(self, echo: bool, share: int) -> None:
        self.engine = ready_engine(echo, max_requests_between=share, timing=self.timing)
        self.servos = FaultyServos(echo)
        self.wire = Wire(self.engine, self.servos)
        self.wire.on_write = self._check_no_request_delays_a_due_slot
        self.requests: list[Recorded] = []
        self.source: FakeSource | None = None
        self.source_errors: list[str] = []
        self.starts_before_request = 0
        self.head: tuple[object, int] = (None, 0)  # the queue's head and the stream's starts when it became so
        self.starts_at_last_write = 0
        self.uncounted = 0  # transactions a lost port took off the wire before they ended

    # ---------------------------------------------------------------- rules

    @rule(
        batch=st.lists(
            st.tuples(
                st.sampled_from(IDS),
                st.sampled_from(("position", "speed", "stretch", "current")),
                st.integers(1, protocol.POSITION_MAX),
                st.sampled_from(list(Priority)),
                st.integers(0, 2),
            ),
            min_size=1,
            max_size=3,
        )
    )
    def submit(self, batch: list[tuple[int, str, int, Priority, int]]) -> None:
        for sid, what, pos, priority, retries in batch:
            if what == "position":
                command: protocol.Command[int] = protocol.Position(sid, pos, baudrate=BAUD)
            else:
                command = protocol.ReadParam(sid, Param[what.upper()])
            req = Recorded(command, priority, retries, wire=self.wire)
            self.requests.append(req)
            self.wire.submit(req)
        self._note_head()

    @precondition(lambda self: self.requests)
    @rule(data=st.data())
    def cancel(self, data: st.DataObject) -> None:
        data.draw(st.sampled_from(self.requests)).cancel()
        self._note_head()

    @rule(batch=st.lists(faults, min_size=1, max_size=4))
    def inject(self, batch: list[tuple[str, float, list[int]]]) -> None:
        """Faults for the next transactions, one each."""
        self.servos.faults.extend(batch[: 8 - len(self.servos.faults)])

    @rule(dt=st.one_of(st.floats(0.0, 0.03), st.sampled_from([0.0002, 0.001, 0.011, 0.3])))
    def advance(self, dt: float) -> None:
        self.wire.run_for(dt)

    @precondition(lambda self: self.servos.late_until < self.wire.now)
    @rule(n=st.integers(1, 4))
    def noise(self, n: int) -> None:
        self.wire.schedule(self.wire.now, b"\xff" * n, tag="noise")
        self.wire.run_until(self.wire.now)  # now, before any later write can draw a late fault

    @precondition(lambda self: self.source is None)
    @rule(ids=st.lists(st.sampled_from(IDS), min_size=1, max_size=3), paced=st.booleans())
    def attach_stream(self, ids: list[int], paced: bool = False) -> None:
        # paced: a stream with a rate, whose slots are deadlines (see _check_no_request_delays_a_due_slot)
        source = FakeSource(ids, wake_at=self.wire.now, period=0.004, paced=paced)
        source.on_value = self._check_source_value
        self.source = source
        self.starts_before_request = 0  # the source's transactions started before the last request went
        self.head = (None, 0)
        self.starts_at_last_write = 0
        self._note_head()
        self.wire.emit(self.engine.attach_source(source, self.wire.now))

    @precondition(lambda self: self.source is not None)
    @rule()
    def detach_stream(self) -> None:
        # The stream stops offering work and leaves once its own transaction is off the wire:
        # a source detached mid-transaction is test_a_detached_sources_transaction_is_still_judged
        # (a known engine bug, xfail).
        source = self.source
        assert source is not None
        source.active, source.wake_at = False, math.inf
        engine = self.engine
        own = {protocol.position_tx(sid, protocol.FREE) for sid in source.ids}
        while engine.state is State.BUSY and self.wire.writes[-1][1] in own:
            self.wire.run_until(engine.deadline)
        engine.detach_source(source)
        self.source = None

    @rule(event=st.sampled_from(["lost", "reopen", *["nothing"] * 6]))
    def port(self, event: str) -> None:
        """Now and then the port is lost and reconnected, or reopened (when idle)."""
        engine = self.engine
        if event == "lost":
            if engine.state in (State.BUSY, State.DRAINING):
                self.uncounted += 1
            engine.lost("unplugged", reconnect=True)
        elif event == "reopen" and engine.state is State.IDLE:
            engine.disconnected()
        else:
            return
        self.wire.clear_in_flight()
        self.servos.late_until = self.servos.stall_end = self.servos.backlog_until = -math.inf
        self.wire.emit(engine.connected(self.wire.now))

    def _check_no_request_delays_a_due_slot(self) -> None:
        # Beside a paced stream, a request starts only while no slot is due, unless it is URGENT, or the
        # stream runs late (a slot already past when its previous transaction ended: faults, a short
        # period) and requests were passed over in two of its slots since the last one went (the
        # second is the one it takes): then the stream has started a transaction since.
        # Each request's own count: the stream has started a transaction since the request became the queue's
        # head (a count left by a head that was cancelled, or went, is not the next head's).
        source, current = self.source, self.engine._current
        # (the head changes between writes only, at a rule or a transaction's end: a head first seen at this
        # write became so with the stream's starts as they were after the write before)
        before_this_write, self.starts_at_last_write = self.starts_at_last_write, len(source.started) if source else 0
        try:
            if source is None or not source.paced or not source.active or not isinstance(current, Recorded):
                return
            since = len(source.started) - self.starts_before_request
            self.starts_before_request = len(source.started)
            as_head = len(source.started) - self.head[1] if self.head[0] is current else 0
            if current.priority != Priority.URGENT and source.wake_at <= self.wire.now and min(since, as_head) < 1:
                self.source_errors.append(
                    f"{current!r} started at {self.wire.now}, the slot due at {source.wake_at}, "
                    f"{since} stream transaction(s) since the last request, {as_head} since it became the head"
                )
        finally:
            self._note_head(before_this_write)

    def _note_head(self, starts: int | None = None) -> None:
        waiting = self.engine.queue.waiting()
        head = waiting[0] if waiting else None
        if head is not self.head[0]:
            if starts is None:
                starts = len(self.source.started) if self.source is not None else 0
            self.head = (head, starts)

    def _check_source_value(self, sid: int, value: int) -> None:
        k = len(self.wire.writes) - 1
        if (
            self.wire.writes[k][1] != protocol.Position(sid, 0, baudrate=BAUD).tx
            or self.servos.answers[k] != value
            or k in self.servos.bad_writes
        ):
            answered = self.servos.answers[k]
            self.source_errors.append(f"stream got {value} for ID {sid}; write {k} was answered {answered}")

    # ---------------------------------------------------------------- invariants

    @invariant()
    def state_and_deadline(self) -> None:
        engine = self.engine
        assert isinstance(engine.state, State)
        if engine.state in (State.BUSY, State.QUIET, State.DRAINING):
            assert math.isfinite(engine.deadline), engine.state
        assert 0.0 <= engine.link.extra <= engine.link.bound

    @invariant()
    def each_request_ends_at_most_once_with_its_own_value(self) -> None:
        for req in self.requests:
            assert req.calls <= 1, req
            if req.state == "done":
                problem = misattributed(req, self.servos)
                assert problem is None, problem
                assert req.write_index not in self.servos.bad_writes, f"{req!r} took a faulty answer"
            if req.state == "failed":
                assert req.error is not None and req.value is None
        assert not self.source_errors, self.source_errors

    @invariant()
    def an_undisturbed_clean_transaction_succeeds(self) -> None:
        wire, servos = self.wire, self.servos
        for req in self.requests:
            k = req.write_index
            if req.state != "failed" or isinstance(req.error, PortLost) or k in servos.bad_writes | servos.stalled:
                continue
            if servos.answers[k] is None:
                continue  # nobody there to answer
            others = [tag for tag in wire.delivered[wire.marks[k] : req.end_mark] if tag != k]
            assert others, f"{req!r} failed on write {k}, answered cleanly and alone: {req.error}"

    @invariant()
    def counters_add_up(self) -> None:
        total = self.engine.counters.snapshot(0).total
        errors = total.timeouts + total.partial_replies + total.echo_mismatches + total.bad_replies
        assert total.ok + errors == total.transactions
        on_the_wire = 1 if self.engine.state in (State.BUSY, State.DRAINING) else 0
        assert total.transactions == len(self.wire.writes) - self.uncounted - on_the_wire

    def teardown(self) -> None:
        if not hasattr(self, "engine"):
            return
        if self.source is not None:
            self.detach_stream()
        self.wire.settle(limit=120.0)
        for req in self.requests:
            assert req.calls == 1 or (req.state == "cancelled" and req.calls == 0), req
            assert req.state in ("done", "failed", "cancelled"), req
        self.each_request_ends_at_most_once_with_its_own_value()
        self.an_undisturbed_clean_transaction_succeeds()
        self.counters_add_up()
        # Whatever happened before, a quiet line works again, however the replies are cut up.
        self.servos.faults.clear()
        self.servos.faults.extend(("split", 0.5, [cut, cut + 1]) for cut in range(4) for _ in range(4))
        fresh = [
            Recorded(command, wire=self.wire)
            for sid in IDS
            for command in (protocol.ReadParam(sid, Param.SPEED), protocol.Position(sid, 0, baudrate=BAUD))
        ]
        for req in fresh:
            self.wire.submit(req)
        self.wire.settle(limit=120.0)
        for req in fresh:
            if req.command.servo_id in PRESENT:
                assert req.state == "done" and misattributed(req, self.servos) is None, req
            else:
                assert isinstance(req.error, ReplyTimeout), req
        self.engine.close()
        assert self.engine.state is State.CLOSED and self.engine.deadline == math.inf


SETTINGS = settings(
    max_examples=200, stateful_step_count=50, deadline=None, suppress_health_check=[HealthCheck.too_slow]
)


@pytest.mark.no_cover  # a soak: thousands of passes through code the other tests cover (see conftest)
@pytest.mark.slow
@pytest.mark.timeout(900)  # a pass takes seconds; shrinking a failure takes longer
def test_engine_against_a_model_of_the_line() -> None:
    run_state_machine_as_test(LineModel, settings=SETTINGS)


class ShortAllowanceLineModel(LineModel):
    """The model on a line opened with a small ``adapter_latency`` (3 ms, as the control-loop guide's example).

    The stream's learnt wait (4 ms at least; the model's servos answer within a few ms) is then longer than the
    full allowance, so the stream waits that allowance, and a failure holds its servo back as after a short wait.
    At the default 20 ms allowance the learnt wait never reaches it here: that rule would go untested.
    """

    timing = BusTiming(adapter_latency=0.003)


@pytest.mark.no_cover
@pytest.mark.slow
@pytest.mark.timeout(900)
def test_engine_against_a_model_of_a_line_with_a_short_adapter_allowance() -> None:
    run_state_machine_as_test(ShortAllowanceLineModel, settings=SETTINGS)


def test_a_very_late_reply_after_a_streams_short_wait_is_not_taken_by_its_next_transaction() -> None:
    # Found by the model above: a stream transaction gives up after its short wait; its reply comes
    # a quiet time after that deadline, where only a guard read may take it.  (It was taken by the
    # stream's next transaction to the same servo when the resync after the short wait was short.)
    state = LineModel()
    state.open_line(echo=False, share=1)
    state.attach_stream(ids=[1])
    state.advance(dt=0.0)
    state.inject(batch=[("very_late", 0.0, [])])
    state.advance(dt=0.3)
    state.each_request_ends_at_most_once_with_its_own_value()
    state.teardown()


def test_a_reply_that_failed_on_anothers_late_bytes_is_not_taken_by_its_retry() -> None:
    # Found by the model above: a guard read takes a timed-out read's very late reply; the guard's
    # own reply then lands in the next command (a read of the same servo), which fails on it at
    # once, with its own reply still to come, late.  The resync after that early failure must last
    # as long as after a timeout, and its retry must get a guard read first, else the retry (the
    # same command) takes that late reply for its own.
    state = LineModel()
    state.open_line(echo=False, share=1)
    state.advance(dt=0.0)
    state.inject(batch=[("clean", 0.0, []), ("clean", 0.0, []), ("very_late", 0.0, [])])
    state.inject(batch=[("clean", 0.0, []), ("late", 0.0, []), ("drop", 0.0, [])])
    state.submit(batch=[(1, "position", 1, Priority.URGENT, 0), (2, "stretch", 1, Priority.HIGH, 0)])
    state.submit(batch=[(1, "position", 1, Priority.URGENT, 0), (2, "speed", 1, Priority.HIGH, 1)])
    state.advance(dt=0.3)
    state.each_request_ends_at_most_once_with_its_own_value()
    state.teardown()


def test_a_streams_reply_late_by_more_than_the_links_extra_is_not_taken_after_the_hold() -> None:
    # Found by the model above: on a line whose link has shown lateness (a guard read's tail came in
    # its resync, so every deadline and resync gets an extra), a stream transaction gives up after
    # its short wait and its reply comes where a timeout's resync would still have been listening,
    # a quiet time and the extra after the full deadline.  The servo was held back only to the full
    # deadline and a quiet time, so the stream's next transaction to it took that reply for its own.
    state = LineModel()
    state.open_line(echo=False, share=1)
    state.attach_stream(ids=[1], paced=False)
    state.advance(dt=0.3)
    state.inject(batch=[("drop", 0.0, []), ("tail_late", 1.0, [])])
    state.inject(batch=[("late", 1.0, []), ("clean", 0.0, [])])
    state.inject(batch=[("drop", 0.0, [])])
    state.advance(dt=0.3)
    state.each_request_ends_at_most_once_with_its_own_value()
    state.teardown()


def test_a_guard_read_twin_of_an_unheard_guard_read_leaves_the_stalls_backlog_suspect() -> None:
    # Found by the model (short allowance): a one-servo stream's free command answered late (heard), its guard read
    # (a2 01) sent as the far end stalled, got nothing; the stream's command after it got nothing either; the next
    # guard read, the first one's twin, took the first one's echo and reply as they came, and that echo, taken for
    # its own, cleared every command remembered without its echo: the stream's next free command then took the
    # stalled one's reply (value 4 for write 4, answered 6).  The replay of the steps hypothesis found.
    state = ShortAllowanceLineModel()

    def step(rule: str, **args: object) -> None:
        getattr(state, rule)(**args)
        state.counters_add_up()
        state.each_request_ends_at_most_once_with_its_own_value()
        state.state_and_deadline()

    step("open_line", echo=True, share=1)
    step("noise", n=1)
    step("advance", dt=0.001)
    step("inject", batch=[("late", 0.75, [])])
    step("inject", batch=[("stall", 0.75, [])])
    step("advance", dt=0.3)
    step("attach_stream", ids=[2], paced=True)
    step("advance", dt=0.3)
    state.teardown()
