"""Simulation: sampling trajectories and running online agents."""

from .online import run_online
from .sampling import sample

__all__ = ["sample", "run_online"]
