"""Deployed agents in operation: an agent's own log, live step lines, rejoin, stop, merged team records (issue points 5-8).

A 3-vehicle platoon (KCF, T = 40..60) keeps every test short; the live ones start at most four
processes on 127.0.0.1 and pace the log (``--rate``) so that the team is still running when an
agent rejoins or a signal arrives.
"""

from __future__ import annotations

import importlib.util
import io
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from teamkf.deploy import AgentCore, DropRecord, QueueHub, replay, run_agent
from teamkf.deploy.merge import merge_reports
from teamkf.exceptions import ArgumentError
from teamkf.study import measurements as M
from teamkf.study.deploy import prepare

SRC = Path(__file__).resolve().parents[2] / "src"
ENV = {**os.environ, "PYTHONPATH": f"{SRC}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
live = pytest.mark.skipif(importlib.util.find_spec("zenoh") is None, reason="needs eclipse-zenoh (pip install 'teamkf[deploy]')")

P3 = """name = "platoon-3"
horizon = {T}
estimators = ["kcf"]
[system]
A = [[0.9, 0.0, 0.0], [0.7, 0.9, 0.0], [0.5, 0.7, 0.9]]
Q = 1.0
Sigma_x = 1.0
[[agents]]
C = [[1, 0, 0]]
R = 0.1
[[agents]]
C = [[0, 1, 0]]
R = 0.1
[[agents]]
C = [[0, 0, 1]]
R = 0.1
[graph]
edges = [[0, 1, 1], [1, 0, 1], [1, 2, 1], [2, 1, 1]]
[cost]
kind = "platoon"
lambda = 10.0
"""


@pytest.fixture(scope="module")
def p3(tmp_path_factory):
    """A 3-agent platoon (T = 60), a sampled log, its KCF preparation."""
    from teamkf.simulation.sampling import sample_paths
    from teamkf.study.scenario import load_scenario

    d = tmp_path_factory.mktemp("ops")
    (d / "p3.toml").write_text(P3.format(T=60))
    sc = load_scenario(d / "p3.toml")
    paths = sample_paths(sc.system, sc.horizon, 1, rng=3)
    M.write_measurements(d / "log.csv", [y[0] for y in paths.y])
    log = M.read_measurements(d / "log.csv", sc.system, sc.horizon)
    return sc, d, log, prepare(sc, log, "kcf")


def _teamkf(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "teamkf", *args], capture_output=True, text=True, env=ENV, timeout=timeout)


# ---------------------------------------------------------------------------
# 5. each robot its own data
# ---------------------------------------------------------------------------
def test_own_log_with_only_its_rows_or_no_agent_column_equals_the_team_log(p3, tmp_path):
    import pandas as pd

    from teamkf.study.agent_input import read_own_log

    sc, d, log, _ = p3
    team = pd.read_csv(d / "log.csv")
    own = team[team.agent == 1]
    own.to_csv(tmp_path / "own.csv", index=False)
    own.drop(columns="agent").to_csv(tmp_path / "bare.csv", index=False)
    for f in ("own.csv", "bare.csv"):
        got = read_own_log(str(tmp_path / f), sc.system, sc.horizon, 1)
        assert got.n_steps == 60 and got.y[1].tobytes() == log.y[1].tobytes() and not got.has_gaps
    assert read_own_log(str(d / "log.csv"), sc.system, sc.horizon, 1).y[1].tobytes() == log.y[1].tobytes()  # a team log works too
    own[own.step < 30].to_csv(tmp_path / "short.csv", index=False)  # the steps present define T
    assert read_own_log(str(tmp_path / "short.csv"), sc.system, sc.horizon, 1).n_steps == 30
    own[own.step != 7].to_csv(tmp_path / "gap.csv", index=False)
    with pytest.raises(M.MeasurementFileError, match="agent 1 has no value for step 7"):
        read_own_log(str(tmp_path / "gap.csv"), sc.system, sc.horizon, 1)
    with pytest.raises(M.MeasurementFileError, match="no row of agent 2"):
        read_own_log(str(tmp_path / "own.csv"), sc.system, sc.horizon, 2)


def test_live_lines_carry_their_step_gaps_repeats_and_stepless_lines_are_named():
    from teamkf.study.agent_input import StepLines

    warned: list[str] = []
    src = StepLines(io.StringIO("0,1.5\n1,2.5\n1,2.5\n0,9\n2,3.5\n4,5\n"), 1, 10, agent=2, estimator="kcf", warn=warned.append)
    assert [float(src(k)[0, 0]) for k in range(3)] == [1.5, 2.5, 3.5]
    assert len(warned) == 2 and "step 1 again" in warned[0] and "line 3" in warned[0] and "out of order" in warned[1]
    assert src.counts["repeated"] == 1 and src.counts["out_of_order"] == 1
    with pytest.raises(ArgumentError, match=r"line 6: step 4 follows step 2: step 3 missing"):
        src(3)
    with pytest.raises(ArgumentError, match="without its step.*prefix each line with its step"):
        StepLines(io.StringIO("0.5\n"), 1, 10)(0)
    with pytest.raises(ArgumentError, match="outside the run's steps"):
        StepLines(io.StringIO("12,0.5\n"), 1, 10)(0)
    late = StepLines(io.StringIO("0,1\n1,2\n2,3\n3,4\n"), 1, 10)  # a rejoined agent starts at step 2: earlier lines skipped
    assert float(late(2)[0, 0]) == 3.0 and late.counts["before_start"] == 2


# ---------------------------------------------------------------------------
# 6. rejoin
# ---------------------------------------------------------------------------
def _run_report(r, prep, run_id):
    d = r.to_json()
    d["run"] = {
        "run_id": run_id,
        "scenario": prep.scenario,
        "fingerprint": prep.fingerprint,
        "estimator": "kcf",
        "agents": prep.n_agents,
        "steps": prep.n_steps,
        "p_drop": 0.0,
        "seed": None,
    }
    return d


@pytest.mark.parametrize("family", ["kcf", "mtmse", "mmse"])
def test_rejoined_agent_in_process_is_fused_again_and_its_merged_record_replays_bit_for_bit(p3, family):
    sc, d, log, prep = p3
    if family != "kcf":
        prep = prepare(sc, log, family)
    n, T, rate = 3, prep.n_steps, 30.0
    hub = QueueHub(n)
    first: list = [None] * n
    second: list = [None]

    def one(i, out, idx, **kw):
        yi, t0 = prep.ys[i], []

        def src(k):
            if not t0:
                t0.append(time.monotonic() - k / rate)
            time.sleep(max(0.0, t0[0] + k / rate - time.monotonic()))
            return yi[:, k]

        core = AgentCore(prep.design, i, graph=prep.graph)
        out[idx] = run_agent(prep.design, i, hub.transport(i), src, n_steps=T, run_id=9, deadline=0.3, join_timeout=10, core=core, **kw)

    th = [threading.Thread(target=one, args=(i, first, i), kwargs={"kill_at": 12 if i == 2 else None}) for i in range(n)]
    for t in th:
        t.start()
    th[2].join()
    time.sleep(0.2)
    while not hub.queues[2].empty():  # what was sent to the dead process is lost
        hub.queues[2].get_nowait()
    t2 = threading.Thread(target=one, args=(2, second, 0), kwargs={"rejoin": True})
    t2.start()
    for t in [*th, t2]:
        t.join(60)
    r2 = second[0]
    assert r2.error is None and r2.steps_done == T and 12 < r2.started < T - 5
    k0 = r2.started
    assert np.isnan(r2.estimates[:k0]).all() and np.isfinite(r2.estimates[k0:]).all()
    from1 = {s for (j, s, _) in first[1].missed if j == 2}
    assert from1 and min(from1) == 12 and max(from1) < k0  # agent 1 fused agent 2 again from its rejoin on
    assert first[1].counts.get("rejoins") == 1
    reports = [("r0", _run_report(first[0], prep, 9)), ("r1", _run_report(first[1], prep, 9)), ("r2", _run_report(r2, prep, 9))]
    rec, problems = merge_reports(reports, died={2: 12})
    assert problems == [] and rec.stopped == {2: 12} and rec.rejoined == {2: ((k0, T),)}
    z = replay(prep.design, prep.ys, DropRecord.from_json(rec.to_json()), prep.offsets, graph=prep.graph)
    want = np.concatenate([first[0].estimates, first[1].estimates, np.where(np.isnan(r2.estimates), first[2].estimates, r2.estimates)], axis=1)
    assert z.tobytes() == want.tobytes()


def test_rejoin_is_refused_in_one_line_for_a_family_without_a_restart(p3):
    from teamkf.study.agent_ops import check_rejoin

    sc, *_ = p3
    with pytest.raises(ArgumentError, match="--rejoin: diffusion defines no restart"):
        check_rejoin(sc.design("diffusion"), 0, sc.graph, rejoin=True)
    for family in ("kcf", "mtmse", "mmse"):
        assert check_rejoin(sc.design(family), 0, sc.graph, rejoin=True).tolerant


# ---------------------------------------------------------------------------
# 8. a team record from separate machines
# ---------------------------------------------------------------------------
def test_merge_reports_names_each_problem(p3, tmp_path):
    sc, d, log, prep = p3
    res = [run for run in _queue_team(prep)]
    reps = [(f"r{i}", _run_report(r, prep, 5)) for i, r in enumerate(res)]
    rec, problems = merge_reports(reps)
    assert problems == [] and rec.missed == () and rec.complete and rec.stopped == {}
    other = json.loads(json.dumps(reps[2][1]))
    other["run"]["run_id"] = 6
    _, problems = merge_reports([reps[0], reps[1], reps[1], ("x", other)])
    assert any("x: run run_id is 6, r0's is 5" in p for p in problems)
    assert any("agent 1: r1 and r1 cover the same steps" in p for p in problems)
    _, problems = merge_reports(reps[:2])
    assert problems == ["agent 2: no report; give its report (teamkf agent --report), or --died 2:STEPS if its process died without one"]
    for i, (_, r) in enumerate(reps):
        (tmp_path / f"r{i}.json").write_text(json.dumps(r))
    out = tmp_path / "team.json"
    proc = _teamkf("record", "merge", *(str(tmp_path / f"r{i}.json") for i in range(2)), "--out", str(out))
    assert proc.returncode == 2 and proc.stderr.strip() == (
        "teamkf: error: REPORT: agent 2: no report; give its report (teamkf agent --report), or --died 2:STEPS if its process died without one"
    )
    assert _teamkf("record", "merge", *(str(tmp_path / f"r{i}.json") for i in range(3)), "--out", str(out)).returncode == 0
    assert DropRecord.read(out).run_id == 5


def _queue_team(prep):
    hub, out = QueueHub(prep.n_agents), [None] * prep.n_agents

    def one(i):
        yi = prep.ys[i]
        out[i] = run_agent(prep.design, i, hub.transport(i), lambda k: yi[:, k], n_steps=prep.n_steps, run_id=5, graph=prep.graph)

    th = [threading.Thread(target=one, args=(i,)) for i in range(prep.n_agents)]
    for t in th:
        t.start()
    for t in th:
        t.join(60)
    return out


# ---------------------------------------------------------------------------
# 7. nothing lost on stop; stale run folders
# ---------------------------------------------------------------------------
def test_stale_run_folders_of_dead_deploys_are_removed(tmp_path):
    from teamkf.study.agent_ops import clean_stale_run_dirs

    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    (tmp_path / f"teamkf-deploy-{dead.pid}-abc").mkdir()
    (tmp_path / f"teamkf-deploy-{dead.pid}-abc" / "roster.toml").write_text("x")
    (tmp_path / f"teamkf-deploy-{os.getpid()}-def").mkdir()
    (tmp_path / "other").mkdir()
    gone = clean_stale_run_dirs(str(tmp_path))
    assert gone == [str(tmp_path / f"teamkf-deploy-{dead.pid}-abc")]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([f"teamkf-deploy-{os.getpid()}-def", "other"])


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return Path(f"/proc/{pid}").exists() or True


@live
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_stopped_deploy_writes_the_completed_steps_and_an_incomplete_record_that_replays(p3, tmp_path, sig):
    sc, d, log, prep = p3
    out, rec, rep = tmp_path / "est.csv", tmp_path / "drops.json", tmp_path / "replay.csv"
    args = ["deploy", str(d / "p3.toml"), "--measurements", str(d / "log.csv"), "--out", str(out), "--record", str(rec), "--rate", "10"]
    proc = subprocess.Popen([sys.executable, "-m", "teamkf", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV)
    assert proc.stderr is not None
    line = proc.stderr.readline()
    pids = [int(p) for p in line.split("pids")[1].split()]
    end = time.monotonic() + 90
    while time.monotonic() < end:  # until every agent streamed a few steps (starting up takes a while on a loaded machine)
        streams = list(Path(tempfile.gettempdir()).glob(f"teamkf-deploy-{proc.pid}-*/agent-*.f8"))
        if len(streams) == 3 and all(f.stat().st_size >= 8 * 4 for f in streams):
            break
        time.sleep(0.1)
    proc.send_signal(sig)
    proc.communicate(timeout=60)
    assert proc.returncode == 128 + sig
    record = DropRecord.read(rec)
    assert not record.complete and 0 < record.completed < 60 and set(record.stopped) == {0, 1, 2}
    import pandas as pd

    est = pd.read_csv(out)
    z = est[[c for c in est.columns if c.startswith("z")]].to_numpy()
    assert np.isfinite(z[: 3 * record.completed]).all() and np.isnan(z[3 * max(record.stopped.values()) :]).all()
    from teamkf.cli import main

    assert main(["filter", str(d / "p3.toml"), "--measurements", str(d / "log.csv"), "--drops", str(rec), "--out", str(rep)]) == 0
    assert rep.read_bytes() == out.read_bytes()
    assert not [p for p in pids if _alive(p)], "orphans"
    assert not list(Path(tempfile.gettempdir()).glob(f"teamkf-deploy-{proc.pid}-*"))


@live
def test_killed_agent_restarted_with_rejoin_over_zenoh_is_fused_again_and_the_merged_record_replays(p3, tmp_path):
    """Three `teamkf agent` processes (as on three machines); agent 2 dies at step 10 and is restarted with --rejoin."""
    from teamkf.deploy import Roster, free_ports

    sc, d, log, prep = p3
    roster = tmp_path / "roster.toml"
    import secrets

    from teamkf.deploy.roster import write_key

    write_key(tmp_path / "team.key", secrets.token_bytes(32))  # frames are signed: the three processes share the team key
    Roster({i: f"tcp/127.0.0.1:{p}" for i, p in enumerate(free_ports(3))}, 77, "teamkf/test-rejoin", key_file="team.key").write(roster)
    common = ["--roster", str(roster), "--measurements", str(d / "log.csv"), "--rate", "6", "--deadline", "1"]

    def agent(i, *extra, tag=""):
        files = ["--out", str(tmp_path / f"a{i}{tag}.npz"), "--report", str(tmp_path / f"a{i}{tag}.json"), "--stream", str(tmp_path / f"a{i}.f8")]
        cmd = [sys.executable, "-m", "teamkf", "agent", str(d / "p3.toml"), "--id", str(i), *common, *files, *extra]
        return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV)

    procs = [agent(0), agent(1), agent(2, "--kill-at", "10")]
    procs[2].communicate(timeout=60)
    assert procs[2].returncode == -signal.SIGKILL
    again = agent(2, "--rejoin", tag="b")
    _, err = again.communicate(timeout=90)
    for p in procs[:2]:
        p.communicate(timeout=60)
    assert [p.returncode for p in procs[:2]] == [0, 0], [p.stderr for p in procs]
    assert again.returncode == 3, err  # completed, with the steps before its rejoin missed
    r2 = json.loads((tmp_path / "a2b.json").read_text())
    k0 = r2["started"]
    assert 10 < k0 < 55 and r2["steps_done"] == 60 and r2["previous_steps"] == 10
    r1 = json.loads((tmp_path / "a1.json").read_text())
    from2 = sorted(s for (j, s, _) in r1["missed"] if j == 2)
    assert from2 and from2[0] >= 9 and from2[-1] < k0 + 3  # fused again from (about) its first on-time message
    assert r1["counts"].get("rejoins") == 1
    stream = np.fromfile(tmp_path / "a2.f8", dtype="<f8").reshape(60, -1)
    assert np.isfinite(stream[:10]).all() and np.isnan(stream[10:k0]).all() and np.isfinite(stream[k0:]).all()
    team = tmp_path / "team.json"
    proc = _teamkf("record", "merge", *(str(tmp_path / f) for f in ("a0.json", "a1.json", "a2b.json")), "--out", str(team))
    assert proc.returncode == 0, proc.stderr
    assert DropRecord.read(team).rejoined == {2: ((k0, 60),)}
    rep = tmp_path / "replay.csv"
    assert _teamkf("filter", str(d / "p3.toml"), "--measurements", str(d / "log.csv"), "--drops", str(team), "--out", str(rep)).returncode == 0
    import pandas as pd

    z = pd.read_csv(rep)
    z = z[[c for c in z.columns if c.startswith("z")]].to_numpy().reshape(60, -1)
    want = [np.load(tmp_path / f"a{i}.npz")["z"] for i in (0, 1)] + [stream]
    assert z.tobytes() == np.concatenate(want, axis=1).tobytes()


@pytest.mark.parametrize("family", ["mtmse", "mmse"])
def test_a_restarted_team_agent_returns_to_the_nominal_estimates(family):
    """An MTMSE / MMSE agent restarted at step k0 from the prior (nothing held) and then given what a nominal agent gets
    from k0 on: its estimates differ at first and return to the nominal agent's (the predictor's error decays)."""
    import teamkf as T
    from teamkf.estimators.team import TeamAgent

    system, cost, graph = T.LinearGaussianSystem.platoon(3), T.TeamCost.platoon(3, lam=10.0), T.CommGraph.line(3, delay=1)
    d = (T.design_mtmse if family == "mtmse" else T.design_mmse)(system, cost, graph, horizon=60)
    _, y = T.sample(system, 60, n_runs=1, rng=3)
    nominal, restarted = TeamAgent(d, 2), TeamAgent(d, 2, tolerant=True)
    sa, sb, k0, diff = nominal.init_state(1), None, 20, []
    for k in range(60):
        packets = [(j, s, y[j][:, s]) for j in range(3) for s in range(k + 1) if s + d.structure.arrival_lag(2, j) == k]
        sa, za = nominal.step(sa, k, packets)
        if k == k0:
            sb = restarted.restart_state(1, k)
        if k >= k0:
            sb, zb = restarted.step(sb, k, packets)
            diff.append(float(np.abs(za - zb).max()))
    assert diff[0] > 1e-3 and max(diff[10:]) < 1e-6 * max(1.0, diff[0])
