"""Finding and naming devices on a line: scan, ID read, the safe ID write."""

from __future__ import annotations

from collections.abc import Iterable
from typing import TYPE_CHECKING

import anyio

from . import protocol
from .errors import BadReply, ReplyError, UnsafeOperation
from .units import check_ids, check_int

if TYPE_CHECKING:
    from .bus import Bus


async def read_id(bus: Bus, *, exactly_one_device: bool = False) -> int:
    """Read the ID of the only device on the line.

    With several devices on the line every one answers at once and the
    result is garbage, so the caller must confirm there is exactly one.
    """
    if exactly_one_device is not True:
        raise UnsafeOperation(
            "read_id() needs exactly one device on the line (every device answers the ID command); "
            "pass exactly_one_device=True to confirm"
        )
    return await bus.request(protocol.ReadId())


async def write_id(bus: Bus, new_id: int, *, exactly_one_device: bool = False) -> int:
    """Give the only device on the line the ID ``new_id`` (stored in its EEPROM).

    Every device on the line takes the new ID, so this is refused unless
    the caller confirms with ``exactly_one_device=True``.
    """
    command = protocol.WriteId(new_id)
    if exactly_one_device is not True:
        raise UnsafeOperation(
            "write_id() renames EVERY device on the line; disconnect all but one and pass exactly_one_device=True"
        )
    # Take the caller's word, but check it: exactly one ID may answer a harmless read,
    # and the ID read (which every device answers) must agree with it.
    found = await scan(bus)
    if len(found) != 1:
        raise UnsafeOperation(
            f"{len(found)} devices answer on this line (IDs {found}); write_id() needs exactly one; "
            "nothing was written"
        )
    try:
        current = await bus.request(protocol.ReadId())
    except BadReply as exc:
        raise UnsafeOperation(
            f"the ID read came back garbled ({exc.raw.hex(' ')}): more than one device is on the line; "
            "nothing was written"
        ) from exc
    if current != found[0]:
        raise UnsafeOperation(
            f"the ID read says {current} but ID {found[0]} answers: another device (at another baud "
            "rate?) may share the line; nothing was written"
        )
    return await bus.request(command)


async def scan(bus: Bus, ids: Iterable[int] = range(32), *, concurrency: int = 32) -> list[int]:
    """IDs that answer a stretch read (harmless: it moves nothing).

    ``concurrency`` bounds how many probes are queued at once (the line
    still runs them one at a time), leaving room for other callers.
    """
    checked = check_ids("ids", ids)
    gate = anyio.Semaphore(check_int("concurrency", concurrency, 1, 32))
    answered: set[int] = set()

    async def probe(i: int) -> None:
        async with gate:
            try:
                await bus.request(protocol.ReadParam(i, protocol.Param.STRETCH), retries=1)
            except ReplyError:
                return
            answered.add(i)

    async with anyio.create_task_group() as group:
        for i in checked:
            group.start_soon(probe, i)
    return [i for i in checked if i in answered]
