"""MTMSE on a random directed graph with unequal delays, infinite horizon, and a networkx round trip.

Run:  python examples/custom_graph.py
"""

import numpy as np

from teamkf import CommGraph, InformationStructure, LinearGaussianSystem, TeamCost, design_mmse, design_mtmse

rng = np.random.default_rng(7)
n = 5
graph = CommGraph.random(n, p=0.35, delays=(1, 3), rng=rng)
print(graph, "weighted diameter tau* =", graph.diameter)
print("geodesic delays l_ij:\n", graph.geodesic_delays())

system = LinearGaussianSystem.uav_formation(n)  # spectral radius 1.05: unstable, detectable
cost = TeamCost.ring(n, lam=20.0)
structure = InformationStructure.from_graph(graph)
print("local dimensions:", structure.local_dims(system.dy))

mtmse = design_mtmse(system, cost, structure)
mmse = design_mmse(system, cost, structure)
print(
    f"average cost: MTMSE {mtmse.average_cost:.3f}  MMSE {mmse.average_cost:.3f}  "
    f"improvement {(mmse.average_cost / mtmse.average_cost - 1) * 100:.1f} %"
)

G = graph.to_networkx()  # edit with networkx, come back
assert CommGraph.from_networkx(G) == graph

# pictures (matplotlib: pip install 'teamkf[plot]'): the random graph with its delays and the
# information structure it induces (eq. (14))
import matplotlib.pyplot as plt  # noqa: E402

graph.plot(layout="spring", seed=1)
structure.plot()
plt.show()
