"""``method="joint"``: Algorithm 2 as one recursion on cov([e; ε]) against the block-operator implementation.

The two differ only in the order of the floating-point operations. Everything the filter's performance is
made of (Σ_{k|k-1}, Σ_{k|k}, tr P, the stage costs) agrees to 1e-10 relative. Theorem 4's consensus gains
themselves are determined only to about 1e-8 relative by the covariances (Σ_ν̃ is formed by cancellation
and is ill-conditioned; scaling P by 1 + 2^-52 moves the reference's own gains by as much, and can move a
pivot of the cut-off), so the gains are checked through what they do: with the joint design's gains fixed,
the block-operator recursion reproduces the joint design's covariances to 1e-10, and with fixed gains the
two methods agree on everything.
"""

from __future__ import annotations

import numpy as np
import pytest

from teamkf import TeamCost
from teamkf.estimators.cikf import _mse_cost, design_cikf
from teamkf.exceptions import ArgumentError

from ._close import close as _close
from ._close import compare_to_reference
from .cikf_reference import reference_iterate


def _same_covariances(a, b):
    for name in ("Sigma_pred", "Sigma_filt", "P_pred_trace", "stage_costs"):
        _close(getattr(a, name), getattr(b, name), name)


@pytest.mark.parametrize("form", ["filter", "predictor"])
@pytest.mark.parametrize("pinv", ["cholesky", "eigh"])
def test_joint_covariances_match_structured(field12, field_singular, form, pinv):
    for sysm, graph in (field12, field_singular):
        a = design_cikf(sysm, None, graph, 12, form=form, pinv=pinv, method="joint")
        b = design_cikf(sysm, None, graph, 12, form=form, pinv=pinv, method="structured")
        _same_covariances(a, b)
        assert a.info["method"] == "joint"


@pytest.mark.parametrize("form", ["filter", "predictor"])
def test_joint_covariances_are_those_of_its_gains(field12, field_singular, form):
    """The block-operator recursion run with the joint design's gains gives the joint design's covariances."""
    for sysm, graph in (field12, field_singular):
        a = design_cikf(sysm, None, graph, 12, form=form, method="joint")
        b = design_cikf(sysm, None, graph, 12, form=form, gains=a, method="structured")
        _same_covariances(a, b)
        _close(a.K, b.K, "K")


def test_joint_fixed_gains_match_reference(field_singular):
    sysm, graph = field_singular
    g = design_cikf(sysm, None, graph, 10, rcond=1e-6)
    d = design_cikf(sysm, None, graph, 8, gains=g, method="joint")
    ref = reference_iterate(sysm, graph, 8, cost=_mse_cost(sysm.n_agents, sysm.dx), form="filter", fixed=g)
    compare_to_reference(d, ref, gains=False)
    _close(d.K, ref["K"], "K")


@pytest.mark.parametrize("form", ["filter", "predictor"])
def test_joint_general_cost(field_singular, form):
    sysm, graph = field_singular
    N, M = sysm.n_agents, sysm.dx
    rng = np.random.default_rng(3)
    L = rng.standard_normal((2 * N, M))
    B = rng.standard_normal((2 * N, 2 * N))
    cost = TeamCost(S=B @ B.T + np.eye(2 * N), L=L, n_agents=N)
    a = design_cikf(sysm, cost, graph, 8, form=form, method="joint")
    b = design_cikf(sysm, cost, graph, 8, form=form, gains=a, method="structured")
    _same_covariances(a, b)
    _close(a.stage_costs, design_cikf(sysm, cost, graph, 8, form=form, method="structured").stage_costs, "stage_costs vs structured")


def test_joint_threads_do_not_change_the_numbers(field12):
    sysm, graph = field12
    a = design_cikf(sysm, None, graph, 8, method="joint", threads=1)
    b = design_cikf(sysm, None, graph, 8, method="joint", threads=2)
    for k in range(8):
        for n in range(sysm.n_agents):
            assert np.array_equal(a.B_cons[k][n], b.B_cons[k][n]) and np.array_equal(a.B_innov[k][n], b.B_innov[k][n])
    for name in ("K", "Sigma_pred", "Sigma_filt", "P_pred_trace", "stage_costs"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name


def test_joint_runs_the_corrected_equations_only(field_singular):
    sysm, graph = field_singular
    with pytest.raises(ArgumentError, match="method='joint'"):
        design_cikf(sysm, None, graph, 4, method="joint", equations="printed")


def test_joint_in_place_sandwich(field12, monkeypatch):
    """Large problems form M P M' in place of M P (no separate (M P)'): the same numbers to round-off."""
    import teamkf.estimators.cikf.joint as cikf_joint

    sysm, graph = field12
    a = design_cikf(sysm, None, graph, 8, method="joint", threads=2)
    monkeypatch.setattr(cikf_joint, "_MPT_BYTES", 0)
    b = design_cikf(sysm, None, graph, 8, method="joint", threads=2)
    _same_covariances(b, a)
    assert np.array_equal(b.stage_costs, design_cikf(sysm, None, graph, 8, method="joint", threads=1).stage_costs)
