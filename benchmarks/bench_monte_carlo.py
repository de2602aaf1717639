"""Monte Carlo speed: the UAV formation (n = 10, T = 100), 1000 runs, MTMSE + MMSE + KCF together.

    PYTHONPATH=src python3 benchmarks/bench_monte_carlo.py [--runs 1000] [--loop-runs 50]

"vectorized" is teamkf's Monte Carlo (all runs as an array axis, cancellation-free
error recursions). "plain loop" is the way most research code runs: one run at a
time, one step at a time, each estimator's agents stepping on that run's data
(batch of 1) through teamkf's own online agents and the message-passing
runtime; it is timed on --loop-runs runs and scaled linearly to --runs
(the per-run cost is constant), and its numbers are checked against the
vectorized ones on the same runs. The UAV with n = 10 is unstable, so the plain
loop's L x - z loses digits late in the horizon; only its time is compared.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from teamkf import CommGraph, LinearGaussianSystem, TeamCost, design_kcf, design_mmse, design_mtmse
from teamkf.simulation.monte_carlo import monte_carlo
from teamkf.simulation.runtime import graph_agents, run_graph
from teamkf.simulation.sampling import sample_paths


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=1000)
    ap.add_argument("--loop-runs", type=int, default=50)
    ap.add_argument("--variant", default="honest", choices=["honest", "ideal", "stale"])
    a = ap.parse_args()
    n, T = 10, 100
    system, cost, graph = LinearGaussianSystem.uav_formation(n), TeamCost.average_tracking(n, 10.0 * n * n), CommGraph.complete(n, 2)
    t0 = time.perf_counter()
    designs = {
        "mtmse": design_mtmse(system, cost, graph, T),
        "mmse": design_mmse(system, cost, graph, T),
        "kcf": design_kcf(system, cost, graph, T, variant=a.variant),
    }
    t1 = time.perf_counter()
    mc = monte_carlo(designs, T, a.runs, rng=1)
    t2 = time.perf_counter()
    vec = t2 - t1

    t3 = time.perf_counter()
    loop_costs = {name: [] for name in designs}
    for r in range(a.loop_runs):  # one run at a time, every step in Python, batch of 1
        p = sample_paths(system, T, 1, rng=1, first_run=r)  # run r of the Monte Carlo's seed, alone
        for name, d in designs.items():
            z = run_graph(graph_agents(d), graph, p.y)
            c = sum(float(cost.value(p.x[0, k], z[0, k], k)) for k in range(T))
            loop_costs[name].append(c)
    t4 = time.perf_counter()
    loop_per_run = (t4 - t3) / a.loop_runs
    loop_est = loop_per_run * a.runs
    print(f"design (3 estimators): {t1 - t0:.2f} s")
    print(f"vectorized Monte Carlo, {a.runs} runs x {T} steps x 3 estimators: {vec:.2f} s")
    print(
        f"plain per-run loop: {loop_per_run * 1e3:.1f} ms per run -> {loop_est:.1f} s for {a.runs} runs "
        f"(measured on {a.loop_runs}); ratio {loop_est / vec:.0f}x"
    )
    for name, r in mc.items():
        lo, hi = r.ci95
        print(
            f"  {name:6s} MC J_T = {r.total_mean:.6g}  95% CI [{lo:.6g}, {hi:.6g}]"
            + (f"  analytic {designs[name].total_cost:.6g}" if designs[name].stage_costs is not None else "")
        )
    # same runs, early steps (before the cancellation matters): both paths agree
    p = sample_paths(system, 10, 3, rng=1)
    for name, d in designs.items():
        z = run_graph(graph_agents(d), graph, p.y)
        e_loop = np.stack([p.x[:, k] @ cost.L_at(k).T - z[:, k] for k in range(10)], axis=1)
        print(f"  {name:6s} max |e_loop - e_vectorized| over the first 10 steps: {np.abs(e_loop - d.errors(p)).max():.2e}")


if __name__ == "__main__":
    main()
