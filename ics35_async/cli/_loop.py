"""The event loop a command runs on: uvloop when it is installed, else asyncio's (``ICS35_LOOP`` chooses)."""

from __future__ import annotations

import asyncio
import logging
import os
from collections.abc import Awaitable, Callable
from typing import TypeVar

from ._settings import CliError, ExitCode
from ._signals import command_task, received

T = TypeVar("T")
LOOPS = ("auto", "asyncio", "uvloop")
log = logging.getLogger("ics35_async")


async def _await(main: Awaitable[T]) -> T:
    task = asyncio.current_task()
    assert task is not None
    with command_task(task):  # (SIGTERM and SIGHUP cancel it, as Ctrl-C does)
        return await main


def loop_factory() -> tuple[str, Callable[[], asyncio.AbstractEventLoop] | None]:
    """The loop ``ICS35_LOOP`` asks for (``auto``: uvloop when installed, about 20% less CPU per transaction)."""
    choice = os.environ.get("ICS35_LOOP", "").strip().lower() or "auto"
    if choice not in LOOPS:
        raise CliError(ExitCode.USAGE, f"ICS35_LOOP must be one of {', '.join(LOOPS)}, not {choice!r}")
    if choice == "asyncio":
        return "asyncio", None
    try:
        import uvloop
    except ImportError:
        if choice == "uvloop":
            missing = "ICS35_LOOP=uvloop, but uvloop is not installed"
            raise CliError(ExitCode.USAGE, missing, "pip install uvloop") from None
        return "asyncio", None
    return "uvloop", uvloop.new_event_loop


def run_loop(main: Awaitable[T]) -> T:
    """``asyncio.run`` on the loop :func:`loop_factory` names."""
    try:
        name, factory = loop_factory()
    except CliError:
        if asyncio.iscoroutine(main):
            main.close()  # never awaited: no "coroutine was never awaited" warning
        raise
    log.info("event loop: %s", name)
    with asyncio.Runner(loop_factory=factory) as runner:
        try:
            return runner.run(_await(main))
        except asyncio.CancelledError:
            if received() is None:
                raise
            raise KeyboardInterrupt from None  # cancelled by a stop signal: what Ctrl-C's cancel becomes
