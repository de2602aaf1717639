"""Sample trajectories of a :class:`~teamkf.LinearGaussianSystem`, batched over runs (run axis first).

Every run draws its primitive variables (x(0), w(0:T-2), v(0:T-1)) from its
own counter-based stream: run r of seed s uses the Philox-4x64 generator with
key ``SeedSequence(s).generate_state(2, uint64)`` and counter ``(0, 0, r, 0)``
(:class:`RunStreams`). Run r's stream is built on demand from (seed, r), so it
gets the same numbers whether it is drawn alone, in a chunk, or on another
worker, and no per-run object is kept: a chunk of runs resets one generator's
counter run by run. Streams of different runs never overlap (a run would have
to draw 2^130 numbers to reach the next run's counter).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any, Sequence

import numpy as np

from .. import _validation as V
from .._validation import FloatArray
from ..exceptions import ArgumentError, ShapeError
from ..models import LinearGaussianSystem

__all__ = ["Paths", "RunStreams", "sample", "sample_paths", "run_streams", "psd_sqrt", "seed_sequence"]


def psd_sqrt(M: FloatArray) -> FloatArray:
    """A factor B with B B' = M for a PSD M (eigen-decomposition, so singular M is fine)."""
    lam, U = np.linalg.eigh(0.5 * (M + M.T))
    return U * np.sqrt(np.clip(lam, 0.0, None))  # type: ignore[no-any-return]


def run_streams(seed: int | np.random.SeedSequence | np.random.Generator | None, n_runs: int) -> list[np.random.SeedSequence]:
    """One SeedSequence per run, spawned from ``seed`` (SciPy SPEC 7)."""
    return seed_sequence(seed).spawn(n_runs)


def seed_sequence(seed: int | np.random.SeedSequence | np.random.Generator | None) -> np.random.SeedSequence:
    """The SeedSequence behind a seed: an int, a SeedSequence, a Generator created from a seed, or None (fresh entropy)."""
    if isinstance(seed, np.random.Generator):
        seq = seed.bit_generator.seed_seq
        if not isinstance(seq, np.random.SeedSequence):
            raise ArgumentError("rng: expected a seed or a Generator created from a seed", argument="rng")
        return seq
    if isinstance(seed, np.random.SeedSequence):
        return seed
    if seed is not None:  # SeedSequence's own messages do not name the argument
        seed = V.integer(seed, "rng", minimum=0, what="an integer seed (or a SeedSequence, a Generator, None)")
    return np.random.SeedSequence(None if seed is None else int(seed))


class RunStreams:
    """Counter-based per-run random streams: run r of a seed is Philox(key(seed), counter (0, 0, r, 0)).

    Parameters
    ----------
    seed : int, SeedSequence, Generator (created from a seed) or None (fresh entropy, see ``entropy``)

    Attributes
    ----------
    key : (2,) uint64, the Philox key, ``seed_sequence(seed).generate_state(2, np.uint64)``
    entropy, spawn_key : what reproduces the streams (``RunStreams(SeedSequence(entropy, spawn_key=spawn_key))``)

    Examples
    --------
    >>> import numpy as np
    >>> s = RunStreams(7)
    >>> a = s.normals(3, 5, 4)             # runs 3 and 4, 4 numbers each
    >>> b = s.generator(4).standard_normal(4)
    >>> bool(np.array_equal(a[1], b))
    True
    """

    def __init__(self, seed: int | np.random.SeedSequence | np.random.Generator | None):
        seq = seed_sequence(seed)
        self.entropy = seq.entropy
        self.spawn_key = tuple(int(k) for k in seq.spawn_key)
        self.key = seq.generate_state(2, dtype=np.uint64)

    def generator(self, run: int) -> np.random.Generator:
        """Run ``run``'s generator, built from (key, run)."""
        return np.random.Generator(np.random.Philox(key=self.key, counter=[0, 0, int(run), 0]))

    def normals(self, start: int, stop: int, m: int) -> FloatArray:
        """(stop - start, m) standard normals: row i is the first m draws of run start + i."""
        if not 0 <= start <= stop:
            raise ArgumentError(f"runs: expected 0 <= start <= stop, found {start}, {stop}", argument="runs")
        bg = np.random.Philox(key=self.key)
        gen = np.random.Generator(bg)
        st = bg.state
        Z = np.empty((stop - start, m))
        for i, r in enumerate(range(start, stop)):  # reset the counter run by run: the same as generator(r)
            st["state"]["counter"][:] = (0, 0, r, 0)
            st["buffer_pos"] = 4
            st["has_uint32"] = 0
            bg.state = st
            gen.standard_normal(out=Z[i])
        return Z


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

    @cached_property
    def y_stack(self) -> FloatArray:
        """(n_runs, T, d_y) all agents' measurements."""
        return np.concatenate(self.y, axis=2)

    @cached_property
    def v_stack(self) -> FloatArray:
        return np.concatenate(self.v, axis=2)


def sample_paths(
    system: LinearGaussianSystem,
    n_steps: int,
    n_runs: int,
    *,
    rng: int | np.random.SeedSequence | np.random.Generator | None,
    streams: Sequence[np.random.SeedSequence] | RunStreams | None = None,
    first_run: int = 0,
) -> Paths:
    """Draw the runs first_run to first_run + n_runs - 1, of ``n_steps`` steps each.

    Parameters
    ----------
    rng : seed, SeedSequence or Generator; run r uses the counter-based stream ``RunStreams(rng).generator(r)``
    streams : a :class:`RunStreams` (overrides ``rng``), or explicit per-run SeedSequences (one per run drawn)
    first_run : index of the first run drawn (with ``rng`` or a RunStreams): drawing runs a..b of a seed
        gives the numbers of those runs in any larger draw
    """
    V.instance(system, "system", LinearGaussianSystem, "a LinearGaussianSystem")
    T = V.positive_int(n_steps, "n_steps")
    R_ = V.positive_int(n_runs, "n_runs")
    first = V.positive_int(first_run, "first_run", minimum=0)
    system.require_horizon(T)
    dx, dys = system.dx, system.dy
    dy = sum(dys)
    m = dx + (T - 1) * dx + T * dy
    from .._budget import check_memory

    check_memory(
        8.0 * 3 * float(R_) * m,  # the normals, x and y (float64)
        f"sampling {R_:,} runs x {T} steps (d_x = {dx}, d_y = {dy})",
        argument="n_runs",
        fix="draw fewer runs or steps at a time (first_run= draws any later block of the same streams)",
    )
    if streams is None or isinstance(streams, RunStreams):
        rs = streams if streams is not None else RunStreams(rng)
        Z = rs.normals(first, first + R_, m)
    else:
        seqs = list(streams)
        if len(seqs) != R_:
            raise ShapeError(f"streams: expected {R_} SeedSequences, found {len(seqs)}", argument="streams")
        Z = np.empty((R_, m))
        for r, s in enumerate(seqs):  # each run from its own stream
            Z[r] = np.random.default_rng(s).standard_normal(m)
    z0 = Z[:, :dx]
    zw = Z[:, dx : dx + (T - 1) * dx].reshape(R_, T - 1, dx)
    zv = Z[:, dx + (T - 1) * dx :].reshape(R_, T, dy)
    x = np.empty((R_, T, dx))
    x[:, 0] = z0 @ psd_sqrt(system.Sigma_x).T
    w = np.empty((R_, max(T - 1, 0), dx))
    memo: dict[tuple[Any, ...], FloatArray] = {}  # factor once per distinct matrix (time-invariant systems)

    def factor(M: FloatArray, how: str) -> FloatArray:
        key = (how, M.__array_interface__["data"][0], M.shape, M.strides)  # the same stored matrix (a view of it)
        if key not in memo:
            memo[key] = np.asarray(psd_sqrt(M) if how == "sqrt" else np.linalg.cholesky(M), dtype=float)
        return memo[key]

    for k in range(T - 1):
        w[:, k] = zw[:, k] @ factor(system.Q_at(k), "sqrt").T
        x[:, k + 1] = x[:, k] @ system.A_at(k).T + w[:, k]
    offs = system.offsets
    v, y = [], []
    for i in range(system.n_agents):
        vi = np.empty((R_, T, dys[i]))
        yi = np.empty((R_, T, dys[i]))
        for k in range(T):
            vi[:, k] = zv[:, k, offs[i] : offs[i + 1]] @ factor(system.R_at(i, k), "chol").T
            yi[:, k] = x[:, k] @ system.C_at(i, k).T + vi[:, k]
        v.append(vi)
        y.append(yi)
    return Paths(x=x, y=y, w=w, v=v)


def sample(
    system: LinearGaussianSystem, n_steps: int, n_runs: int, *, rng: int | np.random.SeedSequence | np.random.Generator | None
) -> tuple[FloatArray, list[FloatArray]]:
    """Draw x(0:T-1) and every y_i(0:T-1) for ``n_runs`` runs (see :func:`sample_paths`).

    x(0) ~ N(0, Σ_x), x(k+1) = A x(k) + w(k), y_i(k) = C_i x(k) + v_i(k), with
    w(k) ~ N(0, Q) and v(k) ~ N(0, R) independent.

    Parameters
    ----------
    system : LinearGaussianSystem
        The process x(k+1) = A x(k) + w(k) and the agents' measurements y_i(k) = C_i x(k) + v_i(k).
    n_steps : int
        The number of steps T.
    n_runs : int
        The number of independent runs (paths).
    rng : int, SeedSequence, Generator or None
        The seed: run r uses the counter-based stream ``RunStreams(rng).generator(r)``, so the
        first runs of a larger draw are the same numbers.

    Returns
    -------
    x : (n_runs, n_steps, d_x) array
        The states.
    y : list over agents of (n_runs, n_steps, d_y^i) arrays
        Each agent's measurements.

    Examples
    --------
    >>> from teamkf import LinearGaussianSystem, sample
    >>> x, y = sample(LinearGaussianSystem.platoon(4), 50, n_runs=10, rng=1)
    >>> x.shape, len(y), y[0].shape
    ((10, 50, 4), 4, (10, 50, 4))
    """
    p = sample_paths(system, n_steps, n_runs, rng=rng)
    return p.x, p.y
