"""Unit tests for teamkf.network.graph.CommGraph."""

from __future__ import annotations

import copy
import dataclasses
import json
import pickle

import networkx as nx
import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import given, settings
from hypothesis import strategies as st

from teamkf.exceptions import GraphError, TeamkfError
from teamkf.network.graph import CommGraph

# ----------------------------------------------------------------------------
# independent reference: Floyd–Warshall on the edge list
# ----------------------------------------------------------------------------


def floyd_warshall(n: int, edges) -> np.ndarray:
    d = np.full((n, n), np.inf)
    np.fill_diagonal(d, 0.0)
    for i, j, w in edges:
        d[i, j] = min(d[i, j], w)
    for k in range(n):
        for i in range(n):
            for j in range(n):
                if d[i, k] + d[k, j] < d[i, j]:
                    d[i, j] = d[i, k] + d[k, j]
    return d


@st.composite
def edge_lists(draw, max_n: int = 7, max_delay: int = 6):
    n = draw(st.integers(1, max_n))
    pairs = [(i, j) for i in range(n) for j in range(n) if i != j]
    chosen = draw(st.lists(st.sampled_from(pairs), unique=True)) if pairs else []
    edges = [(i, j, draw(st.integers(1, max_delay))) for i, j in chosen]
    return n, edges


# ----------------------------------------------------------------------------
# construction and normalisation
# ----------------------------------------------------------------------------


def test_fields_are_normalised_and_sorted():
    g = CommGraph(3, [[2, 0, 1.0], (0, 1, np.int64(2)), [1, 2, 3]])
    assert g.n_agents == 3
    assert g.edges == ((0, 1, 2), (1, 2, 3), (2, 0, 1))
    assert all(type(x) is int for e in g.edges for x in e)
    assert g.n_edges == 3


def test_frozen_equal_hashable():
    a = CommGraph(2, [(0, 1, 1), (1, 0, 2)])
    b = CommGraph(2, [(1, 0, 2), (0, 1, 1)])
    assert a == b and hash(a) == hash(b)
    with pytest.raises(dataclasses.FrozenInstanceError):
        a.n_agents = 3  # type: ignore[misc]
    a.geodesic_delays()  # populate cache; equality must not depend on it
    assert a == b


def test_from_edges_matches_constructor():
    es = [[0, 1, 2], [1, 0, 3]]
    assert CommGraph.from_edges(2, es) == CommGraph(2, tuple(map(tuple, es)))
    assert CommGraph.from_edges(2, np.array(es)) == CommGraph(2, tuple(map(tuple, es)))


def test_single_agent_no_edges():
    g = CommGraph(1)
    assert g.edges == ()
    assert g.is_strongly_connected()
    assert g.diameter == 0
    assert g.geodesic_delays().tolist() == [[0]]


# ----------------------------------------------------------------------------
# builders
# ----------------------------------------------------------------------------


@pytest.mark.parametrize("n", [1, 2, 3, 5])
@pytest.mark.parametrize("d", [1, 3])
def test_complete(n, d):
    g = CommGraph.complete(n, delay=d)
    assert g.n_edges == n * (n - 1)
    assert {e[2] for e in g.edges} <= {d}
    L = g.geodesic_delays()
    assert np.array_equal(L, d * (1 - np.eye(n, dtype=int)))
    assert g.diameter == (d if n > 1 else 0)


@pytest.mark.parametrize("n", [1, 2, 4, 7])
def test_line_unit_delay(n):
    g = CommGraph.line(n)
    assert g.n_edges == 2 * (n - 1)
    idx = np.arange(n)
    assert np.array_equal(g.geodesic_delays(), np.abs(idx[:, None] - idx[None, :]))
    assert g.diameter == n - 1


def test_line_with_delay():
    g = CommGraph.line(4, delay=2)
    assert g.diameter == 6
    assert g.geodesic_delays()[0, 3] == 6


@pytest.mark.parametrize("n", [2, 3, 6])
@pytest.mark.parametrize("d", [1, 2])
def test_directed_ring(n, d):
    g = CommGraph.ring(n, delay=d, directed=True)
    assert g.n_edges == n
    assert g.edges == tuple(sorted((i, (i + 1) % n, d) for i in range(n)))
    assert g.diameter == d * (n - 1)
    L = g.geodesic_delays()
    for i in range(n):
        for j in range(n):
            assert L[i, j] == d * ((j - i) % n)


@pytest.mark.parametrize("n", [2, 3, 6, 7])
def test_undirected_ring(n):
    g = CommGraph.ring(n, delay=2)
    assert g.n_edges == (2 if n == 2 else 2 * n)
    assert g.diameter == 2 * (n // 2)
    assert g == g.reversed()


def test_ring_one_agent():
    assert CommGraph.ring(1).edges == ()
    assert CommGraph.ring(1, directed=True).edges == ()


@pytest.mark.parametrize("n", [2, 3, 5])
@pytest.mark.parametrize("center", [0, 1])
@pytest.mark.parametrize("d", [1, 4])
def test_star(n, center, d):
    g = CommGraph.star(n, delay=d, center=center)
    assert g.n_edges == 2 * (n - 1)
    assert g.in_neighbors(center) == tuple(j for j in range(n) if j != center)
    assert g.diameter == (2 * d if n > 2 else d)


def test_star_diameter_is_twice_delay():
    assert CommGraph.star(6, delay=3).diameter == 6


@pytest.mark.parametrize("builder", [CommGraph.complete, CommGraph.line, CommGraph.ring, CommGraph.star])
def test_builders_one_agent(builder):
    g = builder(1)
    assert g.n_agents == 1 and g.edges == ()


# ----------------------------------------------------------------------------
# geodesic delays vs independent references
# ----------------------------------------------------------------------------


@settings(max_examples=150, deadline=None)
@given(edge_lists())
def test_geodesic_matches_floyd_warshall(case):
    n, edges = case
    g = CommGraph(n, edges)
    ref = floyd_warshall(n, edges)
    assert g.is_strongly_connected() == bool(np.all(np.isfinite(ref)))
    if g.is_strongly_connected():
        L = g.geodesic_delays()
        assert L.dtype.kind == "i"
        assert np.array_equal(L, ref.astype(int))
        assert g.diameter == int(ref.max())
    else:
        with pytest.raises(GraphError):
            g.geodesic_delays()
        with pytest.raises(GraphError):
            _ = g.diameter
        assert set(g.unreachable_pairs()) == {tuple(map(int, p)) for p in zip(*np.nonzero(np.isinf(ref)))}


def test_geodesic_matches_networkx_seeded():
    for seed in range(25):
        g = CommGraph.random(8, p=0.35, delays=(1, 5), rng=seed)
        lengths = dict(nx.all_pairs_dijkstra_path_length(g.to_networkx(), weight="delay"))
        L = g.geodesic_delays()
        for i in range(8):
            for j in range(8):
                assert L[i, j] == lengths[i][j]


def test_unequal_delays_take_the_fast_detour():
    # 0 -> 2 directly costs 10, via 1 it costs 3
    g = CommGraph(3, [(0, 2, 10), (0, 1, 1), (1, 2, 2), (2, 0, 1)])
    L = g.geodesic_delays()
    assert L[0, 2] == 3
    assert L[1, 0] == 3
    assert L[2, 1] == 2
    assert g.diameter == 3


def test_geodesic_is_cached_and_read_only():
    g = CommGraph.line(4)
    L = g.geodesic_delays()
    assert g.geodesic_delays() is L
    assert not L.flags.writeable
    with pytest.raises(ValueError):
        L[0, 1] = 7


def test_pickle_and_copy_roundtrip():
    g = CommGraph.random(5, rng=1)
    g.geodesic_delays()
    for h in (pickle.loads(pickle.dumps(g)), copy.deepcopy(g), copy.copy(g)):
        assert h == g
        assert np.array_equal(h.geodesic_delays(), g.geodesic_delays())
        assert not h.geodesic_delays().flags.writeable


# ----------------------------------------------------------------------------
# neighbours, delays, adjacency, derived graphs
# ----------------------------------------------------------------------------


def test_neighbors_delay_adjacency():
    g = CommGraph(4, [(0, 1, 2), (2, 1, 3), (1, 3, 1), (3, 0, 4)])
    assert g.in_neighbors(1) == (0, 2)
    assert g.out_neighbors(1) == (3,)
    assert g.in_neighbors(2) == ()
    assert g.delay(2, 1) == 3
    assert g.has_edge(0, 1) and not g.has_edge(1, 0)
    A = g.adjacency()
    assert sp.issparse(A) and A.format == "csr"
    dense = A.toarray()
    assert dense.shape == (4, 4)
    assert dense[0, 1] == 2 and dense[2, 1] == 3 and dense[1, 3] == 1 and dense[3, 0] == 4
    assert np.count_nonzero(dense) == 4


def test_delay_missing_edge():
    g = CommGraph.line(3)
    with pytest.raises(GraphError, match=r"0 -> 2"):
        g.delay(0, 2)


@pytest.mark.parametrize("bad", [-1, 3, 1.5, True])
def test_agent_index_checked(bad):
    g = CommGraph.line(3)
    with pytest.raises(GraphError, match=r"i: expected an agent index"):
        g.in_neighbors(bad)


def test_adjacency_empty():
    A = CommGraph(3).adjacency()
    assert A.shape == (3, 3) and A.nnz == 0


def test_with_delay_and_reversed():
    g = CommGraph(3, [(0, 1, 1), (1, 2, 2), (2, 0, 3)])
    h = g.with_delay(5)
    assert [(s, t) for s, t, _ in h.edges] == [(s, t) for s, t, _ in g.edges]
    assert {d for *_, d in h.edges} == {5}
    assert h.diameter == 10
    r = g.reversed()
    assert r.edges == tuple(sorted([(1, 0, 1), (2, 1, 2), (0, 2, 3)]))
    assert np.array_equal(r.geodesic_delays(), g.geodesic_delays().T)
    assert r.reversed() == g
    with pytest.raises(GraphError, match=r"delay.*found 0"):
        g.with_delay(0)


def test_repr_short():
    assert repr(CommGraph.line(3)) == "CommGraph(n_agents=3, n_edges=4, delay=1)"
    assert repr(CommGraph(2, [(0, 1, 1), (1, 0, 3)])) == "CommGraph(n_agents=2, n_edges=2, delays=1..3)"
    assert repr(CommGraph(1)) == "CommGraph(n_agents=1, n_edges=0)"


# ----------------------------------------------------------------------------
# random builder
# ----------------------------------------------------------------------------


def test_random_reproducible_connected_in_range():
    a = CommGraph.random(10, p=0.25, delays=(2, 4), rng=np.random.default_rng(42))
    b = CommGraph.random(10, p=0.25, delays=(2, 4), rng=np.random.default_rng(42))
    c = CommGraph.random(10, p=0.25, delays=(2, 4), rng=42)
    assert a == b == c
    for seed in range(20):
        g = CommGraph.random(9, p=0.3, delays=(2, 4), rng=seed)
        assert g.is_strongly_connected()
        assert all(2 <= d <= 4 for *_, d in g.edges)
        assert all(s != t for s, t, _ in g.edges)


def test_random_uses_whole_delay_range():
    g = CommGraph.random(12, p=0.8, delays=(1, 3), rng=0)
    assert {d for *_, d in g.edges} == {1, 2, 3}


def test_random_single_delay_and_one_agent():
    g = CommGraph.random(6, p=0.5, delays=2, rng=3)
    assert {d for *_, d in g.edges} == {2}
    assert CommGraph.random(1, rng=0).edges == ()


def test_random_not_required_connected():
    g = CommGraph.random(6, p=0.0, rng=0, strongly_connected=False)
    assert g.edges == () and not g.is_strongly_connected()


def test_random_gives_up():
    with pytest.raises(GraphError, match=r"larger p"):
        CommGraph.random(30, p=0.01, rng=0, max_tries=5)
    with pytest.raises(GraphError, match=r"p: .*found 0"):
        CommGraph.random(3, p=0.0, rng=0)


@pytest.mark.parametrize(
    "kwargs, pattern",
    [
        (dict(p=1.5), r"p: .*found 1\.5"),
        (dict(p=-0.1), r"p: .*found -0\.1"),
        (dict(delays=(3, 1)), r"delays: .*found \(3, 1\)"),
        (dict(delays=(0, 2)), r"delays\[0\]: .*found 0"),
        (dict(delays=(1, 2, 3)), r"delays: .*found \(1, 2, 3\)"),
        (dict(max_tries=0), r"max_tries: .*found 0"),
    ],
)
def test_random_argument_checks(kwargs, pattern):
    with pytest.raises(GraphError, match=pattern):
        CommGraph.random(4, rng=0, **kwargs)


@pytest.mark.parametrize("rng", [None, "seed", 1.5, True])
def test_random_rng_checked(rng):
    with pytest.raises(GraphError, match=r"rng: .*found"):
        CommGraph.random(4, rng=rng)


def test_random_rng_required():
    with pytest.raises(TypeError):
        CommGraph.random(4)  # type: ignore[call-arg]


# ----------------------------------------------------------------------------
# networkx
# ----------------------------------------------------------------------------


def test_networkx_roundtrip():
    g = CommGraph.random(7, p=0.4, delays=(1, 4), rng=5)
    G = g.to_networkx()
    assert isinstance(G, nx.DiGraph)
    assert sorted(G.nodes) == list(range(7))
    assert {(u, v, d["delay"]) for u, v, d in G.edges(data=True)} == set(g.edges)
    assert CommGraph.from_networkx(G) == g


def test_to_networkx_keeps_isolated_nodes():
    G = CommGraph(3, [(0, 1, 1)]).to_networkx()
    assert sorted(G.nodes) == [0, 1, 2]


def test_from_undirected_gives_both_directions():
    G = nx.Graph()
    G.add_edge(0, 1, delay=2)
    G.add_edge(1, 2, delay=3)
    g = CommGraph.from_networkx(G)
    assert g.edges == ((0, 1, 2), (1, 0, 2), (1, 2, 3), (2, 1, 3))
    assert g.diameter == 5


def test_from_networkx_relabels_sorted():
    G = nx.DiGraph()
    G.add_edge("c", "a", delay=1)
    G.add_edge("a", "b", delay=2)
    G.add_edge("b", "c", delay=3)
    assert CommGraph.networkx_node_order(G) == ["a", "b", "c"]
    g = CommGraph.from_networkx(G)
    assert g.edges == ((0, 1, 2), (1, 2, 3), (2, 0, 1))


def test_from_networkx_non_contiguous_ints_relabel_sorted():
    G = nx.DiGraph()
    G.add_edge(30, 10, delay=1)
    G.add_edge(10, 20, delay=1)
    g = CommGraph.from_networkx(G)
    assert g.edges == ((0, 1, 1), (2, 0, 1))


def test_from_networkx_unsortable_uses_insertion_order():
    G = nx.DiGraph()
    G.add_node("x")
    G.add_node(0)
    G.add_node(("t",))
    G.add_edge(0, "x", delay=2)
    G.add_edge(("t",), 0, delay=1)
    assert CommGraph.networkx_node_order(G) == ["x", 0, ("t",)]
    assert CommGraph.from_networkx(G).edges == ((1, 0, 2), (2, 1, 1))


def test_from_networkx_delay_attribute_and_default():
    G = nx.DiGraph()
    G.add_edge(0, 1, w=4)
    G.add_edge(1, 0)
    with pytest.raises(GraphError, match=r"edge \(0, 1\) has no 'delay' attribute"):
        CommGraph.from_networkx(G)
    with pytest.raises(GraphError, match=r"edge \(1, 0\) has no 'w' attribute"):
        CommGraph.from_networkx(G, delay="w")
    g = CommGraph.from_networkx(G, delay="w", default_delay=2)
    assert g.edges == ((0, 1, 4), (1, 0, 2))


def test_from_networkx_bad_inputs():
    G = nx.DiGraph()
    G.add_edge(0, 1, delay=0.5)
    with pytest.raises(GraphError, match=r"G\.edges\[0, 1\]\['delay'\].*found 0\.5"):
        CommGraph.from_networkx(G)
    M = nx.MultiDiGraph()
    M.add_edge(0, 1, delay=1)
    with pytest.raises(GraphError, match=r"G: .*MultiDiGraph"):
        CommGraph.from_networkx(M)
    with pytest.raises(GraphError, match=r"G: .*found dict"):
        CommGraph.from_networkx({0: [1]})  # type: ignore[arg-type]
    S = nx.DiGraph()
    S.add_edge(0, 0, delay=1)
    with pytest.raises(GraphError, match=r"self-loops.*\(0, 0\)"):
        CommGraph.from_networkx(S)
    with pytest.raises(GraphError, match=r"n_agents"):
        CommGraph.from_networkx(nx.DiGraph())
    with pytest.raises(GraphError, match=r"default_delay.*found 0"):
        CommGraph.from_networkx(G, default_delay=0)


# ----------------------------------------------------------------------------
# dict round trip
# ----------------------------------------------------------------------------


def test_dict_roundtrip_through_json():
    g = CommGraph.random(6, p=0.4, rng=11)
    d = g.to_dict()
    assert d["n_agents"] == 6 and d["edges"] == [list(e) for e in g.edges]
    assert CommGraph.from_dict(json.loads(json.dumps(d))) == g


@pytest.mark.parametrize(
    "data, pattern",
    [
        ({"edges": []}, r"'n_agents'"),
        ({"n_agents": 2}, r"'edges'"),
        ({"n_agents": 2, "edges": [], "delay": 1}, r"\['delay'\]"),
        ([2, []], r"found list"),
        ({"n_agents": 2, "edges": [[0, 1]]}, r"edges\[0\]: .*found \[0, 1\]"),
        ({"n_agents": 2, "edges": 5}, r"edges: .*found int"),
    ],
)
def test_from_dict_errors(data, pattern):
    with pytest.raises(GraphError, match=pattern):
        CommGraph.from_dict(data)


# ----------------------------------------------------------------------------
# validation: type, argument name and found value in the message
# ----------------------------------------------------------------------------


@pytest.mark.parametrize(
    "n_agents, edges, pattern",
    [
        (0, (), r"n_agents: .*>= 1.*found 0"),
        (-2, (), r"n_agents: .*found -2"),
        (2.5, (), r"n_agents: .*found 2\.5"),
        (True, (), r"n_agents: .*found True"),
        ("3", (), r"n_agents: .*found '3'"),
        (3, [(1, 1, 1)], r"edges\[0\]: .*self-loop \(1, 1\)"),
        (3, [(0, 1, 1), (1, 2, 1), (0, 1, 2)], r"edges: .*pair \(0, 1\) twice.*edges\[0\].*edges\[2\]"),
        (2, [(0, 1, 0)], r"edges\[0\] delay: expected an integer delay >= 1, found 0"),
        (2, [(0, 1, -3)], r"edges\[0\] delay: .*found -3"),
        (2, [(0, 1, 1.5)], r"edges\[0\] delay: .*found 1\.5"),
        (2, [(0, 1, True)], r"edges\[0\] delay: .*found True"),
        (2, [(0, 1, float("nan"))], r"edges\[0\] delay: .*found nan"),
        (2, [(0, 1, "1")], r"edges\[0\] delay: .*found '1'"),
        (3, [(0, 3, 1)], r"edges\[0\] target: expected an agent index in 0\.\.2, found 3"),
        (3, [(1, 0, 1), (-1, 0, 1)], r"edges\[1\] source: .*found -1"),
        (3, [(0.5, 1, 1)], r"edges\[0\] source: .*found 0\.5"),
        (3, [(0, 1)], r"edges\[0\]: expected a \(source, target, delay\) triple, found \(0, 1\)"),
        (3, [5], r"edges\[0\]: .*found 5"),
        (3, ["abc"], r"edges\[0\]: .*found 'abc'"),
        (3, "012", r"edges: .*found str"),
        (3, None, r"edges: .*found NoneType"),
    ],
)
def test_constructor_validation(n_agents, edges, pattern):
    with pytest.raises(GraphError, match=pattern) as info:
        CommGraph(n_agents, edges)
    assert isinstance(info.value, TeamkfError) and isinstance(info.value, ValueError)


def test_validation_messages_suggest_a_fix():
    cases = [
        lambda: CommGraph(2, [(0, 1, 0)]),
        lambda: CommGraph(2, [(0, 0, 1)]),
        lambda: CommGraph(2, [(0, 1, 1), (0, 1, 1)]),
        lambda: CommGraph(2, [(0, 2, 1)]),
        lambda: CommGraph(2, [(0, 1, 1)]).require_strongly_connected(),
    ]
    for make in cases:
        with pytest.raises(GraphError) as info:
            make()
        assert ";" in str(info.value)  # "expected ..., found ...; <fix>"


@pytest.mark.parametrize(
    "call, pattern",
    [
        (lambda: CommGraph.complete(0), r"n: .*found 0"),
        (lambda: CommGraph.line(3, delay=0), r"delay: .*found 0"),
        (lambda: CommGraph.ring(3, delay=1.5), r"delay: .*found 1\.5"),
        (lambda: CommGraph.ring(3, directed="yes"), r"directed: .*found 'yes'"),
        (lambda: CommGraph.star(3, center=3), r"center: .*found 3"),
        (lambda: CommGraph.star(3, delay=-1), r"delay: .*found -1"),
    ],
)
def test_builder_validation(call, pattern):
    with pytest.raises(GraphError, match=pattern):
        call()


def test_integral_float_delay_accepted():
    assert CommGraph(2, [(0, 1, 2.0), (1.0, 0, np.float32(3))]).edges == ((0, 1, 2), (1, 0, 3))
    assert CommGraph.complete(3, delay=2.0).diameter == 2


# ----------------------------------------------------------------------------
# strong connectivity
# ----------------------------------------------------------------------------


def test_not_strongly_connected_names_pair():
    g = CommGraph(3, [(0, 1, 1), (1, 2, 1)])  # a one-way path: nothing reaches 0
    assert not g.is_strongly_connected()
    with pytest.raises(GraphError, match=r"my_graph: .*no directed path from agent 1 to agent 0.*add an edge such as \(1, 0, 1\)"):
        g.require_strongly_connected("my_graph")
    with pytest.raises(GraphError, match=r"graph: .*from agent 1 to agent 0"):
        g.geodesic_delays()
    with pytest.raises(GraphError, match=r"from agent 1 to agent 0"):
        _ = g.diameter
    assert g.unreachable_pairs() == [(1, 0), (2, 0), (2, 1)]


def test_require_strongly_connected_returns_self():
    g = CommGraph.ring(4, directed=True)
    assert g.require_strongly_connected() is g


def test_disconnected_components():
    g = CommGraph(4, [(0, 1, 1), (1, 0, 1), (2, 3, 1), (3, 2, 1)])
    assert not g.is_strongly_connected()
    with pytest.raises(GraphError, match=r"from agent 0 to agent 2"):
        g.require_strongly_connected()
    # inspection still works on a broken graph
    assert g.in_neighbors(2) == (3,)
    assert g.to_dict()["n_agents"] == 4


@pytest.mark.parametrize("dmin, dmax", [(1, 1), (2, 4), (1, 3), (3, 7)])
def test_complete_graph_geodesics_equal_dijkstra(dmin: int, dmax: int) -> None:
    """A complete graph takes the direct-edge shortcut only when no delay is above twice another; Dijkstra agrees either way."""
    n = 70  # >= 64 edges: the vectorized edge check too
    rng = np.random.default_rng(dmin * 10 + dmax)
    edges = [(i, j, int(rng.integers(dmin, dmax + 1))) for i in range(n) for j in range(n) if i != j]
    g = CommGraph(n, edges)
    ref = sp.csgraph.shortest_path(g.adjacency().astype(float), method="D", directed=True)
    np.testing.assert_array_equal(g.geodesic_delays(), ref.astype(np.int64))
    assert (dmax > 2 * dmin) == bool((g.geodesic_delays() < g.adjacency().toarray()).any())  # a faster two-hop path exists
