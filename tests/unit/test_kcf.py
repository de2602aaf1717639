"""Kalman-consensus filter baseline (design/baselines.md): runtime, information discipline, reductions, errors, Monte Carlo."""

import numpy as np
import pytest

from teamkf import CommGraph, LinearGaussianSystem, TeamCost, design_centralized, design_mtmse, run_online
from teamkf.estimators.kcf import KCFDesign, KCFMessage, design_kcf
from teamkf.exceptions import ArgumentError, GraphError, InformationStructureError, ShapeError, TeamkfError, UnsupportedOperationError
from teamkf.simulation.runtime import graph_agents, run_graph
from teamkf.simulation.sampling import sample_paths
from tests.helpers import random_cost, random_system

VARIANTS = ("honest", "ideal")


def _random_instance(seed, n=4, dx=3, T=12, stable=True, delays=(1, 3), p=0.4):
    rng = np.random.default_rng(seed)
    dys = [int(d) for d in rng.integers(1, 3, size=n)]
    g = CommGraph.random(n, p, delays=delays, rng=rng)
    sys_ = random_system(rng, n, dx, dys, stable=stable)
    cost = random_cost(rng, n, dx, 2)
    return sys_, cost, g, T


def _first_change(z0, z1, i, dz):
    """First step at which agent i's estimate differs (bit for bit), or None."""
    diff = np.any(z0[:, :, i * dz : (i + 1) * dz] != z1[:, :, i * dz : (i + 1) * dz], axis=(0, 2))
    hits = np.flatnonzero(diff)
    return int(hits[0]) if hits.size else None


# ---------------------------------------------------------------------------
# design object
# ---------------------------------------------------------------------------
def test_design_fields_and_schedules():
    sys_, cost, g, T = _random_instance(0)
    d = design_kcf(sys_, cost, g, T, epsilon=0.2, variant="ideal")
    assert isinstance(d, KCFDesign)
    assert (d.estimator, d.horizon, d.stage_costs, d.average_cost) == ("kcf", T, None, None)
    assert d.info["variant"] == "ideal" and d.info["epsilon"] == 0.2 and d.info["realizable"] is False
    assert d.system is sys_ and d.cost is cost and d.graph is g
    n, dx = sys_.n_agents, sys_.dx
    assert d.P.shape == d.M.shape == d.S_fused.shape == (n, T, dx, dx) and d.gamma.shape == (n, T)
    assert not d.M.flags.writeable
    assert d.total_cost is None and d.cost_value is None and not d.has_analytic_cost  # no closed form: Monte Carlo
    for i in range(n):
        np.testing.assert_allclose(d.P[i, 0], sys_.Sigma_x)
        for k in range(T):
            P, S, M = d.P[i, k], d.S_fused[i, k], d.M[i, k]
            # M = (P^-1 + S)^-1 = P (I + S P)^-1 without inverting P (Sigma_x of random_system is singular)
            ref = P @ np.linalg.inv(np.eye(dx) + S @ P)
            np.testing.assert_allclose(M, 0.5 * (ref + ref.T), atol=1e-10 * max(1.0, np.abs(P).max()))
            assert np.allclose(M, M.T) and np.linalg.eigvalsh(M)[0] > -1e-10
            assert d.gamma[i, k] == pytest.approx(0.2 / (1 + np.linalg.norm(M, "fro")))
            if k + 1 < T:
                np.testing.assert_allclose(d.P[i, k + 1], sys_.A_at(k) @ M @ sys_.A_at(k).T + sys_.Q_at(k), atol=1e-12)
            want = sys_.C_at(i, k).T @ np.linalg.solve(sys_.R_at(i, k), sys_.C_at(i, k))
            for j in g.in_neighbors(i):
                want = want + sys_.C_at(j, k).T @ np.linalg.solve(sys_.R_at(j, k), sys_.C_at(j, k))
            np.testing.assert_allclose(S, want, atol=1e-10)
    # information form when P is positive definite
    Pd = d.P[0, 3]
    assert np.linalg.eigvalsh(Pd)[0] > 1e-6
    np.testing.assert_allclose(d.M[0, 3], np.linalg.inv(np.linalg.inv(Pd) + d.S_fused[0, 3]), rtol=1e-9, atol=1e-12)


def test_honest_sources_follow_edge_delays():
    sys_, cost, g, T = _random_instance(1)
    d = design_kcf(sys_, cost, g, T)
    for i in range(g.n_agents):
        for k in range(T):
            want = [(j, k - g.delay(j, i)) for j in g.in_neighbors(i) if k - g.delay(j, i) >= 0]
            assert list(d.sources[i][k]) == want
    # a neighbour enters the fused information only once its first message has arrived
    i = next(i for i in range(g.n_agents) if g.in_neighbors(i))
    j = g.in_neighbors(i)[0]
    assert all(jj != j for (jj, _) in d.sources[i][g.delay(j, i) - 1])


# ---------------------------------------------------------------------------
# honest variant through the message-passing runtime
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("seed", range(3))
def test_honest_run_graph_equals_simulate(seed):
    sys_, cost, g, T = _random_instance(seed, n=5, T=15)
    d = design_kcf(sys_, cost, g, T)
    p = sample_paths(sys_, T, 7, rng=seed)
    z_rt = run_graph(graph_agents(d), g, p.y)
    z_sim = d.simulate(p.y)
    assert z_rt.shape == (7, T, sys_.n_agents * cost.dz)
    np.testing.assert_allclose(z_rt, z_sim, rtol=1e-12, atol=1e-12 * np.abs(z_sim).max())
    # the payload is (u_i(k), k, xbar_i(k)) and the agent's state only its prior
    ag = d.graph_agents()[0]
    st = ag.init_state(7)
    assert set(st) == {"xbar"} and st["xbar"].shape == (7, sys_.dx)
    st, z, msg = ag.step(st, 0, p.y[0][:, 0], [])
    assert isinstance(msg, KCFMessage) and msg.step == 0 and np.all(msg.xbar == 0)


@pytest.mark.parametrize("seed", range(4))
def test_information_discipline_through_run_graph(seed):
    """Changing y_j(s) leaves agent i's estimates untouched before s + l_ji (bit for bit), and changes them later.

    The KCF relays information only through priors xbar (one extra step per relay
    hop), so the first change comes at s + l'_ji, where l'_ji is the shortest path
    with weights tau + 1, minus 1 (l'_ji = tau_ji for a direct edge) >= l_ji.
    """
    rng = np.random.default_rng(100 + seed)
    n, T, s = 5, 22, 1
    g = CommGraph.random(n, 0.35, delays=(1, 3), rng=rng)
    assert len({dl for (_, _, dl) in g.edges}) > 1  # unequal delays
    sys_ = random_system(rng, n, 3, [1, 2, 1, 2, 1], stable=True)
    cost = random_cost(rng, n, 3, 1)
    d = design_kcf(sys_, cost, g, T)
    p = sample_paths(sys_, T, 3, rng=seed)
    ell = g.geodesic_delays()
    slow = CommGraph(n, [(a, b, dl + 1) for (a, b, dl) in g.edges]).geodesic_delays() - 1
    z0 = run_graph(d.graph_agents(), g, p.y)
    for j in range(n):
        y = [yi.copy() for yi in p.y]
        y[j][:, s] += 0.37
        z1 = run_graph(d.graph_agents(), g, y)
        for i in range(n):
            first = _first_change(z0, z1, i, cost.dz)
            lag = 0 if i == j else int(slow[j, i])
            assert first is not None and first >= s + ell[j, i]
            assert first == s + lag
            np.testing.assert_array_equal(z0[:, : s + ell[j, i], i], z1[:, : s + ell[j, i], i])


# ---------------------------------------------------------------------------
# reductions
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("variant", VARIANTS)
def test_single_agent_is_the_centralized_kalman_filter(variant):
    rng = np.random.default_rng(5)
    sys_ = random_system(rng, 1, 3, [2], stable=False)
    cost = random_cost(rng, 1, 3, 2)
    T = 15
    d = design_kcf(sys_, cost, CommGraph(1), T, variant=variant)
    p = sample_paths(sys_, T, 20, rng=3)
    z_kf = run_online(design_centralized(sys_, cost, horizon=T).agents(), p.y)
    z = d.simulate(p.y)
    np.testing.assert_allclose(z, z_kf, rtol=0, atol=1e-10 * max(1.0, np.abs(z_kf).max()))
    if variant == "honest":
        np.testing.assert_allclose(run_graph(d.graph_agents(), CommGraph(1), p.y), z_kf, atol=1e-10 * max(1.0, np.abs(z_kf).max()))


def _local_kf(sys_, i, g, T, y, honest):
    """Agent i's local Kalman filter on its own and its in-neighbours' measurements.

    Honest: y_j(k - tau_ji) is treated as a measurement C_j x(k) + v — a
    time-varying subsystem whose C_j(k) is zero before the first message arrives.
    """
    members = [i, *g.in_neighbors(i)]
    lags = [0] + [g.delay(j, i) if honest else 0 for j in members[1:]]
    C = [[sys_.C_at(j, 0) if k >= lag else 0 * sys_.C_at(j, 0) for k in range(T)] for j, lag in zip(members, lags)]
    sub = LinearGaussianSystem(A=sys_.A_at(0), Q=sys_.Q_at(0), Sigma_x=sys_.Sigma_x, C=C, R=[sys_.R_at(j, 0) for j in members])
    ys = []
    for j, lag in zip(members, lags):
        yj = np.zeros_like(y[j])
        yj[:, lag:] = y[j][:, : T - lag]
        ys.append(yj)
    m, dx = len(members), sys_.dx
    z = run_online(design_centralized(sub, TeamCost.mse(m, dx), horizon=T).agents(), ys)
    return z[:, :, :dx]


@pytest.mark.parametrize("variant", VARIANTS)
def test_vanishing_epsilon_gives_local_kalman_filters(variant):
    sys_, _, g, T = _random_instance(7, n=4, dx=3, T=12)
    n, dx = sys_.n_agents, sys_.dx
    d = design_kcf(sys_, TeamCost.mse(n, dx), g, T, epsilon=1e-13, variant=variant)
    p = sample_paths(sys_, T, 10, rng=8)
    z = d.simulate(p.y)
    for i in range(n):
        ref = _local_kf(sys_, i, g, T, p.y, honest=variant == "honest")
        np.testing.assert_allclose(z[:, :, i * dx : (i + 1) * dx], ref, atol=1e-9 * max(1.0, np.abs(ref).max()))


def test_ideal_on_complete_graph_is_the_centralized_filter():
    """Every agent fuses everything and all priors coincide: the consensus term vanishes."""
    sys_, cost, _, T = _random_instance(9, n=3, T=10)
    g = CommGraph.complete(3, 2)
    d = design_kcf(sys_, cost, g, T, variant="ideal", epsilon=0.5)
    p = sample_paths(sys_, T, 10, rng=1)
    z_kf = run_online(design_centralized(sys_, cost, horizon=T).agents(), p.y)
    np.testing.assert_allclose(d.simulate(p.y), z_kf, atol=1e-10 * max(1.0, np.abs(z_kf).max()))


# ---------------------------------------------------------------------------
# errors() from the primitive noises
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("seed", range(3))
def test_errors_equal_direct_on_stable_systems(variant, seed):
    sys_, cost, g, T = _random_instance(20 + seed, n=4, T=14)
    d = design_kcf(sys_, cost, g, T, variant=variant)
    p = sample_paths(sys_, T, 25, rng=seed)
    e = d.errors(p)
    direct = p.x @ cost.L_at(0).T - d.simulate(p.y)
    assert e.shape == direct.shape == (25, T, sys_.n_agents * cost.dz)
    assert np.abs(e - direct).max() <= 1e-9 * np.abs(direct).max()
    c = d.costs(p)
    np.testing.assert_allclose(c[:, 3], cost.value(p.x[:, 3], d.simulate(p.y)[:, 3], 3), rtol=1e-8)


def test_errors_time_varying_system():
    rng = np.random.default_rng(31)
    n, T = 3, 9
    g = CommGraph.random(n, 0.6, delays=(1, 2), rng=rng)
    sys_ = random_system(rng, n, 2, [1, 2, 1], time_varying=True, n_steps=T)
    cost = random_cost(rng, n, 2, 1, time_varying=True, n_steps=T)
    for variant in VARIANTS:
        d = design_kcf(sys_, cost, g, T, variant=variant)
        p = sample_paths(sys_, T, 10, rng=2)
        z = d.simulate(p.y)
        direct = np.stack([p.x[:, k] @ cost.L_at(k).T - z[:, k] for k in range(T)], axis=1)
        assert np.abs(d.errors(p) - direct).max() <= 1e-9 * np.abs(direct).max()
        if variant == "honest":
            np.testing.assert_allclose(run_graph(d.graph_agents(), g, p.y), z, atol=1e-12 * np.abs(z).max())


def test_errors_unstable_uav_formation_ideal():
    """UAV-10 (spectral radius 1.55): |x(99)| ~ 1e18, so L x - z keeps no digit; the noise recursion does."""
    n, T = 10, 100
    sys_ = LinearGaussianSystem.uav_formation(n)
    cost = TeamCost.average_tracking(n, 1000.0)
    g = CommGraph.complete(n, 2)
    d = design_kcf(sys_, cost, g, T, variant="ideal")
    p = sample_paths(sys_, T, 100, rng=11)
    e = d.errors(p)
    direct = p.x @ cost.L_at(0).T - d.simulate(p.y)
    assert np.all(np.isfinite(e))
    early = np.abs(e[:, :10]).max()
    assert np.abs(e[:, 99]).max() < 3 * early  # stays of sane size
    assert np.abs(e[:, :10] - direct[:, :10]).max() <= 1e-9 * early  # agree while x is small
    garbage = np.abs(direct[:, 99] - e[:, 99]).max()
    assert np.abs(p.x[:, 99]).max() > 1e16
    assert garbage > 100 * np.abs(e[:, 99]).max()  # the direct path lost every digit
    # on a complete graph the ideal KCF is the centralized filter: the late stage costs match its analytic ones
    c = d.costs(p)[:, 50:].sum(axis=1)
    ref = design_centralized(sys_, cost, horizon=T).stage_costs[50:].sum()
    assert abs(c.mean() - ref) < 4 * c.std(ddof=1) / np.sqrt(c.size)


def test_errors_unstable_honest_grow_with_the_state():
    """Honest KCF on UAV-10: the stale fused measurements are wrong by (A^2 - I) x, so the error is O(x) and accurate relative to it."""
    n, T = 10, 60
    sys_ = LinearGaussianSystem.uav_formation(n)
    cost = TeamCost.average_tracking(n, 1000.0)
    d = design_kcf(sys_, cost, CommGraph.complete(n, 2), T)
    p = sample_paths(sys_, T, 20, rng=4)
    e = d.errors(p)
    direct = p.x @ cost.L_at(0).T - d.simulate(p.y)
    assert np.all(np.isfinite(e))
    assert np.abs(e[:, -1]).max() > 1e-3 * np.abs(p.x[:, -1]).max()  # of the order of x
    assert np.abs(e - direct).max() <= 1e-9 * np.abs(direct).max()


# ---------------------------------------------------------------------------
# Monte Carlo sanity: no estimator beats the optimum on its own information
# ---------------------------------------------------------------------------
def test_monte_carlo_platoon_not_below_bounds():
    sys_, cost, g, T = LinearGaussianSystem.platoon(4), TeamCost.platoon(4, 10.0), CommGraph.line(4), 30
    p = sample_paths(sys_, T, 2000, rng=2024)
    J_mtmse = design_mtmse(sys_, cost, g, T).total_cost
    J_cent = design_centralized(sys_, cost, horizon=T).total_cost
    for variant, bound in (("honest", J_mtmse), ("ideal", J_cent)):
        tot = design_kcf(sys_, cost, g, T, variant=variant).costs(p).sum(axis=1)
        sem = tot.std(ddof=1) / np.sqrt(tot.size)
        assert tot.mean() >= bound - 4 * sem, (variant, tot.mean(), sem, bound)


# ---------------------------------------------------------------------------
# bad input
# ---------------------------------------------------------------------------
def test_bad_input():
    sys_, cost, g = LinearGaussianSystem.platoon(4), TeamCost.platoon(4, 10.0), CommGraph.line(4)
    for eps in (0, -0.1, float("nan"), float("inf"), "a", True):
        with pytest.raises(ArgumentError, match="epsilon"):
            design_kcf(sys_, cost, g, 5, epsilon=eps)
    with pytest.raises(ArgumentError, match="horizon.*steady-state"):
        design_kcf(sys_, cost, g, None)
    with pytest.raises(ArgumentError, match="horizon"):
        design_kcf(sys_, cost, g, 0)
    with pytest.raises(GraphError, match="graph"):
        design_kcf(sys_, cost, CommGraph.line(3), 5)
    with pytest.raises(GraphError, match="graph"):
        design_kcf(sys_, cost, "line", 5)
    with pytest.raises(ArgumentError, match="variant.*'honset'"):
        design_kcf(sys_, cost, g, 5, variant="honset")
    with pytest.raises(ShapeError, match="cost"):
        design_kcf(sys_, TeamCost.platoon(3, 1.0), g, 5)
    ideal = design_kcf(sys_, cost, g, 5, variant="ideal")
    with pytest.raises(UnsupportedOperationError, match="kcf.*ideal"):
        ideal.graph_agents()
    with pytest.raises(TeamkfError):
        graph_agents(ideal)
    honest = design_kcf(sys_, cost, g, 5)
    p = sample_paths(sys_, 6, 2, rng=0)
    with pytest.raises(ShapeError, match="horizon"):
        honest.simulate(p.y)
    with pytest.raises(ShapeError, match="horizon"):
        run_graph(honest.graph_agents(), g, p.y)
    with pytest.raises(ShapeError, match=r"measurements\[1\]"):
        honest.simulate([p.y[0][:, :5], p.y[1][:, :5, :2], p.y[2][:, :5], p.y[3][:, :5]])
    with pytest.raises(InformationStructureError, match="agent"):
        run_graph(honest.graph_agents(), CommGraph.complete(4), [yi[:, :5] for yi in p.y])
    with pytest.raises(UnsupportedOperationError, match="graph_agents"):
        honest.agents()
