"""Unit tests for teamkf.study.scenario: loading, validation messages, dotted keys."""

from __future__ import annotations

import copy
import json
import tomllib
from pathlib import Path

import numpy as np
import pytest

import teamkf
from teamkf import CommGraph, InformationStructure, LinearGaussianSystem, TeamCost
from teamkf.exceptions import ScenarioError, TeamkfError
from teamkf.study.scenario import (
    Scenario,
    load_packaged,
    load_scenario,
    packaged_scenarios,
    scenario_from_dict,
    set_dotted,
)

ROOT = Path(__file__).resolve().parents[2]
PACKAGED = ROOT / "src" / "teamkf" / "scenarios"
EXAMPLES = ROOT / "examples" / "scenarios"
POPULATION = ("interference",)
NAMES = ["platoon-4", "platoon-4-is1", "platoon-4-steady", "uav-4", "uav-10", "lqg-2"]
#: packaged for teamkf deploy (6 agent processes, 200 steps; tests/unit/test_deploy.py)
DEPLOY = ["platoon-6"]

PLATOON_A = [[0.9, 0, 0, 0], [0.7, 0.9, 0, 0], [0.7, 0.7, 0.9, 0], [0.5, 0.7, 0.7, 0.9]]
IS1_LOCAL = [[[0, 0, 1], [1, 1, 1]], [[0, 1, 1], [1, 0, 1], [2, 1, 1]], [[1, 1, 1], [2, 0, 1], [3, 1, 1]], [[2, 1, 1], [3, 0, 1]]]


def base_dict() -> dict:
    """A small valid scenario (the platoon, short horizon) as plain data."""
    return {
        "name": "t",
        "horizon": 5,
        "system": {"A": copy.deepcopy(PLATOON_A), "Q": 1.0, "Sigma_x": 1.0},
        "agents": [{"C": np.eye(4).tolist(), "R": 0.1} for _ in range(4)],
        "graph": {"kind": "line", "delay": 1},
        "cost": {"kind": "platoon", "lambda": 10.0},
        "estimators": ["mtmse", "mmse", "centralized"],
    }


def error_of(d: dict) -> str:
    with pytest.raises(ScenarioError) as ei:
        scenario_from_dict(d)
    return str(ei.value)


# ---------------------------------------------------------------------------
# packaged scenarios
# ---------------------------------------------------------------------------
def test_packaged_list():
    assert sorted(n for n in packaged_scenarios() if n not in POPULATION) == sorted(NAMES + DEPLOY)


@pytest.mark.parametrize("name", NAMES)
def test_each_packaged_scenario_loads(name):
    sc = load_scenario(PACKAGED / f"{name}.toml")
    assert isinstance(sc, Scenario)
    assert sc.name == name
    assert sc.estimators == ("mtmse", "mmse", "centralized")
    assert sc.horizon == (None if name.endswith("steady") else 20 if name == "lqg-2" else 100)
    by_name = load_packaged(name)
    assert by_name.name == name and by_name.horizon == sc.horizon


@pytest.mark.parametrize("name", NAMES)
def test_examples_are_copies_of_packaged(name):
    assert (EXAMPLES / f"{name}.toml").read_bytes() == (PACKAGED / f"{name}.toml").read_bytes()


def test_platoon_matches_builders():
    sc = load_packaged("platoon-4")
    ref = LinearGaussianSystem.platoon(4)
    np.testing.assert_allclose(sc.system.A, ref.A)
    np.testing.assert_allclose(sc.system.Q, ref.Q)
    np.testing.assert_allclose(sc.system.Sigma_x, ref.Sigma_x)
    for i in range(4):
        np.testing.assert_allclose(sc.system.C[i], ref.C[i])
        np.testing.assert_allclose(sc.system.R[i], ref.R[i])
    assert sc.graph == CommGraph.line(4, 1)
    np.testing.assert_allclose(sc.cost.S, TeamCost.platoon(4, 100.0).S)
    np.testing.assert_allclose(sc.cost.L, TeamCost.platoon(4, 100.0).L)
    assert sc.information == InformationStructure.from_graph(CommGraph.line(4))
    assert not sc.has_reduced_information


@pytest.mark.parametrize("n", [4, 10])
def test_uav_matches_builders(n):
    sc = load_packaged(f"uav-{n}")
    ref = LinearGaussianSystem.uav_formation(n)
    np.testing.assert_allclose(sc.system.A, ref.A)
    for i in range(n):
        np.testing.assert_allclose(sc.system.C[i], ref.C[i])
        np.testing.assert_allclose(sc.system.R[i], ref.R[i])
    np.testing.assert_allclose(sc.system.Q[0], np.eye(n))
    np.testing.assert_allclose(sc.system.Sigma_x, np.eye(n))
    assert sc.graph == CommGraph.complete(n, 2)
    np.testing.assert_allclose(sc.cost.S, TeamCost.average_tracking(n, 10.0 * n * n).S)
    assert sc.information.common_lag == 2


def test_is1_structure():
    sc = load_packaged("platoon-4-is1")
    assert sc.has_reduced_information
    assert sc.information == InformationStructure(4, 3, IS1_LOCAL)
    assert sc.information.local_dims(sc.system.dy) == (12, 16, 16, 12)
    assert sc.information.is_sub_structure_of(load_packaged("platoon-4").information)


def test_commented_is0_in_platoon_file_equals_graph_structure():
    """The [information] block spelled out in platoon-4.toml's comment is the graph's structure."""
    text = (PACKAGED / "platoon-4.toml").read_text()
    block = "\n".join(line[4:] for line in text.splitlines() if line.startswith("#   "))
    data = tomllib.loads(text)
    data["information"] = tomllib.loads(block)["information"]
    sc = scenario_from_dict(data)
    assert sc.information == load_packaged("platoon-4").information


def test_designs_follow_the_scenario():
    sc = load_packaged("platoon-4").updated({"horizon": 10})
    ds = sc.designs()
    assert list(ds) == ["mtmse", "mmse", "centralized"]
    assert all(d.horizon == 10 and len(d.stage_costs) == 10 for d in ds.values())
    assert ds["centralized"].total_cost <= ds["mtmse"].total_cost <= ds["mmse"].total_cost
    steady = load_packaged("platoon-4-steady").design("mtmse")
    assert steady.horizon is None and steady.average_cost > 0


# ---------------------------------------------------------------------------
# conversions
# ---------------------------------------------------------------------------
def test_scalar_covariances_mean_q_times_identity():
    d = base_dict()
    d["system"]["Q"] = 2.5
    d["system"]["Sigma_x"] = 0.5
    d["agents"][1]["R"] = 0.3
    sc = scenario_from_dict(d)
    np.testing.assert_allclose(sc.system.Q[0], 2.5 * np.eye(4))
    np.testing.assert_allclose(sc.system.Sigma_x, 0.5 * np.eye(4))
    np.testing.assert_allclose(sc.system.R[1][0], 0.3 * np.eye(4))


def test_matrices_as_nested_lists():
    d = base_dict()
    d["system"]["Q"] = np.diag([1.0, 2.0, 3.0, 4.0]).tolist()
    d["agents"] = [
        {"C": [[1, 0, 0, 0]], "R": [[0.2]]},
        {"C": [[0, 1, 0, 0], [0, 0, 1, 0]], "R": [[0.1, 0.0], [0.0, 0.3]]},
        {"C": [[0, 0, 1, 0]], "R": 0.1},
        {"C": [[0, 0, 0, 1]], "R": 0.1},
    ]
    sc = scenario_from_dict(d)
    assert sc.system.dy == (1, 2, 1, 1)
    np.testing.assert_allclose(sc.system.Q[0], np.diag([1.0, 2.0, 3.0, 4.0]))
    np.testing.assert_allclose(sc.system.R[1][0], [[0.1, 0.0], [0.0, 0.3]])


@pytest.mark.parametrize(
    "kind, builder", [("complete", CommGraph.complete), ("line", CommGraph.line), ("ring", CommGraph.ring), ("star", CommGraph.star)]
)
def test_builder_graphs(kind, builder):
    d = base_dict()
    d["graph"] = {"kind": kind, "delay": 2}
    assert scenario_from_dict(d).graph == builder(4, 2)
    d["graph"] = {"kind": kind}
    assert scenario_from_dict(d).graph == builder(4, 1)  # delay defaults to 1


def test_builder_graph_options():
    d = base_dict()
    d["graph"] = {"kind": "ring", "directed": True}
    assert scenario_from_dict(d).graph == CommGraph.ring(4, 1, directed=True)
    d["graph"] = {"kind": "star", "center": 2, "delay": 3}
    assert scenario_from_dict(d).graph == CommGraph.star(4, 3, center=2)


def test_explicit_edges():
    d = base_dict()
    d["graph"] = {"edges": [[0, 1, 1], [1, 2, 2], [2, 3, 1], [3, 0, 3]]}
    sc = scenario_from_dict(d)
    assert sc.graph == CommGraph(4, ((0, 1, 1), (1, 2, 2), (2, 3, 1), (3, 0, 3)))
    assert sc.information == InformationStructure.from_graph(sc.graph)


def test_explicit_S_and_L():
    d = base_dict()
    ref = TeamCost.platoon(4, 10.0)
    d["cost"] = {"S": ref.S[0].tolist(), "L": np.eye(4).tolist()}
    sc = scenario_from_dict(d)
    np.testing.assert_allclose(sc.cost.S, ref.S)
    d["cost"] = {"S": 2.0, "L": np.eye(4).tolist()}
    np.testing.assert_allclose(scenario_from_dict(d).cost.S[0], 2.0 * np.eye(4))


@pytest.mark.parametrize("kind, builder", [("average", TeamCost.average_tracking), ("platoon", TeamCost.platoon), ("ring", TeamCost.ring)])
def test_cost_builders(kind, builder):
    d = base_dict()
    d["cost"] = {"kind": kind, "lambda": 3}
    np.testing.assert_allclose(scenario_from_dict(d).cost.S, builder(4, 3.0).S)


def test_mse_cost():
    d = base_dict()
    d["cost"] = {"kind": "mse"}
    c = scenario_from_dict(d).cost
    np.testing.assert_allclose(c.S, TeamCost.mse(4, 4).S)
    np.testing.assert_allclose(c.L, TeamCost.mse(4, 4).L)


def test_reduced_information_is_used_and_validated():
    d = base_dict()
    d["information"] = {"common_lag": 3, "local": copy.deepcopy(IS1_LOCAL)}
    sc = scenario_from_dict(d)
    assert sc.information == InformationStructure(4, 3, IS1_LOCAL)
    assert sc.design("mtmse").info["local_dims"] == (12, 16, 16, 12)


def test_information_window_violating_the_graph():
    d = base_dict()
    local = copy.deepcopy(IS1_LOCAL)
    local[0] = [[0, 0, 1], [1, 0, 1]]  # y_1(t) cannot reach agent 0 at once: the link has delay 1
    d["information"] = {"common_lag": 3, "local": local}
    msg = error_of(d)
    assert msg.startswith("information.local[0]"), msg
    assert "newest >= 1" in msg


def test_information_common_lag_too_small():
    d = base_dict()
    d["information"] = {"common_lag": 2, "local": [[[i, 0, 1]] for i in range(4)]}
    msg = error_of(d)
    assert msg.startswith("information.common_lag"), msg


def test_information_bad_window():
    d = base_dict()
    d["information"] = {"common_lag": 3, "local": [[[0, 2, 1]], [], [], []]}
    assert error_of(d).startswith("information.local[0][0]")
    d["information"] = {"common_lag": 3, "local": [[[0, 0, 3]], [], [], []]}
    assert error_of(d).startswith("information.local[0][0]")
    d["information"] = {"common_lag": 3, "local": [[], []]}
    assert error_of(d).startswith("information.local")
    d["information"] = {"common_lag": 3}
    assert error_of(d).startswith("information.local: missing")


def test_json_scenario_equals_toml():
    js = load_scenario(EXAMPLES / "platoon-4.json")
    tm = load_scenario(EXAMPLES / "platoon-4.toml")
    assert js.name == tm.name and js.horizon == tm.horizon and js.estimators == tm.estimators
    assert js.graph == tm.graph and js.information == tm.information
    for a, b in ((js.system.A, tm.system.A), (js.system.Q, tm.system.Q), (js.cost.S, tm.cost.S), (js.cost.L, tm.cost.L)):
        np.testing.assert_array_equal(a, b)
    for i in range(4):
        np.testing.assert_array_equal(js.system.C[i], tm.system.C[i])
        np.testing.assert_array_equal(js.system.R[i], tm.system.R[i])
    assert js.design("mtmse").total_cost == pytest.approx(tm.design("mtmse").total_cost, rel=1e-12)


def test_name_defaults_to_file_stem(tmp_path):
    d = base_dict()
    del d["name"]
    p = tmp_path / "my-case.json"
    p.write_text(json.dumps(d))
    assert load_scenario(p).name == "my-case"


def test_estimators_after_the_last_table_are_accepted(tmp_path):
    """As in the contract's example: `estimators = [...]` written after [cost] lands in that table in TOML."""
    text = (PACKAGED / "platoon-4.toml").read_text().replace('estimators = ["mtmse", "mmse", "centralized"]', "")
    p = tmp_path / "late.toml"
    p.write_text(text + '\nestimators = ["mmse", "centralized"]\n')
    sc = load_scenario(p)
    assert sc.estimators == ("mmse", "centralized")
    assert "estimators" not in sc.raw["cost"]


def test_raw_is_a_copy():
    d = base_dict()
    sc = scenario_from_dict(d)
    d["cost"]["lambda"] = 99.0
    assert sc.raw["cost"]["lambda"] == 10.0


# ---------------------------------------------------------------------------
# bad input: every error is a ScenarioError starting with the key path
# ---------------------------------------------------------------------------
@pytest.mark.parametrize(
    "path", ["system", "system.A", "system.Q", "system.Sigma_x", "agents", "graph", "cost", "estimators", "agents[1].C", "agents[3].R"]
)
def test_missing_required_key(path):
    d = base_dict()
    if "[" in path:
        i = int(path.split("[")[1].split("]")[0])
        del d["agents"][i][path.rsplit(".", 1)[1]]
    elif "." in path:
        a, b = path.split(".")
        del d[a][b]
    else:
        del d[path]
    msg = error_of(d)
    assert msg.startswith(f"{path}: missing"), msg


@pytest.mark.parametrize(
    "where, key, expected",
    [
        ("", "horizn", "horizn: unknown key; did you mean 'horizon'?"),
        ("system", "Sigma", "system.Sigma: unknown key; did you mean 'Sigma_x'?"),
        ("cost", "lamda", "cost.lamda: unknown key; did you mean 'lambda'?"),
        ("graph", "dealy", "graph.dealy: unknown key; did you mean 'delay'?"),
        ("agents[2]", "Rr", "agents[2].Rr: unknown key; did you mean 'R'?"),
        ("information", "comon_lag", "information.comon_lag: unknown key; did you mean 'common_lag'?"),
    ],
)
def test_unknown_key(where, key, expected):
    d = base_dict()
    d["information"] = {"common_lag": 3, "local": copy.deepcopy(IS1_LOCAL)}
    if where == "":
        d[key] = 1
    elif where == "agents[2]":
        d["agents"][2][key] = 1
    else:
        d[where][key] = 1
    msg = error_of(d)
    assert msg.startswith(expected), msg


def test_wrong_shape_R_names_the_agent():
    d = base_dict()
    d["agents"][2]["R"] = np.eye(3).tolist()
    assert error_of(d) == "agents[2].R: expected a 4x4 symmetric positive definite matrix, found 3x3"


def test_non_pd_R():
    d = base_dict()
    d["agents"][1]["R"] = np.diag([1.0, 1.0, 0.0, 1.0]).tolist()
    msg = error_of(d)
    assert msg.startswith("agents[1].R: expected a symmetric positive definite matrix"), msg
    d["agents"][1]["R"] = -0.1
    assert error_of(d).startswith("agents[1].R: expected a symmetric positive definite matrix")


def test_non_symmetric_Q():
    d = base_dict()
    Q = np.eye(4)
    Q[0, 1] = 0.5
    d["system"]["Q"] = Q.tolist()
    assert error_of(d).startswith("system.Q: expected a symmetric matrix")


@pytest.mark.parametrize(
    "mutate, prefix",
    [
        (
            lambda d: d["system"].__setitem__("A", [[0.9, 0.0], [0.0, 0.9]]),
            "agents[0].C: expected a kx2 matrix, found 4x4 (every C_i needs d_x columns",
        ),
        (lambda d: d["system"].__setitem__("A", [[0.9, 0, 0], [0, 0.9, 0]]), "system.A: expected a square"),
        (lambda d: d["system"].__setitem__("A", 0.9), "system.A: expected a matrix"),
        (
            lambda d: d["system"].__setitem__("A", [[0.9, 0, 0, 0], [0.7, 0.9, 0], [0, 0, 1, 0], [0, 0, 0, 1]]),
            "system.A: expected rows of equal length, found row 0 with 4 entries and row 1 with 3",
        ),
        (
            lambda d: d["system"].__setitem__("A", [[0.9, "x", 0, 0]] * 4),
            "system.A: expected a number or nested lists of numbers, found the string 'x' at [0][1]",
        ),
        (lambda d: d["system"].__setitem__("Sigma_x", np.eye(3).tolist()), "system.Sigma_x: expected a 4x4"),
        (lambda d: d["agents"][3].__setitem__("C", [[1, 0, 0]]), "agents[3].C: expected a kx4 matrix, found 1x3"),
        (lambda d: d["agents"][0].__setitem__("C", True), "agents[0].C: expected a number or nested lists of numbers, found the boolean true"),
        (lambda d: d.__setitem__("agents", []), "agents: expected a non-empty list"),
        (lambda d: d.__setitem__("agents", [1, 2]), "agents[0]: expected a table"),
        (lambda d: d.__setitem__("system", [1]), "system: expected a table"),
        (lambda d: d.__setitem__("horizon", 0), "horizon: expected an integer number of steps >= 1"),
        (lambda d: d.__setitem__("horizon", 2.5), "horizon: expected an integer"),
        (lambda d: d.__setitem__("name", ""), "name: expected a non-empty string"),
        (lambda d: d["cost"].__setitem__("lambda", -1.0), "cost.lambda: expected a non-negative number"),
        (lambda d: d["cost"].__setitem__("lambda", "big"), "cost.lambda: expected a non-negative number"),
        (lambda d: d["cost"].pop("lambda"), "cost.lambda: missing required key"),
        (lambda d: d["cost"].__setitem__("kind", "platon"), "cost.kind: unknown cost kind 'platon'; did you mean 'platoon'?"),
        (
            lambda d: d.__setitem__("cost", {"kind": "mse", "lambda": 1.0}),
            "cost.lambda: the 'mse' cost (S = I, every agent estimates the whole state) has no lambda",
        ),
        (lambda d: d.__setitem__("cost", {"kind": "platoon", "lambda": 1.0, "S": 1.0}), "cost: give either kind"),
        (lambda d: d.__setitem__("cost", {"S": np.eye(4).tolist()}), "cost.L: missing required key"),
        (lambda d: d.__setitem__("cost", {"S": np.eye(3).tolist(), "L": np.eye(4).tolist()}), "cost.S: expected a size that is a multiple"),
        (lambda d: d.__setitem__("cost", {"S": np.eye(4).tolist(), "L": np.eye(4)[:, :3].tolist()}), "cost.L: expected 4 columns"),
        (lambda d: d.__setitem__("cost", {"S": (-np.eye(4)).tolist(), "L": np.eye(4).tolist()}), "cost.S: expected a symmetric positive definite"),
        (lambda d: d.__setitem__("cost", {}), "cost: expected kind"),
        (lambda d: d.__setitem__("graph", {"kind": "tree"}), "graph.kind: unknown graph kind 'tree'"),
        (lambda d: d.__setitem__("graph", {"kind": "line", "delay": 0}), "graph.delay: expected an integer delay >= 1"),
        (lambda d: d.__setitem__("graph", {"kind": "line", "delay": 1.5}), "graph.delay: expected an integer delay >= 1"),
        (lambda d: d.__setitem__("graph", {"kind": "line", "directed": True}), 'graph.directed: only used with kind = "ring"'),
        (lambda d: d.__setitem__("graph", {"kind": "line", "colour": 1}), "graph.colour: unknown key"),
        (lambda d: d.__setitem__("graph", {"kind": "line", "edges": [[0, 1, 1]]}), "graph: give either edges or kind"),
        (lambda d: d.__setitem__("graph", {}), "graph: expected edges"),
        (
            lambda d: d.__setitem__("graph", {"edges": [[0, 1, 1], [1, 0, 1], [1, 2, 1], [2, 1, 1], [2, 3, 1]]}),
            "graph: expected a strongly connected graph, found no directed path from agent 3",
        ),
        (lambda d: d.__setitem__("graph", {"edges": [[0, 4, 1]]}), "graph.edges[0] target: expected an agent index in 0..3"),
        (lambda d: d.__setitem__("graph", {"edges": [[0, 1, 0]]}), "graph.edges[0] delay: expected an integer delay >= 1"),
        (lambda d: d.__setitem__("graph", {"edges": "0-1"}), "graph.edges: expected a list"),
        (lambda d: d.__setitem__("estimators", ["mtmse", "kalman"]), "estimators[1]: unknown estimator 'kalman'"),
        (lambda d: d.__setitem__("estimators", ["mtmes"]), "estimators[0]: unknown estimator 'mtmes'; did you mean 'mtmse'?"),
        (lambda d: d.__setitem__("estimators", []), "estimators: expected a non-empty list"),
        (lambda d: d.__setitem__("estimators", "mtmse"), "estimators: expected a non-empty list"),
        (lambda d: d.__setitem__("estimators", ["mmse", "mmse"]), "estimators[1]: 'mmse' is listed twice"),
        (lambda d: d["system"].__setitem__("A", [np.eye(4).tolist()] * 3), "system.A: a horizon of 5 steps needs 4 matrices, found 3"),
    ],
)
def test_bad_input_names_the_key(mutate, prefix):
    d = base_dict()
    mutate(d)
    msg = error_of(d)
    assert msg.startswith(prefix), msg


def test_kcf_in_scenarios():
    d = base_dict()
    d["estimators"] = ["mtmse", "kcf"]
    d["kcf"] = {"epsilon": 0.05, "variant": "ideal"}
    sc = scenario_from_dict(d)
    k = sc.design("kcf")
    assert k.info["variant"] == "ideal" and k.info["epsilon"] == 0.05
    for bad, prefix in [
        ({"epsilon": -1.0}, "kcf.epsilon: expected a consensus step > 0"),
        ({"variant": "fast"}, "kcf.variant: expected"),
        ({"eps": 1.0}, "kcf.eps: unknown option of the 'kcf' family; did you mean 'epsilon'?"),
    ]:
        d2 = base_dict()
        d2["estimators"] = ["kcf"]
        d2["kcf"] = bad
        assert error_of(d2).startswith(prefix)
    d3 = base_dict()
    d3.pop("horizon", None)
    d3["estimators"] = ["mtmse", "kcf"]
    assert error_of(d3).startswith("horizon: the 'kcf' family has no infinite-horizon design")


def test_cikf_in_scenarios():
    d = base_dict()
    d["estimators"] = ["mtmse", "cikf", "centralized"]
    ds = scenario_from_dict(d).designs()
    assert ds["cikf"].estimator == "cikf"
    assert np.all(ds["centralized"].stage_costs <= ds["cikf"].stage_costs * (1 + 1e-9))
    d["estimators"] = ["mtmse", "ukf"]
    msg = error_of(d)
    assert msg.startswith("estimators[1]: unknown estimator 'ukf'")
    for avail in teamkf.families():
        assert avail in msg


def test_population_scenarios():
    from teamkf.study.population import PopulationScenario

    sc = scenario_from_dict({"name": "interference", "horizon": 50, "population": {"n_agents": 1000, "a": 2.5}})
    assert isinstance(sc, PopulationScenario) and sc.model.n_agents == 1000
    d = {"name": "interference", "horizon": 1000, "population": {"n_agents": 1000, "a": "fast"}}
    msg = error_of(d)
    assert msg.startswith("population.a:"), msg


def test_steady_state_with_time_varying_system():
    d = base_dict()
    del d["horizon"]
    d["system"]["A"] = [PLATOON_A] * 5
    assert error_of(d).startswith("system: a steady-state design needs constant")


def test_toml_syntax_error_has_file_line_and_column(tmp_path):
    p = tmp_path / "broken.toml"
    p.write_text('name = "x"\nhorizon = 10\n[system]\nA = = [[1.0]]\n')
    with pytest.raises(ScenarioError) as ei:
        load_scenario(p)
    msg = str(ei.value)
    assert msg.startswith(str(p)) and "invalid TOML" in msg and "line 4" in msg and "column" in msg


def test_json_syntax_error(tmp_path):
    p = tmp_path / "broken.json"
    p.write_text('{"name": "x",\n "horizon": }')
    with pytest.raises(ScenarioError) as ei:
        load_scenario(p)
    assert str(ei.value).startswith(str(p)) and "line 2" in str(ei.value)


def test_json_top_level_must_be_an_object(tmp_path):
    p = tmp_path / "list.json"
    p.write_text("[1, 2]")
    with pytest.raises(ScenarioError, match="top level"):
        load_scenario(p)


def test_binary_file(tmp_path):
    p = tmp_path / "x.toml"
    p.write_bytes(b"\xff\xfe\x00binary")
    with pytest.raises(ScenarioError, match="UTF-8"):
        load_scenario(p)


def test_missing_file():
    with pytest.raises(FileNotFoundError):
        load_scenario("/nonexistent/x.toml")
    with pytest.raises(ScenarioError, match="no packaged scenario"):
        load_packaged("nope")


def test_scenario_error_is_a_teamkf_value_error():
    d = base_dict()
    del d["cost"]
    with pytest.raises(ValueError):
        scenario_from_dict(d)
    with pytest.raises(TeamkfError):
        scenario_from_dict(d)


def test_error_key_attribute():
    d = base_dict()
    d["agents"][2]["R"] = np.eye(3).tolist()
    with pytest.raises(ScenarioError) as ei:
        scenario_from_dict(d)
    assert ei.value.key == "agents[2].R"


# ---------------------------------------------------------------------------
# dotted keys
# ---------------------------------------------------------------------------
def test_set_dotted_returns_a_modified_copy():
    d = base_dict()
    e = set_dotted(d, "cost.lambda", 123.0)
    assert e["cost"]["lambda"] == 123.0 and d["cost"]["lambda"] == 10.0
    assert scenario_from_dict(e).cost.S[0][0, 0] == pytest.approx(1 + 123.0)


def test_set_dotted_graph_delay_builder_and_edges():
    d = base_dict()
    e = set_dotted(d, "graph.delay", 2)
    assert scenario_from_dict(e).graph == CommGraph.line(4, 2)
    d["graph"] = {"edges": [[0, 1, 1], [1, 0, 3], [1, 2, 1], [2, 1, 1], [2, 3, 1], [3, 2, 1]]}
    with pytest.raises(ScenarioError, match=r"graph.delay: the graph has explicit edges with different delays \(1, 3\)"):
        set_dotted(d, "graph.delay", 2)  # the 3 would be lost silently
    d["graph"]["edges"][1] = [1, 0, 1]  # one common delay: graph.delay sets it
    e = set_dotted(d, "graph.delay", 2)
    assert scenario_from_dict(e).graph == CommGraph.line(4, 2)
    assert d["graph"]["edges"][1] == [1, 0, 1]


def test_set_dotted_paths():
    d = base_dict()
    e = set_dotted(d, "agents[2].R", 0.5)
    assert e["agents"][2]["R"] == 0.5 and d["agents"][2]["R"] == 0.1
    e = set_dotted(d, "agents.1.R", 0.7)
    assert e["agents"][1]["R"] == 0.7
    e = set_dotted(d, "information.common_lag", 4)
    assert e["information"] == {"common_lag": 4}
    e = set_dotted(d, "horizon", 7)
    assert scenario_from_dict(e).horizon == 7
    with pytest.raises(ScenarioError):
        set_dotted(d, "agents[9].R", 1.0)
    with pytest.raises(ScenarioError):
        set_dotted(d, "horizon.x", 1.0)
    with pytest.raises(ScenarioError):
        set_dotted(d, "cost..lambda", 1.0)


def test_scenario_updated():
    sc = load_packaged("uav-4")
    sc2 = sc.updated({"cost.lambda": 1.6, "graph.delay": 1, "horizon": 10})
    assert sc2.horizon == 10 and sc2.graph == CommGraph.complete(4, 1)
    np.testing.assert_allclose(sc2.cost.S, TeamCost.average_tracking(4, 1.6).S)
    assert sc.horizon == 100 and sc.graph == CommGraph.complete(4, 2)
