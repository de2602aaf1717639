"""Online agents reproduce their designs: Monte Carlo within k standard errors of the analytic cost.

k = 4 (two-sided): with a fixed seed the test is deterministic; under the null
each comparison fails with probability ~6e-5.
"""

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
    run_online,
    sample,
)
from teamkf.simulation.monte_carlo import monte_carlo
from tests.helpers import random_cost, random_system

K_SIGMA = 4.0


@pytest.mark.parametrize("case", ["platoon", "platoon-IS1", "uav4", "random"])
def test_monte_carlo_matches_analytic(case):
    T = 25
    if case.startswith("platoon"):
        sys, cost, g = LinearGaussianSystem.platoon(4), TeamCost.platoon(4, 10.0), CommGraph.line(4)
        st = (
            g
            if case == "platoon"
            else InformationStructure(
                4, 3, [[(0, 0, 1), (1, 1, 1)], [(0, 1, 1), (1, 0, 1), (2, 1, 1)], [(1, 1, 1), (2, 0, 1), (3, 1, 1)], [(2, 1, 1), (3, 0, 1)]]
            )
        )
    elif case == "uav4":
        sys, cost, g = LinearGaussianSystem.uav_formation(4), TeamCost.average_tracking(4, 160.0), CommGraph.complete(4, 2)
        st = g
    else:
        rng = np.random.default_rng(5)
        sys = random_system(rng, 3, 3, [1, 2, 1], stable=True)
        cost = random_cost(rng, 3, 3, 2)
        st = CommGraph.random(3, p=0.5, delays=(1, 3), rng=rng)
    designs = {
        "mtmse": design_mtmse(sys, cost, st, T),
        "mmse": design_mmse(sys, cost, st, T),
        "centralized": design_centralized(sys, cost, horizon=T),
    }
    mc = monte_carlo(designs, T, 3000, rng=2024)
    for name, d in designs.items():
        r = mc[name]
        assert abs(r.total_mean - d.total_cost) <= K_SIGMA * r.total_sem, (name, r.total_mean, d.total_cost, r.total_sem)
        z = (r.stage_mean - d.stage_costs) / r.stage_sem
        assert np.max(np.abs(z)) < 4.5, (name, z)
    assert mc["centralized"].total_mean < mc["mtmse"].total_mean < mc["mmse"].total_mean


def test_steady_state_agents_reach_average_cost():
    sys, cost, g = LinearGaussianSystem.platoon(4), TeamCost.platoon(4, 10.0), CommGraph.line(4)
    d = design_mtmse(sys, cost, g)
    T = 60
    x, y = sample(sys, T, 3000, rng=7)
    z = run_online(d.agents(), y)
    c = np.stack([cost.value(x[:, k], z[:, k]) for k in range(30, T)], axis=1).mean(axis=1)
    assert abs(c.mean() - d.average_cost) < K_SIGMA * c.std(ddof=1) / np.sqrt(c.size)


def test_single_agent_mtmse_agent_is_the_kalman_filter_exactly():
    rng = np.random.default_rng(3)
    sys = random_system(rng, 1, 3, [2], stable=True)
    cost = random_cost(rng, 1, 3, 3)
    g = CommGraph(1, ())
    T = 12
    x, y = sample(sys, T, 5, rng=1)
    z_team = run_online(design_mtmse(sys, cost, g, T).agents(), y)
    z_kf = run_online(design_centralized(sys, cost, horizon=T).agents(), y)
    np.testing.assert_allclose(z_team, z_kf, rtol=1e-9, atol=1e-9)


def test_agents_do_not_need_undelivered_data():
    """Agents fail loudly if a measurement they need was never delivered."""
    sys, cost, g = LinearGaussianSystem.platoon(4), TeamCost.platoon(4, 10.0), CommGraph.line(4)
    ag = design_mtmse(sys, cost, g, 5).agents()[0]
    state = ag.init_state(2)
    with pytest.raises(ValueError, match="not delivered"):
        ag.step(state, 0, [])
