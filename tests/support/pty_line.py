"""A simulated line served on a pty by a thread of the test's own process: the test sees and changes its servos
(``line.sim``) while a program under test, in a process of its own, drives it through the pty as a serial port."""

from __future__ import annotations

import threading

from ics35_async.sim import VirtualLine, VirtualServo
from ics35_async.sim.pty_server import PtyServer


class PtyLine:
    """A simulated line served on a pty by a thread of this process."""

    def __init__(self, ids: tuple[int, ...], ics36: tuple[int, ...] = ()) -> None:
        self.sim = VirtualLine([VirtualServo(i, ics36=i in ics36) for i in ids])
        self.server = PtyServer(self.sim)
        self.path = str(self.server.open())
        self.thread = threading.Thread(target=self.server.serve, daemon=True)
        self.thread.start()

    def close(self) -> None:
        self.server.stop()
        self.thread.join(5)
        self.server.close()
        self.sim.close()
