"""The fast CIKF design and error recursion are pinned to the pre-change implementation (1e-10 relative).

``cikf_reference.py`` is a frozen copy of Algorithm 2 and of the error recursion as they were before the
speed work (one BLAS call per block, Python loops over agents). The library's batched implementation must
reproduce its gains, covariances, stage costs, simulated estimates and errors on small instances, for every
option that changes the code path (form, pseudo-inverse, general cost, printed equations, fixed gains).
"""

from __future__ import annotations

import numpy as np
import pytest

from teamkf import TeamCost
from teamkf.estimators.cikf import _mse_cost, design_cikf
from teamkf.simulation.sampling import sample_paths
from teamkf.study.random_field import random_field

from .cikf_reference import recursion_impl, reference_iterate

RTOL = 1e-10


def _close(got, want, what):
    got, want = np.asarray(got, dtype=float), np.asarray(want, dtype=float)
    assert got.shape == want.shape, what
    scale = max(float(np.abs(want).max()), 1e-300)
    err = float(np.abs(got - want).max()) / scale
    assert err <= RTOL, f"{what}: max relative difference {err:.2e} > {RTOL:.0e}"


def _compare(d, ref):
    T = d.horizon
    for k in range(T):
        for n in range(d.n_agents):
            _close(d.B_cons[k][n], ref["B_cons"][k][n], f"B_cons[{k}][{n}]")
            _close(d.B_innov[k][n], ref["B_innov"][k][n], f"B_innov[{k}][{n}]")
    _close(d.K, ref["K"], "K")
    _close(d.Sigma_pred, ref["Sigma_pred"], "Sigma_pred")
    _close(d.Sigma_filt, ref["Sigma_filt"], "Sigma_filt")
    _close(d.P_pred_trace, ref["P_pred_trace"], "P_pred_trace")
    _close(d.stage_costs, ref["stage"], "stage_costs")


@pytest.fixture(scope="module")
def field12():
    return random_field(12, 12, rng=0)


@pytest.fixture(scope="module")
def field_singular():
    return random_field(15, 6, rng=1)  # G singular (some sites unobserved)


@pytest.mark.parametrize("form", ["filter", "predictor"])
@pytest.mark.parametrize("pinv", ["cholesky", "eigh"])
def test_design_matches_reference(field12, field_singular, form, pinv):
    for sysm, graph in (field12, field_singular):
        T = 12
        d = design_cikf(sysm, None, graph, T, form=form, pinv=pinv)
        assert d.model.rank <= sysm.dx
        ref = reference_iterate(sysm, graph, T, cost=_mse_cost(sysm.n_agents, sysm.dx), form=form, pinv=pinv)
        _compare(d, ref)


@pytest.mark.parametrize("threads", [1, 2])
def test_design_matches_reference_threads(field_singular, threads):
    sysm, graph = field_singular
    d = design_cikf(sysm, None, graph, 10, threads=threads)
    ref = reference_iterate(sysm, graph, 10, cost=_mse_cost(sysm.n_agents, sysm.dx), form="filter")
    _compare(d, ref)


@pytest.mark.parametrize("form", ["filter", "predictor"])
def test_general_cost_matches_reference(field_singular, form):
    sysm, graph = field_singular
    N, M = sysm.n_agents, sysm.dx
    rng = np.random.default_rng(3)
    L = rng.standard_normal((2 * N, M))
    B = rng.standard_normal((2 * N, 2 * N))
    cost = TeamCost(S=B @ B.T + np.eye(2 * N), L=L, n_agents=N)
    d = design_cikf(sysm, cost, graph, 8, form=form)
    ref = reference_iterate(sysm, graph, 8, cost=cost, form=form)
    _compare(d, ref)


@pytest.mark.parametrize("equations", ["printed", "printed-43", "printed-45"])
def test_printed_equations_match_reference(field_singular, equations):
    sysm, graph = field_singular
    d = design_cikf(sysm, None, graph, 8, equations=equations)
    ref = reference_iterate(sysm, graph, 8, cost=_mse_cost(sysm.n_agents, sysm.dx), form="filter", equations=equations)
    _compare(d, ref)


def test_fixed_gains_match_reference(field_singular):
    sysm, graph = field_singular
    g = design_cikf(sysm, None, graph, 10, rcond=1e-6)
    d = design_cikf(sysm, None, graph, 8, gains=g)
    ref = reference_iterate(sysm, graph, 8, cost=_mse_cost(sysm.n_agents, sysm.dx), form="filter", fixed=g)
    _compare(d, ref)


@pytest.mark.parametrize("form", ["filter", "predictor"])
@pytest.mark.parametrize("threads", [1, 2])
def test_errors_and_simulate_match_reference(field12, field_singular, form, threads):
    for sysm, graph in (field12, field_singular):
        T = 10
        d = design_cikf(sysm, None, graph, T, form=form, threads=threads)
        paths = sample_paths(sysm, T, 37, rng=5)
        want_e = recursion_impl(d, paths.v, paths.x[:, 0], paths.w, paths.n_runs, T, form)
        _close(d.errors(paths), want_e, "errors")
        want_z = recursion_impl(d, paths.y, None, None, paths.n_runs, T, form)
        _close(d.simulate(paths.y), want_z, "simulate")


def test_errors_general_cost_match_reference(field_singular):
    sysm, graph = field_singular
    N, M = sysm.n_agents, sysm.dx
    L = np.random.default_rng(4).standard_normal((N, M))
    cost = TeamCost(S=np.eye(N), L=L, n_agents=N)
    d = design_cikf(sysm, cost, graph, 6)
    paths = sample_paths(sysm, 6, 11, rng=6)
    _close(d.errors(paths), recursion_impl(d, paths.v, paths.x[:, 0], paths.w, 11, 6, "filter"), "errors (general L)")
