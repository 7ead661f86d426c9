"""The engine's life cycle: offline and reopen, close and drain, a lost port, and what it may not import.

Plain calls and simulated time only (see engine_support): no event loop.
"""

from __future__ import annotations

import ast
import math
from pathlib import Path

import pytest

from ics35_async import protocol
from ics35_async.engine import LineEngine, State
from ics35_async.errors import BusClosed, InvalidArgument, PortLost, ReplyTimeout
from ics35_async.protocol import Timing
from tests.support.engine_support import FakeSource, Recorded, Servos, Wire, position, read, ready_engine

ENGINE_DIR = Path(__file__).resolve().parents[1] / "ics35_async" / "engine"
REPLY = read(3).encode_reply(9)


def busy_engine() -> tuple[LineEngine, Recorded, Recorded]:
    """An engine with ``a`` on the wire and ``b`` queued."""
    engine = ready_engine()
    a, b = Recorded(read(3), retries=2), Recorded(read(4))
    assert engine.submit(a, 0.0) == read(3).tx
    assert engine.submit(b, 0.0) is None
    return engine, a, b


# ---------------------------------------------------------------- offline, reopen, baud


def test_requests_wait_while_offline_and_go_when_connected() -> None:
    engine = LineEngine(baudrate=115200)
    assert engine.state is State.OFFLINE
    req = Recorded(read(3))
    assert engine.submit(req, 0.0) is None
    assert engine.connected(1.0) == read(3).tx
    assert engine.state is State.BUSY


def test_a_reopen_keeps_queued_requests() -> None:
    engine = ready_engine()
    engine.disconnected()
    assert engine.state is State.OFFLINE and engine.deadline == math.inf
    a, b = Recorded(read(3)), Recorded(read(4))
    assert engine.submit(a, 0.1) is None and engine.submit(b, 0.1) is None
    wire = Wire(engine, Servos({3, 4}))
    wire.now = 0.2
    wire.emit(engine.connected(wire.now))
    wire.settle()
    assert a.state == b.state == "done"
    assert wire.sent() == [read(3).tx, read(4).tx]


def test_a_line_asked_offline_while_busy_goes_offline_once_its_transaction_ends() -> None:
    # A reopen beside a program that keeps requests queued (telemetry) waited for a line with nothing on the wire
    # and nothing queued, which never came; taking the line offline at once was refused while busy.  Now the
    # transaction on the wire ends, then the line goes offline, and what was queued meanwhile waits for the port.
    engine = ready_engine()
    wire = Wire(engine, Servos({3, 4}))
    a, b = Recorded(read(3)), Recorded(read(4))
    wire.submit(a)
    assert engine.state is State.BUSY
    assert engine.disconnected() is False  # (at the end of a's transaction)
    # A dump taken meanwhile says so: a busy line that queues nothing more would look stuck otherwise.
    assert engine.describe(wire.now)["going_offline"] is True
    wire.submit(b)
    wire.run_for(0.1)  # (a's transaction takes a millisecond)
    assert a.state == "done" and b.state != "done"
    assert engine.state is State.OFFLINE and engine.deadline == math.inf
    assert engine.describe(wire.now)["going_offline"] is False  # (offline now: the state says it)
    assert wire.sent() == [read(3).tx]
    with pytest.raises(InvalidArgument):
        engine.disconnected()  # (offline already)
    wire.emit(engine.connected(wire.now))
    wire.settle()
    assert b.state == "done" and wire.sent() == [read(3).tx, read(4).tx]


def test_an_open_line_cannot_be_connected_again() -> None:
    engine, _, _ = busy_engine()
    with pytest.raises(InvalidArgument):
        engine.connected(0.0)  # already open


def test_a_baud_change_clears_the_allowance_cache() -> None:
    engine = ready_engine()
    nbytes = len(read(3).tx) + read(3).reply_len
    tx = engine.submit(Recorded(read(3)), 0.0)
    assert engine.deadline == pytest.approx(engine.timing.allowance(nbytes, 115200))
    engine.receive(tx + REPLY, 0.001)
    engine.disconnected()
    engine.baudrate = 1250000
    engine.connected(1.0)
    engine.submit(Recorded(read(3)), 1.0)
    fast = engine.timing.allowance(nbytes, 1250000)
    assert fast < engine.timing.allowance(nbytes, 115200)
    assert engine.deadline - 1.0 == pytest.approx(fast)


@pytest.mark.parametrize(
    ("command", "kind"),
    [(read(3), Timing.NORMAL), (protocol.ReadId(), Timing.ID), (protocol.WriteId(5), Timing.ID)],
    ids=["normal", "read id", "write id"],
)
def test_each_command_gets_its_own_allowance(command: protocol.Command[int], kind: Timing) -> None:
    engine = ready_engine()
    engine.submit(Recorded(command), 2.0)
    nbytes = len(command.tx) + command.reply_len
    assert engine.deadline - 2.0 == pytest.approx(engine.timing.allowance(nbytes, 115200, kind))


# ---------------------------------------------------------------- close and abort


def test_close_while_busy_fails_the_queue_and_drains_the_wire() -> None:
    engine, a, b = busy_engine()
    engine.close()
    assert engine.state is State.DRAINING
    assert isinstance(b.error, BusClosed)
    assert a.state == "queued"
    with pytest.raises(BusClosed):
        engine.submit(Recorded(read(5)), 0.001)
    assert engine.receive(read(3).tx + REPLY, 0.002) is None  # nothing new starts
    assert a.result() == 9
    assert engine.state is State.CLOSED and engine.deadline == math.inf and engine.idle


def test_a_transaction_that_fails_while_draining_is_not_retried() -> None:
    engine, a, _ = busy_engine()
    engine.close()
    assert engine.tick(engine.deadline) is None
    assert isinstance(a.error, BusClosed)  # it had retries left, but the bus is closing
    assert engine.state is State.CLOSED and engine.deadline == math.inf


def test_a_transaction_without_retries_that_times_out_while_draining_keeps_its_error() -> None:
    engine = ready_engine()
    req = Recorded(read(3))
    engine.submit(req, 0.0)
    engine.close()
    engine.tick(engine.deadline)
    assert isinstance(req.error, ReplyTimeout) and engine.state is State.CLOSED


@pytest.mark.parametrize("make_quiet", [False, True], ids=["idle", "resyncing"])
def test_close_when_nothing_is_on_the_wire_closes_at_once(make_quiet: bool) -> None:
    engine = ready_engine()
    source = FakeSource([1])
    source.active = False
    engine.attach_source(source, 0.0)
    if make_quiet:
        engine.receive(b"\x00", 0.0)
        assert engine.state is State.QUIET
    engine.close()
    assert engine.state is State.CLOSED and engine.deadline == math.inf
    assert isinstance(source.closed, BusClosed)
    with pytest.raises(BusClosed):
        engine.attach_source(FakeSource([2]), 1.0)
    engine.close()  # twice is harmless
    assert engine.state is State.CLOSED


def test_abort_fails_the_transaction_on_the_wire() -> None:
    engine, a, b = busy_engine()
    engine.abort()
    assert isinstance(a.error, BusClosed) and isinstance(b.error, BusClosed)
    assert engine.state is State.CLOSED
    assert engine.receive(read(3).tx + REPLY, 0.001) is None  # late bytes are ignored
    assert a.calls == 1


# ---------------------------------------------------------------- a lost port


def test_a_lost_port_fails_everything_and_reconnect_keeps_the_source() -> None:
    engine = ready_engine()
    source = FakeSource([1])
    source.active = False
    engine.attach_source(source, 0.0)
    a, b = Recorded(read(3)), Recorded(read(4))
    engine.submit(a, 0.0)
    engine.submit(b, 0.0)
    engine.lost("unplugged", reconnect=True)
    assert isinstance(a.error, PortLost) and isinstance(b.error, PortLost)
    assert engine.state is State.LOST and engine.deadline == math.inf
    assert source.closed is None
    with pytest.raises(PortLost):
        engine.submit(Recorded(read(5)), 0.1)
    assert engine.receive(b"\x00", 0.2) is None and engine.state is State.LOST
    source.active = True
    assert engine.connected(1.0) == position(1, 0).tx  # the source resumes on the new port
    assert engine.state is State.BUSY


def test_a_lost_port_without_reconnect_closes_the_line() -> None:
    engine = ready_engine()
    source = FakeSource([1])
    engine.attach_source(source, 0.0)
    engine.lost("unplugged", reconnect=False)
    assert engine.state is State.CLOSED
    assert isinstance(source.closed, PortLost)
    with pytest.raises(BusClosed):
        engine.submit(Recorded(read(3)), 1.0)


def test_a_lost_port_while_draining_closes_the_line() -> None:
    engine, a, _ = busy_engine()
    engine.close()
    engine.lost("unplugged", reconnect=True)
    assert isinstance(a.error, PortLost) and engine.state is State.CLOSED
    engine.lost("again", reconnect=True)
    assert engine.state is State.CLOSED and a.calls == 1


def test_a_reconnect_during_a_resync_starts_clean() -> None:
    wire = Wire(ready_engine(), Servos({3}))
    wire.engine.receive(b"\x55", 0.0)
    wire.engine.lost("unplugged", reconnect=True)
    wire.clear_in_flight()
    wire.now = 1.0
    wire.emit(wire.engine.connected(wire.now))
    req = Recorded(read(3))
    assert wire.submit(req) == read(3).tx
    wire.settle()
    assert req.state == "done"


# ---------------------------------------------------------------- purity


FORBIDDEN = {"asyncio", "time", "threading", "select", "selectors", "socket", "serial", "os", "trio", "anyio"}


@pytest.mark.parametrize("path", sorted(ENGINE_DIR.glob("*.py")), ids=lambda p: p.name)
def test_the_engine_imports_no_io_no_clock_and_no_event_loop(path: Path) -> None:
    tree = ast.parse(path.read_text())
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    assert not names & FORBIDDEN, f"{path.name} imports {names & FORBIDDEN}"
