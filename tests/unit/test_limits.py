"""Reliability round 4: every environment setting validated, every command sized against the work limit before it starts.

* every ``TEAMKF_*`` variable teamkf reads: a bad value is one line naming it (exit 2), never ignored;
* ``filter`` (also ``--drops`` and streamed), ``reproduce``, ``deploy`` and ``agent`` refuse work above the
  limit (``TEAMKF_MAX_HOURS`` / ``--max-hours``) before it starts;
* a 10⁴-agent team is refused by its size check; the drop-aware design is sized before it allocates;
* deploy deadlines and timeouts that cannot work are refused.
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from teamkf import _budget, _validation, scenario_from_dict
from teamkf.cli import main
from teamkf.exceptions import ArgumentError, ResourceError, ScenarioError
from teamkf.study import _limits, _size
from teamkf.study import measurements as M

GIB = 1024**3


def _err(capsys: Any) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("teamkf: error: "), err
    return err


# ---------------------------------------------------------------------------
# environment settings
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("value", ["abc", "-1", "nan", "0", "inf", "-inf", "1e999"])
def test_bad_max_hours_is_one_line_never_ignored(monkeypatch: Any, capsys: Any, value: str) -> None:
    monkeypatch.setenv("TEAMKF_MAX_HOURS", value)
    assert main(["families"]) == 2
    err = _err(capsys)
    assert f"TEAMKF_MAX_HOURS: expected a positive number of hours (e.g. 24), found {value!r}" in err
    if value in ("inf", "1e999"):
        assert "for no practical limit use a large number (1e6)" in err
    with pytest.raises(ArgumentError, match="TEAMKF_MAX_HOURS"):  # in Python too, where the limit is read
        _budget.work_limit_s()


def test_max_hours_flag_overrides_a_bad_variable(monkeypatch: Any, capsys: Any) -> None:
    monkeypatch.setenv("TEAMKF_MAX_HOURS", "abc")
    assert main(["--max-hours", "3", "families"]) == 0
    monkeypatch.setenv("TEAMKF_MAX_HOURS", "1e6")
    assert _budget.work_limit_s() == 3.6e9


@pytest.mark.parametrize(
    ("name", "value", "expected"),
    [
        ("TEAMKF_PROGRESS", "maybe", "TEAMKF_PROGRESS: expected one of 0/false/no/off/1/true/yes/on, found 'maybe'"),
        ("TEAMKF_WORKERS", "0", "TEAMKF_WORKERS: expected a whole number >= 1, found '0'"),
        ("TEAMKF_WORKERS", "four", "TEAMKF_WORKERS: expected a whole number >= 1, found 'four'"),
        ("TEAMKF_PLUGINS", "a\0b", "TEAMKF_PLUGINS: expected module names or .py files"),
    ],
)
def test_bad_settings_are_one_line(monkeypatch: Any, capsys: Any, name: str, value: str, expected: str) -> None:
    if "\0" in value:  # the OS refuses NUL in the environment: check the reader directly
        monkeypatch.setattr(os, "environ", {name: value})
        with pytest.raises(ArgumentError, match=expected):
            _validation.check_environment()
        return
    monkeypatch.setenv(name, value)
    assert main(["families"]) == 2
    assert expected in _err(capsys)


def test_cache_dir_naming_a_file_is_refused(monkeypatch: Any, capsys: Any, tmp_path: Path) -> None:
    f = tmp_path / "file"
    f.write_text("x")
    monkeypatch.setenv("TEAMKF_CACHE_DIR", str(f))
    assert main(["families"]) == 2
    assert "TEAMKF_CACHE_DIR: expected a folder (or off/0/none/no)" in _err(capsys)
    for ok in ("off", str(tmp_path), ""):
        monkeypatch.setenv("TEAMKF_CACHE_DIR", ok)
        assert main(["families"]) == 0


def test_progress_values_and_a_misspelled_variable(monkeypatch: Any, capsys: Any) -> None:
    for ok in ("0", "off", "YES", "1", ""):
        monkeypatch.setenv("TEAMKF_PROGRESS", ok)
        assert main(["families"]) == 0
    for name in ("TEAMKF_RUNS", "TEAMKF_T", "TEAMKF_SOMETHING"):  # the examples' variables, and names not close to a setting
        monkeypatch.setenv(name, "3")
    capsys.readouterr()
    assert main(["families"]) == 0
    assert "warning" not in capsys.readouterr().err
    monkeypatch.setenv("TEAMKF_MAX_HOUR", "3")
    assert main(["families"]) == 0
    assert (
        "teamkf: warning: TEAMKF_MAX_HOUR is not a setting teamkf reads, so it is ignored; did you mean TEAMKF_MAX_HOURS?" in capsys.readouterr().err
    )


# ---------------------------------------------------------------------------
# every command applies the work limit before it starts
# ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def log4(tmp_path_factory: Any) -> tuple[Path, Path]:
    """platoon-4 (horizon 100), a 20-step log."""
    from teamkf.simulation.sampling import sample_paths
    from teamkf.study.scenario import load_packaged

    sc = load_packaged("platoon-4")
    paths = sample_paths(sc.system, 20, 1, rng=1)
    d = tmp_path_factory.mktemp("limits")
    M.write_measurements(d / "log.csv", [y[0] for y in paths.y])
    return d, d / "log.csv"


def _no_work(monkeypatch: Any) -> None:
    """Any design would fail the test: the refusal must come before it."""
    from teamkf.estimators import registry

    def boom(*a: Any, **k: Any) -> Any:
        raise AssertionError("a design ran before the work limit was checked")

    monkeypatch.setattr(registry.Family, "build", boom)


def test_filter_applies_the_limit(monkeypatch: Any, capsys: Any, log4: Any) -> None:
    d, log = log4
    monkeypatch.setenv("TEAMKF_MAX_HOURS", "1e-9")
    _no_work(monkeypatch)
    assert main(["filter", "platoon-4", "--measurements", str(log), "--out", str(d / "e.csv")]) == 2
    err = _err(capsys)
    assert "--measurements: teamkf filter:" in err and "over T = 20 steps" in err and "--max-hours H" in err
    assert not (d / "e.csv").exists()


def test_streamed_filter_applies_the_limit(monkeypatch: Any, capsys: Any, log4: Any) -> None:
    d, log = log4
    monkeypatch.setenv("TEAMKF_MAX_HOURS", "1e-9")
    _no_work(monkeypatch)
    assert main(["filter", "platoon-4-steady", "--measurements", str(log), "--out", str(d / "s.csv")]) == 2
    assert "steady-state estimator(s) over a" in _err(capsys)


def test_filter_drops_applies_the_limit(monkeypatch: Any, capsys: Any, log4: Any) -> None:
    from teamkf.deploy import DropRecord

    d, log = log4
    rec = DropRecord("kcf", 4, 20)
    rec.write(d / "drops.json")
    monkeypatch.setenv("TEAMKF_MAX_HOURS", "1e-9")
    _no_work(monkeypatch)
    assert main(["filter", "platoon-4", "--measurements", str(log), "--drops", str(d / "drops.json"), "--out", str(d / "r.csv")]) == 2
    assert "teamkf filter --drops:" in _err(capsys)


def test_reproduce_applies_the_limit(monkeypatch: Any, capsys: Any) -> None:
    from teamkf import experiments

    monkeypatch.setenv("TEAMKF_MAX_HOURS", "1e-9")
    import dataclasses

    monkeypatch.setitem(experiments._REGISTRY, "fig5", dataclasses.replace(experiments.get("fig5"), func=None))  # never called
    assert main(["reproduce", "fig5", "--quick"]) == 2
    err = _err(capsys)
    assert "fig5: the reproduction 'fig5' (--quick) needs at least" in err and "--max-hours H" in err
    monkeypatch.setenv("TEAMKF_MAX_HOURS", "0.5")  # 30 minutes: the full leaderboard-drops (>= 100 s) fits, ...
    experiments._check_work("leaderboard-drops", False)
    monkeypatch.setenv("TEAMKF_MAX_HOURS", "0.01")  # ... 36 s does not
    with pytest.raises(ResourceError, match="run the smaller version with --quick"):
        experiments._check_work("leaderboard-drops", False)


def test_deploy_applies_the_limit(monkeypatch: Any, capsys: Any, log4: Any) -> None:
    d, log = log4
    monkeypatch.setenv("TEAMKF_MAX_HOURS", "1e-9")
    _no_work(monkeypatch)
    assert main(["deploy", "platoon-4", "--measurements", str(log), "--out", str(d / "dep.csv"), "--transport", "queue"]) == 2
    assert "teamkf deploy: 4 agents over T = 20 steps" in _err(capsys)


def test_agent_applies_the_limit_and_checks_steps(monkeypatch: Any, capsys: Any, log4: Any) -> None:
    d, log = log4
    roster = d / "roster.toml"
    roster.write_text('run_id = 1\nprefix = "t"\n' + "".join(f'[[agents]]\nid = {i}\nendpoint = "tcp/127.0.0.1:{7450 + i}"\n' for i in range(4)))
    _no_work(monkeypatch)
    base = ["agent", "platoon-4", "--id", "0", "--roster", str(roster), "--measurements", "-", "--insecure"]
    assert main([*base, "--steps", "0"]) == 2
    assert "--steps: expected a number of steps, an integer >= 1, found 0" in _err(capsys)
    assert main([*base, "--steps", str(10**15)]) == 2  # huge: its work exceeds the limit
    assert "--steps: teamkf agent 0: 4 agents over T = 1,000,000,000,000,000 steps needs at least" in _err(capsys)
    assert main([*base, "--steps", str(10**5)]) == 2  # fits the work limit, but not its worst case: 10^5 x 2 s
    assert "--deadline: the run's worst case, 60 s to join + 100,000 steps x 2 s = 2.3 days" in _err(capsys)
    monkeypatch.setenv("TEAMKF_MAX_HOURS", "1e-9")
    assert main([*base, "--deadline", "1e-3", "--join-timeout", "1e-3"]) == 2  # the horizon (100 steps)
    assert "teamkf agent 0: 4 agents over T = 100 steps" in _err(capsys)


@pytest.mark.parametrize(
    ("flags", "expected"),
    [
        (["--deadline", "1e-300"], "--deadline: expected at least 0.001 s (1 ms; heartbeats run every deadline / 4), found 1e-300"),
        (["--join-timeout", "1e-300"], "--join-timeout: expected at least 0.001 s"),
        (["--timeout", "1e-300"], "--timeout: expected at least 0.001 s"),
        (["--deadline", "1e300"], "--deadline: 1e+300 s is beyond the work limit of 2.0 hours"),
        (["--join-timeout", "1e300"], "--join-timeout: 1e+300 s is beyond the work limit"),
        (["--timeout", "1e300"], "--timeout: 1e+300 s is beyond the work limit"),
        (["--deadline", "400"], "--deadline: the run's worst case, 60 s to join + 20 steps x 400 s = 2.2 hours, exceeds the work limit"),
    ],
)
def test_deadline_extremes_refused(monkeypatch: Any, capsys: Any, log4: Any, flags: list[str], expected: str) -> None:
    d, log = log4
    _no_work(monkeypatch)
    t0 = time.monotonic()
    assert main(["deploy", "platoon-4", "--measurements", str(log), "--out", str(d / "x.csv"), "--transport", "queue", *flags]) == 2
    assert expected in _err(capsys)
    assert time.monotonic() - t0 < 20


def test_small_deploy_still_runs(log4: Any, capsys: Any) -> None:
    """The checks do not refuse an ordinary run (queue transport, 20 steps), nor a long deadline that --timeout bounds."""
    d, log = log4
    _limits.check_deploy(200, 6, deadline=10.0, join_timeout=60.0)  # test_deploy's generous deadline: 2060 s worst case
    _limits.check_deploy(20, 4, deadline=400.0, join_timeout=60.0, timeout=600.0)
    assert main(["deploy", "platoon-4", "--measurements", str(log), "--out", str(d / "ok.csv"), "--transport", "queue", "--json"]) == 0
    assert (d / "ok.csv").exists()


# ---------------------------------------------------------------------------
# teams and lossy horizons, sized before they start
# ---------------------------------------------------------------------------
def _team(n: int, kind: str = "ring") -> dict[str, Any]:
    return {
        "name": "big",
        "horizon": 10,
        "system": {"A": [[0.9, 0.1], [0.0, 0.8]], "Q": 1.0, "Sigma_x": 1.0},
        "agents": [{"C": [[1.0, 0.0]], "R": 0.5}] * n,
        "graph": {"kind": kind, "delay": 1},
        "cost": {"kind": "mse"},
        "estimators": ["local"],
    }


@pytest.mark.parametrize("kind", ["line", "ring", "complete"])
def test_ten_thousand_agents_refused_by_the_size_check(monkeypatch: Any, kind: str) -> None:
    """10^4 agents read as ~250-300 bytes per pair (measured at n = 2000): 23+ GiB, refused on a 22 GiB machine at once."""
    monkeypatch.setattr(_budget, "available_memory", lambda: 22 * GIB)
    t0 = time.monotonic()
    with pytest.raises(ResourceError, match=r"agents: reading a team of 10,000 agents") as info:
        scenario_from_dict(_team(10**4, kind))
    assert time.monotonic() - t0 < 20
    assert info.value.argument == "agents"
    assert _size.PAIR_BYTES_BY_KIND[kind] >= 240


def test_ten_thousand_agents_from_a_file_via_the_cli(monkeypatch: Any, capsys: Any, tmp_path: Path) -> None:
    monkeypatch.setattr(_budget, "available_memory", lambda: 22 * GIB)
    f = tmp_path / "big.toml"
    head = 'name = "big"\nhorizon = 10\nestimators = ["local"]\n[system]\nA = [[0.9, 0.1], [0.0, 0.8]]\nQ = 1.0\nSigma_x = 1.0\n'
    f.write_text(head + '[graph]\nkind = "ring"\ndelay = 1\n[cost]\nkind = "mse"\n' + "[[agents]]\nC = [[1.0, 0.0]]\nR = 0.5\n" * 10**4)
    t0 = time.monotonic()
    assert main(["evaluate", str(f)]) == 2
    assert "agents: reading a team of 10,000 agents" in _err(capsys)
    assert time.monotonic() - t0 < 20


def _lossy(T: int, memory: int | None = None) -> Any:
    from teamkf.study.scenario import load_packaged

    upd: dict[str, Any] = {"horizon": T, "graph.delay": 2, "network.p_drop": 0.2, "estimators": ["mtmse_lossy"]}
    if memory is not None:
        upd["mtmse_lossy.memory"] = memory
    return load_packaged("platoon-6").updated(upd)


def test_lossy_horizon_refused_before_allocation(monkeypatch: Any) -> None:
    """T = 3000 on 6 agents with delay-2 edges needs terabytes: refused before the local moments are computed."""
    from teamkf.estimators import team_lossy

    monkeypatch.setattr(_budget, "available_memory", lambda: 22 * GIB)
    monkeypatch.setattr(team_lossy, "local_filter_moments", lambda *a, **k: pytest.fail("allocated before the size check"))
    with pytest.raises(
        ScenarioError,
        match=r"horizon: mtmse_lossy: the mtmse_lossy design over T = 3,000 steps needs about .* TiB .* set the mtmse_lossy option memory = 24 \(",
    ) as info:
        _lossy(3000).design("mtmse_lossy")
    assert isinstance(info.value.__cause__, ResourceError)  # the size check, not a MemoryError
    monkeypatch.setattr(_budget, "available_memory", lambda: 2 * GIB)
    with pytest.raises(ScenarioError, match=r"over T = 300 steps needs about 3\.\d GiB.* set the mtmse_lossy option memory = \d+ \(the items"):
        _lossy(300).design("mtmse_lossy")
    # with a memory the windowed form keeps arrays of a fixed size per step: T = 3000 fits, a million steps do not
    from teamkf.estimators import _lossy_size
    from teamkf.estimators._arrivals import ArrivalModel

    sc = _lossy(3000, memory=5)
    _lossy_size.check(sc.system, ArrivalModel.build(sc.graph, 0.2, 0), 3000, 5, sc.cost.dz, False)
    with pytest.raises(
        ScenarioError, match=r"over T = 1,000,000 steps \(memory = 5\) needs about .* use a horizon of at most [\d,]+ steps with memory = 5"
    ):
        _lossy(10**6, memory=5).design("mtmse_lossy")


def test_lossy_estimate_tracks_the_measured_peaks() -> None:
    """The estimate of the arrays stays below the measured peak RSS (never premature) and within 40 % of it."""
    from teamkf.estimators import _lossy_size
    from teamkf.estimators._arrivals import ArrivalModel

    sc = _lossy(10)
    arr = ArrivalModel.build(sc.graph, 0.2, 0)
    measured = {(40, None): 88.3, (80, None): 304.3, (160, None): 1174.5}  # MiB, docstring of _lossy_size
    for (T, m), peak in measured.items():
        est = _lossy_size.estimate(sc.system.dy, arr.ell, arr.prob, T, m, sc.system.dx, sc.cost.dz, m is None)[0] / 2**20
        assert 0.6 * peak < est < peak, (T, m, est)
    # the windowed form (memory = 5): an upper bound (the steady form's reuse is not counted), within a factor 3
    for (T, m), peak in {(80, 5): 2.6, (400, 5): 7.8}.items():  # MiB above the process before the design
        est = _lossy_size.estimate(sc.system.dy, arr.ell, arr.prob, T, m, sc.system.dx, sc.cost.dz, False)[0] / 2**20
        assert peak < est < 3 * peak, (T, m, est)
    small = _lossy_size.estimate(sc.system.dy, arr.ell, arr.prob, 10**9, 3, sc.system.dx, sc.cost.dz, False)
    assert all(np.isfinite(small))  # a huge horizon is a number (refused), never an overflow


def test_lossy_small_horizon_still_designs() -> None:
    d = _lossy(8).design("mtmse_lossy")
    assert d.horizon == 8


def test_monte_carlo_under_drops_counts_its_python_steps(monkeypatch: Any) -> None:
    """path="runtime" (unreliable links, --p-drop): each agent's step runs in Python per block of runs and step."""
    from teamkf.simulation import monte_carlo as mc
    from teamkf.study.scenario import load_packaged

    d = load_packaged("platoon-4").design("kcf")
    monkeypatch.setenv("TEAMKF_MAX_HOURS", "0.01")  # 36 s
    mc._check_work({"kcf": d}, d.system, 10**6, 2)  # the batched estimate alone: about 20 s
    with pytest.raises(ResourceError, match=r"n_runs: a Monte Carlo of 2 runs x 1000000 steps"):
        mc._check_work({"kcf": d}, d.system, 10**6, 2, blocks=1)  # + 4 agents x 10^6 steps x 10 us
