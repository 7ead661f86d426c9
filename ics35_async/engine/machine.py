"""The line engine: every rule of a half-duplex ICS line as a plain state machine.

No event loop, no clock, no I/O (h11 is the model).  A driver feeds it what
happens -- bytes received, the time, a deadline passed, the port lost -- and
each call answers with the bytes to write next (or ``None``).  After any
call, ``deadline`` is when the engine wants :meth:`tick` (``math.inf``: not
until something else happens).  When a resync ends, :meth:`tick` answers
with a :class:`FlushInput` instead of bytes: drop what the port has buffered,
then write its ``then``.  Requests learn their outcome through
``Request.resolve``/``reject``; the stream (the background source) through
its own plain methods.  The rules it holds: see :mod:`ics35_async.engine`.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable

from ..errors import BusClosed, ClosedByPortLoss, EchoMismatch, IcsError, InvalidArgument, PortLost, ReplyError
from ..protocol import Timing, wire_time
from ..protocol.wire import echo_offset
from .counters import NO_ID, LineCounters, error_counter
from .guard import GuardRule
from .link import LinkLatency
from .outcome import framing_error, timeout_error
from .probe import FLOOR as STREAM_WAIT_FLOOR
from .probe import STREAM_RESYNC, AnswerTimes
from .requests import GuardRequest, Priority, Request, RequestQueue
from .source import BackgroundSource
from .state import State
from .timing import BusTiming

log = logging.getLogger("ics35_async")
# Each failed transaction, in words (DEBUG: a faulty line fails many a second).  Its own logger so
# that it can be turned on without the byte dumps (the CLI's -v does).
fault_log = logging.getLogger("ics35_async.faults")

INF = math.inf
# The states and timing the hot path compares with, as plain names (no attribute lookup).
# (An enum member looked up on its class costs more than the rest of a comparison.)
BUSY, IDLE, QUIET, DRAINING, CLOSED = State.BUSY, State.IDLE, State.QUIET, State.DRAINING, State.CLOSED
OFFLINE, LOST = State.OFFLINE, State.LOST
NORMAL = Timing.NORMAL
PROBE = Timing.PROBE
SILENT = Timing.SILENT
URGENT = Priority.URGENT
LOW = Priority.LOW
ANOTHER_STREAM = "this bus already runs a stream; close it first"  # (the bus refuses it too: see Bus.attach_source)
FIT_MARGIN = 0.0005  # seconds a request beside a paced stream must leave before the next cycle is due
BURST_LIMIT = 512
"""Transactions in one burst at most: sixteen cycles of a 32-servo stream (a wake still stops it at its next
boundary).  Each burst's start hands a plan to another thread and its end waits for the loop to feed its last
transactions; longer plans pay that less often (``benchmarks/bench_burst.py``: the loop's thread 4.7 against 5.3 us
a transaction at 128; no less at 1,024)."""
PlannedTransaction = tuple[bytes, int, int, float, bytes]
"""One transaction of a burst: the bytes to write, bytes expected back, of which echo, allowance (s), and
the shape of a reply the source takes (see :data:`.source.Upcoming`)."""


class FlushInput:
    """What :meth:`LineEngine.tick` answers when a resync ends: drop the port's input, then write ``then``.

    Whatever the OS still buffers from before the resync is stale (the late
    bytes of a failed transaction).  An answer rather than a flag, as h11
    returns events: a driver cannot forget to look at it.
    """

    __slots__ = ("then",)

    def __init__(self, then: bytes | None) -> None:
        self.then = then

    def __eq__(self, other: object) -> bool:
        return isinstance(other, FlushInput) and other.then == self.then

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        return f"FlushInput(then={self.then!r})"


Output = bytes | FlushInput | None
"""What an engine call answers: bytes to write, a :class:`FlushInput`, or nothing."""


class LineEngine:
    """The rules of one ICS line.  See the module docstring for the contract."""

    def __init__(
        self,
        *,
        baudrate: int,
        echo: bool = True,
        timing: BusTiming | None = None,
        max_requests_between: int = 16,
        port: object = None,
    ) -> None:
        self.baudrate = baudrate
        # What the fault log names the line by (the bus's port as given): a robot's lines each have an ID 1.
        self.port = port
        self.echo = echo
        self.timing = timing or BusTiming()
        self.max_requests_between = max_requests_between
        self.state = OFFLINE
        self.deadline = INF
        self._going_offline = False  # asked offline while busy: at the end of the transaction (see disconnected)
        self.counters = LineCounters()
        self.link = LinkLatency(bound=self.timing.link_extra_max)
        self.counters.link = self.link
        self.debug = False
        # Told of the port's comings and goings: LOST or CLOSED when it is lost, IDLE when it
        # is back after a loss.  Called from wherever the engine runs (see Bus.state_change).
        self.on_state_change: Callable[[State], None] | None = None
        self.queue = RequestQueue()
        self._lost: str | None = None  # why the port was lost, if that closed the line
        self._source: BackgroundSource | None = None
        self._in_row = 0  # requests run since the source's last transaction
        # Slots of a paced stream that one request, the queue's head, was passed over in (see _passed_over_in).
        self._passed_over = 0
        self._passed_over_due = -INF  # the slot of the last one counted
        self._passed_over_head: Request | None = None  # the request they were counted for
        self._allowances: dict[int, float] = {}  # NORMAL allowance by transaction size
        # The transaction on the wire.
        self._buf = bytearray()
        self._tx = b""
        self._expect = 0
        self._echo_len = 0
        self._current: Request | None = None  # None while the source's transaction runs
        self._owner: BackgroundSource | None = None
        self._current_id = NO_ID
        self._t_start = 0.0
        self._base = 0.0  # this transaction's full allowance without the link's extra (a probe waits less)
        self._short = False  # this transaction waits less than its full allowance (a probe, the stream)
        self._read_in_slack = False  # this transaction is a read beside a paced stream (see _begin)
        # A stream transaction whose answers are learnt, waiting its full allowance since that is shorter than the
        # learnt wait (a small adapter_latency): one that fails is held back as a short one is (see _hold).
        self._learnt_stream = False
        self._wire: dict[int, float] = {}  # wire time by transaction size
        # First bytes (command and ID) whose reply may still come after a stream transaction's or a slack read's
        # failure that was followed by no whole quiet_time: no command that starts with one goes on the wire before
        # its time here (see _hold).
        self._held: dict[int, float] = {}
        self._hold_wake = INF
        # First bytes held back (see _hold), and when their hold ends: the first command after that, if it starts
        # so, gets the guard read the end of a timeout's resync would have given it (the stream's own offer is
        # skipped once more instead while it has another: see _skip_held).
        self._guard_after_hold: dict[int, float] = {}
        self._corrupted = False  # a byte of this transaction had a parity/framing error
        self._tail_until = 0.0  # until then a partial reply's tail may still come (see _settle)
        self._planned = False  # a burst runs what plan_burst planned: until burst_over, it goes first
        self._settling = False  # this transaction's reply is in; waiting to see no more comes
        self._t_done = 0.0  # when it came in
        self._due = 0.0  # its deadline, while it settles
        self.guard = GuardRule()
        self.answers = AnswerTimes()
        self._t_first = 0.0  # when this transaction's first byte arrived (a slow link's evidence)
        self._quiet_until = 0.0
        self._quiet_span = self.timing.quiet_time  # the silence that ends the resync in progress
        self._resync_limit = 0.0

    # ------------------------------------------------------------------ life cycle

    def connected(self, now: float) -> bytes | None:
        """The port is open (first time, after a reopen, or reconnected)."""
        if self.state not in (OFFLINE, LOST):
            raise InvalidArgument(f"connected() while {self.state.value}")
        resumed = self.state is LOST
        self._buf.clear()
        self._allowances.clear()  # wire times depend on the baud rate, which may have changed
        self.link.in_step()  # a fresh port: no reply from before can still arrive
        self.guard.unheard = ()  # (nor any echo)
        self.answers.reset()
        self._wire.clear()
        self._held.clear()
        self._guard_after_hold.clear()
        self.state = IDLE
        if resumed:
            if self._source is not None:
                self._source.line_resumed(now)
            if self.on_state_change is not None:
                self.on_state_change(IDLE)
        return self._start_next(now)

    def disconnected(self) -> bool:
        """The driver is to close the port on purpose (reopen); requests wait for it to be open again.

        Idle: offline now (True).  With a transaction on the wire or a resync under way: offline once it ends
        (False; the state tells when), and no queued request goes meanwhile: a program that keeps requests
        queued (telemetry) would otherwise never leave the line idle for the reopen.
        """
        if self.state is IDLE:
            self.state = OFFLINE
            self.deadline = INF
            return True
        if self.state is BUSY or self.state is QUIET:
            self._going_offline = True
            return False
        raise InvalidArgument(f"cannot take the line offline while {self.state.value}")

    def lost(self, reason: str, *, reconnect: bool) -> None:
        """The port went away: everything waiting fails with PortLost."""
        if self.state in (CLOSED, LOST):
            return
        self._going_offline = False
        draining = self.state is DRAINING
        current, self._current = self._current, None
        if current is not None:
            current.reject(PortLost(reason))
        self.queue.fail_all(PortLost(reason))
        self.deadline = INF
        if reconnect and not draining:
            self.state = LOST  # the source stays attached and resumes after the reconnect
        else:
            self.state = CLOSED
            if not draining:  # (a loss while the program closes it: the program closed it)
                self._lost = reason
            self._detach(PortLost(reason))
        if self.on_state_change is not None:
            self.on_state_change(self.state)

    def closed_error(self) -> BusClosed:
        """What work on the closed line meets: why it closed, if losing its port closed it."""
        if self._lost is not None:
            return ClosedByPortLoss(f"the bus closed itself: {self._lost}")
        return BusClosed("bus is closed")

    def close(self) -> None:
        """No new work: queued requests fail with BusClosed; a transaction on the wire finishes."""
        if self.state in (CLOSED, DRAINING):
            return
        self._going_offline = False
        self._detach(BusClosed("bus closed"))
        self.queue.fail_all(BusClosed("bus closed"))
        if self.state is BUSY:
            self.state = DRAINING
        else:
            self.state = CLOSED
            self.deadline = INF

    @property
    def drain_bound(self) -> float:
        """How long a driver waits for a closing line's last transaction before :meth:`abort`:
        an EEPROM write's allowance for 200 bytes (more than any transaction has) on this link,
        and a second more."""
        return self.timing.allowance(200, self.baudrate, Timing.EEPROM_WRITE, self.link.extra) + 1

    def abort(self) -> None:
        """Close now, even with a transaction on the wire (it fails with BusClosed)."""
        self.close()
        current, self._current = self._current, None
        if current is not None:
            current.reject(BusClosed("bus closed"))
        self.state = CLOSED
        self.deadline = INF

    def describe(self, now: float) -> dict[str, object]:
        """What the line is doing at ``now``, as plain values: for a dump when something seems stuck.

        The state, when the engine wants its next :meth:`tick` (seconds from ``now``; None: not
        until something happens), the transaction on the wire (bytes sent and so far received,
        who waits for it), every queued request in the order it would run, ``going_offline``
        (asked offline while busy, by a reopen: offline when the transaction or resync ends, the
        queued requests waiting until the port is open again), and the slow-link, guard-read and hold
        rules' state (the first bytes held back, and those whose next command still gets a guard read).
        """
        wire: dict[str, object] | None = None
        if self.state in (BUSY, DRAINING):
            wire = {
                "tx": self._tx.hex(" "),
                "received": bytes(self._buf).hex(" "),
                "expect": self._expect,
                "started_s_ago": round(now - self._t_start, 6),
                "for": repr(self._current) if self._current is not None else "the stream",
            }
        source = self._source
        return {
            "state": self.state.value,
            "deadline_in_s": None if self.deadline == INF else round(self.deadline - now, 6),
            "on_the_wire": wire,
            "queued": [repr(request) for request in self.queue.waiting()],
            "going_offline": self._going_offline,
            "stream": None if source is None else repr(source),
            "link_extra_s": self.link.extra,
            "reply_owed": self.link.owed_since != INF,
            "guard_suspect": ", ".join(shape.hex(" ") for shape in self.guard.suspect),
            # (commands whose echo never came back: sent again, each gets a guard read first; see .guard)
            "guard_unheard": [tx.hex(" ") for tx in self.guard.unheard],
            "held_back_s": {f"{b:02x}": round(until - now, 6) for b, until in self._held.items() if until > now},
            # (first bytes whose next command gets a guard read once their hold is over, over or not: see _hold)
            "guard_after_hold": sorted(f"{b:02x}" for b in self._guard_after_hold),
        }

    @property
    def idle(self) -> bool:
        """Nothing on the wire, resyncing or queued."""
        return self.state not in (BUSY, QUIET, DRAINING) and not self.queue

    def submit(self, request: Request, now: float) -> bytes | None:
        state = self.state
        if state is IDLE or state is BUSY or state is QUIET or state is OFFLINE:
            self.queue.push(request)
            counted = self._passed_over_head
            if counted is not None and request.priority < counted.priority:
                # It outranks the head whose passed-over slots were counted: that one comes to the head again
                # later (this one gone or cancelled) and starts from none, as any request that comes to the head.
                self._passed_over_head = None
            return self._start_next(now) if state is IDLE else None
        if state is LOST:
            raise PortLost("the port is lost; reconnecting")
        raise self.closed_error()

    def attach_source(self, source: BackgroundSource, now: float) -> bytes | None:
        """Let ``source`` fill the line's idle time (one at a time)."""
        if self._source is not None and self._source is not source:
            raise InvalidArgument(ANOTHER_STREAM)
        if self.state is CLOSED or self.state is DRAINING:
            raise self.closed_error()
        # Slots a request was passed over in beside an earlier stream do not count: it goes ahead
        # of this stream only once passed over in two of this stream's slots.
        if source is not self._source:
            self._passed_over, self._passed_over_due = 0, -INF
        self._source = source
        return self.kick(now)

    @property
    def source(self) -> BackgroundSource | None:
        """The attached background source (the stream), if any."""
        return self._source

    def detach_source(self, source: BackgroundSource) -> None:
        if self._source is source:
            self._source = None
            if self.state is BUSY and self._current is None and self._owner is source and source.probing_silent():
                self._unheeded_probe()

    def _unheeded_probe(self) -> None:
        """The source left while its probe of a servo it had found silent was on the wire (a stream closing as
        it probes an offline ID): nobody will hear the answer that would have brought the servo back, and
        silence tells nothing new, so the probe waits no longer than a command to such a servo does
        (``Timing.SILENT``).  Before anything has answered the stream's probe waits the whole allowance (only
        that is known to cover this link), and the close waited it out.  A reply that still comes is held off as
        after any stream transaction that gave up early (see _hold)."""
        if self._settling:
            return  # its reply is in
        nbytes = len(self._tx) + self._expect - self._echo_len
        wait = self.answers.silent_allowance(self._base, self._wire_time(nbytes))
        deadline = self._t_start + wait + self.link.extra
        if deadline < self.deadline:
            self.deadline = deadline
            self._short = True

    def kick(self, now: float) -> bytes | None:
        """The source has work again (new targets, or it was just attached)."""
        return self._start_next(now) if self.state is IDLE else None

    # ------------------------------------------------------------------ bursts

    def plan_burst(self, limit: int = BURST_LIMIT) -> tuple[float, list[PlannedTransaction], list[int]] | None:
        """The transactions a burst executor may run from the one just put on the wire, or None.

        A burst is the source's transaction on the wire (returned by the last call) followed by
        the source's next ones, as far as the sharing rule lets the source keep the line (to the
        end of its cycle, or of later cycles where the source knows them; not past a boundary where
        a queued request would go instead), at most ``limit`` in all.  Returned with the plan: its
        first transaction's deadline, and the entries after which the source has news for its
        program (a frame), where the driver should feed the engine without waiting for the burst's
        end.  Each entry is ``(tx, expect, echo, allowance, shape)``: the bytes to write, how many
        come back (echo included), how many of them are the echo, the seconds from the
        transaction's start (when the previous one's last byte came) to its deadline, and the shape
        of a reply the source takes (see :data:`.source.Upcoming`).  The executor stops after a
        reply not of that shape, as the source refuses it and the line then goes as it would
        without a burst; a transaction whose source gives no shape ends the plan.

        Only while the line is in step (no reply owed or held back, no slow-link allowance
        learnt, nothing received yet of the transaction on the wire): after a fault the ordinary
        path runs until a late reply can no longer come.  A transaction's wait is the one the
        engine would give it; where the stream's wait may be recomputed before it (see
        :mod:`.probe`), the least it can become: the executor then gives up no later than the
        engine would, and the engine waits on for the rest.  The
        source keeps the planned transactions as they are until :meth:`burst_over`, and they go
        first: a request queued meanwhile (or one the source's stop would let through) waits for it.

        The executor runs the plan, stops at the first transaction that is late, short, not
        echoed as sent or answered out of shape, or at a boundary when woken; the driver then
        feeds every byte through :meth:`receive` (and the deadline through :meth:`tick`) with the
        times they came, so the engine judges them exactly as if they had come one by one.
        """
        source = self._source
        if (
            self.state is not BUSY
            or self._current is not None
            or source is None
            or self._owner is not source
            or self._buf
            or self.link.extra
            or self.link.owed_since != INF
            or self.guard.unheard
            or self._tail_until > self._t_start
        ):
            return None
        if self._held and max(self._held.values()) > self._t_start:
            # A late reply may still land in any transaction (see _hold); and a hold just over leaves the first
            # command after it to _skip_held and _begin (the guard read after a hold), which a plan would pass by.
            return None
        queue = self.queue
        if queue.count and self._request_goes(queue.peek(), self._t_start, note=False):
            return None  # a request takes the line at the next boundary
        upcoming = source.upcoming(limit)
        if not upcoming or upcoming[0][0] != self._tx:
            source.upcoming_done()
            return None  # (the source no longer plans what is on the wire: never expected)
        plan: list[PlannedTransaction] = [
            (self._tx, self._expect, self._echo_len, self.deadline - self._t_start, upcoming[0][3])
        ]
        news = [0] if upcoming[0][4] else []
        echo = self.echo
        latency = self.answers.stream_latency
        steady = self.answers.answers_before_change()
        waits: dict[tuple[int, bool], float] = {}  # (a stream's transactions are all alike: computed once)
        for j in range(1, len(upcoming)):
            if not plan[-1][4]:
                break  # a reply of no shape may only end a burst: the source may refuse it
            tx, reply_len, _sid, shape, has_news = upcoming[j]
            nbytes = len(tx) + reply_len
            learnt = j < steady  # (after that, the learnt wait may be recomputed: the least it can become)
            allowance = waits.get((nbytes, learnt))
            if allowance is None:
                full = self._allowances.get(nbytes)
                if full is None:
                    full = self._allowance(nbytes, NORMAL)
                allowance = self._stream_wait(nbytes, full, latency if learnt else STREAM_WAIT_FLOOR)
                waits[nbytes, learnt] = allowance
            echo_len = len(tx) if echo else 0
            plan.append((tx, echo_len + reply_len, echo_len, allowance, shape))
            if has_news:
                news.append(j)
        self._planned = True
        return self.deadline, plan, news

    def would_take(self, request: Request, now: float) -> bool:
        """Would ``request``, queued now, get the line at the next transaction boundary, before the
        source's next transaction?  (What a driver asks of a request that arrives during a burst:
        if so, it wakes the burst, which stops at that boundary.)"""
        head = self.queue.peek()
        if head is None or request.priority < head.priority:
            head = request
        return self._source is None or self._request_goes(head, now, note=False)

    def burst_over(self) -> None:
        """The burst's bytes are fed up to its last transaction: the source may change its plan again.

        Called before the last transaction's bytes are fed, so that what goes on the line next
        is what the source wants now.
        """
        self._planned = False
        if self._source is not None:
            self._source.upcoming_done()

    # ------------------------------------------------------------------ the line talking

    def receive(self, data: bytes, now: float) -> bytes | None:
        state = self.state
        if state is BUSY or state is DRAINING:
            buf = self._buf
            if not buf:
                self._t_first = now
            buf += data
            if len(buf) >= self._expect:
                if self._tail_until > now and len(buf) - len(data) > self._echo_len and not self._settling:
                    self._settle(now)
                    return None
                return self._finish(now)
        elif state is QUIET:
            self.counters.stray += len(data)
            if self.link.owed > 0:  # the reply that just timed out may be coming late (see .link)
                self.link.stray(data, now)
            self._quiet_until = now + self._quiet_span + self.link.extra
            self.deadline = min(self._quiet_until, self._resync_limit)
        elif state is IDLE:
            # Bytes on an idle line: a late reply or noise.  Let it settle first.
            self.counters.stray += len(data)
            if self.debug:
                log.debug("stray bytes on idle line: %s", data.hex(" "))
            self._resync(now)
        return None

    def written(self, now: float) -> None:
        """The driver wrote the bytes the engine last answered with at ``now``.  Later than the time the engine was
        given when it answered, where the program held the driver up in between (the stream's warning through a
        slow log handler as it planned its next transaction, another thread holding the interpreter): the
        transaction's allowance counts from the write, or a servo that answered at once after it was judged silent
        for the program's delay."""
        if self.state is BUSY and now > self._t_start:
            self.deadline += now - self._t_start
            self._t_start = now

    def receive_planned(
        self, records: list[tuple[bytes, float, float]], count: int, plan: list[PlannedTransaction], first: int
    ) -> tuple[int, bytes | None]:
        """Feed a burst executor's first ``count`` records, each the bytes of one transaction of ``plan`` from
        entry ``first`` on and when its first and last bytes came, through :meth:`receive` one by one (at the
        time its last byte came), as long as the engine answers each with the plan's next transaction (the
        one the executor then wrote).  Returns how many were fed and the engine's answer to the last of them:
        fewer than ``count`` where it answered otherwise.  None of them may be the plan's last (its answer is
        the driver's to write).  The same as a loop over :meth:`receive` in the driver, in one call: with the
        engine compiled, without CPython's cost a transaction."""
        out = None
        for j in range(count):
            data, _first, at = records[j]
            out = self.receive(data, at) if data else None
            if out != plan[first + j + 1][0]:
                return j + 1, out
        return count, out

    def input_dropped(self, count: int) -> None:
        """The driver, told to drop the port's input as a resync ended (:class:`FlushInput`), found
        ``count`` bytes there unread: bytes of no transaction (a late reply that came as the resync
        ended), counted as stray so that nothing that came leaves no trace."""
        self.counters.stray += count
        if self.debug:
            log.debug("%d byte(s) dropped as a resync ended", count)

    def line_error(self, count: int) -> None:
        """The port saw ``count`` bytes arrive with parity or framing errors."""
        self.counters.line_errors += count
        if self.state is BUSY or self.state is DRAINING:
            self._corrupted = True  # the transaction fails once its bytes are all in

    def tick(self, now: float) -> Output:
        """Time has passed: a deadline, the end of a resync, or the source's wake-up.

        A driver calls this only once input that arrived before ``now`` has
        been fed through :meth:`receive` (after a stalled loop, a reply may be
        waiting behind the timer).
        """
        if now < self.deadline:
            return None
        state = self.state
        if state is BUSY or state is DRAINING:
            return self._timeout(now)
        if state is QUIET:
            if now < self._quiet_until and now < self._resync_limit:
                self.deadline = min(self._quiet_until, self._resync_limit)
                return None
            if now < self._quiet_until:
                log.warning("line never went quiet; carrying on")
            self.link.resync_over()
            self.state = IDLE
            return FlushInput(self._start_next(now))
        if state is IDLE:
            return self._start_next(now)
        return None

    # ------------------------------------------------------------------ transactions

    def _start_next(self, now: float) -> bytes | None:
        """Put the next transaction on the wire, if any.  Only when IDLE.

        Who goes first (see :mod:`ics35_async.engine`, "sharing the line"): without a stream,
        requests in priority order.  Beside a stream without a rate, at most
        ``max_requests_between`` requests between two of its transactions.  Beside a stream with
        a rate (a deadline), its cycle's transactions first; requests in the slack between
        cycles, each only if it is expected to finish before the next cycle is due (its wire
        time plus what answers on this line usually take); ``URGENT`` requests outrank the stream; and a request
        too long for the slack it was passed over in still goes after the next cycle (it delays
        that one cycle rather than waiting forever), as does one beside a stream that runs late
        (no slack at all: each overdue slot counts as one it was passed over in).
        """
        if self._going_offline:  # (asked while busy: see disconnected)
            self._going_offline = False
            self.state, self.deadline = OFFLINE, INF
            return None
        source = self._source
        queue = self.queue
        self._hold_wake = INF  # when a request or offer kept back by a hold may go (see _hold)
        # (While a burst runs, the boundaries up to its last are the planned transactions': the
        # executor has sent them, even if the source stopped meanwhile.  Requests queued then wait.)
        if queue.count and not self._planned and self._request_goes(queue.peek(), now, note=True):
            out = self._begin_request(now)
            if out is not None:
                return out
        self._in_row = 0
        if source is not None:
            job = source.next_transaction(now)
            if job is not None and self._held:
                job = self._skip_held(source, job, now)
            if job is not None:
                self._owner = source
                return self._begin(job[0], job[1], job[2], None, NORMAL, now)
            if queue.count:
                # The source has nothing now (between slots, every ID held or offline): a request
                # may take the time, by the same rule as above, judged against the next slot.
                due = source.slot_due(now)
                if due is None or self._fits_before(queue.peek(), due, now, note=True):
                    out = self._begin_request(now)
                    if out is not None:
                        return out
            self.deadline = source.wake_at
        else:
            self.deadline = INF
        if self._held:
            held = self._held
            for first in [b for b, until in held.items() if until <= now]:
                del held[first]
            if self._hold_wake < self.deadline:
                self.deadline = self._hold_wake
        return None

    def _skip_held(
        self, source: BackgroundSource, job: tuple[bytes, int, int], now: float
    ) -> tuple[bytes, int, int] | None:
        """The source's offer, or the next one it makes, that no hold keeps off the wire (None: none now).

        A held offer is skipped (the source moves on without counting a failure); an offer the
        source comes back to within this call is left pending, offered again once its hold ends.
        An offer whose hold is over but no command has gone since is skipped too, once: as the first
        command after the hold it would need a guard read before it (see _guard_after_holds), a whole
        transaction a cycle with a full allowance should its reply be lost; another servo's transaction
        going first instead is where a reply later than the hold lands, and its header does not fit
        there.  Only when the source has nothing else does the offer go, with its guard read.
        """
        held = self._held
        skipped: set[int] = set()
        offer: tuple[bytes, int, int] | None = job
        while offer is not None:
            first = offer[0][0]
            until = held.get(first)
            if until is None:
                return offer
            if until <= now and (first in skipped or first not in self._guard_after_hold):
                del held[first]
                return offer
            if first in skipped:
                self._hold_wake = min(self._hold_wake, until)
                return None
            skipped.add(first)
            self.counters.held_back += 1
            source.skip(now)
            offer = source.next_transaction(now)
        return None

    def _begin_request(self, now: float) -> bytes | None:
        """Put the queue's next request on the wire; None if only abandoned ones were left."""
        if self._held:  # a request whose reply a held one could pass for waits for the hold to end
            head = self.queue.peek()
            # (but a command to a servo already found silent: as for the guard read, see _begin)
            until = 0.0 if head is None or head.command.timing is SILENT else self._held.get(head.command.tx[0], 0.0)
            if until > now:
                self._hold_wake = min(self._hold_wake, until)
                return None
        req = self.queue.pop()
        if req is None:
            return None
        self._in_row += 1
        self._passed_over_head = None  # the next head starts its own count
        cmd = req.command
        return self._begin(cmd.tx, cmd.reply_len, cmd.servo_id, req, cmd.timing, now)

    def _request_goes(self, head: Request | None, now: float, *, note: bool) -> bool:
        """Does ``head`` (the queue's next request) go before the source's next transaction at ``now``?"""
        source = self._source
        due = None if source is None else source.slot_due(now)
        if due is None:
            return source is None or self._in_row < self.max_requests_between
        return self._fits_before(head, due, now, note=note)

    def _fits_before(self, head: Request | None, due: float, now: float, *, note: bool) -> bool:
        """May ``head`` go now, beside a stream whose next transaction is due at ``due``?

        ``note``: this is the engine's decision, so a request too long for this slack is counted
        as passed over in it (not when only asked, as :meth:`would_take` does).
        """
        if head is None:
            return True  # only abandoned requests: pop() drops them
        if head.priority == URGENT:
            return True
        if due == now:  # a cycle runs: its transactions go first
            return False
        if due < now:
            # The source runs late (its cycles take longer than its period): there is no slack, and
            # none will come.  Each overdue slot counts as one the request was passed over in, so it
            # still goes within two cycles (below) rather than never.
            return self._passed_over_in(head, due, note)
        cmd = head.command
        beyond_wire = self.answers.expected
        if beyond_wire < 0:  # nothing answered yet on this port: expect the full allowance
            expected = self._allowance(len(cmd.tx) + cmd.reply_len, cmd.timing)
        else:
            expected = wire_time(len(cmd.tx) + cmd.reply_len, self.baudrate) + beyond_wire + FIT_MARGIN
        if now + expected <= due:
            return True
        # Too long for this slack.
        return self._passed_over_in(head, due, note)

    def _passed_over_in(self, head: Request, due: float, note: bool) -> bool:
        """``head`` does not fit in the slack before ``due``: passed over in two slacks, it goes now
        (delaying the next cycle once), rather than waiting forever for a slack it can never fit in.
        Only its own count: a request that comes to the head (the one before it went, was cancelled,
        or was outranked) starts from none.  ``note``: count this slack (the engine's decision, not a
        question)."""
        passed = self._passed_over if self._passed_over_head is head else 0
        if self._passed_over_due != due or self._passed_over_head is not head:
            passed += 1
        if note:
            self._passed_over_head, self._passed_over_due, self._passed_over = head, due, passed
        return passed >= 2

    def _begin(
        self, tx: bytes, reply_len: int, servo_id: int | None, req: Request | None, timing: Timing, now: float
    ) -> bytes:
        # A reply may still come (see .guard).  A command to a servo already found silent goes without the guard
        # read, which would wait a whole allowance: its own reply would only confirm it, so a late one passing for
        # it misleads nobody; the suspicion stays for the command after it.
        if self._guard_after_hold:
            self._guard_after_holds(now)
        rule = self.guard
        if (rule.suspect or rule.unheard) and timing is not SILENT and (req is None or not req.is_guard):
            guard = rule.before(tx, servo_id)
            if guard is not None:  # a read of another shape first (see .guard)
                if req is not None:
                    self.queue.push_front(req)
                self.counters.guards += 1
                return self._begin(guard.tx, guard.reply_len, servo_id, GuardRequest(guard, req, tx), guard.timing, now)
        self.state = BUSY
        self._current = req
        self._current_id = sid = NO_ID if servo_id is None else servo_id
        if req is not None:
            if req.sent:  # a retry: counted as it goes (a try a guard read spent never went again)
                self.counters.per_name["retries"][sid] += 1
            req.sent = True
        self._tx = tx
        echo_len = len(tx) if self.echo else 0
        self._echo_len = echo_len
        self._expect = echo_len + reply_len
        self._buf.clear()
        self._corrupted = False
        self._settling = False
        self._t_start = now
        nbytes = len(tx) + reply_len
        allowance = self._allowances.get(nbytes) if timing is NORMAL else None
        if allowance is None:
            allowance = self._allowance(nbytes, timing)
        # The link's bookkeeping (lateness learnt, replies owed) is measured against the full
        # allowance; a probe only gives up sooner, since silence is its usual answer (see .probe).
        self._base = allowance
        self._short = timing is PROBE or timing is SILENT
        self._read_in_slack = False
        self._learnt_stream = False
        if timing is PROBE:
            allowance = self.answers.allowance(allowance, self._wire_time(nbytes))
        elif timing is SILENT:
            allowance = self.answers.silent_allowance(allowance, self._wire_time(nbytes))
        elif req is None or self._in_slack(req, timing, now):
            # The stream's transaction, or a read beside a paced stream: it waits what this line's answers
            # take, and a failure holds it back rather than the line (see _hold).
            self._read_in_slack = req is not None
            wait = self._stream_wait(nbytes, allowance, self.answers.stream_latency)
            if req is not None:
                wait = min(wait, self._slack_left(nbytes, now))
            if wait < allowance:
                self._short = True
                allowance = wait
            else:  # (the full allowance is the shorter: a small adapter_latency)
                self._learnt_stream = req is None and self.answers.stream_latency is not None
        self.deadline = now + allowance + self.link.extra
        return tx

    def _in_slack(self, req: Request, timing: Timing, now: float) -> bool:
        """Is ``req`` a read in a paced stream's slack, which waits and fails as the stream's transactions do?

        A read (nothing changes for it: giving up on its reply sooner, and asking again, does nothing to the
        servo) with the normal allowance, whose silence is not an answer (a scan's second look waits its whole
        allowance), below ``URGENT`` (which takes the line whatever the stream's slot), beside a stream that
        keeps a schedule: there a failure that waited its allowance and then a quiet time would run past the
        next slot.  Without a schedule there is no slot to keep, and the ordinary rule stands.
        """
        if timing is not NORMAL or req.priority == URGENT or req.is_guard:
            return False
        command = req.command
        source = self._source
        return (
            command.changes_nothing
            and command.silence is None
            and source is not None
            and source.slot_due(now) is not None
        )

    def _slack_left(self, nbytes: int, now: float) -> float:
        """How long a read in a paced stream's slack (see _in_slack) of ``nbytes`` waits at most: until the slot
        it was fitted before (see _fits_before).

        It fitted with its wire time, what this line's answers usually take and a margin, so by the slot its
        reply is overdue; waiting on would start the cycle later by what its wait has left.  A reply that still
        comes is held off as after the stream's own short wait (see _hold).  A read that went without fitting
        (passed over in two slots, or before anything answered) delays the cycle by design: no limit (inf).
        """
        source = self._source
        due = None if source is None else source.slot_due(now)
        beyond_wire = self.answers.expected
        if due is None or beyond_wire < 0 or now + (self._wire_time(nbytes) + beyond_wire + FIT_MARGIN) > due:
            return INF
        return due - now

    def _stream_wait(self, nbytes: int, allowance: float, latency: float | None) -> float:
        """How long a stream transaction of ``nbytes`` waits, given its full allowance.

        What this line's answers take beyond the wire time (``latency``, see .probe), not the
        adapter's worst case: a failure then costs the control loop little.  Its reply may still
        come later: see _hold.
        """
        if latency is None:
            return allowance
        return min(allowance, self._wire_time(nbytes) + latency)

    def _wire_time(self, nbytes: int) -> float:
        wire = self._wire.get(nbytes)
        if wire is None:
            wire = self._wire[nbytes] = wire_time(nbytes, self.baudrate)
        return wire

    def _allowance(self, nbytes: int, timing: Timing) -> float:
        allowance = self.timing.allowance(nbytes, self.baudrate, timing)
        if timing is NORMAL:
            self._allowances[nbytes] = allowance
        return allowance

    def _finish(self, now: float) -> bytes | None:
        buf = self._buf
        sid = self._current_id
        tx = self._tx
        counters = self.counters
        if self.debug:
            log.debug("id %s tx %s rx %s", sid, tx.hex(" "), buf.hex(" "))
        latency = (self._t_done if self._settling else now) - self._t_start
        counters.transactions[sid] += 1
        counters.bytes_tx[sid] += len(tx)
        counters.bytes_rx[sid] += len(buf)
        echo_len = self._echo_len
        if len(buf) != self._expect or (echo_len and not buf.startswith(tx)) or self._corrupted:
            counters.latency.add(latency)
            error = framing_error(self._current, sid, tx, buf, echo_len, self._expect, self._corrupted)
            link = self.link
            if link.owed_since != INF:
                link.judge(
                    buf, tx, echo_len, self._expect, self._t_first, self._t_start + self._base, self.guard.unheard
                )
            req = self._current
            due = self._due if self._settling else self.deadline
            echoed = self._note_what_came()
            out = self._failed(error, sid, now)
            self._after_early_failure(req, due, now)
            if not echoed and isinstance(req, GuardRequest):
                self._guard_proved_nothing(req, sid, now)
            return out
        over = latency - self._base  # before the next transaction replaces _base
        value = None  # a request's answer, handed over once everything is counted
        req = self._current
        self._current = None
        if req is None:
            # Only the source that sent the command hears its reply (it may have been
            # detached, and another attached, while the command was on the wire).
            source = self._owner if self._owner is self._source else None
            if source is None:  # its stream left mid-transaction: nobody judges these bytes, so
                counters.ok[sid] += 1  # let the line settle in case they were not its reply
                counters.latency.add(latency)
                self._resync(now)
                return None
            counters.ok[sid] += 1  # before the frame this ends is published (counted first, as below)
            rejected = source.complete(buf, echo_len, now)
            if rejected is not None:  # (complete changed nothing: the stream hears once it is counted)
                counters.ok[sid] -= 1
                counters.latency.add(latency)
                due = self._due if self._settling else self.deadline
                out = self._fault(rejected, sid, now)
                self._after_early_failure(None, due, now)
                source.fail(rejected, now, True)
                return out
            if over <= 0:  # (a reply later than the full allowance is a fault the link's extra caught, not a norm)
                self.answers.answered(latency - self._wire_time(len(tx) + self._expect - echo_len))
        else:
            try:
                value = req.command.parse(bytes(buf[echo_len:]))
            except ReplyError as exc:
                counters.latency.add(latency)
                due = self._due if self._settling else self.deadline
                out = self._fail_request(req, exc, sid, now)
                self._after_early_failure(req, due, now)
                return out
            name = req.command.name
            counters.by_command[name] = counters.by_command.get(name, 0) + 1
            self.answers.answered(latency - self._wire_time(len(tx) + self._expect - echo_len))
            # Counted before the caller hears (or the stream publishes a frame): under the thread
            # driver the caller runs on another thread and may read the statistics at once.
            counters.ok[sid] += 1
        hist = counters.latency  # LatencyHistogram.add, inline: this runs once per transaction
        hist.counts[int(latency * 1e6).bit_length()] += 1
        hist.sum_s += latency
        if latency > hist.max_s:
            hist.max_s = latency
        link = self.link
        if link.extra or link.owed_since != INF:
            if link.extra:
                link.succeeded(over)
            if link.owed_since != INF:
                link.in_step()  # a valid reply: nothing earlier is still owed
        if self.guard.unheard:
            self.guard.echo_came(tx, True)  # (its echo came first: see .guard)
        if req is not None:
            req.resolve(value)
        if self.state is BUSY:
            self.state = IDLE
            if req is not None and req.priority < LOW and self._source is not None and not self.queue.count:
                # The caller's next turn first (see "sharing the line"): a request it makes then goes before the
                # stream's next transaction, which the driver starts at this deadline otherwise.  (Not after a
                # LOW one: background reads, a safety watch's, slip in between the stream's transactions.)
                self.deadline = now
                return None
            return self._start_next(now)
        self.state, self.deadline = CLOSED, INF  # draining: that was the last transaction
        return None

    def _detach(self, exc: IcsError) -> None:
        source, self._source = self._source, None
        if source is not None:
            source.line_closed(exc)

    # What the engine does when a transaction fails: count it, tell its owner, retry, resync.
    # A timeout also feeds the guard read (see .guard) and the slow-link learning (see .link);
    # a probe's silence gets a short resync (see .probe).

    def _settle(self, now: float) -> None:
        """A reply came in more than one piece while a stream reply's tail may still come (see _hold).

        If that tail landed after this command's echo, it and the first bytes of this command's
        own reply could fill the reply's length and pass for it; the rest of the real reply is
        then right behind.  So the reply is taken only if nothing more arrives for the rest of a
        reply's wire time and a millisecond (one more USB frame).  Rare: only in pieces, and only
        while the servo of a failed stream transaction is held back (see _hold).
        """
        self._settling = True
        self._t_done = now
        self._due = self.deadline
        self.deadline = now + self._wire_time(self._expect - self._echo_len) + 0.001

    def _timeout(self, now: float) -> bytes | None:
        if self._settling:  # nothing more came: the reply is this command's own (see _settle)
            return self._finish(now)
        if self._short and len(self._buf) < self._echo_len:
            # A short wait (a stream transaction's, a read's in its slack, a probe's, a command's to a servo found
            # silent) is for silence after the echo: a servo that does not answer still echoes.  With the echo not
            # yet round, the host or the link is late (an FTDI adapter's latency timer holds echo and reply
            # together), and giving up would take a servo there for absent and fail whatever its bytes land in:
            # wait the full allowance.
            self._short = False
            full = self._full_deadline()
            if now < full:
                self.deadline = full
                return None
        buf, sid, tx, echo_len = self._buf, self._current_id, self._tx, self._echo_len
        if self.debug:  # logged as _finish logs one, so its failure (logged next) follows its own bytes
            log.debug("id %s tx %s rx %s", sid, tx.hex(" "), buf.hex(" "))
        self.counters.count(sid, len(tx), len(buf))
        error = timeout_error(self._current, sid, tx, buf, echo_len, self._expect)
        req = self._current
        heard = not isinstance(error, EchoMismatch)  # the echo came, or as much of it as came matched
        partial = len(buf) > echo_len
        self.guard.timed_out(
            tx,
            heard=heard,
            was_guard=req is not None and req.is_guard,
            went_past=req is not None and req.command.timing is SILENT,
        )
        link, due = self.link, self._t_start + self._base
        if link.owed_since != INF:
            link.judge(buf, tx, echo_len, self._expect, self._t_first, due, self.guard.unheard)
        probe = self._short  # a probe: it waited less than the full allowance
        if heard and not probe:  # its reply is owed from its base deadline on (see .link)
            # (A probe's short wait says nothing of the link: its late reply must not raise the
            # allowance of every transaction; the scan treats it as a slow servo instead.)
            link.owe(due, tx, len(buf), echo_len, self._expect)
        read_in_slack, only_echo = self._read_in_slack, len(buf) == echo_len  # (before the resync clears buf)
        echoed = self._note_what_came()
        out = self._failed(error, sid, now)
        if not echoed and isinstance(req, GuardRequest):
            self._guard_proved_nothing(req, sid, now)
        if read_in_slack:
            # A read in a paced stream's slack timed out with its echo and nothing more: its servo is held back as a
            # stream transaction's is (a retry waits, the stream and other commands go on).  After a partial reply
            # (a tail has no header) or bytes not its own, it resyncs as after its whole wait.
            if heard and only_echo:
                self._hold(now)
            elif self.state is QUIET:  # (partial, or the echo wrong: the resync listens as after its whole wait)
                self._quiet_until = max(self._quiet_until, self._resync_end(self._full_deadline()))
                self.deadline = min(self._quiet_until, self._resync_limit)
        # (A learnt stream's transaction whose full allowance was shorter than its learnt wait, its echo heard: its
        # servo is held back as after a short wait, so the line need not stay quiet a whole quiet_time.)
        elif req is None and (probe or (self._learnt_stream and heard)):
            self._hold(now)
            if partial:
                self._tail_until = self._held[tx[0]]  # see _settle
        elif probe and not partial:
            self._short_resync(now, self.answers.latency)  # silence at a probed ID (see .probe)
        if partial and self.state is State.QUIET and req is not None:
            # The rest may be on its way (a link that holds a reply's tail): listen for it as
            # long again as the transaction's full allowance, so its arrival is seen and learnt.
            self._quiet_until = max(self._quiet_until, now + self._base)
            self.deadline = min(self._quiet_until, self._resync_limit)
        return out

    def _failed(self, error: ReplyError, sid: int, now: float) -> bytes | None:
        """Hand a failed transaction's error to its request, or to the source that sent it."""
        req, self._current = self._current, None
        if req is not None:
            return self._fail_request(req, error, sid, now)
        owner = self._owner if self._owner is self._source else None
        out = self._fault(error, sid, now)  # counted before the stream hears (it may publish a frame)
        if owner is not None:
            owner.fail(error, now, True)
        return out

    def _after_early_failure(self, req: Request | None, due: float, now: float) -> None:
        """A transaction failed on what came before its deadline (after the resync began).

        What came may not have been its reply at all (another command's late reply, noise), so
        its own may still come, as late as it could after a timeout.  A stream transaction that
        waited less than its full allowance, or its full allowance where that is shorter than its
        learnt wait, holds its servo back (see _hold); anything else gets the resync and the guard
        read a timeout would have: quiet until a quiet time after its deadline, then, if the next
        command has the same command byte (a retry), a guard read first (see .guard).
        """
        if req is None and (self._short or self._learnt_stream):
            self._hold(now)
            return
        if self.state is not QUIET:
            return
        if self._read_in_slack:  # (it may have waited less than its full allowance: its reply may come after that)
            due = max(due, self._full_deadline())
        self.guard.timed_out(
            self._tx,
            heard=True,
            was_guard=req is not None and req.is_guard,
            went_past=req is not None and req.command.timing is SILENT,
        )
        self._quiet_until = max(self._quiet_until, self._resync_end(due))
        self._resync_limit = max(self._resync_limit, self._resync_give_up(due))
        self.deadline = min(self._quiet_until, self._resync_limit)

    def _hold(self, now: float) -> None:
        """A stream transaction that waited less than its full allowance, or its full allowance where that is
        shorter than the stream's learnt wait (a small adapter_latency), failed (after the resync began); or a
        read in a paced stream's slack timed out with its echo and nothing more (see _in_slack).

        Its reply may still come, as late as a timeout at its full deadline would still listen for
        it: that deadline (the full allowance and the link's extra), then the resync's quiet time
        and the extra again.  Until then no command with its first byte (its command and ID) goes on
        the wire: the stream skips that servo, and a request to it waits.  A reply from it landing
        in another command's transaction cannot pass for that one's answer (another ID or command
        in its header), so it costs a failure there, never a value taken for another; and the
        resync after this failure can be as short as a probe's (see .probe).  One later still, after
        the hold, is what a guard read is for after a timeout's resync (see .guard): the first command
        after the hold gets one if it has the held first byte (see _guard_after_holds; the stream's own
        transaction is skipped once more instead while it has another: see _skip_held); a command with
        that byte, going right after the hold, would take such a reply for its own (on a line without
        echo at once, on one with echo when it comes after the command's echo).  The tail of a
        partial reply has no header to tell it by: see _settle.
        """
        first = self._tx[0]
        self._held[first] = until = self._resync_end(self._full_deadline())
        self._guard_after_hold[first] = until
        self._short_resync(now, STREAM_RESYNC)

    def _guard_after_holds(self, now: float) -> None:
        """Holds (see _hold) over by ``now``: the next command is the first after them, and gets a guard read
        if it has such a hold's first byte (the suspicion lasts that one command)."""
        after = self._guard_after_hold
        for first in [first for first, until in after.items() if until <= now]:
            del after[first]
            self.guard.suspect = (*self.guard.suspect, bytes((first,)))

    def _note_what_came(self) -> bool:
        """Tell the guard rule what came back for the failing transaction (see .guard), and whether its own echo
        did (always, on a line without echo).  Nothing at all, on a line with echo: a command whose echo never
        came.  Its own echo (first, or behind bytes that were on their way): its echo came.  Other bytes only (a
        damaged echo, another command's late bytes, a servo that answers without echo): nothing told, the rules
        for those hold (see .link and _after_early_failure)."""
        if not self._echo_len:
            return True
        tx, buf = self._tx, self._buf
        if not buf:
            self.guard.echo_came(tx, False)
            return False
        if echo_offset(buf, tx, 0) < 0:
            return False
        if self.guard.unheard:
            self.guard.echo_came(tx, True)
        return True

    def _guard_proved_nothing(self, guard: GuardRequest, sid: int, now: float) -> None:
        """A guard read got no echo of its own back (nothing at all, or only bytes not its own: a servo of another
        ID answering without echo or garbled), and the command it went before is one that got nothing either (see
        .guard): it would only get another guard read, and another, on a line that answers nothing (or nothing
        of its own), and nothing it got clears that command.  So the guard counts as one of that command's tries:
        a request loses a retry, or fails as a try that got nothing back would (taken off the queue: nothing else
        may end it); the source's transaction fails so."""
        protected, tx = guard.protects, guard.protected_tx
        if tx not in self.guard.unheard:
            return  # (a guard for a late reply alone: the command goes next, as it would have)
        nothing = timeout_error(protected, sid, tx, bytearray(), len(tx), 0)
        if protected is not None and protected.abandoned():
            return  # (its caller gave up: the queue drops it)
        if protected is None:
            owner = self._owner if self._owner is self._source else None
            if owner is not None:
                owner.fail(nothing, now, False)  # (its offer never went: its frame says so)
        elif protected.retries_left > 0:
            protected.retries_left -= 1  # (no retry counted: the command did not go again, see _begin)
        elif self.queue.remove(protected):
            protected.reject(nothing)

    def _full_deadline(self) -> float:
        """The transaction's deadline with its full allowance (and the link's extra), whatever it waited."""
        return self._t_start + self._base + self.link.extra

    def _resync_end(self, deadline: float) -> float:
        """How long the resync after a timeout at ``deadline`` listens for the late reply (see .link)."""
        return deadline + self.timing.quiet_time + self.link.extra

    def _resync_give_up(self, start: float) -> float:
        """When a resync from ``start`` uses the line anyway, quiet or not (a line that never goes quiet)."""
        return start + self.timing.max_resync + self.link.extra

    def _short_resync(self, now: float, latency: float | None) -> None:
        if self.state is QUIET and latency is not None:
            self._quiet_span = min(self._quiet_span, latency)
            self._quiet_until = min(self._quiet_until, now + latency + self.link.extra)
            self.deadline = self._quiet_until

    def _fault(self, error: ReplyError, sid: int, now: float) -> bytes | None:
        self.counters.per_name[error_counter(error)][sid] += 1
        if self.port is None:
            fault_log.debug("%s", error)
        else:
            fault_log.debug("%s: %s", self.port, error)
        self._resync(now)
        return None

    def _fail_request(self, req: Request, error: ReplyError, sid: int, now: float) -> bytes | None:
        closing = self.state is State.DRAINING
        if req.retries_left > 0 and not req.abandoned() and not closing:
            req.retries_left -= 1
            self.queue.push_front(req)
            return self._fault(error, sid, now)
        out = self._fault(error, sid, now)  # counted before the caller hears, as a success is
        req.reject(BusClosed("bus closed") if closing and req.retries_left else error)
        return out

    def _resync(self, now: float) -> None:
        if self.state is State.DRAINING:  # closing anyway: the port's buffers go with it
            self.state = State.CLOSED
            self.deadline = INF
            return
        self.counters.resyncs += 1
        self.state = State.QUIET
        self._quiet_span = self.timing.quiet_time  # the silence that ends it (a short wait's fault: less)
        self._quiet_until = self._resync_end(now)
        self._resync_limit = self._resync_give_up(now)
        self._buf.clear()
        self.deadline = self._quiet_until
