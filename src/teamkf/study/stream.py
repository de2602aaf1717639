"""Streaming ``teamkf filter``: long logs in chunks, with bounded memory, through the steady-state forms.

A steady-state design (``horizon`` omitted) of a family that offers
``steady_form()`` (:class:`~teamkf.estimators.steady.SteadyForm`: the
centralized filter, MTMSE, per-agent MMSE) is a linear time-invariant map
from the measurements to the estimates after its warm-up. The file is read
in chunks of rows (CSV through pandas, Parquet by row groups/batches), every
chunk is validated exactly like the in-memory reader (rows numbered in the
whole file), and each estimator carries its state between chunks: the common
predictor x̂ and the last c - 1 measurement rows. The first ``start`` steps
(the exact warm-up gains) are run by the design's online agents. Memory is
O(chunk), independent of the number of steps; the estimates agree with the
online agents to round-off (tests).

Streaming needs the rows sorted by step (the order ``write_measurements``
and loggers produce) and no gaps: missing values have an exact treatment only
for a finite-horizon design (:mod:`teamkf.study.measurements`), which is not
streamed.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator, Sequence

import numpy as np

from .._progress import bar as _progress_bar
from .._validation import FloatArray
from ..exceptions import UnsupportedOperationError
from ..simulation.monte_carlo import team_stage_costs
from .measurements import KnownInputs, known_inputs, online_estimates, read_truth
from .measurements.format import (
    Columns,
    MeasurementFileError,
    cell_location,
    check_columns,
    check_text_file,
    coerce_numeric,
    file_error,
    file_suffix,
    int_column,
    offset_values,
    read_npz,
    validate_rows,
)

__all__ = ["stream_filter", "StreamSummary", "iter_blocks", "SteadyStream"]


# ---------------------------------------------------------------------------
# reading in blocks of whole steps
# ---------------------------------------------------------------------------
def _raw_chunks(p: Path, suffix: str, chunk_rows: int) -> Iterator[Any]:
    import pandas as pd

    if suffix == ".csv":
        check_text_file(p)
        try:
            reader = pd.read_csv(p, skipinitialspace=True, chunksize=chunk_rows)
            for df in reader:
                yield df
        except UnicodeDecodeError as exc:
            raise file_error(p, "", f"expected a UTF-8 text file (CSV), found undecodable bytes at position {exc.start}; save it as UTF-8") from None
        except pd.errors.EmptyDataError:
            raise file_error(p, "", "the file is empty; expected a header row 'step,agent,y0,...'") from None
        except pd.errors.ParserError as exc:
            raise file_error(p, "", f"not a valid CSV file ({' '.join(str(exc).split())})") from None
    else:
        import pyarrow as pa
        import pyarrow.parquet as pq

        try:
            pf = pq.ParquetFile(p, pre_buffer=False)
        except Exception as exc:  # pyarrow's own error types
            raise file_error(p, "", f"not a readable Parquet file ({type(exc).__name__}: {' '.join(str(exc).split())[:200]})") from None
        pool = pa.default_memory_pool()
        for batch in pf.iter_batches(batch_size=chunk_rows):
            df = batch.to_pandas()
            del batch
            pool.release_unused()  # Arrow's allocator keeps freed chunks otherwise: memory would grow with the file
            yield df


@dataclass(frozen=True)
class Block:
    """Whole steps k0, k0+1, ... of a measurement file.

    Y : (steps, Σ d_y^i) stacked measurements (NaN where missing)
    u : (steps, d_u) known inputs, or None;  b : (steps, d_x) process offsets b(t), or None
    d : (steps, Σ d_y^i) stacked measurement offsets d_i(t), or None
    """

    k0: int
    Y: FloatArray
    u: FloatArray | None = None
    b: FloatArray | None = None
    d: FloatArray | None = None


def iter_blocks(path: str | Path, system: Any, *, chunk_rows: int = 400_000, progress: Any = None) -> Iterator[Block]:
    """:class:`Block` s of whole steps from a long-form measurement file (rows sorted by step); NPZ files
    are read whole and sliced."""
    p = Path(path)
    suffix = file_suffix(p, "--measurements")
    if not p.exists():
        raise FileNotFoundError(2, "No such file or directory", str(p))
    n, dys = system.n_agents, system.dy
    offs = system.offsets
    dy = int(sum(dys))
    if suffix == ".npz":
        log = read_npz(p, system, None)
        Y = np.concatenate(log.y, axis=1)
        D = None if log.d is None else np.concatenate(log.d, axis=1)
        steps = max(1, chunk_rows // n)
        for k0 in range(0, log.n_steps, steps):
            if progress is not None:
                progress.update(min(steps, log.n_steps - k0) * n)
            sl = slice(k0, k0 + steps)
            yield Block(k0, Y[sl], None if log.u is None else log.u[sl], None if log.b is None else log.b[sl], None if D is None else D[sl])
        return
    csv = suffix == ".csv"
    row0 = 0
    next_step = 0
    pending: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, int] | None = None  # rows of the last, maybe unfinished step
    spec: Columns | None = None  # the optional columns (u, b per step; d per row, appended to the y values)
    ucols: list[str] = []
    cols: list[str] = []
    seen_rows = False
    m = max(dys)

    def emit(step: np.ndarray, agent: np.ndarray, vals: np.ndarray, u: np.ndarray | None, first_row: int) -> Block:
        nonlocal next_step
        k1 = int(step[-1]) + 1
        B = k1 - next_step
        Y = np.full((B, dy), np.nan)
        key = (step - next_step) * n + agent
        if key.size > 1:
            dup = np.flatnonzero(key[1:] == key[:-1]) if np.all(np.diff(key) >= 0) else np.array([], dtype=int)
            if not np.all(np.diff(key) >= 0):  # same step, agents out of order: sort within the step
                order = np.lexsort((agent, step))
                key, step, agent, vals = key[order], step[order], agent[order], vals[order]
                rows_g = first_row + order
                dup = np.flatnonzero(key[1:] == key[:-1])
            else:
                rows_g = first_row + np.arange(key.size)
            if dup.size:
                r1, r2 = sorted((int(rows_g[dup[0]]), int(rows_g[dup[0] + 1])))
                raise file_error(
                    p,
                    cell_location(r2, "step", csv),
                    f"duplicated (step, agent) = ({int(step[dup[0]])}, {int(agent[dup[0]])}), first at row {r1 + 1}; keep one row per agent and step",
                )
        D = np.full((B, dy), np.nan) if spec is not None and spec.d else None
        for i in range(n):
            rows = agent == i
            Y[step[rows] - next_step, offs[i] : offs[i] + dys[i]] = vals[rows][:, : dys[i]]
            if D is not None:
                D[step[rows] - next_step, offs[i] : offs[i] + dys[i]] = vals[rows][:, m : m + dys[i]]
        U = None
        if u is not None:
            U = np.full((B, u.shape[1]), np.nan)
            U[step - next_step] = u
            if np.isnan(U[:, 0]).any():
                s = next_step + int(np.flatnonzero(np.isnan(U[:, 0]))[0])
                raise file_error(
                    p, f"column {ucols[0]!r}", f"step {s} has no row, so no {ucols[0][0]}({s}); give a row (y cells may be empty) for every step"
                )
        k0 = next_step
        next_step = k1
        nu = len(spec.u) if spec is not None else 0
        return Block(k0, Y, None if U is None or not nu else U[:, :nu], None if U is None or spec is None or not spec.b else U[:, nu:], D)

    for df in _raw_chunks(p, suffix, chunk_rows):
        if spec is None:
            df = coerce_numeric(df, p, csv, row0)
            spec = check_columns(df, p, system)
            ucols = spec.per_step
        else:
            if list(df.columns) != cols:
                raise file_error(p, f"row {row0 + 1}", "the columns changed within the file")
            df = coerce_numeric(df, p, csv, row0)
        cols = list(df.columns)
        if len(df) == 0:
            continue
        seen_rows = True
        step, agent, vals = validate_rows(df, p, system, None, None, csv, row0)
        dv = offset_values(df, spec, p, system, agent, vals, csv, row0)
        if dv is not None:
            vals = np.concatenate([vals, dv], axis=1)
        u = df[ucols].to_numpy(dtype=float) if ucols else None
        if u is not None and not np.all(np.isfinite(u)):
            r, c = (int(v) for v in np.argwhere(~np.isfinite(u))[0])
            raise file_error(
                p,
                cell_location(row0 + r, ucols[c], csv),
                f"expected a finite value, found {u[r, c]} (known inputs u(t) and offsets b(t) cannot be missing)",
            )
        back = np.flatnonzero(np.diff(step) < 0)
        if back.size or (pending is not None and step[0] < pending[0][-1]):
            r = int(back[0]) + 1 if back.size else 0
            prev = int(step[r - 1]) if back.size else int(pending[0][-1])  # type: ignore[index]
            raise file_error(
                p,
                cell_location(row0 + r, "step", csv),
                f"step {int(step[r])} after step {prev}: streaming needs the rows sorted by step; sort the file (or give a horizon)",
            )
        if u is not None:  # one input per step
            same = np.flatnonzero((np.diff(step) == 0) & np.any(np.diff(u, axis=0) != 0, axis=1))
            if same.size:
                r = int(same[0]) + 1
                raise file_error(
                    p,
                    cell_location(row0 + r, ucols[0], csv),
                    f"step {int(step[r])} has different values of {', '.join(ucols)} on different rows; u(t) and b(t) are one value per step",
                )
        if pending is not None:
            ps, pa, pv, pu, pr = pending
            first_row = pr
            step, agent, vals = np.concatenate([ps, step]), np.concatenate([pa, agent]), np.concatenate([pv, vals])
            u = None if u is None else np.concatenate([pu, u])  # type: ignore[list-item]
        else:
            first_row = row0
        last = int(step[-1])
        cut = int(np.searchsorted(step, last, side="left"))
        if cut > 0:
            yield emit(step[:cut], agent[:cut], vals[:cut], None if u is None else u[:cut], first_row)
        pending = (step[cut:], agent[cut:], vals[cut:], None if u is None else u[cut:], first_row + cut)
        row0 += len(df)
        if progress is not None:
            progress.update(len(df))
    if not seen_rows:
        raise file_error(p, "", "no data rows; expected one row per agent and step")
    if pending is not None and pending[0].size:
        yield emit(pending[0], pending[1], pending[2], pending[3], pending[4])


# ---------------------------------------------------------------------------
# one estimator, carried between blocks
# ---------------------------------------------------------------------------
@dataclass
class SteadyStream:
    """Runs one steady-state design block by block (state: x̂ at the next anchor, last c - 1 rows)."""

    design: Any
    form: Any = None
    x: FloatArray | None = None
    hist: FloatArray | None = None
    warm: FloatArray | None = None
    shared: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.form = self.design.steady_form()
        self.x = np.zeros(self.form.M.shape[0])
        self.hist = np.zeros((0, self.form.N.shape[1]))

    def warm_up(self, Y: FloatArray) -> None:
        """z(0 .. start-1) from the design's online agents (the exact warm-up gains); Y holds at least those steps."""
        s = self.form.start
        if s > 0:
            sys = self.design.system
            offs = sys.offsets
            ys = [Y[:s, offs[i] : offs[i + 1]] for i in range(sys.n_agents)]
            self.warm = online_estimates(self.design, ys)

    def predictor(self, k0: int, Yext: FloatArray, h: int, k1: int) -> FloatArray:
        """x̂(a) for the anchors a = max(0, k0-c+1) .. k1-c of this block (updates the carried x̂)."""
        f = self.form
        c = f.lag
        a_lo = max(0, k0 - c + 1)
        n_anch = max(0, k1 - c + 1 - a_lo)
        X = np.empty((n_anch, f.M.shape[0]))
        if n_anch:
            first = a_lo - (k0 - h)
            U = Yext[first : first + n_anch] @ f.N.T
            self.x = _linear_recurrence(f.M, U, self.x, X)  # type: ignore[arg-type]
        return X

    def block(self, k0: int, Y: FloatArray, X_cache: dict[bytes, Any]) -> FloatArray:
        """Estimates (B, n d_z) of the steps k0 .. k0+B-1."""
        f = self.form
        c = f.lag
        B = Y.shape[0]
        k1 = k0 + B
        h = self.hist.shape[0]  # type: ignore[union-attr]
        Yext = np.concatenate([self.hist, Y]) if h else Y
        key = f.M.tobytes() + f.N.tobytes() + bytes([c % 256]) + c.to_bytes(8, "little")
        if key in X_cache:  # the same predictor as another estimator of this run (centralized, MTMSE, MMSE share K̄)
            X, self.x = X_cache[key]
        else:
            X = self.predictor(k0, Yext, h, k1)
            X_cache[key] = (X, self.x)
        a_lo = max(0, k0 - c + 1)
        Z = np.empty((B, f.G.shape[0]))
        lo = max(k0, f.start)
        if lo < k1:
            Zs = X[lo - c + 1 - a_lo : k1 - c + 1 - a_lo] @ f.G.T
            for l in range(c):
                if np.any(f.H[l]):
                    Zs += Yext[lo - l - (k0 - h) : k1 - l - (k0 - h)] @ f.H[l].T
            Z[lo - k0 :] = Zs
        if k0 < f.start:
            Z[: min(f.start, k1) - k0] = self.warm[k0 : min(f.start, k1)]  # type: ignore[index]
        self.hist = Yext[max(0, Yext.shape[0] - (c - 1)) :] if c > 1 else Yext[:0]
        return Z


def _linear_recurrence(M: FloatArray, U: FloatArray, x0: FloatArray, X: FloatArray, block: int = 32) -> FloatArray:
    """X[r] = x(r) for x(r+1) = M x(r) + U[r], x(0) = x0; returns x(len(U)).

    Blocked: inside a block of b steps x(j) = M^j x(s) + Σ_{q<j} M^{j-1-q} U[s+q], one
    matrix product for every block at once; the block starts are propagated in a short
    loop (len(U)/b steps). The same numbers as the step-by-step loop up to round-off.
    """
    n, d = U.shape
    nb = n // block
    x = np.array(x0, dtype=float)
    if nb >= 2:
        P = [np.eye(d)]
        for _ in range(block):
            P.append(M @ P[-1])
        Tb = np.zeros((block * d, block * d))  # row block j, column block q: M^{j-1-q} for q < j
        for j in range(block):
            for q in range(j):
                Tb[j * d : (j + 1) * d, q * d : (q + 1) * d] = P[j - 1 - q]
        Pj = np.stack(P[:block])  # (b, d, d): M^j
        Ub = U[: nb * block].reshape(nb, block * d)
        part = (Ub @ Tb.T).reshape(nb, block, d)  # zero-start responses
        last = part[:, -1] @ M.T + U[block - 1 : nb * block : block]  # x(start of next block) - M^b x(start)
        Mb = P[block]
        starts = np.empty((nb, d))
        for b in range(nb):
            starts[b] = x
            x = Mb @ x + last[b]
        X[: nb * block] = (part + np.einsum("jab,nb->nja", Pj, starts)).reshape(nb * block, d)
    MT = M.T
    for r in range(nb * block if nb >= 2 else 0, n):
        X[r] = x
        x = x @ MT + U[r]
    return x


# ---------------------------------------------------------------------------
# the driver
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class StreamSummary:
    """What a streaming run did: steps, rows read and written, realized total costs (with a truth)."""

    n_steps: int
    rows_in: int
    rows_out: int
    estimators: tuple[str, ...]
    total_costs: dict[str, float] | None = None

    def summary(self) -> dict[str, Any]:
        from ..estimators.base import json_float

        out: dict[str, Any] = {
            "steps": self.n_steps,
            "rows_in": self.rows_in,
            "rows_out": self.rows_out,
            "estimators": list(self.estimators),
            "streamed": True,
        }
        if self.total_costs is not None:
            out["total_cost"] = {k: json_float(v) for k, v in self.total_costs.items()}
        return out


class _Writer:
    """Long-form estimates (and per-step costs) appended block by block, CSV or Parquet (pyarrow)."""

    def __init__(self, fh: Any, fmt: str, columns: Sequence[str]):
        self.fh, self.fmt, self.columns = fh, fmt, list(columns)
        self.w: Any = None

    def write(self, cols: dict[str, Any]) -> None:
        import pyarrow as pa

        table = pa.table(cols)
        if self.fmt == ".csv":
            import pyarrow.csv as pacsv

            if self.w is None:
                self.w = pacsv.CSVWriter(self.fh, table.schema)
            self.w.write_table(table)
        else:
            import pyarrow.parquet as pq

            if self.w is None:
                self.w = pq.ParquetWriter(self.fh, table.schema)
            self.w.write_table(table)

    def close(self) -> None:
        if self.w is not None:
            self.w.close()


def _first_missing(k0: int, Y: FloatArray, system: Any) -> tuple[int, int] | None:
    bad = np.argwhere(np.isnan(Y))
    if not bad.size:
        return None
    r, col = (int(v) for v in bad[0])
    agent = int(np.searchsorted(system.offsets, col, side="right") - 1)
    return agent, k0 + r


def stream_filter(
    scenario: Any,
    measurements: str | Path,
    out: Any,
    *,
    fmt: str,
    estimators: Sequence[str] | None = None,
    truth: str | Path | None = None,
    cost_out: Any = None,
    chunk_rows: int = 400_000,
    progress: bool | None = None,
) -> StreamSummary:
    """Filter a long measurement file in chunks with the scenario's steady-state designs.

    Parameters
    ----------
    scenario : a steady-state Scenario (``horizon`` None)
    measurements : CSV, Parquet (streamed) or NPZ (read whole) file
    out : open binary file for the estimates (``step, agent, estimator, z0, ...``)
    fmt : ".csv" or ".parquet"
    truth : states file (read whole: d_x numbers per step), optional
    cost_out : open binary file for the per-step realized costs (with ``truth``)
    chunk_rows : rows read per chunk (memory ~ chunk_rows × (d_y + estimators × d_z) numbers)
    progress : the package's progress bar (:mod:`teamkf._progress`; None: only on a terminal)
    """
    names = list(scenario.estimators if estimators is None else estimators)
    if scenario.horizon is not None:
        raise UnsupportedOperationError("filter", "streaming a finite-horizon scenario", "omit horizon (steady-state designs) to stream")
    streams = []
    for name in names:
        scenario.family(name).require(
            "steady_form", "streaming a file through its steady-state LTI form (give the scenario a horizon to filter in memory)"
        )
        streams.append(SteadyStream(scenario.design(name)))
    system, cost = scenario.system, scenario.cost
    n, dz = system.n_agents, cost.dz
    known: KnownInputs | None = known_inputs(scenario)
    x_true = None
    costs_tot = {name: 0.0 for name in names} if truth is not None else None
    bar = _progress_bar(None, desc="teamkf filter", unit=" rows", unit_scale=True, enabled=progress)
    writer = _Writer(out, fmt, ["step", "agent", "estimator"] + [f"z{c}" for c in range(dz)])
    cwriter = _Writer(cost_out, fmt, ["step", "estimator", "cost"]) if cost_out is not None else None
    m_next = None if known is None else known.x0_mean.copy()
    rows_in = rows_out = 0
    T = 0
    buffer: list[tuple[int, FloatArray, FloatArray | None]] = []
    need = max(s.form.start for s in streams)
    warmed = False
    L = cost.L_at(0)
    try:
        for blk in iter_blocks(measurements, system, chunk_rows=chunk_rows, progress=bar):
            k0, Y = blk.k0, blk.Y
            miss = _first_missing(k0, Y, system)
            if miss is not None:
                raise UnsupportedOperationError(
                    names[0],
                    "streaming measurements with missing values",
                    f"the first missing measurement is agent {miss[0]} at step {miss[1]} (in {measurements}); missing values are filtered "
                    "exactly only by a finite-horizon design: give the scenario a horizon (streaming also needs the rows sorted by step)",
                )
            rows_in += Y.shape[0] * n
            if known is None and (blk.b is not None or blk.d is not None):  # the log's own offsets: zero means otherwise
                known = KnownInputs.zero(system)
                m_next = known.x0_mean.copy()
            if known is not None:
                Y, m_block, m_next = _centre(known, system, blk, m_next)  # type: ignore[arg-type]
            elif blk.u is not None:
                raise MeasurementFileError(
                    f"{measurements}: u columns: the scenario has no input matrix (system.B or agents[i].D) to use them", argument="u"
                )
            else:
                m_block = None
            if not warmed:  # the warm-up steps need the first `need` steps at once
                buffer.append((k0, Y, m_block))
                if sum(b[1].shape[0] for b in buffer) < need:
                    continue
                k0, Y = buffer[0][0], np.concatenate([b[1] for b in buffer])
                m_block = None if known is None else np.concatenate([b[2] for b in buffer])  # type: ignore[misc]
                buffer = []
                for s in streams:
                    s.warm_up(Y)
                warmed = True
            T = k0 + Y.shape[0]
            B = Y.shape[0]
            X_cache: dict[bytes, Any] = {}
            Z = np.stack([s.block(k0, Y, X_cache) for s in streams], axis=1)  # (B, E, n dz)
            if m_block is not None:
                Z = Z + (m_block @ L.T)[:, None, :]
            _write_block(writer, names, k0, Z, n, dz)
            rows_out += B * n * len(names)
            _release_arrow()
            if costs_tot is not None:
                if x_true is None:
                    x_true = _TruthStream(truth, system.dx, max(1, chunk_rows // n))
                X = x_true.get(k0, B)
                E = (X @ L.T)[:, None, :] - Z
                c = team_stage_costs(cost, E.transpose(1, 0, 2)).T  # (B, estimators), as the Monte Carlo evaluates it
                for e, name in enumerate(names):
                    costs_tot[name] += float(np.sum(c[:, e]))
                if cwriter is not None:
                    cwriter.write(
                        {
                            "step": np.repeat(np.arange(k0, k0 + B), len(names)),
                            "estimator": _names_column(names, B),
                            "cost": c.ravel(),
                        }
                    )
        if not warmed and buffer:  # a log shorter than the warm-up
            k0, Y = buffer[0][0], np.concatenate([b[1] for b in buffer])
            m_block = None if known is None else np.concatenate([b[2] for b in buffer])  # type: ignore[misc]
            for s in streams:
                s.warm_up(np.concatenate([Y, np.zeros((need, Y.shape[1]))]))
            Z = np.stack([s.warm[: Y.shape[0]] for s in streams], axis=1)  # type: ignore[index]
            if m_block is not None:
                Z = Z + (m_block @ L.T)[:, None, :]
            _write_block(writer, names, k0, Z, n, dz)
            T = Y.shape[0]
            rows_out += T * n * len(names)
            if costs_tot is not None:
                x_true = _TruthStream(truth, system.dx, max(1, chunk_rows // n))
                X = x_true.get(0, T)
                E = (X @ L.T)[:, None, :] - Z
                c = team_stage_costs(cost, E.transpose(1, 0, 2)).T  # (B, estimators), as the Monte Carlo evaluates it
                for e, name in enumerate(names):
                    costs_tot[name] += float(np.sum(c[:, e]))
                if cwriter is not None:
                    cwriter.write({"step": np.repeat(np.arange(T), len(names)), "estimator": _names_column(names, T), "cost": c.ravel()})
    finally:
        writer.close()
        if cwriter is not None:
            cwriter.close()
        bar.close()
    if x_true is not None:
        x_true.finish(T)
    return StreamSummary(T, rows_in, rows_out, tuple(names), costs_tot)


def _centre(known: KnownInputs, system: Any, blk: Block, m_next: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Subtract the measurement means of a block; returns (centred Y, state means of the block, m at the next step)."""
    Y, U = blk.Y, blk.u
    B = Y.shape[0]
    offs, dys = system.offsets, system.dy
    d_log = None if blk.d is None else [blk.d[:, offs[i] : offs[i] + dys[i]] for i in range(system.n_agents)]
    b, d = known.offsets(B, blk.b, d_log)
    if known.B is not None or known.D is not None:
        if U is None:
            if known.u is None:
                raise MeasurementFileError("u: the scenario has B/D but no inputs; give system.u or u columns in the measurements", argument="u")
            U = np.broadcast_to(known.u, (B, known.u.shape[0]))
        elif known.u is not None:
            raise MeasurementFileError("u: given both as system.u in the scenario and as u columns of the measurements; keep one", argument="u")
    A = system.A_at(0)
    m = np.empty((B, system.dx))
    x = m_next
    for t in range(B):
        m[t] = x
        x = A @ x + b[t]
        if known.B is not None:
            x = x + known.B @ U[t]  # type: ignore[index]
    C = system.C_stack(0)
    ybar = m @ C.T + np.concatenate(d, axis=1)
    if known.D is not None:
        ybar = ybar + U @ np.vstack(known.D).T  # type: ignore[operator]
    return Y - ybar, m, x


def _write_block(writer: _Writer, names: Sequence[str], k0: int, Z: FloatArray, n: int, dz: int) -> None:
    """Rows ordered by step, agent, estimator (as the in-memory writer)."""
    B, E = Z.shape[0], Z.shape[1]
    zz = Z.reshape(B, E, n, dz).transpose(0, 2, 1, 3).reshape(B * n * E, dz)
    cols: dict[str, Any] = {
        "step": np.repeat(np.arange(k0, k0 + B, dtype=np.int64), n * E),
        "agent": np.tile(np.repeat(np.arange(n, dtype=np.int64), E), B),
        "estimator": _names_column(names, B * n),
    }
    cols.update({f"z{c}": zz[:, c] for c in range(dz)})
    writer.write(cols)


def _release_arrow() -> None:
    import pyarrow as pa

    pa.default_memory_pool().release_unused()


def _names_column(names: Sequence[str], repeats: int) -> Any:
    """The estimator names repeated, as an Arrow string column (built in C++, not as Python objects)."""
    import pyarrow as pa

    idx = pa.array(np.tile(np.arange(len(names), dtype=np.int32), repeats))
    return pa.DictionaryArray.from_arrays(idx, pa.array(list(names), pa.string())).cast(pa.string())


class _TruthStream:
    """The true states read forward in chunks (CSV/Parquet rows ``step, x0, ...`` sorted by step; NPZ read whole)."""

    def __init__(self, truth: Any, dx: int, chunk_rows: int):
        self.p = Path(truth)
        self.dx = dx
        suffix = file_suffix(self.p, "--truth")
        if not self.p.exists():
            raise FileNotFoundError(2, "No such file or directory", str(self.p))
        self.csv = suffix == ".csv"
        self.buf = np.zeros((0, dx))
        self.k_buf = 0  # step of buf[0]
        self.row0 = 0
        self.n_steps: int | None = None
        if suffix == ".npz":
            with np.load(self.p, allow_pickle=False) as z:
                n = int(z["x"].shape[0]) if "x" in z.files else 0
            self.buf = read_truth(self.p, dx, n)
            self.chunks: Iterator[Any] = iter(())
        else:
            self.chunks = _raw_chunks(self.p, suffix, chunk_rows)
        self.want = ["step"] + [f"x{c}" for c in range(dx)]

    def _pull(self) -> bool:
        for df in self.chunks:
            df = coerce_numeric(df, self.p, self.csv, self.row0)
            for col in df.columns:
                if col not in self.want:
                    raise file_error(self.p, f"column {col!r}", f"unknown column; expected {', '.join(self.want)} (d_x = {self.dx})")
            for col in self.want:
                if col not in df.columns:
                    raise file_error(self.p, f"column {col!r}", f"missing; expected {', '.join(self.want)} (d_x = {self.dx})")
            if len(df) == 0:
                continue
            step = int_column(df, "step", self.p, self.csv, self.row0)
            expect = self.k_buf + self.buf.shape[0] + np.arange(len(step))
            bad = np.flatnonzero(step != expect)
            if bad.size:
                r = int(bad[0])
                raise file_error(
                    self.p,
                    cell_location(self.row0 + r, "step", self.csv),
                    f"expected step {int(expect[r])}, found {int(step[r])}: streaming needs one row per step, sorted by step",
                )
            vals = df[self.want[1:]].to_numpy(dtype=float)
            bad2 = np.argwhere(~np.isfinite(vals))
            if bad2.size:
                r, c = (int(v) for v in bad2[0])
                raise file_error(self.p, cell_location(self.row0 + r, f"x{c}", self.csv), f"expected a finite number, found {vals[r, c]}")
            self.buf = np.concatenate([self.buf, vals])
            self.row0 += len(df)
            return True
        return False

    def get(self, k0: int, B: int) -> FloatArray:
        drop = k0 - self.k_buf
        if drop > 0:
            self.buf, self.k_buf = self.buf[drop:], k0
        while self.buf.shape[0] < B:
            if not self._pull():
                raise MeasurementFileError(
                    f"{self.p}: step {self.k_buf + self.buf.shape[0]} has no row; the truth needs every step of the measurements", argument="--truth"
                )
        return self.buf[:B]

    def finish(self, T: int) -> None:
        """Raise when the truth has more steps than the measurements."""
        extra = self.k_buf + self.buf.shape[0] > T or self._pull()
        if extra:
            raise MeasurementFileError(
                f"{self.p}: has steps beyond the measurements' last step {T - 1}; give the truth of the same steps", argument="--truth"
            )
