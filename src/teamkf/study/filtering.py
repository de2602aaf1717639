"""The workflow of ``teamkf filter``: a recorded log in, estimate (and realized-cost) files out, atomically.

Finite-horizon scenarios are filtered in memory (:func:`~teamkf.study.measurements.filter_log`); steady-state
ones are streamed through the families' LTI forms in chunks (:func:`~teamkf.study.stream.stream_filter`),
with bounded memory. The command line only parses its flags and prints :class:`FilterRun`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..exceptions import ArgumentError
from . import measurements as M
from .outputs import write_atomic

__all__ = ["FilterRun", "filter_to_files"]


@dataclass(frozen=True)
class FilterRun:
    """What one ``teamkf filter`` wrote: a JSON summary and the lines a terminal shows."""

    summary: dict[str, Any]
    lines: list[str] = field(default_factory=list)
    total_costs: dict[str, float] | None = None


def filter_to_files(
    scenario: Any,
    measurements: str | Path,
    out: Path,
    *,
    estimators: Sequence[str],
    truth: str | Path | None = None,
    cost_out: Path | None = None,
    chunk_rows: int = 400_000,
) -> FilterRun:
    """Filter ``measurements`` with every estimator, write the estimates to ``out`` (and, with ``truth``, the
    per-step realized team costs to ``cost_out``), each through a temporary file renamed at the end."""
    names = list(estimators)
    for k, name in enumerate(names):
        if name in names[:k]:  # two columns of estimates under one name would be silently merged
            raise ArgumentError(f"estimators: {name!r} is listed twice (--estimators); list each estimator once", argument="estimators")
    fmt = out.suffix.lower()
    head = {"scenario": scenario.name, "measurements": str(measurements), "out": str(out)}
    if cost_out is not None:
        head["cost_out"] = str(cost_out)
    if scenario.horizon is None:  # steady-state designs: stream the file in chunks (bounded memory)
        return _streamed(scenario, measurements, out, fmt, names, truth, cost_out, chunk_rows, head)
    log = M.read_measurements(measurements, scenario.system, scenario.horizon)
    x = M.read_truth(truth, scenario.system.dx, log.n_steps) if truth is not None else None
    res = M.filter_log(scenario, log, estimators=names, truth=x)
    write_atomic(out, lambda fh: M.write_estimates(fh, res.estimates, res.n_agents, fmt=fmt))
    if cost_out is not None and res.stage_costs is not None:
        from .. import _validation as V

        pd = V.require("pandas", "dask")
        T = log.n_steps
        frame = pd.concat([pd.DataFrame({"step": np.arange(T), "estimator": n, "cost": c}) for n, c in res.stage_costs.items()], ignore_index=True)
        write_atomic(cost_out, lambda fh: M.write_frame(frame, fh, fmt))
    lines = []
    if res.loglik is not None:
        ll = f"{res.loglik:.6f}" if np.isfinite(res.loglik) else f"{res.loglik} (non-finite: a measurement lies far outside what the model predicts)"
        lines.append(f"log-likelihood of the data under the centralized filter: {ll}")
    gaps = "no gaps" if not log.has_gaps else f"{sum(int(np.isnan(y).any(axis=1).sum()) for y in log.y)} agent-steps with missing values"
    lines.append(f"{scenario.name}: {log.n_steps} steps, {res.n_agents} agents ({gaps}); estimates of {', '.join(names)} written to {out}")
    return FilterRun({**head, **res.summary()}, lines, res.total_costs)


def _streamed(
    scenario: Any, measurements: Any, out: Path, fmt: str, names: list[str], truth: Any, cost_out: Path | None, chunk_rows: int, head: dict[str, Any]
) -> FilterRun:
    from .stream import stream_filter

    done: dict[str, Any] = {}

    def run(fh: Any, ch: Any = None) -> None:
        done["summary"] = stream_filter(
            scenario, measurements, fh, fmt=fmt, estimators=names, truth=truth, cost_out=ch, chunk_rows=chunk_rows, progress=None
        )

    if cost_out is not None:
        write_atomic(out, lambda fh: write_atomic(cost_out, lambda ch: run(fh, ch)))
    else:
        write_atomic(out, run)
    s = done["summary"]
    line = (
        f"{scenario.name}: {s.n_steps} steps streamed (steady-state gains), {s.rows_in} measurement rows; "
        f"{s.rows_out} estimate rows of {', '.join(names)} written to {out}"
    )
    return FilterRun({**head, **s.summary()}, [line], s.total_costs)
