"""What the engine does when a transaction fails: count it, tell its owner, retry, resync.

A part of :class:`~.machine.LineEngine` kept in its own file: the engine
inherits these methods, and the attributes below are the engine's.  A
timeout also feeds the guard read (see .guard) and the slow-link learning
(see .link); a probe's silence gets a short resync (see .probe).
"""

from __future__ import annotations

import logging

from ..errors import BusClosed, EchoMismatch, ReplyError
from .counters import LineCounters, error_counter
from .guard import GuardRule
from .link import LinkLatency
from .outcome import timeout_error
from .probe import AnswerTimes
from .requests import Request, RequestQueue
from .source import BackgroundSource
from .state import State
from .timing import BusTiming

log = logging.getLogger("ics35_async")

INF = float("inf")


class FailureRules:
    """The failure half of the line's rules (mixed into LineEngine)."""

    state: State
    deadline: float
    timing: BusTiming
    counters: LineCounters
    link: LinkLatency
    guard: GuardRule
    answers: AnswerTimes
    queue: RequestQueue
    _source: BackgroundSource | None
    _owner: BackgroundSource | None
    _current: Request | None
    _current_id: int
    _buf: bytearray
    _tx: bytes
    _expect: int
    _echo_len: int
    _t_start: float
    _t_first: float
    _base: float
    _short: bool
    baudrate: int
    _quiet_until: float
    _quiet_span: float
    _resync_limit: float

    def _timeout(self, now: float) -> bytes | None:
        buf, sid, tx, echo_len = self._buf, self._current_id, self._tx, self._echo_len
        self.counters.count(sid, len(tx), len(buf))
        error = timeout_error(self._current, sid, tx, buf, echo_len, self._expect)
        req = self._current
        heard = not isinstance(error, EchoMismatch)  # the echo came, or as much of it as came matched
        partial = len(buf) > echo_len
        self.guard.timed_out(tx, heard=heard, was_guard=req is not None and req.is_guard)
        link, due = self.link, self._t_start + self._base
        if link.owed_since != INF:
            link.judge(buf, tx, echo_len, self._expect, self._t_first, due)
        probe = self._short  # a probe: it waited less than the full allowance
        if heard and not probe:  # its reply is owed from its base deadline on (see .link)
            # (A probe's short wait says nothing of the link: its late reply must not raise the
            # allowance of every transaction; the scan treats it as a slow servo instead.)
            link.owe(due, tx, len(buf), echo_len, self._expect)
        out = self._failed(error, sid, now)
        if probe and not partial and self.state is State.QUIET and self.answers.latency is not None:
            # Silence at a probed ID: a resync as short as the probe's own wait (see .probe).
            self._quiet_span = min(self._quiet_span, self.answers.latency)
            self._quiet_until = min(self._quiet_until, now + self.answers.latency + self.link.extra)
            self.deadline = self._quiet_until
        if partial and self.state is State.QUIET:
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
            owner.fail(error, now)
        return out

    def _fault(self, error: ReplyError, sid: int, now: float) -> bytes | None:
        self.counters.per_name[error_counter(error)][sid] += 1
        log.debug("%s", error)
        self._resync(now)
        return None

    def _fail_request(self, req: Request, error: ReplyError, sid: int, now: float) -> bytes | None:
        closing = self.state is State.DRAINING
        if req.retries_left > 0 and not req.abandoned() and not closing:
            req.retries_left -= 1
            self.counters.per_name["retries"][sid] += 1
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
        self._quiet_until = now + self.timing.quiet_time + self.link.extra
        self._resync_limit = now + self.timing.max_resync + self.link.extra
        self._buf.clear()
        self.deadline = self._quiet_until
