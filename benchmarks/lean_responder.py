"""A lean pty responder: the far end of a benchmark whose own cost is small, so the client's dominates.

The full simulator costs about 100 us of its own per transaction, which
hides most of a client's cost.  This responder only does what the
half-duplex ICS line does for the commands a benchmark sends:

* a position command (3 bytes, 0x80|ID) -> its echo + a 3-byte reply with
  the servo's position (the target it was last sent; FREE leaves it);
* a parameter read (2 bytes, 0xA0|ID, 1..4) -> its echo + a 3-byte reply
  (fixed values);
* anything else is dropped byte by byte (the client times out).

Every ID 0..31 answers.  ID 0 at 115200 keeps the MSB in its position reply's
header, as real servos do (ICS 2.0 compatibility).  With ``wire=True`` each
answer is held back until the transaction would have finished on a wire at
``baud`` (11 bits a byte, no turnaround, one transaction after the other on
each line): the responder sleeps (1 ns timer slack) until 100 us before an
answer is due, then polls without sleeping, so it answers at or a few
microseconds after the wire time (and keeps a core busy while answers are
due).  One process serves ``lines``
ptys (``select``); a single untimed line uses a plain blocking read loop.

    with lean_lines(4, baud=1250000, wire=True) as paths: ...
    .venv/bin/python benchmarks/lean_responder.py FD [FD ...] [--baud B] [--wire]   (what the child runs)
"""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import os
import select
import subprocess
import sys
import time
from collections import deque
from collections.abc import Iterator
from pathlib import Path

SPIN_MARGIN = 100e-6
"""Wire mode: seconds before an answer is due at which the responder stops sleeping and polls."""
PARAMS = (0, 30, 100, 5, 70)  # stretch, speed, current, temperature: plausible fixed answers


class Line:
    """One pty master: framing of the host's bytes and the answers (echo + reply) they call for."""

    def __init__(self, fd: int, baud: int, wire: bool) -> None:
        self.fd = fd
        self.pending = b""
        self.positions = [7500] * 32
        self.id0_header = 0x80 if baud == 115200 else 0x00
        self.byte_time = 11 / baud if wire else 0.0
        self.busy_until = 0.0  # wire mode: when the line's last transaction ends
        self.due: deque[tuple[float, bytes]] = deque()

    def answers(self, data: bytes) -> list[bytes]:
        buf = self.pending + data
        out: list[bytes] = []
        i, n = 0, len(buf)
        while i < n:
            head = buf[i]
            kind, sid = head & 0xE0, head & 0x1F
            if kind == 0x80:
                if n - i < 3:
                    break
                target = buf[i + 1] << 7 | buf[i + 2]
                if target:
                    self.positions[sid] = target
                p = self.positions[sid]
                header = self.id0_header if sid == 0 else head & 0x7F
                out.append(buf[i : i + 3] + bytes((header, p >> 7, p & 0x7F)))
                i += 3
            elif kind == 0xA0:
                if n - i < 2:
                    break
                sc = buf[i + 1]
                if 1 <= sc <= 4:
                    out.append(buf[i : i + 2] + bytes((head & 0x7F, sc, PARAMS[sc])))
                i += 2
            else:
                i += 1
        self.pending = buf[i:]
        return out


def lower_timer_slack() -> None:
    """So that a sleep of tens of microseconds wakes close to its target (Linux; harmless elsewhere)."""
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None).prctl(29, 1, 0, 0, 0)  # PR_SET_TIMERSLACK, 1 ns


def serve_blocking(fd: int, baud: int) -> None:
    """The leanest loop: read, answer at once, write."""
    line = Line(fd, baud, wire=False)
    read, write = os.read, os.write
    while True:
        try:
            data = read(fd, 4096)
        except OSError:  # EIO: the last slave fd closed
            return
        if not data:
            return
        out = line.answers(data)
        if out:
            write(fd, b"".join(out))


def serve(fds: list[int], baud: int, wire: bool) -> None:
    """Several lines in one process; answers due at their wire times."""
    lower_timer_slack()
    lines = {fd: Line(fd, baud, wire) for fd in fds}
    clock = time.perf_counter
    while True:
        due = [line.due[0][0] for line in lines.values() if line.due]
        timeout = None
        if due:
            # Sleep until SPIN_MARGIN before the next answer is due, then poll without sleeping: a sleep
            # overshoots by tens of microseconds, a whole transaction at 1.25 Mbit/s.
            timeout = min(due) - clock() - SPIN_MARGIN
            timeout = timeout if timeout > 0 else 0.0
        ready, _, _ = select.select(list(lines), [], [], timeout)
        for fd in ready:
            try:
                data = os.read(fd, 4096)
            except OSError:
                return
            if not data:
                return
            line = lines[fd]
            now = clock()
            for answer in line.answers(data):
                if not wire:
                    os.write(fd, answer)
                    continue
                line.busy_until = max(now, line.busy_until) + len(answer) * line.byte_time
                line.due.append((line.busy_until, answer))
        now = clock()
        for line in lines.values():
            while line.due and line.due[0][0] <= now:
                os.write(line.fd, line.due.popleft()[1])


@contextlib.contextmanager
def lean_lines(lines: int = 1, *, baud: int = 115200, wire: bool = False) -> Iterator[list[str]]:
    """``lines`` ptys answered by one responder child process; yields their device paths."""
    masters, slaves = [], []
    for _ in range(lines):
        master, slave = os.openpty()  # we keep a slave fd so the master never sees EIO between opens
        masters.append(master)
        slaves.append(slave)
    args = [sys.executable, str(Path(__file__).resolve()), *map(str, masters), "--baud", str(baud)]
    proc = subprocess.Popen([*args, *(["--wire"] if wire else [])], pass_fds=masters, stdout=subprocess.PIPE)
    for master in masters:
        os.close(master)
    try:
        # Wait for the child to be serving: a command written before it reads would be answered late,
        # after the client's allowance (a false timeout, or a late reply taken by the next command).
        assert proc.stdout is not None
        ready, _, _ = select.select([proc.stdout], [], [], 15)
        if not ready or not proc.stdout.readline():
            raise RuntimeError(f"the lean responder did not start (exit code {proc.poll()})")
        yield [os.ttyname(slave) for slave in slaves]
    finally:
        for slave in slaves:
            os.close(slave)
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        if proc.stdout is not None:
            proc.stdout.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("fds", nargs="+", type=int, help="pty master file descriptors (inherited)")
    parser.add_argument("--baud", type=int, default=115200)
    parser.add_argument("--wire", action="store_true", help="answer at the wire time of each transaction")
    args = parser.parse_args()
    print("ready", flush=True)
    if len(args.fds) == 1 and not args.wire:
        serve_blocking(args.fds[0], args.baud)
    else:
        serve(args.fds, args.baud, args.wire)


if __name__ == "__main__":
    main()
