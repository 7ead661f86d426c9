"""Pieces the soaks share: the fault mix, the workloads' requests, the consistency check, the table."""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import math
import random
import threading
import time
from collections.abc import AsyncIterator, Awaitable, Callable, Sequence
from typing import Any

from benchmarks.bench_common import burst_path_built
from ics35_async import (
    Bus,
    Eeprom,
    Priority,
    ReplyError,
    Servo,
    protocol,
)
from ics35_async.protocol import Command, Param
from ics35_async.sim import (
    FaultConfig,
    FaultInjector,
    PtyServer,
    VirtualLine,
)
from ics35_async.stats import IdStats
from tests.support.oracle import FAULT_KINDS, band

IN_PROCESS, PTY, PTY_BURST = "in-process", "pty", "pty, burst path"
"""Where a soak's simulator answers: in this process as a WireDevice, or on a pty with the bus on the ordinary
path or on the burst path (see the chaos soak's module), under the asyncio driver, or the thread driver
(PTY_BURST_THREAD), or the anyio driver on asyncio (PTY_BURST_ANYIO)."""
PTY_BURST_THREAD = "pty, burst path, thread driver"
PTY_BURST_ANYIO = "pty, burst path, anyio driver"
BURST_LINKS = (PTY_BURST, PTY_BURST_THREAD, PTY_BURST_ANYIO)  # the links whose bus runs streams on the compiled path


def link_driver(link: str) -> str:
    """The bus driver a soak over ``link`` opens with."""
    return {PTY_BURST_THREAD: "thread", PTY_BURST_ANYIO: "anyio"}.get(link, "asyncio")


@contextlib.asynccontextmanager
async def served_on_a_pty(sim: VirtualLine) -> AsyncIterator[str]:
    """``sim`` answering on a pty from a thread of this process (its log stays readable here); yields the path."""
    server = PtyServer(sim)
    path = str(server.open())
    thread = threading.Thread(target=server.serve, name="soak pty server", daemon=True)
    thread.start()
    try:
        yield path
    finally:
        server.stop()
        await asyncio.to_thread(thread.join)
        server.close()


def fault_spec(rate: float, kinds: Sequence[str] = FAULT_KINDS) -> str:
    """A spec giving every kind the same rate so that about ``rate`` of transactions get a fault."""
    if rate <= 0:
        return "none"
    each = 1 - (1 - rate) ** (1 / len(kinds))
    return ",".join(f"{kind}:{each:.6f}" for kind in kinds)


def stream_target(i: int, cycle: int) -> int:
    low, high = band(i)
    middle, amplitude = (low + high) // 2, (high - low) // 2 - 2
    return 2 * ((middle + round(amplitude * math.sin(cycle / 15 + i))) // 2)


def random_request(
    rng: random.Random, bus: Bus, sid: int, image: Eeprom
) -> tuple[Command[Any], Callable[[], Awaitable[Any]], int]:
    """A random request to ``sid``: its command (for the bytes), how to make it, attempts allowed."""
    priority = rng.choice(list(Priority))
    servo = Servo(bus, sid, priority=priority)
    roll = rng.random()
    default_attempts = 1 + bus.retries
    if roll < 0.25:
        low, high = band(sid)
        position = rng.randrange(low + 1, high, 2)
        return (
            protocol.Position(sid, position, baudrate=bus.baudrate),
            lambda: servo.set_position(position),
            default_attempts,
        )
    if roll < 0.33:
        return protocol.Position(sid, protocol.FREE, baudrate=bus.baudrate), servo.free, default_attempts
    if roll < 0.55:
        # Current and temperature only: the bus's own guard reads (after a timeout) read stretch or
        # speed, so those bytes in the log are always a guard, never a caller's request.
        param = rng.choice((Param.CURRENT, Param.TEMPERATURE))
        reader = servo.read_current if param is Param.CURRENT else servo.read_temperature
        return protocol.ReadParam(sid, param), reader, default_attempts
    if roll < 0.70:
        # Straight to the bus, with its own priority and retries.
        cmd: Command[Any] = protocol.ReadParam(sid, rng.choice((Param.CURRENT, Param.TEMPERATURE)))
        retries = rng.randrange(3)
        return cmd, lambda: bus.request(cmd, priority=priority, retries=retries), 1 + retries
    if roll < 0.88:
        param = Param(rng.randrange(1, 5))
        low, high = protocol.WRITE_RANGES[param]
        if param is Param.TEMPERATURE:
            high = 80  # a limit this hot (smaller is hotter) never trips: the servos keep their torque
        value = rng.randint(low, high)
        writer = {
            Param.STRETCH: servo.write_stretch,
            Param.SPEED: servo.write_speed,
            Param.CURRENT: servo.write_current_limit,
            Param.TEMPERATURE: servo.write_temperature_limit,
        }[param]
        return protocol.WriteParam(sid, param, value), lambda: writer(value), default_attempts
    if roll < 0.97:
        return protocol.ReadEeprom(sid), servo.read_eeprom, default_attempts
    if roll < 0.995:
        write = protocol.WriteEeprom(sid, image)  # not idempotent: never retried
        return write, lambda: bus.request(write, priority=priority, retries=2), 1
    # A servo has no generic memory: it stays silent, the caller gets a timeout.
    silent = protocol.ReadMemory(sid, rng.randrange(100), rng.randrange(1, 8))
    return silent, lambda: bus.request(silent, priority=priority, retries=0), 1


REALTIME_PATIENCE = 2.0
"""Seconds the check after a soak over a pty keeps asking for each value (see :func:`consistency_check`)."""


async def consistency_check(sim: VirtualLine, bus: Bus, *, realtime: bool = False) -> dict[str, Any]:
    """Faults off; every servo must answer exactly what the simulator holds; the bus idle and its counters sane.

    ``realtime``: the simulator answers on a pty from a thread of this process, which a loaded machine may hold
    up past a reply's allowance (the soaks' is short): each value is then asked for again for up to
    :data:`REALTIME_PATIENCE` seconds, and errors on the fault-free line are told in ``notes``, not ``problems``,
    as the soaks over a pty count rejected valid replies without failing on them.
    """
    sim.faults = FaultInjector(FaultConfig(), 0)
    problems: list[str] = []
    notes: list[str] = []

    async def ask(command: Command[Any]) -> Any:
        give_up = time.monotonic() + (REALTIME_PATIENCE if realtime else 0.0)
        while True:
            try:
                return await bus.request(command)  # (each command here is idempotent: asked again, it does no harm)
            except ReplyError:
                if time.monotonic() >= give_up:
                    raise

    # A reply held back by a `late` fault of the very last transaction lands on the next one: let it.
    with contextlib.suppress(ReplyError):
        await bus.request(protocol.ReadParam(0, Param.STRETCH), retries=1)
    before = bus.stats.total.errors
    per_id_before = {i: dataclasses.replace(c) for i, c in bus.stats.per_id.items()}
    for servo in sim.servos:
        i = servo.servo_id
        # Each expected value is read from the servo right after the transaction (left to right).
        for what, got, want in (
            ("stretch", await ask(protocol.ReadParam(i, Param.STRETCH)), servo.stretch),
            ("speed", await ask(protocol.ReadParam(i, Param.SPEED)), servo.speed),
            (
                "current limit",
                await ask(protocol.WriteParam(i, Param.CURRENT, servo.current_limit)),
                servo.current_limit,
            ),
            ("eeprom", await ask(protocol.ReadEeprom(i)), servo.eeprom),
            ("position", await ask(protocol.Position(i, protocol.FREE, baudrate=bus.baudrate)), servo.position),
        ):
            if got != want:
                problems.append(f"ID {i} {what}: bus says {got!r}, servo holds {want!r}")
        if not servo.calibration_intact:
            problems.append(f"ID {i}: factory calibration bytes changed")
    await bus.wait_idle()
    stats = bus.stats
    if stats.total.errors != before:
        kinds = ("timeouts", "partial_replies", "echo_mismatches", "bad_replies")
        which = {
            f"ID {i}": {k: n for k in kinds if (n := getattr(c, k) - getattr(per_id_before.get(i, IdStats()), k))}
            for i, c in stats.per_id.items()
            if c.errors != per_id_before.get(i, IdStats()).errors
        }
        errors = f"{stats.total.errors - before} errors on a fault-free line: {which}"
        if realtime:
            notes.append(f"{errors} (real time: the simulator's thread held up)")
        else:
            problems.append(errors)
    if stats.queued:
        problems.append(f"{stats.queued} requests still queued")
    if stats.total.transactions != sim.transactions:
        problems.append(f"bus counted {stats.total.transactions} transactions, the line saw {sim.transactions}")
    if stats.total.ok + stats.total.errors != stats.total.transactions:
        problems.append(f"ok {stats.total.ok} + errors {stats.total.errors} != {stats.total.transactions}")
    if sum(s.transactions for s in stats.per_id.values()) != stats.total.transactions:
        problems.append("per-ID transaction counts do not add up")
    return {"consistent": not problems, "problems": problems, "notes": notes, "resyncs": stats.resyncs}


def ms(seconds: float) -> str:
    return f"{seconds * 1e3:.1f} ms"


Row = tuple[str, str, bool | None]
"""One line of the table: check, result, whether its target is met (None: a figure, no target)."""


def executor_row(check: str, count: int, detail: str = "") -> Row:
    """How many transactions the compiled executor ran: a target (some did) where it is built here."""
    built = burst_path_built()
    return (
        check,
        f"{count:,}{detail}" + ("" if built else " (the executor is not built here)"),
        count > 0 if built else None,
    )


def markdown(rows: Sequence[Row]) -> str:
    lines = ["| check | result | target met |", "|---|---|---|"]
    for name, value, ok in rows:
        lines.append(f"| {name} | {value} | {'' if ok is None else 'yes' if ok else '**NO**'} |")
    return "\n".join(lines)
