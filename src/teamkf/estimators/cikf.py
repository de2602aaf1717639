r"""Consensus+Innovations Kalman filter (CIKF) with optimized gains (Das & Moura, IEEE TSP 2016).

Every agent n keeps an estimate of the *pseudo-state* y = G x and of the
state x. At step k it combines its own pseudo-observation with its
neighbours' previous pseudo-state predictions (one exchange per step, unit
delay), then updates its state estimate from its pseudo-state estimate:

.. math::

    \hat y^n_{k|k} &= \hat y^n_{k|k-1} + \sum_{l \in \Omega_n} B^{nl}_k (\hat y^l_{k|k-1} - \hat y^n_{k|k-1})
                      + B^{nn}_k (\tilde z^n_k - \tilde H_n \hat y^n_{k|k-1} - \check H_n \hat x^n_{k|k-1})   \quad (21) \\
    \hat x^n_{k|k} &= \hat x^n_{k|k-1} + K^n_k (\hat y^n_{k|k} - G \hat x^n_{k|k-1})                        \quad (22) \\
    \hat y^n_{k+1|k} &= \tilde A \hat y^n_{k|k} + \check A \hat x^n_{k|k}, \qquad
    \hat x^n_{k+1|k} = A \hat x^n_{k|k}                                                                   \quad (23, 24)

Notation (paper -> teamkf; steps 0-based, the paper's i is our k)
-----------------------------------------------------------------
================================  ==============================================================
paper                             here
================================  ==============================================================
M, N                              ``system.dx``, ``system.n_agents``
A, V, Sigma_0                     ``system.A``, ``system.Q``, ``system.Sigma_x`` (x̄_0 = 0)
H_n, R_n, z^n_i                   ``system.C[n]``, ``system.R[n]``, y_n(k)
H̄_n = H_n' R_n^-1 H_n             ``model.H_bar[n]``                                   (5)
G = sum_n H̄_n                     ``model.G``                                          (7)
G†, Ĩ = I - G† G                  ``model.G_pinv``, ``model.I_tilde``                  (15)
Ã = G A G†, Ǎ = G A Ĩ             ``model.A_tilde``, ``model.A_check``                 (11, 13)
H̃_n = H̄_n G†, Ȟ_n = H̄_n Ĩ         ``model.H_tilde[n]``, ``model.H_check[n]``           (12, 14)
λ_1, λ_m                          smallest / largest non-zero eigenvalue of G (Theorem 3)
Ω_n                               ``graph.in_neighbors(n)`` (every edge must have delay 1)
B^{nl}, B^{nn}, K^n               :meth:`CIKFDesign.paper_gains` (full coordinates)
P, Σ, Π, Γ                        pseudo-state, state and cross error covariances (34)-(40)
================================  ==============================================================

Reduced coordinates (how G need not be invertible)
--------------------------------------------------
Let G = U Λ U' with U (M x r) an orthonormal basis of range(G) (eigenvalues
below ``G_RTOL`` times the largest count as zero). Every pseudo-state error
lies in range(G) (e_{0|-1} = G(x_0 - x̄_0), and (32) maps into range(G)),
and so does every gain's output, so the filter runs on y_r = U' y in R^r:

* G_r = Λ U' (r x M), Ã_r = U' Ã U = Λ U' A U Λ^-1, Ǎ_r = U' Ǎ = Λ U' A Ĩ;
* Ȟ_n = 0 identically: null(G) is the intersection of the null spaces of
  the PSD H̄_n, so H̄_n Ĩ = 0 and H_n Ĩ = 0 — the Ȟ terms of (21), (30),
  (41)-(42) and Theorem 4 drop out (checked literally in the tests);
* the M-dimensional innovation z̃^n - H̃_n ŷ^n = H_n' R_n^-1 u^n is a
  full-column-rank image of the M_n-dimensional u^n = z^n - C̃_n ŷ_r^n with
  C̃_n = H_n U Λ^-1, so the Theorem-4 gain on it is B_u^n = B^{nn} H_n' R_n^-1
  (r x M_n) and the estimate is the same; :meth:`CIKFDesign.paper_gains`
  maps back to B^{nn} = U B_u^n (H_n' R_n^-1)†, B^{nl} = U B_r^{nl} U',
  K^n = K_r^n U'.

In these coordinates Σ_ν̃ has size d_n r + M_n instead of (d_n + 1) M and
its innovation block C̃ P C̃' + R_n is positive definite.

The corrected covariance iterations (Algorithm 2)
-------------------------------------------------
Derived from Lemma 2, eqs. (30)-(33), and the definitions (34)-(40); with
M_k = I - B^C - B^I D̃_H (block-sparse, the graph's pattern), F_k = I - K (I ⊗ G)
(block-diagonal):

.. math::

    \Gamma &= \Pi_{k|k-1} M_k^\top                                                   && (41) \\
    P_{k|k} &= M_k P_{k|k-1} M_k^\top + B^I \bar D_H B^{I\top}                         && (42) \\
    \Sigma_{k|k} &= F \Sigma_{k|k-1} F^\top + F \Gamma K^\top + K \Gamma^\top F^\top + K P_{k|k} K^\top  && (43)^* \\
    \Pi_{k|k} &= F \Gamma + K P_{k|k}                                                 && (44) \\
    P_{k+1|k} &= \tilde A P \tilde A^\top + \check A \Sigma \check A^\top + \tilde A \Pi^\top \check A^\top
                 + \check A \Pi \tilde A^\top + (1 1^\top) \otimes (G V G)              && (45)^* \\
    \Sigma_{k+1|k} &= A \Sigma A^\top + (1 1^\top) \otimes V                          && (46) \\
    \Pi_{k+1|k} &= A \Pi \tilde A^\top + A \Sigma \check A^\top + (1 1^\top) \otimes (V G)   && (47)

(all Ã, Ǎ, A act blockwise, I_N ⊗ ·; the filter-step covariances on the
right of (45)-(47)). Corrections to the extracted text (*): in (43) the cross
terms need Γ_k, not Π_{k|k-1} (ε_{k|k} = F ε_{k|k-1} + K e_{k|k} and
E[ε_{k|k-1} e_{k|k}'] = Γ_k, eq. 40); in (45) the Σ and cross terms need Ǎ,
not Ã (e_{k+1|k} = Ã e_{k|k} + Ǎ ε_{k|k} + G v_k, eq. 32); the initial
conditions are (1 1') ⊗ Σ_0, (1 1') ⊗ (G Σ_0 G), (1 1') ⊗ (Σ_0 G) (the
printed J ⊗ Σ_0 with J = (1 1') ⊗ I has the wrong size). These forms hold
for *any* gains (Joseph-like), so the iteration gives the true covariance of
the filter that is run, whatever the pseudo-inverse cut-off.

Theorem 4 (the gains), in reduced coordinates, with ν̃^n = [e^n - e^{l_1}; ...;
e^n - e^{l_d}; u^n], u^n = C̃_n e^n + r^n and ν^n = G_r ε^n_{k|k-1} - e^n_{k|k}:

.. math::

    \hat B^n = \Sigma_{e\tilde\nu} \Sigma_{\tilde\nu}^{+}, \quad
    \Sigma_{e\tilde\nu} = [P^{nn} - P^{nl_1}, \dots, P^{nn} - P^{nl_d}, P^{nn} \tilde C_n^\top], \\
    [\Sigma_{\tilde\nu}]_{qs} = P^{nn} - P^{nl_s} - P^{l_q n} + P^{l_q l_s}, \quad
    [\Sigma_{\tilde\nu}]_{q,u} = (P^{nn} - P^{l_q n}) \tilde C_n^\top, \quad
    [\Sigma_{\tilde\nu}]_{u,u} = \tilde C_n P^{nn} \tilde C_n^\top + R_n, \\
    K^n = (\Sigma^{nn} G_r^\top - \Gamma^{nn}) \Sigma_\nu^{+}, \quad
    \Sigma_\nu = G_r \Sigma^{nn} G_r^\top - G_r \Gamma^{nn} - \Gamma^{nn\top} G_r^\top + P^{nn}_{k|k}.

The paper writes Σ_{yν̃} = E[(y - ȳ) ν̃'] and drops E[(ŷ^n - ȳ) ν̃'] — the
MSE-minimizing gain is E[e^n ν̃'] Σ_ν̃^+, which is what its block formulas
(and ours) compute.

The pseudo-inverse cut-off
--------------------------
Σ_ν̃ is singular at k = 0 (all agents start from the same prior, so every
difference e^n - e^l is exactly 0) and, later, its difference blocks are
formed by cancellation (P^{nn} - P^{nl} - P^{ln} + P^{ll} of nearly equal
blocks), so their smallest eigenvalues carry absolute errors of order
eps ||P||. ``_psd_solve`` (``pinv="cholesky"``, default) runs a pivoted
Cholesky that stops when the largest remaining conditional variance is
below ``rcond`` times the largest variance: innovation components that are
(numerically) predictable from the kept ones get zero gain, which is exact
for the consistent systems of Theorem 4 when Σ_ν̃ is exactly singular.
``pinv="eigh"`` truncates the eigen-decomposition at ``rcond * lambda_max``.
The default ``rcond = 1e-9`` stays three orders of magnitude above the
round-off level of the differences; at M = N = 50 it costs 5e-4 dB against
1e-12, and neither drifts (``docs/cikf.md``, tested).

Cost (M = N = 50: NM = 2500)
----------------------------
M_k has N + 2|E| non-zero M x M blocks and K, F, I ⊗ Ã, I ⊗ Ǎ are
block-diagonal, so every product is done block-wise: one GEMM per agent over
its closed neighbourhood for M_k, batched GEMMs for the block-diagonal
factors. No NM x NM matrix is ever multiplied by another as a dense matrix
(``method="dense"`` does exactly that, as the benchmark's baseline).

``method="joint"`` (the default for the corrected equations) runs the same
equations as one recursion on the joint covariance J = cov([e; ε])
(N(r + M) square, agent-major): the update (41)-(42) is M_k on the e-rows
of J, and (43)-(47) collapse into one (r + M) x (r + M) map per agent,
Φ^n = [[Ã + Ǎ K^n, Ǎ F^n], [A K^n, A F^n]], applied on both sides; both
two-sided products are computed on the upper block triangle only, in place
(``_iterate_joint``). At M = N = 50 that is 12.2 GFLOP per step against 14.4
for the block-operator form, in fewer and larger GEMMs, and J (plus
(M_k P)' when small) is all the memory. Theorem 4's per-agent pivoted
Cholesky factorizations run on the worker threads with the GIL released
(``teamkf._lapack``). ``method="structured"`` keeps the block-operator
arithmetic that ``tests/unit/test_cikf_reference.py`` pins entry by entry.
The two differ only in the rounding: Σ, P, the stage costs and the errors
agree to ~1e-12, but Theorem 4's consensus gains only to ~1e-8, because
Σ_ν̃ is formed by cancellation (the structured method itself moves that much
when P is scaled by 1 + 2^-52, see ``tests/unit/test_cikf_joint.py``), so
gains are compared by what they produce.

References
----------
.. [1] S. Das and J. M. F. Moura, "Consensus+Innovations Distributed Kalman
   Filter with Optimized Gains", IEEE Trans. Signal Processing, 2016 (eqs.
   cited above; Algorithms 1-2; Theorems 3-4).
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass
from functools import lru_cache
from typing import Any, Callable, Literal, Sequence

import numpy as np
import scipy.linalg as sla

from .. import _validation as V
from .._blas import blas_threads
from .._lapack import pstrf_solve
from .._validation import FloatArray
from ..exceptions import ArgumentError, DetectabilityError, DivergenceError, GraphError, InformationStructureError, ShapeError
from ..models import LinearGaussianSystem, TeamCost
from ..network.graph import CommGraph
from .base import Design, check_measurements
from .registry import Family, Option, _register_builtin

__all__ = [
    "PseudoStateModel",
    "pseudo_state_model",
    "CIKFDesign",
    "CIKFAgent",
    "design_cikf",
    "TrackingCapacity",
    "tracking_bound",
    "tracking_capacity",
    "tracking_capacity_upper_bound",
    "G_RTOL",
    "DEFAULT_RCOND",
]

#: eigenvalues of G below G_RTOL * lambda_max(G) count as zero (rank of G)
G_RTOL = 1e-10
#: default relative cut-off of the pseudo-inverses in Theorem 4 (see the module docstring)
DEFAULT_RCOND = 1e-9

Form = Literal["filter", "predictor"]
Method = Literal["structured", "joint", "dense"]


# ---------------------------------------------------------------------------
# Proposition 1: the pseudo-state model
# ---------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class PseudoStateModel:
    r"""The pseudo-state model of Proposition 1, eqs. (4)-(16), for any (A, H) — G may be singular.

    Full (paper) coordinates: ``G``, ``G_pinv`` (G†), ``I_tilde`` (Ĩ), ``A_tilde``
    (Ã), ``A_check`` (Ǎ), ``H_bar``, ``H_tilde``, ``H_check`` (one M x M matrix per
    agent, stacked on the first axis). Reduced coordinates on range(G):
    ``U`` (M x r), ``lam`` (the r non-zero eigenvalues of G), ``G_r`` = Λ U',
    ``A_tilde_r``, ``A_check_r``, ``C_tilde`` (per agent, M_n x r) and
    ``innov_map`` (per agent, H_n' R_n^-1, M x M_n).
    """

    G: FloatArray
    G_pinv: FloatArray
    I_tilde: FloatArray
    A_tilde: FloatArray
    A_check: FloatArray
    H_bar: FloatArray
    H_tilde: FloatArray
    H_check: FloatArray
    U: FloatArray
    lam: FloatArray
    G_r: FloatArray
    A_tilde_r: FloatArray
    A_check_r: FloatArray
    C_tilde: tuple
    innov_map: tuple

    @property
    def rank(self) -> int:
        """rank(G) = r."""
        return int(self.lam.size)

    @property
    def dx(self) -> int:
        return int(self.G.shape[0])

    @property
    def invertible(self) -> bool:
        """Whether G is invertible (distributed observability, [5] of the paper)."""
        return self.rank == self.dx

    @property
    def lambda_1(self) -> float:
        """Smallest non-zero eigenvalue of G (Theorem 3)."""
        return float(self.lam.min())

    @property
    def lambda_m(self) -> float:
        """Largest eigenvalue of G (Theorem 3)."""
        return float(self.lam.max())


def _frozen_stack(mats: Sequence[FloatArray]) -> FloatArray:
    return V.frozen(np.stack(mats)) if len(mats) else V.frozen(np.zeros((0, 0, 0)))


def pseudo_state_model(system: LinearGaussianSystem, *, rtol: float = G_RTOL) -> PseudoStateModel:
    """Build G, G†, Ĩ, Ã, Ǎ, H̄_n, H̃_n, Ȟ_n (Proposition 1) and the reduced coordinates on range(G).

    Parameters
    ----------
    system : LinearGaussianSystem (time-invariant)
    rtol : float
        Eigenvalues of G below ``rtol * lambda_max(G)`` count as zero.

    Examples
    --------
    >>> import numpy as np
    >>> from teamkf import LinearGaussianSystem
    >>> from teamkf.estimators.cikf import pseudo_state_model
    >>> sys = LinearGaussianSystem(A=np.eye(3), Q=1.0, Sigma_x=1.0, C=[[[1.0, 0, 0]], [[0, 1.0, 0]]], R=1.0)
    >>> m = pseudo_state_model(sys)
    >>> m.rank, m.invertible, float(np.abs(m.H_check).max())
    (2, False, 0.0)
    """
    if not isinstance(system, LinearGaussianSystem):
        raise ShapeError(f"system: expected a LinearGaussianSystem, found {type(system).__name__}")
    system.require_time_invariant("the CIKF (its pseudo-state model, Proposition 1)")
    M, N = system.dx, system.n_agents
    A = system.A_at(0)
    H_bar, maps = [], []
    for n in range(N):
        C, R = system.C_at(n, 0), system.R_at(n, 0)
        Hm = sla.cho_solve(sla.cho_factor(R, lower=True), C).T  # H_n' R_n^-1 (M x M_n)
        Hb = Hm @ C
        H_bar.append(0.5 * (Hb + Hb.T))
        maps.append(Hm)
    G = np.sum(H_bar, axis=0)
    G = 0.5 * (G + G.T)
    w, Q = np.linalg.eigh(G)
    top = max(float(w[-1]), 0.0)
    if top <= 0.0:
        raise DetectabilityError(
            "system: expected at least one observed direction (G = sum_n H_n' R_n^-1 H_n != 0), found G = 0; give some agent a non-zero C"
        )
    keep = w > float(rtol) * top
    U, lam = Q[:, keep], w[keep]
    G_pinv = (U / lam) @ U.T
    I_tilde = np.eye(M) - U @ U.T
    A_tilde = G @ A @ G_pinv
    A_check = G @ A @ I_tilde
    G_r = lam[:, None] * U.T
    A_tilde_r = (lam[:, None] * (U.T @ A @ U)) / lam[None, :]
    A_check_r = lam[:, None] * (U.T @ A @ I_tilde)
    C_tilde = tuple(V.frozen((system.C_at(n, 0) @ U) / lam[None, :]) for n in range(N))
    return PseudoStateModel(
        V.frozen(G),
        V.frozen(G_pinv),
        V.frozen(I_tilde),
        V.frozen(A_tilde),
        V.frozen(A_check),
        _frozen_stack(H_bar),
        _frozen_stack([Hb @ G_pinv for Hb in H_bar]),
        _frozen_stack([Hb @ I_tilde for Hb in H_bar]),
        V.frozen(U),
        V.frozen(lam),
        V.frozen(G_r),
        V.frozen(A_tilde_r),
        V.frozen(A_check_r),
        C_tilde,
        tuple(V.frozen(m) for m in maps),
    )


# ---------------------------------------------------------------------------
# numerical kernels
# ---------------------------------------------------------------------------
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


class _worker_pool:
    """A thread pool of ``n`` workers for the block products (None when ``n`` is None or 1).

    numpy releases the GIL inside BLAS calls and ufunc loops, so ``n`` Python threads each running
    single-threaded BLAS on its own range of agents use ``n`` cores without OpenBLAS's spinning threads.
    """

    def __init__(self, n: int | None):
        self.n = n
        self.pool: Any = None

    def __enter__(self) -> Any:
        if self.n is not None and self.n > 1:
            from concurrent.futures import ThreadPoolExecutor

            self.pool = ThreadPoolExecutor(max_workers=self.n, thread_name_prefix="teamkf-cikf")
        return self.pool

    def __exit__(self, *exc: Any) -> None:
        if self.pool is not None:
            self.pool.shutdown(wait=True)


def _sym(X: FloatArray) -> FloatArray:
    X += X.T
    X *= 0.5
    return X


class _Structured:
    """Block products that never form an NM x NM operator: M_k by closed neighbourhoods, the rest block-diagonally.

    Every block of a result is computed by one BLAS call whose shape does not depend on ``pool``; with a
    thread pool (one BLAS thread per worker) the calls are spread over the workers in contiguous ranges of
    agents, so the numbers are the same with one worker or several.
    """

    def __init__(self, N: int, r: int, hoods: Sequence[np.ndarray], r_idx: Sequence[np.ndarray], pool: Any = None, workers: int = 1):
        self.N, self.r, self.hoods, self.r_idx = N, r, hoods, r_idx
        self.pool, self.workers = pool, max(1, int(workers))

    def _par(self, fn: Any, n: int) -> None:
        """fn(lo, hi) over ``workers`` contiguous ranges of range(n) (in the pool when there is one)."""
        if self.pool is None or self.workers == 1 or n < 2:
            fn(0, n)
            return
        cuts = np.linspace(0, n, min(self.workers, n) + 1).round().astype(int)
        futs = [self.pool.submit(fn, int(a), int(b)) for a, b in zip(cuts[:-1], cuts[1:]) if b > a]
        for f in futs:
            f.result()

    def m_right(self, X: FloatArray, rows: Sequence[FloatArray]) -> FloatArray:
        """X M' (M given by its block rows over closed neighbourhoods)."""
        r = self.r
        out = np.empty((X.shape[0], self.N * r))

        def work(lo: int, hi: int) -> None:
            for n in range(lo, hi):
                out[:, n * r : (n + 1) * r] = X[:, self.r_idx[n]] @ rows[n].T

        self._par(work, self.N)
        return out

    def m_left(self, rows: Sequence[FloatArray], X: FloatArray) -> FloatArray:
        """M X."""
        r = self.r
        out = np.empty((self.N * r, X.shape[1]))

        def work(lo: int, hi: int) -> None:
            for n in range(lo, hi):
                np.matmul(rows[n], np.take(X, self.r_idx[n], axis=0), out=out[n * r : (n + 1) * r])

        self._par(work, self.N)
        return out

    def m_sandwich(self, rows: Sequence[FloatArray], Zt: FloatArray) -> FloatArray:
        """M Z' given Z' (symmetric result M P M' with Z = M P): the upper block triangle, mirrored."""
        r, N = self.r, self.N
        out = np.empty((N * r, Zt.shape[1]))

        def upper(lo: int, hi: int) -> None:
            for n in range(lo, hi):
                np.matmul(rows[n], Zt[self.r_idx[n], n * r :], out=out[n * r : (n + 1) * r, n * r :])

        # balance the triangle: agent n's row costs ~ (N - n) blocks
        self._par_tri(upper, N)

        def mirror(lo: int, hi: int) -> None:
            for n in range(max(lo, 1), hi):
                out[n * r : (n + 1) * r, : n * r] = out[: n * r, n * r : (n + 1) * r].T

        self._par(mirror, N)
        return out

    def _par_tri(self, fn: Any, n: int) -> None:
        """Like _par, with ranges of equal work for rows whose cost falls linearly (upper triangles)."""
        if self.pool is None or self.workers == 1 or n < 2:
            fn(0, n)
            return
        w = np.arange(n, 0, -1, dtype=float)
        c = np.concatenate([[0.0], np.cumsum(w)])
        cuts = [0] + [int(np.searchsorted(c, c[-1] * j / self.workers)) for j in range(1, self.workers)] + [n]
        futs = [self.pool.submit(fn, a, b) for a, b in zip(cuts[:-1], cuts[1:]) if b > a]
        for f in futs:
            f.result()

    def bd_left(self, B: FloatArray, X: FloatArray) -> FloatArray:
        """blockdiag(B) X; B is (N, a, b) or one shared (a, b)."""
        b = B.shape[-1]
        a = B.shape[-2]
        C = X.shape[1]
        X3 = np.ascontiguousarray(X).reshape(self.N, b, C)
        out = np.empty((self.N, a, C))

        def work(lo: int, hi: int) -> None:
            np.matmul(B if B.ndim == 2 else B[lo:hi], X3[lo:hi], out=out[lo:hi])

        self._par(work, self.N)
        return out.reshape(-1, C)

    def bd_right(self, X: FloatArray, B: FloatArray) -> FloatArray:
        """X blockdiag(B)'; B is (N, a, b) or one shared (a, b)."""
        Rr = X.shape[0]
        b = B.shape[-1]
        if B.ndim == 2:
            X3 = np.ascontiguousarray(X).reshape(Rr, self.N, b)
            out2 = np.empty((Rr, self.N * B.shape[0]))

            def work2(lo: int, hi: int) -> None:  # row ranges: the one GEMM split by rows
                np.matmul(X3[lo:hi].reshape(-1, b), B.T, out=out2[lo:hi].reshape(-1, B.shape[0]))

            self._par(work2, Rr)
            return out2
        a = B.shape[1]
        out = np.empty((Rr, self.N * a))

        def work(lo: int, hi: int) -> None:
            for n in range(lo, hi):  # strided column blocks go to BLAS without copies
                np.matmul(X[:, n * b : (n + 1) * b], B[n].T, out=out[:, n * a : (n + 1) * a])

        self._par(work, self.N)
        return out

    def bd_left_add(self, out: FloatArray, B: FloatArray, X: FloatArray) -> FloatArray:
        """out += blockdiag(B) X, block row by block row (no full-size temporary)."""
        b, C = B.shape[-1], X.shape[1]
        X3 = np.ascontiguousarray(X).reshape(self.N, b, C)
        a = B.shape[-2]
        o3 = out.reshape(self.N, a, C)

        def work(lo: int, hi: int) -> None:
            for n in range(lo, hi):
                o3[n] += (B if B.ndim == 2 else B[n]) @ X3[n]

        self._par(work, self.N)
        return out

    def bd_right_add(self, out: FloatArray, X: FloatArray, B: FloatArray) -> FloatArray:
        """out += X blockdiag(B)' for a per-agent B (N, a, b), column block by column block."""
        a, b = B.shape[1], B.shape[2]

        def work(lo: int, hi: int) -> None:
            for n in range(lo, hi):
                out[:, n * a : (n + 1) * a] += X[:, n * b : (n + 1) * b] @ B[n].T

        self._par(work, self.N)
        return out

    def add_check(self, P: FloatArray, Y1: FloatArray, Y2: FloatArray, Aw: FloatArray) -> FloatArray:
        """P += 2 Y1 blockdiag(Aw)' + Y2 blockdiag(Aw)' by row ranges (Y1, Y2 thin: N (M - r) columns)."""
        q = Aw.shape[1]
        Y1, Y2 = np.ascontiguousarray(Y1), np.ascontiguousarray(Y2)

        def work(lo: int, hi: int) -> None:
            T1 = (Y1[lo:hi].reshape(-1, q) @ Aw.T).reshape(hi - lo, -1)
            T2 = (Y2[lo:hi].reshape(-1, q) @ Aw.T).reshape(hi - lo, -1)
            P[lo:hi] += 2.0 * T1 + T2

        self._par(work, P.shape[0])
        return P

    def add(self, X: FloatArray, Y: FloatArray) -> FloatArray:
        """X += Y by row ranges."""

        def work(lo: int, hi: int) -> None:
            X[lo:hi] += Y[lo:hi]

        self._par(work, X.shape[0])
        return X

    def add_tiled(self, X: FloatArray, B: FloatArray) -> FloatArray:
        """X += (1 1') ⊗ B (every a x b block of X gets B), without forming the tiled matrix."""
        a, b = B.shape
        X4 = X.reshape(X.shape[0] // a, a, X.shape[1] // b, b)

        def work(lo: int, hi: int) -> None:
            X4[lo:hi] += B[None, :, None, :]

        self._par(work, X4.shape[0])
        return X

    def sym(self, X: FloatArray) -> FloatArray:
        """X <- (X + X') / 2 in place, by block rows (upper block triangle computed, then mirrored)."""
        n = X.shape[0]
        nb = max(1, min(self.N, n))
        edges = np.linspace(0, n, nb + 1).round().astype(int)

        def upper(lo: int, hi: int) -> None:
            for i in range(lo, hi):
                a, b = edges[i], edges[i + 1]
                blk = X[a:b, a:]
                blk += X[a:, a:b].T
                blk *= 0.5

        self._par_tri(upper, nb)

        def mirror(lo: int, hi: int) -> None:
            for i in range(max(lo, 1), hi):
                a, b = edges[i], edges[i + 1]
                X[a:b, :a] = X[:a, a:b].T

        self._par(mirror, nb)
        return X


class _Dense(_Structured):
    """The same products with every operator formed as a dense NM x NM matrix (benchmark baseline)."""

    def _m(self, rows: Sequence[FloatArray]) -> FloatArray:
        r = self.r
        Mf = np.zeros((self.N * r, self.N * r))
        for n, row in enumerate(rows):
            Mf[n * r : (n + 1) * r, self.r_idx[n]] = row
        return Mf

    def _bd(self, B: FloatArray) -> FloatArray:
        if B.ndim == 2:
            return np.asarray(np.kron(np.eye(self.N), B), dtype=float)
        return sla.block_diag(*B)  # type: ignore[no-any-return]

    def m_right(self, X: FloatArray, rows: Sequence[FloatArray]) -> FloatArray:
        return X @ self._m(rows).T  # type: ignore[no-any-return]

    def m_left(self, rows: Sequence[FloatArray], X: FloatArray) -> FloatArray:
        return self._m(rows) @ X  # type: ignore[no-any-return]

    def m_sandwich(self, rows: Sequence[FloatArray], Zt: FloatArray) -> FloatArray:
        out = self._m(rows) @ Zt
        return _sym(out)

    def bd_left(self, B: FloatArray, X: FloatArray) -> FloatArray:
        return self._bd(B) @ X  # type: ignore[no-any-return]

    def bd_right(self, X: FloatArray, B: FloatArray) -> FloatArray:
        return X @ self._bd(B).T  # type: ignore[no-any-return]


def _diag_blocks(X: FloatArray, N: int, a: int) -> FloatArray:
    """The N diagonal a x a blocks of an Na x Na matrix, (N, a, a)."""
    X4 = X.reshape(N, a, N, a)
    return np.ascontiguousarray(X4[np.arange(N), :, np.arange(N), :])


def _agent_groups(neighbors: Sequence[Sequence[int]], m_sizes: Sequence[int], parts: int = 1) -> list[list[tuple[np.ndarray, np.ndarray]]]:
    """Agents batched by (neighbourhood size, measurement size), each batch split into ``parts`` shares.

    Returns ``parts`` lists of (agents, closed neighbourhoods (g, d+1)) with about equal numbers of agents
    of each size, so that ``parts`` workers get equal work.
    """
    keyed: dict[tuple[int, int], list[int]] = {}
    for n, nb in enumerate(neighbors):
        keyed.setdefault((len(nb), int(m_sizes[n])), []).append(n)
    out: list[list[tuple[np.ndarray, np.ndarray]]] = [[] for _ in range(max(1, parts))]
    for (d, _), agents in sorted(keyed.items()):
        for j, share in enumerate(np.array_split(np.asarray(agents, dtype=np.intp), len(out))):
            if share.size:
                hood = np.asarray([[n, *neighbors[n]] for n in share], dtype=np.intp).reshape(share.size, d + 1)
                out[j].append((share, hood))
    return [p for p in out if p]


# ---------------------------------------------------------------------------
# the design
# ---------------------------------------------------------------------------
@dataclass(frozen=True, eq=False, kw_only=True)
class CIKFDesign(Design):
    r"""Gains (Algorithm 2, Theorem 4) and error covariances (corrected eqs. 41-47) of the CIKF.

    Built by :func:`~teamkf.design_cikf`.

    Parameters
    ----------
    estimator, horizon, system, cost, stage_costs, average_cost, info
        As in :class:`~teamkf.Design`: the family name, T (None for the steady state), the
        model, the team cost, the exact E[c(x(k), ẑ(k))] per step and the plain-data facts.
    graph : CommGraph
        The communication graph: agent i hears agent j over edge (j, i) after its integer delay τ_ji.
    model : PseudoStateModel
        The pseudo-state model of Section III (each agent's reduced coordinates).
    form : "filter" or "predictor"
        ẑ_n(k) = L_n x̂^n_{k|k} (filter) or L_n x̂^n_{k|k-1} (predictor).
    rcond : float
        The pseudo-inverse cut-off of Theorem 4.
    neighbors : tuple
        Ω_n, in the order of the consensus gain blocks.
    B_cons : tuple over steps of tuples over agents of (r, d_n r) arrays
        [B_r^{n l_1}, ..., B_r^{n l_d}] in reduced coordinates.
    B_innov : tuple over steps of tuples over agents of (r, M_n) arrays
        The innovation gains B_u^n.
    K : (T, N, M, r) array
        The state gains K_r^n.
    Sigma_pred, Sigma_filt : (T, N, M, M) arrays
        Agent n's Σ^{nn}_{k|k-1} and Σ^{nn}_{k|k}.
    P_pred_trace : (T, N) array
        tr P^{nn}_{k|k-1} (pseudo-state MSE, reduced = full coordinates).

    See Also
    --------
    design_cikf

    Examples
    --------
    >>> from teamkf import design_cikf
    >>> from teamkf.study.random_field import random_field
    >>> system, graph = random_field(15, 6, rng=1)
    >>> d = design_cikf(system, None, graph, horizon=5)
    >>> d.K.shape[:2], len(d.neighbors)
    ((5, 6), 6)
    """

    graph: CommGraph
    model: PseudoStateModel
    form: Form = "filter"
    rcond: float = DEFAULT_RCOND
    neighbors: tuple[tuple[int, ...], ...]
    B_cons: tuple[tuple[FloatArray, ...], ...]
    B_innov: tuple[tuple[FloatArray, ...], ...]
    K: FloatArray
    Sigma_pred: FloatArray
    Sigma_filt: FloatArray
    P_pred_trace: FloatArray

    @property
    def n_agents(self) -> int:
        return int(self.system.n_agents)

    # --- analytic MSE -------------------------------------------------------
    def mse(self, form: Form | None = None, *, per_agent: bool = False) -> FloatArray:
        """tr Σ^{nn} per step: (T, N) with ``per_agent``, else the average over agents (T,).

        ``form="predictor"``: Σ_{k|k-1} (the paper's Fig. 4 plots tr Σ_{i+1|i}, i.e. entries 1..T-1);
        ``form="filter"``: Σ_{k|k}.
        """
        f = self.form if form is None else form
        if f not in ("filter", "predictor"):
            raise ShapeError(f"form: expected 'filter' or 'predictor', found {f!r}")
        S = self.Sigma_filt if f == "filter" else self.Sigma_pred
        t = np.trace(S, axis1=2, axis2=3)
        return t if per_agent else t.mean(axis=1)  # type: ignore[no-any-return]

    # --- gains --------------------------------------------------------------
    def gains(self, k: int) -> dict[str, Any]:
        """Reduced-coordinate gains at step k: ``B_cons`` (per agent (r, d_n r)), ``B_innov`` (per agent (r, M_n)), ``K`` (N, M, r)."""
        k = self._step(k)
        return {"B_cons": self.B_cons[k], "B_innov": self.B_innov[k], "K": self.K[k]}

    def _step(self, k: int) -> int:
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 0 <= k < self.horizon:  # type: ignore[operator]
            raise ShapeError(f"k: expected a step in 0..{self.horizon - 1} (horizon = {self.horizon}), found {k!r}")  # type: ignore[operator]
        return int(k)

    def m_rows(self, k: int) -> list[FloatArray]:
        """Block rows of M_k = I - B^C - B^I D̃_H in reduced coordinates over each closed neighbourhood [n, l_1, ..., l_d]."""
        k = self._step(k)
        r = self.model.rank
        rows = []
        for n in range(self.n_agents):
            Bc, Bu = self.B_cons[k][n], self.B_innov[k][n]
            d = len(self.neighbors[n])
            row = np.empty((r, (d + 1) * r))
            row[:, :r] = np.eye(r) - Bu @ self.model.C_tilde[n] - Bc.reshape(r, d, r).sum(axis=1)
            row[:, r:] = Bc
            rows.append(row)
        return rows

    def paper_gains(self, k: int) -> dict[str, FloatArray]:
        """B^C, B^I and K of eqs. (60)-(63) in the paper's full coordinates, as dense NM x NM matrices (small problems).

        B^{nl} = U B_r^{nl} U', B^{nn} = U B_u^n (H_n' R_n^-1)†, K^n = K_r^n U'. They act on the
        paper's M-dimensional pseudo-state and pseudo-observations; the estimate they give is the
        reduced-coordinate filter's (module docstring).
        """
        k = self._step(k)
        m, N, M = self.model, self.n_agents, self.system.dx
        U = m.U
        BC = np.zeros((N * M, N * M))
        BI = np.zeros((N * M, N * M))
        K = np.zeros((N * M, N * M))
        r = m.rank
        for n in range(N):
            sl = slice(n * M, (n + 1) * M)
            Bc = self.B_cons[k][n]
            for q, l in enumerate(self.neighbors[n]):
                Bnl = U @ Bc[:, q * r : (q + 1) * r] @ U.T
                BC[sl, l * M : (l + 1) * M] = -Bnl
                BC[sl, sl] += Bnl
            BI[sl, sl] = U @ self.B_innov[k][n] @ np.linalg.pinv(m.innov_map[n])
            K[sl, sl] = self.K[k, n] @ U.T
        return {"B_C": BC, "B_I": BI, "K": K}

    # --- online: graph agents -------------------------------------------------
    def graph_agents(self) -> list["CIKFAgent"]:
        """Algorithm 1: one message-passing agent per node for :func:`teamkf.simulation.runtime.run_graph`."""
        return [CIKFAgent(self, n) for n in range(self.n_agents)]

    def agents(self) -> list[Any]:
        raise self._unsupported(
            "agents()",
            "CIKF agents exchange pseudo-state predictions, not measurement packets: run them with "
            "run_graph(design.graph_agents(), design.graph, y), or use design.filter(y) / design.errors(paths)",
        )

    def _filter(self, ys: list[FloatArray]) -> FloatArray:
        return self.simulate(ys)

    def details(self) -> dict[str, Any]:
        return {"form": self.form, "rank": self.model.rank, "local_dims": None, "gain_shapes": {"K_n": list(self.K.shape[-2:])}}

    def arrays(self) -> dict[str, np.ndarray]:
        """Costs, the state gains ``K`` (T, N, M, r), the consensus gains ``B_cons_{n}`` (T, r, d_n r) and the
        innovation gains ``B_innov_{n}`` (T, r, M_n) of each agent, and the error covariances."""
        out = {**super().arrays(), "K": np.asarray(self.K), "Sigma_pred": np.asarray(self.Sigma_pred), "Sigma_filt": np.asarray(self.Sigma_filt)}
        for n in range(self.n_agents):
            out[f"B_cons_{n}"] = np.stack([np.asarray(step[n]) for step in self.B_cons])
            out[f"B_innov_{n}"] = np.stack([np.asarray(step[n]) for step in self.B_innov])
            out[f"neighbors_{n}"] = np.asarray(self.neighbors[n], dtype=np.int64)
        return out

    # --- vectorized Monte Carlo ---------------------------------------------------
    def _check_y(self, y: Any) -> tuple[list[FloatArray], int, int]:
        ys, n_runs, T, _ = check_measurements(y, self.system, self.horizon)
        return ys, n_runs, T

    def _recursion(self, ys: Sequence[FloatArray] | None, x0: FloatArray | None, w: FloatArray | None, n_runs: int, T: int, form: str) -> FloatArray:
        threads = self.info.get("threads", 1)
        with blas_threads(None if threads is None else 1):
            return self._recursion_impl(ys, x0, w, n_runs, T, form)

    def _recursion_impl(
        self, ys: Sequence[FloatArray] | None, x0: FloatArray | None, w: FloatArray | None, n_runs: int, T: int, form: str
    ) -> FloatArray:
        r"""Algorithm 1 on data (``ys``) or its error recursion (30)-(33) on the primitive noises (x0, w, ys = v).

        Runs-last layout. The pseudo-state parts live in ``Y`` (N, r, n_runs); ``X`` (N, r + M, n_runs) holds,
        per agent, [ŷ^n_{k|k}; x̂^n_{k|k-1}] (errors: [e^n_{k|k}; ε^n_{k|k-1}]). One step is

            X[n, :r] = [M_k]_{n, hood(n)} Y[hood(n)] ± B_u^n y_n(k)       (21) / (30): one GEMM per agent on
                                                                          its gathered neighbourhood
            [Y[n]; X[n, r:]] <- Φ^n_k X[n] (+ [G_r; I] w(k))              (22)-(24) / (31)-(33) fused

        with Φ^n = [[Ã + Ǎ K^n, Ǎ F^n], [A K^n, A F^n]], F^n = I - K^n G_r (x̂_{k|k} = K ŷ_{k|k} + F x̂_{k|k-1}):
        one (r + M) x (r + M) GEMM per agent instead of five products and their passes over memory.
        The filter form's output x̂^n_{k|k} = [K^n F^n] X[n] costs one more GEMM per agent.
        """
        m, sys, cost = self.model, self.system, self.cost
        N, M, r = self.n_agents, sys.dx, m.rank
        q = r + M
        A = sys.A_at(0)
        Gr, At, Ac = m.G_r, m.A_tilde_r, m.A_check_r
        errors = x0 is not None
        R_ = n_runs
        Y = np.empty((N, r, R_))
        X = np.empty((N, q, R_))
        if errors:
            Y[:] = (Gr @ x0.T)[None]  # type: ignore[union-attr]  # e^n_{0|-1} = G_r (x0 - x̄0)
            X[:, r:] = x0.T[None]  # type: ignore[union-attr]  # ε^n_{0|-1}
        else:
            Y[:] = 0.0  # ŷ^n_{0|-1} = G_r x̄_0 = 0
            X[:, r:] = 0.0
        dz = cost.dz
        identity_L = dz == M and all(
            np.array_equal(cost.L_block(n, k), np.eye(M)) for n in range(N) for k in range(min(T, 1 if not cost.is_time_varying else T))
        )
        threads = self.info.get("threads", 1) or 1
        groups = _agent_groups(self.neighbors, [c.shape[0] for c in m.C_tilde], parts=threads)
        hoods = [np.asarray([n, *nb], dtype=np.intp) for n, nb in enumerate(self.neighbors)]
        offs = np.concatenate([[0], np.cumsum([c.shape[0] for c in m.C_tilde])])
        ystack = np.concatenate([np.asarray(y, dtype=float) for y in ys], axis=2)  # type: ignore[union-attr]  # (R, T, sum M_n)
        # zero-filled, not np.empty: the strided first writes below would otherwise fault the fresh pages in
        # one by one (measured: 1.6 s of CPU for the 640 MB of 1000 runs x 32 steps at M = N = 50, against 0.2 s)
        out = np.zeros((n_runs, T, N * dz))
        Lb = None if identity_L else [np.stack([cost.L_block(n, k) for n in range(N)]) for k in range(T)]
        cuts = np.linspace(0, N, min(threads, N) + 1).round().astype(int)
        sign = -1.0 if errors else 1.0  # - B_u^n v_n (errors) | + B_u^n y_n (data)
        with _worker_pool(threads if threads > 1 else None) as pool:

            def run(tasks: Sequence[Any]) -> None:
                if pool is None:
                    for f in tasks:
                        f()
                else:
                    for fut in [pool.submit(f) for f in tasks]:
                        fut.result()

            for k in range(T):
                Bu_k = self.B_innov[k]
                rows_k = self.m_rows(k)
                Kk = self.K[k]
                F = np.eye(M) - Kk @ Gr
                KF = np.concatenate([Kk, F], axis=2)  # x̂_{k|k} = [K F] [ŷ_{k|k}; x̂_{k|k-1}], (N, M, q)
                Phi = None
                if k + 1 < T:
                    Phi = np.empty((N, q, q))
                    Phi[:, :r, :r] = At + Ac @ Kk
                    Phi[:, :r, r:] = Ac @ F
                    Phi[:, r:, :r] = A @ Kk
                    Phi[:, r:, r:] = A @ F
                yk = np.ascontiguousarray(ystack[:, k].T)  # (sum M_n, R)
                wk = np.ascontiguousarray(w[:, k].T) if errors and k + 1 < T else None  # type: ignore[index]  # (M, R)
                Gw = None if wk is None else Gr @ wk

                def consensus(part: Sequence[tuple[np.ndarray, np.ndarray]], rows_k: Any = rows_k, Bu_k: Any = Bu_k, yk: FloatArray = yk) -> None:
                    for agents, _ in part:
                        for n in agents:  # M_k's block row times the neighbourhood's (d + 1) r x n_runs rows
                            np.matmul(rows_k[n], Y[hoods[n]].reshape(-1, R_), out=X[n, :r])
                        mn = offs[agents[0] + 1] - offs[agents[0]]
                        if mn:
                            Bu = np.stack([Bu_k[n] for n in agents])
                            Yv = np.stack([yk[offs[n] : offs[n] + mn] for n in agents])
                            X[agents, :r] += sign * np.matmul(Bu, Yv)

                def update(
                    lo: int,
                    hi: int,
                    k: int = k,
                    KF: FloatArray = KF,
                    Phi: FloatArray | None = Phi,
                    wk: FloatArray | None = wk,
                    Gw: FloatArray | None = Gw,
                ) -> None:
                    src = np.matmul(KF[lo:hi], X[lo:hi]) if form == "filter" else X[lo:hi, r:]  # (hi - lo, M, R)
                    if Lb is not None:
                        src = np.matmul(Lb[k][lo:hi], src)
                    o = out[:, k, lo * dz : hi * dz].reshape(R_, hi - lo, dz)
                    for i in range(0, R_, 64):  # transposed into the run-major output, 64 runs at a time
                        o[i : i + 64] = src[:, :, i : i + 64].transpose(2, 0, 1)
                    if Phi is None:  # the last step: no prediction
                        return
                    tmp = np.empty((q, R_))
                    for n in range(lo, hi):
                        np.matmul(Phi[n], X[n], out=tmp)  # [ŷ_{k+1|k}; x̂_{k+1|k}] = Φ^n [ŷ_{k|k}; x̂_{k|k-1}]
                        Y[n] = tmp[:r]
                        X[n, r:] = tmp[r:]
                        if wk is not None and Gw is not None:  # + [G_r; I] w(k)
                            Y[n] += Gw
                            X[n, r:] += wk

                run([lambda p=p: consensus(p) for p in groups])
                run([lambda a=a, b=b: update(a, b) for a, b in zip(cuts[:-1], cuts[1:]) if b > a])
        return out

    def simulate(self, y: Any, *, form: Form | None = None) -> FloatArray:
        """Algorithm 1 for every agent at once, batched over runs: ẑ (n_runs, T', N d_z), agent-major.

        Parameters
        ----------
        y : list over agents of (n_runs, T', d_y^n) arrays (T' <= horizon), or a ``Paths``
        form : override the design's form ("filter" or "predictor")

        Equals ``run_graph(design.graph_agents(), design.graph, y)`` (tested).
        """
        ys, n_runs, T = self._check_y(y)
        f = self.form if form is None else form
        if f not in ("filter", "predictor"):
            raise ShapeError(f"form: expected 'filter' or 'predictor', found {f!r}")
        return self._recursion(ys, None, None, n_runs, T, f)

    def errors(self, paths: Any, *, form: Form | None = None) -> FloatArray:
        r"""Team errors L x(k) - ẑ(k), (n_runs, T', N d_z), from the primitive noises (no cancellation).

        The error recursion of Lemma 2 with Ȟ_n = 0, in reduced coordinates:

            e^n_{k|k} = e^n - Σ_l B^{nl}(e^n - e^l) - B_u^n (C̃_n e^n + v_n(k))       (30)
            ε^n_{k|k} = ε^n - K^n (G_r ε^n - e^n_{k|k})                              (31)
            e^n_{k+1|k} = Ã_r e^n_{k|k} + Ǎ_r ε^n_{k|k} + G_r w(k)                   (32)
            ε^n_{k+1|k} = A ε^n_{k|k} + w(k)                                         (33)

        from ε^n_{0|-1} = x(0), e^n_{0|-1} = G_r x(0). Only x(0), w and v enter, so
        nothing large is subtracted when A is unstable; the result is what the online
        agents produce (``L x - simulate(y)``) up to round-off.
        """
        x = V.as_float_array(paths.x, "paths.x")
        sys, N = self.system, self.n_agents
        if x.ndim != 3 or x.shape[2] != sys.dx:
            raise ShapeError(f"paths.x: expected shape (n_runs, n_steps, {sys.dx}), found {x.shape}")
        n_runs, T = x.shape[:2]
        if T > self.horizon:  # type: ignore[operator]
            raise ShapeError(f"paths: expected at most horizon = {self.horizon} steps, found {T}")
        w = np.asarray(paths.w, dtype=float)
        v = [np.asarray(vi, dtype=float) for vi in paths.v]
        if w.shape != (n_runs, max(T - 1, 0), sys.dx) or len(v) != N or any(vi.shape != (n_runs, T, sys.dy[i]) for i, vi in enumerate(v)):
            raise ShapeError(
                f"paths: expected w of shape {(n_runs, max(T - 1, 0), sys.dx)} and {N} noise arrays v[i] of shape "
                f"(n_runs, {T}, d_y^i), found w {w.shape} and {[vi.shape for vi in v]}"
            )
        f = self.form if form is None else form
        if f not in ("filter", "predictor"):
            raise ShapeError(f"form: expected 'filter' or 'predictor', found {f!r}")
        return self._recursion(v, x[:, 0], w, n_runs, T, f)

    def costs(self, paths: Any) -> FloatArray:
        """Team cost c(x(k), ẑ(k)) per run and step, (n_runs, T'), from :meth:`errors`."""
        e = self.errors(paths)
        return np.stack([np.einsum("ra,ab,rb->r", e[:, k], self.cost.S_at(k), e[:, k]) for k in range(e.shape[1])], axis=1)

    # --- tracking capacity ---------------------------------------------------
    def tracking_bound(self, k: int | None = None, *, subspace: Literal["range", "full"] = "range") -> float:
        """Theorem 3's bound λ_1 / (λ_m ||I - B^C - B^I D̃_H||_2) with this design's gains at step k (default: the last)."""
        return tracking_bound(self, self.horizon - 1 if k is None else k, subspace=subspace)  # type: ignore[operator]


class CIKFAgent:
    """Agent n of Algorithm 1 on the message-passing runtime.

    Its state is (ŷ^n_{k|k-1} in reduced coordinates, x̂^n_{k|k-1}). At step k it
    receives its own measurement y_n(k) (its pseudo-observation z̃^n = H_n' R_n^-1 y_n(k)
    enters only through B^{nn}(z̃^n - H̃_n ŷ^n) = B_u^n (y_n(k) - C̃_n ŷ_r^n), which is
    what is computed) and the payloads its neighbours sent at
    k - 1: their pseudo-state predictions ŷ^l_{k|k-1} in the paper's coordinates
    (M-dimensional, ŷ = U ŷ_r). At k = 0 nothing has arrived and every
    neighbour's prediction is the common prior G x̄_0 = 0 (Assumption 3), so
    the differences are zero (and so are the step-0 consensus gains). It
    returns L_n x̂^n_{k|k} (or L_n x̂^n_{k|k-1}) and sends ŷ^n_{k+1|k}.
    """

    def __init__(self, design: CIKFDesign, index: int, *, tolerant: bool = False):
        self.design = design
        self.index = index
        #: on unreliable links (teamkf.simulation.links): the consensus term uses the neighbours whose
        #: step-(k-1) prediction arrived; a missing neighbour's difference ŷ^l - ŷ^n is taken as zero
        #: (its block of B^{nl} is dropped, the others are not renormalized)
        self.tolerant = tolerant

    def init_state(self, n_runs: int) -> dict[str, FloatArray]:
        d = self.design
        return {"y": np.zeros((n_runs, d.model.rank)), "x": np.zeros((n_runs, d.system.dx))}

    def step(
        self, state: dict[str, FloatArray], k: int, own: FloatArray, inbox: Sequence[Any]
    ) -> tuple[dict[str, FloatArray], FloatArray, FloatArray]:
        d, n = self.design, self.index
        if k >= d.horizon:  # type: ignore[operator]
            raise ShapeError(f"k: the CIKF was designed for horizon = {d.horizon} steps, found step {k}; design a longer horizon")
        m = d.model
        yh, xh = state["y"], state["x"]
        nb = d.neighbors[n]
        got = {j: p for (j, s, p) in inbox if s == k - 1}
        if k > 0 and sorted(got) != list(nb) and not self.tolerant:
            raise InformationStructureError(
                f"CIKF agent {n} at step {k}: expected the step-{k - 1} predictions of its neighbours {list(nb)}, "
                f"found messages from {sorted(got)}; run it on the graph it was designed for (unit delays)"
            )
        u = np.asarray(own, dtype=float) - yh @ m.C_tilde[n].T
        yf = yh + u @ d.B_innov[k][n].T
        if nb and k > 0:
            diff = np.concatenate([np.asarray(got[l], dtype=float) @ m.U - yh if l in got else np.zeros_like(yh) for l in nb], axis=1)
            yf = yf + diff @ d.B_cons[k][n].T
        xf = xh + (yf - xh @ m.G_r.T) @ d.K[k, n].T
        z = (xf if d.form == "filter" else xh) @ d.cost.L_block(n, k).T
        yn = yf @ m.A_tilde_r.T + xf @ m.A_check_r.T
        xn = xf @ d.system.A_at(0).T
        return {"y": yn, "x": xn}, z, yn @ m.U.T


# ---------------------------------------------------------------------------
# Algorithm 2
# ---------------------------------------------------------------------------
def _neighbors(graph: CommGraph, n_agents: int) -> tuple[tuple[int, ...], ...]:
    if not isinstance(graph, CommGraph):
        raise GraphError(f"graph: expected a CommGraph, found {type(graph).__name__}; build one with CommGraph.from_networkx(G, default_delay=1)")
    if graph.n_agents != n_agents:
        raise GraphError(f"graph: expected a graph of {n_agents} agents (as the system), found one of {graph.n_agents}")
    slow = [(i, j, d) for (i, j, d) in graph.edges if d != 1]
    if slow:
        raise GraphError(
            f"graph: expected every edge to have delay 1 (the CIKF exchanges once per step), found {len(slow)} "
            f"edges with other delays, e.g. {slow[0]}; use graph.with_delay(1)"
        )
    return tuple(graph.in_neighbors(n) for n in range(n_agents))


def _stage_cost(cost: TeamCost, k: int, S_full: FloatArray, blocks: FloatArray, mse_like: bool, ops: _Structured) -> float:
    if mse_like:
        return float(np.trace(blocks, axis1=1, axis2=2).sum())
    Lb = np.stack([cost.L_block(n, k) for n in range(blocks.shape[0])])
    W = ops.bd_right(ops.bd_left(Lb, S_full), Lb)
    return float(np.sum(cost.S_at(k) * W))


def _is_mse(cost: TeamCost, N: int, M: int, T: int) -> bool:
    """S = I and every L_n = I (the stage cost is then the sum of the agents' traces)."""
    if cost.dz != M:
        return False
    steps = range(T) if cost.is_time_varying else range(1)
    return all(_is_identity(cost.S_at(k)) and all(_is_identity(cost.L_block(n, k)) for n in range(N)) for k in steps)


def _is_identity(X: FloatArray) -> bool:
    """X == I, without forming I (S is N M x N M: 800 MB at M = N = 100)."""
    d = np.diagonal(X)
    return bool(X.ndim == 2 and X.shape[0] == X.shape[1] and np.all(d == 1.0) and np.count_nonzero(X) == d.size)


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


class _CheckA:
    """Ǎ_r = Λ U' A Ĩ, applied blockwise through its factorization Ǎ_r = (Λ U' A W) W' (W: basis of null G)."""

    def __init__(self, model: PseudoStateModel, A: FloatArray):
        M, r = model.dx, model.rank
        self.zero = r == M
        if not self.zero:
            w, Q = np.linalg.eigh(model.I_tilde)
            W = Q[:, w > 0.5]  # orthonormal basis of null(G)
            self.Wt = np.ascontiguousarray(W.T)
            self.Aw = model.lam[:, None] * (model.U.T @ A @ W)

    def left(self, ops: "_Structured", X: FloatArray) -> FloatArray:
        return ops.bd_left(self.Aw, ops.bd_left(self.Wt, X))

    def right(self, ops: "_Structured", X: FloatArray) -> FloatArray:
        return ops.bd_right(ops.bd_right(X, self.Wt), self.Aw)


def _iterate(
    system: LinearGaussianSystem,
    model: PseudoStateModel,
    nbrs: Sequence[Sequence[int]],
    cost: TeamCost,
    T: int,
    rcond: float,
    form: str,
    ops: _Structured,
    fixed: CIKFDesign | None,
    equations: str,
    pinv: str,
) -> dict[str, Any]:
    """Algorithm 2 with the corrected eqs. (41)-(47) (module docstring), in reduced coordinates.

    Stored: P = P_{k|k-1} (Nr x Nr), Pt = Π'_{k|k-1} = E[e ε'] (Nr x NM), Sig = Σ_{k|k-1} (NM x NM). Keeping
    Π transposed makes every product with the block-sparse M_k a row gather; symmetric results are
    formed as sym(X + Y) where the exact result is X + Y' with X + Y' symmetric.
    """
    N, M, r = system.n_agents, system.dx, model.rank
    A, Vq, S0 = system.A_at(0), system.Q_at(0), system.Sigma_x
    Gr, At = model.G_r, model.A_tilde_r
    chk = _CheckA(model, A)
    Ct = model.C_tilde
    Rn = [system.R_at(n, 0) for n in range(N)]
    mse_like = _is_mse(cost, N, M, T)
    p43 = equations in ("printed", "printed-43")
    p45 = equations in ("printed", "printed-45")
    # initial conditions (corrected sizes): (1 1') ⊗ G Σ0 G, (1 1') ⊗ G Σ0 (= Π'), (1 1') ⊗ Σ0
    P = np.tile(Gr @ S0 @ Gr.T, (N, N))
    Pt = np.tile(Gr @ S0, (N, N))
    Sig = np.tile(S0, (N, N))
    GVG1, GV1, VV1 = Gr @ Vq @ Gr.T, Gr @ Vq, Vq  # the noise terms (1 1') ⊗ (.), added block by block
    eyeM, eyer = np.eye(M), np.eye(r)
    diag_r = np.arange(N)
    B_cons, B_innov = [], []
    K_all = np.empty((T, N, M, r))
    Sp, Sf_all = np.empty((T, N, M, M)), np.empty((T, N, M, M))
    Ptr = np.empty((T, N))
    stage = np.empty(T)
    for k in range(T):
        Sp[k] = _diag_blocks(Sig, N, M)
        Ptr[k] = np.trace(_diag_blocks(P, N, r), axis1=1, axis2=2)
        if form == "predictor":
            stage[k] = _stage_cost(cost, k, Sig, Sp[k], mse_like, ops)
        # --- Theorem 4: consensus + innovation gains B̂^n ---
        if fixed is not None:
            Bc_k, Bu_k = list(fixed.B_cons[k]), list(fixed.B_innov[k])
        else:
            Bc_k, Bu_k = [], []
            for n in range(N):
                Bc, Bu = _theorem4_pseudo(P.reshape(N, r, N, r), n, nbrs[n], r, Ct[n], Rn[n], rcond, pinv)
                Bc_k.append(Bc)
                Bu_k.append(Bu)
        rows = []
        for n in range(N):
            d = len(nbrs[n])
            row = np.empty((r, (d + 1) * r))
            row[:, :r] = eyer - Bu_k[n] @ Ct[n] - (Bc_k[n].reshape(r, d, r).sum(axis=1) if d else 0.0)
            row[:, r:] = Bc_k[n]
            rows.append(row)
        B_cons.append(tuple(Bc_k))
        B_innov.append(tuple(Bu_k))
        # --- (41): Γ' = M Π' ;  (42): P_f = M P M' + B^I D̄_H B^I' ---
        Gt = ops.m_left(rows, Pt)  # Γ' = E[e_{k|k} ε_{k|k-1}'], (Nr x NM)
        if not p43:
            del Pt
        Z = ops.m_left(rows, P)  # M P; P M' = Z' (P symmetric)
        del P  # (the big matrices are released as soon as they are used: peak memory)
        Zt = np.ascontiguousarray(Z.T)
        del Z
        Pf = ops.m_sandwich(rows, Zt)  # M P M', symmetric by construction
        del Zt
        for n in range(N):
            nz = Bu_k[n] @ Rn[n] @ Bu_k[n].T
            Pf[n * r : (n + 1) * r, n * r : (n + 1) * r] += 0.5 * (nz + nz.T)
        # --- Theorem 4: state gains K^n ---
        Sd = Sp[k]
        Gd = Gt.reshape(N, r, N, M)[diag_r, :, diag_r, :]  # (Γ^{nn})', (N, r, M)
        if fixed is not None:
            Kk = np.array(fixed.K[k])
        else:
            Pfd = _diag_blocks(Pf, N, r)
            Kk = np.empty((N, M, r))
            for n in range(N):
                GrS = Gr @ Sd[n]
                S_nu = GrS @ Gr.T - Gr @ Gd[n].T - Gd[n] @ Gr.T + Pfd[n]  # G Σ G - G Γ - Γ' G + P_f
                Kk[n] = _psd_solve(GrS.T - Gd[n].T, S_nu, rcond, pinv)  # (Σ G - Γ) Σ_ν^+
        K_all[k] = Kk
        F = eyeM - Kk @ Gr  # (N, M, M)
        # --- (44): Π_f' = Γ' F' + P_f K' ;  (43)*: Σ_f = F Σ F' + F Γ K' + K Γ' F' + K P_f K' ---
        Pft = ops.bd_right(Gt, F)
        ops.bd_right_add(Pft, Pf, Kk)
        L1 = ops.bd_left(F, Sig)
        del Sig
        ops.bd_left_add(L1, Kk, Pt if p43 else Gt)  # F Σ + K Γ'
        del Gt
        if p43:  # the extracted (43): Π_{k|k-1} in both cross terms
            Sf = ops.bd_right(L1, F) + ops.bd_left(Kk, ops.bd_right(Pt, F) + ops.bd_right(Pf, Kk))
        else:  # exact: L1 F' + Π_f K' = L1 F' + (K Π_f')'
            Sf = ops.bd_right(L1, F)
            ops.bd_left_add(Sf, Kk, Pft)
        del L1
        if p43:
            del Pt
        ops.sym(Sf)
        Sf_all[k] = _diag_blocks(Sf, N, M)
        if form == "filter":
            stage[k] = _stage_cost(cost, k, Sf, Sf_all[k], mse_like, ops)
        if k + 1 == T:
            break
        # --- (45)*: P' = Ã P_f Ã' + 2 sym(Ã Π_f' Ǎ') + Ǎ Σ_f Ǎ' ; (47): Π'' = (Ã Π_f' + Ǎ Σ_f) A' ; (46) ---
        Yx = ops.bd_left(At, Pft)  # Ã Π_f'   (Nr x NM)
        P = ops.bd_right(ops.bd_left(At, Pf), At)
        del Pf
        if p45:  # the extracted (45): Ã (acting on x-quantities: Ã_r U') in every term
            Ax = At @ model.U.T
            P += 2.0 * ops.bd_right(Yx, Ax) + ops.bd_right(ops.bd_left(Ax, Sf), Ax)
        if not chk.zero:
            AcS = chk.left(ops, Sf)  # Ǎ Σ_f
            if not p45:  # P += 2 Yx Ǎ' + Ǎ Σ_f Ǎ' (rank M - r factors; row ranges, no full-size temporaries)
                ops.add_check(P, ops.bd_right(Yx, chk.Wt), ops.bd_right(AcS, chk.Wt), chk.Aw)
            ops.add(Yx, AcS)
            del AcS
        ops.sym(P)
        ops.add_tiled(P, GVG1)
        Pt = ops.bd_right(Yx, A)
        del Yx, Pft
        ops.add_tiled(Pt, GV1)
        Sig = ops.bd_right(ops.bd_left(A, Sf), A)  # symmetric to round-off (Σ_f is symmetrized)
        del Sf
        ops.add_tiled(Sig, VV1)
        if not (np.isfinite(P[0, 0]) and np.isfinite(Sig[0, 0])):
            raise DivergenceError(
                f"CIKF gain design: the error covariances overflowed at step {k + 1}; the error dynamics diverge (see tracking_capacity)"
            )
    return _schedules(B_cons, B_innov, K_all, Sp, Sf_all, Ptr, stage)


# ---------------------------------------------------------------------------
# Algorithm 2 on the joint covariance of [e; ε] (method="joint", equations="corrected")
# ---------------------------------------------------------------------------
#: width of the column panels of the M_k products (columns; fixed, so that the numbers do not depend on the
#: thread count): the panel of J's e-rows stays in the cache, and there are enough panels to share
_PANEL_COLS = 512


#: largest (M_k P)' kept as a separate array by method="joint" (bytes): 37 MiB at M = N = 50, 489 MiB at 100
_MPT_BYTES = 256 * 2**20


def _schedules(B_cons: list, B_innov: list, K: Any, Sp: Any, Sf: Any, Ptr: Any, stage: Any) -> dict[str, Any]:
    """What Algorithm 2 returns, whichever recursion ran it (gains, covariances, traces, stage costs)."""
    return {"B_cons": tuple(B_cons), "B_innov": tuple(B_innov), "K": K, "Sigma_pred": Sp, "Sigma_filt": Sf, "P_pred_trace": Ptr, "stage": stage}


def _ranges(pool: Any, workers: int, fn: Callable[[int, int], None], n: int, *, triangular: bool = False, weights: Any = None) -> None:
    """fn(lo, hi) over one contiguous range of range(n) per worker (in ``pool``; inline without one).

    ``triangular``: item i costs ~ n - i (rows of an upper block triangle); ``weights``: item i costs
    weights[i]; either way the ranges get equal work. The items, hence every BLAS call and its shape,
    do not depend on the number of workers.
    """
    if pool is None or workers <= 1 or n < 2:
        fn(0, n)
        return
    if triangular:
        weights = np.arange(n, 0, -1, dtype=float)
    if weights is not None:
        c = np.concatenate([[0.0], np.cumsum(weights, dtype=float)])
        cuts = [0, *(int(np.searchsorted(c, c[-1] * j / workers)) for j in range(1, workers)), n]
    else:
        cuts = np.linspace(0, n, min(workers, n) + 1).round().astype(int).tolist()
    for fut in [pool.submit(fn, a, b) for a, b in zip(cuts[:-1], cuts[1:]) if b > a]:
        fut.result()


def _joint_stage_cost(cost: TeamCost, k: int, J: FloatArray, maps: FloatArray) -> float:
    """E[c] = sum(S ∘ W), W = blockdiag(L_n Ψ_n) J blockdiag(L_n Ψ_n)' for agent n's error L_n Ψ_n [e^n; ε^n]."""
    N, q = maps.shape[0], maps.shape[2]
    LPsi = np.stack([cost.L_block(n, k) for n in range(N)]) @ maps  # (N, d_z, q)
    dz = LPsi.shape[1]
    Y = np.matmul(LPsi, J.reshape(N, q, N * q)).reshape(N * dz, N, q)  # blockdiag(L Ψ) J
    W = np.matmul(Y.transpose(1, 0, 2), LPsi.transpose(0, 2, 1))  # (N, N d_z, d_z): column blocks of W
    return float(np.sum(cost.S_at(k) * W.transpose(1, 0, 2).reshape(N * dz, N * dz)))


def _iterate_joint(
    system: LinearGaussianSystem,
    model: PseudoStateModel,
    nbrs: Sequence[Sequence[int]],
    cost: TeamCost,
    T: int,
    rcond: float,
    form: str,
    fixed: CIKFDesign | None,
    pinv: str,
    pool: Any = None,
    workers: int = 1,
) -> dict[str, Any]:
    r"""Algorithm 2 with the corrected eqs. (41)-(47) as one recursion on J = cov([e; ε]), in reduced coordinates.

    J is N q x N q with q = r + M, agent-major: block (n, m) is E[[e^n; ε^n][e^m; ε^m]'] =
    [[P^{nm}, Π'^{nm}], [Π^{nm}, Σ^{nm}]] (``J4 = J.reshape(N, q, N, q)``). One step is two maps:

    * the update (41)-(42): [e_{k|k}; ε_{k|k-1}] = blockrows(M_k on e, I on ε) [e; ε] - [B^I v; 0], so
      J_f = [[M P M' + B^I D̄ B^I', M Π'], [Π M', Σ]]: M_k acts on the e-rows of J only (Γ' = M Π', eq. 41);
    * the gain K^n and, (43)-(47) fused, the prediction [e; ε]_{k+1|k} = Φ [e_{k|k}; ε_{k|k-1}] + [G_r; I] w with
      Φ_n = [[Ã + Ǎ K^n, Ǎ F^n], [A K^n, A F^n]], F^n = I - K^n G_r (since ε_{k|k} = F ε + K e_{k|k}), so
      J_{k+1|k} = Φ J_f Φ' + (1 1') ⊗ ([G_r; I] V [G_r; I]'): one q x q map per agent on both sides.

    Symmetry is used throughout: M P M' and Φ J_f Φ' are computed on the upper block triangle and
    mirrored. J is updated in place (column panels for M_k, row panels for Φ), so the memory is J, plus
    (M_k P)' (N r x N r) while that is at most ``_MPT_BYTES`` (above, M P M' is formed row by row in place of
    M P). Σ_{k|k} is never formed as a whole: its diagonal blocks are [K F] J_f^{nn} [K F]'.
    """
    N, M, r = system.n_agents, system.dx, model.rank
    q = r + M
    A, Vq, S0 = system.A_at(0), system.Q_at(0), system.Sigma_x
    Gr, At, Ac = model.G_r, model.A_tilde_r, model.A_check_r
    Ct = model.C_tilde
    Rn = [system.R_at(n, 0) for n in range(N)]
    mse_like = _is_mse(cost, N, M, T)
    full_gamma = form == "filter" and not mse_like  # the stage cost then reads the whole J_f
    mirror_rows = r if mse_like else q  # rows of the lower block triangle of J_{k+1|k} that are read
    Gx = np.vstack([Gr, np.eye(M)])  # [e; ε] = [G_r; I] x for x(0) - x̄_0 and for w(k)
    J = np.empty((N * q, N * q))
    J4, J3 = J.reshape(N, q, N, q), J.reshape(N, q, N * q)
    J4[...] = _sym(Gx @ S0 @ Gx.T)[None, :, None, :]  # (1 1') ⊗ cov([G_r x0; x0]) (no tiled temporaries)
    Wn = _sym(Gx @ Vq @ Gx.T)  # the noise block added to every block of J, (45)-(47)
    hoods = [np.asarray([n, *nbrs[n]], dtype=np.intp) for n in range(N)]
    width = max(1, _PANEL_COLS // q)  # agents per column panel of the M_k products
    n_panels = -(-N // width)
    # (M_k P)' as its own (N, r, N, r) array when small (M P M' then takes one large GEMM per agent); else M P is
    # written in place of P and M P M' formed row by row in place (smaller GEMMs, no extra N r x N r array)
    MPt = np.empty((N, r, N, r)) if (N * r) ** 2 * 8 <= _MPT_BYTES else None
    by_size: dict[int, list[int]] = {}
    for n in range(N):
        by_size.setdefault(len(nbrs[n]), []).append(n)
    groups = [(np.asarray(a, dtype=np.intp), np.stack([hoods[n] for n in a])) for _, a in sorted(by_size.items())]
    diag = np.arange(N)
    t4_cost = [(len(nbrs[n]) * r + Ct[n].shape[0]) ** 3 for n in range(N)]  # Theorem 4's factorization, per agent
    eyeM, eyer = np.eye(M), np.eye(r)
    Psi_pred = np.broadcast_to(np.hstack([np.zeros((M, r)), eyeM]), (N, M, q))  # ε^n = [0 I][e^n; ε^n]
    B_cons, B_innov = [], []
    K_all = np.empty((T, N, M, r))
    Sp, Sf_all = np.empty((T, N, M, M)), np.empty((T, N, M, M))
    Ptr = np.empty((T, N))
    stage = np.empty(T)
    noise = np.empty((N, r, r))  # (42): B^I D̄_H B^I' = B_u^n R_n B_u^n', the diagonal blocks of the step
    for k in range(T):
        Sp[k] = J4[diag, r:, diag, r:]
        Ptr[k] = np.trace(J4[diag, :r, diag, :r], axis1=1, axis2=2)
        if form == "predictor":
            stage[k] = float(np.trace(Sp[k], axis1=1, axis2=2).sum()) if mse_like else _joint_stage_cost(cost, k, J, Psi_pred)
        # --- Theorem 4: consensus + innovation gains B̂^n (from P_{k|k-1} = the e-e blocks of J), M_k's block rows ---
        Bc_k: list[Any] = [None] * N
        Bu_k: list[Any] = [None] * N
        rows: list[Any] = [None] * N  # block rows of M_k = I - B^C - B^I D̃_H over the closed neighbourhoods [n, l_1, ..., l_d]

        def gains_and_rows(lo: int, hi: int, k: int = k, rows: list[Any] = rows, Bc_k: list[Any] = Bc_k, Bu_k: list[Any] = Bu_k) -> None:
            for n in range(lo, hi):
                if fixed is None:
                    Bc_k[n], Bu_k[n] = _theorem4_pseudo(J4[:, :r, :, :r], n, nbrs[n], r, Ct[n], Rn[n], rcond, pinv)
                else:
                    Bc_k[n], Bu_k[n] = fixed.B_cons[k][n], fixed.B_innov[k][n]
                d = len(nbrs[n])
                row = np.empty((r, (d + 1) * r))
                row[:, :r] = eyer - Bu_k[n] @ Ct[n] - (Bc_k[n].reshape(r, d, r).sum(axis=1) if d else 0.0)
                row[:, r:] = Bc_k[n]
                rows[n] = row
                nz = Bu_k[n] @ Rn[n] @ Bu_k[n].T
                noise[n] = 0.5 * (nz + nz.T)

        _ranges(pool, workers, gains_and_rows, N, weights=t4_cost if fixed is None else None)
        B_cons.append(tuple(Bc_k))
        B_innov.append(tuple(Bu_k))

        # --- (41), (42): M_k on the e-rows of J (column panels, in place), then M P M' = M (M P)' ---
        def update(lo: int, hi: int, rows: list[FloatArray] = rows) -> None:
            E = np.empty((N, r, width * q))
            for p in range(lo, hi):
                j0, j1 = p * width, min((p + 1) * width, N)
                Ep = E[:, :, : (j1 - j0) * q]
                Ep[...] = J4[:, :r, j0:j1, :].reshape(N, r, -1)  # the panel's e-rows, contiguous (cache-resident)
                for n in range(N):  # one GEMM per agent on its neighbourhood's e-rows, written back in place:
                    # [M P, M Π'] (M P is replaced by M P M' below; Γ' = M Π', eq. 41)
                    np.matmul(rows[n], Ep[hoods[n]].reshape(-1, Ep.shape[2]), out=J4[n, :r, j0:j1, :].reshape(r, -1))
                for j in range(j0, j1):
                    m0 = 0 if full_gamma else j  # Γ: the upper block triangle is all that (43)-(47) read
                    J4[j, r:, m0:, :r] = J4[m0:, :r, j, r:].transpose(2, 0, 1)
                    if MPt is not None:
                        MPt[j] = J4[:, :r, j, :r].transpose(2, 0, 1)  # (M P)' = P M'

        _ranges(pool, workers, update, n_panels)

        def add_noise(n: int) -> None:  # (42) on the diagonal block of row n, once M P M' is there
            Pnn = J4[n, :r, n, :r]
            Pnn[...] = 0.5 * (Pnn + Pnn.T) + noise[n]

        def sandwich_out(lo: int, hi: int, rows: list[FloatArray] = rows) -> None:
            assert MPt is not None
            for n in range(lo, hi):  # block row n of M P M' = M_n (M P)'[hood(n), m >= n]: one GEMM per agent
                h = hoods[n]
                Y = rows[n] @ MPt[h, :, n:, :].reshape(h.size * r, (N - n) * r)
                J4[n, :r, n:, :r] = Y.reshape(r, N - n, r)
                add_noise(n)

        # M_m', by neighbourhood size: for the in-place sandwich only, built once for all its workers
        rowsT_g = [np.stack([rows[m].T for m in agents]) for agents, _ in groups] if MPt is None else []

        def sandwich(lo: int, hi: int, rowsT_g: list[FloatArray] = rowsT_g) -> None:
            for n in range(lo, hi):  # block row n of M P M' = (M P) M' from the diagonal on, in place of (M P)[n]
                MPn = J4[n, :r, :, :r].copy()  # (r, N, r)
                for (agents, hood), RgT in zip(groups, rowsT_g):
                    sel = agents >= n
                    if sel.any():  # (M P M')[n, m] = (M P)[n, hood(m)] M_m'
                        X = MPn[:, hood[sel], :].transpose(1, 0, 2, 3).reshape(int(sel.sum()), r, -1)
                        J4[n, :r, agents[sel], :r] = np.matmul(X, RgT[sel])  # (int, advanced) index: (g, r, r)
                add_noise(n)

        _ranges(pool, workers, sandwich if MPt is None else sandwich_out, N, triangular=True)

        def mirror(lo: int, hi: int) -> None:  # the lower block triangle of M P M'
            for n in range(lo, hi):
                J4[n + 1 :, :r, n, :r] = J4[n, :r, n + 1 :, :r].transpose(1, 2, 0)

        _ranges(pool, workers, mirror, N, triangular=True)
        # --- Theorem 4: state gains K^n from the diagonal blocks of J_f ---
        Jd = J4[diag, :, diag, :]  # (N, q, q): [[P_f^{nn}, Γ'^{nn}], [Γ^{nn}, Σ^{nn}_{k|k-1}]]
        if fixed is not None:
            Kk = np.array(fixed.K[k])
        else:
            Kk = np.empty((N, M, r))
            GrS = Gr @ Jd[:, r:, r:]  # G Σ^{nn}, (N, r, M)
            GrG = Gr @ Jd[:, r:, :r]  # G Γ^{nn}
            S_nu = GrS @ Gr.T - GrG - GrG.transpose(0, 2, 1) + Jd[:, :r, :r]  # G Σ G - G Γ - Γ' G + P_f
            S_xnu = GrS.transpose(0, 2, 1) - Jd[:, r:, :r]  # Σ G - Γ

            def state_gains(lo: int, hi: int, Kk: FloatArray = Kk, S_xnu: FloatArray = S_xnu, S_nu: FloatArray = S_nu) -> None:
                for n in range(lo, hi):
                    Kk[n] = _psd_solve(S_xnu[n], S_nu[n], rcond, pinv)  # (Σ G - Γ) Σ_ν^+

            _ranges(pool, workers, state_gains, N)
        K_all[k] = Kk
        F = eyeM - Kk @ Gr  # (N, M, M)
        KF = np.concatenate([Kk, F], axis=2)  # ε_{k|k} = [K F] [e_{k|k}; ε_{k|k-1}], (N, M, q)
        Sf = KF @ Jd @ KF.transpose(0, 2, 1)  # (43), diagonal blocks
        Sf_all[k] = 0.5 * (Sf + Sf.transpose(0, 2, 1))
        if form == "filter":
            stage[k] = float(np.trace(Sf_all[k], axis1=1, axis2=2).sum()) if mse_like else _joint_stage_cost(cost, k, J, KF)
        if k + 1 == T:
            break
        # --- (43)-(47) fused: J <- Φ J_f Φ' + (1 1') ⊗ W, upper block triangle by row panels, mirrored ---
        Phi = np.empty((N, q, q))
        Phi[:, :r, :r] = At + Ac @ Kk
        Phi[:, :r, r:] = Ac @ F
        Phi[:, r:, :r] = A @ Kk
        Phi[:, r:, r:] = A @ F
        PhiT = np.ascontiguousarray(Phi.transpose(0, 2, 1))

        def predict(lo: int, hi: int, Phi: FloatArray = Phi, PhiT: FloatArray = PhiT) -> None:
            for i in range(lo, hi):
                Y = Phi[i] @ J3[i, :, i * q :]  # Φ_i J_f^{i, j >= i}, (q, (N - i) q)
                blocks = J4[i, :, i:, :].transpose(1, 0, 2)  # (N - i, q, q) view of the blocks (i, j >= i)
                np.matmul(Y.reshape(q, N - i, q).transpose(1, 0, 2), PhiT[i:], out=blocks)  # (Φ_i J_f^{ij}) Φ_j'
                blocks += Wn
                _sym(blocks[0])
                # the lower block triangle: its e-rows are read by Theorem 4 and the update; the rest only by a
                # general stage cost (the e-rows are 47 % of the mirror at M = N = 50)
                J4[i + 1 :, :mirror_rows, i, :] = blocks[1:, :, :mirror_rows].transpose(0, 2, 1)

        _ranges(pool, workers, predict, N, triangular=True)
        if not (np.isfinite(J[0, 0]) and np.isfinite(J[r, r])):
            raise DivergenceError(
                f"CIKF gain design: the error covariances overflowed at step {k + 1}; the error dynamics diverge (see tracking_capacity)"
            )
    return _schedules(B_cons, B_innov, K_all, Sp, Sf_all, Ptr, stage)


@lru_cache(maxsize=8)
def _mse_cost(N: int, M: int) -> TeamCost:
    """TeamCost.mse(N, M), built once per size (validating S = I of size NM costs an NM x NM eigen-decomposition)."""
    return TeamCost.mse(N, M)


def design_cikf(
    system: LinearGaussianSystem,
    cost: TeamCost | CommGraph | None = None,
    graph: CommGraph | int | None = None,
    horizon: int | None = None,
    *,
    form: Form = "filter",
    rcond: float = DEFAULT_RCOND,
    method: Method | None = None,
    check: bool = True,
    gains: CIKFDesign | None = None,
    equations: Literal["corrected", "printed", "printed-43", "printed-45"] = "corrected",
    threads: int | None = 1,
    pinv: Literal["cholesky", "eigh"] = "cholesky",
) -> CIKFDesign:
    """Algorithm 2: optimal CIKF gains (Theorem 4) and the error covariances (corrected eqs. 41-47).

    Parameters
    ----------
    system : LinearGaussianSystem
        Time-invariant; x̄_0 = 0. (A, H) must be detectable (checked when ``check``); G need not be invertible.
    graph : CommGraph
        Every edge with delay 1 (one exchange per step); agent n uses the predictions of ``graph.in_neighbors(n)``
        (an undirected graph has both directions).
    horizon : int
        Number of steps T (gains and covariances for k = 0..T-1).
    cost : TeamCost, optional
        Team cost evaluated by ``stage_costs``; default ``TeamCost.mse(N, M)`` (S = I, L = 1 ⊗ I:
        the sum over agents of E|x(k) - x̂^n|^2). Agent n reports ẑ_n = L_n x̂^n.
    form : "filter" or "predictor"
        ẑ_n(k) = L_n x̂^n_{k|k} (default) or L_n x̂^n_{k|k-1} (the paper's Fig. 4 plots the predictor).
    rcond : float in (0, 1)
        Relative cut-off of the pseudo-inverses of Theorem 4 (module docstring; default 1e-9).
    method : "joint", "structured", "dense" or None (default)
        None: "joint" for the corrected equations, "structured" for the printed ones.
        "joint": one recursion on cov([e; ε]) with the update and the prediction fused into one map per
        agent and symmetric halves (module docstring; about 1.7-2x faster than "structured", memory
        N(r + M) squared; corrected equations only). "structured": the block products of eqs. (41)-(47)
        one by one, the arithmetic of the frozen reference (``tests/unit/test_cikf_reference.py``).
        The two agree to ~1e-12 on everything the gains produce (covariances, costs, errors); the consensus
        gains themselves agree only to the ~1e-8 to which Theorem 4 determines them (module docstring).
        "dense" forms M_k, K, F, I ⊗ Ã, ... as dense NM x NM matrices: the numbers of "structured", much
        slower (the benchmark's baseline).
    check : bool
        Check that (A, H) is detectable (Assumption 4).
    gains : CIKFDesign, optional
        Use that design's gains instead of Theorem 4's (same system, graph and horizon >= this one):
        the covariances are then the true ones of those gains.
    equations : "corrected" (default), "printed", "printed-43" or "printed-45"
        "printed" runs eqs. (43) and (45) as extracted (Π_{k|k-1} for Γ_k, Ã for Ǎ; "printed-43"/"-45": only
        that one) — only to quantify the errata; its covariances are not the filter's (evaluate its gains
        with ``gains=``).
    pinv : "cholesky" (default) or "eigh"
        How Theorem 4's singular covariances are inverted: pivoted Cholesky that drops innovation components
        whose conditional variance is below ``rcond`` times the largest variance (fast), or the truncated
        eigen pseudo-inverse (directions below ``rcond * lambda_max``). They agree to ~1e-4 dB (tested).
    threads : int or None
        Worker threads for the design's block products and the design's Monte Carlo methods, each with a
        single-threaded BLAS (default 1; 2 on an otherwise idle 2-core machine). The products are split
        over contiguous ranges of agents and every block is one BLAS call of the same shape whatever the
        number of threads, so the numbers do not depend on it (tested). Python threads do not spin like
        OpenBLAS's own threads, which can make a shared machine ten times slower (``docs/cikf.md``).
        None leaves the BLAS setting alone and uses no pool.

    Returns
    -------
    CIKFDesign
        The gains and error covariances, with the exact stage costs of the chosen form.

    Examples
    --------
    >>> from teamkf.study.random_field import random_field
    >>> from teamkf.estimators.cikf import design_cikf
    >>> system, graph = random_field(15, 6, rng=1)
    >>> d = design_cikf(system, None, graph, horizon=10)
    >>> d.estimator, d.stage_costs.shape, bool(d.mse()[-1] < d.mse()[0])
    ('cikf', (10,), True)
    """
    if isinstance(cost, CommGraph):  # the 0.1 argument order: design_cikf(system, graph, horizon, cost=...)
        warnings.warn(
            "design_cikf(system, graph, horizon, cost=...) is deprecated; write design_cikf(system, cost, graph, horizon) "
            "(cost None means TeamCost.mse)",
            DeprecationWarning,
            stacklevel=2,
        )
        if horizon is not None:
            raise ArgumentError("horizon: given twice (old and new argument order mixed)", argument="horizon")
        cost, graph, horizon = None, cost, graph  # type: ignore[assignment]
    if not isinstance(graph, CommGraph):
        raise GraphError(f"graph: expected a CommGraph with unit delays, found {type(graph).__name__}", argument="graph")
    t0 = time.perf_counter()
    if not isinstance(system, LinearGaussianSystem):
        raise ArgumentError(f"system: expected a LinearGaussianSystem, found {type(system).__name__}", argument="system")
    model = pseudo_state_model(system)
    N, M = system.n_agents, system.dx
    nbrs = _neighbors(graph, N)
    if horizon is None:
        raise ShapeError("horizon: the CIKF gains are designed over a finite horizon (Algorithm 2), found horizon=None; give T steps")
    T = V.positive_int(horizon, "horizon")
    if cost is None:
        cost = _mse_cost(N, M)
    if not isinstance(cost, TeamCost):
        raise ShapeError(f"cost: expected a TeamCost (or None for TeamCost.mse), found {type(cost).__name__}")
    cost.check_system(M, N)
    cost.require_horizon(T)
    if form not in ("filter", "predictor"):
        raise ShapeError(f"form: expected 'filter' or 'predictor', found {form!r}")
    if method is None:
        method = "joint" if equations == "corrected" else "structured"
    if method not in ("structured", "joint", "dense"):
        raise ShapeError(f"method: expected 'structured', 'joint' or 'dense', found {method!r}")
    if method == "joint" and equations != "corrected":
        raise ArgumentError(
            f"equations: method='joint' runs the corrected eqs. (41)-(47) only (it propagates cov([e; ε]) of the filter), "
            f"found equations={equations!r}; use method='structured'",
            argument="equations",
        )
    if equations not in ("corrected", "printed", "printed-43", "printed-45"):
        raise ShapeError(f"equations: expected 'corrected' or 'printed' ('printed-43', 'printed-45': one of the two), found {equations!r}")
    if isinstance(rcond, bool) or not isinstance(rcond, (int, float, np.floating)) or not 0.0 < float(rcond) < 1.0:
        raise ShapeError(f"rcond: expected a relative cut-off in (0, 1), e.g. 1e-9, found {rcond!r}")
    rcond = float(rcond)
    if gains is not None:
        if not isinstance(gains, CIKFDesign):
            raise ShapeError(f"gains: expected a CIKFDesign whose gains to evaluate, found {type(gains).__name__}")
        if gains.system.n_agents != N or gains.system.dx != M or gains.neighbors != nbrs or gains.model.rank != model.rank:
            raise ShapeError("gains: expected a CIKF design for the same system and graph, found one for another")
        if gains.horizon < T:  # type: ignore[operator]
            raise ShapeError(f"gains: expected a design with horizon >= {T}, found {gains.horizon}")
    if check:
        from .riccati import unstable_unobservable_modes

        bad = unstable_unobservable_modes(system.A_at(0), system.C_stack(0))
        if bad:
            raise DetectabilityError(
                f"system: expected (A, H) detectable (Assumption 4 of the CIKF), found unobservable unstable modes "
                f"{[complex(b) for b in bad[:4]]}; observe them with some agent's C, or pass check=False"
            )
    r = model.rank
    hoods = [np.array([n, *nbrs[n]], dtype=int) for n in range(N)]
    r_idx = [np.concatenate([np.arange(l * r, (l + 1) * r) for l in h]) for h in hoods]
    Ops = _Structured if method == "structured" else _Dense
    if pinv not in ("cholesky", "eigh"):
        raise ShapeError(f"pinv: expected 'cholesky' or 'eigh', found {pinv!r}")
    if threads is not None:
        threads = V.positive_int(threads, "threads")
    with blas_threads(None if threads is None else 1), _worker_pool(threads) as pool:
        if method == "joint":
            res = _iterate_joint(system, model, nbrs, cost, T, rcond, form, gains, pinv, pool, threads or 1)
        else:
            ops = Ops(N, r, hoods, r_idx, pool, threads or 1)
            res = _iterate(system, model, nbrs, cost, T, rcond, form, ops, gains, equations, pinv)
    info = {
        "rank_G": r,
        "G_invertible": model.invertible,
        "lambda_1": model.lambda_1,
        "lambda_m": model.lambda_m,
        "rcond": rcond,
        "method": method,
        "equations": equations,
        "form": form,
        "design_seconds": time.perf_counter() - t0,
        "n_edges": graph.n_edges,
        "evaluated_gains": gains is not None,
        "threads": threads,
        "pinv": pinv,
    }
    return CIKFDesign(
        estimator="cikf",
        horizon=T,
        stage_costs=V.frozen(res["stage"]),
        info=info,
        system=system,
        cost=cost,
        graph=graph,
        model=model,
        form=form,
        rcond=rcond,
        neighbors=nbrs,
        B_cons=res["B_cons"],
        B_innov=res["B_innov"],
        K=V.frozen(res["K"]),
        Sigma_pred=V.frozen(res["Sigma_pred"]),
        Sigma_filt=V.frozen(res["Sigma_filt"]),
        P_pred_trace=V.frozen(res["P_pred_trace"]),
    )


# ---------------------------------------------------------------------------
# Theorem 3: tracking capacity
# ---------------------------------------------------------------------------
def _m_norm(rows: Sequence[FloatArray], hoods: Sequence[np.ndarray], r: int) -> float:
    """||M||_2 of the block-sparse M (dense SVD when small, ARPACK otherwise)."""
    N = len(rows)
    n_tot = N * r
    if n_tot <= 600:
        Mf = np.zeros((n_tot, n_tot))
        for n, row in enumerate(rows):
            Mf[n * r : (n + 1) * r, np.concatenate([np.arange(l * r, (l + 1) * r) for l in hoods[n]])] = row
        return float(np.linalg.norm(Mf, 2))
    import scipy.sparse as sp
    from scipy.sparse.linalg import svds

    ii, jj, vv = [], [], []
    for n, row in enumerate(rows):
        cols = np.concatenate([np.arange(l * r, (l + 1) * r) for l in hoods[n]])
        I, J = np.meshgrid(np.arange(n * r, (n + 1) * r), cols, indexing="ij")
        ii.append(I.ravel())
        jj.append(J.ravel())
        vv.append(row.ravel())
    Ms = sp.csr_matrix((np.concatenate(vv), (np.concatenate(ii), np.concatenate(jj))), shape=(n_tot, n_tot))
    s = svds(Ms, k=1, return_singular_vectors=False, tol=1e-10, random_state=0)
    return float(s[0])


def tracking_bound(design: CIKFDesign, k: int, *, subspace: Literal["range", "full"] = "range") -> float:
    r"""Theorem 3 with given gains: λ_1 / (λ_m ||I - B^C_k - B^I_k D̃_H||_2).

    ``subspace="range"`` (default) takes the norm on range(G)^N, where every
    pseudo-state error lives (the reduced M_k); ``"full"`` as printed, on all of
    R^{NM}: there M_k acts as the identity on null(G)^N, so the norm is >= 1 and
    the bound <= λ_1/λ_m whenever G is singular. ``inf`` when the norm is 0.
    """
    if not isinstance(design, CIKFDesign):
        raise ShapeError(f"design: expected a CIKFDesign, found {type(design).__name__}")
    if subspace not in ("range", "full"):
        raise ShapeError(f"subspace: expected 'range' or 'full', found {subspace!r}")
    rows = design.m_rows(k)
    hoods = [np.array([n, *design.neighbors[n]]) for n in range(design.n_agents)]
    nrm = _m_norm(rows, hoods, design.model.rank)
    if subspace == "full" and not design.model.invertible:
        nrm = max(nrm, 1.0)
    m = design.model
    return float("inf") if nrm <= 1e-12 else m.lambda_1 / (m.lambda_m * nrm)


@dataclass(frozen=True, eq=False)
class TrackingCapacity:
    """The tracking capacity of Theorem 3 and the structured gains that attain it.

    Attributes
    ----------
    capacity : float           C = λ_1 / (λ_m min ||M||_2)  (inf when min ||M|| = 0)
    min_norm : float           min over structured B^C, B^I of ||I - B^C - B^I D̃_H||_2 (on range(G)^N)
    lower_bound_norm : float   min over B^I alone of ||M (1 ⊗ I)|| / sqrt(N): M (1 ⊗ y) does not depend on
                               B^C, so every graph — the complete one too — has min_norm >= this
    capacity_upper : float     λ_1 / (λ_m lower_bound_norm): no graph exceeds it
    lambda_ratio : float       λ_1 / λ_m
    B_cons, B_innov : tuples   optimal reduced-coordinate blocks (per agent)
    status : str               solver status
    """

    capacity: float
    min_norm: float
    lower_bound_norm: float
    capacity_upper: float
    lambda_ratio: float
    B_cons: tuple
    B_innov: tuple
    status: str


def tracking_capacity_upper_bound(system: LinearGaussianSystem) -> float:
    r"""A graph-independent closed-form upper bound on Theorem 3's capacity (no solver needed).

    Since B^C (1 ⊗ y) = 0, ||M|| >= ||stack_n(I - B_u^n C̃_n)|| / sqrt(N) (see :func:`tracking_capacity`), and
    ||X||_2^2 >= ||X||_F^2 / r with ||I - B C̃_n||_F^2 >= r - rank(C̃_n), so

    .. math::

        \min ||I - B^C - B^I \tilde D_H||_2 \ge \sqrt{1 - \textstyle\sum_n \operatorname{rank}(H_n U) / (N r)}, \qquad
        C \le \frac{\lambda_1}{\lambda_m} \Big/ \sqrt{1 - \textstyle\sum_n \operatorname{rank}(H_n U)/(N r)}

    for every graph (inf when the agents' ranks add up to N r, e.g. every agent observes range(G)).
    """
    model = pseudo_state_model(system)
    N, r = system.n_agents, model.rank
    ranks = sum(int(np.linalg.matrix_rank(c)) for c in model.C_tilde)
    frac = 1.0 - ranks / (N * r)
    ratio = model.lambda_1 / model.lambda_m
    return float("inf") if frac <= 0 else ratio / float(np.sqrt(frac))


def tracking_capacity(system: LinearGaussianSystem, graph: CommGraph, *, solver: str | None = None, zero_tol: float = 1e-7) -> TrackingCapacity:
    r"""Theorem 3: C = max over structured B^C, B^I of λ_1 / (λ_m ||I - B^C - B^I D̃_H||_2), with cvxpy.

    B^C has the graph's Laplacian block pattern ([B^C]_{nl} = -B^{nl}, [B^C]_{nn} = Σ_l B^{nl}) and B^I is
    block-diagonal; minimizing the spectral norm of this affine map is a convex (SDP) problem. It is
    solved in reduced coordinates on range(G)^N (B_r^{nl}: r x r, B_u^n: r x M_n), which equals the
    paper's problem when G is invertible and is its meaningful restriction when G is singular (on
    null(G)^N the printed M is the identity). For small problems only (the SDP has N r rows).

    Needs the optional extra ``cvx`` (``pip install 'teamkf[cvx]'``).

    Also returned: a graph-independent lower bound on the norm. Since B^C (1 ⊗ y) = 0,
    M (1 ⊗ y) = [(I - B_u^n C̃_n) y]_n whatever the graph, so even the complete graph has a finite
    capacity unless every agent alone observes range(G) (then B_u^n C̃_n = I is possible and C = inf).
    On every connected graph we tried the optimum *attains* this bound (line = ring = complete): the
    capacity (53) depends on the graph only through whether each connected component jointly observes
    range(G) (``docs/cikf.md``).
    """
    cp = V.require("cvxpy", "cvx")
    model = pseudo_state_model(system)
    N = system.n_agents
    nbrs = _neighbors(graph, N)
    r = model.rank
    Ct = model.C_tilde
    Bc = {(n, l): cp.Variable((r, r)) for n in range(N) for l in nbrs[n]}
    Bu = [cp.Variable((r, Ct[n].shape[0])) for n in range(N)]
    eye = np.eye(r)
    blocks = []
    for n in range(N):
        row = []
        for l in range(N):
            if l == n:
                expr = eye - Bu[n] @ Ct[n]
                for q in nbrs[n]:
                    expr = expr - Bc[(n, q)]
                row.append(expr)
            elif l in nbrs[n]:
                row.append(Bc[(n, l)])
            else:
                row.append(np.zeros((r, r)))
        blocks.append(row)
    Mexpr = cp.bmat(blocks)
    prob = cp.Problem(cp.Minimize(cp.sigma_max(Mexpr)))
    prob.solve(solver=solver)
    min_norm = float(prob.value)
    # graph-independent lower bound: M (1 ⊗ I_r) / sqrt(N) = stack_n (I - B_u^n C̃_n) / sqrt(N)
    Bu2 = [cp.Variable((r, Ct[n].shape[0])) for n in range(N)]
    stack = cp.vstack([eye - Bu2[n] @ Ct[n] for n in range(N)]) / np.sqrt(N)
    prob2 = cp.Problem(cp.Minimize(cp.sigma_max(stack)))
    prob2.solve(solver=solver)
    lb = float(prob2.value)
    ratio = model.lambda_1 / model.lambda_m
    cap = float("inf") if min_norm <= zero_tol else ratio / min_norm
    cap_up = float("inf") if lb <= zero_tol else ratio / lb
    return TrackingCapacity(
        cap,
        min_norm,
        lb,
        cap_up,
        ratio,
        tuple(np.hstack([Bc[(n, l)].value for l in nbrs[n]]) if nbrs[n] else np.zeros((r, 0)) for n in range(N)),
        tuple(Bu[n].value for n in range(N)),
        str(prob.status),
    )


FAMILY = _register_builtin(
    Family(
        name="cikf",
        design=design_cikf,
        title="Consensus+Innovations Kalman filter with optimized gains (Das & Moura 2016, Algorithms 1-2, Theorem 4)",
        uses="graph",
        horizons=frozenset({"finite"}),
        unit_delays=True,
        options=(
            Option(
                name="form",
                default="filter",
                check=lambda v, k: V.choice(v, k, ("filter", "predictor")),
                doc='"filter": L x^n(k|k); "predictor": L x^n(k|k-1) (the paper\'s Fig. 4)',
            ),
            Option(
                name="method",
                default="joint",
                check=lambda v, k: V.choice(v, k, ("joint", "structured", "dense")),
                doc='"joint": one fused recursion on cov([e; ε]); "structured": eqs. (41)-(47) block by block, about 1.7-2x '
                'slower (same covariances and costs to ~1e-12); "dense": dense operators (a baseline)',
            ),
        ),
        example="design_cikf(system, cost, graph, horizon=32)",
    )
)
