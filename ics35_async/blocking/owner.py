"""A blocking object that owns its loop thread: closing it, and closing it anyway when it is forgotten.

The blocking bus and the blocking robot each start a loop thread for their
async object.  ``close`` runs the async object's own close on that loop to
the end, then stops the thread; a program that never closes one has it
closed at garbage collection or interpreter exit, with a ResourceWarning
(the thread is a daemon so that a forgotten object cannot hang the exit:
this releases the port cleanly first).
"""

from __future__ import annotations

import threading
import warnings
import weakref
from collections.abc import Awaitable, Callable
from types import TracebackType
from typing import TYPE_CHECKING, NoReturn, Self, TypeVar

from ..running import close_step
from .forward import Wrapper
from .loop_thread import LoopThread

A = TypeVar("A")

Closer = Callable[[], Awaitable[None]]


class LoopOwner(Wrapper[A]):
    """A :class:`Wrapper` whose loop thread is its own (see the module docstring)."""

    __slots__ = ("__weakref__", "_finalizer")
    _usage = ""  # how a program uses it: said to one that wrote `async with` where `with` goes

    def _own(self, loop: LoopThread, aclose: Closer, what: str) -> None:
        """From now on, closing (or forgetting) this object runs ``aclose`` on ``loop``, then ends it."""
        self._finalizer = weakref.finalize(self, _close_forgotten, what, aclose, loop)

    @close_step
    def close(self) -> None:
        """Close, release the port, end the loop thread.

        Idempotent.  A Ctrl-C while closing is raised once everything is released.
        """
        # (A close_step: a stop signal meanwhile is raised once all is closed, the port released, the thread ended.)
        detached = self._finalizer.detach()
        if detached is not None:
            _, _, (_, aclose, loop), _ = detached
            _close(aclose, loop)

    def __enter__(self) -> Self:
        return self

    if not TYPE_CHECKING:  # (at run time only: a type checker says `async with` is wrong itself)

        async def __aenter__(self) -> NoReturn:
            # `async with` written for `with`: said so, and this object (open already) closed at once, so that
            # the port it holds is free for the async API the program reaches for next, not at garbage collection.
            self.close()
            raise TypeError(self._usage)

        async def __aexit__(self, *exc: object) -> None:
            return None

    @close_step
    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    @property
    def thread(self) -> threading.Thread:
        """The thread running this object's event loop."""
        return self._loop.thread


def _close(aclose: Closer, loop: LoopThread) -> None:
    try:
        if loop.is_running:
            loop.call_to_end(aclose)
    finally:
        loop.stop()


def _close_forgotten(what: str, aclose: Closer, loop: LoopThread) -> None:
    warnings.warn(f"{what} was never closed; closing it now", ResourceWarning, stacklevel=1)
    _close(aclose, loop)
