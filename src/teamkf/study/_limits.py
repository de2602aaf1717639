"""The work limit applied by ``teamkf filter``, ``teamkf deploy`` and ``teamkf agent``: each sized before it starts.

Every command that runs work estimates it first and refuses, with one
:class:`~teamkf.exceptions.ResourceError` naming ``--max-hours``, a job whose optimistic
time exceeds :func:`teamkf._budget.work_limit_s` (``teamkf --max-hours H`` or
``TEAMKF_MAX_HOURS``), as ``evaluate``, ``design``, ``sweep`` and ``reproduce`` do:

* ``filter`` (a finite horizon, and ``--drops``): every estimator designed over the log's
  :math:`T` steps (:data:`~teamkf._budget.DESIGN_STEP_LOOPS` each) and run by each agent
  (:data:`~teamkf._budget.STEP_LOOPS` per agent and step);
* ``filter`` of a steady-state scenario (streamed): the designs, and at least one
  measurement row per :data:`ROW_BYTES` bytes of the file;
* ``deploy`` and ``agent``: the agents' steps, and the run's **worst case in wall time**:
  join timeout + :math:`T` deadlines (what ``deploy``'s default ``--timeout`` allows, less the
  120 s of starting the processes), or ``--timeout`` when it is smaller; each of ``--deadline``,
  ``--join-timeout`` and ``--timeout`` alone within the limit. A value below :data:`MIN_SECONDS`
  (the heartbeats run every deadline / 4) is refused when the arguments are read.
"""

from __future__ import annotations

import os
from typing import Any, Sequence

from .. import _budget
from ..exceptions import ArgumentError, ResourceError

__all__ = ["check_agent", "check_filter", "check_streamed", "check_deploy", "MIN_SECONDS", "ROW_BYTES"]

#: the shortest --deadline, --join-timeout and --timeout accepted, in seconds (heartbeats run every deadline / 4)
MIN_SECONDS = 1e-3
#: bytes of a measurement file that hold at least one row (a CSV row of a few numbers; Parquet compresses more)
ROW_BYTES = 64.0


def _loops(n_steps: float, n_agents: int, n_designs: int) -> float:
    return float(n_steps) * n_designs * (_budget.DESIGN_STEP_LOOPS + n_agents * _budget.STEP_LOOPS)


def check_filter(n_steps: int, n_agents: int, estimators: Sequence[str], *, what: str = "teamkf filter") -> float:
    """Refuse filtering ``n_steps`` steps with ``estimators`` (designed over the log, run by each agent) above the work limit."""
    k = max(len(estimators), 1)
    label = f"{what}: {k} estimator(s) designed and run by {n_agents} agents over T = {n_steps:,} steps"
    t = _budget.check_work(
        0.0, label, argument="--measurements", fix="filter a shorter log or fewer --estimators", loops=_loops(n_steps, n_agents, k)
    )
    _budget.announce(t, label)
    return t


def check_streamed(path: Any, n_agents: int, estimators: Sequence[str], max_dy: int) -> float:
    """Refuse streaming a measurement file whose rows (at least size / (:data:`ROW_BYTES` (3 + d_y)) of them) exceed the work limit."""
    try:
        size = float(os.path.getsize(path))
    except (OSError, TypeError, ValueError):
        size = 0.0
    rows = size / (ROW_BYTES * (3 + max_dy))
    k = max(len(estimators), 1)
    label = f"teamkf filter: {k} steady-state estimator(s) over a {_budget.format_bytes(size)} log (at least {rows:,.0f} rows)"
    loops = k * 10 * _budget.DESIGN_STEP_LOOPS + rows * k * 10  # a steady design iterates >= 10 steps; a streamed row costs >= 1 us
    t = _budget.check_work(0.0, label, argument="--measurements", fix="filter a shorter log or fewer --estimators", loops=loops)
    _budget.announce(t, label)
    return t


def check_deploy(
    n_steps: int, n_agents: int, *, deadline: float, join_timeout: float, timeout: float | None = None, what: str = "teamkf deploy"
) -> None:
    """Refuse a deployment whose work or worst-case wall time exceeds the limit (before any agent starts).

    Raises
    ------
    teamkf.exceptions.ResourceError
        Naming ``--steps``, ``--deadline``, ``--join-timeout`` or ``--timeout``.
    """
    label = f"{what}: {n_agents} agents over T = {n_steps:,} steps"
    _budget.check_work(0.0, label, argument="--steps", fix="run fewer steps (a shorter log or --steps)", loops=_loops(n_steps, n_agents, 1))
    limit = _budget.work_limit_s()
    how = "; or raise the limit: teamkf --max-hours H, or TEAMKF_MAX_HOURS=H"
    for flag, v in (("--deadline", deadline), ("--join-timeout", join_timeout), ("--timeout", timeout)):
        if v is not None and v > limit:
            raise ResourceError(
                f"{flag}: {v:g} s is beyond the work limit of {_budget.format_seconds(limit)}; use a smaller {flag}{how}", argument=flag
            )
    worst = join_timeout + float(n_steps) * deadline  # what deploy's default --timeout allows (plus 120 s to start the processes)
    if timeout is not None and timeout < worst:
        return  # the run is killed at --timeout, within the limit
    if worst > limit:
        raise ResourceError(
            f"--deadline: the run's worst case, {join_timeout:g} s to join + {n_steps:,} steps x {deadline:g} s = "
            f"{_budget.format_seconds(worst)}, exceeds the work limit of {_budget.format_seconds(limit)}; use a smaller --deadline, "
            f"fewer steps or a --timeout within the limit{how}",
            argument="--deadline",
        )


def check_agent(args: Any, scenario: Any, n_steps: int | None = None) -> None:
    """``teamkf agent``: ``--steps`` a whole number >= 1, and the run sized (:func:`check_deploy`) once its steps are known.

    ``n_steps``: the log's steps (None: ``--steps``, else the scenario's horizon; unknown for a steady-state log: not sized yet).
    """
    steps = getattr(args, "steps", None)
    if steps is not None and (not isinstance(steps, int) or isinstance(steps, bool) or steps < 1):
        raise ArgumentError(f"--steps: expected a whole number of steps >= 1, found {steps!r}", argument="--steps")
    T = n_steps if n_steps is not None else (steps if steps is not None else scenario.horizon)
    if T is not None:
        n = int(scenario.system.n_agents)
        check_deploy(int(T), n, deadline=args.deadline, join_timeout=args.join_timeout, what=f"teamkf agent {getattr(args, 'id', 0)}")
