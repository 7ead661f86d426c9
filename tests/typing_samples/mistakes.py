"""A user's program with mistakes a type checker must catch (tests/test_typing.py runs mypy on it)."""

from ics35_async import BusGroup, BusOptions, ReplyTimeout, blocking, open_bus, protocol
from ics35_async.engine import TimingOverrides


async def main() -> None:
    fast: TimingOverrides = {"adapter_latency": 0.002, "quiet_time": 0.002}
    async with open_bus("sim://?ids=1", **fast) as bus:
        bus.stream([1], free_on_clsoe=True)  # MISTAKE: misspelt option
        bus.stream([1], on_close="limp")  # MISTAKE: not a close state
        bus.stream([1], on_close="free", on_resume="wait")
        try:
            await bus.servo(1).read_stretch()
        except TimeoutError as exc:
            assert isinstance(exc, ReplyTimeout)
        pending = bus.submit(protocol.ReadParam(1, protocol.Param.STRETCH))
        if not pending.done():
            pending.cancel()  # (a future's own methods, on every driver)
        stretch: int = await pending
        label: str = await pending  # MISTAKE: a stretch is an int
        print(stretch, label, pending.exception())
    open_bus("sim://", adapter_latncy=0.1)  # MISTAKE: misspelt timing
    slow: TimingOverrides = {"adapter_latency": "20 ms"}  # MISTAKE: not seconds
    print(slow)
    open_bus("sim://", reconect=True)  # MISTAKE: misspelt option
    open_bus("sim://", baudrate="115200")  # MISTAKE: not a number
    line: BusOptions = {"baudrate": 1250000, "echo": "yes"}  # MISTAKE: not a bool
    open_bus("sim://", **line)
    BusGroup.open({"legs": "sim://"}, retries=1, adapter_latency=0.002)
    BusGroup.open({"legs": "sim://"}, retry=1)  # MISTAKE: misspelt option
    blocking.open_bus("sim://", max_requests_between=8, quiet_time=0.002)
    blocking.open_bus("sim://", drivr="thread")  # MISTAKE: misspelt option
    async with open_bus("sim://?ids=1") as bus:
        with bus.stream([1]):  # MISTAKE: a stream runs in `async with`
            pass
    async with blocking.open_bus("sim://"):  # MISTAKE: a blocking bus is used with `with`
        pass
