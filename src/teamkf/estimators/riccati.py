r"""Steady-state Kalman Riccati solutions and detectability checks.

The one-step *predictor* error covariance of the centralized Kalman filter,
:math:`P(t+1) = \operatorname{cov}(x(t+1) \mid y(1{:}t))`, obeys the
finite-horizon Riccati recursion

.. math::

    P(t+1) = A P(t) A^\top - A P(t) C^\top (C P(t) C^\top + R)^{-1} C P(t) A^\top + Q ,

and, when :math:`(A, C)` is detectable and :math:`(A, Q^{1/2})` is
stabilizable (assumption (A5) of the team-MMSE paper), converges from any
:math:`P(1) \succeq 0` to the unique stabilizing solution :math:`\bar P` of
the filter algebraic Riccati equation (paper eq. 37)

.. math::

    \bar P = A \bar P A^\top - A \bar P C^\top (C \bar P C^\top + R)^{-1} C \bar P A^\top + Q .

:func:`solve_filter_dare` computes :math:`\bar P` with the structure-preserving
doubling algorithm (SDA) of Chu, Fan and Lin (2005) -- only matrix products
and one LU factorization per step, quadratic convergence -- and verifies the
result (Riccati residual, closed-loop spectral radius). :func:`steady_state_kalman`
adds the gain and the filtered covariance.

The detectability and stabilizability checks use the Popov-Belevitch-Hautus
(PBH) test restricted to the unstable invariant subspace: one real Schur
decomposition of :math:`A` (:math:`O(n^3)`) and a small test per distinct
unstable eigenvalue.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
import scipy.linalg as sla
from numpy.typing import ArrayLike

from .. import _validation as V
from .._linalg import (  # noqa: F401  (re-exported: detectability lives below the models layer)
    PBH_RTOL,
    UNIT_CIRCLE_TOL,
    _detectability_message,
    _modes_from_subspace,
    _psd_factor_rows,
    _schur_select,
    _square,
    _stabilizability_message,
    _stabilizability_modes,
    _tol,
    check_detectable,
    check_stabilizable,
    is_detectable,
    is_stabilizable,
    unstable_unobservable_modes,
)
from ..exceptions import ConvergenceError, DetectabilityError, NotPositiveDefiniteError, TeamkfError

FloatArray = V.FloatArray

__all__ = [
    "solve_filter_dare",
    "steady_state_kalman",
    "steady_state_kalman_blocks",
    "riccati_residual",
    "unstable_unobservable_modes",
    "is_detectable",
    "is_stabilizable",
    "check_detectable",
    "check_stabilizable",
]

#: relative Riccati residual above which a computed solution is rejected
RESIDUAL_RTOL = 1e-8

Method = Literal["auto", "sda", "scipy"]


class _OptionError(TeamkfError, ValueError):
    """A keyword option has an unsupported value."""


# ----------------------------------------------------------------------------
# input handling
# ----------------------------------------------------------------------------


def _system(A: ArrayLike, C: ArrayLike, Q: ArrayLike, R: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Validate (A, C, Q, R): A dx x dx, C dy x dx, Q dx x dx PSD, R dy x dy PD."""
    A_ = _square(A, "A")
    dx = A_.shape[0]
    C_ = V.matrix(C, "C", (None, dx))
    dy = C_.shape[0]
    Q_ = V.covariance(Q, "Q", dx)
    R_ = V.covariance(R, "R", dy, definite=True)
    return A_, C_, Q_, R_


def _check_pair(A_: FloatArray, C_: FloatArray, Q_: FloatArray) -> None:
    """Detectability of (A, C) and stabilizability of (A, Q^1/2) from one Schur form."""
    n = A_.shape[0]
    if n == 0:
        return
    T, Z, sel = _schur_select(A_, 1.0 - UNIT_CIRCLE_TOL)
    if not sel.any():
        return
    modes = _modes_from_subspace(T, Z, sel, C_, _tol(A_, C_), left=False)
    if modes:
        raise DetectabilityError(_detectability_message("(A, C)", modes))
    D = _psd_factor_rows(Q_)
    modes = _modes_from_subspace(T, Z, sel, D, _tol(A_, D), left=True)
    if modes:
        raise DetectabilityError(_stabilizability_message("(A, Q^1/2)", modes))


# ----------------------------------------------------------------------------
# Riccati solvers
# ----------------------------------------------------------------------------


def _gain_and_filtered(A: FloatArray, C: FloatArray, R: FloatArray, P: FloatArray) -> tuple[FloatArray, FloatArray]:
    """K = P C' (C P C' + R)^-1 and P - K C P (symmetrized)."""
    S = C @ P @ C.T + R
    S = 0.5 * (S + S.T)
    PCt = P @ C.T
    try:
        cf = sla.cho_factor(S, lower=True, check_finite=False)
        K = sla.cho_solve(cf, PCt.T, check_finite=False).T
    except np.linalg.LinAlgError:
        K = np.linalg.solve(S, PCt.T).T
    Pf = P - K @ PCt.T
    return K, 0.5 * (Pf + Pf.T)


def riccati_residual(A: ArrayLike, C: ArrayLike, Q: ArrayLike, R: ArrayLike, P: ArrayLike) -> float:
    r"""Relative residual of the filter Riccati equation at ``P``.

    .. math::

        \frac{\| A (P - P C^\top (C P C^\top + R)^{-1} C P) A^\top + Q - P \|_F}
             {\|A P A^\top\|_F + \|Q\|_F + \|P\|_F}
    """
    A_, C_, Q_, R_ = _system(A, C, Q, R)
    P_ = V.matrix(P, "P", A_.shape)
    return _residual(A_, C_, Q_, R_, P_)[0]


def _residual(A: FloatArray, C: FloatArray, Q: FloatArray, R: FloatArray, P: FloatArray) -> tuple[float, FloatArray, FloatArray, FloatArray]:
    """(relative residual, K, P_filt, A K)."""
    K, Pf = _gain_and_filtered(A, C, R, P)
    AP = A @ P
    APAt = AP @ A.T
    AK = A @ K
    # A P_filt A' = A P A' - (A K)(A P C')'
    res = APAt - AK @ (AP @ C.T).T + Q - P
    den = float(np.linalg.norm(APAt)) + float(np.linalg.norm(Q)) + float(np.linalg.norm(P))
    rel = float(np.linalg.norm(res)) / max(den, np.finfo(float).tiny)
    return rel, K, Pf, AK


def _spectral_radius(M: FloatArray) -> float:
    if M.shape[0] == 0:
        return 0.0
    return float(np.max(np.abs(np.linalg.eigvals(M))))


def _verify(A: FloatArray, C: FloatArray, Q: FloatArray, R: FloatArray, P: FloatArray, what: str) -> tuple[FloatArray, FloatArray, float, float]:
    """Reject a candidate solution with a large residual or a non-Schur closed loop."""
    if not np.all(np.isfinite(P)):
        raise ConvergenceError(f"{what}: the solution has NaN or inf entries")
    rel, K, Pf, AK = _residual(A, C, Q, R, P)
    rho = _spectral_radius(A - AK @ C)
    if not rel <= RESIDUAL_RTOL:
        raise ConvergenceError(f"{what}: relative Riccati residual {rel:.3g} exceeds {RESIDUAL_RTOL:g} (closed-loop spectral radius {rho:.6g})")
    if not rho < 1.0:
        raise ConvergenceError(
            f"{what}: the solution is not stabilizing, closed-loop spectral radius rho(A - A K C) = {rho:.6g} >= 1 "
            f"(relative residual {rel:.3g}); check detectability of (A, C) and stabilizability of (A, Q^1/2)"
        )
    return K, Pf, rel, rho


def _sda(A: FloatArray, G: FloatArray, H: FloatArray, tol: float, max_iter: int) -> tuple[FloatArray, int, float]:
    r"""Structure-preserving doubling for X = Ahat' X (I + G X)^-1 Ahat + H, here Ahat = A'.

    Returns (X, iterations, last relative change). Raises ConvergenceError on
    non-finite iterates or when ``max_iter`` is reached.
    """
    n = A.shape[0]
    Ak = np.array(A.T, order="C")
    Gk = G.copy()
    Hk = H.copy()
    eye = np.eye(n)
    rel = np.inf
    prev = np.inf
    for it in range(1, max_iter + 1):
        # W = (I + G H)^-1, applied through one LU factorization
        lu = sla.lu_factor(eye + Gk @ Hk, check_finite=False)
        rhs = np.empty((n, 2 * n), order="F")  # LAPACK's layout: no copy inside lu_solve
        rhs[:, :n] = Ak
        rhs[:, n:] = Gk
        Y = sla.lu_solve(lu, rhs, overwrite_b=True, check_finite=False)
        WA, WG = Y[:, :n], Y[:, n:]
        A_next = Ak @ WA
        G_next = Gk + Ak @ WG @ Ak.T
        H_next = Hk + Ak.T @ (Hk @ WA)
        G_next = 0.5 * (G_next + G_next.T)
        H_next = 0.5 * (H_next + H_next.T)
        if not (np.all(np.isfinite(H_next)) and np.all(np.isfinite(A_next)) and np.all(np.isfinite(G_next))):
            raise ConvergenceError(
                f"SDA for the filter Riccati equation produced NaN or inf after {it} iterations "
                f"(last relative change {rel:.3g}); the system is badly scaled or not detectable/stabilizable"
            )
        dH = float(np.linalg.norm(H_next - Hk))
        nH = float(np.linalg.norm(H_next))
        rel = dH / nH if nH > 0 else dH
        Ak, Gk, Hk = A_next, G_next, H_next
        if rel <= tol:
            return Hk, it, rel
        # H W = (I + H G)^-1 H is PSD and <= H (Loewner), so the next change
        # A' (H W) A is at most ||A||_F^2 ||H||_F: stop one step early when that is below tol
        if float(np.linalg.norm(Ak)) ** 2 <= tol:
            return Hk, it, rel
        # round-off floor: quadratic convergence has stopped, the residual check decides
        if rel <= 1e-8 and rel >= 0.5 * prev:
            return Hk, it, rel
        prev = rel
    raise ConvergenceError(
        f"SDA for the filter Riccati equation did not converge in {max_iter} iterations "
        f"(relative change of H {rel:.3g} > tol {tol:g}); raise max_iter or use method='scipy'"
    )


def _solve_sda(A: FloatArray, C: FloatArray, Q: FloatArray, R: FloatArray, tol: float, max_iter: int) -> FloatArray:
    # G = C' R^-1 C through a Cholesky factor of R: B = L^-1 C, G = B' B
    try:
        L = sla.cholesky(R, lower=True, check_finite=False)
    except np.linalg.LinAlgError:  # pragma: no cover - covariance() already checked R > 0
        raise NotPositiveDefiniteError("R: Cholesky factorization failed; R must be positive definite") from None
    B = sla.solve_triangular(L, C, lower=True, check_finite=False)
    G = B.T @ B
    G = 0.5 * (G + G.T)
    P, it, rel = _sda(A, G, Q, tol, max_iter)
    _verify(A, C, Q, R, P, f"SDA ({it} iterations, last relative change {rel:.3g})")
    return P


def _solve_scipy(A: FloatArray, C: FloatArray, Q: FloatArray, R: FloatArray) -> FloatArray:
    # scipy solves X = a' X a - a' X b (r + b' X b)^-1 b' X a + q; a = A', b = C' gives eq. 37
    try:
        P = sla.solve_discrete_are(A.T, C.T, Q, R)
    except (np.linalg.LinAlgError, ValueError) as exc:
        raise ConvergenceError(f"scipy.linalg.solve_discrete_are failed: {exc}") from None
    P = 0.5 * (P + P.T)
    _verify(A, C, Q, R, P, "scipy.linalg.solve_discrete_are")
    return P


def solve_filter_dare(
    A: ArrayLike,
    C: ArrayLike,
    Q: ArrayLike,
    R: ArrayLike,
    *,
    method: Method = "auto",
    tol: float = 1e-13,
    max_iter: int = 200,
    check: bool = True,
) -> FloatArray:
    r"""Stabilizing solution of the filter algebraic Riccati equation (team-MMSE paper eq. 37).

    Solves

    .. math::

        \bar P = A \bar P A^\top - A \bar P C^\top (C \bar P C^\top + R)^{-1} C \bar P A^\top + Q

    for the stabilizing :math:`\bar P \succeq 0`, the steady-state one-step
    predictor error covariance :math:`\operatorname{cov}(x(t+1) \mid y(1{:}t))`.

    With :math:`G = C^\top R^{-1} C` the equation reads
    :math:`\bar P = A \bar P (I + G \bar P)^{-1} A^\top + Q`, which the
    structure-preserving doubling algorithm (Chu, Fan & Lin 2005) solves from
    :math:`\hat A_0 = A^\top,\ G_0 = G,\ H_0 = Q`:

    .. math::

        W_k &= (I + G_k H_k)^{-1}, \\
        \hat A_{k+1} &= \hat A_k W_k \hat A_k, \\
        G_{k+1} &= G_k + \hat A_k W_k G_k \hat A_k^\top, \\
        H_{k+1} &= H_k + \hat A_k^\top H_k W_k \hat A_k \;\to\; \bar P,

    quadratically, with one LU factorization of :math:`I + G_k H_k` per step.
    Every result (SDA or scipy) is verified: the relative Riccati residual
    (:func:`riccati_residual`) must be below ``RESIDUAL_RTOL`` and the closed
    loop :math:`A - A \bar K C`, :math:`\bar K = \bar P C^\top (C \bar P C^\top + R)^{-1}`,
    must be Schur stable.

    Parameters
    ----------
    A : (d_x, d_x) array_like
        State matrix.
    C : (d_y, d_x) array_like
        Stacked output matrix of all agents.
    Q : (d_x, d_x) array_like or float
        Process-noise covariance, positive semi-definite (a scalar means ``q I``).
    R : (d_y, d_y) array_like or float
        Measurement-noise covariance, positive definite (a scalar means ``r I``).
    method : {"auto", "sda", "scipy"}
        ``"sda"``: doubling; ``"scipy"``: :func:`scipy.linalg.solve_discrete_are`
        on ``(A', C', Q, R)``; ``"auto"``: SDA, falling back to scipy when SDA
        raises :class:`~teamkf.exceptions.ConvergenceError`.
    tol : float
        SDA stops when :math:`\|H_{k+1} - H_k\|_F \le \text{tol}\, \|H_{k+1}\|_F`,
        or when :math:`\|\hat A_{k+1}\|_F^2 \le \text{tol}` (which bounds the
        next relative change, since :math:`0 \preceq H W \preceq H`), or when the
        change stalls at round-off level below 1e-8.
    max_iter : int
        Maximum number of SDA steps.
    check : bool
        First check that :math:`(A, C)` is detectable and :math:`(A, Q^{1/2})`
        stabilizable (assumption (A5)); a failing system raises
        :class:`~teamkf.exceptions.DetectabilityError` instead of a
        convergence failure.

    Returns
    -------
    (d_x, d_x) ndarray
        The stabilizing solution :math:`\bar P` (symmetric).

    Raises
    ------
    ShapeError, NotSymmetricError, NotPositiveDefiniteError
        Invalid inputs; the message names the argument.
    DetectabilityError
        ``check=True`` and assumption (A5) fails.
    ConvergenceError
        No verified solution was found.

    Examples
    --------
    >>> import numpy as np
    >>> A = np.array([[1.1, 0.2], [0.0, 0.7]]); C = np.array([[1.0, 0.0]])
    >>> P = solve_filter_dare(A, C, np.eye(2), 0.1)
    >>> riccati_residual(A, C, np.eye(2), 0.1, P) < 1e-12
    True
    """
    A_, C_, Q_, R_ = _system(A, C, Q, R)
    return _solve(A_, C_, Q_, R_, method, tol, max_iter, check)


def _solve(A_: FloatArray, C_: FloatArray, Q_: FloatArray, R_: FloatArray, method: str, tol: float, max_iter: int, check: bool) -> FloatArray:
    if method not in ("auto", "sda", "scipy"):
        raise _OptionError(f"method: expected 'auto', 'sda' or 'scipy', found {method!r}")
    tol_ = float(tol)
    if not (np.isfinite(tol_) and tol_ > 0):
        raise _OptionError(f"tol: expected a positive tolerance, found {tol!r}")
    max_iter_ = V.positive_int(max_iter, "max_iter")
    if check:
        _check_pair(A_, C_, Q_)
    if A_.shape[0] == 0:
        return np.zeros((0, 0))
    if method == "scipy":
        return _solve_scipy(A_, C_, Q_, R_)
    if method == "sda":
        return _solve_sda(A_, C_, Q_, R_, tol_, max_iter_)
    try:
        return _solve_sda(A_, C_, Q_, R_, tol_, max_iter_)
    except ConvergenceError as sda_exc:
        try:
            return _solve_scipy(A_, C_, Q_, R_)
        except ConvergenceError as sp_exc:
            raise ConvergenceError(
                f"both solvers failed. {sda_exc}. Fallback: {sp_exc}. The Riccati equation is probably "
                "ill-conditioned in double precision (modes that are nearly undetectable or nearly unexcited, "
                "e.g. many strongly unstable modes seen through few outputs); rescale the state, add measurements, "
                "or use a finite horizon"
            ) from None


def steady_state_kalman(
    A: ArrayLike,
    C: ArrayLike,
    Q: ArrayLike,
    R: ArrayLike,
    *,
    method: Method = "auto",
    tol: float = 1e-13,
    max_iter: int = 200,
    check: bool = True,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    r"""Steady-state centralized Kalman filter: predictor covariance, gain, filtered covariance.

    .. math::

        \bar K = \bar P C^\top (C \bar P C^\top + R)^{-1}, \qquad
        \bar P_{\mathrm{filt}} = \bar P - \bar K C \bar P ,

    with :math:`\bar P` from :func:`solve_filter_dare`. :math:`\bar K` is the
    gain of the paper's eq. 21, used as
    :math:`\hat x(t+1) = A \hat x(t) + A \bar K (y(t) - C \hat x(t))`;
    :math:`\bar P_{\mathrm{filt}} = \operatorname{cov}(x(t) \mid y(1{:}t))`.

    Parameters are those of :func:`solve_filter_dare`.

    Returns
    -------
    P_pred : (d_x, d_x) ndarray
        :math:`\bar P`.
    K : (d_x, d_y) ndarray
        :math:`\bar K`.
    P_filt : (d_x, d_x) ndarray
        :math:`\bar P - \bar K C \bar P` (symmetrized).
    """
    A_, C_, Q_, R_ = _system(A, C, Q, R)
    P = _solve(A_, C_, Q_, R_, method, tol, max_iter, check)
    K, Pf = _gain_and_filtered(A_, C_, R_, P)
    return P, K, Pf


def steady_state_kalman_blocks(
    A: ArrayLike,
    C_blocks: list[ArrayLike],
    Q: ArrayLike,
    R_blocks: list[ArrayLike],
    *,
    tol: float = 1e-13,
    max_iter: int = 200,
    check: bool = True,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    r""":func:`steady_state_kalman` for C = rows(C_i) and R = blockdiag(R_i), in information form.

    No d_y x d_y matrix is formed: the doubling algorithm needs only :math:`G = \sum_i C_i^\top R_i^{-1} C_i`
    (one Cholesky factor per distinct block), and with :math:`M = I + \bar P G`

    .. math::

        \bar K = \bar P (I + G \bar P)^{-1} C^\top R^{-1}, \qquad
        \bar P_{\mathrm{filt}} = M^{-1} \bar P, \qquad A - A \bar K C = A M^{-1}

    (push-through identities), so the work is O(d_y d_x^2 + d_x^3) instead of O(d_y^3): the
    platoon's n^2 x n^2 R at n = 40 (20 MB, 1600^3 flops per factorization) never exists. Same
    checks as :func:`steady_state_kalman` (detectability, residual, stable closed loop); equal to it
    to round-off. Falls back to it (dense) when the doubling algorithm fails.
    """
    A_ = _square(A, "A")
    dx = A_.shape[0]
    Q_ = V.covariance(Q, "Q", dx)
    Cs = [V.matrix(C, f"C_{i}", (None, dx)) for i, C in enumerate(C_blocks)]
    cache: dict[tuple[int, int], tuple[FloatArray, FloatArray]] = {}
    G = np.zeros((dx, dx))
    CtRinv = []
    for i, (C, Rb) in enumerate(zip(C_blocks, R_blocks)):
        key = (id(C), id(Rb))
        if key not in cache:  # identical blocks (every vehicle of a platoon) are factored once
            R_ = V.covariance(Rb, f"R_{i}", Cs[i].shape[0], definite=True)
            L = sla.cholesky(R_, lower=True, check_finite=False)
            B = sla.solve_triangular(L, Cs[i], lower=True, check_finite=False)  # L^-1 C_i
            cache[key] = (B.T @ B, sla.solve_triangular(L, B, lower=True, trans="T", check_finite=False).T)  # C_i' R_i^-1 C_i, C_i' R_i^-1
        Gi, W = cache[key]
        G += Gi
        CtRinv.append(W)
    G = 0.5 * (G + G.T)
    if check:
        _check_pair(A_, np.vstack(Cs), Q_)
    if dx == 0:
        return np.zeros((0, 0)), np.zeros((0, sum(C.shape[0] for C in Cs))), np.zeros((0, 0))
    try:
        P, it, rel = _sda(A_, G, Q_, float(tol), V.positive_int(max_iter, "max_iter"))
        I = np.eye(dx)
        Pf = np.linalg.solve(I + P @ G, P)  # (I + P G)^-1 P = P - P C'(C P C' + R)^-1 C P
        Pf = 0.5 * (Pf + Pf.T)
        APAt = A_ @ P @ A_.T
        den = float(np.linalg.norm(APAt)) + float(np.linalg.norm(Q_)) + float(np.linalg.norm(P))
        res = float(np.linalg.norm(A_ @ Pf @ A_.T + Q_ - P)) / max(den, np.finfo(float).tiny)
        rho = _spectral_radius(A_ @ np.linalg.inv(I + P @ G))
        if not (np.all(np.isfinite(P)) and res <= RESIDUAL_RTOL and rho < 1.0):
            raise ConvergenceError(f"SDA ({it} iterations, last relative change {rel:.3g}): residual {res:.3g}, closed loop {rho:.6g}")
    except ConvergenceError:
        Rd = sla.block_diag(*[np.atleast_2d(np.asarray(R, dtype=float)) for R in R_blocks])
        return steady_state_kalman(A_, np.vstack(Cs), Q_, Rd, check=False)
    K = P @ np.linalg.solve(I + G @ P, np.hstack(CtRinv))  # P (I + G P)^-1 C' R^-1
    return P, K, Pf
