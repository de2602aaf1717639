"""Decentralized LQG through MTMSE (Appendix D): brute force on the equivalent problem and closed-loop Monte Carlo."""

import numpy as np
import pytest

from teamkf import LinearGaussianSystem, TeamCost
from teamkf.control.lqg import LQGProblem, backward_riccati, design_lqg, simulate_closed_loop
from teamkf.exceptions import NotPositiveDefiniteError, ShapeError
from tests.helpers import brute_force_team


def scalar_problem(seed):
    rng = np.random.default_rng(seed)
    a = rng.uniform(0.8, 1.3)
    system = LinearGaussianSystem(
        A=[[a]],
        Q=rng.uniform(0.2, 1.0),
        Sigma_x=rng.uniform(0.5, 2.0),
        C=[[[rng.uniform(0.5, 1.5)]], [[rng.uniform(0.5, 1.5)]]],
        R=[rng.uniform(0.1, 1), rng.uniform(0.1, 1)],
    )
    B = rng.uniform(0.3, 1.2, size=(1, 2))
    M = rng.standard_normal((2, 2))
    return LQGProblem(system, B=B, Q_x=[[rng.uniform(0.5, 2)]], R_u=M @ M.T + 0.5 * np.eye(2))


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("T", [2, 3, 4])
def test_theorem4_cost_equals_brute_force_on_equivalent_problem(seed, T):
    """n = 2, scalar state: the analytic cost = Lemma 6's constant + Radner's optimum of (67) at every step."""
    prob = scalar_problem(seed)
    d = design_lqg(prob, T)
    P, S, L = backward_riccati(prob, T)
    sys = prob.system
    base = float(np.trace(sys.Sigma_x @ P[0]) + sum(np.trace(sys.Q_at(k) @ P[k + 1]) for k in range(T - 1)))
    cost = TeamCost(S=S, L=L, n_agents=2)
    total = base
    for k in range(T - 1):
        sets = [{(i, k)} | {(j, s) for j in range(2) for s in range(k)} for i in range(2)]  # I_i(k) = {y_i(k), y(0:k-1)}
        J_bf, _ = brute_force_team(sys, cost, sets, k)
        total += J_bf
    assert d.cost == pytest.approx(total, rel=1e-9)
    assert d.cost <= design_lqg(prob, T, kind="mmse").cost * (1 + 1e-12)


def test_closed_loop_monte_carlo_matches_analytic():
    prob = scalar_problem(1)
    for kind in ("mtmse", "mmse"):
        d = design_lqg(prob, 6, kind=kind)
        mc = simulate_closed_loop(d, 40000, rng=3)
        assert abs(mc["mean"] - d.cost) < 4 * mc["sem"], (kind, mc["mean"], d.cost, mc["sem"])


def test_no_separation_gains_change_with_control_weight_but_kalman_gain_does_not():
    from teamkf.experiments.lqg import problem

    a, b = design_lqg(problem(0.1), 10), design_lqg(problem(10.0), 10)
    np.testing.assert_allclose(a.estimation.K_at(4), b.estimation.K_at(4))
    assert not np.allclose(a.F_at(4)[0], b.F_at(4)[0])


def test_lqg_validation():
    sys = LinearGaussianSystem(A=[[1.0]], Q=1.0, Sigma_x=1.0, C=[[[1.0]], [[1.0]]], R=1.0)
    with pytest.raises(ShapeError, match="B: expected n d_u columns"):
        LQGProblem(sys, B=[[1.0, 1.0, 1.0]], Q_x=[[1.0]], R_u=np.eye(3))
    with pytest.raises(NotPositiveDefiniteError, match="R_u"):
        LQGProblem(sys, B=[[1.0, 1.0]], Q_x=[[1.0]], R_u=np.zeros((2, 2)))
    with pytest.raises(ShapeError, match="kind"):
        design_lqg(LQGProblem(sys, B=[[1.0, 1.0]], Q_x=[[1.0]], R_u=np.eye(2)), 3, kind="lqr")


def test_control_scenario_and_cli(capsys):
    import json

    from teamkf.cli import main
    from teamkf.study.scenario import load_packaged, scenario_from_dict

    sc = load_packaged("lqg-2")
    assert sc.control is not None and sc.control.du == 1
    assert main(["evaluate", "lqg-2", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    from teamkf.experiments.lqg import problem

    assert out["control"]["optimal"]["total_cost"] == pytest.approx(design_lqg(problem(1.0), 20).cost, rel=1e-12)
    assert out["control"]["optimal"]["total_cost"] <= out["control"]["certainty_equivalent"]["total_cost"]
    raw = dict(sc.raw)
    raw["control"] = {"B": [[1.0, 0.6]], "Q_x": 1.0, "R_u": 1.0}
    with pytest.raises(ValueError, match=r"^control.B: expected a 2x"):
        scenario_from_dict(raw)
    raw["control"] = {"B": [[1.0, 0.6], [0.4, 1.0]], "Q_x": 1.0}
    with pytest.raises(ValueError, match=r"^control.R_u: missing required key"):
        scenario_from_dict(raw)
