"""Streaming Monte Carlo: throughput per core, 2-worker Dask speed-up, peak memory against the run count.

    PYTHONPATH=src python3 benchmarks/bench_mc_streaming.py                       # 10^6 runs, serial vs 2 workers
    PYTHONPATH=src python3 benchmarks/bench_mc_streaming.py --runs 200000 --memory 10000 100000 1000000
    PYTHONPATH=src python3 benchmarks/bench_mc_streaming.py --runs 0 --memory 10000000   # only the 10^7-run memory

The model is ``scenarios/uav-4.toml`` (UAV formation, n = 4, T = 100, MTMSE + MMSE + centralized).

Cases (one process, in this order)
----------------------------------
serial      ``monte_carlo(..., scheduler=None)`` on --runs runs: wall and CPU time, runs per second per core.
dask        the same runs on an already started LocalCluster with --workers single-threaded worker processes
            (started before the clock; its start-up is printed separately): wall time, the speed-up against
            serial, and whether the result is bit-for-bit the serial one.
memory      for each count in --memory, a fresh Python process runs the serial Monte Carlo and reports its peak
            resident set (``ru_maxrss``); the baseline is the same process's peak after designing, before
            simulating. Memory does not grow with the runs: only one block (``batch`` runs) is alive.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

SCENARIO = Path(__file__).resolve().parents[1] / "src" / "teamkf" / "scenarios" / "uav-4.toml"

_CHILD = r"""
import resource, sys, time, json
from teamkf.study.scenario import load_scenario
from teamkf.simulation.monte_carlo import monte_carlo
ds = load_scenario(sys.argv[1]).designs()
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
t = time.perf_counter()
mc = monte_carlo(ds, 100, int(sys.argv[2]), rng=1, progress=False)
dt = time.perf_counter() - t
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(json.dumps({"runs": int(sys.argv[2]), "base_MiB": base / 1024, "peak_MiB": peak / 1024, "seconds": dt,
                  "mtmse": mc["mtmse"].total_mean}))
"""


def _same(a, b) -> bool:
    import numpy as np

    return all(
        np.array_equal(a[n].stage_mean, b[n].stage_mean) and a[n].total_mean == b[n].total_mean and a[n].total_sem == b[n].total_sem for n in a
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=1_000_000, help="runs for the serial and Dask timings (0: skip)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--memory", type=int, nargs="*", default=[10_000, 100_000], help="run counts for the peak-memory table")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()

    from teamkf.simulation.monte_carlo import monte_carlo
    from teamkf.study.scenario import load_scenario

    res: dict = {"scenario": "uav-4", "T": 100, "runs": a.runs, "workers": a.workers, "load": os.getloadavg()}
    ds = load_scenario(SCENARIO).designs()
    if a.runs:
        monte_carlo(ds, 100, 2048, rng=0, progress=False)  # warm
        t, c = time.perf_counter(), time.process_time()
        serial = monte_carlo(ds, 100, a.runs, rng=1, progress=False)
        res["serial_s"], res["serial_cpu_s"] = time.perf_counter() - t, time.process_time() - c
        res["runs_per_s_per_core"] = a.runs / res["serial_cpu_s"]
        res["runs_per_s_serial"] = a.runs / res["serial_s"]
        if a.workers:
            import distributed

            from teamkf.study.sweep import local_cluster

            t = time.perf_counter()
            cluster = local_cluster(a.workers)
            client = distributed.Client(cluster)
            client.wait_for_workers(a.workers)
            res["dask_startup_s"] = time.perf_counter() - t
            try:
                monte_carlo(ds, 100, 4096, rng=0, scheduler=client, chunk=2048, progress=False)  # ship imports
                t = time.perf_counter()
                dask = monte_carlo(ds, 100, a.runs, rng=1, scheduler=client, progress=False)
                res["dask_s"] = time.perf_counter() - t
            finally:
                client.close()
                cluster.close()
            res["dask_speedup"] = res["serial_s"] / res["dask_s"]
            res["dask_equals_serial_bit_for_bit"] = _same(serial, dask)
        res["mtmse_mc"] = serial["mtmse"].total_mean
        res["mtmse_ci95"] = list(serial["mtmse"].ci95)
        res["mtmse_analytic"] = float(ds["mtmse"].total_cost)
    res["memory"] = []
    for n in a.memory:
        out = subprocess.run([sys.executable, "-c", _CHILD, str(SCENARIO), str(n)], capture_output=True, text=True, check=True, env=os.environ)
        res["memory"].append(json.loads(out.stdout.strip().splitlines()[-1]))
    res["load_after"] = os.getloadavg()
    if a.json:
        print(json.dumps(res, indent=1))
        return
    print(f"streaming Monte Carlo, uav-4 (n = 4, T = 100, 3 estimators); load {res['load']} -> {res['load_after']}")
    if a.runs:
        print(
            f"  serial: {a.runs} runs in {res['serial_s']:.1f} s ({res['runs_per_s_serial']:.0f} runs/s); "
            f"{res['runs_per_s_per_core']:.0f} runs/s per core (CPU time)"
        )
        if a.workers:
            print(
                f"  Dask, {a.workers} workers: {res['dask_s']:.1f} s -> x{res['dask_speedup']:.2f} serial "
                f"(cluster start {res['dask_startup_s']:.1f} s, not counted); bit-for-bit = serial: {res['dask_equals_serial_bit_for_bit']}"
            )
        print(f"  mtmse: MC {res['mtmse_mc']:.4f}, 95% CI {res['mtmse_ci95']}, analytic {res['mtmse_analytic']:.4f}")
    for m in res["memory"]:
        print(f"  memory: {m['runs']:>10d} runs: peak RSS {m['peak_MiB']:.0f} MiB (after designing: {m['base_MiB']:.0f} MiB), {m['seconds']:.1f} s")


if __name__ == "__main__":
    main()
