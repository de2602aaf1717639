r"""Algorithm 2 of Das & Moura (2016), block-operator form (``method="structured"`` and ``"dense"``).

Each step k computes Theorem 4's gains from the predicted covariances and advances the corrected covariance
iterations (41)-(47) of :mod:`teamkf.estimators.cikf`:
Γ = Π_{k|k-1} M_kᵀ, P_{k|k} = M_k P_{k|k-1} M_kᵀ + B^I D̄_H B^Iᵀ, Σ_{k|k} = F Σ Fᵀ + F Γ Kᵀ + K Γᵀ Fᵀ + K P_{k|k} Kᵀ,
Π_{k|k} = F Γ + K P_{k|k}, then the predictions (45)-(47) (or the printed equations, to quantify the errata).
This arithmetic is the one ``tests/unit/test_cikf_reference.py`` pins entry by entry.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from ..._validation import FloatArray
from ...exceptions import DivergenceError
from ...models import LinearGaussianSystem, TeamCost
from .filter import CIKFDesign
from .gains import _psd_solve, _theorem4_pseudo
from .kernels import _diag_blocks, _schedules, _Structured
from .model import PseudoStateModel

__all__ = []


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
