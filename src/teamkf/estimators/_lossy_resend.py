r"""Re-sent items for the drop-aware design (``mtmse_lossy`` with ``resend = r``).

The protocol
------------
Agent j's packet of step τ carries its last r items u_j(τ - r + 1 : τ) (not only u_j(τ)); relays flood
every packet once, when they first learn it, as with ``resend = 1`` (the packet of origin (j, τ) plays the
part of today's item ν_j(τ)). A packet is *on time* at agent i when it arrives at τ + ℓ_ji, which happens
with the indicator d_i(j, τ) of :mod:`teamkf.estimators._arrivals` (an OR over geodesic paths of ANDs of
edge-step events). Item (j, s) is therefore *available* at agent i by step k when some packet that carries
it arrived on time by k:

.. math::  a_i(j, s; k) = \bigvee_{\tau = s}^{\min(s + r - 1,\; k - \ell_{ji})} d_i(j, \tau),

again an OR of ANDs of independent edge-step events (the paths of the packets of τ = s..s + c - 1, shifted),
so its probability and every joint probability of two of them are exact by inclusion–exclusion over those
paths (:func:`_union`). A missed item is lost for good only when all r packets that carry it are lost.

The class (stated; exact within it)
-----------------------------------
As ``resend = 1`` (:mod:`teamkf.estimators.team_lossy`, eq. (1)), with the availability in place of the
on-time indicator:

.. math::  \hat z_i(k) = L_i \hat x_i(k|k) + \sum_{(j,s) \in \mathcal I_i(k)} G_i(k; j, s)\, f_i(j, s; k), \qquad
           f_i(j, s; k) = a_i(j, s; k)\, u_j(s) + (1 - a_i(j, s; k))\, H_i(j, s)\, u_i(0 : s + \ell_{ji}),

H_i the fill of today's class (fixed offline), G_i(k) chosen offline. ``resend = 1`` is today's class; the
fill and gains of r are allowed for every r' ≥ r with a ≥ today's indicator, and at p = 0 and p = 1 the
class is today's (MTMSE, the own-history optimum).

Optimality conditions and algorithm
-----------------------------------
The stage cost is the convex quadratic of today's class with Γ(k), η(k) built from the moments of a(·; k):
q_a(k) = P(a_a(k) = 1) and M₁₁(k) = E[a_a(k) a_b(k)] (E[f_a f_bᵀ] = M₁₁ Σ + (q_a − M₁₁) Σ H_bᵀ + (q_b − M₁₁) H_a Σ
+ (1 − q_a − q_b + M₁₁) H_a Σ H_bᵀ), and Γ(k) g = η(k) are its Radner conditions; J_k* = c₀(k) − η(k)ᵀ g.
An item's availability stops changing once every packet carrying it is due: at its *settle step*
σ = s + ℓ_ji + r − 1. Ordering the slots by σ, the slots settled at k form a prefix whose moments are those
of the final availabilities: with a constant S their block Γ_SS(k) is the leading block of one matrix, and one
Cholesky factorization serves every step. The at most r − 1 unsettled slots per (source, agent) pair,
U(k) = {due ≤ k < σ}, enter by a Schur complement: W = L_SS⁻¹ Γ_SU(k), L_U L_Uᵀ = Γ_UU(k) − WᵀW,
z₁ = L_SS⁻¹ η_S, z₂ = L_U⁻¹ (η_U − Wᵀ z₁), J_k* = c₀ − |z₁|² − |z₂|². (A time-varying S: a factorization
of the live Γ(k) per step.)
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from .._lazy import scipy_linalg as sla
from .._linalg import block_diag
from ..exceptions import ArgumentError
from ._arrivals import ArrivalModel, _union_prob
from ._lossy_moments import local_filter_errors

__all__ = ["MAX_RESEND", "design_resend", "availability_prob"]

#: at most this many items per packet (r)
MAX_RESEND = 16
#: inclusion–exclusion over at most this many paths (2^paths terms); above it the events are enumerated
_MAX_PATHS = 14
#: the events are enumerated when there are at most this many (2^events assignments)
_MAX_EVENTS = 16

Event = tuple[int, int]


_BITS: dict[int, np.ndarray] = {}


def _union(paths: list[frozenset[Event]], q: np.ndarray) -> float:
    """P(some path has all its events succeed), independent events of probability q[edge] (exact).

    Every assignment of the distinct events is enumerated (vectorized) when there are at most
    :data:`_MAX_EVENTS` of them, else inclusion–exclusion over at most :data:`_MAX_PATHS` paths.
    """
    if not paths:
        return 0.0
    if any(len(p) == 0 for p in paths):
        return 1.0
    uniq = list(dict.fromkeys(paths))
    paths = [p for p in uniq if not any(o < p for o in uniq)]  # absorption: a path containing another adds nothing
    events = sorted({ev for p in paths for ev in p})
    m = len(events)
    if sum(len(p) for p in paths) == m:  # paths with disjoint events: independent
        return 1.0 - float(np.prod([1.0 - float(np.prod([q[e] for (e, _) in p])) for p in paths]))
    if m > _MAX_EVENTS:
        if len(paths) <= _MAX_PATHS:
            return _union_prob(paths, q)
        raise ArgumentError(
            f"resend: the availability of an item is an OR of {len(paths)} paths over {m} link events, more than the "
            f"exact computation takes ({_MAX_PATHS} paths or {_MAX_EVENTS} events); use a smaller resend or a graph with fewer geodesics",
            argument="resend",
        )
    bits = _BITS.get(m)
    if bits is None:
        bits = _BITS[m] = ((np.arange(1 << m)[:, None] >> np.arange(m)[None, :]) & 1).astype(bool)
    pos = {ev: t for t, ev in enumerate(events)}
    qs = np.array([q[e] for (e, _) in events])
    w = np.prod(np.where(bits, qs, 1.0 - qs), axis=1)
    ok = np.zeros(1 << m, dtype=bool)
    for p in paths:
        ok |= bits[:, [pos[ev] for ev in p]].all(axis=1)
    return float(w[ok].sum())


def _shifted(arr: ArrivalModel, j: int, i: int, s: int, c: int) -> list[frozenset[Event]]:
    """The paths of the packets of origin τ = s..s + c - 1 from j to i, at absolute steps."""
    return [frozenset((e, s + t + o) for (e, o) in p) for t in range(c) for p in arr.paths[(j, i)]]


class _Avail:
    """Exact moments of the availabilities a_i(j, s; k), cached by their time-invariant keys."""

    def __init__(self, arr: ArrivalModel, r: int):
        self.arr, self.r = arr, r
        self._q: dict[tuple[int, int, int], float] = {}
        self._c: dict[tuple[int, int, int, int, int, int, int], float] = {}
        n = arr.n_agents
        span = int(arr.ell.max()) if arr.ell.size else 0
        ev = {(j, i): {e for p in arr.paths[(j, i)] for (e, _) in p} for j in range(n) for i in range(n) if j != i}
        #: (j, i) -> [((h, l), lo, hi)]: the pairs whose paths share an edge with (j, i)'s, and the shifts s_b - s_a to try
        self.dep: dict[tuple[int, int], list[tuple[tuple[int, int], int, int]]] = {}
        for ka, ea in ev.items():
            for kb, eb in ev.items():
                if ea & eb:
                    self.dep.setdefault(ka, []).append((kb, -span - r + 1, span + r - 1))

    def q(self, j: int, i: int, c: int) -> float:
        if j == i:
            return 1.0
        key = (j, i, c)
        v = self._q.get(key)
        if v is None:
            v = self._q[key] = _union(_shifted(self.arr, j, i, 0, c), self.arr.q)
        return v

    def corr(self, ka: tuple[int, int], ca: int, kb: tuple[int, int], cb: int, delta: int) -> float:
        """E[a_a a_b] - q_a q_b for a = (ka, s, ca copies), b = (kb, s + delta, cb copies)."""
        key = (*ka, ca, *kb, cb, delta)
        v = self._c.get(key)
        if v is None:
            pa = _shifted(self.arr, ka[0], ka[1], 0, ca)
            pb = _shifted(self.arr, kb[0], kb[1], delta, cb)
            if {x for p in pa for x in p} & {x for p in pb for x in p}:
                qa, qb = self.q(*ka, ca), self.q(*kb, cb)
                v = qa + qb - _union(pa + pb, self.arr.q) - qa * qb
            else:
                v = 0.0
            self._c[key] = v
        return v


def availability_prob(arr: ArrivalModel, r: int, j: int, i: int, copies: int | None = None) -> float:
    """P(a_i(j, s; k) = 1) with ``copies`` = min(r, k - s - ℓ_ji + 1) packets counted (default r)."""
    return _Avail(arr, r).q(j, i, r if copies is None else copies)


# ---------------------------------------------------------------------------
# the moments of the filled items
# ---------------------------------------------------------------------------
class _Moments:
    """E[f_a f_bᵀ] over blocks of slot-rows, for given copies counted per row (exact)."""

    def __init__(self, sl: Any, av: _Avail, agent: np.ndarray, src: np.ndarray, step: np.ndarray):
        self.sl, self.av = sl, av
        self.agent, self.src, self.step = agent, src, step  # per row
        self.Sigma = sl.Sigma
        self.HS = sl.H @ sl.Sigma if sl.fill else None  # (rows, N): H Σ
        self.owner = sl.owner
        self.index: dict[tuple[int, int, int], list[int]] = {}
        for t, key in enumerate(zip(agent.tolist(), src.tolist(), step.tolist())):
            self.index.setdefault(key, []).append(t)

    def qrow(self, rows: np.ndarray, copies: np.ndarray) -> np.ndarray:
        return np.array([self.av.q(int(self.src[a]), int(self.agent[a]), int(c)) for a, c in zip(rows.tolist(), copies.tolist())])

    def m11(self, Ia: np.ndarray, ca: np.ndarray, Ib: np.ndarray, cb: np.ndarray) -> np.ndarray:
        qa, qb = self.qrow(Ia, ca), self.qrow(Ib, cb)
        M = np.outer(qa, qb)
        posb: dict[int, list[int]] = {}
        for t, b in enumerate(Ib.tolist()):
            posb.setdefault(b, []).append(t)
        cbd = dict(zip(Ib.tolist(), cb.tolist()))
        for t, (a, c_a) in enumerate(zip(Ia.tolist(), ca.tolist())):
            i, j, s = int(self.agent[a]), int(self.src[a]), int(self.step[a])
            if i == j:
                continue
            for (h, l), lo, hi in self.av.dep.get((j, i), ()):
                for delta in range(lo, hi + 1):
                    for b in self.index.get((l, h, s + delta), ()):
                        us = posb.get(b)
                        if not us:
                            continue
                        if b == a:  # the item with itself: E[a²] = E[a]
                            for u in us:
                                M[t, u] = qa[t]
                            continue
                        cval = self.av.corr((j, i), int(c_a), (h, l), int(cbd[b]), delta)
                        if cval:
                            for u in us:
                                M[t, u] += cval
        return M

    def block(self, Ia: np.ndarray, ca: np.ndarray, Ib: np.ndarray, cb: np.ndarray) -> np.ndarray:
        """X[Ia, Ib] = E[f_a f_bᵀ] (rows of the slot table)."""
        sl = self.sl
        M = self.m11(Ia, ca, Ib, cb)
        ra, rb = sl.rows[Ia], sl.rows[Ib]
        X = self.Sigma[np.ix_(ra, rb)]
        if self.HS is None:
            return M * X  # type: ignore[no-any-return]
        qa, qb = self.qrow(Ia, ca), self.qrow(Ib, cb)
        A = self.HS[np.ix_(Ia, rb)]  # E[(H_a u) u_b]
        At = self.HS[np.ix_(Ib, ra)].T  # E[u_a (H_b u)]
        B = np.zeros((Ia.size, Ib.size))
        ob = self.owner[Ib]
        for o_l, own in enumerate(sl.own_rows):
            sel = np.flatnonzero(ob == o_l)
            if sel.size:
                B[:, sel] = self.HS[np.ix_(Ia, own)] @ sl.H[np.ix_(Ib[sel], own)].T
        return M * (X - A - At + B) + qa[:, None] * (At - B) + qb[None, :] * (A - B) + B  # type: ignore[no-any-return]


def solve_resend(
    system: Any, cost: Any, arr: ArrivalModel, mom: Any, T: int, fill: bool, r: int, *, schur: bool = True
) -> tuple[list[Any], list[Any], list[Any], np.ndarray, np.ndarray]:
    """Items, gains, fills, stage costs and local-filter stage costs of every step (module docstring)."""
    from .team_lossy import _own_cols, _slots

    n, dz = system.n_agents, cost.dz
    sl0 = _slots(system, arr, mom.Sigma, T, fill)
    # slots re-ordered by their settle step σ = due + r - 1 (own items: due)
    sig0 = np.where(sl0.agent == sl0.src, sl0.due, sl0.due + r - 1)
    perm = np.lexsort((sl0.step, sl0.src, sl0.agent, sl0.due, sig0))
    rank = np.empty_like(perm)
    rank[perm] = np.arange(perm.size)
    row_perm = np.argsort(rank[sl0.row_slot], kind="stable")
    sl = _Reordered(sl0, perm, rank, row_perm)
    R = sl.rows.size
    agent, src, step, due = sl.agent[sl.row_slot], sl.src[sl.row_slot], sl.step[sl.row_slot], sl.due[sl.row_slot]
    sig = np.where(agent == src, due, due + r - 1)
    av = _Avail(arr, r)
    mm = _Moments(sl, av, agent, src, step)
    zidx = (sl.owner[:, None] * dz + np.arange(dz)[None, :]).ravel()
    rr = np.repeat(np.arange(R), dz)
    const_S = not cost.is_time_varying
    use_schur = schur and const_S
    chol = None
    if use_schur:
        settled = np.flatnonzero(sig <= T - 1)  # a prefix (the order is by σ)
        nS_all = settled.size
        S0 = cost.S_at(0)
        G_SS = np.empty((nS_all * dz, nS_all * dz))
        full_c = np.full(nS_all, r)
        blk = max(1, min(max(nS_all, 1), 2**21 // max(nS_all, 1)))
        for r0 in range(0, nS_all, blk):
            ia = settled[r0 : r0 + blk]
            X = mm.block(ia, full_c[: ia.size], settled, full_c)
            ua = (ia[:, None] * dz + np.arange(dz)[None, :]).ravel()
            G_SS[r0 * dz : (r0 + ia.size) * dz] = (
                X[np.ix_(np.repeat(np.arange(ia.size), dz), rr[: nS_all * dz])] * S0[np.ix_(zidx[ua], zidx[: nS_all * dz])]
            )
        # symmetric up to round-off: its transpose is the same matrix in Fortran order, factored in place (no copy)
        chol = np.asfortranarray(sla.cholesky(G_SS.T, lower=True, check_finite=False, overwrite_a=True)) if nS_all else None
        del G_SS
    stages, locs = np.zeros(T), np.zeros(T)
    gains: list[list[Any]] = []
    fills: list[list[Any]] = []
    items: list[list[Any]] = []
    for k in range(T):
        S, L = cost.S_at(k), cost.L_at(k)
        Lb = block_diag(*[L[i * dz : (i + 1) * dz] for i in range(n)])
        c0 = float(np.trace(S @ Lb @ mom.Pe[k] @ Lb.T))
        live = np.flatnonzero(due <= k)
        copies = np.where(agent[live] == src[live], 1, np.minimum(r, k - due[live] + 1))
        if use_schur:
            nS = int(np.searchsorted(sig, k, side="right"))
            order = np.concatenate([np.arange(nS), live[sig[live] > k]])  # settled prefix, then the unsettled
            copies = np.concatenate([np.where(agent[:nS] == src[:nS], 1, r), np.minimum(r, k - due[order[nS:]] + 1)])
        else:
            nS, order = 0, live
        q = mm.qrow(order, copies)
        # η: q (S L̄ Θ)[., rows] + (1 - q) (S L̄ Θ) Hᵀ
        Wk = S @ Lb @ mom.Theta[k]
        V1 = Wk[:, sl.rows[order]]
        V2 = np.zeros_like(V1)
        if fill:
            for i in range(n):
                mine = np.flatnonzero(sl.owner[order] == i)
                if mine.size:
                    own = _own_cols(system, i, k)
                    V2[:, mine] = Wk[:, own] @ sl.H[np.ix_(order[mine], own)].T
        u_rows = np.repeat(np.arange(order.size), dz)
        zr = zidx[(order[:, None] * dz + np.arange(dz)[None, :]).ravel()]
        eta = q[u_rows] * V1[zr, u_rows] + (1.0 - q[u_rows]) * V2[zr, u_rows]
        nu_ = order.size * dz
        if nu_ == 0:
            g = np.zeros(0)
            val = 0.0
        elif use_schur:
            mS = nS * dz
            Uo = order[nS:]
            cU = copies[nS:]
            if Uo.size:
                zU = zr[mS:]
                XU = mm.block(Uo, cU, Uo, cU)
                uU = np.repeat(np.arange(Uo.size), dz)
                GUU = XU[np.ix_(uU, uU)] * S[np.ix_(zU, zU)]
            z1 = _tri(chol, mS, eta[:mS]) if mS else np.zeros(0)
            if Uo.size:
                if mS:
                    XSU = mm.block(order[:nS], copies[:nS], Uo, cU)
                    GSU = XSU[np.ix_(np.repeat(np.arange(nS), dz), uU)] * S[np.ix_(zr[:mS], zU)]
                    Wm = _tri(chol, mS, GSU)
                    Sc = GUU - Wm.T @ Wm
                    rhs = eta[mS:] - Wm.T @ z1
                else:
                    Wm = np.zeros((0, Uo.size * dz))
                    Sc, rhs = GUU, eta[mS:]
                LU = sla.cholesky(0.5 * (Sc + Sc.T), lower=True, check_finite=False)
                z2 = sla.solve_triangular(LU, rhs, lower=True, check_finite=False)
                gU = sla.solve_triangular(LU, z2, lower=True, trans="T", check_finite=False)
                gS = _tri(chol, mS, z1 - Wm @ gU, trans=1) if mS else np.zeros(0)
                g = np.concatenate([gS, gU])
                val = float(z1 @ z1 + z2 @ z2)
            else:
                g = _tri(chol, mS, z1, trans=1)
                val = float(z1 @ z1)
        else:
            X = mm.block(order, copies, order, copies)
            Gk = X[np.ix_(u_rows, u_rows)] * S[np.ix_(zr, zr)]
            g = sla.cho_solve(sla.cho_factor(0.5 * (Gk + Gk.T), lower=True, check_finite=False), eta, check_finite=False)
            val = float(g @ eta)
        stages[k] = c0 - val
        locs[k] = c0
        gk = g.reshape(-1, dz) if nu_ else np.zeros((0, dz))
        Gi, Fi, Ii = [], [], []
        for i in range(n):
            mine = np.flatnonzero(sl.owner[order] == i)
            slots_i = list(dict.fromkeys(sl.row_slot[order[mine]].tolist()))
            Ii.append([(int(sl.src[a]), int(sl.step[a])) for a in slots_i])
            Gi.append(gk[mine].T.copy())
            Fi.append(sl.H[np.ix_(order[mine], _own_cols(system, i, k))])
        gains.append(Gi)
        fills.append(Fi)
        items.append(Ii)
    return items, gains, fills, stages, locs


def _tri(chol: Any, m: int, b: np.ndarray, trans: int = 0) -> np.ndarray:
    """Solve with the leading m x m block of the lower factor ``chol`` (Fortran order), read in place (no copy)."""
    from .team_lossy import _dtrtrs

    rhs = np.asfortranarray(b.reshape(m, -1))
    x, info = _dtrtrs(chol[:, :m], rhs, lower=1, trans=trans)
    if info:  # pragma: no cover - a positive definite factor has a nonzero diagonal
        raise np.linalg.LinAlgError(f"resend: triangular solve failed (info {info})")
    return x.reshape(b.shape)  # type: ignore[no-any-return]


class _Reordered:
    """The slot table of :func:`teamkf.estimators.team_lossy._slots` in another slot order (rows follow their slots)."""

    agent: np.ndarray
    src: np.ndarray
    step: np.ndarray
    due: np.ndarray
    row_slot: np.ndarray
    rows: np.ndarray
    owner: np.ndarray
    H: np.ndarray
    Sigma: np.ndarray
    fill: bool
    own_rows: list[np.ndarray]

    def __init__(self, sl: Any, perm: np.ndarray, rank: np.ndarray, row_perm: np.ndarray):
        self.agent, self.src, self.step, self.due = sl.agent[perm], sl.src[perm], sl.step[perm], sl.due[perm]
        self.row_slot = rank[sl.row_slot[row_perm]]
        self.rows = sl.rows[row_perm]
        self.owner = sl.owner[row_perm]
        self.H = sl.H[row_perm]
        self.Sigma, self.fill, self.own_rows = sl.Sigma, sl.fill, sl.own_rows


# ---------------------------------------------------------------------------
# the design object and its agents
# ---------------------------------------------------------------------------
def _design_class() -> Any:
    from .team_lossy import LossyTeamAgent, LossyTeamDesign, _own_cols, _rows

    @dataclass(frozen=True, eq=False, kw_only=True)
    class ResendLossyDesign(LossyTeamDesign):
        """The drop-aware design whose packets carry the sender's last ``resend`` items (module docstring)."""

        resend: int = field(default=1)

        def available(self, arrived: np.ndarray, k: int, i: int, its: Sequence[tuple[int, int]]) -> np.ndarray:
            """(n_runs, len(its)) booleans a_i(j, s; k) from the packet indicators ``arrived`` (n_runs, T, n, n)."""
            ell = np.asarray(self.arrivals.ell, dtype=int)
            cnt = np.concatenate([np.zeros((arrived.shape[0], 1, *arrived.shape[2:]), dtype=np.int64), np.cumsum(arrived, axis=1)], axis=1)
            src = np.array([j for j, _ in its], dtype=int)
            stp = np.array([s for _, s in its], dtype=int)
            hi = np.minimum(np.minimum(stp + self.resend - 1, k - ell[src, i]), arrived.shape[1] - 1)
            return (cnt[:, hi + 1, src, i] - cnt[:, stp, src, i]) > 0  # type: ignore[no-any-return]

        def errors(self, paths: Any, *, p_drop: Any = None, jitter: Any = None, rng: Any = None, arrived: Any = None) -> Any:
            """Team errors with sampled packet events (as :meth:`LossyTeamDesign.errors`), items available by re-sends."""
            x0, w, v, arrived = self._error_inputs(paths, p_drop, jitter, rng, arrived)
            sysm, cost = self.system, self.cost
            n_runs, T = v.shape[:2]
            n, dx, dz, dyt = sysm.n_agents, sysm.dx, cost.dz, sysm.dy_total
            nu = np.zeros((n_runs, T * dyt))
            yv = (
                np.concatenate([np.asarray(yi, dtype=float) for yi in paths.y], axis=2).reshape(n_runs, -1)
                if self.coordinates == "measurements"
                else nu
            )
            out = np.empty((n_runs, T, n * dz))
            for k, nu_k, ef in local_filter_errors(sysm, self.K_local, x0, w, v):
                nu[:, k * dyt : (k + 1) * dyt] = nu_k
                L = cost.L_at(k)
                for i in range(n):
                    its = self.items[k][i]
                    z = ef[:, i * dx : (i + 1) * dx] @ L[i * dz : (i + 1) * dz].T
                    if its:
                        rows = _rows(sysm, its)
                        a = self.available(arrived, k, i, its)
                        m = np.repeat(a, [sysm.dy[j] for j, _ in its], axis=1).astype(float)
                        vals = nu if self.coordinates == "innovations" else yv
                        f = vals[:, rows] * m + (1.0 - m) * (vals[:, _own_cols(sysm, i, k)] @ self.fills[k][i].T)
                        z = z - f @ self.gains[k][i].T
                    out[:, k, i * dz : (i + 1) * dz] = z
            return out

        def graph_agents(self) -> list[Any]:
            return [ResendLossyAgent(self, i) for i in range(self.n_agents)]

        def agent_slice(self, i: int) -> tuple[str, dict[str, np.ndarray], dict[str, Any]]:
            """The slice of :meth:`LossyTeamDesign.agent_slice` with ``resend`` in its meta (the agent rebuilt re-sends)."""
            kind, arrays, meta = super().agent_slice(i)
            return kind, arrays, {**meta, "resend": int(self.resend)}

        def details(self) -> dict[str, Any]:
            out = super().details()
            out["resend"] = self.resend
            out["class"] = (
                f"gains per step on the {self.coordinates} available by step k (each packet carries the sender's last {self.resend}), "
                "missed ones filled from the agent's own"
            )
            return out

        def arrays(self) -> dict[str, np.ndarray]:
            out = super().arrays()
            out["resend"] = np.asarray(self.resend)
            return out

    class ResendLossyAgent(LossyTeamAgent):
        """Agent i of a re-sending design: its packet of step k carries its items of k - r + 1..k; relays flood
        each packet once; an item enters the estimate once a packet carrying it arrived on time."""

        def init_state(self, n_runs: int) -> dict[str, Any]:
            return {"xhat": np.zeros((n_runs, self.system.dx)), "items": {}, "seen": set(), "mine": [], "n_runs": n_runs}

        def step(self, state: dict[str, Any], k: int, own: Any, inbox: Sequence[Any]) -> tuple[dict[str, Any], Any, list[Any]]:
            d: Any = self.design
            i, sysm, r = self.index, self.system, d.resend
            xhat = state["xhat"] if k == 0 else state["xhat"] @ sysm.A_at(k - 1).T
            y = np.asarray(own, dtype=float)
            nu = y - xhat @ sysm.C_at(i, k).T
            xhat = xhat + nu @ d.K_local[k][i].T
            mine = [*state["mine"], y if d.coordinates == "measurements" else nu]
            items, seen = dict(state["items"]), set(state["seen"])
            pkt = (i, k, tuple((s, mine[s]) for s in range(max(0, k - r + 1), k + 1)))
            new = []
            for j, tau, vals in [pkt, *[p for (_, _, payload) in inbox for p in payload]]:
                if (j, tau) in seen:
                    continue
                seen.add((j, tau))
                new.append((j, tau, vals))
                if k == tau + int(d.arrivals.ell[j, i]):  # on time: its items are available from now on
                    for s, val in vals:
                        items.setdefault((j, s), np.asarray(val))
            z = xhat @ d.cost.L_block(i, k).T
            its = d.items[k][i]
            if its:
                fill = np.hstack(mine) @ d.fills[k][i].T
                parts, col = [], 0
                for j, s in its:
                    dj = sysm.dy[j]
                    val = items.get((j, s))
                    parts.append(fill[:, col : col + dj] if val is None else val)
                    col += dj
                z = z + np.hstack(parts) @ d.gains[k][i].T
            return {"xhat": xhat, "items": items, "seen": seen, "mine": mine, "n_runs": state["n_runs"]}, z, new

    ResendLossyDesign.Agent = ResendLossyAgent  # type: ignore[attr-defined]  # what a deployed slice rebuilds
    return ResendLossyDesign


_CLASS: list[Any] = []


def resend_design_class() -> Any:
    """The re-sending design's class (built once, on first use)."""
    if not _CLASS:
        _CLASS.append(_design_class())
    return _CLASS[0]


def resend_agent_class() -> Any:
    """The agent class of the re-sending design (for :mod:`teamkf.estimators._lossy_slice`)."""
    return resend_design_class().Agent


def design_resend(
    system: Any,
    cost: Any,
    graph: Any,
    T: int,
    p: Any,
    J: Any,
    arr: ArrivalModel,
    candidates: tuple[str, ...],
    r: int,
    fill: bool,
    bound: bool,
    threads: int | None,
    *,
    keyed: int = 0,
    memory: int | None = None,
    schur: bool = True,
) -> Any:
    """``design_mtmse_lossy(..., resend=r)``: every item kind of ``candidates`` designed, the lower exact cost kept."""
    from .._blas import blas_threads
    from .team_lossy import _item_moments, local_filter_moments

    if keyed or memory is not None or not isinstance(fill, bool):
        raise ArgumentError(
            f"resend: resend = {r} is designed without keyed gains, without memory and with fill = true or false, found keyed = {keyed}, "
            f"memory = {memory}, fill = {fill!r}; drop keyed/memory/fill or use resend = 1",
            argument="resend",
        )

    tried = {}
    with blas_threads(threads):
        mom0 = local_filter_moments(system, T)
        for c in candidates:
            tried[c] = solve_resend(system, cost, arr, _item_moments(system, mom0, T, c), T, fill, r, schur=schur)
    coords = min(candidates, key=lambda c: float(np.sum(tried[c][3])))
    items, gains, fills, stage, local = tried[coords]
    from .team_lossy import build_lossy_design

    return build_lossy_design(
        resend_design_class(),
        system,
        cost,
        graph,
        T,
        p=p,
        J=J,
        memory=None,
        coords=coords,
        arr=arr,
        items=tuple(tuple(tuple(it) for it in step) for step in items),
        gains=gains,
        fills=fills,
        K_local=mom0.K,
        stage=stage,
        local=local,
        bound=bound,
        items_costs={c: float(np.sum(tried[c][3])) for c in candidates},
        info_mid={"resend": r},
        resend=r,
    )


from .team_lossy import register_resend  # noqa: E402  (this module extends team_lossy, which never imports it)

register_resend(design_resend)
