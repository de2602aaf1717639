"""Models: the observed process and the team cost."""

from .costs import TeamCost
from .system import LinearGaussianSystem

__all__ = ["LinearGaussianSystem", "TeamCost"]
