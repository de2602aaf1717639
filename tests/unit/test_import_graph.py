"""The import graph of teamkf has no circle (function-local imports included).

import-linter (``make lint``) checks the layers, the independence of the estimator families and what the CLI
imports; a circle inside one layer (two modules of ``teamkf.study`` importing each other, say) passes those
contracts, so it is checked here on grimp's graph, the one import-linter reads.
"""

from __future__ import annotations

import networkx as nx
import pytest

grimp = pytest.importorskip("grimp")


def _graph() -> nx.DiGraph:
    g = grimp.build_graph("teamkf", include_external_packages=False, cache_dir=None)
    G = nx.DiGraph()
    for m in g.modules:
        G.add_node(m)
        G.add_edges_from((m, d) for d in g.find_modules_directly_imported_by(m))
    return G


def _circles(G: nx.DiGraph) -> list[list[str]]:
    return [sorted(c) for c in nx.strongly_connected_components(G) if len(c) > 1]


def test_the_import_graph_has_no_circle():
    G = _graph()
    assert G.number_of_nodes() > 50 and G.has_edge("teamkf.__main__", "teamkf.cli")  # the graph was built, with its edges
    circles = _circles(G)
    cycles = [[a for a, _ in nx.find_cycle(G.subgraph(c))] for c in circles]
    assert not circles, "import circles: " + "; ".join(" -> ".join([*cyc, cyc[0]]) for cyc in cycles)


def test_the_circle_check_finds_a_circle():
    """The check itself can fail: one added edge back up the graph makes a circle it reports."""
    G = _graph()
    path = nx.shortest_path(G, "teamkf.__main__", "teamkf.exceptions")
    G.add_edge(path[-1], path[0])
    assert any(set(path) <= set(c) for c in _circles(G))
