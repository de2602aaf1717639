"""The central oracle: Theorem 2's per-step optimum equals a brute force on the stacked information.

The brute force builds every measurement an agent holds as a linear map of
the primitive variables (x(0), w, v), stacks them, and solves Radner's
person-by-person stationarity conditions with an explicit Kronecker matrix.
It shares no code with the design (no Kalman filter, no innovations, no
common/local split).
"""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from teamkf import CommGraph, InformationStructure, design_mmse, design_mtmse
from tests.helpers import brute_force_team, eq14_information, random_cost, random_system, window_information

RTOL = 1e-8


def _check(system, cost, structure, info_fn, T, *, mmse=False):
    design = (design_mmse if mmse else design_mtmse)(system, cost, structure, horizon=T)
    for k in range(T):
        sets = [info_fn(i, k) for i in range(system.n_agents)]
        J_bf, _ = brute_force_team(system, cost, sets, k, mmse=mmse)
        assert design.stage_costs[k] == pytest.approx(J_bf, rel=RTOL, abs=1e-10), (k, design.stage_costs[k], J_bf)
    return design


def _graph(rng, n, kind):
    if kind == "complete":
        return CommGraph.complete(n, delay=int(rng.integers(1, 3)))
    if kind == "line":
        return CommGraph.line(n)
    if kind == "ring":
        return CommGraph.ring(n, delay=1, directed=True)
    return CommGraph.random(n, p=0.5, delays=(1, 3), rng=rng)


@pytest.mark.parametrize("kind", ["complete", "line", "ring", "random"])
@pytest.mark.parametrize("seed", range(3))
def test_theorem2_equals_brute_force_on_graphs(kind, seed):
    rng = np.random.default_rng(100 + seed)
    n = int(rng.integers(2, 4))
    dx = int(rng.integers(1, 4))
    dys = [int(rng.integers(1, 3)) for _ in range(n)]
    dz = int(rng.integers(1, 3))
    g = _graph(rng, n, kind)
    sys = random_system(rng, n, dx, dys)
    cost = random_cost(rng, n, dx, dz)
    T = g.diameter + 3  # covers t < tau* and the stationary regime
    _check(sys, cost, g, lambda i, k: eq14_information(g, i, k), T)


@pytest.mark.parametrize("seed", range(4))
def test_common_part_choice_does_not_change_optimum(seed):
    """On a line graph the intersection is larger than y(0:k-tau*); a larger common lag changes nothing either."""
    rng = np.random.default_rng(200 + seed)
    n = 3
    g = CommGraph.line(n)
    sys = random_system(rng, n, 2, [1, 2, 1])
    cost = random_cost(rng, n, 2, 1)
    T = 6
    base = _check(sys, cost, g, lambda i, k: eq14_information(g, i, k), T)
    for c in (g.diameter + 1, g.diameter + 2):
        st_c = InformationStructure.from_graph(g, common_lag=c)
        d = design_mtmse(sys, cost, st_c, horizon=T)
        np.testing.assert_allclose(d.stage_costs, base.stage_costs, rtol=RTOL)


@pytest.mark.parametrize("seed", range(4))
def test_reduced_structures_equal_brute_force(seed):
    rng = np.random.default_rng(300 + seed)
    n, c = 3, 3
    local = []
    for i in range(n):
        wins = []
        for j in range(n):
            if rng.random() < 0.7:
                a = int(rng.integers(0, c))
                b = int(rng.integers(a, c))
                wins.append((j, a, b))
        local.append(wins)
    st_ = InformationStructure(n, c, local)
    sys = random_system(rng, n, 2, [1, 2, 1])
    cost = random_cost(rng, n, 2, 2)
    _check(sys, cost, st_, lambda i, k: window_information(n, c, local, i, k), 6)


@pytest.mark.parametrize("seed", range(3))
def test_time_varying_system_and_cost(seed):
    rng = np.random.default_rng(400 + seed)
    n, T = 3, 6
    g = CommGraph.random(n, p=0.6, delays=(1, 2), rng=rng)
    sys = random_system(rng, n, 3, [1, 1, 2], time_varying=True, n_steps=T)
    cost = random_cost(rng, n, 3, 1, time_varying=True, n_steps=T)
    _check(sys, cost, g, lambda i, k: eq14_information(g, i, k), T)


@pytest.mark.parametrize("seed", range(3))
def test_mmse_cost_equals_brute_force(seed):
    rng = np.random.default_rng(500 + seed)
    n = 3
    g = CommGraph.line(n, delay=1)
    sys = random_system(rng, n, 2, [1, 2, 1])
    cost = random_cost(rng, n, 2, 1)
    _check(sys, cost, g, lambda i, k: eq14_information(g, i, k), 5, mmse=True)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(2, 3), dx=st.integers(1, 3), dz=st.integers(1, 2))
def test_property_random_graphs(seed, n, dx, dz):
    rng = np.random.default_rng(seed)
    g = CommGraph.random(n, p=0.5, delays=(1, 3), rng=rng)
    dys = [int(rng.integers(1, 3)) for _ in range(n)]
    sys = random_system(rng, n, dx, dys)
    cost = random_cost(rng, n, dx, dz)
    T = min(g.diameter + 2, 7)
    _check(sys, cost, g, lambda i, k: eq14_information(g, i, k), T)
