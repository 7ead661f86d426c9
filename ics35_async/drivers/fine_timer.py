"""A deadline timer finer than the event loop's: a Linux ``timerfd`` the loop watches like a port.

asyncio hands its next timer to ``epoll_wait`` in whole milliseconds, rounded up, and uvloop keeps its
timers in whole milliseconds: a deadline there fires up to a millisecond late.  For a line that is a
paced stream's cycle starting up to a millisecond after its slot (half of one at the median), and every
reply given up on a millisecond late, each costing the line that time.  A ``timerfd`` set to the
deadline itself (``CLOCK_MONOTONIC``, the clock the drivers give the engine: :mod:`.clock`) turns
readable when the kernel's timer fires, within tens of microseconds; the loop wakes for it as for input.
The thread driver's I/O thread, which ``poll``s a tty in whole milliseconds, watches one for a deadline's
last millisecond (see .thread_driver).

Linux only (the C library's ``timerfd_create`` through ``ctypes``, as ``os.timerfd_create`` comes only with
Python 3.13); elsewhere, or where it cannot be had, :func:`open_fine_timer` gives None and the driver keeps the
loop's timers (or ``poll``'s milliseconds, rounded up).
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import math
import os
import sys
from collections.abc import Callable

_CLOCK_MONOTONIC = 1
_TFD_NONBLOCK = os.O_NONBLOCK
_TFD_CLOEXEC = 0o2000000  # (O_CLOEXEC on every Linux architecture but a few the library does not run on)
_TFD_TIMER_ABSTIME = 1


class _Timespec(ctypes.Structure):
    _fields_ = [("tv_sec", ctypes.c_long), ("tv_nsec", ctypes.c_long)]


class _Itimerspec(ctypes.Structure):
    _fields_ = [("it_interval", _Timespec), ("it_value", _Timespec)]


def _libc_timerfd() -> tuple[Callable[[], int], Callable[[int, float], None]] | None:
    """(create, set_absolute) through the C library, or None where it has no timerfd."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or None, use_errno=True)
        create, settime = libc.timerfd_create, libc.timerfd_settime
    except (OSError, AttributeError):
        return None
    create.argtypes, create.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    settime.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.POINTER(_Itimerspec), ctypes.c_void_p]
    settime.restype = ctypes.c_int

    def make() -> int:
        fd: int = create(_CLOCK_MONOTONIC, _TFD_NONBLOCK | _TFD_CLOEXEC)
        if fd < 0:
            err = ctypes.get_errno()
            raise OSError(err, os.strerror(err))
        return fd

    def set_absolute(fd: int, when: float) -> None:
        spec = _Itimerspec()
        if when > 0:  # (0: disarmed)
            seconds = math.floor(when)
            spec.it_value.tv_sec = seconds
            spec.it_value.tv_nsec = min(999_999_999, max(1, int((when - seconds) * 1e9)))
        if settime(fd, _TFD_TIMER_ABSTIME, ctypes.byref(spec), None) != 0:
            err = ctypes.get_errno()
            raise OSError(err, os.strerror(err))

    return make, set_absolute


_BINDING = _libc_timerfd() if sys.platform.startswith("linux") else None


TIMER_NAME = "deadline timer"
"""What ``--version -v`` and doctor call how the line's deadlines are timed."""


def fine_deadlines() -> tuple[bool, str]:
    """Whether the drivers time the line's deadlines on a timerfd here, and what that means, in plain words
    (for ``--version -v`` and doctor, after :data:`TIMER_NAME`)."""
    if _BINDING is None:
        where = "not Linux" if not sys.platform.startswith("linux") else "no timerfd in the C library"
        return False, f"the event loop's own, in whole milliseconds ({where})"
    return True, (
        "a timerfd, to the microsecond (the asyncio driver's, and the thread driver's on a tty: a paced stream's "
        "slots and replies given up on; the anyio driver keeps its whole milliseconds)"
    )


class FineTimer:
    """One deadline at a time on a ``timerfd``: :meth:`arm` it, watch :attr:`fd` for reading, and call
    :meth:`fired` when it is readable (True: the armed deadline came; False: it was moved or cancelled
    since, and nothing is due)."""

    def __init__(self, fd: int, set_absolute: Callable[[int, float], None]) -> None:
        self.fd = fd
        self._set = set_absolute
        self.armed = False

    def arm(self, when: float) -> None:
        """Fire at ``when`` (seconds on :func:`time.monotonic`'s clock; in the past: at once).  Replaces the
        deadline armed before, and any expiry of it not yet read."""
        self._set(self.fd, max(when, 1e-9))
        self.armed = True

    def cancel(self) -> None:
        if self.armed:
            self.armed = False
            with contextlib.suppress(OSError):  # (closed under it: nothing to cancel)
                self._set(self.fd, 0.0)

    def fired(self) -> bool:
        try:
            os.read(self.fd, 8)
        except (BlockingIOError, InterruptedError):
            return False  # re-armed or cancelled after it expired: a setting clears what was not read
        except OSError:
            return False
        if not self.armed:
            return False
        self.armed = False
        return True

    def close(self) -> None:
        self.armed = False
        with contextlib.suppress(OSError):
            os.close(self.fd)


def open_fine_timer() -> FineTimer | None:
    """A :class:`FineTimer`, or None where the system has none (not Linux, no timerfd, no descriptor left)."""
    if _BINDING is None:
        return None
    make, set_absolute = _BINDING
    try:
        return FineTimer(make(), set_absolute)
    except OSError:
        return None
