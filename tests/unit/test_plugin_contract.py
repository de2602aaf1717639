"""The plug-in contract, completed: a step's outputs checked in one line, what a ``missing_data`` family receives
for a missing measurement (NaN in ``own``: the mask is ``np.isnan(own)``), and the leaderboard's plug-ins
(ranked where their records permit, the others listed with the reason before the run and in the notes).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import teamkf
from teamkf.cli import main
from teamkf.estimators import registry
from teamkf.exceptions import ShapeError

SOURCE = """
from dataclasses import dataclass

import numpy as np

import teamkf
from teamkf.estimators.base import Design

RECEIVED = []  # every ``own`` the agents were given, (agent, step, copy)
Z = "zeros"  # what the step returns: "zeros", "narrow" (one column short), "ints"


@dataclass(frozen=True, eq=False, kw_only=True)
class RecDesign(Design):
    graph: teamkf.CommGraph

    def graph_agents(self):
        return [RecAgent(self, i) for i in range(self.n_agents)]


class RecAgent:
    def __init__(self, design, index):
        self.d, self.index = design, index

    def init_state(self, n_runs):
        return None

    def step(self, state, k, own, inbox):
        RECEIVED.append((self.index, k, np.array(own)))
        n, dz = own.shape[0], self.d.cost.dz
        z = {"zeros": np.zeros((n, dz)), "narrow": np.zeros((n, dz - 1)), "ints": np.zeros((n, dz), dtype=int)}[Z]
        return None, z, None


def design_rec(system, cost, graph, horizon=None):
    return RecDesign(estimator="rec", horizon=horizon, system=system, cost=cost, graph=graph)


teamkf.register_family(name="rec", design=design_rec, title="records what it receives", uses="graph",
                       horizons={"finite"}, analytic_cost=False, missing_data=True, lossy_links=True)
"""


@pytest.fixture()
def rec(tmp_path):
    """The recording plug-in, loaded from a file; forgotten afterwards."""
    f = tmp_path / "rec.py"
    f.write_text(SOURCE)
    mod = teamkf.load_plugin(str(f))
    yield f, mod
    registry._unload_plugin(mod.__name__)


def scenario_dict(T: int = 6) -> dict:
    return {
        "name": "rec",
        "horizon": T,
        "system": {"A": (0.9 * np.eye(2)).tolist(), "Q": 1.0, "Sigma_x": 1.0},
        "agents": [{"C": [[1.0, 0.0], [0.0, 1.0]], "R": 0.1} for _ in range(3)],
        "graph": {"kind": "ring", "delay": 1},
        "cost": {"kind": "mse"},
        "estimators": ["rec", "mtmse"],
    }


# --- a step's outputs -------------------------------------------------------------------------------
@pytest.mark.parametrize("kind, found", [("narrow", "shape (5, 1)"), ("ints", "dtype int64")])
def test_a_wrong_z_is_one_error_naming_plugin_family_agent_and_step(rec, kind, found):
    f, mod = rec
    mod.Z = kind
    sc = teamkf.scenario_from_dict(scenario_dict())
    d = sc.design("rec")
    x, y = teamkf.sample(sc.system, 6, n_runs=5, rng=1)
    with pytest.raises(ShapeError) as info:
        d.filter(y)
    msg = str(info.value)
    assert msg.startswith(f"plug-in {f.resolve()}, family 'rec', agent 0 (RecAgent).step at step 0: expected z of shape (5, 2)"), msg
    assert found in msg and "\n" not in msg


def test_a_wrong_z_in_the_cli_is_one_line(rec, tmp_path, capsys):
    f, mod = rec
    scen = tmp_path / "s.json"
    scen.write_text(json.dumps(scenario_dict()))
    (tmp_path / "narrow.py").write_text(SOURCE.replace('Z = "zeros"', 'Z = "narrow"').replace('name="rec"', 'name="rec2"').replace('"rec"', '"rec2"'))
    scen.write_text(json.dumps({**scenario_dict(), "estimators": ["rec2"]}))
    for extra in ([], ["--p-drop", "0.2"]):  # the reliable runtime and the lossy one (run by run)
        rc = main(["--plugin", str(tmp_path / "narrow.py"), "evaluate", str(scen), "--monte-carlo", "4", "--seed", "1", "--quiet", *extra])
        err = capsys.readouterr().err.strip().splitlines()
        assert rc == 2 and len(err) == 1, err
        assert err[0].startswith(f"teamkf: error: plug-in {(tmp_path / 'narrow.py').resolve()}, family 'rec2', agent 0 (RecAgent).step at step 0")
        assert "expected z of shape" in err[0] and "found an array of shape" in err[0]
    registry._unload_plugin("teamkf_plugin_narrow")


def test_the_deployed_agent_checks_the_step_too(rec):
    from teamkf.deploy.agent import AgentCore

    f, mod = rec
    mod.Z = "narrow"
    sc = teamkf.scenario_from_dict(scenario_dict())
    core = AgentCore(sc.design("rec"), 1)
    core.init()
    with pytest.raises(ShapeError, match=r"family 'rec', agent 1 \(RecAgent\)\.step at step 0: expected z of shape \(1, 2\)"):
        core.step(0, np.zeros((1, 2)), {})


def test_builtin_steps_pass_the_check(rng):
    sc = teamkf.scenario_from_dict({**scenario_dict(), "estimators": ["mtmse", "kcf", "local"]})
    x, y = teamkf.sample(sc.system, 6, n_runs=3, rng=2)
    for name in ("mtmse", "kcf", "local"):
        d = sc.design(name)
        assert np.asarray(teamkf.run_graph(d.graph_agents(), sc.graph, y, design=d)).shape == (3, 6, 6)


# --- missing measurements ----------------------------------------------------------------------------
def test_a_missing_data_plugin_receives_nan_where_a_value_is_missing(rec):
    from teamkf.study.measurements import filter_log

    f, mod = rec
    sc = teamkf.scenario_from_dict(scenario_dict())
    x, y = teamkf.sample(sc.system, 6, n_runs=1, rng=3)
    ys = [np.array(yi[0]) for yi in y]
    ys[1][2, 0] = np.nan  # agent 1 misses its first value at step 2
    ys[2][4, :] = np.nan  # agent 2 misses step 4 entirely
    mod.RECEIVED.clear()
    res = filter_log(sc, ys)
    got = {(i, k): v[0] for (i, k, v) in mod.RECEIVED}
    assert set(got) == {(i, k) for i in range(3) for k in range(6)}
    for i in range(3):
        for k in range(6):
            np.testing.assert_array_equal(np.isnan(got[(i, k)]), np.isnan(ys[i][k]))  # the mask is np.isnan(own)
            np.testing.assert_array_equal(got[(i, k)][~np.isnan(ys[i][k])], ys[i][k][~np.isnan(ys[i][k])])
    # a design that declares handles_missing (teamkf's own) gets 0.0 there and stays finite
    assert np.all(np.isfinite(res.estimates["mtmse"])) and res.designs["mtmse"].handles_missing


# --- the leaderboard ---------------------------------------------------------------------------------
def test_the_leaderboard_ranks_plugins_or_says_why_not(rec, monkeypatch, tmp_path, capsys):
    from teamkf.experiments import leaderboard as lb

    def design(system, cost, graph, horizon=None):
        return teamkf.design_local(system, cost, graph, horizon)

    def steady_only(system, cost, graph, horizon=None):
        return teamkf.design_local(system, cost, graph, horizon)

    teamkf.register_family(name="exact_local", design=design, title="an exact plug-in", uses="graph")
    teamkf.register_family(name="steady_only", design=steady_only, title="no finite horizon", uses="graph", horizons={"infinite"})
    try:
        mine = {"rec", "exact_local", "steady_only"}  # other test files of this process may have registered plug-ins too
        ranked, left = lb.plugin_entrants()
        assert [n for n in ranked if n in mine] == ["exact_local"]
        assert "analytic_cost=False" in left["rec"] and "finite-horizon" in left["steady_only"]
        assert [n for n in lb.plugin_entrants(lossy=True)[0] if n in mine] == ["rec"]
        # one small network, the base part only (no tuning): the plug-in rows are added to it
        small = [(name, build) for name, build in lb.networks(True) if name.startswith("platoon")][:1]
        monkeypatch.setattr(lb, "networks", lambda quick: small)
        monkeypatch.setattr(lb, "PARTS", ("base",))
        monkeypatch.setenv("TEAMKF_CACHE_DIR", "off")
        monkeypatch.setenv("TEAMKF_WORKERS", "1")
        res = lb.run(None, True)
        err = capsys.readouterr().err
        assert "teamkf: leaderboard: plug-ins ranked (exact cost, published defaults): exact_local" in err
        assert "plug-in 'rec' left out: its record declares analytic_cost=False" in err
        row = next(r for r in res.rows if r["estimator"] == "exact_local")
        assert row["form"] == "plug-in" and row["J / J*"] >= 1.0 - 1e-9
        assert "Plug-ins: plug-ins ranked" in res.notes and "'steady_only' left out" in res.notes
        assert set(res.data["plugins"]["left_out"]) & mine == {"rec", "steady_only"}
    finally:
        teamkf.unregister_family("exact_local")
        teamkf.unregister_family("steady_only")
