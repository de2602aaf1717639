"""Design once, ship each agent its slice: ``teamkf design --out`` / ``teamkf deploy`` write it, ``teamkf agent --design`` reads it.

An agent process rebuilds its graph agent from its slice and the scenario's model and never builds
the team design (a hook in the agent processes makes ``Scenario.design`` fail: the run still passes,
bit for bit equal to ``teamkf filter``). A slice of another scenario, agent, estimator or run, a
tampered or truncated file is refused in one line.
"""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from teamkf.estimators._slices import SliceContext, agent_from_slice
from teamkf.estimators.base import pass_messages
from teamkf.exceptions import ArgumentError
from teamkf.study import measurements as M
from teamkf.study.scenario import load_scenario
from teamkf.study.slices import agent_files, content_hash, read_slice, slice_sections, write_slices

SRC = Path(__file__).resolve().parents[2] / "src"
live = pytest.mark.skipif(importlib.util.find_spec("zenoh") is None, reason="needs eclipse-zenoh (pip install 'teamkf[deploy]')")


def platoon_toml(n: int, T: int, *, lam: float = 100.0, estimators: str = '["kcf", "mtmse", "mmse"]') -> str:
    """An n-vehicle platoon (each vehicle measures its own position) on a line graph with unit delays."""
    rows = ",\n     ".join("[" + ", ".join("0.9" if j == i else ("0.5" if j == i - 1 else "0.0") for j in range(n)) + "]" for i in range(n))
    out = [f'name = "platoon-{n}"', f"horizon = {T}", f"estimators = {estimators}", "", "[system]", f"A = [{rows}]", "Q = 1.0", "Sigma_x = 1.0", ""]
    for i in range(n):
        out += ["[[agents]]", "C = [[" + ", ".join("1" if j == i else "0" for j in range(n)) + "]]", "R = 0.1", ""]
    out += ["[graph]", 'kind = "line"', "delay = 1", "", "[cost]", 'kind = "platoon"', f"lambda = {lam}", ""]
    return "\n".join(out)


def scenario_and_log(d: Path, n: int, T: int, **kw) -> tuple[Path, Path]:
    from teamkf.simulation.sampling import sample_paths

    sp, lp = d / f"p{n}.toml", d / f"p{n}-log.csv"
    sp.write_text(platoon_toml(n, T, **kw), encoding="utf-8")
    sc = load_scenario(sp)
    M.write_measurements(lp, [y[0] for y in sample_paths(sc.system, T, 1, rng=11).y])
    return sp, lp


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    """A 4-vehicle platoon, T = 12, its log, and `teamkf design --out` of it."""
    from teamkf.cli import main

    d = tmp_path_factory.mktemp("slices")
    sp, lp = scenario_and_log(d, 4, 12)
    gains = d / "gains.npz"
    assert main(["--quiet", "design", str(sp), "--out", str(gains)]) == 0
    return load_scenario(sp), sp, lp, gains


def _ys(sc, lp):
    log = M.read_measurements(lp, sc.system, sc.horizon)
    return [np.asarray(y, dtype=float)[None] for y in log.filled()]


@pytest.mark.parametrize("name", ["kcf", "mtmse", "mmse"])
@pytest.mark.parametrize("tolerant", [False, True])
def test_design_out_slices_rebuild_the_agents_bit_for_bit(small, name, tolerant):
    """Every agent rebuilt from `teamkf design --out`'s file runs the team design's arithmetic, bit for bit (nominal and loss-tolerant step)."""
    sc, _, lp, gains = small
    d = sc.design(name)
    ys = _ys(sc, lp)
    ref_agents = d.graph_agents()
    ctx = SliceContext(sc.system, sc.cost, sc.graph, sc.information, sc.horizon)
    agents = []
    for i in range(4):
        kind, arrays, meta = read_slice(str(gains), sc, name, i)
        view, ag = agent_from_slice(kind, ctx, i, arrays, meta)
        assert view.estimator == name and not hasattr(view, "graph_agents")  # a view of one agent, not a design
        for a in (ag, ref_agents[i]):
            for o in (a, getattr(a, "inner", None)):
                if o is not None and hasattr(o, "tolerant"):
                    o.tolerant = tolerant
        agents.append(ag)
    ref = pass_messages(ref_agents, sc.graph, ys, design=d)
    z = pass_messages(agents, sc.graph, ys, design=view)
    assert z.tobytes() == ref.tobytes()


def test_a_slice_holds_one_agents_gains_only(small):
    sc, _, _, gains = small
    kind, arrays, meta = read_slice(str(gains), sc, "kcf", 2)
    view, ag = agent_from_slice(kind, SliceContext(sc.system, sc.cost, sc.graph, sc.information, sc.horizon), 2, arrays, meta)
    assert arrays["M"].shape == (12, 4, 4) and ag.design.algorithm.M[2, 3].shape == (4, 4)
    with pytest.raises(IndexError, match="holds no row of agent 1"):
        ag.design.algorithm.M[1, 3]
    with np.load(gains, allow_pickle=False) as f:  # the team file: every agent's section, read by key
        assert {k.split("/")[2] for k in f.files if k.startswith("slices/kcf/") and not k.endswith("meta")} == {"0", "1", "2", "3"}


def _one_line(exc: pytest.ExceptionInfo) -> str:
    msg = str(exc.value)
    assert "\n" not in msg
    return msg


def test_mismatched_or_damaged_slices_are_refused_in_one_line(small, tmp_path):
    sc, sp, _, gains = small
    other = tmp_path / "other.toml"
    other.write_text(platoon_toml(4, 12, lam=10.0), encoding="utf-8")
    with pytest.raises(ArgumentError) as e:  # another scenario: both hashes named
        read_slice(str(gains), load_scenario(other), "kcf", 0)
    msg = _one_line(e)
    assert str(gains) in msg and content_hash(sc, "kcf")[:16] in msg and content_hash(load_scenario(other), "kcf")[:16] in msg
    one = tmp_path / "agent-1.npz"
    write_slices(one, slice_sections(sc, sc.design("kcf"), [1], run_id=77))
    with pytest.raises(ArgumentError, match=r"expected agent 0's slice \(--id 0\), found agents \[1\]"):  # another agent's file
        read_slice(str(one), sc, "kcf", 0, 77)
    with pytest.raises(ArgumentError, match="written for run 77, the roster is of run 78"):  # another roster
        read_slice(str(one), sc, "kcf", 1, 78)
    with pytest.raises(ArgumentError, match=r"expected a slice of 'mtmse', found slices of \['kcf'\]"):  # another estimator
        read_slice(str(one), sc, "mtmse", 1)
    # a tampered hash, then tampered gains
    with np.load(one, allow_pickle=False) as f:
        arrays = {k: f[k] for k in f.files}
    head = json.loads(str(arrays["slices/kcf/meta"][()]))
    forged = tmp_path / "forged.npz"
    write_slices(forged, {**arrays, "slices/kcf/meta": np.asarray(json.dumps({**head, "content_hash": "0" * 64}))})
    with pytest.raises(ArgumentError) as e:
        read_slice(str(forged), sc, "kcf", 1)
    assert "content hash 0000000000000000" in _one_line(e)
    bent = {**arrays, "slices/kcf/1/M": arrays["slices/kcf/1/M"] * (1 + 1e-15)}
    write_slices(forged, bent)
    with pytest.raises(ArgumentError, match="do not match their digest"):
        read_slice(str(forged), sc, "kcf", 1)
    # truncated, not a zip, missing
    cut = tmp_path / "cut.npz"
    cut.write_bytes(one.read_bytes()[: one.stat().st_size // 2])
    for bad in (cut, sp):
        with pytest.raises(ArgumentError) as e:
            read_slice(str(bad), sc, "kcf", 1)
        assert "not a readable slice file" in _one_line(e) and str(bad) in str(e.value)
    with pytest.raises(ArgumentError, match="no such file"):
        read_slice(str(tmp_path / "nope.npz"), sc, "kcf", 1)
    # an object array (pickle) in a slice file is never loaded
    pickled = tmp_path / "pickled.npz"
    np.savez(pickled, **{**arrays, "slices/kcf/1/M": np.array([{"a": 1}], dtype=object)})
    with pytest.raises(ArgumentError, match="not a readable slice file"):
        read_slice(str(pickled), sc, "kcf", 1)


def test_a_family_without_slices_says_so_and_falls_back(small, capsys):
    sc, _, _, _ = small
    assert agent_files(sc, sc.design("local"), 5) is None
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "'local' family does not support agent_slice()" in err[0] and "every agent process designs the team" in err[0]


# ---------------------------------------------------------------------------
# live: agent processes over Zenoh on loopback
# ---------------------------------------------------------------------------
HOOK = """
import sys
if "agent" in sys.argv:  # an agent process: building the team design is an error
    import teamkf.study.scenario as S

    def _refuse(self, *a, **k):
        print("teamkf: error: this agent process built the team design", file=sys.stderr)
        raise SystemExit(3)

    S.Scenario.design = _refuse
"""


def _env(hook_dir: Path | None = None) -> dict[str, str]:
    parts = ([str(hook_dir)] if hook_dir else []) + [str(SRC), os.environ.get("PYTHONPATH", "")]
    return {**os.environ, "PYTHONPATH": os.pathsep.join(parts)}


def _teamkf(*args: str, env: dict[str, str], timeout: float = 400) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "teamkf", *args], capture_output=True, text=True, env=env, timeout=timeout)


@live
@pytest.mark.parametrize("name", ["kcf", "mtmse"])
def test_deploy_ships_slices_agents_never_design_and_equal_filter(small, tmp_path, name):
    """teamkf deploy with agents that cannot design: exit 0, the file teamkf filter writes, byte for byte."""
    sc, sp, lp, _ = small
    hook = tmp_path / "hook"
    hook.mkdir()
    (hook / "sitecustomize.py").write_text(HOOK, encoding="utf-8")
    out, fout = tmp_path / "deploy.csv", tmp_path / "filter.csv"
    ref = M.filter_log(sc, M.read_measurements(lp, sc.system, sc.horizon), estimators=[name], with_innovations=False).estimates[name]
    M.write_estimates(fout, {name: ref}, 4)
    proc = _teamkf("deploy", str(sp), "--measurements", str(lp), "--out", str(out), "--estimator", name, "--deadline", "10", "--json", env=_env(hook))
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    assert summary["failed"] == {} and all(r["peak_rss_mb"] is None or r["peak_rss_mb"] > 0 for r in summary["reports"])
    assert out.read_bytes() == fout.read_bytes()


@live
def test_agent_cli_refuses_a_wrong_slice_and_the_hook_catches_a_design(small, tmp_path):
    """`teamkf agent --design` of another agent: one line, exit 2; without --design the hook proves an agent would design."""
    from teamkf.deploy import Roster, free_ports

    sc, sp, lp, gains = small
    ports = free_ports(4)
    roster = tmp_path / "roster.toml"
    Roster({i: f"tcp/127.0.0.1:{ports[i]}" for i in range(4)}, 5, "teamkf/5").write(roster)
    one = tmp_path / "agent-1.npz"
    write_slices(one, slice_sections(sc, sc.design("kcf"), [1], run_id=5))
    hook = tmp_path / "hook"
    hook.mkdir()
    (hook / "sitecustomize.py").write_text(HOOK, encoding="utf-8")
    base = ["agent", str(sp), "--id", "0", "--roster", str(roster), "--measurements", str(lp), "--estimator", "kcf", "--insecure"]
    proc = _teamkf(*base, "--design", str(one), env=_env(hook))
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1, proc.stderr
    assert lines[0].startswith(f"teamkf: error: --design: {one}: expected agent 0's slice (--id 0), found agents [1]")
    proc = _teamkf(*base, env=_env(hook))  # no slice: it designs, and the hook stops it
    assert proc.returncode == 3 and "built the team design" in proc.stderr


@live
@pytest.mark.slow
def test_24_agents_with_a_24_dim_state_deploy_within_memory_and_time(tmp_path):
    """The issue's bar: 24 agents, d_x = 24, T = 200 on this machine: exit 0, byte-equal to filter, each agent <= 400 MB, < 300 s."""
    sp, lp = scenario_and_log(tmp_path, 24, 200, estimators='["kcf"]')
    out, fout = tmp_path / "deploy.csv", tmp_path / "filter.csv"
    t0 = time.monotonic()
    proc = _teamkf("deploy", str(sp), "--measurements", str(lp), "--out", str(out), "--estimator", "kcf", "--deadline", "10", "--json", env=_env())
    wall = time.monotonic() - t0
    assert proc.returncode == 0, proc.stderr[-2000:]
    summary = json.loads(proc.stdout)
    peaks = [r["peak_rss_mb"] for r in summary["reports"]]
    assert len(peaks) == 24 and all(p is not None and p <= 400 for p in peaks), peaks
    assert wall < 300, wall
    ff = _teamkf("filter", str(sp), "--measurements", str(lp), "--out", str(fout), "--estimators", "kcf", env=_env())
    assert ff.returncode == 0, ff.stderr
    assert out.read_bytes() == fout.read_bytes()


def test_steady_state_mtmse_slices_rebuild_the_agents_bit_for_bit(tmp_path):
    """A steady-state design's slice: the transient gains F_i(k), k < c, and F-bar_i."""
    from teamkf.simulation.sampling import sample_paths
    from teamkf.study.scenario import load_packaged

    sc = load_packaged("platoon-4-steady")
    ys = [np.asarray(v)[:, :12] for v in sample_paths(sc.system, 12, 1, rng=3).y]
    d = sc.design("mtmse")
    path = tmp_path / "steady.npz"
    write_slices(path, slice_sections(sc, d))
    ctx = SliceContext(sc.system, sc.cost, sc.graph, sc.information, sc.horizon)
    built = []
    for i in range(4):
        kind, arrays, meta = read_slice(str(path), sc, "mtmse", i)
        built.append(agent_from_slice(kind, ctx, i, arrays, meta))
    z = pass_messages([a for _, a in built], sc.graph, ys, design=built[0][0])
    assert z.tobytes() == pass_messages(d.graph_agents(), sc.graph, ys, design=d).tobytes()


def test_a_slice_carries_its_neighbours_payload_structures():
    """An agent rebuilt from its slice checks its in-neighbours' frames against the structures the team's design learned
    (it has no team design to learn them from): they travel in the slice file, as JSON, and read back the same."""
    import json

    from teamkf.deploy import check_deployable
    from teamkf.deploy.payload import learn_payloads, specs_from_json, specs_to_json
    from teamkf.study.scenario import load_packaged

    sc = load_packaged("platoon-4")
    design = sc.design("kcf")
    specs, sizes = learn_payloads(design, check_deployable(design, sc.graph))
    back, back_sizes = specs_from_json(json.loads(json.dumps(specs_to_json(specs, sizes))))
    assert back_sizes == sizes and set(back) == set(specs)
    for j, spec in specs.items():
        assert back[j]._expected() == spec._expected()
        assert back[j].why("a string") == spec.why("a string") is not None
        assert back[j].why(np.zeros((7, 7))) == spec.why(np.zeros((7, 7))) is not None
