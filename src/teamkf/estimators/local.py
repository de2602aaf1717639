r"""Local Kalman filters: every agent filters its own measurements only (no communication), the floor.

Agent i runs the Kalman filter of (A, Q, Σ_x, C_i, R_i):

.. math::

    P_i(t|t) = (P_i(t|t-1)^{-1} + C_i^\top R_i^{-1} C_i)^{-1}, \quad
    \hat x_i(t|t) = \hat x_i(t|t-1) + P_i(t|t) C_i^\top R_i^{-1} (y_i - C_i \hat x_i(t|t-1)),

x̂_i(t+1|t) = A x̂_i(t|t), P_i(t+1|t) = A P_i(t|t) Aᵀ + Q, prior 0 and Σ_x;
ẑ_i = L_i x̂_i(t|t). It is the diffusion filter with no neighbours
(:mod:`teamkf.estimators.diffusion`), so both ``variant`` values are the same
filter (the option exists for a uniform scenario table).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..models import LinearGaussianSystem, TeamCost
from ..network.graph import CommGraph
from ._consensus_common import VARIANTS, DiffusionAlgorithm, check_variant, finite_horizon
from .checks import check_graph, check_model
from .linear_team import LinearTeamDesign, finish_design
from .registry import Family, Option, _register_builtin

__all__ = ["design_local"]


class LocalAlgorithm(DiffusionAlgorithm):
    """Per-agent Kalman filter: the diffusion step with N_i = {i} and c = I."""

    payload_kinds: dict[str, str] = {}

    @property
    def info_graph(self) -> CommGraph | None:
        return None

    def agent_step(self, i: int, k: int, prev: dict | None, y_i: Any, inbox: Any, zero: Any) -> tuple[dict, dict]:
        xbar = self._prior(i, k, prev, zero)
        return {"xhat": self.adapt(i, k, xbar, {(i, k): y_i})}, {}

    #: no messages are used, so lost or late ones change nothing (unreliable links)
    agent_step_tolerant = agent_step

    def agent_step_runs(self, i: int, k: int, prev: dict | None, y_i: Any, slots: Any) -> tuple[dict, dict]:
        """:meth:`agent_step` for every run of a block at once (stacked columns (R, d, 1): the same numbers, run by run)."""
        R = y_i.shape[0]
        return self.agent_step(i, k, prev, y_i, [], lambda dim: np.zeros((R, dim, 1)))


def design_local(
    system: LinearGaussianSystem, cost: TeamCost, graph: CommGraph | None = None, horizon: int | None = None, *, variant: str = "honest"
) -> LinearTeamDesign:
    """Design the per-agent (local) Kalman filters with their exact team cost.

    Each agent runs the Kalman filter of its own measurements only; nothing is exchanged.

    Parameters
    ----------
    system : LinearGaussianSystem
        The process x(k+1) = A x(k) + w(k) and the agents' measurements y_i(k) = C_i x(k) + v_i(k).
    cost : TeamCost
        The team cost c(x, ẑ) = (L x - ẑ)ᵀ S (L x - ẑ) (``None``: the sum of the agents' MSEs).
    graph : CommGraph or None
        Only used to run the (silent) agents on the runtime; None is allowed.
    horizon : int
        Number of steps T (finite horizon only).
    variant : str
        "honest" (the only one: local filters need no exchange).

    Returns
    -------
    LinearTeamDesign
        The per-step linear maps with the exact team cost (stage costs E[c(x(k), ẑ(k))]).

    Examples
    --------
    >>> from teamkf import LinearGaussianSystem, TeamCost, design_local
    >>> d = design_local(LinearGaussianSystem.platoon(4), TeamCost.platoon(4, 10.0), None, 10)
    >>> float(d.total_cost) > 0, d.label
    (True, 'local')
    """
    check_model(system, cost)
    if graph is not None:
        check_graph(graph, system.n_agents)
    variant = check_variant(variant, "variant")
    T = finite_horizon(horizon, "local", system, cost)
    alg = LocalAlgorithm(system, cost, graph, T, np.eye(system.n_agents), honest=True)
    return finish_design("local", alg, variant, {"communicates": False})  # labelled "local", not "local [honest]"


FAMILY = _register_builtin(
    Family(
        name="local",
        design=design_local,
        title="Local Kalman filters on own measurements only (no communication): the floor",
        uses="graph",
        horizons=frozenset({"finite"}),
        analytic_cost=True,
        lossy_links=True,  # capabilities (registry.Family): its agents run over links that drop
        options=(
            Option(
                name="variant",
                default="honest",
                check=check_variant,
                doc="both variants are the same filter (no communication): " + ", ".join(VARIANTS),
                choices=tuple(VARIANTS),
            ),
        ),
        example="design_local(system, cost, graph, horizon=100)",
    )
)
