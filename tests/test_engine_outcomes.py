"""The engine's outcomes, by table: byte sequences and times in, a value or a typed error out.

Plain calls only (``submit``/``receive``/``tick`` with a simulated time): no
event loop, no clock.  ``Wire.run_until`` feeds scheduled bytes and ticks at
the engine's deadlines in time order, as a driver must.
"""

from __future__ import annotations

import itertools
from typing import Any

import pytest

from ics35_async.engine import FlushInput, State
from ics35_async.errors import (
    BadReply,
    EchoMismatch,
    PartialReply,
    ReplyDataError,
    ReplyError,
    ReplyHeaderError,
    ReplySubcommandError,
    ReplyTimeout,
)
from ics35_async.protocol import Position, ReadId
from tests.support.engine_support import Recorded, Wire, position, read, ready_engine

CMD = read(3)
TX = CMD.tx
REPLY = CMD.encode_reply(42)
BAD_ECHO = bytes([TX[0] ^ 0x01]) + TX[1:]
LATE = -1.0  # stands for "just after the deadline"
LATE_AHEAD = bytes.fromhex("81 00 00 01 3a 4c")  # a free command to ID 1, its echo and reply

COUNTER = {
    ReplyTimeout: "timeouts",
    PartialReply: "partial_replies",
    EchoMismatch: "echo_mismatches",
}

# (name, events [(time, bytes)], expected value or error class, extra checks on the error)
ECHO_TABLE: list[tuple[str, list[tuple[float, bytes]], Any]] = [
    ("clean", [(0.001, TX + REPLY)], 42),
    ("echo then reply", [(0.0002, TX), (0.001, REPLY)], 42),
    ("reply just before the deadline", [(0.0205, TX + REPLY)], 42),
    ("nothing", [], ReplyTimeout),
    ("half the echo", [(0.0001, TX[:1])], ReplyTimeout),
    ("echo only", [(0.0002, TX)], ReplyTimeout),
    ("echo and 1 reply byte", [(0.001, TX + REPLY[:1])], PartialReply),
    ("echo and 2 reply bytes", [(0.001, TX + REPLY[:2])], PartialReply),
    ("reply after the deadline", [(LATE, TX + REPLY)], ReplyTimeout),
    ("wrong echo, complete", [(0.001, BAD_ECHO + REPLY)], EchoMismatch),
    ("wrong echo, at the deadline", [(0.0002, BAD_ECHO)], EchoMismatch),
    ("wrong echo byte 2, at the deadline", [(0.0002, TX[:1] + b"\x7f")], EchoMismatch),
    ("an extra byte", [(0.001, TX + REPLY + b"\x00")], BadReply),
    # An earlier command's late echo and reply, read in one chunk with this one's (as a pty delivers them).
    ("a late reply ahead, one chunk", [(0.001, LATE_AHEAD + TX + REPLY)], EchoMismatch),
    ("wrong header", [(0.001, TX + bytes([REPLY[0] ^ 1]) + REPLY[1:])], ReplyHeaderError),
    ("wrong sub-command", [(0.001, TX + REPLY[:1] + b"\x01" + REPLY[2:])], ReplySubcommandError),
    ("value byte with its MSB set", [(0.001, TX + REPLY[:2] + b"\x85")], ReplyDataError),
]

NO_ECHO_TABLE: list[tuple[str, list[tuple[float, bytes]], Any]] = [
    ("clean", [(0.001, REPLY)], 42),
    ("nothing", [], ReplyTimeout),
    ("1 reply byte", [(0.001, REPLY[:1])], PartialReply),
    ("2 reply bytes", [(0.001, REPLY[:2])], PartialReply),
    ("reply after the deadline", [(LATE, REPLY)], ReplyTimeout),
    ("an extra byte", [(0.001, REPLY + b"\x00")], BadReply),
    # Without an echo the host's own bytes are a reply of the wrong header (and one byte short).
    ("own command heard back", [(0.001, TX + REPLY[:1])], ReplyHeaderError),
    ("wrong header", [(0.001, bytes([REPLY[0] ^ 1]) + REPLY[1:])], ReplyHeaderError),
]


def play(echo: bool, events: list[tuple[float, bytes]], retries: int = 0) -> tuple[Recorded, Wire]:
    engine = ready_engine(echo)
    wire = Wire(engine)
    req = Recorded(CMD, retries=retries)
    assert wire.submit(req) == TX
    assert engine.state is State.BUSY
    deadline = engine.deadline
    assert deadline == pytest.approx(engine.timing.allowance(len(TX) + CMD.reply_len, engine.baudrate))
    for at, data in events:
        wire.schedule(deadline + 0.001 if at == LATE else at, data)
    wire.run_until(deadline + 0.002)
    return req, wire


def check(req: Recorded, wire: Wire, events: list[tuple[float, bytes]], expected: Any) -> None:
    engine = wire.engine
    stats = engine.counters.snapshot(0)
    assert stats.total.transactions == 1
    assert req.calls == 1
    if isinstance(expected, type):
        assert type(req.error) is expected, req.error
        assert isinstance(req.error, ReplyError) and req.error.servo_id == 3 and req.error.command == "read_speed"
        # The error carries the bytes received for the transaction (and only those); an error
        # from the codec carries the reply it was given, the echo already stripped.
        before_deadline = b"".join(data for at, data in events if at != LATE)
        codec = expected not in (ReplyTimeout, PartialReply, EchoMismatch, BadReply)
        assert req.error.raw == (before_deadline[len(TX) * engine.echo :] if codec else before_deadline)
        if expected is PartialReply:
            assert isinstance(req.error, PartialReply)
            assert req.error.expected == 3 and req.error.received == len(before_deadline) - (len(TX) * engine.echo)
        with pytest.raises(expected):
            req.result()
        assert getattr(stats.total, COUNTER.get(expected, "bad_replies")) == 1
        assert stats.total.ok == 0
        assert engine.counters.resyncs == 1
    else:
        assert req.result() == expected and req.error is None
        assert stats.total.ok == 1 and engine.state is State.IDLE and engine.deadline == float("inf")
        assert engine.counters.resyncs == 0
    assert stats.per_id[3].transactions == 1


@pytest.mark.parametrize(("name", "events", "expected"), ECHO_TABLE, ids=[row[0] for row in ECHO_TABLE])
def test_outcome_with_echo(name: str, events: list[tuple[float, bytes]], expected: Any) -> None:
    req, wire = play(True, events)
    check(req, wire, events, expected)


@pytest.mark.parametrize(("name", "events", "expected"), NO_ECHO_TABLE, ids=[row[0] for row in NO_ECHO_TABLE])
def test_outcome_without_echo(name: str, events: list[tuple[float, bytes]], expected: Any) -> None:
    req, wire = play(False, events)
    check(req, wire, events, expected)


def test_a_late_reply_read_in_one_chunk_with_the_echo_is_named_as_late_not_as_extra_bytes() -> None:
    # A stream's transaction given up on at its deadline answered after the resync's flush, just as the next command
    # went: its six bytes and the next command's echo and reply came in one read.  "Extra bytes after the reply" sent
    # a reader to baud rates and shared IDs; the echo is there, behind a late reply: a slow servo or link.
    events = [(0.001, LATE_AHEAD + TX + REPLY)]
    req, _ = play(True, events)
    assert isinstance(req.error, EchoMismatch), req.error
    assert req.error.echo_at == len(LATE_AHEAD) and req.error.echo_behind
    assert "ahead of the echo" in str(req.error)


def test_no_echo_at_all_names_an_adapter_that_holds_bytes_back_as_well_as_one_not_connected() -> None:
    # On an FTDI adapter with its 16 ms latency timer, an echo held past the allowance read "is the adapter
    # connected?" of an adapter that was.
    req, _ = play(True, [])
    assert isinstance(req.error, ReplyTimeout)
    assert "is the adapter connected" in str(req.error) and "latency timer" in str(req.error), req.error


def test_a_complete_wrong_transaction_fails_at_once_and_resyncs() -> None:
    engine = ready_engine()
    req = Recorded(CMD)
    engine.submit(req, 0.0)
    assert engine.receive(BAD_ECHO + REPLY, 0.001) is None
    assert isinstance(req.error, EchoMismatch)
    assert engine.state is State.QUIET
    # What came may not have been its reply: its own may still come, as late as after a timeout,
    # so the resync lasts as long as a timeout's would (a quiet time past its deadline).
    due = engine.timing.allowance(len(CMD.tx) + CMD.reply_len, engine.baudrate, CMD.timing)
    assert engine.deadline == pytest.approx(due + engine.timing.quiet_time)


def test_extra_bytes_after_an_id_reply_are_said_to_be_several_devices_answering() -> None:
    # Every device on the line answers the ID command: a scan's ID read on a line of several servos
    # gets more than one reply, and `-v` should read as that, not as a line fault.
    engine = ready_engine()
    req = Recorded(ReadId())
    assert engine.submit(req, 0.0) == ReadId().tx
    engine.receive(ReadId().tx + b"\xe1\xe2", 0.001)
    assert isinstance(req.error, BadReply) and req.error.command == "read_id"
    assert "more than one device answering the ID command?" in str(req.error), req.error
    other = Recorded(CMD)  # a servo's own reply with a byte more: no such guess
    engine = ready_engine()
    engine.submit(other, 0.0)
    engine.receive(TX + REPLY + b"\x00", 0.001)
    assert "unexpected extra byte(s) after the reply" in str(other.error)
    assert "answered" not in str(other.error)


def compositions(n: int) -> list[list[int]]:
    """Every way to cut ``n`` bytes into consecutive non-empty chunks, as chunk lengths."""
    out = []
    for cuts in itertools.product((False, True), repeat=n - 1):
        sizes, size = [], 1
        for cut in cuts:
            if cut:
                sizes.append(size)
                size = 0
            size += 1
        out.append([*sizes, size])
    return out


@pytest.mark.parametrize("echo", [True, False], ids=["echo", "no-echo"])
@pytest.mark.parametrize("command", [read(3), position(5, 9000)], ids=["read", "position"])
def test_every_split_of_echo_and_reply_gives_the_value(echo: bool, command: Any) -> None:
    reply = command.encode_reply(1234 if isinstance(command, Position) else 42)
    stream = (command.tx if echo else b"") + reply
    for sizes in compositions(len(stream)):
        engine = ready_engine(echo)
        req = Recorded(command)
        assert engine.submit(req, 0.0) == command.tx
        at, t = 0, 0.0
        for size in sizes:
            assert engine.state is State.BUSY, sizes  # nothing is judged before the last byte
            t += 0.001
            assert engine.receive(stream[at : at + size], t) is None
            at += size
        assert req.result() == command.parse(reply), sizes
        assert engine.state is State.IDLE


def test_a_reply_the_driver_feeds_late_still_counts() -> None:
    # After a stalled loop the driver feeds input that arrived in time before it ticks;
    # the engine judges by bytes, not by the time they are handed over.
    engine = ready_engine()
    req = Recorded(CMD)
    engine.submit(req, 0.0)
    assert engine.receive(TX + REPLY, engine.deadline + 1.0) is None
    assert req.result() == 42


def test_a_byte_after_a_complete_reply_is_stray_and_starts_a_resync() -> None:
    engine = ready_engine()
    req = Recorded(CMD)
    engine.submit(req, 0.0)
    engine.receive(TX + REPLY, 0.001)
    engine.receive(b"\x00", 0.0015)
    assert req.result() == 42
    assert engine.state is State.QUIET and engine.counters.stray == 1


# ---------------------------------------------------------------- parity errors


def test_a_parity_marked_byte_fails_the_transaction() -> None:
    engine = ready_engine()
    req = Recorded(CMD)
    engine.submit(req, 0.0)
    engine.receive(TX + REPLY[:1], 0.001)
    engine.line_error(1)  # reported by the port before the damaged byte is handed over
    engine.receive(REPLY[1:], 0.0011)
    assert type(req.error) is ReplyDataError and "parity" in str(req.error)
    assert req.error.raw == TX + REPLY
    assert engine.counters.line_errors == 1
    assert engine.counters.snapshot(0).total.bad_replies == 1
    assert engine.state is State.QUIET


def test_a_parity_error_outside_a_transaction_spoils_no_later_one() -> None:
    engine = ready_engine()
    engine.line_error(2)
    req = Recorded(CMD)
    engine.submit(req, 0.0)
    engine.receive(TX + REPLY, 0.001)
    assert req.result() == 42
    assert engine.counters.line_errors == 2


# ---------------------------------------------------------------- resync


def test_stray_bytes_on_an_idle_line_start_a_resync_and_the_queue_waits() -> None:
    engine = ready_engine()
    quiet = engine.timing.quiet_time
    assert engine.receive(b"\x55\x55", 1.0) is None
    assert engine.state is State.QUIET and engine.counters.stray == 2 and engine.counters.resyncs == 1
    assert engine.deadline == pytest.approx(1.0 + quiet)
    req = Recorded(CMD)
    assert engine.submit(req, 1.001) is None  # waits for the silence
    assert engine.tick(1.0 + quiet / 2) is None
    # The driver drops whatever the OS still buffers, then writes.
    assert engine.tick(engine.deadline) == FlushInput(TX)
    assert engine.state is State.BUSY


def test_bytes_during_a_resync_extend_it() -> None:
    engine = ready_engine()
    quiet = engine.timing.quiet_time
    engine.receive(b"\x55", 1.0)
    first = engine.deadline
    engine.receive(b"\x55", 1.0 + quiet * 0.8)
    assert engine.deadline == pytest.approx(1.0 + quiet * 1.8)
    assert engine.tick(first) is None and engine.state is State.QUIET
    assert engine.tick(engine.deadline) == FlushInput(None)
    assert engine.state is State.IDLE
    assert engine.counters.resyncs == 1 and engine.counters.stray == 2


def test_max_resync_caps_a_resync_on_a_line_that_never_goes_quiet() -> None:
    engine = ready_engine()
    quiet, cap = engine.timing.quiet_time, engine.timing.max_resync
    engine.receive(b"\x55", 1.0)
    req = Recorded(CMD)
    engine.submit(req, 1.0)
    t, written_at = 1.0, None
    while t < 1.0 + 4 * cap and written_at is None:
        t += quiet / 2
        # A driver ticks at the engine's deadline, before later input.
        if engine.deadline <= t and engine.tick(engine.deadline) == FlushInput(TX):
            written_at = t
        engine.receive(b"\x55", t)  # noise, faster than the quiet time
    assert written_at is not None and written_at <= 1.0 + cap + quiet


def test_flush_input_is_asked_when_a_fault_resync_ends() -> None:
    req, wire = play(True, [])
    engine = wire.engine
    assert isinstance(req.error, ReplyTimeout) and engine.state is State.QUIET
    assert engine.tick(engine.deadline) == FlushInput(None)
    assert engine.state is State.IDLE


def test_a_clean_transaction_asks_no_flush() -> None:
    req, wire = play(True, [(0.001, TX + REPLY)])
    assert req.result() == 42 and wire.flushes == 0
