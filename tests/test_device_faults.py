"""An in-process device that misbehaves: its ``write`` raises.

Whatever a device does, every request ends once with a typed error and the
program never hangs: the driver takes the raising device for a lost port
(the bus reconnects if asked to, exactly as after an unplug).  Run on every
driver and async library.
"""

from __future__ import annotations

from typing import Any

import anyio
import pytest

from ics35_async import IcsError, PortLost, open_bus, protocol
from ics35_async.protocol import decode_request
from tests.support.fuzzing import valid_value

FAST = {"adapter_latency": 0.05, "quiet_time": 0.002}
CASES = [("asyncio", "asyncio"), ("thread", "asyncio"), ("anyio", "asyncio"), ("anyio", "trio")]


class BrokenDevice:
    """Answers like a healthy servo until ``broken`` is set; then its ``write`` raises."""

    def __init__(self) -> None:
        self.host: Any = None
        self.broken: Exception | None = None
        self.writes = 0

    def connect(self, host: Any, baudrate: int) -> None:
        self.host, self.baudrate = host, baudrate

    def disconnect(self) -> None:
        self.host = None

    def write(self, data: bytes) -> None:
        self.writes += 1
        if self.broken is not None:
            raise self.broken
        framed = decode_request(data, baudrate=self.baudrate)
        assert framed is not None and framed[0] is not None
        command = framed[0]
        self.host.deliver(data + command.encode_reply(valid_value(command, b"\x05")))


@pytest.mark.parametrize(("driver", "library"), CASES, ids=[f"{d}-{lib}" for d, lib in CASES])
@pytest.mark.parametrize("error", [IndexError("pop from an empty deque"), OSError(5, "I/O error")], ids=repr)
def test_a_device_whose_write_raises_ends_every_request_typed(driver: str, library: str, error: Exception) -> None:
    device = BrokenDevice()

    async def main() -> None:
        with anyio.fail_after(10):  # a hang is the failure this test is about
            async with open_bus(device, driver=driver, **FAST) as bus:
                assert await bus.servo(3).read_stretch() == 5
                device.broken = error
                outcomes: list[BaseException | Any] = []

                async def one(sid: int) -> None:
                    try:
                        outcomes.append(await bus.servo(sid).read_stretch())
                    except Exception as exc:  # what the caller sees, typed or not
                        outcomes.append(exc)

                async with anyio.create_task_group() as tg:
                    for sid in range(4):
                        tg.start_soon(one, sid)
                assert len(outcomes) == 4
                assert all(isinstance(o, IcsError) for o in outcomes), outcomes
                lost = [o for o in outcomes if isinstance(o, PortLost)]
                assert lost, outcomes
                assert str(error.args[-1]) in str(lost[0])
                with pytest.raises(IcsError):
                    await bus.request(protocol.ReadParam(1, protocol.Param.STRETCH))

    anyio.run(main, backend=library)
