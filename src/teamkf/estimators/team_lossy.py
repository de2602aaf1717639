r"""The drop-aware team filter ``mtmse_lossy`` (alias ``mtmse-lossy``): minimum EXPECTED team MSE over lossy links.

Problem
-------
Links drop each packet independently (edge e: probability p_e; with a jitter bound J_e a packet
also counts as lost when it is late, so it arrives on time with probability
q_e = (1 - p_e)/(J_e + 1)). Minimize the expected team cost

.. math::  J_T = \sum_{k=0}^{T-1} E\big[(Lx(k) - \hat z(k))^\top S\, (Lx(k) - \hat z(k))\big]

over estimates that each agent computes from what actually reached it.

The class (stated; exact within it)
-----------------------------------
Every agent j runs its own Kalman filter on its own measurements (prior 0, Σ_x) and floods one item
u_j(s) per step: its raw measurement y_j(s) (``items="measurements"``, the default for a stable A)
or its filter's innovation ν_j(s) = y_j(s) - C_j x̂_j(s|s-1) (``items="innovations"``, the default
for an unstable A); relays forward every item once, like the MTMSE relays. Agent i's estimate is

.. math::  \hat z_i(k) = L_i \hat x_i(k|k) + \sum_{(j,s) \in \mathcal I_i(k)} G_i(k; j, s)\, f_i(j, s),
           \quad f_i(j, s) = d_i(j, s)\, u_j(s) + (1 - d_i(j, s))\, H_i(j, s)\, u_i(0 : s + \ell_{ji}),      (1)

where 𝓘_i(k) are the items that can have reached i on time by k (s ≤ k - ℓ_ji; the last ``memory``
steps when a memory is set), d_i(j, s) ∈ {0, 1} says whether the item arrived on time
(:mod:`teamkf.estimators._arrivals`; late items are not used), H_i(j, s) is the best linear
predictor of the item from the agent's own items (the fill of a miss; zero with ``fill=False``)
and the gains G_i(k) are chosen offline. u_j(0:s) spans y_j(0:s), so

* at p = 0 (every d = 1) the class is every linear function of the full information of eq. (14):
  its optimum is the MTMSE filter (Theorem 2);
* at p = 1 (only own items) it is every linear function of y_i(0:k): its optimum is the team
  optimum of the own-history structure (``InformationStructure.own_window(n, T)``);
* G = 0 is the local Kalman filter (family ``local``), so the design never costs more than it.

The gains are the best *for the probability* of each miss, not for its realization (they do not
depend on the arrival pattern; only the fill does, through d). Gains that re-weight with the
realized pattern (the missed-packet rule of the nominal design does) are not in the class.

Optimality conditions and algorithm
-----------------------------------
With e_i(k) = x(k) - x̂_i(k|k), the error of agent i is L_i e_i(k) - G_i f_i, and because the link
events are independent of the noises, the expected cost of step k is the quadratic

.. math::  J_k(G) = \operatorname{Tr}(S \bar L P_e \bar L^\top) - 2\langle G, \eta\rangle + \langle G, \Gamma G\rangle,
           \qquad \eta_i = \sum_j S_{ij} L_j E[e_j(k) f_i^\top],
           \qquad \Gamma_{(i,a),(j,b)} = S_{ij}\, E[f_i(a) f_j(b)^\top],

E[f_i(a) f_j(b)ᵀ] = M₁₁∘Σ + M₁₀∘(Σ H_jᵀ) + M₀₁∘(H_i Σ) + M₀₀∘(H_i Σ H_jᵀ), with Σ the covariance of
the items and M₁₁ = E[d_i(a) d_j(b)], M₁₀ = E[d_i(a)(1 - d_j(b))], ... exact (the product of the
marginals plus the corrections of the items whose paths share a link event). It is convex; the
stationarity (Radner) conditions Σ_j S_ij E[(L_j e_j - G_j f_j) f_iᵀ] = 0 are Γ G = η, symmetric
positive definite, and J_k* = Tr(S L̄ P_e L̄ᵀ) - ⟨G, η⟩. The steps decouple because (1) is linear in
the data, not in earlier estimates. The slots (agent, item) are ordered by the step from which they
can be held and E[f fᵀ] does not depend on k, so (constant S, no memory) Γ(k) is the leading block of
Γ(T-1): one Cholesky factorization serves every step.

The covariances come from one forward pass over the stacked local-filter errors
ε(s) = (e_1(s|s-1), …, e_n(s|s-1)), ε(s+1) = A(I - K C) ε(s) - A K v(s) + 1 ⊗ w(s), whose transition
is stable (detectable agents); with innovation items no quantity of the size of x(k) enters
(unstable processes are fine), raw measurements are y = B ν.

Complexity: R = Σ_i Σ_j d_y^j (T - ℓ_ji) slot rows; O(R³/3) once (one factorization), or with
``memory = m`` the windowed form of :mod:`teamkf.estimators._lossy_window` (a factorization per step of the live
items, fills from a window of own items, moments from a lifted recursion of fixed size, gains reused once steady). Sized before anything is allocated
(:mod:`teamkf.estimators._lossy_size`): a design beyond the memory or work limit is refused naming a memory that fits.

Lower bound
-----------
:attr:`LossyTeamDesign.lower_bound` is certified: any strategy over lossy links uses a subset of the
full information plus link events independent of the Gaussian variables, so each stage cost is at
least the MTMSE stage cost of the full information structure (randomization independent of the data
cannot lower a convex quadratic team cost). ``info["gap"]`` is the relative gap to it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from .. import _validation as V
from .._blas import blas_threads
from .._lazy import scipy_linalg as sla  # SciPy loads on first use
from .._linalg import block_diag
from .._validation import FloatArray
from ..exceptions import ArgumentError, ShapeError
from ..models import LinearGaussianSystem, TeamCost
from ..network.graph import CommGraph
from . import _lossy_size
from ._arrivals import ArrivalModel, _jitter_value, _p_value
from ._lossy_bound import KnownRequest, known_pattern_bound, relay_of
from ._lossy_moments import LocalMoments, _item_moments, local_filter_errors, local_filter_moments
from .base import Design, check_paths
from .checks import check_graph, check_model
from .registry import Family, Option, _register_builtin, register_alias

__all__ = ["LossyTeamDesign", "LossyTeamAgent", "design_mtmse_lossy", "local_filter_moments", "known_pattern_bound"]


# ---------------------------------------------------------------------------
# the items each agent may hold, and their joint arrival moments
# ---------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class _Slots:
    """Every (agent i, item (j, s)) of the horizon, ordered by the step k0 = s + ℓ_ji from which it can be held.

    agent, src, step, due : per slot;  rows : per slot-row, the position in ν;  owner : per slot-row, the agent;
    q : per slot-row, P(on time);  H : (rows, N) the fill of each slot-row (its predictor from the agent's own
    innovations ν_i(0 : k0)), applied to the filled vector f = d ν + (1 - d) H ν (:func:`_second_moment`).
    """

    agent: np.ndarray
    src: np.ndarray
    step: np.ndarray
    due: np.ndarray
    row_slot: np.ndarray
    rows: np.ndarray
    owner: np.ndarray
    q: np.ndarray
    H: FloatArray
    arr: ArrivalModel
    Sigma: FloatArray
    fill: bool
    own_rows: list[np.ndarray]


def _slots(system: LinearGaussianSystem, arr: ArrivalModel, Sigma: FloatArray, T: int, fill: bool) -> _Slots:
    n, dyt, off = system.n_agents, system.dy_total, system.offsets
    lst = [
        (s + int(arr.ell[j, i]), i, j, s) for i in range(n) for j in range(n) for s in range(T) if s + arr.ell[j, i] <= T - 1 and arr.prob[j, i] > 0
    ]
    lst.sort()
    due = np.array([x[0] for x in lst], dtype=int)
    agent = np.array([x[1] for x in lst], dtype=int)
    src = np.array([x[2] for x in lst], dtype=int)
    step = np.array([x[3] for x in lst], dtype=int)
    dys = np.array([system.dy[j] for j in src], dtype=int)
    row_slot = np.repeat(np.arange(len(lst)), dys)
    rows = (
        np.concatenate([step[a] * dyt + int(off[src[a]]) + np.arange(dys[a]) for a in range(len(lst))]).astype(int) if lst else np.zeros(0, dtype=int)
    )
    owner = agent[row_slot]
    q = arr.prob[src, agent][row_slot]
    N = Sigma.shape[0]
    H = np.zeros((rows.size, N))
    if fill:
        own_rows = [np.concatenate([s_ * dyt + int(off[i]) + np.arange(system.dy[i]) for s_ in range(T)]).astype(int) for i in range(n)]
        chol = [sla.cholesky(Sigma[np.ix_(o, o)], lower=True) if o.size else None for o in own_rows]
        # H rows of agent i: Σ[o_m, r]ᵀ Σ[o_m, o_m]⁻¹ with o_m its own innovations up to the slot's due step. One
        # forward substitution serves every slot of the agent (the leading block's solve is the leading part of
        # the full one), then one back substitution per group of slots with the same due step.
        for i in range(n):
            Lc = chol[i]
            if Lc is None:
                continue
            here = np.flatnonzero((agent[row_slot] == i) & (src[row_slot] != i))
            if not here.size:
                continue
            o = own_rows[i]
            Z = sla.solve_triangular(Lc, Sigma[np.ix_(o, rows[here])], lower=True, check_finite=False)
            ms = (due[row_slot[here]] + 1) * system.dy[i]  # own innovations ν_i(0 : k0)
            for m in np.unique(ms).tolist():
                g = np.flatnonzero(ms == m)
                Hg = sla.solve_triangular(Lc[:m, :m], Z[:m, g], lower=True, trans="T", check_finite=False)
                H[np.ix_(here[g], o[:m])] = Hg.T
    own_all = [np.concatenate([s_ * dyt + int(off[i]) + np.arange(system.dy[i]) for s_ in range(T)]).astype(int) for i in range(n)]
    return _Slots(agent, src, step, due, row_slot, rows, owner, q, H, arr, Sigma, fill, own_all)


def _second_moment(sl: _Slots, idx: np.ndarray) -> FloatArray:
    """X[idx, idx] with X = E[f f'] over the slot-rows ``idx`` (f = d ν + (1 - d) H ν, exact arrival moments)."""
    arr, Sigma = sl.arr, sl.Sigma
    slots = np.unique(sl.row_slot[idx])
    where = {int(a): t for t, a in enumerate(slots)}
    qs = arr.prob[sl.src[slots], sl.agent[slots]]
    M = np.outer(qs, qs)
    index = {(int(sl.agent[a]), int(sl.src[a]), int(sl.step[a])): t for t, a in enumerate(slots)}
    for t, a in enumerate(slots):
        i, j, s_ = int(sl.agent[a]), int(sl.src[a]), int(sl.step[a])
        M[t, t] = qs[t]  # E[d^2] = E[d]
        if i == j:
            continue
        for (h, l), corr in arr.pairs_from.get((j, i), ()):
            for delta, c in corr.items():
                u = index.get((l, h, s_ + delta))
                if u is not None and u != t:
                    M[t, u] += c
    loc = np.array([where[int(a)] for a in sl.row_slot[idx]], dtype=int)
    M11 = M if np.array_equal(loc, np.arange(len(slots))) else M[np.ix_(loc, loc)]  # one row per slot: no copy
    del M
    rows = sl.rows[idx]
    X = Sigma[np.ix_(rows, rows)]
    if not sl.fill:
        X *= M11
        return 0.5 * (X + X.T)  # type: ignore[no-any-return]
    # E[f_a f_b] = M11 Σ_ab + (q_a - M11) (Σ Hᵀ)_ab + (q_b - M11) (H Σ)_ab + (1 - q_a - q_b + M11) (H Σ Hᵀ)_ab
    #            = M11 (Σ - A - Aᵀ + B)_ab + q_a (Aᵀ - B)_ab + q_b (A - B)_ab + B_ab,   A = H Σ Pᵀ, B = H Σ Hᵀ
    # with the rows of the fill H of agent i acting on its own innovations only (whole-matrix products, in place)
    q = sl.q[idx]
    owners = sl.owner[idx]
    R = idx.size
    HS = np.zeros((R, Sigma.shape[0]))
    Hs = []
    for i, o in enumerate(sl.own_rows):
        b_i = np.flatnonzero(owners == i)
        Hi = sl.H[np.ix_(idx[b_i], o)]
        Hs.append((b_i, o, Hi))
        if b_i.size:
            HS[b_i] = Hi @ Sigma[o]  # H_i Σ
    A = HS[:, rows]  # (H Σ)[a, rows[b]]
    B = np.zeros((R, R))
    for b_l, o, Hl in Hs:
        if b_l.size:
            B[:, b_l] = HS[:, o] @ Hl.T  # H Σ H_lᵀ
    del HS
    blk = max(1, min(R, 2**21 // max(R, 1)))  # rows per block: the block's temporaries stay a few MB
    for r0 in range(0, R, blk):
        rb = slice(r0, min(R, r0 + blk))
        Ab, At, Bb, Xb = A[rb], A[:, rb].T, B[rb], X[rb]
        Xb -= Ab
        Xb -= At
        Xb += Bb
        Xb *= M11[rb]
        Xb += q[rb, None] * (At - Bb)
        Xb += q[None, :] * (Ab - Bb)
        Xb += Bb
    del A, B, M11
    for r0 in range(0, R, blk):  # symmetric part (round-off), block by block: no R x R temporary
        rb = slice(r0, min(R, r0 + blk))
        for c0 in range(r0, R, blk):
            cb = slice(c0, min(R, c0 + blk))
            avg = 0.5 * (X[rb, cb] + X[cb, rb].T)
            X[rb, cb] = avg
            X[cb, rb] = avg.T
    return X


def _dtrtrs(a: FloatArray, b: FloatArray, **kw: Any) -> tuple[FloatArray, int]:
    """LAPACK dtrtrs on the leading ``a.shape[1]`` square block of the Fortran-ordered ``a`` (its leading dimension
    is ``a.shape[0]``: a column slice of a factor is solved with in place, not copied)."""
    from scipy.linalg import lapack

    return lapack.dtrtrs(a, b, lda=a.shape[0], **kw)  # type: ignore[no-any-return]


def _solve_all(
    system: LinearGaussianSystem, cost: TeamCost, arr: ArrivalModel, mom: LocalMoments, T: int, memory: int | None, fill: bool, progress: bool | None
) -> tuple[list[list[list[tuple[int, int]]]], list[list[FloatArray]], list[list[FloatArray]], np.ndarray, np.ndarray]:
    """Gains, fills and stage costs of every step.

    The slots are ordered by the step from which they can be held, and E[f f'] does not depend on k,
    so with a constant S the matrix Γ(k) of step k is the leading n_k × n_k block of Γ(T-1): one
    Cholesky factorization serves every step (its leading block is the factor of Γ(k)).
    """
    from .._resources import progress as _progress

    n, dz = system.n_agents, cost.dz
    sl = _slots(system, arr, mom.Sigma, T, fill)
    R = sl.rows.size
    zidx = (sl.owner[:, None] * dz + np.arange(dz)[None, :]).ravel()  # unknown (row, z component) -> row of S
    rr = np.repeat(np.arange(R), dz)
    const_S = not cost.is_time_varying
    chol = None
    stages, locs = np.zeros(T), np.zeros(T)
    gains: list[list[FloatArray]] = []
    fills: list[list[FloatArray]] = []
    items: list[list[list[tuple[int, int]]]] = []
    for k in _progress(range(T), total=T, desc="mtmse_lossy design", enabled=progress):
        S, L = cost.S_at(k), cost.L_at(k)
        Lb = block_diag(*[L[i * dz : (i + 1) * dz] for i in range(n)])
        c0 = float(np.trace(S @ Lb @ mom.Pe[k] @ Lb.T))
        live_rows = np.flatnonzero(sl.due[sl.row_slot] <= k)
        if memory is not None:
            live_rows = live_rows[sl.step[sl.row_slot[live_rows]] >= k - memory + 1]
        u = (live_rows[:, None] * dz + np.arange(dz)[None, :]).ravel()  # unknowns of step k
        W = S @ Lb @ mom.Theta[k]  # (n dz, N_k): row block i is Σ_j S_ij L_j Θ_j
        cols = sl.rows[live_rows]
        V1 = W[:, cols]
        # V2 = W Hᵀ over the live rows; the fill of agent i's rows acts on its own innovations ν_i(0:k) only
        owner_live = sl.owner[live_rows]
        mines = [np.flatnonzero(owner_live == i) for i in range(n)]
        owns = [_own_cols(system, i, k) for i in range(n)]
        Fk_all = [sl.H[np.ix_(live_rows[mines[i]], owns[i])] for i in range(n)]
        V2 = np.zeros((W.shape[0], live_rows.size))
        for i in range(n):
            if mines[i].size:
                V2[:, mines[i]] = W[:, owns[i]] @ Fk_all[i].T
        zr = zidx[u]
        rk = rr[u]
        qk = sl.q[rk]
        pos = np.searchsorted(live_rows, rk)
        eta = qk * V1[zr, pos] + (1.0 - qk) * V2[zr, pos]
        if u.size:
            prefix = memory is None and const_S
            if prefix and chol is None:
                G_all = _second_moment(sl, np.arange(R))
                if dz == 1:  # in place: the largest array of the design is formed once
                    for a in range(n):
                        ra = np.flatnonzero(sl.owner == a)
                        G_all[ra] *= S[a][sl.owner][None, :]
                else:
                    G_all = G_all[np.ix_(rr, rr)] * S[np.ix_(zidx, zidx)]
                # Γ is symmetric: its transpose is the same matrix in Fortran order, factored in place (no copy)
                chol = np.asfortranarray(sla.cholesky(G_all.T, lower=True, check_finite=False, overwrite_a=True))
                del G_all
            if prefix:
                # the leading u x u block of the factor, read in place (leading dimension R): two triangular solves
                Lk = chol[:, : u.size]  # type: ignore[index]
                z, info = _dtrtrs(Lk, eta[:, None], lower=1, trans=0)
                g, info2 = _dtrtrs(Lk, z, lower=1, trans=1, overwrite_b=1)
                if info or info2:  # pragma: no cover - a positive definite factor has a nonzero diagonal
                    raise np.linalg.LinAlgError(f"mtmse_lossy: triangular solve failed at step {k} (info {info or info2})")
                g = g[:, 0]
            else:
                Gk = _second_moment(sl, live_rows)[np.ix_(pos, pos)] * S[np.ix_(zr, zr)]
                g = sla.cho_solve(sla.cho_factor(Gk, lower=True, check_finite=False), eta, check_finite=False)
        else:
            g = np.zeros(0)
        stages[k] = c0 - float(g @ eta)
        locs[k] = c0
        Gk_list, Fk_list, Ik_list = [], [], []
        for i in range(n):
            mine = mines[i]
            slots_i = list(dict.fromkeys(sl.row_slot[live_rows[mine]].tolist()))
            Ik_list.append([(int(sl.src[a]), int(sl.step[a])) for a in slots_i])
            gi = g.reshape(-1, dz)[mine].T if u.size else np.zeros((dz, 0))
            Gk_list.append(gi)
            Fk_list.append(Fk_all[i])
        gains.append(Gk_list)
        fills.append(Fk_list)
        items.append(Ik_list)
    return items, gains, fills, stages, locs


def _own_cols(system: LinearGaussianSystem, i: int, k: int) -> np.ndarray:
    """Positions in ν of agent i's own innovations ν_i(0:k) (the columns its fills act on at step k)."""
    return _rows(system, [(i, s) for s in range(k + 1)])


def _rows(system: LinearGaussianSystem, items: Sequence[tuple[int, int]]) -> np.ndarray:
    """Positions of the items' entries in the stacked ν = (ν(0), ..., ν(T-1))."""
    dyt, off = system.dy_total, system.offsets
    parts = [s * dyt + int(off[j]) + np.arange(system.dy[j]) for (j, s) in items]
    return np.concatenate(parts).astype(int) if parts else np.zeros(0, dtype=int)


# ---------------------------------------------------------------------------
# the design
# ---------------------------------------------------------------------------
@dataclass(frozen=True, eq=False, kw_only=True)
class LossyTeamDesign(Design):
    """The drop-aware team filter (1) with its exact expected cost (module docstring).

    Attributes
    ----------
    graph : CommGraph
    p_drop, jitter : the link model it is designed for (a number, or {(a, b): value})
    memory : int or None      innovations older than this many steps are not used (None: all)
    arrivals : ArrivalModel   the on-time probabilities it uses
    items : per step, per agent, the items (j, s) of 𝓘_i(k)
    gains : per step, per agent, G_i(k) of shape (d_z, Σ d_y^j over 𝓘_i(k))
    K_local : per step, per agent, the local Kalman gains
    lower_bound_stages : (T,) certified lower bound of every stage cost (MTMSE, full information)
    local_stages : (T,) stage costs of the local Kalman filters (G = 0)
    """

    graph: CommGraph
    p_drop: Any
    jitter: Any
    memory: int | None
    coordinates: str
    arrivals: ArrivalModel = field(repr=False)
    items: tuple[tuple[tuple[tuple[int, int], ...], ...], ...] = field(repr=False)
    gains: tuple[tuple[FloatArray, ...], ...] = field(repr=False)
    fills: tuple[tuple[FloatArray, ...], ...] = field(repr=False)
    K_local: tuple[tuple[FloatArray, ...], ...] = field(repr=False)
    lower_bound_stages: FloatArray = field(repr=False)
    local_stages: FloatArray = field(repr=False)

    @property
    def lower_bound(self) -> float:
        """Certified lower bound of the expected total cost of ANY strategy on these lossy links."""
        return float(np.sum(self.lower_bound_stages))

    @property
    def gap(self) -> float:
        """(J_T - lower bound) / lower bound."""
        return (float(self.total_cost or 0.0) - self.lower_bound) / self.lower_bound

    @property
    def tolerates_losses(self) -> bool:
        return True

    @property
    def cost_link_model(self) -> dict[str, Any]:
        """The links its exact expected cost is under: ``{"p_drop", "jitter"}`` (a number, or {(a, b): value})."""
        return {"p_drop": self.p_drop, "jitter": self.jitter}

    # --- Monte Carlo ---------------------------------------------------------------------
    def _error_inputs(self, paths: Any, p_drop: Any, jitter: Any, rng: Any, arrived: Any) -> tuple[FloatArray, FloatArray, FloatArray, Any]:
        """x(0), w and v (n_runs, T', Σ d_y) of ``paths``, and the on-time events (given, sampled, or all True), checked."""
        check_paths(paths, self.system)
        x0 = np.asarray(paths.x, dtype=float)[:, 0]
        w = np.asarray(paths.w, dtype=float)
        v = np.concatenate([np.asarray(vi, dtype=float) for vi in paths.v], axis=2)
        n_runs, T = v.shape[:2]
        if self.horizon is not None and T > self.horizon:
            raise ShapeError(f"paths: expected at most horizon = {self.horizon} steps, found {T}")
        n = self.system.n_agents
        if arrived is None:
            if p_drop is None:
                arrived = np.ones((n_runs, T, n, n), dtype=bool)
            else:
                arr = ArrivalModel.build(self.graph, p_drop, 0 if jitter is None else jitter)
                arrived = arr.sample(n_runs, T, np.random.default_rng(rng))
        arrived = np.asarray(arrived, dtype=bool)
        if arrived.shape != (n_runs, T, n, n):
            raise ShapeError(f"arrived: expected shape {(n_runs, T, n, n)}, found {arrived.shape}")
        return x0, w, v, arrived

    def errors(self, paths: Any, *, p_drop: Any = None, jitter: Any = None, rng: Any = None, arrived: Any = None) -> FloatArray:
        """Team errors e(k) = L x(k) - ẑ(k), (n_runs, T', n d_z), with sampled link events.

        By default every item arrives (reliable links, as the lossless Monte Carlo assumes); give
        ``p_drop`` (and ``jitter``) with ``rng`` to sample on-time events per edge and step
        (:meth:`ArrivalModel.sample`), or ``arrived`` (n_runs, T', n, n) booleans d_i(j, s) directly.
        Vectorized over runs: the local filters' errors are propagated from the primitive noises and
        the estimate (1) is a batched product with the arrival-masked innovations.
        """
        x0, w, v, arrived = self._error_inputs(paths, p_drop, jitter, rng, arrived)
        sysm, cost = self.system, self.cost
        n_runs, T = v.shape[:2]
        n, dx, dz, dyt = sysm.n_agents, sysm.dx, cost.dz, sysm.dy_total
        off = sysm.offsets
        nu = np.zeros((n_runs, T * dyt))
        yv = np.concatenate([np.asarray(yi, dtype=float) for yi in paths.y], axis=2).reshape(n_runs, -1) if self.coordinates == "measurements" else nu
        mask = np.zeros((n_runs, T * dyt, n))  # mask[:, row, i] = d_i(source of row, step of row)
        for s in range(T):
            for j in range(n):
                rr = slice(s * dyt + int(off[j]), s * dyt + int(off[j]) + sysm.dy[j])
                mask[:, rr, :] = arrived[:, s, j, :][:, None, :]
        out = np.empty((n_runs, T, n * dz))
        for k, nu_k, ef in local_filter_errors(sysm, self.K_local, x0, w, v):
            nu[:, k * dyt : (k + 1) * dyt] = nu_k
            L = cost.L_at(k)
            for i in range(n):
                rows = _rows(sysm, self.items[k][i])
                z = ef[:, i * dx : (i + 1) * dx] @ L[i * dz : (i + 1) * dz].T
                if rows.size:
                    own = _own_cols(sysm, i, k)
                    own = own[own.size - self.fills[k][i].shape[1] :]  # the fills act on the last w own items
                    m = mask[:, rows, i]
                    vals = nu if self.coordinates == "innovations" else yv
                    f = vals[:, rows] * m + (1.0 - m) * (vals[:, own] @ self.fills[k][i].T)  # the fill of a missed item
                    z = z - f @ self.gains[k][i].T
                out[:, k, i * dz : (i + 1) * dz] = z
        return out

    # --- online agents -------------------------------------------------------------------
    def graph_agents(self) -> list[Any]:
        """One agent per node: its own Kalman filter, flooding of innovations, the estimate (1) on what arrived on time."""
        return [LossyTeamAgent(self, i) for i in range(self.n_agents)]

    @property
    def delivery_graph(self) -> CommGraph | None:
        return self.graph

    def agent_slice(self, i: int) -> tuple[str, dict[str, np.ndarray], dict[str, Any]]:
        """Agent i's arrays (rebuilt by :mod:`teamkf.estimators._lossy_slice`): ``ell`` (ℓ_ji for every j), and per step
        k ``K/k`` (its local Kalman gain), ``items/k`` ((source, step) rows), ``G/k`` (gains), ``F/k`` (fills)."""
        T = int(self.horizon or 0)  # a drop-aware design always has a horizon
        arrays: dict[str, np.ndarray] = {"ell": np.asarray(self.arrivals.ell, dtype=np.int64)[:, i].copy()}
        for k in range(T):
            arrays[f"K/{k}"] = np.asarray(self.K_local[k][i])
            arrays[f"items/{k}"] = np.asarray(self.items[k][i], dtype=np.int64).reshape(-1, 2)
            arrays[f"G/{k}"] = np.asarray(self.gains[k][i])
            arrays[f"F/{k}"] = np.asarray(self.fills[k][i])
        return "lossy", arrays, {"horizon": T, "coordinates": str(self.coordinates), "memory": self.memory}

    # --- what the CLI writes ---------------------------------------------------------------
    def details(self) -> dict[str, Any]:
        return {
            "p_drop": self.p_drop if not isinstance(self.p_drop, dict) else {f"{a}->{b}": v for (a, b), v in self.p_drop.items()},
            "jitter": self.jitter if not isinstance(self.jitter, dict) else {f"{a}->{b}": v for (a, b), v in self.jitter.items()},
            "memory": self.memory,
            "lower_bound": self.lower_bound,
            "gap": self.gap,
            **{key: self.info[key] for key in ("known_pattern_bound", "known_pattern_gap") if key in self.info},
            "local_kf_cost": float(np.sum(self.local_stages)),
            "items": self.coordinates,
            "class": f"gains per step on the on-time {self.coordinates} (pattern-independent), missed ones filled from the agent's own",
        }

    def arrays(self) -> dict[str, np.ndarray]:
        """Costs, the bound, the on-time probabilities ``q_arrival`` [j, i], and per step k and agent i the gains
        ``G_{i}_t{k}`` with their items ``items_{i}_t{k}`` ((source, step) rows) and the local gains ``K_{i}_t{k}``."""
        out = {
            **super().arrays(),
            "lower_bound_stages": np.asarray(self.lower_bound_stages),
            "local_stages": np.asarray(self.local_stages),
            "q_arrival": np.asarray(self.arrivals.prob),
        }
        for k, step in enumerate(self.gains):
            for i, G in enumerate(step):
                out[f"G_{i}_t{k}"] = np.asarray(G)
                out[f"items_{i}_t{k}"] = np.asarray(self.items[k][i], dtype=np.int64).reshape(-1, 2)
                out[f"K_{i}_t{k}"] = np.asarray(self.K_local[k][i])
        return out


class LossyTeamAgent:
    """Agent i of a :class:`LossyTeamDesign` on the message-passing runtime (any links).

    Runs its own Kalman filter, floods ν_i(k) and every item it learns for the first time (payload:
    list of (j, s, ν_j(s))), records when each item arrived, and outputs (1) using the items that
    arrived on time (at s + ℓ_ji). It never needs a message, so lost and late packets are fine.
    """

    def __init__(self, design: LossyTeamDesign, index: int):
        self.design = design
        self.index = index
        self.system = design.system

    def init_state(self, n_runs: int) -> dict[str, Any]:
        return {"xhat": np.zeros((n_runs, self.system.dx)), "items": {}, "n_runs": n_runs}

    def step(self, state: dict[str, Any], k: int, own: Any, inbox: Sequence[Any]) -> tuple[dict[str, Any], FloatArray, list[Any]]:
        d, i, sysm = self.design, self.index, self.system
        xhat = state["xhat"] if k == 0 else state["xhat"] @ sysm.A_at(k - 1).T
        y = np.asarray(own, dtype=float)
        nu = y - xhat @ sysm.C_at(i, k).T
        xhat = xhat + nu @ d.K_local[k][i].T
        items = dict(state["items"])
        new = []
        mine = y if d.coordinates == "measurements" else nu  # the item this agent floods
        for j, s, val in [(i, k, mine), *[p for (_, _, payload) in inbox for p in payload]]:
            if (j, s) not in items:
                on_time = k == s + int(d.arrivals.ell[j, i])
                items[(j, s)] = np.asarray(val) if on_time else None  # late items are kept out of (1)
                new.append((j, s, val))
        z = xhat @ d.cost.L_block(i, k).T
        its = d.items[k][i]
        if its:
            w = d.fills[k][i].shape[1] // sysm.dy[i] if sysm.dy[i] else k + 1  # the fills act on the last w own items
            nu_own = np.hstack([items[(i, s)] for s in range(k + 1 - w, k + 1)])
            fill = nu_own @ d.fills[k][i].T  # the predictions of every item from the own innovations
            parts, col = [], 0
            for j, s in its:
                dj = sysm.dy[j]
                val = items.get((j, s))
                parts.append(fill[:, col : col + dj] if val is None else val)
                col += dj
            z = z + np.hstack(parts) @ d.gains[k][i].T
        return {"xhat": xhat, "items": items, "n_runs": state["n_runs"]}, z, new


# ---------------------------------------------------------------------------
# entry point
# ---------------------------------------------------------------------------
# the other classes: modules of their own that extend this one (never imported here), registered by the loader (_builtin.EXTENSIONS)
_KEYED: list[Any] = []  #: ``keyed=1``, registered by :mod:`teamkf.estimators._lossy_keyed`
register_keyed = _KEYED.append
_RESEND: list[Any] = []  #: ``resend=r``, registered by :mod:`teamkf.estimators._lossy_resend`
register_resend = _RESEND.append
_ADAPTIVE: list[Any] = []  #: ``adaptive=true`` on top of ``resend=r``, registered by :mod:`teamkf.estimators._lossy_adaptive`
register_adaptive = _ADAPTIVE.append
_HELD: list[Any] = []  #: ``fill="held"`` (the class containing the rule), registered by :mod:`teamkf.estimators._lossy_rulefill`
register_held = _HELD.append
_SUMMARY: list[Any] = []  #: ``summary=M`` (age-keyed filter summaries), registered by :mod:`teamkf.estimators._lossy_summary`
register_summary = _SUMMARY.append


def design_mtmse_lossy(
    system: LinearGaussianSystem,
    cost: TeamCost,
    graph: CommGraph,
    horizon: int | None = None,
    *,
    p_drop: Any = None,
    jitter: Any = 0,
    memory: int | None = None,
    items: str = "auto",
    fill: bool | str = True,
    patterns: int | None = None,
    held_window: int | None = None,
    bound: bool = True,
    known_bound: int = 0,
    known_window: int | None = None,
    known_knowledge: str = "every",
    keyed: int = 0,
    resend: int = 1,
    adaptive: bool = False,
    summary: int = 0,
    threads: int | None = 1,
    progress: bool | None = None,
) -> LossyTeamDesign:
    """Design the drop-aware team filter for links that drop packets with probability ``p_drop``.

    Parameters
    ----------
    system, cost : the model and the team cost (S, L)
    graph : CommGraph
        The links (delays); items are flooded over it.
    horizon : int
        T (finite horizon only).
    p_drop : float in [0, 1] or {(source, target): p}
        Drop probability of every packet (or per edge). A scenario gives its ``[network] p_drop``;
        None means reliable links (0: the design is then the MTMSE filter).
    jitter : int >= 0 or {(source, target): J}
        A packet late by 1..J steps counts as lost (its item is not used): on-time probability (1 - p)/(J + 1).
    memory : int or None
        Use only the items of the last ``memory`` steps, missed ones filled from the agent's own items of a window, with
        a steady form for long horizons (:mod:`teamkf.estimators._lossy_window`; exact cost); None: all, the full class.
    items : "auto", "measurements" or "innovations"
        What the agents flood and the gains act on: the raw measurements y_j(s), or the innovations
        ν_j(s) of the sender's own Kalman filter. Both give MTMSE at p = 0 and the own-history optimum
        at p = 1; in between they are different classes (a missed raw measurement is predicted well
        from the agent's own ones when the agents measure alike). "auto": by exact cost where both kinds
        stay bounded and the design is cheap — both are designed and the lower exact expected cost is kept
        (``info["items_costs"]`` has both) — when the growth of A over the horizon, ρ(A)^(2T), is at most
        :data:`AUTO_GROWTH` and the estimated work at most :data:`AUTO_WORK` flops; otherwise measurements
        when every A(k) is stable (spectral radius < 1), else innovations (bounded second moments on
        unstable processes).
    fill : bool or "held"
        Replace a missed item by its predictor from the agent's own innovations (else by zero, its mean). "held": the
        class containing the nominal design under the missed-packet rule, today's class and the local filters
        (:mod:`teamkf.estimators._lossy_rulefill`; never worse than any of them; ``patterns``: link patterns sampled
        for the fit and as many fresh ones for the cost, None: all of them when few, else 400; ``held_window``: its window W).
    threads : int or None
        BLAS threads for the design (1: robust on a shared machine; None: the library's default).
    bound : bool
        Also compute the certified lower bound (the MTMSE stage costs of the full information).
    known_bound : int
        Also compute the known-pattern optimum (:func:`known_pattern_bound`: the team told every drop; relays
        flooding raw measurements for ``items="measurements"``, relaying everything held otherwise) over this
        many sampled patterns, or every pattern when there are at most ``EXACT_LIMIT``; 0: not computed.
        ``info["known_pattern_bound"]`` (value, sem, interval) and ``info["known_pattern_gap"]``.
    known_window : int or None
        Its window (data older than k - W given to every agent: a looser bound, less work); None: W = ℓ_max + 4.
    known_knowledge : "every" or "causal"
        What that bound's agents are told of the link events: every one, or only those due before the step and their own
        arrivals of the step (all that any protocol can tell an agent: a tighter bound, still below every design;
        no jitter). Recorded in ``info["known_pattern_bound"]["knowledge"]``.
    keyed : 0 or 1
        1: gains keyed on the agent's current arrivals (the on-time indicators of the items due at step k;
        :mod:`teamkf.estimators._lossy_keyed`): a larger class containing today's, exact cost, small teams only
        (no ``memory``). 0: gains independent of the arrival pattern.
    resend : int >= 1
        r: every packet carries the sender's last r items, so a lost item can arrive in a later packet
        (:mod:`teamkf.estimators._lossy_resend`: exact cost; no ``memory``, no ``keyed``). 1: one item per packet.
    adaptive : bool
        True: on top of ``resend = r`` (raw measurements), gains also on each agent's exact conditional means of the recent
        states given what it holds, re-weighted with the realized pattern (:mod:`teamkf.estimators._lossy_adaptive`: cost sampled
        over ``patterns`` link patterns, paired with the re-sending design's exact cost).
    summary : int >= 0
        M >= 1: the class of :mod:`teamkf.estimators._lossy_summary` instead: every agent sends its own filter estimate each
        step, and gains keyed on the age (< M) of each in-neighbour's newest one (exact cost; long horizons by a steady form).

    Returns
    -------
    LossyTeamDesign
        ``stage_costs``/``total_cost`` exact expected costs, ``lower_bound``, ``gap``.

    Examples
    --------
    >>> from teamkf import LinearGaussianSystem, TeamCost, CommGraph
    >>> sys, cost, g = LinearGaussianSystem.platoon(4), TeamCost.platoon(4, 10.0), CommGraph.line(4)
    >>> d0 = design_mtmse_lossy(sys, cost, g, 8, p_drop=0.0)
    >>> d5 = design_mtmse_lossy(sys, cost, g, 8, p_drop=0.5)
    >>> d0.lower_bound <= d0.total_cost <= d5.total_cost <= d5.info["local_kf_cost"]
    True
    """
    check_model(system, cost)
    check_graph(graph, system.n_agents)
    if horizon is None:
        raise ArgumentError(
            "horizon: the drop-aware design is finite-horizon only (its gains act on every past innovation); give horizon = T",
            argument="horizon",
        )
    T = V.positive_int(horizon, "horizon")
    system.require_horizon(T)
    cost.require_horizon(T)
    if p_drop is None:  # a scenario fills it from its [network] table; plain calls: reliable links (= MTMSE)
        p_drop = 0.0
    p = _p_value(p_drop, "p_drop")
    J = _jitter_value(jitter, "jitter")
    mem = None if memory is None else V.positive_int(memory, "memory")
    coords = V.choice(items, "items", ("auto", "measurements", "innovations"))
    arr = ArrivalModel.build(graph, p, J)
    known = KnownRequest.build(system, cost, graph, T, p, J, arr, known_bound, known_window, known_knowledge)  # checked before any work
    if summary:  # age-keyed filter summaries: a class of its own, sized and checked by its own module
        if not _SUMMARY:
            from .registry import families

            families()  # loads the built-in modules and their extensions (_builtin.EXTENSIONS)
        others = (keyed, memory, resend, fill, items, held_window)
        return _SUMMARY[-1](system, cost, graph, T, p, J, arr, summary, bound, threads, others=others, known=known)  # type: ignore[no-any-return]

    def kinds(m: int | None) -> int:  # item kinds designed with memory m (``items="auto"`` may design both)
        return len(_auto_items(system, arr, T, m)) if coords == "auto" else 1

    rs = V.integer(resend, "resend", minimum=1, maximum=16, what="the items per packet r (1: one item per packet)")
    _lossy_size.check(system, arr, T, mem, cost.dz, prefix=mem is None and not cost.is_time_varying, kinds=kinds, resend=rs)  # before any work
    kw = V.integer(keyed, "keyed", minimum=0, maximum=1, what="the window w (0: gains independent of the pattern, 1: keyed on the current arrivals)")
    candidates = _auto_items(system, arr, T, mem) if coords == "auto" else (coords,)
    fill = _lossy_size.check_fill(fill, "fill")
    ad = _lossy_size._flag(adaptive, "adaptive")
    if (fill == "held" and not _HELD) or (kw and not _KEYED) or ((rs > 1 or ad) and not (_RESEND and _ADAPTIVE)):  # modules of their own
        from .registry import families

        families()  # loads the built-in modules and their extensions (_builtin.EXTENSIONS), which register here
    if ad and (fill == "held" or held_window is not None):
        raise ArgumentError('adaptive: a class of its own over re-sending relays, found fill = "held"; drop one of them', argument="adaptive")
    if rs > 1 or ad:  # re-sent items (and the pattern-adaptive features on top)
        d = _RESEND[-1](system, cost, graph, T, p, J, arr, candidates, rs, fill, bound, threads, keyed=kw, memory=mem)
        if ad:
            d = _ADAPTIVE[-1](d, patterns=patterns, threads=threads)
        return known.attach(d, *relay_of(d.coordinates, rs))
    if fill == "held":  # the class containing the missed-packet rule (raw measurements, relayed once)
        with blas_threads(threads):  # the same bits wherever it is designed (a deployment's agents and its replay)
            d = _HELD[-1](system, cost, graph, T, p, J, arr, patterns=patterns, keyed=kw, memory=mem, window=held_window)
        return known.attach(d, "flood")
    if held_window is not None:
        raise ArgumentError(
            f'held_window: the window of fill = "held", found fill = {fill!r}; drop held_window or set fill = "held"', argument="held_window"
        )
    if kw:  # gains keyed on the current arrivals
        d = _KEYED[-1](system, cost, graph, T, p, J, arr, candidates, mem, fill, bound, threads)
        return known.attach(d, *relay_of(d.coordinates))
    with blas_threads(threads):
        if mem is not None:  # windowed fills, a lifted moment recursion and a steady form: memory independent of T
            from . import _lossy_window

            tried: dict[str, Any] = {c: _lossy_window.solve(system, cost, arr, T, mem, bool(fill), c, progress) for c in candidates}
        else:
            mom0 = local_filter_moments(system, T)
            tried = {
                c: (*_solve_all(system, cost, arr, _item_moments(system, mom0, T, c), T, mem, bool(fill), progress), mom0.K, {}) for c in candidates
            }
    coords = min(candidates, key=lambda c: float(np.sum(tried[c][3])))  # the lower exact expected cost (ties: the first)
    held, gains, fills, stage, local, K_loc, extra = tried[coords]
    d = build_lossy_design(
        LossyTeamDesign,
        system,
        cost,
        graph,
        T,
        p=p,
        J=J,
        memory=mem,
        coords=coords,
        arr=arr,
        items=held if isinstance(held, tuple) else tuple(tuple(tuple(it) for it in step) for step in held),  # windowed: built lazily
        gains=gains,
        fills=fills,
        K_local=K_loc,
        stage=stage,
        local=local,
        bound=bound,
        items_costs={c: float(np.sum(tried[c][3])) for c in candidates},
        info_tail=extra,
    )
    return known.attach(d, *relay_of(coords))


#: ``items="auto"`` designs both kinds only while raw measurements stay bounded: ρ(A)^(2T) at most this
AUTO_GROWTH = 1e8
#: ... and while the estimated work of one design (flops of its factorizations) is at most this
AUTO_WORK = 2e9


def build_lossy_design(
    cls: Any,
    system: LinearGaussianSystem,
    cost: TeamCost,
    graph: CommGraph,
    T: int,
    *,
    p: Any,
    J: Any,
    memory: int | None,
    coords: str,
    arr: ArrivalModel,
    items: Any,
    gains: Any,
    fills: Any,
    K_local: Any,
    stage: FloatArray,
    local: FloatArray,
    bound: bool,
    items_costs: dict[str, float],
    info_mid: dict[str, Any] | None = None,
    info_tail: dict[str, Any] | None = None,
    **fields: Any,
) -> Any:
    """The design object of every form of ``mtmse_lossy`` (``cls``: :class:`LossyTeamDesign` or a subclass, whose extra
    ``fields`` are passed on), with its certified lower bound (the MTMSE stage costs of the full information, never
    above the design's own) when ``bound``, and its ``info``: the link model, the memory, the item kind, ``info_mid``,
    both item kinds' costs, the local filters' cost, ``info_tail``, the lower bound and the gap."""
    if bound:
        from .registry import get_family  # the registered MTMSE family (families do not import each other)

        nominal = get_family("mtmse").build(system, cost, graph=graph, structure=graph, horizon=T)
        lb = np.minimum(np.asarray(nominal.stage_costs, dtype=float), stage)  # equal at p = 0 up to round-off
    else:
        lb = np.full(T, np.nan)
    info = {"p_drop": p, "jitter": J, "memory": memory, "items": coords, **(info_mid or {})}
    info.update({"items_costs": items_costs, "local_kf_cost": float(np.sum(local)), **(info_tail or {})})
    d = cls(
        estimator="mtmse_lossy",
        horizon=T,
        system=system,
        cost=cost,
        stage_costs=stage,
        info=info,
        graph=graph,
        p_drop=p,
        jitter=J,
        memory=memory,
        coordinates=coords,
        arrivals=arr,
        items=items,
        gains=tuple(tuple(step) for step in gains),
        fills=tuple(tuple(step) for step in fills),
        K_local=tuple(tuple(K) for K in K_local),
        lower_bound_stages=lb,
        local_stages=local,
        **fields,
    )
    d.info["lower_bound"] = d.lower_bound
    d.info["gap"] = d.gap
    return d


def _auto_items(system: LinearGaussianSystem, arr: ArrivalModel, T: int, memory: int | None) -> tuple[str, ...]:
    """The item kinds ``items="auto"`` designs: both when raw measurements stay bounded and it is cheap, else the rule."""
    steps = range(T) if system.is_time_varying else range(1)
    rho = max(float(np.max(np.abs(np.linalg.eigvals(system.A_at(k))))) for k in steps)
    rule = ("measurements",) if rho < 1.0 else ("innovations",)
    if 2 * T * np.log10(max(rho, 1e-300)) > np.log10(AUTO_GROWTH):
        return rule
    dy = [system.C_at(j, 0).shape[0] for j in range(system.n_agents)]
    n = system.n_agents
    if memory is None:  # one factorization of R = Σ_i Σ_j d_y^j (T − ℓ_ji) slot rows
        rows = sum(dy[j] * max(T - int(arr.ell[j, i]), 0) for i in range(n) for j in range(n))
        work = rows**3 / 3.0
    else:  # one factorization per step of size n m Σ_j d_y^j
        work = T * (n * memory * sum(dy)) ** 3 / 3.0
    return ("measurements", "innovations") if work <= AUTO_WORK else rule


def _check_p(v: Any, key: str) -> Any:
    return None if v is None else _p_value(v, key)


def _check_memory(v: Any, key: str) -> Any:
    return None if v is None else V.positive_int(v, key)


FAMILY = _register_builtin(
    Family(
        name="mtmse_lossy",
        design=design_mtmse_lossy,
        title="drop-aware team filter: minimum expected team MSE for links that drop packets with a known probability (exact cost, certified bound)",
        uses="graph",
        horizons=frozenset({"finite"}),
        analytic_cost=True,
        lossy_links=True,  # capabilities (registry.Family): its agents run over links that drop
        strongly_connected=True,
        options=(
            Option(name="p_drop", default=None, check=_check_p, doc="drop probability (default: the scenario's [network] p_drop)"),
            Option(name="jitter", default=0, check=lambda v, k: _jitter_value(v, k), doc="late packets (by up to J steps) count as lost"),
            Option(name="memory", default=None, check=_check_memory, doc="use the items of the last m steps only (none: all)"),
            Option(
                name="known_bound",
                default=0,
                check=lambda v, k: V.integer(v, k, minimum=0),
                doc="also compute the known-pattern optimum over this many sampled drop patterns (0: not)",
            ),
            Option(name="known_window", default=None, check=_check_memory, doc="its window W (none: the largest geodesic delay + 4)"),
            Option(
                name="known_knowledge",
                default="every",
                check=lambda v, k: V.choice(v, k, ("every", "causal")),
                doc="what the bound's agents are told: every link event, or the causal ones (all any protocol can tell)",
            ),
            *_lossy_size.fill_options(),  # fill (and patterns, for fill = "held")
            *_lossy_size.form_options(),  # keyed, resend, summary
            Option(
                name="items",
                default="auto",
                check=lambda v, k: V.choice(v, k, ("auto", "measurements", "innovations")),
                doc="what agents flood: raw measurements or their own filter's innovations (auto: measurements for a stable A)",
            ),
        ),
        example="design_mtmse_lossy(system, cost, graph, horizon=50, p_drop=0.2)",
    )
)
register_alias("mtmse-lossy", "mtmse_lossy")
