"""A person's files: read as text by one rule, replaced without being lost.

Reading (a robot file, a motion, a start pose, an EEPROM backup, a recording): UTF-8 whatever the system's
encoding (a file written on one machine is read on another); a byte order mark some Windows editors write
first ("UTF-8 with BOM") is read past, as JSON and TOML refuse it; a binary file given by mistake, or text
saved in another encoding, is refused in words, not a codec's.

Replacing (the robot file calibration edits, a motion teach writes, an EEPROM backup dumped again): the new
content is written whole to a new file beside the old one, flushed to the disk, and renamed over it (a
crash, a full disk or a power cut leaves the old file or the new one, never half of either); the old content
is kept as ``NAME.bak`` beside it, and the old file's line endings (CRLF from a Windows editor) and
permissions are kept.  A symbolic link is written through: the link stays, the file it names gets the new
content.
"""

from __future__ import annotations

import codecs
import errno
import json
import os
import re
import secrets
import shutil
import stat
import tomllib
from pathlib import Path
from typing import Any

from .errors import error_text

# Control characters no text file holds (tab, line breaks, form feed and escape aside): in a file that is not
# UTF-8 either, they say binary, where text in another encoding (Latin-1, Shift JIS) has none.
_CONTROL = re.compile(rb"[\x00-\x08\x0e-\x1a\x1c-\x1f\x7f]")


class UnreadableText(ValueError):
    """The file cannot be read as UTF-8 text: the message says why, for a person, without the file's name
    (the caller's error names it)."""


def empty_path(path: object) -> bool:
    """Whether ``path``, as a person or a script gave it, names no file: an empty or blank string (a script's
    unset variable), which pathlib would read as ".", the current folder.  Each caller refuses it in its
    own words."""
    return isinstance(path, str) and not path.strip()


def is_device(path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` is a device node (a serial port, ``/dev/null``), not a file: one has no end to read to."""
    try:
        mode = os.stat(path).st_mode
    except (OSError, ValueError):  # (nothing there, or a name no path can be: not a device)
        return False
    return stat.S_ISCHR(mode) or stat.S_ISBLK(mode)


def read_user_text(path: str | Path, expected: str) -> str:
    """The text of the file at ``path``; ``expected`` says what it should be, e.g. ``"a motion is UTF-8 JSON"``.

    Raises:
        UnreadableText: an empty path, no such file, a directory, a device (a serial port), not readable, binary,
            or not UTF-8.
    """
    if empty_path(path):
        raise UnreadableText(f"the path is empty; give a file name ({expected})")
    try:
        # Looked at before it is opened: a serial port (open_robot("/dev/ttyUSB0"), the port where the robot file
        # goes) has no end, so reading it would wait for ever, and /dev/zero would fill the memory.  (A pipe ends
        # when its writer does: a shell's <(...) is read.)
        if is_device(path):
            raise UnreadableText(f"is a device (a serial port?), not a file ({expected})")
        raw = Path(path).read_bytes()
    except FileNotFoundError:
        raise UnreadableText("no such file") from None
    except IsADirectoryError:
        raise UnreadableText(f"is a directory, not a file ({expected})") from None
    except OSError as exc:
        raise UnreadableText(f"cannot read it ({exc.strerror or error_text(exc)})") from None  # (the caller names it)
    return decode_user_text(raw, expected)


def decode_user_text(raw: bytes, expected: str) -> str:
    """``raw`` (a file's bytes, or standard input's) as text, by :func:`read_user_text`'s rule.

    Raises:
        UnreadableText: binary, or not UTF-8.
    """
    if raw.startswith((codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)):  # Notepad's "Unicode"
        raise UnreadableText(f"is UTF-16 text ({expected}: save it as UTF-8)")
    if b"\0" in raw:  # no text holds a NUL byte; most binary files do (and UTF-16 without its mark)
        raise UnreadableText(f"not a text file ({expected})")
    body = raw.removeprefix(codecs.BOM_UTF8)  # (its offsets are the ones the codec names)
    try:
        return body.decode("utf-8")
    except UnicodeDecodeError as exc:
        if _CONTROL.search(body):  # (a program's header starts with one: 0x7f ELF)
            raise UnreadableText(f"not a text file ({expected})") from None
        line = body.count(b"\n", 0, exc.start) + 1
        raise UnreadableText(
            f"not UTF-8 text: byte 0x{body[exc.start]:02x} on line {line} ({expected}: save it as UTF-8)"
        ) from None


def parse_json(text: str | bytes) -> object:
    """``json.loads(text)``, with brackets nested deeper than Python's parser goes (a file edited into nonsense)
    refused as any malformed JSON is, not as a ``RecursionError`` that would reach a person as a traceback.

    Raises:
        json.JSONDecodeError: not JSON, or nested too deeply.
    """
    try:
        return json.loads(text)
    except RecursionError:
        doc = text.decode("utf-8", "replace") if isinstance(text, bytes) else text
        raise json.JSONDecodeError("nested too deeply", doc, 0) from None


def parse_toml(text: str) -> dict[str, Any]:
    """``tomllib.loads(text)``, with arrays or tables nested deeper than Python's parser goes refused as any
    malformed TOML is (as :func:`parse_json` does for JSON).

    Raises:
        tomllib.TOMLDecodeError: not TOML, or nested too deeply.
    """
    try:
        return tomllib.loads(text)
    except RecursionError:
        raise tomllib.TOMLDecodeError("nested too deeply") from None


def replace_keeping_backup(target: Path, text: str, *, like: Path | None = None) -> Path | None:
    """Write ``text`` to ``target`` whole, the old content kept as ``NAME.bak`` beside it; returns that
    backup (``None`` when there was no file to keep).  Its line endings are those ``target`` has (CRLF from a
    Windows editor stays CRLF), or given ``like``, those of that file.

    Raises:
        OSError: the file (or its backup) cannot be written; ``target`` and ``NAME.bak`` are then as they
            were.
    """
    if target.is_symlink():
        target = target.resolve()
    check_backup_room(target)
    newline = "\n"
    model = target if like is None else like
    if model.exists() and b"\r\n" in model.read_bytes():
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
