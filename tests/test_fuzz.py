"""Fuzzing, short: random byte streams through every reply parser and through the bus's framing.

``python -m benchmarks.soak`` runs the same at 1,000,000 byte streams.  The oracle
(:class:`tests.support.oracle.WirePredictor`) says what the bus must conclude from the bytes
it received: a value exactly when they form a valid reply (right length,
intact echo, the codec's checks), else the error class they call for.
"""

from __future__ import annotations

import asyncio

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from benchmarks.soak.fuzz import fuzz_soak
from ics35_async import IcsError, Param, ReplyError, open_bus, protocol
from ics35_async.sim import FaultConfig, FaultInjector, VirtualLine
from tests.support.fuzzing import BAUDS, FuzzCase, FuzzCounts, FuzzDevice, FuzzRig, fuzz_case, fuzz_parsers, valid_value
from tests.support.oracle import FAULT_KINDS, WirePredictor, chaos_servos
from tests.support.timing import FAST_TIMING, GUARD

blobs = st.binary(min_size=6, max_size=80)


@pytest.mark.no_cover  # a soak: thousands of passes through code the other tests cover (see conftest)
@pytest.mark.slow
def test_fuzz_short() -> None:
    report = fuzz_soak(streams=6_000, batch=200, lines=16, seed=11)
    assert report.streams == 6_000 and report.bus_transactions == 6_000
    assert report.untyped == report.bus_untyped == report.loop_exceptions == 0, report.examples
    assert report.bus_wrong == 0, report.examples
    assert report.fast_path_disagrees == 0 and report.decode_problems == 0, report.examples
    assert report.health_problems == []
    # The mix exercises both sides: values and every kind of error.
    assert report.bus_values > 500
    assert {"ReplyTimeout", "PartialReply", "EchoMismatch", "BadReply", "ReplyHeaderError"} <= set(report.bus_errors)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(blob=blobs, baud=st.sampled_from(BAUDS))
def test_every_parser_gives_a_value_or_a_reply_error(blob: bytes, baud: int) -> None:
    counts = FuzzCounts()
    fuzz_parsers(fuzz_case(blob, baud), baud, counts)
    assert counts.untyped == counts.fast_path_disagrees == counts.decode_problems == 0, counts.examples


@settings(max_examples=200, deadline=None)
@given(blob=blobs, baud=st.sampled_from(BAUDS))
def test_a_clean_reply_is_judged_valid_and_a_cut_one_is_not(blob: bytes, baud: int) -> None:
    case = fuzz_case(blob, baud)
    command = case.command
    clean = command.encode_reply(valid_value(command, blob[6:]))
    judge = WirePredictor(baud).judge
    verdict = judge(command.tx, command.tx + clean)
    assert verdict.ok and verdict.value == command.parse(clean)
    assert judge(command.tx, command.tx + clean[:-1]).error in ("ReplyTimeout", "PartialReply")
    assert judge(command.tx, command.tx + clean + b"\x00").error == "BadReply"
    assert not judge(command.tx, bytes([command.tx[0] ^ 1]) + command.tx[1:] + clean).ok


@pytest.mark.parametrize("kind", FAULT_KINDS)
async def test_every_fault_at_100_percent_gives_only_typed_errors_and_leaves_the_bus_sound(kind: str) -> None:
    sim = VirtualLine(chaos_servos()[:4], faults=f"{kind}:1.0", seed=3)
    async with open_bus(sim, timing=FAST_TIMING) as bus:
        outcomes: list[object] = []
        for i in range(4):
            for call in (
                bus.servo(i).read_stretch,
                bus.servo(i).read_eeprom,
                bus.servo(i).free,
                lambda i=i: bus.servo(i).write_speed(60 + i),
            ):
                try:
                    async with asyncio.timeout(GUARD):  # a hang is a failure, not a two-minute wait
                        outcomes.append(await call())
                except IcsError as exc:
                    outcomes.append(exc)
        errors = [o for o in outcomes if isinstance(o, ReplyError)]
        if kind == "corrupt":  # no checksum: a flipped data bit can pass; the rest must be caught
            assert len(errors) >= len(outcomes) // 2
        else:
            assert len(errors) == len(outcomes), outcomes
        sim.faults = FaultInjector(FaultConfig(), 0)
        await bus.request(protocol.ReadParam(0, Param.STRETCH), retries=1)  # a held-back reply may still land
        for i in range(4):
            assert await bus.servo(i).read_stretch() == 10 + i
            assert (await bus.servo(i).read_eeprom()) == sim.servo(i).eeprom
        await bus.wait_idle()
        stats = bus.stats
        assert stats.total.transactions == sim.transactions and stats.queued == 0
        assert stats.total.ok + stats.total.errors == stats.total.transactions


class TamperingDevice(FuzzDevice):
    """Sends something other than what the rig judged: one more flipped bit in a data byte."""

    def write(self, data: bytes) -> None:
        case = self.script[0]
        self.script[0] = FuzzCase(case.command, case.echo, case.reply[:-1] + bytes([case.reply[-1] ^ 1]))
        super().write(data)


async def test_the_fuzz_rig_notices_a_conclusion_the_bytes_do_not_support() -> None:
    rig = FuzzRig(lines=1)
    rig.devices[0] = TamperingDevice()
    await rig.open()
    try:
        await rig.run([bytes([2, 5, 1, 0, 0, 0, 9])])  # a clean stretch read of ID 5
    finally:
        await rig.close()
    assert rig.counts.bus_values == 1 and rig.counts.bus_wrong == 1
