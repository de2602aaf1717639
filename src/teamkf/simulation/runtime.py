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
    design: Any = None,
) -> FloatArray:
    """Run graph agents over the horizon of ``y``, each using only what the graph delivers.

    At step k agent i gets its own y_i(k) and every payload an in-neighbour j sent at step
    k - τ_ji (or, with ``links``, what the unreliable links deliver).

    Parameters
    ----------
    agents : sequence of graph agents
        One per node (``design.graph_agents()``).
    graph : CommGraph
        The communication graph: agent i hears agent j over edge (j, i) after its integer delay τ_ji.
    y : list over agents of (n_runs, T, d_y^i) arrays
        The measurements.
    links : :class:`~teamkf.simulation.links.LinkModel` or None
        Unreliable links (drops, jitter, outages, failures). None, or one with
        p_drop = 0 and jitter = 0 and no outage or failure, is exactly the
        reliable runtime (the same code, bit for bit).
    rng : int, SeedSequence, Generator or None
        The seed of the link events (run r uses :func:`~teamkf.simulation.links.link_streams` ``(rng, n_runs)[r]``).
    streams : sequence or None
        Explicit per-run link streams (instead of ``rng``).
    stats : LinkStats or None
        A :class:`~teamkf.simulation.links.LinkStats` that receives the per-edge counts.
    design : Design or None
        The design the agents come from (default: the agents' ``design`` attribute, when they have one):
        every step's z is checked against its width d_z, and an error names its family (and plug-in).

    Returns
    -------
    z : (n_runs, T, sum of estimate widths) array
        The estimates, agent-major in the last axis.

    Examples
    --------
    >>> from teamkf import LinearGaussianSystem, TeamCost, CommGraph, design_mtmse
    >>> system, cost, graph = LinearGaussianSystem.platoon(4), TeamCost.platoon(4, lam=100.0), CommGraph.line(4, delay=1)
    >>> from teamkf import sample, run_online, run_graph
    >>> mtmse = design_mtmse(system, cost, graph, horizon=30)
    >>> x, y = sample(system, 30, n_runs=5, rng=1)
    >>> z = run_graph(mtmse.graph_agents(), graph, y)
    >>> bool(abs(z - run_online(mtmse.agents(), y)).max() < 1e-8)
    True
    """
    from .online import _batched

    if not isinstance(graph, CommGraph):
        raise GraphError(f"graph: expected a CommGraph, found {type(graph).__name__}", argument="graph")
    inner = [getattr(a, "inner", a) for a in agents]
    ys = _batched(inner, y)
    if design is None and inner:
        design = getattr(inner[0], "design", None)
    if links is None or links.trivial:
        if stats is not None:  # count the packets of the reliable runtime too
            _count_reliable(graph, agents, ys[0].shape[0], ys[0].shape[1], stats)
        return pass_messages(agents, graph, ys, design=design)
    from .links import link_streams, pass_messages_lossy

    if streams is None:
        streams = link_streams(rng, ys[0].shape[0])
    return pass_messages_lossy(agents, graph, ys, links, streams, stats, design=design)


def _count_reliable(graph: CommGraph, agents: Sequence[Any], n_runs: int, T: int, stats: Any) -> None:
    for a, b, _ in graph.edges:
        if getattr(agents[a], "omniscient", False):
            continue
        stats.add((a, b), "sent", n_runs * T)
        stats.add((a, b), "delivered", n_runs * T)


def graph_agents(design: Any) -> list[Any]:
    """The graph agents of a design (``design.graph_agents()``; relays around packet agents by default)."""
    return list(design.graph_agents())
