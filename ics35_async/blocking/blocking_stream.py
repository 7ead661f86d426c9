"""The blocking position stream: the async :class:`~ics35_async.Stream` runs on the loop thread.

The stream's cycles run entirely on the loop (the I/O callback that
completes one servo's reply writes the next servo's command), so a blocking
consumer costs one thread hop per *frame* it takes, never per transaction:
the wire runs at the same pace as under asyncio.  A slow consumer gets the
newest frame, with ``frame.skipped`` counting the ones it missed.
"""

from __future__ import annotations

from types import TracebackType
from typing import TYPE_CHECKING, NoReturn

from .. import units
from ..errors import BusClosed
from ..frames import Frame, StreamStats
from ..running import close_step
from ..stream import Stream
from .forward import ReadThrough, Wrapper, on_loop, read_on_loop
from .loop_thread import within


class BlockingStream(Wrapper[Stream]):
    """Position streaming for code without an event loop.  Create with :meth:`BlockingBus.stream`.

    ``with bus.stream(ids) as stream:`` starts it and stops it on leaving;
    ``for frame in stream:`` takes frames until the stream or bus closes.
    Target setters take effect before they return and raise typed errors
    (nothing is applied when one target is bad).
    """

    __slots__ = ()

    set_target = on_loop(Stream.set_target)
    set_targets = on_loop(Stream.set_targets)
    set_target_degrees = on_loop(Stream.set_target_degrees)
    set_targets_degrees = on_loop(Stream.set_targets_degrees)
    free = on_loop(Stream.free)
    watch = on_loop(Stream.watch)
    target = read_on_loop(Stream.target)
    longest_cycle = read_on_loop(Stream.longest_cycle)

    ids = ReadThrough[tuple[int, ...]]("The servo IDs this stream cycles over, in order.")
    rate_hz = ReadThrough[float | None]("Cycles per second asked for (``None``: as fast as the line allows).")
    latest = ReadThrough[Frame | None]("The newest frame (does not mark it taken; a frame is immutable).")

    @property
    def stats(self) -> StreamStats:
        """Achieved rate, cycle-time percentiles, jitter, overruns and per-ID failures so far."""
        return self._loop.read(_stats_of, self._async)

    @property
    def offline(self) -> frozenset[int]:
        """IDs currently out of the cycle after failing ``offline_after`` cycles in a row."""
        return self._loop.read(_offline_of, self._async)

    @property
    def held(self) -> dict[int, str]:
        """IDs held now, sent no command until their target is set (or they are freed or watched), and why
        (see ``Stream.held``): a loop setting every target each pass filters by this, not by a frame's."""
        return self._loop.read(_held_of, self._async)

    @property
    def targets_sent_on_close(self) -> dict[int, int]:
        """What the stream's close sent, ``{id: position}`` (0: free), for a summary after the ``with`` block
        (see ``Stream.targets_sent_on_close``)."""
        return self._loop.read(_sent_on_close_of, self._async)

    def next_frame(self, timeout: float | None = None) -> Frame:
        """The newest frame not yet taken; waits for one (at most ``timeout`` seconds: then ``TimeoutError``).

        Raises :class:`~ics35_async.BusClosed` once the stream or bus is
        closed, :class:`~ics35_async.PortLost` if the port is lost, and
        :class:`~ics35_async.InvalidArgument` if the stream was never started.
        """
        if timeout is not None:
            units.check_seconds("timeout", timeout, 0.0, 1e9)
        return self._loop.call(within, timeout, "frame", self._async.next_frame)

    def __iter__(self) -> BlockingStream:
        return self

    def __next__(self) -> Frame:
        try:
            return self.next_frame()
        except BusClosed:
            # Closing ends the iteration; losing the port (PortLost) is raised.
            raise StopIteration from None

    # ------------------------------------------------------------------ lifetime

    def start(self) -> BlockingStream:
        """Start streaming (``with`` does this)."""
        self._loop.call(self._async.start)
        return self

    @close_step
    def close(self) -> None:
        """Stop streaming; the bus stays usable.  With ``free_on_close`` every ID goes free first."""
        # (A close_step: a stop signal meanwhile is raised once the stream is closed, servos as asked.)
        if self._loop.is_running:
            self._loop.call_to_end(self._async.aclose)

    def __enter__(self) -> BlockingStream:
        return self.start()

    if not TYPE_CHECKING:  # (at run time only: a type checker says `async with` is wrong itself)

        async def __aenter__(self) -> NoReturn:
            raise TypeError(
                "a blocking stream is used with `with bus.stream(...) as stream:`; in async code, the streams of"
                " `async with ics35_async.open_bus(...) as bus:` are used with `async with`"
            )

        async def __aexit__(self, *exc: object) -> None:
            return None

    @close_step
    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<BlockingStream {list(self.ids)} on {self._async.bus!r}>"


def _stats_of(stream: Stream) -> StreamStats:
    return stream.stats


def _offline_of(stream: Stream) -> frozenset[int]:
    return stream.offline


def _held_of(stream: Stream) -> dict[int, str]:
    return stream.held


def _sent_on_close_of(stream: Stream) -> dict[int, int]:
    return stream.targets_sent_on_close
