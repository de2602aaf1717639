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


def kalman_runs(P: FloatArray, C: FloatArray, Rm: FloatArray) -> FloatArray:
    """P(k|k) of :func:`~teamkf.estimators._kalman_common.kalman_step` for each predictor covariance of a stack P (R, d, d).

    The products are stacked; the Cholesky factor and solve are LAPACK's, one matrix at a time, as in the one-run step."""
    from .._lazy import scipy_linalg as sla

    lapack = sla.lapack
    Sy = sym(C @ P @ C.T + Rm)
    CP = C @ P
    K = np.empty((P.shape[0], C.shape[1], C.shape[0]))
    for r in range(P.shape[0]):
        c, info = lapack.dpotrf(Sy[r], lower=1, clean=0)
        if info != 0:
            raise np.linalg.LinAlgError(f"{info}-th leading minor of the innovation covariance not positive definite")
        X, info = lapack.dpotrs(c, CP[r], lower=1)
        if info != 0:  # pragma: no cover - potrs fails only on bad arguments
            raise ValueError(f"illegal value in argument {-info} of potrs")
        K[r] = X.T
    IKC = np.eye(P.shape[-1]) - K @ C
    return sym(IKC @ P @ IKC.swapaxes(-1, -2) + K @ Rm @ K.swapaxes(-1, -2))


def patterns(slots: Sequence[Slot], R: int) -> list[tuple[np.ndarray, list[int]]]:
    """The runs grouped by which slots they received: [(run indices, slot positions)]."""
    code = np.zeros(R, dtype=np.int64)
    for b, (_, _, m, _) in enumerate(slots):  # a few slots (in-neighbours x jitter)
        code |= m.astype(np.int64) << b
    uniq, inverse = np.unique(code, return_inverse=True)
    out = []
    for u_, c in enumerate(uniq.tolist()):
        out.append((np.flatnonzero(inverse == u_), [b for b in range(len(slots)) if (int(c) >> b) & 1]))
    return out


def fuse_delivered_runs(
    alg: Any, i: int, k: int, xbar: FloatArray, P: FloatArray, y_i: FloatArray, slots: Sequence[Slot]
) -> tuple[FloatArray, FloatArray]:
    """:meth:`~teamkf.estimators.linear_team.Algorithm.fuse_delivered` of every run: (r (R, d_x, 1), P⁺ (R, d_x, d_x))."""
    from .._linalg import block_diag

    R = xbar.shape[0]
    _, _, G, Y = alg.compensated(i, k, k)
    r = G @ y_i - Y @ xbar
    for j, s, m, p in slots:
        idx = np.flatnonzero(m)
        _, _, Gj, Yj = alg.compensated(j, s, k)
        r[idx] = r[idx] + (Gj @ p["y"][idx] - Yj @ xbar[idx])
    Pf = np.empty((R, *P.shape[-2:]))
    cache = alg.__dict__.setdefault("_stacked", {})
    for idx, which in patterns(slots, R):
        ls = [(i, k), *[(slots[b][0], slots[b][1]) for b in which]]
        key = (k, tuple(ls)) if alg.system.is_time_varying else tuple((a, k - s) for a, s in ls)
        CR = cache.get(key)
        if CR is None:
            comp = [alg.compensated(a, s, k) for a, s in ls]
            CR = np.vstack([c[0] for c in comp]), block_diag(*[c[1] for c in comp])
            if len(cache) < 4096:
                cache[key] = CR
        Pf[idx] = kalman_runs(P[idx], CR[0], CR[1])
    return r, Pf
