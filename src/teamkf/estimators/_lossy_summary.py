r"""Age-keyed filter summaries for the drop-aware design (``mtmse_lossy`` with ``summary = M``).

The protocol
------------
Every agent j sends, at every step τ and on each of its out-edges, a packet with its own Kalman estimate
x̂_j(τ|τ) (prior 0, Σ_x; its own measurements only): a *summary* of everything it measured, so a later packet
replaces every earlier one that was lost. Packets are not relayed. On edge j → i (delay δ_ji, drop probability
p_e, jitter bound J_e) the packet of origin τ is lost with probability p_e and otherwise arrives at
τ + δ_ji + u, u uniform in 0..J_e, independently of every other packet. Agent i keeps the newest summary it
holds from each in-neighbour; at step k its **age** is a_ij(k) = k − δ_ji − τ* (τ* the newest origin arrived by k).

The class (stated; exact within it)
-----------------------------------
With ψ_ij(τ) = x̂_j(τ|τ) − x̂_i(τ|τ) (the neighbour's summary against the agent's own estimate of the same step,
which the agent keeps for the last δ + M steps),

.. math::  \hat z_i(k) = L_i \hat x_i(k|k) + \sum_{m < W} G_{iim}(k)\, \nu_i(k - m)
           + \sum_{j \in N_i} \sum_{m=0}^{M-1} G_{ijm}(k)\, \mathbb 1[a_{ij}(k) = m]\, \psi_{ij}(k - \delta_{ji} - m),   (S1)

with W = δ_max + M own innovations ν_i and the gains G(k) chosen offline. The summaries' gains are **keyed on the
age**, i.e. on the realized arrival pattern: a fresh summary gets the weight of a fresh summary, a stale one the
weight of a stale one, and a summary older than M steps (or none yet) none at all, so the agent falls back on its
own filter while a neighbour is silent. The own innovations carry what only the agent knows: without them the one
good sensor of the UAV formation cannot pass its measurement of the unstable mode into its estimate, and at p = 0
the class costs 14 times MTMSE; with them it is within 10⁻⁶ of it. G = 0 is the local Kalman filters (family ``local``):
the design never costs more than they do. At p = 0 and J = 0 every age is 0 and (S1) is the best linear use of the
neighbours' filters of δ steps ago and of the own recent innovations.

Why ages: with gains that do not depend on the pattern (the items classes of :mod:`teamkf.estimators.team_lossy`)
the weight on a neighbour's data must serve both its arrival and its miss; on an unstable process
(ρ(A)² p > 1) a weight large enough to track the unstable mode makes the expected cost of the misses diverge,
so those gains stay small (docs/lossy-design.md, "The UAV formation at p = 0.5"). Here the miss costs
nothing: the weight of a missing summary is simply not applied.

Optimality conditions and algorithm
-----------------------------------
e_i(k) = x(k) − x̂_i(k|k), so ψ_ij(τ) = e_i(τ) − e_j(τ) and agent i's error is L_i e_i(k) − Σ G f with
f_a = 1[a_ij(k) = m] ψ_ij(τ_a) (or ν_i(k - m), with probability 1). The ages are independent of the noises, so the expected stage cost is the convex
quadratic J_k(G) = Tr(S L̄ P_e L̄ᵀ) − 2⟨G, η⟩ + ⟨G, ΓG⟩ with

.. math::  \Gamma_{(i,a),(l,b)} = S_{il}\, P(a, b)\, \operatorname{cov}(\psi_a, \psi_b), \qquad
           \eta_{(i,a)} = P(a) \sum_l S_{il} L_l \operatorname{cov}(e_l(k), \psi_a),

and its Radner conditions Γ G = η (necessary and sufficient); J_k* = Tr(S L̄ P_e L̄ᵀ) − ⟨G, η⟩. The ages are
exact: the packet of origin k − δ − m has arrived by k with probability r_m = (1 − p_e) min(1, (m + 1)/(J_e + 1)),
packets are independent, so

.. math::  P(a_{ij}(k) = m) = r_m \prod_{m' < m} (1 - r_{m'}) \qquad (k - \delta_{ji} - m \ge 0),

P(a, b) = P(a) P(b) for features on different edges (independent packets) and P(a) δ_mm' on the same edge (one
age per edge); the own innovations have probability 1. The covariances come from one forward pass over the stacked
local-filter errors and innovations Z(k) = (E(k), ν(k)), E(k) = (e_1(k|k), …, e_n(k|k)):
Z(k) = [U; C̄] ε(k) + [−K̄; I] v(k), ε(k) = Ā E(k − 1) + 1 ⊗ w(k − 1), U = diag(I − K_j C_j), so
cov(Z(k), Z(k − d)) = [U Ā; C̄ Ā] cov(E(k − 1), Z(k − d)) over a window of δ_max + M steps. Nothing of the size of
x(k) enters, so unstable processes are fine. Γ(k) g = η(k) is solved by pivoted Cholesky (early summaries are of
low rank; a feature that is a combination of others gets zero gain, with the same minimum).

Work: one factorization of Γ(k) per step, of size Σ_i d_z (|N_i| M d_x + W d_y^i); once the moments of the window stop
changing (a time-invariant model, the local filters converged, every age law stationary) Γ, η and the cost
do not change either and the last gains serve every later step (the *steady form*: long horizons cost one
step each).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from .. import _budget
from .. import _validation as V
from .._lazy import scipy_linalg as sla
from .._linalg import block_diag
from .._validation import FloatArray
from ..exceptions import ArgumentError, ShapeError
from ._lossy_moments import local_filter_errors, local_kalman_gains

__all__ = ["MAX_AGES", "design_summary", "age_probabilities", "summary_agent_from_slice"]

#: at most this many ages per in-edge (M)
MAX_AGES = 32
#: the window's moments count as unchanged below this relative change (then the last gains serve the step)
STEADY_RTOL = 1e-13


def _edge_value(x: Any, e: tuple[int, int]) -> float:
    return float(x.get(e, 0.0)) if isinstance(x, dict) else float(x)


def age_probabilities(p: float, J: int, M: int, oldest: int) -> FloatArray:
    """P(a = m), m = 0..M-1, of one edge's age (module docstring); origins older than step 0 (m > ``oldest``) have probability 0."""
    m = np.arange(M)
    r = (1.0 - p) * np.minimum(1.0, (m + 1) / (J + 1.0))
    r[m > oldest] = 0.0
    none_newer = np.concatenate([[1.0], np.cumprod(1.0 - r)[:-1]])
    return r * none_newer  # type: ignore[no-any-return]


@dataclass(frozen=True)
class _Edges:
    """The in-edges of every agent: ``(source j, delay δ, p, J)`` lists, and δ_max."""

    into: tuple[tuple[tuple[int, int, float, int], ...], ...]
    dmax: int

    @classmethod
    def build(cls, graph: Any, p: Any, J: Any) -> "_Edges":
        n = graph.n_agents
        into: list[list[tuple[int, int, float, int]]] = [[] for _ in range(n)]
        for a, b, d in sorted((int(a), int(b), int(d)) for (a, b, d) in graph.edges):
            into[b].append((a, d, _edge_value(p, (a, b)), int(_edge_value(J, (a, b)))))
        dmax = max((d for lst in into for (_, d, _, _) in lst), default=0)
        return cls(tuple(tuple(x) for x in into), dmax)


def _solve_psd(G: FloatArray, eta: FloatArray) -> FloatArray:
    """A minimizer of gᵀ Γ g - 2 ηᵀ g for a positive semidefinite Γ with η in its range (η = E[f · error], Γ = E[f fᵀ]-like).

    Pivoted Cholesky (LAPACK dpstrf) keeps the features that are not (numerically) combinations of others — early summaries
    are of low rank — and gives the others zero gain: the same minimum, at the cost of one factorization."""
    g = np.zeros_like(eta)
    if not G.size:
        return g
    d = np.sqrt(np.maximum(np.diag(G), 0.0))
    live = d > 1e-150
    if not live.any():
        return g
    scale = 1.0 / d[live]
    Gs = G[np.ix_(live, live)] * np.outer(scale, scale)  # unit diagonal: the pivoting tolerance is relative
    c, piv, rank, info = sla.lapack.dpstrf(Gs, tol=Gs.shape[0] * 1e-13, lower=1)
    if info < 0:  # pragma: no cover - an argument error of LAPACK
        raise ArithmeticError(f"dpstrf: illegal argument {-info}")
    keep = piv[:rank] - 1
    Lr = np.tril(c[:rank, :rank])
    y = sla.solve_triangular(Lr, (eta[live] * scale)[keep], lower=True, check_finite=False)
    gl = np.zeros(int(live.sum()))
    gl[keep] = sla.solve_triangular(Lr, y, lower=True, trans="T", check_finite=False)
    g[live] = gl * scale
    return g


def _size(system: Any, cost: Any, edges: _Edges, M: int, T: int) -> tuple[float, float]:
    """(peak bytes, flops) of the design: Γ of D = Σ_i d_z (|N_i| M d_x + W d_y^i) rows (a few D² arrays), factored once per step."""
    n, dx, dz = system.n_agents, system.dx, cost.dz
    W = edges.dmax + M
    D = sum(dz * (len(edges.into[i]) * M * dx + W * system.dy[i]) for i in range(n))  # summaries and own innovations
    peak = 8.0 * (5 * D * D + 3 * (W * n * dx) ** 2 + T * D * dz)
    return peak, T * (D**3 / 3.0 + 2.0 * D * D)


def _window_moments(system: Any, Ks: list[list[FloatArray]], k: int, hist: list[list[FloatArray]], W: int) -> list[FloatArray]:
    r"""cov(Z(k), Z(k - d)), d < min(W, k + 1), of Z = (E, ν): every agent's filtered error and innovation (module docstring).

    Z(k) = [U; C̄] ε(k) + [-K̄; I] v(k), ε(k) = Ā E(k - 1) + 1 ⊗ w(k - 1) (ε(0) = 1 ⊗ x(0)), so
    cov(Z(k), Z(k - d)) = [U Ā; C̄ Ā] cov(E(k - 1), Z(k - d)) for d >= 1 (``hist[-1][d - 1]``, its E rows)."""
    n, dx = system.n_agents, system.dx
    nd = n * dx
    K = Ks[k]
    Cs = [system.C_at(j, k) for j in range(n)]
    U = block_diag(*[np.eye(dx) - K[j] @ Cs[j] for j in range(n)])
    Cb, Kb = block_diag(*Cs), block_diag(*K)
    Rb = block_diag(*[system.R_at(j, k) for j in range(n)])
    top = np.vstack([U, Cb])  # Z = top ε + bot v
    bot = np.vstack([-Kb, np.eye(Cb.shape[0])])
    if k == 0:
        P_eps = np.kron(np.ones((n, n)), system.Sigma_x)
        return [_sym(top @ P_eps @ top.T + bot @ Rb @ bot.T)]
    A = system.A_at(k - 1)  # Ā = I ⊗ A, applied block by block (never formed)
    last = hist[-1]
    AE = [_blocks_left(A, c[:nd], n) for c in last[: min(W, k + 1) - 1]]  # Ā cov(E(k - 1), Z(k - d)), d = 1..
    P_eps = _blocks_left(A, _blocks_left(A, last[0][:nd, :nd], n).T, n).T + np.tile(system.Q_at(k - 1), (n, n))
    return [_sym(top @ P_eps @ top.T + bot @ Rb @ bot.T)] + [top @ x for x in AE]


def _blocks_left(A: FloatArray, X: FloatArray, n: int) -> FloatArray:
    """(I_n ⊗ A) X for X with n d_x rows: A applied to each block of d_x rows."""
    dx = A.shape[0]
    return np.matmul(A, X.reshape(n, dx, -1)).reshape(n * dx, -1)  # type: ignore[no-any-return]


def _sym(a: FloatArray) -> FloatArray:
    return 0.5 * (a + a.T)  # type: ignore[no-any-return]


def _features(system: Any, edges: _Edges, k: int, M: int, W: int) -> list[tuple[int, int, int, int, float, int]]:
    """Step k's features (owner i, source j, age m, step τ, probability, key): the summaries of every in-edge with an
    origin τ = k - δ - m >= 0, then the own innovations ν_i(k - m), m < W (``j == i``; probability 1, a key of their own)."""
    out = []
    for i in range(system.n_agents):
        for e, (j, d, pe, Je) in enumerate(edges.into[i]):
            pr = age_probabilities(pe, Je, M, k - d)
            out += [(i, j, m, k - d - m, float(pr[m]), i * 4096 + e) for m in np.flatnonzero(pr > 0).tolist()]
        if system.dy[i]:
            out += [(i, i, m, k - m, 1.0, -1 - (i * 4096 + m)) for m in range(min(W, k + 1))]
    return out


def solve_summary(system: Any, cost: Any, edges: _Edges, T: int, M: int) -> tuple[list, list, FloatArray, FloatArray, list, dict]:
    """Per step and agent the features ((j, m): a summary of in-neighbour j of age m, or j = i: its own ν_i(k - m)) and their
    gains, the exact stage costs, the local filters' stage costs, the local Kalman gains, and ``{"steady_from": k}`` (the step
    from which the last gains were reused; None if never)."""
    n, dx, dz, off = system.n_agents, system.dx, cost.dz, system.offsets
    nd = n * dx
    nz = nd + system.dy_total
    Ks = local_kalman_gains(system, T)
    W = edges.dmax + M  # the window: steps k - W + 1 .. k
    hist: list[list[FloatArray]] = []  # hist[-1 - t][d] = cov(Z(k - t), Z(k - t - d)), d < W
    feats: list[list[tuple[tuple[int, int], ...]]] = []
    gains: list[list[FloatArray]] = []
    stage, local = np.zeros(T), np.zeros(T)
    steady_from = None
    prev: tuple[Any, ...] | None = None
    for k in range(T):
        hist.append(_window_moments(system, Ks, k, hist, W))
        if len(hist) > W:
            hist.pop(0)
        S, L = cost.S_at(k), cost.L_at(k)
        Lb = block_diag(*[L[i * dz : (i + 1) * dz] for i in range(n)])  # (n d_z, n d_x)
        SL = S @ Lb
        c0 = float(np.trace(SL @ hist[-1][0][:nd, :nd] @ Lb.T))
        local[k] = c0
        fl = _features(system, edges, k, M, W)
        feats.append([tuple((f[1], f[2]) for f in fl if f[0] == i) for i in range(n)])
        if not fl:
            gains.append([np.zeros((dz, 0)) for _ in range(n)])
            stage[k] = c0
            continue
        # the window's covariance X over (step t, Z(t)), t = t0 .. k, and one zero row (index -1) for "nothing subtracted"
        t0 = max(0, k - W + 1)
        nt = k - t0 + 1
        X = np.zeros((nt * nz + 1, nt * nz + 1))
        for a in range(nt):  # cov(Z(t0 + a), Z(t0 + b)) = hist[.][a - b] for b <= a
            row = hist[len(hist) - nt + a]
            for b in range(a + 1):
                X[a * nz : (a + 1) * nz, b * nz : (b + 1) * nz] = row[a - b]
                X[b * nz : (b + 1) * nz, a * nz : (a + 1) * nz] = row[a - b].T
        sig = tuple((i, j, m, pr, kk) for i, j, m, _, pr, kk in fl)  # what the features are, not their steps
        same_cost = prev is not None and np.array_equal(prev[3], S) and np.array_equal(prev[4], L)
        if same_cost and prev[0] == sig and _close(prev[1], X) and abs(prev[2] - c0) <= STEADY_RTOL * abs(c0):  # type: ignore[index]
            # steady: Γ(k), η(k) and c0 are those of the previous step to round-off, so are its gains and its cost
            steady_from = k if steady_from is None else steady_from
            stage[k] = stage[k - 1]
            gains.append(gains[-1])
            continue
        steady_from = None
        plus, minus, size = [], [], []
        for i, j, _, tau, _, _ in fl:
            base = (tau - t0) * nz
            if j == i:  # ν_i(τ)
                plus.append(base + nd + int(off[i]) + np.arange(system.dy[i]))
                minus.append(np.full(system.dy[i], -1))
            else:  # ψ_ij(τ) = e_i(τ) - e_j(τ)
                plus.append(base + i * dx + np.arange(dx))
                minus.append(base + j * dx + np.arange(dx))
            size.append(plus[-1].size)
        pi, pj = np.concatenate(plus), np.concatenate(minus)
        r_owner, r_m, r_p, r_key = (np.repeat([f[x] for f in fl], size) for x in (0, 2, 4, 5))
        Xpp = X[np.ix_(pi, pi)] - X[np.ix_(pi, pj)] - X[np.ix_(pj, pi)] + X[np.ix_(pj, pj)]
        rows_k = (nt - 1) * nz + np.arange(nd)  # E(k)
        Xkp = X[np.ix_(rows_k, pi)] - X[np.ix_(rows_k, pj)]
        # P(a, b): independent packets on different edges; one age per edge (the own innovations: probability 1)
        same = r_key[:, None] == r_key[None, :]
        Pab = np.where(same, np.where(r_m[:, None] == r_m[None, :], r_p[:, None], 0.0), np.outer(r_p, r_p))
        # unknowns (z-row of the owner, feature row): Γ = S[zr, zr'] P(a, b) cov(f_a, f_b), η = P(a) (S L̄ cov(E(k), f))[zr, a]
        zr = (r_owner[:, None] * dz + np.arange(dz)).T.ravel()
        fr = np.tile(np.arange(r_owner.size), dz)
        Gm = S[np.ix_(zr, zr)] * (Pab * Xpp)[np.ix_(fr, fr)]
        Gm = _sym(Gm)
        eta = r_p[fr] * (SL @ Xkp)[zr, fr]
        g = _solve_psd(Gm, eta)
        stage[k] = c0 - 2.0 * float(g @ eta) + float(g @ (Gm @ g))
        prev = (sig, X, c0, S, L)
        out = []
        for i in range(n):
            mine = np.flatnonzero(r_owner == i)
            Gi = np.zeros((dz, mine.size))
            sel = np.flatnonzero(r_owner[fr] == i)
            Gi[zr[sel] - i * dz, np.searchsorted(mine, fr[sel])] = g[sel]
            out.append(Gi)
        gains.append(out)
    return feats, gains, stage, local, Ks, {"steady_from": steady_from}


def _close(a: FloatArray, b: FloatArray) -> bool:
    return a.shape == b.shape and float(np.max(np.abs(a - b))) <= STEADY_RTOL * max(float(np.max(np.abs(a))), 1e-300)


# ---------------------------------------------------------------------------
# the design object, its Monte Carlo and its agents
# ---------------------------------------------------------------------------
def _delays(edges: _Edges, n: int) -> np.ndarray:
    """(n, n) int: δ_ji of edge j -> i, -1 where there is none."""
    out = np.full((n, n), -1, dtype=np.int64)
    for i, lst in enumerate(edges.into):
        for j, d, _, _ in lst:
            out[j, i] = d
    return out


def _arrival_steps(delays: np.ndarray, T: int, n_runs: int, p_drop: Any, jitter: Any, rng: Any, arrived: Any) -> np.ndarray:
    """(n_runs, T, n, n) int: the step at which the summary of origin τ on edge j -> i arrives, -1 when lost (or no edge).

    Sampled per packet (lost with p_e, else late by u uniform in 0..J_e), or from ``arrived`` (n_runs, T, n, n) booleans
    (the packet of origin τ on j -> i arrived, on time), or every packet on time when neither is given."""
    n = delays.shape[0]
    edge = delays >= 0
    base = np.arange(T)[None, :, None, None] + delays[None, None]
    if arrived is not None:
        arrived = np.asarray(arrived, dtype=bool)
        if arrived.shape != (n_runs, T, n, n):
            raise ShapeError(f"arrived: expected shape {(n_runs, T, n, n)}, found {arrived.shape}")
        return np.where(arrived & edge, base, -1)  # type: ignore[no-any-return]
    if p_drop is None:
        return np.where(edge, np.broadcast_to(base, (n_runs, T, n, n)), -1)  # type: ignore[no-any-return]
    gen = np.random.default_rng(rng)
    pe = np.array([[_edge_value(p_drop, (j, i)) for i in range(n)] for j in range(n)])
    Je = np.array([[int(_edge_value(0 if jitter is None else jitter, (j, i))) for i in range(n)] for j in range(n)])
    lost = gen.random((n_runs, T, n, n)) < pe
    late = np.floor(gen.random((n_runs, T, n, n)) * (Je + 1)).astype(np.int64)
    return np.where(edge & ~lost, base + late, -1)  # type: ignore[no-any-return]


def _design_class() -> Any:
    from .team_lossy import LossyTeamDesign

    @dataclass(frozen=True, eq=False, kw_only=True)
    class SummaryLossyDesign(LossyTeamDesign):
        """The drop-aware design on age-keyed filter summaries, (S1) of :mod:`teamkf.estimators._lossy_summary`.

        ``items[k][i]`` are agent i's features (j, m) at step k (in-neighbour j, age m), ``gains[k][i]`` their gains
        (d_z, d_x per feature), ``delays`` the edge delays δ_ji (-1: no edge), ``ages`` M.
        """

        ages: int = field(default=1)
        delays: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), dtype=np.int64), repr=False)

        def errors(self, paths: Any, *, p_drop: Any = None, jitter: Any = None, rng: Any = None, arrived: Any = None) -> Any:
            """Team errors L x(k) - ẑ(k), (n_runs, T', n d_z), with sampled packets (``p_drop``, ``jitter``, ``rng``), or ``arrived``
            (n_runs, T', n, n) booleans (the summary of origin τ on edge j -> i arrived on time), or reliable links."""
            x0, w, v, _ = self._error_inputs(paths, None, None, None, None)
            sysm, cost = self.system, self.cost
            n_runs, T = v.shape[:2]
            n, dx, dz, off = sysm.n_agents, sysm.dx, cost.dz, sysm.offsets
            at = _arrival_steps(self.delays, T, n_runs, p_drop, jitter, rng, arrived)
            newest = np.full((n_runs, n, n), -1, dtype=np.int64)  # newest origin arrived so far on j -> i
            Wd = int(np.max(self.delays)) + self.ages
            hist: dict[int, Any] = {}  # step -> (e(k|k) of every agent, [ν_j(k)])
            out = np.empty((n_runs, T, n * dz))
            for k, nu_k, ef in local_filter_errors(sysm, self.K_local, x0, w, v):
                hits = at == k  # (n_runs, τ, j, i)
                if hits.any():
                    tau = np.where(hits, np.arange(T)[None, :, None, None], -1).max(axis=1)
                    np.maximum(newest, tau, out=newest)
                hist[k] = (ef, [nu_k[:, int(off[j]) : int(off[j]) + sysm.dy[j]] for j in range(n)])
                hist.pop(k - Wd - 1, None)
                L = cost.L_at(k)
                for i in range(n):
                    z = ef[:, i * dx : (i + 1) * dx] @ L[i * dz : (i + 1) * dz].T
                    col = 0
                    for j, m in self.items[k][i]:
                        if j == i:  # the own innovation ν_i(k - m)
                            f, col = hist[k - m][1][i], col + sysm.dy[i]
                            z = z - f @ self.gains[k][i][:, col - f.shape[1] : col].T
                            continue
                        tau_a = k - int(self.delays[j, i]) - m
                        on = newest[:, j, i] == tau_a
                        col += dx
                        if on.any():
                            e_t = hist[tau_a][0]
                            psi = e_t[:, i * dx : (i + 1) * dx] - e_t[:, j * dx : (j + 1) * dx]  # e_i(τ) - e_j(τ)
                            z = z - on[:, None] * (psi @ self.gains[k][i][:, col - dx : col].T)
                    out[:, k, i * dz : (i + 1) * dz] = z
            return out

        def graph_agents(self) -> list[Any]:
            return [SummaryAgent(self, i) for i in range(self.n_agents)]

        def agent_slice(self, i: int) -> tuple[str, dict[str, np.ndarray], dict[str, Any]]:
            """Agent i's arrays: ``delays`` (δ_ji for every j, -1: no edge), per step k ``K/k``, ``feats/k`` ((j, m) rows), ``G/k``."""
            T = int(self.horizon or 0)
            arrays: dict[str, np.ndarray] = {"delays": np.asarray(self.delays[:, i], dtype=np.int64).copy()}
            for k in range(T):
                arrays[f"K/{k}"] = np.asarray(self.K_local[k][i])
                arrays[f"feats/{k}"] = np.asarray(self.items[k][i], dtype=np.int64).reshape(-1, 2)
                arrays[f"G/{k}"] = np.asarray(self.gains[k][i])
            return "summary", arrays, {"horizon": T, "ages": int(self.ages)}

        def details(self) -> dict[str, Any]:
            out = super().details()
            out["summary"] = self.ages
            out["class"] = (
                f"gains per step keyed on the age (< {self.ages}) of the newest filter summary from each in-neighbour (summaries not relayed)"
            )
            return out

        def arrays(self) -> dict[str, np.ndarray]:
            out = super().arrays()
            out["summary"] = np.asarray(self.ages)
            out["delays"] = np.asarray(self.delays)
            return out

    return SummaryLossyDesign


class SummaryAgent:
    """Agent i of a summary design on the message-passing runtime: its own Kalman filter, a packet (i, k, x̂_i(k|k)) per step
    to its out-neighbours, the newest summary of each in-neighbour kept, and (S1) keyed on its age."""

    def __init__(self, design: Any, index: int):
        self.design, self.index, self.system = design, index, design.system

    def init_state(self, n_runs: int) -> dict[str, Any]:
        return {"xhat": np.zeros((n_runs, self.system.dx)), "own": {}, "newest": {}, "n_runs": n_runs}

    def step(self, state: dict[str, Any], k: int, own: Any, inbox: Sequence[Any]) -> tuple[dict[str, Any], FloatArray, list[Any]]:
        d, i, sysm = self.design, self.index, self.system
        xhat = state["xhat"] if k == 0 else state["xhat"] @ sysm.A_at(k - 1).T
        nu = np.asarray(own, dtype=float) - xhat @ sysm.C_at(i, k).T
        xhat = xhat + nu @ d.K_local[k][i].T
        delays = d.delays[:, i]
        keep = int(np.max(delays)) + d.ages
        mine = {t: x for t, x in state["own"].items() if t >= k - keep}  # step -> (x̂_i(t|t), ν_i(t))
        mine[k] = (xhat, nu)
        newest = dict(state["newest"])
        for _, _, payload in inbox:
            for j, tau, val in payload:
                if delays[j] >= 0 and (j not in newest or tau > newest[j][0]):
                    newest[j] = (int(tau), np.asarray(val, dtype=float))
        z = xhat @ d.cost.L_block(i, k).T
        G, col = d.gains[k][i], 0
        for j, m in d.items[k][i]:  # (S1): the own innovations ν_i(k - m), and the summaries keyed on their age
            if j == i:
                col += sysm.dy[i]
                z = z + mine[k - m][1] @ G[:, col - sysm.dy[i] : col].T
                continue
            col += sysm.dx
            got = newest.get(j)
            if got is not None and got[0] == k - int(delays[j]) - m:
                z = z + (got[1] - mine[got[0]][0]) @ G[:, col - sysm.dx : col].T
        return {"xhat": xhat, "own": mine, "newest": newest, "n_runs": state["n_runs"]}, z, [(i, k, xhat)]

    @staticmethod
    def run_batched(agents: Sequence["SummaryAgent"], ys: Sequence[FloatArray], out: Any) -> FloatArray:
        """Every agent's :meth:`step` for every run at once on the lossy runtime's link outcomes ``out``
        (:class:`teamkf.simulation.lossy.LinkOutcomes`): the same numbers run by run (rows stacked as (R, 1, d), so each
        product has the one-run step's core shapes), the newest summary of each in-edge read off the arrival steps."""
        d = agents[0].design
        sysm, n = d.system, len(agents)
        R, T = ys[0].shape[:2]
        dx = sysm.dx
        edge = {(a, b): q for q, (a, b, _) in enumerate(out.edges)}
        arrive = np.where(out.delivered, out.arrive, -1)  # (R, T, E): the arrival step of the packet sent at τ, -1: never
        newest = np.full((R, len(out.edges)), -1, dtype=np.int64)
        span = int(np.max(out.arrive - np.arange(T)[None, :, None], initial=0)) if out.edges else 0  # the longest latency
        xh = [np.zeros((R, 1, dx)) for _ in range(n)]
        hist: dict[int, list[tuple[FloatArray, FloatArray]]] = {}
        keep = int(np.max(d.delays)) + d.ages
        z_all = np.empty((R, T, n * d.cost.dz))
        for k in range(T):
            lo = max(0, k - span)
            hit = arrive[:, lo : k + 1] == k  # packets of origins lo..k arriving now
            if hit.any():
                np.maximum(newest, np.where(hit, np.arange(lo, k + 1)[None, :, None], -1).max(axis=1), out=newest)
            step = []
            for i in range(n):
                xhat = xh[i] if k == 0 else xh[i] @ sysm.A_at(k - 1).T
                nu = ys[i][:, k, None, :] - xhat @ sysm.C_at(i, k).T
                xh[i] = xhat + nu @ d.K_local[k][i].T
                step.append((xh[i], nu))
            hist[k] = step
            hist.pop(k - keep - 1, None)
            for i in range(n):
                z = xh[i] @ d.cost.L_block(i, k).T
                G, col = d.gains[k][i], 0
                for j, m in d.items[k][i]:
                    if j == i:
                        col += sysm.dy[i]
                        z = z + hist[k - m][i][1] @ G[:, col - sysm.dy[i] : col].T
                        continue
                    col += dx
                    tau = k - int(d.delays[j, i]) - m
                    on = newest[:, edge[(j, i)]] == tau
                    if on.any():
                        z = np.where(on[:, None, None], z + (hist[tau][j][0] - hist[tau][i][0]) @ G[:, col - dx : col].T, z)
                z_all[:, k, i * d.cost.dz : (i + 1) * d.cost.dz] = z[:, 0, :]
        return z_all


_CLASS: list[Any] = []


def design_summary(
    system: Any,
    cost: Any,
    graph: Any,
    T: int,
    p: Any,
    J: Any,
    arr: Any,
    M: int,
    bound: bool,
    threads: int | None,
    *,
    others: tuple = (0, None, 1, True, "auto", None),
    known: Any = None,
) -> Any:
    """``design_mtmse_lossy(..., summary=M)`` (module docstring): sized first, then solved step by step. ``others``: the
    options of the item classes (keyed, memory, resend, fill, items, held_window), refused unless at their defaults;
    ``known``: the :class:`~teamkf.estimators._lossy_bound.KnownRequest` of the design (None: no bound), the known-pattern optimum of the protocol (:func:`bound_protocol`)."""
    from .._blas import blas_threads
    from .team_lossy import build_lossy_design

    keyed, memory, resend, fill, items, held_window = others
    if keyed or memory is not None or resend != 1 or fill == "held" or items != "auto" or held_window is not None:
        raise ArgumentError(
            f"summary: summary = {M} is a class of its own (no items), found keyed = {keyed}, memory = {memory}, resend = {resend}, "
            f"fill = {fill!r}, items = {items!r}, held_window = {held_window}; drop them or use summary = 0",
            argument="summary",
        )
    M = V.integer(M, "summary", minimum=1, maximum=MAX_AGES, what="the ages M kept per in-neighbour")
    edges = _Edges.build(graph, p, J)
    peak, flops = _size(system, cost, edges, M, T)
    what = f"the mtmse_lossy summary design (summary = {M}) over T = {T:,} steps"
    smaller = (
        f"use summary = {max(1, M // 2)} (fewer ages: Γ has Σ_i d_z |N_i| M d_x rows) or a shorter horizon" if M > 1 else "use a shorter horizon"
    )
    _budget.check_memory(peak, what, argument="summary", fix=smaller)
    _budget.announce(_budget.check_work(flops, what, argument="summary", fix=smaller), what)
    with blas_threads(threads):
        feats, gains, stage, local, Ks, extra = solve_summary(system, cost, edges, T, M)
    if not _CLASS:
        _CLASS.append(_design_class())
    n = system.n_agents
    d = build_lossy_design(
        _CLASS[0],
        system,
        cost,
        graph,
        T,
        p=p,
        J=J,
        memory=None,
        coords="summaries",
        arr=arr,
        items=tuple(tuple(step) for step in feats),
        gains=gains,
        fills=[[np.zeros((0, 0)) for _ in range(n)] for _ in range(T)],
        K_local=Ks,
        stage=stage,
        local=local,
        bound=bound,
        items_costs={"summaries": float(np.sum(stage))},
        info_mid={"summary": M},
        info_tail=extra,
        ages=M,
        delays=_delays(edges, n),
    )
    return d if known is None else known.attach(d, *bound_protocol(arr, edges, T))


def bound_protocol(arr: Any, edges: _Edges, T: int) -> tuple[str, int]:
    """The known-pattern optimum that bounds the summary design: ``("ontime", T)`` (on-time packets carrying the sender's
    whole history: what the summaries carry, relays only adding) when there is no jitter and every edge is a geodesic
    (a summary is then held exactly when its packet is on time), else ``("all", 1)`` (a packet carries everything its
    sender holds: a bound for every protocol)."""
    ok = all(J == 0 and d == int(arr.ell[j, i]) for i, lst in enumerate(edges.into) for (j, d, _, J) in lst)
    return ("ontime", T) if ok else ("all", 1)


# ---------------------------------------------------------------------------
# the agent of a deployed slice (teamkf deploy): no team design in its process
# ---------------------------------------------------------------------------
def summary_agent_from_slice(ctx: Any, i: int, arrays: dict[str, np.ndarray], meta: dict[str, Any]) -> tuple[Any, Any]:
    """``(view, agent)`` of agent i rebuilt from :meth:`SummaryLossyDesign.agent_slice` and the scenario's model."""
    from ._lossy_slice import slice_view

    n = int(ctx.system.n_agents)
    delays = np.full((n, n), -1, dtype=np.int64)
    delays[:, i] = np.asarray(arrays["delays"], dtype=np.int64)
    view = slice_view(ctx, i, arrays, meta, "feats", coordinates="summaries")
    view.delays, view.ages = delays, int(meta["ages"])  # type: ignore[attr-defined]
    return view, SummaryAgent(view, i)


from .team_lossy import register_summary  # noqa: E402  (this module extends team_lossy, which never imports it)

register_summary(design_summary)
