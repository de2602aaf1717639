r"""The entry point :func:`design_cikf` (Algorithm 2: gains and covariances) and the ``cikf`` family record.

It checks the system, the graph (every edge with delay 1) and the options, builds the pseudo-state model
(:mod:`.model`), runs the joint (:mod:`.joint`) or block-operator (:mod:`.recursion`) recursion with Theorem 4's
gains (:mod:`.gains`) and returns a :class:`~teamkf.estimators.cikf.filter.CIKFDesign`.
"""

from __future__ import annotations

import time
from functools import lru_cache
from typing import Literal

import numpy as np

from ... import _validation as V
from ..._blas import blas_threads
from ...exceptions import ArgumentError, DetectabilityError, GraphError, ShapeError
from ...models import LinearGaussianSystem, TeamCost
from ...network.graph import CommGraph
from ..registry import Family, Option, _register_builtin
from .filter import CIKFDesign
from .gains import DEFAULT_RCOND
from .joint import _iterate_joint
from .kernels import Form, Method, _Dense, _Structured, _worker_pool
from .model import _neighbors, pseudo_state_model
from .recursion import _iterate

__all__ = ["design_cikf"]


@lru_cache(maxsize=8)
def _mse_cost(N: int, M: int) -> TeamCost:
    """TeamCost.mse(N, M), built once per size (validating S = I of size NM costs an NM x NM eigen-decomposition)."""
    return TeamCost.mse(N, M)


def design_cikf(
    system: LinearGaussianSystem,
    cost: TeamCost | None = None,
    graph: CommGraph | None = None,
    horizon: int | None = None,
    *,
    form: Form = "filter",
    rcond: float = DEFAULT_RCOND,
    method: Method | None = None,
    check: bool = True,
    gains: CIKFDesign | None = None,
    equations: Literal["corrected", "printed", "printed-43", "printed-45"] = "corrected",
    threads: int | None = 1,
    pinv: Literal["cholesky", "eigh"] = "cholesky",
) -> CIKFDesign:
    """Algorithm 2: optimal CIKF gains (Theorem 4) and the error covariances (corrected eqs. 41-47).

    Parameters
    ----------
    system : LinearGaussianSystem
        Time-invariant; x̄_0 = 0. (A, H) must be detectable (checked when ``check``); G need not be invertible.
    graph : CommGraph
        Every edge with delay 1 (one exchange per step); agent n uses the predictions of ``graph.in_neighbors(n)``
        (an undirected graph has both directions).
    horizon : int
        Number of steps T (gains and covariances for k = 0..T-1).
    cost : TeamCost, optional
        Team cost evaluated by ``stage_costs``; default ``TeamCost.mse(N, M)`` (S = I, L = 1 ⊗ I:
        the sum over agents of E|x(k) - x̂^n|^2). Agent n reports ẑ_n = L_n x̂^n.
    form : "filter" or "predictor"
        ẑ_n(k) = L_n x̂^n_{k|k} (default) or L_n x̂^n_{k|k-1} (the paper's Fig. 4 plots the predictor).
    rcond : float in (0, 1)
        Relative cut-off of the pseudo-inverses of Theorem 4 (module docstring; default 1e-9).
    method : "joint", "structured", "dense" or None (default)
        None: "joint" for the corrected equations, "structured" for the printed ones.
        "joint": one recursion on cov([e; ε]) with the update and the prediction fused into one map per
        agent and symmetric halves (module docstring; about 1.7-2x faster than "structured", memory
        N(r + M) squared; corrected equations only). "structured": the block products of eqs. (41)-(47)
        one by one, the arithmetic of the frozen reference (``tests/unit/test_cikf_reference.py``).
        The two agree to ~1e-12 on everything the gains produce (covariances, costs, errors); the consensus
        gains themselves agree only to the ~1e-8 to which Theorem 4 determines them (module docstring).
        "dense" forms M_k, K, F, I ⊗ Ã, ... as dense NM x NM matrices: the numbers of "structured", much
        slower (the benchmark's baseline).
    check : bool
        Check that (A, H) is detectable (Assumption 4).
    gains : CIKFDesign, optional
        Use that design's gains instead of Theorem 4's (same system, graph and horizon >= this one):
        the covariances are then the true ones of those gains.
    equations : "corrected" (default), "printed", "printed-43" or "printed-45"
        "printed" runs eqs. (43) and (45) as extracted (Π_{k|k-1} for Γ_k, Ã for Ǎ; "printed-43"/"-45": only
        that one) — only to quantify the errata; its covariances are not the filter's (evaluate its gains
        with ``gains=``).
    pinv : "cholesky" (default) or "eigh"
        How Theorem 4's singular covariances are inverted: pivoted Cholesky that drops innovation components
        whose conditional variance is below ``rcond`` times the largest variance (fast), or the truncated
        eigen pseudo-inverse (directions below ``rcond * lambda_max``). They agree to ~1e-4 dB (tested).
    threads : int or None
        Worker threads for the design's block products and the design's Monte Carlo methods, each with a
        single-threaded BLAS (default 1; 2 on an otherwise idle 2-core machine). The products are split
        over contiguous ranges of agents and every block is one BLAS call of the same shape whatever the
        number of threads, so the numbers do not depend on it (tested). Python threads do not spin like
        OpenBLAS's own threads, which can make a shared machine ten times slower (``docs/cikf.md``).
        None leaves the BLAS setting alone and uses no pool.

    Returns
    -------
    CIKFDesign
        The gains and error covariances, with the exact stage costs of the chosen form.

    Examples
    --------
    >>> from teamkf.study.random_field import random_field
    >>> from teamkf.estimators.cikf import design_cikf
    >>> system, graph = random_field(15, 6, rng=1)
    >>> d = design_cikf(system, None, graph, horizon=10)
    >>> d.estimator, d.stage_costs.shape, bool(d.mse()[-1] < d.mse()[0])
    ('cikf', (10,), True)
    """
    if isinstance(cost, CommGraph):
        raise ArgumentError(
            "cost: expected a TeamCost or None (TeamCost.mse), found a CommGraph; the 0.1 order "
            "design_cikf(system, graph, horizon, cost=...) is gone: write design_cikf(system, cost, graph, horizon)",
            argument="cost",
        )
    if not isinstance(graph, CommGraph):
        raise GraphError(f"graph: expected a CommGraph with unit delays, found {type(graph).__name__}", argument="graph")
    t0 = time.perf_counter()
    if not isinstance(system, LinearGaussianSystem):
        raise ArgumentError(f"system: expected a LinearGaussianSystem, found {type(system).__name__}", argument="system")
    model = pseudo_state_model(system)
    N, M = system.n_agents, system.dx
    nbrs = _neighbors(graph, N)
    if horizon is None:
        raise ShapeError("horizon: the CIKF gains are designed over a finite horizon (Algorithm 2), found horizon=None; give T steps")
    T = V.positive_int(horizon, "horizon")
    if cost is None:
        cost = _mse_cost(N, M)
    if not isinstance(cost, TeamCost):
        raise ShapeError(f"cost: expected a TeamCost (or None for TeamCost.mse), found {type(cost).__name__}")
    cost.check_system(M, N)
    cost.require_horizon(T)
    if form not in ("filter", "predictor"):
        raise ShapeError(f"form: expected 'filter' or 'predictor', found {form!r}")
    if method is None:
        method = "joint" if equations == "corrected" else "structured"
    if method not in ("structured", "joint", "dense"):
        raise ShapeError(f"method: expected 'structured', 'joint' or 'dense', found {method!r}")
    if method == "joint" and equations != "corrected":
        raise ArgumentError(
            f"equations: method='joint' runs the corrected eqs. (41)-(47) only (it propagates cov([e; ε]) of the filter), "
            f"found equations={equations!r}; use method='structured'",
            argument="equations",
        )
    if equations not in ("corrected", "printed", "printed-43", "printed-45"):
        raise ShapeError(f"equations: expected 'corrected' or 'printed' ('printed-43', 'printed-45': one of the two), found {equations!r}")
    if isinstance(rcond, bool) or not isinstance(rcond, (int, float, np.floating)) or not 0.0 < float(rcond) < 1.0:
        raise ShapeError(f"rcond: expected a relative cut-off in (0, 1), e.g. 1e-9, found {rcond!r}")
    rcond = float(rcond)
    if gains is not None:
        if not isinstance(gains, CIKFDesign):
            raise ShapeError(f"gains: expected a CIKFDesign whose gains to evaluate, found {type(gains).__name__}")
        if gains.system.n_agents != N or gains.system.dx != M or gains.neighbors != nbrs or gains.model.rank != model.rank:
            raise ShapeError("gains: expected a CIKF design for the same system and graph, found one for another")
        if gains.horizon < T:  # type: ignore[operator]
            raise ShapeError(f"gains: expected a design with horizon >= {T}, found {gains.horizon}")
    if check:
        from ..riccati import unstable_unobservable_modes

        bad = unstable_unobservable_modes(system.A_at(0), system.C_stack(0))
        if bad:
            raise DetectabilityError(
                f"system: expected (A, H) detectable (Assumption 4 of the CIKF), found unobservable unstable modes "
                f"{[complex(b) for b in bad[:4]]}; observe them with some agent's C, or pass check=False"
            )
    r = model.rank
    from ..._budget import check_memory

    check_memory(  # the gains K(t) (T, N, M, r) and the stored covariances: refused before the first allocation
        8.0 * T * N * M * (r + 2 * M),
        f"the CIKF gains and covariances of T = {T:,} steps (N = {N} agents, M = {M})",
        argument="horizon",
        fix="use a shorter horizon",
    )
    hoods = [np.array([n, *nbrs[n]], dtype=int) for n in range(N)]
    r_idx = [np.concatenate([np.arange(l * r, (l + 1) * r) for l in h]) for h in hoods]
    Ops = _Structured if method == "structured" else _Dense
    if pinv not in ("cholesky", "eigh"):
        raise ShapeError(f"pinv: expected 'cholesky' or 'eigh', found {pinv!r}")
    if threads is not None:
        threads = V.positive_int(threads, "threads")
    with blas_threads(None if threads is None else 1), _worker_pool(threads) as pool:
        if method == "joint":
            res = _iterate_joint(system, model, nbrs, cost, T, rcond, form, gains, pinv, pool, threads or 1)
        else:
            ops = Ops(N, r, hoods, r_idx, pool, threads or 1)
            res = _iterate(system, model, nbrs, cost, T, rcond, form, ops, gains, equations, pinv)
    info = {
        "rank_G": r,
        "G_invertible": model.invertible,
        "lambda_1": model.lambda_1,
        "lambda_m": model.lambda_m,
        "rcond": rcond,
        "method": method,
        "equations": equations,
        "form": form,
        "design_seconds": time.perf_counter() - t0,
        "n_edges": graph.n_edges,
        "evaluated_gains": gains is not None,
        "threads": threads,
        "pinv": pinv,
    }
    return CIKFDesign(
        estimator="cikf",
        horizon=T,
        stage_costs=V.frozen(res["stage"]),
        info=info,
        system=system,
        cost=cost,
        graph=graph,
        model=model,
        form=form,
        rcond=rcond,
        neighbors=nbrs,
        B_cons=res["B_cons"],
        B_innov=res["B_innov"],
        K=V.frozen(res["K"]),
        Sigma_pred=V.frozen(res["Sigma_pred"]),
        Sigma_filt=V.frozen(res["Sigma_filt"]),
        P_pred_trace=V.frozen(res["P_pred_trace"]),
    )


FAMILY = _register_builtin(
    Family(
        name="cikf",
        design=design_cikf,
        title="Consensus+Innovations Kalman filter with optimized gains (Das & Moura 2016, Algorithms 1-2, Theorem 4)",
        uses="graph",
        horizons=frozenset({"finite"}),
        unit_delays=True,
        options=(
            Option(
                name="form",
                default="filter",
                check=lambda v, k: V.choice(v, k, ("filter", "predictor")),
                doc='"filter": L x^n(k|k); "predictor": L x^n(k|k-1) (the paper\'s Fig. 4)',
            ),
            Option(
                name="method",
                default="joint",
                check=lambda v, k: V.choice(v, k, ("joint", "structured", "dense")),
                doc='"joint": one fused recursion on cov([e; ε]); "structured": eqs. (41)-(47) block by block, about 1.7-2x '
                'slower (same covariances and costs to ~1e-12); "dense": dense operators (a baseline)',
            ),
        ),
        lossy_links=True,  # capabilities (registry.Family)
        example="design_cikf(system, cost, graph, horizon=32)",
    )
)
