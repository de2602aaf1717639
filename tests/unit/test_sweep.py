"""Unit tests for parameter sweeps: teamkf.study.sweep, teamkf.study.results and `teamkf sweep`.

The Dask tests start real LocalClusters with 2 worker processes; they are
skipped where the ``dask`` extra is not installed (``make test`` installs it).
"""

from __future__ import annotations

import importlib.util
import io
import json
import os
import signal
import time
from pathlib import Path

import numpy as np
import pytest

from teamkf import __version__
from teamkf.cli import main
from teamkf.exceptions import ConvergenceError, ScenarioError
from teamkf.study import sweep as sweep_mod
from teamkf.study.evaluate import evaluate_point
from teamkf.study.results import CostCurves, SweepError, SweepResult
from teamkf.study.sweep import A_SCALE, apply_point, load_sweep, point_id, run_sweep, sweep_from_dict

ROOT = Path(__file__).resolve().parents[2]
PACKAGED = ROOT / "src" / "teamkf" / "scenarios"
HAS_ARROW = importlib.util.find_spec("pyarrow") is not None and importlib.util.find_spec("pandas") is not None
HAS_MPL = importlib.util.find_spec("matplotlib") is not None
needs_arrow = pytest.mark.skipif(not HAS_ARROW, reason="needs the dask extra (pyarrow, pandas)")

CONTRACT = {"estimator", "total_cost", "ci95_low", "ci95_high", "runs", "seed", "teamkf_version", "point_id", "method"}


# ---------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------
def write_files(tmp_path: Path, sweep_body: str, *, horizon: int | None = 8, name: str = "s") -> Path:
    """A short-horizon platoon in tmp/scen/short.toml and a sweep file tmp/<name>.toml using it."""
    text = (PACKAGED / "platoon-4.toml").read_text()
    text = text.replace("horizon = 100 ", f"horizon = {horizon} " if horizon is not None else "# no horizon ")
    (tmp_path / "scen").mkdir(exist_ok=True)
    (tmp_path / "scen" / "short.toml").write_text(text)
    p = tmp_path / f"{name}.toml"
    p.write_text(sweep_body)
    return p


SMALL = """
scenario = "scen/short.toml"
runs = {runs}
seed = 7
[grid]
"cost.lambda" = [1.0, 10.0]
"graph.delay" = [1, 2]
"""


def small_sweep(tmp_path: Path, runs: int = 0, name: str = "s") -> Path:
    return write_files(tmp_path, SMALL.format(runs=runs), name=name)


def frame(path: Path):
    import pandas as pd

    df = pd.read_parquet(path)
    return df.sort_values(["point_index", "estimator"]).reset_index(drop=True)


def parts(path: Path) -> list[str]:
    return sorted(p.name for p in path.iterdir() if p.name.startswith("part-"))


class Counter:
    """A point function that counts its calls (serial runs only)."""

    def __init__(self, stop_after: int | None = None):
        self.calls = 0
        self.stop_after = stop_after

    def __call__(self, scenario, estimators, runs, seed):
        self.calls += 1
        if self.stop_after is not None and self.calls > self.stop_after:
            raise KeyboardInterrupt
        return evaluate_point(scenario, estimators, runs, seed)


def slow_evaluate(scenario, estimators, runs, seed):
    """evaluate_point, slowed down (for killing a worker mid-sweep); importable on Dask workers."""
    time.sleep(0.6)
    return evaluate_point(scenario, estimators, runs, seed)


# ---------------------------------------------------------------------------
# loading
# ---------------------------------------------------------------------------
def test_load_sweep_grid_points_ids_and_seeds(tmp_path, monkeypatch):
    p = write_files(
        tmp_path,
        """
scenario = "scen/short.toml"
runs = 4
seed = 11
estimators = ["mmse", "mtmse"]
[grid]
"cost.lambda" = [1, 2.5, 10]
"graph.delay" = [1, 2]
""",
    )
    monkeypatch.chdir(ROOT)  # the scenario path is relative to the sweep file, not to the working directory
    spec = load_sweep(p)
    assert spec.name == "s" and spec.runs == 4 and spec.seed == 11
    assert spec.scenario == str(tmp_path / "scen" / "short.toml")
    assert spec.estimators == ("mmse", "mtmse")
    assert list(spec.grid) == ["cost.lambda", "graph.delay"]
    assert spec.grid["cost.lambda"] == (1.0, 2.5, 10.0) and all(isinstance(v, float) for v in spec.grid["cost.lambda"])
    assert spec.grid["graph.delay"] == (1, 2)
    pts = spec.points
    assert spec.n_points == len(pts) == 6
    assert [p.params for p in pts[:3]] == [
        {"cost.lambda": 1.0, "graph.delay": 1},
        {"cost.lambda": 1.0, "graph.delay": 2},
        {"cost.lambda": 2.5, "graph.delay": 1},
    ]
    assert len({p.point_id for p in pts}) == 6
    assert pts[3].point_id == point_id({"graph.delay": 2, "cost.lambda": 2.5})
    children = np.random.SeedSequence(11).spawn(6)
    # point 0 runs with the sweep's seed itself (a one-point sweep = teamkf evaluate --seed S); point k its k-th child
    assert [p.seed for p in pts] == [11] + [int(c.generate_state(1, dtype=np.uint64)[0]) >> 1 for c in children[1:]]
    assert all(0 <= p.seed < 2**63 for p in pts)
    # the same sweep loaded again: same ids and seeds
    assert [(q.point_id, q.seed) for q in load_sweep(p).points] == [(q.point_id, q.seed) for q in pts]
    sc = spec.scenario_for(pts[5])
    assert sc.cost.S is not None and sc.horizon == 8 and {e[2] for e in sc.graph.edges} == {2}


def test_defaults_packaged_scenario_and_nested_keys(tmp_path):
    # unquoted dotted keys make nested TOML tables: read as the same dotted keys; the estimators come from the scenario
    p = tmp_path / "n.toml"
    p.write_text('scenario = "platoon-4"\n[grid]\ncost.lambda = [1.0, 2.0]\n')
    spec = load_sweep(p)
    assert spec.scenario == "platoon-4" and spec.runs == 0 and spec.seed == 0
    assert spec.grid == {"cost.lambda": (1.0, 2.0)} and spec.estimators == ("mtmse", "mmse", "centralized")


def test_A_scale_multiplies_A(tmp_path):
    spec = load_sweep(write_files(tmp_path, 'scenario = "scen/short.toml"\n[grid]\n"system.A_scale" = [0.5, 1.1]\n'))
    A = np.asarray(spec.base.system.A_at(0))
    for p, s in zip(spec.points, (0.5, 1.1)):
        np.testing.assert_allclose(spec.scenario_for(p).system.A_at(0), s * A, rtol=0, atol=1e-15)
    sc = apply_point(spec.base, {A_SCALE: 2, "cost.lambda": 3.0})
    np.testing.assert_allclose(sc.system.A_at(0), 2 * A)


def test_sweep_from_dict_errors_name_the_key():
    with pytest.raises(ScenarioError, match=r'^grid\["cost.lamda"\] = 1.0: cost.lamda: unknown key; did you mean \'lambda\''):
        sweep_from_dict({"scenario": "platoon-4", "grid": {"cost.lamda": [1.0]}})
    with pytest.raises(ScenarioError, match=r"^runs: expected an integer >= 0, found the boolean true"):
        sweep_from_dict({"scenario": "platoon-4", "runs": True, "grid": {"cost.lambda": [1.0]}})


BAD = [
    (
        "unknown-top-key",
        'scenario = "scen/short.toml"\ngrd = 1\n[grid]\n"cost.lambda" = [1.0]\n',
        ["grd: unknown key in the sweep file; did you mean 'grid'?"],
    ),
    ("missing-scenario", '[grid]\n"cost.lambda" = [1.0]\n', ["scenario: missing required key"]),
    ("missing-grid", 'scenario = "scen/short.toml"\n', ["grid: missing required key"]),
    ("empty-grid", 'scenario = "scen/short.toml"\n[grid]\n', ["grid: expected at least one dotted key", "found an empty table"]),
    (
        "empty-list",
        'scenario = "scen/short.toml"\n[grid]\n"cost.lambda" = []\n',
        ['grid["cost.lambda"]: expected a non-empty list of values', "found an empty list"],
    ),
    (
        "not-a-list",
        'scenario = "scen/short.toml"\n[grid]\n"cost.lambda" = 10.0\n',
        ['grid["cost.lambda"]: expected a non-empty list of values (one point each), found the number 10.0', "write [10.0]"],
    ),
    ("grid-not-table", 'scenario = "scen/short.toml"\ngrid = [1, 2]\n', ["grid: expected a table of dotted keys", "a list of 2 items"]),
    (
        "runs-string",
        'scenario = "scen/short.toml"\nruns = "10"\n[grid]\n"cost.lambda" = [1.0]\n',
        ["runs: expected an integer >= 0, found the string '10'"],
    ),
    ("runs-negative", 'scenario = "scen/short.toml"\nruns = -1\n[grid]\n"cost.lambda" = [1.0]\n', ["runs: expected an integer >= 0, found -1"]),
    (
        "runs-float",
        'scenario = "scen/short.toml"\nruns = 2.5\n[grid]\n"cost.lambda" = [1.0]\n',
        ["runs: expected an integer >= 0, found the number 2.5"],
    ),
    ("runs-one", 'scenario = "scen/short.toml"\nruns = 1\n[grid]\n"cost.lambda" = [1.0]\n', ["runs: expected 0", "at least 2"]),
    (
        "seed-float",
        'scenario = "scen/short.toml"\nseed = 1.5\n[grid]\n"cost.lambda" = [1.0]\n',
        ["seed: expected an integer >= 0, found the number 1.5"],
    ),
    (
        "unknown-dotted-key",
        'scenario = "scen/short.toml"\n[grid]\n"cost.lamda" = [1.0, 2.0]\n',
        ["grid[\"cost.lamda\"] = 1.0: cost.lamda: unknown key; did you mean 'lambda'?"],
    ),
    (
        "unknown-table",
        'scenario = "scen/short.toml"\n[grid]\n"costs.lambda" = [1.0]\n',
        ["grid[\"costs.lambda\"] = 1.0: costs: unknown key; did you mean 'cost'?"],
    ),
    (
        "bad-value",
        'scenario = "scen/short.toml"\n[grid]\n"graph.delay" = [1, 0]\n',
        ['grid["graph.delay"] = 0: graph.edges[0] delay: expected an integer delay >= 1, found 0'],
    ),
    (
        "wrong-value-type",
        'scenario = "scen/short.toml"\n[grid]\n"cost.lambda" = ["big"]\n',
        ['grid["cost.lambda"] = "big": cost.lambda: expected a non-negative number, found the string \'big\''],
    ),
    (
        "mixed-types",
        'scenario = "scen/short.toml"\n[grid]\n"cost.lambda" = [1.0, "x"]\n',
        ["grid[\"cost.lambda\"]: expected values of one type, found the number 1.0 (value 0) and the string 'x' (value 1)"],
    ),
    ("duplicate", 'scenario = "scen/short.toml"\n[grid]\n"cost.lambda" = [1, 1.0]\n', ['grid["cost.lambda"]: value 1.0 is listed twice']),
    ("A-scale-string", 'scenario = "scen/short.toml"\n[grid]\n"system.A_scale" = ["x"]\n', ['grid["system.A_scale"]: expected numbers']),
    ("swept-column", 'scenario = "scen/short.toml"\n[grid]\n"seed" = [1, 2]\n', ['grid["seed"]: cannot be swept']),
    (
        "no-scenario-file",
        'scenario = "scen/nope.toml"\n[grid]\n"cost.lambda" = [1.0]\n',
        ["scenario: ", "nope.toml: no such file (paths are relative to the sweep file's folder)"],
    ),
    (
        "bad-estimator",
        'scenario = "scen/short.toml"\nestimators = ["mtmse", "mmsee"]\n[grid]\n"cost.lambda" = [1.0]\n',
        ["estimators[1]: unknown estimator 'mmsee'; did you mean 'mmse'?"],
    ),
    ("bad-toml", 'scenario = "scen/short.toml"\n[grid\n', ["invalid TOML"]),
]


@pytest.mark.parametrize("body, fragments", [b[1:] for b in BAD], ids=[b[0] for b in BAD])
def test_bad_sweep_files_one_clear_error_and_nothing_written(tmp_path, capsys, body, fragments):
    p = write_files(tmp_path, body)
    out = tmp_path / "results.parquet"
    assert main(["sweep", str(p), "--out", str(out), "--scheduler", "serial", "--no-progress"]) == 2
    cap = capsys.readouterr()
    err = cap.err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("teamkf: error: "), cap.err
    for f in fragments:
        assert f in err[0], (f, err[0])
    assert "Traceback" not in cap.err and cap.out == ""
    assert not out.exists()
    with pytest.raises((ScenarioError, FileNotFoundError)):
        load_sweep(p)


def test_steady_state_with_runs_is_refused(tmp_path, capsys):
    p = write_files(tmp_path, SMALL.format(runs=5), horizon=None)
    assert main(["sweep", str(p), "--out", str(tmp_path / "o"), "--scheduler", "serial"]) == 2
    assert "runs: Monte Carlo runs need a finite horizon" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_missing_sweep_file(tmp_path, capsys):
    assert main(["sweep", str(tmp_path / "none.toml"), "--scheduler", "serial"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"teamkf: error: {tmp_path / 'none.toml'}: no such sweep file"


# ---------------------------------------------------------------------------
# serial runs, results files, resume
# ---------------------------------------------------------------------------
@needs_arrow
def test_serial_run_rows_columns_and_numbers(tmp_path):
    spec = load_sweep(small_sweep(tmp_path, runs=3))
    out = tmp_path / "r.parquet"
    res = run_sweep(spec, out, "serial", progress=False)
    assert res.n_computed == 4 and res.n_resumed == 0 and res.n_points == 4 and len(res) == 12
    assert len(parts(out)) == 4 and (out / "_sweep.json").is_file()
    assert not [p for p in out.iterdir() if p.name.startswith(".")]  # no temporary files left
    df = frame(out)  # pandas reads the folder as one table
    assert len(df) == 12
    assert CONTRACT | {"cost.lambda", "graph.delay", "mc_cost", "mc_ci95_low", "mc_ci95_high"} <= set(df.columns)
    assert list(df.columns[:2]) == ["cost.lambda", "graph.delay"]
    assert (df["teamkf_version"] == __version__).all() and (df["runs"] == 3).all() and (df["sweep_seed"] == 7).all()
    assert df["ci95_low"].isna().all() and df["ci95_high"].isna().all()  # analytic values
    assert df.groupby("point_id").size().eq(3).all()
    # the numbers are evaluate_point's on the point's scenario with the point's seed (BLAS on one thread)
    for p in spec.points:
        rows = sweep_mod.run_point(evaluate_point, spec.scenario_for(p), spec.estimators, spec.runs, p.seed)
        got = df[df["point_id"] == p.point_id]
        assert list(got["estimator"].sort_values()) == sorted(r["estimator"] for r in rows)
        for r in rows:
            g = got[got["estimator"] == r["estimator"]].iloc[0]
            assert g["total_cost"] == r["total_cost"] and g["mc_cost"] == r["mc_cost"] and g["seed"] == p.seed == r["seed"]
            assert g["cost.lambda"] == p.params["cost.lambda"] and g["point_index"] == p.index
    # the result object: grid order, estimator order
    assert [r["point_index"] for r in res.rows] == [0, 0, 0, 1, 1, 1, 2, 2, 2, 3, 3, 3]
    assert res.estimators == ("mtmse", "mmse", "centralized") and res.cost_key == "total_cost"
    again = SweepResult.load(out)
    assert again.rows == res.rows and again.grid_keys == ("cost.lambda", "graph.delay")


@needs_arrow
def test_analytic_only_has_no_mc_columns_and_steady_state_uses_average_cost(tmp_path):
    p = write_files(tmp_path, 'scenario = "scen/short.toml"\n[grid]\n"cost.lambda" = [1.0, 10.0]\n', horizon=None)
    res = run_sweep(load_sweep(p), tmp_path / "o", "serial", progress=False)
    df = res.to_pandas()
    assert "average_cost" in df.columns and "total_cost" not in df.columns and "mc_cost" not in df.columns
    assert res.cost_key == "average_cost" and (df["average_cost"] > 0).all()


@needs_arrow
def test_existing_results_are_never_mixed(tmp_path, capsys):
    p = small_sweep(tmp_path)
    out = tmp_path / "r.parquet"
    assert main(["sweep", str(p), "--out", str(out), "--scheduler", "serial", "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert "4 points x 3 estimators" in text and "4 points computed now, 0 already there" in text and str(out) in text
    before = {q.name: q.stat().st_mtime_ns for q in out.iterdir()}
    assert main(["sweep", str(p), "--out", str(out), "--scheduler", "serial"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"teamkf: error: {out}: results already exist; pass --resume (resume=True) to continue this sweep, or choose another --out"
    assert {q.name: q.stat().st_mtime_ns for q in out.iterdir()} == before
    # results of another sweep (another seed) are refused even with --resume
    other = write_files(tmp_path, SMALL.format(runs=0).replace("seed = 7", "seed = 8"), name="other")
    assert main(["sweep", str(other), "--out", str(out), "--scheduler", "serial", "--resume"]) == 2
    assert "holds results of a different sweep (seed differ)" in capsys.readouterr().err
    # a folder that is not a results folder, and a file
    (tmp_path / "junk").mkdir()
    (tmp_path / "junk" / "x.txt").write_text("x")
    with pytest.raises(SweepError, match="not a teamkf sweep results folder"):
        run_sweep(load_sweep(p), tmp_path / "junk", "serial", resume=True, progress=False)
    (tmp_path / "f.parquet").write_text("x")
    with pytest.raises(SweepError, match="exists and is a file"):
        run_sweep(load_sweep(p), tmp_path / "f.parquet", "serial", progress=False)
    assert before == {q.name: q.stat().st_mtime_ns for q in out.iterdir()}


@needs_arrow
def test_resume_computes_only_missing_points(tmp_path, capsys):
    spec = load_sweep(small_sweep(tmp_path, runs=2))
    out = tmp_path / "r.parquet"
    full = run_sweep(spec, out, "serial", progress=False)
    ref = frame(out)
    for name in parts(out)[:2]:
        (out / name).unlink()
    count = Counter()
    res = run_sweep(spec, out, "serial", resume=True, progress=False, evaluate=count)
    assert count.calls == 2 and res.n_computed == 2 and res.n_resumed == 2
    assert frame(out).equals(ref) and res.rows == full.rows
    # nothing missing: nothing computed, and no cluster started
    count = Counter()
    res = run_sweep(spec, out, "local", resume=True, progress=False, evaluate=count)
    assert count.calls == 0 and res.n_computed == 0 and res.n_resumed == 4


@needs_arrow
def test_interrupt_then_resume_gives_the_uninterrupted_numbers(tmp_path):
    spec = load_sweep(small_sweep(tmp_path, runs=3))
    ref_out, out = tmp_path / "ref", tmp_path / "r"
    run_sweep(spec, ref_out, "serial", progress=False)

    done: list[str] = []

    def stop_after_two(point, rows):
        done.append(point.point_id)
        if len(done) == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_sweep(spec, out, "serial", progress=False, on_point_done=stop_after_two)
    assert parts(out) == sorted(f"part-{i}.parquet" for i in done)
    count = Counter()
    res = run_sweep(spec, out, "serial", resume=True, progress=False, evaluate=count)
    assert count.calls == 2 and res.n_resumed == 2
    assert frame(out).equals(frame(ref_out))


@needs_arrow
def test_cli_interrupt_and_resume(tmp_path, capsys, monkeypatch):
    p = small_sweep(tmp_path, runs=2)
    out = tmp_path / "r.parquet"
    monkeypatch.setattr(sweep_mod, "evaluate_point", Counter(stop_after=3))
    assert main(["sweep", str(p), "--out", str(out), "--scheduler", "serial", "--no-progress"]) == 130
    err = capsys.readouterr().err.strip()
    assert err.startswith("teamkf: interrupted; the finished points are kept in") and "--resume" in err
    assert len(parts(out)) == 3
    count = Counter()
    monkeypatch.setattr(sweep_mod, "evaluate_point", count)
    assert main(["sweep", str(p), "--out", str(out), "--scheduler", "serial", "--resume", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert count.calls == 1 and doc["computed"] == 1 and doc["resumed"] == 3 and doc["points"] == 4
    assert len(doc["rows"]) == 12 and doc["rows"][0]["cost.lambda"] == 1.0
    monkeypatch.undo()
    ref = tmp_path / "ref"
    run_sweep(load_sweep(p), ref, "serial", progress=False)
    assert frame(out).equals(frame(ref))


@needs_arrow
def test_failed_point_is_one_error_and_keeps_finished_points(tmp_path, capsys, monkeypatch):
    spec = load_sweep(small_sweep(tmp_path))

    def fails_on_third(scenario, estimators, runs, seed, calls=[]):
        calls.append(1)
        if len(calls) == 3:
            raise ConvergenceError("doubling did not converge")
        return evaluate_point(scenario, estimators, runs, seed)

    with pytest.raises(
        SweepError,
        match=r"grid point 2 \(cost.lambda = 10.0, graph.delay = 1\) failed: doubling did not "
        r"converge; the 2 finished points are kept in",
    ):
        run_sweep(spec, tmp_path / "o", "serial", progress=False, evaluate=fails_on_third)
    assert len(parts(tmp_path / "o")) == 2


def test_sweep_progress_is_the_package_bar(tmp_path, capsys, monkeypatch):
    """The sweep counts points on teamkf's one progress bar: silent when stderr is not a terminal (a log file)."""
    import teamkf._progress as P

    made = []
    real = P.Bar

    class Spy(real):  # type: ignore[misc, valid-type]
        def __init__(self, total, **kw):
            made.append((total, kw))
            super().__init__(total, **kw)

    monkeypatch.setattr(P, "Bar", Spy)
    monkeypatch.setattr(sweep_mod, "_progress_bar", lambda total, **kw: Spy(total, **kw))
    p = write_files(tmp_path, SMALL.format(runs=0))
    spec = load_sweep(p)
    run_sweep(spec, tmp_path / "r.parquet", scheduler="serial", progress=True)
    assert made and made[-1][0] == spec.n_points and made[-1][1]["unit"] == "point"
    assert capsys.readouterr().err == ""  # stderr is captured (not a terminal): nothing written


def test_package_bar_rules(monkeypatch):
    """teamkf._progress.Bar: written when asked (enabled=True) on any stream, silent with enabled=False or quiet."""

    import teamkf._progress as P

    monkeypatch.delenv("TEAMKF_PROGRESS", raising=False)  # the suite may silence bars; this test needs them on
    monkeypatch.setattr(P, "_QUIET", False)
    buf = io.StringIO()
    with P.bar(3, desc="points", unit="point", enabled=True, stream=buf, delay=0) as b:
        assert b.shown
        b.update(3)
    assert "points" in buf.getvalue() and "0/3" in buf.getvalue()
    quiet = io.StringIO()
    with P.bar(3, enabled=False, stream=quiet) as b:
        b.update()
    with P.quiet():
        with P.bar(3, enabled=True, stream=quiet) as b:
            assert not b.shown
    monkeypatch.setenv("TEAMKF_PROGRESS", "0")
    with P.bar(3, enabled=True, stream=quiet) as b:
        b.update()
    assert quiet.getvalue() == ""


# ---------------------------------------------------------------------------
# result objects
# ---------------------------------------------------------------------------
def _toy_result() -> SweepResult:
    points = []
    for k, (lam, d) in enumerate([(1.0, 1), (1.0, 2), (100.0, 1), (100.0, 2)]):
        points.append(
            [
                {
                    "cost.lambda": lam,
                    "graph.delay": d,
                    "point_id": f"p{k}",
                    "point_index": k,
                    "estimator": est,
                    "method": "analytic",
                    "total_cost": j,
                    "ci95_low": None,
                    "ci95_high": None,
                }
                for est, j in (("mtmse", 10.0 * lam + d), ("mmse", 12.0 * lam + d), ("centralized", 5.0 * lam))
            ]
        )
    # points out of order (as read from part files): sorted into grid order
    return SweepResult(tuple(r for rows in reversed(points) for r in rows), ("cost.lambda", "graph.delay"))


def test_sweep_result_views():
    res = _toy_result()
    assert [r["point_index"] for r in res.rows][:3] == [0, 0, 0] and res.estimators == ("mtmse", "mmse", "centralized")
    assert res.grid_values("graph.delay") == (1, 2) and res.n_points == 4
    rel = {(r["point_id"], r["estimator"]): r["rel_to_mtmse_pct"] for r in res.relative_to("mtmse")}
    assert rel[("p0", "mtmse")] == 0.0 and rel[("p0", "mmse")] == pytest.approx(100 * (13 - 11) / 11)
    with pytest.raises(SweepError, match="baseline: expected one of the estimators"):
        res.relative_to("kcf")
    with pytest.raises(SweepError, match="x: expected one of the grid keys"):
        res.plot(x="cost.lamda")


@needs_arrow
def test_sweep_result_to_pandas():
    df = _toy_result().to_pandas(baseline="mmse")
    assert list(df.columns[:2]) == ["cost.lambda", "graph.delay"] and "rel_to_mmse_pct" in df.columns
    assert df["ci95_low"].dtype == np.float64 and df["ci95_low"].isna().all()


@pytest.mark.skipif(not HAS_MPL, reason="needs matplotlib")
def test_plots(tmp_path):
    import matplotlib.pyplot as plt

    res = _toy_result()
    ax = res.plot()
    assert ax.get_xscale() == "log" and ax.get_ylabel() == "J_T" and len(ax.get_lines()) == 6  # 3 estimators x 2 delays
    ax2 = res.plot(x="graph.delay", baseline="mtmse")
    assert "[%]" in ax2.get_ylabel() and len(ax2.get_legend().get_texts()) == 4  # mmse, centralized x 2 lambdas
    kinds = SweepResult(tuple({**r, "cost.kind": "platoon" if r["cost.lambda"] == 1.0 else "ring"} for r in res.rows), ("cost.kind", "graph.delay"))
    ax4 = kinds.plot()  # non-numeric values: one tick each
    assert [t.get_text() for t in ax4.get_xticklabels()] == ["platoon", "ring"]
    from teamkf.simulation.monte_carlo import monte_carlo
    from teamkf.study.scenario import load_packaged

    sc = load_packaged("platoon-4").updated({"horizon": 6})
    designs = sc.designs()
    cc = CostCurves.from_designs(designs, title="platoon")
    assert cc.totals()["mtmse"] == pytest.approx(designs["mtmse"].total_cost)
    ax3 = cc.plot()
    assert len(ax3.get_lines()) == 3 and ax3.get_title() == "platoon"
    mc = CostCurves.from_monte_carlo(monte_carlo(designs, 6, 20, rng=1))
    assert mc.methods == ("monte-carlo",) * 3 and mc.stage_sem[0].shape == (6,)
    mc.plot(ax=ax3, cumulative=True)
    ax3.figure.savefig(tmp_path / "c.png")
    plt.close("all")
    with pytest.raises(SweepError, match="finite-horizon design"):
        CostCurves.from_designs(load_packaged("platoon-4-steady").designs(["centralized"]))
    if HAS_ARROW:
        long = mc.to_pandas()
        assert len(long) == 18 and set(long.columns) == {"estimator", "method", "t", "stage_cost", "sem"}


# ---------------------------------------------------------------------------
# Dask
# ---------------------------------------------------------------------------
@pytest.fixture
def cluster():
    distributed = pytest.importorskip("dask.distributed")
    if not HAS_ARROW:
        pytest.skip("needs pyarrow and pandas")
    import logging

    c = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None, silence_logs=logging.ERROR)
    try:
        yield c
    finally:
        c.close()


def test_serial_and_dask_give_identical_numbers(tmp_path, cluster):
    spec = load_sweep(small_sweep(tmp_path, runs=20))
    serial = run_sweep(spec, tmp_path / "serial", "serial", progress=False)
    dask = run_sweep(spec, tmp_path / "dask", cluster.scheduler_address, progress=False)
    assert frame(tmp_path / "dask").equals(frame(tmp_path / "serial"))
    assert dask.rows == serial.rows and dask.n_computed == 4
    assert frame(tmp_path / "dask")["mc_cost"].notna().all()

    # interrupted on Dask after one point, resumed in-process: the same numbers
    def stop(point, rows):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_sweep(spec, tmp_path / "mixed", cluster.scheduler_address, progress=False, on_point_done=stop)
    assert len(parts(tmp_path / "mixed")) == 1
    res = run_sweep(spec, tmp_path / "mixed", "serial", resume=True, progress=False)
    assert res.n_resumed == 1 and res.n_computed == 3
    assert frame(tmp_path / "mixed").equals(frame(tmp_path / "serial"))


def test_embedded_local_cluster_from_the_command_line(tmp_path, capsys):
    pytest.importorskip("dask.distributed")
    if not HAS_ARROW:
        pytest.skip("needs pyarrow and pandas")
    p = small_sweep(tmp_path, runs=5)
    out = tmp_path / "local.parquet"
    assert main(["sweep", str(p), "--out", str(out), "--workers", "2", "--no-progress"]) == 0
    assert "Dask LocalCluster" in capsys.readouterr().out
    run_sweep(load_sweep(p), tmp_path / "serial", "serial", progress=False)
    assert frame(out).equals(frame(tmp_path / "serial"))


def test_killing_a_worker_mid_sweep(tmp_path):
    pytest.importorskip("dask.distributed")
    if not HAS_ARROW:
        pytest.skip("needs pyarrow and pandas")
    from dask.distributed import Client

    from teamkf.study.sweep import WORKER_ENV, local_cluster

    def environ():
        return {k: os.environ.get(k) for k in (*WORKER_ENV, "MALLOC_TRIM_THRESHOLD_")}

    expected_env = {**WORKER_ENV, "MALLOC_TRIM_THRESHOLD_": None}

    p = write_files(
        tmp_path,
        """
scenario = "scen/short.toml"
runs = 10
seed = 3
[grid]
"cost.lambda" = [1.0, 10.0, 100.0]
"graph.delay" = [1, 2]
""",
    )
    spec = load_sweep(p)
    cluster = local_cluster(2)  # the embedded cluster of scheduler="local", started here to kill one of its workers
    client = Client(cluster)
    try:
        assert all(e == expected_env for e in client.run(environ).values())
        pids = client.run(os.getpid)
        killed: list[int] = []
        lost: list[str] = []

        def kill_one(point, rows):
            if not killed:  # after the first point: kill a worker that is running a point
                busy = {addr: tasks for addr, tasks in client.processing().items() if tasks}
                addr = sorted(busy)[0]
                os.kill(pids[addr], signal.SIGKILL)
                killed.append(pids[addr])
                lost.extend(busy[addr])

        res = run_sweep(spec, tmp_path / "dask", client, progress=False, evaluate=slow_evaluate, on_point_done=kill_one)
        assert killed and lost and res.n_computed == spec.n_points
        client.wait_for_workers(2, timeout=30)
        assert killed[0] not in client.run(os.getpid).values()  # the worker really died (and was restarted)
        assert all(e == expected_env for e in client.run(environ).values())
    finally:
        client.close()
        cluster.close()
    df = frame(tmp_path / "dask")
    assert len(parts(tmp_path / "dask")) == spec.n_points
    assert sorted(df["point_id"].unique()) == sorted(q.point_id for q in spec.points)
    assert df.groupby("point_id").size().eq(len(spec.estimators)).all()  # every point exactly once
    run_sweep(spec, tmp_path / "serial", "serial", progress=False)
    assert df.equals(frame(tmp_path / "serial"))


def test_example_sweeps_are_valid():
    ex = ROOT / "examples" / "sweeps"
    spec = load_sweep(ex / "platoon-lambda.toml")
    assert spec.n_points == 9 and spec.base.name == "platoon-4" and spec.runs == 0
    big = load_sweep(ex / "platoon-40.toml")
    assert big.n_points == 40 and big.runs >= 2 and A_SCALE in big.grid
