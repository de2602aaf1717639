"""Speed of the CIKF at the paper's size (Section VII: M = N = 50, i = 0..30, 1000 Monte Carlo runs).

    PYTHONPATH=src python3 benchmarks/bench_cikf.py                 # everything, M = N = 50
    PYTHONPATH=src python3 benchmarks/bench_cikf.py --size 20 --dense-steps 4 --json

Cases (one process, in this order)
----------------------------------
design          Algorithm 2 with the block-structured products (``method="structured"``), T = 32 steps.
design-dense    the same recursion with every operator formed as a dense NM x NM matrix
                (``method="dense"``) for ``--dense-steps`` steps: seconds per step, and the ratio
                to the structured design's seconds per step measured on the same first steps.
mc              1000 runs: sampling the paths, then Algorithm 1's error recursion vectorized over runs
                (``design.errors``), the same filter on the measurements (``design.simulate``), and the
                message-passing runtime (``run_graph`` with one agent object per node).
mc-dense        the error recursion with dense NM x NM operators (I - B^C - B^I D̃_H, K, I ⊗ Ã, ...)
                applied to the stacked errors of all runs: ratio to ``design.errors``.

The paper reports about 30 hours of Matlab on an 8-core Azure DS13 for its Monte Carlo (1000 runs of
CIKF, CKF and DIKF).
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np


def _dense_errors(d, paths) -> np.ndarray:
    """The error recursion of ``CIKFDesign.errors`` with dense (N r x N r, N M x N r, ...) operators."""
    from scipy.linalg import block_diag

    m, sysm = d.model, d.system
    N, M, r = sysm.n_agents, sysm.dx, m.rank
    R_, T = paths.n_runs, paths.n_steps
    A = sysm.A_at(0)
    x0, w = paths.x[:, 0], paths.w
    v = np.concatenate(paths.v, axis=2)  # (R, T, sum M_n)
    e = np.tile(x0 @ m.G_r.T, (1, N))
    eps = np.tile(x0, (1, N))
    IA, IAt, IAc, IG = (np.kron(np.eye(N), X) for X in (A, m.A_tilde_r, m.A_check_r, m.G_r))
    out = np.empty((R_, T, N * M))
    for k in range(T):
        rows = d.m_rows(k)
        Mf = np.zeros((N * r, N * r))
        for n, row in enumerate(rows):
            cols = np.concatenate([np.arange(l * r, (l + 1) * r) for l in (n, *d.neighbors[n])])
            Mf[n * r : (n + 1) * r, cols] = row
        Bu = block_diag(*d.B_innov[k])
        Kf = block_diag(*d.K[k])
        ef = e @ Mf.T - v[:, k] @ Bu.T
        epsf = eps - (eps @ IG.T - ef) @ Kf.T
        out[:, k] = eps
        if k + 1 < T:
            e = ef @ IAt.T + epsf @ IAc.T + np.tile(w[:, k] @ m.G_r.T, (1, N))
            eps = epsf @ IA.T + np.tile(w[:, k], (1, N))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", type=int, default=50, help="M = N (default 50, the paper's)")
    ap.add_argument("--steps", type=int, default=32, help="design horizon T (default 32: i = 0..30)")
    ap.add_argument("--runs", type=int, default=1000)
    ap.add_argument("--dense-steps", type=int, default=3, help="steps of the dense design baseline")
    ap.add_argument("--runtime-runs", type=int, default=1000, help="runs through run_graph (0 to skip)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()

    from teamkf.estimators.cikf import design_cikf
    from teamkf.simulation.runtime import run_graph
    from teamkf.simulation.sampling import sample_paths
    from teamkf.study.random_field import random_field

    res: dict = {
        "M": args.size,
        "N": args.size,
        "T": args.steps,
        "runs": args.runs,
        "threads": os.environ.get("OPENBLAS_NUM_THREADS", "default"),
        "cpus": os.cpu_count(),
    }
    sysm, graph = random_field(args.size, args.size, rng=0)
    design_cikf(sysm, None, graph, 1)  # warm caches (the default cost, imports)

    t = time.perf_counter()
    d = design_cikf(sysm, None, graph, args.steps, form="predictor")
    res["design_s"] = time.perf_counter() - t
    t = time.perf_counter()
    d_few = design_cikf(sysm, None, graph, args.dense_steps, form="predictor")
    res["design_structured_first_steps_s"] = time.perf_counter() - t
    t = time.perf_counter()
    dd = design_cikf(sysm, None, graph, args.dense_steps, form="predictor", method="dense")
    res["design_dense_first_steps_s"] = time.perf_counter() - t
    res["design_dense_per_step_s"] = res["design_dense_first_steps_s"] / args.dense_steps
    res["design_structured_per_step_s"] = res["design_structured_first_steps_s"] / args.dense_steps
    res["design_dense_ratio"] = res["design_dense_first_steps_s"] / res["design_structured_first_steps_s"]
    res["design_dense_agrees"] = bool(np.allclose(dd.mse("predictor"), d_few.mse("predictor"), rtol=1e-9))

    t = time.perf_counter()
    paths = sample_paths(sysm, args.steps, args.runs, rng=1)
    res["mc_sample_s"] = time.perf_counter() - t
    t = time.perf_counter()
    e = d.errors(paths)
    res["mc_errors_s"] = time.perf_counter() - t
    t = time.perf_counter()
    z = d.simulate(paths.y)
    res["mc_simulate_s"] = time.perf_counter() - t
    res["mc_total_s"] = res["mc_sample_s"] + res["mc_errors_s"]
    if args.runtime_runs:
        rr = min(args.runtime_runs, args.runs)
        t = time.perf_counter()
        zg = run_graph(d.graph_agents(), graph, [y[:rr] for y in paths.y])
        res["mc_run_graph_s"] = time.perf_counter() - t
        res["mc_run_graph_runs"] = rr
        res["run_graph_matches_simulate"] = bool(np.allclose(zg, z[:rr], rtol=1e-8, atol=1e-8))
    t = time.perf_counter()
    ed = _dense_errors(d, paths)
    res["mc_dense_errors_s"] = time.perf_counter() - t
    res["mc_dense_ratio"] = res["mc_dense_errors_s"] / res["mc_errors_s"]
    res["mc_dense_agrees"] = bool(np.allclose(ed, e, rtol=1e-8, atol=1e-8 * np.abs(e).max()))
    N, M = sysm.n_agents, sysm.dx
    s = (e.reshape(args.runs, args.steps, N, M) ** 2).sum(axis=3).mean(axis=2)
    z_score = (s.mean(axis=0) - d.mse("predictor")) / (s.std(axis=0, ddof=1) / np.sqrt(args.runs))
    res["mc_worst_z"] = float(np.abs(z_score[1:]).max())
    res["experiment_s"] = res["design_s"] + res["mc_total_s"]
    if args.json:
        print(json.dumps(res, indent=1))
        return
    print(f"CIKF at M = N = {args.size}, T = {args.steps}, {args.runs} runs (OPENBLAS_NUM_THREADS={res['threads']}, {res['cpus']} CPUs)")
    print(f"  gain design (structured):  {res['design_s']:.1f} s  ({res['design_s'] / args.steps:.2f} s/step)")
    print(
        f"  dense baseline:            {res['design_dense_per_step_s']:.2f} s/step vs {res['design_structured_per_step_s']:.2f} s/step "
        f"on the first {args.dense_steps} steps: x{res['design_dense_ratio']:.1f} (same numbers: {res['design_dense_agrees']})"
    )
    print(
        f"  Monte Carlo: sample {res['mc_sample_s']:.2f} s, errors {res['mc_errors_s']:.2f} s, simulate {res['mc_simulate_s']:.2f} s, "
        f"dense errors {res['mc_dense_errors_s']:.2f} s (x{res['mc_dense_ratio']:.1f}, same: {res['mc_dense_agrees']})"
    )
    if args.runtime_runs:
        print(
            f"  message-passing runtime (run_graph, {res['mc_run_graph_runs']} runs): {res['mc_run_graph_s']:.2f} s "
            f"(= simulate: {res['run_graph_matches_simulate']})"
        )
    print(f"  worst |MC - theory| over i = 0..{args.steps - 2}: {res['mc_worst_z']:.2f} standard errors")
    print(f"  Section VII experiment (design + {args.runs}-run MC): {res['experiment_s']:.1f} s  (the paper: about 30 h on 8 cores)")


if __name__ == "__main__":
    main()
