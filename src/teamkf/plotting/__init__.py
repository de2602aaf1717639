"""matplotlib helpers; matplotlib is imported lazily and plt.show() is never called."""

from __future__ import annotations

from typing import Any, Sequence

from .._validation import require
from .colors import family_color, family_style

__all__ = ["stage_cost_axes", "mc_band_axes", "family_color", "family_style", "legend_outside", "legends_off_the_data", "legend_overlaps"]


def _pyplot() -> Any:
    mpl = require("matplotlib", "plot")
    if mpl.get_backend().lower() not in ("agg", "pdf", "svg") and not _has_display():
        mpl.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _has_display() -> bool:
    import os

    return bool(os.environ.get("DISPLAY"))


def legend_outside(ax: Any, **kwargs: Any) -> Any:
    """Put the legend to the right of the axes, off the data (the figure widens to hold it).

    Parameters
    ----------
    ax : matplotlib Axes
        The axes whose labelled lines go into the legend.
    **kwargs
        More keywords for ``ax.legend``.

    Returns
    -------
    matplotlib.legend.Legend or None
        The legend (None when nothing is labelled).

    Examples
    --------
    >>> import matplotlib
    >>> matplotlib.use("Agg")
    >>> import matplotlib.pyplot as plt
    >>> fig, ax = plt.subplots()
    >>> _ = ax.plot([0, 1], [0, 1], label="mtmse")
    >>> legend_outside(ax).get_texts()[0].get_text()
    'mtmse'
    """
    handles, labels = ax.get_legend_handles_labels()
    if not labels:
        return None
    opts = {"loc": "upper left", "bbox_to_anchor": (1.02, 1.0), "borderaxespad": 0.0, "frameon": False, "fontsize": "small"}
    opts.update(kwargs)
    return ax.legend(handles, labels, **opts)


def legend_overlaps(legend: Any, fig: Any) -> bool:
    """Whether ``legend`` (of an axes or of the figure) covers part of any axes' data area, in display coordinates."""
    try:
        renderer = fig.canvas.get_renderer()
    except AttributeError:  # a closed figure (its canvas reset by pyplot)
        renderer = fig._get_renderer()
    box = legend.get_window_extent(renderer)
    return any(ax.get_visible() and ax.axison and box.overlaps(ax.get_window_extent(renderer)) for ax in fig.axes)


def legends_off_the_data(fig: Any) -> int:
    """Move every legend of ``fig`` that covers an axes' data area off the data; returns how many moved.

    An axes' legend goes to the right of its axes (:func:`legend_outside`) and the layout makes room for it;
    a figure legend goes to the right of the figure (saved with ``bbox_inches="tight"``, it widens the image).
    The experiments' :func:`~teamkf.experiments.save_figure` calls it on every figure it writes.

    Examples
    --------
    >>> import matplotlib
    >>> matplotlib.use("Agg")
    >>> import matplotlib.pyplot as plt
    >>> fig, ax = plt.subplots()
    >>> _ = ax.plot([0, 1], [0, 1], label="mtmse")
    >>> _ = ax.legend(loc="center")
    >>> legends_off_the_data(fig), legend_overlaps(ax.get_legend(), fig)
    (1, False)
    """
    fig.canvas.draw()
    moved = 0
    for ax in fig.axes:
        leg = ax.get_legend()
        if leg is not None and legend_overlaps(leg, fig):
            opts = {"title": leg.get_title().get_text() or None, "ncols": getattr(leg, "_ncols", 1)}
            legend_outside(ax, **opts)
            moved += 1
    if moved and not fig.get_constrained_layout():
        fig.tight_layout()  # the axes shrink to leave room for the legends now beside them
    for leg in fig.legends:
        fig.canvas.draw()
        if legend_overlaps(leg, fig):
            leg.set_loc("center left")
            leg.set_bbox_to_anchor((1.0, 0.5), transform=fig.transFigure)
            moved += 1
    return moved


def stage_cost_axes(designs: Sequence[Any], ax: Any = None, *, log: bool = False, title: str | None = None, monte_carlo: Any = None) -> Any:
    """Plot the stage costs of several designs on one axes, each family in its own colour.

    Parameters
    ----------
    designs : sequence of Design
        Finite-horizon designs plot their analytic E[c(x(t), ẑ(t))] per step; a steady-state one its
        average cost as a dashed line.
    ax : matplotlib Axes, optional
        Where to draw; a new figure when None.
    log : bool
        A logarithmic cost axis.
    title : str, optional
        The axes' title.
    monte_carlo : mapping of str to MonteCarloResult, optional
        Monte Carlo results by design name (what :func:`~teamkf.monte_carlo` returns): each is drawn
        as its mean per step with a 95 % band, in the family's colour; a design without an analytic
        cost is then shown by its Monte Carlo mean.

    Returns
    -------
    matplotlib.axes.Axes
        The axes drawn on.

    Examples
    --------
    >>> from teamkf import LinearGaussianSystem, TeamCost, CommGraph, design_mtmse, design_mmse
    >>> from teamkf.plotting import stage_cost_axes
    >>> system, cost, graph = LinearGaussianSystem.platoon(4), TeamCost.platoon(4, 100.0), CommGraph.line(4, delay=1)
    >>> ax = stage_cost_axes([design_mtmse(system, cost, graph, horizon=20), design_mmse(system, cost, graph, horizon=20)])
    >>> [line.get_label() for line in ax.lines]
    ['mtmse', 'mmse']
    """
    plt = _pyplot()
    if ax is None:
        _, ax = plt.subplots(figsize=(8, 4), layout="constrained")
    mc = dict(monte_carlo or {})
    for d in designs:
        label = getattr(d, "label", None) or d.estimator
        style = family_style(label)
        if d.stage_costs is None and d.average_cost is not None:
            ax.axhline(d.average_cost, label=f"{label} (average)", color=style["color"], linestyle="--")
        elif d.stage_costs is not None:
            ax.plot(range(1, len(d.stage_costs) + 1), d.stage_costs, label=label, **style)
    if mc:
        mc_band_axes(mc, ax=ax, log=log, analytic={getattr(d, "estimator", None) for d in designs if d.stage_costs is not None})
    ax.set_xlabel("step t")
    ax.set_ylabel("stage cost E[c(x(t), ẑ(t))]")
    if log:
        ax.set_yscale("log")
    if title:
        ax.set_title(title)
    legend_outside(ax)
    return ax


def mc_band_axes(results: Any, ax: Any = None, *, log: bool = False, analytic: Any = ()) -> Any:
    """Monte Carlo mean stage costs with their 95 % bands, each family in its own colour.

    Parameters
    ----------
    results : mapping of str to MonteCarloResult
        What :func:`~teamkf.monte_carlo` returns.
    ax : matplotlib Axes, optional
        Where to draw; a new figure when None.
    log : bool
        A logarithmic cost axis.
    analytic : collection of str
        Names whose analytic curve is already on the axes: their Monte Carlo mean is drawn as
        markers (a check of the analytic value) instead of a second line.

    Returns
    -------
    matplotlib.axes.Axes
        The axes drawn on.

    Examples
    --------
    >>> from teamkf import LinearGaussianSystem, TeamCost, design_centralized, monte_carlo
    >>> from teamkf.plotting import mc_band_axes
    >>> kf = design_centralized(LinearGaussianSystem.platoon(3), TeamCost.platoon(3, 1.0), horizon=10)
    >>> ax = mc_band_axes(monte_carlo({"centralized": kf}, 10, 200, rng=1))
    >>> ax.lines[0].get_label()
    'centralized (Monte Carlo, 200 runs)'
    """
    import numpy as np

    plt = _pyplot()
    if ax is None:
        _, ax = plt.subplots(figsize=(8, 4), layout="constrained")
    analytic = set(analytic)
    for name, r in results.items():
        style = family_style(name)
        t = np.arange(1, len(r.stage_mean) + 1)
        lo, hi = r.stage_ci95
        ax.fill_between(t, lo, hi, color=style["color"], alpha=0.2, linewidth=0)
        label = f"{name} (Monte Carlo, {r.n_runs} runs)"
        if name in analytic:
            ax.plot(t, r.stage_mean, linestyle="none", marker=".", markersize=4, color=style["color"], label=label)
        else:
            ax.plot(t, r.stage_mean, label=label, **style)
    ax.set_xlabel("step t")
    ax.set_ylabel("stage cost E[c(x(t), ẑ(t))]")
    if log:
        ax.set_yscale("log")
    legend_outside(ax)
    return ax
