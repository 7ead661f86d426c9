"""What every driver shares; each driver (asyncio, thread, anyio) adds only its own way of waiting.

A driver moves bytes and time between one :class:`~ics35_async.engine.LineEngine`
and one port from :func:`~ics35_async.transports.opening.open_port`.  The
core holds the rest, once:

* :meth:`DriverCore._step`: what came from the port (or that time passed)
  fed to the engine, and :meth:`DriverCore._act`: the engine's answer acted
  on (bytes written, the input flushed first when a resync ended, and the
  engine told when they went: ``LineEngine.written``);
* :meth:`DriverCore._after`: the same for an engine call from the user's
  side, with the driver's wait re-aimed when the deadline moved earlier;
* lost-port handling, the reconnect schedule, idle waiters, the drain on
  close, and the opening of a port in a worker thread;
* :class:`CallerRequest`: one request type whose outcome reaches its caller
  through a small callback (a future's setter, a hand-over to the loop's
  thread, an event set).

A driver subclasses :class:`DriverCore` and provides ``_watch``/``_unwatch``
(start and stop waiting on a port), ``_rewait`` (end a wait that would
outlast the engine's new deadline), ``_new_request`` (a request and what its caller awaits) and,
where the engine runs on another thread than its callers, ``notify``.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import itertools
import logging
import math
import os
import sys
import threading
import weakref
from collections.abc import Awaitable, Callable, Iterator
from typing import Any, Protocol

import anyio

from ..engine import FlushInput, LineEngine, Output, Request, State
from ..errors import IcsError, InvalidArgument, PortBusy, PortLost, error_text
from ..protocol import Command
from ..tasks import despite_cancellation
from ..terminal import said_at_the_end
from ..transports.opening import Port, open_port
from ..transports.tty_port import TtyPort, port_gone
from ..transports.wire_device import WireDevice
from .burst import FAILED, PATH_NAME, BurstRunner
from .clock import now
from .settings import LineSettings

log = logging.getLogger("ics35_async")

INF = math.inf
STALL = 1.0
"""Seconds between the looks taken at a line for a wake-up an exception raised inside an event loop callback (by a
signal handler) dropped: under the anyio driver by a timer of the driver's on asyncio and by a waiting caller under
trio (see :meth:`DriverCore.check_progress`), by the supervisor under the asyncio and thread drivers (see
:meth:`LoopDriver._supervisor_task`)."""
LOST, CLOSED, DRAINING, OFFLINE = State.LOST, State.CLOSED, State.DRAINING, State.OFFLINE


class Waiter(Protocol):
    """What a caller waits on (an asyncio future, or an event's holder)."""

    def done(self) -> bool:
        """True once the caller has given up (or has its outcome)."""


class CallerRequest(Request):
    """A request whose outcome reaches its caller through ``deliver(request)``.

    The outcome is stored first (``value`` or ``error``); ``deliver`` hands
    it on once.  A request whose ``waiter`` is done (a cancelled future) is
    abandoned: the engine skips it in the queue.
    """

    __slots__ = ("deliver", "waiter")

    def __init__(
        self,
        command: Command[Any],
        priority: int,
        retries: int,
        waiter: Waiter,
        deliver: Callable[[CallerRequest], None],
    ) -> None:
        super().__init__(command, priority, retries)
        self.waiter = waiter
        self.deliver = deliver

    def abandoned(self) -> bool:
        return self.state != "queued" or self.waiter.done()

    def resolve(self, value: Any) -> None:
        if self.state == "queued":
            self.state, self.value = "done", value
            self.deliver(self)

    def reject(self, error: IcsError) -> None:
        if self.state == "queued":
            self.state, self.error = "failed", error
            self.deliver(self)


def settle_future(request: CallerRequest) -> None:
    """Hand ``request``'s outcome to its asyncio future (on the future's loop's thread)."""
    future: Any = request.waiter
    if not future.done():
        if request.error is not None:
            future.set_exception(request.error)
        else:
            future.set_result(request.value)


def running_loop() -> object | None:
    """The event loop the calling code runs on: asyncio's loop, trio's token, or ``None`` (no loop)."""
    loop = asyncio.events._get_running_loop()
    if loop is not None:
        return loop
    trio: Any = sys.modules.get("trio")  # not imported: not running
    if trio is None:
        return None
    try:
        token: object = trio.lowlevel.current_trio_token()
    except RuntimeError:
        return None
    return token


# The port openings of this process under way, by port.  An opening given up on (a timeout around
# open) runs on in its thread and may hold the port until that thread closes it: an opening of the
# same port started meanwhile, by the same bus or another, would find it busy, taken by this very
# program.  So a new opening waits for the earlier one's thread to end (see DriverCore._open).
_OPENINGS: dict[object, threading.Event] = {}
_OPENINGS_LOCK = threading.Lock()
OPENING_WAIT = 2.0
"""Seconds a new opening of a port waits for an earlier one of this process to end (given up on, its thread
may hang: an RFC 2217 handshake, a bridge); then it is refused as PortBusy, saying so."""


async def _after_earlier_opening(key: object, target: object) -> threading.Event:
    """Wait until no thread of this process is opening the port ``key``; return the new opening's event.

    Raises:
        PortBusy: an earlier opening has not ended within :data:`OPENING_WAIT`.
    """
    delay = 0.0005
    give_up = anyio.current_time() + OPENING_WAIT
    while True:
        with _OPENINGS_LOCK:
            if key not in _OPENINGS:
                ended = _OPENINGS[key] = threading.Event()
                return ended
        if anyio.current_time() >= give_up:
            raise PortBusy(
                errno.EBUSY,
                f"{target!r}: an earlier open of this port in this program has not ended after {OPENING_WAIT:g} s"
                " (given up on, it may hang: a bridge or an RFC 2217 handshake); try again later",
            )
        await anyio.sleep(delay)
        delay = min(delay * 2, 0.02)


def _opening_ended(key: object, ended: threading.Event) -> None:
    with _OPENINGS_LOCK:
        ended.set()
        if _OPENINGS.get(key) is ended:
            del _OPENINGS[key]


# The asyncio tasks of this process's lines' own (the anyio driver's bus tasks), which outlive a cancellation from
# outside for the program's other tasks (see outlive_the_program), never for one another.
_LINE_TASKS: weakref.WeakSet[asyncio.Task[Any]] = weakref.WeakSet()


async def outlive_the_program(run: Callable[[], Awaitable[None]], closing: anyio.CancelScope) -> None:
    """Run ``run()``, the loop of a line's own asyncio task, until ``closing`` (the task's own scope: the bus closing)
    is cancelled, and through the end of the program's run, for the program's closes to put the servos to rest.

    ``asyncio.run()`` ended by a KeyboardInterrupt out of its loop (one its first-Ctrl-C handling did not take: a
    SIGINT handler of the program's own, a second Ctrl-C) cancels every task at once and runs them to their ends: the
    program's tasks close their streams, robots and buses as they go, with commands only the line's task carries.
    Ended with them, the line would fail those closes at once.  So a ``Task.cancel()`` from outside runs ``run()``
    again, until every other task unfinished at that cancellation (other lines' own tasks aside) has ended; then it is
    raised: a line the program never closed ends with the program's tasks, and the run with them.

    A KeyboardInterrupt or SystemExit that a signal handler raised inside this task, rather than in the loop's wait,
    would end the task with it: raised in this library's own code, it goes on out of the loop from a callback of its
    own, as from any callback, and ``run()`` runs again.  Raised inside asyncio's or anyio's (a selector's or a cancel
    scope's bookkeeping half done), it ends the task as before: the line could not be trusted to run on."""
    task = asyncio.current_task()
    assert task is not None
    _LINE_TASKS.add(task)
    waited: set[asyncio.Task[Any]] | None = None  # the tasks outlived, once cancelled from outside
    ending = False

    def ended(other: asyncio.Future[Any]) -> None:
        nonlocal ending
        assert waited is not None
        waited.discard(other)
        if not waited and not ending:
            ending = True
            task.cancel()  # (this time from here: raised, below)

    try:
        while True:
            try:
                await run()
                return
            except asyncio.CancelledError:
                if closing.cancel_called or ending:
                    raise
                if waited is None:
                    waited = {other for other in asyncio.all_tasks() if other not in _LINE_TASKS}
                    if not waited:
                        raise
                    for other in waited:
                        other.add_done_callback(ended)
                task.uncancel()  # (left counted, it would make anyio's cancel scopes in run() take theirs for it)
            except (KeyboardInterrupt, SystemExit) as exc:
                if closing.cancel_called or not _raised_in_the_library(exc):
                    raise
                asyncio.get_running_loop().call_soon(_raise, exc)
    finally:
        for other in waited or ():
            other.remove_done_callback(ended)


def _raise(exc: BaseException) -> None:
    raise exc


_LIBRARY = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
_THE_LOOPS = (os.path.dirname(os.path.abspath(anyio.__file__)), os.path.dirname(os.path.abspath(asyncio.__file__)))


def _raised_in_the_library(exc: BaseException) -> bool:
    """Whether a signal handler raised ``exc`` (caught in the calling frame) in this library's own code, not inside
    anyio's or asyncio's (a selector's too).  The frames past the one it landed in are the handler's own (whose first
    not of this library's ends the walk)."""
    tb = exc.__traceback__
    tb = None if tb is None else tb.tb_next  # (the catching frame's own entry)
    library = False
    while tb is not None:
        path = os.path.abspath(tb.tb_frame.f_code.co_filename)
        if path.startswith(_THE_LOOPS) or os.path.basename(path) == "selectors.py":
            return False  # (this library's code runs in neither: a frame of this library's past it is the handler's)
        if not path.startswith(_LIBRARY + os.sep):
            break
        library = True
        tb = tb.tb_next
    return library


class DriverCore:
    """The shared half of a driver: see the module docstring."""

    name = "core"
    blocking_reads = False  # whether this driver reads a port without a descriptor itself

    def __init__(self, engine: LineEngine, port: str | WireDevice, settings: LineSettings) -> None:
        self.engine = engine
        self.target = port  # what the caller asked to open (the open port is ``port``)
        # The loop the bus opened in: its callers' futures, events and wake-ups all belong to it.
        self.home = running_loop()
        self._home_thread = threading.get_ident()
        self._awaiting_offline = False  # a reopen waits for the transaction on the wire to end (see _go_offline)
        self.settings = settings
        self.port: Port | None = None
        self._waiting_until = INF  # when the driver's current wait ends (it is re-aimed for earlier)
        self._idle: list[anyio.Event] = []
        # The burst path (see .burst), where the driver runs it: while a burst runs, the executor's
        # thread has the port and the engine waits to be fed.
        self.burst: BurstRunner | None = None
        self.requested_at = -math.inf  # when the program last sent a request (no burst for a while after)
        # Held around every engine call where the engine may run on two threads (the thread driver's
        # lock); the other drivers run it on one and hold nothing.
        self.lock: contextlib.AbstractContextManager[Any] = contextlib.nullcontext()

    @property
    def fine_deadlines(self) -> bool:
        """Whether its deadlines fire to the microsecond (see .fine_timer), not on the millisecond timers of its
        loop (or the whole milliseconds of ``poll``)."""
        return False

    # ------------------------------------------------------------------ a driver's own part

    def _watch(self, port: Port) -> None:
        """Start waiting on ``port`` (it has just opened)."""
        raise NotImplementedError

    def _unwatch(self, port: Port) -> None:
        """Stop waiting on ``port`` (it is about to close)."""

    def _rewait(self) -> None:
        """The engine's deadline moved earlier than the current wait's end: wait again."""

    def notify(self, callback: Callable[[], None]) -> None:
        """Run ``callback`` on the callers' event loop thread (here: now, the engine runs there)."""
        callback()

    def _new_request(self, command: Command[Any], priority: int, retries: int) -> tuple[CallerRequest, Any]:
        """A request for ``command``, and what its caller awaits."""
        raise NotImplementedError

    # ------------------------------------------------------------------ the engine's answers, in one place

    def _read(self, port: Port) -> bytes | None:
        """What ``port`` has now (``b""``: nothing); ``None`` once the read failed and the port is lost."""
        try:
            return port.read()
        except OSError as exc:
            self._lose(port, exc)
            return None

    def _step(self, port: Port, data: bytes, t: float) -> None:
        """What came from ``port`` at ``t`` (``b""``: nothing): feed the engine and act on its answer."""
        engine = self.engine
        out: Output
        if data:
            if port.bad:  # bytes the kernel marked damaged: their transaction fails once complete
                engine.line_error(port.bad)
                port.bad = 0
            out = engine.receive(data, t)
        elif t >= engine.deadline:  # nothing more came by the deadline (read just now): judge it
            out = engine.tick(t)
        else:
            out = None
        if out is not None:
            self._act(port, out)
        if self._idle and self._idle_now():
            self._release_idle()

    def _act(self, port: Port, out: bytes | FlushInput) -> None:
        """Do what the engine answered: write its bytes, after dropping stale input if it asks."""
        if isinstance(out, FlushInput):
            dropped = port.discard_input()
            if dropped:
                self.engine.input_dropped(dropped)
            if out.then is None:
                return
            out = out.then
        if self.burst is not None and self._start_burst(self.burst):
            return  # the executor writes it, and the rest of the plan
        try:
            if not port.write(out):
                self._write_blocked(port)
        except Exception as exc:  # the port vanished, or an in-process device failed: a lost port
            self._write_failed(port, exc)
            return
        self.engine.written(now())  # (the allowance counts from here: see LineEngine.written)

    # ------------------------------------------------------------------ the burst path (see .burst)

    @property
    def bursting(self) -> bool:
        """A burst runs: the executor's thread has the port; the engine waits to be fed."""
        burst = self.burst
        return burst is not None and burst.running

    def _start_burst(self, burst: BurstRunner) -> bool:
        """The engine just put a transaction on the wire: run it (and its plan) as a burst; False: write it.
        Only from where the driver waits on the port (its loop, bus task or I/O thread): a burst started by a
        caller could find that wait about to read the port beside the executor."""
        return False

    def _burst_done(self, burst: BurstRunner, *, wait: bool = False, close: bool = False) -> None:
        """Feed the engine what ``burst`` did (see ``BurstRunner.finish``: while it runs, what is done so far).
        Once it stopped: closed if ``close`` (closing or reopening: the rest goes the ordinary way), the port
        handed back to the driver's own wait (:meth:`_burst_over`), and the engine's answer acted on as the
        ordinary path would.  Under the lock; ``wait``: stop it at its next boundary and block until it has."""
        done, out = burst.finish(now, wait=wait)
        if not done:
            return
        if close:
            self._close_burst()
        port = self.port
        if (
            not close
            and isinstance(port, TtyPort)
            and burst.status != FAILED
            and type(out) is bytes
            and self._start_burst(burst)
        ):
            # The next burst runs on from here: the port stays with the executor (handed to the driver's
            # wait and taken back, it costs the asyncio driver two epoll_ctl calls and a selector's
            # bookkeeping a burst).  Otherwise as _act would, once the driver's wait has the port again
            # (closing: the runner is closed, and _act finds none).
            self._after(None)
            return
        self._burst_over(port)
        if not isinstance(port, TtyPort):
            return
        if burst.status == FAILED:
            self._lose(port, port_gone(burst.errno))  # (the executor's write or read)
            return
        self._after(out)

    def _burst_over(self, port: Port | None) -> None:
        """A burst stopped: the driver's wait takes the port again (it waited on the burst's notices)."""

    def _stop_burst(self) -> None:
        """Closing or reopening: a running burst stops at its next boundary and is fed to the engine.  Blocks for
        at most one transaction, with no await: a cancelled close still leaves the engine knowing what was on
        the wire."""
        with self.lock:
            burst = self.burst
            if burst is not None and burst.running:
                self._burst_done(burst, wait=True, close=True)
            else:
                self._close_burst()

    def _end_burst(self) -> None:
        """A running burst stops at its next boundary and is fed to the engine (later ones may run)."""
        burst = self.burst
        if burst is not None and burst.running:
            self._burst_done(burst, wait=True)

    def _close_burst(self) -> None:
        """The burst path of this port ends (the port is unwatched, or closing): its executor's thread stops."""
        burst, self.burst = self.burst, None
        if burst is not None:
            self._burst_closing(burst)
            burst.close()

    def _burst_closing(self, burst: BurstRunner) -> None:
        """Before ``burst``'s executor closes (and with it the descriptor of its notices): stop waiting on it."""

    def _write_blocked(self, port: Port) -> None:
        """Part of a write waits in the tty's ``pending``: wait for the port to take it."""

    def _write_failed(self, port: Port, exc: Exception) -> None:
        self._lose(port, exc)

    def _fail_line(self, reason: str, *, warn: bool = True) -> None:
        """The driver can no longer run the line: it closes for good, every request failing with PortLost(``reason``)
        (none waits for ever), with or without a port."""
        port = self.port
        if port is not None:
            self.port = None
            self._unwatch(port)
            port.close()
        if warn and self.engine.state not in (CLOSED, DRAINING):
            log.warning("%s", reason)
        self.engine.lost(reason, reconnect=False)
        self._release_idle()

    # ------------------------------------------------------------------ a lost wake-up

    def _turned_since(self, t: float) -> bool:
        """Whether the driver's own wait has run (begun a wait, or acted on one's end) at or after ``t``."""
        return True

    def check_progress(self, suspect: float) -> float:
        """A level check every :data:`STALL` seconds (by a waiting caller, or a timer of the driver's): the driver's
        wait must have run since the engine's deadline went by.  An exception raised inside one of the event loop's
        callbacks (a signal handler's: pytest-timeout's alarm, a program's handler raising KeyboardInterrupt) drops
        what that callback was doing, and with it perhaps the wake-up of the driver's wait, edge-triggered: the line
        would stand still for ever.  ``suspect`` is the overdue deadline the previous look found (``INF``: none); the
        same one found again, a whole look later (a loop merely stalled by the program has run the driver's wait
        meanwhile), means the wake-up is lost: the line fails for good, saying so.  Returns the overdue deadline found
        now, or ``INF``."""
        deadline = self.engine.deadline
        if deadline == INF or self.bursting or now() < deadline or self._turned_since(deadline):
            return INF
        if deadline != suspect:
            return deadline
        self._fail_line(
            f"the {self.name} driver's wait for port {self.target} stopped running: an exception raised inside an"
            " event loop callback (by a signal handler) dropped its wake-up"
        )
        return INF

    def _after(self, out: Output) -> None:
        """After an engine call from the user's side: act on the answer, re-aim the wait, wake idle waiters."""
        port = self.port
        if out is not None and port is not None:
            self._act(port, out)
        if self.engine.deadline < self._waiting_until:
            self._rewait()
        if self._idle and self._idle_now():
            self._release_idle()

    # ------------------------------------------------------------------ the port coming and going

    async def _open(self) -> Port:
        """Open the port in a worker thread (closed again if the caller is cancelled meanwhile)."""
        opened: list[Port] = []
        abandoned: list[bool] = []
        started: list[bool] = []
        lock = threading.Lock()
        key = self.target if isinstance(self.target, str) else id(self.target)
        ended = await _after_earlier_opening(key, self.target)

        def opening() -> Port:
            handed = False  # the port went to the caller, who ends the opening (after closing it, if cancelled)
            try:
                with lock:
                    if abandoned:  # given up on before this thread began: nothing to open
                        raise OSError(errno.ECANCELED, "the opening was given up on")
                    started.append(True)
                port = open_port(
                    self.target,
                    self.engine.baudrate,
                    transport=self.settings.transport,
                    direction=self.settings.direction,
                    blocking_reads=self.blocking_reads,
                )
                with lock:
                    if abandoned:  # the caller gave up while this thread was opening it
                        port.close()
                    else:
                        opened.append(port)
                        handed = True
                return port
            finally:
                if not handed:
                    _opening_ended(key, ended)

        try:
            port = await self._in_thread(opening)
        except BaseException:
            with lock:
                abandoned.append(True)
                ends_here = not started or bool(opened)  # (never run, or its port handed over)
            for port in opened:
                port.close()
            if ends_here:
                _opening_ended(key, ended)
            raise
        _opening_ended(key, ended)
        return port

    async def _in_thread(self, call: Callable[[], Port]) -> Port:
        """Run a blocking ``call`` in a thread of its own, which ends with it.

        Not the event loop library's worker threads: trio keeps an idle one alive for seconds,
        so a program that opened a port would end with a thread still running.  Opening a port
        takes milliseconds; the wait polls, doubling from 0.5 ms to 20 ms.  If the wait is
        cancelled the thread runs on, and the caller closes the port it opens (see ``_open``).
        """
        opened: list[Port] = []
        failed: list[BaseException] = []

        def run() -> None:
            try:
                opened.append(call())
            except BaseException as exc:  # handed to the waiting task
                failed.append(exc)

        thread = threading.Thread(target=run, name=f"ics35 open {self.target}", daemon=True)
        thread.start()
        delay = 0.0005
        while thread.is_alive():
            await anyio.sleep(delay)
            delay = min(delay * 2, 0.02)
        if failed:
            raise failed[0]
        return opened[0]

    def _connected(self, port: Port) -> None:
        """``port`` is open: wait on it, and tell the engine (which may have work at once).  Under the lock."""
        self.port = port
        self._watch(port)
        path = f", {PATH_NAME}" if self.burst is not None else ""  # (see .burst: which path streams take)
        log.info("opened %s at %d baud (%s driver%s)", self.target, self.engine.baudrate, self.name, path)
        self._after(self.engine.connected(now()))

    def _lose(self, port: Port, exc: Exception | None, *, reconnect: bool = True) -> bool:
        """``port`` went away: close it, tell the engine; True if it is to be reopened."""
        if port is not self.port:
            return False  # already replaced (or closed on purpose)
        self.port = None
        self._unwatch(port)
        port.close()
        engine = self.engine
        reason = f"port {self.target} lost: {error_text(exc)}" if exc else f"port {self.target} closed"
        reconnect = reconnect and self.settings.reconnect
        # (A loss for good under run() is said by the run, once: see said_at_the_end.)
        if engine.state not in (CLOSED, DRAINING) and (reconnect or not said_at_the_end(log, reason)):
            log.warning("%s", reason)
        engine.lost(reason, reconnect=reconnect)
        self._release_idle()
        return engine.state is LOST

    async def reopen(self, baudrate: int) -> None:
        """Close and reopen the port (the engine holds requests meanwhile), once the transaction on the wire
        (if any) has ended."""
        with self.lock:
            self._refuse_reopen()  # first: a refused reopen leaves the line (and any burst) as it was
        self._stop_burst()
        await self._go_offline()
        await self._release_port()
        self.engine.baudrate = baudrate
        self._reopened(await self._open())  # a failure closes the line for good (the bus tells the engine)

    async def _release_port(self) -> None:
        """A reopen's old port is given up (offline by now): no wait on it remains, and it is closed."""
        self._drop_port()

    def _reopened(self, port: Port) -> None:
        """``port``, opened again by a reopen, is the line's now; unless the bus closed while it opened: closed
        at once then (left open, it would be busy to the program's next open), and the closed error raised."""
        with self.lock:
            if self.engine.state is CLOSED or self.engine.state is DRAINING:
                port.close()
                raise self.engine.closed_error()
            self._connected(port)

    async def _go_offline(self) -> None:
        """Take the line offline for a reopen: at once when idle, else at the end of the transaction on the
        wire (requests queued meanwhile wait for the reopened port).

        Raises:
            PortLost: the port was lost meanwhile (or before).
            BusClosed: the bus closed meanwhile.
        """
        with self.lock:
            self._refuse_reopen()
            offline = self.engine.disconnected()
        if not offline:
            self._awaiting_offline = True
            try:
                await self.wait_idle()  # (offline is idle enough for this wait: see _idle_now)
            finally:
                self._awaiting_offline = False
            with self.lock:
                self._refuse_reopen(waited=True)
                if self.engine.state is not OFFLINE:  # (lost and back already: the reconnect's line, not this one's)
                    raise PortLost(f"port {self.target} was lost and reconnected; reopen again")

    def _refuse_reopen(self, *, waited: bool = False) -> None:
        """Raise if the line cannot be reopened now: PortLost while it is lost, the closed error once closing."""
        state = self.engine.state
        if state is LOST:
            raise PortLost(f"port {self.target} {'was' if waited else 'is'} lost; cannot reopen now")
        if state is CLOSED or state is DRAINING:  # (a close came first: its drain goes on undisturbed)
            raise self.engine.closed_error()

    def _drop_port(self) -> None:
        """Stop waiting on the port and close it (a reopen, or the bus closing)."""
        port, self.port = self.port, None
        if port is not None:
            self._unwatch(port)
            port.close()

    def _backoff(self) -> Iterator[tuple[int, float]]:
        """The reconnect schedule: (attempt, seconds to wait before it), for ever."""
        backoff = self.settings.reconnect_backoff
        for attempt in itertools.count():
            yield attempt + 1, backoff[min(attempt, len(backoff) - 1)]

    async def _reconnect(self) -> None:
        """Reopen a lost port on the reconnect schedule, until it opens or the line closes."""
        for attempt, delay in self._backoff():
            await anyio.sleep(delay)
            if self.engine.state is not LOST:
                return
            try:
                port = await self._open()
            except (OSError, IcsError) as exc:
                log.debug("reconnect %d to %s failed: %s", attempt, self.target, exc)
                continue
            with self.lock:
                if self.engine.state is not LOST:  # closed meanwhile
                    port.close()
                    return
                self.engine.counters.reconnects += 1
                self._connected(port)
            # A warning, as the loss was: a program that set no logging up hears both (Python's last-resort
            # handler prints warnings only), or it would never learn that its port came back.
            log.warning("port %s back: reconnected after %d attempt(s)", self.target, attempt)
            return

    # ------------------------------------------------------------------ the user's side

    def check_caller(self) -> None:
        """Refuse a caller on another event loop than the bus's (before anything is queued or sent)."""
        if running_loop() is not self.home:
            raise InvalidArgument(
                "this bus was opened in another event loop (each asyncio.run() or trio.run() starts its own):"
                " a bus serves the loop it was opened in, so open it in the one that uses it"
                " (or use ics35_async.blocking from code without a loop)"
            )

    def submit(self, command: Command[Any], priority: int, retries: int) -> Any:
        """Queue ``command``; returns what the caller awaits for its outcome."""
        self.check_caller()
        request, awaited = self._new_request(command, priority, retries)
        with self.lock:
            t = now()
            self.requested_at = t
            burst = self.burst
            if burst is None or not burst.submit(request, t):  # (during a burst: queued where it stops)
                self._after(self.engine.submit(request, t))
        return awaited

    def _soon_at_home(self, callback: Callable[[], None]) -> None:
        """Run ``callback`` on the thread of the loop the bus opened in, from any thread."""
        raise NotImplementedError

    def call(self, step: Callable[[float], Output]) -> None:
        """Run an engine call (given the time) and act on what it answers.

        From another thread than the loop's (a program's vision thread setting a stream's targets), where the
        engine runs on the loop's thread without a lock (the asyncio and anyio drivers), the call is made there,
        within a loop turn: run here, it would put commands on the wire beside the loop's own engine calls."""
        if isinstance(self.lock, contextlib.nullcontext) and threading.get_ident() != self._home_thread:
            with contextlib.suppress(RuntimeError):  # the loop has ended: nothing is left to call
                self._soon_at_home(lambda: self.call(step))
            return
        with self.lock:
            burst = self.burst
            if burst is not None and burst.running:
                burst.hold(step)  # where the burst stops (mid-transaction then: nothing to write)
            else:
                self._after(step(now()))

    def call_now(self, step: Callable[[float], Output]) -> None:
        """As :meth:`call`, but at once, so that what the step raises reaches the caller: a running
        burst is stopped at its next boundary first (a wait of one transaction at most).  For a call the
        engine may refuse (attaching a stream while another runs)."""
        with self.lock:
            burst = self.burst
            if burst is not None and burst.running:
                self._end_burst()
            self._after(step(now()))

    # ------------------------------------------------------------------ waiting for quiet; closing

    def _idle_now(self) -> bool:
        if self.engine.state is OFFLINE:
            # A reopen's line: its queued requests wait for the reopened port (not idle, for the program's
            # wait_idle), but the reopen itself waits only for the line to go offline.
            return self._awaiting_offline or self.engine.idle
        return self.engine.idle or self.port is None

    async def wait_idle(self) -> None:
        """Return once nothing is on the wire, resyncing or queued (or the port is gone)."""
        event: anyio.Event | None = None
        while True:
            with self.lock:
                if self._idle_now():
                    return
                if event is None or event not in self._idle:  # (a new one once the last was released)
                    event = anyio.Event()
                    self._idle.append(event)
            # Looking again every STALL seconds: the callback that sets the event may be dropped (an exception
            # raised inside it by a signal handler), and with it the only word that the line is idle.
            with anyio.move_on_after(STALL):
                await event.wait()

    def _release_idle(self) -> None:
        waiters, self._idle = self._idle, []
        for event in waiters:
            self.notify(event.set)

    async def _drain(self) -> None:
        """Close the engine; let a transaction on the wire finish (bounded); then abort what is left."""
        engine = self.engine
        self._stop_burst()  # the engine hears the burst's bytes first (one transaction at most)
        with self.lock:
            engine.close()
            draining = engine.state is DRAINING
        try:
            if draining:
                # To its end also when the close runs cancelled (a program stopped by Ctrl-C or a timeout closes its
                # bus inside that cancellation): released at once, the port's reply still on its way would land in
                # front of the next transaction on that port, the next program's.
                await despite_cancellation(self.wait_idle, engine.drain_bound)
        finally:
            with self.lock:
                engine.abort()
                self._release_idle()


class LoopDriver(DriverCore):
    """A driver whose callers run on an asyncio loop: ports open in the loop's own executor (kept for
    its lifetime), and a supervisor task on the loop reopens a lost port."""

    def __init__(self, engine: LineEngine, port: str | WireDevice, settings: LineSettings) -> None:
        super().__init__(engine, port, settings)
        self.loop = asyncio.get_running_loop()
        self._lost = asyncio.Event()  # set (on the loop) when a lost port is to be reopened
        self._supervisor: asyncio.Task[None] | None = None

    async def _in_thread(self, call: Callable[[], Port]) -> Port:
        return await self.loop.run_in_executor(None, call)

    def _lose(self, port: Port, exc: Exception | None, *, reconnect: bool = True) -> bool:
        again = super()._lose(port, exc, reconnect=reconnect)
        if again:  # the supervisor reopens it (told on the loop's thread: the thread driver's I/O thread loses it)
            self.notify(self._lost.set)
        return again

    def _soon_at_home(self, callback: Callable[[], None]) -> None:
        self.loop.call_soon_threadsafe(callback)

    def _supervise(self) -> None:
        self._supervisor = self.loop.create_task(self._supervisor_task(), name=f"ics35 bus {self.target}")

    async def _supervisor_task(self) -> None:
        while True:
            # A look at the line every STALL seconds meanwhile: a callback of the driver's (a timer, a delivery)
            # that an exception raised inside it (by a signal handler) dropped is made good there, instead of
            # leaving a request waiting for ever.
            with anyio.move_on_after(STALL):
                await self._lost.wait()
            if not self._lost.is_set():
                self._look()
                continue
            self._lost.clear()
            await self._before_reconnect()
            await self._reconnect()

    def _look(self) -> None:
        """Make good what a callback dropped by an exception would have done (see _supervisor_task)."""

    async def _before_reconnect(self) -> None:
        """Anything to end before the port is reopened."""

    async def _end_supervisor(self) -> None:
        if self._supervisor is not None:
            self._supervisor.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._supervisor
            self._supervisor = None
