r"""Algorithm 2 on the joint covariance J = cov([e; ε]) (``method="joint"``, the corrected equations).

The update (41)-(42) is M_k on the e-rows of J; (43)-(47) collapse into one (r + M) x (r + M) map per agent,
Φ^n = [[Ã + Ǎ K^n, Ǎ F^n], [A K^n, A F^n]], applied on both sides of J (upper block triangle only, in place),
plus the noise terms (1 1ᵀ) ⊗ (G V G), (1 1ᵀ) ⊗ V, (1 1ᵀ) ⊗ (V G). The same covariances and costs as
:mod:`.recursion` to ~1e-12 (``tests/unit/test_cikf_joint.py``).
"""

from __future__ import annotations

from typing import Any, Callable, Sequence

import numpy as np

from ..._validation import FloatArray
from ...exceptions import DivergenceError
from ...models import LinearGaussianSystem, TeamCost
from .filter import CIKFDesign
from .gains import _psd_solve, _theorem4_pseudo
from .kernels import _schedules, _sym
from .model import PseudoStateModel
from .recursion import _is_mse

__all__ = []


#: width of the column panels of the M_k products (columns; fixed, so that the numbers do not depend on the
#: thread count): the panel of J's e-rows stays in the cache, and there are enough panels to share
_PANEL_COLS = 512


#: largest (M_k P)' kept as a separate array by method="joint" (bytes): 37 MiB at M = N = 50, 489 MiB at 100
_MPT_BYTES = 256 * 2**20


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
