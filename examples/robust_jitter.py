"""Jitter on the platoon's links: the nominal MTMSE design against the design for the delay bound.

    PYTHONPATH=src python examples/robust_jitter.py          # 100 runs
    TEAMKF_RUNS=400 PYTHONPATH=src python examples/robust_jitter.py

Every packet of the 4-vehicle platoon (line graph, unit delays, T = 20) arrives 0..J extra steps late.
The nominal design replaces each packet that misses its deadline by its conditional expectation given
what the agent holds; the robust design (``robust_graph``: every delay raised by J) waits for it, so it
misses nothing and its Monte Carlo cost is its analytic cost. Both run on the same paths and link events.
"""

import os

from teamkf import design_mtmse
from teamkf.simulation.links import LinkModel, robust_graph
from teamkf.simulation.monte_carlo import monte_carlo
from teamkf.study.scenario import load_packaged

runs = int(os.environ.get("TEAMKF_RUNS", "100"))
sc = load_packaged("platoon-4").updated({"horizon": 20})
nominal = sc.design("mtmse")
print(f"platoon-4, T = 20, {runs} runs, seed 21; team cost J_T, Monte Carlo ± 1.96 standard errors")
print("J | nominal, reliable (analytic) | robust (analytic) | robust, MC under jitter | nominal, MC under jitter")
for J in (1, 2):
    robust = design_mtmse(sc.system, sc.cost, robust_graph(sc.graph, J), horizon=20)
    mc = monte_carlo({"nominal": nominal, "robust": robust}, 20, runs, rng=21, path="runtime", graph=sc.graph, links=LinkModel(jitter=J))
    r, n = mc["robust"], mc["nominal"]
    print(
        f"{J} | {nominal.total_cost:.2f} | {robust.total_cost:.2f} | {r.total_mean:.2f} ± {1.96 * r.total_sem:.2f} "
        f"({sum(r.links.missed.values())} missed) | {n.total_mean:.2f} ± {1.96 * n.total_sem:.2f} ({sum(n.links.missed.values())} missed)"
    )
