"""The shared-sensor innovation CG (every agent measures with the same C_i, R_i) against the general one, and the
information-form steady state against the dense one: the same answers to round-off."""

import numpy as np
import pytest

from teamkf import CommGraph, LinearGaussianSystem, TeamCost, design_mtmse
from teamkf.estimators._gamma_shared import SharedSensorInnovations, block_mask, shared_sensor_window
from teamkf.estimators.gamma import InnovationsProblem, WindowModel
from teamkf.estimators.kalman import steady_state
from teamkf.estimators.riccati import steady_state_kalman, steady_state_kalman_blocks
from teamkf.estimators.team import _local_index
from teamkf.network.information import InformationStructure


def both(system, cost, graph, k=None, P=None):
    """(general InnovationsProblem, SharedSensorInnovations) of one window step (anchor 0)."""
    st = InformationStructure.from_graph(graph)
    k = st.common_lag - 1 if k is None else k
    P = steady_state(system)[0] if P is None else P
    w = k + 1
    idx = [_local_index(system, st, i, k, 0) for i in range(system.n_agents)]
    model = WindowModel(
        [system.A_at(u) for u in range(w - 1)],
        [system.Q_at(u) for u in range(w - 1)],
        [system.C_stack(u) for u in range(w)],
        [system.R_stack(u) for u in range(w)],
        P,
    )
    window = shared_sensor_window(system, 0, w, P)
    assert window is not None
    S, L = cost.S_at(k), cost.L_at(k)
    return InnovationsProblem(S, L, model, idx, cost.dz), SharedSensorInnovations(S, L, window, idx, cost.dz)


def assert_same(old, new, rtol=1e-9):
    F_old, J_old = old.solve()
    F_new, J_new = new.solve()
    assert J_new == pytest.approx(J_old, rel=1e-12)
    assert new.iterations == old.iterations
    assert [f.shape for f in F_new] == [f.shape for f in F_old]
    for a, b in zip(F_old, F_new):
        assert np.linalg.norm(a - b) <= rtol * max(np.linalg.norm(a), 1e-300)


@pytest.mark.parametrize("n", [4, 5, 6, 7, 8])
def test_shared_sensor_platoon_matches_the_general_innovation_cg(n):
    """The steady platoon window (line graph, unit delays): same gains (1e-9), cost (1e-12) and CG iterations."""
    old, new = both(LinearGaussianSystem.platoon(n), TeamCost.platoon(n, 100.0), CommGraph.line(n))
    assert new._diags is not None and new._Rd is not None  # the banded, in-place operator
    assert_same(old, new)


def test_shared_sensor_transient_window_correlated_R_dense_S():
    """A transient window (anchor 0, P = Sigma_x), correlated R shared by all agents, dense S with d_z = 2, directed delays."""
    rng = np.random.default_rng(7)
    dx, m0 = 3, 2
    A = rng.standard_normal((dx, dx))
    A *= 0.9 / max(abs(np.linalg.eigvals(A)))
    C = rng.standard_normal((m0, dx))
    B = rng.standard_normal((m0, m0))
    R = B @ B.T + 0.3 * np.eye(m0)
    system = LinearGaussianSystem(A=A, Q=np.eye(dx), Sigma_x=np.eye(dx), C=[C] * 3, R=[R] * 3)
    Bs = rng.standard_normal((6, 6))
    cost = TeamCost(S=Bs @ Bs.T + np.eye(6), L=rng.standard_normal((6, dx)), n_agents=3)
    graph = CommGraph(3, ((0, 1, 1), (1, 2, 2), (2, 0, 1)))
    old, new = both(system, cost, graph, k=1, P=system.Sigma_x)
    assert new._diags is None and new._Rd is None  # the general products
    assert_same(old, new)


def test_shared_sensor_window_needs_one_sensor_and_whole_blocks():
    rng = np.random.default_rng(1)
    C = [np.eye(2), rng.standard_normal((2, 2))]
    system = LinearGaussianSystem(A=0.5 * np.eye(2), Q=np.eye(2), Sigma_x=np.eye(2), C=C, R=[0.1, 0.1])
    assert shared_sensor_window(system, 0, 2, np.eye(2)) is None
    assert block_mask([np.array([0, 1, 4, 5])], 2, 2, 2) is not None
    assert block_mask([np.array([0, 1, 4])], 2, 2, 2) is None  # half a block
    assert block_mask([np.array([0, 1, 0, 1])], 2, 2, 2) is None  # repeated
    # the design falls back to the general innovation CG and still agrees with dense Cholesky
    cost = TeamCost.platoon(2, 10.0)
    d, dd = design_mtmse(system, cost, CommGraph.line(2), method="cg"), design_mtmse(system, cost, CommGraph.line(2), method="dense")
    assert d.average_cost == pytest.approx(dd.average_cost, rel=1e-10)


def test_shared_sensor_agent_without_local_data():
    n = 4
    old, new = both(LinearGaussianSystem.platoon(n), TeamCost.platoon(n, 10.0), CommGraph.line(n))
    idx = [ix if i else np.zeros(0, int) for i, ix in enumerate(new.idx)]
    old0 = InnovationsProblem(old.S, old.L, old.model, idx, old.dz)
    new0 = SharedSensorInnovations(new.S, new.L, new.window, idx, new.dz)
    assert_same(old0, new0)


def test_design_takes_the_shared_sensor_path_for_platoons():
    n = 6
    system, cost, graph = LinearGaussianSystem.platoon(n), TeamCost.platoon(n, 100.0), CommGraph.line(n)
    d = design_mtmse(system, cost, graph)
    assert d.info["gamma"]["sensors"] == "shared" and d.info["gamma"]["coordinates"] == "innovations"
    old, _ = both(system, cost, graph)
    F_old, J_old = old.solve()
    assert d.average_cost == pytest.approx(J_old, rel=1e-12)
    for a, b in zip(F_old, d.steady_gains):
        assert np.linalg.norm(a - b) <= 1e-9 * np.linalg.norm(a)


@pytest.mark.parametrize("n", [4, 6, 8])
def test_information_form_steady_state_matches_the_dense_one(n):
    s = LinearGaussianSystem.platoon(n)
    dense = steady_state_kalman(s.A_at(0), s.C_stack(0), s.Q_at(0), s.R_stack(0))
    blocks = steady_state_kalman_blocks(s.A_at(0), [s.C_at(i, 0) for i in range(n)], s.Q_at(0), [s.R_at(i, 0) for i in range(n)])
    for a, b in zip(dense, blocks):
        assert a.shape == b.shape
        assert np.linalg.norm(a - b) <= 1e-12 * np.linalg.norm(a)


def test_information_form_steady_state_correlated_blocks():
    rng = np.random.default_rng(3)
    dx = 3
    A = rng.standard_normal((dx, dx))
    A *= 1.1 / max(abs(np.linalg.eigvals(A)))  # unstable: needs the measurements
    C = [rng.standard_normal((d, dx)) for d in (2, 1, 3)]
    R = []
    for d in (2, 1, 3):
        B = rng.standard_normal((d, d))
        R.append(B @ B.T + 0.3 * np.eye(d))
    Rd = np.zeros((6, 6))
    Rd[:2, :2], Rd[2:3, 2:3], Rd[3:, 3:] = R
    dense = steady_state_kalman(A, np.vstack(C), np.eye(dx), Rd)
    blocks = steady_state_kalman_blocks(A, C, np.eye(dx), R)
    for a, b in zip(dense, blocks):
        assert np.linalg.norm(a - b) <= 1e-12 * np.linalg.norm(a)


def test_shared_sensor_cg_reports_non_convergence():
    from teamkf.exceptions import ConvergenceError

    _, new = both(LinearGaussianSystem.platoon(5), TeamCost.platoon(5, 100.0), CommGraph.line(5))
    with pytest.raises(ConvergenceError, match="innovation coordinates"):
        new.solve(max_iter=1, rtol=1e-15)
