"""Throughput of a 40-point sweep: serial vs a Dask LocalCluster with 2 workers, as a ratio.

    PYTHONPATH=src python3 benchmarks/bench_sweep.py                 # needs the dask extra
    PYTHONPATH=src python3 benchmarks/bench_sweep.py --workers 4 --repeat 3 --json
    PYTHONPATH=src python3 benchmarks/bench_sweep.py --runs 400       # longer points: the cluster start-up amortized

The sweep is ``examples/sweeps/platoon-40.toml``: the 4-vehicle platoon (T = 100),
5 values of lambda x 2 delays x 4 scalings of A, 50 Monte Carlo runs per point,
3 estimators. Every mode writes its own results folder (in a temporary
directory); the numbers of all modes are checked to be identical.

Modes
-----
serial           ``run_sweep(..., scheduler="serial")``: in-process, one point after the other
dask (embedded)  ``run_sweep(..., scheduler="local", n_workers=W)``: includes starting and
                 stopping the LocalCluster (what ``teamkf sweep`` does)
dask (running)   the same on an already running cluster (``local_cluster(W)``, its address as
                 the scheduler): the steady-state throughput
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sweep", default=str(ROOT / "examples" / "sweeps" / "platoon-40.toml"))
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=1, help="run every mode this many times and keep the fastest")
    ap.add_argument("--runs", type=int, default=None, help="Monte Carlo runs per point instead of the sweep file's (longer points)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()

    import pandas as pd

    from teamkf.study.sweep import load_sweep, local_cluster, run_sweep

    spec = load_sweep(args.sweep)
    if args.runs is not None:
        import dataclasses

        spec = dataclasses.replace(spec, runs=args.runs)
    n = spec.n_points
    out: dict[str, float] = {}
    frames = {}
    load_before = os.getloadavg()[0]

    def best(key: str, seconds: float) -> None:
        out[key] = min(out.get(key, float("inf")), seconds)

    with tempfile.TemporaryDirectory() as tmp:
        for rep in range(args.repeat):
            t0 = time.perf_counter()
            run_sweep(spec, Path(tmp) / f"serial{rep}", "serial", progress=False)
            best("serial", time.perf_counter() - t0)

            t0 = time.perf_counter()
            run_sweep(spec, Path(tmp) / f"embedded{rep}", "local", n_workers=args.workers, progress=False)
            best("dask_embedded", time.perf_counter() - t0)

            t0 = time.perf_counter()
            cluster = local_cluster(args.workers)
            best("cluster_start", time.perf_counter() - t0)
            try:
                t0 = time.perf_counter()
                run_sweep(spec, Path(tmp) / f"running{rep}", cluster.scheduler_address, progress=False)
                best("dask_running", time.perf_counter() - t0)
            finally:
                cluster.close()
        for mode in ("serial", "embedded", "running"):
            df = pd.read_parquet(Path(tmp) / f"{mode}0")
            frames[mode] = df.sort_values(["point_index", "estimator"]).reset_index(drop=True)
    identical = all(frames[m].equals(frames["serial"]) for m in frames)
    load_after = os.getloadavg()[0]

    result = {
        "sweep": spec.name,
        "points": n,
        "estimators": len(spec.estimators),
        "runs": spec.runs,
        "workers": args.workers,
        "cores": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),
        "serial_s": out["serial"],
        "dask_embedded_s": out["dask_embedded"],
        "dask_running_s": out["dask_running"],
        "cluster_start_s": out["cluster_start"],
        "speedup_embedded": out["serial"] / out["dask_embedded"],
        "speedup_running": out["serial"] / out["dask_running"],
        "identical": identical,
        "repeat": args.repeat,
        "load_average_1min": [load_before, load_after],
    }
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print(
            f"sweep {spec.name}: {n} points x {len(spec.estimators)} estimators, {spec.runs} Monte Carlo runs per point; "
            f"{result['cores']} cores, {args.workers} Dask workers"
        )
        print()
        print(f"  {'mode':<28}{'wall [s]':>10}{'points/s':>10}{'speed-up':>10}")
        for label, key in (("serial", "serial"), ("dask, embedded LocalCluster", "dask_embedded"), ("dask, running LocalCluster", "dask_running")):
            t = out[key]
            print(f"  {label:<28}{t:>10.2f}{n / t:>10.2f}{out['serial'] / t:>9.2f}x")
        print(f"\n  LocalCluster start-up: {out['cluster_start']:.2f} s (included in 'embedded')")
        print(f"  numbers identical in all modes: {identical}")
        print(
            f"  fastest of {args.repeat} run(s) per mode; 1-minute load average {load_before:.2f} before, {load_after:.2f} after "
            "(other processes on the machine slow the Dask workers more than the serial run)"
        )
    return 0 if identical else 1


if __name__ == "__main__":  # required: the Dask workers are spawned processes that import this module
    sys.exit(main())
