"""Pictures of communication graphs and information structures (matplotlib and networkx, lazy).

:func:`plot_graph` draws a :class:`~teamkf.CommGraph` with each edge's delay
``tau_ij`` as its label; :func:`plot_information` draws an
:class:`~teamkf.InformationStructure` as one lag × source grid per agent: cell
``(lag, j)`` of agent ``i``'s panel says whether ``i`` holds ``y_j(k - lag)`` at
step ``k`` (in its local window, in the common part ``y(0 : k - c)``, or not at
all). The methods :meth:`CommGraph.plot <teamkf.CommGraph.plot>` and
:meth:`InformationStructure.plot <teamkf.InformationStructure.plot>` call them.

Examples
--------
>>> from teamkf import CommGraph, InformationStructure
>>> edge_delay_labels(CommGraph.from_edges(2, [(0, 1, 1), (1, 0, 3)]))
{(0, 1): '0→1: 1\\n1→0: 3'}
>>> information_grid(InformationStructure.own_window(2, common_lag=2, length=1), 0).tolist()
[[1, 0], [0, 0], [2, 2]]
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from . import _pyplot

__all__ = ["plot_graph", "plot_information", "edge_delay_labels", "information_grid", "NOT_HELD", "LOCAL", "COMMON"]

#: cell values of :func:`information_grid`
NOT_HELD, LOCAL, COMMON = 0, 1, 2

_LAYOUTS = ("circular", "spring", "kamada_kawai", "shell", "spectral", "planar")


def edge_delay_labels(graph: Any) -> dict[tuple[int, int], str]:
    """One label per connected pair ``(i, j)``, ``i < j``: the delay, or both directions' delays when they differ."""
    out: dict[tuple[int, int], str] = {}
    delays = {(i, j): d for i, j, d in graph.edges}
    for i, j in delays:
        a, b = min(i, j), max(i, j)
        if (a, b) in out:
            continue
        fwd, back = delays.get((a, b)), delays.get((b, a))
        if fwd is not None and back is not None and fwd == back:
            out[(a, b)] = str(fwd)
        else:
            parts = [f"{a}→{b}: {fwd}"] if fwd is not None else []
            parts += [f"{b}→{a}: {back}"] if back is not None else []
            out[(a, b)] = "\n".join(parts)
    return out


def plot_graph(
    graph: Any,
    ax: Any = None,
    *,
    layout: str | dict[int, Sequence[float]] = "circular",
    node_labels: Sequence[str] | None = None,
    node_color: str = "#cfe2f3",
    seed: int = 0,
    title: str | None = None,
) -> Any:
    """Draw ``graph`` with its edge delays as labels; returns the matplotlib axes.

    Parameters
    ----------
    graph : CommGraph
    ax : matplotlib axes to draw on (default: a new figure)
    layout : a networkx layout name ("circular", "spring", "kamada_kawai",
        "shell", "spectral", "planar") or a mapping agent -> (x, y)
    node_labels : one label per agent (default: the agent indices)
    node_color : fill colour of the nodes
    seed : seed of the "spring" layout (the picture is reproducible)
    title : axes title (default: agents, edges and the weighted diameter tau*)
    """
    import networkx as nx

    from ..exceptions import ArgumentError

    plt = _pyplot()
    n = graph.n_agents
    if ax is None:
        side = 5.0 if n <= 8 else min(9.0, 4.0 + 0.25 * n)  # room for 20 agents and their labels
        _, ax = plt.subplots(figsize=(side, side * 0.9))
    G = graph.to_networkx()
    if isinstance(layout, str):
        if layout not in _LAYOUTS:
            raise ArgumentError(f"layout: expected one of {', '.join(_LAYOUTS)} or a mapping agent -> (x, y), found {layout!r}")
        fn = getattr(nx, f"{layout}_layout")
        pos = fn(G, seed=seed) if layout == "spring" else fn(G)
    else:
        missing = [i for i in range(graph.n_agents) if i not in layout]
        if missing:
            raise ArgumentError(f"layout: expected a position for every agent, found none for {missing}")
        pos = {i: tuple(layout[i]) for i in range(graph.n_agents)}
    if node_labels is None:
        labels = {i: str(i) for i in range(graph.n_agents)}
    else:
        if len(node_labels) != graph.n_agents:
            raise ArgumentError(f"node_labels: expected {graph.n_agents} labels (one per agent), found {len(node_labels)}")
        labels = {i: str(node_labels[i]) for i in range(graph.n_agents)}
    size = 600 if n <= 8 else max(220, 5000 // max(n, 1))  # nodes and labels shrink with the team, not below legibility
    font = 10 if n <= 8 else 8
    nx.draw_networkx_nodes(G, pos, ax=ax, node_color=node_color, edgecolors="0.3", node_size=size)
    nx.draw_networkx_labels(G, pos, labels=labels, ax=ax, font_size=font)
    nx.draw_networkx_edges(G, pos, ax=ax, arrows=True, arrowstyle="-|>", arrowsize=10 if n > 8 else 12, node_size=size, edge_color="0.45", width=0.8)
    delays = {d for _, _, d in graph.edges}
    uniform = len(delays) == 1 and graph.n_edges > 12  # one delay on many edges: said once in the title, not on every edge
    if not uniform:
        nx.draw_networkx_edge_labels(G, pos, edge_labels=edge_delay_labels(graph), ax=ax, font_size=7 if n > 8 else 8, rotate=False)
    if title is None:
        title = f"{graph.n_agents} agents, {graph.n_edges} edges" + (f", every delay {next(iter(delays))}" if uniform else " (labels: delays)")
        if graph.n_agents and graph.is_strongly_connected():
            title += f", τ* = {graph.diameter}"
    ax.set_title(title)
    ax.set_axis_off()
    return ax


def information_grid(structure: Any, agent: int, max_lag: int | None = None) -> np.ndarray:
    """Agent ``agent``'s holdings in steady state as a (max_lag + 1, n_agents) integer grid.

    Entry ``[lag, j]`` is :data:`LOCAL` when the agent holds ``y_j(k - lag)`` in
    a local window, :data:`COMMON` when ``lag >= common_lag`` (the common part,
    held by every agent) and :data:`NOT_HELD` otherwise. ``max_lag`` defaults
    to the common lag (its row stands for every older step).
    """
    from ..exceptions import ArgumentError

    n, c = structure.n_agents, structure.common_lag
    if not (isinstance(agent, (int, np.integer)) and 0 <= agent < n):
        raise ArgumentError(f"agent: expected an agent index in 0..{n - 1}, found {agent!r}")
    L = c if max_lag is None else int(max_lag)
    if L < 0:
        raise ArgumentError(f"max_lag: expected an integer >= 0, found {max_lag!r}")
    grid = np.full((L + 1, n), NOT_HELD, dtype=np.int64)
    grid[c:, :] = COMMON
    for j, lag in structure.local_lags(int(agent)):
        if lag <= L:
            grid[lag, j] = LOCAL
    return grid


def plot_information(
    structure: Any,
    ax: Any = None,
    *,
    agents: Sequence[int] | None = None,
    max_lag: int | None = None,
    title: str | None = None,
) -> Any:
    """One lag × source panel per agent: which ``y_j(k - lag)`` the agent holds; returns the axes (array).

    Parameters
    ----------
    structure : InformationStructure
    ax : a sequence of axes, one per agent drawn (default: a new figure with one row of panels)
    agents : which agents to draw (default: all)
    max_lag : last lag shown (default: the common lag, whose row stands for every older step)
    title : figure title
    """
    from matplotlib.colors import ListedColormap
    from matplotlib.patches import Patch

    from ..exceptions import ArgumentError

    plt = _pyplot()
    who = list(range(structure.n_agents)) if agents is None else [int(a) for a in agents]
    grids = [information_grid(structure, i, max_lag) for i in who]
    n = structure.n_agents
    if ax is None:
        # panels on a grid of at most 5 columns (a page's width), each as wide as its n sources need
        ncols = len(who) if len(who) <= 4 else (3 if len(who) <= 6 else (4 if len(who) <= 12 else 5))
        nrows = -(-len(who) // ncols)
        panel_w = min(3.0, max(2.2, 0.12 * n + 1.0))
        panel_h = min(3.0, 0.28 * grids[0].shape[0] + 1.3)
        fig, axes = plt.subplots(nrows, ncols, figsize=(panel_w * ncols + 0.6, panel_h * nrows + 0.9), squeeze=False, sharey=True)
        axs = list(axes.ravel()[: len(who)])
        for extra in axes.ravel()[len(who) :]:
            extra.set_axis_off()
    else:
        axs = list(np.ravel(ax)) if isinstance(ax, (list, tuple, np.ndarray)) else [ax]
        if len(axs) != len(who):
            raise ArgumentError(f"ax: expected {len(who)} axes (one per agent drawn), found {len(axs)}; pass ax=None for a new figure")
        fig = axs[0].figure
    colors = ["#ffffff", "#3c78d8", "#b7b7b7"]
    cmap = ListedColormap(colors)
    c = structure.common_lag
    for a, i, g in zip(axs, who, grids):
        a.imshow(g, cmap=cmap, vmin=0, vmax=2, aspect="auto", interpolation="nearest")
        every = 1 if n <= 8 else (2 if n <= 16 else 5)  # every source's tick, a label on every few when n is large
        a.set_xticks(range(n))
        a.set_xticklabels([str(j) if j % every == 0 else "" for j in range(n)], fontsize=8 if n <= 10 else 7)
        rows = g.shape[0]
        a.set_yticks(range(rows))
        a.set_yticklabels(
            [f"k-{lag}" if lag else "k" for lag in range(rows - 1)] + [f"≤k-{rows - 1}" if rows - 1 >= c else f"k-{rows - 1}"], fontsize=8
        )
        a.set_xticks(np.arange(-0.5, structure.n_agents, 1), minor=True)
        a.set_yticks(np.arange(-0.5, rows, 1), minor=True)
        a.grid(which="minor", color="0.6", linewidth=0.5)
        a.tick_params(which="minor", length=0)
        a.set_title(f"agent {i}", fontsize=10)
        a.set_xlabel("source j")
    for a in axs:
        spec = a.get_subplotspec() if hasattr(a, "get_subplotspec") else None
        if a is axs[0] or (spec is not None and spec.is_first_col()):
            a.set_ylabel("step s of y_j(s)")
    handles = [
        Patch(facecolor=colors[LOCAL], label="local window"),
        Patch(facecolor=colors[COMMON], label=f"common (lag ≥ {c})"),
        Patch(facecolor=colors[NOT_HELD], edgecolor="0.6", label="not held"),
    ]
    fig.legend(handles=handles, loc="lower center", ncol=3, fontsize=8, frameon=False, bbox_to_anchor=(0.5, 0.0))
    fig.suptitle(title if title is not None else "information structure: what each agent holds at step k", fontsize=10)
    fig.tight_layout(rect=(0, 0.5 / fig.get_figheight(), 1, 1))
    return np.array(axs, dtype=object) if len(axs) > 1 else axs[0]
