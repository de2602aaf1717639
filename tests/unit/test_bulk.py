"""Bulk filter (Abedinpour Fallah et al. 2017): exact and finite-memory gains against a brute-force
conditional expectation on the stacked joint Gaussian of N explicit agents; large-N limit;
memory-n convergence; isolated Kalman sequence; population model, scenario and validation."""

import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from teamkf.estimators.bulk import (
    FLUSH,
    BulkFilter,
    FiniteMemoryFilter,
    bulk_filter,
    discrepancy_index,
    exact_bulk_filter,
    finite_memory_filter,
    isolated_gains,
    isolated_kalman_gain,
    isolated_prior_variance,
    riccati_feedback_gain,
    stationarity_index,
)
from teamkf.exceptions import ArgumentError, ScenarioError, ShapeError, TeamkfError
from teamkf.models.population import PopulationModel, cdma_population
from teamkf.study.population import PopulationScenario, evaluate_population, population_from_dict

SCENARIOS = Path(__file__).resolve().parents[2] / "src" / "teamkf" / "scenarios"


# ---------------------------------------------------------------------------
# the oracle: N explicit agents, every variable a coefficient vector over the primitive noises
# ---------------------------------------------------------------------------
def brute_force(m: PopulationModel, T: int, memory: int = 0) -> dict:
    """Condition the stacked joint Gaussian directly, step by step, in the closed loop.

    Primitive standard normals: x_0 (N), w_0..w_{T-1} (N each), v_1..v_T (N each); the last
    coordinate is the constant 1. At step k the gain of agent 0 is Cov(x_k, Y) Cov(Y)^{-1} on
    its window Y (all of y_1..y_k, or the last ``memory``), and every agent applies its own
    gain (checked equal for agent 1).
    """
    N = m.n_agents
    dim = N + 2 * N * T
    one = dim

    def vec() -> np.ndarray:
        return np.zeros(dim + 1)

    x = []
    for i in range(N):
        v = vec()
        v[i] = m.sigma_0
        v[one] = m.x0_mean
        x.append(v)
    xh = []
    for i in range(N):
        v = vec()
        v[one] = m.x0_mean
        xh.append(v)
    Ys: list[list[np.ndarray]] = [[] for _ in range(N)]
    out = {"K": [], "vx": [m.p0], "ex": [m.x0_mean], "sig": [m.p0], "vxh": [0.0], "vm": [m.p0 / N], "cross": [0.0]}
    for k in range(1, T + 1):
        xn = []
        for i in range(N):
            v = m.a * x[i] - m.b * m.f * xh[i]
            v[N + (k - 1) * N + i] += m.sigma_w
            xn.append(v)
        x = xn
        mk = sum(x) / N
        for i in range(N):
            y = m.c * x[i] + m.h * mk
            y[N + N * T + (k - 1) * N + i] += m.sigma_v
            Ys[i].append(y)
        L = k if memory == 0 else min(k, memory)
        gains = []
        for i in range(min(N, 2)):
            Y = np.array(Ys[i][-L:])
            Pyy = Y[:, :one] @ Y[:, :one].T
            Pxy = Y[:, :one] @ x[i][:one]
            gains.append(np.linalg.solve(Pyy, Pxy))
        if N > 1:
            np.testing.assert_allclose(gains[0], gains[1], rtol=1e-9, atol=1e-12)
        K = gains[0]
        out["K"].append(K)
        for i in range(N):
            Y = np.array(Ys[i][-L:])
            v = K @ Y
            v[one] = x[i][one]  # E xhat = E x
            xh[i] = v
        e = x[0] - xh[0]
        out["vx"].append(x[0][:one] @ x[0][:one])
        out["ex"].append(x[0][one])
        out["sig"].append(e[:one] @ e[:one])
        out["vxh"].append(xh[0][:one] @ xh[0][:one])
        out["vm"].append(mk[:one] @ mk[:one])
        out["cross"].append(x[0][:one] @ x[1][:one] if N > 1 else np.nan)
    return out


CASES = [
    dict(n_agents=3, a=2.5, f=2.0),
    dict(n_agents=4, a=5.0, f=4.5),  # persistently time-varying regime
    dict(n_agents=1, a=1.2, f=0.3, h=0.7),
    dict(n_agents=2, a=0.7, f=0.2, c=0.8, h=1.7, sigma_w=0.6, sigma_v=1.3, sigma_0=2.0, x0_mean=0.8, b=1.5),
    dict(n_agents=3, a=-1.4, f=-1.0, h=0.4, x0_mean=-1.0, sigma_0=0.0),
]


@pytest.mark.parametrize("kw", CASES, ids=[f"case{i}" for i in range(len(CASES))])
def test_exact_gains_equal_brute_force(kw):
    m = PopulationModel(**kw)
    T = 9
    bf = exact_bulk_filter(m, T)
    ref = brute_force(m, T)
    G = bf.gains()
    for k in range(1, T + 1):
        np.testing.assert_allclose(bf.gain(k), ref["K"][k - 1], rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(G[k - 1, :k], ref["K"][k - 1], rtol=1e-9, atol=1e-12)
        assert np.all(G[k - 1, k:] == 0)
    cov = bf.covariances
    scale = max(ref["vx"])
    np.testing.assert_allclose(cov.state_variance, ref["vx"], rtol=1e-9, atol=1e-12 * scale)
    np.testing.assert_allclose(cov.state_mean, ref["ex"], rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(cov.error_variance, ref["sig"], rtol=1e-9, atol=1e-12 * scale)
    np.testing.assert_allclose(cov.estimate_variance, ref["vxh"], rtol=1e-9, atol=1e-12 * scale)
    np.testing.assert_allclose(cov.mean_variance, ref["vm"], rtol=1e-9, atol=1e-12 * scale)
    if m.n_agents > 1:
        np.testing.assert_allclose(cov.cross_covariance[1:], ref["cross"][1:], rtol=1e-8, atol=1e-11 * scale)
    else:
        assert np.all(np.isnan(cov.cross_covariance))
    np.testing.assert_allclose(bf.last_entries, [K[-1] for K in ref["K"]], rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("memory", [1, 2, 3])
@pytest.mark.parametrize("kw", CASES[:2] + CASES[3:4], ids=["case0", "case1", "case3"])
def test_finite_memory_gains_equal_brute_force(kw, memory):
    m = PopulationModel(**kw)
    T = 8
    fm = finite_memory_filter(m, T, memory)
    ref = brute_force(m, T, memory)
    for k in range(1, T + 1):
        np.testing.assert_allclose(fm.gain(k), ref["K"][k - 1], rtol=1e-9, atol=1e-12)
    scale = max(ref["vx"])
    cov = fm.covariances
    for key, arr in (("vx", cov.state_variance), ("sig", cov.error_variance), ("vxh", cov.estimate_variance), ("vm", cov.mean_variance)):
        np.testing.assert_allclose(arr, ref[key], rtol=1e-9, atol=1e-12 * scale, err_msg=key)


def test_memory_at_least_horizon_is_the_exact_filter_for_huge_n():
    # two different algorithms (vector recursions with C vs augmented-state covariances), N = 10^9
    m = PopulationModel(n_agents=10**9, a=3.0, f=2.5, x0_mean=0.3)
    T = 40
    bf = exact_bulk_filter(m, T)
    fm = finite_memory_filter(m, T, T)
    for k in (1, 7, 25, 40):
        np.testing.assert_allclose(fm.gain(k), bf.gain(k), rtol=1e-8, atol=1e-11)
    np.testing.assert_allclose(fm.covariances.state_variance, bf.covariances.state_variance, rtol=1e-10)
    # Var m_k rises to O(1) and falls back towards O(1/N): at its minima it is a difference of O(1) terms,
    # so compare against the largest value over the horizon (absolute round-off)
    vm = bf.covariances.mean_variance
    np.testing.assert_allclose(fm.covariances.mean_variance, vm, rtol=1e-8, atol=1e-10 * vm.max())


def test_uncoupled_and_single_agent_reduce_to_the_kalman_filter():
    # h = 0: the time-varying Kalman filter of (a, c) for any N; N = 1: that of (a, c + h).
    for m, cc in ((PopulationModel(n_agents=10**6, a=1.7, f=1.0, h=0.0), 1.0), (PopulationModel(n_agents=1, a=1.7, f=1.0, h=0.6), 1.6)):
        T = 30
        bf = exact_bulk_filter(m, T)
        P = m.p0
        gains_innov = []
        for k in range(T):
            P = m.a**2 * P + m.q  # prior variance
            S = cc * cc * P + m.r_v
            gains_innov.append(cc * P / math.sqrt(S))
            P = P - (cc * P) ** 2 / S
        np.testing.assert_allclose(bf.g, gains_innov, rtol=1e-12)
        np.testing.assert_allclose(bf.covariances.error_variance[-1], P, rtol=1e-10)


def test_paper_vectors_section_4_2_and_4_3():
    K1000 = exact_bulk_filter(PopulationModel(n_agents=1000, a=2.5, f=2.0), 300).final_gains()
    np.testing.assert_allclose(K1000[-5:], [-0.0006, 0.0015, 0.0018, 0.0615, 0.8628], atol=5e-5)
    bf = exact_bulk_filter(PopulationModel(n_agents=10**9, a=2.5, f=2.0), 300)
    K = bf.final_gains()
    np.testing.assert_allclose(K[-4:], [0.0003, 0.0039, 0.0584, 0.8650], atol=5e-5)
    iso = isolated_gains(bf.model, 300)
    np.testing.assert_allclose(iso[-4:], [0.00026616, 0.0039, 0.0584, 0.8650], atol=5e-5)
    # large-N limit: the exact gains approach the isolated sequence (error O(1/N))
    assert discrepancy_index(K, iso) < 1e-7
    d = [discrepancy_index(exact_bulk_filter(bf.model.with_(n_agents=N), 200).final_gains(), iso[-200:]) for N in (10**2, 10**4, 10**6)]
    assert d[0] > 30 * d[1] > 900 * d[2] > 0
    assert bf.stationarity_index() < 1e-13


def test_memory_n_converges_to_exact():
    m = PopulationModel(n_agents=1000, a=2.5, f=2.0)
    T = 200
    K = exact_bulk_filter(m, T).final_gains()
    vx = exact_bulk_filter(m, T).covariances.state_variance[-1]
    errs, verr = [], []
    for n in (1, 2, 3, 5, 8, 13, 30, 60):
        fm = finite_memory_filter(m, T, n)
        Kn = np.zeros(T)
        Kn[T - n :] = fm.final_gains()
        errs.append(np.linalg.norm(Kn - K))
        verr.append(abs(fm.covariances.state_variance[-1] - vx))
    assert all(e1 > e2 for e1, e2 in zip(errs[:-1], errs[1:-1]))  # monotone until round-off
    assert errs[-1] < 1e-12 and errs[0] > 0.01
    assert verr[-1] < 1e-12 * vx and verr[0] > 1e-3 * vx


def test_flush_and_band_do_not_change_results():
    for m in (PopulationModel(n_agents=1000, a=2.5, f=2.0), PopulationModel(n_agents=1000, a=5.0, f=4.5)):
        T = 600
        a = exact_bulk_filter(m, T)
        b = exact_bulk_filter(m, T, flush=0.0)
        assert b.band == T - 1 and a.band < T - 1
        np.testing.assert_allclose(a.final_gains(), b.final_gains(), atol=1e-10)
        np.testing.assert_allclose(a.covariances.state_variance, b.covariances.state_variance, rtol=1e-9)
        # no subnormal numbers survive
        tiny = np.finfo(float).tiny
        for arr in (a.mu, a.gains()):
            nz = np.abs(arr[arr != 0])
            assert nz.size == 0 or nz.min() >= tiny


def test_gain_accessors_and_stationarity_index():
    m = PopulationModel(n_agents=50, a=2.0, f=1.5, x0_mean=1.0)
    bf = exact_bulk_filter(m, 60)
    G = bf.gains()
    for k in (1, 2, 30, 60):
        np.testing.assert_allclose(G[k - 1, :k], bf.gain(k), atol=1e-12)
    assert bf.stationarity_index() == pytest.approx(np.linalg.norm(bf.gain(59) - bf.gain(60)[1:]), abs=1e-15)
    assert stationarity_index([1.0, 2.0], [0.0, 1.0, 2.0]) == 0.0
    assert stationarity_index([1.0, 2.0], [1.0, 2.5]) == pytest.approx(0.5)
    assert discrepancy_index([1.0, 2.0], [2.0]) == pytest.approx(1.0)
    # innovation form is the measurement form: M e = Y - E Y
    M = bf.measurement_matrix()
    np.testing.assert_allclose(np.diag(M), bf.s)
    assert np.all(bf.s >= m.sigma_v - 1e-12)
    with pytest.raises(ShapeError, match="k: expected 1 <= k <= horizon = 60, found 61"):
        bf.gain(61)
    fm = finite_memory_filter(m.with_(memory=4), 10)
    assert fm.gain(2).shape == (2,) and fm.gain(10).shape == (4,) and fm.gains().shape == (10, 4)
    assert fm.stationarity_index() == pytest.approx(np.linalg.norm(fm.gain(9) - fm.gain(10)))
    assert isinstance(bulk_filter(m, 5), BulkFilter) and isinstance(bulk_filter(m.with_(memory=3), 5), FiniteMemoryFilter)


def test_unstable_finite_memory_loop_is_flagged():
    fm = finite_memory_filter(PopulationModel.from_af(100, 8.0, 0.5, memory=3), 1000)
    assert fm.diverged_at is not None and np.isnan(fm.K[-1]).all()


def test_isolated_kalman_filter_and_riccati_gain():
    assert isolated_kalman_gain(5.0) == pytest.approx(0.9616, abs=5e-5)  # paper, Section 4.4
    P = isolated_prior_variance(2.5, c=0.7, sigma_w=0.5, sigma_v=2.0)
    # eq. (7) and the Riccati fixed point it comes from
    q, r, a, c = 0.25, 4.0, 2.5, 0.7
    assert c * c * P * P + ((1 - a * a) * r - c * c * q) * P - q * r == pytest.approx(0, abs=1e-9)
    assert a * a * (P - (c * P) ** 2 / (c * c * P + r)) + q == pytest.approx(P, rel=1e-12)
    # stable a, no process noise: P = 0 (the cancellation-free root)
    assert isolated_prior_variance(0.5, sigma_w=0.0) == 0.0
    # eq. (8)-(9): f* is the LQR gain of the scalar system (fixed point of the control Riccati equation)
    for a, r, b in ((2.0, 1.0, 1.0), (5.0, 1.0, 1.0), (0.5, 3.0, 2.0)):
        f = riccati_feedback_gain(a, r, b=b)
        S = 1.0
        for _ in range(2000):
            S = 1 + a * a * S - (a * b * S) ** 2 / (b * b * S + r)
        assert f == pytest.approx(a * b * S / (b * b * S + r), rel=1e-9)
    # Prop. 1: the FIR sequence is the impulse response of (58)
    m = PopulationModel(n_agents=1, a=2.5, f=2.0)
    Ks = isolated_kalman_gain(2.5)
    iso = isolated_gains(m, 6)
    h, resp = 0.0, []
    for k in range(6):
        h = m.a_f * (1 - Ks) * h + Ks * (1.0 if k == 0 else 0.0)
        resp.append(h)
    np.testing.assert_allclose(iso[::-1], resp, rtol=1e-12)


# ---------------------------------------------------------------------------
# model, CDMA builder, scenario, evaluation
# ---------------------------------------------------------------------------
@pytest.mark.parametrize(
    "kw, words",
    [
        (dict(n_agents=0), ["n_agents", "integer >= 1", "0"]),
        (dict(n_agents=2.5), ["n_agents", "integer", "2.5"]),
        (dict(a=float("nan")), ["a", "finite"]),
        (dict(f="x"), ["f", "real number", "'x'"]),
        (dict(b=0.0), ["b", "> 0", "0.0"]),
        (dict(c=-1.0), ["c", "> 0", "-1.0"]),
        (dict(h=-0.1), ["h", ">= 0", "-0.1", "h = 0"]),
        (dict(sigma_v=0.0), ["sigma_v", "> 0", "strictly positive"]),
        (dict(sigma_w=-1.0), ["sigma_w", ">= 0"]),
        (dict(memory=-2), ["memory", "integer >= 0", "-2"]),
        (dict(r=0.0), ["r", "> 0"]),
    ],
)
def test_model_validation(kw, words):
    args = dict(n_agents=10, a=1.0, f=0.5)
    args.update(kw)
    with pytest.raises(ArgumentError) as ei:
        PopulationModel(**args)
    msg = str(ei.value)
    assert isinstance(ei.value, (TeamkfError, ValueError))
    for w in words:
        assert w in msg, (w, msg)


def test_model_basics_and_cdma():
    m = PopulationModel(n_agents=1e9, a=2.5, f=2.0)
    assert m.n_agents == 10**9 and isinstance(m.n_agents, int) and m.a_f == 0.5
    assert PopulationModel.from_af(10, 3.0, 0.8).f == pytest.approx(2.2)
    assert m.with_(a_f=0.9).f == pytest.approx(1.6)
    with pytest.raises(Exception):
        m.a = 3.0  # frozen
    c = cdma_population(100, a=2.0, alpha=0.5, beta=4.0, h_prime=25.0, f=1.0, sigma_v=0.5)
    assert c.c == pytest.approx(2.0 * (1 - 0.25)) and c.h == pytest.approx(50.0) and c.sigma_v == 0.5
    with pytest.raises(ShapeError, match=r"h_prime: expected 0 <= h_prime < n_agents = 10"):
        cdma_population(10, a=1.0, alpha=1.0, beta=1.0, h_prime=10.0, f=0.5)
    with pytest.raises(ArgumentError, match="alpha"):
        cdma_population(10, a=1.0, alpha=0.0, beta=1.0, h_prime=1.0, f=0.5)


def _err(d) -> str:
    with pytest.raises(ScenarioError) as ei:
        population_from_dict(d)
    return str(ei.value)


def test_population_from_dict_and_errors():
    base = {"name": "p", "horizon": 50, "population": {"n_agents": 1000, "a": 2.5, "f": 2.0}}
    sc = population_from_dict(base)
    assert isinstance(sc, PopulationScenario) and sc.model.a_f == 0.5 and sc.horizon == 50 and sc.model.memory == 0
    # defaults: the paper's numerical setting and f = f*(a, r)
    sc2 = population_from_dict({"horizon": 5, "population": {"n_agents": 3, "a": 2.0}})
    assert sc2.model.f == pytest.approx(riccati_feedback_gain(2.0, 1.0)) and sc2.model.c == sc2.model.h == 1.0
    sc3 = population_from_dict(
        {"horizon": 5, "population": {"n_agents": 1e9, "a": 2.0, "a_f": 0.5, "memory": 5, "cdma": {"alpha": 1.0, "beta": 2.0, "h_prime": 3.0}}}
    )
    assert sc3.model.f == pytest.approx(1.5) and sc3.model.h == pytest.approx(6.0) and sc3.model.memory == 5

    def with_pop(**kw):
        d = {"horizon": 50, "population": {"n_agents": 10, "a": 2.5, "f": 2.0}}
        d["population"].update(kw)
        return d

    assert _err(with_pop(n_agents=0)) == "population.n_agents: expected an integer >= 1, found 0"
    assert _err(with_pop(n_agents="many")).startswith("population.n_agents: expected an integer >= 1, found the string 'many'")
    assert _err(with_pop(sigma_v=0.0)).startswith("population.sigma_v: expected a number > 0, found 0.0")
    assert _err(with_pop(a="2.5")) == "population.a: expected a number, found the string '2.5'"
    assert _err(with_pop(memory=1.5)).startswith("population.memory: expected an integer >= 0")
    assert _err(with_pop(b=-1.0)).startswith("population.b: expected a number > 0, found -1.0")
    msg = _err(with_pop(sigmaw=1.0))
    assert msg.startswith("population.sigmaw: unknown key; did you mean 'sigma_w'?")
    assert _err(with_pop(a_f=0.5)).startswith("population.a_f: give either f or a_f")
    assert _err(with_pop(c=1.0, cdma={"alpha": 1.0, "beta": 1.0, "h_prime": 1.0})).startswith("population.cdma: give either c and h")
    d = {"horizon": 50, "population": {"n_agents": 10, "a": 2.0, "f": 1.0, "cdma": {"alpha": 1.0, "beta": 1.0}}}
    assert _err(d).startswith("population.cdma.h_prime: missing required key")
    d = {"horizon": 50, "population": {"n_agents": 10, "a": 2.0, "f": 1.0, "cdma": {"alpha": 1.0, "beta": 1.0, "h_prime": 20.0}}}
    assert _err(d).startswith("population.cdma.h_prime: expected 0 <= h_prime < n_agents = 10")
    assert _err({"population": {"n_agents": 10, "a": 1.0}}).startswith("horizon: missing required key")
    assert _err({"horizon": 0, "population": {"n_agents": 10, "a": 1.0}}).startswith("horizon: expected an integer number of steps >= 1")
    assert _err({"horizon": 5}).startswith("population: missing required key")
    assert _err({"horizon": 5, "population": 3}).startswith("population: expected a table")
    assert _err({"horizon": 5, "population": {"a": 1.0}}).startswith("population.n_agents: missing required key")
    assert _err({"horizon": 5, "populaton": {}}).startswith("populaton: unknown key; did you mean 'population'?")


def test_packaged_interference_scenario_and_evaluation():
    d = tomllib.loads((SCENARIOS / "interference.toml").read_text())
    sc = population_from_dict(d)
    assert sc.name == "interference" and sc.horizon == 1000 and sc.model.n_agents == 1000 and sc.model.a_f == 0.5
    out = population_from_dict({**d, "horizon": 150}).evaluate()
    for key in (
        "scenario",
        "gains",
        "stationarity_index",
        "isolated_gains",
        "state_variance",
        "average_lq_cost",
        "average_cost",
        "mean_state_variance",
        "cross_covariance",
        "estimation_error_variance",
        "discrepancy_index",
    ):
        assert key in out, key
    assert len(out["gains"]) == 150 == len(out["isolated_gains"])
    np.testing.assert_allclose(out["gains"][-2:], [0.0615, 0.8628], atol=5e-5)
    assert out["stationarity_index"] < 1e-12 and out["state_variance"] > 0 and out["average_lq_cost"] > out["state_variance"]
    import json

    json.dumps(out)  # plain data
    mem = evaluate_population(sc.model.with_(memory=4), 30)
    assert len(mem["gains"]) == 4 and mem["filter"] == "memory-4"
    single = evaluate_population(PopulationModel(n_agents=1, a=1.0, f=0.5), 10)
    assert single["cross_covariance"] is None


def test_flush_argument_validated():
    with pytest.raises(ShapeError, match="flush"):
        exact_bulk_filter(PopulationModel(n_agents=2, a=1.0, f=0.5), 5, flush=0.5)
    with pytest.raises(ShapeError, match="model: expected a PopulationModel"):
        exact_bulk_filter("model", 5)  # type: ignore[arg-type]
    with pytest.raises(ArgumentError, match="horizon"):
        finite_memory_filter(PopulationModel(n_agents=2, a=1.0, f=0.5, memory=2), 0)
    assert FLUSH == 1e-30
