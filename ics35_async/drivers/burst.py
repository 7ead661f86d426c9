"""The burst path: a stream's transactions run by the compiled executor, then fed to the engine.

The engine makes the plan (:meth:`LineEngine.plan_burst <ics35_async.engine.LineEngine.plan_burst>`):
the stream's transaction just put on the wire and its next ones, as far as the sharing rule lets
the stream keep the line.  The executor (:mod:`ics35_async.drivers._burst`, C, in a thread of its own and
without the GIL) writes each command and reads its echo and reply, and stops at the first one that
is late, short, not echoed as sent or answered out of the shape the source gave for its reply (the
source would refuse that reply, and the burst's later commands must not go out after it), or at a
boundary once woken.  :meth:`BurstRunner.finish` hands every byte to the engine with the time it
came, so the engine judges each transaction as if the bytes had come one by one: no rule lives in
the executor.  It feeds a burst in parts while it runs (see :func:`feed_ahead_points`): each frame
as its cycle ends, and all but the last few transactions before the burst's end, so the line waits
for the loop only for those.

What arrives from the program during a burst waits for the boundary where the burst stops: a
request (the burst is woken when the sharing rule would give it the line at the next boundary),
a new target, a detached stream (each wakes it).  They reach the engine before the last
transaction's bytes, so the engine decides at that boundary exactly as it would have without the
burst.  Feeding takes time (several microseconds a transaction in CPython), and a request's command
goes out only after the burst's bytes so far are fed: while the program sends requests (one in the last
:data:`PAUSE_AFTER_REQUEST` seconds), no burst starts, so telemetry beside a stream waits as it does
without bursts.

Every driver runs it on a port with a file descriptor (the asyncio driver from its loop's callbacks,
the thread driver from its I/O thread, the anyio driver, and so trio, from its bus task).  Where the
executor cannot run -- not built (no C compiler at install time), Windows, a port without a file
descriptor -- or with ``ICS35_BURST=0`` set, every transaction takes the ordinary path; on systems
other than Linux, unless ``ICS35_BURST=1`` is set.
"""

from __future__ import annotations

import logging
import math
import os
import sys
from collections.abc import Callable
from typing import Any

from ..engine import LineEngine, Request
from ..engine.machine import PlannedTransaction

try:
    from . import _burst
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
FEED_AHEAD_MIN = 8
"""A plan of at least this many transactions is fed to the engine in parts while it runs (see
:func:`feed_ahead_points`); a shorter one at its end, unless its source has news before then."""
FEED_AHEAD_LAST = 3  # transactions of a plan left to feed at its end
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

    On Linux where the helper is built, unless ``ICS35_BURST=0``: it costs a stream less CPU than the ordinary
    path and keeps its rate beside a busy Python thread, which starves the ordinary path's loop of the GIL
    (``benchmarks/bench_burst.py``); the engine's tests compare it with the ordinary path write for write, and the
    contract suite and the chaos, cancellation and unplug soaks run on it.  Elsewhere (macOS, the BSDs: the
    helper builds there, with ``poll`` in whole milliseconds, but it is tried on Linux only) ``ICS35_BURST=1``
    turns it on.
    """
    if _burst is None:  # (first: no setting turns on what is not there, Windows included)
        return False, f"off, not built ({_IMPORT_ERROR}): streams run without it"
    linux = sys.platform.startswith("linux")
    turn_on = "unset it to turn the path on" if linux else f"{ENV}=1 turns it on"
    setting = os.environ.get(ENV, "").strip().lower()
    if setting in ("0", "off", "no", "false"):
        return False, f"off ({ENV}={os.environ[ENV].strip()}; {turn_on})"
    if setting not in ("", "1", "on", "yes", "true"):
        return False, f"off ({ENV}={os.environ[ENV].strip()!r} is neither 1 nor 0; {turn_on})"
    if not setting and not linux:
        return False, f"off by default on {sys.platform}, where it has not been tried ({ENV}=1 turns it on)"
    return True, "on (streams on serial ports run in the compiled helper ics35_async.drivers._burst)"


def line_path(bursts: bool) -> tuple[bool, str]:
    """As :func:`burst_path`, for a line that opened: ``bursts`` says whether its driver runs the burst
    path (``Bus.describe()["burst_path"]``), in plain words."""
    on, why = burst_path()
    if not on:
        return on, why
    if bursts:
        return True, "on for this line (its streams run in the compiled helper ics35_async.drivers._burst)"
    return False, (
        "off for this line: the helper runs on a serial port's descriptor "
        "(not for a URL such as sim:// or a bridge, nor with the thread transport, which driver='thread' "
        "takes under trio)"
    )


def feed_ahead_points(n: int, news: list[int]) -> list[int]:
    """Where the loop feeds a running plan of ``n`` transactions what is done so far (every transaction
    before the one being written), given the entries ``news`` after which its source has news for the
    program (a stream's frame).

    Right after each entry with news, so a frame reaches the program as soon as its cycle's last reply
    came, not when the burst ends.  In a plan of :data:`FEED_AHEAD_MIN` or more, also
    :data:`FEED_AHEAD_LAST` transactions before its end, and halfway there from the point before when
    that is far: fed all at its end, a burst would keep the line idle while CPython feeds the engine
    its bytes (several microseconds a transaction); fed ahead, only the last few wait for the loop, for a wake-up
    of the loop a point (measured: ``benchmarks/bench_burst.py``, the rows not fed ahead of the end).
    """
    points = {i + 1 for i in news if i + 1 < n}
    if n >= FEED_AHEAD_MIN:
        end = n - FEED_AHEAD_LAST
        end = min((p for p in points if p >= end), default=end)  # (news there serves)
        before = max((p for p in points if p < end), default=0)
        points.add(end)
        if end - before >= 2 * FEED_AHEAD_MIN:
            points.add((before + end) // 2)
    return sorted(points)


class BurstDiverged(RuntimeError):
    """The engine asked for a different transaction than the burst ran (a bug: never expected)."""


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
        last_request: Callable[[], float] = lambda: -math.inf,
    ) -> None:
        self.engine = engine
        self.executor = executor  # an ics35_async.drivers._burst.Burst (tests: the same contract on a simulated wire)
        self.decode = decode
        self._pending = pending  # the port holds half a parity mark: the ordinary read must finish it
        self.plan: list[PlannedTransaction] | None = None
        self.fed = 0  # transactions of the running plan fed to the engine so far
        self.in_step = True  # the engine took every transaction fed so far as the plan has it
        self._ahead: list[int] = []  # where the running plan is still to be fed ahead (feed_ahead_points)
        self._armed = -1  # the point the executor will signal next (-1: none)
        self.held: list[Callable[[float], object]] = []
        self.status = DONE
        self.errno = 0
        self.bursts = 0
        self.transactions = 0
        self.pause_after_request = PAUSE_AFTER_REQUEST  # no burst for this long after a request
        # When the program last sent a request on this line: the driver's, kept across ports (a runner
        # is new after each reopen or reconnect, the program's habit of polling is not).
        self._last_request = last_request

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
        if self._pending() or now - self._last_request() < self.pause_after_request:
            return False
        planned = self.engine.plan_burst()
        if planned is None:
            return False
        deadline, plan, news = planned
        if len(plan) < MIN_PLAN:
            self.engine.burst_over()
            return False
        self.executor.start(deadline, plan)
        self.plan = plan
        self.fed = 0
        self.in_step = True
        self._ahead = feed_ahead_points(len(plan), news)
        self._armed = -1
        self._arm_next()
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
        hands it to the engine.  (The driver notes when it came: see ``last_request``.)"""
        if self.plan is None:
            return False
        engine = self.engine
        self.hold(lambda t: engine.submit(request, t), wake=engine.would_take(request, now))
        return True

    def wake(self) -> None:
        self.executor.wake()

    def finish(self, now: Callable[[], float], *, wait: bool = False) -> tuple[bool, bytes | None]:
        """After ``done_fd`` turned readable: feed the engine what the burst has done.  While it runs, only
        the transactions already followed by another (see :func:`feed_ahead_points`): (False, None).  Once it
        stopped, the rest: (True, what to write next); ``status``/``errno`` say why it stopped.

        ``wait``: stop it at its next boundary and block until it has (at most one transaction).
        """
        executor = self.executor
        plan = self.plan
        assert plan is not None
        if wait:
            executor.wake()
            result: Result | None = executor.wait(self.fed)
        else:
            result = executor.result(self.fed)
        if result is None:
            self._feed(plan, executor.completed(self.fed), None, 0.0)
            self._arm_next()
            return False, None
        self.plan = None
        self._ahead = []
        self.status, self.errno = result[0], result[1]
        self.transactions += self.fed + len(result[2])

        t = now()

        def run_held() -> None:
            held, self.held = self.held, []
            for step in held:
                step(t)

        return True, self._feed(plan, result[2], run_held, t)

    def _arm_next(self) -> None:
        """Ask the executor for a notice at the next point to feed ahead, once the one asked for is passed
        (the transactions up to it are fed: the loop may also come for another reason)."""
        if self._armed > self.fed:
            return  # still to come
        ahead = self._ahead
        while ahead and ahead[0] <= self.fed:
            ahead.pop(0)  # passed already (the loop was slow to come)
        self._armed = ahead.pop(0) if ahead else -1
        if self._armed >= 0:
            self.executor.notify(self._armed)

    def _feed(
        self, plan: list[PlannedTransaction], records: list[Record], before_last: Callable[[], None] | None, now: float
    ) -> bytes | None:
        """Hand the engine the bytes of ``records`` (the plan's from :attr:`fed` on) with their times;
        return what the engine wants written after the last of them.

        Every transaction but the burst's last ended at a boundary the engine had planned: fed its
        bytes with the time they came, the engine must start the next planned one, which the executor
        did write then.  ``before_last`` is None while the burst runs (none of ``records`` is its last).
        Otherwise the last record is the burst's last: before its bytes the engine's source may change
        its plan again and ``before_last`` runs what waited for the burst to stop; its bytes are fed at
        ``now``, as the ordinary path feeds bytes when it reads them: what the engine starts then is
        written now, and its deadline must count from now (the loop may have been slow to come back).
        The port's parity marks are undone by ``decode`` (see ``transports.tty_port.ParityMarks``).
        """
        engine, decode = self.engine, self.decode
        last = len(records) - 1 if before_last is not None else -1
        first = self.fed
        out = None
        done = 0
        # Every record but the burst's last, in one call while the engine answers as planned (none of them
        # holds a parity mark: the executor stops at the first chunk holding an 0xFF).
        bulk = len(records) - 1 if before_last is not None else len(records)
        if self.in_step and bulk > 0:
            done, out = engine.receive_planned(records, bulk, plan, first)
            self.fed = first + done
            if out != plan[first + done][0]:
                self._ran_past(plan, first + done, out)
        for j in range(done, len(records)):  # the burst's last, and the rest once out of step (not checked)
            data, _first, at = records[j]
            if j == last:
                engine.burst_over()
                before_last()  # type: ignore[misc]
            # (bytes with no 0xFF come as they were on the wire: no mark is in them, and none was left half
            # read, as a burst starts only without one and stops at the first chunk holding an 0xFF)
            if decode is not None and 0xFF in data:
                data, errors = decode(data)
                if errors:
                    engine.line_error(errors)
            # What the engine wants written after these bytes: only the last transaction's answer is
            # for the driver (the executor wrote the others'); one stopped with nothing read has none.
            out = engine.receive(data, at if j != last else max(at, now)) if data else None
            self.fed = first + j + 1  # (fed, whatever follows: a record is never fed twice)
        return out

    def _ran_past(self, plan: list[PlannedTransaction], k: int, out: bytes | None) -> None:
        """The engine, fed the bytes before plan entry ``k``, answered ``out`` where the executor wrote entry ``k``."""
        if out is not None:
            raise BurstDiverged(f"burst transaction {k}: the engine wants {out!r}, the burst sent {plan[k][0]!r}")
        # The engine failed a transaction whose reply had its echo, length and shape right, so
        # the executor ran on: not expected (a source's shape says what it refuses), but the
        # burst's later commands are on the line already.  Their bytes reach the engine as what
        # they are to it now, bytes of no transaction: strays that keep its resync waiting for
        # quiet.  None is taken for a reply; the commands go uncounted and are sent again.
        log.warning("burst ran on past a reply the engine refused (transaction %d of %d)", k, len(plan))
        self.in_step = False

    def close(self) -> None:
        """Stop the executor's thread (waiting for a running burst to end: at most one transaction)."""
        if self.plan is not None:
            self.executor.wake()
            self.executor.wait()
            self.plan = None
        self.executor.close()


def open_runner(
    engine: LineEngine,
    fd: int,
    decode: Callable[[bytes], tuple[bytes, int]] | None,
    pending: Callable[[], bool],
    last_request: Callable[[], float],
) -> BurstRunner | None:
    """The burst path for a port with descriptor ``fd`` (``decode``: it marks parity errors), or None
    where it cannot run (see :func:`burst_path`).  ``last_request``: when the program last sent a request
    on this line (see :data:`PAUSE_AFTER_REQUEST`)."""
    if not burst_path()[0] or _burst is None:
        return None
    return BurstRunner(engine, _burst.Burst(fd, marks=decode is not None), decode, pending, last_request)
