"""Streaming `teamkf filter` (steady-state LTI forms, chunks): the same estimates as the online agents."""

from __future__ import annotations

import io

import numpy as np
import pandas as pd
import pytest

from teamkf.cli import main
from teamkf.exceptions import UnsupportedOperationError
from teamkf.simulation.sampling import sample_paths
from teamkf.study import measurements as M
from teamkf.study.scenario import load_packaged
from teamkf.study.stream import _linear_recurrence, stream_filter


@pytest.fixture(scope="module")
def steady():
    sc = load_packaged("platoon-4-steady")
    p = sample_paths(sc.system, 120, 1, rng=11)
    return sc, [y[0] for y in p.y], p.x[0]


@pytest.mark.parametrize("name", ["centralized", "mtmse", "mmse"])
def test_steady_form_equals_online_agents(steady, name):
    sc, ys, _ = steady
    d = sc.design(name)
    f = d.steady_form()
    Y = np.concatenate(ys, axis=1)
    z = M.online_estimates(d, ys)
    x, X = np.zeros(sc.system.dx), []
    for a in range(len(Y)):
        X.append(x)
        x = f.M @ x + f.N @ Y[a]
    c = f.lag
    zz = np.array([f.G @ X[k - c + 1] + sum(f.H[l] @ Y[k - l] for l in range(c)) for k in range(f.start, len(Y))])
    np.testing.assert_allclose(zz, z[f.start :], rtol=1e-11, atol=1e-11 * np.abs(z).max())


def test_linear_recurrence_blocked_equals_loop():
    rng = np.random.default_rng(0)
    M_ = rng.standard_normal((3, 3))
    M_ *= 0.97 / np.max(np.abs(np.linalg.eigvals(M_)))
    for n in (1, 31, 64, 65, 1000):
        U, x0 = rng.standard_normal((n, 3)), rng.standard_normal(3)
        X = np.empty((n, 3))
        xe = _linear_recurrence(M_, U, x0, X)
        x, ref = x0, np.empty((n, 3))
        for r in range(n):
            ref[r] = x
            x = M_ @ x + U[r]
        np.testing.assert_allclose(X, ref, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(xe, x, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("chunk_rows", [3, 17, 64, 100_000])
@pytest.mark.parametrize("ext", [".csv", ".parquet"])
def test_stream_equals_in_memory_for_any_chunking(tmp_path, steady, chunk_rows, ext):
    sc, ys, x = steady
    f = tmp_path / f"m{ext}"
    M.write_measurements(f, ys)
    buf, cbuf = io.BytesIO(), io.BytesIO()
    np.savez(tmp_path / "x.npz", x=x)
    summ = stream_filter(sc, f, buf, fmt=ext, truth=tmp_path / "x.npz", cost_out=cbuf, chunk_rows=chunk_rows, progress=False)
    read = pd.read_csv if ext == ".csv" else pd.read_parquet
    got = read(io.BytesIO(buf.getvalue()))
    ref = M.filter_log(sc, ys, truth=x)
    want = M.estimates_frame(ref.estimates, sc.n_agents)
    assert got[["step", "agent", "estimator"]].equals(want[["step", "agent", "estimator"]])
    np.testing.assert_allclose(got["z0"], want["z0"], rtol=1e-11, atol=1e-11 * np.abs(want["z0"]).max())
    for name, tot in summ.total_costs.items():
        assert tot == pytest.approx(ref.total_costs[name], rel=1e-10)
    costs = read(io.BytesIO(cbuf.getvalue()))
    np.testing.assert_allclose(costs[costs.estimator == "mtmse"]["cost"], ref.stage_costs["mtmse"], rtol=1e-9)
    assert summ.n_steps == 120 and summ.rows_in == 480


def test_stream_rows_out_of_order_within_a_step_are_fine_but_not_across_steps(tmp_path, steady):
    sc, ys, _ = steady
    f = tmp_path / "m.csv"
    M.write_measurements(f, [y[:5] for y in ys])
    df = pd.read_csv(f)
    df.iloc[[0, 1]] = df.iloc[[1, 0]].to_numpy()  # agents 1, 0 at step 0
    df.to_csv(f, index=False, float_format="%.17g")
    buf = io.BytesIO()
    stream_filter(sc, f, buf, fmt=".csv", progress=False, chunk_rows=3)
    df.iloc[[2, 8]] = df.iloc[[8, 2]].to_numpy()
    df.to_csv(f, index=False, float_format="%.17g")
    with pytest.raises(M.MeasurementFileError, match=r"row 4 \(line 5\), column 'step': step 0 after step 2.*sorted by step"):
        stream_filter(sc, f, io.BytesIO(), fmt=".csv", progress=False, chunk_rows=12)


def test_stream_errors_name_global_rows(tmp_path, steady):
    sc, ys, _ = steady
    f = tmp_path / "m.csv"
    M.write_measurements(f, [y[:10] for y in ys])
    lines = f.read_text().splitlines()
    lines[30] = lines[30].rsplit(",", 1)[0] + ",oops"
    f.write_text("\n".join(lines) + "\n")
    with pytest.raises(M.MeasurementFileError, match=r"row 30 \(line 31\), column 'y3': expected a number, found 'oops'"):
        stream_filter(sc, f, io.BytesIO(), fmt=".csv", progress=False, chunk_rows=8)
    lines[30] = lines[29]  # a duplicated (step, agent) across a chunk boundary
    f.write_text("\n".join(lines) + "\n")
    with pytest.raises(M.MeasurementFileError, match=r"duplicated \(step, agent\)"):
        stream_filter(sc, f, io.BytesIO(), fmt=".csv", progress=False, chunk_rows=8)


def test_stream_refuses_gaps_naming_the_first(tmp_path, steady):
    sc, ys, _ = steady
    yy = [y[:20].copy() for y in ys]
    yy[2][7, 1] = np.nan
    f = tmp_path / "m.parquet"
    M.write_measurements(f, yy)
    with pytest.raises(UnsupportedOperationError, match="agent 2 at step 7"):
        stream_filter(sc, f, io.BytesIO(), fmt=".parquet", progress=False)


def test_cli_streams_steady_state_and_leaves_nothing_on_failure(tmp_path, capsys, steady):
    sc, ys, x = steady
    f = tmp_path / "m.csv"
    M.write_measurements(f, ys)
    out = tmp_path / "z.csv"
    assert main(["filter", "platoon-4-steady", "--measurements", str(f), "--out", str(out), "--chunk-rows", "50", "--json"]) == 0
    assert '"streamed": true' in capsys.readouterr().out
    assert len(pd.read_csv(out)) == 120 * 4 * 3
    yy = [y.copy() for y in ys]
    yy[0][100] = np.nan
    M.write_measurements(f, yy)
    out2 = tmp_path / "z2.csv"
    assert main(["filter", "platoon-4-steady", "--measurements", str(f), "--out", str(out2), "--chunk-rows", "50"]) == 2
    assert "agent 0 at step 100" in capsys.readouterr().err
    assert not out2.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["m.csv", "z.csv"]
