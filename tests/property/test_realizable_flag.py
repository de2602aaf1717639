"""``Design.realizable`` is true exactly when the agents use only what the graph delivers (every family, every variant).

The test does not trust the flag: it measures what each agent uses. For every
registered family, every value of its ``variant`` option (the registry's
``choices``) and the fair honest forms of the baselines (exact gains, the
combination rules, lazy updates, the heard-count ICF/HCMCI, another KCF ε, the CI with feedback), it
perturbs one measurement y_j(s) at a time and records every agent estimate
ẑ_i(k) that changes. The graph delivers y_j(s) to agent i at s + ℓ_ji (ℓ: the
geodesic delay, 0 for j = i), so an estimate that changes at k < s + ℓ_ji used
something the graph does not deliver. The flag must be True exactly when no
such change happens (the designs are linear: one perturbation per (j, s)
decides it). Ideal variants exchange inside the step: on a graph whose every
delay is at least 1 they use undelivered data, so the flag must be False —
except ``local``, whose two variants are the same silent filter. Every
realizable design's stage costs are at least MTMSE's (the optimum over what the
graph delivers): the fair forms (exact gains included) are checked against it.
"""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import teamkf
import teamkf.exceptions
from teamkf import CommGraph
from tests.helpers import random_cost, random_system

T = 5

#: the fair honest forms and options of the baselines, each crossed with every variant
EXTRA: dict[str, list[dict]] = {
    "diffusion": [
        {"gains": "exact", "combination": "matrix"},
        {"gains": "exact", "combination": "weights", "lazy": 0.3},
        {"combination": "age"},
        {"combination": "matrix", "lazy": 0.5},
        {"combination": "ci"},
    ],
    "icf": [{"count": "heard"}],
    "hcmci": [{"count": "heard"}],
    "kcf": [{"epsilon": 0.01}],
    "ci": [{"feedback": True}],
}


@st.composite
def instances(draw):
    seed = draw(st.integers(0, 2**31 - 1))
    n = draw(st.integers(2, 3))
    dx = draw(st.integers(1, 3))
    rng = np.random.default_rng(seed)
    system = random_system(rng, n, dx, [draw(st.integers(1, 2)) for _ in range(n)])
    cost = random_cost(rng, n, dx, 1)
    edges = {(i, (i + 1) % n) for i in range(n)} | {(i, j) for i in range(n) for j in range(n) if i != j and draw(st.booleans())}
    unit = draw(st.booleans())
    graph = CommGraph(n, [(i, j, 1 if unit else draw(st.integers(1, 2))) for (i, j) in sorted(edges)])
    return system, cost, graph, seed


def uses_undelivered(design, system, graph, seed) -> bool:
    """True when some ẑ_i(k) changes with a y_j(s) that reaches agent i only after k (linear designs: one probe per (j, s))."""
    n, dz = system.n_agents, design.cost.dz
    rng = np.random.default_rng(seed)
    y = [rng.standard_normal((1, T, system.dy[j])) for j in range(n)]
    z0 = design.filter(y)
    ell = np.asarray(graph.geodesic_delays(), dtype=float)
    for j in range(n):
        for s in range(T):
            y2 = [a.copy() for a in y]
            y2[j][0, s] += 1.0
            dzs = np.abs(design.filter(y2) - z0)[0]  # (T, n dz)
            scale = 1e-9 * (1.0 + np.abs(z0).max())
            for i in range(n):
                arrive = s + (0 if i == j else ell[j, i])
                for k in range(T):
                    if k < arrive and np.max(dzs[k, i * dz : (i + 1) * dz]) > scale:
                        return True
    return False


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(instances())
def test_realizable_exactly_when_only_delivered_data_is_used(inst):
    system, cost, graph, seed = inst
    optimum = teamkf.design_mtmse(system, cost, graph, T).stage_costs
    checked = 0
    for name, fam in teamkf.families().items():
        if "finite" not in fam.horizons:
            continue
        try:
            fam.check_graph(graph)
        except teamkf.TeamkfError:
            continue  # the family does not run on this graph (CIKF: unit delays only)
        variants = fam.variants or (None,)
        for options in [{}, *EXTRA.get(name, [])]:
            for v in variants:
                opts = dict(options, **({"variant": v} if v is not None else {}))
                try:
                    d = fam.build(system, cost, graph=graph, structure=graph, horizon=T, options=opts)
                except (teamkf.exceptions.NotPositiveDefiniteError, teamkf.UnsupportedOperationError, teamkf.ArgumentError) as exc:
                    assert name in str(exc) or exc.argument, (name, exc)  # a documented requirement this instance does not meet
                    continue
                leak = uses_undelivered(d, system, graph, seed)
                assert d.realizable == (not leak), (name, opts, d.realizable, leak)
                if d.realizable and d.stage_costs is not None:  # MTMSE is optimal among what the graph delivers
                    sc = np.asarray(d.stage_costs)
                    assert np.all(optimum <= sc + 1e-9 * np.maximum(1.0, np.abs(sc))), (name, opts)
                if v == "ideal" and name != "local":
                    assert not d.realizable, (name, opts)
                checked += 1
    assert checked >= 10  # mtmse, mmse, centralized, local, kcf (x variants) always design
