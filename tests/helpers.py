"""Independent reference computations for the tests (brute force, random instances)."""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from teamkf import CommGraph, LinearGaussianSystem, TeamCost


def random_system(rng, n_agents, dx, dys, *, time_varying=False, n_steps=8, stable=False):
    def rand_A():
        A = rng.standard_normal((dx, dx)) / np.sqrt(dx)
        if stable:
            A *= 0.9 / max(1e-9, np.max(np.abs(np.linalg.eigvals(A))))
        return A

    def rand_psd(d, definite):
        M = rng.standard_normal((d, d + (0 if definite else -1 if d > 1 else 0)))
        P = M @ M.T / d
        return P + (0.2 * np.eye(d) if definite else 0)

    if time_varying:
        A = [rand_A() for _ in range(n_steps)]
        Q = [rand_psd(dx, False) for _ in range(n_steps)]
        C = [[rng.standard_normal((dy, dx)) for _ in range(n_steps)] for dy in dys]
        R = [[rand_psd(dy, True) for _ in range(n_steps)] for dy in dys]
    else:
        A, Q = rand_A(), rand_psd(dx, False)
        C = [rng.standard_normal((dy, dx)) for dy in dys]
        R = [rand_psd(dy, True) for dy in dys]
    return LinearGaussianSystem(A=A, Q=Q, Sigma_x=rand_psd(dx, False), C=C, R=R)


def random_cost(rng, n_agents, dx, dz, *, time_varying=False, n_steps=8):
    def one():
        M = rng.standard_normal((n_agents * dz, n_agents * dz))
        return M @ M.T + 0.3 * np.eye(n_agents * dz), rng.standard_normal((n_agents * dz, dx))

    if time_varying:
        pairs = [one() for _ in range(n_steps)]
        return TeamCost(S=[p[0] for p in pairs], L=[p[1] for p in pairs], n_agents=n_agents)
    S, L = one()
    return TeamCost(S=S, L=L, n_agents=n_agents)


def eq14_information(graph: CommGraph, i: int, k: int) -> frozenset:
    """I_i(k) by the recursion (14) itself: own y_i(0:k) and I_j(k - tau_ji) of every in-neighbour."""

    @lru_cache(maxsize=None)
    def I(a: int, t: int) -> frozenset:
        if t < 0:
            return frozenset()
        out = {(a, s) for s in range(t + 1)}
        for j in graph.in_neighbors(a):
            out |= I(j, t - graph.delay(j, a))
        return frozenset(out)

    return I(i, k)


def window_information(n_agents, common_lag, local, i, k) -> frozenset:
    """What a (common lag, windows) structure gives agent i at step k, from its definition."""
    out = {(j, s) for j in range(n_agents) for s in range(0, k - common_lag + 1)}
    for j, newest, oldest in local[i]:
        out |= {(j, k - lag) for lag in range(newest, oldest + 1) if k - lag >= 0}
    return frozenset(out)


def joint_moments(system: LinearGaussianSystem, k: int):
    """Linear maps of every x(s), y_j(s) (s <= k) onto the primitive variables, and their covariance."""
    dx, n = system.dx, system.n_agents
    dys = system.dy
    n_prim = dx + k * dx + (k + 1) * sum(dys)
    blocks = [system.Sigma_x] + [system.Q_at(s) for s in range(k)]
    voff = {}
    pos = dx + k * dx
    for s in range(k + 1):
        for j in range(n):
            voff[(j, s)] = pos
            blocks.append(system.R_at(j, s))
            pos += dys[j]
    from scipy.linalg import block_diag

    Cov = block_diag(*blocks)
    X = [np.zeros((dx, n_prim))]
    X[0][:, :dx] = np.eye(dx)
    for s in range(k):
        nxt = system.A_at(s) @ X[s]
        nxt[:, dx + s * dx : dx + (s + 1) * dx] += np.eye(dx)
        X.append(nxt)
    Y = {}
    for s in range(k + 1):
        for j in range(n):
            m = system.C_at(j, s) @ X[s]
            m[:, voff[(j, s)] : voff[(j, s)] + dys[j]] += np.eye(dys[j])
            Y[(j, s)] = m
    assert pos == n_prim
    return X, Y, Cov


def brute_force_team(system, cost, info_sets, k, *, mmse=False, rows=None):
    """Radner's person-by-person conditions on the stacked raw information, solved with an explicit Kronecker matrix.

    info_sets[i] is the set of (j, s) agent i holds at step k. ``rows`` (optional) maps (j, s) to a
    boolean mask of the components of y_j(s) that exist (a recorded log with gaps); the others are
    left out of the stacked information. Returns (cost, F list); F_i acts on agent i's stacked
    available components, in sorted (j, s) order.
    """
    X, Y, Cov = joint_moments(system, k)
    if rows is not None:
        Y = {p: (m[np.asarray(rows[p], dtype=bool)] if p in rows else m) for p, m in Y.items()}
    n, dz = system.n_agents, cost.dz
    S, L = cost.S_at(k), cost.L_at(k)
    M = [np.vstack([Y[p] for p in sorted(info_sets[i])]) if info_sets[i] else np.zeros((0, Cov.shape[0])) for i in range(n)]
    Xk = X[k]
    Sig = [[M[i] @ Cov @ M[j].T for j in range(n)] for i in range(n)]
    Th = [Xk @ Cov @ M[i].T for i in range(n)]
    d = [m.shape[0] for m in M]
    Sb = lambda i, j: S[i * dz : (i + 1) * dz, j * dz : (j + 1) * dz]
    Lb = lambda i: L[i * dz : (i + 1) * dz]
    if mmse:
        F = [Lb(i) @ Th[i] @ np.linalg.inv(Sig[i][i]) if d[i] else np.zeros((dz, 0)) for i in range(n)]
    else:
        # column-major vec: vec(S_ij F_j Sig_ji) = (Sig_ij (x) S_ij) vec(F_j)
        off = np.concatenate([[0], np.cumsum([dz * di for di in d])])
        G = np.zeros((off[-1], off[-1]))
        eta = np.zeros(off[-1])
        for i in range(n):
            for j in range(n):
                G[off[i] : off[i + 1], off[j] : off[j + 1]] = np.kron(Sig[i][j], Sb(i, j))
            eta[off[i] : off[i + 1]] = (S[i * dz : (i + 1) * dz] @ L @ Th[i]).ravel(order="F")
        f = np.linalg.solve(G, eta) if off[-1] else np.zeros(0)
        F = [f[off[i] : off[i + 1]].reshape((dz, d[i]), order="F") for i in range(n)]
    # exact expected cost of z_i = F_i Y_i: E[(Lx - z)' S (Lx - z)]
    E = L @ Xk - np.vstack([F[i] @ M[i] for i in range(n)])  # maps primitives to the error
    J = float(np.trace(E.T @ S @ E @ Cov))
    return J, F


def cli_commands() -> dict:
    """Every ``teamkf`` command and its parser: ``evaluate``, ..., a group's commands by two words (``measurements convert``)."""
    import argparse

    from teamkf.cli import build_parser

    def subparsers(parser: argparse.ArgumentParser) -> dict:
        found = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        return dict(found[0].choices) if found else {}

    out: dict = {}
    for name, parser in subparsers(build_parser()).items():
        nested = subparsers(parser)
        out.update({f"{name} {sub}": q for sub, q in nested.items()} if nested else {name: parser})
    return out


def assert_lossy_mc_matches_exact(design, system, cost, T: int, p_drop: float) -> None:
    """A drop-aware design's exact expected cost equals the Monte Carlo of its own ``errors`` (4000 runs, 4 standard errors)."""
    from teamkf.simulation.sampling import sample_paths

    paths = sample_paths(system, T, 4000, rng=11)
    e = design.errors(paths, p_drop=p_drop, rng=12)
    c = np.einsum("rki,ij,rkj->r", e, cost.S_at(0), e)
    assert abs(c.mean() - design.total_cost) < 4 * c.std(ddof=1) / np.sqrt(c.size)


def assert_lossy_agents_match(design, system, cost, graph, T: int, p_drop: float) -> None:
    """The design's graph agents give its ``errors`` on reliable links, and their runtime Monte Carlo over drops its cost."""
    from teamkf.simulation.links import LinkModel
    from teamkf.simulation.monte_carlo import monte_carlo
    from teamkf.simulation.sampling import sample_paths

    paths = sample_paths(system, T, 5, rng=3)
    z = design.filter(paths.y)
    L = cost.L_at(0)
    e_run = np.stack([paths.x[:, k] @ L.T - z[:, k] for k in range(T)], axis=1)
    np.testing.assert_allclose(e_run, design.errors(paths), rtol=1e-8, atol=1e-8)
    r = monte_carlo({"d": design}, T, 400, rng=4, path="runtime", graph=graph, links=LinkModel(p_drop=p_drop))["d"]
    assert abs(r.total_mean - design.total_cost) < 4 * r.total_sem, (r.total_mean, r.total_sem, design.total_cost)


def assert_deploy_replays(tmp_path, scenario_path, hook: str) -> None:
    """``teamkf deploy SCENARIO`` over drops (p = 0.3, seed 3) with agent processes that cannot design the team (``hook``,
    a ``sitecustomize`` that makes building it an error: they must get slices), and ``teamkf filter --drops`` of the
    recorded drops gives the same estimates file byte for byte."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    from teamkf.cli import main
    from teamkf.simulation.sampling import sample_paths
    from teamkf.study import measurements as Ms
    from teamkf.study.scenario import load_scenario

    root = Path(__file__).resolve().parents[1]
    sc = load_scenario(scenario_path)
    log = tmp_path / "log.csv"
    Ms.write_measurements(str(log), [y[0] for y in sample_paths(sc.system, sc.horizon, 1, rng=2).y])
    hooks = tmp_path / "hook"
    hooks.mkdir()
    (hooks / "sitecustomize.py").write_text(hook, encoding="utf-8")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(hooks), str(root / "src"), os.environ.get("PYTHONPATH", "")])}
    out, rec, rep = tmp_path / "est.csv", tmp_path / "drops.json", tmp_path / "replay.csv"
    args = ["deploy", str(scenario_path), "--measurements", str(log), "--out", str(out), "--estimator", "mtmse_lossy"]
    args += ["--p-drop", "0.3", "--seed", "3", "--record", str(rec), "--deadline", "10"]
    proc = subprocess.run([sys.executable, "-m", "teamkf", *args], capture_output=True, text=True, env=env, timeout=400)
    assert proc.returncode == 0, proc.stderr
    assert "designs the team" not in proc.stderr
    assert main(["--quiet", "filter", str(scenario_path), "--measurements", str(log), "--drops", str(rec), "--out", str(rep)]) == 0
    assert out.read_bytes() == rep.read_bytes()
