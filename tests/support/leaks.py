"""Counting what a test or soak may leak: tasks, file descriptors, threads."""

from __future__ import annotations

import asyncio
import os
import threading


def open_fds() -> int:
    return len(os.listdir("/proc/self/fd"))


def other_tasks() -> int:
    current = asyncio.current_task()
    return sum(1 for t in asyncio.all_tasks() if t is not current and not t.done())


def non_executor_threads() -> int:
    """Threads, not counting the event loop's default executor (a pool kept for the loop's lifetime)."""
    return sum(1 for t in threading.enumerate() if not t.name.startswith("asyncio_"))
