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

    Parameters
    ----------
    agents : one online agent per team member (``design.agents()``)
    y : list over agents of (n_runs, n_steps, d_y^j) measurements

    Returns
    -------
    z : (n_runs, n_steps, n_agents * d_z) estimates, agent-major in the last axis
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
