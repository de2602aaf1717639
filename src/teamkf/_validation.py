"""The one place where input checks and their messages live.

Every check names the argument as the caller wrote it (``"R[2]"``), says what
was expected and what was found, and suggests a fix.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .exceptions import (
    NotPositiveDefiniteError,
    NotSymmetricError,
    OptionalDependencyError,
    ShapeError,
)

FloatArray = NDArray[np.float64]

#: relative tolerance for symmetry and definiteness checks
SYM_RTOL = 1e-9


def frozen(a: FloatArray) -> FloatArray:
    """Return a read-only, C-contiguous float copy of ``a``."""
    out = np.array(a, dtype=float, order="C", copy=True)
    out.setflags(write=False)
    return out


def as_float_array(x: ArrayLike, name: str) -> FloatArray:
    """Convert to a float array; reject non-numeric input and non-finite values."""
    try:
        arr = np.asarray(x, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ShapeError(f"{name}: expected a numeric array, found {type(x).__name__} ({exc})") from None
    if not np.all(np.isfinite(arr)):
        raise ShapeError(f"{name}: expected finite numbers, found NaN or inf; check how {name} was built")
    return arr


def shape_str(shape: Sequence[int]) -> str:
    return "x".join(str(s) for s in shape) if len(shape) else "a scalar"


def matrix(x: ArrayLike, name: str, shape: tuple[int | None, int | None] | None = None) -> FloatArray:
    """A 2-D float matrix, optionally of a given shape (``None`` = any)."""
    arr = as_float_array(x, name)
    if arr.ndim != 2:
        want = "a 2-D matrix" if shape is None else f"a {shape_str([s if s is not None else 'k' for s in shape])} matrix"  # type: ignore[misc]
        raise ShapeError(f"{name}: expected {want}, found an array of shape {shape_str(arr.shape)}; write matrices as nested lists (rows)")
    if shape is not None:
        for ax, want_n in enumerate(shape):
            if want_n is not None and arr.shape[ax] != want_n:
                want = shape_str([s if s is not None else "k" for s in shape])  # type: ignore[misc]
                raise ShapeError(f"{name}: expected a {want} matrix, found {shape_str(arr.shape)}")
    return arr


def covariance(
    x: ArrayLike,
    name: str,
    dim: int | None = None,
    *,
    definite: bool = False,
) -> FloatArray:
    """A symmetric positive (semi-)definite matrix.

    A scalar ``q`` means ``q * I`` of size ``dim`` (which must then be given).
    """
    arr = as_float_array(x, name)
    kind = "positive definite" if definite else "positive semi-definite"
    if arr.ndim == 0:
        if dim is None:
            raise ShapeError(f"{name}: a scalar covariance needs a known dimension; write the full matrix")
        arr = float(arr) * np.eye(dim)
    if arr.ndim != 2 or arr.shape[0] != arr.shape[1] or (dim is not None and arr.shape[0] != dim):
        want = f"{dim}x{dim}" if dim is not None else "square"
        raise ShapeError(f"{name}: expected a {want} symmetric {kind} matrix, found {shape_str(arr.shape)}")
    scale = max(1.0, float(np.max(np.abs(arr)))) if arr.size else 1.0
    asym = float(np.max(np.abs(arr - arr.T))) if arr.size else 0.0
    if asym > SYM_RTOL * scale:
        raise NotSymmetricError(f"{name}: expected a symmetric matrix, found max |M - M'| = {asym:.3g}; use (M + M')/2 if the asymmetry is round-off")
    arr = 0.5 * (arr + arr.T)
    if arr.size:
        lam_min = float(np.linalg.eigvalsh(arr)[0])
        tol = SYM_RTOL * scale * arr.shape[0]  # round-off allowance for PSD
        tol_pd = 10 * arr.shape[0] * np.finfo(float).eps * scale  # numerically singular for PD
        if definite and lam_min <= tol_pd:
            raise NotPositiveDefiniteError(
                f"{name}: expected a symmetric positive definite matrix, found smallest eigenvalue {lam_min:.3g}; "
                "every noise covariance that is inverted must be strictly positive (add a small multiple of I)"
            )
        if not definite and lam_min < -tol:
            raise NotPositiveDefiniteError(f"{name}: expected a symmetric positive semi-definite matrix, found smallest eigenvalue {lam_min:.3g}")
    return arr


def positive_int(x: Any, name: str, *, minimum: int = 1) -> int:
    """An integer ``>= minimum`` (bools are rejected)."""
    if isinstance(x, bool) or not isinstance(x, (int, np.integer)):
        if isinstance(x, float) and float(x).is_integer():
            x = int(x)
        else:
            raise ShapeError(f"{name}: expected an integer >= {minimum}, found {x!r}")
    if x < minimum:
        raise ShapeError(f"{name}: expected an integer >= {minimum}, found {x}")
    return int(x)


def require(module: str, extra: str) -> Any:
    """Import an optional dependency or raise with the install command."""
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError:
        raise OptionalDependencyError(
            f"{module} is needed for this feature but is not installed; install it with: pip install 'teamkf[{extra}]'"
        ) from None


def describe(x: Any) -> str:
    """A short description of a value read from a scenario file, for error messages."""
    from collections.abc import Mapping

    if isinstance(x, bool):
        return f"the boolean {str(x).lower()}"
    if isinstance(x, (int, float)):
        return f"the number {x!r}"
    if isinstance(x, str):
        return f"the string {x!r}"
    if isinstance(x, list):
        return f"a list of {len(x)} items"
    if isinstance(x, Mapping):
        return "a table"
    return type(x).__name__
