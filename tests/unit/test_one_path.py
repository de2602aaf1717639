"""One path for every job: one evaluation behind ``teamkf evaluate`` and every sweep point, and a user's plug-in
family (the one the plug-in guide shows) working in every command on every scheduler.

- ``teamkf evaluate S --json --monte-carlo R --seed X`` and a one-point sweep of S with ``runs = R, seed = X`` give
  identical numbers under one vocabulary, for a team scenario, a population scenario and a plug-in family, on the
  serial path and on the embedded Dask cluster;
- the plug-in (``examples/custom_family.py``, included verbatim by ``docs/guide/plugins.md``) passes design, evaluate
  (``--json``, ``--plot``, ``--monte-carlo`` serial and local), sweep (serial and the default Dask scheduler),
  ``TEAMKF_PLUGINS``, filter; a family that does not declare ``lossy_links`` is refused for ``--p-drop`` in one line;
- plug-in failures (import, design, a step's return) are one line naming the plug-in.
"""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from teamkf.cli import main
from teamkf.study.evaluation import ROW_KEYS, evaluate
from teamkf.study.scenario import load_packaged

ROOT = Path(__file__).resolve().parents[2]
PLUGIN = ROOT / "examples" / "custom_family.py"
HAS_DASK = importlib.util.find_spec("distributed") is not None and importlib.util.find_spec("pyarrow") is not None
needs_dask = pytest.mark.skipif(not HAS_DASK, reason="needs the dask extra")

COMPARED = ("method", "total_cost", "average_cost", "ci95_low", "ci95_high", "mc_cost", "mc_ci95_low", "mc_ci95_high", "runs", "seed")


@pytest.fixture()
def files(tmp_path: Path) -> dict[str, Path]:
    """The plug-in as a user's file, a uav-4 scenario (T = 12) with it, a one-point sweep of that scenario."""
    plugin = tmp_path / "my_family.py"
    plugin.write_text(PLUGIN.read_text())
    text = (ROOT / "src" / "teamkf" / "scenarios" / "uav-4.toml").read_text()
    lines = [ln for ln in text.splitlines() if not ln.startswith(("estimators", "horizon"))]
    scen = tmp_path / "s.toml"
    scen.write_text('horizon = 12\nestimators = ["mtmse", "avg_kf"]\n' + "\n".join(lines) + "\n")
    sweep = tmp_path / "sweep.toml"
    sweep.write_text('scenario = "s.toml"\nruns = 30\nseed = 5\n[grid]\nhorizon = [12]\n')
    return {"plugin": plugin, "scenario": scen, "sweep": sweep, "dir": tmp_path}


def _json(capsys: pytest.CaptureFixture[str], argv: list[str]) -> dict:
    rc = main(argv)
    out = capsys.readouterr()
    assert rc == 0, out.err
    return json.loads(out.out)


def _same(evaluate_json: dict, sweep_json: dict) -> None:
    rows = {r["estimator"]: r for r in sweep_json["rows"]}
    assert set(rows) == set(evaluate_json["estimators"])
    for name, entry in evaluate_json["estimators"].items():
        for k in COMPARED:
            if k in entry or rows[name].get(k) is not None:
                assert entry.get(k) == rows[name].get(k), (name, k)


def test_rows_have_one_vocabulary():
    ev = evaluate(load_packaged("platoon-4").updated({"horizon": 10}), ["mtmse", "kcf"], runs=20, seed=3)
    for r in ev.rows:
        assert set(r) == set(ROW_KEYS) - {"average_cost"}
    assert ev.row("kcf")["runs"] == 20 and ev.row("mtmse")["mc_cost"] is not None
    # runs = 0: nothing is reported as simulated for an analytic estimator
    ev0 = evaluate(load_packaged("platoon-4").updated({"horizon": 10}), ["mtmse"], runs=0, seed=3)
    assert ev0.row("mtmse")["runs"] == 0 and ev0.row("mtmse")["mc_cost"] is None and ev0.row("mtmse")["seed"] is None


def test_evaluate_equals_one_point_sweep_team_and_population(tmp_path, capsys):
    (tmp_path / "t.toml").write_text('scenario = "p.json"\nruns = 25\nseed = 11\n[grid]\nhorizon = [15]\n')
    scen = dict(load_packaged("platoon-4").updated({"horizon": 15}).raw)
    scen["estimators"] = ["mtmse", "mmse", "centralized", "kcf"]
    scen["kcf"] = {"variant": "stale"}  # no closed form: a Monte Carlo row
    (tmp_path / "p.json").write_text(json.dumps(scen))
    ev = _json(capsys, ["evaluate", str(tmp_path / "p.json"), "--json", "--monte-carlo", "25", "--seed", "11"])
    sw = _json(capsys, ["sweep", str(tmp_path / "t.toml"), "--scheduler", "serial", "--out", str(tmp_path / "t.parquet"), "--json"])
    _same(ev, sw)
    assert any(e["method"] == "monte-carlo" for e in ev["estimators"].values())  # kcf/cikf: Monte Carlo rows compared too
    # a population scenario: the exact row
    (tmp_path / "pop.toml").write_text('scenario = "interference"\n[grid]\n"population.memory" = [0]\n')
    pj = _json(capsys, ["evaluate", "interference", "--json"])
    ps = _json(capsys, ["sweep", str(tmp_path / "pop.toml"), "--scheduler", "serial", "--out", str(tmp_path / "pop.parquet"), "--json"])
    assert ps["rows"][0]["average_cost"] == pj["average_cost"] == pj["estimators"]["bulk"]["average_cost"]
    assert pj["estimators"]["bulk"]["method"] == ps["rows"][0]["method"] == "exact"


@needs_dask
def test_plugin_family_in_every_command(files, capsys, monkeypatch):
    plug, scen, d = str(files["plugin"]), str(files["scenario"]), files["dir"]
    design = _json(capsys, ["--plugin", plug, "design", scen, "--json"])
    assert design["estimators"]["avg_kf"]["method"] == "monte-carlo"
    base = ["--plugin", plug, "evaluate", scen, "--json", "--monte-carlo", "30", "--seed", "5"]
    serial = _json(capsys, base)
    local = _json(capsys, base + ["--scheduler", "local"])
    assert serial["estimators"] == local["estimators"]
    sweep_serial = _json(capsys, ["--plugin", plug, "sweep", str(files["sweep"]), "--scheduler", "serial", "--out", str(d / "a.parquet"), "--json"])
    sweep_dask = _json(capsys, ["--plugin", plug, "sweep", str(files["sweep"]), "--out", str(d / "b.parquet"), "--json"])  # default: Dask
    _same(serial, sweep_serial)
    _same(serial, sweep_dask)
    # --plot with Monte Carlo
    assert main(["--plugin", plug, "evaluate", scen, "--monte-carlo", "30", "--seed", "5", "--plot", str(d / "p.png")]) == 0
    assert (d / "p.png").stat().st_size > 10_000
    capsys.readouterr()
    # lossy links: the family declares lossy_links=True
    lossy = _json(capsys, base + ["--p-drop", "0.3"])
    assert np.isfinite(lossy["estimators"]["avg_kf"]["total_cost"])
    # filter on a recorded log
    from teamkf.simulation.sampling import sample_paths
    from teamkf.study import measurements as M
    from teamkf.study.scenario import load_scenario

    sc = load_scenario(files["scenario"])
    p = sample_paths(sc.system, 12, 1, rng=1)
    M.write_measurements(d / "log.csv", [y[0] for y in p.y])
    assert main(["--plugin", plug, "filter", scen, "--measurements", str(d / "log.csv"), "--out", str(d / "est.csv")]) == 0
    assert "avg_kf" in (d / "est.csv").read_text()
    capsys.readouterr()


def test_plugin_through_environment_and_refused_capability(files):
    """TEAMKF_PLUGINS in a fresh process; a family without lossy_links is refused for --p-drop in one line."""
    env = {**os.environ, "TEAMKF_PLUGINS": str(files["plugin"]), "TEAMKF_PROGRESS": "0"}
    run = [sys.executable, "-m", "teamkf"]
    res = subprocess.run(
        run + ["evaluate", str(files["scenario"]), "--json", "--monte-carlo", "10", "--seed", "1"], env=env, capture_output=True, text=True
    )
    assert res.returncode == 0, res.stderr
    assert "avg_kf" in json.loads(res.stdout)["estimators"]
    strict = files["dir"] / "strict_family.py"
    strict.write_text(PLUGIN.read_text().replace('name="avg_kf"', 'name="strict_kf"').replace("    lossy_links=True,", "    lossy_links=False,"))
    scen = files["dir"] / "strict.toml"
    scen.write_text(files["scenario"].read_text().replace('"avg_kf"', '"strict_kf"'))
    res = subprocess.run(
        run + ["--plugin", str(strict), "evaluate", str(scen), "--monte-carlo", "10", "--p-drop", "0.2"],
        env=os.environ,
        capture_output=True,
        text=True,
    )
    assert res.returncode == 2 and res.stdout == ""
    line = res.stderr.strip()
    assert "\n" not in line and "strict_kf" in line and "lossy_links" in line and "Traceback" not in line


@pytest.mark.parametrize(
    "body, where",
    [
        ("raise RuntimeError('broken at import')", "while importing"),
        ("def design_x(system, cost, graph, horizon=None):\n    raise ValueError('no gains today')\n", "design_x()"),
        ("def design_x(system, cost, graph, horizon=None):\n    return None\n", "returned None"),
    ],
)
def test_plugin_failures_are_one_line(files, body, where):
    f = files["dir"] / "broken.py"
    reg = (
        "\nimport teamkf\nteamkf.register_family(name='broken', design=design_x, title='x', uses='graph', horizons={'finite'}, "
        "analytic_cost=False, replace=True)\n"
    )
    f.write_text(body + (reg if "design_x" in body else ""))
    scen = files["dir"] / "b.toml"
    scen.write_text(files["scenario"].read_text().replace('"avg_kf"', '"broken"'))
    res = subprocess.run([sys.executable, "-m", "teamkf", "--plugin", str(f), "evaluate", str(scen)], capture_output=True, text=True)
    assert res.returncode == 2, res.stderr
    line = res.stderr.strip()
    assert "\n" not in line and "Traceback" not in line and where in line and ("broken" in line), line


def test_step_returning_the_wrong_shape_is_named():
    from teamkf.estimators.base import checked_step
    from teamkf.exceptions import ShapeError

    class Bad:
        def step(self, state, k, own, inbox):
            return state, np.zeros(3), None

    with pytest.raises(ShapeError, match=r"agent 2 \(.*Bad\)\.step at step 4: expected z of shape \(5, d_z\)"):
        checked_step(Bad(), 2, None, 4, np.zeros((5, 1)), [], 5)
    with pytest.raises(ShapeError, match="expected a tuple"):

        class Worse:
            def step(self, state, k, own, inbox):
                return None

        checked_step(Worse(), 0, None, 0, np.zeros((5, 1)), [], 5)


def test_start_up_loads_no_family_and_help_no_scipy():
    """``teamkf --version`` imports no estimator family; ``--help`` lists every family without SciPy or networkx
    (they load on first use). Structural, not timed: benchmarks/bench_startup.py measures the seconds."""
    code = (
        "import sys\n"
        "from teamkf.cli import main\n"
        "try:\n    main(['--version'])\nexcept SystemExit:\n    pass\n"
        "print(sorted(m for m in sys.modules if m.startswith('teamkf.estimators.') or m.startswith(('scipy', 'networkx'))))\n"
        "import io, contextlib\n"
        "buf = io.StringIO()\n"
        "with contextlib.redirect_stdout(buf):\n    main(['--help'])\n"
        "print(sorted(m for m in sys.modules if m.startswith(('scipy.linalg', 'scipy.optimize', 'scipy.sparse', 'networkx'))))\n"
        "print('kcf' in buf.getvalue() and 'cikf' in buf.getvalue())\n"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    after_version, after_help, listed = res.stdout.strip().splitlines()[-3:]
    assert after_version == "[]", after_version
    assert after_help == "[]", after_help
    assert listed == "True"
