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
from ._common import CliError, ExitCode, ask_yes_no
from ._console import say, say_labelled

MANUAL = (
    "to do it by hand: save the rules (ics35 udev > 99-ics35-kondo.rules), "
    f"sudo cp 99-ics35-kondo.rules {RULES_PATH}, then {' ; '.join(RELOAD_STEPS)}"
)


def _writable(path: Path) -> bool:
    if path.exists():
        return os.access(path, os.W_OK)
    return path.parent.is_dir() and os.access(path.parent, os.W_OK)


def _read_only(directory: Path) -> bool:
    try:
        return bool(os.statvfs(directory).f_flag & os.ST_RDONLY)
    except OSError:
        return False


def _cannot_write(path: Path, why: str, *hints: str) -> CliError:
    return CliError(ExitCode.PORT, f"cannot write {path}: {why}", *(hints or (MANUAL,)))


def install(text: str, path: Path, yes: bool) -> None:
    """Write ``text`` to ``path``: directly if we may, else with sudo after a yes (never silently).

    What sudo cannot mend is said at once, without asking for it: a directory that is not there (sudo tee
    makes none: no udev on this machine, or a mistyped --path), a read-only file system, and for root any
    failed write."""
    directory = path.parent
    if not directory.is_dir():
        why = f"{directory} is not a directory" if directory.exists() else f"{directory} does not exist"
        if path == RULES_PATH:
            hint = "udev may not run here (a container?): install the rules on the machine the adapter plugs into"
            raise _cannot_write(path, why, hint)
        raise _cannot_write(path, why)
    if _read_only(directory):
        raise _cannot_write(path, f"{directory} is on a read-only file system")
    if os.geteuid() == 0 or _writable(path):  # (root: sudo would change nothing)
        try:
            path.write_text(text, encoding="utf-8")
        except OSError as exc:  # a full disk, or a place the checks above do not see (/proc, /sys)
            raise _cannot_write(path, exc.strerror or str(exc)) from None
        return
    if shutil.which("sudo") is None:
        raise CliError(ExitCode.PORT, f"{path} needs root to write, and there is no sudo here", MANUAL)
    command = ["sudo", "tee", str(path)]
    say(f"writing {escape(str(path))} needs root: this would run  [bold]{' '.join(command)}[/bold]")
    if not yes and not ask_yes_no("run it with sudo (it may ask for your password)?"):
        raise CliError(ExitCode.REFUSED, "not confirmed: nothing was written", MANUAL)
    try:
        done = subprocess.run(command, input=text.encode(), stdout=subprocess.DEVNULL, check=False)
    except KeyboardInterrupt:
        raise CliError(ExitCode.INTERRUPTED, f"interrupted: {path} may not have been written") from None
    if done.returncode != 0:
        raise CliError(ExitCode.REFUSED, f"sudo tee {path} failed (exit {done.returncode}): nothing written", MANUAL)


def _group_exists(name: str) -> bool:
    import grp  # (POSIX only: this command runs on Linux alone)

    try:
        grp.getgrnam(name)  # (the system's groups, LDAP's too: not only /etc/group)
    except KeyError:
        return False
    return True


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
    unknown = None if _group_exists(chosen) else f"group {chosen} does not exist on this system"
    if not do_install:
        click.echo(text, nl=False)
        if unknown:  # (rules printed for another machine may name its group)
            say_labelled(
                "[yellow]warning:[/yellow]", f"{escape(unknown)}: on this machine udev would leave the port root's"
            )
        return 0
    if unknown:
        # A rule with an unknown GROUP leaves the port root's, found out at the next plug-in.
        raise CliError(
            ExitCode.USAGE,
            f"{unknown}: its rule would leave the port root's; nothing was written",
            "pass --group with the group that owns serial ports here (ls -l /dev/ttyS0 names it)",
        )
    install(text, path, yes)
    say(f"wrote {escape(str(path))}; now reload the rules:")
    for step in RELOAD_STEPS:
        say(f"  {escape(step)}")
    if shutil.which("udevadm") is None:
        say_labelled(
            "[yellow]note:[/yellow]",
            "udevadm is not on this system (or not on PATH): udev may not run here"
            " (a container?); the rules act where udev runs, on the machine the adapter plugs into",
        )
    say(
        f"and make sure you are in group {escape(chosen)}: groups  (if not: sudo usermod -aG {escape(chosen)} "
        "$USER, then log in again)"
    )
    return 0


COMMANDS = [udev]
