"""The drop-aware design over long horizons: the finite-memory form (``memory = m``) is exact (its cost is its own Monte
Carlo, and the full design when m >= T), and a design that does not fit is refused in one line naming what fits."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from teamkf import CommGraph, LinearGaussianSystem, TeamCost, _budget
from teamkf.cli import main
from teamkf.estimators import _lossy_size, team_lossy
from teamkf.estimators._arrivals import ArrivalModel
from teamkf.estimators.team_lossy import design_mtmse_lossy
from teamkf.simulation.sampling import sample_paths
from teamkf.study import measurements as M
from teamkf.study.scenario import load_scenario

GIB = 1024**3
RING6 = Path(__file__).parents[2] / "examples" / "scenarios" / "ring-6-lossy.toml"


@pytest.fixture(scope="module")
def ring3() -> tuple[LinearGaussianSystem, TeamCost, CommGraph]:
    """Three agents on a two-way ring with delay-2 links (the farthest item arrives after 2 steps), unlike sensors."""
    A = 0.8 * np.eye(3) + 0.15 * np.roll(np.eye(3), 1, axis=0)
    Cs = [np.array([[1.0, 0, 0]]), np.array([[-1.0, 1, 0]]), np.array([[0, 0, 1.0]])]
    sysm = LinearGaussianSystem(A=A, C=Cs, Q=np.eye(3), R=[np.array([[r]]) for r in (0.1, 0.3, 3.0)], Sigma_x=np.eye(3))
    return sysm, TeamCost.platoon(3, 10.0), CommGraph.ring(3, delay=2)


def test_finite_memory_cost_is_its_own_monte_carlo(ring3: Any) -> None:
    """memory = 3 over T = 30 (items of the last 3 steps only): the exact expected cost within 4 SE of 4000 runs with drops."""
    sysm, cost, g = ring3
    T, p = 30, 0.3
    d = design_mtmse_lossy(sysm, cost, g, T, p_drop=p, memory=3)
    full = design_mtmse_lossy(sysm, cost, g, T, p_drop=p)
    assert full.total_cost < d.total_cost < d.info["local_kf_cost"]  # a smaller class, still better than no communication
    paths = sample_paths(sysm, T, 4000, rng=5)
    e = d.errors(paths, p_drop=p, rng=6)
    c = np.einsum("rki,ij,rkj->r", e, cost.S_at(0), e)
    se = c.std(ddof=1) / np.sqrt(c.size)
    assert abs(c.mean() - d.total_cost) < 4 * se, (c.mean(), se, d.total_cost)
    # the full design's gains, fed the same paths and drops, cost measurably less than memory 3 (the MC resolves the gap)
    ef = full.errors(paths, p_drop=p, rng=6)
    assert np.einsum("rki,ij,rkj->r", ef, cost.S_at(0), ef).mean() < c.mean()


@pytest.mark.parametrize("m", [12, 40])
def test_memory_at_least_the_horizon_is_the_full_design(ring3: Any, m: int) -> None:
    sysm, cost, g = ring3
    full = design_mtmse_lossy(sysm, cost, g, 12, p_drop=0.2)
    d = design_mtmse_lossy(sysm, cost, g, 12, p_drop=0.2, memory=m)  # a factorization per step instead of one for all
    np.testing.assert_allclose(d.stage_costs, full.stage_costs, rtol=1e-9)
    for a, b in zip(d.gains, full.gains):
        for Ga, Gb in zip(a, b):
            np.testing.assert_allclose(Ga, Gb, rtol=1e-6, atol=1e-9)


def test_ring6_example_is_sized_within_2_gib() -> None:
    """The packaged example (6 agents, delay-2 ring, p = 0.2, T = 300, memory = 16) is estimated well under 2 GiB; the
    full design of the same horizon is not (measured: 0.62 GiB and 4.3 GiB peak)."""
    sc = load_scenario(RING6)
    assert sc.horizon == 300 and sc.raw["mtmse_lossy"]["memory"] == 16
    arr = ArrivalModel.build(sc.graph, 0.2, 0)
    lean = _lossy_size.estimate(sc.system.dy, arr.ell, arr.prob, 300, 16, sc.system.dx, sc.cost.dz, False)[0]
    full = _lossy_size.estimate(sc.system.dy, arr.ell, arr.prob, 300, None, sc.system.dx, sc.cost.dz, True)[0]
    assert lean < 0.6 * GIB < 2 * GIB < full
    d = sc.updated({"horizon": 20}).design("mtmse_lossy")
    assert d.memory == 16 and d.lower_bound <= d.total_cost


def _scenario(tmp_path: Path, T: int, memory: int | None) -> Path:
    text = RING6.read_text().replace("horizon = 300", f"horizon = {T}")
    text = text.replace("memory = 16", f"memory = {memory}") if memory is not None else text.replace("memory = 16", "")
    f = tmp_path / f"ring6-{T}-{memory}.toml"
    f.write_text(text)
    return f


def test_cli_refuses_the_full_design_naming_the_memory_that_fits(tmp_path: Path, monkeypatch: Any, capsys: Any) -> None:
    monkeypatch.setattr(_budget, "available_memory", lambda: 2 * GIB)
    monkeypatch.setattr(team_lossy, "local_filter_moments", lambda *a, **k: pytest.fail("allocated before the size check"))
    assert main(["design", str(_scenario(tmp_path, 300, None))]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("teamkf: error: horizon: "), err
    assert "over T = 300 steps needs about 3.9 GiB" in err
    assert "set the mtmse_lossy option memory = 16 (the items of the last 16 steps: about 88.6 MiB" in err  # windowed form
    # filter sizes the same design before it reads a step further
    log = tmp_path / "log.csv"
    M.write_measurements(str(log), [np.zeros((300, 1)) for _ in range(6)])
    assert main(["filter", str(_scenario(tmp_path, 300, None)), "--measurements", str(log), "--out", str(tmp_path / "e.csv")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "memory = 16" in err, err
    assert not (tmp_path / "e.csv").exists()


def test_cli_long_horizon_memory_fits_or_is_refused_naming_the_longest(tmp_path: Path, monkeypatch: Any, capsys: Any) -> None:
    """T = 3000: without a memory refused naming memory = 16 (the windowed form: its arrays do not grow with T); with it the
    design fits 2 GiB; a horizon no memory fits is refused at once naming the longest horizon that does."""
    monkeypatch.setattr(_budget, "available_memory", lambda: 2 * GIB)
    monkeypatch.setattr(team_lossy, "local_filter_moments", lambda *a, **k: pytest.fail("allocated before the size check"))
    assert main(["design", str(_scenario(tmp_path, 3000, None))]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("teamkf: error: horizon: "), err
    assert "over T = 3,000 steps needs about 2.5 TiB" in err and "set the mtmse_lossy option memory = 16" in err, err
    sc = load_scenario(_scenario(tmp_path, 3000, 16))
    arr = ArrivalModel.build(sc.graph, 0.2, 0)
    _lossy_size.check(sc.system, arr, 3000, 16, sc.cost.dz, False)  # fits (measured: 0.27 GiB peak, 10 s of CPU)
    assert _lossy_size.estimate(sc.system.dy, arr.ell, arr.prob, 3000, 16, sc.system.dx, sc.cost.dz, False)[0] < 0.7 * GIB
    assert main(["design", str(_scenario(tmp_path, 100_000, 16))]) == 2
    err = capsys.readouterr().err
    assert (
        err.count("\n") == 1 and "over T = 100,000 steps (memory = 16)" in err and "use a horizon of at most 31,666 steps with memory = 7" in err
    ), err
    # the time limit alone refuses too, with the same kind of suggestion
    monkeypatch.setattr(_budget, "available_memory", lambda: 10**6 * GIB)
    assert main(["--max-hours", "0.0003", "design", str(_scenario(tmp_path, 3000, 16))]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "of computing" in err and "use a horizon of at most" in err, err


# ---------------------------------------------------------------------------
# deploy: each agent process gets its slice and never designs the team
# ---------------------------------------------------------------------------
def test_slices_rebuild_the_agents_bit_for_bit_under_drops(tmp_path: Path) -> None:
    from teamkf.estimators._slices import SliceContext, agent_from_slice
    from teamkf.simulation.links import LinkModel, link_streams, pass_messages_lossy
    from teamkf.study.slices import read_slice, slice_sections, write_slices

    sc = load_scenario(_scenario(tmp_path, 14, 4))
    d = sc.design("mtmse_lossy")
    f = tmp_path / "gains.npz"
    write_slices(f, slice_sections(sc, d))
    ctx = SliceContext(sc.system, sc.cost, sc.graph, sc.information, sc.horizon)
    agents = []
    for i in range(6):
        kind, arrays, meta = read_slice(str(f), sc, "mtmse_lossy", i)
        assert kind == "lossy" and arrays["F/13"].shape[1] == 7  # its fills act on its own last 2 m - 1 = 7 items
        agents.append(agent_from_slice(kind, ctx, i, arrays, meta)[1])
    with pytest.raises(IndexError, match="holds nothing of agent 1"):
        agents[2].design.gains[3][1]
    ys = [y for y in sample_paths(sc.system, 14, 3, rng=1).y]
    links = LinkModel(p_drop=0.4)
    ref = pass_messages_lossy(d.graph_agents(), sc.graph, ys, links, link_streams(5, 3), design=d)
    z = pass_messages_lossy(agents, sc.graph, ys, links, link_streams(5, 3), design=agents[0].design)
    assert z.tobytes() == ref.tobytes()
    with pytest.raises(Exception, match="does not support agent_slice"):  # keyed gains ship none (the agents design)
        sc.updated({"mtmse_lossy.keyed": 1, "mtmse_lossy.memory": None, "horizon": 4}).design("mtmse_lossy").agent_slice(0)


HOOK = """
import sys
if "agent" in sys.argv:  # an agent process: building the team design is an error
    import teamkf.study.scenario as S

    def _refuse(self, *a, **k):
        print("teamkf: error: this agent process built the team design", file=sys.stderr)
        raise SystemExit(3)

    S.Scenario.design = _refuse
"""


@pytest.mark.skipif(importlib.util.find_spec("zenoh") is None, reason="needs eclipse-zenoh (pip install 'teamkf[deploy]')")
def test_deploy_over_drops_ships_slices_and_filter_replays_it(tmp_path: Path) -> None:
    """teamkf deploy of ring-6-lossy (T = 8, memory = 4) with drops; agents that cannot design; filter --drops gives the same file."""
    sp = _scenario(tmp_path, 8, 4)
    sc = load_scenario(sp)
    log = tmp_path / "log.csv"
    M.write_measurements(str(log), [y[0] for y in sample_paths(sc.system, 8, 1, rng=2).y])
    hook = tmp_path / "hook"
    hook.mkdir()
    (hook / "sitecustomize.py").write_text(HOOK, encoding="utf-8")
    src = str(Path(__file__).resolve().parents[2] / "src")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(hook), src, os.environ.get("PYTHONPATH", "")])}
    out, rec, rep = tmp_path / "est.csv", tmp_path / "drops.json", tmp_path / "replay.csv"
    args = ["deploy", str(sp), "--measurements", str(log), "--out", str(out), "--estimator", "mtmse_lossy"]
    args += ["--p-drop", "0.3", "--seed", "3", "--record", str(rec), "--deadline", "10"]
    proc = subprocess.run([sys.executable, "-m", "teamkf", *args], capture_output=True, text=True, env=env, timeout=400)
    assert proc.returncode == 0, proc.stderr
    assert "designs the team" not in proc.stderr  # the agents got their slices
    assert main(["--quiet", "filter", str(sp), "--measurements", str(log), "--drops", str(rec), "--out", str(rep)]) == 0
    assert out.read_bytes() == rep.read_bytes()


# ---------------------------------------------------------------------------
# the steady form: gains frozen once they converge, later costs exact
# ---------------------------------------------------------------------------
def test_steady_form_is_causal_exact_and_its_own_monte_carlo(ring3: Any) -> None:
    """memory = 3 over T = 150 (innovation items): the gains freeze once converged (the same arrays reused), the design of a longer horizon
    has the same first stages (nothing depends on T), the frozen cost is the solved one at the freeze step, and the
    exact total is its own Monte Carlo (2000 runs with drops) within 4 standard errors."""
    sysm, cost, g = ring3
    d = design_mtmse_lossy(sysm, cost, g, 150, p_drop=0.3, memory=3, items="innovations")
    k0 = d.info["steady_from"]
    assert k0 is not None and 6 <= k0 < 100, k0
    assert all(d.gains[k][1] is d.gains[k0][1] for k in range(k0, 150)) and d.fills[149][2] is d.fills[k0][2]
    assert d.items[149][0] == tuple((j, s + 149 - k0) for j, s in d.items[k0][0])  # the frozen items, shifted
    solved, operator = d.info["steady_check"]
    assert operator == pytest.approx(solved, rel=1e-10)
    long = design_mtmse_lossy(sysm, cost, g, 300, p_drop=0.3, memory=3, items="innovations")
    np.testing.assert_allclose(long.stage_costs[:150], d.stage_costs, rtol=1e-12)
    assert long.stage_costs[299] == pytest.approx(long.stage_costs[200], rel=1e-7)  # stationary
    paths = sample_paths(sysm, 150, 2000, rng=8)
    e = d.errors(paths, p_drop=0.3, rng=9)
    c = np.einsum("rki,ij,rkj->r", e, cost.S_at(0), e)
    se = c.std(ddof=1) / np.sqrt(c.size)
    assert abs(c.mean() - d.total_cost) < 4 * se, (c.mean(), se, d.total_cost)
