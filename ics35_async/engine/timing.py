"""How long the engine waits: deadline and resync allowances."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TypedDict

from ..protocol import ADAPTER_LATENCY, Timing, wire_time
from ..units import check_seconds


@dataclass(frozen=True)
class BusTiming:
    """Deadline and resync allowances, in seconds.

    A transaction's deadline is its wire time ((TX + reply bytes) x 11 / baud)
    plus ``turnaround`` plus ``adapter_latency`` plus, for the EEPROM write and
    the ID command, their extra allowance, plus what the engine has learnt a
    slow link adds (never more than ``link_extra_max``).
    """

    turnaround: float = 0.0005
    adapter_latency: float = ADAPTER_LATENCY  # USB adapters add 0.1-16 ms (FTDI latency timer)
    eeprom_write: float = 0.200
    id_command: float = 0.050
    quiet_time: float = 0.010  # silence required before the next transaction after a fault
    max_resync: float = 0.5  # a line that never goes quiet is used anyway after this
    # The most a slow link's learnt lateness may add to a deadline (see engine.link): a dead servo
    # still times out within its allowance plus this.  0 turns the learning off.
    link_extra_max: float = 0.25

    def __post_init__(self) -> None:
        for name in (
            "turnaround",
            "adapter_latency",
            "eeprom_write",
            "id_command",
            "quiet_time",
            "max_resync",
            "link_extra_max",
        ):
            check_seconds(name, getattr(self, name))

    def allowance(self, nbytes: int, baudrate: int, kind: Timing = Timing.NORMAL, extra: float = 0.0) -> float:
        """Seconds from writing a command to the deadline for the last byte of its reply.

        ``nbytes``: command and reply bytes on the wire; ``baudrate``: the line rate; ``kind``: the
        command's timing class (the EEPROM write and the ID command get their extra allowance);
        ``extra`` is what the engine has learnt a slow link adds (see LinkLatency).
        """
        allowance = wire_time(nbytes, baudrate) + self.turnaround + self.adapter_latency + extra
        if kind is Timing.EEPROM_WRITE:
            allowance += self.eeprom_write
        elif kind is Timing.ID:
            allowance += self.id_command
        return allowance


class TimingOverrides(TypedDict, total=False):
    """:class:`BusTiming` fields as keyword arguments of ``open_bus`` (seconds each).

    Annotate a dict of overrides with it and a type checker catches a misspelt name:

    ```python
    fast: TimingOverrides = {"adapter_latency": 0.002, "quiet_time": 0.002}
    bus = await open_bus(port, **fast)
    ```
    """

    turnaround: float
    """Seconds a servo may take to start its reply after the command (default 0.0005)."""
    adapter_latency: float
    """Seconds the interface may add to a reply: USB adapters add 0.1-16 ms (default 0.020)."""
    eeprom_write: float
    """Extra seconds allowed for the EEPROM write's reply (default 0.200)."""
    id_command: float
    """Extra seconds allowed for the ID command's reply (default 0.050)."""
    quiet_time: float
    """Silence required on the line before the next transaction after a fault (default 0.010)."""
    max_resync: float
    """A line that never goes quiet is used anyway after this many seconds (default 0.5)."""
    link_extra_max: float
    """The most a slow link's learnt lateness may add to a deadline (default 0.25; 0 turns learning off)."""
