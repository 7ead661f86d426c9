"""Replacing a user's file without losing it: the robot file calibration edits, a motion teach writes.

The new content is written whole to a new file beside the old one, flushed to the disk, and
renamed over it (a crash, a full disk or a power cut leaves the old file or the new one, never
half of either); the old content is kept as ``NAME.bak`` beside it, and the old file's line
endings (CRLF from a Windows editor) and permissions are kept.  A symbolic link is written
through: the link stays, the file it names gets the new content.
"""

from __future__ import annotations

import errno
import os
import secrets
import shutil
from pathlib import Path


def replace_keeping_backup(target: Path, text: str) -> Path | None:
    """Write ``text`` to ``target`` whole, the old content kept as ``NAME.bak`` beside it; returns that
    backup (``None`` when there was no file to keep).

    Raises:
        OSError: the file (or its backup) cannot be written; ``target`` and ``NAME.bak`` are then as they
            were.
    """
    if target.is_symlink():
        target = target.resolve()
    check_backup_room(target)
    newline = "\n"
    if target.exists() and b"\r\n" in target.read_bytes():
        newline = "\r\n"
    fresh = _beside(target, "new")
    # Created as any new file is (the umask applies), then given the old file's permissions.
    handle = os.open(fresh, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    try:
        with os.fdopen(handle, "w", encoding="utf-8", newline=newline) as file:
            file.write(text)
            file.flush()
            os.fsync(file.fileno())
        backup = _keep_backup(target)
        if backup is not None:
            shutil.copymode(backup, fresh)
        os.replace(fresh, target)
    except BaseException:
        fresh.unlink(missing_ok=True)
        raise
    return backup


def backup_path(target: Path) -> Path:
    """Where :func:`replace_keeping_backup` keeps ``target``'s old content: ``NAME.bak`` beside it (beside the
    file a symbolic link names, for a link)."""
    if target.is_symlink():
        target = target.resolve()
    return target.with_name(f"{target.name}.bak")


def check_backup_room(target: Path) -> None:
    """Refuse to go on when ``target`` has content to keep and its ``NAME.bak`` is a directory, which the backup
    cannot replace: a program checks this before the work whose result replaces ``target``, and
    :func:`replace_keeping_backup` before it writes anything.

    Raises:
        IsADirectoryError: naming the backup's path, in words (not "Is a directory" of ``target``'s).
    """
    backup = backup_path(target)
    if target.exists() and backup.is_dir() and not backup.is_symlink():  # (a link is replaced, not entered)
        raise IsADirectoryError(
            errno.EISDIR, f"its old content goes to {backup}, which is a directory: move or rename that", str(backup)
        )


def _beside(target: Path, suffix: str) -> Path:
    return target.with_name(f".{target.name}.{secrets.token_hex(4)}.{suffix}")


def _keep_backup(target: Path) -> Path | None:
    """Copy ``target`` to ``NAME.bak`` whole: copied beside it first and renamed over the old backup, so a copy
    that fails (a full disk) leaves the backup there was, not half of the new one."""
    if not target.exists():
        return None
    backup = backup_path(target)
    copy = _beside(target, "bak")
    try:
        shutil.copy2(target, copy)
        os.replace(copy, backup)
    except BaseException:
        copy.unlink(missing_ok=True)
        raise
    return backup
