"""``mtmse_lossy`` with ``keyed=1`` (gains keyed on the current arrivals): limits, Monte Carlo, agents, refusals."""

from __future__ import annotations

import numpy as np
import pytest

from teamkf import CommGraph, LinearGaussianSystem, TeamCost
from teamkf.estimators.registry import get_family
from teamkf.estimators.team import design_mtmse
from teamkf.estimators.team_lossy import design_mtmse_lossy
from teamkf.exceptions import ArgumentError

from ..helpers import assert_lossy_agents_match, assert_lossy_mc_matches_exact

T = 10


def unlike_line(n: int = 3, lam: float = 1.0) -> tuple[LinearGaussianSystem, TeamCost]:
    """A line of agents that all estimate x₁; agent 0 measures it precisely (R = 0.01), the others poorly (R = 4)."""
    A = np.array([[0.95, 0.2], [0.0, 0.9]])
    C = [np.array([[1.0, 0.0]]) for _ in range(n)]
    sysm = LinearGaussianSystem(A=A, Q=0.5, Sigma_x=1.0, C=C, R=[0.01] + [4.0] * (n - 1))
    S = (1 + lam) * np.eye(n) - lam / n * np.ones((n, n))
    return sysm, TeamCost(S=S, L=np.tile([[1.0, 0.0]], (n, 1)), n_agents=n)


@pytest.fixture(scope="module")
def team():
    sysm, cost = unlike_line()
    g = CommGraph.line(3)
    return sysm, cost, g, {p: design_mtmse_lossy(sysm, cost, g, T, p_drop=p, keyed=1) for p in (0.0, 0.5, 1.0)}


def test_limits_and_containment(team):
    sysm, cost, g, ds = team
    assert ds[0.0].total_cost == pytest.approx(design_mtmse(sysm, cost, g, T).total_cost, rel=1e-9)  # p = 0: MTMSE
    for p, d in ds.items():
        d0 = design_mtmse_lossy(sysm, cost, g, T, p_drop=p)
        assert d.lower_bound <= d.total_cost <= d0.total_cost * (1 + 1e-12) <= d.info["local_kf_cost"]
        assert d.info["keyed"] == 1 and d.details()["keyed"] == 1
    assert ds[0.5].total_cost < 0.98 * design_mtmse_lossy(sysm, cost, g, T, p_drop=0.5).total_cost  # keying helps here
    assert ds[1.0].total_cost == pytest.approx(design_mtmse_lossy(sysm, cost, g, T, p_drop=1.0).total_cost, rel=1e-9)


def test_monte_carlo_agrees_with_exact_expected_cost(team):
    sysm, cost, _, ds = team
    assert_lossy_mc_matches_exact(ds[0.5], sysm, cost, T, 0.5)


def test_graph_agents_reproduce_errors_and_run_over_drops(team):
    sysm, cost, g, ds = team
    assert_lossy_agents_match(ds[0.5], sysm, cost, g, T, 0.5)


def test_refusals_and_registry(team):
    sysm, cost, g, _ = team
    for bad in (2, -1, "yes", 0.5):
        with pytest.raises(ArgumentError, match="keyed"):
            design_mtmse_lossy(sysm, cost, g, 4, p_drop=0.3, keyed=bad)
    with pytest.raises(ArgumentError, match="memory"):
        design_mtmse_lossy(sysm, cost, g, 4, p_drop=0.3, keyed=1, memory=2)
    s5, c5 = unlike_line(6)
    with pytest.raises(ArgumentError, match="link events"):  # 6 agents, complete graph: 30 events decide one step's arrivals
        design_mtmse_lossy(s5, c5, CommGraph.complete(6, delay=1), 3, p_drop=0.3, keyed=1)
    d = get_family("mtmse_lossy").build(sysm, cost, graph=g, structure=g, horizon=4, options={"p_drop": 0.3, "keyed": 1})
    assert d.info["keyed"] == 1
    arrays = d.arrays()
    assert arrays["due_0_t3"].tolist() == [[1, 2], [2, 1]]  # agent 0's items due at step 3: ν₁(2), ν₂(1); 4 patterns
    assert {f"G_0_t3_p{p}" for p in range(4)} <= set(arrays)
