"""Streaming Monte Carlo: exact merging, chunk- and scheduler-invariance (bit for bit), bounded memory."""

from __future__ import annotations

import math
import tracemalloc
from fractions import Fraction

import numpy as np
import pytest

from teamkf import CommGraph, LinearGaussianSystem, TeamCost, design_centralized, design_mtmse
from teamkf.exceptions import ArgumentError
from teamkf.simulation.monte_carlo import ExactSums, monte_carlo
from teamkf.simulation.sampling import RunStreams, sample_paths


@pytest.fixture(scope="module")
def platoon():
    system, cost, g = LinearGaussianSystem.platoon(4), TeamCost.platoon(4, 10.0), CommGraph.line(4)
    return {"mtmse": design_mtmse(system, cost, g, 10), "centralized": design_centralized(system, cost, horizon=10)}


def _same(a, b):
    for name in a:
        x, y = a[name], b[name]
        assert np.array_equal(x.stage_mean, y.stage_mean), name
        assert np.array_equal(x.stage_sem, y.stage_sem), name
        assert x.total_mean == y.total_mean and x.total_sem == y.total_sem, name


def test_exact_sums_are_exact_and_order_free():
    rng = np.random.default_rng(0)
    x = rng.standard_normal((500, 3)) * 10.0 ** rng.integers(-300, 300, size=(500, 3))
    fw, bw = ExactSums(3), ExactSums(3)
    for row in x:
        fw.add(row)
    for row in x[::-1]:
        bw.add(row)
    assert fw.acc == bw.acc
    # math.fsum is exactly rounded: the same double
    assert [float(v) for v in fw.value()] == [math.fsum(x[:, j]) for j in range(3)]
    # merging split sums gives the same integers
    a, b = ExactSums(3), ExactSums(3)
    for row in x[:123]:
        a.add(row)
    for row in x[123:]:
        b.add(row)
    a.merge(b)
    assert a.acc == fw.acc
    assert Fraction(fw.acc[0], 1 << 1126) == sum(Fraction(float(v)) for v in x[:, 0])
    inf = ExactSums(2)  # a diverging estimator: its non-finite entries stay infinite, flagged later (never an error)
    inf.add(np.array([np.inf, 1.0]))
    inf.merge(ExactSums(2, [5, 7]))
    assert np.isinf(inf.value()[0]) and inf.value()[1] == 1.0  # + 12 units of 2^-1126: below the rounding of 1.0


def test_result_does_not_depend_on_chunk_bit_for_bit(platoon):
    runs = [monte_carlo(platoon, 10, 1000, rng=5, batch=128, chunk=c) for c in (128, 256, 384, 1000, 10**6)]
    for r in runs[1:]:
        _same(runs[0], r)
    assert runs[0]["mtmse"].chunk == 128 and runs[2]["mtmse"].chunk == 384 and runs[3]["mtmse"].chunk == 1024


def test_matches_an_independent_in_memory_computation(platoon):
    """All runs drawn at once from the same per-run streams, costs by numpy: the same moments to rounding."""
    R_, T = 700, 10
    res = monte_carlo(platoon, T, R_, rng=9, batch=100)
    paths = sample_paths(platoon["mtmse"].system, T, R_, rng=9)
    for name, d in platoon.items():
        e = d.errors(paths)
        c = np.stack([np.einsum("ra,ab,rb->r", e[:, k], d.cost.S_at(k), e[:, k]) for k in range(T)], axis=1)
        tot = c.sum(axis=1)
        np.testing.assert_allclose(res[name].stage_mean, c.mean(axis=0), rtol=1e-11)
        np.testing.assert_allclose(res[name].stage_sem, c.std(axis=0, ddof=1) / np.sqrt(R_), rtol=1e-9)
        assert res[name].total_mean == pytest.approx(tot.mean(), rel=1e-11)
        assert res[name].total_sem == pytest.approx(tot.std(ddof=1) / np.sqrt(R_), rel=1e-9)
        # and with the analytic cost (statistical, fixed seed)
        assert abs(res[name].total_mean - d.total_cost) < 4 * res[name].total_sem


def test_batch_changes_only_rounding(platoon):
    a = monte_carlo(platoon, 10, 500, rng=3, batch=500)["mtmse"]
    b = monte_carlo(platoon, 10, 500, rng=3, batch=64)["mtmse"]
    np.testing.assert_allclose(a.stage_mean, b.stage_mean, rtol=1e-12)


def test_seed_is_recorded_and_reproduces(platoon):
    a = monte_carlo(platoon, 10, 300, rng=None, batch=100)
    seed = a["mtmse"].seed
    assert isinstance(seed["entropy"], int) and seed["spawn_key"] == []
    b = monte_carlo(platoon, 10, 300, rng=np.random.SeedSequence(seed["entropy"]), batch=100)
    _same(a, b)
    s = a["mtmse"].summary()
    assert s["seed"] == seed and s["batch"] == 100 and s["chunk"] % 100 == 0 and "teamkf_version" in s
    c = monte_carlo(platoon, 10, 300, rng=7, batch=100)
    assert c["mtmse"].seed == {"entropy": 7, "spawn_key": []}
    assert RunStreams(7).key.tolist() == RunStreams(np.random.default_rng(7)).key.tolist()


def test_memory_does_not_grow_with_runs(platoon):
    """Peak traced memory for 3 000 and 30 000 runs (batch 256): the same to within a few per cent."""
    d = {"mtmse": platoon["mtmse"]}
    monte_carlo(d, 10, 600, rng=1, batch=256)  # one-time allocations (imports, caches) out of the way
    peaks = []
    for runs in (3000, 30000):
        tracemalloc.start()
        monte_carlo(d, 10, runs, rng=1, batch=256)
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
    assert peaks[1] < 1.1 * peaks[0] + 100_000, peaks


def test_absurd_run_counts_are_refused(platoon):
    with pytest.raises(ArgumentError, match="n_runs"):
        monte_carlo(platoon, 10, 2**64, rng=1)


def test_serial_equals_local_dask_bit_for_bit(platoon):
    pytest.importorskip("distributed")
    serial = monte_carlo(platoon, 10, 600, rng=21, batch=100, chunk=200)
    dask = monte_carlo(platoon, 10, 600, rng=21, batch=100, chunk=100, scheduler="local")
    _same(serial, dask)
