"""Counters and a latency histogram for the bus, cheap enough for the hot path."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

# Log2-spaced latency buckets of microseconds: bucket k holds [2^(k-1), 2^k) us, bucket 0 under 1 us.
# Indexed by int(us).bit_length(), which needs no clamp below 2^63 us (the engine inlines this).
_BUCKETS = 64


class LatencyHistogram:
    """Transaction latency (write to complete reply) in log2 buckets of microseconds."""

    __slots__ = ("counts", "max_s", "sum_s")

    def __init__(self) -> None:
        self.counts = [0] * _BUCKETS
        self.sum_s = 0.0
        self.max_s = 0.0

    def add(self, seconds: float) -> None:
        self.counts[int(seconds * 1e6).bit_length()] += 1
        self.sum_s += seconds
        if seconds > self.max_s:
            self.max_s = seconds

    @property
    def total(self) -> int:
        return sum(self.counts)

    def copy(self) -> LatencyHistogram:
        other = LatencyHistogram()
        other.counts = list(self.counts)
        other.sum_s, other.max_s = self.sum_s, self.max_s
        return other

    def percentile(self, p: float) -> float:
        """Upper edge (seconds) of the bucket holding the ``p``-th percentile; 0 when empty."""
        total = self.total
        if not total:
            return 0.0
        rank = math.ceil(total * p / 100)
        seen = 0
        for k, n in enumerate(self.counts):
            seen += n
            if seen >= rank:
                return min(2.0**k * 1e-6, self.max_s)
        return self.max_s

    @property
    def mean(self) -> float:
        total = self.total
        return self.sum_s / total if total else 0.0

    def __repr__(self) -> str:  # (printed inside BusStats: a program prints bus.stats)
        ms = {"mean": self.mean, "p50": self.percentile(50), "p99": self.percentile(99), "max": self.max_s}
        return f"LatencyHistogram(total={self.total}, {', '.join(f'{k}_ms={v * 1e3:.3f}' for k, v in ms.items())})"


@dataclass
class IdStats:
    """Counters of one ID (or of the whole bus): transactions, their outcomes, retries and bytes.

    A guard read (see ``BusStats.guards``) counts under the ID of the command it went before, also where, in a
    long stall, it reads another servo."""

    transactions: int = 0
    """Transactions written (a retry is one more)."""
    ok: int = 0
    """Transactions answered with a good reply."""
    timeouts: int = 0
    """Transactions with no reply by their deadline."""
    partial_replies: int = 0
    """Transactions whose reply stopped short."""
    echo_mismatches: int = 0
    """Transactions whose echo differed from the bytes sent (a collision or a damaged line)."""
    bad_replies: int = 0
    """Transactions whose reply was whole but wrong (header, length, checksum or value)."""
    retries: int = 0
    """Times an idempotent request's command went again after a failure (a try spent by a guard read that got no
    echo of its own back, on a line that had sent nothing back to the command either, is not one: the command did
    not go)."""
    bytes_tx: int = 0
    """Bytes written."""
    bytes_rx: int = 0
    """Bytes received."""

    @property
    def errors(self) -> int:
        return self.timeouts + self.partial_replies + self.echo_mismatches + self.bad_replies

    def add(self, other: IdStats) -> None:
        for name in COUNTER_NAMES:
            setattr(self, name, getattr(self, name) + getattr(other, name))


# Names of the per-ID counters (the fields of IdStats; the bus keeps one list per name).
COUNTER_NAMES = tuple(f.name for f in fields(IdStats))


@dataclass
class BusStats:
    """A snapshot of ``bus.stats``: totals, per-ID counters and latency."""

    total: IdStats
    per_id: dict[int | None, IdStats]
    latency: LatencyHistogram
    resyncs: int
    stray_bytes: int
    line_errors: int  # bytes the serial port received with parity/framing errors
    guards: int  # harmless reads put between a timed-out command and its twin
    reconnects: int
    queued: int
    by_command: dict[str, int] = field(default_factory=dict)
    link_extra: float = 0.0  # seconds added to every deadline for a slow link (learnt; 0 on a fast link)
    late_replies: int = 0  # replies that arrived past their deadline and taught the bus so
    held_back: int = 0  # stream transactions skipped: their servo's reply to a failed command could still come

    def latency_percentiles(self) -> dict[str, float]:
        return {f"p{p}": self.latency.percentile(p) for p in (50, 90, 99)}
