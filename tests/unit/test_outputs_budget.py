"""Nothing lost, sized before started, no bare NaN (issue 25): teamkf.study.outputs, teamkf._budget, and the flags on non-finite results."""

from __future__ import annotations

import json
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from teamkf import _budget
from teamkf.cli import main
from teamkf.exceptions import ArgumentError, ResourceError, ShapeError, TeamkfError
from teamkf.study.outputs import check_output, check_output_dir, same_file, write_atomic


# ---------------------------------------------------------------------------
# outputs
# ---------------------------------------------------------------------------
def test_check_output_refuses_an_input_by_any_spelling(tmp_path: Path, monkeypatch: Any) -> None:
    data = tmp_path / "data.csv"
    data.write_text("x\n1\n")
    (tmp_path / "sub").mkdir()
    (tmp_path / "alias.csv").symlink_to(data)
    monkeypatch.chdir(tmp_path)
    for spelling in ("data.csv", "./data.csv", "sub/../data.csv", str(data), "alias.csv"):
        with pytest.raises(ArgumentError, match="--out: .* is also an input") as info:
            check_output(spelling, "--out", fmt="table", inputs=["scenario-name-not-a-file", str(data)])
        assert info.value.argument == "--out"
    assert check_output("other.csv", "--out", fmt="table", inputs=[str(data)]) == Path("other.csv")
    assert same_file("alias.csv", "data.csv") and not same_file("other.csv", "data.csv")


def test_check_output_extension_and_folders(tmp_path: Path) -> None:
    with pytest.raises(ArgumentError, match=r"ending in \.npz .*found the extension '\.txt'.*use e\.g\. g\.npz"):
        check_output(tmp_path / "g.txt", "--out", fmt="npz")
    with pytest.raises(ArgumentError, match="found no extension.*use e.g. gains.npz"):
        check_output(tmp_path / "gains", "--out", fmt="npz")
    with pytest.raises(ArgumentError, match="the folder '.*typo' does not exist; create it first"):
        check_output(tmp_path / "typo" / "deeper" / "g.npz", "--out", fmt="npz")
    assert not (tmp_path / "typo").exists()
    with pytest.raises(ArgumentError, match="is a directory"):
        check_output(tmp_path, "--plot")
    with pytest.raises(ArgumentError, match="NUL"):
        check_output("a\x00b.npz", "--out")
    with pytest.raises(ArgumentError, match="found the file"):
        check_output_dir(__file__, "--out")
    with pytest.raises(ArgumentError, match="'.*nope' does not exist"):
        check_output_dir(tmp_path / "nope" / "res", "--out")
    assert check_output_dir(tmp_path / "res", "--out") == tmp_path / "res"  # the folder itself may be new
    assert not (tmp_path / "res").exists()  # ... but checking creates nothing


def test_write_atomic_keeps_the_old_file_on_failure(tmp_path: Path) -> None:
    target = tmp_path / "out.csv"
    target.write_text("old")
    target.chmod(0o640)

    def boom(fh: Any) -> None:
        fh.write(b"partial")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        write_atomic(target, boom)
    assert target.read_text() == "old" and sorted(p.name for p in tmp_path.iterdir()) == ["out.csv"]
    write_atomic(target, lambda fh: fh.write("new,ü"), text=True)
    assert target.read_text(encoding="utf-8") == "new,ü"
    assert target.stat().st_mode & 0o777 == 0o640  # an existing file keeps its permissions
    with pytest.raises(ArgumentError, match="does not exist"):
        write_atomic(tmp_path / "missing" / "x.csv", lambda fh: None)


# ---------------------------------------------------------------------------
# budget
# ---------------------------------------------------------------------------
def test_check_memory_and_work_refuse_with_the_estimate(monkeypatch: Any) -> None:
    _budget.check_memory(1e6, "x", argument="a", fix="f", available=10**9)
    with pytest.raises(ResourceError, match=r"n_runs: a job needs about 9\.3 GiB of memory, but this machine has 1\.0 GiB available; fewer"):
        _budget.check_memory(1e10, "a job", argument="n_runs", fix="fewer", available=2**30)
    assert isinstance(ResourceError("x: y"), (ArgumentError, ValueError, TeamkfError))
    # work: t = flops / rate + loops / LOOPS against the limit
    assert _budget.check_work(_budget.FLOPS * 10, "w", argument="a", fix="f") == pytest.approx(10.0)
    with pytest.raises(ResourceError, match=r"iterations: w needs at least 3\.0 hours of computing .* over the limit of 2\.0 hours"):
        _budget.check_work(0.0, "w", argument="iterations", fix="f", loops=3 * 3600 * _budget.LOOPS)
    monkeypatch.setenv("TEAMKF_MAX_HOURS", "4")
    assert _budget.work_limit_s() == 4 * 3600
    _budget.check_work(0.0, "w", argument="iterations", fix="f", loops=3 * 3600 * _budget.LOOPS)
    monkeypatch.setenv("TEAMKF_MAX_HOURS", "nonsense")  # never ignored (round 4): one error naming the variable
    with pytest.raises(ArgumentError, match="TEAMKF_MAX_HOURS: expected a positive number of hours"):
        _budget.work_limit_s()
    monkeypatch.setenv("TEAMKF_MAX_HOURS", "")
    assert _budget.work_limit_s() == _budget.DEFAULT_MAX_HOURS * 3600
    assert _budget.format_bytes(3 * 2**60) == "3.0 EiB" and _budget.format_bytes(2.0**80).endswith("bytes")
    assert _budget.format_seconds(90) == "90 s" and _budget.format_seconds(5400) == "90.0 minutes" and "years" in _budget.format_seconds(1e12)


def test_available_memory_is_read_without_psutil() -> None:
    avail = _budget.available_memory()
    assert avail is None or avail > 0


# ---------------------------------------------------------------------------
# no bare NaN
# ---------------------------------------------------------------------------
BASE: dict[str, Any] = {
    "name": "big-base",
    "horizon": 4,
    "system": {"A": [[0.9, 0.1], [0.0, 0.8]], "Q": 1.0, "Sigma_x": 1.0},
    "agents": [{"C": [[1.0, 0.0]], "R": 0.5}, {"C": [[0.0, 1.0]], "R": 0.5}],
    "graph": {"kind": "line", "delay": 1},
    "cost": {"kind": "average", "lambda": 1.0},
    "estimators": ["centralized"],
}


@pytest.mark.parametrize("big", ["1e250", "-3e300"])
def test_an_impossible_measurement_gives_a_flagged_log_likelihood(tmp_path: Path, capsys: Any, big: str) -> None:
    sc = tmp_path / "s.json"
    sc.write_text(json.dumps(BASE))
    meas = tmp_path / "m.csv"
    meas.write_text("step,agent,y0\n" + "".join(f"{t},{i},{big if (t, i) == (1, 0) else '0.2'}\n" for t in range(4) for i in range(2)))
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # none may escape the command
        assert main(["filter", str(sc), "--measurements", str(meas), "--out", str(tmp_path / "e.csv")]) == 0
    out, err = capsys.readouterr()
    assert "log-likelihood of the data under the centralized filter: -inf (non-finite" in out, out
    assert "nan" not in out.lower().replace("non-finite", "")
    assert all(ln.startswith("teamkf: warning: ") for ln in err.splitlines() if ln.strip()), err
    assert main(["filter", str(sc), "--measurements", str(meas), "--out", str(tmp_path / "e2.csv"), "--json"]) == 0
    out, _ = capsys.readouterr()
    doc = json.loads(out)
    assert doc["loglik"] is None and doc["non_finite"]["loglik"] == "-inf"


def test_a_plain_measurement_has_no_flag(tmp_path: Path, capsys: Any) -> None:
    sc = tmp_path / "s.json"
    sc.write_text(json.dumps(BASE))
    meas = tmp_path / "m.csv"
    meas.write_text("step,agent,y0\n" + "".join(f"{t},{i},0.2\n" for t in range(4) for i in range(2)))
    assert main(["filter", str(sc), "--measurements", str(meas), "--out", str(tmp_path / "e.csv"), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert np.isfinite(doc["loglik"]) and "non_finite" not in doc


def test_strings_are_not_silently_numbers_but_numbers_still_are() -> None:
    from teamkf import _validation as V

    assert V.as_float_array([[1, 2.5]], "A").dtype == float
    assert V.as_float_array(np.arange(3), "A").shape == (3,)
    for bad in (["1"], np.array(["1.0"]), np.array([True]), [[1.0, False]], True):
        with pytest.raises(ShapeError, match="A: expected a numeric array, found (strings|booleans|a boolean)"):
            V.as_float_array(bad, "A")


def test_resource_error_is_fast_and_allocates_nothing() -> None:
    import time

    import teamkf

    t0 = time.perf_counter()
    with pytest.raises(ResourceError, match="n: a graph of 1,000,000 agents"):
        teamkf.CommGraph.complete(10**6)
    assert time.perf_counter() - t0 < 5.0


@pytest.mark.parametrize("kind", ["average_tracking", "platoon", "ring"])
def test_cost_builders_skip_only_a_check_that_holds_by_construction(kind: str) -> None:
    import teamkf

    c = getattr(teamkf.TeamCost, kind)(5, 3.5, d=2)
    validated = teamkf.TeamCost(S=np.array(c.S[0]), L=np.array(c.L[0]), n_agents=5)  # through __post_init__'s checks
    assert np.array_equal(c.S, validated.S) and np.array_equal(c.L, validated.L)
    assert not c.S.flags.writeable and np.linalg.eigvalsh(c.S[0])[0] >= 1.0 - 1e-12  # I + lam W with W >= 0
    with pytest.raises(ResourceError, match="n_agents: the .* team cost of 1,000,000 agents"):
        getattr(teamkf.TeamCost, kind)(10**6, 1.0)
