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
On lossy links the agents run :meth:`~teamkf.estimators._consensus_common.DiffusionAlgorithm.agent_step_tolerant`:

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

Weights (columns of C = [c_lk] sum to 1): ``"metropolis"`` (default,
c_lk = 1/max(n_k, n_l) for l ∈ N_k \ {k}, n_k = ``|N_k|``, c_kk = 1 - Σ),
``"uniform"`` (1/n_k) or an explicit n×n matrix (non-negative, column-stochastic,
non-zero only on the graph's edges l → k and the diagonal).
"""

from __future__ import annotations

from typing import Any

from ..models import LinearGaussianSystem, TeamCost
from ..network.graph import CommGraph
from ._consensus_common import VARIANTS, DiffusionAlgorithm, check_variant, check_weights, diffusion_weights, finite_horizon
from .checks import check_graph, check_model
from .linear_team import LinearTeamDesign, finish_design
from .registry import Family, Option, _register_builtin

__all__ = ["design_diffusion", "diffusion_weights", "VARIANTS", "check_variant"]


def design_diffusion(
    system: LinearGaussianSystem,
    cost: TeamCost,
    graph: CommGraph,
    horizon: int | None = None,
    *,
    weights: Any = "metropolis",
    variant: str = "honest",
) -> LinearTeamDesign:
    """Design the ATC diffusion KF (information form) with its exact team cost.

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
    weights : "metropolis", "uniform" or array
        The combination weights: a rule, or an n×n column-stochastic matrix c[l, k].
    variant : "honest" (default) or "ideal"
        "honest": one exchange per step over the graph's delays, delay-compensated (realizable);
        "ideal": neighbours' current data within the step (a bound, not realizable on a delay graph).

    Returns
    -------
    LinearTeamDesign
        The per-step linear maps with the exact team cost (stage costs E[c(x(k), ẑ(k))]).

    Examples
    --------
    >>> from teamkf import LinearGaussianSystem, TeamCost, CommGraph, design_diffusion
    >>> d = design_diffusion(LinearGaussianSystem.platoon(4), TeamCost.platoon(4, 10.0), CommGraph.line(4), 20)
    >>> d.label, d.stage_costs.shape
    ('diffusion [honest]', (20,))
    """
    check_model(system, cost)
    check_graph(graph, system.n_agents)
    variant = check_variant(variant, "variant")
    T = finite_horizon(horizon, "diffusion", system, cost)
    c = diffusion_weights(graph, weights, key="diffusion.weights")
    alg = DiffusionAlgorithm(system, cost, graph, T, c, honest=(variant == "honest"))
    return finish_design("diffusion", alg, variant, {"weights": weights if isinstance(weights, str) else "explicit"})


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
            Option(name="variant", default="honest", check=check_variant, doc=" | ".join(f"{k!r}: {d}" for k, d in VARIANTS.items())),
        ),
        lossy_links=True,  # capabilities (registry.Family)
        example="design_diffusion(system, cost, graph, horizon=100, weights='metropolis', variant='honest')",
    )
)
