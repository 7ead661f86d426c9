"""A slow link (issue 12 item 4), at the engine level: plain calls on a virtual clock, no event loop.

Through a TCP bridge with Nagle's algorithm on, a 68-byte EEPROM transaction
(2 echo + 66 reply bytes) arrives as 64 bytes, then 4 about 40 ms later:
past the deadline a USB adapter needs.  The simulator's ``tail`` fault does
exactly that, and :class:`tests.support.engine_rig.EngineRig` plays it to a
:class:`LineEngine` at the wire times, so every figure here is exact.

What must hold: the engine learns the link's lateness and the following
transactions succeed; no reply is ever handed to another request; the
learnt allowance stays within a bound (a dead servo still times out in
bounded time), decays when the link is fast again, and is not raised by
faults that are not lateness (partial replies that never complete, noise).
"""

from __future__ import annotations

import itertools
from typing import Any

import pytest

from ics35_async.engine import BusTiming, Request
from ics35_async.engine.link import LinkLatency
from ics35_async.errors import ReplyError, ReplyTimeout
from ics35_async.protocol import Command, Param, Position, ReadEeprom, ReadParam, Timing
from ics35_async.sim import FaultConfig, FaultInjector, VirtualServo
from ics35_async.sim.model import LineModel
from tests.support.engine_rig import EngineRig

EEPROM_SERVO = 1  # its EEPROM replies (66 bytes) are the ones a held tail splits
OTHER = 2


def servos() -> list[VirtualServo]:
    # Distinct values per servo: a reply handed to the wrong request shows.
    return [
        VirtualServo(EEPROM_SERVO, position=5001, ambient_celsius=25.0),
        VirtualServo(OTHER, position=9001, ambient_celsius=60.0),
        VirtualServo(3, position=7001, ambient_celsius=40.0),
    ]


def held_tail_line(tail_delay: float = 0.040, faults: str = f"tail@{EEPROM_SERVO}:1") -> LineModel:
    return LineModel(servos(), realtime=True, faults=faults, tail_bytes=4, tail_delay=tail_delay)


def mixed(round_no: int) -> list[Command[Any]]:
    """One round of the workload: an EEPROM read (held tail), a parameter read, a move, another EEPROM read."""
    return [
        ReadEeprom(EEPROM_SERVO),
        ReadParam(OTHER, Param.TEMPERATURE),
        Position(OTHER, 9001 + 2 * (round_no % 20), baudrate=115200),
        ReadEeprom(OTHER),
        ReadParam(EEPROM_SERVO, Param.TEMPERATURE),
    ]


def expected_value(line: LineModel, command: Command[Any]) -> Any:
    """What the addressed servo itself answered to ``command``'s last attempt (the simulator's log)."""
    entry = next(t for t in reversed(line.log) if t.tx == command.tx)
    return entry.value


class Outcomes:
    def __init__(self) -> None:
        self.ok = 0
        self.failed: list[tuple[int, str]] = []  # (index, error class)
        self.wrong: list[str] = []

    def check(self, rig: EngineRig, index: int, request: Request) -> None:
        if request.state == "done":
            self.ok += 1
            want = expected_value(rig.line, request.command)
            if request.value != want:
                self.wrong.append(f"#{index} {request.command!r}: got {request.value!r}, servo answered {want!r}")
        else:
            assert isinstance(request.error, ReplyError), request.error
            self.failed.append((index, type(request.error).__name__))


def run_workload(rig: EngineRig, rounds: int, retries: int = 0) -> Outcomes:
    outcomes = Outcomes()
    index = 0
    for r in range(rounds):
        for command in mixed(r):
            outcomes.check(rig, index, rig.finish(rig.submit(command, retries=retries)))
            index += 1
    return outcomes


def test_the_rig_delivers_the_held_tail_past_the_deadline() -> None:
    # The premise: without adaptation, this EEPROM read times out with 64 of its 68 bytes in.
    rig = EngineRig(held_tail_line())
    request = rig.finish(rig.submit(ReadEeprom(EEPROM_SERVO)))
    assert request.state == "failed"
    assert type(request.error).__name__ == "PartialReply"
    assert request.error.raw is not None and len(request.error.raw) == 64


def test_a_held_tail_after_the_deadline_is_learnt_and_the_following_transactions_succeed() -> None:
    rig = EngineRig(held_tail_line(0.040))
    outcomes = run_workload(rig, rounds=30)
    assert outcomes.wrong == []
    # The first EEPROM read of servo 1 fails (its tail is learnt during the resync); every later one succeeds.
    assert outcomes.failed == [(0, "PartialReply")]
    assert 0.040 - 0.030 < rig.engine.link.extra <= rig.engine.link.bound


@pytest.mark.parametrize("tail_delay", [0.080, 0.120, 0.200])
def test_a_tail_landing_after_the_resync_is_learnt_from_the_bytes_before_the_next_echo(tail_delay: float) -> None:
    # The tail comes so late that the resync after the timeout has ended: it lands in front of a later
    # transaction's echo ("each request receives the previous one's bytes").  That must teach the engine too.
    rig = EngineRig(held_tail_line(tail_delay))
    outcomes = run_workload(rig, rounds=30)
    assert outcomes.wrong == []
    late = [i for i, _ in outcomes.failed]
    assert late and max(late) < 10, outcomes.failed  # adapted within the first two rounds
    assert len(outcomes.failed) <= 5
    assert rig.engine.link.extra > tail_delay - 0.030


def test_with_retries_the_callers_never_see_the_held_tail() -> None:
    rig = EngineRig(held_tail_line(0.040))
    outcomes = run_workload(rig, rounds=20, retries=1)
    assert outcomes.wrong == [] and outcomes.failed == []


def test_a_dead_servo_still_times_out_within_the_base_allowance_plus_the_bound() -> None:
    rig = EngineRig(held_tail_line(0.200))  # a tail so late that the learnt allowance reaches the bound
    link = rig.engine.link
    for _ in range(10):
        rig.finish(rig.submit(ReadEeprom(EEPROM_SERVO)))
        if link.extra:
            break
    assert link.extra == link.bound
    dead = Position(9, 7500, baudrate=115200)  # no servo 9 on the line
    request = rig.submit(dead)
    written = rig.now
    rig.finish(request)
    assert isinstance(request.error, ReplyTimeout)
    base = BusTiming().allowance(len(dead.tx) + dead.reply_len, 115200, Timing.NORMAL)
    assert base < rig.now - written <= base + link.bound + 1e-9


def test_lateness_beyond_the_bound_is_not_learnt() -> None:
    # No allowance within the bound would catch bytes that late: raising it would only slow the line down.
    link = LinkLatency(bound=0.25)
    link.late_by(0.26)
    assert link.extra == 0.0 and link.late_replies == 0
    link.late_by(0.2)
    assert link.extra == 0.25 and link.late_replies == 1


def test_a_tail_held_longer_than_the_bound_costs_transactions_but_never_a_wrong_reply() -> None:
    rig = EngineRig(held_tail_line(0.600))
    outcomes = run_workload(rig, rounds=20)
    assert outcomes.wrong == []
    assert rig.engine.link.extra <= rig.engine.link.bound
    late_rounds = [i for i, _ in outcomes.failed if i >= 50]
    assert len(late_rounds) <= 2 * 10  # at most the held-tail read and the one after it, per round


def test_the_allowance_holds_while_the_link_is_slow_and_decays_when_it_is_fast_again() -> None:
    line = held_tail_line(0.040)
    rig = EngineRig(line)
    run_workload(rig, rounds=2)
    learnt = rig.engine.link.extra
    assert learnt > 0
    # Still slow: every fifth transaction needs the allowance, so it stays.
    outcomes = run_workload(rig, rounds=60)
    assert outcomes.failed == [] and rig.engine.link.extra >= learnt
    # Fast again: the allowance halves after each window of transactions that did not need it, down to 0.
    line.faults = FaultInjector(FaultConfig(), 0)
    seen = [rig.engine.link.extra]
    for _ in range(300):
        outcomes = run_workload(rig, rounds=1)
        assert outcomes.failed == [] and outcomes.wrong == []
        seen.append(rig.engine.link.extra)
        if seen[-1] == 0.0:
            break
    assert seen[-1] == 0.0, seen[-5:]
    assert all(b <= a for a, b in itertools.pairwise(seen))  # it only ever went down
    assert len(set(seen)) > 3  # in steps, not at once


@pytest.mark.parametrize(
    "faults",
    [
        "truncate@3:1",  # partial replies whose rest never comes
        "noise@3:1",  # stray bytes after every reply
        "drop@3:1",  # no reply at all
        "echo@3:1",  # collisions: a damaged echo
        "late@3:1",  # each reply held back until after the next command's echo
        "drop@3:0.2,truncate@3:0.2,noise@3:0.3,echo@3:0.1,corrupt@3:0.1,msb@3:0.1,late@3:0.2",  # the chaos mix
    ],
)
def test_faults_that_are_not_lateness_do_not_raise_the_allowance(faults: str) -> None:
    rig = EngineRig(held_tail_line(faults=faults))
    for r in range(40):
        for command in (ReadEeprom(3), ReadParam(3, Param.TEMPERATURE), Position(3, 7001 + 2 * r, baudrate=115200)):
            rig.finish(rig.submit(command))
        rig.finish(rig.submit(ReadParam(OTHER, Param.TEMPERATURE)))
    assert rig.engine.link.extra == 0.0
