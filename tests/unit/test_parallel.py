"""Grid studies run the same on Dask as serially (map_points through the sweep engine's clients)."""

import pytest

from teamkf.simulation.parallel import current_scheduler, map_points, use_scheduler


def _square(x):
    return x * x


def test_serial_and_scheduler_context():
    assert map_points(_square, [1, 2, 3]) == [1, 4, 9]
    assert current_scheduler() == "serial"
    with use_scheduler("serial"):
        assert map_points(_square, range(4)) == [0, 1, 4, 9]


def test_bulk_study_identical_on_dask():
    pytest.importorskip("dask.distributed")
    from teamkf import experiments

    serial = experiments.run("bulk-discrepancy", quick=True)
    with use_scheduler("local"):
        dask = experiments.run("bulk-discrepancy", quick=True)
    assert serial.rows == dask.rows


def test_process_map_is_the_serial_map_in_item_order():
    """Forked workers (closures allowed, not pickled) give the serial results, in item order, for any worker count."""
    from teamkf.simulation.parallel import process_map

    offset = 7
    items = list(range(9))
    want = [(x * x + offset, x) for x in items]
    assert process_map(lambda x: (x * x + offset, x), items, workers=2) == want
    assert process_map(lambda x: (x * x + offset, x), items, workers=1) == want


def test_experiments_map_points_in_processes_by_default():
    from teamkf import experiments
    from teamkf.simulation import parallel

    seen = []
    real = parallel.process_map

    def spy(func, items, **kw):
        seen.append(len(list(items)))
        return real(func, items, **kw)

    parallel.process_map, saved = spy, real
    try:
        res = experiments.run("bulk-lq-cost", quick=True)
    finally:
        parallel.process_map = saved
    assert seen and res.rows


def test_fast_inv_is_numpys_inv_and_raises_on_singular():
    import numpy as np
    import pytest

    from teamkf._linalg import inv

    a = np.random.default_rng(0).normal(size=(6, 6)) + 6 * np.eye(6)
    assert np.array_equal(inv(a), np.linalg.inv(a))
    with pytest.raises(np.linalg.LinAlgError):
        inv(np.zeros((3, 3)))
