"""The message-passing runtime delivers exactly what the graph allows; the two Monte Carlo paths agree."""

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
)
from teamkf.simulation.monte_carlo import _team_errors, monte_carlo
from teamkf.simulation.runtime import graph_agents, run_graph
from teamkf.simulation.sampling import sample_paths
from tests.helpers import random_cost, random_system


def _designs(system, cost, graph, T):
    return {
        "mtmse": design_mtmse(system, cost, graph, T),
        "mmse": design_mmse(system, cost, graph, T),
        "centralized": design_centralized(system, cost, horizon=T),
    }


@pytest.mark.parametrize("seed", range(6))
def test_information_discipline(seed):
    """Change y_j(s): agent i's estimates up to s + ell_ji - 1 are bit-for-bit unchanged, and change later."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 5))
    g = CommGraph.random(n, p=0.4, delays=(1, 3), rng=rng)
    system = random_system(rng, n, 2, [1] * n, stable=True)
    cost = random_cost(rng, n, 2, 1)
    T = g.diameter + 6
    paths = sample_paths(system, T, 3, rng=seed)
    ell = g.geodesic_delays()
    for name, d in _designs(system, cost, g, T).items():
        z0 = run_graph(graph_agents(d), g, paths.y)
        for _ in range(3):
            j, s = int(rng.integers(n)), int(rng.integers(T - g.diameter - 1))
            y1 = [yy.copy() for yy in paths.y]
            y1[j][:, s] += 1.0
            z1 = run_graph(graph_agents(d), g, y1)
            for i in range(n):
                lag = 0 if name == "centralized" else int(ell[j, i])
                blk = slice(i * cost.dz, (i + 1) * cost.dz)
                np.testing.assert_array_equal(z0[:, : s + lag, blk], z1[:, : s + lag, blk])
                assert np.any(z0[:, s + lag :, blk] != z1[:, s + lag :, blk]), (name, i, j, s)


def test_runtime_equals_structure_delivery_and_reduced_structures():
    system, cost, g = LinearGaussianSystem.platoon(4), TeamCost.platoon(4, 10.0), CommGraph.line(4)
    IS1 = InformationStructure(
        4, 3, [[(0, 0, 1), (1, 1, 1)], [(0, 1, 1), (1, 0, 1), (2, 1, 1)], [(1, 1, 1), (2, 0, 1), (3, 1, 1)], [(2, 1, 1), (3, 0, 1)]]
    )
    paths = sample_paths(system, 15, 4, rng=0)
    for st in (g, IS1):
        d = design_mtmse(system, cost, st, 15)
        np.testing.assert_array_equal(run_graph(graph_agents(d), g, paths.y), run_online(d.agents(), paths.y))


@pytest.mark.parametrize("steady", [False, True])
def test_error_path_equals_runtime_path_on_stable_systems(steady):
    rng = np.random.default_rng(4)
    system = random_system(rng, 3, 3, [1, 2, 1], stable=True)
    cost = random_cost(rng, 3, 3, 2)
    g = CommGraph.random(3, p=0.5, delays=(1, 2), rng=rng)
    T = 20
    designs = {
        "mtmse": design_mtmse(system, cost, g, None if steady else T),
        "mmse": design_mmse(system, cost, g, None if steady else T),
        "centralized": design_centralized(system, cost, horizon=None if steady else T),
    }
    paths = sample_paths(system, T, 6, rng=1)
    for d in designs.values():
        e_err = d.errors(paths)
        e_run = _team_errors(d, paths, "runtime", g)
        np.testing.assert_allclose(e_err, e_run, rtol=1e-9, atol=1e-9)


def test_unstable_uav10_error_path_is_accurate_where_the_runtime_path_is_not():
    """Spectral radius 1.55: x(100) ~ 1e19 and L x - z from simulated states loses every digit."""
    n, T = 10, 100
    system, cost, g = LinearGaussianSystem.uav_formation(n), TeamCost.average_tracking(n, 1000.0), CommGraph.complete(n, 2)
    designs = _designs(system, cost, g, T)
    mc = monte_carlo(designs, T, 1000, rng=11)
    for name, d in designs.items():
        assert abs(mc[name].total_mean - d.total_cost) < 4 * mc[name].total_sem
    paths = sample_paths(system, T, 20, rng=2)
    assert np.abs(paths.x[:, -1]).max() > 1e15
    e_run = _team_errors(designs["mtmse"], paths, "runtime", None)
    e_err = designs["mtmse"].errors(paths)
    np.testing.assert_allclose(e_run[:, :10], e_err[:, :10], rtol=1e-6, atol=1e-8)  # early steps: both accurate
    assert np.abs(e_run[:, -1]).max() > 1e3 * np.abs(e_err[:, -1]).max()  # late steps: cancellation


def test_monte_carlo_does_not_depend_on_batching():
    system, cost, g = LinearGaussianSystem.platoon(4), TeamCost.platoon(4, 10.0), CommGraph.line(4)
    d = {"mtmse": design_mtmse(system, cost, g, 10)}
    a = monte_carlo(d, 10, 50, rng=5, batch=50)["mtmse"]
    b = monte_carlo(d, 10, 50, rng=5, batch=7)["mtmse"]
    np.testing.assert_allclose(a.stage_mean, b.stage_mean, rtol=1e-12)  # same draws; BLAS blocking may differ in the last bit


def test_sampling_streams_per_run():
    system = LinearGaussianSystem.platoon(4)
    full = sample_paths(system, 8, 10, rng=3)
    from teamkf.simulation.sampling import RunStreams, run_streams

    part = sample_paths(system, 8, 4, rng=3, first_run=6)  # runs 6..9 of seed 3, drawn alone
    np.testing.assert_array_equal(full.x[6:], part.x)
    one = sample_paths(system, 8, 1, rng=None, streams=RunStreams(3), first_run=8)
    np.testing.assert_allclose(full.y[1][8], one.y[1][0], rtol=1e-13)  # same draws; a 1-run product may round differently
    # run r's stream is Philox(key(seed), counter (0, 0, r, 0)), built on demand
    m = system.dx * 8 + 8 * sum(system.dy)
    np.testing.assert_array_equal(RunStreams(3).normals(2, 3, m)[0], RunStreams(3).generator(2).standard_normal(m))
    # explicit SeedSequences per run still work
    seqs = run_streams(3, 10)
    a = sample_paths(system, 8, 4, rng=None, streams=seqs[6:])
    b = sample_paths(system, 8, 10, rng=None, streams=seqs)
    np.testing.assert_array_equal(a.x, b.x[6:])
    for a, b in zip(full.y, part.y):
        np.testing.assert_array_equal(a[6:], b)
    # x and y are consistent with the primitive noises
    np.testing.assert_allclose(full.x[:, 1], full.x[:, 0] @ system.A_at(0).T + full.w[:, 0])
    np.testing.assert_allclose(full.y[2][:, 5], full.x[:, 5] @ system.C_at(2, 5).T + full.v[2][:, 5])


def test_sampling_time_varying_and_statistics():
    rng = np.random.default_rng(0)
    system = random_system(rng, 2, 2, [1, 2], time_varying=True, n_steps=4)
    p = sample_paths(system, 4, 40_000, rng=9)
    from teamkf.estimators.kalman import kalman_covariances

    # covariance of x(3) = Phi Sigma_x Phi' + sum Phi Q Phi'
    P = system.Sigma_x
    for k in range(3):
        P = system.A_at(k) @ P @ system.A_at(k).T + system.Q_at(k)
    emp = np.cov(p.x[:, 3].T)
    assert np.abs(emp - P).max() < 0.05 * max(1.0, np.abs(P).max())
    kalman_covariances(system, 4)
