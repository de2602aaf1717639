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
---------------------------------------------------------------
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

from ..models import LinearGaussianSystem, TeamCost
from ..network.graph import CommGraph
from ._consensus_common import (
    COMBINATIONS,
    GAINS,
    VARIANTS,
    DiffusionAlgorithm,
    check_combination,
    check_gains,
    check_lazy,
    check_variant,
    check_weights,
    diffusion_weights,
    finite_horizon,
)
from .checks import check_graph, check_model
from .linear_team import LinearTeamDesign, finish_design
from .registry import Family, Option, _register_builtin

__all__ = ["design_diffusion", "diffusion_weights", "VARIANTS", "COMBINATIONS", "check_variant", "check_combination", "check_lazy"]


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

    combination : "weights", "age", "matrix" or "ci"
        How the neighbours' intermediate estimates are combined: "weights" (the published fixed weights, default),
        "age" (weights that discount older messages), "matrix" (the best linear unbiased combination with the
        exact error covariances), "ci" (covariance intersection).
    lazy : float in (0, 1]
        α of the lazy combination x̂ = (1 - α) ψ_k + α x̂^comb (1: none, the published step).
    gains : "nominal" or "exact"
        "nominal" (published, default): the adaptation gain from each agent's nominal covariance; "exact": the
        adaptation gain and the combination rule from the exact error covariances.

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
    comb = check_combination(combination, "diffusion.combination")
    al = check_lazy(lazy, "diffusion.lazy")
    gm = check_gains(gains, "diffusion.gains")
    alg = DiffusionAlgorithm(system, cost, graph, T, c, honest=(variant == "honest"), combination=comb, lazy=al, gains=gm)
    info = {"weights": weights if isinstance(weights, str) else "explicit", "combination": comb, "lazy": al, "gains": gm}
    return finish_design("diffusion", alg, variant, info)


FAMILY = _register_builtin(
    Family(
        name="diffusion",
        design=design_diffusion,
        title="ATC diffusion Kalman filter, information form (Cattivelli & Sayed 2010), honest = delay-compensated",
        uses="graph",
        horizons=frozenset({"finite"}),
        analytic_cost=True,
        lossy_links=True,  # capabilities (registry.Family): its agents run over links that drop
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
