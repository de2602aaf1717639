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
