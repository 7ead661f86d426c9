"""``ics35 sim``: the simulator's own command line (``python -m ics35_async.sim``), mounted here."""

from __future__ import annotations

import argparse
from typing import IO, Any, NoReturn

import click
from rich.markup import escape

from ._console import say_labelled
from ._settings import settings_of


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
    from ..sim.server_cli import build_parser, main

    if "-h" in args or "--help" in args:
        click.echo(click_style_help(build_parser("ics35 sim"), "ics35 sim"), nl=False)
        return 0
    settings = settings_of(click.get_current_context())
    if not settings.port_defaulted and not any(v.startswith("ICS35_PORT=") for v in settings.from_environment):
        # (a port given on the command line was meant as where to serve, most likely)
        say_labelled(
            "[dim]note:[/dim]",
            f"[dim]ics35 sim serves a line of its own: --port is not used ({escape(settings.port)}); --link PATH "
            "names the path it serves at[/dim]",
        )
    return main(list(args), prog="ics35 sim", parser_class=ClickStyleErrors)


class SimUsageError(click.UsageError):
    """A usage error of ``ics35 sim``, shown as click shows every other command's (its usage line is the
    help's: the command's own context knows only its pass-through ARGS)."""

    def show(self, file: IO[Any] | None = None) -> None:
        usage = "Usage: ics35 sim [OPTIONS]\nTry 'ics35 sim --help' for help."
        click.echo(f"{usage}\n\nError: {self.message}", file=file, err=file is None)


class ClickStyleErrors(argparse.ArgumentParser):
    """The simulator's parser, its usage errors raised as click's (exit 2, ExitCode.USAGE) instead of
    argparse's usage block and ``ics35 sim: error:`` line."""

    def error(self, message: str) -> NoReturn:
        raise SimUsageError(message[:1].upper() + message[1:])


def click_style_help(parser: argparse.ArgumentParser, prog: str) -> str:
    """The simulator's argparse options laid out as click lays out every other command's help."""
    formatter = click.Context.formatter_class()  # (the one every command's help has in this process: see main)
    formatter.write_usage(prog, "[OPTIONS]")
    if parser.description:
        formatter.write_paragraph()
        with formatter.indentation():
            formatter.write_text(parser.description)
    rows: list[tuple[str, str]] = []
    for action in parser._actions:  # argparse keeps no public list of its options
        if not action.option_strings or isinstance(action, argparse._HelpAction):
            continue
        name = ", ".join(action.option_strings)
        if action.nargs != 0:
            name += f" {action.metavar or ('INTEGER' if action.type is int else 'TEXT')}"
        text = action.help or ""
        rows.append((name, text[:1].upper() + text[1:] + ("." if text and not text.endswith(".") else "")))
    rows.append(("-h, --help", "Show this message and exit."))
    with formatter.section("Options"):
        formatter.write_dl(rows)
    return formatter.getvalue()


COMMANDS = [sim]
