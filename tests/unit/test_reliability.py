"""Regression tests of issue 10: no traceback, no silent nonsense, no non-finite number without a word.

One test (or a few) per case of the issue; the bad-input table is
``test_bad_inputs.py``, the long-horizon checks ``test_long_horizon.py``.
"""

from __future__ import annotations

import json
import time
import warnings
from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import teamkf
from teamkf import _progress, _resources
from teamkf.cli import main
from teamkf.estimators.bulk import DIVERGENCE_RATIO, PRECISION_FLOOR, exact_bulk_filter, finite_memory_filter
from teamkf.exceptions import ArgumentError, DivergenceError
from teamkf.models.population import PopulationModel
from teamkf.study.population import evaluate_population
from teamkf.study.scenario import load_packaged, packaged_scenarios

ROOT = Path(__file__).resolve().parents[2]


def _one_error(capsys: Any) -> str:
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("teamkf: error: "), err
    return lines[0]


# ---------------------------------------------------------------------------
# the bulk filter of an unstable closed loop
# ---------------------------------------------------------------------------
def _exact_gains_open_loop(T: int, a: Fraction, N: int) -> np.ndarray:
    """K_T of the exact filter with f = 0 (no feedback), in exact rational arithmetic: an independent oracle.

    With f = 0 the closed loop does not depend on the filter, so K_T = Cov(x_T, Y) Cov(Y)^{-1} with
    x_{k+1,i} = a x_{k,i} + w, y_{k,i} = x_{k,i} + m_k + v_{k,i} (c = h = 1, unit noises, Var x_0 = 1,
    y_1 the first measurement, of x_1), Cov(x_{s,i}, x_{t,j}) = 0 for i != j and m = mean_j x_j:
    Cov(y_s, y_t) = X(s, t) (1 + 3/N) + [s = t], Cov(x_T, y_t) = X(T, t) (1 + 1/N).
    """
    V = [Fraction(0)] * (T + 1)
    V[1] = a * a + 1
    for k in range(2, T + 1):
        V[k] = a * a * V[k - 1] + 1
    X = [[a ** abs(t - s) * V[min(s, t)] for t in range(1, T + 1)] for s in range(1, T + 1)]
    M = [[X[s][t] * (1 + Fraction(3, N)) + (1 if s == t else 0) for t in range(T)] + [X[T - 1][s] * (1 + Fraction(1, N))] for s in range(T)]
    for i in range(T):  # Gaussian elimination, exact
        for j in range(i + 1, T):
            f = M[j][i] / M[i][i]
            if f:
                M[j] = [mj - f * mi for mj, mi in zip(M[j], M[i])]
    x = [Fraction(0)] * T
    for i in reversed(range(T)):
        x[i] = (M[i][T] - sum(M[i][k] * x[k] for k in range(i + 1, T))) / M[i][i]
    return np.array([float(v) for v in x])


def test_open_loop_oracle_matches_the_stable_regime() -> None:
    m = PopulationModel(n_agents=1000, a=1.5, f=0.0)
    np.testing.assert_allclose(exact_bulk_filter(m, 8).final_gains(), _exact_gains_open_loop(8, Fraction(3, 2), 1000), rtol=0, atol=1e-12)


@pytest.mark.parametrize("a, f", [(1.5, 0.0), (1.05, 0.0)])
def test_exact_bulk_filter_unstable_names_the_step(a: float, f: float) -> None:
    m = PopulationModel(n_agents=1000, a=a, f=f)
    with pytest.raises(DivergenceError) as info:
        exact_bulk_filter(m, 2000)
    err = info.value
    assert err.argument == "horizon" and "step" in str(err) and "last reliable horizon" in str(err)
    k = int(str(err).split("the last reliable horizon is ")[1].split(":")[0])
    exact_bulk_filter(m, k)  # up to the last reliable step the filter runs
    if a == 1.5:  # and its gains there still have 4 digits (exact rational oracle)
        np.testing.assert_allclose(
            exact_bulk_filter(m, k).final_gains(), _exact_gains_open_loop(k, Fraction(3, 2), 1000), rtol=0, atol=PRECISION_FLOOR
        )
    # a stable closed loop never stops
    assert np.all(np.isfinite(exact_bulk_filter(PopulationModel(n_agents=1000, a=2.5, f=2.0), 2000).covariances.state_variance))


def test_finite_memory_flags_divergence_before_it_loses_its_digits() -> None:
    m = PopulationModel(n_agents=1000, a=1.5, f=0.0)
    k = finite_memory_filter(m, 60, 60).diverged_at
    assert k is not None
    before = finite_memory_filter(m, k - 1, k - 1)
    assert before.diverged_at is None
    np.testing.assert_allclose(before.final_gains(), _exact_gains_open_loop(k - 1, Fraction(3, 2), 1000), rtol=0, atol=PRECISION_FLOOR)


def test_population_unstable_cli_and_evaluate(tmp_path: Path, capsys: Any) -> None:
    p = tmp_path / "u.toml"
    p.write_text('name = "u"\nhorizon = 500\n[population]\nn_agents = 1000\na = 1.05\nf = 0.0\n')
    assert main(["evaluate", str(p)]) == 2
    line = _one_error(capsys)
    assert "horizon: the exact bulk filter loses its precision at step" in line
    with pytest.raises(DivergenceError):
        evaluate_population(PopulationModel.from_af(1000, 1.5, 1.3), 1000)


def test_exact_filter_of_a_diverging_loop_is_flagged(tmp_path: Path, capsys: Any) -> None:
    """a = 2.5, a_f = 1.3 keeps its precision (the innovation variance grows too) but the loop diverges: flagged, warned."""
    m = PopulationModel.from_af(1000, 2.5, 1.3)
    out = evaluate_population(m, 300)
    sv = np.asarray(out["state_variance_trajectory"])
    k = out["diverged_at"]
    limit = DIVERGENCE_RATIO * max(m.q, m.r_v, m.p0)
    assert out["diverged"] is True and sv[k] > limit and np.all(sv[:k] <= limit)
    p = tmp_path / "d.toml"
    p.write_text('name = "d"\nhorizon = 300\n[population]\nn_agents = 1000\na = 2.5\na_f = 1.3\n')
    assert main(["evaluate", str(p), "--json"]) == 0
    cap = capsys.readouterr()
    assert json.loads(cap.out)["diverged_at"] == k and f"from step {k}" in cap.err


def test_finite_memory_diverged_at() -> None:
    """The issue's case a = 8, f = 7.6, memory 50: Var x_T = 8e65 was reported with diverged_at = None."""
    m = PopulationModel(n_agents=100, a=8.0, f=7.6, memory=50)
    fm = finite_memory_filter(m, 1000)
    k = fm.diverged_at
    assert k is not None
    sv = fm.covariances.state_variance
    limit = DIVERGENCE_RATIO * max(m.q, m.r_v, m.p0)
    assert np.all(np.isfinite(sv[:k])) and np.all(sv[:k] <= limit) and np.all(np.isnan(sv[k + 1 :]))
    assert np.all(np.isnan(fm.gains()[k:]))
    # a stabilizing memory keeps diverged_at None
    assert finite_memory_filter(PopulationModel(n_agents=100, a=2.5, f=2.0, memory=10), 1000).diverged_at is None


def test_finite_memory_divergence_in_json(tmp_path: Path, capsys: Any) -> None:
    p = tmp_path / "fm.toml"
    p.write_text('name = "fm"\nhorizon = 1000\n[population]\nn_agents = 100\na = 8.0\nf = 7.6\nmemory = 50\n')
    assert main(["evaluate", str(p), "--json"]) == 0
    cap = capsys.readouterr()
    out = json.loads(cap.out, parse_constant=lambda c: pytest.fail(f"non-strict JSON token {c}"))
    assert out["diverged"] is True and out["state_variance"] is None and isinstance(out["diverged_at"], int)
    assert "teamkf: warning: memory-50 filter: the closed loop diverges" in cap.err
    assert main(["evaluate", str(p)]) == 0
    assert "diverged" in capsys.readouterr().out


# ---------------------------------------------------------------------------
# sweeps over population scenarios
# ---------------------------------------------------------------------------
def test_sweep_over_a_population_scenario(tmp_path: Path, capsys: Any) -> None:
    pytest.importorskip("pyarrow")
    sw = tmp_path / "pop.toml"
    sw.write_text('name = "pop"\nscenario = "interference"\n[grid]\n"population.a" = [2.0, 2.5]\n"horizon" = [200]\n')
    out = tmp_path / "pop.parquet"
    assert main(["sweep", str(sw), "--scheduler", "serial", "--out", str(out), "--no-progress", "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    rows = {r["population.a"]: r for r in res["rows"]}
    assert set(rows) == {2.0, 2.5} and all(r["estimator"] == "bulk" and r["method"] == "exact" for r in rows.values())
    base = load_packaged("interference").model
    for a, r in rows.items():
        want = evaluate_population(base.with_(a=a) if hasattr(base, "with_") else PopulationModel(n_agents=base.n_agents, a=a, f=base.f), 200)
        assert r["average_cost"] == pytest.approx(want["average_cost"], rel=1e-12)


# ---------------------------------------------------------------------------
# Monte Carlo: sizes, seeds, batches
# ---------------------------------------------------------------------------
def test_monte_carlo_run_counts_beyond_the_streams_refused_up_front(capsys: Any) -> None:
    """Monte Carlo streams (memory does not grow with the runs, issue 13); only counts beyond the 2^63 run streams are refused."""
    t = time.perf_counter()
    assert main(["evaluate", "platoon-4", "--monte-carlo", str(2**63 + 1)]) == 2
    line = _one_error(capsys)
    assert time.perf_counter() - t < 30
    assert line.startswith("teamkf: error: --monte-carlo: expected at most 2^63 runs")


def test_check_memory_and_estimates(monkeypatch: Any) -> None:
    _resources.check_memory(1e6, "x", argument="a", fix="f", available=10**9)
    with pytest.raises(ArgumentError, match=r"^a: x needs about 953.7 MiB of memory, but this machine has 9.5 MiB available; f"):
        _resources.check_memory(1e9, "x", argument="a", fix="f", available=10**7)
    monkeypatch.setattr(_resources, "available_memory", lambda: 50 * 2**20)
    sc = load_packaged("platoon-4")
    with pytest.raises(ArgumentError, match="horizon: the MTMSE design over T = 100000 steps .* needs about"):
        teamkf.design_mtmse(sc.system, sc.cost, sc.graph, 100000)
    with pytest.raises(ArgumentError, match="horizon: the exact bulk filter over T = 20000 steps"):
        exact_bulk_filter(PopulationModel(n_agents=10, a=2.5, f=2.0), 20000)
    assert _resources.available_memory() is not None


def test_rng_batch_and_nan_measurements_name_the_argument() -> None:
    sc = load_packaged("platoon-4")
    with pytest.raises(ArgumentError, match="^rng: expected an integer seed"):
        teamkf.sample(sc.system, 5, 2, rng=-1)
    d = sc.designs(("mtmse",))["mtmse"]
    with pytest.raises(ArgumentError, match="^batch: "):
        teamkf.monte_carlo({"mtmse": d}, 5, 4, rng=1, batch=0)
    _, y = teamkf.sample(sc.system, 10, 2, rng=1)
    y[2][1, 6, 3] = np.nan
    with pytest.raises(ArgumentError, match=r"^measurements\[2\]: .* for agent 2 at step 6, run 1"):
        teamkf.run_online(d.agents(), y)
    with pytest.raises(ArgumentError, match=r"for agent 2 at step 6 \(component 3\)"):
        d.filter([yi[1] for yi in y])


# ---------------------------------------------------------------------------
# the command line: schedulers, workers, help, JSON
# ---------------------------------------------------------------------------
def test_every_reproduction_uses_or_refuses_the_scheduler(capsys: Any) -> None:
    import inspect

    from teamkf import experiments

    names = experiments.names()
    users = [n for n in names if experiments.get(n).uses_scheduler]
    assert users and len(users) < len(names)
    for n in names:
        exp = experiments.get(n)
        src = inspect.getsource(inspect.getmodule(exp.func))  # type: ignore[arg-type]
        assert exp.uses_scheduler == ("map_points(" in src), n
        if not exp.uses_scheduler:
            assert main(["reproduce", n, "--scheduler", "local"]) == 2
            assert "--scheduler: the reproduction" in _one_error(capsys)


def test_workers_with_serial_scheduler_warned(tmp_path: Path, capsys: Any) -> None:
    pytest.importorskip("pyarrow")
    sw = tmp_path / "s.toml"
    sw.write_text('scenario = "platoon-4"\n[grid]\n"cost.lambda" = [1.0]\n"horizon" = [5]\n')
    assert main(["sweep", str(sw), "--scheduler", "serial", "--workers", "3", "--out", str(tmp_path / "o"), "--no-progress"]) == 0
    assert "teamkf: warning: --workers is ignored with --scheduler serial" in capsys.readouterr().err


def test_help_lists_every_packaged_scenario_and_family(capsys: Any) -> None:
    teamkf.register_family(name="helpcheck", design=lambda *a, **k: None, title="a family registered by a test")
    try:
        assert main(["--help"]) == 0
        text = capsys.readouterr().out
    finally:
        teamkf.unregister_family("helpcheck")
    for name in packaged_scenarios():
        assert name in text, name
    import re

    for name in [*teamkf.families(), "helpcheck"]:
        assert re.search(rf"^\s+{name}\s", text, re.M), name


def test_reproduce_json_is_strict(capsys: Any) -> None:
    assert main(["reproduce", "fig1", "--quick", "--json"]) == 0
    out = json.loads(capsys.readouterr().out, parse_constant=lambda c: pytest.fail(f"non-strict JSON token {c}"))
    inf_rows = [r for r in out["rows"] if "non_finite" in r]
    assert inf_rows and inf_rows[0]["non_finite"] == {"lambda": "inf"} and inf_rows[0]["lambda"] is None


def test_usage_errors_are_one_line(capsys: Any) -> None:
    for argv, head in (
        (["evaluate"], "SCENARIO: "),
        (["evaluate", "platoon-4", "--monte-carlo", "x"], "--monte-carlo: "),
        (["frobnicate"], "COMMAND: "),
    ):
        assert main(argv) == 2
        assert _one_error(capsys).startswith(f"teamkf: error: {head}")


def test_diverging_kcf_on_uav10_no_warnings_and_readable_table(tmp_path: Path, capsys: Any) -> None:
    """The unstable UAV formation: overflow is expected inside the KCF recursions and must not reach the user."""
    text = (ROOT / "src" / "teamkf" / "scenarios" / "uav-10.toml").read_text()
    text = text.replace('estimators = ["mtmse", "mmse", "centralized"]', 'estimators = ["mtmse", "kcf"]')
    p = tmp_path / "uav.toml"
    p.write_text(text)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert main(["evaluate", str(p), "--monte-carlo", "20", "--seed", "1"]) == 0
    out = capsys.readouterr().out
    assert max(len(w) for w in out.split()) < 25, out  # no 40-digit percentages
    assert "e+" in out


# ---------------------------------------------------------------------------
# progress of long computations
# ---------------------------------------------------------------------------
def test_progress_bar_after_delay(monkeypatch: Any, capsys: Any) -> None:
    pytest.importorskip("tqdm")
    sc = load_packaged("platoon-4")
    monkeypatch.setattr(_progress, "DELAY", 0.0)
    teamkf.design_mtmse(sc.system, sc.cost, sc.graph, 30, progress=True)
    assert "mtmse design" in capsys.readouterr().err
    exact_bulk_filter(PopulationModel(n_agents=10, a=2.5, f=2.0), 30, progress=True)
    assert "bulk filter" in capsys.readouterr().err
    teamkf.design_mtmse(sc.system, sc.cost, sc.graph, 30, progress=False)
    teamkf.design_mtmse(sc.system, sc.cost, sc.graph, 30)  # not a terminal under pytest: silent
    assert capsys.readouterr().err == ""


def test_docs_name_every_key() -> None:
    from teamkf.study.evaluate import DEFAULT_MC_RUNS

    doc = (ROOT / "docs" / "scenario-and-cli.md").read_text()
    for word in ("system.A_scale", "a_f", "`r`", "cdma", "default delay", f"{DEFAULT_MC_RUNS} runs", "multiple of n"):
        assert word in doc, word
    for kind in ("average", "platoon", "ring", "mse"):
        assert f"`{kind}`" in doc, kind


def test_overflowing_model_is_flagged_not_printed_as_nan(tmp_path: Path, capsys: Any) -> None:
    """An A entry of 1e200: every cost is reported as diverged (null in JSON) with a warning naming the estimator and step."""
    text = (ROOT / "src" / "teamkf" / "scenarios" / "platoon-4.toml").read_text()
    text = text.replace("[0.7, 0.9, 0.0, 0.0]", "[1e200, 0.9, 0.0, 0.0]").replace("horizon = 100 ", "horizon = 10 ")
    text = text.replace('estimators = ["mtmse", "mmse", "centralized"]', 'estimators = ["mtmse", "centralized", "kcf"]')
    p = tmp_path / "big.toml"
    p.write_text(text + '\n[kcf]\nvariant = "stale"\n')  # the KCF without delay compensation runs (and diverges) by Monte Carlo
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no numpy RuntimeWarning reaches the user
        assert main(["evaluate", str(p), "--json", "--monte-carlo", "4", "--seed", "1"]) == 0
        cap = capsys.readouterr()
        out = json.loads(cap.out, parse_constant=lambda c: pytest.fail(f"non-strict JSON token {c}"))
        for name in ("mtmse", "centralized", "kcf"):
            assert out["estimators"][name]["diverged"] is True
            assert f"teamkf: warning: {name}: the team cost diverges (not finite) from step" in cap.err
        assert main(["evaluate", str(p)]) == 0
        assert "diverged" in capsys.readouterr().out
        assert main(["design", str(p)]) == 0
        assert "teamkf: warning: mtmse: the team cost diverges" in capsys.readouterr().err
    # CIKF cannot design gains past the overflow: a typed error (DivergenceError) naming the family
    q = tmp_path / "bigc.toml"
    q.write_text(text.replace('"kcf"]', '"cikf"]'))
    assert main(["evaluate", str(q)]) == 2
    line = _one_error(capsys)
    assert "CIKF" in line and "diverge" in line, line
    # a delay-compensated baseline cannot propagate past the overflow either: a typed error naming the family
    h = tmp_path / "bigh.toml"
    h.write_text(text.replace('"kcf"]', '"diffusion"]').replace('kind = "line"\ndelay = 1', 'kind = "line"\ndelay = 2'))
    rc = main(["evaluate", str(h)])
    err = capsys.readouterr().err
    assert rc == 0 or ("diverge" in err and err.count("\n") == 1), err
