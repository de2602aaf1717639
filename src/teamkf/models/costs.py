"""Team costs c(x, z) = (L x - z)' S (L x - z) (team-MMSE paper, eq. 3 / 15).

============  ==============================================================
symbol        meaning
============  ==============================================================
z_i           agent i's estimate, in R^{d_z}; z = vec(z_1, ..., z_n)
L             rows(L_1, ..., L_n): agent i estimates L_i x        (eq. 4)
S             [S_ij], n d_z x n d_z, symmetric positive definite (A1)
============  ==============================================================

Builders: :meth:`TeamCost.average_tracking` (eq. 5), :meth:`TeamCost.platoon`
(eq. 6), :meth:`TeamCost.ring` (the closed formation the paper mentions after
eq. 6), :meth:`TeamCost.common_target` (eq. 1) and :meth:`TeamCost.mse` (every agent estimates the whole state; the
paper's example 3 with S = I). S and L may be time-varying (a sequence indexed
by the step), as the decentralized-LQG application needs.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from .. import _validation as V
from ..exceptions import ArgumentError, ShapeError

FloatArray = V.FloatArray

__all__ = ["TeamCost"]


def _difference_matrix(n: int, closed: bool) -> FloatArray:
    """Rows e_i - e_{i+1} for consecutive agents (and e_n - e_1 when closed)."""
    m = n if (closed and n > 2) else n - 1
    D = np.zeros((max(m, 0), n))
    for r in range(m):
        D[r, r] = 1.0
        D[r, (r + 1) % n] = -1.0
    return D


@dataclass(frozen=True, eq=False)
class TeamCost:
    """Quadratic team cost ``(L x - z)' S (L x - z)``.

    Parameters
    ----------
    S : (n d_z, n d_z) array or sequence of them
        Symmetric positive definite weight (A1).
    L : (n d_z, d_x) array or sequence of them
        Stacked L_i.
    n_agents : int
        Number of agents n; d_z = rows(S) / n.

    Examples
    --------
    >>> from teamkf import TeamCost
    >>> c = TeamCost.average_tracking(2, lam=4.0)
    >>> c.S_at(0)
    array([[2., 1.],
           [1., 2.]])
    """

    S: Any
    L: Any
    n_agents: int

    def __post_init__(self) -> None:
        n = V.positive_int(self.n_agents, "n_agents")
        S_arr = V.as_float_array(self.S, "S")
        if S_arr.ndim == 2:
            S_arr = S_arr[None]
        if S_arr.ndim != 3 or S_arr.shape[1] != S_arr.shape[2]:
            raise ShapeError(f"S: expected a square (n d_z) x (n d_z) matrix, found {V.shape_str(S_arr.shape[-2:])}")
        m = S_arr.shape[1]
        if m % n != 0:
            raise ShapeError(f"S: expected a size that is a multiple of n_agents = {n} (n d_z), found {m}x{m}")
        S_arr = np.stack([V.covariance(S_arr[k], "S" if S_arr.shape[0] == 1 else f"S[t={k}]", m, definite=True) for k in range(S_arr.shape[0])])
        L_arr = V.as_float_array(self.L, "L")
        if L_arr.ndim == 2:
            L_arr = L_arr[None]
        if L_arr.ndim != 3 or L_arr.shape[1] != m:
            raise ShapeError(
                f"L: expected a {m} x d_x matrix (n d_z rows, as S), found {V.shape_str(L_arr.shape[-2:] if L_arr.ndim >= 2 else L_arr.shape)}"
            )
        object.__setattr__(self, "n_agents", n)
        object.__setattr__(self, "S", V.frozen(S_arr))
        object.__setattr__(self, "L", V.frozen(L_arr))

    @property
    def dz(self) -> int:
        return int(self.S.shape[1] // self.n_agents)

    @property
    def dx(self) -> int:
        return int(self.L.shape[2])

    @property
    def is_time_varying(self) -> bool:
        return bool(self.S.shape[0] > 1 or self.L.shape[0] > 1)

    def S_at(self, k: int) -> FloatArray:
        return self.S[0] if self.S.shape[0] == 1 else self.S[k]

    def L_at(self, k: int) -> FloatArray:
        return self.L[0] if self.L.shape[0] == 1 else self.L[k]

    def block(self, i: int, j: int, k: int = 0) -> FloatArray:
        """S_ij at step k."""
        d = self.dz
        return self.S_at(k)[i * d : (i + 1) * d, j * d : (j + 1) * d]

    def L_block(self, i: int, k: int = 0) -> FloatArray:
        d = self.dz
        return self.L_at(k)[i * d : (i + 1) * d]

    def require_horizon(self, n_steps: int) -> None:
        for name, m in (("S", self.S), ("L", self.L)):
            if m.shape[0] > 1 and m.shape[0] < n_steps:
                raise ShapeError(f"cost.{name}: a horizon of {n_steps} steps needs {n_steps} matrices, found {m.shape[0]}")

    def require_time_invariant(self) -> None:
        if self.is_time_varying:
            raise ShapeError("cost: a steady-state design needs constant S and L, found time-varying ones; give a finite horizon")

    def check_system(self, dx: int, n_agents: int) -> None:
        """Check that the cost fits a system with ``dx`` states and ``n_agents`` agents."""
        if self.n_agents != n_agents:
            raise ShapeError(f"cost: expected a cost for {n_agents} agents (as the system), found one for {self.n_agents}")
        if self.dx != dx:
            raise ShapeError(f"cost.L: expected {dx} columns (d_x of the system), found {self.dx}")

    def value(self, x: ArrayLike, z: ArrayLike, k: int = 0) -> FloatArray:
        """c(x, z) for batches: x (..., d_x), z (..., n d_z) -> (...)."""
        e = np.asarray(x) @ self.L_at(k).T - np.asarray(z)
        return np.einsum("...a,ab,...b->...", e, self.S_at(k), e)

    # --- builders ----------------------------------------------------------
    @classmethod
    def _local_states(cls, n_agents: int, lam: float, d: int, coupling: str) -> "TeamCost":
        """x = vec(x_1..x_n), x_i in R^d, L = I, S = (I + lam W) (x) I_d for an n x n coupling W."""
        n = V.positive_int(n_agents, "n_agents")
        d = V.positive_int(d, "d")
        lam = _nonneg(lam, "lambda")
        if coupling == "ring" and n < 3:
            raise ArgumentError(
                f"n_agents: expected at least 3 agents for a ring (a closed formation), found {n}; use TeamCost.platoon for 2 agents, mse for 1",
                argument="n_agents",
            )
        from .._budget import check_memory

        check_memory(
            4 * 8.0 * (n * d) ** 2,  # W, I + lam W, S = (I + lam W) (x) I_d and L: dense (n d) x (n d)
            f"the {coupling} team cost of {n:,} agents (dense {n * d:,} x {n * d:,} weights)",
            argument="n_agents",
            fix="use fewer agents, or a population model for very large teams",
        )
        if coupling == "average":
            W = np.ones((n, n)) / n**2
        else:
            D = _difference_matrix(n, closed=coupling == "ring")
            W = D.T @ D
        S = np.asarray(np.kron(np.eye(n) + lam * W, np.eye(d)), dtype=np.float64)
        # S = (I + lam W) (x) I_d with W = D'D or 11'/n^2 positive semi-definite and lam >= 0: symmetric, eigenvalues >= 1
        # by construction, so the eigen-decomposition of __post_init__ (O((n d)^3): minutes for 10^4 agents) is skipped, as for mse
        self = object.__new__(cls)
        object.__setattr__(self, "S", V.frozen(S[None]))
        object.__setattr__(self, "L", V.frozen(np.eye(n * d)[None]))
        object.__setattr__(self, "n_agents", n)
        return self

    @classmethod
    def average_tracking(cls, n_agents: int, lam: float, d: int = 1) -> "TeamCost":
        """Eq. (5): sum_i ||x_i - z_i||^2 + lam ||mean(x) - mean(z)||^2; S_ij = (delta_ij + lam/n^2) I, L = I."""
        return cls._local_states(n_agents, lam, d, "average")

    @classmethod
    def platoon(cls, n_agents: int, lam: float, d: int = 1) -> "TeamCost":
        """Eq. (6): sum_i ||x_i - z_i||^2 + lam sum_{i<n} ||(x_i - x_{i+1}) - (z_i - z_{i+1})||^2."""
        return cls._local_states(n_agents, lam, d, "platoon")

    @classmethod
    def ring(cls, n_agents: int, lam: float, d: int = 1) -> "TeamCost":
        """Closed formation: as :meth:`platoon` plus the pair (n, 1) (for n >= 3)."""
        return cls._local_states(n_agents, lam, d, "ring")

    @classmethod
    def common_target(cls, n_agents: int, dx: int, lam: float) -> "TeamCost":
        """Every agent estimates the whole state x, and the mean estimate should be close to x.

        sum_i ||x - z_i||^2 + lam ||x - mean_i z_i||^2: S = (I + lam/n^2 11') (x) I, L = 1 (x) I.
        With n = 2 and a scalar x this is the introduction's example, eq. (1).
        """
        n = V.positive_int(n_agents, "n_agents")
        dx = V.positive_int(dx, "dx")
        lam = _nonneg(lam, "lambda")
        S = np.kron(np.eye(n) + lam / n**2, np.eye(dx))
        return cls(S=S, L=np.kron(np.ones((n, 1)), np.eye(dx)), n_agents=n)

    @classmethod
    def mse(cls, n_agents: int, dx: int) -> "TeamCost":
        """Plain MSE: each agent estimates the whole state, S = I, L = 1 (x) I.

        S = I is positive definite by construction, so it is not validated (an eigen-decomposition of an
        n d_x square matrix: 2.4 GiB of memory at n = d_x = 100), and it is a read-only Toeplitz view of
        2 n d_x numbers rather than a dense array (763 MiB at n = d_x = 100): S[i, j] = u[m - 1 - i + j]
        with u = e_{m-1}. NumPy reads it as any array; code that needs it contiguous copies it.
        """
        n = V.positive_int(n_agents, "n_agents")
        dx = V.positive_int(dx, "dx")
        m = n * dx
        u = np.zeros(2 * m - 1)
        u[m - 1] = 1.0
        u.setflags(write=False)
        S = np.lib.stride_tricks.as_strided(u[m - 1 :], shape=(1, m, m), strides=(0, -u.itemsize, u.itemsize), writeable=False)
        L = np.kron(np.ones((n, 1)), np.eye(dx))[None]
        L.setflags(write=False)
        self = object.__new__(cls)  # the checks of __post_init__ hold by construction
        object.__setattr__(self, "S", S)
        object.__setattr__(self, "L", L)
        object.__setattr__(self, "n_agents", n)
        return self


def _nonneg(x: Any, name: str) -> float:
    """A finite number >= 0 (complex, bools and strings refused: ArgumentError naming ``name``)."""
    v = V.real(x, name, what="a non-negative number")
    if v < 0:
        raise ArgumentError(f"{name}: expected a non-negative number, found {v:g}", argument=name)
    return v
