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


def run_graph(
    agents: Sequence[Any],
    graph: CommGraph,
    y: Sequence[FloatArray],
    *,
    links: Any = None,
    rng: Any = None,
    streams: Sequence[Any] | None = None,
    stats: Any = None,
) -> FloatArray:
    """Run graph agents over the horizon of ``y`` (list over agents of (n_runs, T, d_y^i)).

    Parameters
    ----------
    links : :class:`~teamkf.simulation.links.LinkModel` or None
        Unreliable links (drops, jitter, outages, failures). None, or one with
        p_drop = 0 and jitter = 0 and no outage or failure, is exactly the
        reliable runtime (the same code, bit for bit).
    rng : seed of the link events (run r uses :func:`~teamkf.simulation.links.link_streams` ``(rng, n_runs)[r]``)
    streams : explicit per-run link streams (instead of ``rng``)
    stats : a :class:`~teamkf.simulation.links.LinkStats` that receives the per-edge counts

    Returns the estimates, (n_runs, T, sum of estimate widths), agent-major.
    """
    from .online import _batched

    if not isinstance(graph, CommGraph):
        raise GraphError(f"graph: expected a CommGraph, found {type(graph).__name__}", argument="graph")
    inner = [getattr(a, "inner", a) for a in agents]
    ys = _batched(inner, y)
    if links is None or links.trivial:
        if stats is not None:  # count the packets of the reliable runtime too
            _count_reliable(graph, agents, ys[0].shape[0], ys[0].shape[1], stats)
        return pass_messages(agents, graph, ys)
    from .links import link_streams, pass_messages_lossy

    if streams is None:
        streams = link_streams(rng, ys[0].shape[0])
    return pass_messages_lossy(agents, graph, ys, links, streams, stats)


def _count_reliable(graph: CommGraph, agents: Sequence[Any], n_runs: int, T: int, stats: Any) -> None:
    for a, b, _ in graph.edges:
        if getattr(agents[a], "omniscient", False):
            continue
        stats.add((a, b), "sent", n_runs * T)
        stats.add((a, b), "delivered", n_runs * T)


def graph_agents(design: Any) -> list[Any]:
    """The graph agents of a design (``design.graph_agents()``; relays around packet agents by default)."""
    return list(design.graph_agents())
