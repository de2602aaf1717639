"""Brute force for the drop-aware design on age-keyed filter summaries (``summary = M``).

Every packet's fate is enumerated (edge j -> i, origin τ: lost, or late by u = 0..J), the newest summary each agent
holds is read off the arrival steps, and given the pattern every feature 1[a_ij(k) = m] (x̂_j(τ|τ) - x̂_i(τ|τ)) is a
linear map of the joint Gaussian vector (x, y), the local Kalman filters run on those maps with gains computed here.
The design's expected stage costs must equal the pattern-weighted traces of its gains, and the optimum of the
class, the minimizer of the pattern-averaged quadratic. Nothing of the design's moment code is used.
"""

from __future__ import annotations

from itertools import product

import numpy as np
import pytest

from teamkf import CommGraph, LinearGaussianSystem, TeamCost
from teamkf.estimators.team_lossy import design_mtmse_lossy

from .test_team_lossy_bruteforce import _joint


def _filters(sysm, T):
    """x̂_i(k|k) and ν_i(k) of every agent's own Kalman filter as maps over (x, y), gains from a Riccati recursion here."""
    n, dx, dyt, off = sysm.n_agents, sysm.dx, sysm.dy_total, sysm.offsets
    width = T * dx + T * dyt
    out, innov = {}, {}
    for i in range(n):
        P, pred = np.array(sysm.Sigma_x, dtype=float), np.zeros((dx, width))
        for k in range(T):
            C, R = sysm.C_at(i, k), sysm.R_at(i, k)
            K = P @ C.T @ np.linalg.inv(C @ P @ C.T + R)
            ysel = np.zeros((sysm.dy[i], width))
            ysel[:, T * dx + k * dyt + int(off[i]) + np.arange(sysm.dy[i])] = np.eye(sysm.dy[i])
            innov[(i, k)] = ysel - C @ pred
            out[(i, k)] = pred + K @ innov[(i, k)]
            pred = sysm.A_at(k) @ out[(i, k)]
            P = sysm.A_at(k) @ (P - K @ C @ P) @ sysm.A_at(k).T + sysm.Q_at(k)
    return out, innov


def _fates(graph, T, p, J):
    """Every pattern: {(j, i, τ): arrival step or None} with its probability."""
    packets = [(a, b, d, t) for (a, b, d) in graph.edges for t in range(T) if t + d <= T - 1]
    options = [None, *range(J + 1)]
    for combo in product(options, repeat=len(packets)):
        prob, fate = 1.0, {}
        for (a, b, d, t), u in zip(packets, combo):
            prob *= p if u is None else (1 - p) / (J + 1)
            fate[(a, b, t)] = None if u is None else t + d + u
        yield fate, prob


def _brute(d, graph, p, J, T, M):
    sysm, cost = d.system, d.cost
    n, dx = sysm.n_agents, sysm.dx
    Cz = _joint(sysm, T)
    xf, innov = _filters(sysm, T)
    W = max(dl for (_, _, dl) in graph.edges) + M
    width = Cz.shape[0]
    delay = {(a, b): dl for (a, b, dl) in graph.edges}
    fates = list(_fates(graph, T, p, J))
    expected, best = [], []
    for k in range(T):
        S, L = cost.S_at(k), cost.L_at(k)
        xk = np.zeros((dx, width))
        xk[:, k * dx : (k + 1) * dx] = np.eye(dx)
        a = np.vstack([L[i : i + 1] @ (xk - xf[(i, k)]) for i in range(n)])  # d_z = 1
        feats = [
            [(j, m) for j in range(n) if (j, i) in delay for m in range(M) if k - delay[(j, i)] - m >= 0] + [(i, m) for m in range(min(W, k + 1))]
            for i in range(n)
        ]
        assert [sorted(f) for f in feats] == [sorted(f) for f in d.items[k]]  # the design's features are every possible one
        offs = np.concatenate([[0], np.cumsum([sum(sysm.dy[i] if j == i else dx for j, _ in f) for i, f in enumerate(feats)])]).astype(int)
        Hm, b = np.zeros((offs[-1], offs[-1])), np.zeros(offs[-1])
        Jexp = 0.0
        for fate, prob in fates:
            F = []
            for i in range(n):
                rows = []
                for j, m in d.items[k][i]:
                    if j == i:  # the own innovation ν_i(k - m), always held
                        rows.append(innov[(i, k - m)])
                        continue
                    arrived = [t for t in range(k + 1) if fate.get((j, i, t)) is not None and fate[(j, i, t)] <= k]
                    tau = k - delay[(j, i)] - m
                    on = bool(arrived) and max(arrived) == tau
                    rows.append(xf[(j, tau)] - xf[(i, tau)] if on else np.zeros((dx, width)))
                F.append(np.vstack(rows) if rows else np.zeros((0, width)))
            err = a - np.vstack([d.gains[k][i] @ F[i] if F[i].size else np.zeros((1, width)) for i in range(n)])
            Jexp += prob * float(np.trace(S @ err @ Cz @ err.T))
            for i in range(n):
                b[offs[i] : offs[i + 1]] += prob * (F[i] @ Cz @ a.T @ S[:, i])
                for l in range(n):
                    Hm[offs[i] : offs[i + 1], offs[l] : offs[l + 1]] += prob * S[i, l] * (F[i] @ Cz @ F[l].T)
        c00 = float(np.trace(S @ a @ Cz @ a.T))
        g = np.linalg.lstsq(Hm, b, rcond=None)[0] if b.size else b
        expected.append(Jexp)
        best.append(c00 - float(g @ b))
    return np.array(expected), np.array(best)


def _team(n):
    rng = np.random.default_rng(3 + n)
    A = np.array([[1.1, 0.3], [-0.2, 0.8]])  # unstable: the summaries' reason
    sysm = LinearGaussianSystem(A=A, Q=0.5, Sigma_x=1.0, C=[rng.normal(size=(1, 2)) for _ in range(n)], R=[0.3 + 0.5 * i for i in range(n)])
    L = np.zeros((n, 2))
    for i in range(n):
        L[i, i % 2] = 1.0
    S = 3.0 * np.eye(n) + np.ones((n, n))
    return sysm, TeamCost(S=S, L=L, n_agents=n)


@pytest.mark.parametrize(
    ("n", "graph", "p", "J", "T", "M"),
    [
        (2, CommGraph.complete(2, delay=1), 0.4, 0, 5, 2),
        (2, CommGraph.complete(2, delay=1), 0.3, 1, 4, 3),
        (3, CommGraph.line(3), 0.5, 0, 4, 2),
    ],
)
def test_summary_cost_and_optimality_by_enumeration(n, graph, p, J, T, M):
    sysm, cost = _team(n)
    d = design_mtmse_lossy(sysm, cost, graph, T, p_drop=p, jitter=J, summary=M, bound=False)
    expected, best = _brute(d, graph, p, J, T, M)
    np.testing.assert_allclose(d.stage_costs, expected, rtol=1e-9, atol=1e-9)  # the exact cost of its gains
    np.testing.assert_allclose(d.stage_costs, best, rtol=1e-9, atol=1e-9)  # and the optimum of the class
    assert np.all(d.stage_costs <= d.local_stages * (1 + 1e-12))  # never worse than the local filters (G = 0)
