"""Run packet agents on measurements, delivering each y_j(s) to agent i at step s + lag.

The structure-driven delivery used to check that online agents reproduce
their designs; the message-passing runtime over a graph is
:mod:`teamkf.simulation.runtime`. Both use the loops of
:mod:`teamkf.estimators.base`.
"""

from __future__ import annotations

from typing import Any, Sequence

from .._validation import FloatArray
from ..estimators.base import OnlineAgent, deliver_structured
from ..exceptions import ShapeError

__all__ = ["run_online"]


def run_online(agents: Sequence[OnlineAgent], y: Sequence[Any]) -> FloatArray:
    """Step every agent over the horizon of ``y``.

    Agent i receives y_j(s) at step s + its arrival lag, as the design's information
    structure says, and outputs ẑ_i(k) from what it holds.

    Parameters
    ----------
    agents : sequence of online agents
        One per team member (``design.agents()``).
    y : list over agents of (n_runs, n_steps, d_y^j) arrays
        The measurements.

    Returns
    -------
    z : (n_runs, n_steps, n_agents * d_z) array
        The estimates, agent-major in the last axis.

    See Also
    --------
    run_graph : agents that exchange messages over the graph instead.

    Examples
    --------
    >>> from teamkf import LinearGaussianSystem, TeamCost, CommGraph, design_mtmse
    >>> system, cost, graph = LinearGaussianSystem.platoon(4), TeamCost.platoon(4, lam=100.0), CommGraph.line(4, delay=1)
    >>> from teamkf import sample, run_online
    >>> mtmse = design_mtmse(system, cost, graph, horizon=30)
    >>> x, y = sample(system, 30, n_runs=5, rng=1)
    >>> run_online(mtmse.agents(), y).shape
    (5, 30, 4)
    """
    from .. import _validation as V

    V.instance(agents, "agents", (list, tuple), "a list of online agents (design.agents())")
    if not agents or not all(hasattr(a, "step") for a in agents):
        raise ShapeError("agents: expected a non-empty list of online agents (from design.agents()), found other objects", argument="agents")
    ys = _batched(agents, y)
    return deliver_structured(agents, ys)


def _batched(agents: Sequence[Any], y: Sequence[Any]) -> list[FloatArray]:
    from .. import _validation as V
    from ..estimators.base import check_measurements

    design = getattr(agents[0], "design", None) if agents else None
    if design is not None and hasattr(design, "system"):  # validate against the design: agents, d_y, horizon
        return check_measurements(y, design.system, design.horizon)[0]

    if not isinstance(y, (list, tuple)) or len(y) != len(agents):
        raise ShapeError(
            f"y: expected one measurement array per agent ({len(agents)}), found {len(y) if isinstance(y, (list, tuple)) else type(y).__name__}"
        )
    ys = [V.as_float_array(yi, f"y[{j}]") for j, yi in enumerate(y)]
    for j, yi in enumerate(ys):
        if yi.ndim != 3 or yi.shape[:2] != ys[0].shape[:2]:
            raise ShapeError(f"y[{j}]: expected shape (n_runs, n_steps, d_y^{j}) with the runs and steps of y[0] {ys[0].shape[:2]}, found {yi.shape}")
    return ys
