"""The ``teamkf`` command.

::

    teamkf evaluate SCENARIO [--json] [--monte-carlo RUNS] [--seed S] [--scheduler WHERE] [--plot OUT.png]
    teamkf design   SCENARIO [--json] [--out GAINS.npz]
    teamkf demo     [--out DIR] [--quick]
    teamkf reproduce ...      (a later version)
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

from .exceptions import ScenarioError, TeamkfError

__all__ = ["main", "build_parser"]


def _version() -> str:
    from . import __version__

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


def _cost_value(design: Any) -> float:
    return float(design.total_cost) if design.horizon is not None else float(design.average_cost)


def _cost_label(horizon: int | None) -> str:
    return "J_T" if horizon is not None else "average cost"


def _fmt(x: float) -> str:
    if x is None or not np.isfinite(x):
        return str(x)
    ax = abs(x)
    if ax != 0 and (ax >= 1e7 or ax < 1e-3):
        return f"{x:.4e}"
    return f"{x:.2f}" if ax >= 100 else f"{x:.4f}"


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
            if all(not isinstance(v, (dict, list, tuple)) for v in x):
                return "[" + ", ".join(json.dumps(v) for v in x) + "]"
            return "[\n" + ",\n".join(inner + enc(v, level + 1) for v in x) + "\n" + pad + "]"
        return json.dumps(x)

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
    if getattr(args, "json", False):
        print(dumps_json(out))
        return 0
    m = sc.model
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
    return 0


def _cmd_evaluate(args: argparse.Namespace) -> int:
    from . import _validation as V

    sc = _load(args.scenario)
    if getattr(sc, "model", None) is not None and not hasattr(sc, "designs"):
        if args.monte_carlo:
            raise ScenarioError("--monte-carlo: a population scenario is evaluated exactly; nothing needs simulating")
        return _cmd_population(sc, args)
    runs = args.monte_carlo
    if runs is not None:
        if sc.horizon is None:
            raise ScenarioError(
                f"horizon: --monte-carlo needs a finite horizon, but scenario {sc.name!r} has none (steady state); add horizon = T to the scenario"
            )
        if runs < 2:
            raise ScenarioError(f"--monte-carlo: expected at least 2 runs (for a confidence interval), found {runs}")
    if args.plot:
        V.require("matplotlib", "plot")  # fail before the work, with the install command

    designs = sc.designs()
    mc: dict[str, Any] = {}
    seed = args.seed
    from .study.evaluate import DEFAULT_MC_RUNS

    mc_only = [name for name, d in designs.items() if d.stage_costs is None and d.average_cost is None]  # e.g. kcf
    if runs is None and mc_only:
        runs = DEFAULT_MC_RUNS
        simulate = {name: designs[name] for name in mc_only}
    else:
        simulate = designs
    if runs is not None:
        from .simulation.monte_carlo import monte_carlo

        if seed is None:
            seed = int(np.random.SeedSequence().entropy % (2**32))  # type: ignore[operator]
        mc = monte_carlo(simulate, sc.horizon, runs, rng=seed, scheduler=args.scheduler)

    notes: list[str] = []
    if args.plot:
        notes.append(_plot_stage_costs(designs, sc, args.plot))

    control = _control_summary(sc, runs, seed)
    if args.json:
        out: dict[str, Any] = {"scenario": sc.name, "horizon": sc.horizon, "estimators": {}}
        if control:
            out["control"] = control
        if mc:  # what repeats the Monte Carlo: seed, runs, block and chunk sizes, teamkf version
            out["monte_carlo"] = {
                k: v for k, v in next(iter(mc.values())).summary().items() if k in ("runs", "seed", "batch", "chunk", "teamkf_version")
            }
        for name, d in designs.items():
            if name in mc_only:
                out["estimators"][name] = {**mc[name].summary(), **({"variant": d.info["variant"]} if "variant" in d.info else {})}
                continue
            entry = d.summary()
            if name in mc:
                r = mc[name]
                lo, hi = r.ci95
                merged: dict[str, Any] = {}
                for k, v in entry.items():
                    merged[k] = v
                    if k in ("total_cost", "average_cost"):
                        merged["mc_cost"] = float(r.total_mean)
                        merged["mc_ci95"] = [float(lo), float(hi)]
                entry = merged
            out["estimators"][name] = entry
        print(dumps_json(out))
        for n in notes:
            print(n, file=sys.stderr)
        return 0

    ref = designs.get("mtmse")
    headers = ["estimator", _cost_label(sc.horizon)]
    if ref is not None:
        headers.append("vs mtmse")
    if mc:
        headers += ["MC mean", "MC 95% CI"]
    ref_value = _cost_value(ref) if ref is not None else 1.0
    rows = []
    for name, d in designs.items():
        v = mc[name].total_mean if name in mc_only else _cost_value(d)
        label = f"{name} [{d.info['variant']}]" if "variant" in d.info else name
        row = [label, _fmt(v) + (" (MC)" if name in mc_only else "")]
        if ref is not None:
            row.append(f"{100.0 * (v - ref_value) / ref_value:+.2f} %")
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


def _plot_stage_costs(designs: dict[str, Any], sc: Any, out: str) -> str:
    from .plotting import stage_cost_axes

    ax = stage_cost_axes(list(designs.values()), title=f"{sc.name}: stage costs")
    fig = ax.figure
    fig.tight_layout()
    path = Path(out)
    if path.parent and not path.parent.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    import matplotlib.pyplot as plt

    plt.close(fig)
    return f"plot written to {path}"


# ---------------------------------------------------------------------------
# design
# ---------------------------------------------------------------------------
def _gain_arrays(name: str, d: Any) -> dict[str, np.ndarray]:
    """The arrays of one design for ``--out`` (npz keys ``name/...``)."""
    out: dict[str, np.ndarray] = {}
    if d.horizon is not None:
        out[f"{name}/stage_costs"] = np.asarray(d.stage_costs, dtype=float)
        out[f"{name}/total_cost"] = np.asarray(d.total_cost, dtype=float)
    else:
        out[f"{name}/average_cost"] = np.asarray(d.average_cost, dtype=float)
    out[f"{name}/K"] = np.asarray(d.K, dtype=float)
    if name == "centralized":
        return out
    steps = d.gains if d.horizon is not None else [d.gain_at(k) for k in range(d.structure.common_lag)]
    for k, step in enumerate(steps):
        for i, F in enumerate(step):
            out[f"{name}/F_{i}_t{k}"] = np.asarray(F, dtype=float)
    if d.steady_gains is not None:
        for i, F in enumerate(d.steady_gains):
            out[f"{name}/F_{i}"] = np.asarray(F, dtype=float)
    st = d.structure
    for i in range(st.n_agents):
        out[f"{name}/local_{i}"] = np.asarray(st.local_lags(i), dtype=np.int64).reshape(-1, 2)
    return out


def _gain_shapes(name: str, d: Any) -> dict[str, list[int]]:
    if name == "centralized":
        K = np.asarray(d.K)
        return {"K": list(K.shape[-2:])}
    last = d.steady_gains if d.steady_gains is not None else d.gains[-1]
    return {f"F_{i}": list(np.asarray(F).shape) for i, F in enumerate(last)}


def _design_summary(name: str, d: Any, sc: Any) -> dict[str, Any]:
    entry = {k: v for k, v in d.summary().items() if k != "stage_costs"}
    if name == "centralized":
        entry["local_dims"] = None
    else:
        entry["local_dims"] = list(d.structure.local_dims(sc.system.dy))
    entry["gain_shapes"] = _gain_shapes(name, d)
    return entry


def _cmd_design(args: argparse.Namespace) -> int:
    sc = _load(args.scenario)
    if getattr(sc, "model", None) is not None and not hasattr(sc, "designs"):
        if args.out:
            out = sc.evaluate()
            path = Path(args.out)
            path.parent.mkdir(parents=True, exist_ok=True)
            with open(path, "wb") as fh:
                np.savez(fh, gains=np.asarray(out["gains"]), state_variance=np.asarray(out["state_variance_trajectory"]))
        return _cmd_population(sc, args)
    designs = sc.designs()
    notes = []
    if args.out:
        arrays: dict[str, np.ndarray] = {"scenario": np.asarray(sc.name), "horizon": np.asarray(-1 if sc.horizon is None else sc.horizon)}
        for name, d in designs.items():
            arrays.update(_gain_arrays(name, d))
        path = Path(args.out)
        if path.parent and not path.parent.exists():
            path.parent.mkdir(parents=True, exist_ok=True)
        with open(path, "wb") as fh:  # np.savez would append .npz to a name without it
            np.savez(fh, **arrays)  # type: ignore[arg-type]
        notes.append(f"gains written to {path} ({len(arrays)} arrays; keys like '{next(iter(designs))}/...'; horizon -1 means steady state)")
    if args.json:
        out = {"scenario": sc.name, "horizon": sc.horizon, "estimators": {name: _design_summary(name, d, sc) for name, d in designs.items()}}
        print(dumps_json(out))
        for n in notes:
            print(n, file=sys.stderr)
        return 0
    when = f"gains at the last step t = {sc.horizon}" if sc.horizon is not None else "steady-state gains"
    print(_header(sc))
    print()
    rows = []
    for name, d in designs.items():
        s = _design_summary(name, d, sc)
        dims = "all (centralized)" if s["local_dims"] is None else ", ".join(map(str, s["local_dims"]))
        shapes = ", ".join(f"{k} {'x'.join(map(str, v))}" for k, v in s["gain_shapes"].items())
        rows.append([name, _fmt(_cost_value(d)), dims, shapes])
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

    with use_scheduler(args.scheduler):
        res = experiments.run(args.name, args.out, quick=args.quick)
    if args.json:
        print(json.dumps(res.to_json(), indent=2, default=float))
        return 0
    print(res.title)
    print(res.format_table())
    if res.notes:
        print("\n" + res.notes)
    if args.out:
        where = ", ".join(res.figures) if res.figures else "no plots (pip install 'teamkf[plot]' for them)"
        print(f"\nwritten to {args.out}: {res.name}.csv, {res.name}.json; {where}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    debug_help = "show the full traceback of an error"
    parser = argparse.ArgumentParser(
        prog="teamkf",
        description="Design and evaluate decentralized team estimators (MTMSE, per-agent MMSE, centralized Kalman) from scenario files.",
        epilog="SCENARIO is a .toml/.json scenario file or a packaged scenario name (platoon-4, platoon-4-is1, platoon-4-steady, uav-4, uav-10).",
    )
    parser.add_argument("--version", action="version", version=f"teamkf {_version()}")
    parser.add_argument("--debug", action="store_true", help=debug_help)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    def add(name: str, help: str) -> argparse.ArgumentParser:
        p = sub.add_parser(name, help=help, description=help)
        p.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help=debug_help)
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
        default="serial",
        metavar="ADDRESS",
        help="where grid points run: serial (default), local (an embedded Dask cluster) or a Dask scheduler address",
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
    return parser


def _one_line(exc: BaseException) -> str:
    if isinstance(exc, OSError) and exc.strerror:
        where = f"{exc.filename}: " if exc.filename else ""
        return f"{where}{exc.strerror}"
    text = " ".join(str(exc).split())
    return text or type(exc).__name__


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``teamkf`` command; returns the exit status (0 success, 2 error)."""
    parser = build_parser()
    try:
        args = parser.parse_args(list(argv) if argv is not None else None)
    except SystemExit as exc:  # --help, --version, usage errors
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 2)
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
