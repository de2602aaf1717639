"""LAPACK calls that release the GIL: the pivoted Cholesky and its solve, for per-agent work on threads.

SciPy's ``scipy.linalg.lapack`` wrappers hold the GIL while LAPACK runs, so
the per-agent factorizations of the CIKF gain design (Theorem 4: one pivoted
Cholesky of a ~250 x 250 matrix per agent and step) do not run in parallel on
worker threads (measured: 0.35 ms each serially, 0.38 ms each on 2 threads).
The same Fortran routines are reached here through the function pointers that
``scipy.linalg.cython_lapack`` publishes (its ``__pyx_capi__`` capsules, the
route Numba takes), called with :mod:`ctypes`, which releases the GIL during a
foreign call. The routines, their arguments and hence their results are the
ones ``scipy.linalg.lapack.dpstrf`` / ``dpotrs`` compute.

If the capsules cannot be read (another SciPy layout), :data:`AVAILABLE` is
False and :func:`pstrf_solve` uses ``scipy.linalg.lapack``.
"""

from __future__ import annotations

import ctypes
from typing import Any

import numpy as np
from scipy.linalg import lapack

from ._validation import FloatArray

__all__ = ["AVAILABLE", "pstrf_solve"]


def _function(module: Any, name: str, *argtypes: Any) -> Any:
    """The C function ``name`` of ``module`` (scipy.linalg.cython_lapack) as a GIL-releasing ctypes function."""
    capsule = module.__pyx_capi__[name]
    api = ctypes.pythonapi
    api.PyCapsule_GetName.restype = ctypes.c_char_p
    api.PyCapsule_GetName.argtypes = [ctypes.py_object]
    api.PyCapsule_GetPointer.restype = ctypes.c_void_p
    api.PyCapsule_GetPointer.argtypes = [ctypes.py_object, ctypes.c_char_p]
    address = api.PyCapsule_GetPointer(capsule, api.PyCapsule_GetName(capsule))
    if not address:
        raise ValueError(f"no address for {name}")
    return ctypes.CFUNCTYPE(None, *argtypes)(address)


_p = ctypes.c_void_p
try:
    from scipy.linalg import cython_lapack

    # dpstrf(uplo, n, a, lda, piv, rank, tol, work, info); dpotrs(uplo, n, nrhs, a, lda, b, ldb, info)
    _dpstrf = _function(cython_lapack, "dpstrf", _p, _p, _p, _p, _p, _p, _p, _p, _p)
    _dpotrs = _function(cython_lapack, "dpotrs", _p, _p, _p, _p, _p, _p, _p, _p)
    AVAILABLE = True
except Exception:  # pragma: no cover - depends on the SciPy build
    AVAILABLE = False

_UPPER = ctypes.c_char(b"U")


def pstrf_solve(S: FloatArray, S_xy: FloatArray, tol: float) -> tuple[FloatArray, np.ndarray]:
    """Pivoted Cholesky of the symmetric PSD ``S`` stopped at ``tol``, then ``S_xy[:, keep] S_11^{-1}``.

    LAPACK ``dpstrf`` (upper, absolute tolerance ``tol`` on the largest remaining diagonal) gives
    P' S P = U'U with rank k; ``keep`` (0-based) are the first k pivots and S_11 = S[keep][:, keep].
    Returns (X, keep) with X = S_xy[:, keep] S_11^{-1} (``dpotrs``), shape (rows of S_xy, k).

    ``S`` must be exactly symmetric (its C-order buffer is read as the column-major matrix); it is
    not modified.
    """
    n = S.shape[0]
    if not AVAILABLE:
        return _pstrf_solve_scipy(S, S_xy, tol)
    a = np.array(S, dtype=np.float64, order="C")  # symmetric: its C-order buffer is S in column-major order
    piv = np.empty(n, dtype=np.intc)
    work = np.empty(2 * n)
    nn, rank, info, t = ctypes.c_int(n), ctypes.c_int(0), ctypes.c_int(0), ctypes.c_double(tol)
    _dpstrf(
        ctypes.byref(_UPPER), ctypes.byref(nn), a.ctypes.data, ctypes.byref(nn), piv.ctypes.data,
        ctypes.byref(rank), ctypes.byref(t), work.ctypes.data, ctypes.byref(info),
    )  # fmt: skip
    if info.value < 0:  # pragma: no cover - an argument error is a bug here
        raise RuntimeError(f"dpstrf: argument {-info.value} is invalid")
    k = rank.value
    keep = piv[:k].astype(np.intp) - 1
    # column-major B (k x m) with ldb = k is the C-order (m, k) array S_xy[:, keep]; X overwrites it
    X = np.ascontiguousarray(S_xy[:, keep], dtype=np.float64)
    if k:
        kk, m = ctypes.c_int(k), ctypes.c_int(X.shape[0])
        _dpotrs(
            ctypes.byref(_UPPER), ctypes.byref(kk), ctypes.byref(m), a.ctypes.data, ctypes.byref(nn),
            X.ctypes.data, ctypes.byref(kk), ctypes.byref(info),
        )  # fmt: skip
        if info.value != 0:  # pragma: no cover
            raise RuntimeError(f"dpotrs: info = {info.value}")
    return X, keep


def _pstrf_solve_scipy(S: FloatArray, S_xy: FloatArray, tol: float) -> tuple[FloatArray, np.ndarray]:
    """:func:`pstrf_solve` through ``scipy.linalg.lapack`` (holds the GIL): the fallback, and the reference of the tests."""
    c, piv, rank, _ = lapack.dpstrf(S, tol=tol, lower=0)
    keep = (piv[:rank] - 1).astype(np.intp)
    if rank == 0:
        return np.zeros((S_xy.shape[0], 0)), keep
    X = lapack.dpotrs(c[:rank, :rank], np.ascontiguousarray(S_xy[:, keep].T), lower=0)[0].T
    return np.ascontiguousarray(X), keep
