"""Serve a simulated line on a pseudo-terminal, for any program that opens a serial port.

``python -m ics35_async.sim --ids 0-31`` (or ``ics35 sim``) prints the
device path on its first line and serves until SIGINT or SIGTERM.  The path
is a symlink in a private temporary directory (or ``--link PATH``) to the
current ``/dev/pts/N``; it stays the same when the simulated port is
unplugged (the link disappears and the pty closes, so an open client sees a
hang-up) and plugged back in (a new pty, the link points at it again).

Line speed: the server reads the client's baud rate from the pty settings
(TCGETS2 on the master), so the simulated line runs at whatever the client
opened it at and servos at another rate stay silent, as on a real wire
(``--fixed-baud`` keeps the line at ``--baud`` instead).

Parity on a Linux pty, as verified on kernel 6.18 with glibc 2.36 and
pyserial 3.5: the pty driver silently clears PARENB (and forces CS8) on
every settings change, and glibc's ``tcsetattr`` re-reads the settings and
reports EINVAL when PARENB did not stick, except when the same call also
changes the baud rate.  For pyserial this means:

* ``serial.Serial(path, 115200, parity=serial.PARITY_EVEN, timeout=0.1)``
  succeeds when the pty was at another speed;
* any later re-configuration at an unchanged speed (setting ``.timeout``,
  ``.write_timeout``, ``.parity``...; pyserial-asyncio does
  ``timeout = 0`` right after opening) raises ``termios.error`` (errno 22,
  EINVAL) -- although the kernel applied everything except PARENB, so a
  client may catch that error and carry on; opening 8N1 avoids it entirely;
* so does a second open at the speed the pty is already at.

To soften this the server "parks" the pty at 38400 bit/s (not an ICS rate;
other settings untouched) as soon as it has read the client's speed, i.e.
with the client's first bytes, and whenever the last client closes it.  A
fresh open, and a re-configuration made after the client has sent
something, then change the speed and pass.  A re-configuration straight
after opening, before any byte, still races the server: do not rely on it.
A plain pyserial client passes ``timeout`` (and ``parity``) to the
constructor and changes nothing afterwards.  (A client that really runs at
38400 is taken to be at the previous speed.)

Timing: in fast mode answers are written at once.  In real-time mode the
server's single thread waits for each chunk's wire time with sleep-then-spin
(:func:`.clock.wait_until`) and then writes it to the master; reading is
timestamped when the bytes are read.  The pty adds its own latency on top
(see the figures in :mod:`ics35_async.sim`).
"""

from __future__ import annotations

import argparse
import array
import contextlib
import ctypes
import errno
import fcntl
import heapq
import itertools
import os
import select
import shutil
import signal
import subprocess
import sys
import tempfile
import termios
import time
import tty
from collections.abc import Iterator, Sequence
from pathlib import Path
from types import FrameType
from typing import Any

from ..eeprom import BaudRate
from ..errors import InvalidArgument
from .clock import SPIN_MARGIN, lower_timer_slack, wait_until
from .faults import FaultConfig, parse_ids
from .line import DEFAULT_EEPROM_WRITE_DELAY, DEFAULT_REPLUG_AFTER, DEFAULT_TURNAROUND, VirtualLine
from .record import ReplayDevice
from .url import parse_seconds

_TCGETS2 = 0x802C542A  # _IOR('T', 0x2A, struct termios2) on x86/arm
_ABSENT_POLL = 0.02  # seconds between checks for a client while none has the pty open
_ABSENT_POLL_NO_INOTIFY = 0.002
_IN_OPEN = 0x20
_IDLE_SPEED = termios.B38400  # the speed a fresh pty has; never one of the ICS rates
_IDLE_BAUD = 38400


def _watch_opens(path: str) -> int | None:
    """An inotify fd that becomes readable when ``path`` is opened (None if unavailable).

    Without it a new client would wait for the next poll before its first bytes are read.
    """
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        fd = int(libc.inotify_init1(os.O_NONBLOCK | os.O_CLOEXEC))
    except (OSError, AttributeError):
        return None
    if fd < 0:
        return None
    if libc.inotify_add_watch(fd, path.encode(), _IN_OPEN) < 0:
        os.close(fd)
        return None
    return fd


def host_baudrate(fd: int) -> int | None:
    """The output speed set on the pty (through its master), in bit/s."""
    buf = array.array("I", [0] * 16)
    try:
        fcntl.ioctl(fd, _TCGETS2, buf)
    except OSError:
        return None
    return int(buf[10])  # c_ospeed: after 4 flags, c_line and 19 c_cc bytes


class PtyServer:
    """Serves ``device`` (a :class:`VirtualLine` or :class:`ReplayDevice`) on a pty."""

    def __init__(
        self,
        device: VirtualLine | ReplayDevice,
        *,
        link: str | Path | None = None,
        follow_host_baud: bool = True,
        spin_margin: float = SPIN_MARGIN,
    ) -> None:
        self.device = device
        self.follow_host_baud = follow_host_baud
        self.spin_margin = spin_margin
        if link is None:
            self._tmpdir: str | None = tempfile.mkdtemp(prefix="ics35-sim-")
            self.path = Path(self._tmpdir) / "ttyICS0"
        else:
            self._tmpdir = None
            self.path = Path(link)
        self.pts_name: str | None = None
        self._master: int | None = None
        self._opens: int | None = None
        self._client_present = False
        self._heap: list[tuple[float, int, bytes | None]] = []
        self._order = itertools.count()
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        os.set_blocking(self._wake_w, False)
        self._stopping = False
        self.dropped_bytes = 0
        device.add_listener(lambda plugged: self.wake())

    # -- pty lifetime

    def _open_pty(self) -> None:
        master, slave = os.openpty()
        name = os.ttyname(slave)
        os.close(slave)  # so the master sees a hang-up whenever no client has it open
        os.set_blocking(master, False)
        self._master = master
        self.pts_name = name
        self._opens = _watch_opens(name)
        self._client_present = False
        self._reset_settings()
        tmp_link = self.path.with_name(self.path.name + ".new")
        with contextlib.suppress(FileNotFoundError):
            tmp_link.unlink()
        os.symlink(name, tmp_link)
        os.replace(tmp_link, self.path)

    def _close_pty(self) -> None:
        with contextlib.suppress(FileNotFoundError):
            if self.path.is_symlink():
                self.path.unlink()
        if self._master is not None:
            os.close(self._master)
        if self._opens is not None:
            os.close(self._opens)
        self._master = None
        self._opens = None
        self.pts_name = None
        self._client_present = False
        self._heap.clear()

    def _reset_settings(self) -> None:
        """Raw mode (no echo by the pty itself) at the idle speed."""
        if self._master is None:
            return
        if self._client_opened(self._master):
            return  # a new client opened meanwhile: its settings are the ones to keep
        tty.setraw(self._master)
        self._park_speed()

    @staticmethod
    def _client_opened(master: int) -> bool:
        poller = select.poll()
        poller.register(master, select.POLLIN)
        return not any(ev & select.POLLHUP for _, ev in poller.poll(0))

    def _park_speed(self, only_if: int | None = None) -> None:
        """Set the pty's speed to 38400, leaving the client's other settings alone.

        A client's next open or re-configuration then changes the speed,
        which is what lets glibc accept it despite the dropped PARENB.
        With ``only_if``, park only while the speed is still that one, so a
        client that just re-opened at another rate is not overwritten.
        """
        if self._master is None:
            return
        attrs = termios.tcgetattr(self._master)
        if only_if is not None and host_baudrate(self._master) != only_if:
            return
        attrs[4] = attrs[5] = _IDLE_SPEED
        with contextlib.suppress(termios.error):
            termios.tcsetattr(self._master, termios.TCSANOW, attrs)

    def open(self) -> Path:
        """Create the pty and the link; returns the path clients should open."""
        if self._master is None and getattr(self.device, "plugged", True):
            self._open_pty()
        return self.path

    def wake(self) -> None:
        with contextlib.suppress(BlockingIOError, OSError):
            os.write(self._wake_w, b"x")

    def stop(self) -> None:
        """Make :meth:`serve` return (safe from a signal handler or another thread)."""
        self._stopping = True
        self.wake()

    def close(self) -> None:
        self._close_pty()
        for fd in (self._wake_r, self._wake_w):
            with contextlib.suppress(OSError):
                os.close(fd)
        if self._tmpdir is not None:
            shutil.rmtree(self._tmpdir, ignore_errors=True)

    # -- the loop

    def serve(self) -> None:
        """Answer the client until :meth:`stop`."""
        lower_timer_slack()
        self.open()
        realtime = self.device.realtime
        while not self._stopping:
            self._follow_plug_state()
            master = self._master
            timeout: float | None = None
            if self._heap:
                timeout = max(0.0, self._heap[0][0] - time.perf_counter() - self.spin_margin)
            watch = [self._wake_r]
            if master is not None:
                if self._client_present:
                    watch.append(master)
                else:
                    if self._opens is not None:
                        watch.append(self._opens)
                    absent_poll = _ABSENT_POLL if self._opens is not None else _ABSENT_POLL_NO_INOTIFY
                    timeout = absent_poll if timeout is None else min(timeout, absent_poll)
            readable, _, _ = select.select(watch, [], [], timeout)
            for fd in (self._wake_r, self._opens):
                if fd is not None and fd in readable:
                    with contextlib.suppress(BlockingIOError):
                        os.read(fd, 4096)
            if master is not None and (master in readable or (not self._client_present and self._check_client(master))):
                self._read(master, realtime)
            self._deliver_due()

    def _check_client(self, master: int) -> bool:
        """Whether a client has opened the pty since we last looked (no more hang-up)."""
        if not self._client_opened(master):
            return False
        self._client_present = True
        return True

    def _read(self, master: int, realtime: bool) -> None:
        try:
            data = os.read(master, 4096)
        except BlockingIOError:
            return
        except OSError as exc:
            if exc.errno != errno.EIO:
                raise
            data = b""
        if not data:
            # The last client closed the pty: forget its settings (see the module docstring).
            self._client_present = False
            self._heap.clear()
            self._reset_settings()
            return
        device = self.device
        baud = host_baudrate(master)
        if baud and baud != _IDLE_BAUD:
            # The client set its speed since we last looked: note it, then park
            # the pty at the idle speed again (see the module docstring).
            if self.follow_host_baud and isinstance(device, VirtualLine):
                device.baudrate = baud
            self._park_speed(only_if=baud)
        chunks = device.process(data)
        epoch = device.epoch
        for when, chunk in chunks:
            heapq.heappush(self._heap, (epoch + when if realtime else 0.0, next(self._order), chunk))
        if device.take_unplug_request() and isinstance(device, VirtualLine):
            line_free = epoch + device._line_free if realtime else 0.0
            heapq.heappush(self._heap, (line_free, next(self._order), None))

    def _deliver_due(self) -> None:
        heap = self._heap
        while heap and heap[0][0] - time.perf_counter() <= self.spin_margin:
            when, _, chunk = heapq.heappop(heap)
            wait_until(when, self.spin_margin)
            if chunk is None:
                device = self.device
                if isinstance(device, VirtualLine):
                    device.unplug(replug_after=device.replug_after)
                self._follow_plug_state()
                return
            self._write(chunk)

    def _write(self, chunk: bytes) -> None:
        master = self._master
        if master is None or not self._client_present:
            self.dropped_bytes += len(chunk)
            return
        try:
            written = os.write(master, chunk)
        except BlockingIOError:
            written = 0
        except OSError as exc:
            if exc.errno != errno.EIO:
                raise
            written = 0
        self.dropped_bytes += len(chunk) - written  # a client that does not read loses bytes

    def _follow_plug_state(self) -> None:
        plugged = getattr(self.device, "plugged", True)
        if plugged and self._master is None:
            self._open_pty()
        elif not plugged and self._master is not None:
            self._close_pty()


# ---------------------------------------------------------------------- command line


def build_parser(prog: str = "python -m ics35_async.sim") -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=prog,
        description="Serve a simulated ICS 3.5 servo line on a pseudo-terminal. "
        "Prints the device path on the first line, then serves until SIGINT/SIGTERM.",
    )
    parser.add_argument("--ids", default="0-31", help="servo IDs, e.g. 0-31 or 1,3,5-7 ('none': no servos)")
    parser.add_argument("--baud", type=int, default=115200, help="servos' baud rate (115200, 625000, 1250000)")
    parser.add_argument("--realtime", action="store_true", help="deliver at the modelled wire times")
    parser.add_argument("--faults", default=None, help="fault spec, e.g. drop:0.01,late@3:0.1 (see sim.faults)")
    parser.add_argument("--seed", type=int, default=0, help="fault random seed")
    parser.add_argument("--no-echo", action="store_true", help="do not echo the client's bytes")
    parser.add_argument("--turnaround", default=None, help=f"servo turnaround (default {DEFAULT_TURNAROUND * 1e6:g}us)")
    parser.add_argument(
        "--eeprom-delay",
        default=None,
        help=f"extra EEPROM-write delay (default {DEFAULT_EEPROM_WRITE_DELAY * 1e3:g}ms)",
    )
    parser.add_argument(
        "--late-delay", default=None, help="late replies arrive this long after (default: next command)"
    )
    parser.add_argument("--memory", default=None, help="IDs of generic 128-byte memory devices")
    parser.add_argument("--unplug-after", default=None, help="unplug the port this many seconds after start")
    parser.add_argument(
        "--replug-after", default=None, help=f"plug it back in this long after (default {DEFAULT_REPLUG_AFTER:g}s)"
    )
    parser.add_argument("--record", default=None, help="record the session to this file")
    parser.add_argument("--replay", default=None, help="serve this recording instead of a simulated line")
    parser.add_argument("--link", default=None, help="path of the symlink to create (default: in a temp dir)")
    parser.add_argument(
        "--fixed-baud", action="store_true", help="ignore the client's baud rate; the line runs at --baud"
    )
    return parser


def build_device(args: argparse.Namespace) -> VirtualLine | ReplayDevice:
    if args.replay:
        return ReplayDevice(args.replay)
    ids = [] if args.ids.strip().lower() == "none" else parse_ids(args.ids)
    replug_after = parse_seconds(args.replug_after, "--replug-after") if args.replug_after else DEFAULT_REPLUG_AFTER
    options: dict[str, Any] = {}
    if args.turnaround is not None:
        options["turnaround"] = parse_seconds(args.turnaround, "--turnaround")
    if args.eeprom_delay is not None:
        options["eeprom_write_delay"] = parse_seconds(args.eeprom_delay, "--eeprom-delay")
    if args.late_delay is not None:
        options["late_delay"] = parse_seconds(args.late_delay, "--late-delay")
    bus = VirtualLine(
        ids,
        baudrate=BaudRate.parse(args.baud),
        memory={i: b"" for i in parse_ids(args.memory)} if args.memory else None,
        realtime=args.realtime,
        echo=not args.no_echo,
        faults=FaultConfig.parse(args.faults),
        seed=args.seed,
        follow_host_baud=not args.fixed_baud,
        replug_after=replug_after,
        record=args.record,
        **options,
    )
    if args.unplug_after is not None:
        bus.schedule_unplug(parse_seconds(args.unplug_after, "--unplug-after"), replug_after)
    return bus


def main(argv: Sequence[str] | None = None, *, prog: str = "python -m ics35_async.sim") -> int:
    """Entry point of ``python -m ics35_async.sim`` (and ``ics35 sim``); returns the exit status."""
    parser = build_parser(prog)
    args = parser.parse_args(argv)
    try:
        device = build_device(args)
    except (InvalidArgument, OSError) as exc:
        parser.error(str(exc))
    server = PtyServer(device, link=args.link, follow_host_baud=not args.fixed_baud)

    def on_signal(signum: int, frame: FrameType | None) -> None:
        server.stop()

    previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        path = server.open()
        print(path, flush=True)
        what = (
            f"replaying {len(device.entries)} transactions"
            if isinstance(device, ReplayDevice)
            else f"{len(device.servos)} servos at {device.baudrate} bit/s, {'real-time' if device.realtime else 'fast'}"
        )
        print(f"ics35 sim: {what} on {server.pts_name} (link {path})", file=sys.stderr, flush=True)
        server.serve()
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        server.close()
        if isinstance(device, VirtualLine):
            device.close()
            print(f"ics35 sim: served {device.transactions} transactions", file=sys.stderr, flush=True)
    return 0


# ---------------------------------------------------------------------- for tests and scripts


def start_subprocess(
    args: Sequence[str] = (), *, timeout: float = 15.0, python: str | None = None, quiet: bool = False
) -> tuple[subprocess.Popen[str], str]:
    """Launch the server in a subprocess; return it and the device path it printed.

    ``quiet`` sends its notes (stderr) to /dev/null.  Stop it with
    :func:`stop_subprocess` (or use :func:`serving`).
    """
    proc = subprocess.Popen(
        [python or sys.executable, "-m", "ics35_async.sim", *args],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL if quiet else None,
        text=True,
    )
    assert proc.stdout is not None
    ready, _, _ = select.select([proc.stdout], [], [], timeout)
    line = proc.stdout.readline() if ready else ""
    if not line.strip():
        stop_subprocess(proc)
        raise RuntimeError(
            f"the simulator did not print its device path within {timeout} s (exit code {proc.returncode})"
        )
    return proc, line.strip()


def stop_subprocess(proc: subprocess.Popen[str], timeout: float = 5.0) -> int:
    """SIGTERM the server, wait for it (kill after ``timeout``), return its exit code."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    if proc.stdout is not None:
        proc.stdout.close()
    return proc.returncode


@contextlib.contextmanager
def serving(args: Sequence[str] = (), *, timeout: float = 15.0) -> Iterator[str]:
    """``with serving(["--ids", "1-3"]) as path:`` a server subprocess for the block."""
    proc, path = start_subprocess(args, timeout=timeout)
    try:
        yield path
    finally:
        stop_subprocess(proc)
