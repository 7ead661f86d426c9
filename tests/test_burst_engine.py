"""The burst path, engine side, in simulated time: the same line with and without bursts, compared.

A burst runs the stream's next transactions away from the engine and feeds their bytes back
afterwards (ics35_async.drivers.burst).  The engine keeps every rule, so on the same wire, with
the same servos, faults and requests at the same times, every write (its bytes and its time), every
outcome and every counter must be the same as on the ordinary path.  tests/support/burst_wire.py
plays the compiled executor's part on the simulated wire; the executor itself is tested on a pty in
tests/test_burst_executor.py.
"""

from __future__ import annotations

import random
from collections import Counter
from dataclasses import astuple, fields
from types import SimpleNamespace
from typing import Any

import pytest

from ics35_async import Frame, protocol
from ics35_async.drivers import burst
from ics35_async.drivers.burst import SHAPE
from ics35_async.engine import LineEngine, Priority
from ics35_async.errors import ReplyError, ReplyValueError
from ics35_async.protocol import Position
from ics35_async.stream import Stream

from .support.burst_wire import BurstWire
from .support.engine_support import TURNAROUND, FakeSource, Recorded, Servos, StalledOnce, Wire, read, ready_engine
from .support.paced_line import BAUD as PACED_BAUD
from .support.paced_line import PERIOD, PacedCycle

IDS = list(range(1, 9))


@pytest.fixture(autouse=True)
def bursts_beside_requests(monkeypatch: pytest.MonkeyPatch) -> None:
    """Bursts run beside requests (the library pauses them while requests are about), so that
    requests arrive mid-burst: the rules that decide where they go are what these tests compare."""
    monkeypatch.setattr(burst, "PAUSE_AFTER_REQUEST", 0.0)


def summary(wire: Wire, requests: list[Recorded]) -> dict[str, Any]:
    """Everything the line did, in values that compare exactly."""
    engine = wire.engine
    stats = engine.counters.snapshot(len(engine.queue.waiting()))
    return {
        "writes": wire.writes,
        "flushes": wire.flushes,  # input dropped as each resync ended, where the driver drops it
        "delivered": wire.delivered,
        "requests": [(r.state, r.value, type(r.error).__name__, r.write_index) for r in requests],
        "per_id": stats.per_id,
        "resyncs": stats.resyncs,
        "stray": stats.stray_bytes,
        "guards": stats.guards,
        "latency": (stats.latency.counts, stats.latency.sum_s),
        "held_back": engine.counters.held_back,
        "state": engine.state,
    }


class SlowAtTimes(Servos):
    """Servos that now and then answer late (2-12 ms beyond the usual turnaround): the stream's
    wait, learnt from the answers, moves up and down while bursts run."""

    def __init__(self, ids: list[int], baudrate: int, seed: int) -> None:
        super().__init__(ids, baudrate=baudrate)
        self.rng = random.Random(seed)

    def deliver(self, wire: Wire, tx: bytes, reply: bytes) -> None:
        self.turnaround = self.rng.uniform(0.002, 0.012) if self.rng.random() < 0.02 else TURNAROUND
        super().deliver(wire, tx, reply)


def servos_with_faults(engine: LineEngine, seed: int, mute_every: int, damage_every: int) -> SlowAtTimes:
    """:class:`SlowAtTimes` servos on IDS where every ``mute_every``-th write gets no reply and every
    ``damage_every``-th a damaged one (0: none; the first few writes are spared)."""
    servos = SlowAtTimes(IDS, engine.baudrate, seed)
    servos.mute = {k for k in range(5, 100_000) if mute_every and k % mute_every == 0}
    servos.damaged = {k for k in range(5, 100_000) if damage_every and k % damage_every == 0}
    return servos


def run_line(
    wire_class: type[Wire],
    *,
    seed: int,
    mute_every: int = 0,
    damage_every: int = 0,
    paced: bool = False,
    requests: int = 40,
    duration: float = 0.5,
) -> tuple[dict[str, Any], Wire]:
    """A stream over 8 servos with ``requests`` reads and position commands at random times."""
    rng = random.Random(seed)
    engine = ready_engine(baudrate=PACED_BAUD) if paced else ready_engine()
    wire = wire_class(engine, servos_with_faults(engine, seed, mute_every, damage_every))
    source: Any = PacedCycle(IDS, PERIOD) if paced else FakeSource(IDS)
    wire.emit(engine.attach_source(source, wire.now))
    recorded = []
    for _ in range(requests):
        sid = rng.choice([*IDS, 20])  # ID 20 is not on the line: its requests time out
        command = read(sid) if rng.random() < 0.7 else Position(sid, 7500, baudrate=engine.baudrate)
        priority = rng.choice([Priority.URGENT, Priority.HIGH, Priority.NORMAL, Priority.LOW])
        request = Recorded(command, priority, retries=rng.choice([0, 1]), wire=wire)
        recorded.append(request)
        wire.at(rng.uniform(0, duration * 0.8), lambda request=request: wire.submit(request))
    wire.run_for(duration)
    return summary(wire, recorded), wire


@pytest.mark.parametrize("paced", [False, True], ids=["unpaced", "paced"])
@pytest.mark.parametrize(
    ("mute_every", "damage_every"),
    [(0, 0), (61, 0), (0, 41)],
    ids=["healthy", "silent", "damaged"],  # damaged: a reply of the right length the stream refuses
)
@pytest.mark.parametrize("seed", range(3))
def test_a_burst_line_does_exactly_what_the_ordinary_line_does(
    paced: bool, mute_every: int, damage_every: int, seed: int
) -> None:
    faults = {"mute_every": mute_every, "damage_every": damage_every}
    plain, _ = run_line(Wire, seed=seed, paced=paced, **faults)
    burst, wire = run_line(BurstWire, seed=seed, paced=paced, **faults)
    assert isinstance(wire, BurstWire)
    # Bursts ran (after a fault the ordinary path runs until a late reply can no longer come).
    assert wire.runner.transactions > len(plain["writes"]) / (10 if mute_every or damage_every else 3)
    if damage_every:  # and some stopped at a damaged reply (the executor must not send the next command)
        assert wire.executor.stops[SHAPE] > 0
    if not mute_every and not damage_every:
        assert wire.executor.notices > 0  # and some were fed to the engine in parts while they ran
    assert burst["requests"] == plain["requests"]
    assert burst["writes"] == plain["writes"]
    assert burst == plain


@pytest.mark.parametrize(
    ("n", "news", "points"),
    [
        (32, [31], [14, 29]),  # one cycle: halfway, then three before the end (its frame: at the end)
        (128, [31, 63, 95, 127], [32, 64, 96, 110, 125]),  # four cycles: each frame, then as above
        (128, [17, 35, 53, 71, 89, 107, 125], [18, 36, 54, 72, 90, 108, 117, 126]),  # a frame near the end serves
        (5, [2, 4], [3]),  # short: its frames only
        (7, [], []),
        (20, [], [8, 17]),
    ],
)
def test_a_burst_is_fed_ahead_at_each_frame_and_a_few_before_its_end(
    n: int, news: list[int], points: list[int]
) -> None:
    assert burst.feed_ahead_points(n, news) == points


class SimulatedBus:
    """What a :class:`Stream` asks of its bus, on a simulated wire: a kick reaches the engine as the
    asyncio driver passes it on (where a running burst stops, if one runs)."""

    echo = True

    def __init__(self, wire: Wire) -> None:
        self.wire = wire
        self.baudrate = wire.engine.baudrate
        self.frames: list[Any] = []

    def kick(self) -> None:
        wire, engine = self.wire, self.wire.engine
        if isinstance(wire, BurstWire) and wire.runner.running:
            wire.runner.hold(engine.kick)
        else:
            wire.emit(engine.kick(wire.now))

    def detach_source(self, source: Any) -> None:
        self.wire.engine.detach_source(source)

    def notify(self, callback: Any) -> None:
        callback()


def run_stream(
    wire_class: type[Wire], *, seed: int, mute_every: int, damage_every: int, absent: bool, joins: bool = False
) -> tuple[dict[str, Any], Wire]:
    """The library's own stream over 8 servos, unpaced (its bursts run on through cycle after cycle),
    with reads and new targets from the program at random times; ``absent``: and an ID no servo has
    (offline, then probed now and then: the cycles it is probed in are not certain beforehand);
    ``joins``: a servo with that ID is plugged in a fifth of a second in (it answers a probe and is held)."""
    rng = random.Random(seed)
    engine = ready_engine()
    servos = servos_with_faults(engine, seed, mute_every, damage_every)
    wire = wire_class(engine, servos)
    bus = SimulatedBus(wire)
    ids = [*IDS[:4], 20, *IDS[4:]] if absent else IDS
    if joins:
        wire.at(0.2, lambda: servos.ids.add(20))
    stream = Stream(bus, ids, offline_after=2, probe_interval=0.1)  # type: ignore[arg-type]
    stream._running = True
    frames: list[tuple[Any, ...]] = []
    mid_burst = [0]  # frames published while a burst still ran (fed ahead where its cycle ended)

    def published() -> None:
        frames.append(astuple(stream._latest))
        mid_burst[0] += isinstance(wire, BurstWire) and wire.runner.running

    stream._wake_waiters = published  # type: ignore[method-assign]
    wire.emit(engine.attach_source(stream._hooks, wire.now))
    recorded = []
    for _ in range(20):
        request = Recorded(read(rng.choice(IDS)), rng.choice(list(Priority)), retries=0, wire=wire)
        recorded.append(request)
        wire.at(rng.uniform(0, 0.4), lambda request=request: wire.submit(request))
    for _ in range(30):
        targets = {sid: rng.randrange(3500, 11500) for sid in rng.sample(IDS, 3)}
        wire.at(rng.uniform(0, 0.4), lambda targets=targets: stream.set_targets(targets))
    if joins:  # targets for it too, before and after it answers (a held ID's new target is not sent)
        wire.at(0.1, lambda: stream.set_targets({20: 9000}))
        wire.at(0.3, lambda: stream.set_targets({20: 9100}))
    wire.run_for(0.5)
    return {**summary(wire, recorded), "frames": frames, "mid_burst": mid_burst[0]}, wire


@pytest.mark.parametrize(
    ("mute_every", "damage_every", "absent"),
    [(0, 0, False), (61, 0, False), (0, 41, False), (0, 0, True)],
    ids=["healthy", "silent", "damaged", "absent"],
)
@pytest.mark.parametrize("seed", range(3))
def test_the_librarys_stream_does_exactly_what_it_does_without_bursts(
    seed: int, mute_every: int, damage_every: int, absent: bool
) -> None:
    faults = {"mute_every": mute_every, "damage_every": damage_every, "absent": absent}
    plain, _ = run_stream(Wire, seed=seed, **faults)
    burst, wire = run_stream(BurstWire, seed=seed, **faults)
    assert isinstance(wire, BurstWire)
    assert max(wire.executor.plan_lengths) > 2 * len(IDS)  # plans ran on through cycles
    # (after each fault the ordinary path runs until a late reply can no longer come: an absent ID's probes are faults)
    assert wire.runner.transactions > len(plain["writes"]) / (10 if mute_every or damage_every or absent else 3)
    assert len(plain["frames"]) > 50
    if not mute_every and not damage_every and not absent:
        # frames did not wait for their burst's end (the cycles around a slow answer's hold, and the guard read
        # after it, run on the ordinary path)
        assert burst["mid_burst"] > len(burst["frames"]) / 4
    assert burst["writes"] == plain["writes"]
    assert burst["frames"] == plain["frames"]
    assert {**burst, "mid_burst": 0} == plain


@pytest.mark.parametrize("seed", range(3))
def test_a_servo_back_from_offline_is_held_alike_on_both_paths_and_sent_no_target(seed: int) -> None:
    # An offline ID's probe is a read with no shape (it ends a plan); it answers, and the ID comes back held.
    plain, _ = run_stream(Wire, seed=seed, mute_every=0, damage_every=0, absent=True, joins=True)
    burst, wire = run_stream(BurstWire, seed=seed, mute_every=0, damage_every=0, absent=True, joins=True)
    assert isinstance(wire, BurstWire) and wire.runner.transactions > 0
    assert burst["writes"] == plain["writes"] and burst["frames"] == plain["frames"]
    assert {**burst, "mid_burst": 0} == plain
    # Its target set while it was offline (9000) never goes out: probed with reads, it comes back held, and
    # only the target the program sets after that (at 0.3 s) is sent.
    moves = [(t, tx) for t, tx in plain["writes"] if tx[0] == 0x80 | 20 and tx[1:] != b"\x00\x00"]
    assert moves and all(t >= 0.3 and tx == protocol.position_tx(20, 9100) for t, tx in moves), moves[:3]
    assert any(t < 0.3 and tx == bytes((0xA0 | 20, 1)) for t, tx in plain["writes"])  # probed with a read
    held = [field.name for field in fields(Frame)].index("held")  # (the frames are compared as tuples)
    assert any(frame[held] == frozenset({20}) for frame in plain["frames"])


PLUGGED_IN = 0.03


def rejoining(wire_class: type[Wire]) -> tuple[Wire, Stream]:
    """Four servos streamed unpaced; ID 2, absent, goes offline, then is plugged in and answers a probe."""
    engine = ready_engine()
    servos = Servos([1, 3, 4])
    wire = wire_class(engine, servos)
    stream = Stream(SimulatedBus(wire), [1, 2, 3, 4], offline_after=1, probe_interval=0.05)  # type: ignore[arg-type]
    stream._running = True
    stream.set_targets({sid: 7000 + 100 * sid for sid in (1, 2, 3, 4)})
    wire.emit(engine.attach_source(stream._hooks, wire.now))
    wire.run_for(PLUGGED_IN)
    assert stream.offline == {2}
    servos.ids.add(2)
    wire.run_for(0.2)
    return wire, stream


def test_a_servo_back_from_offline_mid_cycle_is_planned_no_target_for_the_cycles_after() -> None:
    # Its probe answered mid-cycle: held from then on, but still in the cycle's order, so a burst planned at the
    # next transaction ran on into the next cycles with its old target (sent to a servo that may have restarted,
    # free, elsewhere), and the engine, whose next cycle leaves it out, diverged from the burst.
    plain, plain_stream = rejoining(Wire)
    wire, stream = rejoining(BurstWire)
    assert isinstance(wire, BurstWire) and wire.runner.transactions > 0
    assert plain_stream.held == stream.held == {2: "rejoined"}
    old = protocol.position_tx(2, 7200)
    assert [t for t, tx in wire.writes if tx == old and t > PLUGGED_IN] == []  # (sent before it went offline)
    assert wire.writes == plain.writes


def probing(ids: list[int], absent: int) -> tuple[Wire, Servos, Stream]:
    """A stream on the ordinary path whose ID ``absent`` (target 9000) has gone offline and is probed."""
    engine = ready_engine()
    servos = Servos([i for i in ids if i != absent])
    wire = Wire(engine, servos)
    stream = Stream(SimulatedBus(wire), ids, offline_after=1, probe_interval=0.01)  # type: ignore[arg-type]
    stream._running = True
    stream.set_targets({absent: 9000})
    wire.emit(engine.attach_source(stream._hooks, wire.now))
    wire.run_for(0.05)
    assert stream.offline == {absent}
    return wire, servos, stream


def run_until_written(wire: Wire, tx: bytes, limit: float = 0.5) -> None:
    """Run until ``tx`` has just been written (its answer, if any, still to come)."""
    seen = [w for _, w in wire.writes].count(tx)
    end = wire.now + limit
    while [w for _, w in wire.writes].count(tx) == seen:
        assert wire.now < end, f"{tx!r} never written"
        wire.run_for(1e-5)


@pytest.mark.parametrize("change", ["free", "watch"])
def test_an_id_freed_or_watched_while_its_probe_is_on_the_wire_comes_back_so_not_held(change: str) -> None:
    # The probe's answer came to an ID freed meanwhile (a safety stop's free): it came back "held" with the
    # free target, sent nothing, so the free never went out and the servo kept its old target's torque.
    wire, servos, stream = probing([1, 2], 2)
    servos.ids.add(2)  # back: it answers the next probe
    run_until_written(wire, bytes((0xA0 | 2, 1)))
    since = len(wire.writes)
    stream.free([2]) if change == "free" else stream.watch([2])
    wire.run_for(0.05)
    sent = [w for _, w in wire.writes[since:]]
    assert 2 not in stream.held
    if change == "free":
        assert stream.target(2) == protocol.FREE and protocol.position_tx(2, protocol.FREE) in sent
    else:
        assert protocol.ReadPosition(2).tx in sent


def test_a_probe_job_left_on_an_id_back_online_is_replaced_by_its_target() -> None:
    # A target set from another thread while the probe's answer brought the ID back could leave the probe's
    # read as the slot's job: the ID was then probed every cycle, held again at each answer.
    wire, servos, stream = probing([1, 2], 2)
    servos.ids.add(2)
    wire.run_for(0.05)
    assert stream.held == {2: "rejoined"}
    stream.set_targets({2: 9100})  # the program decides again
    stream._offline[1] = True  # the race's end: a probe job written for a slot online again
    stream._renew_job(1)
    stream._offline[1] = False
    since = len(wire.writes)
    wire.run_for(0.05)
    sent = [w for _, w in wire.writes[since:]]
    assert 2 not in stream.held and protocol.position_tx(2, 9100) in sent
    assert sent.count(bytes((0xA0 | 2, 1))) <= 1


def test_a_request_arriving_mid_burst_takes_the_next_boundary_beside_an_unpaced_stream() -> None:
    engine = ready_engine()
    wire = BurstWire(engine, Servos(IDS))
    wire.emit(engine.attach_source(FakeSource(IDS), wire.now))
    request = Recorded(read(3), wire=wire)
    wire.at(0.0101, lambda: wire.submit(request))
    wire.run_for(0.02)
    assert request.state == "done"
    k = request.write_index
    submitted_in = max(i for i, (t, _) in enumerate(wire.writes) if t <= 0.0101)
    assert k == submitted_in + 1  # the transaction after the one on the wire when it came
    assert wire.executor.runs > 2


def test_no_burst_starts_while_requests_are_about_and_whole_cycles_burst_again_after(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # A request that arrives mid-burst goes out only once the burst's bytes so far are fed to the
    # engine: while the program sends requests, the stream takes the ordinary path.
    monkeypatch.setattr(burst, "PAUSE_AFTER_REQUEST", 0.5)
    ids = list(range(16))
    engine = ready_engine()
    wire = BurstWire(engine, Servos(ids))
    wire.emit(engine.attach_source(FakeSource(ids), wire.now))
    wire.run_for(0.05)
    lengths = wire.executor.plan_lengths
    assert max(lengths) == len(ids)  # no request yet: the one on the wire and the rest of its cycle
    requests = [Recorded(read(k % 16), wire=wire) for k in range(20)]
    bursting: list[bool] = []
    for k, request in enumerate(requests):  # a poller: a read every 10 ms for 0.2 s
        wire.at(0.0505 + 0.01 * k, lambda request=request: (bursting.append(wire.runner.running), wire.submit(request)))
    wire.run_for(0.005)
    assert bursting == [True]  # the first request came mid-burst
    before = len(lengths)
    writes = len(wire.writes)
    wire.run_for(0.2)
    assert all(r.state == "done" for r in requests)
    assert len(lengths) == before  # no burst since
    assert len(wire.writes) - writes > 100  # while the stream ran on, the ordinary way
    wire.run_for(0.5)
    assert max(lengths[before:]) == len(ids)  # the requests have stopped: whole cycles again


def test_beside_a_paced_stream_a_normal_request_waits_for_the_slack_and_an_urgent_one_does_not() -> None:
    engine = ready_engine(baudrate=PACED_BAUD)
    wire = BurstWire(engine, Servos(IDS, baudrate=PACED_BAUD))
    source = PacedCycle(IDS, PERIOD)
    wire.emit(engine.attach_source(source, wire.now))
    normal = Recorded(read(2), wire=wire)
    urgent = Recorded(read(3), Priority.URGENT, wire=wire)
    t = 0.0001  # inside the first cycle (8 transactions of 52.8 us each)
    wire.at(t, lambda: wire.submit(normal))
    wire.at(t, lambda: wire.submit(urgent))
    wire.run_for(0.03)
    cycle_end = 8  # writes 0..7: the first cycle, unless something goes between them
    assert urgent.write_index < cycle_end  # at the first boundary after it came
    assert normal.write_index == cycle_end + 1  # after the whole cycle (with the urgent one in it)


def stream_line(
    wire_class: type[Wire], *, mute: set[int] | None = None, damaged: set[int] | None = None
) -> tuple[Wire, FakeSource, Servos]:
    """A FakeSource streaming over IDS on ``wire_class``; the writes in ``mute`` get no reply, those in
    ``damaged`` one the stream refuses (see Servos)."""
    engine = ready_engine()
    servos = Servos(IDS)
    servos.mute = mute or set()
    servos.damaged = damaged or set()
    wire = wire_class(engine, servos)
    source = FakeSource(IDS)
    wire.emit(engine.attach_source(source, wire.now))
    return wire, source, servos


def test_the_burst_stops_at_the_first_fault_and_the_engine_judges_it() -> None:
    wire, source, _ = stream_line(BurstWire, mute={4})
    engine = wire.engine
    wire.run_for(0.05)
    assert len(source.failures) == 1 and type(source.failures[0]).__name__ == "ReplyTimeout"
    assert engine.counters.resyncs == 1


def test_no_plan_while_a_reply_is_owed_or_the_link_is_slow() -> None:
    engine: LineEngine = ready_engine()
    wire = Wire(engine, Servos(IDS))
    engine.link.extra = 0.002
    wire.emit(engine.attach_source(FakeSource(IDS), wire.now))
    assert engine.plan_burst() is None
    engine.link.extra = 0.0
    planned = engine.plan_burst()
    assert planned is not None and len(planned[1]) == len(IDS)
    engine.burst_over()


class HeldByAdapter(Servos):
    """Echo and reply handed over together 16 ms after the write: a USB adapter's latency timer
    (an FTDI chip holds received bytes until 62 are buffered or its timer runs out)."""

    def __call__(self, wire: Wire, tx: bytes) -> None:
        reply, value = self.reply_for(tx)
        self.answers.append(value)
        wire.schedule(wire.now + 0.016, tx + (reply or b""), tag=len(self.answers) - 1)


def test_a_planned_transaction_given_up_early_is_waited_for_by_the_engine_and_not_sent_twice() -> None:
    # Past the least wait the plan gives a transaction whose wait may be recomputed mid-burst
    # (see plan_burst), inside the engine's own wait: the executor stops with nothing read, the
    # engine waits on for the reply, and nothing is written twice: the same line as without bursts.
    # Twelve servos: the wait is recomputed every 32 answers, so some plans cross such a point.
    ids = list(range(1, 13))

    def line(wire_class: type[Wire]) -> tuple[dict[str, Any], Wire]:
        engine = ready_engine()
        wire = wire_class(engine, HeldByAdapter(ids))
        wire.emit(engine.attach_source(FakeSource(ids), wire.now))
        wire.run_for(1.5)
        return summary(wire, []), wire

    plain, _ = line(Wire)
    burst, wire = line(BurstWire)
    assert isinstance(wire, BurstWire) and wire.runner.bursts > 2
    assert sum(s.ok for s in plain["per_id"].values()) > 60
    assert burst["writes"] == plain["writes"]
    assert burst == plain


def test_a_planned_transaction_whose_echo_comes_round_late_is_waited_for_in_full_and_fails_nothing() -> None:
    # The executor stops at the transaction's planned (short) wait with nothing read; the engine, seeing
    # not even the echo, waits the full allowance, takes the reply, and the stream goes on: the same
    # line as without bursts, with no failure on either.
    def line(wire_class: type[Wire]) -> tuple[dict[str, Any], Wire, FakeSource]:
        engine = ready_engine()
        wire = wire_class(engine, StalledOnce(IDS, stalled=100, delay=0.012))
        source = FakeSource(IDS)
        wire.emit(engine.attach_source(source, wire.now))
        wire.run_for(0.3)
        return summary(wire, []), wire, source

    plain, _, plain_source = line(Wire)
    burst, wire, burst_source = line(BurstWire)
    assert isinstance(wire, BurstWire) and wire.runner.bursts > 2
    assert not plain_source.failures and not burst_source.failures
    assert burst == plain


def test_a_reply_only_the_engine_refuses_ends_the_burst_there_and_the_line_goes_as_without_one() -> None:
    # Write 20's reply has a data byte with its top bit set (the echo and the length right, no parity
    # error): the stream refuses it.  The executor must stop there (its plan gave the reply's shape),
    # not send the cycle's next commands, which the engine would take for strays and send again.
    def line(wire_class: type[Wire]) -> tuple[Wire, FakeSource, Servos]:
        wire, source, servos = stream_line(wire_class, damaged={20})
        wire.run_for(0.001)
        assert len(wire.writes) < 20
        wire.run_for(0.2)
        return wire, source, servos

    plain, _, _ = line(Wire)
    wire, source, servos = line(BurstWire)
    assert isinstance(wire, BurstWire) and wire.runner.bursts > 2
    assert wire.executor.stops[SHAPE] == 1
    assert [type(f).__name__ for f in source.failures] == ["ReplyDataError"]
    assert wire.engine.counters.stray == 0  # nothing came that no transaction of the engine's asked for
    assert wire.writes == plain.writes  # every command once, at the time it goes without bursts
    write_of = {value: k for k, value in enumerate(servos.answers) if value is not None}
    for sid, value in source.values:  # every value taken is the answer to its own servo's command
        assert wire.writes[write_of[value]][1][0] & 0x1F == sid
    assert max(write_of[value] for _, value in source.values) > 40  # and the stream carries on


class QuietLine:
    """Just enough of a line for a stream's hooks to be called by hand."""

    baudrate = 115200
    echo = True

    def __init__(self) -> None:
        self.kicks = 0
        self.detached: Any = None

    @property
    def stats(self) -> Any:
        return SimpleNamespace(per_id={}, by_command={})  # no request ever went on this line

    def kick(self) -> None:
        self.kicks += 1

    def detach_source(self, source: Any) -> None:
        self.detached = source

    def notify(self, callback: Any) -> None:
        callback()


def streaming(ids: list[int]) -> tuple[QuietLine, Stream, Any]:
    """A running stream on a :class:`QuietLine`, and its hooks (the engine's side, called by hand)."""
    line = QuietLine()
    stream = Stream(line, ids)  # type: ignore[arg-type]
    stream._running = True
    return line, stream, stream._hooks


def answer_to_free(sid: int) -> bytearray:
    """The echo of a free command to ``sid`` and its reply (position 7500)."""
    return bytearray(protocol.position_tx(sid, protocol.FREE) + bytes((sid, 58, 76)))


def test_a_stream_keeps_a_planned_target_until_the_burst_is_over_and_asks_for_the_stop() -> None:
    line, stream, hooks = streaming([1, 2, 3])
    assert hooks.next_transaction(0.0) == (protocol.position_tx(1, protocol.FREE), 3, 1)
    shapes = {
        sid: protocol.position_reply_shape(protocol.position_reply_header(sid, line.baudrate)) for sid in (1, 2, 3)
    }
    # The one on the wire first, then the rest of the cycle, each with the shape of a reply the stream takes.
    assert hooks.upcoming(3) == [
        (protocol.position_tx(sid, protocol.FREE), 3, sid, shapes[sid], sid == 3) for sid in (1, 2, 3)
    ]
    stream.set_target(2, 8000)  # planned: the burst sends the old command; the stream asks it to stop
    assert line.kicks == 1 and stream.target(2) == 8000
    stream.set_target(1, 9000)  # on the wire already, not planned: next cycle's command, no stop needed
    assert line.kicks == 1
    stream.watch([3])
    assert line.kicks == 2
    assert hooks.complete(answer_to_free(1), 3, 0.001) is None
    assert hooks.next_transaction(0.001) == (protocol.position_tx(2, protocol.FREE), 3, 2)  # as planned
    hooks.upcoming_done()
    assert hooks.complete(answer_to_free(2), 3, 0.002) is None  # read as the command that was sent
    job = hooks.next_transaction(0.002)
    assert job == (protocol.ReadPosition(3).tx, protocol.ReadPosition(3).reply_len, 3)  # the change applies now
    assert stream._jobs[1] == (protocol.position_tx(2, 8000), 3, 2)


def test_a_stream_closed_during_a_burst_still_answers_for_what_the_burst_already_sent() -> None:
    # The program closes the stream while the executor runs the planned cycle: the engine, fed the
    # burst afterwards, must find the stream offering what the executor already put on the line (its
    # detach waits for the burst to stop); once the burst is over it offers nothing more.
    line, stream, hooks = streaming([1, 2, 3])
    assert hooks.next_transaction(0.0) == (protocol.position_tx(1, protocol.FREE), 3, 1)
    assert len(hooks.upcoming(3)) == 3
    stream._stop()
    assert line.detached is hooks
    assert hooks.complete(answer_to_free(1), 3, 0.001) is None
    assert hooks.next_transaction(0.001) == (protocol.position_tx(2, protocol.FREE), 3, 2)  # sent by the burst
    hooks.upcoming_done()
    assert hooks.complete(answer_to_free(2), 3, 0.002) is None
    assert hooks.next_transaction(0.002) is None  # the burst is over: the stop applies


def test_an_unpaced_stream_with_every_id_in_its_cycle_plans_on_through_the_next_cycles() -> None:
    line, stream, hooks = streaming([1, 2, 3])
    free = {sid: protocol.position_tx(sid, protocol.FREE) for sid in (1, 2, 3)}
    assert hooks.next_transaction(0.0) == (free[1], 3, 1)
    planned = hooks.upcoming(8)
    # The one on the wire, the rest of its cycle, then whole cycles; each cycle's last is news (its frame).
    assert [(tx, news) for tx, _, _, _, news in planned] == [
        (free[1], False), (free[2], False), (free[3], True),
        (free[1], False), (free[2], False), (free[3], True),
        (free[1], False), (free[2], False),
    ]  # fmt: skip
    stream.set_target(1, 8000)  # planned for the next cycle: it waits for the burst's end, which it asks for
    assert line.kicks == 1
    t = 0.0
    for sid in (1, 2, 3, 1):
        t += 0.001
        assert hooks.complete(answer_to_free(sid), 3, t) is None
        assert hooks.next_transaction(t) == (free[sid % 3 + 1], 3, sid % 3 + 1)  # as planned, the old target too
    hooks.upcoming_done()
    assert hooks.complete(answer_to_free(2), 3, 0.006) is None
    assert hooks.next_transaction(0.006) == (protocol.position_tx(3, protocol.FREE), 3, 3)
    assert hooks.complete(answer_to_free(3), 3, 0.007) is None
    assert hooks.next_transaction(0.007) == (protocol.position_tx(1, 8000), 3, 1)  # the new target, now


@pytest.mark.parametrize("why", ["paced", "offline", "held", "watched"])
def test_a_stream_plans_no_further_than_its_cycle_where_the_next_is_not_certain(why: str) -> None:
    line = QuietLine()
    stream = Stream(line, [1, 2, 3], rate_hz=100 if why == "paced" else None)  # type: ignore[arg-type]
    stream._running = True
    hooks = stream._hooks
    if why == "offline":
        stream._offline[1] = True  # ID 2: out of the cycle until its probe is due, which depends on the time
        stream._next_probe[1] = 0.0
    if why == "held":
        stream._held[1] = True  # ID 2 gets no command after a reconnect until the program sets its target
    hooks.next_transaction(0.0)
    if why == "watched":
        stream.watch([3])  # read with ICS 3.6's read, whose reply has no shape: a plan ends there
    planned = hooks.upcoming(8)
    assert len(planned) == len(stream._order) and planned[-1][4]  # its own cycle, whose last is news
    assert not stream._beyond
    assert stream._frozen == set(stream._order[1:])


def test_a_stream_closed_during_a_burst_answers_for_the_next_cycle_the_burst_already_sent() -> None:
    # As above, with a plan that runs on into the next cycle: at the end of this one, the stopped
    # stream still starts the next for the commands the executor already sent.
    _, stream, hooks = streaming([1, 2, 3])
    assert hooks.next_transaction(0.0) == (protocol.position_tx(1, protocol.FREE), 3, 1)
    assert len(hooks.upcoming(5)) == 5  # 1, 2, 3, then 1, 2 of the next cycle
    stream._stop()
    t = 0.0
    for sid in (1, 2, 3):
        t += 0.001
        assert hooks.complete(answer_to_free(sid), 3, t) is None
        assert hooks.next_transaction(t) == (protocol.position_tx(sid % 3 + 1, protocol.FREE), 3, sid % 3 + 1)
    assert hooks.complete(answer_to_free(1), 3, 0.004) is None
    assert hooks.next_transaction(0.004) == (protocol.position_tx(2, protocol.FREE), 3, 2)
    hooks.upcoming_done()
    assert hooks.complete(answer_to_free(2), 3, 0.005) is None
    assert hooks.next_transaction(0.005) is None  # the burst is over: the stop applies


def test_a_stream_closed_during_a_burst_keeps_the_line_for_what_the_burst_already_sent() -> None:
    # A request waits for the slack beside a paced stream (too long for it) when the program closes
    # the stream mid-burst.  The executor has already sent the burst's next commands: the engine,
    # fed the burst afterwards, must give those boundaries to them, not to the request (which a
    # stopped stream, with no schedule left, would let through), and the request goes after them.
    ids = [1, 2, 3]
    engine = ready_engine(baudrate=115200)
    line = QuietLine()
    stream = Stream(line, ids, rate_hz=400)  # type: ignore[arg-type]
    stream._running = True
    wire = BurstWire(engine, Servos(ids, baudrate=115200))
    wire.emit(engine.attach_source(stream._hooks, wire.now))
    request = Recorded(read(2, protocol.Param.TEMPERATURE), wire=wire)
    # Cycles of 2.3 ms every 2.5 ms: the read (0.7 ms) fits no slack, and goes after its second.
    wire.at(0.003, lambda: wire.submit(request))  # mid-burst in the second cycle: queued where it stops
    wire.run_for(0.0055)  # passed over once; the third cycle has started
    assert request.state == "queued"
    stop_at = wire.now + 0.0003
    bursting: list[bool] = []
    wire.at(stop_at, lambda: (bursting.append(wire.runner.running), stream._stop()))
    wire.run_for(0.01)  # BurstDiverged here if the engine gave the request a planned boundary
    assert bursting == [True]  # the stream was closed while the executor ran its cycle
    assert request.state == "done"
    assert [tx[0] for _, tx in wire.writes].count(0xA2) == 1
    first_after_stop = next(i for i, (t, _) in enumerate(wire.writes) if t > stop_at)
    sent_after = [tx for _, tx in wire.writes[first_after_stop:]]
    assert sent_after[0][0] & 0xE0 == 0x80  # the burst's planned command came first


class RefusingOnce(FakeSource):
    """Refuses its ``refused``-th reply though the reply has the shape its plan gave: a source's shape is to
    say what it refuses, and this one breaks that, as a bug in a source would."""

    def __init__(self, ids: list[int], refused: int) -> None:
        super().__init__(ids)
        self.refused = refused
        self.replies = 0

    def complete(self, buf: bytearray, offset: int, now: float) -> ReplyError | None:
        self.replies += 1
        if self.replies == self.refused:
            return ReplyValueError("refused though in shape", command="position", servo_id=None, raw=bytes(buf))
        return super().complete(buf, offset, now)


def test_a_reply_refused_though_in_shape_leaves_the_burst_out_of_step_and_nothing_misattributed(
    caplog: pytest.LogCaptureFixture,
) -> None:
    # The executor ran on past a reply the engine refused: the later transactions' bytes are strays to the
    # engine, none is taken for a reply, and the line goes on once they are over (not a BurstDiverged).
    engine = ready_engine()
    servos = Servos(IDS)
    wire = BurstWire(engine, servos)
    source = RefusingOnce(IDS, refused=len(IDS) + 3)  # mid-burst, in the second cycle
    wire.emit(engine.attach_source(source, wire.now))
    wire.run_for(0.1)
    assert "burst ran on past a reply the engine refused" in caplog.text
    assert len(source.failures) == 1 and isinstance(source.failures[0], ReplyValueError)
    assert engine.counters.snapshot(0).stray_bytes > 0  # the bytes of the commands sent after it
    answered = Counter(sid for sid, _value in source.values)
    assert min(answered[sid] for sid in IDS) > 3  # every ID answered on after it
    # Every value taken is the one that servo sent for a write to that very ID.
    sent = {(tx[0] & 0x1F, value) for (_, tx), value in zip(wire.writes, servos.answers, strict=True)}
    assert set(source.values) <= sent
