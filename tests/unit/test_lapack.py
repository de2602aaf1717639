"""teamkf._lapack: the GIL-releasing pivoted Cholesky solve equals SciPy's LAPACK wrappers bit for bit."""

from __future__ import annotations

import threading

import numpy as np
import pytest
from scipy.linalg.lapack import dpotrs, dpstrf

from teamkf import _lapack


def _scipy(S: np.ndarray, S_xy: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """Written out here from scipy.linalg.lapack, independently of teamkf._lapack's fallback."""
    c, piv, rank, _ = dpstrf(S, tol=tol, lower=0)
    keep = piv[:rank] - 1
    if rank == 0:
        return np.zeros((S_xy.shape[0], 0)), keep
    return dpotrs(c[:rank, :rank], np.ascontiguousarray(S_xy[:, keep].T), lower=0)[0].T, keep


def test_capsules_are_read():
    assert _lapack.AVAILABLE  # the SciPy pinned by the project publishes cython_lapack's capsules


@pytest.mark.parametrize("fallback", [False, True])
@pytest.mark.parametrize("n, rank", [(1, 1), (7, 7), (40, 13), (260, 260), (260, 200), (5, 0)])
def test_pstrf_solve_equals_scipy(n: int, rank: int, fallback: bool, monkeypatch):
    if fallback:  # SciPy without the cython_lapack capsules: scipy.linalg.lapack, same numbers
        monkeypatch.setattr(_lapack, "AVAILABLE", False)
    rng = np.random.default_rng(n + rank)
    X = rng.standard_normal((n, rank))
    S = X @ X.T
    S = 0.5 * (S + S.T)
    S_xy = rng.standard_normal((9, n))
    tol = 1e-9 * max(float(np.diag(S).max()), 1e-300)
    got, keep = _lapack.pstrf_solve(S, S_xy, tol)
    want, keep_ref = _scipy(S, S_xy, tol)
    assert np.array_equal(keep, keep_ref)
    assert got.shape == (9, keep.size) and keep.size == rank
    assert np.array_equal(got, want)
    if rank:  # the solve: X S_11 = S_xy[:, keep]
        np.testing.assert_allclose(got @ S[np.ix_(keep, keep)], S_xy[:, keep], rtol=1e-7, atol=1e-7 * np.abs(S_xy).max())


def test_pstrf_solve_leaves_its_inputs_alone_and_runs_on_threads():
    rng = np.random.default_rng(3)
    X = rng.standard_normal((120, 120))
    S = X @ X.T
    S = 0.5 * (S + S.T)
    S_xy = rng.standard_normal((4, 120))
    S0, Sxy0 = S.copy(), S_xy.copy()
    want, _ = _lapack.pstrf_solve(S, S_xy, 1e-12)
    assert np.array_equal(S, S0) and np.array_equal(S_xy, Sxy0)
    out: list[np.ndarray] = []
    threads = [threading.Thread(target=lambda: out.append(_lapack.pstrf_solve(S, S_xy, 1e-12)[0])) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(out) == 4 and all(np.array_equal(o, want) for o in out)
