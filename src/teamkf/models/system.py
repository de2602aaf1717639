"""The linear-Gaussian process observed by a team of agents.

Notation (team-MMSE paper, Section III-B; code steps are 0-based, ``k = t - 1``):

============  ==============================================================
symbol        meaning
============  ==============================================================
x(k)          state in R^{d_x}; x(0) ~ N(0, Sigma_x)                 (eq. 12)
A(k), Q(k)    x(k+1) = A(k) x(k) + w(k),  w(k) ~ N(0, Q(k))          (eq. 12)
C_i(k), R_i   y_i(k) = C_i(k) x(k) + v_i(k), v_i(k) ~ N(0, R_i(k))    (eq. 13)
y(k)          vec(y_1(k), ..., y_n(k)) = C(k) x(k) + v(k)
============  ==============================================================

Every matrix may be time-varying (the paper's Remark 4): pass a sequence
(or a 3-D array) indexed by the step ``k``; a constant matrix stands for all
steps. The primitive variables x(0), w(.), v_i(.) are independent (A3).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
from numpy.typing import ArrayLike

from .. import _validation as V
from ..exceptions import ShapeError

FloatArray = V.FloatArray

__all__ = ["LinearGaussianSystem"]


def _maybe_sequence(x: Any) -> bool:
    """True when ``x`` is a time sequence of matrices (a 3-D array or a list of 2-D ones)."""
    if isinstance(x, np.ndarray):
        return x.ndim == 3
    if isinstance(x, (list, tuple)) and len(x) > 0:
        try:
            return np.asarray(x[0], dtype=float).ndim == 2
        except (TypeError, ValueError):
            return False
    return False


def _stack(x: Any, name: str, shape: tuple[int | None, int | None], *, cov: bool = False, definite: bool = False) -> FloatArray:
    """A matrix or a time sequence of matrices, validated, as a (n_t, r, c) array."""
    if _maybe_sequence(x):
        mats = []
        for k, xk in enumerate(x):
            nm = f"{name}[t={k}]"
            if cov:
                mats.append(V.covariance(xk, nm, shape[0], definite=definite))
            else:
                mats.append(V.matrix(xk, nm, shape))
        if not mats:
            raise ShapeError(f"{name}: expected a matrix or a non-empty sequence of matrices, found an empty sequence")
        first = mats[0].shape
        for k, m in enumerate(mats):
            if m.shape != first:
                raise ShapeError(f"{name}[t={k}]: every step must have the same shape {V.shape_str(first)}, found {V.shape_str(m.shape)}")
        return V.frozen(np.stack(mats))
    if cov:
        return V.frozen(V.covariance(x, name, shape[0], definite=definite)[None])
    return V.frozen(V.matrix(x, name, shape)[None])


@dataclass(frozen=True, eq=False)
class LinearGaussianSystem:
    """A linear-Gaussian process observed by ``n`` agents (eqs. 12-13).

    Parameters
    ----------
    A : (d_x, d_x) array or sequence of them
        State transition; ``A[k]`` maps x(k) to x(k+1).
    Q : (d_x, d_x) array, scalar, or sequence
        Process-noise covariance (positive semi-definite). A scalar q means q I.
    Sigma_x : (d_x, d_x) array or scalar
        Covariance of the initial state x(0) (the paper's x(1)); PSD.
    C : sequence of (d_y^i, d_x) arrays (or sequences of them), one per agent
        Measurement matrices.
    R : sequence of (d_y^i, d_y^i) arrays or scalars (or sequences), one per agent
        Measurement-noise covariances (positive definite, A2). A single
        scalar or matrix is used for every agent.

    Examples
    --------
    >>> import numpy as np
    >>> from teamkf import LinearGaussianSystem
    >>> sys = LinearGaussianSystem(A=[[0.9]], Q=1.0, Sigma_x=1.0, C=[[[1.0]], [[1.0]]], R=0.1)
    >>> sys.n_agents, sys.dx, sys.dy
    (2, 1, (1, 1))
    """

    A: Any
    Q: Any
    Sigma_x: Any
    C: Any
    R: Any
    _n_time: int | None = field(init=False, repr=False, default=None)

    def __post_init__(self) -> None:
        A = _stack(self.A, "A", (None, None))
        dx = A.shape[1]
        if dx == 0:
            raise ShapeError("A: expected a d_x x d_x matrix with d_x >= 1, found 0x0; a system needs at least one state", argument="A")
        if A.shape[2] != dx:
            raise ShapeError(f"A: expected a square d_x x d_x matrix, found {V.shape_str(A.shape[1:])}")
        Q = _stack(self.Q, "Q", (dx, dx), cov=True)
        Sigma_x = V.frozen(V.covariance(self.Sigma_x, "Sigma_x", dx))
        C_in = self.C
        if isinstance(C_in, np.ndarray) and C_in.ndim == 2:
            raise ShapeError("C: expected one measurement matrix per agent (a list of matrices), found a single 2-D matrix; write C=[C_1, C_2, ...]")
        if not isinstance(C_in, (list, tuple, np.ndarray)) or len(C_in) == 0:
            raise ShapeError(f"C: expected a non-empty list with one measurement matrix per agent, found {type(C_in).__name__}")
        C = tuple(_stack(c, f"C[{i}]", (None, dx)) for i, c in enumerate(C_in))
        for i, c in enumerate(C):
            if c.shape[1] == 0:
                raise ShapeError(
                    f"C[{i}]: expected at least one measurement row (d_y^{i} >= 1), found 0x{dx}; drop the agent or give it a row", argument=f"C[{i}]"
                )
        n = len(C)
        R_in = self.R
        if np.isscalar(R_in) or (isinstance(R_in, np.ndarray) and R_in.ndim == 0):
            R_list: Sequence[Any] = [R_in] * n
        elif isinstance(R_in, np.ndarray) and R_in.ndim == 2 and n > 1:
            R_list = [R_in] * n
        else:
            R_list = list(R_in)
            if len(R_list) != n:
                raise ShapeError(f"R: expected one covariance per agent ({n}, as many as C), found {len(R_list)}")
        R = tuple(_stack(r, f"R[{i}]", (C[i].shape[1], C[i].shape[1]), cov=True, definite=True) for i, r in enumerate(R_list))
        lengths = [m.shape[0] for m in (A, Q, *C, *R) if m.shape[0] > 1]
        n_time = min(lengths) if lengths else None
        object.__setattr__(self, "A", A)
        object.__setattr__(self, "Q", Q)
        object.__setattr__(self, "Sigma_x", Sigma_x)
        object.__setattr__(self, "C", C)
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "_n_time", n_time)
        offs = np.concatenate([[0], np.cumsum([c.shape[1] for c in C])]).astype(int)
        object.__setattr__(self, "_offsets", offs)
        object.__setattr__(self, "_dy", tuple(int(c.shape[1]) for c in C))

    # --- sizes -------------------------------------------------------------
    @property
    def n_agents(self) -> int:
        return len(self.C)

    @property
    def dx(self) -> int:
        return int(self.A.shape[1])

    @property
    def dy(self) -> tuple[int, ...]:
        """Measurement dimension of each agent (computed once: the designs ask for it in their inner loops)."""
        return self._dy  # type: ignore[attr-defined, no-any-return]

    @property
    def dy_total(self) -> int:
        return int(self._offsets[-1])  # type: ignore[attr-defined]

    @property
    def offsets(self) -> FloatArray:
        """Start of each agent's block in the stacked measurement y(k)."""
        return self._offsets  # type: ignore[attr-defined, no-any-return]

    @property
    def is_time_varying(self) -> bool:
        return self._n_time is not None

    @property
    def n_time(self) -> int | None:
        """Number of steps covered by the time-varying matrices (None: constant)."""
        return self._n_time

    def require_horizon(self, n_steps: int) -> None:
        """Check that the time-varying matrices cover ``n_steps`` steps."""
        for name, m, need in (("A", self.A, n_steps - 1), ("Q", self.Q, n_steps - 1)):
            if m.shape[0] > 1 and m.shape[0] < need:
                raise ShapeError(
                    f"{name}: a horizon of {n_steps} steps needs {need} matrices, found {m.shape[0]}; give more steps or a shorter horizon"
                )
        for i in range(self.n_agents):
            for name, m in ((f"C[{i}]", self.C[i]), (f"R[{i}]", self.R[i])):
                if m.shape[0] > 1 and m.shape[0] < n_steps:
                    raise ShapeError(f"{name}: a horizon of {n_steps} steps needs {n_steps} matrices, found {m.shape[0]}")
        if n_steps > 10**5:  # every design and simulation steps through the horizon in Python: sized before it starts
            from .._budget import check_steps

            check_steps(int(n_steps), self.n_agents, what="a design or simulation")

    def require_time_invariant(self, what: str = "a steady-state design") -> None:
        if self.is_time_varying:
            raise ShapeError(f"system: {what} needs constant A, Q, C_i and R_i, found time-varying matrices; give a finite horizon instead")

    # --- matrices at a step ------------------------------------------------
    @staticmethod
    def _at(m: FloatArray, k: int) -> FloatArray:
        return m[0] if m.shape[0] == 1 else m[k]

    def A_at(self, k: int) -> FloatArray:
        return self._at(self.A, k)

    def Q_at(self, k: int) -> FloatArray:
        return self._at(self.Q, k)

    def C_at(self, i: int, k: int) -> FloatArray:
        return self._at(self.C[i], k)

    def R_at(self, i: int, k: int) -> FloatArray:
        return self._at(self.R[i], k)

    def C_stack(self, k: int) -> FloatArray:
        """C(k) = rows(C_1(k), ..., C_n(k))."""
        return np.vstack([self.C_at(i, k) for i in range(self.n_agents)])

    def R_stack(self, k: int) -> FloatArray:
        """R(k) = diag(R_1(k), ..., R_n(k))."""
        from .._linalg import block_diag

        return block_diag(*[self.R_at(i, k) for i in range(self.n_agents)])

    def transition(self, k_to: int, k_from: int) -> FloatArray:
        """Phi(k_to, k_from) = A(k_to - 1) ... A(k_from), identity when equal."""
        Phi = np.eye(self.dx)
        for s in range(k_from, k_to):
            Phi = self.A_at(s) @ Phi
        return Phi

    # --- builders ----------------------------------------------------------
    @classmethod
    def uav_formation(
        cls,
        n_agents: int,
        *,
        a_diag: float = 0.65,
        a_off: float = 0.1,
        c1: float = 2.0,
        c_other: float = 0.1,
        q: float = 1.0,
        r: float = 0.1,
        sigma_x: float = 1.0,
    ) -> "LinearGaussianSystem":
        """The UAV formation of Section IV-A.

        A_ii = 0.65, A_ij = 0.1 (i != j), C_1 = 2 * 1', C_i = 0.1 e_i' (i >= 2),
        Q = I, R = 0.1 I. The spectral radius of A is 0.55 + 0.1 n: the
        process is unstable for n >= 5 (1.55 at n = 10). Sigma_x = I is our
        choice (the paper does not state it).
        """
        n = V.positive_int(n_agents, "n_agents")
        A = a_off * np.ones((n, n)) + (a_diag - a_off) * np.eye(n)
        C = [c1 * np.ones((1, n))] + [c_other * np.eye(n)[i : i + 1] for i in range(1, n)]
        return cls(A=A, Q=q, Sigma_x=sigma_x, C=C, R=r)

    @classmethod
    def platoon(
        cls, n_agents: int = 4, *, q: float = 1.0, r: float = 0.1, sigma_x: float = 1.0, A: ArrayLike | None = None
    ) -> "LinearGaussianSystem":
        """The vehicular platoon of Section IV-B: every vehicle measures all positions (C_i = I).

        For ``n_agents = 4`` the paper's A is used; for other sizes A is the
        lower-triangular Toeplitz extension with diagonal 0.9 and sub-diagonals
        0.7, 0.7, 0.5, 0.5, ... (our choice; the paper gives only n = 4).
        """
        n = V.positive_int(n_agents, "n_agents")
        from .._budget import check_memory

        check_memory(
            8.0 * n * n * (n + 3),
            f"a platoon of {n:,} vehicles (every one measures all {n:,} positions)",
            argument="n_agents",
            fix="use fewer vehicles",
        )
        if A is None:
            col = [0.9, 0.7, 0.7] + [0.5] * max(0, n - 3)
            A_arr = np.zeros((n, n))
            for d in range(n):
                A_arr += np.diag(np.full(n - d, col[d]), -d)
        else:
            A_arr = np.asarray(A, dtype=float)
        return cls(A=A_arr, Q=q, Sigma_x=sigma_x, C=[np.eye(n)] * n, R=r)
