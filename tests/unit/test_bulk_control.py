"""Certainty-equivalent control of interference-coupled populations: the naive controller's
stability region S(a) against explicit agents, a_m, a_s, the exact LQ cost, explicit-agent
simulation against the exact covariances (statistical, fixed seeds), and the studies."""

import math

import numpy as np
import pytest

from teamkf import experiments
from teamkf.control import (
    a_m,
    a_m_of_af,
    a_s,
    in_stability_region,
    lq_cost,
    map_points,
    naive_closed_loop,
    naive_spectral_radii,
    simulate_population,
    stability_region_mask,
)
from teamkf.estimators.bulk import bulk_filter, exact_bulk_filter, isolated_kalman_gain, riccati_feedback_gain
from teamkf.exceptions import ArgumentError, ShapeError
from teamkf.models.population import PopulationModel


# ---------------------------------------------------------------------------
# the naive controller (eq. 5): S(a)
# ---------------------------------------------------------------------------
def explicit_naive_matrix(N, a, K, af, c, h, b=1.0):
    """Noise-free closed loop of N explicit agents with xhat+ = a_f xhat + K (y+ - c a_f xhat)."""
    f = (a - af) / b
    I = np.eye(N)
    J = np.full((N, N), 1.0 / N)
    Axx = a * I
    Axh = -b * f * I
    # y_{k+1} = (c I + h J) x_{k+1},  x_{k+1} = a x - b f xhat
    Cy = c * I + h * J
    Ahx = K * Cy @ Axx
    Ahh = af * I + K * (Cy @ Axh) - K * c * af * I
    return np.block([[Axx, Axh], [Ahx, Ahh]])


def test_naive_mean_and_deviation_loops_match_explicit_agents(rng):
    for _ in range(60):
        a = rng.uniform(0, 7)
        K = rng.uniform(-0.5, 1.5)
        af = rng.uniform(-1.2, 1.2)
        c = rng.uniform(0.3, 2.0)
        h = rng.uniform(0.0, 2.0)
        rho = np.max(np.abs(np.linalg.eigvals(explicit_naive_matrix(4, a, K, af, c, h))))
        rm, rd = naive_spectral_radii(a, K, af, c=c, h=h)
        assert max(float(rm), float(rd)) == pytest.approx(rho, rel=1e-9, abs=1e-12)
        Am, Ad = naive_closed_loop(a, K, af, c=c, h=h)
        assert float(rm) == pytest.approx(np.max(np.abs(np.linalg.eigvals(Am))), rel=1e-9, abs=1e-12)
        np.testing.assert_allclose(sorted(np.linalg.eigvals(Ad).real), sorted([af, a * (1 - K * c)]), atol=1e-9)
        assert np.trace(Am) == pytest.approx(a * (1 - K * c) + af - K * h * (a - af))
        assert np.linalg.det(Am) == pytest.approx(a * af * (1 - K * c), abs=1e-9)
        assert in_stability_region(a, K, af, c=c, h=h) == (rho < 1)


def test_a_m_of_af_reproduces_table_1_last_column():
    for af, paper, digits in ((0.3, 2.36, 2), (0.5, 2.74, 2), (0.8, 3.304, 3), (0.99, 3.67, 2)):
        am = a_m_of_af(af)
        assert round(am, digits) == paper
        K = isolated_kalman_gain(am - 1e-6)
        assert in_stability_region(am - 1e-6, K, af) and not in_stability_region(am + 1e-6, isolated_kalman_gain(am + 1e-6), af)
    # a_m = sup over a_f: increasing in a_f, 3.686 as a_f -> 1 (the paper rounds it to "3.6")
    vals = [a_m_of_af(af) for af in np.linspace(0.0, 0.999, 6)]
    assert all(x < y for x, y in zip(vals, vals[1:]))
    assert a_m() == pytest.approx(3.686, abs=1e-3)


def test_a_s_closed_form_matches_a_grid_search():
    s = a_s()
    assert s == pytest.approx(3 + 2 * math.sqrt(2))
    assert a_s(c=1.0, h=0.0) == math.inf
    Kg = np.linspace(0.0, 2.0, 801)
    for c, h in ((1.0, 1.0), (1.0, 2.0), (2.0, 0.5)):
        s = a_s(c=c, h=h)
        # just below: points near the corner a (1 - K c) -> 1, a_f -> 1 are stable
        a = s - 0.02
        afg = np.linspace(0.95, 0.99999, 400)
        Kc = (1 - np.linspace(0.95, 0.99999, 400) / a) / c
        assert stability_region_mask(a, Kc, afg, c=c, h=h).any()
        # just above: nothing in a wide grid is stable
        a = s + 0.02
        assert not stability_region_mask(a, np.union1d(Kg, Kc), np.linspace(-0.999, 0.99999, 500), c=c, h=h).any()
    mask = stability_region_mask(2.0, [0.8, 5.0], [0.5, 0.9])
    assert mask.shape == (2, 2) and mask[0, 0] and not mask[0, 1]


# ---------------------------------------------------------------------------
# explicit agents vs exact covariances
# ---------------------------------------------------------------------------
@pytest.mark.parametrize(
    "kw",
    [
        dict(n_agents=40, a=2.5, f=2.0, x0_mean=0.5),
        dict(n_agents=25, a=5.0, f=4.5),
        dict(n_agents=40, a=2.5, f=2.0, x0_mean=0.5, memory=2),
        dict(n_agents=1, a=1.5, f=1.0, sigma_0=2.0),
    ],
)
def test_simulation_matches_exact_covariances(kw):
    """Statistical: 300 runs, fixed seed; every step's second moment within 4.5 sigma, Var m_k within
    4.5 sigma of its chi-square spread, the LQ cost within 4.5 sigma."""
    m = PopulationModel(**kw)
    T, R = 30, 300
    filt = bulk_filter(m, T)
    sim = simulate_population(m, T, n_runs=R, rng=20170104, filt=filt)
    cov = filt.covariances
    Ex2 = cov.state_variance + cov.state_mean**2
    emp = sim.second_moment.mean(axis=0)
    se = sim.second_moment.std(axis=0, ddof=1) / math.sqrt(R)
    z = (emp[1:] - Ex2[1:]) / se[1:]
    assert np.max(np.abs(z)) < 4.5
    ratio = sim.mean_state.var(axis=0, ddof=1)[1:] / (cov.mean_variance[1:])
    assert np.max(np.abs(ratio - 1)) < 4.5 * math.sqrt(2 / (R - 1))
    mc = sim.lq_cost
    assert abs(mc.mean() - lq_cost(m, T, filt=filt)) < 4.5 * mc.std(ddof=1) / math.sqrt(R)
    np.testing.assert_allclose(sim.mean_state.mean(axis=0), cov.state_mean, atol=4.5 * math.sqrt(cov.mean_variance.max() / R))


def test_simulation_reproducible_and_batched():
    m = PopulationModel(n_agents=30, a=2.5, f=2.0)
    a = simulate_population(m, 20, n_runs=4, rng=7, keep_states=True)
    b = simulate_population(m, 20, n_runs=4, rng=7, max_chunk_doubles=1)  # one run per chunk
    np.testing.assert_array_equal(a.final_states, b.final_states)
    np.testing.assert_array_equal(a.lq_cost, b.lq_cost)
    one = simulate_population(m, 20, n_runs=1, rng=7)
    np.testing.assert_array_equal(one.final_states[0], a.final_states[0])
    assert a.states.shape == (4, 21, 30) and a.estimates.shape == (4, 21, 30)
    np.testing.assert_array_equal(a.states[:, -1], a.final_states)
    np.testing.assert_allclose(a.states.mean(axis=2), a.mean_state)


@pytest.mark.parametrize("memory", [0, 3])
def test_simulation_noise_blocks_do_not_change_the_numbers(monkeypatch, memory):
    """Each run's noise drawn for a block of steps at once (the block not dividing T) = one draw per step."""
    import teamkf.control.certainty_equivalent as ce

    m = PopulationModel(n_agents=7, a=2.5, f=2.0, memory=memory)
    ref = simulate_population(m, 23, n_runs=3, rng=5, keep_states=True)
    for doubles in (1, 2 * 7 * 3 * 5):  # one step per block; five steps per block (23 = 4 x 5 + 3)
        monkeypatch.setattr(ce, "NOISE_BLOCK_DOUBLES", doubles)
        got = simulate_population(m, 23, n_runs=3, rng=5, keep_states=True)
        np.testing.assert_array_equal(got.states, ref.states)
        np.testing.assert_array_equal(got.estimates, ref.estimates)
        np.testing.assert_array_equal(got.lq_cost, ref.lq_cost)


@pytest.mark.parametrize("memory", [0, 3])
def test_simulator_equals_a_plain_loop_with_measurement_form_gains(memory):
    """The batched simulator (innovation form) against a plain loop with xhat_k = E x_k + K_k (Y - E Y)."""
    from teamkf.simulation.sampling import run_streams

    m = PopulationModel(n_agents=6, a=3.0, f=2.7, x0_mean=0.4, memory=memory)
    T = 25
    filt = bulk_filter(m, T)
    sim = simulate_population(m, T, n_runs=2, rng=11, filt=filt)
    for r, st in enumerate(run_streams(11, 2)):
        g = np.random.default_rng(st)
        x = m.x0_mean + m.sigma_0 * g.standard_normal(m.n_agents)
        xh = np.full(m.n_agents, m.x0_mean)
        Y = []
        for k in range(1, T + 1):
            z = g.standard_normal((2, m.n_agents))
            x = m.a * x - m.b * m.f * xh + m.sigma_w * z[0]
            y = m.c * x + m.h * x.mean() + m.sigma_v * z[1]
            Y.append(y - (m.c + m.h) * m.a_f**k * m.x0_mean)
            K = filt.gain(k)
            xh = m.a_f**k * m.x0_mean + K @ np.array(Y[-len(K) :])
        np.testing.assert_allclose(sim.final_states[r], x, rtol=1e-9, atol=1e-9)


def test_saturation_and_validation():
    m = PopulationModel(n_agents=3, a=1.0, f=0.5)
    sim = simulate_population(m, 5, n_runs=2, rng=0)
    fs = np.array([[1.0, -2e4, 3.0], [np.nan, 1.0, 2.0]])
    object.__setattr__(sim, "final_states", fs)
    np.testing.assert_array_equal(sim.max_abs_final(1000.0), [1000.0, 1000.0])
    with pytest.raises(ShapeError, match="n_agents: expected at most"):
        simulate_population(PopulationModel(n_agents=10**9, a=1.0, f=0.5), 5)
    with pytest.raises(ShapeError, match="filt: expected a filter over at least horizon = 10"):
        simulate_population(m, 10, filt=exact_bulk_filter(m, 5))
    with pytest.raises(ShapeError, match="filt: expected a filter computed for this model"):
        simulate_population(m, 5, filt=exact_bulk_filter(m.with_(n_agents=4), 5))
    with pytest.raises(ArgumentError, match="n_runs"):
        simulate_population(m, 5, n_runs=0)
    assert map_points(lambda p: p * 2, [1, 2, 3]) == [2, 4, 6]


def test_lq_cost_riccati_gain_optimal_only_in_stationary_range():
    # Fig. 10 (a = 2): f* minimizes the exact cost over a grid; Fig. 11 (a = 5): it does not (dual effect)
    T = 400
    for a, expect_fstar in ((2.0, True), (5.0, False)):
        fstar = riccati_feedback_gain(a, 1.0)
        grid = sorted({round(a - af, 6) for af in np.linspace(-0.8, 0.8, 9)} | {fstar})
        costs = {f: lq_cost(PopulationModel(n_agents=10**9, a=a, f=f), T) for f in grid}
        best = min(costs, key=costs.get)
        assert (best == fstar) == expect_fstar, (a, best, fstar)


# ---------------------------------------------------------------------------
# the studies (quick mode: smoke + key numbers)
# ---------------------------------------------------------------------------
def test_bulk_experiments_registered_and_quick():
    names = experiments.names()
    for n in ("bulk-stationarity", "bulk-discrepancy", "bulk-timevarying", "bulk-lq-cost", "bulk-stabilization"):
        assert n in names
    disc = experiments.run("bulk-discrepancy", quick=True)
    assert disc.rows[0]["max |ours - paper|"] < 5e-5 and disc.rows[1]["max |ours - paper|"] < 5e-5
    tv = experiments.run("bulk-timevarying", quick=True)
    row = {r["N"]: r for r in tv.rows}[1000]
    assert row["period [steps]"] == pytest.approx(3.57, abs=0.1) and row["Delta (eq. 61)"] > 1e-2
    assert row["corr(Var m, cross)"] > 0.99 and row["corr(K_k(k), cross)"] < -0.5


def test_bulk_experiments_quick_all():
    st = experiments.run("bulk-stationarity", quick=True)
    assert all(np.isfinite(r["a_m(a_f)"]) for r in st.rows)
    lq = experiments.run("bulk-lq-cost", quick=True)
    assert len(lq.rows) > 10
    stab = experiments.run("bulk-stabilization", quick=True)
    n3, n10 = stab.rows[0], stab.rows[1]
    assert n10["stabilized points"] >= n3["stabilized points"]


@pytest.mark.slow
def test_table_1_thresholds_near_the_paper():
    """Full-size (T = 1000) stationarity thresholds: within 0.03 of Table 1, and near a_m(a_f)."""
    from teamkf.experiments.bulk_stationarity import PAPER_TABLE1, threshold_point

    for af, N, j in ((0.5, 1000, 1), (0.99, 100, 0)):
        r = threshold_point({"a_f": af, "n_agents": N, "horizon": 1000})
        assert abs(r["abar"] - PAPER_TABLE1[af][j]) < 0.03
        assert abs(r["abar"] - a_m_of_af(af)) < 0.15
