"""Gains keyed on the current arrivals (``mtmse_lossy`` with ``keyed=1``) against the missed-packet rule.

    PYTHONPATH=src python3 examples/lossy_keyed.py                      # the table of docs/lossy-design.md (T = 20, 40000 runs)
    TEAMKF_RUNS=2000 PYTHONPATH=src python3 examples/lossy_keyed.py     # a fast look

The team: a 3-agent line (delay 1) whose agents all estimate x₁ of x = (x₁, x₂) (A = [[0.95, 0.2], [0, 0.9]],
Q = 0.5 I, consensus-weighted cost S = 2I − 11ᵀ/3); agent 0 measures x₁ precisely (R = 0.01), agents 1
and 2 poorly (R = 4). For each drop probability p: the nominal MTMSE run over the lossy runtime with the
missed-packet rule (Monte Carlo, ± 1.96 standard errors), the drop-aware design with pattern-independent
gains (``keyed=0``) and keyed on the current arrivals (``keyed=1``), both exact, the keyed design's own
Monte Carlo, the local Kalman filters and the known-pattern optimum (the team told every drop; flooding
relays, W = 6, 400 sampled patterns). Printed as a Markdown table.
"""

from __future__ import annotations

import os

import numpy as np

from teamkf import CommGraph, LinearGaussianSystem, TeamCost
from teamkf.estimators.team import design_mtmse
from teamkf.estimators.team_lossy import design_mtmse_lossy, known_pattern_bound
from teamkf.simulation.links import LinkModel
from teamkf.simulation.monte_carlo import monte_carlo
from teamkf.simulation.sampling import sample_paths

T = int(os.environ.get("TEAMKF_T", "20"))
RUNS = int(os.environ.get("TEAMKF_RUNS", "40000"))
PS = (0.3, 0.5)


def unlike_line(n: int = 3, lam: float = 1.0) -> tuple[LinearGaussianSystem, TeamCost]:
    A = np.array([[0.95, 0.2], [0.0, 0.9]])
    C = [np.array([[1.0, 0.0]]) for _ in range(n)]
    sysm = LinearGaussianSystem(A=A, Q=0.5, Sigma_x=1.0, C=C, R=[0.01] + [4.0] * (n - 1))
    S = (1 + lam) * np.eye(n) - lam / n * np.ones((n, n))
    return sysm, TeamCost(S=S, L=np.tile([[1.0, 0.0]], (n, 1)), n_agents=n)


def main() -> None:
    sysm, cost = unlike_line()
    g = CommGraph.line(3)
    nominal = design_mtmse(sysm, cost, g, T)
    print(f"unlike-sensor line, n = 3, T = {T}; nominal MTMSE (perfect links) {nominal.total_cost:.2f}")
    print()
    print(
        "| p | rule (MC) | keyed = 0, exact | keyed = 1, exact | keyed = 1 (MC) | local KF | known-pattern bound | keyed 0 vs rule | keyed 1 vs rule |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    S = cost.S_at(0)
    for p in PS:
        r = monte_carlo({"mtmse": nominal}, T, RUNS, rng=5, path="runtime", graph=g, links=LinkModel(p_drop=p))["mtmse"]
        d0 = design_mtmse_lossy(sysm, cost, g, T, p_drop=p)
        d1 = design_mtmse_lossy(sysm, cost, g, T, p_drop=p, keyed=1)
        e = d1.errors(sample_paths(sysm, T, min(RUNS, 20000), rng=11), p_drop=p, rng=12)
        c = np.einsum("rki,ij,rkj->r", e, S, e)
        kb = known_pattern_bound(sysm, cost, g, T, p, relay="flood", window=6, n_patterns=400, rng=0)
        rule = r.total_mean
        print(
            f"| {p} | {rule:.2f} ± {1.96 * r.total_sem:.2f} | {d0.total_cost:.2f} | {d1.total_cost:.2f} | "
            f"{c.mean():.2f} ± {1.96 * c.std(ddof=1) / np.sqrt(c.size):.2f} | {d1.info['local_kf_cost']:.2f} | "
            f"{kb.value:.2f} ± {1.96 * kb.sem:.2f} | {100 * (d0.total_cost / rule - 1):+.1f} % | {100 * (d1.total_cost / rule - 1):+.1f} % |"
        )


if __name__ == "__main__":
    main()
