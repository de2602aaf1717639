"""Brute force for the keyed drop-aware design (``keyed=1``, gains keyed on the current arrivals, w = 1).

Every edge-step pattern ω is enumerated and the flooding simulated (the helpers of
``test_team_lossy_bruteforce``: nothing from the moment code). Given ω each agent's pattern π_i(k)
(the on-time bits of its items due at k) is known, so the keyed estimator is one linear map of the
joint Gaussian vector and its cost a trace; the expected cost is the P(ω)-weighted sum. The optimum
of the keyed class is computed directly too: the pattern-averaged quadratic over every gain G_i(π)
(a least-squares solve: gains on an item surely missed under π are redundant).
"""

from __future__ import annotations

import numpy as np
import pytest

from teamkf import CommGraph
from teamkf.estimators.team_lossy import design_mtmse_lossy

from .test_team_lossy_bruteforce import _arrival_steps, _joint, _local_maps, _patterns, _tiny


def _brute_keyed(d, graph, p, T):
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
        npat = [1 << len(d.due[k][i]) for i in range(n)]
        size = [sum(sysm.dy[j] for (j, _) in d.items[k][i]) for i in range(n)]
        # unknowns: (agent i, pattern π, row) -> offset
        offs, o = {}, 0
        for i in range(n):
            for pi in range(npat[i]):
                offs[(i, pi)] = o
                o += size[i]
        Hm, b = np.zeros((o, o)), np.zeros(o)
        c00 = float(np.trace(S @ a @ Cz @ a.T))
        Jexp = 0.0
        for learned, prob in arrivals:
            F, pat = [], []
            for i in range(n):
                fill = d.fills[k][i] @ own[i]
                rows, col = [], 0
                for j, s in d.items[k][i]:
                    dj = sysm.dy[j]
                    on_time = learned.get((j, s, i)) == s + ell[j, i]
                    rows.append(nu[(j, s)] if on_time else fill[col : col + dj])
                    col += dj
                F.append(np.vstack(rows) if rows else np.zeros((0, width)))
                bits = [learned.get((j, s, i)) == s + ell[j, i] for (j, s) in d.due[k][i]]
                pat.append(sum(1 << t for t, bit in enumerate(bits) if bit))
            err = a - np.vstack([d.keyed_gains[k][i][pat[i]] @ F[i] if F[i].size else np.zeros((dz, width)) for i in range(n)])
            Jexp += prob * float(np.trace(S @ err @ Cz @ err.T))
            for i in range(n):
                oi = offs[(i, pat[i])]
                b[oi : oi + size[i]] += prob * (F[i] @ Cz @ a.T @ S[:, i])
                for l in range(n):
                    ol = offs[(l, pat[l])]
                    Hm[oi : oi + size[i], ol : ol + size[l]] += prob * S[i, l] * (F[i] @ Cz @ F[l].T)
        g = np.linalg.lstsq(Hm, b, rcond=1e-13)[0]
        expected.append(Jexp)
        best.append(c00 - g @ b)
    return np.array(expected), np.array(best)


CASES = [
    (2, CommGraph.complete(2, delay=1), 0.3, 4),
    (2, CommGraph.complete(2, delay=1), 0.6, 5),
    (3, CommGraph.line(3), 0.4, 3),
    (3, CommGraph.complete(3, delay=1), 0.5, 2),
]


@pytest.mark.parametrize("items", ["measurements", "innovations"])
@pytest.mark.parametrize(("n", "graph", "p", "T"), CASES)
def test_keyed_expected_cost_and_optimality_by_enumeration(n, graph, p, T, items):
    sysm, cost = _tiny(n)
    d = design_mtmse_lossy(sysm, cost, graph, T, p_drop=p, items=items, keyed=1)
    expected, best = _brute_keyed(d, graph, p, T)
    np.testing.assert_allclose(d.stage_costs, expected, rtol=1e-9)  # the exact expected cost of the keyed gains
    np.testing.assert_allclose(d.stage_costs, best, rtol=1e-9)  # ... and they are the optimum of the keyed class
    d0 = design_mtmse_lossy(sysm, cost, graph, T, p_drop=p, items=items)
    assert np.all(d.stage_costs <= d0.stage_costs * (1 + 1e-12))  # contains today's class
