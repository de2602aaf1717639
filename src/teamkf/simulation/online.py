"""Run online agents on sampled measurements, delivering each y_j(s) to agent i at step s + lag.

This is the simple, structure-driven delivery used to check that online
agents reproduce their designs; the message-passing runtime over a graph
(`simulation/runtime.py`) builds on the same agent interface.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from .._progress import progress
from .._validation import FloatArray
from ..estimators.base import OnlineAgent

__all__ = ["run_online"]


def run_online(agents: Sequence[OnlineAgent], y: Sequence[FloatArray]) -> FloatArray:
    """Step every agent over the horizon of ``y``.

    Parameters
    ----------
    agents : one online agent per team member (``design.agents()``)
    y : list over agents of (n_runs, n_steps, d_y^j) measurements

    Returns
    -------
    z : (n_runs, n_steps, n_agents * d_z) estimates, agent-major in the last axis
    """
    n_runs, T = y[0].shape[:2]
    n = len(y)
    lags = [[ag.arrival_lag(j) for j in range(n)] for ag in agents]
    states = [ag.init_state(n_runs) for ag in agents]
    out = []
    for k in progress(range(T), desc="online agents", unit="step"):
        zs = []
        for i, ag in enumerate(agents):
            received = [(j, k - lags[i][j], y[j][:, k - lags[i][j]]) for j in range(n) if k - lags[i][j] >= 0]
            states[i], z = ag.step(states[i], k, received)
            zs.append(z)
        out.append(np.concatenate(zs, axis=1))
    return np.stack(out, axis=1)
