"""The drop-aware design against the nominal MTMSE with the missed-packet rule (platoon, line graph).

    PYTHONPATH=src python3 examples/lossy_design.py                          # T = 20, 60 runs: a fast look
    TEAMKF_T=50 TEAMKF_RUNS=200 PYTHONPATH=src python3 examples/lossy_design.py  # the table of docs/lossy-design.md

For each drop probability p: the nominal MTMSE (designed for perfect links) run by its agents over the
lossy runtime (the missed-packet rule: a missing measurement is replaced by its conditional
expectation; Monte Carlo, ± 1.96 standard errors), the drop-aware design ``mtmse_lossy`` (its exact
expected cost, and its Monte Carlo on sampled link events), the local Kalman filters, and the
certified lower bound (the MTMSE cost of the full information). The gaps are relative to the bound.
Printed as a Markdown table (the one in docs/lossy-design.md).
"""

from __future__ import annotations

import os

import numpy as np

from teamkf.estimators.team import design_mtmse
from teamkf.estimators.team_lossy import design_mtmse_lossy
from teamkf.network.information import InformationStructure
from teamkf.simulation.links import LinkModel
from teamkf.simulation.monte_carlo import monte_carlo
from teamkf.simulation.sampling import sample_paths
from teamkf.study.scenario import load_packaged

T = int(os.environ.get("TEAMKF_T", "20"))
RUNS = int(os.environ.get("TEAMKF_RUNS", "60"))
PS = (0.1, 0.2, 0.5, 1.0)


def main() -> None:
    sc = load_packaged("platoon-4").updated({"horizon": T})
    nominal = design_mtmse(sc.system, sc.cost, sc.graph, T)
    own = design_mtmse(sc.system, sc.cost, InformationStructure.own_window(4, T), T).total_cost
    S = sc.cost.S_at(0)
    print(f"platoon-4, line graph, T = {T}; nominal MTMSE (perfect links) {nominal.total_cost:.1f}; own-history optimum {own:.1f}")
    print()
    print(
        "| p | nominal + missed-packet rule (MC) | drop-aware, exact | drop-aware (MC) | local KF | lower bound | rule gap | drop-aware gap | drop-aware vs rule |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    paths = sample_paths(sc.system, T, 4000, rng=21)
    for p in PS:
        r = monte_carlo({"mtmse": nominal}, T, RUNS, rng=5, path="runtime", graph=sc.graph, links=LinkModel(p_drop=p))["mtmse"]
        d = design_mtmse_lossy(sc.system, sc.cost, sc.graph, T, p_drop=p)
        e = d.errors(paths, p_drop=p, rng=22)
        c = np.einsum("rki,ij,rkj->r", e, S, e)
        se = c.std(ddof=1) / np.sqrt(c.size)
        lb = d.lower_bound
        print(
            f"| {p} | {r.total_mean:.1f} ± {1.96 * r.total_sem:.1f} | {d.total_cost:.1f} | {c.mean():.1f} ± {1.96 * se:.1f} | "
            f"{d.info['local_kf_cost']:.1f} | {lb:.1f} | {100 * (r.total_mean - lb) / lb:.1f} % | {100 * d.gap:.1f} % | "
            f"{100 * (d.total_cost - r.total_mean) / r.total_mean:+.1f} % |",
            flush=True,
        )


if __name__ == "__main__":
    main()
