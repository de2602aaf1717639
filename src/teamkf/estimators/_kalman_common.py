r"""The centralized Kalman recursion that several families share (the centralized bound, MTMSE/MMSE, the consensus baselines).

Notation (team-MMSE paper eqs. 20-22; steps 0-based):

===========  ==================================================================
P(k)         var(x(k) | y(0:k-1)), predictor covariance; P(0) = Sigma_x
K(k)         P(k) C(k)' [C(k) P(k) C(k)' + R(k)]^-1                     (eq. 21)
P(k|k)       (I - K C) P(k) (I - K C)' + K R K'  (Joseph form)
P(k+1)       A(k) P(k|k) A(k)' + Q(k)                                  (eq. 22)
eps(k+1)     A(k)[eps(k) - K(k)(C(k) eps(k) + v(k))] + w(k)            (predictor error)
===========  ==================================================================

Family modules import these from here, never from each other (the import-linter
independence contract in ``pyproject.toml``); :mod:`teamkf.estimators.kalman`
re-exports them as its public names.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .. import _validation as V
from .._lazy import scipy_linalg as sla  # SciPy / networkx load on first use
from .._validation import FloatArray
from ..models import LinearGaussianSystem

__all__ = ["kalman_step", "kalman_covariances", "steady_state", "predictor_errors"]

#: steady_state takes the information form (:func:`~teamkf.estimators.riccati.steady_state_kalman_blocks`) from this
#: many stacked measurements on (and at least 4 per state): the dense d_y x d_y factorizations cost more than the rest of
#: a steady platoon design from n = 20 on (d_y = 400); below, the dense form (bit for bit as before)
BLOCK_DARE_MIN_DY = 400


def kalman_step(P: FloatArray, C: FloatArray, R: FloatArray) -> tuple[FloatArray, FloatArray]:
    """One measurement update: returns (K, P(k|k)) from the predictor covariance P (eq. 21)."""
    Sy = C @ P @ C.T + R
    # LAPACK's potrf / potrs directly: the arithmetic of sla.cho_factor / cho_solve (lower), without their
    # per-call wrappers (this step runs once per agent, step and run in the lossy runtime)
    lapack = sla.lapack
    c, info = lapack.dpotrf(0.5 * (Sy + Sy.T), lower=1, clean=0)
    if info != 0:
        raise np.linalg.LinAlgError(f"{info}-th leading minor of the innovation covariance not positive definite")
    X, info = lapack.dpotrs(c, C @ P, lower=1)
    if info != 0:  # pragma: no cover - potrs fails only on bad arguments
        raise ValueError(f"illegal value in argument {-info} of potrs")
    K = X.T
    IKC = np.eye(P.shape[0]) - K @ C
    Pf = IKC @ P @ IKC.T + K @ R @ K.T
    return K, 0.5 * (Pf + Pf.T)


def kalman_covariances(system: LinearGaussianSystem, n_steps: int) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Forward Riccati recursion (eq. 22) of the centralized Kalman filter.

    P(k+1) = A (P(k) - K(k) C P(k)) Aᵀ + Q,  K(k) = P(k) Cᵀ (C P(k) Cᵀ + R)⁻¹,  P(0) = Σ_x.

    Parameters
    ----------
    system : LinearGaussianSystem
        The process x(k+1) = A x(k) + w(k) and the agents' measurements y_i(k) = C_i x(k) + v_i(k).
    n_steps : int
        Number of steps of the recursion.

    Returns
    -------
    P_pred : (n_steps, d_x, d_x)       P(k) = var(x(k) | y(0:k-1)), k = 0..n_steps-1
    K : (n_steps, d_x, d_y)            Kalman gains (eq. 21)
    P_filt : (n_steps, d_x, d_x)       P(k|k)

    Examples
    --------
    >>> import numpy as np
    >>> from teamkf import LinearGaussianSystem, kalman_covariances
    >>> P_pred, K, P_filt = kalman_covariances(LinearGaussianSystem.platoon(4), 30)
    >>> bool(np.all(np.trace(P_filt, axis1=1, axis2=2) <= np.trace(P_pred, axis1=1, axis2=2)))
    True
    """
    V.instance(system, "system", LinearGaussianSystem, "a LinearGaussianSystem", "build one with teamkf.LinearGaussianSystem(...)")
    T = V.positive_int(n_steps, "n_steps")
    dx, dy = system.dx, system.dy_total
    from .._budget import check_memory

    check_memory(
        8.0 * T * (2 * dx * dx + dx * dy),
        f"the Kalman covariances and gains of T = {T:,} steps (d_x = {dx}, d_y = {dy})",
        argument="horizon",
        fix="use a shorter horizon, or omit it for the steady-state design",
    )
    system.require_horizon(T)
    P_pred = np.empty((T, dx, dx))
    K = np.empty((T, dx, dy))
    P_filt = np.empty((T, dx, dx))
    P_pred[0] = system.Sigma_x
    from .._resources import progress as _progress

    for k in _progress(range(T), total=T, desc="Kalman covariances"):
        K[k], P_filt[k] = kalman_step(P_pred[k], system.C_stack(k), system.R_stack(k))
        if k + 1 < T:
            A = system.A_at(k)
            Pn = A @ P_filt[k] @ A.T + system.Q_at(k)
            P_pred[k + 1] = 0.5 * (Pn + Pn.T)
    return P_pred, K, P_filt


def steady_state(system: LinearGaussianSystem, *, check: bool = True) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(P_bar, K_bar, P_bar(k|k)) of the algebraic Riccati equation (eq. 37); needs (A4)-(A5)."""
    from .riccati import steady_state_kalman, steady_state_kalman_blocks

    system.require_time_invariant()
    if system.n_agents > 1 and system.dy_total >= max(BLOCK_DARE_MIN_DY, 4 * system.dx):
        # many more measurements than states (the platoons: n^2 against n): the information form, no d_y x d_y R
        n = system.n_agents
        return steady_state_kalman_blocks(
            system.A_at(0), [system.C_at(i, 0) for i in range(n)], system.Q_at(0), [system.R_at(i, 0) for i in range(n)], check=check
        )
    return steady_state_kalman(system.A_at(0), system.C_stack(0), system.Q_at(0), system.R_stack(0), check=check)


def predictor_errors(system: LinearGaussianSystem, K_at: Any, paths: Any, n_steps: int | None = None) -> FloatArray:
    """eps(m) = x(m) - x^(m) of the one-step predictor (eq. 20) with gains ``K_at(m)``, from the primitive noises.

    eps(0) = x(0) (x^(0) = 0) and eps(m+1) = A(m)[eps(m) - K(m)(C(m) eps(m) + v(m))] + w(m):
    no state appears, so the recursion stays accurate when A is unstable.
    Returns (n_runs, T, d_x) with T = ``n_steps`` (default: the paths' length).
    """
    T = paths.n_steps if n_steps is None else n_steps
    v = paths.v_stack
    eps = np.empty((paths.n_runs, T, system.dx))
    eps[:, 0] = paths.x[:, 0]
    for m in range(T - 1):
        e = eps[:, m]
        e = e - (e @ system.C_stack(m).T + v[:, m]) @ K_at(m).T
        eps[:, m + 1] = e @ system.A_at(m).T + paths.w[:, m]
    return eps
