"""The ``teamkf`` command.

::

    teamkf evaluate SCENARIO [--json] [--monte-carlo RUNS] [--seed S] [--scheduler WHERE] [--plot OUT.png]
    teamkf design   SCENARIO [--json] [--out GAINS.npz]
    teamkf demo     [--out DIR] [--quick]
    teamkf reproduce ...      (a later version)
    teamkf filter   SCENARIO --measurements FILE [--truth FILE] --out FILE [--estimators ...] [--json]
    teamkf sweep    SWEEP.toml [--scheduler ADDRESS|local|serial] [--out RESULTS] [--resume] [--no-progress] [--json]
    teamkf --version

``SCENARIO`` is a scenario file (TOML, or JSON by its ``.json`` extension) or
the name of a packaged scenario (``platoon-4``, ``uav-10``, ...). ``--debug``
(before or after the command) shows the traceback of an error; without it an
error is one line ``teamkf: error: <message>`` on stderr and exit status 2.
The formats are a contract: see ``design/scenario-and-cli.md``.
"""

from __future__ import annotations

import argparse
import json
import sys
import traceback
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from .exceptions import ArgumentError, ScenarioError, TeamkfError

__all__ = ["main", "build_parser"]


def _version() -> str:
    from ._version import __version__

    return str(__version__)


def _short_version() -> str:
    return ".".join(_version().split(".")[:2])


# ---------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------
def _load(arg: str) -> Any:
    """A scenario from a path, or from the name of a packaged scenario."""
    from .study.scenario import load_packaged, load_scenario, packaged_scenarios

    p = Path(arg)
    if p.exists():
        if p.is_dir():
            raise ScenarioError(f"{arg}: is a directory; expected a scenario file (.toml or .json)")
        return load_scenario(p)
    packaged = packaged_scenarios()
    if arg in packaged:
        return load_packaged(arg)
    raise ScenarioError(f"{arg}: no such scenario file (packaged scenarios: {', '.join(packaged)})")


def _cost_label(horizon: int | None) -> str:
    return "J_T" if horizon is not None else "average cost"


def _fmt(x: float | None) -> str:
    if x is None:
        return "-"
    if not np.isfinite(x):
        return "diverged"
    ax = abs(x)
    if ax != 0 and (ax >= 1e7 or ax < 1e-3):
        return f"{x:.4e}"
    return f"{x:.2f}" if ax >= 100 else f"{x:.4f}"


def _pct(p: float) -> str:
    """A relative difference in percent; huge ones (a diverging estimator) in e-notation, not 40 digits."""
    if not np.isfinite(p):
        return "diverged"
    return f"{p:+.3e} %" if abs(p) >= 1e5 else f"{p:+.2f} %"


def format_table(headers: Sequence[str], rows: Sequence[Sequence[Any]], *, indent: str = "  ", align: str | None = None) -> str:
    """Plain-text table; ``align`` has one letter per column ("l" or "r"), default: first left, the others right."""
    cells = [[str(h) for h in headers]] + [[str(c) for c in r] for r in rows]
    widths = [max(len(r[k]) for r in cells) for k in range(len(headers))]
    al = align or ("l" + "r" * (len(headers) - 1))
    lines = []
    for n, r in enumerate(cells):
        parts = [c.ljust(w) if a == "l" else c.rjust(w) for c, w, a in zip(r, widths, al)]
        lines.append(indent + "  ".join(parts).rstrip())
        if n == 0:
            lines.append(indent + "  ".join("-" * w for w in widths))
    return "\n".join(lines)


def dumps_json(obj: Any) -> str:
    """JSON with objects indented and lists of numbers kept on one line."""

    def enc(x: Any, level: int) -> str:
        pad, inner = "  " * level, "  " * (level + 1)
        if isinstance(x, dict):
            if not x:
                return "{}"
            items = [f"{inner}{json.dumps(str(k))}: {enc(v, level + 1)}" for k, v in x.items()]
            return "{\n" + ",\n".join(items) + "\n" + pad + "}"
        if isinstance(x, (list, tuple)):
            if all(not isinstance(v, (dict, list, tuple, np.ndarray)) for v in x):
                return "[" + ", ".join(enc(v, level + 1) for v in x) + "]"
            return "[\n" + ",\n".join(inner + enc(v, level + 1) for v in x) + "\n" + pad + "]"
        if isinstance(x, np.ndarray):
            return enc(x.tolist(), level)
        if isinstance(x, np.generic):
            x = x.item()
        if isinstance(x, float) and not np.isfinite(x):
            return "null"  # strict JSON (RFC 8259) has no NaN or Infinity
        if x is None or isinstance(x, (str, bool, int, float)):
            return json.dumps(x, allow_nan=False)
        return enc(str(x), level)  # anything else (a path, ...) as its text

    return enc(obj, 0)


def _header(sc: Any) -> str:
    if sc.horizon is not None:
        what = f"horizon T = {sc.horizon}, J_T = sum over t of E[c(x(t), z(t))]"
    else:
        what = "infinite horizon (steady state), average cost per step"
    info = "reduced information structure from [information]" if sc.has_reduced_information else "full information structure of the graph"
    return (
        f"scenario {sc.name}: {sc.n_agents} agents, d_x = {sc.system.dx}, {what}\n"
        f"  graph: {sc.graph!r}; {info} (common lag {sc.information.common_lag})"
    )


# ---------------------------------------------------------------------------
# evaluate
# ---------------------------------------------------------------------------
def _cmd_population(sc: Any, args: argparse.Namespace) -> int:
    """evaluate / design of a [population] scenario: exact statistics, nothing simulated."""
    out = sc.evaluate()
    if out.get("diverged"):
        _warn(
            f"{out['filter']} filter: the closed loop diverges (Var x_k beyond 4.5e11 times the noise variance) from step {out['diverged_at']}"
            + ("; the numbers from there on are reported as diverged / null" if not np.isfinite(out["state_variance"]) else "")
        )
    if getattr(args, "json", False):
        print(dumps_json(out))
        return 0
    m = sc.model
    if out.get("diverged") and not np.isfinite(out["state_variance"]):
        print(
            f"scenario {sc.name}: population of N = {m.n_agents:,} interference-coupled agents, horizon T = {sc.horizon}, "
            f"{out['filter']} filter, feedback f = {m.f:g} (a_f = {out['a_f']:g})\n"
            f"  diverged: the closed loop is unstable under this filter from step {out['diverged_at']} on (gains, variances and cost not finite)"
        )
        return 0
    print(
        f"scenario {sc.name}: population of N = {m.n_agents:,} interference-coupled agents, horizon T = {sc.horizon}, "
        f"{out['filter']} filter, feedback f = {m.f:g} (a_f = {out['a_f']:g})"
    )
    tail = ", ".join(f"{v:.4g}" for v in out["gains"][-5:])
    iso = out.get("isolated_gains")
    print(f"  final gains K_T (last 5, oldest first): [..., {tail}]")
    if iso:
        print(f"  isolated Kalman sequence (last 5):      [..., {', '.join(f'{v:.4g}' for v in iso[-5:])}]")
    print(
        f"  stationarity index {out['stationarity_index']:.3g}; state variance Var x_T = {out['state_variance']:.6g}; "
        f"average LQ cost per agent {out['average_lq_cost']:.6g}"
    )
    if out.get("diverged"):
        print(f"  diverged: the closed loop is unstable (Var x_k > 4.5e11 times the noise variance from step {out['diverged_at']} on)")
    return 0


def _check_output(path: str, flag: str, suffixes: Sequence[str] | None = None) -> Path:
    """Fail before any work when an output path has an unsupported extension or cannot be written."""
    import os

    p = Path(path)
    if suffixes is not None and p.suffix.lower() not in suffixes:
        raise ArgumentError(f"{flag}: expected a file name ending in {' or '.join(suffixes)}, found {path!r}", argument=flag)
    if p.is_dir():
        raise ArgumentError(f"{flag}: {path!r} is a directory; give a file name", argument=flag)
    parent = p.parent if str(p.parent) else Path(".")
    existing = parent
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir() or not os.access(existing, os.W_OK) or (p.exists() and not os.access(p, os.W_OK)):
        raise ArgumentError(f"{flag}: cannot write {path!r} (no permission or not a directory: {existing}); choose another path", argument=flag)
    return p


def _write_atomic(path: Path, write: Any) -> None:
    """Write through a temporary file in the same folder, renamed at the end: no partial file on failure."""
    import os
    import tempfile

    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            write(fh)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _warn(message: str) -> None:
    print(f"teamkf: warning: {message}", file=sys.stderr)


def _cmd_evaluate(args: argparse.Namespace) -> int:
    from . import _validation as V
    from .study.evaluate import DEFAULT_MC_RUNS

    sc = _apply_network_flags(_load(args.scenario), args)
    plot_to = _check_output(args.plot, "--plot", _PLOT_SUFFIXES) if args.plot else None
    if not hasattr(sc, "designs"):  # a [population] scenario: exact statistics, nothing simulated
        if args.monte_carlo:
            raise ArgumentError("--monte-carlo: a population scenario is evaluated exactly; nothing needs simulating", argument="--monte-carlo")
        if plot_to is not None:
            raise ArgumentError(
                "--plot: a population scenario has no stage costs to plot; use teamkf reproduce bulk-* for its figures", argument="--plot"
            )
        if args.seed is not None:
            _warn("--seed is ignored: a population scenario is evaluated exactly, nothing is sampled")
        return _cmd_population(sc, args)
    runs = args.monte_carlo
    if runs is not None:
        if sc.horizon is None:
            raise ArgumentError(
                f"horizon: --monte-carlo needs a finite horizon, but scenario {sc.name!r} has none (steady state); add horizon = T to the scenario",
                argument="horizon",
            )
        if runs < 2:
            raise ArgumentError(f"--monte-carlo: expected at least 2 runs (for a confidence interval), found {runs}", argument="--monte-carlo")
    if plot_to is not None:
        V.require("matplotlib", "plot")  # fail before the work, with the install command

    with np.errstate(over="ignore", invalid="ignore"):  # a diverging design is reported below (warning, "diverged", null)
        designs = sc.designs()
    mc_only = [name for name, d in designs.items() if not d.has_analytic_cost]
    simulate = designs
    if runs is None and mc_only:
        runs, simulate = DEFAULT_MC_RUNS, {name: designs[name] for name in mc_only}
    if args.seed is not None and runs is None:
        _warn("--seed is ignored without Monte Carlo (every estimator of this scenario has an analytic cost); add --monte-carlo RUNS")
    seed = args.seed
    mc: dict[str, Any] = {}
    if runs is not None:
        from .simulation.monte_carlo import monte_carlo

        if seed is None:
            seed = int(np.random.SeedSequence().entropy % (2**32))  # type: ignore[operator]
        try:
            if args.scheduler not in (None, "serial", "local"):
                _check_scheduler(args.scheduler)
            mc = monte_carlo(
                simulate, sc.horizon, runs, rng=seed, scheduler=args.scheduler, **sc.monte_carlo_options()
            )  # [network]: unreliable links
        except ArgumentError as exc:
            raise (exc.rekeyed("--monte-carlo") if exc.argument == "n_runs" else exc) from None
    for name, d in designs.items():
        if d.diverged or (name in mc and not np.isfinite(mc[name].total_mean)):
            _warn(f"{name}: the team cost diverges (not finite){_divergence_step(d, mc.get(name))}; reported as diverged / null")

    notes: list[str] = []
    if plot_to is not None:
        notes.append(_plot_stage_costs(designs, mc, sc, plot_to))

    control = _control_summary(sc, runs, seed)
    if args.json:
        out: dict[str, Any] = {"scenario": sc.name, "horizon": sc.horizon, "teamkf_version": _version(), "estimators": {}}
        if control:
            out["control"] = control
        if mc:  # what repeats the Monte Carlo: seed, runs, block and chunk sizes, teamkf version
            out["monte_carlo"] = {k: v for k, v in next(iter(mc.values())).summary().items() if k in ("runs", "batch", "chunk", "teamkf_version")}
            out["monte_carlo"]["seed"] = seed  # the --seed given (or drawn and printed): it repeats the run
        for name, d in designs.items():
            if name in mc_only:
                entry = {**mc[name].summary(), **({"variant": d.info["variant"]} if "variant" in d.info else {})}
            else:
                entry = {}
                for k, v in d.cost_summary().items():
                    entry[k] = v
                    if k == d.cost_key and name in mc:
                        lo, hi = mc[name].ci95
                        entry.update(mc_cost=mc[name].total_mean, mc_ci95=[lo, hi])
            if any(isinstance(v, float) and not np.isfinite(v) for v in _leaves(entry)):
                entry["diverged"] = True
            out["estimators"][name] = entry
        print(dumps_json(out))
        for n in notes:
            print(n, file=sys.stderr)
        return 0

    ref = designs.get("mtmse")
    ref_value = ref.cost_value if ref is not None else None
    headers = ["estimator", _cost_label(sc.horizon)]
    if ref_value is not None:
        headers.append("vs mtmse")
    if mc:
        headers += ["MC mean", "MC 95% CI"]
    rows = []
    for name, d in designs.items():
        v = mc[name].total_mean if name in mc_only else d.cost_value
        row = [d.label, _fmt(v) + (" (MC)" if name in mc_only and v is not None and np.isfinite(v) else "")]
        if ref_value is not None:
            ok = v is not None and np.isfinite(v) and np.isfinite(ref_value) and ref_value != 0
            row.append(_pct(100.0 * (v - ref_value) / ref_value) if ok else "-")  # type: ignore[operator]
        if mc:
            if name in mc:
                lo, hi = mc[name].ci95
                row += [_fmt(mc[name].total_mean), f"[{_fmt(lo)}, {_fmt(hi)}]"]
            else:
                row += ["", ""]
        rows.append(row)
    print(_header(sc))
    print()
    print(format_table(headers, rows))
    if control:
        print("\n  decentralized LQG ([control], one-step delayed sharing, Appendix D):")
        for name, entry in control.items():
            extra = (
                f"   closed-loop MC {_fmt(entry['mc_cost'])} [{_fmt(entry['mc_ci95'][0])}, {_fmt(entry['mc_ci95'][1])}]" if "mc_cost" in entry else ""
            )
            print(f"    {name:22s} J = {_fmt(entry['total_cost'])}{extra}")
    if mc:
        print(f"\n  Monte Carlo: {runs} runs, seed {seed} (online agents on sampled paths; analytic values in the {_cost_label(sc.horizon)} column)")
    for n in notes:
        print(n)
    return 0


_PLOT_SUFFIXES = (".png", ".pdf", ".svg", ".jpg", ".jpeg")


def _strict_rows(out: dict[str, Any]) -> dict[str, Any]:
    """Rows with every non-finite number as null, and ``"non_finite": {column: "inf" | "-inf" | "nan"}`` saying which (strict JSON)."""
    rows = []
    for r in out.get("rows", []):
        bad = {k: str(float(v)) for k, v in r.items() if isinstance(v, (float, np.floating)) and not np.isfinite(v)}
        rows.append({**r, "non_finite": bad} if bad else r)
    return {**out, "rows": rows}


def _leaves(x: Any) -> list[Any]:
    if isinstance(x, dict):
        return [v for val in x.values() for v in _leaves(val)]
    if isinstance(x, (list, tuple)):
        return [v for val in x for v in _leaves(val)]
    return [x]


def _divergence_step(design: Any, mc: Any) -> str:
    stages = design.stage_costs if design.stage_costs is not None else (mc.stage_mean if mc is not None else None)
    if stages is None:
        return ""
    bad = np.flatnonzero(~np.isfinite(np.asarray(stages)))
    return f" from step {int(bad[0])}" if bad.size else ""


def _control_summary(sc: Any, runs: int | None, seed: int | None) -> dict[str, Any]:
    """Analytic (and, with runs, closed-loop Monte Carlo) costs of Theorem 4's controller and of certainty equivalence."""
    prob = sc.control
    if prob is None:
        return {}
    from .control.lqg import design_lqg, simulate_closed_loop

    out: dict[str, Any] = {}
    for name, kind in (("optimal", "mtmse"), ("certainty_equivalent", "mmse")):
        d = design_lqg(prob, sc.horizon, kind=kind)
        entry: dict[str, Any] = {"method": "analytic", "total_cost": float(d.cost)}
        if runs:
            mc = simulate_closed_loop(d, runs, rng=seed)
            entry.update(mc_cost=mc["mean"], mc_ci95=[mc["mean"] - 1.96 * mc["sem"], mc["mean"] + 1.96 * mc["sem"]])
        out[name] = entry
    return out


def _plot_stage_costs(designs: dict[str, Any], mc: dict[str, Any], sc: Any, out: Path) -> str:
    from .plotting import stage_cost_axes

    # analytic curves, and every Monte Carlo mean with its 95 % band (markers where an analytic curve is drawn)
    analytic = [d for d in designs.values() if d.has_analytic_cost]
    ax = stage_cost_axes(analytic, title=f"{sc.name}: stage costs", monte_carlo={name: mc[name] for name in designs if name in mc})
    fig = ax.figure
    _write_atomic(out, lambda fh: fig.savefig(fh, dpi=120, format=out.suffix.lstrip(".").lower().replace("jpg", "jpeg")))
    import matplotlib.pyplot as plt

    plt.close(fig)
    return f"plot written to {out}"


# ---------------------------------------------------------------------------
# design
# ---------------------------------------------------------------------------
def _cmd_design(args: argparse.Namespace) -> int:
    sc = _load(args.scenario)
    out_path = _check_output(args.out, "--out") if args.out else None
    if not hasattr(sc, "designs"):  # a [population] scenario
        if out_path is not None:
            res = sc.evaluate()
            _write_atomic(
                out_path, lambda fh: np.savez(fh, gains=np.asarray(res["gains"]), state_variance=np.asarray(res["state_variance_trajectory"]))
            )
        return _cmd_population(sc, args)
    with np.errstate(over="ignore", invalid="ignore"):  # a diverging design is reported as diverged
        designs = sc.designs()
    for name, d in designs.items():
        if d.diverged:
            _warn(f"{name}: the team cost diverges (not finite){_divergence_step(d, None)}; reported as diverged / null")
    notes = []
    if out_path is not None:
        arrays: dict[str, np.ndarray] = {"scenario": np.asarray(sc.name), "horizon": np.asarray(-1 if sc.horizon is None else sc.horizon)}
        for name, d in designs.items():
            arrays.update({f"{name}/{k}": v for k, v in d.arrays().items()})
        _write_atomic(out_path, lambda fh: np.savez(fh, **arrays))  # type: ignore[arg-type]  # a file handle: no suffix added
        notes.append(f"gains written to {out_path} ({len(arrays)} arrays; keys like '{next(iter(designs))}/...'; horizon -1 means steady state)")
    if args.json:
        out = {
            "scenario": sc.name,
            "horizon": sc.horizon,
            "teamkf_version": _version(),
            "estimators": {name: d.summary() for name, d in designs.items()},
        }
        print(dumps_json(out))
        for n in notes:
            print(n, file=sys.stderr)
        return 0
    when = f"gains at the last step t = {sc.horizon}" if sc.horizon is not None else "steady-state gains"
    print(_header(sc))
    print()
    rows = []
    for d in designs.values():
        s = d.summary()
        dims = "all (centralized)" if d.omniscient else ("-" if s.get("local_dims") is None else ", ".join(map(str, s["local_dims"])))
        shapes = ", ".join(f"{k} {'x'.join(map(str, v))}" for k, v in s.get("gain_shapes", {}).items())
        cost = _fmt(d.cost_value) if d.has_analytic_cost else "Monte Carlo (teamkf evaluate)"
        rows.append([d.label, cost, dims, shapes])
    print(format_table(["estimator", _cost_label(sc.horizon), "local dims (scalars per agent)", f"gain shapes ({when})"], rows, align="lrll"))
    for n in notes:
        print(n)
    return 0


# ---------------------------------------------------------------------------
# demo and later commands
# ---------------------------------------------------------------------------
def _cmd_demo(args: argparse.Namespace) -> int:
    from .demo import run_demo

    run_demo(out_dir=args.out, quick=args.quick, echo=True)
    return 0


def _cmd_sweep(args: argparse.Namespace) -> int:
    from .study.sweep import load_sweep, run_sweep

    spec = load_sweep(args.sweep)  # everything is checked before anything is written
    out = Path(args.out) if args.out else Path(f"{Path(args.sweep).stem}.parquet")
    scheduler = args.scheduler or "local"
    _check_scheduler(scheduler)
    if args.workers is not None and scheduler != "local":
        _warn(f"--workers is ignored with --scheduler {scheduler}: it sets the worker processes of the local cluster (--scheduler local)")
    try:
        res = run_sweep(spec, out, scheduler=scheduler, resume=args.resume, progress=not args.no_progress, n_workers=args.workers)
    except KeyboardInterrupt:
        print(f"teamkf: interrupted; the finished points are kept in {out}; run the same command with --resume to continue", file=sys.stderr)
        return 130
    key = res.cost_key
    if args.json:
        print(
            dumps_json(
                {
                    "sweep": spec.name,
                    "scenario": spec.scenario,
                    "out": str(out),
                    "points": spec.n_points,
                    "computed": res.n_computed,
                    "resumed": res.n_resumed,
                    "runs": spec.runs,
                    "seed": spec.seed,
                    "estimators": list(spec.estimators),
                    "grid": {k: list(v) for k, v in spec.grid.items()},
                    "rows": [dict(r) for r in res.rows],
                }
            )
        )
        return 0
    where = {"serial": "in-process (serial)", "local": "Dask LocalCluster"}.get(str(scheduler), f"Dask scheduler {scheduler}")
    print(
        f"sweep {spec.name}: {spec.n_points} points x {len(spec.estimators)} estimators, base scenario {spec.base.name}, "
        f"runs {spec.runs}, seed {spec.seed}; {where}"
    )
    print()
    by_point: dict[str, dict[str, Any]] = {}
    for r in res.rows:
        by_point.setdefault(r["point_id"], {k: r[k] for k in res.grid_keys})[r["estimator"]] = r.get(key)
    limit = 30
    table = [
        [*(p[k] for k in res.grid_keys), *(_fmt(p[e]) if p.get(e) is not None else "-" for e in spec.estimators)]
        for p in list(by_point.values())[:limit]
    ]
    print(format_table([*res.grid_keys, *spec.estimators], table, align="r" * (len(res.grid_keys) + len(spec.estimators))))
    if len(by_point) > limit:
        print(f"  ... and {len(by_point) - limit} more points")
    mc = " (Monte Carlo means for estimators without one; analytic estimators also have mc_cost)" if spec.runs else ""
    print(f"\n  {_cost_label(spec.base.horizon) if key == 'total_cost' else 'average cost'} per estimator{mc}")
    print(
        f"\nresults: {out} ({len(res.rows)} rows; {res.n_computed} points computed now, {res.n_resumed} already there); "
        f"read them with pandas.read_parquet({str(out)!r}) or teamkf.study.results.SweepResult.load"
    )
    return 0


def _cmd_not_yet(args: argparse.Namespace) -> int:
    print(f"teamkf: {args.command} is not available yet in teamkf {_short_version()}", file=sys.stderr)
    return 2


# ---------------------------------------------------------------------------
# filter: recorded measurements (teamkf.study.measurements)
# ---------------------------------------------------------------------------
def _cmd_filter(args: argparse.Namespace) -> int:
    """``teamkf filter SCENARIO --measurements FILE [--truth FILE] --out FILE [--estimators ...]``."""
    from .study import measurements as M

    out_path = _check_output(args.out, "--out", (".csv", ".parquet"))
    cost_path = out_path.with_name(f"{out_path.stem}-cost{out_path.suffix}") if args.truth else None
    if cost_path is not None:
        _check_output(str(cost_path), "--out")
    sc = _load(args.scenario)
    if not hasattr(sc, "designs"):
        raise ArgumentError(
            "SCENARIO: teamkf filter needs a scenario with [system], [[agents]] and a graph, found a population scenario", argument="SCENARIO"
        )
    names = list(args.estimators) if args.estimators else list(sc.estimators)
    from .estimators.registry import get_family

    for k, name in enumerate(names):
        get_family(name, f"--estimators[{k}]")
    if sc.horizon is None:  # steady-state designs: stream the file in chunks (bounded memory)
        return _filter_streamed(sc, args, names, out_path, cost_path)
    log = M.read_measurements(args.measurements, sc.system, sc.horizon)
    truth = M.read_truth(args.truth, sc.system.dx, log.n_steps) if args.truth else None
    res = M.filter_log(sc, log, estimators=names, truth=truth)
    fmt = out_path.suffix.lower()
    _write_atomic(out_path, lambda fh: M.write_estimates(fh, res.estimates, res.n_agents, fmt=fmt))
    if cost_path is not None and res.stage_costs is not None:
        import pandas as pd

        T = log.n_steps
        frame = pd.concat(
            [pd.DataFrame({"step": np.arange(T), "estimator": name, "cost": c}) for name, c in res.stage_costs.items()], ignore_index=True
        )
        _write_atomic(cost_path, lambda fh: M._write_frame(frame, fh, fmt))
    if args.json:
        out = {"scenario": sc.name, "measurements": str(args.measurements), "out": str(out_path), **res.summary()}
        if cost_path is not None:
            out["cost_out"] = str(cost_path)
        print(dumps_json(out))
        return 0
    if res.loglik is not None:
        print(f"log-likelihood of the data under the centralized filter: {res.loglik:.6f}")
    gaps = "no gaps" if not log.has_gaps else f"{sum(int(np.isnan(y).any(axis=1).sum()) for y in log.y)} agent-steps with missing values"
    print(f"{sc.name}: {log.n_steps} steps, {res.n_agents} agents ({gaps}); estimates of {', '.join(names)} written to {out_path}")
    if res.total_costs is not None:
        print(format_table(["estimator", "realized team cost (sum over steps)"], [[k, _fmt(v)] for k, v in res.total_costs.items()], align="lr"))
        print(f"per-step realized costs written to {cost_path}")
    return 0


def _filter_streamed(sc: Any, args: argparse.Namespace, names: list[str], out_path: Path, cost_path: Path | None) -> int:
    from .study.stream import stream_filter

    fmt = out_path.suffix.lower()
    done: dict[str, Any] = {}

    def run(fh: Any, ch: Any = None) -> None:
        done["summary"] = stream_filter(
            sc,
            args.measurements,
            fh,
            fmt=fmt,
            estimators=names,
            truth=args.truth,
            cost_out=ch,
            chunk_rows=args.chunk_rows,
            progress=False if args.no_progress else None,
        )

    if cost_path is not None:
        _write_atomic(out_path, lambda fh: _write_atomic(cost_path, lambda ch: run(fh, ch)))
    else:
        _write_atomic(out_path, run)
    summ = done["summary"]
    if args.json:
        out = {"scenario": sc.name, "measurements": str(args.measurements), "out": str(out_path), **summ.summary()}
        if cost_path is not None:
            out["cost_out"] = str(cost_path)
        print(dumps_json(out))
        return 0
    print(
        f"{sc.name}: {summ.n_steps} steps streamed (steady-state gains), {summ.rows_in} measurement rows; {summ.rows_out} estimate rows of {', '.join(names)} written to {out_path}"
    )
    if summ.total_costs is not None:
        print(format_table(["estimator", "realized team cost (sum over steps)"], [[k, _fmt(v)] for k, v in summ.total_costs.items()], align="lr"))
        print(f"per-step realized costs written to {cost_path}")
    return 0


def _add_network_flags(p: argparse.ArgumentParser) -> None:
    """--p-drop and --jitter: the common keys of a scenario's [network] table (unreliable links, Monte Carlo)."""
    p.add_argument("--p-drop", type=float, metavar="P", help="packet-drop probability on every edge (sets network.p_drop; Monte Carlo)")
    p.add_argument("--jitter", type=int, metavar="J", help="extra delay of 0..J steps on every edge (sets network.jitter; Monte Carlo)")


def _apply_network_flags(sc: Any, args: argparse.Namespace) -> Any:
    """The scenario with --p-drop / --jitter written into its [network] table (validated like the file)."""
    vals = {k: v for k, v in (("network.p_drop", getattr(args, "p_drop", None)), ("network.jitter", getattr(args, "jitter", None))) if v is not None}
    if not vals:
        return sc
    if not hasattr(sc, "updated") or not hasattr(sc, "monte_carlo_options"):
        raise ArgumentError("--p-drop/--jitter: unreliable links need a scenario with a graph, found a population scenario", argument="--p-drop")
    if not getattr(args, "monte_carlo", None):
        _warn("--p-drop/--jitter act on the simulated agents; add --monte-carlo RUNS (analytic costs assume reliable links)")
    return sc.updated(vals)


def _add_filter_parser(add: Any) -> None:
    p = add("filter", "filter recorded measurements with every estimator of a scenario (CSV, Parquet or NPZ in; CSV or Parquet out)")
    p.add_argument("scenario", metavar="SCENARIO")
    p.add_argument(
        "--measurements",
        required=True,
        metavar="FILE",
        help="long form step,agent,y0,... (.csv/.parquet) or one array per agent (.npz); NaN or absent = missing",
    )
    p.add_argument("--truth", metavar="FILE", help="the true states step,x0,... (.csv/.parquet) or .npz key 'x': adds the realized team cost")
    p.add_argument(
        "--out",
        required=True,
        metavar="FILE",
        help="estimates step,agent,estimator,z0,... (.csv or .parquet); with --truth also FILE-cost.csv/.parquet",
    )
    p.add_argument("--estimators", nargs="+", metavar="NAME", help="estimators to run (default: the scenario's)")
    p.add_argument("--json", action="store_true", help="print one JSON object (steps, estimators, realized total costs)")
    p.add_argument(
        "--chunk-rows", type=_positive_int, default=400_000, metavar="N", help="steady-state scenarios are streamed N rows at a time (default 400000)"
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar (it shows only on a terminal anyway)")
    p.set_defaults(func=_cmd_filter)


# ---------------------------------------------------------------------------
# parser and main
# ---------------------------------------------------------------------------
def _int_at_least(minimum: int, what: str) -> Any:
    """An argparse type: an integer >= ``minimum``, with the message naming ``what``."""

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what}, found {text!r}") from None
        if v < minimum:
            raise argparse.ArgumentTypeError(f"expected {what}, found {v}")
        return v

    return parse


_positive_int = _int_at_least(1, "a whole number >= 1")
_seed = _int_at_least(0, "a non-negative integer seed")


def _cmd_reproduce(args: argparse.Namespace) -> int:
    from . import experiments

    if args.list or not args.name:
        if not args.list:
            print("teamkf: error: reproduce needs an experiment NAME (or --list)", file=sys.stderr)
            return 2
        for name in experiments.names():
            print(f"{name:14s} {experiments.get(name).title}")
        return 0
    from .simulation.parallel import use_scheduler

    exp = experiments.get(args.name)
    if args.out:
        _check_output_dir(args.out, "--out")
    scheduler = args.scheduler or "serial"
    owned: list[Any] = []
    if scheduler != "serial":
        if not exp.uses_scheduler:
            raise ArgumentError(
                f"--scheduler: the reproduction {args.name!r} runs in-process (it has no grid of independent points to distribute); "
                f"drop --scheduler (reproductions that use it: {', '.join(n for n in experiments.names() if experiments.get(n).uses_scheduler)})",
                argument="--scheduler",
            )
        scheduler, owned = _open_scheduler(scheduler)
    try:
        with use_scheduler(scheduler):
            res = experiments.run(args.name, args.out, quick=args.quick)
    finally:
        for obj in owned:
            obj.close()
    if args.json:
        print(dumps_json(_strict_rows(res.to_json())))
        return 0
    print(res.title)
    print(res.format_table())
    if res.notes:
        print("\n" + res.notes)
    if args.out:
        where = ", ".join(res.figures) if res.figures else "no plots (pip install 'teamkf[plot]' for them)"
        print(f"\nwritten to {args.out}: {res.name}.csv, {res.name}.json; {where}")
    return 0


def _check_scheduler(address: str) -> None:
    """Fail fast (2 s) when a Dask scheduler address is malformed or nothing listens there."""
    import socket
    from urllib.parse import urlsplit

    if address in ("local", "serial"):
        return
    parts = urlsplit(address if "://" in address else f"tcp://{address}")
    try:
        host, port = parts.hostname, parts.port
    except ValueError:
        host, port = None, None
    if parts.scheme not in ("tcp", "tls", "ws", "wss", "inproc", "ucx") or not host or port is None:
        raise ArgumentError(
            f"--scheduler: expected 'serial', 'local' or a Dask scheduler address like tcp://host:8786, found {address!r}", argument="--scheduler"
        )
    try:
        with socket.create_connection((host, port), timeout=2.0):
            pass
    except OSError as exc:
        raise ArgumentError(
            f"--scheduler: cannot reach a Dask scheduler at {address!r} ({exc.strerror or exc}); start one (dask scheduler) "
            "or use 'local' / 'serial'",
            argument="--scheduler",
        ) from None


def _open_scheduler(address: str) -> tuple[Any, list[Any]]:
    """A Dask client for ``--scheduler`` (checked first), and the objects to close at the end."""
    from . import _validation as V

    _check_scheduler(address)
    V.require("distributed", "dask")
    from .study.sweep import _open_client

    try:
        return _open_client(address, None)  # type: ignore[no-any-return]
    except TeamkfError as exc:
        raise ArgumentError(f"--scheduler: {exc.detail}", argument="--scheduler") from None


def _check_output_dir(path: str, flag: str) -> Path:
    """An output folder that exists or can be created, and is writable; checked before any work."""
    import os

    p = Path(path)
    if p.exists() and not p.is_dir():
        raise ArgumentError(f"{flag}: expected a folder, found the file {path!r}; choose another path", argument=flag)
    existing = p
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir() or not os.access(existing, os.W_OK):
        raise ArgumentError(f"{flag}: cannot write into {path!r} (no permission or not a directory: {existing}); choose another path", argument=flag)
    return p


def _help_text() -> tuple[str, str]:
    """The description and epilog of ``teamkf --help``: every registered family and packaged scenario."""
    from .estimators.registry import families
    from .study.scenario import packaged_scenarios

    lines = [
        "Design, run and evaluate decentralized estimators for teams of agents that share information over a",
        "communication graph with delays. Estimator families (estimators = [...] in a scenario file):",
        "",
    ]
    for name, fam in families().items():
        cost = "analytic cost" if fam.analytic_cost else "Monte Carlo cost"
        lines.append(f"  {name:12s} {fam.title} [{cost}]")
        if fam.example:
            lines.append(f"  {'':12s}   e.g. {fam.example}")
    lines += [
        "  bulk filter  interference-coupled populations (Abedinpour Fallah et al. 2017): a [population] scenario,",
        "               e.g. teamkf evaluate interference",
        "  LQG          decentralized LQG through MTMSE (Afshari & Mahajan, Appendix D): a [control] table,",
        "               e.g. teamkf evaluate lqg-2",
        "",
        "Add your own family with teamkf.register_family (Python), --plugin FILE.py or the 'teamkf.families' entry point.",
    ]
    epilog = (
        "SCENARIO is a .toml/.json scenario file or a packaged scenario name ("
        + ", ".join(packaged_scenarios())
        + "). Errors print one line; --debug shows the traceback."
    )
    return "\n".join(lines), epilog


class _UsageError(Exception):
    """A command-line usage error, reported as one line like every other error."""


class _Parser(argparse.ArgumentParser):
    """argparse with usage errors as one line ``teamkf: error: <argument>: <what is wrong>`` (exit status 2)."""

    def error(self, message: str) -> Any:  # type: ignore[override]
        import re

        m = re.match(r"argument ([^:]+): (.*)", message, re.S)
        if m:
            arg = m.group(1).split("/")[-1].strip()
            text = f"{arg}: {m.group(2)}"
        elif message.startswith("the following arguments are required: "):
            names = message.split(": ", 1)[1]
            text = f"{names.split(', ')[0]}: missing required argument ({names} required)"
        elif message.startswith("unrecognized arguments: "):
            extra = message.split(": ", 1)[1]
            text = f"{extra.split()[0]}: unknown argument ({extra}); expected one of the options listed by --help"
        else:
            text = message
        raise _UsageError(f"{text}; see {self.prog} --help")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``teamkf`` command (its --help lists every registered family)."""
    debug_help = "show the full traceback of an error"
    plugin_help = "import a module or .py file that registers estimator families (repeatable; also TEAMKF_PLUGINS)"
    description, epilog = _help_text()
    parser = _Parser(prog="teamkf", description=description, epilog=epilog, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"teamkf {_version()}")
    parser.add_argument("--debug", action="store_true", help=debug_help)
    parser.add_argument("--plugin", action="append", default=[], metavar="MODULE", help=plugin_help)
    parser.add_argument("--quiet", action="store_true", help="no progress bars (they appear on a terminal after 2 s)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    def add(name: str, help: str) -> argparse.ArgumentParser:
        p = sub.add_parser(name, help=help, description=help)
        p.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help=debug_help)
        p.add_argument("--plugin", action="append", default=argparse.SUPPRESS, metavar="MODULE", help=plugin_help)
        return p

    p = add("evaluate", "design every estimator of a scenario and compare their team costs")
    p.add_argument("scenario", metavar="SCENARIO")
    p.add_argument("--json", action="store_true", help="print one JSON object (scenario, horizon, estimators)")
    p.add_argument("--monte-carlo", type=_positive_int, metavar="RUNS", help="also simulate RUNS runs of the online agents (finite horizon)")
    p.add_argument("--seed", type=_seed, metavar="S", help="seed of the Monte Carlo runs (default: fresh, printed)")
    p.add_argument(
        "--scheduler",
        metavar="WHERE",
        default=None,
        help="where the Monte Carlo chunks run: serial (default), local (an embedded Dask cluster) or a Dask scheduler address",
    )
    p.add_argument("--plot", metavar="OUT.png", help="plot the stage costs of every estimator (needs matplotlib)")
    _add_network_flags(p)
    p.set_defaults(func=_cmd_evaluate)

    p = add("design", "compute the gains of every estimator of a scenario")
    p.add_argument("scenario", metavar="SCENARIO")
    p.add_argument("--json", action="store_true", help="print one JSON object (costs, local dimensions, gain shapes)")
    p.add_argument("--out", metavar="GAINS.npz", help="save the gains (numpy .npz, keys like 'mtmse/F_0_t5', 'mtmse/K')")
    p.set_defaults(func=_cmd_design)

    p = add("demo", "the headline comparisons of the team-MMSE paper, with plots")
    p.add_argument("--out", default="results", metavar="DIR", help="folder for the plots (default: results)")
    p.add_argument("--quick", action="store_true", help="a shorter horizon, for a fast look")
    p.set_defaults(func=_cmd_demo)

    p = add("reproduce", "regenerate a paper figure or table (teamkf reproduce --list)")
    p.add_argument("name", nargs="?", metavar="NAME")
    p.add_argument("--list", action="store_true", help="list the experiments")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.add_argument("--out", metavar="DIR", help="write the table (CSV, JSON) and plots (PNG) into DIR")
    p.add_argument("--quick", action="store_true", help="a coarser grid, for a fast look")
    p.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="where grid points run: serial (default), local (an embedded Dask cluster) or a Dask scheduler address; "
        "only reproductions with a grid of independent points (bulk-*) use it, the others refuse it",
    )
    p.set_defaults(func=_cmd_reproduce)

    p = add("sweep", "run a parameter sweep of a scenario (in-process or on Dask) and write the results as Parquet")
    p.add_argument("sweep", metavar="SWEEP.toml", help="sweep file: base scenario, [grid] of dotted keys, runs, seed, estimators")
    p.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="'local' (default: a Dask LocalCluster, one worker per core), 'serial' (in-process) "
        "or the address of a Dask scheduler (tcp://host:8786)",
    )
    p.add_argument("--out", metavar="RESULTS", help="results folder of Parquet parts (default: <sweep file stem>.parquet)")
    p.add_argument("--resume", action="store_true", help="keep the points already in RESULTS and compute the missing ones")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--workers", type=_positive_int, metavar="N", help="worker processes of the local cluster (default: one per core)")
    p.add_argument("--json", action="store_true", help="print one JSON object (counts and every row)")
    p.set_defaults(func=_cmd_sweep)

    _add_filter_parser(add)
    return parser


def _one_line(exc: BaseException) -> str:
    if isinstance(exc, OSError) and exc.strerror:
        where = f"{exc.filename}: " if exc.filename else ""
        return f"{where}{exc.strerror}"
    text = " ".join(str(exc).split())
    return text or type(exc).__name__


def _load_plugins(argv: Sequence[str]) -> None:
    """Import the --plugin modules first, so that their families appear in --help and in scenario files."""
    from .estimators.registry import load_plugin

    for k, a in enumerate(argv):
        if a == "--plugin" and k + 1 < len(argv):
            load_plugin(argv[k + 1])
        elif a.startswith("--plugin="):
            load_plugin(a.split("=", 1)[1])


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``teamkf`` command; returns the exit status (0 success, 2 error)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        _load_plugins(argv)
    except TeamkfError as exc:
        if "--debug" in argv:
            traceback.print_exc()
        print(f"teamkf: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, --version
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 2)
    except _UsageError as exc:
        print(f"teamkf: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    if getattr(args, "quiet", False):
        from ._progress import set_quiet

        set_quiet(True)
    try:
        return int(args.func(args))
    except (TeamkfError, OSError) as exc:
        if getattr(args, "debug", False):
            traceback.print_exc()
        print(f"teamkf: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # pragma: no cover - interactive
        print("teamkf: interrupted", file=sys.stderr)
        return 130
