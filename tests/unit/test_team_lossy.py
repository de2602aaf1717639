"""The drop-aware team filter ``mtmse_lossy``: its limits (p = 0, p = 1, no gains), Monte Carlo, agents, registry."""

from __future__ import annotations

import numpy as np
import pytest

from teamkf import CommGraph, LinearGaussianSystem, TeamCost
from teamkf.estimators.local import design_local
from teamkf.estimators.registry import get_family
from teamkf.estimators.team import design_mtmse
from teamkf.estimators.team_lossy import design_mtmse_lossy
from teamkf.exceptions import ArgumentError
from teamkf.network.information import InformationStructure
from teamkf.simulation.sampling import sample_paths

T = 10


@pytest.fixture(scope="module")
def platoon():
    return LinearGaussianSystem.platoon(4), TeamCost.platoon(4, 100.0), CommGraph.line(4)


@pytest.fixture(scope="module")
def designs(platoon):
    sysm, cost, g = platoon
    return {p: design_mtmse_lossy(sysm, cost, g, T, p_drop=p) for p in (0.0, 0.2, 0.5, 1.0)}


def test_equals_mtmse_without_drops(platoon, designs):
    sysm, cost, g = platoon
    ref = design_mtmse(sysm, cost, g, T)
    d = designs[0.0]
    assert d.total_cost == pytest.approx(ref.total_cost, rel=1e-9)
    np.testing.assert_allclose(d.stage_costs, ref.stage_costs, rtol=1e-9)
    assert d.gap == pytest.approx(0.0, abs=1e-9)


def test_equals_own_history_optimum_when_nothing_arrives(platoon, designs):
    sysm, cost, _ = platoon
    own = design_mtmse(sysm, cost, InformationStructure.own_window(4, T), T)  # each agent: y_i(0:k), nothing common
    assert designs[1.0].total_cost == pytest.approx(own.total_cost, rel=1e-6)


def test_ordered_between_bound_and_local_kf(platoon, designs):
    sysm, cost, g = platoon
    local = design_local(sysm, cost, g, T).total_cost
    costs = [designs[p].total_cost for p in (0.0, 0.2, 0.5, 1.0)]
    assert all(a <= b + 1e-9 * b for a, b in zip(costs, costs[1:]))  # more drops never help (nested classes in law)
    for p, d in designs.items():
        assert d.info["local_kf_cost"] == pytest.approx(local, rel=1e-9)  # G = 0 is the local Kalman filter
        assert d.lower_bound <= d.total_cost <= local
        assert d.lower_bound == pytest.approx(designs[0.0].total_cost, rel=1e-9)


@pytest.mark.parametrize("p", [0.2, 0.5])
def test_monte_carlo_agrees_with_exact_expected_cost(platoon, designs, p):
    sysm, cost, _ = platoon
    d = designs[p]
    paths = sample_paths(sysm, T, 4000, rng=11)
    e = d.errors(paths, p_drop=p, rng=12)
    c = np.einsum("rki,ij,rkj->r", e, cost.S_at(0), e)
    se = c.std(ddof=1) / np.sqrt(c.size)
    assert abs(c.mean() - d.total_cost) < 4 * se
    # the drops matter: with every packet delivered the same gains cost less than their expected cost
    e0 = d.errors(paths)
    assert np.einsum("rki,ij,rkj->r", e0, cost.S_at(0), e0).mean() < c.mean()


def test_graph_agents_reproduce_errors_on_reliable_links(platoon, designs):
    sysm, cost, _ = platoon
    d = designs[0.5]
    paths = sample_paths(sysm, T, 5, rng=3)
    z = d.filter(paths.y)
    L = cost.L_at(0)
    e_run = np.stack([paths.x[:, k] @ L.T - z[:, k] for k in range(T)], axis=1)
    np.testing.assert_allclose(e_run, d.errors(paths), rtol=1e-8, atol=1e-8)


def test_graph_agents_on_the_lossy_runtime(platoon, designs):
    from teamkf.simulation.links import LinkModel
    from teamkf.simulation.monte_carlo import monte_carlo

    sysm, cost, g = platoon
    d = designs[0.5]
    r = monte_carlo({"lossy": d}, T, 300, rng=4, path="runtime", graph=g, links=LinkModel(p_drop=0.5))["lossy"]
    assert abs(r.total_mean - d.total_cost) < 4 * r.total_sem, (r.total_mean, r.total_sem, d.total_cost)


def test_memory_bounds_the_class(platoon, designs):
    sysm, cost, g = platoon
    m3 = design_mtmse_lossy(sysm, cost, g, T, p_drop=0.5, memory=3)
    m6 = design_mtmse_lossy(sysm, cost, g, T, p_drop=0.5, memory=6)
    full = designs[0.5].total_cost
    assert full - 1e-9 * full <= m6.total_cost <= m3.total_cost + 1e-9 * full <= m3.info["local_kf_cost"]
    mT = design_mtmse_lossy(sysm, cost, g, T, p_drop=0.5, memory=T)  # the per-step path, same class as memory=None
    assert mT.total_cost == pytest.approx(full, rel=1e-9)


def test_registry_alias_and_scenario_network(platoon):
    assert get_family("mtmse-lossy").name == "mtmse_lossy"
    from teamkf.study.scenario import load_packaged

    sc = load_packaged("platoon-4").updated({"horizon": 6, "network": {"p_drop": 0.3}, "estimators": ["mtmse-lossy", "mtmse"]})
    assert sc.estimators[0] == "mtmse_lossy"
    d = sc.design("mtmse_lossy")
    assert d.p_drop == 0.3
    assert d.summary()["p_drop"] == 0.3


def test_validation(platoon):
    sysm, cost, g = platoon
    assert design_mtmse_lossy(sysm, cost, g, 5).p_drop == 0.0  # reliable links unless told
    with pytest.raises(ArgumentError, match="horizon"):
        design_mtmse_lossy(sysm, cost, g, None, p_drop=0.1)
    with pytest.raises(ArgumentError, match="p_drop"):
        design_mtmse_lossy(sysm, cost, g, 5, p_drop=1.5)


def test_auto_items_keeps_the_lower_exact_cost():
    """An unstable A on a short horizon: raw measurements stay bounded and cost less than innovations; "auto" keeps them.

    (Before: "auto" picked innovations for every unstable A.) On a long horizon the measurements would grow like
    ρ^(2T) and "auto" designs innovations only.
    """
    A = np.array([[1.3, 0.1], [0.0, 0.8]])
    C = [np.array([[1.0, 0.0]]), np.array([[1.0, 1.0]]), np.array([[0.0, 1.0]])]
    R = [np.array([[0.05]]), np.array([[1.0]]), np.array([[2.0]])]
    sysm, cost, g = LinearGaussianSystem(A, np.eye(2), np.eye(2), C, R), TeamCost.common_target(3, 2, 1.0), CommGraph.line(3)
    cheap = {it: design_mtmse_lossy(sysm, cost, g, 6, p_drop=0.3, items=it, bound=False).total_cost for it in ("measurements", "innovations")}
    assert cheap["measurements"] < 0.9 * cheap["innovations"]  # 56.8 against 67.1
    auto = design_mtmse_lossy(sysm, cost, g, 6, p_drop=0.3, bound=False)
    assert auto.info["items"] == auto.coordinates == "measurements"
    assert auto.total_cost == pytest.approx(cheap["measurements"], rel=1e-12)
    assert auto.info["items_costs"] == pytest.approx(cheap)
    long = design_mtmse_lossy(sysm, cost, g, 40, p_drop=0.3, bound=False)  # 1.3^80 > AUTO_GROWTH: the rule
    assert long.info["items"] == "innovations" and list(long.info["items_costs"]) == ["innovations"]
