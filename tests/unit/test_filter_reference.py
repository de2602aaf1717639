"""The centralized filter on a user's data (prior mean, known inputs and offsets, gaps) against filterpy and pykalman.

filterpy and pykalman are independent implementations (the ``test`` extra); the suite skips
these checks, with the reason, where they are not installed.
"""

from __future__ import annotations

import numpy as np
import pytest

from teamkf import CommGraph, TeamCost
from teamkf.network.information import InformationStructure
from teamkf.simulation.sampling import sample_paths
from teamkf.study import measurements as M
from teamkf.study.scenario import Scenario
from tests.helpers import random_system

TOL = 1e-10


def _instance(seed, *, T=30):
    """Three agents, d_x = 3, L = I (z_i is the i-th state component), inputs, offsets and a prior mean."""
    rng = np.random.default_rng(seed)
    n, dx, dys, du = 3, 3, [1, 2, 1], 2
    sys = random_system(rng, n, dx, dys, stable=True)
    cost = TeamCost(S=np.eye(n), L=np.eye(dx), n_agents=n)
    B = rng.standard_normal((dx, du))
    D = [rng.standard_normal((d, du)) for d in dys]
    raw = {
        "system": {"x0_mean": rng.standard_normal(dx).tolist(), "B": B.tolist(), "b": rng.standard_normal(dx).tolist()},
        "agents": [{"D": D[i].tolist(), "d": rng.standard_normal(dys[i]).tolist()} for i in range(n)],
    }
    g = CommGraph.complete(n, delay=1)
    sc = Scenario(
        name="ref", horizon=T, system=sys, cost=cost, graph=g, information=InformationStructure.from_graph(g), estimators=("centralized",), raw=raw
    )
    known = M.known_inputs(sc)
    u = rng.standard_normal((T, du))
    # data from the affine model: the zero-mean sample plus the means
    p = sample_paths(sys, T, 1, rng=seed)
    m, ybar = known.means(sys, T, u)
    ys = [p.y[i][0] + ybar[i] for i in range(n)]
    return sc, known, u, ys, p.x[0] + m


def _stack(sys, ys, known, u, T):
    C = np.vstack([sys.C_at(i, 0) for i in range(sys.n_agents)])
    R = sys.R_stack(0)
    Y = np.concatenate(ys, axis=1)
    Dall = np.vstack(known.D)
    dall = np.concatenate(known.d)
    obs_off = u @ Dall.T + dall
    trans_off = u @ known.B.T + known.b
    return C, R, Y, obs_off, trans_off


@pytest.mark.parametrize("seed", range(3))
def test_centralized_equals_pykalman(seed, tmp_path):
    pk = pytest.importorskip("pykalman", reason="pykalman is not installed (pip install 'teamkf[test]')")
    T = 30
    sc, known, u, ys, _ = _instance(seed, T=T)
    sys = sc.system
    f = tmp_path / "m.csv"
    M.write_measurements(f, ys, u=u)  # inputs as u columns of the measurement file
    log = M.read_measurements(f, sys, sc.horizon)
    np.testing.assert_array_equal(log.u, u)
    res = M.filter_log(sc, log)
    C, R, Y, obs_off, trans_off = _stack(sys, ys, known, u, T)
    kf = pk.KalmanFilter(
        transition_matrices=sys.A[0],
        observation_matrices=C,
        transition_covariance=sys.Q[0],
        observation_covariance=R,
        transition_offsets=trans_off[:-1],
        observation_offsets=obs_off,
        initial_state_mean=known.x0_mean,
        initial_state_covariance=sys.Sigma_x,
    )
    means, _ = kf.filter(Y)
    np.testing.assert_allclose(res.estimates["centralized"], means, rtol=TOL, atol=TOL)
    assert res.loglik == pytest.approx(kf.loglikelihood(Y), rel=TOL, abs=TOL)


def test_centralized_with_missing_steps_equals_pykalman():
    pk = pytest.importorskip("pykalman", reason="pykalman is not installed (pip install 'teamkf[test]')")
    T = 25
    sc, known, u, ys, _ = _instance(7, T=T)
    sys = sc.system
    gone = [3, 4, 11, 20]
    for y in ys:
        y[gone] = np.nan  # pykalman masks whole observations
    res = M.filter_log(sc, M.MeasurementLog.from_arrays(ys, sys, T, u=u))
    C, R, Y, obs_off, trans_off = _stack(sys, ys, known, u, T)
    Ym = np.ma.masked_invalid(Y)
    kf = pk.KalmanFilter(
        transition_matrices=sys.A[0],
        observation_matrices=C,
        transition_covariance=sys.Q[0],
        observation_covariance=R,
        transition_offsets=trans_off[:-1],
        observation_offsets=obs_off,
        initial_state_mean=known.x0_mean,
        initial_state_covariance=sys.Sigma_x,
    )
    means, _ = kf.filter(Ym)
    np.testing.assert_allclose(res.estimates["centralized"], means, rtol=TOL, atol=TOL)
    assert res.loglik == pytest.approx(kf.loglikelihood(Ym), rel=TOL, abs=TOL)


@pytest.mark.parametrize("seed", range(3))
def test_centralized_equals_filterpy(seed):
    fp = pytest.importorskip("filterpy.kalman", reason="filterpy is not installed (pip install 'teamkf[test]')")
    T = 30
    sc, known, u, ys, x_true = _instance(100 + seed, T=T)
    sys = sc.system
    res = M.filter_log(sc, M.MeasurementLog.from_arrays(ys, sys, T, u=u), truth=x_true)
    C, R, Y, obs_off, _ = _stack(sys, ys, known, u, T)
    dx, du = sys.dx, u.shape[1]
    kf = fp.KalmanFilter(dim_x=dx, dim_z=C.shape[0], dim_u=du + dx)
    kf.x = known.x0_mean.copy()
    kf.P = np.array(sys.Sigma_x)
    kf.F, kf.H, kf.Q, kf.R = np.array(sys.A[0]), C, np.array(sys.Q[0]), R
    kf.B = np.hstack([known.B, np.eye(dx)])  # x(t+1) = A x + B u + b  as  [B I] [u; b]
    xs, ll = [], 0.0
    for t in range(T):
        kf.update(Y[t] - obs_off[t])
        xs.append(kf.x.copy())
        ll += kf.log_likelihood
        kf.predict(u=np.concatenate([u[t], known.b]))
    np.testing.assert_allclose(res.estimates["centralized"], np.array(xs), rtol=TOL, atol=TOL)
    assert res.loglik == pytest.approx(ll, rel=TOL, abs=TOL)
    # the realized cost is that of the filterpy estimates
    want = np.sum((x_true - np.array(xs)) ** 2, axis=1)
    np.testing.assert_allclose(res.stage_costs["centralized"], want, rtol=1e-8, atol=1e-10)


def test_means_shift_every_family_estimate_and_leave_errors_alone():
    """Known means change estimates by L m(t) and nothing else (MTMSE, MMSE, centralized, KCF, CIKF)."""
    T = 12
    sc, known, u, ys, _ = _instance(5, T=T)
    names = ("mtmse", "mmse", "centralized", "kcf", "cikf")
    with_means = M.filter_log(sc, M.MeasurementLog.from_arrays(ys, sc.system, T, u=u), estimators=names)
    m, ybar = known.means(sc.system, T, u)
    centred = [ys[i] - ybar[i] for i in range(3)]
    without = M.filter_log(sc, centred, estimators=names, inputs=None)
    for name in names:
        np.testing.assert_allclose(with_means.estimates[name] - m, without.estimates[name], rtol=1e-12, atol=1e-12)


def test_bad_known_inputs():
    from teamkf.exceptions import ScenarioError

    sc, known, u, ys, _ = _instance(0, T=5)
    bad = Scenario(**{**sc.__dict__, "raw": {"system": {"x0_mean": [1.0, 2.0]}, "agents": [{}, {}, {}]}})
    with pytest.raises(ScenarioError, match=r"system.x0_mean: expected 3 finite numbers"):
        M.known_inputs(bad)
    with pytest.raises(M.MeasurementFileError, match="no inputs"):
        M.filter_log(sc, ys)  # B but neither system.u nor u columns
