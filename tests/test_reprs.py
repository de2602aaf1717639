"""What a terminal or a notebook shows: short reprs (one screen at any size), HTML tables, no progress-bar warning."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from teamkf import CommGraph, LinearGaussianSystem, TeamCost, design_centralized, design_kcf, design_mmse, design_mtmse, monte_carlo
from teamkf._repr import MAX_REPR_LINES
from teamkf.simulation.mc_result import MonteCarloResults
from teamkf.study.results import SweepResult

ROOT = Path(__file__).resolve().parent.parent
SCREEN_CHARS = 2000  # 20 lines of 100 characters


def one_screen(text: str) -> None:
    assert len(text.splitlines()) <= MAX_REPR_LINES, f"{len(text.splitlines())} lines:\n{text[:500]}"
    assert len(text) <= SCREEN_CHARS, f"{len(text)} characters:\n{text[:500]}"


@pytest.fixture(scope="module")
def platoon():
    return LinearGaussianSystem.platoon(4), TeamCost.platoon(4, lam=100.0), CommGraph.line(4, delay=1)


@pytest.mark.parametrize("horizon", [100, 400])
def test_design_reprs_are_one_screen_at_any_horizon(platoon, horizon):
    system, cost, graph = platoon
    designs = [
        design_kcf(system, cost, graph, horizon=horizon, epsilon=0.1),  # the README's KCF: 1.6 MB before
        design_mtmse(system, cost, graph, horizon=horizon),
        design_kcf(system, cost, graph, horizon=horizon, variant="stale"),
        design_centralized(system, cost, horizon=horizon),
    ]
    for d in designs:
        text = repr(d)
        one_screen(text)
        assert d.estimator in text and str(horizon) in text
        if d.stage_costs is not None:
            assert f"{float(np.sum(d.stage_costs)):.6g}" in text, "the repr shows the analytic cost"
        assert "<table" in d._repr_html_()


def test_a_users_design_gets_the_short_repr_too():
    import runpy

    ns = runpy.run_path(str(ROOT / "examples" / "custom_family.py"), run_name="custom")
    system = LinearGaussianSystem.platoon(4)
    d = ns["design_avg_kf"](system, TeamCost.platoon(4, 10.0), CommGraph.line(4), 300)
    one_screen(repr(d))
    assert repr(d).startswith("AveragingDesign(estimator='avg_kf'")


def test_scenario_repr():
    from importlib.resources import files

    from teamkf import load_scenario

    sc = load_scenario(files("teamkf") / "scenarios" / "uav-10.toml")
    one_screen(repr(sc))
    assert "agents=10" in repr(sc) and "array" not in repr(sc)
    assert "<table" in sc._repr_html_()


def test_sweep_result_repr_with_many_rows():
    rows = tuple(
        {
            "cost.lambda": i,
            "point_id": str(i),
            "point_index": i,
            "estimator": e,
            "method": "analytic",
            "total_cost": float(i + k),
            "ci95_low": None,
            "ci95_high": None,
        }
        for i in range(500)
        for k, e in enumerate(("mtmse", "mmse"))
    )
    res = SweepResult(rows, ("cost.lambda",))
    one_screen(repr(res))
    assert "500 points × 2 estimators" in repr(res) and "more rows" in repr(res)


def test_monte_carlo_results_object(platoon):
    system, cost, graph = platoon
    designs = {"mtmse": design_mtmse(system, cost, graph, horizon=20), "mmse": design_mmse(system, cost, graph, horizon=20)}
    raw = monte_carlo(designs, 20, 300, rng=3)
    mc = MonteCarloResults(raw)
    assert list(mc) == ["mtmse", "mmse"] and mc["mtmse"] is raw["mtmse"] and len(mc) == 2
    one_screen(repr(mc))
    rows = mc.to_rows()
    for row in rows:
        r = raw[row["estimator"]]
        assert row["total_mean"] == r.total_mean and (row["ci95_low"], row["ci95_high"]) == r.ci95
        # the analytic cost lies in the Monte Carlo interval (a 95 % interval: checked with 300 runs, seed 3)
        assert row["ci95_low"] <= designs[row["estimator"]].total_cost <= row["ci95_high"]
    pytest.importorskip("pandas")
    df = mc.to_frame()
    assert list(df.index) == ["mtmse", "mmse"] and df.loc["mmse", "runs"] == 300
    assert "<table" in mc._repr_html_()
    with pytest.raises(KeyError, match="the designs are 'mtmse', 'mmse'"):
        mc["kcf"]


def test_monte_carlo_results_repr_with_many_designs(platoon):
    system, cost, _ = platoon
    kf = design_centralized(system, cost, horizon=5)
    mc = MonteCarloResults(monte_carlo({f"kf{i}": kf for i in range(40)}, 5, 50, rng=1))
    one_screen(repr(mc))
    assert "more (.to_frame() has them all)" in repr(mc)


def test_no_notebook_progress_import_when_progress_is_off():
    """tqdm.auto, in a notebook without ipywidgets, warns "IProgress not found" as it is imported."""
    code = (
        "import sys, teamkf\n"
        "from teamkf import LinearGaussianSystem, TeamCost, design_centralized, monte_carlo\n"
        "kf = design_centralized(LinearGaussianSystem.platoon(3), TeamCost.platoon(3, 1.0), horizon=5)\n"
        "monte_carlo({'kf': kf}, 5, 100, rng=1)\n"
        "print(sorted(m for m in sys.modules if m in ('tqdm.auto', 'tqdm.autonotebook', 'tqdm.notebook')))\n"
    )
    env = {**os.environ, "TEAMKF_PROGRESS": "0", "PYTHONPATH": str(ROOT / "src")}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout.strip()
    assert out == "[]", f"notebook progress modules imported: {out}"
