"""The API as users meet it: engine hooks off the public face, line options read-only, Line exported."""

from __future__ import annotations

import warnings

import pytest

import ics35_async
from ics35_async import Line, open_bus


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
