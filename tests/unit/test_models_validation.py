"""Every validation of the models, information structures and designs: exception type and message."""

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
from teamkf.exceptions import (
    ArgumentError,
    DetectabilityError,
    InformationStructureError,
    NotPositiveDefiniteError,
    NotSymmetricError,
    ShapeError,
    TeamkfError,
)

OK = dict(A=np.eye(2) * 0.5, Q=1.0, Sigma_x=1.0, C=[np.eye(2), [[1.0, 0.0]]], R=[0.1, 0.2])


def make(**kw):
    args = dict(OK)
    args.update(kw)
    return LinearGaussianSystem(**args)


@pytest.mark.parametrize(
    "kw, exc, words",
    [
        (dict(A=np.ones((2, 3))), ShapeError, ["A", "square", "2x3"]),
        (dict(A=[[np.nan, 0], [0, 1]]), ShapeError, ["A", "finite"]),
        (dict(A="abc"), ShapeError, ["A", "numeric"]),
        (dict(Q=np.ones((3, 3))), ShapeError, ["Q", "2x2", "3x3"]),
        (dict(Q=[[1.0, 0.5], [0.0, 1.0]]), NotSymmetricError, ["Q", "symmetric"]),
        (dict(Q=-np.eye(2)), NotPositiveDefiniteError, ["Q", "semi-definite", "-1"]),
        (dict(Sigma_x=[[1.0, 2.0], [2.0, 1.0]]), NotPositiveDefiniteError, ["Sigma_x", "semi-definite"]),
        (dict(C=[np.eye(2), [[1.0, 0.0, 0.0]]]), ShapeError, ["C[1]", "x2", "1x3"]),
        (dict(C=np.eye(2)), ShapeError, ["C", "one measurement matrix per agent"]),
        (dict(C=[]), ShapeError, ["C", "non-empty"]),
        (dict(R=[0.1, 0.0]), NotPositiveDefiniteError, ["R[1]", "positive definite", "0"]),
        (dict(R=[0.1, 0.1, 0.1]), ShapeError, ["R", "one covariance per agent", "3"]),
        (dict(R=[np.eye(3), 0.1]), ShapeError, ["R[0]", "2x2", "3x3"]),
    ],
)
def test_system_validation(kw, exc, words):
    with pytest.raises(exc) as info:
        make(**kw)
    assert isinstance(info.value, TeamkfError)
    for w in words:
        assert w in str(info.value), (w, str(info.value))


def test_scalar_covariances_and_time_varying():
    s = make(A=[np.eye(2), 0.5 * np.eye(2), np.eye(2)])
    assert s.is_time_varying and s.n_time == 3
    np.testing.assert_array_equal(s.A_at(1), 0.5 * np.eye(2))
    np.testing.assert_array_equal(s.R_at(1, 0), [[0.2]])
    with pytest.raises(ShapeError, match="horizon of 6 steps needs 5"):
        s.require_horizon(6)
    with pytest.raises(ShapeError, match="steady-state"):
        design_mtmse(s, TeamCost.mse(2, 2), CommGraph.complete(2))
    with pytest.raises(ShapeError, match=r"A\[t=1\]"):
        make(A=[np.eye(2), np.eye(2)[:1]])
    with pytest.raises(ValueError):  # arrays are read-only
        s.A[0, 0, 0] = 3.0


@pytest.mark.parametrize(
    "kw, exc, words",
    [
        (dict(S=np.eye(3), L=np.eye(3), n_agents=2), ShapeError, ["S", "multiple of n_agents", "3x3"]),
        (dict(S=-np.eye(2), L=np.eye(2), n_agents=2), NotPositiveDefiniteError, ["S", "positive definite"]),
        (dict(S=np.eye(2), L=np.eye(3), n_agents=2), ShapeError, ["L", "2 x d_x"]),
        (dict(S=np.eye(2), L=np.eye(2), n_agents=0), ArgumentError, ["n_agents", ">= 1"]),
    ],
)
def test_cost_validation(kw, exc, words):
    with pytest.raises(exc) as info:
        TeamCost(**kw)
    for w in words:
        assert w in str(info.value), (w, str(info.value))


def test_cost_builders():
    with pytest.raises(ArgumentError, match="lambda"):
        TeamCost.platoon(3, -1.0)
    S = TeamCost.ring(4, 1.0).S_at(0)
    np.testing.assert_allclose(S.sum(axis=1), 1.0)  # differences cancel on constants
    sys = make()
    with pytest.raises(ShapeError, match="cost: expected a cost for 2 agents"):
        design_centralized(sys, TeamCost.mse(3, 2), horizon=3)
    with pytest.raises(ShapeError, match="cost.L: expected 2 columns"):
        design_centralized(sys, TeamCost.mse(2, 3), horizon=3)


@pytest.mark.parametrize(
    "args, words",
    [
        ((2, 0, [[], []]), ["common_lag", ">= 1", "0"]),
        ((2, 2, [[]]), ["local", "one list of windows per agent (2)", "1 lists"]),
        ((2, 2, [[(0, 0, 2)], []]), ["local[0][0]", "oldest <= common_lag - 1 = 1", "2"]),
        ((2, 2, [[(0, 1, 0)], []]), ["local[0][0]", "newest <= oldest"]),
        ((2, 2, [[(5, 0, 1)], []]), ["local[0][0]", "source agent 5"]),
        ((2, 3, [[(0, 0, 1), (0, 1, 2)], []]), ["local[0]", "overlap"]),
        ((2, 3, [[(0, 0.5, 1)], []]), ["newest", "integer"]),
        ((2, 3, [[(0, 1)], []]), ["local[0][0]", "triple"]),
    ],
)
def test_information_structure_validation(args, words):
    with pytest.raises(InformationStructureError) as info:
        InformationStructure(*args)
    for w in words:
        assert w in str(info.value), (w, str(info.value))


def test_information_structure_realizability():
    g = CommGraph.line(4)
    with pytest.raises(InformationStructureError, match="common_lag: 2 is not realizable.*use common_lag >= 3"):
        InformationStructure.own_window(4, 2).validate_on(g)
    bad = InformationStructure(4, 3, [[(1, 0, 1)], [], [], []])
    with pytest.raises(InformationStructureError, match=r"local\[0\].*y_1 reaches agent 0 only after 1 steps"):
        bad.validate_on(g)
    with pytest.raises(InformationStructureError, match="weighted diameter"):
        InformationStructure.from_graph(g, common_lag=2)
    with pytest.raises(InformationStructureError, match="expected 4 agents.*found 3"):
        InformationStructure.own_window(4, 3).validate_on(CommGraph.line(3))


def test_from_graph_is_eq14():
    from tests.helpers import eq14_information

    rng = np.random.default_rng(0)
    for _ in range(10):
        g = CommGraph.random(4, p=0.4, delays=(1, 3), rng=rng)
        st = InformationStructure.from_graph(g)
        for i in range(4):
            for k in range(g.diameter + 3):
                assert st.holds(i, k) == set(eq14_information(g, i, k))


def test_design_argument_errors():
    sys = make()
    cost = TeamCost.mse(2, 2)
    with pytest.raises(InformationStructureError, match="structure: expected an InformationStructure or a CommGraph"):
        design_mtmse(sys, cost, "complete")
    with pytest.raises(InformationStructureError, match="structure: expected 2 agents"):
        design_mtmse(sys, cost, InformationStructure.own_window(3, 1))
    with pytest.raises(ArgumentError, match="horizon"):
        design_mmse(sys, cost, CommGraph.complete(2), horizon=0)
    with pytest.raises(ArgumentError, match="form"):
        design_centralized(sys, cost, horizon=3, form="smoother")  # type: ignore[arg-type]


def test_steady_state_needs_detectability():
    # an unstable mode (2.0) that no agent sees
    sys = LinearGaussianSystem(A=np.diag([2.0, 0.5]), Q=1.0, Sigma_x=1.0, C=[[[0.0, 1.0]], [[0.0, 1.0]]], R=0.1)
    cost = TeamCost.mse(2, 2)
    with pytest.raises(DetectabilityError, match="2"):
        design_mtmse(sys, cost, CommGraph.complete(2))
    design_mtmse(sys, cost, CommGraph.complete(2), horizon=5)  # a finite horizon needs no detectability
    # stabilizability: an unstable mode without process noise
    sys2 = LinearGaussianSystem(A=np.diag([2.0, 0.5]), Q=np.diag([0.0, 1.0]), Sigma_x=1.0, C=[np.eye(2), np.eye(2)], R=0.1)
    with pytest.raises(DetectabilityError):
        design_mmse(sys2, cost, CommGraph.complete(2))
