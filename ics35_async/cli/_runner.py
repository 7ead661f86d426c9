"""Running a command's coroutine: checks before the line is touched, and every failure as a CliError."""

from __future__ import annotations

import functools
from collections.abc import Awaitable, Callable
from typing import Any, TypeVar

import click
from rich.markup import escape

from ..errors import IcsError, ReplyTimeout
from ..transports import adapter_advice
from ..transports.wire_device import example_port
from ._console import say_labelled
from ._errors import NobodyAnswered, no_reply_error, nobody_at_this_rate, translate
from ._loop import run_loop
from ._paths import check_line_files
from ._settings import CliError, ExitCode, Settings, settings_of

T = TypeVar("T")

_advised: set[str] = set()


def simulator_note() -> str:
    """What a command run without --port says first (this system's port named as the example)."""
    return f"note: no --port given: this is the built-in simulator (for hardware: --port {example_port()})"


def advise(port: str) -> None:
    """Print the adapter warnings (FTDI latency timer) once per port."""
    if port in _advised:
        return
    _advised.add(port)
    for warning in adapter_advice(port):
        say_labelled("[yellow]warning:[/yellow]", escape(warning))


def note_simulator(settings: Settings) -> None:
    """Say once, on stderr, that the implicit default simulator is what the command talks to: its plausible fake
    data, read with a robot plugged in, would pass for the robot's.  Not on stdout, which carries results only
    (``ics35 get 1 speed | cut ...``); a JSON result says it as data instead (``"simulated": true``)."""
    if settings.port_defaulted:
        settings.port_defaulted = False
        label, text = simulator_note().split(" ", 1)
        say_labelled(f"[dim]{label}[/dim]", f"[dim]{escape(text)}[/dim]")
        settings.simulated = True


def require_port(settings: Settings, action: str) -> None:
    """Refuse a command that changes a servo when the port is the implicit simulator.

    Without --port (and ICS35_PORT) a write would go to a simulator that is thrown
    away when the command ends, and report a success nothing kept.
    """
    if settings.port_defaulted:
        raise CliError(
            ExitCode.USAGE,
            f"no --port given: refusing to {action} on the built-in simulator, which forgets it at once "
            "(nothing was sent)",
            f"on hardware: ics35 --port {example_port()} ...  (or set ICS35_PORT)",
            "to try it on the simulator anyway: ics35 --port sim:// ...",
        )


# Commands that change a servo, by their full name, and what they would do (for the refusal).
WRITE_COMMANDS = {
    "move": "move a servo",
    "free": "turn servos' torque off",
    "set": "change a servo's RAM parameter",
    "set-id": "change a servo's ID",
    "eeprom set": "write a servo's EEPROM",
    "eeprom restore": "write a servo's EEPROM",
}


def guard_writes(command: click.Command, prefix: str = "") -> None:
    """Make every command of WRITE_COMMANDS in ``command``'s tree call :func:`require_port` as it goes
    to the line (in :func:`run`: after its own checks of its arguments, so a bad value is named first).

    One table, applied when the commands are mounted, so no write command can miss the rule.
    """
    name = f"{prefix}{command.name}"
    if isinstance(command, click.Group):
        for sub in command.commands.values():
            guard_writes(sub, f"{name} ")
        return
    action = WRITE_COMMANDS.get(name)
    inner = command.callback
    if action is None or inner is None:
        return

    @functools.wraps(inner)
    def guarded(*args: Any, **kwargs: Any) -> Any:
        settings_of(click.get_current_context()).write_action = action
        return inner(*args, **kwargs)

    command.callback = guarded


def name_the_environment(settings: Settings, error: CliError) -> CliError:
    """A line error when the port or rate came from ICS35_PORT / ICS35_BAUD: say so, or the person
    looks for a --port they never typed."""
    if settings.from_environment and error.code in (ExitCode.PORT, ExitCode.NO_REPLY, ExitCode.WRONG_BAUD):
        used = ", ".join(settings.from_environment)
        error.hints.append(f"from the environment: {used} (--port and --baud override it)")
    return error


def run(settings: Settings, make: Callable[[], Awaitable[T]]) -> T:
    """Run the command's coroutine; turn every expected failure into a :class:`CliError`."""
    if settings.write_action is not None:
        require_port(settings, settings.write_action)
    check_line_files(settings)
    if not settings.is_sim:
        advise(settings.port)
    note_simulator(settings)
    try:
        try:
            return run_loop(make)
        except KeyboardInterrupt:
            raise CliError(ExitCode.INTERRUPTED, "interrupted") from None
        except NobodyAnswered as nobody:  # (the line is closed now: the other rates can be looked at)
            raise nobody_at_this_rate(settings, nobody) from None
        except BrokenPipeError:
            raise  # `ics35 ... | head`: main() ends quietly
        except (IcsError, OSError) as exc:
            raise line_error(settings, exc) from None
    finally:
        settings.release_sim()


def line_error(settings: Settings, exc: IcsError | OSError) -> CliError:
    """A library error (or one the library did not type: a file a sim:// URL names, an odd driver error) in a
    person's words."""
    if isinstance(exc, ReplyTimeout):
        return name_the_environment(settings, no_reply_error(settings, exc))
    if isinstance(exc, IcsError):
        return name_the_environment(settings, translate(settings, exc))
    return CliError(ExitCode.COMMUNICATION, f"{settings.port}: {exc}")
