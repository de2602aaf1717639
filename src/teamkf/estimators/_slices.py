"""One agent's slice of a design: its own gains as plain arrays, and the graph agent rebuilt from them.

``teamkf deploy`` designs the team once and ships each agent process only its slice
(:mod:`teamkf.study.slices` writes and checks the file); the agent process rebuilds its
graph agent from the slice and the scenario's model (system, cost, graph, information
structure: cheap to build, no design), never the team design.

The protocol (a family opts in):

* ``design.agent_slice(i) -> (kind, arrays, meta)``: agent i's gains as a dict of numeric
  arrays and JSON-able ``meta``; :meth:`teamkf.estimators.base.Design.agent_slice` raises
  :class:`~teamkf.exceptions.UnsupportedOperationError` naming the family by default.
* ``kind`` names a rebuild function in :data:`KINDS` (a fixed table of teamkf's own code: the
  file names a kind, never a module to import), called as ``build(ctx, index, arrays, meta)``
  with the scenario's model in ``ctx`` (:class:`SliceContext`); it returns
  ``(design_view, graph_agent)``: ``design_view`` a :class:`SliceDesign` with what the runtime
  reads of a design (estimator, horizon, system, cost, graph), and the agent that
  ``design.graph_agents()[i]`` would have returned, with the same arithmetic bit for bit.

Implemented for the built-in families that deploy with their shared gains: ``kcf``
(honest variant), ``mtmse``, ``mmse`` and ``mtmse_lossy`` (without ``keyed``). Others (and plug-ins) raise, and the agent
process designs the team itself (:mod:`teamkf.study.slices` says so on stderr).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from importlib import import_module
from typing import Any, Callable, NamedTuple

import numpy as np

from ..exceptions import UnsupportedOperationError

__all__ = ["SliceContext", "SliceDesign", "KINDS", "agent_from_slice", "AgentRows"]


class SliceContext(NamedTuple):
    """The scenario's model, as the design was built on it (no design)."""

    system: Any
    cost: Any
    graph: Any
    structure: Any
    horizon: int | None


@dataclass(eq=False)
class SliceDesign:
    """What the deployment runtime reads of a design, for one agent rebuilt from its slice.

    ``AgentCore``, ``run_agent`` and the families' graph agents read these attributes only;
    the team's gains are not here (each agent's own are on its graph agent).
    """

    estimator: str
    horizon: int | None
    system: Any
    cost: Any
    graph: Any = None  # the graph the agents talk over (None: an information structure delivers)
    structure: Any = None
    info: dict[str, Any] = field(default_factory=dict)
    realizable: bool = True
    omniscient: bool = False
    steps: Any = ()  # a linear family's agent reads len(steps) (the horizon)
    algorithm: Any = None  # a linear family's per-agent step code, holding agent i's gains only

    @property
    def n_agents(self) -> int:
        return int(self.system.n_agents)

    @property
    def delivery_graph(self) -> Any:
        return self.graph

    @property
    def label(self) -> str:
        v = self.info.get("variant")
        return f"{self.estimator} [{v}]" if v else self.estimator


class AgentRows:
    """Agent ``index``'s rows of a per-agent schedule, indexed as the team's: ``rows[index, k]`` or ``rows[index]``.

    Another agent's row is not here: asking for it is an error (the slice holds one agent).
    """

    def __init__(self, index: int, rows: Any):
        self.index, self.rows = int(index), rows

    def __getitem__(self, key: Any) -> Any:
        i, rest = (key[0], key[1:]) if isinstance(key, tuple) else (key, ())
        if int(i) != self.index:
            raise IndexError(f"agent {self.index}'s slice holds no row of agent {i}")
        return self.rows[rest] if rest else self.rows


#: kind -> (module of teamkf.estimators, function): the rebuild functions (never taken from a file)
KINDS: dict[str, tuple[str, str]] = {
    "linear-kcf": ("kcf", "kcf_agent_from_slice"),
    "team": ("team", "team_agent_from_slice"),
    "lossy": ("_lossy_slice", "lossy_agent_from_slice"),
    "summary": ("_lossy_summary", "summary_agent_from_slice"),
}


def agent_from_slice(kind: str, ctx: SliceContext, index: int, arrays: dict[str, np.ndarray], meta: dict[str, Any]) -> tuple[SliceDesign, Any]:
    """``(design_view, graph_agent)`` of agent ``index`` rebuilt from its slice (see the module docstring)."""
    where = KINDS.get(kind)
    if where is None:
        raise UnsupportedOperationError(
            str(meta.get("estimator", "?")), f"an agent slice of kind {kind!r}", f"this teamkf rebuilds only {sorted(KINDS)}; design with it"
        )
    build: Callable[..., tuple[SliceDesign, Any]] = getattr(import_module(f"{__package__}.{where[0]}"), where[1])
    return build(ctx, int(index), arrays, meta)
