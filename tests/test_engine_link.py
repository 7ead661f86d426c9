"""The slow link (engine/link.py) as the engine sees it: late reply tails raise every allowance, within a bound.

A bridge that holds a reply's tail makes long replies time out; the tail then
arrives during the resync.  The engine learns from it (``link.extra``), so the
same transaction succeeds next time; the extra never passes its bound (a dead
servo still times out in bounded time) and decays once the link is fast again.
Plain calls and simulated time only: no event loop.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import pytest

from ics35_async.engine import BusTiming, LineEngine, State
from ics35_async.errors import InvalidArgument, ReplyTimeout
from tests.support.engine_support import Recorded, Servos, Wire, read, ready_engine, wire_time

CMD = read(3)
NBYTES = len(CMD.tx) + CMD.reply_len


class HeldTail(Servos):
    """Servos behind a bridge that holds each reply's tail: the first byte comes at once, the rest ``hold(engine)``
    seconds after the command was written."""

    def __init__(self, ids: set[int], hold: Callable[[LineEngine], float]) -> None:
        super().__init__(ids)
        self.hold = hold

    def deliver(self, wire: Wire, tx: bytes, reply: bytes) -> None:
        wire.schedule(wire.now + wire_time(len(tx) + 1) + self.turnaround, reply[:1])
        wire.schedule(wire.now + self.hold(wire.engine), reply[1:])


def base(engine: LineEngine) -> float:
    return engine.timing.allowance(NBYTES, engine.baudrate)


def one(wire: Wire, command: object = CMD, retries: int = 0) -> Recorded:
    req = Recorded(command, retries=retries)  # type: ignore[arg-type]
    wire.submit(req)
    wire.settle()
    return req


def learn_to_the_bound(wire: Wire) -> None:
    """Tails that always land in the middle of the resync after the timeout, so the lateness keeps growing."""
    engine = wire.engine
    seen = []
    for _ in range(30):
        one(wire)
        seen.append(engine.link.extra)
        assert engine.link.extra <= engine.link.bound
        if engine.link.extra == engine.link.bound:
            break
    assert seen == sorted(seen) and engine.link.extra == engine.link.bound, seen


def growing_tail(engine: LineEngine) -> float:
    # Written just now: the deadline is this transaction's; the resync after a partial reply
    # listens for max(quiet + extra, base) -- land halfway through it.
    b = base(engine)
    window = max(engine.timing.quiet_time + engine.link.extra, b)
    return b + engine.link.extra + window / 2


def test_a_late_tail_raises_the_allowance_and_the_retry_succeeds() -> None:
    engine = ready_engine()
    hold = base(engine) + 0.009  # 9 ms past the deadline: inside the resync that follows
    servos = HeldTail({3}, lambda _: hold)
    wire = Wire(engine, servos)
    assert engine.link.extra == 0
    req = one(wire, retries=1)
    assert req.result() == servos.answers[-1]
    assert engine.link.extra > hold - base(engine)
    stats = engine.counters.snapshot(0).per_id[3]
    assert stats.partial_replies == 1 and stats.retries == 1
    # From now on the same transaction succeeds first time.
    again = one(wire)
    assert again.result() == servos.answers[-1]
    assert engine.counters.snapshot(0).per_id[3].partial_replies == 1


def test_the_learnt_extra_moves_every_deadline_and_the_quiet_time() -> None:
    engine = ready_engine()
    wire = Wire(engine, HeldTail({3}, lambda e: base(e) + 0.009))
    one(wire, retries=1)
    extra = engine.link.extra
    assert extra > 0
    t0 = wire.now
    wire.submit(Recorded(read(4)))  # nobody answers
    assert engine.deadline - t0 == pytest.approx(base(engine) + extra)
    wire.run_until(engine.deadline)
    assert engine.state is State.QUIET
    assert engine.deadline - wire.now >= engine.timing.quiet_time + extra - 1e-9


def test_extra_never_exceeds_its_bound() -> None:
    engine = ready_engine()
    wire = Wire(engine, HeldTail({3}, growing_tail))
    learn_to_the_bound(wire)
    for _ in range(3):  # later, still later tails change nothing
        one(wire)
        assert engine.link.extra == engine.link.bound


def test_a_dead_servo_still_times_out_within_base_allowance_plus_the_bound() -> None:
    engine = ready_engine()
    wire = Wire(engine, HeldTail({3}, growing_tail))
    learn_to_the_bound(wire)
    t0 = wire.now
    dead = Recorded(read(9))
    wire.submit(dead)
    assert engine.deadline - t0 <= base(engine) + engine.link.bound + 1e-9
    wire.run_until(t0 + base(engine) + engine.link.bound)
    assert isinstance(dead.error, ReplyTimeout)


def test_the_extra_decays_once_the_link_is_fast_again() -> None:
    engine = ready_engine()
    slow = True
    servos = HeldTail({3}, lambda e: base(e) + 0.009 if slow else wire_time(NBYTES) + 0.001)
    wire = Wire(engine, servos)
    one(wire, retries=1)
    learnt = engine.link.extra
    slow = False
    window = engine.link.window
    history = []
    for _ in range(window * (math.ceil(math.log2(learnt / 0.001)) + 3)):
        assert one(wire).state == "done"
        history.append(engine.link.extra)
        if not history[-1]:
            break
    # A window of transactions after the late bytes before it moves (the learning request's own
    # transactions are the window's first).
    assert history[: window - 3] == [learnt] * (window - 3)
    assert history == sorted(history, reverse=True)  # never up without late bytes
    assert history[-1] == 0.0


def test_a_link_that_still_needs_the_extra_keeps_it() -> None:
    engine = ready_engine()
    first = True

    def hold(e: LineEngine) -> float:
        # Late at first (learnt), then always past the base allowance but inside the learnt one.
        return base(e) + (0.009 if first else e.link.extra / 2)

    wire = Wire(engine, HeldTail({3}, hold))
    one(wire, retries=1)
    learnt = engine.link.extra
    first = False
    for _ in range(3 * engine.link.window):
        assert one(wire).state == "done"
    assert engine.link.extra == learnt


def test_noise_on_an_idle_line_teaches_nothing() -> None:
    engine = ready_engine()
    engine.receive(b"\x55", 1.0)
    engine.tick(engine.deadline)
    assert engine.link.extra == 0


def test_late_bytes_after_a_wrong_echo_teach_nothing() -> None:
    # A command whose echo came back wrong was never heard: nothing it caused can be late.
    engine = ready_engine()
    engine.submit(Recorded(CMD), 0.0)
    engine.receive(b"\xa3\x7f", 0.0002)
    engine.tick(engine.deadline)
    engine.receive(CMD.encode_reply(5), engine.deadline - 0.001)
    assert engine.link.extra == 0


def test_bytes_in_a_later_resync_teach_nothing() -> None:
    engine = ready_engine()
    engine.submit(Recorded(CMD), 0.0)
    engine.tick(engine.deadline)  # timed out: the resync right after it may learn
    engine.tick(engine.deadline)  # resync over
    assert engine.state is State.IDLE
    engine.receive(b"\x23", 0.2)  # stray: starts another resync, long after the deadline
    engine.receive(b"\x02", 0.201)
    assert engine.link.extra == 0


@pytest.mark.parametrize("bound", [0.0, 0.004, 0.1])
def test_the_bound_is_the_timing_setting_link_extra_max(bound: float) -> None:
    # A line whose bytes can look like late replies (noise, a fuzzing double) must not wait
    # more than the program allows: the learnt extra stops at BusTiming.link_extra_max.
    engine = ready_engine(timing=BusTiming(link_extra_max=bound))
    wire = Wire(engine, HeldTail({3}, growing_tail))
    for _ in range(30):
        one(wire)
        assert engine.link.extra <= bound
    if bound == 0.1:  # tails within the bound are learnt up to it (later ones are not learnt at all)
        assert engine.link.extra == bound


def test_link_extra_max_is_checked_like_every_other_timing() -> None:
    with pytest.raises(InvalidArgument, match="link_extra_max"):
        BusTiming(link_extra_max=-0.1)
