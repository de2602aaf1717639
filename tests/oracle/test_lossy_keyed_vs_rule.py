"""The keyed drop-aware design (``keyed=1``) against the missed-packet rule, on the team where today's class loses.

3-agent line, every agent estimates x₁, one precise sensor of it at one end (``unlike_line``), T = 20,
p = 0.3: the nominal MTMSE with the missed-packet rule (Monte Carlo over the lossy runtime) beats the
pattern-independent design (``keyed=0``, 46.37 against ~43.8: 5.9 % worse); the gains keyed on the
current arrivals (44.19, exact) close most of that gap but still lose by ~0.9 % (docs/lossy-design.md).
"""

from __future__ import annotations

from teamkf import CommGraph
from teamkf.estimators.team import design_mtmse
from teamkf.estimators.team_lossy import design_mtmse_lossy
from teamkf.simulation.links import LinkModel
from teamkf.simulation.monte_carlo import monte_carlo

from ..unit.test_lossy_keyed import unlike_line

T = 20


def test_keyed_closes_most_of_the_gap_to_the_missed_packet_rule():
    sysm, cost = unlike_line()
    g = CommGraph.line(3)
    p = 0.3
    r = monte_carlo({"mtmse": design_mtmse(sysm, cost, g, T)}, T, 4000, rng=5, path="runtime", graph=g, links=LinkModel(p_drop=p))["mtmse"]
    d0 = design_mtmse_lossy(sysm, cost, g, T, p_drop=p)
    d1 = design_mtmse_lossy(sysm, cost, g, T, p_drop=p, keyed=1)
    assert d0.total_cost > r.total_mean + 3 * r.total_sem  # today's class loses to the rule here ...
    assert d1.total_cost < 0.96 * d0.total_cost  # ... keying on the current arrivals gains > 4 % ...
    assert d1.total_cost < 1.02 * r.total_mean  # ... and comes within 2 % of the rule (it is 0.9 % above it)
    assert d1.total_cost < d1.info["local_kf_cost"]
