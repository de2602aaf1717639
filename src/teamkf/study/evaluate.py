"""Evaluate one scenario: analytic costs and, optionally, Monte Carlo, as plain rows.

This is the unit of work of a sweep point and of ``teamkf evaluate``.
"""

from __future__ import annotations

from typing import Any, Sequence

from ..simulation.monte_carlo import monte_carlo

__all__ = ["evaluate_point", "ANALYTIC", "DEFAULT_MC_RUNS"]

#: estimators with an analytic team cost (the others are evaluated by Monte Carlo)
ANALYTIC = ("mtmse", "mmse", "centralized", "cikf")

#: Monte Carlo runs for estimators without a closed form when none are asked for (the paper uses 1000)
DEFAULT_MC_RUNS = 1000


def evaluate_point(scenario: Any, estimators: Sequence[str] | None = None, runs: int = 0, seed: int = 0) -> list[dict[str, Any]]:
    """One row per estimator.

    Row keys: ``estimator``, ``method`` ("analytic" or "monte-carlo"),
    ``total_cost`` (finite horizon) or ``average_cost`` (infinite horizon),
    ``ci95_low``, ``ci95_high`` (None for analytic values), ``runs``, ``seed``;
    with ``runs > 0`` analytic estimators also get ``mc_cost``, ``mc_ci95_low``, ``mc_ci95_high``.
    Deterministic: the same (scenario, estimators, runs, seed) gives the same rows anywhere.
    """
    names = tuple(scenario.estimators if estimators is None else estimators)
    designs = scenario.designs(names)
    key = "total_cost" if scenario.horizon is not None else "average_cost"
    rows: list[dict[str, Any]] = []
    analytic = {n for n, d in designs.items() if d.stage_costs is not None or d.average_cost is not None}
    mc_runs = runs or (DEFAULT_MC_RUNS if len(analytic) < len(designs) else 0)
    mc = monte_carlo(designs, scenario.horizon, mc_runs, rng=seed) if (mc_runs and scenario.horizon is not None) else {}
    for name, d in designs.items():
        row: dict[str, Any] = {"estimator": name, "runs": int(runs), "seed": int(seed)}
        if name in analytic:
            row.update(
                {"method": "analytic", key: float(d.total_cost if key == "total_cost" else d.average_cost), "ci95_low": None, "ci95_high": None}
            )
            if name in mc:
                lo, hi = mc[name].ci95
                row.update({"mc_cost": mc[name].total_mean, "mc_ci95_low": lo, "mc_ci95_high": hi})
        else:
            lo, hi = mc[name].ci95
            row.update({"method": "monte-carlo", key: mc[name].total_mean, "ci95_low": lo, "ci95_high": hi, "runs": mc_runs})
        rows.append(row)
    return rows
