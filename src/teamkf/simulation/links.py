"""Unreliable links: packet drops, jitter, scheduled outages and agent failures in the message-passing runtime.

A :class:`LinkModel` says, per edge or for the whole graph,

==============  =====================================================================
``p_drop``      probability that a packet on the edge is lost (independently per packet)
``jitter``      a delivered packet arrives 0..J extra steps late (uniform), J >= 0 integer
``outages``     (source, target, first, last): the edge loses every packet sent at steps
                first..last (inclusive)
``failures``    agent -> step: the agent stops sending from that step on
==============  =====================================================================

Randomness is seeded per run: run r of a Monte Carlo with seed S draws its
link events from ``SeedSequence(S).spawn(n_runs)[r]`` extended by a fixed key,
so the same seed gives the same drops in one process, in any batch size and
on Dask workers, and the link events are independent of the process and
measurement noises. For every edge and every step, one uniform (drop) and one
jitter draw are taken whatever happens, so changing p_drop does not shift
the jitter stream.

Every run reports per edge the packets ``sent``, ``delivered`` (on time, after
the edge's delay), ``late`` (delivered after extra jitter) and ``dropped``
(lost, or sent into an outage). A failed agent sends nothing (not counted as sent).

What an agent does when a packet is missing at the step it needs it is the
family's business (each family documents it; see ``tolerant`` agents): the
packet agents of MTMSE and MMSE replace a missing measurement by its
conditional expectation given everything the agent holds (its common estimate
and the window measurements it received,
:meth:`teamkf.estimators.team.TeamAgent.expected_measurements`), and the
consensus-type filters (KCF, CIKF, diffusion, CI, ICF, HCMCI) use the neighbours
that delivered (the per-family table is in ``docs/recorded-data-and-links.md``).

The robust design for bounded jitter (:func:`robust_graph`) designs MTMSE/MMSE
for the delays τ_e + J: every packet then arrives by its deadline, the agents
buffer it until then, and the estimator is exactly the design for the larger
delays — jitter costs the larger delay and nothing else.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np

from .. import _validation as V
from .._validation import FloatArray
from ..exceptions import ArgumentError, GraphError, ShapeError
from ..network.graph import CommGraph

__all__ = ["LinkModel", "LinkStats", "robust_graph", "pass_messages_lossy", "link_streams", "LINK_STREAM_KEY"]

#: appended to a run's spawn key for its link events (independent of its noises)
LINK_STREAM_KEY = 0x11E


Edge = tuple[int, int]


def _jitter_value(x: Any, name: str) -> int:
    if isinstance(x, bool) or not isinstance(x, (int, np.integer, float)) or (isinstance(x, float) and not x.is_integer()) or int(x) < 0:
        raise ArgumentError(f"{name}: expected a whole number of steps >= 0, found {x!r}", argument=name)
    return int(x)


@dataclass(frozen=True, eq=False)
class LinkModel:
    """Unreliable links for the runtime (see the module docstring).

    Parameters
    ----------
    p_drop : float in [0, 1], or a mapping (source, target) -> float (other edges: ``default_p_drop``)
    jitter : int >= 0, or a mapping (source, target) -> int
    outages : sequence of (source, target, first, last)
    failures : mapping agent -> first step it no longer sends
    """

    p_drop: Any = 0.0
    jitter: Any = 0
    outages: Sequence[Sequence[int]] = ()
    failures: Mapping[int, int] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if isinstance(self.p_drop, Mapping):
            object.__setattr__(self, "p_drop", {tuple(int(v) for v in e): V.probability(p, f"p_drop[{list(e)}]") for e, p in self.p_drop.items()})
        else:
            object.__setattr__(self, "p_drop", V.probability(self.p_drop, "p_drop"))
        if isinstance(self.jitter, Mapping):
            object.__setattr__(self, "jitter", {tuple(int(v) for v in e): _jitter_value(j, f"jitter[{list(e)}]") for e, j in self.jitter.items()})
        else:
            object.__setattr__(self, "jitter", _jitter_value(self.jitter, "jitter"))
        outs = []
        for q, o in enumerate(self.outages):
            try:
                a, b, first, last = (int(v) for v in o)
            except (TypeError, ValueError):
                raise ArgumentError(f"outages[{q}]: expected [source, target, first, last], found {o!r}", argument=f"outages[{q}]") from None
            if first < 0 or last < first:
                raise ArgumentError(f"outages[{q}]: expected 0 <= first <= last, found first={first}, last={last}", argument=f"outages[{q}]")
            outs.append((a, b, first, last))
        object.__setattr__(self, "outages", tuple(outs))
        fails = {}
        for a, s in dict(self.failures).items():
            fails[int(a)] = V.integer(s, f"failures[{a}]", minimum=0)
        object.__setattr__(self, "failures", fails)

    # --- queries ------------------------------------------------------------------
    @property
    def trivial(self) -> bool:
        """True when every packet arrives exactly after its edge's delay (today's runtime)."""
        p0 = all(v == 0 for v in self.p_drop.values()) if isinstance(self.p_drop, dict) else self.p_drop == 0
        j0 = all(v == 0 for v in self.jitter.values()) if isinstance(self.jitter, dict) else self.jitter == 0
        return p0 and j0 and not self.outages and not self.failures

    def p_of(self, e: Edge) -> float:
        return float(self.p_drop.get(e, 0.0)) if isinstance(self.p_drop, dict) else float(self.p_drop)

    def jitter_of(self, e: Edge) -> int:
        return int(self.jitter.get(e, 0)) if isinstance(self.jitter, dict) else int(self.jitter)

    @property
    def max_jitter(self) -> int:
        return max(self.jitter.values(), default=0) if isinstance(self.jitter, dict) else int(self.jitter)

    def check_graph(self, graph: CommGraph, key: str = "network") -> None:
        """Raise :class:`GraphError` for an edge that the graph does not have, or an agent out of range."""
        edges = {(a, b) for (a, b, _) in graph.edges}
        named: list[tuple[str, Edge]] = []
        if isinstance(self.p_drop, dict):
            named += [(f"{key}.p_drop", e) for e in self.p_drop]
        if isinstance(self.jitter, dict):
            named += [(f"{key}.jitter", e) for e in self.jitter]
        named += [(f"{key}.outages[{q}]", (o[0], o[1])) for q, o in enumerate(self.outages)]
        for where, e in named:
            if e not in edges:
                raise GraphError(f"{where}: the graph has no edge {list(e)}; its edges are {[list(x) for x in sorted(edges)]}", argument=where)
        for a in self.failures:
            if not 0 <= a < graph.n_agents:
                raise GraphError(f"{key}.failures: agent {a} is out of range 0..{graph.n_agents - 1}", argument=f"{key}.failures")

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], graph: CommGraph | None = None, key: str = "network") -> "LinkModel":
        """From a scenario's ``[network]`` table::

            [network]
            p_drop = 0.1                       # or [[from, to, p], ...] per edge
            jitter = 1                         # or [[from, to, J], ...]
            outages = [[0, 1, 20, 29]]         # edge 0 -> 1 down for steps 20..29
            failures = [[2, 50]]               # agent 2 stops sending at step 50

        Every key is optional; a number applies to every edge.
        """
        if not isinstance(d, Mapping):
            raise ArgumentError(f"{key}: expected a table (p_drop, jitter, outages, failures), found {V.describe(d)}", argument=key)
        allowed = ("p_drop", "jitter", "outages", "failures")
        for k in d:
            if k not in allowed:
                raise ArgumentError(f"{key}.{k}: unknown key; expected one of: {', '.join(allowed)}", argument=f"{key}.{k}")

        def per_edge(x: Any, name: str) -> Any:
            if isinstance(x, list):
                out = {}
                for q, row in enumerate(x):
                    if not isinstance(row, (list, tuple)) or len(row) != 3:
                        raise ArgumentError(f"{key}.{name}[{q}]: expected [from, to, value], found {row!r}", argument=f"{key}.{name}[{q}]")
                    out[(int(row[0]), int(row[1]))] = row[2]
                return out
            return x

        try:
            lm = cls(
                p_drop=per_edge(d.get("p_drop", 0.0), "p_drop"),
                jitter=per_edge(d.get("jitter", 0), "jitter"),
                outages=d.get("outages", ()),
                failures={int(a): s for a, s in d.get("failures", [])},
            )
        except ArgumentError as exc:
            raise exc.rekeyed(f"{key}.{exc.argument}") from None
        except (TypeError, ValueError):
            raise ArgumentError(f"{key}.failures: expected [[agent, step], ...], found {d.get('failures')!r}", argument=f"{key}.failures") from None
        if graph is not None:
            lm.check_graph(graph, key)
        return lm


def robust_graph(graph: CommGraph, jitter: int | LinkModel) -> CommGraph:
    """The graph with every edge delay raised by its jitter bound: design MTMSE/MMSE on it for bounded jitter."""
    lm = jitter if isinstance(jitter, LinkModel) else LinkModel(jitter=jitter)
    return CommGraph(graph.n_agents, tuple((a, b, d + lm.jitter_of((a, b))) for (a, b, d) in graph.edges))


@dataclass
class LinkStats:
    """Per-edge packet counts of a run (summed over runs): edge -> {"sent", "delivered", "late", "dropped"}."""

    counts: dict[Edge, dict[str, int]] = field(default_factory=dict)
    missed: dict[int, int] = field(default_factory=dict)

    def add(self, e: Edge, what: str, n: int = 1) -> None:
        c = self.counts.setdefault(e, {"sent": 0, "delivered": 0, "late": 0, "dropped": 0})
        c[what] += n

    def to_rows(self) -> list[dict[str, Any]]:
        return [{"source": a, "target": b, **c} for (a, b), c in sorted(self.counts.items())]

    def merge(self, other: "LinkStats") -> None:
        for e, c in other.counts.items():
            for k, v in c.items():
                self.add(e, k, v)
        for a, m in other.missed.items():
            self.missed[a] = self.missed.get(a, 0) + m


def link_streams(seed: Any, n_runs: int, first_run: int = 0) -> list[np.random.SeedSequence]:
    """The link-event streams of runs ``first_run`` to ``n_runs - 1``, one per run.

    Run r's is ``SeedSequence(seed).spawn(n_runs)[r]``
    extended by :data:`LINK_STREAM_KEY`, i.e. ``SeedSequence(entropy, spawn_key=spawn_key + (r, LINK_STREAM_KEY))``,
    built directly (no spawning state, and no cost for the runs before ``first_run``)."""
    from .sampling import seed_sequence

    root = seed_sequence(seed)
    base, k0 = tuple(root.spawn_key), root.n_children_spawned  # spawn() numbers children from the parent's count
    return [
        np.random.SeedSequence(root.entropy, spawn_key=base + (k0 + r, LINK_STREAM_KEY), pool_size=root.pool_size)
        for r in range(int(first_run), int(n_runs))
    ]


def pass_messages_lossy(
    agents: Sequence[Any],
    graph: CommGraph,
    ys: Sequence[FloatArray],
    links: LinkModel,
    streams: Sequence[np.random.SeedSequence],
    stats: LinkStats | None = None,
    *,
    design: Any = None,
) -> FloatArray:
    """The message-passing loop over unreliable links, each run with its own link events.

    Like :func:`teamkf.estimators.base.pass_messages`, but a payload sent by j at step
    s on edge j -> i is lost with probability p_drop (or in an outage, or not sent by a
    failed agent) and otherwise arrives at s + τ_ji + e, e uniform in 0..J. The inbox
    entries keep (sender, sent step, payload); several may arrive from one sender at
    once. Returns the estimates (n_runs, T, Σ d_z); counts go into ``stats``.

    Batched over runs (:mod:`teamkf.simulation.lossy`): the link events of all runs are
    drawn up front as arrays, relays and the MTMSE/MMSE missed-packet rule run vectorized.
    """
    n = graph.n_agents
    if len(agents) != n or len(ys) != n:
        raise ShapeError(f"agents, y: expected {n} of each (as the graph), found {len(agents)} agents and {len(ys)} measurement arrays")
    links.check_graph(graph)
    n_runs, T = ys[0].shape[:2]
    if len(streams) != n_runs:
        raise ShapeError(f"streams: expected one link stream per run ({n_runs}), found {len(streams)}")
    for ag in agents:  # agents that can run with missing packets switch to that mode
        for obj in (ag, getattr(ag, "inner", None)):
            if obj is not None and hasattr(obj, "tolerant"):
                obj.tolerant = True
    from .lossy import run_lossy

    return run_lossy(agents, graph, ys, links, streams, stats if stats is not None else LinkStats(), design=design)
