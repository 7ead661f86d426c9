"""Replacing a user's file without losing it: the robot file calibration edits, a motion teach writes.

The new content is written whole to a new file renamed over the old one (a crash or a full disk
leaves the old file or the new one, never half of either), the old content is kept as
``NAME.bak`` beside it, and the old file's line endings (CRLF from a Windows editor) are kept.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path


def replace_keeping_backup(target: Path, text: str) -> Path | None:
    """Write ``text`` to ``target`` whole, the old content kept as ``NAME.bak`` beside it; returns that
    backup (``None`` when there was no file to keep).

    Raises:
        OSError: the file (or its backup) cannot be written; ``target`` is then as it was.
    """
    backup: Path | None = None
    newline = "\n"
    if target.exists():
        if b"\r\n" in target.read_bytes():
            newline = "\r\n"
        backup = target.with_name(f"{target.name}.bak")
        shutil.copy2(target, backup)
    fresh = target.with_name(f".{target.name}.new")
    try:
        with fresh.open("w", encoding="utf-8", newline=newline) as file:
            file.write(text)
        os.replace(fresh, target)
    except BaseException:
        fresh.unlink(missing_ok=True)
        raise
    return backup
