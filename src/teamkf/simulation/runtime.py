"""Message-passing runtime: agents see their own measurement and what the graph delivers, nothing else.

At step k agent i receives

* its own measurement y_i(k), and
* every payload that an in-neighbour j sent at step k - tau_ji (the edge's delay),

and returns ``(state, estimate, payload)``; the payload is sent on all its
out-edges. All runs of a batch move together: payloads and estimates carry
the run axis first. Agents of an omniscient design (the centralized bound,
``design.omniscient``) receive every y_j(k) at step k instead — they are a
benchmark, not a network member.

:class:`~teamkf.estimators.base.MeasurementRelay` turns an estimator agent
that consumes measurement packets (MTMSE, MMSE, centralized) into a graph
agent: it forwards every measurement it learns for the first time (the
paper's zeta_i(t), eq. 14), so y_j(s) reaches agent i exactly at s + ell_ji.
"""

from __future__ import annotations

from typing import Any, Sequence

from .._validation import FloatArray
from ..estimators.base import GraphAgent, MeasurementRelay, Message, pass_messages
from ..exceptions import GraphError
from ..network.graph import CommGraph

__all__ = ["GraphAgent", "Message", "MeasurementRelay", "run_graph", "graph_agents"]


def run_graph(agents: Sequence[Any], graph: CommGraph, y: Sequence[FloatArray]) -> FloatArray:
    """Run graph agents over the horizon of ``y`` (list over agents of (n_runs, T, d_y^i)).

    Returns the estimates, (n_runs, T, sum of estimate widths), agent-major.
    """
    from .online import _batched

    if not isinstance(graph, CommGraph):
        raise GraphError(f"graph: expected a CommGraph, found {type(graph).__name__}", argument="graph")
    inner = [getattr(a, "inner", a) for a in agents]
    return pass_messages(agents, graph, _batched(inner, y))


def graph_agents(design: Any) -> list[Any]:
    """The graph agents of a design (``design.graph_agents()``; relays around packet agents by default)."""
    return list(design.graph_agents())
