"""Exact second moments of the agents' local Kalman filters over a horizon (the drop-aware design's forward pass).

See :mod:`teamkf.estimators.team_lossy` (module docstring) for where they enter.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator, Sequence

import numpy as np

from .._lazy import scipy_linalg as sla  # SciPy loads on first use
from .._linalg import block_diag
from .._validation import FloatArray
from ..models import LinearGaussianSystem

__all__ = ["LocalMoments", "local_filter_moments", "local_kalman_gains", "local_filter_errors", "innovations_to_measurements"]


@dataclass(frozen=True, eq=False)
class LocalMoments:
    """Exact second moments of every agent's own Kalman filter, over the horizon.

    K : list over steps of lists over agents of (d_x, d_y^j) gains
    Sigma : (N, N) covariance of all innovations ν = (ν(0), ..., ν(T-1)), ν(s) = (ν_1(s), ..., ν_n(s))
    Theta : list over steps k of (n d_x, N_k) arrays cov(e(k|k), ν(0:k)), N_k = (k+1) Σ d_y
    Pe : list over steps of (n d_x, n d_x) covariances of e(k|k) = (e_1(k|k), ..., e_n(k|k))
    """

    K: list[list[FloatArray]]
    Sigma: FloatArray
    Theta: list[FloatArray]
    Pe: list[FloatArray]


def local_filter_moments(system: LinearGaussianSystem, T: int) -> LocalMoments:
    r"""Joint covariances of the agents' local Kalman filters (see the module docstring).

    ε(0) = 1 ⊗ x(0); e(k|k) = U ε(k) - K̄ v(k), U = diag(I - K_j C_j); ν(k) = C̄ ε(k) + v(k);
    ε(k+1) = Ā e(k|k) + 1 ⊗ w(k). With Z(k) = cov(ε(k), ν(0:k-1)):
    Θ(k) = [U Z(k), U P_ε C̄ᵀ - K̄ R], Z(k+1) = Ā Θ(k), cov(ν(k), ν(0:k-1)) = C̄ Z(k).
    """
    n, dx, dyt = system.n_agents, system.dx, system.dy_total
    Sigma = np.zeros((T * dyt, T * dyt))
    ones = np.ones((n, n))
    P_eps = np.kron(ones, system.Sigma_x)
    Z = np.zeros((n * dx, 0))
    Ks, Thetas, Pes = local_kalman_gains(system, T), [], []
    for k in range(T):
        Cs = [system.C_at(j, k) for j in range(n)]
        K = Ks[k]
        U = block_diag(*[np.eye(dx) - K[j] @ Cs[j] for j in range(n)])
        Kb = block_diag(*K) if dyt else np.zeros((n * dx, 0))
        Cb = block_diag(*Cs) if dyt else np.zeros((0, n * dx))
        R = system.R_stack(k)
        blk = slice(k * dyt, (k + 1) * dyt)
        Sigma[blk, : k * dyt] = Cb @ Z
        Sigma[: k * dyt, blk] = Sigma[blk, : k * dyt].T
        Sv = Cb @ P_eps @ Cb.T + R
        Sigma[blk, blk] = 0.5 * (Sv + Sv.T)
        Theta = np.hstack([U @ Z, U @ P_eps @ Cb.T - Kb @ R])
        Thetas.append(Theta)
        Pe = U @ P_eps @ U.T + Kb @ R @ Kb.T
        Pe = 0.5 * (Pe + Pe.T)
        Pes.append(Pe)
        A = system.A_at(k)
        Ab = np.kron(np.eye(n), A)
        Z = Ab @ Theta
        P_eps = Ab @ Pe @ Ab.T + np.kron(ones, system.Q_at(k))
        P_eps = 0.5 * (P_eps + P_eps.T)
    return LocalMoments(Ks, Sigma, Thetas, Pes)


def local_kalman_gains(system: LinearGaussianSystem, T: int) -> list[list[FloatArray]]:
    """K_j(k) of every agent's own Kalman filter (prior 0, Σ_x), per step: (d_x, d_y^j) each."""
    n, dx = system.n_agents, system.dx
    P_loc = [np.array(system.Sigma_x, dtype=float) for _ in range(n)]
    Ks = []
    for k in range(T):
        Cs = [system.C_at(j, k) for j in range(n)]
        Rs = [system.R_at(j, k) for j in range(n)]
        K = []
        for j in range(n):
            Sy = Cs[j] @ P_loc[j] @ Cs[j].T + Rs[j]
            if Sy.size:
                Kj = sla.cho_solve(sla.cho_factor(0.5 * (Sy + Sy.T), lower=True), Cs[j] @ P_loc[j]).T
            else:
                Kj = np.zeros((dx, 0))
            K.append(Kj)
        Ks.append(K)
        A = system.A_at(k)
        for j in range(n):
            IKC = np.eye(dx) - K[j] @ Cs[j]
            Pf = IKC @ P_loc[j] @ IKC.T + K[j] @ Rs[j] @ K[j].T
            Pp = A @ Pf @ A.T + system.Q_at(k)
            P_loc[j] = 0.5 * (Pp + Pp.T)
    return Ks


def innovations_to_measurements(system: LinearGaussianSystem, K: Sequence[Sequence[FloatArray]], T: int) -> FloatArray:
    r"""B with y = B ν (stacked over steps): y_j(s) = ν_j(s) + C_j(s) x̂_j(s|s-1), x̂_j linear in ν_j(0:s-1).

    x̂_j(s+1|s) = A(s) (x̂_j(s|s-1) + K_j(s) ν_j(s)); block lower triangular, agent by agent.
    """
    n, dx, dyt, off = system.n_agents, system.dx, system.dy_total, system.offsets
    B = np.eye(T * dyt)
    for j in range(n):
        cols_j = [s * dyt + int(off[j]) + np.arange(system.dy[j]) for s in range(T)]
        pred = np.zeros((dx, T * dyt))  # x̂_j(s|s-1) as a map of ν
        for s in range(T):
            B[cols_j[s]] += system.C_at(j, s) @ pred
            upd = pred.copy()
            upd[:, cols_j[s]] += K[s][j]
            pred = system.A_at(s) @ upd
    return B


def _item_moments(system: LinearGaussianSystem, mom: LocalMoments, T: int, coords: str) -> LocalMoments:
    """The moments of the items: the innovations as they are, or the raw y_j(s) = Σ_t B(s, t) ν_j(t)."""
    if coords != "measurements":
        return mom
    B = innovations_to_measurements(system, mom.K, T)
    return LocalMoments(mom.K, B @ mom.Sigma @ B.T, [Th @ B[: Th.shape[1], : Th.shape[1]].T for Th in mom.Theta], mom.Pe)


def local_filter_errors(
    system: LinearGaussianSystem, K: Sequence[Sequence[FloatArray]], x0: FloatArray, w: FloatArray, v: FloatArray
) -> Iterator[tuple[int, FloatArray, FloatArray]]:
    r"""Per step k, every run's innovations ν(k) (R, Σ d_y) and filtered errors e(k|k) (R, n d_x) of the agents' own filters.

    Propagated from the primitive noises (x(0), w, v: R runs), never from the states, so unstable processes stay accurate:
    ε(0) = 1 ⊗ x(0), ν_j(k) = C_j ε_j(k) + v_j(k), e_j(k|k) = ε_j(k) - K_j ν_j(k), ε(k+1) = (I ⊗ A) e(k|k) + 1 ⊗ w(k)
    (I ⊗ A applied block by block)."""
    n, dx, off = system.n_agents, system.dx, system.offsets
    R, T = v.shape[:2]
    eps = np.tile(x0, (1, n))
    for k in range(T):
        nu_k = np.hstack([eps[:, j * dx : (j + 1) * dx] @ system.C_at(j, k).T for j in range(n)]) + v[:, k]
        ef = np.hstack([eps[:, j * dx : (j + 1) * dx] - nu_k[:, int(off[j]) : int(off[j]) + system.dy[j]] @ K[k][j].T for j in range(n)])
        yield k, nu_k, ef
        eps = (ef.reshape(R, n, dx) @ system.A_at(k).T).reshape(R, n * dx) + (np.tile(w[:, k], (1, n)) if k < w.shape[1] else 0.0)
