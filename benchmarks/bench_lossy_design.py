"""Time of the drop-aware design ``mtmse_lossy`` (issue 21): platoon n = 4 and UAV formation n = 10.

    PYTHONPATH=src python3 benchmarks/bench_lossy_design.py                 # both, p in {0.1, 0.5}
    PYTHONPATH=src python3 benchmarks/bench_lossy_design.py --only platoon  # one of them
    PYTHONPATH=src python3 benchmarks/bench_lossy_design.py --memory 10     # the UAV with memory 10 (default: none)
    PYTHONPATH=src python3 benchmarks/bench_lossy_design.py --only platoon --platoon-horizons 50 --p 0.5
    PYTHONPATH=src python3 benchmarks/bench_lossy_design.py --only uav --p 0.5 --summary 1,2,4 --uav-horizons 100,3000

platoon  the packaged platoon-4 scenario (line graph, unit delays, λ = 100), T = 50 and T = 100,
         the exact class (memory none): one Cholesky factorization of Γ serves every step.
uav      the packaged uav-10 scenario (complete graph, delay 2, λ = 1000), T = 100, the exact class
         or a memory m (items of the last m steps; the per-step path).
--summary  also the age-keyed summaries (``summary = M``) of every case, with their time as a ratio to the items
         design of the same case and run (at horizons where the items design is refused for its size, the
         summaries alone: ``items seconds`` is then null).

Printed per case: seconds (design with its exact expected cost; the lower bound, an MTMSE design,
timed separately), J_T, the local Kalman filters' cost and the MTMSE lower bound. One process, one
BLAS thread (the design's default). Timings are noisy on a shared machine: the load average is printed.
"""

from __future__ import annotations

import argparse
import json
import os
import time


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--only", choices=("platoon", "uav"), default=None)
    ap.add_argument("--memory", type=int, default=0, help="memory of the UAV design (steps; 0: none, the exact class)")
    ap.add_argument("--platoon-horizons", default="50,100", help="horizons of the platoon cases (comma-separated)")
    ap.add_argument("--p", default="0.1,0.5", help="drop probabilities (comma-separated)")
    ap.add_argument("--summary", default="", help="ages M of the summary designs to time too (comma-separated; empty: none)")
    ap.add_argument("--uav-horizons", default="100", help="horizons of the UAV cases (comma-separated)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    from teamkf.estimators.team import design_mtmse
    from teamkf.estimators.team_lossy import design_mtmse_lossy
    from teamkf.exceptions import ResourceError
    from teamkf.study.scenario import load_packaged

    print(f"load average {os.getloadavg()}")
    cases = []
    if args.only in (None, "platoon"):
        cases += [("platoon-4", int(T), None) for T in args.platoon_horizons.split(",")]
    if args.only in (None, "uav"):
        cases += [("uav-10", int(T), args.memory or None) for T in args.uav_horizons.split(",")]
    rows = []
    for name, T, mem in cases:
        sc = load_packaged(name).updated({"horizon": T})
        t0 = time.perf_counter()
        ref = design_mtmse(sc.system, sc.cost, sc.graph, T)
        t_ref = time.perf_counter() - t0
        for p in map(float, args.p.split(",")):
            t0, c0 = time.perf_counter(), time.process_time()
            try:
                d = design_mtmse_lossy(sc.system, sc.cost, sc.graph, T, p_drop=p, memory=mem, bound=False)
            except ResourceError as exc:  # refused for its size: the summaries may still run
                print(f"items design refused: {exc}", flush=True)
                d = None
            dt = time.perf_counter() - t0
            cpu = time.process_time() - c0
            for M in (int(x) for x in args.summary.split(",") if x):
                t1, c1 = time.perf_counter(), time.process_time()
                ds = design_mtmse_lossy(sc.system, sc.cost, sc.graph, T, p_drop=p, summary=M, bound=False)
                ts, tc = time.perf_counter() - t1, time.process_time() - c1
                row = {
                    "scenario": name,
                    "T": T,
                    "p": p,
                    "summary": M,
                    "seconds": round(ts, 2),
                    "cpu seconds": round(tc, 2),
                    "items seconds": None if d is None else round(dt, 2),
                    "time / items": None if d is None else round(ts / dt, 3),
                    "J_T": ds.total_cost,
                    "items J_T": None if d is None else d.total_cost,
                    "local KF": ds.info["local_kf_cost"],
                    "steady from": ds.info["steady_from"],
                }
                rows.append(row)
                print(json.dumps(row) if args.json else "  ".join(f"{k}={v}" for k, v in row.items()), flush=True)
            if d is None:
                continue
            row = {
                "scenario": name,
                "T": T,
                "p": p,
                "memory": mem,
                "seconds": round(dt, 2),
                "cpu seconds": round(cpu, 2),
                "J_T": d.total_cost,
                "local KF": d.info["local_kf_cost"],
                "bound (MTMSE)": ref.total_cost,
                "MTMSE seconds": round(t_ref, 2),
            }
            rows.append(row)
            print(json.dumps(row) if args.json else "  ".join(f"{k}={v}" for k, v in row.items()), flush=True)


if __name__ == "__main__":
    main()
