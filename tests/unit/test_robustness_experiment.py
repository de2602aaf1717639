"""`teamkf reproduce robustness --quick`: the grid runs end to end through the lossy runtime."""

import numpy as np

from teamkf import experiments
from teamkf.experiments.robustness import J_QUICK, P_QUICK


def test_robustness_quick(tmp_path):
    res = experiments.run("robustness", tmp_path, quick=True)
    assert (tmp_path / "robustness.csv").exists()
    rows = res.rows
    assert all(np.isfinite(r["J_T (MC)"]) for r in rows)
    for sname in ("platoon-4", "uav-4"):
        for J in J_QUICK:
            cent = [r["J_T (MC)"] for r in rows if r["scenario"] == sname and r["jitter"] == J and r["estimator"] == "centralized"]
            assert len(cent) == len(P_QUICK)
            np.testing.assert_allclose(cent, cent[0], rtol=1e-12)  # the bound does not use the network (batched vs run-by-run: round-off)
            for r in rows:
                simulated = r["packets sent"] is not None  # the drop-aware design's exact-cost rows send nothing
                if simulated and r["scenario"] == sname and r["jitter"] == J and r["p_drop"] == 1.0 and r["estimator"] != "centralized":
                    assert r["dropped"] == r["packets sent"] > 0
    robust = [r for r in rows if r["estimator"] == "mtmse-robust" and r["p_drop"] == 0.0]
    assert robust and all(
        r["ci95 low"] - 2 * (r["ci95 high"] - r["ci95 low"]) < r["J_T analytic (reliable)"] < r["ci95 high"] + 2 * (r["ci95 high"] - r["ci95 low"])
        for r in robust
    )
    assert "cikf" in res.notes  # not designed on the UAV graph (delay 2), and said so


def test_robustness_chains_cover_the_grid_richest_first():
    from teamkf.experiments.robustness import CHAINS, P_FULL, SCENARIOS, _chains

    keys = [(s, J, p, 50, 200, 5) for s in SCENARIOS for J in (0, 1, 2) for p in P_FULL]
    chains = _chains(keys)
    flat = [k for c in chains for k in c]
    assert sorted(flat) == sorted(keys) and len(flat) == len(keys)  # every point once
    for c in chains:
        assert len({k[:2] for k in c}) == 1  # one (scenario, J) row per chain
    assert [k[2] for k in chains[0]] == list(CHAINS[0]) and chains[0][0][:2] == ("platoon-4", 2)  # the heaviest first


def test_robustness_point_does_not_depend_on_the_caches_a_chain_leaves():
    """A point computed after another point of its row (caches warm, as in a chain) = the point alone (caches cold)."""
    import teamkf.simulation.lossy as lossy
    from teamkf.experiments import robustness as R
    from teamkf.study.scenario import load_packaged

    sc = load_packaged("platoon-4").updated({"horizon": 8})
    designs, _ = R._designs(sc)
    R._GRID[("platoon-4", 1)] = (sc, R._with_robust(sc, designs, 1))
    try:
        for c in (lossy._CACHES, lossy._PRE):
            c.clear()
        lossy._MAPS.clear()
        alone = R._point(("platoon-4", 1, 0.2, 8, 6, 3))
        chain = R._chain([("platoon-4", 1, 0.5, 8, 6, 3), ("platoon-4", 1, 0.2, 8, 6, 3)])
    finally:
        R._GRID.clear()
    assert alone[0] == chain[1][0] and alone[2] == chain[1][2]
    for name, r in alone[1].items():
        np.testing.assert_array_equal(r.stage_mean, chain[1][1][name].stage_mean)
