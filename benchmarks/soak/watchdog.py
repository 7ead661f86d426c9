"""A watchdog for the soaks: a run that stops making progress fails with evidence, never stalls silently.

Every soak (in ``make soak`` and in the short versions ``make test`` runs)
runs inside a :class:`Watchdog`.  A thread of its own reads the soak's
progress (work finished, plus every watched bus's transactions) once a
second.  If it has not moved for ``patience`` seconds, the watchdog writes
a dump -- each watched bus's :meth:`~ics35_async.Bus.describe` (the state,
the next deadline, the transaction on the wire, every queued request), the
stacks of all threads and of the event loop's tasks -- and fails the run:

1. it raises :class:`Stalled` (an ``AssertionError``, so a test fails with the
   dump as its message) in the main thread through a signal, which also wakes
   an event loop waiting in ``select`` with no timer armed;
2. if the run still has not ended ``patience`` seconds later (the main thread
   is stuck where no signal reaches), it prints the dump to stderr and ends
   the process with exit code 70.

Progress is read from another thread without locks: plain counters, read
for a dump, never written.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import io
import json
import os
import signal
import sys
import threading
import time
import traceback
from collections.abc import Awaitable, Callable, Coroutine
from types import FrameType, TracebackType
from typing import Any, ParamSpec, TypeVar

from ics35_async import Bus

STALL_EXIT = 70  # the process's exit code when the stalled run could not be interrupted
# Seconds without progress before a soak fails: far beyond any pause a soak makes on purpose (an
# unplugged device returns within 2.4 s), and below pytest-timeout's limit, so the dump is seen.
PATIENCE = float(os.environ.get("ICS35_SOAK_PATIENCE", "60"))
_ACTIVE: list[Watchdog] = []  # the watchdogs running now, innermost last (soaks run one at a time)
_SIGNAL = getattr(signal, "SIGUSR1", None)  # Windows has none: only the second stage works there


class Stalled(AssertionError):
    """A soak made no progress for longer than its watchdog's patience; the message is the dump."""


class Watchdog:
    """Fails the run inside ``with`` if ``progress()`` and the watched buses' transactions stand still
    for ``patience`` seconds.  See the module docstring."""

    def __init__(
        self,
        name: str,
        patience: float = PATIENCE,
        progress: Callable[[], object] | None = None,
        loop: asyncio.AbstractEventLoop | None = None,
    ) -> None:
        self.name = name
        self.patience = patience
        self._progress = progress
        self.buses: list[Bus] = []
        self.report = ""  # the dump, once the watchdog fired
        self._loop = loop  # whose tasks a dump lists (default: the loop running at ``with``)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._main = threading.main_thread().ident
        self._previous: Any = None

    def watch(self, bus: Bus) -> Bus:
        """Count ``bus``'s transactions as progress and describe it in a dump; returns ``bus``."""
        self.buses.append(bus)
        return bus

    def reading(self) -> tuple[object, int]:
        """What counts as progress now: the soak's own figure, and the watched buses' transactions."""
        own = self._progress() if self._progress is not None else None
        return own, sum(bus.stats.total.transactions for bus in list(self.buses))

    # ------------------------------------------------------------------ running

    def __enter__(self) -> Watchdog:
        if self._loop is None:
            with contextlib.suppress(RuntimeError):
                self._loop = asyncio.get_running_loop()
        if _SIGNAL is not None and threading.current_thread() is threading.main_thread():
            self._previous = signal.signal(_SIGNAL, self._raise_stalled)
        self._thread = threading.Thread(target=self._watch, name=f"watchdog {self.name}", daemon=True)
        self._thread.start()
        _ACTIVE.append(self)
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        _ACTIVE.remove(self)
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        if self._previous is not None:
            signal.signal(_SIGNAL, self._previous)  # type: ignore[arg-type]
        if self.report and not isinstance(exc, Stalled):
            # Fired, but the run ended another way (an error the interruption caused): say why.
            raise Stalled(self.report) from exc

    def _raise_stalled(self, signum: int, frame: FrameType | None) -> None:
        raise Stalled(self.report)

    def _watch(self) -> None:
        last = self.reading()
        since = time.monotonic()
        step = min(1.0, self.patience / 10)
        while not self._stop.wait(step):
            try:
                now_reading = self.reading()
            except Exception:  # a counter read mid-change: look again next time
                continue
            if now_reading != last:
                last, since = now_reading, time.monotonic()
                continue
            if time.monotonic() - since < self.patience:
                continue
            self.report = self.dump(f"no progress for {self.patience:g} s (progress stuck at {last})")
            if self._previous is not None and self._main is not None:
                signal.pthread_kill(self._main, _SIGNAL)  # type: ignore[arg-type]
            if self._stop.wait(self.patience):
                return
            sys.stderr.write(f"{self.report}\nwatchdog: the run could not be interrupted; exiting\n")
            sys.stderr.flush()
            os._exit(STALL_EXIT)

    # ------------------------------------------------------------------ the dump

    def dump(self, why: str) -> str:
        """The evidence: what each watched bus is doing, every thread's stack, the loop's tasks."""
        out = io.StringIO()
        out.write(f"watchdog {self.name}: {why}\n")
        for k, bus in enumerate(list(self.buses)):
            try:
                described = bus.describe()
                if described.get("state") == "idle" and not described.get("queued"):
                    continue  # nothing pending on this line
                out.write(f"bus {k}: {json.dumps(described, default=str)}\n")
            except Exception as exc:
                out.write(f"bus {k}: could not be described: {exc!r}\n")
        frames = sys._current_frames()
        for thread in threading.enumerate():
            frame = frames.get(thread.ident or -1)
            if frame is None or thread is threading.current_thread():
                continue
            out.write(f"thread {thread.name}:\n{''.join(traceback.format_stack(frame))}")
        if self._loop is not None:
            tasks: list[asyncio.Task[Any]] = []
            with contextlib.suppress(RuntimeError):  # the loop's task set changed while read
                tasks = list(asyncio.all_tasks(self._loop))
            for task in tasks[:50]:
                stack = task.get_stack(limit=8)
                where = "".join(traceback.format_list(traceback.extract_stack(stack[-1]))) if stack else "(no frame)\n"
                out.write(f"task {task.get_name()}:\n{where}")
        return out.getvalue()


def watched(bus: Bus) -> Bus:
    """Watch ``bus`` with the running watchdog (if any); returns ``bus``.  For soaks that open buses."""
    if _ACTIVE:
        _ACTIVE[-1].watch(bus)
    return bus


A = ParamSpec("A")
R = TypeVar("R")


def under_watchdog(name: str) -> Callable[[Callable[A, Awaitable[R]]], Callable[A, Coroutine[Any, Any, R]]]:
    """Run an async soak inside a :class:`Watchdog` named ``name`` (unless one already runs: a
    soak made of others is watched once, as a whole).  Buses it opens join through :func:`watched`."""

    def decorate(soak: Callable[A, Awaitable[R]]) -> Callable[A, Coroutine[Any, Any, R]]:
        @functools.wraps(soak)
        async def run(*args: A.args, **kwargs: A.kwargs) -> R:
            if _ACTIVE:
                return await soak(*args, **kwargs)
            with Watchdog(name):
                return await soak(*args, **kwargs)

        return run

    return decorate
