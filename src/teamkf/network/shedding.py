"""Information shedding: enumerate reduced information structures and their Pareto front.

A reduced structure keeps the graph's common part y(0:k-c) and, for every
hop distance h (agents j with ell_ji = h), a window of the m_h newest
measurements that can have arrived: y_j(k-h-m_h+1 .. k-h), 0 <= m_h <= c - h.
m = (c, c-1, ..., 1) is the full structure IS0 of eq. (14); on the 4-vehicle
platoon m = (2, 1, 0) is the paper's IS1 and m = (3, 0, 0) its IS2 (Section V-C).
Every structure enumerated here is realizable on the graph by construction
(windows start at the geodesic delay) and is validated.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .graph import CommGraph
from .information import InformationStructure

__all__ = ["HopWindows", "hop_structures", "pareto_front"]


@dataclass(frozen=True)
class HopWindows:
    """A structure given by window lengths per hop distance."""

    m: tuple[int, ...]
    structure: InformationStructure

    @property
    def label(self) -> str:
        return "m=(" + ",".join(str(v) for v in self.m) + ")"

    def links(self) -> int:
        """Number of (agent, other source) pairs in the local windows: the communication it relies on."""
        return sum(1 for i, wins in enumerate(self.structure.local) for (j, _, _) in wins if j != i)


def hop_structures(
    graph: CommGraph, common_lag: int | None = None, *, max_dim: int | None = None, dy: Sequence[int] | None = None
) -> list[HopWindows]:
    """Every hop-window structure on ``graph`` (optionally with total local dimension <= ``max_dim``)."""
    graph.require_strongly_connected()
    ell = np.asarray(graph.geodesic_delays())
    n = graph.n_agents
    c = max(int(ell.max()), 1) if common_lag is None else int(common_lag)
    dys = list(dy) if dy is not None else [1] * n
    out = []
    for m in itertools.product(*[range(0, c - h + 1) for h in range(c)]):
        local = [
            [(j, int(ell[j, i]), int(ell[j, i]) + m[int(ell[j, i])] - 1) for j in range(n) if ell[j, i] < c and m[int(ell[j, i])] > 0]
            for i in range(n)
        ]
        st = InformationStructure(n, c, local)
        if max_dim is not None and sum(st.local_dims(dys)) > max_dim:
            continue
        st.validate_on(graph)
        out.append(HopWindows(tuple(int(v) for v in m), st))
    return out


def pareto_front(sizes: Sequence[float], costs: Sequence[float]) -> list[int]:
    """Indices of the non-dominated points (smaller size and smaller cost are better), by increasing size.

    A point is on the front when no other point has size <= and cost <= with one strict.
    """
    order = sorted(range(len(sizes)), key=lambda i: (sizes[i], costs[i]))
    front: list[int] = []
    best = float("inf")
    for i in order:
        if costs[i] < best * (1 - 1e-12):
            front.append(i)
            best = costs[i]
    return front


def pareto_front_nd(points: Sequence[Sequence[float]]) -> list[int]:
    """Indices of the non-dominated points of several objectives (all minimized)."""
    P = np.asarray(points, dtype=float)
    keep = []
    for i in range(len(P)):
        dominated = np.any(np.all(P <= P[i] * (1 + 1e-12) + 1e-300, axis=1) & np.any(P < P[i] * (1 - 1e-12), axis=1))
        if not dominated:
            keep.append(i)
    return keep
