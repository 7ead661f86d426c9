"""A pseudo-terminal behind a stable path, for the pty server: the POSIX plumbing.

The path is a symlink in a private temporary directory (or a given path) to
the current ``/dev/pts/N``; it stays the same when the simulated port is
unplugged (the link disappears and the pty closes, so an open client sees a
hang-up) and plugged back in (a new pty, the link points at it again).

Line speed: the client's baud rate is read from the pty settings (TCGETS2 on
the master), so the simulated line can run at whatever the client opened it
at.

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
"""

from __future__ import annotations

import array
import contextlib
import ctypes
import errno
import fcntl
import os
import select
import shutil
import tempfile
import termios
from pathlib import Path
from typing import Any

from ..errors import InvalidArgument
from ..transports.platforms import SIM_PTY_DIR_PREFIX, SIM_PTY_NAME
from ..transports.sim_link_lock import LinkInUse, LinkLock, NotALock, lock_path
from ..user_files import empty_path

_TCGETS2 = 0x802C542A  # _IOR('T', 0x2A, struct termios2) on x86/arm
_IN_OPEN = 0x20
_IDLE_SPEED = termios.B38400  # the speed a fresh pty has; never one of the ICS rates
IDLE_BAUD = 38400


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


def _raw_and_parked(attrs: list[Any]) -> list[Any]:
    """``attrs`` in raw mode (Python 3.11's ``tty.setraw``) at the idle speed.

    Left as the client left them: INPCK and PARMRK (a pty has no parity to
    check; the ICS drivers set both on every port they open) and, when the
    client was already non-canonical, VMIN and VTIME (they shape only the
    client's own reads; pyserial sets 0 and 0).
    """
    iflag, oflag, cflag, lflag, _, _, cc = attrs
    wanted = [
        iflag & ~(termios.BRKINT | termios.ICRNL | termios.ISTRIP | termios.IXON),
        oflag & ~termios.OPOST,
        (cflag & ~(termios.CSIZE | termios.PARENB)) | termios.CS8,
        lflag & ~(termios.ECHO | termios.ICANON | termios.IEXTEN | termios.ISIG),
        _IDLE_SPEED,
        _IDLE_SPEED,
        list(cc),
    ]
    if lflag & termios.ICANON:
        wanted[6][termios.VMIN] = 1
        wanted[6][termios.VTIME] = 0
    return wanted


def _client_opened(master: int) -> bool:
    """Whether a client has the pty open (the master sees no hang-up)."""
    poller = select.poll()
    poller.register(master, select.POLLIN)
    return not any(ev & select.POLLHUP for _, ev in poller.poll(0))


def claim_link_path(path: Path) -> LinkLock:
    """Take the lock of the simulator's link at ``path`` (see :mod:`~ics35_async.transports.sim_link_lock`), and
    refuse a path the link may not take: one in no directory, one a running simulator serves, one that is
    something else than a link a simulator made (a file, a directory, another link), or a link to a pty still
    there that no lock tells about (one made by hand, or by a simulator that kept no lock: it may be served).
    A link a killed simulator left (its lock unheld, or its pty gone) is taken over.

    The link is replaced while the simulator runs and removed when it stops, so a wrong path would
    destroy what was there.  (Its ``.new`` sibling, the link made before it takes the path, alike.)

    Raises:
        InvalidArgument: the path, and why.
    """
    if path.name in ("", ".."):  # ("", "." and "/" are all nameless to pathlib)
        raise InvalidArgument(f"{str(path)!r} has no file name for the link (e.g. /tmp/ttyICS0)")
    if not path.parent.is_dir():
        raise InvalidArgument(f"no such directory for the link: {path.parent} (in {path})")
    if not os.access(path.parent, os.W_OK):
        raise InvalidArgument(f"no right to make the link in {path.parent} (in {path})")
    try:
        lock = LinkLock.claim(path)
    except LinkInUse as exc:
        serving = f"a running simulator (process {exc.pid})" if exc.pid else "a running simulator"
        raise InvalidArgument(f"{path} is in use: {serving} serves it (choose another path, or stop it)") from None
    except NotALock as exc:
        raise InvalidArgument(
            f"{exc} exists and is not a simulator's lock: refusing to replace it (choose another path)"
        ) from None
    except OSError as exc:
        raise InvalidArgument(f"cannot make the link's lock {lock_path(path)}: {exc.strerror}") from None
    try:
        for taken in (path, path.with_name(path.name + ".new")):
            _check_link_taken(taken, lock.found)
    except BaseException:
        lock.release(remove=not lock.found)
        raise
    return lock


def _check_link_taken(taken: Path, killed: bool) -> None:
    """Refuse ``taken`` unless it is free or a link a simulator left (``killed``: its lock was there, unheld)."""
    if not (taken.exists() or taken.is_symlink()):
        return
    if not _pty_link(taken):
        raise InvalidArgument(
            f"{taken} exists and is not a simulator's link: refusing to replace it (choose another path)"
        )
    if taken.exists() and not killed:  # (its pty is there: a simulator, or whatever holds that pty now, serves it)
        pts = os.readlink(taken)
        holder = _pty_holder(pts)
        held = f", which {holder} holds" if holder else ""
        raise InvalidArgument(
            f"{taken} is in use: it leads to {pts}{held} (choose another path; if no simulator serves it, remove it)"
        )


def _pty_holder(pts: str, proc: Path = Path("/proc")) -> str | None:
    """``process PID (NAME)`` that holds the master side of the pty ``pts`` (``/dev/pts/N``), or None where the
    system does not say (not Linux, another user's process).  A terminal (a shell's, tmux's) that took a killed
    simulator's pty number tells itself apart from a simulator by its name."""
    index = pts.removeprefix("/dev/pts/")
    if not index.isdigit():
        return None
    for entry in proc.glob("[0-9]*"):
        with contextlib.suppress(OSError):
            for fd in (entry / "fd").iterdir():
                if os.readlink(fd) not in ("/dev/ptmx", "/dev/pts/ptmx"):
                    continue
                info = (entry / "fdinfo" / fd.name).read_text()  # (Linux 4.13 on: the pty's number)
                if f"tty-index:\t{index}\n" in info:
                    name = (entry / "comm").read_text().strip()
                    return f"process {entry.name} ({name})"
    return None


def _pty_link(path: Path) -> bool:
    """A symlink to a pseudo-terminal: a simulator's, or one a killed simulator left."""
    return path.is_symlink() and os.readlink(path).startswith(("/dev/pts/", "/dev/ttys"))  # Linux, macOS


class LinkFolderGone(OSError):
    """The folder of the link was removed while the simulator ran (a temporary folder cleaned away): the link
    cannot be made again at the next plug, and no client can find the port.  (An OSError: where a port opens, as
    at the simulator's start, it is one more reason the port cannot be made.)"""


class PtyPort:
    """The master side of a pty, reachable by clients at :attr:`path`.

    ``master`` is ``None`` while the port is closed (unplugged).
    ``client_present`` says whether a client had the pty open when last
    looked at; ``opens`` is an inotify fd that wakes a ``select`` when a
    client opens the pty (``None`` without inotify: poll instead).
    """

    def __init__(self, link: str | Path | None = None) -> None:
        if link is None:
            self._tmpdir: str | None = tempfile.mkdtemp(prefix=SIM_PTY_DIR_PREFIX)
            self.path = Path(self._tmpdir) / SIM_PTY_NAME
            self._lock: LinkLock | None = None  # (a directory of its own: no other simulator comes there)
        else:
            self._tmpdir = None
            if empty_path(str(link)):
                raise InvalidArgument("the path is empty: give the link's path (e.g. /tmp/ttyICS0)")
            self._lock = claim_link_path(Path(link))
            # Absolute: the path printed is what another terminal, in another directory, opens as --port.
            self.path = Path(link).absolute()
        self.pts_name: str | None = None
        self.master: int | None = None
        self.opens: int | None = None
        self.client_present = False

    def open(self) -> None:
        """Create a new pty and point the link at it."""
        master, slave = os.openpty()
        name = os.ttyname(slave)
        os.close(slave)  # so the master sees a hang-up whenever no client has it open
        os.set_blocking(master, False)
        self.master = master
        self.pts_name = name
        self.opens = _watch_opens(name)
        self.client_present = False
        self.reset_settings()
        tmp_link = self.path.with_name(self.path.name + ".new")
        try:
            if tmp_link.is_symlink():  # (one an earlier simulator left: check_link_path refused anything else)
                tmp_link.unlink()
            os.symlink(name, tmp_link)
            os.replace(tmp_link, self.path)
        except FileNotFoundError:
            if self.path.parent.is_dir():
                raise
            self.close()  # (the pty just made: without its link no client reaches it)
            # Not made again: a folder of the user's is theirs to make, and the private one is gone with whatever
            # cleaned it.
            raise LinkFolderGone(
                f"the link's folder {self.path.parent} is gone (removed while the simulator ran): "
                f"{self.path} cannot be made again"
            ) from None

    def close(self) -> None:
        """Remove the link and close the pty (an open client sees a hang-up)."""
        with contextlib.suppress(FileNotFoundError):
            if self.path.is_symlink():
                self.path.unlink()
        if self.master is not None:
            os.close(self.master)
        if self.opens is not None:
            os.close(self.opens)
        self.master = None
        self.opens = None
        self.pts_name = None
        self.client_present = False

    def dispose(self) -> None:
        """Close, let the link's lock go, and remove the private directory of the link, if any."""
        self.close()
        if self._lock is not None:
            self._lock.release()
        if self._tmpdir is not None:
            shutil.rmtree(self._tmpdir, ignore_errors=True)

    def reset_settings(self) -> None:
        """Raw mode (no echo by the pty itself) at the idle speed.

        Written only when something differs: the usual client (pyserial) left the pty raw, and
        the server parked its speed at its first bytes, so nothing is written.  A write races a
        client that opens right after the last one closed: setting its speed between our read
        of the settings and our write, it would have it overwritten with the idle speed and be
        taken to run at the last client's.  (Nothing flushes here what the last client left
        unread: pyserial discards it as it opens a port, as the library's ports do.)
        """
        if self.master is None:
            return
        attrs = termios.tcgetattr(self.master)
        wanted = _raw_and_parked(attrs)
        if wanted == attrs or _client_opened(self.master):
            return  # nothing to change, or a new client opened: its settings are the ones to keep
        termios.tcsetattr(self.master, termios.TCSANOW, wanted)

    def park_speed(self, only_if: int | None = None) -> None:
        """Set the pty's speed to 38400, leaving the client's other settings alone.

        A client's next open or re-configuration then changes the speed,
        which is what lets glibc accept it despite the dropped PARENB.
        With ``only_if``, park only while the speed is still that one, so a
        client that just re-opened at another rate is not overwritten.
        """
        if self.master is None:
            return
        attrs = termios.tcgetattr(self.master)
        if only_if is not None and host_baudrate(self.master) != only_if:
            return
        attrs[4] = attrs[5] = _IDLE_SPEED
        with contextlib.suppress(termios.error):
            termios.tcsetattr(self.master, termios.TCSANOW, attrs)

    def check_client(self) -> bool:
        """Whether a client has opened the pty since we last looked (no more hang-up)."""
        if self.master is None or not _client_opened(self.master):
            return False
        self.client_present = True
        return True

    def client_baudrate(self) -> int | None:
        """The speed the client set, if it set one since the pty was last parked."""
        if self.master is None:
            return None
        baud = host_baudrate(self.master)
        return baud if baud and baud != IDLE_BAUD else None

    def drain_opens(self) -> None:
        if self.opens is not None:
            with contextlib.suppress(BlockingIOError):
                os.read(self.opens, 4096)

    def read(self) -> bytes | None:
        """The client's bytes; ``None`` if there are none yet, ``b""`` when the last client closed."""
        assert self.master is not None
        try:
            data = os.read(self.master, 4096)
        except BlockingIOError:
            return None
        except OSError as exc:
            if exc.errno != errno.EIO:
                raise
            data = b""
        if not data:
            # Forget the client's settings (see the module docstring).
            self.client_present = False
            self.reset_settings()
        return data

    def write(self, chunk: bytes) -> int:
        """Write to the client; returns how many bytes the pty took (none without a client)."""
        if self.master is None or not self.client_present:
            return 0
        try:
            return os.write(self.master, chunk)
        except BlockingIOError:
            return 0
        except OSError as exc:
            if exc.errno != errno.EIO:
                raise
            return 0
