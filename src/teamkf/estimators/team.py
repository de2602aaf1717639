"""Minimum team mean-squared error (MTMSE) estimation and filtering.

* :func:`static_team_estimate` — Theorem 1: agents hold a common y_0 and local y_i.
* :func:`design_mtmse` — Theorems 2 (finite horizon) and 3 (infinite horizon)
  for ANY information structure (any strongly connected delay graph, reduced
  structures included).
* :func:`design_mmse` — the per-agent MMSE baseline z_i = L_i E[x | I_i] (eq. 46)
  with its analytic team cost (eq. 47).

How the local innovation is built for any structure (steps 0-based)
-------------------------------------------------------------------
Let c be the common lag and a = max(0, k - c + 1) the *anchor* step. Every
agent holds the common part y(0:a-1) = y(0:k-c), so x^(a) = E[x(a) | y(0:a-1)]
is the centralized one-step predictor (eq. 20) with error covariance P(a)
(eq. 22; P(0) = Sigma_x, the first steps k < c included). Each agent's local
measurements are a subset of the *window* y(a:k). With the error trajectory
eps(s) = x(s) - Phi(s, a) x^(a), eps(a) = x~(a), eps(s+1) = A eps(s) + w(s),

    y~(s) = y(s) - C(s) Phi(s, a) x^(a) = C(s) eps(s) + v(s)       (eqs. 27, 29)
    Pi(s) = var eps(s):   Pi(a) = P(a),  Pi(s+1) = A Pi(s) A' + Q
    cov(y~(s), y~(s')) = C(s) Phi(s, s') Pi(s') C(s')' + delta_ss' R(s)   (s >= s')
    cov(x(k) - x^com(k), y~(s)) = Phi(k, s) Pi(s) C(s)'

so the covariance Sigma_W of the whole window innovation and its cross
covariance Theta_W with the common-estimate error follow in one pass, and

    Sigma^_ij(k) = Sigma_W[idx_i, idx_j]     (eq. 30: C^loc P C^loc' + P^w_ij + P^v_ij)
    Theta^_i(k)  = Theta_W[:, idx_i]         (eq. 31: A^{c-1} P C^loc' + P^sigma_i)
    P_0(k)       = Pi(k)                     (eq. 36: A^{c-1} P A^{c-1}' + Sigma^w)

where idx_i are the positions of agent i's local measurements in the window.
:meth:`TeamDesign.local_terms` returns C_loc, P^w, P^v, P^sigma and Sigma^w
explicitly for any structure. The gains solve Gamma F = eta (eq. 34,
:mod:`teamkf.estimators.gamma`) and the stage cost is
Tr(L'SL P_0) - eta' Gamma^-1 eta (eq. 35).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, ClassVar, Literal, Sequence

import numpy as np

from .. import _validation as V
from .._lazy import scipy_linalg as sla  # SciPy / networkx load on first use
from .._linalg import block_diag
from .._validation import FloatArray
from ..exceptions import InformationStructureError, UnsupportedOperationError
from ..models import LinearGaussianSystem, TeamCost
from ..network.information import InformationStructure
from ._kalman_common import kalman_covariances, predictor_errors, steady_state
from .base import Design, Packet, check_paths
from .checks import check_model
from .gamma import DENSE_MAX_BYTES, choose_solver, innovations_pays
from .registry import Family, Option, _register_builtin
from .static_team import (  # noqa: F401  (Theorem 1 and the static solve; public here too)
    StaticTeamEstimate,
    _eta,
    _mmse_gains,
    _solve_step,
    _solve_step_innovations,
    gains_team_cost,
    static_team_estimate,
)

__all__ = [
    "StaticTeamEstimate",
    "static_team_estimate",
    "TeamDesign",
    "TeamAgent",
    "design_mtmse",
    "design_mmse",
    "window_covariances",
    "gains_team_cost",
]

Kind = Literal["mtmse", "mmse"]


# ---------------------------------------------------------------------------
# The per-step machinery shared by Theorems 2 and 3
# ---------------------------------------------------------------------------
def window_covariances(system: LinearGaussianSystem, k: int, anchor: int, P_anchor: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Covariances of the window innovation y~(anchor:k) (see the module docstring).

    Returns
    -------
    Sigma_W : (w d_y, w d_y)  covariance of vec(y~(anchor), ..., y~(k)), w = k - anchor + 1
    Theta_W : (d_x, w d_y)    cov(x(k) - Phi(k, anchor) x^(anchor), y~(.))
    P0 : (d_x, d_x)           var(x(k) - Phi(k, anchor) x^(anchor))
    """
    w = k - anchor + 1
    dy = system.dy_total
    need = 3 * 8.0 * (w * dy) ** 2  # Sigma_W, and about twice it in the solve
    if need > 2**26:  # checked only when large: reading the free memory costs a system call
        from .._budget import check_memory

        check_memory(
            need,
            f"a window of {w:,} steps x {dy} measurements (its {w * dy:,} x {w * dy:,} innovation covariance; w is the common lag)",
            argument="common_lag",
            fix="use a smaller information.common_lag (the window grows with it), or fewer agents",
        )
    Sigma_W = np.zeros((w * dy, w * dy))
    Theta_W = np.zeros((system.dx, w * dy))
    Pi = np.array(P_anchor, dtype=float)
    Cs = [system.C_stack(s) for s in range(anchor, k + 1)]
    for u in range(w):  # u = s - anchor
        s = anchor + u
        G = Pi @ Cs[u].T  # cov(eps(s), y~(s))
        blk = slice(u * dy, (u + 1) * dy)
        Sigma_W[blk, blk] = Cs[u] @ G + system.R_stack(s)
        for u2 in range(u + 1, w):  # propagate to later steps s' = anchor + u2
            G = system.A_at(anchor + u2 - 1) @ G
            blk2 = slice(u2 * dy, (u2 + 1) * dy)
            Sigma_W[blk2, blk] = Cs[u2] @ G
            Sigma_W[blk, blk2] = Sigma_W[blk2, blk].T
        Theta_W[:, blk] = G  # now Phi(k, s) Pi(s) C(s)'
        if u < w - 1:
            A = system.A_at(s)
            Pi = A @ Pi @ A.T + system.Q_at(s)
            Pi = 0.5 * (Pi + Pi.T)
    return 0.5 * (Sigma_W + Sigma_W.T), Theta_W, Pi


def _window_positions(system: LinearGaussianSystem, anchor: int, pairs: Sequence[tuple[int, int]]) -> np.ndarray:
    """Positions of the measurements y_j(s), (j, s) in ``pairs`` (in that order), in the window y(anchor:k)."""
    if not pairs:
        return np.zeros(0, dtype=int)
    js, ss = np.asarray(pairs, dtype=int).T
    lens = np.asarray(system.dy, dtype=int)[js]
    starts = (ss - anchor) * system.dy_total + np.asarray(system.offsets, dtype=int)[js]
    # the block [start, start + d_y^j) of every pair, concatenated: start repeated d_y^j times plus 0 .. d_y^j - 1
    return np.repeat(starts - (np.cumsum(lens) - lens), lens) + np.arange(int(lens.sum()))


def _local_index(system: LinearGaussianSystem, structure: InformationStructure, i: int, k: int, anchor: int) -> np.ndarray:
    """Positions of agent i's local measurements (in local_pairs order) in the window y(anchor:k)."""
    return _window_positions(system, anchor, structure.local_pairs(i, k))


# ---------------------------------------------------------------------------
# Theorems 2 and 3
# ---------------------------------------------------------------------------
@dataclass(frozen=True, eq=False, kw_only=True)
class TeamDesign(Design):
    """Gains and analytic cost of an MTMSE (or per-agent MMSE) filter.

    z_i(k) = L_i x^com(k) + F_i(k) (I_i^loc(k) - C_i^loc x^(anchor))   (eq. 32)

    Built by :func:`~teamkf.design_mtmse` (Theorems 2-3) and :func:`~teamkf.design_mmse` (eq. 46).

    Parameters
    ----------
    estimator, horizon, system, cost, stage_costs, average_cost, info, graph
        As in :class:`~teamkf.Design`: the family name, T (None for the steady state), the
        model, the team cost, the exact E[c(x(k), ẑ(k))] per step and the plain-data facts.
    structure : InformationStructure
        Who holds which measurement when: I_i(k), from a graph (eq. 14) or reduced.
    gains : tuple over steps of tuples over agents of (d_z, d_i(k)) arrays
        F_i(k) for k = 0..T-1 (finite horizon). For the steady state use
        :meth:`gain_at`: the exact gains of the first c steps (anchor x(0),
        P(0) = Sigma_x) are computed on first use, F-bar afterwards.
    steady_gains : tuple of (d_z, d_i) arrays or None
        F-bar_i of Theorem 3, used for k >= c.
    K : array
        The common Kalman gain schedule (T, d_x, d_y), or K-bar (d_x, d_y) in the steady state.
    P_pred : array
        The common predictor covariances P(k), or P-bar.
    warmup : callable or None
        For the steady state: k -> the exact gains of step k < c (computed on first use).

    See Also
    --------
    design_mtmse, design_mmse

    Examples
    --------
    >>> from teamkf import LinearGaussianSystem, TeamCost, CommGraph, design_mtmse
    >>> d = design_mtmse(LinearGaussianSystem.platoon(4), TeamCost.platoon(4, 100.0), CommGraph.line(4, delay=1), horizon=5)
    >>> len(d.gains), len(d.gains[0]), d.gains[0][0].shape[0]
    (5, 4, 1)
    """

    structure: InformationStructure
    gains: tuple[tuple[FloatArray, ...], ...] = ()
    steady_gains: tuple[FloatArray, ...] | None = None
    K: FloatArray
    P_pred: FloatArray
    warmup: Callable[[int], tuple[FloatArray, ...]] | None = field(default=None, repr=False)

    #: exact on the masked model of a missingness pattern (zero gains on decoupled pseudo-measurements)
    handles_missing: ClassVar[bool] = True

    def gain_at(self, k: int) -> tuple:
        """F_i(k) for every agent (steady state: the exact transient gains for k < c, then F-bar)."""
        if self.horizon is not None:
            return self.gains[k]  # type: ignore[no-any-return]
        if k >= self.structure.common_lag:
            return self.steady_gains  # type: ignore[return-value]
        cache = self.info.setdefault("_warmup_gains", {})
        if k not in cache:
            cache[k] = self.warmup(k)  # type: ignore[misc]  # set for every steady-state design
        return cache[k]  # type: ignore[no-any-return]

    def K_at(self, m: int) -> FloatArray:
        return self.K if self.horizon is None else self.K[m]  # type: ignore[no-any-return]

    def P_anchor(self, k: int) -> tuple[int, FloatArray]:
        c = self.structure.common_lag
        a = max(0, k - c + 1)
        if self.horizon is None:
            return a, (self.system.Sigma_x if a == 0 else self.P_pred)
        return a, self.P_pred[a]

    def _local_maps(self, i: int, k: int) -> tuple[FloatArray, FloatArray, list[tuple[int, int]]]:
        """C_i^loc and the map W_i from w(a..k-1) to w_i^loc (eq. 27), with agent i's local pairs."""
        sys = self.system
        a, _ = self.P_anchor(k)
        pairs = self.structure.local_pairs(i, k)
        dx, nw = sys.dx, k - a
        C_loc, W_rows = [np.zeros((0, dx))], [np.zeros((0, nw * dx))]
        for j, s in pairs:
            Cj = sys.C_at(j, s)
            C_loc.append(Cj @ sys.transition(s, a))
            Wr = np.zeros((Cj.shape[0], nw * dx))
            for r in range(a, s):  # y_j(s) contains C_j Phi(s, r+1) w(r)
                Wr[:, (r - a) * dx : (r - a + 1) * dx] = Cj @ sys.transition(s, r + 1)
            W_rows.append(Wr)
        return np.vstack(C_loc), np.vstack(W_rows), pairs

    def local_covariances(self, i: int, j: int, k: int) -> dict[str, FloatArray]:
        """P^w_ij, P^v_ij and Sigma^_ij (eq. 30) for agents i, j at step k, built from the primitive noises.

        This is independent of the window recursion used for the gains; tests
        hold the two against each other. P^v_ij is non-zero whenever the two
        agents' local vectors share a measurement (e.g. neighbours on a line).
        """
        sys = self.system
        a, P = self.P_anchor(k)
        Ci, Wi, pi = self._local_maps(i, k)
        Cj, Wj, pj = self._local_maps(j, k)
        Qbig = block_diag(*[sys.Q_at(r) for r in range(a, k)]) if k > a else np.zeros((0, 0))
        P_w = Wi @ Qbig @ Wj.T
        oi = np.concatenate([[0], np.cumsum([sys.dy[m] for m, _ in pi])]).astype(int)
        oj = np.concatenate([[0], np.cumsum([sys.dy[m] for m, _ in pj])]).astype(int)
        P_v = np.zeros((oi[-1], oj[-1]))
        where_j = {p: q for q, p in enumerate(pj)}
        for q, p in enumerate(pi):  # the same y_m(s) in both vectors shares v_m(s)
            if p in where_j:
                r = where_j[p]
                P_v[oi[q] : oi[q + 1], oj[r] : oj[r + 1]] = sys.R_at(p[0], p[1])
        return {"P_w": P_w, "P_v": P_v, "Sigma_hat": Ci @ P @ Cj.T + P_w + P_v}

    def local_terms(self, i: int, k: int) -> dict[str, FloatArray]:
        """C_i^loc, P^w_ii, P^v_ii, P^sigma_i, Sigma^w, Sigma^_ii, Theta^_i and P_0 (eqs. 27-31, 36) at step k.

        Built explicitly from the primitive noises for any structure (the
        paper derives them by hand for its two examples only).
        """
        sys = self.system
        a, P = self.P_anchor(k)
        C_loc, W_loc, _ = self._local_maps(i, k)
        dx = sys.dx
        Qbig = block_diag(*[sys.Q_at(r) for r in range(a, k)]) if k > a else np.zeros((0, 0))
        Wx = np.hstack([sys.transition(k, r + 1) for r in range(a, k)]) if k > a else np.zeros((dx, 0))
        Psig = Wx @ Qbig @ W_loc.T  # cov(w^(c-1)(0, k), w_i^loc)
        Sw = Wx @ Qbig @ Wx.T
        Phi = sys.transition(k, a)
        cov = self.local_covariances(i, i, k)
        return {
            "C_loc": C_loc,
            "P_w": cov["P_w"],
            "P_v": cov["P_v"],
            "P_sigma": Psig,
            "Sigma_w": Sw,
            "Sigma_hat": cov["Sigma_hat"],
            "Theta_hat": Phi @ P @ C_loc.T + Psig,
            "P0": Phi @ P @ Phi.T + Sw,
        }

    def errors(self, paths: Any) -> FloatArray:
        """L x(k) - z(k) on sampled paths, computed from the primitive noises (no cancellation).

        With eps(m) = x(m) - x^(m) the common predictor's error (:func:`predictor_errors`),
        the window errors eps(s+1) = A eps(s) + w(s) from eps(anchor), the
        innovations y~(s) = C eps(s) + v(s), and e_i(k) = L_i eps(k) - F_i(k) I~_i(k):
        exactly what the online agents produce, but without subtracting two
        large numbers when A is unstable.
        """
        check_paths(paths, self.system)
        sys, cost, st = self.system, self.cost, self.structure
        n, dz = sys.n_agents, cost.dz
        eps_pred = predictor_errors(sys, self.K_at, paths, max(paths.n_steps - st.common_lag + 1, 1))
        v = paths.v_stack
        out = np.empty((paths.n_runs, paths.n_steps, n * dz))
        for k in range(paths.n_steps):
            a = max(0, k - st.common_lag + 1)
            eps = eps_pred[:, a]
            innov = []
            for s in range(a, k + 1):
                if s > a:
                    eps = eps @ sys.A_at(s - 1).T + paths.w[:, s - 1]
                innov.append(eps @ sys.C_stack(s).T + v[:, s])
            Yw = np.concatenate(innov, axis=1)
            e = eps @ cost.L_at(k).T
            F = self.gain_at(k)
            for i in range(n):
                idx = _local_index(sys, st, i, k, a)
                if idx.size:
                    e[:, i * dz : (i + 1) * dz] -= Yw[:, idx] @ F[i].T
            out[:, k] = e
        return out

    def agents(self) -> list["TeamAgent"]:
        return [TeamAgent(self, i) for i in range(self.system.n_agents)]

    def agent_slice(self, i: int) -> tuple[str, dict[str, np.ndarray], dict[str, Any]]:
        """Agent i's slice: the common gains K(k) and P(k) (every agent folds the common part) and its own F_i(k)."""
        c = self.structure.common_lag
        steps = range(self.horizon) if self.horizon is not None else range(c)
        arrays = {"K": np.asarray(self.K), "P_pred": np.asarray(self.P_pred)}
        arrays.update({f"F/{k}": np.asarray(self.gain_at(k)[i]) for k in steps})
        if self.horizon is None:
            arrays["F_steady"] = np.asarray(self.steady_gains[i])  # type: ignore[index]
        return "team", arrays, {"horizon": self.horizon, "common_lag": int(c), "variant": self.info.get("variant")}

    def steady_form(self) -> Any:
        """The steady-state filter as an LTI map (:class:`~teamkf.estimators.steady.SteadyForm`) from step c on.

        With a = k - c + 1 and agent i's local pairs (j, k - l) (eqs. 28-29, steady gains F̄_i):
        z_i(k) = L_i A^{c-1} x̂(a) + Σ F̄_i[:, (j, l)] (y_j(k - l) - C_j A^{c-1-l} x̂(a)).
        """
        from .steady import SteadyForm

        if self.horizon is None and self.steady_gains is not None:
            sys, st, cost = self.system, self.structure, self.cost
            c, n, dz = st.common_lag, sys.n_agents, cost.dz
            A, C, K = sys.A_at(0), sys.C_stack(0), np.asarray(self.K)
            Ap = [np.linalg.matrix_power(A, p) for p in range(c)]
            G = np.zeros((n * dz, sys.dx))
            H = np.zeros((c, n * dz, sys.dy_total))
            offs = sys.offsets
            k = c  # any step >= c: the pairs are (j, k - l)
            for i in range(n):
                rows = slice(i * dz, (i + 1) * dz)
                F = np.asarray(self.steady_gains[i])
                G[rows] = cost.L_block(i, k) @ Ap[c - 1]
                col = 0
                for j, s in st.local_pairs(i, k):
                    lag, d = k - s, sys.dy[j]
                    Fb = F[:, col : col + d]
                    G[rows] -= Fb @ sys.C_at(j, k) @ Ap[c - 1 - lag]
                    H[lag, rows, offs[j] : offs[j] + d] += Fb
                    col += d
            IKC = np.eye(sys.dx) - K @ C
            return SteadyForm(M=A @ IKC, N=A @ K, G=G, H=H, start=c)
        raise UnsupportedOperationError(self.estimator, "steady_form()", "it is a finite-horizon design; design with horizon=None")

    def details(self) -> dict[str, Any]:
        last = self.steady_gains if self.steady_gains is not None else self.gains[-1]
        return {
            "common_lag": self.structure.common_lag,
            "local_dims": list(self.structure.local_dims(self.system.dy)),
            "gain_shapes": {f"F_{i}": list(np.asarray(F).shape) for i, F in enumerate(last)},
        }

    def arrays(self) -> dict[str, np.ndarray]:
        """Costs, the Kalman gains ``K``, the gains ``F_{i}_t{k}`` (steady state: the first c steps and ``F_{i}``)
        and each agent's local pairs ``local_{i}`` ((j, lag) rows)."""
        out = {**super().arrays(), "K": np.asarray(self.K, dtype=float)}
        steps = self.gains if self.horizon is not None else [self.gain_at(k) for k in range(self.structure.common_lag)]
        for k, step in enumerate(steps):
            for i, F in enumerate(step):
                out[f"F_{i}_t{k}"] = np.asarray(F, dtype=float)
        if self.steady_gains is not None:
            for i, F in enumerate(self.steady_gains):
                out[f"F_{i}"] = np.asarray(F, dtype=float)
        for i in range(self.structure.n_agents):
            out[f"local_{i}"] = np.asarray(self.structure.local_lags(i), dtype=np.int64).reshape(-1, 2)
        return out


def _as_structure(structure: Any, n_agents: int) -> InformationStructure:
    if isinstance(structure, InformationStructure):
        st = structure
    elif hasattr(structure, "geodesic_delays"):
        st = InformationStructure.from_graph(structure)
    else:
        raise InformationStructureError(
            f"structure: expected an InformationStructure or a CommGraph, found {type(structure).__name__}", argument="structure"
        )
    if st.n_agents != n_agents:
        raise InformationStructureError(f"structure: expected {n_agents} agents (as the system), found {st.n_agents}", argument="structure")
    return st


def _design(
    kind: Kind,
    system: LinearGaussianSystem,
    cost: TeamCost,
    structure: Any,
    horizon: int | None,
    method: Any,
    dense_max_bytes: int,
    check: bool,
    progress: bool | None = None,
) -> TeamDesign:
    check_model(system, cost)
    st = _as_structure(structure, system.n_agents)
    c, dz, n = st.common_lag, cost.dz, system.n_agents
    want = "mtmse" if kind == "mtmse" else "mmse"
    info: dict[str, Any] = {"common_lag": c, "local_dims": st.local_dims(system.dy)}

    def step(k: int, a: int, P_a: FloatArray, record: bool = True) -> tuple[tuple, float]:
        idx = [_local_index(system, st, i, k, a) for i in range(n)]
        ginfo: dict[str, Any] = {}
        w, dy, S = k - a + 1, system.dy_total, cost.S_at(k)
        if want == "mtmse" and choose_solver(S, idx, dz, w * dy, method, dense_max_bytes) == "cg" and innovations_pays(S, idx, dz, system.dx, dy, w):
            F, J, ginfo = _solve_step_innovations(system, cost, k, a, P_a, idx, dz)  # no window-sized matrix
            Jm = float("nan")
        else:
            Sigma_W, Theta_W, P0 = window_covariances(system, k, a, P_a)
            F, J, Jm = _solve_step(
                cost.S_at(k), cost.L_at(k), Sigma_W, Theta_W, P0, idx, dz, method=method, dense_max_bytes=dense_max_bytes, want=want, gamma_info=ginfo
            )
        if ginfo and record:
            info["gamma"] = ginfo  # the last (largest) step
        return tuple(F), (J if kind == "mtmse" else Jm)

    if horizon is None:
        system.require_time_invariant()
        cost.require_time_invariant()
        P_bar, K_bar, _ = steady_state(system, check=check)
        F_bar, J_bar = step(c - 1, 0, P_bar)  # full window of length c, anchor covariance P-bar (eqs. 38-40)
        return TeamDesign(
            estimator=kind,
            horizon=None,
            average_cost=J_bar,
            info=info,
            system=system,
            cost=cost,
            structure=st,
            steady_gains=F_bar,
            K=K_bar,
            P_pred=P_bar,
            warmup=lambda k: step(k, 0, system.Sigma_x, record=False)[0],
        )
    T = V.positive_int(horizon, "horizon")
    system.require_horizon(T)
    cost.require_horizon(T)
    from .._resources import check_memory
    from .._resources import progress as _progress

    dx, dy = system.dx, system.dy_total
    held = min(sum(info["local_dims"]), n * T * dy)  # a local vector never holds more than the T steps measured so far
    per_step = 8.0 * (3 * dx * dx + dx * dy + dz * held) + 120.0 * (n + 4)  # arrays + object headers
    check_memory(
        T * per_step,
        f"the {kind.upper()} design over T = {T} steps (gains and covariances of every step are kept)",
        argument="horizon",
        fix="use a shorter horizon, or horizon = none for the steady-state design",
    )
    P_pred, K, _ = kalman_covariances(system, max(T - c + 1, 1))
    res = [step(k, max(0, k - c + 1), P_pred[max(0, k - c + 1)]) for k in _progress(range(T), total=T, desc=f"{kind} design", enabled=progress)]
    return TeamDesign(
        estimator=kind,
        horizon=T,
        stage_costs=np.array([j for _, j in res]),
        info=info,
        system=system,
        cost=cost,
        structure=st,
        gains=tuple(g for g, _ in res),
        K=K,
        P_pred=P_pred,
    )


def design_mtmse(
    system: LinearGaussianSystem,
    cost: TeamCost,
    structure: Any,
    horizon: int | None = None,
    *,
    method: Literal["auto", "dense", "cg"] = "auto",
    dense_max_bytes: int = DENSE_MAX_BYTES,
    check: bool = True,
    progress: bool | None = None,
) -> TeamDesign:
    """MTMSE filter for any information structure: Theorem 2 (``horizon=T``) or Theorem 3 (``horizon=None``).

    Parameters
    ----------
    system : LinearGaussianSystem
        The process x(k+1) = A x(k) + w(k) and the agents' measurements y_i(k) = C_i x(k) + v_i(k).
    cost : TeamCost
        The team cost c(x, ẑ) = (L x - ẑ)ᵀ S (L x - ẑ) (``None``: the sum of the agents' MSEs).
    structure : InformationStructure or CommGraph
        A graph means its full information structure (eq. 14).
    horizon : int or None
        T steps (finite horizon, exact gains F_i(k) and stage costs), or None
        for the time-homogeneous strategy minimizing the average cost (needs
        (A4)-(A5), checked when ``check``).
    method : "auto", "dense" or "cg"
        How Gamma F = eta is solved (see :mod:`teamkf.estimators.gamma`).
    dense_max_bytes : int
        The largest dense Γ (in bytes) that ``method="auto"`` solves directly; larger ones use CG.
    check : bool
        Check the structure on the graph and, for the steady state, assumptions (A4)-(A5).
    progress : bool or None
        A progress bar on stderr once a finite-horizon design has run 2 s
        (None: only when stderr is a terminal; False: never).

    Returns
    -------
    TeamDesign
        The gains F_i(k) (or F-bar_i) with the exact stage costs (or average cost).

    Raises
    ------
    teamkf.exceptions.ArgumentError
        (``horizon``) when the gains of every step would not fit in the
        memory available (checked before the work, with the estimate).

    Examples
    --------
    >>> from teamkf import LinearGaussianSystem, TeamCost, CommGraph, design_mtmse, design_mmse
    >>> sys = LinearGaussianSystem.platoon(4)
    >>> cost = TeamCost.platoon(4, lam=10.0)
    >>> g = CommGraph.line(4)
    >>> d = design_mtmse(sys, cost, g, horizon=20)
    >>> d.total_cost <= design_mmse(sys, cost, g, horizon=20).total_cost
    True
    """
    return _design("mtmse", system, cost, structure, horizon, method, dense_max_bytes, check, progress)


def design_mmse(
    system: LinearGaussianSystem, cost: TeamCost, structure: Any, horizon: int | None = None, *, check: bool = True, progress: bool | None = None
) -> TeamDesign:
    """Per-agent MMSE baseline z_i = L_i E[x(k) | I_i(k)] (eq. 46) with its team cost (eq. 47).

    Each agent estimates optimally for itself, blind to the team coupling of the
    cost; the gap to :func:`design_mtmse` is what team-optimality buys.

    Parameters
    ----------
    system : LinearGaussianSystem
        The process x(k+1) = A x(k) + w(k) and the agents' measurements y_i(k) = C_i x(k) + v_i(k).
    cost : TeamCost
        The team cost c(x, ẑ) = (L x - ẑ)ᵀ S (L x - ẑ) (``None``: the sum of the agents' MSEs).
    structure : InformationStructure or CommGraph
        A graph means its full information structure (eq. 14).
    horizon : int or None
        T steps, or None for the steady state.
    check : bool
        As in :func:`design_mtmse`.
    progress : bool or None
        As in :func:`design_mtmse` (the memory check too).

    Returns
    -------
    TeamDesign
        The gains and the exact team cost (eq. 47).

    Examples
    --------
    >>> from teamkf import LinearGaussianSystem, TeamCost, CommGraph, design_mmse
    >>> d = design_mmse(LinearGaussianSystem.platoon(4), TeamCost.platoon(4, 100.0), CommGraph.line(4, delay=1), horizon=20)
    >>> d.estimator, d.stage_costs.shape
    ('mmse', (20,))
    """
    return _design("mmse", system, cost, structure, horizon, "auto", DENSE_MAX_BYTES, check, progress)


class TeamAgent:
    """Agent i running an MTMSE/MMSE design online.

    It keeps only the delayed common estimate x^(anchor) (the centralized
    predictor on the common part, eq. 20) and the measurements of its window
    that it has received; everything older is dropped once it is folded into
    x^(anchor).
    """

    def __init__(self, design: TeamDesign, index: int, *, tolerant: bool = False):
        self.design = design
        self.index = index
        self.system: LinearGaussianSystem = design.system
        self.structure: InformationStructure = design.structure
        #: on unreliable links (teamkf.simulation.links): a measurement that has not arrived when it is
        #: needed is replaced by its conditional expectation given everything the agent holds (its common
        #: estimate and the window measurements it received, :meth:`expected_measurements`) instead of
        #: raising; the state counts the misses
        self.tolerant = tolerant
        self._fill_gains: dict[tuple, tuple[np.ndarray, np.ndarray, FloatArray]] = {}

    def arrival_lag(self, j: int) -> int:
        return self.structure.arrival_lag(self.index, j)

    def init_state(self, n_runs: int) -> dict[str, Any]:
        return {"xhat": np.zeros((n_runs, self.system.dx)), "anchor": 0, "buf": {}}

    def restart_state(self, n_runs: int, k: int) -> dict[str, Any]:
        """A fresh agent at step ``k`` (a restarted process, ``teamkf agent --rejoin``), from the design's prior.

        Its common estimate restarts at the prior mean of x(a), a = max(0, k - common_lag + 1) (zero: known
        means are removed from y and added back to ẑ), with nothing held; the loss-tolerant step then fills
        every window measurement it never received by its conditional expectation (:meth:`expected_measurements`)
        and folds each newly common y(a) into the predictor as it arrives. The predictor's extra error from
        the restart is propagated by A - K C (stable for a detectable system) and so decays; until it has,
        the agent's estimates are those of a team member that missed everything before k, not the team
        optimum's.
        """
        a = max(0, int(k) - self.structure.common_lag + 1)
        return {"xhat": np.zeros((n_runs, self.system.dx)), "anchor": a, "buf": {}, "missed_keys": set(), "missed": 0}

    def step(self, state: dict[str, Any], k: int, received: Sequence[Packet]) -> tuple[dict[str, Any], FloatArray]:
        sys, c, d = self.system, self.structure.common_lag, self.design
        buf = dict(state["buf"])
        for j, s, v in received:
            buf[(j, s)] = np.asarray(v)
        xhat, a = state["xhat"], state["anchor"]
        missed = set(state.get("missed_keys", ()))
        while a < k - c + 1:  # fold the newly common y(a) into the predictor (eq. 20)
            try:
                y = np.concatenate([buf[(j, a)] for j in range(sys.n_agents)], axis=1)
            except KeyError as exc:
                if not self.tolerant:
                    raise InformationStructureError(
                        f"agent {self.index}: y_{exc.args[0][0]}({a}) is common at step {k} but was never delivered"
                    ) from None
                lost = [(j, a) for j in range(sys.n_agents) if (j, a) not in buf]
                fill = self.expected_measurements(xhat, a, k, buf, lost)
                y = np.concatenate([buf.get((j, a), fill.get((j, a))) for j in range(sys.n_agents)], axis=1)
                missed |= set(lost)
            xhat = (xhat + (y - xhat @ sys.C_stack(a).T) @ d.K_at(a).T) @ sys.A_at(a).T
            a += 1
            buf = {key: v for key, v in buf.items() if key[1] >= a}
        # predictions x^(s) = Phi(s, a) x^(a) over the window, local innovation (eqs. 28-29)
        preds = [xhat]
        for s in range(a, k):
            preds.append(preds[-1] @ sys.A_at(s).T)
        pairs = self.structure.local_pairs(self.index, k)
        z = preds[-1] @ d.cost.L_block(self.index, k).T
        if pairs:
            try:
                innov = np.concatenate([buf[(j, s)] - preds[s - a] @ sys.C_at(j, s).T for (j, s) in pairs], axis=1)
            except KeyError as exc:
                if not self.tolerant:
                    raise InformationStructureError(
                        f"agent {self.index}: local measurement y_{exc.args[0][0]}({exc.args[0][1]}) was not delivered by step {k}"
                    ) from None
                lost = [(j, s) for (j, s) in pairs if (j, s) not in buf]
                fill = self.expected_measurements(xhat, a, k, buf, lost)
                innov = np.concatenate([buf.get((j, s), fill.get((j, s))) - preds[s - a] @ sys.C_at(j, s).T for (j, s) in pairs], axis=1)
                missed |= set(lost)
            z = z + innov @ d.gain_at(k)[self.index].T
        out = {"xhat": xhat, "anchor": a, "buf": buf}
        if self.tolerant:
            out["missed_keys"] = missed
            out["missed"] = len(missed)
        return out, z

    def expected_measurements(
        self, xhat: FloatArray, a: int, k: int, buf: dict[tuple[int, int], FloatArray], wanted: Sequence[tuple[int, int]]
    ) -> dict[tuple[int, int], FloatArray]:
        r"""E[y_j(s) | what the agent holds] for the measurements in ``wanted`` that never arrived.

        The agent holds its common estimate x̂(a) (the centralized predictor, error covariance P(a))
        and the window measurements y_h(s'), a <= s' <= k, that it received (``buf``). Given x̂(a), the
        window innovations ỹ(s) = y(s) - C(s) Φ(s, a) x̂(a) are jointly Gaussian with covariance
        Σ_W (:func:`window_covariances`), so with h the held and m the wanted positions

        .. math::  E[y_m | x̂(a), y_h] = C_m Φ x̂(a) + Σ_W[m, h] Σ_W[h, h]^{-1} ỹ_h.

        Exact when x̂(a) is the centralized predictor, i.e. when every measurement folded into it
        arrived; after an earlier miss P(a) understates its error (the substitute is then the
        expectation under the nominal covariance). The gain is cached per (a, k, held, wanted).
        """
        sys = self.system
        wanted = [(j, s) for (j, s) in wanted if a <= s <= k]
        if not wanted:
            return {}
        held = tuple(sorted(key for key in buf if a <= key[1] <= k))
        key = (a, k, held, tuple(wanted))
        if key not in self._fill_gains:
            h, m = _window_positions(sys, a, held), _window_positions(sys, a, wanted)
            if h.size:
                P_a = sys.Sigma_x if a == 0 else (self.design.P_pred if self.design.horizon is None else self.design.P_pred[a])
                Sigma_W, _, _ = window_covariances(sys, k, a, P_a)
                cf = sla.cho_factor(Sigma_W[np.ix_(h, h)], lower=True, check_finite=False)
                G = sla.cho_solve(cf, Sigma_W[np.ix_(h, m)], check_finite=False).T  # Σ_mh Σ_hh^-1
            else:
                G = np.zeros((m.size, 0))
            if len(self._fill_gains) > 4096:  # bounded: the patterns of lossy runs repeat, but need not
                self._fill_gains.clear()
            self._fill_gains[key] = (h, m, G)
        _, _, G = self._fill_gains[key]
        preds = {s: xhat @ sys.transition(s, a).T for s in {s for (_, s) in (*held, *wanted)}}
        innov_h = [buf[(j, s)] - preds[s] @ sys.C_at(j, s).T for (j, s) in held]
        innov_m = np.concatenate(innov_h, axis=1) @ G.T if held else np.zeros((xhat.shape[0], G.shape[0]))
        out, col = {}, 0
        for j, s in wanted:
            d = sys.dy[j]
            out[(j, s)] = preds[s] @ sys.C_at(j, s).T + innov_m[:, col : col + d]
            col += d
        return out


FAMILY_MTMSE = _register_builtin(
    Family(
        name="mtmse",
        design=design_mtmse,
        title="minimum team MSE filter (Afshari & Mahajan 2021, Thms 2-3): the exact team optimum for the information structure",
        uses="structure",
        options=(
            Option(
                name="method",
                default="auto",
                check=lambda v, k: V.choice(v, k, ("auto", "dense", "cg")),
                doc="how Gamma F = eta is solved: dense Cholesky, matrix-free CG, or chosen by size",
            ),
        ),
        lossy_links=True,
        missing_data=True,
        steady_form=True,  # capabilities (registry.Family)
        example="design_mtmse(system, cost, graph, horizon=100)",
    )
)
FAMILY_MMSE = _register_builtin(
    Family(
        name="mmse",
        design=design_mmse,
        title="per-agent MMSE (eq. 46): each agent's best estimate for itself, blind to the team coupling (cost eq. 47)",
        uses="structure",
        lossy_links=True,
        missing_data=True,
        steady_form=True,  # capabilities (registry.Family)
        example="design_mmse(system, cost, graph, horizon=100)",
    )
)


class _TeamSlice:
    """What a :class:`TeamAgent` reads of its design, for one agent rebuilt from its slice."""

    def __init__(self, view: Any, i: int, arrays: dict[str, np.ndarray], meta: dict[str, Any]):
        from ._slices import AgentRows

        self.view, self.index = view, i
        self.K, self.P_pred = arrays["K"], arrays["P_pred"]
        n_f = sum(1 for name in arrays if name.startswith("F/"))
        self._F = [AgentRows(i, arrays[f"F/{k}"]) for k in range(n_f)]
        self._steady = AgentRows(i, arrays["F_steady"]) if "F_steady" in arrays else None

    def __getattr__(self, name: str) -> Any:
        return getattr(self.view, name)

    def gain_at(self, k: int) -> Any:
        if self.view.horizon is None and k >= self.view.structure.common_lag:
            return self._steady
        return self._F[k]

    def K_at(self, m: int) -> FloatArray:
        return self.K if self.view.horizon is None else self.K[m]  # type: ignore[no-any-return]


def team_agent_from_slice(ctx: Any, i: int, arrays: dict[str, np.ndarray], meta: dict[str, Any]) -> tuple[Any, Any]:
    """Agent i of an MTMSE / MMSE design rebuilt from its slice (:meth:`TeamDesign.agent_slice`): a measurement relay around it."""
    from ._slices import SliceDesign
    from .base import MeasurementRelay

    c = int(meta["common_lag"])
    if ctx.structure.common_lag != c:
        raise InformationStructureError(
            f"agent {i}'s slice was designed for common lag {c}, the scenario's information structure has {ctx.structure.common_lag}"
        )
    view = SliceDesign(str(meta["estimator"]), ctx.horizon, ctx.system, ctx.cost, None, ctx.structure, info={"variant": meta.get("variant")})
    return view, MeasurementRelay(TeamAgent(_TeamSlice(view, i, arrays, meta), i))  # type: ignore[arg-type]
