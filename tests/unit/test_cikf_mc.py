"""CIKF Monte Carlo against the covariance iterations (statistical; fixed seeds, k = 4 standard errors).

Default suite: a 15-site, 6-agent Section VII-A field (G singular) with 2000 runs.
``slow``: the paper's size, M = N = 50, with 1000 runs over i = 0..30 (Fig. 4).
"""

from __future__ import annotations

import numpy as np
import pytest

from teamkf import TeamCost
from teamkf.estimators.cikf import design_cikf
from teamkf.estimators.kalman import design_centralized
from teamkf.simulation.sampling import sample_paths
from teamkf.study.random_field import random_field

K_SIGMA = 4.0  # every step's Monte Carlo mean within K_SIGMA standard errors of the iterations


def _per_run_mse(e, N, M):
    """(n_runs, T): the agents' average squared error per run and step."""
    return (e.reshape(e.shape[0], e.shape[1], N, M) ** 2).sum(axis=3).mean(axis=2)


def _check_mc(d, paths, form):
    N, M = d.system.n_agents, d.system.dx
    s = _per_run_mse(d.errors(paths, form=form), N, M)
    mean, se = s.mean(axis=0), s.std(axis=0, ddof=1) / np.sqrt(s.shape[0])
    theory = d.mse(form)
    z = (mean - theory) / se
    assert np.all(np.abs(z) < K_SIGMA), f"{form}: worst |z| = {np.abs(z).max():.2f} at step {int(np.argmax(np.abs(z)))}"
    return z


@pytest.fixture(scope="module")
def small():
    sysm, graph = random_field(15, 6, rng=1)
    T = 20
    d = design_cikf(sysm, None, graph, T)
    paths = sample_paths(sysm, T, 2000, rng=2024)
    return d, paths


@pytest.mark.parametrize("form", ["filter", "predictor"])
def test_monte_carlo_matches_iterations(small, form):
    d, paths = small
    _check_mc(d, paths, form)


def test_online_agents_match_iterations(small):
    """Algorithm 1 on the measurements (not the error recursion): L x - simulate(y) has the predicted MSE."""
    d, paths = small
    N, M = d.system.n_agents, d.system.dx
    sub = slice(0, 1000)
    z = d.simulate([y[sub] for y in paths.y])
    e = np.tile(paths.x[sub], (1, 1, N)) - z
    s = _per_run_mse(e, N, M)
    zs = (s.mean(axis=0) - d.mse("filter")) / (s.std(axis=0, ddof=1) / np.sqrt(s.shape[0]))
    assert np.all(np.abs(zs) < K_SIGMA)


def test_filtered_estimates_unbiased(small):
    d, paths = small
    e = d.errors(paths, form="filter")  # (R, T, N M)
    z = e.mean(axis=0) / (e.std(axis=0, ddof=1) / np.sqrt(e.shape[0]))
    assert np.all(np.abs(z) < 5.0)  # 20 x 90 components, correlated; fixed seed
    assert np.mean(z**2) < 2.0


def test_per_agent_mse_matches(small):
    d, paths = small
    N, M = d.system.n_agents, d.system.dx
    e = d.errors(paths, form="filter").reshape(paths.n_runs, paths.n_steps, N, M)
    s = (e**2).sum(axis=3)  # (R, T, N)
    z = (s.mean(axis=0) - d.mse("filter", per_agent=True)) / (s.std(axis=0, ddof=1) / np.sqrt(s.shape[0]))
    assert np.all(np.abs(z) < K_SIGMA + 0.5)  # 120 correlated comparisons


# ---------------------------------------------------------------------------
# the paper's size (slow)
# ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def paper_size():
    sysm, graph = random_field(rng=0)
    T = 32  # predictions Σ_{i+1|i} for i = 0..30
    d = design_cikf(sysm, None, graph, T, form="predictor")
    return d


@pytest.mark.slow
def test_paper_size_monte_carlo_1000_runs(paper_size):
    d = paper_size
    sysm = d.system
    N, M = sysm.n_agents, sysm.dx
    paths = sample_paths(sysm, d.horizon, 1000, rng=7)
    _check_mc(d, paths, "predictor")
    e = d.errors(paths).reshape(1000, d.horizon, N, M)
    z = e.mean(axis=0) / (e.std(axis=0, ddof=1) / np.sqrt(1000))
    assert np.all(np.abs(z) < 5.5)  # 32 x 2500 correlated components
    ckf = design_centralized(sysm, TeamCost.mse(N, M), horizon=d.horizon, form="predictor").stage_costs / N
    assert np.all(d.mse("predictor", per_agent=True) >= ckf[:, None] * (1 - 1e-9))
    gap = 10 * np.log10(d.mse("predictor")[-1] / ckf[-1])
    assert 0.0 < gap < 6.0


@pytest.mark.slow
def test_paper_size_pinv_choices(paper_size):
    """A near-exact cut-off (1e-12) and the eigen pseudo-inverse stay within 1e-3 dB of the default (no drift)."""
    d = paper_size
    for kw in ({"rcond": 1e-12}, {"pinv": "eigh"}):
        other = design_cikf(d.system, None, d.graph, 12, form="predictor", **kw)
        diff = 10 * np.log10(other.mse("predictor") / d.mse("predictor")[:12])
        assert np.abs(diff).max() < 1e-3
