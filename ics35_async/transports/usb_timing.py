"""The USB serial adapter between host and line: when written bytes reach the wire, and received ones the host.

Kondo's ICS USB adapters are FTDI chips (FT232R).  What an FTDI chip does to
timing, as FTDI's application note AN232B-04 describes it:

* The host's bytes go out in USB transfers; a full-speed device is served in
  1 ms frames, so a write reaches the wire at the start of the next frame.
* Received bytes wait in the chip until 62 are buffered (a 64-byte USB packet
  less its 2 status bytes) or the latency timer runs out (16 ms by default,
  1..255 ms), whichever comes first.  The timer restarts whenever a packet
  goes to the host, and a host always polls, so it runs freely from the last
  packet (when the buffer is empty the chip sends status bytes only).

A host that waits for each reply before writing the next command therefore
locks onto the timer: every transaction takes about one latency period
(16 ms), or at 1 ms one frame out and one period back (about 2 ms).

:class:`FtdiAdapter` is sans-IO: :meth:`~FtdiAdapter.outbound` says when
bytes written at a time reach the wire; :meth:`~FtdiAdapter.inbound` turns
the line's chunks (each with the time its last byte arrived) into the USB
packets the host receives, with their times.  The simulator puts it between
its line and the host (``sim://?adapter=ftdi``); :func:`adapter_cycle_time`
uses it to predict what a cycle costs with an ideal host (``ics35 doctor``, ``make bench``).
"""

from __future__ import annotations

import math

from ..errors import InvalidArgument
from ..units import check_int

DEFAULT_LATENCY_TIMER_MS = 16
USB_FRAME = 1e-3
"""A USB full-speed frame: the chip is served once per frame."""
PACKET_PAYLOAD = 62
"""Data bytes in one 64-byte USB packet (2 bytes carry the modem status)."""

Chunks = list[tuple[float, bytes]]
"""Bytes in delivery order, each chunk with the time its last byte arrived (the simulated line's output too)."""

_EPS = 1e-9  # times within this of a frame start count as on it (float sums of byte times)


class FtdiAdapter:
    """An FTDI USB serial chip's timing (see the module text); ``latency_timer_ms`` is 1..255."""

    def __init__(self, latency_timer_ms: int = DEFAULT_LATENCY_TIMER_MS, *, frame: float = USB_FRAME) -> None:
        self.latency_timer_ms = check_int("latency_timer", latency_timer_ms, 1, 255)
        self.latency = self.latency_timer_ms * 1e-3
        self.frame = frame
        self._anchor = 0.0  # when the last packet went to the host: the timer runs from here

    def reset(self) -> None:
        """The adapter was unplugged: its timer starts afresh."""
        self._anchor = 0.0

    def _next_frame(self, t: float) -> float:
        return math.ceil(t / self.frame - _EPS) * self.frame

    def outbound(self, now: float) -> float:
        """When bytes the host writes at ``now`` start on the wire: the start of the next USB frame
        (a frame's transfers are scheduled before it starts, so even a write right at a frame start waits)."""
        return (math.floor(now / self.frame + _EPS) + 1) * self.frame

    def _next_tick(self, t: float) -> float:
        """The first moment, at or after ``t``, at which the latency timer runs out.

        Bytes that come in while a full packet waits for its frame join the
        next packet, whose timer starts when that one goes.
        """
        periods = math.ceil((t - self._anchor) / self.latency - _EPS) if t > self._anchor else 1
        return self._anchor + max(1, periods) * self.latency

    def inbound(self, chunks: Chunks, byte_time: float) -> Chunks:
        """The USB packets the host receives for the line's ``chunks``, in order, with their times.

        ``byte_time`` spaces the bytes of a chunk: its last byte arrives at the
        chunk's time, the ones before it one byte time apart.
        """
        out: Chunks = []
        buffered = bytearray()
        due = 0.0
        for when, chunk in chunks:
            n = len(chunk)
            for i, byte in enumerate(chunk):
                arrived = when - (n - 1 - i) * byte_time
                if buffered and arrived > due:
                    out.append((due, bytes(buffered)))
                    self._anchor = due
                    buffered.clear()
                if not buffered:
                    due = self._next_tick(arrived)
                buffered.append(byte)
                if len(buffered) == PACKET_PAYLOAD:
                    sent = self._next_frame(arrived)
                    out.append((sent, bytes(buffered)))
                    self._anchor = sent
                    buffered.clear()
        if buffered:
            out.append((due, bytes(buffered)))
            self._anchor = due
        return out

    def __repr__(self) -> str:
        return f"<FtdiAdapter latency_timer={self.latency_timer_ms} ms>"


def adapter_cycle_time(
    adapter: FtdiAdapter | None,
    *,
    servos: int,
    baudrate: int,
    tx_bytes: int = 3,
    reply_bytes: int = 3,
    turnaround: float = 100e-6,
    cycles: int = 8,
) -> float:
    """Seconds one cycle of ``servos`` transactions takes with an ideal host (it writes the moment a reply is whole).

    ``adapter=None`` gives the wire's own limit.  The figure is the mean of
    ``cycles`` cycles after one to settle (the timer's phase locks onto the host).
    """
    from ..protocol import BITS_PER_BYTE

    byte_time = BITS_PER_BYTE / baudrate
    if servos < 1:
        raise InvalidArgument("servos must be at least 1")
    t = 0.0
    start = 0.0
    for n in range((cycles + 1) * servos):
        if n == servos:
            start = t
        on_wire = adapter.outbound(t) if adapter is not None else t
        echo_end = on_wire + tx_bytes * byte_time
        reply_end = echo_end + turnaround + reply_bytes * byte_time
        chunks = [(echo_end, bytes(tx_bytes)), (reply_end, bytes(reply_bytes))]
        if adapter is not None:
            chunks = adapter.inbound(chunks, byte_time)
        t = chunks[-1][0]
    return (t - start) / cycles
