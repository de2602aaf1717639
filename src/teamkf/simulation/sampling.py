"""Sample trajectories of a :class:`~teamkf.LinearGaussianSystem`, batched over runs (run axis first).

Every run draws its primitive variables (x(0), w(0:T-2), v(0:T-1)) from its
own stream, spawned from one ``np.random.SeedSequence``: run r gets the same
numbers whether it is drawn alone, in a batch, or on another worker.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .. import _validation as V
from .._validation import FloatArray
from ..exceptions import ArgumentError, ShapeError
from ..models import LinearGaussianSystem

__all__ = ["Paths", "sample", "sample_paths", "run_streams", "psd_sqrt"]


def psd_sqrt(M: FloatArray) -> FloatArray:
    """A factor B with B B' = M for a PSD M (eigen-decomposition, so singular M is fine)."""
    lam, U = np.linalg.eigh(0.5 * (M + M.T))
    return U * np.sqrt(np.clip(lam, 0.0, None))  # type: ignore[no-any-return]


def run_streams(seed: int | np.random.SeedSequence | np.random.Generator | None, n_runs: int) -> list[np.random.SeedSequence]:
    """One SeedSequence per run, spawned from ``seed`` (SciPy SPEC 7)."""
    if isinstance(seed, np.random.Generator):
        seq = seed.bit_generator.seed_seq
        if not isinstance(seq, np.random.SeedSequence):
            raise ArgumentError("rng: expected a seed or a Generator created from a seed", argument="rng")
    elif isinstance(seed, np.random.SeedSequence):
        seq = seed
    else:
        if seed is not None:  # SeedSequence's own messages do not name the argument
            seed = V.integer(seed, "rng", minimum=0, what="an integer seed (or a SeedSequence, a Generator, None)")
        seq = np.random.SeedSequence(seed)
    return seq.spawn(n_runs)


@dataclass(frozen=True, eq=False)
class Paths:
    """Sampled runs: the state, the measurements and the primitive noises that made them.

    Attributes
    ----------
    x : (n_runs, T, d_x)
    y : list over agents of (n_runs, T, d_y^i)
    w : (n_runs, T - 1, d_x)          process noises, x(k+1) = A x(k) + w(k)
    v : list over agents of (n_runs, T, d_y^i)   measurement noises
    """

    x: FloatArray
    y: list[FloatArray]
    w: FloatArray
    v: list[FloatArray]

    @property
    def n_runs(self) -> int:
        return int(self.x.shape[0])

    @property
    def n_steps(self) -> int:
        return int(self.x.shape[1])

    @property
    def y_stack(self) -> FloatArray:
        """(n_runs, T, d_y) all agents' measurements."""
        return np.concatenate(self.y, axis=2)

    @property
    def v_stack(self) -> FloatArray:
        return np.concatenate(self.v, axis=2)


def sample_paths(
    system: LinearGaussianSystem,
    n_steps: int,
    n_runs: int,
    *,
    rng: int | np.random.SeedSequence | np.random.Generator | None,
    streams: Sequence[np.random.SeedSequence] | None = None,
) -> Paths:
    """Draw ``n_runs`` independent runs of ``n_steps`` steps.

    Parameters
    ----------
    rng : seed, SeedSequence or Generator; run r uses stream ``spawn(n_runs)[r]``
    streams : explicit per-run SeedSequences (overrides ``rng``; used to draw a
        slice of a larger set of runs with identical numbers)
    """
    T = V.positive_int(n_steps, "n_steps")
    R_ = V.positive_int(n_runs, "n_runs")
    system.require_horizon(T)
    seqs = list(streams) if streams is not None else run_streams(rng, R_)
    if len(seqs) != R_:
        raise ShapeError(f"streams: expected {R_} SeedSequences, found {len(seqs)}", argument="streams")
    dx, dys = system.dx, system.dy
    dy = sum(dys)
    m = dx + (T - 1) * dx + T * dy
    Z = np.empty((R_, m))
    for r, s in enumerate(seqs):  # each run from its own stream
        Z[r] = np.random.default_rng(s).standard_normal(m)
    z0 = Z[:, :dx]
    zw = Z[:, dx : dx + (T - 1) * dx].reshape(R_, T - 1, dx)
    zv = Z[:, dx + (T - 1) * dx :].reshape(R_, T, dy)
    x = np.empty((R_, T, dx))
    x[:, 0] = z0 @ psd_sqrt(system.Sigma_x).T
    w = np.empty((R_, max(T - 1, 0), dx))
    for k in range(T - 1):
        w[:, k] = zw[:, k] @ psd_sqrt(system.Q_at(k)).T
        x[:, k + 1] = x[:, k] @ system.A_at(k).T + w[:, k]
    offs = system.offsets
    v, y = [], []
    for i in range(system.n_agents):
        vi = np.empty((R_, T, dys[i]))
        yi = np.empty((R_, T, dys[i]))
        for k in range(T):
            vi[:, k] = zv[:, k, offs[i] : offs[i + 1]] @ np.linalg.cholesky(system.R_at(i, k)).T
            yi[:, k] = x[:, k] @ system.C_at(i, k).T + vi[:, k]
        v.append(vi)
        y.append(yi)
    return Paths(x=x, y=y, w=w, v=v)


def sample(
    system: LinearGaussianSystem, n_steps: int, n_runs: int, *, rng: int | np.random.SeedSequence | np.random.Generator | None
) -> tuple[FloatArray, list[FloatArray]]:
    """Draw x(0:T-1) and every y_i(0:T-1) for ``n_runs`` runs (see :func:`sample_paths`).

    Returns
    -------
    x : (n_runs, n_steps, d_x)
    y : list over agents of (n_runs, n_steps, d_y^i)
    """
    p = sample_paths(system, n_steps, n_runs, rng=rng)
    return p.x, p.y
