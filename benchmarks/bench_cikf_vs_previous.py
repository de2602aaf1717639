"""The CIKF design and error recursion against the previous implementation, in the same run.

    PYTHONPATH=src python3 benchmarks/bench_cikf_vs_previous.py [--size 50] [--steps 4] [--runs 1000]

"previous" is the frozen copy of the implementation before issue 13 (``tests/unit/cikf_reference.py``,
the reference the tests pin the new code to). Every case runs alternately (previous; the default
``method="structured"`` with 1 and 2 threads; ``method="joint"`` with 1 and 2 threads) ``--repeat`` times;
the fastest of each is kept, and wall and CPU times are printed with the load average, since the
development machine's 2 cores are shared. The Monte Carlo does not depend on the method.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "unit"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", type=int, default=50)
    ap.add_argument("--steps", type=int, default=4)
    ap.add_argument("--runs", type=int, default=1000)
    ap.add_argument("--repeat", type=int, default=2)
    a = ap.parse_args()

    from cikf_reference import recursion_impl, reference_iterate

    from teamkf._blas import blas_threads
    from teamkf.estimators.cikf import _mse_cost, design_cikf
    from teamkf.simulation.sampling import sample_paths
    from teamkf.study.random_field import random_field

    sysm, graph = random_field(a.size, a.size, rng=0)
    N, M = sysm.n_agents, sysm.dx
    cost = _mse_cost(N, M)
    res: dict = {"size": a.size, "steps": a.steps, "runs": a.runs, "load_before": os.getloadavg()}
    best: dict = {}

    def clock(key, f):
        t, c = time.perf_counter(), time.process_time()
        out = f()
        w, u = time.perf_counter() - t, time.process_time() - c
        if key not in best or w < best[key][0]:
            best[key] = (w, u)
        return out

    design_cikf(sysm, None, graph, 1)
    for _ in range(a.repeat):
        with blas_threads(1):
            ref = clock("design_previous", lambda: reference_iterate(sysm, graph, a.steps, cost=cost, form="predictor"))
        d1 = clock("design_new_1thread", lambda: design_cikf(sysm, None, graph, a.steps, form="predictor", threads=1))
        d2 = clock("design_new_2threads", lambda: design_cikf(sysm, None, graph, a.steps, form="predictor", threads=2))
        j1 = clock("design_joint_1thread", lambda: design_cikf(sysm, None, graph, a.steps, form="predictor", threads=1, method="joint"))
        j2 = clock("design_joint_2threads", lambda: design_cikf(sysm, None, graph, a.steps, form="predictor", threads=2, method="joint"))
    res["design_max_rel_diff"] = float(np.max(np.abs(d2.stage_costs - ref["stage"]) / np.abs(ref["stage"])))
    res["design_joint_max_rel_diff"] = float(np.max(np.abs(j2.stage_costs - ref["stage"]) / np.abs(ref["stage"])))
    assert np.array_equal(d1.stage_costs, d2.stage_costs) and np.array_equal(j1.stage_costs, j2.stage_costs)
    if a.runs:
        paths = sample_paths(sysm, a.steps, a.runs, rng=1)
        for _ in range(a.repeat):
            with blas_threads(1):
                e0 = clock("errors_previous", lambda: recursion_impl(d1, paths.v, paths.x[:, 0], paths.w, a.runs, a.steps, "predictor"))
            e1 = clock("errors_new_1thread", lambda: d1.errors(paths))
            e2 = clock("errors_new_2threads", lambda: d2.errors(paths))
        res["errors_max_rel_diff"] = float(np.abs(e2 - e0).max() / np.abs(e0).max())
        assert np.array_equal(e1, e2)
        del e0, e1, e2
    res["load_after"] = os.getloadavg()
    for k, (w, u) in best.items():
        res[k + "_wall_s"], res[k + "_cpu_s"] = w, u
    for what in ("design", "errors"):
        if f"{what}_previous" in best:
            for new in ("new_1thread", "new_2threads", "joint_1thread", "joint_2threads"):
                if f"{what}_{new}" not in best:
                    continue
                res[f"{what}_{new}_speedup_wall"] = best[f"{what}_previous"][0] / best[f"{what}_{new}"][0]
    print(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
