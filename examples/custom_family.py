"""A user's own distributed filter, registered with teamkf and usable everywhere a built-in family is.

Each agent runs a Kalman filter on its own measurements, sends its filtered estimate x̂_i(s|s) to its
out-neighbours, and reports z_i(k) = L_i · mean(x̂_i(k|k), A^(k-s) x̂_j(s|s) for every received j):
what arrived τ_ji steps late is delay-compensated by the model before it is averaged.

    teamkf --plugin examples/custom_family.py evaluate examples/scenarios/platoon-4-custom.toml
    python examples/custom_family.py
"""

from dataclasses import dataclass

import numpy as np

import teamkf
from teamkf.estimators.base import Design
from teamkf.estimators.checks import check_graph, check_model
from teamkf.estimators.kalman import kalman_covariances
from teamkf.exceptions import ArgumentError


@dataclass(frozen=True, eq=False, kw_only=True)
class AveragingDesign(Design):
    graph: teamkf.CommGraph
    gains: tuple  # agent i's Kalman gains K_i(k), (T, d_x, d_y^i)

    def graph_agents(self) -> list:
        return [AveragingAgent(self, i) for i in range(self.n_agents)]


class AveragingAgent:
    def __init__(self, design: AveragingDesign, index: int):
        self.d, self.index = design, index

    def init_state(self, n_runs: int) -> np.ndarray:
        return np.zeros((n_runs, self.d.system.dx))  # prior x̂_i(k|k-1); x(0) has mean 0

    def step(self, xpred: np.ndarray, k: int, own: np.ndarray, inbox: list) -> tuple:
        sys, i = self.d.system, self.index
        xf = xpred + (own - xpred @ sys.C_at(i, k).T) @ self.d.gains[i][k].T  # own Kalman update
        A = sys.A_at(0)
        views = [xf] + [x_j @ np.linalg.matrix_power(A, k - s).T for (_, s, x_j) in inbox]  # delay compensation
        z = np.mean(views, axis=0) @ self.d.cost.L_block(i, k).T
        return xf @ A.T, z, xf  # next prior, z_i(k), payload sent on every out-edge


def design_avg_kf(system, cost, graph, horizon=None):
    """Per-agent Kalman gains on each agent's own measurements (finite horizon, time-invariant A)."""
    check_model(system, cost)  # teamkf's own checks: clear errors that name the argument
    check_graph(graph, system.n_agents)
    if isinstance(horizon, bool) or not isinstance(horizon, (int, np.integer)) or horizon < 1:
        raise ArgumentError(f"horizon: expected a number of steps T >= 1, found {horizon!r}; give an integer", argument="horizon")
    gains = []
    for i in range(system.n_agents):
        own = teamkf.LinearGaussianSystem(A=system.A, Q=system.Q, Sigma_x=system.Sigma_x, C=[system.C[i]], R=[system.R[i]])
        gains.append(kalman_covariances(own, horizon)[1])
    return AveragingDesign(estimator="avg_kf", horizon=horizon, system=system, cost=cost, graph=graph, gains=tuple(gains))


FAMILY = teamkf.register_family(
    name="avg_kf",
    design=design_avg_kf,
    title="local Kalman filters, averaged with delay-compensated neighbour estimates (examples/custom_family.py)",
    uses="graph",
    horizons={"finite"},
    analytic_cost=False,
    lossy_links=True,  # its step averages whatever arrived: a lost message is simply not averaged
    replace=True,
)

if __name__ == "__main__":
    system, cost = teamkf.LinearGaussianSystem.platoon(4), teamkf.TeamCost.platoon(4, lam=10.0)
    graph = teamkf.CommGraph.line(4, delay=1)
    designs = {name: teamkf.get_family(name).build(system, cost, graph=graph, structure=graph, horizon=50) for name in ("avg_kf", "mtmse")}
    mc = teamkf.monte_carlo(designs, 50, 500, rng=1)
    for name, r in mc.items():
        print(f"{name:8s} J_T = {r.total_mean:9.2f}  95% CI [{r.ci95[0]:.2f}, {r.ci95[1]:.2f}]")
