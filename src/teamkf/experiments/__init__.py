"""Paper reproductions, one module per figure or table, registered by name.

Every module in this package that calls :func:`register` is discovered
automatically (no central list to edit). An experiment computes everything
from the model parameters; published numbers may appear only as a labelled
comparison column.

>>> from teamkf.experiments import names
>>> "fig1" in names()
True
"""

from __future__ import annotations

import csv
import importlib
import json
import pkgutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

__all__ = ["Experiment", "ExperimentResult", "register", "get", "names", "run"]


@dataclass(frozen=True, eq=False)
class ExperimentResult:
    """What an experiment produced.

    Attributes
    ----------
    name, title : str
    rows : list of dicts      the printed table (also written as ``<name>.csv``)
    columns : list of str     column order of the table
    notes : str               what to know when reading it (model choices, gaps to the paper)
    figures : list of paths   PNG files written (empty without an output folder or matplotlib)
    data : dict               extra arrays for plots and tests
    """

    name: str
    title: str
    rows: list[dict[str, Any]]
    columns: list[str]
    notes: str = ""
    figures: list[str] = field(default_factory=list)
    data: dict[str, Any] = field(default_factory=dict)

    def format_table(self) -> str:
        from .._repr import format_value

        def fmt(v: Any) -> str:
            return format_value(v) if isinstance(v, float) else ("" if v is None else str(v))

        cells = [[fmt(r.get(c)) for c in self.columns] for r in self.rows]
        widths = [max([len(c)] + [len(row[j]) for row in cells]) for j, c in enumerate(self.columns)]
        lines = ["  ".join(c.ljust(w) for c, w in zip(self.columns, widths)), "  ".join("-" * w for w in widths)]
        lines += ["  ".join(v.rjust(w) for v, w in zip(row, widths)) for row in cells]
        return "\n".join(lines)

    @property
    def published_columns(self) -> list[str]:
        """Columns holding published values (their name mentions the paper), shown only for comparison."""
        return [c for c in self.columns if _is_published(c)]

    def _repr_html_(self) -> str:
        from .._repr import html_table

        return html_table(self.columns, self.rows, caption=f"{self.name}: {self.title}", published=_is_published)

    def plot(self, ax: Any = None) -> Any:
        """Show the experiment's figures (the PNG files it wrote) on matplotlib axes; returns the axes.

        The figures exist only when the experiment ran with an output folder
        (``run(name, out_dir)``) and matplotlib was installed.
        """
        from ..exceptions import ArgumentError
        from ..plotting import _pyplot

        if not self.figures:
            raise ArgumentError(
                f"figures: experiment {self.name!r} wrote none; run it with an output folder and matplotlib installed, "
                f"e.g. teamkf.experiments.run({self.name!r}, 'results/')"
            )
        plt = _pyplot()
        import matplotlib.image as mpimg

        if ax is None:
            _, axes = plt.subplots(1, len(self.figures), figsize=(6 * len(self.figures), 4.5), squeeze=False)
            ax = list(axes[0])
        axs = list(ax) if isinstance(ax, (list, tuple, np.ndarray)) else [ax]
        if len(axs) != len(self.figures):
            raise ArgumentError(f"ax: expected {len(self.figures)} axes (one per figure), found {len(axs)}; pass ax=None for a new figure")
        for a, path in zip(axs, self.figures):
            a.imshow(mpimg.imread(path))
            a.set_axis_off()
        return axs if len(axs) > 1 else axs[0]

    def to_json(self) -> dict[str, Any]:
        return {"name": self.name, "title": self.title, "columns": self.columns, "rows": self.rows, "notes": self.notes, "figures": self.figures}

    def write_csv(self, out_dir: Path) -> Path:
        from ..study.outputs import write_atomic

        out_dir.mkdir(exist_ok=True)  # the folder itself, never missing parents (checked by the caller)
        path = out_dir / f"{self.name}.csv"

        def write(fh: Any) -> None:
            w = csv.DictWriter(fh, fieldnames=self.columns, extrasaction="ignore")
            w.writeheader()
            for r in self.rows:
                w.writerow(r)

        write_atomic(path, write, text=True)
        return path


def _is_published(column: str) -> bool:
    c = column.lower()
    return "paper" in c or "published" in c


@dataclass(frozen=True)
class Experiment:
    """A registered reproduction.

    ``uses_scheduler`` is True when its module maps its grid with
    :func:`teamkf.control.map_points` (so ``--scheduler`` sends the points to
    Dask); the others run in-process and refuse ``--scheduler``.
    """

    name: str
    title: str
    func: Callable[..., ExperimentResult]
    uses_scheduler: bool = False


_REGISTRY: dict[str, Experiment] = {}
_LOADED = False


def register(name: str, title: str) -> Callable[[Callable[..., ExperimentResult]], Callable[..., ExperimentResult]]:
    """Decorator: ``@register("fig1", "...")`` on ``run(out_dir: Path | None, quick: bool) -> ExperimentResult``."""

    def deco(func: Callable[..., ExperimentResult]) -> Callable[..., ExperimentResult]:
        _REGISTRY[name] = Experiment(name, title, func, uses_scheduler="map_points" in getattr(func, "__globals__", {}))
        return func

    return deco


def _load() -> None:
    global _LOADED
    if not _LOADED:
        for m in pkgutil.iter_modules(__path__):
            if not m.name.startswith("_"):
                importlib.import_module(f"{__name__}.{m.name}")
        _LOADED = True


def names() -> list[str]:
    """The names of the registered experiments (``teamkf reproduce --list``)."""
    _load()
    return sorted(_REGISTRY)


def get(name: str) -> Experiment:
    """The experiment registered as ``name``; a ScenarioError with the available names otherwise."""
    from ..exceptions import ScenarioError

    _load()
    if name not in _REGISTRY:
        raise ScenarioError(f"reproduce: unknown experiment {name!r}; available: {', '.join(sorted(_REGISTRY))} (teamkf reproduce --list)")
    return _REGISTRY[name]


#: lower bounds of a reproduction's computing time in seconds, full size (about a third of the time measured on the
#: project's 2-core machine: docs/baselines.md, docs/bulk.md); every other one, and every ``quick`` one, at least :data:`MIN_SECONDS`
FULL_SECONDS = {"leaderboard": 30.0, "leaderboard-drops": 100.0, "bulk-lq-cost": 120.0, "bulk-stationarity": 20.0}
#: the least any reproduction computes, in seconds (each designs at least one estimator of a small team)
MIN_SECONDS = 0.01


def _check_work(name: str, quick: bool) -> None:
    """Refuse, before it starts, a reproduction whose estimated time exceeds the work limit (``--max-hours``, ``TEAMKF_MAX_HOURS``)."""
    from .. import _budget

    secs = MIN_SECONDS if quick else FULL_SECONDS.get(name, MIN_SECONDS)
    what = f"the reproduction {name!r}" + (" (--quick)" if quick else "")
    fix = "run the smaller version with --quick" if not quick else "it is already the smallest version"
    _budget.check_work(0.0, what, argument=name, fix=fix, loops=secs * _budget.LOOPS)


def run(name: str, out_dir: str | Path | None = None, *, quick: bool = False, scheduler: Any = None) -> ExperimentResult:
    """Run one experiment; with ``out_dir`` write its CSV (and PNG plots when matplotlib is installed).

    ``scheduler``: where the grid points of an experiment with independent points run (None, the default:
    forked processes, one per core or ``TEAMKF_WORKERS``, :func:`~teamkf.simulation.parallel.process_map`;
    ``"serial"``: this process; ``"local"``, a Dask scheduler address or a ``Client``); the numbers do not depend on it. An
    experiment without such a grid refuses any other scheduler (an ArgumentError naming ``scheduler``).
    """
    from ..exceptions import ArgumentError
    from ..simulation.parallel import _open_client, use_scheduler

    exp = get(name)
    _check_work(name, quick)
    out = Path(out_dir) if out_dir is not None else None
    owned: list[Any] = []
    # by default the independent grid points run in forked processes, one per core (TEAMKF_WORKERS); the numbers
    # do not depend on it (each point is seeded on its own); scheduler="serial" keeps them in this process
    sched: Any = "processes" if scheduler is None else "serial"
    if scheduler not in (None, "serial"):
        if not exp.uses_scheduler:
            users = ", ".join(n for n in names() if get(n).uses_scheduler)
            raise ArgumentError(
                f"scheduler: the reproduction {name!r} runs in-process (it has no grid of independent points to distribute); "
                f"drop the scheduler (reproductions that use one: {users})",
                argument="scheduler",
            )
        sched, owned = _open_client(scheduler, None)
    try:
        with use_scheduler(sched):
            res = exp.func(out, quick)
    finally:
        for obj in owned:
            obj.close()
    if out is not None:
        res.write_csv(out)
        from ..study.outputs import write_atomic

        write_atomic(out / f"{name}.json", lambda fh: json.dump(res.to_json(), fh, indent=1, default=float), text=True)
    return res


def plotting_available() -> bool:
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        return False
    return True


def save_figure(fig: Any, out_dir: Path | None, name: str, figures: Sequence[str] | list[str]) -> None:
    """Save a matplotlib figure as ``out_dir/name.png`` and record the path."""
    if out_dir is None:
        return
    from ..study.outputs import write_atomic

    out_dir.mkdir(exist_ok=True)  # the folder itself, never missing parents (checked by the caller)
    from ..plotting import legends_off_the_data

    legends_off_the_data(fig)  # no legend over a panel's data, whichever experiment drew it
    path = out_dir / f"{name}.png"
    write_atomic(path, lambda fh: fig.savefig(fh, dpi=120, bbox_inches="tight", format="png"))
    import matplotlib.pyplot as plt

    plt.close(fig)
    if isinstance(figures, list):
        figures.append(str(path))
