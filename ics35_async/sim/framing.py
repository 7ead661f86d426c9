"""What the devices' receivers make of the host's bytes: whole commands, junk, a command still arriving.

Every device on the line hears the host's bytes as one stream.
:class:`CommandFramer` buffers that stream and cuts it into commands with the
library's codec; bytes no device understands (or any bytes at a rate that is
not an ICS rate) become one junk frame between commands.  Like a servo, it
forgets a half-received command after a pause (``frame_timeout``).  It also
remembers which buffered bytes were already echoed, so a command that
arrives in pieces echoes each byte once.
"""

from __future__ import annotations

from typing import Any

from ..eeprom import BaudRate
from ..protocol import decode_request

_ICS_BAUDS = frozenset(int(b) for b in BaudRate)

HostFrame = tuple[Any, bytes, int]
"""``(command, bytes, fresh)``: the decoded request (``None`` for junk), its
bytes, and how many of them (at the end) have not been echoed yet."""


class CommandFramer:
    """The host-to-device half of the line: a receive buffer cut into frames."""

    def __init__(self, frame_timeout: float) -> None:
        self.frame_timeout = frame_timeout
        self._rx = bytearray()
        self._echoed = 0  # bytes at the start of _rx already echoed (a command in flight)
        self._time = 0.0

    def reset(self) -> None:
        """Forget a half-received command."""
        self._rx.clear()
        self._echoed = 0

    def feed(self, data: bytes, now: float, baudrate: int) -> tuple[list[HostFrame], bytes]:
        """The frames ``data`` (written at ``now``) completes, and the fresh bytes of a command still arriving.

        Those last bytes count as echoed from now on.
        """
        if self._rx and now - self._time > self.frame_timeout:
            self.reset()  # a servo forgets a half-received command after a pause
        self._time = now
        rx = self._rx
        rx += data
        ics_baud = baudrate in _ICS_BAUDS
        frames: list[HostFrame] = []
        junk = bytearray()
        junk_fresh = 0
        while rx:
            if ics_baud:
                framed = decode_request(rx, baudrate=baudrate)
                if framed is None:
                    break
                command, used = framed
            else:
                command, used = None, len(rx)  # no ICS device can make sense of this rate
            frame = bytes(rx[:used])
            fresh = max(0, used - self._echoed)
            del rx[:used]
            self._echoed = max(0, self._echoed - used)
            if command is None:
                junk += frame
                junk_fresh += fresh
                continue
            if junk:
                frames.append((None, bytes(junk), junk_fresh))
                junk.clear()
                junk_fresh = 0
            frames.append((command, frame, fresh))
        if junk:
            frames.append((None, bytes(junk), junk_fresh))
        fresh = len(rx) - self._echoed
        if fresh <= 0:
            return frames, b""
        self._echoed = len(rx)
        return frames, bytes(rx[-fresh:])
