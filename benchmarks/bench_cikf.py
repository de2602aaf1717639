"""Speed of the CIKF at the paper's size (Section VII: M = N = 50, i = 0..30, 1000 Monte Carlo runs).

    PYTHONPATH=src python3 benchmarks/bench_cikf.py                 # everything, M = N = 50
    PYTHONPATH=src python3 benchmarks/bench_cikf.py --size 20 --dense-steps 4 --json
    PYTHONPATH=src python3 benchmarks/bench_cikf.py --size 100 --steps 2 --runs 0 --dense-steps 0   # scale
    PYTHONPATH=src python3 benchmarks/bench_cikf.py --runs 0 --dense-steps 0 --compare-steps 0 --phases  # where the time goes
    PYTHONPATH=src OPENBLAS_NUM_THREADS=1 python3 benchmarks/bench_cikf.py --threads 1 --dense-steps 0 --compare-steps 0 \
        --runs 0 --joint-dense-steps 4      # the joint design against the dense joint-covariance reference, one thread

Cases (one process, in this order)
----------------------------------
design          Algorithm 2, T = 32 steps, ``--method`` (default "joint": one recursion on cov([e; ε]), fused
                and symmetric; "structured": the block-operator products, bit-compatible with the frozen
                reference), with ``--threads`` worker threads (default 2; one BLAS thread each) and with 1
                thread; wall and CPU (process) time, peak resident memory. With ``--method joint`` the
                structured design is also timed on min(T, 4) steps, and the two MSE curves compared.
design-dense    an independent, straightforward dense implementation of the same recursion
                (``_dense_design`` below): every operator (M_k, B^I, K, F, I ⊗ A, I ⊗ Ã, I ⊗ Ǎ) formed as a
                dense matrix once per step and applied with plain numpy matmuls (BLAS with its default
                threads), for ``--dense-steps`` steps: seconds per step, its agreement with the structured
                design, and the ratio to the structured design's seconds per step.
design-joint-dense  (``--joint-dense-steps S``, off by default) the plain whole-matrix reference
                ``_dense_joint_design`` below — J = cov([e; ε]) of all agents as ONE dense N(r + M) square
                matrix, each step J_f = U J U' and J = Φ J_f Φ' with U and Φ formed as dense matrices — and
                ``design_cikf(method="joint", threads=1)``, back to back for S steps with one BLAS thread:
                wall and CPU time, their ratio, the MSE agreement, and the joint design's GFLOP/s (flops
                counted from its products, ``_joint_flops``) as a fraction of the DGEMM peak measured in the
                same run (a 3000-square matmul, best of 3, on 1 and on 2 BLAS threads). With ``--threads 1``
                the main design (T steps) is also rated against the peak.
mc              1000 runs: sampling the paths, then Algorithm 1's error recursion vectorized over runs
                (``design.errors``), the same filter on the measurements (``design.simulate``), and the
                message-passing runtime (``run_graph`` with one agent object per node).
mc-dense        the error recursion with dense NM x NM operators (I - B^C - B^I D̃_H, K, I ⊗ Ã, ...)
                applied to the stacked errors of all runs: ratio to ``design.errors``.

The paper reports about 30 hours of Matlab on an 8-core Azure DS13 for its Monte Carlo (1000 runs of
CIKF, CKF and DIKF). The load of the machine (``os.getloadavg``) is printed before and after: the
development machine has 2 cores shared with other work.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import time

import numpy as np


def _dense_design(system, graph, T: int, rcond: float = 1e-9) -> np.ndarray:
    """Algorithm 2 (corrected eqs. 41-47, Theorem 4) with dense operators: tr Σ_{k|k-1} averaged over agents, (T,).

    Written from the equations, independently of ``teamkf.estimators.cikf.recursion._iterate``: the joint covariances
    P (N r x N r), Π' (N r x N M), Σ (N M x N M) and every operator as a dense matrix; Theorem 4's per-agent
    blocks are read through selection matrices. Only the model (reduced coordinates) and the pseudo-inverse
    rule (``_psd_solve``, which defines the cut-off) are shared with the library.
    """
    from scipy.linalg import block_diag

    from teamkf.estimators.cikf import _psd_solve, pseudo_state_model

    m = pseudo_state_model(system)
    N, M, r = system.n_agents, system.dx, m.rank
    A, V, S0 = system.A_at(0), system.Q_at(0), system.Sigma_x
    Gr, Atr, Acr, Ct = m.G_r, m.A_tilde_r, m.A_check_r, m.C_tilde
    Rb = block_diag(*[system.R_at(n, 0) for n in range(N)])
    nbrs = [graph.in_neighbors(n) for n in range(N)]
    one = np.ones((N, N))
    I_A, I_At, I_Ac, I_G = (np.kron(np.eye(N), X) for X in (A, Atr, Acr, Gr))
    P, Pt, Sig = np.kron(one, Gr @ S0 @ Gr.T), np.kron(one, Gr @ S0), np.kron(one, S0)
    E = np.eye(N * r)
    out = np.empty(T)
    for k in range(T):
        out[k] = np.trace(Sig) / N
        # Theorem 4: B̂^n = Σ_eν̃ Σ_ν̃^+ with ν̃ = D_n e + [0; v_n], D_n = [E_n - E_l; ...; C̃_n E_n]
        Mk = np.eye(N * r)
        Bu = []
        for n in range(N):
            En = E[n * r : (n + 1) * r]
            D = np.vstack([En - E[l * r : (l + 1) * r] for l in nbrs[n]] + [Ct[n] @ En])
            Snu = D @ P @ D.T
            mn = Ct[n].shape[0]
            Snu[-mn:, -mn:] += system.R_at(n, 0)
            B = _psd_solve(En @ P @ D.T, Snu, rcond)
            Mk[n * r : (n + 1) * r] -= B @ D  # M_k = I - B^C - B^I D̃_H: row n is E_n - B̂^n D_n
            Bu.append(B[:, -mn:])
        BI = block_diag(*Bu)
        Gt = Mk @ Pt  # Γ' (41)
        Pf = Mk @ P @ Mk.T + BI @ Rb @ BI.T  # (42)
        K = np.zeros((N * M, N * r))
        for n in range(N):  # K^n = (Σ^{nn} G' - Γ^{nn}) Σ_ν^+, Σ_ν = G Σ G' - G Γ - Γ' G' + P_f^{nn}
            sx, sr = slice(n * M, (n + 1) * M), slice(n * r, (n + 1) * r)
            Snn, Gnn, Pnn = Sig[sx, sx], Gt[sr, sx].T, Pf[sr, sr]
            K[sx, sr] = _psd_solve(Snn @ Gr.T - Gnn, Gr @ Snn @ Gr.T - Gr @ Gnn - Gnn.T @ Gr.T + Pnn, rcond)
        F = np.eye(N * M) - K @ I_G
        Pft = Gt @ F.T + Pf @ K.T  # (44)
        Sf = F @ Sig @ F.T + F @ Gt.T @ K.T + K @ Gt @ F.T + K @ Pf @ K.T  # (43), corrected
        if k + 1 == T:
            break
        P = I_At @ Pf @ I_At.T + I_At @ Pft @ I_Ac.T + I_Ac @ Pft.T @ I_At.T + I_Ac @ Sf @ I_Ac.T + np.kron(one, Gr @ V @ Gr.T)  # (45)
        Pt = (I_At @ Pft + I_Ac @ Sf) @ I_A.T + np.kron(one, Gr @ V)  # (47)
        Sig = I_A @ Sf @ I_A.T + np.kron(one, V)  # (46)
    return out


def _dense_joint_design(system, graph, T: int, rcond: float = 1e-9) -> np.ndarray:
    """Algorithm 2 on the joint error covariance J = cov([e; ε]) as ONE dense matrix: tr Σ_{k|k-1} / N, (T,).

    The plain whole-matrix reference of ``design-joint-dense``: J is N(r + M) square (all agents' e first, then
    all ε), and each step is two whole-matrix sandwiches with dense per-step transitions:

        J_f     = U J U' + blockdiag(B^I R B^I', 0),   U = [[M_k, 0], [0, I]]          (41)-(42)
        J_{k+1} = Φ J_f Φ' + Gx V Gx',   Φ = [[I ⊗ Ã + (I ⊗ Ǎ) K, (I ⊗ Ǎ) F], [(I ⊗ A) K, (I ⊗ A) F]]   (43)-(47)

    with F = I - K (I ⊗ G_r) and Gx = [1 ⊗ G_r; 1 ⊗ I] (e = G_r x-errors, ε = x-errors). Theorem 4's gains read
    the blocks of J and J_f they need through index arrays. Only the model (reduced coordinates) and the
    pseudo-inverse rule (``_psd_solve``, which defines the cut-off) are shared with the library.
    """
    from scipy.linalg import block_diag

    from teamkf.estimators.cikf import _psd_solve, pseudo_state_model

    m = pseudo_state_model(system)
    N, M, r = system.n_agents, system.dx, m.rank
    A, V, S0 = system.A_at(0), system.Q_at(0), system.Sigma_x
    Gr, Atr, Acr, Ct = m.G_r, m.A_tilde_r, m.A_check_r, m.C_tilde
    ne = N * r  # J = [[P, Π'], [Π, Σ]]: e-rows 0..ne, ε-rows ne..ne + N M
    Gx = np.vstack([np.kron(np.ones((N, 1)), Gr), np.kron(np.ones((N, 1)), np.eye(M))])
    J = Gx @ S0 @ Gx.T
    W = Gx @ V @ Gx.T
    e_idx = [np.arange(n * r, (n + 1) * r) for n in range(N)]
    x_idx = [ne + np.arange(n * M, (n + 1) * M) for n in range(N)]
    out = np.empty(T)
    for k in range(T):
        out[k] = np.trace(J[ne:, ne:]) / N
        # Theorem 4: B̂^n = Σ_eν̃ Σ_ν̃^+ with ν̃ = D_n [e^n; e^{l_1}; ...] + [0; v_n], D_n = [[I, -I, 0..], ...; [C̃_n, 0, ..]]
        Mk = np.eye(ne)
        U = np.eye(J.shape[0])
        Nf = np.zeros_like(J)
        for n in range(N):
            nb = graph.in_neighbors(n)
            d, mn = len(nb), Ct[n].shape[0]
            h = np.concatenate([e_idx[l] for l in (n, *nb)])
            D = np.zeros((d * r + mn, (d + 1) * r))
            for j in range(d):
                D[j * r : (j + 1) * r, :r] = np.eye(r)
                D[j * r : (j + 1) * r, (j + 1) * r : (j + 2) * r] = -np.eye(r)
            D[d * r :, :r] = Ct[n]
            Ph = J[np.ix_(h, h)]
            Snu = D @ Ph @ D.T
            Snu[-mn:, -mn:] += system.R_at(n, 0)
            B = _psd_solve(Ph[:r] @ D.T, Snu, rcond)
            Mk[np.ix_(e_idx[n], h)] -= B @ D  # M_k's block row n: E_n - B̂^n D_n
            Bu = B[:, -mn:]
            Nf[np.ix_(e_idx[n], e_idx[n])] = Bu @ system.R_at(n, 0) @ Bu.T
        U[:ne, :ne] = Mk
        Jf = U @ J @ U.T + Nf  # (41)-(42): P_f = M P M' + B^I R B^I', Γ' = M Π', Σ unchanged
        # Theorem 4: K^n = (Σ^{nn} G' - Γ^{nn}) Σ_ν^+, Σ_ν = G Σ^{nn} G' - G Γ^{nn} - Γ^{nn}' G' + P_f^{nn}
        K = []
        for n in range(N):
            Snn, Gnn, Pnn = Jf[np.ix_(x_idx[n], x_idx[n])], Jf[np.ix_(x_idx[n], e_idx[n])], Jf[np.ix_(e_idx[n], e_idx[n])]
            K.append(_psd_solve(Snn @ Gr.T - Gnn, Gr @ Snn @ Gr.T - Gr @ Gnn - Gnn.T @ Gr.T + Pnn, rcond))
        if k + 1 == T:
            break
        F = [np.eye(M) - Kn @ Gr for Kn in K]
        Phi = np.block(
            [
                [block_diag(*[Atr + Acr @ Kn for Kn in K]), block_diag(*[Acr @ Fn for Fn in F])],
                [block_diag(*[A @ Kn for Kn in K]), block_diag(*[A @ Fn for Fn in F])],
            ]
        )
        J = Phi @ Jf @ Phi.T + W  # (43)-(47): [e; ε]_{k+1|k} = Φ [e_{k|k}; ε_{k|k-1}] + Gx w
    return out


def _joint_flops(system, graph, T: int) -> float:
    """Floating-point operations of ``design_cikf(method="joint")`` over T steps, counted from its products.

    Per step: M_k on J's e-rows (one r x (d_n + 1) r GEMM per agent over all N q columns), M P M' (upper block
    triangle: agent n's row over agents m >= n), Φ J_f Φ' (upper block triangle: Φ_i J_f^{i, j >= i}, then each
    block times Φ_j'), Theorem 4 (per agent a pivoted Cholesky of the s x s Σ_ν̃, s = d_n r + m_n, and its solve
    with r right-hand sides; the r x r state-gain solves) — the last step has no Φ J_f Φ'. The copies,
    gathers, transposes and adds are not counted (they are memory traffic, not flops).
    """
    from teamkf.estimators.cikf import pseudo_state_model

    m = pseudo_state_model(system)
    N, M, r = system.n_agents, system.dx, m.rank
    q = r + M
    d = np.array([len(graph.in_neighbors(n)) for n in range(N)], dtype=float)
    mn = np.array([m.C_tilde[n].shape[0] for n in range(N)], dtype=float)
    update = 2.0 * r * r * (d + 1).sum() * N * q
    sandwich = float(np.sum(2.0 * r * (d + 1) * r * (N - np.arange(N)) * r))
    s = d * r + mn
    gains = float(np.sum(s**3 / 3 + 2 * s * s * r)) + N * (r**3 / 3 + 2.0 * r * r * M)
    predict = 4.0 * q**3 * N * (N + 1) / 2
    return T * (update + sandwich + gains) + (T - 1) * predict


def _dgemm_peak(n: int = 3000, threads: int = 1, repeat: int = 3) -> tuple[float, float]:
    """DGEMM rate of one n x n x n numpy matmul with ``threads`` BLAS threads, best of ``repeat``: GFLOP per second
    of wall time, and per second of process CPU time (per core: the load of a shared machine hurts it less)."""
    from threadpoolctl import threadpool_limits

    a, b = np.random.default_rng(0).standard_normal((2, n, n))
    c = np.empty((n, n))
    wall = cpu = np.inf
    with threadpool_limits(limits=threads, user_api="blas"):
        np.matmul(a, b, out=c)
        for _ in range(repeat):
            t, u = time.perf_counter(), time.process_time()
            np.matmul(a, b, out=c)
            wall, cpu = min(wall, time.perf_counter() - t), min(cpu, time.process_time() - u)
    return 2.0 * n**3 / wall / 1e9, 2.0 * n**3 / cpu / 1e9


def _joint_vs_dense(sysm, graph, steps: int, full_design_s: float | None, full_T: int) -> dict:
    """The ``design-joint-dense`` case: the library design and ``_dense_joint_design`` back to back, one BLAS thread."""
    from threadpoolctl import threadpool_limits

    from teamkf.estimators.cikf import design_cikf

    out: dict = {"joint_dense_steps": steps}
    out["dgemm_peak_1thread_GFLOPs"], out["dgemm_peak_1thread_GFLOPs_cpu"] = _dgemm_peak(threads=1)
    out["dgemm_peak_2threads_GFLOPs"], out["dgemm_peak_2threads_GFLOPs_per_core_cpu"] = _dgemm_peak(threads=2)
    with threadpool_limits(limits=1, user_api="blas"):
        t, c = time.perf_counter(), time.process_time()
        d = design_cikf(sysm, None, graph, steps, form="predictor", threads=1, method="joint")
        lib_s, lib_cpu = time.perf_counter() - t, time.process_time() - c
        t, c = time.perf_counter(), time.process_time()
        ref = _dense_joint_design(sysm, graph, steps)
        ref_s, ref_cpu = time.perf_counter() - t, time.process_time() - c
    lib = d.mse("predictor")
    out["joint_dense_max_rel_diff_mse"] = float(np.max(np.abs(ref - lib) / np.abs(lib)))
    out["joint_dense_s"], out["joint_dense_cpu_s"] = ref_s, ref_cpu
    out["joint_lib_s"], out["joint_lib_cpu_s"] = lib_s, lib_cpu
    out["joint_dense_ratio_wall"] = ref_s / lib_s
    out["joint_dense_ratio_cpu"] = ref_cpu / lib_cpu
    fl = _joint_flops(sysm, graph, steps)
    out["joint_lib_GFLOP"] = fl / 1e9
    out["joint_lib_GFLOPs_cpu"] = fl / lib_cpu / 1e9
    out["joint_lib_peak_fraction_cpu"] = out["joint_lib_GFLOPs_cpu"] / out["dgemm_peak_1thread_GFLOPs_cpu"]
    out["joint_dense_per_step_cpu_s"] = ref_cpu / steps
    if full_design_s is not None:  # the main design case (T steps) on one worker thread: its CPU time
        fl = _joint_flops(sysm, graph, full_T)
        out["design_1thread_GFLOPs_cpu"] = fl / full_design_s / 1e9
        out["design_1thread_peak_fraction_cpu"] = out["design_1thread_GFLOPs_cpu"] / out["dgemm_peak_1thread_GFLOPs_cpu"]
        out["joint_dense_ratio_cpu_full_design"] = out["joint_dense_per_step_cpu_s"] / (full_design_s / full_T)
    return out


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


def _reset_peak_rss() -> bool:
    """Reset the kernel's peak-RSS mark of this process (Linux >= 4.0), so that the next reading is one phase's peak."""
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
        return True
    except OSError:
        return False


def _peak_rss_MiB() -> float:
    """VmHWM (peak resident set size since the last reset) where /proc has it, else ru_maxrss (since the start)."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return float(line.split()[1]) / 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _phases(sysm, graph, T: int, threads: int) -> dict[str, float]:
    """Seconds per step of each phase of the joint design (every ``_ranges`` call, by its function's name).

    "serial" is the rest of the wall time: the numpy work between the phases and J's first touch.
    """
    import teamkf.estimators.cikf as C
    import teamkf.estimators.cikf.joint as J

    acc: dict[str, float] = {}
    ranges = J._ranges

    def timed(pool, workers, fn, n, **kw):
        t = time.perf_counter()
        ranges(pool, workers, fn, n, **kw)
        acc[fn.__name__] = acc.get(fn.__name__, 0.0) + time.perf_counter() - t

    J._ranges = timed
    try:
        t = time.perf_counter()
        C.design_cikf(sysm, None, graph, T, form="predictor", threads=threads, method="joint")
        wall = time.perf_counter() - t
    finally:
        J._ranges = ranges
    out = {k: v / T for k, v in sorted(acc.items(), key=lambda kv: -kv[1])}
    out["serial"] = (wall - sum(acc.values())) / T
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", type=int, default=50, help="M = N (default 50, the paper's)")
    ap.add_argument("--steps", type=int, default=32, help="design horizon T (default 32: i = 0..30)")
    ap.add_argument("--runs", type=int, default=1000)
    ap.add_argument("--dense-steps", type=int, default=2, help="steps of the dense design baseline (0: skip)")
    ap.add_argument(
        "--joint-dense-steps",
        type=int,
        default=0,
        help="steps of the design-joint-dense case (the library design and _dense_joint_design, one BLAS thread; 0: skip)",
    )
    ap.add_argument("--threads", type=int, default=2, help="worker threads of the design and its Monte Carlo")
    ap.add_argument("--method", choices=("joint", "structured"), default="joint", help="design_cikf(method=...) (default joint)")
    ap.add_argument("--compare-steps", type=int, default=4, help="steps of the structured design timed beside the joint one (0: skip)")
    ap.add_argument("--runtime-runs", type=int, default=1000, help="runs through run_graph (0 to skip)")
    ap.add_argument("--phases", action="store_true", help="also time the joint design's phases (the worker-pool calls of _iterate_joint)")
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
    res["load_before"] = os.getloadavg()
    sysm, graph = random_field(args.size, args.size, rng=0)
    design_cikf(sysm, None, graph, 1, method=args.method)  # warm caches (the default cost, imports)

    res["process_peak_rss_before_design_MiB"] = _peak_rss_MiB()  # the model, the graph, the default TeamCost.mse
    res["design_peak_rss_reset"] = _reset_peak_rss()
    t, c = time.perf_counter(), time.process_time()
    d = design_cikf(sysm, None, graph, args.steps, form="predictor", threads=args.threads, method=args.method)
    res["design_s"] = time.perf_counter() - t
    res["design_cpu_s"] = time.process_time() - c
    res["design_method"] = args.method
    res["design_threads"] = args.threads
    res["design_peak_rss_MiB"] = _peak_rss_MiB()  # during the design (whole process if the reset was refused)
    res["design_per_step_s"] = res["design_s"] / args.steps
    if args.phases and args.method == "joint":
        res["design_phases_per_step_s"] = _phases(sysm, graph, args.steps, args.threads)
    short = min(args.steps, 4)
    if args.threads != 1:
        t, c = time.perf_counter(), time.process_time()
        design_cikf(sysm, None, graph, short, form="predictor", threads=1, method=args.method)
        res["design_1thread_per_step_s"] = (time.perf_counter() - t) / short
        res["design_1thread_cpu_per_step_s"] = (time.process_time() - c) / short
    if args.method == "joint" and args.compare_steps:
        short = min(args.steps, args.compare_steps)
        t, c = time.perf_counter(), time.process_time()
        ds = design_cikf(sysm, None, graph, short, form="predictor", threads=args.threads, method="structured")
        res["design_structured_per_step_s"] = (time.perf_counter() - t) / short
        res["design_structured_cpu_per_step_s"] = (time.process_time() - c) / short
        ref = ds.mse("predictor")
        res["design_joint_vs_structured_max_rel_diff_mse"] = float(np.max(np.abs(d.mse("predictor")[:short] - ref) / np.abs(ref)))
        del ds
    if args.dense_steps:
        t = time.perf_counter()
        dense = _dense_design(sysm, graph, args.dense_steps)
        res["design_dense_per_step_s"] = (time.perf_counter() - t) / args.dense_steps
        res["design_dense_ratio"] = res["design_dense_per_step_s"] / res["design_per_step_s"]
        ref = d.mse("predictor")[: args.dense_steps]
        res["design_dense_max_rel_diff"] = float(np.max(np.abs(dense - ref) / np.abs(ref)))
    if args.joint_dense_steps:
        full = res["design_cpu_s"] if args.threads == 1 and args.method == "joint" else None  # CPU time = 1 core's time
        res.update(_joint_vs_dense(sysm, graph, args.joint_dense_steps, full, args.steps))
    if not args.runs:
        res["load_after"] = os.getloadavg()
        print(json.dumps(res, indent=1))
        return

    t = time.perf_counter()
    paths = sample_paths(sysm, args.steps, args.runs, rng=1)
    res["mc_sample_s"] = time.perf_counter() - t
    t, c = time.perf_counter(), time.process_time()
    e = d.errors(paths)
    res["mc_errors_s"] = time.perf_counter() - t
    res["mc_errors_cpu_s"] = time.process_time() - c
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
    res["load_after"] = os.getloadavg()
    if args.json:
        print(json.dumps(res, indent=1))
        return
    print(f"CIKF at M = N = {args.size}, T = {args.steps}, {args.runs} runs ({res['cpus']} CPUs); load {res['load_before']} -> {res['load_after']}")
    print(
        f"  gain design ({args.method}, {args.threads} threads): {res['design_s']:.1f} s wall, {res['design_cpu_s']:.1f} s CPU "
        f"({res['design_per_step_s']:.2f} s/step; 1 thread: {res.get('design_1thread_per_step_s', float('nan')):.2f} s/step); "
        f"peak RSS {res['design_peak_rss_MiB']:.0f} MiB"
    )
    if "design_phases_per_step_s" in res:
        print("  phases (s/step): " + ", ".join(f"{k} {v:.4f}" for k, v in res["design_phases_per_step_s"].items()))
    if "design_structured_per_step_s" in res:
        print(
            f"  structured design ({args.threads} threads, first {min(args.steps, args.compare_steps)} steps): {res['design_structured_per_step_s']:.2f} s/step; "
            f"MSE max relative difference {res['design_joint_vs_structured_max_rel_diff_mse']:.1e}"
        )
    if args.dense_steps:
        print(
            f"  dense numpy baseline:      {res['design_dense_per_step_s']:.2f} s/step on the first {args.dense_steps} steps: "
            f"{args.method} x{res['design_dense_ratio']:.1f} faster (max relative difference of the MSE {res['design_dense_max_rel_diff']:.1e})"
        )
    if args.joint_dense_steps:
        print(
            f"  design-joint-dense (one BLAS thread, first {args.joint_dense_steps} steps, back to back): dense joint reference "
            f"{res['joint_dense_s']:.1f} s wall / {res['joint_dense_cpu_s']:.1f} s CPU, joint design {res['joint_lib_s']:.2f} s / "
            f"{res['joint_lib_cpu_s']:.2f} s CPU: x{res['joint_dense_ratio_wall']:.1f} wall, x{res['joint_dense_ratio_cpu']:.1f} CPU "
            f"(MSE max relative difference {res['joint_dense_max_rel_diff_mse']:.1e}); DGEMM peak {res['dgemm_peak_1thread_GFLOPs']:.1f} "
            f"GFLOP/s on 1 thread ({res['dgemm_peak_1thread_GFLOPs_cpu']:.1f} per CPU second), {res['dgemm_peak_2threads_GFLOPs']:.1f} on 2; the joint design {res['joint_lib_GFLOPs_cpu']:.1f} GFLOP/s "
            f"of CPU time = {res['joint_lib_peak_fraction_cpu']:.0%} of the 1-thread peak"
            + (
                f"; the {args.steps}-step design: {res['design_1thread_GFLOPs_cpu']:.1f} GFLOP/s = {res['design_1thread_peak_fraction_cpu']:.0%}, "
                f"x{res['joint_dense_ratio_cpu_full_design']:.1f} per step against the reference (CPU)"
                if "design_1thread_GFLOPs_cpu" in res
                else ""
            )
        )
    print(
        f"  Monte Carlo: sample {res['mc_sample_s']:.2f} s, errors {res['mc_errors_s']:.2f} s ({res['mc_errors_cpu_s']:.2f} s CPU), simulate {res['mc_simulate_s']:.2f} s, "
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
