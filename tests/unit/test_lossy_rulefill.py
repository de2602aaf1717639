"""``mtmse_lossy`` with ``fill = "held"``: the class containing the missed-packet rule (teamkf.estimators._lossy_rulefill)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from teamkf import CommGraph, LinearGaussianSystem, TeamCost
from teamkf.estimators._lossy_rulefill import RuleFillAgent, flood_arrivals
from teamkf.estimators.team_lossy import design_mtmse_lossy
from teamkf.exceptions import ArgumentError
from teamkf.simulation.links import LinkModel, LinkStats
from teamkf.simulation.monte_carlo import monte_carlo


def unlike(n: int) -> tuple[LinearGaussianSystem, TeamCost]:
    """Agent 0 measures x1 precisely, the others x1 + x2 poorly; everyone estimates x1 (consensus-weighted)."""
    A = np.array([[0.9, 0.3], [0.0, 0.8]])
    C = [np.array([[1.0, 0.0]])] + [np.array([[1.0, 1.0]]) for _ in range(n - 1)]
    sysm = LinearGaussianSystem(A=A, Q=0.5, Sigma_x=1.0, C=C, R=[0.02] + [3.0] * (n - 1))
    S = 2.0 * np.eye(n) - np.ones((n, n)) / n
    return sysm, TeamCost(S=S, L=np.tile([[1.0, 0.0]], (n, 1)), n_agents=n)


def _joint(sysm: LinearGaussianSystem, T: int) -> tuple[np.ndarray, list[np.ndarray]]:
    """Cov of (x(0..T-1), y(0..T-1)) built by propagating the covariance (independent of the design's code)."""
    dx, dyt = sysm.dx, sysm.dy_total
    N = T * dx + T * dyt
    P = np.zeros((N, N))
    # x(k) = A x(k-1) + w: cov(x(k), x(l)) = A^(k-l) P(l) for k >= l
    Pk = [np.asarray(sysm.Sigma_x, dtype=float)]
    for k in range(1, T):
        Pk.append(sysm.A_at(0) @ Pk[-1] @ sysm.A_at(0).T + sysm.Q_at(k - 1))
    Cx = np.zeros((T * dx, T * dx))
    for k in range(T):
        for l_ in range(k + 1):
            M = np.linalg.matrix_power(sysm.A_at(0), k - l_) @ Pk[l_]
            Cx[k * dx : (k + 1) * dx, l_ * dx : (l_ + 1) * dx] = M
            Cx[l_ * dx : (l_ + 1) * dx, k * dx : (k + 1) * dx] = M.T
    Cb = np.kron(np.eye(T), sysm.C_stack(0))
    P[: T * dx, : T * dx] = Cx
    P[T * dx :, : T * dx] = Cb @ Cx
    P[: T * dx, T * dx :] = Cx @ Cb.T
    P[T * dx :, T * dx :] = Cb @ Cx @ Cb.T + np.kron(np.eye(T), sysm.R_stack(0))
    return P, [np.arange(k * dx, (k + 1) * dx) for k in range(T)]


def _brute_cost(d, G: np.ndarray) -> float:
    """Expected cost of gains G: every edge-step pattern of the 2-agent complete graph enumerated, the online agents
    (relay, rule, features) stepped by hand on the unit vectors of y, each pattern's cost on the joint Gaussian law."""
    sysm, cost, T = d.system, d.cost, d.horizon
    n, dyt, dx = sysm.n_agents, sysm.dy_total, sysm.dx
    Ny = T * dyt
    P, xs = _joint(sysm, T)
    Syy, q = P[T * dx :, T * dx :], 1.0 - d.p_drop
    dg = dataclasses.replace(d, G=G)
    events = [(s, e) for s in range(T - 1) for e in range(2)]  # e = 0: 0 -> 1, e = 1: 1 -> 0 (delay 1)
    total = 0.0
    for code in range(1 << len(events)):
        ok = {ev: bool((code >> b) & 1) for b, ev in enumerate(events)}
        w = np.prod([q if v else 1 - q for v in ok.values()])
        agents = [RuleFillAgent(dg, i) for i in range(n)]
        states = [ag.init_state(Ny) for ag in agents]
        sent: list = [[], []]
        for k in range(T):
            zs, now = [], []
            for i, ag in enumerate(agents):
                own = np.eye(Ny)[:, k * dyt + int(sysm.offsets[i]) : k * dyt + int(sysm.offsets[i]) + sysm.dy[i]]
                j = 1 - i
                inbox = [(j, k - 1, sent[j])] if k > 0 and ok[(k - 1, j)] else []
                states[i], z, new = ag.step(states[i], k, own, inbox)
                zs.append(np.asarray(z).T)
                now.append(new)
            sent = now
            Z = np.vstack(zs)  # (n dz, Ny): ẑ(k) = Z y
            L, S = cost.L_at(k), cost.S_at(k)
            Sxy = P[np.ix_(xs[k], np.arange(T * dx, T * dx + Ny))]
            E = L @ P[np.ix_(xs[k], xs[k])] @ L.T - L @ Sxy @ Z.T - Z @ Sxy.T @ L.T + Z @ Syy @ Z.T
            total += w * float(np.trace(S @ E))
    return total


@pytest.fixture(scope="module")
def tiny():
    sysm, cost = unlike(2)
    return design_mtmse_lossy(sysm, cost, CommGraph.complete(2), 3, p_drop=0.4, fill="held")


def test_exact_cost_equals_brute_force(tiny):
    """Exact (every pattern enumerated): the design's cost = the brute-force cost of its online agents; its gains are the
    optimum of the class (no perturbation lowers the brute-force cost); the members' costs are theirs."""
    d = tiny
    assert d.info["exact"] and d.info["patterns"] == 16
    assert d.total_cost == pytest.approx(_brute_cost(d, d.G), rel=1e-9)
    rng = np.random.default_rng(0)
    for _ in range(3):
        dG = 1e-3 * rng.standard_normal(d.G.shape)
        assert _brute_cost(d, d.G + dG) >= d.total_cost - 1e-12
    mc = d.info["member_costs"]
    assert mc["today"]["cost"] == pytest.approx(d.today.total_cost, rel=1e-9)  # today's class, its own exact cost
    assert mc["local"]["cost"] == pytest.approx(d.today.info["local_kf_cost"], rel=1e-9)
    assert d.total_cost <= min(mc["rule"]["cost"], mc["today"]["cost"], mc["local"]["cost"]) + 1e-12
    assert d.total_cost < mc["rule"]["cost"] - 1e-4  # strictly better than the rule on this team


def test_rule_recovered_at_its_gains(tiny):
    """G = [0 I 0 0] is the nominal MTMSE design under the missed-packet rule: the same estimates on the lossy runtime."""
    d = tiny
    rule = dataclasses.replace(d, G=np.zeros_like(d.G))
    rule.G[:, :, :, d.system.dx : d.system.dx + d.cost.dz] = np.eye(d.cost.dz)
    links = LinkModel(p_drop=0.4)
    r = monte_carlo({"held": rule, "mtmse": d.nominal}, 3, 400, rng=3, path="runtime", graph=d.graph, links=links)
    assert r["held"].total_mean == pytest.approx(r["mtmse"].total_mean, rel=1e-10)
    assert d.info["member_costs"]["rule"]["cost"] == pytest.approx(_brute_cost(d, rule.G), rel=1e-9)


def test_monte_carlo_agrees_with_exact_cost(tiny):
    r = monte_carlo({"held": tiny}, 3, 20000, rng=7, path="runtime", graph=tiny.graph, links=LinkModel(p_drop=0.4))["held"]
    assert abs(r.total_mean - tiny.total_cost) < 4 * r.total_sem


def test_batched_runtime_equals_one_run_agents():
    """The lossy runtime's all-runs path (_run_rulefill) gives the agents' own one-run ``step`` estimates."""
    from teamkf.simulation import lossy
    from teamkf.simulation.links import link_streams
    from teamkf.simulation.sampling import sample_paths

    sysm, cost = unlike(3)
    g = CommGraph.line(3)
    d = design_mtmse_lossy(sysm, cost, g, 6, p_drop=0.5, fill="held", patterns=20)
    assert not d.info["exact"] and d.info["sem"] > 0
    lo, hi = d.info["interval"]
    assert lo < d.total_cost < hi
    paths = sample_paths(sysm, 6, 12, rng=1)
    ys = [np.asarray(y) for y in paths.y]
    links = LinkModel(p_drop=0.5)
    streams = link_streams(np.random.SeedSequence(4), 12)
    agents = d.graph_agents()
    z1 = lossy.run_lossy(agents, g, ys, links, streams, LinkStats(), design=d)
    u, jit = lossy.draw_link_events(streams, 6, len(g.edges))
    out = lossy.link_outcomes(links, sorted(g.edges), u, jit, (False,) * 3)
    z2 = lossy._run_grouped(d.graph_agents(), g, ys, out, LinkStats(), d)
    np.testing.assert_allclose(z1, z2, rtol=1e-9, atol=1e-9)


def test_flood_arrivals_matches_the_runtime_relays():
    from teamkf.simulation import lossy

    g = CommGraph.line(4)
    edges = sorted(g.edges)
    rng = np.random.default_rng(2)
    u = rng.random((50, 7, len(edges)))
    links = LinkModel(p_drop=0.4)
    out = lossy.link_outcomes(links, edges, u, np.zeros_like(u), (False,) * 4)
    np.testing.assert_array_equal(lossy.relay_arrivals(out, 4, 7, 0), flood_arrivals(edges, u < 0.4, 4, 7))


def test_refusals():
    sysm, cost = unlike(2)
    g = CommGraph.complete(2)
    with pytest.raises(ArgumentError, match="jitter"):
        design_mtmse_lossy(sysm, cost, g, 3, p_drop=0.2, jitter=1, fill="held")
    with pytest.raises(ArgumentError, match="keyed"):
        design_mtmse_lossy(sysm, cost, g, 3, p_drop=0.2, keyed=1, fill="held")
    with pytest.raises(ArgumentError, match="fill"):
        design_mtmse_lossy(sysm, cost, g, 3, p_drop=0.2, fill="sometimes")
    with pytest.raises(ArgumentError, match="patterns"):
        design_mtmse_lossy(sysm, cost, g, 3, p_drop=0.2, fill="held", patterns=1)


def test_conditional_mean_feature_conditions_the_joint_gaussian(tiny):
    """G picking L_i E[x(k) | H] (feature φ⁴): on every pattern the online agents output the conditional mean of the
    joint Gaussian law of (x, y) given the measurements they hold (own ones, and the other's that arrived by k)."""
    d = tiny
    sysm, T = d.system, d.horizon
    dx, dyt, Ny = sysm.dx, sysm.dy_total, T * sysm.dy_total
    G = np.zeros_like(d.G)
    for k in range(T):
        for i in range(2):
            G[k, i, :, dx + 2 * d.cost.dz : 2 * dx + 2 * d.cost.dz] = d.cost.L_block(i, k)  # φ⁴ = [E[x(k) | H]; ...]
    dg = dataclasses.replace(d, G=G)
    P, xs = _joint(sysm, T)
    Syy = P[T * dx :, T * dx :]
    events = [(s, e) for s in range(T - 1) for e in range(2)]
    for code in range(1 << len(events)):
        ok = {ev: bool((code >> b) & 1) for b, ev in enumerate(events)}
        agents = [RuleFillAgent(dg, i) for i in range(2)]
        states = [ag.init_state(Ny) for ag in agents]
        sent: list = [[], []]
        for k in range(T):
            now = []
            for i, ag in enumerate(agents):
                own = np.eye(Ny)[:, k * dyt + int(sysm.offsets[i]) : k * dyt + int(sysm.offsets[i]) + sysm.dy[i]]
                j = 1 - i
                inbox = [(j, k - 1, sent[j])] if k > 0 and ok[(k - 1, j)] else []
                states[i], z, new = ag.step(states[i], k, own, inbox)
                now.append(new)
                held = [s * dyt + int(sysm.offsets[i]) for s in range(k + 1)]  # d_y = 1 per agent
                held += [s * dyt + int(sysm.offsets[j]) for s in range(k) if ok[(s, j)]]
                H = np.sort(np.array(held))
                Sxh = P[np.ix_(xs[k], T * dx + H)]
                want = np.zeros((Ny, 1 * dx))
                want[H] = np.linalg.solve(Syy[np.ix_(H, H)], Sxh.T)  # E[x(k) | y_H] = Σ_xH Σ_HH⁻¹ y_H
                np.testing.assert_allclose(np.asarray(z), want @ d.cost.L_block(i, k).T, atol=1e-10)
            sent = now


def _held_scenario_text() -> str:
    """The held-out complete-3 scenario with ``fill = "held"`` in its ``[mtmse_lossy]`` table (the file sets the adaptive class)."""
    from pathlib import Path

    src = (Path(__file__).parents[2] / "examples" / "scenarios" / "lossy-complete-3-unlike.toml").read_text(encoding="utf-8")
    assert "resend = 3" in src and "adaptive = true" in src
    return src.replace("resend = 3", "resend = 1").replace("adaptive = true", 'fill = "held"')


def test_a_scenario_table_jitter_is_designed_for_and_refused_for_held(tmp_path):
    """``[mtmse_lossy] jitter`` in a scenario is the jitter designed for (the [network] table's applies only when the family's
    own table does not set it), so fill = "held" refuses it in one line instead of designing silently for no jitter."""

    from teamkf.study.scenario import load_scenario

    src = _held_scenario_text()
    held = tmp_path / "held.toml"
    held.write_text(src.replace('fill = "held"', 'fill = "held"\njitter = 1'), encoding="utf-8")
    with pytest.raises(ArgumentError, match="'held' supports links without jitter, found jitter = 1"):
        load_scenario(held).design("mtmse_lossy")
    plain = tmp_path / "plain.toml"
    plain.write_text(src.replace('fill = "held"', "jitter = 1"), encoding="utf-8")
    d = load_scenario(plain).design("mtmse_lossy")
    assert d.jitter == 1 and d.p_drop == 0.3  # the table's jitter, the [network] drop probability


def test_held_window_is_a_scenario_option(tmp_path):
    """``[mtmse_lossy] held_window = W`` sets the window of the conditional-mean feature; without fill = "held" it is refused."""

    from teamkf.study.scenario import load_scenario

    src = _held_scenario_text()
    sp = tmp_path / "w.toml"
    sp.write_text(
        src.replace('fill = "held"', 'fill = "held"\nheld_window = 1\npatterns = 20').replace("horizon = 12", "horizon = 5"), encoding="utf-8"
    )
    assert load_scenario(sp).design("mtmse_lossy").window == 1
    sp.write_text(src.replace('fill = "held"', "held_window = 3"), encoding="utf-8")
    with pytest.raises(ArgumentError, match='held_window: the window of fill = "held"'):
        load_scenario(sp).design("mtmse_lossy")
