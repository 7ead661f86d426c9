"""Record the wire traffic of a session, and replay a recording as a device.

Format: UTF-8 text, one transaction a line, ``#`` starts a comment::

    # ics35 sim recording v1
    0.000573 81 3a 4c -> 81 3a 4c | 01 3a 4c  # id=1 position value=7500
    0.001200 a1 06 -> a1 06  # id=1 unknown
    0.002000 ff 00 00 00 -> ff 00 00 00 | e1 00  # read_id responders=1,2

Fields: the line's clock in seconds when the command ended, the bytes the
host sent (hex), ``->``, then every byte the host received during that
transaction in order: echo, an earlier late reply, the reply, noise.  ``|``
separates those parts for the reader and is ignored by the parser; ``-``
stands for nothing received.  A reply delivered late is recorded on the line
of the transaction during which it arrived.

:class:`ReplayDevice` serves a recording: whenever the host's bytes add up to
the next line's TX, it delivers that line's RX (at once: a replay has no
timing).  Bytes that do not match are kept in :attr:`ReplayDevice.mismatches`
and answered with silence, so a regression test ends with
``assert device.mismatches == [] and device.remaining == 0``.
"""

from __future__ import annotations

import errno
import threading
import time
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

from ..errors import InvalidArgument
from ..transports import HostSide
from ..user_files import UnreadableText, decode_user_text, empty_path
from .transaction import Transaction

HEADER = "# ics35 sim recording v1"


def _hex(data: bytes) -> str:
    return data.hex(" ")


def describe(record: Transaction) -> str:
    """The comment written after a recorded transaction."""
    parts = [f"id={record.servo_id}" if record.servo_id is not None else "id=-", record.command]
    if record.value is not None and record.command not in ("read_eeprom",):
        value = record.value.hex(" ") if isinstance(record.value, bytes) else record.value
        parts.append(f"value={value}")
    if len(record.responders) > 1:
        parts.append("responders=" + ",".join(map(str, record.responders)))
    if record.fault:
        parts.append(f"fault={record.fault}")
    return " ".join(parts)


class TransactionRecorder:
    """Writes one line per transaction to ``target``, a path (created, and closed by :meth:`close`) or a text stream.

    Raises:
        InvalidArgument: an empty path (nothing created).
        OSError: the file cannot be created.
    """

    def __init__(self, target: str | Path | TextIO) -> None:
        if empty_path(target):
            raise InvalidArgument("the recording's path is empty; give a file name")
        if isinstance(target, (str, Path)):
            self._stream: TextIO = open(target, "w", encoding="utf-8")  # noqa: SIM115 - closed in close()
            self._owned = True
        else:
            self._stream = target
            self._owned = False
        self._lock = threading.Lock()
        self._stream.write(HEADER + "\n")
        self.lines = 0

    def record(self, record: Transaction, rx_parts: list[bytes], baudrate: int) -> None:
        """Write the line of ``record``: its time, TX, and ``rx_parts`` (what the host received, in
        pieces) at ``baudrate``."""
        rx = " | ".join(_hex(p) for p in rx_parts if p) or "-"
        line = f"{record.time:.6f} {_hex(record.tx)} -> {rx}  # {describe(record)}\n"
        with self._lock:
            self._stream.write(line)
            self.lines += 1

    def flush(self) -> None:
        """Flush the stream."""
        with self._lock:
            self._stream.flush()

    def close(self) -> None:
        """Close a file it opened; flush a stream it was given."""
        with self._lock:
            if self._owned:
                self._stream.close()
            else:
                self._stream.flush()


@dataclass(frozen=True, slots=True)
class Entry:
    """One recorded transaction: when, what the host sent, what it received."""

    time: float
    tx: bytes
    rx: bytes
    comment: str = ""


def _parse_hex(text: str, where: str) -> bytes:
    tokens = [t for t in text.replace("|", " ").split() if t != "-"]
    try:
        return bytes(int(t, 16) for t in tokens)
    except ValueError:
        raise InvalidArgument(f"{where}: bad hex byte in {text.strip()!r}") from None


def parse_recording(lines: Iterable[str]) -> list[Entry]:
    """The entries of a recording's ``lines`` (``TIME TX -> RX  # comment``; blank and comment lines skipped).

    Raises:
        InvalidArgument: a line without ``->``, a bad time, an empty TX or a bad hex byte (the error names the line).
    """
    entries: list[Entry] = []
    for number, raw in enumerate(lines, 1):
        body, _, comment = raw.partition("#")
        if not body.strip():
            continue
        where = f"recording line {number}"
        left, arrow, right = body.partition("->")
        if not arrow:
            raise InvalidArgument(f"{where}: no '->' between TX and RX")
        fields = left.split(None, 1)
        if not fields:
            raise InvalidArgument(f"{where}: no time")
        try:
            stamp = float(fields[0])
        except ValueError:
            raise InvalidArgument(f"{where}: bad time {fields[0]!r}") from None
        tx = _parse_hex(fields[1] if len(fields) > 1 else "", where)
        if not tx:
            raise InvalidArgument(f"{where}: empty TX")
        entries.append(Entry(stamp, tx, _parse_hex(right, where), comment.strip()))
    return entries


def load_recording(source: str | Path | TextIO | Iterable[str]) -> list[Entry]:
    """Entries of a recording; ``source`` is a path, a text stream or lines.

    Raises:
        InvalidArgument: a line breaks the format (see :func:`parse_recording`), or the file is not UTF-8 text
            (a byte order mark first is read past).
        OSError: the file cannot be read.
    """
    if isinstance(source, (str, Path)):
        if empty_path(source):
            raise InvalidArgument("the recording's path is empty; give a file name")
        try:
            text = decode_user_text(Path(source).read_bytes(), "a recording is UTF-8 text")
        except UnreadableText as exc:
            raise InvalidArgument(f"{source}: {exc}") from None
        return parse_recording(text.split("\n"))  # (lines as the text's own: numbered as an editor shows them)
    return parse_recording(source)


@dataclass(frozen=True, slots=True)
class Mismatch:
    """Host bytes that did not match the recording at entry ``index``."""

    index: int
    expected: bytes
    got: bytes


class ReplayDevice:
    """A scripted device that plays a recording back (a :class:`WireDevice`).

    Also usable sans-IO via :meth:`feed`, which the pty server calls.

    Args:
        source: the recording: entries, a path, a text stream or lines.

    Raises:
        InvalidArgument: the recording breaks the format.
    """

    realtime = False

    def __init__(self, source: str | Path | TextIO | Iterable[str] | list[Entry]) -> None:
        if isinstance(source, list) and all(isinstance(e, Entry) for e in source):
            self.entries: list[Entry] = list(source)
        else:
            self.entries = load_recording(source)  # type: ignore[arg-type]
        self.index = 0
        self.mismatches: list[Mismatch] = []
        self.baudrate = 0
        self._buffer = bytearray()
        self._host: HostSide | None = None
        self._lock = threading.Lock()
        self.epoch = time.perf_counter()

    @property
    def remaining(self) -> int:
        """Entries not yet played."""
        return len(self.entries) - self.index

    def feed(self, data: bytes, now: float = 0.0) -> list[tuple[float, bytes]]:
        """Host bytes ``data`` written at ``now``: the recorded replies they complete, each at ``now``.

        Bytes that differ from the recording are kept in :attr:`mismatches` and dropped.
        """
        out: list[tuple[float, bytes]] = []
        with self._lock:
            self._buffer += data
            while self._buffer:
                if self.index >= len(self.entries):
                    self.mismatches.append(Mismatch(self.index, b"", bytes(self._buffer)))
                    self._buffer.clear()
                    break
                expected = self.entries[self.index].tx
                if self._buffer.startswith(expected):
                    del self._buffer[: len(expected)]
                    rx = self.entries[self.index].rx
                    self.index += 1
                    if rx:
                        out.append((now, rx))
                elif expected.startswith(self._buffer):
                    break  # the rest of the command is still to come
                else:
                    self.mismatches.append(Mismatch(self.index, expected, bytes(self._buffer)))
                    self._buffer.clear()
        return out

    def process(self, data: bytes) -> list[tuple[float, bytes]]:
        """:meth:`feed` ``data`` at the device's own clock."""
        return self.feed(data, self.now())

    def now(self) -> float:
        """Seconds since the device was made."""
        return time.perf_counter() - self.epoch

    def take_unplug_request(self) -> bool:
        """Always False: a recording is never unplugged (the pty server asks every device)."""
        return False

    def add_listener(self, callback: Any) -> None:
        """Ignored: a replay never unplugs, so ``callback`` would never be called."""
        pass

    # -- WireDevice

    def connect(self, host: HostSide, baudrate: int) -> None:
        """Open the device for ``host`` at ``baudrate`` (the WireDevice face).

        Raises:
            OSError: it is already open (``EBUSY``).
        """
        if self._host is not None:
            raise OSError(errno.EBUSY, "the replay device is already open")
        self._host = host
        self.baudrate = baudrate

    def write(self, data: bytes) -> None:
        """Take the host's ``data``; the replies it completes are delivered at once.

        Raises:
            OSError: the device is not open (``EIO``).
        """
        host = self._host
        if host is None:
            raise OSError(errno.EIO, "the replay device is not open")
        chunks = self.feed(data)
        if chunks:
            host.deliver(b"".join(c for _, c in chunks))

    def disconnect(self) -> None:
        """Close the device for its host."""
        self._host = None

    def close(self) -> None:
        """The same as :meth:`disconnect`."""
        self._host = None

    def __repr__(self) -> str:
        return f"<ReplayDevice {self.index}/{len(self.entries)} mismatches={len(self.mismatches)}>"
