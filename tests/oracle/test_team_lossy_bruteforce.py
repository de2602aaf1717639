"""Brute force for the drop-aware design: enumerate every link-event pattern, flood the items, and
evaluate / optimize the class directly on the joint Gaussian law (nothing from the moment code).

For each pattern ω of the edge-step events (probability Π q^ok (1-q)^lost) the flooding-once relay is
simulated step by step to find when each innovation ν_j(s) reaches each agent; agent i's filled item
vector is then an explicit linear map of the stacked measurements y, and so is every estimate. The
expected stage cost is Σ_ω P(ω) Tr(S cov(error_ω)), and the best gains of the class minimize the
pattern-averaged quadratic — built here from the per-pattern covariances and solved directly.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from teamkf import CommGraph, LinearGaussianSystem, TeamCost
from teamkf.estimators.team_lossy import design_mtmse_lossy

T = 3


def _joint(system: LinearGaussianSystem, T: int):
    """cov of (x(0..T-1), y(0..T-1)) stacked: x blocks first."""
    dx, dyt = system.dx, system.dy_total
    Phi = np.zeros((T * dx, dx + T * dx))  # x(k) = Phi[k] @ (x0, w(0..T-1))
    cur = np.hstack([np.eye(dx), np.zeros((dx, T * dx))])
    for k in range(T):
        Phi[k * dx : (k + 1) * dx] = cur
        nxt = system.A_at(k) @ cur
        nxt[:, dx + k * dx : dx + (k + 1) * dx] += np.eye(dx)
        cur = nxt
    Cov0 = np.zeros((dx + T * dx, dx + T * dx))
    Cov0[:dx, :dx] = system.Sigma_x
    for k in range(T):
        Cov0[dx + k * dx : dx + (k + 1) * dx, dx + k * dx : dx + (k + 1) * dx] = system.Q_at(k)
    Cx = Phi @ Cov0 @ Phi.T
    Cblk = np.zeros((T * dyt, T * dx))
    Rb = np.zeros((T * dyt, T * dyt))
    for k in range(T):
        Cblk[k * dyt : (k + 1) * dyt, k * dx : (k + 1) * dx] = system.C_stack(k)
        Rb[k * dyt : (k + 1) * dyt, k * dyt : (k + 1) * dyt] = system.R_stack(k)
    top = np.hstack([Cx, Cx @ Cblk.T])
    bot = np.hstack([Cblk @ Cx, Cblk @ Cx @ Cblk.T + Rb])
    return np.vstack([top, bot])


def _local_maps(d, T):
    """Linear maps over (x, y) of every agent's x̂_i(k|k) and of every item (ν_j(s), or y_j(s))."""
    sysm = d.system
    n, dx, dyt = sysm.n_agents, sysm.dx, sysm.dy_total
    off = sysm.offsets
    width = T * dx + T * dyt
    xf = {}
    nu = {}
    for i in range(n):
        pred = np.zeros((dx, width))
        for k in range(T):
            ysel = np.zeros((sysm.dy[i], width))
            ysel[:, T * dx + k * dyt + int(off[i]) + np.arange(sysm.dy[i])] = np.eye(sysm.dy[i])
            innov = ysel - sysm.C_at(i, k) @ pred
            nu[(i, k)] = ysel if d.coordinates == "measurements" else innov  # what the agents flood
            xf[(i, k)] = pred + d.K_local[k][i] @ innov
            pred = sysm.A_at(k) @ xf[(i, k)]
    return xf, nu


def _arrival_steps(graph: CommGraph, ok: dict, T: int, n: int):
    """Flooding-once: arrival step of item (j, s) at agent i (None: never), from the edge-step outcomes."""
    learned = {(j, s, j): s for j in range(n) for s in range(T)}
    for t in range(T):
        for a, b, dl in graph.edges:
            for (j, s, u), when in list(learned.items()):
                if u == a and when == t and ok[(a, b, t)]:
                    key = (j, s, b)
                    if key not in learned or learned[key] > t + dl:
                        learned[key] = t + dl
    return learned


def _patterns(graph: CommGraph, T: int, p: float):
    events = [(a, b, t) for (a, b, _) in graph.edges for t in range(T)]
    for bits in itertools.product([False, True], repeat=len(events)):
        ok = dict(zip(events, bits))
        prob = float(np.prod([(1 - p) if b else p for b in bits]))
        yield ok, prob


def _brute(d, graph, p):
    sysm, cost = d.system, d.cost
    n, dx, dz = sysm.n_agents, sysm.dx, cost.dz
    Cz = _joint(sysm, T)
    xf, nu = _local_maps(d, T)
    ell = np.asarray(graph.geodesic_delays())
    width = Cz.shape[0]
    pats = list(_patterns(graph, T, p))
    arrivals = [(_arrival_steps(graph, ok, T, n), prob) for ok, prob in pats]
    expected, best = [], []
    for k in range(T):
        S, L = cost.S_at(k), cost.L_at(k)
        xk = np.zeros((dx, width))
        xk[:, k * dx : (k + 1) * dx] = np.eye(dx)
        a = np.vstack([L[i * dz : (i + 1) * dz] @ (xk - xf[(i, k)]) for i in range(n)])  # L_i e_i(k|k)
        own = {i: np.vstack([nu[(i, s)] for s in range(k + 1)]) for i in range(n)}
        Jexp = 0.0
        sizes = [sum(sysm.dy[j] for (j, _) in d.items[k][i]) for i in range(n)]
        offs = np.concatenate([[0], np.cumsum(sizes)]).astype(int)
        Hm = np.zeros((offs[-1], offs[-1]))
        b = np.zeros(offs[-1])
        c00 = float(np.trace(S @ a @ Cz @ a.T))
        for learned, prob in arrivals:
            F = []
            for i in range(n):
                fill = d.fills[k][i] @ own[i][own[i].shape[0] - d.fills[k][i].shape[1] :]  # on the agent's last w own items
                rows, col = [], 0
                for j, s in d.items[k][i]:
                    dj = sysm.dy[j]
                    on_time = learned.get((j, s, i)) == s + ell[j, i]
                    rows.append(nu[(j, s)] if on_time else fill[col : col + dj])
                    col += dj
                F.append(np.vstack(rows) if rows else np.zeros((0, width)))
            err = a - np.vstack([d.gains[k][i] @ F[i] if F[i].size else np.zeros((dz, width)) for i in range(n)])
            Jexp += prob * float(np.trace(S @ err @ Cz @ err.T))
            # the class's quadratic (dz = 1): J(g) = c00 - 2 g'b + g' Hm g
            for i in range(n):
                b[offs[i] : offs[i + 1]] += prob * (F[i] @ Cz @ a.T @ S[:, i])
                for l in range(n):
                    Hm[offs[i] : offs[i + 1], offs[l] : offs[l + 1]] += prob * S[i, l] * (F[i] @ Cz @ F[l].T)
        g = np.linalg.solve(Hm, b)
        expected.append(Jexp)
        best.append((c00 - g @ b, g, np.concatenate([d.gains[k][i].ravel() for i in range(n)])))
    return expected, best


def _tiny(n: int):
    rng = np.random.default_rng(7 + n)
    A = np.array([[0.9, 0.3], [-0.2, 0.8]])
    C = [rng.normal(size=(1, 2)) for _ in range(n)]
    sysm = LinearGaussianSystem(A=A, Q=0.5, Sigma_x=1.0, C=C, R=0.3)
    L = np.zeros((n, 2))
    for i in range(n):
        L[i, i % 2] = 1.0
    lam = 3.0
    S = (1 + lam) * np.eye(n) - lam / n * np.ones((n, n)) + 0.1 * np.eye(n)
    return sysm, TeamCost(S=S, L=L, n_agents=n)


@pytest.mark.parametrize("items", ["measurements", "innovations"])
@pytest.mark.parametrize(("n", "graph", "p"), [(2, CommGraph.complete(2, delay=1), 0.3), (3, CommGraph.line(3), 0.4)])
def test_expected_cost_and_optimality_by_enumeration(n, graph, p, items):
    sysm, cost = _tiny(n)
    d = design_mtmse_lossy(sysm, cost, graph, T, p_drop=p, items=items)
    expected, best = _brute(d, graph, p)
    np.testing.assert_allclose(d.stage_costs, expected, rtol=1e-10)  # the exact expected cost
    for k in range(T):
        Jbest, g, g_design = best[k]
        assert d.stage_costs[k] == pytest.approx(Jbest, rel=1e-10)  # the optimum of the class
        np.testing.assert_allclose(g_design, g, rtol=1e-6, atol=1e-9)
