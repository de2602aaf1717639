"""Start-up time of the ``teamkf`` command: ``--version`` and ``--help`` (wall and CPU), median of N runs.

    python benchmarks/bench_startup.py [--runs 10] [--json]

Reports the median wall time and CPU time (user + system of the child) of each command, beside
``python -c pass`` and ``python -c "import numpy"`` measured in the same run (the floor every command pays).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import time


def _time(argv: list[str], runs: int) -> dict[str, float]:
    walls, cpus = [], []
    for _ in range(runs):
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        subprocess.run(argv, check=True, stdout=subprocess.DEVNULL, env={**os.environ, "TEAMKF_PROGRESS": "0"})
        walls.append(time.perf_counter() - t0)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpus.append((after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime))
    return {"wall_median_s": statistics.median(walls), "cpu_median_s": statistics.median(cpus)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=10)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    py = sys.executable
    cases = {
        "python -c pass": [py, "-c", "pass"],
        "python -c 'import numpy'": [py, "-c", "import numpy"],
        "teamkf --version": [py, "-m", "teamkf", "--version"],
        "teamkf --help": [py, "-m", "teamkf", "--help"],
    }
    out = {name: _time(argv, args.runs) for name, argv in cases.items()}
    if args.json:
        print(json.dumps(out, indent=1))
        return
    print(f"{'command':28s} {'wall (median)':>14s} {'CPU (median)':>13s}   ({args.runs} runs, load {os.getloadavg()[0]:.1f})")
    for name, r in out.items():
        print(f"{name:28s} {r['wall_median_s']:13.3f}s {r['cpu_median_s']:12.3f}s")


if __name__ == "__main__":
    main()
