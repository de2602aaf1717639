"""The linear system Gamma F = eta of Theorems 1-3, solved with its structure.

For gains F_i (d_z x d_i), Radner's stationarity conditions (eq. 33) read

    sum_j S_ij F_j Sigma_ji = S_i. L Theta_i        for every agent i,

i.e. Gamma vec(F) = eta with Gamma_ij = Sigma_ij (x) S_ij (eq. 34; we use the
row-major vec, so our blocks are S_ij (x) Sigma_ij). Gamma is symmetric
positive definite when S > 0 and every Sigma_ii > 0 (Lemma 5).

Every Sigma_ij here is a sub-block of one covariance ``Sigma`` of a *pool* of
measurements (the window y(k-c+1 : k) for filtering), indexed by ``idx[i]``.
That lets Gamma be applied without ever forming it (:meth:`GammaProblem.apply`):
scatter the F_i into a sparse n d_z x D matrix G, then

    (Gamma F)_i = [ S (G Sigma) ]_{rows of i, columns idx[i]},

which costs O(d_z D_loc D + nnz(S) D) and touches blocks with S_ij = 0 not at
all (Remark 8) when S is sparse. Small problems assemble Gamma densely (a
Hadamard product per pair of d_z components, no Kronecker product) and use a
Cholesky factorization; large ones use preconditioned conjugate gradients
with the block-Jacobi preconditioner Gamma_ii^-1 X = S_ii^-1 X Sigma_ii^-1.
``method="auto"`` picks CG when dense Gamma would exceed ``dense_max_bytes``
(1 GiB) or when ~150 operator applications cost fewer flops than the
Cholesky factorization (sparse S, long windows: the 10-vehicle platoon);
dense otherwise (dense S, short windows: the UAV formation). The measured
crossover is in docs/performance.md.

Innovation coordinates (:class:`InnovationsProblem`)
-----------------------------------------------------
For a window of a state-space model (the team designs' Sigma_W) CG runs in
other coordinates. The window innovation y~ = C eps + v carries eps(anchor),
the common predictor's error propagated over the c - 1 steps of the window,
so Sigma_W, eta and Tr(L'SL P_0) grow like ||A^(c-1)||^2 (1e15 for the
18-vehicle platoon, 1e19 at 24) while the cost stays O(n): in float64 the
R-sized part of Sigma_W, the residual of Gamma F = eta and the cost of eq.
(35) are all lost in rounding. Each agent i instead runs its own Kalman
filter over its local window data (prior eps(anchor) ~ N(0, P(anchor))) and
uses its innovations e_i (cov(e_i(u)) = N_i(u), block diagonal in time) and
the estimate z_i = L_i (x^com + x^_i(k|k)) + F^_i e_i. Every quantity is then
of the size of the filter errors: Gamma^_ij = S_ij (x) cov(e_i, e_j), eta^_i
= sum_j S_ij cov(L_j (eps(k) - x^_j(k|k)), e_i), the block-Jacobi preconditioner
S_ii^-1 (x) blockdiag_u N_i(u)^-1 is exact and cheap (Woodbury with the d_x x d_x
filter covariance when R is diagonal), and the operator is applied by one adjoint (backward) and one
forward pass of every agent's filter over the noise coordinates
(eps(anchor), w, v) -- O(n w (d_x^2 + d_x d_y)) per application, no
window-sized matrix at all. The cost is summed over the independent noises
(no cancellation), and the gains are mapped back to the local data
(F_i = L_i B_i + F^_i T_i with B_i, T_i the filter's maps) by one more
backward pass. The designs use this form when :func:`choose_solver` picks
CG and :func:`innovations_pays` (every agent filters the whole state: n w d_x^3
to set up: too much for the UAV formation, d_x = d_y = n with a 2-step window;
little for the platoon, d_x = n against d_y = n^2 measurements per step). When every agent measures
with the same C_i and R_i (the platoons) they run it on the shared sensor instead
(:class:`~teamkf.estimators._gamma_shared.SharedSensorInnovations`: the same answer, no k x d_x matrix).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from .._blas import single_thread_blas
from .._lazy import scipy_linalg as sla  # SciPy / networkx load on first use
from .._lazy import scipy_sparse as sp
from .._lazy import scipy_sparse_linalg as spla
from .._validation import FloatArray
from ..exceptions import ArgumentError, ConvergenceError, NotPositiveDefiniteError

__all__ = ["GammaProblem", "InnovationsProblem", "WindowModel", "choose_solver", "innovations_pays", "DENSE_MAX_BYTES"]

#: dense Gamma is assembled when it needs at most this much memory
DENSE_MAX_BYTES = 1 << 30

Method = Literal["auto", "dense", "cg"]


def _flop_estimates(S: FloatArray, dz: int, D_loc: int, D: int, cg_iterations: int = 150) -> tuple[float, float]:
    N = float(dz * D_loc)
    density = np.count_nonzero(S) / max(S.size, 1)
    nnz_S = float(np.count_nonzero(S)) if density < 0.25 else float(S.size)
    dense = N**3 / 3.0 + 2.0 * N**2
    cg = cg_iterations * 2.0 * (dz * D_loc * float(D) + nnz_S * float(D))
    return dense, cg


def choose_solver(S: FloatArray, idx: list[np.ndarray], dz: int, D: int, method: Method = "auto", dense_max_bytes: int = DENSE_MAX_BYTES) -> str:
    """The solver for Gamma of a pool of dimension D, "dense" or "cg" (from the sizes alone).

    Dense Cholesky unless Gamma would not fit in ``dense_max_bytes`` or ~150 applications of the
    operator are estimated to cost fewer flops than the factorization.
    """
    if method != "auto":
        return method
    D_loc = int(sum(len(ix) for ix in idx))
    if 8 * (dz * D_loc) ** 2 > dense_max_bytes:
        return "cg"
    dense, cg = _flop_estimates(S, dz, D_loc, D)
    return "cg" if cg < dense else "dense"


def innovations_pays(S: FloatArray, idx: list[np.ndarray], dz: int, dx: int, dy: int, w: int) -> bool:
    """Whether CG in innovation coordinates is estimated cheaper than CG on the window covariance.

    Window covariance: 150 applications of 2 (d_z D_loc D + nnz(S) D) flops plus the block-Jacobi
    inverses sum d_i^3 (D = w d_y). Innovations: every agent's filter, n w 12 d_x^3, plus 250
    applications of 12 d_z D_loc d_x + 2 nnz(S) w d_y + 2 n w d_z d_x^2. The platoons (d_x = n,
    d_y = n^2, w = n - 1) take the innovations, the UAV formation (d_x = d_y = n, w = 2) the window.
    """
    d = np.array([len(ix) for ix in idx], dtype=float)
    D_loc, D, n = float(d.sum()), float(w * dy), float(len(idx))
    nnz_S = float(np.count_nonzero(S))
    window = 150 * 2.0 * (dz * D_loc * D + nnz_S * D) + float(np.sum(d**3))
    innov = n * w * 12.0 * dx**3 + 250 * (12.0 * dz * D_loc * dx + 2.0 * nnz_S * w * dy + 2.0 * n * w * dz * dx**2)
    return innov < window


def _agent_layout(idx: list[np.ndarray]) -> tuple[int, np.ndarray, np.ndarray, int]:
    """(n, d, offsets, D_loc): agent i's d_i local unknowns sit at offsets[i]:offsets[i + 1] of D_loc."""
    d = np.array([len(ix) for ix in idx], dtype=int)
    offsets = np.concatenate([[0], np.cumsum(d)]).astype(int)
    return len(idx), d, offsets, int(offsets[-1])


@dataclass(eq=False)
class GammaProblem:
    """Gamma of one step: cost weight ``S`` and pooled innovation covariance ``Sigma``.

    Parameters
    ----------
    S : (n d_z, n d_z) array
    Sigma : (D, D) array
        Covariance of the pooled innovations; agent i's local innovation is
        ``pool[idx[i]]`` so Sigma_ij = Sigma[idx[i]][:, idx[j]].
    idx : list of int arrays
        Indices of each agent's local innovation in the pool (no repeats
        within one agent).
    dz : int
    """

    S: FloatArray
    Sigma: FloatArray
    idx: list[np.ndarray]
    dz: int
    iterations: int = field(default=0, init=False)
    method_used: str = field(default="", init=False)

    def __post_init__(self) -> None:
        self.n, self.d, self.offsets, self.D_loc = _agent_layout(self.idx)
        self.idx_all = np.concatenate(self.idx).astype(int) if self.n else np.zeros(0, int)
        self.agent_of = np.repeat(np.arange(self.n), self.d)
        dz = self.dz
        density = np.count_nonzero(self.S) / max(self.S.size, 1)
        self._S_op = sp.csr_matrix(self.S) if density < 0.25 else self.S
        # scatter pattern of G: row (i, a), column idx[i][p]
        rows = (self.agent_of * dz)[None, :] + np.arange(dz)[:, None]  # (dz, D_loc), order (a, i, p)
        cols = np.broadcast_to(self.idx_all, rows.shape)
        self._g_rows = rows.ravel()
        self._g_cols = cols.ravel()

    @property
    def size(self) -> int:
        """Number of unknowns, d_z * sum_i d_i."""
        return self.dz * self.D_loc

    # --- vectorization: list of (dz, d_i) <-> flat (a, i, p) -----------------
    def flatten(self, F: list[FloatArray]) -> FloatArray:
        if self.D_loc == 0:
            return np.zeros(0)
        return np.concatenate([np.asarray(f).reshape(self.dz, -1) for f in F], axis=1).ravel()

    def unflatten(self, x: FloatArray) -> list[FloatArray]:
        M = np.asarray(x).reshape(self.dz, self.D_loc)
        return [M[:, self.offsets[i] : self.offsets[i + 1]].copy() for i in range(self.n)]

    # --- the operator --------------------------------------------------------
    def apply_flat(self, x: FloatArray) -> FloatArray:
        """Gamma x without forming Gamma."""
        if self.D_loc == 0:
            return np.zeros(0)
        D = self.Sigma.shape[0]
        G = sp.csr_matrix((np.asarray(x, dtype=float).ravel(), (self._g_rows, self._g_cols)), shape=(self.n * self.dz, D))
        H = np.asarray(G @ self.Sigma)  # (n dz, D): row (j, b) = F_j[b] scattered, times Sigma
        K = np.asarray(self._S_op @ H)  # (n dz, D)
        return K[self._g_rows, self._g_cols]

    def apply(self, F: list[FloatArray]) -> list[FloatArray]:
        return self.unflatten(self.apply_flat(self.flatten(F)))

    def dense(self) -> FloatArray:
        """Gamma assembled densely in the (a, i, p) ordering of :meth:`flatten`."""
        dz, N = self.dz, self.D_loc
        Sig = self.Sigma[np.ix_(self.idx_all, self.idx_all)]
        G = np.empty((dz * N, dz * N))
        ag = self.agent_of
        for a in range(dz):
            for b in range(dz):
                Sab = self.S[a::dz, b::dz]  # (n, n): S_ij[a, b]
                np.multiply(Sig, Sab[np.ix_(ag, ag)], out=G[a * N : (a + 1) * N, b * N : (b + 1) * N])
        return G

    # --- solving -------------------------------------------------------------
    def flop_estimates(self, cg_iterations: int = 150) -> tuple[float, float]:
        """Rough flop counts of the dense Cholesky path and of ``cg_iterations`` operator applications."""
        return _flop_estimates(self.S, self.dz, self.D_loc, self.Sigma.shape[0], cg_iterations)

    def choose(self, method: Method = "auto", dense_max_bytes: int = DENSE_MAX_BYTES) -> str:
        """The solver: dense Cholesky unless Gamma would not fit in ``dense_max_bytes`` or the operator is cheaper."""
        return choose_solver(self.S, self.idx, self.dz, self.Sigma.shape[0], method, dense_max_bytes)

    def solve(
        self,
        eta: list[FloatArray],
        method: Method = "auto",
        *,
        rtol: float = 1e-12,
        max_iter: int | None = None,
        dense_max_bytes: int = DENSE_MAX_BYTES,
    ) -> list[FloatArray]:
        """Solve Gamma F = eta; ``eta`` and the result are lists of (d_z, d_i) arrays."""
        b = self.flatten(eta)
        if b.size == 0:
            self.method_used = "empty"
            return self.unflatten(b)
        m = self.choose(method, dense_max_bytes)
        self.method_used = m
        if m == "dense":
            try:
                cf = sla.cho_factor(self.dense(), lower=True, check_finite=False)
            except np.linalg.LinAlgError:
                raise NotPositiveDefiniteError(
                    "Gamma: the Theorem-2 system is not numerically positive definite; check that S > 0 and R_i > 0 are well conditioned"
                ) from None
            x = sla.cho_solve(cf, b, check_finite=False)
        elif m == "cg":
            x = self._cg(b, rtol=rtol, max_iter=max_iter)
        else:
            raise ArgumentError(f"method: expected 'auto', 'dense' or 'cg', found {m!r}", argument="method")
        return self.unflatten(x)

    def _preconditioner(self) -> spla.LinearOperator:
        dz = self.dz
        S_inv = [np.linalg.inv(self.S[i * dz : (i + 1) * dz, i * dz : (i + 1) * dz]) for i in range(self.n)]
        groups: dict[int, list[int]] = {}
        for i, di in enumerate(self.d):
            if di:
                groups.setdefault(int(di), []).append(i)
        inv_blocks = {}
        for di, members in groups.items():
            blocks = np.stack([self.Sigma[np.ix_(self.idx[i], self.idx[i])] for i in members])
            inv_blocks[di] = (np.array(members), np.linalg.inv(blocks), np.stack([S_inv[i] for i in members]))

        def apply(x: FloatArray) -> FloatArray:
            M = np.asarray(x).reshape(dz, self.D_loc)
            out = np.empty_like(M)
            for di, (members, Sig_inv, Sinv) in inv_blocks.items():
                cols = self.offsets[members][:, None] + np.arange(di)[None, :]  # (g, di)
                X = M[:, cols].transpose(1, 0, 2)  # (g, dz, di)
                Y = Sinv @ X @ Sig_inv
                out[:, cols] = Y.transpose(1, 0, 2)
            return out.ravel()

        return spla.LinearOperator((self.size, self.size), matvec=apply, dtype=float)

    def _cg(self, b: FloatArray, *, rtol: float, max_iter: int | None) -> FloatArray:
        A = spla.LinearOperator((self.size, self.size), matvec=self.apply_flat, dtype=float)
        count = [0]

        def cb(_: FloatArray) -> None:
            count[0] += 1

        maxiter = max_iter if max_iter is not None else max(1000, 10 * int(np.sqrt(self.size)))
        x, info = spla.cg(A, b, rtol=rtol, atol=0.0, maxiter=maxiter, M=self._preconditioner(), callback=cb)
        self.iterations = count[0]
        if info != 0:
            res = float(np.linalg.norm(self.apply_flat(x) - b)) / max(float(np.linalg.norm(b)), 1e-300)
            raise ConvergenceError(
                f"Gamma F = eta: conjugate gradients stopped after {count[0]} iterations with relative residual {res:.3g} "
                f"(asked {rtol:g}); raise max_iter or use method='dense' if Gamma fits in memory"
            )
        return np.asarray(x)

    def quad(self, F: list[FloatArray]) -> float:
        """<F, Gamma F>."""
        x = self.flatten(F)
        return float(x @ self.apply_flat(x)) if x.size else 0.0


# ---------------------------------------------------------------------------
# Gamma F = eta in the agents' Kalman-innovation coordinates
# ---------------------------------------------------------------------------
@dataclass(eq=False)
class WindowModel:
    """The window u = 0..w-1: eps(u+1) = A[u] eps(u) + w(u), y~(u) = C[u] eps(u) + v(u), eps(0) ~ N(0, P0).

    w(u) ~ N(0, Q[u]) and v(u) ~ N(0, R[u]) independent; the pool of :class:`GammaProblem` is
    vec(y~(0), ..., y~(w-1)), position u d_y + r for row r of step u.
    """

    A: list[FloatArray]
    Q: list[FloatArray]
    C: list[FloatArray]
    R: list[FloatArray]
    P0: FloatArray

    @property
    def steps(self) -> int:
        return len(self.C)


# a noise vector, or rows of them: (eps(0): (k, dx), w: (w-1, k, dx), v: (w, k, dy))
_Noise = tuple[FloatArray, FloatArray, FloatArray]


@dataclass(eq=False)
class _InnovationCov:
    """N^-1 for one step's innovation covariance N = H P H' + R_rows.

    R_rows diagonal: Woodbury, N^-1 = R^-1 - B M^-1 B' with B = R^-1 H P^1/2 (k x d_x) and
    M = I + P^1/2' H' R^-1 H P^1/2 (d_x x d_x, eigenvalues >= 1): O(k d_x) per row. Otherwise N^-1 dense.
    """

    r_inv: FloatArray | None
    B: FloatArray | None
    M_inv: FloatArray | None
    N_inv: FloatArray | None

    def right(self, X: FloatArray) -> FloatArray:
        """X N^-1 (N symmetric) for rows X (., k)."""
        if self.N_inv is not None:
            return X @ self.N_inv
        assert self.r_inv is not None and self.B is not None and self.M_inv is not None
        return X * self.r_inv - ((X @ self.B) @ self.M_inv) @ self.B.T

    @classmethod
    def of(cls, H: FloatArray, P: FloatArray, Rr: FloatArray) -> "_InnovationCov":
        rd = np.diag(Rr).copy()
        if np.all(rd > 0) and not np.any(Rr - np.diag(rd)):
            lam, V = np.linalg.eigh(P)
            HPc = H @ (V * np.sqrt(np.clip(lam, 0.0, None)))  # H P^1/2
            B = HPc / rd[:, None]
            M = np.eye(P.shape[0]) + HPc.T @ B
            return cls(1.0 / rd, B, np.linalg.inv(0.5 * (M + M.T)), None)
        N = H @ P @ H.T + Rr
        try:
            cf = sla.cho_factor(0.5 * (N + N.T), lower=True, check_finite=False)
        except np.linalg.LinAlgError:
            raise NotPositiveDefiniteError("Gamma: an agent's innovation covariance is not positive definite; check R_i > 0") from None
        return cls(None, None, None, sla.cho_solve(cf, np.eye(N.shape[0]), check_finite=False))


@dataclass(eq=False)
class _LocalFilter:
    order: np.ndarray  # idx positions in time order
    # per step u: (rows, position in e, count, H, N^-1, K, I - K H)
    steps: list[tuple[np.ndarray, int, int, FloatArray, _InnovationCov | None, FloatArray, FloatArray]]


@dataclass(eq=False)
class InnovationsProblem:
    """MTMSE gains of one window step by CG in the agents' innovation coordinates (module docstring).

    Parameters
    ----------
    S : (n d_z, n d_z) array
    L : (n d_z, d_x) array
    model : WindowModel
    idx : list of int arrays
        Agent i's local measurements as positions in the window pool (as for :class:`GammaProblem`).
    dz : int
    """

    S: FloatArray
    L: FloatArray
    model: WindowModel
    idx: list[np.ndarray]
    dz: int
    iterations: int = field(default=0, init=False)
    method_used: str = field(default="cg", init=False)

    def __post_init__(self) -> None:
        self.n, self.d, self.offsets, self.D_loc = _agent_layout(self.idx)
        m = self.model
        self.w, self.dx, self.dy = m.steps, m.P0.shape[0], m.C[0].shape[0]
        with single_thread_blas():
            self.filters = [self._filter(np.asarray(ix, dtype=int)) for ix in self.idx]
        self._R_sp = [sp.csr_matrix(R) for R in m.R]  # block diagonal (per agent) in the designs

    @property
    def size(self) -> int:
        return self.dz * self.D_loc

    def _filter(self, ix: np.ndarray) -> _LocalFilter:
        m, dx = self.model, self.dx
        u_of, r_of = ix // self.dy, ix % self.dy
        order = np.lexsort((r_of, u_of))
        u_sorted, r_sorted = u_of[order], r_of[order]
        steps = []
        P, pos = np.asarray(m.P0, dtype=float), 0
        I = np.eye(dx)
        for u in range(self.w):
            rows = r_sorted[u_sorted == u]
            k = rows.size
            if k:
                H = m.C[u][rows]
                Rr = m.R[u][np.ix_(rows, rows)]
                Ninv: _InnovationCov | None = _InnovationCov.of(H, P, Rr)
                K = Ninv.right(P @ H.T)  # type: ignore[union-attr]  # P H' N^-1
                G = I - K @ H
                P = G @ P @ G.T + K @ Rr @ K.T  # Joseph form
            else:
                H, Ninv, K, G = np.zeros((0, dx)), None, np.zeros((dx, 0)), I
            steps.append((rows, pos, k, H, Ninv, K, G))
            pos += k
            if u < self.w - 1:
                P = m.A[u] @ P @ m.A[u].T + m.Q[u]
                P = 0.5 * (P + P.T)
        return _LocalFilter(order, steps)

    # --- the filters as maps between noise coordinates and innovations ----------
    def _noise_zeros(self, k: int) -> _Noise:
        return np.zeros((k, self.dx)), np.zeros((max(self.w - 1, 0), k, self.dx)), np.zeros((self.w, k, self.dy))

    def _forward(self, i: int, psi: _Noise) -> FloatArray:
        """e_i (rows, d_i in time order) for the noise realizations psi (rows)."""
        e0, wn, vn = psi
        out = np.empty((e0.shape[0], int(self.d[i])))
        xi = e0  # eps(u) - x^_i(u|u-1)
        for u, (rows, pos, k, H, _, K, G) in enumerate(self.filters[i].steps):
            if k:
                vr = vn[u][:, rows]
                out[:, pos : pos + k] = xi @ H.T + vr
                xi = xi @ G.T - vr @ K.T
            if u < self.w - 1:
                xi = xi @ self.model.A[u].T + wn[u]
        return out

    def _adjoint(self, i: int, phi: FloatArray | None, terminal: FloatArray, acc: _Noise) -> None:
        """Add to ``acc`` the noise sensitivities of phi e_i + terminal (eps(w-1) - x^_i(w-1|w-1)) (rows)."""
        e0, wn, vn = acc
        lam = terminal
        for u in range(self.w - 1, -1, -1):
            rows, pos, k, H, _, K, G = self.filters[i].steps[u]
            if u < self.w - 1:
                wn[u] += lam
                lp = lam @ self.model.A[u]
            else:
                lp = terminal
            if k:
                if phi is not None:
                    g = phi[:, pos : pos + k]
                    vn[u][:, rows] += g - lp @ K
                    lam = g @ H + lp @ G
                else:
                    vn[u][:, rows] -= lp @ K
                    lam = lp @ G
            else:
                lam = lp
        e0 += lam

    def _data_adjoint(self, i: int, phi: FloatArray, terminal: FloatArray) -> FloatArray:
        """Coefficients on agent i's local data (time order) of phi e_i + terminal x^_i(w-1|w-1)."""
        out = np.empty((phi.shape[0], int(self.d[i])))
        mu = terminal
        for u in range(self.w - 1, -1, -1):
            rows, pos, k, H, _, K, G = self.filters[i].steps[u]
            mp = terminal if u == self.w - 1 else mu @ self.model.A[u]
            if k:
                ge = phi[:, pos : pos + k] + mp @ K
                out[:, pos : pos + k] = ge
                mu = mp - ge @ H
            else:
                mu = mp
        return out

    def _sensitivities(self, Fhat: list[FloatArray] | None, terminal: bool) -> _Noise:
        """Rows (j, a): noise sensitivities of Fhat_j[a] e_j (+ L_j[a] (eps(k) - x^_j(k|k)) when ``terminal``)."""
        dz = self.dz
        acc = self._noise_zeros(self.n * dz)
        for j in range(self.n):
            sl = slice(j * dz, (j + 1) * dz)
            term = self.L[sl] if terminal else np.zeros((dz, self.dx))
            self._adjoint(j, Fhat[j] if Fhat is not None else None, term, (acc[0][sl], acc[1][:, sl], acc[2][:, sl]))
        return acc

    def _weight(self, psi: _Noise, mix: bool = True) -> _Noise:
        """S psi Lambda, Lambda = blockdiag(P0, Q, R): the noise covariance."""
        e0, wn, vn = psi
        m, S = self.model, self.S
        if mix:
            e0, wn, vn = S @ e0, np.matmul(S, wn), np.matmul(S, vn)
        wq = np.stack([wn[u] @ m.Q[u] for u in range(self.w - 1)]) if self.w > 1 else wn
        return e0 @ m.P0, wq, np.stack([np.asarray(self._R_sp[u] @ vn[u].T).T for u in range(self.w)])

    def _to_agents(self, psi: _Noise) -> list[FloatArray]:
        dz = self.dz
        return [
            self._forward(i, (psi[0][i * dz : (i + 1) * dz], psi[1][:, i * dz : (i + 1) * dz], psi[2][:, i * dz : (i + 1) * dz]))
            for i in range(self.n)
        ]

    def flatten(self, F: list[FloatArray]) -> FloatArray:
        return np.concatenate([np.asarray(f).reshape(self.dz, -1) for f in F], axis=1).ravel() if self.D_loc else np.zeros(0)

    def unflatten(self, x: FloatArray) -> list[FloatArray]:
        M = np.asarray(x).reshape(self.dz, self.D_loc)
        return [M[:, self.offsets[i] : self.offsets[i + 1]] for i in range(self.n)]

    def apply_flat(self, x: FloatArray) -> FloatArray:
        """Gamma^ x in innovation coordinates."""
        return self.flatten(self._to_agents(self._weight(self._sensitivities(self.unflatten(x), terminal=False))))

    def _noise_cost(self, X: _Noise) -> float:
        """sum Tr(S X Lambda X') over the noise blocks: non-negative terms, no cancellation."""
        XL = self._weight(X, mix=False)
        S = self.S
        J = float(np.sum(S * (X[0] @ XL[0].T)))
        for a, b in zip(X[1], XL[1]):
            J += float(np.sum(S * (a @ b.T)))
        for a, b in zip(X[2], XL[2]):
            J += float(np.sum(S * (a @ b.T)))
        return J

    # --- solving -------------------------------------------------------------
    def solve(self, *, rtol: float = 1e-12, max_iter: int | None = None) -> tuple[list[FloatArray], float]:
        """Gains F_i on the local data (idx order, (d_z, d_i) each) and their team cost.

        Runs on one BLAS thread: every product is small (at most d_y x d_x), and OpenBLAS's second
        thread made the 14-vehicle platoon 3x slower on the shared 2-core machine.
        """
        with single_thread_blas():
            return self._solve(rtol, max_iter)

    def _solve(self, rtol: float, max_iter: int | None) -> tuple[list[FloatArray], float]:
        dz, n = self.dz, self.n
        Xi = self._sensitivities(None, terminal=True)  # L_j (eps(k) - x^_j(k|k))
        b = self.flatten(self._to_agents(self._weight(Xi)))
        x = np.zeros_like(b)
        if b.size and np.any(b):
            S_inv = [np.linalg.inv(self.S[i * dz : (i + 1) * dz, i * dz : (i + 1) * dz]) for i in range(n)]

            def prec(v: FloatArray) -> FloatArray:  # block Jacobi: S_ii^-1 X blockdiag_u(N_u^-1) = Gamma_ii^-1
                out = []
                for i, X in enumerate(self.unflatten(v)):
                    Y = np.empty_like(X)
                    for _rows, pos, k, _H, Ninv, _K, _G in self.filters[i].steps:
                        if k:
                            Y[:, pos : pos + k] = Ninv.right(X[:, pos : pos + k])  # type: ignore[union-attr]
                    out.append(S_inv[i] @ Y)
                return self.flatten(out)

            N = self.size
            count = [0]

            def cb(_: FloatArray) -> None:
                count[0] += 1

            A = spla.LinearOperator((N, N), matvec=self.apply_flat, dtype=float)
            M = spla.LinearOperator((N, N), matvec=prec, dtype=float)
            maxiter = max_iter if max_iter is not None else max(1000, 10 * int(np.sqrt(N)))
            x, info = spla.cg(A, b, rtol=rtol, atol=0.0, maxiter=maxiter, M=M, callback=cb)
            self.iterations = count[0]
            if info != 0:
                res = float(np.linalg.norm(self.apply_flat(x) - b)) / max(float(np.linalg.norm(b)), 1e-300)
                raise ConvergenceError(
                    f"Gamma F = eta (innovation coordinates): conjugate gradients stopped after {count[0]} iterations with relative "
                    f"residual {res:.3g} (asked {rtol:g}); raise max_iter or use method='dense' if Gamma fits in memory"
                )
        Fhat = self.unflatten(x)
        Psi = self._sensitivities(Fhat, terminal=False)
        J = self._noise_cost((Xi[0] - Psi[0], Xi[1] - Psi[1], Xi[2] - Psi[2]))
        F = []
        for i, f in enumerate(Fhat):
            coef = self._data_adjoint(i, f, self.L[i * dz : (i + 1) * dz])
            Fi = np.empty_like(coef)
            Fi[:, self.filters[i].order] = coef
            F.append(Fi)
        return F, J

    def gains_cost(self, F: list[FloatArray]) -> float:
        """Team cost of z_i = L_i x^com + F_i y~_i for any gains on the local data (idx order), without eq. (35)'s cancellation.

        The error L eps(k) - F y~ has the noise sensitivities X_j = sum_{u >= j} Y_u Phi(u, j) (Y: L at the last step minus
        F C), computed backwards Z_j = Y_j + Z_{j+1} A[j], each as small as the error itself.
        """
        dz, m = self.dz, self.model
        nz = self.n * dz
        Y = np.zeros((self.w, nz, self.dx))
        V = np.zeros((self.w, nz, self.dy))
        for i, ix in enumerate(self.idx):
            ix = np.asarray(ix, dtype=int)
            u_of, r_of = ix // self.dy, ix % self.dy
            Fi = np.asarray(F[i]).reshape(dz, -1)
            for u in np.unique(u_of):
                sel = u_of == u
                Y[u, i * dz : (i + 1) * dz] -= Fi[:, sel] @ m.C[u][r_of[sel]]
                V[u, i * dz : (i + 1) * dz][:, r_of[sel]] -= Fi[:, sel]
        Y[self.w - 1] += self.L
        Z = Y[self.w - 1]
        X = np.empty_like(Y)
        X[self.w - 1] = Z
        for j in range(self.w - 2, -1, -1):
            Z = Y[j] + Z @ m.A[j]
            X[j] = Z
        return self._noise_cost((X[0], X[1:], V))
