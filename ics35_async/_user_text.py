"""Reading a person's text file (a robot file, a motion, a start pose, an EEPROM backup): one rule for all.

UTF-8 whatever the system's encoding (a file written on one machine is read on another); a byte order
mark some Windows editors write first ("UTF-8 with BOM") is read past, as JSON and TOML refuse it; a
binary file given by mistake, or text saved in another encoding, is refused in words, not a codec's.
"""

from __future__ import annotations

import codecs
import re
from pathlib import Path

from .errors import error_text

# Control characters no text file holds (tab, line breaks, form feed and escape aside): in a file that is not
# UTF-8 either, they say binary, where text in another encoding (Latin-1, Shift JIS) has none.
_CONTROL = re.compile(rb"[\x00-\x08\x0e-\x1a\x1c-\x1f\x7f]")


class UnreadableText(ValueError):
    """The file cannot be read as UTF-8 text: the message says why, for a person, without the file's name
    (the caller's error names it)."""


def read_user_text(path: str | Path, expected: str) -> str:
    """The text of the file at ``path``; ``expected`` says what it should be, e.g. ``"a motion is UTF-8 JSON"``.

    Raises:
        UnreadableText: no such file, a directory, not readable, binary, or not UTF-8.
    """
    try:
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
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        if _CONTROL.search(raw):  # (a program's header starts with one: 0x7f ELF)
            raise UnreadableText(f"not a text file ({expected})") from None
        line = raw.count(b"\n", 0, exc.start) + 1
        raise UnreadableText(
            f"not UTF-8 text: byte 0x{raw[exc.start]:02x} on line {line} ({expected}: save it as UTF-8)"
        ) from None
