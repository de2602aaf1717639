"""A frozen copy of the CIKF design (Algorithm 2) and error recursion as they were before the speed work.

Kept verbatim (renamed only) as the reference the structured implementation in
``teamkf.estimators.cikf`` is pinned against (``test_cikf_reference.py``): the new code must give the
same gains and covariances to 1e-10 relative on small instances. Not imported by the library.
"""

# ruff: noqa
from __future__ import annotations

from typing import Any, Sequence

import numpy as np
import scipy.linalg as sla
from scipy.linalg.lapack import dpstrf

from teamkf.estimators.cikf import PseudoStateModel, _neighbors, pseudo_state_model
from teamkf.models import LinearGaussianSystem, TeamCost

FloatArray = np.ndarray
CIKFDesign = Any


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
            raise FloatingPointError("CIKF gain design: a covariance overflowed (the error dynamics diverge; see tracking_capacity)")
        out = np.zeros_like(S_xy)
        if top <= 0.0:
            return out
        c, piv, rank, _ = dpstrf(S, tol=rcond * top, lower=0)
        if rank == 0:
            return out
        keep = piv[:rank] - 1
        U11 = np.triu(c[:rank, :rank])
        out[:, keep] = sla.cho_solve((U11, False), S_xy[:, keep].T, check_finite=False).T
        return out
    w, Q = sla.eigh(S, driver="evd", check_finite=False)
    top = float(w[-1]) if w.size else 0.0
    if not np.isfinite(top):
        raise FloatingPointError("CIKF gain design: a covariance overflowed (the error dynamics diverge; see tracking_capacity)")
    keep = w > rcond * max(top, np.finfo(float).tiny)
    Qk = Q[:, keep]
    return ((S_xy @ Qk) / w[keep]) @ Qk.T  # type: ignore[no-any-return]


def _sym(X: FloatArray) -> FloatArray:
    X += X.T
    X *= 0.5
    return X


class _Structured:
    """Block products that never form an NM x NM operator: M_k by closed neighbourhoods, the rest block-diagonally."""

    def __init__(self, N: int, r: int, hoods: Sequence[np.ndarray], r_idx: Sequence[np.ndarray]):
        self.N, self.r, self.hoods, self.r_idx = N, r, hoods, r_idx

    def m_right(self, X: FloatArray, rows: Sequence[FloatArray]) -> FloatArray:
        """X M' (M given by its block rows over closed neighbourhoods)."""
        r = self.r
        out = np.empty((X.shape[0], self.N * r))
        for n, row in enumerate(rows):
            out[:, n * r : (n + 1) * r] = X[:, self.r_idx[n]] @ row.T
        return out

    def m_left(self, rows: Sequence[FloatArray], X: FloatArray) -> FloatArray:
        """M X."""
        r = self.r
        out = np.empty((self.N * r, X.shape[1]))
        for n, row in enumerate(rows):
            out[n * r : (n + 1) * r] = row @ X[self.r_idx[n]]
        return out

    def m_sandwich(self, rows: Sequence[FloatArray], Zt: FloatArray) -> FloatArray:
        """M Z' given Z' (symmetric result M P M' with Z = M P): the upper block triangle, mirrored."""
        r = self.r
        out = np.empty((self.N * r, Zt.shape[1]))
        for n, row in enumerate(rows):
            out[n * r : (n + 1) * r, n * r :] = row @ Zt[self.r_idx[n], n * r :]
        for n in range(1, self.N):
            out[n * r : (n + 1) * r, : n * r] = out[: n * r, n * r : (n + 1) * r].T
        return out

    def bd_left(self, B: FloatArray, X: FloatArray) -> FloatArray:
        """blockdiag(B) X; B is (N, a, b) or one shared (a, b)."""
        b = B.shape[-1]
        C = X.shape[1]
        X3 = np.ascontiguousarray(X).reshape(self.N, b, C)
        return np.matmul(B, X3).reshape(-1, C)  # type: ignore[no-any-return]

    def bd_right(self, X: FloatArray, B: FloatArray) -> FloatArray:
        """X blockdiag(B)'; B is (N, a, b) or one shared (a, b)."""
        Rr = X.shape[0]
        b = B.shape[-1]
        X3 = np.ascontiguousarray(X).reshape(Rr, self.N, b)
        if B.ndim == 2:
            return (X3.reshape(-1, b) @ B.T).reshape(Rr, -1)  # type: ignore[no-any-return]
        a = B.shape[1]
        out = np.empty((Rr, self.N * a))
        for n in range(self.N):  # strided column blocks go to BLAS without copies
            out[:, n * a : (n + 1) * a] = X[:, n * b : (n + 1) * b] @ B[n].T
        return out


def _diag_blocks(X: FloatArray, N: int, a: int) -> FloatArray:
    """The N diagonal a x a blocks of an Na x Na matrix, (N, a, a)."""
    X4 = X.reshape(N, a, N, a)
    return np.ascontiguousarray(X4[np.arange(N), :, np.arange(N), :])


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
    return all(np.array_equal(cost.S_at(k), np.eye(N * M)) and all(np.array_equal(cost.L_block(n, k), np.eye(M)) for n in range(N)) for k in steps)


def _theorem4_pseudo(
    P: FloatArray, n: int, nb: Sequence[int], r: int, Ct: FloatArray, Rn: FloatArray, rcond: float, how: str
) -> tuple[FloatArray, FloatArray]:
    """Theorem 4's B̂^n = Σ_{eν̃} Σ_ν̃^+ in reduced coordinates: returns (B_cons (r, d r), B_u (r, M_n))."""
    d, mn = len(nb), Ct.shape[0]
    dr = d * r
    Pnn = P[n * r : (n + 1) * r, n * r : (n + 1) * r]
    Snu = np.empty((dr + mn, dr + mn))
    Sey = np.empty((r, dr + mn))
    if d:
        li = np.concatenate([np.arange(l * r, (l + 1) * r) for l in nb])
        Pnl = P[n * r : (n + 1) * r, li]  # [P^{n l_1} ... P^{n l_d}]; P^{l n} = (P^{n l})' (P symmetric)
        Pll = P[np.ix_(li, li)]
        # [Σ_ν̃]_{qs} = P^{nn} - P^{n l_s} - P^{l_q n} + P^{l_q l_s}
        Snu[:dr, :dr] = np.tile(Pnn, (d, d)) - np.tile(Pnl, (d, 1)) - np.tile(Pnl.T, (1, d)) + Pll
        # [Σ_ν̃]_{q,u} = (P^{nn} - P^{l_q n}) C̃_n'
        Snu[:dr, dr:] = (np.tile(Pnn, (d, 1)) - Pnl.T) @ Ct.T
        Snu[dr:, :dr] = Snu[:dr, dr:].T
        Sey[:, :dr] = np.tile(Pnn, (1, d)) - Pnl  # E[e^n (e^n - e^{l_q})'] = P^{nn} - P^{n l_q}
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
    GVG, GV, VV = np.tile(Gr @ Vq @ Gr.T, (N, N)), np.tile(Gr @ Vq, (N, N)), np.tile(Vq, (N, N))
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
                Bc, Bu = _theorem4_pseudo(P, n, nbrs[n], r, Ct[n], Rn[n], rcond, pinv)
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
        Z = ops.m_left(rows, P)  # M P; P M' = Z' (P symmetric)
        Pf = ops.m_sandwich(rows, np.ascontiguousarray(Z.T))  # M P M', symmetric by construction
        del Z
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
        Pft += ops.bd_right(Pf, Kk)
        L1 = ops.bd_left(F, Sig)
        L1 += ops.bd_left(Kk, Pt if p43 else Gt)  # F Σ + K Γ'
        if p43:  # the extracted (43): Π_{k|k-1} in both cross terms
            Sf = ops.bd_right(L1, F) + ops.bd_left(Kk, ops.bd_right(Pt, F) + ops.bd_right(Pf, Kk))
        else:  # exact: L1 F' + Π_f K' = L1 F' + (K Π_f')'
            Sf = ops.bd_right(L1, F)
            Sf += ops.bd_left(Kk, Pft)
        _sym(Sf)
        Sf_all[k] = _diag_blocks(Sf, N, M)
        if form == "filter":
            stage[k] = _stage_cost(cost, k, Sf, Sf_all[k], mse_like, ops)
        if k + 1 == T:
            break
        # --- (45)*: P' = Ã P_f Ã' + 2 sym(Ã Π_f' Ǎ') + Ǎ Σ_f Ǎ' ; (47): Π'' = (Ã Π_f' + Ǎ Σ_f) A' ; (46) ---
        Yx = ops.bd_left(At, Pft)  # Ã Π_f'   (Nr x NM)
        P = ops.bd_right(ops.bd_left(At, Pf), At)
        if p45:  # the extracted (45): Ã (acting on x-quantities: Ã_r U') in every term
            Ax = At @ model.U.T
            P += 2.0 * ops.bd_right(Yx, Ax) + ops.bd_right(ops.bd_left(Ax, Sf), Ax)
        if not chk.zero:
            AcS = chk.left(ops, Sf)  # Ǎ Σ_f
            if not p45:
                P += 2.0 * chk.right(ops, Yx) + chk.right(ops, AcS)
            Yx += AcS
        _sym(P)
        P += GVG
        Pt = ops.bd_right(Yx, A)
        Pt += GV
        Sig = ops.bd_right(ops.bd_left(A, Sf), A)  # symmetric to round-off (Σ_f is symmetrized)
        Sig += VV
        if not (np.isfinite(P[0, 0]) and np.isfinite(Sig[0, 0])):
            raise FloatingPointError(
                f"CIKF gain design: the error covariances overflowed at step {k + 1}; the error dynamics diverge (see tracking_capacity)"
            )
    return {
        "B_cons": tuple(B_cons),
        "B_innov": tuple(B_innov),
        "K": K_all,
        "Sigma_pred": Sp,
        "Sigma_filt": Sf_all,
        "P_pred_trace": Ptr,
        "stage": stage,
    }


def recursion_impl(self, ys: Sequence[FloatArray] | None, x0: FloatArray | None, w: FloatArray | None, n_runs: int, T: int, form: str) -> FloatArray:
    """Algorithm 1 on data (``ys``) or its error recursion (30)-(33) on the primitive noises (x0, w, ys = v).

    Agent-major layout (N, n_runs, .) so that every per-agent product is a contiguous GEMM.
    """
    m, sys, cost = self.model, self.system, self.cost
    N, M, r = self.n_agents, sys.dx, m.rank
    A = sys.A_at(0)
    errors = x0 is not None
    if errors:
        yh = np.repeat((x0 @ m.G_r.T)[None], N, axis=0)  # type: ignore[index]  # e^n_{0|-1} = G_r (x0 - x̄0)
        xh = np.repeat(x0[None], N, axis=0)  # type: ignore[index]  # ε^n_{0|-1}
    else:
        yh = np.zeros((N, n_runs, r))  # ŷ^n_{0|-1} = G_r x̄_0 = 0
        xh = np.zeros((N, n_runs, M))
    dz = cost.dz
    identity_L = dz == M and all(
        np.array_equal(cost.L_block(n, k), np.eye(M)) for n in range(N) for k in range(min(T, 1 if not cost.is_time_varying else T))
    )
    out = np.empty((n_runs, T, N * dz))
    sign = -1.0 if errors else 1.0
    for k in range(T):
        Bc_k, Bu_k = self.B_cons[k], self.B_innov[k]
        yf = np.empty_like(yh)
        for n in range(N):
            nb = self.neighbors[n]
            own = yh[n]
            # innovation u^n = y_n - C̃_n ŷ^n (data)  |  C̃_n e^n + v_n (errors)
            if errors:
                u = own @ m.C_tilde[n].T + ys[n][:, k]  # type: ignore[index]
            else:
                u = ys[n][:, k] - own @ m.C_tilde[n].T  # type: ignore[index]
            acc = u @ Bu_k[n].T
            if sign < 0:
                np.negative(acc, out=acc)
            acc += own
            if nb:
                # consensus + Σ_l B^{nl} (ŷ^l - ŷ^n) on data, + Σ_l B^{nl} (e^l - e^n) on errors (same sign)
                Bc = Bc_k[n]
                acc -= own @ Bc.reshape(r, len(nb), r).sum(axis=1).T
                for q, l in enumerate(nb):
                    acc += yh[l] @ Bc[:, q * r : (q + 1) * r].T
            yf[n] = acc
        # ν = ŷ_f - G_r x̂ (data) | G_r ε - e_f (errors);  x̂_f = x̂ + K ν | ε_f = ε - K ν
        nu = xh @ m.G_r.T
        if errors:
            nu -= yf
        else:
            np.subtract(yf, nu, out=nu)
        corr = np.matmul(nu, self.K[k].transpose(0, 2, 1))  # (N, R, M)
        xf = xh - corr if errors else xh + corr
        src = xf if form == "filter" else xh
        if identity_L:
            out[:, k] = src.transpose(1, 0, 2).reshape(n_runs, N * M)
        else:
            for n in range(N):
                out[:, k, n * dz : (n + 1) * dz] = src[n] @ cost.L_block(n, k).T
        if k + 1 < T:
            yh = yf @ m.A_tilde_r.T
            if m.rank < M:
                yh += xf @ m.A_check_r.T
            xh = xf @ A.T
            if errors:
                yh += w[:, k] @ m.G_r.T  # type: ignore[index]
                xh += w[:, k]  # type: ignore[index]
    return out


def reference_iterate(
    system: Any,
    graph: Any,
    T: int,
    *,
    cost: Any,
    form: str,
    rcond: float = 1e-9,
    pinv: str = "cholesky",
    equations: str = "corrected",
    fixed: Any = None,
) -> dict[str, Any]:
    """Algorithm 2 as the pre-change code ran it (structured products, one BLAS call per block)."""
    model = pseudo_state_model(system)
    N = system.n_agents
    nbrs = _neighbors(graph, N)
    r = model.rank
    hoods = [np.array([n, *nbrs[n]], dtype=int) for n in range(N)]
    r_idx = [np.concatenate([np.arange(l * r, (l + 1) * r) for l in h]) for h in hoods]
    ops = _Structured(N, r, hoods, r_idx)
    return _iterate(system, model, nbrs, cost, T, rcond, form, ops, fixed, equations, pinv)
