"""Sized before started, round 3: a team sized from its raw tables, the --max-hours override, Ctrl-C, Parquet's non_finite column."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from teamkf import _budget, scenario_from_dict
from teamkf.cli import main
from teamkf.exceptions import ResourceError
from teamkf.study import _size
from teamkf.study.datafile import check_depth

ROOT = Path(__file__).resolve().parents[2]
GIB = 1024**3


def _team(n: int, kind: str = "ring", horizon: int | None = 10, estimators: tuple[str, ...] = ("mtmse",)) -> dict[str, Any]:
    d: dict[str, Any] = {
        "name": "big",
        "system": {"A": [[0.9, 0.1], [0.0, 0.8]], "Q": 1.0, "Sigma_x": 1.0},
        "agents": [{"C": [[1.0, 0.0]], "R": 0.5}] * n,
        "graph": {"kind": kind, "delay": 1},
        "cost": {"kind": "mse"},
        "estimators": list(estimators),
    }
    if horizon is not None:
        d["horizon"] = horizon
    return d


def test_ten_thousand_agents_refused_from_the_raw_tables_at_once(monkeypatch: Any) -> None:
    """n = 10^4: refused in well under a second of CPU, naming agents, the estimate and what to change (no n^2 work first)."""
    monkeypatch.setattr(_budget, "available_memory", lambda: 16 * GIB)
    data = _team(10**4, "complete", estimators=("local",))
    t0 = time.process_time()
    with pytest.raises(ResourceError, match=r"agents: reading a team of 10,000 agents .* needs about 27\.9 GiB .* use fewer agents") as info:
        scenario_from_dict(data)
    assert time.process_time() - t0 < 1.0
    assert info.value.argument == "agents"
    # the estimate is n^2 pairs x the bytes per pair of a complete graph, exactly
    assert f"{_budget.format_bytes(1e8 * _size.PAIR_BYTES_BY_KIND['complete'])}" in str(info.value)


def test_bytes_per_pair_by_graph_kind_never_premature(monkeypatch: Any) -> None:
    """A star (26 bytes per pair measured) or an edge list is counted at 24 bytes per pair: 10^4 agents fit in 16 GiB."""
    monkeypatch.setattr(_budget, "available_memory", lambda: 16 * GIB)
    _size.check_team_size(_team(10**4, "star", estimators=("local",)), 10, {})
    edges = {**_team(10**4, "line", estimators=("local",)), "graph": {"edges": [[i, (i + 1) % 10**4, 1] for i in range(10**4)]}}
    _size.check_team_size(edges, 10, {})
    with pytest.raises(ResourceError, match="250 bytes for each"):
        _size.check_team_size(_team(15_000, "line", estimators=("local",)), 10, {})


def test_a_ring_team_design_refused_by_its_window_whatever_the_machine(monkeypatch: Any) -> None:
    """A ring of 2000 agents: the MTMSE window (lag n/2 = 1000 steps x 2000 rows) is a 2e6 x 2e6 covariance (96 TB)."""
    monkeypatch.setattr(_budget, "available_memory", lambda: 1024 * GIB)
    with pytest.raises(
        ResourceError, match=r"agents: the mtmse design of a team of 2,000 agents \(its window of 1,000 steps x 2,000 measurements"
    ) as info:
        scenario_from_dict(_team(2000, "ring", horizon=None))
    w = 1000 * 2000
    assert _budget.format_bytes(24.0 * w * w) in str(info.value)


def test_lags_of_the_builders_and_lower_bounds() -> None:
    """The common lag is the weighted diameter of the builder graphs (checked against the graph itself), 1 for an edge list."""
    from teamkf import CommGraph, InformationStructure

    for kind, build in (("line", CommGraph.line), ("ring", CommGraph.ring), ("star", CommGraph.star), ("complete", CommGraph.complete)):
        for n in (3, 6, 7):
            for d in (1, 3):
                exact = InformationStructure.from_graph(build(n, delay=d)).common_lag
                assert _size._lag({"graph": {"kind": kind, "delay": d}}, n) == exact, (kind, n, d)
    assert _size._lag({"graph": {"edges": [[0, 1, 5], [1, 0, 5]]}}, 2) == 1
    assert _size._lag({"graph": {"kind": "line"}, "information": {"common_lag": 7}}, 50) == 7


def test_work_estimate_and_the_override(monkeypatch: Any) -> None:
    """t = n^2 (tau_read + T s tau_step): over the limit it is refused; --max-hours (TEAMKF_MAX_HOURS) lets it through."""
    monkeypatch.setattr(_budget, "available_memory", lambda: 10**6 * GIB)
    n, T = 5000, 10**5
    data = _team(n, "complete", horizon=T)
    seconds = n * n * (_size.PAIR_SECONDS + T * _size.PAIR_STEP_SECONDS)
    with pytest.raises(ResourceError, match="agents: reading a team of 5,000 agents .* and 1 team design.* over the limit of 2.0 hours") as info:
        _size.check_team_size(data, T, {"mtmse": type("F", (), {"uses": "structure"})()})
    assert _budget.format_seconds(seconds) in str(info.value)
    assert "--max-hours" in str(info.value)
    with _budget.max_hours(math.ceil(seconds / 3600) + 1):
        _size.check_team_size(data, T, {"mtmse": type("F", (), {"uses": "structure"})()})  # passes under the raised limit
    assert os.environ.get("TEAMKF_MAX_HOURS") is None  # restored


def test_a_small_team_is_not_sized_and_a_medium_one_passes() -> None:
    _size.check_team_size(_team(_size.SMALL_TEAM), 10, {})
    _size.check_team_size(_team(1000, "complete"), 10, {})  # 1e6 pairs: 200 MB and 20 s at most


def test_max_hours_flag(tmp_path: Path, capsys: Any) -> None:
    good = tmp_path / "g.json"
    good.write_text(json.dumps({**_team(2, "line", horizon=4), "cost": {"kind": "average", "lambda": 1.0}}))
    assert main(["evaluate", str(good), "--monte-carlo", "1000000", "--max-hours", "1e-4"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("teamkf: error: --monte-carlo:") and "over the limit of 0 s" in err[0] and "--max-hours" in err[0]
    for bad in ("0", "-1", "nan", "inf", "abc"):
        assert main(["--max-hours", bad, "evaluate", str(good)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "--max-hours: expected a" in err[0], err


def test_check_depth_is_linear_and_names_the_top_key() -> None:
    wide = {"agents": [{"C": [[1.0, 0.0]], "R": 0.5}] * 50_000}
    t0 = time.process_time()
    check_depth(wide)
    assert time.process_time() - t0 < 1.5
    deep: Any = 1.0
    for _ in range(40):
        deep = [deep]
    with pytest.raises(Exception, match=r"^system: expected at most 32 levels"):
        check_depth({"name": "x", "system": {"A": deep}})


def test_parquet_parts_carry_non_finite(tmp_path: Path) -> None:
    """A non-finite cost in a sweep row is named in the part's non_finite column (JSON), null when every number is finite."""
    pa = pytest.importorskip("pyarrow")
    import pyarrow.parquet as pq

    from teamkf.study.sweep import _Writer, sweep_from_dict

    spec = sweep_from_dict({"name": "s", "scenario": "platoon-4", "grid": {"cost.lambda": [1.0, 2.0]}})
    w = _Writer(spec, tmp_path / "r.parquet", pa)
    w.create()
    p0, p1 = spec.points
    base = {"estimator": "mtmse", "label": "mtmse", "method": "analytic", "diverged": False}
    w.write(p0, [{**base, spec.cost_keys[0]: float("inf"), "diverged": True}, {**base, "estimator": "mmse", spec.cost_keys[0]: float("nan")}])
    w.write(p1, [{**base, spec.cost_keys[0]: 3.5}])
    rows = {(r["point_index"], r["estimator"]): r for r in pq.read_table(tmp_path / "r.parquet").to_pylist()}
    assert json.loads(rows[(0, "mtmse")]["non_finite"]) == {spec.cost_keys[0]: "inf"}
    assert json.loads(rows[(0, "mmse")]["non_finite"]) == {spec.cost_keys[0]: "nan"}
    assert rows[(1, "mtmse")]["non_finite"] is None and rows[(1, "mtmse")][spec.cost_keys[0]] == 3.5


def _foreground(args: list[str], cwd: Path) -> subprocess.Popen[str]:
    """``python -m teamkf ARGS`` as from a shell's foreground: SIGINT at its default (pytest-xdist workers ignore it,
    and a child inherits that)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src") + os.pathsep + os.environ.get("PYTHONPATH", ""), TEAMKF_PROGRESS="0")
    return subprocess.Popen(
        [sys.executable, "-m", "teamkf", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        cwd=cwd,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )


@pytest.mark.skipif(sys.platform == "win32", reason="SIGINT to a child process")
def test_ctrl_c_stops_a_long_monte_carlo_in_one_line(tmp_path: Path) -> None:
    """A long job (10^8 runs: about half an hour here, under the limit) stops on Ctrl-C: exit 130, one line, no traceback, no file."""
    scen = tmp_path / "g.json"
    scen.write_text(json.dumps({**_team(2, "line", horizon=4), "cost": {"kind": "average", "lambda": 1.0}}))
    proc = _foreground(["evaluate", str(scen), "--monte-carlo", str(10**8), "--plot", str(tmp_path / "p.png")], tmp_path)
    time.sleep(3.0)
    assert proc.poll() is None, proc.communicate()
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, (out, err)
    assert err.strip().splitlines() == ["teamkf: interrupted"] and "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["g.json"]


def _numpy_loaded(pid: int) -> bool:
    """numpy's compiled core is mapped in the process: teamkf's own imports are under way."""
    try:
        return "_multiarray_umath" in Path(f"/proc/{pid}/maps").read_text()
    except OSError:
        return False


@pytest.mark.skipif(not Path("/proc/self/maps").exists(), reason="reads the loaded libraries from /proc")
def test_ctrl_c_while_the_libraries_load_is_one_line_too(tmp_path: Path) -> None:
    """Ctrl-C while teamkf's libraries still import (numpy mapped, scipy and the rest to come): exit 130, one line."""
    proc = _foreground(["evaluate", str(ROOT / "examples" / "scenarios" / "platoon-4.toml")], tmp_path)
    end = time.monotonic() + 30
    while not _numpy_loaded(proc.pid) and proc.poll() is None and time.monotonic() < end:
        time.sleep(0.001)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=60)
    if proc.returncode == 0:
        pytest.skip("the command finished before the signal")
    assert proc.returncode == 130, (out, err)
    assert err.strip().splitlines() == ["teamkf: interrupted"] and "Traceback" not in err


def test_announcement_on_a_terminal_only(monkeypatch: Any, capsys: Any) -> None:
    """A team whose reading is estimated over ANNOUNCE_S says so on a terminal (Ctrl-C stops it), and is silent elsewhere."""
    monkeypatch.setattr(_budget, "available_memory", lambda: 10**6 * GIB)
    monkeypatch.setattr(_budget, "ANNOUNCE_S", 0.0)
    _size.check_team_size(_team(300), 10, {})
    assert capsys.readouterr().err == ""  # not a terminal
    import teamkf._progress as P

    monkeypatch.setattr(P, "progress_enabled", lambda *a, **k: True)
    _size.check_team_size(_team(300), 10, {})
    assert "reading a team of 300 agents" in capsys.readouterr().err and np.isfinite(_size.PAIR_BYTES)
