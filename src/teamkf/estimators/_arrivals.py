r"""On-time arrivals of flooded packets over lossy links: exact probabilities of the indicators.

The agents of the drop-aware design (:mod:`teamkf.estimators.team_lossy`) flood every item
ν_j(s) they learn for the first time, as the MTMSE relays do. A packet sent on edge e at step t
arrives *on time* (after exactly τ_e steps) with probability

.. math::  q_e = (1 - p_e) / (J_e + 1)

(not dropped, and no extra jitter); edge-step events are independent. An item ν_j(s) is *on time*
at agent i when it arrives at s + ℓ_ji (ℓ the geodesic delay), which happens exactly when every hop
of some geodesic path j = u_0 → u_1 → … → u_L = i succeeds, the hop u_h → u_{h+1} departing at
s + ℓ_{j u_h} (a node on a geodesic learns the item on time only through a geodesic, and floods
it at once). So the indicator is an OR of ANDs of independent edge-step events,

.. math::  d_i(j, s) = \bigvee_{P \in \mathcal G_{ji}} \; \bigwedge_{(e, o) \in P} \omega_e(s + o),

and every probability below is exact, by inclusion–exclusion over the geodesic paths:
P(∪_P A_P) = Σ_{∅≠𝒮⊆𝒢} (-1)^{|𝒮|+1} Π_{(e,t) ∈ ∪𝒮} q_e. Two indicators are dependent only when
their paths share an edge-step event; their joint probability is
P(U ∩ V) = P(U) + P(V) - P(U ∪ V). Everything is time-invariant (a shift of s shifts every event).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from itertools import combinations
from typing import Any

import numpy as np

from .. import _validation as V
from ..exceptions import ArgumentError, GraphError

__all__ = ["ArrivalModel", "MAX_GEODESICS"]

#: at most this many geodesic paths per (source, target) pair (inclusion-exclusion is 2^paths)
MAX_GEODESICS = 12

Event = tuple[int, int]  # (edge index, offset from the item's step s)
Path = frozenset[Event]


def _union_prob(paths: list[frozenset[Event]], q: np.ndarray) -> float:
    """P(at least one path has all its events succeed), events independent with P = q[edge]."""
    if not paths:
        return 0.0
    if any(len(p) == 0 for p in paths):
        return 1.0
    total = 0.0
    for r in range(1, len(paths) + 1):
        sign = 1.0 if r % 2 else -1.0
        for sub in combinations(paths, r):
            ev = frozenset().union(*sub)
            total += sign * float(np.prod([q[e] for (e, _) in ev]))
    return total


@dataclass(frozen=True, eq=False)
class ArrivalModel:
    """Which items reach which agent on time, and with what (joint) probabilities.

    Attributes
    ----------
    n_agents : int
    ell : (n, n) int array           geodesic delays, ell[j, i] from j to i
    edges : tuple of (source, target, delay)
    q : (n_edges,) array             on-time probability of one packet on each edge
    paths : dict (j, i) -> list of frozensets of (edge index, offset)   the geodesic paths
    prob : (n, n) array              prob[j, i] = P(d_i(j, s) = 1) (1 on the diagonal)
    pairs : dict                     ((j, i), (h, l)) -> {Δ: P(d_i(j, s) d_l(h, s + Δ)) - prob[j, i] prob[h, l]}
                                     for the dependent pairs only (Δ = 0 and (j, i) = (h, l): the
                                     item with itself, prob (1 - prob))
    """

    n_agents: int
    ell: np.ndarray
    edges: tuple[tuple[int, int, int], ...]
    q: np.ndarray
    paths: dict[tuple[int, int], list[frozenset[Event]]] = field(repr=False)
    prob: np.ndarray = field(repr=False)
    pairs: dict[tuple[tuple[int, int], tuple[int, int]], dict[int, float]] = field(repr=False)

    @property
    def pairs_from(self) -> dict[tuple[int, int], list[tuple[tuple[int, int], dict[int, float]]]]:
        """``pairs`` grouped by the first (source, target) key (cached)."""
        cache = self.__dict__.get("_pairs_from")
        if cache is None:
            cache = {}
            for (a, b), corr in self.pairs.items():
                cache.setdefault(a, []).append((b, corr))
            object.__setattr__(self, "_pairs_from", cache)
        return cache

    @classmethod
    def build(cls, graph: Any, p_drop: Any, jitter: Any = 0) -> "ArrivalModel":
        """From a :class:`~teamkf.network.graph.CommGraph`, a drop probability (number or {(a, b): p}) and a jitter bound."""
        n = graph.n_agents
        graph.require_strongly_connected()
        ell = np.asarray(graph.geodesic_delays(), dtype=int)
        edges = tuple(sorted((int(a), int(b), int(d)) for (a, b, d) in graph.edges))

        def per_edge(x: Any, e: tuple[int, int], default: float) -> float:
            return float(x.get(e, default)) if isinstance(x, dict) else float(x)

        q = np.array([(1.0 - per_edge(p_drop, (a, b), 0.0)) / (per_edge(jitter, (a, b), 0.0) + 1.0) for (a, b, _) in edges])
        out_edges: dict[int, list[tuple[int, int, int]]] = {}
        for idx, (a, b, d) in enumerate(edges):
            out_edges.setdefault(a, []).append((idx, b, d))
        paths: dict[tuple[int, int], list[frozenset[Event]]] = {}
        for j in range(n):
            for i in range(n):
                if i == j:
                    paths[(j, i)] = [frozenset()]
                    continue
                found: list[frozenset[Event]] = []

                def walk(u: int, t: int, acc: tuple[Event, ...], j: int = j, i: int = i, found: list = found) -> None:
                    if u == i:
                        found.append(frozenset(acc))
                        if len(found) > MAX_GEODESICS:
                            raise GraphError(
                                f"graph: more than {MAX_GEODESICS} geodesic paths from agent {j} to agent {i}; the drop-aware design "
                                "computes arrival probabilities by inclusion-exclusion over them (give the edges distinct delays)",
                                argument="graph",
                            )
                        return
                    for idx, b, d in out_edges.get(u, []):
                        if t + d + ell[b, i] == ell[j, i] and t + d == ell[j, b]:
                            walk(b, t + d, acc + ((idx, t),), j, i, found)

                walk(j, 0, ())
                paths[(j, i)] = found
        prob = np.array([[_union_prob(paths[(j, i)], q) for i in range(n)] for j in range(n)])
        pairs: dict[tuple[tuple[int, int], tuple[int, int]], dict[int, float]] = {}
        keys = [(j, i) for j in range(n) for i in range(n) if j != i]
        span = int(ell.max()) if ell.size else 0
        by_edge: dict[int, list[tuple[int, int]]] = {}
        for key in keys:
            for e in {e for p in paths[key] for (e, _) in p}:
                by_edge.setdefault(e, []).append(key)
        candidates = {(a, b) for lst in by_edge.values() for a in lst for b in lst}
        for ka, kb in sorted(candidates):
            ev_a = {ev for p in paths[ka] for ev in p}
            ev_b = {ev for p in paths[kb] for ev in p}
            # the shifts that make the two path sets share an event: o_a - o_b on a common edge (at most 2 span + 1 of them;
            # a loop over every shift in [-span, span] is endless for a delay of 1e9)
            shifts = sorted({oa - ob for (ea, oa) in ev_a for (eb, ob) in ev_b if ea == eb and abs(oa - ob) <= span})
            for delta in shifts:
                shifted = [frozenset((e, o + delta) for (e, o) in p) for p in paths[kb]]
                joint = prob[ka] + prob[kb] - _union_prob(paths[ka] + shifted, q)
                c = float(joint - prob[ka] * prob[kb])
                if abs(c) > 0.0:
                    pairs.setdefault((ka, kb), {})[delta] = c
        return cls(n, ell, edges, q, paths, prob, pairs)

    def sample(self, n_runs: int, n_steps: int, rng: np.random.Generator) -> np.ndarray:
        """On-time indicators, (n_runs, n_steps, n_agents(source j), n_agents(target i)) booleans: d_i(j, s).

        Draws one uniform per edge and step (the event ω_e(t) is u < q_e) and evaluates the OR of
        ANDs of every geodesic path, so the joint law is the one the exact probabilities describe.
        """
        n = self.n_agents
        span = int(self.ell.max()) if self.ell.size else 0
        if span > n_steps:  # a hop that starts at or after n_steps belongs to an item that arrives after the horizon: never drawn
            span = n_steps
        ok = rng.random((n_runs, n_steps + span, len(self.edges))) < self.q
        d = np.zeros((n_runs, n_steps, n, n), dtype=bool)
        for (j, i), plist in self.paths.items():
            acc = np.zeros((n_runs, n_steps), dtype=bool)
            for p in plist:
                if any(o > span for _, o in p):  # arrives after the horizon (the delay exceeds it): never on time
                    continue
                hit = np.ones((n_runs, n_steps), dtype=bool)
                for e, o in p:
                    hit &= ok[:, o : o + n_steps, e]
                acc |= hit
            d[:, :, j, i] = acc
        return d


# the link values of a design's options and a scenario's [network]: a number, or one per edge
def _per_edge(x: Any, name: str) -> Any:
    """A number, or per edge: {(source, target): value} or [[source, target, value], ...] (as in ``[network]``)."""
    if isinstance(x, (list, tuple)):
        try:
            x = {(int(a), int(b)): v for (a, b, v) in x}
        except (TypeError, ValueError):
            raise ArgumentError(f"{name}: expected a number or [[source, target, value], ...], found {V.describe(x)}", argument=name) from None
    if isinstance(x, dict):
        out = {}
        for e, v in x.items():
            if not (isinstance(e, tuple) and len(e) == 2 and all(isinstance(u, (int, np.integer)) for u in e)):
                raise ArgumentError(f"{name}: expected a number or {{(source, target): value}}, found the key {e!r}", argument=name)
            out[(int(e[0]), int(e[1]))] = v
        return out
    return x


def _p_value(x: Any, name: str) -> Any:
    x = _per_edge(x, name)
    if isinstance(x, dict):
        return {e: V.probability(p, f"{name}[{list(e)}]") for e, p in x.items()}
    return V.probability(x, name)


def _jitter_value(x: Any, name: str) -> Any:
    x = _per_edge(x, name)
    if isinstance(x, dict):
        return {e: V.integer(j, f"{name}[{list(e)}]", minimum=0) for e, j in x.items()}
    return V.integer(x, name, minimum=0)
