"""Message-passing runtime: agents see their own measurement and what the graph delivers, nothing else.

At step k agent i receives

* its own measurement y_i(k), and
* every payload that an in-neighbour j sent at step k - tau_ji (the edge's delay),

and returns ``(state, estimate, payload)``; the payload is sent on all its
out-edges. All runs of a batch move together: payloads and estimates carry
the run axis first. Agents that "hold everything" (the centralized bound)
declare ``omniscient = True`` and receive every y_j(k) at step k instead —
they are a benchmark, not a network member.

:class:`MeasurementRelay` turns an estimator agent that consumes measurement
packets (MTMSE, MMSE, centralized) into a graph agent: it forwards every
measurement it learns for the first time (the paper's zeta_i(t), eq. 14), so
y_j(s) reaches agent i exactly at s + ell_ji, and hands the new packets to
the estimator.
"""

from __future__ import annotations

from typing import Any, Protocol, Sequence

import numpy as np

from .._validation import FloatArray
from ..estimators.base import OnlineAgent, Packet
from ..exceptions import ShapeError
from ..network.graph import CommGraph

__all__ = ["GraphAgent", "Message", "MeasurementRelay", "run_graph", "graph_agents"]

#: (sender j, step it was sent, payload)
Message = tuple[int, int, Any]


class GraphAgent(Protocol):
    index: int

    def init_state(self, n_runs: int) -> Any: ...

    def step(self, state: Any, k: int, own: FloatArray, inbox: Sequence[Message]) -> tuple[Any, FloatArray, Any]: ...


class MeasurementRelay:
    """Graph agent around a packet-consuming estimator agent (flooding of new measurements)."""

    def __init__(self, inner: OnlineAgent, *, omniscient: bool = False):
        self.inner = inner
        self.index = inner.index
        self.omniscient = omniscient

    def init_state(self, n_runs: int) -> dict[str, Any]:
        return {"inner": self.inner.init_state(n_runs), "seen": set()}

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


def run_graph(agents: Sequence[Any], graph: CommGraph, y: Sequence[FloatArray]) -> FloatArray:
    """Run graph agents over the horizon of ``y`` (list over agents of (n_runs, T, d_y^i)).

    Returns the estimates, (n_runs, T, sum of estimate widths), agent-major.
    """
    n = graph.n_agents
    if len(agents) != n or len(y) != n:
        raise ShapeError(f"agents, y: expected {n} of each (as the graph), found {len(agents)} agents and {len(y)} measurement arrays")
    n_runs, T = y[0].shape[:2]
    ins = [[(j, graph.delay(j, i)) for j in graph.in_neighbors(i)] for i in range(n)]
    sent: list[dict[int, Any]] = [{} for _ in range(n)]
    max_delay = max((d for (_, _, d) in graph.edges), default=1)
    states = [ag.init_state(n_runs) for ag in agents]
    out = []
    for k in range(T):
        zs = []
        payloads = []
        for i, ag in enumerate(agents):
            inbox = [(j, k - d, sent[j][k - d]) for (j, d) in ins[i] if k - d >= 0 and sent[j].get(k - d) is not None]
            if getattr(ag, "omniscient", False):
                own: Any = [(j, k, y[j][:, k]) for j in range(n)]
                inbox = []
            else:
                own = y[i][:, k]
            states[i], z, payload = ag.step(states[i], k, own, inbox)
            zs.append(z)
            payloads.append(payload)
        for i in range(n):  # sent after every agent has stepped: nothing arrives within the step
            sent[i][k] = payloads[i]
            sent[i].pop(k - max_delay - 1, None)
        out.append(np.concatenate(zs, axis=1))
    return np.stack(out, axis=1)


def graph_agents(design: Any) -> list[Any]:
    """The graph agents of a design: its own (``design.graph_agents()``) or relays around ``design.agents()``.

    The centralized design's agents are omniscient (they hold every y_j(k) at step k).
    """
    if hasattr(design, "graph_agents"):
        return list(design.graph_agents())
    omni = getattr(design, "estimator", "") == "centralized"
    return [MeasurementRelay(a, omniscient=omni) for a in design.agents()]
