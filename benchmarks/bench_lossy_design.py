"""Time of the drop-aware design ``mtmse_lossy`` (issue 21): platoon n = 4 and UAV formation n = 10.

    PYTHONPATH=src python3 benchmarks/bench_lossy_design.py                 # both, p in {0.1, 0.5}
    PYTHONPATH=src python3 benchmarks/bench_lossy_design.py --only platoon  # one of them
    PYTHONPATH=src python3 benchmarks/bench_lossy_design.py --memory 10     # the UAV with memory 10 (default: none)
    PYTHONPATH=src python3 benchmarks/bench_lossy_design.py --only platoon --platoon-horizons 50 --p 0.5

platoon  the packaged platoon-4 scenario (line graph, unit delays, λ = 100), T = 50 and T = 100,
         the exact class (memory none): one Cholesky factorization of Γ serves every step.
uav      the packaged uav-10 scenario (complete graph, delay 2, λ = 1000), T = 100, the exact class
         or a memory m (items of the last m steps; the per-step path).

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
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    from teamkf.estimators.team import design_mtmse
    from teamkf.estimators.team_lossy import design_mtmse_lossy
    from teamkf.study.scenario import load_packaged

    print(f"load average {os.getloadavg()}")
    cases = []
    if args.only in (None, "platoon"):
        cases += [("platoon-4", int(T), None) for T in args.platoon_horizons.split(",")]
    if args.only in (None, "uav"):
        cases += [("uav-10", 100, args.memory or None)]
    rows = []
    for name, T, mem in cases:
        sc = load_packaged(name).updated({"horizon": T})
        t0 = time.perf_counter()
        ref = design_mtmse(sc.system, sc.cost, sc.graph, T)
        t_ref = time.perf_counter() - t0
        for p in map(float, args.p.split(",")):
            t0, c0 = time.perf_counter(), time.process_time()
            d = design_mtmse_lossy(sc.system, sc.cost, sc.graph, T, p_drop=p, memory=mem, bound=False)
            dt = time.perf_counter() - t0
            cpu = time.process_time() - c0
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
