"""``ics35 sim``: the simulator's own command line (``python -m ics35_async.sim``), mounted here."""

from __future__ import annotations

import argparse

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
    from ..sim.server_cli import build_parser, main

    if "-h" in args or "--help" in args:
        click.echo(click_style_help(build_parser("ics35 sim"), "ics35 sim"), nl=False)
        return 0
    return main(list(args), prog="ics35 sim")


def click_style_help(parser: argparse.ArgumentParser, prog: str) -> str:
    """The simulator's argparse options laid out as click lays out every other command's help."""
    formatter = click.HelpFormatter()
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
