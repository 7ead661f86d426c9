"""The line's side of a diagnosis: each answering servo's round trip, the latency timer it points to,
and the cycle rate to expect now and after each fix.

Measured with temperature reads (2 bytes out, 3 back: close to a position
command's 3 and 3, and they neither move nor free a servo), one servo after
another as a cycle runs.  A USB adapter's latency timer shows in the times:
a host that waits for each reply locks onto the timer, so round trips sit
near one timer period (16 ms, FTDI's default; 8 ms on some drivers) whatever
the wire needs.  Where the system shows the timer (Linux sysfs) the caller
passes it in; elsewhere (macOS, Windows, a remote bridge) the times alone
say it.
"""

from __future__ import annotations

import statistics
import time
from dataclasses import dataclass, field
from typing import Any

from ..bus import Bus
from ..errors import ReplyError
from ..frames import percentile
from ..protocol import wire_time
from ..transports.platforms import latency_timer_advice
from ..transports.usb_timing import FtdiAdapter, adapter_cycle_time
from .findings import Finding

PROBE_TX, PROBE_REPLY = 2, 3  # a temperature read
POSITION_TX, POSITION_REPLY = 3, 3  # the transaction a control cycle repeats; the host also hears its own 3 (echo)
CYCLE_SERVOS = 32  # the figure users compare: a full line
SUSPECT_TIMERS_MS = (16, 8)
"""Latency timers round trips are compared with: FTDI's default, and the 8 ms some drivers and hosts set."""
SLOW_EXCESS = 3e-3
"""Round trips this much above the wire's need point to something holding bytes back."""
DEFAULT_BUDGET = 200
MIN_PER_SERVO = 5


async def measure_round_trips(
    bus: Bus, servo_ids: list[int], *, per_servo: int | None = None, budget: int = DEFAULT_BUDGET
) -> tuple[dict[int, list[float]], int]:
    """Round trips (seconds) of ``servo_ids``, round robin; and how many transactions failed.

    Without ``per_servo``: ``budget`` transactions in all, at least
    :data:`MIN_PER_SERVO` each (32 servos at 16 ms: about 3 s).

    Raises:
        PortLost, BusClosed: the port went away (an adapter pulled) or the bus closed while measuring.
    """
    count = per_servo or max(MIN_PER_SERVO, budget // max(1, len(servo_ids)))
    samples: dict[int, list[float]] = {i: [] for i in servo_ids}
    failed = 0
    servos = [(i, bus.servo(i)) for i in servo_ids]
    for _ in range(count):
        for servo_id, servo in servos:
            start = time.perf_counter()
            try:
                await servo.read_temperature()
            except ReplyError:
                # (only a reply that failed: a port lost or a bus closed ends the measurement with its own
                # error, not as reads that blame the wiring)
                failed += 1
                continue
            samples[servo_id].append(time.perf_counter() - start)
    return samples, failed


def suspect_latency_timer(round_trips: list[float], baudrate: int) -> int | None:
    """The latency timer (ms) the round trips point to, or None when nothing points to one."""
    if not round_trips:
        return None
    median = statistics.median(round_trips)
    if median - wire_time(PROBE_TX + PROBE_REPLY, baudrate) < SLOW_EXCESS:
        return None
    for timer_ms in SUSPECT_TIMERS_MS:
        period = timer_ms * 1e-3
        if abs(median - period) <= max(1.5e-3, 0.15 * period):
            return timer_ms
    return None


SIMULATED_TIMER_FIX = (
    "the simulator's adapter model takes its timer from the port: latency_timer=1 in the sim:// URL "
    "(ics35 sim --latency-timer 1 on a pty); on hardware, ics35 doctor --port PORT gives this system's fix"
)


@dataclass
class LineReport:
    """The measurement and what it means; times in seconds, shown in ms by :meth:`to_dict`."""

    baudrate: int
    samples: dict[int, list[float]]
    failed: int = 0
    system_latency_timer_ms: int | None = None
    platform: str = "linux"
    # A sim:// line: its latency timer is the adapter model's, set in the URL, not in this system's files.
    simulated: bool = False
    findings: list[Finding] = field(default_factory=list)

    @property
    def servo_ids(self) -> list[int]:
        return [i for i, s in self.samples.items() if s]

    @property
    def all_samples(self) -> list[float]:
        return [t for s in self.samples.values() for t in s]

    @property
    def median(self) -> float | None:
        return statistics.median(self.all_samples) if self.all_samples else None

    @property
    def p99(self) -> float | None:
        return percentile(sorted(self.all_samples), 99) if self.all_samples else None

    @property
    def suspected_timer_ms(self) -> int | None:
        # The timer the system shows is the one the adapter uses: round trips that look like a timer's beside a
        # timer of 1 ms are a busy machine's or a bridge's, and a timer above 1 ms counts even if they hide it.
        if self.system_latency_timer_ms is not None:
            return self.system_latency_timer_ms if self.system_latency_timer_ms > 1 else None
        return suspect_latency_timer(self.all_samples, self.baudrate)

    def position_round_trip(self) -> float | None:
        """Seconds a position command's round trip is expected to take, from the measured reads.

        A cycle sends position commands (3 bytes out, 3 back), not reads: the
        read's own wire time is taken out of its measured round trip (what is
        left is the servo's turnaround and the host's and adapter's delays) and
        the position command's put in.  Never shorter than the wire allows.
        """
        median = self.median
        if median is None:
            return None
        estimate = (
            median
            - wire_time(PROBE_TX + PROBE_REPLY, self.baudrate)
            + wire_time(POSITION_TX + POSITION_REPLY, self.baudrate)
        )
        return max(estimate, self._wire_cycle() / CYCLE_SERVOS)

    def _wire_cycle(self) -> float:
        return adapter_cycle_time(
            None, servos=CYCLE_SERVOS, baudrate=self.baudrate, tx_bytes=POSITION_TX, reply_bytes=POSITION_REPLY
        )

    def cycle_hz(self) -> dict[str, Any]:
        """Position-cycle rates: now (estimated from the measured reads), after setting the timer to 1 ms (the
        adapter model), and the wire's limit."""
        n = len(self.servo_ids)
        each = self.position_round_trip()
        rates: dict[str, Any] = {
            "servos": n,
            "now": round(1 / (n * each), 2) if n and each else None,
            "now_32": round(1 / (CYCLE_SERVOS * each), 2) if each else None,
            "after_fixes": [],
            "wire_limit_32": round(1 / self._wire_cycle(), 1),
        }
        if self.suspected_timer_ms is not None:
            fixed = FtdiAdapter(1)
            rates["after_fixes"].append(
                {
                    "fix": "latency timer 1 ms",
                    "cycle_hz": round(1 / adapter_cycle_time(fixed, servos=max(n, 1), baudrate=self.baudrate), 2),
                    "cycle_hz_32": round(
                        1 / adapter_cycle_time(FtdiAdapter(1), servos=CYCLE_SERVOS, baudrate=self.baudrate), 2
                    ),
                }
            )
        return rates

    def judge(self) -> list[Finding]:
        """The findings the measurement supports (also kept in :attr:`findings`)."""
        found: list[Finding] = []
        median, p99 = self.median, self.p99
        if median is None or p99 is None:
            return found
        timer = self.suspected_timer_ms
        rates = self.cycle_hz()
        # A timer the system shows has its own finding, with the fix for this port's tty (not always ttyUSB0);
        # the round trips may not show it at all, as the library asks the driver for low latency.
        system_timer = self.system_latency_timer_ms is not None and self.system_latency_timer_ms > 1
        if timer is not None and not system_timer:
            if self.simulated:
                fix = SIMULATED_TIMER_FIX
            else:
                fix = latency_timer_advice(self.platform)
                if self.platform.startswith("linux"):
                    fix += "  (or: ics35 udev --install)"
            after = rates["after_fixes"][0]["cycle_hz_32"]
            found.append(
                Finding(
                    "latency_timer",
                    "warning",
                    f"round trips of {median * 1e3:.1f} ms (p99 {p99 * 1e3:.1f} ms) sit at a {timer} ms USB latency "
                    f"timer: 32 servos would cycle at {rates['now_32']:.1f} Hz; with the timer at 1 ms, "
                    f"about {after:.0f} Hz",
                    fix,
                )
            )
        elif timer is None and median - wire_time(PROBE_TX + PROBE_REPLY, self.baudrate) >= SLOW_EXCESS:
            found.append(
                Finding(
                    "round_trip",
                    "warning",
                    f"round trips of {median * 1e3:.1f} ms are {(median - wire_time(5, self.baudrate)) * 1e3:.1f} ms "
                    "more than the wire needs, and no latency timer explains it: a network bridge, a slow adapter "
                    "or a busy machine",
                    "for a bridge: see its latency settings; otherwise try the adapter on another USB port",
                )
            )
        if self.failed:
            total = self.failed + len(self.all_samples)
            found.append(
                Finding(
                    "round_trip",
                    "warning",
                    f"{self.failed} of {total} reads failed while measuring",
                    "check the wiring and the servos' power; a garbled reply can mean two servos share one ID",
                )
            )
        self.findings = found
        return found

    def to_dict(self) -> dict[str, Any]:
        median, p99 = self.median, self.p99
        return {
            "baud": self.baudrate,
            "servos": self.servo_ids,
            "transactions": len(self.all_samples),
            "failed": self.failed,
            "round_trip_ms": {
                "median": None if median is None else round(median * 1e3, 3),
                "p99": None if p99 is None else round(p99 * 1e3, 3),
                "per_servo": {
                    str(i): {
                        "median": round(statistics.median(s) * 1e3, 3),
                        "p99": round(percentile(sorted(s), 99) * 1e3, 3),
                    }
                    for i, s in self.samples.items()
                    if s
                },
            },
            "latency_timer_suspected_ms": self.suspected_timer_ms,
            "cycle_hz": self.cycle_hz(),
        }
