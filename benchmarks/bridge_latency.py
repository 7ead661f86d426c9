"""Per-transaction latency through TCP serial bridges (socat, ser2net) in front of the simulator's pty.

    .venv/bin/python benchmarks/bridge_latency.py [--transactions 300] [--json FILE]

Loopback only: the pty simulator (real time, servo 1) stands for the serial
line on the far machine; a bridge serves it on 127.0.0.1; the bus connects
with ``socket://`` (or, for the last path, opens a local pty that a second
socat carries to the bridge).  For each path: the latency of a position
command (6 bytes with the echo) and of an EEPROM read (68 bytes: the reply
Nagle's algorithm splits), median and 99th percentile over sequential
requests, the failures, and what the bus learnt about the link
(``bus.stats.link_extra``).  Needs ``socat`` and ``ser2net`` on PATH
(Debian: ``apt-get install socat ser2net``); not part of ``make bench``.
The first transactions of each path are not timed (the bridge opens its
device on the first connection), nor counted.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from ics35_async import IcsError, open_bus
from ics35_async.protocol import Command, Position, ReadEeprom
from ics35_async.sim import start_subprocess, stop_subprocess

WARM_UP = 5


@dataclass
class PathResult:
    path: str
    position_ms_median: float
    position_ms_p99: float
    eeprom_ms_median: float
    eeprom_ms_p99: float
    failures: int
    transactions: int
    link_extra_ms: float
    late_replies: int


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def wait_for_port(port: int, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", port), timeout=0.2):
            return
        time.sleep(0.05)
    raise RuntimeError(f"nothing listens on 127.0.0.1:{port}")


@contextlib.contextmanager
def process(args: list[str]) -> Iterator[subprocess.Popen[bytes]]:
    proc = subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        yield proc
    finally:
        proc.terminate()
        try:
            proc.wait(5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@contextlib.contextmanager
def socat_server(pty: str, nodelay: bool) -> Iterator[str]:
    """socat serving the pty on a TCP port (one client, then it exits)."""
    port = free_port()
    listen = f"TCP-LISTEN:{port},bind=127.0.0.1,reuseaddr" + (",nodelay" if nodelay else "")
    with process(["socat", listen, f"FILE:{pty},raw,echo=0,b115200,parenb=1,parodd=0,cs8,cstopb=0"]):
        # socat must not be probed (one connection only): wait until its socket exists.
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and f":{port:04X} " not in Path("/proc/net/tcp").read_text():
            time.sleep(0.05)
        yield f"socket://127.0.0.1:{port}"


def ser2net_config(pty: str, port: int, nodelay: bool) -> str:
    """A ser2net (4.x, YAML) connection for a servo line: raw TCP, no per-character delay."""
    accepter = f"tcp{'(nodelay)' if nodelay else ''},127.0.0.1,{port}"
    return (
        "connection: &servos\n"
        f"  accepter: {accepter}\n"
        f"  connector: serialdev,{pty},115200e81,local\n"
        "  options:\n"
        "    kickolduser: true\n"
        "    chardelay: false\n"
    )


@contextlib.contextmanager
def ser2net_server(pty: str, nodelay: bool, workdir: str) -> Iterator[str]:
    port = free_port()
    config = Path(workdir) / f"ser2net-{port}.yaml"
    config.write_text(ser2net_config(pty, port, nodelay))
    with process(["ser2net", "-n", "-u", "-c", str(config), "-P", str(Path(workdir) / f"ser2net-{port}.pid")]):
        wait_for_port(port)  # ser2net takes a probe connection and the next one fine
        time.sleep(0.2)
        yield f"socket://127.0.0.1:{port}"


@contextlib.contextmanager
def socat_client_pty(url: str, workdir: str) -> Iterator[str]:
    """A local pty that socat carries to the bridge (for programs that want a device path)."""
    host_port = url.removeprefix("socket://")
    link = Path(workdir) / "ttyBRIDGE"
    with process(["socat", f"PTY,raw,echo=0,link={link}", f"TCP:{host_port},nodelay"]):
        deadline = time.monotonic() + 10
        while not link.exists() and time.monotonic() < deadline:
            time.sleep(0.05)
        yield str(link)


async def measure(name: str, port: str, transactions: int) -> PathResult:
    position: list[float] = []
    eeprom: list[float] = []
    failures = 0
    async with open_bus(port, retries=0) as bus:
        # Not timed: the first transactions open the bridge's device and, with Nagle on, teach the bus the link.
        for _ in range(WARM_UP):
            with contextlib.suppress(IcsError):
                await bus.request(ReadEeprom(1))
        commands: list[Command[Any]] = [
            ReadEeprom(1) if k % 3 == 2 else Position(1, 7001 + 2 * (k % 50), baudrate=bus.baudrate)
            for k in range(transactions)
        ]
        for command in commands:
            t0 = time.perf_counter()
            try:
                await bus.request(command)
            except IcsError:
                failures += 1
                continue
            (eeprom if isinstance(command, ReadEeprom) else position).append((time.perf_counter() - t0) * 1e3)
        stats = bus.stats
    print(f"{name}: {failures} failed, errors {stats.total}", file=sys.stderr)
    return PathResult(
        name,
        percentile(position, 50),
        percentile(position, 99),
        percentile(eeprom, 50),
        percentile(eeprom, 99),
        failures,
        transactions,
        stats.link_extra * 1e3,
        stats.late_replies,
    )


def percentile(values: list[float], p: float) -> float:
    if not values:
        return float("nan")
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, max(0, round(len(ordered) * p / 100) - 1))]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--transactions", type=int, default=300, help="per path (a third are EEPROM reads)")
    parser.add_argument("--json", default=None, help="also write the figures to this file")
    args = parser.parse_args(argv)
    missing = [tool for tool in ("socat", "ser2net") if shutil.which(tool) is None]
    if missing:
        print(f"needs {' and '.join(missing)} on PATH (Debian: apt-get install socat ser2net)", file=sys.stderr)
        return 2
    results: list[PathResult] = []
    proc, pty = start_subprocess(["--ids", "1"], quiet=True)
    try:
        with tempfile.TemporaryDirectory() as workdir:
            n = args.transactions
            results.append(asyncio.run(measure("direct (the pty)", pty, n)))
            for nodelay in (False, True):
                label = "nodelay" if nodelay else "Nagle on (default)"
                with socat_server(pty, nodelay) as url:
                    results.append(asyncio.run(measure(f"socat TCP-LISTEN, {label}", url, n)))
                with ser2net_server(pty, nodelay, workdir) as url:
                    results.append(asyncio.run(measure(f"ser2net, {label}", url, n)))
            with ser2net_server(pty, True, workdir) as url, socat_client_pty(url, workdir) as local:
                results.append(asyncio.run(measure("ser2net nodelay + local socat pty", local, n)))
    finally:
        stop_subprocess(proc)
    print("| path | position (6 B) median / p99 | EEPROM read (68 B) median / p99 | failed | learnt allowance |")
    print("|---|---|---|---|---|")
    for r in results:
        print(
            f"| {r.path} | {r.position_ms_median:.2f} / {r.position_ms_p99:.2f} ms "
            f"| {r.eeprom_ms_median:.2f} / {r.eeprom_ms_p99:.2f} ms | {r.failures} of {r.transactions} "
            f"| {r.link_extra_ms:.1f} ms ({r.late_replies} late replies) |"
        )
    print(f"\nPython {sys.version.split()[0]}, {os.cpu_count()} CPUs, loopback")
    if args.json:
        Path(args.json).write_text(json.dumps([asdict(r) for r in results], indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
