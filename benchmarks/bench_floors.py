"""Floors for section A: what the pty, the event loop and the engine cost on their own, with nothing of ours around.

Each is a measure of one layer under a stream or sequential transaction, so
that section A can say where each microsecond of ours goes:

* ``loop_stream(path, loop)``: an event loop's reader callback reads the
  reply and writes the next position command (``add_reader``, ``os.read``,
  ``os.write``): one loop pass per transaction and nothing else;
* ``loop_sequential(path, loop)``: a coroutine writes a command and awaits a
  future that the reader callback resolves once 6 bytes are in: the await,
  the future and the task's wake-up an awaited request cannot avoid;
* ``engine_alone()``: the engine and a 32-ID stream fed complete replies in a
  loop, with no I/O and no event loop: their own Python per transaction
  (warm caches; between system calls the same code runs slower).

Every I/O floor talks to the lean responder like the rows it explains.
"""

from __future__ import annotations

import asyncio
import os
import time
from typing import Any

import serial
from bench_common import IDS, NEUTRAL, POSITION_TXS, run_on

from ics35_async import protocol
from ics35_async.engine import LineEngine
from ics35_async.stream import Stream

Figures = dict[str, Any]


def _port(path: str) -> tuple[serial.Serial, int]:
    ser = serial.Serial(path, 115200, parity=serial.PARITY_NONE, timeout=1)
    fd = ser.fileno()
    os.set_blocking(fd, False)
    return ser, fd


def loop_stream(path: str, loop: str, duration: float) -> Figures:
    """One event-loop pass per transaction: the reader callback writes the next command."""
    ser, fd = _port(path)
    txs = POSITION_TXS

    async def measure() -> Figures:
        running = asyncio.get_running_loop()
        done = running.create_future()
        state = {"got": 0, "n": 0}
        end = [0.0]

        def readable() -> None:
            state["got"] += len(os.read(fd, 64))
            if state["got"] < 6:
                return
            state["got"] = 0
            n = state["n"] = state["n"] + 1
            if not n % 1024 and time.perf_counter() >= end[0]:
                running.remove_reader(fd)
                done.set_result(None)
                return
            os.write(fd, txs[n % len(txs)])

        running.add_reader(fd, readable)
        wall0, cpu0 = time.perf_counter(), time.process_time()
        end[0] = wall0 + duration
        os.write(fd, txs[0])
        await done
        wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
        return {"tx_per_s": state["n"] / wall, "cpu_us_per_tx": cpu / state["n"] * 1e6, "failures": 0}

    try:
        return run_on(loop, measure)
    finally:
        ser.close()


def loop_sequential(path: str, loop: str, duration: float) -> Figures:
    """An awaited future per transaction, resolved by the reader callback."""
    ser, fd = _port(path)
    txs = POSITION_TXS

    async def measure() -> Figures:
        running = asyncio.get_running_loop()
        waiting: list[asyncio.Future[None]] = []
        got = [0]

        def readable() -> None:
            got[0] += len(os.read(fd, 64))
            if got[0] >= 6 and waiting:
                got[0] = 0
                waiting.pop().set_result(None)

        async def transaction(tx: bytes) -> None:
            fut = running.create_future()
            waiting.append(fut)
            os.write(fd, tx)
            await fut

        running.add_reader(fd, readable)
        try:
            n = 0
            wall0, cpu0 = time.perf_counter(), time.process_time()
            end = wall0 + duration
            while time.perf_counter() < end:
                for tx in txs:
                    await transaction(tx)
                n += len(txs)
            wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
        finally:
            running.remove_reader(fd)
        return {"tx_per_s": n / wall, "cpu_us_per_tx": cpu / n * 1e6, "failures": 0}

    try:
        return run_on(loop, measure)
    finally:
        ser.close()


class _NoLine:
    """The least a stream needs of its line when nothing goes on a wire."""

    baudrate = 115200

    def notify(self, callback: Any) -> None:
        callback()


def engine_alone(transactions: int = 200_000) -> Figures:
    """The engine and a 32-ID stream fed each complete echo + reply at once: CPU per transaction."""
    engine = LineEngine(baudrate=115200)
    stream = Stream(_NoLine(), IDS)  # type: ignore[arg-type]
    stream._running = True  # started by hand: no bus to attach to
    engine.connected(0.0)
    answers = {}
    for sid in IDS:
        tx = protocol.position_tx(sid, protocol.FREE)
        header = protocol.position_reply_header(sid, 115200)
        answers[tx] = tx + bytes((header, NEUTRAL >> 7, NEUTRAL & 0x7F))
    out = engine.attach_source(stream._hooks, 0.0)  # what the bus attaches (the stream itself warns)
    clock = time.perf_counter
    receive = engine.receive
    cpu0 = time.process_time()
    for _ in range(transactions):
        out = receive(answers[out], clock())  # type: ignore[index]
    cpu = time.process_time() - cpu0
    assert stream._cycle >= transactions // len(IDS)
    return {"cpu_us_per_tx": cpu / transactions * 1e6, "transactions": transactions}
