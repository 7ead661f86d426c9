"""The lock a pty simulator (``ics35 sim --link PATH``) holds beside its link while it serves it: ``PATH.lock``.

A simulator killed with SIGKILL cannot remove its link, and the ``/dev/pts`` number the link names goes to
the next program that opens a pty (a terminal).  The pty number says nothing about who made the link; the
lock does: the system releases it whatever way its holder ends, so an unheld lock beside a link means the
simulator that made the link is gone, and a held one names the running simulator (its process ID is the
file's text).  A simulator that stops removes its link and then the lock file; a killed one leaves both.
"""

from __future__ import annotations

import contextlib
import os
import time
from pathlib import Path

PTY_DIRS = ("/dev/pts/", "/dev/ttys")  # where a pty's node is: Linux, macOS

# How long a starting simulator tries for a lock a client holds for an instant, to look (see
# :func:`left_by_a_stopped_simulator`), before taking it to be a running simulator's.
_CLAIM_PATIENCE = 0.3


def lock_path(link: Path) -> Path:
    """Where the simulator serving ``link`` keeps its lock."""
    return link.with_name(link.name + ".lock")


def _holder_pid(text: str) -> int | None:
    """The process ID a lock file names; None for an empty one (its maker had not written it yet)."""
    return int(text) if text.strip().isdigit() else None


def _is_a_simulators_lock(text: str) -> bool:
    return not text.strip() or text.strip().isdigit()


class LinkInUse(Exception):
    """A running simulator serves the link (``pid`` is its process ID, None if its lock did not say)."""

    def __init__(self, pid: int | None) -> None:
        super().__init__(pid)
        self.pid = pid


class NotALock(Exception):
    """Something else than a simulator's lock has the lock's path: not to be overwritten."""


class LinkLock:
    """The lock of one link, held from :meth:`claim` until :meth:`release`.

    ``found`` says a lock file was there already: the link beside it is a simulator's that was killed.
    """

    def __init__(self, fd: int, path: Path, found: bool) -> None:
        self._fd: int | None = fd
        self.path = path
        self.found = found

    @classmethod
    def claim(cls, link: Path) -> LinkLock:
        """Take the lock of ``link`` (non-blocking: refused at once if a running simulator holds it).

        Raises:
            LinkInUse: a running simulator holds it.
            NotALock: the lock's path has something else than a simulator's lock (a file of the user's).
            OSError: the lock file cannot be made.
        """
        import fcntl  # (POSIX only, as the pty simulator is)

        path = lock_path(link)
        deadline = time.monotonic() + _CLAIM_PATIENCE
        while True:
            found = os.path.lexists(path)
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC, 0o644)
            held = False
            try:
                text = os.read(fd, 64).decode("ascii", "replace")
                if not _is_a_simulators_lock(text):
                    raise NotALock(path)
                try:
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                except BlockingIOError:
                    if time.monotonic() < deadline:
                        os.close(fd)
                        time.sleep(0.02)
                        continue
                    raise LinkInUse(_holder_pid(text)) from None
                held = True
                # A simulator that stopped removes the file after we opened it: its inode is no lock anyone sees.
                with contextlib.suppress(FileNotFoundError):
                    if os.stat(path, follow_symlinks=False).st_ino == os.fstat(fd).st_ino:
                        os.ftruncate(fd, 0)
                        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
                        return cls(fd, path, found)
                os.close(fd)
            except BaseException:
                # A file made here goes again, but only while held: unheld, another simulator may have it open
                # already, and would hold a lock no one else sees.
                if held and not found:
                    with contextlib.suppress(OSError):
                        os.unlink(path)
                with contextlib.suppress(OSError):
                    os.close(fd)
                raise

    def release(self, remove: bool = True) -> None:
        """Let the lock go, removing its file first unless ``remove`` is False (one that was there before a
        refusal stays with the link it tells about)."""
        if self._fd is None:
            return
        if remove:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(self.path)
        os.close(self._fd)
        self._fd = None


def left_by_a_stopped_simulator(link: str) -> bool:
    """Whether ``link`` is a link to a pty that a simulator made and no simulator serves any more (it was killed:
    its lock is there, unheld).  False where that cannot be told (no lock beside it, not POSIX)."""
    try:
        import fcntl
    except ImportError:  # (Windows: no pty simulator)
        return False
    path = lock_path(Path(link))
    try:
        if not os.readlink(link).startswith(PTY_DIRS):
            return False
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
    except OSError:
        return False
    try:
        if not _is_a_simulators_lock(os.read(fd, 64).decode("ascii", "replace")):
            return False
        # A shared lock, let go at once: a simulator starting meanwhile waits for it (see LinkLock.claim).
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        return True
    except OSError:  # (held: a running simulator's)
        return False
    finally:
        os.close(fd)
