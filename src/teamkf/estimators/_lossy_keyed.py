r"""Pattern-keyed gains for the drop-aware design (``mtmse_lossy`` with ``keyed=1``): window w = 1.

The class
---------
Agent i's estimate re-weights with the on-time indicators of the items that become due at step k,
π_i(k) = (d_i(j, s))_{(j, s) ∈ D_i(k)}, D_i(k) = {(j, s): s + ℓ_ji = k, j ≠ i} (its current arrivals):

.. math::  \hat z_i(k) = L_i \hat x_i(k|k) + \sum_{\pi} 1[\pi_i(k) = \pi]\, G_i(k; \pi)\, f_i(k),

f_i(k) the filled items of today's class (an item, or its fill from the agent's own items). Older
items enter as today (item or fill). G independent of π is today's class, so the keyed optimum is
never worse than it (hence never worse than the local filters, and MTMSE at p = 0).

Exact expected cost
-------------------
Every quantity is an expectation over the link events of products of at most two fill vectors and
two pattern indicators. Let E_k be the edge-step events of the items due at k (every agent); the
patterns are functions of ω ∈ {0, 1}^{E_k}. Conditionally on ω an indicator d_a has probability
c_a(ω) (inclusion–exclusion over its geodesic paths with the events of E_k fixed) and two indicators
are conditionally dependent only when they share an event outside E_k. With Y[ω, (i, π, a)] =
1[π_i(ω) = π] c_a(ω), O[ω, (i, π, a)] = 1[π_i(ω) = π] and w(ω) = P(ω):

* P(π_i = π, π_l = π', d_a = 1, d_b = 1) = (Yᵀ diag(w) Y) + Σ_ω w 1 1 (P(d_a d_b | ω) − c_a c_b);
* P(π_i = π, π_l = π', d_a = 1) = (Yᵀ diag(w) O), P(π_i = π, π_l = π') = (Oᵀ diag(w) O);

and E[1 1 f_a f_bᵀ] = M₁₁ Σ + (P_a − M₁₁) Σ Hᵀ + (P_b − M₁₁) H Σ + (P − P_a − P_b + M₁₁) H Σ Hᵀ as in
today's class. The stage cost is a convex quadratic in all the G(π); its stationarity conditions
(Γ g = η) couple agent i's pattern-π gains with agent l's pattern-π' gains through these joint
probabilities. Gains on an item that is surely missed under π (its fill is a function of the own
items, which are unknowns too) and on patterns of probability 0 are set to 0.

Work: 2^|E_k| assignments per step (refused above :data:`MAX_EVENTS`), one dense factorization of
size Σ_i (patterns_i × rows_i) per step: for small teams and short horizons.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .._lazy import scipy_linalg as sla
from .._linalg import block_diag
from ..exceptions import ArgumentError
from ._arrivals import ArrivalModel, _union_prob
from ._lossy_moments import local_filter_errors

__all__ = ["MAX_EVENTS", "MAX_DUE", "design_keyed", "solve_keyed", "pattern_index"]

#: at most this many edge-step events decide the current arrivals of one step (2^events assignments)
MAX_EVENTS = 14
#: at most this many items due at one step per agent (2^items patterns)
MAX_DUE = 8

_TOL = 1e-12


def _reduce(paths: list[frozenset[tuple[int, int]]], fixed: dict[tuple[int, int], int]) -> list[frozenset[tuple[int, int]]] | None:
    """The paths given the fixed events: a failed event removes its path, a successful one leaves it. None: surely on time."""
    out = []
    for p in paths:
        if any(fixed.get(ev, 1) == 0 for ev in p):
            continue
        r = frozenset(ev for ev in p if ev not in fixed)
        if not r:
            return None
        out.append(r)
    return out


def _cond_prob(paths: list[frozenset[tuple[int, int]]], fixed: dict[tuple[int, int], int], q: np.ndarray) -> float:
    r = _reduce(paths, fixed)
    return 1.0 if r is None else _union_prob(r, q)


def pattern_index(bits: Any) -> Any:
    """The pattern number of on-time bits (item t of D_i(k) is bit t)."""
    bits = np.asarray(bits, dtype=np.int64)
    return (bits * (1 << np.arange(bits.shape[-1], dtype=np.int64))).sum(axis=-1)


def solve_keyed(
    system: Any, cost: Any, arr: ArrivalModel, mom: Any, sl: Any, T: int
) -> tuple[list[Any], list[Any], list[Any], list[Any], np.ndarray, np.ndarray]:
    """Keyed gains of every step: (items, due, keyed gains {π: G}, fills, stage costs, local stage costs).

    ``sl`` are the slots of :func:`teamkf.estimators.team_lossy._slots` (no memory) and ``mom`` the item moments.
    """
    n, dz = system.n_agents, cost.dz
    nslots = sl.agent.size
    slot_paths = [[frozenset((e, int(sl.step[a]) + o) for (e, o) in p) for p in arr.paths[(int(sl.src[a]), int(sl.agent[a]))]] for a in range(nslots)]
    slot_events = [frozenset().union(*ps) if ps else frozenset() for ps in slot_paths]
    slot_q = arr.prob[sl.src, sl.agent]
    row_slot, rows, H, Sigma = sl.row_slot, sl.rows, sl.H, sl.Sigma
    joint0: dict[tuple[int, int], float] = {}
    items_all, due_all, gains_all, fills_all = [], [], [], []
    stages, locs = np.zeros(T), np.zeros(T)
    for k in range(T):
        S, L = cost.S_at(k), cost.L_at(k)
        Lb = block_diag(*[L[i * dz : (i + 1) * dz] for i in range(n)])
        c0 = float(np.trace(S @ Lb @ mom.Pe[k] @ Lb.T))
        live = np.flatnonzero(sl.due <= k)  # slots (ordered by due step)
        due_now = [[int(a) for a in live if sl.due[a] == k and sl.agent[a] == i and sl.src[a] != i] for i in range(n)]
        for i in range(n):
            if len(due_now[i]) > MAX_DUE:
                raise ArgumentError(
                    f"keyed: agent {i} has {len(due_now[i])} items due at step {k}, expected at most {MAX_DUE} (2^items gains); use keyed = 0",
                    argument="keyed",
                )
        E = sorted(frozenset().union(*[slot_events[a] for lst in due_now for a in lst]))
        if len(E) > MAX_EVENTS:
            raise ArgumentError(
                f"keyed: the arrivals of step {k} depend on {len(E)} link events, expected at most {MAX_EVENTS}; use keyed = 0", argument="keyed"
            )
        Eset = set(E)
        nom = 1 << len(E)
        bits = (np.arange(nom)[:, None] >> np.arange(len(E))[None, :]) & 1
        qe = np.array([arr.q[e] for (e, _) in E])
        w = np.prod(np.where(bits == 1, qe[None, :], 1.0 - qe[None, :]), axis=1) if E else np.ones(1)
        fixed = [{ev: int(bits[o, t]) for t, ev in enumerate(E)} for o in range(nom)]
        touch = {int(a) for a in live if slot_events[a] & Eset}
        pos = {int(a): t for t, a in enumerate(live)}
        C = np.tile(slot_q[live], (nom, 1))  # c_a(ω)
        for a in touch:
            C[:, pos[a]] = [_cond_prob(slot_paths[a], fixed[o], arr.q) for o in range(nom)]
        pats = []  # per agent: (Ω,) pattern number
        for i in range(n):
            b = np.rint(C[:, [pos[a] for a in due_now[i]]]).astype(np.int64) if due_now[i] else np.zeros((nom, 0), dtype=np.int64)
            pats.append(pattern_index(b))
        # slot-level unknown blocks (agent, pattern, slot)
        su_agent, su_pat, su_slot = [], [], []
        for i in range(n):
            mine = [int(a) for a in live if sl.agent[a] == i]
            for pi in range(1 << len(due_now[i])):
                for a in mine:
                    su_agent.append(i)
                    su_pat.append(pi)
                    su_slot.append(a)
        su_agent_a, su_pat_a = np.array(su_agent, dtype=int), np.array(su_pat, dtype=int)
        Os = np.stack([pats[i] for i in su_agent], axis=1) == su_pat_a[None, :] if su_agent else np.zeros((nom, 0), dtype=bool)
        Os = Os.astype(float)
        Ys = Os * C[:, [pos[a] for a in su_slot]] if su_agent else np.zeros((nom, 0))
        wY = w[:, None] * Ys
        M11 = Ys.T @ wY
        Pa = wY.T @ Os  # P(π_i, π_l, d_a = 1)
        P = Os.T @ (w[:, None] * Os)
        # corrections: the conditional dependence of two indicators sharing an event outside E_k (and d_a^2 = d_a)
        by_slot: dict[int, list[int]] = {}
        for u, a in enumerate(su_slot):
            by_slot.setdefault(a, []).append(u)
        ev_map: dict[tuple[int, int], list[int]] = {}
        for a in live.tolist():
            if sl.src[a] != sl.agent[a]:
                for ev in slot_events[a]:
                    ev_map.setdefault(ev, []).append(a)
        dep = {(a, b) for lst in ev_map.values() for a in lst for b in lst}
        for a, b in dep:
            if a == b:
                corr = C[:, pos[a]] - C[:, pos[a]] ** 2
            elif a not in touch and b not in touch:
                key = (min(a, b), max(a, b))
                if key not in joint0:
                    joint0[key] = slot_q[a] + slot_q[b] - _union_prob(slot_paths[a] + slot_paths[b], arr.q) - slot_q[a] * slot_q[b]
                corr = np.full(nom, joint0[key])
            else:
                corr = np.array(
                    [
                        C[o, pos[a]] + C[o, pos[b]] - _cond_prob(slot_paths[a] + slot_paths[b], fixed[o], arr.q) - C[o, pos[a]] * C[o, pos[b]]
                        for o in range(nom)
                    ]
                )
            if not np.any(np.abs(corr) > 0):
                continue
            ua, ub = by_slot[a], by_slot[b]
            M11[np.ix_(ua, ub)] += Os[:, ua].T @ ((w * corr)[:, None] * Os[:, ub])
        # row-level unknowns
        lr = np.flatnonzero(np.isin(row_slot, live))  # live rows
        rpos = {int(r): t for t, r in enumerate(lr)}
        u_su, u_row = [], []
        for t, a in enumerate(su_slot):
            for r in np.flatnonzero(row_slot == a).tolist():
                u_su.append(t)
                u_row.append(rpos[r])
        u_su_a, u_row_a = np.array(u_su, dtype=int), np.array(u_row, dtype=int)
        p0 = np.diag(P)[u_su_a] if u_su else np.zeros(0)
        pr1 = np.diag(Pa)[u_su_a] if u_su else np.zeros(0)
        keep = (p0 > _TOL) & (pr1 > _TOL * np.maximum(p0, _TOL))
        ku = np.flatnonzero(keep)
        Rl = rows[lr]
        Hl = H[lr]
        X = Sigma[np.ix_(Rl, Rl)]
        X1 = Sigma[Rl] @ Hl.T  # Σ Hᵀ
        B = Hl @ Sigma @ Hl.T
        su_k, ro_k = u_su_a[ku], u_row_a[ku]
        m11 = M11[np.ix_(su_k, su_k)]
        pa = Pa[np.ix_(su_k, su_k)]
        pb = pa.T
        pp = P[np.ix_(su_k, su_k)]
        ix = np.ix_(ro_k, ro_k)
        Ef = m11 * X[ix] + (pa - m11) * X1[ix] + (pb - m11) * X1.T[ix] + (pp - pa - pb + m11) * B[ix]
        ag = su_agent_a[su_k]
        zi = (ag[:, None] * dz + np.arange(dz)[None, :]).ravel()
        uu = np.repeat(np.arange(ku.size), dz)
        Gam = Ef[np.ix_(uu, uu)] * S[np.ix_(zi, zi)]
        Gam = 0.5 * (Gam + Gam.T)
        Wm = S @ Lb @ mom.Theta[k]
        Nk = Wm.shape[1]
        V1 = Wm[:, Rl]
        V2 = Wm @ Hl[:, :Nk].T
        eta = pr1[ku][uu] * V1[zi, ro_k[uu]] + (p0[ku] - pr1[ku])[uu] * V2[zi, ro_k[uu]]
        if eta.size:
            try:
                g = sla.cho_solve(sla.cho_factor(Gam, lower=True, check_finite=False), eta, check_finite=False)
            except np.linalg.LinAlgError:  # a redundant unknown (an item surely known from others): any solution has the same cost
                g = np.linalg.lstsq(Gam, eta, rcond=None)[0]
        else:
            g = np.zeros(0)
        stages[k] = c0 - float(g @ eta)
        locs[k] = c0
        # per agent: its items (as today), the items due now, and {π: G}
        items_k, due_k, gains_k, fills_k = [], [], [], []
        gfull = np.zeros((len(u_su), dz))
        gfull[ku] = g.reshape(-1, dz)
        for i in range(n):
            mine = [int(a) for a in live if sl.agent[a] == i]
            items_k.append([(int(sl.src[a]), int(sl.step[a])) for a in mine])
            due_k.append([(int(sl.src[a]), int(sl.step[a])) for a in due_now[i]])
            mrows = [rpos[r] for a in mine for r in np.flatnonzero(row_slot == a).tolist()]
            own = _own_cols(system, i, k)
            fills_k.append(H[np.ix_(lr[mrows], own)] if mrows else np.zeros((0, own.size)))
            gi = {}
            for pi in range(1 << len(due_now[i])):
                sel = np.flatnonzero((su_agent_a[u_su_a] == i) & (su_pat_a[u_su_a] == pi))
                gi[pi] = gfull[sel].T.copy()
            gains_k.append(gi)
        items_all.append(items_k)
        due_all.append(due_k)
        gains_all.append(gains_k)
        fills_all.append(fills_k)
    return items_all, due_all, gains_all, fills_all, stages, locs


def _own_cols(system: Any, i: int, k: int) -> np.ndarray:
    dyt, off = system.dy_total, system.offsets
    parts = [s * dyt + int(off[i]) + np.arange(system.dy[i]) for s in range(k + 1)]
    return np.concatenate(parts).astype(int)


# ---------------------------------------------------------------------------
# the design object
# ---------------------------------------------------------------------------
def _design_class() -> Any:
    from dataclasses import dataclass, field

    from .team_lossy import LossyTeamAgent, LossyTeamDesign, _rows
    from .team_lossy import _own_cols as own_cols

    @dataclass(frozen=True, eq=False, kw_only=True)
    class KeyedLossyDesign(LossyTeamDesign):
        """The drop-aware design with gains keyed on the current arrivals (``keyed = 1``).

        ``due[k][i]`` are the items (j, s) of D_i(k) (bit t of the pattern is item t on time), ``keyed_gains[k][i]``
        maps a pattern number to G_i(k; π) over ``items[k][i]``; ``gains`` holds the all-on-time pattern's gains.
        """

        due: tuple[Any, ...] = field(repr=False)
        keyed_gains: tuple[Any, ...] = field(repr=False)

        def gain_of(self, k: int, i: int, arrived_bits: Any) -> Any:
            """G_i(k; π) for the on-time bits of ``due[k][i]``."""
            return self.keyed_gains[k][i][int(pattern_index(np.asarray(arrived_bits, dtype=int)))]

        def errors(self, paths: Any, *, p_drop: Any = None, jitter: Any = None, rng: Any = None, arrived: Any = None) -> Any:
            """Team errors with sampled link events (as :meth:`LossyTeamDesign.errors`), each run with its pattern's gains."""
            x0, w, v, arrived = self._error_inputs(paths, p_drop, jitter, rng, arrived)
            sysm, cost = self.system, self.cost
            n_runs, T = v.shape[:2]
            n, dx, dz, dyt = sysm.n_agents, sysm.dx, cost.dz, sysm.dy_total
            off = sysm.offsets
            nu = np.zeros((n_runs, T * dyt))
            yv = (
                np.concatenate([np.asarray(yi, dtype=float) for yi in paths.y], axis=2).reshape(n_runs, -1)
                if self.coordinates == "measurements"
                else nu
            )
            mask = np.zeros((n_runs, T * dyt, n))
            for s in range(T):
                for j in range(n):
                    mask[:, s * dyt + int(off[j]) : s * dyt + int(off[j]) + sysm.dy[j], :] = arrived[:, s, j, :][:, None, :]
            out = np.empty((n_runs, T, n * dz))
            for k, nu_k, ef in local_filter_errors(sysm, self.K_local, x0, w, v):
                nu[:, k * dyt : (k + 1) * dyt] = nu_k
                L = cost.L_at(k)
                for i in range(n):
                    rows = _rows(sysm, self.items[k][i])
                    z = ef[:, i * dx : (i + 1) * dx] @ L[i * dz : (i + 1) * dz].T
                    if rows.size:
                        own = own_cols(sysm, i, k)
                        m = mask[:, rows, i]
                        vals = nu if self.coordinates == "innovations" else yv
                        f = vals[:, rows] * m + (1.0 - m) * (vals[:, own] @ self.fills[k][i].T)
                        bits = np.stack([arrived[:, s, j, i] for (j, s) in self.due[k][i]], axis=1) if self.due[k][i] else np.zeros((n_runs, 0))
                        pat = pattern_index(bits)
                        Gst = np.stack([self.keyed_gains[k][i][p] for p in range(1 << len(self.due[k][i]))])
                        z = z - np.einsum("rc,rzc->rz", f, Gst[pat])
                    out[:, k, i * dz : (i + 1) * dz] = z
            return out

        def graph_agents(self) -> list[Any]:
            return [KeyedLossyAgent(self, i) for i in range(self.n_agents)]

        def agent_slice(self, i: int) -> tuple[str, dict[str, np.ndarray], dict[str, Any]]:
            raise self._unsupported("agent_slice()", "its keyed gains ship no per-agent slice; its agent processes design the team themselves")

        def details(self) -> dict[str, Any]:
            out = super().details()
            out["class"] = f"gains per step and per pattern of the current arrivals (w = 1) on the on-time {self.coordinates}, missed ones filled"
            out["keyed"] = 1
            return out

        def arrays(self) -> dict[str, np.ndarray]:
            out = super().arrays()
            for k, step in enumerate(self.keyed_gains):
                for i, gi in enumerate(step):
                    out[f"due_{i}_t{k}"] = np.asarray(self.due[k][i], dtype=np.int64).reshape(-1, 2)
                    for p, G in gi.items():
                        out[f"G_{i}_t{k}_p{p}"] = np.asarray(G)
            return out

    class KeyedLossyAgent(LossyTeamAgent):
        """Agent i of a keyed design: as :class:`LossyTeamAgent`, with the gains of the pattern of its current arrivals."""

        def step(self, state: dict[str, Any], k: int, own: Any, inbox: Any) -> Any:
            d: Any = self.design
            i = self.index
            new_state, _, new = super().step(state, k, own, inbox)
            items = new_state["items"]
            bits = [items.get(it) is not None for it in d.due[k][i]]
            G = d.gain_of(k, i, bits)
            sysm = self.system
            z = new_state["xhat"] @ d.cost.L_block(i, k).T
            its = d.items[k][i]
            if its:
                nu_own = np.hstack([items[(i, s)] for s in range(k + 1)])
                fill = nu_own @ d.fills[k][i].T
                parts, col = [], 0
                for j, s in its:
                    dj = sysm.dy[j]
                    val = items.get((j, s))
                    parts.append(fill[:, col : col + dj] if val is None else val)
                    col += dj
                z = z + np.hstack(parts) @ G.T
            return new_state, z, new

    return KeyedLossyDesign


_CLASS: list[Any] = []


def keyed_design(
    system: Any, cost: Any, graph: Any, T: int, p: Any, J: Any, coords: str, arr: ArrivalModel, mom: Any, tried: dict[str, Any], bound: bool
) -> Any:
    """The :class:`KeyedLossyDesign` of the chosen item kind (``tried[coords]`` from :func:`solve_keyed`)."""
    if not _CLASS:
        _CLASS.append(_design_class())
    items, due, gains, fills, stage, local = tried[coords]
    top = [[g[(1 << len(due[k][i])) - 1] for i, g in enumerate(gains[k])] for k in range(T)]
    from .team_lossy import build_lossy_design

    return build_lossy_design(
        _CLASS[0],
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
        gains=top,
        fills=fills,
        K_local=mom.K,
        stage=stage,
        local=local,
        bound=bound,
        items_costs={c: float(np.sum(tried[c][4])) for c in tried},
        info_mid={"keyed": 1},
        due=tuple(tuple(tuple(step_i) for step_i in step) for step in due),
        keyed_gains=tuple(tuple(step) for step in gains),
    )


def design_keyed(
    system: Any,
    cost: Any,
    graph: Any,
    T: int,
    p: Any,
    J: Any,
    arr: ArrivalModel,
    candidates: tuple[str, ...],
    memory: int | None,
    fill: bool,
    bound: bool,
    threads: int | None,
) -> Any:
    """``design_mtmse_lossy(..., keyed=1)``: every item kind of ``candidates`` designed, the lower exact cost kept."""
    from .._blas import blas_threads
    from .team_lossy import _item_moments, _slots, local_filter_moments

    if memory is not None:
        raise ArgumentError(
            f"keyed: the keyed gains use every item (memory = None), found memory = {memory}; drop memory or use keyed = 0", argument="keyed"
        )
    tried = {}
    with blas_threads(threads):
        mom0 = local_filter_moments(system, T)
        for c in candidates:
            mc = _item_moments(system, mom0, T, c)
            tried[c] = solve_keyed(system, cost, arr, mc, _slots(system, arr, mc.Sigma, T, fill), T)
    coords = min(candidates, key=lambda c: float(np.sum(tried[c][4])))  # the lower exact expected cost (ties: the first)
    return keyed_design(system, cost, graph, T, p, J, coords, arr, mom0, tried, bound)


from .team_lossy import register_keyed  # noqa: E402  (this module extends team_lossy, which never imports it)

register_keyed(design_keyed)
