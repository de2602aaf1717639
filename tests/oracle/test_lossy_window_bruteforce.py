"""The finite-memory form (``memory = m``: windowed fills, the lifted moment recursion, the steady form) checked by
brute force: every edge-step pattern enumerated, the flooding simulated, each step's expected cost computed on the
joint Gaussian law of (x, y) (:mod:`tests.oracle.test_team_lossy_bruteforce`)."""

from __future__ import annotations

import numpy as np
import pytest

from teamkf import CommGraph
from teamkf.estimators import _lossy_window
from teamkf.estimators.team_lossy import design_mtmse_lossy

from . import test_team_lossy_bruteforce as bf


@pytest.mark.parametrize("items", ["measurements", "innovations"])
def test_windowed_fills_exact_and_optimal_by_enumeration(monkeypatch, items):
    """m = 2 < T = 4: the fill of item (j, 2) uses the own items 1..3 only; exact cost and the class's optimum."""
    monkeypatch.setattr(bf, "T", 4)
    sysm, cost = bf._tiny(2)
    g = CommGraph.complete(2, delay=1)
    d = design_mtmse_lossy(sysm, cost, g, 4, p_drop=0.3, items=items, memory=2)
    full = design_mtmse_lossy(sysm, cost, g, 4, p_drop=0.3, items=items)
    assert d.fills[3][0].shape == (3, 3)  # its items (0, 2), (0, 3), (1, 2); fills on the own items 1..3
    assert not np.allclose(d.stage_costs[3], full.stage_costs[3])  # the window changes the class
    expected, best = bf._brute(d, g, 0.3)
    np.testing.assert_allclose(d.stage_costs, expected, rtol=1e-10)
    for k in range(4):
        assert d.stage_costs[k] == pytest.approx(best[k][0], rel=1e-10)
        np.testing.assert_allclose(best[k][2], best[k][1], rtol=1e-6, atol=1e-9)


def test_steady_form_cost_exact_by_enumeration(monkeypatch):
    """Gains frozen at once (tolerance forced open): the later stage costs, from ⟨𝓜, cov z(k)⟩, are still exact."""
    monkeypatch.setattr(bf, "T", 6)
    monkeypatch.setattr(_lossy_window, "STEADY_TOL", np.inf)
    monkeypatch.setattr(_lossy_window, "STEADY_STEPS", 1)
    sysm, cost = bf._tiny(2)
    g = CommGraph.complete(2, delay=1)
    d = design_mtmse_lossy(sysm, cost, g, 6, p_drop=0.3, items="measurements", memory=2)
    assert d.info["steady_from"] == 5 and d.gains[5][0] is d.gains[4][0] and d.fills[5][1] is d.fills[4][1]
    expected, best = bf._brute(d, g, 0.3)
    np.testing.assert_allclose(d.stage_costs, expected, rtol=1e-10)
    assert d.stage_costs[5] > best[5][0] * (1 + 1e-9)  # step 5 reuses step 4's gains: exact, no longer optimal
