r"""Consensus and diffusion code that several baseline families share.

The families ``local``, ``diffusion``, ``ci``, ``icf`` and ``hcmci`` (and the
KCF's honest variant) all exchange over a delay graph in one of two variants
(:data:`VARIANTS`), design over a finite horizon (:func:`finite_horizon`) and
fuse the in-neighbours' data that has arrived (:func:`information_sources`:
agent i uses y_l(s) at step k with s = k - τ_li once it has arrived, or s = k
in the ideal variant). :class:`DiffusionAlgorithm` is the ATC diffusion
Kalman filter of Cattivelli & Sayed (2010) in information form,

.. math::

    P_k(t|t) = (P_k(t|t-1)^{-1} + S_k)^{-1}, \quad
    \psi_k = \hat x_k(t|t-1) + P_k(t|t)\,(q_k - S_k \hat x_k(t|t-1)), \quad
    \hat x_k(t|t) = \sum_{l\in N_k} c_{lk}\, \psi_l ,

which ``diffusion`` runs and ``local`` (no communication) and ``ci``
(covariance-intersection fusion) specialize; the equations, the variants and
the lossy-link rules are documented in :mod:`teamkf.estimators.diffusion`.

Family modules import these from here, never from each other (the import-linter
independence contract in ``pyproject.toml``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .. import _validation as V
from .._lazy import scipy_linalg as sla  # SciPy loads on first use
from .._linalg import block_diag
from .._validation import FloatArray
from ..exceptions import ArgumentError, NotPositiveDefiniteError
from ..models import LinearGaussianSystem, TeamCost
from ..network.graph import CommGraph
from ._kalman_common import kalman_step
from .linear_team import Algorithm, delivered, freshest, process_noise, shared_schedules

__all__ = [
    "VARIANTS",
    "check_variant",
    "check_weights",
    "check_iterations",
    "diffusion_weights",
    "information_sources",
    "finite_horizon",
    "DiffusionAlgorithm",
]


VARIANTS: dict[str, str] = {
    "honest": "one exchange per step over the graph's edges and delays, delay-compensated (realizable, runs in run_graph)",
    "ideal": "the published algorithm: neighbours' data of the same step (exchanges inside the step; not realizable with delays)",
}


def check_variant(v: Any, key: str) -> str:
    """The ``variant`` option: "ideal" (exchanges within the step) or "honest" (one delay-compensated exchange per step)."""
    return V.choice(v, key, tuple(VARIANTS))


#: combination rules of the diffusion step (module docstring)
COMBINATIONS: dict[str, str] = {
    "weights": "the published scalar combination with the weights c_lk (age-blind)",
    "age": "age-aware scalar weights c_lk / tr(P~_l) (P~_l: the received estimate's covariance after its age), normalized",
    "matrix": "information-matrix weights (sum c_lk P~_l^-1)^-1 c_lk P~_l^-1",
    "ci": "covariance intersection of the received estimates (trace-minimizing), prediction from the CI covariance",
}


def check_combination(v: Any, key: str) -> str:
    """The ``combination`` option: "weights" (published), "age", "matrix" or "ci" (module docstring)."""
    return V.choice(v, key, tuple(COMBINATIONS), what="a combination rule, one of")


def check_lazy(v: Any, key: str) -> float:
    """The ``lazy`` option α in (0, 1]: x̂ = (1 - α) ψ_k + α x̂^comb (1: no laziness)."""
    a = V.real(v, key, minimum=0.0, strict=True, what="a lazy-update factor")
    if a > 1.0:
        raise ArgumentError(
            f"{key}: expected a lazy-update factor 0 < alpha <= 1 (1: the combination itself), found {a:g}; give a value in (0, 1]", argument=key
        )
    return float(a)


#: how the gains are designed (module docstring)
GAINS: dict[str, str] = {
    "nominal": "the published gains from the nominal covariances P_k (which ignore the correlations of delayed data)",
    "exact": "the adaptation gain (linear MMSE) and the combination rule from the exact error covariances of the joint recursion",
}


def check_gains(v: Any, key: str) -> str:
    """The ``gains`` option: "nominal" (published) or "exact" (module docstring)."""
    return V.choice(v, key, tuple(GAINS), what="a gain design, one of")


def check_weights(w: Any, key: str) -> Any:
    """``"metropolis"``, ``"uniform"`` or an explicit non-negative column-stochastic square matrix."""
    if isinstance(w, str):
        return V.choice(w, key, ("metropolis", "uniform"), what="a weight rule")
    try:
        c = np.asarray(w, dtype=float)
    except (TypeError, ValueError):
        raise ArgumentError(f"{key}: expected 'metropolis', 'uniform' or a square matrix of weights, found {V.describe(w)}", argument=key) from None
    if c.ndim != 2 or c.shape[0] != c.shape[1] or c.size == 0:
        raise ArgumentError(f"{key}: expected a square n×n matrix of weights c[l, k], found shape {c.shape}", argument=key)
    if not np.all(np.isfinite(c)):
        raise ArgumentError(f"{key}: expected finite weights, found {c[~np.isfinite(c)][0]!r}", argument=key)
    if np.any(c < 0):
        l, k = np.argwhere(c < 0)[0]
        raise ArgumentError(f"{key}: expected non-negative weights, found c[{l}, {k}] = {c[l, k]:g}", argument=key)
    sums = c.sum(axis=0)
    if not np.allclose(sums, 1.0, atol=1e-9):
        k = int(np.argmax(np.abs(sums - 1.0)))
        raise ArgumentError(
            f"{key}: expected a column-stochastic matrix (every column c[:, k] sums to 1: agent k's combination weights), "
            f"found column {k} summing to {sums[k]:.6g}",
            argument=key,
        )
    return c


def diffusion_weights(graph: CommGraph, weights: Any = "metropolis", key: str = "weights") -> FloatArray:
    """The combination matrix C = [c_lk] (column k: agent k's weights over N_k = {k} ∪ in-neighbours)."""
    n = graph.n_agents
    w = check_weights(weights, key)
    N = [set(graph.in_neighbors(k)) | {k} for k in range(n)]
    if isinstance(w, str):
        c = np.zeros((n, n))
        for k in range(n):
            nk = len(N[k])
            for lnode in N[k] - {k}:
                c[lnode, k] = 1.0 / nk if w == "uniform" else 1.0 / max(nk, len(N[lnode]))
            c[k, k] = 1.0 - c[:, k].sum()
        return c
    if w.shape != (n, n):
        raise ArgumentError(f"{key}: expected a {n}×{n} matrix (one row and column per agent), found shape {w.shape}", argument=key)
    for lnode, k in np.argwhere(w > 0):
        if lnode != k and lnode not in N[k]:
            raise ArgumentError(
                f"{key}: expected weights only on the graph's edges l -> k and the diagonal, found c[{lnode}, {k}] = {w[lnode, k]:g} "
                f"but agent {lnode} is not an in-neighbour of agent {k}",
                argument=key,
            )
    return np.array(w, dtype=float)


def _information(P: FloatArray, rule: str, agent: int, s: int, k: int) -> FloatArray:
    """P⁻¹ for the information-weighted combination rules; a typed error naming the option when P is singular."""
    lam = np.linalg.eigvalsh(0.5 * (P + P.T))
    if lam[0] <= 1e-12 * max(1.0, float(lam[-1])):
        raise NotPositiveDefiniteError(
            f"diffusion.combination: the {rule!r} rule weighs by P^-1, but agent {agent}'s covariance from step {s}, used at step {k}, "
            f"is singular (smallest eigenvalue {lam[0]:.3g}); give Sigma_x and Q positive definite, or use combination='weights' or 'age'",
            argument="diffusion.combination",
        )
    return np.asarray(np.linalg.inv(P), dtype=float)


def _solve_psd(S: FloatArray, B: FloatArray) -> FloatArray:
    """S⁻¹ B for a symmetric positive (semi-)definite S: Cholesky, or least squares when S is singular."""
    try:
        return np.asarray(sla.cho_solve(sla.cho_factor(S, lower=True, check_finite=False), B, check_finite=False))
    except np.linalg.LinAlgError:
        return np.asarray(np.linalg.lstsq(S, B, rcond=1e-12)[0])


def information_sources(graph: CommGraph | None, T: int, honest: bool) -> list[list[list[tuple[int, int]]]]:
    """src[i][k]: (l, s) of the in-neighbours' data agent i uses at step k: s = k - τ_li (honest, once arrived) or s = k (ideal)."""
    if graph is None:
        return []
    out = []
    for i in range(graph.n_agents):
        ins = [(j, graph.delay(j, i)) for j in graph.in_neighbors(i)]
        if honest:
            out.append([[(j, k - d) for (j, d) in ins if k - d >= 0] for k in range(T)])
        else:
            out.append([[(j, k) for (j, _) in ins] for k in range(T)])
    return out


def _nominal(alg: "DiffusionAlgorithm") -> tuple[dict[tuple[int, int, int, int], tuple[FloatArray, FloatArray]], FloatArray, FloatArray]:
    """The nominal adaptation of every agent (combination not "ci"): gains (G̃, Y) of each fused y_l(s), P_i(k|k), P_i(k).

    P_i(k|k) = (P_i(k)⁻¹ + Σ Y)⁻¹ over y_i(k) and the delay-compensated y_l(s) agent i fuses (Joseph form),
    P_i(k+1) = A P_i(k|k) Aᵀ + Q. They depend on the model, the sources and T only, so the designs of one
    tuning grid share them: stored on ``system`` (read-only arrays, the last few source patterns).
    """
    system, T, n, dx = alg.system, alg.horizon, alg.system.n_agents, alg.system.dx
    gain: dict[tuple[int, int, int, int], tuple[FloatArray, FloatArray]] = {}
    P_filt = np.empty((n, T, dx, dx))
    P_pred = np.empty((n, T, dx, dx))
    P = [system.Sigma_x for _ in range(n)]
    for k in range(T):
        for i in range(n):
            P_pred[i, k] = P[i]
            Cs, Rs = [], []
            for lnode, s in [(i, k), *alg.src[i][k]]:
                Ct, Rt, G, Y = alg.compensated(lnode, s, k)
                gain[(i, k, lnode, s)] = (G, Y)
                Cs.append(Ct)
                Rs.append(Rt)
            _, P_filt[i, k] = kalman_step(P[i], np.vstack(Cs), block_diag(*Rs))  # (P^-1 + S)^-1, Joseph form
            if k + 1 < T:
                A = system.A_at(k)
                Pn = A @ P_filt[i, k] @ A.T + system.Q_at(k)
                P[i] = 0.5 * (Pn + Pn.T)
    P_filt.setflags(write=False)
    P_pred.setflags(write=False)
    return gain, P_filt, P_pred


class DiffusionAlgorithm(Algorithm):
    """The ATC diffusion KF on columns; nominal covariances and compensated gains precomputed."""

    state_kinds = {"xhat": "x"}
    payload_kinds = {"y": "y", "psi": "x"}

    @property
    def info_graph(self) -> CommGraph | None:
        """The graph whose in-neighbours' data is fused (None: no communication)."""
        return self.graph

    def __init__(
        self,
        system: LinearGaussianSystem,
        cost: TeamCost,
        graph: CommGraph | None,
        horizon: int,
        c: FloatArray,
        honest: bool,
        combination: str = "weights",
        lazy: float = 1.0,
        gains: str = "nominal",
    ):
        super().__init__(system, cost, graph, horizon)
        self.honest, self.c = honest, c
        self.combination, self.lazy = combination, float(lazy)
        #: exact gains: the adaptation gain and the combination from the exact error covariances (module docstring)
        self.exact_gains = gains == "exact"
        self._errcov: Any = None
        self.xgain: dict[tuple[int, int], FloatArray] = {}
        self.xcomb: dict[tuple[int, int], list[FloatArray]] = {}
        n, dx, T = system.n_agents, system.dx, horizon
        self.src = information_sources(self.info_graph, T, honest) or [[[] for _ in range(T)] for _ in range(n)]
        self.nbrs = [set(graph.in_neighbors(i)) if graph is not None and self.info_graph is not None else set() for i in range(n)]
        #: (i, k) -> [(l, s, W)]: x̂_i = Σ W ψ_l(s) (W includes Φ(k, s)); only for the non-published rules
        self.comb: dict[tuple[int, int], list[tuple[int, int, FloatArray]]] = {}
        #: (i,k,l,s) -> (G̃ = C̃'R̃^-1, Y = G̃ C̃)
        self.gain: dict[tuple[int, int, int, int], tuple[FloatArray, FloatArray]] = {}
        if self.combination != "ci":  # the nominal covariances do not depend on the combination: shared by the designs on this system
            self.gain, self.P_filt, self.P_pred = shared_schedules(self, "_teamkf_nominal", lambda: _nominal(self))
            if not self._published and not self.exact_gains:
                for k in range(T):
                    for i in range(n):
                        items = [(i, k, self.P_filt[i, k]), *[(lnode, s, self.P_filt[lnode, s]) for lnode, s in self.src[i][k]]]
                        self.comb[(i, k)], _ = self.combination_gains(i, k, items)
            self.schedules = {"P_filt": self.P_filt, "P_pred": self.P_pred, "weights": c}
            return
        self.P_filt = np.empty((n, T, dx, dx))
        self.P_pred = np.empty((n, T, dx, dx))
        P = [system.Sigma_x for _ in range(n)]
        for k in range(T):
            for i in range(n):
                self.P_pred[i, k] = P[i]
                Cs, Rs = [], []
                for lnode, s in [(i, k), *self.src[i][k]]:
                    Ct, Rt, G, Y = self.compensated(lnode, s, k)
                    self.gain[(i, k, lnode, s)] = (G, Y)
                    Cs.append(Ct)
                    Rs.append(Rt)
                _, Pf = kalman_step(P[i], np.vstack(Cs), block_diag(*Rs))  # (P^-1 + S)^-1, Joseph form
                self.P_filt[i, k] = Pf
            for i in range(n):
                Pnext = self.P_filt[i, k]
                if not self._published and not self.exact_gains:
                    items = [(i, k, self.P_filt[i, k]), *[(lnode, s, self.P_filt[lnode, s]) for lnode, s in self.src[i][k]]]
                    self.comb[(i, k)], Pc = self.combination_gains(i, k, items)
                    if self.combination == "ci":
                        Pnext = Pc
                if k + 1 < T:
                    A = system.A_at(k)
                    Pn = A @ Pnext @ A.T + system.Q_at(k)
                    P[i] = 0.5 * (Pn + Pn.T)
        self.schedules = {"P_filt": self.P_filt, "P_pred": self.P_pred, "weights": c}

    @property
    def _published(self) -> bool:
        """The published scalar combination without laziness (its arithmetic is kept exactly as before)."""
        return self.combination == "weights" and self.lazy == 1.0

    def combination_gains(self, i: int, k: int, items: list[tuple[int, int, FloatArray]]) -> tuple[list[tuple[int, int, FloatArray]], FloatArray]:
        """The combination x̂_i = Σ W_l ψ_l(s) over ``items`` = [(l, s, P_l(s|s))] (own first), and the covariance for the prediction.

        W_l includes the propagation Φ(k, s) and the lazy mix; the covariance is P_i(k|k) except for the
        CI rule (its P_f). The rules are those of the module docstring.
        """
        dx = self.system.dx
        heard = {lnode for lnode, _, _ in items[1:]}
        Pt = []
        for _lnode, s, Pl in items:
            if s == k:
                Pt.append(Pl)
            else:
                Phi = self.Phi(k, s)
                M = Phi @ Pl @ Phi.T + process_noise(self.system, k, s)
                Pt.append(0.5 * (M + M.T))
        # scalar weights over the items: c_li, the weight of neighbours not heard going to the agent itself
        cw = np.array([self.c[i, i] + sum(self.c[lnode, i] for lnode in self.nbrs[i] - heard)] + [self.c[lnode, i] for lnode, _, _ in items[1:]])
        Pc = items[0][2]
        if self.combination == "weights":
            mats = [w * np.eye(dx) for w in cw]
        elif self.combination == "age":
            a = cw / np.array([np.trace(M) for M in Pt])
            a = a / a.sum()
            mats = [w * np.eye(dx) for w in a]
        else:
            infos = [_information(M, self.combination, lnode, s, k) for M, (lnode, s, _) in zip(Pt, items)]
            if self.combination == "matrix":
                omega = cw
            else:
                omega = ci_weights(infos)
            Pf = np.linalg.inv(sum(w * Y for w, Y in zip(omega, infos)))
            Pf = 0.5 * (Pf + Pf.T)
            mats = [w * Pf @ Y for w, Y in zip(omega, infos)]
            if self.combination == "ci":
                Pc = Pf
        al = self.lazy
        out = []
        for a_idx, ((lnode, s, _), W) in enumerate(zip(items, mats)):
            W = al * W + ((1.0 - al) * np.eye(dx) if a_idx == 0 else 0.0)
            if s != k:
                W = W @ self.Phi(k, s)
            out.append((lnode, s, W))
        return out, Pc

    def _prior(self, i: int, k: int, prev: dict | None, zero: Any) -> Any:
        return zero(self.system.dx) if prev is None else self.system.A_at(k - 1) @ prev["xhat"]

    def adapt(self, i: int, k: int, xbar: Any, ys: dict[tuple[int, int], Any]) -> Any:
        """ψ_i = x̄ + P(t|t)(q - S x̄), q = Σ G̃_l y_l(s), S = Σ Y_l over {i} ∪ sources (exact gains: x̄ + K (ỹ - C̃ x̄))."""
        if self.exact_gains:
            return self._adapt_exact(i, k, xbar, ys)
        r = None
        for lnode, s in [(i, k), *self.src[i][k]]:
            G, Y = self.gain[(i, k, lnode, s)]
            term = G @ ys[(lnode, s)] - Y @ xbar
            r = term if r is None else r + term
        return xbar + self.P_filt[i, k] @ r

    def _adapt_exact(self, i: int, k: int, xbar: Any, ys: dict[tuple[int, int], Any]) -> Any:
        r"""Exact-gain adaptation: the linear MMSE update of the prior with the measurements it holds.

        With e the prior's error x(k) - x̄ and e_y = C̃ x(k) - ỹ the errors of the stacked (delay-compensated)
        measurements, the innovation is ν = ỹ - C̃ x̄ = C̃ e - e_y and

        .. math:: K = \operatorname{Cov}(e, \nu)\,\operatorname{Cov}(\nu)^{-1}, \qquad \psi = \bar x + K \nu,

        with the covariances the exact ones of the joint error recursion (:mod:`.linear_team`), which include the
        correlation between the compensation noise and the prior error that the published gain ignores.
        """
        keys = [(i, k), *self.src[i][k]]
        Ct = [self.compensated(lnode, s, k)[0] for lnode, s in keys]
        Cs = np.vstack(Ct)
        y = ys[keys[0]] if len(keys) == 1 else np.vstack([ys[key] for key in keys])
        if self._errcov is not None:
            dx = self.system.dx
            S = self._errcov([(xbar, np.eye(dx)), *[(ys[key], C) for key, C in zip(keys, Ct)]])
            Sxx, Sxy, Syy = S[:dx, :dx], S[:dx, dx:], S[dx:, dx:]
            cov_en = Sxx @ Cs.T - Sxy
            cov_nn = Cs @ Sxx @ Cs.T - Cs @ Sxy - Sxy.T @ Cs.T + Syy
            self.xgain[(i, k)] = _solve_psd(0.5 * (cov_nn + cov_nn.T), cov_en.T).T
        return xbar + self.xgain[(i, k)] @ (y - Cs @ xbar)

    def _combine_exact(self, i: int, k: int, psi_i: Any, psis: dict[tuple[int, int], Any]) -> Any:
        """Exact-gain combination: the rule applied with the exact error covariances of the items (BLUE for "matrix")."""
        dx = self.system.dx
        used = self.src[i][k]
        items = [psi_i, *[self.Phi(k, s) @ psis[(lnode, s)] for lnode, s in used]]
        if self._errcov is not None:
            m = len(items)
            S = self._errcov([(q, np.eye(dx)) for q in items])
            # a relative 1e-12 ridge: a singular Σ (a noise-free direction) keeps a unique, unbiased (Σ W = I) combination
            S = S + 1e-12 * max(float(np.trace(S)) / len(S), 1e-300) * np.eye(len(S))
            blocks = [S[a * dx : (a + 1) * dx, a * dx : (a + 1) * dx] for a in range(m)]
            heard = {lnode for lnode, _ in used}
            cw = np.array([self.c[i, i] + sum(self.c[lnode, i] for lnode in self.nbrs[i] - heard)] + [self.c[lnode, i] for lnode, _ in used])
            if self.combination == "weights":
                Ws = [w * np.eye(dx) for w in cw]
            elif self.combination == "age":
                a = cw / np.array([np.trace(B) for B in blocks])
                Ws = [w * np.eye(dx) for w in a / a.sum()]
            elif self.combination == "matrix":  # best linear unbiased combination: W = (J' S^-1 J)^-1 J' S^-1, J = 1 ⊗ I
                J = np.tile(np.eye(dx), (m, 1))
                SiJ = _solve_psd(S, J)
                W = np.linalg.solve(J.T @ SiJ, SiJ.T)
                Ws = [W[:, a * dx : (a + 1) * dx] for a in range(m)]
            else:
                infos = [np.linalg.inv(B) for B in blocks]
                omega = ci_weights(infos)
                Pf = np.linalg.inv(sum(w * Y for w, Y in zip(omega, infos)))
                Ws = [w * Pf @ Y for w, Y in zip(omega, infos)]
            al = self.lazy
            self.xcomb[(i, k)] = [al * W + ((1.0 - al) * np.eye(dx) if a == 0 else 0.0) for a, W in enumerate(Ws)]
        out = None
        for W, q in zip(self.xcomb[(i, k)], items):
            t = W @ q
            out = t if out is None else out + t
        return out

    def combine(self, i: int, k: int, psi_i: Any, psis: dict[tuple[int, int], Any]) -> Any:
        """x̂_i = c_ii ψ_i + Σ c_li Φ(k, s) ψ_l(s); weights of neighbours not yet heard go to c_ii (other rules: the gains W)."""
        if self.exact_gains:
            return self._combine_exact(i, k, psi_i, psis)
        if not self._published:
            out = None
            for lnode, s, W in self.comb[(i, k)]:
                t = W @ (psi_i if (lnode, s) == (i, k) else psis[(lnode, s)])
                out = t if out is None else out + t
            return out
        used = self.src[i][k]
        cii = self.c[i, i] + sum(self.c[lnode, i] for lnode in self.nbrs[i] - {l2 for l2, _ in used})
        out = cii * psi_i
        for lnode, s in used:
            if self.c[lnode, i] != 0.0:
                out = out + self.c[lnode, i] * (self.Phi(k, s) @ psis[(lnode, s)])
        return out

    def agent_step(self, i: int, k: int, prev: dict | None, y_i: Any, inbox: Any, zero: Any) -> tuple[dict, dict]:
        xbar = self._prior(i, k, prev, zero)
        got = {(lnode, s): p for (lnode, s, p) in inbox}
        ys = {(i, k): y_i, **{key: p["y"] for key, p in got.items()}}
        psi = self.adapt(i, k, xbar, ys)
        xhat = self.combine(i, k, psi, {key: p["psi"] for key, p in got.items()})
        return {"xhat": xhat}, {"y": y_i, "psi": psi}

    def agent_step_tolerant(self, i: int, k: int, prev: dict | None, y_i: Any, inbox: Any, zero: Any) -> tuple[dict, dict]:
        r"""Unreliable links: adapt with every measurement that arrived, combine the neighbours that delivered.

        Agent i (the paper's k) with prior (x̄_i, P_i(t|t-1)) (0 and Σ_x at the first step; P_i is carried in the
        state, per run) fuses y_i(t) and every y_l(s) in the inbox, delay-compensated to t
        (:meth:`~teamkf.estimators.linear_team.Algorithm.compensated`, late ones too):

        .. math:: P_i(t|t) = (P_i(t|t-1)^{-1} + S_i)^{-1}, \quad
                  \psi_i = \bar x_i + P_i(t|t)\,(q_i - S_i \bar x_i),

        then :math:`\hat x_i = c'_{ii}\,\psi_i + \sum_{l \in D_i} c_{li}\,\Phi(t, s_l)\,\psi_l(s_l)` over the set
        D_i of neighbours that delivered (the most recent packet s_l of each), with
        :math:`c'_{ii} = c_{ii} + \sum_{l \notin D_i} c_{li}` (module docstring), and
        P_i(t+1|t) = A P_i(t|t) Aᵀ + Q. It sends (y_i(t), ψ_i(t)), like :meth:`agent_step`.

        Returns
        -------
        (state, payload) : state = {"xhat": x̂_i(t|t), "P": P_i(t+1|t)}, payload = {"y", "psi"}
        """
        if self.exact_gains:
            from ..exceptions import UnsupportedOperationError

            raise UnsupportedOperationError(
                "diffusion", "lost or late packets with gains='exact'", "its gains are designed for the graph's messages; use gains='nominal'"
            )
        sysm = self.system
        xbar = self._prior(i, k, prev, zero)
        P = sysm.Sigma_x if prev is None else prev.get("P", self.P_pred[i, k])
        pk = delivered(self.info_graph, i, inbox)
        r, Pf = self.fuse_delivered(i, k, xbar, P, y_i, pk)  # (P^-1 + S)^-1, Joseph form (as the design)
        psi = xbar + Pf @ r
        fresh = freshest(pk)
        Pnext = Pf
        if self._published:
            cii = self.c[i, i] + sum(self.c[lnode, i] for lnode in self.nbrs[i] - {l2 for l2, _, _ in fresh})
            xhat = cii * psi
            for lnode, s, p in fresh:
                if self.c[lnode, i] != 0.0:
                    xhat = xhat + self.c[lnode, i] * (self.Phi(k, s) @ p["psi"])
        else:  # the rule over what was delivered, with the senders' covariances P_l(s|s) carried in their packets
            items = [(i, k, Pf), *[(lnode, s, p.get("P", self.P_filt[lnode, s])) for lnode, s, p in fresh]]
            gains, Pc = self.combination_gains(i, k, items)
            psis = {(lnode, s): p["psi"] for lnode, s, p in fresh}
            xhat = None
            for lnode, s, W in gains:
                t = W @ (psi if (lnode, s) == (i, k) else psis[(lnode, s)])
                xhat = t if xhat is None else xhat + t
            if self.combination == "ci":
                Pnext = Pc
        if k + 1 < self.horizon:
            A = sysm.A_at(k)
            P = A @ Pnext @ A.T + sysm.Q_at(k)
            P = 0.5 * (P + P.T)
        return {"xhat": xhat, "P": P}, {"y": y_i, "psi": psi, "P": Pf}

    @property
    def runs_graph(self) -> CommGraph | None:
        """The graph whose packets :meth:`agent_step_runs` uses (as :meth:`agent_step_tolerant`: ``info_graph``)."""
        return self.info_graph

    @property
    def stacks_runs(self) -> bool:
        """Whether :meth:`agent_step_runs` applies (the published combination, nominal gains)."""
        return self._published and not self.exact_gains

    def agent_step_runs(self, i: int, k: int, prev: dict | None, y_i: Any, slots: Any) -> tuple[dict, dict]:
        """:meth:`agent_step_tolerant` (published combination) for every run of a block at once (:mod:`._runs`)."""
        from ._runs import freshest_runs, fuse_delivered_runs, heard, sym

        sysm, R, dx = self.system, y_i.shape[0], self.system.dx
        xbar = np.zeros((R, dx, 1)) if prev is None else sysm.A_at(k - 1) @ prev["xhat"]
        P = np.broadcast_to(sysm.Sigma_x, (R, dx, dx)) if prev is None else prev["P"]
        r, Pf = fuse_delivered_runs(self, i, k, xbar, P, y_i, slots)
        psi = xbar + Pf @ r
        hd = heard(slots, R)
        code = np.zeros(R, dtype=np.int64)
        order = list(hd)  # senders in slot order (in-neighbour position): the order ``freshest`` lists them
        for b, j in enumerate(order):
            code |= hd[j].astype(np.int64) << b
        uniq, inv_code = np.unique(code, return_inverse=True)
        cw = [self.c[i, i] + sum(self.c[lnode, i] for lnode in self.nbrs[i] - {j for b, j in enumerate(order) if (int(c) >> b) & 1}) for c in uniq]
        xhat = np.array(cw, dtype=float)[inv_code].reshape(R, 1, 1) * psi
        for lnode, groups in freshest_runs(slots, R):
            if self.c[lnode, i] == 0.0:
                continue
            for s, idx, p in groups:
                xhat[idx] = xhat[idx] + self.c[lnode, i] * (self.Phi(k, s) @ p["psi"][idx])
        if k + 1 < self.horizon:
            A = sysm.A_at(k)
            P = sym(A @ Pf @ A.T + sysm.Q_at(k))
        return {"xhat": xhat, "P": P}, {"y": y_i, "psi": psi, "P": Pf}

    def team_step(self, k: int, prev: list[dict | None], ys: list[Any], zero: Any) -> list[dict]:
        n = self.system.n_agents
        yd = {(j, k): ys[j] for j in range(n)}
        psis = {(i, k): self.adapt(i, k, self._prior(i, k, prev[i], zero), yd) for i in range(n)}
        return [{"xhat": self.combine(i, k, psis[(i, k)], psis)} for i in range(n)]


COUNTS: dict[str, str] = {
    "all": "the published rule: N, the number of agents (counts the own measurement N times when fewer are heard)",
    "heard": "m_i(k), the number of agents whose data entered agent i's fusion at step k (own Kalman filter when none is heard)",
}


def check_count(v: Any, key: str) -> str:
    """The ``count`` option: "all" (published N) or "heard" (module docstring)."""
    return V.choice(v, key, tuple(COUNTS), what="an agent count, one of")


def heard_counts(graph: CommGraph, src: list, T: int, honest: bool, iterations: int) -> FloatArray:
    """m[i, k]: 1 + the neighbours heard at step k (honest), or the size of the ``iterations``-hop in-neighbourhood (ideal)."""
    n = graph.n_agents
    m = np.empty((n, T))
    for i in range(n):
        if honest:
            for k in range(T):
                m[i, k] = 1 + len({j for j, _ in src[i][k]})
        else:
            reach = {i}
            for _ in range(iterations):
                reach = reach | {j for a in reach for j in graph.in_neighbors(a)}
            m[i, :] = len(reach)
    return m


def ci_weights(infos: list[FloatArray]) -> FloatArray:
    r"""ω on the simplex minimizing f(ω) = tr((Σ_j ω_j Y_j)⁻¹) for information matrices Y_j.

    f is convex on the simplex; with P = (Σ ω_j Y_j)⁻¹ its gradient and Hessian are

    .. math:: g_j = -\operatorname{tr}(P^2 Y_j), \qquad H_{jl} = 2 \operatorname{tr}(P^2 Y_j P Y_l),

    so a primal active-set Newton method solves it to round-off in a few iterations: on the free set F
    (ω_j > 0) the step d solves the equality-constrained Newton system [H_FF 1; 1ᵀ 0][d; ν] = [-g_F; 0].
    A full step that leaves the simplex is tried projected (every weight it sends below zero leaves F at
    once) and kept when it decreases f; otherwise the step is cut at the boundary (the blocking weight
    leaves F) and backtracked (Armijo) until f decreases; at a stationary point a weight at zero whose KKT multiplier g_j - λ is negative
    (λ = -ν, the multiplier of Σ ω = 1) re-enters F. The result is never worse than the best single
    estimate (ω = e_j).
    """
    m = len(infos)
    if m == 1:
        return np.ones(1)
    Ys = np.stack(infos)  # (m, d, d)
    flat = Ys.reshape(m, -1)
    shape = Ys.shape[1:]

    def cost(w: FloatArray) -> float:
        return float(np.trace(np.linalg.inv((w @ flat).reshape(shape))))

    traces = np.trace(np.linalg.inv(Ys), axis1=1, axis2=2)
    best = np.zeros(m)
    best[int(np.argmin(traces))] = 1.0
    w = np.full(m, 1.0 / m)
    free = np.ones(m, dtype=bool)
    f = cost(w)
    for _ in range(200):
        P = np.linalg.inv((w @ flat).reshape(shape))
        P2 = P @ P
        g = -(flat @ P2.reshape(-1))
        F = np.flatnonzero(free)
        PY = P @ Ys[F]  # (|F|, d, d): P Y_j
        H = 2.0 * np.einsum("jab,lba->jl", P @ PY, PY)  # tr(P² Y_j P Y_l) = tr((P P Y_j)(P Y_l))
        nf = F.size
        kkt = np.zeros((nf + 1, nf + 1))
        kkt[:nf, :nf] = H + 1e-14 * max(float(np.trace(H)), 1e-300) * np.eye(nf)  # a flat direction (equal Y_j) stays solvable
        kkt[:nf, nf] = kkt[nf, :nf] = 1.0
        sol = np.linalg.solve(kkt, np.concatenate([-g[F], [0.0]]))
        d, lam = sol[:nf], -sol[nf]
        decrement = -float(g[F] @ d)  # the Newton decrement: the predicted decrease is half of it
        if decrement <= 1e-15 * abs(f):
            out = ~free & (g < lam - 1e-12 * max(abs(lam), 1e-300))
            if not out.any():
                break
            free[int(np.argmin(np.where(out, g, np.inf)))] = True  # the most violated KKT condition re-enters
            continue
        neg = d < 0
        a_max = float(np.min(-w[F][neg] / d[neg])) if neg.any() else np.inf
        if a_max < 1.0:  # the full step leaves the simplex: its projection drops every weight it sends below zero at once
            wp = np.zeros(m)
            wp[F] = np.maximum(w[F] + d, 0.0)
            fp = cost(wp / wp.sum())
            if fp < f:
                free = wp > 0.0
                w, f = wp / wp.sum(), fp
                continue
        a = min(1.0, a_max)
        while True:
            wn = w.copy()
            wn[F] = np.maximum(w[F] + a * d, 0.0)
            fn = cost(wn)
            if fn <= f - 1e-4 * a * decrement or a < 1e-12:
                break
            a *= 0.5
        if fn > f:  # no decrease at round-off level: the optimum
            break
        if a == a_max:  # the blocking weight reaches the boundary and leaves the free set
            jb = F[neg][int(np.argmin(-w[F][neg] / d[neg]))]
            wn[jb] = 0.0
            free[jb] = False
        w, f = wn / wn.sum(), fn  # Σ d = 0: the sum is 1 up to round-off
    return w if f <= cost(best) else best


#: the most consensus iterations per step (ICF, HCMCI); consensus has converged to round-off long before
MAX_ITERATIONS = 10_000


def check_iterations(v: Any, key: str) -> int:
    """The ``iterations`` option: consensus iterations per step of the ideal variant (an integer in 1..MAX_ITERATIONS).

    Consensus converges geometrically, so more than :data:`MAX_ITERATIONS` iterations a step
    change nothing but the run time (10^9 of them would run for days): refused up front.
    """
    return V.integer(v, key, minimum=1, maximum=MAX_ITERATIONS, what="a number of consensus iterations")


def finite_horizon(horizon: Any, family: str, system: LinearGaussianSystem, cost: TeamCost) -> int:
    """The finite horizon T of a baseline design, checked against the model's and the cost's horizons."""
    if horizon is None:
        raise ArgumentError(
            f"horizon: the {family!r} family has a finite-horizon design only, found horizon=None; give a number of steps T", argument="horizon"
        )
    T = V.positive_int(horizon, "horizon")
    system.require_horizon(T)
    cost.require_horizon(T)
    return T
