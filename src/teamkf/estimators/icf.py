r"""Information-weighted consensus filter, ICF (Kamal, Farrell & Roy-Chowdhury, IEEE TAC 58(12), 2013).

Agent i, N agents, prior (x̄_i, J̄_i) (J̄_i(0) = Σ_x⁻¹, x̄_i(0) = 0), at step t:

.. math::

    V_i^{0} = \tfrac1N \bar J_i + C_i^\top R_i^{-1} C_i, \qquad
    v_i^{0} = \tfrac1N \bar J_i \bar x_i + C_i^\top R_i^{-1} y_i, \\
    v_i^{(m+1)} = v_i^{(m)} + \epsilon \sum_{j\in N_i} (v_j^{(m)} - v_i^{(m)}), \quad
    V_i^{(m+1)} = V_i^{(m)} + \epsilon \sum_{j\in N_i} (V_j^{(m)} - V_i^{(m)}) \quad (m < K), \\
    \hat x_i = (V_i^{(K)})^{-1} v_i^{(K)}, \quad J_i = N V_i^{(K)}, \quad
    \bar J_i \leftarrow (A J_i^{-1} A^\top + Q)^{-1}, \quad \bar x_i \leftarrow A \hat x_i,

N_i the in-neighbours, 0 < ε < 1/Δ_max (Δ_max the maximum in-degree); ẑ_i = L_i x̂_i.

Variants: ``ideal`` runs the K consensus iterations inside the step (the
paper). ``honest`` has one exchange per step, hence one iteration: agent j
sends x̂_j(s) = V_j(s)⁻¹ v_j(s) (its pair after the step's iteration), agent i
uses it at k = s + τ_ji as the pair (V_j(s), v_j(s)) through the prediction with
process noise (:func:`~teamkf.estimators.linear_team.compensate_information`);
``iterations`` is then unused.

Counting the agents (``count``)
-------------------------------
``count="all"`` (default) is the published rule: the prior weight J̄_i/N and
J_i = N V_i assume that consensus averages all N agents. When an agent hears
fewer (one exchange per step, a sparse graph, lost packets), that counts its own
measurement N times; with nobody heard it is the Kalman filter of y_i with noise
covariance R_i/N. ``count="heard"`` replaces N by m_i(k), the number of agents
whose data entered agent i's pair at step k (itself and the neighbours heard:
1 + \|N_i(k)\| for the honest variant and on lossy links, the size of the K-hop
in-neighbourhood for the ideal one), so an agent that hears nobody is exactly
its own Kalman filter; with everybody heard it is the published rule.

Unreliable links (:mod:`teamkf.simulation.links`)
-------------------------------------------------
On lossy links the agents run :meth:`ICFAlgorithm.agent_step_tolerant`: the
one consensus iteration runs over the neighbours that delivered, D_i(k),

.. math::

    V_i = V_i^{0} + \epsilon \sum_{j\in D_i(k)} (\tilde V_j - V_i^{0}), \qquad
    v_i = v_i^{0} + \epsilon \sum_{j\in D_i(k)} (\tilde v_j - v_i^{0}),

i.e. the weight ε of a neighbour that delivered nothing stays with the agent
(self weight 1 - ε|D_i(k)| > 0: the consensus protocol on the graph of the
links that worked, as for switching topologies). A packet carries the
sender's pair: x̂_j(s) and, because its V_j(s) now depends on what *it*
received, V_j(s) itself (in the paper the agents exchange (v_j, V_j)); the
receiver uses the pair through the prediction with process noise from s to k
(:func:`~teamkf.estimators.linear_team.compensate_information`), on time or
late; of several packets of one sender in one inbox the most recent is used.
The agent carries its prior information J̄_i (per run), so the next step's
prior follows the information actually fused. With nothing lost it is the
honest variant (the same arithmetic, bit for bit). With every packet lost
(p = 1) V_i = J̄_i/N + C_iᵀR_i⁻¹C_i and J_i = N V_i: the definition makes
each agent the Kalman filter of its own measurements with its measurement
information counted N times (noise covariance R_i/N) — the ICF's weighting
J̄_i/N assumes that consensus will average N agents' measurements.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .. import _validation as V
from .._lazy import scipy_linalg as sla  # SciPy loads on first use
from .._linalg import inv
from ..exceptions import ArgumentError
from ..models import LinearGaussianSystem, TeamCost
from ..network.graph import CommGraph
from ._consensus_common import COUNTS, VARIANTS, check_count, check_iterations, check_variant, finite_horizon, heard_counts, information_sources
from .checks import check_graph, check_information_form, check_model
from .linear_team import Algorithm, LinearTeamDesign, compensate_information, delivered, finish_design, freshest
from .registry import Family, Option, _register_builtin

__all__ = ["design_icf", "check_iterations", "check_rate", "consensus_rate", "check_count", "COUNTS", "heard_counts"]


#: how the agents are counted (module docstring)
def check_rate(v: Any, key: str) -> float | None:
    """The ``epsilon`` option: the consensus rate (> 0; None picks one below 1 / max degree)."""
    return None if v is None else V.real(v, key, minimum=0.0, strict=True, what="a consensus rate")


def consensus_rate(graph: CommGraph, epsilon: Any, key: str = "epsilon") -> float:
    """ε checked against 0 < ε < 1/Δ_max (Δ_max: maximum in-degree); None gives 1/(Δ_max + 1)."""
    dmax = max((len(graph.in_neighbors(i)) for i in range(graph.n_agents)), default=0)
    if epsilon is None:
        return 1.0 / (dmax + 1)
    eps = check_rate(epsilon, key)
    assert eps is not None
    if dmax > 0 and eps >= 1.0 / dmax:
        raise ArgumentError(
            f"{key}: expected a consensus rate 0 < epsilon < 1/Delta_max = {1.0 / dmax:.6g} (this graph's maximum in-degree is {dmax}), found {eps:g}",
            argument=key,
        )
    return eps


class ICFAlgorithm(Algorithm):
    state_kinds = {"xhat": "x"}
    payload_kinds = {"xhat": "x"}

    def __init__(
        self,
        system: LinearGaussianSystem,
        cost: TeamCost,
        graph: CommGraph,
        horizon: int,
        epsilon: float,
        iterations: int,
        honest: bool,
        count: str = "all",
    ):
        super().__init__(system, cost, graph, horizon)
        self.honest, self.eps, self.K = honest, epsilon, iterations if not honest else 1
        n, dx, T = system.n_agents, system.dx, horizon
        self.src = information_sources(graph, T, honest)
        self.count = count
        #: m[i, k]: the number the agents are counted by (N published, or the agents heard)
        self.m = np.full((n, T), float(n)) if count == "all" else heard_counts(graph, self.src, T, honest, self.K)
        self.ins = [list(graph.in_neighbors(i)) for i in range(n)]
        self.G, self.U = [], []
        for j in range(n):
            C, R = system.C_at(j, 0), system.R_at(j, 0)
            g = sla.cho_solve(sla.cho_factor(R, lower=True), C).T
            self.G.append(g)
            self.U.append(g @ C)
        if system.is_time_varying:
            raise ArgumentError("system: the 'icf' family needs a time-invariant model here", argument="system")
        self.Jbar = np.empty((n, T, dx, dx))
        self.V0 = np.empty((n, T, dx, dx))
        self.Vf = np.empty((n, T, dx, dx))
        self.comp: dict[tuple[int, int, int, int], tuple[Any, Any]] = {}
        Jbar = [np.linalg.inv(system.Sigma_x) for _ in range(n)]
        for k in range(T):
            for i in range(n):
                self.Jbar[i, k] = Jbar[i]
                self.V0[i, k] = Jbar[i] / self.m[i, k] + self.U[i]
            if honest:
                sent: dict[tuple[int, int], tuple[Any, Any]] = {}  # V_j(s) compensated to step k: the same for every receiver
                for i in range(n):
                    Vi = self.V0[i, k].copy()
                    for j, s in self.src[i][k]:
                        if (j, s) not in sent:
                            sent[(j, s)] = compensate_information(system, self.Vf[j, s], s, k)
                        Yc, Tm = sent[(j, s)]
                        self.comp[(i, k, j, s)] = (Yc, Tm)
                        Vi = Vi + epsilon * (Yc - self.V0[i, k])
                    self.Vf[i, k] = Vi
            else:
                Vs = [self.V0[i, k] for i in range(n)]
                for _ in range(self.K):
                    Vs = [Vs[i] + epsilon * sum((Vs[j] - Vs[i] for j in self.ins[i]), np.zeros((dx, dx))) for i in range(n)]
                for i in range(n):
                    self.Vf[i, k] = Vs[i]
            for i in range(n):
                A = system.A_at(k)
                Jinv = np.linalg.inv(self.m[i, k] * self.Vf[i, k])
                Jbar[i] = np.linalg.inv(A @ Jinv @ A.T + system.Q_at(k))
                Jbar[i] = 0.5 * (Jbar[i] + Jbar[i].T)
        self.Vinv = np.linalg.inv(self.Vf)
        self.schedules = {"Jbar": self.Jbar, "V": self.Vf}

    def _v0(self, i: int, k: int, prev: dict | None, y_i: Any, zero: Any) -> Any:
        xbar = zero(self.system.dx) if prev is None else self.system.A_at(k - 1) @ prev["xhat"]
        return (self.Jbar[i, k] / self.m[i, k]) @ xbar + self.G[i] @ y_i

    def agent_step(self, i: int, k: int, prev: dict | None, y_i: Any, inbox: Any, zero: Any) -> tuple[dict, dict]:
        v0 = self._v0(i, k, prev, y_i, zero)
        v = v0
        for j, s, p in inbox:
            _, Tm = self.comp[(i, k, j, s)]
            v = v + self.eps * (Tm @ p["xhat"] - v0)
        xh = self.Vinv[i, k] @ v
        return {"xhat": xh}, {"xhat": xh}

    def agent_step_tolerant(self, i: int, k: int, prev: dict | None, y_i: Any, inbox: Any, zero: Any) -> tuple[dict, dict]:
        r"""Unreliable links: one consensus iteration over the neighbours that delivered (module docstring).

        With the carried prior information J̄_i (Σ_x⁻¹ at the first step), V_i⁰ = J̄_i/N + C_iᵀR_i⁻¹C_i,
        v_i⁰ = J̄_i x̄_i / N + C_iᵀR_i⁻¹y_i and, for each neighbour j that delivered (its latest packet, sent
        at s_j), its pair (V_j(s_j), V_j(s_j) x̂_j(s_j)) through the prediction to step k, (Ṽ_j, T_j x̂_j):

        .. math:: V_i = V_i^0 + \epsilon \sum_j (\tilde V_j - V_i^0), \quad
                  v_i = v_i^0 + \epsilon \sum_j (T_j \hat x_j(s_j) - v_i^0), \quad \hat x_i = V_i^{-1} v_i,

        J̄_i ← (A (N V_i)⁻¹ Aᵀ + Q)⁻¹.

        Returns
        -------
        (state, payload) : state = {"xhat", "Jbar": J̄_i(k+1)}, payload = {"xhat": x̂_i(k), "V": V_i(k)}
        """
        sysm, n = self.system, self.system.n_agents
        Jbar = self.Jbar[i, 0] if prev is None else prev.get("Jbar", self.Jbar[i, k])
        xbar = zero(sysm.dx) if prev is None else sysm.A_at(k - 1) @ prev["xhat"]
        fresh = freshest(delivered(self.graph, i, inbox))
        if self.count == "heard":
            n = 1 + len(fresh)
        V0 = Jbar / n + self.U[i]
        v0 = (Jbar / n) @ xbar + self.G[i] @ y_i
        Vi, v = V0.copy(), v0
        for _j, s, p in fresh:
            Yc, Tm = compensate_information(sysm, p["V"], s, k)
            Vi = Vi + self.eps * (Yc - V0)
            v = v + self.eps * (Tm @ p["xhat"] - v0)
        xh = inv(Vi) @ v
        A = sysm.A_at(k)
        Jinv = inv(n * Vi)
        Jn = inv(A @ Jinv @ A.T + sysm.Q_at(k))
        Jn = 0.5 * (Jn + Jn.T)
        return {"xhat": xh, "Jbar": Jn}, {"xhat": xh, "V": Vi}

    def agent_step_runs(self, i: int, k: int, prev: dict | None, y_i: Any, slots: Any) -> tuple[dict, dict]:
        """:meth:`agent_step_tolerant` for every run of a block at once (:mod:`._runs`: the same numbers, run by run).

        ``prev``: None or the stacked state {"xhat": (R, d_x, 1), "Jbar": (R, d_x, d_x)}; ``y_i`` (R, d_y, 1);
        ``slots``: the possible packets of the inbox with the runs that received each (:mod:`._runs`)."""
        from ._runs import compensate_information_runs, freshest_runs, heard, inv_runs, sym

        sysm, R, dx = self.system, y_i.shape[0], self.system.dx
        Jbar = np.broadcast_to(self.Jbar[i, 0], (R, dx, dx)) if prev is None else prev["Jbar"]
        xbar = np.zeros((R, dx, 1)) if prev is None else sysm.A_at(k - 1) @ prev["xhat"]
        n: Any = sysm.n_agents
        if self.count == "heard":
            hd = heard(slots, R)
            n = (1 + sum((hd[j].astype(np.int64) for j in hd), np.zeros(R, dtype=np.int64))).reshape(R, 1, 1)
        V0 = Jbar / n + self.U[i]
        v0 = (Jbar / n) @ xbar + self.G[i] @ y_i
        Vi, v = V0.copy(), v0.copy()
        for _j, groups in freshest_runs(slots, R):
            for s, idx, p in groups:
                Yc, Tm = compensate_information_runs(sysm, p["V"][idx], s, k)
                Vi[idx] = Vi[idx] + self.eps * (Yc - V0[idx])
                v[idx] = v[idx] + self.eps * (Tm @ p["xhat"][idx] - v0[idx])
        xh = inv_runs(Vi) @ v
        A = sysm.A_at(k)
        Jinv = inv_runs(n * Vi)
        Jn = sym(inv_runs(A @ Jinv @ A.T + sysm.Q_at(k)))
        return {"xhat": xh, "Jbar": Jn}, {"xhat": xh, "V": Vi}

    def team_step(self, k: int, prev: list[dict | None], ys: list[Any], zero: Any) -> list[dict]:
        n = self.system.n_agents
        vs = [self._v0(i, k, prev[i], ys[i], zero) for i in range(n)]
        for _ in range(self.K):
            new = []
            for i in range(n):
                acc = vs[i]
                for j in self.ins[i]:
                    acc = acc + self.eps * (vs[j] - vs[i])
                new.append(acc)
            vs = new
        return [{"xhat": self.Vinv[i, k] @ vs[i]} for i in range(n)]


def design_icf(
    system: LinearGaussianSystem,
    cost: TeamCost,
    graph: CommGraph,
    horizon: int | None = None,
    *,
    iterations: int = 5,
    epsilon: float | None = None,
    variant: str = "honest",
    count: str = "all",
) -> LinearTeamDesign:
    """Design the information-weighted consensus filter with its exact team cost (module docstring).

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
    iterations : int >= 1
        Consensus iterations K per step (ideal variant; the honest one exchanges once per step).
    epsilon : float in (0, 1/Δ_max), or None
        The consensus step; None gives 1/(Δ_max + 1), Δ_max the largest in-degree.
    variant : "honest" (default) or "ideal"
        "honest": one exchange per step over the graph's delays, delay-compensated (realizable);
        "ideal": neighbours' current data within the step (a bound, not realizable on a delay graph).

    count : "all" or "heard"
        "all" (published): the own measurement is weighted as if N agents were heard; "heard": by the number of
        estimates actually heard (the local Kalman filter when none arrives).

    Returns
    -------
    LinearTeamDesign
        The per-step linear maps with the exact team cost (stage costs E[c(x(k), ẑ(k))]).

    Examples
    --------
    >>> from teamkf import LinearGaussianSystem, TeamCost, CommGraph, design_icf
    >>> d = design_icf(LinearGaussianSystem.platoon(4), TeamCost.platoon(4, 10.0), CommGraph.line(4), 10, variant="ideal")
    >>> d.label
    'icf [ideal]'
    """
    check_model(system, cost)
    check_information_form(system, "icf")
    check_graph(graph, system.n_agents)
    variant = check_variant(variant, "variant")
    K = check_iterations(iterations, "iterations")
    eps = consensus_rate(graph, epsilon, key="icf.epsilon")
    T = finite_horizon(horizon, "icf", system, cost)
    cnt = check_count(count, "icf.count")
    alg = ICFAlgorithm(system, cost, graph, T, eps, K, honest=(variant == "honest"), count=cnt)
    return finish_design("icf", alg, variant, {"epsilon": eps, "iterations": alg.K, "count": cnt})


FAMILY = _register_builtin(
    Family(
        name="icf",
        design=design_icf,
        title="Information-weighted consensus filter (Kamal, Farrell & Roy-Chowdhury 2013), honest = one delay-compensated exchange per step",
        uses="graph",
        horizons=frozenset({"finite"}),
        analytic_cost=True,
        lossy_links=True,  # capabilities (registry.Family): its agents run over links that drop
        options=(
            Option(name="iterations", default=5, check=check_iterations, doc="consensus iterations K per step (ideal variant)"),
            Option(
                name="epsilon", default=None, check=check_rate, doc="consensus rate, 0 < epsilon < 1/max in-degree (default 1/(max in-degree + 1))"
            ),
            Option(
                name="variant",
                default="honest",
                check=check_variant,
                doc=" | ".join(f"{k!r}: {d}" for k, d in VARIANTS.items()),
                choices=tuple(VARIANTS),
            ),
            Option(name="count", default="all", check=check_count, doc=" | ".join(f"{k!r}: {d}" for k, d in COUNTS.items()), choices=tuple(COUNTS)),
        ),
        example="design_icf(system, cost, graph, horizon=100, iterations=5, variant='ideal')",
    )
)
