"""Shared builders for the team-MMSE reproductions."""

from __future__ import annotations

from ..models import LinearGaussianSystem, TeamCost
from ..network import CommGraph, InformationStructure

__all__ = ["platoon", "uav", "IS1_PLATOON", "platoon_structures"]


def platoon(lam: float, n: int = 4) -> tuple[LinearGaussianSystem, TeamCost, CommGraph]:
    """Section IV-B: the paper's A (n = 4), C_i = I, Q = I, R = 0.1 I, line graph with unit delays, cost (6)."""
    return LinearGaussianSystem.platoon(n), TeamCost.platoon(n, lam), CommGraph.line(n, 1)


def uav(n: int, lam: float) -> tuple[LinearGaussianSystem, TeamCost, CommGraph]:
    """Section IV-A: the UAV formation, complete graph with delay 2, cost (5)."""
    return LinearGaussianSystem.uav_formation(n), TeamCost.average_tracking(n, lam), CommGraph.complete(n, 2)


#: IS1 of Section V-C: own y(t-1:t) and the neighbours' y(t-1)
IS1_PLATOON = InformationStructure(
    4, 3, [[(0, 0, 1), (1, 1, 1)], [(0, 1, 1), (1, 0, 1), (2, 1, 1)], [(1, 1, 1), (2, 0, 1), (3, 1, 1)], [(2, 1, 1), (3, 0, 1)]]
)


def platoon_structures() -> dict[str, InformationStructure]:
    """IS0 (the line graph's full structure), IS1 and IS2 (own y(t-2:t)) of Table I."""
    g = CommGraph.line(4, 1)
    return {"IS0": InformationStructure.from_graph(g), "IS1": IS1_PLATOON, "IS2": InformationStructure.own_window(4, 3)}
