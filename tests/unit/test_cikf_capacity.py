"""CIKF tracking capacity (Theorem 3): the SDP with cvxpy (optional extra ``cvx``) and the closed-form bounds."""

from __future__ import annotations

import networkx as nx
import numpy as np
import pytest

from teamkf import CommGraph, LinearGaussianSystem
from teamkf.estimators.cikf import design_cikf, tracking_capacity, tracking_capacity_upper_bound
from teamkf.exceptions import OptionalDependencyError


def _system(M=3, N=6, seed=5, local=False):
    rng = np.random.default_rng(seed)
    A = 1.02 * np.eye(M) + 0.2 * rng.standard_normal((M, M))
    C = [np.eye(M)] * N if local else [np.eye(M)[[n % M]] for n in range(N)]
    R = [np.eye(M) * (1.0 + 0.3 * n) for n in range(N)] if local else [np.array([[1.0 + 0.3 * n]]) for n in range(N)]
    return LinearGaussianSystem(A=A, Q=1.0, Sigma_x=1.0, C=C, R=R)


def _graph(edges, N):
    G = nx.Graph(edges)
    G.add_nodes_from(range(N))
    return CommGraph.from_networkx(G, default_delay=1)


def test_closed_form_upper_bound_without_solver():
    sysm = _system()
    ub = tracking_capacity_upper_bound(sysm)
    # each agent sees one of r = 3 coordinates: bound = (λ1/λm) / sqrt(1 - 1/3)
    from teamkf.estimators.cikf import pseudo_state_model

    m = pseudo_state_model(sysm)
    assert ub == pytest.approx(m.lambda_1 / m.lambda_m / np.sqrt(2 / 3))
    assert tracking_capacity_upper_bound(_system(local=True)) == float("inf")


def test_given_gains_bound_never_exceeds_closed_form():
    sysm = _system()
    ub = tracking_capacity_upper_bound(sysm)
    for g in (CommGraph.line(6), CommGraph.ring(6), CommGraph.complete(6)):
        d = design_cikf(sysm, None, g, 15)
        assert 0 < d.tracking_bound() <= ub * (1 + 1e-9)


def test_missing_cvxpy_gives_install_command(monkeypatch):
    import importlib

    real = importlib.import_module

    def fake(name, *a, **k):
        if name == "cvxpy":
            raise ImportError("no cvxpy")
        return real(name, *a, **k)

    monkeypatch.setattr(importlib, "import_module", fake)
    with pytest.raises(OptionalDependencyError, match=r"teamkf\[cvx\]"):
        tracking_capacity(_system(), CommGraph.line(6))


def test_capacity_nondecreasing_with_connectivity():
    pytest.importorskip("cvxpy")
    N = 6
    sysm = _system(N=N)
    family = [  # nested edge sets: each graph contains the previous one
        [],
        [(0, 1), (2, 3), (4, 5)],
        [(0, 1), (2, 3), (4, 5), (1, 2)],
        [(0, 1), (2, 3), (4, 5), (1, 2), (3, 4)],  # the line: connected
        [(0, 1), (2, 3), (4, 5), (1, 2), (3, 4), (5, 0)],  # ring
        [(i, j) for i in range(N) for j in range(i + 1, N)],  # complete
    ]
    caps = [tracking_capacity(sysm, _graph(e, N)) for e in family]
    values = [c.capacity for c in caps]
    assert all(c.status == "optimal" for c in caps)
    assert all(b >= a * (1 - 1e-5) for a, b in zip(values, values[1:]))
    assert values[-1] > values[0] * 1.1  # connecting the agents raises it ...
    # ... to the graph-independent ceiling, which even the complete graph cannot pass
    for c in caps:
        assert c.capacity <= c.capacity_upper * (1 + 1e-5)
        assert c.capacity_upper <= tracking_capacity_upper_bound(sysm) * (1 + 1e-6)
    assert values[-1] == pytest.approx(caps[-1].capacity_upper, rel=1e-4)
    # without links M is block-diagonal and ||I - B_u C̃_n|| >= 1: C = λ1/λm
    assert values[0] == pytest.approx(caps[0].lambda_ratio, rel=1e-5)


def test_complete_graph_capacity_is_finite_unless_locally_observable():
    pytest.importorskip("cvxpy")
    sysm = _system(N=4)
    c = tracking_capacity(sysm, CommGraph.complete(4))
    assert np.isfinite(c.capacity) and c.min_norm == pytest.approx(c.lower_bound_norm, rel=1e-4)
    local = tracking_capacity(_system(N=4, local=True), CommGraph.line(4))
    assert local.capacity == float("inf") and local.min_norm < 1e-6


def test_capacity_dominates_any_gains_bound():
    pytest.importorskip("cvxpy")
    sysm = _system(N=5)
    for g in (CommGraph.line(5), CommGraph.complete(5)):
        cap = tracking_capacity(sysm, g)
        d = design_cikf(sysm, None, g, 12)
        for k in (0, 5, 11):
            assert d.tracking_bound(k) <= cap.capacity * (1 + 1e-5)
        # the optimal structured gains attain the optimal norm
        rows_norm = cap.min_norm
        assert cap.lambda_ratio / rows_norm == pytest.approx(cap.capacity)
