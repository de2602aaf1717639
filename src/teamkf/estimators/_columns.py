"""Symbolic columns of the linear team recursion (:func:`teamkf.estimators.linear_team.build_steps`), stored by blocks."""

from __future__ import annotations

from typing import Any

import numpy as np

from .._validation import FloatArray


class _Column:
    r"""A symbolic column of :func:`build_steps`: the coefficients of a linear expression over the stacked
    (ξ(k-1), y(k)), stored by blocks: Σ_c M_c · [the slot at column c].

    A family's step reads a handful of slots, so each ``M @ q`` multiplies d × d blocks rather than a
    d × (dim ξ + dim y) row of mostly zeros. It supports what :class:`Algorithm` allows on columns
    (``M @ q``, ``q ± q``, scalars times q); any other use (``np.vstack``, a product with a dense row)
    sees the dense coefficient matrix (``__array__``), and arithmetic with a dense row gives a dense row.
    """

    __array_ufunc__ = None  # NumPy defers M @ q, a * q, row ± q to the methods below
    __slots__ = ("blocks", "rows", "width")

    def __init__(self, blocks: dict[int, FloatArray], rows: int, width: int):
        self.blocks, self.rows, self.width = blocks, rows, width

    @property
    def shape(self) -> tuple[int, int]:
        return (self.rows, self.width)

    def __array__(self, dtype: Any = None, copy: Any = None) -> FloatArray:
        out = np.zeros((self.rows, self.width), dtype=dtype or float)
        for c, B in self.blocks.items():
            out[:, c : c + B.shape[1]] += B
        return out

    def _or_dense(self) -> Any:
        """Itself, or its dense row when its blocks would cost more than the row (an expression over many slots).

        Measured (one BLAS thread): a block product or sum costs 1.3-4 µs whatever d; a dense d × d product
        with a d × w row about 0.17-0.66 ns per multiply-add, 8 µs for d = 4, w = 750 and 61 µs for
        d = 20, w = 880: blocks pay off up to about max(3, d² w / 25000) of them.
        """
        if len(self.blocks) > max(3, self.rows * self.rows * self.width // 25000):
            return np.asarray(self)
        return self

    def __rmatmul__(self, M: Any) -> Any:
        M = np.asarray(M, dtype=float)
        return _Column({c: M @ B for c, B in self.blocks.items()}, M.shape[0], self.width)._or_dense()

    def __mul__(self, a: Any) -> Any:
        if np.ndim(a) != 0:
            return np.asarray(self) * a
        return _Column({c: a * B for c, B in self.blocks.items()}, self.rows, self.width)

    __rmul__ = __mul__

    def __neg__(self) -> "_Column":
        return self * -1.0

    def _plus(self, other: Any, sign: float) -> Any:
        if isinstance(other, _Column):
            out = dict(self.blocks)
            for c, B in other.blocks.items():
                if c in out:
                    out[c] = out[c] + B if sign > 0 else out[c] - B
                else:
                    out[c] = B if sign > 0 else -B
            return _Column(out, self.rows, self.width)._or_dense()
        if np.ndim(other) == 0 and other == 0:  # sum() starts from 0
            return self
        return np.asarray(self) + sign * np.asarray(other, dtype=float)

    def __add__(self, other: Any) -> Any:
        return self._plus(other, 1.0)

    __radd__ = __add__

    def __sub__(self, other: Any) -> Any:
        return self._plus(other, -1.0)

    def __rsub__(self, other: Any) -> Any:
        return (-self)._plus(other, 1.0)

    def place(self, out: FloatArray, row: int) -> None:
        """Write the coefficients into rows row .. row + rows of ``out`` (zeros there)."""
        for c, B in self.blocks.items():
            out[row : row + self.rows, c : c + B.shape[1]] = B


#: I_d, read-only (the selection blocks)
_EYES: dict[int, FloatArray] = {}


def _eye(d: int) -> FloatArray:
    e = _EYES.get(d)
    if e is None:
        e = np.eye(d)
        e.setflags(write=False)
        _EYES[d] = e
    return e
