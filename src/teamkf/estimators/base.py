"""The family contract: what every estimator design is and does, and how agents receive data.

Every estimator family (centralized Kalman, MTMSE, per-agent MMSE, KCF, CIKF,
and any family a user registers) returns from its design function an
immutable :class:`Design`. A design carries the offline gains and, where the
family has one, the exact analytic team cost; it can

=====================  ==================================================================
``errors(paths)``      the team error e(k) = L x(k) - ẑ(k) on sampled paths, vectorized
                       over runs, propagated from the primitive noises (Monte Carlo)
``graph_agents()``     one online agent per node for the message-passing runtime
``filter(y)``          the estimates ẑ_i(k) of every agent on given measurements, each agent
                       using only what the graph (or information structure) delivers
``stage_costs``        E[c(x(k), ẑ(k))] per step, or None without an analytic cost
``total_cost``         Σ_k stage cost (finite horizon), or None
``average_cost``       long-run average cost (steady state), or None
``arrays()``           the gains as named arrays (``teamkf design --out``)
``summary()``          a strict-JSON summary (``teamkf design --json``)
=====================  ==================================================================

An operation a family cannot perform raises
:class:`~teamkf.exceptions.UnsupportedOperationError` naming the family and
the operation. Whether an agent is omniscient (the centralized bound, which
holds every y_j(k) at step k) is the class attribute :attr:`Design.omniscient`.

Two delivery loops live here so that ``Design.filter`` needs nothing above
this layer; :mod:`teamkf.simulation.runtime` builds the public runtime (and
lossy links) on them:

* :func:`deliver_structured` hands agent i the measurement y_j(s) at step
  s + ``arrival_lag(j)`` (packet agents, :class:`OnlineAgent`);
* :func:`pass_messages` runs graph agents (:class:`GraphAgent`): at step k
  agent i gets its own y_i(k) and every payload an in-neighbour j sent at
  step k - τ_ji.
"""

from __future__ import annotations

import abc
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar, Protocol, Sequence

import numpy as np

from .._repr import DesignReprMixin
from .._validation import FloatArray
from ..exceptions import ArgumentError, ShapeError, UnsupportedOperationError
from ..models import LinearGaussianSystem, TeamCost

if TYPE_CHECKING:
    from ..network.graph import CommGraph
    from .registry import Family

__all__ = [
    "Design",
    "OnlineAgent",
    "GraphAgent",
    "Packet",
    "Message",
    "MeasurementRelay",
    "check_measurements",
    "check_paths",
    "deliver_structured",
    "pass_messages",
    "checked_step",
    "step_context",
    "json_float",
]

#: a measurement y_j(s) delivered to an agent: (j, s, values of shape (n_runs, d_y^j))
Packet = tuple[int, int, np.ndarray]
#: a message on an edge: (sender j, step it was sent, payload)
Message = tuple[int, int, Any]


class OnlineAgent(Protocol):
    """A team member that consumes measurement packets (MTMSE, MMSE, centralized)."""

    index: int

    def init_state(self, n_runs: int) -> Any: ...

    def step(self, state: Any, k: int, received: Sequence[Packet]) -> tuple[Any, FloatArray]:
        """Consume the packets received at step k; return the new state and z_i(k), shape (n_runs, d_z)."""
        ...

    def arrival_lag(self, j: int) -> int:
        """Lag after which this agent needs y_j(s) (it must be delivered by step s + lag)."""
        ...


class GraphAgent(Protocol):
    """A node of the message-passing runtime: ``step(state, k, own, inbox) -> (state, z_i(k), payload)``."""

    index: int

    def init_state(self, n_runs: int) -> Any: ...

    def step(self, state: Any, k: int, own: Any, inbox: Sequence[Message]) -> tuple[Any, FloatArray, Any]: ...


def json_float(x: Any) -> float | None:
    """``float(x)``, or None when it is not finite (strict JSON has no NaN or Infinity)."""
    v = float(x)
    return v if math.isfinite(v) else None


# ---------------------------------------------------------------------------
# the contract
# ---------------------------------------------------------------------------
@dataclass(frozen=True, eq=False, kw_only=True)
class Design(DesignReprMixin, abc.ABC):
    """Base class of every estimator design (see the module docstring for the contract).

    A design is what a family's design function returns: its offline gains
    and, where the family has one, its exact team cost
    J_T = Σ_{k<T} E[c(x(k), ẑ(k))]. Designs are immutable; build them with a
    design function (:func:`~teamkf.design_mtmse`, ...), not with this class.

    Parameters
    ----------
    estimator : str
        The registry name of the family ("mtmse", "kcf", ...).
    horizon : int or None
        Number of steps T, or None for the infinite-horizon (steady-state) design.
    system : LinearGaussianSystem
        The process x(k+1) = A x(k) + w(k) and the agents' measurements y_i(k) = C_i x(k) + v_i(k).
    cost : TeamCost
        The team cost c(x, ẑ) = (L x - ẑ)ᵀ S (L x - ẑ) the design minimizes (or is evaluated on).
    stage_costs : (T,) array or None
        E[c(x(k), ẑ(k))] for k = 0..T-1; None when the family has no analytic cost
        (or for a steady-state design).
    average_cost : float or None
        Long-run average cost per step (steady state), or None.
    info : dict
        Family-specific facts, plain data; ``info["variant"]`` (when present) names the variant in
        :attr:`label` and in every table.
    graph : CommGraph or None
        The graph the agents talk over (:meth:`graph_agents` on the runtime, lossy links); None when the
        information structure delivers the measurements.

    See Also
    --------
    families : every registered family and the design it returns.
    monte_carlo : simulated costs, with confidence intervals, of any design.

    Examples
    --------
    >>> from teamkf import LinearGaussianSystem, TeamCost, CommGraph, design_mtmse
    >>> system, cost = LinearGaussianSystem.platoon(4), TeamCost.platoon(4, lam=100.0)
    >>> design = design_mtmse(system, cost, CommGraph.line(4, delay=1), horizon=20)
    >>> design.estimator, design.horizon, design.stage_costs.shape
    ('mtmse', 20, (20,))
    >>> bool(design.total_cost == design.stage_costs.sum())
    True
    """

    estimator: str
    horizon: int | None
    system: LinearGaussianSystem
    cost: TeamCost
    stage_costs: FloatArray | None = None
    average_cost: float | None = None
    info: dict[str, Any] = field(default_factory=dict)
    graph: Any = None

    #: True for a benchmark whose agents hold every y_j(k) at step k (the centralized filter)
    omniscient: ClassVar[bool] = False
    #: True when a design on the masked time-varying model of a missingness pattern (C_i(t) rows of the
    #: missing values zeroed, their noise decoupled) is the exact estimator for that pattern
    #: (:mod:`teamkf.study.measurements`); families without an exact treatment of gaps keep False
    handles_missing: ClassVar[bool] = False

    # --- identity -----------------------------------------------------------------
    @property
    def family(self) -> Family | None:
        """The registry record of this design's family (None for an unregistered one)."""
        from .registry import families

        return families().get(self.estimator)

    @property
    def n_agents(self) -> int:
        return int(self.system.n_agents)

    @property
    def realizable(self) -> bool:
        """True when every agent uses only what the graph delivers (not omniscient, not an 'ideal' variant).

        No realizable design can beat MTMSE on the same graph: MTMSE is optimal
        among all estimators that use that information (a property test checks it).
        """
        if self.omniscient:
            return False
        if "realizable" in self.info:
            return bool(self.info["realizable"])
        # a family that does not say: an "ideal" variant exchanges inside the step, which no delay graph delivers
        return str(self.info.get("variant", "")) != "ideal"

    @property
    def label(self) -> str:
        """The estimator name, with its variant when it has one (``"kcf [honest]"``).

        A design whose agents send nothing (``info["communicates"] is False``: ``local``) has no exchange to
        be honest or ideal about, and is labelled by its name alone.
        """
        v = self.info.get("variant")
        return f"{self.estimator} [{v}]" if v and self.info.get("communicates", True) is not False else self.estimator

    def _unsupported(self, operation: str, reason: str = "") -> UnsupportedOperationError:
        return UnsupportedOperationError(self.estimator, operation, reason)

    # --- analytic cost --------------------------------------------------------------
    @property
    def has_analytic_cost(self) -> bool:
        """True when the design carries its exact team cost (else evaluate it by Monte Carlo)."""
        return self.stage_costs is not None or self.average_cost is not None

    @property
    def total_cost(self) -> float | None:
        """J_T = Σ_k E[c(x(k), ẑ(k))] (finite horizon with an analytic cost), else None."""
        if self.stage_costs is None or self.horizon is None:
            return None
        return float(np.sum(self.stage_costs))

    @property
    def cost_value(self) -> float | None:
        """:attr:`total_cost` for a finite horizon, :attr:`average_cost` for the steady state (None without one)."""
        if self.horizon is None:
            return None if self.average_cost is None else float(self.average_cost)
        return self.total_cost

    def require_cost(self) -> float:
        """:attr:`cost_value` as a float; :class:`~teamkf.exceptions.UnsupportedOperationError` without an analytic cost."""
        v = self.cost_value
        if v is None:
            raise self._unsupported("an analytic team cost", "evaluate it by Monte Carlo (teamkf.monte_carlo or teamkf evaluate)")
        return v

    @property
    def cost_key(self) -> str:
        """``"total_cost"`` (finite horizon) or ``"average_cost"`` (steady state)."""
        return "total_cost" if self.horizon is not None else "average_cost"

    @property
    def diverged(self) -> bool:
        """True when the analytic cost left the floating-point range."""
        v = self.cost_value
        if v is not None and not math.isfinite(v):
            return True
        return self.stage_costs is not None and not bool(np.all(np.isfinite(self.stage_costs)))

    # --- Monte Carlo and online agents ------------------------------------------------
    def errors(self, paths: Any) -> FloatArray:
        """Team errors e(k) = L x(k) - ẑ(k), shape (n_runs, T', n d_z), on sampled ``paths``.

        The default filters the sampled measurements and subtracts: e(k) = L x(k) - ẑ(k).
        That cancels catastrophically when x grows (an unstable process), so teamkf's
        families override it with an error recursion driven by the primitive noises
        (``paths.x[:, 0]``, ``paths.w``, ``paths.v``).
        """
        check_paths(paths, self.system)
        ys, _, T, _ = check_measurements(paths.y, self.system, self.horizon)
        z = self._filter(ys)
        L = [self.cost.L_at(k) for k in range(T)]
        return np.stack([paths.x[:, k] @ L[k].T - z[:, k] for k in range(T)], axis=1)

    def agents(self) -> Sequence[OnlineAgent]:
        """Packet-consuming online agents (delivered by the information structure)."""
        raise self._unsupported("agents()", "its agents exchange messages; use graph_agents()")

    @property
    def delivery_graph(self) -> CommGraph | None:
        """The graph the agents of this design talk over (None: delivery by the information structure)."""
        return self.graph

    def graph_agents(self) -> list[Any]:
        """One message-passing agent per node (default: measurement relays around :meth:`agents`)."""
        return [MeasurementRelay(a, omniscient=self.omniscient) for a in self.agents()]

    def agent_slice(self, i: int) -> tuple[str, dict[str, np.ndarray], dict[str, Any]]:
        """Agent i's slice: ``(kind, arrays, meta)``, its own gains as plain arrays (:mod:`teamkf.estimators._slices`).

        ``teamkf deploy`` ships it to agent i's process, which rebuilds its graph agent from it and the
        scenario's model instead of designing the team. The default raises: the family ships no slice.
        """
        raise self._unsupported("agent_slice()", "it ships no per-agent slice; its agent processes design the team themselves")

    def filter(self, measurements: Any) -> FloatArray:
        """Run the designed estimator on given measurements.

        Parameters
        ----------
        measurements : list over agents of arrays, or a ``Paths``
            Agent i's measurements y_i(0..T'-1), shape (T', d_y^i) for one run or
            (n_runs, T', d_y^i) for a batch; T' <= horizon.

        Returns
        -------
        z : (T', n d_z) or (n_runs, T', n d_z)
            Every agent's estimate ẑ_i(k), agent-major; agent i uses only the
            measurements its graph (or information structure) has delivered by k.
        """
        ys, _, _, single = check_measurements(measurements, self.system, self.horizon)
        z = self._filter(ys)
        return z[0] if single else z

    def _filter(self, ys: list[FloatArray]) -> FloatArray:
        """Batched filtering (validated input); families with a vectorized form override it."""
        graph = self.delivery_graph
        if graph is not None:
            return pass_messages(self.graph_agents(), graph, ys, design=self)
        return deliver_structured(self.agents(), ys)

    # --- what the CLI writes ------------------------------------------------------------
    def cost_summary(self) -> dict[str, Any]:
        """The analytic cost in the ``teamkf evaluate --json`` format (strict JSON).

        ``{"method": "analytic", "total_cost": J, "stage_costs": [...]}`` (finite
        horizon), ``{"method": "analytic", "average_cost": J}`` (steady state), or
        ``{"method": "monte-carlo"}`` for a family without an analytic cost.
        Non-finite numbers are written as null with ``"diverged": true``.
        """
        if not self.has_analytic_cost:
            return {"method": "monte-carlo"}
        out: dict[str, Any] = {"method": "analytic"}
        v = self.cost_value
        out[self.cost_key] = None if v is None else json_float(v)
        if self.horizon is not None and self.stage_costs is not None:
            out["stage_costs"] = [json_float(c) for c in self.stage_costs]
        if self.diverged:
            out["diverged"] = True
        return out

    def details(self) -> dict[str, Any]:
        """Family-specific, JSON-ready facts about the gains (``summary`` adds them); override."""
        return {}

    def summary(self) -> dict[str, Any]:
        """What ``teamkf design --json`` prints for this design (strict JSON)."""
        out = {k: v for k, v in self.cost_summary().items() if k != "stage_costs"}
        if "variant" in self.info:
            out["variant"] = self.info["variant"]
        out.update(self.details())
        return out

    def arrays(self) -> dict[str, np.ndarray]:
        """The design as named arrays (``teamkf design --out`` writes them under ``<name>/``).

        The analytic cost, then every array-valued field a family adds (a tuple of
        arrays is stacked when the shapes agree, else written as ``field_0``,
        ``field_1``, ...). Families override it to choose names and layouts.
        """
        from dataclasses import fields

        out: dict[str, np.ndarray] = {}
        if self.stage_costs is not None:
            out["stage_costs"] = np.asarray(self.stage_costs, dtype=float)
        v = self.cost_value
        if v is not None:
            out[self.cost_key] = np.asarray(v, dtype=float)
        own = {f.name for f in fields(Design)}
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name in own:
                continue
            if isinstance(value, np.ndarray):
                out[f.name] = value
            elif isinstance(value, tuple) and value and all(isinstance(a, np.ndarray) for a in value):
                if all(a.shape == value[0].shape for a in value):
                    out[f.name] = np.stack(value)
                else:
                    out.update({f"{f.name}_{i}": a for i, a in enumerate(value)})
        return out

    # --- results ------------------------------------------------------------------------
    def to_pandas(self) -> Any:
        """Stage costs as a DataFrame (needs pandas)."""
        from .._validation import require

        pd = require("pandas", "dask")
        if self.stage_costs is None:
            return pd.DataFrame({"estimator": [self.estimator], self.cost_key: [self.cost_value]})
        return pd.DataFrame({"estimator": self.estimator, "step": np.arange(len(self.stage_costs)), "stage_cost": self.stage_costs})

    def plot(self, ax: Any = None, **kwargs: Any) -> Any:
        """Stage cost against the step (matplotlib, imported lazily); returns the axes."""
        from ..plotting import stage_cost_axes

        return stage_cost_axes([self], ax=ax, **kwargs)


# ---------------------------------------------------------------------------
# measurements
# ---------------------------------------------------------------------------
def check_paths(paths: Any, system: LinearGaussianSystem) -> None:
    """``paths`` must be sampled runs of ``system`` (what :func:`teamkf.sample` returns): x, y, w, v with d_x matching.

    The boundary check of every family's :meth:`Design.errors`: a wrong object is one
    :class:`~teamkf.exceptions.ArgumentError`, not an ``AttributeError`` deep inside a recursion.
    """
    from .._validation import describe

    fix = "pass the sampled runs teamkf.sample(system, n_steps, n_runs=..., rng=...) returns"
    if any(not hasattr(paths, a) for a in ("x", "y", "w", "v")):
        raise ArgumentError(f"paths: expected sampled runs (an object with x, y, w, v), found {describe(paths)}; {fix}", argument="paths")
    x = np.asarray(paths.x)
    if x.ndim != 3 or x.shape[2] != system.dx:
        raise ShapeError(f"paths.x: expected shape (n_runs, n_steps, {system.dx}), found {x.shape}; {fix}")


def check_measurements(y: Any, system: LinearGaussianSystem, horizon: int | None) -> tuple[list[FloatArray], int, int, bool]:
    """Validate measurements: a list over agents of (n_runs, T, d_y^i) or (T, d_y^i) arrays, or a ``Paths``.

    Returns ``(ys, n_runs, T, single)`` with every array batched (run axis
    first); ``single`` is True when the input had no run axis.
    """

    if hasattr(y, "y") and not isinstance(y, (list, tuple, np.ndarray)):
        y = y.y
    n = system.n_agents
    if not isinstance(y, (list, tuple)) or len(y) != n:
        found = f"{type(y).__name__}" + (f" of length {len(y)}" if isinstance(y, (list, tuple)) else "")
        raise ShapeError(
            f"measurements: expected a list of {n} arrays (one per agent, each (n_steps, d_y^i) or (n_runs, n_steps, d_y^i)), found {found}"
        )
    ys = [_finite_measurements(yi, i) for i, yi in enumerate(y)]
    single = ys[0].ndim == 2
    if single:
        ys = [yi[None] if yi.ndim == 2 else yi for yi in ys]
    n_runs, T = ys[0].shape[:2] if ys[0].ndim == 3 else (0, 0)
    for i, yi in enumerate(ys):
        want = (n_runs, T, system.dy[i])
        if yi.ndim != 3 or yi.shape != want:
            layout = "(n_steps, d_y^i)" if single else "(n_runs, n_steps, d_y^i)"
            raise ShapeError(
                f"measurements[{i}]: expected shape {layout} = {want[1:] if single else want}, found {yi.shape[1:] if single and yi.ndim == 3 else yi.shape}; "
                "every agent needs the same runs and steps, and d_y^i columns"
            )
    if T == 0:
        raise ShapeError("measurements: expected at least one step, found 0")
    if horizon is not None and T > horizon:
        raise ShapeError(f"measurements: expected at most horizon = {horizon} steps, found {T}; design a longer horizon")
    return ys, n_runs, T, single


def _finite_measurements(yi: Any, i: int) -> FloatArray:
    """Agent i's measurements as floats; a NaN or inf is refused with the agent and the step where it is."""
    from .. import _validation as V

    name = f"measurements[{i}]"
    raw = yi if isinstance(yi, np.ndarray) else None
    if raw is None and isinstance(yi, (list, tuple)):
        try:
            raw = np.asarray(yi)
        except (TypeError, ValueError):
            raw = None
    if raw is not None and raw.dtype.kind == "f" and raw.ndim in (2, 3) and not np.all(np.isfinite(raw)):
        bad = tuple(int(j) for j in np.argwhere(~np.isfinite(raw))[0])
        run = f", run {bad[0]}" if raw.ndim == 3 else ""
        raise ArgumentError(
            f"{name}: expected finite measurements, found {float(raw[bad])} for agent {i} at step {bad[-2]}{run} (component {bad[-1]}); "
            "NaN cannot mark a missing measurement here (no missing-measurement model): fill the value or drop the run",
            argument=name,
        )
    return V.as_float_array(yi, name)


# ---------------------------------------------------------------------------
# delivery loops
# ---------------------------------------------------------------------------
class MeasurementRelay:
    """Graph agent around a packet-consuming agent: floods every measurement it learns for the first time.

    This is the paper's ζ_i(t) (eq. 14): y_j(s) reaches agent i exactly at
    s + ℓ_ji. An omniscient inner agent (the centralized bound) gets every
    y_j(k) at step k instead.
    """

    def __init__(self, inner: OnlineAgent, *, omniscient: bool = False):
        self.inner = inner
        self.index = inner.index
        self.omniscient = omniscient

    def init_state(self, n_runs: int) -> dict[str, Any]:
        return {"inner": self.inner.init_state(n_runs), "seen": set()}

    @property
    def restart_state(self) -> Any:
        """``(n_runs, k) -> state``: the wrapped agent's restart at step k (a restarted process), nothing relayed yet; None
        when the wrapped agent defines no restart."""
        inner = getattr(self.inner, "restart_state", None)
        if not callable(inner):
            return None
        return lambda n_runs, k: {"inner": inner(n_runs, k), "seen": set()}

    def step(self, state: dict[str, Any], k: int, own: Any, inbox: Sequence[Message]) -> tuple[dict[str, Any], FloatArray, list[Packet]]:
        seen = set(state["seen"])
        new: list[Packet] = []
        candidates: list[Packet] = list(own) if self.omniscient else [(self.index, k, own)]
        for _, _, payload in inbox:
            candidates.extend(payload)
        for j, s, v in candidates:
            if (j, s) not in seen:
                seen.add((j, s))
                new.append((j, s, v))
        inner_state, z = self.inner.step(state["inner"], k, new)
        return {"inner": inner_state, "seen": seen}, z, new


def deliver_structured(agents: Sequence[OnlineAgent], ys: Sequence[FloatArray]) -> FloatArray:
    """Step packet agents over the horizon of ``ys``, delivering y_j(s) to agent i at s + ``arrival_lag(j)``.

    Returns the estimates (n_runs, T, Σ d_z), agent-major.
    """
    n_runs, T = ys[0].shape[:2]
    n = len(ys)
    lags = [[ag.arrival_lag(j) for j in range(n)] for ag in agents]
    states = [ag.init_state(n_runs) for ag in agents]
    out = []
    for k in range(T):
        zs = []
        for i, ag in enumerate(agents):
            received = [(j, k - lags[i][j], ys[j][:, k - lags[i][j]]) for j in range(n) if k - lags[i][j] >= 0]
            states[i], z = ag.step(states[i], k, received)
            zs.append(z)
        out.append(np.concatenate(zs, axis=1))
    return np.stack(out, axis=1)


def step_context(design: Any) -> tuple[int | None, str]:
    """``(d_z, who)`` for :func:`checked_step`: a design's estimate width and ``"plug-in FILE, family 'name', "`` (the prefix of its messages)."""
    if design is None:
        return None, ""
    dz = getattr(getattr(design, "cost", None), "dz", None)
    name = getattr(design, "estimator", None)
    who = f"family {name!r}, " if name else ""
    from .registry import plugin_of

    plugin = plugin_of(type(design).__module__)
    return (int(dz) if isinstance(dz, (int, np.integer)) else None), (f"plug-in {plugin}, {who}" if plugin else who)


def checked_step(
    agent: Any, i: int, state: Any, k: int, own: Any, inbox: Any, n_runs: int, dz: int | None = None, who: str = ""
) -> tuple[Any, Any, Any]:
    """``agent.step(state, k, own, inbox)``, with its return checked: ``(state, z, payload)``, z a float array of shape (n_runs, d_z).

    A step that returns something else (a user's plug-in, typically) is a :class:`ShapeError` naming the plug-in
    and family (``who``, from :func:`step_context`), the agent's class, the step, and expected vs found, instead
    of an error deep in the runtime. The check is a few attribute reads per agent and step (no pass over the
    values): a non-finite z is not refused here (a diverging estimator's inf or NaN is flagged in the results).
    """
    out = agent.step(state, k, own, inbox)
    if not isinstance(out, tuple) or len(out) != 3:
        raise ShapeError(
            f"{who}agent {i} ({type(agent).__qualname__}).step at step {k}: expected a tuple (next state, z, payload), found {_describe(out)}"
        )
    z = out[1]
    if not isinstance(z, np.ndarray) or z.ndim != 2 or z.shape[0] != n_runs or (dz is not None and z.shape[1] != dz) or z.dtype.kind != "f":
        found = f"an array of shape {z.shape} and dtype {z.dtype}" if isinstance(z, np.ndarray) else _describe(z)
        want = f"({n_runs}, {dz})" if dz is not None else f"({n_runs}, d_z)"
        raise ShapeError(
            f"{who}agent {i} ({type(agent).__qualname__}).step at step {k}: expected z of shape {want} and a float dtype "
            f"(one row per run, cost.dz columns), found {found}; fix the step's z (docs: plugins.html, 'The agents')"
        )
    return out


def _describe(x: Any) -> str:
    from .._validation import describe

    return describe(x)


def pass_messages(agents: Sequence[Any], graph: CommGraph, ys: Sequence[FloatArray], *, design: Any = None) -> FloatArray:
    """Run graph agents over ``graph``: own y_i(k) plus in-neighbours' payloads sent at k - τ_ji.

    Payloads are sent after every agent has stepped, so nothing arrives within
    a step. Omniscient agents receive every y_j(k) at step k. Returns the
    estimates (n_runs, T, Σ d_z), agent-major. With ``design`` every step's z is
    checked against its d_z (:func:`checked_step`).
    """
    n = graph.n_agents
    if len(agents) != n or len(ys) != n:
        raise ShapeError(f"agents, y: expected {n} of each (as the graph), found {len(agents)} agents and {len(ys)} measurement arrays")
    n_runs, T = ys[0].shape[:2]
    ins = [[(j, graph.delay(j, i)) for j in graph.in_neighbors(i)] for i in range(n)]
    sent: list[dict[int, Any]] = [{} for _ in range(n)]
    max_delay = max((d for (_, _, d) in graph.edges), default=1)
    states = [ag.init_state(n_runs) for ag in agents]
    dz, who = step_context(design)
    out = []
    for k in range(T):
        zs = []
        payloads = []
        for i, ag in enumerate(agents):
            inbox = [(j, k - d, sent[j][k - d]) for (j, d) in ins[i] if k - d >= 0 and sent[j].get(k - d) is not None]
            if getattr(ag, "omniscient", False):
                own: Any = [(j, k, ys[j][:, k]) for j in range(n)]
                inbox = []
            else:
                own = ys[i][:, k]
            states[i], z, payload = checked_step(ag, i, states[i], k, own, inbox, n_runs, dz, who)
            zs.append(z)
            payloads.append(payload)
        for i in range(n):
            sent[i][k] = payloads[i]
            sent[i].pop(k - max_delay - 1, None)
        out.append(np.concatenate(zs, axis=1))
    return np.stack(out, axis=1)
