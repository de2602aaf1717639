"""The tuning step of the leaderboard: each baseline family's free parameters, per network, by its exact cost.

Every baseline family is linear with data-independent gains, so its exact team
cost J_T = Σ_{t<T} E[c(x(t), ẑ(t))] comes from the covariance recursion of the
stacked errors (:mod:`teamkf.estimators.linear_team`). :func:`tune` evaluates
the published defaults and every candidate of the family's documented grid
(:data:`GRIDS`) on the network, exactly, and returns the one with the smallest
J_T among those that do not diverge (ties: the first in grid order, the
published defaults first). The search is a fixed grid, so it is reproducible
bit for bit; nothing is random.

The grids (honest variants; ``docs/baselines.md``):

==========  ==========================================================================
family      candidates (besides the published defaults)
==========  ==========================================================================
local       none (no free parameter)
ci          ``feedback=True``: the CI diffusion (the fused estimate and its CI covariance
            are the next prior); the weights are optimized per step in both forms
diffusion   ``gains="exact"`` with the ``"matrix"`` (best linear unbiased) combination;
            age-aware weights; CI combination; lazy α = 0.1 with Metropolis weights
kcf         ε ∈ {0.03, 0.01, 0.003} (published 0.1)
icf         ``count`` ∈ {"all", "heard"} × ε ∈ {1/(Δ_max + 1), 0.5/Δ_max}
hcmci       ``count="heard"`` (published "all")
any other   none: its registry defaults
==========  ==========================================================================
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..estimators.registry import get_family

__all__ = ["GRIDS", "Candidate", "TuneResult", "candidates", "diverging", "tune"]


def _icf_grid(graph: Any) -> list[dict[str, Any]]:
    dmax = max((len(graph.in_neighbors(i)) for i in range(graph.n_agents)), default=0)
    out: list[dict[str, Any]] = [{"count": "heard"}]
    if dmax > 0:
        half = 0.5 / dmax
        out += [{"epsilon": half}, {"count": "heard", "epsilon": half}]
    return out


#: family -> candidate options (a list, or a function of the graph returning one), besides the published defaults
GRIDS: dict[str, Any] = {
    "local": [],
    "ci": [{"feedback": True}],
    "diffusion": [{"gains": "exact", "combination": "matrix"}, {"combination": "age"}, {"combination": "ci"}, {"lazy": 0.1}],
    "kcf": [{"epsilon": e} for e in (0.03, 0.01, 0.003)],
    "icf": _icf_grid,
    "hcmci": [{"count": "heard"}],
}


def candidates(family: str, graph: Any) -> list[dict[str, Any]]:
    """The published defaults ({}) followed by the family's grid on ``graph``."""
    grid = GRIDS.get(family, [])
    return [{}, *(grid(graph) if callable(grid) else grid)]


def _slope(y: np.ndarray) -> float:
    """Least-squares slope of ``y`` against 0, 1, ..., len(y) - 1."""
    t = np.arange(len(y), dtype=float)
    t -= t.mean()
    return float(np.dot(t, y - y.mean()) / np.dot(t, t))


def diverging(stage: Any) -> bool:
    """Still growing at the end of the horizon T (the numeric test; the divergence theorem is :mod:`~teamkf.experiments.divergence`).

    Either rule flags a row:

    * **fast growth**: a stage cost is not finite, or the last three are all above 1.5 times the one at 3T/4;
    * **sustained growth** (T >= 16; linear growth, which the first rule misses: a random walk's cost goes from
      300 to 400 over the last quarter of T = 400): the least-squares slope of the stage costs over the last
      quarter is positive, at least 3/4 of the slope over the third quarter (the growth does not slow down, as a
      converging transient's does: over a quarter it shrinks by rho^(T/4)), and the rise it gives over the second
      half, slope × T/2, is at least 10 % of the mean stage cost of the last quarter.

    A transient that converges more slowly than rho^(T/4) >= 3/4 (a time constant beyond about T steps) is still
    growing on this horizon and is flagged too.
    """
    sc = np.asarray(stage, dtype=float)
    T = len(sc)
    if T == 0:
        return False
    if (not np.all(np.isfinite(sc))) or bool(np.min(sc[-3:]) > 1.5 * sc[(3 * T) // 4]):
        return True
    if T < 16:
        return False
    q = T // 4
    s3, s4 = _slope(sc[T - 2 * q : T - q]), _slope(sc[T - q :])
    return bool(s4 > 0.0 and s4 >= 0.75 * s3 and s4 * (T / 2) >= 0.1 * float(np.mean(sc[T - q :])))


@dataclass
class Candidate:
    """One evaluated option set: its exact J_T, stage costs, whether it diverges, and the design time."""

    options: dict[str, Any]
    J_T: float
    stage_costs: np.ndarray
    diverging: bool
    seconds: float
    realizable: bool
    error: str | None = None


@dataclass
class TuneResult:
    """The tuned options of one family on one network (``best``) and every candidate tried, in grid order."""

    family: str
    variant: str
    tried: list[Candidate] = field(default_factory=list)

    @property
    def published(self) -> Candidate:
        return self.tried[0]

    @property
    def best(self) -> Candidate:
        ok = [c for c in self.tried if c.error is None and not c.diverging and np.isfinite(c.J_T)]
        pool = ok or [c for c in self.tried if c.error is None] or self.tried
        return min(pool, key=lambda c: c.J_T if np.isfinite(c.J_T) else np.inf)


def evaluate(family: str, system: Any, cost: Any, graph: Any, horizon: int, options: dict[str, Any]) -> Candidate:
    """Design ``family`` with ``options`` and its exact cost; a family error is recorded, not raised."""
    import time

    from ..exceptions import TeamkfError

    t0 = time.perf_counter()
    try:
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            d = get_family(family).build(system, cost, graph=graph, structure=graph, horizon=horizon, options=options)
    except (TeamkfError, np.linalg.LinAlgError) as exc:
        return Candidate(dict(options), float("nan"), np.full(horizon, np.nan), True, time.perf_counter() - t0, False, error=str(exc))
    sc = np.asarray(d.stage_costs, dtype=float)
    with np.errstate(over="ignore", invalid="ignore"):
        J = float(np.sum(sc))
    return Candidate(dict(options), J, sc, diverging(sc), time.perf_counter() - t0, bool(d.realizable))


def tune(family: str, system: Any, cost: Any, graph: Any, horizon: int, *, variant: str = "honest") -> TuneResult:
    """Evaluate the published defaults and the grid of ``family`` (``variant`` fixed), exactly; see the module docstring.

    Examples
    --------
    >>> from teamkf import LinearGaussianSystem, TeamCost, CommGraph
    >>> r = tune("kcf", LinearGaussianSystem.platoon(4), TeamCost.platoon(4, 10.0), CommGraph.line(4), 20)
    >>> [c.options for c in r.tried][:2], r.best.J_T <= r.published.J_T
    ([{'variant': 'honest'}, {'epsilon': 0.03, 'variant': 'honest'}], True)
    """
    res = TuneResult(family, variant)
    for opts in candidates(family, graph):
        res.tried.append(evaluate(family, system, cost, graph, horizon, {**opts, "variant": variant}))
    return res
