"""``ics35 sim``: the simulator's own command line (``python -m ics35_async.sim``), mounted here."""

from __future__ import annotations

import click


@click.command(
    context_settings={"ignore_unknown_options": True, "allow_extra_args": True, "help_option_names": []},
    add_help_option=False,
)
@click.argument("args", nargs=-1, type=click.UNPROCESSED)
def sim(args: tuple[str, ...]) -> int:
    """Serve simulated servos on a pseudo-terminal, in real time unless --fast (ics35 sim --help lists its options).

    Prints the device path on its first line; use it as --port in another terminal.
    """
    # Imported here, not at the top: the pty server needs termios/fcntl (POSIX only),
    # and every other command must load on any platform.
    from ..sim.server_cli import main

    return main(list(args), prog="ics35 sim")


COMMANDS = [sim]
