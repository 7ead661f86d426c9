"""Sequential transactions over a pty, per transport: rate and client CPU per transaction.

Each transaction writes a 3-byte command and waits for 6 bytes (the 3-byte
echo plus a 3-byte reply), as a position command does on the real line.  The
far end is a lean responder process on the pty master (raw os.read/os.write),
so the client's ``time.process_time`` measures the client alone.

Rows: blocking pyserial (the baseline), then open_line's transports (direct,
pyserial-asyncio-fast, stock pyserial-asyncio) driven the way the bus drives
them (an asyncio Protocol resolving one future per transaction), each with
the default loop and uvloop.  An in-process row (no pty) shows the cost of
InProcessTransport alone.  Medians of --runs runs, variants interleaved so
drift hits them all alike.

    .venv/bin/python benchmarks/transports.py [-n 3000] [--runs 5]
"""

from __future__ import annotations

import argparse
import asyncio
import os
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from typing import Any

import serial

from ics35_async.transports import HostSide, open_line

COMMAND = b"\x80\x3a\x4c"  # position command to ID 0: 3 bytes out, 3 echoed, 3 back
TX_LEN, RX_LEN = 3, 6
WARMUP = 200
KINDS = (("direct", "direct (ours)"), ("fast", "pyserial-asyncio-fast"), ("stock", "pyserial-asyncio"))

RESPONDER = r"""
import os, sys
fd = int(sys.argv[1])
pending = b""
while True:
    try:
        data = os.read(fd, 4096)
    except OSError:  # EIO: the last slave fd closed
        break
    if not data:
        break
    pending += data
    n = len(pending) - len(pending) % 3
    if n:
        out = bytearray()
        for i in range(0, n, 3):
            cmd = pending[i:i + 3]
            out += cmd
            out.append(cmd[0] & 0x7F)
            out += cmd[1:]
        os.write(fd, out)
        pending = pending[n:]
"""


class PtyResponder:
    """A pty whose master end answers every 3-byte command, in a child process."""

    def __enter__(self) -> str:
        master, self._slave = os.openpty()  # we keep a slave fd so the master never sees EIO between opens
        self._proc = subprocess.Popen([sys.executable, "-c", RESPONDER, str(master)], pass_fds=(master,))
        os.close(master)
        return os.ttyname(self._slave)

    def __exit__(self, *exc: object) -> None:
        os.close(self._slave)
        try:
            self._proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()


Measurement = tuple[float, float]  # (transactions per second, CPU seconds per transaction)


def run_blocking(port: str, n: int) -> Measurement:
    # A pty has no parity (and drops PARENB); the baseline does not need to care.
    ser = serial.serial_for_url(port, baudrate=115200, parity=serial.PARITY_NONE, timeout=1)
    try:
        for _ in range(WARMUP):
            ser.write(COMMAND)
            ser.read(RX_LEN)
        wall, cpu = time.perf_counter(), time.process_time()
        for _ in range(n):
            ser.write(COMMAND)
            if len(ser.read(RX_LEN)) != RX_LEN:
                raise RuntimeError("responder went silent")
        wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    finally:
        ser.close()
    return n / wall, cpu / n


class Client(asyncio.Protocol):
    """The bus's pattern: write, then await a future resolved by data_received."""

    def __init__(self) -> None:
        self.received = 0
        self.waiter: asyncio.Future[None] | None = None

    def data_received(self, data: bytes) -> None:
        self.received += len(data)
        if self.received >= RX_LEN and self.waiter is not None and not self.waiter.done():
            self.waiter.set_result(None)

    def connection_lost(self, exc: Exception | None) -> None:
        if self.waiter is not None and not self.waiter.done():
            self.waiter.set_exception(exc or ConnectionError("closed"))


async def transact(loop: asyncio.AbstractEventLoop, line: asyncio.Transport, client: Client, n: int) -> None:
    for _ in range(n):
        client.received = 0
        client.waiter = loop.create_future()
        line.write(COMMAND)
        await client.waiter


async def measure_line(port: Any, kind: str, n: int) -> Measurement:
    loop = asyncio.get_running_loop()
    line, client = await open_line(port, baudrate=115200, protocol_factory=Client, transport=kind)
    try:
        await transact(loop, line, client, WARMUP)
        wall, cpu = time.perf_counter(), time.process_time()
        await transact(loop, line, client, n)
        wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    finally:
        line.close()
        await asyncio.sleep(0.01)
    return n / wall, cpu / n


class ReplyingDevice:
    """In-process far end: echo plus reply for every 3 bytes, delivered at once."""

    def connect(self, host: HostSide, baudrate: int) -> None:
        self.host = host

    def write(self, data: bytes) -> None:
        self.host.deliver(data + bytes((data[0] & 0x7F,)) + data[1:])

    def disconnect(self) -> None:
        pass


def loop_factory(name: str) -> Callable[[], asyncio.AbstractEventLoop]:
    if name == "uvloop":
        import uvloop

        return uvloop.new_event_loop
    return asyncio.new_event_loop


def run_async(port: Any, kind: str, loop_name: str, n: int) -> Measurement:
    with asyncio.Runner(loop_factory=loop_factory(loop_name)) as runner:
        return runner.run(measure_line(port, kind, n))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("-n", type=int, default=3000, help="transactions per run (default 3000)")
    parser.add_argument("--runs", type=int, default=5, help="runs per variant; medians are shown (default 5)")
    args = parser.parse_args()

    loops = ["asyncio"]
    try:
        import uvloop  # noqa: F401

        loops.append("uvloop")
    except ImportError:
        print("uvloop not installed: default loop only")

    variants: list[tuple[str, str, Callable[[], Measurement]]] = [
        ("blocking pyserial", "-", lambda: on_pty(lambda port: run_blocking(port, args.n)))
    ]
    for loop_name in loops:
        for kind, label in KINDS:
            variants.append(
                (label, loop_name, lambda k=kind, lp=loop_name: on_pty(lambda port: run_async(port, k, lp, args.n)))
            )
    in_process = [
        ("in-process (no pty)", loop_name, lambda lp=loop_name: run_async(ReplyingDevice(), "auto", lp, args.n))
        for loop_name in loops
    ]

    results: dict[tuple[str, str], list[Measurement]] = {}
    for run in range(args.runs):
        print(f"run {run + 1}/{args.runs}", file=sys.stderr)
        for label, loop_name, fn in variants + in_process:
            results.setdefault((label, loop_name), []).append(fn())

    def medians(key: tuple[str, str]) -> Measurement:
        runs = results[key]
        return statistics.median(r for r, _ in runs), statistics.median(c for _, c in runs)

    base_rate, base_cpu = medians(("blocking pyserial", "-"))
    print(f"\n{args.n} sequential write-{TX_LEN}/read-{RX_LEN} transactions over a pty, median of {args.runs} runs")
    print(f"{'transport':24} {'loop':8} {'tx/s':>8} {'CPU us/tx':>10} {'rate/base':>10} {'CPU/base':>9}")
    for label, loop_name, _ in variants + in_process:
        rate, cpu = medians((label, loop_name))
        print(
            f"{label:24} {loop_name:8} {rate:8.0f} {cpu * 1e6:10.1f} {rate / base_rate:10.2f} {cpu / base_cpu:9.2f}"
        )
    print("base = blocking pyserial; in-process rows have no pty and are shown for scale only")


def on_pty(fn: Callable[[str], Measurement]) -> Measurement:
    with PtyResponder() as port:
        return fn(port)


if __name__ == "__main__":
    main()
