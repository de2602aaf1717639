"""The ``teamkf`` command: evaluate, design, filter, measurements, sweep, reproduce, demo, families, deploy, agent, record, roster.

``teamkf --help`` lists the commands and the families, ``teamkf COMMAND --help`` a command's options;
``docs/scenario-and-cli.md`` specifies them and the file formats (a contract, tested against this parser).
``SCENARIO`` is a scenario file (TOML, or JSON by its ``.json`` extension) or the name of a packaged
scenario (``platoon-4``, ``uav-10``, ...). ``--debug`` shows the traceback of an error; without it an error
is one line ``teamkf: error: <message>`` on stderr and exit status 2. Output into a closed pipe
(``teamkf ... | head``) ends silently with status 1, as CPython's "Note on SIGPIPE" advises.
"""

from __future__ import annotations

import argparse
import os
import sys
import traceback
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping, Sequence

from . import _budget
from ._lazy import lazy_module
from ._version import __version__
from .exceptions import ArgumentError, ScenarioError, TeamkfError
from .study.deploy_args import count  # the argparse type of a whole number with a floor
from .study.textout import dumps_json, format_table

if TYPE_CHECKING:
    import numpy as np
else:  # imported on first use: --help, --version and every COMMAND --help start without numpy
    np = lazy_module("numpy")

__all__ = ["main", "build_parser", "dumps_json", "format_table"]


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


# the formatting lives in teamkf.study.report (imported on first use: --help starts without numpy)
def _cost_label(horizon: int | None) -> str:
    from .study.report import cost_label

    return cost_label(horizon)


def _fmt(x: float | None) -> str:
    from .study.report import fmt

    return fmt(x)


def _header(sc: Any) -> str:
    if sc.horizon is not None:
        what = f"horizon T = {sc.horizon}, J_T = sum over t of E[c(x(t), z(t))]"
    else:
        what = "infinite horizon (steady state), average cost per step"
    info = "reduced information structure from [information]" if sc.has_reduced_information else "full information structure of the graph"
    from .study.report import link_record, link_text

    links = f"\n  links: {link_text(link_record(sc.links))} ([network])" if sc.links is not None else ""
    return (
        f"scenario {sc.name}: {sc.n_agents} agents, d_x = {sc.system.dx}, {what}\n"
        f"  graph: {sc.graph!r}; {info} (common lag {sc.information.common_lag}){links}"
    )


# ---------------------------------------------------------------------------
# evaluate
# ---------------------------------------------------------------------------
def _cmd_population(sc: Any, args: argparse.Namespace) -> int:
    """evaluate / design of a [population] scenario: exact statistics, nothing simulated (:func:`teamkf.study.evaluation.evaluate`)."""
    from .study.evaluation import evaluate

    ev = evaluate(sc)
    out = dict(ev.details)
    if out.get("diverged"):
        _warn(
            f"{out['filter']} filter: the closed loop diverges (Var x_k beyond 4.5e11 times the noise variance) from step {out['diverged_at']}"
            + ("; the numbers from there on are reported as diverged / null" if not np.isfinite(out["state_variance"]) else "")
        )
    if getattr(args, "json", False):
        rows = {r["estimator"]: {k: v for k, v in r.items() if k != "estimator" and v is not None} for r in ev.json_rows()}
        print(dumps_json({**out, "schema_version": ev.schema_version, "estimators": rows}))
        return 0
    print(sc.describe_result(out))
    return 0


def _check_output(path: str, flag: str, suffixes: Sequence[str] | str | None = None, inputs: Sequence[Any] = ()) -> Path:
    """Fail before any work when an output path is an input, has the wrong extension, or lies in a missing folder (teamkf.study.outputs)."""
    from .study.outputs import check_output

    return check_output(path, flag, fmt=suffixes, inputs=inputs)


def _write_atomic(path: Path, write: Any) -> None:
    """Write through a temporary file in the same folder, renamed at the end: no partial file on failure."""
    from .study.outputs import write_atomic

    write_atomic(path, write)


def _warn(message: str) -> None:
    print(f"teamkf: warning: {message}", file=sys.stderr)


def _cmd_evaluate(args: argparse.Namespace) -> int:
    """``teamkf evaluate``: parse, call :func:`teamkf.study.evaluation.evaluate`, then print, write or plot its rows."""
    from . import _validation as V
    from .study.evaluation import check_capabilities, evaluate

    sc = _apply_network_flags(_load(args.scenario), args)
    plot_to = _check_output(args.plot, "--plot", _PLOT_SUFFIXES, inputs=[args.scenario]) if args.plot is not None else None
    if args.scheduler is not None:  # checked even when nothing ends up simulated: a typo must not pass silently
        _check_scheduler(args.scheduler)
    if not sc.simulates:  # a [population] scenario: exact statistics, nothing simulated
        if args.monte_carlo:
            raise ArgumentError("--monte-carlo: a population scenario is evaluated exactly; nothing needs simulating", argument="--monte-carlo")
        if plot_to is not None:
            raise ArgumentError(
                "--plot: a population scenario has no stage costs to plot; use teamkf reproduce bulk-* for its figures", argument="--plot"
            )
        if args.seed is not None:
            _warn("--seed is ignored: a population scenario is evaluated exactly, nothing is sampled")
        return _cmd_population(sc, args)
    runs = args.monte_carlo or 0
    if runs == 1:
        raise ArgumentError("--monte-carlo: expected at least 2 runs (for a confidence interval), found 1", argument="--monte-carlo")
    if runs and sc.horizon is None:
        raise ArgumentError(
            f"horizon: --monte-carlo needs a finite horizon, but scenario {sc.name!r} has none (steady state); add horizon = T to the scenario",
            argument="horizon",
        )
    names = sc.estimators
    mc_only = [n for n in names if not sc.family(n).analytic_cost]
    check_capabilities(sc, names if runs else mc_only, simulate=bool(runs or mc_only))
    if plot_to is not None:
        V.require("matplotlib", "plot")  # fail before the work, with the install command
    if args.seed is not None and not runs and not mc_only:
        _warn("--seed is ignored without Monte Carlo (every estimator of this scenario has an analytic cost); add --monte-carlo RUNS")
    if args.scheduler not in (None, "serial", "local"):
        _check_scheduler(args.scheduler)
    try:
        ev = evaluate(sc, runs=runs, seed=args.seed, scheduler=args.scheduler)
    except ArgumentError as exc:
        raise (exc.rekeyed("--monte-carlo") if exc.argument in ("n_runs", "runs") else exc) from None
    for r in ev.rows:
        if r["diverged"]:
            d, mc = ev.designs[r["estimator"]], ev.monte_carlo.get(r["estimator"])
            _warn(f"{r['estimator']}: the team cost diverges (not finite){_divergence_step(d, mc)}; reported as diverged / null")
    notes: list[str] = []
    if plot_to is not None:
        notes.append(_plot_stage_costs(ev.designs, ev.monte_carlo, sc, plot_to))
    if args.json:
        print(dumps_json(_evaluation_json(ev)))
        for n in notes:
            print(n, file=sys.stderr)
        return 0
    print(_header(sc))
    print()
    print(_evaluation_table(ev))
    control = ev.details.get("control")
    if control:
        print("\n  decentralized LQG ([control], one-step delayed sharing, Appendix D):")
        for name, entry in control.items():
            extra = (
                f"   closed-loop MC {_fmt(entry['mc_cost'])} [{_fmt(entry['mc_ci95'][0])}, {_fmt(entry['mc_ci95'][1])}]" if "mc_cost" in entry else ""
            )
            print(f"    {name:22s} J = {_fmt(entry['total_cost'])}{extra}")
    if ev.runs:
        print(
            f"\n  Monte Carlo: {ev.runs} runs, seed {ev.seed} (online agents on sampled paths; analytic values in the {_cost_label(sc.horizon)} column)"
        )
    for n in notes:
        print(n)
    return 0


def _evaluation_json(ev: Any) -> dict[str, Any]:
    """``teamkf evaluate --json`` (:func:`teamkf.study.report.evaluation_json`)."""
    from .study.report import evaluation_json

    return evaluation_json(ev, __version__)


def _evaluation_table(ev: Any) -> str:
    """The text table of an evaluation (:func:`teamkf.study.report.evaluation_table`)."""
    from .study.report import evaluation_table

    return evaluation_table(ev)


_PLOT_SUFFIXES = (".png", ".pdf", ".svg", ".jpg", ".jpeg")


def _strict_rows(out: dict[str, Any]) -> dict[str, Any]:
    """Rows with every non-finite number as null, and ``"non_finite": {column: "inf" | "-inf" | "nan"}`` saying which (strict JSON)."""
    rows = []
    for r in out.get("rows", []):
        bad = {k: str(float(v)) for k, v in r.items() if isinstance(v, (float, np.floating)) and not np.isfinite(v)}
        rows.append({**r, "non_finite": bad} if bad else r)
    return {**out, "rows": rows}


def _divergence_step(design: Any, mc: Any) -> str:
    stages = design.stage_costs if design.stage_costs is not None else (mc.stage_mean if mc is not None else None)
    if stages is None:
        return ""
    bad = np.flatnonzero(~np.isfinite(np.asarray(stages)))
    return f" from step {int(bad[0])}" if bad.size else ""


def _plot_stage_costs(designs: Mapping[str, Any], mc: Mapping[str, Any], sc: Any, out: Path) -> str:
    from .plotting import stage_cost_axes

    # analytic curves, and every Monte Carlo mean with its 95 % band (markers where an analytic curve is drawn)
    analytic = [d for d in designs.values() if d.has_analytic_cost]
    from .study.report import link_record, link_text

    links = f" (links: {link_text(link_record(sc.links))})" if sc.has_lossy_links else ""
    ax = stage_cost_axes(analytic, title=f"{sc.name}: stage costs{links}", monte_carlo={name: mc[name] for name in designs if name in mc})
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
    out_path = _check_output(args.out, "--out", "npz", inputs=[args.scenario]) if args.out is not None else None
    if not sc.simulates:  # a [population] scenario: its gains are exact statistics
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
        from .study.slices import design_out_arrays as more  # E/... and, per agent, its slice slices/E/i/... (teamkf agent --design)

        arrays: dict[str, np.ndarray] = {"scenario": np.asarray(sc.name), "horizon": np.asarray(sc.horizon or -1), **more(sc, designs)}  # -1: steady
        _write_atomic(out_path, lambda fh: np.savez(fh, **arrays))  # type: ignore[arg-type]  # a file handle: no suffix added
        notes.append(f"gains written to {out_path} ({len(arrays)} arrays; keys like '{next(iter(designs))}/...'; horizon -1 means steady state)")
    if args.json:
        out = {
            "scenario": sc.name,
            "horizon": sc.horizon,
            "teamkf_version": __version__,
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

    _check_output_dir(args.out, "--out")
    run_demo(out_dir=args.out, quick=args.quick, echo=True)
    return 0


def _cmd_sweep(args: argparse.Namespace) -> int:
    from .study.sweep import load_sweep, run_sweep

    spec = load_sweep(args.sweep)  # everything is checked before anything is written
    out = _check_output_dir(args.out, "--out") if args.out is not None else Path(f"{Path(args.sweep).stem}.parquet")
    _check_output_dir(str(out), "--out" if args.out is not None else "--out (default)", inputs=[args.sweep, spec.scenario])
    scheduler = args.scheduler or "local"
    _check_scheduler(scheduler)
    if args.workers is not None and scheduler != "local":
        _warn(f"--workers is ignored with --scheduler {scheduler}: it sets the worker processes of the local cluster (--scheduler local)")
    try:
        res = run_sweep(spec, out, scheduler=scheduler, resume=args.resume, progress=True, n_workers=args.workers)
    except KeyboardInterrupt:
        kept = f"the finished points are kept in {out}; run the same command with --resume to continue" if out.exists() else "nothing was written"
        print(f"teamkf: interrupted; {kept}", file=sys.stderr)
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
                    "rows": _strict_rows({"rows": [dict(r) for r in res.rows]})["rows"],  # non-finite costs: null and a non_finite mark
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
    from .study.report import SWEEP_NOTE, sweep_cell

    by_point: dict[str, dict[str, Any]] = {}
    cells = {(r["point_id"], r["estimator"]): sweep_cell(r, key) for r in res.rows}  # "*": a perfect-link cost at a lossy point
    for r in res.rows:
        by_point.setdefault(r["point_id"], {k: r[k] for k in res.grid_keys})[r["estimator"]] = cells[(r["point_id"], r["estimator"])][0]
    limit = 30
    table = [[*(p[k] for k in res.grid_keys), *(p.get(e, "-") for e in spec.estimators)] for p in list(by_point.values())[:limit]]
    print(format_table([*res.grid_keys, *spec.estimators], table, align="r" * (len(res.grid_keys) + len(spec.estimators))))
    if len(by_point) > limit:
        print(f"  ... and {len(by_point) - limit} more points")
    mc = " (Monte Carlo means for estimators without one; analytic estimators also have mc_cost)" if spec.runs else ""
    print(f"\n  {_cost_label(spec.base.horizon) if key == 'total_cost' else 'average cost'} per estimator{mc}")
    if any(marked for _, marked in cells.values()):
        print(f"  {SWEEP_NOTE}")
    print(
        f"\nresults: {out} ({len(res.rows)} rows; {res.n_computed} points computed now, {res.n_resumed} already there); "
        f"read them with pandas.read_parquet({str(out)!r}) or teamkf.study.results.SweepResult.load"
    )
    return 0


# ---------------------------------------------------------------------------
# filter: recorded measurements (teamkf.study.measurements)
# ---------------------------------------------------------------------------
def _cmd_filter(args: argparse.Namespace) -> int:
    """``teamkf filter SCENARIO --measurements FILE [--truth FILE] --out FILE [--estimators ...]`` (:mod:`teamkf.study.filtering`)."""
    from . import get_family
    from .study.recording import filter_to_files  # teamkf.study.filtering's, and MCAP (a ROS 2 recording, --map)

    inputs = [args.scenario, args.measurements, args.truth, args.drops, args.map]
    out_path = _check_output(args.out, "--out", (".csv", ".parquet", ".mcap"), inputs=inputs)
    if args.drops:  # replay a deployment's drop record (teamkf deploy --record)
        from .study.deploy import cmd_filter_drops

        return cmd_filter_drops(args)
    cost_path = out_path.with_name(f"{out_path.stem}-cost{out_path.suffix}") if args.truth and out_path.suffix.lower() != ".mcap" else None
    if cost_path is not None:
        _check_output(str(cost_path), "--out (its cost file)", (".csv", ".parquet"), inputs=inputs)
    sc = _load(args.scenario)
    sc.require_simulation("teamkf filter", "SCENARIO")
    names = list(args.estimators) if args.estimators else list(sc.estimators)
    for k, name in enumerate(names):
        get_family(name, f"--estimators[{k}]")
    run = filter_to_files(
        sc, args.measurements, out_path, estimators=names, truth=args.truth, cost_out=cost_path, chunk_rows=args.chunk_rows, topic_map=args.map
    )
    if args.json:
        print(dumps_json(run.summary))
        return 0
    print("\n".join(run.lines))
    if run.total_costs is not None:
        print(format_table(["estimator", "realized team cost (sum over steps)"], [[k, _fmt(v)] for k, v in run.total_costs.items()], align="lr"))
        print(f"per-step realized costs written to {cost_path or out_path}")
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
    sc.require_simulation("unreliable links (--p-drop/--jitter)", "--p-drop")
    if not getattr(args, "monte_carlo", None):
        _warn("--p-drop/--jitter act on the simulated agents; add --monte-carlo RUNS (analytic costs other than mtmse_lossy's assume reliable links)")
    return sc.updated(vals)


# ---------------------------------------------------------------------------
# parser and main
# ---------------------------------------------------------------------------
_positive_int = count(1, "a whole number", phrase="a whole number >= 1")
_seed = count(0, "a seed", phrase="a non-negative integer seed")


def _cmd_reproduce(args: argparse.Namespace) -> int:
    from . import experiments

    if args.list or not args.name:
        if not args.list:
            return _error("reproduce needs an experiment NAME (or --list)")
        for name in experiments.names():
            print(f"{name:14s} {experiments.get(name).title}")
        return 0
    experiments.get(args.name)  # an unknown name fails before any work
    if args.out is not None:
        _check_output_dir(args.out, "--out")
    if args.scheduler not in (None, "serial"):
        _check_scheduler(args.scheduler)
    try:
        res = experiments.run(args.name, args.out, quick=args.quick, scheduler=args.scheduler)
    except TeamkfError as exc:
        raise (exc.rekeyed("--scheduler") if isinstance(exc, ArgumentError) and exc.argument == "scheduler" else exc) from None
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
    """Fail fast (2 s) when a Dask scheduler address is malformed or nothing listens there (:func:`teamkf.study.outputs.check_scheduler`)."""
    from .study.outputs import check_scheduler

    check_scheduler(address, "--scheduler")


def _check_output_dir(path: str, flag: str, inputs: Sequence[Any] = ()) -> Path:
    """An output folder that exists or whose parent exists, writable, not an input; checked before any work."""
    from .study.outputs import check_output_dir

    return check_output_dir(path, flag, inputs=inputs)


def _help_text() -> tuple[str, str]:
    """The description and epilog of ``teamkf --help``: every family (from :func:`~teamkf.study.catalog.family_listing`) and packaged scenario."""
    from .study.catalog import family_listing, packaged_scenarios

    lines = [
        "Design, run and evaluate decentralized estimators for teams of agents that share information over a",
        "communication graph with delays. Estimator families (estimators = [...] in a scenario file):",
        "",
    ]
    for name, fam in family_listing().items():
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
    """argparse with usage errors as one line ``teamkf: error: <argument>: <what is wrong>`` (exit status 2).

    The top-level description (every registered family) is built only when help is printed: ``teamkf
    --version`` and every command start without importing the families.
    """

    lazy_help = False

    def format_help(self) -> str:
        if self.lazy_help and self.description is None:
            self.description, self.epilog = _help_text()
        return super().format_help()

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
    parser = _Parser(prog="teamkf", formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.lazy_help = True  # the family list is read from the registry only when --help is asked for
    parser.add_argument("--version", action="version", version=f"teamkf {__version__}")
    parser.add_argument("--debug", action="store_true", help=debug_help)
    parser.add_argument("--plugin", action="append", default=[], metavar="MODULE", help=plugin_help)
    quiet_help = "no progress bars (they appear only on a terminal, after 2 s; TEAMKF_PROGRESS=0 also silences them)"
    parser.add_argument("--quiet", action="store_true", help=quiet_help)
    hours_help = "refuse a job whose estimated computing time exceeds H hours (default 2, or TEAMKF_MAX_HOURS); raise it to run a longer one"
    parser.add_argument("--max-hours", type=_budget.hours_argument, metavar="H", help=hours_help)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    def add(name: str, help: str, within: Any = None) -> argparse.ArgumentParser:
        """A command (``within``: a group's subparsers, e.g. ``measurements convert``) with the options every command takes."""
        p = (within or sub).add_parser(name, help=help, description=help)
        p.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help=debug_help)
        p.add_argument("--quiet", action="store_true", default=argparse.SUPPRESS, help=quiet_help)
        p.add_argument("--no-progress", dest="quiet", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS)  # 0.2 name
        p.add_argument("--plugin", action="append", default=argparse.SUPPRESS, metavar="MODULE", help=plugin_help)
        p.add_argument("--max-hours", type=_budget.hours_argument, default=argparse.SUPPRESS, metavar="H", help=hours_help)
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
    p.add_argument("--workers", type=_positive_int, metavar="N", help="worker processes of the local cluster (default: one per core)")
    p.add_argument("--json", action="store_true", help="print one JSON object (counts and every row)")
    p.set_defaults(func=_cmd_sweep)

    from .study.recording_args import add_filter_parser  # filter; measurements convert (MCAP)
    from .study.recording_args import add_parsers as add_measurements_parsers

    add_filter_parser(add, _cmd_filter, _positive_int)
    add_measurements_parsers(add)

    p = add("families", "list the registered estimator families: name, cost, capabilities, options (built-in and plug-ins)")
    p.add_argument("--json", action="store_true", help="print one JSON object: name -> record")
    p.set_defaults(func=_cmd_families)
    from .study.deploy_args import add_parsers as add_deploy_parsers  # teamkf deploy, teamkf agent

    add_deploy_parsers(add)
    return parser


def _cmd_families(args: argparse.Namespace) -> int:
    from . import families

    records = {name: fam.describe() for name, fam in families().items()}
    if args.json:
        print(dumps_json(records))
        return 0
    rows = [
        [n, r["cost"], ", ".join(c for c in r["capabilities"] if c != "analytic_cost") or "-", ", ".join(r["options"]) or "-", r["title"]]
        for n, r in records.items()
    ]
    print(format_table(["family", "cost", "capabilities", "options", "what it is"], rows, align="lllll"))
    return 0


def _error(text: str) -> int:
    """Print the one error line ``teamkf: error: <text>`` on stderr; returns the exit status 2."""
    print(f"teamkf: error: {' '.join(str(text).split())}", file=sys.stderr)
    return 2


def _one_line(exc: BaseException) -> str:
    if isinstance(exc, OSError) and exc.strerror:
        where = f"{exc.filename}: " if exc.filename else ""
        return f"{where}{exc.strerror}"
    text = " ".join(str(exc).split())
    return text or type(exc).__name__


def _plugin_frame(exc: BaseException) -> str | None:
    """``plugin NAME (FILE), in FUNCTION()`` for the innermost traceback frame in a loaded plug-in, or None."""
    from . import loaded_plugins

    plugins = {name: path for name, path, _ in loaded_plugins()}
    files = {path: name for name, path in plugins.items() if path}
    tb, found = exc.__traceback__, None
    while tb is not None:
        frame = tb.tb_frame
        mod = frame.f_globals.get("__name__", "") if isinstance(getattr(frame, "f_globals", None), dict) else ""
        root = next((p for p in plugins if mod == p or mod.startswith(p + ".")), None)
        if root is None and frame.f_code.co_filename in files:
            root = files[frame.f_code.co_filename]
        if root is not None:
            found = f"plugin {root}" + (f" ({plugins[root]})" if plugins[root] else "") + f", in {frame.f_code.co_name}()"
        tb = tb.tb_next
    return found


def _resource_line(exc: BaseException) -> str:
    """One line for an error that a size or encoding check should have caught first."""
    what = {
        MemoryError: "not enough memory for this request",
        RecursionError: "the input is nested too deeply",
        OverflowError: "a number is too large for the computation",
    }
    head = next((w for t, w in what.items() if isinstance(exc, t)), "the input is not valid UTF-8 text")
    return f"{head} ({type(exc).__name__}: {_one_line(exc)[:200]}); use smaller sizes or check the input (--debug shows where)"


def _report_warnings(caught: Sequence[Any]) -> None:
    """numpy's RuntimeWarnings of a command, as one ``teamkf: warning:`` line each kind (non-finite results are flagged in the output)."""
    kinds: dict[str, int] = {}
    for w in caught:
        if issubclass(w.category, RuntimeWarning):
            msg = " ".join(str(w.message).split())
            kinds[msg] = kinds.get(msg, 0) + 1
        else:
            import warnings

            warnings.showwarning(w.message, w.category, w.filename, w.lineno)
    for msg, k in kinds.items():
        _warn(f"numerical {msg}{f' ({k} times)' if k > 1 else ''}; results that are not finite are reported as diverged / null")


def _load_plugins(argv: Sequence[str]) -> None:
    """Import the --plugin modules first, so that their families appear in --help and in scenario files."""
    specs = [argv[k + 1] for k, a in enumerate(argv[:-1]) if a == "--plugin"] + [a.split("=", 1)[1] for a in argv if a.startswith("--plugin=")]
    if specs:
        from . import load_plugin

        for spec in specs:
            load_plugin(spec)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``teamkf`` command; returns the exit status (0 success, 2 error, 1 output into a closed pipe)."""
    try:
        rc = _main(argv)
        sys.stdout.flush()  # here, not at exit: a reader that left (``| head``) shows up inside the try
        return rc
    except BrokenPipeError:  # silent, as CPython's "Note on SIGPIPE": stdout to devnull (for the flush at exit), status 1
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1


def _main(argv: Sequence[str] | None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        _load_plugins(argv)
    except TeamkfError as exc:
        if "--debug" in argv:
            traceback.print_exc()
        return _error(_one_line(exc))
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, --version
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 2)
    except _UsageError as exc:
        return _error(str(exc))
    import warnings

    from ._budget import command_settings as _settings  # --max-hours, and every TEAMKF_* variable checked
    from ._progress import quiet

    try:
        # numpy's RuntimeWarnings: one summary line, never raw; --quiet holds for this command only
        with warnings.catch_warnings(record=True) as caught, quiet(getattr(args, "quiet", False)), _settings(getattr(args, "max_hours", None)):
            warnings.simplefilter("always", RuntimeWarning)
            rc = int(args.func(args))
        _report_warnings(caught)
        return rc
    except BrokenPipeError:
        raise
    except (TeamkfError, OSError) as exc:
        if getattr(args, "debug", False):
            traceback.print_exc()
        return _error(_one_line(exc))
    except (MemoryError, RecursionError, OverflowError, UnicodeError) as exc:  # a size no check foresaw: still one line
        if getattr(args, "debug", False):
            traceback.print_exc()
        return _error(_resource_line(exc))
    except Exception as exc:
        where = _plugin_frame(exc)
        if where is None:  # not from a user's plug-in: a teamkf bug, shown in full
            raise
        if getattr(args, "debug", False):
            traceback.print_exc()
        return _error(f"{where} raised {type(exc).__name__}: {_one_line(exc)} (--debug shows the traceback)")
    except KeyboardInterrupt:  # pragma: no cover - interactive
        print("teamkf: interrupted", file=sys.stderr)
        return 130
