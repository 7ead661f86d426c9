"""What a bus offers on top of its line: servos, devices, streams, the ID command and a quick scan.

These build on layer 5 (servos, streams, policies) through lazy imports, so
opening a bus does not load them; :class:`~ics35_async.bus.Bus` mixes them in.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import TYPE_CHECKING, Any, cast

from . import protocol
from .errors import InvalidArgument, UnsafeOperation
from .units import check_ids

if TYPE_CHECKING:
    from .line import Line
    from .servo import Device, Servo
    from .stream import Stream


class LineConveniences:
    """Servos, devices, streams, the ID command and a scan, for a class that is a :class:`~ics35_async.line.Line`."""

    @property
    def _line(self) -> Line:
        return cast("Line", self)

    def servo(self, servo_id: int) -> Servo:
        """A [`Servo`][ics35_async.servo.Servo] with ID ``servo_id`` (0..31) on this line; nothing is sent.

        Raises:
            InvalidArgument: ``servo_id`` is not an ID 0..31.
        """
        from .servo import Servo

        return Servo(self._line, servo_id)

    def device(self, device_id: int) -> Device:
        """A generic memory [`Device`][ics35_async.servo.Device] with ID ``device_id`` (0..31); nothing is sent.

        Raises:
            InvalidArgument: ``device_id`` is not an ID 0..31.
        """
        from .servo import Device

        return Device(self._line, device_id)

    def servos(self, ids: Iterable[int]) -> list[Servo]:
        """One :class:`Servo` per ID in ``ids``, in order.

        Raises:
            InvalidArgument: an ID is not 0..31 or ``ids`` is not an iterable of IDs.
        """
        return [self.servo(i) for i in check_ids("ids", ids)]

    def stream(self, ids: Iterable[int], *, rate_hz: float | None = None, **options: Any) -> Stream:
        """A position [`Stream`][ics35_async.stream.Stream] over ``ids``; use it as ``async with``.

        ``rate_hz`` (``None``: cycles back to back) and the options (``offline_after``,
        ``probe_interval``, ``free_on_close``, ``history``) are the stream's.

        Raises:
            InvalidArgument: an unknown option, a bad ID, a duplicate ID or an out-of-range value.
        """
        from .stream import STREAM_OPTIONS, Stream

        unknown = set(options) - STREAM_OPTIONS
        if unknown:
            raise InvalidArgument(f"unknown stream option(s): {', '.join(sorted(unknown))}")
        return Stream(self._line, ids, rate_hz=rate_hz, **options)

    async def read_id(self, *, exactly_one_device: bool = False) -> int:
        """Read the ID of the only device on the line.

        With several devices on the line every one answers at once and the
        result is garbage, so the caller must confirm there is exactly one.
        """
        if exactly_one_device is not True:
            raise UnsafeOperation(
                "read_id() needs exactly one device on the line (every device answers the ID command); "
                "pass exactly_one_device=True to confirm"
            )
        return await self._line.request(protocol.ReadId())

    async def write_id(self, new_id: int, *, exactly_one_device: bool = False) -> int:
        """Give the only device on the line the ID ``new_id`` (stored in its EEPROM).

        Every device on the line takes the new ID, so this is refused unless
        the caller confirms with ``exactly_one_device=True`` -- and then still
        unless exactly one device is proven on the line
        (:func:`~ics35_async.policies.write_lone_id`).
        """
        protocol.check_id(new_id)
        if exactly_one_device is not True:
            raise UnsafeOperation(
                "write_id() renames EVERY device on the line; disconnect all but one and pass exactly_one_device=True"
            )
        from .policies import write_lone_id

        return (await write_lone_id(self._line, new_id)).new_id

    async def scan(self, ids: Iterable[int] = range(32), *, concurrency: int = 32) -> list[int]:
        """IDs that answer a harmless read (it moves nothing), in the order asked.

        ``concurrency`` bounds how many probes are queued at once (the line
        still runs them one at a time), leaving room for other callers.  The
        whole scan over baud rates, with EEPROM cross-checks, is
        :func:`ics35_async.policies.scan`.
        """
        from .policies import probe_ids

        checked = check_ids("ids", ids)
        return list((await probe_ids(self._line, checked, id_read_first=False, concurrency=concurrency)).answered)
