"""Simulated servos that do something to their line at a chosen moment (for tests of a line lost part-way), or whose
replies go astray."""

from __future__ import annotations

import signal
from collections.abc import Callable
from typing import Any

from ics35_async.protocol import Param, Position, ReadParam, ReadPosition, WriteEeprom
from ics35_async.sim import VirtualLine, VirtualServo
from ics35_async.sim.virtual_servo import NO_REPLY


def free_command(command: Any) -> bool:
    """The free command (a position command with target 0)."""
    return isinstance(command, Position) and command.position == 0


class UnplugsWhenAsked(VirtualServo):
    """A servo whose line is pulled away as it hears a command: ``what`` is a command class (a ``ReadParam``: a
    scan's probe; a ``ReadEeprom``: once the probes found every servo) or a test of the command
    (:func:`free_command`).  It acts on the command, whose reply never gets back.  ``line`` is set once the line
    holds it (None: never).  With ``replug_after`` (seconds) the line comes back by itself, and the servo pulls it
    away only the first time."""

    def __init__(
        self, servo_id: int, what: type | Callable[[Any], bool], *, replug_after: float | None = None, **options: Any
    ) -> None:
        super().__init__(servo_id, **options)
        self.heard = what if not isinstance(what, type) else lambda command: isinstance(command, what)
        self.line: VirtualLine | None = None
        self.replug_after = replug_after

    def handle(self, command: Any) -> Any:
        if self.line is not None and self.heard(command):
            self.line.unplug(replug_after=self.replug_after)
            if self.replug_after is not None:
                self.line = None
        return super().handle(command)


class CtrlCWhenAsked(VirtualServo):
    """A servo at whose command ``what`` Ctrl-C is pressed (SIGINT to this process): the command still reaches it
    (it acts on it)."""

    def __init__(self, servo_id: int, what: type) -> None:
        super().__init__(servo_id)
        self.what = what

    def handle(self, command: Any) -> Any:
        if isinstance(command, self.what):
            signal.raise_signal(signal.SIGINT)
        return super().handle(command)


class TakesTheWriteSilently(VirtualServo):
    """A servo that writes its EEPROM as told, its acknowledgement never reaching the host (noise, a long line)."""

    def handle(self, command: Any) -> Any:
        reply = super().handle(command)
        return NO_REPLY if isinstance(command, WriteEeprom) else reply


class UnpluggedAfterWrite(VirtualServo):
    """A servo that acknowledges an EEPROM write, then leaves the line (its cable pulled, the adapter still there):
    the read-back gets no answer.  ``line`` is set once the line holds it."""

    line: VirtualLine | None = None

    def handle(self, command: Any) -> Any:
        known_as = self.servo_id  # (the ID the line knows it by: the write may give it another)
        reply = super().handle(command)
        if isinstance(command, WriteEeprom) and self.line is not None:
            self.line.remove_servo(known_as)
        return reply


class LosesPositionReplies(VirtualServo):
    """An ICS 3.6 servo whose first ``lost`` replies to the position read never reach the host (noise on the line,
    or a reply held past the wait): it hears each read, as a servo whose reply is lost does."""

    def __init__(self, servo_id: int, lost: int, **options: Any) -> None:
        super().__init__(servo_id, ics36=True, **options)
        self.lost = lost

    def handle(self, command: Any) -> Any:
        reply = super().handle(command)
        if isinstance(command, ReadPosition) and self.lost > 0:
            self.lost -= 1
            return NO_REPLY
        return reply


class LosesStretchReplies(VirtualServo):
    """A servo whose first ``lost`` replies to the stretch read (a scan's probe) never reach the host: it hears each
    read, as a servo whose reply is lost does, and answers every other command."""

    def __init__(self, servo_id: int, lost: int, **options: Any) -> None:
        super().__init__(servo_id, **options)
        self.lost = lost

    def handle(self, command: Any) -> Any:
        reply = super().handle(command)
        if isinstance(command, ReadParam) and command.param is Param.STRETCH and self.lost > 0:
            self.lost -= 1
            return NO_REPLY
        return reply


TELEMETRY_PARAMS = (Param.TEMPERATURE, Param.CURRENT)


class TelemetryGoesSilent(VirtualServo):
    """A servo that answers its first ``answered`` temperature and current reads, then leaves every later one
    unanswered, while it answers everything else (its position commands, the guard reads after a silence): a
    servo whose telemetry reads keep failing while its position transactions go through."""

    def __init__(self, servo_id: int, answered: int, **options: Any) -> None:
        super().__init__(servo_id, **options)
        self.answered = answered
        self.unanswered = 0  # (telemetry reads heard and left unanswered)

    def handle(self, command: Any) -> Any:
        reply = super().handle(command)
        if isinstance(command, ReadParam) and command.param in TELEMETRY_PARAMS:
            if self.answered > 0:
                self.answered -= 1
            else:
                self.unanswered += 1
                return NO_REPLY
        return reply


class TelemetryOnAndOff(VirtualServo):
    """A servo whose temperature and current reads go unanswered while ``silent`` is set (a test sets it), and
    answers everything else (its position reads): a servo that misses a few telemetry reads now and then."""

    def __init__(self, servo_id: int, **options: Any) -> None:
        super().__init__(servo_id, **options)
        self.silent = False

    def handle(self, command: Any) -> Any:
        reply = super().handle(command)
        if self.silent and isinstance(command, ReadParam) and command.param in TELEMETRY_PARAMS:
            return NO_REPLY
        return reply
