"""Start-up time of the ``teamkf`` command: ``--version``, ``--help`` and ``COMMAND --help`` (wall and CPU), median of N runs.

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python benchmarks/bench_startup.py [--runs 10] [--json] [--importtime 12]

Reports the median wall time and CPU time (user + system of the child) of each command, beside
``python -c pass`` and ``python -c "import numpy"`` measured in the same run (the floor every command pays;
``--help`` and ``--version`` import no numpy). ``--importtime N`` adds the N largest cumulative imports of
``python -X importtime -m teamkf --help`` (microseconds, one run) and how many modules it imports.
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
from typing import Any


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


def _importtime(argv: list[str], top: int) -> dict[str, Any]:
    """The ``top`` largest cumulative import times (microseconds) that ``-X importtime`` reports, and the module count."""
    res = subprocess.run(argv, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env={**os.environ, "TEAMKF_PROGRESS": "0"})
    rows = []
    for line in res.stderr.splitlines():
        parts = line.removeprefix("import time:").split("|")
        if len(parts) == 3 and parts[1].strip().isdigit():
            rows.append((parts[2].strip(), int(parts[1])))
    largest = sorted(rows, key=lambda r: -r[1])[:top]
    return {"modules": len(rows), "largest_cumulative_us": dict(largest)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=10)
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--importtime", type=int, default=0, metavar="N", help="also list the N largest imports of --help (python -X importtime)")
    args = ap.parse_args()
    py = sys.executable
    cases = {
        "python -c pass": [py, "-c", "pass"],
        "python -c 'import numpy'": [py, "-c", "import numpy"],
        "teamkf --version": [py, "-m", "teamkf", "--version"],
        "teamkf --help": [py, "-m", "teamkf", "--help"],
        "teamkf evaluate --help": [py, "-m", "teamkf", "evaluate", "--help"],
        "teamkf sweep --help": [py, "-m", "teamkf", "sweep", "--help"],
    }
    out: dict[str, Any] = {name: _time(argv, args.runs) for name, argv in cases.items()}
    if args.importtime:
        out["importtime --help"] = _importtime([py, "-X", "importtime", "-m", "teamkf", "--help"], args.importtime)
    if args.json:
        print(json.dumps(out, indent=1))
        return
    print(f"{'command':28s} {'wall (median)':>14s} {'CPU (median)':>13s}   ({args.runs} runs, load {os.getloadavg()[0]:.1f})")
    for name, r in out.items():
        if name in cases:
            print(f"{name:28s} {r['wall_median_s']:13.3f}s {r['cpu_median_s']:12.3f}s")
    if args.importtime:
        it = out["importtime --help"]
        print(f"\npython -X importtime -m teamkf --help: {it['modules']} modules imported; the largest (cumulative, microseconds):")
        for name, us in it["largest_cumulative_us"].items():
            print(f"  {us:8d}  {name}")


if __name__ == "__main__":
    main()
