"""The web configurator's cost: the stream's rate on 32 servos with the Live plots page open vs none,
and the server's CPU per page update.

Runs ``ics35 web`` (a subprocess, as a user runs it) on a simulated line of
32 servos served on a pty by another process (``python -m ics35_async.sim``,
so the server's CPU is its own), starts the live stream on all of them,
then alternates three phases of ``--seconds`` each, ``--rounds`` times:

* ``no page``: nobody is connected; the benchmark reads the newest frame's
  cycle number twice a second over HTTP;
* ``page open``: a WebSocket client takes every update the Live plots page
  gets (the browser's drawing costs the browser, not the server);
* ``traffic on``: the same, with the Traffic page's recording on (every
  transaction logged and kept), which a page asks for once it has shown the
  Traffic page.

Rate: stream cycles per second (the frame's cycle counter over wall time).
CPU: the server process's user + system time (/proc, Linux), all threads;
the difference between ``page open`` and ``no page`` over the updates sent
is the server's CPU per update.  Medians over rounds; the ratios are taken
against the ``no page`` phases of the same run.  The simulator runs in real
time (wire-timed, 1.25 Mbit/s) unless ``--fast``, where the stream is bound
by the CPU and every cycle the server spends on the page is a cycle the
stream loses: the worst case.

    .venv/bin/python benchmarks/bench_web.py [--seconds 3] [--rounds 3] [--fast]     (about 35 s)
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import threading
import time
import urllib.request
from typing import Any

from websockets.sync.client import connect

from ics35_async.sim.launch import start_subprocess, stop_subprocess

TICK = os.sysconf("SC_CLK_TCK")


def cpu_seconds(pid: int) -> float:
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICK  # utime, stime


class Server:
    def __init__(self, fast: bool) -> None:
        sim_args = ["--ids", "0-31", "--baud", "1250000", "--fast" if fast else "--realtime"]
        self.sim, port = start_subprocess(sim_args, quiet=True)
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "ics35_async.cli", "web", "--no-browser", "--port", port, "--baud", "1250000"],
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            text=True,
        )
        assert self.proc.stdout is not None
        url = self.proc.stdout.readline().strip()
        self.base, _, self.token = url.partition("/?token=")
        self.headers = {"cookie": f"ics35_token={self.token}", "origin": self.base}

    def call(self, path: str, data: Any = None) -> Any:
        body = None if data is None else json.dumps(data).encode()
        headers = {**self.headers, "content-type": "application/json"}
        request = urllib.request.Request(self.base + path, data=body, headers=headers)
        with urllib.request.urlopen(request, timeout=10) as response:
            return json.loads(response.read())

    def cycle(self) -> int:
        frame = self.call("/api/live")
        return int(frame["cycle"]) if frame else 0

    def close(self) -> None:
        self.proc.terminate()
        self.proc.wait(10)
        stop_subprocess(self.sim)


def phase(server: Server, seconds: float, page: bool, traffic: bool = False) -> dict[str, float]:
    updates = 0
    stop = threading.Event()

    def watch() -> None:
        nonlocal updates
        ws_url = server.base.replace("http://", "ws://") + "/ws"
        with connect(ws_url, additional_headers=server.headers) as ws:
            ws.send(json.dumps({"traffic": traffic}))
            while not stop.is_set():
                if json.loads(ws.recv(timeout=2)).get("live"):
                    updates += 1

    watcher = threading.Thread(target=watch) if page else None
    if watcher is not None:
        watcher.start()
        time.sleep(0.5)  # connected and streaming before measuring
    c0, t0, cpu0, u0 = server.cycle(), time.perf_counter(), cpu_seconds(server.proc.pid), updates
    while time.perf_counter() - t0 < seconds:
        time.sleep(0.5)
        if not page:
            server.cycle()
    c1, t1, cpu1, u1 = server.cycle(), time.perf_counter(), cpu_seconds(server.proc.pid), updates
    stop.set()
    if watcher is not None:
        watcher.join(5)
    wall = t1 - t0
    return {"rate": (c1 - c0) / wall, "cpu": (cpu1 - cpu0) / wall, "updates": (u1 - u0) / wall}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--fast", action="store_true", help="fast-mode simulator: the stream is CPU-bound")
    args = parser.parse_args()
    server = Server(args.fast)
    try:
        server.call("/api/live/start", {"ids": list(range(32))})
        time.sleep(1.0)
        none, open_, traced = [], [], []
        for _ in range(args.rounds):
            none.append(phase(server, args.seconds, page=False))
            open_.append(phase(server, args.seconds, page=True))
            traced.append(phase(server, args.seconds, page=True, traffic=True))
    finally:
        server.close()

    def med(rows: list[dict[str, float]], key: str) -> float:
        return statistics.median(r[key] for r in rows)

    rate_none, rate_open = med(none, "rate"), med(open_, "rate")
    cpu_none, cpu_open, ups = med(none, "cpu"), med(open_, "cpu"), med(open_, "updates")
    mode = "fast-mode (CPU-bound)" if args.fast else "real-time, 1.25 Mbit/s"
    print(f"32 streaming servos, {mode} simulator on a pty; medians of {args.rounds} rounds of {args.seconds:g} s")
    print(f"  stream rate, no page      {rate_none:8.1f} cycles/s")
    print(f"  stream rate, page open    {rate_open:8.1f} cycles/s   ({rate_open / rate_none:.1%} of no page)")
    rate_traced = med(traced, "rate")
    print(f"  stream rate, traffic on   {rate_traced:8.1f} cycles/s   ({rate_traced / rate_none:.1%} of no page)")
    print(f"  page updates              {ups:8.1f} /s")
    print(f"  server CPU, no page       {cpu_none:8.1%} of a core")
    print(f"  server CPU, page open     {cpu_open:8.1%} of a core")
    if ups:
        print(f"  server CPU per update     {(cpu_open - cpu_none) / ups * 1000:8.2f} ms")


if __name__ == "__main__":
    main()
