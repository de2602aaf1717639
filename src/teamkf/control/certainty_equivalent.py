"""Certainty-equivalent control u = -f xhat of interference-coupled populations.

Reference: Abedinpour Fallah, Malhamé, Saussié, Martinelli (GERAD G-2017-04),
Sections 3.1 and 4; model :class:`~teamkf.models.population.PopulationModel`.

Contents
--------
* The naive observer-based controller (eq. 5) with a constant gain K and its
  stability region S(a) in the (K, a_f) plane (both the population-mean and
  the deviation closed loops must be Schur), the thresholds a_m(a_f), a_m and
  a_s (Fig. 1).
* The exact average LQ cost (eq. 3 over a horizon) of the bulk or memory-n
  filter, from the exact closed-loop covariances.
* Batched closed-loop simulation of N explicit agents (run axis first,
  per-run seeds from :func:`teamkf.simulation.sampling.run_streams`).
* :func:`map_points`: the serial loop over grid points used by the studies
  (the sweep engine can run the same pure per-point functions on Dask).

The naive controller's two closed loops (docs/bulk.md, "S(a)")
--------------------------------------------------------------
With xhat_{k+1} = a_f xhat_k + K (y_{k+1} - c a_f xhat_k) in every agent, the
population mean (m, mtilde) and each agent's deviation (d, dhat) evolve as::

    mean:       [[a, -(a - a_f)], [K (c + h) a, a_f - K (c + h)(a - a_f) - K c a_f]]
    deviation:  [[a, -(a - a_f)], [K c a,       a_f - K c a]]

(noise aside; b f = a - a_f). The deviation matrix has eigenvalues a_f and
a (1 - K c) (separation); the mean matrix has trace
a (1 - K c) + a_f - K h (a - a_f) and determinant a a_f (1 - K c). S(a) is
the set of (K, a_f) where both are Schur; it does not depend on N or b.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Iterable, TypeVar, cast

import numpy as np
from numpy.typing import ArrayLike

from .. import _validation as V
from .._validation import FloatArray
from ..estimators.bulk import (
    BulkFilter,
    FiniteMemoryFilter,
    bulk_filter,
    isolated_kalman_gain,
)
from ..exceptions import ShapeError
from ..models.population import PopulationModel
from ..simulation.sampling import run_streams

__all__ = [
    "naive_closed_loop",
    "naive_spectral_radii",
    "in_stability_region",
    "stability_region_mask",
    "a_m_of_af",
    "a_m",
    "a_s",
    "lq_cost",
    "PopulationSimulation",
    "simulate_population",
    "map_points",
    "MAX_EXPLICIT_AGENTS",
]

#: largest population simulated agent by agent (exact statistics for any N come from the filters)
MAX_EXPLICIT_AGENTS = 10**7
#: largest n_agents x horizon of an explicit simulation (2 GiB of filter history)
MAX_HISTORY_DOUBLES = 2**28
#: doubles of filter history a simulation step should touch per chunk of runs (~ a last-level cache)
CACHE_DOUBLES = 2**21
#: doubles of noise drawn ahead per chunk (each run's (w_k, v_{k+1}) for a block of steps)
NOISE_BLOCK_DOUBLES = 2**20

P = TypeVar("P")
R = TypeVar("R")


def map_points(func: Callable[[P], R], points: Iterable[P]) -> list[R]:
    """Apply a pure, picklable per-point function to every grid point, in order.

    Serial by default; inside ``teamkf.simulation.parallel.use_scheduler(...)``
    (``teamkf reproduce NAME --scheduler local``) the points run on Dask workers.
    """
    from ..simulation.parallel import map_points as _map

    return _map(func, points)


# ---------------------------------------------------------------------------
# the naive observer-based controller (eq. 5): S(a), a_m, a_s
# ---------------------------------------------------------------------------
def naive_closed_loop(a: float, K: float, a_f: float, *, c: float = 1.0, h: float = 1.0) -> tuple[FloatArray, FloatArray]:
    """The 2 x 2 closed-loop matrices (mean, deviation) of the naive controller, states (x, xhat).

    Examples
    --------
    >>> Am, Ad = naive_closed_loop(2.0, 0.8, 0.5)
    >>> sorted(np.round(np.linalg.eigvals(Ad).real, 6).tolist())
    [0.4, 0.5]
    """
    bf = a - a_f
    Am = np.array([[a, -bf], [K * (c + h) * a, a_f - K * (c + h) * bf - K * c * a_f]])
    Ad = np.array([[a, -bf], [K * c * a, a_f - K * c * bf - K * c * a_f]])
    return Am, Ad


def _radius(tr: np.ndarray, det: np.ndarray) -> np.ndarray:
    disc = np.asarray(tr * tr - 4.0 * det, dtype=complex)
    sq = np.sqrt(disc)
    return np.maximum(np.abs((tr + sq) / 2.0), np.abs((tr - sq) / 2.0))  # type: ignore[no-any-return]


def naive_spectral_radii(a: ArrayLike, K: ArrayLike, a_f: ArrayLike, *, c: float = 1.0, h: float = 1.0) -> tuple[FloatArray, FloatArray]:
    """Spectral radii (mean loop, deviation loop) of the naive controller; broadcasts over arrays."""
    a_, K_, af = np.broadcast_arrays(np.asarray(a, dtype=float), np.asarray(K, dtype=float), np.asarray(a_f, dtype=float))
    tr_m = a_ * (1.0 - K_ * c) + af - K_ * h * (a_ - af)
    det_m = a_ * af * (1.0 - K_ * c)
    rho_m = _radius(tr_m, det_m)
    rho_d = np.maximum(np.abs(af), np.abs(a_ * (1.0 - K_ * c)))
    return rho_m, rho_d


def in_stability_region(a: ArrayLike, K: ArrayLike, a_f: ArrayLike, *, c: float = 1.0, h: float = 1.0) -> Any:
    """True where (K, a_f) is in S(a): both naive closed loops Schur (spectral radius < 1)."""
    rm, rd = naive_spectral_radii(a, K, a_f, c=c, h=h)
    out = (rm < 1.0) & (rd < 1.0)
    return bool(out) if out.ndim == 0 else out


def stability_region_mask(a: float, K_values: ArrayLike, af_values: ArrayLike, *, c: float = 1.0, h: float = 1.0) -> FloatArray:
    """S(a) on a grid: boolean array of shape (len(af_values), len(K_values)) (Fig. 1)."""
    Kv = np.asarray(K_values, dtype=float)
    Av = np.asarray(af_values, dtype=float)
    return in_stability_region(a, Kv[None, :], Av[:, None], c=c, h=h)  # type: ignore[no-any-return]


def a_m_of_af(
    a_f: float, *, c: float = 1.0, h: float = 1.0, sigma_w: float = 1.0, sigma_v: float = 1.0, grid_step: float = 1e-3, tol: float = 1e-10
) -> float:
    """a_m(a_f): the largest a with (K*(a), a_f) in S(a) (Section 3.1, Table 1's last column).

    Scans a in [0, a_s] with step ``grid_step`` and refines the upper end of the
    last stable stretch by bisection to ``tol``. Returns NaN when no a >= 0
    qualifies (e.g. a_f near 1 is unstable already at a = 0 when
    a_f (1 + K*(0) h) >= 1).

    Examples
    --------
    >>> round(a_m_of_af(0.5), 3), round(a_m_of_af(0.99), 3)
    (2.736, 3.667)
    """
    af = float(a_f)
    amax = a_s(c=c, h=h) + 1.0

    def ok(a: float) -> bool:
        K = isolated_kalman_gain(a, c=c, sigma_w=sigma_w, sigma_v=sigma_v)
        return bool(in_stability_region(a, K, af, c=c, h=h))

    grid = np.arange(0.0, amax + grid_step, grid_step)
    Ks = np.array([isolated_kalman_gain(x, c=c, sigma_w=sigma_w, sigma_v=sigma_v) for x in grid])
    inside = np.asarray(in_stability_region(grid, Ks, af, c=c, h=h))
    if not inside.any():
        return float("nan")
    j = int(np.flatnonzero(inside)[-1])
    if j == grid.size - 1:  # pragma: no cover - S(a) is empty past a_s
        return float(grid[-1])
    lo, hi = float(grid[j]), float(grid[j + 1])
    while hi - lo > tol:
        mid = 0.5 * (lo + hi)
        if ok(mid):
            lo = mid
        else:
            hi = mid
    return lo


def a_m(*, c: float = 1.0, h: float = 1.0, sigma_w: float = 1.0, sigma_v: float = 1.0, af_limit: float = 1.0 - 1e-9) -> float:
    """a_m = sup over a_f in [0, 1) of a_m(a_f): a_m(a_f) increases with a_f, so this is a_m(a_f -> 1).

    Examples
    --------
    >>> round(a_m(), 3)
    3.686
    """
    return a_m_of_af(af_limit, c=c, h=h, sigma_w=sigma_w, sigma_v=sigma_v)


def a_s(*, c: float = 1.0, h: float = 1.0) -> float:
    """a_s: past it no constant (K, a_f) stabilizes, S(a) is empty (Section 3.1).

    In the corner a (1 - K c) -> 1, a_f -> 1 the binding Jury condition of the
    mean loop, 1 + tr + det > 0, reads (a - 1)^2 / a < 4 c / h, so
    ``a_s = 1 + 2 kappa + 2 sqrt(kappa^2 + kappa)``, kappa = c / h
    (3 + 2 sqrt 2 ~ 5.83 for c = h; infinite for h = 0). S(a) is an open set that
    shrinks into that corner as a -> a_s.

    Examples
    --------
    >>> round(a_s(), 4)
    5.8284
    """
    if h <= 0:
        return float("inf")
    kap = c / h
    return 1.0 + 2.0 * kap + 2.0 * math.sqrt(kap * kap + kap)


# ---------------------------------------------------------------------------
# LQ cost of the bulk / memory-n closed loop
# ---------------------------------------------------------------------------
def lq_cost(model: PopulationModel, horizon: int, *, filt: BulkFilter | FiniteMemoryFilter | None = None) -> float:
    """Exact average LQ cost per agent, (1/T) sum_{k<T} E[x_k^2 + r u_k^2] (eq. 3 over T steps).

    Uses the exact closed-loop covariances of the filter ``model.memory`` asks
    for (or of ``filt``); valid for any N (nothing is simulated).

    Examples
    --------
    >>> round(lq_cost(PopulationModel(n_agents=10**9, a=2.0, f=1.6), 400), 2)
    15.3
    """
    T = V.positive_int(horizon, "horizon")
    f = filt if filt is not None else bulk_filter(model, T)
    if f.horizon < T:
        raise ShapeError(f"filt: expected a filter over at least horizon = {T} steps, found {f.horizon}")
    cov = f.covariances
    m2 = cov.state_mean[:T] ** 2
    return float(np.mean(cov.state_variance[:T] + m2 + model.r * model.f**2 * (cov.estimate_variance[:T] + m2)))


# ---------------------------------------------------------------------------
# explicit N-agent simulation
# ---------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class PopulationSimulation:
    """Closed-loop runs of N explicit agents (run axis first).

    Attributes
    ----------
    n_runs, n_agents, horizon : int
    final_states : (n_runs, n_agents)
        x_{T,i}.
    lq_cost : (n_runs,)
        (1/(N T)) sum_i sum_{k<T} (x_{k,i}^2 + r u_{k,i}^2), per run.
    second_moment : (n_runs, T + 1)
        (1/N) sum_i x_{k,i}^2.
    mean_state : (n_runs, T + 1)
        m_k = (1/N) sum_i x_{k,i}.
    states, estimates : (n_runs, T + 1, n_agents) or None
        Kept only with ``keep_states=True``.
    """

    n_runs: int
    n_agents: int
    horizon: int
    final_states: FloatArray
    lq_cost: FloatArray
    second_moment: FloatArray
    mean_state: FloatArray
    states: FloatArray | None = None
    estimates: FloatArray | None = None

    def max_abs_final(self, saturate: float = 1000.0) -> FloatArray:
        """``max_i |x_{T,i}|`` per run, saturated (non-finite values count as ``saturate``; Fig. 12)."""
        with np.errstate(invalid="ignore"):
            m = np.max(np.abs(self.final_states), axis=1)
        m = np.where(np.isfinite(m), m, saturate)
        return np.minimum(m, saturate)  # type: ignore[no-any-return]


def _mu_windows(mu: np.ndarray) -> np.ndarray:
    nz = mu != 0
    any_nz = nz.any(axis=1)
    first = np.where(any_nz, np.argmax(nz, axis=1), np.arange(mu.shape[0]))
    return first  # type: ignore[no-any-return]


def simulate_population(
    model: PopulationModel,
    horizon: int,
    *,
    n_runs: int = 1,
    rng: int | np.random.SeedSequence | np.random.Generator | None = None,
    filt: BulkFilter | FiniteMemoryFilter | None = None,
    keep_states: bool = False,
    max_chunk_doubles: int = 2**25,
) -> PopulationSimulation:
    """Simulate N = ``model.n_agents`` explicit agents in closed loop for T steps, ``n_runs`` times.

    Every agent runs the same filter (exact bulk filter in innovation form, or
    the memory-n filter) on its own measurements and applies u = -f xhat.
    Run r draws x_0, then (w_k, v_{k+1}) for k = 0..T-1, from its own stream
    ``run_streams(rng, n_runs)[r]``, so a run gives the same numbers alone or in
    a batch.

    Parameters
    ----------
    model : PopulationModel
        N <= MAX_EXPLICIT_AGENTS.
    horizon : int
        T.
    n_runs : int
    rng : seed, SeedSequence or Generator (keyword)
    filt : BulkFilter or FiniteMemoryFilter, optional
        Precomputed filter for ``model`` over >= T steps (default: computed).
    keep_states : bool
        Keep the (n_runs, T + 1, N) states and estimates.
    max_chunk_doubles : int
        Runs are processed in chunks whose filter memory (T x N x runs) stays
        below this many doubles.

    Returns
    -------
    PopulationSimulation

    Notes
    -----
    The exact filter costs O(N x band) per step (band = number of non-zero
    past coefficients of the mean predictor); N = 10^4, T = 1000 takes a few
    seconds (benchmarks/bench_bulk.py).
    """
    if not isinstance(model, PopulationModel):
        raise ShapeError(f"model: expected a PopulationModel, found {type(model).__name__}")
    T = V.positive_int(horizon, "horizon")
    R_ = V.positive_int(n_runs, "n_runs")
    N = model.n_agents
    if N > MAX_EXPLICIT_AGENTS:
        raise ShapeError(
            f"model.n_agents: expected at most {MAX_EXPLICIT_AGENTS} agents for an explicit simulation, found {N}; "
            "the exact statistics for any N come from teamkf.estimators.bulk.bulk_filter(model, T).covariances"
        )
    if N * T > MAX_HISTORY_DOUBLES:
        raise ShapeError(
            f"model.n_agents, horizon: expected n_agents x horizon <= {MAX_HISTORY_DOUBLES} (the filter keeps T values per agent), "
            f"found {N} x {T}; simulate fewer agents or a shorter horizon"
        )
    f_ = filt if filt is not None else bulk_filter(model, T)
    if f_.horizon < T:
        raise ShapeError(f"filt: expected a filter over at least horizon = {T} steps, found {f_.horizon}")
    if f_.model.with_(memory=0) != model.with_(memory=0):
        raise ShapeError(f"filt: expected a filter computed for this model, found one for {f_.model}; pass filt=None to compute it")
    exact = isinstance(f_, BulkFilter)
    a, b, c, h, fb = model.a, model.b, model.c, model.h, model.f
    af = model.a_f
    with np.errstate(under="ignore", over="ignore"):
        Ex = model.x0_mean * af ** np.arange(T + 1, dtype=float)
    Ey = (c + h) * Ex
    streams = run_streams(rng, R_)
    # runs per chunk: the filter history of a chunk must fit in memory, and the part every step reads
    # (band x N per run) should stay in cache from one step to the next
    if exact:
        bfil = cast(BulkFilter, f_)
        mu = np.asarray(bfil.mu)
        lo_row = _mu_windows(mu[:T, :T])
        g, s = bfil.g, bfil.s
        band = int(np.max(np.arange(T) - lo_row))
    else:
        mfil = cast(FiniteMemoryFilter, f_)
        Kf = np.asarray(mfil.K)
        n = mfil.memory
        band = n
    chunk = max(1, min(R_, int(max_chunk_doubles) // max(1, N * T), CACHE_DOUBLES // max(1, band * N)))
    final = np.empty((R_, N))
    cost = np.empty(R_)
    m2 = np.empty((R_, T + 1))
    mean = np.empty((R_, T + 1))
    states = np.empty((R_, T + 1, N)) if keep_states else None
    ests = np.empty((R_, T + 1, N)) if keep_states else None
    r_w = model.r
    with np.errstate(over="ignore", invalid="ignore"):
        for r0 in range(0, R_, chunk):
            r1 = min(R_, r0 + chunk)
            gens = [np.random.default_rng(st) for st in streams[r0:r1]]
            Rc = r1 - r0
            x = model.x0_mean + model.sigma_0 * np.stack([gn.standard_normal(N) for gn in gens])
            xh = np.full((Rc, N), model.x0_mean)
            acc = np.zeros(Rc)
            m2[r0:r1, 0] = np.mean(x * x, axis=1)
            mean[r0:r1, 0] = np.mean(x, axis=1)
            if states is not None and ests is not None:
                states[r0:r1, 0] = x
                ests[r0:r1, 0] = xh
            # innovations (exact filter) or centred measurements (memory n), per run; every run is
            # processed with arrays of its own shape, so its numbers do not depend on the batching
            hist = np.zeros((Rc, T, N))
            xc = np.zeros((Rc, N))
            # each run's noises (w_k, v_{k+1}) for a block of steps in one draw from its stream: the same numbers
            # as one (2, N) draw per step (a Generator fills an array in order)
            block = max(1, min(T, NOISE_BLOCK_DOUBLES // max(1, 2 * N * Rc)))
            zb = np.empty((Rc, block, 2, N))
            for k in range(T):
                if k % block == 0:
                    nb = min(block, T - k)
                    for j, gn in enumerate(gens):
                        zb[j, :nb] = gn.standard_normal((nb, 2, N))
                z = zb[:, k % block]
                u = -fb * xh
                acc += np.mean(x * x + r_w * u * u, axis=1)
                x = a * x + b * u + model.sigma_w * z[:, 0]
                mk = np.mean(x, axis=1)
                y = c * x + h * mk[:, None] + model.sigma_v * z[:, 1]
                yc = y - Ey[k + 1]
                if exact:
                    lo = int(lo_row[k])
                    if k > lo:
                        # one (band,) @ (band, N) product per run, as one stacked matmul (the same BLAS gemv per run)
                        pred = np.matmul(mu[k, lo:k], hist[:, lo:k])
                        e = (yc - c * af * xc - h * pred) / s[k]
                    else:
                        e = (yc - c * af * xc) / s[k]
                    hist[:, k] = e
                    xc = af * xc + g[k] * e
                else:
                    hist[:, k] = yc
                    L = min(k + 1, n)
                    xc = np.matmul(Kf[k, n - L :], hist[:, k + 1 - L : k + 1])
                xh = Ex[k + 1] + xc
                m2[r0:r1, k + 1] = np.mean(x * x, axis=1)
                mean[r0:r1, k + 1] = mk
                if states is not None and ests is not None:
                    states[r0:r1, k + 1] = x
                    ests[r0:r1, k + 1] = xh
            final[r0:r1] = x
            cost[r0:r1] = acc / T
    return PopulationSimulation(R_, N, T, final, cost, m2, mean, states, ests)
