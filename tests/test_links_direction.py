"""Direction control for DIY half-duplex interfaces (``direction="rts"``, ``--direction``), as far as a pty goes.

A pty has no RTS pin and its driver refuses RS-485 mode (TIOCSRS485:
ENOTTY), so opening one with direction control must fail typed.  To see the
setting reach the driver, the kernel's answer is stood in for: pyserial's
``fcntl.ioctl`` accepts the two RS-485 ioctls on the pty and records the
flags pyserial asked for, and the bus then runs on the simulator as usual.
What this does not prove: a real UART's RTS timing.
"""

from __future__ import annotations

import array
import sys
from collections.abc import Iterator
from typing import Any

import pytest
import serial.serialposix as serialposix

from ics35_async import DirectionControlNotSupported, open_bus
from ics35_async.errors import InvalidArgument, SerialPortError
from ics35_async.sim import start_subprocess, stop_subprocess
from tests.support.timing import NO_TIMEOUTS, NO_TIMEOUTS_OPTION

pytestmark = [
    pytest.mark.pty,
    pytest.mark.skipif(not sys.platform.startswith("linux"), reason="Linux ptys and RS-485 ioctls"),
]

DRIVERS = ("asyncio", "thread", "anyio")
TIOCGRS485, TIOCSRS485 = 0x542E, 0x542F
ENABLED, RTS_ON_SEND, RTS_AFTER_SEND = 0b001, 0b010, 0b100


@pytest.fixture(scope="module")
def far_pty() -> Iterator[str]:
    proc, path = start_subprocess(["--ids", "1-2"], quiet=True)
    try:
        yield path
    finally:
        stop_subprocess(proc)


@pytest.fixture
def rs485_driver(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """A kernel that takes RS-485 mode on any tty: the flags set, in order."""
    real_ioctl = serialposix.fcntl.ioctl
    state = array.array("i", [0] * 8)
    flags: list[int] = []

    def ioctl(fd: int, request: int, arg: Any = 0, *rest: Any) -> Any:
        if request == TIOCGRS485:
            arg[:] = state
            return 0
        if request == TIOCSRS485:
            state[:] = arg
            flags.append(arg[0])
            return 0
        return real_ioctl(fd, request, arg, *rest)

    real_fcntl = serialposix.fcntl

    class Fcntl:  # pyserial's view of the fcntl module, with ioctl stood in for
        def __getattr__(self, name: str) -> Any:
            return ioctl if name == "ioctl" else getattr(real_fcntl, name)

    monkeypatch.setattr(serialposix, "fcntl", Fcntl())
    return flags


@pytest.mark.parametrize("driver", DRIVERS)
async def test_a_driver_without_rs485_mode_is_a_typed_error(far_pty: str, driver: str) -> None:
    with pytest.raises(DirectionControlNotSupported, match="refused direction control") as caught:
        async with open_bus(far_pty, direction="rts", driver=driver):
            pass
    assert isinstance(caught.value, SerialPortError)
    # The port was released: it opens normally at once.
    async with open_bus(far_pty, driver=driver, retries=2, **NO_TIMEOUTS) as bus:
        assert await bus.servo(1).read_stretch() == 30


@pytest.mark.parametrize("driver", DRIVERS)
@pytest.mark.parametrize(
    ("direction", "expected"),
    [("rts", ENABLED | RTS_ON_SEND), ("rts-inverted", ENABLED | RTS_AFTER_SEND)],
)
async def test_the_setting_reaches_the_driver(
    far_pty: str, rs485_driver: list[int], driver: str, direction: str, expected: int
) -> None:
    async with open_bus(far_pty, direction=direction, driver=driver, retries=2, **NO_TIMEOUTS) as bus:
        assert await bus.servo(2).read_stretch() == 30
    assert rs485_driver and rs485_driver[-1] & 0b111 == expected


async def test_no_direction_leaves_rts_alone(far_pty: str, rs485_driver: list[int]) -> None:
    async with open_bus(far_pty, retries=2, **NO_TIMEOUTS) as bus:
        assert await bus.servo(1).read_stretch() == 30
    assert rs485_driver == []


@pytest.mark.parametrize(
    ("port", "direction"),
    [("sim://?ids=1", "rts"), ("socket://127.0.0.1:1", "rts"), ("/dev/ttyUSB0", "cts"), ("/dev/ttyUSB0", "")],
)
def test_bad_direction_is_refused_before_opening(port: str, direction: str) -> None:
    with pytest.raises(InvalidArgument):
        open_bus(port, direction=direction)


def test_cli_direction_on_a_port_without_rs485_mode_exits_3(far_pty: str, cli: Any) -> None:
    result = cli("--port", far_pty, "--direction", "rts", "get", "1", "stretch")
    assert result.code == 3
    assert "refused direction control" in result.err
    assert "drop --direction" in result.err


def test_cli_direction_after_the_command_reaches_the_driver(far_pty: str, rs485_driver: list[int], cli: Any) -> None:
    # The reply is expected (a pty served by another process answers late on a loaded machine).
    result = cli("--port", far_pty, *NO_TIMEOUTS_OPTION, "get", "1", "stretch", "--direction", "rts-inverted")
    assert result.code == 0, result.err
    assert rs485_driver[-1] & 0b111 == ENABLED | RTS_AFTER_SEND


def test_cli_direction_on_the_simulator_is_a_usage_error(cli: Any) -> None:
    result = cli("--port", "sim://?ids=1", "--direction", "rts", "get", "1", "stretch")
    assert result.code == 2
    assert "direction" in result.err
