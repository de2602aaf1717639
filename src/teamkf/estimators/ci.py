r"""Local Kalman filters fused by covariance intersection (Julier & Uhlmann, ACC 1997).

Every agent i runs the Kalman filter of its own measurements (x̂_i^loc, P_i,
:mod:`teamkf.estimators.local`) and reports the covariance-intersection fusion
of its own and its in-neighbours' local estimates:

.. math::

    P_f^{-1} = \sum_{j\in J_i} \omega_j \tilde P_j^{-1}, \qquad
    \hat x_i = P_f \sum_{j\in J_i} \omega_j \tilde P_j^{-1} \tilde x_j, \qquad
    \omega = \arg\min_{\omega\ge 0,\ \sum\omega = 1} \operatorname{tr} P_f,

ẑ_i = L_i x̂_i. The local filters are not changed by the fusion (no feedback).
The weights depend on covariances only, so they are computed at design time
(the filter stays linear with data-independent gains: exact analytic cost).

``feedback=True`` (the CI diffusion of Hu, Xie & Zhang, IEEE TSP 2012, and
Battistelli & Chisci, Automatica 2014; :class:`CIFeedbackAlgorithm`): each
agent updates its prior with its own measurement (ψ_i, P_i(k|k)), CI-fuses ψ_i
with the delay-compensated ψ_l(s) it received, and the fused estimate with its
CI covariance P_f is its next prior (x̄_i = A x̂_i, P = A P_f Aᵀ + Q). Where no
agent detects x alone the published form's local filters diverge, and so does
their fusion; the feedback form spreads the information over the graph.

Variants: ``ideal`` fuses the neighbours' current x̂_j^loc(k), P_j(k|k);
``honest`` (default) fuses what the graph delivered, x̂_j^loc(s) sent at
s = k - τ_ji, delay-compensated: x̃_j = Φ(k,s) x̂_j^loc(s) and
P̃_j = Φ(k,s) P_j(s|s) Φ(k,s)ᵀ + Q(k,s).

Unreliable links (:mod:`teamkf.simulation.links`)
-------------------------------------------------
On lossy links the agents run :meth:`CIAlgorithm.agent_step_tolerant`. The
local filters use no message, so losses do not change them (nor their
covariances P_j(s|s), which stay the design's schedules: nothing per run needs
to be carried or sent). Agent i fuses its own x̂_i^loc(k) and, of every
in-neighbour that delivered, the most recent x̂_j^loc(s) in its inbox, on time
or late, compensated from s to k as above; the weights ω are re-optimized over
the estimates actually fused (the CI rule itself: the trace-minimizing point of
the simplex over J_i(k) = {i} ∪ the neighbours that delivered). CI is
consistent for any cross-correlation, so a late (older) estimate is fused as
correctly as an on-time one. With nothing lost it is the honest variant (the
same arithmetic, bit for bit); with every packet lost (p = 1) J_i = {i} and
x̂_i = x̂_i^loc, each agent's own Kalman filter (to round-off: the fusion gain
P_f P̃_i⁻¹ is the identity in exact arithmetic).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .._validation import FloatArray
from ..exceptions import ArgumentError, NotPositiveDefiniteError
from ..models import LinearGaussianSystem, TeamCost
from ..network.graph import CommGraph
from ._consensus_common import VARIANTS, DiffusionAlgorithm, check_variant, ci_weights, finite_horizon, information_sources
from ._kalman_common import kalman_step
from .checks import check_graph, check_information_form, check_model
from .linear_team import Algorithm, LinearTeamDesign, delivered, finish_design, freshest, process_noise
from .registry import Family, Option, _register_builtin

__all__ = ["design_ci", "ci_weights", "check_feedback", "CIFeedbackAlgorithm"]


def _information(P: FloatArray, agent: int, s: int, k: int) -> FloatArray:
    """P^-1 for the information form of CI; a typed error when P is (numerically) singular."""
    P = 0.5 * (P + P.T)
    lam = np.linalg.eigvalsh(P)
    if lam[0] <= 1e-12 * max(1.0, float(lam[-1])):
        raise NotPositiveDefiniteError(
            f"ci: agent {agent}'s covariance from step {s}, used at step {k}, is singular (smallest eigenvalue {lam[0]:.3g}): "
            "covariance intersection fuses information matrices P^-1 and needs positive definite covariances; "
            "give Sigma_x and Q positive definite (add a small multiple of I), or use another family",
            argument="ci",
        )
    return np.asarray(np.linalg.inv(P), dtype=float)


def _ci_fusion(alg: Any, k: int, items: list[tuple[int, int, FloatArray]]) -> tuple[list[FloatArray], FloatArray, FloatArray]:
    """CI at step k of estimates from steps s with covariances P, ``items`` = [(l, s, P)]: the information
    matrices P̃⁻¹ (P̃ = Φ(k, s) P Φ(k, s)ᵀ + Q(k, s)), the weights ω (:func:`ci_weights`, solved once per
    distinct set of matrices: converged covariances repeat) and P_f = (Σ ω_l P̃_l⁻¹)⁻¹."""
    Ys = []
    for lnode, s, Pl in items:
        Pt = Pl if s == k else alg.Phi(k, s) @ Pl @ alg.Phi(k, s).T + process_noise(alg.system, k, s)
        Ys.append(_information(Pt, lnode, s, k))
    key = tuple(np.round(Y, 12).tobytes() for Y in Ys)
    if key not in alg._wcache:
        alg._wcache[key] = ci_weights(Ys)
    w = alg._wcache[key]
    return Ys, w, np.linalg.inv(sum(wj * Y for wj, Y in zip(w, Ys)))


class CIAlgorithm(DiffusionAlgorithm):
    """Local KF per agent (no combination), then CI fusion of the local estimates received."""

    state_kinds = {"xloc": "x", "xhat": "x"}
    payload_kinds = {"xloc": "x"}

    @property
    def info_graph(self) -> CommGraph | None:
        return None  # the local filters use own measurements only

    def __init__(self, system: LinearGaussianSystem, cost: TeamCost, graph: CommGraph, horizon: int, honest: bool):
        super().__init__(system, cost, graph, horizon, np.eye(system.n_agents), honest)
        n, T = system.n_agents, horizon
        self.fuse_src = information_sources(graph, T, honest)
        self.fuse: dict[tuple[int, int], list[tuple[int, int, FloatArray]]] = {}  # (i,k) -> [(l, s, gain)]
        self.omega = np.zeros((n, T, n))
        self._wcache: dict[tuple, FloatArray] = {}
        self._tolerant_fuse: dict[tuple[tuple[int, int], ...], list[tuple[int, int, FloatArray]]] = {}
        for i in range(n):
            for k in range(T):
                srcs = [(i, k), *self.fuse_src[i][k]]
                self.fuse[(i, k)], w = self._fusion(k, srcs)
                for (lnode, _), wj in zip(srcs, w):
                    self.omega[i, k, lnode] = wj
        self.schedules = {"P_local": self.P_filt, "omega": self.omega}

    def _fusion(self, k: int, srcs: list[tuple[int, int]]) -> tuple[list[tuple[int, int, FloatArray]], FloatArray]:
        """CI of the local estimates x̂_l^loc(s), (l, s) in ``srcs``, at step k: the gains ω_l P_f P̃_l⁻¹ Φ(k, s) and ω."""
        Ys, w, Pf = _ci_fusion(self, k, [(lnode, s, self.P_filt[lnode, s]) for lnode, s in srcs])
        return [(lnode, s, wj * Pf @ Y @ self.Phi(k, s)) for (lnode, s), wj, Y in zip(srcs, w, Ys) if wj > 0], w

    def _prior(self, i: int, k: int, prev: dict | None, zero: Any) -> Any:
        return zero(self.system.dx) if prev is None else self.system.A_at(k - 1) @ prev["xloc"]

    def _fused(self, i: int, k: int, xlocs: dict) -> Any:
        out = None
        for lnode, s, Gm in self.fuse[(i, k)]:
            t = Gm @ xlocs[(lnode, s)]
            out = t if out is None else out + t
        return out

    def agent_step(self, i: int, k: int, prev: dict | None, y_i: Any, inbox: Any, zero: Any) -> tuple[dict, dict]:
        xloc = self.adapt(i, k, self._prior(i, k, prev, zero), {(i, k): y_i})
        xlocs = {(i, k): xloc, **{(lnode, s): p["xloc"] for (lnode, s, p) in inbox}}
        return {"xloc": xloc, "xhat": self._fused(i, k, xlocs)}, {"xloc": xloc}

    def agent_step_tolerant(self, i: int, k: int, prev: dict | None, y_i: Any, inbox: Any, zero: Any) -> tuple[dict, dict]:
        r"""Unreliable links: CI of the own local estimate and the most recent one of each neighbour that delivered.

        With J_i(k) = {(i, k)} ∪ {(j, s_j)}, s_j the latest step of j's packets in the inbox (on time or late),
        x̃_j = Φ(k, s_j) x̂_j^loc(s_j), P̃_j = Φ P_j(s_j|s_j) Φᵀ + Q(k, s_j) and ω re-optimized over J_i(k):

        .. math:: \hat x_i = P_f \sum_{j\in J_i(k)} \omega_j \tilde P_j^{-1} \tilde x_j,
                  \qquad P_f^{-1} = \sum_{j\in J_i(k)} \omega_j \tilde P_j^{-1}.

        The local filter x̂_i^loc does not use messages and is the same as in :meth:`agent_step`.

        Returns
        -------
        (state, payload) : state = {"xloc", "xhat"}, payload = {"xloc": x̂_i^loc(k)}
        """
        xloc = self.adapt(i, k, self._prior(i, k, prev, zero), {(i, k): y_i})
        fresh = freshest(delivered(self.graph, i, inbox))
        srcs = ((i, k), *[(lnode, s) for (lnode, s, _) in fresh])
        if list(srcs) == [(i, k), *self.fuse_src[i][k]]:
            gains = self.fuse[(i, k)]  # what the design fuses: its precomputed gains
        else:
            if srcs not in self._tolerant_fuse:
                self._tolerant_fuse[srcs] = self._fusion(k, list(srcs))[0]
            gains = self._tolerant_fuse[srcs]
        xlocs = {(i, k): xloc, **{(lnode, s): p["xloc"] for (lnode, s, p) in fresh}}
        out: Any = None
        for lnode, s, Gm in gains:
            t = Gm @ xlocs[(lnode, s)]
            out = t if out is None else out + t
        return {"xloc": xloc, "xhat": out}, {"xloc": xloc}

    @property
    def runs_graph(self) -> CommGraph | None:
        """The graph whose packets :meth:`agent_step_runs` fuses (the local estimates of the in-neighbours)."""
        return self.graph

    def agent_step_runs(self, i: int, k: int, prev: dict | None, y_i: Any, slots: Any) -> tuple[dict, dict]:
        """:meth:`agent_step_tolerant` for every run of a block at once (:mod:`._runs`: the same numbers, run by run).

        The runs are grouped by the packets they fuse (the freshest of each neighbour), each group with its gains."""
        from ._runs import freshest_runs

        sysm, R, dx = self.system, y_i.shape[0], self.system.dx
        xbar = np.zeros((R, dx, 1)) if prev is None else sysm.A_at(k - 1) @ prev["xloc"]
        xloc = self.adapt(i, k, xbar, {(i, k): y_i})
        fr = freshest_runs(slots, R)
        got = np.full((R, len(fr)), -1, dtype=np.int64)  # per run, the sent step of each sender's freshest packet (-1: none)
        pays: dict[tuple[int, int], Any] = {}
        for c, (j, groups) in enumerate(fr):
            for s, idx, p in groups:
                got[idx, c] = s
                pays[(j, s)] = p
        uniq, inverse = np.unique(got, axis=0, return_inverse=True)
        out = np.empty((R, dx, 1))
        for u_, row in enumerate(uniq.tolist()):
            idx = np.flatnonzero(inverse.reshape(-1) == u_)
            srcs = ((i, k), *[(fr[c][0], s) for c, s in enumerate(row) if s >= 0])
            if list(srcs) == [(i, k), *self.fuse_src[i][k]]:
                gains = self.fuse[(i, k)]
            else:
                if srcs not in self._tolerant_fuse:
                    self._tolerant_fuse[srcs] = self._fusion(k, list(srcs))[0]
                gains = self._tolerant_fuse[srcs]
            acc: Any = None
            for lnode, s, Gm in gains:
                t = Gm @ (xloc[idx] if (lnode, s) == (i, k) else pays[(lnode, s)]["xloc"][idx])
                acc = t if acc is None else acc + t
            out[idx] = acc
        return {"xloc": xloc, "xhat": out}, {"xloc": xloc}

    def team_step(self, k: int, prev: list[dict | None], ys: list[Any], zero: Any) -> list[dict]:
        n = self.system.n_agents
        xl = {(i, k): self.adapt(i, k, self._prior(i, k, prev[i], zero), {(i, k): ys[i]}) for i in range(n)}
        return [{"xloc": xl[(i, k)], "xhat": self._fused(i, k, xl)} for i in range(n)]


class CIFeedbackAlgorithm(DiffusionAlgorithm):
    r"""CI diffusion with feedback: own update, CI of the estimates received, the fused estimate is the next prior.

    Agent i, step k, prior (x̄_i, P_i(k|k-1)) (0 and Σ_x at k = 0):

    .. math::

        P_i(k|k) = (P_i(k|k-1)^{-1} + C_i^\top R_i^{-1} C_i)^{-1}, \quad
        \psi_i = \bar x_i + P_i(k|k)\, C_i^\top R_i^{-1} (y_i - C_i \bar x_i), \\
        \hat x_i = P_f \sum_{(l,s)\in J_i(k)} \omega_l \tilde P_l^{-1} \Phi(k,s)\,\psi_l(s), \quad
        P_f^{-1} = \sum \omega_l \tilde P_l^{-1}, \quad
        \bar x_i(k+1) = A \hat x_i, \quad P_i(k+1|k) = A P_f A^\top + Q,

    with J_i(k) = {(i, k)} ∪ {(l, k - τ_li)} (honest, once arrived) or {(l, k)} (ideal), P̃_l = Φ P_l(s|s) Φᵀ + Q(k, s)
    (P̃_i = P_i(k|k)) and ω the trace-minimizing point of the simplex. The nominal covariances P_i(k|k), P_f and the
    weights depend on the model only, so the step is linear with data-independent gains (exact cost).
    """

    state_kinds = {"xhat": "x"}
    payload_kinds = {"psi": "x"}

    @property
    def info_graph(self) -> CommGraph | None:
        return None  # the adaptation uses the agent's own measurement only; the graph carries the estimates ψ

    def __init__(self, system: LinearGaussianSystem, cost: TeamCost, graph: CommGraph, horizon: int, honest: bool):
        Algorithm.__init__(self, system, cost, graph, horizon)  # the nominal recursion below replaces the diffusion one
        n, dx, T = system.n_agents, system.dx, horizon
        self.honest, self.c = honest, np.eye(n)
        self.combination, self.lazy, self.exact_gains = "ci", 1.0, False
        self.xgain, self.xcomb = {}, {}
        self.src = [[[] for _ in range(T)] for _ in range(n)]  # adaptation: own measurement only
        self.nbrs = [set() for _ in range(n)]
        self.fuse_src = information_sources(graph, T, honest)
        self.gain = {}
        self.P_filt = np.empty((n, T, dx, dx))
        self.P_pred = np.empty((n, T, dx, dx))
        self.omega = np.zeros((n, T, n))
        self.P_fused = np.empty((n, T, dx, dx))
        self.comb = {}
        self._wcache: dict[tuple, FloatArray] = {}
        P = [system.Sigma_x for _ in range(n)]
        for k in range(T):
            for i in range(n):
                self.P_pred[i, k] = P[i]
                Ct, Rt, G, Y = self.compensated(i, k, k)
                self.gain[(i, k, i, k)] = (G, Y)
                self.P_filt[i, k] = kalman_step(P[i], Ct, Rt)[1]
            for i in range(n):
                srcs = [(i, k), *self.fuse_src[i][k]]
                self.comb[(i, k)], w, Pf = self._fusion(k, [(lnode, s, self.P_filt[lnode, s]) for lnode, s in srcs])
                self.P_fused[i, k] = Pf
                for (lnode, _), wj in zip(srcs, w):
                    self.omega[i, k, lnode] = wj
                if k + 1 < T:
                    A = system.A_at(k)
                    Pn = A @ Pf @ A.T + system.Q_at(k)
                    P[i] = 0.5 * (Pn + Pn.T)
        self.schedules = {"P_filt": self.P_filt, "P_pred": self.P_pred, "P_fused": self.P_fused, "omega": self.omega}

    def _fusion(self, k: int, items: list[tuple[int, int, FloatArray]]) -> tuple[list[tuple[int, int, FloatArray]], FloatArray, FloatArray]:
        """CI at step k of ψ_l(s) with covariances P_l(s|s), ``items`` = [(l, s, P)] (own first): gains ω_l P_f P̃_l⁻¹ Φ(k, s), ω, P_f."""
        Ys, w, Pf = _ci_fusion(self, k, items)
        Pf = 0.5 * (Pf + Pf.T)
        gains = [(lnode, s, wj * Pf @ Y @ self.Phi(k, s)) for (lnode, s, _), wj, Y in zip(items, w, Ys) if wj > 0]
        return gains, w, Pf

    def agent_step(self, i: int, k: int, prev: dict | None, y_i: Any, inbox: Any, zero: Any) -> tuple[dict, dict]:
        psi = self.adapt(i, k, self._prior(i, k, prev, zero), {(i, k): y_i})
        xhat = self.combine(i, k, psi, {(lnode, s): p["psi"] for (lnode, s, p) in inbox})
        return {"xhat": xhat}, {"psi": psi}

    def agent_step_tolerant(self, i: int, k: int, prev: dict | None, y_i: Any, inbox: Any, zero: Any) -> tuple[dict, dict]:
        r"""Unreliable links: own update, then CI of ψ_i and the most recent ψ_l(s_l) of each in-neighbour that delivered.

        The agent carries its own P_i(k|k-1) (a per-run quantity) and each packet carries its sender's P_l(s|s), so
        the weights ω are re-optimized over J_i(k) = {(i, k)} ∪ {(l, s_l)}, the estimates actually fused (on time or
        late, compensated from s_l to k as in :meth:`agent_step`), and P_i(k+1|k) = A P_f Aᵀ + Q. CI is consistent for
        any cross-correlation, so a late estimate is fused as correctly as an on-time one. With nothing lost it is the
        honest variant; with every packet lost each agent is its own Kalman filter (:mod:`teamkf.estimators.local`).

        Returns
        -------
        (state, payload) : state = {"xhat": x̂_i(k|k), "P": P_i(k+1|k)}, payload = {"psi": ψ_i(k), "P": P_i(k|k)}
        """
        sysm = self.system
        xbar = self._prior(i, k, prev, zero)
        P = sysm.Sigma_x if prev is None else prev.get("P", self.P_pred[i, k])
        r, Pk = self.fuse_delivered(i, k, xbar, P, y_i, [])
        psi = xbar + Pk @ r
        fresh = freshest(delivered(self.graph, i, inbox))
        items = [(i, k, Pk), *[(lnode, s, p.get("P", self.P_filt[lnode, s])) for lnode, s, p in fresh]]
        nominal = [(lnode, s) for lnode, s, _ in items] == [(i, k), *self.fuse_src[i][k]] and all(
            np.array_equal(Pl, self.P_filt[lnode, s]) for lnode, s, Pl in items
        )
        if nominal:  # what the design fused, with the design's covariances: its gains (bit for bit the reliable runtime)
            gains, Pf = self.comb[(i, k)], self.P_fused[i, k]
        else:
            gains, _, Pf = self._fusion(k, items)
        psis = {(i, k): psi, **{(lnode, s): p["psi"] for lnode, s, p in fresh}}
        xhat: Any = None
        for lnode, s, W in gains:
            t = W @ psis[(lnode, s)]
            xhat = t if xhat is None else xhat + t
        if k + 1 < self.horizon:
            A = sysm.A_at(k)
            P = A @ Pf @ A.T + sysm.Q_at(k)
            P = 0.5 * (P + P.T)
        return {"xhat": xhat, "P": P}, {"psi": psi, "P": Pk}


def design_ci(
    system: LinearGaussianSystem, cost: TeamCost, graph: CommGraph, horizon: int | None = None, *, variant: str = "honest", feedback: bool = False
) -> LinearTeamDesign:
    """Design local Kalman filters with covariance-intersection fusion, with the exact team cost.

    Parameters
    ----------
    system : LinearGaussianSystem
        The process x(k+1) = A x(k) + w(k) and the agents' measurements y_i(k) = C_i x(k) + v_i(k).
    cost : TeamCost
        The team cost c(x, ẑ) = (L x - ẑ)ᵀ S (L x - ẑ) (``None``: the sum of the agents' MSEs).
    graph : CommGraph
        The communication graph: agent i hears agent j over edge (j, i) after its integer delay τ_ji.
    horizon : int
        Number of steps T (finite horizon only).
    variant : "honest" (default) or "ideal"
        "honest": one exchange per step over the graph's delays, delay-compensated (realizable);
        "ideal": neighbours' current data within the step (a bound, not realizable on a delay graph).
    feedback : bool
        False (default, the published form): the local filters are not changed by the fusion. True: the CI
        diffusion (:class:`CIFeedbackAlgorithm`): each agent updates with its own measurement, CI-fuses the
        estimates ψ_l it received, and the fused estimate with its CI covariance P_f is its next prior.

    Returns
    -------
    LinearTeamDesign
        The per-step linear maps with the exact team cost (stage costs E[c(x(k), ẑ(k))]).

    Examples
    --------
    >>> from teamkf import LinearGaussianSystem, TeamCost, CommGraph, design_ci
    >>> d = design_ci(LinearGaussianSystem.platoon(4), TeamCost.platoon(4, 10.0), CommGraph.line(4), 10)
    >>> d.label
    'ci [honest]'
    >>> design_ci(LinearGaussianSystem.platoon(4), TeamCost.platoon(4, 10.0), CommGraph.line(4), 10, feedback=True).info["feedback"]
    True
    """
    check_model(system, cost)
    check_information_form(system, "ci")
    check_graph(graph, system.n_agents)
    variant = check_variant(variant, "variant")
    fb = check_feedback(feedback, "ci.feedback")
    T = finite_horizon(horizon, "ci", system, cost)
    honest = variant == "honest"
    alg: DiffusionAlgorithm = CIFeedbackAlgorithm(system, cost, graph, T, honest) if fb else CIAlgorithm(system, cost, graph, T, honest=honest)
    return finish_design("ci", alg, variant, {"feedback": fb})


def check_feedback(v: Any, key: str) -> bool:
    """The ``feedback`` option: a bool (True or False; numpy bools accepted, nothing else)."""
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    raise ArgumentError(
        f"{key}: expected a bool, True (the fused estimate is the next prior: CI diffusion) or False (the published form: local "
        f"filters not changed by the fusion), found {v!r} of type {type(v).__name__}; give true or false",
        argument=key,
    )


FAMILY = _register_builtin(
    Family(
        name="ci",
        design=design_ci,
        title="Local Kalman filters fused by covariance intersection, trace-minimizing weights (Julier & Uhlmann 1997)",
        uses="graph",
        horizons=frozenset({"finite"}),
        analytic_cost=True,
        lossy_links=True,  # capabilities (registry.Family): its agents run over links that drop
        options=(
            Option(
                name="variant",
                default="honest",
                check=check_variant,
                doc=" | ".join(f"{k!r}: {d}" for k, d in VARIANTS.items()),
                choices=tuple(VARIANTS),
            ),
            Option(
                name="feedback",
                default=False,
                check=check_feedback,
                doc="False (published): local filters, CI fusion reported only | True: CI diffusion, the fused estimate and P_f are the next prior",
            ),
        ),
        example="design_ci(system, cost, graph, horizon=100, variant='honest')",
    )
)
