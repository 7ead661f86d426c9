"""The group's options as one object every command reads, the exit codes, and the error type for a person.

Kept free of heavy imports (rich, the bus, the simulator): ``ics35 --version``
and ``--help`` load only this and click.
"""

from __future__ import annotations

import contextlib
import enum
import itertools
import logging
import os
import shlex
import sys
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from ..eeprom import FACTORY_BAUD
from ..protocol.wire import ADAPTER_LATENCY, TOOL_RETRIES

if TYPE_CHECKING:
    import click

    from ..bus import Bus

_SIM_NAMES = itertools.count(1)

DEFAULT_PORT = "sim://"


class ExitCode(enum.IntEnum):
    """Process exit codes of ``ics35``.

    The docs' exit-code table is generated from these members and their docstrings.
    """

    OK = 0
    """Success; also `demo`, `monitor`, `play`, `sniff`, `sim` or `web` stopped with Ctrl-C, and `teach` ended
    with Ctrl-C."""
    COMMUNICATION = 1
    """Communication error: a garbled reply, an echo mismatch, a verify failure, the port lost mid-command."""
    USAGE = 2
    """Bad argument, nothing sent: ID 32, position 20000 (or 90 without `--deg`), an unknown parameter or
    field, a broken backup file, a `--plot` or `sim://?record=` file that cannot be written (or a taught
    motion's: it is printed instead), `--plot` without matplotlib, a robot or motion file missing, unreadable
    or with a mistake, a motion beyond the robot's limits, a write without `--port`, or a `udev --group` this
    system does not have."""
    PORT = 3
    """The port cannot be opened: missing, permission denied, busy, not a serial port, direction control
    refused by its driver; a bridge (`socket://`, `rfc2217://`) that refuses or drops the connection (what
    was sent before it dropped stands); `ports` found no serial port; `udev --install` cannot write its rules file."""
    NO_REPLY = 4
    """No servo answered (or nothing came back at all, not even the echo): baud, power, wiring, ID."""
    REFUSED = 5
    """Refused or not confirmed, nothing written: a baud change without `--change-baud`, an ID already taken,
    `set-id` with more or fewer than one servo, `move` outside the servo's EEPROM pulse limits, "no" (or end
    of input) at the prompt, `teach` with no pose captured, `calibrate` with its input ended early or a joint
    not moved far enough to both ends of its range, `play` with a joint whose servo has not answered since the
    robot opened or a joint turned past its limit by hand (its first command would throw it to the limit)."""
    WRONG_BAUD = 6
    """The servo answers, but at another baud rate than `--baud` (the message names it); for a command that asked
    every ID (`free all`, `monitor` without IDs), a device answers at another rate."""
    SAFETY_STOP = 7
    """`play`: a robot's safety watch stopped the motion (a joint too hot, drawing too much current, or
    offline)."""
    HANGUP = 129
    """The terminal closed (SIGHUP): the command ended as Ctrl-C ends it (servos freed or held as then, poses
    written), with nothing more on the terminal."""
    INTERRUPTED = 130
    """Interrupted (Ctrl-C) during a one-shot command, or at a `[y/N]` question (the first Ctrl-C; nothing
    written or moved); `calibrate` stopped before it writes (nothing written); `play`, `teach` or `calibrate`
    interrupted while the robot opens (the error says what the open left the joints in); or a second Ctrl-C that
    cut a stop short (`demo`, `play`, `web`: the last line says what it left)."""
    TERMINATED = 143
    """Stopped by SIGTERM (a service manager, `kill`): the command ended as Ctrl-C ends it (servos freed or
    held as then, poses written)."""


class CliError(Exception):
    """An error for a person: a message, hints on what to do, and an exit code."""

    def __init__(self, code: ExitCode, message: str, *hints: str) -> None:
        super().__init__(message)
        self.code = code
        self.message = message
        self.hints = list(hints)


@dataclass
class Settings:
    """The line options, shared with every command through ``ctx.obj``."""

    port: str = DEFAULT_PORT
    baud: int = FACTORY_BAUD
    timeout: float = ADAPTER_LATENCY
    retries: int = TOOL_RETRIES
    echo: bool = True
    transport: str = "auto"
    direction: str = "none"  # RTS direction control for DIY half-duplex interfaces
    verbose: int = 0
    port_defaulted: bool = False  # neither --port nor ICS35_PORT: the implicit, throwaway simulator
    simulated: bool = False  # this command reads the implicit simulator (its output says so)
    write_action: str | None = None  # a command that changes a servo: what it does (see _runner.guard_writes)
    json_output: bool = False  # --json given before the command
    from_environment: tuple[str, ...] = ()  # "ICS35_PORT=/dev/ttyUSB0": line options the environment set
    # The line options given (on the command line or by the environment), by name ("baud", "no_echo"), whatever
    # their value: `--baud 115200` is given as much as `--baud 625000`, though it is the default.
    given: frozenset[str] = frozenset()
    _sim_name: str | None = field(default=None, init=False, repr=False)
    # Every named URL url gave: an error may be said once release_sim has closed its line (see as_given)
    _sim_urls: list[str] = field(default_factory=list, init=False, repr=False)

    @property
    def is_sim(self) -> bool:
        from ..transports.wire_device import url_scheme  # (here: `ics35 --version` loads no transport)

        return url_scheme(self.port) == "sim"

    @property
    def is_bare_sim(self) -> bool:
        """The simulator with nothing asked of it (``sim://``, the default): a command may shape it its way."""
        from ..transports.wire_device import asks_nothing

        return asks_nothing(self.port)

    def builtin_sim(self, options: str = "") -> str:
        """The built-in simulator's URL for this command: its servos at the command's baud rate (it stands in for
        servos set up for this line, so every command finds them at ``--baud``); ``options``: more of its URL's
        (``realtime=1&``).  At its servos' own rate (115200) the URL names none: the configurator's port field
        shows ``sim://``, as its list of ports does."""
        query = options if int(self.baud) == FACTORY_BAUD else f"{options}baud={self.baud}"
        return f"sim://?{query.rstrip('&')}" if query else "sim://"

    @property
    def port_to_open(self) -> str:
        """The port as given, but the simulator with nothing asked of it (``sim://``, the default), which is
        :meth:`builtin_sim`."""
        return self.builtin_sim() if self.is_bare_sim else self.port

    @property
    def url(self) -> str:
        """The port to open (:attr:`port_to_open`).  An unnamed sim:// line gets a name, so that every reopening
        within this command (scan at each baud, a read-back) finds the same simulated servos."""
        from ..transports.wire_device import opens_anew

        port = self.port_to_open
        if not opens_anew(port):
            return port
        from ..sim.url import named_url

        if self._sim_name is None:
            self._sim_name = f"ics35-cli-{os.getpid()}-{next(_SIM_NAMES)}"
        url = named_url(port, self._sim_name)
        if url not in self._sim_urls:
            self._sim_urls.append(url)
        return url

    def as_given(self, text: str) -> str:
        """``text`` (a library error's) with the port as it was given where it names :attr:`url`: the name an
        unnamed sim:// line got is the command's own, also after :meth:`release_sim` closed that line."""
        for url in self._sim_urls:
            text = text.replace(url, self.port)
        return text

    def line_args(self, without: tuple[str, ...] = ()) -> list[str]:
        """The line options that reach this line again, as arguments: --port unless the implicit simulator,
        and every other option that differs from its default, but for the flags in ``without`` (a command
        that gives one of its own: the same flag twice would leave which one counts to the reader)."""
        args = [] if self.port_defaulted else ["--port", self.port]
        defaults = Settings()
        for flag, name in (
            ("--baud", "baud"),
            ("--timeout", "timeout"),
            ("--retries", "retries"),
            ("--no-echo", "echo"),
            ("--direction", "direction"),
            ("--transport", "transport"),
        ):
            value = getattr(self, name)
            if value == getattr(defaults, name) or flag in without:
                continue
            if isinstance(value, bool):
                args.append(flag)  # --no-echo: echo off
            else:
                args += [flag, f"{value:g}" if isinstance(value, float) else str(value)]
        return args

    def command_line(self, *words: str) -> str:
        """``ics35 [the line options of this command] WORDS...``, quoted for a shell: every hint that names a
        command to run renders it here, so it reaches the same line (without --port it would read the
        simulator, or refuse to write).  A line option among ``WORDS`` replaces this command's."""
        given = tuple(word for word in words if word.startswith("--"))
        return shlex.join(["ics35", *self.line_args(without=given), *words])

    def release_sim(self) -> None:
        """Close the simulated line :attr:`url` named, if any (it lives for one command)."""
        name, self._sim_name = self._sim_name, None
        if name is not None:
            from .. import sim

            with contextlib.suppress(KeyError):
                sim.named(name).close()

    def bus(
        self,
        baud: int | None = None,
        *,
        timeout: float | None = None,
        retries: int | None = None,
        reconnect: bool = False,
    ) -> Bus:
        """A not-yet-open bus with these settings (``async with`` it); ``reconnect``: a port lost once it is open is
        reopened when it comes back (the library's reconnect and its schedule)."""
        from ..bus import open_bus

        return open_bus(
            self.url,
            baudrate=self.baud if baud is None else baud,
            echo=self.echo,
            transport=self.transport,
            direction=self.direction,
            retries=self.retries if retries is None else retries,
            adapter_latency=self.timeout if timeout is None else timeout,
            reconnect=reconnect,
        )


def settings_of(ctx: click.Context) -> Settings:
    obj = ctx.find_object(Settings)
    return obj if obj is not None else Settings()


# On the library's logger without -v: its records said by the command itself, or not at all.
LIBRARY_QUIET = logging.NullHandler()


def _after_ctrl_c(record: logging.LogRecord) -> bool:
    """The log's filter: a record written as a command stops on Ctrl-C followed the echoed ``^C`` on its line."""
    from ..terminal import clear_after_ctrl_c  # (not at the top: ics35 --version stays light)

    clear_after_ctrl_c()
    return True


def setup_logging(verbose: int) -> None:
    if not verbose:
        # The library logs a lost port as a warning, which Python's last-resort handler would
        # print; the command reports it itself, once.  (Configured handlers still get records.)
        logging.getLogger("ics35_async").addHandler(LIBRARY_QUIET)
        return
    logging.getLogger("ics35_async").removeHandler(LIBRARY_QUIET)
    level = logging.DEBUG if verbose > 1 else logging.INFO
    root = logging.getLogger()
    ours = not root.handlers  # (a program that set up logging itself keeps its own handlers as they are)
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s", stream=sys.stderr)
    if ours:
        for handler in root.handlers:
            handler.addFilter(_after_ctrl_c)
    # -v may come again after the command (ics35 scan -vv): the last count wins.
    logging.getLogger().setLevel(level)
    # Every failed transaction in words at -v (what the live tables' error columns count).
    logging.getLogger("ics35_async.faults").setLevel(logging.DEBUG)
