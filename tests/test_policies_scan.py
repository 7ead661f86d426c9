"""The scan policy against the in-process simulator: rates, garbled replies, one listing per servo, cost."""

from __future__ import annotations

import contextlib
import time
from collections.abc import AsyncIterator, Iterator
from contextlib import AbstractAsyncContextManager
from typing import Any

import anyio
import pytest

from ics35_async import open_bus
from ics35_async.bus import Bus
from ics35_async.eeprom import BaudRate
from ics35_async.errors import BusClosed, EchoMismatch, InvalidArgument, PartialReply, PortLost, ReplyError
from ics35_async.policies import ALL_BAUDS, Line, echo_setting_wrong, probe_ids, scan, servo_rates
from ics35_async.protocol import Param, Position, ReadEeprom, ReadId, ReadParam
from ics35_async.sim import VirtualLine, VirtualServo
from ics35_async.transports import PortNotFound, SerialPortError
from tests.support.engine_support import Recorded, Wire, ready_engine
from tests.support.sim_servos import UnplugsWhenAsked
from tests.support.timing import FAST, PATIENT


@pytest.fixture
def lines() -> Iterator[Any]:
    made: list[VirtualLine] = []

    def make(servos: Any, **options: Any) -> VirtualLine:
        sim = VirtualLine(list(servos), log_size=None, **options)
        made.append(sim)
        return sim

    yield make
    for sim in made:
        sim.close()


def opener(sim: VirtualLine, **options: Any) -> Any:
    def open_at(baud: int) -> AbstractAsyncContextManager[Line]:
        return open_bus(sim, baudrate=baud, **{**FAST, **options})

    return open_at


async def test_each_servo_is_found_at_its_rate_with_its_eeprom(lines: Any) -> None:
    sim = lines([VirtualServo(1), VirtualServo(2, baud_rate=1250000), VirtualServo(3, baud_rate=625000)])
    report = await scan(opener(sim), ids=range(6))
    assert [(s.servo_id, s.baud) for s in report.servos] == [(1, 115200), (2, 1250000), (3, 625000)]
    for found in report.servos:
        assert found.eeprom is not None and found.eeprom == sim.servo(found.servo_id).eeprom
        assert found.answered_at == (found.baud,) and not found.baud_pending
    assert [r.baud for r in report.rates] == list(ALL_BAUDS)
    assert report.garbled == [] and not report.silent


async def test_a_rate_where_nobody_answers_costs_one_transaction(lines: Any) -> None:
    sim = lines([VirtualServo(4), VirtualServo(9), VirtualServo(30)])
    report = await scan(opener(sim), read_eeprom=False)
    assert [s.servo_id for s in report.servos] == [4, 9, 30]
    nobody = [r for r in report.rates if r.nobody]
    assert [r.baud for r in nobody] == [625000, 1250000]
    # 115200: the ID read, then each ID probed once (silent ones are not retried), except the
    # last: silent, it is read again with the normal allowance, behind a guard read that would
    # take its late reply.
    stretch_reads = [t.servo_id for t in sim.log if t.command == "read_stretch"]
    assert sorted(stretch_reads) == [*range(32), 31]
    assert [t.command for t in sim.log].count("read_id") == 3
    sent = [(t.command, t.servo_id) for t in sim.log]
    again = len(sent) - 1 - sent[::-1].index(("read_stretch", 31))
    assert sent[again - 1] == ("read_speed", 31)
    assert sim.transactions == 3 + 32 + 2


async def test_a_scan_of_some_ids_that_finds_none_asks_the_line_once_whether_a_device_at_another_id_answers(
    lines: Any,
) -> None:
    # (so that a person told "none of 20-25 answered" also hears that the line and its power are right)
    one = lines([VirtualServo(2)])
    (rate,) = (await scan(opener(one), bauds=[115200], ids=range(20, 26), read_eeprom=False)).rates
    assert rate.elsewhere and rate.id_answer == 2 and not rate.only_id_read
    assert [t.command for t in one.log].count("read_id") == 1
    several = lines([VirtualServo(1), VirtualServo(2)])  # (they answer the ID read together: garbled)
    (rate,) = (await scan(opener(several), bauds=[115200], ids=[7], read_eeprom=False)).rates
    assert rate.elsewhere and rate.id_answer is None
    empty = lines([])
    (rate,) = (await scan(opener(empty), bauds=[115200], ids=[7], read_eeprom=False)).rates
    assert not rate.elsewhere
    # A device that answers the ID read as an ID that was asked is no other ID's (see only_id_read).
    odd = lines([VirtualServo(3, ignores={"read_stretch"})])
    (rate,) = (await scan(opener(odd), bauds=[115200], ids=range(10), read_eeprom=False)).rates
    assert not rate.elsewhere and rate.only_id_read and rate.id_answer == 3
    # Every ID asked: nothing more to learn.
    (rate,) = (await scan(opener(lines([])), bauds=[115200], read_eeprom=False)).rates
    assert rate.nobody and not rate.elsewhere
    # Fewer than the ID read's own threshold, one of them the odd device's: its ID read's answer is kept (the
    # report's note names it), not taken for another ID's.
    (rate,) = (await scan(opener(odd), bauds=[115200], ids=[3, 4], read_eeprom=False)).rates
    assert not rate.elsewhere and rate.only_id_read and rate.id_answer == 3


async def test_a_port_lost_as_a_scan_of_some_ids_asks_for_other_ids_is_the_report_s_loss(lines: Any) -> None:
    # (not "no servo answered", with the power hints)
    puller = UnplugsWhenAsked(2, ReadId)
    sim = lines([puller])
    puller.line = sim
    report = await scan(opener(sim), bauds=[115200], ids=[20], read_eeprom=False)
    assert isinstance(report.lost, (PortLost, BusClosed)), report


async def test_silent_ids_are_not_retried_even_when_the_bus_retries(lines: Any) -> None:
    sim = lines([VirtualServo(2)])
    async with open_bus(sim, retries=3, **FAST) as bus:
        rate = await probe_ids(bus, range(8))
        assert rate.answered == (2,)
        # The ID read, one probe per ID, then the last (silent) ID once more behind a guard read.
        assert bus.stats.total.transactions == 1 + 8 + 2
        assert bus.stats.guards == 1
        assert bus.stats.total.retries == 0


@pytest.mark.parametrize("ids", [range(8), range(4)], ids=["probed before others", "probed last"])
async def test_a_servo_slower_than_the_probes_wait_is_found_not_taken_for_empty(lines: Any, ids: range) -> None:
    # Servo 3 answers 12 ms late: well within the normal allowance (100 ms, so that a loaded machine
    # cannot push it out) and the quiet time, past a probe's (about 5 ms after servo 1 answered at
    # once).  Its late bytes must send the silent IDs round again.
    sim = lines([VirtualServo(1), VirtualServo(3)], faults="late@3:1.0", late_delay=0.012, realtime=True)
    async with open_bus(sim, adapter_latency=0.100, quiet_time=0.030) as bus:
        rate = await probe_ids(bus, ids, id_read_first=False)
    assert rate.answered == (1, 3)
    assert rate.garbled == {}


async def test_a_late_reply_ahead_of_the_next_echo_is_not_taken_for_a_wrong_echo_setting(lines: Any) -> None:
    # A reply that lands just as the next probe is written arrives ahead of that probe's echo
    # ("23 01 1e a4 01": servo 3's late answer, then the echo of the probe of ID 4; seen on a loaded
    # machine).  The echo is there, so it says nothing of the echo setting: the garbled ID is probed
    # again, not reported as "this interface does not echo".  (A held tail in fast mode comes with
    # the host's next write, before its echo: the same bytes, every time.)
    sim = lines([VirtualServo(1), VirtualServo(3)], faults="tail@3:1.0", tail_bytes=2)
    async with open_bus(sim, **FAST) as bus:
        rate = await probe_ids(bus, range(6), id_read_first=False)
    assert rate.echo_evidence is None
    assert isinstance(rate.garbled[4], EchoMismatch) and rate.garbled[4].raw[0] < 0x80
    assert [t.servo_id for t in sim.log if t.command == "read_stretch"].count(4) >= 2  # probed again


@pytest.mark.parametrize(
    ("command", "ahead", "evidence"),
    [
        (ReadParam(4, Param.STRETCH), ReadParam(3, Param.STRETCH).encode_reply(30), False),  # a late reply, echo whole
        (Position(2, 7482, baudrate=115200), b"\x05\x0a\x03\x01", False),  # a held tail: echo cut off
        (ReadParam(4, Param.STRETCH), b"", True),  # only a reply: the interface does not echo
    ],
    ids=["late reply ahead", "echo cut off", "no echo"],
)
def test_only_an_echo_missing_from_the_bytes_is_evidence_of_the_echo_setting(
    command: Any, ahead: bytes, evidence: bool
) -> None:
    # Through the engine: the bytes that arrive for one transaction, and the error it makes of them.
    engine = ready_engine(True)
    wire = Wire(engine)
    req = Recorded(command)
    assert wire.submit(req) == command.tx
    arrived = ahead + command.tx if ahead else command.encode_reply(30)
    expect = len(command.tx) + command.reply_len
    wire.schedule(0.0005, arrived[:expect])  # the count is reached here: the rest comes as strays
    wire.schedule(0.0006, arrived[expect:])
    wire.run_until(engine.deadline + 0.001)
    assert isinstance(req.error, EchoMismatch), req.error
    assert req.error.raw == arrived[:expect]
    assert echo_setting_wrong(req.error, echo=True) is evidence
    assert req.error.echo_behind is (not evidence)


async def test_a_shared_id_is_garbled_not_found(lines: Any) -> None:
    sim = lines([VirtualServo(1), VirtualServo(3), VirtualServo(3)])
    report = await scan(opener(sim), bauds=[115200], ids=range(5))
    assert [s.servo_id for s in report.servos] == [1]
    assert [(baud, i) for baud, i, _ in report.garbled] == [(115200, 3)]
    # Garbled twice: the first probe and the one after the line settled.
    assert [t.servo_id for t in sim.log if t.command == "read_stretch"].count(3) == 2


@pytest.mark.parametrize("seed", range(12))
async def test_a_reply_garbled_once_is_found_on_the_second_probe(lines: Any, seed: int) -> None:
    sim = lines([VirtualServo(1), VirtualServo(3)], faults="msb@3:0.5", seed=seed)
    async with open_bus(sim, **FAST) as bus:
        rate = await probe_ids(bus, range(5))
    reads_of_3 = [t for t in sim.log if t.command == "read_stretch" and t.servo_id == 3]
    last_clean = reads_of_3[-1].fault is None
    assert (3 in rate.answered) == last_clean
    assert (3 in rate.garbled) == (not last_clean)
    assert len(reads_of_3) == (1 if reads_of_3[0].fault is None else 2)


async def test_a_line_that_ignores_rates_lists_each_servo_once_at_its_eeprom_rate(lines: Any) -> None:
    # The line runs at 625000 whatever the host sets: the servos answer at every rate.
    sim = lines([VirtualServo(1, baud_rate=625000), VirtualServo(2, baud_rate=625000)], follow_host_baud=False)
    sim.baudrate = 625000
    for read_eeprom in (True, False):
        report = await scan(opener(sim), read_eeprom=read_eeprom)
        assert [(s.servo_id, s.baud) for s in report.servos] == [(1, 625000), (2, 625000)]
        assert all(s.answered_at == ALL_BAUDS for s in report.servos)
        assert all(s.eeprom is not None for s in report.servos)


async def test_two_servos_sharing_an_id_at_two_rates_are_both_listed(lines: Any) -> None:
    sim = lines([VirtualServo(5), VirtualServo(5, baud_rate=1250000)])
    sim.servos[1].eeprom = sim.servos[1].eeprom.replace(speed=50)  # another unit
    report = await scan(opener(sim), ids=[5], read_eeprom=False)
    assert [(s.servo_id, s.baud) for s in report.servos] == [(5, 115200), (5, 1250000)]


async def test_a_pending_baud_change_is_listed_where_the_servo_answers(lines: Any) -> None:
    sim = lines([VirtualServo(7)])
    sim.servo(7).eeprom = sim.servo(7).eeprom.replace(baud_rate=BaudRate.B1250000)  # not power-cycled yet
    report = await scan(opener(sim), ids=[7])
    (found,) = report.servos
    assert (found.baud, found.eeprom_baud, found.baud_pending) == (115200, 1250000, True)


async def test_a_silent_line_and_a_wrong_echo_setting_are_told_apart(lines: Any) -> None:
    dead = lines([], echo=False)
    report = await scan(opener(dead), ids=range(4))
    assert report.servos == () and report.silent

    echoing = lines([VirtualServo(1)])
    for ids in (range(4), range(32)):  # probed one by one / the ID read shows it at once
        report = await scan(opener(echoing, echo=False), ids=ids)
        assert report.servos == () and not report.silent
        evidence = report.echo_evidence
        assert isinstance(evidence, ReplyError) and evidence.raw[0] >= 0x80
    assert echoing.transactions <= 3 * 4 + 3
    report = await scan(opener(echoing), ids=range(4))
    assert report.echo_evidence is None

    not_echoing = lines([VirtualServo(1)], echo=False)
    report = await scan(opener(not_echoing), bauds=[115200], ids=range(4))
    assert report.servos == () and isinstance(report.echo_evidence, ReplyError)
    assert report.echo_evidence.raw[0] < 0x80


async def test_a_rate_the_port_cannot_open_is_skipped(lines: Any) -> None:
    sim = lines([VirtualServo(1, baud_rate=1250000)])

    def open_at(baud: int) -> Bus:
        if baud == 625000:
            raise SerialPortError("this adapter cannot do 625000 baud")
        return open_bus(sim, baudrate=baud, **FAST)

    report = await scan(open_at, ids=[1])
    assert dict(report.skipped) == {625000: "this adapter cannot do 625000 baud"}
    assert [(s.servo_id, s.baud) for s in report.servos] == [(1, 1250000)]

    def missing(baud: int) -> Bus:
        raise PortNotFound(2, "no serial port /dev/nothing")

    with pytest.raises(PortNotFound):
        await scan(missing, ids=[1])

    def refused(baud: int) -> Bus:
        raise SerialPortError(111, f"the connection was refused (at {baud})")

    # No rate opened at all: the port's own error (the first rate's), not an empty report.
    with pytest.raises(SerialPortError, match=r"refused \(at 625000\)"):
        await scan(refused, bauds=[625000, 115200], ids=[1])


async def test_a_path_that_is_no_serial_port_stops_the_scan_at_once(tmp_path: Any) -> None:
    # The same at every rate: no probe is counted for rates never tried (a progress bar showed a full
    # scan before the error).
    path = tmp_path / "notes.txt"
    path.write_text("")
    opened: list[int] = []
    heard: list[object] = []

    def open_at(baud: int) -> Bus:
        opened.append(baud)
        return open_bus(str(path), baudrate=baud, **FAST)

    with pytest.raises(SerialPortError, match="not a serial port"):
        await scan(open_at, ids=range(32), on_probe=lambda *outcome: heard.append(outcome))
    assert len(opened) == 1 and heard == []


async def test_bad_arguments_raise_before_the_line_opens(lines: Any) -> None:
    sim = lines([VirtualServo(1)])
    for kwargs in ({"bauds": [9600]}, {"bauds": []}, {"ids": [32]}):
        with pytest.raises(InvalidArgument):
            await scan(opener(sim), **kwargs)
    assert sim.transactions == 0


class LossyAt115200(VirtualServo):
    """A 115200 servo on a line that passes every rate, whose replies at 115200 are lost."""

    def answers(self, baudrate: int) -> bool:
        return baudrate != 115200


async def test_servo_rates_never_offers_a_rate_the_eeprom_contradicts(lines: Any) -> None:
    sim = lines([LossyAt115200(1), VirtualServo(2, baud_rate=1250000)])
    assert await servo_rates(opener(sim), 1, [625000, 1250000]) == ()
    assert await servo_rates(opener(sim), 2, [115200, 625000, 1250000]) == (1250000,)


async def test_servo_rates_asks_each_other_rate_once_with_the_whole_allowance(lines: Any) -> None:
    # `ics35 monitor 1-4 --free --timeout 1` on a line where nothing answers: the search of the other rates for
    # servo 1 asked each rate three times (the read, the bus's retry and the guard read before it), three whole
    # allowances a rate.  Whether anything answers there is all it asks: once a rate, with the whole allowance
    # (nothing has answered to learn a shorter wait from, and a slow link delays a reply at every rate alike).
    sim = lines([VirtualServo(2, baud_rate=1250000)])
    allowance = PATIENT["adapter_latency"]
    tried: list[int] = []
    start = time.monotonic()
    found = await servo_rates(
        opener(sim, adapter_latency=allowance, retries=1), 1, [625000, 1250000], on_rate=tried.append
    )
    took = time.monotonic() - start
    assert found == () and tried == [625000, 1250000]
    assert [(t.servo_id, t.command) for t in sim.log] == [(1, "read_stretch")] * 2
    assert 2 * allowance <= took < 3 * allowance, took  # (six allowances before)
    # A servo there is still found (its EEPROM read, the longest reply, with the bus's retries as ever).
    assert await servo_rates(opener(sim, retries=1), 2, [625000, 1250000]) == (1250000,)


async def test_a_search_of_the_other_rates_says_which_it_tried_and_where_a_device_answers(lines: Any) -> None:
    # After nothing answered at a line's rate, doctor and the configurator's Line page look at the other rates, and
    # said nothing of which once the search found nothing: the search tells which rates it tried, in words too.
    from ics35_async.policies import search_other_rates

    sim = lines([VirtualServo(2, baud_rate=1250000)])
    told: list[int] = []
    search = await search_other_rates(opener(sim), [115200], on_rate=told.append)
    assert (search.tried, search.found) == ((625000, 1250000), (1250000,)) and told == [625000, 1250000]
    assert search.nothing_elsewhere() is None  # (a device answers at 1250000)
    empty = lines([])
    nobody = await search_other_rates(opener(empty), [625000])
    assert (nobody.tried, nobody.found) == ((115200, 1250000), ())
    assert nobody.nothing_elsewhere() == "nor any device at 115200 or 1250000 baud"
    assert (await search_other_rates(opener(empty), ALL_BAUDS)).tried == ()  # (no other rate to try)
    with pytest.raises(InvalidArgument):
        await search_other_rates(opener(empty), [9600])


async def test_a_rate_whose_ask_raised_is_not_said_asked_and_unanswered(lines: Any) -> None:
    # Why a servo did not answer: its search of the other rates listed each rate it began to ask as asked and not
    # answered, one whose ask raised too (the port lost as the servo was asked there, its answer never back), and
    # the words said "nor at 625000 baud".  Only a rate asked to its end is said so; the others could not be tried.
    from ics35_async.errors import ReplyTimeout
    from ics35_async.policies import NoReplyCause, why_no_reply

    puller = UnplugsWhenAsked(1, ReadParam, baud_rate=625000)  # (answers at 625000, pulling the port as it hears)
    sim = lines([puller])
    puller.line = sim
    async with open_bus(sim, **FAST) as bus:
        with pytest.raises(ReplyTimeout) as unanswered:
            await bus.request(ReadParam(1, Param.STRETCH), retries=0)
    told: list[int] = []
    finding = await why_no_reply(unanswered.value, opener(sim), 115200, on_rate=told.append)
    assert told == [625000] and sim.unplug_count == 1  # (asked there: the port went as it was)
    assert finding.cause is NoReplyCause.UNKNOWN and finding.rates_tried
    assert finding.searched == () and finding.nothing_elsewhere() is None, finding
    assert finding.not_searched == (625000, 1250000), finding
    assert finding.not_searched_in_words() == "625000 and 1250000 baud could not be tried"


@pytest.mark.parametrize("seed", range(4))
async def test_a_cut_reply_is_garbled_and_no_reply_is_silence(lines: Any, seed: int) -> None:
    sim = lines([VirtualServo(2)], faults="truncate@2:1.0", seed=seed)
    async with open_bus(sim, **FAST) as bus:
        rate = await probe_ids(bus, range(4), id_read_first=False)
    assert rate.answered == ()
    last = [t for t in sim.log if t.servo_id == 2][-1]
    if last.reply:
        assert isinstance(rate.garbled[2], PartialReply)
    else:
        assert 2 not in rate.garbled


def noisy_rate_blind_line(lines: Any, level: float, seed: int) -> VirtualLine:
    """Servos 1, 2 and 5 (EEPROM: 115200) on a line that answers at every rate, like a pty, with ``level``
    of the replies dropped, truncated, corrupted or late."""
    each = level / 4
    faults = f"drop:{each},truncate:{each},corrupt:{each},late:{each}"
    return lines([VirtualServo(1), VirtualServo(2), VirtualServo(5)], follow_host_baud=False, faults=faults, seed=seed)


@pytest.mark.parametrize("level", [0.15, 0.30])
@pytest.mark.slow
async def test_a_noisy_line_that_ignores_rates_never_lists_a_servo_twice_or_at_a_contradicted_rate(
    lines: Any, level: float
) -> None:
    listed_once = 0
    for seed in range(16):
        sim = noisy_rate_blind_line(lines, level, seed)
        report = await scan(opener(sim), ids=range(8))
        ids = [s.servo_id for s in report.servos]
        assert len(ids) == len(set(ids)), (seed, report.servos)  # never twice
        assert set(ids) <= {1, 2, 5}, (seed, report.servos)
        for found in report.servos:
            if found.rate_unconfirmed:  # the entry says so: its EEPROM could not be read
                assert found.eeprom is None and found.eeprom_error is not None, (seed, found)
            else:  # a listed rate is the one its EEPROM names
                assert found.eeprom is not None and found.baud == found.eeprom_baud == 115200, (seed, found)
        listed_once += sorted(ids) == [1, 2, 5] and not any(s.rate_unconfirmed for s in report.servos)
        if level == 0.15:  # with reads retried, every servo is found and confirmed
            assert sorted(ids) == [1, 2, 5] and not any(s.rate_unconfirmed for s in report.servos), (seed, report)
    assert listed_once >= 8  # most scans find every servo even at 30%


@pytest.mark.parametrize("ids_from", [0, 1])
async def test_a_scan_on_a_lost_port_raises_port_lost_itself_not_a_group_of_them(ids_from: int) -> None:
    # The probes run concurrently; the caller asked for one scan and gets the one error it documents.
    # (ids_from=1 skips the ID read a full scan starts with: the probes are the first to fail.)
    from ics35_async import PortLost, State

    sim = VirtualLine([VirtualServo(1)])
    async with open_bus(sim, reconnect=True) as bus:
        sim.unplug()
        while bus.state is not State.LOST:
            await bus.state_change()
        with pytest.raises(PortLost):
            await bus.scan(range(ids_from, 32))
    sim.close()


@pytest.mark.parametrize("pulled_at", [ReadParam, ReadEeprom], ids=["probing", "reading-eeprom"])
async def test_a_port_lost_part_way_keeps_the_servos_found_before_it(lines: Any, pulled_at: type) -> None:
    # Servos 1 and 2 answered before the line went: a caller gets them, and the loss, not only the loss.
    puller = UnplugsWhenAsked(20, pulled_at)
    sim = lines([VirtualServo(1), VirtualServo(2), puller, VirtualServo(7, baud_rate=625000)])
    puller.line = sim
    report = await scan(opener(sim), ids=range(32))
    assert [s.servo_id for s in report.servos][:2] == [1, 2], report
    assert 7 not in [s.servo_id for s in report.servos]  # (its rate came after the loss)
    if pulled_at is ReadEeprom:  # the probes were over: servo 1's EEPROM was read before the loss
        assert report.servos[0].eeprom == sim.servo(1).eeprom
    assert isinstance(report.lost, (PortLost, BusClosed)), report.lost


async def test_a_cancelled_scan_has_told_on_found_of_each_servo_it_found(lines: Any) -> None:
    # A program cancels a scan (a person's Ctrl-C) as it moves on to 625000 baud: servos 1 and 3 had answered at
    # 115200, heard as they did, not only in a report the cancel never lets the scan return.
    sim = lines([VirtualServo(1), VirtualServo(3), VirtualServo(7, baud_rate=625000)])
    found: list[tuple[int, int]] = []
    with anyio.CancelScope() as scope:
        plain = opener(sim)

        def open_at(baud: int) -> AbstractAsyncContextManager[Line]:
            if baud == 625000:
                scope.cancel()
            return plain(baud)  # type: ignore[no-any-return]

        await scan(open_at, bauds=[115200, 625000], ids=range(8), on_found=lambda i, baud: found.append((i, baud)))
    assert scope.cancelled_caught
    assert found == [(1, 115200), (3, 115200)]


async def test_a_servo_found_only_by_the_second_look_is_told_to_on_found_too(lines: Any) -> None:
    # Servo 3 answers past the probes' short wait: the silent IDs' second look (the normal allowance) finds it.
    sim = lines([VirtualServo(1), VirtualServo(3)], faults="late@3:1.0", late_delay=0.012, realtime=True)
    found: list[tuple[int, int]] = []
    report = await scan(
        opener(sim, adapter_latency=0.100, quiet_time=0.030),
        bauds=[115200],
        ids=range(4),
        read_eeprom=False,
        on_found=lambda i, baud: found.append((i, baud)),
    )
    assert [s.servo_id for s in report.servos] == [1, 3]
    assert sorted(found) == [(1, 115200), (3, 115200)]


async def test_a_port_lost_between_two_rates_of_one_reopened_line_keeps_the_servos_found_before_it(
    lines: Any,
) -> None:
    # One line reopened at each rate (as the configurator scans): its port went after the first rate's last read,
    # before the reopen at the next.  The reopen's PortLost ("cannot reopen now")
    # came out of the scan, and the servos found at 115200 with it.
    from ics35_async import State
    from ics35_async.policies import reopening

    sim = lines([VirtualServo(1), VirtualServo(2), VirtualServo(7, baud_rate=625000)])
    async with open_bus(sim, reconnect=True, **FAST) as bus:
        reopen_at = reopening(bus)

        @contextlib.asynccontextmanager
        async def open_at(baud: int) -> AsyncIterator[Line]:
            if baud != int(bus.baudrate):  # between two rates: the adapter pulled out
                sim.unplug()
                while bus.state is not State.LOST:
                    await bus.state_change()
            async with reopen_at(baud) as line:
                yield line

        report = await scan(open_at, bauds=[115200, 625000], ids=range(8))
    assert [s.servo_id for s in report.servos] == [1, 2], report
    assert report.servos[0].eeprom == sim.servo(1).eeprom
    assert isinstance(report.lost, PortLost), report.lost
