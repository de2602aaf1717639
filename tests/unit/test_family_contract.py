"""The joins: every registered family (teamkf's own and a user's plugin) through every command and contract method.

Parametrized over ``teamkf.families()``, so a new family is covered the moment it registers.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import teamkf
from teamkf.cli import main
from teamkf.estimators.registry import Family, load_plugin
from teamkf.exceptions import ArgumentError, TeamkfError, UnsupportedOperationError
from teamkf.simulation.runtime import run_graph
from teamkf.simulation.sampling import sample_paths
from teamkf.study.evaluate import evaluate_point
from teamkf.study.scenario import scenario_from_dict

ROOT = Path(__file__).resolve().parents[2]
PLUGIN = ROOT / "examples" / "custom_family.py"
load_plugin(str(PLUGIN))  # registers "avg_kf", as `teamkf --plugin examples/custom_family.py` does
FAMILIES = list(teamkf.families())
T = 8


def strict_json(text: str) -> object:
    """Parse JSON refusing NaN / Infinity tokens (RFC 8259)."""

    def bad(token: str) -> object:
        raise AssertionError(f"non-standard JSON token {token}")

    return json.loads(text, parse_constant=bad)


def scenario_dict(name: str) -> dict:
    """A small ring of 4 agents with unit delays (every family's requirements hold), horizon T."""
    return {
        "name": f"joins-{name}",
        "horizon": T,
        "system": {"A": (0.9 * np.eye(4) + 0.05 * np.eye(4, k=1)).tolist(), "Q": 1.0, "Sigma_x": 1.0},
        "agents": [{"C": [[1.0 if j == i else 0.0 for j in range(4)], [0.3, 0.3, 0.3, 0.3]], "R": 0.2} for i in range(4)],
        "graph": {"kind": "ring", "delay": 1},
        "cost": {"kind": "platoon", "lambda": 10.0},
        "estimators": [name] if name == "centralized" else [name, "centralized"],
    }


def scenario_file(tmp_path: Path, name: str) -> Path:
    p = tmp_path / f"{name}.json"
    p.write_text(json.dumps(scenario_dict(name)))
    return p


def cli(*args: str) -> list[str]:
    return ["--plugin", str(PLUGIN), *args]


@pytest.mark.parametrize("name", FAMILIES)
def test_family_record(name):
    fam = teamkf.get_family(name)
    assert isinstance(fam, Family) and fam.name == name and fam.title
    assert fam.check_options({}) == {o.name: o.default for o in fam.options}
    with pytest.raises(ArgumentError, match=rf"{name}\.no_such_option: unknown option"):
        fam.check_options({"no_such_option": 1})


@pytest.mark.parametrize("name", FAMILIES)
def test_design_contract(name):
    sc = scenario_from_dict(scenario_dict(name))
    d = sc.design(name)
    assert isinstance(d, teamkf.Design) and d.estimator == name and d.family is teamkf.get_family(name)
    assert d.has_analytic_cost == teamkf.get_family(name).analytic_cost
    if d.has_analytic_cost:
        assert d.stage_costs.shape == (T,) and d.total_cost == pytest.approx(float(np.sum(d.stage_costs)))
    else:
        assert d.total_cost is None and d.cost_value is None  # never an exception
    summary = d.summary()
    strict_json(json.dumps(summary, allow_nan=False))
    arrays = d.arrays()
    assert all(isinstance(v, np.ndarray) for v in arrays.values())
    # filter on data: batched == single run, and == the message-passing runtime (honest delivery over the graph)
    paths = sample_paths(sc.system, T, 3, rng=5)
    z = d.filter(paths.y)
    assert z.shape == (3, T, sc.n_agents * sc.cost.dz) and np.all(np.isfinite(z))
    np.testing.assert_allclose(d.filter([yi[1] for yi in paths.y]), z[1], rtol=1e-12, atol=1e-12)
    z_rt = run_graph(d.graph_agents(), sc.graph, paths.y)
    np.testing.assert_allclose(z_rt, z, rtol=1e-9, atol=1e-9 * np.abs(z).max())
    # the Monte Carlo errors are the estimation errors of those estimates
    e = d.errors(paths)
    x_err = np.stack([paths.x[:, k] @ sc.cost.L_at(k).T - z[:, k] for k in range(T)], axis=1)
    np.testing.assert_allclose(e, x_err, rtol=1e-8, atol=1e-8 * np.abs(x_err).max())


@pytest.mark.parametrize("name", FAMILIES)
def test_every_command(name, tmp_path, capsys):
    path = str(scenario_file(tmp_path, name))
    assert main(cli("design", path)) == 0
    assert name in capsys.readouterr().out
    assert main(cli("design", path, "--json")) == 0
    out = strict_json(capsys.readouterr().out)
    assert name in out["estimators"]
    npz = tmp_path / "gains.npz"
    assert main(cli("design", path, "--out", str(npz))) == 0
    with np.load(npz) as f:
        assert any(k.startswith(f"{name}/") for k in f.files) and int(f["horizon"]) == T
    capsys.readouterr()
    assert main(cli("evaluate", path, "--json")) == 0
    ev = strict_json(capsys.readouterr().out)
    entry = ev["estimators"][name]
    assert entry["method"] == ("analytic" if teamkf.get_family(name).analytic_cost else "monte-carlo")
    assert entry["total_cost"] is not None and np.isfinite(entry["total_cost"])
    assert main(cli("evaluate", path, "--monte-carlo", "20", "--seed", "3", "--json")) == 0
    ev = strict_json(capsys.readouterr().out)
    assert ev["monte_carlo"]["runs"] == 20 and ev["monte_carlo"]["seed"] == 3 and ev["monte_carlo"]["teamkf_version"]
    pytest.importorskip("matplotlib")
    png = tmp_path / "costs.png"
    assert main(cli("evaluate", path, "--plot", str(png))) == 0
    assert png.stat().st_size > 1000


@pytest.mark.parametrize("name", FAMILIES)
def test_sweep_point_and_sweep_command(name, tmp_path, capsys):
    sc = scenario_from_dict(scenario_dict(name))
    rows = evaluate_point(sc, [name], runs=10, seed=2)
    assert [r["estimator"] for r in rows] == [name] and np.isfinite(rows[0]["total_cost"])
    pytest.importorskip("pyarrow")
    scen = scenario_file(tmp_path, name)
    sweep = tmp_path / "sweep.toml"
    sweep.write_text(f'scenario = "{scen.name}"\nruns = 10\nseed = 1\nestimators = ["{name}"]\n[grid]\n"cost.lambda" = [1.0, 10.0]\n')
    assert main(cli("sweep", str(sweep), "--scheduler", "serial", "--no-progress", "--out", str(tmp_path / "res"), "--json")) == 0
    res = strict_json(capsys.readouterr().out)
    assert res["points"] == 2 and len(res["rows"]) == 2


def test_monte_carlo_of_every_family_at_once():
    sc = scenario_from_dict({**scenario_dict("mtmse"), "estimators": FAMILIES})
    mc = teamkf.monte_carlo(sc.designs(), T, 200, rng=4)
    cen = mc["centralized"].stage_mean
    for name, r in mc.items():
        assert np.all(np.isfinite(r.stage_mean)), name
        # no decentralized estimator beats the centralized filter (same paths; 4 joint standard errors of slack)
        assert r.total_mean >= mc["centralized"].total_mean - 4 * (r.total_sem + mc["centralized"].total_sem), name
    assert cen.shape == (T,)


def test_unsupported_operations_are_typed():
    sc = scenario_from_dict({**scenario_dict("kcf"), "estimators": ["kcf", "cikf", "avg_kf"]})
    for name in ("kcf", "cikf", "avg_kf"):
        with pytest.raises(UnsupportedOperationError) as info:
            sc.design(name).agents()
        assert info.value.family == name and "agents()" in info.value.operation


def test_omniscience_is_a_property_of_the_design():
    sc = scenario_from_dict({**scenario_dict("mtmse"), "estimators": ["mtmse", "centralized"]})
    assert sc.design("centralized").omniscient and not sc.design("mtmse").omniscient


def test_register_family_validates_and_refuses_duplicates():
    with pytest.raises(ArgumentError, match="name"):
        teamkf.register_family(name="Bad Name", design=lambda *a, **k: None, title="x")
    with pytest.raises(ArgumentError, match="already registered"):
        teamkf.register_family(name="mtmse", design=lambda *a, **k: None, title="x")
    with pytest.raises(ArgumentError, match="horizons"):
        teamkf.register_family(name="x_family", design=lambda *a, **k: None, title="x", horizons={"forever"})


def test_entry_point_families(monkeypatch):
    """An installed package's family arrives through the 'teamkf.families' entry-point group."""
    import importlib.metadata as md

    from teamkf.estimators import registry

    fam = Family(
        name="ep_local",
        design=teamkf.get_family("avg_kf").design,
        title="from an entry point",
        uses="graph",
        horizons={"finite"},
        analytic_cost=False,
    )

    class EP:
        name, value = "ep_local", "somepkg:FAMILY"

        def load(self):
            return fam

    monkeypatch.setattr(md, "entry_points", lambda group=None: [EP()] if group == registry.ENTRY_POINT_GROUP else [])
    monkeypatch.setattr(registry, "_ENTRY_POINTS_LOADED", False)
    try:
        assert "ep_local" in teamkf.families() and teamkf.get_family("ep_local") is fam
        sc = scenario_from_dict({**scenario_dict("ep_local"), "estimators": ["ep_local"]})
        assert np.isfinite(evaluate_point(sc, runs=10, seed=0)[0]["total_cost"])
    finally:
        teamkf.unregister_family("ep_local")


def test_plugin_errors_are_one_line(capsys):
    assert main(["--plugin", "no/such/file.py", "evaluate", "platoon-4"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("teamkf: error: plugin: no such file")
    with pytest.raises(TeamkfError, match="cannot import module"):
        load_plugin("no_such_module_xyz")


def test_unknown_estimator_names_the_key_and_suggests():
    with pytest.raises(TeamkfError, match=r"estimators\[0\]: unknown estimator 'mtmes'; did you mean 'mtmse'\?"):
        scenario_from_dict({**scenario_dict("mtmse"), "estimators": ["mtmes"]})


def test_cikf_unit_delays_checked_when_the_scenario_is_read():
    d = {**scenario_dict("cikf"), "graph": {"kind": "ring", "delay": 2}}
    with pytest.raises(TeamkfError, match=r"^graph: .*'cikf' family .* delay 1.*estimators\[0\] = 'cikf'"):
        scenario_from_dict(d)
