"""What a user waits for outside the hot path: import time, ``ics35 --version``, ``ics35 scan``, ``ics35 set-id``.

Each figure is the wall time of a fresh subprocess, the best of ``tries``
(the least disturbed by other work on the machine):

* ``import ics35_async`` (``python -c``), and the bare interpreter start
  (``python -c pass``) so the import's own share shows;
* ``ics35 --version``;
* ``ics35 --port PTY scan`` against the pty simulator (real-time mode) with
  3 servos (IDs 1, 7, 20), every baud rate x every ID (3 x 32), the CLI's
  defaults (EEPROM read of each servo found);
* ``ics35 --port PTY set-id NEW --yes`` against the pty simulator with one
  servo, renumbering it back and forth.

The CLI rows include the CLI's own start-up (about the ``--version`` figure).

    .venv/bin/python benchmarks/bench_tools.py [--tries 3] [--sections imports,scan]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from bench_common import progress

from ics35_async.sim import serving

SCAN_IDS = "1,7,20"
SET_ID_SERVO = 3


def ics35() -> list[str]:
    """The console script next to this interpreter (the venv's), else the module."""
    script = Path(sys.executable).with_name("ics35")
    return [str(script)] if script.exists() else [sys.executable, "-m", "ics35_async.cli"]


def timed(argv: list[str], expect: int = 0) -> float:
    """Wall seconds of one subprocess; a failing command is an error, not a figure."""
    t0 = time.perf_counter()
    done = subprocess.run(argv, capture_output=True, text=True, timeout=120)
    elapsed = time.perf_counter() - t0
    if done.returncode != expect:
        raise RuntimeError(f"{' '.join(argv)} exited {done.returncode}: {done.stderr.strip()[-500:]}")
    return elapsed


def best(argv: list[str], tries: int) -> dict[str, Any]:
    times = [timed(argv) for _ in range(tries)]
    return {"best_s": min(times), "all_s": times}


def imports(tries: int) -> dict[str, Any]:
    python = sys.executable
    timed([python, "-c", "import ics35_async"])  # warm the file cache and the bytecode
    bare = best([python, "-c", "pass"], tries)
    package = best([python, "-c", "import ics35_async"], tries)
    version = best([*ics35(), "--version"], tries)
    return {
        "python_startup": bare,
        "import_ics35_async": package,
        "import_ics35_async_net_s": package["best_s"] - bare["best_s"],
        "ics35_version": version,
    }


def scan(tries: int) -> dict[str, Any]:
    with serving(["--ids", SCAN_IDS, "--realtime"]) as path:
        argv = [*ics35(), "--port", path, "scan", "--json"]
        times = []
        found = None
        for _ in range(tries):
            t0 = time.perf_counter()
            done = subprocess.run(argv, capture_output=True, text=True, timeout=120)
            times.append(time.perf_counter() - t0)
            if done.returncode != 0:
                raise RuntimeError(f"scan exited {done.returncode}: {done.stderr.strip()[-500:]}")
            found = len(json.loads(done.stdout)["servos"])
    return {"servos": SCAN_IDS, "bauds": 3, "ids": 32, "entries_found": found, "best_s": min(times), "all_s": times}


def set_id(tries: int) -> dict[str, Any]:
    with serving(["--ids", str(SET_ID_SERVO), "--realtime"]) as path:
        times = []
        for k in range(tries):
            new = SET_ID_SERVO + 1 if k % 2 == 0 else SET_ID_SERVO
            times.append(timed([*ics35(), "--port", path, "set-id", str(new), "--yes"]))
    return {"best_s": min(times), "all_s": times}


PARTS = {"imports": imports, "scan": scan, "set_id": set_id}


def run(tries: int = 3, parts: tuple[str, ...] = tuple(PARTS)) -> dict[str, Any]:
    out: dict[str, Any] = {"tries": tries}
    for name in parts:
        progress(f"tools: {name}")
        out[name] = PARTS[name](tries)
    return out


def print_startup(r: dict[str, Any]) -> None:
    im = r["imports"]
    print(f"\nC. Start-up (wall time of a fresh subprocess, best of {r['tries']})")
    print(
        f"  import ics35_async            {im['import_ics35_async']['best_s'] * 1e3:7.0f} ms  "
        f"({im['import_ics35_async_net_s'] * 1e3:.0f} ms over a bare interpreter's "
        f"{im['python_startup']['best_s'] * 1e3:.0f} ms)"
    )
    print(f"  ics35 --version               {im['ics35_version']['best_s'] * 1e3:7.0f} ms")


def print_line_tools(r: dict[str, Any]) -> None:
    sc, si = r["scan"], r["set_id"]
    print(f"\nD. Line tools on the real-time pty simulator (wall time of the command, best of {r['tries']})")
    print(
        f"  ics35 scan (3 rates x 32 IDs) {sc['best_s']:7.2f} s   "
        f"(servos {sc['servos']}; {sc['entries_found']} entries listed)"
    )
    print(f"  ics35 set-id (one servo)      {si['best_s']:7.2f} s")


def print_table(r: dict[str, Any]) -> None:
    if "imports" in r:
        print_startup(r)
    if "scan" in r and "set_id" in r:
        print_line_tools(r)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tries", type=int, default=3)
    parser.add_argument("--sections", default=",".join(PARTS), help=f"comma-separated subset of {','.join(PARTS)}")
    parser.add_argument("--json", action="store_true", help="print the figures as JSON, not the table")
    args = parser.parse_args()
    result = run(args.tries, tuple(s.strip() for s in args.sections.split(",") if s.strip()))
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print_table(result)


if __name__ == "__main__":
    main()
