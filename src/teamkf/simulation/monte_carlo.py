"""Monte Carlo of estimators: team cost per step and in total, with 95 % confidence intervals.

All estimators are evaluated on the same sampled paths (common random
numbers), vectorized over runs. Two ways to get each estimator's errors:

* ``path="errors"`` (default): ``design.errors(paths)`` propagates the
  estimator's error recursion from the primitive noises, e = L x - z without
  ever subtracting two large numbers. It stays accurate when A is unstable
  (the UAV formation with n = 10 has spectral radius 1.55: x(100) ~ 1e19).
* ``path="runtime"``: the agents run in the message-passing runtime on the
  sampled measurements and e = L x - z is formed from the simulated state —
  the honest check of the information discipline, accurate for stable
  systems only.

Runs are drawn in batches from per-run streams (``SeedSequence(seed).spawn``)
so the numbers do not depend on the batch size.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal, Mapping

import numpy as np

from .. import _validation as V
from .._validation import FloatArray
from ..exceptions import ArgumentError, ShapeError
from .online import run_online
from .sampling import run_streams, sample_paths

__all__ = ["MonteCarloResult", "monte_carlo", "Z95"]

Z95 = 1.959963984540054


@dataclass(frozen=True, eq=False)
class MonteCarloResult:
    """Sample team costs of one estimator.

    Attributes
    ----------
    stage_mean, stage_sem : (T,) mean of c(x(k), z(k)) over runs and its standard error
    total_mean, total_sem : mean and standard error of sum_k c(x(k), z(k))
    n_runs : int
    path : "errors" or "runtime"
    """

    estimator: str
    n_runs: int
    stage_mean: FloatArray
    stage_sem: FloatArray
    total_mean: float
    total_sem: float
    path: str = "errors"

    @property
    def ci95(self) -> tuple[float, float]:
        return (self.total_mean - Z95 * self.total_sem, self.total_mean + Z95 * self.total_sem)

    @property
    def stage_ci95(self) -> tuple[FloatArray, FloatArray]:
        return (self.stage_mean - Z95 * self.stage_sem, self.stage_mean + Z95 * self.stage_sem)

    @property
    def diverged(self) -> bool:
        """True when the simulated cost is not finite (the estimator diverges on this system)."""
        return not bool(np.isfinite(self.total_mean))

    def summary(self) -> dict[str, Any]:
        """JSON-ready (strict: non-finite values are null, with ``"diverged": true``)."""
        from ..estimators.base import json_float

        lo, hi = self.ci95
        out: dict[str, Any] = {
            "method": "monte-carlo",
            "runs": self.n_runs,
            "total_cost": json_float(self.total_mean),
            "ci95": [json_float(lo), json_float(hi)],
            "stage_costs": [json_float(c) for c in self.stage_mean],
        }
        if self.diverged:
            out["diverged"] = True
        return out

    def to_pandas(self) -> Any:
        pd = V.require("pandas", "dask")
        lo, hi = self.stage_ci95
        return pd.DataFrame(
            {"estimator": self.estimator, "step": np.arange(len(self.stage_mean)), "stage_cost": self.stage_mean, "ci95_low": lo, "ci95_high": hi}
        )

    def plot(self, ax: Any = None, **kwargs: Any) -> Any:
        """Stage cost against the step with its 95 % band (matplotlib, lazy)."""
        from ..plotting import _pyplot

        plt = _pyplot()
        if ax is None:
            _, ax = plt.subplots(figsize=(6, 4))
        t = np.arange(1, len(self.stage_mean) + 1)
        lo, hi = self.stage_ci95
        (line,) = ax.plot(t, self.stage_mean, label=f"{self.estimator} (MC, {self.n_runs} runs)", **kwargs)
        ax.fill_between(t, lo, hi, alpha=0.2, color=line.get_color())
        ax.set_xlabel("t")
        ax.set_ylabel("E[c(x(t), z(t))]")
        ax.legend()
        return ax


def _team_errors(design: Any, paths: Any, path: str, graph: Any) -> FloatArray:
    if path == "errors":
        return design.errors(paths)  # type: ignore[no-any-return]
    graph = graph if graph is not None else getattr(design, "graph", None)
    if graph is not None:
        from .runtime import graph_agents, run_graph

        z = run_graph(graph_agents(design), graph, paths.y)
    else:
        z = run_online(design.agents(), paths.y)
    cost = design.cost
    return np.stack([paths.x[:, k] @ cost.L_at(k).T - z[:, k] for k in range(paths.n_steps)], axis=1)


def _same_system(a: Any, b: Any) -> bool:
    """Equal models: same sizes and equal matrices (designs built separately for one system agree)."""
    if a.dx != b.dx or list(a.dy) != list(b.dy):
        return False
    pairs = [(a.A, b.A), (a.Q, b.Q), (a.Sigma_x, b.Sigma_x), *zip(a.C, b.C), *zip(a.R, b.R)]
    return all(np.shape(x) == np.shape(y) and np.array_equal(x, y) for x, y in pairs)


#: bytes per run held for the whole Monte Carlo: its SeedSequence (measured: ~380) and a margin
_BYTES_PER_STREAM = 512


def _check_memory(designs: Mapping[str, Any], system: Any, T: int, R_: int, batch: int) -> None:
    """Refuse up front (with the estimate) a Monte Carlo whose memory exceeds what the machine has."""
    from .._resources import check_memory

    b = min(batch, R_)
    per_batch = (
        8.0 * b * T * (3 * system.dx + 3 * sum(system.dy) + 2 * len(designs) * max(getattr(d.cost, "dz", system.dx) for d in designs.values()))
    )
    estimate = R_ * (_BYTES_PER_STREAM + 8.0 * T * len(designs)) + per_batch
    check_memory(
        estimate,
        f"a Monte Carlo of {R_:,} runs x {T} steps x {len(designs)} estimators (one seed stream and {T} stage costs per run and estimator)",
        argument="n_runs",
        fix="use fewer runs (the 95 % interval only shrinks like 1/sqrt(runs)), or a shorter horizon",
    )


def monte_carlo(
    designs: Mapping[str, Any],
    n_steps: int,
    n_runs: int,
    *,
    rng: int | np.random.SeedSequence | np.random.Generator | None,
    batch: int = 1000,
    path: Literal["errors", "runtime"] = "errors",
    graph: Any = None,
) -> dict[str, MonteCarloResult]:
    """Evaluate every design on the same ``n_runs`` sampled paths.

    Parameters
    ----------
    designs : mapping name -> design (with ``.system``, ``.cost`` and ``.errors`` / ``.agents``)
    n_steps : horizon simulated
    n_runs : number of independent runs (>= 2)
    rng : seed (or SeedSequence / Generator); run r uses ``SeedSequence(seed).spawn(n_runs)[r]``
    batch : runs per batch (memory); results do not depend on it
    path : "errors" (cancellation-free recursions) or "runtime" (agents on measurements)
    graph : with path="runtime", run the agents over this graph (message passing)
        instead of the structure-driven delivery
    """
    T = V.positive_int(n_steps, "n_steps")
    R_ = V.positive_int(n_runs, "n_runs", minimum=2)
    if not designs:
        raise ShapeError("designs: expected at least one design")
    if path not in ("errors", "runtime"):
        raise ShapeError(f"path: expected 'errors' or 'runtime', found {path!r}")
    first_name, first = next(iter(designs.items()))
    system = first.system
    for name, d in designs.items():
        if d.system is not system and not _same_system(d.system, system):
            raise ArgumentError(
                f"designs[{name!r}]: every design must be for the same system (common random numbers), found one that differs from "
                f"designs[{first_name!r}]'s; run monte_carlo once per system",
                argument=f"designs[{name!r}]",
            )
    if (horizon := getattr(first, "horizon", None)) is not None and T > horizon:
        raise ArgumentError(f"n_steps: expected at most the designs' horizon {horizon}, found {T}; design a longer horizon", argument="n_steps")
    batch = V.positive_int(batch, "batch")
    _check_memory(designs, system, T, R_, batch)
    streams = run_streams(rng, R_)
    costs = {name: np.empty((R_, T)) for name in designs}
    for start in range(0, R_, batch):
        stop = min(R_, start + batch)
        paths = sample_paths(system, T, stop - start, rng=None, streams=streams[start:stop])
        for name, d in designs.items():
            with np.errstate(over="ignore", invalid="ignore"):  # a diverging estimator: reported as not finite, below
                e = _team_errors(d, paths, path, graph)
                for k in range(T):
                    costs[name][start:stop, k] = np.einsum("ra,ab,rb->r", e[:, k], d.cost.S_at(k), e[:, k])
    out = {}
    for name, c in costs.items():
        if not np.all(np.isfinite(c)):  # diverged: keep the steps that are finite, mark the rest inf
            c = np.where(np.isfinite(c), c, np.inf)
        with np.errstate(over="ignore", invalid="ignore"):  # inf - inf in the spread of a diverged estimator: NaN, reported
            tot = c.sum(axis=1)
            out[name] = MonteCarloResult(
                name, R_, c.mean(axis=0), c.std(axis=0, ddof=1) / np.sqrt(R_), float(tot.mean()), float(tot.std(ddof=1) / np.sqrt(R_)), path
            )
    return out
