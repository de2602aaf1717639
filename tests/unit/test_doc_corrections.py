"""The numbers of the corrections in docs/baselines.md ("Corrections (issue 22)"), computed and checked.

CIKF vs the per-agent MMSE with the graph's neighbourhood sharing on the leaderboard's rings of scalar
sensors (unit delays, team MSE cost: MMSE = MTMSE there): equal for the first steps only, then above.
"""

import numpy as np
import pytest

from teamkf.estimators.registry import get_family
from teamkf.experiments.leaderboard import ring_sensors

T = 30


@pytest.mark.parametrize(
    ("n", "dx", "last_equal", "at4", "peak", "last"),
    [(6, 4, 2, 0.0126, 0.0160, 0.0154), (12, 6, 3, 0.0092, 0.0243, 0.0229)],
)
def test_cikf_equals_mmse_on_a_ring_only_for_the_first_steps(n, dx, last_equal, at4, peak, last):
    s, c, g = ring_sensors(n, dx)
    ck = get_family("cikf").build(s, c, graph=g, structure=g, horizon=T).stage_costs
    mm = get_family("mmse").build(s, c, graph=g, structure=g, horizon=T).stage_costs
    mt = get_family("mtmse").build(s, c, graph=g, structure=g, horizon=T).stage_costs
    np.testing.assert_allclose(mm, mt, rtol=1e-12)  # S = I: the per-agent MMSE is the team optimum
    r = ck / mm - 1.0
    assert np.all(np.abs(r[: last_equal + 1]) <= 5e-15), r[: last_equal + 1]
    assert r[last_equal + 1] > 1e-3
    assert np.all(r[last_equal + 1 :] > 0)
    # the docs' numbers, to the digits printed there
    assert abs(r[4] - at4) < 5e-5 and abs(r[2:].max() - peak) < 5e-5 and abs(r[-1] - last) < 5e-5, (r[4], r[2:].max(), r[-1])
