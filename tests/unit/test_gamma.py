"""Gamma F = eta: the operator, the dense assembly and the solvers agree with an explicit Kronecker matrix."""

import numpy as np
import pytest

from teamkf.estimators.gamma import GammaProblem
from teamkf.exceptions import ConvergenceError


def problem(rng, n=4, dz=2, D=12, sparse_S=False):
    M = rng.standard_normal((D, D + 3))
    Sigma = M @ M.T / D + 0.1 * np.eye(D)
    idx = [np.sort(rng.choice(D, size=int(rng.integers(1, 6)), replace=False)) for _ in range(n)]
    B = rng.standard_normal((n * dz, n * dz))
    S = B @ B.T + np.eye(n * dz)
    if sparse_S:  # tridiagonal agent coupling
        for i in range(n):
            for j in range(n):
                if abs(i - j) > 1:
                    S[i * dz : (i + 1) * dz, j * dz : (j + 1) * dz] = 0
        S += n * np.eye(n * dz)
    return GammaProblem(S, Sigma, idx, dz)


def explicit_gamma(g):
    """Column-major vec, Gamma_ij = Sigma_ij (x) S_ij (Lemma 5), with np.kron."""
    dz = g.dz
    sizes = [dz * len(ix) for ix in g.idx]
    o = np.concatenate([[0], np.cumsum(sizes)])
    G = np.zeros((o[-1], o[-1]))
    for i, ii in enumerate(g.idx):
        for j, jj in enumerate(g.idx):
            G[o[i] : o[i + 1], o[j] : o[j + 1]] = np.kron(g.Sigma[np.ix_(ii, jj)], g.S[i * dz : (i + 1) * dz, j * dz : (j + 1) * dz])
    return G, o


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("sparse_S", [False, True])
def test_operator_dense_and_kron_agree(seed, sparse_S):
    rng = np.random.default_rng(seed)
    g = problem(rng, sparse_S=sparse_S)
    F = [rng.standard_normal((g.dz, len(ix))) for ix in g.idx]
    x = g.flatten(F)
    np.testing.assert_allclose(g.apply_flat(x), g.dense() @ x, rtol=1e-12, atol=1e-12)
    G, o = explicit_gamma(g)
    y = G @ np.concatenate([f.ravel(order="F") for f in F])
    out = g.apply(F)
    for i in range(len(F)):
        np.testing.assert_allclose(out[i].ravel(order="F"), y[o[i] : o[i + 1]], rtol=1e-12, atol=1e-12)
    assert np.all(np.linalg.eigvalsh(g.dense()) > 0)  # Lemma 5: S > 0, Sigma_ii > 0 => Gamma > 0


@pytest.mark.parametrize("seed", range(4))
def test_dense_and_cg_solutions_agree(seed):
    rng = np.random.default_rng(seed)
    g = problem(rng, n=6, dz=2, D=20)
    eta = [rng.standard_normal((g.dz, len(ix))) for ix in g.idx]
    Fd = g.solve(eta, method="dense")
    Fc = g.solve(eta, method="cg", rtol=1e-13)
    assert g.method_used == "cg" and g.iterations > 0
    for a, b in zip(Fd, Fc):
        np.testing.assert_allclose(a, b, rtol=1e-8, atol=1e-10)
    res = g.apply(Fd)
    for r, e in zip(res, eta):
        np.testing.assert_allclose(r, e, rtol=1e-9, atol=1e-10)


def test_auto_switches_to_cg_when_dense_would_not_fit():
    rng = np.random.default_rng(0)
    g = problem(rng)
    assert g.choose("auto") == "dense"
    assert g.choose("auto", dense_max_bytes=8) == "cg"


def test_cg_reports_non_convergence():
    rng = np.random.default_rng(0)
    g = problem(rng, n=6, D=20)
    eta = [rng.standard_normal((g.dz, len(ix))) for ix in g.idx]
    with pytest.raises(ConvergenceError, match="conjugate gradients"):
        g.solve(eta, method="cg", max_iter=1, rtol=1e-15)


def test_empty_local_information():
    g = GammaProblem(np.eye(2), np.eye(3), [np.zeros(0, int), np.zeros(0, int)], 1)
    F = g.solve([np.zeros((1, 0)), np.zeros((1, 0))])
    assert [f.shape for f in F] == [(1, 0), (1, 0)]


# ---------------------------------------------------------------------------
# Innovation coordinates (InnovationsProblem): same gains and cost as dense Gamma
# ---------------------------------------------------------------------------
from teamkf import CommGraph, LinearGaussianSystem, TeamCost, design_mtmse  # noqa: E402
from teamkf.estimators.gamma import InnovationsProblem, WindowModel, choose_solver  # noqa: E402
from teamkf.estimators.kalman import steady_state  # noqa: E402
from teamkf.estimators.team import _eta, _local_index, gains_team_cost, window_covariances  # noqa: E402
from teamkf.exceptions import NotPositiveDefiniteError  # noqa: E402
from teamkf.network.information import InformationStructure  # noqa: E402


def window_problems(system, cost, graph, k=None, anchor=0, P=None):
    """(InnovationsProblem, dense GammaProblem, eta, trace term) of one window step."""
    st = InformationStructure.from_graph(graph)
    if k is None:
        k = st.common_lag - 1
    if P is None:
        P = steady_state(system)[0]
    w = k - anchor + 1
    idx = [_local_index(system, st, i, k, anchor) for i in range(system.n_agents)]
    model = WindowModel(
        [system.A_at(anchor + u) for u in range(w - 1)],
        [system.Q_at(anchor + u) for u in range(w - 1)],
        [system.C_stack(anchor + u) for u in range(w)],
        [system.R_stack(anchor + u) for u in range(w)],
        P,
    )
    S, L = cost.S_at(k), cost.L_at(k)
    Sig, Th, P0 = window_covariances(system, k, anchor, P)
    inn = InnovationsProblem(S, L, model, idx, cost.dz)
    g = GammaProblem(S, Sig, idx, cost.dz)
    return inn, g, _eta(S, L, Th, idx, cost.dz), float(np.trace(L.T @ S @ L @ P0))


def random_system(rng, n=3, dx=3, dy=(2, 1, 3), corr_R=True):
    A = rng.standard_normal((dx, dx))
    A *= 0.9 / max(abs(np.linalg.eigvals(A)))
    C = [rng.standard_normal((d, dx)) for d in dy[:n]]
    R = []
    for d in dy[:n]:
        B = rng.standard_normal((d, d))
        R.append(B @ B.T + 0.3 * np.eye(d) if corr_R else np.diag(rng.uniform(0.2, 1.0, d)))
    Bq = rng.standard_normal((dx, dx))
    return LinearGaussianSystem(A=A, Q=Bq @ Bq.T / dx + 0.1 * np.eye(dx), Sigma_x=np.eye(dx), C=C, R=R)


@pytest.mark.parametrize("n", [4, 5, 6])
def test_innovations_match_dense_on_platoons(n):
    inn, g, eta, tr = window_problems(LinearGaussianSystem.platoon(n), TeamCost.platoon(n, 100.0), CommGraph.line(n))
    F, J = inn.solve()
    Fd = g.solve(eta, method="dense")
    J_dense = tr - sum(float(np.sum(f * e)) for f, e in zip(Fd, eta))  # eq. (35): accurate at these sizes
    assert J == pytest.approx(J_dense, rel=1e-10)
    assert inn.gains_cost(Fd) == pytest.approx(J_dense, rel=1e-10)
    for a, b in zip(F, Fd):
        np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-7 * max(abs(b).max(), 1.0))
    res = g.apply(F)  # the innovation-coordinate gains solve the original Gamma F = eta
    for r, e in zip(res, eta):
        np.testing.assert_allclose(r, e, rtol=1e-6, atol=1e-8 * max(abs(e).max(), 1.0))


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("corr_R", [True, False])
def test_innovations_match_dense_on_random_systems(seed, corr_R):
    """Any A, C (d_y < d_x and > d_x), correlated or diagonal R, directed delays, a transient (anchor 0, P = Sigma_x) window."""
    rng = np.random.default_rng(seed)
    system = random_system(rng, corr_R=corr_R)
    B = rng.standard_normal((3 * 2, 3 * 2))
    cost = TeamCost(S=B @ B.T + np.eye(6), L=rng.standard_normal((6, 3)), n_agents=3)
    graph = CommGraph(3, ((0, 1, 1), (1, 2, 2), (2, 0, 1)))
    for k, P in [(None, None), (1, system.Sigma_x)]:
        inn, g, eta, tr = window_problems(system, cost, graph, k=k, P=P)
        F, J = inn.solve(rtol=1e-13)
        Fd = g.solve(eta, method="dense")
        J_dense = tr - sum(float(np.sum(f * e)) for f, e in zip(Fd, eta))
        assert J == pytest.approx(J_dense, rel=1e-10)
        for a, b in zip(F, Fd):
            np.testing.assert_allclose(a, b, rtol=1e-7, atol=1e-9)


def test_gains_cost_is_the_team_cost_of_any_gains():
    rng = np.random.default_rng(3)
    inn, g, eta, tr = window_problems(LinearGaussianSystem.platoon(5), TeamCost.platoon(5, 10.0), CommGraph.line(5))
    F = [rng.standard_normal((g.dz, len(ix))) * 0.3 for ix in g.idx]
    assert inn.gains_cost(F) == pytest.approx(gains_team_cost(g, eta, F, tr), rel=1e-9)


def test_design_uses_innovations_when_cg_is_chosen_and_agrees_with_dense():
    n = 6
    system, cost, graph = LinearGaussianSystem.platoon(n), TeamCost.platoon(n, 100.0), CommGraph.line(n)
    st = InformationStructure.from_graph(graph)
    idx = [_local_index(system, st, i, n - 2, 0) for i in range(n)]
    assert choose_solver(cost.S_at(0), idx, cost.dz, (n - 1) * n * n) == "cg"
    d = design_mtmse(system, cost, graph)
    dd = design_mtmse(system, cost, graph, method="dense")
    assert d.info["gamma"]["coordinates"] == "innovations" and d.info["gamma"]["iterations"] > 0
    assert dd.info["gamma"]["method"] == "dense"
    assert d.average_cost == pytest.approx(dd.average_cost, rel=1e-10)
    for a, b in zip(d.steady_gains, dd.steady_gains):
        np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-7)
    # the transient steps k < c take the same path (anchor 0, P = Sigma_x)
    for k in range(st.common_lag - 1):
        for a, b in zip(d.gain_at(k), dd.gain_at(k)):
            np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-7)


def test_innovations_edge_cases():
    n = 4
    system, cost, graph = LinearGaussianSystem.platoon(n), TeamCost.platoon(n, 10.0), CommGraph.line(n)
    inn, g, eta, tr = window_problems(system, cost, graph)
    # an agent without local data: its gain is empty and the rest still solves Gamma F = eta
    idx = [ix if i else np.zeros(0, int) for i, ix in enumerate(g.idx)]
    inn0 = InnovationsProblem(inn.S, inn.L, inn.model, idx, inn.dz)
    g0 = GammaProblem(g.S, g.Sigma, idx, g.dz)
    eta0 = [e if i else np.zeros((g.dz, 0)) for i, e in enumerate(eta)]
    F, J = inn0.solve()
    assert F[0].shape == (g.dz, 0)
    Fd = g0.solve(eta0, method="dense")
    assert J == pytest.approx(tr - sum(float(np.sum(f * e)) for f, e in zip(Fd, eta0)), rel=1e-10)
    with pytest.raises(ConvergenceError, match="innovation coordinates"):
        InnovationsProblem(inn.S, inn.L, inn.model, g.idx, inn.dz).solve(max_iter=1, rtol=1e-15)
    bad = WindowModel(inn.model.A, inn.model.Q, inn.model.C, [-np.eye(r.shape[0]) for r in inn.model.R], inn.model.P0)
    with pytest.raises(NotPositiveDefiniteError):
        InnovationsProblem(inn.S, inn.L, bad, g.idx, inn.dz)


def test_innovations_pay_for_platoons_not_for_the_uav_formation():
    from teamkf.estimators.gamma import innovations_pays

    for kind, n, expected in [("platoon", 4, True), ("platoon", 12, True), ("uav", 10, False), ("uav", 300, False)]:
        if kind == "platoon":
            system, cost, graph = LinearGaussianSystem.platoon(n), TeamCost.platoon(n, 100.0), CommGraph.line(n)
        else:
            system, cost, graph = LinearGaussianSystem.uav_formation(n), TeamCost.average_tracking(n, 10.0 * n * n), CommGraph.complete(n, 2)
        st = InformationStructure.from_graph(graph)
        c = st.common_lag
        idx = [_local_index(system, st, i, c - 1, 0) for i in range(n)]
        assert innovations_pays(cost.S_at(0), idx, cost.dz, system.dx, system.dy_total, c) is expected
