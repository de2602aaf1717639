"""Speed and scale of the exact bulk filter and of the explicit-agent simulation.

Each case runs in its own subprocess so that its peak memory (max RSS) is its own; timings are
the best of ``--repeat`` runs (default 3: the machine is shared and timings vary by 2-10x).

    PYTHONPATH=src python3 benchmarks/bench_bulk.py                       # everything
    PYTHONPATH=src python3 benchmarks/bench_bulk.py --only gains --sizes 1000 5000
    PYTHONPATH=src python3 benchmarks/bench_bulk.py --only sim

Cases
-----
gains   exact gains K_1..K_T (teamkf.estimators.bulk.exact_bulk_filter + BulkFilter.gains) for
        several T in four regimes:
          stationary  a = 2.5, f = 2, N = 1000 (coefficients decay: banded recursion)
          hugeN       a = 2.5, f = 2, N = 10^9
          periodic    a = 5, f = 4.5, N = 1000 (persistently time-varying, Section 4.4)
          dense       a = 3.9, a_f = 0.99, N = 1000 (nothing decays below the flush threshold
                      within T <= 6000: the worst case, one full k x k matrix-vector product per step)
        Reports the recursion time (innovation form, everything the closed loop needs), the time
        of K_T alone (one triangular solve) and of all K_k (one triangular inversion), FLOP
        counts and rates, and the peak memory.
matmul  this machine's dense matrix-multiply rate (numpy, default BLAS threads and one thread),
        the reference for the FLOP rates.
sim     closed-loop simulation of N = 10^4 explicit agents for T = 1000 steps with the exact filter.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time


def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


REGIMES = {
    "stationary": dict(n_agents=1000, a=2.5, f=2.0),
    "hugeN": dict(n_agents=10**9, a=2.5, f=2.0),
    "periodic": dict(n_agents=1000, a=5.0, f=4.5),
    "dense": dict(n_agents=1000, a=3.9, f=3.9 - 0.99),
}


def case_gains(regime: str, T: int, all_gains: bool, repeat: int) -> dict:
    from teamkf.estimators.bulk import exact_bulk_filter
    from teamkf.models.population import PopulationModel

    m = PopulationModel(**REGIMES[regime])  # type: ignore[arg-type]
    exact_bulk_filter(m, 20).gains()  # warm imports and BLAS
    rec, fin, allk = [], [], []
    for _ in range(repeat):  # the machine is shared: report the best of `repeat` runs
        t0 = time.perf_counter()
        bf = exact_bulk_filter(m, T)
        t1 = time.perf_counter()
        KT = bf.final_gains()
        t2 = time.perf_counter()
        rec.append(t1 - t0)
        fin.append(t2 - t1)
        if all_gains:
            t3 = time.perf_counter()
            G = bf.gains()
            allk.append(time.perf_counter() - t3)
            rows_agree = float(abs(G[-1] - KT).max())
            del G
        band, flops, delta = bf.band, bf.flops, bf.stationarity_index()
        del bf  # so that the next repeat's peak memory is its own
    out = {
        "case": "gains",
        "regime": regime,
        "T": T,
        "repeat": repeat,
        "recursion_s": min(rec),
        "recursion_s_all": rec,
        "final_gain_s": min(fin),
        "band": band,
        "recursion_flops": flops,
        "recursion_gflops": flops / min(rec) / 1e9,
        "K_T_last": [float(v) for v in KT[-3:]],
        "delta": delta,
    }
    if all_gains:
        fl = T**3 / 3.0 + T * T  # dtrtri + the row recursion
        out.update(
            all_gains_s=min(allk),
            all_gains_s_all=allk,
            all_gains_flops=fl,
            all_gains_gflops=fl / min(allk) / 1e9,
            total_s=min(rec) + min(allk),
            rows_agree=rows_agree,
        )
    out["peak_mb"] = _peak_mb()
    return out


def case_matmul(n: int, threads: str) -> dict:
    import numpy as np

    from teamkf.estimators.bulk import single_thread_blas

    A = np.random.default_rng(0).standard_normal((n, n))
    B = np.random.default_rng(1).standard_normal((n, n))
    A @ B
    ctx = single_thread_blas() if threads == "1" else None
    best = float("inf")
    if ctx is not None:
        with ctx:
            for _ in range(3):
                t0 = time.perf_counter()
                A @ B
                best = min(best, time.perf_counter() - t0)
    else:
        for _ in range(3):
            t0 = time.perf_counter()
            A @ B
            best = min(best, time.perf_counter() - t0)
    # matrix-vector rate on a k x k block of a larger array (what the recursion does)
    x = np.ones(n)
    with single_thread_blas():
        t0 = time.perf_counter()
        for _ in range(20):
            A @ x
        mv = (time.perf_counter() - t0) / 20
    return {
        "case": "matmul",
        "n": n,
        "threads": threads,
        "gemm_gflops": 2 * n**3 / best / 1e9,
        "gemv_1thread_gflops": 2 * n * n / mv / 1e9,
        "gemv_1thread_GBps": 8 * n * n / mv / 1e9,
    }


def case_sim(regime: str, N: int, T: int, repeat: int) -> dict:
    from teamkf.control import simulate_population
    from teamkf.estimators.bulk import exact_bulk_filter
    from teamkf.models.population import PopulationModel

    m = PopulationModel(**{**REGIMES[regime], "n_agents": N})  # type: ignore[arg-type]
    fil, sims = [], []
    for _ in range(repeat):
        t0 = time.perf_counter()
        bf = exact_bulk_filter(m, T)
        t1 = time.perf_counter()
        sim = simulate_population(m, T, n_runs=1, rng=1, filt=bf)
        t2 = time.perf_counter()
        fil.append(t1 - t0)
        sims.append(t2 - t1)
    cov = bf.covariances
    return {
        "case": "sim",
        "regime": regime,
        "N": N,
        "T": T,
        "repeat": repeat,
        "filter_s": min(fil),
        "simulate_s": min(sims),
        "simulate_s_all": sims,
        "total_s": min(fil) + min(sims),
        "band": bf.band,
        "agent_steps_per_s": N * T / min(sims),
        "empirical_Ex2_T": float(sim.second_moment[0, -1]),
        "exact_Ex2_T": float(cov.state_variance[-1] + cov.state_mean[-1] ** 2),
        "mc_cost": float(sim.lq_cost[0]),
        "peak_mb": _peak_mb(),
    }


def _run(args: list[str], timeout: float) -> dict:
    p = subprocess.run([sys.executable, __file__, "--case", *args], capture_output=True, text=True, timeout=timeout, env=dict(os.environ))
    if p.returncode != 0:
        return {"case": args[0], "args": args, "error": p.stderr.strip().splitlines()[-1] if p.stderr else f"exit {p.returncode}"}
    return json.loads(p.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--case", nargs="+", help=argparse.SUPPRESS)
    ap.add_argument("--only", choices=["gains", "matmul", "sim"], action="append")
    ap.add_argument("--sizes", type=int, nargs="+", default=[500, 1000, 2000, 3000, 5000])
    ap.add_argument("--regimes", nargs="+", default=list(REGIMES))
    ap.add_argument("--repeat", type=int, default=3, help="report the best of this many runs (shared machine)")
    ap.add_argument("--json", help="also write the rows to this file")
    ap.add_argument("--timeout", type=float, default=1800)
    a = ap.parse_args()
    if a.case:
        name, *rest = a.case
        fn = {
            "gains": lambda: case_gains(rest[0], int(rest[1]), rest[2] == "1", int(rest[3])),
            "matmul": lambda: case_matmul(int(rest[0]), rest[1]),
            "sim": lambda: case_sim(rest[0], int(rest[1]), int(rest[2]), int(rest[3])),
        }[name]
        print(json.dumps(fn()))
        return
    todo = a.only or ["matmul", "gains", "sim"]
    rows = []
    print(
        f"# python {sys.version.split()[0]}, cpus {os.cpu_count()}, threads env "
        f"{ {k: os.environ.get(k) for k in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS')} }"
    )
    if "matmul" in todo:
        for threads in ("default", "1"):
            r = _run(["matmul", "3000", threads], a.timeout)
            rows.append(r)
            print(
                f"dense matmul n=3000, BLAS threads {threads}: {r.get('gemm_gflops', float('nan')):.1f} GFLOP/s; "
                f"gemv (1 thread) {r.get('gemv_1thread_gflops', float('nan')):.1f} GFLOP/s = {r.get('gemv_1thread_GBps', float('nan')):.1f} GB/s"
            )
    if "gains" in todo:
        print(
            f"{'regime':>10} {'T':>6} {'band':>5} {'recursion[s]':>12} {'K_T[s]':>7} {'all K[s]':>9} {'total[s]':>9} "
            f"{'rec GF':>9} {'rec GF/s':>8} {'allK GF/s':>9} {'peak MB':>8}"
        )
        for regime in a.regimes:
            for T in a.sizes:
                r = _run(["gains", regime, str(T), "1", str(a.repeat)], a.timeout)
                rows.append(r)
                if "error" in r:
                    print(regime, T, r["error"])
                    continue
                print(
                    f"{regime:>10} {T:>6} {r['band']:>5} {r['recursion_s']:>12.3f} {r['final_gain_s']:>7.3f} {r['all_gains_s']:>9.3f} "
                    f"{r['total_s']:>9.3f} {r['recursion_flops'] / 1e9:>9.2f} {r['recursion_gflops']:>8.2f} {r['all_gains_gflops']:>9.1f} "
                    f"{r['peak_mb']:>8.0f}",
                    flush=True,
                )
    if "sim" in todo:
        for regime in ("stationary", "periodic"):
            r = _run(["sim", regime, "10000", "1000", str(a.repeat)], a.timeout)
            rows.append(r)
            if "error" in r:
                print("sim", regime, r["error"])
                continue
            print(
                f"simulate N=10^4 T=1000 {regime:>10}: filter {r['filter_s']:.2f} s + simulation {r['simulate_s']:.2f} s = "
                f"{r['total_s']:.2f} s (band {r['band']}, {r['agent_steps_per_s'] / 1e6:.2f} M agent-steps/s, peak {r['peak_mb']:.0f} MB; "
                f"(1/N) sum x_T^2 = {r['empirical_Ex2_T']:.3f} vs exact E x_T^2 = {r['exact_Ex2_T']:.3f})",
                flush=True,
            )
    if a.json:
        with open(a.json, "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
