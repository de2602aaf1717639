"""Loss-tolerant steps stacked over runs: the per-run arithmetic of a family's ``agent_step_tolerant``, all runs at once.

On unreliable links each run of a Monte Carlo block has its own arrival pattern, so an agent's
carried covariance (HCMCI's Ω̄_i, ICF's J̄_i) differs from run to run. A family's
``agent_step_runs`` keeps them as stacks (R, d, d) and its estimates as (R, d, 1) and repeats the
operations of its one-run step in the same order: a stacked ``matmul`` is one BLAS call per slice
with the core shapes of the one-run product (``(d, d) @ (d, 1)`` stays a matrix-vector product),
the stacked inverse is the same LAPACK gufunc per matrix, element-wise operations do not depend on
the stacking, and a term that only some runs have (a neighbour that delivered) is added to those
runs only, in the one-run order. The estimates are therefore those of the one-run step bit for bit
(checked in ``tests/unit/test_lossy_mc.py``).

A slot is one possible packet of agent i's inbox at step k: ``(j, s, mask, payload)``, the sender j,
its sent step s, the runs (R,) bool in which it arrives at k, and j's stacked payload of step s.
Slots are listed in the order :func:`~teamkf.estimators.linear_team.delivered` sorts an inbox
(in-neighbour position, then sent step).
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from .._linalg import _INV
from .._validation import FloatArray
from .linear_team import process_noise, transition

Slot = tuple[int, int, np.ndarray, dict]


def inv_runs(a: FloatArray) -> FloatArray:
    """The inverse of each matrix of a stack (R, d, d): :func:`teamkf._linalg.inv` per matrix, the same numbers."""
    if _INV is None:  # pragma: no cover - another numpy layout
        return np.asarray(np.linalg.inv(a), dtype=float)
    with np.errstate(invalid="ignore", over="ignore", divide="ignore", under="ignore"):
        out = _INV(a, signature="d->d")
    if np.isnan(out).any():  # singular (or NaN in a): np.linalg.inv raises, or returns the same NaNs
        return np.asarray(np.linalg.inv(a), dtype=float)
    return out  # type: ignore[no-any-return]


def sym(a: FloatArray) -> FloatArray:
    """0.5 (a + aᵀ) of each matrix of a stack."""
    return 0.5 * (a + a.swapaxes(-1, -2))  # type: ignore[no-any-return]


def compensate_information_runs(system: Any, Y: FloatArray, s: int, k: int) -> tuple[FloatArray, FloatArray]:
    """:func:`~teamkf.estimators.linear_team.compensate_information` of each matrix of a stack Y (R, d, d), s < k."""
    Phi = transition(system, k, s)
    P = Phi @ inv_runs(Y) @ Phi.T + process_noise(system, k, s)
    Yn = sym(inv_runs(sym(P)))
    return Yn, np.asarray(Yn @ Phi, dtype=float)


def heard(slots: Sequence[Slot], R: int) -> dict[int, np.ndarray]:
    """{sender j: (R,) bool, the runs in which j delivered at least one packet}, senders in slot order."""
    out: dict[int, np.ndarray] = {}
    for j, _, m, _ in slots:
        out[j] = out[j] | m if j in out else m
    return out


def freshest_runs(slots: Sequence[Slot], R: int) -> list[tuple[int, list[tuple[int, np.ndarray, dict]]]]:
    """Per sender (in slot order), [(s, runs, payload)]: the runs (indices) whose most recent packet from j was sent at s.

    The runs of a sender's groups are disjoint; together they are the runs that heard j
    (:func:`~teamkf.estimators.linear_team.freshest`, run by run)."""
    by: dict[int, list[Slot]] = {}
    for sl in slots:
        by.setdefault(sl[0], []).append(sl)
    out = []
    for j, sls in by.items():
        taken = np.zeros(R, dtype=bool)
        groups = []
        for _, s, m, p in sorted(sls, key=lambda e: -e[1]):  # latest first
            idx = np.flatnonzero(m & ~taken)
            if idx.size:
                taken[idx] = True
                groups.append((s, idx, p))
        out.append((j, groups))
    return out


def per_run(values: dict[Any, float], keys: np.ndarray) -> FloatArray:
    """(R, 1, 1) array of ``values[key]`` for each run's key."""
    uniq, inverse = np.unique(keys, return_inverse=True)
    return np.array([values[int(u)] for u in uniq], dtype=float)[inverse].reshape(-1, 1, 1)  # type: ignore[no-any-return]
