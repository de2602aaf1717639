"""Recorded measurements: file formats, validation, `teamkf filter`, and exact filtering with gaps.

Independent references: the brute-force team oracle of tests/helpers.py (fed only the
components that exist), a plain Kalman filter written here that skips the missing rows, and
the Monte Carlo runtime path (same seed, same code path, bit for bit).
"""

from __future__ import annotations

from fractions import Fraction

import numpy as np
import pandas as pd
import pytest
import scipy.linalg as sla

import teamkf
from teamkf import CommGraph, design_centralized, design_mmse, design_mtmse
from teamkf.cli import main
from teamkf.exceptions import TeamkfError, UnsupportedOperationError
from teamkf.network.information import InformationStructure
from teamkf.simulation.monte_carlo import monte_carlo
from teamkf.simulation.sampling import RunStreams, sample_paths
from teamkf.study import measurements as M
from teamkf.study.scenario import Scenario, load_packaged
from tests.helpers import brute_force_team, eq14_information, random_cost, random_system

SEED = 20261123


def _scenario(system, cost, graph, horizon, estimators=("mtmse", "mmse", "centralized")):
    return Scenario(
        name="t",
        horizon=horizon,
        system=system,
        cost=cost,
        graph=graph,
        information=InformationStructure.from_graph(graph),
        estimators=tuple(estimators),
    )


def _with_gaps(rng, ys, p=0.3):
    out, present = [], []
    for y in ys:
        m = rng.random(y.shape) > p
        yy = y.copy()
        yy[~m] = np.nan
        out.append(yy)
        present.append(m)
    return out, present


# ---------------------------------------------------------------------------
# formats
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("ext", [".csv", ".parquet", ".npz"])
def test_round_trip_is_exact_with_gaps(tmp_path, ext):
    rng = np.random.default_rng(1)
    sys = random_system(rng, 3, 2, [1, 2, 3])
    ys = [rng.standard_normal((9, d)) for d in sys.dy]
    ys, _ = _with_gaps(rng, ys)
    ys[1][4] = np.nan  # a whole absent row
    f = tmp_path / f"m{ext}"
    M.write_measurements(f, ys)
    log = M.read_measurements(f, sys)
    assert log.n_steps == 9 and log.has_gaps
    for a, b in zip(ys, log.y):
        np.testing.assert_array_equal(a, b)  # NaN where missing, every value bit for bit


def test_absent_rows_and_n_steps(tmp_path):
    sys = random_system(np.random.default_rng(2), 2, 1, [1, 1])
    f = tmp_path / "m.csv"
    f.write_text("step,agent,y0\n0,0,1.5\n2,1,-2\n")
    log = M.read_measurements(f, sys)
    assert log.n_steps == 3
    np.testing.assert_array_equal(log.y[0][:, 0], [1.5, np.nan, np.nan])
    np.testing.assert_array_equal(log.y[1][:, 0], [np.nan, np.nan, -2.0])
    assert log.first_missing() == (1, 0)


# ---------------------------------------------------------------------------
# bad input: typed errors naming file, row and column
# ---------------------------------------------------------------------------
BAD_CSV = [
    ("step,agent,y0,y1\n0,0,1,2\n", "column 'y1'", "unknown column"),
    ("step,agent\n0,0\n", "column 'y0'", "missing"),
    ("step,agent,y0\n0,0,1\n0,5,2\n", "row 2 (line 3), column 'agent'", "unknown agent 5"),
    ("step,agent,y0\n0,0,1\n10,1,2\n", "row 2 (line 3), column 'step'", "beyond"),
    ("step,agent,y0\n0,0,1\n0,1,2\n0,0,3\n", "row 3 (line 4), column 'step'", "duplicated (step, agent) = (0, 0), first at row 1"),
    ("step,agent,y0\n0,0,1\n0,1,abc\n", "row 2 (line 3), column 'y0'", "expected a number, found 'abc'"),
    ("step,agent,y0\n0,0,1\n0,1,inf\n", "row 2 (line 3), column 'y0'", "finite"),
    ("step,agent,y0\n0,0,1\n1.5,1,2\n", "row 2 (line 3), column 'step'", "whole number"),
    ("step,agent,y0\n0,0,1\n-1,1,2\n", "row 2 (line 3), column 'step'", ">= 0"),
    ("", "", "empty"),
]


@pytest.mark.parametrize("text, where, what", BAD_CSV)
def test_bad_csv(tmp_path, text, where, what):
    sys = random_system(np.random.default_rng(3), 2, 1, [1, 1])
    f = tmp_path / "bad.csv"
    f.write_text(text)
    with pytest.raises(M.MeasurementFileError) as ei:
        M.read_measurements(f, sys, horizon=5)
    msg = str(ei.value)
    assert str(f) in msg and where in msg and what in msg, msg


def test_bad_values_for_smaller_agent(tmp_path):
    sys = random_system(np.random.default_rng(4), 2, 2, [1, 2])
    f = tmp_path / "bad.csv"
    f.write_text("step,agent,y0,y1\n0,0,1,7\n0,1,2,3\n")
    with pytest.raises(M.MeasurementFileError, match=r"row 1 \(line 2\), column 'y1'.*agent 0 has d_y = 1"):
        M.read_measurements(f, sys)


def test_bad_parquet_strings(tmp_path):
    sys = random_system(np.random.default_rng(5), 2, 1, [1, 1])
    f = tmp_path / "bad.parquet"
    pd.DataFrame({"step": [0, 0], "agent": [0, 1], "y0": ["1.0", "x"]}).to_parquet(f)
    with pytest.raises(M.MeasurementFileError, match=r"bad.parquet: row 2, column 'y0': expected a number, found 'x'"):
        M.read_measurements(f, sys)


@pytest.mark.parametrize(
    "arrays, match",
    [
        ({"agent0": np.zeros((3, 1))}, "key 'agent1'"),
        ({"agent0": np.zeros((3, 1)), "agent1": np.zeros((3, 2))}, r"agent 1: expected shape \(n_steps, 1\)"),
        ({"agent0": np.zeros((3, 1)), "agent1": np.zeros((4, 1))}, "agent 1: expected 3 steps"),
        ({"agent0": np.array([[0.0], [np.inf]]), "agent1": np.zeros((2, 1))}, "agent 0, step 1, column y0"),
        ({"agent0": np.array([["a"], ["b"]]), "agent1": np.zeros((2, 1))}, "key 'agent0': expected numbers"),
        ({"agent0": np.zeros((9, 1)), "agent1": np.zeros((9, 1))}, "beyond the scenario's horizon of 5"),
        ({"agent0": np.zeros((3, 1)), "agent1": np.zeros((3, 1)), "extra": np.zeros(1)}, "key 'extra'"),
    ],
)
def test_bad_npz(tmp_path, arrays, match):
    sys = random_system(np.random.default_rng(6), 2, 1, [1, 1])
    f = tmp_path / "bad.npz"
    np.savez(f, **arrays)
    with pytest.raises(M.MeasurementFileError, match=match):
        M.read_measurements(f, sys, horizon=5)


def test_bad_truth(tmp_path):
    f = tmp_path / "x.csv"
    f.write_text("step,x0\n0,1\n2,1\n")
    with pytest.raises(M.MeasurementFileError, match="step 1 has no row"):
        M.read_truth(f, 1, 3)
    f.write_text("step,x0,x1\n0,1,2\n")
    with pytest.raises(M.MeasurementFileError, match="column 'x1': unknown column"):
        M.read_truth(f, 1, 1)


# ---------------------------------------------------------------------------
# filter == Monte Carlo (runtime path), bit for bit, for every family of the registry
# ---------------------------------------------------------------------------
def runtime_estimates_or_filter(d, ys):
    """What the Monte Carlo ``path="runtime"`` computes for these runs."""
    from teamkf.estimators.base import UnsupportedOperationError
    from teamkf.simulation.monte_carlo import runtime_estimates

    try:
        return runtime_estimates(d, ys)[0]
    except UnsupportedOperationError:
        return d.filter([y[0] for y in ys])


def _family_designs(sc):
    out = {}
    for name in teamkf.families():
        try:
            out[name] = sc.design(name)
        except TeamkfError as exc:  # a family whose requirements this scenario does not meet
            out[name] = exc
    return out


@pytest.mark.parametrize("name", sorted(teamkf.families()))
def test_filter_equals_monte_carlo_bit_for_bit(tmp_path, name):
    sc = load_packaged("platoon-4").updated({"horizon": 25})
    d = _family_designs(sc)[name]
    if isinstance(d, Exception):
        pytest.skip(f"{name} cannot be designed for platoon-4: {d}")
    T, R = 25, 3
    mc = monte_carlo({name: d}, T, R, rng=SEED, batch=1, path="runtime")[name]
    streams = RunStreams(SEED)  # run r's counter-based stream, as the Monte Carlo draws it
    costs = np.empty((R, T))
    for r in range(R):
        p = sample_paths(sc.system, T, 1, rng=None, streams=streams, first_run=r)
        f, xf = tmp_path / f"y{r}.csv", tmp_path / f"x{r}.npz"
        M.write_measurements(f, [y[0] for y in p.y])
        np.savez(xf, x=p.x[0])
        log = M.read_measurements(f, sc.system, sc.horizon)
        res = M.filter_log(sc, log, estimators=[name], truth=M.read_truth(xf, sc.system.dx, T))
        costs[r] = res.stage_costs[name]
        # the estimates are the Monte Carlo runtime path's, bit for bit (the CSV round trip is exact)
        np.testing.assert_array_equal(res.estimates[name], runtime_estimates_or_filter(d, p.y))
        # Design.filter agrees (same arithmetic up to round-off; bit for bit for most)
        zf = d.filter([y[0] for y in p.y])
        np.testing.assert_allclose(res.estimates[name], zf, rtol=1e-10, atol=1e-10)
        # and L x - z agrees with the cancellation-free error recursion of the Monte Carlo "errors" path
        e = np.stack([p.x[0, k] @ sc.cost.L_at(k).T - res.estimates[name][k] for k in range(T)])
        np.testing.assert_allclose(e, d.errors(p)[0], rtol=1e-9, atol=1e-9)
    # the Monte Carlo sums the per-run costs exactly and rounds the mean once; filter --truth evaluates
    # e'Se with the same function (team_stage_costs), so the realized costs are the Monte Carlo's, bit for bit
    exact_mean = [float(sum(Fraction(float(c)) for c in costs[:, k]) / R) for k in range(T)]
    np.testing.assert_array_equal(np.array(exact_mean), mc.stage_mean)
    totals = costs.sum(axis=1)  # a run's total as the Monte Carlo forms it (batch = 1), then summed exactly
    assert float(sum(Fraction(float(t)) for t in totals) / R) == mc.total_mean


# ---------------------------------------------------------------------------
# missing measurements, exactly
# ---------------------------------------------------------------------------
def _random_instance(seed):
    rng = np.random.default_rng(seed)
    n = 3
    dx, dz = int(rng.integers(1, 4)), int(rng.integers(1, 3))
    dys = [int(rng.integers(1, 3)) for _ in range(n)]
    g = CommGraph.random(n, p=0.5, delays=(1, 3), rng=rng)
    sys = random_system(rng, n, dx, dys)
    cost = random_cost(rng, n, dx, dz)
    T = min(g.diameter + 3, 7)
    p = sample_paths(sys, T, 1, rng=seed)
    ys, present = _with_gaps(rng, [y[0] for y in p.y])
    ys[0][1] = np.nan  # agent 0 silent at step 1
    present[0][1] = False
    return rng, sys, cost, g, T, ys, present


@pytest.mark.parametrize("mmse", [False, True], ids=["mtmse", "mmse"])
@pytest.mark.parametrize("seed", range(5))
def test_gaps_equal_brute_force_oracle(seed, mmse):
    _, sys, cost, g, T, ys, present = _random_instance(900 + seed)
    name = "mmse" if mmse else "mtmse"
    sc = _scenario(sys, cost, g, T, (name,))
    res = M.filter_log(sc, ys)
    d = res.designs[name]
    z = res.estimates[name]
    dz = cost.dz
    for k in range(T):
        sets = [eq14_information(g, i, k) for i in range(sys.n_agents)]
        rows = {(j, s): present[j][s] for j in range(sys.n_agents) for s in range(k + 1)}
        J, F = brute_force_team(sys, cost, sets, k, mmse=mmse, rows=rows)
        assert d.stage_costs[k] == pytest.approx(J, rel=1e-8, abs=1e-10), k
        for i in range(sys.n_agents):
            Yi = np.concatenate([ys[j][s][present[j][s]] for (j, s) in sorted(sets[i])] or [np.zeros(0)])
            zi = F[i] @ Yi
            np.testing.assert_allclose(z[k, i * dz : (i + 1) * dz], zi, rtol=1e-8, atol=1e-8 * (1 + np.abs(zi).max()))


def _plain_kf_skipping(sys, ys, present, L):
    """A textbook Kalman filter that, at every step, stacks only the components that exist."""
    n, dx, T = sys.n_agents, sys.dx, ys[0].shape[0]
    x, P = np.zeros(dx), np.array(sys.Sigma_x)
    out = []
    for k in range(T):
        C = np.vstack([sys.C_at(i, k)[present[i][k]] for i in range(n)])
        R = sla.block_diag(*[sys.R_at(i, k)[np.ix_(present[i][k], present[i][k])] for i in range(n)])
        y = np.concatenate([ys[i][k][present[i][k]] for i in range(n)])
        if y.size:
            K = P @ C.T @ np.linalg.inv(C @ P @ C.T + R)
            x = x + K @ (y - C @ x)
            P = (np.eye(dx) - K @ C) @ P
        out.append(L @ x)
        x, P = sys.A_at(k) @ x, sys.A_at(k) @ P @ sys.A_at(k).T + sys.Q_at(k)
    return np.array(out)


@pytest.mark.parametrize("seed", range(5))
def test_centralized_with_gaps_equals_kf_that_skips_rows(seed):
    _, sys, cost, g, T, ys, present = _random_instance(950 + seed)
    sc = _scenario(sys, cost, g, T, ("centralized",))
    z = M.filter_log(sc, ys).estimates["centralized"]
    ref = _plain_kf_skipping(sys, ys, present, cost.L_at(0))
    np.testing.assert_allclose(z, ref, rtol=1e-10, atol=1e-10 * (1 + np.abs(ref).max()))


def test_gaps_equal_removed_rows_design_cost():
    """Masking every component of one agent at every step equals the model without that agent's rows."""
    rng = np.random.default_rng(7)
    sys = random_system(rng, 2, 2, [2, 1])
    cost = random_cost(rng, 2, 2, 1)
    present = [np.ones((5, 2), bool), np.ones((5, 1), bool)]
    present[0][:, 1] = False  # component 1 of agent 0 never exists
    sysm = M.masked_system(sys, present)
    reduced = teamkf.LinearGaussianSystem(
        A=sys.A[0], Q=sys.Q[0], Sigma_x=sys.Sigma_x, C=[sys.C[0][0][:1], sys.C[1][0]], R=[sys.R[0][0][:1, :1], sys.R[1][0]]
    )
    g = CommGraph.complete(2, delay=1)
    for design in (design_mtmse, design_mmse):
        np.testing.assert_allclose(design(sysm, cost, g, horizon=5).stage_costs, design(reduced, cost, g, horizon=5).stage_costs, rtol=1e-10)
    np.testing.assert_allclose(
        design_centralized(sysm, cost, horizon=5).stage_costs, design_centralized(reduced, cost, horizon=5).stage_costs, rtol=1e-10
    )


def test_family_without_gap_support_names_first_missing():
    sc = load_packaged("platoon-4").updated({"horizon": 10})
    p = sample_paths(sc.system, 10, 1, rng=1)
    ys = [y[0].copy() for y in p.y]
    ys[2][4, 1] = np.nan
    ys[3][6] = np.nan
    with pytest.raises(UnsupportedOperationError, match=r"kcf.*agent 2 at step 4") as ei:
        M.filter_log(sc, ys, estimators=["kcf"])
    assert ei.value.family == "kcf"


# ---------------------------------------------------------------------------
# the command
# ---------------------------------------------------------------------------
def test_cli_filter_end_to_end(tmp_path, capsys):
    sc = load_packaged("platoon-4")
    p = sample_paths(sc.system, 12, 1, rng=3)
    ys = [y[0].copy() for y in p.y]
    ys[1][2] = np.nan
    M.write_measurements(tmp_path / "m.parquet", ys)
    pd.DataFrame({"step": np.arange(12), **{f"x{c}": p.x[0, :, c] for c in range(4)}}).to_csv(tmp_path / "x.csv", index=False, float_format="%.17g")
    out = tmp_path / "z.csv"
    rc = main(["filter", "platoon-4", "--measurements", str(tmp_path / "m.parquet"), "--truth", str(tmp_path / "x.csv"), "--out", str(out), "--json"])
    assert rc == 0, capsys.readouterr().err
    z = pd.read_csv(out)
    assert list(z.columns) == ["step", "agent", "estimator", "z0"] and len(z) == 12 * 4 * 3
    res = M.filter_log(sc, ys, truth=p.x[0])
    got = z[z.estimator == "mtmse"].sort_values(["step", "agent"])["z0"].to_numpy()
    np.testing.assert_array_equal(got, res.estimates["mtmse"].ravel())
    cost = pd.read_csv(tmp_path / "z-cost.csv")
    np.testing.assert_array_equal(cost[cost.estimator == "centralized"]["cost"].to_numpy(), res.stage_costs["centralized"])


@pytest.mark.parametrize(
    "bad, match",
    [
        ("step,agent,y0,y1,y2,y3\n0,9,1,2,3,4\n", "unknown agent 9"),
        ("step,agent,y0,y1,y2,y3\n0,0,1,2,3,nope\n", "column 'y3': expected a number"),
    ],
)
def test_cli_filter_failure_writes_nothing(tmp_path, capsys, bad, match):
    f = tmp_path / "m.csv"
    f.write_text(bad)
    out = tmp_path / "z.csv"
    rc = main(["filter", "platoon-4", "--measurements", str(f), "--out", str(out)])
    assert rc == 2
    assert match in capsys.readouterr().err
    assert not out.exists() and list(tmp_path.iterdir()) == [f]


def test_cli_filter_bad_out_suffix_and_unknown_estimator(tmp_path, capsys):
    f = tmp_path / "m.npz"
    M.write_measurements(f, [np.zeros((3, 4))] * 4)
    assert main(["filter", "platoon-4", "--measurements", str(f), "--out", str(tmp_path / "z.txt")]) == 2
    assert "--out" in capsys.readouterr().err
    assert main(["filter", "platoon-4", "--measurements", str(f), "--out", str(tmp_path / "z.csv"), "--estimators", "mtmsee"]) == 2
    assert "did you mean 'mtmse'" in capsys.readouterr().err
    assert not (tmp_path / "z.csv").exists()
