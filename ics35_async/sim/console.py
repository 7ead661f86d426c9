"""The console of ``ics35 sim --console``: plug servos in, unplug them and power-cycle them while the line serves.

:class:`LineConsole` turns one command line into one change to a :class:`~.virtual_line.VirtualLine`
(whose methods do the work, under its lock) and returns its answer; :class:`ConsoleReader` reads
commands from a file descriptor (stdin) in a thread of its own and writes each answer on a line.
Commands::

    plug ID [BAUD] [ics36]   a new servo, factory settings, at ID (at BAUD, else the simulator's --baud)
    unplug ID                the servo at ID leaves the line (of two at one ID, the one plugged in last)
    replug [ID]              an unplugged servo comes back, powered up (the last unplugged, or the one at ID)
    unplug port              the port goes, as a USB adapter pulled out: a program on it loses it, until...
    replug port              ...the port comes back at the same path (a program's reconnect finds it there)
    power [ID]               power-cycle every servo, or those at ID: a baud rate in their EEPROM applies now
    turn ID POSITION         turn the servo(s) at ID by hand to POSITION (3500..11500): a free one stays there,
                             a holding one turns back to its target
    list                     each servo: ID, ICS 3.5/3.6, the rate it listens at (and its EEPROM's), position
    help                     the commands
    quit                     stop the simulator (as end of input and Ctrl-C do)

Every command answers with one line (``list``: a first line that says how many servo lines follow);
a command it cannot carry out answers ``error: ...`` and changes nothing.
"""

from __future__ import annotations

import contextlib
import os
import select
import threading
from collections.abc import Callable
from typing import ClassVar, TextIO

from ..eeprom import BaudRate
from ..errors import InvalidArgument, error_text
from ..terminal import ERASE_LINE, fitted_lines
from ..units import TRAVEL_MAX, TRAVEL_MIN, position_to_degrees
from .virtual_line import ServoState, VirtualLine
from .virtual_servo import VirtualServo

PROMPT = "sim> "  # (on a terminal only: see ConsoleReader)
HELP = (
    "commands: plug ID [BAUD] [ics36] (a new servo), unplug ID, replug [ID], unplug port, replug port, "
    "power [ID], turn ID POSITION (by hand, 3500..11500), list, help, quit"
)


REPLUG_PORT = "replug port plugs it back in"


class ConsoleError(Exception):
    """A command the console cannot carry out (it changed nothing)."""


def _servos(count: int) -> str:
    return f"{count} servo{'s' if count != 1 else ''}"


def _number(text: str) -> int | None:
    """``text`` as a number if it is one in ASCII digits, else None.

    Not ``str.isdigit`` alone: it takes digits ``int`` fails on (``²``) and others it reads (Arabic-Indic one is 1);
    and no more digits than any rate has: ``int`` refuses a string past 4300 of them.
    """
    if not (text.isascii() and text.isdecimal()) or len(text) > 9:
        return None
    return int(text)


def _parse_id(text: str) -> int:
    servo_id = _number(text)
    if servo_id is None or servo_id > 31:
        raise ConsoleError(f"an ID is 0..31, got {text!r}")
    return servo_id


def _parse_position(text: str) -> int:
    position = _number(text)
    if position is None or not TRAVEL_MIN <= position <= TRAVEL_MAX:
        raise ConsoleError(
            f"a position is {TRAVEL_MIN}..{TRAVEL_MAX} (-135..+135 degrees, the servo's travel), got {text!r}"
        )
    return position


def _describe(state: ServoState) -> str:
    version = "ICS 3.6" if state.ics36 else "ICS 3.5"
    rate = f"{state.baud} bit/s"
    if state.eeprom_baud is None:
        rate += " (an undefined rate in its EEPROM)"
    elif state.eeprom_baud != state.baud:
        rate += f" ({state.eeprom_baud} in its EEPROM, after power)"
    return f"  ID {state.servo_id}: {version}, {rate}, at {state.position}, {'free' if state.free else 'holding'}"


class LineConsole:
    """Carries out console commands on ``line``; new servos come at ``baudrate`` unless told another.  ``path``:
    where programs open the line (what ``unplug port`` takes away)."""

    def __init__(self, line: VirtualLine, baudrate: int, path: str = "the port") -> None:
        self.line = line
        self.path = path
        self.baudrate = int(BaudRate.parse(baudrate))
        self.unplugged: list[VirtualServo] = []  # off the line, EEPROM kept: replug brings one back
        self.quit = False

    def execute(self, text: str) -> str:
        """Carry out one command line; its answer (one line; ``list``: one line per servo after it)."""
        words = text.split()
        if not words:
            return HELP
        name, args = words[0].lower(), words[1:]
        handler = self._COMMANDS.get(name)
        try:
            if handler is None:
                raise ConsoleError(f"unknown command {words[0]!r} (help lists the commands)")
            return handler(self, args)
        except ConsoleError as exc:
            return f"error: {exc}"
        except Exception as exc:  # a bug, not the input's fault: still an answer, and the console lives on
            return f"error: {words[0]} failed: {error_text(exc)}"

    def _on_line(self) -> str:
        return f"{_servos(len(self.line.servos))} on the line"

    def _sharing(self, servo_id: int, more: bool = False) -> str:
        count = len(self.line.servos_at(servo_id))
        if more:
            return f"; {count} more still answer{'s' if count == 1 else ''} to ID {servo_id}" if count else ""
        return f"; {count} servos now answer to ID {servo_id}: their replies collide" if count > 1 else ""

    def _plug(self, args: list[str]) -> str:
        if not args:
            raise ConsoleError("plug takes an ID, e.g. plug 0 (then a baud rate and ics36 if wanted)")
        servo_id = _parse_id(args[0])
        baudrate, ics36 = self.baudrate, False
        for word in args[1:]:
            if word.lower() == "ics36":
                ics36 = True
            elif (number := _number(word)) is not None:
                try:
                    baudrate = int(BaudRate.parse(number))
                except InvalidArgument as exc:
                    raise ConsoleError(str(exc)) from None
            else:
                raise ConsoleError(f"plug ID takes a baud rate and ics36 after it, not {word!r}")
        self.line.add_device(VirtualServo(servo_id, baud_rate=baudrate, ics36=ics36))
        version = "ICS 3.6" if ics36 else "ICS 3.5"
        return (
            f"plugged in a new servo at ID {servo_id} ({version}, {baudrate} bit/s); {self._on_line()}"
            f"{self._sharing(servo_id)}"
        )

    def _one_id(self, command: str, args: list[str]) -> int:
        if len(args) != 1:
            raise ConsoleError(f"{command} takes one ID, e.g. {command} 1")
        return _parse_id(args[0])

    def _unplug(self, args: list[str]) -> str:
        if [a.lower() for a in args] == ["port"]:
            if not self.line.plugged:
                raise ConsoleError(f"the port is unplugged already ({REPLUG_PORT})")
            self.line.unplug()  # (no replug of its own: it stays out until told, as an adapter left on the desk)
            return f"unplugged the port: {self.path} is gone and a program on it loses it ({REPLUG_PORT})"
        servo_id = self._one_id("unplug", args)
        shared = len(self.line.servos_at(servo_id)) > 1
        try:
            servo = self.line.remove_servo(servo_id)
        except KeyError:
            raise ConsoleError(f"no servo at ID {servo_id} on the line (list shows them)") from None
        self.unplugged.append(servo)
        which = " plugged in last" if shared else ""
        return (
            f"unplugged the servo at ID {servo_id}{which} (replug {servo_id} plugs it back in); {self._on_line()}"
            f"{self._sharing(servo_id, more=True)}"
        )

    def _replug(self, args: list[str]) -> str:
        if [a.lower() for a in args] == ["port"]:
            if self.line.plugged:
                raise ConsoleError("the port is plugged in (unplug port pulls it out)")
            self.line.replug()
            return f"plugged the port back in at {self.path}; {self._on_line()}"
        if len(args) > 1:
            raise ConsoleError("replug takes at most one ID, e.g. replug 1")
        servo_id = _parse_id(args[0]) if args else None
        waiting = [s for s in self.unplugged if servo_id is None or s.servo_id == servo_id]
        if not waiting:
            at = "" if servo_id is None else f" at ID {servo_id}"
            raise ConsoleError(f"no unplugged servo{at} to plug back in")
        servo = waiting[-1]
        self.unplugged.remove(servo)
        servo.power_cycle()  # plugged in is powered up: it wakes up with what its EEPROM holds
        self.line.add_device(servo)
        return (
            f"plugged the servo at ID {servo.servo_id} back in ({int(servo.baud_rate)} bit/s); {self._on_line()}"
            f"{self._sharing(servo.servo_id)}"
        )

    def _power(self, args: list[str]) -> str:
        if not args:
            return f"power-cycled {_servos(len(self.line.power_cycle()))}"
        servo_id = self._one_id("power", args)
        try:
            servos = self.line.power_cycle(servo_id)
        except KeyError:
            raise ConsoleError(f"no servo at ID {servo_id} on the line (list shows them)") from None
        rates = " and ".join(sorted({str(int(s.baud_rate)) for s in servos}))
        if len(servos) == 1:
            return f"power-cycled the servo at ID {servo_id}: it listens at {rates} bit/s"
        return f"power-cycled the {len(servos)} servos at ID {servo_id}: they listen at {rates} bit/s"

    def _turn(self, args: list[str]) -> str:
        if len(args) != 2:
            raise ConsoleError("turn takes an ID and a position, e.g. turn 1 9000")
        servo_id, position = _parse_id(args[0]), _parse_position(args[1])
        try:
            servos = self.line.move_by_hand(servo_id, position)
        except KeyError:
            raise ConsoleError(f"no servo at ID {servo_id} on the line (list shows them)") from None
        which = "the servo" if len(servos) == 1 else f"the {len(servos)} servos"
        done = f"turned {which} at ID {servo_id} by hand to {position} ({position_to_degrees(position):+.1f} degrees)"
        targets = sorted({s.target for s in servos if s.target is not None})
        if not targets:
            return done + ("; it is free: it stays there" if len(servos) == 1 else "; they are free: they stay there")
        held = " and ".join(str(t) for t in targets)
        if len(servos) == 1:
            return f"{done}; it is holding {held}: it turns back there"
        holding = sum(not s.free for s in servos)
        free = len(servos) - holding
        return f"{done}; {holding} of them holding {held} turn{'s' if holding == 1 else ''} back" + (
            f", {free} free stay{'s' if free == 1 else ''} there" if free else ""
        )

    def _list(self, args: list[str]) -> str:
        if args:
            raise ConsoleError("list takes nothing after it")
        states = self.line.servo_states()
        if not states:
            return "list: no servos on the line (plug ID puts one in)"
        head = f"list: {_servos(len(states))}"
        if not self.line.plugged:
            head += f", the port unplugged ({REPLUG_PORT})"
        return "\n".join([head, *(_describe(state) for state in states)])

    def _help(self, args: list[str]) -> str:
        return HELP

    def _quit(self, args: list[str]) -> str:
        self.quit = True
        return "quit: the simulator stops"

    _COMMANDS: ClassVar[dict[str, Callable[[LineConsole, list[str]], str]]] = {
        "plug": _plug,
        "unplug": _unplug,
        "replug": _replug,
        "power": _power,
        "turn": _turn,
        "list": _list,
        "help": _help,
        "quit": _quit,
        "exit": _quit,
    }


class ConsoleReader:
    """Reads commands from ``fd`` in a thread, one a line, and writes each answer to ``out``.

    ``prompt``, when given, is written to ``prompt_out`` (the terminal a person types on, not a program reading
    the answers) before each command is read; a line said meanwhile goes through :meth:`aside`.  ``on_end`` is
    called (from that thread) at the end of input and after ``quit``; :meth:`close` stops the thread, from any
    other thread.
    """

    def __init__(
        self,
        console: LineConsole,
        on_end: Callable[[], None],
        *,
        fd: int = 0,
        out: TextIO,
        prompt: str = "",
        prompt_out: TextIO | None = None,
    ) -> None:
        self.console = console
        self.on_end = on_end
        self.fd = fd
        self.out = out
        self.prompt = prompt
        self.prompt_out = prompt_out
        self._prompted = False  # the cursor stands after a prompt: what is written next must not follow it
        self._prompt_lock = threading.Lock()  # (a line said aside comes from another thread)
        self._stop_r, self._stop_w = os.pipe()
        self._thread = threading.Thread(target=self._run, name="ics35-sim-console", daemon=True)

    def start(self) -> None:
        with contextlib.suppress(OSError, ValueError):
            self.out.flush()  # (what was printed before goes first: the answers bypass the stream's buffer)
        self._thread.start()

    def close(self) -> None:
        with contextlib.suppress(OSError):
            os.write(self._stop_w, b"x")
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            # Bounded: the thread may be blocked writing an answer to a stdout nobody reads (a full pipe),
            # where the stop pipe cannot reach it; a daemon, it then ends with the process.
            self._thread.join(timeout=1.0)
        if not self._thread.is_alive():
            # Stopped at the prompt (a signal): it goes, with the ^C a Ctrl-C echoed after it, so the last words
            # start a line of their own.
            with self._prompt_lock:
                if self._prompted:
                    self._prompted = False
                    self._write_to(self.prompt_out, ERASE_LINE)
        for fd in (self._stop_r, self._stop_w):
            with contextlib.suppress(OSError):
                os.close(fd)

    def aside(self, say: Callable[[], None]) -> None:
        """``say()`` writes a line of the simulator's own (the port unplugged): where the prompt waits, it goes
        first and comes back below that line, so the line starts where it should and the prompt stays last."""
        with self._prompt_lock:
            if self._prompted:
                self._write_to(self.prompt_out, ERASE_LINE)
            say()
            if self._prompted:
                self._write_to(self.prompt_out, self.prompt)

    def _write(self, text: str) -> None:
        self._write_to(self.out, text)

    @staticmethod
    def _write_to(stream: TextIO | None, text: str) -> None:
        """``text`` to ``stream``: on its descriptor directly where it has one.  Through a buffered stream
        (Python's stdout unless PYTHONUNBUFFERED), a write blocked on a pipe nobody reads held the stream's lock,
        and Python ending meanwhile (Ctrl-C) aborted on it ("Fatal Python error: _enter_buffered_busy"): a blocked
        ``os.write`` holds none, and the thread, a daemon, ends with the process."""
        if stream is None:
            return
        with contextlib.suppress(OSError, ValueError):  # (nobody reads them any more: the commands count)
            try:
                fd = stream.fileno()
            except (OSError, ValueError, AttributeError):  # (not a file: a test's StringIO)
                stream.write(text)
                stream.flush()
                return
            data = memoryview(text.encode(stream.encoding or "utf-8", "replace"))
            while data:
                data = data[os.write(fd, data) :]

    def _ask(self) -> None:
        """The prompt, where a person types the commands."""
        if self.prompt and self.prompt_out is not None:
            with self._prompt_lock:
                self._write_to(self.prompt_out, self.prompt)
                self._prompted = True

    def _run(self) -> None:
        pending = b""
        self._ask()
        while True:
            try:
                readable, _, _ = select.select([self.fd, self._stop_r], [], [])
                if self._stop_r in readable:
                    return
                data = os.read(self.fd, 4096)
            except OSError:
                data = b""  # no input to read (closed, or not readable): as at its end
            if not data:
                with self._prompt_lock:
                    if self._prompted:  # (Ctrl-D at the prompt: the words saying so go below it, as a shell's do)
                        self._prompted = False
                        self._write_to(self.prompt_out, "\n")
                self.on_end()
                return
            pending += data
            *lines, pending = pending.split(b"\n")
            if lines:
                with self._prompt_lock:
                    self._prompted = False  # (the line typed ended with its newline, echoed by the terminal)
            for line in lines:
                answer = self.console.execute(line.decode("utf-8", "replace"))
                self._write(fitted_lines(answer, self.out) + "\n")
                if self.console.quit:
                    self.on_end()
                    return
            if lines:
                self._ask()
