"""A packet that misses its deadline is replaced by the agent's conditional expectation given what it holds.

Checked against a brute force that shares no code with the agent: every measurement is a linear map
of the primitive variables (x(0), w, v) (``tests.helpers.joint_moments``), and E[y_m | y_H] is the
Gaussian conditional mean over the stacked held measurements H = y(0:a-1) ∪ (received window).
"""

from __future__ import annotations

import numpy as np
import pytest

from teamkf import CommGraph, design_mmse, design_mtmse
from teamkf.estimators.team import TeamAgent
from tests.helpers import joint_moments, random_cost, random_system


def _brute_force(Y, Cov, held_keys, wanted, values):
    """E[y_m | y_H] = Y_m Cov Y_H' (Y_H Cov Y_H')^-1 y_H (zero means)."""
    YH = np.vstack([Y[key] for key in held_keys])
    yH = np.concatenate([values[key] for key in held_keys])
    w = np.linalg.solve(YH @ Cov @ YH.T, yH)
    return {key: Y[key] @ Cov @ YH.T @ w for key in wanted}


@pytest.mark.parametrize("kind", ["mtmse", "mmse"])
@pytest.mark.parametrize("seed", range(4))
def test_missed_packet_is_replaced_by_its_conditional_expectation(kind, seed):
    rng = np.random.default_rng(500 + seed)
    n, dx, dys = 3, int(rng.integers(1, 4)), [int(v) for v in rng.integers(1, 3, size=3)]
    g = CommGraph.line(n) if seed % 2 == 0 else CommGraph.complete(n, delay=2)
    sys, cost = random_system(rng, n, dx, dys), random_cost(rng, n, dx, 1)
    T = 9
    d = (design_mtmse if kind == "mtmse" else design_mmse)(sys, cost, g, horizon=T)
    X, Y, Cov = joint_moments(sys, T - 1)
    xi = rng.multivariate_normal(np.zeros(Cov.shape[0]), Cov, method="eigh")  # Q may be singular
    values = {key: m @ xi for key, m in Y.items()}

    i = 0
    lags = [d.structure.arrival_lag(i, j) for j in range(n)]
    # one packet that agent 0 needs from a neighbour never arrives
    j_lost = int(np.argmax([lag if j != i else -1 for j, lag in enumerate(lags)]))
    s_lost = 3
    agent = TeamAgent(d, i, tolerant=True)
    calls = []
    inner = agent.expected_measurements

    def recording(xhat, a, k, buf, wanted):
        out = inner(xhat, a, k, buf, wanted)
        calls.append((a, k, sorted(key for key in buf if a <= key[1] <= k), list(wanted), out))
        return out

    agent.expected_measurements = recording  # type: ignore[method-assign]
    state = agent.init_state(1)
    for k in range(T):
        received = [
            (j, k - lags[j], values[(j, k - lags[j])][None, :]) for j in range(n) if k - lags[j] >= 0 and (j, k - lags[j]) != (j_lost, s_lost)
        ]
        state, z = agent.step(state, k, received)
        assert np.all(np.isfinite(z))
    assert state["missed_keys"] == {(j_lost, s_lost)}
    checked = 0
    for a, k, held, wanted, out in calls:
        if a > s_lost:  # x̂(a) already contains the substitute: no longer the exact centralized predictor
            continue
        common = [(j, s) for s in range(a) for j in range(n)]
        bf = _brute_force(Y, Cov, common + held, wanted, values)
        for key in wanted:
            np.testing.assert_allclose(out[key][0], bf[key], rtol=1e-8, atol=1e-10)
            checked += 1
    assert checked >= 1


def test_nothing_held_gives_the_prediction():
    """With no window measurement held, the substitute is C_j(s) Φ(s, a) x̂(a) (the common prediction)."""
    rng = np.random.default_rng(7)
    sys, cost = random_system(rng, 2, 2, [1, 1]), random_cost(rng, 2, 2, 1)
    d = design_mtmse(sys, cost, CommGraph.line(2), horizon=5)
    agent = TeamAgent(d, 0, tolerant=True)
    xhat = rng.standard_normal((3, 2))
    out = agent.expected_measurements(xhat, 1, 2, {}, [(1, 2)])
    np.testing.assert_allclose(out[(1, 2)], xhat @ sys.transition(2, 1).T @ sys.C_at(1, 2).T)
