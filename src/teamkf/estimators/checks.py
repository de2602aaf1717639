"""Argument checks shared by the design functions of every family."""

from __future__ import annotations

from typing import Any

from ..exceptions import ArgumentError, GraphError
from ..models import LinearGaussianSystem, TeamCost
from ..network.graph import CommGraph

__all__ = ["check_model", "check_graph"]


def check_model(system: Any, cost: Any) -> None:
    """``system`` is a LinearGaussianSystem and ``cost`` a TeamCost of matching size."""
    if not isinstance(system, LinearGaussianSystem):
        raise ArgumentError(f"system: expected a LinearGaussianSystem, found {type(system).__name__}", argument="system")
    if not isinstance(cost, TeamCost):
        raise ArgumentError(
            f"cost: expected a TeamCost, found {type(cost).__name__}; build one with TeamCost.mse/platoon/average_tracking", argument="cost"
        )
    cost.check_system(system.dx, system.n_agents)


def check_graph(graph: Any, n_agents: int) -> CommGraph:
    """``graph`` is a CommGraph on ``n_agents`` nodes."""
    if not isinstance(graph, CommGraph):
        raise GraphError(
            f"graph: expected a CommGraph, found {type(graph).__name__}; build one with CommGraph.complete/line/ring or CommGraph(n, edges)",
            argument="graph",
        )
    if graph.n_agents != n_agents:
        raise GraphError(f"graph: expected a graph of {n_agents} agents (as the system), found one of {graph.n_agents}", argument="graph")
    return graph
