"""Files a command will write or read, checked before the line is touched (so no work is lost at the end)."""

from __future__ import annotations

import os
from collections.abc import Collection
from pathlib import Path

from ..errors import InvalidArgument, error_text
from ..user_files import check_backup_room, empty_path
from ._settings import CliError, ExitCode, Settings


def _refuse(what: str, path: str, why: str) -> CliError:
    joined = f"{what}{path}" if what.endswith("=") else f"{what} {path}"  # --port sim://?record=FILE
    return CliError(ExitCode.USAGE, f"{joined}: {why} (nothing was sent)")


def _refuse_empty(path: str, what: str) -> None:
    if empty_path(path):
        raise CliError(ExitCode.USAGE, f"{what}: the path is empty; give a file name (nothing was sent)")


def check_output_path(path: str, what: str, formats: Collection[str] | None = None) -> Path:
    """``path`` if a file can be written there (and, given ``formats``, its suffix is one of them).

    Raises a :class:`CliError` (exit code 2) naming ``what`` (e.g. ``--plot``) otherwise.
    """
    _refuse_empty(path, what)
    target = Path(path)
    if target.is_dir():
        raise _refuse(what, path, "is a directory; give a file name")
    parent = target.parent
    if not parent.exists():
        raise _refuse(what, path, f"the directory {parent} does not exist")
    if not parent.is_dir():
        raise _refuse(what, path, f"{parent} is not a directory")
    if target.exists():
        if not os.access(target, os.W_OK):
            raise _refuse(what, path, "the file is not writable")
    elif not os.access(parent, os.W_OK | os.X_OK):
        raise _refuse(what, path, f"cannot create files in {parent}")
    if formats is not None:
        suffix = target.suffix.lower().lstrip(".")
        if suffix not in formats:
            shown = f".{suffix} files" if suffix else "files without a suffix"
            raise _refuse(what, path, f"cannot write {shown}; use one of: {', '.join(sorted(formats))}")
    return target


def check_backup_path(target: Path, what: str) -> None:
    """Refuse, before the work begins, a file whose old content cannot be kept as ``NAME.bak`` when it is
    replaced at the end (a directory there): a :class:`CliError` (exit code 2) naming ``what``."""
    try:
        check_backup_room(target)
    except OSError as exc:
        raise _refuse(what, str(target), error_text(exc)) from None


def check_input_path(path: str, what: str) -> Path:
    """``path`` if it is a readable file, else a :class:`CliError` (exit code 2)."""
    _refuse_empty(path, what)
    source = Path(path)
    if source.is_dir():
        raise _refuse(what, path, f"is a directory; give the file ({what}) itself")
    if not source.is_file():
        raise _refuse(what, path, "no such file")
    if not os.access(source, os.R_OK):
        raise _refuse(what, path, "the file is not readable")
    return source


def check_line_files(settings: Settings) -> None:
    """A sim:// port may name a file to record to or replay from: check it before opening the line."""
    if not settings.is_sim:
        return
    from ..sim import parse_url

    try:
        _, options = parse_url(settings.port)
    except InvalidArgument as exc:
        raise CliError(ExitCode.USAGE, f"{exc} (nothing was sent)") from None
    if isinstance(options.get("record"), str):
        check_output_path(options["record"], "--port sim://?record=")
    if isinstance(options.get("replay"), str):
        check_input_path(options["replay"], "--port sim://?replay=")
