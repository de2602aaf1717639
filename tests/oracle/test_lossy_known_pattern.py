"""The known-pattern optimum against brute force: every edge-step pattern enumerated, the flooding (or the
relay of everything held) simulated, and each step's static team problem solved on the full joint
Gaussian law of (x, y) with the agents' held measurements stacked (no common-data window, no Kalman
filter); and its place between the full-information cost and the drop-aware design's exact cost."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from teamkf import CommGraph, LinearGaussianSystem, TeamCost
from teamkf.estimators.registry import get_family
from teamkf.estimators.team_lossy import design_mtmse_lossy, known_pattern_bound

T = 3


def _joint(system, T):
    """cov of (x(0..T-1), y(0..T-1)) stacked: x blocks first."""
    dx, dyt = system.dx, system.dy_total
    Phi = np.zeros((T * dx, dx + T * dx))
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
    return np.block([[Cx, Cx @ Cblk.T], [Cblk @ Cx, Cblk @ Cx @ Cblk.T + Rb]])


def _held(graph, ok, n, relay):
    """held[k][i] = set of (j, s) agent i holds at step k, simulated packet by packet."""
    held = [[{(i, s) for s in range(k + 1)} for i in range(n)] for k in range(T)]
    for t in range(T):
        for a, b, dl in graph.edges:
            if not ok[(a, b, t)] or t + dl > T - 1:
                continue
            if relay == "all":
                payload = set(held[t][a])
            else:  # the items a learned at step t (first held at t)
                payload = held[t][a] - (held[t - 1][a] if t else set())
            for k in range(t + dl, T):
                held[k][b] |= payload
    return held


def _brute(system, cost, graph, p, relay):
    n, dx, dyt = system.n_agents, system.dx, system.dy_total
    Cz = _joint(system, T)
    off = system.offsets
    events = [(a, b, t) for (a, b, _) in graph.edges for t in range(T)]
    stages = np.zeros(T)
    for bits in itertools.product([False, True], repeat=len(events)):
        ok = dict(zip(events, bits))
        prob = float(np.prod([(1 - p) if b else p for b in bits]))
        held = _held(graph, ok, n, relay)
        for k in range(T):
            S, L = cost.S_at(k), cost.L_at(k)
            xk = np.arange(k * dx, (k + 1) * dx)
            rows = [[T * dx + s * dyt + int(off[j]) + r for (j, s) in sorted(held[k][i]) for r in range(system.dy[j])] for i in range(n)]
            # Radner conditions, dz = 1: sum_l S_il (L_l cov(x, Y_i) - g_l' cov(Y_l, Y_i)) = 0
            sizes = np.cumsum([0] + [len(r) for r in rows])
            H = np.zeros((sizes[-1], sizes[-1]))
            b = np.zeros(sizes[-1])
            for i in range(n):
                for l in range(n):
                    H[sizes[i] : sizes[i + 1], sizes[l] : sizes[l + 1]] = S[i, l] * Cz[np.ix_(rows[i], rows[l])]
                    b[sizes[i] : sizes[i + 1]] += S[i, l] * (L[l] @ Cz[np.ix_(xk, rows[i])])
            g = np.linalg.solve(H, b)
            c0 = float(np.trace(S @ L @ Cz[np.ix_(xk, xk)] @ L.T))
            stages[k] += prob * (c0 - g @ b)
    return stages


def _tiny(n):
    rng = np.random.default_rng(11 + n)
    A = np.array([[0.9, 0.3], [-0.2, 0.8]])
    C = [rng.normal(size=(1, 2)) for _ in range(n)]
    sysm = LinearGaussianSystem(A=A, Q=0.5, Sigma_x=1.0, C=C, R=0.3)
    L = np.zeros((n, 2))
    for i in range(n):
        L[i, i % 2] = 1.0
    S = 4.0 * np.eye(n) - 3.0 / n * np.ones((n, n)) + 0.1 * np.eye(n)
    return sysm, TeamCost(S=S, L=L, n_agents=n)


@pytest.mark.parametrize("relay", ["flood", "all"])
@pytest.mark.parametrize(("n", "graph", "p"), [(2, CommGraph.complete(2, delay=1), 0.3), (3, CommGraph.line(3), 0.4)])
def test_known_pattern_optimum_by_enumeration(n, graph, p, relay):
    sysm, cost = _tiny(n)
    b = known_pattern_bound(sysm, cost, graph, T, p, relay=relay)
    assert b.exact and b.sem == 0.0
    np.testing.assert_allclose(b.stages, _brute(sysm, cost, graph, p, relay), rtol=1e-10)


def test_relay_all_holds_more_than_flooding_on_a_longer_line():
    sysm, cost = _tiny(3)
    g = CommGraph.line(3)
    fl = known_pattern_bound(sysm, cost, g, 4, 0.5, relay="flood")
    al = known_pattern_bound(sysm, cost, g, 4, 0.5, relay="all")
    assert fl.exact and al.exact
    assert al.value < fl.value - 1e-6  # a re-sent measurement reaches agent 2 where flooding-once lost it


@pytest.mark.parametrize("p", [0.0, 0.3, 0.7, 1.0])
def test_bound_between_full_information_and_the_design(p):
    sysm, cost = _tiny(3)
    g, Tn = CommGraph.line(3), 4
    d = design_mtmse_lossy(sysm, cost, g, Tn, p_drop=p, items="measurements")
    full = get_family("mtmse").build(sysm, cost, graph=g, structure=g, horizon=Tn)
    for relay in ("flood", "all"):
        b = known_pattern_bound(sysm, cost, g, Tn, p, relay=relay)
        assert b.exact
        assert np.all(b.stages >= np.asarray(full.stage_costs) - 1e-9)
        assert np.all(b.stages <= np.asarray(d.stage_costs) + 1e-9)
    if p in (0.0, 1.0):  # the class's exact optima at the ends: MTMSE and the own-history optimum
        np.testing.assert_allclose(b.stages, d.stage_costs, rtol=1e-9)


def test_window_gives_a_looser_bound_and_monte_carlo_agrees():
    sysm, cost = _tiny(3)
    g, Tn = CommGraph.line(3), 4
    exact = known_pattern_bound(sysm, cost, g, Tn, 0.5)
    w = [known_pattern_bound(sysm, cost, g, Tn, 0.5, window=W).value for W in (0, 1, 2)]
    assert w[0] <= w[1] + 1e-9 <= w[2] + 2e-9 <= exact.value + 3e-9
    assert w[0] < exact.value - 1e-6
    mc = known_pattern_bound(sysm, cost, g, Tn, 0.5, n_patterns=400, rng=3)
    assert not mc.exact and abs(mc.value - exact.value) < 4 * mc.sem
    lo, hi = mc.interval
    assert lo < mc.value < hi


def test_jitter_counts_late_packets_as_held_later():
    sysm, cost = _tiny(2)
    g = CommGraph.complete(2, delay=1)
    b0 = known_pattern_bound(sysm, cost, g, 4, 0.2)
    bj = known_pattern_bound(sysm, cost, g, 4, 0.2, jitter=1)
    assert b0.exact and bj.exact and bj.value > b0.value


def test_design_reports_its_gap_to_the_known_pattern_optimum():
    sysm, cost = _tiny(3)
    g = CommGraph.line(3)
    d = design_mtmse_lossy(sysm, cost, g, 4, p_drop=0.5, items="measurements", known_bound=50)
    kb = d.info["known_pattern_bound"]
    assert kb["exact"] and kb["relay"] == "flood" and kb["n_patterns"] == 4096
    exact = known_pattern_bound(sysm, cost, g, 4, 0.5)
    assert kb["value"] == pytest.approx(exact.value, rel=1e-12)  # the window ℓ_max + 4 covers T = 4: exact
    assert d.info["known_pattern_gap"] == pytest.approx((d.total_cost - exact.value) / exact.value)
    assert 0.0 < d.info["known_pattern_gap"] < d.gap
    assert d.details()["known_pattern_gap"] == d.info["known_pattern_gap"]
    di = design_mtmse_lossy(sysm, cost, g, 4, p_drop=0.5, items="innovations", known_bound=50)
    assert di.info["known_pattern_bound"]["relay"] == "all"  # a bound for every protocol
    assert di.info["known_pattern_bound"]["value"] <= di.total_cost


def test_bad_arguments_are_refused_by_name():
    from teamkf.exceptions import ArgumentError

    sysm, cost = _tiny(2)
    g = CommGraph.complete(2, delay=1)
    with pytest.raises(ArgumentError, match="relay"):
        known_pattern_bound(sysm, cost, g, 3, 0.2, relay="everything")
    with pytest.raises(ArgumentError, match=r"p_drop\[\[0, 5\]\]"):
        known_pattern_bound(sysm, cost, g, 3, {(0, 5): 0.2})
    with pytest.raises(ArgumentError, match="p_drop"):
        known_pattern_bound(sysm, cost, g, 3, 1.5)
