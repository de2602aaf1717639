"""matplotlib helpers; matplotlib is imported lazily and plt.show() is never called."""

from __future__ import annotations

from typing import Any, Sequence

from .._validation import require
from .colors import family_color

__all__ = ["stage_cost_axes", "family_color"]


def _pyplot() -> Any:
    mpl = require("matplotlib", "plot")
    if mpl.get_backend().lower() not in ("agg", "pdf", "svg") and not _has_display():
        mpl.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _has_display() -> bool:
    import os

    return bool(os.environ.get("DISPLAY"))


def stage_cost_axes(designs: Sequence[Any], ax: Any = None, *, log: bool = False, title: str | None = None) -> Any:
    """Plot the stage costs of several finite-horizon designs on one axes."""
    plt = _pyplot()
    if ax is None:
        _, ax = plt.subplots(figsize=(6, 4))
    for d in designs:
        if d.stage_costs is None:
            ax.axhline(d.average_cost, label=f"{d.estimator} (average)", linestyle="--")
        else:
            ax.plot(range(1, len(d.stage_costs) + 1), d.stage_costs, label=d.estimator)
    ax.set_xlabel("t")
    ax.set_ylabel("E[c(x(t), z(t))]")
    if log:
        ax.set_yscale("log")
    if title:
        ax.set_title(title)
    ax.legend()
    return ax
