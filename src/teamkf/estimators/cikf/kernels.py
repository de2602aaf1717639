r"""Block kernels of the CIKF design: the products of Algorithm 2 without forming an NM x NM matrix.

M_k = I - B^C - B^I D̃_H has N + 2|E| non-zero blocks (the graph's pattern) and K, F, I ⊗ Ã, I ⊗ Ǎ are
block-diagonal, so :class:`_Structured` multiplies block by block (one GEMM per agent over its closed
neighbourhood, batched GEMMs for the block-diagonal factors); :class:`_Dense` forms the dense operators
(the benchmark's baseline, the same numbers). The worker pool splits the agents over threads in fixed
contiguous groups, so the numbers do not depend on the thread count.
"""

from __future__ import annotations

from typing import Any, Literal, Sequence

import numpy as np

from ..._linalg import block_diag
from ..._validation import FloatArray

__all__ = ["Form", "Method"]


Form = Literal["filter", "predictor"]


Method = Literal["structured", "joint", "dense"]


class _worker_pool:
    """A thread pool of ``n`` workers for the block products (None when ``n`` is None or 1).

    numpy releases the GIL inside BLAS calls and ufunc loops, so ``n`` Python threads each running
    single-threaded BLAS on its own range of agents use ``n`` cores without OpenBLAS's spinning threads.
    """

    def __init__(self, n: int | None):
        self.n = n
        self.pool: Any = None

    def __enter__(self) -> Any:
        if self.n is not None and self.n > 1:
            from concurrent.futures import ThreadPoolExecutor

            self.pool = ThreadPoolExecutor(max_workers=self.n, thread_name_prefix="teamkf-cikf")
        return self.pool

    def __exit__(self, *exc: Any) -> None:
        if self.pool is not None:
            self.pool.shutdown(wait=True)


def _sym(X: FloatArray) -> FloatArray:
    X += X.T
    X *= 0.5
    return X


class _Structured:
    """Block products that never form an NM x NM operator: M_k by closed neighbourhoods, the rest block-diagonally.

    Every block of a result is computed by one BLAS call whose shape does not depend on ``pool``; with a
    thread pool (one BLAS thread per worker) the calls are spread over the workers in contiguous ranges of
    agents, so the numbers are the same with one worker or several.
    """

    def __init__(self, N: int, r: int, hoods: Sequence[np.ndarray], r_idx: Sequence[np.ndarray], pool: Any = None, workers: int = 1):
        self.N, self.r, self.hoods, self.r_idx = N, r, hoods, r_idx
        self.pool, self.workers = pool, max(1, int(workers))

    def _par(self, fn: Any, n: int) -> None:
        """fn(lo, hi) over ``workers`` contiguous ranges of range(n) (in the pool when there is one)."""
        if self.pool is None or self.workers == 1 or n < 2:
            fn(0, n)
            return
        cuts = np.linspace(0, n, min(self.workers, n) + 1).round().astype(int)
        futs = [self.pool.submit(fn, int(a), int(b)) for a, b in zip(cuts[:-1], cuts[1:]) if b > a]
        for f in futs:
            f.result()

    def m_right(self, X: FloatArray, rows: Sequence[FloatArray]) -> FloatArray:
        """X M' (M given by its block rows over closed neighbourhoods)."""
        r = self.r
        out = np.empty((X.shape[0], self.N * r))

        def work(lo: int, hi: int) -> None:
            for n in range(lo, hi):
                out[:, n * r : (n + 1) * r] = X[:, self.r_idx[n]] @ rows[n].T

        self._par(work, self.N)
        return out

    def m_left(self, rows: Sequence[FloatArray], X: FloatArray) -> FloatArray:
        """M X."""
        r = self.r
        out = np.empty((self.N * r, X.shape[1]))

        def work(lo: int, hi: int) -> None:
            for n in range(lo, hi):
                np.matmul(rows[n], np.take(X, self.r_idx[n], axis=0), out=out[n * r : (n + 1) * r])

        self._par(work, self.N)
        return out

    def m_sandwich(self, rows: Sequence[FloatArray], Zt: FloatArray) -> FloatArray:
        """M Z' given Z' (symmetric result M P M' with Z = M P): the upper block triangle, mirrored."""
        r, N = self.r, self.N
        out = np.empty((N * r, Zt.shape[1]))

        def upper(lo: int, hi: int) -> None:
            for n in range(lo, hi):
                np.matmul(rows[n], Zt[self.r_idx[n], n * r :], out=out[n * r : (n + 1) * r, n * r :])

        # balance the triangle: agent n's row costs ~ (N - n) blocks
        self._par_tri(upper, N)

        def mirror(lo: int, hi: int) -> None:
            for n in range(max(lo, 1), hi):
                out[n * r : (n + 1) * r, : n * r] = out[: n * r, n * r : (n + 1) * r].T

        self._par(mirror, N)
        return out

    def _par_tri(self, fn: Any, n: int) -> None:
        """Like _par, with ranges of equal work for rows whose cost falls linearly (upper triangles)."""
        if self.pool is None or self.workers == 1 or n < 2:
            fn(0, n)
            return
        w = np.arange(n, 0, -1, dtype=float)
        c = np.concatenate([[0.0], np.cumsum(w)])
        cuts = [0] + [int(np.searchsorted(c, c[-1] * j / self.workers)) for j in range(1, self.workers)] + [n]
        futs = [self.pool.submit(fn, a, b) for a, b in zip(cuts[:-1], cuts[1:]) if b > a]
        for f in futs:
            f.result()

    def bd_left(self, B: FloatArray, X: FloatArray) -> FloatArray:
        """blockdiag(B) X; B is (N, a, b) or one shared (a, b)."""
        b = B.shape[-1]
        a = B.shape[-2]
        C = X.shape[1]
        X3 = np.ascontiguousarray(X).reshape(self.N, b, C)
        out = np.empty((self.N, a, C))

        def work(lo: int, hi: int) -> None:
            np.matmul(B if B.ndim == 2 else B[lo:hi], X3[lo:hi], out=out[lo:hi])

        self._par(work, self.N)
        return out.reshape(-1, C)

    def bd_right(self, X: FloatArray, B: FloatArray) -> FloatArray:
        """X blockdiag(B)'; B is (N, a, b) or one shared (a, b)."""
        Rr = X.shape[0]
        b = B.shape[-1]
        if B.ndim == 2:
            X3 = np.ascontiguousarray(X).reshape(Rr, self.N, b)
            out2 = np.empty((Rr, self.N * B.shape[0]))

            def work2(lo: int, hi: int) -> None:  # row ranges: the one GEMM split by rows
                np.matmul(X3[lo:hi].reshape(-1, b), B.T, out=out2[lo:hi].reshape(-1, B.shape[0]))

            self._par(work2, Rr)
            return out2
        a = B.shape[1]
        out = np.empty((Rr, self.N * a))

        def work(lo: int, hi: int) -> None:
            for n in range(lo, hi):  # strided column blocks go to BLAS without copies
                np.matmul(X[:, n * b : (n + 1) * b], B[n].T, out=out[:, n * a : (n + 1) * a])

        self._par(work, self.N)
        return out

    def bd_left_add(self, out: FloatArray, B: FloatArray, X: FloatArray) -> FloatArray:
        """out += blockdiag(B) X, block row by block row (no full-size temporary)."""
        b, C = B.shape[-1], X.shape[1]
        X3 = np.ascontiguousarray(X).reshape(self.N, b, C)
        a = B.shape[-2]
        o3 = out.reshape(self.N, a, C)

        def work(lo: int, hi: int) -> None:
            for n in range(lo, hi):
                o3[n] += (B if B.ndim == 2 else B[n]) @ X3[n]

        self._par(work, self.N)
        return out

    def bd_right_add(self, out: FloatArray, X: FloatArray, B: FloatArray) -> FloatArray:
        """out += X blockdiag(B)' for a per-agent B (N, a, b), column block by column block."""
        a, b = B.shape[1], B.shape[2]

        def work(lo: int, hi: int) -> None:
            for n in range(lo, hi):
                out[:, n * a : (n + 1) * a] += X[:, n * b : (n + 1) * b] @ B[n].T

        self._par(work, self.N)
        return out

    def add_check(self, P: FloatArray, Y1: FloatArray, Y2: FloatArray, Aw: FloatArray) -> FloatArray:
        """P += 2 Y1 blockdiag(Aw)' + Y2 blockdiag(Aw)' by row ranges (Y1, Y2 thin: N (M - r) columns)."""
        q = Aw.shape[1]
        Y1, Y2 = np.ascontiguousarray(Y1), np.ascontiguousarray(Y2)

        def work(lo: int, hi: int) -> None:
            T1 = (Y1[lo:hi].reshape(-1, q) @ Aw.T).reshape(hi - lo, -1)
            T2 = (Y2[lo:hi].reshape(-1, q) @ Aw.T).reshape(hi - lo, -1)
            P[lo:hi] += 2.0 * T1 + T2

        self._par(work, P.shape[0])
        return P

    def add(self, X: FloatArray, Y: FloatArray) -> FloatArray:
        """X += Y by row ranges."""

        def work(lo: int, hi: int) -> None:
            X[lo:hi] += Y[lo:hi]

        self._par(work, X.shape[0])
        return X

    def add_tiled(self, X: FloatArray, B: FloatArray) -> FloatArray:
        """X += (1 1') ⊗ B (every a x b block of X gets B), without forming the tiled matrix."""
        a, b = B.shape
        X4 = X.reshape(X.shape[0] // a, a, X.shape[1] // b, b)

        def work(lo: int, hi: int) -> None:
            X4[lo:hi] += B[None, :, None, :]

        self._par(work, X4.shape[0])
        return X

    def sym(self, X: FloatArray) -> FloatArray:
        """X <- (X + X') / 2 in place, by block rows (upper block triangle computed, then mirrored)."""
        n = X.shape[0]
        nb = max(1, min(self.N, n))
        edges = np.linspace(0, n, nb + 1).round().astype(int)

        def upper(lo: int, hi: int) -> None:
            for i in range(lo, hi):
                a, b = edges[i], edges[i + 1]
                blk = X[a:b, a:]
                blk += X[a:, a:b].T
                blk *= 0.5

        self._par_tri(upper, nb)

        def mirror(lo: int, hi: int) -> None:
            for i in range(max(lo, 1), hi):
                a, b = edges[i], edges[i + 1]
                X[a:b, :a] = X[:a, a:b].T

        self._par(mirror, nb)
        return X


class _Dense(_Structured):
    """The same products with every operator formed as a dense NM x NM matrix (benchmark baseline)."""

    def _m(self, rows: Sequence[FloatArray]) -> FloatArray:
        r = self.r
        Mf = np.zeros((self.N * r, self.N * r))
        for n, row in enumerate(rows):
            Mf[n * r : (n + 1) * r, self.r_idx[n]] = row
        return Mf

    def _bd(self, B: FloatArray) -> FloatArray:
        if B.ndim == 2:
            return np.asarray(np.kron(np.eye(self.N), B), dtype=float)
        return block_diag(*B)  # type: ignore[no-any-return]

    def m_right(self, X: FloatArray, rows: Sequence[FloatArray]) -> FloatArray:
        return X @ self._m(rows).T  # type: ignore[no-any-return]

    def m_left(self, rows: Sequence[FloatArray], X: FloatArray) -> FloatArray:
        return self._m(rows) @ X  # type: ignore[no-any-return]

    def m_sandwich(self, rows: Sequence[FloatArray], Zt: FloatArray) -> FloatArray:
        out = self._m(rows) @ Zt
        return _sym(out)

    def bd_left(self, B: FloatArray, X: FloatArray) -> FloatArray:
        return self._bd(B) @ X  # type: ignore[no-any-return]

    def bd_right(self, X: FloatArray, B: FloatArray) -> FloatArray:
        return X @ self._bd(B).T  # type: ignore[no-any-return]


def _diag_blocks(X: FloatArray, N: int, a: int) -> FloatArray:
    """The N diagonal a x a blocks of an Na x Na matrix, (N, a, a)."""
    X4 = X.reshape(N, a, N, a)
    return np.ascontiguousarray(X4[np.arange(N), :, np.arange(N), :])


def _agent_groups(neighbors: Sequence[Sequence[int]], m_sizes: Sequence[int], parts: int = 1) -> list[list[tuple[np.ndarray, np.ndarray]]]:
    """Agents batched by (neighbourhood size, measurement size), each batch split into ``parts`` shares.

    Returns ``parts`` lists of (agents, closed neighbourhoods (g, d+1)) with about equal numbers of agents
    of each size, so that ``parts`` workers get equal work.
    """
    keyed: dict[tuple[int, int], list[int]] = {}
    for n, nb in enumerate(neighbors):
        keyed.setdefault((len(nb), int(m_sizes[n])), []).append(n)
    out: list[list[tuple[np.ndarray, np.ndarray]]] = [[] for _ in range(max(1, parts))]
    for (d, _), agents in sorted(keyed.items()):
        for j, share in enumerate(np.array_split(np.asarray(agents, dtype=np.intp), len(out))):
            if share.size:
                hood = np.asarray([[n, *neighbors[n]] for n in share], dtype=np.intp).reshape(share.size, d + 1)
                out[j].append((share, hood))
    return [p for p in out if p]


def _schedules(B_cons: list, B_innov: list, K: Any, Sp: Any, Sf: Any, Ptr: Any, stage: Any) -> dict[str, Any]:
    """What Algorithm 2 returns, whichever recursion ran it (gains, covariances, traces, stage costs)."""
    return {"B_cons": tuple(B_cons), "B_innov": tuple(B_innov), "K": K, "Sigma_pred": Sp, "Sigma_filt": Sf, "P_pred_trace": Ptr, "stage": stage}
