"""Control: closed loops built on teamkf's estimators.

* :mod:`teamkf.control.certainty_equivalent` -- certainty-equivalent feedback
  u = -f xhat for populations of interference-coupled agents (Abedinpour
  Fallah et al. 2017): stability region S(a) of the naive observer-based
  controller, the thresholds a_m(a_f), a_m, a_s, the exact average LQ cost of
  the bulk / memory-n closed loop, and batched simulation of N explicit agents.
* :mod:`teamkf.control.lqg` -- decentralized LQG with one-step delayed sharing
  through MTMSE (team-MMSE paper, Appendix D); import it from there.

Examples
--------
>>> from teamkf.control import a_s, in_stability_region
>>> round(a_s(), 3)
5.828
>>> in_stability_region(2.0, 0.8, 0.5)
True
"""

from .certainty_equivalent import (
    MAX_EXPLICIT_AGENTS,
    PopulationSimulation,
    a_m,
    a_m_of_af,
    a_s,
    in_stability_region,
    lq_cost,
    map_points,
    naive_closed_loop,
    naive_spectral_radii,
    simulate_population,
    stability_region_mask,
)

__all__ = [
    "naive_closed_loop",
    "naive_spectral_radii",
    "in_stability_region",
    "stability_region_mask",
    "a_m_of_af",
    "a_m",
    "a_s",
    "lq_cost",
    "PopulationSimulation",
    "simulate_population",
    "map_points",
    "MAX_EXPLICIT_AGENTS",
]
