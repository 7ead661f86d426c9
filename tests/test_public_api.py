"""The API as users meet it: engine hooks off the public face, line options read-only, Line exported."""

from __future__ import annotations

import importlib
import inspect
import re
import warnings
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

import pytest

import ics35_async
from ics35_async import Line, Priority, ReplyTimeout, Stream, open_bus
from ics35_async.bus import Bus
from ics35_async.sim import VirtualLine, VirtualServo
from ics35_async.stats import BusStats


async def test_line_options_are_read_only_after_opening() -> None:
    async with open_bus("sim://?ids=1", echo=True, max_requests_between=4) as bus:
        for name, value in [("echo", False), ("max_requests_between", 1), ("settings", None), ("port", "x")]:
            with pytest.raises(AttributeError):
                setattr(bus, name, value)
        assert bus.echo is True and bus.max_requests_between == 4
        assert bus.port == "sim://?ids=1"
        bus.retries = 2  # read per request: changing it works, so it stays writable
        assert await bus.servo(1).read_speed() > 0


async def test_line_is_exported_and_a_bus_is_one() -> None:
    assert "Line" in ics35_async.__all__
    async with open_bus("sim://?ids=1") as bus:
        assert isinstance(bus, Line)


class ThirdPartyLine:
    """A line of another package's making: what the ``Line`` protocol asked of one before the close's hooks
    (``close_out_begins``/``close_out_ends``) were added; here it hands each call to a bus."""

    def __init__(self, bus: Bus) -> None:
        self._bus = bus
        self.baudrate, self.echo = bus.baudrate, bus.echo

    @property
    def is_open(self) -> bool:
        return self._bus.is_open

    @property
    def stats(self) -> BusStats:
        return self._bus.stats

    async def request(self, command: Any, *, priority: Priority = Priority.NORMAL, retries: int | None = None) -> Any:
        return await self._bus.request(command, priority=priority, retries=retries)

    def submit(self, command: Any, *, priority: Priority = Priority.NORMAL, retries: int | None = None) -> Any:
        return self._bus.submit(command, priority=priority, retries=retries)

    async def reopen(self, *, baudrate: int | None = None) -> None:
        await self._bus.reopen(baudrate=baudrate)

    def attach_source(self, source: Any, *, close_out: Callable[[], Awaitable[None]] | None = None) -> None:
        self._bus.attach_source(source, close_out=close_out)

    def detach_source(self, source: Any) -> None:
        self._bus.detach_source(source)

    def kick(self) -> None:
        self._bus.kick()

    def notify(self, callback: Callable[[], None]) -> None:
        self._bus.notify(callback)


async def test_a_line_without_the_close_out_hooks_is_a_line_and_its_streams_close_out() -> None:
    # The close's hooks were added to the protocol as required methods: a line made elsewhere was no Line any more
    # (isinstance), and its stream's close raised AttributeError before it freed its servos.
    sim = VirtualLine([VirtualServo(1), VirtualServo(2)])
    async with open_bus(sim) as bus:
        line = ThirdPartyLine(bus)
        assert isinstance(line, Line)
        async with Stream(line, [1, 2], on_close="free") as stream:
            stream.set_targets({1: 7000, 2: 8000})
            while (await stream.next_frame()).positions.get(1) != 7000:
                pass
        assert stream.targets_sent_on_close == {1: 0, 2: 0}
        assert sim.servo(1).free and sim.servo(2).free


@pytest.mark.parametrize("package", ["ics35_async", "ics35_async.transports", "ics35_async.sim"])
def test_names_a_package_imports_when_asked_for_resolve_and_others_are_attribute_errors(package: str) -> None:
    """A package's lazy names (its ``__getattr__``) give the object they name, and an unknown name is an
    AttributeError (so ``hasattr`` and star imports work), asked directly: an earlier import may have
    cached a name already."""
    module = importlib.import_module(package)
    lazy = getattr(module, "_LAZY", {"PtyServer": ".pty_server", "main": ".server_cli"})
    for name, where in lazy.items():
        assert module.__getattr__(name) is getattr(importlib.import_module(where, package), name)
    with pytest.raises(AttributeError, match="no_such_name"):
        module.__getattr__("no_such_name")
    assert not hasattr(module, "no_such_name")


async def test_stream_engine_hooks_are_private_and_the_old_names_warn() -> None:
    async with open_bus("sim://?ids=1-2") as bus, bus.stream([1, 2]) as stream:
        frame = await stream.next_frame()
        assert sorted(frame.positions) == [1, 2]
        public = {name for name in dir(type(stream)) if not name.startswith("_")}
        for hook in ("next_transaction", "complete", "fail", "line_closed", "wake_at"):
            assert hook in public  # kept one release for old callers...
            with pytest.warns(DeprecationWarning, match=f"Stream.{hook}"):
                getattr(stream, hook)  # ...each with a warning
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # the stream itself never goes through the deprecated names
            await stream.next_frame()


def test_bus_options_are_declared_once_and_every_opener_takes_them() -> None:
    """open_bus, Bus, blocking.open_bus, BusGroup.open and open_robot take the one BusOptions."""
    from ics35_async import BusGroup, BusOptions, blocking
    from ics35_async.bus import Bus
    from ics35_async.robot import RobotOptions, open_robot

    for opener in (open_bus, Bus, blocking.open_bus, BusGroup.open):
        (options,) = [p for p in inspect.signature(opener).parameters.values() if p.kind is p.VAR_KEYWORD]
        assert options.annotation == "Unpack[BusOptions]", opener
    robot_options = inspect.signature(open_robot).parameters["options"].annotation
    assert robot_options == "Unpack[RobotOptions]"
    assert BusOptions.__optional_keys__ < RobotOptions.__optional_keys__
    assert {"baudrate", "reconnect", "adapter_latency", "quiet_time"} <= BusOptions.__optional_keys__


def test_stream_options_come_from_the_package_as_bus_options_do() -> None:
    """A program annotating its stream options imports them where it imports BusOptions."""
    from ics35_async import StreamOptions
    from ics35_async.bus import Bus

    assert "StreamOptions" in ics35_async.__all__
    (options,) = [p for p in inspect.signature(Bus.stream).parameters.values() if p.kind is p.VAR_KEYWORD]
    assert options.annotation == "Unpack[StreamOptions]"
    assert {"on_close", "offline", "watch"} <= StreamOptions.__optional_keys__


async def test_bus_takes_timing_fields_as_open_bus_does_and_refuses_unknown_options() -> None:
    from ics35_async.bus import Bus

    bus = Bus("sim://?ids=1", adapter_latency=0.004, retries=2)
    assert bus.timing.adapter_latency == 0.004 and bus.retries == 2
    assert open_bus("sim://", quiet_time=0.002).timing.quiet_time == 0.002
    for opener in (Bus, open_bus):
        with pytest.raises(ics35_async.InvalidArgument, match=r"unknown open_bus option.*baudrat"):
            opener("sim://", baudrat=115200)  # type: ignore[call-arg]


async def test_open_robot_passes_bus_options_to_every_line_and_refuses_unknown_ones() -> None:
    from ics35_async.robot import open_robot

    description = {
        "lines": {"a": {"port": "sim://?ids=1"}, "b": {"port": "sim://?ids=2"}},
        "joints": {"x": {"line": "a", "id": 1}, "y": {"line": "b", "id": 2}},
    }
    async with open_robot(description, check_limits=False, adapter_latency=0.007, on_close="hold") as robot:
        assert [bus.timing.adapter_latency for bus in robot.group.buses.values()] == [0.007, 0.007]
    with pytest.raises(ics35_async.InvalidArgument, match=r"unknown open_robot option.*colour"):
        async with open_robot(description, colour="red"):  # type: ignore[call-arg]
            pass
    with pytest.raises(ics35_async.InvalidArgument, match="baudrate: set per line"):
        async with open_robot(description, baudrate=115200):
            pass


def test_the_simulated_line_options_are_declared_once() -> None:
    from ics35_async.sim import LineModel, LineModelOptions, VirtualLine

    for cls in (LineModel, VirtualLine):
        (options,) = [p for p in inspect.signature(cls).parameters.values() if p.kind is p.VAR_KEYWORD]
        assert options.annotation == "Unpack[LineModelOptions]", cls
    line = VirtualLine([1], turnaround=0.0002, tail_bytes=2, log_size=0, name=None)
    assert (line.turnaround, line.tail_bytes, line.echo, line.baudrate) == (0.0002, 2, True, 115200)
    assert {"faults", "seed", "realtime", "adapter", "ics36"} <= LineModelOptions.__optional_keys__
    with pytest.raises(ics35_async.InvalidArgument, match=r"unknown simulated line option.*turnarond"):
        VirtualLine([1], turnarond=0.1)  # type: ignore[call-arg]


def test_the_api_reference_names_each_of_its_names_not_importable_from_the_package() -> None:
    """The bus, servos and streams page says its names import from ``ics35_async`` itself but for those its
    opening names: every other one documented there does."""
    page = (Path(__file__).resolve().parents[1] / "docs" / "reference" / "api.md").read_text(encoding="utf-8")
    opening = page.split("\n\n")[1]  # (after the title)
    documented = re.findall(r"^::: (ics35_async\.[\w.]+)$", page, flags=re.M)
    elsewhere = [
        path
        for path in documented
        if not path.startswith("ics35_async.stats")
        and not hasattr(ics35_async, name := path.rpartition(".")[2])
        and f"`{name}`" not in opening
    ]
    assert documented and elsewhere == []


async def test_a_reply_error_says_what_went_wrong_apart_from_where_and_the_bytes() -> None:
    # A reply error's message is "<command> to ID <n>: <what> (raw: <bytes>)"; a program (the backup file's words, the
    # configurator's) that wants only the what took it apart by its punctuation, which a what holding ": " broke.
    async with open_bus("sim://?ids=3&faults=drop:1.0") as bus:
        with pytest.raises(ReplyTimeout) as caught:
            await bus.servo(3).read_temperature()
    error = caught.value
    assert error.reason and error.reason in str(error)
    assert "ID 3" not in error.reason and "raw" not in error.reason
    assert str(error) == f"{error.command} to ID 3: {error.reason} (raw: {error.raw.hex(' ') or 'nothing'})"
