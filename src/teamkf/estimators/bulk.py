"""Exact growing-memory ("bulk") filter for interference-coupled agents, its finite-memory
approximations (Theorem 2) and the isolated Kalman sequence (eqs. 6-9, Proposition 1).

Reference: M. Abedinpour Fallah, R. P. Malhamé, D. Saussié, F. Martinelli,
"Filtering for decentralized control in multi-agent interference coupled
systems", Les Cahiers du GERAD G-2017-04 (2017). Equation numbers below are the
paper's.

Model (:class:`~teamkf.models.population.PopulationModel`): N scalar agents,
``x_{k+1,i} = a x_{k,i} - b f xhat_{k,i} + w_{k,i}``, ``y_{k,i} = c x_{k,i} + h m_k + v_{k,i}``
with ``m_k`` the population mean; every agent applies the same linear filter
``xhat_{k,i} = E x_k + K_k (Y^k_{1,i} - E Y^k_{1,i})`` (eqs. 15-17) on its own
measurements y_1 .. y_k.

How the exact filter is computed (no agent is simulated; see docs/bulk.md)
--------------------------------------------------------------------------
1. **Mean/deviation split.** Because every agent applies the same linear
   filter, the population mean (m_k, its measurement ybar_k = (c+h) m_k + vbar_k,
   the mean estimate) and each agent's deviation from it (d_k = x_k - m_k,
   y_k - ybar_k = c d_k + v_k - vbar_k) are two *independent* closed loops of the
   same form, driven by noises of variance (sigma_w**2, sigma_v**2, sigma_0**2)/N
   and (1 - 1/N)(...). Agent i sees their sum.
2. **Innovation form.** With e_k the agent's normalized innovation,
   ``xhat_k = a_f xhat_{k-1} + g_k e_k`` (the paper's eq. 70: K_k(1:k-1) =
   a_f K_{k-1}), and
   ``e_k = (y_k - E y_k - c a_f xhat_{k-1} - h sum_{t<k} mu_{k,t} e_t) / s_k``
   where ``mu_{k,t} = Cov(m_k, e_t)`` is the agent's predictor of the mean
   (the "infinite regress" of the paper: it has no finite-dimensional
   recursion). Splitting e_k = eta^m_k + eta^d_k into its mean and deviation
   parts, Cov(eta^m) = C (a T x T matrix) and Cov(eta^d) = I - C, so one step
   costs one matrix-vector product with C plus O(k) work; everything else
   (g_k, s_k, mu_k, the closed-loop covariances) follows from scalar and
   vector recursions.
3. **Gains in measurement coordinates.** y = M e with M lower triangular
   (M_{k,t} = Cov(y_k, e_t) = c a_f^{k-t} g_t + h mu_{k,t}, M_{kk} = s_k), so
   K_k = gamma_k M_{1:k,1:k}^{-1} with gamma_k(t) = a_f^{k-t} g_t: one
   triangular solve for K_T, one triangular inversion (BLAS-3) for all K_k.

The cost is O(T^2) memory and at most O(T^3) time (one matrix-vector product
with the k x k block of C at step k); where the filter becomes stationary the
old coefficients decay geometrically and are flushed to zero once they fall
below ``flush`` times the largest entry of their vector (default 1e-30: their
total effect on any computed number is below T * 1e-30 relative, far below
round-off). This also keeps subnormal floats (up to 10x slower on x86) out of
the arithmetic, and lets each step work only on the non-zero band, so
stationary cases cost O(T * band^2). ``flush=0`` turns both off.

Notation
--------
=================  =============================================================
symbol             meaning
=================  =============================================================
K_k                1 x k gain on (y_1..y_k), oldest first (eq. 17)
g_k                Cov(x_k, e_k): gain on the normalized innovation e_k
s_k                innovation standard deviation, s_k**2 = Var(y_k | Y_{1:k-1})
mu_{k,t}           Cov(m_k, e_t), t < k: agent's predictor of the mean
Sigma_k            filter error variance Var(x_k - xhat_k) (eq. 16)
K*(a), P_inf(a)    isolated (h = 0) steady-state Kalman gain (eqs. 6-7)
f*(a, r)           Riccati feedback gain (eqs. 8-9)
K'_j               isolated FIR sequence (a_f (1 - c K*))^{j-1} K* (Prop. 1)
=================  =============================================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.linalg import cho_factor, cho_solve, solve_triangular
from scipy.linalg.lapack import dtrtri

from .. import _validation as V
from .._blas import single_thread_blas
from .._validation import FloatArray
from ..exceptions import DivergenceError, ShapeError
from ..models.population import PopulationModel

__all__ = [
    "FLUSH",
    "single_thread_blas",
    "ClosedLoopCovariances",
    "BulkFilter",
    "FiniteMemoryFilter",
    "exact_bulk_filter",
    "finite_memory_filter",
    "bulk_filter",
    "isolated_prior_variance",
    "isolated_kalman_gain",
    "riccati_feedback_gain",
    "isolated_gains",
    "stationarity_index",
    "discrepancy_index",
]

#: default relative flush threshold for decaying coefficients (see the module docstring)
FLUSH = 1e-30
#: the exact filter stops (DivergenceError) when the round-off bound of the innovation variance s_k^2
#: exceeds this fraction of s_k^2: fewer than 4 significant digits left (see exact_bulk_filter, Notes)
PRECISION_FLOOR = 1e-4
#: a closed loop counts as diverged once Var x_k exceeds PRECISION_FLOOR / eps (4.5e11) times its largest noise
#: variance: an error variance of the order of the noise, computed as a difference of such numbers, then has
#: fewer than 4 correct digits (see finite_memory_filter)
DIVERGENCE_RATIO = PRECISION_FLOOR / float(np.finfo(float).eps)


# ---------------------------------------------------------------------------
# isolated (naive) Kalman filter and Riccati gain
# ---------------------------------------------------------------------------
def _positive_root(A: float, B: float, C0: float) -> float:
    """Largest root of A x^2 + B x - C0 = 0 (A > 0, C0 >= 0), without cancellation."""
    disc = math.sqrt(B * B + 4.0 * A * C0)
    if B <= 0:
        return (-B + disc) / (2.0 * A)
    return (2.0 * C0) / (B + disc) if C0 > 0 else 0.0


def isolated_prior_variance(a: float, *, c: float = 1.0, sigma_w: float = 1.0, sigma_v: float = 1.0) -> float:
    """P_inf(a): the positive root of eq. (7), the steady prior variance of the isolated filter.

    ``c^2 P^2 + ((1 - a^2) sigma_v^2 - c^2 sigma_w^2) P - sigma_w^2 sigma_v^2 = 0``  (7)

    Examples
    --------
    >>> round(isolated_prior_variance(5.0), 4)
    25.0399
    """
    if not (c > 0 and sigma_v > 0 and sigma_w >= 0):
        raise ShapeError(f"c, sigma_v, sigma_w: expected c > 0, sigma_v > 0, sigma_w >= 0, found {c!r}, {sigma_v!r}, {sigma_w!r}")
    q, r = sigma_w**2, sigma_v**2
    return _positive_root(c * c, (1.0 - a * a) * r - c * c * q, q * r)


def isolated_kalman_gain(a: float, *, c: float = 1.0, sigma_w: float = 1.0, sigma_v: float = 1.0) -> float:
    """K*(a) = c P_inf / (c^2 P_inf + sigma_v^2) (eq. 6): the naive filter that ignores h.

    Examples
    --------
    >>> round(isolated_kalman_gain(5.0), 4), round(isolated_kalman_gain(2.5), 4)
    (0.9616, 0.865)
    """
    P = isolated_prior_variance(a, c=c, sigma_w=sigma_w, sigma_v=sigma_v)
    return c * P / (c * c * P + sigma_v**2)


def riccati_feedback_gain(a: float, r: float, *, b: float = 1.0) -> float:
    """f*(a, r) = a b Sigma / (b^2 Sigma + r) (eq. 8), Sigma the positive root of eq. (9).

    ``b^2 Sigma^2 + (r - a^2 r - b^2) Sigma - r = 0``  (9)

    Examples
    --------
    >>> round(riccati_feedback_gain(2.0, 1.0), 4), round(riccati_feedback_gain(5.0, 1.0), 4)
    (1.618, 4.808)
    """
    if not (b > 0 and r > 0):
        raise ShapeError(f"b, r: expected b > 0 and r > 0, found b = {b!r}, r = {r!r}")
    S = _positive_root(b * b, r - a * a * r - b * b, r)
    return a * b * S / (b * b * S + r)


def isolated_gains(model: PopulationModel, length: int, *, K: float | None = None) -> FloatArray:
    """The isolated Kalman filter as an FIR sequence [K'_length, ..., K'_2, K'_1] (Prop. 1, eqs. 54-57).

    ``K'_j = (a_f (1 - c K*))^{j-1} K*``, oldest measurement first (as the gains
    K_k), so that it lines up with the last ``length`` entries of a bulk gain.

    Parameters
    ----------
    model : PopulationModel
    length : int
    K : float, optional
        The observer gain (default K*(a) of eq. 6).

    Examples
    --------
    >>> from teamkf.models.population import PopulationModel
    >>> isolated_gains(PopulationModel(n_agents=1, a=2.5, f=2.0), 4).round(5).tolist()
    [0.00027, 0.00394, 0.0584, 0.86498]
    """
    n = V.positive_int(length, "length")
    Ks = isolated_kalman_gain(model.a, c=model.c, sigma_w=model.sigma_w, sigma_v=model.sigma_v) if K is None else float(K)
    rho = model.a_f * (1.0 - model.c * Ks)
    with np.errstate(under="ignore", over="ignore"):
        p = rho ** np.arange(n - 1, -1, -1, dtype=float)
    p[np.abs(p) < FLUSH] = 0.0
    return V.frozen(Ks * p)


def stationarity_index(K_prev: Any, K_last: Any) -> float:
    """Eq. (61): ||K_{T-1}(1:T-1) - K_T(2:T)||, the two gains aligned by lag.

    For a growing-memory filter (len K_T = len K_{T-1} + 1) this is the paper's
    index; for a memory-n filter (both of length n) it is ||K_{T-1} - K_T||.
    """
    a = np.asarray(K_prev, dtype=float)
    b = np.asarray(K_last, dtype=float)
    L = min(a.size, b.size)
    return float(np.linalg.norm(a[a.size - L :] - b[b.size - L :]))


def discrepancy_index(K: Any, K_isolated: Any) -> float:
    """Eq. (62): ||K_bulk - K_isolated||, aligned on the newest measurement (the shorter is zero-padded)."""
    a = np.asarray(K, dtype=float)
    b = np.asarray(K_isolated, dtype=float)
    L = max(a.size, b.size)
    pa = np.zeros(L)
    pb = np.zeros(L)
    pa[L - a.size :] = a
    pb[L - b.size :] = b
    return float(np.linalg.norm(pa - pb))


# ---------------------------------------------------------------------------
# results
# ---------------------------------------------------------------------------
def _ro(a: np.ndarray) -> FloatArray:
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class ClosedLoopCovariances:
    """Exact first and second moments of one agent of the closed loop, k = 0 .. T.

    The arrays have length T + 1 (index k).

    Attributes
    ----------
    state_mean : E x_{k,i} = a_f^k x0_mean (also E xhat_{k,i})
    state_variance : Var x_{k,i}
    estimate_variance : Var xhat_{k,i}
    error_variance : Var(x_{k,i} - xhat_{k,i})  (eq. 16; sigma_0^2 at k = 0)
    mean_variance : Var m_k (the population mean; Fig. 9)
    cross_covariance : Cov(x_{k,i}, x_{k,j}), i != j (Fig. 8): Var m_k - Var d_k / (N - 1);
        NaN for N = 1
    n_agents : int
    """

    state_mean: FloatArray
    state_variance: FloatArray
    estimate_variance: FloatArray
    error_variance: FloatArray
    mean_variance: FloatArray
    cross_covariance: FloatArray
    n_agents: int

    @property
    def horizon(self) -> int:
        return int(self.state_variance.size - 1)

    def stage_costs(self, r: float, f: float) -> FloatArray:
        """E[x_k^2 + r u_k^2] for k = 0 .. T-1, u_k = -f xhat_k (the summand of eq. 3)."""
        T = self.horizon
        m2 = self.state_mean[:T] ** 2
        return _ro(self.state_variance[:T] + m2 + r * f * f * (self.estimate_variance[:T] + m2))

    def lq_cost(self, r: float, f: float) -> float:
        """(1/T) sum_{k=0}^{T-1} E[x_k^2 + r u_k^2]: the average LQ cost per agent (eq. 3 over T)."""
        return float(np.mean(self.stage_costs(r, f)))

    def to_pandas(self) -> Any:
        pd = V.require("pandas", "dask")
        return pd.DataFrame(
            {
                "k": np.arange(self.state_variance.size),
                "state_mean": self.state_mean,
                "state_variance": self.state_variance,
                "estimate_variance": self.estimate_variance,
                "error_variance": self.error_variance,
                "mean_variance": self.mean_variance,
                "cross_covariance": self.cross_covariance,
            }
        )


def _covariances(model: PopulationModel, vx: np.ndarray, vxh: np.ndarray, sig: np.ndarray, vm: np.ndarray) -> ClosedLoopCovariances:
    T = vx.size - 1
    N = model.n_agents
    with np.errstate(under="ignore", over="ignore"):
        mean = model.x0_mean * model.a_f ** np.arange(T + 1, dtype=float)
    if N > 1:
        with np.errstate(over="ignore", invalid="ignore"):
            cross = vm - (vx - vm) / (N - 1)
    else:
        cross = np.full(T + 1, np.nan)
    return ClosedLoopCovariances(_ro(mean), _ro(vx), _ro(vxh), _ro(sig), _ro(vm), _ro(np.asarray(cross, dtype=float)), N)


class _GainsMixin:
    """Shared gain accessors (K_k oldest first)."""

    horizon: int
    model: PopulationModel
    covariances: ClosedLoopCovariances

    def gain(self, k: int) -> FloatArray:  # pragma: no cover - overridden
        raise NotImplementedError

    def final_gains(self) -> FloatArray:
        """K_T, oldest measurement first."""
        return self.gain(self.horizon)

    def _repr_html_(self) -> str:
        from .._repr import html_table

        m, cov = self.model, self.covariances
        rows: list[dict[str, Any]] = [
            {"field": "filter", "value": type(self).__name__},
            {"field": "agents N", "value": m.n_agents},
            {"field": "a, b, f (a_f = a - b f)", "value": f"{m.a:g}, {m.b:g}, {m.f:g} ({m.a_f:g})"},
            {"field": "horizon T", "value": self.horizon},
        ]
        for name in ("memory", "band", "diverged_at"):
            if hasattr(self, name):
                rows.append({"field": name, "value": getattr(self, name)})
        rows.append({"field": "Var(x_T - xhat_T) (exact)", "value": float(cov.error_variance[-1])})
        rows.append({"field": "Var x_T (exact)", "value": float(cov.state_variance[-1])})
        return html_table(["field", "value"], rows, caption="teamkf bulk filter")

    def plot(self, ax: Any = None) -> Any:
        """Exact closed-loop variances against k: state, estimation error, population mean; returns the axes."""
        from ..plotting import _pyplot, legend_outside

        cov = self.covariances
        plt = _pyplot()
        if ax is None:
            _, ax = plt.subplots(figsize=(6, 4))
        k = np.arange(len(cov.state_variance))
        ax.plot(k, cov.state_variance, label="Var x_k")
        ax.plot(k, cov.error_variance, label="Var(x_k - xhat_k)")
        ax.plot(k, cov.mean_variance, label="Var m_k (population mean)")
        ax.set_yscale("log")
        ax.set_xlabel("k")
        ax.set_title(f"{type(self).__name__}, N = {self.model.n_agents}")
        legend_outside(ax)
        return ax

    def stationarity_index(self) -> float:
        """Eq. (61) at the end of the horizon (0.0 for T = 1)."""
        if self.horizon < 2:
            return 0.0
        return stationarity_index(self.gain(self.horizon - 1), self.gain(self.horizon))


@dataclass(frozen=True, eq=False)
class BulkFilter(_GainsMixin):
    """The exact growing-memory filter over T steps, in innovation form.

    ``xhat_k = E x_k + a_f (xhat_{k-1} - E x_{k-1}) + g_k e_k`` with
    ``e_k = (y_k - (c+h) E x_k - c a_f (xhat_{k-1} - E x_{k-1}) - h sum_{t<k} mu[k-1, t-1] e_t) / s_k``
    reproduces eqs. (15)-(17) exactly; :meth:`gain` and :meth:`gains` give the
    same filter in the paper's measurement coordinates.

    Attributes
    ----------
    model : PopulationModel
    horizon : int
        T.
    g : (T,) array
        g[k-1] = Cov(x_k, e_k).
    s : (T,) array
        s[k-1] = innovation standard deviation at step k (>= sigma_v).
    mu : (T, T) array
        Strictly lower triangular: mu[k-1, t-1] = Cov(m_k, e_t), t < k.
    covariances : ClosedLoopCovariances
    flush : float
        Relative flush threshold used (0: none).
    band : int
        Largest number of non-zero past coefficients the recursion carried
        (T - 1 where nothing was flushed).
    flops : int
        Floating-point operations of the recursion (2 per multiply-add of the
        matrix-vector products, plus an estimated 40 per carried coefficient
        for the vector updates); for benchmarks.
    """

    model: PopulationModel
    horizon: int
    g: FloatArray
    s: FloatArray
    mu: FloatArray
    covariances: ClosedLoopCovariances
    flush: float = FLUSH
    band: int = 0
    flops: int = 0
    _cache: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)

    memory = 0

    @property
    def last_entries(self) -> FloatArray:
        """K_k(k) for k = 1..T (weight of the newest measurement; Fig. 7): g_k / s_k."""
        return _ro(self.g / self.s)

    def _powers(self) -> np.ndarray:
        p = self._cache.get("powers")
        if p is None:
            with np.errstate(under="ignore", over="ignore"):
                p = self.model.a_f ** np.arange(self.horizon, dtype=float)
            if self.flush > 0:
                p[np.abs(p) < self.flush] = 0.0
            self._cache["powers"] = p
        return p  # type: ignore[no-any-return]

    def innovation_gains(self, k: int) -> FloatArray:
        """gamma_k(t) = Cov(x_k, e_t) = a_f^{k-t} g_t, t = 1..k."""
        k = self._check_k(k)
        return _ro(self._powers()[:k][::-1] * self.g[:k])

    def _check_k(self, k: int) -> int:
        k = V.positive_int(k, "k")
        if k > self.horizon:
            raise ShapeError(f"k: expected 1 <= k <= horizon = {self.horizon}, found {k}")
        return k

    def measurement_matrix(self) -> FloatArray:
        """M (T x T, lower triangular) with Y - E Y = M e: M[k-1, t-1] = Cov(y_k, e_t).

        ``M[k, t] = c a_f^{k-t} g_t + h mu[k, t]`` below the diagonal, ``M[k, k] = s_k``.
        """
        M = self._cache.get("M")
        if M is None:
            T = self.horizon
            p = self._powers()
            c = self.model.c
            M = self.model.h * np.asarray(self.mu)  # a new array
            for k in range(1, T):
                M[k, :k] += c * p[k:0:-1] * self.g[:k]
            M[np.arange(T), np.arange(T)] = self.s
            self._cache["M"] = _ro(M)
        return M  # type: ignore[no-any-return]

    def gain(self, k: int) -> FloatArray:
        """K_k (eq. 17): the 1 x k gain on y_1..y_k, oldest first, by one triangular solve."""
        k = self._check_k(k)
        cached = self._cache.get("gains")
        if cached is not None:
            return _ro(cached[k - 1, :k].copy())
        M = self.measurement_matrix()
        x = solve_triangular(M[:k, :k], self.innovation_gains(k), lower=True, trans="T", check_finite=False)
        return _ro(np.asarray(x, dtype=float))

    def gains(self) -> FloatArray:
        """All gains: a (T, T) lower-triangular array whose row k-1 is K_k (zeros after column k).

        Computed as Gamma M^{-1} with one triangular inversion (LAPACK dtrtri,
        T^3/3 flops, one BLAS thread) and the recursion K_k = a_f [K_{k-1}, 0] + g_k W_k
        (eq. 21 with W = M^{-1}: row k of W is the innovation filter e_k = W_k Y).
        """
        K = self._cache.get("gains")
        if K is None:
            # M is C-ordered, so M.T is Fortran-ordered and upper triangular: inverting it
            # in place gives W.T in Fortran order, i.e. W = M^{-1} in C order, with no copy.
            Mt = np.array(self.measurement_matrix(), order="C", copy=True).T
            with single_thread_blas():  # threaded dtrtri is 2x faster on an idle machine, 5-30x slower on a busy one
                Wt, info = dtrtri(Mt, lower=0, overwrite_c=1)
            if info != 0:  # pragma: no cover - s_k >= sigma_v > 0
                raise ShapeError(f"gains: the measurement matrix is singular (dtrtri info {info})")
            del Mt
            K = np.ascontiguousarray(Wt.T)  # no copy when dtrtri worked in place
            del Wt
            T = self.horizon
            af = self.model.a_f
            fl = self.flush
            # overwrite W row by row with K_k = a_f [K_{k-1}, 0] + g_k W_k  (eq. 21)
            K[0, 0] *= self.g[0]
            for k in range(1, T):
                row = K[k, : k + 1]
                row *= self.g[k]
                row[:k] += af * K[k - 1, :k]
                if fl > 0:
                    _flush(row, fl)
            self._cache["gains"] = _ro(K)
        return K  # type: ignore[no-any-return]


@dataclass(frozen=True, eq=False)
class FiniteMemoryFilter(_GainsMixin):
    """The memory-n filter of Theorem 2 and its exact closed loop.

    ``xhat^{(n)}_k = E x_k + K^{(n)}_k (Y^k_{k-n+1} - E Y^k_{k-n+1})`` (eqs. 47-50, with the
    mean term kept so that x0_mean != 0 is allowed), where K^{(n)}_k is the best
    linear gain given only the last min(k, n) measurements *in the closed loop
    that uses these same finite-memory estimates*.

    Attributes
    ----------
    model : PopulationModel
    horizon : int
    memory : int
        n.
    K : (T, n) array
        Row k-1 is K^{(n)}_k right-aligned (oldest first; the first n - k entries
        are 0 while k < n).
    covariances : ClosedLoopCovariances
    diverged_at : int or None
        First step whose covariances overflowed (the closed loop is unstable);
        the rest of K and the covariances are NaN.
    """

    model: PopulationModel
    horizon: int
    memory: int
    K: FloatArray
    covariances: ClosedLoopCovariances
    diverged_at: int | None = None

    @property
    def last_entries(self) -> FloatArray:
        """K^{(n)}_k(end) for k = 1..T (weight of the newest measurement)."""
        return _ro(self.K[:, -1].copy())

    def gain(self, k: int) -> FloatArray:
        """K^{(n)}_k, length min(k, n), oldest first."""
        k = V.positive_int(k, "k")
        if k > self.horizon:
            raise ShapeError(f"k: expected 1 <= k <= horizon = {self.horizon}, found {k}")
        L = min(k, self.memory)
        return _ro(self.K[k - 1, self.memory - L :].copy())

    def gains(self) -> FloatArray:
        """The (T, n) array of gains (row k-1 = K^{(n)}_k, right-aligned)."""
        return self.K


# ---------------------------------------------------------------------------
# the exact filter
# ---------------------------------------------------------------------------
_OPENBLAS: list[tuple[Any, Any]] | None = None


def _flush(v: np.ndarray, thr_rel: float) -> None:
    if thr_rel > 0 and v.size:
        m = float(np.max(np.abs(v)))
        if m > 0:
            v[np.abs(v) < thr_rel * m] = 0.0


def _first_nonzero(v: np.ndarray) -> int:
    nz = np.flatnonzero(v)
    return int(nz[0]) if nz.size else v.size


def exact_bulk_filter(model: PopulationModel, horizon: int, *, flush: float = FLUSH, progress: bool | None = None) -> BulkFilter:
    """The exact growing-memory filter (eqs. 15-17 / Theorem 1) and its closed loop, for any N.

    Parameters
    ----------
    model : PopulationModel
        ``model.memory`` is ignored (see :func:`bulk_filter`).
    horizon : int
        T: gains K_1 .. K_T.
    flush : float
        Relative threshold below which decayed coefficients are set to 0
        (default 1e-30; 0 turns flushing and the band restriction off).
    progress : bool or None
        Progress bar on stderr after 2 s (None: only when stderr is a terminal).

    Returns
    -------
    BulkFilter

    Raises
    ------
    teamkf.exceptions.DivergenceError
        (``argument="horizon"``) at the first step k where the innovation
        variance has lost its precision (see Notes): the closed loop is
        unstable (``|a_f| >= 1`` or an unstable mean loop) and the horizon is too
        long for double precision. The message gives the last reliable horizon.
    teamkf.exceptions.ArgumentError
        When the two T x T matrices (16 T^2 bytes) do not fit in memory.

    Notes
    -----
    Per step k (measurement k+1), with alpha = Cov(m_k, eta^m_{1:k}),
    beta = Cov(mtilde_k, eta^m_{1:k}) (mtilde the population-mean estimate) and
    C = Cov(eta^m) (docs/bulk.md, section "The exact filter")::

        mu     = a alpha - b f beta                      Cov(m_{k+1}, e_{1:k})
        Pi_xx  = a^2 Sigma_k + sigma_w^2                 Var(x_{k+1} | Y_{1:k})
        Pi_xm  = Var m_{k+1} - a_f gamma_k . mu          Cov(x_{k+1}, m_{k+1} | Y_{1:k})
        Pi_mm  = Var m_{k+1} - mu . mu
        s^2    = c^2 Pi_xx + 2 c h Pi_xm + h^2 Pi_mm + sigma_v^2
        g      = (c Pi_xx + h Pi_xm) / s
        C[k+1, 1:k] = ((c+h) mu - c a_f beta - h C mu) / s

    In exact arithmetic s^2 >= sigma_v^2 > 0. In floating point, s^2 is a sum
    of terms as large as Var m_{k+1}, which grows like a_f^{2k} (or a^{2k})
    when the closed loop is unstable, while s^2 stays of the order of the
    noise: its round-off bound
    ``eps (c^2 |Pi_xx| + 2|c h| (Var m + |gamma . mu|) + h^2 (Var m + mu . mu) + sigma_v^2)``
    is checked at every step, and the filter stops with a DivergenceError
    once the bound exceeds ``PRECISION_FLOOR`` (1e-4) times s^2 (the gains
    would then carry fewer than 4 correct digits, and a few steps later s^2
    turns negative). A stable closed loop never gets there.

    Examples
    --------
    >>> from teamkf.models.population import PopulationModel
    >>> bf = exact_bulk_filter(PopulationModel(n_agents=1000, a=2.5, f=2.0), 300)
    >>> bf.final_gains()[-5:].round(4).tolist()
    [-0.0006, 0.0015, 0.0018, 0.0615, 0.8628]
    """
    if not isinstance(model, PopulationModel):
        raise ShapeError(f"model: expected a PopulationModel, found {type(model).__name__}")
    T = V.positive_int(horizon, "horizon")
    fl = float(flush)
    if not (fl >= 0 and fl < 1e-3):
        raise ShapeError(f"flush: expected 0 <= flush < 1e-3 (a relative round-off threshold), found {flush!r}")
    from .._resources import check_memory
    from .._resources import progress as _progress

    check_memory(
        24.0 * T * T,  # U and C (T x T), and one T x T triangular inverse for the gains
        f"the exact bulk filter over T = {T} steps (O(T^2) memory)",
        argument="horizon",
        fix="use a shorter horizon or a finite-memory filter (population.memory = n)",
    )
    a, b, c, h, f = model.a, model.b, model.c, model.h, model.f
    N = float(model.n_agents)
    af, bf = a - b * f, b * f
    eps = float(np.finfo(float).eps)
    q, r, p0 = model.q, model.r_v, model.p0
    qm, rm = q / N, r / N
    ch = c + h

    U = np.zeros((T, T))
    Cm = np.zeros((T, T))
    first = np.zeros(T, dtype=np.intp)  # first non-zero column of row t of C (lower triangle)
    g = np.empty(T)
    s = np.empty(T)
    alpha = np.zeros(T)
    beta = np.zeros(T)
    gam = np.zeros(T)
    vx = np.empty(T + 1)
    vxh = np.empty(T + 1)
    sig = np.empty(T + 1)
    vmv = np.empty(T + 1)
    vm, cmt, vmt, Sig, Vh = p0 / N, 0.0, 0.0, p0, 0.0
    vx[0], vxh[0], sig[0], vmv[0] = p0, 0.0, p0, vm
    lo = 0  # alpha, beta, gam vanish before lo
    band = 0
    flops = 0
    with np.errstate(over="ignore", invalid="ignore", under="ignore"), single_thread_blas():
        for k in _progress(range(T), total=T, desc="bulk filter", enabled=progress):
            al = alpha[lo:k]
            be = beta[lo:k]
            mu = a * al - bf * be
            cmtp = a * cmt - bf * vmt  # Cov(m_{k+1}, mtilde_k)
            vm1 = a * a * vm - 2.0 * a * bf * cmt + bf * bf * vmt + qm  # Var m_{k+1}
            Pxx = a * a * Sig + q
            gp = af * gam[lo:k]  # Cov(x_{k+1}, e_t)
            mumu = float(mu @ mu)
            gpmu = float(gp @ mu)
            Pxm = vm1 - gpmu
            Pmm = vm1 - mumu
            s2 = c * c * Pxx + 2.0 * c * h * Pxm + h * h * Pmm + r
            bound = eps * (c * c * abs(Pxx) + 2.0 * abs(c * h) * (abs(vm1) + abs(gpmu)) + h * h * (abs(vm1) + mumu) + r)
            if not (math.isfinite(s2) and s2 > 0 and bound <= PRECISION_FLOOR * s2):
                raise DivergenceError(
                    f"horizon: the exact bulk filter loses its precision at step {k + 1} of {T}: the closed loop is unstable "
                    f"(a = {a:g}, a_f = {af:g}) and the population-mean variance has grown to {vm1:.3g}, so the innovation variance "
                    f"(exactly >= sigma_v^2 = {r:g}) is computed as {s2:.3g} with a round-off of {bound:.2g}; "
                    f"the last reliable horizon is {k}: use horizon <= {k}, or a stabilizing feedback (|a - b f| < 1)",
                    argument="horizon",
                )
            sk = math.sqrt(s2)
            gk = (c * Pxx + h * Pxm) / sk
            Sig = Pxx - gk * gk
            Vh = af * af * Vh + gk * gk
            # u = C[:, lo:k] mu: rows that can be non-zero start at lo2
            if k > lo:
                lo2 = int(first[lo:k].min())
                u = Cm[lo2:k, lo:k] @ mu
            else:
                lo2 = k
                u = np.zeros(0)
            band = max(band, k - lo2)
            flops += 2 * (k - lo2) * (k - lo) + 40 * (k - lo2)
            # new row of C (columns lo2 .. k-1)
            crow = -h * u
            crow[lo - lo2 :] += ch * mu - c * af * be
            crow /= sk
            anew = (ch * vm1 - c * af * cmtp - h * mumu) / sk  # Cov(m_{k+1}, eta_{k+1})
            mube = float(be @ mu)
            bnew0 = (ch * cmtp - c * af * vmt - h * mube) / sk  # Cov(mtilde_k, eta_{k+1})
            cd = (
                ch * ch * vm1
                - 2.0 * ch * c * af * cmtp
                + c * c * af * af * vmt
                + rm
                - 2.0 * h * (ch * mumu - c * af * mube)
                + h * h * float(mu @ u[lo - lo2 :])
            ) / s2
            # updates
            alpha[lo:k] = mu
            alpha[k] = anew
            beta[lo2:k] *= af
            beta[lo2:k] += gk * crow
            beta[k] = af * bnew0 + gk * cd
            cmt = af * cmtp + gk * anew
            vmt = af * af * vmt + 2.0 * af * gk * bnew0 + gk * gk * cd
            vm = vm1
            gam[lo:k] = gp
            gam[k] = gk
            if fl > 0:
                m = abs(cd)
                if crow.size:
                    m = max(m, float(np.max(np.abs(crow))))
                crow[np.abs(crow) < fl * m] = 0.0
            if fl > 0:
                _flush(mu, fl)  # (after its last use) keeps the stored rows free of subnormals
            U[k, lo:k] = mu
            Cm[k, lo2:k] = crow
            Cm[lo2:k, k] = crow
            Cm[k, k] = cd
            first[k] = lo2 + _first_nonzero(crow) if crow.size else k
            g[k] = gk
            s[k] = sk
            vx[k + 1] = Sig + Vh
            vxh[k + 1] = Vh
            sig[k + 1] = Sig
            vmv[k + 1] = vm
            if fl > 0:
                w0 = min(lo, lo2)
                for v in (alpha, beta, gam):
                    _flush(v[w0 : k + 1], fl)
                lo = w0 + min(_first_nonzero(alpha[w0 : k + 1]), _first_nonzero(beta[w0 : k + 1]), _first_nonzero(gam[w0 : k + 1]))
                lo = min(lo, k)
    cov = _covariances(model, vx, vxh, sig, vmv)
    return BulkFilter(model, T, _ro(g), _ro(s), _ro(U), cov, fl, band, flops)


# ---------------------------------------------------------------------------
# finite-memory filters (Theorem 2)
# ---------------------------------------------------------------------------
def _subsystems(model: PopulationModel) -> list[tuple[float, float, float, float]]:
    """(c_j, q_j, r_j, p0_j) of the mean and (for N > 1) the deviation closed loops."""
    N = float(model.n_agents)
    q, r, p0 = model.q, model.r_v, model.p0
    subs = [(model.c + model.h, q / N, r / N, p0 / N)]
    if model.n_agents > 1:
        w = 1.0 - 1.0 / N
        subs.append((model.c, q * w, r * w, p0 * w))
    return subs


def finite_memory_filter(model: PopulationModel, horizon: int, memory: int | None = None, *, progress: bool | None = None) -> FiniteMemoryFilter:
    """The memory-n filter (Theorem 2, eqs. 46-52) and its exact closed loop, for any N.

    Each of the two independent closed loops (population mean, agent's deviation;
    see the module docstring) is finite-dimensional under a memory-n filter: its
    state is (x_k, the last n measurements). Their covariances are propagated
    exactly in O(n^2) per step and added; K^{(n)}_k = P_{x,Y} P_{Y,Y}^{-1} on the
    window by a Cholesky solve (O(n^3) per step). With n >= T this is the exact
    filter.

    Parameters
    ----------
    model : PopulationModel
    horizon : int
        T.
    memory : int, optional
        n >= 1 (default ``model.memory``).
    progress : bool or None
        Progress bar on stderr after 2 s (None: only when stderr is a terminal).

    Returns
    -------
    FiniteMemoryFilter
        When the closed loop is unstable its variances grow geometrically: the
        first step k at which Var x_k exceeds ``DIVERGENCE_RATIO`` =
        PRECISION_FLOOR / eps (4.5e11) times the largest noise variance
        (sigma_w^2, sigma_v^2, sigma_0^2) is recorded in ``diverged_at``, and
        the gains and variances from there on are NaN. The gains solve
        P_YY K = P_xY with covariances that large, so the error variance, of
        the order of the noise, is a difference of numbers 4.5e11 times
        larger: fewer than 4 correct digits are left (checked against exact
        rational arithmetic in the tests). Overflow to inf is caught the same
        way.

    Examples
    --------
    >>> from teamkf.models.population import PopulationModel
    >>> m = PopulationModel(n_agents=10**9, a=2.5, f=2.0)
    >>> finite_memory_filter(m, 200, 3).final_gains().round(4).tolist()  # exact: [.., 0.0039, 0.0584, 0.865]
    [0.0041, 0.0584, 0.865]
    """
    if not isinstance(model, PopulationModel):
        raise ShapeError(f"model: expected a PopulationModel, found {type(model).__name__}")
    T = V.positive_int(horizon, "horizon")
    n = V.positive_int(model.memory if memory is None else memory, "memory")
    from .. import _budget
    from .._resources import progress as _progress

    subs = _subsystems(model)
    _budget.check_memory(
        8.0 * ((len(subs) + 1) * (n + 1.0) ** 2 + (T + 1.0) * (n + 4)),
        f"the finite-memory bulk filter with memory n = {n:,} over T = {T:,} steps ({len(subs)} (n+1) x (n+1) covariances, T x n gains)",
        argument="memory",
        fix="use a smaller memory (the gains of old measurements vanish geometrically; n = 20 is usually exact to round-off)",
    )
    _budget.check_work(
        10.0 * len(subs) * T * (n + 1.0) ** 2,  # a rank-one covariance update of (n+1) x (n+1) per step and subsystem
        f"the finite-memory bulk filter with memory n = {n:,} over T = {T:,} steps",
        argument="memory",
        fix="use a smaller memory or a shorter horizon",
    )
    a, bf = model.a, model.b * model.f
    Ps = []
    for _, _, _, p0j in subs:
        P = np.zeros((n + 1, n + 1))
        P[0, 0] = p0j
        Ps.append(P)
    K = np.zeros((T, n))
    kprev = np.zeros(n)
    vx = np.full(T + 1, np.nan)
    vxh = np.full(T + 1, np.nan)
    sig = np.full(T + 1, np.nan)
    vm = np.full(T + 1, np.nan)
    vx[0], vxh[0], sig[0], vm[0] = model.p0, 0.0, model.p0, model.p0 / model.n_agents
    row = np.empty(n + 1)
    diverged: int | None = None
    limit = DIVERGENCE_RATIO * max(model.q, model.r_v, model.p0)
    with np.errstate(over="ignore", invalid="ignore"), single_thread_blas():
        for k in _progress(range(T), total=T, desc=f"memory-{n} filter", enabled=progress):
            row[0] = a
            row[1:] = -bf * kprev
            for P, (cj, qj, rj, _) in zip(Ps, subs):
                p = P @ row  # Cov(z_k, xi_{k+1} - w_k)
                vxi = float(row @ p) + qj  # Var xi_{k+1}
                # shift the window: o'_i = o_{i+1}, newest o'_n = c_j xi' + v
                P[1:n, 1:n] = P[2:, 2:]
                P[0, 1:n] = P[1:n, 0] = p[2:]
                P[0, 0] = vxi
                P[n, 1:n] = P[1:n, n] = cj * p[2:]
                P[n, 0] = P[0, n] = cj * vxi
                P[n, n] = cj * cj * vxi + rj
            Pt = Ps[0] + Ps[1] if len(Ps) > 1 else Ps[0]
            L = min(k + 1, n)
            sl = slice(n + 1 - L, n + 1)
            Pyy = Pt[sl, sl]
            pxy = Pt[0, sl]
            if not (np.all(np.isfinite(Pyy)) and np.isfinite(Pt[0, 0])) or Pt[0, 0] > limit:
                diverged = k + 1
                K[k:] = np.nan
                break
            try:
                kk = cho_solve(cho_factor(Pyy, lower=True, check_finite=False), pxy, check_finite=False)
            except np.linalg.LinAlgError:
                kk = np.linalg.lstsq(Pyy, pxy, rcond=None)[0]
            K[k, n - L :] = kk
            kprev = K[k]
            e = float(kk @ pxy)
            vx[k + 1] = Pt[0, 0]
            vxh[k + 1] = e
            sig[k + 1] = Pt[0, 0] - e
            vm[k + 1] = Ps[0][0, 0]
    cov = _covariances(model, vx, vxh, sig, vm)
    return FiniteMemoryFilter(model, T, n, _ro(K), cov, diverged)


def bulk_filter(model: PopulationModel, horizon: int) -> BulkFilter | FiniteMemoryFilter:
    """The filter the model asks for: exact (``memory = 0``) or memory-n (Theorem 2)."""
    if not isinstance(model, PopulationModel):
        raise ShapeError(f"model: expected a PopulationModel, found {type(model).__name__}")
    if model.memory == 0:
        return exact_bulk_filter(model, horizon)
    return finite_memory_filter(model, horizon)
