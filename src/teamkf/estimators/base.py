"""The estimator interface: an offline *design* (gains + analytic cost) and online *agents*.

A design is an immutable object returned by ``design_*`` functions. It holds
the gain schedule and the analytic team cost, and builds one online agent per
team member with :meth:`Design.agents`. An agent is a pure
``step(state, received) -> (state, estimate)`` function wrapped in a thin
class; ``received`` lists the measurements that reach the agent at that step
as ``(source j, step s, values)`` with ``values`` of shape (n_runs, d_y^j).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol, Sequence

import numpy as np

from .._validation import FloatArray

__all__ = ["Design", "OnlineAgent", "Packet", "check_measurements"]

#: a measurement y_j(s) delivered to an agent: (j, s, values of shape (n_runs, d_y^j))
Packet = tuple[int, int, np.ndarray]


class OnlineAgent(Protocol):
    """One team member running online on what it has received."""

    index: int

    def init_state(self, n_runs: int) -> Any: ...

    def step(self, state: Any, k: int, received: Sequence[Packet]) -> tuple[Any, FloatArray]:
        """Consume the packets received at step k; return the new state and z_i(k), shape (n_runs, d_z)."""
        ...

    def arrival_lag(self, j: int) -> int:
        """Lag after which this agent needs y_j(s) (it must be delivered by step s + lag)."""
        ...


@dataclass(frozen=True, eq=False)
class Design:
    """Common fields of every design.

    Attributes
    ----------
    estimator : str
        Registry name ("mtmse", "mmse", "centralized").
    horizon : int or None
        Number of steps T, or None for the infinite-horizon (steady-state) design.
    stage_costs : (T,) array or None
        E[c(x(k), z(k))] for k = 0..T-1 (finite horizon).
    average_cost : float or None
        Long-run average cost per step (infinite horizon).
    """

    estimator: str
    horizon: int | None
    stage_costs: FloatArray | None
    average_cost: float | None
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def total_cost(self) -> float:
        """J_T = sum_k E[c(x(k), z(k))] (finite horizon only)."""
        if self.stage_costs is None:
            raise ValueError(f"{self.estimator}: an infinite-horizon design has no total cost; use average_cost")
        return float(np.sum(self.stage_costs))

    @property
    def cost_value(self) -> float:
        """total_cost for a finite horizon, average_cost for the steady state."""
        return self.total_cost if self.horizon is not None else float(self.average_cost)  # type: ignore[arg-type]

    def summary(self) -> dict[str, Any]:
        """A JSON-ready summary in the `teamkf evaluate --json` format."""
        if self.horizon is None:
            return {"method": "analytic", "average_cost": float(self.average_cost)}  # type: ignore[arg-type]
        return {"method": "analytic", "total_cost": self.total_cost, "stage_costs": [float(c) for c in self.stage_costs]}  # type: ignore[union-attr]

    def to_pandas(self) -> Any:
        """Stage costs as a DataFrame (needs pandas)."""
        from .._validation import require

        pd = require("pandas", "dask")
        if self.stage_costs is None:
            return pd.DataFrame({"estimator": [self.estimator], "average_cost": [self.average_cost]})
        return pd.DataFrame({"estimator": self.estimator, "step": np.arange(len(self.stage_costs)), "stage_cost": self.stage_costs})

    def plot(self, ax: Any = None, **kwargs: Any) -> Any:
        """Stage cost against the step (matplotlib, imported lazily); returns the axes."""
        from ..plotting import stage_cost_axes

        return stage_cost_axes([self], ax=ax, **kwargs)

    def agents(self) -> Sequence[OnlineAgent]:  # pragma: no cover - overridden
        raise NotImplementedError


def check_measurements(y: Any, system: Any, horizon: int | None) -> tuple[list[FloatArray], int, int]:
    """Validate measurements for a batched simulation: a list over agents of (n_runs, T, d_y^i), or a ``Paths``."""
    from .. import _validation as V
    from ..exceptions import ShapeError

    if hasattr(y, "y") and not isinstance(y, (list, tuple, np.ndarray)):
        y = y.y
    n = system.n_agents
    if not isinstance(y, (list, tuple)) or len(y) != n:
        raise ShapeError(
            f"y: expected a list of {n} measurement arrays (one per agent), found {type(y).__name__}"
            + (f" of length {len(y)}" if isinstance(y, (list, tuple)) else "")
        )
    ys = [V.as_float_array(yi, f"y[{i}]") for i, yi in enumerate(y)]
    n_runs, T = ys[0].shape[:2] if ys[0].ndim == 3 else (0, 0)
    for i, yi in enumerate(ys):
        want = (n_runs, T, system.dy[i])
        if yi.ndim != 3 or yi.shape != want:
            raise ShapeError(f"y[{i}]: expected shape (n_runs, n_steps, d_y^{i}) = {want}, found {yi.shape}")
    if horizon is not None and T > horizon:
        raise ShapeError(f"y: expected at most horizon = {horizon} steps, found {T}; design a longer horizon")
    return ys, n_runs, T
