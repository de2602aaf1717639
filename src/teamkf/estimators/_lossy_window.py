r"""The drop-aware design with a finite memory (``memory = m``): windowed fills, a lifted moment recursion, a steady form.

The class (a variant of eq. (1) of :mod:`teamkf.estimators.team_lossy`)
-----------------------------------------------------------------------
Agent i's estimate at step k acts on the items of the last m steps, 𝓘_i(k) = {(j, s) : k - m + 1 ≤ s ≤ k - ℓ_ji},

.. math::  \hat z_i(k) = L_i \hat x_i(k|k) + \sum_{(j,s) \in \mathcal I_i(k)} G_i(k; j, s)\, f_i(j, s), \qquad
           f_i(j, s) = d_i(j, s)\, u_j(s) + (1 - d_i(j, s))\, H_i(j, s)\, u_i(s - m + 1 : s + \ell_{ji}),

the fill H_i(j, s) being the best linear predictor of the item from the agent's own items of the window
s - m + 1 .. s + ℓ_ji (fixed offline at the step s + ℓ_ji the item is due; older own data stay in x̂_i(k|k)).
With m ≥ T the window starts at 0: the full class of :mod:`~teamkf.estimators.team_lossy`.

Moments. Everything step k needs is a linear function of the lifted vector
z(k) = (x(k) [raw-measurement items only], e_1(k|k), …, e_n(k|k), u(k), u(k-1), …, u(k - W + 1)),
W = max(2m - 1, m + ℓ_max) (the live items reach back to k - m + 1, their fills' windows to k - 2m + 2).
With c = (x, e) and the prediction (x(k+1), ε(k+1)) = (I ⊗ A)(x(k), e(k|k)) + 1 ⊗ w(k), the new item
u(k+1) = C_u (x, ε)(k+1) + v(k+1) (y_j = C_j x + v_j, or ν_j = C_j ε_j + v_j) and the update
e_j(k+1|k+1) = (I - K_j C_j) ε_j - K_j v_j, the covariance of z(k+1) is that of z(k) shifted by one item
block plus the new rows: O(dim² + dim · dim_c²) per step, dim = dim_c + W Σ_j d_y^j, whatever T.

Optimality conditions. The link events are independent of the Gaussian variables, the fills are fixed, so the
stage cost is the convex quadratic J_k(G) = Tr(S L̄ P_e L̄ᵀ) - 2⟨G, η⟩ + ⟨G, Γ G⟩ of the full class, with
E[f_a f_bᵀ] = M₁₁(Σ - A - Aᵀ + B)_ab + q_a(Aᵀ - B)_ab + q_b(A - B)_ab + B_ab, Σ = cov(u_a, u_b),
A_ab = cov(h_a, u_b), B_ab = cov(h_a, h_b) (h_a the fill), η from cov(e_l(k|k), u_a) and cov(e_l(k|k), h_a):
all entries of cov z(k). The Radner conditions are Γ G = η (necessary and sufficient); J_k* = c₀ - ⟨G, η⟩.

Steady form. With a time-invariant model and cost the slot layout repeats from step 2m - 1 on; once the
gains and fills change by less than :data:`STEADY_TOL` (relative) over :data:`STEADY_STEPS` steps they are
frozen and reused (the same arrays) for every later step. The later stage costs stay exact: for fixed gains
and fills the estimation error is err = Φ₀ z - G D Ψ z (D = diag(d), Ψ the item minus its fill, Φ₀ = L̄ E_e - G H),
so J_k = ⟨𝓜, P_z(k)⟩ with 𝓜 = Φ₀ᵀSΦ₀ - Φ₀ᵀ S G diag(q) Ψ - (…)ᵀ + Ψᵀ((GᵀSG)∘M₁₁)Ψ, and P_z(k) is the recursion
above (run to T with the agents' actual local gains K(k)). Work O(T) with constant memory once frozen.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .._lazy import scipy_linalg as sla
from .._linalg import block_diag
from .._validation import FloatArray

#: the gains and fills are frozen once their relative change per step stays below this ...
STEADY_TOL = 1e-9
#: ... for this many consecutive steps
STEADY_STEPS = 3


def window_steps(memory: int, lmax: int) -> int:
    """W: the item steps the lifted vector holds (the live items and their fills' own windows)."""
    return max(2 * memory - 1, memory + lmax, 1)


def _m11(arr: Any, agent: np.ndarray, src: np.ndarray, step: np.ndarray) -> FloatArray:
    """E[d_a d_b] over the slots (exact: the product of the marginals plus the dependent pairs' corrections)."""
    qs = arr.prob[src, agent]
    M = np.outer(qs, qs)
    index = {(int(agent[t]), int(src[t]), int(step[t])): t for t in range(agent.size)}
    for t in range(agent.size):
        i, j, s_ = int(agent[t]), int(src[t]), int(step[t])
        M[t, t] = qs[t]
        if i == j:
            continue
        for (h, l), corr in arr.pairs_from.get((j, i), ()):
            for delta, c in corr.items():
                u = index.get((l, h, s_ + delta))
                if u is not None and u != t:
                    M[t, u] += c
    return M


def solve(
    system: Any, cost: Any, arr: Any, T: int, memory: int, fill: bool, coords: str, progress: bool | None
) -> tuple[tuple[Any, ...], list[Any], list[Any], np.ndarray, np.ndarray, list[list[FloatArray]], dict[str, Any]]:
    """Items, gains, fills (on the agent's last w own items), stage costs, local costs, local gains and info."""
    from .._resources import progress as _progress

    n, dx, dz, dyt = system.n_agents, system.dx, cost.dz, system.dy_total
    dy = [int(d) for d in system.dy]
    off = [int(o) for o in system.offsets]
    m = int(memory)
    meas = coords == "measurements"
    live = arr.prob > 0
    ell = np.asarray(arr.ell, dtype=int)
    lmax = int(np.max(np.where(live, ell, 0)))
    W = window_steps(m, lmax)
    r = n + (1 if meas else 0)  # blocks of the core c = (x, e_1, ..., e_n)
    dc = r * dx
    ex = np.arange(dc - n * dx, dc)  # the rows of e(k|k)
    dim = dc + W * dyt
    d1 = dc + dyt
    steady_ok = not system.is_time_varying and not cost.is_time_varying
    # pairs (i, j) that exchange items, each agent's slots ordered like the full design's (due step, source, step)
    P = np.zeros((dim, dim))
    P_loc = [np.array(system.Sigma_x, dtype=float) for _ in range(n)]
    Hcache: dict[tuple[int, int, int], FloatArray] = {}
    Ks: list[list[FloatArray]] = []
    items: list[Any] = []
    gains: list[Any] = []
    fills: list[Any] = []
    stages, locs = np.zeros(T), np.zeros(T)
    M_cache: FloatArray | None = None
    prev: tuple[FloatArray, FloatArray] | None = None
    calm = 0
    frozen: dict[str, Any] | None = None
    info: dict[str, Any] = {"window": W, "steady_from": None}

    def upos(t: int, k: int, j: int) -> np.ndarray:
        s0 = dc + (k - t) * dyt + off[j]
        return np.arange(s0, s0 + dy[j])

    for k in _progress(range(T), total=T, desc="mtmse_lossy design (memory)", enabled=progress):
        # ---- the lifted covariance: z(k-1) -> z(k) -------------------------------------------------
        if k == 0:
            Cp = np.kron(np.ones((r, r)), system.Sigma_x)
            cross = None
        else:
            Fa = np.kron(np.eye(r), system.A_at(k - 1))
            cross = Fa @ P[:dc]  # cov((x, ε)(k), z(k-1))
            Cp = cross[:, :dc] @ Fa.T + np.kron(np.ones((r, r)), system.Q_at(k - 1))
        Cs = [system.C_at(j, k) for j in range(n)]
        Rs = [system.R_at(j, k) for j in range(n)]
        K = []
        for j in range(n):
            Sy = Cs[j] @ P_loc[j] @ Cs[j].T + Rs[j]
            K.append(sla.cho_solve(sla.cho_factor(0.5 * (Sy + Sy.T), lower=True), Cs[j] @ P_loc[j]).T if Sy.size else np.zeros((dx, 0)))
        Ks.append(K)
        U = block_diag(*[np.eye(dx) - K[j] @ Cs[j] for j in range(n)])
        Kb = block_diag(*K) if dyt else np.zeros((n * dx, 0))
        Cb = block_diag(*Cs) if dyt else np.zeros((0, n * dx))
        Mx = np.zeros((d1, dc))
        if meas:
            Mx[:dx, :dx] = np.eye(dx)
            Mx[dc:, :dx] = np.vstack(Cs) if dyt else np.zeros((0, dx))
        Mx[dc - n * dx : dc, dc - n * dx : dc] = U
        if not meas:
            Mx[dc:, :] = Cb
        Nv = np.vstack([np.zeros((dc - n * dx, dyt)), -Kb, np.eye(dyt)])
        Rk = system.R_stack(k)
        Pn = np.zeros((dim, dim))
        top = Mx @ Cp @ Mx.T + Nv @ Rk @ Nv.T
        Pn[:d1, :d1] = 0.5 * (top + top.T)
        if cross is not None:
            X1 = Mx @ cross[:, dc : dc + (W - 1) * dyt]
            Pn[:d1, d1:] = X1
            Pn[d1:, :d1] = X1.T
            Pn[d1:, d1:] = P[dc : dc + (W - 1) * dyt, dc : dc + (W - 1) * dyt]
        P = Pn
        for j in range(n):
            A = system.A_at(k)
            IKC = np.eye(dx) - K[j] @ Cs[j]
            Pf = IKC @ P_loc[j] @ IKC.T + K[j] @ Rs[j] @ K[j].T
            Pp = A @ Pf @ A.T + system.Q_at(k)
            P_loc[j] = 0.5 * (Pp + Pp.T)
        # ---- stage k ----------------------------------------------------------------------------------
        S, L = cost.S_at(k), cost.L_at(k)
        Lb = block_diag(*[L[i * dz : (i + 1) * dz] for i in range(n)])
        c0 = float(np.trace(S @ Lb @ P[np.ix_(ex, ex)] @ Lb.T))
        locs[k] = c0
        if frozen is not None:  # steady: the frozen gains' exact cost, a linear functional of cov z(k); items shifted
            stages[k] = float(np.sum(frozen["Mop"] * P))
            gains.append(frozen["G"])
            fills.append(frozen["F"])
            items.append(ShiftedItems(frozen["items"], k - frozen["k"]))
            continue
        w = min(k + 1, 2 * m - 1)  # the fills act on the agent's own items u_i(k - w + 1 : k)
        slot_i, slot_j, slot_s = [], [], []
        per_agent: list[list[tuple[int, int]]] = []
        for i in range(n):
            lst = sorted((s + int(ell[j, i]), j, s) for j in range(n) if live[j, i] for s in range(max(0, k - m + 1), k - int(ell[j, i]) + 1))
            per_agent.append([(j, s) for (_, j, s) in lst])
            for _, j, s in lst:
                slot_i.append(i)
                slot_j.append(j)
                slot_s.append(s)
        ag, sr, st = np.array(slot_i, dtype=int), np.array(slot_j, dtype=int), np.array(slot_s, dtype=int)
        items.append(tuple(tuple(x) for x in per_agent))
        # fills of the items due now (best linear predictor from the own window), kept while the item is live
        if fill and frozen is None:
            for i in range(n):
                for j, s in per_agent[i]:
                    if j != i and s + int(ell[j, i]) == k and dy[i]:
                        t0 = max(0, s - m + 1)
                        o = np.concatenate([upos(t, k, i) for t in range(t0, k + 1)])
                        Soo = P[np.ix_(o, o)]
                        rhs = P[np.ix_(o, upos(s, k, j))]
                        Hcache[(i, j, s)] = sla.cho_solve(sla.cho_factor(0.5 * (Soo + Soo.T), lower=True), rhs).T
            for key in [key for key in Hcache if key[2] < k - m + 1]:
                del Hcache[key]
        F_list = []
        for i in range(n):
            rows_i = sum(dy[j] for j, _ in per_agent[i])
            F = np.zeros((rows_i, w * dy[i]))
            rr0 = 0
            for j, s in per_agent[i]:
                H = Hcache.get((i, j, s)) if fill and j != i else None
                if H is not None:
                    t0 = max(0, s - m + 1)
                    c_ = (t0 - (k - w + 1)) * dy[i]
                    F[rr0 : rr0 + dy[j], c_ : c_ + H.shape[1]] = H
                rr0 += dy[j]
            F_list.append(F)
        own = [np.concatenate([upos(t, k, i) for t in range(k - w + 1, k + 1)]) if dy[i] else np.zeros(0, dtype=int) for i in range(n)]
        row_slot = np.repeat(np.arange(ag.size), [dy[j] for j in sr]).astype(int)
        cols = np.concatenate([upos(int(st[a]), k, int(sr[a])) for a in range(ag.size)]).astype(int) if ag.size else np.zeros(0, dtype=int)
        owner = ag[row_slot]
        q = arr.prob[sr, ag][row_slot]
        R = cols.size
        b = [np.flatnonzero(owner == i) for i in range(n)]
        Wm = S @ Lb  # (n dz, n dx)
        zidx = (owner[:, None] * dz + np.arange(dz)[None, :]).ravel()
        rr = np.repeat(np.arange(R), dz)
        if M_cache is not None and k >= m - 1 and M_cache.shape[0] == ag.size:
            Ms = M_cache
        else:
            Ms = _m11(arr, ag, sr, st)
            if k >= m - 1:
                M_cache = Ms
        M11 = Ms[np.ix_(row_slot, row_slot)]
        HP = np.zeros((R, dim))
        for i in range(n):
            if b[i].size and own[i].size:
                HP[b[i]] = F_list[i] @ P[own[i]]
        Am = HP[:, cols]  # cov(h_a, u_b)
        Bm = np.zeros((R, R))
        for i in range(n):
            if b[i].size and own[i].size:
                Bm[:, b[i]] = HP[:, own[i]] @ F_list[i].T
        X = P[np.ix_(cols, cols)] - Am - Am.T + Bm
        X *= M11
        X += q[:, None] * (Am.T - Bm) + q[None, :] * (Am - Bm) + Bm
        X = 0.5 * (X + X.T)
        V1 = Wm @ P[np.ix_(ex, cols)]
        V2 = Wm @ HP[:, ex].T
        eta = q[rr] * V1[zidx, rr] + (1.0 - q[rr]) * V2[zidx, rr]
        if R:
            Gk = X[np.ix_(rr, rr)] * S[np.ix_(zidx, zidx)]
            g = sla.cho_solve(sla.cho_factor(Gk, lower=True, check_finite=False), eta, check_finite=False)
        else:
            g = np.zeros(0)
        stages[k] = c0 - float(g @ eta)
        G_list = [g.reshape(-1, dz)[b[i]].T if R else np.zeros((dz, 0)) for i in range(n)]
        # the steady form: once the layout repeats and the gains and fills have stopped changing
        if steady_ok and k >= 2 * m - 1 and R:
            cur = (g, np.concatenate([F.ravel() for F in F_list]))
            if prev is not None and prev[0].shape == cur[0].shape and prev[1].shape == cur[1].shape:
                dg = float(np.linalg.norm(cur[0] - prev[0])) / max(float(np.linalg.norm(cur[0])), 1e-300)
                df = float(np.linalg.norm(cur[1] - prev[1])) / max(float(np.linalg.norm(cur[1])), 1e-300)
                calm = calm + 1 if max(dg, df) <= STEADY_TOL else 0
            prev = cur
            if calm >= STEADY_STEPS and k < T - 1:
                Mop = _operator(g, q, M11, F_list, Lb, S, ex, cols, own, b, zidx, rr, n * dz, dim)
                frozen = {"G": G_list, "F": F_list, "Mop": Mop, "items": items[-1], "k": k}
                info["steady_from"] = k + 1
                # the same cost two ways at this step: the solved c₀ - ⟨G, η⟩ and the operator's ⟨𝓜, P_z(k)⟩
                info["steady_check"] = (float(stages[k]), float(np.sum(Mop * P)))
        gains.append(G_list)
        fills.append(F_list)
    return tuple(items), gains, fills, stages, locs, Ks, info


class ShiftedItems:
    """The items of every agent at a step of the steady form: those of the frozen step, ``shift`` steps later (no copies kept)."""

    __slots__ = ("base", "shift")

    def __init__(self, base: tuple[tuple[tuple[int, int], ...], ...], shift: int):
        self.base, self.shift = base, int(shift)

    def __getitem__(self, i: int) -> tuple[tuple[int, int], ...]:
        return tuple((j, s + self.shift) for j, s in self.base[i])

    def __len__(self) -> int:
        return len(self.base)

    def __iter__(self) -> Any:
        return (self[i] for i in range(len(self.base)))


def _operator(
    g: FloatArray,
    q: FloatArray,
    M11: FloatArray,
    F_list: list[FloatArray],
    Lb: FloatArray,
    S: FloatArray,
    ex: np.ndarray,
    cols: np.ndarray,
    own: list[np.ndarray],
    b: list[np.ndarray],
    zidx: np.ndarray,
    rr: np.ndarray,
    nz: int,
    dim: int,
) -> FloatArray:
    """𝓜 with J_k = ⟨𝓜, cov z(k)⟩ for fixed gains g and fills: err = Φ₀ z - G D Ψ z (module docstring)."""
    R = cols.size
    Gd = np.zeros((nz, R))
    Gd[zidx, rr] = g
    Hz = np.zeros((R, dim))
    Uz = np.zeros((R, dim))
    Uz[np.arange(R), cols] = 1.0
    for i, Fi in enumerate(F_list):
        if b[i].size and own[i].size:
            Hz[np.ix_(b[i], own[i])] = Fi
    Ee = np.zeros((ex.size, dim))
    Ee[np.arange(ex.size), ex] = 1.0
    Phi0 = Lb @ Ee - Gd @ Hz
    Psi = Uz - Hz
    SG = S @ Gd
    cr = Phi0.T @ (SG * q[None, :]) @ Psi
    Mop = Phi0.T @ S @ Phi0 - cr - cr.T + Psi.T @ ((Gd.T @ SG) * M11) @ Psi
    return 0.5 * (Mop + Mop.T)  # type: ignore[no-any-return]


def estimate(dy: Any, ell: Any, prob: Any, T: int, memory: int, dx: int, dz: int, coords_x: bool = True) -> tuple[float, float, float]:
    """(peak bytes, flops, Python loop iterations) of :func:`solve`, counted without assuming it becomes steady."""
    dy_a = np.asarray(dy, dtype=float)
    n = dy_a.size
    dyt = float(dy_a.sum())
    m = int(memory)
    live = np.asarray(prob) > 0
    lmax = int(np.max(np.where(live, ell, 0)))
    W = window_steps(m, lmax)
    dim = (n + 1) * dx + W * dyt
    Rk = Sk = F = 0.0  # live rows, live slots, kept fill numbers per step
    for i in range(n):
        rows_i = 0.0
        for j in range(n):
            if prob[j, i] > 0:
                c = max(0.0, min(float(m), T - float(ell[j, i])))
                rows_i += dy_a[j] * c
                Sk += c
        Rk += rows_i
        F += rows_i * min(T, 2 * m - 1) * dy_a[i]
    Rz = Rk * dz
    per_step = 8 * (3 * dim * dim + 6 * Rk * Rk + 2 * Rz * Rz + 2 * Rk * dim + Sk * Sk)
    kept = T * (8 * (F + Rz) + 120 * Sk + 400 * n)  # fills, gains and the item tuples of every step (no steady reuse assumed)
    flops = T * (
        Rz**3 / 3 + 12 * Rk * Rk + 2 * Rk * dim * (2 * m - 1) * dyt / max(n, 1) + 4 * dim * (n + 1) * dx * dx + 2 * Rk * Rk * dim / max(n, 1)
    )
    loops = T * (Sk * 20 + 2000)
    return per_step + kept, flops, loops
