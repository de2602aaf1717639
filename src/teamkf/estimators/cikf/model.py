r"""Proposition 1 of Das & Moura (2016): the pseudo-state model of a linear-Gaussian system.

With H̄_n = H_n' R_n^-1 H_n (5) and G = Σ_n H̄_n (7), the pseudo-state y = G x obeys
y_{k+1} = Ã y_k + Ǎ x_k + G v_k with Ã = G A G† (11), Ǎ = G A Ĩ (13), Ĩ = I - G† G (15), and agent n's
pseudo-observation z̃^n = H̄_n G† y + H̄_n Ĩ x + H_n' R_n^-1 r^n = H̃_n y + Ȟ_n x + ... (12, 14).
:func:`pseudo_state_model` builds these matrices in the reduced coordinates y_r = U' y of range(G)
(:mod:`teamkf.estimators.cikf`, "Reduced coordinates"); ``_neighbors`` reads Ω_n off the graph.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ... import _validation as V
from ..._lazy import scipy_linalg as sla  # SciPy / networkx load on first use
from ..._validation import FloatArray
from ...exceptions import DetectabilityError, GraphError, ShapeError
from ...models import LinearGaussianSystem
from ...network.graph import CommGraph

__all__ = ["G_RTOL", "PseudoStateModel", "pseudo_state_model"]


#: eigenvalues of G below G_RTOL * lambda_max(G) count as zero (rank of G)
G_RTOL = 1e-10


@dataclass(frozen=True, eq=False)
class PseudoStateModel:
    r"""The pseudo-state model of Proposition 1, eqs. (4)-(16), for any (A, H) — G may be singular.

    Full (paper) coordinates: ``G``, ``G_pinv`` (G†), ``I_tilde`` (Ĩ), ``A_tilde``
    (Ã), ``A_check`` (Ǎ), ``H_bar``, ``H_tilde``, ``H_check`` (one M x M matrix per
    agent, stacked on the first axis). Reduced coordinates on range(G):
    ``U`` (M x r), ``lam`` (the r non-zero eigenvalues of G), ``G_r`` = Λ U',
    ``A_tilde_r``, ``A_check_r``, ``C_tilde`` (per agent, M_n x r) and
    ``innov_map`` (per agent, H_n' R_n^-1, M x M_n).
    """

    G: FloatArray
    G_pinv: FloatArray
    I_tilde: FloatArray
    A_tilde: FloatArray
    A_check: FloatArray
    H_bar: FloatArray
    H_tilde: FloatArray
    H_check: FloatArray
    U: FloatArray
    lam: FloatArray
    G_r: FloatArray
    A_tilde_r: FloatArray
    A_check_r: FloatArray
    C_tilde: tuple
    innov_map: tuple

    @property
    def rank(self) -> int:
        """rank(G) = r."""
        return int(self.lam.size)

    @property
    def dx(self) -> int:
        return int(self.G.shape[0])

    @property
    def invertible(self) -> bool:
        """Whether G is invertible (distributed observability, [5] of the paper)."""
        return self.rank == self.dx

    @property
    def lambda_1(self) -> float:
        """Smallest non-zero eigenvalue of G (Theorem 3)."""
        return float(self.lam.min())

    @property
    def lambda_m(self) -> float:
        """Largest eigenvalue of G (Theorem 3)."""
        return float(self.lam.max())


def _frozen_stack(mats: Sequence[FloatArray]) -> FloatArray:
    return V.frozen(np.stack(mats)) if len(mats) else V.frozen(np.zeros((0, 0, 0)))


def pseudo_state_model(system: LinearGaussianSystem, *, rtol: float = G_RTOL) -> PseudoStateModel:
    """Build G, G†, Ĩ, Ã, Ǎ, H̄_n, H̃_n, Ȟ_n (Proposition 1) and the reduced coordinates on range(G).

    Parameters
    ----------
    system : LinearGaussianSystem (time-invariant)
    rtol : float
        Eigenvalues of G below ``rtol * lambda_max(G)`` count as zero.

    Examples
    --------
    >>> import numpy as np
    >>> from teamkf import LinearGaussianSystem
    >>> from teamkf.estimators.cikf import pseudo_state_model
    >>> sys = LinearGaussianSystem(A=np.eye(3), Q=1.0, Sigma_x=1.0, C=[[[1.0, 0, 0]], [[0, 1.0, 0]]], R=1.0)
    >>> m = pseudo_state_model(sys)
    >>> m.rank, m.invertible, float(np.abs(m.H_check).max())
    (2, False, 0.0)
    """
    if not isinstance(system, LinearGaussianSystem):
        raise ShapeError(f"system: expected a LinearGaussianSystem, found {type(system).__name__}")
    system.require_time_invariant("the CIKF (its pseudo-state model, Proposition 1)")
    M, N = system.dx, system.n_agents
    A = system.A_at(0)
    H_bar, maps = [], []
    for n in range(N):
        C, R = system.C_at(n, 0), system.R_at(n, 0)
        Hm = sla.cho_solve(sla.cho_factor(R, lower=True), C).T  # H_n' R_n^-1 (M x M_n)
        Hb = Hm @ C
        H_bar.append(0.5 * (Hb + Hb.T))
        maps.append(Hm)
    G = np.sum(H_bar, axis=0)
    G = 0.5 * (G + G.T)
    w, Q = np.linalg.eigh(G)
    top = max(float(w[-1]), 0.0)
    if top <= 0.0:
        raise DetectabilityError(
            "system: expected at least one observed direction (G = sum_n H_n' R_n^-1 H_n != 0), found G = 0; give some agent a non-zero C"
        )
    keep = w > float(rtol) * top
    U, lam = Q[:, keep], w[keep]
    G_pinv = (U / lam) @ U.T
    I_tilde = np.eye(M) - U @ U.T
    A_tilde = G @ A @ G_pinv
    A_check = G @ A @ I_tilde
    G_r = lam[:, None] * U.T
    A_tilde_r = (lam[:, None] * (U.T @ A @ U)) / lam[None, :]
    A_check_r = lam[:, None] * (U.T @ A @ I_tilde)
    C_tilde = tuple(V.frozen((system.C_at(n, 0) @ U) / lam[None, :]) for n in range(N))
    return PseudoStateModel(
        V.frozen(G),
        V.frozen(G_pinv),
        V.frozen(I_tilde),
        V.frozen(A_tilde),
        V.frozen(A_check),
        _frozen_stack(H_bar),
        _frozen_stack([Hb @ G_pinv for Hb in H_bar]),
        _frozen_stack([Hb @ I_tilde for Hb in H_bar]),
        V.frozen(U),
        V.frozen(lam),
        V.frozen(G_r),
        V.frozen(A_tilde_r),
        V.frozen(A_check_r),
        C_tilde,
        tuple(V.frozen(m) for m in maps),
    )


def _neighbors(graph: CommGraph, n_agents: int) -> tuple[tuple[int, ...], ...]:
    if not isinstance(graph, CommGraph):
        raise GraphError(f"graph: expected a CommGraph, found {type(graph).__name__}; build one with CommGraph.from_networkx(G, default_delay=1)")
    if graph.n_agents != n_agents:
        raise GraphError(f"graph: expected a graph of {n_agents} agents (as the system), found one of {graph.n_agents}")
    slow = [(i, j, d) for (i, j, d) in graph.edges if d != 1]
    if slow:
        raise GraphError(
            f"graph: expected every edge to have delay 1 (the CIKF exchanges once per step), found {len(slow)} "
            f"edges with other delays, e.g. {slow[0]}; use graph.with_delay(1)"
        )
    return tuple(graph.in_neighbors(n) for n in range(n_agents))
