"""The burst path: a stream's transactions run by the compiled executor, then fed to the engine.

The engine makes the plan (:meth:`LineEngine.plan_burst <ics35_async.engine.LineEngine.plan_burst>`):
the stream's transaction just put on the wire and its next ones, as far as the sharing rule lets
the stream keep the line.  The executor (:mod:`ics35_async._burst`, C, in a thread of its own and
without the GIL) writes each command and reads its echo and reply, and stops at the first one that
is late, short, not echoed as sent or answered out of the shape the source gave for its reply (the
source would refuse that reply, and the burst's later commands must not go out after it), or at a
boundary once woken.  :func:`feed` then hands every byte to the engine with the time it came, so
the engine judges each transaction as if the bytes had come one by one: no rule lives in the
executor.

What arrives from the program during a burst waits for the boundary where the burst stops: a
request (the burst is woken when the sharing rule would give it the line at the next boundary),
a new target, a detached stream (each wakes it).  They reach the engine before the last
transaction's bytes, so the engine decides at that boundary exactly as it would have without the
burst.  Feeding takes time (several microseconds a transaction in CPython), and a request's command
goes out only after the burst's bytes so far are fed: while the program sends requests (one in the last
:data:`PAUSE_AFTER_REQUEST` seconds), no burst starts, so telemetry beside a stream waits as it does
without bursts.

Where the executor cannot run -- not built (no C compiler at install time), Windows, a port
without a file descriptor -- or unless ``ICS35_BURST=1`` is set, every transaction takes the
ordinary path.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Callable
from typing import Any

from ..engine import LineEngine, Request
from ..engine.machine import PlannedTransaction

try:
    from .. import _burst
except ImportError as exc:  # not built (no compiler at install time) or not for this platform
    _burst = None  # type: ignore[assignment]
    _IMPORT_ERROR: str = str(exc)
else:
    _IMPORT_ERROR = ""

# What the executor hands back: why it stopped, an errno, and per transaction written its raw bytes
# and when the first and the last of them came.
DONE, WOKEN, LATE, MISMATCH, MARK, OVERRUN, HANGUP, FAILED, SHAPE = range(9)
Record = tuple[bytes, float, float]
Result = tuple[int, int, list[Record]]
log = logging.getLogger("ics35_async")
MIN_PLAN = 2  # a plan of one transaction gains nothing from a thread hand-off
PAUSE_AFTER_REQUEST = 1.0
"""Seconds after the program's last request during which the stream takes the ordinary path.  A request
that arrives during a burst goes out only once the burst's bytes so far are fed to the engine (several
microseconds a transaction in CPython, plus a hand-off between threads), so telemetry beside a stream would
wait longer with bursts than without; with no burst to feed, it waits exactly as on the ordinary path.
Read as a port's burst path opens (the burst path's tests and soaks set it to 0 to put requests
arriving mid-burst through it)."""
ENV = "ICS35_BURST"


PATH_NAME = "compiled stream path"
"""What ``--version -v`` and doctor call the burst path: a reader needs to know it is optional, not how it works."""


def burst_path() -> tuple[bool, str]:
    """Whether the burst path runs on ports with a descriptor, and why, in plain words (for ``--version -v`` and
    doctor, after :data:`PATH_NAME`).

    Opt-in (``ICS35_BURST=1``): it has not yet met its CPU and rate goals (the chaos, cancellation
    and unplug soaks run on it over a pty, and pass).
    """
    if os.environ.get(ENV, "").strip().lower() not in ("1", "on", "yes", "true"):
        return False, f"off (optional; {ENV}=1 turns it on)"
    if _burst is None:
        return False, f"off, not built ({_IMPORT_ERROR}): streams run without it"
    return True, "on (streams on serial ports under the asyncio driver run in the compiled helper ics35_async._burst)"


class BurstDiverged(RuntimeError):
    """The engine asked for a different transaction than the burst ran (a bug: never expected)."""


def feed(
    engine: LineEngine,
    plan: list[PlannedTransaction],
    result: Result,
    decode: Callable[[bytes], tuple[bytes, int]] | None,
    before_last: Callable[[], None],
    now: float,
) -> bytes | None:
    """Hand a burst's bytes to ``engine`` with their times; return what the engine wants written next.

    Every transaction but the last ended at a boundary the engine had planned: fed its bytes with
    the time they came, the engine must start the next planned one, which the executor did write
    then.  Before the last one's bytes, the engine's source may change its plan again and
    ``before_last`` runs what waited for the burst to stop.  The last one's bytes are fed at
    ``now``, as the ordinary path feeds bytes when it reads them: what the engine starts then is
    written now, and its deadline must count from now (the loop may have been slow to come back).
    ``decode`` undoes the port's parity marks (see ``transports.tty_port.ParityMarks``).
    """
    _status, _errno, records = result
    last = len(records) - 1
    out = None
    in_step = True
    for i, (data, _first, at) in enumerate(records):
        if i == last:
            engine.burst_over()
            before_last()
        if decode is not None and data:
            data, errors = decode(data)
            if errors:
                engine.line_error(errors)
        # What the engine wants written after these bytes: only the last transaction's answer is
        # for the driver (the executor wrote the others'); one stopped with nothing read has none.
        out = engine.receive(data, at if i < last else max(at, now)) if data else None
        if in_step and i < last and out != plan[i + 1][0]:
            if out is not None:
                raise BurstDiverged(
                    f"burst transaction {i + 1}: the engine wants {out!r}, the burst sent {plan[i + 1][0]!r}"
                )
            # The engine failed a transaction whose reply had its echo, length and shape right, so
            # the executor ran on: not expected (a source's shape says what it refuses), but the
            # burst's later commands are on the line already.  Their bytes reach the engine as what
            # they are to it now, bytes of no transaction: strays that keep its resync waiting for
            # quiet.  None is taken for a reply; the commands go uncounted and are sent again.
            log.warning("burst ran %d transaction(s) past a reply the engine refused", last - i)
            in_step = False
    return out


class BurstRunner:
    """The burst path of one open port: plans, the executor, what waits for a burst to stop.

    Driver-neutral: a driver asks :meth:`start` after the engine put a transaction on the wire
    (instead of writing it), waits for ``done_fd`` to turn readable, then calls :meth:`finish`.
    """

    def __init__(
        self,
        engine: LineEngine,
        executor: Any,
        decode: Callable[[bytes], tuple[bytes, int]] | None,
        pending: Callable[[], bool] = lambda: False,
    ) -> None:
        self.engine = engine
        self.executor = executor  # an ics35_async._burst.Burst (tests: the same contract on a simulated wire)
        self.decode = decode
        self._pending = pending  # the port holds half a parity mark: the ordinary read must finish it
        self.plan: list[PlannedTransaction] | None = None
        self.held: list[Callable[[float], object]] = []
        self.status = DONE
        self.errno = 0
        self.bursts = 0
        self.transactions = 0
        self.pause_after_request = PAUSE_AFTER_REQUEST  # no burst for this long after a request
        self.requested_at = -math.inf  # when the program last sent a request on this line

    @property
    def done_fd(self) -> int:
        fd: int = self.executor.done_fd
        return fd

    @property
    def running(self) -> bool:
        return self.plan is not None

    def start(self, now: float) -> bool:
        """Run a burst from the transaction the engine just put on the wire (the executor writes it);
        False: write it the ordinary way (also shortly after a request: see :data:`PAUSE_AFTER_REQUEST`)."""
        if self._pending() or now - self.requested_at < self.pause_after_request:
            return False
        planned = self.engine.plan_burst()
        if planned is None:
            return False
        deadline, plan = planned
        if len(plan) < MIN_PLAN:
            self.engine.burst_over()
            return False
        self.executor.start(deadline, plan)
        self.plan = plan
        self.bursts += 1
        return True

    def hold(self, step: Callable[[float], object], *, wake: bool = True) -> None:
        """Run ``step(now)`` on the engine where the burst stops; ``wake``: stop it at its next boundary."""
        self.held.append(step)
        if wake:
            self.executor.wake()

    def submit(self, request: Request, now: float) -> bool:
        """A request from the program.  During a burst it joins the queue where the burst stops (the
        next boundary if the sharing rule gives it the line there): True.  Otherwise False: the driver
        hands it to the engine.  Either way, no burst starts for a while (see :data:`PAUSE_AFTER_REQUEST`)."""
        self.requested_at = now
        if self.plan is None:
            return False
        engine = self.engine
        self.hold(lambda t: engine.submit(request, t), wake=engine.would_take(request, now))
        return True

    def wake(self) -> None:
        self.executor.wake()

    def finish(self, now: Callable[[], float], *, wait: bool = False) -> tuple[bool, bytes | None]:
        """After ``done_fd`` turned readable: (False, None) if the burst still runs; else feed it to the
        engine and return (True, what to write next).  ``status``/``errno`` say why it stopped.

        ``wait``: stop it at its next boundary and block until it has (at most one transaction).
        """
        if wait:
            self.executor.wake()
            result: Result | None = self.executor.wait()
        else:
            result = self.executor.result()
        if result is None:
            return False, None
        plan, self.plan = self.plan, None
        assert plan is not None
        self.status, self.errno = result[0], result[1]
        self.transactions += len(result[2])

        t = now()

        def run_held() -> None:
            held, self.held = self.held, []
            for step in held:
                step(t)

        return True, feed(self.engine, plan, result, self.decode, run_held, t)

    def close(self) -> None:
        """Stop the executor's thread (waiting for a running burst to end: at most one transaction)."""
        if self.plan is not None:
            self.executor.wake()
            self.executor.wait()
            self.plan = None
        self.executor.close()


def open_runner(
    engine: LineEngine, fd: int, decode: Callable[[bytes], tuple[bytes, int]] | None, pending: Callable[[], bool]
) -> BurstRunner | None:
    """The burst path for a port with descriptor ``fd`` (``decode``: it marks parity errors), or None
    where it cannot run (see :func:`burst_path`)."""
    if not burst_path()[0] or _burst is None:
        return None
    return BurstRunner(engine, _burst.Burst(fd, marks=decode is not None), decode, pending)
