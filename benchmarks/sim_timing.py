"""How accurately the real-time simulator keeps the wire model, and how fast the fast mode is.

Prints, for each way of waiting or delivering, the lateness (arrival minus
the modelled wire time) in microseconds: median, 99th percentile, maximum.
Baselines measured in the same run: plain ``time.sleep``, ``asyncio.sleep``,
and the pty server in fast mode (the pty's own latency).

    .venv/bin/python benchmarks/sim_timing.py [--n 2000] [--quick]
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import sys
import threading
import time
from collections.abc import Callable

import serial

from ics35_async.protocol import Position, wire_time
from ics35_async.sim import Deliverer, VirtualLine, lower_timer_slack, start_subprocess, stop_subprocess, wait_until
from ics35_async.transports import DevicePort, open_port


def summary(label: str, lateness: list[float]) -> str:
    us = sorted(x * 1e6 for x in lateness)
    p99 = us[min(len(us) - 1, int(len(us) * 0.99))]
    return f"{label:<56} median {statistics.median(us):8.1f}  p99 {p99:8.1f}  max {us[-1]:8.1f}  (n={len(us)})"


def bench_waits(n: int, delay: float) -> None:
    print(f"\n-- waiting {delay * 1e6:.0f} us (overshoot, us)")

    def measure(wait: Callable[[float], None]) -> list[float]:
        out = []
        for _ in range(n):
            start = time.perf_counter()
            wait(start + delay)
            out.append(time.perf_counter() - start - delay)
        return out

    def in_thread(slack: bool, fn: Callable[[float], None]) -> list[float]:
        result: list[float] = []

        def run() -> None:
            if slack:
                lower_timer_slack()
            result.extend(measure(fn))

        thread = threading.Thread(target=run)
        thread.start()
        thread.join()
        return result

    def sleep_to(deadline: float) -> None:
        time.sleep(max(0.0, deadline - time.perf_counter()))

    print(summary("time.sleep, default timer slack (baseline)", in_thread(False, sleep_to)))
    print(summary("time.sleep, 1 ns timer slack", in_thread(True, sleep_to)))
    print(summary("wait_until (sleep, then spin 250 us), 1 ns slack", in_thread(True, wait_until)))

    async def loop_sleep() -> list[float]:
        out = []
        for _ in range(n):
            start = time.perf_counter()
            await asyncio.sleep(delay)
            out.append(time.perf_counter() - start - delay)
        return out

    print(summary("asyncio.sleep in an event loop (baseline)", asyncio.run(loop_sleep())))


def bench_deliverer(n: int) -> None:
    print("\n-- Deliverer thread: sink call time minus scheduled time (us)")
    deliverer = Deliverer()
    lateness: list[float] = []
    done = threading.Event()

    def sink_for(when: float) -> Callable[[bytes], None]:
        def sink(_: bytes) -> None:
            lateness.append(time.perf_counter() - when)
            if len(lateness) == n:
                done.set()

        return sink

    for _ in range(n):
        when = time.perf_counter() + 0.0007
        deliverer.schedule(when, b"x", sink_for(when))
        time.sleep(0.001)
    done.wait(10)
    deliverer.close()
    print(summary("host.deliver call, chunks 0.7 ms ahead", lateness))


class _TimedHost:
    def __init__(self) -> None:
        self.arrivals: list[float] = []
        self.cond = threading.Condition()

    def deliver(self, data: bytes) -> None:
        stamp = time.perf_counter()
        with self.cond:
            self.arrivals.append(stamp)
            self.cond.notify_all()

    def replied(self) -> bool:
        """The echo and the reply have come (two deliveries)."""
        return len(self.arrivals) >= 2

    def lost(self, exc: Exception | None) -> None:
        pass


def bench_in_process(n: int) -> None:
    print("\n-- VirtualLine real-time, in process: reply arrival minus modelled reply time (us)")
    for baud in (115200, 1250000):
        bus = VirtualLine([1], baudrate=baud, realtime=True)
        host = _TimedHost()
        bus.connect(host, baud)
        lateness = []
        for i in range(n):
            bus.write(Position(1, 7000 + i % 1000, baudrate=baud).tx)
            with host.cond:
                host.cond.wait_for(host.replied, 5)
                reply_at = host.arrivals[1]
                host.arrivals.clear()
            modelled = bus.log[-1].reply_time
            assert modelled is not None
            lateness.append(reply_at - (bus.epoch + modelled))
        bus.close()
        print(summary(f"host.deliver, position @ {baud}", lateness))


async def _asyncio_run(n: int, baud: int, realtime: bool) -> list[float]:
    name = f"bench-{baud}-{realtime}"
    port = open_port(f"sim://{name}?ids=1&baud={baud}&realtime={int(realtime)}", baud)
    assert isinstance(port, DevicePort)
    from ics35_async.sim import named

    bus = named(name)
    loop = asyncio.get_running_loop()
    got = bytearray()
    want = 0
    done: asyncio.Future[float] = loop.create_future()

    def readable() -> None:  # as the asyncio driver reads an in-process device: on the loop, told by on_input
        got.extend(port.read())
        if len(got) >= want and not done.done():
            done.set_result(time.perf_counter())

    def told() -> None:  # (from the device's thread)
        loop.call_soon_threadsafe(readable)

    port.on_input = told
    lateness = []
    for i in range(n):
        got.clear()
        want = 6
        done = loop.create_future()
        written = time.perf_counter()
        port.write(Position(1, 7000 + i % 1000, baudrate=baud).tx)
        arrived = await done
        if realtime:
            modelled = bus.log[-1].reply_time
            assert modelled is not None
            lateness.append(arrived - (bus.epoch + modelled))
        else:
            lateness.append(arrived - written)
    port.close()
    bus.close()
    return lateness


def bench_asyncio(n: int) -> None:
    print("\n-- through open_port + asyncio (a DevicePort read on the loop): reply minus modelled time (us)")
    for baud in (115200, 1250000):
        print(
            summary(
                f"fast @ {baud}: write -> reply (baseline, no model)",
                asyncio.run(_asyncio_run(n, baud, False)),
            )
        )
        print(summary(f"real-time @ {baud}: reply minus modelled time", asyncio.run(_asyncio_run(n, baud, True))))


def bench_pty(n: int) -> None:
    print("\n-- pty server, blocking pyserial client: (write -> whole reply) minus modelled wire time (us)")
    command = Position(1, 7500, baudrate=115200)
    for baud in (115200, 1250000):
        modelled = wire_time(6, baud) + 100e-6
        for realtime in (False, True):
            args = ["--ids", "1", "--baud", str(baud)] + (["--realtime"] if realtime else ["--fast"])
            proc, path = start_subprocess(args)
            try:
                port = serial.Serial(path, baud, parity=serial.PARITY_EVEN, timeout=2)
                lateness = []
                for _ in range(n):
                    start = time.perf_counter()
                    port.write(command.tx)
                    got = port.read(6)
                    elapsed = time.perf_counter() - start
                    assert len(got) == 6, got
                    lateness.append(elapsed - (modelled if realtime else 0.0))
                port.close()
            finally:
                stop_subprocess(proc)
            what = (
                f"real-time @ {baud}: minus {modelled * 1e6:.0f} us"
                if realtime
                else f"fast @ {baud} (baseline: pty latency)"
            )
            print(summary(what, lateness))


def bench_throughput(n: int) -> None:
    print("\n-- fast mode throughput (VirtualLine.process, position commands to 32 servos)")
    bus = VirtualLine(log_size=1000)
    commands = [Position(i, 7000 + i, baudrate=115200).tx for i in range(32)]
    start = time.perf_counter()
    for i in range(n):
        bus.process(commands[i % 32])
    elapsed = time.perf_counter() - start
    print(f"{n / elapsed:,.0f} transactions/s ({elapsed / n * 1e6:.1f} us each)")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--n", type=int, default=2000, help="samples per measurement")
    parser.add_argument("--quick", action="store_true", help="200 samples per measurement")
    args = parser.parse_args()
    n = 200 if args.quick else args.n
    print(f"Python {sys.version.split()[0]} on {sys.platform}; {n} samples per line")
    bench_waits(n, 300e-6)
    bench_deliverer(n)
    bench_in_process(n)
    bench_asyncio(n)
    bench_pty(n)
    bench_throughput(max(n * 50, 20000))
    return 0


if __name__ == "__main__":
    sys.exit(main())
