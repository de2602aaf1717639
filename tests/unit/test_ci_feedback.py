"""The CI diffusion (``ci`` with ``feedback=True``) and the leaderboard's "why diverging" column.

Independent checks: a plain-numpy implementation of the feedback filter (own Kalman update, CI of the
delay-compensated estimates received, the fused estimate and its CI covariance as the next prior) gives the
design's estimates; the design's exact cost agrees with a Monte Carlo of the errors (95 % intervals per step
and in total); its ideal variant is not realizable; with every packet lost each agent is its own Kalman filter;
the option is validated; the ci grid holds it; the "why" of a diverging row names the undetecting agents (PBH
test, closed-form cases).
"""

from __future__ import annotations

import numpy as np
import pytest

from teamkf import CommGraph, LinearGaussianSystem, TeamCost
from teamkf.estimators._consensus_common import ci_weights
from teamkf.estimators.checks import detects, undetecting_agents
from teamkf.estimators.ci import design_ci
from teamkf.exceptions import ArgumentError
from teamkf.experiments.divergence import why_diverging
from teamkf.experiments.tuning import GRIDS, candidates
from teamkf.simulation.sampling import sample_paths

T = 10


@pytest.fixture(scope="module")
def small():
    """3 agents, 2-dim slightly unstable process, scalar measurements, delays 1 and 2 (a directed cycle plus one edge)."""
    A = np.array([[1.02, 0.1], [0.0, 0.97]])
    system = LinearGaussianSystem(
        A=A,
        Q=np.array([[0.2, 0.05], [0.05, 0.1]]),
        Sigma_x=np.eye(2),
        C=[np.array([[1.0, 0.0]]), np.array([[0.0, 1.0]]), np.array([[1.0, 1.0]])],
        R=0.5,
    )
    graph = CommGraph(3, ((0, 1, 1), (1, 2, 2), (2, 0, 1), (1, 0, 1)))
    return system, TeamCost.mse(3, 2), graph


def reference_filter(system, graph, y, honest=True):
    """CI diffusion in plain numpy, every run at once: returns x̂_i(k) as (n_runs, T, n, dx)."""
    n, dx = system.n_agents, system.dx
    A, Q = system.A_at(0), system.Q_at(0)
    n_runs, steps = y[0].shape[:2]
    xhat = np.zeros((n_runs, n, dx))
    P = [system.Sigma_x.copy() for _ in range(n)]
    psi_hist, Pk_hist = {}, {}
    out = np.empty((n_runs, steps, n, dx))
    for k in range(steps):
        for i in range(n):
            xbar = np.zeros((n_runs, dx)) if k == 0 else xhat[:, i] @ A.T
            C, R = system.C_at(i, k), system.R_at(i, k)
            K = P[i] @ C.T @ np.linalg.inv(C @ P[i] @ C.T + R)
            psi_hist[(i, k)] = xbar + (y[i][:, k] - xbar @ C.T) @ K.T
            IKC = np.eye(dx) - K @ C
            Pk_hist[(i, k)] = IKC @ P[i] @ IKC.T + K @ R @ K.T
        new = np.empty_like(xhat)
        for i in range(n):
            items = [(psi_hist[(i, k)], Pk_hist[(i, k)])]
            for j in graph.in_neighbors(i):
                s = k - graph.delay(j, i) if honest else k
                if s < 0:
                    continue
                Phi, Qs = np.eye(dx), np.zeros((dx, dx))
                for _ in range(k - s):
                    Phi, Qs = A @ Phi, A @ Qs @ A.T + Q
                items.append((psi_hist[(j, s)] @ Phi.T, Phi @ Pk_hist[(j, s)] @ Phi.T + Qs))
            infos = [np.linalg.inv(Pm) for _, Pm in items]
            w = ci_weights(infos)
            Pf = np.linalg.inv(sum(wj * Y for wj, Y in zip(w, infos)))
            new[:, i] = sum((x @ (wj * Pf @ Y).T) for (x, _), wj, Y in zip(items, w, infos))
            P[i] = A @ Pf @ A.T + Q
        xhat = new
        out[:, k] = xhat
    return out


def test_feedback_design_is_the_plain_ci_diffusion_filter(small):
    system, cost, graph = small
    p = sample_paths(system, T, 5, rng=3)
    for honest in (True, False):
        d = design_ci(system, cost, graph, T, variant="honest" if honest else "ideal", feedback=True)
        ref = reference_filter(system, graph, p.y, honest).reshape(5, T, -1)
        np.testing.assert_allclose(d.filter(p.y), ref, rtol=1e-9, atol=1e-9)
        assert d.realizable is honest  # the ideal variant fuses the neighbours' current estimates: not on a delay graph
    # and the feedback changes the published form's estimates (which does not feed the fusion back)
    pub = design_ci(system, cost, graph, T).filter(p.y)
    assert np.max(np.abs(pub - design_ci(system, cost, graph, T, feedback=True).filter(p.y))) > 1e-3


def test_feedback_exact_cost_matches_monte_carlo(small):
    system, cost, graph = small
    d = design_ci(system, cost, graph, T, feedback=True)
    runs = 20000
    p = sample_paths(system, T, runs, rng=17)
    e = d.errors(p)  # (runs, T, n dx): L x - ẑ, from the primitive noises
    c = np.stack([np.einsum("rj,jk,rk->r", e[:, k], cost.S_at(k), e[:, k]) for k in range(T)], axis=1)
    mean, sem = c.mean(axis=0), c.std(axis=0, ddof=1) / np.sqrt(runs)
    z = (mean - d.stage_costs) / sem
    assert np.max(np.abs(z)) < 4.0, z
    tot = c.sum(axis=1)
    assert abs(tot.mean() - np.sum(d.stage_costs)) < 1.96 * tot.std(ddof=1) / np.sqrt(runs) * 2.0
    # the same Monte Carlo through the independent filter: its errors are the design's
    x = np.asarray(p.x)
    ref = reference_filter(system, graph, [yi[:200] for yi in p.y])
    e_ref = (x[:200, :, None, :] - ref).reshape(200, T, -1)
    np.testing.assert_allclose(e_ref, e[:200], rtol=1e-8, atol=1e-8)


def test_feedback_with_every_packet_lost_is_each_agents_kalman_filter(small):
    from teamkf.simulation.links import LinkModel
    from teamkf.simulation.runtime import graph_agents, run_graph

    system, cost, graph = small
    d = design_ci(system, cost, graph, T, feedback=True)
    assert d.tolerates_losses
    p = sample_paths(system, T, 3, rng=9)
    z = run_graph(graph_agents(d), graph, p.y, links=LinkModel(p_drop=1.0), rng=0)
    edgeless = CommGraph(3, ())
    ref = design_ci(system, cost, edgeless, T, feedback=True).filter(p.y)  # no neighbour: the own Kalman filter
    np.testing.assert_allclose(z, ref, rtol=1e-8, atol=1e-8)
    loc = design_ci(system, cost, edgeless, T).filter(p.y)  # the published form's local filters, the same
    np.testing.assert_allclose(ref, loc, rtol=1e-8, atol=1e-8)
    # nothing lost: the runtime's agents are the design's filter, and the tolerant step is the nominal one bit for bit
    from teamkf.simulation.links import link_streams, pass_messages_lossy
    from teamkf.simulation.online import _batched

    ref = run_graph(graph_agents(d), graph, p.y)
    np.testing.assert_allclose(ref, d.filter(p.y), rtol=1e-9, atol=1e-9)
    ys = _batched([getattr(a, "inner", a) for a in graph_agents(d)], p.y)
    got = pass_messages_lossy(graph_agents(d), graph, ys, LinkModel(), link_streams(0, 3))  # tolerant mode, nothing lost
    for r in range(3):
        np.testing.assert_array_equal(got[r : r + 1], run_graph(graph_agents(d), graph, [y[r : r + 1] for y in p.y]))
    # some packets lost or late: finite, and each agent's estimate is no worse than its own filter's on average (CI is consistent)
    zl = run_graph(graph_agents(d), graph, p.y, links=LinkModel(p_drop=0.4, jitter=1), rng=2)
    assert np.all(np.isfinite(zl)) and np.max(np.abs(zl - ref)) > 0


def test_feedback_option_is_validated_and_in_the_ci_grid(small):
    system, cost, graph = small
    for bad in ("yes", 1, None):
        with pytest.raises(ArgumentError, match=r"ci\.feedback: expected a bool"):
            design_ci(system, cost, graph, T, feedback=bad)
    assert {"feedback": True} in GRIDS["ci"]
    assert candidates("ci", graph) == [{}, {"feedback": True}]


def test_detectability_helper_closed_forms():
    # x = (unstable 1.1, stable 0.5, marginal 1.0): agent 0 sees mode 0 only, agent 1 modes 1 and 2, agent 2 modes 0 and 2
    A = np.diag([1.1, 0.5, 1.0])
    C = [np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 1.0]]), np.array([[1.0, 0.0, 1.0]])]
    system = LinearGaussianSystem(A=A, Q=0.1, Sigma_x=1.0, C=C, R=1.0)
    assert [detects(system, [i]) for i in range(3)] == [False, False, True]
    assert detects(system, [0, 1]) is True
    assert undetecting_agents(system) == [0, 1]
    assert undetecting_agents(system, [[0, 1], [1], [2]]) == [1]


def test_why_text_on_a_tiny_undetectable_network():
    # modes 1.1 and 1.05; agents 0 and 1 see the first, agent 2 the second; the line 0 - 1 - 2
    A = np.diag([1.1, 1.05])
    C = [np.array([[1.0, 0.0]]), np.array([[1.0, 0.0]]), np.array([[0.0, 1.0]])]
    system = LinearGaussianSystem(A=A, Q=0.1, Sigma_x=1.0, C=C, R=1.0)
    cost, graph = TeamCost.mse(3, 2), CommGraph.line(3)
    from teamkf.experiments.tuning import diverging

    assert diverging(teamkf_local(system, cost, graph, 60).stage_costs)
    why = why_diverging("local", {"variant": "honest"}, system, graph, cost=cost)
    assert why.startswith("structural: no filter using only its own measurements converges for all 3 agents: their C_i cannot detect")
    assert "the modes λ = 1.1, 1.05 (unstable; excited by the process noise), which their cost (L_i) weighs" in why
    # published ci: agents 1 and 2 have a jointly detecting in-neighbourhood, agent 0 ({0, 1}: the first mode only) has not
    assert diverging(design_ci(system, cost, graph, 60).stage_costs)
    why = why_diverging("ci", {"variant": "honest"}, system, graph, cost=cost)
    assert why.startswith("structural: the published CI fuses local Kalman filters that do not converge")
    assert (
        "do not force the cost to grow for agents 1, 2 (2 of 3), not for agents 0 (1 of 3), whose in-neighbourhood cannot detect the mode λ = 1.05"
        in why
    )
    # feedback on a one-way chain 0 -> 1 -> 2: nothing reaches agent 0 but its own data
    chain = CommGraph(3, ((0, 1, 1), (1, 2, 1)))
    why = why_diverging("ci", {"variant": "honest", "feedback": True}, system, chain, cost=cost)
    assert why.startswith("structural: the measurements that can reach agents 0, 1 (2 of 3) over the graph do not keep their cost bounded")
    # on the line every agent's reachable data detect x: a parametric reason, naming the tuned row
    why = why_diverging("kcf", {"variant": "honest"}, system, graph, tuned=("epsilon=0.003", False))
    assert why.startswith("parametric: published parameters on this delay graph") and "the tuned row (epsilon=0.003) does not diverge" in why
    why = why_diverging("ci", {"variant": "ideal", "feedback": True}, system, graph, tuned=None)
    assert why.startswith("parametric: parameters feedback=True with exchanges inside the step") and why.endswith("the family has no tuned row")


def teamkf_local(system, cost, graph, horizon):
    from teamkf.estimators.local import design_local

    return design_local(system, cost, graph, horizon)
