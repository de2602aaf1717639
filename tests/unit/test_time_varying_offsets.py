"""Time-varying offsets b(t), d_i(t) from the measurement file's columns (CSV, Parquet, NPZ; in memory and
streamed), against pykalman's time-varying transition/observation offsets, plus their validation."""

from __future__ import annotations

import io

import numpy as np
import pandas as pd
import pytest

from teamkf import CommGraph, TeamCost
from teamkf.network.information import InformationStructure
from teamkf.simulation.sampling import sample_paths
from teamkf.study import measurements as M
from teamkf.study.measurements import MeasurementFileError
from teamkf.study.scenario import Scenario, load_packaged
from teamkf.study.stream import stream_filter
from tests.helpers import random_system

TOL = 1e-10


def _instance(seed, *, T=25, with_inputs=True, const_b=False):
    """Three agents, d_x = 3, inputs u(t) and a prior mean in the scenario; b(t), d_i(t) for the file."""
    rng = np.random.default_rng(seed)
    n, dx, dys, du = 3, 3, [1, 2, 1], 2
    sys = random_system(rng, n, dx, dys, stable=True)
    cost = TeamCost(S=np.eye(n), L=np.eye(dx), n_agents=n)
    raw: dict = {"system": {"x0_mean": rng.standard_normal(dx).tolist()}, "agents": [{} for _ in range(n)]}
    B = rng.standard_normal((dx, du))
    D = [rng.standard_normal((d, du)) for d in dys]
    if with_inputs:
        raw["system"]["B"] = B.tolist()
        for i in range(n):
            raw["agents"][i]["D"] = D[i].tolist()
    if const_b:
        raw["system"]["b"] = [1.0] * dx
    g = CommGraph.complete(n, delay=1)
    sc = Scenario(
        name="tv", horizon=T, system=sys, cost=cost, graph=g, information=InformationStructure.from_graph(g), estimators=("centralized",), raw=raw
    )
    u = rng.standard_normal((T, du)) if with_inputs else None
    b = rng.standard_normal((T, dx))
    d = [rng.standard_normal((T, k)) for k in dys]
    # the affine model's data: the zero-mean sample plus the means, computed here (not by teamkf)
    m = np.empty((T, dx))
    m[0] = raw["system"]["x0_mean"]
    for t in range(T - 1):
        m[t + 1] = sys.A[0] @ m[t] + b[t] + (B @ u[t] if with_inputs else 0)
    p = sample_paths(sys, T, 1, rng=seed)
    ys = [p.y[i][0] + m @ sys.C_at(i, 0).T + d[i] + (u @ D[i].T if with_inputs else 0) for i in range(n)]
    return sc, u, b, d, ys, B, D, m


@pytest.mark.parametrize("ext", [".csv", ".parquet", ".npz"])
@pytest.mark.parametrize("seed", range(2))
def test_offset_columns_equal_pykalman(tmp_path, ext, seed):
    pk = pytest.importorskip("pykalman", reason="pykalman is not installed (pip install 'teamkf[test]')")
    T = 25
    sc, u, b, d, ys, B, D, _ = _instance(seed, T=T)
    sys = sc.system
    for y in ys:
        y[[4, 9]] = np.nan  # whole missing steps (pykalman masks whole observations)
    f = tmp_path / f"m{ext}"
    M.write_measurements(f, ys, u=u, b=b, d=d)
    log = M.read_measurements(f, sys, sc.horizon)
    np.testing.assert_array_equal(log.b, b)
    for i in range(3):  # where y is missing the offset is never used (stored as 0)
        np.testing.assert_array_equal(log.d[i], np.where(np.isnan(ys[i]), 0.0, d[i]))
    res = M.filter_log(sc, log)
    C = np.vstack([sys.C_at(i, 0) for i in range(3)])
    Y = np.ma.masked_invalid(np.concatenate(ys, axis=1))
    kf = pk.KalmanFilter(
        transition_matrices=sys.A[0],
        observation_matrices=C,
        transition_covariance=sys.Q[0],
        observation_covariance=sys.R_stack(0),
        transition_offsets=(u @ B.T + b)[:-1],
        observation_offsets=u @ np.vstack(D).T + np.concatenate(d, axis=1),
        initial_state_mean=np.array(sc.raw["system"]["x0_mean"]),
        initial_state_covariance=sys.Sigma_x,
    )
    means, _ = kf.filter(Y)
    np.testing.assert_allclose(res.estimates["centralized"], means, rtol=TOL, atol=TOL)
    assert res.loglik == pytest.approx(kf.loglikelihood(Y), rel=TOL, abs=TOL)


def test_offsets_alone_need_no_scenario_keys():
    """A scenario without any known-input key: the file's b/d columns alone shift the estimates by m(t)."""
    sc, _, b, d, ys, _, _, m = _instance(3, with_inputs=False)
    raw = {"system": {}, "agents": [{} for _ in range(3)]}
    sc0 = Scenario(
        name="z", horizon=sc.horizon, system=sc.system, cost=sc.cost, graph=sc.graph, information=sc.information, estimators=sc.estimators, raw=raw
    )
    m0 = np.empty_like(m)  # the mean trajectory with a zero prior mean
    m0[0] = 0.0
    for t in range(len(m) - 1):
        m0[t + 1] = sc.system.A[0] @ m0[t] + b[t]
    ybar = [m0 @ sc.system.C_at(i, 0).T + d[i] for i in range(3)]
    with_offsets = M.filter_log(sc0, M.MeasurementLog.from_arrays(ys, sc.system, sc.horizon, b=b, d=d), estimators=["centralized", "mtmse"])
    centred = M.filter_log(sc0, [ys[i] - ybar[i] for i in range(3)], estimators=["centralized", "mtmse"], inputs=None)
    for name in ("centralized", "mtmse"):
        np.testing.assert_allclose(with_offsets.estimates[name] - m0, centred.estimates[name], rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("ext", [".csv", ".npz"])
def test_stream_with_offset_columns_equals_in_memory(tmp_path, ext):
    sc = load_packaged("platoon-4-steady")
    T = 60
    rng = np.random.default_rng(4)
    p = sample_paths(sc.system, T, 1, rng=5)
    b = rng.standard_normal((T, sc.system.dx))
    d = [rng.standard_normal((T, k)) for k in sc.system.dy]
    ys = [p.y[i][0] + d[i] for i in range(sc.n_agents)]
    f = tmp_path / f"m{ext}"
    M.write_measurements(f, ys, b=b, d=d)
    buf = io.BytesIO()
    stream_filter(sc, f, buf, fmt=".csv", chunk_rows=23, progress=False)
    got = pd.read_csv(io.BytesIO(buf.getvalue()))
    ref = M.filter_log(sc, M.read_measurements(f, sc.system, None))
    want = M.estimates_frame(ref.estimates, sc.n_agents)
    np.testing.assert_allclose(got["z0"], want["z0"], rtol=1e-10, atol=1e-10 * np.abs(want["z0"]).max())


def _write_csv(path, rows, cols):
    pd.DataFrame(rows, columns=cols).to_csv(path, index=False)


@pytest.mark.parametrize(
    "mutate, match",
    [
        (lambda df: df.assign(b0=np.where(df.index == 5, np.nan, df.b0)), r"row 6 \(line 7\), column 'b0': expected a finite value"),
        (lambda df: df.assign(d0=np.where(df.index == 2, np.nan, df.d0)), r"row 3 \(line 4\), column 'd0': expected a finite offset"),
        (lambda df: df.assign(b0=np.where(df.index == 1, 99.0, df.b0)), r"column 'b0': step 0 has b0 = 99"),
        (lambda df: df.drop(columns=["b2"]), r"column 'b1': process-offset columns must be b0..b2"),
        (lambda df: df.assign(d1=np.where(df.agent == 0, 1.0, df.d1)), r"column 'd1': agent 0 has d_y = 1 \(columns d0..d0\); leave d1 empty"),
    ],
)
def test_bad_offset_columns(tmp_path, mutate, match):
    sc, u, b, d, ys, *_ = _instance(0, T=6)
    f = tmp_path / "m.csv"
    M.write_measurements(f, ys, u=u, b=b, d=d)
    df = mutate(pd.read_csv(f))
    df.to_csv(f, index=False)
    with pytest.raises(MeasurementFileError, match=match):
        M.read_measurements(f, sc.system, sc.horizon)


def test_offset_given_twice_is_refused():
    sc, u, b, d, ys, *_ = _instance(1, T=6, const_b=True)
    log = M.MeasurementLog.from_arrays(ys, sc.system, sc.horizon, u=u, b=b)
    with pytest.raises(MeasurementFileError, match="b: given both as system.b"):
        M.filter_log(sc, log)
