"""Probes (``Timing.PROBE``): a short wait at IDs that are probably empty, learnt from the link's answers.

Plain calls and simulated time only (see engine_support): no event loop.
"""

from __future__ import annotations

import pytest

from ics35_async import protocol
from ics35_async.engine import State
from ics35_async.engine.probe import FACTOR, FLOOR, MARGIN, REFRESH, AnswerTimes
from ics35_async.errors import InvalidArgument, ReplyTimeout
from tests.support.engine_support import (
    BAUD,
    FakeSource,
    Recorded,
    Servos,
    StalledOnce,
    Wire,
    read,
    ready_engine,
    wire_time,
)

NORMAL_WAIT = 0.0005 + 0.020  # BusTiming's turnaround + adapter latency


def line(ids: set[int], turnaround: float = 0.0002) -> tuple[Wire, Servos]:
    engine = ready_engine()
    servos = Servos(ids, turnaround=turnaround)
    return Wire(engine, servos), servos


def probe_deadline(wire: Wire, sid: int) -> float:
    """The deadline the engine gives a probe of ``sid`` sent now, measured from its write."""
    start = wire.now
    wire.submit(Recorded(protocol.ProbeRead(sid)))
    return wire.engine.deadline - start


def test_a_probe_is_a_stretch_read_with_the_probe_timing() -> None:
    probe = protocol.ProbeRead(5)
    assert probe.tx == read(5, protocol.Param.STRETCH).tx
    assert probe.timing is protocol.Timing.PROBE and protocol.ReadParam.timing is protocol.Timing.NORMAL
    with pytest.raises(InvalidArgument):
        protocol.ProbeRead(32)


def test_before_any_answer_a_probe_waits_the_normal_allowance() -> None:
    wire, _ = line(set())
    assert probe_deadline(wire, 4) == pytest.approx(wire_time(5) + NORMAL_WAIT)


def test_after_an_answer_a_probe_waits_twice_the_slowest_answer_plus_a_millisecond() -> None:
    wire, _ = line({1}, turnaround=0.003)  # a servo that answers 3 ms after its wire time
    ok = Recorded(read(1))
    wire.submit(ok)
    wire.settle()
    assert ok.state == "done"
    assert probe_deadline(wire, 4) == pytest.approx(wire_time(5) + 2 * 0.003 + 0.001, abs=1e-6)


def test_a_probe_waits_at_least_the_floor_and_at_most_the_normal_allowance() -> None:
    fast, _ = line({1}, turnaround=0.0)
    fast.submit(Recorded(read(1)))
    fast.settle()
    assert probe_deadline(fast, 4) == pytest.approx(wire_time(5) + FLOOR)
    slow, _ = line({1}, turnaround=0.015)  # answered within the normal allowance, but late
    slow.submit(Recorded(read(1)))
    slow.settle()
    assert probe_deadline(slow, 4) == pytest.approx(wire_time(5) + NORMAL_WAIT)


def test_an_answer_faster_than_its_wire_time_counts_as_immediate() -> None:
    # A fast-mode simulator answers before the bytes could have crossed a real wire.
    wire, _ = line({1}, turnaround=-wire_time(2))  # the whole reply 2 byte times early
    wire.submit(Recorded(read(1)))
    wire.settle()
    assert probe_deadline(wire, 4) == pytest.approx(wire_time(5) + FLOOR)


def test_a_silent_probe_times_out_early_and_resyncs_for_as_long_as_it_waited() -> None:
    wire, _ = line({1}, turnaround=0.0)
    wire.submit(Recorded(read(1)))
    wire.settle()
    probe = Recorded(protocol.ProbeRead(4))
    wire.submit(probe)
    sent = wire.now
    wire.settle()
    assert isinstance(probe.error, ReplyTimeout)
    # wait (wire + FLOOR) + the resync's quiet (FLOOR) instead of 20.5 ms + 10 ms
    assert wire.now - sent == pytest.approx(wire_time(5) + 2 * FLOOR, abs=1e-6)
    assert wire.engine.counters.resyncs == 1


def test_a_probe_whose_echo_has_not_come_waits_the_full_allowance_for_it_and_takes_its_answer() -> None:
    # Kondo's adapter is an FTDI chip, whose latency timer (16 ms by default) holds an echo and its reply back
    # together.  A probe's wait learnt from quicker answers gave up before even the echo came, and the servo
    # there was taken for absent (`scan`, `free all`, `eeprom dump all` missed servos plugged in, exit 0), its
    # bytes then failing the probes after it.  A servo that does not answer still echoes: with the echo not yet
    # round, the host or the link is late, and the probe waits its full allowance, as a stream's short wait does.
    servos = StalledOnce([1, 4], stalled=1, delay=0.012)  # write 1 (the probe of 4) comes round 12 ms late
    wire = Wire(ready_engine(), servos)
    wire.submit(Recorded(read(1)))
    wire.settle()
    probe = Recorded(protocol.ProbeRead(4))
    wire.submit(probe)
    assert wire.engine.deadline - wire.now < 0.012  # (a short wait, learnt: shorter than the adapter's hold)
    wire.settle()
    assert probe.state == "done" and probe.error is None, probe.error
    # (and a probe answered 12 ms late teaches the probes after it: they wait the normal allowance now)
    assert probe_deadline(wire, 6) == pytest.approx(wire_time(5) + NORMAL_WAIT)


def silent_free_deadline(wire: Wire, sid: int) -> float:
    """The deadline the engine gives a closing stream's free to offline ``sid`` sent now, from its write."""
    start = wire.now
    wire.submit(Recorded(protocol.SilentFree(sid, baudrate=BAUD)))
    return wire.engine.deadline - start


def test_a_free_to_a_servo_already_found_silent_waits_little_even_before_any_answer() -> None:
    # A robot's leg line where nothing answers: a probe's wait there is the whole allowance (nothing to learn a
    # shorter one from), and a closing stream's free to each offline joint waited it, one after the other.
    assert protocol.SilentFree(5, baudrate=BAUD).tx == protocol.Position(5, protocol.FREE, baudrate=BAUD).tx
    fresh, _ = line(set())
    assert silent_free_deadline(fresh, 4) == pytest.approx(wire_time(6) + FLOOR + MARGIN)
    answered, _ = line({1}, turnaround=0.003)  # once something has answered: a probe's wait
    answered.submit(Recorded(read(1)))
    answered.settle()
    assert silent_free_deadline(answered, 4) == pytest.approx(wire_time(6) + 2 * 0.003 + 0.001, abs=1e-6)


class OfflineProbes(FakeSource):
    """A stream that has found every ID it offers silent: each of its transactions is an offline ID's probe."""

    def probing_silent(self) -> bool:
        return True


@pytest.mark.parametrize("silent", [True, False], ids=["offline-probe", "online"])
def test_a_stream_leaving_gives_up_briefly_only_on_its_probe_of_a_silent_servo(silent: bool) -> None:
    # A robot's leg line where nothing answers: the stream's probe of an offline joint waited the whole allowance
    # (nothing to learn a shorter one from) as the stream closed, then a guard read's before that joint's free.
    wire, _ = line(set())
    engine = wire.engine
    source = OfflineProbes([4]) if silent else FakeSource([4])
    start = wire.now
    probe = wire.emit(engine.attach_source(source, start))
    full = wire_time(6) + NORMAL_WAIT
    assert engine.deadline - start == pytest.approx(full)
    source.active = False
    engine.detach_source(source)
    free = Recorded(protocol.SilentFree(4, baudrate=BAUD))
    wire.submit(free)
    wire.settle()
    assert [tx for _, tx in wire.writes] == [probe, free.command.tx]  # no guard read before the free
    freed_at = wire.writes[1][0] - start
    if silent:  # nobody hears the probe's answer now: it waits as the free does
        assert freed_at < wire_time(6) + FLOOR + MARGIN + 0.002, freed_at
    else:  # a transaction to a servo that may well answer keeps its whole allowance
        assert freed_at >= full, freed_at


def test_a_plain_read_keeps_the_normal_wait_and_quiet_time() -> None:
    wire, _ = line({1}, turnaround=0.0)
    wire.submit(Recorded(read(1)))
    wire.settle()
    silent = Recorded(read(4))
    wire.submit(silent)
    sent = wire.now
    wire.settle()
    assert isinstance(silent.error, ReplyTimeout)
    assert wire.now - sent == pytest.approx(wire_time(5) + NORMAL_WAIT + 0.010, abs=1e-6)


def test_a_new_port_forgets_what_the_old_one_showed() -> None:
    wire, _ = line({1}, turnaround=0.0)
    wire.submit(Recorded(read(1)))
    wire.settle()
    engine = wire.engine
    engine.disconnected()
    engine.baudrate = 1250000
    assert engine.connected(wire.now) is None
    assert engine.state is State.IDLE
    start = wire.now
    wire.emit(engine.submit(Recorded(protocol.ProbeRead(4)), wire.now))
    expected = protocol.wire_time(5, 1250000) + NORMAL_WAIT
    assert engine.deadline - start == pytest.approx(expected)


def test_a_probe_answered_past_its_short_wait_does_not_teach_the_link_lateness() -> None:
    # The link's extra allowance learns from answers past the *normal* allowance; a probe's wait is
    # shorter only because empty IDs are expected, so an answer past it says nothing of the link.
    wire, servos = line({1, 4}, turnaround=0.0)
    wire.submit(Recorded(read(1)))
    wire.settle()
    engine = wire.engine
    engine.link.extra = 0.010  # a link already known to be 10 ms slow
    servos.turnaround = FLOOR + 0.009  # past the probe's own wait, inside its deadline and the normal wait
    probe = Recorded(protocol.ProbeRead(4))
    wire.submit(probe)
    wire.settle()
    assert probe.state == "done"
    assert engine.link.extra == 0.010


def test_the_streams_wait_leaves_out_the_two_slowest_recent_answers() -> None:
    # Host hiccups: the stream's wait is set from the third-slowest of the recent answers, twice it plus a
    # millisecond, never under the floor.
    times = AnswerTimes()
    beyond = [0.0031, 0.0002, 0.050, 0.0007, 0.0029, 0.120, 0.0012, 0.0030]  # RECENT_MIN answers, two hiccups
    for b in beyond:
        times.answered(b)
    assert times.stream_latency == pytest.approx(max(FLOOR, FACTOR * 0.0031 + MARGIN))
    for _ in range(REFRESH - len(beyond) - 1):
        times.answered(0.0001)
    assert times.stream_latency == pytest.approx(max(FLOOR, FACTOR * 0.0031 + MARGIN))  # not yet refreshed
    times.answered(0.0001)  # the REFRESH-th: the same three slowest, so the same wait
    assert times.stream_latency == pytest.approx(max(FLOOR, FACTOR * 0.0031 + MARGIN))
