"""Sample trajectories of a :class:`~teamkf.LinearGaussianSystem`, batched over runs (run axis first)."""

from __future__ import annotations

import numpy as np

from .. import _validation as V
from .._validation import FloatArray
from ..models import LinearGaussianSystem

__all__ = ["sample", "psd_sqrt"]


def psd_sqrt(M: FloatArray) -> FloatArray:
    """A factor B with B B' = M for a PSD M (eigen-decomposition, so singular M is fine)."""
    lam, U = np.linalg.eigh(0.5 * (M + M.T))
    return U * np.sqrt(np.clip(lam, 0.0, None))


def sample(system: LinearGaussianSystem, n_steps: int, n_runs: int, *, rng: np.random.Generator | int | None) -> tuple[FloatArray, list[FloatArray]]:
    """Draw x(0:T-1) and every y_i(0:T-1) for ``n_runs`` independent runs.

    Returns
    -------
    x : (n_runs, n_steps, d_x)
    y : list over agents of (n_runs, n_steps, d_y^i)
    """
    T = V.positive_int(n_steps, "n_steps")
    R_ = V.positive_int(n_runs, "n_runs")
    system.require_horizon(T)
    gen = np.random.default_rng(rng)
    dx = system.dx
    x = np.empty((R_, T, dx))
    x[:, 0] = gen.standard_normal((R_, dx)) @ psd_sqrt(system.Sigma_x).T
    for k in range(T - 1):
        w = gen.standard_normal((R_, dx)) @ psd_sqrt(system.Q_at(k)).T
        x[:, k + 1] = x[:, k] @ system.A_at(k).T + w
    ys = []
    for i in range(system.n_agents):
        yi = np.empty((R_, T, system.dy[i]))
        for k in range(T):
            v = gen.standard_normal((R_, system.dy[i])) @ np.linalg.cholesky(system.R_at(i, k)).T
            yi[:, k] = x[:, k] @ system.C_at(i, k).T + v
        ys.append(yi)
    return x, ys
