"""Recorded measurements: read, validate, filter with every estimator of a scenario, write the estimates.

Modules
-------
- :mod:`~teamkf.study.measurements.format`: the file formats (the contract of ``teamkf filter``): readers,
  writers, validation, :class:`MeasurementFileError`; the streaming reader (:mod:`teamkf.study.stream`) uses
  its public names.
- :mod:`~teamkf.study.measurements.transform`: known means (inputs, offsets), innovations and
  log-likelihood, the masked model of a log with gaps.
- :mod:`~teamkf.study.measurements.workflow`: design for a log, filter it with every estimator, realized costs.
- :mod:`~teamkf.study.measurements.mcap_source` and :mod:`~teamkf.study.measurements.mcap_write`: ROS 2
  recordings (MCAP) through a topic map, and estimates written as ROS 2 topics (``pip install 'teamkf[ros]'``).

Every public name of the three is importable from here.

Missing measurements, exactly
-----------------------------
For a recorded log the whole missingness pattern is known in advance, so the
exact team-optimal estimates *for that pattern* are computable: the
estimators are designed on the time-varying model whose measurement of agent
i at step t keeps only the rows present at t. teamkf realizes that reduced
model with fixed dimensions (:func:`masked_system`): a missing row r of
y_i(t) gets C_i(t)[r] = 0 and a unit-variance noise that is independent of
every other variable (its rows and columns of R_i(t) are those of the
identity), and the value 0 is fed for it. That pseudo-measurement is
independent of x, w, v and every present measurement, so

* the Kalman gain on it is exactly zero (cov(x, y_r) = 0 and the innovation
  covariance is block diagonal), and
* in the team problem, with z = z_present + G u where u collects the
  pseudo-measurements, E[(Lx - z)'S(Lx - z)] = E[(Lx - z_present)'S(...)] +
  E[(Gu)'S(Gu)] (cross terms vanish by independence), minimized only by
  G u = 0, i.e. zero gains on u (S > 0, var u = I > 0; Radner's conditions
  keep a unique solution because Gamma stays positive definite).

So the estimates and costs equal those of the model with the rows removed (a
different thing from the "infinite variance" approximation, which is only a
limit). This is the **offline (re-analysis) optimum**: every agent is
designed as if it knew in advance which measurements of the others will be
missing. Online, agents learn the others' gaps only through the graph; the
online-feasible optimum is in general worse.

Families whose registry records declare ``missing_data`` (the centralized filter,
MTMSE, per-agent MMSE) filter logs with gaps; any other family raises
:class:`~teamkf.exceptions.UnsupportedOperationError` naming the family and
the first missing (agent, step).
"""

from .format import (
    FORMATS,
    MeasurementFileError,
    MeasurementLog,
    estimates_frame,
    read_measurements,
    read_truth,
    write_estimates,
    write_frame,
    write_measurements,
)
from .mcap_source import read_log
from .transform import Innovations, KnownInputs, innovations, known_inputs, masked_system
from .workflow import FilterResult, design_for_log, filter_log, online_estimates, realized_costs

__all__ = [
    "MeasurementFileError",
    "MeasurementLog",
    "FilterResult",
    "read_measurements",
    "read_log",
    "write_measurements",
    "read_truth",
    "write_estimates",
    "masked_system",
    "design_for_log",
    "filter_log",
    "online_estimates",
    "realized_costs",
    "FORMATS",
    "KnownInputs",
    "known_inputs",
    "Innovations",
    "innovations",
    "write_frame",
    "estimates_frame",
]
