"""The recorded-measurement file formats: read, validate and write measurement, truth and estimate files.

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

The streaming reader (:mod:`teamkf.study.stream`) reads the same formats in blocks of whole steps with the
validators of this module (:func:`file_suffix`, :func:`check_columns`, :func:`validate_rows`, :func:`offset_values`,
:func:`coerce_numeric`, :func:`int_column`, :func:`read_npz`), so both paths accept and refuse the same files with
the same messages.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from ... import _validation as V
from ..._validation import FloatArray
from ...exceptions import TeamkfError
from ...models import LinearGaussianSystem
from ..outputs import write_atomic

__all__ = [
    "FORMATS",
    "MeasurementFileError",
    "file_error",
    "file_suffix",
    "MeasurementLog",
    "coerce_numeric",
    "cell_location",
    "int_column",
    "Columns",
    "check_columns",
    "offset_values",
    "validate_rows",
    "read_measurements",
    "read_npz",
    "read_truth",
    "write_measurements",
    "write_frame",
    "estimates_frame",
    "write_estimates",
]


#: file extensions understood (lower case)
FORMATS = (".csv", ".parquet", ".npz")


class MeasurementFileError(TeamkfError, ValueError):
    """A measurement, truth or estimate file is not what the scenario needs (names file, row and column)."""


def file_error(path: Any, where: str, message: str) -> MeasurementFileError:
    """The :class:`MeasurementFileError` for ``path``: "path: where: message" (``where`` names the row and column, or is empty)."""
    loc = f"{path}: {where}: " if where else f"{path}: "
    return MeasurementFileError(loc + message, argument=str(path))


def file_suffix(path: Path, flag: str) -> str:
    """The lower-case extension of ``path`` if it is one of :data:`FORMATS`; else a :class:`MeasurementFileError` naming ``flag``."""
    s = path.suffix.lower()
    if s not in FORMATS:
        raise MeasurementFileError(
            f"{path}: expected a file ending in .csv, .parquet or .npz, found {path.suffix or 'no extension'!r}", argument=flag
        )
    return s


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
    #: the time of step 0 in nanoseconds when the log came from a recording (MCAP), else None
    start_ns: int | None = None

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
                raise file_error(source, f"agent {i}", f"expected numbers, found {np.asarray(yi).dtype}") from None
            if a.ndim != 2 or a.shape[1] != system.dy[i]:
                raise file_error(source, f"agent {i}", f"expected shape (n_steps, {system.dy[i]}) (d_y^{i} = {system.dy[i]}), found {a.shape}")
            bad = np.argwhere(np.isinf(a))
            if bad.size:
                r, c = (int(v) for v in bad[0])
                raise file_error(source, f"agent {i}, step {r}, column y{c}", f"expected a finite number or NaN (missing), found {a[r, c]}")
            ys.append(a)
        T = ys[0].shape[0]
        for i, a in enumerate(ys):
            if a.shape[0] != T:
                raise file_error(source, f"agent {i}", f"expected {T} steps (as agent 0), found {a.shape[0]}")
        if T == 0:
            raise file_error(source, "", "expected at least one step, found none")
        if horizon is not None and T > horizon:
            raise file_error(
                source,
                f"step {horizon}",
                f"beyond the scenario's horizon of {horizon} steps (steps 0..{horizon - 1}); shorten the log or raise horizon",
            )
        for a in ys:
            a.setflags(write=False)
        if u is not None:
            u = np.asarray(u, dtype=float)
            if u.ndim != 2 or u.shape[0] != T or not np.all(np.isfinite(u)):
                raise file_error(source, "u", f"expected finite known inputs of shape ({T}, d_u), found shape {u.shape}")
        if b is not None:
            b = np.asarray(b, dtype=float)
            if b.shape != (T, system.dx) or not np.all(np.isfinite(b)):
                raise file_error(source, "b", f"expected finite process offsets b(t) of shape ({T}, {system.dx}) (steps, d_x), found shape {b.shape}")
        ds = None
        if d is not None:
            if len(d) != n:
                raise file_error(source, "d", f"expected {n} arrays of measurement offsets d_i(t) (one per agent), found {len(d)}")
            ds = []
            for i, di in enumerate(d):
                a = np.array(di, dtype=float)
                if a.shape != ys[i].shape:
                    raise file_error(source, f"d, agent {i}", f"expected shape {ys[i].shape} (as its measurements), found {a.shape}")
                need = ~np.isnan(ys[i]) & ~np.isfinite(a)
                if need.any():
                    r, c = (int(v) for v in np.argwhere(need)[0])
                    raise file_error(source, f"agent {i}, step {r}, column d{c}", f"expected a finite offset where y{c} has a value, found {a[r, c]}")
                a = np.where(np.isnan(ys[i]), 0.0, a)  # where y is missing the offset is never used
                a.setflags(write=False)
                ds.append(a)
        return cls(ys, source, u, b, ds)


def _pandas() -> Any:
    return V.require("pandas", "dask")


def check_text_file(path: Path) -> None:
    """Refuse a CSV file that is UTF-16 or binary (NUL bytes in its first 4 kB), in one line."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(4096)
    except OSError:
        return
    if head.startswith((b"\xff\xfe", b"\xfe\xff")) or b"\x00" in head:
        raise file_error(path, "", "expected a UTF-8 text file (CSV), found UTF-16 or binary data (NUL bytes); save it as UTF-8 CSV")


def _read_table(path: Path, suffix: str) -> Any:
    """A DataFrame from CSV/Parquet, every column numeric; strings are reported with row and column."""
    pd = _pandas()
    if suffix == ".csv":
        check_text_file(path)
        try:
            df = pd.read_csv(path, skipinitialspace=True)
        except UnicodeDecodeError as exc:
            raise file_error(
                path, "", f"expected a UTF-8 text file (CSV), found undecodable bytes at position {exc.start}; save it as UTF-8"
            ) from None
        except pd.errors.EmptyDataError:
            raise file_error(path, "", "the file is empty; expected a header row 'step,agent,y0,...'") from None
        except pd.errors.ParserError as exc:
            raise file_error(path, "", f"not a valid CSV file ({' '.join(str(exc).split())})") from None
    else:
        try:
            df = pd.read_parquet(path)
        except Exception as exc:  # pyarrow raises its own types for a corrupt file
            raise file_error(path, "", f"not a readable Parquet file ({type(exc).__name__}: {' '.join(str(exc).split())[:200]})") from None
    return coerce_numeric(df, path, suffix == ".csv")


def _is_real(v: Any) -> bool:
    """A real number as a Parquet object column holds it (float, int, Decimal), not a bool or text."""
    import decimal
    import numbers

    return isinstance(v, (numbers.Real, decimal.Decimal)) and not isinstance(v, (bool, np.bool_))


def _numeric_text(v: Any) -> bool:
    """Text that reads as a number ("1.5")."""
    if not isinstance(v, str):
        return False
    try:
        float(v)
    except ValueError:
        return False
    return True


def _parquet_types(df: Any, path: Path, row0: int) -> None:
    """A Parquet file's columns are numeric: integers or floats (nullable ones too), or decimals or all null;
    a categorical or text column is refused naming its dtype (CSV cells are checked one by one instead)."""
    pd = _pandas()
    for col in df.columns:
        s = df[col]
        if isinstance(s.dtype, pd.CategoricalDtype):
            raise file_error(
                path,
                f"column {col!r}",
                f"expected a numeric column (integers or floats), found dtype category (categorical values, categories of "
                f"dtype {s.cat.categories.dtype}); store it as float64 (df[{col!r}].astype(float)) before writing the Parquet file",
            )
        if s.dtype.kind in "OSU" or isinstance(s.dtype, pd.StringDtype):
            vals = s.to_numpy(dtype=object)
            present = [r for r, v in enumerate(vals) if v is not None and not (isinstance(v, float) and np.isnan(v)) and v is not pd.NA]
            other = [r for r in present if not _is_real(vals[r]) and not isinstance(vals[r], (bool, np.bool_))]  # true/false: below
            if not other:
                continue  # all null, or numbers as objects (decimals): coerced below
            r = next((q for q in other if not _numeric_text(vals[q])), other[0])
            v = vals[r]
            if _numeric_text(v):
                raise file_error(
                    path,
                    f"column {col!r}",
                    f"expected a numeric column (integers or floats), found text (dtype {s.dtype}), e.g. {v!r} in row {r + 1 + row0}; "
                    "store the numbers as float64 before writing the Parquet file",
                )
            raise file_error(path, cell_location(r + row0, col, False), f"expected a number, found {v!r} (a column of dtype {s.dtype})")


def coerce_numeric(df: Any, path: Path, csv: bool, row0: int = 0) -> Any:
    """Every column numeric; the first string is reported with its row (``row0``: rows before this chunk) and column.

    A Parquet file (``csv`` False) must also have numeric column types: a categorical or text column is refused
    naming its dtype.
    """
    pd = _pandas()
    for col in df.columns:
        if not isinstance(col, str):
            raise file_error(path, f"column {col!r}", "expected string column names")
    if not csv:
        _parquet_types(df, path, row0)
    for col in df.columns:
        s = df[col]
        if s.dtype.kind == "b" or (s.dtype.kind == "O" and s.map(lambda v: isinstance(v, (bool, np.bool_))).any()):
            raise file_error(path, f"column {col!r}", "expected numbers, found true/false values; write measurements as numbers (1.0, 0.0)")
        if s.dtype.kind in "mM":
            raise file_error(
                path, f"column {col!r}", f"expected numbers, found {'dates/times' if s.dtype.kind == 'M' else 'durations'}; give steps as integers"
            )
        if s.dtype.kind not in "fiub":
            num = pd.to_numeric(s, errors="coerce")
            bad = np.flatnonzero(num.isna().to_numpy() & s.notna().to_numpy())
            if bad.size:
                r = int(bad[0])
                raise file_error(path, cell_location(r + row0, col, csv), f"expected a number, found {s.iloc[r]!r}")
            df[col] = num.astype(float)
        vals = df[col].to_numpy()
        if vals.dtype.kind == "f" and np.isinf(vals).any():
            r = int(np.flatnonzero(np.isinf(vals))[0])
            raise file_error(
                path,
                cell_location(r + row0, col, csv),
                f"expected a finite number (empty or NaN = missing), found {float(vals[r])!r} (beyond 1.8e308?)",
            )
    return df


def cell_location(r: int, col: str, csv: bool) -> str:
    """Where data row ``r`` (0-based) and column ``col`` are: "row r+1 (line r+2), column 'col'" (the line only for CSV, after the header)."""
    return f"row {r + 1}" + (f" (line {r + 2})" if csv else "") + f", column {col!r}"


_where_abs = cell_location


def int_column(df: Any, col: str, path: Path, csv: bool, row0: int = 0) -> np.ndarray:
    """Column ``col`` as int64, every value a finite whole number (else the first offending cell; ``row0`` rows came before this chunk)."""
    a = df[col].to_numpy(dtype=float)
    bad = np.flatnonzero(~np.isfinite(a) | (a != np.round(a)))
    if bad.size:
        r = int(bad[0])
        v = df[col].iloc[r]
        raise file_error(path, cell_location(r + row0, col, csv), f"expected a whole number, found {v.item() if hasattr(v, 'item') else v!r}")
    return a.astype(np.int64)


@dataclass(frozen=True)
class Columns:
    """The optional columns of a long-form file: inputs u, process offsets b (per step), measurement offsets d (per row)."""

    u: list[str]
    b: list[str]
    d: list[str]

    @property
    def per_step(self) -> list[str]:
        return self.u + self.b


def _numbered(df: Any, prefix: str) -> list[str]:
    return sorted((c for c in df.columns if isinstance(c, str) and c.startswith(prefix) and c[1:].isdigit()), key=lambda c: int(c[1:]))


def check_columns(df: Any, p: Path, system: LinearGaussianSystem) -> Columns:
    """The columns step, agent, y0..y{m-1} (m = max d_y^i), and the optional u0.., b0..b{d_x-1}, d0..d{m-1}."""
    m = max(system.dy)
    want = ["step", "agent"] + [f"y{c}" for c in range(m)]
    ucols, bcols, dcols = _numbered(df, "u"), _numbered(df, "b"), _numbered(df, "d")
    if ucols and ucols != [f"u{c}" for c in range(len(ucols))]:
        raise file_error(p, f"column {ucols[-1]!r}", f"input columns must be u0..u{len(ucols) - 1} without gaps, found {', '.join(ucols)}")
    if bcols and bcols != [f"b{c}" for c in range(system.dx)]:
        raise file_error(
            p, f"column {bcols[-1]!r}", f"process-offset columns must be b0..b{system.dx - 1} (d_x = {system.dx}), found {', '.join(bcols)}"
        )
    if dcols and dcols != [f"d{c}" for c in range(m)]:
        raise file_error(p, f"column {dcols[-1]!r}", f"measurement-offset columns must be d0..d{m - 1} (as y0..y{m - 1}), found {', '.join(dcols)}")
    want_all = want + ucols + bcols + dcols
    for col in df.columns:
        if col not in want_all:
            extra = (
                f"; the model has max d_y = {m}, so the columns are {', '.join(want)}"
                if col.startswith("y")
                else f"; expected the columns {', '.join(want)}"
            )
            raise file_error(p, f"column {col!r}", f"unknown column{extra}")
    for col in want:
        if col not in df.columns:
            raise file_error(p, f"column {col!r}", f"missing; expected the columns {', '.join(want)} (one y column per measurement component)")
    return Columns(ucols, bcols, dcols)


def offset_values(
    df: Any, cols: Columns, p: Path, system: LinearGaussianSystem, agent: np.ndarray, vals: np.ndarray, csv: bool, row0: int = 0
) -> Any:
    """The d columns of validated rows (rows, m): finite where y has a value, empty beyond d_y^i; None without d columns."""
    if not cols.d:
        return None
    dv = df[cols.d].to_numpy(dtype=float)
    cells = np.argwhere(np.isinf(dv) | (~np.isnan(vals) & np.isnan(dv)))
    if cells.size:
        r, c = (int(v) for v in cells[0])
        raise file_error(
            p, cell_location(r + row0, f"d{c}", csv), f"expected a finite offset d_i(t) where y{c} has a value, found {df[f'd{c}'].iloc[r]!r}"
        )
    for i, dyi in enumerate(system.dy):
        extra = dv[agent == i][:, dyi:]
        hit = np.argwhere(~np.isnan(extra))
        if hit.size:
            r = int(np.flatnonzero(agent == i)[hit[0][0]])
            c = dyi + int(hit[0][1])
            raise file_error(p, cell_location(r + row0, f"d{c}", csv), f"agent {i} has d_y = {dyi} (columns d0..d{dyi - 1}); leave d{c} empty")
    return dv


def validate_rows(
    df: Any, p: Path, system: LinearGaussianSystem, horizon: int | None, n_steps: int | None, csv: bool, row0: int = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(step, agent, y values) of validated rows; ``row0`` rows came before (chunked reading)."""
    n, dys = system.n_agents, system.dy
    m = max(dys)

    def cell_location(r: int, col: str, csv: bool) -> str:
        return _where_abs(r + row0, col, csv)

    step = int_column(df, "step", p, csv, row0)
    agent = int_column(df, "agent", p, csv, row0)
    bad = np.flatnonzero((agent < 0) | (agent >= n))
    if bad.size:
        r = int(bad[0])
        raise file_error(p, cell_location(r, "agent", csv), f"unknown agent {int(agent[r])}; the scenario has agents 0..{n - 1}")
    bad = np.flatnonzero(step < 0)
    if bad.size:
        r = int(bad[0])
        raise file_error(p, cell_location(r, "step", csv), f"expected a step >= 0, found {int(step[r])}")
    limit = horizon if horizon is not None else n_steps
    if limit is not None:
        bad = np.flatnonzero(step >= limit)
        if bad.size:
            r = int(bad[0])
            what = f"the scenario's horizon of {horizon} steps" if horizon is not None else f"n_steps = {n_steps}"
            raise file_error(
                p, cell_location(r, "step", csv), f"step {int(step[r])} is beyond {what} (steps 0..{limit - 1}); drop it or raise horizon"
            )
    key = step * n + agent
    order = np.argsort(key, kind="stable")
    dup = np.flatnonzero(key[order][1:] == key[order][:-1])
    if dup.size:
        r2 = int(order[dup[0] + 1])
        r1 = int(order[dup[0]])
        r1, r2 = min(r1, r2), max(r1, r2)
        raise file_error(
            p,
            cell_location(r2, "step", csv),
            f"duplicated (step, agent) = ({int(step[r2])}, {int(agent[r2])}), first at row {r1 + 1 + row0}; keep one row per agent and step",
        )
    vals = df[[f"y{c}" for c in range(m)]].to_numpy(dtype=float)
    cells = np.argwhere(np.isinf(vals))
    if cells.size:
        r, c = (int(v) for v in cells[0])
        raise file_error(p, cell_location(r, f"y{c}", csv), f"expected a finite number or an empty cell (missing), found {vals[r, c]}")
    for i in range(n):
        if dys[i] < m:
            rows = agent == i
            extra = vals[rows][:, dys[i] :]
            hit = np.argwhere(~np.isnan(extra))
            if hit.size:
                r = int(np.flatnonzero(rows)[hit[0][0]])
                c = dys[i] + int(hit[0][1])
                raise file_error(p, cell_location(r, f"y{c}", csv), f"agent {i} has d_y = {dys[i]} (columns y0..y{dys[i] - 1}); leave y{c} empty")
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
    suffix = file_suffix(p, "--measurements")
    if not p.exists():
        raise FileNotFoundError(2, "No such file or directory", str(p))
    if suffix == ".npz":
        return read_npz(p, system, horizon)
    csv = suffix == ".csv"
    df = _read_table(p, suffix)
    cols = check_columns(df, p, system)
    if len(df) == 0:
        raise file_error(p, "", "no data rows; expected one row per agent and step")
    step, agent, vals = validate_rows(df, p, system, horizon, n_steps, csv)
    dys = system.dy
    T = n_steps if n_steps is not None else int(step.max()) + 1
    dv = offset_values(df, cols, p, system, agent, vals, csv)

    ys = per_agent_rows(vals, step, agent, T, dys)
    u, b = step_inputs(df, cols, step, T, p, csv)
    d = None if dv is None else per_agent_rows(dv, step, agent, T, dys)
    return MeasurementLog.from_arrays(ys, system, horizon, source=str(p), u=u, b=b, d=d)


def per_agent_rows(v: np.ndarray, step: np.ndarray, agent: np.ndarray, T: int, dys: Any) -> list[FloatArray]:
    """Long-form rows ``v`` (one per agent and step) as one (T, d_y^i) array per agent, NaN where a row is absent."""
    out = []
    for i, d in enumerate(dys):
        a = np.full((T, int(d)), np.nan)
        rows = agent == i
        a[step[rows]] = v[rows][:, : int(d)]
        out.append(a)
    return out


def step_inputs(df: Any, cols: Any, step: np.ndarray, T: int, p: Path, csv: bool) -> tuple[FloatArray | None, FloatArray | None]:
    """The known inputs u(t) and process offsets b(t) of a log's per-step columns, or None each."""
    ub = _read_u_columns(df, cols.per_step, step, T, p, csv) if cols.per_step else None
    u = None if ub is None or not cols.u else ub[:, : len(cols.u)]
    b = None if ub is None or not cols.b else ub[:, len(cols.u) :]
    return u, b


def _read_u_columns(df: Any, ucols: list[str], step: np.ndarray, T: int, p: Path, csv: bool) -> FloatArray:
    """u(t) (and b(t)) from the per-step columns: every row of a step must give the same finite values, every step needs one."""
    uv = df[ucols].to_numpy(dtype=float)
    bad = np.argwhere(~np.isfinite(uv))
    if bad.size:
        r, c = (int(v) for v in bad[0])
        raise file_error(
            p, cell_location(r, ucols[c], csv), f"expected a finite value, found {uv[r, c]} (known inputs u(t) and offsets b(t) cannot be missing)"
        )
    u = np.full((T, len(ucols)), np.nan)
    for r in np.argsort(step, kind="stable"):
        s = step[r]
        if np.isnan(u[s, 0]):
            u[s] = uv[r]
        elif not np.array_equal(u[s], uv[r]):
            c = int(np.flatnonzero(u[s] != uv[r])[0])
            raise file_error(
                p,
                cell_location(int(r), ucols[c], csv),
                f"step {int(s)} has {ucols[c]} = {uv[r, c]} here and {u[s, c]} on another row; u(t) and b(t) are one value per step",
            )
    gone = np.flatnonzero(np.isnan(u[:, 0]))
    if gone.size:
        raise file_error(
            p,
            f"column {ucols[0]!r}",
            f"step {int(gone[0])} has no row, so no {ucols[0][0]}({int(gone[0])}); give a row (y cells may be empty) for every step",
        )
    return u


def _npz_arrays(p: Path) -> dict[str, np.ndarray]:
    try:
        with open(p, "rb") as fh:
            magic = fh.read(4)
    except OSError:
        magic = b"PK"  # np.load below says what is wrong
    if not magic.startswith(b"PK"):
        raise file_error(
            p,
            "",
            f"not an NPZ file (a zip archive of arrays, as np.savez writes), found {'an empty file' if not magic else repr(magic)} at its start",
        )
    try:
        with np.load(p, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except ValueError as exc:
        raise file_error(p, "", f"not a readable NPZ file of numeric arrays ({exc})") from None
    except Exception as exc:  # zipfile.BadZipFile, OSError on a truncated file
        raise file_error(p, "", f"not a readable NPZ file ({type(exc).__name__}: {exc})") from None


_NPZ_FIX = "; save float arrays (np.savez(path, agent0=y.astype(float), ...))"


def read_npz(p: Path, system: LinearGaussianSystem, horizon: int | None) -> MeasurementLog:
    """A :class:`MeasurementLog` from an NPZ file (keys ``agent0``, ... or ``arr_0``, ...; optional ``u``, ``b``, ``d_agent0``, ...), validated."""
    arrs = _npz_arrays(p)
    n = system.n_agents
    names = [f"agent{i}" for i in range(n)]
    if not all(k in arrs for k in names):
        alt = [f"arr_{i}" for i in range(n)]
        if all(k in arrs for k in alt):
            names = alt
        else:
            raise file_error(
                p,
                f"key {next(k for k in names if k not in arrs)!r}",
                f"missing; expected one array per agent: {', '.join(names)} (found {', '.join(arrs) or 'none'})",
            )
    opt: dict[str, Any] = {}
    for key in ("u", "b", *[f"d_agent{i}" for i in range(n)]):
        a = arrs.pop(key, None)
        if a is not None and a.dtype.kind not in "fiu":
            raise file_error(p, f"key {key!r}", f"expected numbers (integers or floats), found dtype {a.dtype}{_NPZ_FIX}")
        opt[key] = None if a is None else a.astype(float)
    extra = [k for k in arrs if k not in names]
    if extra:
        raise file_error(
            p, f"key {extra[0]!r}", f"unknown array; expected {', '.join(names)} (the scenario has {n} agents), and optionally u, b, d_agent0, ..."
        )
    dk = [f"d_agent{i}" for i in range(n)]
    if any(opt[k] is not None for k in dk) and not all(opt[k] is not None for k in dk):
        raise file_error(p, f"key {next(k for k in dk if opt[k] is None)!r}", "missing; measurement offsets need one array per agent")
    d = [opt[k] for k in dk] if opt[dk[0]] is not None else None
    ys = []
    for k in names:
        a = arrs[k]
        if a.dtype.kind not in "fiu":
            raise file_error(p, f"key {k!r}", f"expected numbers (integers or floats), found dtype {a.dtype}{_NPZ_FIX}")
        ys.append(a.astype(float))
    return MeasurementLog.from_arrays(ys, system, horizon, source=str(p), u=opt["u"], b=opt["b"], d=d)


def read_truth(path: str | Path, dx: int, n_steps: int) -> FloatArray:
    """Read the true states x(0..n_steps-1): ``step, x0, x1, ...`` (CSV/Parquet) or NPZ key ``x`` (steps, d_x)."""
    p = Path(path)
    suffix = file_suffix(p, "--truth")
    if not p.exists():
        raise FileNotFoundError(2, "No such file or directory", str(p))
    if suffix == ".npz":
        arrs = _npz_arrays(p)
        if "x" not in arrs:
            raise file_error(
                p, "key 'x'", f"missing; expected the states as an array 'x' of shape ({n_steps}, {dx}) (found {', '.join(arrs) or 'none'})"
            )
        x = arrs["x"]
        if x.dtype.kind not in "fiu":
            raise file_error(p, "key 'x'", f"expected numbers (integers or floats), found dtype {x.dtype}{_NPZ_FIX}")
        x = x.astype(float)
        if x.ndim != 2 or x.shape != (n_steps, dx):
            raise file_error(p, "key 'x'", f"expected shape ({n_steps}, {dx}) (steps of the measurements, d_x), found {x.shape}")
        cells = np.argwhere(~np.isfinite(x))
        if cells.size:
            r, c = (int(v) for v in cells[0])
            raise file_error(p, f"step {r}, column x{c}", f"expected a finite number, found {x[r, c]}")
        return x
    csv = suffix == ".csv"
    df = _read_table(p, suffix)
    want = ["step"] + [f"x{c}" for c in range(dx)]
    for col in df.columns:
        if col not in want:
            raise file_error(p, f"column {col!r}", f"unknown column; expected {', '.join(want)} (d_x = {dx})")
    for col in want:
        if col not in df.columns:
            raise file_error(p, f"column {col!r}", f"missing; expected {', '.join(want)} (d_x = {dx})")
    step = int_column(df, "step", p, csv)
    vals = df[want[1:]].to_numpy(dtype=float)
    cells = np.argwhere(~np.isfinite(vals))
    if cells.size:
        r, c = (int(v) for v in cells[0])
        raise file_error(p, cell_location(r, f"x{c}", csv), f"expected a finite number, found {df[f'x{c}'].iloc[r]!r}")
    bad = np.flatnonzero((step < 0) | (step >= n_steps))
    if bad.size:
        r = int(bad[0])
        raise file_error(p, cell_location(r, "step", csv), f"step {int(step[r])} is outside the measurements' steps 0..{n_steps - 1}")
    x = np.full((n_steps, dx), np.nan)
    seen = np.zeros(n_steps, dtype=bool)
    for r, s in enumerate(step):
        if seen[s]:
            raise file_error(p, cell_location(r, "step", csv), f"duplicated step {int(s)}; one row per step")
        seen[s] = True
    x[step] = vals
    if not seen.all():
        raise file_error(p, "column 'step'", f"step {int(np.flatnonzero(~seen)[0])} has no row; the truth needs every step 0..{n_steps - 1}")
    return x


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
    suffix = fmt if fmt is not None else file_suffix(Path(path), "path")
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
        if hasattr(path, "write"):
            np.savez(path, **arrays)
        else:  # atomically, to the name np.savez would give (".npz" added when missing)
            target = str(path) if str(path).endswith(".npz") else f"{path}.npz"
            write_atomic(target, lambda fh: np.savez(fh, **arrays))
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
    write_frame(pd.DataFrame(cols), path, suffix)


def write_frame(df: Any, path: Any, suffix: str) -> None:
    """Write a DataFrame as CSV (every float with 17 significant digits, round-trip exact) or Parquet, to a path
    (atomically: :func:`teamkf.study.outputs.write_atomic`) or a binary file object."""
    if not hasattr(path, "write"):
        write_atomic(path, lambda fh: write_frame(df, fh, suffix))
        return
    if suffix == ".csv":
        import io

        buf = io.StringIO()
        df.to_csv(buf, index=False, float_format="%.17g")
        path.write(buf.getvalue().encode())
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
    write_frame(estimates_frame(estimates, n_agents), path, suffix)
