"""Speed of the baseline families on the UAV formation n = 10 (complete graph, delay 2, T = 100).

    PYTHONPATH=src python3 benchmarks/bench_baselines.py            # designs + Monte Carlo
    PYTHONPATH=src python3 benchmarks/bench_baselines.py --runs 200  # a smaller Monte Carlo

design  every family and variant: design + exact analytic cost (the symbolic step description,
        the error-noise coefficients and the joint covariance propagation), best of --repeat.
        MTMSE (the optimum) is timed in the same run as the reference for the ratios.
mc      Monte Carlo of all families and variants together (teamkf.simulation.monte_carlo,
        common random numbers, errors(paths) path), --runs runs x 100 steps, once.

Timings are noisy on a shared machine: the load average is printed; compare ratios.
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--runs", type=int, default=1000)
    ap.add_argument("--n", type=int, default=10)
    args = ap.parse_args()
    from teamkf import design_mtmse
    from teamkf.estimators.registry import get_family
    from teamkf.experiments._common import uav
    from teamkf.experiments.leaderboard import FAMILIES
    from teamkf.simulation.monte_carlo import monte_carlo

    system, cost, graph = uav(args.n, float(args.n**2))
    T = 100
    print(f"load average {os.getloadavg()}; UAV n = {args.n}, complete graph delay 2, T = {T}")

    def best(f):
        ts, out = [], None
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            out = f()
            ts.append(time.perf_counter() - t0)
        return min(ts), out

    t_ref, ref = best(lambda: design_mtmse(system, cost, graph, T))
    rows = [{"design": "mtmse (reference)", "seconds": t_ref, "ratio": 1.0, "J_T": ref.total_cost}]
    designs = {}
    for fam, variants in FAMILIES:  # the leaderboard's families and variants
        for v in variants:
            with np.errstate(over="ignore", invalid="ignore"):
                t, d = best(lambda fam=fam, v=v: get_family(fam).design(system, cost, graph, T, variant=v))
            designs[f"{fam}-{v}"] = d
            rows.append({"design": f"{fam} [{v}]", "seconds": t, "ratio": t / t_ref, "J_T": d.total_cost})
    for r in rows:
        print(f"  {r['design']:<22} {r['seconds']:8.3f} s   x{r['ratio']:6.2f} of MTMSE   J_T = {r['J_T']:.6g}")
    t0 = time.perf_counter()
    with np.errstate(over="ignore", invalid="ignore"):
        mc = monte_carlo(designs, T, args.runs, rng=2024)
    t_mc = time.perf_counter() - t0
    worst = max(float(np.max(np.abs(mc[k].stage_mean - d.stage_costs) / np.maximum(mc[k].stage_sem, 1e-300))) for k, d in designs.items())
    print(
        f"Monte Carlo: {len(designs)} designs together, {args.runs} runs x {T} steps: {t_mc:.2f} s; max |MC - analytic| / sem over steps = {worst:.2f}"
    )
    print(json.dumps({"design": rows, "monte_carlo_seconds": t_mc, "runs": args.runs, "max_z": worst}, default=float))


if __name__ == "__main__":
    main()
