"""Precise waiting for the real-time simulator.

An event loop's timers (and a plain ``time.sleep``) overshoot by tens of
microseconds, more than a whole byte time at 1.25 Mbit/s (8.8 us).  So the
real-time simulator waits in two steps: a sleep that releases the GIL until
:data:`SPIN_MARGIN` before the deadline, then a busy loop on
``time.perf_counter``.  The waiting thread lowers its timer slack to 1 ns
(``prctl(PR_SET_TIMERSLACK)``, Linux) so the sleep itself wakes closer to
its target and the spin stays short.

Measured figures are in the package docstring (:mod:`ics35_async.sim`) and
are printed by ``benchmarks/sim_timing.py``.
"""

from __future__ import annotations

import contextlib
import ctypes
import heapq
import itertools
import sys
import threading
import time
from collections.abc import Callable

SPIN_MARGIN = 250e-6
"""Seconds before a deadline at which sleeping stops and spinning starts."""

_PR_SET_TIMERSLACK = 29


def lower_timer_slack(nanoseconds: int = 1) -> bool:
    """Set the calling thread's timer slack to ``nanoseconds`` (Linux only); True if it worked."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return bool(libc.prctl(_PR_SET_TIMERSLACK, nanoseconds, 0, 0, 0) == 0)
    except (OSError, AttributeError):
        return False


def wait_until(deadline: float, spin_margin: float = SPIN_MARGIN) -> None:
    """Return at ``time.perf_counter() >= deadline``: sleep, then spin the last ``spin_margin`` seconds."""
    remaining = deadline - time.perf_counter()
    if remaining > spin_margin:
        time.sleep(remaining - spin_margin)
    while time.perf_counter() < deadline:
        pass


class Deliverer:
    """A thread that calls ``sink(data)`` for each scheduled chunk at its time.

    Times are ``time.perf_counter()`` values.  Chunks are delivered in time
    order (ties in scheduling order).  :meth:`cancel` drops everything not
    yet delivered, e.g. when the port is unplugged.  While it waits the thread
    holds no lock and no GIL except during the final spin.

    A reader may also take what is due on its own thread (:meth:`deliver_due`):
    the thread is only as punctual as the interpreter lets it be, and a busy
    program holds it back, where a real device's bytes wait in the operating
    system's buffer from the moment they arrive.

    Args:
        spin_margin: seconds spun (not slept) before each chunk's time.
        name: the thread's name.
    """

    def __init__(self, spin_margin: float = SPIN_MARGIN, name: str = "ics35-sim-delivery") -> None:
        self.spin_margin = spin_margin
        self._heap: list[tuple[float, int, bool, Callable[[bytes], None], bytes]] = []
        self._order = itertools.count()
        self._cond = threading.Condition(threading.Lock())
        # Held while chunks are handed over, by the thread or a reader taking what is due: one at a time, so
        # that a chunk popped by one is not overtaken by a later one the other pops.
        self._handing = threading.Lock()
        self._closed = False
        self.lateness_max = 0.0
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def schedule(self, when: float, data: bytes, sink: Callable[[bytes], None], *, thread_only: bool = False) -> None:
        """Call ``sink(data)`` at ``when`` (a ``time.perf_counter()`` value).

        ``thread_only``: only the delivery thread calls it (an event, such as an unplug, that stops this
        deliverer: :meth:`deliver_due` stops in front of it)."""
        with self._cond:
            heapq.heappush(self._heap, (when, next(self._order), thread_only, sink, data))
            self._cond.notify()

    def deliver_due(self, now: float | None = None) -> int:
        """Hand over now, on the calling thread and in order, every chunk due by ``now`` (default: the present)
        that the thread has not delivered yet, up to the first that is ``thread_only``; return how many."""
        return self._hand_over(time.perf_counter() if now is None else now, by_thread=False)

    def cancel(self) -> None:
        """Drop every chunk not yet delivered."""
        with self._cond:
            self._heap.clear()

    def pending(self) -> int:
        """How many chunks wait to be delivered."""
        with self._cond:
            return len(self._heap)

    def close(self) -> None:
        """Drop what is pending and end the thread."""
        with self._cond:
            self._closed = True
            self._heap.clear()
            self._cond.notify()
        if self._thread is not threading.current_thread():
            self._thread.join(timeout=2)

    def _run(self) -> None:
        lower_timer_slack()
        cond = self._cond
        while True:
            with cond:
                while not self._closed and not self._heap:
                    cond.wait()
                if self._closed:
                    return
                when = self._heap[0][0]
                remaining = when - time.perf_counter()
                if remaining > self.spin_margin:
                    # Wakes early if an earlier chunk is scheduled meanwhile.
                    cond.wait(remaining - self.spin_margin)
                    continue
            while time.perf_counter() < when:
                pass
            self._hand_over(time.perf_counter(), by_thread=True)

    def _hand_over(self, now: float, *, by_thread: bool) -> int:
        count = 0
        cond, heap = self._cond, self._heap
        with self._handing:
            while True:
                with cond:
                    # (popped under the lock, as cancel and close empty the heap: what they drop is never handed over)
                    if not heap or heap[0][0] > now or (heap[0][2] and not by_thread):
                        return count
                    when, _, _, sink, data = heapq.heappop(heap)
                if by_thread:  # (the thread's own punctuality: a reader's look is as late as the reader)
                    self.lateness_max = max(self.lateness_max, time.perf_counter() - when)
                with contextlib.suppress(Exception):  # a host gone away must not kill the thread
                    sink(data)
                count += 1
