"""The engine's rules between transactions: guard reads, priorities, the stream's share, retries, cancellation.

Plain calls and simulated time only (see engine_support): no event loop.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from typing import Any

import pytest

from ics35_async import protocol
from ics35_async.engine import FlushInput, Priority, State
from ics35_async.errors import ReplyTimeout
from ics35_async.protocol import Param, guard_read
from tests.support.engine_support import (
    BAUD,
    FakeSource,
    Recorded,
    Servos,
    StalledPipe,
    Wire,
    misattributed,
    position,
    read,
    ready_engine,
    wire_time,
)


def line(ids: set[int], **options: object) -> tuple[Wire, Servos]:
    engine = ready_engine(**options)  # type: ignore[arg-type]
    servos = Servos(ids, echo=engine.echo)
    return Wire(engine, servos), servos


# ---------------------------------------------------------------- the guard read


def test_a_twin_of_a_timed_out_command_is_preceded_by_the_guard_read() -> None:
    wire, servos = line({3})
    servos.mute = {0}
    first, twin = Recorded(read(3)), Recorded(read(3))
    wire.submit(first)
    wire.run_for(0.025)  # past the deadline: the resync is running
    assert isinstance(first.error, ReplyTimeout) and wire.engine.state is State.QUIET
    wire.submit(twin)
    wire.settle()
    guard = protocol.guard_read(read(3).tx, 3)
    assert guard.tx == read(3, Param.STRETCH).tx
    assert wire.sent() == [read(3).tx, guard.tx, read(3).tx]
    assert twin.result() == servos.answers[2]
    assert wire.engine.counters.guards == 1


def test_the_guard_for_a_stretch_read_reads_the_speed() -> None:
    wire, servos = line({3})
    servos.mute = {0}
    wire.submit(Recorded(read(3, Param.STRETCH)))
    wire.run_for(0.025)
    wire.submit(Recorded(read(3, Param.STRETCH)))
    wire.settle()
    assert wire.sent()[1] == read(3, Param.SPEED).tx


def test_a_late_reply_lands_in_the_guard_and_the_twin_gets_its_own() -> None:
    wire, servos = line({3})
    servos.mute = {0}
    first, twin = Recorded(read(3)), Recorded(read(3))
    wire.submit(first)
    wire.submit(twin)
    deadline = wire.engine.deadline
    wire.run_until(deadline)  # the first one timed out; the resync runs
    resync_end = wire.engine.deadline
    # The first command's reply, very late: just after the guard's echo, inside the guard's transaction.
    wire.schedule(resync_end + 0.0003, read(3).encode_reply(99))
    wire.settle()
    assert wire.sent() == [read(3).tx, read(3, Param.STRETCH).tx, read(3).tx]
    assert isinstance(first.error, ReplyTimeout)
    assert twin.result() == servos.answers[2] != 99
    assert wire.engine.counters.snapshot(0).per_id[3].bad_replies == 1  # the guard took the blow


def test_a_guard_that_times_out_does_not_guard_the_command_it_protected_again() -> None:
    wire, servos = line({3})
    servos.mute = {0, 1}  # the command and its guard go unanswered
    first, twin = Recorded(read(3)), Recorded(read(3))
    wire.submit(first)
    wire.submit(twin)
    wire.settle()
    assert wire.sent() == [read(3).tx, read(3, Param.STRETCH).tx, read(3).tx]
    assert twin.result() == servos.answers[2]
    assert wire.engine.counters.guards == 1


# A far end that stalls (a pty simulator not scheduled, an adapter or a bridge holding bytes) sends a command's echo
# and reply late together, and everything written meanwhile behind them, in order.  A command whose echo never came
# says nothing of what is still on its way: only a command's own echo, first, shows that the older bytes are gone.
STALLS = [n / 1000 for n in range(2, 300, 2)]  # from one allowance to many, with every phase of the retries


@pytest.mark.parametrize("retries", [1, 2, 4])
def test_a_stalled_line_hands_no_request_another_attempts_reply(retries: int) -> None:
    taken = []
    for stall in STALLS:
        engine = ready_engine()
        servos = StalledPipe({3}, 0.0, stall)
        wire = Wire(engine, servos)
        req = Recorded(read(3), retries=retries, wire=wire)
        wire.submit(req)
        wire.settle()
        if req.state == "done" and (problem := misattributed(req, servos)) is not None:
            taken.append(f"stalled {stall * 1e3:.0f} ms: {problem}; sent {[tx.hex(' ') for tx in wire.sent()]}")
    assert not taken, "\n".join(taken[:5])


@pytest.mark.parametrize("between", [read(4), position(5)], ids=["a read of another servo", "another servo's move"])
def test_a_stalled_line_hands_no_request_an_older_twins_reply_past_another_command(
    between: protocol.Command[int],
) -> None:
    # The twin comes after another command, which got nothing back either: it proves nothing.
    taken = []
    for stall in STALLS:
        engine = ready_engine()
        servos = StalledPipe({3, 4, 5}, 0.0, stall)
        wire = Wire(engine, servos)
        first, other, twin = Recorded(read(3), wire=wire), Recorded(between), Recorded(read(3), wire=wire)
        for req in (first, other, twin):
            wire.submit(req)
        wire.settle()
        for req in (first, twin):
            if req.state == "done" and (problem := misattributed(req, servos)) is not None:
                taken.append(f"stalled {stall * 1e3:.0f} ms: {problem}; sent {[tx.hex(' ') for tx in wire.sent()]}")
    assert not taken, "\n".join(taken[:5])


@pytest.mark.parametrize("retries", [0, 1])
def test_a_stalled_line_hands_no_command_another_ones_reply_whatever_went_between(retries: int) -> None:
    # Three commands sent in one stall, in every order, of a servo's reads in both guard reads' shapes (stretch,
    # speed), its current read, a move, another servo's read: a guard read going then must be a twin of none of
    # them but the last, whose echo and reply, taken for its own, show that every older one's came first (found:
    # a speed read after two stretch reads, or after a current read and a stretch read, took a late reply).
    commands = {
        "stretch": read(3, Param.STRETCH),
        "speed": read(3, Param.SPEED),
        "current": read(3, Param.CURRENT),
        "move": position(3),
        "other": read(4),
    }
    taken = []
    for names in itertools.product(commands, repeat=3):
        for stall in STALLS[::3]:
            engine = ready_engine()
            servos = StalledPipe({3, 4}, 0.0, stall)
            wire = Wire(engine, servos)
            sent = [Recorded(commands[name], retries=retries, wire=wire) for name in names]
            for req in sent:
                wire.submit(req)
            wire.settle()
            for req in sent:
                if req.state == "done" and (problem := misattributed(req, servos)) is not None:
                    writes = [tx.hex(" ") for tx in wire.sent()]
                    taken.append(f"{names} stalled {stall * 1e3:.0f} ms: {problem}; sent {writes}")
    assert not taken, "\n".join(taken[:5])


def test_a_stalled_line_hands_a_stream_no_reply_of_an_earlier_transaction() -> None:
    taken = []
    for stall in STALLS:
        engine = ready_engine()
        servos = StalledPipe({1}, 0.0005, 0.0005 + stall)
        wire = Wire(engine, servos)
        source = FakeSource([1], wake_at=0.0, period=0.004)

        def check(sid: int, value: int, wire: Wire = wire, servos: StalledPipe = servos, stall: float = stall) -> None:
            k = len(wire.writes) - 1
            if servos.answers[k] != value:
                taken.append(
                    f"stalled {stall * 1e3:.0f} ms: the stream got {value}, write {k} was answered {servos.answers[k]}"
                )

        source.on_value = check
        wire.emit(engine.attach_source(source, 0.0))
        wire.run_for(0.5)
    assert not taken, "\n".join(taken[:5])


@pytest.mark.parametrize("ids", [[1], [1, 2, 3]], ids=["one servo", "three servos"])
def test_a_stalled_line_hands_no_read_beside_a_stream_another_reads_reply(ids: list[int]) -> None:
    # A program reading a servo's stretch and speed beside a stream as the line stalls (found: the second read took
    # the reply to the first one's guard read, with the old rule's guard a twin of the first read).
    taken = []
    orders = ((Param.STRETCH, Param.SPEED), (Param.SPEED, Param.STRETCH))
    for shapes, start, stall in itertools.product(orders, (0.0013, 0.0031), STALLS[::2]):
        engine = ready_engine()
        servos = StalledPipe(set(ids), start, start + stall)
        wire = Wire(engine, servos)
        source = FakeSource(ids, wake_at=0.0, period=0.004 / len(ids))
        where = f"{[p.name for p in shapes]} stalled {stall * 1e3:.0f} ms from {start * 1e3:.1f}"

        def check(sid: int, value: int, wire: Wire = wire, servos: StalledPipe = servos, where: str = where) -> None:
            k = len(wire.writes) - 1
            if servos.answers[k] != value:
                taken.append(f"{where}: the stream got {value}, write {k} was answered {servos.answers[k]}")

        source.on_value = check
        wire.emit(engine.attach_source(source, 0.0))
        reads = [Recorded(read(1, param), retries=1, wire=wire) for param in shapes]
        wire.run_for(start + 0.0005)
        for req in reads:
            wire.submit(req)
        wire.run_for(0.4)
        for req in reads:
            if req.state == "done" and (problem := misattributed(req, servos)) is not None:
                taken.append(f"{where}: {problem}; sent {[tx.hex(' ') for tx in wire.sent()[:8]]}")
    assert not taken, "\n".join(taken[:5])


def test_a_line_that_never_answers_fails_a_request_after_its_attempts() -> None:
    # Nothing comes back at all (an adapter that takes bytes and sends none): however many guard reads go before
    # its retries, the request still fails, after no more transactions than its tries and a guard before each retry.
    engine = ready_engine()
    wire = Wire(engine)  # (no answer at all: not even the echo)
    req = Recorded(read(3), retries=2)
    wire.submit(req)
    wire.settle()
    assert isinstance(req.error, ReplyTimeout)
    sent = wire.sent()
    assert len(sent) <= 1 + 2 * 2, [tx.hex(" ") for tx in sent]
    assert engine.describe(wire.now)["guard_unheard"] == ["a3 02", "a3 01"]  # (what a dump of a stuck line shows)
    # A guard read that got nothing spent a try without sending the command again: ``retries`` counts the times it
    # went again (the chaos soak's check of a stream's close found one send fewer than the count).
    assert len(sent) > sent.count(read(3).tx) + 1, [tx.hex(" ") for tx in sent]
    assert engine.counters.snapshot(0).per_id[3].retries == sent.count(read(3).tx) - 1


def test_a_twin_failed_by_its_guard_reads_on_a_silent_line_ends_once() -> None:
    # Its tries spent on a guard read that got nothing, it fails off the queue: the port lost in the resync after
    # it (every queued request fails) does not hand it a second outcome.
    engine = ready_engine()
    wire = Wire(engine)
    first, twin = Recorded(read(3)), Recorded(read(3))
    wire.submit(first)
    wire.submit(twin)
    for _ in range(3):  # the first times out; the resync ends and the guard read goes; the guard read times out
        wire.run_until(engine.deadline)
    assert isinstance(twin.error, ReplyTimeout) and wire.sent() == [read(3).tx, guard_read(read(3).tx, 3).tx]
    engine.lost("unplugged", reconnect=False)
    assert (first.calls, twin.calls) == (1, 1)


def test_a_fresh_port_forgets_the_commands_whose_echo_never_came() -> None:
    engine = ready_engine()
    wire = Wire(engine)
    wire.submit(Recorded(read(3)))
    wire.settle()
    assert engine.describe(wire.now)["guard_unheard"] == ["a3 02"]
    engine.lost("unplugged", reconnect=True)
    wire.emit(engine.connected(wire.now))
    assert engine.describe(wire.now)["guard_unheard"] == []  # (bytes from before cannot come through a new port)


@pytest.mark.parametrize("other", [position(3), read(4)], ids=["same servo, other command", "other servo"])
def test_a_different_command_goes_straight_on(other: protocol.Command[int]) -> None:
    wire, servos = line({3, 4})
    servos.mute = {0}
    wire.submit(Recorded(read(3)))
    nxt = Recorded(other)
    wire.submit(nxt)
    wire.settle()
    assert wire.sent() == [read(3).tx, other.tx]
    assert nxt.result() == servos.answers[1] and wire.engine.counters.guards == 0


def test_a_wrong_echo_at_the_deadline_arms_no_guard() -> None:
    # The servo never heard the command (the echo came back wrong), so no reply can come late.
    engine = ready_engine()
    first = Recorded(read(3))
    engine.submit(first, 0.0)
    engine.receive(b"\xa3\x7f", 0.0002)
    engine.tick(engine.deadline)
    engine.submit(Recorded(read(3)), engine.deadline)
    assert engine.tick(engine.deadline) == FlushInput(read(3).tx)  # after the resync: no guard read first
    assert engine.counters.guards == 0


@pytest.mark.parametrize("silent_answers", [False, True], ids=["silent stays silent", "silent answers"])
def test_a_free_to_a_silent_servo_between_a_timeout_and_its_twin_leaves_the_guard_read(silent_answers: bool) -> None:
    # A stream closing while a read of servo 3 had timed out: its free to offline servo 4 goes without a guard
    # read, and whether that free times out too or is answered, the twin of the read still gets one, so the
    # read's late reply cannot pass for the twin's.
    wire, servos = line({3, 4} if silent_answers else {3})
    servos.mute = {0}
    first, twin = Recorded(read(3)), Recorded(read(3), wire=wire)
    free = Recorded(protocol.SilentFree(4, baudrate=BAUD))
    wire.submit(first)
    wire.submit(free)
    wire.submit(twin)
    late = read(3).encode_reply(99)

    def late_reply_after_the_next_echo() -> None:  # as late as the late reply a guard exists for
        if len(wire.writes) == 2:  # (the write after the free's is going out)
            wire.schedule(wire.now + wire_time(len(read(3).tx)) + 0.0003, late)

    wire.run_until(wire.engine.deadline)  # the read timed out
    wire.on_write = late_reply_after_the_next_echo
    wire.settle()
    assert isinstance(first.error, ReplyTimeout)
    assert misattributed(twin, servos) is None, twin.value
    assert wire.sent() == [read(3).tx, free.command.tx, read(3, Param.STRETCH).tx, read(3).tx]


# ---------------------------------------------------------------- priorities and the stream's share


def test_urgent_runs_first_and_each_level_is_fifo() -> None:
    wire, _ = line({1, 2, 3, 4, 5, 6, 7})
    wire.submit(Recorded(read(1)))  # on the wire while the others queue
    queued = [
        (2, Priority.NORMAL),
        (3, Priority.NORMAL),
        (4, Priority.URGENT),
        (5, Priority.LOW),
        (6, Priority.HIGH),
        (7, Priority.NORMAL),
    ]
    for sid, prio in queued:
        wire.submit(Recorded(read(sid), prio))
    wire.settle()
    assert [tx[0] & 0x1F for tx in wire.sent()] == [1, 4, 6, 2, 3, 7, 5]


def stream_or_request(sent: list[bytes]) -> str:
    """The writes in order as letters: ``S`` a position command (the stream's), ``R`` any other (a request's)."""
    return "".join("S" if tx[0] & 0xE0 == protocol.CMD_POSITION else "R" for tx in sent)


def test_the_stream_gets_a_turn_after_at_most_max_requests_between() -> None:
    wire, _ = line({1, 2, *range(10, 30)}, max_requests_between=3)
    source = FakeSource([1, 2])
    wire.emit(wire.engine.attach_source(source, wire.now))
    requests = [Recorded(read(sid)) for sid in range(10, 30)]
    for req in requests:
        wire.submit(req)
    wire.run_for(0.2)
    assert all(req.state == "done" for req in requests)
    kinds = stream_or_request(wire.sent())
    assert max(len(run) for run in kinds.split("S")) <= 3
    assert "RRRR" not in kinds and kinds.count("R") == 20
    assert len(source.values) == kinds.count("S") - (wire.engine.state is State.BUSY)
    assert {sid for sid, _ in source.values} == {1, 2}


def test_after_a_request_beside_a_stream_the_programs_next_turn_comes_before_the_streams_next_transaction() -> None:
    # A caller reading several values in a row beside a stream (current, then temperature) waited a whole stream
    # transaction for each read after its first: the stream's next was put on the wire as the first read's reply
    # came in, before the caller had its turn to ask again.  The line now waits for the driver's next turn
    # (a deadline of now): a request made by then goes first, else the stream goes on.
    for follow_up in (True, False):
        engine = ready_engine()
        source = FakeSource([1])
        stream_tx = position(1, 0)
        assert engine.attach_source(source, 0.0) == stream_tx.tx
        first, second = Recorded(read(3)), Recorded(read(3, Param.TEMPERATURE))
        assert engine.submit(first, 0.0005) is None  # (queued behind the stream's transaction)
        assert engine.receive(stream_tx.tx + stream_tx.encode_reply(7500), 0.001) == read(3).tx
        assert engine.receive(read(3).tx + read(3).encode_reply(9), 0.002) is None
        assert first.result() == 9 and engine.deadline == 0.002 and engine.state is State.IDLE
        if follow_up:
            assert engine.submit(second, 0.002) == read(3, Param.TEMPERATURE).tx
        else:
            assert engine.tick(0.002) == stream_tx.tx
    # Not after a LOW one: background reads (a safety watch's, a live table's) slip in between the stream's
    # transactions and take no more of the line.
    engine = ready_engine()
    source = FakeSource([1])
    engine.attach_source(source, 0.0)
    engine.submit(Recorded(read(3), priority=Priority.LOW), 0.0005)
    assert engine.receive(stream_tx.tx + stream_tx.encode_reply(7500), 0.001) == read(3).tx
    assert engine.receive(read(3).tx + read(3).encode_reply(9), 0.002) == stream_tx.tx


def test_the_sources_wake_at_becomes_the_deadline_when_it_has_nothing() -> None:
    engine = ready_engine()
    source = FakeSource([1], wake_at=5.0)
    source.active = False
    assert engine.attach_source(source, 0.0) is None
    assert engine.deadline == 5.0 and engine.state is State.IDLE
    assert engine.tick(4.9) is None
    # A request still goes while the source has nothing.
    req = Recorded(read(3))
    assert engine.submit(req, 4.9) == read(3).tx
    engine.receive(read(3).tx + read(3).encode_reply(7), 4.901)
    assert req.result() == 7 and engine.deadline == 4.901  # (the caller's next turn first)
    assert engine.tick(4.901) is None and engine.deadline == 5.0
    source.active = True
    asked = source.asked
    assert engine.tick(5.0) == position(1, 0).tx
    assert source.asked == asked + 1


def test_kick_starts_a_source_that_waits_for_no_time() -> None:
    engine = ready_engine()
    source = FakeSource([1])
    source.active = False
    engine.attach_source(source, 0.0)
    assert engine.deadline == math.inf
    source.active = True
    assert engine.kick(1.0) == position(1, 0).tx
    assert engine.kick(1.0) is None  # busy: the source is asked again once the line is free


def test_a_source_transaction_displaced_by_a_guard_is_asked_for_again() -> None:
    wire, servos = line({1})
    servos.mute = {0}
    wire.submit(Recorded(position(1, 0)))  # times out: a position twin must wait for a guard
    wire.run_for(0.022)
    source = FakeSource([1])
    wire.emit(wire.engine.attach_source(source, wire.now))
    wire.run_for(0.05)
    assert wire.sent()[:3] == [position(1, 0).tx, read(1, Param.STRETCH).tx, position(1, 0).tx]
    assert source.values and not source.failures


# ---------------------------------------------------------------- retries


def test_an_idempotent_command_is_retried_and_counted() -> None:
    wire, servos = line({3})
    servos.mute = {0}
    req = Recorded(read(3), retries=2)
    wire.submit(req)
    wire.settle()
    # the retry follows a timeout, so a guard goes first
    assert wire.sent() == [read(3).tx, read(3, Param.STRETCH).tx, read(3).tx]
    assert req.result() == servos.answers[2] and req.calls == 1
    assert wire.engine.counters.snapshot(0).per_id[3].retries == 1


def test_retries_run_out_with_the_last_error() -> None:
    wire, _ = line(set())
    req = Recorded(read(3), retries=2)
    wire.submit(req)
    wire.settle()
    assert [tx for tx in wire.sent() if tx == read(3).tx] == [read(3).tx] * 3
    assert isinstance(req.error, ReplyTimeout) and req.calls == 1
    stats = wire.engine.counters.snapshot(0).per_id[3]
    assert stats.retries == 2 and stats.timeouts == 5  # three tries and two guards


def test_a_bad_reply_is_retried_after_a_timeouts_resync_and_a_guard_read() -> None:
    # The bytes were another servo's: this one's reply may still come, as late as after a timeout.
    engine = ready_engine()
    req = Recorded(read(3), retries=1)
    tx = engine.submit(req, 0.0)
    reply = read(3).encode_reply(5)
    due = engine.deadline
    engine.receive(tx + b"\x24" + reply[1:], 0.001)  # another servo's header
    assert req.state == "queued" and engine.state is State.QUIET
    assert engine.deadline == pytest.approx(due + engine.timing.quiet_time)
    guard = guard_read(read(3).tx, 3)
    t = engine.deadline
    # The retry has the same command byte: a guard read first (after the input is dropped).
    assert engine.tick(t) == FlushInput(guard.tx)
    assert engine.receive(guard.tx + guard.encode_reply(1), t + 0.001) == tx  # then the retry
    engine.receive(tx + reply, t + 0.002)
    assert req.result() == 5 and engine.counters.snapshot(0).total.retries == 1


def test_a_command_that_acts_is_never_retried() -> None:
    wire, _ = line(set())
    write = protocol.WriteMemory(3, 0x10, b"\x01")
    assert not write.idempotent
    req = Recorded(write, retries=3)
    wire.submit(req)
    wire.settle()
    assert wire.sent() == [write.tx]
    assert isinstance(req.error, ReplyTimeout)
    assert wire.engine.counters.snapshot(0).total.retries == 0


# ---------------------------------------------------------------- cancellation


def test_a_cancelled_queued_request_is_skipped() -> None:
    wire, servos = line({1, 2, 3})
    a, b, c = Recorded(read(1)), Recorded(read(2)), Recorded(read(3))
    for req in (a, b, c):
        wire.submit(req)
    b.cancel()
    wire.settle()
    assert wire.sent() == [read(1).tx, read(3).tx]
    assert b.state == "cancelled" and b.calls == 0
    assert a.result() == servos.answers[0] and c.result() == servos.answers[1]


def test_a_request_cancelled_on_the_wire_has_its_reply_consumed_and_the_next_gets_its_own() -> None:
    engine = ready_engine()
    a, b = Recorded(read(3)), Recorded(read(3))
    tx = engine.submit(a, 0.0)
    engine.submit(b, 0.0)
    engine.receive(tx + b"\x23", 0.0005)
    a.cancel()
    # The rest of a's reply: consumed and dropped, and b goes straight on.
    assert engine.receive(b"\x02\x11", 0.001) == read(3).tx
    assert a.state == "cancelled" and a.value is None
    engine.receive(tx + read(3).encode_reply(0x22), 0.002)
    assert b.result() == 0x22
    assert engine.counters.stray == 0 and engine.counters.resyncs == 0
    assert engine.counters.snapshot(0).total.ok == 2


def test_a_request_cancelled_on_the_wire_that_times_out_is_not_retried() -> None:
    wire, _ = line(set())
    req = Recorded(read(3), retries=3)
    wire.submit(req)
    req.cancel()
    wire.settle()
    assert wire.sent() == [read(3).tx] and req.state == "cancelled"


def test_a_timed_out_guards_late_reply_is_not_taken_for_the_next_commands_reply() -> None:
    wire, servos = line({3})
    servos.mute = {0, 1}  # the read and its guard go unanswered in time
    first, twin = Recorded(read(3)), Recorded(read(3))
    wire.submit(first)
    wire.submit(twin)
    wire.run_until(wire.engine.deadline)  # the read timed out
    wire.run_until(wire.engine.deadline)  # resync over: the guard is on the wire
    assert wire.sent()[-1] == read(3, Param.STRETCH).tx
    wire.run_until(wire.engine.deadline)  # the guard timed out too
    resync_end = wire.engine.deadline
    urgent = Recorded(read(3, Param.STRETCH), Priority.URGENT, wire=wire)  # the guard's shape, ahead of the twin
    wire.submit(urgent)
    # The guard's reply, exactly as late as the late reply a guard exists for: right after the next echo.
    wire.schedule(resync_end + 0.0003, read(3, Param.STRETCH).encode_reply(99))
    wire.settle()
    assert urgent.state == "failed" or misattributed(urgent, servos) is None, urgent.value


def test_a_detached_sources_transaction_is_still_judged() -> None:
    engine = ready_engine(echo=False)
    servos = Servos({1}, echo=False)
    wire = Wire(engine, servos)
    source = FakeSource([1])
    assert wire.emit(engine.attach_source(source, 0.0)) == position(1, 0).tx
    engine.detach_source(source)  # the stream closes with its transaction on the wire
    req = Recorded(position(1, 0), wire=wire)
    wire.submit(req)
    wire.schedule(0.0001, b"\x02\x10\x10")  # before the reply: three bytes that are not it (ID 2's header)
    wire.settle()
    assert req.state == "failed" or misattributed(req, servos) is None, req.value


# ---------------------------------------------------------------- a stream with a rate is a deadline


def paced_line(period: float = 0.004, **options: Any) -> tuple[Wire, FakeSource]:
    wire, _ = line({1, *range(3, 32)}, **options)
    source = FakeSource([1], wake_at=0.0, period=period, paced=True)
    wire.emit(wire.engine.attach_source(source, wire.now))
    return wire, source


def teach_answer_times(wire: Wire) -> None:
    """A few answered requests, so the engine knows what an answer takes on this line."""
    for sid in (3, 4, 5):
        req = Recorded(read(sid))
        wire.submit(req)
        wire.run_for(0.02)
        assert req.state == "done"


def test_requests_use_the_slack_of_a_paced_stream_and_never_delay_a_slot() -> None:
    wire, source = paced_line()
    teach_answer_times(wire)
    requests = [Recorded(read(sid)) for sid in range(3, 32)] * 4
    source.started.clear()
    for req in requests:
        wire.submit(req)
    wire.run_for(0.3)
    assert all(req.state == "done" for req in requests)
    late = [began - slot for slot, began in source.started if began - slot > 1e-9]
    # A slot may only wait for the stream's own previous transaction, never for a request.
    assert not late, late
    # ...and the requests did get the slack: several between two slots.
    kinds = stream_or_request(wire.sent())
    assert max(len(run) for run in kinds.split("S")[1:-1]) >= 3


def test_an_urgent_request_outranks_a_due_slot() -> None:
    wire, source = paced_line()
    teach_answer_times(wire)
    wire.run_until(source.wake_at - 1e-6)  # the slot is about to come: no slack left for a read
    normal, urgent = Recorded(read(7)), Recorded(read(8), priority=Priority.URGENT)
    wire.submit(normal)
    wire.submit(urgent)
    wire.run_for(0.001)
    assert urgent.state == "done"  # went at once, ahead of the slot
    assert normal.state == "queued"  # waits for the stream's transaction and the slack after it
    wire.run_for(0.02)
    assert normal.state == "done"


def test_a_request_too_long_for_any_slack_still_runs_after_two_cycles() -> None:
    wire, _ = paced_line(period=0.004)
    teach_answer_times(wire)
    write = Recorded(protocol.WriteEeprom(3, protocol.Eeprom.factory(3)))  # longer than a 4 ms period
    wire.submit(write)
    wire.run_for(0.1)
    assert write.state == "done"
    # It went only after being passed over in two slacks: two slots kept, then one delayed once.
    position_writes = [t for t, tx in wire.writes if tx[0] & 0xE0 == protocol.CMD_POSITION]
    eeprom_at = next(t for t, tx in wire.writes if tx[:2] == write.command.tx[:2])
    assert sum(1 for t in position_writes if t < eeprom_at) >= 2 + 3  # 3 while learning answer times


def test_without_a_rate_the_stream_shares_by_count() -> None:
    wire, _ = line({1, *range(10, 30)}, max_requests_between=2)
    source = FakeSource([1], wake_at=0.0, period=0.004)  # one per period, but keeps no schedule
    wire.emit(wire.engine.attach_source(source, wire.now))
    requests = [Recorded(read(sid)) for sid in range(10, 30)]
    for req in requests:
        wire.submit(req)
    wire.run_for(0.3)
    assert all(req.state == "done" for req in requests)
    late = [began - slot for slot, began in source.started if began - slot > 1e-9]
    assert late  # requests ran over its wishes: it has no slots to keep


class EmptyCycles(FakeSource):
    """A paced source whose cycles have nothing to send (every ID held after a reconnect, or offline)."""

    def next_transaction(self, now: float) -> tuple[bytes, int, int] | None:
        while self.wake_at <= now:
            self.wake_at += self.period  # the slot passes with an empty cycle
        return None


def test_a_request_beside_a_paced_stream_with_nothing_to_send_still_runs() -> None:
    # A request whose expected time is unknown (a fresh port: the full allowance, longer than a
    # slot) must still get the line when the stream's cycles are empty, not wait for ever.
    wire, _ = line({1, 3})
    source = EmptyCycles([1], wake_at=0.0, period=0.004, paced=True)
    wire.emit(wire.engine.attach_source(source, wire.now))
    req = Recorded(read(3))
    wire.submit(req)
    wire.run_for(0.1)
    assert req.state == "done"


def test_a_request_beside_a_paced_stream_that_runs_late_still_runs() -> None:
    # Cycles longer than the period (more servos than the rate allows): every slot is past when a
    # cycle ends, so there is never a slack; a request still goes within two cycles, as when too long.
    wire, source = paced_line(period=0.0002)  # one position transaction takes about 0.6 ms
    reads = [Recorded(read(7)), Recorded(read(8))]
    for req in reads:
        wire.submit(req)
    wire.run_for(0.05)
    assert [req.state for req in reads] == ["done", "done"]
    assert len(source.started) > 20  # the stream went on, late as it is
    # Each read went only after the stream had kept an (overdue) slot, never two reads in a row.
    kinds = stream_or_request(wire.sent())
    assert kinds.startswith("S") and "RR" not in kinds and kinds.count("R") == 2, kinds[:20]


def test_a_new_stream_starts_its_own_count_of_slots_a_request_was_passed_over_in() -> None:
    # A request passed over once beside a late stream; that stream closes and another (late as
    # well) attaches while its last transaction is on the wire: the new stream's first overdue
    # slot is the first the request was passed over in beside it, so one of its transactions
    # goes first (the rule: it goes once passed over in two of the stream's slots).
    wire, old = paced_line(period=0.0002)
    wire.run_for(0.005)
    new = FakeSource([1], wake_at=0.0, period=0.0002, paced=True)
    swapped: list[int] = []

    def swap_after_one_pass() -> None:
        if not swapped:  # this write is the old stream's, made after passing the request over once
            swapped.append(len(wire.writes) + 1)
            wire.engine.detach_source(old)
            assert wire.engine.attach_source(new, wire.now) is None  # its transaction is on the wire

    req = Recorded(read(7))
    wire.submit(req)
    wire.on_write = swap_after_one_pass
    wire.run_for(0.05)
    assert req.state == "done" and new.started
    kinds = stream_or_request(wire.sent()[swapped[0] :])
    assert kinds.startswith("S") and kinds.count("R") == 1, kinds[:20]


def passed_over_once_then(then: Callable[[Wire, Recorded], None]) -> tuple[Recorded, str]:
    """A request passed over once beside a late stream, ``then(wire, it)`` done at the stream's write made after
    that pass, and the line run on: the request, and what went on the wire from that write on (S stream, R request)."""
    wire, _ = paced_line(period=0.0002)
    wire.run_for(0.005)
    first = Recorded(read(7))
    marks: list[int] = []

    def after_one_pass() -> None:
        if not marks:
            marks.append(len(wire.writes) + 1)
            then(wire, first)

    wire.submit(first)
    wire.on_write = after_one_pass
    wire.run_for(0.05)
    return first, stream_or_request(wire.sent()[marks[0] :])


def test_a_request_outranked_and_back_at_the_head_starts_its_count_of_slots_again() -> None:
    # The engine's hypothesis model found it: a request passed over once beside a late stream is outranked by an
    # URGENT one, which is cancelled before it goes; back at the head, the first kept its count and went at the
    # next overdue slot, ahead of the stream, with no stream transaction since it came to the head again.
    urgent = Recorded(read(8), priority=Priority.URGENT)

    def outranked(wire: Wire, first: Recorded) -> None:
        wire.submit(urgent)
        urgent.cancel()

    first, kinds = passed_over_once_then(outranked)
    assert urgent.state == "cancelled" and first.state == "done"
    assert kinds.startswith("S") and kinds.count("R") == 1, kinds[:20]


def test_a_request_does_not_inherit_the_slots_another_was_passed_over_in() -> None:
    # A request passed over once beside a late stream is cancelled; the next one is passed over in
    # slots of its own: one of the stream's transactions goes before it.
    second = Recorded(read(8))

    def cancelled(wire: Wire, first: Recorded) -> None:
        first.cancel()
        wire.submit(second)

    first, kinds = passed_over_once_then(cancelled)
    assert first.state == "cancelled" and second.state == "done"
    assert kinds.startswith("S") and kinds.count("R") == 1, kinds[:20]
