"""Brute force for the re-sending drop-aware design (``resend = r``: each packet carries the sender's last r items).

Every edge-step pattern ω is enumerated and the packets flooded (``_arrival_steps`` of
``test_team_lossy_bruteforce``: packet (j, τ) first reaches agent i at a known step). Item (j, s) is
available at agent i by step k when a packet τ ∈ [s, s + r - 1] reached i on time (at τ + ℓ_ji ≤ k).
Given ω every filled item is a linear map of the joint Gaussian vector, so the design's estimator has
a cost that is a trace; the expected cost is the P(ω)-weighted sum, and the optimum of the class is the
pattern-averaged quadratic's minimizer. Nothing of the moment code is used.
"""

from __future__ import annotations

import numpy as np
import pytest

from teamkf import CommGraph
from teamkf.estimators.team_lossy import design_mtmse_lossy

from .test_team_lossy_bruteforce import _arrival_steps, _joint, _local_maps, _patterns, _tiny


def _brute_resend(d, graph, p, T, r):
    sysm, cost = d.system, d.cost
    n, dx, dz = sysm.n_agents, sysm.dx, cost.dz
    Cz = _joint(sysm, T)
    xf, nu = _local_maps(d, T)
    ell = np.asarray(graph.geodesic_delays())
    width = Cz.shape[0]
    arrivals = [(_arrival_steps(graph, ok, T, n), prob) for ok, prob in _patterns(graph, T, p)]
    expected, best = [], []
    for k in range(T):
        S, L = cost.S_at(k), cost.L_at(k)
        xk = np.zeros((dx, width))
        xk[:, k * dx : (k + 1) * dx] = np.eye(dx)
        a = np.vstack([L[i * dz : (i + 1) * dz] @ (xk - xf[(i, k)]) for i in range(n)])
        own = {i: np.vstack([nu[(i, s)] for s in range(k + 1)]) for i in range(n)}
        sizes = [sum(sysm.dy[j] for (j, _) in d.items[k][i]) for i in range(n)]
        offs = np.concatenate([[0], np.cumsum(sizes)]).astype(int)
        Hm, b = np.zeros((offs[-1], offs[-1])), np.zeros(offs[-1])
        c00 = float(np.trace(S @ a @ Cz @ a.T))
        Jexp = 0.0
        for learned, prob in arrivals:
            F = []
            for i in range(n):
                fill = d.fills[k][i] @ own[i]
                rows, col = [], 0
                for j, s in d.items[k][i]:
                    dj = sysm.dy[j]
                    avail = any(learned.get((j, tau, i)) == tau + ell[j, i] for tau in range(s, min(s + r - 1, k - ell[j, i]) + 1))
                    rows.append(nu[(j, s)] if avail else fill[col : col + dj])
                    col += dj
                F.append(np.vstack(rows) if rows else np.zeros((0, width)))
            err = a - np.vstack([d.gains[k][i] @ F[i] if F[i].size else np.zeros((dz, width)) for i in range(n)])
            Jexp += prob * float(np.trace(S @ err @ Cz @ err.T))
            for i in range(n):  # the class's quadratic (dz = 1): J(g) = c00 - 2 g'b + g' Hm g
                b[offs[i] : offs[i + 1]] += prob * (F[i] @ Cz @ a.T @ S[:, i])
                for l in range(n):
                    Hm[offs[i] : offs[i + 1], offs[l] : offs[l + 1]] += prob * S[i, l] * (F[i] @ Cz @ F[l].T)
        g = np.linalg.solve(Hm, b)
        expected.append(Jexp)
        best.append((c00 - g @ b, g, np.concatenate([d.gains[k][i].ravel() for i in range(n)])))
    return expected, best


@pytest.mark.parametrize(
    ("n", "graph", "p", "T", "r", "items"),
    [
        (2, CommGraph.complete(2, delay=1), 0.3, 5, 2, "innovations"),
        (2, CommGraph.complete(2, delay=1), 0.5, 5, 3, "measurements"),
        (3, CommGraph.line(3), 0.4, 3, 2, "innovations"),
        (3, CommGraph.line(3), 0.4, 3, 3, "measurements"),
    ],
)
def test_resend_expected_cost_and_optimality_by_enumeration(n, graph, p, T, r, items):
    sysm, cost = _tiny(n)
    d = design_mtmse_lossy(sysm, cost, graph, T, p_drop=p, items=items, resend=r)
    expected, best = _brute_resend(d, graph, p, T, r)
    np.testing.assert_allclose(d.stage_costs, expected, rtol=1e-10)  # the exact expected cost
    for k in range(T):
        Jbest, g, g_design = best[k]
        assert d.stage_costs[k] == pytest.approx(Jbest, rel=1e-10)  # the optimum of the class
        np.testing.assert_allclose(g_design, g, rtol=1e-6, atol=1e-9)
