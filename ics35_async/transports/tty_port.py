"""A port with a POSIX file descriptor (device paths, ptys): read and written with ``os.read``/``os.write``.

pyserial opens and configures the port; after that, reading is one
``os.read`` per readiness event and writing one ``os.write``, skipping
pyserial's per-call ``select`` and timeout bookkeeping.  The port never
waits: each driver waits on :attr:`TtyPort.fd` in its own way (an event
loop's reader, ``poll`` in an I/O thread, ``anyio.wait_readable``).
"""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import select
from collections.abc import Callable

import serial

from .serial_port import TermiosError

try:
    import termios
except ImportError:  # no POSIX terminals (Windows): nothing here is chosen for a port there
    termios = None  # type: ignore[assignment]

log = logging.getLogger("ics35_async.transports")

READ_SIZE = 4096
DISCARD_READS = 16
"""Reads a discard makes at most before it flushes the rest unread (a line that never stops talking)."""


class ParityMarks:
    """Undo the kernel's PARMRK marking of received bytes.

    With INPCK and PARMRK set (and IGNPAR, ISTRIP clear), Linux passes a
    byte that arrived with a parity or framing error as ``FF 00 x`` and a
    genuine ``FF`` as ``FF FF``.  :meth:`decode` returns the bytes as they
    were on the wire and how many of them were marked bad; a mark split
    across two reads is completed by the next call.
    """

    __slots__ = ("_pending",)

    def __init__(self) -> None:
        self._pending = b""

    @property
    def pending(self) -> bool:
        """A mark split across reads waits for its next byte: the next chunk must be decoded."""
        return bool(self._pending)

    def forget(self) -> None:
        """Drop half a mark (the input it belonged to was discarded)."""
        self._pending = b""

    def decode(self, data: bytes) -> tuple[bytes, int]:
        if self._pending:
            data = self._pending + data
            self._pending = b""
        elif 0xFF not in data:
            return data, 0
        out = bytearray()
        errors = 0
        i, n = 0, len(data)
        while i < n:
            j = data.find(b"\xff", i)
            if j < 0:
                out += data[i:]
                break
            out += data[i:j]
            if j + 1 >= n:
                self._pending = data[j:]
                break
            if data[j + 1] == 0xFF:
                out.append(0xFF)
                i = j + 2
            elif data[j + 1] == 0x00:
                if j + 2 >= n:
                    self._pending = data[j:]
                    break
                out.append(data[j + 2])
                errors += 1
                i = j + 3
            else:  # not a mark (PARMRK off after all): keep it as it came
                out.append(0xFF)
                i = j + 1
        return bytes(out), errors


def enable_parity_marks(fd: int) -> bool:
    """Ask the kernel to mark bytes received with parity/framing errors; True if set."""
    try:
        attrs = termios.tcgetattr(fd)
        attrs[0] |= termios.INPCK | termios.PARMRK
        attrs[0] &= ~(termios.IGNPAR | termios.ISTRIP)
        termios.tcsetattr(fd, termios.TCSANOW, attrs)
        return bool(termios.tcgetattr(fd)[0] & termios.PARMRK)
    except termios.error:
        log.debug("could not enable parity-error marks on fd %d", fd, exc_info=True)
        return False


def hung_up(fd: int) -> bool:
    """Whether a tty whose read gave 0 bytes has really gone (POLLHUP), not just had its input flushed."""
    poller = select.poll()
    poller.register(fd, select.POLLIN)
    return any(events & (select.POLLHUP | select.POLLERR | select.POLLNVAL) for _, events in poller.poll(0))


# The errors a tty gives once its device has gone (an adapter pulled out, a pty's other end closed).
GONE_ERRNOS = frozenset({errno.EIO, errno.ENXIO, errno.ENODEV})


def port_gone(code: int | None) -> OSError:
    """The error a read or write of a tty that failed with ``code`` raises: for a device gone, in one wording
    whichever call met it first (the read's hang-up and the write's "Input/output error" were one adapter pulled
    out); any other failure in the system's words."""
    code = code or errno.EIO  # (none given, or the executor's 0: a failure all the same)
    if code in GONE_ERRNOS:
        return OSError(code, "the serial port hung up (device disconnected?)")
    return OSError(code, os.strerror(code))


class TtyPort:
    """A tty or pty that pyserial opened, read and written on its descriptor.

    :meth:`read` never blocks: it returns what has arrived (``b""`` if
    nothing), parity marks decoded and the damaged bytes counted in
    :attr:`bad`; it raises :class:`OSError` when the device has gone.
    :meth:`write` writes at once; what the port cannot take yet waits in
    :attr:`pending` until the driver sees the descriptor writable and calls
    :meth:`write_pending`.
    """

    kind = "tty"

    def __init__(self, ser: serial.SerialBase) -> None:
        self.serial = ser
        self.fd: int = ser.fileno()
        # pyserial opens O_NONBLOCK; rely on it being so, since with VMIN=0 a blocking read of an
        # empty tty returns 0 bytes, which would look like a hangup.
        os.set_blocking(self.fd, False)
        # pyserial turns input parity checking off; ICS replies carry no checksum, so a damaged
        # byte is caught only if the kernel marks it (and it is unmarked here).
        self._marks: ParityMarks | None = ParityMarks() if enable_parity_marks(self.fd) else None
        self.bad = 0  # bytes marked damaged since the driver last took the count
        self.pending = bytearray()  # what a partial write left
        self.closed = False

    @property
    def decode_marks(self) -> Callable[[bytes], tuple[bytes, int]] | None:
        """The decoder of the kernel's parity marks, when the port marks them (for the burst path,
        whose executor reads the descriptor itself)."""
        return self._marks.decode if self._marks is not None else None

    def in_between(self) -> bool:
        """Bytes still to write, or half a parity mark read: the ordinary path must finish them first."""
        return bool(self.pending) or (self._marks is not None and self._marks.pending)

    def read(self) -> bytes:
        try:
            data = os.read(self.fd, READ_SIZE)
        except (BlockingIOError, InterruptedError):
            return b""
        except OSError as exc:
            raise port_gone(exc.errno) from exc
        if not data:
            # A raw tty (VMIN=0, VTIME=0) reads 0 bytes when nothing waits, and when its input was
            # flushed (a resync) between a readiness event and this read (Linux returns 0 there
            # even with O_NONBLOCK): only POLLHUP is a hangup.
            if hung_up(self.fd):
                raise port_gone(errno.EIO)
            return b""
        marks = self._marks
        if marks is not None and (0xFF in data or marks.pending):
            data, errors = marks.decode(data)
            self.bad += errors
        return data

    def write(self, data: bytes) -> bool:
        """Write ``data``; False if part of it waits in :attr:`pending` for the port to take it."""
        if self.pending:
            self.pending += data
            return False
        try:
            n = os.write(self.fd, data)
        except (BlockingIOError, InterruptedError):
            n = 0
        except OSError as exc:
            raise port_gone(exc.errno) from exc
        if n == len(data):
            return True
        self.pending += data[n:]
        return False

    def write_pending(self) -> bool:
        """Write what a partial write left, as far as the port takes it; True once nothing is left."""
        if self.pending:
            try:
                n = os.write(self.fd, self.pending)
            except (BlockingIOError, InterruptedError):
                return False
            except OSError as exc:
                raise port_gone(exc.errno) from exc
            del self.pending[:n]
        return not self.pending

    def discard_input(self) -> int:
        """Drop what sits in the OS input buffer; return how many bytes that was.

        Read, not flushed with ``tcflush``: bytes that came while the driver was not looking
        (a late reply landing as a resync ends) are counted, never lost without a trace.  A
        port that is gone says so at its next read.
        """
        dropped = 0
        marks = self._marks
        with contextlib.suppress(OSError):
            for _ in range(DISCARD_READS):
                data = os.read(self.fd, READ_SIZE)
                if not data:
                    break
                if marks is not None:
                    data, _ = marks.decode(data)  # bytes of no transaction: their damage is nobody's
                dropped += len(data)
            else:  # still talking: what is left goes unread
                with contextlib.suppress(TermiosError):
                    termios.tcflush(self.fd, termios.TCIFLUSH)
        if marks is not None:
            marks.forget()
        return dropped

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        self.pending.clear()
        try:
            self.serial.close()
        except Exception:
            log.debug("closing %s failed", self.serial.port, exc_info=True)
