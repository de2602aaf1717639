"""Directed communication graphs with integer link delays.

A team of agents ``0, ..., n-1`` talks over a *directed* communication graph
(Afshari & Mahajan 2021, Section III-A/B). Each edge ``i -> j`` carries an
integer delay ``tau_ij >= 1``: a message that agent ``i`` sends at time ``t``
reaches agent ``j`` at time ``t + tau_ij``. Messages are relayed, so what
matters for the information structure is the *geodesic delay* ``l_ij``, the
smallest total delay of a directed path from ``i`` to ``j`` (eq. (14) of the
paper). Agent ``i`` therefore holds the measurements ``y_j(s)`` for
``s <= t - l_ji``.

Notation
--------
==============  ==============================================  =================================
Symbol          Meaning                                         In code
==============  ==============================================  =================================
``n``           number of agents                                :attr:`CommGraph.n_agents`
``tau_ij``      delay of the edge ``i -> j`` (>= 1 step)        :meth:`CommGraph.delay` ``(i, j)``
``N_i^-``       in-neighbours of ``i`` (agents sending to i)    :meth:`CommGraph.in_neighbors`
``N_i^+``       out-neighbours of ``i`` (agents i sends to)     :meth:`CommGraph.out_neighbors`
``l_ij``        geodesic delay from ``i`` to ``j``, eq. (14);   :meth:`CommGraph.geodesic_delays`
                ``l_ii = 0``                                    ``[i, j]``
``tau*``        weighted diameter ``max_ij l_ij``               :attr:`CommGraph.diameter`
==============  ==============================================  =================================

Examples 1 and 2 of the paper work through small graphs of this kind; the
builders :meth:`CommGraph.complete`, :meth:`CommGraph.line`,
:meth:`CommGraph.ring` and :meth:`CommGraph.star` cover the usual topologies.

References
----------
.. [1] Afshari, M. and Mahajan, A. (2021), the team-MMSE filtering paper this
   package implements: Section III-A/B (communication graph and information
   structure), eq. (14) (geodesic delays), Examples 1-2.
"""

from __future__ import annotations

from collections.abc import Hashable, Iterable, Mapping
from dataclasses import dataclass
from functools import cached_property
from numbers import Integral, Real
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._lazy import networkx as nx  # SciPy / networkx load on first use
from .._lazy import scipy_csgraph
from .._lazy import scipy_sparse as sp
from ..exceptions import GraphError

__all__ = ["CommGraph"]

IntArray = NDArray[np.int64]
Edge = tuple[int, int, int]

# ----------------------------------------------------------------------------
# private checks (GraphError, message: name, expected, found, fix)
# ----------------------------------------------------------------------------


def _as_int(x: Any, name: str, expected: str, fix: str) -> int:
    """``x`` as an int; integral floats are accepted, bools and the rest are not."""
    if isinstance(x, (bool, np.bool_)):
        raise GraphError(f"{name}: expected {expected}, found {x!r} (a bool); {fix}")
    if isinstance(x, (Integral, np.integer)):
        return int(x)
    if isinstance(x, (Real, np.floating)) and np.isfinite(float(x)) and float(x).is_integer():
        return int(float(x))
    raise GraphError(f"{name}: expected {expected}, found {x!r}; {fix}")


def _count(x: Any, name: str, minimum: int = 1) -> int:
    n = _as_int(x, name, f"an integer >= {minimum}", f"pass a whole number of agents, e.g. {name}=3")
    if n < minimum:
        raise GraphError(f"{name}: expected an integer >= {minimum}, found {n}; a team has at least one agent")
    _check_size(n, name)
    return n


def _check_size(n: int, name: str, per_pair: float = 8.0) -> None:
    """Refuse, before anything is allocated, a graph whose all-pairs delay matrix (``n^2`` numbers) does not fit in memory."""
    from .._budget import check_memory

    check_memory(
        per_pair * float(n) * float(n),
        f"a graph of {n:,} agents ({per_pair:.0f} bytes for each of the n^2 agent pairs: geodesic delays, edges)",
        argument=name,
        fix="use fewer agents (the team designs grow like n^2 or faster), or a population model for very large teams",
    )


def _delay(x: Any, name: str) -> int:
    fix = "delays are whole numbers of time steps and at least 1 (use delay=1 for the fastest link)"
    d = _as_int(x, name, "an integer delay >= 1", fix)
    if d < 1:
        raise GraphError(f"{name}: expected an integer delay >= 1, found {d}; {fix}", argument=name)
    if d > MAX_DELAY:
        found = f"{d:.3g}" if d < 10**300 else f"an integer of {len(str(d)) if d < 10**4000 else 'over 4000'} digits"
        raise GraphError(
            f"{name}: expected an integer delay between 1 and {MAX_DELAY:.0e} steps, found {found}; "
            "a delay longer than any horizon means the message never arrives: remove the edge instead",
            argument=name,
        )
    return d


#: the longest delay a graph holds (sums of delays along paths stay exact in 64-bit integers and floats)
MAX_DELAY = 10**9


def _agent(x: Any, name: str, n: int) -> int:
    expected = f"an agent index in 0..{n - 1}"
    fix = f"agents are numbered 0..{n - 1} (n_agents={n}); renumber the edge or raise n_agents"
    i = _as_int(x, name, expected, fix)
    if not 0 <= i < n:
        raise GraphError(f"{name}: expected {expected}, found {i}; {fix}", argument=name)
    return i


def _rng(rng: Any) -> np.random.Generator:
    if isinstance(rng, np.random.Generator):
        return rng
    if isinstance(rng, (Integral, np.integer)) and not isinstance(rng, (bool, np.bool_)):
        return np.random.default_rng(int(rng))
    raise GraphError(f"rng: expected a numpy.random.Generator or an int seed, found {rng!r}; pass rng=np.random.default_rng(seed) or rng=seed")


# ----------------------------------------------------------------------------
# the graph
# ----------------------------------------------------------------------------


@dataclass(frozen=True, repr=False)
class CommGraph:
    r"""A directed communication graph whose edges carry integer delays.

    Parameters
    ----------
    n_agents : int
        Number of agents ``n >= 1``; agents are ``0, ..., n-1``.
    edges : iterable of (source, target, delay)
        Directed edges ``i -> j`` with delay ``tau_ij >= 1`` (integer time
        steps; integral floats such as ``2.0`` are accepted and converted).
        They are stored as a sorted tuple of int triples, so two graphs with
        the same edges compare (and hash) equal.

    Raises
    ------
    GraphError
        If ``n_agents`` is not an integer >= 1, an endpoint is out of range,
        an edge is a self-loop, a delay is not an integer >= 1 (``0``,
        negatives, ``1.5`` and bools are rejected) or a directed pair
        ``(source, target)`` appears twice.

    Notes
    -----
    Strong connectivity is **not** required to build a graph (one can build
    and inspect a broken graph), but everything that needs geodesic delays
    (:meth:`geodesic_delays`, :attr:`diameter`) raises :class:`GraphError` on
    a graph that is not strongly connected. Use :meth:`is_strongly_connected`
    or :meth:`require_strongly_connected` to check up front.

    ==========  ========================================  ======================================
    Symbol      Meaning                                   In code
    ==========  ========================================  ======================================
    ``tau_ij``  delay of edge ``i -> j``                  ``delay(i, j)``
    ``N_i^-``   in-neighbours of ``i``                    ``in_neighbors(i)``
    ``l_ij``    geodesic delay ``i -> j`` (eq. (14))      ``geodesic_delays()[i, j]``
    ``tau*``    weighted diameter ``max_ij l_ij``         ``diameter``
    ==========  ========================================  ======================================

    Agent ``i`` knows ``y_j(s)`` for ``s <= t - l_ji`` (Examples 1-2 of [1]_).

    References
    ----------
    .. [1] Afshari, M. and Mahajan, A. (2021), Section III-A/B.

    Examples
    --------
    >>> from teamkf import CommGraph
    >>> g = CommGraph.line(3)
    >>> g.geodesic_delays().tolist()
    [[0, 1, 2], [1, 0, 1], [2, 1, 0]]
    >>> g.diameter
    2
    """

    n_agents: int
    edges: tuple[tuple[int, int, int], ...] = ()

    # -- construction ----------------------------------------------------------

    def __post_init__(self) -> None:
        n = _count(self.n_agents, "n_agents")
        raw: Any = self.edges
        if isinstance(raw, (str, bytes, Mapping)) or not isinstance(raw, Iterable):
            raise GraphError(
                f"edges: expected an iterable of (source, target, delay) triples, found {type(raw).__name__}; "
                "write edges as e.g. [[0, 1, 1], [1, 0, 2]]"
            )
        fast = self._fast_edges(raw, n)
        if fast is not None:
            object.__setattr__(self, "n_agents", n)
            object.__setattr__(self, "edges", fast)
            return
        seen: dict[tuple[int, int], tuple[int, int]] = {}
        out: list[Edge] = []
        for k, e in enumerate(raw):
            name = f"edges[{k}]"
            try:
                items = tuple(e)
            except TypeError:
                items = ()
            if len(items) != 3 or isinstance(e, (str, bytes)):
                raise GraphError(f"{name}: expected a (source, target, delay) triple, found {e!r}; write each edge as [from, to, delay]")
            s = _agent(items[0], f"{name} source", n)
            t = _agent(items[1], f"{name} target", n)
            if s == t:
                raise GraphError(
                    f"{name}: expected source != target, found a self-loop ({s}, {t}); remove it "
                    "(an agent always knows its own measurements: l_ii = 0)"
                )
            d = _delay(items[2], f"{name} delay")
            if (s, t) in seen:
                k0, d0 = seen[(s, t)]
                raise GraphError(
                    f"edges: expected at most one edge per directed pair, found the pair ({s}, {t}) twice "
                    f"(edges[{k0}] with delay {d0} and {name} with delay {d}); keep a single delay for it"
                )
            seen[(s, t)] = (k, d)
            out.append((s, t, d))
        object.__setattr__(self, "n_agents", n)
        object.__setattr__(self, "edges", tuple(sorted(out)))

    @staticmethod
    def _fast_edges(raw: Any, n: int) -> tuple[Edge, ...] | None:
        """Vectorized validation of a large, well-formed integer edge list; None sends it to the detailed loop."""
        try:
            arr = np.asarray(raw)
        except (TypeError, ValueError):
            return None
        if arr.ndim != 2 or arr.shape[1] != 3 or arr.shape[0] < 64 or arr.dtype.kind not in "iu":
            return None
        s, t, d = arr[:, 0], arr[:, 1], arr[:, 2]
        if (s < 0).any() or (s >= n).any() or (t < 0).any() or (t >= n).any() or (s == t).any() or (d < 1).any():
            return None
        key = np.sort(s.astype(np.int64) * n + t)  # a repeated (s, t) pair: the detailed loop names it
        if (key[1:] == key[:-1]).any():
            return None
        order = np.lexsort((d, t, s))
        return tuple(map(tuple, arr[order].tolist()))

    # caches live in __dict__ (cached_property); keep them out of pickles
    def __getstate__(self) -> dict[str, Any]:
        return {"n_agents": self.n_agents, "edges": self.edges}

    def __setstate__(self, state: dict[str, Any]) -> None:
        object.__setattr__(self, "n_agents", state["n_agents"])
        object.__setattr__(self, "edges", state["edges"])

    def __repr__(self) -> str:
        if self.edges:
            ds = [d for _, _, d in self.edges]
            lo, hi = min(ds), max(ds)
            dtxt = f"delay={lo}" if lo == hi else f"delays={lo}..{hi}"
            return f"CommGraph(n_agents={self.n_agents}, n_edges={len(self.edges)}, {dtxt})"
        return f"CommGraph(n_agents={self.n_agents}, n_edges=0)"

    # -- basic queries ---------------------------------------------------------

    @property
    def n_edges(self) -> int:
        """Number of directed edges."""
        return len(self.edges)

    @cached_property
    def _delay_map(self) -> dict[tuple[int, int], int]:
        return {(s, t): d for s, t, d in self.edges}

    @cached_property
    def _neighbors(self) -> tuple[tuple[tuple[int, ...], ...], tuple[tuple[int, ...], ...]]:
        ins: list[list[int]] = [[] for _ in range(self.n_agents)]
        outs: list[list[int]] = [[] for _ in range(self.n_agents)]
        for s, t, _ in self.edges:
            outs[s].append(t)
            ins[t].append(s)
        return tuple(tuple(sorted(x)) for x in ins), tuple(tuple(sorted(x)) for x in outs)

    def _check_agent(self, i: Any, name: str) -> int:
        return _agent(i, name, self.n_agents)

    def in_neighbors(self, i: int) -> tuple[int, ...]:
        """In-neighbours ``N_i^-``: agents with an edge into ``i``, sorted."""
        return self._neighbors[0][self._check_agent(i, "i")]

    def out_neighbors(self, i: int) -> tuple[int, ...]:
        """Out-neighbours ``N_i^+``: agents that ``i`` has an edge to, sorted."""
        return self._neighbors[1][self._check_agent(i, "i")]

    def has_edge(self, i: int, j: int) -> bool:
        """Whether the directed edge ``i -> j`` exists."""
        return (self._check_agent(i, "i"), self._check_agent(j, "j")) in self._delay_map

    def delay(self, i: int, j: int) -> int:
        """Delay ``tau_ij`` of the edge ``i -> j``.

        Raises
        ------
        GraphError
            If there is no edge ``i -> j`` (use :meth:`geodesic_delays` for
            the delay of the fastest multi-hop route).
        """
        key = (self._check_agent(i, "i"), self._check_agent(j, "j"))
        try:
            return self._delay_map[key]
        except KeyError:
            raise GraphError(
                f"(i, j): expected an edge {key[0]} -> {key[1]}, found none; "
                f"check out_neighbors({key[0]}) = {self.out_neighbors(key[0])}, "
                "or use geodesic_delays() for the delay of a multi-hop route"
            ) from None

    def adjacency(self) -> sp.csr_matrix:
        """Delay-weighted adjacency as an ``n x n`` CSR matrix (0 = no edge).

        Entry ``[i, j]`` is ``tau_ij``. A fresh matrix is returned each call.
        """
        n = self.n_agents
        if not self.edges:
            return sp.csr_matrix((n, n), dtype=np.int64)
        arr = np.asarray(self.edges, dtype=np.int64)
        return sp.csr_matrix((arr[:, 2], (arr[:, 0], arr[:, 1])), shape=(n, n), dtype=np.int64)

    # -- connectivity and geodesic delays --------------------------------------

    @cached_property
    def _distances(self) -> NDArray[np.float64]:
        """All-pairs shortest total delay (``inf`` where unreachable)."""
        n = self.n_agents
        if not self.edges:
            dist = np.full((n, n), np.inf)
            np.fill_diagonal(dist, 0.0)
        elif len(self.edges) == n * (n - 1) and 2 * min(d for _, _, d in self.edges) >= max(d for _, _, d in self.edges):
            # complete, no delay above twice another: a path of two or more hops is never faster than the direct edge
            dist = self.adjacency().toarray().astype(float)
        else:
            dist = scipy_csgraph.shortest_path(self.adjacency().astype(float), method="D", directed=True)
        dist = np.asarray(dist, dtype=float)
        dist.setflags(write=False)
        return dist

    def is_strongly_connected(self) -> bool:
        """Whether every agent has a directed path to every other agent (strong components: O(n + edges), no all-pairs matrix)."""
        if "_distances" in self.__dict__:
            return bool(np.all(np.isfinite(self._distances)))
        from scipy.sparse.csgraph import connected_components

        return self.n_agents == 1 or int(connected_components(self.adjacency(), directed=True, connection="strong")[0]) == 1

    def unreachable_pairs(self) -> list[tuple[int, int]]:
        """All ordered pairs ``(i, j)`` with no directed path ``i -> j``."""
        ii, jj = np.nonzero(~np.isfinite(self._distances))
        return [(int(i), int(j)) for i, j in zip(ii, jj)]

    def require_strongly_connected(self, name: str = "graph") -> CommGraph:
        """Raise unless the graph is strongly connected; return ``self``.

        Parameters
        ----------
        name : str
            How the caller refers to this graph in the message.

        Raises
        ------
        GraphError
            Naming the first (row-major) pair ``(i, j)`` with no directed path
            ``i -> j`` and suggesting an edge that fixes it.
        """
        bad = [] if self.is_strongly_connected() else self.unreachable_pairs()
        if bad:
            i, j = bad[0]
            more = f" ({len(bad)} unreachable ordered pairs in all)" if len(bad) > 1 else ""
            raise GraphError(
                f"{name}: expected a strongly connected graph, found no directed path from agent {i} "
                f"to agent {j}{more}; add an edge such as ({i}, {j}, 1), or make one-way links bidirectional"
            )
        return self

    @cached_property
    def _geodesic(self) -> IntArray:
        self.require_strongly_connected()
        out = np.asarray(self._distances, dtype=np.int64).copy()
        out.setflags(write=False)
        return out

    def geodesic_delays(self) -> IntArray:
        """Geodesic delays ``l_ij`` (eq. (14)) as a read-only ``n x n`` int array.

        Entry ``[i, j]`` is the smallest total delay of a directed path from
        ``i`` to ``j``; the diagonal is 0. Agent ``j`` holds ``y_i(s)`` for
        ``s <= t - l_ij``. Computed once with Dijkstra
        (:func:`scipy.sparse.csgraph.shortest_path`) and cached.

        Raises
        ------
        GraphError
            If the graph is not strongly connected.
        """
        return self._geodesic

    @property
    def diameter(self) -> int:
        """Weighted diameter ``tau* = max_ij l_ij`` (0 for a single agent).

        Raises
        ------
        GraphError
            If the graph is not strongly connected.
        """
        return int(self._geodesic.max())

    # -- derived graphs --------------------------------------------------------

    def with_delay(self, delay: int) -> CommGraph:
        """Same topology with every edge delay replaced by ``delay``."""
        d = _delay(delay, "delay")
        return type(self)(self.n_agents, tuple((s, t, d) for s, t, _ in self.edges))

    def reversed(self) -> CommGraph:
        """The graph with every edge ``i -> j`` turned into ``j -> i`` (same delay)."""
        return type(self)(self.n_agents, tuple((t, s, d) for s, t, d in self.edges))

    # -- builders --------------------------------------------------------------

    @classmethod
    def from_edges(cls, n_agents: int, edges: Iterable[Iterable[Any]]) -> CommGraph:
        """Build from ``n_agents`` and an iterable of ``[from, to, delay]`` edges."""
        return cls(n_agents, edges)  # type: ignore[arg-type]

    @classmethod
    def complete(cls, n: int, delay: int = 1) -> CommGraph:
        """Every ordered pair ``i != j`` linked with the same delay (``l_ij = delay``)."""
        n, d = _count(n, "n"), _delay(delay, "delay")
        _check_size(n, "n", per_pair=8.0 + 120.0)  # the delay matrix, and n - 1 edges per agent (arrays and tuples)
        ii, jj = np.nonzero(~np.eye(n, dtype=bool))
        return cls(n, np.column_stack([ii, jj, np.full(ii.size, d)]))  # type: ignore[arg-type]

    @classmethod
    def line(cls, n: int, delay: int = 1) -> CommGraph:
        """Bidirectional path ``0 - 1 - ... - n-1`` (``l_ij = delay * |i - j|``)."""
        n, d = _count(n, "n"), _delay(delay, "delay")
        es = [(i, i + 1, d) for i in range(n - 1)] + [(i + 1, i, d) for i in range(n - 1)]
        return cls(n, tuple(es))

    @classmethod
    def ring(cls, n: int, delay: int = 1, directed: bool = False) -> CommGraph:
        """Cycle ``0 -> 1 -> ... -> n-1 -> 0``.

        ``directed=False`` (default) links both ways; ``directed=True`` keeps only
        ``i -> i+1 (mod n)``, so ``tau* = delay * (n - 1)``. For ``n = 2`` both
        give the two edges ``0 -> 1`` and ``1 -> 0``.
        """
        n, d = _count(n, "n"), _delay(delay, "delay")
        if not isinstance(directed, (bool, np.bool_)):
            raise GraphError(f"directed: expected True or False, found {directed!r}")
        pairs: set[tuple[int, int]] = set()
        if n > 1:
            for i in range(n):
                pairs.add((i, (i + 1) % n))
                if not directed:
                    pairs.add(((i + 1) % n, i))
        return cls(n, tuple((i, j, d) for i, j in pairs))

    @classmethod
    def star(cls, n: int, delay: int = 1, center: int = 0) -> CommGraph:
        """Bidirectional spokes between ``center`` and every other agent (``tau* = 2 delay``)."""
        n, d = _count(n, "n"), _delay(delay, "delay")
        c = _agent(center, "center", n)
        es = [(c, j, d) for j in range(n) if j != c] + [(j, c, d) for j in range(n) if j != c]
        return cls(n, tuple(es))

    @classmethod
    def random(
        cls,
        n: int,
        p: float = 0.3,
        delays: int | tuple[int, int] = (1, 3),
        *,
        rng: np.random.Generator | int,
        strongly_connected: bool = True,
        max_tries: int = 1000,
    ) -> CommGraph:
        """Directed Erdős–Rényi graph with integer delays.

        Each ordered pair ``i != j`` gets an edge independently with
        probability ``p``; each edge gets a delay drawn uniformly from the
        integers ``lo..hi`` (inclusive). With ``strongly_connected=True`` the
        draw is repeated until the graph is strongly connected.

        Parameters
        ----------
        n : int
            Number of agents (``n = 1`` gives a graph with no edges).
        p : float
            Edge probability in ``[0, 1]``.
        delays : int or (int, int)
            Inclusive delay range ``(lo, hi)`` with ``1 <= lo <= hi``; an int
            ``d`` means ``(d, d)``.
        rng : numpy.random.Generator or int
            Source of randomness (required); an int is a seed for
            :func:`numpy.random.default_rng`. The same seed gives the same graph.
        strongly_connected : bool
            Resample until strongly connected (default) or return the first draw.
        max_tries : int
            Number of draws before giving up.

        Raises
        ------
        GraphError
            On bad arguments, or if no strongly connected draw was found in
            ``max_tries`` attempts (raise ``p``).
        """
        n = _count(n, "n")
        gen = _rng(rng)
        if isinstance(p, (bool, np.bool_)) or not isinstance(p, (Real, np.floating, np.integer)) or not 0.0 <= float(p) <= 1.0:
            raise GraphError(f"p: expected an edge probability in [0, 1], found {p!r}; e.g. p=0.3")
        p = float(p)
        if isinstance(delays, (Integral, np.integer, float, np.floating)) and not isinstance(delays, bool):
            lo = hi = _delay(delays, "delays")
        else:
            try:
                pair = tuple(delays)  # type: ignore[arg-type]
            except TypeError:
                pair = ()
            if len(pair) != 2:
                raise GraphError(f"delays: expected an inclusive range (lo, hi), found {delays!r}; e.g. delays=(1, 3)")
            lo, hi = _delay(pair[0], "delays[0]"), _delay(pair[1], "delays[1]")
            if hi < lo:
                raise GraphError(f"delays: expected lo <= hi, found ({lo}, {hi}); swap the bounds")
        tries = _count(max_tries, "max_tries")
        if n == 1:
            return cls(1, ())
        if strongly_connected and p == 0.0:
            raise GraphError(f"p: expected p > 0 for a strongly connected graph of {n} agents, found 0; raise p")
        off_diag = ~np.eye(n, dtype=bool)
        for _ in range(tries):
            mask = (gen.random((n, n)) < p) & off_diag
            dmat = gen.integers(lo, hi + 1, size=(n, n))
            ii, jj = np.nonzero(mask)
            g = cls(n, tuple((int(i), int(j), int(dmat[i, j])) for i, j in zip(ii, jj)))
            if not strongly_connected or g.is_strongly_connected():
                return g
        raise GraphError(
            f"p: expected an edge probability that gives a strongly connected graph of {n} agents, "
            f"found none in max_tries={tries} draws with p={p}; use a larger p (log(n)/n = "
            f"{np.log(n) / n:.3g} is the connectivity threshold) or raise max_tries"
        )

    # -- networkx --------------------------------------------------------------

    def to_networkx(self) -> nx.DiGraph:
        """A :class:`networkx.DiGraph` on nodes ``0..n-1`` with edge attribute ``delay``."""
        G = nx.DiGraph()
        G.add_nodes_from(range(self.n_agents))
        G.add_weighted_edges_from(self.edges, weight="delay")
        return G

    @staticmethod
    def networkx_node_order(G: nx.Graph) -> list[Hashable]:
        """The node order :meth:`from_networkx` uses: agent ``k`` is ``order[k]``.

        Nodes are sorted if they are mutually comparable, else kept in
        insertion order. Integer nodes ``0..n-1`` thus map to themselves.
        """
        nodes = list(G.nodes)
        try:
            return sorted(nodes)
        except TypeError:
            return nodes

    @classmethod
    def from_networkx(
        cls,
        G: nx.Graph,
        delay: str = "delay",
        default_delay: int | None = None,
    ) -> CommGraph:
        """Build from a networkx graph.

        Parameters
        ----------
        G : networkx.DiGraph or networkx.Graph
            Nodes may be the integers ``0..n-1`` (kept as they are) or any
            hashables, which are relabelled ``0..n-1`` in sorted order when
            they are mutually comparable and in insertion order otherwise (see
            :meth:`networkx_node_order` for the mapping). An undirected graph
            gives both directions of every edge, with the same delay.
            Multigraphs are rejected.
        delay : str
            Name of the edge attribute holding the delay.
        default_delay : int, optional
            Delay for edges without that attribute; if ``None`` such an edge
            raises :class:`GraphError` naming it.
        """
        if not isinstance(G, nx.Graph):
            raise GraphError(f"G: expected a networkx Graph or DiGraph, found {type(G).__name__}")
        if G.is_multigraph():
            raise GraphError(
                f"G: expected a simple graph, found a {type(G).__name__}; keep one edge per pair, "
                "e.g. nx.DiGraph(G) after choosing the delay of parallel edges"
            )
        if default_delay is not None:
            default_delay = _delay(default_delay, "default_delay")
        order = cls.networkx_node_order(G)
        index = {v: k for k, v in enumerate(order)}
        edges: list[Edge] = []
        for u, v, data in G.edges(data=True):
            ename = f"G.edges[{u!r}, {v!r}][{delay!r}]"
            if u == v:
                raise GraphError(f"G: expected no self-loops, found the edge ({u!r}, {v!r}); remove it (nx.selfloop_edges)")
            if delay in data:
                d = _delay(data[delay], ename)
            elif default_delay is not None:
                d = default_delay
            else:
                raise GraphError(
                    f"G: edge ({u!r}, {v!r}) has no {delay!r} attribute (found {sorted(map(str, data))}); "
                    f"set it on every edge or pass default_delay=..."
                )
            edges.append((index[u], index[v], d))
            if not G.is_directed():
                edges.append((index[v], index[u], d))
        return cls(len(order), tuple(edges))

    # -- plain data ------------------------------------------------------------

    def plot(self, ax: Any = None, **kwargs: Any) -> Any:
        """Draw the graph with each edge's delay as its label (networkx + matplotlib); returns the axes.

        Keywords go to :func:`teamkf.plotting.network.plot_graph` (``layout``,
        ``node_labels``, ``node_color``, ``seed``, ``title``).
        """
        from ..plotting.network import plot_graph

        return plot_graph(self, ax, **kwargs)

    def to_dict(self) -> dict[str, Any]:
        """Plain-data form ``{"n_agents": n, "edges": [[i, j, d], ...]}`` for scenario files."""
        return {"n_agents": self.n_agents, "edges": [list(e) for e in self.edges]}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> CommGraph:
        """Inverse of :meth:`to_dict`; both keys are required, others are rejected."""
        if not isinstance(data, Mapping):
            raise GraphError(f"graph: expected a mapping with keys 'n_agents' and 'edges', found {type(data).__name__}")
        missing = [k for k in ("n_agents", "edges") if k not in data]
        if missing:
            raise GraphError(
                f"graph: expected keys 'n_agents' and 'edges', found {sorted(map(str, data))}; "
                f"add {', '.join(repr(k) for k in missing)} (edges = [[from, to, delay], ...])"
            )
        extra = sorted(str(k) for k in data if k not in ("n_agents", "edges"))
        if extra:
            raise GraphError(f"graph: expected only keys 'n_agents' and 'edges', found also {extra}; remove or rename them")
        return cls(data["n_agents"], data["edges"])
