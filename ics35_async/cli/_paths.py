"""Files a command will write or read, checked before the line is touched (so no work is lost at the end)."""

from __future__ import annotations

import os
from collections.abc import Collection
from pathlib import Path

from ..errors import InvalidArgument, error_text
from ..user_files import check_backup_room, empty_path
from ._settings import CliError, ExitCode, Settings


class InputPathError(CliError):
    """An input file that cannot be read (exit code 2): ``missing`` when there is no file at the path (or no
    path), else it is there but cannot be read (a directory, no permission)."""

    def __init__(self, message: str, *, missing: bool) -> None:
        super().__init__(ExitCode.USAGE, message)
        self.missing = missing


def _said(what: str, path: str, why: str) -> str:
    joined = f"{what}{path}" if what.endswith("=") else f"{what} {path}"  # --port sim://?record=FILE
    return f"{joined}: {why} (nothing was sent)"


def _refuse(what: str, path: str, why: str) -> CliError:
    return CliError(ExitCode.USAGE, _said(what, path, why))


def _empty_path_said(what: str) -> str:
    return f"{what}: the path is empty; give a file name (nothing was sent)"


def _refuse_empty(path: str, what: str) -> None:
    if empty_path(path):
        raise CliError(ExitCode.USAGE, _empty_path_said(what))


def names_directory(path: str) -> bool:
    """Whether ``path``, given where output goes, names a directory: one that is there, or a path ending in a
    separator (``backup/``, a directory to make)."""
    return path.endswith(("/", os.sep)) or Path(path).is_dir()


def check_output_dir(path: str, what: str) -> Path:
    """``path`` (a directory: :func:`names_directory`) if files can be made in it: it is there, or its parent is
    (it is made when the files are written).  A missing parent is refused, not made: ``bakcup/2024/`` is a typo
    far more often than a tree to grow, and the files would go where nobody looks.  A :class:`CliError` (exit
    code 2) naming ``what`` otherwise."""
    _refuse_empty(path, what)
    directory = Path(path)
    existing = directory if directory.exists() else directory.parent
    if not existing.exists():
        raise _refuse(what, path, f"the directory {existing} does not exist")
    if not existing.is_dir():
        raise _refuse(what, path, f"{existing} is not a directory")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise _refuse(what, path, f"cannot create files in {existing}")
    return directory


def check_output_path(
    path: str, what: str, formats: Collection[str] | None = None, *, default_name: str | None = None
) -> Path:
    """The file to write for ``path`` if one can be written there (and, given ``formats``, its suffix is one of
    them).  ``path`` naming a directory (:func:`names_directory`): the file ``default_name`` in it, the name the
    command gives a file of its own (its parent must be there: see :func:`check_output_dir`); a command with no
    name of its own refuses it (it wrote a file named like the directory, ``heard/`` into ``heard``).

    Raises a :class:`CliError` (exit code 2) naming ``what`` (e.g. ``--plot``) otherwise.
    """
    _refuse_empty(path, what)
    if names_directory(path):
        if default_name is None:
            why = "is a directory" if Path(path).is_dir() else "names a directory"
            raise _refuse(what, path, f"{why}; give a file name")
        target = check_output_dir(path, what) / default_name
        if not target.parent.exists():
            return target  # (in a directory made as it is written)
    else:
        target = Path(path)
    if target.is_dir():
        raise _refuse(what, path, "is a directory" if default_name is None else f"{target} is a directory")
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
    """``path`` if it is a readable file, else an :class:`InputPathError` (exit code 2)."""
    if empty_path(path):
        raise InputPathError(_empty_path_said(what), missing=True)
    source = Path(path)
    if source.is_dir():
        raise InputPathError(_said(what, path, f"is a directory; give the file ({what}) itself"), missing=False)
    if source.is_char_device() or source.is_block_device():  # (a serial port given where the file goes)
        raise InputPathError(_said(what, path, "is a device (a serial port?), not a file"), missing=False)
    if not source.is_file():
        raise InputPathError(_said(what, path, "no such file"), missing=True)
    if not os.access(source, os.R_OK):
        raise InputPathError(_said(what, path, "the file is not readable"), missing=False)
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
