r"""Theorem 4 of Das & Moura (2016): the MSE-optimal consensus and innovation gains of one step.

In reduced coordinates, for agent n with in-neighbours l_1..l_d,

.. math::

    \hat B^n = \Sigma_{e\tilde\nu} \Sigma_{\tilde\nu}^{+}, \qquad
    K^n = (\Sigma^{nn} G_r^\top - \Gamma^{nn}) \Sigma_\nu^{+}, \quad
    \Sigma_\nu = G_r \Sigma^{nn} G_r^\top - G_r \Gamma^{nn} - \Gamma^{nn\top} G_r^\top + P^{nn}_{k|k}

(the blocks of Σ_eν̃ and Σ_ν̃ are in :mod:`teamkf.estimators.cikf`). The pseudo-inverses are
:func:`_psd_solve`: a pivoted Cholesky that stops below ``rcond`` times the largest variance (default), or an
eigen-decomposition truncated at ``rcond * lambda_max``.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..._lazy import scipy_linalg as sla  # SciPy / networkx load on first use
from ..._validation import FloatArray
from ...exceptions import DivergenceError

__all__ = ["DEFAULT_RCOND"]


#: default relative cut-off of the pseudo-inverses in Theorem 4 (see the module docstring)
DEFAULT_RCOND = 1e-9


def _psd_solve(S_xy: FloatArray, S_yy: FloatArray, rcond: float, how: str = "cholesky") -> FloatArray:
    """S_xy S_yy^- for a PSD S_yy, dropping numerically redundant directions (module docstring).

    ``how="cholesky"``: pivoted Cholesky (LAPACK ``dpstrf``) that stops when the largest remaining
    conditional variance falls below ``rcond`` times the largest variance; the innovation components
    kept are the pivots, the others (predictable from the kept ones to that tolerance) get zero gain.
    ``how="eigh"``: truncated eigen pseudo-inverse, directions below ``rcond * lambda_max`` dropped.
    For S_xy with rows in range(S_yy) both give the estimate of the Moore-Penrose solution.
    """
    S = 0.5 * (S_yy + S_yy.T)
    if how == "cholesky":
        d = np.diag(S)
        top = float(d.max()) if d.size else 0.0
        if not np.isfinite(top):
            raise DivergenceError("CIKF gain design: a covariance overflowed (the error dynamics diverge; see tracking_capacity)")
        out = np.zeros_like(S_xy)
        if top <= 0.0:
            return out
        from ..._lapack import pstrf_solve  # reads SciPy's LAPACK pointers: on first use, not at import

        X, keep = pstrf_solve(S, S_xy, rcond * top)  # LAPACK dpstrf + dpotrs, GIL released (per-agent threads)
        out[:, keep] = X
        return out
    w, Q = sla.eigh(S, driver="evd", check_finite=False)
    top = float(w[-1]) if w.size else 0.0
    if not np.isfinite(top):
        raise DivergenceError("CIKF gain design: a covariance overflowed (the error dynamics diverge; see tracking_capacity)")
    keep = w > rcond * max(top, np.finfo(float).tiny)
    Qk = Q[:, keep]
    return ((S_xy @ Qk) / w[keep]) @ Qk.T  # type: ignore[no-any-return]


def _theorem4_pseudo(
    P4: FloatArray, n: int, nb: Sequence[int], r: int, Ct: FloatArray, Rn: FloatArray, rcond: float, how: str
) -> tuple[FloatArray, FloatArray]:
    """Theorem 4's B̂^n = Σ_{eν̃} Σ_ν̃^+ in reduced coordinates: returns (B_cons (r, d r), B_u (r, M_n)).

    ``P4`` is P_{k|k-1} as (N, r, N, r) blocks (a view; only agent n's closed neighbourhood is read).
    """
    d, mn = len(nb), Ct.shape[0]
    dr = d * r
    Pnn = P4[n, :, n, :]
    Snu = np.empty((dr + mn, dr + mn))
    Sey = np.empty((r, dr + mn))
    if d:
        nba = np.asarray(nb, dtype=np.intp)
        Pnl4 = P4[n][:, nba, :]  # (r, d, r): [P^{n l_1} ... P^{n l_d}]; P^{l n} = (P^{n l})' (P symmetric)
        PlnT = Pnl4.transpose(1, 2, 0)  # (d, r, r): P^{l_q n}
        Pll4 = P4[nba[:, None], :, nba[None, :], :].transpose(0, 2, 1, 3)  # (d, r, d, r): P^{l_q l_s}
        # [Σ_ν̃]_{qs} = P^{nn} - P^{n l_s} - P^{l_q n} + P^{l_q l_s}
        S4 = Snu[:dr, :dr].reshape(d, r, d, r)
        np.subtract(Pnn[None, :, None, :], Pnl4[None], out=S4)
        S4 -= PlnT[:, :, None, :]
        S4 += Pll4
        # [Σ_ν̃]_{q,u} = (P^{nn} - P^{l_q n}) C̃_n'
        Snu[:dr, dr:] = (Pnn[None] - PlnT).reshape(dr, r) @ Ct.T
        Snu[dr:, :dr] = Snu[:dr, dr:].T
        Sey[:, :dr] = (Pnn[:, None, :] - Pnl4).reshape(r, dr)  # E[e^n (e^n - e^{l_q})'] = P^{nn} - P^{n l_q}
    Snu[dr:, dr:] = Ct @ Pnn @ Ct.T + Rn  # C̃ P^{nn} C̃' + R_n
    Sey[:, dr:] = Pnn @ Ct.T  # E[e^n u^n'] = P^{nn} C̃_n'
    Bhat = _psd_solve(Sey, Snu, rcond, how)
    return Bhat[:, :dr], Bhat[:, dr:]
