r"""Hybrid consensus on measurements and information, HCMCI (Battistelli, Chisci, Mugnai, Farina & Graziano, IEEE TAC 60(6), 2015).

Agent i, information-form prior (Ω̄_i, q̄_i = Ω̄_i x̄_i) (Ω̄_i(0) = Σ_x⁻¹,
x̄_i(0) = 0), novelty δΩ_i = C_iᵀR_i⁻¹C_i, δq_i = C_iᵀR_i⁻¹y_i, at step t:

.. math::

    (\Omega, q, \delta\Omega, \delta q)_i^{(l+1)} = \sum_{j\in N_i\cup\{i\}} \pi_{ij}\, (\Omega, q, \delta\Omega, \delta q)_j^{(l)}
    \quad (l < L), \\
    \Omega_i = \Omega_i^{(L)} + \omega\, \delta\Omega_i^{(L)}, \quad q_i = q_i^{(L)} + \omega\, \delta q_i^{(L)}, \quad
    \hat x_i = \Omega_i^{-1} q_i, \\
    \bar\Omega_i \leftarrow (A \Omega_i^{-1} A^\top + Q)^{-1}, \quad \bar x_i \leftarrow A \hat x_i,

with the paper's Metropolis weights π_ij (row-stochastic; π_ij = c_ji of
:func:`~teamkf.estimators.diffusion.diffusion_weights`) and ω = N (the number
of agents: with L → ∞ on a connected graph the novelties' average times N is
the total measurement information, the centralized filter). ẑ_i = L_i x̂_i.

Variants: ``ideal`` runs the L iterations inside the step; ``honest`` exchanges
once per step (one iteration): agent j sends (x̄_j(s), y_j(s)); agent i uses at
k = s + τ_ji the prior pair through the prediction with process noise and the
novelty of y_j(s) as a measurement of x(k) (delay compensation); the weights of
neighbours not yet heard go to the agent itself. ``iterations`` is then unused.

Counting the agents (``count``)
-------------------------------
``count="all"`` (default) is the published ω = N. ``count="heard"`` uses
ω_i(k) = m_i(k), the number of agents whose novelty entered agent i's average
at step k (itself and the neighbours heard; the L-hop in-neighbourhood for the
ideal variant; see :func:`~teamkf.estimators.icf.heard_counts`): an agent that
hears nobody is then exactly its own Kalman filter instead of one that counts
its measurement N times.

Unreliable links (:mod:`teamkf.simulation.links`)
-------------------------------------------------
On lossy links the agents run :meth:`HCMCIAlgorithm.agent_step_tolerant`, the
honest step over the neighbours that delivered, D_i(k):

* **weights**: π_ij for j ∈ D_i(k); the weight of a neighbour that delivered
  nothing goes to the agent itself, π'_ii = π_ii + Σ_{j∉D_i(k)} π_ij (the rule
  above for neighbours not yet heard; for Metropolis weights it is the
  re-assignment of a failed link's weight to the diagonal of Xiao, Boyd & Lall,
  IPSN 2005, which keeps the weights summing to 1);
* **consensus on information** (the priors): a packet carries (x̄_j(s), y_j(s))
  and, because Ω̄_j(s) now depends on what the sender received, Ω̄_j(s) itself
  (the paper exchanges (Ω, q)); the most recent packet of each sender in the
  inbox enters through the prediction with process noise from s to k;
* **consensus on measurements** (the novelties): every y_j(s) that arrived,
  on time or late, enters once with weight π_ij, as a measurement of x(k)
  (delay compensation), so no measurement is lost because its packet was late;
* the agent carries its prior information Ω̄_i (per run), so the next prior
  follows the information actually fused.

With nothing lost it is the honest variant (the same arithmetic, bit for bit).
With every packet lost (p = 1) π'_ii = 1 and Ω_i = Ω̄_i + ω C_iᵀR_i⁻¹C_i:
with ω = N the definition makes each agent the Kalman filter of its own
measurements with its measurement information counted N times (noise
covariance R_i/N) — ω = N assumes the novelty consensus averages N agents'
measurements.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .._linalg import inv
from ..exceptions import ArgumentError
from ..models import LinearGaussianSystem, TeamCost
from ..network.graph import CommGraph
from ._consensus_common import (
    COUNTS,
    VARIANTS,
    check_count,
    check_iterations,
    check_variant,
    diffusion_weights,
    finite_horizon,
    heard_counts,
    information_sources,
)
from .checks import check_graph, check_information_form, check_model
from .linear_team import Algorithm, LinearTeamDesign, compensate_information, delivered, finish_design, freshest
from .registry import Family, Option, _register_builtin

__all__ = ["design_hcmci"]


class HCMCIAlgorithm(Algorithm):
    state_kinds = {"xhat": "x"}
    payload_kinds = {"xbar": "x", "y": "y"}

    def __init__(
        self, system: LinearGaussianSystem, cost: TeamCost, graph: CommGraph, horizon: int, iterations: int, honest: bool, count: str = "all"
    ):
        super().__init__(system, cost, graph, horizon)
        if system.is_time_varying:
            raise ArgumentError("system: the 'hcmci' family needs a time-invariant model here", argument="system")
        self.honest, self.L = honest, (1 if honest else iterations)
        n, dx, T = system.n_agents, system.dx, horizon
        self.omega = float(n)
        self.count = count
        self.pi = diffusion_weights(graph, "metropolis").T  # pi[i, j]: agent i's weight on j
        self.src = information_sources(graph, T, honest)
        #: ω_i(k): N (published) or the number of agents heard (module docstring)
        self.om = np.full((n, T), float(n)) if count == "all" else heard_counts(graph, self.src, T, honest, self.L)
        self.ins = [list(graph.in_neighbors(i)) for i in range(n)]
        self.Obar = np.empty((n, T, dx, dx))
        self.Om = np.empty((n, T, dx, dx))
        self.w: dict[tuple[int, int], float] = {}  # honest: (i,k) -> self weight
        self.prior_c: dict[tuple[int, int, int, int], tuple[Any, Any]] = {}
        self.nov_c: dict[tuple[int, int, int, int], tuple[Any, Any]] = {}
        Obar = [np.linalg.inv(system.Sigma_x) for _ in range(n)]
        for k in range(T):
            for i in range(n):
                self.Obar[i, k] = Obar[i]
            dO = [self.compensated(j, k, k)[3] for j in range(n)]
            if honest:
                sent: dict[tuple[int, int], tuple[Any, Any]] = {}  # Obar_j(s) compensated to step k: the same for every receiver
                for i in range(n):
                    heard = {j for j, _ in self.src[i][k]}
                    wii = self.pi[i, i] + sum(self.pi[i, j] for j in self.ins[i] if j not in heard)
                    self.w[(i, k)] = wii
                    Oi, dOi = wii * self.Obar[i, k], wii * dO[i]
                    for j, s in self.src[i][k]:
                        if (j, s) not in sent:
                            sent[(j, s)] = compensate_information(system, self.Obar[j, s], s, k)
                        Yc, Tm = sent[(j, s)]
                        _, _, Gc, Yn = self.compensated(j, s, k)
                        self.prior_c[(i, k, j, s)] = (Yc, Tm)
                        self.nov_c[(i, k, j, s)] = (Yn, Gc)
                        Oi = Oi + self.pi[i, j] * Yc
                        dOi = dOi + self.pi[i, j] * Yn
                    self.Om[i, k] = Oi + self.om[i, k] * dOi
            else:
                Os = [self.Obar[i, k] for i in range(n)]
                ds = list(dO)
                for _ in range(self.L):
                    Os = [self.pi[i, i] * Os[i] + sum((self.pi[i, j] * Os[j] for j in self.ins[i]), np.zeros((dx, dx))) for i in range(n)]
                    ds = [self.pi[i, i] * ds[i] + sum((self.pi[i, j] * ds[j] for j in self.ins[i]), np.zeros((dx, dx))) for i in range(n)]
                for i in range(n):
                    self.Om[i, k] = Os[i] + self.om[i, k] * ds[i]
            for i in range(n):
                A = system.A_at(k)
                P = A @ np.linalg.inv(self.Om[i, k]) @ A.T + system.Q_at(k)
                Obar[i] = np.linalg.inv(0.5 * (P + P.T))
                Obar[i] = 0.5 * (Obar[i] + Obar[i].T)
        self.Ominv = np.linalg.inv(self.Om)
        self.schedules = {"Omega_prior": self.Obar, "Omega": self.Om}

    def _xbar(self, i: int, k: int, prev: dict | None, zero: Any) -> Any:
        return zero(self.system.dx) if prev is None else self.system.A_at(k - 1) @ prev["xhat"]

    def agent_step(self, i: int, k: int, prev: dict | None, y_i: Any, inbox: Any, zero: Any) -> tuple[dict, dict]:
        xbar = self._xbar(i, k, prev, zero)
        _, _, G, _ = self.compensated(i, k, k)
        wii = self.w[(i, k)]
        q = wii * (self.Obar[i, k] @ xbar)
        dq = wii * (G @ y_i)
        for j, s, p in inbox:
            _, Tm = self.prior_c[(i, k, j, s)]
            _, Gc = self.nov_c[(i, k, j, s)]
            q = q + self.pi[i, j] * (Tm @ p["xbar"])
            dq = dq + self.pi[i, j] * (Gc @ p["y"])
        xh = self.Ominv[i, k] @ (q + self.om[i, k] * dq)
        return {"xhat": xh}, {"xbar": xbar, "y": y_i}

    def agent_step_tolerant(self, i: int, k: int, prev: dict | None, y_i: Any, inbox: Any, zero: Any) -> tuple[dict, dict]:
        r"""Unreliable links: one HCMCI iteration over the neighbours that delivered (module docstring).

        With the carried prior (Ω̄_i, x̄_i) (Σ_x⁻¹ and 0 at the first step), π'_ii = π_ii + Σ_{j∉D} π_ij,
        (Ω̃_j, T_j) the prior pair of j's latest packet (sent at s_j) through the prediction to step k, and
        (G̃, Ỹ) each delivered y_j(s) as a measurement of x(k):

        .. math:: \Omega_i = \pi'_{ii}\bar\Omega_i + \sum_{j\in D}\pi_{ij}\tilde\Omega_j
                  + \omega\Big(\pi'_{ii} \delta\Omega_i + \sum_{(j,s)} \pi_{ij} \tilde Y_j(s)\Big), \quad
                  q_i = \pi'_{ii}\bar\Omega_i \bar x_i + \sum_{j\in D}\pi_{ij} T_j \bar x_j(s_j)
                  + \omega\Big(\pi'_{ii} \delta q_i + \sum_{(j,s)} \pi_{ij} \tilde G_j\, y_j(s)\Big),

        x̂_i = Ω_i⁻¹ q_i and Ω̄_i ← (A Ω_i⁻¹ Aᵀ + Q)⁻¹.

        Returns
        -------
        (state, payload) : state = {"xhat", "Obar": Ω̄_i(k+1)}, payload = {"xbar": x̄_i(k), "y": y_i(k), "Obar": Ω̄_i(k)}
        """
        sysm = self.system
        Obar = self.Obar[i, 0] if prev is None else prev.get("Obar", self.Obar[i, k])
        xbar = self._xbar(i, k, prev, zero)
        _, _, G, dO = self.compensated(i, k, k)
        pk = delivered(self.graph, i, inbox)
        heard = {j for j, _, _ in pk}
        wii = self.pi[i, i] + sum(self.pi[i, j] for j in self.ins[i] if j not in heard)
        Oi, dOi = wii * Obar, wii * dO
        q = wii * (Obar @ xbar)
        dq = wii * (G @ y_i)
        for j, s, p in freshest(pk):
            Yc, Tm = compensate_information(sysm, p["Obar"], s, k)
            Oi = Oi + self.pi[i, j] * Yc
            q = q + self.pi[i, j] * (Tm @ p["xbar"])
        for j, s, p in pk:
            _, _, Gc, Yn = self.compensated(j, s, k)
            dOi = dOi + self.pi[i, j] * Yn
            dq = dq + self.pi[i, j] * (Gc @ p["y"])
        om = self.omega if self.count == "all" else float(1 + len({j for j, _, _ in pk}))
        Om = Oi + om * dOi
        Om_inv = inv(Om)
        xh = Om_inv @ (q + om * dq)
        A = sysm.A_at(k)
        P = A @ Om_inv @ A.T + sysm.Q_at(k)
        On = inv(0.5 * (P + P.T))
        On = 0.5 * (On + On.T)
        return {"xhat": xh, "Obar": On}, {"xbar": xbar, "y": y_i, "Obar": Obar}

    def agent_step_runs(self, i: int, k: int, prev: dict | None, y_i: Any, slots: Any) -> tuple[dict, dict]:
        """:meth:`agent_step_tolerant` for every run of a block at once (:mod:`._runs`: the same numbers, run by run).

        ``prev``: None or the stacked state {"xhat": (R, d_x, 1), "Obar": (R, d_x, d_x)}; ``y_i`` (R, d_y, 1);
        ``slots``: the possible packets of the inbox with the runs that received each (:mod:`._runs`)."""
        from ._runs import compensate_information_runs, freshest_runs, heard, inv_runs, sym

        sysm, R, dx = self.system, y_i.shape[0], self.system.dx
        Obar = np.broadcast_to(self.Obar[i, 0], (R, dx, dx)) if prev is None else prev["Obar"]
        xbar = np.zeros((R, dx, 1)) if prev is None else sysm.A_at(k - 1) @ prev["xhat"]
        _, _, G, dO = self.compensated(i, k, k)
        hd = heard(slots, R)
        code = np.zeros(R, dtype=np.int64)  # which in-neighbours each run heard, as bits
        for b, j in enumerate(self.ins[i]):
            if j in hd:
                code |= hd[j].astype(np.int64) << b
        uniq, inv_code = np.unique(code, return_inverse=True)
        w = [self.pi[i, i] + sum(self.pi[i, j] for b, j in enumerate(self.ins[i]) if not (int(c) >> b) & 1) for c in uniq]
        wii = np.array(w, dtype=float)[inv_code].reshape(R, 1, 1)
        Oi, dOi = wii * Obar, wii * dO
        q = wii * (Obar @ xbar)
        dq = wii * (G @ y_i)
        for j, groups in freshest_runs(slots, R):
            for s, idx, p in groups:
                Yc, Tm = compensate_information_runs(sysm, p["Obar"][idx], s, k)
                Oi[idx] = Oi[idx] + self.pi[i, j] * Yc
                q[idx] = q[idx] + self.pi[i, j] * (Tm @ p["xbar"][idx])
        for j, s, m, p in slots:
            idx = np.flatnonzero(m)
            if not idx.size:
                continue
            _, _, Gc, Yn = self.compensated(j, s, k)
            dOi[idx] = dOi[idx] + self.pi[i, j] * Yn
            dq[idx] = dq[idx] + self.pi[i, j] * (Gc @ p["y"][idx])
        if self.count == "all":
            om: Any = self.omega
        else:
            nh = sum((hd[j].astype(np.int64) for j in hd), np.zeros(R, dtype=np.int64))
            om = (1.0 + nh).reshape(R, 1, 1)
        Om = Oi + om * dOi
        Om_inv = inv_runs(Om)
        xh = Om_inv @ (q + om * dq)
        A = sysm.A_at(k)
        P = A @ Om_inv @ A.T + sysm.Q_at(k)
        On = sym(inv_runs(sym(P)))
        return {"xhat": xh, "Obar": On}, {"xbar": xbar, "y": y_i, "Obar": Obar}

    def team_step(self, k: int, prev: list[dict | None], ys: list[Any], zero: Any) -> list[dict]:
        n = self.system.n_agents
        qs = [self.Obar[i, k] @ self._xbar(i, k, prev[i], zero) for i in range(n)]
        ds = [self.compensated(i, k, k)[2] @ ys[i] for i in range(n)]
        for _ in range(self.L):
            nq, nd = [], []
            for i in range(n):
                a, b = self.pi[i, i] * qs[i], self.pi[i, i] * ds[i]
                for j in self.ins[i]:
                    a = a + self.pi[i, j] * qs[j]
                    b = b + self.pi[i, j] * ds[j]
                nq.append(a)
                nd.append(b)
            qs, ds = nq, nd
        return [{"xhat": self.Ominv[i, k] @ (qs[i] + self.om[i, k] * ds[i])} for i in range(n)]


def design_hcmci(
    system: LinearGaussianSystem,
    cost: TeamCost,
    graph: CommGraph,
    horizon: int | None = None,
    *,
    iterations: int = 5,
    variant: str = "honest",
    count: str = "all",
) -> LinearTeamDesign:
    """Design the HCMCI filter with its exact team cost (module docstring).

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
        Consensus iterations per step (ideal variant; the honest one exchanges once per step).
    variant : "honest" (default) or "ideal"
        "honest": one exchange per step over the graph's delays, delay-compensated (realizable);
        "ideal": neighbours' current data within the step (a bound, not realizable on a delay graph).

    count : "all" or "heard"
        "all" (published): ω = N; "heard": the number of estimates actually heard (the local Kalman filter when
        none arrives).

    Returns
    -------
    LinearTeamDesign
        The per-step linear maps with the exact team cost (stage costs E[c(x(k), ẑ(k))]).

    Examples
    --------
    >>> from teamkf import LinearGaussianSystem, TeamCost, CommGraph, design_hcmci
    >>> d = design_hcmci(LinearGaussianSystem.platoon(4), TeamCost.platoon(4, 10.0), CommGraph.line(4), 10, iterations=3, variant="ideal")
    >>> d.info["iterations"]
    3
    """
    check_model(system, cost)
    check_information_form(system, "hcmci")
    check_graph(graph, system.n_agents)
    variant = check_variant(variant, "variant")
    L = check_iterations(iterations, "iterations")
    T = finite_horizon(horizon, "hcmci", system, cost)
    cnt = check_count(count, "hcmci.count")
    alg = HCMCIAlgorithm(system, cost, graph, T, L, honest=(variant == "honest"), count=cnt)
    return finish_design("hcmci", alg, variant, {"iterations": alg.L, "omega": alg.omega if cnt == "all" else "heard", "count": cnt})


FAMILY = _register_builtin(
    Family(
        name="hcmci",
        design=design_hcmci,
        title="Hybrid consensus on measurements and information (Battistelli et al. 2015), honest = one delay-compensated exchange per step",
        uses="graph",
        horizons=frozenset({"finite"}),
        analytic_cost=True,
        lossy_links=True,  # capabilities (registry.Family): its agents run over links that drop
        options=(
            Option(name="iterations", default=5, check=check_iterations, doc="consensus iterations L per step (ideal variant)"),
            Option(
                name="variant",
                default="honest",
                check=check_variant,
                doc=" | ".join(f"{k!r}: {d}" for k, d in VARIANTS.items()),
                choices=tuple(VARIANTS),
            ),
            Option(name="count", default="all", check=check_count, doc=" | ".join(f"{k!r}: {d}" for k, d in COUNTS.items()), choices=tuple(COUNTS)),
        ),
        example="design_hcmci(system, cost, graph, horizon=100, iterations=5, variant='ideal')",
    )
)
