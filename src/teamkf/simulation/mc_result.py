"""What :func:`~teamkf.monte_carlo` returns: the results of every design, as one object.

:class:`MonteCarloResults` is a read-only mapping name -> :class:`~teamkf.MonteCarloResult` (so
``mc["kcf"].total_mean`` works as with a dict) with a table view (:meth:`~MonteCarloResults.to_frame`,
:meth:`~MonteCarloResults.to_rows`), a short ``repr`` (one line per design, one screen at any size),
an HTML table in notebooks and a plot of the per-step means with their 95 % bands.

Every number is a sample mean over ``n_runs`` independent runs with its standard error s / √n; the
95 % interval is mean ± 1.96 standard errors (normal approximation, exact enough from a few tens of
runs on).
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from typing import Any

import numpy as np

from .._repr import MAX_REPR_LINES, format_value, html_table
from .._validation import require
from ..exceptions import ArgumentError

__all__ = ["MonteCarloResults", "COLUMNS"]

#: the columns of :meth:`MonteCarloResults.to_rows` and :meth:`MonteCarloResults.to_frame`
COLUMNS = ("estimator", "runs", "steps", "total_mean", "total_sem", "ci95_low", "ci95_high", "diverged", "path")


class MonteCarloResults(Mapping[str, Any]):
    """The Monte Carlo results of several designs on the same sampled paths, by name.

    A read-only mapping name -> :class:`~teamkf.MonteCarloResult`, in the order the designs were given.

    Parameters
    ----------
    results : mapping of str to MonteCarloResult
        One result per design, as :func:`~teamkf.monte_carlo` computes them.

    See Also
    --------
    teamkf.monte_carlo : computes them.
    teamkf.MonteCarloResult : one design's result (means, standard errors, ``ci95``).

    Examples
    --------
    >>> from teamkf import LinearGaussianSystem, TeamCost, CommGraph, design_mtmse, design_mmse, monte_carlo
    >>> from teamkf.simulation.mc_result import MonteCarloResults
    >>> system, cost, graph = LinearGaussianSystem.platoon(4), TeamCost.platoon(4, 100.0), CommGraph.line(4, delay=1)
    >>> designs = {"mtmse": design_mtmse(system, cost, graph, horizon=20), "mmse": design_mmse(system, cost, graph, horizon=20)}
    >>> mc = MonteCarloResults(monte_carlo(designs, 20, 200, rng=1))
    >>> list(mc), mc["mtmse"].n_runs
    (['mtmse', 'mmse'], 200)
    >>> print(repr(mc))  # doctest: +ELLIPSIS
    MonteCarloResults(2 designs, 200 runs, 20 steps; J_T = mean [95 % interval])
      mtmse  ... [..., ...]
      mmse   ... [..., ...]
    >>> [row["estimator"] for row in mc.to_rows()]
    ['mtmse', 'mmse']
    """

    def __init__(self, results: Mapping[str, Any]) -> None:
        if not isinstance(results, Mapping):
            raise ArgumentError(
                f"results: expected a mapping name -> MonteCarloResult (what monte_carlo computes), found {type(results).__name__}",
                argument="results",
            )
        for name, r in results.items():
            if not (hasattr(r, "total_mean") and hasattr(r, "stage_mean") and hasattr(r, "ci95")):
                raise ArgumentError(f"results[{name!r}]: expected a MonteCarloResult, found {type(r).__name__}", argument=f"results[{name!r}]")
        self._results: dict[str, Any] = dict(results)

    # --- the mapping ------------------------------------------------------------------------------
    def __getitem__(self, name: str) -> Any:
        try:
            return self._results[name]
        except KeyError:
            raise KeyError(f"{name!r}: no design of that name; the designs are {', '.join(map(repr, self._results)) or 'none'}") from None

    def __iter__(self) -> Iterator[str]:
        return iter(self._results)

    def __len__(self) -> int:
        return len(self._results)

    # --- tables -----------------------------------------------------------------------------------
    def to_rows(self) -> list[dict[str, Any]]:
        """One plain-data row per design (the columns of :data:`COLUMNS`).

        Returns
        -------
        list of dict
            ``estimator``, ``runs``, ``steps``, ``total_mean``, ``total_sem``, ``ci95_low``,
            ``ci95_high``, ``diverged`` and ``path`` of each design, in order.

        Examples
        --------
        >>> from teamkf import LinearGaussianSystem, TeamCost, design_centralized, monte_carlo
        >>> from teamkf.simulation.mc_result import MonteCarloResults
        >>> kf = design_centralized(LinearGaussianSystem.platoon(3), TeamCost.platoon(3, 1.0), horizon=5)
        >>> row = MonteCarloResults(monte_carlo({"kf": kf}, 5, 100, rng=1)).to_rows()[0]
        >>> row["runs"], row["steps"], row["ci95_low"] < row["total_mean"] < row["ci95_high"]
        (100, 5, True)
        """
        rows = []
        for name, r in self._results.items():
            lo, hi = r.ci95
            rows.append(
                {
                    "estimator": name,
                    "runs": int(r.n_runs),
                    "steps": len(r.stage_mean),
                    "total_mean": float(r.total_mean),
                    "total_sem": float(r.total_sem),
                    "ci95_low": float(lo),
                    "ci95_high": float(hi),
                    "diverged": not bool(np.isfinite(r.total_mean)),
                    "path": r.path,
                }
            )
        return rows

    def to_frame(self) -> Any:
        """A pandas DataFrame, one row per design, indexed by name (the columns of :meth:`to_rows`).

        Returns
        -------
        pandas.DataFrame
            Needs pandas (the ``[dask]`` extra).

        Examples
        --------
        >>> from teamkf import LinearGaussianSystem, TeamCost, design_centralized, monte_carlo
        >>> from teamkf.simulation.mc_result import MonteCarloResults
        >>> kf = design_centralized(LinearGaussianSystem.platoon(3), TeamCost.platoon(3, 1.0), horizon=5)
        >>> df = MonteCarloResults(monte_carlo({"kf": kf}, 5, 100, rng=1)).to_frame()
        >>> list(df.index), list(df.columns[:3])
        (['kf'], ['runs', 'steps', 'total_mean'])
        """
        pd = require("pandas", "dask")
        return pd.DataFrame.from_records(self.to_rows(), columns=list(COLUMNS)).set_index("estimator")

    # --- display ----------------------------------------------------------------------------------
    def _describe(self) -> str:
        runs = sorted({int(r.n_runs) for r in self._results.values()})
        steps = sorted({len(r.stage_mean) for r in self._results.values()})
        n = len(self._results)
        return f"{n} design{'s' if n != 1 else ''}, {'/'.join(map(str, runs))} runs, {'/'.join(map(str, steps))} steps"

    def __repr__(self) -> str:
        lines = [f"MonteCarloResults({self._describe()}; J_T = mean [95 % interval])"]
        rows = self.to_rows()
        width = max((len(r["estimator"]) for r in rows), default=0)
        shown = rows if len(rows) <= MAX_REPR_LINES - 1 else rows[: MAX_REPR_LINES - 2]
        for r in shown:
            value = (
                "diverged" if r["diverged"] else f"{format_value(r['total_mean'])} [{format_value(r['ci95_low'])}, {format_value(r['ci95_high'])}]"
            )
            lines.append(f"  {r['estimator']:<{width}}  {value}")
        if len(shown) < len(rows):
            lines.append(f"  ... {len(rows) - len(shown)} more (.to_frame() has them all)")
        return "\n".join(lines)

    def _repr_html_(self) -> str:
        rows = [
            {
                "estimator": r["estimator"],
                "J_T (mean)": "diverged" if r["diverged"] else r["total_mean"],
                "95 % low": None if r["diverged"] else r["ci95_low"],
                "95 % high": None if r["diverged"] else r["ci95_high"],
                "runs": r["runs"],
                "steps": r["steps"],
            }
            for r in self.to_rows()
        ]
        return html_table(
            ["estimator", "J_T (mean)", "95 % low", "95 % high", "runs", "steps"], rows, caption=f"teamkf Monte Carlo: {self._describe()}"
        )

    def plot(self, ax: Any = None, *, log: bool = False) -> Any:
        """The mean stage cost of every design against the step, with its 95 % band.

        Parameters
        ----------
        ax : matplotlib Axes, optional
            Where to draw; a new figure when None.
        log : bool
            A logarithmic cost axis.

        Returns
        -------
        matplotlib.axes.Axes
            The axes drawn on.

        Examples
        --------
        >>> from teamkf import LinearGaussianSystem, TeamCost, design_centralized, monte_carlo
        >>> from teamkf.simulation.mc_result import MonteCarloResults
        >>> kf = design_centralized(LinearGaussianSystem.platoon(3), TeamCost.platoon(3, 1.0), horizon=5)
        >>> ax = MonteCarloResults(monte_carlo({"kf": kf}, 5, 100, rng=1)).plot()
        >>> len(ax.lines), len(ax.collections)
        (1, 1)
        """
        from ..plotting import mc_band_axes

        return mc_band_axes(self._results, ax=ax, log=log)
