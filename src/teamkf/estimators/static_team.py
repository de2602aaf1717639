"""Theorem 1 of Afshari & Mahajan (2021): the static team estimate with a common measurement, and the one
static solve that every step of Theorems 2-3 makes (:mod:`teamkf.estimators.team` calls it).

Available on its own as :func:`teamkf.static_team_estimate`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from .. import _validation as V
from .._lazy import scipy_linalg as sla  # SciPy / networkx load on first use
from .._validation import FloatArray
from ..exceptions import ShapeError
from ..models import LinearGaussianSystem, TeamCost
from ._gamma_shared import SharedSensorInnovations, block_mask, shared_sensor_window
from .gamma import DENSE_MAX_BYTES, GammaProblem, InnovationsProblem, WindowModel

__all__ = ["StaticTeamEstimate", "static_team_estimate", "gains_team_cost"]


# ---------------------------------------------------------------------------
# Theorem 1: static estimation with a common measurement
# ---------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class StaticTeamEstimate:
    """The MTMSE estimate z_i = L_i x^_0 + F_i (y_i - y^_i) of Theorem 1.

    Built by :func:`~teamkf.static_team_estimate`.

    Parameters
    ----------
    F : list of (d_z, d_i) arrays
        Gains on the local innovations (eq. 10).
    common_gain : (d_x, d_0) array
        x^_0 = common_gain @ y_0 (Lemma 1.3).
    local_prediction : list of (d_i, d_0) arrays
        y^_i = local_prediction[i] @ y_0 (Lemma 1.4).
    cost : float
        J*, the team-optimal cost (eq. 11).
    mmse_cost : float
        The team cost of z_i = L_i E[x | y_0, y_i] (the per-agent MMSE baseline).
    P0 : (d_x, d_x) array
        var(x - x^_0).
    Theta_hat : list of arrays
        cov(x - x^_0, y_i - y^_i), per agent.
    Sigma_hat : array or None
        The joint covariance of the local innovations (y_i - y^_i).

    See Also
    --------
    static_team_estimate

    Examples
    --------
    >>> import numpy as np
    >>> from teamkf import TeamCost, static_team_estimate
    >>> Sig = np.array([[1.0, 1, 1], [1, 2, 1], [1, 1, 2]])
    >>> est = static_team_estimate(Sig, (1, 0, 1, 1), TeamCost.common_target(2, 1, 4.0))
    >>> est.cost <= est.mmse_cost, [F.shape for F in est.F]
    (True, [(1, 1), (1, 1)])
    """

    F: list[FloatArray]
    common_gain: FloatArray
    local_prediction: list[FloatArray]
    cost: float
    mmse_cost: float
    P0: FloatArray
    Theta_hat: list[FloatArray] = field(repr=False, default_factory=list)
    Sigma_hat: FloatArray | None = field(repr=False, default=None)

    def estimate(self, y0: FloatArray | None, y: Sequence[FloatArray], L: FloatArray, dz: int) -> FloatArray:
        """Apply the strategy to measurements (batched along the first axis): returns z, (..., n d_z)."""
        y0a = np.zeros(self.common_gain.shape[1]) if y0 is None else np.asarray(y0)
        x0 = y0a @ self.common_gain.T
        zs = []
        for i, Fi in enumerate(self.F):
            innov = np.asarray(y[i]) - y0a @ self.local_prediction[i].T
            zs.append(x0 @ L[i * dz : (i + 1) * dz].T + innov @ Fi.T)
        return np.concatenate(zs, axis=-1)


def static_team_estimate(joint_cov: Any, dims: Sequence[int], cost: TeamCost, *, method: str = "auto") -> StaticTeamEstimate:
    """Theorem 1: the team-optimal estimate when agent i holds (y_0, y_i).

    Parameters
    ----------
    joint_cov : array
        Covariance of the zero-mean Gaussian vector (x, y_0, y_1, ..., y_n).
    dims : sequence of int
        (d_x, d_0, d_1, ..., d_n); d_0 = 0 means no common measurement.
    cost : TeamCost
        S and L (constant).
    method : "auto", "dense" or "cg"
        How Γ F = η is solved (see :mod:`teamkf.estimators.gamma`).

    Returns
    -------
    StaticTeamEstimate
        The gains F_i, the common estimate's gain and the costs J* and J_MMSE.

    Examples
    --------
    The two-agent example of the introduction (sigma = 1, lambda = 4):

    >>> import numpy as np
    >>> from teamkf import TeamCost, static_team_estimate
    >>> s2 = 1.0
    >>> Sig = np.array([[1, 1, 1], [1, 1 + s2, 1], [1, 1, 1 + s2]])
    >>> est = static_team_estimate(Sig, (1, 0, 1, 1), TeamCost.common_target(2, 1, 4.0))
    >>> round(est.cost, 6)  # (2 + lam) alpha s2 / (1 + alpha s2), alpha = 2/3
    2.4
    """
    if isinstance(dims, (str, bytes)) or not hasattr(dims, "__len__") or np.ndim(dims) != 1:
        raise ShapeError(f"dims: expected a sequence (d_x, d_0, d_1, ..., d_n) of whole numbers, found {V.describe(dims)}")
    dims = [V.integer(d, f"dims[{k}]", minimum=0) for k, d in enumerate(dims)]
    V.instance(cost, "cost", TeamCost, "a TeamCost", "build one with teamkf.TeamCost(...)")
    if len(dims) < 3 or any(d < 0 for d in dims) or dims[0] < 1:
        raise ShapeError(f"dims: expected (d_x, d_0, d_1, ..., d_n) with d_x >= 1 and d_i >= 0, found {tuple(dims)}")
    n = len(dims) - 2
    tot = sum(dims)
    Sig = V.covariance(joint_cov, "joint_cov", tot)
    cost.check_system(dims[0], n)
    off = np.concatenate([[0], np.cumsum(dims)]).astype(int)
    blk = [slice(off[m], off[m + 1]) for m in range(len(dims))]
    x, y0 = blk[0], blk[1]
    ys_all = np.concatenate([np.arange(off[m], off[m + 1]) for m in range(2, len(dims))])
    if dims[1] > 0:
        S00 = Sig[y0, y0]
        cf = sla.cho_factor(S00, lower=True)
        common_gain = sla.cho_solve(cf, Sig[y0, x]).T  # Theta_0 Sigma_00^-1  (Lemma 1.3)
        pred = sla.cho_solve(cf, Sig[y0][:, ys_all]).T  # Sigma_i0 Sigma_00^-1 (Lemma 1.4)
        Sig_loc = Sig[np.ix_(ys_all, ys_all)] - pred @ Sig[y0][:, ys_all]  # Lemma 1.2
        Theta = Sig[x][:, ys_all] - common_gain @ Sig[y0][:, ys_all]  # Lemma 1.1 (cov(x, y~_i))
        P0 = Sig[x, x] - common_gain @ Sig[y0, x]
    else:
        common_gain = np.zeros((dims[0], 0))
        pred = np.zeros((len(ys_all), 0))
        Sig_loc = Sig[np.ix_(ys_all, ys_all)]
        Theta = Sig[x][:, ys_all]
        P0 = Sig[x, x]
    loc_off = np.concatenate([[0], np.cumsum(dims[2:])]).astype(int)
    idx = [np.arange(loc_off[i], loc_off[i + 1]) for i in range(n)]
    for i in range(n):
        if idx[i].size:
            V.covariance(Sig_loc[np.ix_(idx[i], idx[i])], f"Sigma_hat[{i}]", definite=True)
    F, J, J_mmse = _solve_step(cost.S_at(0), cost.L_at(0), Sig_loc, Theta, P0, idx, cost.dz, method=method)
    return StaticTeamEstimate(
        F=F,
        common_gain=common_gain,
        local_prediction=[pred[idx[i]] for i in range(n)],
        cost=J,
        mmse_cost=J_mmse,
        P0=P0,
        Theta_hat=[Theta[:, idx[i]] for i in range(n)],
        Sigma_hat=Sig_loc,
    )


# ---------------------------------------------------------------------------
# the static solve of one step (Theorem 1; Theorems 2-3 call it every step)
# ---------------------------------------------------------------------------
def _eta(S: FloatArray, L: FloatArray, Theta_W: FloatArray, idx: list[np.ndarray], dz: int) -> list[FloatArray]:
    """eta_i = S_i. L Theta^_i (eq. 34), as (d_z, d_i) matrices."""
    SL = S @ L
    return [SL[i * dz : (i + 1) * dz] @ Theta_W[:, ix] for i, ix in enumerate(idx)]


def _mmse_gains(L: FloatArray, Sigma_W: FloatArray, Theta_W: FloatArray, idx: list[np.ndarray], dz: int) -> list[FloatArray]:
    """F_i = L_i Theta^_i Sigma^_ii^-1: z_i = L_i E[x(k) | I_i(k)] (eq. 46)."""
    out = []
    for i, ix in enumerate(idx):
        if ix.size == 0:
            out.append(np.zeros((dz, 0)))
            continue
        cf = sla.cho_factor(Sigma_W[np.ix_(ix, ix)], lower=True, check_finite=False)
        out.append(sla.cho_solve(cf, (L[i * dz : (i + 1) * dz] @ Theta_W[:, ix]).T, check_finite=False).T)
    return out


def gains_team_cost(gamma: GammaProblem, eta: list[FloatArray], F: list[FloatArray], trace_term: float) -> float:
    """Team cost of any linear strategy z_i = L_i x^com + F_i I~_i:  Tr(L'SL P_0) - 2 <F, eta> + <F, Gamma F>."""
    return float(trace_term - 2.0 * sum(float(np.sum(f * e)) for f, e in zip(F, eta)) + gamma.quad(F))


def _solve_step(
    S: FloatArray,
    L: FloatArray,
    Sigma_W: FloatArray,
    Theta_W: FloatArray,
    P0: FloatArray,
    idx: list[np.ndarray],
    dz: int,
    *,
    method: Any = "auto",
    dense_max_bytes: int = DENSE_MAX_BYTES,
    want: str = "both",
    gamma_info: dict[str, Any] | None = None,
) -> tuple[list[FloatArray], float, float]:
    """MTMSE gains and cost, and the MMSE cost, for one step."""
    gamma = GammaProblem(S, Sigma_W, idx, dz)
    eta = _eta(S, L, Theta_W, idx, dz)
    trace_term = float(np.trace(L.T @ S @ L @ P0))
    F: list[FloatArray] = []
    J = J_mmse = float("nan")
    if want in ("both", "mtmse"):
        F = gamma.solve(eta, method=method, dense_max_bytes=dense_max_bytes)
        J = trace_term - sum(float(np.sum(f * e)) for f, e in zip(F, eta))  # eq. (35)
        if gamma_info is not None:
            gamma_info.update(method=gamma.method_used, size=gamma.size, iterations=gamma.iterations)
    if want in ("both", "mmse"):
        Fm = _mmse_gains(L, Sigma_W, Theta_W, idx, dz)
        J_mmse = gains_team_cost(gamma, eta, Fm, trace_term)  # eq. (47)
        if want == "mmse":
            F = Fm
    return F, J, J_mmse


def _solve_step_innovations(
    system: LinearGaussianSystem, cost: TeamCost, k: int, anchor: int, P_anchor: FloatArray, idx: list[np.ndarray], dz: int
) -> tuple[list[FloatArray], float, dict[str, Any]]:
    """MTMSE gains and cost of one step by CG in the agents' innovation coordinates (:class:`InnovationsProblem`).

    When every agent measures with the same C_i and R_i (the platoons: every vehicle measures all positions)
    the filters are run on the shared sensor (:class:`~teamkf.estimators._gamma_shared.SharedSensorInnovations`):
    the same answer, with no k x d_x matrix per step and no window-sized R.
    """
    w = k - anchor + 1
    window = shared_sensor_window(system, anchor, w, P_anchor)
    if window is not None and block_mask(idx, w, window.n_src, window.C[0].shape[0]) is not None:
        shared = SharedSensorInnovations(cost.S_at(k), cost.L_at(k), window, idx, dz)
        F, J = shared.solve()
        return F, J, {"method": "cg", "size": shared.size, "iterations": shared.iterations, "coordinates": "innovations", "sensors": "shared"}
    model = WindowModel(
        A=[system.A_at(anchor + u) for u in range(w - 1)],
        Q=[system.Q_at(anchor + u) for u in range(w - 1)],
        C=[system.C_stack(anchor + u) for u in range(w)],
        R=[system.R_stack(anchor + u) for u in range(w)],
        P0=np.asarray(P_anchor, dtype=float),
    )
    prob = InnovationsProblem(cost.S_at(k), cost.L_at(k), model, idx, dz)
    F, J = prob.solve()
    return F, J, {"method": "cg", "size": prob.size, "iterations": prob.iterations, "coordinates": "innovations"}
