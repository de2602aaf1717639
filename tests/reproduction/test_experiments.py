"""Reproductions compute their numbers (checked here against closed forms and inequalities)."""

import numpy as np
import pytest

from teamkf import experiments


def test_registry_discovers_modules():
    assert "fig1" in experiments.names()
    with pytest.raises(ValueError, match="unknown experiment"):
        experiments.get("nope")


def test_fig1_matches_closed_forms():
    from teamkf.experiments.fig1 import improvement

    for sigma in (0.3, 1.0, 2.0):
        for lam in (1.0, 100.0):
            s2 = sigma**2
            alpha = (1 + lam / 4) / (1 + lam / 2)
            J_lin = (2 + lam) * alpha * s2 / (1 + alpha * s2)
            J_mmse = 2 * (s2 / (1 + s2)) * (1 + lam / 4 * (1 + 2 * s2) / (1 + s2))
            Jm, Jt, d = improvement(sigma, lam)
            assert Jt == pytest.approx(J_lin, rel=1e-12) and Jm == pytest.approx(J_mmse, rel=1e-12)
    res = experiments.run("fig1", quick=True)
    deltas = [r["Delta % at sigma=1"] for r in res.rows]
    assert all(a < b for a, b in zip(deltas, deltas[1:]))  # grows with lambda
    assert deltas[-1] == pytest.approx(12.5, abs=1e-6)
    assert np.all(np.isfinite(res.data["sigma"]))
