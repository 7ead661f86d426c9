"""The USB adapter models a simulated line can put between itself and the host (``adapter=`` in sim:// URLs).

The timing model itself is :class:`~ics35_async.transports.usb_timing.FtdiAdapter`
(real adapters' behaviour, also used to predict cycle rates); here it is
chosen by name.
"""

from __future__ import annotations

from ..errors import InvalidArgument
from ..transports.usb_timing import DEFAULT_LATENCY_TIMER_MS, PACKET_PAYLOAD, FtdiAdapter, adapter_cycle_time

ADAPTER_KINDS = ("ftdi",)


def make_adapter(kind: str | None, latency_timer_ms: int | None = None) -> FtdiAdapter | None:
    """The adapter model ``kind`` names (``None``: the line reaches the host directly)."""
    if kind is None:
        if latency_timer_ms is not None:
            raise InvalidArgument(
                "a latency timer needs an adapter model: adapter=ftdi in a sim:// URL, --adapter ftdi for ics35 sim"
            )
        return None
    if kind.strip().lower() not in ADAPTER_KINDS:
        raise InvalidArgument(f"unknown adapter model {kind!r} (known: {', '.join(ADAPTER_KINDS)})")
    return FtdiAdapter(DEFAULT_LATENCY_TIMER_MS if latency_timer_ms is None else latency_timer_ms)


__all__ = [
    "ADAPTER_KINDS",
    "DEFAULT_LATENCY_TIMER_MS",
    "PACKET_PAYLOAD",
    "FtdiAdapter",
    "adapter_cycle_time",
    "make_adapter",
]
