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
from ..exceptions import NotPositiveDefiniteError
from ..models import LinearGaussianSystem, TeamCost
from ..network.graph import CommGraph
from ._consensus_common import VARIANTS, DiffusionAlgorithm, check_variant, ci_weights, finite_horizon, information_sources
from .checks import check_graph, check_information_form, check_model
from .linear_team import LinearTeamDesign, delivered, finish_design, freshest, process_noise
from .registry import Family, Option, _register_builtin

__all__ = ["design_ci", "ci_weights"]


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
        Ys = []
        for lnode, s in srcs:
            Phi = self.Phi(k, s)
            Pt = Phi @ self.P_filt[lnode, s] @ Phi.T + (process_noise(self.system, k, s) if s != k else 0.0)
            Ys.append(_information(Pt, lnode, s, k))
        key = tuple(np.round(Y, 12).tobytes() for Y in Ys)  # converged covariances: the same weights, solved once
        if key not in self._wcache:
            self._wcache[key] = ci_weights(Ys)
        w = self._wcache[key]
        Pf = np.linalg.inv(sum(wj * Y for wj, Y in zip(w, Ys)))
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

    def team_step(self, k: int, prev: list[dict | None], ys: list[Any], zero: Any) -> list[dict]:
        n = self.system.n_agents
        xl = {(i, k): self.adapt(i, k, self._prior(i, k, prev[i], zero), {(i, k): ys[i]}) for i in range(n)}
        return [{"xloc": xl[(i, k)], "xhat": self._fused(i, k, xl)} for i in range(n)]


def design_ci(
    system: LinearGaussianSystem, cost: TeamCost, graph: CommGraph, horizon: int | None = None, *, variant: str = "honest"
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
    """
    check_model(system, cost)
    check_information_form(system, "ci")
    check_graph(graph, system.n_agents)
    variant = check_variant(variant, "variant")
    T = finite_horizon(horizon, "ci", system, cost)
    alg = CIAlgorithm(system, cost, graph, T, honest=(variant == "honest"))
    return finish_design("ci", alg, variant)


FAMILY = _register_builtin(
    Family(
        name="ci",
        design=design_ci,
        title="Local Kalman filters fused by covariance intersection, trace-minimizing weights (Julier & Uhlmann 1997)",
        uses="graph",
        horizons=frozenset({"finite"}),
        analytic_cost=True,
        options=(
            Option(
                name="variant",
                default="honest",
                check=check_variant,
                doc=" | ".join(f"{k!r}: {d}" for k, d in VARIANTS.items()),
                choices=tuple(VARIANTS),
            ),
        ),
        example="design_ci(system, cost, graph, horizon=100, variant='honest')",
    )
)
