"""The web configurator's cost: the stream's rate on 32 servos with the Live plots page open vs none,
and the server's CPU per page update.

Runs ``ics35 web`` (a subprocess, as a user runs it) on a simulated line of
32 servos served on a pty by another process (``python -m ics35_async.sim``,
so the server's CPU is its own), starts the live stream on all of them,
then measures phases of ``--seconds`` each in this order, ``--rounds``
times, ending with one more ``no page``::

    no page, page open, no page, traffic on, no page, page open, ...

* ``no page``: nobody is connected; the benchmark reads the newest frame's
  cycle number twice a second over HTTP;
* ``page open``: a WebSocket client takes every update the Live plots page
  gets (the browser's drawing costs the browser, not the server);
* ``traffic on``: the same, with the Traffic page's recording on (every
  transaction logged and kept), which a page asks for once it has shown the
  Traffic page.

Rate: stream cycles per second (the frame's cycle counter over wall time).
Each ``page open`` and ``traffic on`` phase is taken as a ratio against the
mean of the two ``no page`` phases either side of it, and the figure is the
median of those ratios: the real-time simulator's rate drifts by tens of
percent from one few-second phase to the next on this machine, so only
neighbours are compared.  The same ratio of each inner ``no page`` phase
against its own two ``no page`` neighbours (nothing changed between them)
is printed as the noise floor.  CPU: the server process's user + system
time (/proc, Linux), all threads; the ``page open`` phases' over their
neighbours', summed over the rounds and divided by the updates sent, is the
server's CPU per update.  The simulator runs in real time (wire-timed, 1.25 Mbit/s) unless ``--fast``,
where the stream is bound by the CPU and every cycle the server spends on
the page is a cycle the stream loses: the worst case.

    .venv/bin/python benchmarks/bench_web.py [--seconds 2] [--rounds 4] [--fast] [--json]     (about 45 s)

``--startup`` measures instead how long ``ics35 web`` takes to start (median of ``--starts``, 9 by
default, wall time of fresh processes): ``ics35 --version`` and the two imports for comparison, then
``ics35 web --no-browser`` on the built-in simulator until it prints its address and until it first
answers ``/api/status``.
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

from ics35_async.sim.launch import start_subprocess, stop_subprocess

TICK = os.sysconf("SC_CLK_TCK")
NO_PAGE, PAGE, TRAFFIC = "no page", "page open", "traffic on"


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


def startup(starts: int = 9) -> dict[str, float]:
    """Median wall seconds of fresh processes: the CLI and imports for comparison, then ``ics35 web``."""

    def wall(argv: list[str]) -> float:
        t0 = time.perf_counter()
        subprocess.run(argv, check=True, stdout=subprocess.DEVNULL)
        return time.perf_counter() - t0

    def web() -> tuple[float, float]:
        t0 = time.perf_counter()
        proc = subprocess.Popen(
            [sys.executable, "-m", "ics35_async.cli", "web", "--no-browser"],
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            text=True,
        )
        try:
            assert proc.stdout is not None
            url = proc.stdout.readline().strip()
            printed = time.perf_counter() - t0
            base, _, token = url.partition("/?token=")
            request = urllib.request.Request(base + "/api/status", headers={"cookie": f"ics35_token={token}"})
            with urllib.request.urlopen(request, timeout=10) as response:
                response.read()
            return printed, time.perf_counter() - t0
        finally:
            proc.terminate()
            proc.wait(10)

    rows: dict[str, list[float]] = {}
    for _ in range(starts):
        for name, argv in (
            ("ics35 --version", [sys.executable, "-m", "ics35_async.cli", "--version"]),
            ("import ics35_async", [sys.executable, "-c", "import ics35_async"]),
            ("import ics35_async.web", [sys.executable, "-c", "import ics35_async.web"]),
        ):
            rows.setdefault(name, []).append(wall(argv))
        printed, answered = web()
        rows.setdefault("ics35 web: address printed", []).append(printed)
        rows.setdefault("ics35 web: first answer", []).append(answered)
    return {name: statistics.median(values) for name, values in rows.items()}


def phase(server: Server, seconds: float, kind: str) -> dict[str, Any]:
    from websockets.sync.client import connect

    updates = 0
    stop = threading.Event()
    page = kind != NO_PAGE

    def watch() -> None:
        nonlocal updates
        ws_url = server.base.replace("http://", "ws://") + "/ws"
        with connect(ws_url, additional_headers=server.headers) as ws:
            ws.send(json.dumps({"traffic": kind == TRAFFIC}))
            while not stop.is_set():
                if json.loads(ws.recv(timeout=2)).get("live"):
                    updates += 1

    watcher = threading.Thread(target=watch) if page else None
    if watcher is not None:
        watcher.start()
        time.sleep(0.2)  # connected and streaming before measuring
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
    return {"kind": kind, "rate": (c1 - c0) / wall, "cpu": (cpu1 - cpu0) / wall, "updates": (u1 - u0) / wall}


def against_neighbours(phases: list[dict[str, Any]], kind: str) -> list[dict[str, float]]:
    """Each phase of ``kind`` against the mean of the ``no page`` phases right before and after it."""
    out = []
    for k, p in enumerate(phases):
        if p["kind"] != kind or k == 0 or k == len(phases) - 1:
            continue
        before, after = phases[k - 1], phases[k + 1]
        if before["kind"] != NO_PAGE or after["kind"] != NO_PAGE:
            continue
        rate = (before["rate"] + after["rate"]) / 2
        cpu = (before["cpu"] + after["cpu"]) / 2
        out.append({"ratio": p["rate"] / rate, "cpu_over": p["cpu"] - cpu, "updates": p["updates"]})
    return out


def noise_floor(phases: list[dict[str, Any]]) -> list[float]:
    """Each inner ``no page`` phase against the two ``no page`` phases nearest it on either side."""
    quiet = [p["rate"] for p in phases if p["kind"] == NO_PAGE]
    return [quiet[k] / ((quiet[k - 1] + quiet[k + 1]) / 2) for k in range(1, len(quiet) - 1)]


def run(seconds: float = 2.0, rounds: int = 4, fast: bool = False) -> dict[str, Any]:
    order = [NO_PAGE, PAGE, NO_PAGE, TRAFFIC] * rounds + [NO_PAGE]
    server = Server(fast)
    phases: list[dict[str, Any]] = []
    try:
        server.call("/api/live/start", {"ids": list(range(32)), "free_ics35": True})
        time.sleep(1.0)
        for kind in order:
            phases.append(phase(server, seconds, kind))
    finally:
        server.close()
    page, traffic = against_neighbours(phases, PAGE), against_neighbours(phases, TRAFFIC)
    noise = noise_floor(phases)
    ups = statistics.median(r["updates"] for r in page)
    # Over all page phases together: /proc counts CPU in 10 ms ticks, a tenth of a page phase's difference.
    updates = sum(r["updates"] for r in page)
    per_update = sum(r["cpu_over"] for r in page) / updates if updates else None
    return {
        "mode": "fast" if fast else "realtime",
        "phase_seconds": seconds,
        "rounds": rounds,
        "no_page_cycles_per_s": statistics.median(p["rate"] for p in phases if p["kind"] == NO_PAGE),
        "page_vs_no_page": statistics.median(r["ratio"] for r in page),
        "page_vs_no_page_each": [r["ratio"] for r in page],
        "traffic_vs_no_page": statistics.median(r["ratio"] for r in traffic),
        "traffic_vs_no_page_each": [r["ratio"] for r in traffic],
        "noise_floor_each": noise,
        "page_updates_per_s": ups,
        "server_cpu_no_page": statistics.median(p["cpu"] for p in phases if p["kind"] == NO_PAGE),
        "server_cpu_page": statistics.median(p["cpu"] for p in phases if p["kind"] == PAGE),
        "server_cpu_ms_per_update": None if per_update is None else per_update * 1000,
        "phases": phases,
    }


def _spread(values: list[float]) -> str:
    return f"{min(values):.0%}..{max(values):.0%}" if values else "-"


def print_table(r: dict[str, Any]) -> None:
    mode = "fast-mode (CPU-bound)" if r["mode"] == "fast" else "real-time, 1.25 Mbit/s"
    rounds = f"{r['rounds']} rounds of {r['phase_seconds']:g} s"
    print(f"\n10. Web configurator: 32 streaming servos, {mode} simulator on a pty, {rounds}")
    print("   each phase against the mean of the 'no page' phases either side of it; medians (spread)")
    print(f"  stream rate, no page       {r['no_page_cycles_per_s']:8.1f} cycles/s")
    each = r["page_vs_no_page_each"]
    print(f"  stream rate, page open     {r['page_vs_no_page']:8.1%} of no page   ({_spread(each)})")
    each = r["traffic_vs_no_page_each"]
    print(f"  stream rate, traffic on    {r['traffic_vs_no_page']:8.1%} of no page   ({_spread(each)})")
    noise = r["noise_floor_each"]
    if noise:
        print(f"  noise: no page vs no page  {statistics.median(noise):8.1%}              ({_spread(noise)})")
    print(f"  page updates               {r['page_updates_per_s']:8.1f} /s")
    print(f"  server CPU, no page        {r['server_cpu_no_page']:8.1%} of a core")
    print(f"  server CPU, page open      {r['server_cpu_page']:8.1%} of a core")
    per = r["server_cpu_ms_per_update"]
    if per is not None:
        print(f"  server CPU per update      {per:8.2f} ms")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=2.0)
    parser.add_argument("--rounds", type=int, default=4)
    parser.add_argument("--fast", action="store_true", help="fast-mode simulator: the stream is CPU-bound")
    parser.add_argument("--json", action="store_true", help="print the figures as JSON too")
    parser.add_argument("--startup", action="store_true", help="measure how long ics35 web takes to start instead")
    parser.add_argument("--starts", type=int, default=9, help="with --startup: fresh processes per row")
    args = parser.parse_args()
    if args.startup:
        print(f"ics35 web start-up: wall time of fresh processes, median of {args.starts}")
        for name, seconds in startup(args.starts).items():
            print(f"  {name:30} {seconds * 1e3:6.0f} ms")
        return
    result = run(args.seconds, args.rounds, args.fast)
    print_table(result)
    if args.json:
        print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
