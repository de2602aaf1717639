"""Unreliable links in the runtime: reliable links are today's runtime, drops/jitter/outages/failures are
seeded and counted, nothing breaks for p in [0, 1], and the robust design makes jitter cost only the
larger delay (Monte Carlo == analytic)."""

from __future__ import annotations

import numpy as np
import pytest

from teamkf import CommGraph, design_mtmse
from teamkf.exceptions import ArgumentError, GraphError, TeamkfError
from teamkf.simulation.links import LinkModel, LinkStats, link_streams, pass_messages_lossy, robust_graph
from teamkf.simulation.monte_carlo import monte_carlo
from teamkf.simulation.online import _batched
from teamkf.simulation.runtime import graph_agents, run_graph
from teamkf.simulation.sampling import sample_paths
from teamkf.study.scenario import load_packaged

FAMILIES = ("mtmse", "mmse", "centralized", "kcf", "cikf")


@pytest.fixture(scope="module")
def platoon():
    sc = load_packaged("platoon-4").updated({"horizon": 15})
    return sc, sc.designs(FAMILIES)


def test_reliable_links_are_todays_runtime_bit_for_bit(platoon):
    sc, ds = platoon
    p = sample_paths(sc.system, 15, 3, rng=4)
    for name, d in ds.items():
        ref = run_graph(graph_agents(d), sc.graph, p.y)
        np.testing.assert_array_equal(run_graph(graph_agents(d), sc.graph, p.y, links=LinkModel(p_drop=0.0, jitter=0), rng=1), ref)
    mc0 = monte_carlo(ds, 15, 4, rng=2, path="runtime", graph=sc.graph)
    mc1 = monte_carlo(ds, 15, 4, rng=2, path="runtime", graph=sc.graph, links=LinkModel())
    for name in ds:
        np.testing.assert_array_equal(mc0[name].stage_mean, mc1[name].stage_mean)
        assert name == "centralized" or mc1[name].links.counts[(0, 1)] == {"sent": 60, "delivered": 60, "late": 0, "dropped": 0}


@pytest.mark.parametrize("name", ["mtmse", "mmse", "kcf", "cikf"])
def test_lossy_loop_without_losses_equals_reliable_loop(platoon, name):
    """The lossy loop itself, forced on with nothing lost: the same estimates run by run (bit for bit for
    CIKF, whose lossy loop steps one run at a time with the agents' own step; to round-off for MTMSE/MMSE,
    whose lossy step is one linear map per arrival pattern applied to all runs at once — the same
    arithmetic in another order — and for KCF, which recomputes its gains online in tolerant mode)."""
    sc, ds = platoon
    d = ds[name]
    p = sample_paths(sc.system, 15, 2, rng=5)
    ys = _batched([getattr(a, "inner", a) for a in graph_agents(d)], p.y)
    got = pass_messages_lossy(graph_agents(d), sc.graph, ys, LinkModel(), link_streams(0, 2))
    for r in range(2):
        ref = run_graph(graph_agents(d), sc.graph, [y[r : r + 1] for y in p.y])
        if name == "cikf":
            np.testing.assert_array_equal(got[r : r + 1], ref)
        tol = 1e-12 if name in ("mtmse", "mmse") else 1e-9
        np.testing.assert_allclose(got[r : r + 1], ref, rtol=tol, atol=tol * np.abs(ref).max())


@pytest.mark.parametrize("p_drop", [0.0, 0.05, 0.5, 1.0])
@pytest.mark.parametrize("jitter", [0, 2])
def test_no_nan_no_exception_for_any_drop_probability(platoon, p_drop, jitter):
    sc, ds = platoon
    mc = monte_carlo(ds, 15, 3, rng=7, path="runtime", graph=sc.graph, links=LinkModel(p_drop=p_drop, jitter=jitter))
    for name, r in mc.items():
        assert np.all(np.isfinite(r.stage_mean)), name
    c = mc["mtmse"].links.counts[(1, 2)]
    assert c["sent"] == 45 and c["delivered"] + c["late"] + c["dropped"] == 45
    if p_drop == 1.0:
        assert c["dropped"] == 45


def test_p_one_means_every_agent_on_its_own_measurements(platoon):
    """With every packet lost, KCF is each agent's own Kalman filter on y_i alone (no neighbour ever fused)."""
    sc, ds = platoon
    from teamkf import LinearGaussianSystem, design_centralized

    p = sample_paths(sc.system, 15, 1, rng=8)
    z = run_graph(graph_agents(ds["kcf"]), sc.graph, p.y, links=LinkModel(p_drop=1.0), rng=0)
    sysm = sc.system
    for i in range(4):
        own = LinearGaussianSystem(A=sysm.A[0], Q=sysm.Q[0], Sigma_x=sysm.Sigma_x, C=[sysm.C[i][0]], R=[sysm.R[i][0]])
        from teamkf import TeamCost

        kf = design_centralized(own, TeamCost(S=np.eye(1), L=sc.cost.L_block(i, 0), n_agents=1), horizon=15)
        zi = run_graph(graph_agents(kf), CommGraph(1, ()), [p.y[i]])
        np.testing.assert_allclose(z[0, :, i], zi[0, :, 0], rtol=1e-9, atol=1e-9)


def test_seeded_and_independent_of_batch(platoon):
    sc, ds = platoon
    lm = LinkModel(p_drop=0.3, jitter=1)
    sub = {"mtmse": ds["mtmse"], "kcf": ds["kcf"]}
    a = monte_carlo(sub, 15, 6, rng=11, path="runtime", graph=sc.graph, links=lm, batch=6)
    b = monte_carlo(sub, 15, 6, rng=11, path="runtime", graph=sc.graph, links=lm, batch=4)
    c = monte_carlo(sub, 15, 6, rng=12, path="runtime", graph=sc.graph, links=lm, batch=6)
    d = monte_carlo(sub, 15, 6, rng=11, path="runtime", graph=sc.graph, links=lm, batch=2, chunk=2)
    for name in sub:
        # the same link events whatever the batch; the costs bit for bit for one batch size (any chunking) and to
        # round-off across batch sizes (the sampled noises are drawn block by block)
        np.testing.assert_array_equal(
            a[name].stage_mean, monte_carlo(sub, 15, 6, rng=11, path="runtime", graph=sc.graph, links=lm, batch=6, chunk=6)[name].stage_mean
        )
        np.testing.assert_allclose(a[name].stage_mean, b[name].stage_mean, rtol=1e-12)
        np.testing.assert_allclose(a[name].stage_mean, d[name].stage_mean, rtol=1e-12)
        assert a[name].links.counts == b[name].links.counts == d[name].links.counts
    assert a["mtmse"].links.counts != c["mtmse"].links.counts


def test_outages_and_failures_are_counted():
    g = CommGraph.line(3)
    sc = load_packaged("platoon-4")  # only for a system of the right kind
    del sc
    from tests.helpers import random_cost, random_system

    rng = np.random.default_rng(0)
    sys, cost = random_system(rng, 3, 2, [1, 1, 1], stable=True), random_cost(rng, 3, 2, 1)
    d = design_mtmse(sys, cost, g, horizon=20)
    p = sample_paths(sys, 20, 2, rng=1)
    st = LinkStats()
    z = run_graph(graph_agents(d), g, p.y, links=LinkModel(outages=[(0, 1, 5, 9)], failures={2: 12}), rng=3, stats=st)
    assert np.all(np.isfinite(z))
    assert st.counts[(0, 1)] == {"sent": 40, "delivered": 30, "late": 0, "dropped": 10}
    assert st.counts[(2, 1)]["sent"] == 24 and st.counts[(2, 1)]["dropped"] == 0
    assert st.missed  # agents noticed the missing packets


def test_robust_design_for_bounded_jitter_costs_only_the_larger_delay():
    """Designed for τ + J and run with jitter up to J: no deadline is missed, and the Monte Carlo cost
    equals the analytic cost of the design for the larger delays within 4 standard errors."""
    sc = load_packaged("platoon-4").updated({"horizon": 20})
    J = 2
    g = sc.graph
    robust = design_mtmse(sc.system, sc.cost, robust_graph(g, J), horizon=20)
    mc = monte_carlo({"robust": robust}, 20, 400, rng=21, path="runtime", graph=g, links=LinkModel(jitter=J))["robust"]
    assert mc.links.missed == {}
    c = mc.links.counts[(0, 1)]
    assert c["late"] > 0 and c["dropped"] == 0
    assert abs(mc.total_mean - robust.total_cost) < 4 * mc.total_sem, (mc.total_mean, robust.total_cost, mc.total_sem)
    # the nominal design under the same jitter misses deadlines and does worse than the robust one
    nominal = sc.design("mtmse")
    mcn = monte_carlo({"nominal": nominal}, 20, 400, rng=21, path="runtime", graph=g, links=LinkModel(jitter=J))["nominal"]
    assert mcn.links.missed and mcn.total_mean > robust.total_cost


@pytest.mark.parametrize(
    "kwargs, match, exc",
    [
        ({"p_drop": 1.5}, "p_drop", ArgumentError),
        ({"p_drop": -0.1}, "p_drop", ArgumentError),
        ({"jitter": -1}, "jitter: expected a whole number of steps >= 0", ArgumentError),
        ({"jitter": 0.5}, "jitter", ArgumentError),
        ({"outages": [(0, 1, 5, 2)]}, r"outages\[0\]: expected 0 <= first <= last", ArgumentError),
    ],
)
def test_bad_link_models(kwargs, match, exc):
    with pytest.raises(exc, match=match):
        LinkModel(**kwargs)


def test_network_table_and_edges_that_do_not_exist():
    g = CommGraph.line(3)
    lm = LinkModel.from_dict({"p_drop": [[0, 1, 0.2]], "jitter": 1, "outages": [[1, 2, 0, 3]], "failures": [[2, 10]]}, g)
    assert lm.p_of((0, 1)) == 0.2 and lm.p_of((1, 0)) == 0.0 and lm.jitter_of((2, 1)) == 1 and lm.failures == {2: 10}
    with pytest.raises(GraphError, match=r"network.outages\[0\]: the graph has no edge \[0, 2\]"):
        LinkModel.from_dict({"outages": [[0, 2, 1, 2]]}, g)
    with pytest.raises(GraphError, match=r"network.p_drop: the graph has no edge \[2, 0\]"):
        LinkModel.from_dict({"p_drop": [[2, 0, 0.5]]}, g)
    with pytest.raises(TeamkfError, match="network.p_drop"):
        LinkModel.from_dict({"p_drop": 2}, g)
    with pytest.raises(ArgumentError, match="network.drop: unknown key"):
        LinkModel.from_dict({"drop": 0.1}, g)


def _network_scenario(tmp_path, network: str):
    import importlib.resources

    base = (importlib.resources.files("teamkf") / "scenarios" / "platoon-4.toml").read_text()
    base = base.replace("horizon = 100", "horizon = 12")
    f = tmp_path / "lossy.toml"
    f.write_text(base + "\n[network]\n" + network)
    return f


def test_scenario_network_table_drives_evaluate(tmp_path, capsys):
    import json

    from teamkf.cli import main
    from teamkf.study.scenario import load_scenario

    f = _network_scenario(tmp_path, "p_drop = 0.2\njitter = 1\noutages = [[0, 1, 3, 5]]\n")
    sc = load_scenario(f)
    assert sc.links.p_of((2, 3)) == 0.2 and sc.monte_carlo_options()["path"] == "runtime"
    assert main(["evaluate", str(f), "--monte-carlo", "20", "--seed", "3", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["estimators"]["mtmse"]["mc_cost"] > out["estimators"]["mtmse"]["total_cost"]  # lossy links cost more than the design


@pytest.mark.parametrize(
    "network, match",
    [
        ("p_drop = 1.5\n", "network.p_drop"),
        ("jitter = -1\n", "network.jitter"),
        ("outages = [[0, 3, 1, 2]]\n", r"network.outages\[0\]: the graph has no edge \[0, 3\]"),
        ("dropp = 0.1\n", "network.dropp: unknown key"),
    ],
)
def test_bad_network_table(tmp_path, network, match):
    from teamkf.exceptions import ScenarioError
    from teamkf.study.scenario import load_scenario

    with pytest.raises(ScenarioError, match=match):
        load_scenario(_network_scenario(tmp_path, network))


def _lossy_mc_summary(seed: int) -> tuple[list[float], dict]:
    sc = load_packaged("platoon-4").updated({"horizon": 10})
    mc = monte_carlo({"mtmse": sc.design("mtmse")}, 10, 3, rng=seed, path="runtime", graph=sc.graph, links=LinkModel(p_drop=0.3, jitter=1))["mtmse"]
    return mc.stage_mean.tolist(), mc.links.counts


def test_same_seed_same_drops_in_another_process():
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(1) as ex:
        there = ex.submit(_lossy_mc_summary, 31).result()
    assert there == _lossy_mc_summary(31)


def test_cli_network_flags(capsys):
    import json

    from teamkf.cli import main

    argv = ["evaluate", "platoon-4", "--monte-carlo", "10", "--seed", "1", "--json"]
    assert main(argv) == 0
    reliable = json.loads(capsys.readouterr().out)["estimators"]["mtmse"]["mc_cost"]
    assert main(argv + ["--p-drop", "0.5", "--jitter", "1"]) == 0
    lossy = json.loads(capsys.readouterr().out)["estimators"]["mtmse"]["mc_cost"]
    assert lossy > reliable
    assert main(argv + ["--p-drop", "1.5"]) == 2
    assert "network.p_drop" in capsys.readouterr().err
    assert main(argv + ["--jitter", "-1"]) == 2
    assert "network.jitter" in capsys.readouterr().err


def test_same_drops_on_dask_as_in_one_process(platoon):
    """Determinism: the same seed gives the same link events, counts and costs on a local Dask cluster."""
    pytest.importorskip("distributed")
    sc, ds = platoon
    lm = LinkModel(p_drop=0.3, jitter=1, outages=[(1, 2, 3, 6)])
    sub = {"mtmse": ds["mtmse"], "kcf": ds["kcf"]}
    serial = monte_carlo(sub, 15, 8, rng=11, path="runtime", graph=sc.graph, links=lm, batch=2, chunk=2)
    dask = monte_carlo(sub, 15, 8, rng=11, path="runtime", graph=sc.graph, links=lm, batch=2, chunk=2, scheduler="local")
    for name in sub:
        np.testing.assert_array_equal(serial[name].stage_mean, dask[name].stage_mean)
        assert serial[name].links.counts == dask[name].links.counts
        assert serial[name].links.missed == dask[name].links.missed
