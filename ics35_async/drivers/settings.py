"""What a driver needs to know about the line beyond the engine's own settings."""

from __future__ import annotations

from dataclasses import dataclass

# Seconds between reopen attempts after a loss, the last repeating: a returning adapter is found within a tenth of
# a second (a robot's stream back as soon), and a try at a missing port costs some 60 us, a refused TCP bridge
# about as little: no load worth backing off further for.
RECONNECT_BACKOFF = (0.05, 0.1)


@dataclass(frozen=True)
class LineSettings:
    transport: str = "auto"  # see ics35_async.transports.open_line
    direction: str = "none"  # RTS direction control: see ics35_async.transports.direction
    reconnect: bool = False
    reconnect_backoff: tuple[float, ...] = RECONNECT_BACKOFF
