"""A peer: rcb4's ``ICSServoController`` against the same pty server, sequential transactions.

rcb4 (PyPI) is installed into a throwaway virtualenv under the system's
temporary directory (reused by later runs), never into ours, and driven
from a child process with that venv's interpreter.  Its
``open_connection()`` only looks for Kondo's USB adapter (VID 0x165C, PID
0x0008), so the child opens the pty itself exactly as rcb4 opens the
adapter (``serial.Serial(port, baudrate, timeout=..., parity=EVEN)``) and
assigns it to ``controller.ics``; everything after that is rcb4's own code
(``set_angle(7500, servo_id=k)``, which writes 3 bytes and reads 6).

In the same run, against the same fast-mode server: the raw blocking
pyserial loop (the baseline) and our ``servo.set_position`` loop.

    .venv/bin/python benchmarks/bench_peer.py [--runs 3] [--duration 1.0]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

from bench_common import median, progress, pty_sim
from bench_overhead import api_sequential, raw_loop

VENV = Path(tempfile.gettempdir()) / "ics35-bench-rcb4-venv"

CHILD = r"""
import json, sys, time
import serial
from rcb4.ics import ICSServoController

path, duration = sys.argv[1], float(sys.argv[2])
controller = ICSServoController(baudrate=115200, timeout=0.1)
parity = "even"
try:
    # What rcb4's _open_connection_pyserial does once it has found the adapter.
    controller.ics = serial.Serial(path, 115200, timeout=controller.timeout, parity=serial.PARITY_EVEN)
    controller.set_angle(7500, servo_id=0)
except Exception as exc:  # a pty has no parity: see ics35_async.sim.pty_port
    parity = f"none (even failed on the pty: {exc!r})"
    if controller.ics is not None:
        controller.ics.close()
    controller.ics = serial.Serial(path, 115200, timeout=controller.timeout, parity=serial.PARITY_NONE)
for k in range(32):
    controller.set_angle(7500, servo_id=k)
n = 0
wall0, cpu0 = time.perf_counter(), time.process_time()
while time.perf_counter() - wall0 < duration:
    for k in range(32):
        controller.set_angle(7500, servo_id=k)
    n += 32
wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
controller.ics.close()
import importlib.metadata as md
print(json.dumps({"tx_per_s": n / wall, "cpu_us_per_tx": cpu / n * 1e6, "parity": parity,
                  "rcb4_version": md.version("rcb4")}))
"""


def ensure_rcb4() -> tuple[Path | None, str]:
    """The venv's python with rcb4 importable, or None and why not."""
    python = VENV / "bin" / "python"
    check = [str(python), "-c", "import rcb4.ics"]
    if python.exists() and subprocess.run(check, capture_output=True, timeout=120).returncode == 0:
        return python, "reused"
    try:
        progress(f"peer: installing rcb4 into {VENV}")
        subprocess.run(
            [sys.executable, "-m", "venv", "--clear", str(VENV)], check=True, capture_output=True, timeout=300
        )
        pip = subprocess.run(
            [str(python), "-m", "pip", "install", "--quiet", "--disable-pip-version-check", "rcb4"],
            capture_output=True,
            text=True,
            timeout=600,
        )
        if pip.returncode != 0:
            return None, f"pip install rcb4 failed: {pip.stderr.strip()[-500:]}"
        imp = subprocess.run(check, capture_output=True, text=True, timeout=120)
        if imp.returncode != 0:
            return None, f"rcb4 installed but does not import: {imp.stderr.strip()[-500:]}"
    except (OSError, subprocess.SubprocessError) as exc:
        return None, f"could not make a venv for rcb4: {exc}"
    return python, "installed"


def run(runs: int = 3, duration: float = 1.0) -> dict[str, Any]:
    python, how = ensure_rcb4()
    out: dict[str, Any] = {"peer": "rcb4.ics.ICSServoController.set_angle", "venv": str(VENV), "runs": runs}
    if python is None:
        out["status"] = f"not measured: {how}"
        return out
    raw: list[float] = []
    ours: list[float] = []
    peer: list[dict[str, Any]] = []
    errors: list[str] = []
    with pty_sim("--fast") as path:
        for r in range(runs):
            progress(f"peer: run {r + 1}/{runs}")
            before = raw_loop(path, duration / 2)["tx_per_s"]
            ours.append(api_sequential(path, "asyncio", "direct", duration / 2)["tx_per_s"])
            child = subprocess.run(
                [str(python), "-c", CHILD, path, str(duration)],
                capture_output=True,
                text=True,
                timeout=120,
                env={**os.environ, "PYTHONPATH": ""},
            )
            after = raw_loop(path, duration / 2)["tx_per_s"]
            raw.append((before + after) / 2)
            if child.returncode != 0:
                errors.append(child.stderr.strip()[-500:])
                continue
            peer.append(json.loads(child.stdout.strip().splitlines()[-1]))
    if not peer:
        out["status"] = f"installed ({how}) but could not talk to the pty: {errors[-1] if errors else '?'}"
        return out
    ratios = [p["tx_per_s"] / b for p, b in zip(peer, raw, strict=False)]
    out.update(
        {
            "status": f"measured (venv {how})",
            "rcb4_version": peer[0]["rcb4_version"],
            "parity_used": peer[0]["parity"],
            "raw_tx_per_s": median(raw),
            "ours_sequential_tx_per_s": median(ours),
            "peer_tx_per_s": median([p["tx_per_s"] for p in peer]),
            "peer_cpu_us_per_tx": median([p["cpu_us_per_tx"] for p in peer]),
            "peer_vs_raw": median(ratios),
            "ours_vs_peer": median([o / p["tx_per_s"] for o, p in zip(ours, peer, strict=False)]),
            "errors": errors,
        }
    )
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--duration", type=float, default=1.0)
    args = parser.parse_args()
    print(json.dumps(run(args.runs, args.duration), indent=2))


if __name__ == "__main__":
    main()
