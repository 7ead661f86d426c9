"""A stream's targets: per ID a position, free (0), or watched (ICS 3.6's position read, no target sent).

The half of :class:`~ics35_async.stream.Stream` that its users call to steer
it; each change rewrites the ID's prepared transaction, so the stream's hot
path only sends what is ready.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

from . import protocol, units
from .errors import InvalidArgument

WATCH = -1
"""The target of a watched ID: ICS 3.6's position read each cycle, torque and target left alone."""


class StreamTargets:
    """Target bookkeeping of a stream (mixed into :class:`~ics35_async.stream.Stream`)."""

    ids: tuple[int, ...]
    _index: dict[int, int]
    _targets: list[int]
    _jobs: list[tuple[bytes, int, int]]
    _readers: list[protocol.ReadPosition | None]

    def _slot(self, servo_id: int) -> int:
        try:
            return self._index[servo_id]
        except (KeyError, TypeError):
            raise InvalidArgument(f"ID {servo_id!r} is not in this stream {list(self.ids)}") from None

    def set_target(self, servo_id: int, position: int) -> None:
        """Latest-value target for one ID: 1..16383, or 0 for free (torque off, still read back)."""
        self.apply_targets([(self._slot(servo_id), units.check_int("position", position, 0, protocol.POSITION_MAX))])

    def set_targets(self, targets: Mapping[int, int]) -> None:
        """Several targets at once; all are checked before any is applied."""
        self.apply_targets(self.check_targets(targets))

    def check_targets(self, targets: Mapping[int, int]) -> list[tuple[int, int]]:
        """Check every target (raising before anything changes) and return them ready for apply_targets."""
        if not isinstance(targets, Mapping):
            raise InvalidArgument(f"targets must be a mapping {{id: position}}, not {type(targets).__name__}")
        return [(self._slot(i), units.check_int("position", p, 0, protocol.POSITION_MAX)) for i, p in targets.items()]

    def apply_targets(self, checked: list[tuple[int, int]]) -> None:
        """Apply targets that :meth:`check_targets` returned."""
        for k, p in checked:
            if self._targets[k] != p:
                self._targets[k] = p
                sid = self.ids[k]
                self._jobs[k] = (protocol.position_tx(sid, p), 3, sid)
                self._readers[k] = None

    def set_target_degrees(self, servo_id: int, degrees: float) -> None:
        self.set_target(servo_id, units.degrees_to_position(degrees))

    def set_targets_degrees(self, targets: Mapping[int, float]) -> None:
        if not isinstance(targets, Mapping):
            raise InvalidArgument(f"targets must be a mapping {{id: degrees}}, not {type(targets).__name__}")
        self.set_targets({i: units.degrees_to_position(d) for i, d in targets.items()})

    def free(self, ids: Iterable[int] | None = None) -> None:
        """Put ``ids`` (default: all) in free mode: torque off, positions still read back."""
        self.set_targets(dict.fromkeys(self.ids if ids is None else units.check_ids("ids", ids), protocol.FREE))

    def watch(self, ids: Iterable[int] | None = None) -> None:
        """Watch ``ids`` (default: all): read their position with ICS 3.6's read, sending no target.

        For ICS 3.6 servos only (an ICS 3.5 servo stays silent to the read,
        and goes offline in the stream); the torque is left as it is.
        """
        slots = [self._slot(i) for i in (self.ids if ids is None else units.check_ids("ids", ids))]
        for k in slots:
            reader = protocol.ReadPosition(self.ids[k])
            self._targets[k] = WATCH
            self._readers[k] = reader
            self._jobs[k] = (reader.tx, reader.reply_len, self.ids[k])

    def target(self, servo_id: int) -> int:
        """The ID's target: a position, 0 (free) or :data:`WATCH`."""
        return self._targets[self._slot(servo_id)]
