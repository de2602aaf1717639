"""Centralized Kalman filter and predictor — the lower bound and the oracle for the rest.

Notation (team-MMSE paper eqs. 20-22; steps 0-based):

===========  ==================================================================
P(k)         var(x(k) | y(0:k-1)), predictor covariance; P(0) = Sigma_x
K(k)         P(k) C(k)' [C(k) P(k) C(k)' + R(k)]^-1                     (eq. 21)
P(k|k)       (I - K C) P(k) (I - K C)' + K R K'  (Joseph form)
P(k+1)       A(k) P(k|k) A(k)' + Q(k)                                  (eq. 22)
x^(k+1)      A x^(k) + A K(k) [y(k) - C x^(k)]                         (eq. 20)
===========  ==================================================================

A centralized estimator holds every measurement y(0:k). Its team cost with
z = L x^(k|k) is Tr(L' S L P(k|k)) (filter form) or Tr(L' S L P(k))
(predictor form, z = L x^(k|k-1)). No decentralized estimator beats it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Literal, Sequence

import numpy as np

from .. import _validation as V
from .._validation import FloatArray
from ..exceptions import ArgumentError, InformationStructureError
from ..models import LinearGaussianSystem, TeamCost
from ._kalman_common import kalman_covariances, kalman_step, predictor_errors, steady_state
from .base import Design, Packet, check_paths
from .checks import check_model
from .registry import Family, Option, _register_builtin

__all__ = ["kalman_covariances", "design_centralized", "CentralizedDesign", "CentralizedAgent", "kalman_step", "predictor_errors"]

Form = Literal["filter", "predictor"]


@dataclass(frozen=True, eq=False, kw_only=True)
class CentralizedDesign(Design):
    """Centralized Kalman filter (or predictor) design: the lower bound on every team's cost.

    One fusion centre holds every y_j(k) at step k, so x̂(k|k) = E[x(k) | y(0:k)] and
    ẑ = L x̂(k|k) (filter) or ẑ = L x̂(k|k-1) (predictor). Built by :func:`~teamkf.design_centralized`.

    Parameters
    ----------
    estimator, horizon, system, cost, stage_costs, average_cost, info, graph
        As in :class:`~teamkf.Design`: the family name, T (None for the steady state), the
        model, the team cost, the exact E[c(x(k), ẑ(k))] per step and the plain-data facts.
    form : "filter" or "predictor"
        Whether ẑ(k) uses y(k) (filter) or only y(0:k-1) (predictor).
    P_pred, K, P_filt : arrays
        The predictor covariances P(k), Kalman gains K(k) and filter covariances P(k|k) of
        eqs. 21-22, shape (T, ., .), or one matrix each for the steady state.

    See Also
    --------
    design_centralized

    Examples
    --------
    >>> from teamkf import LinearGaussianSystem, TeamCost, design_centralized
    >>> kf = design_centralized(LinearGaussianSystem.platoon(4), TeamCost.platoon(4, 100.0), horizon=10)
    >>> kf.P_pred.shape, kf.K.shape, kf.form
    ((10, 4, 4), (10, 4, 16), 'filter')
    """

    form: Form = "filter"
    P_pred: FloatArray
    K: FloatArray
    P_filt: FloatArray

    omniscient: ClassVar[bool] = True
    handles_missing: ClassVar[bool] = True  # zero gain on a decoupled pseudo-measurement (teamkf.study.measurements)

    def K_at(self, k: int) -> FloatArray:
        return self.K if self.horizon is None else self.K[k]  # type: ignore[no-any-return]

    def errors(self, paths: Any) -> FloatArray:
        """L x(k) - z(k) for sampled paths, from the filter's error recursion (no cancellation).

        eps(k) = x(k) - x^(k|k-1):  eps(0) = x(0),
        eps(k+1) = A [eps(k) - K (C eps(k) + v(k))] + w(k)   (stable: A(I - KC) is)
        filter error eps(k) - K (C eps(k) + v(k)).
        """
        check_paths(paths, self.system)
        sys, cost = self.system, self.cost
        eps = predictor_errors(sys, self.K_at, paths)
        out = []
        for k in range(paths.n_steps):
            e = eps[:, k]
            if self.form == "filter":
                e = e - (e @ sys.C_stack(k).T + paths.v_stack[:, k]) @ self.K_at(k).T
            out.append(e @ cost.L_at(k).T)
        return np.stack(out, axis=1)

    def agents(self) -> list["CentralizedAgent"]:
        """One agent per team member; each holds every measurement at once (a bound, not a network)."""
        return [CentralizedAgent(self, i) for i in range(self.system.n_agents)]

    def steady_form(self) -> Any:
        """The steady-state filter as an LTI map (:class:`~teamkf.estimators.steady.SteadyForm`, c = 1, from step 0)."""
        from .steady import SteadyForm

        if self.horizon is not None:
            raise self._unsupported("steady_form()", "it is a finite-horizon design; design with horizon=None")
        sys, L = self.system, self.cost.L_at(0)
        A, C, K = sys.A_at(0), sys.C_stack(0), np.asarray(self.K)
        IKC = np.eye(sys.dx) - K @ C
        if self.form == "filter":
            G, H = L @ IKC, (L @ K)[None]
        else:
            G, H = L, np.zeros((1, L.shape[0], C.shape[0]))
        return SteadyForm(M=A @ IKC, N=A @ K, G=G, H=H, start=0)

    def details(self) -> dict[str, Any]:
        return {"form": self.form, "local_dims": None, "gain_shapes": {"K": list(np.asarray(self.K).shape[-2:])}}

    def arrays(self) -> dict[str, np.ndarray]:
        """Costs, the gain schedule ``K`` ((T, d_x, d_y) or the steady K-bar) and the covariances."""
        return {**super().arrays(), "K": np.asarray(self.K), "P_pred": np.asarray(self.P_pred), "P_filt": np.asarray(self.P_filt)}


def design_centralized(
    system: LinearGaussianSystem,
    cost: TeamCost,
    graph_or_structure: Any = None,
    horizon: int | None = None,
    *,
    form: Form = "filter",
    check: bool = True,
) -> CentralizedDesign:
    """Design the centralized Kalman filter/predictor and its analytic team cost.

    Parameters
    ----------
    system : LinearGaussianSystem
        The process x(k+1) = A x(k) + w(k) and the agents' measurements y_i(k) = C_i x(k) + v_i(k).
    cost : TeamCost
        The team cost c(x, ẑ) = (L x - ẑ)ᵀ S (L x - ẑ) (``None``: the sum of the agents' MSEs).
    graph_or_structure : ignored
        The centralized bound holds every measurement at once, whatever the
        graph; the argument keeps the family signature
        ``design_X(system, cost, graph_or_structure, horizon)``.
    horizon : int or None
        Number of steps T; None for the steady state (algebraic Riccati equation).
    form : "filter" or "predictor"
        ẑ = L x̂(k|k) (filter) or ẑ = L x̂(k|k-1) (predictor).
    check : bool
        Check detectability and stabilizability for the steady state.

    Returns
    -------
    CentralizedDesign
        The gains and covariances, with the exact stage costs (finite horizon) or average cost.

    Examples
    --------
    >>> from teamkf import LinearGaussianSystem, TeamCost, design_centralized
    >>> d = design_centralized(LinearGaussianSystem.platoon(4), TeamCost.platoon(4, 100.0), horizon=50)
    >>> d.stage_costs.shape, d.omniscient
    ((50,), True)
    """
    if isinstance(graph_or_structure, (int, np.integer)) and not isinstance(graph_or_structure, bool):
        raise ArgumentError(
            f"graph_or_structure: expected a CommGraph, an InformationStructure or None (the centralized filter ignores it), "
            f"found the integer {int(graph_or_structure)}; the 0.1 order design_centralized(system, cost, T) is gone: "
            f"write design_centralized(system, cost, horizon={int(graph_or_structure)})",
            argument="graph_or_structure",
        )
    check_model(system, cost)
    V.choice(form, "form", ("filter", "predictor"))
    W = lambda k: cost.L_at(k).T @ cost.S_at(k) @ cost.L_at(k)  # noqa: E731  (L' S L)
    if horizon is None:
        cost.require_time_invariant()
        P, K, Pf = steady_state(system, check=check)
        avg = float(np.trace(W(0) @ (Pf if form == "filter" else P)))
        return CentralizedDesign(
            estimator="centralized",
            horizon=None,
            average_cost=avg,
            info={"form": form},
            system=system,
            cost=cost,
            form=form,
            P_pred=P,
            K=K,
            P_filt=Pf,
        )
    T = V.positive_int(horizon, "horizon")
    cost.require_horizon(T)
    P, K, Pf = kalman_covariances(system, T)
    stage = np.array([np.trace(W(k) @ (Pf[k] if form == "filter" else P[k])) for k in range(T)])
    return CentralizedDesign(
        estimator="centralized", horizon=T, stage_costs=stage, info={"form": form}, system=system, cost=cost, form=form, P_pred=P, K=K, P_filt=Pf
    )


class CentralizedAgent:
    """Agent i of the centralized bound: receives every y_j(k) at step k, reports L_i x^(k|k)."""

    def __init__(self, design: CentralizedDesign, index: int):
        self.design = design
        self.index = index
        self.system: LinearGaussianSystem = design.system
        self.cost: TeamCost = design.cost

    def arrival_lag(self, j: int) -> int:
        return 0

    def init_state(self, n_runs: int) -> dict[str, Any]:
        return {"xhat": np.zeros((n_runs, self.system.dx))}

    def step(self, state: dict[str, Any], k: int, received: Sequence[Packet]) -> tuple[dict[str, Any], FloatArray]:
        sys = self.system
        got = {j: v for (j, s, v) in received if s == k}
        if len(got) != sys.n_agents:
            raise InformationStructureError(f"centralized agent {self.index}: expected every y_j({k}) at step {k}, found {sorted(got)}")
        y = np.concatenate([got[j] for j in range(sys.n_agents)], axis=1)
        xpred = state["xhat"]
        xfilt = xpred + (y - xpred @ sys.C_stack(k).T) @ self.design.K_at(k).T
        Li = self.cost.L_block(self.index, k)
        z = (xfilt if self.design.form == "filter" else xpred) @ Li.T
        return {"xhat": xfilt @ sys.A_at(k).T}, z


FAMILY = _register_builtin(
    Family(
        name="centralized",
        design=design_centralized,
        title="centralized Kalman filter: every agent holds every measurement at once (the lower bound, not a network)",
        uses="none",
        options=(
            Option(
                name="form",
                default="filter",
                check=lambda v, k: V.choice(v, k, ("filter", "predictor")),
                doc='"filter": L x^(k|k); "predictor": L x^(k|k-1)',
            ),
        ),
        lossy_links=True,
        missing_data=True,
        steady_form=True,  # capabilities (registry.Family)
        example="design_centralized(system, cost, horizon=100)",
    )
)
