"""Per-transaction latency through a line on another machine: direct pty, TCP bridge (socket://), RFC 2217.

The far end is the simulator's pty (``python -m ics35_async.sim``, real
time: each reply takes its wire time at 115200 baud, about 0.6 ms for a
stretch read).  In front of it, on loopback, sit the test suite's bridges
(tests/support/links.py): a raw TCP forwarder (what ser2net's raw mode or
socat do, TCP_NODELAY on both ends) and pyserial's own RFC 2217 server side.
Each path runs N stretch reads one after another (IDs 1-3 in turn), timing
each ``bus.request`` from call to result: median and 99th percentile.

Run from the project root: ``.venv/bin/python -m benchmarks.bench_links [--requests 1000] [--json]``.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import time
from typing import Any

from ics35_async import open_bus, protocol
from ics35_async.protocol import Param
from ics35_async.sim import serving
from tests.support.links import Rfc2217Bridge, TcpBridge


async def latencies(port: str, driver: str, requests: int) -> dict[str, Any]:
    times: list[float] = []
    failed = 0
    async with open_bus(port, driver=driver) as bus:
        for i in range(50):  # warm up (first connection, caches)
            await bus.request(protocol.ReadParam(1 + i % 3, Param.STRETCH), retries=2)
        for i in range(requests):
            start = time.perf_counter()
            try:
                await bus.request(protocol.ReadParam(1 + i % 3, Param.STRETCH), retries=0)
            except Exception:
                failed += 1
                continue
            times.append(time.perf_counter() - start)
    times.sort()
    return {
        "median_ms": round(times[len(times) // 2] * 1e3, 3),
        "p99_ms": round(times[min(len(times) - 1, int(len(times) * 0.99))] * 1e3, 3),
        "failed": failed,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--requests", type=int, default=1000)
    parser.add_argument("--drivers", default="asyncio,thread,anyio")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    results: dict[str, dict[str, Any]] = {}
    with serving(["--ids", "1-3"]) as pty:
        for driver in args.drivers.split(","):
            results[f"direct pty, {driver}"] = asyncio.run(latencies(pty, driver, args.requests))
            for name, bridge_class in (("TCP bridge (socket://)", TcpBridge), ("RFC 2217", Rfc2217Bridge)):
                with bridge_class(pty) as bridge:
                    results[f"{name}, {driver}"] = asyncio.run(latencies(bridge.url, driver, args.requests))
    if args.json:
        print(json.dumps(results, indent=2))
        return
    print(f"{'path, driver':40} {'median ms':>10} {'p99 ms':>10} {'failed':>7}")
    for name, r in results.items():
        print(f"{name:40} {r['median_ms']:>10.3f} {r['p99_ms']:>10.3f} {r['failed']:>7}")


if __name__ == "__main__":
    main()
