"""ROS 2 recordings (MCAP) in ``teamkf filter``, and ``teamkf measurements convert``.

An MCAP recording is turned into the log ``teamkf filter`` reads (an NPZ of exactly the recorded float64
values, in a temporary folder) through the topic map (:mod:`teamkf.study.measurements.mcap_source`), and
filtered by the one path every log takes (:func:`teamkf.study.filtering.filter_to_files`), in memory or
streamed; estimates asked as ``.mcap`` are written by that path as a temporary CSV (17 significant digits,
read back exactly) and then as ROS 2 topics (:mod:`teamkf.study.measurements.mcap_write`). So the estimates
from a recording equal, bit for bit, those from the same measurements as a table.

The command-line parsers are in :mod:`teamkf.study.recording_args` (light: nothing of this module or of
MCAP is imported until a command runs).
"""

from __future__ import annotations

import argparse
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator, Sequence

from ..exceptions import ArgumentError, TeamkfError
from .outputs import check_output, write_atomic

__all__ = ["filter_to_files", "filter_recording", "cmd_convert"]


def filter_to_files(
    scenario: Any,
    measurements: str | Path,
    out: Path,
    *,
    estimators: Sequence[str],
    truth: str | Path | None = None,
    cost_out: Path | None = None,
    chunk_rows: int = 400_000,
    topic_map: str | Path | None = None,
) -> Any:
    """:func:`teamkf.study.filtering.filter_to_files` (what ``teamkf filter`` runs), with MCAP: a recording as
    ``measurements`` or ``truth``, or estimates ``out`` ending in ``.mcap``, through the topic map ``topic_map``
    (:func:`filter_recording`)."""
    from . import filtering
    from .measurements.mcap_source import is_mcap

    if is_mcap(measurements) or is_mcap(truth) or out.suffix.lower() == ".mcap":
        return filter_recording(
            scenario, measurements, out, estimators=estimators, truth=truth, cost_out=cost_out, chunk_rows=chunk_rows, topic_map=topic_map
        )
    if topic_map is not None:
        raise ArgumentError(
            "--map: a topic map is for an MCAP recording (--measurements or --truth REC.mcap) or MCAP estimates (--out EST.mcap); drop it",
            argument="--map",
        )
    return filtering.filter_to_files(scenario, measurements, out, estimators=estimators, truth=truth, cost_out=cost_out, chunk_rows=chunk_rows)


def _need_map(topic_map: Any, what: str) -> Any:
    from .measurements.mcap_source import read_map, require_ros

    require_ros()
    if topic_map is None:
        raise ArgumentError(f"--map: {what} needs a topic map (--map MAP.toml: period, start, [[topics]] topic, agent, fields)", argument="--map")
    return read_map(topic_map)


@contextmanager
def _renamed(tmp: str, name: str) -> Iterator[None]:
    """Errors that name the temporary log name the recording instead."""
    try:
        yield
    except TeamkfError as exc:
        text = str(exc)
        if tmp in text:
            exc.args = (text.replace(tmp, name), *exc.args[1:])
            exc.detail = exc.detail.replace(tmp, name)
        raise


def filter_recording(
    scenario: Any,
    measurements: str | Path,
    out: Path,
    *,
    estimators: Sequence[str],
    truth: str | Path | None = None,
    cost_out: Path | None = None,
    chunk_rows: int = 400_000,
    topic_map: str | Path | None = None,
) -> Any:
    """``teamkf filter`` with an MCAP recording in (``measurements`` or ``truth``) or MCAP estimates out (see the module docstring)."""
    import numpy as np

    from . import measurements as M
    from .filtering import FilterRun
    from .measurements.mcap_source import check_sizes, is_mcap, read_recorded_truth, read_recording
    from .measurements.mcap_write import write_estimates_mcap

    what = f"the recording {measurements}" if is_mcap(measurements) else f"the recording {truth}" if is_mcap(truth) else f"--out {out}"
    tmap = _need_map(topic_map, what)
    sys_ = scenario.system
    mcap_out = out.suffix.lower() == ".mcap"
    with tempfile.TemporaryDirectory(prefix="teamkf-mcap-") as tmp:
        log_path, start_ns = str(measurements), tmap.start_ns
        if is_mcap(measurements):
            check_sizes(tmap, sys_)
            rec = read_recording(measurements, tmap, horizon=scenario.horizon)
            log_path = str(Path(tmp) / "measurements.npz")
            M.write_measurements(log_path, rec.y)
            start_ns, T = rec.start_ns, rec.n_steps
        else:
            T = M.read_measurements(measurements, sys_, scenario.horizon).n_steps
        start_ns = 0 if start_ns is None else start_ns
        truth_path = truth
        if is_mcap(truth):
            x = read_recorded_truth(str(truth), tmap, start_ns, T)
            if x.shape[1] != sys_.dx:
                raise ArgumentError(
                    f"{tmap.source}: truth: its fields add up to {x.shape[1]} but the state has d_x = {sys_.dx} values", argument="--map"
                )
            truth_path = str(Path(tmp) / "truth.npz")
            np.savez(truth_path, x=x)
        est_path = Path(tmp) / "estimates.csv" if mcap_out else out
        cost_path = (Path(tmp) / "estimates-cost.csv" if mcap_out else cost_out) if truth is not None else None
        with _renamed(str(Path(tmp) / "measurements.npz"), str(measurements)), _renamed(str(Path(tmp) / "truth.npz"), str(truth)):
            run = _plain(scenario, log_path, est_path, estimators=estimators, truth=truth_path, cost_out=cost_path, chunk_rows=chunk_rows)
        if not mcap_out:
            return _relabel(run, {log_path: str(measurements)}, FilterRun)
        z, costs = _read_back(est_path, cost_path, sys_.n_agents)
        xt = None if truth_path is None else M.read_truth(truth_path, sys_.dx, next(iter(z.values())).shape[0])
        write_atomic(out, lambda fh: write_estimates_mcap(fh, z, sys_.n_agents, start_ns=start_ns, period_ns=tmap.period_ns, truth=xt, costs=costs))
        topics = f"/teamkf/<estimator>/agent<i> ({len(z)} x {sys_.n_agents} topics)" + (
            ", /teamkf/truth and /teamkf/<estimator>/cost" if costs else ""
        )
        run = _relabel(run, {log_path: str(measurements), str(est_path): str(out)}, FilterRun)
        summary = {k: v for k, v in run.summary.items() if k != "cost_out"}
        lines = [
            *run.lines,
            f"{topics} written to {out} (ROS 2 std_msgs/msg/Float64MultiArray, step k at {start_ns / 1e9:.9f} s + k x {tmap.period} s)",
        ]
        return FilterRun(summary, lines, run.total_costs)


def _plain(scenario: Any, log: str, out: Path, **kw: Any) -> Any:
    from .filtering import filter_to_files as plain

    return plain(scenario, log, out, **kw)


def _relabel(run: Any, names: dict[str, str], cls: Any) -> Any:
    def fix(v: Any) -> Any:
        if isinstance(v, str):
            for a, b in names.items():
                v = v.replace(a, b)
        return v

    return cls({k: fix(v) for k, v in run.summary.items()}, [fix(s) for s in run.lines], run.total_costs)


def _read_back(est: Path, cost: Path | None, n: int) -> tuple[dict[str, Any], dict[str, Any] | None]:
    """The estimates (and costs) the filter wrote as CSV, as float64 arrays, exactly (round-trip parsing)."""
    from .. import _validation as V

    pd = V.require("pandas", "dask")
    exact = {"float_precision": "round_trip"} if int(pd.__version__.split(".")[0]) < 3 else {}  # pandas 3 parses exactly by default
    df = pd.read_csv(est, **exact)
    zc = [c for c in df.columns if c.startswith("z")]
    z = {}
    for name in dict.fromkeys(df["estimator"]):
        part = df[df["estimator"] == name].sort_values(["step", "agent"], kind="stable")
        T = int(part["step"].max()) + 1
        z[str(name)] = part[zc].to_numpy(dtype=float).reshape(T, n * len(zc))
    costs = None
    if cost is not None and cost.exists():
        cf = pd.read_csv(cost, **exact)
        costs = {str(k): cf[cf["estimator"] == k].sort_values("step")["cost"].to_numpy(dtype=float) for k in dict.fromkeys(cf["estimator"])}
    return z, costs


# ---------------------------------------------------------------------------
# teamkf measurements convert
# ---------------------------------------------------------------------------
_TABLES = (".csv", ".parquet", ".npz")


def cmd_convert(args: argparse.Namespace) -> int:
    """``teamkf measurements convert IN --map MAP --out OUT``: a recording to a table, or a table to a recording."""
    import numpy as np

    from . import measurements as M
    from .measurements.mcap_source import is_mcap, read_recording
    from .measurements.mcap_write import write_measurements_mcap

    src, dst = args.input, args.out
    to_mcap = is_mcap(dst)
    if is_mcap(src) == to_mcap:
        kind = "MCAP" if to_mcap else "table"
        raise ArgumentError(
            f"--out: {src} and {dst} are both {kind} files; convert a recording (.mcap) to a table (.csv, .parquet, .npz) or a table to a recording",
            argument="--out",
        )
    out = check_output(dst, "--out", fmt=(".mcap",) if to_mcap else _TABLES, inputs=[src, args.map])
    if not is_mcap(src) and Path(src).suffix.lower() not in _TABLES:
        raise ArgumentError(f"IN: expected a recording (.mcap) or a table (.csv, .parquet, .npz), found {src!r}", argument="IN")
    tmap = _need_map(args.map, f"converting {src}")
    if not to_mcap:
        rec = read_recording(src, tmap)
        suffix = out.suffix.lower()
        write_atomic(out, lambda fh: M.write_measurements(fh, rec.y, fmt=suffix))
        gaps = sum(int(np.isnan(y).any(axis=1).sum()) for y in rec.y)
        print(
            f"{src}: {rec.n_steps} steps of {len(rec.y)} agents ({gaps} agent-steps with missing values), step 0 at {rec.start_ns / 1e9:.9f} s; "
            f"written to {out}"
        )
        return 0
    from types import SimpleNamespace

    dy = tmap.sizes()
    system = SimpleNamespace(n_agents=len(dy), dy=dy, dx=0)  # the map says the agents and their sizes
    log = M.read_measurements(src, system, None)  # type: ignore[arg-type]
    if log.u is not None or log.b is not None or log.d is not None:
        raise ArgumentError(f"{src}: u, b or d columns: a recording carries the measurements only; drop those columns", argument="IN")
    start = 0 if tmap.start_ns is None else tmap.start_ns
    write_atomic(out, lambda fh: write_measurements_mcap(fh, log.y, tmap, start))
    print(
        f"{src}: {log.n_steps} steps of {len(dy)} agents written to {out} as {len(tmap.topics)} ROS 2 topics ({', '.join(e.topic for e in tmap.topics)})"
    )
    return 0


def write_team_estimates(path: str | Path, estimates: Any, n_agents: int, *, topic_map: str | Path | None, start_ns: int | None) -> None:
    """The estimates of ``teamkf deploy`` (or any team run) in the format ``path`` names: a table, or MCAP (``.mcap``: one
    topic per agent, step k at the recording's start + k x the map's period; ``topic_map`` needed, checked before the run)."""
    from . import measurements as M

    if Path(path).suffix.lower() != ".mcap":
        fmt = Path(path).suffix.lower()
        write_atomic(path, lambda fh: M.write_estimates(fh, estimates, n_agents, fmt=fmt))
        return
    from .measurements.mcap_write import write_estimates_mcap

    tmap = _need_map(topic_map, f"--out {path}")
    t0 = start_ns if start_ns is not None else (tmap.start_ns or 0)
    write_atomic(path, lambda fh: write_estimates_mcap(fh, estimates, n_agents, start_ns=t0, period_ns=tmap.period_ns))
