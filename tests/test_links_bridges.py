"""Lines on another machine: ``rfc2217://`` and ``socket://`` through loopback bridges to the simulator's pty.

The simulator runs in another process (``python -m ics35_async.sim``, its
servos at 115200 baud, following the rate its pty is set to); in front of its
pty sit pyserial's own RFC 2217 server side (which applies the client's baud
rate and parity) or a raw TCP forwarder (which carries neither, like ser2net's
raw mode or socat).  See tests/support/links.py.  Every driver that can drive
such a port runs: asyncio (auto), thread and anyio.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import socket
import threading
from collections.abc import Callable, Iterator
from typing import Any

import pytest

from ics35_async import open_bus, policies, protocol
from ics35_async.errors import InvalidArgument, PortLost, ReplyError, ReplyTimeout, SerialPortError
from ics35_async.protocol import Param
from ics35_async.sim import start_subprocess, stop_subprocess
from ics35_async.transports import links
from tests.support.links import Rfc2217Bridge, TcpBridge
from tests.support.timing import NO_TIMEOUTS, PATIENT, PATIENT_OPTION

pytestmark = pytest.mark.pty

DRIVERS = ("asyncio", "thread", "anyio")
ASKED = range(5)  # the far pty's servos (1-3) and an ID either side: a scan that counts them asks these
BRIDGES = {"rfc2217": Rfc2217Bridge, "socket": TcpBridge}


@pytest.fixture(scope="module")
def far_pty() -> Iterator[str]:
    proc, path = start_subprocess(["--ids", "1-3"], quiet=True)
    try:
        yield path
    finally:
        stop_subprocess(proc)


@pytest.fixture
def rfc2217(far_pty: str) -> Iterator[Rfc2217Bridge]:
    with Rfc2217Bridge(far_pty) as bridge:
        yield bridge


@pytest.fixture
def tcp_bridge(far_pty: str) -> Iterator[TcpBridge]:
    with TcpBridge(far_pty) as bridge:
        yield bridge


def free_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


# --------------------------------------------------------------------------- the direct path, for comparison


@pytest.mark.parametrize("driver", DRIVERS)
async def test_direct_pty_runs_many_transactions(far_pty: str, driver: str) -> None:
    """The path the bridges stand in front of, under every driver (the anyio driver once took an
    empty read of the raw tty for a hangup)."""
    # Every reply counted: the no-timeouts allowance (a stalled machine's late reply is not the subject).
    async with open_bus(far_pty, driver=driver, retries=2, **NO_TIMEOUTS) as bus:
        for i in range(300):
            assert await bus.servo(1 + i % 3).read_stretch() == 30


# --------------------------------------------------------------------------- RFC 2217


@pytest.mark.parametrize("driver", DRIVERS)
async def test_rfc2217_opens_and_its_baud_and_parity_reach_the_far_end(rfc2217: Rfc2217Bridge, driver: str) -> None:
    # Every reply expected: the no-timeouts allowance (a loaded machine holds a reply up in the bridge).
    async with open_bus(rfc2217.url, driver=driver, retries=2, **NO_TIMEOUTS) as bus:
        assert await bus.servo(1).read_stretch() == 30
        assert (115200, "E") in rfc2217.port_settings
    # At 625000 the far end's port runs at 625000: the servos (115200) cannot hear it.
    async with open_bus(rfc2217.url, baudrate=625000, driver=driver) as bus:
        with pytest.raises(ReplyTimeout):
            await bus.servo(1).read_stretch()
    assert (625000, "E") in rfc2217.port_settings


@pytest.mark.parametrize("driver", DRIVERS)
async def test_rfc2217_answers_right_after_a_silent_id(rfc2217: Rfc2217Bridge, driver: str) -> None:
    """A timeout makes the bus drop its input; over RFC 2217 that must not hold the next request up
    (pyserial's purge waits for the far end in 50 ms sleeps, longer than a reply's allowance): the bus
    sends the far end no purge, and the next request is answered."""
    async with open_bus(rfc2217.url, driver=driver, retries=2) as bus:
        await bus.servo(1).read_stretch()  # connected and settled
        purges = rfc2217.input_purges
        for _ in range(3):
            with pytest.raises(ReplyTimeout):
                await _stretch_once(bus, 9)  # nobody has ID 9
            # Retries allowed: a loaded machine can make a reply late; a purge that would hold one up is counted below.
            assert await bus.servo(2).read_stretch() == 30
        assert rfc2217.input_purges == purges


async def _stretch_once(bus: Any, servo_id: int) -> int:
    """One stretch read, no retry."""
    value: int = await bus.request(protocol.ReadParam(servo_id, Param.STRETCH), retries=0)
    return value


@pytest.mark.slow
async def test_rfc2217_scan_finds_each_servo_at_its_rate(rfc2217: Rfc2217Bridge) -> None:
    # Every present servo must answer at its rate, and only their IDs are asked; at the other rates each
    # waits its allowance out: the patient one.
    report = await policies.scan(
        lambda baud: open_bus(rfc2217.url, baudrate=baud, **PATIENT), ids=[1, 2, 3], read_eeprom=False
    )
    assert [(s.servo_id, s.baud) for s in report.servos] == [(1, 115200), (2, 115200), (3, 115200)]
    assert len(report.rates) == 3 and not report.rate_blind


# --------------------------------------------------------------------------- socket:// (a raw TCP bridge)


@pytest.mark.parametrize("driver", DRIVERS)
async def test_socket_bridge_works_and_warns_once_that_it_carries_no_settings(
    tcp_bridge: TcpBridge, driver: str, caplog: pytest.LogCaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    caplog.set_level(logging.WARNING, logger="ics35_async")
    # Once per port per process: an earlier test in this worker may have had this port number (the OS
    # hands free ports out again), so the test starts from a process that has warned of none.
    monkeypatch.setattr(links, "_warned", set())
    for _ in range(2):
        async with open_bus(tcp_bridge.url, driver=driver, retries=2, **NO_TIMEOUTS) as bus:
            assert await bus.servo(3).read_stretch() == 30
            async with bus.stream([1, 2], rate_hz=100) as stream:
                stream.set_targets({1: 7000, 2: 8000})
                seen: set[int] = set()
                for _ in range(5):
                    seen.update((await stream.next_frame()).positions)
            assert seen == {1, 2}
    warnings = [r for r in caplog.records if "does not carry the baud rate" in r.getMessage()]
    assert len(warnings) == 1, [r.getMessage() for r in caplog.records]
    assert tcp_bridge.port_settings and all(s == (115200, "N") for s in tcp_bridge.port_settings)


async def test_scan_over_socket_probes_once_and_lists_each_servo_once(tcp_bridge: TcpBridge) -> None:
    report = await policies.scan(lambda baud: open_bus(tcp_bridge.url, baudrate=baud, **PATIENT), ids=ASKED)
    assert report.rate_blind
    assert [r.baud for r in report.rates] == [115200]
    # (the whole report when one is missed: whether its answer came garbled, late or not at all)
    assert [s.servo_id for s in report.servos] == [1, 2, 3], report
    assert all(s.baud == 115200 and s.eeprom is not None for s in report.servos)
    assert tcp_bridge.connections == 1


async def test_scan_over_socket_lists_the_eeprom_rate(tcp_bridge: TcpBridge) -> None:
    # Asked for 625000 first: the bridge still runs at its own rate, and the servos say theirs.  Both servos
    # answer at every rate, so no reply may time out (a real-time pty behind a bridge thread, on a busy machine):
    # the patient allowance, as the other scans over a bridge.
    report = await policies.scan(
        lambda baud: open_bus(tcp_bridge.url, baudrate=baud, **PATIENT), bauds=[625000, 115200], ids=[1, 2]
    )
    assert [r.baud for r in report.rates] == [625000]
    assert [(s.servo_id, s.baud) for s in report.servos] == [(1, 115200), (2, 115200)]


def test_cli_scan_over_socket_lists_each_servo_once(tcp_bridge: TcpBridge, cli: Any) -> None:
    result = cli("--port", tcp_bridge.url, *PATIENT_OPTION, "scan", "--ids", "0-4", "--quick", "--json")
    assert result.code == 0, result.err
    data = result.json()
    assert [s["id"] for s in data["servos"]] == [1, 2, 3]
    assert data["rate_blind"] is True
    result = cli("--port", tcp_bridge.url, *PATIENT_OPTION, "scan", "--ids", "1-3")
    assert result.code == 0, result.err
    assert "does not carry the baud rate" in result.err
    assert "3 servo(s) found" in result.out


def test_cli_no_reply_over_socket_names_the_bridge_settings(tcp_bridge: TcpBridge, cli: Any) -> None:
    # (A patient allowance: on a loaded machine the bridge held the first try's echo past the default 20 ms, and
    # the retry took that late echo for its own, its own echo for a reply: "reply command byte 0xA9".)
    result = cli("--port", tcp_bridge.url, *PATIENT_OPTION, "get", "9", "stretch")
    assert result.code == 4, result.err
    assert "bridge's serial side" in result.err
    assert "does at" not in result.err  # no other baud rate offered: every rate is the bridge's one


# --------------------------------------------------------------------------- refused and dropped


@pytest.mark.parametrize("scheme", BRIDGES)
@pytest.mark.parametrize("driver", DRIVERS)
async def test_refused_connection_is_a_port_error(scheme: str, driver: str) -> None:
    with pytest.raises(SerialPortError, match="refused"):
        async with open_bus(f"{scheme}://127.0.0.1:{free_tcp_port()}", driver=driver):
            pass


@pytest.mark.parametrize("scheme", BRIDGES)
def test_cli_refused_connection_exits_3(scheme: str, cli: Any) -> None:
    result = cli("--port", f"{scheme}://127.0.0.1:{free_tcp_port()}", "get", "1", "stretch")
    assert result.code == 3, result.err
    assert "refused" in result.err


# A link URL pyserial cannot read: its own message for each is a Python error of its own (a format string's
# braces, None compared with a number), so the library reads the URL first.
MALFORMED_LINKS = {
    "socket://localhost": "no TCP port",
    "rfc2217://localhost": "no TCP port",
    "socket://127.0.0.1:99999": "1..65535, got '99999'",
    "rfc2217://127.0.0.1:99999": "1..65535, got '99999'",
    "socket://127.0.0.1:abc": "1..65535, got 'abc'",
    "socket://:4000": "no host",
    "socket://127.0.0.1:4000?logging=loud": "logging must be one of debug, info, warning, error, got 'loud'",
    "rfc2217://127.0.0.1:4000?logging=loud": "logging must be one of debug, info, warning, error, got 'loud'",
    "socket://127.0.0.1:4000?speed=1": "unknown option 'speed'",
    "rfc2217://127.0.0.1:4000?timeout=soon": "timeout must be a number of seconds, got 'soon'",
}


@contextlib.contextmanager
def accepting(on_accept: Callable[[socket.socket], object]) -> Iterator[int]:
    """A TCP port on 127.0.0.1 (its number) whose thread hands each connection it accepts to ``on_accept``."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(8)

    def serve() -> None:
        while True:
            try:
                conn, _ = server.accept()
            except OSError:
                return
            on_accept(conn)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        yield int(server.getsockname()[1])
    finally:
        # close() alone does not wake a thread blocked in accept() on Linux; shutdown() does.
        with contextlib.suppress(OSError):
            server.shutdown(socket.SHUT_RDWR)
        server.close()
        thread.join(5)
    assert not thread.is_alive()


@pytest.fixture
def listener() -> Iterator[tuple[int, list[socket.socket]]]:
    """A TCP port that accepts and keeps its connections, for URLs that must not reach it."""
    accepted: list[socket.socket] = []
    with accepting(accepted.append) as port:
        yield port, accepted


@pytest.mark.parametrize(("url", "said"), MALFORMED_LINKS.items())
async def test_a_malformed_link_url_is_refused_saying_what_is_wrong(url: str, said: str) -> None:
    with pytest.raises(InvalidArgument) as caught:
        async with open_bus(url):
            pass
    assert said in str(caught.value)
    assert "socket://HOST:PORT" in str(caught.value) or "rfc2217://HOST:PORT" in str(caught.value)


@pytest.mark.parametrize("scheme", BRIDGES)
async def test_a_link_url_with_a_bad_option_connects_to_nothing(
    scheme: str, listener: tuple[int, list[socket.socket]]
) -> None:
    port, accepted = listener
    with pytest.raises(InvalidArgument, match="logging must be"):
        async with open_bus(f"{scheme}://127.0.0.1:{port}?logging=loud"):
            pass
    await asyncio.sleep(0.1)  # (a connection made would have been accepted by now)
    assert accepted == []


def test_cli_malformed_link_url_exits_3_saying_what_is_wrong(cli: Any) -> None:
    result = cli("--port", "socket://localhost", "get", "1", "stretch")
    assert result.code == 3, result.err
    assert "no TCP port" in result.err
    assert "Traceback" not in result.err and "NoneType" not in result.err


@pytest.fixture
def hang_up_server() -> Iterator[int]:
    """A TCP port whose server accepts and hangs up at once (a bridge whose serial port is taken)."""
    with accepting(lambda conn: conn.close()) as port:
        yield port


def test_cli_dropped_connection_exits_3(hang_up_server: int, cli: Any) -> None:
    result = cli("--port", f"socket://127.0.0.1:{hang_up_server}", "get", "1", "stretch")
    assert result.code == 3, result.err
    assert "bridge" in result.err


async def _until_lost(bus: Any) -> None:
    for _ in range(200):
        try:
            await _stretch_once(bus, 1)
        except PortLost:
            return
        except ReplyError:  # (the far end going away can cut a reply short)
            pass
        await asyncio.sleep(0.01)
    pytest.fail("the dropped connection was never reported as PortLost")


async def _until_answers(bus: Any) -> int:
    # Right after the far end is back a read may fail in any typed way (a loaded machine can hold a reply's
    # tail in the bridge: a partial reply); what is tested is that the bus recovers, with the right value.
    for _ in range(500):
        try:
            return await _stretch_once(bus, 1)
        except (PortLost, ReplyError):
            await asyncio.sleep(0.02)
    pytest.fail("the bus did not recover after the far end came back")


@pytest.mark.parametrize("scheme", BRIDGES)
@pytest.mark.parametrize("driver", DRIVERS)
async def test_dropped_connection_is_port_lost_and_reconnect_recovers(far_pty: str, scheme: str, driver: str) -> None:
    bridge = BRIDGES[scheme](far_pty, tcp_port=free_tcp_port())
    bridge.start()
    try:
        # The patient allowance: the first read must be answered through the bridge however loaded the machine,
        # and the reads while the far end is gone or back fail and are tried again.
        async with open_bus(
            bridge.url, driver=driver, reconnect=True, reconnect_backoff=(0.05,), retries=2, **PATIENT
        ) as bus:
            assert await bus.servo(1).read_stretch() == 30
            bridge.stop()  # the far end goes away: connection dropped, then refused
            await _until_lost(bus)
            bridge.start()  # back, on the same TCP port
            assert await _until_answers(bus) == 30
            assert bus.stats.reconnects >= 1
    finally:
        bridge.stop()
