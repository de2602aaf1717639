r"""Filter a recorded log with every estimator of a scenario (``teamkf filter``).

:func:`design_for_log` designs a family on the masked model of the log (exact for its missingness pattern, see
:mod:`teamkf.study.measurements`), :func:`online_estimates` runs the design's filter over the recorded
measurements, :func:`realized_costs` is the realized team cost c(t) = (L x(t) - ẑ(t))ᵀ S (L x(t) - ẑ(t)) given
the truth, and :func:`filter_log` does all of it for every estimator and returns a :class:`FilterResult`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from ... import _validation as V
from ..._validation import FloatArray
from ...exceptions import ArgumentError, TeamkfError, UnsupportedOperationError
from ...simulation.monte_carlo import runtime_estimates, team_stage_costs
from .format import MeasurementFileError, MeasurementLog, estimates_frame
from .transform import Innovations, KnownInputs, innovations, known_inputs, masked_system

__all__ = ["design_for_log", "FilterResult", "realized_costs", "online_estimates", "filter_log"]


def _missing_error(name: str, log: MeasurementLog, reason: str = "") -> UnsupportedOperationError:
    i, s = log.first_missing()  # type: ignore[misc]
    why = f"the first missing measurement is agent {i} at step {s} (in {log.source}); {reason or 'it has no exact treatment of gaps'}"
    return UnsupportedOperationError(name, "filtering measurements with missing values", why + "; fill the gaps, or use centralized, mtmse or mmse")


def design_for_log(scenario: Any, name: str, log: MeasurementLog) -> Any:
    """Design estimator ``name`` of ``scenario`` for a recorded log.

    Without gaps: the scenario's own design. With gaps: the design on
    :func:`masked_system` for the log's steps (finite horizon), when the family
    declares the ``missing_data`` capability; otherwise an
    :class:`~teamkf.exceptions.UnsupportedOperationError` naming the family
    and the first missing (agent, step).
    """
    if not log.has_gaps:
        return scenario.design(name)
    fam = scenario.family(name)
    if not fam.missing_data:
        raise _missing_error(name, log)
    if "finite" not in fam.horizons:
        raise _missing_error(name, log, "it has no finite-horizon (time-varying) design")
    sysm = masked_system(scenario.system, log.present)
    opts = scenario.options.get(name) or fam.check_options({})
    try:
        d = fam.build(sysm, scenario.cost, graph=scenario.graph, structure=scenario.information, horizon=log.n_steps, options=opts)
    except TeamkfError as exc:
        raise _missing_error(name, log, f"its design on the time-varying model of the gaps failed ({exc})") from exc
    return d


@dataclass(frozen=True, eq=False)
class FilterResult:
    """Estimates of every estimator on one recorded log, and the realized team cost when the truth is known.

    Attributes
    ----------
    estimates : dict name -> (n_steps, n_agents d_z)
    stage_costs : dict name -> (n_steps,) realized c(x(k), z(k)) = (L x - z)' S (L x - z), or None
    designs : dict name -> Design
    """

    estimates: dict[str, FloatArray]
    n_agents: int
    stage_costs: dict[str, FloatArray] | None = None
    designs: dict[str, Any] = field(default_factory=dict, repr=False)
    innovations: Innovations | None = None

    @property
    def loglik(self) -> float | None:
        """log p(y) under the centralized filter (None when not computed)."""
        return None if self.innovations is None else self.innovations.loglik

    @property
    def total_costs(self) -> dict[str, float] | None:
        if self.stage_costs is None:
            return None
        return {k: float(np.sum(v)) for k, v in self.stage_costs.items()}

    def to_pandas(self) -> Any:
        return estimates_frame(self.estimates, self.n_agents)

    def summary(self) -> dict[str, Any]:
        from ...estimators.base import json_float

        T = next(iter(self.estimates.values())).shape[0]
        out: dict[str, Any] = {"steps": T, "agents": self.n_agents, "estimators": list(self.estimates)}
        if self.stage_costs is not None:
            out["total_cost"] = {k: json_float(v) for k, v in (self.total_costs or {}).items()}
        if self.innovations is not None:
            out["loglik"] = json_float(self.innovations.loglik)
        bad = {f"total_cost.{k}": str(v) for k, v in (self.total_costs or {}).items() if not np.isfinite(v)}
        if self.innovations is not None and not np.isfinite(self.innovations.loglik):
            bad["loglik"] = str(self.innovations.loglik)
        if bad:  # strict JSON has no NaN or Infinity: the nulls above say which, and why
            out["non_finite"] = bad
        return out


def realized_costs(cost: Any, x: FloatArray, z: FloatArray) -> FloatArray:
    """c(k) = (L(k) x(k) - z(k))' S(k) (L(k) x(k) - z(k)) for one run (n_steps,) or a batch (n_runs, n_steps)."""
    single = x.ndim == 2
    xb, zb = (x[None], z[None]) if single else (x, z)
    e = np.stack([xb[:, k] @ cost.L_at(k).T - zb[:, k] for k in range(xb.shape[1])], axis=1)  # as the Monte Carlo forms it
    c = team_stage_costs(cost, e)
    return c[0] if single else c


def online_estimates(design: Any, ys: Sequence[FloatArray], *, missing: bool = False) -> FloatArray:
    """One run's estimates (n_steps, n d_z) from the design's online agents, exactly as the Monte Carlo
    ``path="runtime"`` computes them (message passing over the design's graph, or delivery by its
    information structure); ``design.filter`` for a design without online agents (the ideal KCF).

    ``missing=True``: ``ys`` holds NaN where a measurement is missing, and the agents receive it as it is
    (the contract of a ``missing_data`` family whose design does not set ``handles_missing``, see
    :func:`filter_log`); otherwise every value must be finite."""
    batch = [np.asarray(y, dtype=float)[None] for y in ys]
    if missing:
        from ...estimators.base import deliver_structured, pass_messages
        from ...simulation.runtime import graph_agents

        graph = getattr(design, "graph", None)
        if graph is not None:
            return np.asarray(pass_messages(graph_agents(design), graph, batch, design=design))[0]
        return np.asarray(deliver_structured(design.agents(), batch))[0]
    try:
        return np.asarray(runtime_estimates(design, batch))[0]
    except UnsupportedOperationError:
        return np.asarray(design.filter(list(ys)))


def filter_log(
    scenario: Any,
    log: MeasurementLog | Sequence[Any],
    *,
    estimators: Sequence[str] | None = None,
    truth: Any = None,
    inputs: Any = "scenario",
    with_innovations: bool = True,
) -> FilterResult:
    """Run every estimator of ``scenario`` (or ``estimators``) on a recorded log.

    Parameters
    ----------
    scenario : Scenario
    log : MeasurementLog, or per-agent (n_steps, d_y^i) arrays (NaN = missing; see Notes)
    estimators : names (default: the scenario's)
    truth : (n_steps, d_x) states, or None
    inputs : KnownInputs, None (zero means) or "scenario" (default: :func:`known_inputs` of the scenario)
    with_innovations : also compute the centralized filter's innovations and log-likelihood

    Returns
    -------
    FilterResult

    Notes
    -----
    What a family gets for a missing measurement (a log with gaps; only families that declare
    ``missing_data`` are run on one): its design function receives the masked model of the log
    (:func:`masked_system`: the rows of C_i(t) of the missing values are zero, their noise unit-variance and
    independent of everything else), and its agents' ``step`` receives **NaN** in ``own`` (and so in whatever
    relays it) at each missing entry: ``np.isnan(own)`` is the mask. A design class that sets
    ``handles_missing = True`` (teamkf's centralized filter, MTMSE and MMSE: their gains on the masked rows
    are exactly zero) receives 0.0 there instead.
    """
    if not isinstance(log, MeasurementLog):
        log = MeasurementLog.from_arrays(log, scenario.system, scenario.horizon)
    names = list(scenario.estimators if estimators is None else estimators)
    for k, name in enumerate(names):
        if name in names[:k]:  # two columns of estimates under one name would be silently merged
            raise ArgumentError(f"estimators: {name!r} is listed twice (--estimators); list each estimator once", argument="estimators")
    known = known_inputs(scenario) if inputs == "scenario" else inputs
    T, n = log.n_steps, scenario.system.n_agents
    if known is None and (log.b is not None or log.d is not None):
        if inputs != "scenario":
            raise MeasurementFileError(
                f"{log.source}: b/d columns: the log has time-varying offsets but inputs=None (zero means) was asked; drop one", argument="inputs"
            )
        known = KnownInputs.zero(scenario.system)
    if known is not None:
        mean, ybar = known.means(scenario.system, T, log.u, log.b, log.d)
        ys = [np.where(np.isnan(log.y[i]), 0.0, log.y[i] - ybar[i]) for i in range(n)]
        raw = [log.y[i] - ybar[i] for i in range(n)]  # NaN where missing
    else:
        if log.u is not None:
            raise MeasurementFileError(
                f"{log.source}: u columns: the scenario has no input matrix (system.B or agents[i].D) to use them; add one or drop the columns",
                argument="u",
            )
        ys = log.filled()
        raw = list(log.y)
    est: dict[str, FloatArray] = {}
    designs: dict[str, Any] = {}
    for name in names:
        d = design_for_log(scenario, name, log)
        designs[name] = d
        gaps = log.has_gaps and not getattr(d, "handles_missing", False)  # the missing_data contract: NaN, the mask being np.isnan(own)
        with np.errstate(over="ignore", invalid="ignore"):
            z = online_estimates(d, raw, missing=True) if gaps else online_estimates(d, ys)
            if known is not None:
                z = z + np.stack([scenario.cost.L_at(k) @ mean[k] for k in range(T)])
        est[name] = z
    inn = innovations(scenario.system, log, known) if with_innovations else None
    costs = None
    if truth is not None:
        x = V.as_float_array(truth, "truth")
        if x.shape != (log.n_steps, scenario.system.dx):
            raise MeasurementFileError(f"truth: expected shape ({log.n_steps}, {scenario.system.dx}) (steps, d_x), found {x.shape}", argument="truth")
        with np.errstate(over="ignore", invalid="ignore"):
            costs = {name: realized_costs(scenario.cost, x, z) for name, z in est.items()}
    return FilterResult(est, scenario.system.n_agents, costs, designs, inn)
