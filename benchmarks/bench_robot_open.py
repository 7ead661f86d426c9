"""What learning a robot's starting pose costs: opening a robot and reading its first pose, ICS 3.5 vs ICS 3.6.

Over the pty simulator in real time (``ics35 sim``), a one-line robot of
``--joints`` joints is opened (``check_limits=False``) and its first pose
read, ``--runs`` times with ICS 3.5 servos and as often with ICS 3.6 ones,
alternating.  An ICS 3.6 joint is read with its position read; an ICS 3.5
joint is probed first (two silences, a parameter read between) and then
read by freeing it.  Reported: the median seconds of each and their ratio.

    .venv/bin/python benchmarks/bench_robot_open.py [--joints 17] [--runs 3]
"""

from __future__ import annotations

import argparse
import statistics
import time
from typing import Any

import anyio

from ics35_async import open_robot
from ics35_async.sim import serving


def description(port: str, joints: int) -> dict[str, Any]:
    return {
        "lines": {"main": {"port": port}},
        "joints": {f"j{i}": {"line": "main", "id": i} for i in range(1, joints + 1)},
    }


async def open_and_read(port: str, joints: int) -> float:
    began = time.perf_counter()
    async with open_robot(description(port, joints), check_limits=False) as robot:
        await robot.read_pose()
        return time.perf_counter() - began


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--joints", type=int, default=17)
    parser.add_argument("--runs", type=int, default=3)
    args = parser.parse_args()
    ids = f"1-{args.joints}"
    times: dict[str, list[float]] = {"ICS 3.5": [], "ICS 3.6": []}
    with serving(["--ids", ids]) as old, serving(["--ids", ids, "--ics36", ids]) as new:
        for _ in range(args.runs):
            times["ICS 3.5"].append(anyio.run(open_and_read, old, args.joints))
            times["ICS 3.6"].append(anyio.run(open_and_read, new, args.joints))
    median = {kind: statistics.median(values) for kind, values in times.items()}
    for kind, seconds in median.items():
        print(f"{kind}: open + first pose of {args.joints} joints: {seconds:.3f} s (median of {args.runs})")
    print(f"ratio ICS 3.5 / ICS 3.6: {median['ICS 3.5'] / median['ICS 3.6']:.1f}")


if __name__ == "__main__":
    main()
