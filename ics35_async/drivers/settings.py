"""What a driver needs to know about the line beyond the engine's own settings."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class LineSettings:
    transport: str = "auto"  # see ics35_async.transports.open_line
    direction: str = "none"  # RTS direction control: see ics35_async.transports.direction
    reconnect: bool = False
    reconnect_backoff: tuple[float, ...] = (0.05, 0.1, 0.2, 0.4)
