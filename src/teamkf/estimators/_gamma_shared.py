"""Gamma F = eta in innovation coordinates when every source measures with the same sensor.

:class:`~teamkf.estimators.gamma.InnovationsProblem` runs every agent's Kalman filter over its local
window data with dense k x d_x matrices per step (H, K and a Woodbury factor), k = the agent's rows at
that step. In the steady platoon every vehicle measures all positions (C_j = I, R_j = r I), the
window is the common lag c = n - 1 long and agent i holds the whole block y_j(s) of every vehicle j
it has heard from: k grows to n^2 rows, those matrices take 24 d_x sum_i d_i bytes (2.6 GB at n = 40)
and one application of the operator costs n w k d_x ~ n^5 flops (92 s of CPU at n = 40).

Here the window's sources p = 0..n_s-1 all measure y_p(u) = C(u) eps(u) + v_p(u) with one C(u) and
one R(u) (v_p independent), and each agent's local data at step u is a set J of whole source blocks
(m = |J|). Then, with H = 1_m (x) C and R_J = I_m (x) R,

* the filter is that of the mean of the m blocks, C eps + v-bar with covariance R / m:
  K-bar = P C' (C P C' + R/m)^-1, the gain on each block is K_p = K-bar / m and I - K H = I - K-bar C,
  so the filter stores d_x x d_x and d_x x d_y0 matrices per step, whatever m;
* every product with H or K is a sum over the blocks followed by one small product
  (sum_p g_p C, (sum_p v_p) K_p'), O(k + d_y0 d_x) per row instead of O(k d_x);
* N = I_m (x) R + 1 1' (x) C P C' has N^-1 = I_m (x) R^-1 + 1 1' (x) Y with
  Y = -(R + m C P C')^-1 C P C' R^-1 (the exact block-Jacobi preconditioner, O(k) per row).

All agents run in lockstep on padded arrays (step u, agent i, row a of z, source p, row of the
block), the blocks an agent does not hold kept at zero, so a pass over the window is a loop over the
w steps of batched products: O(n w (n_s d_y0 + d_x^2)) per application of the operator (n^4 for the
platoon) and a few such arrays of memory. The mathematics, the CG iterations and the answers are
those of :class:`~teamkf.estimators.gamma.InnovationsProblem` (same coordinates, same ordering of
the unknowns within an agent, the same preconditioner) up to round-off.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .._blas import single_thread_blas
from .._validation import FloatArray
from ..exceptions import ArgumentError, ConvergenceError, NotPositiveDefiniteError

__all__ = ["SharedSensorWindow", "SharedSensorInnovations", "shared_sensor_window"]

# noise rows of all agents: (eps(0): (n_a, dz, dx), w: (w-1, n_a, dz, dx), v: (w, n_a, dz, n_s, m0))
_Noise = tuple[FloatArray, FloatArray, FloatArray]


@dataclass(eq=False)
class SharedSensorWindow:
    """The window u = 0..w-1 of n_s sources that all measure y_p(u) = C[u] eps(u) + v_p(u), v_p(u) ~ N(0, R[u]).

    eps(u+1) = A[u] eps(u) + w(u), w(u) ~ N(0, Q[u]), eps(0) ~ N(0, P0). The pool (as for
    :class:`~teamkf.estimators.gamma.GammaProblem`) is vec over u of (y_0(u), ..., y_{n_s-1}(u)):
    row r of source p at step u sits at u n_s d_y0 + p d_y0 + r.
    """

    A: list[FloatArray]
    Q: list[FloatArray]
    C: list[FloatArray]
    R: list[FloatArray]
    P0: FloatArray
    n_src: int

    @property
    def steps(self) -> int:
        return len(self.C)


def shared_sensor_window(system: Any, anchor: int, w: int, P_anchor: FloatArray) -> SharedSensorWindow | None:
    """The window of ``system`` from ``anchor`` over ``w`` steps, or None unless every agent has agent 0's C_i and R_i at every step."""
    n = system.n_agents
    C, R = [], []
    for u in range(w):
        s = anchor + u
        C0, R0 = np.asarray(system.C_at(0, s), dtype=float), np.asarray(system.R_at(0, s), dtype=float)
        if not all(np.array_equal(system.C_at(j, s), C0) and np.array_equal(system.R_at(j, s), R0) for j in range(1, n)):
            return None
        C.append(C0)
        R.append(R0)
    return SharedSensorWindow(
        A=[np.asarray(system.A_at(anchor + u), dtype=float) for u in range(w - 1)],
        Q=[np.asarray(system.Q_at(anchor + u), dtype=float) for u in range(w - 1)],
        C=C,
        R=R,
        P0=np.asarray(P_anchor, dtype=float),
        n_src=n,
    )


def block_mask(idx: list[np.ndarray], w: int, n_src: int, m0: int) -> np.ndarray | None:
    """(n_a, w, n_s) bool: agent i holds block (u, p); None unless every agent's idx is a set of whole blocks (no repeats)."""
    dy = n_src * m0
    mask = np.zeros((len(idx), w, n_src), dtype=bool)
    for i, ix in enumerate(idx):
        ix = np.asarray(ix, dtype=int)
        if ix.size == 0:
            continue
        if ix.min() < 0 or ix.max() >= w * dy or np.unique(ix).size != ix.size:
            return None
        counts = np.bincount(ix // m0, minlength=w * n_src)
        if np.any((counts != 0) & (counts != m0)):
            return None
        mask[i] = (counts > 0).reshape(w, n_src)
    return mask


def _diagonals(S: FloatArray) -> list[tuple[int, FloatArray]] | None:
    """The nonzero diagonals (d, s) of S, s[r] = S[r, r + d] (main diagonal first), or None when there are many."""
    R = S.shape[0]
    rows, cols = np.nonzero(S)
    offsets = sorted(set((cols - rows).tolist()), key=lambda d: (d != 0, abs(d), d))
    if len(offsets) > max(3, R // 8) or (offsets and offsets[0] != 0):
        return None
    out = []
    for d in offsets:
        s = np.zeros(R)
        r = np.arange(max(0, -d), R - max(0, d))
        s[r] = S[r, r + d]
        out.append((d, s))
    return out


def _sym_inv(M: FloatArray, what: str) -> FloatArray:
    try:
        Lc = np.linalg.cholesky(0.5 * (M + np.swapaxes(M, -1, -2)))
    except np.linalg.LinAlgError:
        raise NotPositiveDefiniteError(f"Gamma: {what} is not positive definite; check R_i > 0") from None
    Li = np.linalg.inv(Lc)
    return np.swapaxes(Li, -1, -2) @ Li


@dataclass(eq=False)
class SharedSensorInnovations:
    """MTMSE gains of one window step by CG in the agents' innovation coordinates, shared sensors (module docstring).

    Parameters
    ----------
    S : (n d_z, n d_z) array
    L : (n d_z, d_x) array
    window : SharedSensorWindow
    idx : list of int arrays
        Agent i's local measurements as positions in the window pool, whole source blocks
        (:func:`block_mask`; the positions of the team designs).
    dz : int
    """

    S: FloatArray
    L: FloatArray
    window: SharedSensorWindow
    idx: list[np.ndarray]
    dz: int
    iterations: int = field(default=0, init=False)
    method_used: str = field(default="cg", init=False)

    def __post_init__(self) -> None:
        win = self.window
        self.n = len(self.idx)
        self.w, self.dx, self.n_src = win.steps, win.P0.shape[0], win.n_src
        self.m0 = win.C[0].shape[0]
        mask = block_mask(self.idx, self.w, self.n_src, self.m0)
        if mask is None:
            raise ArgumentError(
                "idx: expected every agent's local data to be whole blocks y_p(u) of the window, found a partial or repeated block",
                argument="idx",
            )
        self.mask = mask
        self.d = mask.sum(axis=(1, 2)) * self.m0
        self.D_loc = int(self.d.sum())
        self.shape = (self.w, self.n, self.dz, self.n_src, self.m0)
        mk = np.ascontiguousarray(mask.transpose(1, 0, 2), dtype=float)  # (w, n_a, n_s)
        self._mk = mk[:, :, None, :, None]  # broadcasts against (w, n_a, dz, n_s, m0)
        self._diags = _diagonals(np.asarray(self.S, dtype=float))
        self.Cs = np.stack([np.asarray(C, dtype=float) for C in win.C])  # (w, m0, dx)
        self.CsT = np.ascontiguousarray(np.swapaxes(self.Cs, 1, 2))
        self.As = np.stack(win.A) if self.w > 1 else np.zeros((0, self.dx, self.dx))
        self.AsT = np.ascontiguousarray(np.swapaxes(self.As, 1, 2))
        self.Qs = np.stack(win.Q) if self.w > 1 else np.zeros((0, self.dx, self.dx))
        self.Rs = np.stack([np.asarray(R, dtype=float) for R in win.R])  # (w, m0, m0)
        diag = all(not np.any(R - np.diag(np.diag(R))) for R in self.Rs)
        self._Rd = np.stack([np.diag(R) for R in self.Rs])[:, None, None, None, :] if diag else None  # (w, 1, 1, 1, m0)
        with single_thread_blas():
            self._filter()

    @property
    def size(self) -> int:
        return self.dz * self.D_loc

    def _filter(self) -> None:
        """Every agent's filter over the window, batched: G = I - K-bar C, K_p = K-bar / m, Y (module docstring)."""
        win, n, w, dx, m0 = self.window, self.n, self.w, self.dx, self.m0
        counts = self.mask.sum(axis=2)  # (n_a, w)
        I = np.eye(dx)
        P = np.broadcast_to(np.asarray(win.P0, dtype=float), (n, dx, dx)).copy()
        self.G = np.broadcast_to(I, (w, n, dx, dx)).copy()
        self.Kp = np.zeros((w, n, dx, m0))
        self.Y = np.zeros((w, n, m0, m0))
        self.R_inv = [_sym_inv(R, "a measurement noise covariance R_i") for R in win.R]
        for u in range(w):
            C, R = win.C[u], win.R[u]
            act = np.nonzero(counts[:, u])[0]
            if act.size:
                m = counts[act, u].astype(float)[:, None, None]
                Pa = P[act]
                CP = C @ Pa  # (a, m0, dx)
                M0 = CP @ C.T  # C P C'
                Nbar_inv = _sym_inv(M0 + R / m, "an agent's innovation covariance")
                Kbar = np.swapaxes(Nbar_inv @ CP, 1, 2)  # P C' (C P C' + R/m)^-1
                Gu = I - Kbar @ C
                Pn = Gu @ Pa @ np.swapaxes(Gu, 1, 2) + Kbar @ (R / m) @ np.swapaxes(Kbar, 1, 2)  # Joseph form
                P[act] = 0.5 * (Pn + np.swapaxes(Pn, 1, 2))
                self.G[u, act] = Gu
                self.Kp[u, act] = Kbar / m
                self.Y[u, act] = -(Nbar_inv / m) @ M0 @ self.R_inv[u]  # -(R + m C P C')^-1 C P C' R^-1
            if u < w - 1:
                A = win.A[u]
                P = A @ P @ A.T + win.Q[u]
                P = 0.5 * (P + np.swapaxes(P, 1, 2))
        self.R_inv_s = np.stack(self.R_inv)
        self._count = np.ascontiguousarray(counts.T, dtype=float)  # (w, n_a)
        self.GT = np.ascontiguousarray(np.swapaxes(self.G, 2, 3))
        self.KpT = np.ascontiguousarray(np.swapaxes(self.Kp, 2, 3))

    # --- the filters as maps between noise coordinates and innovations ----------
    # Each pass is one loop over the window of small batched products (d_x-sized rows per agent); the
    # products over the padded (w, n_a, dz, n_s, m0) arrays are made once, outside the loop.
    def _forward(self, psi: _Noise) -> FloatArray:
        """Innovations of every agent (padded, shape ``self.shape``) for the noise rows psi."""
        e0, wn, vn = psi
        vr = vn * self._mk
        vsum = vr.sum(axis=3)  # (w, n_a, dz, m0): the blocks each agent holds, summed
        xiC = np.empty(vsum.shape)
        xi = e0  # eps(u) - x^_i(u|u-1), rows (n_a, dz, dx)
        for u in range(self.w):
            np.matmul(xi, self.CsT[u], out=xiC[u])
            xi = xi @ self.GT[u] - vsum[u] @ self.KpT[u]
            if u < self.w - 1:
                xi = xi @ self.AsT[u] + wn[u]
        vr += xiC[:, :, :, None, :] * self._mk
        return vr

    def _adjoint(self, phi: FloatArray | None, terminal: FloatArray) -> _Noise:
        """Noise sensitivities of phi e_i + terminal (eps(w-1) - x^_i(w-1|w-1)), rows (n_a, dz)."""
        w = self.w
        wn = np.empty((max(w - 1, 0), self.n, self.dz, self.dx))
        lk = np.empty((w, self.n, self.dz, self.m0))
        gC = None if phi is None else np.matmul(phi.sum(axis=3), self.Cs[:, None])  # (w, n_a, dz, dx)
        lam = terminal
        for u in range(w - 1, -1, -1):
            if u < w - 1:
                wn[u] = lam
                lp = lam @ self.As[u]
            else:
                lp = terminal
            np.matmul(lp, self.Kp[u], out=lk[u])
            lam = lp @ self.G[u]
            if gC is not None:
                lam += gC[u]
        vn = lk[:, :, :, None, :] * self._mk
        if phi is not None:
            np.subtract(phi, vn, out=vn)
        else:
            np.negative(vn, out=vn)
        return lam, wn, vn

    def _data_adjoint(self, phi: FloatArray, terminal: FloatArray) -> FloatArray:
        """Coefficients on every agent's local data (padded) of phi e_i + terminal x^_i(w-1|w-1)."""
        w = self.w
        gC = np.matmul(phi.sum(axis=3), self.Cs[:, None])  # (w, n_a, dz, dx)
        kk = np.empty((w, self.n, self.dz, self.m0))
        mu = terminal
        for u in range(w - 1, -1, -1):
            mp = terminal if u == w - 1 else mu @ self.As[u]
            np.matmul(mp, self.Kp[u], out=kk[u])
            mu = mp - gC[u] - (kk[u] * self._count[u][:, None, None]) @ self.Cs[u]  # the m held blocks each add mp K_p
        out = kk[:, :, :, None, :] * self._mk
        out += phi
        return out

    def _mix(self, X: FloatArray) -> FloatArray:
        """S applied to the rows (agent, a) of X (T, n_a, dz, ...): by its nonzero diagonals when S is banded."""
        T, R = X.shape[0], self.n * self.dz
        Xr = X.reshape(T, R, -1)
        if self._diags is None:
            return np.matmul(np.asarray(self.S, dtype=float), Xr).reshape(X.shape)
        out = np.empty_like(Xr)
        for t, (d, s) in enumerate(self._diags):
            lo, hi = max(0, -d), R - max(0, d)
            if t == 0:  # the main diagonal (S_ii > 0) first
                np.multiply(Xr, s[:, None], out=out)
            else:
                out[:, lo:hi] += Xr[:, lo + d : hi + d] * s[lo:hi, None]
        return out.reshape(X.shape)

    def _times_R(self, V: FloatArray) -> FloatArray:
        """V (w, n_a, dz, n_s, m0) times R(u) on every block."""
        if self._Rd is not None:
            V *= self._Rd
            return V
        return np.matmul(V, self.Rs[:, None, None])

    def _weight(self, psi: _Noise, mix: bool = True) -> _Noise:
        """S psi Lambda, Lambda = blockdiag(P0, Q, R): the noise covariance."""
        e0, wn, vn = psi
        if mix:
            e0, wn, vn = self._mix(e0[None])[0], self._mix(wn), self._mix(vn)
        else:
            vn = vn.copy()
        return e0 @ self.window.P0, np.matmul(wn, self.Qs[:, None]), self._times_R(vn)

    def _noise_cost(self, X: _Noise) -> float:
        """sum Tr(S X Lambda X') over the noise blocks: non-negative terms, no cancellation."""
        XL = self._weight(X, mix=False)
        J = float(np.sum(self._mix(XL[0][None])[0] * X[0]))
        J += float(np.sum(self._mix(XL[1]) * X[1]))
        J += float(np.sum(self._mix(XL[2]) * X[2]))
        return J

    def apply_flat(self, x: FloatArray) -> FloatArray:
        """Gamma^ x in innovation coordinates (padded vector, zero off the agents' blocks)."""
        Fhat = x.reshape(self.shape)
        return self._forward(self._weight(self._adjoint(Fhat, np.zeros((self.n, self.dz, self.dx))))).ravel()

    def _precondition(self, v: FloatArray) -> FloatArray:
        """Block Jacobi S_ii^-1 X blockdiag_u(N_i(u)^-1) = Gamma^_ii^-1."""
        X = v.reshape(self.shape)
        corr = np.matmul(X.sum(axis=3), self.Y)  # (w, n_a, dz, m0): (sum_q X_q) Y
        if self._Rd is not None:
            out = X / self._Rd
        else:
            out = np.matmul(X, self.R_inv_s[:, None, None])
        out += corr[:, :, :, None, :] * self._mk
        if self.dz == 1:
            out *= self._S_inv[:, 0, 0][None, :, None, None, None]
        else:
            out = np.einsum("iab,uibpr->uiapr", self._S_inv, out)
        return out.ravel()

    # --- the operator and the preconditioner for CG: in place, few passes ---------
    def _setup_cg(self) -> None:
        """Buffers and folded coefficients of :meth:`_apply_into` (banded S, diagonal R) and :meth:`_precondition_into`."""
        dz, n = self.dz, self.n
        self._S_inv = np.stack([np.linalg.inv(self.S[i * dz : (i + 1) * dz, i * dz : (i + 1) * dz]) for i in range(n)])
        diags, Rd_full = self._diags, self._Rd
        self._fast = diags is not None and Rd_full is not None
        self._buf = [np.empty(self.shape) for _ in range(2)]
        if diags is not None and Rd_full is not None:
            Rd = Rd_full[:, 0, 0]  # (w, 1, m0)
            same = bool(np.all(Rd == Rd[:1]))
            Rd = Rd[:1] if same else Rd
            # S_ij R(u) on the rows (agent, a): coefficient of the diagonal d, broadcast against (w, n_a dz, n_s, m0)
            self._coef = [(d, sd[None, :, None, None] * Rd[:, None]) for d, sd in diags]
            if dz == 1:  # S_ii^-1 R(u)^-1, and S_ii^-1 for the rank-one correction
                sinv = self._S_inv[:, 0, 0]
                self._pc1 = sinv[None, :, None, None, None] / Rd_full
                self._pc2 = sinv[None, :, None, None]

    def _mix_R_into(self, X: FloatArray, out: FloatArray, tmp: FloatArray) -> None:
        """out = S X R (R on every block), by the diagonals of S with R folded in."""
        T, R = X.shape[0], self.n * self.dz
        Xr, Or, Tr = X.reshape(T, R, self.n_src, -1), out.reshape(T, R, self.n_src, -1), tmp.reshape(T, R, self.n_src, -1)
        for t, (d, c) in enumerate(self._coef):
            lo, hi = max(0, -d), R - max(0, d)
            if t == 0:
                np.multiply(Xr, c, out=Or)
            else:
                np.multiply(Xr[:, lo + d : hi + d], c[:, lo:hi], out=Tr[:, lo:hi])
                Or[:, lo:hi] += Tr[:, lo:hi]

    def _apply_into(self, x: FloatArray, out: FloatArray) -> None:
        """out = Gamma^ x (as :meth:`apply_flat`) with two work arrays and about twelve passes over them."""
        if not self._fast:
            out[:] = self.apply_flat(x)
            return
        w, mk = self.w, self._mk
        F = x.reshape(self.shape)
        V, W = self._buf
        # adjoint: noise sensitivities of F e (no terminal term)
        gC = np.matmul(F.sum(axis=3), self.Cs[:, None])  # (w, n_a, dz, dx)
        lk = np.empty((w, self.n, self.dz, self.m0))
        wn = np.empty((max(w - 1, 0), self.n, self.dz, self.dx))
        lam = np.zeros((self.n, self.dz, self.dx))
        for u in range(w - 1, -1, -1):
            if u < w - 1:
                wn[u] = lam
                lp = lam @ self.As[u]
            else:
                lp = lam
            np.matmul(lp, self.Kp[u], out=lk[u])
            lam = lp @ self.G[u] + gC[u]
        np.multiply(lk[:, :, :, None, :], mk, out=V)
        np.subtract(F, V, out=V)
        # weight: S (.) Lambda
        e0 = self._mix(lam[None])[0] @ self.window.P0
        wn = np.matmul(self._mix(wn), self.Qs[:, None])
        self._mix_R_into(V, W, out.reshape(self.shape))
        # forward: the agents' innovations
        np.multiply(W, mk, out=W)
        vsum = W.sum(axis=3)
        xiC = np.empty(vsum.shape)
        xi = e0
        for u in range(w):
            np.matmul(xi, self.CsT[u], out=xiC[u])
            xi = xi @ self.GT[u] - vsum[u] @ self.KpT[u]
            if u < w - 1:
                xi = xi @ self.AsT[u] + wn[u]
        E = out.reshape(self.shape)
        np.multiply(xiC[:, :, :, None, :], mk, out=E)
        E += W

    def _precondition_into(self, v: FloatArray, out: FloatArray) -> None:
        """out = block Jacobi S_ii^-1 X blockdiag_u(N_i(u)^-1) applied to v."""
        if not (self._fast and self.dz == 1):
            out[:] = self._precondition(v)
            return
        X, O = v.reshape(self.shape), out.reshape(self.shape)
        corr = np.matmul(X.sum(axis=3), self.Y)  # (w, n_a, 1, m0)
        corr *= self._pc2
        np.multiply(X, self._pc1, out=O)
        T = self._buf[0]
        np.multiply(corr[:, :, :, None, :], self._mk, out=T)
        O += T

    def _pcg(self, b: FloatArray, rtol: float, maxiter: int) -> tuple[FloatArray, int]:
        """Preconditioned CG as scipy.sparse.linalg.cg (same iterates, same stopping rule), in place: (x, 0 or maxiter)."""
        from .._lazy import scipy_linalg as sla

        axpy, dot, nrm2 = sla.get_blas_funcs(("axpy", "dot", "nrm2"), (b,))
        atol = rtol * float(nrm2(b))
        x, r = np.zeros_like(b), b.copy()
        z, p, q = np.empty_like(b), np.empty_like(b), np.empty_like(b)
        rho_prev = 1.0
        for it in range(maxiter):
            if float(nrm2(r)) < atol:
                self.iterations = it
                return x, 0
            self._precondition_into(r, z)
            rho = float(dot(r, z))
            if it == 0:
                p[:] = z
            else:
                p *= rho / rho_prev
                p += z
            self._apply_into(p, q)
            alpha = rho / float(dot(p, q))
            axpy(p, x, a=alpha)
            axpy(q, r, a=-alpha)
            rho_prev = rho
        self.iterations = maxiter
        return x, maxiter

    # --- solving -------------------------------------------------------------
    def solve(self, *, rtol: float = 1e-12, max_iter: int | None = None) -> tuple[list[FloatArray], float]:
        """Gains F_i on the local data (idx order, (d_z, d_i) each) and their team cost (on one BLAS thread)."""
        with single_thread_blas():
            return self._solve(rtol, max_iter)

    def _solve(self, rtol: float, max_iter: int | None) -> tuple[list[FloatArray], float]:
        dz, n, dx = self.dz, self.n, self.dx
        Lr = np.asarray(self.L, dtype=float).reshape(n, dz, dx)
        Xi = self._adjoint(None, Lr)  # L_j (eps(k) - x^_j(k|k))
        b = self._forward(self._weight(Xi)).ravel()
        x = np.zeros_like(b)
        if b.size and np.any(b):
            self._setup_cg()
            maxiter = max_iter if max_iter is not None else max(1000, 10 * int(np.sqrt(self.size)))
            x, info = self._pcg(b, rtol, maxiter)
            count = [self.iterations]
            if info != 0:
                res = float(np.linalg.norm(self.apply_flat(x) - b)) / max(float(np.linalg.norm(b)), 1e-300)
                raise ConvergenceError(
                    f"Gamma F = eta (innovation coordinates): conjugate gradients stopped after {count[0]} iterations with relative "
                    f"residual {res:.3g} (asked {rtol:g}); raise max_iter or use method='dense' if Gamma fits in memory"
                )
        Fhat = np.asarray(x).reshape(self.shape)
        Psi = self._adjoint(Fhat, np.zeros((n, dz, dx)))
        J = self._noise_cost((Xi[0] - Psi[0], Xi[1] - Psi[1], Xi[2] - Psi[2]))
        coef = self._data_adjoint(Fhat, Lr)
        F = []
        for i, ix in enumerate(self.idx):
            ix = np.asarray(ix, dtype=int)
            blocks = np.moveaxis(coef[:, i], 1, 0)[:, self.mask[i]]  # (dz, blocks in (u, p) order, m0)
            Fi = np.empty((dz, ix.size))
            Fi[:, np.argsort(ix, kind="stable")] = blocks.reshape(dz, -1)  # time order = increasing pool position
            F.append(Fi)
        return F, J
