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

The window covariance is also accepted in *factored* form
(:class:`FactoredCovariance`): Sigma = C Pi C' + R with C = blockdiag(C(s))
and R = blockdiag(R(s)) sparse and Pi the (m x m, m = w d_x) covariance of
the error trajectory over the window. Then Gamma is applied as

    G Sigma = ((G C) Pi) C' + G R

in O(D_loc nnz-per-row(C) + n d_z m^2 + nnz(S) D) flops, never touching a
D x D matrix, and the block-Jacobi preconditioner is applied exactly by the
Woodbury identity Sigma_ii^-1 = R_ii^-1 - R_ii^-1 C_i L M_i^-1 L' C_i' R_ii^-1,
Pi = L L', M_i = I + L' C_i' R_ii^-1 C_i L (an m x m Cholesky factor per agent
instead of a d_i x d_i inverse). This pays when measurements outnumber states
(d_y > d_x, e.g. the platoon where every vehicle measures every position:
m = (n-1) n against D = (n-1) n^2); :meth:`GammaProblem.prefers_factored`
tells, and the team designs build the factors only then.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .._validation import FloatArray
from ..exceptions import ArgumentError, ConvergenceError, NotPositiveDefiniteError

__all__ = ["GammaProblem", "FactoredCovariance", "DENSE_MAX_BYTES"]

#: dense Gamma is assembled when it needs at most this much memory
DENSE_MAX_BYTES = 1 << 30

Method = Literal["auto", "dense", "cg"]


@dataclass(eq=False)
class FactoredCovariance:
    """A covariance Sigma = C Pi C' + R kept in factors (never formed unless asked).

    Parameters
    ----------
    C : (D, m) sparse matrix
    Pi : (m, m) symmetric positive semidefinite array
    R : (D, D) sparse symmetric matrix, positive definite on every agent's
        local block (block diagonal in the team designs: R = blockdiag(R(s))).
    """

    C: sp.csr_matrix
    Pi: FloatArray
    R: sp.csr_matrix

    def __post_init__(self) -> None:
        self.C = sp.csr_matrix(self.C)
        self.R = sp.csr_matrix(self.R)
        self.Pi = 0.5 * (np.asarray(self.Pi, dtype=float) + np.asarray(self.Pi, dtype=float).T)

    @property
    def shape(self) -> tuple[int, int]:
        D = int(self.C.shape[0])
        return (D, D)

    @property
    def rank_dim(self) -> int:
        """m, the inner dimension of the low-rank part."""
        return int(self.C.shape[1])

    def block(self, rows: np.ndarray, cols: np.ndarray) -> FloatArray:
        """Sigma[rows][:, cols] as a dense array."""
        Cr, Cc = self.C[rows], self.C[cols]
        out = np.asarray(Cr @ np.asarray(Cc @ self.Pi).T)
        return out + self.R[rows][:, cols].toarray()

    def dense(self) -> FloatArray:
        """Sigma formed (D x D)."""
        ix = np.arange(self.shape[0])
        return self.block(ix, ix)



@dataclass(eq=False)
class GammaProblem:
    """Gamma of one step: cost weight ``S`` and pooled innovation covariance ``Sigma``.

    Parameters
    ----------
    S : (n d_z, n d_z) array
    Sigma : (D, D) array or FactoredCovariance
        Covariance of the pooled innovations; agent i's local innovation is
        ``pool[idx[i]]`` so Sigma_ij = Sigma[idx[i]][:, idx[j]]. In factored
        form the operator and the preconditioner use the factors (module
        docstring); the dense path forms only Sigma[idx_all][:, idx_all].
    idx : list of int arrays
        Indices of each agent's local innovation in the pool (no repeats
        within one agent).
    dz : int
    """

    S: FloatArray
    Sigma: FloatArray | FactoredCovariance
    idx: list[np.ndarray]
    dz: int
    iterations: int = field(default=0, init=False)
    method_used: str = field(default="", init=False)

    def __post_init__(self) -> None:
        self.n = len(self.idx)
        self.d = np.array([len(ix) for ix in self.idx], dtype=int)
        self.offsets = np.concatenate([[0], np.cumsum(self.d)]).astype(int)
        self.D_loc = int(self.offsets[-1])
        self.idx_all = np.concatenate(self.idx).astype(int) if self.n else np.zeros(0, int)
        self.agent_of = np.repeat(np.arange(self.n), self.d)
        self._fac = self.Sigma if isinstance(self.Sigma, FactoredCovariance) else None
        self.D = int(self.Sigma.shape[0])
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
        G = sp.csr_matrix((np.asarray(x, dtype=float).ravel(), (self._g_rows, self._g_cols)), shape=(self.n * self.dz, self.D))
        if self._fac is not None:
            fac = self._fac
            P = np.asarray((G @ fac.C).todense()) @ fac.Pi  # (n dz, m): G C Pi
            Ht = np.asarray(fac.C @ P.T) + np.asarray((fac.R @ G.T).todense())  # (D, n dz): (G Sigma)'
            K = np.asarray(self._S_op @ Ht.T)
        else:
            H = np.asarray(G @ self.Sigma)  # (n dz, D): row (j, b) = F_j[b] scattered, times Sigma
            K = np.asarray(self._S_op @ H)  # (n dz, D)
        return K[self._g_rows, self._g_cols]

    def scatter(self, F: list[FloatArray]) -> sp.csr_matrix:
        """The gains as one sparse (n d_z, D) matrix: row (i, a) holds F_i[a] at the columns idx[i]."""
        return sp.csr_matrix((self.flatten(F), (self._g_rows, self._g_cols)), shape=(self.n * self.dz, self.D))

    def apply(self, F: list[FloatArray]) -> list[FloatArray]:
        return self.unflatten(self.apply_flat(self.flatten(F)))

    def dense(self) -> FloatArray:
        """Gamma assembled densely in the (a, i, p) ordering of :meth:`flatten`."""
        dz, N = self.dz, self.D_loc
        Sig = self._fac.block(self.idx_all, self.idx_all) if self._fac is not None else np.asarray(self.Sigma)[np.ix_(self.idx_all, self.idx_all)]
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
        N, D = float(self.size), float(self.D)
        dense = N**3 / 3.0 + 2.0 * N**2
        cg = cg_iterations * 2.0 * (self.dz * self.D_loc * D + self._nnz_S() * D)
        return dense, cg

    def _nnz_S(self) -> float:
        return float(self._S_op.nnz) if sp.issparse(self._S_op) else float(self.S.size)  # type: ignore[union-attr]

    def factored_apply_flops(self) -> float:
        """Rough flops of one operator application with the factors (inf without them)."""
        if self._fac is None:
            return float("inf")
        fac, nz = self._fac, float(self.n * self.dz)
        m, D = float(fac.rank_dim), float(self.D)
        per_row_C = fac.C.nnz / max(D, 1.0)
        per_row_R = fac.R.nnz / max(D, 1.0)
        return 2.0 * (self.dz * self.D_loc * (per_row_C + per_row_R) + nz * m * m + nz * fac.C.nnz + self._nnz_S() * D)

    def prefers_factored(self, method: Method = "auto", dense_max_bytes: int = DENSE_MAX_BYTES) -> bool:
        """True when this (factored) problem will be solved by CG and the factored operator is cheaper than a dense Sigma's.

        The solver choice is :meth:`choose`'s, made from the sizes alone, so it is the same with a dense Sigma.
        """
        if self._fac is None or self.D_loc == 0 or self.choose(method, dense_max_bytes) != "cg":
            return False
        return self.factored_apply_flops() < 2.0 * (self.dz * self.D_loc * self.D + self._nnz_S() * self.D)

    def choose(self, method: Method = "auto", dense_max_bytes: int = DENSE_MAX_BYTES) -> str:
        """The solver: dense Cholesky unless Gamma would not fit in ``dense_max_bytes`` or the operator is cheaper."""
        if method != "auto":
            return method
        if 8 * self.size**2 > dense_max_bytes:
            return "cg"
        dense, cg = self.flop_estimates()
        return "cg" if cg < dense else "dense"

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
        if self._fac is not None:
            return self._preconditioner_factored(self._fac)
        dz = self.dz
        Sigma = np.asarray(self.Sigma)
        S_inv = [np.linalg.inv(self.S[i * dz : (i + 1) * dz, i * dz : (i + 1) * dz]) for i in range(self.n)]
        groups: dict[int, list[int]] = {}
        for i, di in enumerate(self.d):
            if di:
                groups.setdefault(int(di), []).append(i)
        inv_blocks = {}
        for di, members in groups.items():
            blocks = np.stack([Sigma[np.ix_(self.idx[i], self.idx[i])] for i in members])
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

    def _preconditioner_factored(self, fac: FactoredCovariance) -> spla.LinearOperator:
        """Block Jacobi S_ii^-1 X Sigma_ii^-1 with Sigma_ii^-1 by the Woodbury identity (module docstring)."""
        dz = self.dz
        lam, V = np.linalg.eigh(fac.Pi)
        keep = lam > max(float(lam[-1]), 0.0) * 1e-13 if lam.size else np.zeros(0, bool)
        L = np.ascontiguousarray(V[:, keep] * np.sqrt(lam[keep]))  # Pi ~ L L' (m, r)
        blocks: list[tuple | None] = []
        for i, ix in enumerate(self.idx):
            if ix.size == 0:
                blocks.append(None)
                continue
            S_inv = np.linalg.inv(self.S[i * dz : (i + 1) * dz, i * dz : (i + 1) * dz])
            Ci = fac.C[ix]  # (d_i, m)
            Rii = sp.csr_matrix(fac.R[ix][:, ix])
            diag = Rii.diagonal()
            if Rii.nnz == np.count_nonzero(Rii.diagonal()) == ix.size and sp.triu(Rii, 1).nnz == 0 and np.all(diag > 0):
                r_inv: FloatArray | None = 1.0 / diag
                lu = None
                W = np.asarray((Ci.T @ sp.diags(r_inv) @ Ci) @ L)  # C_i' R_ii^-1 C_i L
            else:
                try:
                    lu = spla.splu(sp.csc_matrix(Rii))
                except RuntimeError:
                    raise NotPositiveDefiniteError("Gamma preconditioner: an agent's block of R is singular") from None
                r_inv = None
                W = np.asarray(Ci.T @ lu.solve(np.asarray(Ci @ L)))
            # M_i = I + K, K = L' C_i' R_ii^-1 C_i L >= 0; by eigenvalues (K's may reach 1e17: no Cholesky of M_i)
            mu, E = np.linalg.eigh(0.5 * (L.T @ W + W.T @ L))
            EL = L @ E  # (m, r): M_i^-1 = E diag(1 / (1 + mu)) E'
            blocks.append((S_inv, Ci, sp.csr_matrix(Ci.T), r_inv, lu, EL, 1.0 / (1.0 + np.maximum(mu, 0.0))))

        def apply(x: FloatArray) -> FloatArray:
            M = np.asarray(x).reshape(dz, self.D_loc)
            out = np.empty_like(M)
            for i, blk in enumerate(blocks):
                if blk is None:
                    continue
                S_inv, Ci, CiT, r_inv, lu, EL, w = blk
                sl = slice(self.offsets[i], self.offsets[i + 1])
                Xt = M[:, sl].T  # (d_i, dz)
                Zt = Xt * r_inv[:, None] if r_inv is not None else lu.solve(np.ascontiguousarray(Xt))
                T = w[:, None] * (EL.T @ np.asarray(CiT @ Zt))  # (r, dz)
                U = np.asarray(Ci @ (EL @ T))
                Yt = Zt - (U * r_inv[:, None] if r_inv is not None else lu.solve(U))
                out[:, sl] = S_inv @ Yt.T
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
