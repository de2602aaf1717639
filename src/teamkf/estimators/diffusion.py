r"""ATC diffusion Kalman filter, information form (Cattivelli & Sayed, IEEE TAC 55(9), 2010).

Agent k, neighbourhood N_k = {k} ∪ in-neighbours, at step t:

.. math::

    S_k = \sum_{l\in N_k} C_l^\top R_l^{-1} C_l, \quad q_k = \sum_{l\in N_k} C_l^\top R_l^{-1} y_l, \\
    P_k(t|t) = (P_k(t|t-1)^{-1} + S_k)^{-1}, \quad
    \psi_k = \hat x_k(t|t-1) + P_k(t|t)\,(q_k - S_k \hat x_k(t|t-1)), \\
    \hat x_k(t|t) = \sum_{l\in N_k} c_{lk}\, \psi_l, \quad
    \hat x_k(t+1|t) = A \hat x_k(t|t), \quad P_k(t+1|t) = A P_k(t|t) A^\top + Q,

prior 0 and Σ_x at the first step; ẑ_k = L_k x̂_k(t|t).

Variants
--------
``ideal``
    The published algorithm: neighbours' y_l(t) and ψ_l(t) of the *same* step
    (two exchanges inside a step; not realizable on a delay graph).
``honest`` (default)
    One exchange per step over the graph: agent l sends (y_l(s), ψ_l(s)) at
    step s; agent k uses it at t = s + τ_lk, **delay-compensated**: y_l(s) as
    a measurement of x(t) with C̃ = C_l Φ(t,s)⁻¹, R̃ = R_l + C̃ Q(t,s) C̃ᵀ (its
    information pair through the prediction with process noise, see
    :func:`~teamkf.estimators.linear_team.compensated_measurement`), and ψ_l(s)
    propagated to Φ(t,s) ψ_l(s). Before a neighbour's first message arrives its
    combination weight goes to the agent itself.

Unreliable links (:mod:`teamkf.simulation.links`)
-------------------------------------------------
On lossy links the agents run :meth:`DiffusionAlgorithm.agent_step_tolerant`:

* **adaptation**: every y_l(s) that arrives at step t is fused once, on time
  (s = t - τ_lk) or late (s < t - τ_lk), delay-compensated from s to t exactly
  as above; the agent carries its own P_k(t|t-1) (a per-run quantity) and
  computes P_k(t|t) = (P_k(t|t-1)⁻¹ + S_k)⁻¹ from the S_k of what arrived, so
  the gain follows the information actually fused;
* **combination**: a neighbour that delivered enters with Φ(t,s) ψ_l(s) (the
  most recent of its packets in the inbox, when several arrive together) and
  its weight c_lk; the weight of a neighbour that delivered nothing goes to the
  agent itself (the rule above for neighbours not yet heard; the same
  re-assignment of a failed link's weight to the diagonal as Xiao, Boyd & Lall,
  IPSN 2005, for Metropolis weights), so the weights used still sum to 1;
* with nothing lost it is the honest variant (the same arithmetic, bit for
  bit); with every packet lost (p = 1) every agent is its own Kalman filter on
  y_k alone (:mod:`teamkf.estimators.local`).

Combination rules (``combination``) and lazy updates (``lazy``)
--------------------------------------------------------------
The published combination is the scalar one above (``combination="weights"``).
The fair honest forms weigh each received ψ̃_l = Φ(t,s) ψ_l(s) by how good it is
after its age, with the nominal covariance P̃_l = Φ(t,s) P_l(s|s) Φ(t,s)ᵀ + Q(t,s)
(P̃_k = P_k(t|t) for the agent's own ψ_k); every rule is data-independent, so the
exact cost is kept:

``"age"`` (age-aware scalar weights)
    a_lk ∝ c_lk / tr P̃_l, normalized over {k} and the neighbours heard (the
    weight of a neighbour not yet heard goes to c_kk first, as above);
``"matrix"`` (information-matrix weights)
    x̂_k = (Σ_l c_lk P̃_l⁻¹)⁻¹ Σ_l c_lk P̃_l⁻¹ ψ̃_l;
``"ci"`` (covariance intersection, Hu, Xie & Zhang, IEEE TSP 60(5), 2012)
    x̂_k = P_f Σ_l ω_l P̃_l⁻¹ ψ̃_l, P_f⁻¹ = Σ_l ω_l P̃_l⁻¹, ω = argmin tr P_f on
    the simplex (:func:`~teamkf.estimators.ci.ci_weights`), and the prediction
    starts from P_f (P_k(t+1|t) = A P_f Aᵀ + Q): the consistent CI diffusion.

``lazy`` = α ∈ (0, 1] mixes the combination with the agent's own ψ_k:
x̂_k = (1 - α) ψ_k + α x̂_k^comb (α = 1: the rule itself). The
tuning step (:mod:`teamkf.experiments.tuning`) picks the rule and α per network
by the exact cost.

Exact gains (``gains="exact"``)
-------------------------------
The published gains come from the nominal covariances P_k, which ignore that
delay-compensated data and the agent's own prior share the process noise (and
that the combination correlates the agents' errors). With ``gains="exact"`` the
adaptation is the linear MMSE update of the prior with the measurements the
agent holds, K = Cov(e, ν) Cov(ν)⁻¹ for the innovation ν = ỹ - C̃ x̄, and the
combination applies its rule with the exact error covariances of the items
(``"matrix"``: the best linear unbiased combination W = (Jᵀ Σ⁻¹ J)⁻¹ Jᵀ Σ⁻¹,
J = 1 ⊗ I, with their cross-covariances Σ). The covariances are those of the
joint error recursion of :mod:`teamkf.estimators.linear_team`, computed while
the steps are built; the gains stay data-independent, so the cost is exact.
Each agent still uses only what the graph delivered (the gains are offline
quantities, like every Kalman gain). On lossy links this form is not defined
(its gains are designed for the graph's messages) and raises.

Weights (columns of C = [c_lk] sum to 1): ``"metropolis"`` (default,
c_lk = 1/max(n_k, n_l) for l ∈ N_k \ {k}, n_k = ``|N_k|``, c_kk = 1 - Σ),
``"uniform"`` (1/n_k) or an explicit n×n matrix (non-negative, column-stochastic,
non-zero only on the graph's edges l → k and the diagonal).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.linalg as sla

from .. import _validation as V
from .._validation import FloatArray
from ..exceptions import ArgumentError, NotPositiveDefiniteError
from ..models import LinearGaussianSystem, TeamCost
from ..network.graph import CommGraph
from .checks import check_graph, check_model
from .kalman import kalman_step
from .linear_team import Algorithm, LinearTeamDesign, _block_diag, delivered, finish_design, freshest, process_noise
from .registry import Family, Option, _register_builtin

__all__ = ["design_diffusion", "diffusion_weights", "VARIANTS", "COMBINATIONS", "check_variant", "check_combination", "check_lazy"]

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
        self.gain: dict[tuple[int, int, int, int], tuple[FloatArray, FloatArray]] = {}  # (i,k,l,s) -> (G̃ = C̃'R̃^-1, Y = G̃ C̃)
        self.P_filt = np.empty((n, T, dx, dx))
        self.P_pred = np.empty((n, T, dx, dx))
        #: (i, k) -> [(l, s, W)]: x̂_i = Σ W ψ_l(s) (W includes Φ(k, s)); only for the non-published rules
        self.comb: dict[tuple[int, int], list[tuple[int, int, FloatArray]]] = {}
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
                _, Pf = kalman_step(P[i], np.vstack(Cs), _block_diag(Rs))  # (P^-1 + S)^-1, Joseph form
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
                from .ci import ci_weights

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
                from .ci import ci_weights

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

    def team_step(self, k: int, prev: list[dict | None], ys: list[Any], zero: Any) -> list[dict]:
        n = self.system.n_agents
        yd = {(j, k): ys[j] for j in range(n)}
        psis = {(i, k): self.adapt(i, k, self._prior(i, k, prev[i], zero), yd) for i in range(n)}
        return [{"xhat": self.combine(i, k, psis[(i, k)], psis)} for i in range(n)]


def design_diffusion(
    system: LinearGaussianSystem,
    cost: TeamCost,
    graph: CommGraph,
    horizon: int | None = None,
    *,
    weights: Any = "metropolis",
    variant: str = "honest",
    combination: str = "weights",
    lazy: float = 1.0,
    gains: str = "nominal",
) -> LinearTeamDesign:
    """Design the ATC diffusion KF (information form) with its exact team cost.

    Parameters
    ----------
    system, cost, graph
    horizon : int
        Number of steps T (finite horizon only).
    weights : "metropolis", "uniform" or an n×n column-stochastic matrix c[l, k]
    variant : "honest" (default) or "ideal" (module docstring)
    combination : "weights" (published, default), "age", "matrix" or "ci" (module docstring)
    lazy : float in (0, 1]
        α of the lazy combination x̂ = (1 - α) ψ_k + α x̂^comb (1: none, the published step)
    gains : "nominal" (published, default) or "exact"
        "exact": the adaptation gain and the combination rule from the exact error covariances (module docstring)

    Examples
    --------
    >>> from teamkf import LinearGaussianSystem, TeamCost, CommGraph
    >>> d = design_diffusion(LinearGaussianSystem.platoon(4), TeamCost.platoon(4, 10.0), CommGraph.line(4), 20)
    >>> d.label, d.stage_costs.shape
    ('diffusion [honest]', (20,))
    """
    check_model(system, cost)
    check_graph(graph, system.n_agents)
    variant = check_variant(variant, "variant")
    T = _horizon(horizon, "diffusion", system, cost)
    c = diffusion_weights(graph, weights, key="diffusion.weights")
    comb = check_combination(combination, "diffusion.combination")
    al = check_lazy(lazy, "diffusion.lazy")
    gm = check_gains(gains, "diffusion.gains")
    alg = DiffusionAlgorithm(system, cost, graph, T, c, honest=(variant == "honest"), combination=comb, lazy=al, gains=gm)
    info = {"weights": weights if isinstance(weights, str) else "explicit", "combination": comb, "lazy": al, "gains": gm}
    return finish_design("diffusion", alg, variant, info)


def _horizon(horizon: Any, family: str, system: LinearGaussianSystem, cost: TeamCost) -> int:
    """The finite horizon T of a baseline design, checked against the model's and the cost's horizons."""
    if horizon is None:
        raise ArgumentError(
            f"horizon: the {family!r} family has a finite-horizon design only, found horizon=None; give a number of steps T", argument="horizon"
        )
    T = V.positive_int(horizon, "horizon")
    system.require_horizon(T)
    cost.require_horizon(T)
    return T


FAMILY = _register_builtin(
    Family(
        name="diffusion",
        design=design_diffusion,
        title="ATC diffusion Kalman filter, information form (Cattivelli & Sayed 2010), honest = delay-compensated",
        uses="graph",
        horizons=frozenset({"finite"}),
        analytic_cost=True,
        options=(
            Option(
                name="weights", default="metropolis", check=check_weights, doc="'metropolis' | 'uniform' | an n×n column-stochastic matrix c[l, k]"
            ),
            Option(
                name="variant",
                default="honest",
                check=check_variant,
                doc=" | ".join(f"{k!r}: {d}" for k, d in VARIANTS.items()),
                choices=tuple(VARIANTS),
            ),
            Option(
                name="combination",
                default="weights",
                check=check_combination,
                doc=" | ".join(f"{k!r}: {d}" for k, d in COMBINATIONS.items()),
                choices=tuple(COMBINATIONS),
            ),
            Option(name="gains", default="nominal", check=check_gains, doc=" | ".join(f"{k!r}: {d}" for k, d in GAINS.items()), choices=tuple(GAINS)),
            Option(
                name="lazy", default=1.0, check=check_lazy, doc="lazy combination factor alpha in (0, 1]: xhat = (1 - alpha) psi_k + alpha xhat_comb"
            ),
        ),
        example="design_diffusion(system, cost, graph, horizon=100, weights='metropolis', variant='honest')",
    )
)
