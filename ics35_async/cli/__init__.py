"""The ``ics35`` command: find, read, set, back up and watch ICS 3.5 servos.

Every command runs against ``--port`` (default: the built-in simulator,
which lives only as long as the command; ``ics35 sim`` runs one on a pty
for longer sessions).  Expected failures end with a message, hints and a
documented exit code (:class:`ExitCode`), never a traceback.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

import click

from . import _basic, _eeprom, _live, _simcmd
from ._common import DEFAULT_PORT, ExitCode, Settings, fail, setup_logging
from ._common import CliError as CliError

CONTEXT_SETTINGS = {"help_option_names": ["-h", "--help"], "max_content_width": 110}


@click.group(context_settings=CONTEXT_SETTINGS)
@click.option(
    "--port",
    "-p",
    default=DEFAULT_PORT,
    show_default=True,
    envvar="ICS35_PORT",
    help="Serial device (/dev/ttyUSB0, COM3), pyserial URL, or sim://[?ids=..] for the built-in simulator.",
)
@click.option(
    "--baud",
    "-b",
    type=click.Choice(["115200", "625000", "1250000"]),
    default="115200",
    show_default=True,
    envvar="ICS35_BAUD",
    help="Line baud rate (625000 and 1250000 need the ICS USB adapter HS).",
)
@click.option(
    "--timeout",
    type=click.FloatRange(0.0, 5.0),
    default=0.020,
    show_default=True,
    help="Seconds allowed on top of the wire time for each reply (USB adapter latency).",
)
@click.option(
    "--retries", type=click.IntRange(0, 10), default=1, show_default=True, help="Retries for reads and positions."
)
@click.option("--no-echo", is_flag=True, help="The interface does not loop sent bytes back (no echo to skip).")
@click.option(
    "--transport",
    type=click.Choice(["auto", "fast", "stock", "direct"]),
    default="auto",
    show_default=True,
    help="Serial driver for device paths.",
)
@click.option("--verbose", "-v", count=True, help="Log bus activity to stderr (-vv: every byte).")
@click.version_option(package_name="ics35_async", prog_name="ics35")
@click.pass_context
def cli(
    ctx: click.Context,
    port: str,
    baud: str,
    timeout: float,
    retries: int,
    no_echo: bool,
    transport: str,
    verbose: int,
) -> None:
    """Drive Kondo ICS 3.5 serial servos (KRS series).

    \b
    Try it without hardware:   ics35 demo
    On hardware:               ics35 --port /dev/ttyUSB0 scan

    Exit codes: 0 ok, 1 communication error, 2 bad argument (nothing sent), 3 port cannot be opened,
    4 no servo answered, 5 refused or not confirmed (nothing written), 6 servo answers at another baud,
    130 interrupted.
    """
    setup_logging(verbose)
    ctx.obj = Settings(
        port=port,
        baud=int(baud),
        timeout=timeout,
        retries=retries,
        echo=not no_echo,
        transport=transport,
        verbose=verbose,
        port_defaulted=ctx.get_parameter_source("port") is click.core.ParameterSource.DEFAULT,
    )


for _command in (*_basic.COMMANDS, *_eeprom.COMMANDS, *_live.COMMANDS, *_simcmd.COMMANDS):
    cli.add_command(_command)


def main(argv: Sequence[str] | None = None) -> None:
    """Console-script entry point: runs ``ics35`` and exits with its code."""
    try:
        code = cli.main(args=list(argv) if argv is not None else None, prog_name="ics35", standalone_mode=False)
    except CliError as exc:
        fail(exc)
    except click.exceptions.Abort:
        click.echo("aborted", err=True)
        sys.exit(int(ExitCode.INTERRUPTED))
    except click.ClickException as exc:
        exc.show()
        sys.exit(exc.exit_code)
    except click.exceptions.Exit as exc:
        sys.exit(exc.exit_code)
    except BrokenPipeError:
        # `ics35 ... | head`: the reader left; not an error worth a traceback.
        sys.stderr.close()
        sys.exit(0)
    sys.exit(code if isinstance(code, int) else 0)


__all__ = ["CliError", "ExitCode", "cli", "main"]
