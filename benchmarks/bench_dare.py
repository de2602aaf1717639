"""Benchmark: steady-state filter Riccati equation on the team-MMSE paper's UAV formation.

System (n agents, n states):

    A = 0.55 I + 0.1 * 1 1'                      (spectral radius 0.55 + 0.1 n)
    C = rows(2 * 1', 0.1 e_2', ..., 0.1 e_n')    (agent 1 measures twice the sum,
                                                  agent i >= 2 measures 0.1 x_i)
    Q = I,  R = 0.1 I

For each n the script times

* ``sda``     -- ``solve_filter_dare(..., method="sda", check=False)``: the doubling
  iteration plus input validation and verification (Riccati residual and
  closed-loop eigenvalues);
* ``scipy``   -- the bare ``scipy.linalg.solve_discrete_are(A', C', Q, R)``;
* ``detect``  -- ``check_detectable(A, C)`` (one real Schur form);
* ``a5``      -- the (A5) check ``solve_filter_dare`` runs by default: detectability of
  (A, C) and stabilizability of (A, Q^1/2) from one shared Schur form;

and reports the speed-up scipy/sda, the relative difference of the two solutions
(Frobenius) and both relative Riccati residuals. Times are the best of a few
repeats (fewer for large n).

BLAS threading matters: on a small (2 vCPU) machine multi-threaded OpenBLAS made
small-n timings erratic (up to 100x slower); set ``OPENBLAS_NUM_THREADS=1`` (or
``OMP_NUM_THREADS=1``) for stable numbers. The JSON records these variables.

Usage::

    PYTHONPATH=src python3 benchmarks/bench_dare.py [--sizes 10 100 300 1000]
        [--skip-scipy-above N] [--json PATH]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from typing import Any, Callable

import numpy as np
import scipy
import scipy.linalg as sla

from teamkf.estimators import riccati as ric


def uav_system(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    A = 0.55 * np.eye(n) + 0.1 * np.ones((n, n))
    C = np.vstack([2.0 * np.ones((1, n)), 0.1 * np.eye(n)[1:]])
    return A, C, np.eye(n), 0.1 * np.eye(n)


def best_time(fn: Callable[[], Any], repeats: int) -> tuple[float, Any]:
    best, out = np.inf, None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def repeats_for(n: int) -> int:
    return 7 if n <= 30 else 5 if n <= 100 else 3 if n <= 300 else 1


def run(n: int, skip_scipy_above: int | None) -> dict[str, Any]:
    A, C, Q, R = uav_system(n)
    reps = repeats_for(n)
    row: dict[str, Any] = {"n": n, "rho_A": 0.55 + 0.1 * n, "repeats": reps}

    # iteration count of the bare doubling (for the record)
    L = np.linalg.cholesky(R)
    B = sla.solve_triangular(L, C, lower=True)
    _, iters, _ = ric._sda(A, B.T @ B, Q, 1e-13, 200)
    row["sda_iters"] = iters

    t_sda, P_sda = best_time(lambda: ric.solve_filter_dare(A, C, Q, R, method="sda", check=False), reps)
    row["sda_s"] = t_sda
    row["sda_residual"] = ric.riccati_residual(A, C, Q, R, P_sda)
    K, _ = ric._gain_and_filtered(A, C, R, P_sda)
    row["closed_loop_rho"] = float(max(abs(np.linalg.eigvals(A - A @ K @ C))))

    t_det, _ = best_time(lambda: ric.check_detectable(A, C), reps)
    row["detect_s"] = t_det
    t_a5, _ = best_time(lambda: ric._check_pair(A, C, Q), reps)
    row["a5_check_s"] = t_a5

    if skip_scipy_above is not None and n > skip_scipy_above:
        row.update(scipy_s=None, speedup=None, rel_diff=None, scipy_residual=None)
    else:
        t_sp, P_sp = best_time(lambda: sla.solve_discrete_are(A.T, C.T, Q, R), reps)
        row["scipy_s"] = t_sp
        row["speedup"] = t_sp / t_sda
        row["rel_diff"] = float(np.linalg.norm(P_sda - P_sp) / np.linalg.norm(P_sp))
        row["scipy_residual"] = ric.riccati_residual(A, C, Q, R, 0.5 * (P_sp + P_sp.T))
    return row


def fmt(x: Any, spec: str) -> str:
    return "-" if x is None else format(x, spec)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[10, 100, 300, 1000])
    ap.add_argument("--skip-scipy-above", type=int, default=None, metavar="N", help="do not run scipy for n > N")
    ap.add_argument("--json", metavar="PATH", default=None, help="also write the table as JSON")
    args = ap.parse_args(argv)

    header = (
        f"{'n':>6} {'iters':>5} {'sda [s]':>10} {'scipy [s]':>10} {'scipy/sda':>9} {'rel diff':>9} "
        f"{'res sda':>9} {'res scipy':>9} {'detect [s]':>10} {'A5 [s]':>9} {'rho_cl':>7}"
    )
    print(
        f"UAV formation DARE benchmark -- numpy {np.__version__}, scipy {scipy.__version__}, python {platform.python_version()}, {platform.machine()}"
    )
    print(header)
    print("-" * len(header))
    rows = []
    for n in args.sizes:
        row = run(n, args.skip_scipy_above)
        rows.append(row)
        print(
            f"{n:>6} {row['sda_iters']:>5} {row['sda_s']:>10.4g} {fmt(row['scipy_s'], '>10.4g')} "
            f"{fmt(row['speedup'], '>9.3g')} {fmt(row['rel_diff'], '>9.2e')} {row['sda_residual']:>9.2e} "
            f"{fmt(row['scipy_residual'], '>9.2e')} {row['detect_s']:>10.4g} {row['a5_check_s']:>9.4g} "
            f"{row['closed_loop_rho']:>7.4f}",
            flush=True,
        )
    if args.json:
        meta = {
            "numpy": np.__version__,
            "scipy": scipy.__version__,
            "python": platform.python_version(),
            "machine": platform.machine(),
            "cpu_count": os.cpu_count(),
            "argv": sys.argv,
            "threads_env": {k: os.environ.get(k) for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")},
        }
        with open(args.json, "w") as fh:
            json.dump({"meta": meta, "rows": rows}, fh, indent=2)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
