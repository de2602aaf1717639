"""Baseline families (local, diffusion, ci, kcf honest/ideal) on the exact engine of :mod:`teamkf.estimators.linear_team`.

Each family is held against a direct, independent implementation of its
published algorithm (explicit inverses, per-agent loops, row vectors) on the
same sampled path; its analytic cost against Monte Carlo; its graph agents
against the runtime's information discipline; and the limits it must reach.
"""

import numpy as np
import pytest

from teamkf import CommGraph, LinearGaussianSystem, TeamCost, design_centralized
from teamkf.estimators.ci import ci_weights, design_ci
from teamkf.estimators.diffusion import design_diffusion, diffusion_weights
from teamkf.estimators.hcmci import design_hcmci
from teamkf.estimators.icf import design_icf
from teamkf.estimators.kcf import design_kcf, kcf_schedules
from teamkf.estimators.local import design_local
from teamkf.estimators.registry import get_family
from teamkf.exceptions import ArgumentError, TeamkfError, UnsupportedOperationError
from teamkf.simulation.monte_carlo import monte_carlo
from teamkf.simulation.runtime import run_graph
from teamkf.simulation.sampling import sample_paths

inv = np.linalg.inv


def pd_system(rng, n, dx, dys, rho=0.95):
    """A random time-invariant system with invertible A (spectral radius rho) and positive definite Σ_x, Q, R."""
    A = rng.standard_normal((dx, dx))
    A *= rho / np.max(np.abs(np.linalg.eigvals(A)))

    def pd(d):
        M = rng.standard_normal((d, d))
        return M @ M.T / d + 0.3 * np.eye(d)

    return LinearGaussianSystem(A=A, Q=pd(dx), Sigma_x=pd(dx), C=[rng.standard_normal((d, dx)) for d in dys], R=[pd(d) for d in dys])


def pd_cost(rng, n, dx, dz=2):
    M = rng.standard_normal((n * dz, n * dz))
    return TeamCost(S=M @ M.T + 0.3 * np.eye(n * dz), L=rng.standard_normal((n * dz, dx)), n_agents=n)


def instance(seed, dx=3):
    rng = np.random.default_rng(seed)
    sys_ = pd_system(rng, 3, dx, [1, 2, 1])
    cost = pd_cost(rng, 3, dx)
    g = CommGraph(3, [(0, 1, 1), (1, 2, 2), (2, 0, 1), (1, 0, 3)])  # strongly connected, unequal delays
    return sys_, cost, g


# ---------------------------------------------------------------------------
# direct implementations (independent of the engine: explicit inverses, row vectors, per-agent loops)
# ---------------------------------------------------------------------------
def _comp(sys_, j, m):
    """y_j(k - m) as a measurement of x(k): (C Φ^-m, R + C Φ^-m Q_m Φ^-mᵀ Cᵀ), Q_m = Σ_{r<m} A^r Q A^rᵀ."""
    A, Q, C, R = sys_.A_at(0), sys_.Q_at(0), sys_.C_at(j, 0), sys_.R_at(j, 0)
    Phi_inv = inv(np.linalg.matrix_power(A, m))
    Qm = sum((np.linalg.matrix_power(A, r) @ Q @ np.linalg.matrix_power(A, r).T for r in range(m)), np.zeros_like(Q))
    Ct = C @ Phi_inv
    return Ct, R + Ct @ Qm @ Ct.T


def _sources(g, i, k, honest):
    if g is None:
        return []
    return [(j, k - g.delay(j, i)) for j in g.in_neighbors(i) if k - g.delay(j, i) >= 0] if honest else [(j, k) for j in g.in_neighbors(i)]


def direct(family, sys_, cost, g, y, honest, c=None, eps=0.1):
    """The published algorithms, run agent by agent on one batch y (list of (runs, T, d_y^i)); returns z (runs, T, n d_z)."""
    n, T, dx = sys_.n_agents, y[0].shape[1], sys_.dx
    runs = y[0].shape[0]
    A, Q = sys_.A_at(0), sys_.Q_at(0)
    xhat = {}  # (i, k) -> reported/combined estimate (diffusion, kcf), local estimate (ci)
    psi, xbar, Pf = {}, {}, {}
    Pbar = {i: sys_.Sigma_x for i in range(n)}
    z = np.zeros((runs, T, n * cost.dz))
    comm = None if family == "local" else g
    for k in range(T):
        for i in range(n):
            xbar[(i, k)] = np.zeros((runs, dx)) if k == 0 else xhat[(i, k - 1)] @ A.T
        for i in range(n):
            xb = xbar[(i, k)]
            info_src = [] if family in ("local", "ci") else _sources(comm, i, k, honest)
            S = np.zeros((dx, dx))
            q = np.zeros((runs, dx))
            for j, s in [(i, k), *info_src]:
                Ct, Rt = _comp(sys_, j, k - s)
                S += Ct.T @ inv(Rt) @ Ct
                q += y[j][:, s] @ (Ct.T @ inv(Rt)).T
            M = inv(inv(Pbar[i]) + S)
            Pf[(i, k)] = M
            if family == "kcf":
                cons = sum(((xbar[(j, s)] @ np.linalg.matrix_power(A, k - s).T - xb) for j, s in info_src), np.zeros((runs, dx)))
                gam = eps / (1 + np.linalg.norm(M, "fro"))
                xhat[(i, k)] = xb + (q - xb @ S.T) @ M.T + gam * cons @ M.T
            else:
                psi[(i, k)] = xb + (q - xb @ S.T) @ M.T
            Pbar[i] = A @ M @ A.T + Q
        for i in range(n):
            if family in ("local", "diffusion"):
                used = _sources(comm, i, k, honest)
                cii = c[i, i] + sum(c[j, i] for j in (g.in_neighbors(i) if comm is not None else []) if j not in [u for u, _ in used])
                xhat[(i, k)] = cii * psi[(i, k)] + sum((c[j, i] * psi[(j, s)] @ np.linalg.matrix_power(A, k - s).T for j, s in used), 0)
                out = xhat[(i, k)]
            elif family == "ci":
                xhat[(i, k)] = psi[(i, k)]
                srcs = [(i, k), *_sources(g, i, k, honest)]
                Ys, xs = [], []
                for j, s in srcs:
                    Phi = np.linalg.matrix_power(A, k - s)
                    Qm = sum((np.linalg.matrix_power(A, r) @ Q @ np.linalg.matrix_power(A, r).T for r in range(k - s)), np.zeros_like(Q))
                    Ys.append(inv(Phi @ Pf[(j, s)] @ Phi.T + Qm))
                    xs.append(psi[(j, s)] @ Phi.T)
                w = ci_weights(Ys)
                P = inv(sum(wj * Y for wj, Y in zip(w, Ys)))
                out = sum(wj * xj @ (P @ Y).T for wj, Y, xj in zip(w, Ys, xs))
            else:
                out = xhat[(i, k)]
            z[:, k, i * cost.dz : (i + 1) * cost.dz] = out @ cost.L_block(i, k).T
    return z


FAMILIES = ("local", "diffusion", "ci", "kcf", "icf", "hcmci")
DESIGNS = {"local": design_local, "diffusion": design_diffusion, "ci": design_ci, "kcf": design_kcf, "icf": design_icf, "hcmci": design_hcmci}


def design(family, sys_, cost, g, T, variant, **kw):
    return DESIGNS[family](sys_, cost, g, T, variant=variant, **kw)


def direct_consensus(family, sys_, cost, g, y, K, eps=None, honest=False):
    """ICF (Kamal et al. 2013, Algorithm 1) and HCMCI (Battistelli et al. 2015, Table I), run per agent with explicit inverses.

    honest: one iteration per step on the in-neighbours' messages sent at k - τ_ji, delay-compensated
    (information pairs through the prediction with process noise, novelties of y_j(s) as measurements of x(k)).
    """
    n, T, dx = sys_.n_agents, y[0].shape[1], sys_.dx
    runs = y[0].shape[0]
    A, Q = sys_.A_at(0), sys_.Q_at(0)
    U = [sys_.C_at(i, 0).T @ inv(sys_.R_at(i, 0)) @ sys_.C_at(i, 0) for i in range(n)]
    Gm = [sys_.C_at(i, 0).T @ inv(sys_.R_at(i, 0)) for i in range(n)]
    ins = [list(g.in_neighbors(i)) for i in range(n)]
    pi = diffusion_weights(g).T
    Jb = [inv(sys_.Sigma_x)] * n
    xb = [np.zeros((runs, dx))] * n
    z = np.zeros((runs, T, n * cost.dz))
    hist = {}

    def predict_pair(Y, m):
        Phi = np.linalg.matrix_power(A, m)
        Qm = sum((np.linalg.matrix_power(A, r) @ Q @ np.linalg.matrix_power(A, r).T for r in range(m)), np.zeros_like(Q))
        Yn = inv(Phi @ inv(Y) @ Phi.T + Qm)
        return Yn, Yn @ Phi

    for k in range(T):
        if family == "icf":
            V = [Jb[i] / n + U[i] for i in range(n)]
            v = [xb[i] @ (Jb[i] / n).T + y[i][:, k] @ Gm[i].T for i in range(n)]
            if honest:
                V2, v2 = [], []
                for i in range(n):
                    Vi, vi = V[i].copy(), v[i].copy()
                    for j, s in _sources(g, i, k, True):
                        Yn, Tm = predict_pair(hist[(j, s)][0], k - s)
                        Vi += eps * (Yn - V[i])
                        vi += eps * (hist[(j, s)][1] @ Tm.T - v[i])
                    V2.append(Vi)
                    v2.append(vi)
                V, v = V2, v2
            else:
                for _ in range(K):
                    V = [V[i] + eps * sum((V[j] - V[i] for j in ins[i]), np.zeros((dx, dx))) for i in range(n)]
                    v = [v[i] + eps * sum((v[j] - v[i] for j in ins[i]), np.zeros((runs, dx))) for i in range(n)]
            xh = [v[i] @ inv(V[i]).T for i in range(n)]
            for i in range(n):
                hist[(i, k)] = (V[i], xh[i])
            Jb = [inv(A @ inv(n * V[i]) @ A.T + Q) for i in range(n)]
        else:
            O = [Jb[i] for i in range(n)]
            q = [xb[i] @ Jb[i].T for i in range(n)]
            dO = list(U)
            dq = [y[i][:, k] @ Gm[i].T for i in range(n)]
            if honest:
                O2, q2, dO2, dq2 = [], [], [], []
                for i in range(n):
                    heard = _sources(g, i, k, True)
                    w = pi[i, i] + sum(pi[i, j] for j in ins[i] if j not in [a for a, _ in heard])
                    a, b, c, d = w * O[i], w * q[i], w * dO[i], w * dq[i]
                    for j, s in heard:
                        Yn, Tm = predict_pair(hist[(j, s)][0], k - s)
                        Ct, Rt = _comp(sys_, j, k - s)
                        a, b = a + pi[i, j] * Yn, b + pi[i, j] * hist[(j, s)][1] @ Tm.T
                        c, d = c + pi[i, j] * Ct.T @ inv(Rt) @ Ct, d + pi[i, j] * y[j][:, s] @ (Ct.T @ inv(Rt)).T
                    O2.append(a)
                    q2.append(b)
                    dO2.append(c)
                    dq2.append(d)
                for i in range(n):
                    hist[(i, k)] = (O[i], xb[i])
                O, q, dO, dq = O2, q2, dO2, dq2
            else:
                for _ in range(K):
                    O = [pi[i, i] * O[i] + sum(pi[i, j] * O[j] for j in ins[i]) for i in range(n)]
                    q = [pi[i, i] * q[i] + sum(pi[i, j] * q[j] for j in ins[i]) for i in range(n)]
                    dO = [pi[i, i] * dO[i] + sum(pi[i, j] * dO[j] for j in ins[i]) for i in range(n)]
                    dq = [pi[i, i] * dq[i] + sum(pi[i, j] * dq[j] for j in ins[i]) for i in range(n)]
            Om = [O[i] + n * dO[i] for i in range(n)]
            xh = [(q[i] + n * dq[i]) @ inv(Om[i]).T for i in range(n)]
            Jb = [inv(A @ inv(Om[i]) @ A.T + Q) for i in range(n)]
        for i in range(n):
            z[:, k, i * cost.dz : (i + 1) * cost.dz] = xh[i] @ cost.L_block(i, k).T
        xb = [xh[i] @ A.T for i in range(n)]
    return z


@pytest.mark.parametrize("family", FAMILIES)
@pytest.mark.parametrize("variant", ("honest", "ideal"))
def test_matches_direct_implementation(family, variant):
    sys_, cost, g = instance(1)
    T = 9
    p = sample_paths(sys_, T, 4, rng=7)
    if family in ("icf", "hcmci"):
        d = design(family, sys_, cost, g, T, variant, iterations=3)
        ref = direct_consensus(family, sys_, cost, g, p.y, 3, eps=d.info.get("epsilon"), honest=variant == "honest")
    else:
        d = design(family, sys_, cost, g, T, variant)
        c = diffusion_weights(g) if family == "diffusion" else np.eye(3)
        ref = direct(family, sys_, cost, g, p.y, variant == "honest", c=c)
    z = d.filter(p.y)
    np.testing.assert_allclose(z, ref, rtol=1e-10, atol=1e-10 * np.abs(ref).max())
    # errors(paths) is the same linear map applied to the noises
    ex = np.stack([p.x[:, k] @ cost.L_at(k).T - z[:, k] for k in range(T)], axis=1)
    np.testing.assert_allclose(d.errors(p), ex, rtol=1e-9, atol=1e-10 * np.abs(ex).max())


def test_ideal_kcf_equals_the_independent_nominal_implementation():
    """The engine's ideal KCF and KCFDesign (the pre-0.2 code) agree on data and errors."""
    sys_, cost, g = instance(2)
    T = 12
    p = sample_paths(sys_, T, 3, rng=1)
    a = design_kcf(sys_, cost, g, T, variant="ideal", epsilon=0.3)
    b = kcf_schedules(sys_, cost, g, T, variant="ideal", epsilon=0.3)
    np.testing.assert_allclose(a.filter(p.y), b.simulate(p.y), rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(a.errors(p), b.errors(p), rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("family", FAMILIES)
@pytest.mark.parametrize("variant", ("honest", "ideal"))
def test_analytic_cost_equals_monte_carlo(family, variant):
    sys_, cost, g = instance(3)
    T = 12
    d = design(family, sys_, cost, g, T, variant)
    mc = monte_carlo({"d": d}, T, 3000, rng=11)["d"]
    zs = (mc.stage_mean - d.stage_costs) / mc.stage_sem
    assert np.all(np.abs(zs) < 4), (family, variant, zs)
    assert abs(mc.total_mean - d.total_cost) < 4 * mc.total_sem


@pytest.mark.parametrize("family", FAMILIES)
def test_honest_runtime_discipline(family):
    """run_graph(graph_agents) = filter; changing y_j(s) leaves agent i unchanged before s + l_ji (geodesic delay)."""
    sys_, cost, g = instance(4)
    T, s = 10, 1
    d = design(family, sys_, cost, g, T, "honest")
    p = sample_paths(sys_, T, 2, rng=3)
    z0 = run_graph(d.graph_agents(), g, p.y)
    np.testing.assert_allclose(z0, d.filter(p.y), rtol=1e-10, atol=1e-12)
    ell = g.geodesic_delays()
    dz = cost.dz
    for j in range(3):
        y = [yi.copy() for yi in p.y]
        y[j][:, s] += 0.5
        z1 = run_graph(d.graph_agents(), g, y)
        for i in range(3):
            lag = 0 if i == j else int(ell[j, i])
            np.testing.assert_array_equal(z0[:, : s + lag, i * dz : (i + 1) * dz], z1[:, : s + lag, i * dz : (i + 1) * dz])


@pytest.mark.parametrize("family", ("diffusion", "ci", "kcf", "icf", "hcmci"))
def test_ideal_has_no_graph_agents(family):
    sys_, cost, g = instance(5)
    with pytest.raises(UnsupportedOperationError):
        design(family, sys_, cost, g, 4, "ideal").graph_agents()


# ---------------------------------------------------------------------------
# limits
# ---------------------------------------------------------------------------
def test_diffusion_single_agent_is_the_kalman_filter():
    rng = np.random.default_rng(9)
    sys_ = pd_system(rng, 1, 3, [2])
    cost = pd_cost(rng, 1, 3)
    T = 15
    kf = design_centralized(sys_, cost, horizon=T)
    for v in ("honest", "ideal"):
        d = design_diffusion(sys_, cost, CommGraph(1), T, variant=v)
        np.testing.assert_allclose(d.stage_costs, kf.stage_costs, rtol=1e-10)
        p = sample_paths(sys_, T, 2, rng=1)
        np.testing.assert_allclose(d.errors(p), kf.errors(p), rtol=1e-9, atol=1e-11)


def test_local_is_the_per_agent_kalman_filter():
    """Agent i's local estimate is the centralized KF of the one-agent system (A, Q, Σ_x, C_i, R_i)."""
    sys_, cost, g = instance(6)
    T = 10
    d = design_local(sys_, cost, g, T)
    p = sample_paths(sys_, T, 3, rng=2)
    z = d.filter(p.y)
    for i in range(3):
        one = LinearGaussianSystem(A=sys_.A_at(0), Q=sys_.Q_at(0), Sigma_x=sys_.Sigma_x, C=[sys_.C_at(i, 0)], R=[sys_.R_at(i, 0)])
        Li = cost.L_block(i, 0)
        kf = design_centralized(one, TeamCost(S=np.eye(cost.dz), L=Li, n_agents=1), horizon=T)
        np.testing.assert_allclose(z[:, :, i * cost.dz : (i + 1) * cost.dz], kf.filter([p.y[i]]), rtol=1e-10, atol=1e-12)


def test_ideal_diffusion_on_a_complete_graph_is_centralized():
    sys_, cost, _ = instance(7)
    T = 12
    c = design_centralized(sys_, cost, horizon=T)
    d = design_diffusion(sys_, cost, CommGraph.complete(3), T, variant="ideal")
    np.testing.assert_allclose(d.stage_costs, c.stage_costs, rtol=1e-9)


@pytest.mark.parametrize("family", ("icf", "hcmci"))
def test_many_iterations_on_a_complete_graph_approach_centralized(family):
    rng = np.random.default_rng(12)
    n = 4
    sys_ = pd_system(rng, n, 3, [1, 1, 2, 1])
    cost = pd_cost(rng, n, 3)
    T = 10
    c = design_centralized(sys_, cost, horizon=T).stage_costs
    # complete graph: ICF with a small rate converges with K; HCMCI's Metropolis weights (1/n) average exactly in one iteration
    for g, kw in ((CommGraph.complete(n), {"epsilon": 0.2} if family == "icf" else {}), (CommGraph.ring(n), {})):
        gaps = []
        for K in (1, 3, 60):
            d = design(family, sys_, cost, g, T, "ideal", iterations=K, **kw).stage_costs
            gaps.append(np.max(np.abs(d - c) / c))
        assert gaps[2] < 1e-6, gaps
        if gaps[0] > 1e-12:
            assert gaps[0] > gaps[1] > gaps[2], gaps


def test_family_records():
    for name in FAMILIES:
        fam = get_family(name)
        assert fam.analytic_cost and fam.uses == "graph" and "variant" in fam.option_names


# ---------------------------------------------------------------------------
# bad input
# ---------------------------------------------------------------------------
@pytest.mark.parametrize(
    "weights, match",
    [
        ([[1.0, 0, 0], [0, 0.5, 0], [0, 0.5, 1.0]], r"c\[2, 1\] = 0.5 but agent 2 is not an in-neighbour of agent 1"),
        ([[1.0, 0, 0.3], [0, 1, 0], [0, 0, 0.7]], r"c\[0, 2\] = 0.3 but agent 0 is not an in-neighbour"),
        ([[1.2, 0, 0], [-0.2, 1, 0], [0, 0, 1]], "non-negative"),
        ([[0.5, 0, 0], [0, 1, 0], [0, 0, 1]], "column-stochastic"),
        ([[1.0, 0], [0, 1.0]], "3×3"),
        ("metropolos", "did you mean 'metropolis'"),
    ],
)
def test_bad_weights(weights, match):
    sys_, cost, g = instance(8)
    with pytest.raises(ArgumentError, match=match):
        design_diffusion(sys_, cost, g, 5, weights=weights)


def test_bad_options_name_the_key():
    fam = get_family("diffusion")
    with pytest.raises(ArgumentError, match=r"^diffusion\.weights: expected non-negative"):
        fam.check_options({"weights": [[1.5, 0], [-0.5, 1]]})
    with pytest.raises(ArgumentError, match=r"^diffusion\.variant: expected one of 'honest', 'ideal'"):
        fam.check_options({"variant": "honset"})
    with pytest.raises(ArgumentError, match=r"^diffusion\.epsilon: unknown option of the 'diffusion' family"):
        fam.check_options({"epsilon": 0.1})
    with pytest.raises(ArgumentError, match=r"^ci\.weights: unknown option"):
        get_family("ci").check_options({"weights": "uniform"})
    with pytest.raises(ArgumentError, match=r"^kcf\.variant: expected one of 'honest', 'ideal', 'stale'"):
        get_family("kcf").check_options({"variant": "fair"})
    sys_, cost, g = instance(8)
    with pytest.raises(ArgumentError, match="horizon"):
        design_local(sys_, cost, g, None)
    for fam in ("icf", "hcmci"):
        for bad in (0, -2, 2.5, "3", True):
            with pytest.raises(ArgumentError, match=rf"^{fam}\.iterations: expected a number of consensus iterations >= 1"):
                get_family(fam).check_options({"iterations": bad})
    with pytest.raises(ArgumentError, match=r"^icf\.epsilon: expected a consensus rate > 0"):
        get_family("icf").check_options({"epsilon": 0.0})
    with pytest.raises(ArgumentError, match=r"epsilon: expected a consensus rate 0 < epsilon < 1/Delta_max = 0.5 .*in-degree is 2"):
        design_icf(sys_, cost, g, 5, epsilon=0.6)
    with pytest.raises(ArgumentError, match=r"^hcmci\.epsilon: unknown option"):
        get_family("hcmci").check_options({"epsilon": 0.1})


def test_biased_description_is_detected():
    """The engine refuses a step that is not an estimator of its targets (x(b) left in the error)."""
    from teamkf.estimators.diffusion import DiffusionAlgorithm
    from teamkf.estimators.linear_team import build_steps

    sys_, cost, g = instance(9)

    class Biased(DiffusionAlgorithm):
        def combine(self, i, k, psi_i, psis):
            return 0.9 * psi_i

    with pytest.raises(TeamkfError, match="biased"):
        build_steps(Biased(sys_, cost, g, 8, np.eye(3), honest=True))


def test_families_in_scenarios():
    """Scenario tables pick the families up from the registry; bad options name the scenario key."""
    from teamkf.exceptions import ScenarioError
    from teamkf.study.scenario import scenario_from_dict
    from tests.unit.test_scenario import base_dict

    d = base_dict()
    d["estimators"] = ["mtmse", "local", "diffusion", "ci", "kcf", "icf", "hcmci"]
    d["diffusion"] = {"weights": "uniform", "variant": "ideal"}
    d["icf"] = {"iterations": 3, "epsilon": 0.4}
    sc = scenario_from_dict(d)
    dd = sc.design("diffusion")
    assert dd.label == "diffusion [ideal]" and dd.info["weights"] == "uniform"
    J = sc.design("mtmse").total_cost
    for name in ("local", "ci", "kcf", "icf", "hcmci"):
        des = sc.design(name)
        assert des.info["variant"] == "honest" and des.total_cost >= J
    for table, bad, prefix in [
        ("diffusion", {"weights": [[1.0, 0.5], [0.0, 0.5]]}, "diffusion.weights: expected a 4×4 matrix"),
        (
            "diffusion",
            {"weights": [[0, 0, 0, 0], [0, 1, 0, 0], [1, 0, 1, 0], [0, 0, 0, 1]]},
            "diffusion.weights: expected weights only on the graph's edges",
        ),
        ("icf", {"epsilon": 0.7}, "icf.epsilon: expected a consensus rate 0 < epsilon < 1/Delta_max = 0.5"),
        ("diffusion", {"weights": "metro"}, "diffusion.weights: expected a weight rule"),
        ("icf", {"iterations": 0}, "icf.iterations: expected a number of consensus iterations >= 1"),
        ("hcmci", {"iterations": 1.5}, "hcmci.iterations: expected a number of consensus iterations"),
        ("ci", {"variant": "fair"}, "ci.variant: expected one of 'honest', 'ideal'"),
        ("local", {"weights": "uniform"}, "local.weights: unknown option of the 'local' family"),
    ]:
        d2 = base_dict()
        d2["estimators"] = [table]
        d2[table] = bad
        with pytest.raises((ScenarioError, ArgumentError)) as ei:
            scenario_from_dict(d2).design(table)
        assert str(ei.value).startswith(prefix), str(ei.value)
