r"""Kalman-consensus filter (KCF) baseline (Olfati-Saber, CDC 2007; ``design/baselines.md``).

The team-MMSE paper (Afshari & Mahajan 2021, Section IV-A, its reference [17])
compares MTMSE filtering with a "consensus Kalman filter" whose team cost it
evaluates by Monte Carlo over 1000 sample paths. The KCF's gains do not depend
on the data, so its honest (delay-compensated) and ideal variants carry the
exact analytic team cost (:mod:`teamkf.estimators.linear_team`); the stale
variant (:class:`KCFDesign`) is evaluated by Monte Carlo.

Notation (steps 0-based, ``k = t - 1``)
---------------------------------------
=================  ==========================================================
symbol             meaning
=================  ==========================================================
x̄_i(k), P_i(k)     agent i's prior and its (nominal) covariance; x̄_i(0) = 0,
                   P_i(0) = Sigma_x
u_j(s), U_j(s)     C_j(s)' R_j(s)^-1 y_j(s),  C_j(s)' R_j(s)^-1 C_j(s)
J_i(k)             {i} ∪ the in-neighbours whose message is used at step k
N_i(k)             J_i(k) \ {i}
s_j                the step of j's message used by i at step k (``sources``)
S_i(k)             U_i(k) + Σ_{j∈N_i(k)} U_j(s_j)           (``S_fused``)
M_i(k)             (P_i^-1 + S_i)^-1                          (``M``)
γ_i(k)             ε / (1 + ||M_i||_F)                        (``gamma``)
x̂_i(k)             x̄_i + M_i (s_i - S_i x̄_i) + γ_i M_i Σ_{j∈N_i} (x̄_j(s_j) - x̄_i)
P_i(k+1)           A(k) M_i(k) A(k)' + Q(k)
x̄_i(k+1)           A(k) x̂_i(k)
ẑ_i(k)             L_i(k) x̂_i(k)
=================  ==========================================================

with s_i = u_i(k) + Σ_{j∈N_i(k)} u_j(s_j).

Three variants (``variant=``)
-----------------------------
``"honest"`` (default)
    Realizable on the delay graph, **delay-compensated** (``design/baselines.md``):
    agent j sends (y_j(s), x̄_j(s)) at step s; agent i uses it at k = s + τ_ji,
    y_j(s) through the prediction with process noise (its information pair about
    x(k): C̃ = C_j Φ(k,s)⁻¹, R̃ = R_j + C̃ Q(k,s) C̃ᵀ) and Φ(k, s) x̄_j(s) in the
    consensus term. Linear with data-independent gains: exact analytic cost
    (:class:`KCFAlgorithm` on :mod:`teamkf.estimators.linear_team`).
``"ideal"``
    The original paper's idealization: every in-neighbour's *current*
    (u_j(k), U_j(k), x̄_j(k)) is exchanged within the step (delays ignored).
    Not realizable on a delay graph (``graph_agents`` raises); exact analytic cost.
``"stale"``
    The behaviour of teamkf <= 0.2's "honest" KCF (:class:`KCFDesign`): at step
    k agent i uses the message (u_j, U_j, x̄_j) that j sent at s_j = k - τ_ji
    and fuses the stale u_j(s_j) as if it measured x(k) (no compensation), so on
    an unstable process its error grows like (Φ(k, k - τ) - I) x. Monte Carlo
    cost only (:meth:`KCFDesign.errors`). :func:`kcf_schedules` also builds the
    ideal variant this way (an independent implementation used as a test oracle).

For :class:`KCFDesign` the covariance recursion does not depend on data, so
M_i(k), γ_i(k), P_i(k) and S_i(k) are deterministic schedules computed at
design time. P_i is the *nominal* covariance of the KCF: it ignores the
consensus term and (stale variant) the staleness of the fused measurements.

Choice of ε
-----------
The default ``epsilon = 0.1`` is our choice (baselines.md leaves it open; the
KCF needs "a small consensus step"). Since γ_i ||M_i||_F < ε, the consensus
term of agent i is a correction of gain below ``ε · |N_i|``; with ε = 0.1 that is
below 1 for in-degrees up to 9, e.g. the complete graph of the ten-UAV
formation, so the consensus correction alone never overshoots. Larger graphs
may want a smaller ε.

Computing M_i without inverting P_i
-----------------------------------
P_i can be singular (e.g. a singular Sigma_x or Q). With C̃ = rows(C_j(s_j),
j ∈ J_i) and R̃ = diag(R_j(s_j)), S_i = C̃' R̃^-1 C̃ and (when P_i is
invertible) (P_i^-1 + S_i)^-1 is exactly the Kalman update of P_i with
(C̃, R̃); we compute it in Joseph form (:func:`teamkf.estimators.kalman.kalman_step`),
which needs only a Cholesky of the positive definite C̃ P_i C̃' + R̃, is
defined for singular P_i (it equals P_i (I + S_i P_i)^-1 there) and is
symmetric positive semi-definite by construction.

References
----------
.. [1] R. Olfati-Saber, "Distributed Kalman filtering for sensor networks",
   Proc. 46th IEEE CDC, 2007 (the Kalman-consensus filter).
.. [2] M. Afshari and A. Mahajan, team-MMSE filtering (2021), Section IV-A
   (the KCF as a baseline, Monte Carlo over 1000 sample paths).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal, NamedTuple, Sequence

import numpy as np

from .. import _validation as V
from .._lazy import scipy_linalg as sla  # SciPy / networkx load on first use
from .._linalg import block_diag
from .._validation import FloatArray
from ..exceptions import ArgumentError, InformationStructureError, ShapeError
from ..models import LinearGaussianSystem, TeamCost
from ..network.graph import CommGraph
from ._consensus_common import information_sources
from ._kalman_common import kalman_step
from .base import Design, check_measurements, check_paths
from .checks import check_graph, check_model
from .linear_team import Algorithm, delivered, finish_design, freshest, shared_schedules
from .registry import Family, Option, _register_builtin

__all__ = ["KCFDesign", "KCFAgent", "KCFMessage", "KCFAlgorithm", "design_kcf", "kcf_schedules", "VARIANTS"]

Variant = Literal["stale", "ideal"]

#: variant name -> one-line description (also stored in ``design.info``)
VARIANTS: dict[str, str] = {
    "honest": "one exchange per step over the graph's edges and delays; received (y_j(s), xbar_j(s)) delay-compensated to step k "
    "(information pair through the prediction with process noise, Phi(k, s) xbar_j(s)); realizable, exact analytic cost",
    "ideal": "neighbours' current (u_j(k), U_j(k), xbar_j(k)) exchanged within the step, delays ignored (Olfati-Saber's idealization; "
    "not realizable on a delay graph); exact analytic cost",
    "stale": "the previous 'honest': messages travel with the edge delay and the stale u_j(k - tau_ji), xbar_j(k - tau_ji) are fused as if "
    "current (no delay compensation; diverges on unstable processes); Monte Carlo cost only",
}


class KCFMessage(NamedTuple):
    """What a KCF agent sends at step k: its u_i(k), the step k (indexing the deterministic U_i(k)) and its prior x̄_i(k)."""

    u: FloatArray
    step: int
    xbar: FloatArray


def _update(xbar: FloatArray, s: FloatArray, S: FloatArray, M: FloatArray, gamma: float, neighbour_priors: Sequence[FloatArray]) -> FloatArray:
    """x̂ = x̄ + M (s - S x̄) + γ M Σ_j (x̄_j - x̄), batched over runs (the one kernel of both online paths)."""
    r = s - xbar @ S.T
    if neighbour_priors:
        cons = neighbour_priors[0] - xbar
        for xj in neighbour_priors[1:]:
            cons = cons + (xj - xbar)
        r = r + gamma * cons
    return xbar + r @ M.T  # type: ignore[no-any-return]


@dataclass(frozen=True, eq=False, kw_only=True)
class KCFDesign(Design):
    """The "stale" Kalman-consensus filter over a horizon of T steps (see the module docstring for the equations).

    ``design_kcf(..., variant="stale")`` returns it: delayed data fused as if current. Its
    team cost has no closed form and is evaluated by Monte Carlo; the "honest" and "ideal"
    variants return a :class:`~teamkf.LinearTeamDesign` with the exact cost instead.

    Parameters
    ----------
    estimator, horizon, system, cost, stage_costs, average_cost, info
        As in :class:`~teamkf.Design`: the family name, T (None for the steady state), the
        model, the team cost, the exact E[c(x(k), ẑ(k))] per step and the plain-data facts.
    graph : CommGraph
        The communication graph: agent i hears agent j over edge (j, i) after its integer delay τ_ji.
    variant : "stale"
        Neighbours' messages arrive with the edge delay and are fused as current
        (realizable, :meth:`graph_agents`).
    epsilon : float
        Consensus step ε of γ_i = ε / (1 + ||M_i||_F).
    P : (n, T, d_x, d_x)
        Priors' nominal covariances P_i(k).
    M : (n, T, d_x, d_x)
        M_i(k) = (P_i(k)^-1 + S_i(k))^-1.
    gamma : (n, T)
        γ_i(k).
    S_fused : (n, T, d_x, d_x)
        S_i(k) = Σ_{j∈J_i(k)} U_j(s_j), the information fused at step k.
    sources : tuple over agents of tuples over steps of ((j, s_j), ...)
        The in-neighbours whose message agent i uses at step k and the step it
        was sent (own measurement not listed).
    G, U : tuples of arrays
        Per agent, the information-form measurement terms G_i = C_iᵀ R_i⁻¹ and U_i = C_iᵀ R_i⁻¹ C_i.

    Notes
    -----
    ``stage_costs`` and ``average_cost`` are None: this variant's team cost has no
    closed form; evaluate it with :meth:`costs` over sampled paths (or :func:`~teamkf.monte_carlo`).

    Examples
    --------
    >>> from teamkf import LinearGaussianSystem, TeamCost, CommGraph, design_kcf
    >>> d = design_kcf(LinearGaussianSystem.platoon(4), TeamCost.platoon(4, 10.0), CommGraph.line(4), 10, variant="stale")
    >>> type(d).__name__, d.stage_costs is None, d.gamma.shape
    ('KCFDesign', True, (4, 10))
    """

    graph: CommGraph
    variant: Variant = "stale"
    epsilon: float = 0.1
    P: FloatArray
    M: FloatArray
    gamma: FloatArray
    S_fused: FloatArray
    sources: tuple[tuple[tuple[tuple[int, int], ...], ...], ...]
    G: tuple[FloatArray, ...]
    U: tuple[FloatArray, ...]

    # --- deterministic schedules ----------------------------------------------
    @property
    def n_agents(self) -> int:
        return int(self.system.n_agents)

    def G_at(self, j: int, s: int) -> FloatArray:
        """C_j(s)' R_j(s)^-1, shape (d_x, d_y^j): u_j(s) = G_j(s) y_j(s)."""
        g = self.G[j]
        return g[0] if g.shape[0] == 1 else g[s]  # type: ignore[no-any-return]

    def U_at(self, j: int, s: int) -> FloatArray:
        """U_j(s) = C_j(s)' R_j(s)^-1 C_j(s)."""
        u = self.U[j]
        return u[0] if u.shape[0] == 1 else u[s]  # type: ignore[no-any-return]

    # --- online: graph agents -------------------------------------------------
    def graph_agents(self) -> list["KCFAgent"]:
        """One message-passing agent per node for :func:`teamkf.simulation.runtime.run_graph` (honest variant only)."""
        if self.variant != "stale":
            raise self._unsupported(
                "graph_agents() for the 'ideal' variant",
                "the ideal KCF exchanges neighbours' current estimates within the step, which no delay graph can deliver; "
                "use design.filter(y) or design_kcf(..., variant='honest')",
            )
        return [KCFAgent(self, i) for i in range(self.n_agents)]

    def agents(self) -> list[Any]:
        raise self._unsupported(
            "agents()",
            "KCF agents exchange estimates, not measurement packets: run them with "
            "run_graph(design.graph_agents(), graph, y), or use design.filter(y) / design.errors(paths)",
        )

    def _filter(self, ys: list[FloatArray]) -> FloatArray:
        return self.simulate(ys)

    def details(self) -> dict[str, Any]:
        return {
            "epsilon": self.epsilon,
            "realizable": self.variant == "stale",
            "local_dims": None,
            "gain_shapes": {"M_i": [self.system.dx, self.system.dx]},
        }

    def arrays(self) -> dict[str, np.ndarray]:
        """The deterministic schedules: ``P`` (priors' nominal covariances), ``M``, ``gamma`` and ``S_fused``, each (n, T, ...)."""
        return {
            **super().arrays(),
            "P": np.asarray(self.P),
            "M": np.asarray(self.M),
            "gamma": np.asarray(self.gamma),
            "S_fused": np.asarray(self.S_fused),
        }

    # --- helpers --------------------------------------------------------------
    def _check_y(self, y: Any) -> tuple[list[FloatArray], int, int]:
        ys, n_runs, T, _ = check_measurements(y, self.system, self.horizon)
        return ys, n_runs, T

    # --- vectorized simulation ----------------------------------------------
    def simulate(self, y: Any) -> FloatArray:
        """Every agent's estimate straight from the measurements (both variants).

        Parameters
        ----------
        y : list over agents of (n_runs, T', d_y^i) arrays (T' <= horizon), or a ``Paths``

        Returns
        -------
        z : (n_runs, T', n d_z), agent-major. For the honest variant it equals
            ``run_graph(design.graph_agents(), graph, y)``.
        """
        ys, n_runs, T = self._check_y(y)
        n, dx, sys, cost = self.n_agents, self.system.dx, self.system, self.cost
        keep = 1 + max((d for (_, _, d) in self.graph.edges), default=0)
        u: dict[tuple[int, int], FloatArray] = {}
        xbar: dict[tuple[int, int], FloatArray] = {(i, 0): np.zeros((n_runs, dx)) for i in range(n)}
        out = np.empty((n_runs, T, n * cost.dz))
        for k in range(T):
            for j in range(n):
                u[(j, k)] = ys[j][:, k] @ self.G_at(j, k).T
            for i in range(n):
                src = self.sources[i][k]
                s_i = u[(i, k)]
                for j, sj in src:
                    s_i = s_i + u[(j, sj)]
                xh = _update(xbar[(i, k)], s_i, self.S_fused[i, k], self.M[i, k], float(self.gamma[i, k]), [xbar[(j, sj)] for (j, sj) in src])
                out[:, k, i * cost.dz : (i + 1) * cost.dz] = xh @ cost.L_block(i, k).T
                if k + 1 < T:
                    xbar[(i, k + 1)] = xh @ sys.A_at(k).T
            for j in range(n):
                u.pop((j, k - keep), None)
                xbar.pop((j, k - keep), None)
        return out

    # --- cancellation-free errors --------------------------------------------
    def errors(self, paths: Any) -> FloatArray:
        r"""Team errors e(k) = L x(k) - ẑ(k), (n_runs, T', n d_z), from the primitive noises.

        Forming x - x̂ from simulated states cancels catastrophically when x is
        large (an unstable process: ``|x(99)| ~ 1e19`` for the ten-UAV formation,
        so x - x̂ keeps no digit). Instead each agent's prior error
        ẽ_i(k) = x(k) - x̄_i(k) is propagated by a recursion in the noises.

        Derivation. Write y_j(s) = C_j(s) x(s) + v_j(s), G_j(s) = C_j(s)' R_j(s)^-1,
        U_j(s) = G_j(s) C_j(s), and δ_j(k) = x(k) - x(s_j) (zero for j = i and
        for the ideal variant, where s_j = k). Then::

            s_i - S_i x̄_i = Σ_{j∈J_i} G_j (y_j(s_j) - C_j x̄_i(k))
                          = Σ_{j∈J_i} [U_j (ẽ_i(k) - δ_j(k)) + G_j v_j(s_j)]
                          = S_i ẽ_i + Σ_{j∈J_i} G_j v_j(s_j) - Σ_{j∈N_i} U_j δ_j,
            x̄_j(s_j) - x̄_i(k) = (x(s_j) - ẽ_j(s_j)) - (x(k) - ẽ_i(k))
                              = ẽ_i(k) - ẽ_j(s_j) - δ_j(k),

        so with e_i⁺ = x(k) - x̂_i(k)::

            e_i⁺ = ẽ_i - M_i [S_i ẽ_i + Σ_{j∈J_i} G_j v_j(s_j) - Σ_{j∈N_i} U_j δ_j]
                       - γ_i M_i Σ_{j∈N_i} (ẽ_i - ẽ_j(s_j) - δ_j),
            ẽ_i(k+1) = A(k) e_i⁺ + w(k),   ẽ_i(0) = x(0)   (x̄_i(0) = 0),

        and e_i(k) = L_i(k) e_i⁺. For the ideal variant every δ_j = 0: a
        recursion in x(0), w and v only. For the honest variant δ_j(k) is a
        genuine error term (a delayed measurement of x(s_j) fused as one of
        x(k)); it is of the order of x on an unstable process, and so is the
        honest KCF's error: nothing cancels there. We form it without the
        difference x(k) - x(s_j) of two large numbers, by telescoping
        x(s+1) - x(s) = (A(s) - I) x(s) + w(s)::

            δ_j(k) = Σ_{s=s_j}^{k-1} [(A(s) - I) x(s) + w(s)],

        accurate to round-off relative to ``|A - I| |x| + |w|`` (better than
        relative to ``|x|`` when A is close to I).

        Parameters
        ----------
        paths : ``teamkf.simulation.sampling.Paths`` (x, y, w, v), T' <= horizon steps
        """
        check_paths(paths, self.system)
        n, dx, sys, cost = self.n_agents, self.system.dx, self.system, self.cost
        x = V.as_float_array(paths.x, "paths.x")
        if x.ndim != 3 or x.shape[2] != dx:
            raise ShapeError(f"paths.x: expected shape (n_runs, n_steps, {dx}), found {x.shape}")
        n_runs, T = x.shape[:2]
        if T > self.horizon:  # type: ignore[operator]
            raise ShapeError(f"paths: expected at most horizon = {self.horizon} steps, found {T}")
        w = np.asarray(paths.w, dtype=float)
        v = [np.asarray(vi, dtype=float) for vi in paths.v]
        if w.shape != (n_runs, max(T - 1, 0), dx) or len(v) != n or any(vi.shape != (n_runs, T, sys.dy[i]) for i, vi in enumerate(v)):
            raise ShapeError(
                f"paths: expected w of shape {(n_runs, max(T - 1, 0), dx)} and {n} noise arrays v[i] of shape "
                f"(n_runs, {T}, d_y^i), found w {w.shape} and {[vi.shape for vi in v]}"
            )
        keep = 1 + max((d for (_, _, d) in self.graph.edges), default=0)
        eye = np.eye(dx)
        incr: dict[int, FloatArray] = {}  # x(s+1) - x(s)
        delta: dict[tuple[int, int], FloatArray] = {}  # (k, tau) -> x(k) - x(k - tau)
        Gv: dict[tuple[int, int], FloatArray] = {}
        et: dict[tuple[int, int], FloatArray] = {(i, 0): x[:, 0].copy() for i in range(n)}
        out = np.empty((n_runs, T, n * cost.dz))

        def delta_at(k: int, tau: int) -> FloatArray:
            if (k, tau) not in delta:
                acc = incr[k - tau]
                for s in range(k - tau + 1, k):
                    acc = acc + incr[s]
                delta[(k, tau)] = acc
            return delta[(k, tau)]

        for k in range(T):
            if k + 1 < T:
                incr[k] = x[:, k] @ (sys.A_at(k) - eye).T + w[:, k]
            for j in range(n):
                Gv[(j, k)] = v[j][:, k] @ self.G_at(j, k).T
            for i in range(n):
                src = self.sources[i][k]
                ei = et[(i, k)]
                r = ei @ self.S_fused[i, k].T + Gv[(i, k)]
                cons = np.zeros_like(ei)
                for j, sj in src:
                    r = r + Gv[(j, sj)]
                    c = ei - et[(j, sj)]
                    if sj != k:
                        d = delta_at(k, k - sj)
                        r = r - d @ self.U_at(j, sj).T
                        c = c - d
                    cons = cons + c
                ep = ei - (r + float(self.gamma[i, k]) * cons) @ self.M[i, k].T
                out[:, k, i * cost.dz : (i + 1) * cost.dz] = ep @ cost.L_block(i, k).T
                if k + 1 < T:
                    et[(i, k + 1)] = ep @ sys.A_at(k).T + w[:, k]
            for j in range(n):
                et.pop((j, k - keep), None)
                Gv.pop((j, k - keep), None)
            incr.pop(k - keep, None)
            for key in [key for key in delta if key[0] < k]:
                del delta[key]
        return out

    def costs(self, paths: Any) -> FloatArray:
        """Team cost c(x(k), ẑ(k)) = e' S e per run and step, (n_runs, T'), from :meth:`errors`.

        The Monte Carlo team cost J_T is ``costs(paths).sum(axis=1).mean()``.
        """
        e = self.errors(paths)
        return np.stack([np.einsum("ra,ab,rb->r", e[:, k], self.cost.S_at(k), e[:, k]) for k in range(e.shape[1])], axis=1)


class KCFAgent:
    """Agent i of the honest KCF on the message-passing runtime.

    Its state holds only its own prior x̄_i (n_runs, d_x). At step k it
    receives y_i(k) and the messages :class:`KCFMessage` (u_j, s, x̄_j) its
    in-neighbours sent at s = k - tau_ji, returns ẑ_i(k) = L_i x̂_i(k) and sends
    (u_i(k), k, x̄_i(k)) — U_i(k) is the deterministic schedule entry of step k.
    """

    def __init__(self, design: KCFDesign, index: int, *, tolerant: bool = False):
        self.design = design
        self.index = index
        self.system: LinearGaussianSystem = design.system
        self.cost: TeamCost = design.cost
        #: on unreliable links (teamkf.simulation.links): fuse the messages that did arrive, whatever step
        #: they were sent at, with S_i = U_i + Σ_delivered U_j, M_i = P_i (I + S_i P_i)^-1 and
        #: γ_i = ε / (1 + ||M_i||_F) recomputed, and P_i(k+1) = A M_i A' + Q propagated in the state
        self.tolerant = tolerant

    def init_state(self, n_runs: int) -> dict[str, FloatArray]:
        return {"xbar": np.zeros((n_runs, self.system.dx))}

    def step(
        self, state: dict[str, FloatArray], k: int, own: FloatArray, inbox: Sequence[Any]
    ) -> tuple[dict[str, FloatArray], FloatArray, KCFMessage]:
        d, i = self.design, self.index
        if k >= d.horizon:  # type: ignore[operator]
            raise ShapeError(f"k: the KCF was designed for horizon = {d.horizon} steps, found step {k}; design a longer horizon")
        if self.tolerant:
            return self._step_tolerant(state, k, own, inbox)
        src = d.sources[i][k]
        got = {(j, s): p for (j, s, p) in inbox}
        if sorted(got) != sorted(src):
            raise InformationStructureError(
                f"KCF agent {i} at step {k}: expected messages {sorted(src)} (sender, sent step) as designed on the graph, "
                f"found {sorted(got)}; run it on the graph it was designed for"
            )
        xbar = state["xbar"]
        u_i = np.asarray(own, dtype=float) @ d.G_at(i, k).T
        s_i = u_i
        for key in src:
            s_i = s_i + got[key].u
        xh = _update(xbar, s_i, d.S_fused[i, k], d.M[i, k], float(d.gamma[i, k]), [got[key].xbar for key in src])
        z = xh @ self.cost.L_block(i, k).T
        nxt = xh @ self.system.A_at(k).T if k + 1 < d.horizon else xh  # type: ignore[operator]
        return {"xbar": nxt}, z, KCFMessage(u_i, k, xbar)

    def restart_state(self, n_runs: int, k: int) -> dict[str, FloatArray]:
        """A fresh agent at step ``k`` (a restarted process, ``teamkf agent --rejoin``): the design's prior at k.

        The prior mean of x(k) (zero: known means are removed from y and added back to ẑ) and its
        covariance Π(k), Π(0) = Σ_x, Π(s+1) = A(s) Π(s) A(s)' + Q(s), as the loss-tolerant step's
        ``P``; only that step keeps ``P`` (``tolerant``), so a restart needs it.
        """
        sys = self.system
        P = np.array(sys.Sigma_x, dtype=float)
        for s in range(int(k)):
            P = sys.A_at(s) @ P @ sys.A_at(s).T + sys.Q_at(s)
            P = 0.5 * (P + P.T)
        return {"xbar": np.zeros((n_runs, sys.dx)), "P": P}

    def _step_tolerant(
        self, state: dict[str, FloatArray], k: int, own: FloatArray, inbox: Sequence[Any]
    ) -> tuple[dict[str, FloatArray], FloatArray, KCFMessage]:
        """The KCF update with the neighbours whose messages arrived (see ``tolerant``)."""
        d, i, sys = self.design, self.index, self.system
        xbar = state["xbar"]
        P = state.get("P", sys.Sigma_x)
        u_i = np.asarray(own, dtype=float) @ d.G_at(i, k).T
        s_i, S = u_i, d.U_at(i, k)
        for j, _, msg in inbox:
            s_i = s_i + msg.u
            S = S + d.U_at(j, msg.step)
        M = np.linalg.solve((np.eye(sys.dx) + S @ P).T, P.T).T  # P (I + S P)^-1 = (P^-1 + S)^-1
        M = 0.5 * (M + M.T)
        gamma = d.epsilon / (1.0 + float(np.linalg.norm(M)))
        xh = _update(xbar, s_i, S, M, gamma, [msg.xbar for _, _, msg in inbox])
        z = xh @ self.cost.L_block(i, k).T
        last = k + 1 >= d.horizon  # type: ignore[operator]
        A = sys.A_at(k) if not last else np.eye(sys.dx)
        Pn = A @ M @ A.T + (sys.Q_at(k) if not last else 0.0)
        return {"xbar": xh @ A.T, "P": 0.5 * (Pn + Pn.T)}, z, KCFMessage(u_i, k, xbar)


def _epsilon(epsilon: Any, name: str = "epsilon") -> float:
    return V.positive_float(epsilon, name, what="a consensus step")


def kcf_schedules(
    system: LinearGaussianSystem, cost: TeamCost, graph: CommGraph, horizon: int | None, *, epsilon: float = 0.1, variant: Variant = "stale"
) -> KCFDesign:
    """The nominal KCF of the original implementation, without delay compensation (variants "stale" and "ideal").

    ``design_kcf(..., variant="stale")`` returns it; its "ideal" variant is an
    independent implementation of the ideal KCF (a test oracle of the
    exact-cost one). Deterministic schedules M_i(k), γ_i(k), P_i(k), S_i(k).

    Parameters
    ----------
    system, cost
    graph : CommGraph
        Who talks to whom and with which delay (strong connectivity is not
        required; its size must match the system's).
    horizon : int
        Number of steps T. A steady-state KCF is not provided (None raises).
    epsilon : float > 0
        Consensus step ε, γ_i = ε / (1 + ||M_i||_F). The default 0.1 is our
        choice: it keeps ε · in-degree < 1 up to in-degree 9 (module docstring).
    variant : "honest" or "ideal"
        "honest": neighbours' messages arrive with the edge delay (realizable;
        ``graph_agents()`` + ``run_graph``). "ideal": neighbours' current
        messages within the step (the original idealization; ``simulate`` only).

    Examples
    --------
    >>> from teamkf import LinearGaussianSystem, TeamCost, CommGraph
    >>> from teamkf.estimators.kcf import kcf_schedules
    >>> d = kcf_schedules(LinearGaussianSystem.platoon(4), TeamCost.platoon(4, 10.0), CommGraph.line(4), 20)
    >>> d.estimator, d.horizon, d.info["variant"], d.stage_costs is None
    ('kcf', 20, 'stale', True)
    """
    check_model(system, cost)
    n = system.n_agents
    check_graph(graph, n)
    V.choice(variant, "variant", ("stale", "ideal"))
    eps = _epsilon(epsilon)
    if horizon is None:
        raise ArgumentError(
            "horizon: the KCF has no steady-state (infinite-horizon) design here, found horizon=None; "
            "give a finite number of steps T (its cost is evaluated by Monte Carlo over T steps)",
            argument="horizon",
        )
    T = V.positive_int(horizon, "horizon")
    system.require_horizon(T)
    cost.require_horizon(T)
    dx = system.dx

    # per-agent local information maps G_j(s) = C_j' R_j^-1 and U_j(s) = G_j C_j
    G, U = [], []
    for j in range(n):
        constant = system.C[j].shape[0] == 1 and system.R[j].shape[0] == 1
        Gj, Uj = [], []
        for s in range(1 if constant else T):
            C, R = system.C_at(j, s), system.R_at(j, s)
            g = sla.cho_solve(sla.cho_factor(R, lower=True), C).T
            Gj.append(g)
            Uj.append(0.5 * (g @ C + (g @ C).T))
        G.append(V.frozen(np.stack(Gj)))
        U.append(V.frozen(np.stack(Uj)))

    ins = [[(j, graph.delay(j, i)) for j in graph.in_neighbors(i)] for i in range(n)]
    if variant == "stale":
        sources = tuple(tuple(tuple((j, k - d) for (j, d) in ins[i] if k - d >= 0) for k in range(T)) for i in range(n))
    else:
        sources = tuple(tuple(tuple((j, k) for (j, _) in ins[i]) for k in range(T)) for i in range(n))

    P = np.empty((n, T, dx, dx))
    M = np.empty((n, T, dx, dx))
    S_f = np.empty((n, T, dx, dx))
    gam = np.empty((n, T))
    from .._resources import progress as _progress

    for i in range(n):
        P[i, 0] = system.Sigma_x
        for k in _progress(range(T), total=T, desc=f"kcf design, agent {i}"):  # stderr after 2 s, terminals only
            fused = [(i, k), *sources[i][k]]
            Ct = np.vstack([system.C_at(j, s) for (j, s) in fused])
            Rt = block_diag(*[system.R_at(j, s) for (j, s) in fused])
            _, Mk = kalman_step(P[i, k], Ct, Rt)  # (P^-1 + S)^-1 in Joseph form, P may be singular
            M[i, k] = Mk
            Sk = np.zeros((dx, dx))
            for j, s in fused:
                Sk = Sk + (U[j][0] if U[j].shape[0] == 1 else U[j][s])
            S_f[i, k] = Sk
            gam[i, k] = eps / (1.0 + np.linalg.norm(Mk, "fro"))
            if k + 1 < T:
                A = system.A_at(k)
                Pn = A @ Mk @ A.T + system.Q_at(k)
                P[i, k + 1] = 0.5 * (Pn + Pn.T)
    info = {
        "variant": variant,
        "epsilon": eps,
        "variant_description": VARIANTS[variant],
        "realizable": variant == "stale",
        "cost_method": "monte-carlo",
    }
    return KCFDesign(
        estimator="kcf",
        horizon=T,
        info=info,
        system=system,
        cost=cost,
        graph=graph,
        variant=variant,
        epsilon=eps,
        P=V.frozen(P),
        M=V.frozen(M),
        gamma=V.frozen(gam),
        S_fused=V.frozen(S_f),
        sources=sources,
        G=tuple(G),
        U=tuple(U),
    )


class KCFAlgorithm(Algorithm):
    r"""The KCF on columns, delay-compensated (honest) or within the step (ideal); exact cost by :mod:`.linear_team`.

    Agent i at step k, with J_i = {i} ∪ sources (l, s) (s = k - τ_li once arrived; s = k ideal):
    (G̃, Y) of y_l(s) as a measurement of x(k) (:func:`.linear_team.compensated_measurement`),
    S_i = Σ Y, M_i = (P_i⁻¹ + S_i)⁻¹, γ_i = ε / (1 + ‖M_i‖_F),

    .. math:: \hat x_i = \bar x_i + M_i\Big(\sum_{J_i} \tilde G\, y_l(s) - S_i \bar x_i\Big)
              + \gamma_i M_i \sum_{(l,s)} (\Phi(k,s)\, \bar x_l(s) - \bar x_i),

    P_i ← A M_i Aᵀ + Q, x̄_i ← A x̂_i. It sends (y_i(k), x̄_i(k)).
    """

    state_kinds = {"xhat": "x"}
    payload_kinds = {"y": "y", "xbar": "x"}

    def __init__(self, system: LinearGaussianSystem, cost: TeamCost, graph: CommGraph, horizon: int, epsilon: float, honest: bool):

        super().__init__(system, cost, graph, horizon)
        self.honest, self.epsilon = honest, epsilon
        T = horizon
        self.src = information_sources(graph, T, honest)
        # the nominal covariances do not depend on ε: shared by the designs of one system (an ε grid)
        self.gain, self.M, self.S, self.P, norms = shared_schedules(self, "_teamkf_kcf_nominal", self._nominal)
        self.gamma = epsilon / (1.0 + norms)
        self.schedules = {"P": self.P, "M": self.M, "gamma": self.gamma, "S_fused": self.S}

    def _nominal(self) -> tuple[dict[tuple[int, int, int, int], tuple[FloatArray, FloatArray]], FloatArray, FloatArray, FloatArray, FloatArray]:
        """Gains (G̃, Y) of every fused y_l(s), M_i(k), S_i(k), P_i(k) and ‖M_i(k)‖_F (read-only arrays)."""
        system, T = self.system, self.horizon
        n, dx = system.n_agents, system.dx
        gain: dict[tuple[int, int, int, int], tuple[FloatArray, FloatArray]] = {}
        Ms, Ss, Ps = np.empty((n, T, dx, dx)), np.empty((n, T, dx, dx)), np.empty((n, T, dx, dx))
        for i in range(n):
            P = system.Sigma_x
            for k in range(T):
                Ps[i, k] = P
                Cs, Rs, S = [], [], np.zeros((dx, dx))
                for lnode, s in [(i, k), *self.src[i][k]]:
                    Ct, Rt, G, Y = self.compensated(lnode, s, k)
                    gain[(i, k, lnode, s)] = (G, Y)
                    Cs.append(Ct)
                    Rs.append(Rt)
                    S = S + Y
                _, M = kalman_step(P, np.vstack(Cs), block_diag(*Rs))  # (P^-1 + S)^-1 in Joseph form
                Ms[i, k], Ss[i, k] = M, S
                if k + 1 < T:
                    A = system.A_at(k)
                    P = A @ M @ A.T + system.Q_at(k)
                    P = 0.5 * (P + P.T)
        # ‖M‖_F one matrix at a time, as the agents' step for lost packets computes it (bit for bit the same γ)
        norms = np.array([[np.linalg.norm(Ms[i, k], "fro") for k in range(T)] for i in range(n)]).reshape(n, T)
        for a in (Ms, Ss, Ps, norms):
            a.setflags(write=False)
        return gain, Ms, Ss, Ps, norms

    def _prior(self, i: int, k: int, prev: dict | None, zero: Any) -> Any:
        return zero(self.system.dx) if prev is None else self.system.A_at(k - 1) @ prev["xhat"]

    def update(self, i: int, k: int, xbar: Any, ys: dict, xbars: dict) -> Any:
        r = None
        for lnode, s in [(i, k), *self.src[i][k]]:
            G, Y = self.gain[(i, k, lnode, s)]
            term = G @ ys[(lnode, s)] - Y @ xbar
            r = term if r is None else r + term
        for lnode, s in self.src[i][k]:
            r = r + self.gamma[i, k] * (self.Phi(k, s) @ xbars[(lnode, s)] - xbar)
        return xbar + self.M[i, k] @ r

    def agent_step_tolerant(self, i: int, k: int, prev: dict | None, y_i: Any, inbox: Any, zero: Any) -> tuple[dict, dict]:
        """Unreliable links: Olfati-Saber's update with the messages that arrived.

        The agent keeps its own nominal prior covariance P_i (a per-run quantity now) and recomputes
        M_i = (P_i⁻¹ + S_i)⁻¹ and γ_i from the information that arrived: every delivered y_l(s) is fused
        once, delay-compensated from its sent step s (late ones too, as the honest step compensates
        the nominal delay), and the consensus term uses the latest prior x̄_l(s) of each neighbour
        that delivered, propagated by Φ(k, s); a lost message takes no part in either. With every
        message lost the agent is its own Kalman filter on y_i alone. Nothing lost: the design's
        arithmetic, in its order (``delivered`` sorts the inbox as the nominal runtime delivers it).
        """
        xbar = self._prior(i, k, prev, zero)
        P = self.system.Sigma_x if prev is None else prev["P"]
        pk = delivered(self.graph, i, inbox)
        r, M = self.fuse_delivered(i, k, xbar, P, y_i, pk)
        gamma = self.epsilon / (1.0 + np.linalg.norm(M, "fro"))
        for _, s, p in freshest(pk):
            r = r + gamma * (self.Phi(k, s) @ p["xbar"] - xbar)
        xh = xbar + M @ r
        A = self.system.A_at(k)
        P_next = A @ M @ A.T + self.system.Q_at(k)
        return {"xhat": xh, "P": 0.5 * (P_next + P_next.T)}, {"y": y_i, "xbar": xbar}

    def agent_step_runs(self, i: int, k: int, prev: dict | None, y_i: Any, slots: Any) -> tuple[dict, dict]:
        """:meth:`agent_step_tolerant` for every run of a block at once (:mod:`._runs`: the same numbers, run by run)."""
        from ._runs import freshest_runs, fuse_delivered_runs, sym

        sysm, R, dx = self.system, y_i.shape[0], self.system.dx
        xbar = np.zeros((R, dx, 1)) if prev is None else sysm.A_at(k - 1) @ prev["xhat"]
        P = np.broadcast_to(sysm.Sigma_x, (R, dx, dx)) if prev is None else prev["P"]
        r, M = fuse_delivered_runs(self, i, k, xbar, P, y_i, slots)
        gamma = np.array([self.epsilon / (1.0 + np.linalg.norm(M[q], "fro")) for q in range(R)]).reshape(R, 1, 1)
        for _j, groups in freshest_runs(slots, R):
            for s, idx, p in groups:
                r[idx] = r[idx] + gamma[idx] * (self.Phi(k, s) @ p["xbar"][idx] - xbar[idx])
        xh = xbar + M @ r
        A = sysm.A_at(k)
        return {"xhat": xh, "P": sym(A @ M @ A.T + sysm.Q_at(k))}, {"y": y_i, "xbar": xbar}

    def agent_restart(self, i: int, k: int, zero: Any) -> dict:
        """The state of a fresh agent i at step k > 0 (a restarted process, ``teamkf agent --rejoin``): the prior of x(k).

        Its mean is zero (known means are removed from y and added back to ẑ), so x̂ = 0 gives x̄_i(k) = 0, and its
        covariance is Π(k), Π(0) = Σ_x, Π(s+1) = A(s) Π(s) A(s)ᵀ + Q(s): the loss-tolerant step's P from there.
        """
        P = np.array(self.system.Sigma_x, dtype=float)
        for s in range(int(k)):
            A = self.system.A_at(s)
            P = A @ P @ A.T + self.system.Q_at(s)
            P = 0.5 * (P + P.T)
        return {"xhat": zero(self.system.dx), "P": P}

    def agent_step(self, i: int, k: int, prev: dict | None, y_i: Any, inbox: Any, zero: Any) -> tuple[dict, dict]:
        xbar = self._prior(i, k, prev, zero)
        got = {(lnode, s): p for (lnode, s, p) in inbox}
        ys = {(i, k): y_i, **{key: p["y"] for key, p in got.items()}}
        xh = self.update(i, k, xbar, ys, {key: p["xbar"] for key, p in got.items()})
        return {"xhat": xh}, {"y": y_i, "xbar": xbar}

    def team_step(self, k: int, prev: list[dict | None], ys: list[Any], zero: Any) -> list[dict]:
        n = self.system.n_agents
        yd = {(j, k): ys[j] for j in range(n)}
        xb = {(j, k): self._prior(j, k, prev[j], zero) for j in range(n)}
        return [{"xhat": self.update(i, k, xb[(i, k)], yd, xb)} for i in range(n)]

    # --- one agent's slice (teamkf.estimators._slices) ------------------------------------------
    def agent_slice(self, i: int) -> tuple[str, dict[str, np.ndarray], dict[str, Any]]:
        """Agent i's M_i(k), γ_i(k) and the compensation gains (C̃, R̃, G̃, Y) of every y_l(s) it fuses."""
        arrays: dict[str, np.ndarray] = {"M": np.asarray(self.M[i]), "gamma": np.asarray(self.gamma[i])}
        by_node: dict[int, dict[tuple[int, int], tuple[FloatArray, ...]]] = {}
        for k in range(self.horizon):
            for lnode, s in [(i, k), *self.src[i][k]]:
                by_node.setdefault(lnode, {}).setdefault(self._key(k, s), self.compensated(lnode, s, k))
        for lnode, entries in sorted(by_node.items()):
            keys = sorted(entries)
            arrays[f"comp/{lnode}/key"] = np.asarray(keys, dtype=np.int64).reshape(-1, 2)
            for q, name in enumerate("CRGY"):
                arrays[f"comp/{lnode}/{name}"] = np.stack([entries[key][q] for key in keys])
        return "linear-kcf", arrays, {"epsilon": float(self.epsilon), "horizon": int(self.horizon)}


def kcf_agent_from_slice(ctx: Any, i: int, arrays: dict[str, np.ndarray], meta: dict[str, Any]) -> tuple[Any, Any]:
    """Agent i of an honest KCF rebuilt from its slice (:meth:`KCFAlgorithm.agent_slice`): the same arithmetic, no team design."""
    from ._slices import AgentRows, SliceDesign
    from .linear_team import LinearAgent

    T = int(meta["horizon"])
    alg = KCFAlgorithm.__new__(KCFAlgorithm)
    Algorithm.__init__(alg, ctx.system, ctx.cost, ctx.graph, T)
    alg.honest, alg.epsilon = True, float(meta["epsilon"])
    ins = [(j, ctx.graph.delay(j, i)) for j in ctx.graph.in_neighbors(i)]
    src_i = [[(j, k - d) for (j, d) in ins if k - d >= 0] for k in range(T)]
    alg.src = AgentRows(i, src_i)  # type: ignore[assignment]
    alg.M, alg.gamma = AgentRows(i, arrays["M"]), AgentRows(i, arrays["gamma"])  # type: ignore[assignment]
    comp: dict[tuple[int, int, int], tuple[FloatArray, ...]] = {}
    for name in arrays:
        if name.startswith("comp/") and name.endswith("/key"):
            lnode = int(name.split("/")[1])
            stacks = [arrays[f"comp/{lnode}/{q}"] for q in "CRGY"]
            for r, key in enumerate(np.asarray(arrays[name]).tolist()):
                comp[(lnode, int(key[0]), int(key[1]))] = tuple(st[r] for st in stacks)
    alg.__dict__["_comp"] = comp
    alg.gain = {(i, k, lnode, s): comp[(lnode, *alg._key(k, s))][2:] for k in range(T) for (lnode, s) in [(i, k), *src_i[k]]}  # type: ignore[misc]
    alg.S = alg.P = None  # type: ignore[assignment]  # the nominal covariances: not an agent's
    alg.schedules = {}
    view = SliceDesign("kcf", T, ctx.system, ctx.cost, ctx.graph, info={"variant": meta.get("variant", "honest")}, steps=range(T), algorithm=alg)
    return view, LinearAgent(view, i)  # type: ignore[arg-type]


def design_kcf(
    system: LinearGaussianSystem, cost: TeamCost, graph: CommGraph, horizon: int | None = None, *, epsilon: float = 0.1, variant: str = "honest"
) -> Any:
    """Design the Kalman-consensus filter (Olfati-Saber 2007) on a delay graph.

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
    epsilon : float > 0
        Consensus step ε, γ_i = ε / (1 + ||M_i||_F). The default 0.1 is our
        choice: it keeps ε · in-degree < 1 up to in-degree 9 (module docstring).
    variant : "honest" (default), "ideal" or "stale"
        "honest": one exchange per step, delay-compensated, exact analytic cost
        (:class:`KCFAlgorithm` on :mod:`.linear_team`); "ideal": neighbours'
        current data within the step, exact analytic cost; "stale": the
        previous honest variant (delayed data fused as current), a
        :class:`KCFDesign` with Monte Carlo cost only.

    Returns
    -------
    LinearTeamDesign or KCFDesign
        "honest" and "ideal": a :class:`~teamkf.LinearTeamDesign` with the exact team cost;
        "stale": a :class:`~teamkf.KCFDesign`, evaluated by Monte Carlo.

    Examples
    --------
    >>> from teamkf import LinearGaussianSystem, TeamCost, CommGraph
    >>> from teamkf.estimators.kcf import design_kcf
    >>> d = design_kcf(LinearGaussianSystem.platoon(4), TeamCost.platoon(4, 10.0), CommGraph.line(4), 20)
    >>> d.label, d.stage_costs.shape
    ('kcf [honest]', (20,))
    """
    check_model(system, cost)
    check_graph(graph, system.n_agents)
    variant = V.choice(variant, "variant", tuple(VARIANTS))
    eps = _epsilon(epsilon)
    if variant == "stale":
        return kcf_schedules(system, cost, graph, horizon, epsilon=eps, variant="stale")
    if horizon is None:
        raise ArgumentError(
            "horizon: the KCF has no steady-state (infinite-horizon) design here, found horizon=None; give a finite number of steps T",
            argument="horizon",
        )
    T = V.positive_int(horizon, "horizon")
    system.require_horizon(T)
    cost.require_horizon(T)
    alg = KCFAlgorithm(system, cost, graph, T, eps, honest=(variant == "honest"))
    return finish_design("kcf", alg, variant, {"epsilon": eps, "variant_description": VARIANTS[variant], "realizable": variant == "honest"})


FAMILY = _register_builtin(
    Family(
        name="kcf",
        design=design_kcf,
        title="Kalman-consensus filter (Olfati-Saber 2007): local information fusion plus a consensus step on the priors",
        uses="graph",
        horizons=frozenset({"finite"}),
        analytic_cost=True,
        options=(
            Option(name="epsilon", default=0.1, check=_epsilon, doc="consensus step: gamma_i = epsilon / (1 + ||M_i||_F)"),
            Option(
                name="variant",
                default="honest",
                check=lambda v, k: V.choice(v, k, tuple(VARIANTS)),
                doc=" | ".join(f"{k!r}: {d}" for k, d in VARIANTS.items()),
                choices=tuple(VARIANTS),
            ),
        ),
        lossy_links=True,  # capabilities (registry.Family)
        example="design_kcf(system, cost, graph, horizon=100, epsilon=0.1, variant='honest')",
    )
)
