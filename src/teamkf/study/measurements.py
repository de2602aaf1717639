"""Recorded measurements: read, validate, filter with every estimator of a scenario, write the estimates.

File formats (the contract of ``teamkf filter``)
------------------------------------------------
Measurements, long form (CSV, or Parquet by the ``.parquet`` extension)::

    step,agent,y0,y1,...
    0,0,0.31,-1.2
    0,1,0.05,
    ...

one row per agent and step; columns ``y0 .. y{m-1}`` with m = max_i d_y^i (an
agent with d_y^i < m leaves the columns from ``y{d_y^i}`` on empty). An empty
cell (NaN) or an absent (step, agent) row is a **missing** measurement: the
sensor produced nothing. NPZ: one array per agent, keys ``agent0``,
``agent1``, ... (or ``arr_0``, ... from ``np.savez(*ys)``), shape
(steps, d_y^i), NaN for missing.

Known inputs and time-varying offsets (optional columns, see :class:`KnownInputs`):
``u0 .. u{d_u-1}`` the inputs u(t) and ``b0 .. b{d_x-1}`` the process offset b(t), one value
per step (every row of a step carries the same values; every step needs a row, its y cells may
be empty); ``d0 .. d{m-1}`` agent i's measurement offset d_i(t) on its row (required where a y
value is present; an agent with d_y^i < m leaves the columns from ``d{d_y^i}`` empty). NPZ:
keys ``u`` (steps, d_u), ``b`` (steps, d_x) and ``d_agent0``, ``d_agent1``, ... (steps, d_y^i).

Truth (optional, for the realized team cost): ``step, x0, x1, ...`` one row
per step (CSV/Parquet), or NPZ with the key ``x`` of shape (steps, d_x).

Estimates (output): ``step, agent, estimator, z0, z1, ...`` (CSV or Parquet by
the extension), one row per step, agent and estimator.

Everything is validated against the scenario: unknown agents, wrong d_y
(columns), steps beyond the horizon, duplicated (step, agent) rows, strings in
numeric columns, inf. Errors are :class:`MeasurementFileError` naming the
file, the row (1-based, data rows; CSV line = row + 1) and the column.

Missing measurements, exactly
-----------------------------
For a recorded log the whole missingness pattern is known in advance, so the
exact team-optimal estimates *for that pattern* are computable: the
estimators are designed on the time-varying model whose measurement of agent
i at step t keeps only the rows present at t. teamkf realizes that reduced
model with fixed dimensions (:func:`masked_system`): a missing row r of
y_i(t) gets C_i(t)[r] = 0 and a unit-variance noise that is independent of
every other variable (its rows and columns of R_i(t) are those of the
identity), and the value 0 is fed for it. That pseudo-measurement is
independent of x, w, v and every present measurement, so

* the Kalman gain on it is exactly zero (cov(x, y_r) = 0 and the innovation
  covariance is block diagonal), and
* in the team problem, with z = z_present + G u where u collects the
  pseudo-measurements, E[(Lx - z)'S(Lx - z)] = E[(Lx - z_present)'S(...)] +
  E[(Gu)'S(Gu)] (cross terms vanish by independence), minimized only by
  G u = 0, i.e. zero gains on u (S > 0, var u = I > 0; Radner's conditions
  keep a unique solution because Gamma stays positive definite).

So the estimates and costs equal those of the model with the rows removed (a
different thing from the "infinite variance" approximation, which is only a
limit). This is the **offline (re-analysis) optimum**: every agent is
designed as if it knew in advance which measurements of the others will be
missing. Online, agents learn the others' gaps only through the graph; the
online-feasible optimum is in general worse.

Families whose designs declare ``handles_missing`` (the centralized filter,
MTMSE, per-agent MMSE) filter logs with gaps; any other family raises
:class:`~teamkf.exceptions.UnsupportedOperationError` naming the family and
the first missing (agent, step).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import scipy.linalg as sla

from .. import _validation as V
from .._validation import FloatArray
from ..exceptions import TeamkfError, UnsupportedOperationError
from ..models import LinearGaussianSystem
from ..simulation.monte_carlo import runtime_estimates, team_stage_costs

__all__ = [
    "MeasurementFileError",
    "MeasurementLog",
    "FilterResult",
    "read_measurements",
    "write_measurements",
    "read_truth",
    "write_estimates",
    "masked_system",
    "design_for_log",
    "filter_log",
    "online_estimates",
    "realized_costs",
    "FORMATS",
    "KnownInputs",
    "known_inputs",
    "Innovations",
    "innovations",
]

#: file extensions understood (lower case)
FORMATS = (".csv", ".parquet", ".npz")


class MeasurementFileError(TeamkfError, ValueError):
    """A measurement, truth or estimate file is not what the scenario needs (names file, row and column)."""


def _fmt_err(path: Any, where: str, message: str) -> MeasurementFileError:
    loc = f"{path}: {where}: " if where else f"{path}: "
    return MeasurementFileError(loc + message, argument=str(path))


def _suffix(path: Path, flag: str) -> str:
    s = path.suffix.lower()
    if s not in FORMATS:
        raise MeasurementFileError(
            f"{path}: expected a file ending in .csv, .parquet or .npz, found {path.suffix or 'no extension'!r}", argument=flag
        )
    return s


# ---------------------------------------------------------------------------
# the log
# ---------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class MeasurementLog:
    """Validated measurements of one recorded run.

    Attributes
    ----------
    y : list over agents of (n_steps, d_y^i) arrays, NaN where missing
    source : str
        Where they came from (a path, or ``"<arrays>"``).
    u : (n_steps, d_u) known inputs, or None
    b : (n_steps, d_x) process offsets b(t), or None (then the scenario's constant b)
    d : list over agents of (n_steps, d_y^i) measurement offsets d_i(t) (NaN where y is missing), or None
    """

    y: list[FloatArray]
    source: str = "<arrays>"
    u: FloatArray | None = None
    b: FloatArray | None = None
    d: list[FloatArray] | None = None

    @property
    def n_steps(self) -> int:
        return int(self.y[0].shape[0])

    @property
    def n_agents(self) -> int:
        return len(self.y)

    @property
    def present(self) -> list[np.ndarray]:
        """Boolean masks (n_steps, d_y^i): True where a value was recorded."""
        return [~np.isnan(yi) for yi in self.y]

    @property
    def has_gaps(self) -> bool:
        return any(bool(np.isnan(yi).any()) for yi in self.y)

    def first_missing(self) -> tuple[int, int] | None:
        """The first missing (agent, step), by step then agent; None without gaps."""
        best: tuple[int, int] | None = None
        for i, yi in enumerate(self.y):
            rows = np.flatnonzero(np.isnan(yi).any(axis=1))
            if rows.size and (best is None or (int(rows[0]), i) < (best[1], best[0])):
                best = (i, int(rows[0]))
        return best

    def filled(self) -> list[FloatArray]:
        """The measurements with 0 where missing (what the masked model's filters are fed)."""
        return [np.where(np.isnan(yi), 0.0, yi) for yi in self.y]

    @classmethod
    def from_arrays(
        cls,
        y: Sequence[Any],
        system: LinearGaussianSystem,
        horizon: int | None = None,
        source: str = "<arrays>",
        u: Any = None,
        b: Any = None,
        d: Sequence[Any] | None = None,
    ) -> "MeasurementLog":
        """Validate per-agent arrays (n_steps, d_y^i) with NaN for missing values, and the optional known
        inputs u (n_steps, d_u), process offsets b (n_steps, d_x) and measurement offsets d (per agent,
        (n_steps, d_y^i), finite wherever y is present)."""
        n = system.n_agents
        if not isinstance(y, (list, tuple)) or len(y) != n:
            raise MeasurementFileError(
                f"{source}: expected {n} arrays (one per agent), found {len(y) if isinstance(y, (list, tuple)) else type(y).__name__}"
            )
        ys = []
        for i, yi in enumerate(y):
            try:
                a = np.array(yi, dtype=float)
            except (TypeError, ValueError):
                raise _fmt_err(source, f"agent {i}", f"expected numbers, found {np.asarray(yi).dtype}") from None
            if a.ndim != 2 or a.shape[1] != system.dy[i]:
                raise _fmt_err(source, f"agent {i}", f"expected shape (n_steps, {system.dy[i]}) (d_y^{i} = {system.dy[i]}), found {a.shape}")
            bad = np.argwhere(np.isinf(a))
            if bad.size:
                r, c = (int(v) for v in bad[0])
                raise _fmt_err(source, f"agent {i}, step {r}, column y{c}", f"expected a finite number or NaN (missing), found {a[r, c]}")
            ys.append(a)
        T = ys[0].shape[0]
        for i, a in enumerate(ys):
            if a.shape[0] != T:
                raise _fmt_err(source, f"agent {i}", f"expected {T} steps (as agent 0), found {a.shape[0]}")
        if T == 0:
            raise _fmt_err(source, "", "expected at least one step, found none")
        if horizon is not None and T > horizon:
            raise _fmt_err(
                source,
                f"step {horizon}",
                f"beyond the scenario's horizon of {horizon} steps (steps 0..{horizon - 1}); shorten the log or raise horizon",
            )
        for a in ys:
            a.setflags(write=False)
        if u is not None:
            u = np.asarray(u, dtype=float)
            if u.ndim != 2 or u.shape[0] != T or not np.all(np.isfinite(u)):
                raise _fmt_err(source, "u", f"expected finite known inputs of shape ({T}, d_u), found shape {u.shape}")
        if b is not None:
            b = np.asarray(b, dtype=float)
            if b.shape != (T, system.dx) or not np.all(np.isfinite(b)):
                raise _fmt_err(source, "b", f"expected finite process offsets b(t) of shape ({T}, {system.dx}) (steps, d_x), found shape {b.shape}")
        ds = None
        if d is not None:
            if len(d) != n:
                raise _fmt_err(source, "d", f"expected {n} arrays of measurement offsets d_i(t) (one per agent), found {len(d)}")
            ds = []
            for i, di in enumerate(d):
                a = np.array(di, dtype=float)
                if a.shape != ys[i].shape:
                    raise _fmt_err(source, f"d, agent {i}", f"expected shape {ys[i].shape} (as its measurements), found {a.shape}")
                need = ~np.isnan(ys[i]) & ~np.isfinite(a)
                if need.any():
                    r, c = (int(v) for v in np.argwhere(need)[0])
                    raise _fmt_err(source, f"agent {i}, step {r}, column d{c}", f"expected a finite offset where y{c} has a value, found {a[r, c]}")
                a = np.where(np.isnan(ys[i]), 0.0, a)  # where y is missing the offset is never used
                a.setflags(write=False)
                ds.append(a)
        return cls(ys, source, u, b, ds)


# ---------------------------------------------------------------------------
# readers
# ---------------------------------------------------------------------------
def _pandas() -> Any:
    return V.require("pandas", "dask")


def _read_table(path: Path, suffix: str) -> Any:
    """A DataFrame from CSV/Parquet, every column numeric; strings are reported with row and column."""
    pd = _pandas()
    if suffix == ".csv":
        try:
            with open(path, "rb") as fh:
                head = fh.read(4096)
        except OSError:
            head = b""
        if head.startswith((b"\xff\xfe", b"\xfe\xff")) or b"\x00" in head:
            raise _fmt_err(path, "", "expected a UTF-8 text file (CSV), found UTF-16 or binary data (NUL bytes); save it as UTF-8 CSV")
        try:
            df = pd.read_csv(path, skipinitialspace=True)
        except UnicodeDecodeError as exc:
            raise _fmt_err(path, "", f"expected a UTF-8 text file (CSV), found undecodable bytes at position {exc.start}; save it as UTF-8") from None
        except pd.errors.EmptyDataError:
            raise _fmt_err(path, "", "the file is empty; expected a header row 'step,agent,y0,...'") from None
        except pd.errors.ParserError as exc:
            raise _fmt_err(path, "", f"not a valid CSV file ({' '.join(str(exc).split())})") from None
    else:
        try:
            df = pd.read_parquet(path)
        except Exception as exc:  # pyarrow raises its own types for a corrupt file
            raise _fmt_err(path, "", f"not a readable Parquet file ({type(exc).__name__}: {' '.join(str(exc).split())[:200]})") from None
    return _coerce_numeric(df, path, suffix == ".csv")


def _coerce_numeric(df: Any, path: Path, csv: bool, row0: int = 0) -> Any:
    """Every column numeric; the first string is reported with its row (``row0``: rows before this chunk) and column."""
    pd = _pandas()
    for col in df.columns:
        if not isinstance(col, str):
            raise _fmt_err(path, f"column {col!r}", "expected string column names")
        s = df[col]
        if s.dtype.kind == "b" or (s.dtype.kind == "O" and s.map(lambda v: isinstance(v, (bool, np.bool_))).any()):
            raise _fmt_err(path, f"column {col!r}", "expected numbers, found true/false values; write measurements as numbers (1.0, 0.0)")
        if s.dtype.kind in "mM":
            raise _fmt_err(
                path, f"column {col!r}", f"expected numbers, found {'dates/times' if s.dtype.kind == 'M' else 'durations'}; give steps as integers"
            )
        if s.dtype.kind not in "fiub":
            num = pd.to_numeric(s, errors="coerce")
            bad = np.flatnonzero(num.isna().to_numpy() & s.notna().to_numpy())
            if bad.size:
                r = int(bad[0])
                raise _fmt_err(path, _where(r + row0, col, csv), f"expected a number, found {s.iloc[r]!r}")
            df[col] = num.astype(float)
        vals = df[col].to_numpy()
        if vals.dtype.kind == "f" and np.isinf(vals).any():
            r = int(np.flatnonzero(np.isinf(vals))[0])
            raise _fmt_err(
                path, _where(r + row0, col, csv), f"expected a finite number (empty or NaN = missing), found {float(vals[r])!r} (beyond 1.8e308?)"
            )
    return df


def _where(r: int, col: str, csv: bool) -> str:
    return f"row {r + 1}" + (f" (line {r + 2})" if csv else "") + f", column {col!r}"


_where_abs = _where


def _int_column(df: Any, col: str, path: Path, csv: bool, row0: int = 0) -> np.ndarray:
    a = df[col].to_numpy(dtype=float)
    bad = np.flatnonzero(~np.isfinite(a) | (a != np.round(a)))
    if bad.size:
        r = int(bad[0])
        v = df[col].iloc[r]
        raise _fmt_err(path, _where(r + row0, col, csv), f"expected a whole number, found {v.item() if hasattr(v, 'item') else v!r}")
    return a.astype(np.int64)


@dataclass(frozen=True)
class _Columns:
    """The optional columns of a long-form file: inputs u, process offsets b (per step), measurement offsets d (per row)."""

    u: list[str]
    b: list[str]
    d: list[str]

    @property
    def per_step(self) -> list[str]:
        return self.u + self.b


def _numbered(df: Any, prefix: str) -> list[str]:
    return sorted((c for c in df.columns if isinstance(c, str) and c.startswith(prefix) and c[1:].isdigit()), key=lambda c: int(c[1:]))


def _check_columns(df: Any, p: Path, system: LinearGaussianSystem) -> _Columns:
    """The columns step, agent, y0..y{m-1} (m = max d_y^i), and the optional u0.., b0..b{d_x-1}, d0..d{m-1}."""
    m = max(system.dy)
    want = ["step", "agent"] + [f"y{c}" for c in range(m)]
    ucols, bcols, dcols = _numbered(df, "u"), _numbered(df, "b"), _numbered(df, "d")
    if ucols and ucols != [f"u{c}" for c in range(len(ucols))]:
        raise _fmt_err(p, f"column {ucols[-1]!r}", f"input columns must be u0..u{len(ucols) - 1} without gaps, found {', '.join(ucols)}")
    if bcols and bcols != [f"b{c}" for c in range(system.dx)]:
        raise _fmt_err(
            p, f"column {bcols[-1]!r}", f"process-offset columns must be b0..b{system.dx - 1} (d_x = {system.dx}), found {', '.join(bcols)}"
        )
    if dcols and dcols != [f"d{c}" for c in range(m)]:
        raise _fmt_err(p, f"column {dcols[-1]!r}", f"measurement-offset columns must be d0..d{m - 1} (as y0..y{m - 1}), found {', '.join(dcols)}")
    want_all = want + ucols + bcols + dcols
    for col in df.columns:
        if col not in want_all:
            extra = (
                f"; the model has max d_y = {m}, so the columns are {', '.join(want)}"
                if col.startswith("y")
                else f"; expected the columns {', '.join(want)}"
            )
            raise _fmt_err(p, f"column {col!r}", f"unknown column{extra}")
    for col in want:
        if col not in df.columns:
            raise _fmt_err(p, f"column {col!r}", f"missing; expected the columns {', '.join(want)} (one y column per measurement component)")
    return _Columns(ucols, bcols, dcols)


def _offset_values(
    df: Any, cols: _Columns, p: Path, system: LinearGaussianSystem, agent: np.ndarray, vals: np.ndarray, csv: bool, row0: int = 0
) -> Any:
    """The d columns of validated rows (rows, m): finite where y has a value, empty beyond d_y^i; None without d columns."""
    if not cols.d:
        return None
    dv = df[cols.d].to_numpy(dtype=float)
    cells = np.argwhere(np.isinf(dv) | (~np.isnan(vals) & np.isnan(dv)))
    if cells.size:
        r, c = (int(v) for v in cells[0])
        raise _fmt_err(p, _where(r + row0, f"d{c}", csv), f"expected a finite offset d_i(t) where y{c} has a value, found {df[f'd{c}'].iloc[r]!r}")
    for i, dyi in enumerate(system.dy):
        extra = dv[agent == i][:, dyi:]
        hit = np.argwhere(~np.isnan(extra))
        if hit.size:
            r = int(np.flatnonzero(agent == i)[hit[0][0]])
            c = dyi + int(hit[0][1])
            raise _fmt_err(p, _where(r + row0, f"d{c}", csv), f"agent {i} has d_y = {dyi} (columns d0..d{dyi - 1}); leave d{c} empty")
    return dv


def _validate_rows(
    df: Any, p: Path, system: LinearGaussianSystem, horizon: int | None, n_steps: int | None, csv: bool, row0: int = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(step, agent, y values) of validated rows; ``row0`` rows came before (chunked reading)."""
    n, dys = system.n_agents, system.dy
    m = max(dys)

    def _where(r: int, col: str, csv: bool) -> str:
        return _where_abs(r + row0, col, csv)

    step = _int_column(df, "step", p, csv, row0)
    agent = _int_column(df, "agent", p, csv, row0)
    bad = np.flatnonzero((agent < 0) | (agent >= n))
    if bad.size:
        r = int(bad[0])
        raise _fmt_err(p, _where(r, "agent", csv), f"unknown agent {int(agent[r])}; the scenario has agents 0..{n - 1}")
    bad = np.flatnonzero(step < 0)
    if bad.size:
        r = int(bad[0])
        raise _fmt_err(p, _where(r, "step", csv), f"expected a step >= 0, found {int(step[r])}")
    limit = horizon if horizon is not None else n_steps
    if limit is not None:
        bad = np.flatnonzero(step >= limit)
        if bad.size:
            r = int(bad[0])
            what = f"the scenario's horizon of {horizon} steps" if horizon is not None else f"n_steps = {n_steps}"
            raise _fmt_err(p, _where(r, "step", csv), f"step {int(step[r])} is beyond {what} (steps 0..{limit - 1}); drop it or raise horizon")
    key = step * n + agent
    order = np.argsort(key, kind="stable")
    dup = np.flatnonzero(key[order][1:] == key[order][:-1])
    if dup.size:
        r2 = int(order[dup[0] + 1])
        r1 = int(order[dup[0]])
        r1, r2 = min(r1, r2), max(r1, r2)
        raise _fmt_err(
            p,
            _where(r2, "step", csv),
            f"duplicated (step, agent) = ({int(step[r2])}, {int(agent[r2])}), first at row {r1 + 1 + row0}; keep one row per agent and step",
        )
    vals = df[[f"y{c}" for c in range(m)]].to_numpy(dtype=float)
    cells = np.argwhere(np.isinf(vals))
    if cells.size:
        r, c = (int(v) for v in cells[0])
        raise _fmt_err(p, _where(r, f"y{c}", csv), f"expected a finite number or an empty cell (missing), found {vals[r, c]}")
    for i in range(n):
        if dys[i] < m:
            rows = agent == i
            extra = vals[rows][:, dys[i] :]
            hit = np.argwhere(~np.isnan(extra))
            if hit.size:
                r = int(np.flatnonzero(rows)[hit[0][0]])
                c = dys[i] + int(hit[0][1])
                raise _fmt_err(p, _where(r, f"y{c}", csv), f"agent {i} has d_y = {dys[i]} (columns y0..y{dys[i] - 1}); leave y{c} empty")
    return step, agent, vals


def read_measurements(path: str | Path, system: LinearGaussianSystem, horizon: int | None = None, *, n_steps: int | None = None) -> MeasurementLog:
    """Read a measurement file (CSV, Parquet or NPZ; see the module docstring) and validate it against the model.

    Parameters
    ----------
    path : file
    system : the scenario's model (agents and d_y^i)
    horizon : the scenario's horizon (steps must be < horizon), or None (steady state: any step)
    n_steps : the number of steps of the log (default: last step in the file + 1)

    Raises
    ------
    MeasurementFileError
        Naming the file, the row and the column of the first problem.
    FileNotFoundError
    """
    p = Path(path)
    suffix = _suffix(p, "--measurements")
    if not p.exists():
        raise FileNotFoundError(2, "No such file or directory", str(p))
    if suffix == ".npz":
        return _read_npz(p, system, horizon)
    csv = suffix == ".csv"
    df = _read_table(p, suffix)
    cols = _check_columns(df, p, system)
    if len(df) == 0:
        raise _fmt_err(p, "", "no data rows; expected one row per agent and step")
    step, agent, vals = _validate_rows(df, p, system, horizon, n_steps, csv)
    n, dys = system.n_agents, system.dy
    T = n_steps if n_steps is not None else int(step.max()) + 1
    dv = _offset_values(df, cols, p, system, agent, vals, csv)

    def per_agent(v: np.ndarray) -> list[FloatArray]:
        out = []
        for i in range(n):
            a = np.full((T, dys[i]), np.nan)
            rows = agent == i
            a[step[rows]] = v[rows][:, : dys[i]]
            out.append(a)
        return out

    ys = per_agent(vals)
    ub = _read_u_columns(df, cols.per_step, step, T, p, csv) if cols.per_step else None
    u = None if ub is None or not cols.u else ub[:, : len(cols.u)]
    b = None if ub is None or not cols.b else ub[:, len(cols.u) :]
    return MeasurementLog.from_arrays(ys, system, horizon, source=str(p), u=u, b=b, d=None if dv is None else per_agent(dv))


def _read_u_columns(df: Any, ucols: list[str], step: np.ndarray, T: int, p: Path, csv: bool) -> FloatArray:
    """u(t) (and b(t)) from the per-step columns: every row of a step must give the same finite values, every step needs one."""
    uv = df[ucols].to_numpy(dtype=float)
    bad = np.argwhere(~np.isfinite(uv))
    if bad.size:
        r, c = (int(v) for v in bad[0])
        raise _fmt_err(
            p, _where(r, ucols[c], csv), f"expected a finite value, found {uv[r, c]} (known inputs u(t) and offsets b(t) cannot be missing)"
        )
    u = np.full((T, len(ucols)), np.nan)
    for r in np.argsort(step, kind="stable"):
        s = step[r]
        if np.isnan(u[s, 0]):
            u[s] = uv[r]
        elif not np.array_equal(u[s], uv[r]):
            c = int(np.flatnonzero(u[s] != uv[r])[0])
            raise _fmt_err(
                p,
                _where(int(r), ucols[c], csv),
                f"step {int(s)} has {ucols[c]} = {uv[r, c]} here and {u[s, c]} on another row; u(t) and b(t) are one value per step",
            )
    gone = np.flatnonzero(np.isnan(u[:, 0]))
    if gone.size:
        raise _fmt_err(
            p,
            f"column {ucols[0]!r}",
            f"step {int(gone[0])} has no row, so no {ucols[0][0]}({int(gone[0])}); give a row (y cells may be empty) for every step",
        )
    return u


def _npz_arrays(p: Path) -> dict[str, np.ndarray]:
    try:
        with np.load(p, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except ValueError as exc:
        raise _fmt_err(p, "", f"not a readable NPZ file of numeric arrays ({exc})") from None
    except Exception as exc:  # zipfile.BadZipFile, OSError on a truncated file
        raise _fmt_err(p, "", f"not a readable NPZ file ({type(exc).__name__}: {exc})") from None


def _read_npz(p: Path, system: LinearGaussianSystem, horizon: int | None) -> MeasurementLog:
    arrs = _npz_arrays(p)
    n = system.n_agents
    names = [f"agent{i}" for i in range(n)]
    if not all(k in arrs for k in names):
        alt = [f"arr_{i}" for i in range(n)]
        if all(k in arrs for k in alt):
            names = alt
        else:
            raise _fmt_err(
                p,
                f"key {next(k for k in names if k not in arrs)!r}",
                f"missing; expected one array per agent: {', '.join(names)} (found {', '.join(arrs) or 'none'})",
            )
    opt: dict[str, Any] = {}
    for key in ("u", "b", *[f"d_agent{i}" for i in range(n)]):
        a = arrs.pop(key, None)
        if a is not None and a.dtype.kind not in "fiub":
            raise _fmt_err(p, f"key {key!r}", f"expected numbers, found dtype {a.dtype}")
        opt[key] = None if a is None else a.astype(float)
    extra = [k for k in arrs if k not in names]
    if extra:
        raise _fmt_err(
            p, f"key {extra[0]!r}", f"unknown array; expected {', '.join(names)} (the scenario has {n} agents), and optionally u, b, d_agent0, ..."
        )
    dk = [f"d_agent{i}" for i in range(n)]
    if any(opt[k] is not None for k in dk) and not all(opt[k] is not None for k in dk):
        raise _fmt_err(p, f"key {next(k for k in dk if opt[k] is None)!r}", "missing; measurement offsets need one array per agent")
    d = [opt[k] for k in dk] if opt[dk[0]] is not None else None
    ys = []
    for k in names:
        a = arrs[k]
        if a.dtype.kind not in "fiub":
            raise _fmt_err(p, f"key {k!r}", f"expected numbers, found dtype {a.dtype}")
        ys.append(a.astype(float))
    return MeasurementLog.from_arrays(ys, system, horizon, source=str(p), u=opt["u"], b=opt["b"], d=d)


def read_truth(path: str | Path, dx: int, n_steps: int) -> FloatArray:
    """Read the true states x(0..n_steps-1): ``step, x0, x1, ...`` (CSV/Parquet) or NPZ key ``x`` (steps, d_x)."""
    p = Path(path)
    suffix = _suffix(p, "--truth")
    if not p.exists():
        raise FileNotFoundError(2, "No such file or directory", str(p))
    if suffix == ".npz":
        arrs = _npz_arrays(p)
        if "x" not in arrs:
            raise _fmt_err(
                p, "key 'x'", f"missing; expected the states as an array 'x' of shape ({n_steps}, {dx}) (found {', '.join(arrs) or 'none'})"
            )
        x = arrs["x"]
        if x.dtype.kind not in "fiub":
            raise _fmt_err(p, "key 'x'", f"expected numbers, found dtype {x.dtype}")
        x = x.astype(float)
        if x.ndim != 2 or x.shape != (n_steps, dx):
            raise _fmt_err(p, "key 'x'", f"expected shape ({n_steps}, {dx}) (steps of the measurements, d_x), found {x.shape}")
        cells = np.argwhere(~np.isfinite(x))
        if cells.size:
            r, c = (int(v) for v in cells[0])
            raise _fmt_err(p, f"step {r}, column x{c}", f"expected a finite number, found {x[r, c]}")
        return x
    csv = suffix == ".csv"
    df = _read_table(p, suffix)
    want = ["step"] + [f"x{c}" for c in range(dx)]
    for col in df.columns:
        if col not in want:
            raise _fmt_err(p, f"column {col!r}", f"unknown column; expected {', '.join(want)} (d_x = {dx})")
    for col in want:
        if col not in df.columns:
            raise _fmt_err(p, f"column {col!r}", f"missing; expected {', '.join(want)} (d_x = {dx})")
    step = _int_column(df, "step", p, csv)
    vals = df[want[1:]].to_numpy(dtype=float)
    cells = np.argwhere(~np.isfinite(vals))
    if cells.size:
        r, c = (int(v) for v in cells[0])
        raise _fmt_err(p, _where(r, f"x{c}", csv), f"expected a finite number, found {df[f'x{c}'].iloc[r]!r}")
    bad = np.flatnonzero((step < 0) | (step >= n_steps))
    if bad.size:
        r = int(bad[0])
        raise _fmt_err(p, _where(r, "step", csv), f"step {int(step[r])} is outside the measurements' steps 0..{n_steps - 1}")
    x = np.full((n_steps, dx), np.nan)
    seen = np.zeros(n_steps, dtype=bool)
    for r, s in enumerate(step):
        if seen[s]:
            raise _fmt_err(p, _where(r, "step", csv), f"duplicated step {int(s)}; one row per step")
        seen[s] = True
    x[step] = vals
    if not seen.all():
        raise _fmt_err(p, "column 'step'", f"step {int(np.flatnonzero(~seen)[0])} has no row; the truth needs every step 0..{n_steps - 1}")
    return x


# ---------------------------------------------------------------------------
# writers
# ---------------------------------------------------------------------------
def write_measurements(
    path: str | Path | Any, y: Sequence[Any], *, fmt: str | None = None, u: Any = None, b: Any = None, d: Sequence[Any] | None = None
) -> None:
    """Write per-agent measurements (n_steps, d_y^i) (NaN = missing) in long form (CSV/Parquet) or NPZ.

    ``path`` may be an open binary file when ``fmt`` (".csv", ".parquet", ".npz") is given.
    A CSV/Parquet file has a row for every (step, agent) with at least one value (every row
    when per-step values are given: known inputs ``u`` (n_steps, d_u), columns ``u0, u1, ...``;
    process offsets ``b`` (n_steps, d_x), columns ``b0, ...``). Measurement offsets ``d`` (per
    agent, (n_steps, d_y^i)) go in columns ``d0, ...`` of the agent's rows. NPZ keys: ``u``,
    ``b``, ``d_agent0``, ...
    """
    suffix = fmt if fmt is not None else _suffix(Path(path), "path")
    ys = [np.asarray(a, dtype=float) for a in y]
    uu = None if u is None else np.asarray(u, dtype=float).reshape(ys[0].shape[0], -1)
    bb = None if b is None else np.asarray(b, dtype=float).reshape(ys[0].shape[0], -1)
    dd = None if d is None else [np.asarray(a, dtype=float).reshape(ys[i].shape) for i, a in enumerate(d)]
    if suffix == ".npz":
        arrays: dict[str, Any] = {f"agent{i}": a for i, a in enumerate(ys)}
        if uu is not None:
            arrays["u"] = uu
        if bb is not None:
            arrays["b"] = bb
        arrays.update({f"d_agent{i}": di for i, di in enumerate(dd or [])})
        np.savez(path, **arrays)
        return
    pd = _pandas()
    m = max(a.shape[1] for a in ys)
    T = ys[0].shape[0]
    blocks = []
    for i, a in enumerate(ys):
        full = np.full((T, 2 * m), np.nan)  # y columns, then d columns
        full[:, : a.shape[1]] = a
        if dd is not None:
            full[:, m : m + a.shape[1]] = np.where(np.isnan(a), np.nan, dd[i])
        keep = ~np.isnan(a).all(axis=1) if uu is None and bb is None else np.ones(T, dtype=bool)
        blocks.append((np.flatnonzero(keep), np.full(int(keep.sum()), i), full[keep]))
    step = np.concatenate([blk[0] for blk in blocks])
    agent = np.concatenate([blk[1] for blk in blocks])
    vals = np.concatenate([blk[2] for blk in blocks])
    order = np.lexsort((agent, step))
    cols = {"step": step[order], "agent": agent[order], **{f"y{c}": vals[order, c] for c in range(m)}}
    if uu is not None:
        cols.update({f"u{c}": uu[step[order], c] for c in range(uu.shape[1])})
    if bb is not None:
        cols.update({f"b{c}": bb[step[order], c] for c in range(bb.shape[1])})
    if dd is not None:
        cols.update({f"d{c}": vals[order, m + c] for c in range(m)})
    _write_frame(pd.DataFrame(cols), path, suffix)


def _write_frame(df: Any, path: Any, suffix: str) -> None:
    if suffix == ".csv":
        if hasattr(path, "write"):
            import io

            buf = io.StringIO()
            df.to_csv(buf, index=False, float_format="%.17g")
            path.write(buf.getvalue().encode())
        else:
            df.to_csv(path, index=False, float_format="%.17g")
    else:
        df.to_parquet(path, index=False)


def estimates_frame(estimates: Mapping[str, FloatArray], n_agents: int) -> Any:
    """Long form ``step, agent, estimator, z0, ...`` of estimates name -> (n_steps, n_agents d_z)."""
    pd = _pandas()
    frames = []
    for name, z in estimates.items():
        T = z.shape[0]
        dz = z.shape[1] // n_agents
        zz = z.reshape(T, n_agents, dz).reshape(T * n_agents, dz)
        cols = {"step": np.repeat(np.arange(T), n_agents), "agent": np.tile(np.arange(n_agents), T), "estimator": name}
        cols.update({f"z{c}": zz[:, c] for c in range(dz)})
        frames.append(pd.DataFrame(cols))
    df = pd.concat(frames, ignore_index=True)
    return df.sort_values(["step", "agent"], kind="stable", ignore_index=True)


def write_estimates(path: str | Path | Any, estimates: Mapping[str, FloatArray], n_agents: int, *, fmt: str | None = None) -> None:
    """Write estimates in long form ``step, agent, estimator, z0, ...`` (CSV or Parquet)."""
    suffix = fmt if fmt is not None else Path(path).suffix.lower()
    if suffix not in (".csv", ".parquet"):
        raise MeasurementFileError(
            f"{path}: expected an output file ending in .csv or .parquet, found {suffix or 'no extension'!r}", argument="--out"
        )
    _write_frame(estimates_frame(estimates, n_agents), path, suffix)


# ---------------------------------------------------------------------------
# known means: prior mean, inputs and offsets
# ---------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class KnownInputs:
    r"""Known means that every agent knows: prior mean, inputs and offsets.

    .. math::

        x(0) \sim N(\bar x_0, \Sigma_x), \quad x(t+1) = A x(t) + B u(t) + b + w(t), \quad
        y_i(t) = C_i x(t) + D_i u(t) + d_i + v_i(t)

    Every family designed for the zero-mean model runs on the centred data
    y_i(t) - \bar y_i(t) and adds L_i(t) m(t), with the mean trajectory
    m(0) = \bar x_0, m(t+1) = A m(t) + B u(t) + b and \bar y_i(t) = C_i m(t) + D_i u(t) + d_i.
    For the centralized filter, MTMSE and MMSE this is the exact optimum of the
    affine problem (the errors x - m, y - \bar y are the zero-mean problem and
    the means are common knowledge); for every linear filter it is the filter
    run with the known inputs in its prediction step. Errors, and so every
    analytic and Monte Carlo cost, do not change.

    Attributes
    ----------
    x0_mean : (d_x,)
    B : (d_x, d_u) or None
    u : (d_u,) constant input, or None (then per-step inputs come with the measurements)
    b : (d_x,)
    D : tuple over agents of (d_y^i, d_u) or None
    d : tuple over agents of (d_y^i,)
    """

    x0_mean: FloatArray
    b: FloatArray
    d: tuple[FloatArray, ...]
    B: FloatArray | None = None
    u: FloatArray | None = None
    D: tuple[FloatArray, ...] | None = None

    def inputs(self, T: int, u_log: FloatArray | None) -> FloatArray | None:
        """u(0..T-1): from the log when it has them, else the constant u (None without inputs)."""
        if self.B is None and self.D is None:
            return None
        du = self.B.shape[1] if self.B is not None else self.D[0].shape[1]  # type: ignore[index]
        if u_log is not None:
            if u_log.shape[1] != du:
                raise MeasurementFileError(
                    f"u: the scenario's B/D take {du} inputs, the measurements give {u_log.shape[1]} (u0..u{u_log.shape[1] - 1})", argument="u"
                )
            if self.u is not None:
                raise MeasurementFileError("u: given both as system.u in the scenario and as u columns of the measurements; keep one", argument="u")
            return u_log[:T]
        if self.u is None:
            raise MeasurementFileError(
                f"u: the scenario has B/D but no inputs; give system.u (a constant) or u0..u{du - 1} columns in the measurements", argument="u"
            )
        return np.broadcast_to(self.u, (T, du))

    @classmethod
    def zero(cls, system: LinearGaussianSystem) -> "KnownInputs":
        """Zero prior mean and offsets, no inputs (a log's own offset columns then give the means)."""
        return cls(x0_mean=np.zeros(system.dx), b=np.zeros(system.dx), d=tuple(np.zeros(k) for k in system.dy))

    def offsets(self, T: int, b_log: FloatArray | None, d_log: Sequence[FloatArray] | None) -> tuple[FloatArray, list[FloatArray]]:
        """b(t) (T, d_x) and d_i(t) (T, d_y^i): from the log's offset columns, else the scenario's constants.

        The same offset given both ways is refused (which one is meant is not ours to guess).
        """
        if b_log is not None and np.any(self.b != 0):
            raise MeasurementFileError("b: given both as system.b in the scenario and as b columns of the measurements; keep one", argument="b")
        if d_log is not None and any(np.any(di != 0) for di in self.d):
            raise MeasurementFileError("d: given both as agents[i].d in the scenario and as d columns of the measurements; keep one", argument="d")
        b = b_log[:T] if b_log is not None else np.broadcast_to(self.b, (T, self.b.shape[0]))
        d = [di[:T] for di in d_log] if d_log is not None else [np.broadcast_to(di, (T, di.shape[0])) for di in self.d]
        return b, d

    def means(
        self,
        system: LinearGaussianSystem,
        T: int,
        u_log: FloatArray | None = None,
        b_log: FloatArray | None = None,
        d_log: Sequence[FloatArray] | None = None,
    ) -> tuple[FloatArray, list[FloatArray]]:
        """The mean trajectory m (T, d_x) and the measurement means ȳ_i (T, d_y^i).

        ``u_log``, ``b_log``, ``d_log``: the log's per-step inputs and time-varying offsets
        (:attr:`MeasurementLog.u`, ``.b``, ``.d``), used instead of the scenario's constants.
        """
        u = self.inputs(T, u_log)
        b, d = self.offsets(T, b_log, d_log)
        m = np.empty((T, system.dx))
        m[0] = self.x0_mean
        for t in range(T - 1):
            nxt = system.A_at(t) @ m[t] + b[t]
            if u is not None and self.B is not None:
                nxt = nxt + self.B @ u[t]
            m[t + 1] = nxt
        ybar = []
        for i in range(system.n_agents):
            yi = np.stack([system.C_at(i, t) @ m[t] for t in range(T)]) + d[i]
            if u is not None and self.D is not None:
                yi = yi + u @ self.D[i].T
            ybar.append(yi)
        return m, ybar


def known_inputs(scenario: Any) -> KnownInputs | None:
    """The known means of a scenario (``[system] x0_mean, B, u, b``; ``[[agents]] D, d``), validated, or None."""
    from ..exceptions import ScenarioError

    raw = getattr(scenario, "raw", {}) or {}
    s = raw.get("system", {}) or {}
    agents = raw.get("agents", []) or []
    keys = ("x0_mean", "B", "u", "b")
    if not any(k in s for k in keys) and not any(isinstance(a, dict) and ("D" in a or "d" in a) for a in agents):
        return None
    sys_ = scenario.system
    dx, n = sys_.dx, sys_.n_agents

    def vec(x: Any, key: str, size: int) -> FloatArray:
        try:
            a = np.asarray(x, dtype=float)
        except (TypeError, ValueError):
            raise ScenarioError(f"{key}: expected a number or a list of {size} numbers, found {V.describe(x)}", argument=key) from None
        a = np.broadcast_to(a, (size,)).copy() if a.ndim == 0 else a
        if a.shape != (size,) or not np.all(np.isfinite(a)):
            raise ScenarioError(f"{key}: expected {size} finite numbers, found shape {a.shape}", argument=key)
        return a

    def mat(x: Any, key: str, rows: int, cols: int | None) -> FloatArray:
        try:
            a = np.asarray(x, dtype=float)
        except (TypeError, ValueError):
            raise ScenarioError(f"{key}: expected a matrix of numbers, found {V.describe(x)}", argument=key) from None
        if a.ndim != 2 or a.shape[0] != rows or (cols is not None and a.shape[1] != cols) or not np.all(np.isfinite(a)):
            want = f"{rows}x{cols}" if cols is not None else f"{rows}xd_u"
            raise ScenarioError(f"{key}: expected a finite {want} matrix, found shape {a.shape}", argument=key)
        return a

    x0 = vec(s.get("x0_mean", 0.0), "system.x0_mean", dx)
    b = vec(s.get("b", 0.0), "system.b", dx)
    B = mat(s["B"], "system.B", dx, None) if "B" in s else None
    du = B.shape[1] if B is not None else None
    Ds: list[FloatArray] | None = None
    if any("D" in a for a in agents):
        Ds = []
        for i, a in enumerate(agents):
            if "D" in a:
                Di = mat(a["D"], f"agents[{i}].D", sys_.dy[i], du)
                du = Di.shape[1] if du is None else du
            else:
                Di = None
            Ds.append(Di)  # type: ignore[arg-type]
        Ds = [Di if Di is not None else np.zeros((sys_.dy[i], du)) for i, Di in enumerate(Ds)]  # type: ignore[arg-type]
    u = vec(s["u"], "system.u", du) if "u" in s and du is not None else None
    if "u" in s and du is None:
        raise ScenarioError("system.u: inputs need system.B (or agents[i].D) to act on; add B or drop u", argument="system.u")
    d = tuple(vec(a.get("d", 0.0), f"agents[{i}].d", sys_.dy[i]) for i, a in enumerate(agents))
    if len(d) != n:
        d = tuple(np.zeros(k) for k in sys_.dy)
    return KnownInputs(x0_mean=x0, b=b, d=d, B=B, u=u, D=None if Ds is None else tuple(Ds))


# ---------------------------------------------------------------------------
# innovations and log-likelihood under the centralized filter
# ---------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Innovations:
    r"""Innovations of the centralized Kalman filter on a log, and the log-likelihood of the data.

    e(t) = y(t) - C(t) x̂(t|t-1) - ȳ-terms over the components present at t,
    S(t) = C(t) P(t) C(t)' + R(t) (present rows), and

    .. math::

        \log p(y) = \sum_t -\tfrac12 \left[ m_t \log 2\pi + \log\det S(t) + e(t)' S(t)^{-1} e(t) \right]

    with m_t the number of components present at t (a step with none adds 0).

    Attributes
    ----------
    e : list over agents of (n_steps, d_y^i), NaN where missing
    loglik_steps : (n_steps,)
    """

    e: list[FloatArray]
    loglik_steps: FloatArray

    @property
    def loglik(self) -> float:
        """The sum over steps; ``-inf`` once a step's term overflows (a measurement the model makes impossible: p(y) = 0 in floats)."""
        ll = self.loglik_steps
        bad = ~np.isfinite(ll)
        if bad.any() and np.isneginf(ll[int(np.flatnonzero(bad)[0])]):
            return float("-inf")  # later steps inherit the overflowed state (NaN); the likelihood is already 0
        return float(np.sum(ll))


def innovations(system: LinearGaussianSystem, log: MeasurementLog, inputs: KnownInputs | None = None) -> Innovations:
    """Innovations and log-likelihood of ``log`` under the centralized filter (gaps: present rows only)."""
    T, n, dx = log.n_steps, system.n_agents, system.dx
    if inputs is not None:
        _, ybar = inputs.means(system, T, log.u, log.b, log.d)
        yc = [log.y[i] - ybar[i] for i in range(n)]
    else:
        yc = list(log.y)
    pres = log.present
    x, P = np.zeros(dx), np.array(system.Sigma_x, dtype=float)
    e = [np.full(y.shape, np.nan) for y in log.y]
    ll = np.zeros(T)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):  # an overflow is reported as a non-finite log-likelihood
        _innovation_steps(system, yc, pres, x, P, e, ll)
    return Innovations(e, ll)


def _innovation_steps(system: LinearGaussianSystem, yc: list[Any], pres: Any, x: FloatArray, P: FloatArray, e: list[Any], ll: FloatArray) -> None:
    """The centralized filter's recursion of :func:`innovations` (fills ``e`` and ``ll`` in place)."""
    n, dx, T = system.n_agents, system.dx, ll.size
    for t in range(T):
        C = np.vstack([system.C_at(i, t)[pres[i][t]] for i in range(n)])
        blocks = [system.R_at(i, t)[np.ix_(pres[i][t], pres[i][t])] for i in range(n)]
        R = sla.block_diag(*blocks)
        y = np.concatenate([yc[i][t][pres[i][t]] for i in range(n)])
        if y.size:
            S = C @ P @ C.T + R
            S = 0.5 * (S + S.T)
            r = y - C @ x
            cf = sla.cho_factor(S, lower=True, check_finite=False)
            K = sla.cho_solve(cf, C @ P, check_finite=False).T
            q = float(r @ sla.cho_solve(cf, r, check_finite=False))
            ll[t] = -np.inf if not np.isfinite(q) else -0.5 * (y.size * np.log(2 * np.pi) + 2 * np.sum(np.log(np.diag(cf[0]))) + q)
            pos = 0
            for i in range(n):
                k = int(pres[i][t].sum())
                e[i][t, pres[i][t]] = r[pos : pos + k]
                pos += k
            x = x + K @ r
            IKC = np.eye(dx) - K @ C
            P = IKC @ P @ IKC.T + K @ R @ K.T
        A = system.A_at(t)
        x = A @ x
        P = A @ P @ A.T + system.Q_at(t)


# ---------------------------------------------------------------------------
# the masked model and filtering
# ---------------------------------------------------------------------------
def masked_system(system: LinearGaussianSystem, present: Sequence[np.ndarray]) -> LinearGaussianSystem:
    r"""The time-varying model of a missingness pattern, with fixed dimensions.

    For every agent i and step t, with r the rows missing at t:

    .. math::

        C_i(t)[r, :] = 0, \quad R_i(t)[r, :] = R_i(t)[:, r] = 0, \quad R_i(t)[r, r] = I

    (the present rows keep C_i(t) and their block of R_i(t)). The missing rows
    become unit-variance noise independent of everything else, on which every
    optimal gain is exactly zero (module docstring): the estimates equal those
    of the model with the rows removed.

    Parameters
    ----------
    system : the model
    present : list over agents of boolean (n_steps, d_y^i) masks
    """
    T = int(present[0].shape[0])
    system.require_horizon(T)
    C, R = [], []
    for i, mask in enumerate(present):
        Ci, Ri = [], []
        for t in range(T):
            c = np.array(system.C_at(i, t), dtype=float)
            r = np.array(system.R_at(i, t), dtype=float)
            miss = ~mask[t]
            if miss.any():
                c[miss] = 0.0
                r[miss] = 0.0
                r[:, miss] = 0.0
                r[miss, miss] = 1.0
            Ci.append(c)
            Ri.append(r)
        C.append(Ci)
        R.append(Ri)
    A = system.A[0] if system.A.shape[0] == 1 else list(system.A)
    Q = system.Q[0] if system.Q.shape[0] == 1 else list(system.Q)
    return LinearGaussianSystem(A=A, Q=Q, Sigma_x=system.Sigma_x, C=C, R=R)


def _missing_error(name: str, log: MeasurementLog, reason: str = "") -> UnsupportedOperationError:
    i, s = log.first_missing()  # type: ignore[misc]
    why = f"the first missing measurement is agent {i} at step {s} (in {log.source}); {reason or 'it has no exact treatment of gaps'}"
    return UnsupportedOperationError(name, "filtering measurements with missing values", why + "; fill the gaps, or use centralized, mtmse or mmse")


def design_for_log(scenario: Any, name: str, log: MeasurementLog) -> Any:
    """Design estimator ``name`` of ``scenario`` for a recorded log.

    Without gaps: the scenario's own design. With gaps: the design on
    :func:`masked_system` for the log's steps (finite horizon), when the family
    declares ``handles_missing``; otherwise an
    :class:`~teamkf.exceptions.UnsupportedOperationError` naming the family
    and the first missing (agent, step).
    """
    if not log.has_gaps:
        return scenario.design(name)
    from ..estimators.registry import get_family

    fam = (getattr(scenario, "families", None) or {}).get(name) or get_family(name, "estimators")
    if "finite" not in fam.horizons:
        raise _missing_error(name, log, "it has no finite-horizon (time-varying) design")
    sysm = masked_system(scenario.system, log.present)
    opts = scenario.options.get(name) or fam.check_options({})
    try:
        d = fam.build(sysm, scenario.cost, graph=scenario.graph, structure=scenario.information, horizon=log.n_steps, options=opts)
    except TeamkfError as exc:
        raise _missing_error(name, log, f"its design on the time-varying model of the gaps failed ({exc})") from exc
    if not getattr(d, "handles_missing", False):
        raise _missing_error(name, log)
    return d


@dataclass(frozen=True, eq=False)
class FilterResult:
    """Estimates of every estimator on one recorded log, and the realized team cost when the truth is known.

    Attributes
    ----------
    estimates : dict name -> (n_steps, n_agents d_z)
    stage_costs : dict name -> (n_steps,) realized c(x(k), z(k)) = (L x - z)' S (L x - z), or None
    designs : dict name -> Design
    """

    estimates: dict[str, FloatArray]
    n_agents: int
    stage_costs: dict[str, FloatArray] | None = None
    designs: dict[str, Any] = field(default_factory=dict, repr=False)
    innovations: Innovations | None = None

    @property
    def loglik(self) -> float | None:
        """log p(y) under the centralized filter (None when not computed)."""
        return None if self.innovations is None else self.innovations.loglik

    @property
    def total_costs(self) -> dict[str, float] | None:
        if self.stage_costs is None:
            return None
        return {k: float(np.sum(v)) for k, v in self.stage_costs.items()}

    def to_pandas(self) -> Any:
        return estimates_frame(self.estimates, self.n_agents)

    def summary(self) -> dict[str, Any]:
        from ..estimators.base import json_float

        T = next(iter(self.estimates.values())).shape[0]
        out: dict[str, Any] = {"steps": T, "agents": self.n_agents, "estimators": list(self.estimates)}
        if self.stage_costs is not None:
            out["total_cost"] = {k: json_float(v) for k, v in (self.total_costs or {}).items()}
        if self.innovations is not None:
            out["loglik"] = json_float(self.innovations.loglik)
        bad = {f"total_cost.{k}": str(v) for k, v in (self.total_costs or {}).items() if not np.isfinite(v)}
        if self.innovations is not None and not np.isfinite(self.innovations.loglik):
            bad["loglik"] = str(self.innovations.loglik)
        if bad:  # strict JSON has no NaN or Infinity: the nulls above say which, and why
            out["non_finite"] = bad
        return out


def realized_costs(cost: Any, x: FloatArray, z: FloatArray) -> FloatArray:
    """c(k) = (L(k) x(k) - z(k))' S(k) (L(k) x(k) - z(k)) for one run (n_steps,) or a batch (n_runs, n_steps)."""
    single = x.ndim == 2
    xb, zb = (x[None], z[None]) if single else (x, z)
    e = np.stack([xb[:, k] @ cost.L_at(k).T - zb[:, k] for k in range(xb.shape[1])], axis=1)  # as the Monte Carlo forms it
    c = team_stage_costs(cost, e)
    return c[0] if single else c


def online_estimates(design: Any, ys: Sequence[FloatArray]) -> FloatArray:
    """One run's estimates (n_steps, n d_z) from the design's online agents, exactly as the Monte Carlo
    ``path="runtime"`` computes them (message passing over the design's graph, or delivery by its
    information structure); ``design.filter`` for a design without online agents (the ideal KCF)."""
    batch = [np.asarray(y, dtype=float)[None] for y in ys]
    try:
        return np.asarray(runtime_estimates(design, batch))[0]
    except UnsupportedOperationError:
        return np.asarray(design.filter(list(ys)))


def filter_log(
    scenario: Any,
    log: MeasurementLog | Sequence[Any],
    *,
    estimators: Sequence[str] | None = None,
    truth: Any = None,
    inputs: Any = "scenario",
    with_innovations: bool = True,
) -> FilterResult:
    """Run every estimator of ``scenario`` (or ``estimators``) on a recorded log.

    Parameters
    ----------
    scenario : Scenario
    log : MeasurementLog, or per-agent (n_steps, d_y^i) arrays (NaN = missing)
    estimators : names (default: the scenario's)
    truth : (n_steps, d_x) states, or None
    inputs : KnownInputs, None (zero means) or "scenario" (default: :func:`known_inputs` of the scenario)
    with_innovations : also compute the centralized filter's innovations and log-likelihood

    Returns
    -------
    FilterResult
    """
    if not isinstance(log, MeasurementLog):
        log = MeasurementLog.from_arrays(log, scenario.system, scenario.horizon)
    names = list(scenario.estimators if estimators is None else estimators)
    known = known_inputs(scenario) if inputs == "scenario" else inputs
    T, n = log.n_steps, scenario.system.n_agents
    if known is None and (log.b is not None or log.d is not None):
        if inputs != "scenario":
            raise MeasurementFileError(
                f"{log.source}: b/d columns: the log has time-varying offsets but inputs=None (zero means) was asked; drop one", argument="inputs"
            )
        known = KnownInputs.zero(scenario.system)
    if known is not None:
        mean, ybar = known.means(scenario.system, T, log.u, log.b, log.d)
        ys = [np.where(np.isnan(log.y[i]), 0.0, log.y[i] - ybar[i]) for i in range(n)]
    else:
        if log.u is not None:
            raise MeasurementFileError(
                f"{log.source}: u columns: the scenario has no input matrix (system.B or agents[i].D) to use them; add one or drop the columns",
                argument="u",
            )
        ys = log.filled()
    est: dict[str, FloatArray] = {}
    designs: dict[str, Any] = {}
    for name in names:
        d = design_for_log(scenario, name, log)
        designs[name] = d
        with np.errstate(over="ignore", invalid="ignore"):
            z = online_estimates(d, ys)
            if known is not None:
                z = z + np.stack([scenario.cost.L_at(k) @ mean[k] for k in range(T)])
        est[name] = z
    inn = innovations(scenario.system, log, known) if with_innovations else None
    costs = None
    if truth is not None:
        x = V.as_float_array(truth, "truth")
        if x.shape != (log.n_steps, scenario.system.dx):
            raise MeasurementFileError(f"truth: expected shape ({log.n_steps}, {scenario.system.dx}) (steps, d_x), found {x.shape}", argument="truth")
        with np.errstate(over="ignore", invalid="ignore"):
            costs = {name: realized_costs(scenario.cost, x, z) for name, z in est.items()}
    return FilterResult(est, scenario.system.n_agents, costs, designs, inn)
