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

from .. import _validation as V
from .._validation import FloatArray
from ..exceptions import TeamkfError, UnsupportedOperationError
from ..models import LinearGaussianSystem

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
    """

    y: list[FloatArray]
    source: str = "<arrays>"

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
    def from_arrays(cls, y: Sequence[Any], system: LinearGaussianSystem, horizon: int | None = None, source: str = "<arrays>") -> "MeasurementLog":
        """Validate per-agent arrays (n_steps, d_y^i) with NaN for missing values."""
        n = system.n_agents
        if not isinstance(y, (list, tuple)) or len(y) != n:
            raise MeasurementFileError(
                f"{source}: expected {n} arrays (one per agent), found {len(y) if isinstance(y, (list, tuple)) else type(y).__name__}"
            )
        ys = []
        for i, yi in enumerate(y):
            try:
                a = np.asarray(yi, dtype=float)
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
        return cls(ys, source)


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
            df = pd.read_csv(path, skipinitialspace=True)
        except pd.errors.EmptyDataError:
            raise _fmt_err(path, "", "the file is empty; expected a header row 'step,agent,y0,...'") from None
        except pd.errors.ParserError as exc:
            raise _fmt_err(path, "", f"not a valid CSV file ({' '.join(str(exc).split())})") from None
        first_line = 2
    else:
        try:
            df = pd.read_parquet(path)
        except Exception as exc:  # pyarrow raises its own types for a corrupt file
            raise _fmt_err(path, "", f"not a readable Parquet file ({type(exc).__name__}: {' '.join(str(exc).split())[:200]})") from None
        first_line = None
    for col in df.columns:
        if not isinstance(col, str):
            raise _fmt_err(path, f"column {col!r}", "expected string column names")
        s = df[col]
        if s.dtype.kind not in "fiub":
            num = pd.to_numeric(s, errors="coerce")
            bad = np.flatnonzero(num.isna().to_numpy() & s.notna().to_numpy())
            if bad.size:
                r = int(bad[0])
                line = f" (line {r + first_line})" if first_line else ""
                raise _fmt_err(path, f"row {r + 1}{line}, column {col!r}", f"expected a number, found {s.iloc[r]!r}")
            df[col] = num.astype(float)
    return df


def _where(r: int, col: str, csv: bool) -> str:
    return f"row {r + 1}" + (f" (line {r + 2})" if csv else "") + f", column {col!r}"


def _int_column(df: Any, col: str, path: Path, csv: bool) -> np.ndarray:
    a = df[col].to_numpy(dtype=float)
    bad = np.flatnonzero(~np.isfinite(a) | (a != np.round(a)))
    if bad.size:
        r = int(bad[0])
        raise _fmt_err(path, _where(r, col, csv), f"expected a whole number, found {df[col].iloc[r]!r}")
    return a.astype(np.int64)


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
    n, dys = system.n_agents, system.dy
    m = max(dys)
    want = ["step", "agent"] + [f"y{c}" for c in range(m)]
    for col in df.columns:
        if col not in want:
            extra = (
                f"; the model has max d_y = {m}, so the columns are {', '.join(want)}"
                if col.startswith("y")
                else f"; expected the columns {', '.join(want)}"
            )
            raise _fmt_err(p, f"column {col!r}", f"unknown column{extra}")
    for col in want:
        if col not in df.columns:
            raise _fmt_err(p, f"column {col!r}", f"missing; expected the columns {', '.join(want)} (one y column per measurement component)")
    if len(df) == 0:
        raise _fmt_err(p, "", "no data rows; expected one row per agent and step")
    step = _int_column(df, "step", p, csv)
    agent = _int_column(df, "agent", p, csv)
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
            f"duplicated (step, agent) = ({int(step[r2])}, {int(agent[r2])}), first at row {r1 + 1}; keep one row per agent and step",
        )
    vals = df[[f"y{c}" for c in range(m)]].to_numpy(dtype=float)
    bad = np.argwhere(np.isinf(vals))
    if bad.size:
        r, c = (int(v) for v in bad[0])
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
    T = n_steps if n_steps is not None else int(step.max()) + 1
    ys = []
    for i in range(n):
        a = np.full((T, dys[i]), np.nan)
        rows = agent == i
        a[step[rows]] = vals[rows][:, : dys[i]]
        ys.append(a)
    return MeasurementLog.from_arrays(ys, system, horizon, source=str(p))


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
    extra = [k for k in arrs if k not in names]
    if extra:
        raise _fmt_err(p, f"key {extra[0]!r}", f"unknown array; expected {', '.join(names)} (the scenario has {n} agents)")
    ys = []
    for k in names:
        a = arrs[k]
        if a.dtype.kind not in "fiub":
            raise _fmt_err(p, f"key {k!r}", f"expected numbers, found dtype {a.dtype}")
        ys.append(a.astype(float))
    return MeasurementLog.from_arrays(ys, system, horizon, source=str(p))


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
        bad = np.argwhere(~np.isfinite(x))
        if bad.size:
            r, c = (int(v) for v in bad[0])
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
    bad = np.argwhere(~np.isfinite(vals))
    if bad.size:
        r, c = (int(v) for v in bad[0])
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
def write_measurements(path: str | Path | Any, y: Sequence[Any], *, fmt: str | None = None) -> None:
    """Write per-agent measurements (n_steps, d_y^i) (NaN = missing) in long form (CSV/Parquet) or NPZ.

    ``path`` may be an open binary file when ``fmt`` (".csv", ".parquet", ".npz") is given.
    A CSV/Parquet file has a row for every (step, agent) with at least one value.
    """
    suffix = fmt if fmt is not None else _suffix(Path(path), "path")
    ys = [np.asarray(a, dtype=float) for a in y]
    if suffix == ".npz":
        np.savez(path, **{f"agent{i}": a for i, a in enumerate(ys)})
        return
    pd = _pandas()
    m = max(a.shape[1] for a in ys)
    T = ys[0].shape[0]
    blocks = []
    for i, a in enumerate(ys):
        full = np.full((T, m), np.nan)
        full[:, : a.shape[1]] = a
        keep = ~np.isnan(a).all(axis=1)
        blocks.append((np.flatnonzero(keep), np.full(int(keep.sum()), i), full[keep]))
    step = np.concatenate([b[0] for b in blocks])
    agent = np.concatenate([b[1] for b in blocks])
    vals = np.concatenate([b[2] for b in blocks])
    order = np.lexsort((agent, step))
    df = pd.DataFrame({"step": step[order], "agent": agent[order], **{f"y{c}": vals[order, c] for c in range(m)}})
    _write_frame(df, path, suffix)


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

    fam = get_family(name, "estimators")
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
        return out


def realized_costs(cost: Any, x: FloatArray, z: FloatArray) -> FloatArray:
    """c(k) = (L(k) x(k) - z(k))' S(k) (L(k) x(k) - z(k)) for one run (n_steps,) or a batch (n_runs, n_steps)."""
    single = x.ndim == 2
    xb, zb = (x[None], z[None]) if single else (x, z)
    T = xb.shape[1]
    c = np.empty((xb.shape[0], T))
    for k in range(T):
        e = xb[:, k] @ cost.L_at(k).T - zb[:, k]
        c[:, k] = np.einsum("ra,ab,rb->r", e, cost.S_at(k), e)
    return c[0] if single else c


def online_estimates(design: Any, ys: Sequence[FloatArray]) -> FloatArray:
    """One run's estimates (n_steps, n d_z) from the design's online agents, exactly as the Monte Carlo
    ``path="runtime"`` computes them (message passing over the design's graph, or delivery by its
    information structure); ``design.filter`` for a design without online agents (the ideal KCF)."""
    from ..simulation.monte_carlo import runtime_estimates

    batch = [np.asarray(y, dtype=float)[None] for y in ys]
    try:
        return np.asarray(runtime_estimates(design, batch))[0]
    except UnsupportedOperationError:
        return np.asarray(design.filter(list(ys)))


def filter_log(scenario: Any, log: MeasurementLog | Sequence[Any], *, estimators: Sequence[str] | None = None, truth: Any = None) -> FilterResult:
    """Run every estimator of ``scenario`` (or ``estimators``) on a recorded log.

    Parameters
    ----------
    scenario : Scenario
    log : MeasurementLog, or per-agent (n_steps, d_y^i) arrays (NaN = missing)
    estimators : names (default: the scenario's)
    truth : (n_steps, d_x) states, or None

    Returns
    -------
    FilterResult
    """
    if not isinstance(log, MeasurementLog):
        log = MeasurementLog.from_arrays(log, scenario.system, scenario.horizon)
    names = list(scenario.estimators if estimators is None else estimators)
    ys = log.filled()
    est: dict[str, FloatArray] = {}
    designs: dict[str, Any] = {}
    for name in names:
        d = design_for_log(scenario, name, log)
        designs[name] = d
        with np.errstate(over="ignore", invalid="ignore"):
            est[name] = online_estimates(d, ys)
    costs = None
    if truth is not None:
        x = V.as_float_array(truth, "truth")
        if x.shape != (log.n_steps, scenario.system.dx):
            raise MeasurementFileError(f"truth: expected shape ({log.n_steps}, {scenario.system.dx}) (steps, d_x), found {x.shape}", argument="truth")
        with np.errstate(over="ignore", invalid="ignore"):
            costs = {name: realized_costs(scenario.cost, x, z) for name, z in est.items()}
    return FilterResult(est, scenario.system.n_agents, costs, designs)
