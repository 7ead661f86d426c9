"""Concurrent work that fails the way one call does.

The library runs some of its work concurrently: a scan's probes, a robot's lines, a group's
streams.  An anyio task group wraps its tasks' errors in an exception group, but whoever called
``bus.scan()`` made one call and expects the library error it documents (``PortLost``,
``BusClosed``...), not a group of 32 of them.  :func:`task_group` raises the first library error
as itself; anything else in the group (a bug, a cancellation) is raised as the group was, so
nothing is hidden.
"""

from __future__ import annotations

import contextlib
import math
import sys
from collections.abc import AsyncIterator, Awaitable, Callable, Coroutine
from typing import TYPE_CHECKING, Any, TypeVar

from .errors import IcsError

T = TypeVar("T")

if TYPE_CHECKING:
    import asyncio

    from anyio.abc import TaskGroup


E = TypeVar("E", bound=BaseException)


def again(error: E) -> E:
    """``error``, kept to be raised at every call after something ended (a lost line, a safety stop that stands),
    without the traceback of its last raise: each raise adds its call's frames to the one traceback, so a
    program's traceback would name every earlier call, and a loop catching it at each pass grow it (and the
    frames it holds) without end.  ``raise again(self._end_error)``."""
    return error.with_traceback(None)


def only_error(exc: BaseException) -> BaseException:
    """The one exception inside (nested) exception groups of one, else ``exc`` itself."""
    while isinstance(exc, BaseExceptionGroup) and len(exc.exceptions) == 1:
        exc = exc.exceptions[0]
    return exc


def first_library_error(group: BaseExceptionGroup[BaseException]) -> BaseException:
    """The first library error in ``group`` when it holds nothing else; else ``group`` itself."""
    errors, rest = group.split(IcsError)
    if errors is None or rest is not None:
        return group
    error: BaseException = errors
    while isinstance(error, BaseExceptionGroup):
        error = error.exceptions[0]
    return error


@contextlib.asynccontextmanager
async def task_group() -> AsyncIterator[TaskGroup]:
    """An anyio task group whose failure is the first library error itself (see the module)."""
    import anyio  # not at module level: ``import ics35_async`` stays cheap

    try:
        async with anyio.create_task_group() as group:
            yield group
    except BaseExceptionGroup as exc:
        error = first_library_error(exc)
        if error is exc:
            raise
        raise error from None


async def despite_cancellation(work: Callable[[], Awaitable[None]], bound: float | None) -> None:
    """Run ``work()`` to its end (``bound`` seconds at most, if given) even when the caller is cancelled meanwhile;
    a cancellation that came is raised once it is done.  For a close-out that must reach the servos
    (freeing them) however the program is being stopped.

    An anyio shielded scope keeps out anyio's and trio's cancellation, not asyncio's ``Task.cancel()``
    (an ``asyncio.timeout`` around a task that is then cancelled, a task group cancelling its tasks,
    a server cancelling a handler): it reaches the task inside any shield.  On asyncio the work
    therefore runs in a task of its own, which the caller waits for again after each cancel.  (A
    second Ctrl-C under plain ``asyncio.run`` is another matter: it raises KeyboardInterrupt and
    asyncio cancels every task, this one too; ``ics35_async.run`` takes the second signal calmly.)
    """
    import anyio

    async def bounded() -> None:
        with anyio.move_on_after(math.inf if bound is None else bound):
            await work()

    asyncio = sys.modules.get("asyncio")
    if asyncio is None or asyncio.events._get_running_loop() is None:  # trio: its shield is enough
        with anyio.CancelScope(shield=True):
            await bounded()
        return
    task = retrieved(bounded())
    cancelled: BaseException | None = None
    with anyio.CancelScope(shield=True):  # (anyio's own cancellation would re-deliver every loop turn)
        while not task.done():
            try:
                await asyncio.shield(task)
            except asyncio.CancelledError as exc:
                cancelled = cancelled or exc
    failure = None if task.cancelled() else task.exception()  # (retrieved: asyncio would log it unread)
    if cancelled is not None:
        raise cancelled from failure
    task.result()


def retrieved(step: Coroutine[Any, Any, T]) -> asyncio.Task[T]:
    """``step`` as an asyncio task whose error is retrieved however it ends: a program forced out meanwhile (a
    third Ctrl-C) never waits for it again, and asyncio would print its error at exit ("Task exception was never
    retrieved"); what the work left is said by the program's own message."""
    import asyncio

    task = asyncio.ensure_future(step)
    task.add_done_callback(lambda t: None if t.cancelled() else t.exception())
    return task
