"""Evaluate one scenario: analytic costs and, optionally, Monte Carlo, as plain rows.

This is the unit of work of a sweep point and of ``teamkf evaluate``. Which
estimators have an analytic cost comes from the registry
(:attr:`Family.analytic_cost <teamkf.estimators.registry.Family.analytic_cost>`).
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from ..estimators.registry import get_family
from ..simulation.monte_carlo import monte_carlo

__all__ = ["evaluate_point", "is_analytic", "DEFAULT_MC_RUNS"]

#: Monte Carlo runs for estimators without a closed form when none are asked for (the paper uses 1000)
DEFAULT_MC_RUNS = 1000


def is_analytic(estimator: str) -> bool:
    """True when the family of ``estimator`` has an exact analytic team cost."""
    return bool(get_family(estimator).analytic_cost)


def __getattr__(name: str) -> Any:  # 0.1 name: the tuple of analytic estimators, now from the registry
    if name == "ANALYTIC":
        from ..estimators.registry import families

        return tuple(n for n, f in families().items() if f.analytic_cost)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def evaluate_point(scenario: Any, estimators: Sequence[str] | None = None, runs: int = 0, seed: int = 0) -> list[dict[str, Any]]:
    """Evaluate a scenario's estimators: one row per estimator.

    Parameters
    ----------
    scenario : Scenario
        The scenario (a population scenario gives the bulk filter's row).
    estimators : sequence of str, optional
        The families to evaluate; default: the scenario's ``estimators``.
    runs : int
        Monte Carlo runs: 0 gives only the analytic costs (and :data:`DEFAULT_MC_RUNS` runs for an
        estimator without one); more adds simulated costs with 95 % intervals.
    seed : int
        The seed of the Monte Carlo runs.

    Returns
    -------
    list of dict
        One row per estimator, plain data (the keys below).

    Notes
    -----
    Row keys: ``estimator``, ``method`` ("analytic" or "monte-carlo"),
    ``total_cost`` (finite horizon) or ``average_cost`` (infinite horizon),
    ``ci95_low``, ``ci95_high`` (None for analytic values), ``runs``, ``seed``;
    with ``runs > 0`` analytic estimators also get ``mc_cost``, ``mc_ci95_low``, ``mc_ci95_high``.
    Estimators without an analytic cost are simulated with ``runs`` runs
    (:data:`DEFAULT_MC_RUNS` when ``runs`` is 0).
    Deterministic: the same (scenario, estimators, runs, seed) gives the same rows anywhere.
    A population scenario gives one exact row, estimator ``"bulk"``, with its
    ``average_cost`` (the average LQ cost per agent; NaN when the memory-n
    closed loop diverges, and a DivergenceError where the exact filter does).

    Examples
    --------
    >>> from teamkf import scenario_from_dict
    >>> sc = scenario_from_dict({
    ...     "name": "two-sensors", "horizon": 20,
    ...     "system": {"A": [[0.9]], "Q": 1.0, "Sigma_x": 1.0},
    ...     "agents": [{"C": [[1.0]], "R": 0.5}, {"C": [[1.0]], "R": 2.0}],
    ...     "graph": {"kind": "complete", "delay": 1},
    ...     "cost": {"kind": "mse"},
    ...     "estimators": ["mtmse", "mmse", "centralized"],
    ... })
    >>> from teamkf import evaluate_point
    >>> rows = evaluate_point(sc)
    >>> [(r["estimator"], r["method"]) for r in rows]
    [('mtmse', 'analytic'), ('mmse', 'analytic'), ('centralized', 'analytic')]
    >>> rows[2]["total_cost"] <= rows[0]["total_cost"] <= rows[1]["total_cost"]
    True
    """
    if not hasattr(scenario, "designs"):  # a [population] scenario: exact statistics (study.population)
        return [_population_row(scenario, seed)]
    names = tuple(scenario.estimators if estimators is None else estimators)
    with np.errstate(over="ignore", invalid="ignore"):  # a diverging design: its cost is not finite (inf/NaN in the row)
        designs = scenario.designs(names)
    key = "total_cost" if scenario.horizon is not None else "average_cost"
    analytic = {n for n, d in designs.items() if d.has_analytic_cost}
    mc_runs = runs or (DEFAULT_MC_RUNS if len(analytic) < len(designs) else 0)
    mc_opts = scenario.monte_carlo_options() if hasattr(scenario, "monte_carlo_options") else {}  # [network]: unreliable links
    mc = monte_carlo(designs, scenario.horizon, mc_runs, rng=seed, **mc_opts) if (mc_runs and scenario.horizon is not None) else {}
    rows: list[dict[str, Any]] = []
    for name, d in designs.items():
        row: dict[str, Any] = {"estimator": name, "runs": int(runs), "seed": int(seed)}
        if name in analytic:
            row.update({"method": "analytic", key: d.cost_value, "ci95_low": None, "ci95_high": None})
            if name in mc:
                lo, hi = mc[name].ci95
                row.update({"mc_cost": mc[name].total_mean, "mc_ci95_low": lo, "mc_ci95_high": hi})
        else:
            lo, hi = mc[name].ci95
            row.update({"method": "monte-carlo", key: mc[name].total_mean, "ci95_low": lo, "ci95_high": hi, "runs": mc_runs})
        rows.append(row)
    return rows


def _population_row(scenario: Any, seed: int) -> dict[str, Any]:
    out = scenario.evaluate()
    return {
        "estimator": scenario.estimators[0],
        "method": "exact",
        "average_cost": float(out["average_cost"]),
        "ci95_low": None,
        "ci95_high": None,
        "runs": 0,
        "seed": int(seed),
    }
