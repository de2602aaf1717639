"""Speed and scale of MTMSE designs (numbers for docs/performance.md and the closing notes).

Each case runs in its own subprocess so that its peak memory (max RSS) is its own.

    PYTHONPATH=src OPENBLAS_NUM_THREADS=1 python3 benchmarks/bench_design.py            # everything
    PYTHONPATH=src python3 benchmarks/bench_design.py --only uav --uav-sizes 10 100 300 1000
    PYTHONPATH=src python3 benchmarks/bench_design.py --only platoon-scale --platoon-sizes 6 8 10 12

Cases
-----
uav            steady-state MTMSE design of the UAV formation (Section IV-A: complete graph,
               delay 2, cost (5) with lambda = 10 n^2) for several n; the DARE alone by the
               doubling algorithm and by scipy.linalg.solve_discrete_are in the same run.
platoon-finite finite-horizon design of the 4-vehicle platoon, T = 100.
platoon-scale  steady-state design of platoons with n vehicles (line graph, unit delays,
               tau* = n - 1, every vehicle measures all positions): time and peak memory.
gamma          the Gamma F = eta crossover: dense Cholesky vs the CG operator on the same steps.
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


def case_uav(n: int, scipy_max: int) -> dict:
    import numpy as np
    import scipy.linalg as sla

    from teamkf import CommGraph, InformationStructure, LinearGaussianSystem, TeamCost, design_mtmse
    from teamkf.estimators.riccati import solve_filter_dare

    t0 = time.perf_counter()
    system = LinearGaussianSystem.uav_formation(n)
    cost = TeamCost.average_tracking(n, 10.0 * n * n)
    graph = CommGraph.complete(n, 2)
    structure = InformationStructure.from_graph(graph)
    t1 = time.perf_counter()
    design = design_mtmse(system, cost, structure)
    t2 = time.perf_counter()
    A, C, Q, R = system.A_at(0), system.C_stack(0), system.Q_at(0), system.R_stack(0)
    t3 = time.perf_counter()
    P_sda = solve_filter_dare(A, C, Q, R, method="sda", check=False)
    t4 = time.perf_counter()
    out = {
        "case": "uav",
        "n": n,
        "setup_s": t1 - t0,
        "design_s": t2 - t1,
        "total_s": t2 - t0,
        "dare_sda_s": t4 - t3,
        "average_cost": design.average_cost,
        "gamma": design.info["gamma"],
    }
    if n <= scipy_max:
        t5 = time.perf_counter()
        P_sp = sla.solve_discrete_are(A.T, C.T, Q, R)
        t6 = time.perf_counter()
        out["dare_scipy_s"] = t6 - t5
        out["scipy_over_sda"] = (t6 - t5) / (t4 - t3)
        out["scipy_over_design"] = (t6 - t5) / (t2 - t1)
        out["whole_over_scipy"] = (t2 - t0) / (t6 - t5)  # what a user waits for (set-up + design) per second of scipy's DARE
        out["dare_rel_diff"] = float(np.linalg.norm(P_sp - P_sda) / np.linalg.norm(P_sp))
    out["peak_mb"] = _peak_mb()
    return out


def case_platoon_finite(n: int, T: int) -> dict:
    from teamkf import CommGraph, LinearGaussianSystem, TeamCost, design_mtmse

    system, cost, graph = LinearGaussianSystem.platoon(n), TeamCost.platoon(n, 100.0), CommGraph.line(n)
    design_mtmse(system, cost, graph, horizon=3)  # warm imports
    t0 = time.perf_counter()
    d = design_mtmse(system, cost, graph, horizon=T)
    t1 = time.perf_counter()
    return {"case": "platoon-finite", "n": n, "T": T, "design_s": t1 - t0, "total_cost": d.total_cost, "peak_mb": _peak_mb()}


def case_platoon_scale(n: int, method: str) -> dict:
    from teamkf import CommGraph, LinearGaussianSystem, TeamCost, design_mtmse

    system, cost, graph = LinearGaussianSystem.platoon(n), TeamCost.platoon(n, 100.0), CommGraph.line(n)
    load0 = os.getloadavg()[0]
    t0, c0 = time.perf_counter(), time.process_time()
    d = design_mtmse(system, cost, graph, method=method)  # type: ignore[arg-type]
    t1, c1 = time.perf_counter(), time.process_time()
    return {
        "case": "platoon-scale",
        "n": n,
        "method": method,
        "design_s": t1 - t0,
        "design_cpu_s": c1 - c0,
        "load_1min": [load0, os.getloadavg()[0]],
        "average_cost": d.average_cost,
        "gamma": d.info["gamma"],
        "window": (n - 1) * n * n,
        "threads": {k: os.environ.get(k) for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")},
        "peak_mb": _peak_mb(),
    }


def case_gamma(kind: str, n: int) -> dict:
    """Time dense vs CG on the steady-state step of one instance."""
    import numpy as np

    from teamkf import CommGraph, LinearGaussianSystem, TeamCost
    from teamkf.estimators.gamma import GammaProblem, InnovationsProblem, WindowModel, innovations_pays
    from teamkf.estimators.kalman import steady_state
    from teamkf.estimators.team import _eta, _local_index, window_covariances
    from teamkf.network.information import InformationStructure

    if kind == "platoon":
        system, cost, graph = LinearGaussianSystem.platoon(n), TeamCost.platoon(n, 100.0), CommGraph.line(n)
    else:
        system, cost, graph = LinearGaussianSystem.uav_formation(n), TeamCost.average_tracking(n, 10.0 * n * n), CommGraph.complete(n, 2)
    st = InformationStructure.from_graph(graph)
    c = st.common_lag
    P, _, _ = steady_state(system)
    Sig, Th, _ = window_covariances(system, c - 1, 0, P)
    idx = [_local_index(system, st, i, c - 1, 0) for i in range(n)]
    eta = _eta(cost.S_at(0), cost.L_at(0), Th, idx, cost.dz)
    out: dict = {"case": "gamma", "kind": kind, "n": n}
    sols = {}
    for m in ("dense", "cg"):
        g = GammaProblem(cost.S_at(0), Sig, idx, cost.dz)
        out["size"] = g.size
        if m == "dense" and 8 * g.size**2 > 2 * 2**30:
            out["dense_s"] = None
            continue
        t0 = time.perf_counter()
        sols[m] = g.flatten(g.solve(eta, method=m))  # type: ignore[arg-type]
        out[f"{m}_s"] = time.perf_counter() - t0
        if m == "cg":
            out["cg_iterations"] = g.iterations
        out["auto_choice"] = g.choose("auto")
    if len(sols) == 2:
        out["rel_diff"] = float(np.linalg.norm(sols["dense"] - sols["cg"]) / np.linalg.norm(sols["dense"]))
    # the designs' CG: innovation coordinates (no window covariance); costs by gains_cost (no eq. 35 cancellation)
    w = c
    out["innovations_pays"] = innovations_pays(cost.S_at(0), idx, cost.dz, system.dx, system.dy_total, w)
    if not out["innovations_pays"]:  # every agent filters the whole state: n w d_x^3 (hours for the UAV n = 1000)
        out["peak_mb"] = _peak_mb()
        return out
    model = WindowModel(
        [system.A_at(u) for u in range(w - 1)],
        [system.Q_at(u) for u in range(w - 1)],
        [system.C_stack(u) for u in range(w)],
        [system.R_stack(u) for u in range(w)],
        P,
    )
    t0 = time.perf_counter()
    inn = InnovationsProblem(cost.S_at(0), cost.L_at(0), model, idx, cost.dz)
    F_inn, J_inn = inn.solve()
    out["innov_s"] = time.perf_counter() - t0
    out["innov_iterations"] = inn.iterations
    out["innov_cost"] = J_inn
    for m, x in sols.items():
        J_m = inn.gains_cost(g.unflatten(x))
        out[f"{m}_cost"] = J_m
        out[f"innov_vs_{m}_cost"] = abs(J_inn - J_m) / abs(J_m)
        out[f"innov_vs_{m}_gains"] = float(np.linalg.norm(g.flatten(F_inn) - x) / np.linalg.norm(x))
    out["peak_mb"] = _peak_mb()
    return out


def _run(args: list[str], timeout: float) -> dict:
    env = dict(os.environ)
    p = subprocess.run([sys.executable, __file__, "--case", *args], capture_output=True, text=True, timeout=timeout, env=env)
    if p.returncode != 0:
        return {"case": args[0], "args": args, "error": p.stderr.strip().splitlines()[-1] if p.stderr else f"exit {p.returncode}"}
    return json.loads(p.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--case", nargs="+", help=argparse.SUPPRESS)
    ap.add_argument("--only", choices=["uav", "platoon-finite", "platoon-scale", "gamma"], action="append")
    ap.add_argument("--uav-sizes", type=int, nargs="+", default=[10, 100, 300, 1000])
    ap.add_argument("--scipy-max", type=int, default=1000, help="run scipy's DARE for n up to this")
    ap.add_argument("--platoon-sizes", type=int, nargs="+", default=[4, 6, 8, 10, 12])
    ap.add_argument("--json", help="also write the rows to this file")
    ap.add_argument("--timeout", type=float, default=1800)
    a = ap.parse_args()
    if a.case:
        name, *rest = a.case
        fn = {
            "uav": lambda: case_uav(int(rest[0]), int(rest[1])),
            "platoon-finite": lambda: case_platoon_finite(int(rest[0]), int(rest[1])),
            "platoon-scale": lambda: case_platoon_scale(int(rest[0]), rest[1]),
            "gamma": lambda: case_gamma(rest[0], int(rest[1])),
        }[name]
        print(json.dumps(fn()))
        return
    todo = a.only or ["platoon-finite", "uav", "platoon-scale", "gamma"]
    rows = []
    threads = {k: os.environ.get(k) for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}
    print(f"# threads: {threads}")
    if "platoon-finite" in todo:
        r = _run(["platoon-finite", "4", "100"], a.timeout)
        rows.append(r)
        print(f"platoon n=4 finite horizon T=100: design {r.get('design_s', float('nan')):.3f} s  (J_T = {r.get('total_cost')})")
    if "uav" in todo:
        print(
            f"{'n':>6} {'design[s]':>10} {'setup[s]':>9} {'SDA[s]':>8} {'scipy[s]':>9} {'scipy/SDA':>10} {'scipy/design':>12} {'(setup+design)/scipy':>21} {'Gamma':>16} {'peak MB':>8}"
        )
        for n in a.uav_sizes:
            r = _run(["uav", str(n), str(a.scipy_max)], a.timeout)
            rows.append(r)
            if "error" in r:
                print(n, r["error"])
                continue
            print(
                f"{n:>6} {r['design_s']:>10.3f} {r['setup_s']:>9.3f} {r['dare_sda_s']:>8.3f} {r.get('dare_scipy_s', float('nan')):>9.2f} "
                f"{r.get('scipy_over_sda', float('nan')):>10.1f} {r.get('scipy_over_design', float('nan')):>12.1f} {r.get('whole_over_scipy', float('nan')):>21.2f} "
                f"{r['gamma']['method'] + ' ' + str(r['gamma']['size']):>16} {r['peak_mb']:>8.0f}"
            )
    if "platoon-scale" in todo:
        print(
            f"{'n':>4} {'window':>7} {'Gamma size':>10} {'method':>6} {'iters':>6} {'design[s]':>10} {'CPU[s]':>7} {'peak MB':>8} "
            f"{'average cost':>20} {'load':>11}",
            flush=True,
        )
        fit = []
        for n in a.platoon_sizes:
            r = _run(["platoon-scale", str(n), "auto"], a.timeout)
            rows.append(r)
            if "error" in r:
                print(n, r["error"])
                continue
            g = r["gamma"]
            print(
                f"{n:>4} {r['window']:>7} {g['size']:>10} {g['method']:>6} {g['iterations']:>6} {r['design_s']:>10.2f} {r['design_cpu_s']:>7.2f} "
                f"{r['peak_mb']:>8.0f} {r['average_cost']:>20.15g} {r['load_1min'][0]:>5.1f}-{r['load_1min'][1]:<5.1f}",
                flush=True,
            )
            fit.append((n, r["design_cpu_s"], r["design_s"]))
        if len(fit) >= 3:  # least-squares slope of log(time) against log(n): time ~ n^b
            import numpy as np

            ln = np.log([f[0] for f in fit])
            b_cpu = np.polyfit(ln, np.log([f[1] for f in fit]), 1)[0]
            b_wall = np.polyfit(ln, np.log([f[2] for f in fit]), 1)[0]
            half = [f for f in fit if f[0] >= np.median([f[0] for f in fit])]
            b_top = np.polyfit(np.log([f[0] for f in half]), np.log([f[1] for f in half]), 1)[0] if len(half) >= 2 else float("nan")
            print(f"# fitted growth: CPU ~ n^{b_cpu:.2f} (n = {fit[0][0]}..{fit[-1][0]}; n^{b_top:.2f} over the larger half), wall ~ n^{b_wall:.2f}")
    if "gamma" in todo:
        print(
            f"{'instance':>12} {'size':>6} {'dense[s]':>9} {'cg[s]':>8} {'iters':>6} {'auto':>6} {'rel diff':>9} "
            f"{'innov[s]':>9} {'iters':>6} {'cost vs dense':>13} {'cost vs cg':>10} {'F vs dense':>10}"
        )
        for kind, n in [("uav", 100), ("uav", 300), ("uav", 1000), ("platoon", 6), ("platoon", 8), ("platoon", 10), ("platoon", 12), ("platoon", 14)]:
            r = _run(["gamma", kind, str(n)], a.timeout)
            rows.append(r)
            if "error" in r:
                print(kind, n, r["error"])
                continue
            ds = r.get("dense_s")
            print(
                f"{kind + '-' + str(n):>12} {r['size']:>6} {(ds if ds is not None else float('nan')):>9.3f} {r['cg_s']:>8.3f} "
                f"{r['cg_iterations']:>6} {r['auto_choice']:>6} {r.get('rel_diff', float('nan')):>9.1e} "
                f"{r.get('innov_s', float('nan')):>9.3f} {r.get('innov_iterations', 0):>6} {r.get('innov_vs_dense_cost', float('nan')):>13.1e} "
                f"{r.get('innov_vs_cg_cost', float('nan')):>10.1e} {r.get('innov_vs_dense_gains', float('nan')):>10.1e}",
                flush=True,
            )
    if a.json:
        with open(a.json, "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
