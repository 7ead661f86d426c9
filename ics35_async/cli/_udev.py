"""udev: the rules for Kondo's USB adapters on Linux, printed, or installed after asking (library: diagnose.udev)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import click
from rich.markup import escape

from ..diagnose.udev import RELOAD_STEPS, RULES_PATH, rules_text, serial_group
from ._common import CliError, ExitCode, ask_yes_no, err

MANUAL = (
    "to do it by hand: save the rules (ics35 udev > 99-ics35-kondo.rules), "
    f"sudo cp 99-ics35-kondo.rules {RULES_PATH}, then {' ; '.join(RELOAD_STEPS)}"
)


def _writable(path: Path) -> bool:
    if path.exists():
        return os.access(path, os.W_OK)
    return path.parent.is_dir() and os.access(path.parent, os.W_OK)


def install(text: str, path: Path, yes: bool) -> None:
    """Write ``text`` to ``path``: directly if we may, else with sudo after a yes (never silently)."""
    if _writable(path):
        path.write_text(text, encoding="utf-8")
        return
    if shutil.which("sudo") is None:
        raise CliError(ExitCode.PORT, f"{path} needs root to write, and there is no sudo here", MANUAL)
    command = ["sudo", "tee", str(path)]
    err.print(f"writing {escape(str(path))} needs root: this would run  [bold]{' '.join(command)}[/bold]")
    if not yes and not ask_yes_no("run it with sudo (it may ask for your password)?"):
        raise CliError(ExitCode.REFUSED, "not confirmed: nothing was written", MANUAL)
    try:
        done = subprocess.run(command, input=text.encode(), stdout=subprocess.DEVNULL, check=False)
    except KeyboardInterrupt:
        raise CliError(ExitCode.INTERRUPTED, f"interrupted: {path} may not have been written") from None
    if done.returncode != 0:
        raise CliError(ExitCode.REFUSED, f"sudo tee {path} failed (exit {done.returncode}): nothing written", MANUAL)


@click.command()
@click.option("--group", default=None, help="The group the port gets (default: dialout or uucp, one you are in).")
@click.option("--install", "do_install", is_flag=True, help=f"Write the rules to {RULES_PATH} (asks before sudo).")
@click.option(
    "--path",
    "path",
    type=click.Path(dir_okay=False, path_type=Path),
    default=RULES_PATH,
    show_default=True,
    help="Where --install writes the rules.",
)
@click.option("--yes", "-y", is_flag=True, help="Run sudo without asking (it is still printed).")
def udev(group: str | None, do_install: bool, path: Path, yes: bool) -> int:
    """Print udev rules for Kondo's ICS USB adapters (Linux): bind 165C:0006 and 165C:0008 to ftdi_sio,
    the port's group, a stable name by serial number, and the latency timer at 1 ms.

    \b
    ics35 udev                    print them (save with: ics35 udev > 99-ics35-kondo.rules)
    ics35 udev --install          write them to /etc/udev/rules.d (asks before using sudo)
    """
    if not sys.platform.startswith("linux"):
        raise CliError(
            ExitCode.USAGE,
            "udev rules are Linux's: nothing to do on this system",
            "see ics35 doctor for this system's steps",
        )
    chosen = group or serial_group(user_gids=set(os.getgroups()) | {os.getegid()})
    text = rules_text(chosen)
    if not do_install:
        click.echo(text, nl=False)
        return 0
    install(text, path, yes)
    err.print(f"wrote {escape(str(path))}; now reload the rules:")
    for step in RELOAD_STEPS:
        err.print(f"  {escape(step)}")
    err.print(
        f"and make sure you are in group {escape(chosen)}: groups  (if not: sudo usermod -aG {escape(chosen)} "
        "$USER, then log in again)"
    )
    return 0


COMMANDS = [udev]
