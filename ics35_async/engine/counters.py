"""The engine's counters, and the :class:`~ics35_async.stats.BusStats` snapshot built from them."""

from __future__ import annotations

from ..errors import EchoMismatch, PartialReply, ReplyError, ReplyTimeout
from ..stats import COUNTER_NAMES, BusStats, IdStats, LatencyHistogram
from .link import LinkLatency

NO_ID = 32  # counter slot for the ID command, which addresses the whole line


def error_counter(error: ReplyError) -> str:
    """The per-ID counter a failed transaction adds to."""
    if isinstance(error, ReplyTimeout):
        return "timeouts"
    if isinstance(error, PartialReply):
        return "partial_replies"
    if isinstance(error, EchoMismatch):
        return "echo_mismatches"
    return "bad_replies"


class LineCounters:
    """Per-ID counters (a list per name, indexed by ID; slot 32 is the ID command) and line-wide ones."""

    def __init__(self) -> None:
        self.per_name: dict[str, list[int]] = {name: [0] * 33 for name in COUNTER_NAMES}
        # The hot path's counters, as direct references.
        self.transactions = self.per_name["transactions"]
        self.ok = self.per_name["ok"]
        self.bytes_tx = self.per_name["bytes_tx"]
        self.bytes_rx = self.per_name["bytes_rx"]
        self.latency = LatencyHistogram()
        self.resyncs = 0
        self.stray = 0
        self.line_errors = 0
        self.guards = 0
        self.held_back = 0  # stream transactions skipped (see LineEngine._hold)
        self.reconnects = 0
        self.by_command: dict[str, int] = {}
        self.link: LinkLatency | None = None  # the engine's, for the snapshot

    def count(self, sid: int, n_tx: int, n_rx: int) -> None:
        """One more transaction for ``sid`` (the hot path inlines this)."""
        self.transactions[sid] += 1
        self.bytes_tx[sid] += n_tx
        self.bytes_rx[sid] += n_rx

    def snapshot(self, queued: int) -> BusStats:
        per_id: dict[int | None, IdStats] = {}
        total = IdStats()
        for slot in range(33):
            values = {name: self.per_name[name][slot] for name in COUNTER_NAMES}
            if any(values.values()):
                s = IdStats(**values)
                per_id[None if slot == NO_ID else slot] = s
                total.add(s)
        return BusStats(
            total=total,
            per_id=per_id,
            latency=self.latency.copy(),
            resyncs=self.resyncs,
            stray_bytes=self.stray,
            line_errors=self.line_errors,
            guards=self.guards,
            reconnects=self.reconnects,
            queued=queued,
            by_command=dict(self.by_command),
            link_extra=self.link.extra if self.link is not None else 0.0,
            late_replies=self.link.late_replies if self.link is not None else 0,
            held_back=self.held_back,
        )
