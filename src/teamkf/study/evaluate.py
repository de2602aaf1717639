"""The rows of one evaluation (the unit of work of a sweep point): :func:`evaluate_point`.

A thin view of :func:`teamkf.study.evaluation.evaluate`, which owns the
vocabulary of the rows (:data:`~teamkf.study.evaluation.ROW_KEYS`) and the
rule for Monte Carlo runs and seeds.
"""

from __future__ import annotations

from typing import Any, Sequence

from ..estimators.registry import get_family
from .evaluation import DEFAULT_MC_RUNS, evaluate

__all__ = ["evaluate_point", "is_analytic", "DEFAULT_MC_RUNS"]


def is_analytic(estimator: str) -> bool:
    """True when the family of ``estimator`` has an exact analytic team cost."""
    return bool(get_family(estimator).analytic_cost)


def evaluate_point(scenario: Any, estimators: Sequence[str] | None = None, runs: int = 0, seed: int | None = 0) -> list[dict[str, Any]]:
    """The rows of :func:`~teamkf.study.evaluation.evaluate` (one per estimator), as plain dicts.

    Deterministic: the same (scenario, estimators, runs, seed) gives the same rows anywhere. See
    :mod:`teamkf.study.evaluation` for the keys and the Monte Carlo rule.

    Parameters
    ----------
    scenario : Scenario or PopulationScenario
        Any scenario kind.
    estimators : sequence of str, optional
        Registry names (default: the scenario's).
    runs : int
        Monte Carlo runs for every estimator (0: only those without an analytic cost, with 1000 runs).
    seed : int, optional
        Seed of the Monte Carlo runs.

    Returns
    -------
    list of dict
        One row per estimator, keys :data:`teamkf.study.evaluation.ROW_KEYS`.

    Examples
    --------
    >>> from teamkf import evaluate_point
    >>> from teamkf.study.scenario import load_packaged
    >>> rows = evaluate_point(load_packaged("platoon-4"), ["mtmse", "centralized"])
    >>> [(r["estimator"], r["method"]) for r in rows]
    [('mtmse', 'analytic'), ('centralized', 'analytic')]
    """
    return [dict(r) for r in evaluate(scenario, estimators, runs=runs, seed=seed).rows]
