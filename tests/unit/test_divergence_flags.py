"""The leaderboard's "diverging by a theorem" flag (teamkf.experiments.divergence.forced) against the actual filter.

A row is forced to diverge only where, for some agent, a mode of modulus >= 1 is undetectable from its data, excited
(by the noise; by Sigma_x when unstable or in a Jordan block) and weighed by its cost rows L_i. Each case is
checked against the exact stage costs of teamkf's local Kalman filters (the independent check): bounded where the
flag is off, growing (at the predicted rate) where it is on. Two-agent systems, d_z = 1 unless stated: agent i
estimates L_i x, S = I.
"""

from __future__ import annotations

import numpy as np
import pytest

from teamkf import CommGraph, LinearGaussianSystem, TeamCost
from teamkf.estimators.checks import detects, forced_growth
from teamkf.estimators.local import design_local
from teamkf.experiments.divergence import forced, why_diverging
from teamkf.experiments.tuning import diverging

GRAPH = CommGraph.line(2)


def _cost(*rows: list[float]) -> TeamCost:
    """Agent i estimates rows[i] @ x (d_z = 1), S = I."""
    return TeamCost(S=np.eye(len(rows)), L=np.array(rows, dtype=float), n_agents=len(rows))


def _stage(system: LinearGaussianSystem, cost: TeamCost, T: int) -> np.ndarray:
    return np.asarray(design_local(system, cost, GRAPH, T).stage_costs, dtype=float)


def _bounded(sc: np.ndarray) -> bool:
    """Not growing: no stage cost of the second half exceeds the one at T/2 by more than 0.1 %."""
    h = sc[len(sc) // 2 :]
    return bool(np.max(h) <= (1.0 + 1e-3) * h[0])


def _old_forced(system: LinearGaussianSystem) -> bool:
    """The rule this replaces: some agent's own data do not detect x and Q > 0."""
    q_pd = np.linalg.eigvalsh(system.Q_at(0))[0] > 0.0
    return bool(q_pd and any(detects(system, [i]) is False for i in range(system.n_agents)))


def test_counterexample_undetected_mode_not_weighed_is_not_flagged_and_stays_bounded():
    """Two random walks; agent i measures x_i and estimates x_i only. Agent 0 cannot detect x_1, but its cost does not
    weigh it: nothing forces a growth, and the local filters' stage cost settles (2 (√5 - 1)/2 = 1.236) for 400 steps."""
    system = LinearGaussianSystem(A=np.eye(2), Q=1.0, Sigma_x=1.0, C=[np.array([[1.0, 0.0]]), np.array([[0.0, 1.0]])], R=1.0)
    cost = _cost([1.0, 0.0], [0.0, 1.0])
    assert _old_forced(system)  # the old flag said "by a theorem"
    assert not forced("local", {}, system, GRAPH, cost)
    sc = _stage(system, cost, 400)
    assert _bounded(sc) and sc[-1] == pytest.approx(np.sqrt(5.0) - 1.0, rel=1e-9) and not diverging(sc)
    from teamkf.experiments.leaderboard import _explain

    row = _explain({"stage_costs": list(sc[:40])}, "local", {}, system, GRAPH, None, cost)
    assert row["why diverging"] is None
    # the same system with the team-MSE cost (every agent weighs all of x) is forced: each misses a weighed random walk
    assert forced("local", {}, system, GRAPH, TeamCost.mse(2, 2))
    assert not _bounded(_stage(system, TeamCost.mse(2, 2), 40))


def test_counterexample_random_walk_with_singular_q_is_flagged_and_grows_linearly():
    """x = (random walk, stable 0.5) with Q = diag(1, 0); agent 0 measures the stable state only and (team MSE) weighs
    the random walk: forced by the noise, its stage cost grows by q = 1 a step (about 400 at T = 400)."""
    system = LinearGaussianSystem(
        A=np.diag([1.0, 0.5]), Q=np.diag([1.0, 0.0]), Sigma_x=1.0, C=[np.array([[0.0, 1.0]]), np.array([[1.0, 0.0]])], R=1.0
    )
    cost = TeamCost.mse(2, 2)
    assert not _old_forced(system)  # Q singular: the old flag said nothing
    assert forced("local", {}, system, GRAPH, cost)
    [f0, f1] = forced_growth(system, cost) or []
    assert f0.by_noise == (1.0,) and f0.by_initial == () and not f1.forced
    sc = _stage(system, cost, 400)
    assert np.diff(sc[200:]) == pytest.approx(np.ones(199), rel=1e-6)  # linear: + q per step
    assert 400.0 <= sc[-1] <= 402.0
    old_numeric = bool(np.min(sc[-3:]) > 1.5 * sc[300])
    assert not old_numeric and diverging(sc)  # the ratio test misses it; the sustained-growth rule catches it
    why = why_diverging("local", {}, system, GRAPH, cost=cost)
    assert why.startswith("structural: no filter using only its own measurements converges for agents 0 (1 of 2)")
    assert "their C_i cannot detect the mode λ = 1 (marginal; excited by the process noise), which their cost (L_i) weighs" in why
    from teamkf.experiments.leaderboard import _explain

    row = _explain({"stage_costs": list(sc[:40])}, "local", {}, system, GRAPH, None, cost)  # at T = 40 the numbers show it
    assert row["why diverging"].startswith("structural") and "by the divergence theorem" not in row["why diverging"]
    row = _explain({"stage_costs": list(sc[:12])}, "local", {}, system, GRAPH, None, cost)  # at T = 12 only the theorem does
    assert not diverging(sc[:12]) and row["why diverging"].endswith(
        "(by the divergence theorem: the cost grows without bound, slowly on this horizon)"
    )


JORDAN = np.array([[1.0, 1.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.5]])
#: agent 0 measures the stable third state only; agent 1 measures x_1, which detects the Jordan chain
C_JORDAN = [np.array([[0.0, 0.0, 1.0]]), np.array([[1.0, 0.0, 0.0]])]


@pytest.mark.parametrize(
    ("Q", "Sigma", "row0", "expect", "growth"),
    [
        # x_2(0) = 0 known (Sigma_x), noise on x_1 (the chain's top; the left eigenvector e_2 sees no noise):
        # x_1 is a random walk, linear growth
        (np.diag([1.0, 0.0, 0.0]), np.diag([1.0, 0.0, 1.0]), [1.0, 0.0, 0.0], "noise", 1),
        # the same noise, agent 0 weighs x_2 only (a constant): nothing forced, bounded
        (np.diag([1.0, 0.0, 0.0]), np.diag([1.0, 0.0, 1.0]), [0.0, 1.0, 0.0], None, 0),
        # noise on x_2 (the chain's bottom): x_1 integrates a random walk, cubic growth
        (np.diag([0.0, 1.0, 0.0]), np.diag([1.0, 0.0, 1.0]), [1.0, 0.0, 0.0], "noise", 3),
        # no noise: x_1(t) = x_1(0) + t x_2(0), the Jordan block grows from Sigma_x alone (quadratic)
        (np.zeros((3, 3)), 1.0, [1.0, 0.0, 0.0], "initial", 2),
        (np.zeros((3, 3)), 1.0, [0.0, 1.0, 0.0], None, 0),
    ],
)
def test_jordan_block_on_the_unit_circle(Q, Sigma, row0, expect, growth):
    system = LinearGaussianSystem(A=JORDAN, Q=Q, Sigma_x=Sigma, C=C_JORDAN, R=1.0)
    cost = _cost(row0, [1.0, 0.0, 0.0])
    [f0, f1] = forced_growth(system, cost) or []
    assert f0.undetected == (1.0,) and not f1.forced  # agent 1 detects the chain, agent 0 none of it
    assert forced("local", {}, system, GRAPH, cost) is (expect is not None)
    assert bool(f0.by_noise) is (expect == "noise") and bool(f0.by_initial) is (expect == "initial")
    sc = _stage(system, cost, 200)
    if growth == 0:
        assert _bounded(sc)
    else:  # polynomial growth of the predicted degree: sc(2t) / sc(t) -> 2^degree
        assert sc[199] / sc[99] == pytest.approx(2.0**growth, rel=0.05)


def test_repeated_eigenvalue_weighed_or_not():
    """A = I (a double eigenvalue 1, not a Jordan block): agent 0 measures x_1 + x_2, so x_1 - x_2 is undetected.
    Weighing only x_1 + x_2 it is not forced (bounded); weighing x_1 it is (linear growth, 1/2 per step)."""
    system = LinearGaussianSystem(A=np.eye(2), Q=1.0, Sigma_x=1.0, C=[np.array([[1.0, 1.0]]), np.array([[1.0, 0.0], [0.0, 1.0]])], R=1.0)
    sums = _cost([1.0, 1.0], [1.0, 0.0])
    assert not forced("local", {}, system, GRAPH, sums) and _bounded(_stage(system, sums, 200))
    first = _cost([1.0, 0.0], [1.0, 0.0])
    assert forced("local", {}, system, GRAPH, first)
    sc = _stage(system, first, 200)
    assert np.diff(sc[100:]) == pytest.approx(np.full(99, 0.5), rel=1e-6)  # Var of (x_1 - x_2)/2 grows by 2/4 a step


@pytest.mark.parametrize(
    ("lam", "Sigma", "expect"),
    [
        (1.05, np.eye(2), "initial"),  # unstable, no noise on it, uncertain start: grows as 1.05^(2t)
        (1.0, np.eye(2), None),  # marginal, no noise: its error stays at its initial variance
        (1.05, np.diag([0.0, 1.0]), None),  # unstable but known to start at 0 and never excited: x_1 = 0
    ],
)
def test_initial_uncertainty_alone(lam, Sigma, expect):
    """x = (mode lam, stable 0.5), noise on the stable state only; agent 0 measures the stable state, weighs both."""
    system = LinearGaussianSystem(
        A=np.diag([lam, 0.5]), Q=np.diag([0.0, 1.0]), Sigma_x=Sigma, C=[np.array([[0.0, 1.0]]), np.array([[1.0, 0.0]])], R=1.0
    )
    cost = TeamCost.mse(2, 2)
    assert forced("local", {}, system, GRAPH, cost) is (expect is not None)
    [f0, _] = forced_growth(system, cost) or []
    assert f0.by_noise == () and bool(f0.by_initial) is (expect == "initial")
    sc = _stage(system, cost, 200)
    if expect:
        assert sc[199] / sc[198] == pytest.approx(lam**2, rel=1e-6) and diverging(sc)
        assert "excited by the initial uncertainty Sigma_x" in why_diverging("local", {}, system, GRAPH, cost=cost)
    else:
        assert _bounded(sc) and not diverging(sc)
        why = why_diverging("local", {}, system, GRAPH, cost=cost)
        assert why.startswith("undetectable: the data that can reach agents 0 (1 of 2) do not detect the mode λ =")


def test_numeric_rule_sustained_growth():
    t = np.arange(400, dtype=float)
    assert diverging(5.0 + t) and diverging(5.0 + t[:40]) and diverging(1.01**t)
    assert not diverging(10.0 - 0.9**t) and not diverging(np.full(40, 3.0)) and not diverging(2.0 + 0.5 ** t[:40])
    assert not diverging(1.0 + t[:8])  # below 16 steps only the ratio rule applies
    assert not diverging(1000.0 + 0.01 * t[:40])  # a rise of 0.02 % over the second half: not growth
