"""Unit tests for the `teamkf` command (teamkf.cli) and `teamkf demo` (teamkf.demo)."""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from teamkf import __version__, experiments
from teamkf.cli import dumps_json, format_table, main
from teamkf.demo import run_demo

ROOT = Path(__file__).resolve().parents[2]
PACKAGED = ROOT / "src" / "teamkf" / "scenarios"
HAS_MPL = importlib.util.find_spec("matplotlib") is not None
SHORT_VERSION = ".".join(__version__.split(".")[:2])


def run_cli(*args: str) -> subprocess.CompletedProcess:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT / "src") + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    return subprocess.run([sys.executable, "-m", "teamkf", *args], capture_output=True, text=True, env=env, cwd=ROOT, timeout=300)


def write_scenario(tmp_path: Path, name: str = "short", *, horizon: int | None = 10, replace: dict[str, str] | None = None) -> Path:
    """The packaged platoon with another horizon (and optional text replacements)."""
    text = (PACKAGED / "platoon-4.toml").read_text()
    text = text.replace('name = "platoon-4"', f'name = "{name}"')
    text = text.replace("horizon = 100 ", f"horizon = {horizon} " if horizon is not None else "# no horizon ")
    for old, new in (replace or {}).items():
        assert old in text, old
        text = text.replace(old, new)
    p = tmp_path / f"{name}.toml"
    p.write_text(text)
    return p


def bad_R_scenario(tmp_path: Path) -> Path:
    text = (PACKAGED / "platoon-4.toml").read_text()
    blocks = text.split("[[agents]]")
    blocks[3] = blocks[3].replace("R = 0.1", "R = [[0.1, 0, 0], [0, 0.1, 0], [0, 0, 0.1]]")
    p = tmp_path / "bad.toml"
    p.write_text("[[agents]]".join(blocks))
    return p


# ---------------------------------------------------------------------------
# evaluate
# ---------------------------------------------------------------------------
def test_evaluate_table(capsys):
    assert main(["evaluate", "platoon-4"]) == 0
    out = capsys.readouterr().out
    assert "scenario platoon-4" in out and "T = 100" in out
    for name in ("mtmse", "mmse", "centralized"):
        assert name in out
    assert "vs mtmse" in out and "+0.00 %" in out


def test_evaluate_json_in_process(capsys):
    assert main(["evaluate", str(PACKAGED / "platoon-4.toml"), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert list(data) == ["scenario", "horizon", "teamkf_version", "schema_version", "links", "estimators"]
    assert data["scenario"] == "platoon-4" and data["horizon"] == 100
    assert list(data["estimators"]) == ["mtmse", "mmse", "centralized"]
    for entry in data["estimators"].values():
        assert entry["method"] == "analytic"
        assert len(entry["stage_costs"]) == 100
        assert entry["total_cost"] == pytest.approx(sum(entry["stage_costs"]))
    e = data["estimators"]
    assert e["centralized"]["total_cost"] <= e["mtmse"]["total_cost"] <= e["mmse"]["total_cost"]


def test_evaluate_json_subprocess():
    res = run_cli("evaluate", str(PACKAGED / "platoon-4.toml"), "--json")
    assert res.returncode == 0, res.stderr
    data = json.loads(res.stdout)
    assert set(data) == {"scenario", "horizon", "teamkf_version", "schema_version", "links", "estimators"}
    assert data["horizon"] == 100
    for entry in data["estimators"].values():
        assert {"method", "total_cost", "stage_costs"} <= set(entry)
        assert len(entry["stage_costs"]) == data["horizon"]


def test_evaluate_json_steady_state(capsys):
    assert main(["evaluate", "platoon-4-steady", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["horizon"] is None
    for name, entry in data["estimators"].items():
        assert entry == {
            "method": "analytic",
            "average_cost": pytest.approx(entry["average_cost"]),
            "runs": 0,
            "label": name,
            "cost_links": "perfect",
            "diverged": False,
        }
        assert "stage_costs" not in entry and "total_cost" not in entry
    e = data["estimators"]
    assert e["centralized"]["average_cost"] <= e["mtmse"]["average_cost"] <= e["mmse"]["average_cost"]


def test_evaluate_monte_carlo_json(tmp_path, capsys):
    p = write_scenario(tmp_path, horizon=10)
    assert main(["evaluate", str(p), "--json", "--monte-carlo", "200", "--seed", "1"]) == 0
    data = json.loads(capsys.readouterr().out)
    for name, entry in data["estimators"].items():
        assert entry["method"] == "analytic"
        lo, hi = entry["mc_ci95"]
        assert lo < entry["mc_cost"] < hi
        # analytic value within a generous band of the simulated one (fixed seed: deterministic)
        assert abs(entry["mc_cost"] - entry["total_cost"]) < 2.5 * (hi - lo), name
        assert list(entry)[:4] == ["method", "total_cost", "mc_cost", "mc_ci95"]
    # the same seed gives the same numbers
    assert main(["evaluate", str(p), "--json", "--monte-carlo", "200", "--seed", "1"]) == 0
    again = json.loads(capsys.readouterr().out)
    assert again == data


def test_evaluate_monte_carlo_table(tmp_path, capsys):
    p = write_scenario(tmp_path, horizon=5)
    assert main(["evaluate", str(p), "--monte-carlo", "20", "--seed", "3"]) == 0
    out = capsys.readouterr().out
    assert "MC mean" in out and "MC 95% CI" in out and "20 runs, seed 3" in out


def test_evaluate_monte_carlo_needs_a_horizon(capsys):
    assert main(["evaluate", "platoon-4-steady", "--monte-carlo", "10"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("teamkf: error: horizon:") and "finite horizon" in err[0]


@pytest.mark.skipif(HAS_MPL, reason="checks the message without matplotlib")
def test_evaluate_plot_without_matplotlib(tmp_path, capsys):
    out = tmp_path / "stage.png"
    assert main(["evaluate", "platoon-4", "--plot", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "pip install 'teamkf[plot]'" in err[0]
    assert not out.exists()


@pytest.mark.skipif(not HAS_MPL, reason="needs matplotlib")
def test_evaluate_plot(tmp_path, capsys):
    out = tmp_path / "sub" / "stage.png"
    assert main(["evaluate", "platoon-4", "--plot", str(out)]) == 2  # a missing folder is never created (issue 25)
    assert "the folder" in capsys.readouterr().err and not out.parent.exists()
    out.parent.mkdir()
    assert main(["evaluate", "platoon-4", "--plot", str(out)]) == 0
    assert out.exists() and out.stat().st_size > 1000
    assert "plot written to" in capsys.readouterr().out
    assert main(["evaluate", "platoon-4-steady", "--json", "--plot", str(tmp_path / "s.png")]) == 0
    json.loads(capsys.readouterr().out)  # stdout stays pure JSON


# ---------------------------------------------------------------------------
# errors
# ---------------------------------------------------------------------------
def test_bad_scenario_subprocess_one_line_no_traceback(tmp_path):
    res = run_cli("evaluate", str(bad_R_scenario(tmp_path)))
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert lines == ["teamkf: error: agents[2].R: expected a 4x4 symmetric positive definite matrix, found 3x3"]
    assert "Traceback" not in res.stderr and res.stdout == ""


@pytest.mark.parametrize("where", ["before", "after"])
def test_debug_shows_traceback(tmp_path, where):
    bad = str(bad_R_scenario(tmp_path))
    args = ["--debug", "evaluate", bad] if where == "before" else ["evaluate", bad, "--debug"]
    res = run_cli(*args)
    assert res.returncode == 2
    assert "Traceback (most recent call last)" in res.stderr
    assert res.stderr.strip().splitlines()[-1].startswith("teamkf: error: agents[2].R")


@pytest.mark.parametrize(
    "case, expected",
    [
        ("missing", "teamkf: error: {dir}/nope.toml: no such scenario file"),
        ("syntax", "teamkf: error: {dir}/syntax.toml: invalid TOML: "),
        ("cikf", "teamkf: error: estimators[1]: unknown estimator 'ukf'"),
        ("typo", "teamkf: error: cost.lamda: unknown key; did you mean 'lambda'?"),
        ("graph", "teamkf: error: graph: expected a strongly connected graph"),
        ("population", "teamkf: error: population.a:"),
        ("directory", "teamkf: error: {dir}: is a directory"),
    ],
)
def test_errors_in_process(tmp_path, capsys, case, expected):
    if case == "missing":
        p = tmp_path / "nope.toml"
    elif case == "syntax":
        p = write_scenario(tmp_path, "syntax", replace={"lambda = 100.0": "lambda = = 100.0"})
    elif case == "cikf":
        p = write_scenario(tmp_path, "cikf", replace={'estimators = ["mtmse", "mmse", "centralized"]': 'estimators = ["mtmse", "ukf"]'})
    elif case == "typo":
        p = write_scenario(tmp_path, "typo", replace={"lambda = 100.0": "lamda = 100.0"})
    elif case == "graph":
        p = write_scenario(tmp_path, "graph", replace={", [3, 2, 1]]": "]"})
    elif case == "population":
        p = tmp_path / "pop.toml"
        p.write_text('name = "interference"\nhorizon = 1000\n[population]\nn_agents = 1000\na = "fast"\n')
    else:
        p = tmp_path
    for command in ("evaluate", "design"):
        assert main([command, str(p)]) == 2
        captured = capsys.readouterr()
        lines = captured.err.strip().splitlines()
        assert len(lines) == 1, captured.err
        assert lines[0].startswith(expected.format(dir=tmp_path)), lines[0]
        assert captured.out == ""


def test_toml_error_has_line_and_column(tmp_path, capsys):
    p = write_scenario(tmp_path, "syntax", replace={"lambda = 100.0": "lambda = = 100.0"})
    assert main(["evaluate", str(p)]) == 2
    err = capsys.readouterr().err
    assert "line" in err and "column" in err


def test_usage_errors_exit_2(capsys):
    assert main([]) == 2
    assert main(["evaluate"]) == 2
    assert main(["evaluate", "platoon-4", "--monte-carlo", "zero"]) == 2
    assert main(["frobnicate"]) == 2
    capsys.readouterr()


def test_version(capsys):
    assert main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"teamkf {__version__}"


def test_reproduce_list_run_and_unknown(capsys, tmp_path):
    assert main(["reproduce", "--list"]) == 0
    assert "fig1" in capsys.readouterr().out
    assert main(["reproduce", "fig1", "--quick", "--json", "--out", str(tmp_path)]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["name"] == "fig1" and res["rows"]
    assert (tmp_path / "fig1.csv").exists()
    assert main(["reproduce", "no-such-figure"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("teamkf: error: reproduce: unknown experiment 'no-such-figure'")


# ---------------------------------------------------------------------------
# design
# ---------------------------------------------------------------------------
def test_design_out_finite_horizon(tmp_path, capsys):
    p = write_scenario(tmp_path, horizon=6)
    out = tmp_path / "gains.npz"
    assert main(["design", str(p), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "gain shapes" in text and "F_0 1x24" in text and "K 4x16" in text
    z = np.load(out)
    assert str(z["scenario"]) == "short" and int(z["horizon"]) == 6
    for est in ("mtmse", "mmse"):
        for i in range(4):
            for k in range(6):
                F = z[f"{est}/F_{i}_t{k}"]
                assert F.ndim == 2 and F.shape[0] == 1
            assert z[f"{est}/local_{i}"].shape[1] == 2
        assert z[f"{est}/stage_costs"].shape == (6,)
        assert float(z[f"{est}/total_cost"]) == pytest.approx(z[f"{est}/stage_costs"].sum())
    assert z["mtmse/F_1_t5"].shape == (1, 32)
    assert z["centralized/K"].shape == (6, 4, 16)
    assert z["centralized/stage_costs"].shape == (6,)


def test_design_out_steady_state_and_json(tmp_path, capsys):
    bare = tmp_path / "steady"  # no .npz extension: refused, nothing written (issue 25)
    assert main(["design", "platoon-4-steady", "--json", "--out", str(bare)]) == 2
    assert "--out: expected a file name ending in .npz" in capsys.readouterr().err and not bare.exists()
    out = tmp_path / "steady.npz"
    assert main(["design", "platoon-4-steady", "--json", "--out", str(out)]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["horizon"] is None and data["scenario"] == "platoon-4-steady"
    m = data["estimators"]["mtmse"]
    assert m["local_dims"] == [24, 32, 32, 24]
    assert m["gain_shapes"] == {"F_0": [1, 24], "F_1": [1, 32], "F_2": [1, 32], "F_3": [1, 24]}
    assert "average_cost" in m and "stage_costs" not in m
    assert data["estimators"]["centralized"]["gain_shapes"] == {"K": [4, 16]}
    assert data["estimators"]["centralized"]["local_dims"] is None
    z = np.load(out)
    assert int(z["horizon"]) == -1
    assert z["mtmse/F_2"].shape == (1, 32)
    assert z["mtmse/K"].shape == (4, 16)
    assert float(z["mtmse/average_cost"]) == pytest.approx(m["average_cost"])
    # the steady gains' columns follow local_i: (source, lag) pairs, each a block of d_y = 4 columns
    assert z["mtmse/local_1"].shape[0] * 4 == z["mtmse/F_1"].shape[1]


def test_design_json_reduced_structure(capsys):
    assert main(["design", "platoon-4-is1", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["estimators"]["mtmse"]["local_dims"] == [12, 16, 16, 12]
    assert data["estimators"]["mtmse"]["total_cost"] > 0


# ---------------------------------------------------------------------------
# demo
# ---------------------------------------------------------------------------
def test_demo_quick_cli(tmp_path, capsys):
    out_dir = tmp_path / "plots"
    assert main(["demo", "--quick", "--out", str(out_dir)]) == 0
    text = capsys.readouterr().out
    for part in (
        "1. UAV formation",
        "2. Vehicular platoon",
        "3. Information shedding",
        "J_T*/lambda (paper, Table I)",
        "180.46",
        "193.72",
        "252.09",
        "cannot come from the stated model",
        "KCF",
    ):
        assert part in text, part
    if HAS_MPL:
        assert (out_dir / "fig3.png").exists() and (out_dir / "fig5.png").exists() and (out_dir / "table1.png").exists()
    else:
        assert "pip install 'teamkf[plot]'" in text
        assert not out_dir.exists()


def test_demo_uav_row_equals_packaged_scenario():
    """The demo's UAV n = 4, lambda/n^2 = 10 row is `teamkf evaluate uav-4`."""
    from teamkf.study.scenario import load_packaged

    rows = experiments.run("fig3", quick=True).rows
    row = [r for r in rows if r["n"] == 4 and r["lambda/n^2"] == 10.0][0]
    ds = load_packaged("uav-4").designs()
    assert row["J* (MTMSE)"] == pytest.approx(ds["mtmse"].total_cost, rel=1e-12)
    assert row["J mmse"] == pytest.approx(ds["mmse"].total_cost, rel=1e-12)


def test_run_demo_returns_text(tmp_path, capsys):
    text = run_demo(out_dir=tmp_path / "d", quick=True, echo=False)
    assert capsys.readouterr().out == ""
    assert "Delta mmse" in text and "Computed in" in text


# ---------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------
def test_format_table_aligns_columns():
    t = format_table(["a", "bb"], [["x", "1.0"], ["yyy", "10.25"]])
    lines = t.splitlines()
    assert len(lines) == 4 and len({len(line) for line in lines}) == 1


def test_dumps_json_round_trips():
    obj = {"a": [1.5, 2, None], "b": {"c": [[1, 2], [3, 4]], "d": {}}, "e": "x"}
    assert json.loads(dumps_json(obj)) == obj


def test_population_evaluate_json(capsys):
    assert main(["evaluate", "interference", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    for key in ("gains", "stationarity_index", "isolated_gains", "state_variance", "average_lq_cost"):
        assert key in out
    assert len(out["gains"]) == out["horizon"] == 1000
    assert out["stationarity_index"] < 1e-8  # a = 2.5, f = 2 is in the stationary region
    assert main(["evaluate", "interference", "--monte-carlo", "10"]) == 2
