"""Deployment workflows: ``teamkf deploy``, ``teamkf agent`` and ``teamkf filter --drops``.

The scenario and measurement files are read here; :mod:`teamkf.deploy` runs the
agents. The agents consume exactly what ``teamkf filter`` feeds its in-process
runtime (:func:`teamkf.study.measurements.filter_log`): agent i's measurements
y_i(k) - ȳ_i(k) (the known means removed, ȳ from the scenario's known inputs and the
log's u/b/d columns), and the known mean L(k) x̄(k) is added back to its estimate,
so a deployment without misses writes the same estimate file, bit for bit.
"""

from __future__ import annotations

import json
import secrets
import shutil
import signal
import sys
import threading
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from ..deploy import AgentCore, AgentResult, DropRecord, QueueHub, Roster, ZenohTransport, check_deployable, free_ports, launch, replay, run_agent
from ..deploy.agent import REFUSED
from ..deploy.roster import write_key
from ..deploy.transport import TransportError
from ..estimators.base import check_measurements
from ..exceptions import ArgumentError, UnsupportedOperationError
from . import _limits
from . import measurements as M
from .outputs import check_output, command_inputs, open_stream, write_atomic

__all__ = [
    "Prepared",
    "prepare",
    "deploy_estimator",
    "run_team",
    "deploy_processes",
    "DeployResult",
    "cmd_deploy",
    "cmd_agent",
    "cmd_filter_drops",
    "scenario_fingerprint",
]


# ---------------------------------------------------------------------------
# what the agents consume
# ---------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Prepared:
    """A design and the per-agent data of a recorded log, as ``teamkf filter`` feeds its runtime."""

    estimator: str
    design: Any
    ys: list[np.ndarray]  # per agent (1, T, d_y^i), known means removed
    offsets: np.ndarray | None  # (T, n d_z): L(k) x̄(k), or None
    n_steps: int
    graph: Any = None  # the graph the agents talk over
    n_agents: int = 0
    dz: int = 0  # estimate width per agent
    scenario: str | None = None  # the scenario's name and fingerprint, for the drop record
    fingerprint: str | None = None


def scenario_fingerprint(scenario: Any, estimator: str) -> str | None:
    """16 hex digits of the SHA-256 of the scenario's tables and the deployed family (canonical JSON; None for a scenario built in Python without them).

    A drop record carries it, so that ``teamkf filter --drops`` refuses a record of another scenario or estimator.
    """
    raw = getattr(scenario, "raw", None)
    if not raw:
        return None
    import hashlib

    text = json.dumps({"scenario": raw, "estimator": estimator}, sort_keys=True, separators=(",", ":"), allow_nan=True, default=str)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]


def deploy_estimator(scenario: Any, name: str | None) -> str:
    """``name``, or the scenario's first estimator that is not the centralized benchmark."""
    if name is not None:
        from ..estimators.registry import get_family

        get_family(name, "--estimator")
        return name
    for e in scenario.estimators:
        if e != "centralized":
            return str(e)
    raise ArgumentError(
        f"--estimator: the scenario {scenario.name!r} lists only {list(scenario.estimators)}; name a realizable family (e.g. mtmse)",
        argument="--estimator",
    )


def _means(scenario: Any, log: Any) -> tuple[list[np.ndarray], np.ndarray | None]:
    """(per-agent (T, d_y^i) measurements minus their known means, (T, n d_z) L(k) x̄(k) or None), as filter_log."""
    known = M.known_inputs(scenario)
    T = log.n_steps
    if known is None and (log.b is not None or log.d is not None):
        known = M.KnownInputs.zero(scenario.system)
    if known is None:
        if log.u is not None:
            raise M.MeasurementFileError(
                f"{log.source}: u columns: the scenario has no input matrix (system.B or agents[i].D) to use them", argument="u"
            )
        return log.filled(), None
    mean, ybar = known.means(scenario.system, T, log.u, log.b, log.d)
    ys = [np.where(np.isnan(log.y[i]), 0.0, log.y[i] - ybar[i]) for i in range(scenario.system.n_agents)]
    return ys, np.stack([scenario.cost.L_at(k) @ mean[k] for k in range(T)])


def prepare(scenario: Any, log: Any, estimator: str | None = None, *, design: Any = None, design_here: bool = True) -> Prepared:
    """Design ``estimator`` (refusing what no network can run) and lay out the log as the agents consume it.

    ``design_here=False``: do not design (the agent processes design for themselves and refuse what
    they cannot run); ``Prepared.design`` is then None.
    """
    if getattr(scenario, "kind", "team") != "team":
        raise ArgumentError(
            f"SCENARIO: deployment needs a scenario with [system], [[agents]] and a graph, found a {scenario.kind} scenario", argument="SCENARIO"
        )
    name = deploy_estimator(scenario, estimator)
    if not isinstance(log, M.MeasurementLog):
        log = M.MeasurementLog.from_arrays(log, scenario.system, scenario.horizon)
    if log.has_gaps:
        i, s = log.first_missing()  # type: ignore[misc]
        raise UnsupportedOperationError(
            name,
            "deployment on a log with missing values",
            f"agent {i} misses step {s}; the recorded-gaps design needs every agent's gaps in advance, which no online agent has: fill the gaps",
        )
    n, dz = int(scenario.system.n_agents), int(scenario.cost.dz)
    ys, offs = _means(scenario, log)
    ident = (getattr(scenario, "name", None), scenario_fingerprint(scenario, name))
    if not design_here:
        _refuse_early(scenario, name)
        return Prepared(name, None, [], offs, log.n_steps, scenario.graph, n, dz, *ident)
    d = design if design is not None else scenario.design(name)
    graph = check_deployable(d, scenario.graph)
    batch = check_measurements([np.asarray(y, dtype=float)[None] for y in ys], d.system, d.horizon)[0]
    return Prepared(name, d, batch, offs, log.n_steps, graph, n, dz, *ident)


def _refuse_early(scenario: Any, name: str) -> None:
    """Refuse, without designing, what the registry already says no network runs (the agents refuse the rest)."""
    fam = (getattr(scenario, "families", None) or {}).get(name)
    if fam is None:
        from ..estimators.registry import get_family

        fam = get_family(name, "--estimator")
    opts = scenario.options.get(name) or {}
    if getattr(fam, "uses", None) == "none":
        raise UnsupportedOperationError(
            name, "deployment on a network", "it is the omniscient benchmark (every agent holds every y_j(k) at once); deploy a realizable family"
        )
    if opts.get("variant") == "ideal":
        raise UnsupportedOperationError(name, "deployment on a network", "its 'ideal' variant is not realizable; use variant = \"honest\"")


# ---------------------------------------------------------------------------
# a team run
# ---------------------------------------------------------------------------
@dataclass
class DeployResult:
    """Every agent's estimates and report, and the team's drop record."""

    estimator: str
    estimates: np.ndarray  # (T, n d_z), NaN where an agent did not complete a step
    reports: list[dict[str, Any]]
    record: DropRecord
    failed: dict[int, str] = field(default_factory=dict)  # agent -> why
    wall_s: float = 0.0
    #: the signal that stopped the run (SIGINT, SIGTERM) before its last step, or None
    stopped_by: int | None = None

    def mark_stopped(self, signum: int) -> None:
        """The run was stopped by ``signum``: its record is marked incomplete, with the steps every agent completed."""
        import dataclasses

        done = min((int(r.get("steps_done", 0)) for r in self.reports), default=0)
        self.record = dataclasses.replace(self.record, complete=False, completed=done)
        self.stopped_by = int(signum)

    def summary(self) -> dict[str, Any]:
        return {
            "estimator": self.estimator,
            "agents": len(self.reports),
            "steps": int(self.estimates.shape[0]),
            "failed": {str(a): w for a, w in sorted(self.failed.items())},
            "missed": len(self.record.missed),
            "wall_s": self.wall_s,
            "complete": self.record.complete,
            "completed": self.record.to_json()["completed"],
            "reports": self.reports,
        }


def _merge(prep: Prepared, results: Sequence[AgentResult | None], **info: Any) -> DeployResult:
    n, T, dz = prep.n_agents, prep.n_steps, prep.dz
    z = np.full((T, n * dz), np.nan)
    failed: dict[int, str] = {}
    reports = []
    for i, r in enumerate(results):
        if r is None:
            failed[i] = "no report (the process died)"
            reports.append({"agent": i, "error": failed[i], "steps_done": 0})
            continue
        z[:, i * dz : (i + 1) * dz] = r.estimates
        reports.append(r.to_json())
        if r.steps_done < T or r.error:
            failed[i] = r.error or f"stopped after {r.steps_done} of {T} steps"
    rec = DropRecord.from_results(prep.estimator, results, T, scenario=prep.scenario, fingerprint=prep.fingerprint, **info)
    return DeployResult(prep.estimator, z, reports, rec, failed)


def run_team(
    prep: Prepared,
    *,
    transport: str = "queue",
    deadline: float = 2.0,
    join_timeout: float = 60.0,
    p_drop: float = 0.0,
    rng: int | None = None,
    kill: tuple[int, int] | None = None,
    insecure: bool = False,
) -> DeployResult:
    """Run every agent as a thread of this process, over in-process queues (``"queue"``) or Zenoh on loopback.

    Every frame is signed with a fresh team key (HMAC-SHA256) on both transports; ``insecure`` runs without
    one (plain SHA-256 checksums; for measuring what authentication costs).
    """
    n = prep.n_agents
    run_id = secrets.randbits(63)
    key = None if insecure else secrets.token_bytes(32)
    agents = prep.design.graph_agents()
    if transport == "queue":
        hub = QueueHub(n)
        transports: list[Any] = [hub.transport(i) for i in range(n)]
    elif transport == "zenoh":
        ports = free_ports(n)
        eps = {i: f"tcp/127.0.0.1:{ports[i]}" for i in range(n)}
        transports = [ZenohTransport(i, eps, prefix=f"teamkf/{run_id}") for i in range(n)]
    else:
        raise ArgumentError(f"--transport: expected 'zenoh' or 'queue', found {transport!r}", argument="--transport")
    results: list[AgentResult | None] = [None] * n
    stop = threading.Event()

    def one(i: int) -> None:
        core = AgentCore(prep.design, i, agent=agents[i], graph=prep.graph)
        offs = None if prep.offsets is None else prep.offsets[:, i * core_dz : (i + 1) * core_dz]
        yi = prep.ys[i]
        results[i] = run_agent(
            prep.design,
            i,
            transports[i],
            lambda k: yi[:, k],
            n_steps=prep.n_steps,
            run_id=run_id,
            offsets=offs,
            deadline=deadline,
            join_timeout=join_timeout,
            p_drop=p_drop,
            rng=rng,
            kill_at=kill[1] if kill is not None and kill[0] == i else None,
            stop=stop,
            core=core,
            key=key,
        )

    core_dz = prep.dz
    t0 = time.monotonic()
    threads = [threading.Thread(target=one, args=(i,), name=f"teamkf-agent-{i}", daemon=True) for i in range(n)]
    for t in threads:
        t.start()
    signum = None
    try:
        for t in threads:
            while t.is_alive():
                t.join(0.1)
    except KeyboardInterrupt as exc:  # the agents stop after their step; what they completed is kept
        signum = int(getattr(exc, "signum", signal.SIGINT))
        stop.set()
        for t in threads:
            t.join(10)
    res = _merge(prep, results, run_id=run_id, p_drop=p_drop, seed=rng)
    res.wall_s = time.monotonic() - t0
    if signum is not None:
        res.mark_stopped(signum)
    return res


def _agent_command(
    args: Any, scenario: str, i: int, roster: Path, run_dir: Path, estimator: str, plugins: Sequence[str], design: Path | None = None
) -> list[str]:
    cmd = [sys.executable, "-m", "teamkf"]
    for p in plugins:
        cmd += ["--plugin", p]
    cmd += ["--quiet", "agent", scenario, "--id", str(i), "--roster", str(roster), "--measurements", str(Path(args.measurements).resolve())]
    cmd += ["--out", str(run_dir / f"agent-{i}.npz"), "--report", str(run_dir / f"agent-{i}.json"), "--stream", str(run_dir / f"agent-{i}.f8")]
    cmd += ["--estimator", estimator] + (["--design", str(design)] if design is not None else [])
    if getattr(args, "map", None):
        cmd += ["--map", str(Path(args.map).resolve())]
    cmd += ["--deadline", repr(args.deadline), "--join-timeout", repr(args.join_timeout), "--p-drop", repr(args.p_drop)]
    if args.seed is not None:
        cmd += ["--seed", str(args.seed)]
    if args.kill is not None and args.kill[0] == i:
        cmd += ["--kill-at", str(args.kill[1])]
    if getattr(args, "rate", None) is not None:
        cmd += ["--rate", repr(args.rate)]
    if getattr(args, "insecure", False):
        cmd += ["--insecure"]
    return cmd


def deploy_processes(
    args: Any,
    prep: Prepared,
    on_start: Callable[[list[int]], None] | None = None,
    *,
    run_id: int | None = None,
    slices: Sequence[dict[str, np.ndarray]] | None = None,
) -> DeployResult:
    """One ``teamkf agent`` process per agent over Zenoh on loopback (what ``teamkf deploy`` runs).

    ``slices``: each agent's slice file (:func:`teamkf.study.slices.agent_files`), written into the run
    folder and passed as ``--design``: the agent processes then never design the team.
    """
    n = prep.n_agents
    run_id = secrets.randbits(63) if run_id is None else run_id
    from ..deploy.launcher import Stopped
    from .agent_ops import new_run_dir

    run_dir = new_run_dir()  # teamkf-deploy-<pid>-*, mode 0700 (the key stays private); a later deploy removes it if this process is SIGKILLed
    try:
        ports = free_ports(n)
        key_file = None
        if not getattr(args, "insecure", False):
            key_file = "team.key"
            write_key(run_dir / key_file, secrets.token_bytes(32))  # a fresh key per run, mode 0600
        roster = Roster({i: f"tcp/127.0.0.1:{ports[i]}" for i in range(n)}, run_id, f"teamkf/{run_id}", key_file=key_file)
        rpath = run_dir / "roster.toml"
        roster.write(rpath)
        scen = str(Path(args.scenario).resolve()) if Path(args.scenario).exists() else args.scenario
        plugins = list(getattr(args, "plugin", None) or [])
        designs: list[Path | None] = [None] * n
        if slices is not None:
            from .slices import write_slices

            for i in range(n):
                designs[i] = run_dir / f"agent-{i}.slice.npz"
                write_slices(designs[i], slices[i])  # type: ignore[arg-type]
        cmds = [_agent_command(args, scen, i, rpath, run_dir, prep.estimator, plugins, designs[i]) for i in range(n)]
        timeout = args.timeout if args.timeout is not None else 120.0 + args.join_timeout + prep.n_steps * args.deadline
        t0 = time.monotonic()
        signum = None
        try:
            children = launch(cmds, timeout=timeout, on_start=on_start)
        except Stopped as exc:  # Ctrl-C, SIGTERM: the agents were stopped and reaped; keep what they completed
            signum, children = exc.signum, []
        wall = time.monotonic() - t0
        results: list[AgentResult | None] = [_read_agent(run_dir, i, prep) for i in range(n)]
        res = _merge(prep, results, run_id=run_id, p_drop=args.p_drop, seed=args.seed)
        for i, ch in enumerate(children):
            rep = res.reports[i]
            rep["pid"] = ch.pid
            rep["exit"] = ch.returncode
            rep["peak_rss_mb"] = _peak_rss(run_dir / f"agent-{i}.json")
            if ch.timed_out:
                res.failed[i] = f"killed after the run's timeout ({timeout:g} s)"
            elif ch.returncode < 0:
                res.failed[i] = f"killed by signal {signal.Signals(-ch.returncode).name}" + (
                    f" after {rep['steps_done']} steps" if results[i] is not None else " (nothing written)"
                )
            elif ch.returncode not in (0, 1) and i not in res.failed:
                res.failed[i] = f"exit status {ch.returncode}: {ch.stderr.strip().splitlines()[-1] if ch.stderr.strip() else ''}"
            if ch.returncode == 2 and ch.stderr.strip():
                res.failed[i] = ch.stderr.strip().splitlines()[-1].removeprefix("teamkf: error: ")
        res.wall_s = wall
        if signum is not None:
            res.mark_stopped(signum)
        return res
    finally:
        shutil.rmtree(run_dir, ignore_errors=True)


def _own_peak_rss() -> float | None:
    """This process's peak resident memory in MB: VmHWM of /proc/self/status (ru_maxrss is inherited from the parent; None off Linux)."""
    try:
        for line in Path("/proc/self/status").read_text(encoding="ascii").splitlines():
            if line.startswith("VmHWM:"):
                return round(int(line.split()[1]) / 1024.0, 1)
    except (OSError, ValueError, IndexError):
        pass
    return None


def _peak_rss(report: Path) -> float | None:
    """The agent process's peak resident memory in MB, as its report says (None: no report)."""
    try:
        v = json.loads(report.read_text(encoding="utf-8")).get("peak_rss_mb")
        return None if v is None else float(v)
    except (OSError, ValueError, AttributeError):
        return None


def _read_agent(run_dir: Path, i: int, prep: Prepared) -> AgentResult | None:
    rp, zp = run_dir / f"agent-{i}.json", run_dir / f"agent-{i}.npz"
    if rp.exists() and zp.exists():
        try:
            return _read_report(rp, zp, i, prep)
        except Exception:  # noqa: BLE001 - a report cut short (the process died writing it): what it streamed, as a killed agent
            pass
    part = run_dir / f"agent-{i}.f8"  # killed: what it streamed before it died
    if not part.exists():
        return None
    raw = part.read_bytes()
    rows = min(len(raw) // (8 * prep.dz), prep.n_steps)
    z = np.full((prep.n_steps, prep.dz), np.nan)
    z[:rows] = np.frombuffer(raw[: rows * 8 * prep.dz], dtype="<f8").reshape(rows, prep.dz)
    return AgentResult(i, prep.n_steps, z, rows, error="no report (the process died)")


def _read_report(rp: Path, zp: Path, i: int, prep: Prepared) -> AgentResult:
    d = json.loads(rp.read_text(encoding="utf-8"))
    with np.load(zp, allow_pickle=False) as f:
        z = np.array(f["z"], dtype=float).reshape(prep.n_steps, prep.dz)
        lat = [float(x) for x in f["latency"]] if "latency" in f else []
    r = AgentResult(i, prep.n_steps, z, int(d["steps_done"]), [(int(j), int(s), str(w)) for j, s, w in d["missed"]], dict(d["counts"]))
    r.failed_neighbours = list(d["failed_neighbours"])
    r.tolerant, r.sent, r.dropped_sent, r.cpu_s, r.error = d["tolerant"], d["sent"], d["dropped_sent"], d["cpu_s"], d["error"]
    r.latency = lat
    r.dropped_out = [(int(b), int(s)) for b, s in d.get("dropped_out", [])]
    return r


# ---------------------------------------------------------------------------
# the commands (teamkf.study.deploy_args adds their parsers)
# ---------------------------------------------------------------------------
def _load(arg: str, what: str = "deploy") -> Any:
    """The scenario ``arg`` (a file or a packaged name); a population scenario is refused: it has no agents to ``what``."""
    from .scenario import load_packaged, load_scenario, packaged_scenarios

    p = Path(arg)
    if p.exists() and not p.is_dir():
        sc = load_scenario(p)
    elif arg in packaged_scenarios():
        sc = load_packaged(arg)
    else:
        from ..exceptions import ScenarioError

        raise ScenarioError(f"{arg}: no such scenario file (packaged scenarios: {', '.join(packaged_scenarios())})")
    if getattr(sc, "kind", "team") != "team":
        raise ArgumentError(
            f"SCENARIO: {arg} is a {sc.kind} scenario ([{sc.kind}]): it has no agents to {what}; "
            "deployment needs a scenario with [system], [[agents]] and a graph (e.g. platoon-4)",
            argument="SCENARIO",
        )
    return sc


def _out_suffix(path: str, flag: str, allowed: Sequence[str]) -> str:
    suf = Path(path).suffix.lower()
    if suf not in allowed:
        raise ArgumentError(f"{flag}: expected a file name ending in {' or '.join(allowed)}, found {path!r}", argument=flag)
    return suf


def _table(headers: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    cells = [[str(h) for h in headers]] + [[str(c) for c in r] for r in rows]
    w = [max(len(r[c]) for r in cells) for c in range(len(headers))]
    return "\n".join("  " + "  ".join(x.rjust(w[c]) for c, x in enumerate(r)) for r in cells)


def _fmt_ms(v: Any) -> str:
    return "-" if v is None else f"{v:.2f}"


def cmd_deploy(args: Any) -> int:
    """``teamkf deploy``: exit 0 when every agent completed, 1 when one failed (the report names it)."""
    _deploy_outputs(args)  # before any work: no output is an input, or the other output
    sc = _load(args.scenario)
    log = M.read_log(args.measurements, sc.system, sc.horizon, getattr(args, "map", None))
    _limits.check_deploy(log.n_steps, sc.system.n_agents, deadline=args.deadline, join_timeout=args.join_timeout, timeout=args.timeout)
    name = deploy_estimator(sc, args.estimator)
    if args.kill is not None and not 0 <= args.kill[0] < sc.system.n_agents:
        raise ArgumentError(f"--kill: agent {args.kill[0]} is out of range 0..{sc.system.n_agents - 1}", argument="--kill")
    prep = prepare(sc, log, name)  # designed once, here: each agent process gets its slice
    run_id, files = secrets.randbits(63), None
    if args.transport == "zenoh":
        from .slices import agent_files

        files = agent_files(sc, prep.design, run_id)
        prep = replace(prep, design=None)  # the team design is not needed while the agents run

    def started(pids: list[int]) -> None:
        print(f"teamkf deploy: {len(pids)} agent processes started: pids {' '.join(map(str, pids))}", file=sys.stderr, flush=True)

    if args.transport == "zenoh":
        from ..deploy.transport import zenoh_module

        zenoh_module()  # the install command now, not from six agents later
    if args.transport == "queue":
        from .agent_ops import sigterm_interrupts

        with sigterm_interrupts():
            res = run_team(
                prep,
                transport="queue",
                deadline=args.deadline,
                join_timeout=args.join_timeout,
                p_drop=args.p_drop,
                rng=args.seed,
                kill=args.kill,
                insecure=getattr(args, "insecure", False),
            )
    else:
        res = deploy_processes(args, prep, on_start=started, run_id=run_id, slices=files)
    if res.stopped_by is None and len(res.failed) == prep.n_agents and all(r.get("steps_done", 0) == 0 for r in res.reports):  # nothing ran
        raise ArgumentError(f"no agent ran: agent 0: {res.failed[0]}", argument="SCENARIO")
    from .recording import write_team_estimates

    write_team_estimates(args.out, {name: res.estimates}, prep.n_agents, topic_map=getattr(args, "map", None), start_ns=log.start_ns)
    if args.record:  # atomic too (DropRecord.write)
        res.record.write(args.record)
    if args.json:
        from ..estimators.base import json_float  # noqa: F401  (strict JSON: the reports hold no NaN)

        print(json.dumps({"scenario": sc.name, "out": args.out, "record": args.record, **res.summary()}))
        return _status(res)
    rows = []
    for r in res.reports:
        c = r.get("counts", {})
        bad = sum(v for k, v in c.items() if k in REFUSED)
        rows.append(
            [
                r["agent"],
                r.get("pid", "-"),
                f"{r.get('steps_done', 0)}/{prep.n_steps}",
                len(r.get("missed", [])),
                c.get("late", 0),
                bad,
                _fmt_ms(r.get("median_step_ms")),
                _fmt_ms(r.get("p99_step_ms")),
                "-" if r.get("cpu_s") is None else f"{r['cpu_s']:.2f}",
                "stopped" if res.stopped_by is not None else "failed" if r["agent"] in res.failed else "ok",
            ]
        )
    print(f"{sc.name}: {prep.estimator} on {prep.n_agents} agents ({args.transport}), {prep.n_steps} steps in {res.wall_s:.1f} s")
    print(_table(["agent", "pid", "steps", "missed", "late", "refused", "median ms", "p99 ms", "cpu s", "status"], rows))
    for a, why in sorted(res.failed.items()):
        if res.stopped_by is None:
            print(f"agent {a} failed: {why}")
    print(f"estimates written to {args.out}" + (f"; drop record ({len(res.record.missed)} misses) written to {args.record}" if args.record else ""))
    return _status(res)


def _status(res: DeployResult) -> int:
    """0 every agent completed, 1 one failed, 128 + the signal (130 Ctrl-C, 143 SIGTERM) when the run was stopped."""
    if res.stopped_by is not None:
        name = signal.Signals(res.stopped_by).name
        print(
            f"teamkf deploy: stopped by {name} after {res.record.completed} steps on every agent; the estimates and the record "
            "(marked incomplete) hold the steps completed",
            file=sys.stderr,
        )
        return 128 + res.stopped_by
    return 1 if res.failed else 0


def cmd_agent(args: Any) -> int:
    """``teamkf agent``: exit 0 when it completed its steps, 3 when it completed them after ``--rejoin`` (steps before its rejoin missed), 1 on an error, 130 on Ctrl-C."""
    inputs = _agent_outputs(args)  # before any work: no output is an input, or another output
    sc = _load(args.scenario, "run")
    n = sc.system.n_agents
    if not 0 <= args.id < n:
        raise ArgumentError(f"--id: expected an agent id in 0..{n - 1}, found {args.id}", argument="--id")
    roster = Roster.read(args.roster)
    roster.check(n)
    if roster.key is None and not getattr(args, "insecure", False):
        raise ArgumentError(
            f'{roster.source}: no key_file: every frame must be signed with the team key; add key_file = "team.key" '
            "(teamkf roster new writes a roster and a key), or run with --insecure on a network nobody else reaches",
            argument="--roster",
        )
    roster.check_network(args.id)  # every host resolves, this agent's endpoint is free here: one line, before any work
    i = args.id
    name = deploy_estimator(sc, args.estimator)
    _limits.check_agent(args, sc)  # --steps, --deadline and the work limit, before the design
    from .slices import agent_design

    design, agent = agent_design(args, sc, name, roster.run_id)  # --design: its slice (no team design); else the team design
    dz = int(design.cost.dz)
    if args.measurements == "-":
        T = args.steps if args.steps is not None else sc.horizon
        if T is None:
            raise ArgumentError("--steps: a steady-state scenario reading stdin needs --steps T", argument="--steps")
        known = M.known_inputs(sc)
        ybar, offs = None, None
        if known is not None:
            mean, yb = known.means(sc.system, T)
            ybar, offs = yb[i], np.stack([sc.cost.L_at(k) @ mean[k] for k in range(T)])[:, i * dz : (i + 1) * dz]
        from .agent_input import StepLines

        source: Callable[[int], Any] = StepLines(sys.stdin, int(sc.system.dy[i]), T, ybar, agent=i, estimator=name)
    else:
        if args.map:
            log = M.read_log(args.measurements, sc.system, sc.horizon, args.map, agents=[i])  # a recording: its own topics only
        else:
            from .agent_input import read_own_log

            log = read_own_log(args.measurements, sc.system, sc.horizon, i)  # its own rows, or a team log
        _limits.check_agent(args, sc, min(log.n_steps, args.steps or log.n_steps))
        prep = prepare(sc, log, name, design=design)
        T = prep.n_steps if args.steps is None else min(args.steps, prep.n_steps)
        yi = prep.ys[i]  # only this agent's column is kept
        offs = None if prep.offsets is None else prep.offsets[:, i * dz : (i + 1) * dz]
        del prep, log

        def own_column(k: int) -> Any:
            return yi[:, k]

        source = own_column

    from .agent_ops import AgentStream, check_rejoin, rate_limited, report_json

    core = check_rejoin(design, i, sc.graph, rejoin=bool(getattr(args, "rejoin", False)), agent=agent)  # before the network: one line
    transport = ZenohTransport(i, roster.endpoints, prefix=roster.prefix, tls=roster.tls)
    try:
        transport.open()  # what Zenoh still refuses (the roster was checked): one line naming the roster and the endpoint
    except TransportError as exc:
        raise ArgumentError(f"{roster.source}: {exc}", argument="--roster") from None
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    sinks: list[Callable[[int, np.ndarray], None]] = []
    if args.out == "-":
        sinks.append(lambda k, z: print(",".join([str(k), *(repr(float(v)) for v in z)]), flush=True))
    keep = bool(getattr(args, "rejoin", False))  # a rejoined agent continues the stream of the process before
    stream = AgentStream(args.stream, dz, keep=keep, opener=lambda: open_stream(args.stream, "--stream", inputs=inputs)) if args.stream else None
    if stream is not None:
        sinks.append(stream.write)

    def printer(k: int, z: np.ndarray) -> None:
        for f in sinks:
            f(k, z)

    res = run_agent(
        design,
        i,
        transport,
        rate_limited(source, getattr(args, "rate", None), stop),
        n_steps=T,
        run_id=roster.run_id,
        peers=roster.agents,
        offsets=offs,
        deadline=args.deadline,
        join_timeout=args.join_timeout,
        p_drop=args.p_drop,
        rng=args.seed,
        kill_at=args.kill_at,
        hard_kill=True,
        on_estimate=printer if sinks else None,
        stop=stop,
        graph=sc.graph,
        core=core,
        rejoin=bool(getattr(args, "rejoin", False)),
        key=roster.key,
    )
    if stream is not None:
        stream.close()
    if args.out and args.out != "-":
        _write_own(args.out, res, name)
    run = {"run_id": roster.run_id, "scenario": getattr(sc, "name", None), "fingerprint": scenario_fingerprint(sc, name), "estimator": name}
    run.update({"agents": n, "steps": T, "p_drop": args.p_drop, "seed": args.seed})
    if args.report:
        extra = {
            "run": run,
            "previous_steps": None if stream is None else stream.previous,
            "input": getattr(source, "counts", None),
            "peak_rss_mb": _own_peak_rss(),
        }
        report = json.dumps(report_json(res, **extra)) + "\n"
        write_atomic(args.report, lambda fh: fh.write(report), text=True)
    if res.error == "interrupted":
        print(f"teamkf agent {i}: interrupted after {res.steps_done} steps", file=sys.stderr)
        return 130
    if res.error:
        print(f"teamkf: error: agent {i}: {res.error}", file=sys.stderr)
        return 1
    if res.started > 0:  # rejoined: it completed, without its steps before the rejoin
        print(f"teamkf agent {i}: rejoined at step {res.started}: steps 0..{res.started - 1} are not this process's", file=sys.stderr)
        return 3
    return 0


def _deploy_outputs(args: Any) -> None:
    """``teamkf deploy``'s --out and --record, checked against every input and each other (:mod:`teamkf.study.outputs`)."""
    inputs = command_inputs(args.scenario, args.measurements, getattr(args, "map", None))
    out = check_output(args.out, "--out", fmt=(".csv", ".parquet", ".mcap"), inputs=inputs)
    if out.suffix.lower() == ".mcap" and getattr(args, "map", None) is None:
        raise ArgumentError(
            f"--out: {args.out} is a ROS 2 recording (.mcap): its time stamps need a topic map (--map MAP.toml with period and start)",
            argument="--out",
        )
    if args.record:
        check_output(args.record, "--record", inputs=inputs, outputs=[(out, "--out")])


def _agent_outputs(args: Any) -> list[str]:
    """``teamkf agent``'s --out, --report and --stream, checked against every input and each other; returns the inputs."""
    inputs = command_inputs(args.scenario, args.roster, args.measurements, getattr(args, "design", None), getattr(args, "map", None))
    outs: list[tuple[Any, str]] = []
    if args.out and args.out != "-":
        outs.append((check_output(args.out, "--out", fmt=(".csv", ".parquet", ".npz"), inputs=inputs), "--out"))
    if args.report:
        outs.append((check_output(args.report, "--report", inputs=inputs, outputs=outs), "--report"))
    if args.stream:
        check_output(args.stream, "--stream", inputs=inputs, outputs=outs)
    return inputs


def _write_own(path: str, res: AgentResult, name: str) -> None:
    suf = Path(path).suffix.lower()
    if suf == ".npz":
        write_atomic(path, lambda fh: np.savez(fh, z=res.estimates, latency=np.asarray(res.latency, dtype=float), steps_done=res.steps_done))
        return
    from .. import _validation as V

    pd = V.require("pandas", "dask")
    z = res.estimates
    cols: dict[str, Any] = {"step": np.arange(z.shape[0]), "agent": res.index, "estimator": name}
    cols.update({f"z{c}": z[:, c] for c in range(z.shape[1])})
    frame = pd.DataFrame(cols)
    write_atomic(path, lambda fh: M.write_frame(frame, fh, suf))


def cmd_filter_drops(args: Any) -> int:
    """``teamkf filter SCENARIO --measurements LOG --drops DROPS --out EST``: replay a deployment in-process."""
    _out_suffix(args.out, "--out", (".csv", ".parquet"))
    rec = DropRecord.read(args.drops)
    if args.estimators and list(args.estimators) != [rec.estimator]:
        raise ArgumentError(f"--estimators: the drop record is of {rec.estimator!r}; drop --estimators or name only it", argument="--estimators")
    if getattr(args, "truth", None):
        raise ArgumentError("--truth: not available with --drops (the replay writes the estimates only)", argument="--truth")
    sc = _load(args.scenario, "replay")
    from ..estimators.registry import get_family

    get_family(rec.estimator, f"{rec.source}: estimator")  # a family of another installation: named as the record's entry
    rec.check(n_agents=sc.system.n_agents, n_steps=rec.n_steps, scenario=sc.name, fingerprint=scenario_fingerprint(sc, rec.estimator))
    log = M.read_log(args.measurements, sc.system, sc.horizon, getattr(args, "map", None))
    _limits.check_filter(log.n_steps, sc.system.n_agents, [rec.estimator], what="teamkf filter --drops")
    prep = prepare(sc, log, rec.estimator)
    z = replay(prep.design, prep.ys, rec, prep.offsets, graph=prep.graph)  # checks the record's steps against the log's, its misses against the graph
    fmt = Path(args.out).suffix.lower()
    write_atomic(args.out, lambda fh: M.write_estimates(fh, {rec.estimator: z}, prep.n_agents, fmt=fmt))
    if args.json:
        print(json.dumps({"scenario": sc.name, "out": args.out, "estimator": rec.estimator, "steps": rec.n_steps, "missed": len(rec.missed)}))
        return 0
    print(f"{sc.name}: {rec.estimator} replayed in-process with {len(rec.missed)} missed messages from {args.drops}; estimates written to {args.out}")
    return 0
