"""``mtmse_lossy`` with ``adaptive = true``: the smoother against direct conditioning of the joint Gaussian, the class
against the re-sending design it contains, Monte Carlo of its errors and of its runtime agents, refusals."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from teamkf import CommGraph, LinearGaussianSystem, TeamCost
from teamkf.estimators import _lossy_adaptive as LA
from teamkf.estimators._lossy_rulefill import _joint
from teamkf.estimators.registry import get_family
from teamkf.estimators.team import design_mtmse
from teamkf.estimators.team_lossy import design_mtmse_lossy
from teamkf.exceptions import ArgumentError, ResourceError

from ..helpers import assert_deploy_replays, assert_lossy_agents_match, assert_lossy_mc_matches_exact

T = 8


def unlike_line(n: int = 3) -> tuple[LinearGaussianSystem, TeamCost]:
    """A line of agents that all estimate x₁; agent 0 measures it precisely, the others poorly (unlike sensors)."""
    A = np.array([[0.95, 0.2], [0.0, 0.9]])
    C = [np.array([[1.0, 0.0]]), np.array([[1.0, 0.5]]), np.array([[0.0, 1.0]])][:n]
    sysm = LinearGaussianSystem(A=A, Q=0.5, Sigma_x=1.0, C=C, R=[0.01] + [4.0] * (n - 1))
    S = 2 * np.eye(n) - np.ones((n, n)) / n
    return sysm, TeamCost(S=S, L=np.tile([[1.0, 0.0]], (n, 1)), n_agents=n)


@pytest.fixture(scope="module")
def team():
    sysm, cost = unlike_line()
    g = CommGraph.line(3)
    d = design_mtmse_lossy(sysm, cost, g, T, p_drop=0.5, items="measurements", resend=2, adaptive=True, patterns=60, bound=False)
    return sysm, cost, g, d


def test_the_smoother_is_the_exact_conditional_mean_given_what_is_held(team):
    """E[x(k - D : k) | H] of every agent and step, for sampled patterns, against Σ_xH Σ_HH⁻¹ of the joint law of (x, y)."""
    sysm, _, _, d = team
    Syy, Sxy, _ = _joint(sysm, T)
    dyt, off, dx = sysm.dy_total, sysm.offsets, sysm.dx
    av = LA.available_steps(d.arrivals.sample(5, T, np.random.default_rng(7)), np.asarray(d.arrivals.ell), d.resend)
    Ny = T * dyt
    for i in range(3):
        unit = lambda j, s, rows: np.eye(Ny)[None, s * dyt + int(off[j]) : s * dyt + int(off[j]) + sysm.dy[j]]  # noqa: E731
        for k, phi in enumerate(d.smoothed(i, av[:, i], unit, Ny)):
            for b in range(av.shape[0]):
                H = [s * dyt + int(off[j]) + c for s in range(k + 1) for j in range(3) if av[b, i, j, s] <= k for c in range(sysm.dy[j])]
                for lag in range(d.D + 1):
                    want = np.zeros((dx, Ny))
                    if k - lag >= 0:
                        want[:, H] = np.linalg.solve(Syy[np.ix_(H, H)], Sxy[k - lag][:, H].T).T
                    np.testing.assert_allclose(phi[b, lag * dx : (lag + 1) * dx], want, atol=1e-9)
    assert d.D == int(np.max(d.arrivals.ell)) + d.resend - 1 and d.lags == int(np.max(d.arrivals.ell))


def test_the_class_contains_the_re_sending_design_and_reports_a_paired_cost(team):
    sysm, cost, g, d = team
    rd = design_mtmse_lossy(sysm, cost, g, T, p_drop=0.5, items="measurements", resend=2, bound=False)
    info = d.info
    assert info["resend_cost"] == pytest.approx(rd.total_cost, rel=1e-12)
    assert d.total_cost == pytest.approx(rd.total_cost + info["paired"]["diff"], rel=1e-12)
    assert info["kept"] == "class" and info["paired"]["diff"] < -4 * info["paired"]["sem"] < 0  # it re-weights: it pays
    lo, hi = info["interval"]
    assert lo < d.total_cost < hi and hi - lo == pytest.approx(2 * 1.96 * info["paired"]["sem"])
    s = info["resend_cost_sampled"]  # the re-sending design's cost over the fresh patterns agrees with its exact value
    assert abs(s["cost"] - rd.total_cost) < 4 * s["sem"]
    # at p = 0 every pattern is the full one: nothing to re-weight, the class is MTMSE
    d0 = design_mtmse_lossy(sysm, cost, g, T, p_drop=0.0, items="measurements", resend=2, adaptive=True, patterns=4, bound=False)
    assert d0.total_cost == pytest.approx(design_mtmse(sysm, cost, g, T).total_cost, rel=1e-8)


def test_monte_carlo_of_its_errors_agrees_with_its_cost(team):
    sysm, cost, _, d = team
    assert_lossy_mc_matches_exact(d, sysm, cost, T, 0.5)


def test_graph_agents_reproduce_errors_and_run_over_drops(team):
    sysm, cost, g, d = team
    assert_lossy_agents_match(d, sysm, cost, g, T, 0.5)


def test_refusals_and_registry(team):
    sysm, cost, g, d = team
    with pytest.raises(ArgumentError, match="adaptive"):
        design_mtmse_lossy(sysm, cost, g, 4, p_drop=0.3, items="innovations", resend=2, adaptive=True, patterns=4)
    with pytest.raises(ArgumentError, match="adaptive"):
        design_mtmse_lossy(sysm, cost, g, 4, p_drop=0.3, items="measurements", fill="held", adaptive=True, patterns=4)
    with pytest.raises(ResourceError, match="patterns"):  # sized before any pattern is drawn
        design_mtmse_lossy(sysm, cost, g, 4, p_drop=0.3, items="measurements", resend=2, adaptive=True, patterns=10**10)
    for bad in ("yes", 1, None):
        with pytest.raises(ArgumentError, match="adaptive"):
            design_mtmse_lossy(sysm, cost, g, 4, p_drop=0.3, items="measurements", adaptive=bad)
    opts = {"p_drop": 0.3, "resend": 2, "adaptive": True, "items": "measurements", "patterns": 4}
    b = get_family("mtmse_lossy").build(sysm, cost, graph=g, structure=g, horizon=4, options=opts)
    assert b.details()["adaptive"] is True and b.arrays()["G"].shape[:3] == (4, 3, 1)


def test_evaluate_prints_its_sampled_cost_with_its_interval(tmp_path):
    """``teamkf evaluate`` on a scenario with ``adaptive = true``: the row carries the interval of its sampled cost."""
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    text = (root / "examples" / "scenarios" / "platoon-4-lossy.toml").read_text()
    text = (
        text.replace("horizon = 50", "horizon = 6").replace("known_bound = 50", "known_bound = 0").replace("resend = 4", "resend = 2\npatterns = 30")
    )
    assert "adaptive = true" in text
    (tmp_path / "s.toml").write_text(text)
    env = {**os.environ, "PYTHONPATH": str(root / "src"), "TEAMKF_PROGRESS": "0"}
    out = subprocess.run(
        [sys.executable, "-m", "teamkf", "evaluate", str(tmp_path / "s.toml"), "--json", "--quiet"],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    assert out.returncode == 0, out.stderr
    row = json.loads(out.stdout)["estimators"]["mtmse_lossy"]
    assert row["cost_links"] == "lossy" and row["ci95"][0] < row["total_cost"] < row["ci95"][1]
    text = subprocess.run(
        [sys.executable, "-m", "teamkf", "evaluate", str(tmp_path / "s.toml")], capture_output=True, text=True, env=env, timeout=300
    )
    assert "mtmse_lossy: an estimate of its expected cost (the re-sending design's exact" in text.stdout  # marked, with its interval


def test_deployed_slices_rebuild_the_adaptive_agents_bit_for_bit(team) -> None:
    """``teamkf deploy`` ships slices: agent i rebuilt from its slice (no team design) is the adaptive agent and gives the
    design's own agents' numbers bit for bit over the same lossy links."""
    from teamkf.estimators._slices import SliceContext, agent_from_slice
    from teamkf.simulation import lossy
    from teamkf.simulation.links import LinkModel, LinkStats, link_streams
    from teamkf.simulation.sampling import sample_paths

    sysm, cost, g, d = team
    ctx = SliceContext(sysm, cost, g, None, T)
    agents = []
    for i in range(3):
        kind, arrays, meta = d.agent_slice(i)
        assert meta["adaptive"] and meta["resend"] == 2
        agents.append(agent_from_slice(kind, ctx, i, arrays, meta)[1])
    assert type(agents[0]) is type(d.graph_agents()[0])
    ys = list(sample_paths(sysm, T, 3, rng=1).y)
    u, jit = lossy.draw_link_events(link_streams(2, 3), T, len(g.edges))
    out = lossy.link_outcomes(LinkModel(p_drop=0.5), sorted(g.edges), u, jit, (False,) * 3)
    ref = lossy._run_grouped(d.graph_agents(), g, ys, out, LinkStats(), d)
    got = lossy._run_grouped(agents, g, ys, out, LinkStats(), agents[0].design)
    assert got.tobytes() == ref.tobytes()
    rd = design_mtmse_lossy(sysm, cost, g, T, p_drop=0.5, items="measurements", resend=2, bound=False)
    other = lossy._run_grouped(rd.graph_agents(), g, ys, out, LinkStats(), rd)
    assert not np.allclose(other, got)  # not the re-sending agent's estimates


@pytest.mark.parametrize("jitter", [0, 1])
def test_the_batched_runtime_gives_the_agents_own_numbers(jitter) -> None:
    """The lossy runtime steps every run at once (:meth:`AdaptiveLossyDesign.estimates` on the on-time events read off the
    link outcomes); the agents' own one-run steps on the same link events give the same numbers (late packets ignored)."""
    from teamkf.simulation import lossy
    from teamkf.simulation.links import LinkModel, LinkStats, link_streams
    from teamkf.simulation.sampling import sample_paths

    sysm, cost = unlike_line()
    g = CommGraph.complete(3, delay=1)  # a relayed copy (two hops) is late: ignored
    d = design_mtmse_lossy(sysm, cost, g, T, p_drop=0.4, jitter=jitter, items="measurements", resend=2, adaptive=True, patterns=30, bound=False)
    ys = list(sample_paths(sysm, T, 40, rng=2).y)
    u, jit = lossy.draw_link_events(link_streams(3, 40), T, len(g.edges))
    out = lossy.link_outcomes(LinkModel(p_drop=0.4, jitter=jitter), sorted(g.edges), u, jit, (False,) * 3)
    agents = d.graph_agents()
    assert lossy._is_adaptive(agents)
    ref = lossy._run_grouped(agents, g, ys, out, LinkStats(), d)
    got = type(agents[0]).run_batched(agents, ys, out)
    np.testing.assert_allclose(got, ref, rtol=1e-10, atol=1e-10)


@pytest.mark.skipif(importlib.util.find_spec("zenoh") is None, reason="needs eclipse-zenoh (pip install 'teamkf[deploy]')")
def test_deploy_ships_adaptive_slices_and_filter_replays_it(tmp_path) -> None:
    """``teamkf deploy`` of the adaptive class over drops: agent processes that cannot design (they get slices), and
    ``teamkf filter --drops`` of the recorded drops gives the same file byte for byte."""
    from pathlib import Path

    from teamkf.study.scenario import load_scenario

    from ..unit.test_lossy_long import HOOK

    root = Path(__file__).resolve().parents[2]
    src = (root / "examples" / "scenarios" / "lossy-complete-3-unlike.toml").read_text(encoding="utf-8")
    sp = tmp_path / "s.toml"
    sp.write_text(src.replace("adaptive = true", "adaptive = true\npatterns = 30").replace("horizon = 12", "horizon = 8"), encoding="utf-8")
    assert load_scenario(sp).design("mtmse_lossy").info["kept"] == "class"  # the adaptive agents are deployed (p = 0.3, as below)
    assert_deploy_replays(tmp_path, sp, HOOK)


def test_the_design_has_the_same_bits_whatever_blas_threads_the_caller_set(team) -> None:
    """A deployment's slices and its replay are designed in different processes: the fit runs on ``threads`` BLAS threads
    (default 1) whatever the caller's setting, so the gains are the same bits."""
    from teamkf._blas import blas_threads

    sysm, cost, g, d = team
    with blas_threads(2):
        d2 = design_mtmse_lossy(sysm, cost, g, T, p_drop=0.5, items="measurements", resend=2, adaptive=True, patterns=60, bound=False)
    assert np.asarray(d2.G).tobytes() == np.asarray(d.G).tobytes() and d2.total_cost == d.total_cost
