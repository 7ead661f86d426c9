"""Several lines used together: :class:`BusGroup` opens them, :class:`GroupStream` streams on all at once.

A humanoid's two ICS lines cycle side by side, each at its own pace; a
merged frame holds every line's newest cycle.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterable, Mapping, Sequence
from typing import TYPE_CHECKING, NoReturn, Unpack

import anyio

from . import units
from .bus import Bus, BusOptions, open_bus
from .errors import BusClosed, IcsError, InvalidArgument
from .frames import Frame, FrameIterator, GroupFrame, StreamStats
from .stream import LineStreamOptions, Stream
from .tasks import again, first_library_error
from .transports.wire_device import WireDevice

GROUP_NOT_STARTED = "the group stream is not started: use it as `async with group.stream(...) as stream:`"


class GroupStream(FrameIterator[GroupFrame]):
    """Streams on several lines at once, each at its own pace, giving merged frames.

    :meth:`next_frame` waits until every line has completed a cycle newer
    than the one in the previous merged frame, then merges the newest of
    each; ``skipped`` is the most cycles any one line ran meanwhile unseen.

    Args:
        streams: ``{line name: stream}``; [`BusGroup.stream`][ics35_async.group.BusGroup.stream] makes them.

    Raises:
        InvalidArgument: no stream (``group.stream({})``): its frames would merge nothing.
    """

    _used_with = "a group stream runs in `async with group.stream(...) as stream:`"

    def __init__(self, streams: Mapping[str, Stream]) -> None:
        self.streams = dict(streams)
        if not self.streams:
            raise InvalidArgument("a group stream needs at least one line's IDs: {line: ids}")
        self._cycle = 0
        self._last: dict[str, Frame] = {}  # each line's frame in the last merged one
        self._closed = False
        self._end_error: IcsError = BusClosed("group stream closed")

    def set_target(self, line: str, servo_id: int, position: int) -> None:
        """Latest-value target ``position`` for servo ``servo_id`` on ``line`` (0 frees it).

        Raises:
            InvalidArgument: an unknown line, an ID not in that line's stream, a position out of range.
            BusClosed: that line's stream (or bus) was closed.
        """
        self._stream(line).set_target(servo_id, position)

    def set_targets(self, targets: Mapping[tuple[str, int], int], *, lift_holds: bool = True) -> None:
        """``targets`` keyed by ``(line, id)``; all are checked, on every line, before any is applied.
        ``lift_holds``: as for :meth:`Stream.apply_targets <ics35_async.Stream.apply_targets>`.

        Raises:
            InvalidArgument: not a mapping, a key that is not ``(line, id)``, an unknown line, an ID not
                in that line's stream or a position out of range (nothing applied).
            BusClosed: a line's stream (or bus) was closed (nothing applied).
        """
        if not isinstance(targets, Mapping):
            raise InvalidArgument(f"targets must be a mapping {{(line, id): position}}, not {type(targets).__name__}")
        by_line: dict[str, dict[int, int]] = {}
        for key, pos in targets.items():
            if not isinstance(key, tuple) or len(key) != 2:
                raise InvalidArgument(f"group targets are keyed by (line, id), not {key!r}")
            line, sid = key
            self._stream(line)
            by_line.setdefault(line, {})[sid] = pos
        checked = {}
        for line, line_targets in by_line.items():
            try:
                checked[line] = self.streams[line].check_targets(line_targets)
            except InvalidArgument as exc:  # which line: the same ID may be on several
                raise InvalidArgument(f"line {line}: {exc}") from None
        for line, c in checked.items():
            self.streams[line].apply_targets(c, lift_holds=lift_holds)

    def set_targets_degrees(self, targets: Mapping[tuple[str, int], float], *, lift_holds: bool = True) -> None:
        """Like :meth:`set_targets`, in degrees (-135..+135, 0 neutral); ``lift_holds`` as there.

        Raises:
            InvalidArgument: as :meth:`set_targets`, or an angle out of range (nothing applied).
            BusClosed: a line's stream (or bus) was closed (nothing applied).
        """
        if not isinstance(targets, Mapping):
            raise InvalidArgument(f"targets must be a mapping {{(line, id): degrees}}, not {type(targets).__name__}")
        positions = {}
        for key, degrees in targets.items():
            try:
                positions[key] = units.degrees_to_position(degrees)
            except InvalidArgument as exc:  # which line, as set_targets says it
                line = key[0] if isinstance(key, tuple) and key else key
                raise InvalidArgument(f"line {line}: {exc}") from None
        self.set_targets(positions, lift_holds=lift_holds)

    def free(self) -> None:
        """Put every servo on every line in free mode (torque off, still read back).

        Raises:
            BusClosed: a line's stream (or bus) was closed: every other line is freed all the same.
        """
        refused: BusClosed | None = None
        for s in self.streams.values():
            try:
                s.free()
            except BusClosed as exc:  # one closed line must not keep the others holding
                refused = refused or exc
        if refused is not None:
            raise refused

    def _stream(self, line: str) -> Stream:
        try:
            return self.streams[line]
        except KeyError:
            raise InvalidArgument(f"no line named {line!r} (lines: {', '.join(self.streams)})") from None

    async def next_frame(self) -> GroupFrame:
        """Wait until every line has completed a newer cycle and return them merged.

        Raises:
            InvalidArgument: the group stream was never started (``async with group.stream(...)`` starts it).
            BusClosed: the stream or a bus was closed.
            PortLost: a line lost its port (without ``reconnect``).
        """
        return self._merged(await self._take(every_line=True))

    async def next_update(self) -> GroupFrame:
        """Wait until any line has completed a newer cycle; return every line's newest frame merged.

        Each line's new cycle comes out as soon as it ends, whatever the other lines' pace (a slower
        line, or one slowed by a silent servo, does not hold up a faster one); a line with no newer
        cycle contributes the frame it gave last.  The first call waits for every line, as
        :meth:`next_frame` does, so the first merged frame knows every servo.

        Raises:
            InvalidArgument: the group stream was never started (``async with group.stream(...)`` starts it).
            BusClosed: the stream or a bus was closed.
            PortLost: a line lost its port (without ``reconnect``).
        """
        return self._merged(await self._take(every_line=len(self._last) < len(self.streams)))

    async def _take(self, every_line: bool) -> dict[str, Frame]:
        """Each line's next frame: from every line, or from those that have one first (the others' waits,
        cancelled, take nothing: a stream's frame is only taken when it is returned)."""
        if self._closed:
            raise again(self._end_error)
        frames: dict[str, Frame] = {}

        async def take(line: str, stream: Stream, scope: anyio.CancelScope) -> None:
            frames[line] = await stream.next_frame()
            if not every_line:
                scope.cancel()

        try:
            async with anyio.create_task_group() as group:
                for line, stream in self.streams.items():
                    group.start_soon(take, line, stream, group.cancel_scope)
        except BaseExceptionGroup as group_error:
            # A line closed or lost its port: the group ends, with that line's reason.
            reason = first_library_error(group_error)
            if not isinstance(reason, IcsError):
                raise
            if isinstance(reason, InvalidArgument):  # not started: a mistake to mend, not the group's end
                raise InvalidArgument(GROUP_NOT_STARTED) from None
            self._closed, self._end_error = True, reason
            raise reason from None
        return frames

    def _merged(self, new: dict[str, Frame]) -> GroupFrame:
        self._last.update(new)
        self._cycle += 1
        return self._merge(self._last, new, self._cycle)

    def _merge(self, frames: Mapping[str, Frame], new: Mapping[str, Frame], cycle: int) -> GroupFrame:
        """``frames`` (one per line) as one group frame; ``new``: those taken since the previous one."""
        positions: dict[tuple[str, int], int] = {}
        stamps: dict[tuple[str, int], float] = {}
        failed: set[tuple[str, int]] = set()
        offline: set[tuple[str, int]] = set()
        held: set[tuple[str, int]] = set()
        not_sent: set[tuple[str, int]] = set()
        for line in self.streams:
            f = frames[line]
            positions.update(((line, i), p) for i, p in f.positions.items())
            stamps.update(((line, i), t) for i, t in f.timestamps.items())
            failed.update((line, i) for i in f.failed)
            offline.update((line, i) for i in f.offline)
            held.update((line, i) for i in f.held)
            not_sent.update((line, i) for i in f.not_sent)
        return GroupFrame(
            cycle=cycle,
            positions=positions,
            timestamps=stamps,
            failed=frozenset(failed),
            offline=frozenset(offline),
            line_cycles={line: f.cycle for line, f in frames.items()},
            skipped=max(f.skipped for f in new.values()),
            line_started={line: f.started for line, f in frames.items()},
            # (from the new frames only: each line's own next_frame keeps what its skipped frames said)
            missed_slots=sum(f.missed_slots for f in new.values()),
            resumed=frozenset(line for line, f in new.items() if f.resumed),
            held=frozenset(held),
            not_sent=frozenset(not_sent),
        )

    @property
    def latest(self) -> GroupFrame | None:
        """Every line's newest published frame merged (takes none: does not mark them consumed); ``None`` until
        every line has published one.

        As :attr:`Stream.latest <ics35_async.Stream.latest>`, for any task while another takes the frames:
        ``line_cycles`` tell how new each line's part is; ``cycle`` is the last merged frame taken's (0 before one
        was), ``skipped`` is 0, and ``missed_slots`` and ``resumed`` are what those newest frames say.
        """
        frames = {line: s.latest for line, s in self.streams.items()}
        newest = {line: f for line, f in frames.items() if f is not None}
        if len(newest) < len(frames):
            return None
        return self._merge(newest, newest, self._cycle)  # (a published frame's own skipped is 0)

    @property
    def offline(self) -> frozenset[tuple[str, int]]:
        """Each line's :attr:`Stream.offline <ics35_async.Stream.offline>` now, keyed by ``(line, id)``."""
        return frozenset((line, sid) for line, stream in self.streams.items() for sid in stream.offline)

    @property
    def held(self) -> dict[tuple[str, int], str]:
        """Each line's :attr:`Stream.held <ics35_async.Stream.held>` now, keyed by ``(line, id)``."""
        return {(line, sid): why for line, stream in self.streams.items() for sid, why in stream.held.items()}

    @property
    def stats(self) -> dict[str, StreamStats]:
        """Each line's stream statistics, by line name."""
        return {line: s.stats for line, s in self.streams.items()}

    async def __aenter__(self) -> GroupStream:
        try:
            for s in self.streams.values():
                await s.start()
        except BaseException:
            await self.aclose()  # the lines already started must not stay attached
            raise
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.aclose()

    def __repr__(self) -> str:
        lives = {s._life() for s in self.streams.values()}
        if self._closed or len(lives) == 1:  # (one state for all: said once)
            lines = ", ".join(f"{line}: {list(s.ids)} {s._pace()}" for line, s in self.streams.items())
            return f"<GroupStream {lines}, {'closed' if self._closed else lives.pop()}>"
        # Lines in different states (one ended by its lost port, the others running): each says its own.
        lines = ", ".join(f"{line}: {list(s.ids)} {s._pace()} {s._life()}" for line, s in self.streams.items())
        return f"<GroupStream {lines}>"

    async def aclose(self) -> None:
        """Stop every line's stream; the buses stay open."""
        self._closed = True
        async with anyio.create_task_group() as group:
            for s in self.streams.values():
                group.start_soon(s.aclose)


class BusGroup:
    """Several ICS lines used together (e.g. left and right half of a humanoid).

    ``BusGroup({"left": open_bus("/dev/ttyUSB0"), "right": open_bus("/dev/ttyUSB1")})``;
    use as ``async with`` to open and close every line.

    Args:
        buses: ``{line name: bus}``, or a list of buses (named ``"0"``, ``"1"``, ...).

    Raises:
        InvalidArgument: no bus, or something that is not a bus.
    """

    def __init__(self, buses: Mapping[str, Bus] | Sequence[Bus]) -> None:
        if isinstance(buses, Mapping):
            self.buses = dict(buses)
        elif isinstance(buses, Sequence) and not isinstance(buses, (str, bytes)):
            self.buses = {str(k): b for k, b in enumerate(buses)}
        else:
            raise InvalidArgument(f"a BusGroup takes {{name: bus}} or a list of buses, not {type(buses).__name__}")
        if not self.buses:
            raise InvalidArgument("a BusGroup needs at least one bus")
        for name, bus in self.buses.items():
            if isinstance(bus, (str, os.PathLike)):  # a port, as BusGroup.open takes them
                raise InvalidArgument(
                    f"line {name!r} is a port, not a Bus: BusGroup({{{name!r}: open_bus({str(bus)!r})}}), or"
                    f" BusGroup.open({{{name!r}: {str(bus)!r}}}) to open every line with the same options"
                )
            if not isinstance(bus, Bus):
                raise InvalidArgument(f"line {name!r} is not a Bus")

    def __repr__(self) -> str:
        return f"<BusGroup {', '.join(f'{name}={bus!r}' for name, bus in self.buses.items())}>"

    @classmethod
    def open(
        cls, ports: Mapping[str, str | WireDevice] | Sequence[str | WireDevice], **bus_options: Unpack[BusOptions]
    ) -> BusGroup:
        """A group of buses opened with the same options.

        Args:
            ports: ``{line name: port}``, or a list of ports (lines named ``"0"``, ``"1"``, ..., as ``BusGroup``
                names a list of buses).
            **bus_options: every line's options ([`BusOptions`][ics35_async.bus.BusOptions]).

        Raises:
            InvalidArgument: ``ports`` is neither, or a bad port or option (see ``open_bus``).
        """
        if isinstance(ports, Mapping):
            named = dict(ports)
        elif isinstance(ports, Sequence) and not isinstance(ports, (str, bytes)):
            named = {str(k): port for k, port in enumerate(ports)}
        else:
            raise InvalidArgument(f"BusGroup.open takes {{name: port}} or a list of ports, not {type(ports).__name__}")
        return cls({name: open_bus(port, **bus_options) for name, port in named.items()})

    def __getitem__(self, line: str) -> Bus:
        return self.buses[line]

    def stream(
        self,
        ids: Mapping[str, Iterable[int]],
        *,
        rate_hz: float | None = None,
        watch: Iterable[int | tuple[str, int]] = (),
        offline: Iterable[int | tuple[str, int]] = (),
        **stream_options: Unpack[LineStreamOptions],
    ) -> GroupStream:
        """A [`GroupStream`][ics35_async.group.GroupStream] over ``{line: ids}``; use as ``async with``.

        ``rate_hz`` and ``stream_options`` are each line's stream's, as [`Bus.stream`][ics35_async.bus.Bus.stream]
        takes them; ``offline`` and ``watch`` also take ``(line, id)`` pairs, as the group's frames name servos,
        each for its own line only (a plain ID is for every line).

        Raises:
            InvalidArgument: no line, an unknown line, a bad ID or option.
        """
        if not isinstance(ids, Mapping):
            raise InvalidArgument(f"a group stream takes {{line: ids}}, not {type(ids).__name__}")
        unknown = set(ids) - set(self.buses)
        if unknown:
            raise InvalidArgument(f"unknown line(s): {', '.join(sorted(unknown))}")
        watched = _ids_per_line("watch", watch, ids)
        silent = _ids_per_line("offline", offline, ids)
        return GroupStream(
            {
                line: self.buses[line].stream(
                    i, rate_hz=rate_hz, watch=watched[line], offline=silent[line], **stream_options
                )
                for line, i in ids.items()
            }
        )

    async def __aenter__(self) -> BusGroup:
        try:
            for bus in self.buses.values():
                await bus.open()
        except BaseException:
            await self.aclose()
            raise
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.aclose()

    if not TYPE_CHECKING:  # (at run time only: a type checker says `with` is wrong itself, and suggests __aenter__)

        def __enter__(self) -> NoReturn:
            raise TypeError("a group of lines is opened with `async with BusGroup(...) as group:`")

        def __exit__(self, *exc: object) -> None:
            return None

    async def aclose(self) -> None:
        """Close every bus, in reverse order; errors while closing are suppressed."""
        # One after another, in reverse order: the last opened is the first closed.
        for bus in reversed(self.buses.values()):
            with contextlib.suppress(IcsError, OSError):
                await bus.aclose()


def _ids_per_line(name: str, given: Iterable[int | tuple[str, int]], lines: Iterable[str]) -> dict[str, list[int]]:
    """``given`` (``watch`` or ``offline`` of a group stream) split by line: a ``(line, id)`` pair for its line,
    as the group's frames name servos; a plain ID for every line."""
    per_line: dict[str, list[int]] = {line: [] for line in lines}
    for item in given:
        if isinstance(item, tuple) and len(item) == 2 and isinstance(item[0], str):
            line, sid = item
            if line not in per_line:
                raise InvalidArgument(f"{name}: {item!r} names line {line!r}, not one of this stream's")
            per_line[line].append(sid)
        else:
            for ids in per_line.values():
                ids.append(item)  # (checked by each line's stream: an int 0..31)
    return per_line
