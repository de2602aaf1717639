"""Lossy Monte Carlo against lossless: the 4-vehicle platoon (T = 50), its estimators (MTMSE, MMSE, centralized).

    PYTHONPATH=src python3 benchmarks/bench_lossy.py [--runs 20000] [--p-drop 0.5] [--repeats 1]

Both Monte Carlos run in this one process, one after the other, on the same seed and the same number of
runs, with the defaults of ``teamkf evaluate`` (batch 1024, serial): "lossless" is the scenario as shipped
(the cancellation-free error recursions), "lossy" the same scenario with ``[network] p_drop`` set (the
agents in the batched lossy runtime, :mod:`teamkf.simulation.lossy`). The lossy time includes everything
a first call pays (the fill gains of the missed-packet rule are computed on first use and cached per
model). Prints both times (wall and CPU, ``time.process_time``), runs per second and their ratios (issue 21's target: ratio <= 4), then the
costs, and checks that p_drop = 0 gives the lossless numbers exactly.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from teamkf.simulation.monte_carlo import monte_carlo
from teamkf.study.scenario import load_packaged


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=20000)
    ap.add_argument("--p-drop", type=float, default=0.5)
    ap.add_argument("--horizon", type=int, default=50)
    ap.add_argument("--repeats", type=int, default=1, help="alternate lossless / lossy this many times (report each)")
    a = ap.parse_args()
    sc = load_packaged("platoon-4").updated({"horizon": a.horizon})
    lossy_sc = sc.updated({"network.p_drop": a.p_drop})
    designs = sc.designs()
    print(f"platoon-4, T = {a.horizon}, estimators {list(designs)}, {a.runs} runs each, seed 1, one process; load average {os.getloadavg()[0]:.1f}")
    for rep in range(a.repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        ref = monte_carlo(designs, a.horizon, a.runs, rng=1, progress=False)
        t1, c1 = time.perf_counter(), time.process_time()
        lossy = monte_carlo(designs, a.horizon, a.runs, rng=1, progress=False, **lossy_sc.monte_carlo_options())
        t2, c2 = time.perf_counter(), time.process_time()
        tl, tp = t1 - t0, t2 - t1
        print(
            f"[{rep + 1}] lossless: {tl:.2f} s ({a.runs / tl:,.0f} runs/s)   lossy p_drop = {a.p_drop}: {tp:.2f} s ({a.runs / tp:,.0f} runs/s)   "
            f"ratio lossy / lossless = {tp / tl:.2f}   CPU {c1 - c0:.2f} s / {c2 - c1:.2f} s, ratio {(c2 - c1) / (c1 - c0):.2f}   (load {os.getloadavg()[0]:.1f})"
        )
    for name in designs:
        lo, hi = lossy[name].ci95
        print(f"  {name:12s} lossless J = {ref[name].total_mean:10.3f}   lossy J = {lossy[name].total_mean:10.3f}  95% CI [{lo:.3f}, {hi:.3f}]")
    stats = lossy["mtmse"].links
    c = stats.counts[(0, 1)]
    print(f"  edge 0->1: {c}; measurements replaced by their expectation (MTMSE, all agents): {sum(stats.missed.values()):,}")
    zero = monte_carlo(designs, a.horizon, min(a.runs, 2000), rng=1, progress=False, **sc.updated({"network.p_drop": 0.0}).monte_carlo_options())
    ref0 = monte_carlo(designs, a.horizon, min(a.runs, 2000), rng=1, progress=False)
    same = all(np.array_equal(zero[n].stage_mean, ref0[n].stage_mean) and zero[n].total_sem == ref0[n].total_sem for n in designs)
    print(f"  p_drop = 0 gives the lossless numbers bit for bit: {same}")


if __name__ == "__main__":
    main()
