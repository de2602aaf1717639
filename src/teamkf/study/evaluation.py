"""One evaluation of a scenario: the unit of work of ``teamkf evaluate``, of every sweep point and of the reproductions.

:func:`evaluate` designs the scenario's estimators, computes their analytic
costs, runs the Monte Carlo it was asked for (or that an estimator without an
analytic cost needs), and returns one typed :class:`Evaluation`: a table of
rows, one per estimator, with one vocabulary of keys (:data:`ROW_KEYS`,
:data:`SCHEMA_VERSION`). ``teamkf evaluate`` prints, writes or plots it;
:func:`~teamkf.study.sweep.run_sweep` writes its rows with the grid columns;
nothing else re-implements it.

Rows
----
``estimator``
    the registry name; ``label`` the display name (with the variant).
``method``
    ``"analytic"`` (exact closed form), ``"monte-carlo"`` (no closed form: the
    cost is a sample mean) or ``"exact"`` (a population scenario's statistics).
``total_cost`` (finite horizon) or ``average_cost`` (steady state, and population scenarios)
    the team cost: Σ_t E[c(x(t), ẑ(t))] over the horizon, or its long-run average per step.
``ci95_low``, ``ci95_high``
    the 95 % confidence interval of a Monte Carlo cost (None for analytic and exact values).
``mc_cost``, ``mc_ci95_low``, ``mc_ci95_high``
    the simulated cost of an analytic estimator and its interval, when Monte Carlo ran
    (None otherwise): the check of the closed form by simulation.
``runs``
    the Monte Carlo runs behind the row's numbers (0: nothing simulated for it).
``seed``
    the seed of the Monte Carlo (None when nothing was simulated).
``diverged``
    True when a cost of the row is not finite (the number is then inf or NaN here, null in JSON, and
    the JSON row names the column in ``non_finite``).
``cost_links``
    the links the row's cost is under: ``"perfect"`` (an analytic cost on links that never drop; with a
    ``[network]`` table that drops, the design costs more over the scenario's links: see its ``mc_cost``),
    ``"lossy"`` (the expected cost under the scenario's links: the drop-aware design's exact cost, a design
    that uses no link, any Monte Carlo cost) or ``"assumed"`` (the drop-aware design's cost under the
    links of its own table); :func:`teamkf.study.report.cost_links`. None for a population scenario.
``links``
    the scenario's link model in one line (``"perfect"``, ``"p_drop 0.5 on every edge"``, ...;
    :func:`teamkf.study.report.link_text`); :attr:`Evaluation.links` has it as a mapping.

Runs and seeds
--------------
With ``runs = R ≥ 2`` every estimator is simulated on the same R runs; with
``runs = 0`` only the estimators without an analytic cost are, with
:data:`DEFAULT_MC_RUNS` runs. The runs come from
``monte_carlo(designs, T, R, rng=seed)``: run r of every estimator uses the
counter-based stream of ``SeedSequence(seed)`` for r, whichever other
estimators are evaluated beside it. A sweep's point 0 runs with the sweep's
seed itself and point k ≥ 1 with the k-th child of ``SeedSequence(seed)``
(:attr:`~teamkf.study.sweep.SweepSpec.points`), so a one-point sweep with
``runs = R, seed = S`` gives exactly the numbers of
``teamkf evaluate --monte-carlo R --seed S``, and any point is repeated by
``teamkf evaluate`` with ``--seed <the point's seed column>``.

Examples
--------
>>> from teamkf.study.scenario import load_packaged
>>> ev = evaluate(load_packaged("platoon-4"), ["mtmse", "mmse"])
>>> [r["estimator"] for r in ev.rows], ev.cost_key
(['mtmse', 'mmse'], 'total_cost')
>>> ev.row("mtmse")["total_cost"] <= ev.row("mmse")["total_cost"]
True
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np

from ..exceptions import ArgumentError

__all__ = ["evaluate", "Evaluation", "ROW_KEYS", "SCHEMA_VERSION", "DEFAULT_MC_RUNS", "check_capabilities"]

#: version of the row vocabulary below; bumped when a key changes meaning or goes away
SCHEMA_VERSION = 1
#: the keys of a row, in order (``total_cost`` or ``average_cost``: the scenario's cost key)
ROW_KEYS = (
    "estimator",
    "label",
    "method",
    "total_cost",
    "average_cost",
    "ci95_low",
    "ci95_high",
    "mc_cost",
    "mc_ci95_low",
    "mc_ci95_high",
    "runs",
    "seed",
    "diverged",
    "cost_links",
    "links",
)
#: Monte Carlo runs for estimators without a closed form when none are asked for (the paper uses 1000)
DEFAULT_MC_RUNS = 1000


@dataclass(frozen=True, eq=False)
class Evaluation:
    """The result of :func:`evaluate`: one row per estimator, and what the rows were computed from.

    Attributes
    ----------
    scenario : str
        The scenario's name.
    kind : str
        The scenario's kind (``"team"`` or ``"population"``).
    horizon : int or None
        T, or None for the steady state.
    cost_key : str
        ``"total_cost"`` or ``"average_cost"``: the key of the cost in every row.
    rows : tuple of dict
        One row per estimator, keys from :data:`ROW_KEYS` (module docstring).
    runs : int
        Monte Carlo runs per simulated estimator (0: nothing simulated).
    seed : int or None
        The Monte Carlo seed (drawn and recorded here when none was given).
    designs : dict
        name -> design (team scenarios; empty for a population).
    monte_carlo : dict
        name -> :class:`~teamkf.simulation.monte_carlo.MonteCarloResult` of the simulated estimators.
    details : dict
        Kind-specific facts: a population's exact statistics (``gains``, ``stationarity_index``, ...), a
        ``[control]`` table's LQG costs under ``"control"``.
    links : dict or None
        The scenario's link model (:func:`teamkf.study.report.link_record`: per-edge drop probabilities,
        jitter, outages, failures); None for a population scenario.
    """

    scenario: str
    kind: str
    horizon: int | None
    cost_key: str
    rows: tuple[dict[str, Any], ...]
    runs: int = 0
    seed: int | None = None
    designs: Mapping[str, Any] = field(default_factory=dict, repr=False)
    monte_carlo: Mapping[str, Any] = field(default_factory=dict, repr=False)
    details: Mapping[str, Any] = field(default_factory=dict, repr=False)
    schema_version: int = SCHEMA_VERSION
    links: Mapping[str, Any] | None = None

    def row(self, estimator: str) -> dict[str, Any]:
        """The row of ``estimator`` (KeyError naming the estimators otherwise)."""
        for r in self.rows:
            if r["estimator"] == estimator:
                return r
        raise KeyError(f"{estimator!r}: not evaluated here; estimators: {', '.join(r['estimator'] for r in self.rows)}")

    def stage_costs(self, estimator: str) -> list[float] | None:
        """E[c(x(t), ẑ(t))] per step: analytic where the family has a closed form, else the Monte Carlo mean."""
        d = self.designs.get(estimator)
        if d is not None and d.has_analytic_cost and d.stage_costs is not None:
            return [float(c) for c in d.stage_costs]
        mc = self.monte_carlo.get(estimator)
        return None if mc is None else [float(c) for c in mc.stage_mean]

    def to_frame(self) -> Any:
        """The rows as a pandas DataFrame (needs pandas)."""
        from .. import _validation as V

        pd = V.require("pandas", "dask")
        return pd.DataFrame(list(self.rows))

    def json_rows(self) -> list[dict[str, Any]]:
        """The rows in strict JSON: non-finite numbers as null, named in ``non_finite`` (column -> "inf"/"-inf"/"nan")."""
        out = []
        for r in self.rows:
            bad = {k: str(float(v)) for k, v in r.items() if isinstance(v, (float, np.floating)) and not math.isfinite(v)}
            row = {k: (None if k in bad else v) for k, v in r.items()}
            if bad:
                row["non_finite"] = bad
            out.append(row)
        return out

    def __repr__(self) -> str:
        runs = f", {self.runs} runs, seed {self.seed}" if self.runs else ""
        costs = ", ".join(f"{r['estimator']}={_short(r.get(self.cost_key))}" for r in self.rows[:8])
        more = f", ... ({len(self.rows)} estimators)" if len(self.rows) > 8 else ""
        return f"Evaluation({self.scenario!r}, {self.kind}, horizon={self.horizon}{runs}: {self.cost_key} {costs}{more})"


def _short(v: Any) -> str:
    return "None" if v is None else f"{float(v):.6g}"


def check_capabilities(scenario: Any, estimators: Sequence[str], *, simulate: bool) -> None:
    """Refuse, before any work, an estimator whose family cannot serve what the scenario asks.

    Unreliable links (``[network]`` with drops, jitter, outages or failures) act on simulated agents: with
    Monte Carlo, every simulated family must declare ``lossy_links`` in its registry record. Raises
    :class:`~teamkf.exceptions.UnsupportedOperationError` naming the family and the capability.
    """
    if not simulate or not scenario.has_lossy_links:
        return
    for name in estimators:
        scenario.family(name).require("lossy_links", "unreliable links ([network] p_drop / jitter / outages, --p-drop, --jitter)")


def evaluate(
    scenario: Any,
    estimators: Sequence[str] | None = None,
    *,
    runs: int = 0,
    seed: int | None = None,
    scheduler: Any = None,
    progress: bool | None = None,
) -> Evaluation:
    """Evaluate a scenario: analytic costs, and Monte Carlo where asked or needed (module docstring).

    Parameters
    ----------
    scenario : Scenario or PopulationScenario
        Any scenario kind (:mod:`teamkf.study.protocol`).
    estimators : sequence of str, optional
        Registry names (default: the scenario's ``estimators``).
    runs : int
        Monte Carlo runs for every estimator (0, or at least 2; 0: only the estimators without an analytic
        cost are simulated, with :data:`DEFAULT_MC_RUNS` runs).
    seed : int, optional
        Seed of the Monte Carlo (None: fresh entropy, recorded in the result).
    scheduler : optional
        Where the Monte Carlo chunks run (:func:`~teamkf.simulation.monte_carlo.monte_carlo`); the numbers
        do not depend on it.
    progress : bool, optional
        The Monte Carlo progress bar (None: on a terminal only).

    Returns
    -------
    Evaluation
        One row per estimator.

    Raises
    ------
    ArgumentError
        ``runs`` of 1 or negative, or Monte Carlo asked of a steady-state or population scenario.
    UnsupportedOperationError
        An estimator whose family lacks a capability the scenario needs (before any work).
    """
    from .protocol import scenario_kind

    kind = scenario_kind(scenario)
    if isinstance(runs, bool) or not isinstance(runs, (int, np.integer)) or runs < 0 or runs == 1:
        raise ArgumentError(f"runs: expected 0 (analytic costs) or at least 2 Monte Carlo runs, found {runs!r}", argument="runs")
    runs = int(runs)
    if kind == "population":
        if runs:
            raise ArgumentError("runs: a population scenario is evaluated exactly; nothing is simulated (use runs = 0)", argument="runs")
        return _evaluate_population(scenario, seed)
    return _evaluate_team(scenario, estimators, runs, seed, scheduler, progress)


def _evaluate_team(scenario: Any, estimators: Sequence[str] | None, runs: int, seed: int | None, scheduler: Any, progress: bool | None) -> Evaluation:
    from ..simulation.monte_carlo import monte_carlo

    names = tuple(scenario.estimators if estimators is None else estimators)
    # refused before any work on the families' declarations; then decided on the designs themselves (a variant
    # without a closed form, e.g. KCF 'stale', or a design whose cost overflowed, is simulated too)
    expected = [n for n in names if not scenario.family(n).analytic_cost]
    _check_monte_carlo(scenario, runs, names if runs else expected)
    with np.errstate(over="ignore", invalid="ignore"):  # a diverging design: its cost is not finite (inf/NaN in the row)
        designs = scenario.designs(names)
    mc_only = [n for n, d in designs.items() if not d.has_analytic_cost]
    simulated = list(names) if runs else mc_only
    mc_runs = runs or (DEFAULT_MC_RUNS if mc_only else 0)
    _check_monte_carlo(scenario, mc_runs, simulated)
    if mc_runs and seed is None:
        seed = int(np.random.SeedSequence().entropy % (2**32))  # type: ignore[operator]
    mc: Mapping[str, Any] = {}
    if mc_runs:
        with np.errstate(over="ignore", invalid="ignore"):
            mc = monte_carlo(
                {n: designs[n] for n in simulated},
                scenario.horizon,
                mc_runs,
                rng=seed,
                scheduler=scheduler,
                progress=progress,
                **scenario.monte_carlo_options(),
            )
    from .report import cost_links, link_record, link_text

    key = "total_cost" if scenario.horizon is not None else "average_cost"
    links = scenario.links
    record = link_record(links)
    rows = []
    for name, d in designs.items():
        row: dict[str, Any] = {"estimator": name, "label": d.label}
        r = mc.get(name)
        if d.has_analytic_cost:
            row.update({"method": "analytic", key: _num(d.cost_value), "ci95_low": None, "ci95_high": None})
            if d.info.get("exact") is False and "interval" in d.info:  # an expected cost estimated over sampled link patterns
                row.update({"ci95_low": float(d.info["interval"][0]), "ci95_high": float(d.info["interval"][1])})
            if r is not None:
                lo, hi = r.ci95
                row.update({"mc_cost": float(r.total_mean), "mc_ci95_low": float(lo), "mc_ci95_high": float(hi)})
            else:
                row.update({"mc_cost": None, "mc_ci95_low": None, "mc_ci95_high": None})
        else:
            r = mc[name]
            lo, hi = r.ci95
            row.update({"method": "monte-carlo", key: float(r.total_mean), "ci95_low": float(lo), "ci95_high": float(hi)})
            row.update({"mc_cost": None, "mc_ci95_low": None, "mc_ci95_high": None})
        row.update({"runs": mc_runs if r is not None else 0, "seed": seed if r is not None else None})
        row["diverged"] = bool(d.diverged) or any(isinstance(v, float) and not math.isfinite(v) for v in row.values())
        row["cost_links"] = cost_links(d, links, scenario.graph, row["method"])
        row["links"] = link_text(record)
        rows.append(row)
    details: dict[str, Any] = {}
    control = _control_summary(scenario, runs, seed)
    if control:
        details["control"] = control
    return Evaluation(
        scenario.name,
        "team",
        scenario.horizon,
        key,
        tuple(rows),
        runs=mc_runs,
        seed=seed if mc_runs else None,
        designs=designs,
        monte_carlo=mc,
        details=details,
        links=record,
    )


def _check_monte_carlo(scenario: Any, runs: int, simulated: Sequence[str]) -> None:
    """Monte Carlo needs a finite horizon and, over unreliable links, families that declare ``lossy_links``."""
    if not runs and not simulated:
        return
    if scenario.horizon is None:
        what = "runs" if runs else f"estimators {', '.join(simulated)}"
        raise ArgumentError(
            f"{'runs' if runs else 'horizon'}: Monte Carlo ({what}) needs a finite horizon, but scenario {scenario.name!r} has none "
            "(steady state); add horizon = T to the scenario",
            argument="runs" if runs else "horizon",
        )
    check_capabilities(scenario, simulated, simulate=True)


def _num(v: Any) -> float | None:
    return None if v is None else float(v)


def _control_summary(scenario: Any, runs: int, seed: int | None) -> dict[str, Any]:
    """Analytic (and, with runs, closed-loop Monte Carlo) costs of Theorem 4's controller and of certainty equivalence."""
    prob = scenario.control
    if prob is None:
        return {}
    from ..control.lqg import design_lqg, simulate_closed_loop

    out: dict[str, Any] = {}
    for name, kind in (("optimal", "mtmse"), ("certainty_equivalent", "mmse")):
        d = design_lqg(prob, scenario.horizon, kind=kind)
        entry: dict[str, Any] = {"method": "analytic", "total_cost": float(d.cost)}
        if runs:
            mc = simulate_closed_loop(d, runs, rng=seed)
            entry.update(mc_cost=mc["mean"], mc_ci95=[mc["mean"] - 1.96 * mc["sem"], mc["mean"] + 1.96 * mc["sem"]])
        out[name] = entry
    return out


def _evaluate_population(scenario: Any, seed: int | None) -> Evaluation:
    out = scenario.evaluate()
    cost = float(out["average_cost"])
    row = {
        "estimator": scenario.estimators[0],
        "label": f"{scenario.estimators[0]} ({out['filter']})",
        "method": "exact",
        "average_cost": cost,
        "ci95_low": None,
        "ci95_high": None,
        "mc_cost": None,
        "mc_ci95_low": None,
        "mc_ci95_high": None,
        "runs": 0,
        "seed": None,
        "diverged": not math.isfinite(cost) or bool(out.get("diverged")),
        "cost_links": None,
        "links": None,
    }
    return Evaluation(scenario.name, "population", scenario.horizon, "average_cost", (row,), details=out)
