"""Quickstart: MTMSE vs per-agent MMSE vs the centralized Kalman filter on the 4-vehicle platoon.

Run:  python examples/quickstart.py
"""

from teamkf import (
    CommGraph,
    InformationStructure,
    LinearGaussianSystem,
    TeamCost,
    design_centralized,
    design_mmse,
    design_mtmse,
    run_online,
    sample,
)

system = LinearGaussianSystem.platoon(4)  # Section IV-B of the team-MMSE paper
cost = TeamCost.platoon(4, lam=100.0)  # eq. (6)
graph = CommGraph.line(4, delay=1)
T = 100

designs = {
    "centralized": design_centralized(system, cost, horizon=T),
    "mtmse": design_mtmse(system, cost, graph, horizon=T),
    "mmse": design_mmse(system, cost, graph, horizon=T),
}
for name, d in designs.items():
    print(f"{name:12s} J_T = {d.total_cost:10.2f}")

# information shedding: every vehicle keeps only its own last three readings (IS2)
IS2 = InformationStructure.own_window(4, common_lag=3)
IS2.validate_on(graph)
print(f"{'mtmse IS2':12s} J_T = {design_mtmse(system, cost, IS2, horizon=T).total_cost:10.2f}")

# the online agents reproduce the design on simulated data
x, y = sample(system, T, n_runs=400, rng=1)
z = run_online(designs["mtmse"].agents(), y)
mc = sum(cost.value(x[:, k], z[:, k]).mean() for k in range(T))
print(f"{'mtmse (MC)':12s} J_T ~ {mc:10.2f}  (400 simulated runs)")

# pictures (matplotlib: pip install 'teamkf[plot]'): the graph with its delays, what each vehicle
# holds under IS2, and the stage costs of the three designs
import matplotlib.pyplot as plt  # noqa: E402

from teamkf.study.results import CostCurves  # noqa: E402

graph.plot()
IS2.plot()
CostCurves.from_designs(designs, title="platoon, n = 4, T = 100").plot(log=True)
plt.show()
