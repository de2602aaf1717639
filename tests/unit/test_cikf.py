"""CIKF (Das & Moura 2016): pseudo-state model, corrected covariance iterations, gains, online filter, validation."""

from __future__ import annotations

import numpy as np
import pytest

from teamkf import CommGraph, LinearGaussianSystem, TeamCost
from teamkf.estimators.cikf import CIKFDesign, design_cikf, pseudo_state_model, tracking_bound
from teamkf.estimators.kalman import design_centralized
from teamkf.estimators.riccati import is_detectable
from teamkf.exceptions import ArgumentError, DetectabilityError, GraphError, InformationStructureError, ShapeError
from teamkf.simulation.runtime import run_graph
from teamkf.simulation.sampling import sample_paths
from teamkf.study.random_field import random_field, random_field_instance

from ..helpers import eq14_information, joint_moments


# ---------------------------------------------------------------------------
# instances
# ---------------------------------------------------------------------------
def small_field(seed=1, M=15, N=6):
    """A Section VII-A field with three groups of five sites: G singular, no agent detects alone."""
    return random_field(M, N, rng=seed)


def invertible_instance():
    """Every site observed (G invertible), ring of 4 agents, unstable A."""
    rng = np.random.default_rng(7)
    M, N = 4, 4
    A = 0.3 * rng.standard_normal((M, M)) + 1.02 * np.eye(M)
    Q = np.eye(M) + 0.2 * np.ones((M, M))
    C = [np.eye(M)[[n, (n + 1) % M]] for n in range(N)]
    R = [np.array([[2.0, 0.3], [0.3, 1.0]]) for _ in range(N)]
    return LinearGaussianSystem(A=A, Q=Q, Sigma_x=3.0 * np.eye(M), C=C, R=R), CommGraph.ring(N)


def singular_instance():
    """Sites 4 and 5 unobserved (G singular, rank 4) but reached through A; line graph of 4 agents."""
    rng = np.random.default_rng(3)
    M, N = 6, 4
    A = 0.4 * rng.uniform(0, 1, (M, M)) * (rng.uniform(0, 1, (M, M)) < 0.5) + 0.9 * np.eye(M)
    A[4, 0] = A[5, 2] = 0.5  # unobserved sites feed from observed ones ...
    A[0, 4] = A[2, 5] = 0.6  # ... and back, so (A, H) stays detectable
    A *= 1.05 / np.linalg.norm(A, 2)
    C = [np.eye(M)[[0, 1]], np.eye(M)[[1, 2]], np.eye(M)[[2, 3]], np.eye(M)[[3, 0]]]
    R = [np.diag([1.5, 0.7]) for _ in range(N)]
    sysm = LinearGaussianSystem(A=A, Q=np.eye(M), Sigma_x=4.0 * np.eye(M), C=C, R=R)
    assert is_detectable(A, sysm.C_stack(0))
    return sysm, CommGraph.line(N)


# ---------------------------------------------------------------------------
# reference: direct propagation of the joint covariance of [e; ε] in the paper's coordinates
# ---------------------------------------------------------------------------
def joint_reference(d: CIKFDesign, T: int):
    """Ξ = cov([e; ε]) from Lemma 2 (30)-(33) with Ȟ_n kept literally and the gains of eqs. (60)-(63).

    Returns per step the predicted and filtered joint covariances (2NM x 2NM).
    """
    sysm, m = d.system, d.model
    N, M = sysm.n_agents, sysm.dx
    A, V, S0 = sysm.A_at(0), sysm.Q_at(0), sysm.Sigma_x
    from scipy.linalg import block_diag

    G = m.G
    Dt, Dc, Db = block_diag(*m.H_tilde), block_diag(*m.H_check), block_diag(*m.H_bar)
    J = np.ones((N, N))
    I = np.eye(N * M)
    IG = np.kron(np.eye(N), G)
    Fp = np.block([[np.kron(np.eye(N), m.A_tilde), np.kron(np.eye(N), m.A_check)], [np.zeros((N * M, N * M)), np.kron(np.eye(N), A)]])
    Qp = np.block([[np.kron(J, G @ V @ G), np.kron(J, G @ V)], [np.kron(J, V @ G), np.kron(J, V)]])
    Xi = np.block([[np.kron(J, G @ S0 @ G), np.kron(J, G @ S0)], [np.kron(J, S0 @ G), np.kron(J, S0)]])
    pred, filt = [], []
    for k in range(T):
        pred.append(Xi)
        g = d.paper_gains(k)
        BC, BI, K = g["B_C"], g["B_I"], g["K"]
        Mf = I - BC - BI @ Dt
        W = BI @ Dc
        Fu = np.block([[Mf, -W], [K @ Mf, I - K @ IG - K @ W]])
        Nb = np.vstack([BI, K @ BI])
        Xi = Fu @ Xi @ Fu.T + Nb @ Db @ Nb.T
        filt.append(Xi)
        Xi = Fp @ Xi @ Fp.T + Qp
    return pred, filt


def _diag_traces(X, N, M, lower: bool):
    off = N * M if lower else 0
    return np.array([np.trace(X[off + n * M : off + (n + 1) * M, off + n * M : off + (n + 1) * M]) for n in range(N)])


# ---------------------------------------------------------------------------
# Proposition 1
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("make", [invertible_instance, singular_instance, small_field])
def test_pseudo_state_model_identities(make):
    sysm, _ = make()
    m = pseudo_state_model(sysm)
    A = sysm.A_at(0)
    G, Gp, It = m.G, m.G_pinv, m.I_tilde
    assert np.allclose(G @ Gp @ G, G) and np.allclose(Gp @ G @ Gp, Gp)
    assert np.allclose(It, It @ It) and np.allclose(G @ It, 0)
    # (9): G A x = Ã G x + Ǎ x for every x; (10): H̄_n x = H̃_n G x + Ȟ_n x
    assert np.allclose(G @ A, m.A_tilde @ G + m.A_check)
    for n in range(sysm.n_agents):
        assert np.allclose(m.H_bar[n], m.H_tilde[n] @ G + m.H_check[n])
    # Ȟ_n = H̄_n Ĩ vanishes identically (null G = ∩ null H̄_n), Ǎ does not when G is singular
    assert np.abs(m.H_check).max() <= 1e-12 * np.abs(m.H_bar).max()
    assert m.invertible == (np.abs(m.A_check).max() < 1e-12)
    # reduced coordinates reproduce the full ones on range(G)
    U = m.U
    assert np.allclose(U @ m.A_tilde_r @ U.T, m.A_tilde)
    assert np.allclose(U @ m.A_check_r, m.A_check)
    assert np.allclose(U @ m.G_r, G)
    for n in range(sysm.n_agents):
        assert np.allclose(m.innov_map[n] @ m.C_tilde[n] @ U.T, m.H_tilde[n])


def test_singular_instance_really_singular():
    assert random_field_instance(15, 6, rng=1).unobserved.size > 0  # small_field leaves sites unobserved
    for make in (singular_instance, small_field):
        sysm, _ = make()
        m = pseudo_state_model(sysm)
        assert not m.invertible and m.rank < sysm.dx
    assert pseudo_state_model(invertible_instance()[0]).invertible


# ---------------------------------------------------------------------------
# the corrected iterations against the joint covariance of [e; ε]
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("make", [invertible_instance, singular_instance, small_field])
def test_iterations_match_joint_covariance(make):
    sysm, graph = make()
    T = 12
    d = design_cikf(sysm, None, graph, T)
    pred, filt = joint_reference(d, T)
    N, M = sysm.n_agents, sysm.dx
    for k in range(T):
        for n in range(N):
            sl = slice(N * M + n * M, N * M + (n + 1) * M)
            assert np.allclose(pred[k][sl, sl], d.Sigma_pred[k, n], rtol=1e-8, atol=1e-8 * np.abs(d.Sigma_pred[k]).max())
            assert np.allclose(filt[k][sl, sl], d.Sigma_filt[k, n], rtol=1e-8, atol=1e-8 * np.abs(d.Sigma_filt[k]).max())
        assert np.allclose(_diag_traces(pred[k], N, M, lower=False), d.P_pred_trace[k], rtol=1e-8)
    # the stage cost is the sum of the agents' filtered MSEs (S = I, L = 1 ⊗ I)
    assert np.allclose(d.stage_costs, [sum(_diag_traces(f, N, M, lower=True)) for f in filt], rtol=1e-9)


@pytest.mark.parametrize("make", [invertible_instance, singular_instance])
def test_gains_are_theorem4_optimal_in_full_coordinates(make):
    """Theorem 4 literally ((d+1)M-dimensional ν̃ with Ȟ terms, pseudo-inverse) gives the same filtered covariances."""
    sysm, graph = make()
    T = 6
    d = design_cikf(sysm, None, graph, T)
    pred, filt = joint_reference(d, T)
    m = d.model
    N, M = sysm.n_agents, sysm.dx
    from scipy.linalg import block_diag

    Dt, Dc, Db = block_diag(*m.H_tilde), block_diag(*m.H_check), block_diag(*m.H_bar)
    for k in range(T):
        Xi = pred[k]
        P = Xi[: N * M, : N * M]
        # after the pseudo-state update only (design gains): cov([e_{k|k}; ε_{k|k-1}])
        g = d.paper_gains(k)
        Mf = np.eye(N * M) - g["B_C"] - g["B_I"] @ Dt
        Fm = np.block([[Mf, -g["B_I"] @ Dc], [np.zeros((N * M, N * M)), np.eye(N * M)]])
        Nm = np.vstack([g["B_I"], np.zeros((N * M, N * M))])
        Xm = Fm @ Xi @ Fm.T + Nm @ Db @ Nm.T
        for n in range(N):
            b = lambda X, i, j: X[i * M : (i + 1) * M, j * M : (j + 1) * M]  # noqa: E731
            nb = d.neighbors[n]
            # ν̃ = [e^n - e^l ...; H̃ e^n + Ȟ ε^n + H' R^-1 r^n]; its rows as maps of [e; ε] plus noise
            rows = []
            for l in nb:
                Rw = np.zeros((M, 2 * N * M))
                Rw[:, n * M : (n + 1) * M] += np.eye(M)
                Rw[:, l * M : (l + 1) * M] -= np.eye(M)
                rows.append(Rw)
            Rw = np.zeros((M, 2 * N * M))
            Rw[:, n * M : (n + 1) * M] = m.H_tilde[n]
            Rw[:, N * M + n * M : N * M + (n + 1) * M] = m.H_check[n]
            rows.append(Rw)
            D = np.vstack(rows)
            Snu = D @ Xi @ D.T
            Snu[-M:, -M:] += m.H_bar[n]
            En = np.zeros((M, 2 * N * M))
            En[:, n * M : (n + 1) * M] = np.eye(M)
            Sey = En @ Xi @ D.T
            Pf_opt = b(P, n, n) - Sey @ np.linalg.pinv(Snu, rcond=1e-11, hermitian=True) @ Sey.T
            Pf_design = b(filt[k], n, n)
            assert np.trace(Pf_design) == pytest.approx(np.trace(Pf_opt), rel=1e-6)
            # K^n: ν = G ε^n - e^n_{k|k} (M-dimensional), optimal filtered Σ^{nn} = Σ^{nn} - Σ_xν Σ_ν^+ Σ_xν'
            Nu = np.zeros((M, 2 * N * M))
            Nu[:, N * M + n * M : N * M + (n + 1) * M] = m.G
            Nu[:, n * M : (n + 1) * M] -= np.eye(M)
            Ex = np.zeros((M, 2 * N * M))
            Ex[:, N * M + n * M : N * M + (n + 1) * M] = np.eye(M)
            S_nu, S_xnu = Nu @ Xm @ Nu.T, Ex @ Xm @ Nu.T
            Sf_opt = Ex @ Xm @ Ex.T - S_xnu @ np.linalg.pinv(S_nu, rcond=1e-11, hermitian=True) @ S_xnu.T
            assert np.trace(d.Sigma_filt[k, n]) == pytest.approx(np.trace(Sf_opt), rel=1e-6)


def test_dense_method_matches_structured():
    sysm, graph = small_field()
    a = design_cikf(sysm, None, graph, 8, method="structured")
    b = design_cikf(sysm, None, graph, 8, method="dense")
    assert np.allclose(a.Sigma_pred, b.Sigma_pred, rtol=1e-9, atol=1e-9)
    assert np.allclose(a.stage_costs, b.stage_costs, rtol=1e-10)


@pytest.mark.parametrize("make", [invertible_instance, singular_instance, small_field])
def test_printed_equations_are_off(make):
    """Eqs. (43) and (45) as extracted predict an MSE that is not the filter's (errata)."""
    sysm, graph = make()
    T = 10
    lit = design_cikf(sysm, None, graph, T, equations="printed")
    true = design_cikf(sysm, None, graph, T, gains=lit)  # the true covariances of the printed design's gains
    pred, act = lit.mse("predictor"), true.mse("predictor")
    with np.errstate(invalid="ignore", divide="ignore"):
        gap_db = np.where(pred > 0, np.abs(10 * np.log10(pred / act)), np.inf)
    assert gap_db[0] == 0.0 and gap_db.max() > 0.5  # 0.7 dB, 2.1 dB and a negative "MSE" on these three
    good = design_cikf(sysm, None, graph, T)
    assert np.allclose(design_cikf(sysm, None, graph, T, gains=good).stage_costs, good.stage_costs, rtol=1e-10)


def test_rcond_choice_is_immaterial():
    """Cut-offs at or below the default agree to 1e-4 dB; a coarse 1e-7 costs a few thousandths of a dB."""
    sysm, graph = small_field()
    base = 10 * np.log10(design_cikf(sysm, None, graph, 40).mse("predictor"))
    for rc, tol in ((1e-11, 1e-4), (1e-13, 1e-4), (1e-7, 2e-2)):
        other = 10 * np.log10(design_cikf(sysm, None, graph, 40, rcond=rc).mse("predictor"))
        assert np.abs(other - base).max() < tol
        assert other[-1] >= base[-1] - 1e-6  # never better than the default here


def test_step0_consensus_gains_vanish():
    sysm, graph = small_field()
    d = design_cikf(sysm, None, graph, 3)
    scale = max(np.abs(b).max() for b in d.B_innov[0])
    assert all(np.abs(b).max() <= 1e-12 * scale for b in d.B_cons[0])  # round-off of the eigenvectors only
    assert any(np.abs(b).max() > 0.0 for b in d.B_cons[1])


# ---------------------------------------------------------------------------
# Algorithm 1 online
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("form", ["filter", "predictor"])
def test_run_graph_simulate_and_errors_agree(form):
    sysm, graph = small_field()
    d = design_cikf(sysm, None, graph, 15, form=form)
    paths = sample_paths(sysm, 15, 40, rng=11)
    z_graph = run_graph(d.graph_agents(), graph, paths.y)
    z_sim = d.simulate(paths.y)
    assert np.allclose(z_graph, z_sim, rtol=1e-10, atol=1e-10)
    e = d.errors(paths)
    Lx = np.stack([paths.x[:, k] @ d.cost.L_at(k).T for k in range(15)], axis=1)
    assert np.allclose(Lx - z_sim, e, atol=1e-9 * max(1.0, np.abs(Lx).max()))


def test_agent_needs_its_neighbours_messages():
    sysm, graph = small_field()
    d = design_cikf(sysm, None, graph, 4)
    ag = d.graph_agents()[0]
    st = ag.init_state(2)
    st, z, msg = ag.step(st, 0, np.zeros((2, 2)), [])
    assert msg.shape == (2, sysm.dx)
    with pytest.raises(InformationStructureError, match="neighbours"):
        ag.step(st, 1, np.zeros((2, 2)), [])


# ---------------------------------------------------------------------------
# bounds: centralized never beaten, MTMSE no worse per agent
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("make", [invertible_instance, singular_instance, small_field])
def test_centralized_never_beaten(make):
    sysm, graph = make()
    T = 20
    d = design_cikf(sysm, None, graph, T)
    N, M = sysm.n_agents, sysm.dx
    cf = design_centralized(sysm, TeamCost.mse(N, M), horizon=T, form="filter")
    cp = design_centralized(sysm, TeamCost.mse(N, M), horizon=T, form="predictor")
    per_f = d.mse("filter", per_agent=True)
    per_p = d.mse("predictor", per_agent=True)
    ckf_f = cf.stage_costs / N
    ckf_p = cp.stage_costs / N
    assert np.all(per_f >= ckf_f[:, None] * (1 - 1e-9))
    assert np.all(per_p >= ckf_p[:, None] * (1 - 1e-9))
    assert np.allclose(per_p[0], ckf_p[0])  # both start from Σ0


def _per_agent_mmse(sysm, graph, k):
    """tr var(x(k) | I_n(k)) by conditioning the joint Gaussian on agent n's graph information (unit delays)."""
    X, Y, Cov = joint_moments(sysm, k)
    out = []
    for n in range(sysm.n_agents):
        info = sorted(eq14_information(graph, n, k))
        My = np.vstack([Y[p] for p in info])
        Cxx = X[k] @ Cov @ X[k].T
        Cxy = X[k] @ Cov @ My.T
        Cyy = My @ Cov @ My.T
        out.append(np.trace(Cxx - Cxy @ np.linalg.solve(Cyy, Cxy.T)))
    return np.array(out)


def test_mtmse_with_neighbourhood_sharing_is_no_worse_per_agent():
    from teamkf import design_mtmse

    sysm, graph = random_field(9, 4, rng=2)
    T = 7
    N, M = sysm.n_agents, sysm.dx
    d = design_cikf(sysm, None, graph, T)
    mt = design_mtmse(sysm, TeamCost.mse(N, M), graph, T)
    cikf_agents = d.mse("filter", per_agent=True)
    for k in range(T):
        mm = _per_agent_mmse(sysm, graph, k)
        assert np.all(mm <= cikf_agents[k] * (1 + 1e-9))
        assert mt.stage_costs[k] == pytest.approx(mm.sum(), rel=1e-7)  # S = I: MTMSE = per-agent MMSE
    assert np.all(mt.stage_costs <= d.stage_costs * (1 + 1e-9))


# ---------------------------------------------------------------------------
# general cost, forms
# ---------------------------------------------------------------------------
def test_general_cost_stage_costs_match_monte_carlo_errors():
    sysm, graph = invertible_instance()
    N, M = sysm.n_agents, sysm.dx
    rng = np.random.default_rng(0)
    L = rng.standard_normal((N * 2, M))
    B = rng.standard_normal((2 * N, 2 * N))
    cost = TeamCost(S=B @ B.T + np.eye(2 * N), L=L, n_agents=N)
    d = design_cikf(sysm, cost, graph, 6)
    # analytic: blockdiag(L_n) Σ blockdiag(L_n)' from the joint reference
    _, filt = joint_reference(d, 6)
    from scipy.linalg import block_diag

    Lb = block_diag(*[cost.L_block(n) for n in range(N)])
    want = [np.sum(cost.S_at(k) * (Lb @ f[N * M :, N * M :] @ Lb.T)) for k, f in enumerate(filt)]
    assert np.allclose(d.stage_costs, want, rtol=1e-9)
    assert d.summary()["method"] == "analytic"


# ---------------------------------------------------------------------------
# tracking capacity: bound with given gains
# ---------------------------------------------------------------------------
def test_tracking_bound_with_gains():
    sysm, graph = singular_instance()
    d = design_cikf(sysm, None, graph, 10)
    m = d.model
    b_range = d.tracking_bound()
    b_full = tracking_bound(d, 9, subspace="full")
    assert 0 < b_full <= b_range
    assert b_full <= m.lambda_1 / m.lambda_m + 1e-12  # printed M is the identity on null(G)^N
    # the bound is λ1/(λm ||M||) computed densely
    rows = d.m_rows(9)
    r, N = m.rank, sysm.n_agents
    Mf = np.zeros((N * r, N * r))
    for n, row in enumerate(rows):
        cols = np.concatenate([np.arange(l * r, (l + 1) * r) for l in (n, *d.neighbors[n])])
        Mf[n * r : (n + 1) * r, cols] = row
    assert b_range == pytest.approx(m.lambda_1 / (m.lambda_m * np.linalg.norm(Mf, 2)), rel=1e-9)


# ---------------------------------------------------------------------------
# validation
# ---------------------------------------------------------------------------
def test_validation_errors():
    sysm, graph = small_field()
    with pytest.raises(GraphError, match="delay 1"):
        design_cikf(sysm, None, graph.with_delay(2), 5)
    with pytest.raises(GraphError, match="agents"):
        design_cikf(sysm, None, CommGraph.line(3), 5)
    with pytest.raises(GraphError, match="CommGraph"):
        design_cikf(sysm, None, "ring", 5)
    with pytest.raises(ShapeError, match="horizon"):
        design_cikf(sysm, None, graph, None)
    with pytest.raises(ArgumentError, match="horizon"):
        design_cikf(sysm, None, graph, 0)
    with pytest.raises(ShapeError, match="rcond"):
        design_cikf(sysm, None, graph, 5, rcond=0.0)
    with pytest.raises(ShapeError, match="form"):
        design_cikf(sysm, None, graph, 5, form="smoother")
    with pytest.raises(ShapeError, match="method"):
        design_cikf(sysm, None, graph, 5, method="sparse")
    with pytest.raises(ShapeError, match="cost"):
        design_cikf(sysm, TeamCost.mse(3, 2), graph, 5)
    with pytest.raises(ArgumentError, match="system"):
        design_cikf("sys", None, graph, 5)
    # (A, H) not detectable: an unstable mode nobody sees
    bad = LinearGaussianSystem(A=np.diag([1.2, 0.5]), Q=1.0, Sigma_x=1.0, C=[[[0.0, 1.0]], [[0.0, 1.0]]], R=1.0)
    with pytest.raises(DetectabilityError, match="detectable"):
        design_cikf(bad, None, CommGraph.line(2), 5)
    # time-varying systems are out of scope
    tv = LinearGaussianSystem(A=[np.eye(2), np.eye(2)], Q=1.0, Sigma_x=1.0, C=[np.eye(2), np.eye(2)], R=1.0)
    with pytest.raises(ShapeError, match="CIKF"):
        design_cikf(tv, None, CommGraph.line(2), 2)
    d = design_cikf(sysm, None, graph, 5)
    paths = sample_paths(sysm, 6, 3, rng=0)
    with pytest.raises(ShapeError, match="horizon"):
        d.errors(paths)
    with pytest.raises(ShapeError, match="list of"):
        d.simulate(paths.y[:2])
    with pytest.raises(ShapeError, match="step"):
        d.gains(5)
    with pytest.raises(NotImplementedError, match="run_graph"):
        d.agents()


# ---------------------------------------------------------------------------
# the Section VII-A builder
# ---------------------------------------------------------------------------
def test_random_field_properties():
    inst = random_field_instance(rng=0)
    sysm, graph = inst.system, inst.graph
    A = sysm.A_at(0)
    assert sysm.dx == 50 and sysm.n_agents == 50 and set(sysm.dy) == {2}
    assert np.linalg.norm(A, 2) == pytest.approx(1.05)
    assert np.all(A >= 0) and np.all(A < 1.05)
    assert np.linalg.norm(sysm.Q_at(0), 2) == pytest.approx(4.0)
    assert np.linalg.norm(sysm.Sigma_x, 2) == pytest.approx(16.0)
    assert all(np.linalg.norm(sysm.R_at(n, 0), 2) == pytest.approx(8.0) for n in range(50))
    assert all(np.all(np.linalg.eigvalsh(sysm.R_at(n, 0)) > 0) for n in range(50))
    for c in sysm.C:  # 0-1 rows, one site each
        assert set(np.unique(c)) <= {0.0, 1.0} and np.all(c[0].sum(axis=1) == 1)
    # degree-4 lattice (plus the diagonal)
    off = (A > 0) & ~np.eye(50, dtype=bool)
    assert np.all(off.sum(axis=1) == 4)
    assert inst.n_edges == 138 and graph.is_strongly_connected()
    assert all(d == 1 for (_, _, d) in graph.edges)
    assert is_detectable(A, sysm.C_stack(0))
    assert not any(is_detectable(A, sysm.C_at(n, 0)) for n in range(50))
    assert inst.rho_A >= 1.0 and inst.n_unstable >= 3
    # seeded
    again = random_field_instance(rng=0)
    assert np.array_equal(again.system.A_at(0), A) and again.graph == graph


def test_random_field_validation():
    with pytest.raises(ShapeError, match="sites_per_agent"):
        random_field(5, 3, rng=0, sites_per_agent=6)
    with pytest.raises(ShapeError, match="rng"):
        random_field(15, 4, rng="seed")
    with pytest.raises(DetectabilityError, match="alone"):
        random_field(15, 6, rng=0, a_norm=0.9)  # a stable field: every agent detects it


def test_paper_gains_structure():
    """B^C has the Laplacian block pattern and annihilates 1 ⊗ y; B^I and K are block-diagonal (eqs. 60-63)."""
    sysm, graph = singular_instance()
    d = design_cikf(sysm, None, graph, 5)
    N, M = sysm.n_agents, sysm.dx
    g = d.paper_gains(3)
    BC = g["B_C"].reshape(N, M, N, M)
    for n in range(N):
        for l in range(N):
            if l != n and l not in d.neighbors[n]:
                assert np.all(BC[n, :, l, :] == 0.0)
                assert np.all(g["B_I"].reshape(N, M, N, M)[n, :, l, :] == 0.0)
                assert np.all(g["K"].reshape(N, M, N, M)[n, :, l, :] == 0.0)
    y = np.random.default_rng(0).standard_normal(M)
    assert np.allclose(g["B_C"] @ np.tile(y, N), 0.0, atol=1e-12)


def test_experiments_registered_and_quick_runs(tmp_path):
    from teamkf import experiments

    assert {"cikf-fig4", "cikf-capacity"} <= set(experiments.names())
    res = experiments.run("cikf-fig4", tmp_path, quick=True)
    data = res.data
    assert data["gap_db"] > 0 and data["worst_z"] < 4.0
    assert np.all(data["theory_cikf"] >= data["theory_ckf"] * (1 - 1e-9))
    ok = np.isfinite(data["filter_mtmse"])
    assert ok.sum() >= 10 and np.all(data["filter_mtmse"][ok] <= data["filter_cikf"][ok] * (1 + 1e-9))
    assert (tmp_path / "cikf-fig4.csv").exists() and len(res.rows) == 31
    cap = experiments.run("cikf-capacity", None, quick=True)
    assert len(cap.rows) == 7
    if cap.data["have_cvxpy"]:
        caps = [r["capacity (53)"] for r in cap.rows]
        assert all(b >= a * (1 - 1e-5) for a, b in zip(caps, caps[1:]))
