"""Identities and inequalities that MTMSE filtering must satisfy."""

import numpy as np
import pytest

from teamkf import (
    CommGraph,
    InformationStructure,
    LinearGaussianSystem,
    TeamCost,
    design_centralized,
    design_mmse,
    design_mtmse,
)
from teamkf.estimators.team import _local_index, window_covariances
from tests.helpers import random_cost, random_system


def platoon(lam=100.0):
    return LinearGaussianSystem.platoon(4), TeamCost.platoon(4, lam), CommGraph.line(4)


@pytest.mark.parametrize("seed", range(5))
def test_ordering_centralized_mtmse_mmse(seed):
    rng = np.random.default_rng(seed)
    n = 3
    g = CommGraph.random(n, p=0.5, delays=(1, 2), rng=rng)
    sys = random_system(rng, n, 3, [1, 2, 1])
    cost = random_cost(rng, n, 3, 2)
    T = 8
    c = design_centralized(sys, cost, horizon=T).stage_costs
    t = design_mtmse(sys, cost, g, T).stage_costs
    m = design_mmse(sys, cost, g, T).stage_costs
    assert np.all(c <= t * (1 + 1e-10))
    assert np.all(t <= m * (1 + 1e-10))


def test_block_diagonal_S_gives_mmse():
    """Remark 3: no cost coupling -> MTMSE = per-agent MMSE (gains and costs)."""
    rng = np.random.default_rng(7)
    n, dz = 3, 2
    sys = random_system(rng, n, 3, [1, 2, 1])
    blocks = [rng.standard_normal((dz, dz)) for _ in range(n)]
    from scipy.linalg import block_diag

    S = block_diag(*[b @ b.T + np.eye(dz) for b in blocks])
    cost = TeamCost(S=S, L=rng.standard_normal((n * dz, 3)), n_agents=n)
    g = CommGraph.line(n)
    t = design_mtmse(sys, cost, g, 6)
    m = design_mmse(sys, cost, g, 6)
    np.testing.assert_allclose(t.stage_costs, m.stage_costs, rtol=1e-10)
    for Ft, Fm in zip(t.gains, m.gains):
        for a, b in zip(Ft, Fm):
            np.testing.assert_allclose(a, b, rtol=1e-8, atol=1e-10)


def test_complete_graph_zero_extra_delay_single_agent_is_kalman_filter():
    rng = np.random.default_rng(1)
    sys = random_system(rng, 1, 3, [2])
    cost = random_cost(rng, 1, 3, 2)
    g = CommGraph(1, ())
    np.testing.assert_allclose(design_mtmse(sys, cost, g, 6).stage_costs, design_centralized(sys, cost, horizon=6).stage_costs, rtol=1e-10)


@pytest.mark.parametrize("make", ["platoon", "uav4", "uav10"])
def test_infinite_horizon_is_limit_of_finite(make):
    if make == "platoon":
        sys, cost, g = platoon()
    else:
        n = 4 if make == "uav4" else 10  # uav10 is unstable (spectral radius 1.55)
        sys, cost, g = LinearGaussianSystem.uav_formation(n), TeamCost.average_tracking(n, 10.0 * n * n), CommGraph.complete(n, 2)
    for design in (design_mtmse, design_mmse):
        inf = design(sys, cost, g)
        fin = design(sys, cost, g, horizon=150)
        assert fin.stage_costs[-1] == pytest.approx(inf.average_cost, rel=1e-9)
    assert design_centralized(sys, cost, horizon=150).stage_costs[-1] == pytest.approx(design_centralized(sys, cost).average_cost, rel=1e-9)


def test_relabelling_agents_permutes_results():
    rng = np.random.default_rng(11)
    n, dz = 3, 1
    sys = random_system(rng, n, 2, [1, 2, 1])
    cost = random_cost(rng, n, 2, dz)
    g = CommGraph.random(n, p=0.5, delays=(1, 3), rng=rng)
    perm = [2, 0, 1]  # new agent a is old agent perm[a]
    inv = np.argsort(perm)
    sys_p = LinearGaussianSystem(A=sys.A[0], Q=sys.Q[0], Sigma_x=sys.Sigma_x, C=[sys.C[p][0] for p in perm], R=[sys.R[p][0] for p in perm])
    rows = np.concatenate([np.arange(p * dz, (p + 1) * dz) for p in perm])
    cost_p = TeamCost(S=cost.S_at(0)[np.ix_(rows, rows)], L=cost.L_at(0)[rows], n_agents=n)
    g_p = CommGraph.from_edges(n, [[int(inv[i]), int(inv[j]), d] for (i, j, d) in g.edges])
    T = 6
    d0 = design_mtmse(sys, cost, g, T)
    d1 = design_mtmse(sys_p, cost_p, g_p, T)
    np.testing.assert_allclose(d0.stage_costs, d1.stage_costs, rtol=1e-10)
    # gains: the same columns, reordered as the local measurements (sorted by step, then source)
    for k in range(T):
        for a in range(n):

            def columns(design, system, agent, rename):
                out, pos = {}, 0
                for j, s in design.structure.local_pairs(agent, k):
                    out[(rename(j), s)] = slice(pos, pos + system.dy[j])
                    pos += system.dy[j]
                return out

            c_old = columns(d0, sys, perm[a], lambda j: j)
            c_new = columns(d1, sys_p, a, lambda j: perm[j])
            assert c_old.keys() == c_new.keys()
            for key in c_old:
                np.testing.assert_allclose(d0.gains[k][perm[a]][:, c_old[key]], d1.gains[k][a][:, c_new[key]], rtol=1e-8, atol=1e-12)


def test_more_information_never_hurts():
    sys, cost, g = platoon()
    IS0 = InformationStructure.from_graph(g)
    IS1 = InformationStructure(
        4, 3, [[(0, 0, 1), (1, 1, 1)], [(0, 1, 1), (1, 0, 1), (2, 1, 1)], [(1, 1, 1), (2, 0, 1), (3, 1, 1)], [(2, 1, 1), (3, 0, 1)]]
    )
    IS2 = InformationStructure.own_window(4, 3)
    IS3 = InformationStructure.own_window(4, 3, length=1)
    assert IS1.is_sub_structure_of(IS0) and IS2.is_sub_structure_of(IS0) and IS3.is_sub_structure_of(IS2)
    J = {name: design_mtmse(sys, cost, st, 50).stage_costs for name, st in [("0", IS0), ("1", IS1), ("2", IS2), ("3", IS3)]}
    assert np.all(J["0"] <= J["1"] * (1 + 1e-12))
    assert np.all(J["0"] <= J["2"] * (1 + 1e-12))
    assert np.all(J["2"] <= J["3"] * (1 + 1e-12))
    for st in (IS1, IS2, IS3):
        st.validate_on(g)


def test_local_terms_match_window_and_paper_uav_example():
    """eq. (30)-(31) from explicit C_loc, P^w, P^v, P^sigma equal the window covariances; Section IV-A forms."""
    n = 4
    sys = LinearGaussianSystem.uav_formation(n)
    cost = TeamCost.average_tracking(n, 10.0)
    g = CommGraph.complete(n, 2)
    d = design_mtmse(sys, cost, g, horizon=6)
    for k in range(6):
        a, P = d.P_anchor(k)
        Sig, Th, P0 = window_covariances(sys, k, a, P)
        for i in range(n):
            lt = d.local_terms(i, k)
            ix = _local_index(sys, d.structure, i, k, a)
            np.testing.assert_allclose(lt["Sigma_hat"], Sig[np.ix_(ix, ix)], rtol=1e-12, atol=1e-12)
            np.testing.assert_allclose(lt["Theta_hat"], Th[:, ix], rtol=1e-12, atol=1e-12)
            np.testing.assert_allclose(lt["P0"], P0, rtol=1e-12, atol=1e-12)
    # Section IV-A (with the errata): for t >= 2, P^sigma_i = [0, Q C_i'], P^w_ii = diag(0, C_i Q C_i'), Sigma^w = Q
    lt = d.local_terms(1, 4)
    Ci, Q = sys.C_at(1, 0), sys.Q_at(0)
    np.testing.assert_allclose(lt["P_sigma"], np.hstack([np.zeros((n, 1)), Q @ Ci.T]))
    np.testing.assert_allclose(lt["P_w"], np.diag([0.0, (Ci @ Q @ Ci.T).item()]))
    np.testing.assert_allclose(lt["Sigma_w"], Q)
    np.testing.assert_allclose(lt["C_loc"], np.vstack([Ci, Ci @ sys.A_at(0)]))
    # the first step has no y_i(-1): a one-entry local vector (errata: not diag(0, R_i))
    assert d.local_terms(1, 0)["Sigma_hat"].shape == (1, 1)


def test_line_graph_local_noise_overlaps():
    """Errata: on a line graph the local windows overlap, so P^v_ij != 0 for neighbours; cross blocks match too."""
    sys, cost, g = platoon()
    d = design_mtmse(sys, cost, g, horizon=6)
    for k in (1, 4, 5):
        a, P = d.P_anchor(k)
        Sig, _, _ = window_covariances(sys, k, a, P)
        idx = [_local_index(sys, d.structure, i, k, a) for i in range(4)]
        for i in range(4):
            for j in range(4):
                cov = d.local_covariances(i, j, k)
                np.testing.assert_allclose(cov["Sigma_hat"], Sig[np.ix_(idx[i], idx[j])], rtol=1e-12, atol=1e-12)
    cov01 = d.local_covariances(0, 1, 5)
    assert np.abs(cov01["P_v"]).max() > 0  # shared measurements -> shared noise
    # agents 0 and 3 (three hops apart) share y_1(k-2) and y_2(k-2): two 4x4 blocks R = 0.1 I
    assert np.count_nonzero(d.local_covariances(0, 3, 5)["P_v"]) == 2 * 4


def test_gains_depend_on_S():
    sys, cost, g = platoon(1.0)
    _, cost2, _ = platoon(100.0)
    F1 = design_mtmse(sys, cost, g).steady_gains
    F2 = design_mtmse(sys, cost2, g).steady_gains
    assert not np.allclose(F1[1], F2[1])
