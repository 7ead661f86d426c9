"""Running a controller program until it ends or is told to stop (Ctrl-C, SIGTERM), servos at rest.

A robot program is stopped by Ctrl-C at a terminal and by SIGTERM from a
service manager (systemd, Docker, a supervisor).  Without help, SIGTERM ends
the process on the spot (no ``finally``, no ``async with`` exit: the servos
keep whatever they were last told), and Ctrl-C prints asyncio's
``KeyboardInterrupt`` traceback.  :func:`run` turns both signals into a
cancellation of ``main``: its ``async with`` blocks unwind in order (a stream
closes as its ``on_close`` says, a robot stops smoothly, a bus drains and
releases its port), then it returns an exit code for ``sys.exit``.  A second
signal while that unwinding runs is ignored: the servos are being put to rest.
"""

from __future__ import annotations

import contextlib
import signal
import sys
from collections.abc import Awaitable, Callable, Iterator
from types import FrameType
from typing import Literal

from .errors import IcsError
from .tasks import only_error

EXIT_OK = 0
EXIT_ERROR = 1  # main raised an IcsError (printed as one line)
EXIT_SIGINT = 128 + signal.SIGINT  # 130, as a shell reports a Ctrl-C'd program
EXIT_SIGTERM = 128 + signal.SIGTERM  # 143

Backend = Literal["asyncio", "uvloop", "trio"]


def run(main: Callable[[], Awaitable[object]], *, backend: Backend = "asyncio") -> int:
    """Run ``main()`` until it returns, or until SIGINT (Ctrl-C) or SIGTERM cancels it; return an exit code.

    0 when ``main`` returned; 130 after SIGINT and 143 after SIGTERM, once ``main``'s
    ``async with`` blocks have closed (streams, robots, buses, in that order); 1 when
    ``main`` raised an :class:`~ics35_async.IcsError`, printed to stderr as one line
    without a traceback.  Other exceptions propagate.  ``backend``: ``"asyncio"``,
    ``"uvloop"`` (needs the uvloop package) or ``"trio"``.  Call it from the main thread::

        async def main() -> None:
            async with open_bus("/dev/ttyUSB0") as bus, bus.stream(ids, rate_hz=100, on_close="free") as s:
                async for frame in s:
                    ...


        sys.exit(ics35_async.run(main))
    """
    import anyio

    received: list[int] = []

    async def until_signal() -> None:
        with anyio.open_signal_receiver(signal.SIGINT, signal.SIGTERM) as signals:
            async with anyio.create_task_group() as tasks:
                main_scope = anyio.CancelScope()

                async def main_then_stop() -> None:
                    with main_scope:
                        await main()
                    tasks.cancel_scope.cancel()  # main is done (or cancelled): stop listening

                async def listen() -> None:
                    async for signum in signals:
                        if not received:
                            received.append(int(signum))
                            main_scope.cancel()

                tasks.start_soon(main_then_stop)
                tasks.start_soon(listen)

    options: dict[str, object] = {}
    name = backend
    if backend == "uvloop":
        import uvloop

        name, options = "asyncio", {"loop_factory": uvloop.new_event_loop}
    try:
        anyio.run(until_signal, backend=name, backend_options=options)
    except BaseException as exc:
        error = only_error(exc)
        if isinstance(error, IcsError):
            print(f"error: {error}", file=sys.stderr)
            return EXIT_ERROR
        raise
    if not received:
        return EXIT_OK
    return EXIT_SIGINT if received[0] == signal.SIGINT else EXIT_SIGTERM


class _Stopped(BaseException):
    """Raised in the main thread by a signal inside :func:`stop_on_signals` (not an error: a stop)."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum


@contextlib.contextmanager
def stop_on_signals() -> Iterator[None]:
    """For programs without an event loop: SIGINT (Ctrl-C) and SIGTERM end the ``with`` block like an
    exception, so the ``with`` blocks inside it close in order (a blocking stream frees or holds as its
    ``on_close`` says, a bus releases its port), then the program exits with 130 or 143 and no
    traceback (``SystemExit``).  Use it around everything, in the main thread::

        with stop_on_signals(), blocking.open_bus(port) as bus, bus.stream(ids, on_close="free") as s:
            ...
    """

    def stop(signum: int, frame: FrameType | None) -> None:
        raise _Stopped(signum)

    previous = {signum: signal.signal(signum, stop) for signum in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    except _Stopped as stopped:
        raise SystemExit(EXIT_SIGINT if stopped.signum == signal.SIGINT else EXIT_SIGTERM) from None
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


__all__ = ["EXIT_ERROR", "EXIT_OK", "EXIT_SIGINT", "EXIT_SIGTERM", "run", "stop_on_signals"]
