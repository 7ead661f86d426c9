"""The ``ics35`` command: find, read, set, back up and watch ICS 3.5 servos.

Every command runs against ``--port`` (default: the built-in simulator,
which lives only as long as the command; ``ics35 sim`` runs one on a pty
for longer sessions).  Expected failures end with a message, hints and a
documented exit code (:class:`ExitCode`), never a traceback.

Only click and :mod:`._settings` load up front: the commands (and with them
rich, the bus and the simulator) are imported when one is run or listed, so
``ics35 --version`` stays quick.
"""

from __future__ import annotations

import importlib
import inspect  # click imports it already: no start-up cost
import shutil  # (click too)
import sys
from collections.abc import Iterable, Sequence
from typing import Any, NoReturn

import click

from .. import __version__
from . import _signals
from ._line_options import add_line_options, group_line_options, settings_from
from ._settings import CliError, ExitCode

CONTEXT_SETTINGS = {"help_option_names": ["-h", "--help"], "max_content_width": 110}


class HelpFitted(click.HelpFormatter):
    """click's help layout, fitted to a terminal narrower than the 50 columns click lays it out for at least (the
    terminal cut every line mid-word): the terminal's width, and the options' first column narrower so their
    descriptions keep words beside it.  Into a pipe or a file, click's own."""

    def __init__(self, indent_increment: int = 2, width: int | None = None, max_width: int | None = None) -> None:
        if width is None and sys.stdout.isatty():
            columns = shutil.get_terminal_size().columns
            if columns - 2 < 50:
                width = max(columns - 2, 20)
        super().__init__(indent_increment, width, max_width)

    def write_dl(self, rows: Iterable[tuple[str, str]], col_max: int = 30, col_spacing: int = 2) -> None:
        super().write_dl(rows, min(col_max, max(self.width // 3, 8)), col_spacing)


# Each command's module (its COMMANDS list is mounted on the group): running a command imports only its
# own module, so `ics35 get` does not pay for the robot, the plot or the web server; listing them (help)
# imports them all.  tests/test_cli_options.py checks this table against the modules' COMMANDS.
COMMAND_MODULES = {
    "scan": "_scan",
    "info": "_basic",
    "move": "_basic",
    "free": "_basic",
    "get": "_basic",
    "set": "_basic",
    "set-id": "_scan",
    "eeprom": "_eeprom",
    "monitor": "_monitor",
    "demo": "_demo",
    "sim": "_simcmd",
    "ports": "_ports",
    "doctor": "_doctor",
    "udev": "_udev",
    "sniff": "_sniff",
    "play": "_robot_play",
    "teach": "_robot_teach",
    "calibrate": "_robot_teach",
    "check": "_robot_check",
    "web": "_web",
}
# Commands that pass their arguments through untouched get no line options after them.
PASS_THROUGH = frozenset({"sim"})
# Commands that open no line: no line options after them either.
NO_LINE = frozenset({"ports", "udev", "check"})


class LazyGroup(click.Group):
    """A group that imports a command's module only when that command is looked up (all when listed)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._loaded: set[str] = set()

    def parse_args(self, ctx: click.Context, args: list[str]) -> list[str]:
        ctx.meta["ics35.argv"] = list(args)  # what --version -v looks at (it runs before -v is parsed)
        return super().parse_args(ctx, args)

    def _load(self, module_name: str) -> None:
        if module_name in self._loaded:
            return
        self._loaded.add(module_name)
        from ._runner import guard_writes

        module = importlib.import_module(f"{__name__}.{module_name}")
        for command in module.COMMANDS:
            if command.name not in PASS_THROUGH | NO_LINE:
                add_line_options(command)
            guard_writes(command)
            self.add_command(command)

    def list_commands(self, ctx: click.Context) -> list[str]:
        for module_name in dict.fromkeys(COMMAND_MODULES.values()):
            self._load(module_name)
        return super().list_commands(ctx)

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        module_name = COMMAND_MODULES.get(cmd_name)
        if module_name is None:
            if not ctx.resilient_parsing:  # a typo: click's "Did you mean" looks among every command
                self.list_commands(ctx)
            return None
        self._load(module_name)
        return super().get_command(ctx, cmd_name)


def _print_version(ctx: click.Context, _param: click.Parameter, value: bool) -> None:
    """The version; with -v also the Python, the platform, the I/O path that runs, whether the engine is compiled and
    how deadlines are timed."""
    if not value or ctx.resilient_parsing:
        return
    click.echo(f"ics35, version {__version__}")
    argv = ctx.meta.get("ics35.argv", [])
    if any(a == "--verbose" or (a.startswith("-v") and set(a[1:]) == {"v"}) for a in argv):
        import platform

        from rich.markup import escape

        from ..compiled import ENGINE_NAME, engine_compiled
        from ..drivers.burst import PATH_NAME, burst_path
        from ..drivers.fine_timer import TIMER_NAME, fine_deadlines
        from ._console import out, say  # (with -v only: the plain version stays quick)

        python = f"Python {platform.python_version()} ({platform.python_implementation()}), {platform.platform()}"
        for line in (python, f"{PATH_NAME}: {burst_path()[1]}", f"{ENGINE_NAME}: {engine_compiled()[1]}"):
            say(escape(line), to=out)
        say(escape(f"{TIMER_NAME}: {fine_deadlines()[1]}"), to=out)
    ctx.exit()


@click.group(cls=LazyGroup, context_settings=CONTEXT_SETTINGS)
@group_line_options
@click.option(
    "--json", "json_output", is_flag=True, help="Print machine-readable JSON on stdout (as the command's own --json)."
)
# The version string, not package metadata: importlib.metadata alone costs ~15 ms at start-up.
@click.option(
    "--version",
    is_flag=True,
    expose_value=False,
    is_eager=True,
    callback=_print_version,
    help="Show the version and exit (with -v: the Python, the platform and whether the compiled stream path is on).",
)
@click.pass_context
def cli(ctx: click.Context, /, **line_options: Any) -> None:
    """Drive Kondo ICS 3.5 serial servos (KRS series).

    \b
    Try it without hardware:   ics35 demo
    On hardware:               ics35 --port /dev/ttyUSB0 scan
    First day on hardware:     ics35 doctor --port /dev/ttyUSB0

    The line options (--port, --baud, --timeout, ...) may also follow the command:
    ics35 scan --port /dev/ttyUSB0.  Commands that change a servo need an explicit
    --port (or ICS35_PORT): the default simulator would forget the change at once.
    """
    json_output = line_options.pop("json_output")
    ctx.obj = settings_from(ctx, line_options)
    ctx.obj.json_output = json_output
    name = ctx.invoked_subcommand
    command = cli.get_command(ctx, name) if json_output and name else None
    if (
        command is not None
        and not isinstance(command, click.Group)
        and not any("--json" in getattr(param, "opts", ()) for param in command.params)
    ):
        raise click.UsageError(f"--json: `ics35 {name}` has no JSON output")


# Written from the enum, the one place that defines the codes (the docs' table is generated from it too).
_CODES = ", ".join(f"{int(code)} {code.name.lower().replace('_', ' ')}" for code in ExitCode)
cli.help = f"{inspect.cleandoc(cli.help or '')}\n\nExit codes: {_CODES} (the docs' exit-code reference says more)."


def main(argv: Sequence[str] | None = None) -> None:
    """Console-script entry point: runs ``ics35`` and exits with its code."""
    try:
        _signals.install()  # (within the try: a Ctrl-C as main begins ends in one line too)
        click.Context.formatter_class = HelpFitted  # (this process's: every command's help, the group's too)
        code = cli.main(args=list(argv) if argv is not None else None, prog_name="ics35", standalone_mode=False)
        # (Within the try: a Ctrl-C as the exit code is worked out, the command over, ends in one line too.)
        code = code if isinstance(code, int) else 0
        signum = _signals.received()
        if signum is not None and code == ExitCode.OK:  # (a command that stops on Ctrl-C as its normal end)
            code = _SIGNAL_CODES[signum]
    except CliError as exc:
        from ._console import fail

        fail(_stopped_by_signal(exc))
    except click.exceptions.Abort as exc:  # (click's form of a KeyboardInterrupt outside a command's handling)
        # (a Ctrl-C has one name wherever it lands, not click's "aborted"; click wrote a newline on stderr first)
        _interrupted("interrupted", newline_on_stderr=isinstance(exc.__cause__, KeyboardInterrupt))
    except click.ClickException as exc:
        from ._console import say_click_error

        say_click_error(exc)
        sys.exit(exc.exit_code)
    except click.exceptions.Exit as exc:
        sys.exit(exc.exit_code)
    except KeyboardInterrupt:
        # Ctrl-C outside a command's own handling (as main begins, while parsing, once it is over): no traceback.
        _interrupted("interrupted")
    except RuntimeError as exc:
        # Ctrl-C landing in a class as it was made (a dataclass's fields, as a command imports what it needs):
        # Python 3.11 hands the KeyboardInterrupt on inside a RuntimeError ("Error calling __set_name__ ...");
        # 3.12 raises it bare (click, running the command, makes it an Abort).
        if not isinstance(exc.__cause__, KeyboardInterrupt):
            raise
        _interrupted("interrupted")
    except BrokenPipeError:
        # `ics35 ... | head`: the reader left; not an error worth a traceback.
        sys.stderr.close()
        sys.exit(0)
    sys.exit(code)


# The stop signals' exit codes, by signal number (128 + the number, as a shell reports a process it ended).
_SIGNAL_CODES = {int(code) - 128: code for code in (ExitCode.HANGUP, ExitCode.TERMINATED)}


def _interrupted(word: str, *, newline_on_stderr: bool = False) -> NoReturn:
    """Ctrl-C (or a stop signal) outside a command's own handling: one line, the signal's exit code.
    ``newline_on_stderr``: written there since the press (see clear_echoed_ctrl_c)."""
    _signals.same_stop_for_a_moment()
    stopped = _stopped_by_signal(CliError(ExitCode.INTERRUPTED, word))
    if stopped.code == ExitCode.INTERRUPTED:
        from ..terminal import clear_echoed_ctrl_c

        clear_echoed_ctrl_c(newline_on_stderr=newline_on_stderr)
    click.echo(f"error: {stopped.message}", err=True)  # (as every failure is said; plain: no console to load now)
    sys.exit(int(stopped.code))


def _stopped_by_signal(error: CliError) -> CliError:
    """An interrupted command's error, told by the signal that stopped it (SIGTERM, SIGHUP) if not Ctrl-C."""
    signum = _signals.received()
    if signum is None or error.code != ExitCode.INTERRUPTED:
        return error
    stopped = CliError(_SIGNAL_CODES[signum], f"{_signals.stop_name()}: {error.message}")
    stopped.hints = error.hints
    return stopped


__all__ = ["CliError", "ExitCode", "cli", "main"]
