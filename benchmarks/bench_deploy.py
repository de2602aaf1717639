"""Step latency and CPU of deployed agents (``teamkf deploy``), on loopback.

    PYTHONPATH=src python3 benchmarks/bench_deploy.py                  # n = 2, 4, 6 agents, 200 steps
    PYTHONPATH=src python3 benchmarks/bench_deploy.py --agents 6 --steps 400 --repeat 3
    PYTHONPATH=src python3 benchmarks/bench_deploy.py --auth on off        # authentication on and off, side by side
    PYTHONPATH=src python3 benchmarks/bench_deploy.py --scale 24 --steps 200   # memory and wall time at scale

``--scale N``: one ``teamkf deploy`` of an N-vehicle platoon (d_x = N, N agent processes, KCF,
the parent designs once and ships each agent its slice), checked byte-equal to ``teamkf filter``;
it prints each agent process's peak resident memory (VmHWM, from the agents' reports), the
parent's peak, and the wall times of deploy and filter.

A platoon of n vehicles on a line graph with unit delays (the packaged ``platoon-6`` for n = 6,
the same model for other n), KCF agents, a log sampled with teamkf (seed 2026). Three ways to run
the same agents:

zenoh processes   ``teamkf deploy``: one OS process per agent, Zenoh peers on 127.0.0.1
zenoh threads     every agent a thread of one process, each with its own Zenoh session
queue threads     every agent a thread of one process, in-process queues (no network)

Step latency: per agent and step, from the moment it starts waiting for the messages due at the
step to the moment its payload is sent — in lockstep this is the team's step period. The table
gives the median over agents of each agent's median, and the largest per-agent p99. CPU: the
agent thread's CPU time over the run (its steps; not the import, the design or Zenoh's own
threads), mean over agents. ``--auth on off`` runs every configuration with signed frames (HMAC-SHA256
under a team key, payload checks; the default) and without (``--insecure``), interleaved repeat by
repeat so that both see the same load. Timings are noisy on a shared machine: the load average is printed,
and every configuration is run --repeat times (the median repeat is reported). Every run also
checks that the estimates equal the in-process runtime's bit for bit.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np


def platoon(n: int, T: int) -> dict:
    A = 0.9 * np.eye(n) + 0.5 * np.eye(n, k=-1)
    return {
        "name": f"platoon-{n}-deploy",
        "horizon": T,
        "estimators": ["kcf"],
        "system": {"A": A.tolist(), "Q": 1.0, "Sigma_x": 1.0},
        "agents": [{"C": [np.eye(n)[i].tolist()], "R": 0.1} for i in range(n)],
        "graph": {"kind": "line", "delay": 1},
        "cost": {"kind": "platoon", "lambda": 100.0},
    }


def summarize(reports: list[dict]) -> tuple[float, float, float]:
    med = float(np.median([r["median_step_ms"] for r in reports]))
    p99 = float(max(r["p99_step_ms"] for r in reports))
    cpu = float(np.mean([r["cpu_s"] for r in reports]))
    return med, p99, cpu


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--agents", type=int, nargs="+", default=[2, 4, 6])
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--modes", nargs="+", default=["zenoh processes", "zenoh threads", "queue threads"])
    ap.add_argument("--auth", nargs="+", choices=("on", "off"), default=["on"], help="signed frames (on, the default) and/or unsigned (off)")
    ap.add_argument("--scale", type=int, metavar="N", help="one deploy of an N-vehicle platoon: per-agent peak memory and wall time")
    args = ap.parse_args()
    if args.scale:
        return scale(args.scale, args.steps)
    from teamkf.simulation.sampling import sample_paths
    from teamkf.study import measurements as M
    from teamkf.study.deploy import prepare, run_team
    from teamkf.study.scenario import scenario_from_dict

    print(f"load average {os.getloadavg()}; {os.cpu_count()} CPUs; KCF agents, line graph, unit delays, {args.steps} steps")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in args.agents:
            d = platoon(n, args.steps)
            spath = Path(tmp) / f"platoon-{n}.json"
            spath.write_text(json.dumps(d))
            sc = scenario_from_dict(d)
            paths = sample_paths(sc.system, args.steps, 1, rng=2026)
            lpath = Path(tmp) / f"log-{n}.csv"
            M.write_measurements(lpath, [y[0] for y in paths.y])
            log = M.read_measurements(lpath, sc.system, sc.horizon)
            prep = prepare(sc, log, "kcf")
            ref = M.filter_log(sc, log, estimators=["kcf"], with_innovations=False).estimates["kcf"]
            for mode in args.modes:
                got: dict[str, list] = {a: [] for a in args.auth}
                for _ in range(args.repeat):
                    for auth in args.auth:  # interleaved: on and off see the same load
                        insecure = auth == "off"
                        if mode == "zenoh processes":
                            out = Path(tmp) / "est.csv"
                            cmd = [sys.executable, "-m", "teamkf", "deploy", str(spath), "--measurements", str(lpath), "--out", str(out), "--json"]
                            proc = subprocess.run(cmd + ["--insecure"] * insecure, capture_output=True, text=True)
                            if proc.returncode != 0:
                                raise SystemExit(proc.stderr)
                            reports = json.loads(proc.stdout)["reports"]
                            import pandas as pd

                            est = pd.read_csv(out)
                            z = est.sort_values(["step", "agent"])[[c for c in est.columns if c.startswith("z")]].to_numpy().reshape(args.steps, -1)
                            equal = np.array_equal(z, ref)
                        else:
                            res = run_team(prep, transport=mode.split()[0], insecure=insecure)
                            reports, equal = res.reports, res.estimates.tobytes() == ref.tobytes()
                        got[auth].append((*summarize(reports), equal))
                for auth in args.auth:
                    g = sorted(got[auth])
                    med, p99, cpu, equal = g[len(g) // 2]
                    rows.append((mode, auth, n, args.steps, med, p99, cpu, all(x[3] for x in g)))
                    print(
                        f"  {mode:16s} auth {auth:3s} n={n}: median {med:.2f} ms, p99 {p99:.2f} ms, CPU/agent {cpu:.3f} s, equal: {equal}", flush=True
                    )
    print("\n| transport | authentication | agents | steps | median step (ms) | p99 step (ms) | CPU per agent (s) | bit-equal |")
    print("|---|:---:|---:|---:|---:|---:|---:|:---:|")
    for mode, auth, n, T, med, p99, cpu, eq in rows:
        print(f"| {mode} | {auth} | {n} | {T} | {med:.2f} | {p99:.2f} | {cpu:.3f} | {'yes' if eq else 'NO'} |")


def scale(n: int, T: int) -> None:
    """``teamkf deploy`` of an n-vehicle platoon (d_x = n) over T steps: peak memory per agent process, wall time, byte-equal to filter."""
    import resource
    import time

    from teamkf.simulation.sampling import sample_paths
    from teamkf.study import measurements as M
    from teamkf.study.scenario import scenario_from_dict

    print(f"load average {os.getloadavg()}; {os.cpu_count()} CPUs; KCF, {n} agents, d_x = {n}, line graph, unit delays, T = {T}")
    with tempfile.TemporaryDirectory() as tmp:
        d = platoon(n, T)
        spath, lpath = Path(tmp) / f"platoon-{n}.json", Path(tmp) / "log.csv"
        spath.write_text(json.dumps(d))
        sc = scenario_from_dict(d)
        M.write_measurements(lpath, [y[0] for y in sample_paths(sc.system, T, 1, rng=2026).y])
        walls, outs = {}, {}
        for cmd in ("deploy", "filter"):
            outs[cmd] = Path(tmp) / f"{cmd}.csv"
            flags = ["--estimator", "kcf", "--deadline", "10", "--json"] if cmd == "deploy" else ["--estimators", "kcf"]
            t0 = time.monotonic()
            proc = subprocess.run(
                [sys.executable, "-m", "teamkf", cmd, str(spath), "--measurements", str(lpath), "--out", str(outs[cmd]), *flags],
                capture_output=True,
                text=True,
            )
            walls[cmd] = time.monotonic() - t0
            if proc.returncode != 0:
                raise SystemExit(proc.stderr)
            if cmd == "deploy":
                summary = json.loads(proc.stdout)
                parent = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024  # the largest child so far: deploy's parent
        peaks = [r["peak_rss_mb"] for r in summary["reports"]]
        equal = outs["deploy"].read_bytes() == outs["filter"].read_bytes()
    print(
        "\n| agents | d_x | T | agent peak RSS (MB), max | median | deploy parent peak (MB) | deploy wall (s) | agents' run (s) | filter wall (s) | byte-equal |"
    )
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|:---:|")
    print(
        f"| {n} | {n} | {T} | {max(peaks):.0f} | {float(np.median(peaks)):.0f} | {parent:.0f} | {walls['deploy']:.1f} | {summary['wall_s']:.1f} "
        f"| {walls['filter']:.1f} | {'yes' if equal else 'NO'} |"
    )


if __name__ == "__main__":
    main()
