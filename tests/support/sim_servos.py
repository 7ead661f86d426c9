"""Simulated servos that do something to their line at a chosen moment (for tests of a line lost part-way)."""

from __future__ import annotations

from typing import Any

from ics35_async.sim import VirtualLine, VirtualServo


class UnplugsWhenAsked(VirtualServo):
    """A servo whose line is pulled away as it hears a ``what`` command (a ``ReadParam``: a scan's probe; a
    ``ReadEeprom``: once the probes found every servo).  ``line`` is set once the line holds it (None: never)."""

    def __init__(self, servo_id: int, what: type, **options: Any) -> None:
        super().__init__(servo_id, **options)
        self.what = what
        self.line: VirtualLine | None = None

    def handle(self, command: Any) -> Any:
        if self.line is not None and isinstance(command, self.what):
            self.line.unplug()
        return super().handle(command)
