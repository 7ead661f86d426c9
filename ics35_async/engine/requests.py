"""What the engine queues: requests, their priority, and the queue's fairness rule; what a caller holds of one."""

from __future__ import annotations

import enum
from collections import deque
from collections.abc import Generator
from typing import Any, Protocol, TypeVar

from ..errors import IcsError
from ..protocol import Command


class Priority(enum.IntEnum):
    """Request priority: lower runs first; FIFO within a level."""

    URGENT = 0  # e.g. free-all / emergency stop: before everything queued
    HIGH = 1
    NORMAL = 2
    LOW = 3


T_co = TypeVar("T_co", covariant=True)


class RequestHandle(Protocol[T_co]):
    """A queued request (:meth:`Bus.submit <ics35_async.bus.Bus.submit>`): awaited, its result; and, on every
    driver, what an asyncio future answers (the asyncio and thread drivers give one; under the anyio driver,
    trio included, these raise asyncio's ``CancelledError`` and ``InvalidStateError`` as a future does)."""

    def __await__(self) -> Generator[Any, None, T_co]: ...

    def done(self) -> bool:
        """Finished: a result, an error, or cancelled."""

    def cancelled(self) -> bool:
        """Cancelled (while queued it is never sent; on the wire it finishes there, its reply dropped)."""

    def cancel(self) -> bool:
        """Cancel it; False if it had finished."""

    def result(self) -> T_co:
        """Its result, once done (else ``InvalidStateError``); raises its error, or ``CancelledError``."""

    def exception(self) -> BaseException | None:
        """Its error, once done (None if it has a result); ``CancelledError`` if cancelled."""


class Request:
    """One command waiting for, or on, the line.

    The engine never blocks and never calls out except through :meth:`resolve`
    and :meth:`reject`, which a driver overrides to hand the outcome to its
    caller (a future, a trio event...).  They must not call back into the
    engine.  The base class keeps the outcome, which is what the engine's own
    tests read.
    """

    __slots__ = ("command", "error", "priority", "retries_left", "sent", "state", "value")

    is_guard = False

    def __init__(self, command: Command[Any], priority: int = Priority.NORMAL, retries: int = 0) -> None:
        self.command = command
        self.priority = priority
        # Retrying a command that moves or writes could act twice: only idempotent ones retry.
        self.retries_left = retries if command.idempotent else 0
        self.sent = False  # its command has gone on the wire (each time after the first is a retry: counted)
        self.state = "queued"  # queued -> done | failed | cancelled
        self.value: Any = None
        self.error: IcsError | None = None

    def abandoned(self) -> bool:
        """True once nobody waits for the outcome (the caller was cancelled)."""
        return self.state != "queued"

    def cancel(self) -> None:
        """The caller gave up.  A queued request is skipped; one on the wire still has its reply consumed."""
        if self.state == "queued":
            self.state = "cancelled"

    def resolve(self, value: Any) -> None:
        if self.state == "queued":
            self.state, self.value = "done", value

    def reject(self, error: IcsError) -> None:
        if self.state == "queued":
            self.state, self.error = "failed", error

    def result(self) -> Any:
        """The value, or raise the error (for plain-call tests and simple drivers)."""
        if self.error is not None:
            raise self.error
        if self.state != "done":
            raise RuntimeError(f"request is {self.state}")
        return self.value

    def __repr__(self) -> str:
        return f"<Request {self.command!r} {Priority(self.priority).name} {self.state}>"


class GuardRequest(Request):
    """The harmless read the engine slips in after a timeout; nobody waits for it.  ``protects``: the
    request it goes before (None: the source's transaction), whose tries it may cost (see .guard);
    ``protected_tx``: the bytes that one sends (kept here: a source's transaction has no request to hold them)."""

    __slots__ = ("protected_tx", "protects")

    is_guard = True

    def __init__(self, command: Command[Any], protects: Request | None, protected_tx: bytes) -> None:
        super().__init__(command)
        self.protects = protects
        self.protected_tx = protected_tx


class RequestQueue:
    """Priority levels, FIFO within each; skips requests whose caller gave up."""

    __slots__ = ("_levels", "count")

    def __init__(self) -> None:
        self._levels: list[deque[Request]] = [deque() for _ in Priority]
        self.count = 0

    def __bool__(self) -> bool:
        return self.count > 0

    def push(self, request: Request) -> None:
        self._levels[request.priority].append(request)
        self.count += 1

    def push_front(self, request: Request) -> None:
        """Put a request back at the head of its level (a retry, or a request a guard read goes before)."""
        self._levels[request.priority].appendleft(request)
        self.count += 1

    def peek(self) -> Request | None:
        """The request :meth:`pop` would return, left in place (abandoned ones ahead of it are dropped)."""
        for level in self._levels:
            while level:
                if not level[0].abandoned():
                    return level[0]
                level.popleft()
                self.count -= 1
        return None

    def pop(self) -> Request | None:
        if not self.count:
            return None
        for level in self._levels:
            while level:
                request = level.popleft()
                self.count -= 1
                if not request.abandoned():
                    return request
        return None

    def remove(self, request: Request) -> bool:
        """Take ``request`` off the queue (False: it was not on it)."""
        try:
            self._levels[request.priority].remove(request)
        except ValueError:
            return False
        self.count -= 1
        return True

    def waiting(self) -> list[Request]:
        """The requests queued, in the order they would go on the line (a copy, for diagnostics)."""
        # list() copies each deque at once (the I/O thread may pop from it meanwhile)
        return [request for level in self._levels for request in list(level) if not request.abandoned()]

    def fail_all(self, error: IcsError) -> None:
        for level in self._levels:
            while level:
                level.popleft().reject(error)
        self.count = 0
