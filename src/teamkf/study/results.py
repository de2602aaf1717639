"""Result objects of sweeps and cost curves: named fields, ``.to_pandas()``, ``.plot()``.

:class:`SweepResult` holds the rows of a parameter sweep (one per grid point
and estimator, see :mod:`teamkf.study.sweep`); :class:`CostCurves` holds
the stage costs E[c(x(t), z(t))] of several estimators over time, from their
designs (analytic) or from a Monte Carlo run.

pandas and matplotlib are imported only when ``.to_pandas()`` / ``.plot()``
are called (``pip install 'teamkf[dask]'`` / ``'teamkf[plot]'``); reading a
results folder needs pyarrow (in the ``dask`` extra). ``.plot()`` returns the
matplotlib axes and never calls ``plt.show()``.

Examples
--------
>>> from teamkf.study.results import SweepResult
>>> rows = [
...     {"cost.lambda": 1.0, "point_id": "a", "point_index": 0, "estimator": "mtmse", "total_cost": 10.0},
...     {"cost.lambda": 1.0, "point_id": "a", "point_index": 0, "estimator": "mmse", "total_cost": 12.0},
...     {"cost.lambda": 10.0, "point_id": "b", "point_index": 1, "estimator": "mtmse", "total_cost": 20.0},
...     {"cost.lambda": 10.0, "point_id": "b", "point_index": 1, "estimator": "mmse", "total_cost": 30.0},
... ]
>>> res = SweepResult(rows, grid_keys=("cost.lambda",))
>>> res.n_points, res.estimators
(2, ('mtmse', 'mmse'))
>>> [round(r["rel_to_mtmse_pct"], 1) for r in res.relative_to("mtmse") if r["estimator"] == "mmse"]
[20.0, 50.0]
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from .. import _validation as V
from .._validation import FloatArray
from ..exceptions import TeamkfError

__all__ = ["SweepResult", "CostCurves", "SweepError", "load_results", "MANIFEST_NAME"]

#: name of the file, inside a results folder, that describes the sweep that wrote it
MANIFEST_NAME = "_sweep.json"

_COST_KEYS = ("total_cost", "average_cost")


class SweepError(TeamkfError, ValueError):
    """A sweep cannot be run as asked (a results folder in the way, a failed point, a bad plot request)."""


# ---------------------------------------------------------------------------
# sweep results
# ---------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class SweepResult:
    """The rows of a parameter sweep: one per grid point and estimator.

    Attributes
    ----------
    rows : tuple of dict
        In grid order (``point_index``), then in the order of the estimators.
        Keys (the columns of the results folder): one per grid key, then
        ``point_id``, ``point_index``, ``estimator``, ``method``,
        ``total_cost`` (finite horizon) or ``average_cost`` (steady state),
        ``ci95_low``, ``ci95_high`` (None for analytic values), with Monte
        Carlo runs also ``mc_cost``, ``mc_ci95_low``, ``mc_ci95_high`` for the
        analytic estimators, then ``runs``, ``seed`` (the point's own seed),
        ``sweep_seed`` and ``teamkf_version``.
    grid_keys : tuple of str
        The swept dotted keys, in the order of the sweep file.
    path : Path or None
        The results folder the rows were read from.
    n_computed, n_resumed : int
        For :func:`~teamkf.study.sweep.run_sweep`: points computed by that
        call, and points found already written (``resume``).
    info : dict
        The sweep's description as written beside the results (``_sweep.json``).
    """

    rows: tuple[dict[str, Any], ...]
    grid_keys: tuple[str, ...]
    path: Path | None = None
    n_computed: int = 0
    n_resumed: int = 0
    info: dict[str, Any] = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        rows = tuple(dict(r) for r in self.rows)
        if rows and all("point_index" in r for r in rows):
            names = _unique([*self.info.get("estimators", ()), *(r.get("estimator") for r in rows)])
            order = {name: k for k, name in enumerate(names)}
            rows = tuple(sorted(rows, key=lambda r: (r["point_index"], order.get(r.get("estimator"), 0))))
        object.__setattr__(self, "rows", rows)
        object.__setattr__(self, "grid_keys", tuple(self.grid_keys))
        if self.path is not None:
            object.__setattr__(self, "path", Path(self.path))

    # -- reading --------------------------------------------------------------
    @classmethod
    def load(cls, path: str | Path) -> "SweepResult":
        """Read a results folder written by :func:`~teamkf.study.sweep.run_sweep` (or one Parquet file)."""
        return load_results(path)

    # -- views ----------------------------------------------------------------
    def __len__(self) -> int:
        return len(self.rows)

    @property
    def cost_key(self) -> str:
        """``"total_cost"`` (finite horizon) or ``"average_cost"`` (steady state)."""
        for k in _COST_KEYS:
            if any(r.get(k) is not None for r in self.rows):
                return k
        return str(self.info.get("cost_key", "total_cost"))

    @property
    def estimators(self) -> tuple[str, ...]:
        """Estimator names, in the order of the sweep."""
        return tuple(_unique(r["estimator"] for r in self.rows))

    @property
    def n_points(self) -> int:
        return len({r["point_id"] for r in self.rows})

    def grid_values(self, key: str) -> tuple[Any, ...]:
        """The distinct values of one grid key, in grid order."""
        self._check_key(key, "key")
        return tuple(_unique(r[key] for r in self.rows))

    def relative_to(self, baseline: str, y: str | None = None) -> tuple[dict[str, Any], ...]:
        """The rows with ``rel_to_<baseline>_pct`` = 100 (J − J_baseline) / J_baseline added.

        ``J`` is column ``y`` (default: the cost column) and ``J_baseline`` is
        the baseline estimator's value at the same grid point (negative: lower
        cost than the baseline).
        """
        y = self.cost_key if y is None else y
        if baseline not in self.estimators:
            raise SweepError(f"baseline: expected one of the estimators of the sweep ({', '.join(self.estimators)}), found {baseline!r}")
        ref = {r["point_id"]: r.get(y) for r in self.rows if r["estimator"] == baseline}
        col = f"rel_to_{baseline}_pct"
        out = []
        for r in self.rows:
            j, j0 = r.get(y), ref.get(r["point_id"])
            rel = None if j is None or j0 is None or j0 == 0 else 100.0 * (float(j) - float(j0)) / float(j0)
            out.append({**r, col: rel})
        return tuple(out)

    def to_pandas(self, baseline: str | None = None) -> Any:
        """A pandas DataFrame, one row per point × estimator (with ``rel_to_<baseline>_pct`` when asked)."""
        pd = V.require("pandas", "dask")
        rows = self.relative_to(baseline) if baseline is not None else self.rows
        columns = _columns(rows, self.grid_keys)
        df = pd.DataFrame.from_records(list(rows), columns=columns)
        for c in (*_FLOAT_COLUMNS, f"rel_to_{baseline}_pct"):
            if c in df.columns:
                df[c] = df[c].astype("float64")  # None (analytic values) -> NaN
        return df

    def __repr__(self) -> str:
        """One screen at any size: the grid, the estimators and the first rows' costs (``.to_pandas()`` for all)."""
        from .._repr import MAX_REPR_LINES, format_value

        grid = ", ".join(
            f"{k} ∈ {{{', '.join(map(str, self.grid_values(k)[:6]))}{', ...' if len(self.grid_values(k)) > 6 else ''}}}" for k in self.grid_keys
        )
        head = f"SweepResult({self.n_points} points × {len(self.estimators)} estimators ({', '.join(self.estimators)}); {grid or 'no grid'}"
        lines = [head + (f"; from {self.path}" if self.path is not None else "") + ")"]
        y = self.cost_key
        shown = self.rows[: MAX_REPR_LINES - 2]
        for r in shown:
            at = ", ".join(f"{k}={r.get(k)}" for k in self.grid_keys)
            ci = f" [{format_value(r['ci95_low'])}, {format_value(r['ci95_high'])}]" if r.get("ci95_low") is not None else ""
            lines.append(f"  {at:<24} {r['estimator']:<14} {y} = {format_value(r.get(y))}{ci}")
        if len(self.rows) > len(shown):
            lines.append(f"  ... {len(self.rows) - len(shown)} more rows (.to_pandas() has them all)")
        return "\n".join(lines)

    def _repr_html_(self) -> str:
        from .._repr import html_table

        cols = [*self.grid_keys, "estimator", "method", self.cost_key, "ci95_low", "ci95_high"]
        if any("mc_cost" in r for r in self.rows):
            cols += ["mc_cost", "mc_ci95_low", "mc_ci95_high"]
        where = f" from {self.path}" if self.path is not None else ""
        caption = f"teamkf sweep: {self.n_points} points × {len(self.estimators)} estimators{where}"
        return html_table(cols, self.rows, caption=caption)

    # -- plots ----------------------------------------------------------------
    def plot(
        self,
        x: str | None = None,
        y: str | None = None,
        baseline: str | None = None,
        ax: Any = None,
        *,
        logx: bool | str = "auto",
        title: str | None = None,
    ) -> Any:
        """Cost against a swept parameter, one line per estimator (and per value of the other grid keys).

        Parameters
        ----------
        x : grid key on the horizontal axis (default: the first one)
        y : column on the vertical axis (default: the cost column; ``"mc_cost"`` for the Monte Carlo means)
        baseline : estimator name; when given, plot the relative difference
            100 (J − J_baseline) / J_baseline in % of every other estimator
        ax : matplotlib axes to draw on (default: a new figure)
        logx : True, False or "auto" (log scale when x spans two decades or more)
        title : the axes title (default: the link model when every point shares one whose links drop)

        Returns
        -------
        The matplotlib axes.

        Notes
        -----
        Each estimator keeps its family's colour (:func:`~teamkf.plotting.family_color`), the same in
        every plot; the other grid keys' values differ by marker and line style. Monte Carlo values
        get error bars (their 95 % interval); an axis of integer values gets integer ticks; the legend
        sits to the right of the axes, off the data. An estimator whose analytic cost is its perfect-link cost at points whose
        links drop (row ``cost_links == "perfect"``) is labelled "(perfect links)".
        """
        from ..plotting import _pyplot, family_style, legend_outside

        x = self.grid_keys[0] if x is None else x
        self._check_key(x, "x")
        y = self.cost_key if y is None else y
        if self.rows and y not in self.rows[0]:
            raise SweepError(f"y: no column {y!r} in the results; columns: {', '.join(self.rows[0])}")
        rows = self.relative_to(baseline, y) if baseline is not None else self.rows
        ycol = f"rel_to_{baseline}_pct" if baseline is not None else y
        plt = _pyplot()
        if ax is None:
            _, ax = plt.subplots(figsize=(7.5, 4), layout="constrained")
        others = [k for k in self.grid_keys if k != x]
        lo_col, hi_col = ("mc_ci95_low", "mc_ci95_high") if y == "mc_cost" else ("ci95_low", "ci95_high")
        groups: dict[tuple[Any, ...], list[dict[str, Any]]] = {}
        for r in rows:
            if baseline is not None and r["estimator"] == baseline:
                continue
            groups.setdefault((r["estimator"], *(r[k] for k in others)), []).append(r)
        xvalues = list(_unique(r[x] for r in self.rows))
        numeric = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in xvalues)
        pos = {v: (float(v) if numeric else float(k)) for k, v in enumerate(xvalues)}
        variants = list(_unique(gkey[1:] for gkey in groups))  # the other keys' values: a marker and a line style each
        markers, styles = ("o", "s", "^", "D", "v", "P"), ("-", "--", ":", "-.")
        for gkey, grows in groups.items():
            pts = sorted(((pos[r[x]], r) for r in grows if r.get(ycol) is not None), key=lambda t: t[0])
            if not pts:
                continue
            xs = [p[0] for p in pts]
            ys = [float(p[1][ycol]) for p in pts]
            label = gkey[0] + (f" ({', '.join(f'{k}={v}' for k, v in zip(others, gkey[1:]))})" if others else "")
            if y != "mc_cost" and any(r.get("cost_links") == "perfect" and r.get("links") not in (None, "perfect") for _, r in pts):
                label += " (perfect links)"  # its analytic cost where the links drop: not the cost over them
            v = variants.index(gkey[1:])
            style = {**family_style(gkey[0]), "marker": markers[v % len(markers)]}
            if others:
                style["linestyle"] = styles[v % len(styles)]
            if baseline is None and all(p[1].get(lo_col) is not None for p in pts):
                lo = [float(p[1][lo_col]) for p in pts]
                hi = [float(p[1][hi_col]) for p in pts]
                yerr = [[max(0.0, a - b) for a, b in zip(ys, lo)], [max(0.0, b - a) for a, b in zip(ys, hi)]]
                ax.errorbar(xs, ys, yerr=yerr, capsize=3, label=label + " (95 % interval)", **style)
            else:
                ax.plot(xs, ys, label=label, **style)
        if baseline is not None:
            ax.axhline(0.0, color="0.5", linewidth=0.8, linestyle="--")
        xvals = list(pos.values())
        if not numeric:  # strings, booleans, JSON values: one tick per value, in grid order
            ax.set_xticks(xvals)
            ax.set_xticklabels([str(v) for v in xvalues])
        elif logx is True or (logx == "auto" and xvals and min(xvals) > 0 and max(xvals) / min(xvals) >= 100):
            ax.set_xscale("log")
            ax.set_xticks(xvals)
            ax.set_xticklabels([f"{v:g}" for v in xvals])
            ax.xaxis.set_minor_locator(plt.NullLocator())
        elif all(float(v).is_integer() for v in xvalues):  # an integer axis (delays, sizes): integer ticks only
            from matplotlib.ticker import MaxNLocator

            if len(xvals) <= 12:
                ax.set_xticks(xvals)
                ax.set_xticklabels([f"{int(v)}" for v in xvals])
            else:
                ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.set_xlabel(x)
        label = {"total_cost": "J_T", "average_cost": "average cost", "mc_cost": "Monte Carlo J_T"}.get(y, y)
        ax.set_ylabel(f"100 ({label} − {label}[{baseline}]) / {label}[{baseline}]  [%]" if baseline is not None else label)
        shared = {r.get("links") for r in self.rows}
        if title is None and len(shared) == 1 and shared != {None} and shared != {"perfect"}:
            title = f"links: {shared.pop()}"  # the link model every point shares (a swept one is on an axis)
        if title:
            ax.set_title(title)
        ax.grid(True, color="0.92")
        legend_outside(ax)
        return ax

    # -- helpers --------------------------------------------------------------
    def _check_key(self, key: str, arg: str) -> None:
        if key not in self.grid_keys:
            raise SweepError(f"{arg}: expected one of the grid keys ({', '.join(self.grid_keys)}), found {key!r}")


def load_results(path: str | Path) -> SweepResult:
    """Read sweep results: a folder of Parquet parts (with ``_sweep.json``) or one Parquet file."""
    pq = V.require("pyarrow.parquet", "dask")
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(2, "no such sweep results folder", str(p))
    info: dict[str, Any] = {}
    manifest = p / MANIFEST_NAME
    if p.is_dir() and manifest.exists():
        try:
            info = json.loads(manifest.read_text(encoding="utf-8"))
        except (ValueError, UnicodeDecodeError):
            raise SweepError(f"{manifest}: unreadable sweep description (not JSON); the folder was not written by teamkf sweep") from None
    parts = sorted(str(c) for c in p.iterdir() if c.name.endswith(".parquet") and not c.name.startswith((".", "_"))) if p.is_dir() else [str(p)]
    try:  # the parts only: another file in the folder would make a dataset reader fail
        rows: list[dict[str, Any]] = pq.read_table(parts).to_pylist() if len(parts) > 1 else (pq.read_table(parts[0]).to_pylist() if parts else [])
    except Exception as exc:  # pyarrow's own error types (ArrowInvalid, ...)
        raise SweepError(f"{p}: not readable as sweep results ({type(exc).__name__}: {' '.join(str(exc).split())[:200]})") from None
    if "grid_keys" in info:
        keys = tuple(info["grid_keys"])
    else:
        fixed = set(_FIXED_COLUMNS)
        keys = tuple(k for k in (rows[0] if rows else {}) if k not in fixed)
    return SweepResult(tuple(rows), keys, path=p, info=info)


_FIXED_COLUMNS = (
    "point_id",
    "point_index",
    "estimator",
    "label",
    "method",
    "total_cost",
    "average_cost",
    "ci95_low",
    "ci95_high",
    "mc_cost",
    "mc_ci95_low",
    "mc_ci95_high",
    "runs",
    "seed",
    "diverged",
    "sweep_seed",
    "teamkf_version",
)


_FLOAT_COLUMNS = ("total_cost", "average_cost", "ci95_low", "ci95_high", "mc_cost", "mc_ci95_low", "mc_ci95_high")


def _columns(rows: Sequence[Mapping[str, Any]], grid_keys: Sequence[str]) -> list[str]:
    seen = list(grid_keys)
    for r in rows:
        for k in r:
            if k not in seen:
                seen.append(k)
    return seen


def _unique(items: Any) -> list[Any]:
    out: list[Any] = []
    seen: set[Any] = set()
    for x in items:
        if x not in seen:
            seen.add(x)
            out.append(x)
    return out


# ---------------------------------------------------------------------------
# cost against time
# ---------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class CostCurves:
    """Stage costs E[c(x(t), z(t))], t = 1..T, of several estimators.

    Attributes
    ----------
    estimators : tuple of str
    stage_costs : tuple of (T,) arrays, one per estimator
    stage_sem : tuple of (T,) arrays or None
        Standard errors of Monte Carlo means (None for analytic curves).
    methods : tuple of str
        ``"analytic"`` or ``"monte-carlo"`` per estimator.
    title : str or None

    Examples
    --------
    >>> import numpy as np
    >>> cc = CostCurves(("a", "b"), (np.ones(3), 2 * np.ones(3)))
    >>> cc.totals()
    {'a': 3.0, 'b': 6.0}
    """

    estimators: tuple[str, ...]
    stage_costs: tuple[FloatArray, ...]
    stage_sem: tuple[FloatArray | None, ...] | None = None
    methods: tuple[str, ...] | None = None
    title: str | None = None

    def __post_init__(self) -> None:
        names = tuple(str(e) for e in self.estimators)
        costs = tuple(V.frozen(np.asarray(c, dtype=float).reshape(-1)) for c in self.stage_costs)
        if len(costs) != len(names):
            raise SweepError(f"stage_costs: expected one curve per estimator ({len(names)}), found {len(costs)}")
        sems = self.stage_sem if self.stage_sem is not None else (None,) * len(names)
        if len(sems) != len(names):
            raise SweepError(f"stage_sem: expected one entry per estimator ({len(names)}), found {len(sems)}")
        sems = tuple(None if s is None else V.frozen(np.asarray(s, dtype=float).reshape(-1)) for s in sems)
        for n, c, s in zip(names, costs, sems):
            if s is not None and s.shape != c.shape:
                raise SweepError(f"stage_sem[{n!r}]: expected {c.shape[0]} values (one per step), found {s.shape[0]}")
        methods = tuple(self.methods) if self.methods is not None else tuple("analytic" if s is None else "monte-carlo" for s in sems)
        object.__setattr__(self, "estimators", names)
        object.__setattr__(self, "stage_costs", costs)
        object.__setattr__(self, "stage_sem", sems)
        object.__setattr__(self, "methods", methods)

    @classmethod
    def from_designs(cls, designs: Mapping[str, Any] | Sequence[Any], title: str | None = None) -> "CostCurves":
        """Analytic stage costs of finite-horizon designs (a mapping name -> design, or a list of designs)."""
        items = list(designs.items()) if isinstance(designs, Mapping) else [(d.estimator, d) for d in designs]
        for name, d in items:
            if getattr(d, "stage_costs", None) is None:
                raise SweepError(
                    f"designs[{name!r}]: expected a finite-horizon design (with stage costs), found a steady-state one; design with a horizon T"
                )
        return cls(tuple(n for n, _ in items), tuple(d.stage_costs for _, d in items), title=title)

    @classmethod
    def from_monte_carlo(cls, results: Mapping[str, Any], title: str | None = None) -> "CostCurves":
        """Monte Carlo stage costs (``monte_carlo(...)``'s mapping name -> MonteCarloResult), with standard errors."""
        names = tuple(results)
        return cls(
            names, tuple(results[n].stage_mean for n in names), tuple(results[n].stage_sem for n in names), ("monte-carlo",) * len(names), title=title
        )

    def totals(self) -> dict[str, float]:
        """Sum of the stage costs per estimator (J_T)."""
        return {n: float(np.sum(c)) for n, c in zip(self.estimators, self.stage_costs)}

    def _repr_html_(self) -> str:
        from .._repr import html_table

        assert self.methods is not None  # set in __post_init__
        rows = [
            {"estimator": n, "method": m, "steps": c.shape[0], "J_T (sum)": float(np.sum(c)), "last stage cost": float(c[-1]) if c.size else None}
            for n, m, c in zip(self.estimators, self.methods, self.stage_costs)
        ]
        return html_table(["estimator", "method", "steps", "J_T (sum)", "last stage cost"], rows, caption=self.title or "teamkf cost curves")

    def to_pandas(self) -> Any:
        """Long format: ``estimator``, ``method``, ``t`` (from 1), ``stage_cost``, ``sem`` (None for analytic)."""
        pd = V.require("pandas", "dask")
        recs = []
        assert self.stage_sem is not None and self.methods is not None  # set in __post_init__
        for n, m, c, s in zip(self.estimators, self.methods, self.stage_costs, self.stage_sem):
            for k, v in enumerate(c):
                recs.append({"estimator": n, "method": m, "t": k + 1, "stage_cost": float(v), "sem": None if s is None else float(s[k])})
        return pd.DataFrame.from_records(recs, columns=["estimator", "method", "t", "stage_cost", "sem"])

    def plot(self, ax: Any = None, *, log: bool = False, band: bool = True, cumulative: bool = False) -> Any:
        """Cost against time, one line per estimator (with a 95 % band for Monte Carlo curves); returns the axes.

        Each estimator keeps its family's colour (:func:`~teamkf.plotting.family_color`); the legend
        sits to the right of the axes.
        """
        from ..plotting import _pyplot, family_style, legend_outside

        plt = _pyplot()
        if ax is None:
            _, ax = plt.subplots(figsize=(7.5, 4), layout="constrained")
        assert self.stage_sem is not None and self.methods is not None
        for n, m, c, s in zip(self.estimators, self.methods, self.stage_costs, self.stage_sem):
            t = np.arange(1, c.shape[0] + 1)
            y = np.cumsum(c) if cumulative else c
            (line,) = ax.plot(t, y, label=n if m == "analytic" else f"{n} ({m})", **family_style(n))
            if band and s is not None and not cumulative:
                ax.fill_between(t, c - 1.959963984540054 * s, c + 1.959963984540054 * s, color=line.get_color(), alpha=0.2, linewidth=0)
        ax.set_xlabel("t")
        ax.set_ylabel("sum over s <= t of E[c(x(s), z(s))]" if cumulative else "E[c(x(t), z(t))]")
        if log:
            ax.set_yscale("log")
        if self.title:
            ax.set_title(self.title)
        legend_outside(ax)
        return ax
